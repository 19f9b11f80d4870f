"""Figure 5.1 (and 5.11 for incremental tasks) drawn with matplotlib: per fold, against the stage,
the test outcome proportions with t_KSD written at each stage (boxed where the target was met),
the feature counts, and the features sampled so far; and figure 5.19 for incremental tasks, the
features sampled against the classes taught on log-log axes with the fitted power law. Every panel
has labelled axes and a legend; the figure's title names the task and the seed. The ``*_figure``
functions return the matplotlib figure: :func:`figure_rgb` renders it for PNG files,
``SummaryWriter.add_figure`` for TensorBoard. They are drawn without pyplot, so importing this module
changes no matplotlib backend (a notebook keeps showing its figures inline)."""
from __future__ import annotations

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from training.recognition.records import FoldEntry, Report
from training.recognition.report import shown
from training.recognition.robustness import TypeRow
from training.recognition.tradeoff import Tradeoff

OUTCOMES = ("accuracy", "top1", "correct", "ambiguous", "ignorant", "wrong")
NAMES = {"accuracy": "accuracy (def. 4.6)", "top1": "top-1 accuracy"}  # legend names where not the key


def subplots(*grid, figsize, squeeze: bool = True, **options) -> tuple[Figure, object]:
    """``pyplot.subplots`` without pyplot: a figure owned by no window manager, so drawing it here
    neither opens a window nor switches the backend of a notebook that imports this module."""
    figure = Figure(figsize=figsize, dpi=100)
    return figure, figure.subplots(*grid, squeeze=squeeze, **options)


def figure_rgb(figure: Figure) -> np.ndarray:
    """A matplotlib figure as an RGB uint8 array (H, W, 3)."""
    canvas = FigureCanvasAgg(figure)
    canvas.draw()
    return np.asarray(canvas.buffer_rgba())[..., :3].copy()


def _panels(axes, fold: FoldEntry) -> None:
    stages = fold.stages
    xs = [s.stage.step for s in stages]
    top = axes[0]
    for name in OUTCOMES:  # a stage tested before top-1 was reported has none: a gap (report.without_top1)
        top.plot(xs, [_or_nan(getattr(s.test, name)) for s in stages], marker="o", markersize=3, label=NAMES.get(name, name))
    top.set_ylim(0, 1.12)
    top.set_ylabel("share of test views")
    for x, s in zip(xs, (s.stage for s in stages)):
        text = f"{s.t_ksd:.2f}".lstrip("0") if 0 < s.t_ksd < 1 else f"{s.t_ksd:.0f}"
        box = {"boxstyle": "square,pad=0.15", "fill": False} if s.target_met else None
        top.text(x, 1.06, text, ha="center", va="center", fontsize=7, bbox=box)
    top.set_title(f"fold {fold.fold}: test results (t_KSD above; boxed: met)", fontsize=9)
    middle = axes[1]
    for key, name in (("bn", "in the networks"), ("different", "different"), ("queried", "queried per recognition")):
        middle.plot(xs, [getattr(s.features, key) for s in stages], marker="o", markersize=3, label=name)
    middle.set_ylabel("features")
    axes[2].plot(xs, [s.features.sampled for s in stages], marker="o", markersize=3, label="sampled so far")
    axes[2].set_ylabel("features sampled")
    if len(axes) > 3:
        axes[3].plot(xs, [s.stage.classes for s in stages], marker="o", markersize=3, label="classes taught")
        axes[3].set_ylabel("classes")
    for ax in axes:
        ax.legend(fontsize=7, loc="best")
        ax.grid(alpha=0.3)
        ax.set_xticks(xs)
    axes[-1].set_xlabel("stage (its running number in the fold)")


def _or_nan(value: float | None) -> float:
    """A figure, NaN (a gap in a curve) where not available."""
    return np.nan if value is None else value


def _incremental(folds: list[FoldEntry]) -> bool:
    """Whether any fold's stages teach more classes (figure 5.11's extra row of panels)."""
    return any(f.stages and f.stages[0].stage.classes != f.stages[-1].stage.classes for f in folds)


def _curves(folds: list[FoldEntry], title: str, incremental: bool) -> Figure:
    rows = 4 if incremental else 3
    figure, axes = subplots(rows, len(folds), figsize=(5.2 * len(folds), 2.6 * rows), squeeze=False)
    for k, fold in enumerate(folds):
        _panels(axes[:, k], fold)
    figure.suptitle(f"{title}: figure {'5.11' if incremental else '5.1'} form", fontsize=11)
    figure.tight_layout()
    return figure


def _title(config: dict) -> str:
    return f"{config.get('task', 'task')}{'-inc' if config.get('incremental') else ''}, seed {config.get('seed', '?')}"


def curves_figure(report: Report) -> Figure:
    """The folds' figure 5.1 curves side by side, titled with the task and the seed (a matplotlib
    figure)."""
    return _curves(report.folds, _title(report.config), _incremental(report.folds))


def fold_curves_figure(fold: FoldEntry, config: dict) -> Figure:
    """One fold's report entry in the form of :func:`curves_figure` (its column of panels), titled
    with the task, the seed and the fold (a matplotlib figure, for the fold's TensorBoard run)."""
    return _curves([fold], f"{_title(config)}, fold {fold.fold}", _incremental([fold]))


def growth_figure(report: Report) -> Figure:
    """Figure 5.19: features sampled so far against classes taught, log-log, for every fold (and
    fold 1 of every further seed of a ``--seeds`` run, in grey) with the power law a * classes**b
    fitted over the folds (the report's ``growth`` block; ``seeds.growth`` in the title)."""
    growth, config = report.growth, report.config
    figure, ax = subplots(figsize=(6.4, 4.6))
    for k, points in growth.sampled.items():
        ax.plot(*zip(*points), marker="o", markersize=3, label=f"fold {k}: b = {shown(growth.folds[k].exponent)}")
    seeds = report.seeds.growth if report.seeds is not None else None
    if seeds:
        more = seeds.seeds[1:]
        for n, points in enumerate(list(seeds.sampled.values())[1:]):
            ax.plot(*zip(*points), color="0.6", linewidth=0.8, marker=".", markersize=3, zorder=1,
                    label=f"fold {seeds.fold}, seed{'s' * (len(more) > 1)} {_span(more)}" if n == 0 else None)
    classes = np.array(sorted({c for points in growth.sampled.values() for c, _ in points}))
    if growth.exponent is not None:
        ax.plot(classes, growth.scale * classes.astype(float) ** growth.exponent, "k--", linewidth=1,
                label=f"fit a * classes^b: b = {growth.exponent:.2f}{_interval(growth.interval)}")
    ax.set_xscale("log")
    ax.set_yscale("log")
    ticks = [classes[0]]
    for c in classes[1:]:  # labels at least 0.1 apart in log(classes), the last class always
        if np.log(c / ticks[-1]) >= 0.1:
            ticks.append(c)
    ticks[-1] = classes[-1]
    ax.set_xticks(ticks, [str(c) for c in ticks], fontsize=7)
    ax.minorticks_off()
    ax.set_xlabel("classes taught")
    ax.set_ylabel("features sampled so far")
    ax.grid(alpha=0.3, which="both")
    ax.legend(fontsize=7, loc="upper left")
    title = f"{_title(config)}: figure 5.19 form"
    if seeds:
        title += f"\nb over seeds {_span(seeds.seeds)}: {shown(seeds.mean)}{_interval(seeds.interval)}"
    ax.set_title(title, fontsize=10)
    figure.tight_layout()
    return figure


def _span(seeds: list[int]) -> str:
    return f"{seeds[0]}-{seeds[-1]}" if len(seeds) > 1 else str(seeds[0])


def _interval(interval: list[float]) -> str:
    """The text " (95% low-high)", or none where too few points gave no interval."""
    low, high = interval
    return "" if low is None else f" (95% {low:.2f}-{high:.2f})"


def feature_types_figure(types: dict[str, TypeRow], title: str) -> Figure:
    """The robustness benchmark's per-type table (``average.types``) as two panels: how often each
    feature type's nodes fire on their own class per set (bars; the false-alarm rate on the other
    classes as a black tick), and how often their states flip under each perturbation."""
    kinds = sorted(types, key=lambda k: -types[k].nodes)
    sets = list(types[kinds[0]].own)
    flips = list(types[kinds[0]].flipped)
    figure, (left, right) = subplots(1, 2, figsize=(12, 5), gridspec_kw={"width_ratios": [len(sets), max(1, len(flips))]})
    width = 0.8 / len(kinds)
    for j, kind in enumerate(kinds):
        t = types[kind]
        at = np.arange(len(sets)) + (j - (len(kinds) - 1) / 2) * width
        left.bar(at, [t.own[n] or 0 for n in sets], width, label=f"{kind} ({t.nodes} node{'s' * (t.nodes != 1)})")
        left.scatter(at, [t.other[n] or 0 for n in sets], marker="_", color="k", s=60, zorder=3,
                     label="present on other classes" if j == 0 else None)
        at = np.arange(len(flips)) + (j - (len(kinds) - 1) / 2) * width
        right.bar(at, [t.flipped[n] or 0 for n in flips], width)
    left.set_xticks(range(len(sets)), sets)
    left.set_ylabel("share of own-class views where present")
    left.set_ylim(0, 1)
    left.legend(fontsize=7, loc="upper center", bbox_to_anchor=(0.5, -0.1), ncol=3)
    left.set_title("nodes present on their own class", fontsize=10)
    right.set_xticks(range(len(flips)), flips)
    right.set_ylabel("share of node states flipped vs clean")
    right.set_ylim(0, 1)
    right.set_title("nodes flipped by the perturbation", fontsize=10)
    for ax in (left, right):
        ax.grid(alpha=0.3, axis="y")
    figure.suptitle(title, fontsize=10)
    figure.tight_layout()
    return figure


METHODS = {"ftorch": ("ftorch", "o", "C0"), "sift": ("SIFT, ratio per view", "s", "C1"),
           "sift_across": ("SIFT, ratio across classes", "D", "C3"), "pixel_nn": ("pixel 1-NN", "^", "C2")}


def tradeoff_figure(result: Tradeoff, title: str) -> Figure:
    """The accuracy-per-byte front (training/recognition/tradeoff.py): mean top-1 accuracy over the
    sets, then top-1 accuracy per set, against bytes stored per class (log axis), one line per method
    through its settings in order of bytes, each point named by its setting; ftorch's accuracy of
    def. 4.6 (its open-world answer) beside its top-1, dotted; the 4 kB budget dashed."""
    sets = result.sets
    panels = [("mean over the sets", "mean"), *[(s, s) for s in sets]]
    cols = min(3, len(panels))
    rows = -(-len(panels) // cols)
    figure, axes = subplots(rows, cols, figsize=(5 * cols, 4 * rows), squeeze=False)
    for ax, (heading, key) in zip(axes.flat, panels):
        for method, (name, marker, colour) in METHODS.items():
            points = sorted((p for p in result.points if p.method == method
                             and (key == "mean" or key in p.accuracy)), key=lambda p: p.bytes_per_class)
            if not points:
                continue
            xs = [p.bytes_per_class for p in points]
            ys = [p.mean_top1 if key == "mean" else p.top1[key] for p in points]
            ax.plot(xs, ys, marker=marker, color=colour, label=f"{name}, top-1")
            if method == "ftorch":
                ax.plot(xs, [p.mean if key == "mean" else p.accuracy[key] for p in points], marker=marker,
                        color=colour, linestyle=":", fillstyle="none", label=f"{name}, accuracy (def. 4.6)")
            if key == "mean":
                for p, y in zip(points, ys):
                    ax.annotate(p.setting.replace(" keypoints", "").replace(" pixels", ""), (p.bytes_per_class, y),
                                fontsize=6, xytext=(3, -8), textcoords="offset points")
        ax.axvline(4096, color="k", linestyle="--", linewidth=0.8)
        ax.set_xscale("log")
        ax.set_ylim(0, 1.02)
        ax.set_xlabel("bytes stored per class")
        ax.set_ylabel("top-1 accuracy (ftorch: also def. 4.6)")
        ax.set_title(heading, fontsize=10)
        ax.grid(alpha=0.3)
    for ax in list(axes.flat)[len(panels):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=8, loc="lower right")
    figure.suptitle(title, fontsize=10)
    figure.tight_layout()
    return figure
