"""Where a feature looks: a disc in the image frame or the object frame (beyond the thesis).

The thesis's feature value is its best match over all reference points of an image (eq. 3.14).
A :class:`Region` bounds that maximum to the reference points inside a disc, so that "an eye" can
become "an eye at the upper left": one more feature parameter, sampled general-to-specific (3.6),
the whole image first (``ftorch.space.generate.localize``; :class:`~ftorch.space.features.Within`).

Two frames, each a point's coordinates (u, v):

- :attr:`Frame.IMAGE`: u = (x + 0.5) / W, v = (y + 0.5) / H, of the image's own size (records'
  ``sizes``: padding in a batch changes nothing), so (0.5, 0.5) is the centre and the image is the
  unit square. A disc in these units is an ellipse in the pixels of a non-square image.
- :attr:`Frame.OBJECT`: u = (x - cx) / s, v = (y - cy) / s, where (cx, cy) is the coordinate-wise
  median of the image's salient points (all kinds) and s the median of their distances to it: a
  frame that moves and scales with the object. Medians, not means, so that a few clutter points
  do not move it (up to half the points may lie anywhere). torch's median of an even count is the
  lower of the two middle values. An image without salient points, or whose median distance is 0
  (more than half its points at one pixel), has no object frame: no point is inside its regions.

A point is inside a region when (u - x)^2 + (v - y)^2 <= radius^2.
"""
from __future__ import annotations

import math
import numbers
from dataclasses import dataclass
from enum import StrEnum
from typing import Sequence

import torch
from torch import Tensor

from ..errors import InputError
from .record import ImageRecords


class Frame(StrEnum):
    """The coordinates a region is given in (see the module docstring); its value is its JSON name."""

    IMAGE = "image"
    OBJECT = "object"


def as_frame(value: Frame | str) -> Frame:
    """``value`` (a :class:`Frame` or its name) as a frame; InputError for anything else."""
    try:
        return Frame(value)
    except (ValueError, TypeError):
        raise InputError(f"region frame must be 'image' or 'object', got {value!r}") from None


def _number(name: str, value) -> float:
    if isinstance(value, bool) or not isinstance(value, numbers.Real) or not math.isfinite(float(value)):
        raise InputError(f"region {name} must be a finite number, got {value!r}")
    return float(value)


@dataclass(frozen=True)
class Region:
    """A disc of ``radius`` around (x, y) in ``frame`` coordinates; immutable, hashable, JSON-exact."""

    frame: Frame
    x: float
    y: float
    radius: float

    def __post_init__(self):
        object.__setattr__(self, "frame", as_frame(self.frame))
        for name in ("x", "y", "radius"):
            object.__setattr__(self, name, _number(name, getattr(self, name)))
        if not self.radius > 0:
            raise InputError(f"region radius must be > 0, got {self.radius}")

    def to_dict(self) -> dict:
        return {"frame": str(self.frame), "x": self.x, "y": self.y, "radius": self.radius}

    @staticmethod
    def from_dict(data: dict) -> "Region":
        """The region that ``data`` (its :meth:`to_dict`) describes."""
        try:
            return Region(data["frame"], data["x"], data["y"], data["radius"])
        except (KeyError, TypeError) as err:
            raise InputError(f"not a region description: {data!r:.200} ({err})") from None

    def describe(self) -> str:
        """For legends: 'image region (0.31, 0.42; r 0.25)'."""
        return f"{self.frame} region ({self.x:.2f}, {self.y:.2f}; r {self.radius:.2f})"

    def order(self) -> tuple:
        """A sort key: the regions around one feature are kept in one order whatever their nesting."""
        return str(self.frame), self.x, self.y, self.radius


OBJECT_FRAME = "object frame"  # its key among a records object's cached reference points


def object_frames(records: ImageRecords) -> Tensor:
    """(N, 3): (cx, cy, s) of every image's object frame; NaN where an image has none. Found once
    per records object (records are never changed in place), as the reference points are."""
    known = records.reference_points
    if OBJECT_FRAME not in known:
        x = torch.where(records.mask, records.x, math.nan)
        y = torch.where(records.mask, records.y, math.nan)
        if x.shape[1] == 0:
            known[OBJECT_FRAME] = x.new_full((len(records), 3), math.nan)
        else:
            cx, cy = x.nanmedian(1).values, y.nanmedian(1).values  # NaN where an image has no point
            s = torch.hypot(x - cx[:, None], y - cy[:, None]).nanmedian(1).values
            known[OBJECT_FRAME] = torch.stack([cx, cy, torch.where(s > 0, s, math.nan)], 1)
    return known[OBJECT_FRAME]


def frame_coordinates(records: ImageRecords, frame: Frame | str, image: Tensor, x: Tensor,
                      y: Tensor) -> tuple[Tensor, Tensor]:
    """(u, v) in ``frame`` of K points (``x``, ``y`` in pixels, of images ``image``, all (K,)); NaN
    where the image has no object frame."""
    if Frame(frame) is Frame.IMAGE:
        size = records.sizes[image].to(x.dtype)
        return (x + 0.5) / size[:, 1], (y + 0.5) / size[:, 0]
    cx, cy, s = object_frames(records)[image].unbind(1)
    return (x - cx) / s, (y - cy) / s


def inside(regions: Sequence[Region], records: ImageRecords, image: Tensor, x: Tensor, y: Tensor) -> Tensor:
    """(R, K) bool: whether each of K points (as in :func:`frame_coordinates`) lies inside each of
    the R regions (never where its image has no object frame and the region is in that frame)."""
    frames = list(dict.fromkeys(r.frame for r in regions))
    coords = {f: frame_coordinates(records, f, image, x, y) for f in frames}
    out = torch.zeros(len(regions), len(x), dtype=torch.bool, device=x.device)
    for f in frames:  # at most two: the rows of each frame at once
        rows = [i for i, r in enumerate(regions) if r.frame is f]
        disc = torch.tensor([[regions[i].x, regions[i].y, regions[i].radius] for i in rows], dtype=x.dtype,
                            device=x.device)
        u, v = coords[f]
        out[rows] = (u - disc[:, :1]) ** 2 + (v - disc[:, 1:2]) ** 2 <= disc[:, 2:] ** 2  # NaN compares False
    return out


def pixel_ellipse(region: Region, records: ImageRecords, n: int) -> tuple[float, float, float, float] | None:
    """The region on image n in pixels: centre (x, y) and half-axes (along x, along y), an ellipse in
    the image frame of a non-square image; None where the image has no object frame."""
    if region.frame is Frame.IMAGE:
        height, width = (float(v) for v in records.sizes[n])
        return region.x * width - 0.5, region.y * height - 0.5, region.radius * width, region.radius * height
    cx, cy, s = (float(v) for v in object_frames(records)[n])
    if not math.isfinite(s):
        return None
    return cx + region.x * s, cy + region.y * s, region.radius * s, region.radius * s
