"""The instance list (4.4.1): every probability the learner uses is counted from it.

One row per distinct image (an image's feature values never change, so presenting it again
adds no information), holding its true classes and the values of the features measured on it
so far; values not measured are NaN and are left out of every count.
"""
from __future__ import annotations

from collections.abc import Hashable, Iterable

import numpy as np


class InstanceList:
    def __init__(self):
        self.images: list[Hashable] = []
        self.labels: list[frozenset] = []
        self.features: list[Hashable] = []
        self._row: dict[Hashable, int] = {}
        self._column: dict[Hashable, int] = {}
        self._store = np.full((0, 0), np.nan)  # grows by doubling; the table is its used corner

    @property
    def _values(self) -> np.ndarray:
        """The table (instances, features), a view of the store."""
        return self._store[: len(self.images), : len(self.features)]

    def _reserve(self, rows: int, columns: int) -> None:
        have_rows, have_columns = self._store.shape
        if rows > have_rows or columns > have_columns:
            grown = np.full((have_rows if rows <= have_rows else max(rows, 2 * have_rows),
                             have_columns if columns <= have_columns else max(columns, 2 * have_columns)), np.nan)
            grown[: self._store.shape[0], : self._store.shape[1]] = self._store
            self._store = grown

    def __len__(self) -> int:
        return len(self.images)

    def add(self, image: Hashable, labels: Iterable[Hashable]) -> int:
        """Row of ``image``, added with its true classes if new."""
        if image in self._row:
            return self._row[image]
        self._reserve(len(self.images) + 1, len(self.features))
        self._row[image] = len(self.images)
        self.images.append(image)
        self.labels.append(frozenset(labels))
        return self._row[image]

    def column(self, feature: Hashable) -> int:
        if feature not in self._column:
            self._reserve(len(self.images), len(self.features) + 1)
            self._column[feature] = len(self.features)
            self.features.append(feature)
        return self._column[feature]

    def set(self, image: Hashable, feature: Hashable, value: float) -> None:
        column = self.column(feature)  # may widen the array: look it up first
        self._values[self._row[image], column] = value

    def set_block(self, images: list, features: list, values: np.ndarray) -> None:
        """Set the values (len(features), len(images)) of several features on several images at once."""
        columns = [self.column(f) for f in features]  # may widen the array: look them up first
        rows = [self._row[i] for i in images]
        self._values[np.ix_(rows, columns)] = np.asarray(values, dtype=float).T

    def get(self, image: Hashable, feature: Hashable) -> float:
        """Value of ``feature`` on ``image``, NaN if not measured (or unknown)."""
        row, column = self._row.get(image), self._column.get(feature)
        return np.nan if row is None or column is None else float(self._values[row, column])

    def values(self, feature: Hashable) -> np.ndarray:
        """Values of one feature over all instances (n,), NaN where not measured."""
        column = self._column.get(feature)
        return np.full(len(self), np.nan) if column is None else self._values[:, column].copy()

    def block(self, features: list) -> np.ndarray:
        """Values of several features over all instances (F, n), NaN where not measured."""
        out = np.full((len(features), len(self)), np.nan)
        known = [(i, self._column[f]) for i, f in enumerate(features) if f in self._column]
        if known:
            rows, columns = zip(*known)
            out[list(rows)] = self._values[:, list(columns)].T
        return out

    def values_table(self) -> np.ndarray:
        """All values (instances, features), NaN where not measured."""
        return self._values.copy()

    def has(self, label: Hashable) -> np.ndarray:
        """(n,) bool: instances whose true classes include ``label``."""
        return np.array([label in labels for labels in self.labels], dtype=bool)

    def has_any(self, labels: Iterable[Hashable]) -> np.ndarray:
        labels = set(labels)
        return np.array([bool(labels & own) for own in self.labels], dtype=bool)

    def forget(self, features: Iterable[Hashable]) -> None:
        """Drop features' columns (discarded features); unknown ones are ignored."""
        columns = [self._column[f] for f in features if f in self._column]
        if not columns:
            return
        keep = np.ones(len(self.features), dtype=bool)
        keep[columns] = False
        kept = self._values[:, keep]
        self._store[:, : len(self.features)] = np.nan
        self.features = [f for f, k in zip(self.features, keep) if k]
        self._store[: len(self.images), : len(self.features)] = kept
        self._column = {f: i for i, f in enumerate(self.features)}
