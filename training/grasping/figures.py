"""Histograms in the form of figures 6.13, 6.14 and 6.17, drawn with matplotlib (figures: rendered
with :func:`training.plots.figure_rgb` for PNG files, given to ``SummaryWriter.add_figure`` for
TensorBoard): labelled axes, the count of grasps in each legend, titled by the caller
with the experiment, the seed and the fold."""
from __future__ import annotations

import numpy as np
from matplotlib.figure import Figure

from training.plots import subplots

from .records import Grasp, Mode, SeedStudy

ERROR_BINS = np.arange(0, 65, 5.0)    # degrees; the last bin holds everything above 60 (figure 6.13)
PROBE_BINS = np.arange(1, 21, 1.0)    # the last bin holds 20 probes or more (figure 6.14)
MU0_BINS = np.arange(0, 1.05, 0.05)   # the last bin holds mu_0 >= 1


def counts(values, bins: np.ndarray) -> np.ndarray:
    """Histogram with len(bins) bins: [b_i, b_{i+1}) and an overflow bin from bins[-1] on (NaN and
    infinity included)."""
    values = np.asarray([np.inf if v is None else v for v in values], dtype=float)
    index = np.searchsorted(bins, np.nan_to_num(values, nan=np.inf), side="right") - 1
    return np.bincount(np.clip(index, 0, len(bins) - 1), minlength=len(bins))


def _histogram(ax, values, bins: np.ndarray, xlabel: str, label: str, colour: str) -> None:
    """Bars of :func:`counts` over ``bins``; the overflow bin's tick ends with '+'."""
    width = float(bins[1] - bins[0])
    ax.bar(bins + width / 2, counts(values, bins), width=width * 0.9, color=colour, label=f"{label} (n={len(values)})")
    ticks = [0, len(bins) // 2, len(bins) - 1]
    ax.set_xticks([bins[i] + width / 2 for i in ticks], [f"{bins[i]:g}" + ("+" if i == len(bins) - 1 else "") for i in ticks])
    ax.set_xlabel(xlabel)
    ax.set_ylabel("grasps")
    ax.legend(fontsize=7)


def error_figure(errors: list, title: str) -> Figure:
    """Figure 6.13: prediction error magnitudes (degrees; no prediction counts in the last bin)."""
    figure, ax = subplots(figsize=(4.2, 2.8))
    _histogram(ax, errors, ERROR_BINS, "orientation error, degrees (last bin: > 60, none)",
               "test grasps", "C0")
    ax.set_title(title, fontsize=9)
    figure.tight_layout()
    return figure


def grasp_figure(columns: dict[str, list[Grasp]], title: str) -> Figure:
    """Figures 6.14 and 6.17: per column of grasps, the probes (top) and mu_0 (bottom) histograms."""
    figure, axes = subplots(2, len(columns), figsize=(3.4 * len(columns), 5.2), squeeze=False)
    for n, (name, grasps) in enumerate(columns.items()):
        colour = f"C{n}"
        _histogram(axes[0, n], [g.probes for g in grasps], PROBE_BINS, "probes until the grasp settles", name, colour)
        _histogram(axes[1, n], [g.mu0 for g in grasps], MU0_BINS, "mu_0 (lower is better; last bin: >= 1)", name, colour)
        axes[0, n].set_title(name, fontsize=9)
    figure.suptitle(title, fontsize=10)
    figure.tight_layout()
    return figure


def reduction_figure(study: SeedStudy, title: str) -> Figure:
    """Histogram of the per-seed poor-grasp reductions, off-line (and on-line), in percent; a seed
    without poor haptic grasps has no reduction: it is left out, and the legend says how many were."""
    figure, ax = subplots(figsize=(4.2, 2.8))
    bins = np.arange(-20, 105, 5.0)
    for n, mode in enumerate(study.reduction):
        reductions = [(e.poor_grasp_fraction if mode is Mode.OFFLINE else e.online.poor_grasp_fraction).reduction
                      for e in study.runs]
        values = [100 * r for r in reductions if r is not None]
        left = len(reductions) - len(values)
        note = f"; {left} left out: no poor haptic grasps" if left else ""
        ax.hist(np.clip(values, bins[0], bins[-1]), bins=bins, alpha=0.7, color=f"C{n}",
                label=f"{mode} (n={len(values)} seeds{note})")
    ax.set_xlabel("reduction of poor grasps by the cue, % (mu_0 > 0.4)")
    ax.set_ylabel("seeds")
    ax.legend(fontsize=7)
    ax.set_title(title, fontsize=9)
    figure.tight_layout()
    return figure
