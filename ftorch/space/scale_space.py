"""Half-octave Gaussian-derivative scale space (3.3.3) as a torch module.

For an image whose shorter side is m pixels the levels are sigma_k = 2^(k/2), k = 0..K, with
sigma_K <= m/4 (DESIGN.md). At each level the five steerable basis responses (G1@0, G1@pi/2,
G2@0, G2@pi/3, G2@2pi/3; eq. 3.8) are computed with separable kernels. Each 1-D pass is a
matrix product with a band matrix that has the symmetric ('reflect') boundary folded in, so
all images, levels and kernels of one pass are a few large GEMMs: the same sums as a direct
convolution, in another order (agreement with scipy is tested to 1e-10 in float64).
"""
from __future__ import annotations

import math
from dataclasses import dataclass

import torch
from torch import Tensor, nn

from ..errors import InputError
from ..images import as_image_batch
from .kernels import band_matrix, derivative_kernels, kernel_radius
from .steering import cartesian_from_basis

_SQRT3_2 = math.sqrt(3) / 2


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
    Kernels live in buffers and follow ``.to(device)``; the band matrices built from them are
    cached per (size, device, dtype).
    """

    def __init__(self, truncate: float = 3.0, max_levels: int = 20):
        super().__init__()
        if not truncate > 0:
            raise InputError(f"truncate must be positive, got {truncate}")
        self.truncate = float(truncate)
        self.max_levels = int(max_levels)
        for k in range(self.max_levels):
            kernels = torch.from_numpy(derivative_kernels(self.sigma(k), self.truncate))
            self.register_buffer(f"kernels_{k}", kernels, persistent=False)
        self._matrices: dict = {}

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
        """Per level: horizontal (3, W, W) for g, g', g'' and vertical row tiles.

        Vertical groups act on one horizontal channel each and carry the basis weights:
        g -> (Gy, 3/4 Gyy), g' -> (Gx, sqrt3/2 Gxy), g'' -> (Gxx, 1/4 Gxx). Each tile is
        (first row, last row, first column, 3 x 2T x C matrix): only the columns inside the
        band of its T output rows, so small scales cost less than a dense product.
        """
        key = (height, width, levels, str(device), dtype)
        if key not in self._matrices:
            if len(self._matrices) >= 8:
                self._matrices.pop(next(iter(self._matrices)))
            plan = []
            for k in range(levels):
                kern = getattr(self, f"kernels_{k}").cpu().numpy()
                horizontal = torch.stack([torch.from_numpy(band_matrix(kern[c], width).T) for c in range(3)])
                v = [torch.from_numpy(band_matrix(kern[c], height)) for c in range(3)]
                groups = torch.stack([
                    torch.stack([v[1], 0.75 * v[2]]),
                    torch.stack([v[0], _SQRT3_2 * v[1]]),
                    torch.stack([v[0], 0.25 * v[0]]),
                ])  # (3 channels, 2 outputs, H, H)
                tile = max(32, 2 * kernel_radius(self.sigma(k), self.truncate))
                tiles = []
                for a in range(0, height, tile):
                    b = min(a + tile, height)
                    used = groups[:, :, a:b].abs().sum((0, 1, 2)).nonzero()[:, 0]
                    c0, c1 = int(used.min()), int(used.max()) + 1
                    block = groups[:, :, a:b, c0:c1].reshape(3, 2 * (b - a), c1 - c0)
                    tiles.append((a, b, c0, c1, block.to(device=device, dtype=dtype).contiguous()))
                plan.append((horizontal.to(device=device, dtype=dtype), tiles))
            self._matrices[key] = plan
        return self._matrices[key]

    def forward(self, images) -> ScaleSpaceOutput:
        x = as_image_batch(images)[:, 0]
        batch, height, width = x.shape
        levels = self.num_levels(height, width)
        plan = self._band_matrices(height, width, levels, x.device, x.dtype)
        out = torch.empty(batch, levels, 5, height, width, device=x.device, dtype=x.dtype)
        rows = x.permute(1, 0, 2).reshape(height * batch, width)
        # out= writes save a temporary per tile but autograd refuses them: with a graph to record, the
        # same sums are written by assignment
        graph = torch.is_grad_enabled() and x.requires_grad
        for k, (horizontal, tiles) in enumerate(plan):
            h = torch.matmul(rows, horizontal).view(3, height, batch * width)
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
        sigmas = torch.tensor([self.sigma(k) for k in range(levels)], device=x.device, dtype=x.dtype)
        return ScaleSpaceOutput(out, sigmas, self.valid_mask(height, width, levels, x.device))
