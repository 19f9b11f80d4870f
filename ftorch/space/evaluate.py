"""Batched feature values (eq. 3.12-3.14, always rotation invariant).

For F features and N image records the values come from gathered tensors: part 0 of every
local feature is matched against the canonical descriptors of all reference points at once
(one matrix product); later parts are placed by alg. 3.6, sampled from the pyramid and steered
to their orientation. Since steering is orthogonal, the normalised inner product of canonical
vectors equals eq. 3.13's. Texture features (7.2.1) are matched against the texture grid points
of their level in the same way. Boolean compounds combine their sub-feature values (3.5.2).

A compound's texture parts (3.5 with 7.2.1) are sampled from the texture grid
(``sampling.sample_texture``), and each multiplies the cosine of the oriented parts (eq. 3.13 over
their vectors alone) by its Bhattacharyya coefficient, the dot product of the unit-normalised sampled
and stored vectors, in [0, 1]. The two kinds live in different units (responses, a unit-length
distribution), so one normalised dot product over both would weigh them arbitrarily; the product
stays in [0, 1], is 1 at the compound's own reference point, and acts as a conjunction placed
geometrically. A point where any part's sample is invalid does not count. A compound without texture
parts is measured by the same arithmetic as before they existed.

A :class:`~ftorch.space.features.Within` bounds the maximum to the reference points inside its
regions (``ftorch.space.region``): a point outside counts as no applicable point, as an invalid
sample does (cosine -1 before the per-image maximum), so an image with none inside gives value 0
and no location. Its leaves are measured once per (leaf, regions), in groups apart from the
unbounded leaves, which are measured exactly as without regions (the same groups, the same code).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import torch
from torch import Tensor

from ..errors import InputError
from .features import Feature, LocalFeature, Texture, Within
from .primitives import PartKind
from .record import ImageRecords
from .region import Region, inside
from .sampling import Frames, placements, sample_texture, sample_unmasked, steered
from .steering import dot, unit
from .texture import level_sigma


@dataclass
class FeatureValues:
    """values (F, N) in [0, 1], and x, y, sigma, theta (F, N) of the maximising reference point.

    Where an image has no applicable reference point the value is 0 and the location NaN. For
    Boolean compounds the location is that of the sub-feature with the larger value.
    """

    values: Tensor
    x: Tensor
    y: Tensor
    sigma: Tensor
    theta: Tensor


def part_vector(kind: PartKind, vector: Sequence[float], device=None, dtype=None) -> Tensor:
    """A part's vector in the 15-slot descriptor layout."""
    out = torch.zeros(15, device=device, dtype=dtype)
    out[PartKind(kind).slots] = torch.tensor(vector, device=device, dtype=dtype)
    return out


def local_values(features: list[LocalFeature], records: ImageRecords, max_elements: int = 1 << 24) -> FeatureValues:
    """Values of local features whose parts have the same kinds, part by part."""
    return FeatureValues(*_local_fields(features, records, max_elements, located=True))


def _local_fields(features: list[LocalFeature], records: ImageRecords, max_elements: int,
                  located: bool, regions: list[tuple[Region, ...]] | None = None) -> tuple[Tensor, ...]:
    """:func:`local_values`' fields, or its values alone (a 1-tuple) where not ``located``; ``regions``:
    each feature's regions, whose intersection bounds its maximum (None: none has any)."""
    device, dtype = records.device, records.dtype
    kinds = tuple(p.kind for p in features[0].parts)
    vectors = [torch.tensor([f.parts[i].vector for f in features], device=device, dtype=dtype) for i in range(len(kinds))]
    params = torch.tensor([[[p.phi, p.dtheta, p.d, p.dsigma] for p in f.parts] for f in features], device=device, dtype=dtype)
    reference = _ReferencePoints.of(records, kinds[0])
    n_images, n_points = reference.padded
    if n_points == 0:
        return reference.nothing(len(features), located)
    bounds = None if regions is None else _Bounds(regions, records, reference)
    per_feature = n_images * n_points * 15 * (2 if len(kinds) > 1 else 1) + (0 if bounds is None else bounds.elements)
    chunk = max(1, max_elements // max(1, per_feature))
    results = [_local_chunk([v[s : s + chunk] for v in vectors], params[s : s + chunk], kinds, records, reference,
                            located, None if bounds is None else bounds.allowed(s, s + chunk))
               for s in range(0, len(features), chunk)]
    return tuple(torch.cat(parts) for parts in zip(*results))


class _Bounds:
    """The regions of a group's features over its reference points (K,): each feature's allowed
    mask, the points inside all its regions (an empty tuple of regions: all points), made chunk by
    chunk, so that the memory bound holds: a chunk's distinct regions (R, K) and their distance
    tests, its mask (F, K) and the masked cosines count as ``elements`` per feature."""

    def __init__(self, regions: list[tuple[Region, ...]], records: ImageRecords, reference: "_ReferencePoints"):
        self.regions, self.records, self.reference = regions, records, reference
        self.depth = max(len(r) for r in regions)
        self.elements = (3 * self.depth + 2) * len(reference.image)

    def allowed(self, start: int, stop: int) -> Tensor:
        """(F, K) bool of features start..stop-1."""
        chunk = self.regions[start:stop]
        distinct = list(dict.fromkeys(r for rs in chunk for r in rs))
        ref = self.reference
        masks = torch.cat([inside(distinct, self.records, ref.image, ref.x, ref.y),
                           torch.ones(1, len(ref.image), dtype=torch.bool, device=ref.x.device)])
        at = {r: i for i, r in enumerate(distinct)}
        rows = torch.tensor([[at[r] for r in rs] + [len(distinct)] * (self.depth - len(rs)) for rs in chunk],
                            device=ref.x.device)
        out = masks[rows[:, 0]]
        for j in range(1, self.depth):  # the nesting depth: an intersection of regions
            out &= masks[rows[:, j]]
        return out


class _ReferencePoints:
    """The reference points of one kind in a batch of records as one list (K,), image by image:
    each point's image and slot (its rank among that image's points of the kind), x, y, sigma,
    theta and canonical vector. Per-image maxima are taken in the padded layout ``padded`` =
    (N, P_kind). The kinds: the salient edgels or texels (the first-order pair for edgels, all 15
    numbers for texels), or the texture grid points of one level (their histograms, theta 0)."""

    def __init__(self, applicable: Tensor, x: Tensor, y: Tensor, sigma: Tensor, theta: Tensor, vectors: Tensor):
        image, point = applicable.nonzero(as_tuple=True)
        rank = applicable.cumsum(1) - 1
        self.image, self.slot = image, rank[image, point]
        self.padded = (applicable.shape[0], int(rank.max()) + 1 if len(image) else 0)
        self.x, self.y, self.sigma, self.theta = (field[image, point] for field in (x, y, sigma, theta))
        self.canonical = vectors[image, point]

    @staticmethod
    def of(records: ImageRecords, kind: PartKind | int) -> "_ReferencePoints":
        """The points of ``kind`` (a part kind, or a texture level) in ``records``, found once per
        records object (records are never changed in place)."""
        known = records.reference_points
        if kind not in known:
            if isinstance(kind, PartKind):
                known[kind] = _ReferencePoints(kind.mask(records), records.x, records.y, records.sigma, records.theta,
                                               records.canonical[..., kind.slots])
            else:
                sigma = torch.full_like(records.grid_x, level_sigma(kind))
                known[kind] = _ReferencePoints(records.grid_mask & (records.grid_level == kind), records.grid_x,
                                               records.grid_y, sigma, torch.zeros_like(sigma), records.histograms)
        return known[kind]

    def located(self, field: Tensor, best: Tensor, where: Tensor) -> Tensor:
        """``field`` (K,) of the point at slot ``where`` (F, N) of each image; NaN where ``best`` < 0."""
        padded = field.new_full(self.padded, math.nan)
        padded[self.image, self.slot] = field
        at = padded.expand(len(where), -1, -1).gather(-1, where[..., None])[..., 0]
        return torch.where(best >= 0, at, math.nan)

    def best(self, cosine: Tensor, located: bool) -> tuple[Tensor, ...]:
        """Eq. 3.14: the largest of ``cosine`` (F, K) per image (0 where an image has no point, or
        where every point's is invalid, -1), with the fields of the point reaching it where ``located``."""
        padded = cosine.new_full((len(cosine), *self.padded), -1.0)
        padded[:, self.image, self.slot] = cosine
        if not located:
            return (padded.amax(-1).clamp_min(0),)
        top, where = padded.max(-1)
        return (top.clamp_min(0), *(self.located(field, top, where) for field in (self.x, self.y, self.sigma, self.theta)))

    def nothing(self, features: int, located: bool) -> tuple[Tensor, ...]:
        """The fields where no image has a point of this kind: values 0, locations NaN."""
        zeros = self.canonical.new_zeros(features, self.padded[0])
        nan = torch.full_like(zeros, math.nan)
        return (zeros, nan, nan, nan, nan) if located else (zeros,)


def _local_chunk(vectors: list[Tensor], params: Tensor, kinds: tuple[PartKind, ...], records: ImageRecords,
                 reference: _ReferencePoints, located: bool, allowed: Tensor | None = None) -> tuple[Tensor, ...]:
    """Eq. 3.13 at every reference point (F, K), then its maximum per image (eq. 3.14) over the
    ``allowed`` points (F, K; None: all): the fields of :class:`FeatureValues`, or the values alone
    where not ``located``."""
    numerator = dot(vectors[0][:, None], reference.canonical[None])
    observed = dot(reference.canonical, reference.canonical).expand_as(numerator)
    valid = None
    attitudes = [tuple(params[:, i, j][:, None] for j in range(4)) for i in range(1, len(kinds))]
    parts = placements((reference.x, reference.y, reference.sigma, reference.theta), attitudes)
    next(parts)  # the first part was matched at the reference points themselves
    frames = None  # the limits of valid samples, found at the first oriented part after the first
    tiny = torch.finfo(numerator.dtype).tiny
    texture = None  # the product of the texture parts' Bhattacharyya coefficients (F, K)
    for i, (x, y, sigma, theta) in enumerate(parts, 1):
        # an invalid sample's cosine becomes -1 below, so its responses need not be zeroed first
        if kinds[i] is PartKind.TEXTURE:
            sample, ok = sample_texture(records, reference.image, x, y, sigma)
            coefficient = dot(unit(sample, tiny), unit(vectors[i])[:, None]).clamp(0, 1)
            texture = coefficient if texture is None else texture * coefficient
        else:
            edgel = kinds[i] == PartKind.EDGEL
            frames = Frames.of(records, reference.image) if frames is None else frames
            sample, ok = sample_unmasked(records.pyramid, frames, x, y, sigma, edgel)
            sample = steered(sample, theta, edgel)
            numerator = numerator + dot(sample, vectors[i][:, None])
            observed = observed + dot(sample, sample)
        valid = ok if valid is None else valid & ok
    oriented = [dot(v, v) for v, kind in zip(vectors, kinds) if kind is not PartKind.TEXTURE]  # part 0 is oriented
    pattern = sum(oriented[1:], start=oriented[0])[:, None]
    cosine = numerator / torch.sqrt(observed * pattern).clamp_min(tiny)
    if texture is not None:  # the oriented parts' cosine (eq. 3.13) times each texture part's coefficient
        cosine = cosine * texture
    cosine = cosine.clamp_min(0) if valid is None else torch.where(valid, cosine.clamp_min(0), -1.0)
    if allowed is not None:  # a point outside the regions: no applicable point, as an invalid sample
        cosine = torch.where(allowed, cosine, -1.0)
    return reference.best(cosine, located)


def _texture_fields(features: list[Texture], records: ImageRecords, max_elements: int,
                    located: bool, regions: list[tuple[Region, ...]] | None = None) -> tuple[Tensor, ...]:
    """Texture features of one level (7.2.1): the Bhattacharyya coefficient of their histograms
    and those of the level's grid points, a normalised dot product, at its largest per image (over
    the grid points inside each feature's ``regions``, as :func:`_local_fields`)."""
    reference = _ReferencePoints.of(records, features[0].level)
    if reference.padded[1] == 0:
        return reference.nothing(len(features), located)
    vectors = torch.tensor([f.histogram for f in features], device=records.device, dtype=records.dtype)
    bounds = None if regions is None else _Bounds(regions, records, reference)
    chunk = max(1, max_elements // max(1, len(reference.image) * 2 + (0 if bounds is None else bounds.elements)))
    tiny = torch.finfo(records.dtype).tiny
    points = unit(reference.canonical, tiny)
    results = []
    for start in range(0, len(features), chunk):
        v = vectors[start : start + chunk]
        cosine = dot(unit(v)[:, None], points[None]).clamp(0, 1)
        if bounds is not None:
            cosine = torch.where(bounds.allowed(start, start + chunk), cosine, -1.0)
        results.append(reference.best(cosine, located))
    return tuple(torch.cat(parts) for parts in zip(*results))


def feature_values(features: Sequence[Feature], records: ImageRecords, max_elements: int = 1 << 24) -> FeatureValues:
    """Values of ``features`` in every image of ``records`` (eq. 3.14) and where each is strongest.

    All local features (texels, geometric compounds, textures, the leaves of Boolean compounds)
    are evaluated once each (once per set of regions around them), batched by structure.

    Args:
        features: F features of any types.
        records: the records of N images.
        max_elements: a bound on the elements of the gathered tensors (features are chunked to it).

    Returns:
        the values in [0, 1] (0 where an image has no applicable reference point) and the x, y,
        sigma, theta of the maximising point (NaN where none), in the records' dtype and device.

    Shape:
        - Output: :class:`FeatureValues`, each field :math:`(F, N)`.
    """
    return FeatureValues(*_evaluate(features, records, max_elements, located=True))


def values_only(features: Sequence[Feature], records: ImageRecords, max_elements: int = 1 << 24) -> Tensor:
    """``feature_values(features, records).values``, the same numbers, without finding where each
    is reached: what the learners measure.

    Args:
        features: F features of any types.
        records: the records of N images.
        max_elements: a bound on the elements of the gathered tensors.

    Returns:
        the values in [0, 1].

    Shape:
        - Output: :math:`(F, N)`.
    """
    return _evaluate(features, records, max_elements, located=False)[0]


def _evaluate(features: Sequence[Feature], records: ImageRecords, max_elements: int, located: bool) -> tuple[Tensor, ...]:
    """:class:`FeatureValues`' fields of ``features``, or their values alone (a 1-tuple) where not ``located``."""
    features = list(features)
    if not all(isinstance(f, Feature) for f in features):
        raise InputError("features: every item must be an ftorch Feature")
    leaves: dict[tuple[LocalFeature | Texture, tuple[Region, ...]], int] = {}
    for feature in features:
        _collect(feature, leaves, ())
    # leaves without regions form the groups they always formed, and are measured by the same code
    # (no mask); bounded leaves are grouped apart, so that adding a Within changes no other value
    groups: dict[tuple, list[tuple[LocalFeature | Texture, tuple[Region, ...]]]] = {}
    for leaf, regions in leaves:
        make = ("texture", leaf.level) if isinstance(leaf, Texture) else tuple(p.kind for p in leaf.parts)
        groups.setdefault((make, bool(regions)), []).append((leaf, regions))
    leaf_values: dict[tuple[Feature, tuple[Region, ...]], tuple[Tensor, ...]] = {}
    for (_, bounded), group in groups.items():
        # a group is all textures of one level or all local features of one make-up
        textures = [leaf for leaf, _ in group if isinstance(leaf, Texture)]
        local = [leaf for leaf, _ in group if isinstance(leaf, LocalFeature)]
        bounds = [regions for _, regions in group] if bounded else None
        result = (_texture_fields(textures, records, max_elements, located, bounds) if textures
                  else _local_fields(local, records, max_elements, located, bounds))
        for j, leaf_regions in enumerate(group):
            leaf_values[leaf_regions] = tuple(t[j] for t in result)
    if not features:
        empty = records.x.new_zeros(0, len(records))
        return (empty,) * (5 if located else 1)
    rows = [_combine(f, leaf_values, ()) for f in features]
    return tuple(torch.stack(col) for col in zip(*rows))


def bounded_by(regions: tuple[Region, ...], region: Region) -> tuple[Region, ...]:
    """The regions around a feature inside one more Within: each once, in one order, so that
    Within(Within(f, a), b), Within(Within(f, b), a) and Within(Within(Within(f, a), b), a) are one leaf."""
    return tuple(sorted({*regions, region}, key=Region.order))


def _collect(feature: Feature, leaves: dict, regions: tuple[Region, ...]) -> None:
    """Every leaf of ``feature`` with the regions around it (the Withins it lies in)."""
    if isinstance(feature, Within):
        _collect(feature.feature, leaves, bounded_by(regions, feature.region))
        return
    if isinstance(feature, (LocalFeature, Texture)):
        leaves.setdefault((feature, regions), len(leaves))
    for sub in feature.subfeatures():
        _collect(sub, leaves, regions)


def _combine(feature: Feature, leaf_values: dict, regions: tuple[Region, ...]) -> tuple[Tensor, ...]:
    if isinstance(feature, Within):
        return _combine(feature.feature, leaf_values, bounded_by(regions, feature.region))
    if isinstance(feature, (LocalFeature, Texture)):
        return leaf_values[feature, regions]
    return feature.combine(*(_combine(sub, leaf_values, regions) for sub in feature.subfeatures()))
