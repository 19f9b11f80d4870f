"""Von Mises mixtures on the circle (6.3.2, 6.4.1, appendix), fitted in batches.

Density (eq. 6.1): p(theta | mu, kappa) = exp(kappa cos(theta - mu)) / (2 pi I0(kappa)); the
mixture (eq. 6.4) weights K of them by P(k). Each mixture is fitted by maximum likelihood
(eq. 6.5) with the EM algorithm of the appendix. The appendix set EM aside because kappa has no
closed form; a few Newton steps on A1(kappa) = r from Best and Fisher's estimate give it to
machine precision, and batched EM then reaches a higher likelihood than a batched direct
(L-BFGS) fit, in less time (measured in docs/decisions.md). kappa is capped at ``max_kappa`` (no
singular modes). K is chosen by ICL (Biernacki et al. 2000, the criterion of 6.4.1):
log L + sum_ik t_ik log t_ik - (3K - 1)/2 log N, with t_ik the component posteriors.

Many data sets and every candidate K are fitted together as one padded batch: the hot path
has no Python loop over data points or data sets.
"""
from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Sequence

import torch
from torch import Tensor

from ..errors import InputError

TWO_PI = 2 * math.pi
MAX_KAPPA = 1000.0  # about 1.8 degrees: the angular resolution of a feature's orientation


def wrap(theta: Tensor) -> Tensor:
    """Angles to [-pi, pi)."""
    return torch.remainder(theta + math.pi, TWO_PI) - math.pi


def vonmises_log_pdf(theta: Tensor, mu: Tensor, kappa: Tensor) -> Tensor:
    """log p_vM(theta | mu, kappa), eq. 6.1 (log I0 through the scaled Bessel function i0e)."""
    return kappa * (torch.cos(theta - mu) - 1) - torch.log(torch.special.i0e(kappa)) - math.log(TWO_PI)


def kappa_estimate(r: Tensor) -> Tensor:
    """Best and Fisher's approximation of A1^{-1}(r), the ML kappa for mean resultant length r."""
    r = r.clamp(0, 1 - 1e-9)
    small = 2 * r + r ** 3 + 5 * r ** 5 / 6
    middle = -0.4 + 1.39 * r + 0.43 / (1 - r)
    large = 1 / (r ** 3 - 4 * r ** 2 + 3 * r)
    return torch.where(r < 0.53, small, torch.where(r < 0.85, middle, large))


def kappa_ml(r: Tensor, max_kappa: float = MAX_KAPPA, steps: int = 4, start: Tensor | None = None) -> Tensor:
    """The ML kappa, A1^{-1}(r) with A1 = I1 / I0: Newton steps on A1(kappa) = r (A1' = 1 - A1 / kappa
    - A1^2) from ``start``, by default Best and Fisher's approximation."""
    kappa = (kappa_estimate(r) if start is None else start).clamp(1e-6, max_kappa)
    for _ in range(steps):
        a = torch.special.i1e(kappa) / torch.special.i0e(kappa)
        kappa = (kappa - (a - r) / (1 - a / kappa - a ** 2).clamp_min(1e-12)).clamp(1e-6, max_kappa)
    return kappa


@dataclass
class VonMisesMixture:
    """Fitted mixture (eq. 6.4): mu, kappa, weight (K,), with the N data points it models."""

    mu: Tensor
    kappa: Tensor
    weight: Tensor
    n: int
    log_likelihood: float
    icl: float

    @property
    def k(self) -> int:
        return len(self.mu)

    def log_pdf(self, theta) -> Tensor:
        theta = torch.as_tensor(theta, dtype=torch.float64)[..., None]
        return torch.logsumexp(vonmises_log_pdf(theta, self.mu, self.kappa) + torch.log(self.weight), -1)

    def pdf(self, theta) -> Tensor:
        return self.log_pdf(theta).exp()

    def concentrated(self, min_points: float = 3.0) -> int:
        """Alg. 6.2 step 3: the component of largest kappa among those modelling >= min_points points
        (the largest-weight one where none does)."""
        eligible = self.weight * self.n >= min_points
        if not bool(eligible.any()):
            return int(self.weight.argmax())
        return int(torch.where(eligible, self.kappa, torch.full_like(self.kappa, -1.0)).argmax())

    def to_dict(self) -> dict:
        return {"mu": self.mu.tolist(), "kappa": self.kappa.tolist(), "weight": self.weight.tolist(), "n": self.n,
                "log_likelihood": self.log_likelihood, "icl": self.icl}

    @classmethod
    def from_dict(cls, data: dict) -> "VonMisesMixture":
        try:
            mu, kappa, weight = (torch.tensor([float(v) for v in data[k]], dtype=torch.float64) for k in ("mu", "kappa", "weight"))
            n, ll, icl = int(data["n"]), float(data["log_likelihood"]), float(data["icl"])
        except (KeyError, TypeError, ValueError) as err:
            raise InputError(f"not a von Mises mixture description: {err}") from None
        if not len(mu) == len(kappa) == len(weight) > 0:
            raise InputError("von Mises mixture: mu, kappa and weight must be non-empty and of equal length")
        return cls(mu, kappa, weight, n, ll, icl)


def _padded(datasets: Sequence) -> tuple[Tensor, Tensor]:
    data = [torch.as_tensor(d, dtype=torch.float64).reshape(-1) for d in datasets]
    for i, d in enumerate(data):
        if len(d) == 0:
            raise InputError(f"von Mises fit: data set {i} is empty")
        if not bool(torch.isfinite(d).all()):
            raise InputError(f"von Mises fit: data set {i} has NaN or infinite angles")
    width = max(len(d) for d in data)
    theta = torch.zeros(len(data), width, dtype=torch.float64)
    mask = torch.zeros(len(data), width, dtype=torch.bool)
    for i, d in enumerate(data):
        theta[i, : len(d)], mask[i, : len(d)] = d, True
    return theta, mask


def _farthest_means(theta: Tensor, mask: Tensor, k: int) -> Tensor:
    """Start means (B, k): the circular mean, then repeatedly the point farthest from all chosen."""
    z = (torch.polar(torch.ones_like(theta), theta) * mask).sum(1)
    means = [torch.angle(z)]
    for _ in range(1, k):
        gap = torch.stack([wrap(theta - m[:, None]).abs() for m in means]).amin(0)
        gap = torch.where(mask, gap, torch.full_like(gap, -1.0))
        means.append(theta.gather(1, gap.argmax(1, keepdim=True))[:, 0])
    return torch.stack(means, 1)


def _component_log(theta: Tensor, mu: Tensor, kappa: Tensor, log_weight: Tensor) -> Tensor:
    """log p_vM(theta_i | mu_k, kappa_k) + log P(k): (B, N, K)."""
    return vonmises_log_pdf(theta[:, :, None], mu[:, None, :], kappa[:, None, :]) + log_weight[:, None, :]


def _fit_batch(theta: Tensor, mask: Tensor, ks: Tensor, max_kappa: float, max_steps: int = 40, tol: float = 1e-6):
    """Maximum-likelihood mixtures for rows of ``theta`` (B, N) with K = ks (B,) components each, by
    EM (appendix: E-step eq. A.2, M-step the weighted circular mean for mu_k (A.7), exact ML
    kappa_k by :func:`kappa_ml`, and P(k) by A.5), from a hard farthest-point assignment, until no
    row's log-likelihood rises by more than ``tol`` per point."""
    width = int(ks.max())
    active = torch.arange(width)[None, :] < ks[:, None]
    weight = mask.to(theta.dtype)
    means = _farthest_means(theta, mask, width)
    distance = torch.stack([wrap(theta - means[:, j, None]).abs() for j in range(width)], -1)
    resp = torch.nn.functional.one_hot(distance.masked_fill(~active[:, None, :], math.inf).argmin(-1), width)
    resp = resp.to(theta.dtype)
    n = weight.sum(1)
    previous = torch.full_like(n, -math.inf)
    done = torch.zeros_like(n, dtype=torch.bool)
    fit: tuple[Tensor, Tensor, Tensor] | None = None  # (mu, kappa, log_weight) so far: none before the first M step
    for _ in range(max_steps):
        resp = resp * weight[:, :, None]
        mass = resp.sum(1)
        z = (torch.polar(torch.ones_like(theta), theta)[:, :, None] * resp).sum(1)
        start = None if fit is None else fit[1]
        step = (torch.angle(z), kappa_ml(z.abs() / mass.clamp_min(1e-12), max_kappa, 4 if start is None else 2, start),
                torch.log(mass / n[:, None]).masked_fill(~active, -math.inf))
        mu, kappa, log_weight = step
        if fit is not None:  # a converged row keeps its fit: each row's result is that of its own EM
            mu, kappa, log_weight = (torch.where(done[:, None], old, new) for old, new in zip(fit, step))
        fit = mu, kappa, log_weight
        log_joint = _component_log(theta, mu, kappa, log_weight)
        log_mix = torch.logsumexp(log_joint, -1)
        ll = (log_mix * weight).sum(1)
        resp = torch.exp(log_joint - log_mix[:, :, None])
        done = done | ((ll - previous) <= tol * n)
        if bool(done.all()):
            break
        previous = ll
    entropy = torch.where(resp > 0, resp * resp.clamp_min(1e-300).log(), torch.zeros_like(resp)).sum(-1)
    icl = ll + (entropy * weight).sum(1) - (3 * ks - 1) / 2 * torch.log(n)
    return wrap(mu), kappa, log_weight.exp(), ll, icl


def fit_mixtures(datasets: Sequence, max_k: int = 4, max_kappa: float = MAX_KAPPA, k: int | None = None
                 ) -> list[VonMisesMixture]:
    """One mixture per data set (angles in radians): ML fit (eq. 6.5) for every K from 1 to
    ``max_k`` (at most N/3 components, each able to model three points), best by ICL; or exactly
    ``k`` components where given."""
    if max_k < 1 or (k is not None and k < 1):
        raise InputError(f"von Mises fit: the number of components must be at least 1, got {k or max_k}")
    theta, mask = _padded(datasets)
    n = mask.sum(1)
    candidates = []  # (data set, K) pairs, fitted as one batch
    for i in range(len(theta)):
        sizes = [k] if k is not None else range(1, max(1, min(max_k, int(n[i]) // 3)) + 1)
        candidates += [(i, kk) for kk in sizes]
    rows = torch.tensor([i for i, _ in candidates])
    ks = torch.tensor([kk for _, kk in candidates])
    mu, kappa, probs, ll, icl = _fit_batch(theta[rows], mask[rows], ks, max_kappa)
    best: dict[int, int] = {}
    for j, (i, _) in enumerate(candidates):
        if i not in best or icl[j] > icl[best[i]]:
            best[i] = j
    out = []
    for i in range(len(theta)):
        j, kk = best[i], int(ks[best[i]])
        out.append(VonMisesMixture(mu[j, :kk].clone(), kappa[j, :kk].clone(), probs[j, :kk].clone(), int(n[i]),
                                   float(ll[j]), float(icl[j])))
    return out


def fit_mixture(theta, max_k: int = 4, max_kappa: float = MAX_KAPPA, k: int | None = None) -> VonMisesMixture:
    """:func:`fit_mixtures` for one data set."""
    return fit_mixtures([theta], max_k, max_kappa, k)[0]
