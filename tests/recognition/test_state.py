"""Saved learner state: one schema version with one migration per version, a newer one refused, a new
option added in two places (its settings field and where it is used), and the estimator's parameters."""
import json
from dataclasses import dataclass

import pytest

from ftorch.errors import InputError
from ftorch.recognition.learner import DistinctiveFeatureLearner
from ftorch.recognition.settings import LearnerSettings
from ftorch.recognition.state import SCHEMA, migrated
from ftorch.settings import option
from tests.recognition.test_learner import shapes  # noqa: F401  (a fixture)


@dataclass(frozen=True)
class SkipSettings(LearnerSettings):
    """A new option, place 1 of 2: its settings field (validated, saved, loaded and set like every option)."""

    skip: int = option(1, "a search tests its candidates from the skip-th on", at_least=1)


class SkippingLearner(DistinctiveFeatureLearner):
    """Place 2 of 2: where the option is used."""

    def _in_order(self, label, classes: list, candidates: list, cuts, powers, t_ksd: float) -> list[tuple]:
        return super()._in_order(label, classes, candidates, cuts, powers, t_ksd)[self.settings.skip - 1:]


def _learned(learner, env, n: int = 12):
    for i in range(n):
        learner.learn(env, i)
    return learner


def _without(state: dict, *keys) -> dict:
    return {k: v for k, v in state.items() if k not in keys}


def test_a_new_option_needs_its_settings_field_and_its_use_only(shapes):
    plain = _learned(DistinctiveFeatureLearner.thesis(seed=3), shapes).state_dict()
    off = _learned(SkippingLearner(SkipSettings.thesis(), seed=3), shapes).state_dict()
    assert off["skip"] == 1 and _without(off, "skip") == plain  # at its default the learner is the library's
    on = _learned(SkippingLearner(SkipSettings.thesis(skip=2), seed=3), shapes)
    state = json.loads(json.dumps(on.state_dict()))
    assert state["skip"] == 2 and _without(state, "skip") != plain  # the option is used
    again = SkippingLearner(SkipSettings(), seed=3)
    again.load_state_dict(state)
    assert again.settings == on.settings and again.settings.skip == 2
    assert on.learn(shapes, 12) == again.learn(shapes, 12) and on.state_dict() == again.state_dict()
    assert again.set_params(skip=3).settings.skip == 3
    with pytest.raises(InputError, match="skip"):
        again.set_params(skip=0)
    older = SkippingLearner(SkipSettings(skip=5))
    older.load_state_dict(_without(state, "skip"))  # a file written before the option: its default
    assert older.settings.skip == 1


def test_states_of_schema_0_migrate_to_the_values_before_each_option_existed(shapes):
    learner = _learned(DistinctiveFeatureLearner(seed=1), shapes)
    state = json.loads(json.dumps(learner.state_dict()))
    assert state["schema"] == SCHEMA == 2
    newer = [k for k in LearnerSettings.names() if k not in ("n_ex", "n_fgen", "min_information")]
    old = _without(state, "schema", "seed", *newer)
    moved = migrated(old)
    thesis = LearnerSettings.thesis()
    assert moved["schema"] == 2 and moved["seed"] == 0 and moved["distinctions"] == "pair"
    assert moved["test_information"] == state["min_information"]
    assert all(moved[k] == getattr(thesis, k) for k in ("pseudocount", "redundancy", "leak", "contrast", "calibrate"))
    assert moved["primitives"] == "texel,edgel" and old.get("schema") is None  # the input is left as it was
    loaded = DistinctiveFeatureLearner()
    loaded.load_state_dict(old)
    assert loaded.settings == thesis.replace(n_ex=state["n_ex"], n_fgen=state["n_fgen"], min_information=state["min_information"],
                                             test_information=state["min_information"])
    assert loaded.networks.keys() == learner.networks.keys() and loaded.presentations == learner.presentations


def test_states_of_schema_1_learned_one_class_pair_per_expert_search(shapes):
    learner = _learned(DistinctiveFeatureLearner(seed=1, distinctions="shared"), shapes)
    state = json.loads(json.dumps(learner.state_dict()))
    assert state["distinctions"] == "shared"
    old = {**_without(state, "distinctions"), "schema": 1}
    loaded = DistinctiveFeatureLearner(distinctions="shared")
    loaded.load_state_dict(old)
    assert loaded.settings == learner.settings.replace(distinctions="pair")


def test_a_newer_schema_is_refused_in_one_line_and_a_state_missing_an_option_is_damaged(shapes, tmp_path):
    learner = _learned(DistinctiveFeatureLearner.thesis(seed=2), shapes)
    path = tmp_path / "learner.json"
    learner.save(path)
    data = json.loads(path.read_text())
    data["learner"]["schema"] = SCHEMA + 1
    path.write_text(json.dumps(data))
    with pytest.raises(InputError, match=f"learner.json: a learner state of schema {SCHEMA + 1}, newer") as err:
        DistinctiveFeatureLearner.load(path)
    assert "\n" not in str(err.value)
    data["learner"]["schema"] = SCHEMA
    del data["learner"]["leak"]
    path.write_text(json.dumps(data))
    with pytest.raises(InputError, match="damaged learner checkpoint .*without the option 'leak'"):
        DistinctiveFeatureLearner.load(path)
    for bad in ("1", -1, True):
        with pytest.raises(ValueError, match="not a version number"):
            migrated({**data["learner"], "schema": bad})


def test_get_params_and_set_params_make_the_learner_a_scikit_learn_estimator(shapes):
    base = pytest.importorskip("sklearn.base")
    learner = _learned(DistinctiveFeatureLearner(seed=4, redundancy=2), shapes, 6)
    params = learner.get_params()
    assert set(params) == {"settings", "seed", "device"} and params["settings"].redundancy == 2
    copy = base.clone(learner)
    assert copy is not learner and copy.get_params() == params and not copy.networks and copy.presentations == 0
    assert _learned(copy, shapes, 6).state_dict() == learner.state_dict()  # the same seed and settings learn the same
    assert learner.set_params(seed=9, settings=LearnerSettings.thesis()).seed == 9 and learner.settings == LearnerSettings.thesis()
    with pytest.raises(InputError, match="LearnerSettings"):
        learner.set_params(settings={"redundancy": 2})
