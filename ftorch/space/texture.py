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

from .kernels import band_matrix, band_span, derivative_kernels, kernel_radius
from .scale_space import DENSE_WIDTH

BINS = 8
FIRST_LEVEL = 2  # sigma = 2
_WIDE_TILE = 64  # pixels of grid points per blur tile beyond DENSE_WIDTH (at least 2r)


def level_sigma(level: int) -> float:
    """sigma_k = 2^(k/2), the scale space's levels (3.3.3)."""
    return 2.0 ** (level / 2)


def sigma_level(sigma: float) -> int | None:
    """The level k >= ``FIRST_LEVEL`` with sigma_k = ``sigma`` (to 1e-9), or None."""
    if not (isinstance(sigma, float) and math.isfinite(sigma) and sigma > 0):
        return None
    level = round(2 * math.log2(sigma))
    return level if level >= FIRST_LEVEL and abs(level_sigma(level) - sigma) <= 1e-9 * sigma else None


def grid_step(level: int) -> int:
    """Pixels between the grid's rows and columns at a level: max(1, round(sigma))."""
    return max(1, round(level_sigma(level)))


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


def _blur_at(g: np.ndarray, n: int, points: np.ndarray, device, dtype):
    """The blur of an n-long axis with ``g`` at ``points`` (ascending): the rows (P, n) of its band
    matrix up to ``DENSE_WIDTH`` (the products every image size the project uses has always had, bit
    for bit), beyond it tiles (first point, last point, first input, last input, block (p, C)) that
    hold only the inputs inside the band of about max(64, 2r) pixels of points, so no matrix grows
    as n^2 / sigma (1 GB at sigma 2 for 16000 columns)."""
    if n <= DENSE_WIDTH:
        return torch.from_numpy(band_matrix(g, n, points)).to(device=device, dtype=dtype)
    radius = (len(g) - 1) // 2
    per = _points_per_tile(points, radius)
    tiles = []
    for p0 in range(0, len(points), per):
        p1 = min(p0 + per, len(points))
        c0, c1 = band_span(int(points[p0]), int(points[p1 - 1]) + 1, radius, n)
        block = torch.from_numpy(band_matrix(g, n, points[p0:p1], (c0, c1)))
        tiles.append((p0, p1, c0, c1, block.to(device=device, dtype=dtype)))
    return tiles


def _points_per_tile(points: np.ndarray, radius: int) -> int:
    """Grid points per tile: those within about max(64, 2r) pixels (the grid is evenly spaced)."""
    step = int(points[1] - points[0]) if len(points) > 1 else 1
    return max(1, max(_WIDE_TILE, 2 * radius) // step)


def _blur_numbers(n: int, points: np.ndarray, radius: int) -> int:
    """Upper bound of the numbers :func:`_blur_at` holds."""
    if n <= DENSE_WIDTH:
        return len(points) * n
    per = _points_per_tile(points, radius)
    return sum((p1 - p0) * min(n, int(points[p1 - 1] - points[p0]) + 1 + 2 * radius)
               for p0 in range(0, len(points), per) for p1 in [min(p0 + per, len(points))])


def _rows_blur(vertical, x: Tensor) -> Tensor:
    """(..., P, W): x (..., H, W) blurred down the columns at the grid rows (:func:`_blur_at`)."""
    if isinstance(vertical, Tensor):
        return torch.matmul(vertical, x)
    out = x.new_empty(*x.shape[:-2], vertical[-1][1], x.shape[-1])
    for p0, p1, c0, c1, block in vertical:
        out[..., p0:p1, :] = torch.matmul(block, x[..., c0:c1, :])
    return out


def _columns_blur(x: Tensor, horizontal) -> Tensor:
    """(..., P, Q): x (..., P, W) blurred along the rows at the grid columns (:func:`_blur_at`, dense
    as (W, Q))."""
    if isinstance(horizontal, Tensor):
        return torch.matmul(x, horizontal)
    out = x.new_empty(*x.shape[:-1], horizontal[-1][1])
    for p0, p1, c0, c1, block in horizontal:
        out[..., p0:p1] = torch.matmul(x[..., c0:c1], block.T)
    return out


class TextureGrid:
    """The texture statistics of equal-sized images at the grid points of every level from
    ``FIRST_LEVEL`` on: x, y, level (Q,) and the square-rooted histograms (B, Q, BINS).

    The blur is the sampled Gaussian of :func:`~ftorch.space.kernels.derivative_kernels` (order 0),
    as a product with its reflect-folded band matrix, evaluated at the grid rows and columns only
    (tiled along a side longer than ``DENSE_WIDTH``, :func:`_blur_at`).
    """

    def __init__(self, truncate: float = 3.0):
        self.truncate = float(truncate)
        self._plans: dict = {}

    def points(self, height: int, width: int, levels: int) -> list[tuple[int, np.ndarray, np.ndarray]]:
        """(level, rows, columns) of the grid at each level that has points."""
        out = []
        for k in range(FIRST_LEVEL, levels):
            radius, step = kernel_radius(level_sigma(k), self.truncate), grid_step(k)
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
                vertical = _blur_at(g, height, rows, device, dtype)
                horizontal = _blur_at(g, width, cols, device, dtype)
                if isinstance(horizontal, Tensor):
                    horizontal = horizontal.T
                y, x = np.meshgrid(rows, cols, indexing="ij")
                plan.append((k, vertical, horizontal, torch.from_numpy(x.ravel()), torch.from_numpy(y.ravel())))
            self._plans[key] = plan
        return self._plans[key]

    def plan_nbytes(self, height: int, width: int, levels: int, dtype=torch.float32) -> int:
        """Bytes of the blur matrices and grid coordinates one image size's plan holds (an upper bound,
        known without building them)."""
        itemsize = torch.empty(0, dtype=dtype).element_size()
        total = 0
        for k, rows, cols in self.points(height, width, levels):
            radius = kernel_radius(level_sigma(k), self.truncate)
            total += (_blur_numbers(height, rows, radius) + _blur_numbers(width, cols, radius)) * itemsize
            total += 2 * len(rows) * len(cols) * 8
        return total

    def __call__(self, images: Tensor, levels: int) -> tuple[Tensor, Tensor, Tensor, Tensor]:
        """x, y, level (Q,) and histograms (B, Q, BINS) of images (B, H, W) with ``levels`` scale levels."""
        batch, height, width = images.shape
        plan = self._plan(height, width, levels, images.device, images.dtype)
        member = memberships(images)
        xs, ys, ks, hists = [], [], [], []
        for k, vertical, horizontal, x, y in plan:
            blurred = _columns_blur(_rows_blur(vertical, member), horizontal)  # (B, BINS, rows, cols)
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
