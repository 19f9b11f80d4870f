"""Example 3.5: a texel is found again across rotation and scaling, thanks to steering (eq. 3.13)."""
import cv2
import numpy as np
import pytest
import torch

from ftorch import FeatureSpace
from ftorch.space.steering import steer


def cosine(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return torch.nn.functional.cosine_similarity(a[None], b, dim=-1).clamp_min(0)


@pytest.mark.parametrize("angle", [30, 60, 90])
def test_texel_found_again_in_rotated_and_scaled_image(scene, angle):
    space = FeatureSpace()
    image = scene.astype(np.float64)
    original = space(torch.from_numpy(image))
    texels = original.texel_mask()[0] & (original.sigma[0] >= 2.5)
    # the strongest anisotropic texel: one whose descriptor changes under rotation
    candidates = texels.nonzero()[:, 0]
    strongest = candidates[original.strength[0, candidates].argsort(descending=True)[:10]]
    turned = steer(original.descriptors[0, strongest], torch.full((len(strongest),), torch.pi / 2, dtype=torch.float64))
    self_match = torch.nn.functional.cosine_similarity(original.descriptors[0, strongest], turned, dim=-1)
    p = int(strongest[self_match.argmin()])

    warp = cv2.getRotationMatrix2D((63.5, 63.5), angle, 0.7)
    moved = cv2.warpAffine(image, warp, (128, 128), flags=cv2.INTER_CUBIC, borderMode=cv2.BORDER_REFLECT)
    target = space(torch.from_numpy(moved))
    x, y = warp @ np.array([float(original.x[0, p]), float(original.y[0, p]), 1.0])
    near = target.texel_mask()[0] & (torch.hypot(target.x[0] - x, target.y[0] - y) <= 2.0)
    assert near.any(), "no texel near the corresponding point"
    normalised = cosine(original.canonical[0, p], target.canonical[0, near])
    best = int(normalised.argmax())
    unnormalised = cosine(original.descriptors[0, p], target.descriptors[0, near])[best]
    assert float(normalised[best]) >= 0.95
    assert float(normalised[best]) > float(unnormalised)
    ratio = float(target.sigma[0, near][best] / original.sigma[0, p])
    assert 0.5 - 1e-9 <= ratio <= 1 + 1e-9  # within one half-octave level of the true 0.7
