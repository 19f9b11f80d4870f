"""The incremental learner (alg. 4.7, 4.8, 4.10) on a small synthetic task, and its pieces."""
import cv2
import numpy as np
import pytest
import torch

from ftorch.environment import ImageSet
from ftorch.instances import InstanceList
from ftorch.learner import DistinctiveFeatureLearner
from ftorch.recognition import Recognition, accuracy


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
    learner = DistinctiveFeatureLearner(seed=seed)
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
    learner = DistinctiveFeatureLearner()
    rec = Recognition(beliefs, {c for c, p in beliefs.items() if p > 0.5}, beliefs=[beliefs])
    char, disc, char_is_true = learner.choose_classes(rec, frozenset(true))
    assert (char, set(disc), char_is_true) == expected


def test_zero_beliefs_consult_the_earlier_stage():
    learner = DistinctiveFeatureLearner()
    earlier = {"A": 0.4, "B": 0.4, "C": 0.3, "D": 0.3, "E": 0.2}
    final = dict.fromkeys(earlier, 0.0)
    rec = Recognition(final, set(), beliefs=[earlier, final])
    char, disc, char_is_true = learner.choose_classes(rec, frozenset({"A", "B"}))
    assert char in {"A", "B"} and set(disc) == {"C", "D"} and char_is_true


def test_instance_list_counts_only_measured_values():
    instances = InstanceList()
    instances.add("i1", {"A"})
    instances.add("i2", {"B"})
    instances.set("i1", "f", 0.5)
    assert instances.add("i1", {"A"}) == 0 and len(instances) == 2
    assert np.isnan(instances.get("i2", "f")) and instances.get("i1", "f") == 0.5
    assert instances.has("A").tolist() == [True, False] and instances.has_any({"A", "B"}).tolist() == [True, True]
    instances.forget("f")
    assert instances.features == [] and np.isnan(instances.get("i1", "f"))
