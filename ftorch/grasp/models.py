"""A grasp feature's models, fitted on its set's instance list: the orientation model of alg. 6.1
(KSD_f, alpha_f, the von Mises mixture of eq. 6.4 and E[M_0(f)] of eq. 6.8) and the quality split
(beyond chapter 6: ftorch/grasp/learner.py's module doc says why and how it is used).

Both are batched over a set's features: the instance list is given as arrays, values and
orientations (n, F), NaN orientation where a feature found no point, and per instance the final
hand orientation theta_H, mu_0 (capped) and the symmetry period (n,).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
import torch

from ..checkpoint import stored_position
from ..ksd import ksd
from .vonmises import VonMisesMixture, fit_mixtures


def angular_error(predicted, actual, period) -> np.ndarray:
    """|predicted - actual| in radians, modulo the symmetry period (0: every orientation is right)."""
    predicted, actual, period = np.broadcast_arrays(*(np.asarray(a, dtype=float) for a in (predicted, actual, period)))
    full = np.where(period > 0, period, 2 * math.pi)
    difference = np.remainder(predicted - actual + full / 2, full) - full / 2
    return np.where(period > 0, np.abs(difference), 0.0)


@dataclass
class FeatureModel:
    """Alg. 6.1's result: KSD_f, threshold alpha_f, orientation model (eq. 6.4) and E[M_0(f)] (eq. 6.8)."""

    ksd: float
    alpha: float
    mixture: VonMisesMixture
    offset: float  # mu_{k*} of alg. 6.2 step 3
    expected_mu0: float
    support: int  # instances above alpha_f that eq. 6.4 and 6.8 were fitted on
    rows: np.ndarray | None = field(default=None, repr=False, compare=False)  # those instances' rows

    def to_dict(self, rows: bool = False) -> dict:
        """JSON-ready; with ``rows``, the instance rows it was fitted on (which learning compares)."""
        out = {"ksd": self.ksd, "alpha": self.alpha, "mixture": self.mixture.to_dict(), "offset": self.offset,
               "expected_mu0": self.expected_mu0, "support": self.support}
        if not rows:
            return out
        if self.rows is None:
            raise ValueError("this model was read without the instance rows it was fitted on: it cannot write them")
        return {**out, "rows": self.rows.tolist()}

    @classmethod
    def from_dict(cls, data: dict, instances: int | None = None) -> "FeatureModel":
        """A model written by :meth:`to_dict`; its rows, where written, are positions among ``instances``."""
        numbers = [float(data[k]) for k in ("ksd", "alpha", "offset", "expected_mu0")]
        rows = None
        if "rows" in data:
            rows = np.array([stored_position(i, instances or 0) for i in data["rows"]], dtype=np.int64)
            if len(rows) != int(data["support"]):
                raise ValueError(f"a model fitted on {data['support']} instances lists {len(rows)} rows")
        return cls(numbers[0], numbers[1], VonMisesMixture.from_dict(data["mixture"]), numbers[2], numbers[3],
                   int(data["support"]), rows)


def fit_models(models: list[FeatureModel | None], values: np.ndarray, thetas: np.ndarray, theta_H: np.ndarray,
               mu0: np.ndarray, period: np.ndarray, t_dtheta: float, max_k: int, min_points: int) -> list[FeatureModel | None]:
    """Alg. 6.1 for every feature of a set, batched: its models after ``models`` (None: a feature without
    one, which is first fitted to all of its data points). The prediction errors are those of each
    feature's current model on every instance (the exact Expectation step of 6.4.4)."""
    offsets = theta_H[:, None] - thetas  # (n, F), NaN where a feature found no point
    located = np.isfinite(offsets)
    fresh = [j for j, m in enumerate(models) if m is None and located[:, j].sum() >= min_points]
    start = dict(zip(fresh, fit_mixtures([offsets[located[:, j], j] for j in fresh], max_k))) if fresh else {}
    mixture = {j: m.mixture for j, m in enumerate(models) if m is not None} | start  # start: features without a model
    modelled = sorted(mixture)
    if not modelled:
        return list(models)
    offset = np.array([float(mixture[j].mu[mixture[j].concentrated(min_points)]) for j in modelled])
    error = angular_error(thetas[:, modelled] + offset, theta_H[:, None], period[:, None])
    correct = located[:, modelled] & (error < t_dtheta)
    false = located[:, modelled] & ~correct
    split = ksd(torch.from_numpy(np.where(located[:, modelled], values[:, modelled], np.nan).T),
                torch.from_numpy(correct.T), torch.from_numpy(false.T))
    power, alpha = split.distinctive.numpy().copy(), split.cutpoint.numpy().copy()
    perfect = ~false.any(0) & (correct.sum(0) >= min_points)
    power[perfect], alpha[perfect] = 1.0, -math.inf
    chosen = located[:, modelled] & (values[:, modelled] > alpha[None, :])
    usable = [i for i in range(len(modelled)) if power[i] > 0 and chosen[:, i].sum() >= min_points]
    rows = {i: np.flatnonzero(chosen[:, i]) for i in usable}
    previous = {i: models[modelled[i]] for i in usable}
    # A model fitted to the same instances keeps its mixture: EM on the same points reaches the
    # same fit (each fit is independent of its batch, ftorch/grasp/vonmises.py), so only changed ones are fitted.
    kept = {i: m.mixture for i, m in previous.items() if m is not None and m.rows is not None
            and np.array_equal(m.rows, rows[i])}
    refit = [i for i in usable if i not in kept]
    fitted = {**kept, **dict(zip(refit, fit_mixtures([offsets[rows[i], modelled[i]] for i in refit], max_k)
                                      if refit else []))}
    fitted_models: list[FeatureModel | None] = [None] * len(models)
    for i in usable:
        j, mix, points = modelled[i], fitted[i], rows[i]
        weight = mix.pdf(torch.from_numpy(offsets[points, j])).numpy()
        expected = float((weight * mu0[points]).sum() / max(weight.sum(), 1e-300))
        fitted_models[j] = FeatureModel(float(power[i]), float(alpha[i]), mix, float(mix.mu[mix.concentrated(min_points)]),
                                        expected, len(points), points)
    return fitted_models


def quality_splits(values: np.ndarray, mu0: np.ndarray, mu0_split: float, min_points: int) -> np.ndarray:
    """Quality splits (beyond chapter 6), (4, F): per feature, the KSD (def. 4.2, either direction) between
    its values on good (mu_0 <= ``mu0_split``) and poor instances, its cut-point, and the mean mu_0 on
    each side (above, below); a side with fewer than ``min_points`` instances gives no split (KSD 0)."""
    good = torch.from_numpy(mu0 <= mu0_split)
    split = ksd(torch.from_numpy(values.T.copy()), good, ~good)
    distance, cut = split.distance.numpy(), split.cutpoint.numpy()
    located = np.isfinite(values)
    high = located & (values > cut[None, :])
    low = located & ~high
    count = np.stack([high.sum(0), low.sum(0)])
    mean = np.stack([(side * mu0[:, None]).sum(0) for side in (high, low)]) / np.maximum(count, 1)
    enough = (count >= min_points).all(0) & np.isfinite(cut)
    return np.stack([np.where(enough, distance, 0.0), cut, *mean])
