"""Independent tasks in local processes and on Ray: same results as one after another, failures retried once."""
import json
import re
import shutil
import time
from dataclasses import replace
from pathlib import Path

import pytest
import torch

from ftorch import FeatureSpace
from ftorch.errors import InputError
from tests.conftest import needs_ray
from tests.training.test_protocol import check_events
from training import run
from training.cli.outputs import Ledger
from training.cli.parallel import CORES, TasksFailed, run_tasks, share_idle_cores
from training.commands import recognize

ARGS = ["recognize", "--task", "plym", "--classes", "3", "--size", "32", "--folds", "2", "--seed", "1",
        "--device", "cpu", "--quiet", "--stages", "0", "--max-cycles", "3"]


def square(x):
    return x * x


def flaky(argument):
    """Fails the first time it is called for a marker file that does not exist yet."""
    marker, value = argument
    if value < 0:
        raise ValueError(f"bad value {value}")
    if not Path(marker).exists():
        Path(marker).write_text("failed once")
        raise RuntimeError("first attempt fails")
    return value + 1


def report_text(folder: Path) -> str:
    return re.sub(r'"seconds": [0-9.e+-]+', '"seconds": _', (folder / "report.json").read_text())


@pytest.mark.parametrize("workers", [1, 2])
def test_failed_tasks_run_once_more_and_results_keep_their_order(tmp_path, workers, capsys):
    arguments = [(str(tmp_path / f"m{i}"), i) for i in range(3)]
    assert run_tasks(flaky, arguments, ["a", "b", "c"], workers=workers, progress=False) == [1, 2, 3]
    printed = capsys.readouterr()
    assert (printed.out + printed.err).count("running it again") == 3
    (tmp_path / "ok").write_text("")
    with pytest.raises(TasksFailed) as failed:
        run_tasks(flaky, [(str(tmp_path / "ok"), 5), (str(tmp_path / "ok"), -1)], ["good", "bad"],
                  workers=workers, progress=False)
    assert list(failed.value.failures) == ["bad"] and "bad value -1" in failed.value.failures["bad"]


def test_processes_give_the_results_of_one_process():
    assert run_tasks(square, list(range(7)), [str(i) for i in range(7)], workers=2, progress=False) == [
        i * i for i in range(7)]


def threads_while_waiting(seconds: float) -> tuple[int, int]:
    """A task's torch threads at its start, and once they changed (waiting up to ``seconds``)."""
    start = torch.get_num_threads()
    deadline = time.monotonic() + seconds
    while time.monotonic() < deadline and torch.get_num_threads() == start:
        share_idle_cores()
        time.sleep(0.05)
    return start, torch.get_num_threads()


@pytest.mark.skipif(CORES < 2, reason="one core: there is nothing to share")
def test_the_last_task_takes_the_idle_cores():
    short, long = run_tasks(threads_while_waiting, [0.0, 60.0], ["short", "long"], workers=2, progress=False)
    assert short == (CORES // 2, CORES // 2)  # two tasks for two workers: half the cores each
    assert long == (CORES // 2, CORES)  # once the short one is done, all of them
    threads = torch.get_num_threads()
    share_idle_cores()  # outside a worker it changes nothing
    assert torch.get_num_threads() == threads


@pytest.mark.skipif(CORES < 4, reason="fewer than four cores: four workers get one thread each either way")
def test_more_workers_than_tasks_share_the_cores_from_the_start():
    assert run_tasks(threads_while_waiting, [60.0, 60.0], ["a", "b"], workers=4, progress=False) == [
        (CORES // 4, CORES // 2)] * 2


def test_two_workers_write_the_sequential_report(tmp_path):
    assert run.main([*ARGS, "--out", str(tmp_path / "one")]) == 0
    assert run.main([*ARGS, "--out", str(tmp_path / "two"), "--workers", "2"]) == 0
    assert report_text(tmp_path / "one") == report_text(tmp_path / "two")
    report = json.loads((tmp_path / "two" / "report.json").read_text())
    for k in (1, 2):  # each task wrote its own complete fold folder and TensorBoard run
        assert (tmp_path / "two" / f"fold{k}" / "learner.json").is_file()
        check_events(tmp_path / "two" / "tensorboard" / f"fold{k}", report["folds"][k - 1], report["config"])


def test_the_same_seed_writes_the_same_learner_bytes_whatever_the_workers_and_threads(tmp_path):
    """Issue 55's rule: the same seed gives the same bits whatever the batch, workers or threads
    (feature values are summed in a fixed order, ftorch.space.steering.dot). An expert stage is included."""
    args = [*ARGS, "--stages", "1"]
    threads = torch.get_num_threads()
    try:
        for n in (1, 2):
            torch.set_num_threads(n)
            assert run.main([*args, "--out", str(tmp_path / f"threads{n}")]) == 0
    finally:
        torch.set_num_threads(threads)
    assert run.main([*args, "--out", str(tmp_path / "workers2"), "--workers", "2"]) == 0
    for k in (1, 2):
        learned = [(tmp_path / run_name / f"fold{k}" / "learner.json").read_bytes()
                   for run_name in ("threads1", "threads2", "workers2")]
        assert learned[0] == learned[1] == learned[2], k
    assert report_text(tmp_path / "threads1") == report_text(tmp_path / "workers2")


@needs_ray
def test_ray_runs_two_folds_to_the_sequential_report(tmp_path):
    import ray

    assert run.main([*ARGS, "--out", str(tmp_path / "one")]) == 0
    ray.init(num_cpus=2, include_dashboard=False, log_to_driver=False)
    try:
        assert run.main([*ARGS, "--out", str(tmp_path / "ray"), "--ray", "auto"]) == 0
    finally:
        ray.shutdown()
    assert report_text(tmp_path / "one") == report_text(tmp_path / "ray")
    assert json.loads((tmp_path / "ray" / "report.json").read_text())["folds"][1]["fold"] == 2


@needs_ray
def test_a_full_disk_on_the_cluster_ends_the_run_without_a_second_try():
    import errno

    import ray

    ray.init(num_cpus=1, include_dashboard=False, log_to_driver=False)
    try:  # writing to /dev/full fails with ENOSPC: not retried, raised as the error itself
        with pytest.raises(OSError) as full:
            run_tasks(Path("/dev/full").write_text, ["x"], ["full disk"], ray="auto", progress=False)
        assert full.value.errno == errno.ENOSPC
        with pytest.raises(TasksFailed, match="ZeroDivisionError"):  # any other error is run again and reported
            run_tasks((1).__truediv__, [0], ["zero"], ray="auto", progress=False)
    finally:
        ray.shutdown()


def test_a_bad_worker_count_gets_one_line(tmp_path, capsys):
    with pytest.raises(SystemExit) as refused:  # the parser refuses it itself
        run.main([*ARGS, "--out", str(tmp_path / "x"), "--workers", "0"])
    assert refused.value.code == 2
    assert "--workers: 0: expected a number of processes (an integer from 1 to 1024)" in capsys.readouterr().err
    with pytest.raises(InputError, match="--workers 0: expected at least 1"):
        run_tasks(len, [[1]], ["a"], workers=0)  # and the library function


def test_the_folds_compute_each_view_set_once(tmp_path, monkeypatch):
    """Fold 2 trains on fold 1's test views and tests on its training views: two record sets, not four."""
    calls = []
    records = FeatureSpace.records
    monkeypatch.setattr(FeatureSpace, "records", lambda self, images, **kw: calls.append(len(images)) or records(self, images, **kw))
    assert run.main([*ARGS, "--out", str(tmp_path / "one")]) == 0
    assert len(calls) == 2 and sum(calls) == 3 * 15  # three solids of 15 views, each view once


def test_a_process_without_shared_records_computes_each_view_set_once(tmp_path, monkeypatch):
    """Ray tasks and workers without shared memory compute their own records: each view set once
    per process, for the first task that needs it, and the report stays the same."""
    seeds = [*ARGS, "--seeds", "2"]  # fold 1 and 2 of seed 1, fold 1 of seed 2: all on the same two view sets
    assert run.main([*seeds, "--out", str(tmp_path / "shared")]) == 0
    calls = []
    records = FeatureSpace.records
    monkeypatch.setattr(FeatureSpace, "records", lambda self, images, **kw: calls.append(len(images)) or records(self, images, **kw))
    monkeypatch.setattr(recognize, "shared_records", lambda *arguments: {})
    assert run.main([*seeds, "--out", str(tmp_path / "own")]) == 0
    assert len(calls) == 2 and sum(calls) == 3 * 15  # not six sets
    assert report_text(tmp_path / "own") == report_text(tmp_path / "shared")
    calls.clear()  # a worker that runs a task of another data set next (a Ray worker serves many runs)
    other = tmp_path / "other"
    args = run.parser().parse_args([*seeds, "--size", "24", "--quiet"])
    images = recognize.TaskChoice.of(args)
    config = recognize.run_config(args, images.load(), recognize.learner_settings(args), torch.device("cpu"), False)
    recognize.fold_task(recognize.FoldJob(replace(config, seed=1), 1, other, other / "tb", Ledger(str(other)), images, args.device,
                                          False, False, args.checkpoint_every))
    assert len(calls) == 2  # its own records, not those of the views with the same indices before


def is_shared(records) -> bool:
    return records.pyramid.first.is_shared() and records.pyramid.second.is_shared() and records.x.is_shared()


def test_worker_processes_receive_records_in_shared_memory():
    records = FeatureSpace().records([torch.rand(32, 32) for _ in range(3)])
    assert not is_shared(records)
    assert run_tasks(is_shared, [records, records], ["a", "b"], workers=2, progress=False) == [True, True]
    assert is_shared(records)  # moved there once, in place: the workers map the parent's pyramid, no copies


def test_records_are_shared_only_where_workers_can_map_them(monkeypatch):
    args = run.parser().parse_args([*ARGS, "--workers", "2"])
    task = recognize.TaskChoice.of(args).load()
    jobs = [1, 2]  # the jobs' folds
    shared = recognize.shared_records(args, task, jobs, torch.device("cpu"))
    assert set(shared) == {tuple(ix) for ix in task.fold(1)}  # fold 2's sets are fold 1's
    args.augment = 1  # augmented training sets are drawn per fold: only the test sets are shared
    assert set(recognize.shared_records(args, task, jobs, torch.device("cpu"))) == {tuple(task.fold(k)[1]) for k in (1, 2)}
    args.augment, args.ray = 0, "auto"  # Ray tasks may run elsewhere: they compute their own
    assert recognize.shared_records(args, task, jobs, torch.device("cpu")) == {}
    args.ray = None
    assert recognize.shared_records(args, task, jobs, torch.device("cuda")) == {}  # no CUDA memory between processes
    nbytes = sum(r.nbytes for r in shared.values())
    pyramids = sum(r.pyramid.first.nbytes + r.pyramid.second.nbytes for r in shared.values())
    calls = []
    records = FeatureSpace.records
    monkeypatch.setattr(FeatureSpace, "records", lambda self, images, **kw: calls.append(len(images)) or records(self, images, **kw))
    for free, computed in ((nbytes, 2), (nbytes - 1, 2), (pyramids, 2), (pyramids - 1, 0)):  # /dev/shm too small (containers)
        monkeypatch.setattr(shutil, "disk_usage", lambda path: shutil._ntuple_diskusage(1 << 40, (1 << 40) - free, free))
        calls.clear()
        assert (recognize.shared_records(args, task, jobs, torch.device("cpu")) == {}) == (free < nbytes)
        assert len(calls) == computed  # none where the pyramids alone would not fit
