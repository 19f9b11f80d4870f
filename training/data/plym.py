"""The built-in Plym-like task (4.5.2): eight untextured geometric solids rendered by a small torch renderer.

Objects (names as in table 4.5): con6 (six-sided cone), cube, cucon (cube + cone), cucy (cube
+ cylinder), cycu (cylinder with a box protruding from its side), cyl3 and cyl6 (three- and
six-sided prisms) and tub6 (hollow six-sided prism). Each is a signed-distance function (exact
or a lower bound, which sphere tracing allows), unions are minima and the cavity a maximum
with the negated inner solid.

Views (15 per object, in this order): azimuth -10..10 degrees in 2-degree steps about the
vertical axis at 25 degrees elevation, then elevations 15 and 35 at azimuth 0, then in-plane
rotations of -10 and +10 degrees. Neighbouring views in this order are split alternately
between training and test sets (8 and 7 per class).

Rendering: a pinhole camera 6 units from the origin; rays are sphere-traced (96 steps) at
twice the output resolution; surfaces are Lambertian under one directional light plus
ambient light, on a flat grey background (0.35); the picture is area-averaged to the output size and
given faint Gaussian sensor noise (sigma 0.004) drawn from the seed. Everything else is fixed,
so the same seed gives the same images.
"""
from __future__ import annotations

import math

import torch
from torch import Tensor
from torch.nn.functional import avg_pool2d

OBJECTS = ("con6", "cube", "cucon", "cucy", "cycu", "cyl3", "cyl6", "tub6")
ELEVATION = 25.0
BACKGROUND = 0.35
VIEWS = [(az, ELEVATION, 0.0) for az in range(-10, 11, 2)] + [(0, ELEVATION - 10, 0.0), (0, ELEVATION + 10, 0.0),
                                                             (0, ELEVATION, -10.0), (0, ELEVATION, 10.0)]


def _box(p: Tensor, centre, half) -> Tensor:
    q = (p - torch.tensor(centre, dtype=p.dtype)).abs() - torch.tensor(half, dtype=p.dtype)
    return q.clamp_min(0).norm(dim=-1) + q.max(-1).values.clamp_max(0)


def _cylinder(p: Tensor, centre, radius: float, half_height: float, axis: int = 1) -> Tensor:
    q = p - torch.tensor(centre, dtype=p.dtype)
    others = [i for i in range(3) if i != axis]
    d = torch.stack([q[..., others].norm(dim=-1) - radius, q[..., axis].abs() - half_height], -1)
    return d.clamp_min(0).norm(dim=-1) + d.max(-1).values.clamp_max(0)


def _prism(p: Tensor, sides: int, radius: float, y0: float, y1: float, turn: float = 0.0) -> Tensor:
    """Upright regular prism (lower bound: the largest plane distance)."""
    angles = torch.arange(sides, dtype=p.dtype) * (2 * math.pi / sides) + turn
    apothem = radius * math.cos(math.pi / sides)
    faces = p[..., 0:1] * torch.cos(angles) + p[..., 2:3] * torch.sin(angles) - apothem
    return torch.maximum(faces.max(-1).values, torch.maximum(y0 - p[..., 1], p[..., 1] - y1))


def _pyramid(p: Tensor, sides: int, radius: float, y0: float, height: float, round_: bool = False) -> Tensor:
    """Upright cone (round, or with ``sides`` faces) with base at y0 (lower bound)."""
    slope = math.hypot(height, radius)
    if round_:
        r = p[..., [0, 2]].norm(dim=-1)
    else:
        angles = torch.arange(sides, dtype=p.dtype) * (2 * math.pi / sides)
        r = (p[..., 0:1] * torch.cos(angles) + p[..., 2:3] * torch.sin(angles)).max(-1).values
        radius = radius * math.cos(math.pi / sides)
        slope = math.hypot(height, radius)
    lateral = (r * height + (p[..., 1] - y0) * radius - radius * height) / slope
    return torch.maximum(lateral, y0 - p[..., 1])


def solid(name: str, p: Tensor) -> Tensor:
    """Signed distance (lower bound) from points p (..., 3) to object ``name``, about one unit tall, centred."""
    if name == "con6":
        return _pyramid(p, 6, 0.9, -0.7, 1.5)
    if name == "cube":
        return _box(p, (0, 0, 0), (0.6, 0.6, 0.6))
    if name == "cucon":
        return torch.minimum(_box(p, (0, -0.35, 0), (0.5, 0.45, 0.5)), _pyramid(p, 0, 0.5, 0.1, 0.8, round_=True))
    if name == "cucy":
        return torch.minimum(_box(p, (0, -0.35, 0), (0.55, 0.45, 0.55)), _cylinder(p, (0, 0.4, 0), 0.35, 0.35))
    if name == "cycu":
        return torch.minimum(_cylinder(p, (0, 0, 0), 0.55, 0.75), _box(p, (0.55, 0.1, 0.25), (0.3, 0.18, 0.15)))
    if name == "cyl3":
        return _prism(p, 3, 0.85, -0.7, 0.7, turn=math.pi / 6)
    if name == "cyl6":
        return _prism(p, 6, 0.7, -0.7, 0.7)
    if name == "tub6":
        return torch.maximum(_prism(p, 6, 0.7, -0.7, 0.7), -_prism(p, 6, 0.5, -0.6, 0.8))
    raise ValueError(f"unknown Plym object {name!r}; known: {', '.join(OBJECTS)}")


def _rotation(azimuth: float, elevation: float, roll: float) -> Tensor:
    """Camera-to-world rotation (columns: right, up, backward) for a camera on a sphere looking at the origin."""
    a, e, r = (math.radians(v) for v in (azimuth, elevation, roll))
    back = torch.tensor([math.sin(a) * math.cos(e), math.sin(e), math.cos(a) * math.cos(e)], dtype=torch.float64)
    right = torch.linalg.cross(torch.tensor([0.0, 1.0, 0.0], dtype=torch.float64), back)
    right = right / right.norm()
    up = torch.linalg.cross(back, right)
    c, s = math.cos(r), math.sin(r)
    return torch.stack([c * right + s * up, -s * right + c * up, back], 1)


def render(name: str, view: tuple[float, float, float], size: int = 64, distance: float = 6.0,
           focal: float = 5.0) -> Tensor:
    """One grey image (size, size) in [0, 1] of object ``name`` from ``view`` = (azimuth, elevation, roll)."""
    n = 2 * size
    rot = _rotation(*view)
    u = (torch.arange(n, dtype=torch.float64) + 0.5) / n * 2 - 1
    yy, xx = torch.meshgrid(-u, u, indexing="ij")
    direction = torch.stack([xx, yy, torch.full_like(xx, -focal)], -1) @ rot.T
    direction = direction / direction.norm(dim=-1, keepdim=True)
    origin = rot[:, 2] * distance
    t = torch.zeros(n, n, dtype=torch.float64)
    for _ in range(96):
        t = t + solid(name, origin + t[..., None] * direction).clamp_min(0) * 0.9
    point = origin + t[..., None] * direction
    hit = solid(name, point).abs() < 2e-3
    eps = 1e-4
    normal = torch.stack([solid(name, point + eps * e) - solid(name, point - eps * e) for e in torch.eye(3, dtype=torch.float64)], -1)
    normal = normal / normal.norm(dim=-1, keepdim=True).clamp_min(1e-12)
    light = torch.tensor([-0.5, 0.8, 0.6], dtype=torch.float64)
    shade = 0.15 + 0.8 * (normal @ (light / light.norm())).clamp_min(0)
    image = torch.where(hit, shade, torch.full_like(shade, BACKGROUND))
    return avg_pool2d(image[None, None], 2)[0, 0].float()


def plym_layout() -> tuple[list[str], list[str], list[int]]:
    """(labels, names, position of the view in its object's sequence) of all 8 x 15 views in
    :func:`plym_images`'s order, without rendering any (what a request can be checked against)."""
    return ([name for name in OBJECTS for _ in VIEWS], [f"{name}_v{k:02d}" for name in OBJECTS for k in range(len(VIEWS))],
            [k for _ in OBJECTS for k in range(len(VIEWS))])


def plym_images(size: int = 64, seed: int = 0) -> tuple[list[Tensor], list[str], list[str], list[int]]:
    """All 8 x 15 views: (images, labels, names, position of the view in its object's sequence)."""
    g = torch.Generator().manual_seed(int(seed))
    images = []
    for name in OBJECTS:
        for view in VIEWS:
            image = render(name, view, size)
            noise = torch.randn(image.shape, generator=g) * 0.004
            images.append((image + noise).clamp(0, 1))
    return images, *plym_layout()
