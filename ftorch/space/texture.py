"""Statistical texture (7.2.1): the local intensity distribution, without regard to its spatial
organization, as a primitive beside the texel and the edgel.

At a point (x, y) and scale sigma the statistic is the Gaussian-weighted histogram of the image's
intensities around it: ``BINS`` soft bins over [0, 1] (each intensity shares its weight between
the two nearest bin centres, linearly, so the memberships of every pixel sum to one), blurred
with the scale space's own sampled Gaussian of that sigma (reflect boundary). Its weights sum to
one, so the vector of their square roots has unit length and the dot product of two such vectors
is the Bhattacharyya coefficient of the two histograms: a similarity in [0, 1], matched as a
gathered dot product like every other primitive (eq. 3.13).

Decisions the text leaves open:
- Where: on a grid at every level from sigma = 2 (``FIRST_LEVEL``; below it the window holds a
  few pixels and the histogram is a pixel's value), spaced max(1, round(sigma)) pixels, where the
  level's kernel fits inside the image (as salient points, 3.4.3). A histogram is smooth on the
  scale sigma, so a grid of spacing sigma misses little; it costs a few thousand points per
  128x128 image, against the tens of thousands of a dense grid.
- Matching: a texture feature's value in an image is its largest coefficient over the grid points
  of its own level (eq. 3.14 with the grid as reference points). An isotropic window makes the
  value invariant to rotation; it is not invariant to I -> a I + b, as texels and edgels are
  (3.4.4): the distribution of intensities is what it describes.
"""
from __future__ import annotations

import math

import numpy as np
import torch
from torch import Tensor

from .kernels import band_matrix, derivative_kernels, kernel_radius

BINS = 8
FIRST_LEVEL = 2  # sigma = 2


def level_sigma(level: int) -> float:
    """sigma_k = 2^(k/2), the scale space's levels (3.3.3)."""
    return 2.0 ** (level / 2)


def sigma_level(sigma: float) -> int | None:
    """The level k >= ``FIRST_LEVEL`` with sigma_k = ``sigma`` (to 1e-9), or None."""
    if not (isinstance(sigma, float) and math.isfinite(sigma) and sigma > 0):
        return None
    level = round(2 * math.log2(sigma))
    return level if level >= FIRST_LEVEL and abs(level_sigma(level) - sigma) <= 1e-9 * sigma else None


def memberships(images: Tensor) -> Tensor:
    """(B, BINS, H, W): each pixel's weight in each soft bin, from images (B, H, W) in [0, 1];
    linear between the two nearest bin centres (b + 1/2) / BINS, all in the end bin beyond them."""
    t = (images.clamp(0, 1) * BINS - 0.5).clamp(0, BINS - 1)
    low = t.floor().clamp(max=BINS - 2)
    upper = t - low
    out = images.new_zeros(images.shape[0], BINS, *images.shape[1:])
    out.scatter_(1, low.long()[:, None], (1 - upper)[:, None])
    out.scatter_add_(1, low.long()[:, None] + 1, upper[:, None])
    return out


class TextureGrid:
    """The texture statistics of equal-sized images at the grid points of every level from
    ``FIRST_LEVEL`` on: x, y, level (Q,) and the square-rooted histograms (B, Q, BINS).

    The blur is the sampled Gaussian of :func:`~ftorch.space.kernels.derivative_kernels` (order 0),
    as a product with its reflect-folded band matrix, evaluated at the grid rows and columns only.
    """

    def __init__(self, truncate: float = 3.0):
        self.truncate = float(truncate)
        self._plans: dict = {}

    def points(self, height: int, width: int, levels: int) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """(level, rows, columns) of the grid at each level that has points."""
        out = []
        for k in range(FIRST_LEVEL, levels):
            sigma = level_sigma(k)
            radius, step = kernel_radius(sigma, self.truncate), max(1, round(sigma))
            rows, cols = np.arange(radius, height - radius, step), np.arange(radius, width - radius, step)
            if len(rows) and len(cols):
                out.append((k, rows, cols))
        return out

    def _plan(self, height: int, width: int, levels: int, device, dtype) -> list:
        key = (height, width, levels, str(device), dtype)
        if key not in self._plans:
            if len(self._plans) >= 8:
                self._plans.pop(next(iter(self._plans)))
            plan = []
            for k, rows, cols in self.points(height, width, levels):
                g = derivative_kernels(level_sigma(k), self.truncate)[0]
                vertical = torch.from_numpy(band_matrix(g, height)[rows]).to(device=device, dtype=dtype)
                horizontal = torch.from_numpy(band_matrix(g, width)[cols].T).to(device=device, dtype=dtype)
                y, x = np.meshgrid(rows, cols, indexing="ij")
                plan.append((k, vertical, horizontal, torch.from_numpy(x.ravel()), torch.from_numpy(y.ravel())))
            self._plans[key] = plan
        return self._plans[key]

    def __call__(self, images: Tensor, levels: int) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """x, y, level (Q,) and histograms (B, Q, BINS) of images (B, H, W) with ``levels`` scale levels."""
        batch, height, width = images.shape
        plan = self._plan(height, width, levels, images.device, images.dtype)
        member = memberships(images)
        xs, ys, ks, hists = [], [], [], []
        for k, vertical, horizontal, x, y in plan:
            blurred = torch.matmul(torch.matmul(vertical, member), horizontal)  # (B, BINS, rows, cols)
            hists.append(blurred.clamp_min(0).sqrt().flatten(2).transpose(1, 2))
            xs.append(x)
            ys.append(y)
            ks.append(torch.full((len(x),), k, dtype=torch.long))
        if not plan:
            empty = torch.zeros(0, device=images.device)
            return (empty.to(images.dtype), empty.to(images.dtype), empty.long(),
                    images.new_zeros(batch, 0, BINS))
        device, dtype = images.device, images.dtype
        return (torch.cat(xs).to(device, dtype), torch.cat(ys).to(device, dtype), torch.cat(ks).to(device),
                torch.cat(hists, 1))
