import importlib.util
from pathlib import Path

import numpy as np
import pytest
import torch

from training.data import datasets, plym
from training.data.builtin import builtin_scene
from training.data.datasets import Task, plym_task

COIL = Path(__file__).resolve().parents[1].parent / "shared" / "data" / "coil-20-32"
needs_ray = pytest.mark.skipif(importlib.util.find_spec("ray") is None, reason="Ray is not installed (pip install -e \".[distributed]\")")


@pytest.fixture(scope="session", autouse=True)
def plym_views_rendered_once():
    """The Plym task's views rendered once per test run for each (size, seed): all 8 x 15 take 10 s at
    32 pixels and over a minute at 64, and rendering is deterministic, so every later request gets
    copies of the same views. Where a test replaces ``plym.render`` (to watch or forbid rendering) each
    call renders; ``rendered_afresh`` renders for one test."""
    rendered, genuine = {}, plym.render

    def plym_images(size: int = 64, seed: int = 0):
        if plym.render is not genuine:
            return plym.plym_images(size, seed)
        if (size, int(seed)) not in rendered:
            rendered[size, int(seed)] = plym.plym_images(size, seed)
        images, *layout = rendered[size, int(seed)]
        return [image.clone() for image in images], *(list(part) for part in layout)

    with pytest.MonkeyPatch.context() as patch:
        patch.setattr(datasets, "plym_images", plym_images)
        yield


@pytest.fixture
def rendered_afresh(monkeypatch):
    """Plym views rendered anew on every request (a test of the rendering itself)."""
    monkeypatch.setattr(datasets, "plym_images", plym.plym_images)


@pytest.fixture(scope="session")
def scene() -> np.ndarray:
    return builtin_scene(128)


@pytest.fixture(scope="session")
def small_task() -> Task:
    """Four Plym solids at 48 pixels (the folds of tests/training/test_protocol.py and the end-to-end tests)."""
    full = plym_task(size=48, seed=0)
    keep = [i for i, label in enumerate(full.labels) if label in ("con6", "cube", "cycu", "cyl3")]
    return Task("plym4", *([getattr(full, k)[i] for i in keep] for k in ("images", "labels", "names", "positions")))


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
