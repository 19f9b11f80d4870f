"""Alg. 3.6's placement of a local feature's parts, and sampling their responses from the dense
pyramid at any (x, y, sigma) (steps 3 and 4): the one implementation that evaluation, generation
and drawing use (``ftorch.space.reference`` keeps an independent one, as the test oracle).

Between pixels: bilinear. Between levels: linear in the level index u = 2*log2(sigma) (i.e. in
log sigma), applied to the scale-normalised responses. A texel at u reads levels u-1, u, u+1;
an edgel reads the first-order pair at u. At integer positions and levels this returns the
stored values exactly, so a feature measured from an image has value 1 at its own reference
point. Level indices within 1e-4 of an integer are snapped to it (float32 sigmas such as
sqrt(2) would otherwise fall just outside a level). A sample is valid when (x, y) lies inside
the image and the levels it reads exist.
"""
from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import NamedTuple

import torch
from torch import Tensor

from .record import ImageRecords, Pyramid
from .steering import rotate_pair, steer


def level_index(sigma: Tensor) -> Tensor:
    """Fractional pyramid level u = 2*log2(sigma), snapped to integers within 1e-4."""
    u = 2 * torch.log2(sigma)
    nearest = torch.round(u)
    return torch.where((u - nearest).abs() < 1e-4, nearest, u)


def advance(x: Tensor, y: Tensor, sigma: Tensor, theta: Tensor, phi, dtheta, d, dsigma):
    """Alg. 3.6 step 3: location, scale and orientation of part i from those of part i-1."""
    step = sigma * d
    return x + step * torch.cos(theta + phi), y + step * torch.sin(theta + phi), sigma * dsigma, theta + dtheta


def placements(start: tuple, attitudes: Iterable[tuple]) -> Iterator[tuple]:
    """(x, y, sigma, theta) of every part: the first part's ``start``, then each later part placed
    from the one before by its attitude (phi, dtheta, d, dsigma) (alg. 3.6 step 3). Attitudes may
    be numbers or tensors that broadcast with ``start`` (a batch of features at once)."""
    state = start
    yield state
    for attitude in attitudes:
        state = advance(*state, *attitude)
        yield state


def steered_sample(records: ImageRecords, image: Tensor, x: Tensor, y: Tensor, sigma: Tensor, theta: Tensor,
                   edgel: bool) -> tuple[Tensor, Tensor]:
    """A part's responses sampled at (x, y, sigma) (:func:`sample_part`) and steered to theta, so
    comparable with canonical descriptors (eq. 3.13), and their validity (alg. 3.6 step 4)."""
    sample, valid = sample_part(records, image, x, y, sigma, edgel)
    return steered(sample, theta, edgel), valid


def steered(sample: Tensor, theta: Tensor, edgel: bool) -> Tensor:
    """Samples of one part kind steered to theta (eq. 3.8)."""
    return rotate_pair(sample, theta) if edgel else steer(sample, theta)


def sample_part(records: ImageRecords, image: Tensor, x: Tensor, y: Tensor, sigma: Tensor,
                edgel: bool) -> tuple[Tensor, Tensor]:
    """Responses of one part kind at finite inputs of one shape (``image``, each sample's record,
    broadcasts to it): (..., 2) first-order pairs at u for an edgel, (..., 15) blocks at u-1, u,
    u+1 for a texel, in the image frame, and validity (...). Invalid samples are zero. A texel
    reads 4 corners x 4 levels x 5 responses, an edgel 4 corners x 2 levels x 2."""
    values, valid = sample_unmasked(records.pyramid, Frames.of(records, image), x, y, sigma, edgel)
    return torch.where(valid[..., None], values, 0.0), valid


class Frames(NamedTuple):
    """The limits of valid samples in each sample's image (alg. 3.6 step 4), as the samples'
    float type, and its row in the pyramid: found once for many parts sampled in the same images."""

    x_max: Tensor
    y_max: Tensor
    u_max: Tensor
    source: Tensor

    @staticmethod
    def of(records: ImageRecords, image: Tensor) -> "Frames":
        size, levels, dtype = records.sizes[image], records.levels[image], records.dtype
        return Frames((size[..., 1] - 1).to(dtype), (size[..., 0] - 1).to(dtype), (levels - 1).to(dtype),
                      records.source[image])


def sample_unmasked(pyramid: Pyramid, frames: Frames, x: Tensor, y: Tensor, sigma: Tensor,
                    edgel: bool) -> tuple[Tensor, Tensor]:
    """:func:`sample_part`'s values and validity, except that an invalid sample holds what its
    nearest cells give (finite), not zero: for callers that discard invalid samples anyway."""
    u = level_index(sigma)
    reach = 0 if edgel else 1
    # the limits are small integers, exact as floats: the same comparisons as with the integers
    valid = ((x >= 0) & (y >= 0) & (x <= frames.x_max) & (y <= frames.y_max)
             & (u - reach >= 0) & (u + reach <= frames.u_max))
    return _read(pyramid, frames.source.expand(x.shape), x, y, u, edgel), valid


def _read(pyramid: Pyramid, source: Tensor, x: Tensor, y: Tensor, u: Tensor, edgel: bool) -> Tensor:
    """Bilinear in (x, y), linear in the level u, from the pyramid's tables (see ``Pyramid``);
    positions outside the pyramid read its nearest cells (their samples are invalid)."""
    shape = x.shape
    source, x, y, u = source.reshape(-1), x.reshape(-1), y.reshape(-1), u.reshape(-1)
    _, height, width, stride, _ = pyramid.first.shape
    lo = torch.floor(u).clamp(0, stride - 4)
    w = (u - lo).clamp(0, 1)[:, None]
    # the cell's lower corner; on the last row or column the cell below reads it with weight 1
    x0, y0 = torch.floor(x).clamp(0, max(width - 2, 0)), torch.floor(y).clamp(0, max(height - 2, 0))
    wx, wy = (x - x0)[:, None], (y - y0)[:, None]
    weights = ((1 - wy) * (1 - wx), (1 - wy) * wx, wy * (1 - wx), wy * wx)
    # table entry lo + 1 holds level lo: an edgel reads levels lo, lo + 1, a texel lo - 1 .. lo + 2
    entry = ((source * height + y0.long()) * width + x0.long()) * stride + lo.long() + (1 if edgel else 0)
    rows = (entry, entry + stride, entry + width * stride, entry + (width + 1) * stride)  # the cell's corners

    def planar(table: Tensor, span: int) -> Tensor:
        """The four corners' runs of ``span`` numbers from ``rows``, weighted and summed (M, span)."""
        size = table.shape[-1]
        runs = table.view(-1).as_strided(((table.numel() - span) // size + 1, span), (size, 1))
        c = [runs.index_select(0, r) for r in rows]
        return weights[0] * c[0] + weights[1] * c[1] + weights[2] * c[2] + weights[3] * c[3]

    if edgel:  # (G1@0, G1@pi/2) at levels lo, lo + 1
        pair = planar(pyramid.first, 4)
        return ((1 - w) * pair[:, 0:2] + w * pair[:, 2:4]).view(*shape, 2)
    blocks = torch.cat([planar(pyramid.first, 8).view(-1, 4, 2), planar(pyramid.second, 12).view(-1, 4, 3)], -1)
    return ((1 - w[:, :, None]) * blocks[:, 0:3] + w[:, :, None] * blocks[:, 1:4]).view(*shape, 15)
