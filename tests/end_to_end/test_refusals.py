"""Nothing silently wrong, no traceback, no crash after the work is done: the second round of
careless and hostile inputs (the first is tests/end_to_end/test_hardening.py)."""
import base64
import json
import math
import subprocess
import sys
import time
import tracemalloc
import zlib
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from ftorch import FeatureSpace, InputError, NotFittedError, as_image_batch
from ftorch.checkpoint import MAX_BYTES
from ftorch.recognition.environment import ImageSet
from ftorch.recognition.learner import DistinctiveFeatureLearner
from ftorch.space import record
from tests.conftest import needs_ray
from tests.end_to_end.test_hardening import RUN, exit_code, one_line
from tests.recognition.test_learner import shape, train
from tests.training.test_protocol import make_fold
from training import bench, run
from training.cli import outputs, parallel
from training.data.datasets import load_task, plym_task
from training.data.perturb import save_examples


def _folder(root, classes: dict[str, list[np.ndarray]]):
    for label, images in classes.items():
        (root / label).mkdir(parents=True, exist_ok=True)
        for n, image in enumerate(images):
            cv2.imwrite(str(root / label / f"{n:02d}.png"), image)
    return root


def _plym_folder(root, size: int, classes: int = 2, views: int | None = None):
    task = plym_task(size=size, classes=classes)
    images = {}
    for image, label, position in zip(task.images, task.labels, task.positions):
        if views is None or position < views:
            images.setdefault(label, []).append((image.numpy() * 255).round().astype(np.uint8))
    return _folder(root, images)


# -- 4. an incremental run of two classes has no growth fit -------------------------------------
def test_an_incremental_run_of_two_classes_reports_its_growth_as_not_available(tmp_path, capsys):
    out = tmp_path / "inc"
    argv = ["incremental", "--task", "plym", "--classes", "2", "--views", "4", "--stages", "0", "--folds", "2",
            "--quiet", "--device", "cpu", "--out", str(out)]
    assert run.main(argv) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["growth"]["exponent"] is None and report["growth"]["interval"] == [None, None]
    assert "b = n/a" in (out / "report.md").read_text() and not (out / "growth.png").exists()
    assert run.main([*argv, "--resume"]) == 0


# -- 6. Ray addresses ------------------------------------------------------------------------------
@needs_ray  # without Ray, reach_ray refuses before it tries the address
def test_a_ray_address_that_does_not_answer_is_one_line_not_a_hang(tmp_path):
    done = subprocess.run([sys.executable, "-m", "training.run", *RUN, "--ray", "localhost:1", "--out", str(tmp_path / "r")],
                          capture_output=True, text=True, timeout=300)  # it hung for good before
    assert done.returncode == 2 and done.stderr.count("\n") == 1, done.stderr
    assert done.stderr.startswith("error: --ray localhost:1: cannot reach a Ray cluster there (Connection refused)")


@pytest.mark.parametrize("address", ["bogus::addr", "ray://", "host:99999", "a b:1", "10.0.0.5"])
def test_a_ray_address_of_the_wrong_form_is_refused(address):
    with pytest.raises(InputError, match="expected local, auto, HOST:PORT"):
        parallel.reach_ray(address)


@pytest.mark.parametrize("address", ["local", "auto", "127.0.0.1:6379"])
def test_ray_not_installed_is_refused_among_the_input_checks(address, monkeypatch):
    monkeypatch.setitem(sys.modules, "ray", None)  # import ray raises ImportError
    with pytest.raises(InputError, match=r"^--ray needs Ray: pip install"):
        parallel.reach_ray(address)


@needs_ray  # without Ray, reach_ray refuses before it tries the address
def test_a_far_ray_address_times_out(monkeypatch):
    monkeypatch.setattr(parallel, "CONNECT_TIMEOUT", 0.2)

    def silent(address, timeout):
        time.sleep(timeout)
        raise TimeoutError("timed out")
    monkeypatch.setattr(parallel.socket, "create_connection", silent)
    with pytest.raises(InputError, match=r"^--ray 192.0.2.1:6379: cannot reach a Ray cluster there \(no answer within 0.2 s\)"):
        parallel.reach_ray("192.0.2.1:6379")


# -- 7. images too large for memory ------------------------------------------------------------
def test_images_whose_pyramid_does_not_fit_are_refused_before_any_work(tmp_path, capsys, monkeypatch):
    assert record.free_memory(torch.device("cpu")) > 2**20  # the machine tells
    big = np.zeros((1000, 1000), np.uint8)
    cv2.circle(big, (500, 500), 200, 255, -1)
    data = _folder(tmp_path / "big", {"a": [big, big], "b": [big, big]})
    need = FeatureSpace().pyramid_nbytes([(1000, 1000)] * 4)
    monkeypatch.setattr(record, "free_memory", lambda device: need // 4)  # room for one image
    with pytest.raises(InputError, match=r"^2 images of up to 1000x1000 pixels need 0.\d GiB for their scale-space pyramid"):
        FeatureSpace().records([torch.from_numpy(big).float() / 255] * 2)
    start = time.perf_counter()
    assert exit_code(["recognize", "--task", "folder", "--data", str(data), "--device", "cpu", "--out", str(tmp_path / "o")]) == 2
    assert time.perf_counter() - start < 10
    line = one_line(capsys)
    assert "the 4 images of the task (up to 1000x1000 pixels) need" in line and "--size" in line
    assert exit_code(["recognize", "--task", "folder", "--data", str(data), "--size", "100", "--folds", "1", "--stages", "0",
                      "--max-cycles", "1", "--quiet", "--device", "cpu", "--out", str(tmp_path / "o")]) == 0


# -- 8. a small file cannot make the reader allocate what its structure does not need ------------
def _zeros_bomb(nbytes: int) -> str:
    packer = zlib.compressobj(9)
    chunk = bytes(1 << 20)
    packed = b"".join(packer.compress(chunk) for _ in range(nbytes >> 20)) + packer.flush()
    return base64.b64encode(packed).decode("ascii")


def test_a_compressed_array_larger_than_its_place_is_refused_before_inflating(small_task, tmp_path):
    fold = make_fold(small_task, tmp_path)
    fold.run(max_cycles=1)
    data = json.loads(fold.checkpoint.read_text())
    features = len(data["cache"]["features"])
    rows = 1024  # one block of the value cache, declaring 300 MB where the cache holds a few kB
    data["cache"]["values"] = {"shape": [rows, (300 << 20) // (8 * rows)], "dtype": "<f8", "blocks": [_zeros_bomb(300 << 20)]}
    fold.checkpoint.write_text(json.dumps(data))
    tracemalloc.start()
    try:
        needs = rf"declares shape \(1024, 38400\) where the file's structure needs \({features}, {len(fold.train)}\)"
        with pytest.raises(InputError, match=needs):
            fold.run(max_cycles=1, resume=True)
        assert tracemalloc.get_traced_memory()[1] < 100 << 20
    finally:
        tracemalloc.stop()


def test_a_feature_table_block_declaring_too_much_is_refused_before_inflating():
    from ftorch.space.features import unpack_features
    with pytest.raises(ValueError, match="more than the 67108864 such a text may hold"):
        unpack_features({"blocks": [{"bytes": MAX_BYTES // 2, "data": _zeros_bomb(1 << 20)}]})


# -- 9. a learner recognizes images of the size it learned from ---------------------------------
def test_a_learner_trained_small_evaluates_at_its_size_or_refuses(tmp_path, capsys):
    train_data = _plym_folder(tmp_path / "train", 32)
    assert run.main(["recognize", "--task", "folder", "--data", str(train_data), "--folds", "1", "--stages", "0",
                     "--quiet", "--device", "cpu", "--out", str(tmp_path / "run")]) == 0
    learner = tmp_path / "run" / "fold1" / "learner.json"
    assert json.loads(learner.read_text())["learner"]["sides"] == [32, 32]
    big = _plym_folder(tmp_path / "big", 128)
    common = ["evaluate", "--learner", str(learner), "--task", "folder", "--data", str(big), "--quiet", "--device", "cpu"]
    capsys.readouterr()
    assert run.main([*common, "--out", str(tmp_path / "e1")]) == 0
    assert "note: images area-averaged to the learned shorter side of 32 pixels (--size 32)" in capsys.readouterr().err
    small = json.loads((tmp_path / "e1" / "evaluate.json").read_text())
    assert small["size"] == 32 and small["test"]["accuracy"] > 0.5
    assert exit_code([*common, "--size", "64", "--out", str(tmp_path / "e2")]) == 2
    assert "learned from images whose shorter side is 32 pixels; 30 of these are not within a scale step" in one_line(capsys)


# -- 10, 11. folds and task options --------------------------------------------------------------
def test_a_class_that_a_fold_would_never_train_on_is_refused(tmp_path, capsys):
    data = _plym_folder(tmp_path / "d", 32)
    (data / "lonely").mkdir()
    cv2.imwrite(str(data / "lonely" / "only.png"), cv2.imread(str(next((data / "con6").iterdir())), cv2.IMREAD_GRAYSCALE))
    assert exit_code(["recognize", "--task", "folder", "--data", str(data), "--out", str(tmp_path / "o")]) == 2
    assert "class 'lonely' has only one view: two folds train on alternate views, so fold 2 would never see it" in one_line(capsys)


def test_task_options_apply_to_every_task_and_the_report_records_what_ran(tmp_path, capsys):
    data = _plym_folder(tmp_path / "d", 32, classes=3)
    out = tmp_path / "o"
    assert run.main(["recognize", "--task", "folder", "--data", str(data), "--classes", "2", "--views", "4",
                     "--first-view", "2", "--folds", "1", "--stages", "0", "--quiet", "--device", "cpu",
                     "--out", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    assert report["classes"] == ["con6", "cube"] and report["config"]["views"] == 4
    assert report["folds"][0]["stages"][0]["confusion"]["con6"]["as"]["con6"] <= 2  # two test views per class
    task = load_task("folder", data, 2, 4, first_view=2)
    assert task.names[:4] == ["con6/02.png", "con6/03.png", "con6/04.png", "con6/05.png"] and task.positions[:4] == [0, 1, 2, 3]
    assert load_task("plym", None, 2, 3, 32, first_view=5).positions == [0, 1, 2] * 2
    assert load_task("folder", data, size=16).images[0].shape == (16, 16)
    for argv, message in ((["--task", "plym", "--data", str(data)], "the plym task renders its own images"),
                          (["--task", "plym", "--first-view", "50"], "class 'con6' of the plym task has 15 views; --first-view 50"),
                          (["--task", "folder", "--data", str(data), "--classes", "5"], "--classes 5: the folder task has 3 classes")):
        assert exit_code(["recognize", *argv, "--out", str(tmp_path / "x")]) == 2
        assert message in one_line(capsys)


# -- 12. reports are JSON ----------------------------------------------------------------------
def _strict(text: str):
    def refuse(constant):
        raise ValueError(f"{constant} is not JSON")
    return json.loads(text, parse_constant=refuse)


def test_report_json_holds_null_not_nan(tmp_path, capsys):
    out = tmp_path / "seeds"
    assert run.main([*RUN, "--seeds", "2", "--out", str(out)]) == 0
    report = _strict((out / "report.json").read_text())
    assert report["seeds"]["t"] is None and report["seeds"]["p"] is None
    assert "t = n/a, p = n/a (not available" in (out / "report.md").read_text()
    assert "p = n/a" in capsys.readouterr().out


# -- 13. a flat image is an image without salient points, through every step -------------------
def test_a_flat_image_trains_and_evaluates(tmp_path):
    data = _plym_folder(tmp_path / "d", 32, views=6)
    cv2.imwrite(str(data / "con6" / "99.png"), np.full((32, 32), 90, np.uint8))
    out = tmp_path / "o"
    assert run.main(["recognize", "--task", "folder", "--data", str(data), "--folds", "2", "--stages", "1", "--quiet",
                     "--device", "cpu", "--out", str(out)]) == 0
    assert run.main(["evaluate", "--learner", str(out / "fold2" / "learner.json"), "--task", "folder", "--data", str(data),
                     "--quiet", "--device", "cpu", "--out", str(tmp_path / "e")]) == 0
    images = {r["image"]: r for r in json.loads((tmp_path / "e" / "evaluate.json").read_text())["images"]}
    assert "con6/99.png" in images
    usage = (Path(__file__).parents[2] / "docs" / "usage.md").read_text()  # and the docs say so
    assert "A flat image (one grey level) is an image" in usage and "empty or flat images" not in usage


# -- 14. tracebacks that became one line ---------------------------------------------------------
def test_an_integer_of_5000_digits_in_a_learner_file_is_one_line(tmp_path, capsys):
    path = tmp_path / "learner.json"
    path.write_text('{"format": "ftorch", "kind": "learner", "version": 4, "learner": {"n_ex": ' + "9" * 5000 + "}}")
    assert exit_code(["evaluate", "--learner", str(path), "--task", "folder", "--data", str(tmp_path / "data"),
                      "--out", str(tmp_path / "e")]) == 2
    assert "not a readable checkpoint" in one_line(capsys)


def test_a_learner_with_integer_labels_evaluates_folders_named_by_them(tmp_path):
    rng = np.random.default_rng(0)
    kinds = [i % 3 for i in range(18)]
    env = ImageSet([shape(k, rng.uniform(0, 2 * np.pi), rng) for k in kinds], kinds)  # labels 0, 1, 2: ints
    learner, _ = train(env, seed=4, cycles=6)
    learner.save(tmp_path / "learner.json")
    images = {str(k): [(shape(k, rng.uniform(0, 2 * np.pi), rng) * 255).round().astype(np.uint8) for _ in range(3)]
              for k in range(3)}
    data = _folder(tmp_path / "d", images)
    assert run.main(["evaluate", "--learner", str(tmp_path / "learner.json"), "--task", "folder", "--data", str(data),
                     "--quiet", "--device", "cpu", "--out", str(tmp_path / "e")]) == 0
    result = json.loads((tmp_path / "e" / "evaluate.json").read_text())
    assert result["classes"] == ["0", "1", "2"] and result["test"]["accuracy"] > 0.5


@pytest.mark.parametrize("options, message", [
    ({"seed": 2**70}, "seed must be an integer from 0 to 9223372036854775807, got 1180591620717411303424"),
    ({"seed": -1}, "seed must be an integer from 0"), ({"n_fgen": 2.5}, "n_fgen must be an integer of at least 1, got 2.5"),
    ({"n_ex": True}, "n_ex must be an integer"), ({"redundancy": 0}, "redundancy must be an integer of at least 1"),
])
def test_learner_options_are_whole_numbers_in_range(options, message):
    with pytest.raises(InputError, match=message):
        DistinctiveFeatureLearner.thesis(**options)


def test_a_meta_tensor_is_refused():
    with pytest.raises(InputError, match="a tensor on the meta device holds no pixels"):
        as_image_batch(torch.empty(32, 32, device="meta"))
    with pytest.raises(InputError, match="meta device"):
        ImageSet([torch.empty(32, 32, device="meta")], [{0}])


@pytest.mark.skipif(torch.cuda.is_available(), reason="this machine has CUDA")
def test_the_benchmark_refuses_an_absent_device_and_a_bad_json_path_before_it_runs(tmp_path, capsys, monkeypatch):
    monkeypatch.setattr(bench, "features", lambda args: pytest.fail("the benchmark ran"))
    monkeypatch.setattr(bench, "recognition", lambda args: pytest.fail("the benchmark ran"))
    assert bench.main(["features", "--quick", "--device", "cuda"]) == 2
    assert one_line(capsys) == "error: --device cuda: CUDA is not available on this machine"
    assert bench.main(["recognition", "--quick", "--json", str(tmp_path)]) == 2
    assert one_line(capsys) == f"error: --json {tmp_path}: a folder is there, not a file"

    def read_only(*args, **kwargs):
        raise OSError(30, "Read-only file system")
    monkeypatch.setattr(outputs.tempfile, "TemporaryFile", read_only)
    assert bench.main(["recognition", "--quick", "--json", str(tmp_path / "ro" / "b.json")]) == 2
    assert one_line(capsys) == f"error: --json {tmp_path / 'ro'}: cannot write there (Read-only file system)"


# -- 16. library misuse --------------------------------------------------------------------------
def test_labels_are_whole_values_and_image_positions_are_checked():
    images = [np.asarray(shape(k, 0.3, np.random.default_rng(k))) for k in (0, 1)]
    assert ImageSet(images, ["obj1", "obj2"]).labels == [frozenset({"obj1"}), frozenset({"obj2"})]
    assert ImageSet(images, [1, 2]).labels == [frozenset({1}), frozenset({2})]
    assert ImageSet(images, [{"a", "b"}, ["c"]]).labels == [frozenset({"a", "b"}), frozenset({"c"})]
    assert ImageSet(images, [("x", 1), set()]).labels == [frozenset({("x", 1)}), frozenset()]
    with pytest.raises(InputError, match="labels of image 0: dict is not a label"):
        ImageSet(images, [{"a": 1}, 2])
    env = ImageSet(images, [0, 1])
    learner = DistinctiveFeatureLearner.thesis()
    with pytest.raises(NotFittedError, match="learned no class yet"):
        learner.recognize(env, 0)
    for bad in (-1, 99, 1.0, True):
        with pytest.raises(InputError, match=rf"image {bad!r}: expected a position in this image set, an integer from 0 to 1"):
            learner.learn(env, bad)
    assert learner.presentations == 0
    learner.learn(env, 0)
    for bad in (-1, 99, 1.0, True):
        with pytest.raises(InputError, match="expected a position in this image set"):
            learner.recognize(env, bad)


def test_an_entry_that_holds_several_images_is_refused_and_chw_colour_is_one_image():
    rgb = torch.rand(3, 24, 28)
    [grey] = ImageSet([rgb], [{0}]).images
    assert torch.allclose(grey, (rgb * torch.tensor([0.299, 0.587, 0.114])[:, None, None]).sum(0))
    assert torch.equal(ImageSet([rgb.permute(1, 2, 0)], [{0}]).images[0], grey)  # (H, W, C) as well
    for many in (torch.rand(2, 1, 24, 28), torch.rand(4, 24, 28), np.zeros((2, 24, 28), np.float32)):
        with pytest.raises(InputError, match=r"expected one image, got shape .*, which holds [24]"):
            ImageSet([many], [{0}])
        with pytest.raises(InputError, match="expected one image"):
            FeatureSpace().records([many])


# -- minor -------------------------------------------------------------------------------------------
def test_perturbed_images_keep_one_image_suffix(tmp_path):
    paths = save_examples([torch.rand(20, 20)] * 2, ["cls/a.png", "obj1__3"], tmp_path)
    assert [p.name for p in paths] == ["cls_a.png", "obj1__3.png"] and all(p.is_file() for p in paths)


def test_not_available_numbers_are_null_in_every_written_report(tmp_path):
    from training.recognition.report import write_json
    write_json(tmp_path / "r.json", {"a": math.nan, "b": [math.inf, 1.5], "c": {"d": -math.inf}})
    assert _strict((tmp_path / "r.json").read_text()) == {"a": None, "b": [None, 1.5], "c": {"d": None}}
