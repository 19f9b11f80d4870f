"""Perturbed test views for the robustness benchmark (7.2).

Images are grey float tensors (H, W) in [0, 1] showing one object on a black background, as in
COIL-20. Four perturbations:

- ``rotate``: in-plane rotation by an angle drawn from U(0, 360) degrees and scaling by U(0.75, 1)
  about the image centre (bilinear; the uncovered corners are black).
- ``clutter``: the object (its silhouette, :func:`mask`) pasted onto a random crop of one of
  scikit-image's bundled textures (brick, grass, gravel, drawn per image).
- ``occlude``: a grey (0.5) square whose area is 20 % of the object's, i.e. 0.2 x the mask area;
  the fraction of the object actually covered is lower wherever the square overlaps background.
- ``pair``: each view side by side (H, 2W) with a random view of another class; the true labels
  are both classes.

Each call draws from one generator seeded with (seed, kind), so a kind reproduces bit for bit
from the seed and does not depend on the other kinds.
"""
from __future__ import annotations

import math
from functools import cache
from pathlib import Path

import cv2
import numpy as np
import torch
from scipy.ndimage import binary_fill_holes

from ftorch.checkpoint import write_atomic
from ftorch.errors import InputError
from ftorch.images import to_uint8
from training.cli.outputs import Ledger
from training.data.datasets import IMAGE_SUFFIXES

KINDS = ("rotate", "clutter", "occlude", "pair")
MASK_THRESHOLD = 0.05
OCCLUDED = 0.2  # square area / mask area
GREY = 0.5
TEXTURES = ("brick", "grass", "gravel")


def perturb(images: list[torch.Tensor], labels: list[frozenset], kind: str,
            seed: int) -> tuple[list[torch.Tensor], list[frozenset]]:
    """The perturbed images of ``kind`` and their true label sets."""
    if kind not in KINDS:
        raise InputError(f"perturbation {kind!r}: expected one of {', '.join(KINDS)}")
    if len(images) != len(labels):
        raise InputError(f"{len(images)} images but {len(labels)} label sets")
    rng = np.random.default_rng([seed, KINDS.index(kind)])
    labels = [frozenset(names) for names in labels]
    if kind == "pair":
        return _pair(images, labels, rng)
    change = {"rotate": rotate, "clutter": _clutter, "occlude": _occlude}[kind]
    return [change(image, rng) for image in images], labels


def mask(image: torch.Tensor) -> torch.BoolTensor:
    """The object's silhouette: pixels above ``MASK_THRESHOLD``, closed then opened with a 3 x 3
    square (bridging one-pixel gaps, dropping one-pixel specks), with enclosed holes filled."""
    above = (_array(image) > MASK_THRESHOLD).astype(np.uint8)
    kernel = np.ones((3, 3), np.uint8)
    closed = cv2.morphologyEx(above, cv2.MORPH_CLOSE, kernel)
    opened = cv2.morphologyEx(closed, cv2.MORPH_OPEN, kernel)
    return torch.from_numpy(binary_fill_holes(opened))


def save_examples(images: list[torch.Tensor], names: list[str], folder, limit: int | None = None,
                  ledger: Ledger | None = None) -> list[Path]:
    """Write the first ``limit`` (default all) images as 8-bit PNGs ``folder/<name>.png`` (a name's own
    image suffix replaced, its folders joined by _), each atomically, recorded in ``ledger`` first
    where given; returns their paths."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    chosen = list(zip(images, names))[:limit]
    paths = [folder / f"{_stem(name).replace('/', '_')}.png" for _, name in chosen]
    if ledger is not None:
        ledger.files(*paths)
    for (image, _), path in zip(chosen, paths):
        encoded, png = cv2.imencode(".png", to_uint8(image))
        if not encoded:
            raise OSError(f"{path}: could not encode the PNG")
        write_atomic(path, png.tobytes())
    return paths


def _stem(name: str) -> str:
    """A view's name without the image suffix of its file (``cls/a.png`` -> ``cls/a``)."""
    return name[: -len(Path(name).suffix)] if Path(name).suffix.lower() in IMAGE_SUFFIXES else name


def _array(image: torch.Tensor) -> np.ndarray:
    return np.ascontiguousarray(image.detach().cpu().numpy())


def rotate(image: torch.Tensor, rng: np.random.Generator) -> torch.Tensor:
    """In-plane rotation by U(0, 360) degrees and scaling by U(0.75, 1) about the image centre."""
    angle, scale = rng.uniform(0, 360), rng.uniform(0.75, 1)
    height, width = image.shape
    matrix = cv2.getRotationMatrix2D(((width - 1) / 2, (height - 1) / 2), angle, scale)
    return torch.from_numpy(cv2.warpAffine(_array(image), matrix, (width, height), flags=cv2.INTER_LINEAR,
                                           borderMode=cv2.BORDER_CONSTANT, borderValue=0))


@cache
def _textures() -> tuple[np.ndarray, ...]:
    import skimage.data

    return tuple(getattr(skimage.data, name)().astype(np.float32) / 255 for name in TEXTURES)


def _clutter(image: torch.Tensor, rng: np.random.Generator) -> torch.Tensor:
    """A random (2H, 2W) crop of a texture (tiled where the texture is smaller), area-reduced to (H, W)."""
    texture = _textures()[rng.integers(len(TEXTURES))]
    height, width = image.shape
    texture = np.tile(texture, (math.ceil(2 * height / texture.shape[0]), math.ceil(2 * width / texture.shape[1])))
    top = rng.integers(texture.shape[0] - 2 * height + 1)
    left = rng.integers(texture.shape[1] - 2 * width + 1)
    crop = cv2.resize(texture[top:top + 2 * height, left:left + 2 * width], (width, height),
                      interpolation=cv2.INTER_AREA)
    return paste(image, crop)


def paste(image: torch.Tensor, background: np.ndarray) -> torch.Tensor:
    """The object (its silhouette, :func:`mask`) on ``background`` (H, W) instead of black."""
    return torch.where(mask(image), image, torch.from_numpy(background).to(image.dtype))


def _start(rng: np.random.Generator, low: int, high: int, side: int, size: int) -> int:
    """First row (or column) of a square of ``side`` inside [0, size) whose centre lies in
    [low, high]; the nearest inside position where the object is too close to the border."""
    half = (side - 1) / 2
    first = min(max(math.ceil(low - half), 0), size - side)
    last = min(max(math.floor(high - half), 0), size - side)
    return int(rng.integers(first, last + 1))


def _occlude(image: torch.Tensor, rng: np.random.Generator) -> torch.Tensor:
    return occlude(image, rng, OCCLUDED, GREY)


def occlude(image: torch.Tensor, rng: np.random.Generator, fraction: float, grey: float) -> torch.Tensor:
    """A square of grey level ``grey`` whose area is ``fraction`` x the mask area, centred on a
    random pixel of the object's bounding box (moved inside the image where it would leave it)."""
    silhouette = mask(image)
    area = int(silhouette.sum())
    if area == 0:
        return image.clone()
    height, width = image.shape
    side = min(max(1, round(math.sqrt(fraction * area))), height, width)
    rows, cols = np.nonzero(silhouette.numpy())
    top = _start(rng, rows.min(), rows.max(), side, height)
    left = _start(rng, cols.min(), cols.max(), side, width)
    out = image.clone()
    out[top:top + side, left:left + side] = grey
    return out


def _pair(images: list[torch.Tensor], labels: list[frozenset],
          rng: np.random.Generator) -> tuple[list[torch.Tensor], list[frozenset]]:
    shapes = {tuple(image.shape) for image in images}
    if len(shapes) > 1:
        raise InputError(f"pair: all views need the same shape, got {sorted(shapes)}")
    out, true = [], []
    for i, image in enumerate(images):
        others = [j for j, names in enumerate(labels) if not names & labels[i]]
        if not others:
            raise InputError(f"pair: view {i} ({', '.join(map(str, labels[i]))}) has no view of another class to pair with")
        j = others[rng.integers(len(others))]
        out.append(torch.cat([image, images[j]], dim=1))
        true.append(labels[i] | labels[j])
    return out, true
