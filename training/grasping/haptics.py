"""A haptic grasp controller on planar prisms (6.3.1) and its grasp quality mu_0.

Pre-shaping (figure 6.7): the hand at azimuth theta_h touches the boundary where the rays from
the object centre at theta_h + 2 pi k / c meet it (finger k = 0 .. c-1). The hand orientation
of a grasp is theta_H = arg sum_k exp(i (phi_k - 2 pi k / c)), phi_k the polar angle of contact k:
the ray of finger 0 for a symmetric hand, as in the figure.

Control (Coelho's native controller, planar): each finger presses with unit force along its
inward normal; the wrench residual is rho = (sum f_k, sum p_k x f_k / L), L the object's mean
radius, and epsilon = rho^T rho. A probe senses contact normals (angle noise ``normal_noise``)
and moves the one contact whose Gauss-Newton step along the boundary promises the largest
decrease of epsilon, by at most ``max_step``. A contact pushed past a face's end slips over the
vertex onto the next face (a fingertip of radius ``fingertip`` cannot rest on a corner). The
grasp has converged when the sensed epsilon is below ``tolerance`` or no step promises a
decrease above ``tolerance / 20``; it is abandoned after ``max_probes`` probes. The first touch
counts as probe 1.

Quality mu_0 (the smallest friction coefficient admitting equilibrium at the final contacts):
two contacts balance only by equal and opposite forces along the line through them, so
mu_0 = tan of the larger angle between that line and the inward normals (infinite beyond 90
degrees); three contacts press with equal unit normal forces and friction takes up the residual
wrench: mu_0 = min max_k |t_k| over tangential forces t_k giving equilibrium, a linear program.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.optimize import linprog

from .objects import GraspObject


@dataclass(frozen=True)
class GraspOutcome:
    fingers: int
    theta_h: float       # initial hand azimuth (radians)
    theta_H: float       # final hand orientation
    mu0: float           # grasp quality, lower is better (inf: no equilibrium)
    probes: int
    converged: bool
    contacts: np.ndarray  # (c, 2) final contact points

    def to_dict(self) -> dict:
        return {"fingers": self.fingers, "theta_h": self.theta_h, "theta_H": self.theta_H,
                "mu0": self.mu0 if math.isfinite(self.mu0) else None, "probes": self.probes,
                "converged": self.converged}


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return a[..., 0] * b[..., 1] - a[..., 1] * b[..., 0]


def _unit(angle: np.ndarray) -> np.ndarray:
    return np.stack([np.cos(angle), np.sin(angle)], -1)


def hand_orientation(points: np.ndarray) -> float:
    """theta_H of contacts (c, 2) around the object centre (the origin), finger k at k * 2 pi / c."""
    c = len(points)
    phi = np.arctan2(points[:, 1], points[:, 0]) - 2 * math.pi * np.arange(c) / c
    return float(np.angle(np.exp(1j * phi).sum()))


def min_friction(points: np.ndarray, normals: np.ndarray) -> float:
    """mu_0 of contacts (c, 2) with outward unit normals (c, 2), c = 2 (closed form) or 3 (LP)."""
    inward = -normals
    if len(points) == 2:
        line = points[1] - points[0]
        length = np.linalg.norm(line)
        if length < 1e-12:  # both fingertips on one point (slipped to one vertex): no squeezing line
            return math.inf
        line = line / length
        cosines = np.array([inward[0] @ line, -(inward[1] @ line)])
        if cosines.min() <= 1e-12:
            return math.inf
        return float(np.tan(np.arccos(np.clip(cosines.min(), -1, 1))))
    tangent = np.stack([-inward[:, 1], inward[:, 0]], 1)
    # unknowns t_1..t_c, mu: minimise mu with sum(inward + t tangent) = 0 and zero torque, |t_k| <= mu
    c = len(points)
    a_eq = np.zeros((3, c + 1))
    a_eq[:2, :c] = tangent.T
    a_eq[2, :c] = _cross(points, tangent)
    b_eq = -np.array([*inward.sum(0), _cross(points, inward).sum()])
    a_ub = np.zeros((2 * c, c + 1))
    a_ub[:c, :c], a_ub[c:, :c] = np.eye(c), -np.eye(c)
    a_ub[:, c] = -1
    result = linprog(np.eye(c + 1)[c], A_ub=a_ub, b_ub=np.zeros(2 * c), A_eq=a_eq, b_eq=b_eq,
                     bounds=[(None, None)] * c + [(0, None)], method="highs")
    return float(result.x[c]) if result.status == 0 else math.inf


class HapticController:
    """Simulated haptic grasping (module docstring); every random choice comes from the rng passed in."""

    def __init__(self, normal_noise_deg: float = 3.0, max_step: float = 0.04, fingertip: float = 0.08,
                 tolerance: float = 0.01, stall: float = 0.05, max_probes: int = 30):
        self.normal_noise = math.radians(normal_noise_deg)
        self.max_step, self.fingertip = max_step, fingertip
        self.tolerance, self.stall, self.max_probes = tolerance, stall, max_probes

    def _limits(self, obj: GraspObject, arc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        margin = self.fingertip / obj.radii[arc]
        return obj.starts[arc] + margin, obj.starts[arc] + obj.spans[arc] - margin

    def place(self, obj: GraspObject, theta_h: float, fingers: int) -> tuple[np.ndarray, np.ndarray]:
        """Contacts (arc, angle) where the pre-shaped hand at theta_h first touches the object."""
        outline = obj.outline(64)
        arcs = np.repeat(np.arange(len(obj.radii)), 64)
        local = np.tile(np.arange(64) / 64, len(obj.radii))
        polar = np.arctan2(outline[:, 1], outline[:, 0])
        rays = theta_h + 2 * math.pi * np.arange(fingers) / fingers
        nearest = np.abs(np.angle(np.exp(1j * (polar[None, :] - rays[:, None])))).argmin(1)
        arc = arcs[nearest]
        angle = obj.starts[arc] + obj.spans[arc] * local[nearest]
        if obj.kind != "cylinder":
            low, high = self._limits(obj, arc)
            angle = np.clip(angle, low, high)
        return arc, angle

    def _move(self, obj: GraspObject, arc: int, angle: float, ds: float) -> tuple[int, float]:
        angle = angle + ds / obj.radii[arc]
        if obj.kind == "cylinder":
            return arc, angle
        low, high = self._limits(obj, np.array([arc]))
        m = len(obj.radii)
        if angle > high[0]:
            arc = (arc + 1) % m
            return arc, float(self._limits(obj, np.array([arc]))[0][0])
        if angle < low[0]:
            arc = (arc - 1) % m
            return arc, float(self._limits(obj, np.array([arc]))[1][0])
        return arc, angle

    def _residual(self, obj: GraspObject, arc: np.ndarray, points: np.ndarray, direction: np.ndarray, scale: float):
        """rho (3,) and its derivatives (c, 3) along the boundary arc length of each contact, for
        contacts at ``points`` whose normals point along the angles ``direction``."""
        normal, tangent = _unit(direction), _unit(direction + math.pi / 2)
        force = -normal
        rho = np.array([*force.sum(0), _cross(points, force).sum() / scale])
        dforce = -tangent / obj.radii[arc, None]
        dtorque = (_cross(tangent, force) + _cross(points, dforce)) / scale
        return rho, np.concatenate([dforce, dtorque[:, None]], 1)

    def grasp(self, obj: GraspObject, fingers: int, theta_h: float, rng: np.random.Generator) -> GraspOutcome:
        """Run the controller from the pre-shape at theta_h until convergence or ``max_probes``."""
        if fingers not in (2, 3):
            raise ValueError(f"fingers must be 2 or 3, got {fingers}")
        arc, angle = self.place(obj, theta_h, fingers)
        scale = obj.size / 2
        probes, converged = 1, False
        while True:
            points = obj.point(arc, angle)
            sensed = angle + rng.normal(0, self.normal_noise, fingers)  # the normal's direction, noisy
            rho, jac = self._residual(obj, arc, points, sensed, scale)
            gain = (jac @ rho) ** 2 / np.maximum((jac ** 2).sum(1), 1e-12)
            if rho @ rho < self.tolerance or gain.max() < max(self.tolerance / 20, self.stall * (rho @ rho)):
                converged = True
                break
            if probes >= self.max_probes:
                break
            k = int(gain.argmax())
            step = float(np.clip(-(jac[k] @ rho) / (jac[k] @ jac[k]), -self.max_step, self.max_step))
            arc[k], angle[k] = self._move(obj, int(arc[k]), float(angle[k]), step)
            probes += 1
        points = obj.point(arc, angle)
        return GraspOutcome(fingers, float(theta_h), hand_orientation(points), min_friction(points, _unit(angle)), probes,
                            converged, points)


def symmetry_period(obj_symmetry: int) -> float:
    """Angle after which a grasp of the object repeats: 2 pi / its rotational symmetry order (6.5.1);
    0 where every orientation is equivalent (a cylinder). The fingers are labelled (finger 0 is
    the thumb of figure 6.7), so relabelling them is not a symmetry."""
    return 0.0 if obj_symmetry == 0 else 2 * math.pi / obj_symmetry
