"""Baseline classifiers for the robustness benchmark (7.2), run on the learner's splits and images.

- :class:`PixelNN`: the class of the nearest training view in pixel space (Euclidean), as stored
  (8-bit pixels) or reduced to ``side`` x ``side`` pixels.
- :class:`SiftMatcher`: OpenCV SIFT descriptors matched against every training view with Lowe's
  ratio test; the view with most good matches decides. :meth:`SiftMatcher.strongest` keeps only
  the n strongest keypoints of each training view.

Both count what they store at its stored precision (:meth:`storage_per_class`): a pixel and a
SIFT descriptor's entry are one byte each (OpenCV's SIFT entries are whole numbers below 256).

Both answer with sets of classes, scored by :func:`score` exactly as the learner's recognitions
(def. 4.5, 4.6), and with one label each, their best class (pixel 1-NN: its one class; SIFT: the
first of :meth:`SiftMatcher.ranked`), scored as the learner's top label (top-1 accuracy): the figure
on which ours is set against theirs.
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
from .records import TestBlock

DESCRIPTOR_BYTES = 128  # 128 entries, each a whole number below 256 (OpenCV saturates them to uchar)
CHUNK = 1 << 22  # squared distances computed at once in SiftMatcher.good_matches


def score(predicted: list[frozenset], true: list[frozenset], classes: list, top: list | None = None) -> TestBlock:
    """Accuracy (def. 4.6), top-1 accuracy and outcome proportions (def. 4.5), computed by
    ``protocol.test_block`` so that baselines and learner are scored by the same code. ``top``: each
    image's one label (None: none); default, the class of a one-class answer, else None."""
    if len(predicted) != len(true):
        raise InputError(f"{len(predicted)} predictions but {len(true)} label sets")
    if top is None:
        top = [next(iter(p)) if len(p) == 1 else None for p in predicted]
    elif len(top) != len(predicted):
        raise InputError(f"{len(predicted)} predictions but {len(top)} top labels")
    return test_block([Recognition({}, set(p), top=t) for p, t in zip(predicted, top)], [frozenset(t) for t in true], classes)


def score_ranked(answers: list[list], true: list[frozenset], classes: list) -> TestBlock:
    """:func:`score` of answers given best class first (:meth:`SiftMatcher.ranked`): the set, and the first as top label."""
    return score([frozenset(a) for a in answers], true, classes, [a[0] if a else None for a in answers])


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
    """Nearest training view in Euclidean distance of 8-bit pixels; ties go to the first view.

    ``side``: every image (training view or query, of any size) is first area-averaged to
    ``side`` x ``side`` pixels (``cv2.INTER_AREA``); without it images are compared as they are,
    so only images of the training views' shape can be answered (:meth:`supports`).
    """

    def __init__(self, side: int | None = None):
        if side is not None and side < 1:
            raise InputError(f"PixelNN: side {side}: expected a number of pixels >= 1")
        self.side = side

    def _vector(self, image: torch.Tensor) -> torch.Tensor:
        pixels = to_uint8(image)
        if self.side is not None:
            pixels = cv2.resize(pixels, (self.side, self.side), interpolation=cv2.INTER_AREA)
        return torch.from_numpy(pixels.reshape(-1).astype(np.float32))

    def fit(self, images: list[torch.Tensor], labels: list[frozenset]) -> PixelNN:
        if not images or len(images) != len(labels):
            raise InputError(f"PixelNN.fit: {len(images)} images and {len(labels)} label sets")
        self.shape = tuple(images[0].shape)
        for i, image in enumerate(images):
            if not self.supports(image.shape):
                raise InputError(f"PixelNN.fit: image {i} is {tuple(image.shape)}, image 0 is {self.shape}")
        self.view_classes = _view_classes(labels)
        self.vectors = torch.stack([self._vector(image) for image in images])
        return self

    def supports(self, shape) -> bool:
        """Whether images of ``shape`` can be compared with the training views (any shape where
        images are reduced to ``side``; else the same shape)."""
        return self.side is not None or tuple(shape) == self.shape

    def predict(self, images: list[torch.Tensor]) -> list[frozenset]:
        for i, image in enumerate(images):
            if not self.supports(image.shape):
                raise InputError(f"PixelNN: image {i} is {tuple(image.shape)} but the training views are "
                                 f"{self.shape}; check PixelNN.supports first")
        if not images:
            return []
        queries = torch.stack([self._vector(image) for image in images])
        nearest = torch.cdist(queries, self.vectors, compute_mode="donot_use_mm_for_euclid_dist").argmin(1)
        return [frozenset({self.view_classes[j]}) for j in nearest.tolist()]

    def storage_per_class(self) -> float:
        """Bytes stored per class: 8-bit pixels x training views, mean over classes."""
        return _per_class(self.view_classes, [self.vectors.shape[1]] * len(self.view_classes))


def sift_descriptors(image: torch.Tensor) -> np.ndarray:
    """SIFT descriptors (K, 128) float32 of an image in [0, 1], K >= 0, strongest keypoint first
    (by detector response; equal responses in OpenCV's order)."""
    points, found = cv2.SIFT_create().detectAndCompute(to_uint8(image), None)
    if found is None:
        return np.zeros((0, 128), np.float32)
    return found[np.argsort([-p.response for p in points], kind="stable")]


class SiftMatcher:
    """SIFT matching against each training view (Lowe's ratio test, per view), or against all
    training views at once with the ratio test across classes (``across_classes``).

    Per view, a test descriptor is a good match for a view when its nearest descriptor in that
    view is closer than ``ratio`` times the second nearest; views with fewer than 2 descriptors
    count 0, and a class scores its best view's count. Across classes (Lowe 2004, section 7.1: the
    second neighbour is the nearest one known to come from another object), a test descriptor
    votes for the class of its nearest training descriptor when that is closer than ``ratio`` times
    the nearest descriptor of any other class, and a class scores its votes. This form still works
    with very few descriptors per view (:meth:`strongest`), where per view nearly any descriptor
    passes the test. The ``n_classes`` best classes (default 2 with ``two_classes``, else 1) with
    a positive score are the answer, ties to the first class in fit order. No good match at all
    gives the empty set (an ignorant result, def. 4.5).
    """

    def __init__(self, ratio: float = 0.75, two_classes: bool = False, across_classes: bool = False):
        self.ratio, self.two_classes, self.across_classes = ratio, two_classes, across_classes

    def fit(self, images: list[torch.Tensor], labels: list[frozenset],
            descriptors: list[np.ndarray] | None = None) -> SiftMatcher:
        """Fit to the training views; ``descriptors``: theirs (``sift_descriptors``), where computed before."""
        if not images or len(images) != len(labels):
            raise InputError(f"SiftMatcher.fit: {len(images)} images and {len(labels)} label sets")
        if descriptors is None:
            descriptors = [sift_descriptors(image) for image in images]
        return self._fit(descriptors, _view_classes(labels))

    def _fit(self, found: list[np.ndarray], view_classes: list) -> SiftMatcher:
        self.classes = list(dict.fromkeys(view_classes))
        self.view_classes = view_classes
        self._class_of_view = torch.tensor([self.classes.index(c) for c in view_classes])
        self._found = found
        self.counts = torch.tensor([len(d) for d in found])
        # padded (V, Kmax, 128); a padded slot is never a nearest neighbour (distance inf)
        self._padded = torch.zeros(len(found), max(2, int(self.counts.max())), 128, dtype=torch.float64)
        for v, d in enumerate(found):
            self._padded[v, :len(d)] = torch.from_numpy(d)
        self._norms = self._padded.square().sum(2)
        self._valid = torch.arange(self._padded.shape[1]) < self.counts[:, None]
        self._flat = torch.from_numpy(np.concatenate(found)).double() if sum(map(len, found)) else torch.zeros(0, 128).double()
        self._class_of_row = torch.repeat_interleave(self._class_of_view, self.counts)
        return self

    def strongest(self, n: int) -> SiftMatcher:
        """The same matcher keeping only the ``n`` strongest keypoints of each training view
        (queries still use all of theirs)."""
        if n < 1:
            raise InputError(f"SiftMatcher.strongest: {n} keypoints: expected at least 1")
        return SiftMatcher(self.ratio, self.two_classes, self.across_classes)._fit([d[:n] for d in self._found],
                                                                                   self.view_classes)

    def good_matches(self, image: torch.Tensor, query: np.ndarray | None = None) -> torch.Tensor:
        """Good matches (V,) of the image's descriptors (``query``, where computed before) in each
        training view, equal to counting over ``cv2.BFMatcher(cv2.NORM_L2).knnMatch(query, view,
        k=2)`` view by view: OpenCV's SIFT descriptors are whole numbers below 256, so the float64
        squared distances are exact and their float32 roots are the distances BFMatcher returns."""
        query = torch.from_numpy(sift_descriptors(image) if query is None else query).double()
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

    def class_votes(self, image: torch.Tensor, query: np.ndarray | None = None) -> torch.Tensor:
        """Votes (C,) of the image's descriptors by the ratio test across classes (class doc):
        exact float64 squared distances, compared as float32 roots as BFMatcher would."""
        query = torch.from_numpy(sift_descriptors(image) if query is None else query).double()
        votes = torch.zeros(len(self.classes), dtype=torch.int64)
        if len(query) == 0 or len(self._flat) == 0 or len(self.classes) < 2:
            return votes
        squared = (query.square().sum(1)[:, None] + self._flat.square().sum(1)[None] - 2 * query @ self._flat.T).clamp_min(0)
        nearest = torch.full((len(query), len(self.classes)), torch.inf, dtype=torch.float64).scatter_reduce(
            1, self._class_of_row.expand(len(query), -1), squared, "amin")
        two = nearest.topk(2, dim=1, largest=False)
        distance = two.values.float().sqrt().double()
        good = distance[:, 0] < self.ratio * distance[:, 1]
        return votes.index_add_(0, two.indices[good, 0], torch.ones(int(good.sum()), dtype=torch.int64))

    def predict(self, images: list[torch.Tensor], n_classes: int | None = None,
                queries: list[np.ndarray] | None = None) -> list[frozenset]:
        """The answer for each image; ``queries``: their descriptors (``sift_descriptors``), where
        computed before (e.g. once for many budgets)."""
        return [frozenset(answer) for answer in self.ranked(images, n_classes, queries)]

    def ranked(self, images: list[torch.Tensor], n_classes: int | None = None,
               queries: list[np.ndarray] | None = None) -> list[list]:
        """:meth:`predict`'s answer for each image as a list, best class first (its one label)."""
        if n_classes is None:
            n_classes = 2 if self.two_classes else 1
        out = []
        for k, image in enumerate(images):
            query = None if queries is None else queries[k]
            if self.across_classes:
                scores = self.class_votes(image, query).tolist()
            else:
                scores = torch.zeros(len(self.classes), dtype=torch.int64).scatter_reduce(
                    0, self._class_of_view, self.good_matches(image, query), "amax").tolist()
            best = sorted(range(len(self.classes)), key=lambda c: -scores[c])[:n_classes]
            out.append([self.classes[c] for c in best if scores[c] > 0])
        return out

    def storage_per_class(self) -> float:
        """Bytes of descriptors stored per class (128 one-byte entries each), mean over classes."""
        return _per_class(self.view_classes, (self.counts * DESCRIPTOR_BYTES).tolist())

    def descriptors_per_view(self) -> float:
        return float(self.counts.double().mean())
