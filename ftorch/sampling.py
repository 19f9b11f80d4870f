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

from .record import ImageRecords, kind_slots
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
    """Responses (M, 15) in descriptor layout, image frame, and validity (M,) for flat inputs (M,)."""
    responses = records.responses
    levels = responses.shape[1]
    height, width = responses.shape[-2:]
    size = records.sizes[image]
    n_levels = records.levels[image]
    u = level_index(sigma)
    inside = (x >= 0) & (y >= 0) & (x <= size[:, 1] - 1) & (y <= size[:, 0] - 1)
    edgel = kind == EDGEL
    low = torch.where(edgel, u, u - 1)
    high = torch.where(edgel, u, u + 1)
    valid = inside & (low >= 0) & (high <= n_levels - 1)

    lo = torch.floor(u).clamp(0, levels - 1)
    w = (u - lo).clamp(0, 1)[:, None, None]
    x0, y0 = torch.floor(x), torch.floor(y)
    wx, wy = (x - x0)[:, None], (y - y0)[:, None]
    xs = (x0.long()[:, None] + torch.arange(2, device=x.device)).clamp(0, width - 1)
    ys = (y0.long()[:, None] + torch.arange(2, device=y.device)).clamp(0, height - 1)
    pixel = ((image[:, None, None] * height + ys[:, :, None]) * width + xs[:, None, :]).reshape(-1, 4)
    rows = (pixel * (levels + 3) + lo.long()[:, None]).reshape(-1)
    corners = records.sampling_rows.index_select(0, rows).view(-1, 4, 20)  # (M, 4 corners, 4 levels x 5)
    weights = (torch.cat([1 - wy, wy], 1)[:, :, None] * torch.cat([1 - wx, wx], 1)[:, None, :]).reshape(-1, 1, 4)
    planar = torch.bmm(weights, corners).view(-1, 4, 5)  # levels lo-1 .. lo+2
    blocks = (1 - w) * planar[:, 0:3] + w * planar[:, 1:4]  # levels u-1, u, u+1
    return blocks.flatten(1) * kind_slots(kind), valid
