"""Generating candidate features from a sample image (alg. 4.10, methods 2 and 3; the texture
primitive of 7.2.1, alone or, where asked, as a part added by a geometric expansion, 3.5), and
bounding a feature to a region around its strongest occurrence (:func:`localize`,
general-to-specific as 3.6 orders the feature space).

Every generated part is measured exactly as :func:`ftorch.space.evaluate.feature_values` measures
it, so a feature sampled from an image has value 1 at its own reference point there.
Randomness comes only from the ``generator`` passed in (a ``torch.Generator``), so a seed
fixes every choice. Each function returns ``None`` where the image offers no suitable point.
"""
from __future__ import annotations

import dataclasses
import math

import torch
from torch import Tensor

from ..errors import InputError
from .evaluate import feature_values
from .features import Feature, Geometric, LocalFeature, Part, Texel, Texture, Within
from .primitives import PartKind
from .record import ImageRecords
from .region import Frame, Region, as_frame, frame_coordinates
from .sampling import placements, sample_texture, steered_sample
from .texture import level_sigma


def _choose(candidates: Tensor, generator) -> int | None:
    if len(candidates) == 0:
        return None
    pick = torch.randint(len(candidates), (1,), generator=generator, device="cpu")
    return int(candidates[int(pick)])


def _default_distance(records: ImageRecords, n: int, max_distance: float | None) -> float:
    return float(records.sizes[n].min()) / 4 if max_distance is None else float(max_distance)


def _point(records: ImageRecords, n: int, p: int) -> tuple[Tensor, ...]:
    return records.x[n, p], records.y[n, p], records.sigma[n, p], records.theta[n, p]


def _part_kind(records: ImageRecords, n: int, p: int) -> PartKind:
    return PartKind.of_point(int(records.kind[n, p]))


def _attitude(previous: tuple[Tensor, ...], x1: float, y1: float, s1: float, t1: float) -> tuple[float, ...]:
    """(phi, dtheta, d, dsigma) of a part at (x1, y1, s1, t1) relative to the previous part (x, y,
    sigma, theta): alg. 3.6 step 3 read backwards."""
    x0, y0, s0, t0 = (float(v) for v in previous)
    return math.atan2(y1 - y0, x1 - x0) - t0, t1 - t0, math.hypot(x1 - x0, y1 - y0) / s0, s1 / s0


def _relative_part(records: ImageRecords, n: int, q: int, previous: tuple[Tensor, ...]) -> Part:
    """Part for salient point q placed relative to the previous part (x, y, sigma, theta)."""
    kind = _part_kind(records, n, q)
    attitude = _attitude(previous, *(float(v) for v in _point(records, n, q)))
    _, (x, y, sigma, theta) = placements(previous, [attitude])
    image = torch.tensor([n], device=records.device)
    vector, _ = steered_sample(records, image, x[None], y[None], sigma[None], theta[None], kind == PartKind.EDGEL)
    return Part(kind, tuple(vector[0].tolist()), *attitude)


def _texture_part(records: ImageRecords, n: int, q: int, previous: tuple[Tensor, ...]) -> Part:
    """Part for texture grid point q placed relative to the previous part (3.5 with 7.2.1), as
    :func:`_relative_part` places a salient point, with the previous orientation (dtheta 0), its
    vector sampled there as evaluation samples it (``sampling.sample_texture``)."""
    attitude = _attitude(previous, float(records.grid_x[n, q]), float(records.grid_y[n, q]),
                         level_sigma(int(records.grid_level[n, q])), float(previous[3]))
    _, (x, y, sigma, _) = placements(previous, [attitude])
    vector, _ = sample_texture(records, torch.tensor([n], device=records.device), x[None], y[None], sigma[None])
    return Part(PartKind.TEXTURE, tuple(vector[0].tolist()), *attitude)


def _own_vector(records: ImageRecords, n: int, p: int) -> tuple[float, ...]:
    return tuple(records.canonical[n, p, _part_kind(records, n, p).slots].tolist())


def random_texel(records: ImageRecords, n: int, generator: torch.Generator | None = None) -> Texel | None:
    """Method 2, texel branch: the texel response vector at a random salient texel of image n.

    Args:
        records: the records holding image n.
        n: the sample image's index in ``records``.
        generator: the source of every random choice.

    Returns:
        the texel, or None where image n has no salient texel.
    """
    p = _choose(records.texel_mask()[n].nonzero()[:, 0].cpu(), generator)
    return None if p is None else Texel(_own_vector(records, n, p))


def random_texture(records: ImageRecords, n: int, generator: torch.Generator | None = None) -> Texture | None:
    """Method 2, texture branch (7.2.1): the histogram at a random texture grid point of image n,
    its level drawn first (uniformly among the levels with points), then the point.

    Args:
        records: the records holding image n.
        n: the sample image's index in ``records``.
        generator: the source of every random choice.

    Returns:
        the texture, or None where image n has no grid point.
    """
    points = records.grid_mask[n]
    levels = records.grid_level[n][points].unique().cpu()
    level = _choose(levels, generator)
    if level is None:
        return None
    q = _choose((points & (records.grid_level[n] == level)).nonzero()[:, 0].cpu(), generator)
    return Texture(level_sigma(level), tuple(records.histograms[n, q].tolist()))


def random_edgel_pair(records: ImageRecords, n: int, generator: torch.Generator | None = None,
                      max_distance: float | None = None) -> Geometric | None:
    """Method 2, edgel branch: a geometric compound of two random salient edgels of image n.

    The second edgel is drawn from those within ``max_distance`` pixels of the first.

    Args:
        records: the records holding image n.
        n: the sample image's index in ``records``.
        generator: the source of every random choice.
        max_distance: the reach in pixels (default: a quarter of the shorter image side, the largest scale).

    Returns:
        the compound of two edgel parts, or None where image n has no such pair.
    """
    edgels = records.edgel_mask()[n].nonzero()[:, 0].cpu()
    first = _choose(edgels, generator)
    if first is None:
        return None
    distance = torch.hypot(records.x[n, edgels] - records.x[n, first], records.y[n, edgels] - records.y[n, first]).cpu()
    second = _choose(edgels[(distance > 0) & (distance <= _default_distance(records, n, max_distance))], generator)
    if second is None:
        return None
    head = Part(PartKind.EDGEL, _own_vector(records, n, first))
    return Geometric((head, _relative_part(records, n, second, _point(records, n, first))))


def strongest(feature: Feature, records: ImageRecords, n: int) -> tuple[Tensor, ...] | None:
    """Where ``feature`` is strongest in image n (eq. 3.14): (x, y, sigma, theta), or None where it
    has no valid occurrence; measured on that image alone, so the same feature and image always give
    the same numbers (a caller may remember them)."""
    found = feature_values([feature], records[n])
    if not bool(torch.isfinite(found.x[0, 0])):
        return None
    return found.x[0, 0], found.y[0, 0], found.sigma[0, 0], found.theta[0, 0]


def _occurrence(feature: Feature, records: ImageRecords, n: int, located: dict | None) -> tuple[Tensor, ...] | None:
    """:func:`strongest`, from and into the caller's memory ``located`` where given."""
    if located is None:
        return strongest(feature, records, n)
    if feature not in located:
        located[feature] = strongest(feature, records, n)
    return located[feature]


def expand_geometric(feature: LocalFeature, records: ImageRecords, n: int, generator: torch.Generator | None = None,
                     max_distance: float | None = None, located: dict | None = None,
                     texture: bool = False) -> Geometric | None:
    """Method 3: add a random salient edgel or texel near the feature's strongest occurrence.

    The feature is located in image n by eq. 3.14 (:func:`strongest`; from ``located``, the
    caller's memory of that image's occurrences by feature, where it holds the feature, and kept
    there); its parts are placed there by alg. 3.6 and a salient point (edgel or texel) within
    ``max_distance`` pixels of the last part becomes the new last part. The existing parts keep
    their vectors, so the result is more specific.

    With ``texture`` the new part's kind is drawn first, a salient point or a texture grid point
    (3.5 with 7.2.1), one half each; a texture part is a grid point of any level in that reach
    (:func:`_texture_part`). Without it, the draws are those made before texture parts existed.

    Args:
        feature: a texel or geometric compound.
        records: the records holding image n.
        n: the sample image's index in ``records``.
        generator: the source of every random choice.
        max_distance: the reach in pixels from the last part (default as :func:`random_edgel_pair`).
        located: the caller's memory of strongest occurrences in image n, by feature.
        texture: whether the new part may be a texture part.

    Returns:
        the compound one part longer, or None where the feature does not occur in image n or
        no point lies within reach.
    """
    if not isinstance(feature, LocalFeature):
        raise InputError(f"geometric expansion needs a texel or geometric feature, got {type(feature).__name__}")
    occurrence = _occurrence(feature, records, n, located)
    if occurrence is None:
        return None
    *_, state = placements(occurrence, feature.attitudes())
    grid = texture and bool(torch.rand(1, generator=generator) < 0.5)
    mask, x, y = (records.grid_mask, records.grid_x, records.grid_y) if grid else (records.mask, records.x, records.y)
    points = mask[n].nonzero()[:, 0]
    distance = torch.hypot(x[n, points] - state[0], y[n, points] - state[1])
    near = points[(distance >= 0.5) & (distance <= _default_distance(records, n, max_distance))].cpu()
    q = _choose(near, generator)
    if q is None:
        return None
    return Geometric((*feature.parts, (_texture_part if grid else _relative_part)(records, n, q, state)))


def localize(feature: Feature, records: ImageRecords, n: int, frame: Frame | str, radius: float,
             located: dict | None = None) -> Within | None:
    """``feature`` bounded to a disc of ``radius`` in ``frame`` (``ftorch.space.region``), centred
    where it is strongest in image n (eq. 3.14, :func:`strongest`; from and into ``located`` as in
    :func:`expand_geometric`): a more specific feature, general-to-specific (3.6), that keeps its
    value on image n where its reference point there is what matters (a local feature). A Boolean
    compound's disc is centred where its stronger side is; the other side's best match may lie outside.

    Where ``feature`` is a Within already, the new region replaces its outermost one and is centred
    at its strongest occurrence inside that region: narrowing it is the caller's choice of ``radius``.
    None where image n gives no location (value 0) or, in the object frame, has no object frame.

    Args:
        feature: any feature.
        records: the records holding image n.
        n: the sample image's index in ``records``.
        frame: the region's frame (:class:`~ftorch.space.region.Frame` or its name).
        radius: the disc's radius in ``frame`` units.
        located: the caller's memory of strongest occurrences in image n, by feature.

    Returns:
        the bounded feature, or None.
    """
    disc = Region(as_frame(frame), 0.0, 0.0, radius)  # the frame and radius checked before anything is measured
    occurrence = _occurrence(feature, records, n, located)
    if occurrence is None:
        return None
    image = torch.tensor([n], device=records.device)
    u, v = (float(c[0]) for c in frame_coordinates(records, disc.frame, image, occurrence[0][None], occurrence[1][None]))
    if not (math.isfinite(u) and math.isfinite(v)):
        return None
    inner = feature.feature if isinstance(feature, Within) else feature
    return Within(inner, dataclasses.replace(disc, x=u, y=v))
