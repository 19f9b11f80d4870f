"""Long, thin images (issue 52, item 11): band matrices built in parts, the horizontal pass and the
texture blur tiled beyond DENSE_WIDTH (against scipy and against the dense products), plans whose
size grows with the image side, not its square, and a memory check that counts them."""
import numpy as np
import pytest
import torch

from ftorch import FeatureSpace, InputError, ScaleSpace
from ftorch.space import record, scale_space, texture
from ftorch.space.kernels import band_matrix, band_span, derivative_kernels, kernel_radius
from ftorch.space.reference import scipy_basis
from tests.conftest import random_image
from tests.space.test_texture import brute_histograms


def _nbytes(plan) -> int:
    """Bytes of the tensors in a plan (nested lists and tuples)."""
    if isinstance(plan, torch.Tensor):
        return plan.nbytes
    if isinstance(plan, (list, tuple, dict)):
        return sum(_nbytes(p) for p in (plan.values() if isinstance(plan, dict) else plan))
    return 0


def test_band_matrix_builds_any_part_with_the_values_of_the_whole_bit_for_bit():
    rng = np.random.default_rng(0)
    for sigma, truncate, n in [(1.0, 3.0, 7), (2.0, 3.0, 40), (5.66, 3.0, 31), (4.0, 5.0, 16), (11.3, 3.0, 300)]:
        for kernel in derivative_kernels(sigma, truncate):
            whole = band_matrix(kernel, n)
            radius = (len(kernel) - 1) // 2
            for _ in range(5):
                rows = np.sort(rng.choice(n, size=min(n, 6), replace=False))
                c0, c1 = sorted(rng.choice(n + 1, 2, replace=False))
                part = band_matrix(kernel, n, rows, (c0, c1))
                assert part.view(np.uint64).tolist() == whole[rows][:, c0:c1].view(np.uint64).tolist()
                a, b = sorted(rng.choice(n + 1, 2, replace=False))
                lo, hi = band_span(a, b, radius, n)
                inside = np.zeros(n, bool)
                inside[lo:hi] = True
                assert not whole[a:b, ~inside].any() and hi - lo <= min(n, b - a + 2 * radius)


def test_a_wide_image_takes_the_tiled_horizontal_pass_and_equals_scipy():
    image = random_image(24, 3000, seed=7)
    image = (image - image.min()) / (image.max() - image.min())  # range exactly 1: any contrast rule keeps it
    space = ScaleSpace()
    out = space(image)
    (plan,) = space._matrices.values()
    assert all(isinstance(horizontal, list) for horizontal, _ in plan)  # tiles, no (3, W, W) matrix
    for k, sigma in enumerate(out.sigmas.tolist()):
        np.testing.assert_allclose(out.responses[0, k].numpy(), scipy_basis(image.numpy(), sigma), rtol=0, atol=1e-12)


def _dense_and_tiled(monkeypatch, run):
    """``run()`` with today's DENSE_WIDTH and with 32: the passes of sides beyond 32 tiled."""
    out = []
    for dense_width in (scale_space.DENSE_WIDTH, 32):
        monkeypatch.setattr(scale_space, "DENSE_WIDTH", dense_width)
        monkeypatch.setattr(texture, "DENSE_WIDTH", dense_width)
        out.append(run())
    return out


def test_the_tiled_passes_equal_the_dense_ones(monkeypatch):
    g = torch.Generator().manual_seed(3)
    for shape in [(2, 1, 40, 300), (1, 1, 260, 36)]:
        images = torch.rand(shape, dtype=torch.float64, generator=g)

        def run():
            out = ScaleSpace()(images)
            grid = texture.TextureGrid()
            return out.responses, grid(images[:, 0], out.responses.shape[1]), grid._plans

        (dense, dense_grid, _), (tiled, tiled_grid, tiled_plan) = _dense_and_tiled(monkeypatch, run)
        torch.testing.assert_close(tiled, dense, rtol=0, atol=1e-12)
        for a, b in zip(tiled_grid, dense_grid):
            torch.testing.assert_close(a, b, rtol=0, atol=1e-12)
        ((_, vertical, horizontal, *_), *_), = tiled_plan.values()
        assert isinstance(vertical, list) and isinstance(horizontal, list)  # both blurs were tiled
        at = tiled_grid[2] == texture.FIRST_LEVEL
        x, y = tiled_grid[0][at].long().numpy(), tiled_grid[1][at].long().numpy()
        brute = brute_histograms(images[0, 0].numpy(), texture.level_sigma(texture.FIRST_LEVEL))[y, x]
        np.testing.assert_allclose(tiled_grid[3][0, at].numpy(), brute, rtol=0, atol=1e-10)


def test_the_tiled_horizontal_pass_has_the_dense_ones_gradient(monkeypatch):
    images = torch.rand(2, 1, 16, 90, dtype=torch.float64, generator=torch.Generator().manual_seed(4))
    weights = torch.randn(2, 5, 5, 16, 90, dtype=torch.float64, generator=torch.Generator().manual_seed(5))

    def run():
        pixels = images.clone().requires_grad_()
        return torch.autograd.grad((ScaleSpace()(pixels).responses * weights).sum(), pixels)[0]

    dense, tiled = _dense_and_tiled(monkeypatch, run)
    torch.testing.assert_close(tiled, dense, rtol=0, atol=1e-12)


def test_the_plans_of_a_wide_image_grow_with_its_sides_not_their_squares():
    """Each tile of T = max(32, 2r) outputs reads at most T + 2r <= 32 + 4r inputs: 3 kernels along x
    and 6 (3 channels x 2 outputs) down y; the dense (3, W, W) matrices were 3 W numbers per column,
    and the texture's (W, grid columns) W per grid column."""
    height, width = 16, 2500
    images = torch.rand(1, 1, height, width, generator=torch.Generator().manual_seed(5))
    space = FeatureSpace()
    space(images)
    levels = space.scale_space.num_levels(height, width)
    bound = sum(9 * (height + width) * (32 + 4 * r) for r in space.scale_space.radii(levels)) * 4  # float32
    held = _nbytes(space.scale_space._matrices)
    assert held <= bound < 3 * width * width * 4
    # the texture blur: at most 64 + 2r inputs per grid row and column, and the points' x and y
    grid = space.texture.points(height, width, levels)
    assert _nbytes(space.texture._plans) <= sum((len(rows) + len(cols)) * (64 + 2 * kernel_radius(texture.level_sigma(k), 3))
                                                * 4 + 16 * len(rows) * len(cols) for k, rows, cols in grid)
    # what the memory check counts: an upper bound of what the plans hold
    assert held <= space.scale_space.plan_nbytes(height, width) <= bound
    assert held + _nbytes(space.texture._plans) <= space.matrices_nbytes([(height, width)])


def test_a_16_by_16000_image_gets_its_records_and_the_check_counts_the_matrices(monkeypatch):
    space = FeatureSpace()
    need = space.matrices_nbytes([(16, 16000)])
    assert need < 100 * 2**20  # the dense horizontal matrices alone were 6 GB a level
    image = random_image(16, 16000, seed=9, dtype=torch.float32).clamp(0, 1)
    pyramid = space.pyramid_nbytes([image])
    monkeypatch.setattr(record, "free_memory", lambda device: pyramid + need // 2)
    with pytest.raises(InputError, match=r"^1 images of up to 16x16000 pixels need 0.0 GiB for their scale-space "
                                         r"pyramid and 0.0 GiB for its filter matrices, more than"):
        space.records([image])
    assert not space.scale_space._matrices and not space.texture._plans  # refused before building anything
    monkeypatch.setattr(record, "free_memory", lambda device: pyramid + need)
    records = space.records([image])
    assert records.counts()["edgels"][0] > 0 and records.grid_mask.any()
    assert _nbytes(space.scale_space._matrices) + _nbytes(space.texture._plans) <= need
