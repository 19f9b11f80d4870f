"""Saving and restoring a grasp learner (alg. 6.2): JSON-ready states of its sets and of the learner.

A recommending state holds the settings and, per finger count, the features (positions in one
packed feature table), their models (alg. 6.1) and quality splits. A training state adds all that
learning reads: the instance lists (each row's image name, values, orientations and outcome, stored
exactly; the rows of each image's records), the rows each model was fitted on, the features' birth
and last use, the grasp and sampling counts, the seed and the generator's state. The images are not
held: restoring a training state takes their records by name.

Schema versions (``"schema"`` in the state; a state without it is version 0, and a newer one is
refused in one line, :func:`~ftorch.checkpoint.schema_of`):

- 0: states written before the schema was numbered; they read as they are (no migration).
- 1: the same contents, numbered.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Hashable

import numpy as np
import torch

from ..checkpoint import decode_array, encode_array, schema_of, stored_position
from ..errors import InputError
from ..space.features import Feature, FeatureTable, unpack_features
from ..space.record import ImageRecords
from .feature_set import GraspFeatureSet
from .models import FeatureModel
from .settings import GraspSettings

SCHEMA = 1
KIND = "grasp-learner"
FINGERS = (2, 3)
GENERATOR_STATE = tuple(torch.Generator().get_state().shape)  # the bytes of a torch.Generator's state
Records = Callable[[Hashable], ImageRecords]  # an image of the instance list's records, by its name


def set_state(feature_set: GraspFeatureSet, table: FeatureTable, training: bool = True) -> dict:
    """JSON-ready: the set's features (positions in ``table``), their models (alg. 6.1) and quality splits;
    with ``training``, all that learning reads too (module doc)."""
    state = {"fingers": feature_set.fingers, "features": [table.index(f) for f in feature_set.features],
             "models": [None if m is None else m.to_dict(rows=training) for m in feature_set.models],
             "quality": encode_array(np.ascontiguousarray(feature_set.quality, dtype=np.float64))}
    if training:
        first_row, source_of_row = feature_set.sources()
        state.update({"images": [_name_to_json(i) for i in feature_set.images], "values": encode_array(feature_set.values),
                      "thetas": encode_array(feature_set.thetas), "outcomes": encode_array(feature_set.outcomes),
                      "source_of_row": source_of_row, "first_row": first_row,
                      "born": list(feature_set.born), "used": list(feature_set.used), "grasps": feature_set.grasps,
                      "sampled": feature_set.sampled})
    return state


def restore_set(fingers: int, state: dict, features: list[Feature], records: Records | None = None) -> GraspFeatureSet:
    """The set of ``fingers`` that :func:`set_state` wrote (``features``: the unpacked table). A training state needs ``records``,
    which gives the records of the image named by the first row of each source; ValueError (or another of
    ``ftorch.checkpoint.DAMAGED``) for a damaged state."""
    feature_set = GraspFeatureSet(fingers)
    chosen = [features[stored_position(i, len(features))] for i in state["features"]]
    width, training = len(chosen), "images" in state
    n = len(state["images"]) if training else 0
    models = [None if m is None else FeatureModel.from_dict(m, n if training else None) for m in state["models"]]
    if len(models) != width:
        raise ValueError(f"{width} features but {len(models)} models")
    feature_set.features, feature_set.models = chosen, models
    feature_set.quality = decode_array(state["quality"], shape=(4, width))
    if not training:
        feature_set.born, feature_set.used = [0] * width, [0] * width
        return feature_set
    if records is None:
        raise ValueError("a training state needs the records of its images")
    _restore_instances(feature_set, state, n, width, records)
    feature_set.born, feature_set.used = list(state["born"]), list(state["used"])
    feature_set.grasps, feature_set.sampled = state["grasps"], state["sampled"]
    return feature_set


def _restore_instances(feature_set: GraspFeatureSet, state: dict, n: int, width: int, records: Records) -> None:
    """The instance list of a training state, checked, into the empty ``feature_set``."""
    images = [_name_from_json(i) for i in state["images"]]
    if len(set(images)) != n:
        raise ValueError("an image name occurs twice in the instance list")
    first = [stored_position(r, n) for r in state["first_row"]]
    rows = [stored_position(s, len(first)) for s in state["source_of_row"]]
    if len(rows) != n or any(rows[r] != s for s, r in enumerate(first)) or first != sorted(set(first)):
        raise ValueError("the rows' sources do not match the sources' first rows")
    counts = [state[k] for k in ("grasps", "sampled")] + list(state["born"]) + list(state["used"])
    if len(state["born"]) != width or len(state["used"]) != width or \
            any(isinstance(v, bool) or not isinstance(v, int) or v < -1 for v in counts):
        raise ValueError("born, used, grasps and sampled must be integers, one born and used per feature")
    values, thetas, outcomes = (decode_array(state[k], shape=shape) for k, shape in
                                (("values", (n, width)), ("thetas", (n, width)), ("outcomes", (n, 3))))
    sources = [records(images[row]) for row in first]
    for row, found in zip(first, sources):
        if not isinstance(found, ImageRecords) or len(found) != 1:
            raise ValueError(f"no records of one image for {images[row]!r}")
    feature_set.fill(images, values, thetas, outcomes, sources, first, rows)


@dataclass
class LearnerState:
    """A learner's state as :func:`restore_learner` reads it: the settings, the sets by finger count and,
    for a training state, the seed and the generator's state (None for a recommending one)."""

    settings: GraspSettings
    sets: dict[int, GraspFeatureSet]
    seed: int | None = None
    generator: torch.Tensor | None = None


def learner_state(settings: GraspSettings, sets: dict[int, GraspFeatureSet], seed: int | None = None,
                  generator: torch.Generator | None = None) -> dict:
    """JSON-ready: the settings and the sets (:func:`set_state`); with the ``seed`` and the ``generator``
    a training state, else a recommending one; its schema last."""
    table, training = FeatureTable(), generator is not None
    state: dict[str, object] = {"settings": settings.to_dict(), "sets": [set_state(s, table, training) for s in sets.values()],
                                "features": table.pack()}
    if generator is not None:
        state.update({"seed": seed, "generator": encode_array(generator.get_state().numpy().astype(np.float64))})
    state["schema"] = SCHEMA
    return state


def restore_learner(state: dict, records: Records | None = None) -> LearnerState:
    """What :func:`learner_state` wrote (of any schema up to :data:`SCHEMA`; NewerSchema for a newer one); a
    training state needs ``records`` (:func:`restore_set`)."""
    schema_of(state.get("schema"), "a grasp learner state", SCHEMA)
    settings = GraspSettings(**state["settings"])
    training = "generator" in state
    seed = int(state["seed"]) if training else None
    features = unpack_features(state["features"])
    if sorted(r["fingers"] for r in state["sets"]) != list(FINGERS):
        raise ValueError(f"sets {[r['fingers'] for r in state['sets']]}, expected one for each of {FINGERS}")
    written = {r["fingers"]: r for r in state["sets"]}
    sets = {c: restore_set(c, written[c], features, records if training else None) for c in FINGERS}
    generator = None
    if training:
        generator = torch.from_numpy(decode_array(state["generator"], shape=GENERATOR_STATE).astype(np.uint8))
    return LearnerState(settings, sets, seed, generator)


def _name_to_json(name):
    """An image name of the instance list as JSON (a tuple as a list); InputError for other than
    strings, numbers, None and tuples of them."""
    if isinstance(name, tuple):
        return [_name_to_json(part) for part in name]
    if name is None or isinstance(name, (str, int, float)):
        return name
    raise InputError(f"image name {name!r}: a training state holds names that are strings, numbers or tuples of them")


def _name_from_json(name):
    """Inverse of :func:`_name_to_json`."""
    return tuple(_name_from_json(part) for part in name) if isinstance(name, list) else name
