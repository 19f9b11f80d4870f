"""A learner's state as JSON-ready data (learner.json, a fold's checkpoint.json), its schema versions,
and the one migration per version that fills what older files lack.

Schema versions (``"schema"`` in the state; files without it are version 0):

- 0: files written before the schema was numbered; an option a file does not record ran at the
  value it had before the option existed, which is the thesis's (:meth:`LearnerSettings.thesis`:
  every option beyond the thesis was introduced with its thesis behaviour as the value "off"), and
  ``test_information`` at ``min_information``'s (the answers used it); a missing seed was 0.
- 1: every option and the seed recorded.
- 2: ``distinctions`` recorded; a version 1 file learned one class pair per expert search (``pair``).

Load, resume and the trade-off read a state through :func:`migrated`; a state of a newer schema
is refused in one line. Features are referred to by position in a feature table (``"features"``,
:class:`~ftorch.space.features.FeatureTable`).
"""
from __future__ import annotations

from collections.abc import Hashable
from typing import TYPE_CHECKING

import numpy as np
import torch

from ..checkpoint import decode_array, encode_array, schema_of, stored_position
from ..errors import InputError
from ..space.features import Feature, FeatureTable, unpack_features
from .bayes import ClassNetwork
from .counting import Counting
from .environment import ImageSet
from .instances import are_stored_values
from .settings import Distinctions, LearnerSettings, integer_in

if TYPE_CHECKING:
    from .learning import Learning

SCHEMA = 2
KIND = "learner"
TRAINING_STATE = ("generator", "discriminates", "selected", "usage", "instances")  # what a training state adds
GENERATOR_STATE = tuple(torch.Generator().get_state().shape)  # the bytes of a torch.Generator's state
MAX_SEED = 2**63 - 1  # torch.Generator.manual_seed takes 0 .. 2**64 - 1; a seed stays a signed 64-bit integer


def checked_seed(value) -> int:
    """A learner's seed: an integer from 0 to :data:`MAX_SEED`; InputError otherwise."""
    return integer_in("seed", value, 0, MAX_SEED)


def options_before(stored: dict) -> dict:
    """The learner options of ``stored`` (a learner state, or a run's config that writes them in line)
    completed by schema 0's rule: an option it does not record at its value before the option existed,
    the thesis's, and ``test_information`` at ``min_information``'s. Only the options; lists as stored."""
    options = {k: stored[k] for k in ("n_ex", "n_fgen", "min_information")}  # in every file
    options.update({k: stored[k] for k in LearnerSettings.names() if k in stored})
    options.setdefault("test_information", options["min_information"])  # validated by LearnerSettings
    return {**LearnerSettings.thesis().to_dict(), **options}


def _schema_0(state: dict) -> dict:
    """Version 0 to 1: the options and seed a file does not record, at their values before they existed."""
    return {**state, **options_before(state), "seed": state.get("seed", 0), "schema": 1}


def distinctions_before(stored: dict) -> dict:
    """``stored`` (a learner state, or a run's config that writes its options in line) completed by
    schema 2's rule: a file of an earlier schema learned one class pair per expert search (alg. 5.2 as
    printed, ``distinctions`` pair)."""
    return {"distinctions": str(Distinctions.PAIR), **stored}


def _schema_1(state: dict) -> dict:
    """Version 1 to 2: :func:`distinctions_before`."""
    return {**distinctions_before(state), "schema": 2}


MIGRATIONS = {0: _schema_0, 1: _schema_1}  # version -> the state one version on


def migrated(state: dict) -> dict:
    """``state`` brought to :data:`SCHEMA` by the migrations of the versions it passes; InputError for a newer one."""
    version = schema_of(state.get("schema"), "a learner state", SCHEMA)
    while version < SCHEMA:
        state = MIGRATIONS[version](state)
        version = state["schema"]
    return state


def label(value):
    """Class labels and image ids are stored as JSON scalars: str or int."""
    if isinstance(value, bool) or not isinstance(value, (str, int)):
        raise InputError(f"class labels and image ids must be str or int to be saved, got {value!r}")
    return value


def _number(value) -> float:
    """A stored number: int or float, never a string or a bool that float() would also accept."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ValueError(f"{value!r} is not a number")
    return float(value)


def _count(value) -> int:
    if isinstance(value, bool) or not isinstance(value, int) or value < 0:
        raise ValueError(f"count {value!r} is not an integer >= 0")
    return value


def _index(table: FeatureTable, key: Hashable) -> int:
    """``key``'s position in ``table``; InputError for a network node that is not an ftorch feature."""
    if not isinstance(key, Feature):
        raise InputError(f"{key!r} is not an ftorch feature: only networks of features are saved")
    return table.index(key)


def _cached(env: ImageSet | None, features: list, images: list) -> np.ndarray | None:
    """``env``'s cached values (images, features), the reference of relative instance values; None without ``env``."""
    return None if env is None else env.cache.stored(features, images).T


def _networks_state(learning: Learning, table: FeatureTable) -> list:
    return [{
        "label": label(name), "features": [_index(table, f) for f in net.features],
        "parents": [[_index(table, p) for p in net.parents[f]] for f in net.features],
        "threshold": [net.threshold[f] for f in net.features],
        "prior": net.prior.tolist(), "cpt": [encode_array(net.cpt[f]) for f in net.features],
    } for name, net in learning.networks.items()]


def _training_state(learning: Learning, table: FeatureTable, env: ImageSet | None) -> dict:
    instances = learning.instances
    return {
        "generator": encode_array(learning.generator.get_state().numpy().astype(np.float64)),
        "discriminates": [[label(c), _index(table, f), sorted(map(label, d), key=str)]
                          for (c, f), d in learning.discriminates.items()],
        "selected": [[label(c), _index(table, f), sorted(map(label, images), key=str)]
                     for (c, f), images in learning.counting.selected.items()],
        "usage": [[_index(table, f), n] for f, n in learning.usage.items()],
        "instances": {"images": [label(i) for i in instances.images],
                      "labels": [sorted(map(label, labels), key=str) for labels in instances.labels],
                      "features": [_index(table, f) for f in instances.features],
                      "values": encode_array(instances.values_table(), _cached(env, instances.features, instances.images))},
    }


def state_dict(learning: Learning, training: bool = True, table: FeatureTable | None = None,
               env: ImageSet | None = None) -> dict:
    """The state as JSON-ready data, features referred to by position in a feature table.

    ``training=True``: the complete state (instance list, usage, random state), from which learning
    continues exactly; ``False``: what recognition needs (the networks). The table is written into the
    state as "features", unless the caller passes its own ``table`` (to store features shared with
    other state once) and writes it. ``env``: the image set it learns from, whose value cache the
    caller writes too; the instance values, which are that cache's values, are then written relative
    to it (nearly nothing), and :func:`load_state_dict` needs the same image set, its cache restored.
    """
    own = table is None
    table = FeatureTable() if table is None else table
    settings = learning.settings
    state = {**settings.to_dict(), "primitives": [str(p) for p in settings.primitives],
             "seed": learning.seed, "presentations": learning.presentations, "sampled": learning.sampled,
             "sides": None if learning.sides is None else list(learning.sides),
             "networks": _networks_state(learning, table), "schema": SCHEMA}
    if training:
        state.update(_training_state(learning, table, env))
    if own:
        state["features"] = table.pack()
    return state


def _networks(records: list, at) -> dict:
    networks: dict = {}
    for record in records:
        parents = [[at(p) for p in ps] for ps in record["parents"]]
        net = ClassNetwork.of(label(record["label"]), [at(i) for i in record["features"]], parents,
                              [_number(t) for t in record["threshold"]], [_number(p) for p in record["prior"]],
                              [decode_array(cpt, shape=(2,) * (len(ps) + 2))  # [c, p1..pk, f]
                               for cpt, ps in zip(record["cpt"], parents)])
        if net.label in networks:
            raise ValueError(f"two networks for class {net.label!r}")
        networks[net.label] = net
    return networks


def load_state_dict(learning: Learning, state: dict, features: list[Feature] | None = None,
                    env: ImageSet | None = None) -> None:
    """Restore a state written by :func:`state_dict` (of any schema up to :data:`SCHEMA`; ``features``: the
    caller's table, where it kept one; ``env``: the image set whose cache its instance values were
    written relative to); ValueError or InputError where it is damaged. A recognition-only state gives a
    learner that recognizes but refuses to learn."""
    state = migrated(state)
    features = unpack_features(state["features"]) if features is None else features
    at = lambda i: features[stored_position(i, len(features))]  # noqa: E731
    learning.seed = checked_seed(state["seed"])
    missing = [k for k in LearnerSettings.names() if k not in state]
    if missing:
        raise ValueError(f"a state of schema {SCHEMA} without the option {missing[0]!r}")
    kind = type(learning.settings)  # a subclass's own options, where a file lacks them, at their defaults
    learning.settings = kind(**{k: state[k] for k in kind.names() if k in state})
    learning.presentations, learning.candidates.sampled = _count(state["presentations"]), _count(state["sampled"])
    sides = state.get("sides")  # files written before sides were recorded have none
    if sides is not None and (not isinstance(sides, list) or len(sides) != 2 or _count(sides[0]) > _count(sides[1])):
        raise ValueError(f"sides {sides!r}: expected [smallest, largest] shorter image side")
    learning.sides = None if sides is None else (sides[0], sides[1])
    learning.networks = _networks(state["networks"], at)
    if not learning.networks and "instances" not in state:
        raise ValueError("a recognition file without a class network")  # a fresh learner's full state has none
    learning.trainable = "instances" in state
    learning.counting, learning.usage = Counting(), {}
    learning.generator.set_state(torch.Generator().get_state())  # in place: the parts hold this generator
    if learning.trainable:
        _load_training(learning, state, at, env)


def _load_training(learning: Learning, state: dict, at, env: ImageSet | None) -> None:
    learning.generator.set_state(torch.from_numpy(decode_array(state["generator"], shape=GENERATOR_STATE).astype(np.uint8)))
    counting = learning.counting
    counting.discriminates.update({(c, at(f)): frozenset(d) for c, f, d in state["discriminates"]})
    # files written before selection images were recorded count every node on all instances
    counting.selected.update({(c, at(f)): frozenset(i) for c, f, i in state.get("selected", [])})
    learning.usage = {at(f): _count(n) for f, n in state["usage"]}
    block = state["instances"]
    for image, labels in zip(block["images"], block["labels"]):
        counting.instances.add(image, labels)
    columns = [at(i) for i in block["features"]]
    values = decode_array(block["values"], _cached(env, columns, counting.instances.images),
                          shape=(len(counting.instances), len(columns)))
    if not are_stored_values(values):
        raise ValueError("instance values outside [0, 1] (feature values are similarities, eq. 3.13)")
    if columns:
        counting.instances.set_block(counting.instances.images, columns, values.T)
    if len(counting.instances.features) < len(columns):
        raise ValueError("an instance feature listed twice")
    known = set(counting.instances.images)
    if any(not images <= known for images in counting.selected.values()):
        raise ValueError("a node selected on an image that is not an instance")
