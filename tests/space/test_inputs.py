"""Bad input gets one precise InputError naming the input; good input follows documented rules."""
import numpy as np
import pytest
import torch

from ftorch import FeatureSpace, InputError, ScaleSpace, as_image_batch, load_image
from ftorch.space.features import Feature, Geometric, Part, Texel


def test_conversion_rules():
    grey = np.full((20, 30), 255, np.uint8)
    assert as_image_batch(grey).shape == (1, 1, 20, 30) and float(as_image_batch(grey).max()) == 1.0
    assert float(as_image_batch(np.full((2, 20, 30), 65535, np.uint16)).max()) == 1.0
    assert as_image_batch(torch.zeros(4, 20, 30, dtype=torch.float16)).dtype == torch.float32
    assert as_image_batch(torch.zeros(4, 20, 30, dtype=torch.float64)).dtype == torch.float64
    rgb = torch.zeros(1, 3, 20, 30)
    rgb[:, 0] = 1.0  # pure red -> BT.601 luma 0.299
    assert torch.allclose(as_image_batch(rgb), torch.full((1, 1, 20, 30), 0.299))


@pytest.mark.parametrize(
    "images, words",
    [
        (torch.zeros(0, 10), "empty"),
        (torch.full((20, 20), float("nan")), "NaN"),
        (torch.zeros(1, 1, 1, 20, 20), "expected shape"),
        (torch.zeros(1, 2, 20, 20), "channels"),
        (torch.zeros(20, 20, dtype=torch.int32), "dtype"),
        (torch.zeros(20, 20, dtype=torch.bool), "dtype"),
        ([[0.0] * 20] * 20, "expected a torch.Tensor or numpy array"),
    ],
)
def test_bad_tensors_are_refused_with_one_clear_message(images, words):
    with pytest.raises(InputError, match=words) as info:
        ScaleSpace()(images)
    assert str(info.value).startswith("images:")


def test_images_too_small_for_the_scale_range():
    with pytest.raises(InputError, match=r"8x8 pixels is too small.*at least 9"):
        ScaleSpace()(torch.zeros(8, 8))
    assert ScaleSpace()(torch.rand(9, 9)).responses.shape[1] == 3


def test_files_that_are_missing_or_not_images(tmp_path):
    text = tmp_path / "notes.png"
    text.write_text("not an image")
    with pytest.raises(InputError, match="notes.png: not a readable image file"):
        load_image(text)
    with pytest.raises(InputError, match="no such file"):
        load_image(tmp_path / "missing.png")
    with pytest.raises(InputError, match=r"images\[1\]: image of 5x40 pixels is too small"):
        FeatureSpace().records([torch.rand(40, 40), torch.rand(5, 40)])
    with pytest.raises(InputError, match="sequence is empty"):
        FeatureSpace().records([])


def test_feature_descriptions_are_validated():
    with pytest.raises(InputError, match="15 numbers"):
        Texel([1.0] * 14)
    with pytest.raises(InputError, match="NaN"):
        Texel([float("nan")] + [1.0] * 14)
    with pytest.raises(InputError, match="at least two"):
        Geometric((Part("edgel", (1.0, 0.0)),))
    with pytest.raises(InputError, match="dsigma > 0"):
        Part("edgel", (1.0, 0.0), dsigma=0.0)
    with pytest.raises(InputError, match="not valid JSON"):
        Feature.from_json("{oops")
    with pytest.raises(InputError, match="unknown feature type"):
        Feature.from_json('{"type": "blob"}')
