"""Augmented training views (--augment): seeded, of the stated families, never the benchmark's photographs."""
import json

import numpy as np
import pytest
import torch

from ftorch.recognition.settings import LearnerSettings
from tests.training.test_robustness import views
from training.data import perturb
from training.data.augment import augment, overview, texture


def occluded(image: torch.Tensor) -> bool:
    """A grey square leaves one exact grey level on many pixels; the objects and the clutter are smooth-valued."""
    values, counts = torch.unique(image[image > 0], return_counts=True)
    return bool(len(counts)) and int(counts.max()) >= 50


def cluttered(image: torch.Tensor) -> bool:
    """Without clutter, over half of a copy stays exactly black (the 40 x 40 object fills 39 % of 64 x 64)."""
    return float((image == 0).float().mean()) < 0.2


def test_copies_reproduce_from_seed_and_fold_and_mix_the_families(monkeypatch):
    images, labels = views()
    monkeypatch.setattr(perturb, "_textures", lambda: pytest.fail("augmentation used the benchmark's photographs"))
    a, la = augment(images, labels, 4, seed=3, fold=1)
    b, _ = augment(images, labels, 4, seed=3, fold=1)
    c, _ = augment(images, labels, 4, seed=3, fold=2)
    assert len(a) == 4 * len(images) and la == labels * 4
    assert all(torch.equal(x, y) for x, y in zip(a, b))
    assert not any(torch.equal(x, y) for x, y in zip(a, c))
    assert all(x.shape == images[0].shape and x.dtype == images[0].dtype for x in a)
    assert not any(torch.equal(x, image) for x, image in zip(a, images * 4))  # every copy is rotated and scaled
    for x, image in zip(a, images * 4):  # the scale is at most 1: no more object than before, unless occluded
        assert cluttered(x) or occluded(x) or (x > 0).sum() <= (image > 0).sum() * 1.05
    occ, clut = [occluded(x) for x in a], [cluttered(x) for x in a]
    assert 0.3 < np.mean(occ) < 0.7 and 0.3 < np.mean(clut) < 0.7
    assert {(o, k) for o, k in zip(occ, clut)} == {(False, False), (False, True), (True, False), (True, True)}
    assert augment(images, labels, 0, seed=3, fold=1) == ([], [])


def test_procedural_texture_lies_in_the_stated_range_and_differs_per_draw():
    rng = np.random.default_rng(0)
    draws = [texture(rng, 48, 64) for _ in range(20)]
    for t in draws:
        assert t.shape == (48, 64) and t.dtype == np.float32 and t.min() >= 0 and t.max() <= 1
        assert 0.25 < t.mean() < 0.75 and t.std() > 0.05
    assert not np.array_equal(draws[0], draws[1])


def test_runner_trains_on_the_copies_beside_the_originals(tmp_path, capsys):
    from training import run
    from training.data.datasets import plym_task

    args = ["recognize", "--task", "plym", "--classes", "2", "--size", "32", "--stages", "0", "--folds", "1",
            "--max-cycles", "2", "--quiet", "--device", "cpu"]
    assert run.main([*args, "--augment", "2", "--out", str(tmp_path / "a")]) == 0
    report = json.loads((tmp_path / "a" / "report.json").read_text())
    stage = report["folds"][0]["stages"][-1]
    train, test = plym_task(size=32, seed=0, classes=2).fold(1)
    assert report["config"]["augment"] == 2
    assert (tmp_path / "a" / "fold1" / "augmented.png").is_file() and "fold1/augmented.png" in (tmp_path / "a" / "report.md").read_text()
    assert stage["presentations"] == stage["cycles"] * 3 * len(train)  # originals and two copies each
    assert sum(sum(r["as"].values()) + r["ambiguous"] + r["confused"] + r["ignorant"]
               for r in stage["confusion"].values()) == len(test)  # test views are not augmented
    capsys.readouterr()
    with pytest.raises(SystemExit) as refused:
        run.main([*args, "--augment", "-1", "--out", str(tmp_path / "b")])
    err = capsys.readouterr().err.strip().splitlines()
    assert refused.value.code == 2 and len(err) == 1 and err[0].startswith("error:")
    assert not (tmp_path / "b").exists()


def test_overview_shows_each_class_first_view_beside_its_copies():
    from ftorch.recognition.environment import ImageSet

    images, labels = views(shifts=range(2))
    copies, true = augment(images, labels, 2, seed=0, fold=1)
    env = ImageSet(images + copies, labels + true, names=[f"v{i}" for i in range(3 * len(images))])
    picture = overview(env, len(images), "test")
    # 64-pixel views are repeated 2x (to at least 96 pixels), under a 22-pixel title
    assert picture.dtype == np.uint8 and picture.shape[2] == 3
    assert picture.shape[1] == 3 * 128 + 2 * 6  # one column per class, 6-pixel gaps
    assert picture.shape[0] == 22 + 3 * (128 + 22) + 2 * 6  # the heading, then the originals and two rows of copies
    top_left = picture[22 + 22:22 + 150, :128, 0]  # the first original, enlarged 2x: every second pixel
    assert np.array_equal(top_left[::2, ::2], (images[0].numpy() * 255).round().astype(np.uint8))
    beside = picture[22 + 22:22 + 150, 134:262, 0]  # beside it: the next class's first view (images 2, 3 are c1)
    assert np.array_equal(beside[::2, ::2], (images[2].numpy() * 255).round().astype(np.uint8))


class _Recorder:
    """A stand-in learner for one cycle: it records what is presented and judged, fails every
    presentation, and recognizes the views listed in ``right`` correctly when judging."""

    settings = LearnerSettings(min_information=0.1)

    def __init__(self, right):
        self.shown, self.judged, self.right = [], [], set(right)
        self.presentations, self.networks = 0, {}

    def learn(self, env, image, t_ksd):
        from ftorch.recognition.inference import Recognition, Result
        from ftorch.recognition.learning import Presentation

        self.shown.append(image)
        self.presentations += 1
        return Presentation(Recognition({}, set()), Result.FAILED, {})

    def present(self, env, images, t_ksd):
        return [self.learn(env, i, t_ksd) for i in images]

    def discard_unused(self, since):
        return []

    def recognitions(self, env, images, threshold, top=False):  # learning's judging recognitions (no top label)
        from ftorch.recognition.inference import Recognition

        self.judged.append((list(images), threshold))
        return [Recognition({}, set(env.labels[i]) if i in self.right else set()) for i in images]


@pytest.mark.parametrize("right", [range(6), range(4)])
def test_dynamic_views_present_one_version_of_each_original_and_judge_mistakes_on_the_originals(tmp_path, right):
    from ftorch.recognition.environment import ImageSet
    from training.recognition.protocol import Fold, RunConfig

    images, labels = views(shifts=range(2))
    copies, true = augment(images, labels, 2, seed=0, fold=1)
    train = ImageSet(images + copies, labels + true)
    config = RunConfig("test", augment=2, dynamic=True)
    fold = Fold(1, train, train, config, tmp_path, ["c0", "c1", "c2"], progress=False)
    learner, order = _Recorder(right), torch.Generator().manual_seed(0)
    schedule = fold.schedule(learner, order, 0, 20)
    shown = []
    for _ in range(6):
        cycle = schedule._cycle(list(range(len(train))))
        shown.append(learner.shown[-6:])
        # every presentation failed, yet mistakes count only the originals recognized wrongly, as learning recognizes
        assert cycle.mistakes == 6 - len(right)
        assert learner.judged[-1] == (list(range(6)), 0.1)
    for cycle in shown:
        assert len(cycle) == 6 and sorted(i % 6 for i in cycle) == list(range(6))  # each original once, as some version
    drawn = [i // 6 for cycle in shown for i in cycle]
    assert set(drawn) == {0, 1, 2}  # the original and both copies are drawn
    assert len(learner.shown) == 36 and learner.presentations == 36


def test_runner_dynamic_views_need_copies_and_present_as_many_as_the_originals(tmp_path, capsys):
    from training import run
    from training.data.datasets import plym_task

    args = ["recognize", "--task", "plym", "--classes", "2", "--size", "32", "--stages", "0", "--folds", "1",
            "--max-cycles", "2", "--quiet", "--device", "cpu"]
    assert run.main([*args, "--augment", "2", "--dynamic", "--out", str(tmp_path / "a")]) == 0
    report = json.loads((tmp_path / "a" / "report.json").read_text())
    stage = report["folds"][0]["stages"][-1]
    train, _ = plym_task(size=32, seed=0, classes=2).fold(1)
    assert report["config"]["augment"] == 2 and report["config"]["dynamic"] is True
    assert stage["presentations"] == stage["cycles"] * len(train)
    capsys.readouterr()
    assert run.main([*args, "--dynamic", "--out", str(tmp_path / "b")]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and "--augment" in err[0]
    assert not (tmp_path / "b").exists()
