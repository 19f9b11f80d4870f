"""First contact and careless use: every bad input is one clear line, and nothing is lost."""
import errno
import json
import math
import os
import signal
import stat
import subprocess
import sys
import time
import zipfile

import cv2
import numpy as np
import pytest
import torch

from ftorch import FeatureSpace, InputError, as_image_batch
from ftorch.checkpoint import decode_array, encode_array, write_atomic
from ftorch.recognition.bayes import ClassNetwork
from ftorch.recognition.environment import ImageSet
from ftorch.recognition.learner import DistinctiveFeatureLearner
from tests.recognition.test_learner import shape, train
from tests.training.test_protocol import make_fold
from training import run
from training.cli import outputs
from training.data import coil
from training.data.datasets import coil_task


def exit_code(argv) -> int:
    """run.main's exit code, also where argparse itself refuses an option (SystemExit)."""
    try:
        return run.main(argv)
    except SystemExit as done:
        return done.code


def one_line(capsys) -> str:
    err = capsys.readouterr().err.strip()
    assert err.startswith("error:") and "\n" not in err and "Traceback" not in err, err
    return err


# -- 1. flat images ------------------------------------------------------------------------------
def test_flat_images_have_no_salient_points_and_a_black_image_alone_works():
    space = FeatureSpace()
    for value in (0.0, 0.5, 1.0):
        records = space.records([torch.full((48, 48), value)])  # alone in its batch
        assert int(records.mask.sum()) == 0 and records.canonical.shape[:2] == (1, 0)
    dot = torch.full((48, 48), 128 / 255)
    dot[24, 24] = 129 / 255  # one grey level: the weakest structure an 8-bit image can show
    assert int(space.records([dot]).mask.sum()) > 0


def test_salient_command_on_a_black_file(tmp_path, capsys):
    cv2.imwrite(str(tmp_path / "black.png"), np.zeros((64, 64), np.uint8))
    assert run.main(["salient", str(tmp_path / "black.png"), "--out", str(tmp_path / "out"), "--device", "cpu"]) == 0
    assert "0 edgels, 0 texels" in capsys.readouterr().out


# -- 2. learner files are validated field by field ----------------------------------------------
@pytest.fixture(scope="module")
def saved(tmp_path_factory):
    rng = np.random.default_rng(0)
    kinds = [i % 3 for i in range(18)]
    env = ImageSet([shape(k, rng.uniform(0, 2 * np.pi), rng) for k in kinds], [{k} for k in kinds])
    learner, _ = train(env, seed=4, cycles=2)
    path = tmp_path_factory.mktemp("learner") / "learner.json"
    learner.save(path, training=True)
    return json.loads(path.read_text())


def _cpt(net: dict, change) -> None:
    table = decode_array(net["cpt"][0])
    change(table)
    net["cpt"][0] = encode_array(table)


DAMAGE = {
    "NaN threshold": lambda s: s["networks"][0]["threshold"].__setitem__(0, math.nan),
    "infinite threshold": lambda s: s["networks"][0]["threshold"].__setitem__(0, math.inf),
    "threshold above 1": lambda s: s["networks"][0]["threshold"].__setitem__(0, 1.5),
    "CPT entry above 1": lambda s: _cpt(s["networks"][0], lambda t: t.__setitem__((0,) * t.ndim, 1.2)),
    "CPT not summing to 1": lambda s: _cpt(s["networks"][0], lambda t: t.__imul__(0.5)),
    "NaN in a CPT": lambda s: _cpt(s["networks"][0], lambda t: t.__setitem__((1,) * t.ndim, math.nan)),
    "negative feature index": lambda s: s["networks"][0]["features"].__setitem__(0, -1),
    "feature index past the table": lambda s: s["networks"][0]["features"].__setitem__(0, 10**6),
    "prior of length 3": lambda s: s["networks"][0].__setitem__("prior", [0.2, 0.3, 0.5]),
    "prior not summing to 1": lambda s: s["networks"][0].__setitem__("prior", [0.7, 0.7]),
    "a threshold missing": lambda s: s["networks"][0]["threshold"].pop(),
    "arc from itself": lambda s: s["networks"][0]["parents"].__setitem__(0, [s["networks"][0]["features"][0]]),
    "two networks for a class": lambda s: s["networks"].append(s["networks"][0]),
    "negative presentations": lambda s: s.__setitem__("presentations", -3),
    "instance value above 1": lambda s: s["instances"].__setitem__("values", encode_array(
        np.where(np.isnan(decode_array(s["instances"]["values"])), np.nan, 2.0))),
    "usage by a negative index": lambda s: s["usage"].append([-2, 1]),
    "an instance feature listed twice": lambda s: s["instances"]["features"].__setitem__(1, s["instances"]["features"][0]),
    "an image listed twice": lambda s: s["instances"]["images"].__setitem__(1, s["instances"]["images"][0]),
    "a network feature listed twice": lambda s: s["networks"][0]["features"].append(s["networks"][0]["features"][0]),
    "threshold as a string": lambda s: s["networks"][0]["threshold"].__setitem__(0, "0.5"),
    "a huge integer in the prior": lambda s: s["networks"][0]["prior"].__setitem__(0, 10**400),
    "a CPT of impossible shape": lambda s: s["networks"][0]["cpt"][0].__setitem__("shape", [1e999, 2]),
    "n_ex not an integer": lambda s: s.__setitem__("n_ex", 5.7),
    "a recognition file without a network": lambda s: (s.__setitem__("networks", []), s.pop("instances")),
}


@pytest.mark.parametrize("damage", DAMAGE)
def test_every_damaged_field_of_a_learner_file_is_refused(saved, damage, tmp_path, capsys):
    data = json.loads(json.dumps(saved))
    DAMAGE[damage](data["learner"])
    path = tmp_path / "learner.json"
    path.write_text(json.dumps(data))
    with pytest.raises(InputError, match="damaged learner checkpoint"):
        DistinctiveFeatureLearner.load(path)
    assert run.main(["evaluate", "--learner", str(path), "--data", str(tmp_path / "data"), "--out", str(tmp_path / "e")]) == 2
    assert "damaged learner checkpoint" in one_line(capsys)


def test_the_undamaged_file_loads(saved, tmp_path):
    path = tmp_path / "learner.json"
    path.write_text(json.dumps(saved))
    assert DistinctiveFeatureLearner.load(path).state_dict() == saved["learner"]


def test_network_validation_agrees_with_pgmpy(saved):
    learner = DistinctiveFeatureLearner.thesis()
    learner.load_state_dict(saved["learner"])
    for net in learner.networks.values():
        net.validate()
        assert net.to_pgmpy().check_model()
    net = next(n for n in learner.networks.values() if n.features)
    net.set_cpt(net.features[0], net.cpt[net.features[0]] * 0.9)  # rows sum to 0.9: only a loader's check finds it
    with pytest.raises(ValueError, match="does not sum to 1"):
        net.validate()
    with pytest.raises(ValueError, match="(?i)sum"):
        net.to_pgmpy().check_model()


def test_a_cycle_is_refused():
    table = np.full((2, 2, 2), 0.5)
    with pytest.raises(ValueError, match="cycle"):  # as a damaged file could say
        ClassNetwork.of("a", ["f", "g"], [["g"], ["f"]], [0.5, 0.5], [0.5, 0.5], [table, table])


# -- 4. outputs are checked first, runs never mixed, writes atomic and by the umask --------------
@pytest.mark.parametrize("argv", [
    ["salient"], ["evaluate", "--learner", "/nonexistent.json", "--data", "."], ["recognize"], ["grasp"],
    ["robustness", "--run", "/nonexistent"]])
def test_an_output_that_is_a_file_is_refused_before_any_work(argv, tmp_path, capsys):
    target = tmp_path / "taken"
    target.write_text("a file")
    assert exit_code([*argv, "--out", str(target)]) == 2
    assert one_line(capsys) == f"error: --out {target}: a file is there, not a folder"


def test_an_unwritable_output_is_refused(tmp_path, capsys, monkeypatch):
    def read_only(*args, **kwargs):
        raise OSError(errno.EROFS, "Read-only file system")
    monkeypatch.setattr(outputs.tempfile, "TemporaryFile", read_only)
    assert run.main(["salient", "--out", str(tmp_path / "out")]) == 2
    assert one_line(capsys) == f"error: --out {tmp_path / 'out'}: cannot write there (Read-only file system)"


def test_a_full_disk_is_one_line_and_keeps_the_old_file(tmp_path, capsys, monkeypatch):
    out = tmp_path / "out"
    assert run.main(["salient", "--out", str(out), "--device", "cpu"]) == 0
    before = (out / "salient.json").read_bytes()
    capsys.readouterr()

    def full(source, target):
        raise OSError(errno.ENOSPC, "No space left on device", str(target))
    monkeypatch.setattr("ftorch.checkpoint.os.replace", full)
    assert run.main(["salient", "--out", str(out), "--device", "cpu"]) == 2
    assert one_line(capsys).endswith("No space left on device")
    assert (out / "salient.json").read_bytes() == before
    assert not [p for p in out.iterdir() if p.name.endswith(".tmp")]  # no temporary file left


RUN = ["recognize", "--classes", "2", "--folds", "1", "--stages", "0", "--max-cycles", "1", "--quiet", "--device", "cpu"]


def test_a_folder_that_holds_a_run_is_refused_resumed_or_overwritten(tmp_path, capsys):
    out = tmp_path / "run"
    assert run.main([*RUN, "--out", str(out)]) == 0
    report = (out / "report.json").read_text()
    events = len(list((out / "tensorboard" / "fold1").iterdir()))
    (out / "notes.txt").write_text("mine")
    capsys.readouterr()
    assert run.main([*RUN, "--out", str(out)]) == 2
    assert "already holds a run" in one_line(capsys) and (out / "report.json").read_text() == report
    assert run.main([*RUN, "--out", str(out), "--overwrite", "--resume"]) == 2
    assert run.main([*RUN, "--out", str(out), "--overwrite"]) == 0
    assert (out / "notes.txt").read_text() == "mine"  # only what runs write is replaced
    assert len(list((out / "tensorboard" / "fold1").iterdir())) == events  # one run's events, not two runs'
    logs = tmp_path / "logs"  # a log folder of the user's own, beside --out
    for mine in ("report.md", "seed_notes.txt", "fold_important/a.txt", "tensorboard/keep.txt"):
        (logs / mine).parent.mkdir(parents=True, exist_ok=True)
        (logs / mine).write_text("mine")
    assert run.main([*RUN, "--out", str(out), "--logdir", str(logs), "--overwrite"]) == 0
    assert run.main([*RUN, "--out", str(out), "--logdir", str(logs), "--overwrite"]) == 0
    assert all((logs / mine).read_text() == "mine" for mine in ("report.md", "seed_notes.txt", "fold_important/a.txt",
                                                                "tensorboard/keep.txt"))
    assert len(list((logs / "fold1").iterdir())) == events
    capsys.readouterr()
    assert run.main([*RUN, "--out", str(tmp_path / "fresh"), "--resume"]) == 0
    assert f"note: no checkpoint in {tmp_path / 'fresh'}; --resume starts afresh" in capsys.readouterr().err


def test_damaged_fields_of_a_fold_checkpoint_are_refused_on_resume(small_task, tmp_path):
    fold = make_fold(small_task, tmp_path)
    fold.run(max_cycles=1)
    good = json.loads(fold.checkpoint.read_text())

    def cache_above_one(data):
        values = decode_array(data["cache"]["values"])
        data["cache"]["values"] = encode_array(np.where(np.isnan(values), np.nan, 3.0))

    for damage in (lambda d: d["state"].__setitem__("t_ksd", 7.0),
                   lambda d: d["cache"]["features"].__setitem__(1, d["cache"]["features"][0]),
                   lambda d: d["state"].__setitem__("stage", -1),
                   lambda d: d["state"].__setitem__("done", "no"), cache_above_one,
                   lambda d: d["learner"]["networks"][0]["threshold"].__setitem__(0, math.nan)):
        data = json.loads(json.dumps(good))
        damage(data)
        fold.checkpoint.write_text(json.dumps(data))
        with pytest.raises(InputError, match="damaged"):
            fold.run(max_cycles=1, resume=True)


@pytest.mark.parametrize("umask", [0o022, 0o077])
def test_files_are_written_by_the_umask(tmp_path, umask):
    old = os.umask(umask)
    try:
        written = write_atomic(tmp_path / "a.bin", b"data")
    finally:
        os.umask(old)
    assert stat.S_IMODE(written.stat().st_mode) == 0o666 & ~umask


# -- 5. options that used to crash ---------------------------------------------------------------
@pytest.mark.parametrize("argv, message", [
    (["recognize", "--seed", str(2**63 - 1)], "--seed: 9223372036854775807: expected a seed, 0 to 2147483647"),
    (["grasp", "--seed", "-1"], "--seed: -1: expected a seed"),
    (["recognize", "--seed", str(2**31 - 1), "--seeds", "2"], "the last seed would pass 2147483647"),
    (["recognize", "--size", "0"], "--size: 0: expected an image side in pixels"),
    (["salient", "--device", "meta"], "--device 'meta': expected cpu, cuda, cuda:N or auto"),
    (["salient", "--device", "cpu:3"], "expected cpu, cuda, cuda:N or auto"),
    (["recognize", "--stages", "²"], "--stages '²': expected a number of expert stages"),
    (["recognize", "--seeds", "²"], "--seeds: '²': expected a number of seeds"),
    (["recognize", "--pseudocount", "nan"], "--pseudocount: 'nan': expected a finite number"),
    (["recognize", "--folds", "3"], "--folds: invalid choice: 3"),
])
def test_options_that_crashed_are_one_line(argv, message, tmp_path, capsys):
    assert exit_code([*argv, "--out", str(tmp_path / "out")]) == 2
    assert message in one_line(capsys)


def test_an_interrupted_run_says_where_to_resume(tmp_path):
    out = tmp_path / "run"
    argv = [sys.executable, "-m", "training.run", "recognize", "--classes", "3", "--folds", "1", "--quiet",
            "--device", "cpu", "--checkpoint-every", "0", "--out", str(out)]
    child = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    while not (out / "fold1" / "checkpoint.json").is_file() and time.monotonic() < deadline and child.poll() is None:
        time.sleep(0.05)
    child.send_signal(signal.SIGINT)
    _, err = child.communicate(timeout=60)
    assert child.returncode == 130, err
    assert err.strip() == (f"interrupted; the checkpoints in {out} keep the cycles finished up to their last write: "
                           "run the same command with --resume to continue")
    done = subprocess.run([*argv, "--resume"], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr


def test_sigterm_stops_the_runner_and_its_workers(tmp_path):
    """A scheduler's SIGTERM to the runner alone (not its process group) ends the run as Ctrl-C
    does, and takes the --workers processes with it instead of waiting for their tasks."""
    out = tmp_path / "run"
    argv = [sys.executable, "-m", "training.run", "recognize", "--quiet", "--device", "cpu",  # the default job
            "--workers", "2", "--checkpoint-every", "0", "--out", str(out)]
    child = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 180
    while not all((out / f"fold{k}" / "checkpoint.json").is_file() for k in (1, 2)) and time.monotonic() < deadline \
            and child.poll() is None:
        time.sleep(0.05)
    workers = [int(p) for p in subprocess.run(["pgrep", "-P", str(child.pid)], capture_output=True,
                                              text=True).stdout.split()]
    assert child.poll() is None and len(workers) >= 2  # two workers (and the resource tracker) at work
    child.send_signal(signal.SIGTERM)
    _, err = child.communicate(timeout=20)  # the folds' tasks have a minute or more to go
    assert child.returncode == 130 and err.strip().startswith("interrupted; the checkpoints in"), err

    def alive(pid):
        try:
            with open(f"/proc/{pid}/stat") as stat_file:
                return stat_file.read().split(")")[-1].split()[0] != "Z"  # a zombie has ended
        except FileNotFoundError:
            return False

    deadline = time.monotonic() + 15
    while any(alive(p) for p in workers) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not any(alive(p) for p in workers)


# -- 6. finding images ---------------------------------------------------------------------------
def _coil_views(folder, names):
    folder.mkdir(parents=True, exist_ok=True)
    for name in names:
        cv2.imwrite(str(folder / name), np.random.default_rng(len(name)).integers(0, 255, (32, 32), dtype=np.uint8))


def test_coil_files_in_any_case_and_behind_links_and_duplicates_named(tmp_path):
    _coil_views(tmp_path / "real", ["obj1__0.PNG", "obj1__1.png"])
    _coil_views(tmp_path / "other", ["obj2__0.png", "obj2__1.Png"])
    root = tmp_path / "root"
    root.mkdir()
    (root / "a").symlink_to(tmp_path / "real", target_is_directory=True)
    (root / "b").symlink_to(tmp_path / "other", target_is_directory=True)
    (root / "a" / "loop").symlink_to(root, target_is_directory=True)  # a link cycle ends
    task = coil_task(root, classes=2, views=2)
    assert task.names == ["obj1__0", "obj1__1", "obj2__0", "obj2__1"]
    _coil_views(tmp_path / "other", ["obj1__1.png"])
    with pytest.raises(InputError, match=r"obj1__1 is there twice: .*obj1__1.png and .*obj1__1.png; keep one"):
        coil_task(root, classes=2, views=2)


def test_salient_keeps_one_figure_per_image_of_the_same_name(tmp_path, capsys):
    for folder in ("a", "b"):
        _coil_views(tmp_path / folder, ["x.png"])
    assert run.main(["salient", str(tmp_path / "a/x.png"), str(tmp_path / "b/x.png"), "--out", str(tmp_path / "o")]) == 0
    figures = [row["figure"] for row in json.loads((tmp_path / "o" / "salient.json").read_text())]
    assert len(set(figures)) == 2 and all(os.path.isfile(f) for f in figures)
    _coil_views(tmp_path, ["1-x.png"])
    capsys.readouterr()
    assert run.main(["salient", str(tmp_path / "a/x.png"), str(tmp_path / "b/x.png"), str(tmp_path / "1-x.png"),
                     "--out", str(tmp_path / "o3")]) == 0
    assert len(set(row["figure"] for row in json.loads((tmp_path / "o3" / "salient.json").read_text()))) == 3


def test_a_too_small_image_is_named_by_its_file(tmp_path):
    _coil_views(tmp_path, ["big.png"])
    cv2.imwrite(str(tmp_path / "small.png"), np.zeros((5, 40), np.uint8))
    with pytest.raises(InputError, match=rf"^{tmp_path / 'small.png'}: image of 5x40 pixels is too small"):
        ImageSet([tmp_path / "big.png", tmp_path / "small.png"], [{0}, {1}])
    with pytest.raises(InputError, match=r"^small view: image of 5x40 pixels"):
        ImageSet([torch.rand(32, 32), torch.zeros(5, 40)], [{0}, {1}], names=["big view", "small view"])


# -- 7. colour arrays as PIL and matplotlib give them --------------------------------------------
def test_colour_arrays_in_hwc_order_are_one_image():
    rgb = np.random.default_rng(0).integers(0, 255, (20, 30, 3), dtype=np.uint8)
    expected = as_image_batch(torch.from_numpy(rgb).permute(2, 0, 1)[None])
    assert torch.equal(as_image_batch(rgb), expected)
    rgba = np.concatenate([rgb, np.full((20, 30, 1), 7, np.uint8)], axis=2)
    assert torch.equal(as_image_batch(rgba), expected)  # alpha dropped
    assert as_image_batch(np.zeros((5, 20, 30), np.uint8)).shape == (5, 1, 20, 30)  # a grey batch stays one
    assert as_image_batch(rgb[..., :1]).shape == (1, 1, 20, 30)  # (H, W, 1): one grey image
    assert FeatureSpace().records(rgb).canonical.shape[0] == 1  # one array given alone is its images, not its rows


# -- 8. getting COIL-20 ---------------------------------------------------------------------------
def _archive(path, skip=(), extra=()):
    rng = np.random.default_rng(0)
    with zipfile.ZipFile(path, "w") as zipped:
        for k in range(1, 21):
            for v in range(72):
                if (k, v) not in skip:
                    pixels = rng.integers(0, 255, (128, 128), dtype=np.uint8)
                    zipped.writestr(f"coil-20-proc/obj{k}__{v}.png", cv2.imencode(".png", pixels)[1].tobytes())
        for name, data in extra:
            zipped.writestr(name, data)
    return path


def test_the_coil_folder_is_prepared_from_the_official_archive(tmp_path, capsys):
    archive = _archive(tmp_path / "coil-20-proc.zip", extra=[("coil-20-proc/README.txt", "x")])
    assert coil.main([str(archive), "--out", str(tmp_path / "coil")]) == 0
    assert "1440 COIL-20 images" in capsys.readouterr().out
    with zipfile.ZipFile(archive) as zipped:
        original = cv2.imdecode(np.frombuffer(zipped.read("coil-20-proc/obj7__33.png"), np.uint8), cv2.IMREAD_UNCHANGED)
    assert np.array_equal(cv2.imread(str(tmp_path / "coil" / "obj7__33.png"), cv2.IMREAD_UNCHANGED), original)
    assert len(coil_task(tmp_path / "coil", classes=20, views=72).images) == 1440
    assert coil.main([str(archive), "--out", str(tmp_path / "small"), "--size", "32"]) == 0
    assert cv2.imread(str(tmp_path / "small" / "obj1__0.png"), cv2.IMREAD_UNCHANGED).shape == (32, 32)


def test_a_wrong_archive_is_refused_and_writes_nothing(tmp_path, capsys):
    cases = {
        "missing.zip": (_archive(tmp_path / "missing.zip", skip={(3, 5)}), "1 of the 1440 missing (e.g. obj3__5.png)"),
        "hostile.zip": (_archive(tmp_path / "hostile.zip", skip={(1, 0)}, extra=[("../../obj1__0.png", b"x")]),
                        "is not a 128x128 8-bit grey image"),
        "corrupt.zip": (tmp_path / "corrupt.zip", "not a readable zip archive"),
    }
    (tmp_path / "corrupt.zip").write_bytes(b"PK\x03\x04 not really")
    for name, (archive, message) in cases.items():
        out = tmp_path / f"out-{name}"
        assert coil.main([str(archive), "--out", str(out)]) == 2
        assert message in one_line(capsys) and not out.exists()
    assert not (tmp_path.parent / "obj1__0.png").exists()
