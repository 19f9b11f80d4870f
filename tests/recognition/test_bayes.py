"""Class networks: fast exact inference equals pgmpy, counting, arcs of 4.4.1, BIF export."""
import warnings

import numpy as np
import pytest

from ftorch.recognition import exact
from ftorch.recognition.bayes import CLASS, ClassNetwork, compound_arcs
from ftorch.recognition.exact import ExactInference, engine
from ftorch.space.features import Conjunction, Disjunction, Geometric, Part, Texel

warnings.filterwarnings("ignore", category=FutureWarning)


def random_network(rng, n_features: int, deterministic: bool = False, table_limit: int = ClassNetwork.TABLE_LIMIT) -> ClassNetwork:
    net = ClassNetwork("c", table_limit)
    for i in range(n_features):
        earlier = list(range(i))
        rng.shuffle(earlier)
        parents = earlier[: rng.integers(0, min(2, i) + 1)]
        children = [k for k in earlier[len(parents):][: rng.integers(0, 2)]]
        try:
            net.add_feature(i, parents=parents, children=children)
        except ValueError:
            net.add_feature(i, parents=parents)
    net.prior = np.array([0.0, 1.0]) + np.array([1, -1]) * rng.uniform(0.1, 0.9)
    for key in net.features:
        p = rng.uniform(0.02, 0.98, size=net.cpt[key].shape[:-1])
        if deterministic:
            p = np.where(rng.random(p.shape) < 0.3, np.round(p), p)
        net.set_cpt(key, np.stack([1 - p, p], axis=-1))
    return net


def pgmpy_query(net: ClassNetwork, variables, evidence):
    from pgmpy.inference import VariableElimination

    name = net.node_names()
    result = VariableElimination(net.to_pgmpy()).query(
        [name[v] for v in variables], evidence={name[k]: v for k, v in evidence.items()}, show_progress=False)
    order = [result.variables.index(name[v]) for v in variables]
    return np.transpose(result.values, order)


def information_from(joint: np.ndarray) -> float:
    """Mutual information in bits of a (2, 2) joint table, written out independently."""
    pc, pf = joint.sum(1), joint.sum(0)
    return sum(joint[c, f] * np.log2(joint[c, f] / (pc[c] * pf[f])) for c in range(2) for f in range(2) if joint[c, f] > 0)


@pytest.mark.parametrize("table_limit", [14, 0], ids=["tables", "einsum"])
@pytest.mark.parametrize("seed", range(8))
def test_fast_inference_equals_pgmpy_variable_elimination(seed, table_limit):
    rng = np.random.default_rng(seed)
    net = random_network(rng, n_features=int(rng.integers(3, 9)), table_limit=table_limit)
    assert all(g.table is None for g in engine(net).groups) == (table_limit == 0)
    assert net.to_pgmpy().check_model()
    for _ in range(4):
        observed = [k for k in net.features if rng.random() < 0.5]
        evidence = {k: int(rng.integers(0, 2)) for k in observed}
        np.testing.assert_allclose(engine(net).joint(evidence), pgmpy_query(net, [CLASS], evidence), rtol=0, atol=1e-9)
        assert engine(net).posterior(evidence) == pytest.approx(pgmpy_query(net, [CLASS], evidence)[1], abs=1e-9)
        informations = engine(net).informations(evidence)
        for query in (k for k in net.features if k not in evidence):
            expected = pgmpy_query(net, [CLASS, query], evidence)
            np.testing.assert_allclose(engine(net).joint(evidence, query), expected, rtol=0, atol=1e-9)
            assert informations[query] == pytest.approx(information_from(expected), abs=1e-9)


def test_large_linked_groups_take_einsum_and_equal_pgmpy():
    """A chain of 17 compound arcs is one group beyond TABLE_LIMIT: variable elimination by einsum."""
    rng = np.random.default_rng(7)
    net = ClassNetwork("chain")
    for i in range(17):
        net.add_feature(i, parents=[i - 1] if i else [])
        p = rng.uniform(0.05, 0.95, size=net.cpt[i].shape[:-1])
        net.set_cpt(i, np.stack([1 - p, p], axis=-1))
    assert len(net.features) > ClassNetwork.TABLE_LIMIT and engine(net).groups[0].table is None
    evidence = {0: 1, 5: 0, 16: 1}
    np.testing.assert_allclose(engine(net).joint(evidence), pgmpy_query(net, [CLASS], evidence), rtol=0, atol=1e-9)
    informations = engine(net).informations(evidence)
    for query in (3, 10):
        assert informations[query] == pytest.approx(information_from(pgmpy_query(net, [CLASS, query], evidence)), abs=1e-9)


def test_assigning_a_cpt_or_prior_takes_effect():
    net = ClassNetwork("c")
    net.add_feature("a")
    net.add_feature("b", parents=["a"])
    before = engine(net).posterior({"b": 1})
    net.set_cpt("b", np.array([[[0.9, 0.1], [0.9, 0.1]], [[0.1, 0.9], [0.1, 0.9]]]))
    assert engine(net).posterior({"b": 1}) == pytest.approx(0.9) and before == pytest.approx(0.5)
    net.prior = np.array([0.75, 0.25])
    assert engine(net).posterior({}) == pytest.approx(0.25)


def test_remembered_evaluations_equal_fresh_inference_and_are_forgotten_when_the_network_changes():
    rng = np.random.default_rng(5)
    net = random_network(rng, 7)
    states = [np.where(rng.random(7) < 0.5, rng.integers(0, 2, 7), -1) for _ in range(40)]
    for state in states + states:  # the second pass is answered from memory
        posterior, info = engine(net).evaluate(state)
        fresh = engine(net).infer(state)
        assert posterior == fresh[0] and np.array_equal(info, fresh[1])
    assert len(engine(net).memo) == len({s.tobytes() for s in states})
    state = states[0]
    before = engine(net).evaluate(state)[0]
    net.prior = net.prior[::-1].copy()
    assert len(engine(net).memo) == 0 and engine(net).evaluate(state)[0] == engine(net).infer(state)[0] != before
    net.set_cpt(3, np.full_like(net.cpt[3], 0.5))
    assert len(engine(net).memo) == 0
    net.add_feature(7, parents=[2])
    longer = np.append(state, -1)
    assert engine(net).evaluate(longer)[0] == engine(net).infer(longer)[0] and len(engine(net).evaluate(longer)[1]) == 8


def chain_and_singles(rng, linked: int, singles: int) -> ClassNetwork:
    """A chain of ``linked`` nodes (one group) and ``singles`` arc-free nodes outside it, random CPTs."""
    net = ClassNetwork("chain")
    for i in range(linked):
        net.add_feature(i, parents=[i - 1] if i else [])
    for i in range(linked, linked + singles):
        net.add_feature(i)
    for key in net.features:
        p = rng.uniform(0.05, 0.95, size=net.cpt[key].shape[:-1])
        net.set_cpt(key, np.stack([1 - p, p], axis=-1))
    return net


def test_large_groups_remember_contractions_by_their_own_evidence(monkeypatch):
    """A large group's contractions depend only on its own nodes' evidence: evidence elsewhere
    reuses them, the results equal contracting afresh bit for bit, and a change of the network
    forgets them (but not the einsum paths, which depend on the structure only)."""
    rng = np.random.default_rng(3)
    net = chain_and_singles(rng, 17, 3)
    group = engine(net).groups[0]
    assert group.table is None and len(engine(net).groups) == 1
    calls = []
    afresh = ExactInference._contract_afresh
    monkeypatch.setattr(ExactInference, "_contract_afresh", lambda self, *a: calls.append(1) or afresh(self, *a))
    inside = np.where(rng.random(17) < 0.3, rng.integers(0, 2, 17), -1)
    states = [np.concatenate([inside, outside]) for outside in ([-1, -1, -1], [1, -1, -1], [1, 0, -1], [1, 0, 1])]
    results = [engine(net).infer(state) for state in states]
    open_nodes = int((inside < 0).sum())
    assert len(calls) == 1 + open_nodes  # the likelihood and one query per open node, once for all four states
    for state, (posterior, info) in zip(states, results):
        group.contracted.clear()
        fresh = engine(net).infer(state)
        assert posterior == fresh[0] and np.array_equal(info, fresh[1])
    paths = engine(net).paths
    assert paths and all(len(expression.split(",")) > 3 for expression in paths)  # einsum paths found for big contractions
    before = engine(net)
    net.set_cpt(0, np.full_like(net.cpt[0], 0.5))
    assert engine(net) is not before and engine(net).groups[0].contracted == {}
    assert engine(net).paths is paths  # the paths depend on the structure only: they carry over to the new engine


def test_compiled_groups_remember_their_tables_by_their_own_evidence(monkeypatch):
    """A compiled group's likelihood and open-node tables depend only on its own nodes' evidence:
    evidence elsewhere reuses them, the results equal computing them afresh bit for bit and agree
    with pgmpy, and a change of the network forgets them."""
    net = chain_and_singles(np.random.default_rng(4), 4, 3)
    group = engine(net).groups[0]
    assert group.table is not None and len(engine(net).groups) == 1
    calls = []
    afresh = exact._Group._evidence
    monkeypatch.setattr(exact._Group, "_evidence", lambda self, own: calls.append(1) or afresh(self, own))
    inside = np.array([1, -1, 0, -1])
    states = [np.concatenate([inside, outside]) for outside in ([-1, -1, -1], [1, -1, -1], [1, 0, -1], [1, 0, 1])]
    results = [engine(net).infer(state) for state in states]
    assert len(calls) == 1  # once for all four states
    for state, (posterior, info) in zip(states, results):
        group.given.clear()
        fresh = engine(net).infer(state)
        assert posterior == fresh[0] and np.array_equal(info, fresh[1])
        evidence = {k: int(v) for k, v in zip(net.features, state) if v >= 0}
        np.testing.assert_allclose(posterior, pgmpy_query(net, [CLASS], evidence)[1], atol=1e-12)
        for i in np.flatnonzero(state < 0):
            expected = information_from(pgmpy_query(net, [CLASS, net.features[i]], evidence))
            assert info[i] == pytest.approx(expected, abs=1e-12)
    net.set_cpt(0, np.full_like(net.cpt[0], 0.5))
    assert engine(net).groups[0].given == {}


def test_mutual_information_vanishes_for_observed_or_certain_classes():
    rng = np.random.default_rng(1)
    net = random_network(rng, 4)
    assert engine(net).mutual_information(3, {}) > 0
    assert engine(net).mutual_information(3, {3: 1}) == pytest.approx(0, abs=1e-12)
    net.prior = np.array([0.0, 1.0])
    assert engine(net).mutual_information(3, {}) == pytest.approx(0, abs=1e-12)


def test_counting_with_unknown_values_and_the_zero_count_rule():
    net = ClassNetwork("duck")
    net.add_feature("a")
    net.add_feature("b", parents=["a"])
    present = np.array([1, 1, 1, 0, 0, 0], bool)
    states = {"a": np.array([1, 1, 0, 0, 0, -1]), "b": np.array([1, 0, 1, 0, 0, 0])}
    net.estimate(present, states)
    assert net.prior.tolist() == [0.5, 0.5]
    np.testing.assert_allclose(net.cpt["a"], [[1.0, 0.0], [1 / 3, 2 / 3]])  # class absent: a seen 0, 0 (one unknown)
    # b given (class, a): (0,0): two zeros; (0,1): never seen -> 1/2; (1,0): one 1; (1,1): one 1 and one 0
    np.testing.assert_allclose(net.cpt["b"], [[[1.0, 0.0], [0.5, 0.5]], [[0.0, 1.0], [0.5, 0.5]]])


@pytest.mark.parametrize("seed", range(3))
def test_counts_equal_counting_by_hand(seed):
    """Every CPT cell of random networks (nodes with 0 to several parents, unknown states) is
    (count + a) / (total + 2a) of its configuration, counted instance by instance."""
    rng = np.random.default_rng(seed)
    for _ in range(10):
        net = random_network(rng, int(rng.integers(1, 10)))
        n = int(rng.integers(0, 30))
        present = rng.random(n) < 0.5
        states = {k: rng.integers(-1, 2, n) for k in net.features}
        a = float(rng.choice([0.0, 1.0, 0.5]))
        net.estimate(present, states, a)
        for key in net.features:
            axes = [present.astype(int), *(states[p] for p in net.parents[key])]
            for config in np.ndindex(*(2,) * len(axes)):
                rows = [i for i in range(n) if all(x[i] == v for x, v in zip(axes, config)) and states[key][i] >= 0
                        and all(states[p][i] >= 0 for p in net.parents[key])]
                total = len(rows)
                ones = sum(states[key][i] == 1 for i in rows)
                expected = [0.5, 0.5] if total == 0 else [(total - ones + a) / (total + 2 * a), (ones + a) / (total + 2 * a)]
                assert net.cpt[key][config].tolist() == expected


def test_arcs_follow_compound_structure():
    texel = Texel([1.0] * 15)
    edgel = Part("edgel", (1.0, 0.0), phi=0.3, d=2.0)
    two = Geometric((Part("texel", texel.vector), edgel))
    three = Geometric((*two.parts, Part("edgel", (0.5, 0.5), d=1.0)))
    both = Conjunction(texel, three)
    either = Disjunction(texel, two)
    assert compound_arcs(three, [texel, two]) == ([], [texel, two])  # geometric -> its components
    assert compound_arcs(texel, [three, either]) == ([three], [either])  # component -> disjunction
    assert compound_arcs(both, [texel, three, two]) == ([], [texel, three, two])
    assert compound_arcs(either, [texel, two]) == ([texel, two], [])


def test_cycles_and_unknown_arcs_are_refused_and_bif_exports():
    net = ClassNetwork("x")
    net.add_feature("a")
    net.add_feature("b", parents=["a"])
    with pytest.raises(ValueError, match="cycle"):
        net.add_feature("c", parents=["b"], children=["a"])
    with pytest.raises(ValueError, match="not in the network"):
        net.add_feature("d", parents=["zzz"])
    bif = net.to_bif()
    assert "network x {" in bif and "variable class" in bif and "probability ( f1_b | class, f0_a )" in bif
    assert '<NAME>f1_b</NAME>' in net.to_xmlbif() and "network class_3 {" in ClassNetwork(3).to_bif()
    net.remove_feature("a")
    assert net.parents["b"] == () and net.cpt["b"].shape == (2, 2)


@pytest.mark.parametrize("seed", range(4))
def test_all_informations_at_once_equal_one_by_one(seed):
    rng = np.random.default_rng(100 + seed)
    net = random_network(rng, n_features=8)
    for extra in range(3):  # add arc-free nodes, which take the closed form
        net.add_feature(f"naive{extra}")
        p = rng.uniform(0.05, 0.95, size=2)
        net.set_cpt(f"naive{extra}", np.stack([1 - p, p], axis=-1))
    evidence = {k: int(rng.integers(0, 2)) for k in net.features if rng.random() < 0.4}
    together = engine(net).informations(evidence)
    assert set(together) == {k for k in net.features if k not in evidence}
    for key, info in together.items():
        assert info == pytest.approx(engine(net).mutual_information(key, evidence), abs=1e-12)


def test_a_network_changes_only_through_its_methods():
    """Its tables are read-only views, so nothing outside can leave the compiled inference stale."""
    net = ClassNetwork("c")
    net.add_feature("a")
    net.add_feature("b")
    with pytest.raises(TypeError):
        net.cpt["a"] = np.full((2, 2), 0.5)
    with pytest.raises(TypeError):
        net.threshold["a"] = 0.3
    with pytest.raises((TypeError, AttributeError)):
        net.parents["b"].append("a")
    with pytest.raises(ValueError, match="read-only"):
        net.cpt["a"][0, 0] = 0.9
    before = engine(net).posterior({"b": 1})
    net.add_arc("a", "b")  # a feature arc; b's CPT returns to 1/2 with a's state as a new axis
    assert net.parents["b"] == ("a",) and net.cpt["b"].shape == (2, 2, 2) and engine(net).posterior({"b": 1}) == before
    net.set_cpt("b", np.array([[[0.9, 0.1], [0.9, 0.1]], [[0.1, 0.9], [0.1, 0.9]]]))
    assert engine(net).posterior({"b": 1}) == pytest.approx(0.9)  # the compiled tables follow
    with pytest.raises(ValueError, match="shape"):
        net.set_cpt("b", np.full((2, 2), 0.5))
    with pytest.raises(ValueError, match="cycle"):
        net.add_arc("b", "a")
    net.set_threshold("a", 0.25)
    assert net.threshold["a"] == 0.25 and net.features == ("a", "b")
