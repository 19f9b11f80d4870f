"""The built-in default image: a deterministic synthetic scene that needs no files.

Shaded geometric shapes (a disc, an ellipse, a rotated square, a triangle, a ring and small
blobs) on a smooth gradient, drawn 4x supersampled with anti-aliasing, reduced by area
averaging and given faint sensor noise from the seed. It offers blobs, corners and edges at
several scales, which is what figure 3.9 shows.
"""
from __future__ import annotations

import cv2
import numpy as np


def builtin_scene(size: int = 128, seed: int = 0) -> np.ndarray:
    """Grey float32 image (size, size) in [0, 1]."""
    if size < 16:
        raise ValueError(f"builtin_scene: size must be at least 16, got {size}")
    up = 4
    n = size * up
    yy, xx = np.mgrid[0:n, 0:n] / n
    canvas = (0.35 + 0.25 * xx + 0.1 * yy).astype(np.float32)

    def pt(x, y):
        return int(round(x * n * 16)), int(round(y * n * 16))

    aa = dict(lineType=cv2.LINE_AA, shift=4)
    cv2.circle(canvas, pt(0.27, 0.3), int(0.13 * n * 16), 0.08, -1, **aa)
    cv2.ellipse(canvas, pt(0.72, 0.28), (int(0.17 * n * 16), int(0.08 * n * 16)), 25, 0, 360, 0.9, -1, **aa)
    square = cv2.boxPoints(((0.3 * n, 0.72 * n), (0.22 * n, 0.22 * n), 20)) * 16
    cv2.fillPoly(canvas, [square.astype(np.int32)], 0.95, **aa)
    triangle = np.array([pt(0.62, 0.55), pt(0.9, 0.62), pt(0.7, 0.88)], dtype=np.int32)
    cv2.fillPoly(canvas, [triangle], 0.15, **aa)
    cv2.circle(canvas, pt(0.5, 0.5), int(0.06 * n * 16), 0.75, int(0.02 * n), **aa)
    for x, y, r, v in ((0.47, 0.12, 0.02, 0.05), (0.1, 0.55, 0.03, 0.9), (0.88, 0.9, 0.025, 0.1), (0.55, 0.35, 0.015, 0.95)):
        cv2.circle(canvas, pt(x, y), int(r * n * 16), v, -1, **aa)
    image = cv2.resize(canvas, (size, size), interpolation=cv2.INTER_AREA)
    noise = np.random.default_rng(seed).normal(0.0, 0.002, image.shape).astype(np.float32)
    return np.clip(image + noise, 0.0, 1.0)
