"""Learning features that cue a haptic grasp controller (6.4, alg. 6.1 and 6.2).

A feature's image orientation theta_f predicts the hand orientation theta_h = theta_f + mu_k
(eq. 6.2), mu_k a mode of the von Mises mixture fitted to the offsets theta_H - theta_f it was
seen with (eq. 6.4). Two :class:`GraspFeatureSet` s, F_2 and F_3, each hold their features and
their own instance list (6.4.1): per experienced grasp the value and orientation of every
feature of the set in that grasp's image, the final hand orientation theta_H, the quality mu_0
and the grasp's symmetry period (prediction errors are taken modulo it, 6.5.1).

Decisions the text leaves open:
- The prediction errors of alg. 6.1 step 1 are those of each feature's *current* model on every
  recorded instance (the exact Expectation step of 6.4.4; it is cheap here because the instance
  list keeps every feature's orientation, so no image is revisited). A feature without a model
  (new) is first fitted to all of its data points.
- Where a feature made no false prediction, KSD_f = 1 and alpha_f lies below all its values (the
  empty distribution's cdf is 1 everywhere); it needs ``min_points`` correct ones to be usable.
- Eq. 6.8 weights each instance above alpha_f by the model's density at its offset; mu_0 is
  capped at ``MU0_CAP`` (an infinite mu_0, no equilibrium, would swamp the average).
- Unused features (never f*_c, nor the feature behind the quality split of step 2b, in the last
  ``discard_every`` grasps of their set, and at least that old) are discarded after every
  ``discard_every`` grasps.
- Step 2b's finger choice (``finger_choice``). "thesis": compare E[mu_0] of f*_2 and f*_3, the
  features chosen for their orientation power (KSD_f). "pooled" (beyond chapter 6): compare, per
  set, the mean of eq. 6.8 over *all* features present in the image, each weighted by its support
  (the instances above alpha_f its model was fitted on). The orientation still comes from f*_c.
  Why: a feature's orientation power says nothing about which objects it fires on. Over seed 1,
  fold 1 of the mixed experiment, f*_2 of most squares was a feature with KSD .89 that had been
  present on 6 training images, 5 of them triangles grasped with two fingers (poor); its
  E[mu_0] = .49 made 28 of 80 held-out squares take three fingers. Pooling over the present
  features, with their support, chose right for 73 of 80 squares (thesis rule 52, every triangle
  right under both).
  "quality" (beyond chapter 6; the default of ``grasp``): over seeds 100-104 pooling still failed
  (reductions of poor grasps 79, 36, 41, 8 and 82 %): in seed 102 every training category's mu_0 lies
  in its own narrow band (good .01-.05, poor .42-.57), so choosing the finger count is telling the
  object kinds apart, yet nearly every modelled feature is present (above its orientation alpha_f)
  on both kinds, and support-weighted means of eq. 6.8 come out alike for both sets. A feature may
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
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import NamedTuple, Sequence

import numpy as np
import torch

from ..checkpoint import DAMAGED, decode_array, encode_array, load_checkpoint, save_checkpoint, stored_position
from ..errors import InputError, NotFittedError
from ..ksd import ksd
from ..space.evaluate import feature_values
from ..space.features import Feature, FeatureTable, unpack_features
from ..space.generate import expand_geometric, random_edgel_pair
from ..space.record import ImageRecords
from ..tables import GrowingTable
from .vonmises import VonMisesMixture, fit_mixtures

MU0_CAP = 2.0
KIND = "grasp-learner"
SETTINGS = ("t_dtheta", "max_k", "min_points", "discard_every", "max_distance", "finger_choice", "mu0_split")
FINGERS = (2, 3)
FINGER_CHOICES = ("thesis", "pooled", "quality")  # alg. 6.2 step 2b: see the module doc


def angular_error(predicted, actual, period) -> np.ndarray:
    """|predicted - actual| in radians, modulo the symmetry period (0: every orientation is right)."""
    predicted, actual, period = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (predicted, actual, period)))
    full = np.where(period > 0, period, 2 * math.pi)
    difference = np.remainder(predicted - actual + full / 2, full) - full / 2
    return np.where(period > 0, np.abs(difference), 0.0)


class Experience(NamedTuple):
    """What the haptic system reports after a grasp (alg. 6.2 step 5)."""

    fingers: int
    theta_H: float
    mu0: float
    period: float


class Recommendation(NamedTuple):
    """Alg. 6.2 steps 2-4: finger count, hand orientation, and the feature f*_c behind them;
    ``expected_mu0`` is what step 2b compared (eq. 6.8 of f*_c, or pooled: see the module doc)."""

    fingers: int
    theta_h: float
    feature: Feature
    ksd: float
    expected_mu0: float


@dataclass
class FeatureModel:
    """Alg. 6.1's result: KSD_f, threshold alpha_f, orientation model (eq. 6.4) and E[M_0(f)] (eq. 6.8)."""

    ksd: float
    alpha: float
    mixture: VonMisesMixture
    offset: float  # mu_{k*} of alg. 6.2 step 3
    expected_mu0: float
    support: int  # instances above alpha_f that eq. 6.4 and 6.8 were fitted on
    rows: np.ndarray | None = field(default=None, repr=False, compare=False)  # those instances' rows

    def to_dict(self) -> dict:
        return {"ksd": self.ksd, "alpha": self.alpha, "mixture": self.mixture.to_dict(), "offset": self.offset,
                "expected_mu0": self.expected_mu0, "support": self.support}

    @classmethod
    def from_dict(cls, data: dict) -> "FeatureModel":
        """A model written by :meth:`to_dict` (without the instance rows it was fitted on)."""
        numbers = [float(data[k]) for k in ("ksd", "alpha", "offset", "expected_mu0")]
        return cls(numbers[0], numbers[1], VonMisesMixture.from_dict(data["mixture"]), numbers[2], numbers[3],
                   int(data["support"]))


class GraspFeatureSet:
    """F_c and its instance list for one finger count c (alg. 6.2)."""

    def __init__(self, fingers: int):
        self.fingers = fingers
        self.features: list[Feature] = []
        self.models: list[FeatureModel | None] = []
        self.born: list[int] = []
        self.used: list[int] = []
        self.images: list = []
        self._seen: set = set()
        self._sources: list[ImageRecords] = []  # distinct image records; rows of one image share them
        self._source_index: dict[int, int] = {}  # id of a stored (hence live) records object -> its source
        self._source_of_row: list[int] = []
        self._first_row: list[int] = []  # per source
        self._batch: ImageRecords | None = None
        self._measured: tuple | None = None  # (records, values, thetas) of the last measure; None once features change
        self._values = GrowingTable(fill=0.0)  # (instances, features): each feature's value in each image
        self._thetas = GrowingTable(fill=0.0)  # ... and its orientation theta_f, NaN where it found no point
        self._outcomes = GrowingTable(3, fill=0.0)  # per instance: theta_H, mu_0 (capped), symmetry period
        self.quality = np.zeros((4, 0))  # per feature: KSD, cut-point, E[mu_0] above and below it ("quality")
        self.grasps = 0
        self.sampled = 0

    @classmethod
    def from_instances(cls, fingers: int, features: list[Feature], values, thetas, theta_H, mu0, period) -> GraspFeatureSet:
        """A set of ``features`` without models over given instances (values and thetas (n, F); theta_H,
        mu_0 and period (n,)): for analyses and tests that study alg. 6.1 on chosen measurements."""
        feature_set = cls(fingers)
        n, width = np.shape(values)
        if np.shape(thetas) != (n, width) or len(features) != width or any(np.shape(a) != (n,) for a in (theta_H, mu0, period)):
            raise InputError(f"from_instances: values and thetas must be (n, {len(features)}) and theta_H, mu0, period (n,)")
        feature_set.features = list(features)
        feature_set.models, feature_set.born, feature_set.used = [None] * width, [0] * width, [-1] * width
        feature_set.quality = np.zeros((4, width))
        feature_set.images = list(range(n))
        feature_set._values.add_columns(np.zeros((0, width)))
        feature_set._thetas.add_columns(np.zeros((0, width)))
        feature_set._values.add_rows(values)
        feature_set._thetas.add_rows(thetas)
        feature_set._outcomes.add_rows(np.stack([theta_H, np.minimum(mu0, MU0_CAP), period], 1))
        return feature_set

    @staticmethod
    def _read_only(array: np.ndarray) -> np.ndarray:
        view = array.view()
        view.flags.writeable = False
        return view

    @property
    def values(self) -> np.ndarray:
        """(instances, features): each feature's value on each distinct image (read-only)."""
        return self._read_only(self._values.array)

    @property
    def thetas(self) -> np.ndarray:
        """(instances, features): each feature's orientation theta_f, NaN where it found no point (read-only)."""
        return self._read_only(self._thetas.array)

    @property
    def theta_H(self) -> np.ndarray:
        """(instances,): the final hand orientation of each grasp (read-only)."""
        return self._read_only(self._outcomes.array[:, 0])

    @property
    def mu0(self) -> np.ndarray:
        """(instances,): each grasp's mu_0, capped at MU0_CAP (read-only)."""
        return self._read_only(self._outcomes.array[:, 1])

    @property
    def period(self) -> np.ndarray:
        """(instances,): each object's symmetry period (read-only)."""
        return self._read_only(self._outcomes.array[:, 2])

    def __len__(self) -> int:
        return len(self.features)

    def measure(self, records: ImageRecords) -> tuple[np.ndarray, np.ndarray]:
        """Values and orientations (B, F) of every feature of the set in each image of ``records``
        (step 2a), measured as one batch. An image of the instance list is read from its row (every
        feature was measured on it when the image or the feature arrived); the last result is kept,
        so recommending, trying and learning on one image measure it once."""
        source = self._source_index.get(id(records))
        if source is not None and self._sources[source] is records:
            row = self._first_row[source]
            return self.values[row:row + 1].copy(), self.thetas[row:row + 1].copy()
        last = self._measured
        if last is not None and last[0] is records:
            return last[1], last[2]
        if not self.features:
            return np.zeros((len(records), 0)), np.zeros((len(records), 0))
        found = feature_values(self.features, records)
        values, thetas = found.values.T.double().cpu().numpy(), found.theta.T.double().cpu().numpy()
        self._measured = (records, values, thetas)
        return values, thetas

    def _model_arrays(self) -> np.ndarray:
        """alpha_f, KSD_f, eq. 6.8's E[mu_0] and support, (4, F); a feature without a model is never present."""
        table = [(m.alpha, m.ksd, m.expected_mu0, m.support) if m is not None else (math.inf, 0.0, 0.0, 0)
                 for m in self.models]
        return np.array(table, dtype=float).reshape(len(self.models), 4).T

    def present(self, values: np.ndarray, thetas: np.ndarray) -> np.ndarray:
        """(B, F): the feature has a model, was located in the image (a finite orientation; a feature
        that finds no point has value 0, which a perfect feature's alpha_f = -inf would let pass) and
        its value exceeds alpha_f."""
        return (values > self._model_arrays()[0]) & np.isfinite(thetas)

    def choose(self, present: np.ndarray) -> np.ndarray:
        """Step 2b for each image, from :meth:`present` (B, F) -> (B,): the present feature of largest
        KSD_f (the first where tied), -1 where none is."""
        power = self._model_arrays()[1]
        score = np.where(present & (power > 0), power, 0.0)
        if not score.shape[1]:
            return np.full(len(present), -1)
        return np.where(score.max(1) > 0, score.argmax(1), -1)

    def pooled_mu0(self, present: np.ndarray) -> np.ndarray:
        """E[mu_0] of a grasp with this set's fingers given each image's :meth:`present` (B, F) -> (B,):
        eq. 6.8 of every present feature, weighted by its support (module doc, "pooled"); NaN without one."""
        _, _, expected, support = self._model_arrays()
        weight = np.where(present, support, 0.0)
        total = weight.sum(1)
        return np.where(total > 0, (weight * expected).sum(1) / np.where(total > 0, total, 1.0), np.nan)

    def quality_mu0(self, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """E[mu_0] given each image's measurements (B, F) -> (B,) by the set's best quality split (module
        doc, "quality"): the mean mu_0 of the instances on the image's side of the cut-point of the
        measured feature of largest quality KSD; NaN where none has one. Also that feature (B,), -1 there.
        A feature that finds no point has value 0: its absence lies below every cut-point."""
        power, cut, above, below = self.quality
        score = np.where(np.isfinite(values) & (power > 0), power, 0.0)
        if not score.shape[1]:
            return np.full(len(values), np.nan), np.full(len(values), -1)
        j = score.argmax(1)
        rows = np.arange(len(values))
        found = score[rows, j] > 0
        expected = np.where(values[rows, j] > cut[j], above[j], below[j])
        return np.where(found, expected, np.nan), np.where(found, j, -1)

    def fit_quality(self, mu0_split: float, min_points: int) -> None:
        """Quality splits ("quality", beyond chapter 6): per feature, the KSD (def. 4.2, either direction)
        between its values on good (mu_0 <= split) and poor instances, its cut-point, and the mean mu_0
        on each side; a side with fewer than ``min_points`` instances gives no split."""
        if not self.features or not self.images:
            self.quality = np.zeros((4, len(self)))
            return
        values = torch.from_numpy(self.values.T.copy())
        good = torch.from_numpy(self.mu0 <= mu0_split)
        split = ksd(values, good, ~good)
        distance, cut = split.distance.numpy(), split.cutpoint.numpy()
        located = np.isfinite(self.values)
        high = located & (self.values > cut[None, :])
        low = located & ~high
        count = np.stack([high.sum(0), low.sum(0)])
        mean = np.stack([(side * self.mu0[:, None]).sum(0) for side in (high, low)]) / np.maximum(count, 1)
        enough = (count >= min_points).all(0) & np.isfinite(cut)
        self.quality = np.stack([np.where(enough, distance, 0.0), cut, *mean])

    def add_instance(self, image, records: ImageRecords, values, thetas, experience: Experience) -> None:
        """Step 5: one row of the instance list per distinct ``image`` (presenting an image again with
        the same outcome adds no information, as in 4.4.1)."""
        if image in self._seen:
            return
        self._seen.add(image)
        self.images.append(image)
        if id(records) not in self._source_index:
            self._source_index[id(records)], self._batch = len(self._sources), None
            self._sources.append(records)
            self._first_row.append(len(self.images) - 1)
        self._source_of_row.append(self._source_index[id(records)])
        self._values.add_rows(values[None, :])
        self._thetas.add_rows(thetas[None, :])
        self._outcomes.add_rows([[experience.theta_H, min(experience.mu0, MU0_CAP), experience.period]])

    def add_features(self, features: list[Feature]) -> None:
        """New features, measured at once on every distinct image of the instance list."""
        features = [f for f in features if f is not None and f not in self.features]
        if not features:
            return
        if self.images:
            if self._batch is None:
                self._batch = ImageRecords.cat(self._sources)
            found = feature_values(features, self._batch)
            rows = self._source_of_row
            self._values.add_columns(found.values.double().cpu().numpy().T[rows])
            self._thetas.add_columns(found.theta.double().cpu().numpy().T[rows])
        else:
            self._values.add_columns(np.zeros((0, len(features))))
            self._thetas.add_columns(np.zeros((0, len(features))))
        self.features += features
        self._measured = None
        self.models += [None] * len(features)
        self.quality = np.hstack([self.quality, np.zeros((4, len(features)))])
        self.born += [self.grasps] * len(features)
        self.used += [-1] * len(features)
        self.sampled += len(features)

    def discard(self, window: int) -> int:
        """Drop features at least ``window`` grasps old that were not f* during the last ``window``."""
        keep = [j for j in range(len(self)) if self.born[j] > self.grasps - window or self.used[j] > self.grasps - window]
        dropped = len(self) - len(keep)
        if dropped:
            for name in ("features", "models", "born", "used"):
                setattr(self, name, [getattr(self, name)[j] for j in keep])
            self._values.keep_columns(keep)
            self._thetas.keep_columns(keep)
            self.quality = self.quality[:, keep]
            self._measured = None
        return dropped

    def fit(self, t_dtheta: float, max_k: int, min_points: int) -> None:
        """Alg. 6.1 for every feature of the set, batched."""
        if not self.features or not self.images:
            return
        offsets = self.theta_H[:, None] - self.thetas  # (n, F), NaN where a feature found no point
        located = np.isfinite(offsets)
        fresh = [j for j, m in enumerate(self.models) if m is None and located[:, j].sum() >= min_points]
        start = dict(zip(fresh, fit_mixtures([offsets[located[:, j], j] for j in fresh], max_k))) if fresh else {}
        mixture = {j: start.get(j) or (m.mixture if m is not None else None) for j, m in enumerate(self.models)}
        modelled = [j for j in range(len(self)) if mixture[j] is not None]
        if not modelled:
            return
        offset = np.array([float(mixture[j].mu[mixture[j].concentrated(min_points)]) for j in modelled])
        error = angular_error(self.thetas[:, modelled] + offset, self.theta_H[:, None], self.period[:, None])
        correct = located[:, modelled] & (error < t_dtheta)
        false = located[:, modelled] & ~correct
        values = torch.from_numpy(np.where(located[:, modelled], self.values[:, modelled], np.nan).T)
        split = ksd(values, torch.from_numpy(correct.T), torch.from_numpy(false.T))
        power, alpha = split.distinctive.numpy().copy(), split.cutpoint.numpy().copy()
        perfect = ~false.any(0) & (correct.sum(0) >= min_points)
        power[perfect], alpha[perfect] = 1.0, -math.inf
        chosen = located[:, modelled] & (self.values[:, modelled] > alpha[None, :])
        usable = [i for i in range(len(modelled)) if power[i] > 0 and chosen[:, i].sum() >= min_points]
        rows = {i: np.flatnonzero(chosen[:, i]) for i in usable}
        previous = {i: self.models[modelled[i]] for i in usable}
        # A model fitted to the same instances keeps its mixture: EM on the same points reaches the
        # same fit (each fit is independent of its batch, ftorch/grasp/vonmises.py), so only changed ones are fitted.
        kept = {i: m.mixture for i, m in previous.items() if m is not None and np.array_equal(m.rows, rows[i])}
        refit = [i for i in usable if i not in kept]
        fitted = {**kept, **dict(zip(refit, fit_mixtures([offsets[rows[i], modelled[i]] for i in refit], max_k)
                                          if refit else []))}
        self.models = [None] * len(self)
        for i in usable:
            j, mix, points = modelled[i], fitted[i], rows[i]
            weight = mix.pdf(torch.from_numpy(offsets[points, j])).numpy()
            expected = float((weight * self.mu0[points]).sum() / max(weight.sum(), 1e-300))
            offset = float(mix.mu[mix.concentrated(min_points)])
            self.models[j] = FeatureModel(float(power[i]), float(alpha[i]), mix, offset, expected, len(points), points)


class GraspLearner:
    """Alg. 6.2: recommends finger count and hand orientation, learns from every grasp's outcome.

    ``t_dtheta`` (radians) divides correct from false predictions (6.4.2); ``max_k`` bounds the
    mixtures' components; ``discard_every`` is the discarding period in grasps of a set;
    ``max_distance`` bounds the edgel pairs sampled (pixels, default a quarter image side).
    ``finger_choice`` is step 2b's rule (module doc). ``mu0_split`` (None: the thesis, which learns
    from orientation mistakes only) makes a grasp whose E[mu_0] (as step 2b computes it) lies on the
    other side of the split than its measured mu_0 a mistake too (module doc, "quality mistakes").
    Every random choice comes from ``seed``.
    """

    def __init__(self, t_dtheta: float = math.radians(10), max_k: int = 4, min_points: int = 3,
                 discard_every: int = 40, max_distance: float | None = None, seed: int = 0,
                 finger_choice: str = "thesis", mu0_split: float | None = None):
        if not 0 < t_dtheta < math.pi:
            raise InputError(f"t_dtheta must lie in (0, pi) radians, got {t_dtheta}")
        if finger_choice not in FINGER_CHOICES:
            raise InputError(f"finger_choice {finger_choice!r}: expected one of {', '.join(FINGER_CHOICES)}")
        if mu0_split is not None and not 0 < mu0_split < MU0_CAP:
            raise InputError(f"mu0_split must lie in (0, {MU0_CAP}), got {mu0_split}")
        if finger_choice == "quality" and mu0_split is None:
            raise InputError("finger_choice 'quality' needs mu0_split, the mu_0 that divides good from poor grasps")
        self.finger_choice, self.mu0_split = finger_choice, mu0_split
        if max_k < 1 or min_points < 1 or discard_every < 1:
            raise InputError("max_k, min_points and discard_every must be at least 1")
        self.t_dtheta, self.max_k, self.min_points = t_dtheta, max_k, min_points
        self.discard_every, self.max_distance = discard_every, max_distance
        self.sets = {c: GraspFeatureSet(c) for c in FINGERS}
        self.generator = torch.Generator().manual_seed(seed)
        self.trainable = True  # False once loaded: the images of past grasps are not saved

    # -- state -----------------------------------------------------------------------------------
    def save(self, path) -> None:
        """Write what recommending needs (JSON, atomically): the settings and, per finger count, the
        features, their models (alg. 6.1) and quality splits. The instance lists are not written: new
        features are measured on the images of past grasps, which a file does not hold, so a loaded
        learner recommends but does not learn. NotFittedError before any feature has a model."""
        if not any(m is not None for s in self.sets.values() for m in s.models):
            raise NotFittedError("this GraspLearner has no feature model yet: learn from some grasps first")
        table = FeatureTable()
        sets = [{"fingers": c, "features": [table.index(f) for f in s.features],
                 "models": [None if m is None else m.to_dict() for m in s.models],
                 "quality": encode_array(np.ascontiguousarray(s.quality, dtype=np.float64))}
                for c, s in self.sets.items()]
        save_checkpoint(path, KIND, {"settings": {k: getattr(self, k) for k in SETTINGS}, "sets": sets,
                                     "features": table.pack()})

    @classmethod
    def load(cls, path) -> "GraspLearner":
        """Read a learner written by :meth:`save`; one InputError for a damaged or foreign file."""
        data = load_checkpoint(path, KIND)
        try:
            learner = cls(**data["settings"])
            features = unpack_features(data["features"])
            for record in data["sets"]:
                feature_set = learner.sets[record["fingers"]]
                chosen = [features[stored_position(i, len(features))] for i in record["features"]]
                models = [None if m is None else FeatureModel.from_dict(m) for m in record["models"]]
                quality = decode_array(record["quality"], shape=(4, len(chosen)))
                if len(models) != len(chosen):
                    raise ValueError(f"{len(chosen)} features but {len(models)} models")
                feature_set.features, feature_set.models, feature_set.quality = chosen, models, quality
                feature_set.born, feature_set.used = [0] * len(chosen), [0] * len(chosen)
        except DAMAGED as err:
            raise InputError(f"{path}: damaged grasp learner ({type(err).__name__}: {err})") from None
        learner.trainable = False
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
            values, thetas = feature_set.measure(records)
            chosen, _, expected = self._step_2b(feature_set, values, thetas)
            for i in np.flatnonzero((chosen >= 0) & np.array([f in (None, c) for f in fingers], dtype=bool)):
                if best[i] is None or expected[i] < best[i].expected_mu0:
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
        chosen, behind, expected = self._step_2b(feature_set, values[None, :], thetas[None, :])
        j = int(chosen[0])
        if j < 0:
            return None
        if use:  # f*_c, and the feature whose quality split gave E[mu_0] (else it would be discarded)
            feature_set.used[j] = feature_set.grasps
            if behind[0] >= 0:
                feature_set.used[behind[0]] = feature_set.grasps
        return self._cue(c, 0, j, thetas[None, :], expected)

    def _step_2b(self, feature_set: GraspFeatureSet, values: np.ndarray, thetas: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Step 2b on each image's measurements (B, F) by one set: f*_c (B,; -1 where none is present),
        the feature whose quality split gave E[mu_0] (B,; -1 where none did) and E[mu_0] (B,), by
        ``finger_choice`` ("quality" falls back on "pooled" where no quality split is measured)."""
        present = feature_set.present(values, thetas)
        chosen, behind = feature_set.choose(present), np.full(len(values), -1)
        if self.finger_choice == "thesis":
            expected = feature_set._model_arrays()[2][chosen] if len(feature_set) else np.zeros(len(values))
        else:
            expected = feature_set.pooled_mu0(present)
            if self.finger_choice == "quality":
                quality, behind = feature_set.quality_mu0(values)
                expected = np.where(np.isfinite(quality), quality, expected)
        return chosen, behind, expected

    def _cue(self, c: int, i: int, j: int, thetas: np.ndarray, expected: np.ndarray) -> Recommendation:
        """Steps 3-4 for image i of a batch (B, F) whose f*_c is feature j of set c."""
        model = self.sets[c].models[j]
        return Recommendation(c, float(thetas[i, j] + model.offset), self.sets[c].features[j], model.ksd, float(expected[i]))

    def learn(self, image, records: ImageRecords, experience: Experience) -> str:
        """Steps 5-10 after a grasp with ``experience.fingers`` fingers of the image ``records``
        (``image`` names it in the instance list). Returns 'correct', 'refit' (right after step 7)
        or 'sampled' (step 10)."""
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
        if feature_set.grasps % self.discard_every == 0:
            feature_set.discard(self.discard_every)
        return outcome

    def _correct(self, recommendation: Recommendation | None, experience: Experience) -> bool:
        """Steps 6 and 9: the orientation within t_dtheta (and, with ``mu0_split``, E[mu_0] on the side of it
        that the grasp's mu_0 fell)."""
        if recommendation is None:
            return False
        if self.mu0_split is not None and (recommendation.expected_mu0 > self.mu0_split) != (experience.mu0 > self.mu0_split):
            return False
        return bool(angular_error(recommendation.theta_h, experience.theta_H, experience.period) < self.t_dtheta)

    def _after(self, feature_set, records, values, thetas, before, experience) -> str:
        if self._correct(before, experience):
            return "correct"
        feature_set.fit(self.t_dtheta, self.max_k, self.min_points)
        if self.finger_choice == "quality":
            feature_set.fit_quality(self.mu0_split, self.min_points)
        if self._correct(self._predict(feature_set.fingers, values, thetas, use=True), experience):
            return "refit"
        new = [random_edgel_pair(records, 0, self.generator, self.max_distance)]
        if feature_set.features:
            pick = int(torch.randint(len(feature_set), (1,), generator=self.generator))
            new.append(expand_geometric(feature_set.features[pick], records, 0, self.generator, self.max_distance))
        feature_set.add_features(new)
        return "sampled"
