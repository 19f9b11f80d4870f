"""Robustness benchmark (7.2): seeded perturbations of test views and the baseline classifiers."""
import json
import math

import cv2
import numpy as np
import pytest
import torch

from ftorch.errors import InputError
from tests.conftest import random_image
from training.data.perturb import GREY, KINDS, mask, perturb, save_examples
from training.recognition.peers import PixelNN, SiftMatcher, score, score_ranked

SHIFTS = [(0, 0), (2, 1), (-1, 3), (3, -2)]


def view(cls: int, shift: int = 0, size: int = 64, corner: tuple[int, int] = (12, 12)) -> torch.Tensor:
    """A COIL-like view: class ``cls``'s textured 40 x 40 object on black, shifted by SHIFTS[shift]."""
    pattern = random_image(40, 40, seed=100 + cls, dtype=torch.float32)
    pattern = 0.2 + 0.8 * (pattern - pattern.min()) / (pattern.max() - pattern.min())
    top, left = corner[0] + SHIFTS[shift][0], corner[1] + SHIFTS[shift][1]
    image = torch.zeros(size, size)
    image[top:top + 40, left:left + 40] = pattern
    return image


def views(shifts=range(4), classes=range(3)):
    images = [view(c, s) for c in classes for s in shifts]
    labels = [frozenset({f"c{c}"}) for c in classes for _ in shifts]
    return images, labels


def test_perturbations_reproduce_from_the_seed_and_keep_shapes_and_labels():
    images, labels = views()
    for kind in KINDS:
        a, la = perturb(images, labels, kind, seed=3)
        b, lb = perturb(images, labels, kind, seed=3)
        c, _ = perturb(images, labels, kind, seed=4)
        assert len(a) == len(images) and la == lb
        assert all(torch.equal(x, y) for x, y in zip(a, b)), kind
        assert any(not torch.equal(x, y) for x, y in zip(a, c)), kind
        if kind == "pair":
            assert all(x.shape == (64, 128) for x in a)
            for i, (x, true) in enumerate(zip(a, la)):
                assert len(true) == 2 and labels[i] < true
                assert torch.equal(x[:, :64], images[i])
                partners = [j for j in range(len(images)) if torch.equal(x[:, 64:], images[j])]
                assert partners and labels[partners[0]] == true - labels[i]
        else:
            assert all(x.shape == y.shape and x.dtype == y.dtype for x, y in zip(a, images)) and la == labels


def test_rotate_keeps_the_mass_within_the_scale_bounds_and_turns_about_the_centre_by_spread_angles():
    image = torch.zeros(64, 64)
    image[36:46, 30:50] = 1.0  # centroid (40.5, 39.5), off the centre (31.5, 31.5)
    rotated, _ = perturb([image] * 40, [frozenset({"a"})] * 40, "rotate", seed=0)
    rows, cols = torch.meshgrid(torch.arange(64.0), torch.arange(64.0), indexing="ij")
    radius, angles = math.hypot(9, 8), []
    for x in rotated:
        mass = float(x.sum())
        assert 0.75 ** 2 * 200 * 0.95 <= mass <= 200 * 1.05
        dy, dx = float((x * rows).sum()) / mass - 31.5, float((x * cols).sum()) / mass - 31.5
        scale = math.hypot(dy, dx) / radius
        assert 0.75 - 0.03 <= scale <= 1 + 0.03
        assert mass / 200 == pytest.approx(scale ** 2, rel=0.08)
        angles.append(math.degrees(math.atan2(dy, dx) - math.atan2(9, 8)) % 360)
    assert len({int(a // 90) for a in angles}) == 4 and np.std(angles) > 60


def test_mask_is_the_filled_silhouette():
    rows, cols = torch.meshgrid(torch.arange(64.0), torch.arange(64.0), indexing="ij")
    disc = (rows - 32) ** 2 + (cols - 30) ** 2 <= 15 ** 2
    image = 0.8 * disc.float()
    image[30:33, 28:31] = 0.0  # a dark hole inside the object
    image[3, 3] = 0.9  # a speck outside
    image[disc == 0] += 0.03  # a faint background, below the threshold
    found = mask(image)
    assert found.dtype == torch.bool and found[31, 29] and not found[3, 3]
    assert int((found ^ disc).sum()) <= 8


def test_clutter_keeps_the_object_and_puts_texture_around_it():
    images, labels = views(shifts=[0])
    cluttered, _ = perturb(images, labels, "clutter", seed=1)
    for image, x in zip(images, cluttered):
        inside = mask(image)
        assert torch.equal(x[inside], image[inside])
        outside = x[~inside]
        assert outside.abs().sum() > 0 and outside.var() > 1e-3 and 0 <= x.min() and x.max() <= 1
    assert not torch.equal(cluttered[0][~mask(images[0])], cluttered[1][~mask(images[1])])


def test_occlude_draws_a_grey_square_of_a_fifth_of_the_mask_area_inside_the_image():
    images, labels = views(shifts=[0, 1])
    corner = view(0, corner=(0, 0))  # against the border: the square must be moved inside
    images, labels = images + [corner], labels + [labels[0]]
    for seed in range(3):
        occluded, _ = perturb(images, labels, "occlude", seed=seed)
        for image, x in zip(images, occluded):
            square = x == GREY
            r, c = torch.nonzero(square, as_tuple=True)
            side = int(r.max() - r.min()) + 1
            assert int(c.max() - c.min()) + 1 == side and int(square.sum()) == side ** 2
            area = int(mask(image).sum())
            assert abs(side ** 2 - 0.2 * area) <= side + 1
            assert torch.equal(x[~square], image[~square])
            objr, objc = torch.nonzero(mask(image), as_tuple=True)
            centre = (float(r.min()) + (side - 1) / 2, float(c.min()) + (side - 1) / 2)
            assert objr.min() <= centre[0] <= objr.max() and objc.min() <= centre[1] <= objc.max()


def test_bad_inputs_are_refused():
    images, labels = views(shifts=[0])
    with pytest.raises(InputError, match="rotate, clutter, occlude, pair"):
        perturb(images, labels, "blur", seed=0)
    with pytest.raises(InputError, match="no view of another class"):
        perturb(images[:1] * 2, labels[:1] * 2, "pair", seed=0)
    with pytest.raises(InputError, match="3 images but 2 label sets"):
        perturb(images, labels[:2], "rotate", seed=0)


def test_save_examples_writes_8_bit_pngs(tmp_path):
    images, _ = views(shifts=[0])
    paths = save_examples(images, ["a/0", "b", "c"], tmp_path / "out", limit=2)
    assert [p.name for p in paths] == ["a_0.png", "b.png"] and sorted(p.name for p in (tmp_path / "out").iterdir()) == ["a_0.png", "b.png"]
    read = cv2.imread(str(paths[0]), cv2.IMREAD_UNCHANGED)
    assert read.dtype == np.uint8 and np.array_equal(read, (images[0].numpy() * 255).round().astype(np.uint8))


def u8(image: torch.Tensor) -> np.ndarray:
    """An image in [0, 1] as 8-bit pixels, independently of the product's conversion."""
    return (image.numpy() * 255).round().astype(np.uint8)


def bf_good_matches(image: torch.Tensor, training: list[torch.Tensor], ratio: float = 0.75) -> list[int]:
    """Lowe's ratio test with cv2.BFMatcher, view by view."""
    sift = cv2.SIFT_create()
    _, query = sift.detectAndCompute(u8(image), None)
    counts = []
    for t in training:
        _, desc = sift.detectAndCompute(u8(t), None)
        if query is None or desc is None or len(desc) < 2:
            counts.append(0)
            continue
        pairs = cv2.BFMatcher(cv2.NORM_L2).knnMatch(query, desc, k=2)
        counts.append(sum(m.distance < ratio * n.distance for m, n in pairs))
    return counts


def test_baselines_recognize_copies_and_shifted_views_and_sift_names_both_classes_of_a_pair():
    train, train_labels = views(shifts=[0, 2])
    shifted, shifted_labels = views(shifts=[1, 3])
    classes = ["c0", "c1", "c2"]
    nn, sift = PixelNN().fit(train, train_labels), SiftMatcher().fit(train, train_labels)
    for model in (nn, sift):
        assert score(model.predict(train), train_labels, classes).accuracy == 1.0
        assert score(model.predict(shifted), shifted_labels, classes).correct == 1.0
    pair = torch.cat([train[0], train[4]], dim=1)
    assert sift.predict([pair], n_classes=2) == [frozenset({"c0", "c2"})]
    assert SiftMatcher(two_classes=True).fit(train, train_labels).predict([pair]) == [frozenset({"c0", "c2"})]
    assert sift.predict([torch.zeros(64, 64)]) == [frozenset()]
    assert not nn.supports(pair.shape) and nn.supports(train[0].shape)
    with pytest.raises(InputError, match="supports"):
        nn.predict([pair])
    assert nn.storage_per_class() == 2 * 64 * 64  # one byte per pixel
    counts = [len(cv2.SIFT_create().detectAndCompute(u8(x), None)[0]) for x in train]
    assert sift.descriptors_per_view() == pytest.approx(np.mean(counts))
    assert sift.storage_per_class() == pytest.approx(np.mean([sum(counts[2 * c:2 * c + 2]) * 128 for c in range(3)]))


def test_batched_sift_matching_equals_bfmatcher_view_by_view():
    train, labels = views(shifts=[0, 2])
    train, labels = train + [torch.zeros(64, 64)], labels + [frozenset({"blank"})]  # a view without descriptors
    sift = SiftMatcher().fit(train, labels)
    assert sift.counts[-1] == 0
    queries = [view(1, 1), perturb([view(2, 3)], [labels[0]], "clutter", seed=0)[0][0], torch.cat([train[0], train[2]], 1)]
    for query in queries:
        counts = sift.good_matches(query).tolist()
        assert counts == bf_good_matches(query, train) and max(counts) > 0


def test_sift_ratio_test_is_per_view_and_skips_views_with_one_descriptor(monkeypatch):
    e = torch.eye(128, dtype=torch.float32)
    found = {0: e[:1], 1: torch.stack([e[0], 10 * e[1]]), 2: torch.stack([2 * e[1], 2.1 * e[1]]), 9: e[:1]}
    monkeypatch.setattr("training.recognition.peers.sift_descriptors", lambda image: found[int(image[0, 0])].numpy())
    training = [torch.full((4, 4), float(k)) for k in range(3)]
    sift = SiftMatcher().fit(training, [frozenset({k}) for k in "abc"])
    # view a holds 1 descriptor (no ratio test), b a perfect match, c two neighbours at ratio 0.96
    assert sift.good_matches(torch.full((4, 4), 9.0)).tolist() == [0, 1, 0]
    assert sift.predict([torch.full((4, 4), 9.0)], n_classes=2) == [frozenset({"b"})]


def test_score_matches_definitions_4_5_and_4_6_by_hand():
    true = [{"a"}, {"b"}, {"a"}, {"a"}, {"a"}, {"a", "b"}]
    predicted = [{"a"}, set(), {"a", "b"}, {"b"}, {"b", "c"}, {"a"}]
    block = score([frozenset(p) for p in predicted], [frozenset(t) for t in true], ["a", "b", "c"]).to_json()
    # correct 1, ignorant |true|/n = 1/3, ambiguous 1/(1+1), wrong 0/(1+1), confused 0/(1+2), ignorant 1/2
    assert block["accuracy"] == pytest.approx((1 + 1 / 3 + 1 / 2 + 0 + 0 + 1 / 2) / 6)
    # top-1: a one-class answer is its own top label (a, -, -, b, -, a); no label counts 0
    assert block == pytest.approx({"accuracy": block["accuracy"], "top1": 2 / 6, "correct": 1 / 6, "ignorant": 2 / 6,
                                   "ambiguous": 1 / 6, "wrong": 1 / 6, "confused": 1 / 6})
    # answers best class first (SIFT's ranked): the first is the top label, the set scores def. 4.6 as before
    ranked = [["a"], [], ["b", "a"], ["b"], ["c", "b"], ["a"]]
    by_rank = score_ranked(ranked, [frozenset(t) for t in true], ["a", "b", "c"]).to_json()
    assert by_rank == pytest.approx({**block, "top1": 2 / 6})  # {b, a}: top b, not a true class of image 3
    assert score_ranked([["b", "a"]], [frozenset({"a"})], ["a", "b"]).top1 == 0.0
    assert score_ranked([["a", "b"]], [frozenset({"a"})], ["a", "b"]).top1 == 1.0
    with pytest.raises(InputError, match="top labels"):
        score([frozenset({"a"})], [frozenset({"a"})], ["a"], top=[])


def test_robustness_command_scores_the_runs_learners_and_peers_on_saved_perturbed_views(tmp_path, capsys):
    from training import run
    out = tmp_path / "run"
    assert run.main(["recognize", "--task", "plym", "--classes", "2", "--size", "32", "--stages", "0", "--folds", "1",
                     "--peers", "--quiet", "--device", "cpu", "--out", str(out)]) == 0
    report = json.loads((out / "report.json").read_text())
    assert set(report["peers"]["average"]) == {"pixel_nn", "sift"} and "Peers on the same splits" in (out / "report.md").read_text()
    args = ["robustness", "--run", str(out), "--perturb", "clean,occlude,pair", "--peers", "--quiet", "--device", "cpu"]
    assert run.main([*args, "--out", str(tmp_path / "a")]) == 0
    result = json.loads((tmp_path / "a" / "robustness.json").read_text())
    ours = result["folds"][0]["ours"]
    assert ours["clean"]["accuracy"] == report["folds"][0]["stages"][-1]["test"]["accuracy"]  # the run's own test
    assert "flipped" not in ours["clean"] and 0 < ours["occlude"]["flipped"] < 1
    assert result["average"]["peers"]["sift"]["clean"]["accuracy"] == report["peers"]["average"]["sift"]["clean"]
    # top-1 beside def. 4.6 everywhere: the run's own test, the peers' average, the table set against the peers
    assert ours["clean"]["top1"] == report["folds"][0]["stages"][-1]["test"]["top1"]
    assert result["average"]["peers"]["sift"]["clean"]["top1"] == report["peers"]["average"]["sift"]["clean_top1"]
    assert report["peers"]["average"]["pixel_nn"]["clean_top1"] == result["average"]["peers"]["pixel_nn"]["clean"]["top1"]
    clean = result["average"]["ours"]["clean"]
    row = f"| ftorch | {clean['top1']:.2f} / {clean['accuracy']:.2f} ({clean['ignorant']:.2f}) | "  # clean: the first set
    assert row in (tmp_path / "a" / "robustness.md").read_text() and "top-1 accuracy / accuracy (def. 4.6)" in (
        tmp_path / "a" / "robustness.md").read_text()
    assert "| method | top-1 accuracy | accuracy (def. 4.6) | stores per class |" in (out / "report.md").read_text()
    assert "pair" not in result["average"]["peers"]["pixel_nn"] and "pair" in result["average"]["peers"]["sift"]
    tested = sum(sum(row["as"].values()) + row["ambiguous"] + row["confused"] + row["ignorant"]
                 for row in report["folds"][0]["stages"][-1]["confusion"].values())
    assert len(list((tmp_path / "a" / "fold1" / "occlude").glob("*.png"))) == tested == 14  # 7 test views per class
    assert (tmp_path / "a" / "fold1" / "overview.png").is_file()
    check_node_rows(out, result, tmp_path / "a")
    from ftorch.recognition.learner import DistinctiveFeatureLearner
    from ftorch.recognition.packing import pack
    networks = DistinctiveFeatureLearner.load(out / "fold1" / "learner.json").networks
    assert result["folds"][0]["storage"]["bytes_per_class"] == len(pack(networks)) / 2
    assert run.main([*args, "--out", str(tmp_path / "b")]) == 0
    again = json.loads((tmp_path / "b" / "robustness.json").read_text())
    assert again["average"] == result["average"]  # same seed, same report
    assert result["machine"] == report["machine"]  # run on the machine that trained its learners
    assert f"{result['machine']['cpu_kernels']} kernels" in (tmp_path / "a" / "robustness.md").read_text()
    assert run.main(["robustness", "--run", str(out), "--perturb", "clean", "--quiet", "--device", "cpu",
                     "--test-information", "0.9", "--out", str(tmp_path / "c")]) == 0
    short = json.loads((tmp_path / "c" / "robustness.json").read_text())
    assert short["test_information"] == 0.9 and result["test_information"] is None  # None: the learner's own
    assert short["folds"][0]["ours"]["clean"]["queried"] < ours["clean"]["queried"]
    capsys.readouterr()
    assert run.main(["robustness", "--run", str(out), "--perturb", "blur"]) == 2
    assert run.main(["robustness", "--run", str(tmp_path / "nothing")]) == 2
    assert run.main(["robustness", "--run", str(out), "--test-information", "1.5"]) == 2
    errors = capsys.readouterr().err.strip().splitlines()
    assert len(errors) == 3 and "--perturb 'blur'" in errors[0] and "not a run folder" in errors[1]
    assert "test_information must lie in [0, 1)" in errors[2]


def check_node_rows(run_folder, result: dict, out) -> None:
    """Every node's firing rates, counted here one view at a time from its value and its cut-point,
    equal the benchmark's rows; the per-type table pools them; the report shows both."""
    from ftorch import FeatureSpace
    from ftorch.images import load_image
    from ftorch.recognition.environment import ImageSet
    from ftorch.recognition.learner import DistinctiveFeatureLearner
    from training.data.datasets import plym_task

    learner = DistinctiveFeatureLearner.load(run_folder / "fold1" / "learner.json")
    task = plym_task(size=32, classes=2)
    _, test = task.fold(1)
    names = [task.names[i] for i in test]
    occluded = [load_image(out / "fold1" / "occlude" / f"{name}.png") for name in names]
    space = FeatureSpace()
    sets = {"clean": [task.images[i] for i in test], "occlude": occluded}
    labels = [task.labels[i] for i in test]
    rows = result["folds"][0]["nodes"]
    held = [(net, f) for net in learner.networks.values() for f in net.features]
    assert len(rows) == len(held) > 0
    for name, images in sets.items():
        if name == "occlude":
            continue  # saved as 8-bit PNGs: rounding may move a value across its cut-point; clean is exact
        for (net, f), row in zip(held, rows):
            states = [float(ImageSet([image], [{0}], space).values([f], [0])[0, 0]) > net.threshold[f] for image in images]
            own = [s for s, truth in zip(states, labels) if truth == net.label]
            other = [s for s, truth in zip(states, labels) if truth != net.label]
            assert row["own"][name] == pytest.approx(np.mean(own)) and row["other"][name] == pytest.approx(np.mean(other))
            assert row["class"] == str(net.label) and 0 <= row["flipped"]["occlude"] <= 1
    types = result["average"]["types"]
    assert sum(t["nodes"] for t in types.values()) == len(rows)
    for kind, t in types.items():
        of_kind = [r for r in rows if r["type"] == kind]
        assert t["own"]["clean"] == pytest.approx(np.mean([r["own"]["clean"] for r in of_kind]))
    text = (out / "robustness.md").read_text()
    assert "## Which features survive" in text and "## Every node" in text and (out / "features.png").is_file()
