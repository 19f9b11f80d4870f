"""Pictures of salient points and features in the style of figures 3.9 and 3.11.

Images are drawn enlarged (OpenCV, anti-aliased) and returned as RGB uint8 arrays.
Edgels are segments of length 2*sigma along the edge (across the gradient) centred on the
point; blobs are circles and corners squares of radius sigma, each with a line from the
centre along its orientation.
"""
from __future__ import annotations

import math

import cv2
import numpy as np
from torch import Tensor

from .record import ImageRecords
from .salient import BLOB, CORNER, EDGEL

EDGEL_COLOUR = (220, 40, 40)
BLOB_COLOUR = (40, 200, 60)
CORNER_COLOUR = (40, 120, 255)


def _canvas(records: ImageRecords, n: int, image: Tensor | np.ndarray, min_side: int) -> tuple[np.ndarray, float]:
    height, width = (int(v) for v in records.sizes[n])
    grey = np.asarray(image.detach().cpu() if isinstance(image, Tensor) else image, dtype=np.float64).reshape(height, width)
    lo, hi = float(grey.min()), float(grey.max())
    grey = (grey - lo) / (hi - lo) if hi > lo else np.zeros_like(grey)
    zoom = max(1.0, min_side / min(height, width))
    big = cv2.resize((grey * 255).astype(np.uint8), (round(width * zoom), round(height * zoom)), interpolation=cv2.INTER_NEAREST)
    faded = (0.55 * big + 0.45 * 255).astype(np.uint8)
    return cv2.cvtColor(faded, cv2.COLOR_GRAY2RGB), zoom


def _centre(x: float, y: float, zoom: float) -> tuple[float, float]:
    return (x + 0.5) * zoom - 0.5, (y + 0.5) * zoom - 0.5


def _line(canvas, a, b, colour, width=1):
    shift = 4
    p = tuple(int(round(v * 16)) for v in a)
    q = tuple(int(round(v * 16)) for v in b)
    cv2.line(canvas, p, q, colour, width, cv2.LINE_AA, shift)


def draw_marker(canvas: np.ndarray, kind: int, x: float, y: float, sigma: float, theta: float, zoom: float,
                colour=None, width: int = 1) -> None:
    """Draw one salient point or feature location onto ``canvas`` (enlarged by ``zoom``)."""
    cx, cy = _centre(x, y, zoom)
    r = sigma * zoom
    c, s = math.cos(theta), math.sin(theta)
    if kind == EDGEL:
        _line(canvas, (cx - s * r, cy + c * r), (cx + s * r, cy - c * r), colour or EDGEL_COLOUR, width)
        return
    colour = colour or (BLOB_COLOUR if kind == BLOB else CORNER_COLOUR)
    if kind == CORNER:
        corners = [(cx - r, cy - r), (cx + r, cy - r), (cx + r, cy + r), (cx - r, cy + r)]
        for a, b in zip(corners, corners[1:] + corners[:1]):
            _line(canvas, a, b, colour, width)
    else:
        cv2.circle(canvas, (int(round(cx * 16)), int(round(cy * 16))), int(round(r * 16)), colour, width, cv2.LINE_AA, 4)
    _line(canvas, (cx, cy), (cx + c * r, cy + s * r), colour, width)


def draw_salient(records: ImageRecords, n: int, image, min_side: int = 384) -> np.ndarray:
    """Figure 3.9: edgels (left panel) and texels (right panel) of image n, RGB uint8."""
    left, zoom = _canvas(records, n, image, min_side)
    right = left.copy()
    points = records.mask[n].nonzero()[:, 0].tolist()
    for p in points:
        kind = int(records.kind[n, p])
        values = (float(records.x[n, p]), float(records.y[n, p]), float(records.sigma[n, p]), float(records.theta[n, p]))
        draw_marker(left if kind == EDGEL else right, kind, *values, zoom)
    gap = np.full((left.shape[0], 8, 3), 255, np.uint8)
    return np.concatenate([left, gap, right], axis=1)


def save_rgb(path, picture: np.ndarray) -> None:
    """Write an RGB uint8 array as PNG."""
    if not cv2.imwrite(str(path), cv2.cvtColor(picture, cv2.COLOR_RGB2BGR)):
        raise OSError(f"could not write {path}")

