"""The typed records of a grasp run (6.5): its configuration, the job of one seed, and the blocks of its
checkpoints and report. They become JSON only at the file boundary (:class:`training.records.Record`,
field by field in the order the files have always had, so report.json and checkpoint.json keep their
bytes) and are read back from it (a fold's checkpoint on ``--resume``) strictly: a key they do not
know is refused (:class:`~training.records.StrictRecord`).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum

from ftorch.grasp.learner import GraspLearner
from ftorch.grasp.settings import POOR_MU0, GraspSettings
from training.cli.outputs import Ledger
from training.records import INLINE, OPTIONAL, StrictRecord


class Mode(StrEnum):
    """How a fold's learner gains its experience (6.5; on-line is beyond the thesis)."""

    OFFLINE = "offline"  # observing the haptic system's recorded grasps
    ONLINE = "online"  # executing its own recommendations


@dataclass(frozen=True)
class RunConfig(StrictRecord):
    """A grasp run's settings, as its report and every fold checkpoint record them (a fold resumes only
    under the same); ``device`` as asked until the seed's job resolves it where it runs."""

    experiment: str = "clean"
    seed: int = 0
    pool: int = 80
    best: int = 20
    epochs: int = 10
    size: int = 64
    t_dtheta_deg: float = 10.0
    folds: int = 2
    online: bool = False
    finger_choice: str = "quality"
    mu0_split: float | None = POOR_MU0  # None: orientation mistakes only (thesis and pooled)
    device: str = "cpu"

    def settings(self) -> GraspSettings:
        """The learner's settings (``t_dtheta`` in radians)."""
        return GraspSettings(t_dtheta=math.radians(self.t_dtheta_deg), finger_choice=self.finger_choice,
                             mu0_split=self.mu0_split)

    def new_learner(self, fold: int) -> GraspLearner:
        """A fresh learner for fold ``fold``, seeded with 100 seed + fold."""
        return GraspLearner(self.settings(), seed=self.seed * 100 + fold, device=self.device)

    def fold_config(self, mode: Mode) -> dict:
        """What a fold's checkpoint records: these settings and the fold's mode."""
        return {**self.to_json(), "mode": str(mode)}

    def modes(self) -> tuple[Mode, ...]:
        """The modes each fold runs in: off-line, and on-line with ``online``."""
        return (Mode.OFFLINE, Mode.ONLINE) if self.online else (Mode.OFFLINE,)


@dataclass(frozen=True)
class SeedJob:
    """One seed of a run, for a local process or a Ray task (picklable): its configuration, its run and
    TensorBoard folders, the run's ledger, whether to show progress and to resume from checkpoints."""

    config: RunConfig
    out: str
    logdir: str
    ledger: Ledger
    quiet: bool = True
    resume: bool = False


@dataclass
class Epoch(StrictRecord):
    """A training epoch in the report (alg. 6.2's outcomes counted, mistakes and poor grasps as fractions,
    each set's features and features sampled so far)."""

    epoch: int
    correct: int
    refit: int
    sampled: int
    mistakes: float
    poor: float
    features_2: int
    features_3: int
    sampled_2: int
    sampled_3: int


@dataclass
class Predictions(StrictRecord):
    """What the learner predicted before each training grasp's outcome in an epoch (TensorBoard's):
    orientation error and E[mu_0] (None: no prediction), measured mu_0 (None: no equilibrium), fingers."""

    error_deg: list[float | None] = field(default_factory=list)
    expected_mu0: list[float | None] = field(default_factory=list)
    measured_mu0: list[float | None] = field(default_factory=list)
    fingers: list[int | None] = field(default_factory=list)


@dataclass
class FoldState(StrictRecord):
    """What a fold's training goes on from: the epoch log and predictions, the presentation order's
    generator and the learner's training state (both as ftorch writes them)."""

    epochs: list[Epoch]
    predictions: list[Predictions]
    order: dict
    learner: dict


@dataclass
class Grasp(StrictRecord):
    """A test grasp of a held-out object: its kind and trial index, the outcome (mu0 None: no
    equilibrium) and, for a cued grasp, whether a recommendation started it."""

    object: str
    index: int
    fingers: int
    theta_h: float
    theta_H: float
    mu0: float | None
    probes: int
    converged: bool
    recommended: bool | None = field(default=None, metadata=OPTIONAL)


@dataclass
class FoldTests(StrictRecord):
    """A fold's tests: orientation errors of the test grasps (None: no prediction), and each held-out
    object grasped haptic-only and cued."""

    orientation_errors_deg: list[float | None]
    haptic: list[Grasp]
    cued: list[Grasp]


@dataclass
class Summary(StrictRecord):
    """median, mean and 90th percentile of n values (None where n is 0)."""

    median: float | None
    mean: float | None
    p90: float | None
    n: int


@dataclass
class ErrorSummary(StrictRecord):
    """Orientation errors in degrees: median and 90th percentile of n, unpredicted ones counted."""

    median: float | None
    p90: float | None
    n: int
    unpredicted: int


@dataclass
class Sides(StrictRecord):
    """One summary of haptic-only and one of cued grasps."""

    haptic: Summary
    cued: Summary


@dataclass
class PoorGrasps(StrictRecord):
    """The fractions of poor grasps (mu_0 > ``split_mu0``), haptic-only and cued, and the reduction
    (None: no poor haptic grasp to reduce)."""

    haptic: float
    cued: float
    split_mu0: float
    reduction: float | None


@dataclass
class Results(StrictRecord):
    """The headline of a report or a fold, pooled over tests."""

    orientation_error_deg: ErrorSummary
    mu0: Sides
    probes: Sides
    poor_grasp_fraction: PoorGrasps
    cued_fingers: dict[str, dict[str, int]]  # object kind -> finger count -> cued grasps
    recommended_fraction: float


@dataclass
class FoldEntry(StrictRecord):
    """A fold in the report: its epochs, results and tests, and every learned feature with its model
    and quality split (JSON as ftorch writes them, by finger count)."""

    fold: int
    mode: Mode
    epochs: list[Epoch]
    results: Results = field(metadata=INLINE)
    tests: FoldTests
    features: dict


@dataclass
class PoorShares(StrictRecord):
    """A seed's poor-grasp fractions and reduction in a seed study."""

    haptic: float
    cued: float
    reduction: float | None

    @classmethod
    def of(cls, poor: PoorGrasps) -> "PoorShares":
        return cls(poor.haptic, poor.cued, poor.reduction)


@dataclass
class OnlineRun(StrictRecord):
    """A seed's on-line results in a seed study."""

    poor_grasp_fraction: PoorShares
    orientation_error_deg: ErrorSummary


@dataclass
class SeedRun(StrictRecord):
    """One seed in a seed study."""

    seed: int
    poor_grasp_fraction: PoorShares
    orientation_error_deg: ErrorSummary
    cued_fingers: dict[str, dict[str, int]]
    seconds: float
    online: OnlineRun | None = field(default=None, metadata=OPTIONAL)


@dataclass
class Spread(StrictRecord):
    """mean, sd, worst value and its seed over the ``n`` seeds that have a value (None where none has);
    ``not_available``: the seeds left out."""

    mean: float | None
    sd: float | None
    worst: float | None
    worst_seed: int | None
    n: int
    not_available: int


@dataclass
class SeedStudy(StrictRecord):
    """The ``seeds`` block: each seed, and the spreads of the poor-grasp reductions, the cued poor-grasp
    fractions and the median orientation errors, per mode."""

    runs: list[SeedRun]
    reduction: dict[Mode, Spread]
    poor_cued: dict[Mode, Spread]
    error_median_deg: dict[Mode, Spread]


@dataclass
class GraspReport(StrictRecord):
    """A seed's report.json (with ``seeds`` for the first seed of a study), and its schema
    (:mod:`training.grasping.schema`; None: 0)."""

    config: RunConfig
    device: str
    machine: dict
    seconds: float
    results: Results = field(metadata=INLINE)
    online: dict[Mode, Results] | None = field(default=None, metadata=OPTIONAL)
    folds: list[FoldEntry] = field(default_factory=list)
    figures: list[str] = field(default_factory=list)
    seeds: SeedStudy | None = field(default=None, metadata=OPTIONAL)
    schema: int | None = field(default=None, metadata=OPTIONAL)
