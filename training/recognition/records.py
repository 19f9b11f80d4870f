"""Typed records of a recognition run's report: the test, feature and confusion blocks of a stage
(tables 4.2-4.4, 5.1-5.3), the stage and fold entries, the seed study (figure 5.5), the growth of
the features sampled (figure 5.19), the peers on the same splits, and the report itself; the
robustness and tradeoff benchmarks, evaluate and salient build their files from the same base.

Decision: the runner builds these records and every reader takes them; they become dicts only at
the JSON boundary (:class:`training.records.Record`), so report.json keeps exactly the bytes it had
as nested dicts; a stage entry writes its stage's own fields in line (:class:`StageEntry`).
"""
from __future__ import annotations

import json
import math
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np

from ftorch.errors import InputError
from ftorch.recognition.stages import ClassAdded, Stage
from training.records import INLINE, OPTIONAL, Record, key

from .schema import migrated_config


@dataclass(kw_only=True)
class TestBlock(Record):
    """Accuracy (def. 4.6), top-1 accuracy beside it, and the proportions of the five outcomes (def. 4.5,
    :class:`~ftorch.recognition.inference.Outcome`'s order) over a test set. ``top1`` is None in a
    stage tested before ftorch reported it (a fold resumed from such a checkpoint), NaN in an average
    over stages some of which lack it (``report.without_top1``)."""

    accuracy: float
    top1: float | None = field(default=None, metadata=OPTIONAL)
    correct: float
    wrong: float
    ambiguous: float
    confused: float
    ignorant: float


@dataclass
class FeatureBlock(Record):
    """Table 4.2's feature columns: nodes in all networks (BN), different features, mean queried per
    recognition, sampled so far."""

    bn: float
    different: float
    queried: float
    sampled: float


@dataclass(kw_only=True)
class ConfusionRow(Record):
    """Tables 4.3 and 4.4, one true class: recognized-as counts of correct and wrong results, the
    ambiguous / confused / ignorant counts, the class network's size, and the false-positive classes
    of ambiguous results (counts, or proportions where averaged over folds)."""

    recognized_as: dict = field(metadata=key("as"))
    ambiguous: float
    confused: float
    ignorant: float
    features: float
    ambiguous_with: dict | None = field(default=None, metadata=OPTIONAL)

    def total(self) -> float:
        """The class's test views (single-class ones) the row counts, at least 1."""
        return max(sum(self.recognized_as.values()) + self.ambiguous + self.confused + self.ignorant, 1)


@dataclass
class StageEntry(Record):
    """A finished stage's report entry: the stage (alg. 5.3) in line, then its test on the test views
    of the classes taught, feature counts, confusion rows per class and the seconds so far."""

    stage: Stage = field(metadata=INLINE)
    test: TestBlock
    features: FeatureBlock
    confusion: dict[Any, ConfusionRow]
    seconds: float


@dataclass
class FoldEntry(Record):
    """A fold's report entry: its stages, the classes added (alg. 5.4, incremental folds), the machine
    it trained on and its peak GPU memory (on a GPU)."""

    fold: int
    stages: list[StageEntry]
    added: list[ClassAdded] | None = field(default=None, metadata=OPTIONAL)
    machine: dict | None = field(default=None, metadata=OPTIONAL)
    gpu_memory_mib: float | None = field(default=None, metadata=OPTIONAL)


@dataclass
class StageAverage(Record):
    """Mean over folds of one stage's test and feature blocks."""

    test: TestBlock
    features: FeatureBlock


@dataclass
class Averages(Record):
    """The folds' mean after stage 0 (novices) and after the final stage (experts)."""

    stage0: StageAverage
    final: StageAverage


@dataclass
class Spread(Record):
    """A figure over seeds: each seed's value, their mean and sample standard deviation."""

    values: list[float]
    mean: float
    sd: float


@dataclass
class PowerFit(Record):
    """Figure 5.19's least-squares line on log-log: the exponent b, its 95% interval, the scale a of
    a * classes**b, and the points fitted (None where not available)."""

    exponent: float | None
    interval: list
    scale: float | None
    points: int


@dataclass
class Growth(Record):
    """Figure 5.19 of an incremental run: each fold's curve (classes taught, sampled so far) and fit,
    and the fit over all folds' points."""

    sampled: dict[str, list]
    folds: dict[str, PowerFit]
    exponent: float | None
    interval: list
    scale: float | None
    points: int


@dataclass
class SeedGrowth(Record):
    """Figure 5.19's exponent of one incremental fold over seeds: each seed's, their mean and t-interval."""

    seeds: list[int]
    fold: int
    exponents: list
    mean: float | None
    interval: list
    sampled: dict[str, list]


@dataclass(kw_only=True)
class SeedStudy(Record):
    """Figure 5.5: novice vs expert accuracy (and top-1 accuracy, features queried) of one fold over
    seeds, with a paired one-tailed t-test of expert > novice."""

    seeds: list[int]
    fold: int
    novice: Spread
    expert: Spread
    novice_top1: Spread | None = field(metadata=OPTIONAL)  # None: a report written before top-1 was reported
    expert_top1: Spread | None = field(metadata=OPTIONAL)
    novice_queried: Spread
    expert_queried: Spread
    t: float
    p: float
    growth: SeedGrowth | None = field(default=None, metadata=OPTIONAL)


@dataclass
class PeerScores(Record):
    """A peer on every set (def. 4.5, 4.6 and top-1), with what it stores per class."""

    bytes_per_class: float
    views_per_class: float | None = field(default=None, metadata=OPTIONAL)  # pixel 1-NN
    descriptors_per_view: float | None = field(default=None, metadata=OPTIONAL)  # SIFT matching
    sets: dict[str, TestBlock] = field(default_factory=dict, metadata=INLINE)


@dataclass
class PeerFold(Record):
    """``recognize --peers``: the peers on one fold's clean test views."""

    fold: int
    pixel_nn: PeerScores
    sift: PeerScores
    seconds: float


@dataclass(kw_only=True)
class PeerMeans(Record):
    """A peer's figures averaged over folds: what it stores, its accuracy (def. 4.6) and top-1 accuracy
    on the clean test views."""

    bytes_per_class: float
    views_per_class: float | None = field(default=None, metadata=OPTIONAL)
    descriptors_per_view: float | None = field(default=None, metadata=OPTIONAL)
    clean: float
    clean_top1: float


@dataclass
class SplitPeers(Record):
    """The peers on each fold's clean test views (``recognize --peers``), per fold and averaged."""

    folds: list[PeerFold]
    average: dict[str, PeerMeans]


@dataclass
class Report(Record):
    """A recognition run's report.json: the task, where it ran, its config (as RunConfig.to_dict wrote
    it), every fold's entry, the averages, and where asked the seed study, the growth (incremental),
    the peak GPU memory per task and the peers on the same splits (``recognize --peers``); its schema."""

    task: str
    classes: list
    seed: int
    device: str
    machine: dict
    seconds: float
    config: dict
    folds: list[FoldEntry]
    average: Averages
    seeds: SeedStudy | None = field(default=None, metadata=OPTIONAL)
    growth: Growth | None = field(default=None, metadata=OPTIONAL)
    gpu_memory_mib: dict | None = field(default=None, metadata=OPTIONAL)
    peers: SplitPeers | None = field(default=None, metadata=OPTIONAL)
    schema: int | None = field(default=None, metadata=OPTIONAL)  # training.recognition.schema; None: 0

    @property
    def incremental(self) -> bool:
        return bool(self.config.get("incremental"))


@contextmanager
def recognize_run(run: Path, option: str) -> Iterator[tuple[Report, dict]]:
    """The report.json of the recognize run in folder ``run`` (given as the command line's ``option``) and
    its run config brought to the current schema (:func:`~training.recognition.schema.migrated_config`),
    for the ``with`` body to read them: a newer schema is refused in its own line, and anything found
    wrong, in the file or in what the body reads of it, is one InputError naming the folder."""
    try:
        report = Report.from_json(json.loads((run / "report.json").read_text()))
        yield report, migrated_config(report.config, report.schema, f"{option} {run}: a report")
    except InputError:
        raise  # a newer schema: its own line
    except (OSError, ValueError, KeyError, TypeError, AttributeError, IndexError, RecursionError) as err:
        raise InputError(f"{option} {run}: not a run folder of recognize ({type(err).__name__}: {err})") from None



def mean_block(blocks: list):
    """The field-wise mean of records of one kind (NaN where some lack a figure, None where all do)."""
    values = {}
    for f in fields(blocks[0]):
        known = [getattr(b, f.name) for b in blocks]
        values[f.name] = None if all(v is None for v in known) else math.nan if None in known else float(np.mean(known))
    return type(blocks[0])(**values)
