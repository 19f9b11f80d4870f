"""The feature-value cache of an image set: part of a run's state."""
from __future__ import annotations

from collections.abc import Callable, Sequence

import numpy as np

from ..checkpoint import Memo, decode_array, encode_array, stored_position
from ..errors import InputError
from ..space.features import Feature, FeatureTable, unpack_features
from ..tables import GrowingTable
from .instances import are_stored_values


class ValueCache:
    """Feature values (eq. 3.14) of ``images`` images: one row per feature, in the order first
    asked for, one column per image, NaN where not yet measured. They are stored as ``dtype``, the
    precision they are computed in (float32 for a float32 feature space: exact, and half the
    memory of float64), and handed out as float64.

    Each (feature, image) value is computed once, in one batch with the other values missing at
    that call, and never recomputed. A call for one image (a recognition) computes its missing
    features on all images. Batched float arithmetic may differ in the last bit with the batch's
    composition, so this rule is what makes a run reproducible and resumable bit for bit: the
    cache is part of a run's state (:meth:`state_dict`).
    """

    def __init__(self, images: int, dtype=np.float64) -> None:
        self.images = images
        self.dtype = np.dtype(dtype)
        self._row: dict[Feature, int] = {}
        self._table = GrowingTable(images, dtype=self.dtype)
        self.memo = Memo()  # the blocks of its checkpoints so far: only the grown ones are compressed again

    def __len__(self) -> int:
        return len(self._row)

    def values(self, features: Sequence[Feature], images: Sequence[int],
               compute: Callable[[list[Feature], list[int]], np.ndarray]) -> np.ndarray:
        """Values (F, len(images)): cached ones as they are, missing ones by one call of
        ``compute(features, images)``, which returns their values (F, len(images))."""
        features, images = list(features), list(images)
        for f in features:
            if f not in self._row:
                self._row[f] = len(self._row)
        if len(self._row) > self._table.rows:
            self._table.add_rows(np.full((len(self._row) - self._table.rows, self.images), np.nan))
        table = self._table.array
        rows = np.array([self._row[f] for f in features], dtype=np.int64)
        columns = np.asarray(images)
        block = table[np.ix_(rows, columns)]
        missing = [features[j] for j in np.flatnonzero(np.isnan(block).any(1))]
        if missing:
            missing = list(dict.fromkeys(missing))
            # one image asked for (a recognition): measure the missing features on every image at
            # once, since recognizing the others will ask for them too and a batch costs far less
            batch = list(range(self.images)) if len(images) == 1 else images
            computed = compute(missing, batch)
            for f, row in zip(missing, computed):
                current = table[self._row[f], batch]
                table[self._row[f], batch] = np.where(np.isnan(current), row, current)
            block = table[np.ix_(rows, columns)]
        return block.astype(np.float64, copy=False)

    def extended(self, images: int) -> "ValueCache":
        """A copy for these images followed by ``images`` more: their values not yet measured."""
        out = ValueCache(self.images + images, self.dtype)
        out._row = dict(self._row)
        out._table.add_rows(np.concatenate([self._table.array, np.full((len(self._row), images), np.nan, self.dtype)], 1))
        return out

    def stored(self, features: Sequence[Feature], images: Sequence) -> np.ndarray:
        """The values held for ``features`` on ``images`` (F, n), in storage precision, NaN where none
        is (a feature not asked for yet, an image that is not one of the indices); computes nothing."""
        out = np.full((len(features), len(images)), np.nan, dtype=self.dtype)
        rows = [(k, self._row[f]) for k, f in enumerate(features) if f in self._row]
        columns = [(k, i) for k, i in enumerate(images)
                   if isinstance(i, (int, np.integer)) and not isinstance(i, bool) and 0 <= i < self.images]
        if rows and columns:
            (at, row), (to, column) = zip(*rows), zip(*columns)
            out[np.ix_(at, to)] = self._table.array[np.ix_(row, column)]
        return out

    def table(self) -> FeatureTable:
        """A feature table that starts with this cache's features at their rows (built without
        hashing them: a checkpoint of many thousand features writes them once, cheaply)."""
        return FeatureTable(self._row, self.memo)

    def state_dict(self, table: FeatureTable | None = None) -> dict:
        """The cache as JSON-ready data: the features, by position in ``table`` (or in a table of
        its own, written as "table"), and the exact values."""
        own = table is None
        if table is None:
            table = self.table()
        features = list(self._row)  # in row order: rows are only ever added
        # a table from table() holds them at their rows: compared by identity, nothing hashed
        positions = range(len(features)) if table.features[: len(features)] == features else map(table.index, features)
        state = {"features": list(positions), "values": encode_array(self._table.array, memo=self.memo)}
        if own:
            state["table"] = table.pack()
        return state

    def load_state_dict(self, state: dict, features: list[Feature] | None = None) -> None:
        """Restore a cache written by :meth:`state_dict` for the same images (``features``: the
        table it was written against, where the caller kept one)."""
        try:
            known = unpack_features(state["table"], self.memo) if features is None else features
            features = [known[stored_position(i, len(known))] for i in state["features"]]
            values = decode_array(state["values"], shape=(len(features), self.images))
        except (KeyError, TypeError, ValueError, IndexError, OverflowError) as err:
            raise InputError(f"value cache is damaged: {err}") from None
        if not are_stored_values(values):
            raise InputError("value cache is damaged: values outside [0, 1] (feature values are similarities, eq. 3.13)")
        if not np.array_equal(values.astype(self.dtype), values, equal_nan=True):
            raise InputError(f"value cache holds values that {self.dtype} storage cannot hold exactly: "
                             "written by a feature space of another precision")
        row = {f: i for i, f in enumerate(features)}
        if len(row) < len(features):
            raise InputError("value cache is damaged: a feature listed twice")
        self._row = row
        self._table = GrowingTable(self.images, dtype=self.dtype)
        self._table.add_rows(values)
