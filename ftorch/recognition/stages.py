"""Training stages (alg. 5.3) and incremental tasks (alg. 5.4): the cycles of presentations
around the learner, as :meth:`DistinctiveFeatureLearner.fit` and the runner's folds run them.

A stage presents the training images one by one in a fresh random permutation each cycle until
a cycle has no mistake or ``max_cycles`` (20 in alg. 5.3) cycles have passed. At the end of
every cycle, features not consulted during it are discarded. Stage s learns with the KSD target
t(s): t(0) = 0 (chapter 4 learning), t(s+1) = 1 - (1 - min(KSD_min(s), t(s))) / 2, set to 1
above 0.98 (DESIGN.md), where KSD_min(s) is the smallest KSD_{c,d} of alg. 5.2 met in the
stage's final cycle (1 when no recognition left a class uncertain). A stage meets its target
when the training set was learned and KSD_min(s) >= t(s). ``stages=None`` ("auto") runs until a
stage at t = 1 is done or two stages in a row miss their target (at most ``AUTO_LIMIT`` stages).
Example images for alg. 4.8 come from the training set.

An incremental task (alg. 5.4) teaches the classes in their listed order: it starts with the
training images of the first two, runs alg. 5.3 to its end (at most ``INCREMENTAL_LIMIT`` expert
stages), adds the next class's images and runs alg. 5.3 again from t = 0, keeping the learner.

Dynamic training views (``versions`` > 1): the image set is the original views followed by
``versions - 1`` copies of each, in the same order; a cycle presents every original once, each
time as a version drawn uniformly from the view and its copies, so no copy has to be learned for
its own sake. Mistakes are then judged on the originals: after the cycle each is recognized as
in learning (nothing is learned), and a stage ends when all are right.

:class:`Schedule` holds the loop's whole state (:class:`Progress`) and advances it one step at a
time, a cycle or the end of a stage, so that a caller can test, log and checkpoint between steps
and resume exactly.
"""
from __future__ import annotations

from collections import Counter
from collections.abc import Hashable, Iterable
from dataclasses import dataclass, field, fields

import torch

from ..errors import InputError
from .environment import ImageSet
from .inference import Outcome, Result, outcome
from .learning import Learning
from .settings import integer_in

AUTO_LIMIT = 12  # stages of an "auto" schedule at most
INCREMENTAL_LIMIT = 10  # expert stages per added class (alg. 5.4 step 2)
MAX_CYCLES = 20  # cycles before a stage gives up (alg. 5.3)
# the most a schedule may be asked for (fit's and the runner's bound alike): far above any sensible
# run, so that a typo cannot start one that never ends
STAGES_LIMIT = 100
CYCLES_LIMIT = 1000


REPEATED = 2  # failed searches on one image for one pair of classes in a stage that a stage names (FailedSearch)


def next_target(t: float, ksd_min: float) -> float:
    """Alg. 5.3 step 3 as DESIGN.md reads it."""
    t = 1 - (1 - min(ksd_min, t)) / 2
    return 1.0 if t > 0.98 else t


@dataclass(frozen=True)
class FailedSearch:
    """Searches (alg. 4.8, 5.1) that found no feature: on training image ``image`` (its index in the
    image set, and its ``name`` there), characterizing ``label`` against ``against``, ``searches`` times."""

    image: int
    name: str
    label: Hashable
    against: tuple
    searches: int = 1

    def to_dict(self) -> dict:
        return {"image": self.image, "name": self.name, "class": self.label, "against": list(self.against),
                "searches": self.searches}

    @classmethod
    def from_dict(cls, entry: dict) -> "FailedSearch":
        return cls(entry["image"], entry["name"], entry["class"], tuple(entry["against"]), entry["searches"])


def repeated(failures: Iterable[FailedSearch]) -> tuple[FailedSearch, ...]:
    """The (image, class, against) that ``failures`` hold ``REPEATED`` times or more, with their
    counts, most first (then by image): the training images the search fails on again and again."""
    counts = Counter((f.image, f.name, f.label, f.against) for f in failures for _ in range(f.searches))
    found = [FailedSearch(*key, n) for key, n in counts.items() if n >= REPEATED]
    return tuple(sorted(found, key=lambda f: (-f.searches, f.image, str(f.label), tuple(map(str, f.against)))))


@dataclass(frozen=True)
class Cycle:
    """One cycle: training images wrong at their first recognition (with dynamic views: originals
    wrong after the cycle), presentations that added an expert feature, the smallest KSD_{c,d} met
    (alg. 5.2; 1 when none), features discarded after it (alg. 5.3 step 4), the nodes left, and the
    searches that failed in it."""

    mistakes: int
    expert: int
    ksd_min: float
    discarded: int
    features: int
    failed: tuple[FailedSearch, ...] = ()

    def to_dict(self) -> dict:
        return {**{f.name: getattr(self, f.name) for f in fields(self)[:-1]},
                "failed": [f.to_dict() for f in self.failed]}

    @classmethod
    def from_dict(cls, entry: dict) -> "Cycle":
        """A cycle of a checkpoint (one written before failed searches were recorded has none)."""
        return cls(**{f.name: entry[f.name] for f in fields(cls)[:-1]},
                   failed=tuple(FailedSearch.from_dict(f) for f in entry.get("failed", [])))


@dataclass(frozen=True)
class Stage:
    """One finished stage (alg. 5.3): its number within the current class's schedule and overall
    (``step``), the classes taught, its t_KSD, cycles, presentations so far, whether the training set
    was learned, KSD_min(s), whether the target was met, the per-cycle counts (figure 5.1), and the
    searches that failed on one image ``REPEATED`` times or more (:func:`repeated`; None in a stage
    read from a file written before they were recorded, which is written back without them)."""

    stage: int
    step: int
    classes: int
    t_ksd: float
    cycles: int
    presentations: int
    train_learned: bool
    ksd_min: float
    target_met: bool
    mistakes_per_cycle: list[int]
    expert_per_cycle: list[int]
    discarded_per_cycle: list[int]
    failing: tuple[FailedSearch, ...] | None = ()

    def to_dict(self) -> dict:
        out = {f.name: getattr(self, f.name) for f in fields(self)[:-1]}
        return out if self.failing is None else {**out, "failing": [f.to_dict() for f in self.failing]}

    @classmethod
    def from_dict(cls, entry: dict) -> "Stage":
        """The stage fields of a report entry (which may hold more; one written before failed
        searches were recorded has none: None)."""
        failing = entry.get("failing")
        return cls(**{f.name: entry[f.name] for f in fields(cls)[:-1]},
                   failing=None if failing is None else tuple(FailedSearch.from_dict(f) for f in failing))


@dataclass(frozen=True)
class ClassAdded:
    """Figure 5.13: the features sampled and the stages taken to learn the newest class of an
    incremental task (both first classes at its start)."""

    classes: int
    label: Hashable
    sampled: int
    stages: int

    def to_dict(self) -> dict:
        return {"classes": self.classes, "class": self.label, "sampled": self.sampled, "stages": self.stages}

    @classmethod
    def from_dict(cls, entry: dict) -> "ClassAdded":
        return cls(entry["classes"], entry["class"], entry["sampled"], entry["stages"])


@dataclass
class Progress:
    """Where a schedule stands: the incremental phase (classes taught = phase + 2), the stage within
    it and its t_KSD, the current stage's cycles, the finished stages, targets missed in a row,
    whether it is done, the cycles so far, the classes added, and the features sampled before the
    current class."""

    phase: int = 0
    stage: int = 0
    t_ksd: float = 0.0
    cycles: list[Cycle] = field(default_factory=list)
    stages: list[Stage] = field(default_factory=list)
    misses: int = 0
    done: bool = False
    total_cycles: int = 0
    added: list[ClassAdded] = field(default_factory=list)
    sampled_before: int = 0


def taught_order(classes, known: list) -> list:
    """``classes``, the order in which an incremental task teaches them: each class of the images
    once; InputError for another class, a repeated one or one left out."""
    if isinstance(classes, (str, bytes)) or not isinstance(classes, Iterable):
        raise InputError(f"classes {classes!r}: expected a list of the images' classes")
    classes = list(classes)
    try:
        repeated = [c for c, n in Counter(classes).items() if n > 1]
    except TypeError as err:
        raise InputError(f"classes: {err}") from None
    listed, knowns = set(classes), set(known)
    unknown = [c for c in classes if c not in knowns]
    missing = [c for c in known if c not in listed]
    for problem, found in (("not a class of the images", unknown), ("listed twice", repeated), ("left out", missing)):
        if found:
            raise InputError(f"classes: {found[0]!r} is {problem}; list each of the images' {len(known)} classes "
                             f"once ({', '.join(map(repr, known[:6]))}{', ...' if len(known) > 6 else ''})")
    return classes


class Schedule:
    """Alg. 5.3 for ``learner`` on the training images of ``env`` (alg. 5.4 with ``incremental``,
    teaching ``classes`` in their order), presentations ordered by the generator ``order``;
    ``stages``: expert stages after stage 0, or None for auto (module docstring). ``progress``: where
    an earlier schedule stopped, to go on from there."""

    def __init__(self, learner: Learning, env: ImageSet, order: torch.Generator, stages: int | None = None,
                 max_cycles: int = MAX_CYCLES, classes: list | None = None, incremental: bool = False,
                 versions: int = 1, progress: Progress | None = None):
        self.learner, self.env, self.order = learner, env, order
        self.stages = None if stages is None else integer_in("stages", stages, 0, STAGES_LIMIT)
        self.max_cycles = integer_in("max_cycles", max_cycles, 1, CYCLES_LIMIT)
        self.incremental, self.versions = incremental, versions
        self.classes = env.classes() if classes is None else taught_order(classes, env.classes())
        self.progress = Progress() if progress is None else progress
        limit = AUTO_LIMIT if self.stages is None else self.stages + 1
        self.limit = min(limit, INCREMENTAL_LIMIT + 1) if incremental else limit

    def taught(self, phase: int | None = None) -> list:
        """The classes trained on in ``phase`` (default: the current one): all, or the first phase + 2 (alg. 5.4)."""
        phase = self.progress.phase if phase is None else phase
        return self.classes[:phase + 2] if self.incremental else self.classes

    @property
    def phases(self) -> int:
        return len(self.classes) - 1 if self.incremental else 1

    def indices(self, images: ImageSet, phase: int | None = None) -> list[int]:
        """The images of ``images`` whose classes have all been taught in ``phase``."""
        taught = set(self.taught(phase))
        return [i for i, labels in enumerate(images.labels) if labels <= taught]

    @property
    def stage_over(self) -> bool:
        cycles = self.progress.cycles
        return bool(cycles) and (cycles[-1].mistakes == 0 or len(cycles) >= self.max_cycles)

    def step(self) -> Cycle | Stage:
        """One cycle, or the end of the current stage once its last cycle had no mistake or the
        cycle limit is reached."""
        state = self.progress
        if self.stage_over:
            return self._finish_stage()
        cycle = self._cycle(self.indices(self.env))
        state.cycles.append(cycle)
        state.total_cycles += 1
        return cycle

    def run(self) -> list[Stage]:
        """Steps until done; the finished stages."""
        while not self.progress.done:
            self.step()
        return self.progress.stages

    def _cycle(self, indices: list[int]) -> Cycle:
        """One pass over the training images ``indices`` in a fresh order, then discarding (alg. 5.3 step 2)."""
        learner, env, order, versions = self.learner, self.env, self.order, self.versions
        begin = learner.presentations
        results, failed, ksd_min = [], [], 1.0
        views = len(env) // versions
        shown = [i for i in indices if i < views]
        presented = []
        for k in torch.randperm(len(shown), generator=order).tolist():
            i = shown[k]
            if versions > 1:
                i += views * int(torch.randint(versions, (), generator=order))
            presented.append(i)
        for i, p in zip(presented, learner.present(env, presented, self.progress.t_ksd)):
            results.append(p.result)
            if p.result in (Result.FAILED, Result.EXPERT_FAILED) and p.searched is not None:
                label, against = p.searched
                failed.append(FailedSearch(i, env.names[i], label, tuple(sorted(against, key=str))))
            if p.ksd is not None:
                ksd_min = min(ksd_min, p.ksd)
        discarded = learner.discard_unused(since=begin + 1)
        if versions > 1:
            judged = learner.recognitions(env, shown, learner.settings.min_information)  # learning's: no top label
            mistakes = sum(outcome(r.recognized, env.labels[i]) is not Outcome.CORRECT for r, i in zip(judged, shown))
        else:
            mistakes = sum(r.mistake for r in results)
        return Cycle(mistakes, sum(r is Result.EXPERT for r in results), ksd_min, len(discarded),
                     sum(len(n.features) for n in learner.networks.values()), tuple(failed))

    def _finish_stage(self) -> Stage:
        state, learner = self.progress, self.learner
        cycles, t = state.cycles, state.t_ksd
        learned = cycles[-1].mistakes == 0
        ksd_min = cycles[-1].ksd_min
        met = learned and ksd_min >= t
        stage = Stage(state.stage, len(state.stages), len(self.taught()), t, len(cycles), learner.presentations,
                      learned, ksd_min, met, [c.mistakes for c in cycles], [c.expert for c in cycles],
                      [c.discarded for c in cycles], repeated(f for c in cycles for f in c.failed))
        state.stages.append(stage)
        state.misses = 0 if met else state.misses + 1
        phase_done = (self.stages is None and (t >= 1.0 or state.misses >= 2)) or state.stage + 1 >= self.limit
        state.stage += 1
        state.t_ksd = next_target(t, ksd_min)
        state.cycles = []
        if phase_done and self.incremental:
            taught = self.taught()
            state.added.append(ClassAdded(len(taught), taught[-1], learner.sampled - state.sampled_before, state.stage))
            state.sampled_before = learner.sampled
        if phase_done and state.phase + 1 < self.phases:
            state.phase, state.stage, state.t_ksd, state.misses = state.phase + 1, 0, 0.0, 0
        else:
            state.done = phase_done
        return stage
