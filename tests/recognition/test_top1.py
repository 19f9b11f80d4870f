"""The top-1 answer beside the thesis's open world (issue 53): alg. 4.4 continued on the candidates'
networks, then the largest posterior (def. 4.5's set stays the answer it scores by def. 4.6); the
log posterior odds that break saturated ties, proved against a brute-force joint and pgmpy; the
learner's answers on a learned task, block and image by image; learning untouched (the runner's
reports: tests/training/test_top1_report.py)."""
import itertools
import json
import math

import numpy as np
import pytest
from scipy.special import logsumexp

from ftorch import Answer, DistinctiveFeatureLearner, ImageSet, InputError, LearnerSettings
from ftorch.recognition.bayes import CLASS, ClassNetwork
from ftorch.recognition.exact import engine
from ftorch.recognition.inference import Outcome, Plan, Recognition, outcome, recognize, recognize_block, top_class
from ftorch.recognition.recognizer import BLOCK_MIN
from tests.recognition.test_bayes import pgmpy_query, random_network
from training.data.datasets import plym_task
from training.recognition.protocol import test_block as scored  # (a test_ name would be collected)

PRESENT, ABSENT = 0.9, 0.1  # feature values above and below every hand-made network's threshold 0.5


# -- the log posterior odds (ftorch/recognition/exact.py) ----------------------------------------------

def brute_log_joint(net: ClassNetwork, evidence: dict) -> np.ndarray:
    """log P(C = c, e) for c = 0, 1, by summing the full joint (prior times every CPT entry) over every
    configuration of the unobserved feature nodes, in log space (no underflow)."""
    keys = list(net.features)
    open_keys = [k for k in keys if k not in evidence]
    with np.errstate(divide="ignore"):
        out = []
        for c in (0, 1):
            terms = []
            for bits in itertools.product((0, 1), repeat=len(open_keys)):
                value = {**evidence, **dict(zip(open_keys, bits))}
                entries = [net.prior[c]] + [net.cpt[k][(c, *(value[p] for p in net.parents[k]), value[k])] for k in keys]
                terms.append(float(np.sum(np.log(entries))))
            out.append(logsumexp(terms))
    return np.array(out)


@pytest.mark.parametrize("table_limit", [14, 0], ids=["tables", "einsum"])
@pytest.mark.parametrize("deterministic", [False, True], ids=["soft", "with-zeros"])
@pytest.mark.parametrize("seed", range(6))
def test_log_odds_equal_a_brute_force_joint_and_pgmpy_on_random_networks(seed, deterministic, table_limit):
    rng = np.random.default_rng(seed)
    net = random_network(rng, n_features=int(rng.integers(3, 8)), deterministic=deterministic, table_limit=table_limit)
    checked = 0
    for _ in range(6):
        evidence = {k: int(rng.integers(0, 2)) for k in net.features if rng.random() < 0.6}
        got = engine(net).log_odds(engine(net).state(evidence))
        joint = brute_log_joint(net, evidence)
        if np.isneginf(joint).all():  # impossible evidence under both class values
            assert math.isnan(got)
            continue
        expected = joint[1] - joint[0]
        if math.isinf(expected):  # impossible under one class value only
            assert got == expected
            continue
        assert got == pytest.approx(expected, rel=1e-9, abs=1e-9)
        posterior = pgmpy_query(net, [CLASS], evidence)
        if posterior.min() > 0:
            assert got == pytest.approx(math.log(posterior[1] / posterior[0]), rel=1e-6, abs=1e-9)
        checked += 1
    assert checked  # some finite odds were compared on every network


def test_log_odds_do_not_saturate_where_the_posterior_does():
    """120 strong arc-free features and a linked group: all present gives posterior 1.0 in float and all
    absent 0.0, yet the log odds are finite and equal the brute-force sums."""
    net = ClassNetwork("s")
    for i in range(120):
        net.add_feature(f"f{i}")
        net.set_cpt(f"f{i}", np.array([[0.999, 0.001], [0.002, 0.998]]))
    net.add_feature("g0")
    net.add_feature("g1", parents=["g0"])
    net.set_cpt("g0", np.array([[0.7, 0.3], [0.2, 0.8]]))
    net.set_cpt("g1", np.array([[[0.9, 0.1], [0.6, 0.4]], [[0.5, 0.5], [0.1, 0.9]]]))
    net.prior = np.array([0.3, 0.7])
    for side, saturated in ((1, 1.0), (0, 0.0)):
        evidence = {**{f"f{i}": side for i in range(120)}, "g1": side}  # g0 open: the group sums over it
        assert engine(net).posterior(evidence) == saturated
        got = engine(net).log_odds(engine(net).state(evidence))
        joint = brute_log_joint(net, evidence)
        assert math.isfinite(got) and abs(got) > 700 and got == pytest.approx(joint[1] - joint[0], rel=1e-12)


# -- the rule on hand-made networks (ftorch/recognition/inference.py) ---------------------------------

def network(label, features: dict, prior: float = 0.5) -> ClassNetwork:
    """Arc-free features, each given as (P(present | not the class), P(present | the class))."""
    net = ClassNetwork(label)
    net.prior = np.array([1 - prior, prior])
    for key, (off, on) in features.items():
        net.add_feature(key, threshold=0.5)
        net.set_cpt(key, np.array([[1 - off, off], [1 - on, on]]))
    return net


def three_networks() -> dict:
    """Each class has a strong feature (x1) and a weak one (x2) that a threshold of 0.3 bits leaves unasked."""
    return {"A": network("A", {"a1": (0.1, 0.9), "a2": (0.4, 0.6)}),
            "B": network("B", {"b1": (0.15, 0.85), "b2": (0.4, 0.6)}),
            "C": network("C", {"c1": (0.1, 0.9), "c2": (0.4, 0.6)})}


def measured(values: dict, calls: list):
    return lambda key: calls.append(key) or values[key]


def test_an_ambiguous_answer_goes_on_with_the_recognized_networks_and_takes_the_larger_posterior():
    nets = three_networks()
    values = {"a1": PRESENT, "b1": PRESENT, "c1": ABSENT, "a2": ABSENT, "b2": PRESENT, "c2": PRESENT}
    first = recognize(nets, values.__getitem__, tolerance=0.3)
    assert first.recognized == {"A", "B"} and first.top is None  # ambiguous; no top label unless asked
    assert first.queried == ["a1", "c1", "b1"] and first.posteriors["A"] > first.posteriors["B"]
    calls = []
    answered = recognize(nets, measured(values, calls), tolerance=0.3, top=True)
    # the recognition is alg. 4.4's as before; going on asks the candidates' unasked features, never C's
    assert (answered.queried, answered.posteriors, answered.recognized) == (first.queried, first.posteriors, first.recognized)
    assert calls[:3] == first.queried and sorted(calls[3:]) == ["a2", "b2"] and "c2" not in calls
    # after a2 absent and b2 present: P(A) = .36/.42 < P(B) = .51/.57, so B, though A led before
    assert answered.top == "B" == top_class(nets, first, values.__getitem__)
    assert top_class(nets, first, {**values, "b2": ABSENT}.__getitem__) == "A"  # B now .34/.43 < A
    # with every informative feature asked first, the answer is the larger posterior of the same evidence
    full = recognize(nets, values.__getitem__, top=True)
    assert full.recognized == {"A", "B"} and full.top == max(full.recognized, key=full.posteriors.get) == "B"


def test_an_ignorant_answer_goes_on_with_every_network():
    nets = three_networks()
    values = {"a1": ABSENT, "b1": ABSENT, "c1": ABSENT, "a2": ABSENT, "b2": ABSENT, "c2": PRESENT}
    calls = []
    rec = recognize(nets, measured(values, calls), tolerance=0.3, top=True)
    assert rec.recognized == set() and max(rec.posteriors, key=rec.posteriors.get) == "B"  # .15 against .1, .1
    # every class a candidate: a2, b2 absent and c2 present leave A .04/.58, B .06/.57, C .06/.42
    assert sorted(calls[3:]) == ["a2", "b2", "c2"] and rec.top == "C"
    one = {"A": nets["A"]}
    alone = recognize(one, values.__getitem__, tolerance=0.3, top=True)
    assert alone.recognized == set() and alone.top == "A"  # the only class
    assert top_class({}, Recognition({}, set()), values.__getitem__) is None  # no network, no label


def test_a_single_recognized_class_is_the_top_label_without_asking_more():
    nets = three_networks()
    values = {"a1": PRESENT, "b1": ABSENT, "c1": ABSENT, "a2": ABSENT, "b2": PRESENT, "c2": PRESENT}
    calls = []
    rec = recognize(nets, measured(values, calls), tolerance=0.3, top=True)
    assert rec.recognized == {"A"} and rec.top == "A" and calls == rec.queried


def sure(label: str, off: float) -> ClassNetwork:
    """One feature, present with certainty in the class and with probability ``off`` elsewhere: present,
    it saturates the posterior at 1.0 with log odds -log(off)."""
    return network(label, {f"f{label}": (off, 1.0)})


@pytest.mark.parametrize("offs, order, expected", [
    ((1e-20, 1e-30), "AB", "B"),  # both 1.0: B's log odds 69 beat A's 46, against network order
    ((1e-30, 1e-20), "AB", "A"),
    ((1e-20, 1e-20), "AB", "A"),  # equal odds too: the first network
    ((1e-20, 1e-20), "BA", "B"),
])
def test_posteriors_saturated_at_one_go_to_the_larger_log_odds_then_network_order(offs, order, expected):
    made = {"A": sure("A", offs[0]), "B": sure("B", offs[1])}
    nets = {label: made[label] for label in order}
    rec = recognize(nets, lambda key: PRESENT, top=True)
    assert rec.posteriors == {"A": 1.0, "B": 1.0} and rec.recognized == {"A", "B"}
    assert rec.top == expected
    plan = Plan.of(nets)
    [block] = recognize_block(nets, np.full((len(plan.keys), 1), PRESENT), plan=plan, top=True)
    assert block.top == expected


def test_posteriors_saturated_at_zero_go_to_the_larger_log_odds():
    """Prior 1e-200 and P(absent | class) 1e-200 (A) or 1e-150 (B): absent, both posteriors underflow to 0.0,
    while the log odds are -921 and -806. The first recognition is made by hand, as one that asked both."""
    def rare(label, absent):
        net = ClassNetwork(label)
        net.prior = np.array([1.0, 1e-200])
        net.add_feature(f"f{label}", threshold=0.5)
        net.set_cpt(f"f{label}", np.array([[1.0, 0.0], [absent, 1.0]]))
        return net

    for order in ("AB", "BA"):
        made = {"A": rare("A", 1e-200), "B": rare("B", 1e-150)}
        nets = {label: made[label] for label in order}
        assert all(engine(net).posterior({f"f{c}": 0}) == 0.0 for c, net in nets.items())
        first = Recognition({"A": 0.0, "B": 0.0}, set(), ["fA", "fB"], {"fA": ABSENT, "fB": ABSENT})

        def never(key):
            raise AssertionError(f"{key} was asked again")
        assert top_class(nets, first, never) == "B"


def test_positive_only_evidence_goes_on_as_it_recognizes():
    """With positive_only an absent feature stays unobserved while going on, as in alg. 4.4 (4.4.2)."""
    nets = three_networks()
    values = {"a1": PRESENT, "b1": PRESENT, "c1": ABSENT, "a2": ABSENT, "b2": PRESENT, "c2": PRESENT}
    both = recognize(nets, values.__getitem__, tolerance=0.3, top=True)
    positive = recognize(nets, values.__getitem__, tolerance=0.3, positive_only=True, top=True)
    assert both.recognized == positive.recognized == {"A", "B"}
    assert both.top == "B"  # a2 absent: A .857; b2 present: B .895
    assert positive.top == "A"  # a2's absence not entered: A stays .9 against B's .895


@pytest.mark.parametrize("seed", range(6))
def test_block_and_single_image_paths_give_the_same_top(seed):
    from .test_recognition import random_networks

    rng = np.random.default_rng(seed)
    nets = random_networks(rng)
    plan = Plan.of(nets)
    values = rng.choice([0.1, 0.25, 0.5, 0.6, 0.75, 0.9], size=(len(plan.keys), 40))
    for tolerance, positive_only in ((1e-12, False), (0.2, False), (0.2, True)):
        block = recognize_block(nets, values, tolerance, positive_only, plan, top=True)
        alone = [recognize(nets, dict(zip(plan.keys, column)).__getitem__, tolerance, positive_only, plan, top=True)
                 for column in values.T.tolist()]
        assert [r.top for r in block] == [r.top for r in alone]
        assert all(r.top in nets for r in block) and any(len(r.recognized) != 1 for r in block)
        assert [r.top for r in recognize_block(nets, values, tolerance, positive_only, plan)] == [None] * 40


# -- the learner's answers on a learned task ----------------------------------------------------------

def reference_top(networks: dict, rec: Recognition, values: dict, positive_only: bool = False):
    """The rule written out with the engine's evidence-dict API, one network at a time."""
    if len(rec.recognized) == 1:
        return next(iter(rec.recognized))
    candidates = [c for c in networks if c in rec.recognized] or list(networks)
    evidence = {c: {} for c in candidates}

    def enter(key):
        for c in candidates:
            net = networks[c]
            if key in net and not (positive_only and values[key] <= net.threshold[key]):
                trial = {**evidence[c], key: int(values[key] > net.threshold[key])}
                if not math.isnan(engine(net).posterior(trial)):
                    evidence[c] = trial

    for key in rec.queried:
        enter(key)
    asked = set(rec.queried)
    while True:
        best, most = None, 1e-12
        for c in candidates:
            for key, info in engine(networks[c]).informations(evidence[c]).items():
                if key not in asked and info > most:
                    best, most = key, info
        if best is None:
            break
        asked.add(best)
        enter(best)
    posterior = {c: engine(networks[c]).posterior(evidence[c]) for c in candidates}
    tied = [c for c in candidates if posterior[c] == max(posterior.values())]
    odds = {c: engine(networks[c]).log_odds(engine(networks[c]).state(evidence[c])) for c in tied}
    return next(c for c in tied if odds[c] == max(odds.values()))


@pytest.fixture(scope="module")
def learned():
    """Four Plym solids at 32 pixels learned in stage 0; answered on their test views, the training views
    and the test views turned a quarter (more ambiguous and ignorant answers)."""
    task = plym_task(size=32, classes=4)
    train, test = task.fold(1)
    learner = DistinctiveFeatureLearner(LearnerSettings(n_fgen=6), seed=1)
    learner.fit([task.images[i] for i in train], [task.labels[i] for i in train], stages=0)
    images = [task.images[i] for i in test] + [task.images[i] for i in train] + [task.images[i].rot90() for i in test]
    labels = [{task.labels[i]} for i in [*test, *train, *test]]
    return learner, ImageSet(images, labels, space=learner.space), images, labels


def test_top_is_the_open_world_answer_where_that_is_one_class_and_else_alg_4_4_continued(learned):
    learner, env, _, _ = learned
    assert len(env) > BLOCK_MIN  # the block path
    kinds = {}
    for threshold in (None, 0.2):  # test_information, and a threshold it goes on past
        answers = learner.recognize_many(env, range(len(env)), threshold)
        keys = Plan.of(learner.networks).keys
        table = env.values(keys, list(range(len(env))))
        for i, (rec, true) in enumerate(zip(answers, env.labels)):
            column = dict(zip(keys, table[:, i].tolist()))
            kind = outcome(rec.recognized, true)
            kinds.setdefault(threshold, set()).add(len(rec.recognized) if len(rec.recognized) < 2 else 2)
            if len(rec.recognized) == 1:
                assert rec.top == next(iter(rec.recognized))
            elif rec.recognized:
                assert rec.top in rec.recognized and kind in (Outcome.AMBIGUOUS, Outcome.CONFUSED, Outcome.WRONG)
            else:
                assert rec.top in learner.networks
            assert rec.top == reference_top(learner.networks, rec, column)
    assert kinds[None] == {0, 1, 2} and kinds[0.2] == {0, 1, 2}  # one, several and no class all met


def test_block_and_single_image_answers_agree_on_top(learned):
    learner, env, _, _ = learned
    block = learner.recognize_many(env, range(len(env)))
    single = [learner.recognize(env, i) for i in range(len(env))]
    assert len(env) > BLOCK_MIN and [r.top for r in block] == [r.top for r in single]
    assert [r.recognized for r in block] == [r.recognized for r in single]


def test_predict_and_score_answer_top_1_as_recognize_many(learned):
    learner, env, images, labels = learned
    answers = learner.recognize_many(env, range(len(env)))
    tops = learner.predict(images, answer=Answer.TOP1)
    assert tops == [r.top for r in answers] == learner.predict(env, answer="top-1") and None not in tops
    assert learner.predict(images) == learner.predict(images, answer=Answer.OPEN_WORLD) == [frozenset(r.recognized) for r in answers]
    hits = np.mean([r.top in t for r, t in zip(answers, labels)])
    assert learner.score(images, labels, answer=Answer.TOP1) == pytest.approx(hits)
    n = len(set(learner.networks) | {c for t in labels for c in t})
    assert learner.score(images, labels) == pytest.approx(scored(answers, labels, list(range(n))).accuracy)
    assert learner.score(images, labels, answer=Answer.TOP1) > learner.score(images, labels)  # ignorant answers get a label
    assert np.array_equal(learner.predict_proba(images), [[r.posteriors[c] for c in learner.classes_] for r in answers])
    for call in (lambda: learner.predict(images, answer="top1"), lambda: learner.score(images, labels, answer="closed")):
        with pytest.raises(InputError, match=r"answer '(top1|closed)': expected one of 'open-world', 'top-1'"):
            call()
    assert str(Answer.TOP1) == "top-1" and Answer("open-world") is Answer.OPEN_WORLD


def test_answering_changes_nothing_learning_keeps(learned):
    """Learning's recognitions have no top label, and answering with one leaves the learner's state as it was."""
    learner, env, images, _ = learned
    before = json.dumps(learner.state_dict(training=True))
    learner.predict(images, answer=Answer.TOP1)
    learner.score(env, answer=Answer.TOP1)
    assert json.dumps(learner.state_dict(training=True)) == before
    task = plym_task(size=32, classes=2)
    fresh = DistinctiveFeatureLearner(seed=0)
    taught = ImageSet(task.images[:8], [{label} for label in task.labels[:8]])
    assert all(fresh.learn(taught, i).recognition.top is None for i in range(8))
