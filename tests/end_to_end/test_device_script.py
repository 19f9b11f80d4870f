"""``.ci/device``, the prepared script for a session's GPU machine, runs rarely and on scarce
device time, so it is checked here: it runs every step, in order, with command lines that parse,
on the data its ``prepare`` copies, from folders that git ignores (the device tool carries only
those)."""
import json
import os
import subprocess
import sys
from pathlib import Path

from training import bench, run

ROOT = Path(__file__).resolve().parents[2]
SCRIPT = ROOT / ".ci" / "device"


def test_the_device_script_runs_each_step_with_commands_that_parse(tmp_path):
    calls = tmp_path / "calls"
    python = tmp_path / "python"  # stands in for the device's python3: notes each call, runs nothing
    python.write_text(f"#!{sys.executable}\nimport json, sys\n"
                      f"open({str(calls)!r}, 'a').write(json.dumps(sys.argv[1:]) + '\\n')\n")
    python.chmod(0o755)
    done = subprocess.run([str(SCRIPT)], env={**os.environ, "PYTHON": str(python), "OUT": str(tmp_path / "out")},
                          capture_output=True, text=True, timeout=120)
    assert done.returncode == 0, done.stderr
    summary = done.stdout.split("=== summary\n")[1].splitlines()
    assert [line.split(":")[0] for line in summary] == [
        "CUDA test", "COIL-6 128x128 on cuda", "COIL-6 10 seeds 8 workers on cuda", "feature benchmark on cuda",
        "COIL-6 128x128 on cpu", "feature benchmark on cpu"]
    assert all(line.endswith("exit 0") for line in summary)
    limits = [int(line.split("(limit ")[1].split(" s)")[0]) for line in done.stdout.splitlines()
              if line.startswith("=== ") and "(limit " in line]
    assert len(limits) == len(summary) and sum(limits) <= 590  # the device tool stops a command at 600 s
    assert (tmp_path / "out" / "device.log").read_text() == done.stdout

    modules = [argv[1:] for argv in map(json.loads, calls.read_text().splitlines()) if argv[0] == "-m"]
    assert [m[0] for m in modules] == ["pytest", "training.run", "training.run", "training.bench", "training.run", "training.bench"]
    test_file, selection = modules[0][-3], modules[0][-1]
    assert f"def test_{selection}" in (ROOT / test_file).read_text()
    text = SCRIPT.read_text()
    for module, *argv in modules[1:]:
        args = (run if module == "training.run" else bench).parser().parse_args(argv)
        assert args.device in ("cuda", "cpu")
        if module == "training.run":
            assert args.command == "recognize" and args.task == "coil" and args.seed == 0
            assert f"cp -r ../shared/data/{Path(args.data).name} {Path(args.data).parent}/" in text
            assert subprocess.run(["git", "check-ignore", "-q", args.data], cwd=ROOT).returncode == 0
    assert "--dest .whl" in text and subprocess.run(["git", "check-ignore", "-q", ".whl/a.whl"], cwd=ROOT).returncode == 0
