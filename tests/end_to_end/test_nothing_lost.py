"""Nothing lost on any path, round 3: special files, other commands' folders, outputs inside inputs,
a log folder shared by two runs, and the silent wrong answers (contrast, mixed splits, options the
runner refuses, images changed under a run, names that break a file system or a table)."""
import json
import os
import shutil
import stat
import threading
import time
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from ftorch import DistinctiveFeatureLearner, InputError
from ftorch.checkpoint import write_text
from ftorch.grasp import GraspLearner
from ftorch.recognition.environment import ImageSet
from tests.end_to_end.test_hardening import RUN, exit_code, one_line
from tests.end_to_end.test_run_folders import files
from training import run
from training.cli import outputs
from training.recognition.records import ConfusionRow
from training.recognition.report import confusion_table

ROOT = os.geteuid() == 0 if hasattr(os, "geteuid") else False
needs_root = pytest.mark.skipif(not ROOT, reason="making device nodes (mknod) needs root")


def _node(path: Path, major: int, minor: int) -> Path:
    os.mknod(path, 0o666 | stat.S_IFCHR, os.makedev(major, minor))
    return path


def _still_a_device(path: Path, major: int, minor: int) -> bool:
    st = os.lstat(path)
    return stat.S_ISCHR(st.st_mode) and (os.major(st.st_rdev), os.minor(st.st_rdev)) == (major, minor)


@pytest.fixture(scope="module")
def learner():
    rng = np.random.default_rng(0)
    images = [rng.random((40, 40)) for _ in range(6)]
    for k, image in enumerate(images):
        image[10:30, 10 + 3 * (k % 2): 20 + 3 * (k % 2)] = 1.0
    return DistinctiveFeatureLearner(seed=0).fit(images, [k % 2 for k in range(6)], stages=0, max_cycles=2)


# -- 1. an atomic write replaces only a regular file ---------------------------------------------
@needs_root
def test_a_device_node_is_never_replaced_and_the_null_device_is_written_in_place(tmp_path, learner, capsys):
    full, null = _node(tmp_path / "full", 1, 7), _node(tmp_path / "null", 1, 3)
    with pytest.raises(InputError, match="a character device is there, not a regular file"):
        learner.save(full)
    with pytest.raises(InputError, match="a character device"):
        write_text(full, "x")
    learner.save(null)  # what a user means by /dev/null: nothing kept
    assert _still_a_device(full, 1, 7) and _still_a_device(null, 1, 3)
    assert exit_code(["salient", "--out", str(full), "--device", "cpu"]) == 2
    capsys.readouterr()
    from training import bench
    assert bench.main(["recognition", "--quick", "--json", str(full)]) == 2
    assert "a character device is there" in one_line(capsys)
    assert _still_a_device(full, 1, 7) and sorted(p.name for p in tmp_path.iterdir()) == ["full", "null"]


def test_a_folder_or_a_place_that_takes_no_file_is_named_by_the_users_path(tmp_path, learner):
    (tmp_path / "folder").mkdir()
    with pytest.raises(InputError, match=f"^{tmp_path / 'folder'}: a folder is there"):
        learner.save(tmp_path / "folder")
    with pytest.raises(OSError) as caught:
        learner.save("/proc/ftorch-learner.json")
    assert caught.value.filename == "/proc/ftorch-learner.json" and ".tmp" not in str(caught.value)
    assert "\n" not in str(caught.value)


def test_a_pipe_and_standard_output_are_written_in_place(tmp_path, capfd):
    pipe = tmp_path / "pipe"
    os.mkfifo(pipe)
    got = []
    reader = threading.Thread(target=lambda: got.append(pipe.read_text()), daemon=True)
    reader.start()
    write_text(pipe, "through the pipe")
    reader.join(10)
    assert got == ["through the pipe"] and stat.S_ISFIFO(os.lstat(pipe).st_mode)
    print("before", flush=True)
    write_text("/dev/stdout", "written\n")
    print("after", flush=True)
    assert capfd.readouterr().out == "before\nwritten\nafter\n"


def test_a_link_or_special_file_where_the_run_keeps_its_lock_or_ledger_is_refused(tmp_path, capsys):
    victim = tmp_path / "victim.txt"
    victim.write_text("keep me")
    for name in (outputs.LOCK, outputs.LEDGER):
        out = tmp_path / f"out-{name}"
        out.mkdir()
        (out / name).symlink_to(victim)
        assert exit_code([*RUN, "--out", str(out)]) == 2
        assert "ftorch keeps its own file there, and something else is there" in one_line(capsys)
        assert victim.read_text() == "keep me"


# -- 2. a folder holding another command's run ---------------------------------------------------
@pytest.mark.parametrize("argv", [
    ["tradeoff", "--runs", "OTHER", "--overwrite"],
    ["tradeoff", "--runs", "OTHER"],
    ["incremental", "--task", "plym", "--classes", "2", "--folds", "1", "--stages", "0", "--max-cycles", "1",
     "--overwrite", "--quiet", "--device", "cpu"],
    ["grasp", "--experiment", "clean", "--overwrite", "--quiet", "--device", "cpu"],
    ["evaluate", "--learner", "LEARNER", "--task", "folder", "--data", "DATA", "--device", "cpu"],
    ["robustness", "--run", "OTHER", "--device", "cpu"],
    ["salient", "--device", "cpu"],
], ids=["tradeoff-overwrite", "tradeoff", "incremental", "grasp", "evaluate", "robustness", "salient"])
def test_a_folder_holding_another_commands_run_is_refused_with_or_without_overwrite(argv, finished_run, tmp_path, capsys):
    out, before = finished_run
    other = tmp_path / "other"
    shutil.copytree(out, other)
    data = tmp_path / "data"
    for name in ("a", "b"):
        (data / name).mkdir(parents=True)
        cv2.imwrite(str(data / name / "1.png"), np.full((40, 40), 128, np.uint8))
    argv = [{"OTHER": str(other), "LEARNER": str(other / "fold1" / "learner.json"), "DATA": str(data)}.get(a, a) for a in argv]
    capsys.readouterr()
    assert exit_code([*argv, "--out", str(out)]) == 2
    message = one_line(capsys)
    assert f"--out {out} holds a run of recognize" in message and "another command's folder" in message, message
    assert files(out) == before


def test_overwrite_still_replaces_a_run_of_the_same_command(tmp_path, capsys):
    out = tmp_path / "run"
    assert run.main([*RUN, "--out", str(out)]) == 0
    assert json.loads((out / outputs.LEDGER).read_text().splitlines()[0]) == {"command": "recognize"}
    assert run.main([*RUN, "--out", str(out), "--overwrite"]) == 0
    assert (out / "report.json").is_file()


def test_a_folder_without_a_ledger_is_known_by_its_report(finished_run, tmp_path, capsys):
    """A run written before ledgers named their command: its report.json says which it was."""
    out, _ = finished_run
    old = tmp_path / "old"
    shutil.copytree(out, old)
    (old / outputs.LEDGER).unlink()
    capsys.readouterr()
    assert exit_code(["tradeoff", "--runs", str(out), "--out", str(old), "--overwrite"]) == 2
    assert "holds a run of recognize" in one_line(capsys)


# -- 3. outputs inside inputs --------------------------------------------------------------------
def _folder_data(root: Path, classes=("a", "b"), views=4, size=40) -> Path:
    for k, name in enumerate(classes):
        (root / name).mkdir(parents=True)
        for v in range(views):
            image = np.random.default_rng(10 * k + v).integers(0, 60, (size, size)).astype(np.uint8)
            image[8 + 2 * k: 30, 10 + v: 22 + 2 * k] = 230
            cv2.imwrite(str(root / name / f"{v}.png"), image)
    return root


@pytest.mark.parametrize("where", ["out inside data", "logdir inside data", "data inside out"])
def test_an_output_folder_inside_an_input_folder_or_holding_one_is_refused(where, tmp_path, capsys):
    data = _folder_data(tmp_path / "data")
    before = files(data)
    out = {"out inside data": data / "zrun", "logdir inside data": tmp_path / "run",
           "data inside out": tmp_path}[where]
    argv = ["recognize", "--task", "folder", "--data", str(data), "--out", str(out), "--stages", "0", "--max-cycles", "1",
            "--folds", "1", "--quiet", "--device", "cpu"]
    if where == "logdir inside data":
        argv += ["--logdir", str(data / "tb")]
    capsys.readouterr()
    assert exit_code(argv) == 2
    assert "would be read as input by the next run" in one_line(capsys)
    assert files(data) == before and not (data / "zrun").exists() and not (data / "tb").exists()


def test_robustness_and_evaluate_write_nothing_into_the_data(finished_run, tmp_path, capsys):
    out, _ = finished_run
    data = _folder_data(tmp_path / "data")
    before = files(data)
    capsys.readouterr()
    assert exit_code(["robustness", "--run", str(out), "--data", str(data), "--out", str(data / "r"),
                      "--device", "cpu"]) == 2
    assert "would be read as input" in one_line(capsys)
    assert exit_code(["evaluate", "--learner", str(out / "fold1" / "learner.json"), "--task", "folder", "--data", str(data),
                      "--out", str(data / "e"), "--device", "cpu"]) == 2
    assert "would be read as input" in one_line(capsys)
    assert files(data) == before


def test_salient_does_not_write_its_figures_beside_the_images(tmp_path, capsys):
    image = tmp_path / "x.png"
    cv2.imwrite(str(image), np.random.default_rng(0).integers(0, 255, (40, 40), dtype=np.uint8))
    assert exit_code(["salient", str(image), "--out", str(tmp_path), "--device", "cpu"]) == 2
    assert "holds the images" in one_line(capsys)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["x.png"]


# -- 4. a log folder belongs to one run folder -----------------------------------------------------
def test_a_log_folder_holding_another_runs_tensorboard_runs_is_refused(tmp_path, capsys):
    logs = tmp_path / "logs"
    a, b = tmp_path / "a", tmp_path / "b"
    assert run.main([*RUN, "--out", str(a), "--logdir", str(logs)]) == 0
    events = files(logs)
    assert any("events.out.tfevents" in name for name in events)
    capsys.readouterr()
    for extra in ([], ["--overwrite"]):
        assert exit_code([*RUN, "--out", str(b), "--logdir", str(logs), *extra]) == 2
        assert f"--logdir {logs} holds the TensorBoard runs of another run folder" in one_line(capsys)
    assert files(logs) == events
    # the run that owns it replaces its own logs
    assert run.main([*RUN, "--out", str(a), "--logdir", str(logs), "--overwrite"]) == 0
    # a run's own default log folder is no other run's
    c = tmp_path / "c"
    assert run.main([*RUN, "--out", str(c)]) == 0
    capsys.readouterr()
    assert exit_code([*RUN, "--out", str(b), "--logdir", str(c / "tensorboard")]) == 2
    assert "holds the TensorBoard runs of another run folder" in one_line(capsys)


# -- 5. feature values invariant to I -> a*I + b -----------------------------------------------------
@pytest.fixture(scope="module")
def plym_learner():
    """A learner of three built-in Plym solids (data not used to choose MIN_LEVELS) and its test views,
    with the primitives whose values are invariant to I -> a*I + b (3.4.4): texels and edgels. The
    intensity texture (7.2.1, in the defaults) describes intensities in [0, 1] and is not."""
    from training.data.datasets import load_task
    task = load_task("plym", classes=3, views=8, size=40)
    train, test = task.fold(1)
    learner = DistinctiveFeatureLearner(seed=0, primitives="texel,edgel").fit(
        [task.view(i) for i in train], [task.labels[i] for i in train], stages=0, max_cycles=6)
    views = [task.view(i).double() for i in test]
    return learner, views, learner.predict_proba(views)


def test_answers_are_the_same_for_any_contrast_and_offset_or_refused(plym_learner):
    learner, views, proba = plym_learner
    answers = learner.predict(views)
    rng = np.random.default_rng(7)
    held = refused = 0
    for dtype in (torch.float32, torch.float64):
        for _ in range(12):
            a, b = 10 ** rng.uniform(-6, 6), rng.uniform(-1e4, 1e4)
            changed = [(v * a + b).to(dtype) for v in views]
            if any(float(x.max() - x.min()) == 0 for x in changed):
                continue  # rounded flat by the conversion: flat is what arrives, and nothing can tell what it was
            try:
                got = learner.predict(changed)
            except InputError as err:
                assert "steps of the dtype apart" in str(err) and "\n" not in str(err)
                refused += 1
                continue
            held += 1
            assert got == answers, (dtype, a, b)
    assert held >= 8 and refused >= 1  # both outcomes were drawn
    for a in (1e-5, 2.0**-20, 1e6, 1e300):  # no offset: held in float64 at every scale, floor and squares included
        assert learner.predict([v * a for v in views]) == answers
    np.testing.assert_allclose(learner.predict_proba([v * 1e-5 for v in views]), proba, atol=1e-9)


def test_an_image_whose_values_cannot_hold_its_contrast_is_refused_in_one_line():
    space = DistinctiveFeatureLearner().space
    image = torch.rand(40, 40)
    with pytest.raises(InputError, match="steps of the dtype apart"):
        space.records([image + 1e5])  # float32: values 1/128 apart
    space.records([image.double() + 1e5])  # float64 holds it
    with pytest.raises(InputError, match="span more than"):
        space.records([torch.cat([torch.full((40, 20), -1e308, dtype=torch.float64), torch.full((40, 20), 1e308, dtype=torch.float64)], 1)])
    assert int(space.records([torch.full((40, 40), 1e5)]).mask.sum()) == 0  # flat at any offset: nothing salient


# -- 6. tradeoff compares runs on the same splits only ---------------------------------------------
def test_tradeoff_refuses_runs_of_other_folds_or_seeds(finished_run, tmp_path, capsys):
    out, _ = finished_run
    two = tmp_path / "two"
    shutil.copytree(out, two)
    report = json.loads((two / "report.json").read_text())
    report["folds"].append({**report["folds"][0], "fold": 2})
    (two / "report.json").write_text(json.dumps(report))
    shutil.copytree(two / "fold1", two / "fold2")
    capsys.readouterr()
    assert exit_code(["tradeoff", "--runs", str(out), str(two), "--out", str(tmp_path / "t"), "--device", "cpu"]) == 2
    message = one_line(capsys)
    assert "did not test on the same splits" in message and "fold 1 0.50, fold 2 0.50 against fold 1 1.00" in message


# -- 8. the library takes what the runner takes ------------------------------------------------------
@pytest.mark.parametrize("options, message", [
    ({"stages": "2"}, "stages must be an integer from 0 to 100"),
    ({"stages": -1}, "stages must be an integer from 0 to 100"),
    ({"stages": 1.5}, "stages must be an integer"),
    ({"stages": True}, "stages must be an integer"),
    pytest.param({"stages": 10**9}, "stages must be an integer from 0 to 100", id="a billion stages"),
    ({"max_cycles": 0}, "max_cycles must be an integer from 1 to 1000"),
    ({"max_cycles": -3}, "max_cycles must be an integer from 1 to 1000"),
    ({"incremental": True, "classes": [0, 1, 5]}, "5 is not a class of the images"),
    ({"incremental": True, "classes": [0, 1, 1, 2]}, "1 is listed twice"),
    ({"incremental": True, "classes": [0, 1]}, "2 is left out"),
])
def test_fit_refuses_what_the_runner_refuses_before_learning(options, message):
    images = [np.random.default_rng(k).random((32, 32)) for k in range(6)]
    learner = DistinctiveFeatureLearner(seed=0)
    with pytest.raises(InputError, match=message):
        learner.fit(images, [k % 3 for k in range(6)], **options)
    assert learner.presentations == 0


# -- 9. robustness and tradeoff check the images against the run --------------------------------------
def test_images_changed_under_a_run_are_refused_as_resume_refuses_them(tmp_path, capsys):
    data = _folder_data(tmp_path / "data")
    out = tmp_path / "run"
    argv = ["recognize", "--task", "folder", "--data", str(data), "--stages", "0", "--max-cycles", "1", "--folds", "1",
            "--quiet", "--device", "cpu"]
    assert run.main([*argv, "--out", str(out)]) == 0
    mirrored = tmp_path / "mirrored"
    shutil.copytree(data, mirrored)
    for path in mirrored.rglob("*.png"):
        cv2.imwrite(str(path), cv2.imread(str(path), cv2.IMREAD_UNCHANGED)[:, ::-1])
    capsys.readouterr()
    assert exit_code(["robustness", "--run", str(out), "--data", str(mirrored), "--perturb", "clean",
                      "--out", str(tmp_path / "r"), "--device", "cpu", "--quiet"]) == 2
    assert f"these are not the images --run {out} learned and tested on" in one_line(capsys)
    assert exit_code(["tradeoff", "--runs", str(out), "--data", str(mirrored), "--perturb", "clean",
                      "--out", str(tmp_path / "t"), "--device", "cpu", "--quiet"]) == 2
    assert "these are not the images" in one_line(capsys)
    shutil.rmtree(data)
    mirrored.rename(data)  # the run's own --data path, other pixels: --resume refuses too
    assert exit_code([*argv, "--out", str(out), "--resume"]) == 2
    assert "written by a different run configuration" in one_line(capsys)


def test_a_built_in_task_rendered_otherwise_than_for_the_run_is_named_as_such(capsys):
    from training.data.datasets import load_task
    from training.recognition.protocol import same_images
    task = load_task("plym", classes=2, views=2, size=32)
    same_images(task, task.fingerprint, "--run R", None)
    with pytest.raises(InputError, match="the plym task renders other images than those --run R learned"):
        same_images(task, "0" * 32, "--run R", None)
    same_images(task, None, "--run R", None)
    assert "--run R does not record which images it learned from; the plym task" in capsys.readouterr().err


# -- 10. names, labels and files ---------------------------------------------------------------------------
def test_one_name_per_image():
    images = [np.random.default_rng(k).random((32, 32)) for k in range(3)]
    with pytest.raises(InputError, match="3 images but 1 names"):
        ImageSet(images, [0, 1, 0], names=["only one"])
    with pytest.raises(InputError, match="3 images but 1 names"):
        ImageSet(images, [0, 1, 0], names="abc")


def test_numpy_labels_are_their_python_values_and_save(tmp_path):
    images = [np.random.default_rng(k).random((32, 32)) for k in range(4)]
    learner = DistinctiveFeatureLearner(seed=0).fit(images, np.array([0, 1, 0, 1]), stages=0, max_cycles=1)
    assert learner.classes_ == [0, 1] and all(type(c) is int for c in learner.classes_)
    learner.save(tmp_path / "learner.json")
    assert DistinctiveFeatureLearner.load(tmp_path / "learner.json").classes_ == [0, 1]


def test_class_folders_take_every_image_opencv_reads_and_name_what_they_leave_out(tmp_path, capsys):
    from PIL import Image

    from training.data.datasets import folder_task
    rng = np.random.default_rng(0)
    for name in ("a", "b"):
        (tmp_path / name).mkdir()
        Image.fromarray(rng.integers(0, 255, (20, 20), dtype=np.uint8)).save(tmp_path / name / "1.webp")
        Image.fromarray(rng.integers(0, 255, (20, 20), dtype=np.uint8)).save(tmp_path / name / "2.gif")
    (tmp_path / "a" / "notes.txt").write_text("not an image")
    task = folder_task(tmp_path)
    assert task.names == ["a/1.webp", "a/2.gif", "b/1.webp", "b/2.gif"]
    assert all(tuple(task.view(i).shape) == (20, 20) for i in range(4))
    err = capsys.readouterr().err
    assert "1 file(s) in the class folders" in err and "notes.txt" in err


def test_a_class_name_with_a_bar_or_a_newline_keeps_the_tables_whole():
    classes = ["a|b", "line\nbreak"]
    rows = {c: ConfusionRow(recognized_as={k: int(k == c) for k in classes}, ambiguous=0, confused=0, ignorant=0, features=2)
            for c in classes}
    table = confusion_table(rows, classes)
    widths = {len([cell for cell in line.replace("\\|", "").split("|")]) for line in table}
    assert len(widths) == 1 and all("\n" not in line for line in table)
    assert "a\\|b" in table[0] and "line\\x0abreak" in table[0]


# -- 12. output names checked before training -------------------------------------------------------------
def test_a_class_name_too_long_for_its_files_is_refused_before_training(tmp_path, capsys):
    data = _folder_data(tmp_path / "data", classes=("a", "b" * 245))
    start = time.perf_counter()
    assert exit_code(["recognize", "--task", "folder", "--data", str(data), "--out", str(tmp_path / "run"),
                      "--quiet", "--device", "cpu"]) == 2
    message = one_line(capsys)
    assert "has a name of 245 bytes" in message and "at most 255 bytes" in message
    assert time.perf_counter() - start < 30 and not list((tmp_path / "run").glob("fold*"))


def test_a_file_name_near_the_limit_is_written(tmp_path):
    write_text(tmp_path / ("n" * 250 + ".bif"), "x")  # the temporary file's name does not add to it
    assert (tmp_path / ("n" * 250 + ".bif")).read_text() == "x"


# -- 14. devices ---------------------------------------------------------------------------------------------
@pytest.mark.parametrize("learner_class", [DistinctiveFeatureLearner, GraspLearner])
def test_a_device_that_is_not_there_is_one_line(learner_class):
    with pytest.raises(InputError, match="device 'bogus': expected cpu, cuda, cuda:N"):
        learner_class(device="bogus")
    if not torch.cuda.is_available():
        with pytest.raises(InputError, match="device cuda: CUDA is not available on this machine"):
            learner_class(device="cuda")
