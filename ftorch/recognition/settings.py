"""The distinctive-feature learner's settings: one validated object, read by the learner, the
runner's command line, its run configuration and the saved state alike.

Two presets. :class:`LearnerSettings` () holds the measured best (chosen on seeds 5-9 and on
development data, never on reported views; docs/results.md): a learning threshold of 0.1 bits,
pseudocount 1, redundancy 3, the three primitives (texel, edgel pair, statistical texture) and a
contrastive search of factor 4, one setting for COIL objects and faces alike.
:meth:`LearnerSettings.thesis` holds the dissertation's own settings: recognition until I_max = 0,
relative-frequency CPTs, alg. 5.2 and alg. 4.10 as printed (texels and edgel pairs, one draw of n_fgen).
Each field's ``help`` is what the command line prints for it (``--n-ex`` for ``n_ex``).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from enum import StrEnum

import numpy as np

from ..errors import InputError
from ..settings import Settings, option
from ..space.region import Frame


class Primitive(StrEnum):
    """The kinds of new primitive that method 2 samples, in the order its draw indexes them."""

    TEXEL = "texel"
    EDGEL = "edgel"  # a geometric compound of two edgels
    TEXTURE = "texture"  # 7.2.1


THESIS_PRIMITIVES = (Primitive.TEXEL, Primitive.EDGEL)


def primitive_set(value) -> tuple[Primitive, ...]:
    """The primitives named by ``value`` (a comma-separated string or a sequence of names), in
    :class:`Primitive` order, so that a set names one draw; InputError for an unknown, repeated or
    empty choice."""
    names = value.split(",") if isinstance(value, str) else list(value)
    try:
        chosen = [Primitive(str(name).strip()) for name in names]
    except ValueError:
        raise InputError(f"primitives {value!r}: expected a comma-separated choice of "
                         f"{', '.join(Primitive)}") from None
    if not chosen or len(set(chosen)) != len(chosen):
        raise InputError(f"primitives {value!r}: name each of {', '.join(Primitive)} at most once, one at least")
    return tuple(p for p in Primitive if p in chosen)


def frame_set(value) -> tuple[Frame, ...]:
    """The frames named by ``value`` (a comma-separated string, empty or "none" for none, or a
    sequence of names), in :class:`Frame` order; InputError for an unknown or repeated one."""
    names = ([] if value.strip() in ("", "none") else value.split(",")) if isinstance(value, str) else list(value)
    try:
        chosen = [Frame(str(name).strip()) for name in names]
    except ValueError:
        raise InputError(f"regions {value!r}: expected none, or a comma-separated choice of {', '.join(Frame)}") from None
    if len(set(chosen)) != len(chosen):
        raise InputError(f"regions {value!r}: name each of {', '.join(Frame)} at most once")
    return tuple(f for f in Frame if f in chosen)


class Evidence(StrEnum):
    """What recognition enters into the networks (4.4.1, 4.4.2)."""

    BOTH = "both"  # presence and absence
    POSITIVE = "positive"  # presence only: an absent feature may be occluded


class Distinctions(StrEnum):
    """How expert learning meets the class distinctions that lack distinctive features (alg. 5.2, 7.2.4)."""

    SHARED = "shared"  # a search prefers the feature with the most power over its class's short distinctions
    PAIR = "pair"  # alg. 5.2 as printed: a feature for the one least-well-discriminated pair


@dataclass(frozen=True)
class LearnerSettings(Settings):
    """The options of :class:`~ftorch.recognition.learner.DistinctiveFeatureLearner` (its module
    docstring says what each does and why); validated on construction (InputError)."""

    n_ex: int = option(5, "example images per class, alg. 4.8", at_least=1, at_most=1000,
                              what="a number of images")
    n_fgen: int = option(10, "candidates per generation method, alg. 4.10", at_least=1, at_most=1000,
                                what="a number of candidates")
    min_information: float = option(
        0.1, "stop a recognition inside learning once no unqueried feature has more mutual information "
        "with a class (4.4.2; 0: only at I_max = 0)", "BITS")
    search_rounds: int = option(1, "calls of alg. 4.10 per search at most: alg. 5.1 searches until a candidate "
                                "reaches t_KSD", "N", at_least=1, at_most=100, what="a number of calls")
    redundancy: int = option(3, "distinctive features each needed class distinction should have, 7.2.4 "
                             "(1: alg. 5.2 as printed)", "K", at_least=1, at_most=100, what="a number of features")
    evidence: Evidence = option(Evidence.BOTH, "both: presence and absence enter the networks (4.4.1); "
                                "positive: presence only (4.4.2)")
    distinctions: Distinctions = option(
        Distinctions.PAIR, "pair: an expert search serves alg. 5.2's one least-well-discriminated pair, as "
        "printed; shared: it also measures its candidates on the other classes its class is short of "
        "distinctive features against and tries first those with the most distinctive power summed over "
        "these distinctions (measured, not adopted: docs/decisions.md)")
    pseudocount: float = option(1.0, "added to every CPT count (0: relative frequencies as the thesis)", "A")
    leak: float = option(0.0, "detection failure: every CPT entry p becomes L + (1 - 2L) p, so that one missing "
                         "feature does not rule its class out", "L")
    cut_position: float = option(0.5, "a node's cut-point between the two values where its KSD is reached: "
                                 "0.5 the midpoint (4.3.2)", "W")
    test_information: float = option(0.0, "the stopping threshold of the learner's answers (0: every "
                                      "informative feature is asked)", "BITS")
    primitives: tuple[Primitive, ...] = option(
        tuple(Primitive), f"the new primitives alg. 4.10 samples, a comma-separated choice of {', '.join(Primitive)} "
        "(texture: the statistical texture of 7.2.1, the intensity distribution)", "LIST")
    regions: tuple[Frame, ...] = option(
        (), f"the frames in which a search bounds features to regions, general-to-specific: none, or a "
        f"comma-separated choice of {', '.join(Frame)} (none: a feature looks anywhere, as the thesis's)", "LIST")
    contrast: int = option(4, "contrastive search: each generation method draws N x n_fgen candidates, those "
                           "that sample images from the misrecognized or sample image and the class's other examples "
                           "in turn, and tries the n_fgen most distinctive on the search's images first (1: alg. 4.10 "
                           "as printed)", "N", at_least=1, at_most=100, what="a factor")
    texture_parts: bool = option(False, "geometric expansions (alg. 4.10 method 3) may add a statistical texture "
                                 "part beside an oriented part, half of the time (3.5 with 7.2.1)")
    calibrate: bool = option(False, "calibrated counting: count each node's cut-point and CPT on the training "
                             "views other than those its search selected it on, where enough remain (cross-fitting)")

    def __post_init__(self):
        for f in fields(self):
            if f.metadata["at_least"] is not None:
                object.__setattr__(self, f.name, integer_in(f.name, getattr(self, f.name), f.metadata["at_least"]))
        for name in ("min_information", "test_information"):
            object.__setattr__(self, name, threshold_bits(name, getattr(self, name)))
        for name, low, high, closed in (("pseudocount", 0.0, math.inf, False), ("leak", 0.0, 0.5, False),
                                        ("cut_position", 0.0, 1.0, True)):
            value = _real(name, getattr(self, name))
            if not (low <= value <= high if closed else low <= value < high):
                bound = f"[{low:g}, {high:g}]" if closed else "a finite number >= 0" if high == math.inf else \
                    f"[{low:g}, {high:g})"
                raise InputError(f"{name} must lie in {bound}, got {value}")
            object.__setattr__(self, name, value)
        for name in ("texture_parts", "calibrate"):
            if not isinstance(getattr(self, name), (bool, np.bool_)):
                raise InputError(f"{name} must be True or False, got {getattr(self, name)!r}")
            object.__setattr__(self, name, bool(getattr(self, name)))
        for name, kind in self._choices():
            try:
                object.__setattr__(self, name, kind(getattr(self, name)))
            except ValueError:
                raise InputError(f"{name} {getattr(self, name)!r}: expected one of {', '.join(kind)}") from None
        object.__setattr__(self, "primitives", primitive_set(self.primitives))
        object.__setattr__(self, "regions", frame_set(self.regions))

    @classmethod
    def thesis(cls, **changes) -> "LearnerSettings":
        """The dissertation's settings (alg. 4.4 until I_max = 0, relative frequencies, alg. 5.2 and
        alg. 4.10 as printed), with ``changes``."""
        return cls(min_information=0.0, pseudocount=0.0, redundancy=1, primitives=THESIS_PRIMITIVES,
                   contrast=1).replace(**changes)

    @property
    def positive_only(self) -> bool:
        """Whether only present features enter the networks (``evidence`` positive, 4.4.2)."""
        return self.evidence is Evidence.POSITIVE

    @classmethod
    def _choices(cls) -> list[tuple[str, type[StrEnum]]]:
        """The options that take one of an enum's values (evidence, distinctions): each with its enum."""
        return [(f.name, type(f.default)) for f in fields(cls) if isinstance(f.default, StrEnum)]

    def to_dict(self) -> dict:
        """JSON-ready: the primitives and the regions' frames as comma-separated strings, each choice as its name."""
        out = asdict(self)
        out["primitives"] = ",".join(self.primitives)
        out["regions"] = ",".join(self.regions)
        out.update({name: str(getattr(self, name)) for name, _ in self._choices()})
        return out


def integer_in(name: str, value, minimum: int, maximum: int | None = None) -> int:
    """An integer option from ``minimum`` (to ``maximum``); InputError for a float, a bool or a number out of range."""
    if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < minimum or \
            (maximum is not None and value > maximum):
        bound = f"from {minimum} to {maximum}" if maximum is not None else f"of at least {minimum}"
        raise InputError(f"{name} must be an integer {bound}, got {value!r}")
    return int(value)


def _real(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise InputError(f"{name} must be a number, got {value!r}")
    return float(value)


def threshold_bits(name: str, value) -> float:
    """A stopping threshold of alg. 4.4 in bits: [0, 1); InputError otherwise."""
    value = _real(name, value)
    if not 0.0 <= value < 1.0:
        raise InputError(f"{name} must lie in [0, 1) bits, got {value}")
    return value
