"""The recognition protocol of 4.5 in training stages: a fold trains a learner by its stage schedule
(:mod:`ftorch.recognition.stages`, alg. 5.3 and 5.4), tests it after each stage, logs, and checkpoints.

After a cycle the fold's state (learner, permutation generator, value cache, stages so far) is
written to its checkpoint, so an interrupted fold resumes to exactly the result it would have
reached: after every cycle (``checkpoint_every`` 0), or once at least that many seconds have
passed since the last write. A write costs time that grows with every feature ever measured
(the value cache and the instance list are compressed anew), a few seconds per cycle at 20 COIL
classes in 128x128, so long runs write every minute and lose at most that on interruption.
"""
from __future__ import annotations

import math
import sys
import time
from collections import Counter
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

import numpy as np
import torch
from tqdm import tqdm

from ftorch.checkpoint import decode_array, encode_array, load_checkpoint, reading, save_checkpoint
from ftorch.errors import InputError
from ftorch.recognition.environment import ImageSet
from ftorch.recognition.inference import Outcome, Recognition, accuracy, outcome, top1_accuracy
from ftorch.recognition.learner import DistinctiveFeatureLearner
from ftorch.recognition.settings import LearnerSettings
from ftorch.recognition.stages import ClassAdded, Cycle, Progress, Schedule, Stage
from ftorch.recognition.state import GENERATOR_STATE, TRAINING_STATE
from ftorch.recognition.state import KIND as LEARNER_KIND
from ftorch.space.features import unpack_features
from ftorch.space.record import FeatureSpace, ImageRecords
from training.data.augment import augment
from training.data.datasets import Task, load_task
from training.records import OPTIONAL, Record

from .records import ConfusionRow, FeatureBlock, FoldEntry, StageEntry, TestBlock
from .schema import SCHEMA, migrated_config

FOLD_KIND = "fold"


def test_block(recognitions: list[Recognition], labels: list[frozenset], classes: list) -> TestBlock:
    """Accuracy (def. 4.6), top-1 accuracy beside it (the share of images whose top label,
    :attr:`Recognition.top`, is one of their true classes) and the proportions of the five outcomes
    (def. 4.5) over a test set."""
    outcomes = Counter(outcome(r.recognized, t) for r, t in zip(recognitions, labels))
    n = max(len(recognitions), 1)
    return TestBlock(accuracy=float(np.mean([accuracy(r.recognized, t, len(classes)) for r, t in zip(recognitions, labels)])),
                     top1=float(np.mean([top1_accuracy(r.top, t) for r, t in zip(recognitions, labels)])),
                     **{str(k): outcomes[k] / n for k in Outcome})


def confusion(recognitions: list[Recognition], labels: list[frozenset], classes: list, networks: dict) -> dict[Any, ConfusionRow]:
    """Tables 4.3 and 4.4 for single-class images: per true class, recognized-as counts for correct
    and wrong results, the ambiguous / confused / ignorant counts, the network size, and the
    false-positive classes of ambiguous results."""
    rows = {c: ConfusionRow(recognized_as=dict.fromkeys(classes, 0), ambiguous=0, confused=0, ignorant=0,
                            features=len(networks[c].features) if c in networks else 0,
                            ambiguous_with=dict.fromkeys(classes, 0)) for c in classes}
    for rec, true in zip(recognitions, labels):
        if len(true) != 1:
            continue
        (c,) = true
        kind = outcome(rec.recognized, true)
        if kind in (Outcome.CORRECT, Outcome.WRONG):
            for r in rec.recognized:
                rows[c].recognized_as[r] += 1
        else:  # the other outcomes' names are the row's counts
            setattr(rows[c], str(kind), getattr(rows[c], str(kind)) + 1)
        if kind is Outcome.AMBIGUOUS:
            for r in rec.recognized - true:
                rows[c].ambiguous_with[r] += 1
    return rows


def feature_block(learner: DistinctiveFeatureLearner, recognitions: list[Recognition]) -> FeatureBlock:
    """Table 4.2's feature columns: nodes in all networks, different features, mean queried, sampled."""
    nodes = [f for net in learner.networks.values() for f in net.features]
    return FeatureBlock(len(nodes), len(set(nodes)),
                        float(np.mean([len(r.queried) for r in recognitions])) if recognitions else 0.0, learner.sampled)


@dataclass(frozen=True)
class RunConfig:
    """A run's settings, as its report and every fold checkpoint record them (a fold resumes only
    under the same): the task, the seed, the learner's settings (:class:`LearnerSettings`, written
    in line with the rest) and the schedule's."""

    task: str
    data: str | None = None
    classes: list = field(default_factory=list)
    views: int = 20
    first_view: int = 0
    size: int | None = None
    seed: int = 0
    learner: LearnerSettings = field(default_factory=LearnerSettings)
    device: str = "cpu"
    stages: str = "0"
    max_cycles: int = 20
    augment: int = 0
    dynamic: bool = False
    incremental: bool = False
    images: str | None = None  # the task's fingerprint (Task.fingerprint): which pixels the run learned and tested on

    def to_dict(self) -> dict:
        """JSON-ready, the learner's settings in line where the field stands."""
        out = {}
        for f in fields(self):
            value = getattr(self, f.name)
            if f.name == "learner":
                out.update(value.to_dict())
            else:
                out[f.name] = list(value) if isinstance(value, list) else value
        return out

    def fold_seed(self, fold: int) -> int:
        """Fold k of a run with seed S seeds its learner and its presentation order with 1000 S + k."""
        return self.seed * 1000 + fold

    def new_learner(self, fold: int) -> DistinctiveFeatureLearner:
        """A fresh learner for fold ``fold`` with these settings."""
        return DistinctiveFeatureLearner(self.learner, seed=self.fold_seed(fold), device=self.device)


@dataclass(frozen=True)
class RecordedTask(Record):
    """What a run's config (:meth:`RunConfig.to_dict`) records of the task it learned: enough to load
    it again (:meth:`load`) and check the images (:func:`same_images`; ``images`` None in a run
    written before runs recorded them)."""

    task: str
    data: str | None
    classes: list
    views: int | None
    size: int | None
    seed: int
    first_view: int
    images: str | None = field(default=None, metadata=OPTIONAL)

    def load(self, data: str | None = None) -> Task:
        """The task, from ``data`` where the images have moved."""
        return load_task(self.task, data or self.data, len(self.classes), self.views, self.size, self.seed, self.first_view)


def same_images(task: Task, recorded: str | None, run: str, data) -> None:
    """InputError where ``task``'s views are not the images a run recorded (``recorded``:
    :attr:`RunConfig.images`): e.g. a copy of the data with the same names and mirrored images;
    a note where the run, written before runs recorded them, cannot tell."""
    if recorded is None:
        print(f"note: {run} does not record which images it learned from; "
              f"{f'those in {data}' if data else 'the ' + task.name + ' task'} are taken as they are", file=sys.stderr)
    elif recorded != task.fingerprint:
        if data is None:  # a built-in task, rendered by this version otherwise than by the run's
            raise InputError(f"the {task.name} task renders other images than those {run} learned and tested on "
                             "(another version of ftorch made the run): train it again")
        raise InputError(f"--data {data}: these are not the images {run} learned and tested on (the same names "
                         "hold other pixels, or other views were chosen): give the run's own images")


@dataclass
class SavedProgress(Record):
    """A fold's progress as its checkpoint stores it: the schedule's (:class:`Progress`) with the
    finished stages' report entries in place of the stages, and the seconds so far."""

    phase: int
    stage: int
    t_ksd: float
    cycles: list[Cycle]
    stages: list[StageEntry]
    misses: int
    done: bool
    total_cycles: int
    seconds: float
    added: list[ClassAdded]
    sampled_before: int

    def check(self) -> None:
        """ValueError where a field has the wrong type or range."""
        counts = [self.phase, self.stage, self.misses, self.total_cycles, self.sampled_before]
        if any(isinstance(n, bool) or not isinstance(n, int) or n < 0 for n in counts):
            raise ValueError(f"progress counts {counts} must be integers >= 0")
        if not (isinstance(self.t_ksd, (int, float)) and 0.0 <= self.t_ksd <= 1.0):
            raise ValueError(f"t_KSD {self.t_ksd!r} outside [0, 1]")
        if not (isinstance(self.seconds, (int, float)) and 0.0 <= self.seconds < math.inf):
            raise ValueError(f"seconds {self.seconds!r} is not a duration")
        if not isinstance(self.done, bool):
            raise ValueError("done must be true or false")


@dataclass
class FoldState:
    """A fold's progress, which its checkpoint stores beside the learner: the schedule's
    (:class:`Progress`), the finished stages' report entries, and the seconds so far."""

    progress: Progress = field(default_factory=Progress)
    entries: list[StageEntry] = field(default_factory=list)
    seconds: float = 0.0

    def to_dict(self) -> dict:
        p = self.progress
        return SavedProgress(p.phase, p.stage, p.t_ksd, p.cycles, self.entries, p.misses, p.done, p.total_cycles,
                             self.seconds, p.added, p.sampled_before).to_json()

    @classmethod
    def from_dict(cls, state: dict) -> "FoldState":
        """The progress read from a checkpoint; ValueError where a field is missing or has the wrong type or range."""
        names = [f.name for f in fields(SavedProgress)]
        if not isinstance(state, dict) or sorted(state) != sorted(names):
            raise ValueError(f"progress fields {sorted(state) if isinstance(state, dict) else state!r}, expected {names}")
        if not all(isinstance(state[k], list) for k in ("cycles", "stages", "added")):  # before they are read
            raise ValueError("cycles, stages and added must be lists")
        saved = SavedProgress.from_json(state)
        saved.check()
        progress = Progress(saved.phase, saved.stage, saved.t_ksd, saved.cycles, [e.stage for e in saved.stages], saved.misses,
                            saved.done, saved.total_cycles, saved.added, saved.sampled_before)
        return cls(progress, saved.stages, saved.seconds)


def load_learner(path) -> DistinctiveFeatureLearner:
    """The learner in ``path``: a learner.json, or a fold's checkpoint.json, whose networks it reads
    (the rest of a fold's state needs its image set: ``recognize --resume`` goes on learning from it);
    one InputError for a damaged or foreign file."""
    data = load_checkpoint(path, (LEARNER_KIND, FOLD_KIND))
    if data["kind"] == LEARNER_KIND:
        return DistinctiveFeatureLearner.load(path)
    learner = DistinctiveFeatureLearner()
    with reading(path, "fold checkpoint"):
        state = {k: v for k, v in data["learner"].items() if k not in TRAINING_STATE}
        learner.load_state_dict(state, unpack_features(data["features"]))
    return learner


@dataclass
class Fold:
    """One fold of a task: its image sets, the run configuration and where its files go."""

    fold: int
    train: ImageSet
    test: ImageSet
    config: RunConfig
    folder: Path
    classes: list
    progress: bool = True
    logger: object = None
    incremental: bool = False
    finished_before: bool = field(default=False, init=False)  # resumed from a checkpoint of a fold that had ended

    @property
    def checkpoint(self) -> Path:
        return self.folder / "checkpoint.json"

    def _save(self, learner, order, state: FoldState):
        """The checkpoint: features stored once for the value cache and the learner, the cache's
        first (it only grows, so its packed blocks are reused from the last checkpoint)."""
        table = self.train.cache.table()
        cache = self.train.cache_state(table)
        learned = learner.state_dict(table=table, env=self.train)  # instance values relative to the cache
        save_checkpoint(self.checkpoint, FOLD_KIND, {
            "config": self.config.to_dict(), "fold": self.fold, "state": state.to_dict(),
            "order": encode_array(order.get_state().numpy().astype(np.float64)),
            "features": table.pack(), "learner": learned, "cache": cache, "schema": SCHEMA})

    def _resume(self):
        data = load_checkpoint(self.checkpoint, FOLD_KIND)
        stored = data.get("config")
        if isinstance(stored, dict):  # nor did a run written before runs recorded their images: not checked
            with reading(self.checkpoint, "fold checkpoint"):
                stored = {"images": self.config.images, **migrated_config(stored, data.get("schema"), "a fold checkpoint")}
        if stored != self.config.to_dict() or data.get("fold") != self.fold:
            raise InputError(f"{self.checkpoint}: written by a different run configuration; "
                             f"use another --out or delete it to start afresh")
        learner = DistinctiveFeatureLearner(device=self.config.device)
        order = torch.Generator()
        with reading(self.checkpoint, "fold checkpoint"):
            features = unpack_features(data["features"], self.train.cache.memo)  # blocks read: packed already
            self.train.load_cache_state(data["cache"], features)  # first: the learner's instance values refer to it
            learner.load_state_dict(data["learner"], features, env=self.train)
            order.set_state(torch.from_numpy(decode_array(data["order"], shape=GENERATOR_STATE).astype(np.uint8)))
            state = FoldState.from_dict(data["state"])
        return learner, order, state

    def schedule(self, learner, order: torch.Generator, stages: int | None, max_cycles: int,
                 progress: Progress | None = None) -> Schedule:
        """The fold's stage schedule (with dynamic training views: the originals and their copies)."""
        versions = self.config.augment + 1 if self.config.dynamic else 1
        return Schedule(learner, self.train, order, stages, max_cycles, self.classes, self.incremental, versions,
                        progress)

    def run(self, max_cycles: int = 20, stages: int | None = 0, resume: bool = False, after_cycle=None,
            checkpoint_every: float = 0.0, before_cycle=None) -> tuple[FoldEntry, DistinctiveFeatureLearner]:
        """Train stages 0..``stages`` (None: auto; per added class in an incremental fold, at most
        ``INCREMENTAL_LIMIT`` expert stages) and test after each; returns the fold's report entry
        and the learner (also saved as learner.json). The checkpoint is written after a cycle or
        stage once ``checkpoint_every`` seconds have passed since the last write (0: every time), and
        at the end; ``after_cycle(n)`` is called after a write that holds the n-th cycle, and
        ``before_cycle()`` before each cycle (the runner's workers take idle cores there)."""
        if resume and self.checkpoint.is_file():
            learner, order, state = self._resume()
            self.finished_before = state.progress.done
        else:
            learner = self.config.new_learner(self.fold)
            order = torch.Generator().manual_seed(self.config.fold_seed(self.fold))
            state = FoldState()
        schedule = self.schedule(learner, order, stages, max_cycles, state.progress)
        progress = schedule.progress
        start = time.perf_counter() - state.seconds
        written = time.perf_counter()
        with tqdm(desc=f"fold {self.fold}", unit="cycle", disable=not self.progress, leave=False) as bar:
            while not progress.done:
                phase, added = progress.phase, len(progress.added)
                if not schedule.stage_over and before_cycle is not None:
                    before_cycle()
                step = schedule.step()
                if isinstance(step, Stage):
                    state.entries.append(self._stage_entry(learner, step, schedule, phase, start))
                    self._log_stage(state.entries[-1])
                    if len(progress.added) > added:
                        self._log_class_added(progress.added[-1])
                else:
                    bar.update(1)
                    bar.set_postfix(stage=progress.stage, t_ksd=progress.t_ksd, mistakes=step.mistakes,
                                    features=step.features)
                    self._log_cycle(progress.total_cycles, step)
                if not progress.done and time.perf_counter() - written < checkpoint_every:
                    continue
                state.seconds = time.perf_counter() - start
                self._save(learner, order, state)
                written = time.perf_counter()
                if after_cycle is not None and not progress.done and len(progress.cycles):
                    after_cycle(progress.total_cycles)
        learner.save(self.folder / "learner.json")
        return FoldEntry(self.fold, state.entries, list(progress.added) if self.incremental else None), learner

    def _stage_entry(self, learner, stage: Stage, schedule: Schedule, phase: int, start: float) -> StageEntry:
        """A finished stage's report entry: the stage, tested on the test images of the classes taught
        in its ``phase``."""
        taught, tested = schedule.taught(phase), schedule.indices(self.test, phase)
        recognitions = learner.recognize_many(self.test, tested)
        labels = [self.test.labels[i] for i in tested]
        return StageEntry(stage, test_block(recognitions, labels, taught), feature_block(learner, recognitions),
                          confusion(recognitions, labels, taught, learner.networks), time.perf_counter() - start)

    def _log_class_added(self, added: ClassAdded) -> None:
        if self.logger is not None:
            self.logger.add_scalar("incremental/sampled_for_class", added.sampled, added.classes)
            self.logger.add_scalar("incremental/stages_for_class", added.stages, added.classes)

    def _log_cycle(self, step: int, cycle: Cycle) -> None:
        if self.logger is not None:
            for key in ("mistakes", "expert", "discarded", "features"):
                self.logger.add_scalar(f"train/{key}_per_cycle", getattr(cycle, key), step)
            self.logger.add_scalar("train/ksd_min", cycle.ksd_min, step)

    def _log_stage(self, entry: StageEntry) -> None:
        """Per stage, against the stage's running number in the fold (figures 5.1, 5.11)."""
        if self.logger is None:
            return
        step = entry.stage.step
        for key, value in entry.test.to_json().items():
            self.logger.add_scalar(f"test/{key}", value, step)
        for key, value in entry.features.to_json().items():
            self.logger.add_scalar(f"features/{key}", value, step)
        for key in ("t_ksd", "ksd_min", "cycles", "target_met", "train_learned", "classes"):
            self.logger.add_scalar(f"stage/{key}", float(getattr(entry.stage, key)), step)


def image_set(task: Task, indices: list[int], space: FeatureSpace, progress: bool, copies: int = 0,
               seed: int = 0, fold: int = 0, records: ImageRecords | None = None) -> ImageSet:
    """Views ``indices`` of the task, followed by ``copies`` augmented copies of each (training.data.augment);
    ``records``: the views' records where they were computed before (without copies only)."""
    # with copies the views are loaded here once, for the copies and the set alike
    images = [task.view(i) if copies else task.images[i] for i in indices]
    labels, names = [{task.labels[i]} for i in indices], [task.names[i] for i in indices]
    extra, extra_labels = augment(images, labels, copies, seed, fold)
    names += [f"{name}~{n + 1}" for n in range(copies) for name in names]
    return ImageSet(images + extra, labels + extra_labels, space, names=names, progress=progress,
                    records=None if copies else records)
