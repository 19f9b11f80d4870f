"""Feature values: batched evaluator against the per-point reference, invariances, Boolean rules."""
import math

import numpy as np
import pytest
import torch

from ftorch import FeatureSpace
from ftorch.space.evaluate import feature_values, local_values, values_only
from ftorch.space.features import Conjunction, Disjunction, Feature, Geometric, Part, Texel
from ftorch.space.generate import expand_geometric, random_edgel_pair, random_texel
from ftorch.space.reference import reference_values
from ftorch.space.sampling import sample_part
from tests.conftest import random_image


@pytest.fixture(scope="module")
def records():
    """Three images of two sizes in one padded batch, float64."""
    images = [random_image(48, 48, seed=11), random_image(64, 56, seed=12), random_image(48, 48, seed=13)]
    return FeatureSpace().records(images)


def sampled_features(records, seed: int) -> list[Feature]:
    g = torch.Generator().manual_seed(seed)
    texel = random_texel(records, 0, g)
    pair = random_edgel_pair(records, 1, g)
    three = expand_geometric(texel, records, 0, g)
    four = expand_geometric(expand_geometric(pair, records, 1, g), records, 1, g)
    nested = Disjunction(Conjunction(texel, four), Conjunction(Disjunction(pair, three), texel))
    return [texel, pair, three, four, nested]


def synthetic_features(seed: int) -> list[Feature]:
    """Random parameters and vectors, not taken from any image: exercises interpolation and edges."""
    rng = np.random.default_rng(seed)

    def part(kind, first=False):
        vec = rng.normal(size=15 if kind == "texel" else 2)
        if first:
            return Part(kind, vec)
        return Part(kind, vec, phi=rng.uniform(-4, 4), dtheta=rng.uniform(-4, 4), d=rng.uniform(0, 6),
                    dsigma=float(2 ** rng.uniform(-1.2, 1.2)))

    return [Texel(rng.normal(size=15)),
            Geometric((part("edgel", True), part("texel"))),
            Geometric((part("texel", True), part("edgel"), part("texel"))),
            Geometric((part("edgel", True), part("edgel"), part("texel"), part("edgel")))]


def test_batched_values_equal_the_per_point_reference(records):
    features = sampled_features(records, seed=0) + sampled_features(records, seed=1) + synthetic_features(2)
    batched = feature_values(features, records).values.numpy()
    np.testing.assert_allclose(batched, reference_values(features, records), rtol=0, atol=1e-9)


def test_values_alone_equal_feature_values_bit_for_bit(records):
    """The learners' path (no locations, invalid samples not zeroed) gives the very same values,
    synthetic features with many samples outside the images and Boolean compounds included."""
    features = sampled_features(records, seed=4) + synthetic_features(5) + synthetic_features(7)
    alone = values_only(features, records)
    assert torch.equal(alone, feature_values(features, records).values)
    assert torch.equal(local_values(features[1:2], records).values[0], alone[1])  # the edgel pair, on its own
    assert torch.equal(values_only([], records), feature_values([], records).values)
    empty = records[0]
    empty.mask = torch.zeros_like(empty.mask)
    assert bool((values_only(synthetic_features(6), empty) == 0).all())


def test_sampled_features_have_value_one_at_their_own_reference_point(records):
    g = torch.Generator().manual_seed(3)
    texel = random_texel(records, 2, g)
    features = [texel, random_edgel_pair(records, 2, g)]
    features.append(expand_geometric(features[1], records, 2, g))
    features.append(expand_geometric(features[2], records, 2, g))
    values = feature_values(features, records)
    np.testing.assert_allclose(values.values[:, 2].numpy(), 1.0, atol=1e-9)
    p = int(torch.nonzero((records.canonical[2] == torch.tensor(texel.vector, dtype=torch.float64)).all(1))[0, 0])
    assert (float(values.x[0, 2]), float(values.y[0, 2])) == (float(records.x[2, p]), float(records.y[2, p]))


def test_sampling_at_grid_points_returns_the_stored_responses_exactly(records):
    """Alg. 3.6 step 4 at integer positions and levels, the last row and column included; outside: zero, invalid."""
    n, height, width = 1, 64, 56
    levels = int(records.levels[n])
    responses = records.responses[n]
    xs = torch.tensor([0, width - 1, 0, width - 1, 17, width - 1, width - 0.5], dtype=torch.float64)
    ys = torch.tensor([0, 0, height - 1, height - 1, 23, 40, 3], dtype=torch.float64)
    for edgel, us in ((True, range(levels)), (False, range(1, levels - 1))):
        for u in us:
            sigma = torch.full_like(xs, 2.0 ** (u / 2))
            image = torch.full((len(xs),), n)
            sample, valid = sample_part(records, image, xs, ys, sigma, edgel)
            assert valid.tolist() == [True] * 6 + [False] and not sample[6].any()
            for j in range(6):
                x, y = int(xs[j]), int(ys[j])
                expected = responses[u, :2, y, x] if edgel else responses[u - 1 : u + 2, :, y, x].flatten()
                assert torch.equal(sample[j], expected)


def test_values_are_invariant_to_affine_intensity_changes():
    space = FeatureSpace()
    images = [random_image(56, 56, seed=21), random_image(56, 56, seed=22)]
    base = space.records(images)
    features = sampled_features(base, seed=4)
    changed = space.records([2.5 * im + 0.3 for im in images])
    assert torch.equal(changed.mask, base.mask) and torch.equal(changed.x, base.x)
    torch.testing.assert_close(feature_values(features, changed).values, feature_values(features, base).values,
                               rtol=0, atol=1e-9)


def test_boolean_compounds_are_product_and_max(records):
    texel, pair, three, four, _ = sampled_features(records, seed=5)
    values = feature_values([texel, four, Conjunction(texel, four), Disjunction(texel, four)], records)
    v = values.values
    torch.testing.assert_close(v[2], v[0] * v[1])
    torch.testing.assert_close(v[3], torch.maximum(v[0], v[1]))
    larger = torch.where(v[1] > v[0], values.x[1], values.x[0])
    torch.testing.assert_close(values.x[3], larger, equal_nan=True)


def test_images_without_applicable_points_give_zero_and_no_location(records):
    empty = records[0]
    empty.mask = torch.zeros_like(empty.mask)
    values = feature_values(synthetic_features(6), empty)
    assert bool((values.values == 0).all()) and bool(values.x.isnan().all())


def test_json_round_trip_is_exact_and_validated(records):
    for feature in sampled_features(records, seed=7) + synthetic_features(8):
        again = Feature.from_json(feature.to_json())
        assert again == feature and again.to_json() == feature.to_json()
    assert Texel([math.pi] * 15) != Texel([math.nextafter(math.pi, 4)] + [math.pi] * 14)


@pytest.mark.skipif(not torch.cuda.is_available(), reason="CUDA is not available on this machine")
def test_cuda_and_cpu_agree():
    images = [random_image(64, 64, seed=31, dtype=torch.float32), random_image(64, 64, seed=32, dtype=torch.float32)]
    cpu_records = FeatureSpace().records(images)
    gpu_records = FeatureSpace().cuda().records([im.cuda() for im in images])
    torch.testing.assert_close(gpu_records.responses.cpu(), cpu_records.responses, rtol=1e-4, atol=1e-5)
    features = sampled_features(cpu_records, seed=9)
    torch.testing.assert_close(feature_values(features, gpu_records).values.cpu(),
                               feature_values(features, cpu_records).values, rtol=1e-4, atol=1e-4)


def test_same_seed_gives_the_same_features_and_another_seed_differs(records):
    first, again = sampled_features(records, seed=40), sampled_features(records, seed=40)
    other = sampled_features(records, seed=41)
    assert [f.to_json() for f in first] == [f.to_json() for f in again]
    assert [f.to_json() for f in first] != [f.to_json() for f in other]


@pytest.mark.parametrize("dtype", [torch.float32, torch.float64])
def test_a_value_is_the_same_bits_whatever_shares_its_call_and_the_thread_count(dtype):
    """Random texels, edgel pairs, textures, geometric expansions (some with texture parts) and Booleans on
    images of two sizes: each value computed alone (one feature, one image), all at once, in shuffled order
    and on one thread instead of two, bit for bit (the dot products of eq. 3.13 sum term by term)."""
    from ftorch.space.generate import random_texture

    images = [random_image(40 + 8 * (k % 2), 48, seed=30 + k, dtype=dtype) for k in range(6)]
    records = FeatureSpace().to(dtype=dtype).records(images)
    generator = torch.Generator().manual_seed(4)
    features: list[Feature] = []
    for n in range(len(images)):
        for sampler in (random_texel, random_edgel_pair, random_texture):
            made = sampler(records, n, generator)
            if made is not None:
                features.append(made)
    local = [f for f in features if isinstance(f, (Texel, Geometric))]
    for k in range(12):
        made = expand_geometric(local[k % len(local)], records, k % len(images), generator, texture=k % 2 == 1)
        if made is not None:
            features.append(made)
    features += [Conjunction(features[0], features[-1]), Disjunction(features[1], features[-2])]
    features = list(dict.fromkeys(features))
    threads = torch.get_num_threads()
    try:
        torch.set_num_threads(2)
        merged = values_only(features, records).numpy()
        alone = np.array([[values_only([f], records[torch.tensor([n])]).numpy()[0, 0] for n in range(len(images))]
                          for f in features])
        order = np.random.default_rng(0).permutation(len(features))
        shuffled = values_only([features[i] for i in order], records).numpy()[np.argsort(order)]
        torch.set_num_threads(1)
        one_thread = values_only(features, records).numpy()
    finally:
        torch.set_num_threads(threads)
    assert len(features) > 20 and (merged > 0).any()
    for other in (alone, shuffled, one_thread):
        assert np.array_equal(other.view(np.uint8), merged.view(np.uint8))
