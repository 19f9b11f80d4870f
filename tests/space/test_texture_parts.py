"""Texture parts of geometric compounds (3.5 with 7.2.1): the statistical texture placed relative to an
oriented part, so that "a smooth patch left of this corner" can be learned. Sampling from the grid
against its layout, values and locations against the slow oracle (ftorch.space.reference), invalid
placements, generation, refusals, JSON, packing, drawing and class networks (a learner that needs them:
tests/recognition/test_texture_learning.py)."""
import math

import numpy as np
import pytest
import torch

from ftorch import FeatureSpace
from ftorch.errors import InputError
from ftorch.recognition import candidates as candidates_module
from ftorch.recognition.bayes import ClassNetwork, compound_arcs
from ftorch.recognition.candidates import CandidateGenerator, Method
from ftorch.recognition.learner import DistinctiveFeatureLearner
from ftorch.recognition.packing import KINDS, pack, unpack
from ftorch.recognition.settings import LearnerSettings
from ftorch.space.draw import PALETTE, _centre, draw_features
from ftorch.space.evaluate import feature_values, values_only
from ftorch.space.features import Feature, Geometric, Part, Texel
from ftorch.space.generate import expand_geometric, random_edgel_pair, random_texel
from ftorch.space.primitives import PartKind
from ftorch.space.record import ImageRecords
from ftorch.space.reference import local_value_at, reference_values, texture_grid
from ftorch.space.sampling import SPAN_TOLERANCE, GridLayout, placements, sample_texture
from ftorch.space.texture import BINS, FIRST_LEVEL, TextureGrid, grid_step, level_sigma
from tests.conftest import random_image
from tests.training.test_tradeoff import rounded


@pytest.fixture(scope="module")
def images():
    return [random_image(48, 40, seed=71), random_image(36, 44, seed=72), random_image(48, 40, seed=73)]


@pytest.fixture(scope="module")
def records(images):
    """Three images of two sizes in one padded batch, float64."""
    return FeatureSpace().records(images)


def expanded(records, make, kinds: str, count: int, seed: int = 0) -> list[tuple[Geometric, int]]:
    """``count`` (compound, its image) whose parts are ``kinds``: a feature from ``make`` expanded, with
    texture parts allowed, while its parts begin those."""
    target = kinds.split("-")
    g = torch.Generator().manual_seed(seed)
    found = []
    for attempt in range(400):
        n = attempt % len(records)
        feature = make(records, n, g)
        while feature is not None and len(feature.parts) < len(target) and \
                [str(p.kind) for p in feature.parts] == target[: len(feature.parts)]:
            feature = expand_geometric(feature, records, n, g, texture=True)
        if feature is not None and [str(p.kind) for p in feature.parts] == target:
            found.append((feature, n))
            if len(found) == count:
                return found
    raise AssertionError(f"no {count} {kinds} compounds drawn")


def hand_made(records, count: int, seed: int) -> list[Geometric]:
    """A texel of image 0 and a texture part at random attitudes, its histogram scaled (only its
    direction counts): many placements fall off the grid or between levels, some on levels no image has."""
    rng = np.random.default_rng(seed)
    points = records.texel_mask()[0].nonzero()[:, 0].tolist()
    out = []
    for _ in range(count):
        p = int(rng.choice(points))
        histogram = (rng.uniform(0.2, 5) * records.histograms[int(rng.integers(len(records))), int(rng.integers(20))]).tolist()
        out.append(Geometric((Part("texel", records.canonical[0, p].tolist()),
                              Part("texture", histogram, rng.uniform(-4, 4), 0.0, rng.uniform(0, 12), rng.uniform(0.4, 6)))))
    return out


def test_the_grid_layout_is_the_texture_grids_in_joined_and_selected_records(records):
    """Per image and level: each level's first point in the image's grid row, its first row and column,
    step and counts, as TextureGrid lays them out for that image's size; kept through cat and selection,
    cached once per records object; sampling at a grid point gives its histogram exactly."""
    for batch in (records, records[torch.tensor([1, 0])], ImageRecords.cat([records[1], records[2]])):
        layout = GridLayout.of(batch)
        assert GridLayout.of(batch) is layout
        for n in range(len(batch)):
            height, width = batch.sizes[n].tolist()
            start, seen = 0, set()
            for k, rows, cols in TextureGrid().points(height, width, int(batch.levels[n])):
                assert (int(layout.offset[n, k]), float(layout.x0[n, k]), float(layout.y0[n, k])) == (start, cols[0], rows[0])
                assert (int(layout.columns[n, k]), int(layout.rows[n, k]), float(layout.step[k])) == (len(cols), len(rows),
                                                                                                         grid_step(k))
                start += len(rows) * len(cols)
                seen.add(k)
            assert all(int(layout.columns[n, k]) == 0 for k in range(layout.columns.shape[1]) if k not in seen)
            q = batch.grid_mask[n].nonzero()[:, 0]
            sigma = level_sigma(1) ** batch.grid_level[n, q].to(batch.dtype)
            values, valid = sample_texture(batch, torch.tensor([n]), batch.grid_x[n, q], batch.grid_y[n, q], sigma)
            assert bool(valid.all()) and torch.equal(values, batch.histograms[n, q])


def test_sampling_is_valid_within_the_span_of_an_existing_level_only():
    """Off the span (beyond SPAN_TOLERANCE steps), below FIRST_LEVEL, on a level the image has no
    grid at (though another image of the batch has) and beyond its levels: invalid. Within the
    tolerance: the edge's vector. Half-way between four grid points: their mean."""
    records = FeatureSpace().records([random_image(30, 30, seed=74), random_image(36, 44, seed=75)])
    layout = GridLayout.of(records)
    assert int(layout.columns[0, 5]) == 0 < int(layout.columns[1, 5]) and int(records.levels[0]) == 6
    n, k = 1, 3
    x0, y0, step = float(layout.x0[n, k]), float(layout.y0[n, k]), float(layout.step[k])
    last_x = x0 + (int(layout.columns[n, k]) - 1) * step
    samples = [  # (image, x, y, level, valid)
        (n, x0 + 0.5 * step, y0 + 0.5 * step, k, True), (n, last_x + 0.3 * SPAN_TOLERANCE * step, y0 + 0.5 * step, k, True),
        (n, last_x + 2 * SPAN_TOLERANCE * step, y0, k, False), (n, x0 - 0.5 * step, y0, k, False),
        (n, x0, y0, FIRST_LEVEL - 1, False), (0, float(layout.x0[1, 5]), float(layout.y0[1, 5]), 5, False),
        (1, float(layout.x0[1, 5]), float(layout.y0[1, 5]), 5, True), (0, x0, y0, 6, False)]
    image, x, y, level, expected = zip(*samples)
    sigma = torch.tensor([level_sigma(v) for v in level], dtype=records.dtype)
    values, valid = sample_texture(records, torch.tensor(image), torch.tensor(x, dtype=records.dtype),
                                   torch.tensor(y, dtype=records.dtype), sigma)
    assert valid.tolist() == list(expected)
    at, columns = int(layout.offset[n, k]), int(layout.columns[n, k])
    corners = records.histograms[n, [at, at + 1, at + columns, at + columns + 1]]
    torch.testing.assert_close(values[0], corners.mean(0), rtol=0, atol=1e-15)
    edge = records.histograms[n, [at + columns - 1, at + 2 * columns - 1]].mean(0)
    torch.testing.assert_close(values[1], edge, rtol=0, atol=1e-15)


def test_values_and_locations_equal_the_reference_oracle(records):
    """Compounds with texture parts (texel-texture, edgel-edgel-texture, texel-texture-edgel, drawn by
    expansion, and texel-texture at random attitudes) over three images of two sizes: the oriented
    parts' cosine (eq. 3.13) times each texture part's Bhattacharyya coefficient, maximised over the
    reference points whose parts are all valid (eq. 3.14), as the per-point loop computes it."""
    features = [f for kinds, make in (("texel-texture", random_texel), ("edgel-edgel-texture", random_edgel_pair),
                                      ("texel-texture-edgel", random_texel))
                for f, _ in expanded(records, make, kinds, 3)] + hand_made(records, 12, seed=0)
    found = feature_values(features, records)
    oracle = reference_values(features, records)
    np.testing.assert_allclose(found.values.numpy(), oracle, rtol=0, atol=1e-9)
    assert torch.equal(values_only(features, records), found.values)
    assert (oracle[9:] == 0).any() and (oracle[9:] > 0.5).any()  # some random placements leave every grid
    pyramids = [records[n].responses[0, : int(records.levels[n])].double().numpy() for n in range(len(records))]
    grids = [texture_grid(records, n) for n in range(len(records))]
    for i, feature in enumerate(features):
        want = PartKind.EDGEL.mask(records) if feature.parts[0].kind == "edgel" else PartKind.TEXEL.mask(records)
        for n in range(len(records)):
            at = {}
            for p in want[n].nonzero()[:, 0].tolist():
                point = tuple(float(t[n, p]) for t in (records.x, records.y, records.sigma, records.theta))
                at[point] = local_value_at(feature, pyramids[n], *point, grids[n])
            located = tuple(float(t[i, n]) for t in (found.x, found.y, found.sigma, found.theta))
            if all(v is None for v in at.values()):
                assert math.isnan(located[0]) and float(found.values[i, n]) == 0
            else:  # a point the oracle finds valid, whose value is the maximum
                assert at[located] is not None and at[located] == pytest.approx(oracle[i, n], abs=1e-9)


def test_a_texture_part_off_the_grid_or_its_levels_makes_the_point_invalid(records):
    """Placed beyond every image, at a tenth of the reference point's sigma (below FIRST_LEVEL) or 100
    times it (beyond the levels): no
    reference point is valid, so the value is 0 and there is no location, whatever the oriented part gives."""
    p = int(records.texel_mask()[0].nonzero()[0, 0])
    head = Part("texel", records.canonical[0, p].tolist())
    histogram = records.histograms[0, 0].tolist()
    features = [Geometric((head, Part("texture", histogram, 0.0, 0.0, 1000.0, 1.0))),
                Geometric((head, Part("texture", histogram, 0.0, 0.0, 0.0, 0.1))),
                Geometric((head, Part("texture", histogram, 0.0, 0.0, 0.0, 100.0)))]
    found = feature_values(features + [Texel(head.vector)], records)
    assert bool((found.values[:3] == 0).all()) and bool(found.x[:3].isnan().all()) and bool(found.theta[:3].isnan().all())
    assert float(found.values[3, 0]) == pytest.approx(1.0)
    assert (reference_values(features, records) == 0).all()


@pytest.mark.parametrize("dtype", [torch.float64, torch.float32])
def test_an_expansion_draws_its_kind_first_and_a_texture_part_has_value_one_on_its_image(images, dtype):
    """With texture, a random number < 1/2 draws a texture grid point, else the salient point that the
    call without texture draws from the rest of the stream; without it the draws are exactly those of a
    call that omits it (learners with the default primitives are unchanged). A texture part has
    dtheta 0 and its compound value 1 (to 1e-5) on its sample image, in float32 too."""
    records = FeatureSpace().records([image.to(dtype) for image in images])
    kinds = set()
    for seed in range(24):
        n = seed % len(records)
        base = random_texel(records, n, torch.Generator().manual_seed(100 + seed))
        if seed % 3 == 2:  # a texel-texture or texel-texel/edgel compound
            base = expand_geometric(base, records, n, torch.Generator().manual_seed(200 + seed), texture=True) or base
        plain, omitted = torch.Generator().manual_seed(seed), torch.Generator().manual_seed(seed)
        without = expand_geometric(base, records, n, plain, texture=False)
        assert without == expand_geometric(base, records, n, omitted) and torch.equal(plain.get_state(), omitted.get_state())
        textured, rest = torch.Generator().manual_seed(seed), torch.Generator().manual_seed(seed)
        made = expand_geometric(base, records, n, textured, texture=True)
        if float(torch.rand(1, generator=rest)) >= 0.5:
            assert made == expand_geometric(base, records, n, rest)
        elif made is not None:
            last = made.parts[-1]
            assert last.kind is PartKind.TEXTURE and last.dtheta == 0 and made.parts[:-1] == base.parts
            assert float(values_only([made], records)[0, n]) == pytest.approx(1.0, abs=1e-5)
        kinds.add(made.parts[-1].kind if made is not None else None)
    assert {PartKind.TEXTURE, PartKind.TEXEL, PartKind.EDGEL} <= kinds


def test_the_candidate_generator_allows_texture_parts_only_where_asked(records, monkeypatch):
    calls = []
    monkeypatch.setattr(candidates_module, "expand_geometric", lambda *a, **k: calls.append(k["texture"]))

    class One:
        def record(self, _):
            return records[0]
    texel = random_texel(records, 0, torch.Generator().manual_seed(0))
    for primitives, parts in (("texel,edgel", False), ("texel,edgel,texture", False), ("texel,edgel", True),
                              ("texel,edgel,texture", True)):
        calls.clear()
        CandidateGenerator(torch.Generator().manual_seed(0))(
            Method.EXPANSION, 3, LearnerSettings.thesis(primitives=primitives, texture_parts=parts), {}, One(), [0], "a",
            frozenset(), [texel])
        assert calls == [parts] * 3
    learner = DistinctiveFeatureLearner()
    assert not learner.settings.texture_parts and learner.set_params(texture_parts=True).settings.texture_parts


def test_refusals(records):
    """No texture first (nothing to place the next part from), no orientation of its own (dtheta 0), a
    square-rooted histogram of BINS finite numbers >= 0, not all zero; no salient points or slots."""
    histogram = records.histograms[0, 0].tolist()
    texel = Part("texel", records.canonical[0, int(records.texel_mask()[0].nonzero()[0, 0])].tolist())
    texture = Part("texture", histogram, 0.5, 0.0, 3.0, 1.5)
    assert Geometric((texel, texture)).describe() == "geometric: texel-texture"
    with pytest.raises(InputError, match="first part"):
        Geometric((texture, texel))
    with pytest.raises(InputError, match="first part"):
        Feature.from_dict({"type": "geometric", "parts": [texture.to_dict(), texel.to_dict()]})
    with pytest.raises(InputError, match="dtheta must be 0"):
        Part("texture", histogram, 0.5, 0.1, 3.0, 1.5)
    for bad, message in ((histogram[:-1], "8 numbers"), ([-0.1, *histogram[1:]], "negative"), ([0.0] * BINS, "all zeros"),
                         ([math.nan, *histogram[1:]], "NaN")):
        with pytest.raises(InputError, match=message):
            Part("texture", bad)
    with pytest.raises(InputError, match="'texture'"):
        Part("colour", histogram)
    assert PartKind.TEXTURE.size == BINS and PartKind.of_point(1) is PartKind.TEXEL
    for attribute in ("codes", "slots"):
        with pytest.raises(ValueError, match="no salient points"):
            getattr(PartKind.TEXTURE, attribute)


def test_json_round_trip_is_exact(records):
    (feature, _), = expanded(records, random_texel, "texel-texture-edgel", 1)
    again = Feature.from_json(feature.to_json())
    assert again == feature and again.to_json() == feature.to_json() and hash(again) == hash(feature)
    assert feature.to_dict()["parts"][1]["kind"] == "texture" and feature.to_dict()["parts"][1]["dtheta"] == 0.0


def test_packing_round_trip_and_byte_count(records):
    """Kind code 2 and BINS float32 per texture part; unpacking gives the float32 features, which pack
    to the same bytes; a kind code beyond KINDS is refused."""
    assert KINDS.index(PartKind.TEXTURE) == 2
    (three, _), = expanded(records, random_texel, "texel-texture-edgel", 1)
    two = Geometric(three.parts[:2])
    net = ClassNetwork.of("a", [two, three], [[], [two]], [0.5, 0.75], [0.5, 0.5],
                          [np.array([[0.7, 0.3], [0.2, 0.8]]), np.full((2, 2, 2), 0.5)])
    data = pack({"a": net})
    back = unpack(data, ["a"])["a"]
    assert back.features == (rounded(two), rounded(three)) and pack({"a": back}) == data

    def size(f):
        return 2 + sum(1 + 4 * len(p.vector) + 16 * (k > 0) for k, p in enumerate(f.parts))
    assert len(data) == 4 + size(two) + size(three) + 4 + 2 + (2 + 4 + 1 + 4 * 2) + (2 + 4 + 1 + 2 + 4 * 4)
    assert size(two) == 2 + (1 + 60) + (1 + 4 * BINS + 16)
    kind = data.index(bytes([2]) + np.float32(three.parts[1].vector).tobytes())
    with pytest.raises(ValueError, match="part kind code 3"):
        unpack(data[:kind] + bytes([3]) + data[kind + 1 :], ["a"])


def test_drawing_rings_the_texture_part_where_it_is_placed(images, records):
    """A dashed circle of radius 2 sigma, in the feature's colour, around the placed texture part."""
    for feature, n in expanded(records, random_texel, "texel-texture", 3, seed=5):
        found = feature_values([feature], records[n])
        start = tuple(torch.tensor(float(t[0, 0]), dtype=torch.float64) for t in (found.x, found.y, found.sigma, found.theta))
        x, y, sigma, _ = (float(v) for v in list(placements(start, feature.attitudes()))[-1])
        plain = draw_features(records, n, images[n], [])
        drawn = draw_features(records, n, images[n], [feature])
        zoom = plain.shape[1] / int(records.sizes[n, 1])
        (cx, cy), r = _centre(x, y, zoom), 2 * sigma * zoom
        ring = [(round(cy + r * math.sin(t)), round(cx + r * math.cos(t))) for t in np.linspace(0, 2 * np.pi, 96, endpoint=False)]
        ring = [p for p in ring if 0 <= p[0] < plain.shape[0] and 0 <= p[1] < plain.shape[1]]
        assert len(ring) > 24
        change = np.array([drawn[p].astype(int) - plain[p] for p in ring])
        towards = np.array(PALETTE[0]) - np.array([plain[p] for p in ring])
        assert ((np.abs(change).sum(1) > 0) & ((change * towards).sum(1) > 0)).mean() > 0.35  # dashes: about half


def test_a_network_holds_a_compound_with_a_texture_part_and_exports_through_pgmpy(records):
    (three, _), = expanded(records, random_texel, "texel-texture-edgel", 1)
    two, texel = Geometric(three.parts[:2]), Texel(three.parts[0].vector)
    assert three.components() == [two, texel]
    net = ClassNetwork("corner")
    for feature in (texel, two, three):
        net.add_feature(feature, *compound_arcs(feature, net.features))
    assert net.parents[two] == (three,) and set(net.parents[texel]) == {two, three}
    net.validate()
    net.to_pgmpy().check_model()
    assert "f1_geometric_texel_texture" in net.to_bif() and "f2_geometric_texel_texture_edgel" in net.to_bif()
