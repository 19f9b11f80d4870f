"""The planar grasp simulator: mu_0 against closed forms and brute force, the controller, the camera."""
import math

import numpy as np
import pytest
import torch

from ftorch import FeatureSpace
from training.grasping.camera import render
from training.grasping.haptics import HapticController, hand_orientation, min_friction, symmetry_period
from training.grasping.objects import BULGE, polygon_object, random_object


def _unit(degrees):
    angle = np.radians(np.asarray(degrees, dtype=float))
    return np.stack([np.cos(angle), np.sin(angle)], -1)


def test_two_contacts_closed_form():
    points = np.array([[-1.0, 0.0], [1.0, 0.0]])
    assert min_friction(points, _unit([180, 0])) == pytest.approx(0.0, abs=1e-12)
    # normals tilted by 20 and 10 degrees from the line through the contacts: tan of the larger
    assert min_friction(points, _unit([160, 10])) == pytest.approx(math.tan(math.radians(20)))
    # a normal facing away from the other contact: no equilibrium at any friction
    assert min_friction(points, _unit([180, 180])) == math.inf
    # both fingertips on one point (seen in the seed-6 study: it gave mu_0 = NaN): no equilibrium
    assert min_friction(np.array([[1.0, 0.0], [1.0, 0.0]]), _unit([180, 0])) == math.inf


def _solved_three(points, normals):
    """With equal unit normal forces, three tangential forces t_k balancing force and torque are
    unique where the 3x3 system is regular: mu_0 = max |t_k| (no optimisation needed)."""
    inward = -normals
    tangent = np.stack([-inward[:, 1], inward[:, 0]], 1)
    a = np.vstack([tangent.T, points[:, 0] * tangent[:, 1] - points[:, 1] * tangent[:, 0]])
    b = -np.array([*inward.sum(0), (points[:, 0] * inward[:, 1] - points[:, 1] * inward[:, 0]).sum()])
    t = np.linalg.solve(a, b)
    return np.abs(t).max()


def test_three_contacts_linear_program():
    # equilateral triangle, contacts at the face centres: frictionless equilibrium
    normals = _unit([90, 210, 330])
    assert min_friction(0.3 * normals, normals) == pytest.approx(0.0, abs=1e-9)
    # a square held on three faces: friction must carry the unbalanced finger (0.5 each side)
    points, normals = np.array([[-0.5, 0.0], [0.5, 0.0], [0.0, -0.5]]), _unit([180, 0, 270])
    assert min_friction(points, normals) == pytest.approx(0.5, abs=1e-9)
    rng = np.random.default_rng(0)
    for _ in range(20):
        angles = rng.uniform(0, 360, 3)
        points = _unit(angles) * rng.uniform(0.4, 0.6, (3, 1))
        normals = _unit(angles + rng.normal(0, 15, 3))
        assert min_friction(points, normals) == pytest.approx(_solved_three(points, normals), rel=1e-6)


def test_hand_orientation_follows_figure_6_7():
    assert math.degrees(hand_orientation(_unit([30, 210]))) == pytest.approx(30)
    assert math.degrees(hand_orientation(0.5 * _unit([-40, 80, 200]))) == pytest.approx(-40)


def test_symmetry_periods():
    assert math.degrees(symmetry_period(4)) == pytest.approx(90)
    assert math.degrees(symmetry_period(3)) == pytest.approx(120)
    assert symmetry_period(0) == 0.0


def test_objects_boundary_is_closed_and_bulges():
    rng = np.random.default_rng(1)
    for kind in ("square", "triangle"):
        obj = random_object(kind, rng)
        ends = obj.point(np.arange(len(obj.radii)), obj.starts + obj.spans)
        starts = obj.point(np.roll(np.arange(len(obj.radii)), -1), np.roll(obj.starts, -1))
        assert np.allclose(ends, starts, atol=1e-9)  # each face ends where the next begins: at a vertex
        assert np.allclose(ends, np.roll(obj.vertices, -1, 0), atol=1e-9)
        middle = obj.point(np.arange(len(obj.radii)), obj.starts + obj.spans / 2)
        chord = np.hypot(*(np.roll(obj.vertices, -1, 0) - obj.vertices).T)
        edge, offset = np.roll(obj.vertices, -1, 0) - obj.vertices, middle - obj.vertices
        to_chord = np.abs(edge[:, 0] * offset[:, 1] - edge[:, 1] * offset[:, 0]) / chord
        assert np.allclose(to_chord, BULGE * chord, rtol=1e-9)


def test_controller_converges_from_a_good_start_and_is_repeatable():
    square = polygon_object("square", np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]]), 0.3, 0.7)
    controller = HapticController()
    cued = controller.grasp(square, 2, 0.3, np.random.default_rng(5))
    assert cued.converged and cued.probes <= 3 and cued.mu0 < 0.1
    assert math.degrees(abs(math.remainder(cued.theta_H - 0.3, math.pi / 2))) < 5
    again = controller.grasp(square, 2, 0.3, np.random.default_rng(5))
    assert (again.theta_H, again.mu0, again.probes) == (cued.theta_H, cued.mu0, cued.probes)


def test_finger_count_decides_quality():
    """Figure 6.8: squares are grasped well with two fingers, triangles with three, never the other way."""
    controller, rng = HapticController(), np.random.default_rng(2)
    mu0 = {}
    for kind, fingers in (("square", 2), ("square", 3), ("triangle", 2), ("triangle", 3)):
        mu0[kind, fingers] = np.median([controller.grasp(random_object(kind, rng), fingers, rng.uniform(0, 6.3), rng).mu0
                                        for _ in range(30)])
    assert mu0["square", 2] < 0.2 and mu0["triangle", 3] < 0.2
    assert mu0["square", 3] > 0.4 and mu0["triangle", 2] > math.tan(math.radians(30)) - 0.01


def test_camera_edges_have_the_world_orientation():
    """eq. 6.2 needs image and world angles to agree: the strongest edgels of a rendered square
    point along its face normals."""
    square = polygon_object("square", np.array([[-0.5, -0.5], [0.5, -0.5], [0.5, 0.5], [-0.5, 0.5]]), 0.4, 0.0001)
    image = render(square, 64, np.random.default_rng(0), noise=0.0)
    assert image.shape == (64, 64) and image.dtype == np.float32 and 0 <= image.min() < image.max() <= 1
    records = FeatureSpace()(torch.from_numpy(image)[None, None])
    edgels = records.edgel_mask()[0]
    theta = records.theta[0][edgels].double().numpy()
    strength = records.strength[0][edgels].double().numpy()
    strongest = theta[np.argsort(strength)[-20:]]
    # the top face is brighter than the ground: gradients point inwards, i.e. along -normal
    deviation = np.abs(np.remainder(strongest - 0.4 + math.pi / 4, math.pi / 2) - math.pi / 4)
    assert np.degrees(np.median(deviation)) < 5
