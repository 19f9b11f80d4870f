"""KSD cut-points and distinctive power against scipy.stats.ks_2samp and hand-made cases."""
import math

import numpy as np
import pytest
import torch
from scipy.stats import ks_2samp

from ftorch.ksd import distinctive_at, ksd
from ftorch.recognition.bayes import ClassNetwork
from ftorch.recognition.counting import Counting


@pytest.mark.parametrize("seed", range(6))
def test_distance_and_location_agree_with_scipy(seed):
    rng = np.random.default_rng(seed)
    n_a, n_b = rng.integers(3, 40, size=2)
    rows = []
    for f in range(8):
        a = rng.normal(0, 1, n_a)
        b = rng.normal(rng.uniform(-2, 2), rng.uniform(0.5, 2), n_b)
        if f % 3 == 0:  # many ties
            a, b = np.round(a, 0), np.round(b, 0)
        rows.append(np.concatenate([a, b]))
    values = torch.tensor(np.array(rows))
    discriminated = torch.tensor([True] * n_a + [False] * n_b)
    result = ksd(values, ~discriminated, discriminated)
    for f, row in enumerate(rows):
        ref = ks_2samp(row[:n_a], row[n_a:])
        assert result.distance[f].item() == pytest.approx(ref.statistic, abs=1e-12)
        if ref.statistic == 0:
            continue
        # our cut-point lies just above one of the values where the two cdfs differ by the KSD
        cut = result.cutpoint[f].item()
        below = row[row < cut].max()
        cdf_a, cdf_b = (row[:n_a] <= below).mean(), (row[n_a:] <= below).mean()
        assert abs(cdf_a - cdf_b) == pytest.approx(ref.statistic, abs=1e-12)
        assert not np.any((row > below) & (row < cut))
        expected = ref.statistic if cdf_a > cdf_b else 0.0
        assert result.distinctive[f].item() == pytest.approx(expected, abs=1e-12)


def test_hand_made_cases():
    values = torch.tensor([
        [0.1, 0.2, 0.3, 0.8, 0.9],   # class scores high: characteristic, perfectly separated
        [0.8, 0.9, 0.7, 0.1, 0.2],   # class scores low: not characteristic
        [0.5, 0.5, 0.5, 0.5, 0.5],   # all tied: no cut-point
        [0.1, math.nan, 0.3, 0.9, math.nan],  # unmeasured instances are ignored
    ])
    characterized = torch.tensor([False, False, False, True, True])
    result = ksd(values, characterized, ~characterized)
    assert result.distance.tolist() == [1.0, 1.0, 0.0, 1.0]
    assert result.distinctive.tolist() == [1.0, 0.0, 0.0, 1.0]
    assert result.cutpoint[0].item() == pytest.approx(0.55) and math.isnan(result.cutpoint[2].item())
    assert result.cutpoint[3].item() == pytest.approx(0.6)


def test_empty_group_gives_zero():
    result = ksd(torch.tensor([[0.1, 0.2]]), torch.tensor([False, False]), torch.tensor([True, True]))
    assert result.distance.item() == 0.0 and result.distinctive.item() == 0.0


@pytest.mark.parametrize("seed", range(4))
def test_distinctive_at_a_cutpoint_brute_force(seed):
    """At ksd's own cut-point it reproduces the distinctive power; at any cut-point it matches
    counting by hand, unmeasured (NaN) instances ignored."""
    rng = np.random.default_rng(seed)
    values = rng.normal(0, 1, (6, 30))
    values[:, :15] += rng.uniform(-2, 2, (6, 1))
    values[rng.random(values.shape) < 0.2] = np.nan
    characterized = np.arange(30) < 15
    discriminated = ~characterized & (np.arange(30) % 3 > 0)
    own = ksd(torch.tensor(values), torch.tensor(characterized), torch.tensor(discriminated))
    at_own = distinctive_at(torch.tensor(values), own.cutpoint, torch.tensor(characterized), torch.tensor(discriminated)[None])[0]
    assert torch.allclose(at_own, own.distinctive, atol=1e-12)
    cuts = rng.normal(0, 1, 6)
    groups = np.stack([discriminated, ~characterized, ~characterized & (np.arange(30) > 40)])  # the last is empty
    got = distinctive_at(torch.tensor(values), torch.tensor(cuts), torch.tensor(characterized), torch.tensor(groups))
    assert got.shape == (3, 6)
    for d, group in enumerate(groups):
        for f in range(6):
            a = values[f][group & np.isfinite(values[f])]
            b = values[f][characterized & np.isfinite(values[f])]
            expected = max((a <= cuts[f]).mean() - (b <= cuts[f]).mean(), 0.0) if len(a) and len(b) else 0.0
            assert got[d, f].item() == expected  # counts are exact: the same float as by hand


@pytest.mark.parametrize("seed", range(3))
def test_pair_powers_in_one_call_equal_pair_by_pair(seed):
    """Alg. 5.2's powers of several pairs counted in one call (each row with its own class) equal
    ``distinctive_at`` called pair by pair, bit for bit; a feature may serve two pairs."""
    rng = np.random.default_rng(seed)
    counting, labels = Counting(), "ABCD"
    for image in range(40):
        counting.instances.add(image, {labels[image % 4]} | ({"A"} if image % 7 == 0 else set()))
    networks = {c: ClassNetwork(c) for c in labels}
    for i in range(9):
        for c in labels[: 1 + i % 4]:
            networks[c].add_feature(f"f{i}", threshold=float(rng.uniform(0.2, 0.8)))
        for image in range(40):
            if rng.random() < 0.8:
                counting.instances.set(image, f"f{i}", float(rng.random()))
    pairs = [(c, [d for d in labels if d != c][: 1 + k], list(networks[c].features)) for k, c in enumerate(labels)]
    got = counting.pair_powers(networks, pairs)
    for (c, others, features), block in zip(pairs, got):
        present = torch.from_numpy(counting.instances.has(c))
        against = torch.stack([torch.from_numpy(counting.instances.has(d)) for d in others]) & ~present
        cuts = torch.tensor([networks[c].threshold[f] for f in features], dtype=torch.float64)
        expected = distinctive_at(torch.from_numpy(counting.instances.block(features)), cuts, present, against)
        assert block.shape == (len(others), len(features)) and torch.equal(block, expected)
    assert counting.pair_powers(networks, []) == []
