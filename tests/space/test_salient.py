"""Salient points (3.4.3) and primitive descriptors (3.4.1-3.4.2)."""
import math

import torch

from ftorch import BLOB, EDGEL, FeatureSpace, PartKind
from ftorch.images import contrast_normalized
from ftorch.space.kernels import kernel_radius
from ftorch.space.steering import steer
from tests.conftest import random_image


def test_strongest_blob_sits_at_the_centre_with_its_scale():
    size = 64
    y, x = torch.meshgrid(torch.arange(size, dtype=torch.float64), torch.arange(size, dtype=torch.float64), indexing="ij")
    image = torch.exp(-((x - 30) ** 2 + (y - 34) ** 2) / (2 * 4.0**2))
    records = FeatureSpace()(image)
    blobs = records.mask[0] & (records.kind[0] == BLOB)
    best = records.strength[0].masked_fill(~blobs, -1).argmax()
    assert (float(records.x[0, best]), float(records.y[0, best]), float(records.sigma[0, best])) == (30.0, 34.0, 4.0)


def test_step_edge_gives_a_thin_line_of_edgels_across_the_gradient():
    image = torch.zeros(64, 64, dtype=torch.float64)
    image[:, 32:] = 1.0
    records = FeatureSpace()(image)
    edgels = records.edgel_mask()[0]
    xs = records.x[0, edgels]
    assert len(xs) > 40 and set(xs.tolist()) <= {31.0, 32.0}
    # one edgel per row: non-maximum suppression leaves a thin line
    assert len(set(records.y[0, edgels].tolist())) == len(xs)
    assert torch.allclose(records.theta[0, edgels], torch.zeros(len(xs), dtype=torch.float64), atol=1e-9)


def test_no_point_where_its_kernel_leaves_the_image():
    image = random_image(72, 90, seed=5)
    records = FeatureSpace()(image)
    m = records.mask[0]
    x, y, level = records.x[0, m], records.y[0, m], records.level[0, m]
    margin = torch.minimum(torch.minimum(x, 89 - x), torch.minimum(y, 71 - y))
    radius = torch.tensor([kernel_radius(2 ** (k / 2), 3.0) for k in level.tolist()], dtype=margin.dtype)
    assert bool((margin >= radius).all())
    texel = m & (records.kind[0] != EDGEL)
    assert int(records.level[0, texel].min()) >= 1 and int(records.level[0, texel].max()) <= int(records.levels[0]) - 2


def test_texels_are_3d_maxima_and_descriptors_follow_the_layout():
    image = random_image(64, 64, seed=6)
    space = FeatureSpace()
    out = space.scale_space(contrast_normalized(image))  # records describe the image with its range in (1/2, 1]
    blob, corner, edge = out.scale_functions()
    records = space(image)
    for p in records.mask[0].nonzero()[:, 0].tolist():
        x, y, k, kind = int(records.x[0, p]), int(records.y[0, p]), int(records.level[0, p]), int(records.kind[0, p])
        raw = records.descriptors[0, p]
        if kind == EDGEL:
            assert torch.equal(raw[5:7], out.responses[0, k, :2, y, x]) and not raw[:5].any() and not raw[7:].any()
            assert math.isclose(float(records.canonical[0, p, 6]), 0.0, abs_tol=1e-12)
            continue
        f = (blob if kind == BLOB else corner)[0]
        neighbourhood = f[k - 1 : k + 2, max(y - 1, 0) : y + 2, max(x - 1, 0) : x + 2]
        assert float(f[k, y, x]) == float(neighbourhood.max())
        assert torch.equal(raw, out.responses[0, k - 1 : k + 2, :, y, x].flatten())
        # Chomat orientation: gradient direction at the scale maximising s_edge among fitting levels
        fits = [j for j in range(out.responses.shape[1]) if bool(out.valid[j, y, x])]
        j = max(fits, key=lambda j: float(edge[0, j, y, x]))
        gx, gy = out.responses[0, j, :2, y, x].tolist()
        assert math.isclose(float(records.theta[0, p]), math.atan2(gy, gx), abs_tol=1e-12)
    torch.testing.assert_close(records.canonical, steer(records.descriptors, records.theta))


def test_records_of_mixed_sizes_keep_input_order():
    space = FeatureSpace()
    a, b = random_image(40, 40, seed=7), random_image(56, 48, seed=8)
    joined = space.records([a, b, a])
    assert joined.sizes.tolist() == [[40, 40], [56, 48], [40, 40]]
    alone = space(b)
    n = int(alone.mask[0].sum())
    assert torch.equal(joined.x[1, :n], alone.x[0, :n]) and not joined.mask[1, n:].any()
    assert torch.equal(joined.responses[1, : alone.responses.shape[1], :, :56, :48], alone.responses[0])


def test_the_pyramid_size_is_known_before_it_is_built():
    space = FeatureSpace()
    images = [random_image(40, 40, seed=7), random_image(56, 48, seed=8).to(torch.float32), random_image(33, 64, seed=9)]
    for chosen in ([0], [1], [1, 2], [0, 1, 2]):
        pyramid = space.records([images[i] for i in chosen]).pyramid
        assert space.pyramid_nbytes([images[i] for i in chosen]) == pyramid.first.nbytes + pyramid.second.nbytes


def test_part_kinds_partition_the_salient_points_and_name_their_descriptor_slots():
    records = FeatureSpace()(random_image(64, 64, seed=7))
    texels, edgels = PartKind.TEXEL.mask(records), PartKind.EDGEL.mask(records)
    assert bool(texels.any()) and bool(edgels.any())
    assert torch.equal(texels | edgels, records.mask) and not bool((texels & edgels).any())
    for p in records.mask[0].nonzero()[:, 0].tolist():
        kind = PartKind.of_point(int(records.kind[0, p]))
        assert bool(kind.mask(records)[0, p]) and int(records.kind[0, p]) in kind.codes
        outside = torch.ones(15, dtype=torch.bool)
        outside[kind.slots] = False
        assert not records.descriptors[0, p, outside].any() and len(records.descriptors[0, p, kind.slots]) == kind.size
    assert (PartKind.TEXEL.size, PartKind.EDGEL.size) == (15, 2)
    assert PartKind("edgel") is PartKind.EDGEL and hash(PartKind.EDGEL) == hash("edgel") and f"{PartKind.TEXEL}" == "texel"
