"""The overhead camera (figure 6.12): shaded prism tops with a cast shadow and sensor noise.

An orthographic view from above; the world's x axis is the image column and its y axis the
image row, so an angle in the world and the same angle measured in the image agree (eq. 6.2
needs theta_H - theta_f constant, not a reflection of it). One object unit spans
``UNITS_PER_IMAGE``^-1 of the image width. The light comes from azimuth ``LIGHT_AZIMUTH`` at
elevation ``LIGHT_ELEVATION``: the prism of height h casts its top outline swept by
h / tan(elevation) away from the light (the convex hull of the two outlines). The ground is a
smooth random texture, the shadow darkens it, the top face is brighter with a gentle gradient
toward the light. Polygons are filled at 4x resolution and averaged down (anti-aliasing); the
sensor adds Gaussian noise. Every random choice comes from the rng passed in.
"""
from __future__ import annotations

import math

import cv2
import numpy as np

from .objects import GraspObject

UNITS_PER_IMAGE = 2.5
LIGHT_AZIMUTH = math.radians(225.0)
LIGHT_ELEVATION = math.radians(50.0)
SUPERSAMPLE = 4


def _fill(canvas: np.ndarray, points: np.ndarray, value: float) -> None:
    cv2.fillPoly(canvas, [np.round(points * 16).astype(np.int32)], float(value), lineType=cv2.LINE_AA, shift=4)


def render(obj: GraspObject, size: int, rng: np.random.Generator, noise: float = 0.02) -> np.ndarray:
    """A (size, size) float32 image in [0, 1] of ``obj`` near the image centre."""
    big = size * SUPERSAMPLE
    scale = big / UNITS_PER_IMAGE
    centre = big / 2 + rng.uniform(-0.05, 0.05, 2) * big
    outline = obj.outline(48) * scale + centre
    away = -np.array([math.cos(LIGHT_AZIMUTH), math.sin(LIGHT_AZIMUTH)])
    shifted = outline + away * obj.height / math.tan(LIGHT_ELEVATION) * scale
    shadow_region = cv2.convexHull(np.concatenate([outline, shifted]).astype(np.float32))[:, 0]

    texture = cv2.resize(rng.normal(0, 1, (8, 8)).astype(np.float32), (big, big), interpolation=cv2.INTER_CUBIC)
    ground = 0.45 + 0.04 * texture
    shadow = np.zeros((big, big), np.float32)
    _fill(shadow, shadow_region, 1.0)
    top = np.zeros((big, big), np.float32)
    _fill(top, outline, 1.0)
    rows, cols = np.mgrid[0:big, 0:big].astype(np.float32)
    toward = (np.cos(LIGHT_AZIMUTH) * (cols - centre[0]) + np.sin(LIGHT_AZIMUTH) * (rows - centre[1])) / big
    face = 0.8 + 0.15 * toward
    image = ground * (1 - 0.45 * shadow)
    image = image * (1 - top) + face * top
    image = cv2.resize(image, (size, size), interpolation=cv2.INTER_AREA)
    image = image + rng.normal(0, noise, image.shape)
    return np.clip(image, 0, 1).astype(np.float32)
