import importlib.util
from pathlib import Path

import numpy as np
import pytest
import torch

from training.data.builtin import builtin_scene

COIL = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "coil-20-32"
needs_ray = pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="Ray is not installed (pip install -e \".[distributed]\")")


@pytest.fixture(scope="session")
def scene() -> np.ndarray:
    return builtin_scene(128)


@pytest.fixture(scope="session")
def coil_dir() -> Path:
    if not COIL.is_dir():
        pytest.skip(f"COIL data (../shared/data/coil-20-32) not found at {COIL}")
    return COIL


def random_image(height: int, width: int, seed: int, dtype=torch.float64) -> torch.Tensor:
    """Smoothed random texture: structure at several scales, deterministic."""
    g = torch.Generator().manual_seed(seed)
    noise = torch.rand(1, 1, height, width, generator=g, dtype=dtype)
    coarse = torch.nn.functional.interpolate(torch.rand(1, 1, height // 8, width // 8, generator=g, dtype=dtype),
                                             size=(height, width), mode="bicubic", align_corners=False)
    return (0.3 * noise + coarse)[0, 0]
