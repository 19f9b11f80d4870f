"""Augmented training views (``--augment N``): perturbed copies the learner is trained on beside the
originals, so that a feature must stay distinctive under the changes the robustness benchmark
(:mod:`training.data.perturb`) applies to test views.

Each copy of a view is rotated in the plane by U(0, 360) degrees and scaled by U(0.75, 1) (the
``rotate`` family); then, each with probability 1/2, a grey square of U(0.1, 0.3) x the object's
area and grey level U(0.2, 0.8) is put over it (``occlude`` uses 0.2 and 0.5), and the object is
pasted on procedural clutter. The clutter is band-pass noise (:func:`texture`), never the bundled
photographs the benchmark's ``clutter`` set uses, so that set stays unseen. Copies draw from one
generator seeded with (seed, fold): the same run gives the same copies.
"""
from __future__ import annotations

import cv2
import numpy as np
import torch

from ftorch.recognition.environment import ImageSet
from ftorch.space.draw import grid, panel, titled

from .perturb import occlude, paste, rotate

PRESENT = 0.5  # probability of the occluder, and of the clutter, in a copy


def texture(rng: np.random.Generator, height: int, width: int) -> np.ndarray:
    """Procedural clutter (H, W) in [0, 1]: three layers of white noise smoothed at scales
    2^U(0, 3) pixels, each normalised and mixed with Dirichlet weights, then given a random mean
    U(0.3, 0.7) and spread U(0.1, 0.25) and clipped."""
    mixed = np.zeros((height, width), np.float32)
    for weight in rng.dirichlet(np.ones(3)):
        layer = cv2.GaussianBlur(rng.random((height, width), dtype=np.float32), (0, 0), float(2 ** rng.uniform(0, 3)))
        mixed += weight * (layer - layer.mean()) / max(float(layer.std()), 1e-6)
    mixed /= max(float(mixed.std()), 1e-6)
    return np.clip(rng.uniform(0.3, 0.7) + rng.uniform(0.1, 0.25) * mixed, 0, 1).astype(np.float32)


def augment(images: list[torch.Tensor], labels: list, copies: int, seed: int, fold: int) -> tuple[list, list]:
    """``copies`` perturbed copies of every view (module docstring), copy by copy, with their labels."""
    rng = np.random.default_rng([seed, fold])
    out, true = [], []
    for _ in range(copies):
        for image, label in zip(images, labels):
            view = rotate(image, rng)
            if rng.random() < PRESENT:
                view = occlude(view, rng, rng.uniform(0.1, 0.3), rng.uniform(0.2, 0.8))
            if rng.random() < PRESENT:
                view = paste(view, texture(rng, *view.shape))
            out.append(view)
            true.append(label)
    return out, true


def overview(env: ImageSet, views: int, heading: str) -> np.ndarray:
    """The first training view of each class (top row) and its copies below it (``env``: ``views``
    originals, then the copies in :func:`augment`'s order), as an RGB picture titled ``heading``."""
    first = {}
    for i, labels in enumerate(env.labels[:views]):
        for label in labels:
            first.setdefault(label, i)
    copies = len(env) // views - 1
    panels = [panel(env.images[i + n * views], env.names[i + n * views]) for n in range(copies + 1) for i in first.values()]
    return titled(grid(panels, len(first)), f"{heading}: each class's first training view and its augmented copies")
