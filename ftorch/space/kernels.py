"""Sampled Gaussian-derivative kernels (eq. 3.1-3.2) and their reflect-folded band matrices.

Kernels are the sampled Gaussian normalised to unit sum, times the derivative polynomial,
exactly as ``scipy.ndimage.gaussian_filter1d`` builds them, truncated at
``radius = int(truncate * sigma + 0.5)``. They are *scale-normalised*: the order-d kernel is
multiplied by sigma**d, so responses of different scales are comparable (the gamma = 1
normalisation behind eq. 3.9-3.11 and the scale-invariant texel of 3.4.2).

One deliberate difference from scipy: the truncated, sampled g'' does not sum to zero (its
variance falls short of sigma^2 by ~3% at truncate=3), so a constant image would give a
second-derivative response. A derivative must annihilate constants, or feature values would
not be invariant to I -> a*I + b (3.4.4), so g'' is made zero-sum by subtracting
(sum g'') * g. Against scipy this is exactly ``order=2 result - (sum g'') * order=0 result``,
which is what the tests compare.
"""
from __future__ import annotations

import numpy as np


def kernel_radius(sigma: float, truncate: float) -> int:
    """Half-width of the sampled kernel, scipy's rule: int(truncate * sigma + 0.5)."""
    return int(truncate * sigma + 0.5)


def derivative_kernels(sigma: float, truncate: float) -> np.ndarray:
    """The sampled 1-D Gaussian and its scale-normalised derivatives (eq. 3.1-3.2), float64.

    Args:
        sigma: the scale.
        truncate: the kernel radius in sigmas, r = :func:`kernel_radius`.

    Returns:
        the rows g, sigma*g', sigma^2*g'' (g'' with zero sum).

    Shape:
        - Output: :math:`(3, 2r + 1)`.
    """
    r = kernel_radius(sigma, truncate)
    x = np.arange(-r, r + 1, dtype=np.float64)
    g = np.exp(-0.5 * x * x / sigma**2)
    g /= g.sum()
    g1 = -x / sigma**2 * g
    g2 = (x * x / sigma**4 - 1.0 / sigma**2) * g
    g2 -= g2.sum() * g
    return np.stack([g, sigma * g1, sigma**2 * g2])


def reflect_index(index: np.ndarray, n: int) -> np.ndarray:
    """Map any integer index onto 0..n-1 by symmetric reflection (scipy mode 'reflect', dcba|abcd)."""
    m = np.mod(index, 2 * n)
    return np.where(m >= n, 2 * n - 1 - m, m)


def band_matrix(kernel: np.ndarray, n: int, rows: np.ndarray | None = None,
                columns: tuple[int, int] | None = None) -> np.ndarray:
    """Matrix M with M @ x == convolution of x with ``kernel``, boundary folded in by reflection:
    (n, n), or only its ``rows`` (indices) and the columns ``range(*columns)`` where given.

    The convolution is true convolution, out[i] = sum_j kernel[j] * x[i - j], as in scipy. A part is
    built on its own, never cut from the whole (n, n) matrix, with the same values bit for bit: each
    entry sums its taps in the same order (ascending j) whatever part is asked for.
    """
    r = (len(kernel) - 1) // 2
    out = np.arange(n) if rows is None else np.asarray(rows, dtype=np.int64)
    c0, c1 = (0, n) if columns is None else columns
    src = reflect_index(out[:, None] - np.arange(-r, r + 1)[None, :], n) - c0
    keep = (src >= 0) & (src < c1 - c0)
    m = np.zeros((len(out), c1 - c0))
    at = np.broadcast_to(np.arange(len(out))[:, None], src.shape)
    np.add.at(m, (at[keep], src[keep]), np.broadcast_to(kernel, src.shape)[keep])
    return m


def band_span(start: int, stop: int, radius: int, n: int) -> tuple[int, int]:
    """Columns [c0, c1) that outputs ``start..stop-1`` of a reflect-folded band matrix of this kernel
    ``radius`` can read: the band's columns, at most (stop - start + 2 * radius) of them."""
    src = reflect_index(np.arange(start, stop)[:, None] - np.arange(-radius, radius + 1)[None, :], n)
    return int(src.min()), int(src.max()) + 1
