"""Where a feature looks (ftorch.space.region, Within): a region bounds eq. 3.14's maximum to the
reference points inside it, in the image frame or the object frame; against brute force
(ftorch.space.reference: the per-point loop and the region test in scalar math), across batches,
shifted and scaled copies, JSON, packing, class networks, drawing and localize (3.6)."""
import math

import cv2
import numpy as np
import pytest
import torch

from ftorch import FeatureSpace
from ftorch.errors import InputError
from ftorch.recognition.bayes import ClassNetwork, compound_arcs
from ftorch.recognition.inference import recognize
from ftorch.recognition.packing import pack, unpack
from ftorch.space import Frame, Region, Within
from ftorch.space.draw import PALETTE, _centre, draw_features, feature_legend
from ftorch.space.evaluate import feature_values, values_only
from ftorch.space.features import Conjunction, Disjunction, Feature, Texel
from ftorch.space.generate import expand_geometric, localize, random_edgel_pair, random_texel, random_texture
from ftorch.space.primitives import PartKind
from ftorch.space.reference import local_value_at, reference_values, region_holds
from ftorch.space.region import frame_coordinates, inside, object_frames, pixel_ellipse
from tests.conftest import random_image
from tests.training.test_tradeoff import rounded


@pytest.fixture(scope="module")
def images():
    return [random_image(48, 48, seed=61), random_image(64, 56, seed=62), random_image(48, 48, seed=63)]


@pytest.fixture(scope="module")
def records(images):
    """Three images of two sizes in one padded batch, float64."""
    return FeatureSpace().records(images)


def coordinates(records, n: int, frame, x: float, y: float) -> tuple[float, float]:
    image = torch.tensor([n])
    u, v = frame_coordinates(records, frame, image, torch.tensor([x], dtype=records.dtype),
                             torch.tensor([y], dtype=records.dtype))
    return float(u[0]), float(v[0])


def points_of(records, n: int, kind: PartKind) -> list[int]:
    return kind.mask(records)[n].nonzero()[:, 0].tolist()


def texel_at(records, n: int, p: int) -> Texel:
    return Texel(records.canonical[n, p].tolist())


def regions_of(records) -> tuple[Region, Region, Region]:
    """Two overlapping discs on image 0 (image and object frame) and one in the object frame."""
    return (Region(Frame.IMAGE, 0.35, 0.4, 0.3), Region(Frame.OBJECT, 0.3, -0.2, 0.9),
            Region(Frame.OBJECT, -0.4, 0.5, 1.1))


def compositions(records) -> list[Feature]:
    """Within of a geometric compound, a texture, a conjunction; a disjunction of Withins; nested Withins."""
    g = torch.Generator().manual_seed(3)
    texel = random_texel(records, 0, g)
    pair = random_edgel_pair(records, 1, g)
    three = expand_geometric(expand_geometric(texel, records, 0, g), records, 0, g)
    texture = random_texture(records, 2, g)
    image, obj, other = regions_of(records)
    return [Within(three, image), Within(texture, obj), Within(Conjunction(texel, pair), other),
            Disjunction(Within(texel, image), Within(pair, other)), Within(Within(three, obj), image),
            Within(Disjunction(texture, Within(pair, obj)), image)]


def test_a_region_bounds_the_maximum_to_the_points_inside_it(records):
    """The best match excluded: the best value inside, as the brute-force loop finds it (each point's
    eq. 3.13 by hand, the region tested in scalar math), located at that point; one-point regions give
    that point's own cosine; a region holding no point gives 0 and no location."""
    texels = points_of(records, 0, PartKind.TEXEL)
    p = texels[0]
    texel = texel_at(records, 0, p)  # value 1 at p
    here = coordinates(records, 0, Frame.IMAGE, float(records.x[0, p]), float(records.y[0, p]))
    far = max(texels, key=lambda q: math.dist(here, coordinates(records, 0, Frame.IMAGE, float(records.x[0, q]),
                                                                    float(records.y[0, q]))))
    centre = coordinates(records, 0, Frame.IMAGE, float(records.x[0, far]), float(records.y[0, far]))
    region = Region(Frame.IMAGE, *centre, 0.5 * math.dist(here, centre))
    assert not region_holds(region, records, 0, float(records.x[0, p]), float(records.y[0, p]))
    bounded = Within(texel, region)
    found = feature_values([texel, bounded], records)
    assert float(found.values[0, 0]) == pytest.approx(1.0) and 0 < float(found.values[1, 0]) < 0.999
    np.testing.assert_allclose(found.values[1].numpy(), reference_values([bounded], records)[0], rtol=0, atol=1e-9)
    assert region_holds(region, records, 0, float(found.x[1, 0]), float(found.y[1, 0]))  # located inside
    assert torch.equal(values_only([texel, bounded], records), found.values)

    pyramid = records[0].responses[0, : int(records.levels[0])].double().numpy()
    for q in texels[1:6]:  # one-point regions: the point's own cosine, located there
        x, y = float(records.x[0, q]), float(records.y[0, q])
        one = Within(texel, Region(Frame.IMAGE, *coordinates(records, 0, Frame.IMAGE, x, y), 1e-9))
        at = feature_values([one], records[0])
        own = local_value_at(texel, pyramid, x, y, float(records.sigma[0, q]), float(records.theta[0, q]))
        assert float(at.values[0, 0]) == pytest.approx(own, abs=1e-12) and (float(at.x[0, 0]), float(at.y[0, 0])) == (x, y)

    nowhere = [Within(texel, Region(Frame.IMAGE, 3.0, 3.0, 0.5)), Within(texel, Region(Frame.OBJECT, 50.0, 0.0, 1.0))]
    empty = feature_values(nowhere, records)
    assert bool((empty.values == 0).all()) and bool(empty.x.isnan().all()) and bool(empty.theta.isnan().all())
    assert bool((values_only(nowhere, records) == 0).all())


def test_object_frames_are_the_lower_medians_and_missing_without_salient_points(records):
    frames = object_frames(records)
    for n in range(len(records)):
        xs, ys = records.x[n][records.mask[n]].tolist(), records.y[n][records.mask[n]].tolist()
        cx, cy = sorted(xs)[(len(xs) - 1) // 2], sorted(ys)[(len(ys) - 1) // 2]
        s = sorted(math.hypot(x - cx, y - cy) for x, y in zip(xs, ys))[(len(xs) - 1) // 2]
        assert frames[n].tolist() == pytest.approx([cx, cy, s], abs=1e-12)
    assert object_frames(records) is frames  # once per records object
    bare = records[1]
    bare.mask = torch.zeros_like(bare.mask)  # a fresh records object: nothing cached yet
    assert bool(object_frames(bare).isnan().all())
    texture = random_texture(records, 1, torch.Generator().manual_seed(0))
    values = values_only([texture, Within(texture, Region(Frame.OBJECT, 0.0, 0.0, 100.0)),
                          Within(texture, Region(Frame.IMAGE, 0.5, 0.5, 100.0))], bare)
    assert values[0, 0] == 1 and values[1, 0] == 0 and values[2, 0] == 1  # the grid is there, the object frame is not


def test_image_frame_regions_ignore_the_padding_of_a_batch():
    space = FeatureSpace()
    small, big = random_image(40, 36, seed=41), random_image(72, 64, seed=42)
    alone, batch = space.records([small]), space.records([small, big])
    mask = alone.mask[0]
    image = torch.zeros(int(mask.sum()), dtype=torch.long)
    here = frame_coordinates(alone, Frame.IMAGE, image, alone.x[0][mask], alone.y[0][mask])
    there = frame_coordinates(batch, Frame.IMAGE, image, batch.x[0][batch.mask[0]], batch.y[0][batch.mask[0]])
    assert all(torch.equal(a, b) for a, b in zip(here, there)) and float(here[0].max()) < 1  # the image's own size
    g = torch.Generator().manual_seed(1)
    features = [random_texel(alone, 0, g), random_edgel_pair(alone, 0, g), random_texture(alone, 0, g)]
    regions = [Region(Frame.IMAGE, 0.75, 0.75, 0.3), Region(Frame.IMAGE, 0.25, 0.6, 0.2)]
    bounded = [Within(f, r) for f in features for r in regions]
    one, joined = values_only(features + bounded, alone), values_only(features + bounded, batch)
    torch.testing.assert_close(joined[:, :1], one, rtol=0, atol=1e-12)
    assert (one[len(features):, 0] != one[[k // 2 for k in range(len(bounded))], 0]).any()  # the regions bite


def _object(side: int = 32) -> np.ndarray:
    """A textured, roughly round object on black."""
    texture = random_image(side, side, seed=51).numpy()
    yy, xx = np.mgrid[:side, :side]
    disc = np.clip((0.45 * side - np.hypot(xx - (side - 1) / 2, yy - 0.45 * (side - 1))) / 2, 0, 1)
    return (0.2 + 0.8 * texture / texture.max()) * disc


def _placed(patch: np.ndarray, side: int, at: tuple[int, int]) -> torch.Tensor:
    canvas = np.zeros((side, side))
    canvas[at[1] : at[1] + patch.shape[0], at[0] : at[0] + patch.shape[1]] = patch
    return torch.tensor(canvas)


SCALE_TOLERANCE = 0.03


def test_the_object_frame_follows_a_shifted_and_a_scaled_copy():
    """Features bounded to a disc in the object frame keep their values on the object shifted by
    (13, 9) on the same canvas (exactly: the same pixels around every point) and scaled by 2 with
    cv2.resize on a larger canvas elsewhere. The scaled copy's responses are resampled: a feature's
    cosine at the corresponding point drops by up to 0.017 on these 16 features (their best match
    anywhere, by up to 0.012), so SCALE_TOLERANCE = 0.03 holds it with margin. The same check with
    the same discs (on the first image) in the image frame loses up to the whole value."""
    patch = _object()
    scaled = cv2.resize(patch, (64, 64), interpolation=cv2.INTER_LINEAR)
    records = FeatureSpace().records([_placed(patch, 72, (14, 12)), _placed(patch, 72, (27, 21)),
                                      _placed(scaled, 128, (20, 44))])
    frames = object_frames(records)
    assert torch.equal(frames[1], frames[0] + torch.tensor([13.0, 9.0, 0.0], dtype=frames.dtype))
    assert frames[2, :2].tolist() == pytest.approx((2 * (frames[0, :2] - torch.tensor([14, 12])) +
                                                    torch.tensor([20, 44])).tolist(), abs=1.0)
    assert float(frames[2, 2] / frames[0, 2]) == pytest.approx(2, rel=0.05)
    features = []
    for seed in range(8):
        g = torch.Generator().manual_seed(seed)
        texel = random_texel(records, 0, g)
        features += [texel, expand_geometric(texel, records, 0, g)]

    def change(frame: Frame, radius: float) -> np.ndarray:
        bounded = [localize(f, records, 0, frame, radius) for f in features]
        values = values_only(bounded, records).numpy()
        assert (values[:, 0] == values_only(features, records).numpy()[:, 0]).all()  # localize keeps image 0's
        return np.abs(values[:, 1:] - values[:, :1]).max(0)  # (shifted, scaled)

    shifted, scaled = change(Frame.OBJECT, 0.5)
    assert shifted <= 1e-12 and scaled <= SCALE_TOLERANCE
    shifted, scaled = change(Frame.IMAGE, 0.5 * float(frames[0, 2]) / 72)  # the same discs on image 0
    assert shifted > SCALE_TOLERANCE and scaled > SCALE_TOLERANCE


def test_every_composition_round_trips_and_equals_brute_force(records):
    features = compositions(records)
    for feature in features:
        again = Feature.from_json(feature.to_json())
        assert again == feature and again.to_json() == feature.to_json() and hash(again) == hash(feature)
    assert features[0].to_dict()["region"] == {"frame": "image", "x": 0.35, "y": 0.4, "radius": 0.3}
    assert Within(Texel([0.5] * 15), Region("image", 0.31, 0.42, 0.25)).describe() == \
        "texel in image region (0.31, 0.42; r 0.25)"
    assert features[4].primitives == features[0].primitives == 3
    found = feature_values(features, records)
    np.testing.assert_allclose(found.values.numpy(), reference_values(features, records), rtol=0, atol=1e-9)
    assert torch.equal(values_only(features, records), found.values)
    unbounded = values_only([features[0].feature, features[1].feature, features[2].feature], records)
    assert (found.values[:3] < unbounded - 1e-6).any()  # the regions exclude better matches somewhere
    # nesting is an intersection, whatever the order; Within of a compound bounds each of its leaves
    three, (image, obj, _) = features[0].feature, regions_of(records)
    swapped = [Within(Within(three, image), obj), Within(Within(Within(three, obj), image), obj)]
    same = dict(rtol=0, atol=1e-12)  # another makeup of a group may round its products otherwise (as without regions)
    torch.testing.assert_close(values_only(swapped, records), found.values[[4, 4]], **same)
    texel, pair = features[2].feature.a, features[2].feature.b
    spread = values_only([Conjunction(Within(texel, features[2].region), Within(pair, features[2].region))], records)
    torch.testing.assert_close(spread[0], found.values[2], **same)
    # chunked with the smallest memory bound: the same numbers, bounded and unbounded side by side
    mixed = features + [three, features[1].feature]
    torch.testing.assert_close(values_only(mixed, records, max_elements=1), values_only(mixed, records), **same)


def test_values_without_regions_are_the_same_bits_beside_bounded_features(records):
    """Unbounded leaves are measured in the groups and by the code they always were: the same
    bits (locations included) with or without bounded features in the same call."""
    bounded = compositions(records)
    plain = [bounded[0].feature, bounded[1].feature, bounded[2].feature]
    alone = feature_values(plain, records)
    beside = feature_values(plain + bounded, records)
    for a, b in zip((alone.values, alone.x, alone.y, alone.sigma, alone.theta),
                    (beside.values, beside.x, beside.y, beside.sigma, beside.theta)):
        assert torch.equal(a.nan_to_num(-7), b[: len(plain)].nan_to_num(-7))


def test_packing_round_trip_recognizes_the_same(records):
    features = [rounded(f) for f in compositions(records)]
    rng = np.random.default_rng(0)

    def cpt(parents: int) -> np.ndarray:
        present = rng.uniform(0.05, 0.95, size=(2,) * (1 + parents))
        return np.stack([1 - present, present], axis=-1)
    inner = features[0].feature
    a = ClassNetwork.of("a", [inner, features[0], features[1], features[3]], [[], [], [], [features[0]]],
                        [0.5, 0.75, 0.625, 0.5], [0.5, 0.5], [cpt(0), cpt(0), cpt(0), cpt(1)])
    b = ClassNetwork.of("b", [features[2], features[4], features[5]], [[], [features[2]], []], [0.5, 0.5, 0.25],
                        [0.25, 0.75], [cpt(0), cpt(1), cpt(0)])
    data = pack({"a": a, "b": b})
    back = unpack(data, ["a", "b"])
    assert back["a"].features == a.features and back["b"].features == b.features
    assert pack(back) == data
    # the byte count: the table (each feature once, sub-features first) and the networks
    table = {}

    def add(f):
        for sub in f.subfeatures():
            add(sub)
        table.setdefault(f, len(table))
    for f in a.features + b.features:
        add(f)
    sizes = {"Texel": 1 + 60, "Geometric": None, "Texture": 1 + 1 + 32, "Conjunction": 5, "Disjunction": 5,
             "Within": 1 + 1 + 12 + 2}
    feature_bytes = sum(sizes[type(f).__name__] or 2 + sum(1 + 4 * len(p.vector) + 16 * (k > 0)
                                                           for k, p in enumerate(f.parts)) for f in table)
    networks = sum(4 + 2 + sum(2 + 4 + 1 + 2 * len(net.parents[f]) + 4 * 2 ** (1 + len(net.parents[f]))
                               for f in net.features) for net in (a, b))
    assert len(data) == 4 + feature_bytes + networks and int.from_bytes(data[:2], "little") == len(table)
    for n in range(len(records)):
        values = dict(zip(table, values_only(list(table), records[n])[:, 0].tolist()))
        mine, theirs = recognize({"a": a, "b": b}, values.__getitem__), recognize(back, values.__getitem__)
        assert mine.recognized == theirs.recognized and mine.queried == theirs.queried
        assert mine.posteriors == pytest.approx(theirs.posteriors, abs=1e-6)
    within = data.index(bytes([5]) + bytes([0]) + np.float32([0.35, 0.4, 0.3]).tobytes())
    with pytest.raises(ValueError, match="region frame code 2"):
        unpack(data[: within + 1] + bytes([2]) + data[within + 2 :], ["a", "b"])


def test_a_network_holds_a_feature_and_its_bounded_forms(records):
    features = compositions(records)
    within, inner = features[2], features[2].feature
    assert within.components() == [inner, Within(inner.a, within.region), Within(inner.b, within.region)]
    assert compound_arcs(within, [inner, inner.a]) == ([], [inner])  # it points to the feature it bounds
    assert compound_arcs(inner, [within]) == ([within], [])
    net = ClassNetwork("face")
    for feature in (inner, inner.a, Within(inner.a, within.region), within, features[3], features[4]):
        net.add_feature(feature, *compound_arcs(feature, net.features))
    assert net.parents[inner] == (within,) and net.parents[Within(inner.a, within.region)] == (within,)
    net.validate()
    net.to_pgmpy().check_model()
    assert "texel_in_object_region" in net.to_bif()


def _outline_pixels(records, n: int, region: Region, zoom: float) -> list[tuple[int, int]]:
    cx, cy, ax, ay = pixel_ellipse(region, records, n)
    (x0, y0), ax, ay = _centre(cx, cy, zoom), ax * zoom, ay * zoom
    angles = np.linspace(0, 2 * np.pi, 120, endpoint=False)
    return [(round(y0 + ay * math.sin(t)), round(x0 + ax * math.cos(t))) for t in angles]


def test_drawing_outlines_each_region_in_the_features_colour(images, records):
    features = compositions(records)
    image, obj, _ = regions_of(records)
    for n, feature, regions in ((1, features[0], [image]), (0, features[1], [obj]), (0, features[4], [obj, image]),
                                (1, features[3], [image])):
        blank = draw_features(records, n, images[n], [])
        drawn = draw_features(records, n, images[n], [feature], ids=[1])
        zoom = blank.shape[1] / int(records.sizes[n, 1])
        for region in regions:
            pixels = [(r, c) for r, c in _outline_pixels(records, n, region, zoom)
                      if 0 <= r < blank.shape[0] and 0 <= c < blank.shape[1]]
            assert len(pixels) > 30
            change = np.array([drawn[p].astype(int) - blank[p] for p in pixels])
            towards = np.array(PALETTE[0]) - np.array([blank[p] for p in pixels])
            coloured = (np.abs(change).sum(1) > 0) & ((change * towards).sum(1) > 0)
            assert coloured.mean() > 0.9  # the outline, in the feature's colour
    assert pixel_ellipse(image, records, 1)[2:] == (0.3 * 56, 0.3 * 64)  # an ellipse on a non-square image
    legend = feature_legend(features, range(len(features)), 300)
    assert legend.shape[1] == 300 and (legend < 255).any()


def test_localize_keeps_the_value_at_the_strongest_occurrence(records):
    g = torch.Generator().manual_seed(8)
    texel = random_texel(records, 1, g)
    features = [texel, expand_geometric(texel, records, 1, g), random_edgel_pair(records, 2, g),
                random_texture(records, 0, g)]
    for n in range(len(records)):
        located: dict = {}
        for frame, radius in ((Frame.IMAGE, 0.05), (Frame.OBJECT, 0.2), ("object", 1e-9)):
            bounded = [localize(f, records, n, frame, radius, located) for f in features]
            assert all(b is not None and b.feature == f and b.region.radius == radius for b, f in zip(bounded, features))
            values = values_only(features + bounded, records)
            assert torch.equal(values[len(features):, n], values[: len(features), n])
        assert set(located) == set(features)
    # a Within is narrowed: its outermost region replaced, centred at its best match inside it
    wide = Within(texel, Region(Frame.IMAGE, 0.3, 0.7, 0.4))
    found = feature_values([wide], records[0])
    narrow = localize(wide, records, 0, "image", 0.1)
    assert narrow.feature is texel and (narrow.region.x, narrow.region.y) == coordinates(
        records, 0, Frame.IMAGE, float(found.x[0, 0]), float(found.y[0, 0]))
    assert float(values_only([narrow], records[0])[0, 0]) >= float(found.values[0, 0])
    # no location, no object frame, bad input
    assert localize(Within(texel, Region(Frame.IMAGE, 4.0, 4.0, 0.1)), records, 0, "image", 0.1) is None
    bare = records[0]
    bare.mask = torch.zeros_like(bare.mask)
    assert localize(features[3], bare, 0, "object", 1.0) is None and localize(features[3], bare, 0, "image", 1.0)
    for frame, radius in (("sky", 0.1), ("image", 0.0), ("image", float("nan"))):
        with pytest.raises(InputError, match="region"):
            localize(texel, records, 0, frame, radius)


def test_regions_are_validated_hashable_values():
    region = Region("object", 1, -0.5, 2)
    assert region == Region(Frame.OBJECT, 1.0, -0.5, 2.0) and region.frame is Frame.OBJECT
    assert {region: 1}[Region.from_dict(region.to_dict())] == 1 and isinstance(region.x, float)
    for bad, message in (((("frame"), 0, 0, 1), "frame must be"), (("image", math.inf, 0, 1), "x must be a finite"),
                         (("image", 0, True, 1), "y must be"), (("image", 0, 0, -1), "radius must be > 0"),
                         (("image", 0, 0, "1"), "radius must be a finite")):
        with pytest.raises(InputError, match=message):
            Region(*bad)
    with pytest.raises(InputError, match="not a region description"):
        Region.from_dict({"frame": "image", "x": 0})
    with pytest.raises(InputError, match="bounds a Feature to a Region"):
        Within(Texel([1.0] * 15), {"frame": "image", "x": 0, "y": 0, "radius": 1})
    with pytest.raises(InputError, match="radius must be > 0"):
        Feature.from_dict({"type": "within", "feature": Texel([1.0] * 15).to_dict(),
                           "region": {"frame": "image", "x": 0, "y": 0, "radius": 0}})
    points = inside([Region("image", 0.5, 0.5, 0.25), Region("image", 0.5, 0.5, 0.2)], _OneImage(),
                    torch.zeros(3, dtype=torch.long), torch.tensor([4.5, 7.0, 9.5]), torch.tensor([4.5, 4.5, 4.5]))
    assert points.tolist() == [[True, True, False], [True, False, False]]  # u = 0.5, 0.75 (on the edge: inside), 1


class _OneImage:
    """The one field frame_coordinates reads in the image frame: one 10 x 10 image."""
    sizes = torch.tensor([[10, 10]])
