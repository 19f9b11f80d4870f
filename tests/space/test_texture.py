"""The statistical texture primitive (7.2.1): histograms against scipy's Gaussian filter, values
against a brute-force maximum, generation, the records of mixed sizes, JSON, packing and drawing (a
learner that needs it: tests/recognition/test_texture_learning.py)."""
import json

import numpy as np
import pytest
import torch
from scipy.ndimage import gaussian_filter1d

from ftorch import FeatureSpace
from ftorch.errors import InputError
from ftorch.recognition.bayes import ClassNetwork
from ftorch.recognition.candidates import CandidateGenerator, Method
from ftorch.recognition.packing import pack, unpack
from ftorch.recognition.settings import LearnerSettings
from ftorch.space.draw import draw_features
from ftorch.space.evaluate import feature_values, values_only
from ftorch.space.features import Conjunction, Feature, Texel, Texture
from ftorch.space.generate import random_edgel_pair, random_texel, random_texture
from ftorch.space.record import ImageRecords
from ftorch.space.texture import BINS, FIRST_LEVEL, level_sigma, memberships
from tests.conftest import random_image


@pytest.fixture(scope="module")
def images():
    return [random_image(48, 40, seed=31), random_image(48, 40, seed=32), random_image(36, 44, seed=33)]  # float64


@pytest.fixture(scope="module")
def records(images):
    return FeatureSpace().records(images)


def test_memberships_are_a_partition_of_unity_linear_between_bin_centres():
    centres = (np.arange(BINS) + 0.5) / BINS
    values = torch.tensor([[[0.0, centres[3], (centres[3] + centres[4]) / 2, 0.25 * centres[1] + 0.75 * centres[2], 1.0]]],
                          dtype=torch.float64)
    m = memberships(values)[0, :, 0].T  # (5 pixels, BINS)
    assert torch.allclose(m.sum(1), torch.ones(5, dtype=torch.float64))
    expected = np.zeros((5, BINS))
    expected[0, 0] = expected[1, 3] = expected[4, BINS - 1] = 1
    expected[2, 3] = expected[2, 4] = 0.5
    expected[3, 1], expected[3, 2] = 0.25, 0.75
    assert np.allclose(m.numpy(), expected, atol=1e-12)


def brute_histograms(image: np.ndarray, sigma: float) -> np.ndarray:
    """(H, W, BINS): sqrt of each soft bin's membership blurred by scipy's Gaussian (reflect)."""
    member = memberships(torch.from_numpy(image)[None])[0].numpy()
    out = np.stack([gaussian_filter1d(gaussian_filter1d(m, sigma, 0, mode="reflect", truncate=3.0), sigma, 1,
                                      mode="reflect", truncate=3.0) for m in member], -1)
    return np.sqrt(np.clip(out, 0, None))


def test_grid_histograms_equal_scipys_gaussian_filter_where_the_kernel_fits(images, records):
    for n, image in enumerate(images):
        h, w = image.shape
        mask = records.grid_mask[n]
        levels = sorted(set(records.grid_level[n][mask].tolist()))
        assert levels[0] == FIRST_LEVEL and len(levels) >= 2
        for k in levels:
            sigma, radius = level_sigma(k), int(3 * level_sigma(k) + 0.5)
            at = (mask & (records.grid_level[n] == k)).nonzero()[:, 0]
            x, y = records.grid_x[n, at].long().numpy(), records.grid_y[n, at].long().numpy()
            assert x.min() >= radius and x.max() <= w - 1 - radius and y.min() >= radius and y.max() <= h - 1 - radius
            assert set(np.diff(np.unique(x))) <= {max(1, round(sigma))} and set(np.diff(np.unique(y))) <= {max(1, round(sigma))}
            brute = brute_histograms(image.numpy(), sigma)[y, x]
            assert np.allclose(records.histograms[n, at].numpy(), brute, atol=1e-10)
            assert np.allclose((brute**2).sum(1), 1, atol=1e-10)  # weights sum to one: unit vectors


def test_values_are_the_largest_bhattacharyya_coefficient_over_the_features_level(images, records):
    g = torch.Generator().manual_seed(0)
    features = [random_texture(records, n % 3, g) for n in range(9)]
    assert len({f.level for f in features}) >= 2
    found = feature_values(features, records)
    assert torch.equal(found.values, values_only(features, records))
    for i, f in enumerate(features):
        for n in range(3):
            at = (records.grid_mask[n] & (records.grid_level[n] == f.level)).nonzero()[:, 0]
            hist = records.histograms[n, at].numpy()
            coefficient = hist @ np.array(f.histogram) / np.linalg.norm(hist, axis=1) / np.linalg.norm(f.histogram)
            best = int(coefficient.argmax())
            assert found.values[i, n] == pytest.approx(coefficient[best], abs=1e-12)
            assert (float(found.x[i, n]), float(found.y[i, n])) == (float(records.grid_x[n, at[best]]),
                                                                     float(records.grid_y[n, at[best]]))
            assert float(found.sigma[i, n]) == f.sigma and float(found.theta[i, n]) == 0.0


def test_a_sampled_texture_has_value_one_at_its_point_and_mixed_sizes_equal_single_records(images, records):
    g = torch.Generator().manual_seed(1)
    for n in range(3):
        f = random_texture(records, n, g)
        assert feature_values([f], records).values[0, n] == pytest.approx(1.0, abs=1e-12)
    features = [random_texture(records, n, g) for n in (0, 2, 1, 2)]
    joined = values_only(features, records)
    alone = torch.cat([values_only(features, FeatureSpace().records([image])) for image in images], 1)
    assert torch.allclose(joined, alone, atol=1e-12)


def test_an_image_without_grid_points_gives_zero_and_no_location():
    space = FeatureSpace()
    small = space.records([random_image(14, 14, seed=3)])  # sigma 2's kernel (radius 6) fits at one pixel only
    big = space.records([random_image(64, 64, seed=4)])
    f = Texture(level_sigma(6), random_texture(big, 0, torch.Generator().manual_seed(0)).histogram) \
        if 6 in big.grid_level[0].tolist() else None
    assert f is not None
    found = feature_values([f], small)
    assert float(found.values[0, 0]) == 0.0 and np.isnan(float(found.x[0, 0]))


def test_json_packing_and_validation(records):
    f = random_texture(records, 0, torch.Generator().manual_seed(2))
    assert Feature.from_json(f.to_json()) == f and json.loads(f.to_json())["type"] == "texture"
    for sigma, hist in ((3.0, f.histogram), (1.0, f.histogram), (f.sigma, f.histogram[:-1]),
                        (f.sigma, (-1.0, *f.histogram[1:])), (f.sigma, (0.0,) * BINS), (True, f.histogram)):
        with pytest.raises(InputError):
            Texture(sigma, hist)
    net = ClassNetwork("a")
    texel = random_texel(records, 0, torch.Generator().manual_seed(0))
    for feature in (f, Conjunction(f, texel)):
        net.add_feature(feature, [], [], threshold=0.5)
    data = pack({"a": net})
    back = unpack(data, ["a"])["a"]
    rounded = Texture(f.sigma, np.float32(f.histogram).tolist())
    assert back.features[0] == rounded and back.features[1] == Conjunction(rounded, Texel(np.float32(texel.vector).tolist()))
    assert len(data) == 4 + (1 + 1 + 4 * BINS) + (1 + 15 * 4) + (1 + 2 * 2) + 4 + 2 + 2 * (2 + 4 + 1 + 4 * 2)


def test_drawing_marks_a_texture_where_it_is_strongest(images, records):
    f = random_texture(records, 1, torch.Generator().manual_seed(3))
    blank = draw_features(records, 1, images[1], [])
    drawn = draw_features(records, 1, images[1], [f], ids=[1], legend=True)
    assert drawn.shape[1] == blank.shape[1] and (drawn[: blank.shape[0]] != blank).any(-1).sum() > 50


def test_the_thesis_primitives_draw_exactly_as_the_two_kinds_always_did(records):
    """Method 2 with texel and edgel pair: a texel where rand < 1/2, as before the choice existed."""
    env_records = records[0]
    mine = CandidateGenerator(torch.Generator().manual_seed(5))
    old = torch.Generator().manual_seed(5)

    class One:
        def record(self, _):
            return env_records

    made = mine(Method.PRIMITIVE, 40, LearnerSettings.thesis(), {}, One(), [0], "a", frozenset(), [])
    expected = [random_texel(env_records, 0, old) if torch.rand(1, generator=old) < 0.5 else random_edgel_pair(env_records, 0, old)
                for _ in range(40)]
    assert made == [f for f in expected if f is not None]
    assert {type(f).__name__ for f in made} == {"Texel", "Geometric"}


def test_records_fields_follow_selection_and_device(records):
    part = records[torch.tensor([2, 0])]
    assert torch.equal(part.histograms, records.histograms[[2, 0]]) and torch.equal(part.grid_mask, records.grid_mask[[2, 0]])
    joined = ImageRecords.cat([records[0], records[2]])
    assert joined.grid_mask[1].sum() == records.grid_mask[2].sum()
    assert not joined.grid_mask[1, int(records.grid_mask[2].sum()):].any()
