"""The grasp learner's face: GraspSettings (one set of defaults, the thesis preset, validation), the
runner's options from it, fit / predict / score over past grasps, typed results, save and load."""
import json
import math

import numpy as np
import pytest
import torch

from ftorch import FeatureSpace, NotFittedError
from ftorch.errors import InputError
from ftorch.grasp import POOR_MU0, FingerChoice, GraspLearner, GraspSettings, Learned
from training.grasping.command import add_parser, learner_settings
from training.grasping.experiment import simulate_pool
from training.grasping.haptics import HapticController


def test_one_set_of_defaults_and_the_thesis_preset():
    best, thesis = GraspSettings(), GraspSettings.thesis()
    assert (best.finger_choice, best.mu0_split) == (FingerChoice.QUALITY, POOR_MU0)
    assert (thesis.finger_choice, thesis.mu0_split) == (FingerChoice.THESIS, None)
    assert best.replace(finger_choice="thesis", mu0_split=None) == thesis
    assert GraspLearner().settings == best and GraspLearner.thesis(max_k=2).settings == thesis.replace(max_k=2)
    learner = GraspLearner(thesis, seed=4, min_points=5)
    assert (learner.min_points, learner.finger_choice, learner.seed) == (5, "thesis", 4)
    assert GraspSettings(**json.loads(json.dumps(best.to_dict()))) == best
    assert isinstance(GraspSettings(finger_choice="pooled").finger_choice, FingerChoice)


@pytest.mark.parametrize("options, message", [
    ({"t_dtheta": 4.0}, "t_dtheta must lie in"), ({"max_k": 0}, "max_k must be an integer"),
    ({"min_points": 2.5}, "min_points must be an integer"), ({"discard_every": True}, "discard_every must be an integer"),
    ({"finger_choice": "vote"}, "finger_choice 'vote'"), ({"mu0_split": 3.0}, "mu0_split must lie in"),
    ({"mu0_split": None}, "needs mu0_split"), ({"max_distance": -1.0}, "max_distance must be"),
    ({"pool": 3}, "unknown grasp learner options ['pool']"), ({"t_dtheta": "10"}, "t_dtheta must be a number"),
])
def test_bad_settings_are_refused(options, message):
    with pytest.raises(InputError, match=message.replace("[", r"\[").replace("]", r"\]")):
        GraspLearner(**options)


def test_the_runner_takes_its_options_and_defaults_from_the_settings():
    import argparse

    commands = argparse.ArgumentParser().add_subparsers()
    add_parser(commands)
    parser = commands.choices["grasp"]
    args = parser.parse_args([])
    assert learner_settings(args) == GraspSettings()
    assert (args.t_dtheta, args.finger_choice, args.mu0_split) == (10.0, "quality", POOR_MU0)
    # --mu0-split serves the quality choice only: the others learn from orientation mistakes, as the thesis
    assert learner_settings(parser.parse_args(["--finger-choice", "thesis"])) == GraspSettings.thesis()
    assert learner_settings(parser.parse_args(["--t-dtheta", "5", "--mu0-split", "0.3"])) == \
        GraspSettings(t_dtheta=math.radians(5), mu0_split=0.3)
    with pytest.raises(InputError, match="mu0_split must lie in"):
        learner_settings(parser.parse_args(["--finger-choice", "pooled", "--mu0-split", "2.5"]))


@pytest.fixture(scope="module")
def grasps():
    """Images and haptic experiences of 5 squares (two fingers) and 5 triangles (three)."""
    pool = simulate_pool("clean", 5, seed=3, size=64, controller=HapticController())
    trials = [t for category in pool.values() for t in category]
    return [t.image for t in trials], [t.experience() for t in trials]


def test_fit_is_alg_6_2_over_the_grasps_and_predict_and_score_answer(grasps):
    images, experiences = grasps
    learner = GraspLearner(seed=2)
    for answer in (lambda: learner.predict(images), lambda: learner.score(images, experiences),
                   lambda: learner.save("unused.json")):
        with pytest.raises(NotFittedError, match="no feature model yet"):
            answer()
    assert learner.fit(images, experiences, epochs=3) is learner
    by_hand = GraspLearner(seed=2)  # steps 5-10 grasp by grasp, each image named by its position
    records = FeatureSpace().records(images)
    for _ in range(3):
        results = [by_hand.learn(i, records[i], e) for i, e in enumerate(experiences)]
        assert all(isinstance(r, Learned) for r in results)
        if all(r is Learned.CORRECT for r in results):
            break
    assert json.dumps(learner.state_dict()) == json.dumps(by_hand.state_dict())
    predicted = learner.predict(images, [e.fingers for e in experiences])
    assert predicted == by_hand.recommend_all(records, [e.fingers for e in experiences])
    assert sum(p is not None for p in predicted) >= len(images) // 2
    correct = [p is not None and by_hand._correct(p, e) for p, e in zip(predicted, experiences)]
    assert learner.score(images, experiences) == pytest.approx(np.mean(correct)) and 0 < np.mean(correct)
    again = learner.fit(images, experiences, epochs=3)  # fit starts afresh
    assert json.dumps(again.state_dict()) == json.dumps(by_hand.state_dict())
    with pytest.raises(InputError, match="2 images but 1 experiences"):
        learner.fit(images[:2], experiences[:1])


def test_the_learner_measures_images_on_its_device(grasps, monkeypatch):
    images, experiences = grasps
    seen = []
    records = FeatureSpace.records
    monkeypatch.setattr(FeatureSpace, "records", lambda self, *a, **k: seen.append(
        next(self.buffers()).device) or records(self, *a, **k))
    GraspLearner(device=torch.device("cpu")).fit(images[:4], experiences[:4])
    assert seen == [torch.device("cpu")]
    if torch.cuda.is_available():
        learner = GraspLearner(device="cuda").fit(images, experiences, epochs=2)
        assert seen[-1].type == "cuda" and learner.predict(images[:1]) is not None


def test_saved_settings_load_and_old_files_still_read(grasps, tmp_path):
    images, experiences = grasps
    learner = GraspLearner.thesis(seed=1, max_k=3).fit(images, experiences, epochs=2)
    learner.save(tmp_path / "grasp.json")
    loaded = GraspLearner.load(tmp_path / "grasp.json")
    assert loaded.settings == learner.settings and not loaded.trainable
    assert loaded.predict(images) == learner.predict(images)
    saved = json.loads((tmp_path / "grasp.json").read_text())
    assert saved["settings"] == {"t_dtheta": math.radians(10), "max_k": 3, "min_points": 3, "discard_every": 40,
                                 "max_distance": None, "finger_choice": "thesis", "mu0_split": None}  # as 0.2.0 wrote it
    assert set(saved) == {"format", "kind", "version", "settings", "sets", "features", "schema"} and saved["schema"] == 1
    assert all(set(s) == {"fingers", "features", "models", "quality"} for s in saved["sets"])
    with pytest.raises(InputError, match="recommends but cannot learn"):
        loaded.learn(0, FeatureSpace().records(images[:1]), experiences[0])
    with pytest.raises(InputError, match="no training state"):
        loaded.state_dict()
    assert loaded.fit(images, experiences, epochs=2).trainable  # fit starts afresh, from the loaded settings
    assert json.dumps(loaded.state_dict()) == json.dumps(GraspLearner.thesis(seed=0, max_k=3).fit(
        images, experiences, epochs=2).state_dict())
    for damage in ({"finger_choice": "vote"}, {"pool": 3}):
        (tmp_path / "bad.json").write_text(json.dumps({**saved, "settings": {**saved["settings"], **damage}}))
        with pytest.raises(InputError, match="damaged grasp learner"):
            GraspLearner.load(tmp_path / "bad.json")


def test_the_estimator_face_keeps_its_parameters_and_clones():
    """get_params gives the constructor's parameters as given, set_params changes them (or single settings)
    validated as the constructor does, and ``sklearn.base.clone`` makes an unfitted learner with the same."""
    base = pytest.importorskip("sklearn.base")
    settings, device = GraspSettings.thesis(max_k=2), torch.device("cpu")
    learner = GraspLearner(settings, seed=5, device=device)
    assert learner.get_params() == {"settings": settings, "seed": 5, "device": device}
    assert learner.get_params()["settings"] is settings and learner.device is device
    twin = base.clone(learner)
    assert twin is not learner and twin.get_params() == learner.get_params() and twin.sets[2].features == []
    assert learner.set_params(max_k=3, seed=6) is learner
    assert (learner.settings, learner.seed) == (settings.replace(max_k=3), 6)
    assert learner.set_params(settings=GraspSettings()).settings == GraspSettings()
    with pytest.raises(InputError, match="unknown grasp learner options"):
        learner.set_params(pool=3)
    with pytest.raises(InputError, match="seed must be"):
        learner.set_params(seed=-1)
    with pytest.raises(InputError, match="settings must be GraspSettings"):
        GraspLearner({"max_k": 2})
