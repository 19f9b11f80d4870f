"""Histograms in the form of figures 6.13, 6.14 and 6.17, drawn with OpenCV (PNG)."""
from __future__ import annotations

import cv2
import numpy as np

from ftorch.draw import PALETTE, grid, titled
from training.curves import put_text

WIDTH, HEIGHT, MARGIN = 300, 170, 34
ERROR_BINS = np.arange(0, 65, 5.0)    # degrees; the last bin holds everything above 60 (figure 6.13)
PROBE_BINS = np.arange(1, 21, 1.0)    # the last bin holds 20 probes or more (figure 6.14)
MU0_BINS = np.arange(0, 1.05, 0.05)   # the last bin holds mu_0 >= 1


def counts(values, bins: np.ndarray) -> np.ndarray:
    """Histogram with len(bins) bins: [b_i, b_{i+1}) and an overflow bin from bins[-1] on (NaN and
    infinity included)."""
    values = np.asarray([np.inf if v is None else v for v in values], dtype=float)
    index = np.searchsorted(bins, np.nan_to_num(values, nan=np.inf), side="right") - 1
    return np.bincount(np.clip(index, 0, len(bins) - 1), minlength=len(bins))


def histogram_panel(values, bins: np.ndarray, label: str, colour=PALETTE[2]) -> np.ndarray:
    """Bars of :func:`counts` with the first, middle and overflow bins labelled."""
    tally = counts(values, bins)
    canvas = np.full((HEIGHT, WIDTH, 3), 255, np.uint8)
    left, right, upper, lower = MARGIN, WIDTH - 8, 8, HEIGHT - 26
    top = max(int(tally.max()), 1)
    width = (right - left) / len(bins)
    cv2.rectangle(canvas, (left, upper), (right, lower), (150, 150, 150), 1)
    for i, n in enumerate(tally):
        x0, x1 = int(left + i * width + 1), int(left + (i + 1) * width - 1)
        cv2.rectangle(canvas, (x0, int(lower - n / top * (lower - upper))), (x1, lower), colour, -1)
    for k in (0, top):
        put_text(canvas, str(k), (4, int(lower - k / top * (lower - upper)) + 4))
    for i in (0, len(bins) // 2, len(bins) - 1):
        tick = f"{bins[i]:g}" + ("+" if i == len(bins) - 1 else "")
        put_text(canvas, tick, (int(left + i * width), lower + 13))
    put_text(canvas, f"{label} (n={len(values)})", (left + 4, lower + 24), 0.36)
    return canvas


def error_figure(errors: list, title: str) -> np.ndarray:
    """Figure 6.13: prediction error magnitudes (degrees; no prediction counts in the last bin)."""
    return titled(histogram_panel(errors, ERROR_BINS, "orientation error, degrees"), title)


def grasp_figure(columns: dict[str, list[dict]], title: str) -> np.ndarray:
    """Figures 6.14 and 6.17: per column of grasps, the probes (top) and mu_0 (bottom) histograms."""
    panels = [titled(histogram_panel([g["probes"] for g in grasps], PROBE_BINS, "probes", PALETTE[n]), name)
              for n, (name, grasps) in enumerate(columns.items())]
    panels += [histogram_panel([g["mu0"] for g in grasps], MU0_BINS, "mu_0", PALETTE[n])
               for n, grasps in enumerate(columns.values())]
    return titled(grid(panels, len(columns)), title)
