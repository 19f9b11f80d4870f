"""The experiments of 6.5: simulated grasp data, two-fold cross-validation, off-line and on-line learning.

Data: for each category (object kind, finger count) ``pool`` trials, trial j of a category with
its own object, overhead image and haptic-only grasp from a uniformly random azimuth (the purely
haptic system). Fold k (1, 2) tests on the half with j % 2 == k - 1 and trains on the other half.

Experiments (the categories and how training grasps are chosen from a fold's training half):
- clean (figure 6.13a) and cue (figure 6.14): the ``best`` lowest-mu_0 two-finger grasps of
  squares and three-finger grasps of triangles;
- noisy (figure 6.13b): ``best`` representative (unselected) grasps of each of the four
  categories;
- mixed (figure 6.17): the ``best`` lowest-mu_0 grasps of each of the four categories.

Off-line training presents the chosen grasps in a seeded random order for up to ``epochs``
passes (fewer where a pass makes no mistake); the learner's step 5 is simulated by comparing
its theta_h with the recorded theta_H modulo the grasp's symmetry (6.5.1). On-line training
(``--online``, beyond the thesis) grasps the same objects itself: the haptic controller starts
from the recommended orientation and finger count (a random azimuth and the category's fingers
where there is no recommendation; in ``mixed`` a finger count whose set has no present feature
is tried first, see :meth:`GraspFold._explore`), and learns from what it did.

Tests on the held-out half: orientation errors of the recommendations for the test grasps chosen
as for training (figure 6.13); and every held-out object of the experiment's categories grasped
again from the recommendation (cued) against its recorded haptic-only grasp: probes and mu_0
(figures 6.14, 6.17). The finger count is the category's, except in ``mixed``, where the learned
models choose it (alg. 6.2 step 2b). A grasp is poor where mu_0 > ``POOR_MU0``, the split
between the two modes of figure 6.17.

A fold's state after an epoch (:meth:`GraspFold.state_dict`: the learner's training state with its
generator, the presentation order's generator, the epoch log and what the learner predicted
before each training grasp) restores a fold that trains on exactly as the uninterrupted one: the
pool, the fold's images and their records are recomputed from the seed as before, bit for bit, the
instance lists' values are stored exactly (ftorch.checkpoint), and every other random draw
(regrasps) is a function of the seed and the trial alone.
"""
from __future__ import annotations

import math
from collections import Counter
from dataclasses import dataclass

import numpy as np
import torch
from tqdm import tqdm

from ftorch import FeatureSpace
from ftorch.checkpoint import decode_array, encode_array
from ftorch.grasp.feature_set import Experience
from ftorch.grasp.learner import GraspLearner, Learned
from ftorch.grasp.models import angular_error
from ftorch.grasp.settings import MU0_CAP, POOR_MU0
from ftorch.grasp.state import GENERATOR_STATE
from ftorch.space.record import ImageRecords

from .camera import render
from .haptics import GraspOutcome, HapticController, symmetry_period
from .objects import KINDS, GraspObject, random_object
from .records import Epoch, FoldState, FoldTests, Grasp, Predictions

EXPERIMENTS = ("clean", "noisy", "cue", "mixed")
ALL_CATEGORIES = (("square", 2), ("triangle", 3), ("square", 3), ("triangle", 2))


def categories(experiment: str) -> tuple[tuple[str, int], ...]:
    return ALL_CATEGORIES[:2] if experiment in ("clean", "cue") else ALL_CATEGORIES


@dataclass
class Trial:
    kind: str
    fingers: int
    index: int
    obj: GraspObject
    image: np.ndarray
    outcome: GraspOutcome

    @property
    def key(self) -> tuple:
        return self.kind, self.fingers, self.index

    @property
    def period(self) -> float:
        return symmetry_period(self.obj.symmetry)

    def experience(self, outcome: GraspOutcome | None = None) -> Experience:
        outcome = outcome or self.outcome
        return Experience(outcome.fingers, outcome.theta_H, outcome.mu0, self.period)


def _rng(seed: int, *path: int) -> np.random.Generator:
    return np.random.default_rng([seed, *path])


def simulate(kind: str, fingers: int, index: int, seed: int, size: int, controller: HapticController) -> Trial:
    """Trial ``index`` of a category: object, image and a haptic-only grasp, all from (seed, category, index)."""
    rng = _rng(seed, KINDS.index(kind), fingers, index)
    obj = random_object(kind, rng)
    image = render(obj, size, rng)
    return Trial(kind, fingers, index, obj, image, controller.grasp(obj, fingers, rng.uniform(0, 2 * math.pi), rng))


def regrasp(trial: Trial, fingers: int, theta_h: float | None, seed: int, purpose: int,
            controller: HapticController) -> GraspOutcome:
    """The trial's object grasped again (cued at theta_h, or from a random azimuth where None)."""
    rng = _rng(seed, KINDS.index(trial.kind), trial.fingers, trial.index, 1000 + purpose)
    start = rng.uniform(0, 2 * math.pi) if theta_h is None else theta_h
    return controller.grasp(trial.obj, fingers, start, rng)


def choose(trials: list[Trial], experiment: str, best: int) -> list[Trial]:
    """The ``best`` grasps of one category's half: lowest mu_0 (clean, cue, mixed) or the first ones (noisy)."""
    if experiment == "noisy":
        return trials[:best]
    return sorted(trials, key=lambda t: (t.outcome.mu0, t.index))[:best]


class GraspFold:
    """One fold: training (off-line or on-line) and tests, with per-epoch logs: ``epochs`` (the report's)
    and ``predictions`` (TensorBoard's: per epoch, what the learner predicted before each grasp's outcome)."""

    def __init__(self, k: int, experiment: str, pool: dict, best: int, space: FeatureSpace, learner: GraspLearner,
                 controller: HapticController, seed: int, progress: bool = False):
        self.k, self.experiment = k, experiment
        self.learner, self.controller, self.seed, self.progress = learner, controller, seed, progress
        half = {c: [t for t in trials if t.index % 2 != k - 1] for c, trials in pool.items()}
        held = {c: [t for t in trials if t.index % 2 == k - 1] for c, trials in pool.items()}
        self.train = [t for c in categories(experiment) for t in choose(half[c], experiment, best)]
        self.test = [t for c in categories(experiment) for t in choose(held[c], experiment, best)]
        self.objects = [t for c in categories(experiment) for t in held[c]]
        trials = list({t.key: t for t in self.train + self.test + self.objects}.values())
        with torch.no_grad():
            self.batch = space.records([torch.from_numpy(t.image) for t in trials], progress=self.progress)
        self.position = {t.key: i for i, t in enumerate(trials)}
        self.records: dict[tuple, ImageRecords] = {t.key: self.batch[i] for i, t in enumerate(trials)}
        self.epochs: list[Epoch] = []
        self.predictions: list[Predictions] = []
        self.order = torch.Generator().manual_seed(seed * 1000 + k)  # the presentation order of each epoch

    def _fingers(self, trial: Trial) -> int | None:
        return None if self.experiment == "mixed" else trial.fingers

    def recommendation(self, trial: Trial):
        """The learner's cue for a trial's image: its category's fingers, or chosen in ``mixed``."""
        return self.learner.recommend(self.records[trial.key], self._fingers(trial))

    def _explore(self, trial: Trial) -> tuple[int, float | None]:
        """On-line: fingers and start azimuth for a training grasp. Where the finger count is free
        (mixed) and a set has no present feature, that count is tried from a random azimuth (the
        trial's own count first); otherwise the recommendation, or a random start without one."""
        untried = self.learner.untried(self.records[trial.key]) if self._fingers(trial) is None else []
        if untried:
            return (trial.fingers if trial.fingers in untried else untried[0]), None
        cue = self.recommendation(trial)
        return (cue.fingers, cue.theta_h) if cue is not None else (trial.fingers, None)

    def finished(self, epochs: int, online: bool = False) -> bool:
        """Whether training is over: ``epochs`` passes made, or (off-line) the last made no mistake."""
        return len(self.epochs) >= epochs or (not online and bool(self.epochs) and self.epochs[-1].mistakes == 0)

    def fit(self, epochs: int, online: bool = False, after_epoch=None) -> None:
        """Alg. 6.2 over the training grasps for up to ``epochs`` passes (off-line: the recorded grasps;
        on-line: grasps executed from the learner's recommendations), from the epochs made before (a
        restored fold goes on); ``after_epoch()`` is called after each."""
        bar = tqdm(total=epochs, initial=len(self.epochs), desc=f"fold {self.k} {'on' if online else 'off'}-line",
                   unit="epoch", disable=not self.progress)
        while not self.finished(epochs, online):
            epoch = len(self.epochs)
            counts: Counter[Learned] = Counter()
            mu0, predicted = [], Predictions()
            for i in torch.randperm(len(self.train), generator=self.order).tolist():
                trial = self.train[i]
                if online:
                    fingers, theta_h = self._explore(trial)
                    outcome = regrasp(trial, fingers, theta_h, self.seed, 10 + epoch, self.controller)
                    image = (*trial.key, epoch)
                else:
                    outcome, image = trial.outcome, trial.key
                experience = trial.experience(outcome)
                self._predicted(predicted, trial, experience)
                counts[self.learner.learn(image, self.records[trial.key], experience)] += 1
                mu0.append(outcome.mu0)
            self.predictions.append(predicted)
            two, three = self.learner.sets[2], self.learner.sets[3]
            mistakes = counts[Learned.REFIT] + counts[Learned.SAMPLED]
            self.epochs.append(Epoch(epoch, counts[Learned.CORRECT], counts[Learned.REFIT], counts[Learned.SAMPLED],
                                     mistakes / len(self.train), float(np.mean(np.array(mu0) > POOR_MU0)),
                                     len(two), len(three), two.sampled, three.sampled))
            bar.update(1)
            bar.set_postfix(mistakes=f"{self.epochs[-1].mistakes:.2f}")
            if after_epoch is not None:
                after_epoch()
        bar.close()

    def _predicted(self, predicted: Predictions, trial: Trial, experience: Experience) -> None:
        """What the learner predicts for a training grasp before learning its outcome (recommending is
        pure): the orientation error and E[mu_0] with the fingers grasped with, the measured mu_0 (None:
        no equilibrium; else capped at MU0_CAP, as the instance list holds it), and the fingers it would
        choose (None where it has no prediction). The set grasped with is measured once (learning reuses
        it); in ``mixed`` the finger choice measures the other set too, the one cost these logs add."""
        cue = self.learner.recommend(self.records[trial.key], experience.fingers)
        chosen = cue if self._fingers(trial) == experience.fingers else self.recommendation(trial)
        error = angular_error(cue.theta_h, experience.theta_H, experience.period) if cue is not None else None
        predicted.error_deg.append(None if cue is None else math.degrees(float(error)))
        predicted.expected_mu0.append(None if cue is None else cue.expected_mu0)
        predicted.measured_mu0.append(min(experience.mu0, MU0_CAP) if math.isfinite(experience.mu0) else None)
        predicted.fingers.append(None if chosen is None else chosen.fingers)

    def state_dict(self) -> dict:
        """JSON-ready: what training goes on from (module doc): the epoch log and predictions, the
        presentation order's generator and the learner's training state."""
        return FoldState(self.epochs, self.predictions, encode_array(self.order.get_state().numpy().astype(np.float64)),
                         self.learner.state_dict()).to_json()

    def load_state_dict(self, state: dict) -> None:
        """Restore :meth:`state_dict` into this fold, built as the saved one was; ValueError (or another
        of ``ftorch.checkpoint.DAMAGED``) for a damaged state."""
        stored = FoldState.from_json(state)
        if len(stored.epochs) != len(stored.predictions):
            raise ValueError("the epoch log and the predictions must be lists of one entry per epoch")
        if [e.epoch for e in stored.epochs] != list(range(len(stored.epochs))):
            raise ValueError("the epoch log must number its epochs 0, 1, ...")
        self.learner.load_state_dict(stored.learner, lambda name: self.records[tuple(name[:3])])
        self.order.set_state(torch.from_numpy(decode_array(stored.order, shape=GENERATOR_STATE).astype(np.uint8)))
        self.epochs, self.predictions = stored.epochs, stored.predictions

    def evaluate(self) -> FoldTests:
        """Orientation errors on the test grasps and haptic-only vs cued grasps of the held-out objects,
        recommended for all of them at once (the test grasps are among them: each image is measured once)."""
        held = self.batch[torch.tensor([self.position[t.key] for t in self.objects])]
        given = self.learner.recommend_all(held, [t.fingers for t in self.objects])
        chosen = self.learner.recommend_all(held, [self._fingers(t) for t in self.objects])
        errors = {t.key: None if cue is None else math.degrees(float(angular_error(cue.theta_h, t.outcome.theta_H, t.period)))
                  for t, cue in zip(self.objects, given)}
        haptic, cued = [], []
        for trial, cue in zip(self.objects, chosen):
            fingers = cue.fingers if cue is not None else trial.fingers
            outcome = regrasp(trial, fingers, cue.theta_h if cue else None, self.seed, 0, self.controller)
            haptic.append(Grasp(trial.kind, trial.index, **trial.outcome.to_dict()))
            cued.append(Grasp(trial.kind, trial.index, **outcome.to_dict(), recommended=cue is not None))
        return FoldTests([errors[t.key] for t in self.test], haptic, cued)


def simulate_pool(experiment: str, pool: int, seed: int, size: int, controller: HapticController,
                  progress: bool = False) -> dict:
    """``pool`` trials of each of the experiment's categories."""
    cats = categories(experiment)
    jobs = [(kind, c, j) for kind, c in cats for j in range(pool)]
    trials = [simulate(kind, c, j, seed, size, controller)
              for kind, c, j in tqdm(jobs, desc="simulated grasps", unit="grasp", disable=not progress)]
    return {cat: [t for t in trials if (t.kind, t.fingers) == cat] for cat in cats}
