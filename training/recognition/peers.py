"""Baseline classifiers for the robustness benchmark (7.2), run on the learner's splits and images.

- :class:`PixelNN`: the class of the nearest training view in pixel space (Euclidean).
- :class:`SiftMatcher`: OpenCV SIFT descriptors matched against every training view with Lowe's
  ratio test; the view with most good matches decides.

Both answer with sets of classes, scored by :func:`score` exactly as the learner's recognitions
(def. 4.5, 4.6).
"""
from __future__ import annotations

from collections import Counter

import cv2
import numpy as np
import torch

from ftorch.errors import InputError
from ftorch.images import to_uint8
from ftorch.recognition.inference import Recognition

from .protocol import test_block

DESCRIPTOR_BYTES = 128 * 4  # OpenCV SIFT descriptors are 128 float32
CHUNK = 1 << 22  # squared distances computed at once in SiftMatcher.good_matches


def score(predicted: list[frozenset], true: list[frozenset], classes: list) -> dict:
    """Accuracy (def. 4.6) and outcome proportions (def. 4.5), computed by ``protocol.test_block``
    so that baselines and learner are scored by the same code."""
    if len(predicted) != len(true):
        raise InputError(f"{len(predicted)} predictions but {len(true)} label sets")
    return test_block([Recognition({}, set(p)) for p in predicted], [frozenset(t) for t in true], classes)


def _view_classes(labels: list[frozenset]) -> list:
    """The one class of each training view."""
    classes = []
    for i, label in enumerate(labels):
        label = frozenset(label)
        if len(label) != 1:
            raise InputError(f"training view {i}: expected exactly one class, got {sorted(label, key=str)}")
        classes.extend(label)
    return classes


def _per_class(view_classes: list, amounts) -> float:
    """Mean over classes of the sum of ``amounts`` over each class's views."""
    total = Counter()
    for c, amount in zip(view_classes, amounts):
        total[c] += amount
    return float(np.mean(list(total.values())))


class PixelNN:
    """Nearest training view in Euclidean pixel distance; ties go to the first view."""

    def fit(self, images: list[torch.Tensor], labels: list[frozenset]) -> PixelNN:
        if not images or len(images) != len(labels):
            raise InputError(f"PixelNN.fit: {len(images)} images and {len(labels)} label sets")
        self.shape = tuple(images[0].shape)
        for i, image in enumerate(images):
            if tuple(image.shape) != self.shape:
                raise InputError(f"PixelNN.fit: image {i} is {tuple(image.shape)}, image 0 is {self.shape}")
        self.view_classes = _view_classes(labels)
        self.vectors = torch.stack([image.detach().reshape(-1).float() for image in images])
        return self

    def supports(self, shape) -> bool:
        """Whether images of ``shape`` can be compared with the training views (same shape)."""
        return tuple(shape) == self.shape

    def predict(self, images: list[torch.Tensor]) -> list[frozenset]:
        for i, image in enumerate(images):
            if not self.supports(image.shape):
                raise InputError(f"PixelNN: image {i} is {tuple(image.shape)} but the training views are "
                                 f"{self.shape}; check PixelNN.supports first")
        if not images:
            return []
        queries = torch.stack([image.detach().reshape(-1).float() for image in images])
        nearest = torch.cdist(queries, self.vectors, compute_mode="donot_use_mm_for_euclid_dist").argmin(1)
        return [frozenset({self.view_classes[j]}) for j in nearest.tolist()]

    def storage_per_class(self) -> float:
        """Bytes stored per class: float32 pixels x training views, mean over classes."""
        return _per_class(self.view_classes, [self.vectors.shape[1] * 4] * len(self.view_classes))


def _descriptors(image: torch.Tensor) -> np.ndarray:
    """SIFT descriptors (K, 128) float32 of an image in [0, 1], K >= 0."""
    _, found = cv2.SIFT_create().detectAndCompute(to_uint8(image), None)
    return np.zeros((0, 128), np.float32) if found is None else found


class SiftMatcher:
    """SIFT matching against each training view (Lowe's ratio test, per view).

    A test descriptor is a good match for a view when its nearest descriptor in that view is
    closer than ``ratio`` times the second nearest; views with fewer than 2 descriptors count 0.
    A class scores its best view's count; the ``n_classes`` best classes (default 2 with
    ``two_classes``, else 1) with a positive score are the answer, ties to the first class in fit
    order. No good match at all gives the empty set (an ignorant result, def. 4.5).
    """

    def __init__(self, ratio: float = 0.75, two_classes: bool = False):
        self.ratio, self.two_classes = ratio, two_classes

    def fit(self, images: list[torch.Tensor], labels: list[frozenset]) -> SiftMatcher:
        if not images or len(images) != len(labels):
            raise InputError(f"SiftMatcher.fit: {len(images)} images and {len(labels)} label sets")
        view_classes = _view_classes(labels)
        self.classes = list(dict.fromkeys(view_classes))
        self.view_classes = view_classes
        self._class_of_view = torch.tensor([self.classes.index(c) for c in view_classes])
        found = [_descriptors(image) for image in images]
        self.counts = torch.tensor([len(d) for d in found])
        # padded (V, Kmax, 128); a padded slot is never a nearest neighbour (distance inf)
        self._padded = torch.zeros(len(found), max(2, int(self.counts.max())), 128, dtype=torch.float64)
        for v, d in enumerate(found):
            self._padded[v, :len(d)] = torch.from_numpy(d)
        self._norms = self._padded.square().sum(2)
        self._valid = torch.arange(self._padded.shape[1]) < self.counts[:, None]
        return self

    def good_matches(self, image: torch.Tensor) -> torch.Tensor:
        """Good matches (V,) of the image's descriptors in each training view, equal to counting
        over ``cv2.BFMatcher(cv2.NORM_L2).knnMatch(query, view, k=2)`` view by view: OpenCV's SIFT
        descriptors are whole numbers below 256, so the float64 squared distances are exact and
        their float32 roots are the distances BFMatcher returns."""
        query = torch.from_numpy(_descriptors(image)).double()
        views, kmax = self._padded.shape[:2]
        if len(query) == 0:
            return torch.zeros(views, dtype=torch.int64)
        step = max(1, CHUNK // (len(query) * kmax))
        counts = []
        for start in range(0, views, step):
            block, norms = self._padded[start:start + step], self._norms[start:start + step]
            squared = (query.square().sum(1)[:, None, None] + norms[None]
                       - 2 * torch.einsum("md,vkd->mvk", query, block))
            two = squared.masked_fill(~self._valid[start:start + step], torch.inf).topk(2, dim=2, largest=False).values
            distance = two.float().sqrt().double()
            counts.append((distance[..., 0] < self.ratio * distance[..., 1]).sum(0))
        return torch.cat(counts).masked_fill(self.counts < 2, 0)

    def predict(self, images: list[torch.Tensor], n_classes: int | None = None) -> list[frozenset]:
        if n_classes is None:
            n_classes = 2 if self.two_classes else 1
        out = []
        for image in images:
            scores = torch.zeros(len(self.classes), dtype=torch.int64).scatter_reduce(
                0, self._class_of_view, self.good_matches(image), "amax").tolist()
            best = sorted(range(len(self.classes)), key=lambda c: -scores[c])[:n_classes]
            out.append(frozenset(self.classes[c] for c in best if scores[c] > 0))
        return out

    def storage_per_class(self) -> float:
        """Bytes of descriptors stored per class (128 float32 each), mean over classes."""
        return _per_class(self.view_classes, (self.counts * DESCRIPTOR_BYTES).tolist())

    def descriptors_per_view(self) -> float:
        return float(self.counts.double().mean())
