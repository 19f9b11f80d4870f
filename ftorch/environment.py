"""The task environment the learner acts in (4.4): labelled images and random example views."""
from __future__ import annotations

from collections.abc import Hashable, Iterable, Sequence

import torch

from .evaluate import feature_values
from .features import Feature
from .record import FeatureSpace, ImageRecords


class ImageSet:
    """Images with their sets of true classes; records are computed once, on construction.

    ``examples(label, n)`` draws n random images containing ``label`` (alg. 4.8 step 2).
    """

    def __init__(self, images: Sequence, labels: Sequence[Iterable[Hashable]], space: FeatureSpace | None = None,
                 progress: bool = False):
        if len(images) != len(labels):
            raise ValueError(f"{len(images)} images but {len(labels)} label sets")
        self.labels = [frozenset(l) for l in labels]
        self.space = space or FeatureSpace()
        with torch.no_grad():
            self.all_records = self.space.records(list(images), progress=progress)
        self._single: dict[int, ImageRecords] = {}

    def __len__(self) -> int:
        return len(self.labels)

    def record(self, image: int) -> ImageRecords:
        if image not in self._single:
            self._single[image] = self.all_records[image]
        return self._single[image]

    def records(self, images: Sequence[int]) -> ImageRecords:
        return self.all_records[torch.tensor(list(images), device=self.all_records.device)]

    def values(self, features: Sequence[Feature], images: Sequence[int]) -> torch.Tensor:
        """Feature values (F, len(images)), eq. 3.14."""
        if len(images) == 1:
            return feature_values(features, self.record(images[0])).values
        return feature_values(features, self.records(images)).values

    def examples(self, label: Hashable, n: int, generator: torch.Generator) -> list[int]:
        """Up to n distinct random images whose true classes include ``label``."""
        pool = [i for i, labels in enumerate(self.labels) if label in labels]
        order = torch.randperm(len(pool), generator=generator).tolist()
        return [pool[i] for i in order[:n]]
