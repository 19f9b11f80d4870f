"""F_c, the features of one finger count c with their instance list (6.4.1, alg. 6.2).

Per experienced grasp the instance list holds the value and orientation of every feature of the set
in that grasp's image, the final hand orientation theta_H, the quality mu_0 (capped at ``MU0_CAP``)
and the grasp's symmetry period (prediction errors are taken modulo it, 6.5.1). The set fits its
features' models on it (ftorch/grasp/models.py) and answers step 2b for an image's measurements;
ftorch/grasp/learner.py's module doc gives the decisions, ftorch/grasp/state.py saves and restores it.
"""
from __future__ import annotations

import math
from typing import NamedTuple, Sequence

import numpy as np

from ..errors import InputError
from ..space.evaluate import feature_values
from ..space.features import Feature
from ..space.record import ImageRecords
from ..tables import GrowingTable
from .models import FeatureModel, fit_models, quality_splits
from .settings import MU0_CAP, FingerChoice


class Experience(NamedTuple):
    """What the haptic system reports after a grasp (alg. 6.2 step 5)."""

    fingers: int
    theta_H: float
    mu0: float
    period: float


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
        feature_set.fill(list(range(n)), values, thetas, np.stack([theta_H, np.minimum(mu0, MU0_CAP), period], 1))
        return feature_set

    def fill(self, images: list, values: np.ndarray, thetas: np.ndarray, outcomes: np.ndarray,
             sources: Sequence[ImageRecords] = (), first_row: Sequence[int] = (), source_of_row: Sequence[int] = ()) -> None:
        """The instance list of an empty set: ``images`` and their rows (values and thetas (n, F), outcomes (n, 3));
        the distinct image records ``sources`` (which new features are measured on), the first row of each
        and each row's source."""
        self.images, self._seen = list(images), set(images)
        for table, rows in ((self._values, values), (self._thetas, thetas)):
            table.add_columns(np.zeros((0, np.shape(rows)[1])))
            table.add_rows(rows)
        self._outcomes.add_rows(outcomes)
        self._first_row, self._source_of_row = list(first_row), list(source_of_row)
        for source, found in enumerate(sources):
            self._source_index[id(found)] = source
            self._sources.append(found)

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
    def outcomes(self) -> np.ndarray:
        """(instances, 3): theta_H, mu_0 (capped) and the symmetry period of each grasp (read-only)."""
        return self._read_only(self._outcomes.array)

    def sources(self) -> tuple[list[int], list[int]]:
        """The first row of each distinct image's records, and each row's source (which :meth:`fill` takes)."""
        return list(self._first_row), list(self._source_of_row)

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

    def step_2b(self, values: np.ndarray, thetas: np.ndarray, finger_choice: FingerChoice
                ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Step 2b on each image's measurements (B, F): f*_c (B,; -1 where none is present), the feature
        whose quality split gave E[mu_0] (B,; -1 where none did) and E[mu_0] (B,), by ``finger_choice``
        ("quality" falls back on "pooled" where no quality split is measured)."""
        present = self.present(values, thetas)
        chosen, behind = self.choose(present), np.full(len(values), -1)
        if finger_choice is FingerChoice.THESIS:
            expected = self._model_arrays()[2][chosen] if len(self) else np.zeros(len(values))
        else:
            expected = self.pooled_mu0(present)
            if finger_choice is FingerChoice.QUALITY:
                quality, behind = self.quality_mu0(values)
                expected = np.where(np.isfinite(quality), quality, expected)
        return chosen, behind, expected

    def fit(self, t_dtheta: float, max_k: int, min_points: int) -> None:
        """Alg. 6.1 for every feature of the set, batched (:func:`~ftorch.grasp.models.fit_models`)."""
        if self.features and self.images:
            self.models = fit_models(self.models, self.values, self.thetas, self.theta_H, self.mu0, self.period,
                                     t_dtheta, max_k, min_points)

    def fit_quality(self, mu0_split: float, min_points: int) -> None:
        """Every feature's quality split (:func:`~ftorch.grasp.models.quality_splits`; none without instances)."""
        if not self.features or not self.images:
            self.quality = np.zeros((4, len(self)))
            return
        self.quality = quality_splits(self.values, self.mu0, mu0_split, min_points)

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
        self._outcomes.add_rows(np.array([[experience.theta_H, min(experience.mu0, MU0_CAP), experience.period]]))

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
