"""Def. 4.5 categories, def. 4.6 accuracy, and alg. 4.4 on hand-made networks."""
import numpy as np
import pytest

from ftorch.recognition.bayes import ClassNetwork
from ftorch.recognition.exact import engine
from ftorch.recognition.inference import accuracy, outcome, recognize


@pytest.mark.parametrize("recognized, true, expected", [
    ({"A"}, {"A"}, "correct"),
    ({"A", "B"}, {"A", "B"}, "correct"),
    (set(), set(), "correct"),
    ({"C"}, {"A"}, "wrong"),
    ({"A", "C"}, {"A", "B"}, "wrong"),      # table 4.1, first row: A, C recognized; A, B true
    ({"A", "B", "C"}, {"A", "B"}, "ambiguous"),  # table 4.1, second row
    (set(), {"A", "B"}, "ignorant"),        # table 4.1, last rows
    ({"A"}, {"A", "B"}, "ignorant"),
    ({"C", "D"}, {"A"}, "confused"),
    ({"A", "C", "D"}, {"A", "B"}, "confused"),
    ({"C"}, {"A", "B"}, "confused"),
    ({"C"}, set(), "ambiguous"),  # no true class: all (none) recognized, plus a false one
])
def test_outcome_categories(recognized, true, expected):
    assert outcome(recognized, true) == expected


def test_accuracy_definition():
    assert accuracy({"A"}, {"A"}, 6) == 1.0
    assert accuracy(set(), {"A"}, 6) == pytest.approx(1 / 6)  # ignorant counts as chance
    assert accuracy({"A", "B", "C"}, {"A"}, 6) == pytest.approx(1 / 3)  # ambiguous with two false
    assert accuracy({"C"}, {"A"}, 6) == 0.0
    assert accuracy({"A", "C"}, {"A", "B"}, 6) == pytest.approx(1 / 3)
    assert accuracy(set(), {"A", "B"}, 4) == pytest.approx(0.5)


def two_class_networks():
    """Class A has a perfect feature 'a'; class B a noisy feature 'b' and a perfect one 'bb'."""
    a = ClassNetwork("A")
    a.add_feature("a", threshold=0.5)
    a.prior = np.array([0.5, 0.5])
    a.set_cpt("a", np.array([[1.0, 0.0], [0.0, 1.0]]))
    b = ClassNetwork("B")
    b.add_feature("b", threshold=0.5)
    b.add_feature("bb", threshold=0.7)
    b.prior = np.array([0.6, 0.4])
    b.set_cpt("b", np.array([[0.8, 0.2], [0.3, 0.7]]))
    b.set_cpt("bb", np.array([[1.0, 0.0], [0.0, 1.0]]))
    return {"A": a, "B": b}


def test_recognition_queries_by_information_and_stops_when_certain():
    nets = two_class_networks()
    values = {"a": 0.9, "b": 0.2, "bb": 0.6}
    calls = []
    result = recognize(nets, lambda f: calls.append(f) or values[f])
    # 'a' and 'bb' each settle their class (1 bit and H(0.4) bits); 'a' first, then 'bb'; 'b' is then useless
    assert result.queried == ["a", "bb"] == calls
    assert result.posteriors == {"A": 1.0, "B": 0.0} and result.recognized == {"A"}
    assert result.beliefs[0] == {"A": 0.5, "B": 0.4} and len(result.beliefs) == 3
    assert result.beliefs[1]["A"] == 1.0 and result.beliefs[1]["B"] == 0.4


def test_negative_evidence_counts_and_impossible_evidence_is_skipped():
    nets = two_class_networks()
    nets["B"].set_cpt("bb", np.array([[1.0, 0.0], [0.5, 0.5]]))  # 'bb' never present without B
    result = recognize(nets, lambda f: {"a": 0.1, "b": 0.9, "bb": 0.1}[f])
    assert result.posteriors["A"] == 0.0  # absence of a perfect feature rules A out
    expected = engine(nets["B"]).posterior({"bb": 0, "b": 1})
    assert result.posteriors["B"] == pytest.approx(expected)


def network(label: str, cpt, *features: str) -> ClassNetwork:
    net = ClassNetwork(label)
    for key in features:
        net.add_feature(key, threshold=0.5)
        net.set_cpt(key, np.array(cpt, dtype=float))
    net.prior = np.array([0.5, 0.5])
    return net


@pytest.mark.parametrize("order", [("X", "Y"), ("Y", "X")])
def test_ties_go_to_the_first_network_then_its_first_feature(order):
    """Every feature is perfect (1 bit): the first network's first feature is asked, which settles that
    class; then the next network's first feature."""
    perfect = [[1.0, 0.0], [0.0, 1.0]]
    built = {"X": network("X", perfect, "x1", "x2"), "Y": network("Y", perfect, "y1", "y2")}
    result = recognize({k: built[k] for k in order}, lambda f: 0.9)
    assert result.queried == [f"{order[0].lower()}1", f"{order[1].lower()}1"]


def test_a_feature_is_asked_once_even_where_its_evidence_is_not_entered():
    """With positive evidence only, absent features stay unobserved and keep their information; a
    feature shared by two networks is asked once for both."""
    noisy = [[0.8, 0.2], [0.3, 0.7]]
    nets = {"X": network("X", noisy, "x1", "s"), "Y": network("Y", noisy, "s", "y1")}
    values = {"x1": 0.1, "s": 0.9, "y1": 0.1}  # x1 is asked first, absent and not entered; s then changes X
    calls = []
    result = recognize(nets, lambda f: calls.append(f) or values[f], positive_only=True)
    assert sorted(calls) == ["s", "x1", "y1"] and result.queried == calls and calls[0] == "x1"
    assert result.posteriors["X"] == result.posteriors["Y"] == engine(nets["X"]).posterior({"s": 1})  # only s entered
    both = recognize(nets, lambda f: 0.9)
    assert sorted(both.queried) == ["s", "x1", "y1"] and both.posteriors["X"] == both.posteriors["Y"] > 0.5


def test_recognition_follows_networks_that_change_between_calls():
    """The index of the networks is reused while they keep their features: a feature added,
    removed, or a network added or reordered is seen at the next recognition, which then equals
    one by a freshly indexed recognizer."""
    from ftorch.recognition.inference import Plan

    perfect = [[1.0, 0.0], [0.0, 1.0]]
    nets = {"X": network("X", perfect, "x1"), "Y": network("Y", [[0.8, 0.2], [0.3, 0.7]], "y1")}
    values = {"x1": 0.1, "y1": 0.9, "y2": 0.9, "z1": 0.9}

    plans = [None]  # the plan a learner keeps between its recognitions

    def both_ways(networks):
        plans.append(Plan.of(networks, plans[-1]))
        kept = recognize(networks, values.__getitem__, plan=plans[-1])
        fresh = recognize(networks, values.__getitem__)
        assert (kept.queried, kept.posteriors, kept.beliefs) == (fresh.queried, fresh.posteriors, fresh.beliefs)
        return kept

    assert both_ways(nets).queried == ["x1", "y1"]
    nets["Y"].set_cpt("y1", np.array([[0.8, 0.2], [0.3, 0.7]]))
    assert Plan.of(nets, plans[-1]) is plans[-1]  # a new CPT keeps the structure: the plan is reused
    nets["Y"].add_feature("y2", threshold=0.5)
    nets["Y"].set_cpt("y2", np.array(perfect))
    assert both_ways(nets).queried == ["x1", "y2"]  # the perfect new feature settles Y first
    assert plans[-1] is not plans[-2]  # a new plan for the new structure
    nets["Z"] = network("Z", perfect, "z1")
    assert "z1" in both_ways(nets).queried
    assert both_ways({k: nets[k] for k in ("Z", "Y", "X")}).queried[0] == "z1"  # ties: the first network
    nets["Y"].remove_feature("y2")
    assert "y2" not in both_ways(nets).queried


def random_networks(rng: np.random.Generator) -> dict:
    """Networks over a shared pool of features: some shared by several networks, linked groups (compound
    arcs), deterministic CPT rows (impossible evidence), duplicated CPTs and equal values (ties)."""
    pool = [f"f{i}" for i in range(12)]
    nets = {}
    for label in "ABCD":
        net = ClassNetwork(label, table_limit=int(rng.integers(0, 6)))  # some groups compiled, some by einsum
        for key in rng.choice(pool, size=int(rng.integers(2, 7)), replace=False).tolist():
            parents = [p for p in net.features if rng.random() < 0.3][:2]
            net.add_feature(key, parents=parents, threshold=float(rng.choice([0.25, 0.5, 0.75])))
        for key in net.features:
            shape = (2,) * (len(net.parents[key]) + 1)
            present = rng.choice([0.0, 0.2, 0.5, 0.8, 1.0], size=shape)  # 0 and 1: impossible evidence
            net.set_cpt(key, np.stack([1 - present, present], -1))
        net.prior = np.array([0.5, 0.5]) if rng.random() < 0.5 else np.array([0.7, 0.3])
        nets[label] = net
    if rng.random() < 0.5:  # a twin network: every information tied with another network's
        twin = nets["A"]
        copy = ClassNetwork("E")
        for key in twin.features:
            copy.add_feature(key, parents=twin.parents[key], threshold=twin.threshold[key])
            copy.set_cpt(key, twin.cpt[key])
        copy.prior = twin.prior
        nets["E"] = copy
    return nets


@pytest.mark.parametrize("seed", range(12))
@pytest.mark.parametrize("positive_only", [False, True])
def test_a_block_of_images_is_recognized_as_each_image_alone(seed, positive_only):
    """Alg. 4.4 for many images at once gives each image's queries, values, beliefs and answer bit for
    bit, ties and impossible evidence included."""
    from ftorch.recognition.inference import Plan, recognize_block

    rng = np.random.default_rng(seed)
    nets = random_networks(rng)
    plan = Plan.of(nets)
    values = rng.choice([0.1, 0.25, 0.5, 0.6, 0.75, 0.9], size=(len(plan.keys), 40))  # equal to thresholds too
    block = recognize_block(nets, values, positive_only=positive_only, plan=plan)
    for b, got in enumerate(block):
        column = dict(zip(plan.keys, values[:, b].tolist()))
        alone = recognize(nets, column.__getitem__, positive_only=positive_only)
        assert got.queried == alone.queried and got.values == alone.values
        assert got.beliefs == alone.beliefs and got.posteriors == alone.posteriors and got.recognized == alone.recognized
    assert recognize_block(nets, values[:, :0], plan=plan) == []
    with pytest.raises(ValueError, match="features"):
        recognize_block(nets, values[1:], plan=plan)


def _decided_and_open():
    """Two-class networks where A holds 'x' beside its perfect 'a', and B holds 'x' and its noisy 'b',
    not its perfect 'bb': A can be decided, B never."""
    nets = two_class_networks()
    nets["A"].add_feature("x", threshold=0.5)
    nets["A"].set_cpt("x", np.array([[0.8, 0.2], [0.3, 0.7]]))
    nets["B"].remove_feature("bb")
    nets["B"].add_feature("x", threshold=0.5)
    nets["B"].set_cpt("x", np.array([[0.7, 0.3], [0.2, 0.8]]))
    return nets


@pytest.mark.parametrize("block", [False, True])
def test_a_decided_network_is_neither_asked_nor_told_and_an_undecided_one_goes_on(block, monkeypatch):
    from ftorch.recognition.exact import ExactInference
    from ftorch.recognition.inference import decided, recognize_block

    nets = _decided_and_open()
    values = {"a": 0.9, "x": 0.8, "b": 0.7}
    calls = []
    evaluate = ExactInference.evaluate
    monkeypatch.setattr(ExactInference, "evaluate", lambda self, state: calls.append(
        (self.network.label, tuple(state.tolist()))) or evaluate(self, state))
    if block:
        table = np.array([[values["a"], values["x"], values["b"]]] * 30).T  # plan keys: a, x, b
        rec = recognize_block(nets, table)[0]
    else:
        rec = recognize(nets, values.__getitem__)
    assert rec.queried[0] == "a" and sorted(rec.queried) == ["a", "b", "x"]  # B, undecided, is still asked for both its features
    assert {label for label, state in calls if label == "A" and state[1] >= 0} == set()  # A, decided by 'a', is not told 'x'
    assert rec.posteriors["A"] == 1.0 and decided(engine(nets["A"]), np.array([1, -1]), 1.0)
    expected = engine(nets["B"]).posterior({"x": 1, "b": 1})  # B told everything, as without the rule
    assert rec.posteriors["B"] == pytest.approx(expected, abs=0, rel=1e-15)
    rounded = ClassNetwork("R")  # no zero anywhere: a belief of 1.0 is only rounded, not decided
    rounded.add_feature("r")
    rounded.prior = np.array([1e-17, 1 - 1e-17])
    rounded.set_cpt("r", np.array([[0.5, 0.5], [0.5, 0.5]]))
    assert engine(rounded).posterior({}) == 1.0 and not decided(engine(rounded), np.array([-1]), 1.0)
