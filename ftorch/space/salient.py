"""Salient edgels and texels (3.4.3).

- Texels: 3-D local maxima (3x3x3 neighbourhood, ties allowed) of s_blob and s_corner at
  interior levels 1..S-2, so every maximum is enclosed by lower values in scale (example 3.2)
  and a texel's sigma/sqrt2 and sigma*sqrt2 levels exist. Both sets are kept as separate points;
  two maxima at one pixel stay two points, each with exactly one scale.
- Edgels: s_edge is projected onto the image plane by its maximum over the levels whose kernel
  fits at the pixel (example 3.3); gradient-parallel non-maximum suppression on that map
  (bilinear samples one pixel either side along the gradient) leaves thin contours.
- Orientation: edgels, the gradient direction at their scale (eq. 3.5); texels, the gradient
  direction at the scale that maximises s_edge at their pixel (Chomat et al., 3.4.2).
- No point where its own kernel leaves the image. ``rel_threshold`` drops maxima weaker than
  that fraction of the image's strongest one; it only removes numerical noise in flat regions
  and near-flat maxima whose descriptors match any flat region (the text uses no prominence
  threshold; the default 0.01 is far below any real structure).
- Flat images have no salient points: a point is kept only where one of its five basis responses
  exceeds ``min_response`` in magnitude (default 1e-5, on images whose range
  :func:`~ftorch.images.contrast_normalized` brought into (1/2, 1], so the floor is relative to it). Rounding noise on a
  constant image stays below 1e-7; a single pixel one grey level (1/255) off its surroundings
  already gives 6e-4, so the floor removes noise and nothing an 8-bit image can show. Without it
  the relative threshold alone would keep hundreds of "maxima" of that noise.
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor, nn

from .primitives import BLOB, CORNER, EDGEL
from .scale_space import ScaleSpaceOutput


@dataclass
class Points:
    """Flat list of salient points of a batch: image index and attributes, ordered by image."""

    image: Tensor
    x: Tensor
    y: Tensor
    level: Tensor
    theta: Tensor
    kind: Tensor
    strength: Tensor


class SalientPoints(nn.Module):
    """The salient edgels and texels of a batch's scale space (the module docstring's rules).

    Args:
        rel_threshold: the fraction of an image's strongest maximum below which maxima are dropped.
        min_response: the basis-response magnitude a point needs somewhere (flat images have none).

    Shape:
        - Input: :class:`~ftorch.space.scale_space.ScaleSpaceOutput` of B images, S levels.
        - Output: :class:`Points`, each field :math:`(P,)` for the P points of all images, ordered by image.
    """

    def __init__(self, rel_threshold: float = 1e-2, min_response: float = 1e-5):
        super().__init__()
        self.rel_threshold = float(rel_threshold)
        self.min_response = float(min_response)

    def _threshold(self, f: Tensor, valid: Tensor) -> Tensor:
        strongest = torch.where(valid, f, torch.zeros((), dtype=f.dtype, device=f.device))
        return self.rel_threshold * strongest.flatten(1).amax(1)

    def _scale_maxima(self, f: Tensor, valid: Tensor, structured: Tensor) -> Tensor:
        pooled = f
        for dim in (1, 2, 3):  # the 3x3x3 maximum is separable
            pooled = _max3(pooled, dim)
        levels = f.shape[1]
        interior = torch.zeros(levels, dtype=torch.bool, device=f.device)
        interior[1 : levels - 1] = True
        keep = (f >= pooled) & valid[None] & interior[None, :, None, None] & structured
        return keep & (f > self._threshold(f, valid)[:, None, None, None])

    def forward(self, space: ScaleSpaceOutput) -> Points:
        blob, corner, edge = space.scale_functions()
        valid = space.valid
        structured = space.responses.abs().amax(2) > self.min_response  # (B, S, H, W): not flat
        batch, levels, height, width = edge.shape
        # edge projection over the levels whose kernel fits (example 3.3)
        fitted = torch.where(valid[None], edge, torch.full_like(edge, -1.0))
        strongest, edge_level = fitted.max(1)
        pixel_valid = valid[0]
        projected = torch.where(pixel_valid, strongest, edge[:, 0])
        edge_level = torch.where(pixel_valid, edge_level, torch.zeros_like(edge_level))
        first = space.responses[:, :, :2]  # (B, S, 2, H, W)
        index = edge_level[:, None, None].expand(batch, 1, 2, height, width)
        gx, gy = first.gather(1, index)[:, 0].unbind(1)
        theta = torch.atan2(gy, gx)
        # gradient-parallel non-maximum suppression on the projected map
        ys, xs = torch.meshgrid(
            torch.arange(height, device=edge.device, dtype=edge.dtype),
            torch.arange(width, device=edge.device, dtype=edge.dtype),
            indexing="ij",
        )
        ahead = _bilinear(projected, xs + torch.cos(theta), ys + torch.sin(theta))
        behind = _bilinear(projected, xs - torch.cos(theta), ys - torch.sin(theta))
        edgels = pixel_valid & (projected > ahead) & (projected >= behind) & structured.gather(1, edge_level[:, None])[:, 0]
        edgels &= projected > self._threshold(projected[:, None], valid[:1])[:, None, None]

        found = []
        b, y, x = edgels.nonzero(as_tuple=True)
        found.append((b, y, x, edge_level[b, y, x], torch.full_like(b, EDGEL), projected[b, y, x]))
        for kind, f in ((BLOB, blob), (CORNER, corner)):
            b, k, y, x = self._scale_maxima(f, valid, structured).nonzero(as_tuple=True)
            found.append((b, y, x, k, torch.full_like(b, kind), f[b, k, y, x]))
        image = torch.cat([f[0] for f in found])
        order = torch.argsort(image, stable=True)
        cat = lambda i: torch.cat([f[i] for f in found])[order]  # noqa: E731
        image, y, x, level, kinds, strength = cat(0), cat(1), cat(2), cat(3), cat(4), cat(5)
        return Points(image, x, y, level, theta[image, y, x], kinds, strength)


def _max3(f: Tensor, dim: int) -> Tensor:
    """Maximum over each element and its two neighbours along ``dim`` (outside counts as -inf)."""
    pad = [0, 0] * (f.ndim - 1 - dim) + [1, 1]
    p = F.pad(f, pad, value=-math.inf)
    n = f.shape[dim]
    return torch.maximum(torch.maximum(p.narrow(dim, 0, n), p.narrow(dim, 1, n)), p.narrow(dim, 2, n))


def _bilinear(maps: Tensor, x: Tensor, y: Tensor) -> Tensor:
    """Sample maps (B, H, W) at float pixel coordinates x, y (B, H, W); zero outside."""
    height, width = maps.shape[-2:]
    grid = torch.stack([2 * x / (width - 1) - 1, 2 * y / (height - 1) - 1], dim=-1)
    return F.grid_sample(maps[:, None], grid, mode="bilinear", padding_mode="zeros", align_corners=True)[:, 0]
