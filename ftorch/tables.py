"""Tables that grow by doubling: the instance tables of the recognition and grasp learners (4.4.1,
6.4) and the recognition value cache append rows and columns without copying on every one."""
from __future__ import annotations

import numpy as np


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

    def keep_rows(self, keep) -> None:
        """Keep only the rows ``keep`` (indices or a boolean mask), in their order; only the rows
        vacated at the end are refilled."""
        kept = self.array[keep]
        self._store[: len(kept), : self.columns] = kept
        self._store[len(kept) : self.rows, : self.columns] = self.fill
        self.rows = len(kept)

    def keep_columns(self, keep) -> None:
        """Keep only the columns ``keep`` (indices or a boolean mask), in their order; only the
        columns vacated at the end are refilled."""
        kept = self.array[:, keep]
        self._store[: self.rows, : kept.shape[1]] = kept
        self._store[: self.rows, kept.shape[1] : self.columns] = self.fill
        self.columns = kept.shape[1]
