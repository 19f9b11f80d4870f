"""Sequential recognition across class networks (alg. 4.4) and its evaluation (def. 4.5, 4.6).

Recognition repeatedly queries the feature with the largest mutual information with any class
node, measures it in the image, and enters presence or absence (value above the node's
threshold) into every network that holds it: positive and negative evidence both count. With
``positive_only`` (4.4.2's alternative for robustness to occlusion) only presence is entered; an
absent feature stays unobserved, as if occluded. It stops when no unqueried feature is
informative (I_max <= ``tolerance``). Evidence that a
network deems impossible (probability 0 under its counted CPTs) is not entered there; that
network keeps its belief. Ties in I_max go to the first network, then the first feature.
"""
from __future__ import annotations

import math
from collections.abc import Callable, Hashable, Iterable
from dataclasses import dataclass, field
from enum import StrEnum
from functools import cached_property

import numpy as np

from .bayes import ClassNetwork


class Outcome(StrEnum):
    """The categories of a recognition result (def. 4.5), in the thesis's table order."""

    CORRECT = "correct"  # recognized = true
    WRONG = "wrong"  # as many classes as true, some false
    AMBIGUOUS = "ambiguous"  # all true classes and some false ones
    CONFUSED = "confused"  # some false classes, not all true ones, a different number
    IGNORANT = "ignorant"  # some true classes missing and no false one


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


def residual_entropy(rec: "Recognition") -> dict:
    """Entropy in bits of every class node after recognition (alg. 5.1 step 2)."""
    out = {}
    for label, p in rec.posteriors.items():
        out[label] = 0.0 if not 0.0 < p < 1.0 else float(-(p * math.log2(p) + (1 - p) * math.log2(1 - p)))
    return out


@dataclass
class Recognition:
    """posteriors per class; recognized (> 0.5); features queried in order with their values;
    beliefs after each step (beliefs[0] are the priors), which alg. 4.8 consults."""

    posteriors: dict
    recognized: set
    queried: list = field(default_factory=list)
    values: dict = field(default_factory=dict)
    beliefs: list = field(default_factory=list)


class Plan:
    """The networks' structure as recognition indexes it: every feature once (``keys``), the
    networks holding each, and each network's slots in the side-by-side information array. It
    depends only on the networks and their feature tuples (not on CPTs or thresholds), so its owner
    (a learner, for all its recognitions) reuses it while those are the same (``signature``); a
    learner keeps the last two, since a search adds a candidate and removes it again."""

    def __init__(self, networks: dict[Hashable, ClassNetwork], signature: tuple):
        self.signature = signature
        self.labels, self.nets = list(networks), list(networks.values())
        self.keys = list(dict.fromkeys(k for net in self.nets for k in net.features))
        index = {k: i for i, k in enumerate(self.keys)}
        where = [np.array([index[k] for k in net.features], dtype=np.int64) for net in self.nets]
        self.local = [dict(zip(net.features, range(len(net.features)))) for net in self.nets]
        self.holders = [[] for _ in self.keys]  # the networks holding each feature, in network order
        for n, net in enumerate(self.nets):
            for key in net.features:
                self.holders[index[key]].append(n)
        # every network's informations side by side, network after network: the first maximum is
        # the first network's, then its first feature's (the tie rule in the module docstring)
        self.start = np.cumsum([0] + [len(w) for w in where])
        self.slot_key = np.concatenate(where) if self.keys else np.zeros(0, dtype=np.int64)
        self.slots = [[] for _ in self.keys]  # the slots of each feature
        for slot, i in enumerate(self.slot_key.tolist()):
            self.slots[i].append(slot)
        self.where = where  # each network's features as key indices, in its order

    # the same as arrays, for many images at once (:func:`recognize_block`), built on first use

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

    @staticmethod
    def signature(networks: dict[Hashable, ClassNetwork]) -> tuple:
        return tuple((label, net, net.features) for label, net in networks.items())

    @classmethod
    def of(cls, networks: dict[Hashable, ClassNetwork], *known: "Plan | None") -> "Plan":
        """The plan of ``networks``: one of the ``known`` plans where it fits them, else a new one."""
        signature = cls.signature(networks)
        return next((plan for plan in known if plan is not None and plan.signature == signature), None) or cls(networks, signature)


def recognize(networks: dict[Hashable, ClassNetwork], measure: Callable[[Hashable], float],
              tolerance: float = 1e-12, positive_only: bool = False, plan: Plan | None = None) -> Recognition:
    """Alg. 4.4: ``measure(feature)`` returns the feature's value in the current image (eq. 3.14).

    Features are indexed once per network structure (:class:`Plan`: ``plan`` where the caller
    keeps one that still fits the networks, else a new one); each network keeps its evidence as a
    state array and only the networks that hold the queried feature recompute their informations.
    """
    plan = Plan.of(networks, plan)
    labels, nets, keys, local, holders = plan.labels, plan.nets, plan.keys, plan.local, plan.holders
    start, slot_key, slots = plan.start, plan.slot_key, plan.slots
    states = [np.full(len(net.features), -1, dtype=np.int64) for net in nets]
    evaluated = [net.inference.evaluate(state) for net, state in zip(nets, states)]
    belief = [e[0] for e in evaluated]
    informative = np.concatenate([e[1] for e in evaluated]) if keys else np.zeros(0)
    asked = np.zeros(len(slot_key), dtype=bool)
    beliefs = [dict(zip(labels, belief))]
    queried, values = [], {}
    while len(informative):
        slot = int(informative.argmax())
        if not informative[slot] > tolerance:
            break
        best = int(slot_key[slot])
        key = keys[best]
        asked[slots[best]] = True
        informative[slots[best]] = 0.0
        value = float(measure(key))
        values[key] = value
        queried.append(key)
        for n in holders[best]:
            present = value > nets[n].threshold[key]
            if positive_only and not present:
                continue
            trial = states[n].copy()
            trial[local[n][key]] = int(present)
            posterior, info = nets[n].inference.evaluate(trial)
            if posterior == posterior:  # not NaN: the evidence is possible
                states[n], belief[n] = trial, posterior
                informative[start[n]:start[n + 1]] = np.where(asked[start[n]:start[n + 1]], 0.0, info)
        beliefs.append(dict(zip(labels, belief)))
    posteriors = beliefs[-1]
    return Recognition(posteriors, {c for c, p in posteriors.items() if p > 0.5}, queried, values, beliefs)


def recognize_block(networks: dict[Hashable, ClassNetwork], values: np.ndarray, tolerance: float = 1e-12,
                    positive_only: bool = False, plan: Plan | None = None) -> list[Recognition]:
    """Alg. 4.4 for B images at once: ``values`` (K, B) are the values of the plan's features
    (``Plan.keys``, every network's features once, in network order) in each image.

    The same steps as :func:`recognize`, taken by all images side by side: evidence states
    (B, nodes) per network, informations (B, slots), one argmax per image and step, and each
    network's :meth:`~ftorch.recognition.exact.ExactInference.evaluate` for the states its images
    reach. Every number is computed by the same operations on the same operands as there (the
    block only gathers and scatters them), so the queries, values, beliefs and answers are those
    of :func:`recognize` image by image, ties included (tested).
    """
    plan = Plan.of(networks, plan)
    labels, nets, keys, start, slot_key = plan.labels, plan.nets, plan.keys, plan.start, plan.slot_key
    count = values.shape[1]
    if values.shape[0] != len(keys):
        raise ValueError(f"values for {values.shape[0]} features, but the networks hold {len(keys)}")
    if not count:
        return []
    thresholds = np.zeros(plan.holds.shape)
    for n, net in enumerate(nets):
        thresholds[n, plan.where[n]] = [net.threshold[k] for k in net.features]
    states = [np.full((count, len(net.features)), -1, dtype=np.int64) for net in nets]
    evaluated = [net.inference.evaluate(state[0]) for net, state in zip(nets, states)]
    belief = np.array([[e[0] for e in evaluated]] * count).reshape(count, len(nets))
    informative = np.tile(np.concatenate([e[1] for e in evaluated]) if keys else np.zeros(0), (count, 1))
    asked = np.zeros(informative.shape, dtype=bool)
    first = dict(zip(labels, [e[0] for e in evaluated]))
    beliefs = [[dict(first)] for _ in range(count)]
    queried = [[] for _ in range(count)]
    measured = [{} for _ in range(count)]
    active = np.arange(count) if len(slot_key) else np.zeros(0, dtype=np.int64)
    while len(active):
        rows = informative[active]
        slot = rows.argmax(1)
        go = rows[np.arange(len(active)), slot] > tolerance
        active, slot = active[go], slot[go]
        if not len(active):
            break
        best = slot_key[slot]
        mask = plan.key_slots[best]
        asked[active] |= mask
        informative[active] = np.where(mask, 0.0, informative[active])
        value = values[best, active]
        for b, k, v in zip(active.tolist(), best.tolist(), value.tolist()):
            queried[b].append(keys[k])
            measured[b][keys[k]] = v
        holding = plan.holds[:, best]
        for n in np.flatnonzero(holding.any(1)).tolist():  # the networks that hold some image's query
            net, held = nets[n], holding[n]
            images, nodes = active[held], best[held]
            present = value[held] > thresholds[n, nodes]
            if positive_only:
                images, nodes, present = images[present], nodes[present], present[present]
                if not len(images):
                    continue
            trial = states[n][images]
            trial[np.arange(len(images)), plan.position[n, nodes]] = present
            inference = net.inference
            results = [inference.evaluate(row) for row in trial]
            posterior = np.array([r[0] for r in results])
            possible = posterior == posterior  # not NaN: the evidence is possible
            if not possible.all():
                images, trial, posterior = images[possible], trial[possible], posterior[possible]
                results = [r for r, ok in zip(results, possible.tolist()) if ok]
                if not len(images):
                    continue
            states[n][images], belief[images, n] = trial, posterior
            span = slice(start[n], start[n + 1])
            informative[images, span] = np.where(asked[images, span], 0.0, np.stack([r[1] for r in results]))
        for b, row in zip(active.tolist(), belief[active].tolist()):
            beliefs[b].append(dict(zip(labels, row)))
    out = []
    for b in range(count):
        posteriors = beliefs[b][-1]
        out.append(Recognition(posteriors, {c for c, p in posteriors.items() if p > 0.5}, queried[b], measured[b], beliefs[b]))
    return out
