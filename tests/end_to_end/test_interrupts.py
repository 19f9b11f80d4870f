"""Two Ctrl-C in quick succession, as a terminal sends them to the whole process group: one line,
exit status 130, and --resume finishes the run, with --workers 2 as with one process. The second
SIGINT comes 50 ms after the first, while the runner is ending its workers or Python is shutting
down (that takes a few hundred ms once torch is loaded); it used to print "Exception ignored in
threading._shutdown ... KeyboardInterrupt" or kill the runner (exit status -2), and the workers,
interrupted too, left semaphores that the resource tracker warned about."""
import os
import signal
import subprocess
import sys
import time

import pytest

ARGV = [sys.executable, "-m", "training.run", "recognize", "--task", "plym", "--size", "32", "--classes", "3",
        "--views", "6", "--stages", "0", "--quiet", "--device", "cpu", "--checkpoint-every", "0"]  # 2 folds of 2-3 cycles


@pytest.mark.parametrize("workers", [2, 1])
def test_two_quick_ctrl_c_are_one_line_and_the_run_resumes(workers, tmp_path):
    out = tmp_path / "run"
    argv = [*ARGV, "--workers", str(workers), "--out", str(out)]
    child = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
                             start_new_session=True)  # its own process group, as a shell's job
    try:
        deadline = time.monotonic() + 300  # rendering the views and the first cycle; slow CI machines
        while not (out / "fold1" / "checkpoint.json").is_file() and child.poll() is None \
                and time.monotonic() < deadline:
            time.sleep(0.02)
        assert child.poll() is None, "the run ended before it could be interrupted"
        os.killpg(child.pid, signal.SIGINT)
        time.sleep(0.05)
        os.killpg(child.pid, signal.SIGINT)
        _, err = child.communicate(timeout=120)
    finally:
        if child.poll() is None:
            os.killpg(child.pid, signal.SIGKILL)
            child.wait()
    assert child.returncode == 130, err
    assert err == (f"interrupted; the checkpoints in {out} keep the cycles finished up to their last write: "
                   "run the same command with --resume to continue\n")
    done = subprocess.run([*argv, "--resume"], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr
