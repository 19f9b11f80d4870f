"""Batched feature values (eq. 3.12-3.14, always rotation invariant).

For F features and N image records the values come from gathered tensors: part 0 of every
local feature is matched against the canonical descriptors of all reference points at once
(one matrix product); later parts are placed by alg. 3.6, sampled from the pyramid and steered
to their orientation. Since steering is orthogonal, the normalised inner product of canonical
vectors equals eq. 3.13's. Boolean compounds combine their sub-feature values (3.5.2).
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import torch
from torch import Tensor

from .errors import InputError
from .features import Conjunction, Disjunction, Feature, LocalFeature
from .record import EDGEL_SLOTS, ImageRecords
from .sampling import advance, sample_part
from .steering import rotate_pair, steer


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

    def _fields(self) -> tuple[Tensor, ...]:
        return self.values, self.x, self.y, self.sigma, self.theta


def part_vector(kind: str, vector: Sequence[float], device=None, dtype=None) -> Tensor:
    """A part's vector in the 15-slot descriptor layout."""
    out = torch.zeros(15, device=device, dtype=dtype)
    values = torch.tensor(vector, device=device, dtype=dtype)
    if kind == "edgel":
        out[EDGEL_SLOTS] = values
    else:
        out[:] = values
    return out


def local_values(features: list[LocalFeature], records: ImageRecords, max_elements: int = 1 << 24) -> FeatureValues:
    """Values of local features whose parts have the same kinds, part by part."""
    device, dtype = records.device, records.dtype
    kinds = tuple(p.kind for p in features[0].parts)
    vectors = [torch.tensor([f.parts[i].vector for f in features], device=device, dtype=dtype) for i in range(len(kinds))]
    params = torch.tensor([[[p.phi, p.dtheta, p.d, p.dsigma] for p in f.parts] for f in features], device=device, dtype=dtype)
    reference = _ReferencePoints(records, kinds[0])
    n_images, n_points = reference.mask.shape
    if n_points == 0:
        zeros = torch.zeros(len(features), n_images, device=device, dtype=dtype)
        nan = torch.full_like(zeros, math.nan)
        return FeatureValues(zeros, nan, nan, nan, nan)
    chunk = max(1, max_elements // max(1, n_images * n_points * 15 * (2 if len(kinds) > 1 else 1)))
    results = [_local_chunk([v[s : s + chunk] for v in vectors], params[s : s + chunk], kinds, records, reference)
               for s in range(0, len(features), chunk)]
    return FeatureValues(*(torch.cat(parts) for parts in zip(*(r._fields() for r in results))))


class _ReferencePoints:
    """The salient points of one kind (edgels or texels), packed to the left: (N, P_kind), with
    their canonical vectors (the first-order pair for edgels, all 15 numbers for texels)."""

    def __init__(self, records: ImageRecords, kind: str):
        applicable = records.edgel_mask() if kind == "edgel" else records.texel_mask()
        width = int(applicable.sum(1).max()) if applicable.numel() else 0
        order = torch.argsort((~applicable).to(torch.int8), dim=1, stable=True)[:, :width]
        self.mask = applicable.gather(1, order)
        self.x, self.y = records.x.gather(1, order), records.y.gather(1, order)
        self.sigma, self.theta = records.sigma.gather(1, order), records.theta.gather(1, order)
        canonical = records.canonical[..., EDGEL_SLOTS] if kind == "edgel" else records.canonical
        self.canonical = canonical.gather(1, order[..., None].expand(-1, -1, canonical.shape[-1]))


def _local_chunk(vectors: list[Tensor], params: Tensor, kinds: tuple[str, ...], records: ImageRecords,
                 reference: _ReferencePoints) -> FeatureValues:
    n_feat = params.shape[0]
    n_images, n_points = reference.mask.shape
    shape = (n_feat, n_images, n_points)
    numerator = torch.einsum("fd,npd->fnp", vectors[0], reference.canonical)
    observed = (reference.canonical**2).sum(-1).expand(shape)
    valid = reference.mask.expand(shape)
    # padding points are placed nowhere, so no later part of theirs is sampled
    x = torch.where(reference.mask, reference.x, math.nan).expand(shape)
    y, theta, sigma = reference.y.expand(shape), reference.theta.expand(shape), reference.sigma.expand(shape)
    image = torch.arange(n_images, device=records.device)[None, :, None].expand(shape).reshape(-1)
    for i in range(1, len(kinds)):
        x, y, sigma, theta = advance(x, y, sigma, theta, *(params[:, i, j][:, None, None] for j in range(4)))
        edgel = kinds[i] == "edgel"
        sample, ok = sample_part(records, image, x.reshape(-1), y.reshape(-1), sigma.reshape(-1), edgel)
        sample = (rotate_pair(sample, theta.reshape(-1)) if edgel else steer(sample, theta.reshape(-1))).view(*shape, -1)
        numerator = numerator + torch.einsum("fnpd,fd->fnp", sample, vectors[i])
        observed = observed + (sample**2).sum(-1)
        valid = valid & ok.view(shape)
    pattern = sum((v**2).sum(1) for v in vectors)[:, None, None]
    cosine = numerator / torch.sqrt(observed * pattern).clamp_min(torch.finfo(numerator.dtype).tiny)
    cosine = torch.where(valid, cosine.clamp_min(0), torch.full_like(cosine, -1.0))
    best, where = cosine.max(-1)
    found = best >= 0
    nan = torch.full_like(best, math.nan)

    def at(field: Tensor) -> Tensor:
        return torch.where(found, field.expand(shape).gather(-1, where[..., None])[..., 0], nan)

    return FeatureValues(best.clamp_min(0), at(reference.x), at(reference.y), at(reference.sigma), at(reference.theta))


@torch.no_grad()
def feature_values(features: Sequence[Feature], records: ImageRecords, max_elements: int = 1 << 24) -> FeatureValues:
    """Values (F, N) of ``features`` in every image of ``records`` and where each is strongest.

    All local features (texels, geometric compounds, the leaves of Boolean compounds) are
    evaluated once each, batched by structure; ``max_elements`` bounds the gathered tensors.
    """
    features = list(features)
    if not all(isinstance(f, Feature) for f in features):
        raise InputError("features: every item must be an ftorch Feature")
    leaves: dict[LocalFeature, int] = {}
    for feature in features:
        _collect(feature, leaves)
    groups: dict[tuple, list[LocalFeature]] = {}
    for leaf in leaves:
        groups.setdefault(tuple(p.kind for p in leaf.parts), []).append(leaf)
    leaf_values: dict[LocalFeature, tuple[Tensor, ...]] = {}
    for group in groups.values():
        result = local_values(group, records, max_elements)
        for j, leaf in enumerate(group):
            leaf_values[leaf] = tuple(t[j] for t in result._fields())
    if not features:
        empty = records.x.new_zeros(0, len(records))
        return FeatureValues(empty, empty, empty, empty, empty)
    rows = [_combine(f, leaf_values) for f in features]
    return FeatureValues(*(torch.stack(col) for col in zip(*rows)))


def _collect(feature: Feature, leaves: dict) -> None:
    if isinstance(feature, LocalFeature):
        leaves.setdefault(feature, len(leaves))
    else:
        _collect(feature.a, leaves)
        _collect(feature.b, leaves)


def _combine(feature: Feature, leaf_values: dict) -> tuple[Tensor, ...]:
    if isinstance(feature, LocalFeature):
        return leaf_values[feature]
    a, b = _combine(feature.a, leaf_values), _combine(feature.b, leaf_values)
    take_b = b[0] > a[0]
    located = [torch.where(take_b, fb, fa) for fa, fb in zip(a[1:], b[1:])]
    if isinstance(feature, Conjunction):
        value = a[0] * b[0]
    elif isinstance(feature, Disjunction):
        value = torch.maximum(a[0], b[0])
    else:
        raise InputError(f"unknown feature type {type(feature).__name__}")
    return (value, *located)
