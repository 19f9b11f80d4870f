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
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field
from enum import StrEnum
from typing import Callable, Hashable, NamedTuple, Sequence

import numpy as np
import torch

from ..checkpoint import DAMAGED, decode_array, encode_array, load_checkpoint, save_checkpoint, stored_position
from ..errors import InputError, NotFittedError
from ..ksd import ksd
from ..settings import as_device
from ..space.evaluate import feature_values
from ..space.features import Feature, FeatureTable, unpack_features
from ..space.generate import expand_geometric, random_edgel_pair
from ..space.record import FeatureSpace, ImageRecords
from ..tables import GrowingTable
from .settings import MU0_CAP, FingerChoice, GraspSettings
from .vonmises import VonMisesMixture, fit_mixtures

KIND = "grasp-learner"
FINGERS = (2, 3)
GENERATOR_STATE = tuple(torch.Generator().get_state().shape)  # the bytes of a torch.Generator's state


class Learned(StrEnum):
    """What :meth:`GraspLearner.learn` did with a grasp (alg. 6.2 steps 6-10)."""

    CORRECT = "correct"  # step 6: the prediction was right
    REFIT = "refit"  # step 9: right after the models were refitted (step 7)
    SAMPLED = "sampled"  # step 10: still wrong, new features sampled from the image


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

    def to_dict(self, rows: bool = False) -> dict:
        """JSON-ready; with ``rows``, the instance rows it was fitted on (which learning compares)."""
        out = {"ksd": self.ksd, "alpha": self.alpha, "mixture": self.mixture.to_dict(), "offset": self.offset,
               "expected_mu0": self.expected_mu0, "support": self.support}
        return {**out, "rows": self.rows.tolist()} if rows else out

    @classmethod
    def from_dict(cls, data: dict, instances: int | None = None) -> "FeatureModel":
        """A model written by :meth:`to_dict`; its rows, where written, are positions among ``instances``."""
        numbers = [float(data[k]) for k in ("ksd", "alpha", "offset", "expected_mu0")]
        rows = None
        if "rows" in data:
            rows = np.array([stored_position(i, instances or 0) for i in data["rows"]], dtype=np.int64)
            if len(rows) != int(data["support"]):
                raise ValueError(f"a model fitted on {data['support']} instances lists {len(rows)} rows")
        return cls(numbers[0], numbers[1], VonMisesMixture.from_dict(data["mixture"]), numbers[2], numbers[3],
                   int(data["support"]), rows)


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
        feature_set._fill(list(range(n)), values, thetas, np.stack([theta_H, np.minimum(mu0, MU0_CAP), period], 1))
        return feature_set

    def _fill(self, images: list, values: np.ndarray, thetas: np.ndarray, outcomes: np.ndarray) -> None:
        """The instance list of an empty set: ``images`` and their rows (values and thetas (n, F), outcomes (n, 3))."""
        self.images, self._seen = list(images), set(images)
        for table, rows in ((self._values, values), (self._thetas, thetas)):
            table.add_columns(np.zeros((0, np.shape(rows)[1])))
            table.add_rows(rows)
        self._outcomes.add_rows(outcomes)

    def state_dict(self, table: FeatureTable, training: bool = True) -> dict:
        """JSON-ready: the features (positions in ``table``), their models (alg. 6.1) and quality splits; with
        ``training``, all that learning reads too: the instance list (each row's image name, values,
        orientations and outcome; the rows of each image's records), the models' rows, the features'
        birth and last use, and the grasp and sampling counts."""
        state = {"fingers": self.fingers, "features": [table.index(f) for f in self.features],
                 "models": [None if m is None else m.to_dict(rows=training) for m in self.models],
                 "quality": encode_array(np.ascontiguousarray(self.quality, dtype=np.float64))}
        if training:
            state.update({"images": [_name_to_json(i) for i in self.images], "values": encode_array(self.values),
                          "thetas": encode_array(self.thetas), "outcomes": encode_array(self._outcomes.array),
                          "source_of_row": list(self._source_of_row), "first_row": list(self._first_row),
                          "born": list(self.born), "used": list(self.used), "grasps": self.grasps, "sampled": self.sampled})
        return state

    def load_state_dict(self, state: dict, features: list[Feature],
                        records: Callable[[Hashable], ImageRecords] | None = None) -> None:
        """Restore an empty set from :meth:`state_dict` (``features``: the unpacked table). A training state
        needs ``records``, which gives the records of the image named by the first row of each source;
        ValueError (or another of ``DAMAGED``) for a damaged state."""
        chosen = [features[stored_position(i, len(features))] for i in state["features"]]
        width, training = len(chosen), "images" in state
        n = len(state["images"]) if training else 0
        models = [None if m is None else FeatureModel.from_dict(m, n if training else None) for m in state["models"]]
        if len(models) != width:
            raise ValueError(f"{width} features but {len(models)} models")
        self.features, self.models = chosen, models
        self.quality = decode_array(state["quality"], shape=(4, width))
        if not training:
            self.born, self.used = [0] * width, [0] * width
            return
        if records is None:
            raise ValueError("a training state needs the records of its images")
        images = [_name_from_json(i) for i in state["images"]]
        if len(set(images)) != n:
            raise ValueError("an image name occurs twice in the instance list")
        first = [stored_position(r, n) for r in state["first_row"]]
        rows = [stored_position(s, len(first)) for s in state["source_of_row"]]
        if len(rows) != n or any(rows[r] != s for s, r in enumerate(first)) or first != sorted(set(first)):
            raise ValueError("the rows' sources do not match the sources' first rows")
        counts = [state[k] for k in ("grasps", "sampled")] + list(state["born"]) + list(state["used"])
        if len(state["born"]) != width or len(state["used"]) != width or \
                any(isinstance(v, bool) or not isinstance(v, int) or v < -1 for v in counts):
            raise ValueError("born, used, grasps and sampled must be integers, one born and used per feature")
        self._fill(images, *(decode_array(state[k], shape=shape) for k, shape in
                             (("values", (n, width)), ("thetas", (n, width)), ("outcomes", (n, 3)))))
        self._source_of_row, self._first_row = rows, first
        for source, row in enumerate(first):
            found = records(images[row])
            if not isinstance(found, ImageRecords) or len(found) != 1:
                raise ValueError(f"no records of one image for {images[row]!r}")
            self._source_index[id(found)] = source
            self._sources.append(found)
        self.born, self.used = list(state["born"]), list(state["used"])
        self.grasps, self.sampled = state["grasps"], state["sampled"]

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


def _name_to_json(name):
    """An image name of the instance list as JSON (a tuple as a list); InputError for other than
    strings, numbers, None and tuples of them."""
    if isinstance(name, tuple):
        return [_name_to_json(part) for part in name]
    if name is None or isinstance(name, (str, int, float)):
        return name
    raise InputError(f"image name {name!r}: a training state holds names that are strings, numbers or tuples of them")


def _name_from_json(name):
    """Inverse of :func:`_name_to_json`."""
    return tuple(_name_from_json(part) for part in name) if isinstance(name, list) else name


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
        self.settings = (GraspSettings() if settings is None else settings).replace(**options)
        if isinstance(seed, bool) or not isinstance(seed, (int, np.integer)) or seed < 0:
            raise InputError(f"seed must be an integer of at least 0, got {seed!r}")
        self.seed, self.device = int(seed), as_device(device)
        self.generator = torch.Generator()
        self._blank()

    def _blank(self) -> None:
        """The state before any grasp: empty sets, the generator at ``seed``."""
        self.sets = {c: GraspFeatureSet(c) for c in FINGERS}
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
        splits; with ``training``, all that learning reads too (:meth:`GraspFeatureSet.state_dict`), the
        seed and the generator's state, so that a learner restored by :meth:`load_state_dict` learns on
        exactly as this one would (the images themselves are not held: the caller gives their records)."""
        if training and not self.trainable:
            raise InputError("this grasp learner was loaded without its past grasps: it has no training state")
        table = FeatureTable()
        sets = [s.state_dict(table, training) for s in self.sets.values()]
        state = {"settings": self.settings.to_dict(), "sets": sets, "features": table.pack()}
        if training:
            generator = self.generator.get_state().numpy().astype(np.float64)
            state.update({"seed": self.seed, "generator": encode_array(generator)})
        return state

    def load_state_dict(self, state: dict, records: Callable[[Hashable], ImageRecords] | None = None) -> None:
        """Restore :meth:`state_dict` into this learner (its settings are read from the state). A training
        state needs ``records``: the records of an image of the instance list, by its name. ValueError
        (or another of ``ftorch.checkpoint.DAMAGED``) for a damaged state."""
        self.settings = GraspSettings(**state["settings"])
        training = "generator" in state
        if training:
            self.seed = int(state["seed"])
        self._blank()
        features = unpack_features(state["features"])
        if sorted(r["fingers"] for r in state["sets"]) != list(FINGERS):
            raise ValueError(f"sets {[r['fingers'] for r in state['sets']]}, expected one for each of {FINGERS}")
        for record in state["sets"]:
            self.sets[record["fingers"]].load_state_dict(record, features, records if training else None)
        if training:
            generator = decode_array(state["generator"], shape=GENERATOR_STATE)
            self.generator.set_state(torch.from_numpy(generator.astype(np.uint8)))
        self.trainable = training

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
        try:
            learner.load_state_dict({k: data[k] for k in ("settings", "sets", "features")})
        except DAMAGED as err:
            raise InputError(f"{path}: damaged grasp learner ({type(err).__name__}: {err})") from None
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
        if self.settings.finger_choice is FingerChoice.THESIS:
            expected = feature_set._model_arrays()[2][chosen] if len(feature_set) else np.zeros(len(values))
        else:
            expected = feature_set.pooled_mu0(present)
            if self.settings.finger_choice is FingerChoice.QUALITY:
                quality, behind = feature_set.quality_mu0(values)
                expected = np.where(np.isfinite(quality), quality, expected)
        return chosen, behind, expected

    def _cue(self, c: int, i: int, j: int, thetas: np.ndarray, expected: np.ndarray) -> Recommendation:
        """Steps 3-4 for image i of a batch (B, F) whose f*_c is feature j of set c."""
        model = self.sets[c].models[j]
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
