"""Shared distinctions (issue 55, ask 3): a feature counts for every class distinction it makes, an
expert search measures its candidates against every class its class is short against and tries
first those that make the most of these distinctions; ``distinctions="pair"`` is alg. 5.2 as printed."""
from types import SimpleNamespace

import numpy as np
import pytest
import torch

from ftorch.ksd import distinctive_at
from ftorch.recognition.bayes import ClassNetwork
from ftorch.recognition.candidates import search_order
from ftorch.recognition.expertise import Weakest, makes
from ftorch.recognition.inference import Recognition, residual_entropy
from ftorch.recognition.learner import DistinctiveFeatureLearner
from ftorch.recognition.learning import Search
from ftorch.recognition.settings import Distinctions, LearnerSettings
from tests.recognition.test_learner import shapes  # noqa: F401  (fixture)


def _three_features(k: int, distinctions: str = "shared") -> DistinctiveFeatureLearner:
    """A holds f (high in A only), g (high in A and B) and h (high in A and C): f separates A from B,
    C and D, g from C and D, h from B and D."""
    out = DistinctiveFeatureLearner(redundancy=k, distinctions=distinctions)
    rows = [(0, "A", .9, .9, .9), (1, "A", .8, .8, .8), (2, "B", .1, .85, .1), (3, "B", .2, .9, .2),
            (4, "C", .1, .1, .9), (5, "C", .2, .2, .8), (6, "D", .1, .1, .1), (7, "D", .2, .2, .2)]
    for image, label, *values in rows:
        out.instances.add(image, {label})
        for key, value in zip("fgh", values):
            out.instances.set(image, key, value)
    for label in "ABCD":
        out.networks[label] = ClassNetwork(label)
    for key in "fgh":
        out.networks["A"].add_feature(key, threshold=0.5)
    return out


def test_one_feature_counts_for_every_distinction_it_makes():
    rec = Recognition({"A": 0.9, "B": 0.0, "C": 0.0, "D": 0.0}, {"A"}, ["f"], {"f": 0.9, "g": 0.9, "h": 0.9})
    entropy = residual_entropy(rec)
    one = _three_features(1).choose_pair(rec, frozenset({"A"}), entropy)
    assert one.support == {"B": 1.0, "C": 1.0, "D": 1.0}  # f alone makes all three
    two = _three_features(2).choose_pair(rec, frozenset({"A"}), entropy)
    assert two.support == {"B": 1.0, "C": 1.0, "D": 1.0}  # f with h, f with g, all three
    three = _three_features(3).choose_pair(rec, frozenset({"A"}), entropy)
    assert three == Weakest("A", "B", 0.0, {"B": 0.0, "C": 0.0, "D": 1.0})
    assert three.short(0.5, 3) == {"B", "C"} and three.short(0.0, 3) == {"B", "C"} and three.short(0.0, 1) == set()


def test_makes_needs_the_target_and_with_redundancy_some_power():
    support = np.array([0.0, 0.4, 0.5, 1.0])
    assert makes(support, 0.5, 1).tolist() == [False, False, True, True]
    assert makes(support, 0.0, 1).tolist() == [True] * 4
    assert makes(support, 0.0, 3).tolist() == [False, True, True, True]


def test_search_order_puts_the_most_served_first_then_power_in_drawing_order():
    candidates = ["a", "b", "c", "d", "e"]
    cuts, powers = np.arange(5.0), np.array([0.9, 0.2, 0.6, 0.8, 0.6])
    served = np.array([1.0, 3.0, 2.0, 1.0, 2.0])
    plain = LearnerSettings(n_fgen=3, contrast=2)
    order = [c for c, _, _ in search_order(candidates, cuts, powers, served, 0.5, plain)]
    assert order == ["b", "c", "e", "a"]  # b fails the power test (tested first), then 2, 2, 1 of the n_fgen = 3
    assert [c for c, _, _ in search_order(candidates, cuts, powers, 0 * served, 0.5, plain)] == ["b", "a", "d", "c"]
    printed = LearnerSettings(contrast=1)
    assert [c for c, _, _ in search_order(candidates, cuts, powers, served, 0.5, printed)] == ["b", "c", "e", "a", "d"]
    assert [c for c, _, _ in search_order(candidates, cuts, powers, 0 * served, 0.5, printed)] == candidates


@pytest.mark.parametrize("distinctions", list(Distinctions))
def test_an_expert_search_asks_for_the_short_distinctions_only_when_shared(distinctions, monkeypatch):
    learner = _three_features(3, distinctions)
    searches = []
    monkeypatch.setattr(learner, "_search", lambda env, image, search, *a: searches.append(search) or False)
    rec = Recognition({"A": 0.9, "B": 0.0, "C": 0.0, "D": 0.0}, {"A"}, ["f"], {"f": 0.9})
    learner._expert(SimpleNamespace(labels=[frozenset({"A"})]), 0, rec, residual_entropy(rec), 0.5)
    assert searches == [Search("A", frozenset({"B"}), True, frozenset({"C"}) if distinctions == "shared" else frozenset())]


def test_a_shared_search_measures_every_short_class_and_tries_the_most_served_first(shapes, monkeypatch):
    learner = DistinctiveFeatureLearner(seed=1, distinctions="shared")
    for i in range(18):
        learner.learn(shapes, i)
    tried = []
    monkeypatch.setattr(learner, "_try", lambda env, image, search, candidate, cut, *a: tried.append((candidate, cut)))
    search = Search(0, frozenset({1}), True, frozenset({2}))
    assert not learner._search(shapes, 0, search, 0.5, lambda rec: True)
    assert len(tried) > 1
    counted = learner.instances
    present = torch.from_numpy(counted.has(0))
    groups = torch.from_numpy(np.stack([counted.has(1), counted.has(2)]) & ~counted.has(0))
    values = torch.from_numpy(np.stack([counted.values(f) for f, _ in tried]))
    power = distinctive_at(values, torch.tensor([cut for _, cut in tried], dtype=torch.float64), present, groups).numpy()
    assert np.isfinite(values.numpy()[:, groups[1].numpy()]).sum(1).min() >= 5  # n_ex examples of class 2 measured
    assert (power[0] >= 0.5).all()  # each tried candidate passes alg. 5.1's test against the discriminated class
    served = power.sum(0)  # independent of the learner's count: ksd.distinctive_at on the instance list
    assert (np.diff(served) <= 1e-12).all(), served


def test_the_served_power_is_each_candidates_ksd_summed_over_the_distinctions():
    """f separates A from B, C and D; g from C and D; h from B and D (KSD 1 each): f first, whatever its
    power on the search's images; g and h serve two each and go by that power."""
    learner = _three_features(3)
    cuts, powers = np.full(3, 0.5), np.array([0.6, 0.9, 0.7])
    order = learner._in_order("A", ["B", "C", "D"], ["h", "g", "f"], cuts, powers, 0.5)
    assert [c for c, _, _ in order] == ["f", "g", "h"]
    assert [c for c, _, _ in learner._in_order("A", [], ["h", "g", "f"], cuts, powers, 0.5)] == ["g", "f", "h"]
