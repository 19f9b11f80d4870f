"""The accuracy-per-byte front: packed networks, the peers' budgets, and the tradeoff command."""
import json
import shutil
from pathlib import Path

import cv2
import numpy as np
import pytest
import torch

from ftorch.recognition.bayes import ClassNetwork
from ftorch.recognition.learner import DistinctiveFeatureLearner
from ftorch.recognition.packing import pack, unpack
from ftorch.space.features import Conjunction, Disjunction, Feature, Geometric, Part, Texel, Texture, Within
from tests.training.test_robustness import u8, view, views
from training.recognition.peers import PixelNN, SiftMatcher, score, sift_descriptors
from training.recognition.schema import SCHEMA
from training.recognition.tradeoff import Point, budget_rows, keypoint_budgets

RUN = ["recognize", "--task", "plym", "--classes", "2", "--size", "32", "--stages", "0", "--folds", "1", "--quiet",
       "--device", "cpu"]


def f32(x) -> float:
    return float(np.float32(x))


def packed_size(networks) -> int:
    """The packing's length counted from the structure alone (ftorch.recognition.packing's layout)."""
    seen: set = set()

    def feature_bytes(feature) -> int:
        if feature in seen:
            return 0
        seen.add(feature)
        inner = sum(feature_bytes(sub) for sub in feature.subfeatures())
        if isinstance(feature, Texel):
            return inner + 1 + 15 * 4
        if isinstance(feature, Geometric):
            return inner + 2 + sum(1 + 4 * len(p.vector) + 16 * (k > 0) for k, p in enumerate(feature.parts))
        if isinstance(feature, Texture):
            return inner + 2 + 4 * len(feature.histogram)  # code, level, histogram
        if isinstance(feature, Within):
            return inner + 2 + 3 * 4 + 2  # code, frame, x y radius, the bounded feature's position
        return inner + 1 + 2 * 2

    size = 4 + sum(feature_bytes(f) for net in networks.values() for f in net.features)
    for net in networks.values():
        size += 4 + 2 + sum(2 + 4 + 1 + 2 * len(net.parents[f]) + 4 * 2 ** (1 + len(net.parents[f])) for f in net.features)
    return size


def rounded(feature: Feature) -> Feature:
    """The feature with every parameter rounded to float32, through its JSON form (a texture's sigma
    is packed as its level, exact)."""
    def walk(x):
        if isinstance(x, float):
            return f32(x)
        if isinstance(x, list):
            return [walk(v) for v in x]
        if isinstance(x, dict):
            return {k: v if k == "sigma" else walk(v) for k, v in x.items()}
        return x
    return Feature.from_dict(walk(feature.to_dict()))


def check_round_trip(networks: dict) -> dict:
    data = pack(networks)
    assert len(data) == packed_size(networks)
    back = unpack(data, list(networks))
    assert list(back) == list(networks)
    for label, net in networks.items():
        other = back[label]
        assert other.features == tuple(rounded(f) for f in net.features)
        assert [tuple(map(rounded, net.parents[f])) for f in net.features] == [other.parents[f] for f in other.features]
        assert [f32(net.threshold[f]) for f in net.features] == [other.threshold[f] for f in other.features]
        assert other.prior[1] == f32(net.prior[1]) and other.prior[0] == pytest.approx(net.prior[0], abs=1e-7)
        for f, g in zip(net.features, other.features):
            assert np.allclose(other.cpt[g], net.cpt[f], atol=1e-7) and np.allclose(other.cpt[g].sum(-1), 1)
    assert pack(back) == data  # the packing is a fixed point
    return back


def hand_networks() -> dict:
    """Two networks holding every feature type, one feature shared, a node with two parents."""
    rng = np.random.default_rng(0)
    t1, t2 = Texel(rng.normal(size=15).tolist()), Texel(rng.normal(size=15).tolist())
    geo = Geometric((Part("edgel", rng.normal(size=2).tolist()), Part("texel", rng.normal(size=15).tolist(), 0.3, -1.2, 4.5, 1.5)))
    both = Conjunction(t1, geo)
    either = Disjunction(both, t2)

    def cpt(parents: int) -> np.ndarray:
        present = rng.uniform(0.05, 0.95, size=(2,) * (1 + parents))
        return np.stack([1 - present, present], axis=-1)
    a = ClassNetwork.of("cube", [t1, geo, either], [[], [t1], [t1, geo]], [0.61, 0.37, 0.9], [0.7, 0.3], [cpt(0), cpt(1), cpt(2)])
    b = ClassNetwork.of(7, [both, t1], [[], [both]], [0.5, 0.2], [0.4, 0.6], [cpt(0), cpt(1)])
    return {"cube": a, 7: b}


def test_packing_stores_every_feature_type_once_and_reads_back_what_it_wrote():
    networks = hand_networks()
    check_round_trip(networks)
    # t1 is in both networks and inside the conjunction, the disjunction holds the conjunction: 5 features once each
    assert int.from_bytes(pack(networks)[:2], "little") == 5


def test_damaged_packings_are_refused():
    networks = hand_networks()
    data = pack(networks)
    for damaged, message in [(data[:-3], "end at byte"), (data + b"\0", "bytes left"), (b"\6\0" + data[2:], "type code"),
                             (b"\4\0" + data[2:], "refers to feature"),
                             (data[:4] + b"\x09" + data[5:], "type code 9")]:
        with pytest.raises(ValueError, match=message):
            unpack(damaged, list(networks))
    with pytest.raises(ValueError, match="class names"):
        unpack(data, ["cube"])


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """Two learned runs of one task that differ in redundancy; the first with a second seed."""
    from training import run
    root = tmp_path_factory.mktemp("front")
    assert run.main([*RUN, "--redundancy", "1", "--seeds", "2", "--out", str(root / "k1")]) == 0
    assert run.main([*RUN, "--redundancy", "3", "--out", str(root / "k3")]) == 0
    return root


def test_learned_networks_pack_to_their_counted_bytes_and_recognize_the_same(runs):
    from ftorch.recognition.environment import ImageSet
    from ftorch.space.record import FeatureSpace
    from training.data.datasets import load_task
    learner = DistinctiveFeatureLearner.load(runs / "k1" / "fold1" / "learner.json")
    assert sum(len(n.features) for n in learner.networks.values()) > 0
    back = check_round_trip(learner.networks)
    c = json.loads((runs / "k1" / "report.json").read_text())["config"]
    task = load_task(c["task"], c["data"], len(c["classes"]), c["views"], c["size"], c["seed"], c["first_view"])
    _, test = task.fold(1)
    env = ImageSet([task.images[i] for i in test], [task.labels[i] for i in test], FeatureSpace())
    before = learner.recognize_many(env, range(len(env)))
    learner.networks = back
    after = learner.recognize_many(env, range(len(env)))
    assert [r.recognized for r in after] == [r.recognized for r in before]


def test_pixel_peer_stores_side_squared_bytes_per_view_and_knows_copies_at_every_side():
    train, labels = views(shifts=[0, 2])
    classes = ["c0", "c1", "c2"]
    for side in (4, 8, 16, None):
        nn = PixelNN(side).fit(train, labels)
        assert nn.storage_per_class() == 2 * (64 * 64 if side is None else side * side)  # 2 views per class, a byte a pixel
        assert score(nn.predict(train), labels, classes).accuracy == 1.0
    reduced = PixelNN(4).fit(train, labels)
    block = torch.nn.functional.avg_pool2d(train[0][None, None], 16)[0, 0]  # INTER_AREA at an integer factor
    assert torch.allclose(reduced.vectors[0], (block * 255).round().reshape(-1), atol=1.0)
    pair = torch.cat([train[0], train[0]], dim=1)
    assert reduced.supports(pair.shape) and not PixelNN().fit(train, labels).supports(pair.shape)


def test_sift_peer_keeps_the_strongest_keypoints_and_counts_a_byte_per_entry():
    train, labels = views(shifts=[0, 2])
    full = SiftMatcher().fit(train, labels)
    for x, found in zip(train, full._found):
        points, raw = cv2.SIFT_create().detectAndCompute(u8(x), None)
        strongest = int(np.argmax([p.response for p in points]))
        assert np.array_equal(found[0], raw[strongest]) and len(found) == len(raw)
        assert np.all(found == np.round(found)) and found.max() < 256  # whole numbers below 256: a byte each
    assert keypoint_budgets(int(full.counts.max()))[:3] == [1, 2, 4] and keypoint_budgets(5) == [1, 2, 4, None]
    classes = ["c0", "c1", "c2"]
    for n in (1, 2, 4):
        sift = full.strongest(n)
        kept = torch.clamp(full.counts, max=n)
        assert torch.equal(sift.counts, kept)
        assert sift.storage_per_class() == pytest.approx(float(kept.reshape(3, 2).sum(1).float().mean()) * 128)
    # a view with one descriptor cannot pass Lowe's ratio test within the view: one keypoint answers nothing
    assert full.strongest(1).predict(train) == [frozenset()] * len(train)
    across = SiftMatcher(across_classes=True).fit(train, labels, full._found)
    assert score(across.predict(train), labels, classes).accuracy == 1.0
    assert score(full.predict(train), labels, classes).accuracy == 1.0
    one = across.strongest(1)  # the copy's strongest descriptor is at distance 0 in its own view: it votes right
    assert all(one.class_votes(x, q[:1]).argmax() == k // 2 for k, (x, q) in enumerate(zip(train, full._found)))
    assert torch.equal(across.strongest(2).counts, full.strongest(2).counts)
    queries = [sift_descriptors(x) for x in train]
    assert full.strongest(2).predict(train, queries=queries) == full.strongest(2).predict(train)


def bf_class_votes(image: torch.Tensor, training: list[torch.Tensor], classes: list[int], ratio: float = 0.75) -> list[int]:
    """Lowe's test across classes with cv2.BFMatcher over all training descriptors, one query at a time."""
    sift = cv2.SIFT_create()
    found = [sift.detectAndCompute(u8(t), None)[1] for t in training]
    rows = np.concatenate(found)
    owner = np.concatenate([[c] * len(d) for c, d in zip(classes, found)])
    votes = [0] * (max(classes) + 1)
    _, query = sift.detectAndCompute(u8(image), None)
    for matches in cv2.BFMatcher(cv2.NORM_L2).knnMatch(query, rows, k=len(rows)):
        first = matches[0]
        other = next(m for m in matches if owner[m.trainIdx] != owner[first.trainIdx])
        votes[owner[first.trainIdx]] += first.distance < ratio * other.distance
    return votes


def test_sift_ratio_test_across_classes_equals_bfmatcher():
    train, labels = views(shifts=[0, 2])
    sift = SiftMatcher(across_classes=True).fit(train, labels)
    for query in (view(1, 1), view(2, 3), torch.cat([train[0], train[4]], 1)):
        votes = sift.class_votes(query).tolist()
        assert votes == bf_class_votes(query, train, [0, 0, 1, 1, 2, 2]) and max(votes) > 0
    pair = torch.cat([train[0], train[4]], 1)
    assert sift.predict([pair], n_classes=2) == [frozenset({"c0", "c2"})]


def test_the_budget_table_takes_each_methods_best_point_within_the_budget():
    def point(method, spent, top1):  # def. 4.6's accuracy ordered the other way: the budgets follow top-1
        return Point(method, f"{method} {spent}", spent, {"clean": 1 - top1}, 1 - top1, 1, {"clean": top1}, top1)
    points = [point("ftorch", 300, 0.6), point("ftorch", 900, 0.8), point("sift", 500, 0.7), point("sift", 3000, 0.95),
              point("pixel_nn", 200, 0.5), point("pixel_nn", 1000, 0.9)]
    rows = {r.budget: r.to_json() for r in budget_rows(points)}
    assert rows[256]["ftorch"] is None and rows[256]["pixel_nn"]["mean_top1"] == 0.5 and rows[256]["ftorch_leads"] is None
    assert rows[512]["ftorch"]["mean_top1"] == 0.6 and rows[512]["sift"]["mean_top1"] == 0.7 and rows[512]["ftorch_leads"] is False
    assert rows[1024]["ftorch"]["mean_top1"] == 0.8 and rows[1024]["pixel_nn"]["mean_top1"] == 0.9 and not rows[1024]["ftorch_leads"]
    points.append(point("ftorch", 2000, 0.93))
    rows = {r.budget: r.to_json() for r in budget_rows(points)}
    assert rows[2048]["ftorch_leads"] is True and rows[4096]["ftorch_leads"] is False  # sift .95 at 3000 bytes
    assert rows[2048]["ftorch"]["mean"] == pytest.approx(0.07)  # def. 4.6's accuracy kept beside it


def test_tradeoff_command_measures_every_method_on_the_same_views(runs, tmp_path, capsys):
    from training import run
    from training.data.datasets import load_task
    c = json.loads((runs / "k1" / "report.json").read_text())["config"]
    args = ["tradeoff", "--runs", str(runs / "k1"), str(runs / "k3"), "--perturb", "clean,occlude,pair", "--quiet",
            "--device", "cpu"]
    assert run.main([*args, "--out", str(tmp_path / "a")]) == 0
    result = json.loads((tmp_path / "a" / "tradeoff.json").read_text())
    ours = {p["setting"]: p for p in result["points"] if p["method"] == "ftorch"}
    assert set(ours) == {"redundancy 1", "redundancy 3"}
    rows = [r for r in result["learners"] if r["setting"] == "redundancy 1"]
    assert sorted((r["seed"], r["fold"], r["weight"]) for r in rows) == [(0, 1, 0.5), (1, 1, 0.5)]
    spent = []
    for seed_folder in ("", "seed1/"):
        learner = DistinctiveFeatureLearner.load(runs / "k1" / f"{seed_folder}fold1" / "learner.json")
        spent.append(len(pack(learner.networks)) / 2)
    assert ours["redundancy 1"]["bytes_per_class"] == pytest.approx(np.mean(spent))
    report = json.loads((runs / "k3" / "report.json").read_text())
    assert ours["redundancy 3"]["accuracy"]["clean"] == pytest.approx(report["folds"][0]["stages"][-1]["test"]["accuracy"])
    assert ours["redundancy 3"]["top1"]["clean"] == pytest.approx(report["folds"][0]["stages"][-1]["test"]["top1"])
    settings = {(p["method"], p["setting"]) for p in result["points"]}
    assert {("sift", "1 keypoint"), ("sift", "all keypoints"), ("sift_across", "1 keypoint"), ("pixel_nn", "4x4 pixels"),
            ("pixel_nn", "16x16 pixels"),
            ("pixel_nn", "32x32 pixels")} <= settings
    pixels = {p["setting"]: p for p in result["points"] if p["method"] == "pixel_nn"}
    assert len(pixels) == 4  # 4, 8, 16 and as stored (32 x 32)
    train, _ = load_task(c["task"], c["data"], len(c["classes"]), c["views"], c["size"], c["seed"], c["first_view"]).fold(1)
    assert pixels["32x32 pixels"]["bytes_per_class"] == 32 * 32 * len(train) / 2
    assert pixels["32x32 pixels"]["answered"] == 2 and pixels["16x16 pixels"]["answered"] == 3  # pairs are 32 x 64
    assert [r["budget"] for r in result["budgets"]][0] == 256
    text = (tmp_path / "a" / "tradeoff.md").read_text()
    assert "| ftorch | redundancy 1 |" in text and "Best mean top-1 accuracy within each budget" in text
    assert (tmp_path / "a" / "front.png").stat().st_size > 0 and list((tmp_path / "a" / "tensorboard").glob("events.*"))
    older = []  # the same runs as written before top-1 was reported: their reports hold no top1
    for name in ("k1", "k3"):
        shutil.copytree(runs / name, tmp_path / "older" / name)
        path = tmp_path / "older" / name / "report.json"
        path.write_text(path.read_text().replace('"top1"', '"_dropped"'))
        older.append(str(tmp_path / "older" / name))
    assert "top1" not in (tmp_path / "older" / "k3" / "report.json").read_text()
    assert run.main([*args[:2], *older, *args[4:], "--out", str(tmp_path / "b")]) == 0
    again = json.loads((tmp_path / "b" / "tradeoff.json").read_text())
    assert again["points"] == result["points"]  # same seed, same front, from the learners whatever the report holds
    capsys.readouterr()
    other = tmp_path / "other"
    shutil.copytree(runs / "k3", other)
    report["config"]["size"] = 64
    (other / "report.json").write_text(json.dumps(report))
    missing = tmp_path / "missing"
    shutil.copytree(runs / "k1", missing)
    (missing / "seed1" / "fold1" / "learner.json").unlink()
    assert run.main(["tradeoff", "--runs", str(runs / "k1"), str(other), "--out", str(tmp_path / "c")]) == 2
    assert run.main(["tradeoff", "--runs", str(missing), "--out", str(tmp_path / "c")]) == 2
    assert run.main(["tradeoff", "--runs", str(runs / "k1"), "--out", str(runs / "k1" / "front")]) == 2
    assert run.main([*args, "--out", str(tmp_path / "a")]) == 2  # no --overwrite
    newer = tmp_path / "newer"
    shutil.copytree(runs / "k1", newer)
    (newer / "report.json").write_text(json.dumps({**json.loads((runs / "k1" / "report.json").read_text()), "schema": SCHEMA + 1}))
    assert run.main(["tradeoff", "--runs", str(newer), "--out", str(tmp_path / "c")]) == 2
    errors = capsys.readouterr().err.strip().splitlines()
    assert len(errors) == 5 and "learned different tasks (size differ)" in errors[0] and "is missing" in errors[1]
    assert "lies inside --runs" in errors[2] and not (runs / "k1" / "front").exists()
    assert errors[4].endswith(f"--runs {newer}: a report of schema {SCHEMA + 1}, newer than this ftorch reads ({SCHEMA}): "
                              "update ftorch to read it")


def test_runs_are_named_by_the_options_they_differ_in_and_older_configs_by_their_defaults():
    from ftorch.recognition.settings import LearnerSettings
    from training.recognition.protocol import RunConfig
    from training.recognition.schema import migrated_config
    from training.recognition.tradeoff import settings

    new = RunConfig("folder", learner=LearnerSettings(calibrate=True), augment=2, dynamic=True).to_dict()
    old = RunConfig("folder").to_dict()
    for key in ("calibrate", "dynamic", "leak"):  # written before these options existed
        old.pop(key)
    old = migrated_config(old, None, "a report")  # as tradeoff reads a report of schema 0
    assert settings([old, new], [Path("a"), Path("b")]) == ["calibrate False, augment 0, dynamic False",
                                                            "calibrate True, augment 2, dynamic True"]
    assert settings([old, old], [Path("a"), Path("b")]) == ["a", "b"]
