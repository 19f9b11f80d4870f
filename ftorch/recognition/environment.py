"""The task environment the learner acts in (4.4): labelled images and their records.

Feature values come through the set's :class:`~ftorch.recognition.value_cache.ValueCache`, which computes
each value once and is part of a run's state (:meth:`ImageSet.cache_state`).
"""
from __future__ import annotations

from collections.abc import Hashable, Iterable, Sequence
from pathlib import Path

import numpy as np
import torch

from ..errors import InputError
from ..images import as_image
from ..space.evaluate import values_only
from ..space.features import Feature, FeatureTable
from ..space.record import FeatureSpace, ImageRecords
from .value_cache import ValueCache


class ImageSet:
    """Images with their sets of true classes; records are computed once, on construction.

    ``images`` are file paths, arrays or tensors of any sizes, one image each
    (:func:`ftorch.images.as_image`); ``labels`` give each image's true classes: a set (or list) of
    labels, or one label, any hashable value (``"cube"``, ``3``): a string is one label, never its
    letters. Without ``labels`` (images to recognize) ``labeled`` is False and learning refuses them.
    ``names`` default to the file names (or ``image N``). ``records``: these images' records where they were computed before
    (``space.records(images)``, e.g. once for the folds that share the images); they are used
    as they are, shared, not copied. ``examples(label, n)`` draws n random images containing
    ``label`` (alg. 4.8 step 2).
    """

    def __init__(self, images: Sequence, labels: Sequence[Iterable[Hashable]] | None = None,
                 space: FeatureSpace | None = None, names: Sequence[str] | None = None, progress: bool = False,
                 records: ImageRecords | None = None):
        if isinstance(images, (str, Path)):
            raise InputError(f"images {str(images)!r}: expected a sequence of images (files, arrays or tensors), "
                             "not one path")
        if isinstance(labels, (str, bytes)):
            raise InputError(f"labels {labels!r}: expected one label (or set of labels) per image, not one string")
        self.labeled = labels is not None
        labels = [frozenset()] * len(images) if labels is None else labels
        if len(images) != len(labels):
            raise InputError(f"{len(images)} images but {len(labels)} label sets")
        if len(images) == 0:
            raise InputError("image set: no images")
        if records is not None and len(records) != len(images):
            raise InputError(f"{len(images)} images but {len(records)} records")
        if names is not None and (isinstance(names, (str, bytes)) or len(names) != len(images)):
            raise InputError(f"{len(images)} images but {1 if isinstance(names, (str, bytes)) else len(names)} names: "
                             "give one name per image")
        self.labels = [_label_set(label, i) for i, label in enumerate(labels)]
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
        self._cache = ValueCache(len(self.labels), torch.empty(0, dtype=records.dtype).numpy().dtype)

    def extended(self, other: "ImageSet") -> "ImageSet":
        """These images followed by ``other``'s, in one set: positions here keep their meaning, the
        values cached here are kept, and both sets' records are joined, not recomputed."""
        if self.labeled != other.labeled:
            raise InputError("cannot join a labelled image set and an unlabelled one")
        joined = object.__new__(ImageSet)
        joined.labeled, joined.space = self.labeled, self.space
        joined.labels, joined.names, joined.images = (self.labels + other.labels, self.names + other.names,
                                                      self.images + other.images)
        joined.all_records = ImageRecords.cat([self.all_records, other.all_records.to(self.all_records.device)])
        joined._single = {}
        joined._cache = self._cache.extended(len(other))
        return joined

    @staticmethod
    def _grey(item, name: str) -> torch.Tensor:
        return as_image(item, name)

    def index(self, image) -> int:
        """``image`` as a position in this set; InputError unless an integer from 0 to len - 1 (a
        negative one would silently mean another image)."""
        if isinstance(image, bool) or not isinstance(image, (int, np.integer)) or not 0 <= image < len(self):
            raise InputError(f"image {image!r}: expected a position in this image set, an integer from 0 to {len(self) - 1}")
        return int(image)

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

    @property
    def cache(self) -> ValueCache:
        """These images' feature values, each computed once (:class:`ValueCache`)."""
        return self._cache

    def values(self, features: Sequence[Feature], images: Sequence[int]) -> np.ndarray:
        """Feature values (F, len(images)), eq. 3.14, through the cache."""
        return self._cache.values(features, images, self._compute)

    def _compute(self, features: list[Feature], images: list[int]) -> np.ndarray:
        if len(images) == 1:
            records = self.record(images[0])
        else:
            records = self.all_records if images == list(range(len(self))) else self.records(images)
        return values_only(features, records).cpu().numpy()  # in the records' precision, as the cache stores it

    def cache_state(self, table: FeatureTable | None = None) -> dict:
        """The value cache as JSON-ready data (:meth:`ValueCache.state_dict`)."""
        return self._cache.state_dict(table)

    def load_cache_state(self, state: dict, features: list[Feature] | None = None) -> None:
        """Restore a cache written by :meth:`cache_state` for this same image set (:meth:`ValueCache.load_state_dict`)."""
        self._cache.load_state_dict(state, features)

    def examples(self, label: Hashable, n: int, generator: torch.Generator) -> list[int]:
        """Up to n distinct random images whose true classes include ``label``."""
        pool = [i for i, labels in enumerate(self.labels) if label in labels]
        order = torch.randperm(len(pool), generator=generator).tolist()
        return [pool[i] for i in order[:n]]


def _label_set(labels, image: int) -> frozenset:
    """One image's true classes (:class:`ImageSet`): a set or list of labels, or one hashable label."""
    if isinstance(labels, (set, frozenset, list)):
        items = list(labels)
    elif isinstance(labels, Hashable):
        items = [labels]
    else:
        raise InputError(f"labels of image {image}: {type(labels).__name__} is not a label (any hashable value) "
                         "or a set of labels")
    for label in items:
        if not isinstance(label, Hashable):
            raise InputError(f"labels of image {image}: {label!r} is not hashable, so it cannot be a class label")
    # a numpy scalar (np.int64(3), np.str_("a")) is the Python value it holds: the same class, and one a learner can save
    return frozenset(label.item() if isinstance(label, np.generic) else label for label in items)
