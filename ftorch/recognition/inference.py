"""Sequential recognition across class networks (alg. 4.4) and its evaluation (def. 4.5, 4.6).

Recognition repeatedly queries the feature with the largest mutual information with any class
node, measures it in the image, and enters presence or absence (value above the node's
threshold) into every network that holds it: positive and negative evidence both count. With
``positive_only`` (4.4.2's alternative for robustness to occlusion) only presence is entered; an
absent feature stays unobserved, as if occluded. It stops when no unqueried feature is
informative (I_max <= ``tolerance``). Evidence that a
network deems impossible (probability 0 under its counted CPTs) is not entered there; that
network keeps its belief. Ties in I_max go to the first network, then the first feature. A network
whose class is decided (P(C = 1, e) or P(C = 0, e) exactly 0: log odds +-inf, :func:`decided`) keeps
its belief whatever is entered next and has no information left (0 up to rounding, far below the
least tolerance, 1e-12): it is neither asked nor told again, so it costs nothing for the rest of the
recognition (the same queries and beliefs as telling it).

The answer is a set (def. 4.5): every class whose posterior exceeds 0.5, so one class, several
(ambiguous) or none (ignorant). :func:`top_class` adds one label per image beside it
(:attr:`Recognition.top`, :class:`Answer`): the one class where exactly one is recognized, else alg.
4.4 continued on the candidates' networks and the largest posterior (docs/decisions.md).
"""
from __future__ import annotations

import math
from collections.abc import Callable, Hashable, Iterable
from dataclasses import dataclass, field
from enum import StrEnum
from functools import cached_property

import numpy as np

from ..errors import InputError
from .bayes import ClassNetwork
from .exact import ExactInference, engine

TOP_TOLERANCE = 1e-12  # alg. 4.4 continued for the top label (top_class) stops at I_max <= this, whatever test_information


class Outcome(StrEnum):
    """The categories of a recognition result (def. 4.5), in the thesis's table order."""

    CORRECT = "correct"  # recognized = true
    WRONG = "wrong"  # as many classes as true, some false
    AMBIGUOUS = "ambiguous"  # all true classes and some false ones
    CONFUSED = "confused"  # some false classes, not all true ones, a different number
    IGNORANT = "ignorant"  # some true classes missing and no false one


class Answer(StrEnum):
    """What a learner answers per image: the thesis's set of recognized classes (alg. 4.4, def. 4.5:
    one, several or none) or one label (:func:`top_class`)."""

    OPEN_WORLD = "open-world"  # the classes whose posterior exceeds 0.5 (def. 4.5), scored by def. 4.6
    TOP1 = "top-1"  # Recognition.top, scored by whether it is one of the true classes

    @classmethod
    def of(cls, value) -> "Answer":
        """``value`` as an Answer; one InputError for any other value."""
        try:
            return cls(value)
        except ValueError:
            raise InputError(f"answer {value!r}: expected one of {', '.join(repr(str(a)) for a in cls)}") from None


class Result(StrEnum):
    """What one training presentation did (alg. 4.7, 5.1)."""

    CORRECT = "correct"  # recognized correctly; nothing to learn
    REESTIMATED = "reestimated"  # a mistake, fixed by re-discretizing and re-counting (alg. 4.7 step 3)
    LEARNED = "learned"  # a mistake, fixed by a new feature (alg. 4.8)
    FAILED = "failed"  # a mistake no candidate fixed
    EXPERT = "expert"  # correct, and an expert feature was added (alg. 5.1)
    EXPERT_FAILED = "expert-failed"  # correct, but no candidate reached t_KSD

    @property
    def mistake(self) -> bool:
        """Whether the presentation's first recognition was wrong (a stage ends after a cycle without one)."""
        return self in (Result.REESTIMATED, Result.LEARNED, Result.FAILED)


def outcome(recognized: Iterable[Hashable], true: Iterable[Hashable]) -> Outcome:
    """Category of a recognition result (def. 4.5)."""
    recognized, true = set(recognized), set(true)
    hits, false = recognized & true, recognized - true
    if recognized == true:
        return Outcome.CORRECT
    if not false:
        return Outcome.IGNORANT
    if hits == true:
        return Outcome.AMBIGUOUS
    return Outcome.WRONG if len(recognized) == len(true) else Outcome.CONFUSED


def accuracy(recognized: Iterable[Hashable], true: Iterable[Hashable], n_classes: int) -> float:
    """Accuracy of one recognition result (def. 4.6)."""
    recognized, true = set(recognized), set(true)
    n_t, n_f = len(recognized & true), len(recognized - true)
    if n_t + n_f == 0:
        return len(true) / n_classes
    return n_t / (len(true) + n_f)


def top1_accuracy(top: Hashable | None, true: Iterable[Hashable]) -> float:
    """Top-1 accuracy of one answer: 1 where its single label is one of the true classes, else 0
    (None, no label, counts 0); its mean over images is the top-1 accuracy beside def. 4.6's."""
    return float(top is not None and top in set(true))


def residual_entropy(rec: "Recognition") -> dict:
    """Entropy in bits of every class node after recognition (alg. 5.1 step 2)."""
    out = {}
    for label, p in rec.posteriors.items():
        out[label] = 0.0 if not 0.0 < p < 1.0 else float(-(p * math.log2(p) + (1 - p) * math.log2(1 - p)))
    return out


@dataclass
class Recognition:
    """posteriors per class; recognized (> 0.5); features queried in order with their values;
    beliefs after each step (beliefs[0] are the priors), which alg. 4.8 consults; ``top``: the one
    label of :func:`top_class`, filled where an answer asks for it (None inside learning)."""

    posteriors: dict
    recognized: set
    queried: list = field(default_factory=list)
    values: dict = field(default_factory=dict)
    beliefs: list = field(default_factory=list)
    top: Hashable | None = None


class Plan:
    """The networks' structure as recognition indexes it: every feature once (``keys``), the
    networks holding each, and each network's slots in the side-by-side information array. It
    depends only on the networks and their feature tuples (not on CPTs or thresholds), so its owner
    (a learner, for all its recognitions) reuses it while those are the same (``structure``); a
    learner keeps the last two, since a search adds a candidate and removes it again."""

    def __init__(self, networks: dict[Hashable, ClassNetwork], structure: tuple):
        self.structure = structure
        self.labels, self.nets = list(networks), list(networks.values())
        self.keys = list(dict.fromkeys(k for net in self.nets for k in net.features))
        index = {k: i for i, k in enumerate(self.keys)}
        where = [np.array([index[k] for k in net.features], dtype=np.int64) for net in self.nets]
        self.local = [dict(zip(net.features, range(len(net.features)))) for net in self.nets]
        self.holders: list[list[int]] = [[] for _ in self.keys]  # the networks holding each feature, in network order
        for n, net in enumerate(self.nets):
            for key in net.features:
                self.holders[index[key]].append(n)
        # every network's informations side by side, network after network: the first maximum is
        # the first network's, then its first feature's (the tie rule in the module docstring)
        self.start = np.cumsum([0] + [len(w) for w in where])
        self.slot_key = np.concatenate(where) if self.keys else np.zeros(0, dtype=np.int64)
        self.slots: list[list[int]] = [[] for _ in self.keys]  # the slots of each feature
        for slot, i in enumerate(self.slot_key.tolist()):
            self.slots[i].append(slot)
        self.where = where  # each network's features as key indices, in its order

    # the same as arrays, for many images at once (:func:`recognize_block`), built on first use

    @cached_property
    def index(self) -> dict:
        """Each feature's position in ``keys``."""
        return {k: i for i, k in enumerate(self.keys)}

    @cached_property
    def key_slots(self) -> np.ndarray:
        """Whether slot s belongs to feature k (K, S)."""
        out = np.zeros((len(self.keys), len(self.slot_key)), dtype=bool)
        out[self.slot_key, np.arange(len(self.slot_key))] = True
        return out

    @cached_property
    def holds(self) -> np.ndarray:
        """Whether network n holds feature k (N, K)."""
        out = np.zeros((len(self.nets), len(self.keys)), dtype=bool)
        for n, w in enumerate(self.where):
            out[n, w] = True
        return out

    @cached_property
    def position(self) -> np.ndarray:
        """Feature k's node position in network n (N, K; 0 where n does not hold it)."""
        out = np.zeros((len(self.nets), len(self.keys)), dtype=np.int64)
        for n, w in enumerate(self.where):
            out[n, w] = np.arange(len(w))
        return out

    @classmethod
    def of(cls, networks: dict[Hashable, ClassNetwork], *known: "Plan | None") -> "Plan":
        """The plan of ``networks``: one of the ``known`` plans where it fits them, else a new one."""
        structure = tuple((label, net, net.features) for label, net in networks.items())
        return next((plan for plan in known if plan is not None and plan.structure == structure), None) or cls(networks, structure)


def recognize(networks: dict[Hashable, ClassNetwork], measure: Callable[[Hashable], float],
              tolerance: float = 1e-12, positive_only: bool = False, plan: Plan | None = None,
              top: bool = False) -> Recognition:
    """Alg. 4.4: ``measure(feature)`` returns the feature's value in the current image (eq. 3.14).

    Features are indexed once per network structure (:class:`Plan`: ``plan`` where the caller
    keeps one that still fits the networks, else a new one); each network keeps its evidence as a
    state array and only the networks that hold the queried feature recompute their informations.
    ``top``: also fill :attr:`Recognition.top` (:func:`top_class`), which may measure more features.
    """
    plan = Plan.of(networks, plan)
    labels, nets, keys, slot_key = plan.labels, plan.nets, plan.keys, plan.slot_key
    states = [np.full(len(net.features), -1, dtype=np.int64) for net in nets]
    evaluated = [engine(net).evaluate(state) for net, state in zip(nets, states)]
    belief = [e[0] for e in evaluated]
    informative = np.concatenate([e[1] for e in evaluated]) if keys else np.zeros(0)
    asked = np.zeros(len(slot_key), dtype=bool)
    beliefs = [dict(zip(labels, belief))]
    queried, values = [], {}

    def record(key, value):
        values[key] = value
        queried.append(key)
        beliefs.append(dict(zip(labels, belief)))

    _sequential(plan, states, belief, informative, asked, measure, tolerance, positive_only, record=record)
    posteriors = beliefs[-1]
    rec = Recognition(posteriors, {c for c, p in posteriors.items() if p > 0.5}, queried, values, beliefs)
    if top:
        rec.top = top_class(networks, rec, measure, plan, positive_only)
    return rec


def decided(inference: ExactInference, state: np.ndarray, belief: float) -> bool:
    """Whether a network's class is decided under the evidence ``state``: its ``belief`` is 0 or 1 and
    its log odds are infinite, so that no further evidence can change it (module doc; a belief of 1.0
    that is only rounded is not decided)."""
    return inference.can_decide and (belief == 0.0 or belief == 1.0) and math.isinf(inference.log_odds(state))


def _entered(inference: ExactInference, state: np.ndarray, position: int, present: bool) -> tuple | None:
    """``state`` with node ``position`` observed (present or absent) and the network's (posterior,
    informations) under it, by its engine ``inference``; None where the network deems that evidence
    impossible (not entered)."""
    trial = state.copy()
    trial[position] = int(present)
    posterior, info = inference.evaluate(trial)
    return (trial, posterior, info) if posterior == posterior else None  # NaN: impossible


def _sequential(plan: Plan, states, belief, informative: np.ndarray, asked: np.ndarray, measure, tolerance: float,
                positive_only: bool, chosen: np.ndarray | None = None, record=None) -> None:
    """Alg. 4.4's loop from the evidence ``states`` (per network), ``belief`` (posteriors) and the
    slots' ``informative`` and ``asked`` (all updated in place): query the feature of largest mutual
    information (ties: first network, first feature) while it exceeds ``tolerance``, and enter its
    presence or absence into every network holding it (the ``chosen`` ones only, where given);
    ``record(feature, value)`` after each query."""
    start, slot_key, slots, keys = plan.start, plan.slot_key, plan.slots, plan.keys
    engines = [engine(net) for net in plan.nets]  # the networks stand still during a recognition
    settled: set[int] = set()  # the networks found decided: neither asked nor told again
    while len(informative):
        slot = int(informative.argmax())
        if not informative[slot] > tolerance:
            break
        best = int(slot_key[slot])
        key = keys[best]
        asked[slots[best]] = True
        informative[slots[best]] = 0.0
        value = float(measure(key))
        for n in plan.holders[best]:
            if (chosen is not None and not chosen[n]) or n in settled:
                continue
            if decided(engines[n], states[n], belief[n]):
                settled.add(n)
                continue
            present = value > plan.nets[n].threshold[key]
            if positive_only and not present:
                continue
            entered = _entered(engines[n], states[n], plan.local[n][key], present)
            if entered is not None:
                states[n], belief[n], info = entered
                informative[start[n]:start[n + 1]] = np.where(asked[start[n]:start[n + 1]], 0.0, info)
        if record is not None:
            record(key, value)


def _replayed(net: ClassNetwork, local: dict, rec: Recognition, positive_only: bool) -> np.ndarray:
    """The evidence state alg. 4.4 left in ``net`` after ``rec``: its queried features entered in their
    order as :func:`recognize` enters them (absence skipped with ``positive_only``, evidence the network
    deems impossible not entered), so the same state, step for step."""
    state, inference = np.full(len(net.features), -1, dtype=np.int64), engine(net)
    for key in rec.queried:
        if key not in local:
            continue
        present = rec.values[key] > net.threshold[key]
        if positive_only and not present:
            continue
        entered = _entered(inference, state, local[key], present)
        if entered is not None:
            state = entered[0]
    return state


def top_class(networks: dict[Hashable, ClassNetwork], rec: Recognition, measure: Callable[[Hashable], float],
              plan: Plan | None = None, positive_only: bool = False) -> Hashable | None:
    """The one label of an image beside alg. 4.4's set (def. 4.5), given its recognition ``rec`` and
    ``measure`` (the feature values, as :func:`recognize` takes them); None only without networks.

    Where exactly one class is recognized, that class. Otherwise the candidates are the recognized
    classes (ambiguous) or every class (ignorant), and alg. 4.4 goes on with their networks alone,
    from the evidence ``rec`` entered: it queries the candidates' features not queried yet, by largest
    mutual information with any candidate's class node (ties: first network, first feature), while
    one exceeds :data:`TOP_TOLERANCE`, so past a stopping threshold (``test_information``) the first
    recognition stopped at. The answer is the candidate of largest posterior; posteriors equal in
    float (both saturated at 1.0 or 0.0) go to the larger log posterior odds
    (:meth:`~ftorch.recognition.exact.ExactInference.log_odds`, which does not saturate), then to the
    first network. The other networks are neither asked nor changed.
    """
    if len(rec.recognized) == 1:
        return next(iter(rec.recognized))
    plan = Plan.of(networks, plan)
    labels, nets, local = plan.labels, plan.nets, plan.local
    start, slot_key, slots = plan.start, plan.slot_key, plan.slots
    candidates = [n for n, c in enumerate(labels) if c in rec.recognized] or list(range(len(labels)))
    if len(candidates) <= 1:
        return labels[candidates[0]] if candidates else None
    chosen = np.zeros(len(nets), dtype=bool)
    chosen[candidates] = True
    asked = np.zeros(len(slot_key), dtype=bool)
    for key in rec.queried:
        asked[slots[plan.index[key]]] = True
    informative = np.zeros(len(slot_key))  # the other networks' slots stay 0: never queried for them
    states, belief = {}, {}
    for n in candidates:
        states[n] = _replayed(nets[n], local[n], rec, positive_only)
        belief[n], info = engine(nets[n]).evaluate(states[n])
        informative[start[n]:start[n + 1]] = np.where(asked[start[n]:start[n + 1]], 0.0, info)
    _sequential(plan, states, belief, informative, asked, measure, TOP_TOLERANCE, positive_only, chosen)
    largest = max(belief[n] for n in candidates)
    tied = [n for n in candidates if belief[n] == largest]
    if len(tied) > 1:  # saturated in float: the log odds still tell them apart; then network order
        odds = {n: engine(nets[n]).log_odds(states[n]) for n in tied}
        most = max((o for o in odds.values() if o == o), default=None)
        tied = [n for n in tied if odds[n] == most] or tied
    return labels[tied[0]]


def recognize_block(networks: dict[Hashable, ClassNetwork], values: np.ndarray, tolerance: float = 1e-12,
                    positive_only: bool = False, plan: Plan | None = None, top: bool = False) -> list[Recognition]:
    """Alg. 4.4 for B images at once: ``values`` (K, B) are the values of the plan's features
    (``Plan.keys``, every network's features once, in network order) in each image.

    The same steps as :func:`recognize`, taken by all images side by side: evidence states
    (B, nodes) per network, informations (B, slots), one argmax per image and step, and each
    network's :meth:`~ftorch.recognition.exact.ExactInference.evaluate` for the states its images
    reach. Every number is computed by the same operations on the same operands as there (the
    block only gathers and scatters them), so the queries, values, beliefs and answers are those
    of :func:`recognize` image by image, ties included (tested). ``top``: also fill
    :attr:`Recognition.top` by :func:`top_class`, from the image's column of ``values``; only the
    images whose answer is not one class go on (image by image: a few of a block, each its own
    candidates), so the tops are those of :func:`recognize` too.
    """
    plan = Plan.of(networks, plan)
    if values.shape[0] != len(plan.keys):
        raise ValueError(f"values for {values.shape[0]} features, but the networks hold {len(plan.keys)}")
    if not values.shape[1]:
        return []
    block = _Block(plan, values.shape[1])
    active = np.arange(block.count) if len(plan.slot_key) else np.zeros(0, dtype=np.int64)
    while len(active):
        rows = block.informative[active]
        slot = rows.argmax(1)
        go = rows[np.arange(len(active)), slot] > tolerance
        active, slot = active[go], slot[go]
        if len(active):
            block.query(active, plan.slot_key[slot], values, positive_only)
    out = [Recognition(b[-1], {c for c, p in b[-1].items() if p > 0.5}, q, m, b)
           for b, q, m in zip(block.beliefs, block.queried, block.measured)]
    if top:
        index = plan.index
        for b, rec in enumerate(out):
            rec.top = top_class(networks, rec, _column(values, index, b), plan, positive_only)
    return out


def _column(values: np.ndarray, index: dict, b: int) -> Callable[[Hashable], float]:
    """The measurement of image ``b`` of a block: a feature's value in its column of ``values``."""
    return lambda key: float(values[index[key], b])


class _Block:
    """The state of :func:`recognize_block`'s images side by side: evidence states (B, nodes) per network,
    beliefs (B, networks), informations (B, slots), the slots asked, and each image's trace."""

    def __init__(self, plan: Plan, count: int):
        self.plan, self.count, nets = plan, count, plan.nets
        self.thresholds = np.zeros(plan.holds.shape)
        for n, net in enumerate(nets):
            self.thresholds[n, plan.where[n]] = np.array([net.threshold[k] for k in net.features])
        self.states = [np.full((count, len(net.features)), -1, dtype=np.int64) for net in nets]
        evaluated = [engine(net).evaluate(state[0]) for net, state in zip(nets, self.states)]
        self.belief = np.array([[e[0] for e in evaluated]] * count).reshape(count, len(nets))
        self.informative = np.tile(np.concatenate([e[1] for e in evaluated]) if plan.keys else np.zeros(0), (count, 1))
        self.asked = np.zeros(self.informative.shape, dtype=bool)
        self.settled = np.zeros((count, len(nets)), dtype=bool)  # decided networks: neither asked nor told again
        first = dict(zip(plan.labels, [e[0] for e in evaluated]))
        self.beliefs: list[list[dict]] = [[dict(first)] for _ in range(count)]
        self.queried: list[list] = [[] for _ in range(count)]
        self.measured: list[dict] = [{} for _ in range(count)]

    def query(self, active: np.ndarray, best: np.ndarray, values: np.ndarray, positive_only: bool) -> None:
        """One step of alg. 4.4 for the images ``active``: each measures its feature ``best`` (key positions),
        and every network that holds it takes the evidence."""
        plan, keys = self.plan, self.plan.keys
        mask = plan.key_slots[best]
        self.asked[active] |= mask
        self.informative[active] = np.where(mask, 0.0, self.informative[active])
        value = values[best, active]
        for b, k, v in zip(active.tolist(), best.tolist(), value.tolist()):
            self.queried[b].append(keys[k])
            self.measured[b][keys[k]] = v
        holding = plan.holds[:, best]
        for n in np.flatnonzero(holding.any(1)).tolist():  # the networks that hold some image's query
            held = holding[n]
            self.enter(n, active[held], best[held], value[held] > self.thresholds[n, best[held]], positive_only)
        for b, row in zip(active.tolist(), self.belief[active].tolist()):
            self.beliefs[b].append(dict(zip(plan.labels, row)))

    def enter(self, n: int, images: np.ndarray, nodes: np.ndarray, present: np.ndarray, positive_only: bool) -> None:
        """Network ``n`` takes the presence of its ``nodes`` (key positions) in ``images``, where the evidence
        is possible (only presence with ``positive_only``): new states, beliefs and informations."""
        plan, inference = self.plan, engine(self.plan.nets[n])
        if inference.can_decide:
            belief = self.belief[images, n]
            sure = (belief == 0.0) | (belief == 1.0)
            for i, b in zip(images[sure].tolist(), belief[sure].tolist()):
                self.settled[i, n] = self.settled[i, n] or decided(inference, self.states[n][i], b)
        told = ~self.settled[images, n] & (present if positive_only else True)
        images, nodes, present = images[told], nodes[told], present[told]
        if not len(images):
            return
        trial = self.states[n][images]
        trial[np.arange(len(images)), plan.position[n, nodes]] = present
        results = [inference.evaluate(row) for row in trial]
        posterior = np.array([r[0] for r in results])
        possible = posterior == posterior  # not NaN: the evidence is possible
        if not possible.all():
            images, trial, posterior = images[possible], trial[possible], posterior[possible]
            results = [r for r, ok in zip(results, possible.tolist()) if ok]
            if not len(images):
                return
        self.states[n][images], self.belief[images, n] = trial, posterior
        span = slice(plan.start[n], plan.start[n + 1])
        self.informative[images, span] = np.where(self.asked[images, span], 0.0, np.stack([r[1] for r in results]))
