"""A recognition's trace (alg. 4.4), as data and as a picture: what the learner asked, what it
found where, and how each answer moved its beliefs.

The learner's ``explain`` recognizes one image by its own alg. 4.4 (``recognize`` with its
``test_information`` and ``evidence`` settings), so the answer is ``predict([image])[0]`` and the
posteriors those of ``predict_proba``; :func:`trace` reads that recognition's :class:`Recognition`
(``queried``, ``values``, ``beliefs``) step by step. Where each queried feature was found is
:func:`~ftorch.space.evaluate.feature_values`' located reference point in the same image records
(eq. 3.14), whose value is the one recognition measured.

The picture follows one class, the :attr:`Explanation.focus`: the top class where the recognition
names one, else the recognized class (of largest posterior, where several are, def. 4.5), else the
class of largest posterior. A step raised, lowered or left that class's belief (:class:`Effect`).
"""
from __future__ import annotations

import math
from collections.abc import Hashable
from dataclasses import dataclass, field
from enum import StrEnum
from typing import NamedTuple

import numpy as np
from torch import Tensor

from ..errors import InputError
from ..space import draw
from ..space.evaluate import feature_values
from ..space.features import Feature, Within
from ..space.region import Region
from .bayes import ClassNetwork
from .environment import ImageSet
from .inference import Recognition
from .settings import Evidence, LearnerSettings

# the colours of the picture's marks and legend lines, by the step's effect on the focus class
COLOURS = {"raised": (20, 150, 40), "lowered": (215, 30, 30), "unchanged": (125, 125, 125)}
MIN_SIDE = 384  # the picture's image is enlarged to at least this many pixels a side


class Effect(StrEnum):
    """What a step did to the belief of the class the picture follows."""

    RAISED = "raised"
    LOWERED = "lowered"
    UNCHANGED = "unchanged"

    @classmethod
    def of(cls, before: float, after: float) -> "Effect":
        return cls.RAISED if after > before else cls.LOWERED if after < before else cls.UNCHANGED

    @property
    def colour(self) -> tuple[int, int, int]:
        return COLOURS[self.value]


class Location(NamedTuple):
    """Where a feature is strongest in the image (eq. 3.14): its reference point's x and y (pixels),
    sigma and theta (radians); NaN where the image has no reference point of its kind (value 0)."""

    x: float
    y: float
    sigma: float
    theta: float

    @property
    def found(self) -> bool:
        return math.isfinite(self.x)

    def to_dict(self) -> dict:
        return {name: _finite(value) for name, value in self._asdict().items()}


@dataclass(frozen=True)
class Node:
    """A network that holds the queried feature: its class, the node's threshold, and whether the
    value exceeds it there, i.e. whether the feature was found present (alg. 4.4)."""

    label: Hashable
    threshold: float
    present: bool

    def to_dict(self) -> dict:
        return {"class": _label(self.label), "threshold": _finite(self.threshold), "present": self.present}


@dataclass(frozen=True)
class Step:
    """One query of alg. 4.4: the ``feature`` with the largest mutual information, its ``value`` in
    the image, the ``nodes`` holding it, where it was found, and each class's belief before and
    after its evidence was entered. ``where``: the located points of its parts, keyed by (part,
    regions around it) as :func:`ftorch.space.draw.to_locate` keys them (for drawing compounds and
    region-bound features, each part where it is strongest inside its regions)."""

    feature: Feature
    value: float
    nodes: tuple[Node, ...]
    location: Location
    before: dict
    beliefs: dict
    where: dict = field(repr=False, compare=False)

    @property
    def region(self) -> Region | None:
        """The region a region-bound feature (:class:`~ftorch.space.features.Within`) is bound to, or None."""
        return self.feature.region if isinstance(self.feature, Within) else None

    def effect(self, label: Hashable) -> Effect:
        """What this step did to the belief of class ``label``."""
        return Effect.of(self.before[label], self.beliefs[label])

    def to_dict(self) -> dict:
        region = self.region
        return {"feature": self.feature.to_dict(), "describe": self.feature.describe(), "value": _finite(self.value),
                "networks": [node.to_dict() for node in self.nodes], "location": self.location.to_dict(),
                "region": None if region is None else region.to_dict(), "beliefs": _beliefs(self.beliefs)}


@dataclass(frozen=True)
class Explanation:
    """The trace of one recognition (alg. 4.4) and its answer (def. 4.5): the ``recognized`` classes,
    as ``predict`` gives them, the ``top`` class where the recognition names one, the ``posteriors``,
    the ``priors`` (beliefs before any query) and the query ``steps`` in order. ``evidence`` and
    ``information``: the settings it ran with; ``name`` and ``image``: the image as measured."""

    recognized: frozenset
    top: Hashable | None
    posteriors: dict
    priors: dict
    steps: tuple[Step, ...]
    evidence: Evidence
    information: float
    name: str
    image: Tensor = field(repr=False, compare=False)

    @property
    def focus(self) -> Hashable:
        """The class the picture follows: the top class, else the recognized class of largest
        posterior, else the class of largest posterior (ties: the first network's)."""
        if self.top is not None:
            return self.top
        pool = [c for c in self.posteriors if c in self.recognized] or list(self.posteriors)
        return max(pool, key=lambda c: self.posteriors[c])

    def to_dict(self) -> dict:
        """JSON-ready (strict: a location not found is null, never NaN); classes are JSON scalars
        (str or int labels as they are, others as text), keyed by their text."""
        focus = self.focus
        steps = [{"step": n, **step.to_dict(), "effect": str(step.effect(focus))} for n, step in enumerate(self.steps, 1)]
        return {"image": self.name, "recognized": sorted(map(_label, self.recognized), key=str), "top": _optional(self.top),
                "focus": _label(focus), "posteriors": _beliefs(self.posteriors), "priors": _beliefs(self.priors),
                "evidence": str(self.evidence), "test_information": self.information, "steps": steps}

    def picture(self, min_side: int = MIN_SIDE) -> np.ndarray:
        """The image (grey, enlarged to ``min_side``) with each queried feature drawn where it was
        found, numbered in query order and coloured by its :class:`Effect` on the :attr:`focus`
        class; beside it the legend (step, feature type, value against threshold, belief before and
        after), above it the answer. RGB uint8 (:func:`ftorch.space.draw.save_rgb` writes it)."""
        focus = self.focus
        effects = [step.effect(focus) for step in self.steps]
        lines = [(_legend_line(n, step, focus), effect.colour) for n, (step, effect) in enumerate(zip(self.steps, effects), 1)]
        # the steps that moved the focus class are drawn last, over those that did not
        order = sorted(range(len(self.steps)), key=lambda k: effects[k] is not Effect.UNCHANGED)
        marks = [(self.steps[k].feature, self.steps[k].where, effects[k].colour, str(k + 1)) for k in order]
        return draw.draw_trace(self.image, marks, lines, self._title(), min_side)

    @property
    def answer(self) -> str:
        """The answer in words: the top class (and the recognized ones where they differ), the
        recognized classes, or none (an ignorant result, def. 4.5)."""
        if self.top is not None:
            return f"top {self.top}" + ("" if self.recognized == {self.top} else f", recognized {_names(self.recognized) or 'none'}")
        return f"recognized {_names(self.recognized)}" if self.recognized else "recognized none (ignorant)"

    def _title(self) -> str:
        focus = self.focus
        return (f"{self.name}: {self.answer}; P({focus}) {self.priors[focus]:.3f} -> {self.posteriors[focus]:.3f} "
                f"in {len(self.steps)} queries (green raised it, red lowered it)")


def trace(networks: dict[Hashable, ClassNetwork], settings: LearnerSettings, env: ImageSet,
          rec: Recognition) -> Explanation:
    """The trace (module doc) of ``rec``, the recognition (alg. 4.4, with ``settings``' ``test_information``
    and ``evidence``) of the one image of ``env`` by ``networks``: each queried feature located where it
    is strongest in the image."""
    every: dict = {}  # (part, regions around it) -> the feature that locates it, as a drawing keys them
    for feature in rec.queried:
        draw.to_locate(feature, every)
    measured = list(dict.fromkeys([*rec.queried, *every.values()]))
    where = {}
    if measured:
        found = feature_values(measured, env.record(0))
        where = {f: Location(*(float(t[j, 0]) for t in (found.x, found.y, found.sigma, found.theta)))
                 for j, f in enumerate(measured)}
    return Explanation(frozenset(rec.recognized), rec.top, dict(rec.posteriors), dict(rec.beliefs[0]),
                       tuple(_steps(networks, rec, where)), settings.evidence, settings.test_information,
                       env.names[0], env.images[0])


def _steps(networks: dict[Hashable, ClassNetwork], rec: Recognition, where: dict) -> list[Step]:
    out = []
    for n, feature in enumerate(rec.queried):
        value = rec.values[feature]
        nodes = tuple(Node(label, float(net.threshold[feature]), bool(value > net.threshold[feature]))
                      for label, net in networks.items() if feature in net)
        parts: dict = {}
        draw.to_locate(feature, parts)
        out.append(Step(feature, float(value), nodes, where[feature], dict(rec.beliefs[n]), dict(rec.beliefs[n + 1]),
                        {key: where[located] for key, located in parts.items()}))
    return out


def _legend_line(n: int, step: Step, focus: Hashable) -> str:
    """Step n: its feature's type, its value against each holding node's threshold, and the focus
    class's belief before and after, each to as many decimals as tell them apart (3 to 7)."""
    digits = _digits(step.value, [node.threshold for node in step.nodes])
    tests = ", ".join(f"{'>' if node.present else '<='} {node.threshold:.{digits}f} {node.label}" for node in step.nodes)
    where = "" if step.location.found else " (found nowhere)"
    before, after = step.before[focus], step.beliefs[focus]
    places = _digits(before, [after]) if before != after else 3
    return (f"{n}. {step.feature.describe()}: {step.value:.{digits}f} {tests}{where}; "
            f"P({focus}) {before:.{places}f} -> {after:.{places}f}")


def _digits(value: float, others: list[float]) -> int:
    """The decimals, 3 to 7, that write ``value`` apart from each of ``others``."""
    return next((d for d in range(3, 7) if all(f"{value:.{d}f}" != f"{o:.{d}f}" for o in others)), 7)


def _names(labels) -> str:
    return ", ".join(sorted(map(str, labels)))


def _finite(value: float) -> float | None:
    """A float for strict JSON: None where it is NaN or infinite."""
    value = float(value)
    return value if math.isfinite(value) else None


def _label(label: Hashable):
    """A class label as a JSON scalar: str and int as they are, anything else as its text."""
    return label if isinstance(label, (str, int)) and not isinstance(label, bool) else str(label)


def _optional(label: Hashable | None):
    return None if label is None else _label(label)


def _beliefs(beliefs: dict) -> dict:
    """Beliefs per class keyed by the class's text; InputError where two classes share a text."""
    out = {str(c): _finite(p) for c, p in beliefs.items()}
    if len(out) < len(beliefs):
        raise InputError(f"two classes have the same name as text ({', '.join(sorted(map(repr, beliefs)))}): "
                         "their beliefs cannot be written apart")
    return out
