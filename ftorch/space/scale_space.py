"""Half-octave Gaussian-derivative scale space (3.3.3) as a torch module.

For an image whose shorter side is m pixels the levels are sigma_k = 2^(k/2), k = 0..K, with
sigma_K <= m/4 (DESIGN.md). At each level the five steerable basis responses (G1@0, G1@pi/2,
G2@0, G2@pi/3, G2@2pi/3; eq. 3.8) are computed with separable kernels, in one of two ways
(:class:`FilterMethod`), both with scipy's 'reflect' boundary (dcba|abcd: the edge pixel repeated):

- ``FilterMethod.BAND`` (the default): each 1-D pass is a matrix product with a band matrix that has
  the boundary folded in, so all images, levels and kernels of one pass are a few large GEMMs
  (tiled by output rows, and beyond ``DENSE_WIDTH`` columns by output columns: see there).
- ``FilterMethod.CONV``: each 1-D pass is one ``torch.nn.functional.conv2d`` per level, a (1, k) bank
  of the level's three kernels g, g', g'' across the rows and a (k, 1) bank of the same three
  down the columns, the three horizontal maps folded into the batch (one plain call, though it
  computes 9 maps for the 5 needed: a grouped call with two kernels per group is slower on the
  CPU, docs/benchmark.md). The padding is gathered by index, as torch's own 'reflect' pad leaves the
  edge pixel out.

Both compute the same sums as a direct convolution, in different orders: they agree with scipy to
1e-12 in float64 (tested) but not bit for bit with each other in float32. The band matrices stay
the default for two reasons: they are faster on the CPU (``python -m training.bench features``
times both; docs/benchmark.md, "Feature space and exact inference"), and the
project's reports are kept byte for byte, which another summation order would break.
"""
from __future__ import annotations

import math
from contextlib import contextmanager
from dataclasses import dataclass
from enum import StrEnum

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from ..errors import InputError
from ..images import as_image_batch
from .kernels import band_matrix, band_span, derivative_kernels, kernel_radius, reflect_index
from .steering import cartesian_from_basis

_SQRT3_2 = math.sqrt(3) / 2
PLANS = 8  # cached plans per module (image size, device, dtype)
# Widths up to DENSE_WIDTH run the horizontal pass as one product with dense (W, W) band matrices, as
# this module always did: every image size the project uses (128x128 and anything up to 1024 columns)
# keeps its responses bit for bit, and the reports stay byte for byte. Wider images tile the pass by
# output columns as the vertical pass is tiled by output rows (each tile holds only the input columns
# inside its band, the reflecting boundary folded in): 3 W^2 numbers per level would be 6 GB for a
# 16 x 16000 image, the tiles are 3 W (T + 2r). The tiled sums are the same to rounding (1e-12 in
# float64, tested), not bit for bit.
DENSE_WIDTH = 1024
TILE = 32  # output rows of a vertical tile and columns of a horizontal one, at least (2r, where larger)


@contextmanager
def _ieee_convolutions(device: torch.device):
    """On CUDA, cuDNN runs float32 convolutions in TF32 unless told otherwise (errors near 1e-3, beyond
    the tests' 2e-6); the band path's GEMMs are full float32, and so is the conv2d bank inside this."""
    if device.type != "cuda":
        yield
        return
    conv = torch.backends.cudnn.conv  # type: ignore[attr-defined]  # torch declares the module's other flags, not conv
    saved = conv.fp32_precision
    conv.fp32_precision = "ieee"
    try:
        yield
    finally:
        conv.fp32_precision = saved


def _planned(plans: dict, key: tuple, build):
    """``plans[key]``, built by ``build()`` where missing; the oldest plan goes beyond ``PLANS``."""
    if key not in plans:
        if len(plans) >= PLANS:
            plans.pop(next(iter(plans)))
        plans[key] = build()
    return plans[key]


def _tile(radius: int) -> int:
    """Outputs per tile of a pass whose kernel has this radius: :data:`TILE`, or 2r where larger."""
    return max(TILE, 2 * radius)


def _tiled_numbers(n: int, radius: int) -> int:
    """Upper bound of the numbers per kernel in the tiles of an n-long pass: each tile of T outputs
    reads at most min(n, T + 2 radius) inputs."""
    tile = _tile(radius)
    return sum(min(b - a + 2 * radius, n) * (b - a) for a in range(0, n, tile) for b in [min(a + tile, n)])


def _horizontal_pass(rows: Tensor, horizontal) -> Tensor:
    """(3, R, W): rows (R, W) through g, g', g'' along x, by the level's dense (3, W, W) matrices or its
    column tiles (:meth:`ScaleSpace._band_matrices`)."""
    if isinstance(horizontal, Tensor):
        return torch.matmul(rows, horizontal)
    out = rows.new_empty(3, *rows.shape)
    for a, b, c0, c1, block in horizontal:
        out[:, :, a:b] = torch.matmul(rows[:, c0:c1], block).view(-1, 3, b - a).permute(1, 0, 2)
    return out


class FilterMethod(StrEnum):
    """How :class:`ScaleSpace` runs its separable passes (the module docstring says why BAND is the default)."""

    BAND = "band"  # products with band matrices that have the reflecting boundary folded in
    CONV = "conv"  # torch.nn.functional.conv2d banks on padding gathered by reflection


@dataclass
class ScaleSpaceOutput:
    """Responses (B, S, 5, H, W), sigmas (S,), and valid (S, H, W): where the level's kernel fits."""

    responses: Tensor
    sigmas: Tensor
    valid: Tensor

    def scale_functions(self) -> tuple[Tensor, Tensor, Tensor]:
        """s_blob, s_corner, s_edge (B, S, H, W), eq. 3.9-3.11 on scale-normalised responses."""
        gx, gy, gxx, gxy, gyy = cartesian_from_basis(self.responses)
        blob = (gxx + gyy).abs()
        corner = (gy * gy * gxx - 2 * gx * gy * gxy + gx * gx * gyy).abs()
        edge = torch.sqrt((gx * gx + gy * gy) / self.sigmas[:, None, None])
        return blob, corner, edge


class ScaleSpace(nn.Module):
    """Steerable Gaussian-derivative responses at half-octave scales.

    ``truncate``: kernel radius in sigmas (radius = int(truncate*sigma + 0.5)); a point at level k
    is inside the image's valid region when the level-k kernel fits entirely inside the image.
    ``method``: :class:`FilterMethod` or its value ('band', 'conv'); both give the same responses to
    rounding. Kernels live in buffers and follow ``.to(device)``; the band matrices or conv2d
    weights built from them are cached per (size, device, dtype).

    Args:
        truncate: kernel radius in sigmas.
        max_levels: the most levels an image may have (kernels are built for these).
        method: how the separable passes run (:class:`FilterMethod`).

    Shape:
        - Input: :math:`(B, C, H, W)` (C = 1 grey or 3 RGB), :math:`(B, H, W)` or :math:`(H, W)`
          (:func:`~ftorch.images.as_image_batch`).
        - Output: :class:`ScaleSpaceOutput` with responses :math:`(B, S, 5, H, W)`, sigmas
          :math:`(S,)` and valid :math:`(S, H, W)`, S = :meth:`num_levels` of (H, W).
    """

    def __init__(self, truncate: float = 3.0, max_levels: int = 20, method: FilterMethod | str = FilterMethod.BAND):
        super().__init__()
        if not truncate > 0:
            raise InputError(f"truncate must be positive, got {truncate}")
        self.truncate = float(truncate)
        self.max_levels = int(max_levels)
        self.method = method
        for k in range(self.max_levels):
            kernels = torch.from_numpy(derivative_kernels(self.sigma(k), self.truncate))
            self.register_buffer(f"kernels_{k}", kernels, persistent=False)
        self._matrices: dict = {}
        self._convs: dict = {}

    @property
    def method(self) -> FilterMethod:
        return self._method

    @method.setter
    def method(self, value: FilterMethod | str) -> None:
        try:
            self._method = FilterMethod(value)
        except ValueError:
            raise InputError(f"method must be one of {', '.join(FilterMethod)}, got {value!r}") from None

    @staticmethod
    def sigma(level: float) -> float:
        return 2.0 ** (level / 2)

    def num_levels(self, height: int, width: int) -> int:
        """Number of levels S for an image: sigma from 1 up to a quarter of the shorter side."""
        side = min(height, width)
        levels = min(int(math.floor(2 * math.log2(side / 4) + 1e-9)) + 1 if side >= 4 else 0, self.max_levels)
        need = 2 * kernel_radius(self.sigma(1), self.truncate) + 1
        if levels < 3 or side < need:
            raise InputError(
                f"image of {height}x{width} pixels is too small for the scale range: the shorter side "
                f"must be at least {max(need, 8)} pixels (three half-octave levels from sigma=1, "
                f"kernel radius {kernel_radius(self.sigma(1), self.truncate)} at sigma=sqrt(2))"
            )
        return levels

    def radii(self, levels: int) -> list[int]:
        return [kernel_radius(self.sigma(k), self.truncate) for k in range(levels)]

    def valid_mask(self, height: int, width: int, levels: int, device=None) -> Tensor:
        """(S, H, W) bool: the level's kernel stays inside the image at that pixel (3.4.3)."""
        ys = torch.arange(height, device=device)
        xs = torch.arange(width, device=device)
        margin = torch.minimum(
            torch.minimum(ys, height - 1 - ys)[:, None], torch.minimum(xs, width - 1 - xs)[None, :]
        )
        radii = torch.tensor(self.radii(levels), device=device)
        return margin[None] >= radii[:, None, None]

    def _band_matrices(self, height: int, width: int, levels: int, device, dtype):
        """Per level: the horizontal pass for g, g', g'' and the vertical row tiles.

        Horizontal: (3, W, W) dense matrices up to ``DENSE_WIDTH`` columns, else column tiles
        (first column, last column, first input column, last input column, C x 3T matrix), each
        reading only the C input columns inside the band of its T output columns.
        Vertical groups act on one horizontal channel each and carry the basis weights:
        g -> (Gy, 3/4 Gyy), g' -> (Gx, sqrt3/2 Gxy), g'' -> (Gxx, 1/4 Gxx). Each tile is
        (first row, last row, first column, last column, 3 x 2T x C matrix): only the columns inside the
        band of its T output rows, so small scales cost less than a dense product. No (n, n) matrix is
        built for the tiles (``band_matrix`` builds the rows and columns asked for).
        """
        return _planned(self._matrices, (height, width, levels, str(device), dtype),
                        lambda: [self._band_level(k, height, width, device, dtype) for k in range(levels)])

    def _band_level(self, k: int, height: int, width: int, device, dtype) -> tuple:
        """:meth:`_band_matrices` of level k."""
        kern = getattr(self, f"kernels_{k}").cpu().numpy()
        radius = (kern.shape[1] - 1) // 2
        horizontal: Tensor | list[tuple[int, int, int, int, Tensor]]
        if width <= DENSE_WIDTH:
            horizontal = torch.stack([torch.from_numpy(band_matrix(kern[c], width).T) for c in range(3)])
            horizontal = horizontal.to(device=device, dtype=dtype)
        else:
            horizontal = []
            for a in range(0, width, _tile(radius)):
                b = min(a + _tile(radius), width)
                c0, c1 = band_span(a, b, radius, width)
                columns = np.stack([band_matrix(kern[c], width, np.arange(a, b), (c0, c1)).T for c in range(3)], 1)
                block = torch.from_numpy(columns.reshape(c1 - c0, 3 * (b - a)))
                horizontal.append((a, b, c0, c1, block.to(device=device, dtype=dtype).contiguous()))
        tiles = []
        for a in range(0, height, _tile(radius)):
            b = min(a + _tile(radius), height)
            lo, hi = band_span(a, b, radius, height)
            v = [torch.from_numpy(band_matrix(kern[c], height, np.arange(a, b), (lo, hi))) for c in range(3)]
            groups = torch.stack([
                torch.stack([v[1], 0.75 * v[2]]),
                torch.stack([v[0], _SQRT3_2 * v[1]]),
                torch.stack([v[0], 0.25 * v[0]]),
            ])  # (3 channels, 2 outputs, T, columns lo..hi)
            used = groups.abs().sum((0, 1, 2)).nonzero()[:, 0]
            c0, c1 = lo + int(used.min()), lo + int(used.max()) + 1
            block = groups[..., c0 - lo : c1 - lo].reshape(3, 2 * (b - a), c1 - c0)
            tiles.append((a, b, c0, c1, block.to(device=device, dtype=dtype).contiguous()))
        return horizontal, tiles

    def plan_nbytes(self, height: int, width: int, dtype=torch.float32) -> int:
        """Bytes of the matrices (or conv2d indices and kernels) that one image size's plan holds, an
        upper bound known without building them: what the memory check counts besides the pyramid."""
        levels = self.num_levels(height, width)
        itemsize = torch.empty(0, dtype=dtype).element_size()
        total = 0
        for k, radius in enumerate(self.radii(levels)):
            if self._method is FilterMethod.CONV:
                total += 8 * (height + width + 4 * radius) + 6 * (2 * radius + 1) * itemsize
                continue
            if width <= DENSE_WIDTH:
                total += 3 * width * width * itemsize
            else:
                total += 3 * _tiled_numbers(width, radius) * itemsize
            total += 6 * _tiled_numbers(height, radius) * itemsize
        return total

    def _conv_weights(self, height: int, width: int, levels: int, device, dtype):
        """Per level: the column and row indices of the reflect-padded image ((W + 2r,) and (H + 2r,)),
        and the level's kernels g, g', g'' flipped (conv2d correlates) as (3, 1, 1, k) and (3, 1, k, 1)."""
        return _planned(self._convs, (height, width, levels, str(device), dtype),
                        lambda: [self._conv_level(k, height, width, device, dtype) for k in range(levels)])

    def _conv_level(self, k: int, height: int, width: int, device, dtype) -> tuple:
        """:meth:`_conv_weights` of level k."""
        kern = getattr(self, f"kernels_{k}").detach().to(device=device, dtype=dtype).flip(-1)
        r = (kern.shape[1] - 1) // 2
        columns = torch.from_numpy(reflect_index(np.arange(-r, width + r), width)).to(device)
        rows = torch.from_numpy(reflect_index(np.arange(-r, height + r), height)).to(device)
        return columns, rows, kern[:, None, None, :].contiguous(), kern[:, None, :, None].contiguous()

    def forward(self, images) -> ScaleSpaceOutput:
        x = as_image_batch(images)[:, 0]
        if self._method is FilterMethod.CONV:
            return self._forward_conv(x)
        batch, height, width = x.shape
        levels = self.num_levels(height, width)
        plan = self._band_matrices(height, width, levels, x.device, x.dtype)
        out = torch.empty(batch, levels, 5, height, width, device=x.device, dtype=x.dtype)
        rows = x.permute(1, 0, 2).reshape(height * batch, width)
        # out= writes save a temporary per tile but autograd refuses them: with a graph to record, the
        # same sums are written by assignment
        graph = torch.is_grad_enabled() and x.requires_grad
        for k, (horizontal, tiles) in enumerate(plan):
            h = _horizontal_pass(rows, horizontal).view(3, height, batch * width)
            for a, b, c0, c1, block in tiles:
                v = torch.matmul(block, h[:, c0:c1]).view(6, b - a, batch, width).permute(2, 0, 1, 3)
                gy, gyy, gx, gxy, gxx, gxx4 = v.unbind(1)
                level = out[:, k, :, a:b]
                level[:, 0] = gx
                level[:, 1] = gy
                level[:, 2] = gxx
                if graph:
                    iso = gxx4 + gyy
                    level[:, 3] = iso + gxy
                    level[:, 4] = iso - gxy
                    continue
                iso = torch.add(gxx4, gyy, out=level[:, 3])
                torch.sub(iso, gxy, out=level[:, 4])
                iso.add_(gxy)
        return self._output(out, levels)

    def _forward_conv(self, x: Tensor) -> ScaleSpaceOutput:
        batch, height, width = x.shape
        levels = self.num_levels(height, width)
        plan = self._conv_weights(height, width, levels, x.device, x.dtype)
        out = torch.empty(batch, levels, 5, height, width, device=x.device, dtype=x.dtype)
        x = x[:, None]
        for k, (columns, rows, horizontal, vertical) in enumerate(plan):
            with _ieee_convolutions(x.device):
                h = F.conv2d(x.index_select(3, columns), horizontal)  # (B, 3, H, W): g, g', g'' along x
                h = h.index_select(2, rows).view(batch * 3, 1, -1, width)
                v = F.conv2d(h, vertical).view(batch, 3, 3, height, width)  # [x kernel, y kernel]
            gx, gy, gxx, gxy, gyy = v[:, 1, 0], v[:, 0, 1], v[:, 2, 0], v[:, 1, 1], v[:, 0, 2]
            iso = 0.25 * gxx + 0.75 * gyy
            mixed = _SQRT3_2 * gxy
            level = out[:, k]
            level[:, 0] = gx
            level[:, 1] = gy
            level[:, 2] = gxx
            level[:, 3] = iso + mixed
            level[:, 4] = iso - mixed
        return self._output(out, levels)

    def _output(self, out: Tensor, levels: int) -> ScaleSpaceOutput:
        height, width = out.shape[-2:]
        sigmas = torch.tensor([self.sigma(k) for k in range(levels)], device=out.device, dtype=out.dtype)
        return ScaleSpaceOutput(out, sigmas, self.valid_mask(height, width, levels, out.device))
