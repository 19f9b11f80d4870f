"""Sampling primitive responses from the dense pyramid at any (x, y, sigma) (alg. 3.6 step 4).

Between pixels: bilinear. Between levels: linear in the level index u = 2*log2(sigma) (i.e. in
log sigma), applied to the scale-normalised responses. A texel at u reads levels u-1, u, u+1;
an edgel reads the first-order pair at u. At integer positions and levels this returns the
stored values exactly, so a feature measured from an image has value 1 at its own reference
point. Level indices within 1e-4 of an integer are snapped to it (float32 sigmas such as
sqrt(2) would otherwise fall just outside a level). A sample is valid when (x, y) lies inside
the image and the levels it reads exist.
"""
from __future__ import annotations

import torch
from torch import Tensor

from .record import EDGEL_SLOTS, ImageRecords
from .salient import EDGEL


def level_index(sigma: Tensor) -> Tensor:
    """Fractional pyramid level u = 2*log2(sigma), snapped to integers within 1e-4."""
    u = 2 * torch.log2(sigma)
    nearest = torch.round(u)
    return torch.where((u - nearest).abs() < 1e-4, nearest, u)


def advance(x: Tensor, y: Tensor, sigma: Tensor, theta: Tensor, phi, dtheta, d, dsigma):
    """Alg. 3.6 step 3: location, scale and orientation of part i from those of part i-1."""
    step = sigma * d
    return x + step * torch.cos(theta + phi), y + step * torch.sin(theta + phi), sigma * dsigma, theta + dtheta


def sample_primitives(records: ImageRecords, image: Tensor, x: Tensor, y: Tensor, sigma: Tensor,
                      kind: Tensor) -> tuple[Tensor, Tensor]:
    """Responses (M, 15) in descriptor layout, image frame, and validity (M,) for flat inputs (M,)
    of mixed kinds; invalid samples are zero."""
    out = x.new_zeros(len(x), 15)
    valid = torch.zeros(len(x), dtype=torch.bool, device=x.device)
    for edgel in (True, False):
        chosen = ((kind == EDGEL) == edgel).nonzero()[:, 0]
        if len(chosen):
            values, ok = sample_part(records, image[chosen], x[chosen], y[chosen], sigma[chosen], edgel)
            out[chosen, EDGEL_SLOTS if edgel else slice(None)] = values
            valid[chosen] = ok
    return out, valid


def sample_part(records: ImageRecords, image: Tensor, x: Tensor, y: Tensor, sigma: Tensor,
                edgel: bool) -> tuple[Tensor, Tensor]:
    """Responses of one part kind at flat inputs (M,): (M, 2) first-order pairs at u for an edgel,
    (M, 15) blocks at u-1, u, u+1 for a texel, in the image frame, and validity (M,). Only valid
    samples are read (invalid ones are zero): a texel reads 4 corners x 4 levels x 5 responses,
    an edgel 4 corners x 2 levels x 2."""
    table = records.pyramid.table
    size = records.sizes[image]
    u = level_index(sigma)
    inside = (x >= 0) & (y >= 0) & (x <= size[:, 1] - 1) & (y <= size[:, 0] - 1)
    reach = 0 if edgel else 1
    valid = inside & (u - reach >= 0) & (u + reach <= records.levels[image] - 1)
    out = x.new_zeros(len(x), 2 if edgel else 15)
    chosen = valid.nonzero()[:, 0]
    if len(chosen):
        out[chosen] = _read(table, records.source[image[chosen]], x[chosen], y[chosen], u[chosen], edgel)
    return out, valid


def _read(table: Tensor, source: Tensor, x: Tensor, y: Tensor, u: Tensor, edgel: bool) -> Tensor:
    """Bilinear in (x, y), linear in the level u, from the pyramid table (see ``Pyramid``)."""
    height, width, stride = table.shape[1], table.shape[2], table.shape[3]
    lo = torch.floor(u).clamp(0, stride - 4)
    w = (u - lo).clamp(0, 1)[:, None]
    x0, y0 = torch.floor(x), torch.floor(y)
    wx, wy = (x - x0)[:, None], (y - y0)[:, None]
    xs = (x0.long()[:, None] + torch.arange(2, device=x.device)).clamp(0, width - 1)
    ys = (y0.long()[:, None] + torch.arange(2, device=y.device)).clamp(0, height - 1)
    pixel = ((source[:, None, None] * height + ys[:, :, None]) * width + xs[:, None, :]).reshape(-1, 4)
    weights = (torch.cat([1 - wy, wy], 1)[:, :, None] * torch.cat([1 - wx, wx], 1)[:, None, :]).reshape(-1, 4, 1)
    # row r of a view holds `span` values from table entry r (level r - 1 within its pixel)
    span = 7 if edgel else 20
    rows = table.as_strided(((table.numel() - span) // 5 + 1, span), (5, 1))
    first = pixel * stride + lo.long()[:, None] + (1 if edgel else 0)
    corners = rows.index_select(0, first.reshape(-1)).view(-1, 4, span)
    planar = (weights * corners).sum(1)
    if edgel:  # levels lo, lo + 1 x (G1@0, G1@pi/2)
        return (1 - w) * planar[:, 0:2] + w * planar[:, 5:7]
    planar = planar.view(-1, 4, 5)  # levels lo-1 .. lo+2
    return ((1 - w[:, :, None]) * planar[:, 0:3] + w[:, :, None] * planar[:, 1:4]).flatten(1)
