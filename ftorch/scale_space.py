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

from .errors import InputError
from .images import as_image_batch
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
        key = (height, width, levels, str(device), dtype)
        if key not in self._matrices:
            if len(self._matrices) >= 8:
                self._matrices.pop(next(iter(self._matrices)))
            rows, cols = [], []
            for k in range(levels):
                kern = getattr(self, f"kernels_{k}").cpu().numpy()
                # horizontal: x_rows @ M.T for g, g', g''
                rows.append(torch.stack([torch.from_numpy(band_matrix(kern[c], width).T) for c in range(3)]))
                v = [torch.from_numpy(band_matrix(kern[c], height)) for c in range(3)]
                # vertical groups by horizontal channel: g -> (Gy, Gyy); g' -> (Gx, Gxy); g'' -> (Gxx, unused)
                cols.append(torch.stack([torch.cat([v[1], v[2]]), torch.cat([v[0], v[1]]), torch.cat([v[0], v[1]])]))
            self._matrices[key] = (
                torch.stack(rows).to(device=device, dtype=dtype),
                torch.stack(cols).to(device=device, dtype=dtype),
            )
        return self._matrices[key]

    def forward(self, images) -> ScaleSpaceOutput:
        x = as_image_batch(images)[:, 0]
        batch, height, width = x.shape
        levels = self.num_levels(height, width)
        horizontal, vertical = self._band_matrices(height, width, levels, x.device, x.dtype)
        out = torch.empty(batch, levels, 5, height, width, device=x.device, dtype=x.dtype)
        rows = x.permute(1, 0, 2).reshape(height * batch, width)
        for k in range(levels):
            h = torch.matmul(rows, horizontal[k]).view(3, height, batch * width)
            v = torch.matmul(vertical[k], h).view(6, height, batch, width).permute(2, 0, 1, 3)
            gy, gyy, gx, gxy, gxx = v[:, 0], v[:, 1], v[:, 2], v[:, 3], v[:, 4]
            level = out[:, k]
            level[:, 0] = gx
            level[:, 1] = gy
            level[:, 2] = gxx
            iso = 0.25 * gxx + 0.75 * gyy
            mixed = _SQRT3_2 * gxy
            torch.add(iso, mixed, out=level[:, 3])
            torch.sub(iso, mixed, out=level[:, 4])
        sigmas = torch.tensor([self.sigma(k) for k in range(levels)], device=x.device, dtype=x.dtype)
        return ScaleSpaceOutput(out, sigmas, self.valid_mask(height, width, levels, x.device))
