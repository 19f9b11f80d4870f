"""Von Mises mixtures (6.3.2, 6.4.1): density against scipy, ML fit against scipy for K = 1,
recovery of known mixtures with K chosen by ICL, and bad input."""
import math

import numpy as np
import pytest
import torch
from scipy import special, stats

from ftorch.errors import InputError
from ftorch.grasp.vonmises import VonMisesMixture, fit_mixture, fit_mixtures, kappa_ml, vonmises_log_pdf


def _sample(mus, kappas, weights, n, seed):
    rng = np.random.default_rng(seed)
    component = rng.choice(len(mus), size=n, p=weights)
    return np.array([stats.vonmises.rvs(kappas[c], loc=mus[c], random_state=rng) for c in component])


def _circular_distance(a, b):
    return abs((a - b + math.pi) % (2 * math.pi) - math.pi)


def test_density_matches_scipy():
    theta = torch.linspace(-math.pi, math.pi, 37, dtype=torch.float64)
    for mu, kappa in [(0.0, 0.01), (1.0, 4.0), (-2.5, 80.0), (3.0, 700.0)]:
        ours = vonmises_log_pdf(theta, torch.tensor(mu, dtype=torch.float64), torch.tensor(kappa, dtype=torch.float64))
        assert np.allclose(ours.numpy(), stats.vonmises.logpdf(theta.numpy(), kappa, loc=mu), rtol=1e-10, atol=1e-10)


def test_kappa_ml_inverts_bessel_ratio():
    kappa = torch.tensor([0.05, 0.7, 2.0, 9.0, 150.0], dtype=torch.float64)
    r = torch.from_numpy(special.ive(1, kappa.numpy()) / special.ive(0, kappa.numpy()))
    assert torch.allclose(kappa_ml(r), kappa, rtol=1e-8)


@pytest.mark.parametrize("mu, kappa, n", [(1.0, 4.0, 200), (-2.8, 30.0, 60), (0.3, 0.8, 300)])
def test_single_component_matches_scipy_fit(mu, kappa, n):
    data = _sample([mu], [kappa], [1.0], n, seed=int(kappa * 10))
    fitted = fit_mixture(data, k=1)
    kappa_scipy, loc_scipy, _ = stats.vonmises.fit(data, fscale=1)
    assert _circular_distance(float(fitted.mu[0]), loc_scipy) < 1e-5
    assert float(fitted.kappa[0]) == pytest.approx(kappa_scipy, rel=1e-5)
    assert fitted.log_likelihood == pytest.approx(stats.vonmises.logpdf(data, kappa_scipy, loc=loc_scipy).sum(), rel=1e-8)


@pytest.mark.parametrize("mus, kappas, weights", [
    ([0.5, 2.5, -2.0], [20.0, 8.0, 40.0], [0.5, 0.3, 0.2]),
    ([-1.0, 2.0], [50.0, 50.0], [0.6, 0.4]),
    ([math.pi - 0.1], [15.0], [1.0]),  # a mode across the -pi / pi seam
])
def test_recovers_known_mixture_and_its_k(mus, kappas, weights):
    data = _sample(mus, kappas, weights, 300, seed=len(mus))
    fitted = fit_mixture(data, max_k=5)
    assert fitted.k == len(mus)
    for mu, kappa, weight in zip(mus, kappas, weights):
        j = int(np.argmin([_circular_distance(float(m), mu) for m in fitted.mu]))
        assert math.degrees(_circular_distance(float(fitted.mu[j]), mu)) < 4
        assert float(fitted.weight[j]) == pytest.approx(weight, abs=0.07)
        assert float(fitted.kappa[j]) == pytest.approx(kappa, rel=0.35)


def test_icl_prefers_true_k_over_neighbours():
    data = _sample([0.0, 2.0], [40.0, 40.0], [0.5, 0.5], 200, seed=3)
    icl = {k: fit_mixture(data, k=k).icl for k in (1, 2, 3)}
    assert icl[2] > icl[1] and icl[2] > icl[3]


def test_batch_equals_one_by_one():
    sets = [_sample([0.2], [10.0], [1.0], 40, 1), _sample([1.0, -2.0], [30.0, 30.0], [0.5, 0.5], 90, 2)]
    together = fit_mixtures(sets, max_k=3)
    for data, joint in zip(sets, together):
        alone = fit_mixture(data, max_k=3)
        assert alone.k == joint.k
        assert torch.allclose(alone.mu, joint.mu, atol=1e-9) and torch.allclose(alone.kappa, joint.kappa, rtol=1e-7)


def test_a_fit_does_not_depend_on_its_batch():
    """Each row of the batched EM stops at its own convergence, so a data set's mixture is the one it
    gets alone (to rounding), however slowly its batch-mates converge (they ran on for up to 3e-4
    in mu before rows were frozen)."""
    rng = np.random.default_rng(0)
    worst = 0.0
    for _ in range(30):
        quick = rng.vonmises(0.3, 8, size=int(rng.integers(6, 40)))
        slow = np.concatenate([rng.vonmises(m, 3, size=15) for m in rng.uniform(-3, 3, 3)])
        for data, joint in zip([quick, slow], fit_mixtures([quick, slow], max_k=4)):
            alone = fit_mixture(data, max_k=4)
            assert alone.k == joint.k
            worst = max(worst, float((alone.mu - joint.mu).abs().max()),
                        float(((alone.kappa - joint.kappa) / alone.kappa).abs().max()))
    assert worst < 1e-11


def test_concentrated_component_needs_three_points():
    mixture = VonMisesMixture(torch.tensor([0.0, 1.0]), torch.tensor([900.0, 20.0]), torch.tensor([0.05, 0.95]), 20,
                              0.0, 0.0)
    assert mixture.concentrated(3) == 1  # 1 point in the sharp component: not eligible (alg. 6.2 step 3)
    assert mixture.concentrated(1) == 0


def test_round_trip_and_bad_input():
    fitted = fit_mixture(_sample([1.0], [5.0], [1.0], 30, 0), max_k=2)
    again = VonMisesMixture.from_dict(fitted.to_dict())
    assert torch.equal(again.mu, fitted.mu) and again.icl == fitted.icl
    with pytest.raises(InputError, match="data set 1 is empty"):
        fit_mixtures([[0.1, 0.2, 0.3], []])
    with pytest.raises(InputError, match="NaN"):
        fit_mixture([0.1, float("nan")])
    with pytest.raises(InputError, match="at least 1"):
        fit_mixture([0.1, 0.2], k=0)
    with pytest.raises(InputError, match="not a von Mises mixture"):
        VonMisesMixture.from_dict({"mu": [0.0]})
