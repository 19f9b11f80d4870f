"""Random prism cross-sections (6.5 step 1): roughly square, roughly equilateral triangular, cylindrical.

A boundary is a closed chain of circular arcs: each face of a polygon is an arc bulging outwards
by a sagitta of ``BULGE`` times its length (so the contact normal turns along a face and the
controller's descent never stalls on a flat face), and a cylinder is one full circle. Corners
are sharp: a fingertip cannot rest on a vertex (it slips over to the next face, see
:mod:`training.grasping.haptics`).

Parametric distributions (lengths in object units, the camera maps 1 unit to 0.4 image widths):
- square: sides a ~ U(0.9, 1.1), b = a * U(0.9, 1.1); every vertex moved by N(0, 0.02^2) per axis;
- triangle: equilateral of side U(1.1, 1.3), every vertex moved by N(0, 0.03^2) per axis;
- cylinder: radius U(0.45, 0.6);
- every object: height U(0.5, 0.9), orientation psi ~ U(0, 2 pi), centred on its vertex mean.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

KINDS = ("square", "triangle", "cylinder")
SYMMETRY = {"square": 4, "triangle": 3, "cylinder": 0}  # rotational symmetry order, 0 = any rotation
BULGE = 0.02


@dataclass(frozen=True)
class GraspObject:
    """A prism: its kind, orientation psi, height, and its boundary as arcs (centre, radius, start, span)."""

    kind: str
    psi: float
    height: float
    vertices: np.ndarray  # (n, 2) counter-clockwise, empty for a cylinder
    centres: np.ndarray   # (m, 2)
    radii: np.ndarray     # (m,)
    starts: np.ndarray    # (m,) angle of each arc's first point seen from its centre
    spans: np.ndarray     # (m,) angular extent, counter-clockwise

    @property
    def symmetry(self) -> int:
        return SYMMETRY[self.kind]

    @property
    def size(self) -> float:
        """Characteristic length: twice the mean distance of the boundary from the centre."""
        return 2 * float(np.mean(np.hypot(*self.outline(64).T)))

    def point(self, arc: np.ndarray, angle: np.ndarray) -> np.ndarray:
        unit = np.stack([np.cos(angle), np.sin(angle)], -1)
        return self.centres[arc] + self.radii[arc, None] * unit

    def outline(self, per_arc: int = 24) -> np.ndarray:
        """(m * per_arc, 2) boundary points, counter-clockwise."""
        t = np.arange(per_arc) / per_arc
        arcs = np.repeat(np.arange(len(self.radii)), per_arc)
        return self.point(arcs, self.starts[arcs] + self.spans[arcs] * np.tile(t, len(self.radii)))


def polygon_object(kind: str, vertices: np.ndarray, psi: float, height: float) -> GraspObject:
    """Arcs through consecutive vertices (counter-clockwise), bulging out by BULGE x face length."""
    v = vertices - vertices.mean(0)
    c, s = math.cos(psi), math.sin(psi)
    v = v @ np.array([[c, s], [-s, c]])
    a, b = v, np.roll(v, -1, 0)
    chord = b - a
    length = np.hypot(*chord.T)
    tangent = chord / length[:, None]
    normal = np.stack([tangent[:, 1], -tangent[:, 0]], 1)  # outward for a counter-clockwise polygon
    sagitta = BULGE * length
    radius = (length ** 2 / 4 + sagitta ** 2) / (2 * sagitta)
    half = np.arcsin(length / 2 / radius)
    centre = (a + b) / 2 - normal * (radius - sagitta)[:, None]
    starts = np.arctan2(normal[:, 1], normal[:, 0]) - half
    return GraspObject(kind, psi, height, v, centre, radius, starts, 2 * half)


def random_object(kind: str, rng: np.random.Generator) -> GraspObject:
    """One object of ``kind`` drawn from the distributions in the module docstring."""
    psi = float(rng.uniform(0, 2 * math.pi))
    height = float(rng.uniform(0.5, 0.9))
    if kind == "cylinder":
        r = float(rng.uniform(0.45, 0.6))
        return GraspObject(kind, psi, height, np.zeros((0, 2)), np.zeros((1, 2)), np.array([r]), np.array([psi]),
                           np.array([2 * math.pi]))
    if kind == "square":
        a = rng.uniform(0.9, 1.1)
        b = a * rng.uniform(0.9, 1.1)
        v = np.array([[-a, -b], [a, -b], [a, b], [-a, b]]) / 2 + rng.normal(0, 0.02, (4, 2))
    elif kind == "triangle":
        side = rng.uniform(1.1, 1.3)
        angles = math.pi / 2 + np.arange(3) * 2 * math.pi / 3
        v = side / math.sqrt(3) * np.stack([np.cos(angles), np.sin(angles)], 1) + rng.normal(0, 0.03, (3, 2))
    else:
        raise ValueError(f"object kind must be one of {KINDS}, got {kind!r}")
    return polygon_object(kind, v, psi, height)
