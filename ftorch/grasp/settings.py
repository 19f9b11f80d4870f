"""The grasp learner's settings: one validated object, read by the learner, the runner's command line,
its run configuration and the saved state alike.

Two presets. :class:`GraspSettings` () holds the measured best, what ``grasp`` runs by default
(docs/results.md, development seeds 100-104): step 2b by quality splits and quality mistakes
learned from, good grasps being those with mu_0 <= ``POOR_MU0``. :meth:`GraspSettings.thesis`
holds the dissertation's alg. 6.2: step 2b compares E[mu_0] (eq. 6.8) of f*_2 and f*_3, and only
orientation mistakes are learned from. Each field's ``help`` is what the command line prints for
it (``--t-dtheta`` for ``t_dtheta``, which the command line takes in degrees).
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from enum import StrEnum

import numpy as np

from ..errors import InputError
from ..settings import Settings, option

MU0_CAP = 2.0  # mu_0 is capped here (an infinite mu_0, no equilibrium, would swamp eq. 6.8's average)
POOR_MU0 = 0.4  # the split between the two modes of figure 6.17: a grasp is poor where mu_0 exceeds it


class FingerChoice(StrEnum):
    """Alg. 6.2 step 2b, the finger count (ftorch/grasp/learner.py says why each exists)."""

    THESIS = "thesis"  # E[mu_0] of f*_c, eq. 6.8
    POOLED = "pooled"  # eq. 6.8 of every present feature, weighted by its support
    QUALITY = "quality"  # the mean mu_0 on the image's side of the set's best quality split


@dataclass(frozen=True)
class GraspSettings(Settings):
    """The options of :class:`~ftorch.grasp.learner.GraspLearner`; validated on construction (InputError).
    ``t_dtheta`` is in radians; ``mu0_split`` None learns from orientation mistakes only, as the thesis."""

    WHAT = "grasp learner"

    t_dtheta: float = option(math.radians(10), "the orientation error below which a prediction is correct, "
                             "6.4.2", "DEGREES")
    max_k: int = option(4, "components of a feature's von Mises mixture at most, eq. 6.4", "K", 1,
                        what="a number of components")
    min_points: int = option(3, "instances a feature model, a mixture component or a quality split side needs",
                            "N", 1, what="a number of instances")
    discard_every: int = option(40, "grasps of a set between discards of its unused features", "N", 1,
                                what="a number of grasps")
    max_distance: float | None = option(None, "longest edgel pair sampled, pixels (default a quarter image side)",
                                        "PIXELS")
    finger_choice: FingerChoice = option(FingerChoice.QUALITY, "alg. 6.2 step 2b: quality: per set, the mean mu_0 "
                                         "on the image's side of the best quality split; pooled: E[mu_0] over every "
                                         "present feature, weighted by its support; thesis: E[mu_0] of f*_c alone")
    mu0_split: float | None = option(POOR_MU0, "the mu_0 dividing good from poor grasps, for quality splits and "
                                     "quality mistakes", "MU0")

    def __post_init__(self):
        for f in fields(self):
            value, low = getattr(self, f.name), f.metadata["at_least"]
            if low is not None:
                if isinstance(value, bool) or not isinstance(value, (int, np.integer)) or value < low:
                    raise InputError(f"{f.name} must be an integer of at least {low}, got {value!r}")
                object.__setattr__(self, f.name, int(value))
        t = _real("t_dtheta", self.t_dtheta)
        if not 0 < t < math.pi:
            raise InputError(f"t_dtheta must lie in (0, pi) radians, got {t}")
        object.__setattr__(self, "t_dtheta", t)
        if self.max_distance is not None:
            distance = _real("max_distance", self.max_distance)
            if not 0 < distance < math.inf:
                raise InputError(f"max_distance must be a positive number of pixels or None, got {distance}")
            object.__setattr__(self, "max_distance", distance)
        try:
            object.__setattr__(self, "finger_choice", FingerChoice(self.finger_choice))
        except ValueError:
            raise InputError(f"finger_choice {self.finger_choice!r}: expected one of {', '.join(FingerChoice)}") from None
        if self.mu0_split is not None:
            split = _real("mu0_split", self.mu0_split)
            if not 0 < split < MU0_CAP:
                raise InputError(f"mu0_split must lie in (0, {MU0_CAP}), got {split}")
            object.__setattr__(self, "mu0_split", split)
        elif self.finger_choice is FingerChoice.QUALITY:
            raise InputError("finger_choice 'quality' needs mu0_split, the mu_0 that divides good from poor grasps")

    @classmethod
    def thesis(cls, **changes) -> "GraspSettings":
        """Alg. 6.2 as the dissertation gives it (step 2b by eq. 6.8 of f*_c, orientation mistakes only),
        with ``changes``."""
        return cls(finger_choice=FingerChoice.THESIS, mu0_split=None).replace(**changes)

    def to_dict(self) -> dict:
        """JSON-ready: the finger choice as its name."""
        return {**asdict(self), "finger_choice": str(self.finger_choice)}


def _real(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, (int, float, np.integer, np.floating)):
        raise InputError(f"{name} must be a number, got {value!r}")
    return float(value)
