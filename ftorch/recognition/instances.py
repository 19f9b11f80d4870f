"""Instance tables (4.4.1, 6.4): the learners count every probability from them.

:class:`InstanceList` is the recognition learner's: one row per distinct image (an image's
feature values never change, so presenting it again adds no information), holding its true
classes and the values of the features measured on it so far; values not measured are NaN and
are left out of every count. Both it and the grasp learner's tables grow in rows and columns
through :class:`GrowingTable`, which doubles its store instead of copying on every row.
"""
from __future__ import annotations

from collections.abc import Hashable, Iterable

import numpy as np


def are_stored_values(values: np.ndarray) -> bool:
    """Whether every entry of a stored value table is NaN (not measured) or a feature value: a
    similarity in [0, 1] (eq. 3.13), allowing for cosines that round just above 1."""
    return bool(np.all(np.isnan(values) | ((values >= 0) & (values <= 1 + 1e-6))))


class GrowingTable:
    """A 2-D float table (``dtype``, float64 by default) whose rows and columns are appended; the
    store doubles when full, so n appends copy O(n) values in all. :attr:`array` is the used corner
    (a view: writes go through)."""

    def __init__(self, columns: int = 0, fill: float = np.nan, dtype=np.float64):
        self.fill = fill
        self.rows, self.columns = 0, columns
        self._store = np.full((0, columns), fill, dtype=dtype)

    @property
    def array(self) -> np.ndarray:
        return self._store[: self.rows, : self.columns]

    def _reserve(self, rows: int, columns: int) -> None:
        have_rows, have_columns = self._store.shape
        if rows > have_rows or columns > have_columns:
            grown = np.full((have_rows if rows <= have_rows else max(rows, 2 * have_rows),
                             have_columns if columns <= have_columns else max(columns, 2 * have_columns)), self.fill,
                            dtype=self._store.dtype)
            grown[:have_rows, :have_columns] = self._store
            self._store = grown

    def add_rows(self, block: np.ndarray) -> None:
        """Append rows (k, columns)."""
        block = np.asarray(block)
        self._reserve(self.rows + len(block), self.columns)
        self._store[self.rows: self.rows + len(block), : self.columns] = block
        self.rows += len(block)

    def add_columns(self, block: np.ndarray) -> None:
        """Append columns (rows, k)."""
        block = np.asarray(block)
        self._reserve(self.rows, self.columns + block.shape[1])
        self._store[: self.rows, self.columns: self.columns + block.shape[1]] = block
        self.columns += block.shape[1]

    def keep_columns(self, keep) -> None:
        """Keep only the columns ``keep`` (indices or a boolean mask), in their order."""
        kept = self.array[:, keep]
        self._store[: self.rows, : self.columns] = self.fill
        self.columns = kept.shape[1]
        self._store[: self.rows, : self.columns] = kept


class InstanceList:
    def __init__(self):
        self.images: list[Hashable] = []
        self.labels: list[frozenset] = []
        self.features: list[Hashable] = []
        self._row: dict[Hashable, int] = {}
        self._column: dict[Hashable, int] = {}
        self._table = GrowingTable()  # (instances, features), NaN where not measured

    @property
    def _values(self) -> np.ndarray:
        return self._table.array

    def __len__(self) -> int:
        return len(self.images)

    def add(self, image: Hashable, labels: Iterable[Hashable]) -> int:
        """Row of ``image``, added with its true classes if new."""
        if image in self._row:
            return self._row[image]
        self._table.add_rows(np.full((1, len(self.features)), np.nan))
        self._row[image] = len(self.images)
        self.images.append(image)
        self.labels.append(frozenset(labels))
        return self._row[image]

    def column(self, feature: Hashable) -> int:
        if feature not in self._column:
            self._table.add_columns(np.full((len(self.images), 1), np.nan))
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
        self._table.keep_columns(keep)
        self.features = [f for f, k in zip(self.features, keep) if k]
        self._column = {f: i for i, f in enumerate(self.features)}
