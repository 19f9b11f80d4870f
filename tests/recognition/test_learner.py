"""The incremental learner (alg. 4.7, 4.8, 4.10) on a small synthetic task, and its pieces."""
import json

import cv2
import numpy as np
import pytest
import torch

from ftorch.errors import InputError
from ftorch.recognition.bayes import ClassNetwork
from ftorch.recognition.candidates import in_use
from ftorch.recognition.environment import ImageSet
from ftorch.recognition.exact import engine
from ftorch.recognition.inference import Recognition, accuracy, recognize, recognize_block, residual_entropy
from ftorch.recognition.instances import InstanceList
from ftorch.recognition.learner import DistinctiveFeatureLearner
from ftorch.recognition.value_cache import ValueCache
from ftorch.space.evaluate import feature_values
from ftorch.space.features import FeatureTable, unpack_features
from ftorch.space.generate import random_edgel_pair, random_texel
from ftorch.tables import GrowingTable


def shape(kind: int, angle: float, rng, size: int = 40) -> np.ndarray:
    """A bright disc (0), square (1) or triangle (2) on a dark ground, anti-aliased."""
    up = 8
    n = size * up
    img = np.full((n, n), 0.1, np.float32)
    c, r = n / 2 + rng.uniform(-2, 2) * up, n * 0.28 * rng.uniform(0.9, 1.1)
    if kind == 0:
        cv2.circle(img, (int(c), int(c)), int(r), 0.9, -1)
    else:
        k = 4 if kind == 1 else 3
        pts = [[c + r * np.cos(angle + 2 * np.pi * i / k), c + r * np.sin(angle + 2 * np.pi * i / k)] for i in range(k)]
        cv2.fillPoly(img, [np.array(pts, np.int32)], 0.9)
    return cv2.resize(img, (size, size), interpolation=cv2.INTER_AREA)


@pytest.fixture(scope="module")
def shapes() -> ImageSet:
    rng = np.random.default_rng(0)
    kinds = [i % 3 for i in range(30)]
    return ImageSet([shape(k, rng.uniform(0, 2 * np.pi), rng) for k in kinds], [{k} for k in kinds])


def train(env: ImageSet, seed: int, cycles: int = 10):
    learner = DistinctiveFeatureLearner.thesis(seed=seed)
    order = torch.Generator().manual_seed(seed)
    history = []
    for _ in range(cycles):
        errors = sum(learner.learn(env, i)[1] != "correct" for i in torch.randperm(18, generator=order).tolist())
        history.append(errors)
        if errors == 0:
            break
    return learner, history


def test_learns_the_training_set_and_generalizes(shapes):
    learner, history = train(shapes, seed=0)
    assert history[-1] == 0, history
    test = [accuracy(learner.recognize(shapes, j).recognized, shapes.labels[j], 3) for j in range(18, 30)]
    assert np.mean(test) >= 0.7  # chance is 1/3
    assert all(len(net.features) > 0 for net in learner.networks.values())


def test_same_seed_same_learner(shapes):
    a, history_a = train(shapes, seed=3, cycles=2)
    b, history_b = train(shapes, seed=3, cycles=2)
    assert history_a == history_b
    for label in a.networks:
        assert [f.to_json() for f in a.networks[label].features] == [f.to_json() for f in b.networks[label].features]
        assert a.networks[label].threshold == b.networks[label].threshold


@pytest.mark.parametrize("beliefs, true, expected", [
    ({"A": 0.7, "B": 0.4, "C": 0.8, "D": 0.3, "E": 0.2}, {"A", "B"}, ("B", {"C"}, True)),    # wrong
    ({"A": 0.7, "B": 0.9, "C": 0.8, "D": 0.3, "E": 0.2}, {"A", "B"}, ("C", {"A"}, False)),   # ambiguous
    ({"A": 0.3, "B": 0.4, "C": 0.4, "D": 0.3, "E": 0.2}, {"A", "B"}, ("A", {"C"}, True)),    # ignorant
])
def test_true_and_mistaken_classes_follow_table_4_1(beliefs, true, expected):
    learner = DistinctiveFeatureLearner.thesis()
    rec = Recognition(beliefs, {c for c, p in beliefs.items() if p > 0.5}, beliefs=[beliefs])
    char, disc, char_is_true, _ = learner.choose_classes(rec, frozenset(true))
    assert (char, set(disc), char_is_true) == expected


def test_zero_beliefs_consult_the_earlier_stage():
    learner = DistinctiveFeatureLearner.thesis()
    earlier = {"A": 0.4, "B": 0.4, "C": 0.3, "D": 0.3, "E": 0.2}
    final = dict.fromkeys(earlier, 0.0)
    rec = Recognition(final, set(), beliefs=[earlier, final])
    char, disc, char_is_true, _ = learner.choose_classes(rec, frozenset({"A", "B"}))
    assert char in {"A", "B"} and set(disc) == {"C", "D"} and char_is_true


def test_instance_list_counts_only_measured_values():
    instances = InstanceList()
    instances.add("i1", {"A"})
    instances.add("i2", {"B"})
    instances.set("i1", "f", 0.5)
    assert instances.add("i1", {"A"}) == 0 and len(instances) == 2
    assert np.isnan(instances.get("i2", "f")) and instances.get("i1", "f") == 0.5
    assert instances.has("A").tolist() == [True, False] and instances.has_any({"A", "B"}).tolist() == [True, True]
    instances.set("i2", "g", 0.25)
    instances.set("i1", "h", 0.75)
    assert instances.block(["h", "f"]).tolist()[0][0] == 0.75 and np.isnan(instances.block(["h", "f"])[1, 1])
    instances.forget(["f", "h", "unknown"])
    assert instances.features == ["g"] and np.isnan(instances.get("i1", "f")) and instances.get("i2", "g") == 0.25
    assert np.isnan(instances.get("i1", "g")) and np.isnan(instances.get("i1", "h"))


def test_growing_table_equals_a_table_rebuilt_at_every_step():
    """Random appends of rows and columns and row and column removals, against numpy's vstack/hstack."""
    rng = np.random.default_rng(0)
    table, reference = GrowingTable(fill=-1.0), np.zeros((0, 0))
    for _ in range(400):
        step = rng.integers(4)
        if step == 0:
            rows = rng.normal(size=(int(rng.integers(1, 4)), reference.shape[1]))
            table.add_rows(rows)
            reference = np.vstack([reference, rows])
        elif step == 1:
            columns = rng.normal(size=(reference.shape[0], int(rng.integers(1, 4))))
            table.add_columns(columns)
            reference = np.hstack([reference, columns])
        elif step == 2:
            keep = rng.random(reference.shape[1]) < 0.8
            table.keep_columns(keep)
            reference = reference[:, keep]
        else:
            keep = rng.random(reference.shape[0]) < 0.8
            table.keep_rows(keep)
            reference = reference[keep]
        assert np.array_equal(table.array, reference)
    assert table.array.shape == reference.shape and reference.size > 0


def test_recognition_records_nothing_and_batches_equal_single_images(shapes):
    learner, _ = train(shapes, seed=1, cycles=2)
    before = (len(learner.instances), learner.instances.values_table().copy(), learner.presentations)
    other = ImageSet([shapes.images[j] for j in range(18, 30)], [shapes.labels[j] for j in range(18, 30)])
    many = learner.recognize_many(other, range(12))
    one = [learner.recognize(other, j) for j in range(12)]
    assert [(r.recognized, r.queried, r.posteriors) for r in many] == [(r.recognized, r.queried, r.posteriors) for r in one]
    # the block (alg. 4.4 for all images at once) against the one-image reference on these learned networks
    features = in_use(learner.networks)
    table = other.values(features, list(range(12)))
    for positive_only in (False, True):
        block = recognize_block(learner.networks, table, max(learner.settings.test_information, 1e-12), positive_only)
        for j, got in enumerate(block):
            alone = recognize(learner.networks, dict(zip(features, table[:, j].tolist())).__getitem__,
                              max(learner.settings.test_information, 1e-12), positive_only=positive_only)
            assert (got.queried, got.values, got.beliefs, got.recognized) == (alone.queried, alone.values, alone.beliefs,
                                                                              alone.recognized)
    after = learner.instances.values_table()
    assert len(learner.instances) == before[0] and learner.presentations == before[2]
    np.testing.assert_array_equal(np.isnan(after), np.isnan(before[1]))


@pytest.mark.parametrize("t_ksd, block_min", [(0.0, 1), (0.6, 1), (0.0, 3), (0.6, 3)])
def test_presenting_in_blocks_equals_presenting_one_by_one(shapes, t_ksd, block_min, monkeypatch):
    """present (first recognitions made in blocks while the networks stand) leaves the state that learn
    called image by image leaves: the same presentations, networks, instances, value cache and
    generator, through stage-0 and expert cycles, with blocks recognized image by image or as
    blocks (``BLOCK_MIN``); and blocks were used."""
    import ftorch.recognition.recognizer as module

    monkeypatch.setattr(module, "BLOCK_MIN", block_min)

    def taught(by_blocks: bool):
        env = ImageSet(shapes.images[:18], shapes.labels[:18])
        learner = DistinctiveFeatureLearner.thesis(seed=3)
        order = torch.Generator().manual_seed(3)
        out = []
        for _ in range(4):
            images = torch.randperm(18, generator=order).tolist()
            out += learner.present(env, images, t_ksd) if by_blocks else [learner.learn(env, i, t_ksd) for i in images]
        state = json.dumps(learner.state_dict(training=True, env=env)) + json.dumps(env.cache_state())
        return [(p.result, p.recognition.queried, p.recognition.beliefs, p.pair, p.ksd) for p in out], state

    kept = []
    keep = module.Ahead.keep
    monkeypatch.setattr(module.Ahead, "keep", lambda self, block, signature: kept.append(len(block)) or keep(self, block, signature))
    assert taught(True) == taught(False)
    assert max(kept) > 1  # some blocks recognized several images


def test_each_value_is_computed_once(shapes, monkeypatch):
    env = ImageSet(shapes.images[:6], shapes.labels[:6])
    learner, _ = train(shapes, seed=2, cycles=1)
    features = in_use(learner.networks)[:5]
    calls = []
    original = ImageSet._compute
    monkeypatch.setattr(ImageSet, "_compute", lambda self, f, i: calls.append((len(f), len(i))) or original(self, f, i))
    first = env.values(features, [0, 1, 2])
    again = env.values(features[::-1], [2, 0])
    assert calls == [(5, 3)]
    np.testing.assert_array_equal(again, first[::-1][:, [2, 0]])
    env.values(features, [0, 3])  # only image 3 is missing: computed, image 0 kept as it was
    assert calls[-1] == (5, 2) and np.array_equal(env.values(features, [0])[:, 0], first[:, 0])
    fresh = ImageSet(shapes.images[:6], shapes.labels[:6])
    fresh.load_cache_state(env.cache_state())
    np.testing.assert_array_equal(fresh.values(features, [0, 1, 2, 3]), env.values(features, [0, 1, 2, 3]))
    assert len(calls) == 2



def test_value_cache_follows_its_rule_equals_fresh_values_and_round_trips(shapes):
    """Random requests against a model of the caching rule: the callback is asked exactly for the
    features missing at each call (on the requested images, or on all for one image), every value
    returned is the first one computed for its pair, and the values equal a fresh evaluation."""
    env = ImageSet(shapes.images[:8], shapes.labels[:8], records=shapes.records(range(8)))
    generator = torch.Generator().manual_seed(0)
    features = [f for n in range(8) for f in (random_texel(env.all_records, n, generator),
                                              random_edgel_pair(env.all_records, n, generator)) if f is not None]
    assert len(features) >= 10
    row = {f: k for k, f in enumerate(features)}
    first = np.full((len(features), len(env)), np.nan)  # the model: the first value computed for each pair
    calls = []

    def compute(asked, images):
        calls.append((asked, images))
        values = env._compute(asked, images)
        for f, v in zip(asked, values):
            first[row[f], images] = np.where(np.isnan(first[row[f], images]), v, first[row[f], images])
        return values

    cache, rng = ValueCache(len(env)), np.random.default_rng(0)
    for _ in range(25):
        asked = [features[k] for k in rng.integers(len(features), size=int(rng.integers(1, 6)))]  # repeats too
        images = [int(i) for i in rng.choice(len(env), size=int(rng.integers(1, 5)), replace=False)]
        missing = list(dict.fromkeys(f for f in asked if np.isnan(first[row[f], images]).any()))
        before = len(calls)
        block = cache.values(asked, images, compute)
        batch = list(range(len(env))) if len(images) == 1 else images
        assert calls[before:] == ([(missing, batch)] if missing else [])
        assert np.array_equal(block, first[np.ix_([row[f] for f in asked], images)])
    assert 1 < len(calls) < 25 and np.isnan(first).any() and len(cache) == len(features)
    fresh = feature_values(features, env.all_records).values.double().numpy()
    measured = ~np.isnan(first)
    np.testing.assert_allclose(first[measured], fresh[measured], rtol=0, atol=1e-6)

    order = cache.table().features  # the cache's rows in their order, and all they hold
    shared, saved = FeatureTable(), cache.stored(order, range(len(env)))
    for state, known in ((json.loads(json.dumps(cache.state_dict())), None),
                         (cache.state_dict(shared), list(reversed(shared.features)))):
        if known is not None:  # written against a table the caller keeps, in another order
            state = {"features": [known.index(f) for f in shared.features], "values": state["values"]}
        other = ValueCache(len(env))
        other.load_state_dict(state, known)
        assert other.table().features == order
        assert np.array_equal(other.stored(order, range(len(env))), saved, equal_nan=True)
        assert np.array_equal(other.values(features, range(len(env)), compute), cache.values(features, range(len(env)), compute))
    assert not np.isnan(first).any()
    np.testing.assert_allclose(first, fresh, rtol=0, atol=1e-6)
    with pytest.raises(InputError, match="where the file.s structure needs"):
        ValueCache(len(env) + 1).load_state_dict(cache.state_dict())

def test_a_float32_space_caches_float32_values_exactly(shapes):
    """The cache stores values in the precision they are computed in: half the memory, every
    value the same float64 as a fresh evaluation; a state it cannot hold exactly is refused."""
    env = ImageSet(shapes.images[:8], shapes.labels[:8], records=shapes.records(range(8)))
    generator = torch.Generator().manual_seed(1)
    features = [f for n in range(8) for f in (random_texel(env.all_records, n, generator),
                                              random_edgel_pair(env.all_records, n, generator)) if f is not None]
    assert env.all_records.dtype == torch.float32 and env.cache.dtype == np.float32
    got = env.values(features, range(len(env)))
    fresh = feature_values(features, env.all_records).values.double().numpy()
    assert got.dtype == np.float64 and np.array_equal(got, fresh)
    assert env.cache._table.array.dtype == np.float32
    state = json.loads(json.dumps(env.cache_state()))
    other = ValueCache(len(env), np.float32)
    other.load_state_dict(state)
    assert np.array_equal(other.values(features, range(len(env)), None), got)
    wide = ValueCache(len(env))
    wide.values(features, range(len(env)), lambda f, i: np.full((len(f), len(i)), 0.1))  # 0.1 needs float64
    with pytest.raises(InputError, match="cannot hold exactly"):
        ValueCache(len(env), np.float32).load_state_dict(wide.state_dict())


def test_discard_unused_removes_features_and_recounts(shapes):
    learner, _ = train(shapes, seed=0, cycles=2)
    assert learner.discard_unused(since=0) == []  # every feature was used at some presentation
    last = learner.presentations
    for i in range(3):
        learner.learn(shapes, i)
    used = in_use(learner.networks)
    kept = [f for f in used if learner.usage[f] > last]
    assert 0 < len(kept) < len(used)
    dropped = learner.discard_unused(since=last + 1)
    assert dropped == [f for f in used if f not in kept] and in_use(learner.networks) == kept
    assert all(f not in learner.instances.features and f not in learner.usage for f in dropped)
    for label, net in learner.networks.items():  # re-counted: the CPTs are those a fresh estimate gives
        tables = {f: net.cpt[f].copy() for f in net.features}
        learner.counting.estimate(learner.networks[label], learner.settings)
        assert all(np.array_equal(tables[f], net.cpt[f]) for f in net.features)


def test_saved_learner_continues_exactly(shapes, tmp_path):
    a, _ = train(shapes, seed=4, cycles=1)
    a.save(tmp_path / "a.json", training=True)
    b = DistinctiveFeatureLearner.load(tmp_path / "a.json")
    assert b.state_dict() == a.state_dict()
    for i in list(range(18)) * 2:
        assert a.learn(shapes, i)[1] == b.learn(shapes, i)[1]
    assert b.state_dict() == a.state_dict()


def test_recognition_file_holds_the_networks_only_recognizes_alike_and_refuses_to_learn(shapes, tmp_path):
    a, _ = train(shapes, seed=4, cycles=1)
    a.save(tmp_path / "full.json", training=True)
    a.save(tmp_path / "a.json")
    b = DistinctiveFeatureLearner.load(tmp_path / "a.json")
    assert len(unpack_features(json.loads((tmp_path / "a.json").read_text())["learner"]["features"])) == len(in_use(a.networks))
    assert len(a.instances.features) > len(in_use(a.networks))  # the full state holds more: failed candidates' values
    assert (tmp_path / "a.json").stat().st_size < (tmp_path / "full.json").stat().st_size / 2
    assert b.state_dict(training=False) == a.state_dict(training=False)
    ours, theirs = a.recognize_many(shapes, range(len(shapes))), b.recognize_many(shapes, range(len(shapes)))
    assert [(r.posteriors, r.queried) for r in ours] == [(r.posteriors, r.queried) for r in theirs]
    with pytest.raises(InputError, match="recognition-only"):
        b.learn(shapes, 0)


def test_choose_pair_takes_the_least_well_discriminated_pair_alg_5_2():
    """Class A (true, uncertain) has a feature that separates it from C perfectly but not from B."""
    learner = DistinctiveFeatureLearner.thesis()
    for image, label, value in [(0, "A", 0.9), (1, "A", 0.8), (2, "B", 0.85), (3, "B", 0.1), (4, "C", 0.1), (5, "C", 0.2)]:
        learner.instances.add(image, {label})
        learner.instances.set(image, "f", value)
    for label in "ABC":
        learner.networks[label] = ClassNetwork(label)
    learner.networks["A"].add_feature("f")
    rec = Recognition({"A": 0.7, "B": 0.2, "C": 0.0}, {"A"}, ["f"], {"f": 0.9})
    entropy = residual_entropy(rec)
    assert entropy["C"] == 0 and entropy["A"] > 0 and entropy["B"] > 0
    c, d, weakest, _ = learner.choose_pair(rec, frozenset({"A"}), entropy)
    # A vs B: KSD 0.5 (one B value above the cut); A vs C: 1.0; B has no consulted feature: 0 against A
    assert (c, d, weakest) == ("B", "A", 0.0)
    learner.networks["B"].add_feature("f")
    c, d, weakest, _ = learner.choose_pair(rec, frozenset({"A"}), entropy)
    assert (c, d) == ("B", "A") and weakest == 0.0  # f is characteristic of A, not of B: zero power for B
    learner.networks["B"].remove_feature("f")
    entropy["B"] = 0.0
    assert learner.choose_pair(rec, frozenset({"A"}), entropy)[:3] == ("A", "B", pytest.approx(0.5))


def test_expert_features_meet_the_ksd_target(shapes):
    learner, _ = train(shapes, seed=5, cycles=10)
    accepted = 0
    for i in list(range(18)) * 2:
        before = {label: set(net.features) for label, net in learner.networks.items()}
        p = learner.learn(shapes, i, t_ksd=0.9)
        if p.result in ("expert", "expert-failed"):
            c, d = p.pair
            assert p.entropy[c] > 0 and p.ksd < 0.9 and (c in shapes.labels[i]) != (d in shapes.labels[i])
        if p.result == "expert":
            (new,) = set(learner.networks[p.pair[0]].features) - before[p.pair[0]]
            assert learner.counting.discretize(p.pair[0], [new], learner.settings)[1][0] >= 0.9
            assert learner.discriminates[(p.pair[0], new)] == {p.pair[1]}
            accepted += 1
    assert accepted > 0
    with pytest.raises(InputError, match="t_ksd"):
        learner.learn(shapes, 0, t_ksd=1.5)


@pytest.mark.parametrize("bits", [0.05, 0.2, 0.6])
def test_min_information_stops_recognition_early_and_only_then(shapes, bits):
    """The 4.4.2 stopping threshold: recognition queries a prefix of what alg. 4.4 would query, and
    stops where no unqueried feature has more than ``bits`` of information with any class."""
    learner, _ = train(shapes, seed=0)
    for image in range(18, 30):
        learner.set_params(test_information=0.0)
        full = learner.recognize(shapes, image)
        learner.set_params(test_information=bits)
        short = learner.recognize(shapes, image)
        assert short.queried == full.queried[:len(short.queried)]
        states = {label: engine(net).state({f: int(short.values[f] > net.threshold[f]) for f in short.queried if f in net})
                  for label, net in learner.networks.items()}
        remaining = [info for label, net in learner.networks.items() for f, info in
                     zip(net.features, engine(net).evaluate(states[label])[1]) if f not in short.values]
        assert max(remaining, default=0.0) <= bits
    with pytest.raises(InputError, match="min_information"):
        DistinctiveFeatureLearner.thesis(min_information=1.5)
    with pytest.raises(InputError, match="test_information"):
        DistinctiveFeatureLearner.thesis(test_information=-0.1)
    assert DistinctiveFeatureLearner.thesis(min_information=0.25).state_dict()["min_information"] == 0.25


def test_learning_stops_at_min_information_and_answers_at_test_information(shapes):
    """Two thresholds of alg. 4.4: the recognitions inside learning stop at ``min_information`` and
    decide what is learned; the learner's answers stop at ``test_information``. A state written
    before ``test_information`` existed answers with ``min_information``, as it did then."""
    def taught(test_bits):
        learner = DistinctiveFeatureLearner.thesis(seed=0, min_information=0.3, test_information=test_bits, redundancy=3,
                                            pseudocount=1)
        results = [learner.learn(shapes, i, t_ksd=0.9).result for i in list(range(18)) * 3]
        return learner, results

    short, results_short = taught(0.3)
    full, results_full = taught(0.0)
    assert results_short == results_full  # learning never consults test_information
    assert short.state_dict()["networks"] == full.state_dict()["networks"]
    asked_short = [len(short.recognize(shapes, i).queried) for i in range(18, 30)]
    asked_full = [len(full.recognize(shapes, i).queried) for i in range(18, 30)]
    assert all(a <= b for a, b in zip(asked_short, asked_full)) and sum(asked_short) < sum(asked_full)
    state = full.state_dict()
    first = full.learn(shapes, 0).recognition  # a recognition inside learning
    assert first.queried == short.recognize(shapes, 0).queried
    del state["test_information"], state["schema"]  # a file of schema 0, written before the option existed
    old = DistinctiveFeatureLearner.thesis()
    old.load_state_dict(state)
    assert old.settings.test_information == 0.3 and old.settings == short.settings
    # set_params: one way to answer with other settings, validated like the constructor
    assert full.set_params(test_information=0.3) is full and full.settings == short.settings
    assert [len(full.recognize(shapes, i).queried) for i in range(18, 30)] == asked_short
    with pytest.raises(InputError, match="test_information must lie in"):
        full.set_params(test_information=1.5)
    with pytest.raises(InputError, match="unknown learner options \\['bits'\\]"):
        full.set_params(bits=0.1)
    assert full.settings.test_information == 0.3  # a refused change changes nothing
