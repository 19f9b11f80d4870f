"""Run folders: nothing a user or a completed run wrote is lost on any failure path, two runs never
share a folder, workers never outlive a killed runner, and a full disk is one line."""
import errno
import json
import os
import shutil
import signal
import subprocess
import sys
import time

import cv2
import numpy as np
import pytest

from tests.end_to_end.test_hardening import RUN, exit_code, one_line
from training import run
from training.cli import outputs

LOCK = outputs.LOCK


def files(root) -> dict[str, bytes]:
    """Every file below ``root`` by its relative path, with its bytes (the lock file's holder aside)."""
    return {str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file() and p.name != LOCK}


def _views(folder, names, size=48):
    folder.mkdir(parents=True, exist_ok=True)
    for n, name in enumerate(names):
        cv2.imwrite(str(folder / name), np.random.default_rng(n).integers(0, 255, (size, size), dtype=np.uint8))


def test_a_bad_input_with_overwrite_loses_nothing(finished_run, tmp_path, capsys, monkeypatch):
    out, before = finished_run
    assert {"report.json", "report.md", "curves.png", "fold1/learner.json", "fold1/checkpoint.json"} <= set(before)
    capsys.readouterr()
    # a typo in --data
    assert exit_code(["recognize", "--task", "coil", "--data", str(tmp_path / "typo"), "--classes", "3", "--views", "8",
                      "--out", str(out), "--overwrite"]) == 2
    assert one_line(capsys) == f"error: --data {tmp_path / 'typo'}: no such folder"
    assert files(out) == before
    # a bad image in --data
    data = tmp_path / "data"
    _views(data / "a", ["1.png", "2.png"])
    _views(data / "b", ["1.png"])
    (data / "b" / "2.png").write_bytes(b"not a png")
    assert exit_code(["recognize", "--task", "folder", "--data", str(data), "--out", str(out), "--overwrite"]) == 2
    assert "2.png: not a readable image file" in one_line(capsys)
    assert files(out) == before
    # a Ray address of the wrong form
    assert exit_code([*RUN, "--ray", "bogus::addr", "--out", str(out), "--overwrite"]) == 2
    assert "expected local, auto, HOST:PORT" in one_line(capsys)
    assert files(out) == before
    # images whose pyramids would not fit in memory
    monkeypatch.setattr("ftorch.space.record.free_memory", lambda device: 2**20)
    assert exit_code([*RUN, "--out", str(out), "--overwrite"]) == 2
    assert "GiB for their scale-space pyramid, more than the 0.0 GiB free" in one_line(capsys)
    assert files(out) == before


def test_overwrite_removes_only_what_a_run_recorded(tmp_path, capsys):
    home = tmp_path / "home"
    mine = {"fold1/mydata.txt": "a", "seed3/results.csv": "b", "robustness/paper.tex": "c", "notes.md": "d",
            "tensorboard/keep.txt": "e", "tensorboard/fold1/mine.txt": "f"}
    for name, text in mine.items():
        (home / name).parent.mkdir(parents=True, exist_ok=True)
        (home / name).write_text(text)
    argv = [*RUN, "--out", str(home), "--overwrite"]
    assert run.main(argv) == 0
    assert f"note: {home} has no ledger of a run; its files are kept" in capsys.readouterr().err
    first = files(home)
    assert run.main(argv) == 0
    second = files(home)
    assert all((home / name).read_text() == text for name, text in mine.items())

    def kept(found):
        return {p for p in found if "events.out.tfevents" not in p}
    assert kept(first) == kept(second) and len(first) == len(second)  # one run's events, not two runs'
    # a ledger that names paths outside the run folder removes nothing there
    victim = tmp_path / "victim.txt"
    victim.write_text("keep")
    (home / "fold1" / "link").symlink_to(tmp_path, target_is_directory=True)
    with open(home / outputs.LEDGER, "a") as ledger:
        for path in (str(victim), "../victim.txt", "fold1/link/victim.txt", "fold1/mydata.txt/.."):
            ledger.write(json.dumps({"file": path}) + "\n")
        ledger.write("{not json\n")
    assert run.main(argv) == 0
    assert victim.read_text() == "keep" and all((home / name).read_text() == text for name, text in mine.items())


def test_a_resumed_finished_run_logs_nothing_again(finished_run, tmp_path):
    from tensorboard.backend.event_processing.event_accumulator import EventAccumulator

    out = tmp_path / "again"
    shutil.copytree(finished_run[0], out)
    assert run.main([*RUN, "--out", str(out), "--resume"]) == 0
    events = EventAccumulator(str(out / "tensorboard" / "fold1"), size_guidance={"images": 0})
    events.Reload()
    assert events.Tags()["images"] and all(len(events.Images(tag)) == 1 for tag in events.Tags()["images"])


def _wait(condition, seconds: float, child=None):
    deadline = time.monotonic() + seconds
    while not condition() and time.monotonic() < deadline and (child is None or child.poll() is None):
        time.sleep(0.05)
    return condition()


def _alive(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as stat_file:
            return stat_file.read().split(")")[-1].split()[0] != "Z"  # a zombie has ended
    except FileNotFoundError:
        return False


COMMAND = [sys.executable, "-m", "training.run", "recognize", "--folds", "1", "--seeds", "4", "--checkpoint-every", "0",
           "--quiet", "--device", "cpu"]  # the default job's fold 1 with four seeds: a minute or more


def test_two_runs_never_share_a_folder_and_a_killed_runs_lock_is_taken_over(tmp_path):
    out = tmp_path / "conc"
    first = subprocess.Popen([*COMMAND, "--seed", "0", "--out", str(out)], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True)
    try:
        assert _wait(lambda: (out / "fold1" / "checkpoint.json").is_file(), 120, first), first.communicate()
        for extra in (["--seed", "1"], ["--seed", "0", "--resume"], ["--seed", "1", "--overwrite"]):
            second = subprocess.run([*COMMAND, *extra, "--out", str(out)], capture_output=True, text=True, timeout=120)
            assert second.returncode == 2, second.stderr
            assert f"error: --out {out}: another run is writing there (pid {first.pid} on " in second.stderr
            assert second.stderr.count("\n") == 1
        assert first.poll() is None  # the refusals took seconds; the first run is still going
        first.kill()  # SIGKILL: no handler runs, the lock file stays
        first.wait(timeout=30)
    finally:
        if first.poll() is None:
            first.kill()
            first.wait()
    assert (out / LOCK).is_file()
    again = subprocess.run([sys.executable, "-m", "training.run", *RUN, "--out", str(out), "--overwrite"],
                           capture_output=True, text=True, timeout=300)
    assert again.returncode == 0, again.stderr  # the killed run's stale lock is taken over


def test_workers_end_when_the_runner_is_killed(tmp_path):
    out = tmp_path / "orphans"
    argv = [sys.executable, "-m", "training.run", "recognize", "--quiet", "--device", "cpu", "--workers", "2",
            "--checkpoint-every", "0", "--out", str(out)]  # the default job: two folds of a minute or more
    child = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    workers = []
    try:
        assert _wait(lambda: all((out / f"fold{k}" / "checkpoint.json").is_file() for k in (1, 2)), 180, child)
        workers = [int(p) for p in subprocess.run(["pgrep", "-P", str(child.pid)], capture_output=True,
                                                  text=True).stdout.split()]
        assert len(workers) >= 2
        child.kill()
        child.wait(timeout=30)
        assert _wait(lambda: not any(_alive(p) for p in workers), 20)
    finally:
        for pid in [child.pid, *workers]:
            try:
                os.kill(pid, signal.SIGKILL)
            except ProcessLookupError:
                pass


def _disk_full(*args, **kwargs):
    raise OSError(errno.ENOSPC, "No space left on device")


@pytest.mark.parametrize("where", ["tensorboard", "checkpoint"])
def test_a_full_disk_during_resume_is_one_line_and_not_retried(where, tmp_path, capsys, monkeypatch):
    out = tmp_path / "full"
    if where == "tensorboard":  # TensorBoard's writer thread meets the full disk
        monkeypatch.setattr("tensorboard.summary.writer.record_writer.RecordWriter.write", _disk_full)
    else:
        monkeypatch.setattr("ftorch.checkpoint.os.fsync", _disk_full)
    assert run.main([*RUN, "--checkpoint-every", "0", "--out", str(out), "--resume"]) == 2
    captured = capsys.readouterr()
    assert "running it again" not in captured.out + captured.err
    err = captured.err.strip().splitlines()
    assert err[-1].startswith("error: ") and err[-1].endswith("No space left on device"), captured.err
    assert "Traceback" not in captured.err and len([line for line in err if line.startswith("error")]) == 1
