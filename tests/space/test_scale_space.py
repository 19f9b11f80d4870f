"""Scale space: kernels and responses against scipy, steering against rotated kernels, scale selection."""
import math

import numpy as np
import pytest
import scipy.ndimage as ndi
import torch

from ftorch import InputError, ScaleSpace
from ftorch.space.kernels import kernel_radius
from ftorch.space.reference import scipy_basis
from ftorch.space.scale_space import FilterMethod
from ftorch.space.steering import steer, steer_block
from tests.conftest import random_image


@pytest.mark.parametrize("method", list(FilterMethod))
def test_responses_equal_scipy_everywhere_in_float64(method):
    image = random_image(40, 52, seed=1)
    out = ScaleSpace(method=method)(image)
    assert out.responses.shape == (1, 7, 5, 40, 52)
    for k, sigma in enumerate(out.sigmas.tolist()):
        expected = scipy_basis(image.numpy(), sigma)
        np.testing.assert_allclose(out.responses[0, k].numpy(), expected, rtol=0, atol=1e-12)


@pytest.mark.parametrize("method", list(FilterMethod))
def test_responses_equal_scipy_on_interior_in_float32(method):
    """Tolerance: 2e-6 of the level's largest response, on pixels where the kernel fits."""
    image = random_image(64, 64, seed=2, dtype=torch.float32)
    out = ScaleSpace(method=method)(image[None])
    for k, sigma in enumerate(out.sigmas.tolist()):
        expected = scipy_basis(image.double().numpy(), sigma)
        inside = out.valid[k].numpy()
        if not inside.any():
            continue
        err = np.abs(out.responses[0, k].double().numpy() - expected)[:, inside].max()
        assert err <= 2e-6 * np.abs(expected).max(), (k, err)


def test_the_methods_agree_on_a_batch_beyond_one_reflection_and_under_autograd():
    """Kernels wider than the image (truncate 5: radius 20 at sigma 4 on 16 rows) reflect more than once."""
    images = torch.rand(3, 1, 16, 20, dtype=torch.float64, generator=torch.Generator().manual_seed(5))
    band = ScaleSpace(truncate=5.0)(images)
    conv = ScaleSpace(truncate=5.0, method="conv")(images)
    assert conv.responses.shape == band.responses.shape == (3, 5, 5, 16, 20)
    torch.testing.assert_close(conv.responses, band.responses, rtol=0, atol=1e-12)
    assert torch.equal(conv.valid, band.valid) and torch.equal(conv.sigmas, band.sigmas)
    for k, sigma in enumerate(band.sigmas.tolist()):
        expected = scipy_basis(images[1, 0].numpy(), sigma, truncate=5.0)
        np.testing.assert_allclose(conv.responses[1, k].numpy(), expected, rtol=0, atol=1e-12)
    # a linear map: its gradient for any weighting equals the band path's, which gradcheck checks below
    pixels = images.clone().requires_grad_()
    weights = torch.randn(band.responses.shape, dtype=torch.float64, generator=torch.Generator().manual_seed(6))
    (grad_conv,) = torch.autograd.grad((ScaleSpace(truncate=5.0, method="conv")(pixels).responses * weights).sum(), pixels)
    (grad_band,) = torch.autograd.grad((ScaleSpace(truncate=5.0)(pixels).responses * weights).sum(), pixels)
    torch.testing.assert_close(grad_conv, grad_band, rtol=0, atol=1e-12)


@pytest.mark.parametrize("method", ["fft", "", None, 3, "BAND"])
def test_an_unknown_method_is_an_input_error(method):
    with pytest.raises(InputError, match="method must be one of band, conv"):
        ScaleSpace(method=method)
    space = ScaleSpace()
    with pytest.raises(InputError, match="method must be one of band, conv"):
        space.method = method
    assert space.method is FilterMethod.BAND


def test_the_default_method_is_the_band_matrices():
    assert ScaleSpace().method is FilterMethod.BAND
    space = ScaleSpace(method="conv")
    assert space.method is FilterMethod.CONV and isinstance(space.method, FilterMethod)


def test_the_conv_bank_asks_cudnn_for_full_float32_and_gives_the_setting_back():
    from ftorch.space.scale_space import _ieee_convolutions

    conv = torch.backends.cudnn.conv
    before = conv.fp32_precision
    with _ieee_convolutions(torch.device("cuda")):
        assert conv.fp32_precision == "ieee"
    assert conv.fp32_precision == before
    with pytest.raises(KeyError), _ieee_convolutions(torch.device("cuda")):
        raise KeyError
    assert conv.fp32_precision == before
    with _ieee_convolutions(torch.device("cpu")):
        assert conv.fp32_precision == before


def rotated_kernel(sigma: float, theta: float, order: int, truncate: float = 3.0) -> np.ndarray:
    """G_d^theta sampled directly in rotated coordinates (eq. 3.3), scale-normalised."""
    r = kernel_radius(sigma, truncate)
    y, x = np.mgrid[-r : r + 1, -r : r + 1].astype(np.float64)
    g1 = np.exp(-0.5 * np.arange(-r, r + 1) ** 2 / sigma**2)
    g = np.exp(-(x * x + y * y) / (2 * sigma**2)) / g1.sum() ** 2
    u = x * math.cos(theta) + y * math.sin(theta)
    if order == 1:
        return sigma * (-u / sigma**2) * g
    plain = (u * u / sigma**4 - 1 / sigma**2) * g
    # the zero-sum correction of kernels.py, applied along each axis, is isotropic: c * (cos^2 + sin^2) * G
    dc = ((np.arange(-r, r + 1) ** 2 / sigma**4 - 1 / sigma**2) * g1 / g1.sum()).sum()
    return sigma**2 * (plain - dc * g)


@pytest.mark.parametrize("theta", [0.3, 1.1, 2.5, -0.7, math.pi / 3])
def test_steering_equals_explicitly_rotated_kernels(theta):
    image = random_image(48, 48, seed=3)
    out = ScaleSpace()(image)
    for k in (1, 3):
        sigma = float(out.sigmas[k])
        block = out.responses[0, k].permute(1, 2, 0)
        steered = steer_block(block, torch.tensor(theta, dtype=torch.float64)).permute(2, 0, 1).numpy()
        expect = {
            0: (1, theta), 1: (1, theta + math.pi / 2),
            2: (2, theta), 3: (2, theta + math.pi / 3), 4: (2, theta + 2 * math.pi / 3),
        }
        for channel, (order, angle) in expect.items():
            direct = ndi.convolve(image.numpy(), rotated_kernel(sigma, angle, order), mode="reflect")
            np.testing.assert_allclose(steered[channel], direct, rtol=0, atol=1e-12)


def test_steering_is_orthogonal_composes_and_preserves_inner_products():
    g = torch.Generator().manual_seed(4)
    u = torch.randn(100, 15, generator=g, dtype=torch.float64)
    v = torch.randn(100, 15, generator=g, dtype=torch.float64)
    a = torch.rand(100, generator=g, dtype=torch.float64) * 10 - 5
    b = torch.rand(100, generator=g, dtype=torch.float64) * 10 - 5
    torch.testing.assert_close(steer(u, a).norm(dim=1), u.norm(dim=1), rtol=1e-12, atol=1e-12)
    torch.testing.assert_close((steer(u, a) * steer(v, a)).sum(1), (u * v).sum(1), rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(steer(steer(u, a), b), steer(u, a + b), rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(steer(u, a + 2 * math.pi), steer(u, a), rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(steer(u, torch.zeros(100, dtype=torch.float64)), u)


@pytest.mark.parametrize("std", [1.6, 2.0, 2.9, 4.0, 5.5, 8.0])
def test_gaussian_blob_peaks_at_the_nearest_level(std):
    size = 96
    y, x = torch.meshgrid(torch.arange(size, dtype=torch.float64), torch.arange(size, dtype=torch.float64), indexing="ij")
    image = torch.exp(-((x - 47) ** 2 + (y - 48) ** 2) / (2 * std**2))
    out = ScaleSpace()(image)
    blob = out.scale_functions()[0][0, :, 48, 47]
    nearest = int(torch.argmin((torch.log2(out.sigmas) - math.log2(std)).abs()))
    assert int(blob.argmax()) == nearest


def test_levels_follow_the_quarter_side_rule_and_kernel_fit():
    space = ScaleSpace()
    assert space.num_levels(128, 128) == 11  # sigma 1 .. 32
    assert space.num_levels(32, 200) == 7  # sigma 1 .. 8, shorter side rules
    valid = space.valid_mask(32, 40, 7)
    for k in range(7):
        r = kernel_radius(2 ** (k / 2), 3.0)
        margins = [min(y, 31 - y, x, 39 - x) for y in range(32) for x in range(40)]
        assert valid[k].flatten().tolist() == [m >= r for m in margins]


def test_kernels_are_buffers_that_follow_the_module():
    space = ScaleSpace().double()
    names = dict(space.named_buffers())
    assert "kernels_0" in names and names["kernels_0"].shape == (3, 7)
    assert names["kernels_0"].dtype == torch.float64


def test_the_feature_space_works_under_autograd_and_its_state_is_its_settings():
    from ftorch import FeatureSpace
    from ftorch.space.evaluate import feature_values
    from ftorch.space.features import Conjunction, Disjunction
    from ftorch.space.generate import expand_geometric, random_edgel_pair, random_texel, random_texture

    tiny = torch.rand(1, 1, 12, 12, dtype=torch.float64, requires_grad=True)
    assert torch.autograd.gradcheck(lambda t: ScaleSpace()(t).responses, (tiny,))  # a linear map: exact gradients
    space = FeatureSpace()
    images = torch.rand(2, 1, 32, 32, dtype=torch.float64, generator=torch.Generator().manual_seed(0))
    plain = space(images)
    pixels = images.clone().requires_grad_()
    graph = space(pixels)
    # the same responses (to rounding: matrix products under autograd may block differently)
    assert torch.allclose(graph.responses.detach(), plain.responses, rtol=0, atol=1e-14)
    g = torch.Generator().manual_seed(0)
    t, p = random_texel(plain, 0, g), random_edgel_pair(plain, 0, g)
    features = [t, p, expand_geometric(p, plain, 0, g), random_texture(plain, 0, g), Conjunction(t, p), Disjunction(t, p)]
    values = feature_values(features, graph).values
    assert torch.allclose(values.detach(), feature_values(features, plain).values, rtol=0, atol=1e-12)
    (grad,) = torch.autograd.grad(values.sum(), pixels)
    assert grad.abs().sum() > 0 and torch.isfinite(grad).all()
    state = FeatureSpace(truncate=4.0, rel_threshold=0.05).state_dict()
    assert state["_extra_state"] == {"truncate": 4.0, "rel_threshold": 0.05}
    space.load_state_dict(state)
    assert space.scale_space.truncate == 4.0 and space.salient.rel_threshold == 0.05
