"""Slow, obviously-correct references for tests and benchmarks.

:func:`scipy_basis` builds the five basis maps with ``scipy.ndimage.gaussian_filter``.
The rest evaluates feature values point by point.

It shares nothing with the batched path but the records' pyramids and point lists: each
reference point is visited in a Python loop, alg. 3.6 is followed step by step in scalar
math, responses are interpolated with ``scipy.ndimage.map_coordinates`` (order 1 in level,
row, column), steered with the coefficients of eq. 3.8 written out, and eq. 3.13/3.14 applied.
Textures are matched at their level's grid points one by one; a geometric compound's texture part
(3.5 with 7.2.1) is interpolated between the grid points around it, found by scanning the lines of
its level's grid, and multiplies the cosine of the oriented parts by its Bhattacharyya coefficient;
a region's test (the frames of ``ftorch.space.region``: the image's own size, the lower medians of
the salient points) is written out in scalar math.
"""
from __future__ import annotations

import math

import numpy as np
from scipy.ndimage import gaussian_filter, map_coordinates

from .features import Conjunction, Feature, LocalFeature, Texture, Within
from .kernels import kernel_radius
from .primitives import EDGEL
from .record import ImageRecords
from .region import Frame, Region
from .sampling import SPAN_TOLERANCE
from .texture import FIRST_LEVEL, grid_step


def scipy_basis(image: np.ndarray, sigma: float, truncate: float = 3.0) -> np.ndarray:
    """The five scale-normalised basis maps from scipy, with ftorch's zero-sum g''.

    scipy's order-2 filter minus (sum of its sampled g'') times the smoothed image equals the
    zero-sum second derivative of kernels.py; the rest is scipy as it is (mode 'reflect').

    Args:
        image: a grey image.
        sigma: the scale.
        truncate: the kernel radius in sigmas.

    Returns:
        G1@0, G1@pi/2, G2@0, G2@pi/3, G2@2pi/3 (eq. 3.8), as ``ScaleSpace`` orders them.

    Shape:
        - image: :math:`(H, W)`.
        - Output: :math:`(5, H, W)`.
    """
    def f(oy, ox):
        return gaussian_filter(image, sigma, order=(oy, ox), truncate=truncate, mode="reflect")

    r = kernel_radius(sigma, truncate)
    x = np.arange(-r, r + 1)
    g = np.exp(-0.5 * x * x / sigma**2)
    g /= g.sum()
    dc = ((x * x / sigma**4 - 1 / sigma**2) * g).sum()
    smooth = f(0, 0)
    gx, gy, gxy = sigma * f(0, 1), sigma * f(1, 0), sigma**2 * f(1, 1)
    gxx, gyy = sigma**2 * (f(0, 2) - dc * smooth), sigma**2 * (f(2, 0) - dc * smooth)
    iso, mixed = 0.25 * gxx + 0.75 * gyy, math.sqrt(3) / 2 * gxy
    return np.stack([gx, gy, gxx, iso + mixed, iso - mixed])


def steer_eq38(raw: list[float], theta: float, order: int) -> list[float]:
    """Steer one basis set of order 1 (2 values) or 2 (3 values) by theta, eq. 3.8."""
    if order == 1:
        coef = lambda t, k: math.cos(t - k * math.pi / 2)  # noqa: E731
    else:
        coef = lambda t, k: (1 + 2 * math.cos(2 * (t - k * math.pi / 3))) / 3  # noqa: E731
    n = order + 1
    return [sum(raw[k] * coef(theta + j * math.pi / n, k) for k in range(n)) for j in range(n)]


def _measure(pyramid: np.ndarray, x: float, y: float, sigma: float, theta: float, kind: str):
    levels, _, height, width = pyramid.shape
    u = 2 * math.log2(sigma)
    u = round(u) if abs(u - round(u)) < 1e-4 else u  # the documented snapping rule of sampling.py
    offsets = [0.0] if kind == "edgel" else [-1.0, 0.0, 1.0]
    if not (0 <= x <= width - 1 and 0 <= y <= height - 1):
        return None
    if u + offsets[0] < 0 or u + offsets[-1] > levels - 1:
        return None
    out = []
    for t in offsets:
        raw = [float(map_coordinates(pyramid[:, c], [[u + t], [y], [x]], order=1, mode="nearest")[0]) for c in range(5)]
        out += steer_eq38(raw[:2], theta, 1)
        if kind == "texel":
            out += steer_eq38(raw[2:], theta, 2)
    return out


def texture_grid(records: ImageRecords, n: int) -> dict[int, dict[tuple[float, float], np.ndarray]]:
    """Image ``n``'s texture grid point by point: {level: {(x, y): square-rooted histogram}}."""
    grid: dict[int, dict] = {}
    for q in range(records.grid_mask.shape[1]):
        if bool(records.grid_mask[n, q]):
            at = (float(records.grid_x[n, q]), float(records.grid_y[n, q]))
            grid.setdefault(int(records.grid_level[n, q]), {})[at] = records.histograms[n, q].double().cpu().numpy()
    return grid


def _bracket(values: list[float], v: float, step: int) -> tuple[float, float, float] | None:
    """The grid lines around ``v`` on one axis and the weight of the upper one; None outside their span
    (by more than SPAN_TOLERANCE steps; nearer, ``v`` is moved onto it)."""
    if not values[0] - SPAN_TOLERANCE * step <= v <= values[-1] + SPAN_TOLERANCE * step:
        return None
    v = min(max(v, values[0]), values[-1])
    lower = max(line for line in values if line <= v)
    upper = min((line for line in values if line > v), default=lower)
    if upper == lower and len(values) > 1:  # on the last line: the cell below, upper weight 1
        lower, upper = values[-2], values[-1]
    return lower, upper, (v - lower) / step


def _texture_sample(grid: dict, x: float, y: float, sigma: float) -> np.ndarray | None:
    """A texture part's vector at (x, y, sigma): bilinear between the four grid points around
    (x, y) at the level nearest sigma; None where that level or span has none."""
    u = 2 * math.log2(sigma)
    level = round(round(u) if abs(u - round(u)) < 1e-4 else u)
    points = grid.get(level) if level >= FIRST_LEVEL else None
    if not points:
        return None
    step = grid_step(level)
    across = _bracket(sorted({px for px, _ in points}), x, step)
    down = _bracket(sorted({py for _, py in points}), y, step)
    if across is None or down is None:
        return None
    (x0, x1, wx), (y0, y1, wy) = across, down
    return ((1 - wy) * ((1 - wx) * points[x0, y0] + wx * points[x1, y0])
            + wy * ((1 - wx) * points[x0, y1] + wx * points[x1, y1]))


def local_value_at(feature: LocalFeature, pyramid: np.ndarray, x: float, y: float, sigma: float, theta: float,
                   grid: dict | None = None):
    """Eq. 3.13 for one local feature at one reference point, times the Bhattacharyya coefficient
    of each texture part (sampled from ``grid``, :func:`texture_grid`); None where a part falls outside."""
    observed, pattern, coefficient = [], [], 1.0
    for i, part in enumerate(feature.parts):
        if i > 0:
            x += sigma * part.d * math.cos(theta + part.phi)
            y += sigma * part.d * math.sin(theta + part.phi)
            theta += part.dtheta
            sigma *= part.dsigma
        if part.kind == "texture":
            if grid is None:
                raise ValueError("a texture part is sampled from the image's texture grid: pass texture_grid(records, n)")
            measured = _texture_sample(grid, x, y, sigma)
            if measured is None:
                return None
            stored = np.array(part.vector)
            cosine = float(measured @ stored) / float(np.linalg.norm(measured) * np.linalg.norm(stored))
            coefficient *= min(1.0, max(0.0, cosine))
            continue
        measured = _measure(pyramid, x, y, sigma, theta, part.kind)
        if measured is None:
            return None
        observed += measured
        pattern += list(part.vector)
    o, p = np.array(observed), np.array(pattern)
    norm = np.linalg.norm(o) * np.linalg.norm(p)
    return max(0.0, float(o @ p / norm)) * coefficient if norm > 0 else 0.0


def _lower_median(values: list[float]) -> float:
    ordered = sorted(values)
    return ordered[(len(ordered) - 1) // 2]


def region_holds(region: Region, records: ImageRecords, n: int, x: float, y: float) -> bool:
    """Whether pixel position (x, y) of image ``n`` lies inside ``region``."""
    if region.frame == Frame.IMAGE:
        height, width = (int(v) for v in records.sizes[n])
        u, v = (x + 0.5) / width, (y + 0.5) / height
    else:
        points = [(float(records.x[n, p]), float(records.y[n, p])) for p in range(records.mask.shape[1])
                  if bool(records.mask[n, p])]
        if not points:
            return False
        cx, cy = _lower_median([px for px, _ in points]), _lower_median([py for _, py in points])
        s = _lower_median([math.hypot(px - cx, py - cy) for px, py in points])
        if s == 0:
            return False
        u, v = (x - cx) / s, (y - cy) / s
    return (u - region.x) ** 2 + (v - region.y) ** 2 <= region.radius**2


def texture_value(feature: Texture, records: ImageRecords, n: int, regions: tuple[Region, ...] = ()) -> float:
    """Eq. 3.14 for a texture (7.2.1): the largest Bhattacharyya coefficient over the grid points of
    its level in image ``n`` (inside all ``regions``)."""
    pattern = np.array(feature.histogram) / np.linalg.norm(feature.histogram)
    best = 0.0
    for q in range(records.grid_mask.shape[1]):
        if not bool(records.grid_mask[n, q]) or int(records.grid_level[n, q]) != feature.level:
            continue
        x, y = float(records.grid_x[n, q]), float(records.grid_y[n, q])
        if all(region_holds(r, records, n, x, y) for r in regions):
            observed = records.histograms[n, q].double().cpu().numpy()
            best = max(best, min(1.0, float(observed @ pattern / np.linalg.norm(observed))))
    return best


def reference_value(feature: Feature, records: ImageRecords, n: int, regions: tuple[Region, ...] = ()) -> float:
    """Eq. 3.14 (max over the applicable salient points, inside all ``regions``) in image ``n``,
    Boolean rules of 3.5.2; a Within adds its region to those of every leaf inside it."""
    if isinstance(feature, Within):
        return reference_value(feature.feature, records, n, (*regions, feature.region))
    if isinstance(feature, Texture):
        return texture_value(feature, records, n, regions)
    if not isinstance(feature, LocalFeature):
        a, b = (reference_value(sub, records, n, regions) for sub in feature.subfeatures())
        return a * b if isinstance(feature, Conjunction) else max(a, b)
    levels = int(records.levels[n])
    height, width = (int(v) for v in records.sizes[n])
    pyramid = records[n].responses[0, :levels, :, :height, :width].double().cpu().numpy()
    want_edgel = feature.parts[0].kind == "edgel"
    grid = texture_grid(records, n) if any(part.kind == "texture" for part in feature.parts) else None
    best = 0.0
    for p in range(records.mask.shape[1]):
        if not bool(records.mask[n, p]) or (int(records.kind[n, p]) == EDGEL) != want_edgel:
            continue
        args = (float(records.x[n, p]), float(records.y[n, p]), float(records.sigma[n, p]), float(records.theta[n, p]))
        if not all(region_holds(r, records, n, *args[:2]) for r in regions):
            continue
        value = local_value_at(feature, pyramid, *args, grid)
        if value is not None:
            best = max(best, value)
    return best


def reference_values(features, records: ImageRecords) -> np.ndarray:
    """Feature values by the per-point loop (the test oracle of ``feature_values``).

    Args:
        features: F features.
        records: the records of N images.

    Returns:
        the values (eq. 3.14), float64.

    Shape:
        - Output: :math:`(F, N)`.
    """
    return np.array([[reference_value(f, records, n) for n in range(len(records))] for f in features])
