"""The learner's estimator face: fit / partial_fit / predict / predict_proba / score, its settings
and presets, and the errors a new user meets first."""
import numpy as np
import pytest
import torch

from ftorch import DistinctiveFeatureLearner, ImageSet, InputError, LearnerSettings, NotFittedError
from ftorch.recognition.inference import Result, accuracy
from ftorch.recognition.stages import Schedule, Stage
from training.data.datasets import plym_task
from training.recognition.protocol import Fold, RunConfig


@pytest.fixture(scope="module")
def plym():
    task = plym_task(size=40, classes=3)
    train, test = task.fold(1)
    pick = lambda views: ([task.images[i] for i in views], [task.labels[i] for i in views])  # noqa: E731
    return pick(train), pick(test)


def test_fit_is_the_runners_stage_schedule_and_predict_score_agree_with_recognition(plym, tmp_path):
    (X, y), (X_test, y_test) = plym
    settings = LearnerSettings(n_fgen=6)
    learner = DistinctiveFeatureLearner(settings, seed=1001).fit(X, y, stages=1)
    # the runner's fold 1 of seed 1 seeds its learner and its presentation order with 1001
    train, test = ImageSet(X, y), ImageSet(X_test, y_test)
    fold = Fold(1, train, test, RunConfig("plym", seed=1, learner=settings), tmp_path, sorted(set(y)), progress=False)
    entry, ran = fold.run(stages=1)
    entry = entry.to_json()  # the report entry as report.json holds it
    assert learner.state_dict()["networks"] == ran.state_dict()["networks"]
    assert [s.to_dict() for s in learner.stages_] == [
        {k: v for k, v in e.items() if k not in ("test", "features", "confusion", "seconds")} for e in entry["stages"]]
    assert all(isinstance(s, Stage) for s in learner.stages_) and learner.stages_[1].t_ksd == 0.5
    answers = learner.recognize_many(test, range(len(test)))
    assert learner.predict(X_test) == [frozenset(r.recognized) for r in answers]
    proba = learner.predict_proba(X_test)
    assert proba.shape == (len(X_test), 3) and learner.classes_ == list(learner.networks)
    assert np.array_equal(proba, [[r.posteriors[c] for c in learner.classes_] for r in answers])
    assert np.array_equal(proba > 0.5, [[c in p for c in learner.classes_] for p in learner.predict(X_test)])
    expected = np.mean([accuracy(r.recognized, {t}, 3) for r, t in zip(answers, y_test)])
    assert learner.score(X_test, y_test) == pytest.approx(expected)
    assert entry["stages"][-1]["test"]["accuracy"] == pytest.approx(expected)  # the runner's def. 4.6 figure
    again = DistinctiveFeatureLearner(settings, seed=1001).fit(train, stages=1)  # an ImageSet: the same
    assert again.state_dict()["networks"] == learner.state_dict()["networks"]


def test_partial_fit_presents_each_image_once_and_joins_new_images_to_those_learned_from(plym):
    (X, y), _ = plym
    learner = DistinctiveFeatureLearner(seed=0)
    env = ImageSet(X[:10], y[:10])
    reference = DistinctiveFeatureLearner(seed=0)
    results = [reference.learn(env, i).result for i in range(10)]
    assert learner.partial_fit(X[:6], y[:6]) is learner and learner.presentations == 6
    learner.partial_fit(X[6:10], y[6:10])
    assert learner.presentations == 10 and len(learner.images_) == 10 and learner.images_.labels == env.labels
    assert learner.state_dict()["networks"] == reference.state_dict()["networks"]
    assert all(isinstance(r, Result) for r in results)
    learner.partial_fit(learner.images_)  # the images learned from, presented again
    assert learner.presentations == 20 and len(learner.images_) == 10
    with pytest.raises(InputError, match="carries its own labels"):
        learner.partial_fit(env, y[:10])


def test_the_errors_a_new_user_meets_first(plym, tmp_path):
    (X, y), (X_test, y_test) = plym
    fresh = DistinctiveFeatureLearner()
    for call in (lambda: fresh.predict(X_test), lambda: fresh.predict_proba(X_test), lambda: fresh.score(X_test, y_test),
                 lambda: fresh.classes_, lambda: fresh.save(tmp_path / "l.json")):
        with pytest.raises(NotFittedError, match="learned no class yet"):
            call()
    assert not (tmp_path / "l.json").exists()
    fresh.save(tmp_path / "state.json", training=True)  # a fresh full state loads as it was written
    assert DistinctiveFeatureLearner.load(tmp_path / "state.json").presentations == 0
    assert isinstance(NotFittedError("x"), (ValueError, AttributeError))  # as scikit-learn's
    with pytest.raises(InputError, match="not one string"):
        ImageSet(X[:4], "cube")
    with pytest.raises(InputError, match="not one path"):
        ImageSet("duck.png", ["duck"])
    unlabelled = ImageSet(X[:4])  # images to recognize need no dummy labels
    assert not unlabelled.labeled and unlabelled.labels == [frozenset()] * 4
    with pytest.raises(InputError, match="learning needs labels"):
        fresh.learn(unlabelled, 0)
    with pytest.raises(InputError, match="score needs labels"):
        DistinctiveFeatureLearner(seed=0).fit(X[:6], y[:6], stages=0).score(X_test)
    with pytest.raises(InputError, match="unknown learner options \\['pseudo'\\]"):
        DistinctiveFeatureLearner(pseudo=1)
    loaded = DistinctiveFeatureLearner(seed=0).fit(X[:6], y[:6], stages=0)
    loaded.save(tmp_path / "state.json", training=True)
    with pytest.raises(InputError, match="learned from images it no longer holds"):
        DistinctiveFeatureLearner.load(tmp_path / "state.json").partial_fit(X[:2], y[:2])


def test_labels_are_any_hashable_or_a_set_and_never_split(plym):
    (X, y), (X_test, _) = plym
    names = sorted(set(y))
    numbers = [names.index(label) for label in y]
    by_name = DistinctiveFeatureLearner(seed=0).fit(X, y, stages=0)
    by_number = DistinctiveFeatureLearner(seed=0).fit(X, numbers, stages=0)
    assert set(by_name.classes_) == set(names) and set(by_number.classes_) == {0, 1, 2}
    as_sets = DistinctiveFeatureLearner(seed=0).fit(X, [{label} for label in y], stages=0)
    assert as_sets.predict(X_test) == by_name.predict(X_test)
    assert all(len(p) <= 3 and p <= set(names) for p in by_name.predict(X_test))


def test_one_set_of_defaults_the_measured_best_and_a_thesis_preset():
    from training.run import parser

    best, thesis = LearnerSettings(), LearnerSettings.thesis()
    assert (best.min_information, best.pseudocount, best.redundancy) == (0.1, 1.0, 3)
    assert (thesis.min_information, thesis.pseudocount, thesis.redundancy) == (0.0, 0.0, 1)
    assert (best.primitives, best.contrast) == (("texel", "edgel", "texture"), 4)  # one default for objects and faces
    assert (thesis.primitives, thesis.contrast) == (("texel", "edgel"), 1)  # alg. 4.10 as printed
    assert DistinctiveFeatureLearner().settings == best and DistinctiveFeatureLearner.thesis().settings == thesis
    assert RunConfig("t").learner == best
    args = parser().parse_args(["recognize"])
    assert LearnerSettings(**{k: getattr(args, k) for k in LearnerSettings.names()}) == best  # the runner's defaults
    assert DistinctiveFeatureLearner.thesis(redundancy=2).settings == thesis.replace(redundancy=2)
    for bad, message in (({"redundancy": 0}, "redundancy must be an integer"), ({"leak": 0.5}, "leak must lie in"),
                         ({"evidence": "negative"}, "evidence 'negative'"), ({"primitives": "blob"}, "primitives 'blob'"),
                         ({"min_information": "0.1"}, "min_information must be a number")):
        with pytest.raises(InputError, match=message):
            LearnerSettings(**bad)


def test_a_schedule_steps_one_cycle_or_one_stage_end_at_a_time(plym):
    (X, y), _ = plym
    learner = DistinctiveFeatureLearner(seed=0)
    schedule = Schedule(learner, ImageSet(X, y), torch.Generator().manual_seed(0), stages=0, max_cycles=2)
    steps = []
    while not schedule.progress.done:
        steps.append(schedule.step())
    assert isinstance(steps[-1], Stage) and all(not isinstance(s, Stage) for s in steps[:-1])
    assert len(steps) - 1 == steps[-1].cycles <= 2 and steps[-1].mistakes_per_cycle == [s.mistakes for s in steps[:-1]]
