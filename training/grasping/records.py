"""The typed records of a grasp run (6.5): its configuration, the job of one seed, and the blocks of its
checkpoints and report. They become JSON only at the file boundary (:meth:`Record.to_dict`) and are
read back from it (:meth:`Record.from_dict`: a fold's checkpoint on ``--resume``), field by field in
the order the files have always had, so report.json and checkpoint.json keep their bytes.
"""
from __future__ import annotations

import math
import types
from dataclasses import dataclass, field, fields
from enum import Enum, StrEnum
from typing import Union, get_args, get_origin, get_type_hints

from ftorch.grasp.learner import GraspLearner
from ftorch.grasp.settings import POOR_MU0, GraspSettings
from training.cli.outputs import Ledger

FLAT = {"flat": True}  # a field whose record's fields are written in line with its owner's
OPTIONAL = {"optional": True}  # a field left out of the file where it is None


class Record:
    """A dataclass written to and read from JSON by its field types: records nested (in lists, in dicts by
    name, or None), enums by their value; ``FLAT`` and ``OPTIONAL`` fields as their metadata say."""

    def to_dict(self) -> dict:
        """JSON-ready, in field order."""
        out = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if f.metadata.get("flat"):
                out.update(value.to_dict())
            elif value is not None or not f.metadata.get("optional"):
                out[f.name] = _to_json(value)
        return out

    @classmethod
    def from_dict(cls, data: dict):
        """The record :meth:`to_dict` wrote; ValueError or TypeError for a key it does not know or lacks."""
        if not isinstance(data, dict):
            raise TypeError(f"{cls.__name__}: expected an object, got {type(data).__name__}")
        hints, values, known = get_type_hints(cls), {}, set()
        for f in fields(cls):
            if f.metadata.get("flat"):
                values[f.name] = hints[f.name].from_dict({k: data[k] for k in _names(hints[f.name]) if k in data})
                known |= _names(hints[f.name])
            elif f.name in data:
                values[f.name], known = _from_json(hints[f.name], data[f.name]), known | {f.name}
        unknown = set(data) - known
        if unknown:
            raise ValueError(f"{cls.__name__}: unknown fields {sorted(unknown)}")
        return cls(**values)


def _names(record: type) -> set[str]:
    """The keys a record writes (its flat fields' keys in place of their own)."""
    hints = get_type_hints(record)
    return set().union(*(_names(hints[f.name]) if f.metadata.get("flat") else {f.name} for f in fields(record)))


def _to_json(value):
    if isinstance(value, Enum):
        return value.value
    if isinstance(value, Record):
        return value.to_dict()
    if isinstance(value, list):
        return [_to_json(v) for v in value]
    if isinstance(value, dict):
        return {_to_json(k): _to_json(v) for k, v in value.items()}
    return value


def _from_json(hint, value):
    """``value`` read from JSON as the type ``hint`` says."""
    origin, args = get_origin(hint), get_args(hint)
    if origin in (Union, types.UnionType):
        return None if value is None else _from_json(next(a for a in args if a is not type(None)), value)
    if origin is list:
        return [_from_json(args[0], v) for v in value]
    if origin is dict:
        return {_from_json(args[0], k): _from_json(args[1], v) for k, v in value.items()}
    if isinstance(hint, type) and issubclass(hint, Record):
        return hint.from_dict(value)
    if isinstance(hint, type) and issubclass(hint, Enum):
        return hint(value)
    return value


class Mode(StrEnum):
    """How a fold's learner gains its experience (6.5; on-line is beyond the thesis)."""

    OFFLINE = "offline"  # observing the haptic system's recorded grasps
    ONLINE = "online"  # executing its own recommendations


@dataclass(frozen=True)
class RunConfig(Record):
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
        return {**self.to_dict(), "mode": str(mode)}

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
class Epoch(Record):
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
class Predictions(Record):
    """What the learner predicted before each training grasp's outcome in an epoch (TensorBoard's):
    orientation error and E[mu_0] (None: no prediction), measured mu_0 (None: no equilibrium), fingers."""

    error_deg: list[float | None] = field(default_factory=list)
    expected_mu0: list[float | None] = field(default_factory=list)
    measured_mu0: list[float | None] = field(default_factory=list)
    fingers: list[int | None] = field(default_factory=list)


@dataclass
class FoldState(Record):
    """What a fold's training goes on from: the epoch log and predictions, the presentation order's
    generator and the learner's training state (both as ftorch writes them)."""

    epochs: list[Epoch]
    predictions: list[Predictions]
    order: dict
    learner: dict


@dataclass
class Grasp(Record):
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
class FoldTests(Record):
    """A fold's tests: orientation errors of the test grasps (None: no prediction), and each held-out
    object grasped haptic-only and cued."""

    orientation_errors_deg: list[float | None]
    haptic: list[Grasp]
    cued: list[Grasp]


@dataclass
class Summary(Record):
    """median, mean and 90th percentile of n values (None where n is 0)."""

    median: float | None
    mean: float | None
    p90: float | None
    n: int


@dataclass
class ErrorSummary(Record):
    """Orientation errors in degrees: median and 90th percentile of n, unpredicted ones counted."""

    median: float | None
    p90: float | None
    n: int
    unpredicted: int


@dataclass
class Sides(Record):
    """One summary of haptic-only and one of cued grasps."""

    haptic: Summary
    cued: Summary


@dataclass
class PoorGrasps(Record):
    """The fractions of poor grasps (mu_0 > ``split_mu0``), haptic-only and cued, and the reduction
    (None: no poor haptic grasp to reduce)."""

    haptic: float
    cued: float
    split_mu0: float
    reduction: float | None


@dataclass
class Results(Record):
    """The headline of a report or a fold, pooled over tests."""

    orientation_error_deg: ErrorSummary
    mu0: Sides
    probes: Sides
    poor_grasp_fraction: PoorGrasps
    cued_fingers: dict[str, dict[str, int]]  # object kind -> finger count -> cued grasps
    recommended_fraction: float


@dataclass
class FoldEntry(Record):
    """A fold in the report: its epochs, results and tests, and every learned feature with its model
    and quality split (JSON as ftorch writes them, by finger count)."""

    fold: int
    mode: Mode
    epochs: list[Epoch]
    results: Results = field(metadata=FLAT)
    tests: FoldTests
    features: dict


@dataclass
class PoorShares(Record):
    """A seed's poor-grasp fractions and reduction in a seed study."""

    haptic: float
    cued: float
    reduction: float | None

    @classmethod
    def of(cls, poor: PoorGrasps) -> "PoorShares":
        return cls(poor.haptic, poor.cued, poor.reduction)


@dataclass
class OnlineRun(Record):
    """A seed's on-line results in a seed study."""

    poor_grasp_fraction: PoorShares
    orientation_error_deg: ErrorSummary


@dataclass
class SeedRun(Record):
    """One seed in a seed study."""

    seed: int
    poor_grasp_fraction: PoorShares
    orientation_error_deg: ErrorSummary
    cued_fingers: dict[str, dict[str, int]]
    seconds: float
    online: OnlineRun | None = field(default=None, metadata=OPTIONAL)


@dataclass
class Spread(Record):
    """mean, sd, worst value and its seed over the ``n`` seeds that have a value (None where none has);
    ``not_available``: the seeds left out."""

    mean: float | None
    sd: float | None
    worst: float | None
    worst_seed: int | None
    n: int
    not_available: int


@dataclass
class SeedStudy(Record):
    """The ``seeds`` block: each seed, and the spreads of the poor-grasp reductions, the cued poor-grasp
    fractions and the median orientation errors, per mode."""

    runs: list[SeedRun]
    reduction: dict[Mode, Spread]
    poor_cued: dict[Mode, Spread]
    error_median_deg: dict[Mode, Spread]


@dataclass
class GraspReport(Record):
    """A seed's report.json (with ``seeds`` for the first seed of a study)."""

    config: RunConfig
    device: str
    machine: dict
    seconds: float
    results: Results = field(metadata=FLAT)
    online: dict[Mode, Results] | None = field(default=None, metadata=OPTIONAL)
    folds: list[FoldEntry] = field(default_factory=list)
    figures: list[str] = field(default_factory=list)
    seeds: SeedStudy | None = field(default=None, metadata=OPTIONAL)

