"""Kolmogorov-Smirnoff distance and distinctive power of many features at once (4.3.2, def. 4.2).

Cut-points are the midpoints between adjacent distinct values of the pooled sample (ties are
one value); cdf(alpha | group) is the fraction of the group's values below alpha. The KSD is
max |cdf(alpha | discriminated) - cdf(alpha | characterized)|; where several cut-points reach
it, the lowest is taken. Distinctive power is the KSD where the discriminated classes'
cdf is the larger at that cut-point (the feature is characteristic: its class scores higher),
and zero otherwise. Non-finite values (features not measured on an instance) are ignored.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor


@dataclass
class KSD:
    """distance, cutpoint (NaN where no cut-point exists) and distinctive power, each (F,)."""

    distance: Tensor
    cutpoint: Tensor
    distinctive: Tensor


def ksd(values: Tensor, characterized: Tensor, discriminated: Tensor, position: float = 0.5) -> KSD:
    """KSD of each row of ``values`` (F, n) between two groups of instances, masks (n,) or (F, n).

    The cut-point lies at ``position`` between the two adjacent values that reach the KSD
    (0.5: their midpoint, as 4.3.2; lower values move a characteristic feature's cut-point
    towards the discriminated values, so that slightly weaker occurrences still count as present)."""
    values = torch.as_tensor(values, dtype=torch.float64)
    if values.ndim != 2:
        raise ValueError(f"values must be (features, instances), got shape {tuple(values.shape)}")
    finite = torch.isfinite(values)
    a = torch.as_tensor(discriminated, dtype=torch.bool).expand_as(values) & finite
    b = torch.as_tensor(characterized, dtype=torch.bool).expand_as(values) & finite
    key = torch.where(a | b, values, torch.full_like(values, math.inf))
    ordered, order = key.sort(dim=1, stable=True)
    count_a = a.sum(1, keepdim=True).clamp_min(1)
    count_b = b.sum(1, keepdim=True).clamp_min(1)
    cdf_a = a.gather(1, order).to(torch.float64).cumsum(1) / count_a
    cdf_b = b.gather(1, order).to(torch.float64).cumsum(1) / count_b
    below, above = ordered[:, :-1], ordered[:, 1:]
    candidate = (below < above) & torch.isfinite(above)
    difference = (cdf_a - cdf_b)[:, :-1]
    score = torch.where(candidate, difference.abs(), torch.full_like(difference, -1.0))
    if score.shape[1] == 0:
        score = torch.full((values.shape[0], 1), -1.0, dtype=torch.float64)
        below = above = difference = torch.zeros_like(score)
    best, at = score.max(1)
    found = (best >= 0) & a.any(1) & b.any(1)
    distance = torch.where(found, best, torch.zeros_like(best))
    low, high = below.gather(1, at[:, None])[:, 0], above.gather(1, at[:, None])[:, 0]
    cut = (low + high) / 2 if position == 0.5 else low + position * (high - low)
    cutpoint = torch.where(found, cut, torch.full_like(cut, math.nan))
    characteristic = difference.gather(1, at[:, None])[:, 0] > 0
    return KSD(distance, cutpoint, torch.where(found & characteristic, distance, torch.zeros_like(distance)))


def distinctive_at(values: Tensor, cutpoint: Tensor, characterized: Tensor, discriminated: Tensor) -> Tensor:
    """Distinctive power (D, F) of each row of ``values`` (F, n) at a given cut-point alpha (F,)
    between the ``characterized`` instances (n,), or each row's own (F, n), and each of D
    ``discriminated`` groups (D, n): the KSD_{c,d}(f) of alg. 5.2 for a node already
    discretized: cdf(alpha | discriminated) -
    cdf(alpha | characterized) where positive, else 0, with cdf counting values <= alpha (a node
    is present above its cut-point); 0 where a group has no finite value. The counts for all
    groups at once are products of 0/1 matrices: exact integers, as counting one by one gives."""
    values = torch.as_tensor(values, dtype=torch.float64)
    finite = torch.isfinite(values)
    below = (values <= torch.as_tensor(cutpoint, dtype=torch.float64)[:, None]) & finite
    groups = torch.as_tensor(discriminated, dtype=torch.bool).to(torch.float64).T  # (n, D)
    b = torch.as_tensor(characterized, dtype=torch.bool)
    count_a, below_a = finite.to(torch.float64) @ groups, below.to(torch.float64) @ groups  # (F, D)
    count_b, below_b = (finite & b).sum(1), (below & b).sum(1, dtype=torch.float64)
    cdf_a = below_a / count_a.clamp_min(1)
    cdf_b = below_b / count_b.clamp_min(1)
    power = (cdf_a - cdf_b[:, None]).clamp_min(0.0)
    return torch.where((count_a > 0) & (count_b > 0)[:, None], power, torch.zeros_like(power)).T
