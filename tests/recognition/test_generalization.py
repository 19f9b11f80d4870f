"""The learner's generalization options (issue 13): the search cap of alg. 5.1's "until",
redundant distinctive features (7.2.4), positive-only evidence (4.4.2) and CPT pseudocounts."""
import numpy as np
import pytest
import torch

from ftorch.errors import InputError
from ftorch.ksd import distinctive_at, ksd
from ftorch.recognition.bayes import ClassNetwork
from ftorch.recognition.candidates import Method
from ftorch.recognition.counting import Counting
from ftorch.recognition.exact import engine
from ftorch.recognition.inference import Recognition, recognize, residual_entropy
from ftorch.recognition.learner import DistinctiveFeatureLearner
from ftorch.recognition.learning import Search
from ftorch.recognition.settings import LearnerSettings, Primitive
from tests.recognition.test_learner import shapes  # noqa: F401  (fixture)
from tests.recognition.test_recognition import two_class_networks


def _train(env, learner, cycles: int, t_ksd: float = 0.0, order_seed: int = 0) -> list[list[str]]:
    order = torch.Generator().manual_seed(order_seed)
    history = []
    for _ in range(cycles):
        begin = learner.presentations
        history.append([learner.learn(env, i, t_ksd).result for i in torch.randperm(18, generator=order).tolist()])
        learner.discard_unused(since=begin + 1)
    return history


def _search(env, rounds: int, succeed_at: int | None, monkeypatch) -> tuple[bool, list, list]:
    """A search for class 0 against 1 in which only the ``succeed_at``-th candidate discretized reaches
    the target; returns (found, the alg. 4.10 methods called, the candidates discretized)."""
    learner = DistinctiveFeatureLearner.thesis(seed=1, search_rounds=rounds)
    _train(env, learner, cycles=1)
    calls, tried = [], []
    generate = learner.candidates
    monkeypatch.setattr(learner, "candidates", lambda method, *a: calls.append(method) or generate(method, *a))

    def power(label, features, settings, against=None):
        first = len(tried)
        tried.extend(features)
        return np.zeros(len(features)), np.array([float(first + j == succeed_at) for j in range(len(features))])
    monkeypatch.setattr(learner.counting, "discretize", power)
    found = learner._search(env, 0, Search(0, frozenset({1}), True), 0.5, lambda rec: True)
    if found:  # the successful candidate, and no other of those discretized, joined class 0's network
        assert [f for f in tried if f in learner.networks[0]] == [tried[succeed_at]]
    return found, calls, tried


@pytest.mark.parametrize("rounds", [1, 3])
def test_a_hopeless_search_calls_alg_4_10_search_rounds_times_and_never_retries_a_candidate(shapes, rounds, monkeypatch):
    found, calls, tried = _search(shapes, rounds, None, monkeypatch)
    assert not found and calls == list(Method) * rounds
    assert len(tried) == len(set(tried)) > 0  # a failed candidate is not tried again


def test_the_search_goes_on_past_one_call_of_alg_4_10_and_stops_at_the_first_success(shapes, monkeypatch):
    _, _, first_round = _search(shapes, 1, None, monkeypatch)
    n = len(first_round) + 3  # a candidate of the second call
    assert not _search(shapes, 1, n, monkeypatch)[0]
    found, calls, tried = _search(shapes, 3, n, monkeypatch)
    assert found and tried[:len(first_round)] == first_round
    assert n < len(tried) <= n + 10  # the search ended with the call of alg. 4.10 (n_fgen = 10) that held it
    assert 5 < len(calls) < 10


def test_redundancy_scores_a_pair_by_its_kth_strongest_feature_over_the_whole_network():
    """A (true, certain) holds f, separating it from B and C, and g, separating it from C only."""
    def learner(k):
        out = DistinctiveFeatureLearner.thesis(redundancy=k)
        rows = [(0, "A", .9, .9), (1, "A", .8, .8), (2, "B", .1, .85), (3, "B", .2, .9), (4, "C", .1, .1), (5, "C", .2, .2)]
        for image, label, f, g in rows:
            out.instances.add(image, {label})
            out.instances.set(image, "f", f)
            out.instances.set(image, "g", g)
        for label in "ABC":
            out.networks[label] = ClassNetwork(label)
        out.networks["A"].add_feature("f")
        out.networks["A"].add_feature("g")
        return out
    rec = Recognition({"A": 1.0, "B": 0.0, "C": 0.0}, {"A"}, ["f"], {"f": 0.9})
    entropy = residual_entropy(rec)
    assert learner(1).choose_pair(rec, frozenset({"A"}), entropy) is None  # no class uncertain: alg. 5.2 as printed
    two = learner(2)
    assert two.choose_pair(rec, frozenset({"A"}), entropy)[:3] == ("A", "B", 0.0)  # g does not carry A vs B
    assert set(two.usage) == {"f", "g"}  # both carry A vs C: used
    assert learner(3).choose_pair(rec, frozenset({"A"}), entropy)[:3] == ("A", "B", 0.0)


def _support(learner, c, d) -> list[float]:
    net = learner.networks[c]
    present = torch.from_numpy(learner.instances.has(c))
    values = torch.from_numpy(np.stack([learner.instances.values(f) for f in net.features]))
    cuts = torch.tensor([net.threshold[f] for f in net.features], dtype=torch.float64)
    return distinctive_at(values, cuts, present, (torch.from_numpy(learner.instances.has(d)) & ~present)[None])[0].tolist()


@pytest.mark.parametrize("k", [2, 3])
def test_after_a_clean_cycle_every_needed_distinction_has_k_distinctive_features(shapes, k):
    learner = DistinctiveFeatureLearner.thesis(seed=0, redundancy=k)
    history = _train(shapes, learner, cycles=12)
    clean = [n for n, h in enumerate(history) if all(r == "correct" for r in h)]
    assert clean, history
    learner = DistinctiveFeatureLearner.thesis(seed=0, redundancy=k)
    _train(shapes, learner, cycles=clean[0] + 1)
    labels = sorted({c for i in range(18) for c in shapes.labels[i]})
    for c in labels:
        for d in labels:
            if d != c:
                assert sum(p > 0 for p in _support(learner, c, d)) >= k, (c, d)
    single = DistinctiveFeatureLearner.thesis(seed=0)
    _train(shapes, single, cycles=clean[0] + 1)
    assert sum(len(n.features) for n in single.networks.values()) < sum(len(n.features) for n in learner.networks.values())


def test_positive_evidence_enters_presence_only():
    nets = two_class_networks()
    values = {"a": 0.1, "b": 0.9, "bb": 0.1}
    both = recognize(nets, values.__getitem__)
    assert both.posteriors["A"] == 0.0  # absence of A's perfect feature rules A out
    positive = recognize(nets, values.__getitem__, positive_only=True)
    assert positive.posteriors["A"] == 0.5  # its absence is not entered: the prior stays
    assert positive.posteriors["B"] == pytest.approx(engine(nets["B"]).posterior({"b": 1}))
    present = {"a": 0.9, "b": 0.9, "bb": 0.9}
    assert recognize(nets, present.__getitem__, positive_only=True).posteriors == recognize(nets, present.__getitem__).posteriors


def test_a_positive_evidence_learner_recognizes_with_presence_only(shapes):
    learner = DistinctiveFeatureLearner.thesis(seed=0, evidence="positive")
    _train(shapes, learner, cycles=3)
    for image in range(18, 30):
        rec = learner.recognize(shapes, image)
        evidence = {label: {f: 1 for f in rec.queried if f in net and rec.values[f] > net.threshold[f]}
                    for label, net in learner.networks.items()}
        for label, net in learner.networks.items():
            assert rec.posteriors[label] == pytest.approx(engine(net).posterior(evidence[label]))


def test_pseudocounts_follow_laplace_and_zero_keeps_relative_frequencies():
    net = ClassNetwork("A")
    net.add_feature("f")
    present = np.array([1, 1, 1, 0, 0, 0, 0], bool)
    states = {"f": np.array([1, 1, 1, 1, 0, 0, -1])}
    net.estimate(present, states)
    assert net.cpt["f"].tolist() == [[2 / 3, 1 / 3], [0.0, 1.0]]
    net.estimate(present, states, pseudocount=1.0)
    assert np.allclose(net.cpt["f"], [[3 / 5, 2 / 5], [1 / 5, 4 / 5]])
    assert engine(net).posterior({"f": 0}) > 0  # absence no longer rules A out


def test_a_leak_mixes_every_cpt_entry_with_its_complement_and_keeps_one_miss_from_ruling_a_class_out():
    """l + (1 - 2l) p for every entry, after the counts (and any pseudocount) are taken."""
    net = ClassNetwork("A")
    net.add_feature("f")
    net.add_feature("g", parents=["f"])
    present = np.array([1, 1, 1, 1, 0, 0, 0, 0], bool)
    states = {"f": np.array([1, 1, 1, 1, 0, 0, 0, 1]), "g": np.array([1, 1, 1, 1, 0, 0, 1, 0])}
    plain = ClassNetwork("A")
    plain.add_feature("f")
    plain.add_feature("g", parents=["f"])
    for pseudocount in (0.0, 1.0):
        plain.estimate(present, states, pseudocount)
        net.estimate(present, states, pseudocount, leak=0.1)
        for key in ("f", "g"):
            assert np.allclose(net.cpt[key], 0.1 + 0.8 * plain.cpt[key])
            assert np.allclose(net.cpt[key].sum(-1), 1)
        assert np.allclose(net.prior, plain.prior)  # the class prior is counted, not leaked
    net.estimate(present, states, 0.0, leak=0.1)
    plain.estimate(present, states, 0.0)
    assert engine(plain).posterior({"f": 0, "g": 1}) == 0  # f was present in every view of A: its absence rules A out
    assert engine(net).posterior({"f": 0, "g": 1}) > 0.05  # with the leak, g's presence still speaks for A


def _calibration_case(selected: set) -> tuple[Counting, ClassNetwork, np.ndarray, np.ndarray]:
    """Ten instances, 0-4 of A and 5-9 of B, and one node f of A at threshold 0.5 selected on ``selected``:
    on 0, 1, 5, 6 f separates A from B perfectly, on the others it fires as often on B as on A."""
    values = np.array([0.9, 0.8, 0.7, 0.2, 0.6, 0.1, 0.3, 0.8, 0.55, 0.4])
    present = np.arange(10) < 5
    counting = Counting()
    for i in range(10):
        counting.instances.add(i, {"A" if present[i] else "B"})
    counting.instances.set_block(list(range(10)), ["f"], values[None])
    counting.selected[("A", "f")] = frozenset(selected)
    net = ClassNetwork("A")
    net.add_feature("f", threshold=0.5)
    return counting, net, values, present


def _counted_on(values: np.ndarray, present: np.ndarray, rows: list[int], threshold: float, pseudocount: float) -> np.ndarray:
    """The CPT [c, f] counted by hand on ``rows`` only."""
    table = np.zeros((2, 2))
    for i in rows:
        table[int(present[i]), int(values[i] > threshold)] += 1
    return (table + pseudocount) / (table.sum(1, keepdims=True) + 2 * pseudocount)


def test_calibrated_counting_leaves_a_nodes_selection_images_out_where_enough_remain():
    """Cut-point and CPT on the held-out instances (brute force); all of them without calibrate or with too few left."""
    selected = {0, 1, 5, 6}
    held = [i for i in range(10) if i not in selected]
    for calibrate, rows in ((True, held), (False, list(range(10)))):
        counting, net, values, present = _calibration_case(selected)
        settings = LearnerSettings.thesis(pseudocount=1.0, calibrate=calibrate)
        counting.estimate(net, settings)
        assert np.allclose(net.cpt["f"], _counted_on(values, present, rows, 0.5, 1.0))
        assert np.allclose(net.prior, [0.5, 0.5])  # the prior counts every instance
        cuts, powers = counting.discretize("A", ["f"], settings)
        expected = ksd(torch.from_numpy(values[rows][None]), torch.from_numpy(present[rows]),
                       torch.from_numpy(~present[rows]))
        assert np.allclose(cuts, expected.cutpoint.numpy()) and np.allclose(powers, expected.distinctive.numpy())
    # the case tells the two apart: held out, f fires on B as often as on A
    assert not np.allclose(_counted_on(values, present, held, 0.5, 1.0), _counted_on(values, present, range(10), 0.5, 1.0))
    # only one instance of A outside the selection images: not enough to count on, so all count
    counting, net, values, present = _calibration_case({0, 1, 2, 3, 5})
    counting.estimate(net, LearnerSettings.thesis(pseudocount=1.0, calibrate=True))
    assert np.allclose(net.cpt["f"], _counted_on(values, present, list(range(10)), 0.5, 1.0))


def test_a_calibrated_learner_records_saves_and_checks_each_nodes_selection_images(shapes):
    learner = DistinctiveFeatureLearner.thesis(seed=2, calibrate=True)
    _train(shapes, learner, cycles=2)
    selected = learner.counting.selected
    nodes = {(c, f) for c, net in learner.networks.items() for f in net.features}
    assert selected and set(selected) <= nodes
    assert all(images <= set(learner.instances.images) and len(images) >= 2 for images in selected.values())
    state = learner.state_dict()
    copy = DistinctiveFeatureLearner.thesis()
    copy.load_state_dict(state)
    assert copy.settings.calibrate and copy.counting.selected == selected
    for net in learner.networks.values():
        copy.counting.estimate(copy.networks[net.label], copy.settings)
        assert all(np.array_equal(copy.networks[net.label].cpt[f], net.cpt[f]) for f in net.features)
    state["selected"][0][2] = [10**6]
    with pytest.raises(ValueError, match="not an instance"):
        DistinctiveFeatureLearner.thesis().load_state_dict(state)
    state.pop("selected")  # an older file: every node counted on all instances
    older = DistinctiveFeatureLearner.thesis()
    older.load_state_dict(state)
    assert older.counting.selected == {}


def test_options_are_saved_validated_and_refused_with_one_line(shapes):
    learner = DistinctiveFeatureLearner.thesis(search_rounds=3, redundancy=2, evidence="positive", pseudocount=0.5,
                                        test_information=0.2, leak=0.05, primitives="texture,edgel")
    copy = DistinctiveFeatureLearner.thesis()
    copy.load_state_dict(learner.state_dict())
    assert copy.settings == LearnerSettings(n_ex=5, n_fgen=10, min_information=0.0, search_rounds=3, redundancy=2,
                                            evidence="positive", pseudocount=0.5, leak=0.05, cut_position=0.5,
                                            test_information=0.2, primitives=(Primitive.EDGEL, Primitive.TEXTURE),
                                            contrast=1, calibrate=False, distinctions="pair")
    for bad in ({"search_rounds": 0}, {"redundancy": 0}, {"evidence": "negative"}, {"distinctions": "all"}, {"pseudocount": -1.0},
                {"pseudocount": float("nan")}, {"test_information": 1.0}, {"test_information": float("nan")},
                {"leak": 0.5}, {"leak": -0.1}, {"leak": float("nan")}, {"primitives": ""}, {"calibrate": "yes"}):
        with pytest.raises(InputError):
            DistinctiveFeatureLearner.thesis(**bad)


@pytest.mark.parametrize("option", [["--search-rounds", "0"], ["--redundancy", "0"], ["--pseudocount", "-1"],
                                    ["--pseudocount", "inf"], ["--test-information", "1"], ["--leak", "0.5"],
                                    ["--primitives", "texel,texel"], ["--distinctions", "all"]])
def test_bad_options_are_refused_with_one_line_before_any_work(option, tmp_path, capsys):
    from training import run
    try:
        code = run.main(["recognize", "--task", "plym", "--out", str(tmp_path / "run"), *option])
    except SystemExit as refused:  # counts are refused by the parser itself
        code = refused.code
    assert code == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("error:") and not (tmp_path / "run").exists()


@pytest.mark.parametrize("position", [0.0, 0.25, 0.5, 1.0])
def test_the_cut_position_moves_the_cut_point_within_its_gap_and_nothing_else(position):
    from ftorch.ksd import ksd
    values = torch.tensor([[0.1, 0.2, 0.3, 0.7, 0.8, 0.9]], dtype=torch.float64)
    own = torch.tensor([False, False, False, True, True, True])
    middle, moved = ksd(values, own, ~own), ksd(values, own, ~own, position)
    assert middle.cutpoint.item() == pytest.approx(0.5) and moved.cutpoint.item() == pytest.approx(0.3 + 0.4 * position)
    assert torch.equal(middle.distinctive, moved.distinctive) and torch.equal(middle.distance, moved.distance)
    with pytest.raises(InputError, match="cut_position"):
        DistinctiveFeatureLearner.thesis(cut_position=1.5)
