"""The recognition protocol of 4.5 in training stages (alg. 5.3): train, test after each stage, checkpoint.

A stage presents the training images one by one in a fresh random permutation each cycle
until a cycle has no mistake or ``max_cycles`` (20 in alg. 5.3) cycles have passed. At the end
of every cycle, features not consulted during it are discarded. Stage s learns with the KSD
target t(s): t(0) = 0 (chapter 4 learning), t(s+1) = 1 - (1 - min(KSD_min(s), t(s))) / 2, set
to 1 above 0.98 (DESIGN.md), where KSD_min(s) is the smallest KSD_{c,d} of alg. 5.2 met in
the stage's final cycle (1 when no recognition left a class uncertain). A stage meets its
target when the training set was learned and KSD_min(s) >= t(s). ``stages=None`` ("auto")
runs until a stage at t = 1 is done or two stages in a row miss their target (at most
``AUTO_LIMIT`` stages). Example images for alg. 4.8 come from the training set.

An incremental fold (alg. 5.4) teaches the classes in their listed order: it starts with the
training images of the first two, runs alg. 5.3 to its end (at most ``INCREMENTAL_LIMIT`` expert
stages), adds the next class's images and runs alg. 5.3 again from t = 0, keeping the learner.
After each stage it tests on the test images of the classes taught so far.

After a cycle the fold's state (learner, permutation generator, value cache, stages so far) is
written to its checkpoint, so an interrupted fold resumes to exactly the result it would have
reached: after every cycle (``checkpoint_every`` 0), or once at least that many seconds have
passed since the last write. A write costs time that grows with every feature ever measured
(the value cache and the instance list are compressed anew), a few seconds per cycle at 20 COIL
classes in 128x128, so long runs write every minute and lose at most that on interruption.
"""
from __future__ import annotations

import math
import time
from collections import Counter
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm

from ftorch.checkpoint import decode_array, encode_array, load_checkpoint, save_checkpoint
from ftorch.recognition.environment import ImageSet
from ftorch.errors import InputError
from ftorch.space.features import unpack_features
from ftorch.recognition.learner import GENERATOR_STATE, OPTIONS, DistinctiveFeatureLearner
from ftorch.recognition.inference import Recognition, accuracy, outcome

OUTCOMES = ("correct", "wrong", "ambiguous", "confused", "ignorant")
FOLD_KIND = "fold"
MISTAKES = ("reestimated", "learned", "failed")  # presentations whose first recognition was not correct
AUTO_LIMIT = 12
INCREMENTAL_LIMIT = 10  # expert stages per added class (alg. 5.4 step 2)


def next_target(t: float, ksd_min: float) -> float:
    """Alg. 5.3 step 3 as DESIGN.md reads it."""
    t = 1 - (1 - min(ksd_min, t)) / 2
    return 1.0 if t > 0.98 else t


def test_block(recognitions: list[Recognition], labels: list[frozenset], classes: list) -> dict:
    """Accuracy (def. 4.6) and the proportions of the five outcomes (def. 4.5) over a test set."""
    outcomes = Counter(outcome(r.recognized, t) for r, t in zip(recognitions, labels))
    n = max(len(recognitions), 1)
    block = {"accuracy": float(np.mean([accuracy(r.recognized, t, len(classes)) for r, t in zip(recognitions, labels)]))}
    block.update({k: outcomes[k] / n for k in OUTCOMES})
    return block


def confusion(recognitions: list[Recognition], labels: list[frozenset], classes: list, networks: dict) -> dict:
    """Tables 4.3 and 4.4 for single-class images: per true class, recognized-as counts for correct
    and wrong results, the ambiguous / confused / ignorant counts, the network size, and the
    false-positive classes of ambiguous results."""
    rows = {c: {"as": dict.fromkeys(classes, 0), "ambiguous": 0, "confused": 0, "ignorant": 0,
                "features": len(networks[c].features) if c in networks else 0,
                "ambiguous_with": dict.fromkeys(classes, 0)} for c in classes}
    for rec, true in zip(recognitions, labels):
        if len(true) != 1:
            continue
        (c,) = true
        kind = outcome(rec.recognized, true)
        if kind in ("correct", "wrong"):
            for r in rec.recognized:
                rows[c]["as"][r] += 1
        else:
            rows[c][kind] += 1
        if kind == "ambiguous":
            for r in rec.recognized - true:
                rows[c]["ambiguous_with"][r] += 1
    return rows


def feature_block(learner: DistinctiveFeatureLearner, recognitions: list[Recognition]) -> dict:
    """Table 4.2's feature columns: nodes in all networks, different features, mean queried, sampled."""
    nodes = [f for net in learner.networks.values() for f in net.features]
    return {"bn": len(nodes), "different": len(set(nodes)),
            "queried": float(np.mean([len(r.queried) for r in recognitions])) if recognitions else 0.0,
            "sampled": learner.sampled}


@dataclass(frozen=True)
class RunConfig:
    """A run's settings, as its report and every fold checkpoint record them (a fold resumes only
    under the same). The learner's settings default to the library's (the thesis's); the
    runner gives every field."""

    task: str
    data: str | None = None
    classes: list = field(default_factory=list)
    views: int = 20
    first_view: int = 0
    size: int | None = None
    seed: int = 0
    n_ex: int = 5
    n_fgen: int = 10
    min_information: float = 0.0
    search_rounds: int = 1
    redundancy: int = 1
    evidence: str = "both"
    pseudocount: float = 0.0
    leak: float = 0.0
    cut_position: float = 0.5
    test_information: float = 0.0
    primitives: str = "texel,edgel"
    calibrate: bool = False
    device: str = "cpu"
    stages: str = "0"
    max_cycles: int = 20
    augment: int = 0
    dynamic: bool = False
    incremental: bool = False

    def to_dict(self) -> dict:
        return asdict(self)

    def fold_seed(self, fold: int) -> int:
        """Fold k of a run with seed S seeds its learner and its presentation order with 1000 S + k."""
        return self.seed * 1000 + fold

    def learner(self, fold: int) -> DistinctiveFeatureLearner:
        """A fresh learner for fold ``fold`` with these settings."""
        return DistinctiveFeatureLearner(self.n_ex, self.n_fgen, seed=self.fold_seed(fold),
                                         min_information=self.min_information, **{k: getattr(self, k) for k in OPTIONS})


@dataclass
class FoldState:
    """A fold's progress, which its checkpoint stores beside the learner: the incremental phase
    (classes taught = phase + 2), the stage within it and its t_KSD, the current stage's cycles,
    the finished stages' report entries, targets missed in a row, whether the fold is done, the
    cycles and seconds so far, and figure 5.13's entries per added class with the features
    sampled before the current class."""

    phase: int = 0
    stage: int = 0
    t_ksd: float = 0.0
    cycles: list = field(default_factory=list)
    stages: list = field(default_factory=list)
    misses: int = 0
    done: bool = False
    total_cycles: int = 0
    seconds: float = 0.0
    added: list = field(default_factory=list)
    sampled_before: int = 0

    def to_dict(self) -> dict:
        return asdict(self)

    @classmethod
    def from_dict(cls, state: dict) -> "FoldState":
        """The progress read from a checkpoint; ValueError where a field is missing or has the wrong type or range."""
        names = [f.name for f in fields(cls)]
        if not isinstance(state, dict) or sorted(state) != sorted(names):
            raise ValueError(f"progress fields {sorted(state) if isinstance(state, dict) else state!r}, expected {names}")
        counts = ("phase", "stage", "misses", "total_cycles", "sampled_before")
        if any(isinstance(state[k], bool) or not isinstance(state[k], int) or state[k] < 0 for k in counts):
            raise ValueError(f"progress counts {[state[k] for k in counts]} must be integers >= 0")
        if not (isinstance(state["t_ksd"], (int, float)) and 0.0 <= state["t_ksd"] <= 1.0):
            raise ValueError(f"t_KSD {state['t_ksd']!r} outside [0, 1]")
        if not (isinstance(state["seconds"], (int, float)) and 0.0 <= state["seconds"] < math.inf):
            raise ValueError(f"seconds {state['seconds']!r} is not a duration")
        if not isinstance(state["done"], bool) or not all(isinstance(state[k], list) for k in ("cycles", "stages", "added")):
            raise ValueError("done must be true or false, and cycles, stages and added lists")
        return cls(**state)


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

    def taught(self, phase: int) -> list:
        """The classes trained on in ``phase``: all of them, or the first phase + 2 (alg. 5.4)."""
        return self.classes[:phase + 2] if self.incremental else self.classes

    @property
    def phases(self) -> int:
        return len(self.classes) - 1 if self.incremental else 1

    def _indices(self, images: ImageSet, phase: int) -> list[int]:
        taught = set(self.taught(phase))
        return [i for i, labels in enumerate(images.labels) if labels <= taught]

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
            "features": table.pack(), "learner": learned, "cache": cache})

    def _resume(self):
        data = load_checkpoint(self.checkpoint, FOLD_KIND)
        stored = data.get("config")
        if isinstance(stored, dict):  # a run written before these options existed ran with their defaults
            stored = {**{k: getattr(RunConfig, k) for k in ("leak", "primitives", "calibrate", "dynamic")}, **stored}
        if stored != self.config.to_dict() or data.get("fold") != self.fold:
            raise InputError(f"{self.checkpoint}: written by a different run configuration; "
                             f"use another --out or delete it to start afresh")
        learner = DistinctiveFeatureLearner()
        order = torch.Generator()
        try:
            features = unpack_features(data["features"])
            self.train.load_cache_state(data["cache"], features)  # first: the learner's instance values refer to it
            learner.load_state_dict(data["learner"], features, env=self.train)
            order.set_state(torch.from_numpy(decode_array(data["order"], shape=GENERATOR_STATE).astype(np.uint8)))
            state = FoldState.from_dict(data["state"])
        except (KeyError, TypeError, ValueError, IndexError, RuntimeError, OverflowError, AttributeError) as err:
            raise InputError(f"{self.checkpoint}: damaged fold checkpoint ({type(err).__name__}: {err})") from None
        return learner, order, state

    def run(self, max_cycles: int = 20, stages: int | None = 0, resume: bool = False, after_cycle=None,
            checkpoint_every: float = 0.0, before_cycle=None) -> tuple[dict, DistinctiveFeatureLearner]:
        """Train stages 0..``stages`` (None: auto; per added class in an incremental fold, at most
        ``INCREMENTAL_LIMIT`` expert stages) and test after each; returns the fold's report entry
        and the learner (also saved as learner.json). The checkpoint is written after a cycle or
        stage once ``checkpoint_every`` seconds have passed since the last write (0: every time), and
        at the end; ``after_cycle(n)`` is called after a write that holds the n-th cycle, and
        ``before_cycle()`` before each cycle (the runner's workers take idle cores there)."""
        if resume and self.checkpoint.is_file():
            learner, order, state = self._resume()
            self.finished_before = state.done
        else:
            learner = self.config.learner(self.fold)
            order = torch.Generator().manual_seed(self.config.fold_seed(self.fold))
            state = FoldState()
        start = time.perf_counter() - state.seconds
        written = time.perf_counter()
        limit = AUTO_LIMIT if stages is None else stages + 1
        if self.incremental:
            limit = min(limit, INCREMENTAL_LIMIT + 1)
        with tqdm(desc=f"fold {self.fold}", unit="cycle", disable=not self.progress, leave=False) as bar:
            while not state.done:
                cycles = state.cycles
                if cycles and (cycles[-1]["mistakes"] == 0 or len(cycles) >= max_cycles):
                    self._finish_stage(learner, state, start, stages, limit)
                else:
                    if before_cycle is not None:
                        before_cycle()
                    cycles.append(self._cycle(learner, order, state.t_ksd, self._indices(self.train, state.phase)))
                    state.total_cycles += 1
                    bar.update(1)
                    bar.set_postfix(stage=state.stage, t_ksd=state.t_ksd, mistakes=cycles[-1]["mistakes"],
                                    features=cycles[-1]["features"])
                    self._log_cycle(state.total_cycles, cycles[-1])
                if not state.done and time.perf_counter() - written < checkpoint_every:
                    continue
                state.seconds = time.perf_counter() - start
                self._save(learner, order, state)
                written = time.perf_counter()
                if after_cycle is not None and not state.done and len(state.cycles):
                    after_cycle(state.total_cycles)
        learner.save(self.folder / "learner.json")
        entry = {"fold": self.fold, "stages": state.stages}
        if self.incremental:
            entry["added"] = state.added
        return entry, learner

    def _cycle(self, learner: DistinctiveFeatureLearner, order: torch.Generator, t_ksd: float, indices: list[int]) -> dict:
        """One pass over the training images ``indices`` in a fresh order, then discarding (alg. 5.3 step 2).

        Dynamic training views (``config.dynamic``): the training set is the original views followed
        by ``config.augment`` copies of each (training.data.augment); a cycle presents every original
        view once, each time as a version drawn uniformly from the view and its copies, so no copy
        has to be learned for its own sake. Mistakes are then judged on the originals: after the
        cycle, each is recognized as in learning (nothing is learned), and a stage ends when all are right."""
        begin = learner.presentations
        results, ksd_min = [], 1.0
        versions = self.config.augment + 1 if self.config.dynamic else 1
        views = len(self.train) // versions
        shown = [i for i in indices if i < views]
        for k in torch.randperm(len(shown), generator=order).tolist():
            i = shown[k]
            if versions > 1:
                i += views * int(torch.randint(versions, (), generator=order))
            p = learner.learn(self.train, i, t_ksd)
            results.append(p.result)
            if p.ksd is not None:
                ksd_min = min(ksd_min, p.ksd)
        discarded = learner.discard_unused(since=begin + 1)
        if versions > 1:
            judged = learner.recognize_many(self.train, shown, learner.min_information)
            mistakes = sum(outcome(r.recognized, self.train.labels[i]) != "correct" for r, i in zip(judged, shown))
        else:
            mistakes = sum(r in MISTAKES for r in results)
        return {"mistakes": mistakes, "expert": results.count("expert"),
                "ksd_min": ksd_min, "discarded": len(discarded),
                "features": sum(len(n.features) for n in learner.networks.values())}

    def _finish_stage(self, learner, state: FoldState, start: float, stages: int | None, limit: int) -> None:
        cycles, t, taught = state.cycles, state.t_ksd, self.taught(state.phase)
        learned = cycles[-1]["mistakes"] == 0
        ksd_min = cycles[-1]["ksd_min"]
        met = learned and ksd_min >= t
        tested = self._indices(self.test, state.phase)
        recognitions = learner.recognize_many(self.test, tested)
        labels = [self.test.labels[i] for i in tested]
        stage = {"stage": state.stage, "step": len(state.stages), "classes": len(taught), "t_ksd": t,
                 "cycles": len(cycles), "presentations": learner.presentations,
                 "train_learned": learned, "ksd_min": ksd_min, "target_met": met,
                 "mistakes_per_cycle": [c["mistakes"] for c in cycles],
                 "expert_per_cycle": [c["expert"] for c in cycles],
                 "discarded_per_cycle": [c["discarded"] for c in cycles],
                 "test": test_block(recognitions, labels, taught),
                 "features": feature_block(learner, recognitions),
                 "confusion": confusion(recognitions, labels, taught, learner.networks),
                 "seconds": time.perf_counter() - start}
        state.stages.append(stage)
        self._log_stage(stage)
        state.misses = 0 if met else state.misses + 1
        in_phase = state.stage + 1
        phase_done = (stages is None and (t >= 1.0 or state.misses >= 2)) or in_phase >= limit
        state.stage += 1
        state.t_ksd = next_target(t, ksd_min)
        state.cycles = []
        if phase_done and self.incremental:
            self._class_added(learner, state)
        if phase_done and state.phase + 1 < self.phases:
            state.phase, state.stage, state.t_ksd, state.misses = state.phase + 1, 0, 0.0, 0
        else:
            state.done = phase_done

    def _class_added(self, learner, state: FoldState) -> None:
        """Figure 5.13: features sampled and stages taken to learn the newest class (both first classes at phase 0)."""
        taught = self.taught(state.phase)
        entry = {"classes": len(taught), "class": taught[-1], "sampled": learner.sampled - state.sampled_before,
                 "stages": state.stage}
        state.added.append(entry)
        state.sampled_before = learner.sampled
        if self.logger is not None:
            self.logger.add_scalar("incremental/sampled_for_class", entry["sampled"], entry["classes"])
            self.logger.add_scalar("incremental/stages_for_class", entry["stages"], entry["classes"])

    def _log_cycle(self, step: int, cycle: dict) -> None:
        if self.logger is not None:
            for key in ("mistakes", "expert", "discarded", "features", "ksd_min"):
                self.logger.add_scalar(f"train/{key}_per_cycle" if key != "ksd_min" else "train/ksd_min", cycle[key], step)

    def _log_stage(self, stage: dict) -> None:
        """Per stage, against the stage's running number in the fold (figures 5.1, 5.11)."""
        if self.logger is None:
            return
        step = stage["step"]
        for key, value in stage["test"].items():
            self.logger.add_scalar(f"test/{key}", value, step)
        for key, value in stage["features"].items():
            self.logger.add_scalar(f"features/{key}", value, step)
        for key in ("t_ksd", "ksd_min", "cycles", "target_met", "train_learned", "classes"):
            self.logger.add_scalar(f"stage/{key}", float(stage[key]), step)
