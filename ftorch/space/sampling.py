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

A texture part (3.5 with 7.2.1) is sampled from the texture grid instead (:func:`sample_texture`):
at the level nearest sigma, bilinear between the four surrounding grid points of that level.
"""
from __future__ import annotations

from collections.abc import Iterable, Iterator
from typing import NamedTuple

import torch
from torch import Tensor

from .record import ImageRecords, ResponsePyramids
from .steering import rotate_pair, steer
from .texture import FIRST_LEVEL, grid_step


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


def sample_unmasked(pyramid: ResponsePyramids, frames: Frames, x: Tensor, y: Tensor, sigma: Tensor,
                    edgel: bool) -> tuple[Tensor, Tensor]:
    """:func:`sample_part`'s values and validity, except that an invalid sample holds what its
    nearest cells give (finite), not zero: for callers that discard invalid samples anyway."""
    u = level_index(sigma)
    reach = 0 if edgel else 1
    # the limits are small integers, exact as floats: the same comparisons as with the integers
    valid = ((x >= 0) & (y >= 0) & (x <= frames.x_max) & (y <= frames.y_max)
             & (u - reach >= 0) & (u + reach <= frames.u_max))
    return _read(pyramid, frames.source.expand(x.shape), x, y, u, edgel), valid


def _read(pyramid: ResponsePyramids, source: Tensor, x: Tensor, y: Tensor, u: Tensor, edgel: bool) -> Tensor:
    """Bilinear in (x, y), linear in the level u, from the pyramid's tables (see ``ResponsePyramids``);
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


TEXTURE_GRID = "texture grid"  # its key among a records object's cached reference points
SPAN_TOLERANCE = 1e-2  # grid steps: a texture sample this near the grid's span counts as on its edge


class GridLayout(NamedTuple):
    """Where each level's texture grid lies, per image and level (N, L), L = the most levels of any
    image: its first point's index in the image's grid row (``offset``), its first column and row
    (``x0``, ``y0``, as the records' float type), its numbers of columns and rows (0: none), and
    per level (L,) the step between them (``ftorch.space.texture.grid_step``)."""

    offset: Tensor
    x0: Tensor
    y0: Tensor
    columns: Tensor
    rows: Tensor
    step: Tensor

    @staticmethod
    def of(records: ImageRecords) -> "GridLayout":
        """The layout of the grid ``records`` hold (each level's points row by row, levels in turn,
        as ``TextureGrid`` makes them), read from the grid itself, batched; found once per records
        object (records are never changed in place)."""
        known = records.reference_points
        if TEXTURE_GRID not in known:
            n, q = records.grid_x.shape
            levels, device, dtype = max(1, int(records.levels.max())), records.device, records.dtype
            mask = records.grid_mask
            cell = (torch.arange(n, device=device)[:, None] * levels + records.grid_level.clamp(0, levels - 1))[mask]
            index = torch.arange(q, device=device).expand(n, -1)[mask]
            offset = torch.full((n * levels,), q, device=device).scatter_reduce(0, cell, index, "amin")

            def extreme(field: Tensor, how: str) -> Tensor:
                return field.new_zeros(n * levels).scatter_reduce(0, cell, field[mask], how, include_self=False)
            step = torch.tensor([grid_step(k) for k in range(levels)], device=device, dtype=dtype)
            x0, y0 = extreme(records.grid_x, "amin"), extreme(records.grid_y, "amin")
            present = offset < q
            columns = torch.where(present, torch.round((extreme(records.grid_x, "amax") - x0) / step.repeat(n)) + 1, 0)
            rows = torch.where(present, torch.round((extreme(records.grid_y, "amax") - y0) / step.repeat(n)) + 1, 0)
            offset, x0, y0, columns, rows = (t.view(n, levels) for t in (offset, x0, y0, columns.long(), rows.long()))
            known[TEXTURE_GRID] = GridLayout(offset, x0, y0, columns, rows, step)
        return known[TEXTURE_GRID]


def sample_texture(records: ImageRecords, image: Tensor, x: Tensor, y: Tensor, sigma: Tensor) -> tuple[Tensor, Tensor]:
    """A texture part's square-rooted histogram at finite (x, y, sigma) of one shape (``image``
    broadcasts to it): (..., BINS), and its validity (...) (alg. 3.6 step 4 for this kind).

    The level is k = round(2*log2(sigma)) (:func:`level_index`); the sample is valid where
    k >= ``FIRST_LEVEL``, the image has that level and (x, y) lies within the span of that level's
    grid in that image (within ``SPAN_TOLERANCE`` steps, clamped onto it: float32 placements miss a
    grid point on the edge by a few ulps). Its value is bilinear between the four surrounding grid
    points' vectors (on the last row or column the cell below reads it with weight 1); an invalid
    sample holds what its nearest cells give (finite), or zeros where the records hold no grid."""
    grid = GridLayout.of(records)
    shape = torch.broadcast_shapes(image.shape, x.shape, y.shape, sigma.shape)
    image, x, y = image.expand(shape), x.expand(shape), y.expand(shape)
    level = torch.round(level_index(sigma)).expand(shape)
    k = level.long().clamp(0, grid.step.shape[0] - 1)
    columns, rows = grid.columns[image, k], grid.rows[image, k]
    fx = (x - grid.x0[image, k]) / grid.step[k]
    fy = (y - grid.y0[image, k]) / grid.step[k]
    valid = ((level >= FIRST_LEVEL) & (level < records.levels[image]) & (columns > 0)
             & (fx >= -SPAN_TOLERANCE) & (fx <= columns - 1 + SPAN_TOLERANCE)
             & (fy >= -SPAN_TOLERANCE) & (fy <= rows - 1 + SPAN_TOLERANCE))
    if records.histograms.shape[1] == 0:
        return x.new_zeros(*shape, records.histograms.shape[-1]), valid
    last_column, last_row = (columns - 1).clamp_min(0), (rows - 1).clamp_min(0)
    fx, fy = torch.minimum(fx.clamp_min(0), last_column), torch.minimum(fy.clamp_min(0), last_row)
    j0, i0 = torch.minimum(fx.floor(), (columns - 2).clamp_min(0)), torch.minimum(fy.floor(), (rows - 2).clamp_min(0))
    wx, wy = (fx - j0)[..., None], (fy - i0)[..., None]
    j0, i0 = j0.long(), i0.long()
    j1, i1 = torch.minimum(j0 + 1, last_column), torch.minimum(i0 + 1, last_row)
    start, top = grid.offset[image, k], records.histograms.shape[1] - 1

    def at(i: Tensor, j: Tensor) -> Tensor:
        return records.histograms[image, (start + i * columns + j).clamp(0, top)]
    return ((1 - wy) * ((1 - wx) * at(i0, j0) + wx * at(i0, j1)) + wy * ((1 - wx) * at(i1, j0) + wx * at(i1, j1))), valid
