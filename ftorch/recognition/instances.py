"""Instance tables (4.4.1, 6.4): the learners count every probability from them.

:class:`InstanceList` is the recognition learner's: one instance per distinct image (an image's
feature values never change, so presenting it again adds no information), holding its true
classes and the values of the features measured on it so far; values not measured are NaN and
are left out of every count. Both it and the grasp learner's tables grow in rows and columns
through :class:`~ftorch.tables.GrowingTable`, which doubles its store instead of copying on every row.
"""
from __future__ import annotations

from collections.abc import Hashable, Iterable, Sequence

import numpy as np

from ..tables import GrowingTable


def are_stored_values(values: np.ndarray) -> bool:
    """Whether every entry of a stored value table is NaN (not measured) or a feature value: a
    similarity in [0, 1] (eq. 3.13), allowing for cosines that round just above 1."""
    return bool(np.all(np.isnan(values) | ((values >= 0) & (values <= 1 + 1e-6))))


class InstanceList:
    """The instances (images with their true classes) and the values of the features measured on
    them. Stored feature by feature, (features, instances): the counts read the values of a few
    features over all instances (a feature's values are one contiguous row) and discarding
    features drops rows; :meth:`values_table` gives the (instances, features) table."""

    def __init__(self) -> None:
        self.images: list[Hashable] = []
        self.labels: list[frozenset] = []
        self.features: list[Hashable] = []
        self._image: dict[Hashable, int] = {}  # image -> its column of the table
        self._feature: dict[Hashable, int] = {}  # feature -> its row of the table
        self._table = GrowingTable()  # (features, instances), NaN where not measured

    @property
    def _values(self) -> np.ndarray:
        return self._table.array

    def __len__(self) -> int:
        return len(self.images)

    def add(self, image: Hashable, labels: Iterable[Hashable]) -> int:
        """Index of ``image`` (its column), added with its true classes if new."""
        if image in self._image:
            return self._image[image]
        self._table.add_columns(np.full((len(self.features), 1), np.nan))
        self._image[image] = len(self.images)
        self.images.append(image)
        self.labels.append(frozenset(labels))
        return self._image[image]

    def _feature_row(self, feature: Hashable) -> int:
        if feature not in self._feature:
            self._table.add_rows(np.full((1, len(self.images)), np.nan))
            self._feature[feature] = len(self.features)
            self.features.append(feature)
        return self._feature[feature]

    def column(self, image: Hashable) -> int:
        """The column of an instance already added."""
        return self._image[image]

    def set(self, image: Hashable, feature: Hashable, value: float) -> None:
        row = self._feature_row(feature)  # may grow the array: look it up first
        self._values[row, self._image[image]] = value

    def set_block(self, images: list, features: list, values: np.ndarray) -> None:
        """Set the values (len(features), len(images)) of several features on several images at once."""
        rows = [self._feature_row(f) for f in features]  # may grow the array: look them up first
        columns = [self._image[i] for i in images]
        self._values[np.ix_(rows, columns)] = np.asarray(values, dtype=float)

    def get(self, image: Hashable, feature: Hashable) -> float:
        """Value of ``feature`` on ``image``, NaN if not measured (or unknown)."""
        row, column = self._feature.get(feature), self._image.get(image)
        return np.nan if row is None or column is None else float(self._values[row, column])

    def values(self, feature: Hashable) -> np.ndarray:
        """Values of one feature over all instances (n,), NaN where not measured."""
        row = self._feature.get(feature)
        return np.full(len(self), np.nan) if row is None else self._values[row].copy()

    def block(self, features: Sequence[Hashable]) -> np.ndarray:
        """Values of several features over all instances (F, n), NaN where not measured."""
        out = np.full((len(features), len(self)), np.nan)
        known = [(i, self._feature[f]) for i, f in enumerate(features) if f in self._feature]
        if known:
            at, rows = zip(*known)
            out[list(at)] = self._values[list(rows)]
        return out

    def values_table(self) -> np.ndarray:
        """All values (instances, features), NaN where not measured: the stored table transposed,
        copied 128 features at a time (faster than one transposed copy: docs/benchmark.md, "Design
        choices measured once")."""
        values = self._values
        out = np.empty(values.shape[::-1])
        for s in range(0, len(values), 128):
            out[:, s : s + 128] = values[s : s + 128].T
        return out

    def has(self, label: Hashable) -> np.ndarray:
        """(n,) bool: instances whose true classes include ``label``."""
        return np.array([label in labels for labels in self.labels], dtype=bool)

    def has_any(self, labels: Iterable[Hashable]) -> np.ndarray:
        labels = set(labels)
        return np.array([bool(labels & own) for own in self.labels], dtype=bool)

    def forget(self, features: Iterable[Hashable]) -> None:
        """Drop features' rows (discarded features); unknown ones are ignored."""
        rows = [self._feature[f] for f in features if f in self._feature]
        if not rows:
            return
        keep = np.ones(len(self.features), dtype=bool)
        keep[rows] = False
        self._table.keep_rows(keep)
        self.features = [f for f, k in zip(self.features, keep) if k]
        self._feature = {f: i for i, f in enumerate(self.features)}
