"""Learning features that cue a haptic grasp controller (6.4, alg. 6.1 and 6.2).

A feature's image orientation theta_f predicts the hand orientation theta_h = theta_f + mu_k
(eq. 6.2), mu_k a mode of the von Mises mixture fitted to the offsets theta_H - theta_f it was
seen with (eq. 6.4). Two :class:`~ftorch.grasp.feature_set.GraspFeatureSet` s, F_2 and F_3, each
hold their features and their own instance list (6.4.1): per experienced grasp the value and
orientation of every feature of the set in that grasp's image, the final hand orientation theta_H,
the quality mu_0 and the grasp's symmetry period (prediction errors are taken modulo it, 6.5.1).
The parts: the feature models of alg. 6.1 (ftorch/grasp/models.py), the sets with their instance
lists and step 2b (ftorch/grasp/feature_set.py), saving and restoring (ftorch/grasp/state.py), and
here alg. 6.2 with the estimator face.

Decisions the text leaves open:
- The prediction errors of alg. 6.1 step 1 are those of each feature's *current* model on every
  recorded instance (the exact Expectation step of 6.4.4; it is cheap here because the instance
  list keeps every feature's orientation, so no image is revisited). A feature without a model
  (new) is first fitted to all of its data points.
- Where a feature made no false prediction, KSD_f = 1 and alpha_f lies below all its values (the
  empty distribution's cdf is 1 everywhere); it needs ``min_points`` correct ones to be usable.
- Eq. 6.8 weights each instance above alpha_f by the model's density at its offset; mu_0 is
  capped at ``MU0_CAP`` (an infinite mu_0, no equilibrium, would swamp the average).
- The settings are one :class:`~ftorch.grasp.settings.GraspSettings`; its defaults are the measured
  best ("quality" below), :meth:`GraspLearner.thesis` gives the dissertation's alg. 6.2.
- Unused features (never f*_c, nor the feature behind the quality split of step 2b, in the last
  ``discard_every`` grasps of their set, and at least that old) are discarded after every
  ``discard_every`` grasps.
- Step 2b's finger choice (``finger_choice``, a :class:`FingerChoice`). "thesis": compare E[mu_0] of f*_2 and f*_3, the
  features chosen for their orientation power (KSD_f). "pooled" (beyond chapter 6): compare, per
  set, the mean of eq. 6.8 over *all* features present in the image, each weighted by its support
  (the instances above alpha_f its model was fitted on). The orientation still comes from f*_c.
  Why: a feature's orientation power says nothing about which objects it fires on: f*_c may be a
  feature seen mostly on the other object kind, and its E[mu_0] then picks the wrong finger count
  (the cases are in docs/decisions.md, chapter 6).
  "quality" (beyond chapter 6; the default): pooling can still fail where every training
  category's mu_0 lies in its own narrow band, so that choosing the finger count is telling the
  object kinds apart, yet nearly every modelled feature is present (above its orientation alpha_f)
  on both kinds, and support-weighted means of eq. 6.8 come out alike for both sets (figures in
  docs/results.md, chapter 6). A feature may
  still *respond* differently to the two kinds. So each feature also gets a quality split: the KSD
  (def. 4.2, in either direction, alg. 6.1's machinery with good and poor grasps in place of correct
  and false predictions) between its values on the set's good (mu_0 <= ``mu0_split``) and poor
  instances, its cut-point, and the mean mu_0 of the instances on each side (each side at least
  ``min_points``). Step 2b then takes, per set, the measured feature of largest quality KSD and the
  mean mu_0 on the image's side of its cut-point (pooled where no split exists yet).
- Quality mistakes (``mu0_split``, beyond chapter 6): alg. 6.2 learns only from orientation mistakes,
  so nothing drives the search towards features that tell good from poor grasps. With a split, a
  grasp whose E[mu_0] (step 2b's) lies on the other side of it than the measured mu_0 is a mistake as
  well: steps 7-10 refit and, if still wrong, sample two new features from the image.
- The estimator face in scikit-learn's manner: ``__init__`` keeps its parameters (``settings``,
  ``seed``, ``device``) as given, :meth:`GraspLearner.get_params` and :meth:`GraspLearner.set_params`
  answer with them, so ``sklearn.base.clone`` gives an unfitted learner with the same ones. The
  learned state keeps its names without scikit-learn's trailing underscore (``sets``, ``trainable``,
  ``generator``): the documentation, the notebook and users' code read ``learner.sets``.
"""
from __future__ import annotations

from enum import StrEnum
from typing import Hashable, NamedTuple, Sequence

import numpy as np
import torch

from ..checkpoint import load_checkpoint, reading, save_checkpoint
from ..errors import InputError, NotFittedError
from ..settings import as_device
from ..space.features import Feature
from ..space.generate import expand_geometric, random_edgel_pair
from ..space.record import FeatureSpace, ImageRecords
from .feature_set import Experience, GraspFeatureSet
from .models import angular_error
from .settings import FingerChoice, GraspSettings
from .state import FINGERS, KIND, Records, learner_state, restore_learner


class Learned(StrEnum):
    """What :meth:`GraspLearner.learn` did with a grasp (alg. 6.2 steps 6-10)."""

    CORRECT = "correct"  # step 6: the prediction was right
    REFIT = "refit"  # step 9: right after the models were refitted (step 7)
    SAMPLED = "sampled"  # step 10: still wrong, new features sampled from the image


class Recommendation(NamedTuple):
    """Alg. 6.2 steps 2-4: finger count, hand orientation, and the feature f*_c behind them;
    ``expected_mu0`` is what step 2b compared (eq. 6.8 of f*_c, or pooled: see the module doc)."""

    fingers: int
    theta_h: float
    feature: Feature
    ksd: float
    expected_mu0: float


class GraspLearner:
    """Alg. 6.2: recommends finger count and hand orientation, learns from every grasp's outcome.

    ``settings`` (:class:`GraspSettings`, default the measured best), changed by ``options``;
    :meth:`thesis` gives the dissertation's. Every random choice comes from ``seed``; ``device`` is
    where :meth:`fit`, :meth:`predict` and :meth:`score` compute the records of their images (records
    given to :meth:`recommend` and :meth:`learn` are measured on their own device).

    The estimator face maps onto alg. 6.2 as far as it goes: :meth:`fit` runs steps 2-10 over past
    grasps (images with the haptic system's :class:`Experience`), :meth:`predict` is steps 2-4,
    :meth:`score` step 6's test. There is no ``partial_fit`` over anonymous images: alg. 6.2 keeps one
    instance per distinct image, so the incremental face is :meth:`learn`, which takes the image's
    name; and no ``predict_proba``: a recommendation is an orientation and a finger count, not a class.
    """

    def __init__(self, settings: GraspSettings | None = None, *, seed: int = 0, device: str | torch.device = "cpu",
                 **options):
        settings = GraspSettings() if settings is None else settings
        if not isinstance(settings, GraspSettings):
            raise InputError(f"settings must be GraspSettings, got {type(settings).__name__}")
        self.settings = settings.replace(**options)
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise InputError(f"seed must be an integer of at least 0, got {seed!r}")
        self.seed, self.device = int(seed), as_device(device)
        self.generator = torch.Generator()
        self._blank()

    def get_params(self, deep: bool = True) -> dict:
        """The constructor's parameters as this learner holds them (``deep`` changes nothing: the
        settings are one value)."""
        return {"settings": self.settings, "seed": self.seed, "device": self.device}

    def set_params(self, **params) -> "GraspLearner":
        """Change parameters of :meth:`get_params`, or single settings (``set_params(max_k=2)``), validated
        as the constructor validates them, and return the learner; what it learned stays (:meth:`fit`
        learns afresh with them)."""
        changed = type(self)(params.pop("settings", self.settings), seed=params.pop("seed", self.seed),
                             device=params.pop("device", self.device), **params)
        self.settings, self.seed, self.device = changed.settings, changed.seed, changed.device
        return self

    def _blank(self) -> None:
        """The state before any grasp: empty sets, the generator at ``seed``."""
        self.sets: dict[int, GraspFeatureSet] = {c: GraspFeatureSet(c) for c in FINGERS}
        self.generator.manual_seed(self.seed)
        self.trainable = True  # False once loaded from a file without the past grasps' images

    @classmethod
    def thesis(cls, *, seed: int = 0, device: str | torch.device = "cpu", **options) -> "GraspLearner":
        """A learner with the dissertation's settings (:meth:`GraspSettings.thesis`), changed by ``options``."""
        return cls(GraspSettings.thesis(), seed=seed, device=device, **options)

    def __getattr__(self, name: str):
        """Each setting reads as an attribute too (``learner.min_points``)."""
        if name in GraspSettings.names() and "settings" in self.__dict__:
            return getattr(self.settings, name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    # -- estimator face ---------------------------------------------------------------------------
    def _records(self, images) -> ImageRecords:
        return FeatureSpace().to(self.device).records(images)

    def fit(self, images, experiences: Sequence[Experience], epochs: int = 1) -> "GraspLearner":
        """Alg. 6.2 from scratch over past grasps: ``images`` (files, arrays or tensors) with what the haptic
        system reported for each, presented in their order (image i named i) for up to ``epochs`` passes,
        fewer where a pass makes no mistake."""
        if len(images) != len(experiences):
            raise InputError(f"fit: {len(images)} images but {len(experiences)} experiences")
        epochs = int(epochs)
        if epochs < 1:
            raise InputError(f"epochs must be at least 1, got {epochs}")
        records = self._records(images)
        self._blank()
        for _ in range(epochs):
            learned = [self.learn(i, records[i], experience) for i, experience in enumerate(experiences)]
            if all(result is Learned.CORRECT for result in learned):
                break
        return self

    def _fitted(self) -> None:
        if not any(m is not None for s in self.sets.values() for m in s.models):
            raise NotFittedError("this GraspLearner has no feature model yet: learn from some grasps first")

    def predict(self, images, fingers: Sequence[int | None] | None = None) -> list[Recommendation | None]:
        """Steps 2-4 for each image (:meth:`recommend_all`); NotFittedError before any feature has a model."""
        self._fitted()
        return self.recommend_all(self._records(images), fingers)

    def score(self, images, experiences: Sequence[Experience]) -> float:
        """The fraction of grasps whose recommendation, with the finger count each was grasped with, passes
        step 6's test (orientation within t_dtheta; with ``mu0_split``, E[mu_0] on the grasp's side of it)."""
        self._fitted()
        if len(images) != len(experiences):
            raise InputError(f"score: {len(images)} images but {len(experiences)} experiences")
        cues = self.recommend_all(self._records(images), [e.fingers for e in experiences])
        return float(np.mean([self._correct(cue, e) for cue, e in zip(cues, experiences)]))

    # -- state -----------------------------------------------------------------------------------
    def state_dict(self, training: bool = True) -> dict:
        """JSON-ready: the settings and, per finger count, the features, their models (alg. 6.1) and quality
        splits; with ``training``, all that learning reads too (ftorch/grasp/state.py), the
        seed and the generator's state, so that a learner restored by :meth:`load_state_dict` learns on
        exactly as this one would (the images themselves are not held: the caller gives their records)."""
        if training and not self.trainable:
            raise InputError("this grasp learner was loaded without its past grasps: it has no training state")
        if training:
            return learner_state(self.settings, self.sets, self.seed, self.generator)
        return learner_state(self.settings, self.sets)

    def load_state_dict(self, state: dict, records: Records | None = None) -> None:
        """Restore :meth:`state_dict` into this learner (its settings are read from the state). A training
        state needs ``records``: the records of an image of the instance list, by its name. ValueError
        (or another of ``ftorch.checkpoint.DAMAGED``) for a damaged state."""
        restored = restore_learner(state, records)
        self.settings = restored.settings
        if restored.seed is not None:
            self.seed = restored.seed
        self._blank()
        self.sets = restored.sets
        if restored.generator is not None:
            self.generator.set_state(restored.generator)
        self.trainable = restored.generator is not None

    def save(self, path) -> None:
        """Write what recommending needs (JSON, atomically): :meth:`state_dict` without training. The
        instance lists are not written: new features are measured on the images of past grasps, which a
        file does not hold, so a loaded learner recommends but does not learn. NotFittedError before any
        feature has a model."""
        self._fitted()
        save_checkpoint(path, KIND, self.state_dict(training=False))

    @classmethod
    def load(cls, path, device: str | torch.device = "cpu") -> "GraspLearner":
        """Read a learner written by :meth:`save`; one InputError for a damaged or foreign file."""
        data = load_checkpoint(path, KIND)
        learner = cls(device=device)
        with reading(path, "grasp learner"):
            learner.load_state_dict({**{k: data[k] for k in ("settings", "sets", "features")}, "schema": data.get("schema")})
        return learner

    def _candidates(self, records: ImageRecords, fingers: int | None) -> list[int]:
        if len(records) != 1:
            raise InputError(f"grasp learner: expected the records of one image, got {len(records)}")
        if fingers is not None and fingers not in self.sets:
            raise InputError(f"fingers must be one of {FINGERS}, got {fingers}")
        return list(FINGERS) if fingers is None else [fingers]

    def recommend(self, records: ImageRecords, fingers: int | None = None) -> Recommendation | None:
        """Steps 2-4 on one image: c (given, or the set whose f*_c expects the lower mu_0) and theta_h.
        Pure: only :meth:`learn` counts f*_c as used, for the set that grasped."""
        self._candidates(records, fingers)
        return self.recommend_all(records, [fingers])[0]

    def recommend_all(self, records: ImageRecords, fingers: Sequence[int | None] | None = None
                      ) -> list[Recommendation | None]:
        """:meth:`recommend` for every image of ``records``, each set measured once on the batch;
        ``fingers`` gives each image's finger count (None: chosen by step 2b)."""
        fingers = [None] * len(records) if fingers is None else list(fingers)
        if len(fingers) != len(records) or any(c is not None and c not in self.sets for c in fingers):
            raise InputError(f"fingers: expected one of {FINGERS} or None for each of the {len(records)} images")
        best: list[Recommendation | None] = [None] * len(records)
        for c, feature_set in self.sets.items():
            if None not in fingers and c not in fingers:
                continue  # no image asks for this set: it is not measured
            values, thetas = feature_set.measure(records)
            chosen, _, expected = feature_set.step_2b(values, thetas, self.settings.finger_choice)
            for i in np.flatnonzero((chosen >= 0) & np.array([f in (None, c) for f in fingers], dtype=bool)).tolist():
                current = best[i]
                if current is None or expected[i] < current.expected_mu0:
                    best[i] = self._cue(c, i, int(chosen[i]), thetas, expected)
        return best

    def untried(self, records: ImageRecords) -> list[int]:
        """Finger counts whose set has no present feature in this image, hence no estimate of mu_0 for
        step 2b. An on-line learner tries them (the thesis's off-line data never needed to), or a set
        without features would never gain the experience that gives it some."""
        return [c for c in self._candidates(records, None)
                if self._predict(c, *(a[0] for a in self.sets[c].measure(records))) is None]

    def _predict(self, c: int, values: np.ndarray, thetas: np.ndarray, use: bool = False) -> Recommendation | None:
        """Steps 2b-4 with set c on one image's measurements (F,); ``use`` counts the features used."""
        feature_set = self.sets[c]
        chosen, behind, expected = feature_set.step_2b(values[None, :], thetas[None, :], self.settings.finger_choice)
        j = int(chosen[0])
        if j < 0:
            return None
        if use:  # f*_c, and the feature whose quality split gave E[mu_0] (else it would be discarded)
            feature_set.used[j] = feature_set.grasps
            if behind[0] >= 0:
                feature_set.used[behind[0]] = feature_set.grasps
        return self._cue(c, 0, j, thetas[None, :], expected)

    def _cue(self, c: int, i: int, j: int, thetas: np.ndarray, expected: np.ndarray) -> Recommendation:
        """Steps 3-4 for image i of a batch (B, F) whose f*_c is feature j of set c."""
        model = self.sets[c].models[j]
        if model is None:  # a bug: step 2b chooses among present features, and present() admits modelled ones only
            raise RuntimeError(f"step 2b chose feature {j} of set {c}, which has no model")
        return Recommendation(c, float(thetas[i, j] + model.offset), self.sets[c].features[j], model.ksd, float(expected[i]))

    def learn(self, image: Hashable, records: ImageRecords, experience: Experience) -> Learned:
        """Steps 5-10 after a grasp with ``experience.fingers`` fingers of the image ``records``
        (``image`` names it in the instance list: an image learned from again adds no row)."""
        if not self.trainable:
            raise InputError("this grasp learner was loaded from a file, which holds no images of past grasps: "
                             "it recommends but cannot learn")
        c = self._candidates(records, experience.fingers)[0]
        feature_set = self.sets[c]
        values, thetas = (a[0] for a in feature_set.measure(records))
        before = self._predict(c, values, thetas, use=True)
        feature_set.add_instance(image, records, values, thetas, experience)
        feature_set.grasps += 1
        outcome = self._after(feature_set, records, values, thetas, before, experience)
        if feature_set.grasps % self.settings.discard_every == 0:
            feature_set.discard(self.settings.discard_every)
        return outcome

    def _correct(self, recommendation: Recommendation | None, experience: Experience) -> bool:
        """Steps 6 and 9: the orientation within t_dtheta (and, with ``mu0_split``, E[mu_0] on the side of it
        that the grasp's mu_0 fell)."""
        if recommendation is None:
            return False
        split = self.settings.mu0_split
        if split is not None and (recommendation.expected_mu0 > split) != (experience.mu0 > split):
            return False
        return bool(angular_error(recommendation.theta_h, experience.theta_H, experience.period) < self.settings.t_dtheta)

    def _after(self, feature_set, records, values, thetas, before, experience) -> Learned:
        if self._correct(before, experience):
            return Learned.CORRECT
        feature_set.fit(self.settings.t_dtheta, self.settings.max_k, self.settings.min_points)
        if self.settings.finger_choice is FingerChoice.QUALITY:
            feature_set.fit_quality(self.settings.mu0_split, self.settings.min_points)
        if self._correct(self._predict(feature_set.fingers, values, thetas, use=True), experience):
            return Learned.REFIT
        new = [random_edgel_pair(records, 0, self.generator, self.settings.max_distance)]
        if feature_set.features:
            pick = int(torch.randint(len(feature_set), (1,), generator=self.generator))
            new.append(expand_geometric(feature_set.features[pick], records, 0, self.generator, self.settings.max_distance))
        feature_set.add_features(new)
        return Learned.SAMPLED
