"""The task environment the learner acts in (4.4): labelled images, their records and feature values.

Feature values are cached: each (feature, image) value is computed once, in one batch with the
other values missing at that call, and never recomputed. A call for one image (a recognition)
computes its missing features on all images of the set. Batched float arithmetic may differ
in the last bit with the batch's composition, so this rule is what makes a run reproducible and
resumable bit for bit: the cache is part of a run's state (:meth:`ImageSet.cache_state`).
"""
from __future__ import annotations

from collections.abc import Hashable, Iterable, Sequence
from pathlib import Path

import numpy as np
import torch

from .checkpoint import decode_array, encode_array, stored_position
from .errors import InputError
from .evaluate import feature_values
from .features import Feature, FeatureTable, unpack_features
from .images import as_image_batch, load_image
from .record import FeatureSpace, ImageRecords


class ImageSet:
    """Images with their sets of true classes; records are computed once, on construction.

    ``images`` are file paths, arrays or tensors of any sizes; ``names`` default to the file
    names (or ``image N``). ``records``: these images' records where they were computed before
    (``space.records(images)``, e.g. once for the folds that share the images); they are used
    as they are, shared, not copied. ``examples(label, n)`` draws n random images containing
    ``label`` (alg. 4.8 step 2).
    """

    def __init__(self, images: Sequence, labels: Sequence[Iterable[Hashable]], space: FeatureSpace | None = None,
                 names: Sequence[str] | None = None, progress: bool = False, records: ImageRecords | None = None):
        if len(images) != len(labels):
            raise InputError(f"{len(images)} images but {len(labels)} label sets")
        if len(images) == 0:
            raise InputError("image set: no images")
        if records is not None and len(records) != len(images):
            raise InputError(f"{len(images)} images but {len(records)} records")
        self.labels = [frozenset(l) for l in labels]
        self.names = list(names) if names is not None else [
            Path(x).name if isinstance(x, (str, Path)) else f"image {i}" for i, x in enumerate(images)]
        sources = [str(x) if isinstance(x, (str, Path)) else name for x, name in zip(images, self.names)]
        self.images = [self._grey(x, source) for x, source in zip(images, sources)]
        self.space = space or FeatureSpace()
        if records is None:
            with torch.no_grad():
                records = self.space.records(self.images, progress=progress, names=sources)
        self.all_records = records
        self._single: dict[int, ImageRecords] = {}
        self._row: dict[Feature, int] = {}
        self._cache = np.zeros((0, len(self.labels)))

    @staticmethod
    def _grey(item, name: str) -> torch.Tensor:
        if isinstance(item, (str, Path)):
            return load_image(item)
        return as_image_batch(item, name)[0, 0]

    def __len__(self) -> int:
        return len(self.labels)

    def classes(self) -> list:
        """All classes that occur, sorted."""
        return sorted({c for labels in self.labels for c in labels}, key=str)

    def record(self, image: int) -> ImageRecords:
        if image not in self._single:
            self._single[image] = self.all_records[image]
        return self._single[image]

    def records(self, images: Sequence[int]) -> ImageRecords:
        return self.all_records[torch.tensor(list(images), device=self.all_records.device)]

    def values(self, features: Sequence[Feature], images: Sequence[int]) -> np.ndarray:
        """Feature values (F, len(images)), eq. 3.14: cached ones as they are, missing ones in one batch."""
        features, images = list(features), list(images)
        for f in features:
            if f not in self._row:
                self._row[f] = len(self._row)
        if len(self._row) > len(self._cache):
            grown = np.full((max(len(self._row), 2 * len(self._cache)), len(self)), np.nan)
            grown[: len(self._cache)] = self._cache
            self._cache = grown
        rows = np.array([self._row[f] for f in features], dtype=np.int64)
        block = self._cache[np.ix_(rows, images)]
        missing = [features[j] for j in np.flatnonzero(np.isnan(block).any(1))]
        if missing:
            missing = list(dict.fromkeys(missing))
            # one image asked for (a recognition): measure the missing features on every image at
            # once, since recognizing the others will ask for them too and a batch costs far less
            batch = list(range(len(self))) if len(images) == 1 else images
            computed = self._compute(missing, batch)
            for f, row in zip(missing, computed):
                current = self._cache[self._row[f], batch]
                self._cache[self._row[f], batch] = np.where(np.isnan(current), row, current)
            block = self._cache[np.ix_(rows, images)]
        return block

    def _compute(self, features: list[Feature], images: list[int]) -> np.ndarray:
        if len(images) == 1:
            records = self.record(images[0])
        else:
            records = self.all_records if images == list(range(len(self))) else self.records(images)
        return feature_values(features, records).values.double().cpu().numpy()

    def cache_state(self, table: FeatureTable | None = None) -> dict:
        """The value cache as JSON-ready data: the features, by position in ``table`` (or in a
        table of its own, written as "table"), and the exact values."""
        own = table is None
        table = FeatureTable() if own else table
        features = list(self._row)  # in row order: rows are only ever added
        state = {"features": [table.index(f) for f in features], "values": encode_array(self._cache[: len(features)])}
        if own:
            state["table"] = table.pack()
        return state

    def load_cache_state(self, state: dict, features: list[Feature] | None = None) -> None:
        """Restore a cache written by :meth:`cache_state` for this same image set (``features``:
        the table it was written against, where the caller kept one)."""
        try:
            known = unpack_features(state["table"]) if features is None else features
            features = [known[stored_position(i, len(known))] for i in state["features"]]
            table = decode_array(state["values"])
        except (KeyError, TypeError, ValueError, IndexError, OverflowError) as err:
            raise InputError(f"value cache is damaged: {err}") from None
        if table.shape != (len(features), len(self)):
            raise InputError(f"value cache holds {table.shape}, expected ({len(features)}, {len(self)}) for this image set")
        if not np.all(np.isnan(table) | ((table >= 0) & (table <= 1 + 1e-6))):  # NaN: not yet measured
            raise InputError("value cache is damaged: values outside [0, 1] (feature values are similarities, eq. 3.13)")
        self._row = {f: i for i, f in enumerate(features)}
        self._cache = table

    def examples(self, label: Hashable, n: int, generator: torch.Generator) -> list[int]:
        """Up to n distinct random images whose true classes include ``label``."""
        pool = [i for i, labels in enumerate(self.labels) if label in labels]
        order = torch.randperm(len(pool), generator=generator).tolist()
        return [pool[i] for i in order[:n]]
