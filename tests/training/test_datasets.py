"""Data sets of the recognition protocol: COIL folders, class folders, the Plym-like renderer, folds."""
import shutil

import cv2
import numpy as np
import pytest
import torch

from ftorch.errors import InputError
from ftorch.images import load_image
from training.data.datasets import coil_task, folder_task, load_task, plym_task
from training.data.plym import OBJECTS, VIEWS, render, solid


def test_coil_task_takes_consecutive_views_and_alternates_folds(coil_dir):
    task = coil_task(coil_dir, classes=6, views=20)
    assert len(task.images) == 120 and task.classes() == [f"obj{k}" for k in range(1, 7)]
    assert task.names[:3] == ["obj1__0", "obj1__1", "obj1__2"]
    train, test = task.fold(1)
    assert [task.names[i] for i in train[:3]] == ["obj1__0", "obj1__2", "obj1__4"]
    assert [task.names[i] for i in test[:2]] == ["obj1__1", "obj1__3"]
    assert task.fold(2) == (test, train)


def test_coil_files_are_found_in_the_original_nested_layout_at_any_size(tmp_path):
    nested = tmp_path / "coil-20" / "coil-20-proc"
    nested.mkdir(parents=True)
    rng = np.random.default_rng(0)
    for k in (1, 2):
        for v in range(4):
            cv2.imwrite(str(nested / f"obj{k}__{v}.png"), (rng.random((128, 128)) * 255).astype(np.uint8))
    task = coil_task(tmp_path, classes=2, views=4)
    assert len(task.images) == 8 and task.images[0].name == "obj1__0.png"
    with pytest.raises(InputError, match=r"obj3__0.png not found"):
        coil_task(tmp_path, classes=3, views=4)


def test_coil_size_area_averages_to_the_shared_32_pixel_images(coil_dir):
    full = coil_dir.parent / "coil-20-128"
    if not full.is_dir():
        pytest.skip(f"COIL data (../shared/data/coil-20-128) not found at {full}")
    reduced = coil_task(full, classes=2, views=3, size=32)
    stored = coil_task(coil_dir, classes=2, views=3)
    for image, path in zip(reduced.images, stored.images):
        assert image.shape == (32, 32)
        # coil-20-32 holds the 4x4 block means rounded to 8 bits
        assert float((image - load_image(path)).abs().max()) <= 0.5 / 255 + 1e-6
    assert load_task("coil", full, 2, 3, size=128).images[0].shape == (128, 128)
    with pytest.raises(InputError, match="can only reduce"):
        coil_task(coil_dir, classes=2, views=2, size=64)
    with pytest.raises(InputError, match="at least 9 pixels"):
        coil_task(coil_dir, classes=2, views=2, size=0)


def test_folder_task_and_its_errors(tmp_path):
    for label in ("apple", "pear"):
        (tmp_path / label).mkdir()
        for j in range(3):
            cv2.imwrite(str(tmp_path / label / f"{j}.png"), np.full((16, 16), 40 * j, np.uint8))
    (tmp_path / "apple" / "notes.txt").write_text("not an image")
    task = folder_task(tmp_path)
    assert task.labels == ["apple"] * 3 + ["pear"] * 3 and task.positions == [0, 1, 2] * 2
    with pytest.raises(InputError, match="no such folder"):
        folder_task(tmp_path / "missing")
    shutil.rmtree(tmp_path / "pear")
    with pytest.raises(InputError, match="at least two class folders"):
        folder_task(tmp_path)
    with pytest.raises(InputError, match="needs --data"):
        load_task("coil", None)


def test_plym_task_has_eight_solids_with_fifteen_views_and_is_seeded(rendered_afresh):
    a, b, c = plym_task(size=32, seed=1), plym_task(size=32, seed=1), plym_task(size=32, seed=2)
    assert a.classes() == list(OBJECTS) and len(a.images) == 8 * 15 == len(VIEWS) * len(OBJECTS)
    assert all(torch.equal(x, y) for x, y in zip(a.images, b.images))
    difference = max(float((x - y).abs().max()) for x, y in zip(a.images, c.images))
    assert 0 < difference < 0.05  # seeds differ only in the faint sensor noise
    train, test = a.fold(1)
    assert len(train) == 8 * 8 and len(test) == 8 * 7


def test_plym_solids_are_distinct_and_views_turn_them():
    pictures = {name: render(name, VIEWS[5], 32) for name in OBJECTS}
    for i, x in enumerate(OBJECTS):
        assert 0.02 < float((pictures[x] != pictures[x][0, 0]).float().mean()) < 0.9  # object on background
        for y in OBJECTS[i + 1:]:
            # cyl6 and tub6 differ only by the cavity seen from above, as in the thesis
            assert float((pictures[x] - pictures[y]).abs().mean()) > 0.005, (x, y)
    assert float((render("cube", VIEWS[0], 32) - pictures["cube"]).abs().mean()) > 0.002


def test_signed_distances_of_simple_solids():
    p = torch.tensor([[0.0, 0.0, 0.0], [1.6, 0.0, 0.0], [0.0, 0.0, 0.7]], dtype=torch.float64)
    np.testing.assert_allclose(solid("cube", p).numpy(), [-0.6, 1.0, 0.1], atol=1e-12)
    hollow = solid("tub6", torch.tensor([[0.0, 0.0, 0.0], [0.0, 0.0, 0.6]], dtype=torch.float64))
    assert hollow[0] > 0 > hollow[1]  # the axis of the tube is empty, its wall is solid
