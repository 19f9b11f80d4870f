"""Summaries of grasp experiments: report.json fields (training/grasping/records.py) and report.md (6.5)."""
from __future__ import annotations

from pathlib import Path

import numpy as np

from ftorch.checkpoint import write_text
from ftorch.grasp.settings import MU0_CAP, POOR_MU0
from training.cli.devices import described

from .records import (
    ErrorSummary,
    FoldTests,
    Grasp,
    GraspReport,
    Mode,
    OnlineRun,
    PoorGrasps,
    PoorShares,
    Results,
    SeedRun,
    SeedStudy,
    Sides,
    Spread,
    Summary,
)

UNPREDICTED_DEG = 180.0  # an image without a present feature counts as the worst error


def summary(values, cap: float | None = None) -> Summary:
    """median, mean and 90th percentile (``cap`` bounds values, infinite or missing ones included)."""
    data = np.array([np.inf if v is None else v for v in values], dtype=float)
    if cap is not None:
        data = np.minimum(data, cap)
    if len(data) == 0:
        return Summary(None, None, None, 0)
    return Summary(float(np.median(data)), float(np.mean(data)), float(np.quantile(data, 0.9)), int(len(data)))


def poor_fraction(grasps: list[Grasp]) -> float:
    return float(np.mean([g.mu0 is None or g.mu0 > POOR_MU0 for g in grasps])) if grasps else 0.0


def _sides(haptic: list[Grasp], cued: list[Grasp], value, cap: float | None = None) -> Sides:
    """Summaries of ``value`` of each grasp, haptic-only and cued."""
    return Sides(summary([value(g) for g in haptic], cap), summary([value(g) for g in cued], cap))


def results(evaluations: list[FoldTests]) -> Results:
    """The report's headline fields, pooled over the folds' tests."""
    errors = [e for ev in evaluations for e in ev.orientation_errors_deg]
    haptic = [g for ev in evaluations for g in ev.haptic]
    cued = [g for ev in evaluations for g in ev.cued]
    error = summary([UNPREDICTED_DEG if e is None else e for e in errors])
    poor_haptic, poor_cued = poor_fraction(haptic), poor_fraction(cued)
    poor = PoorGrasps(poor_haptic, poor_cued, POOR_MU0, 1 - poor_cued / poor_haptic if poor_haptic > 0 else None)
    fingers: dict[str, dict[str, int]] = {}
    for g in cued:
        row = fingers.setdefault(g.object, {"2": 0, "3": 0})
        row[str(g.fingers)] += 1
    return Results(ErrorSummary(error.median, error.p90, error.n, sum(e is None for e in errors)),
                   _sides(haptic, cued, lambda g: g.mu0, MU0_CAP), _sides(haptic, cued, lambda g: g.probes), poor, fingers,
                   float(np.mean([g.recommended for g in cued])) if cued else 0.0)


def _spread(values: list[float | None], seeds: list[int], worse_is_lower: bool = True) -> Spread:
    """mean, sd (0 for one value), worst value and its seed over the seeds whose value is not None
    (a reduction where a seed had no poor haptic grasps to reduce); ``n``: how many seeds count,
    ``not_available``: how many were left out. None of them: mean, sd, worst and worst_seed are None."""
    kept = [(v, s) for v, s in zip(values, seeds) if v is not None]
    n, left = len(kept), len(values) - len(kept)
    if not kept:
        return Spread(None, None, None, None, n, left)
    data = [v for v, _ in kept]
    worst = int(np.argmin(data) if worse_is_lower else np.argmax(data))
    return Spread(float(np.mean(data)), float(np.std(data, ddof=1)) if len(data) > 1 else 0.0, float(data[worst]),
                  kept[worst][1], n, left)


def reduction_words(spread: Spread, sd: str = ", sd ") -> str:
    """A seed study's poor-grasp reduction in words (report.md, the command's last lines): mean, sd
    (after ``sd``) and worst over the seeds that had poor haptic grasps to reduce, and how many had none."""
    total, left = spread.n + spread.not_available, spread.not_available
    if spread.mean is None:
        return (f"poor-grasp reduction not available (none of the {total} seeds had poor haptic grasps to reduce)" if total > 1
                else "poor-grasp reduction not available (the seed had no poor haptic grasps to reduce)")
    words = (f"poor-grasp reduction mean {spread.mean:.0%}{sd}{spread.sd:.0%}, worst {spread.worst:.0%} "
             f"(seed {spread.worst_seed}")
    if left:
        words += (f"; mean over {spread.n} of {total} seeds; {left} seed{'s' if left > 1 else ''} "
                  f"had no poor haptic grasps to reduce")
    return words + ")"


def _percent(value: float | None) -> str:
    return "n/a" if value is None else f"{value:.0%}"


def _seed_run(report: GraspReport) -> SeedRun:
    """A seed's entry in a seed study."""
    results, online = report.results, None
    if report.online is not None:
        on = report.online[Mode.ONLINE]
        online = OnlineRun(PoorShares.of(on.poor_grasp_fraction), on.orientation_error_deg)
    return SeedRun(report.config.seed, PoorShares.of(results.poor_grasp_fraction), results.orientation_error_deg,
                   results.cued_fingers, report.seconds, online)


def seed_study(reports: list[GraspReport]) -> SeedStudy:
    """The ``seeds`` block: one entry per seed's report; the mean, sd and worst seed of the poor-grasp
    reductions, of the cued poor-grasp fractions and of the median orientation errors, off-line (and
    on-line where run)."""
    runs = [_seed_run(r) for r in reports]
    seeds = [e.seed for e in runs]
    modes: dict[Mode, list] = {Mode.OFFLINE: runs}
    if all(e.online is not None for e in runs):
        modes[Mode.ONLINE] = [e.online for e in runs]
    return SeedStudy(runs,
                     {m: _spread([e.poor_grasp_fraction.reduction for e in es], seeds) for m, es in modes.items()},
                     {m: _spread([e.poor_grasp_fraction.cued for e in es], seeds, False) for m, es in modes.items()},
                     {m: _spread([e.orientation_error_deg.median for e in es], seeds, False) for m, es in modes.items()})


def grasp_columns(evaluations: list[FoldTests], experiment: str) -> dict[str, list[Grasp]]:
    """Figure 6.17 (mixed): haptic-only two- and three-finger grasps, and cued ones; figure 6.14 (the
    others): haptic-only and cued grasps per object kind."""
    haptic = [g for ev in evaluations for g in ev.haptic]
    cued = [g for ev in evaluations for g in ev.cued]
    if experiment == "mixed":
        return {"haptic, 2 fingers": [g for g in haptic if g.fingers == 2],
                "haptic, 3 fingers": [g for g in haptic if g.fingers == 3],
                "cued (fingers chosen)": cued}
    columns = {}
    for kind in dict.fromkeys(g.object for g in haptic):
        fingers = next(g.fingers for g in haptic if g.object == kind)
        columns[f"{kind}s, {fingers} fingers: haptic"] = [g for g in haptic if g.object == kind and g.fingers == fingers]
        columns[f"{kind}s: cued"] = [g for g in cued if g.object == kind and g.fingers == fingers]
    return columns


THESIS = {  # what the thesis reports in words (6.5); it gives histograms, not numbers
    "clean": "figure 6.13a: prediction errors almost always on the order of the variation in the training signal",
    "noisy": "figure 6.13b: graceful degradation; most poor recommendations on outliers",
    "cue": "figure 6.14: lengthy (> 13 probes) and poor (mu_0) grasps drastically reduced; expected probes unchanged",
    "mixed": "figure 6.17: the mu_0 mode near 0.6 almost disappears; expected probes rise slightly",
}


def _block(title: str, res: Results) -> list[str]:
    e, p, mu0, probes = res.orientation_error_deg, res.poor_grasp_fraction, res.mu0, res.probes
    reduction = _percent(p.reduction)
    return [f"### {title}", "",
            "| | haptic only | cued |", "|---|---|---|",
            f"| mu_0 median / p90 | {mu0.haptic.median:.3f} / {mu0.haptic.p90:.3f} | {mu0.cued.median:.3f} / {mu0.cued.p90:.3f} |",
            f"| probes mean / median | {probes.haptic.mean:.1f} / {probes.haptic.median:.0f} "
            f"| {probes.cued.mean:.1f} / {probes.cued.median:.0f} |",
            f"| poor grasps (mu_0 > {p.split_mu0}) | {p.haptic:.2f} | {p.cued:.2f} (reduction {reduction}) |", "",
            f"Orientation error on {e.n} test grasps: median {e.median:.1f} deg, 90th percentile {e.p90:.1f} deg "
            f"({e.unpredicted} without a prediction, counted as {UNPREDICTED_DEG:.0f} deg). "
            f"Finger counts chosen for cued grasps: {res.cued_fingers}.", ""]


def write_markdown(path: Path, report: GraspReport) -> None:
    """report.md: the results, off-line vs on-line where run, per fold, the seed study, the figures."""
    config = report.config
    lines = [f"# Grasp experiment `{config.experiment}` (chapter 6)", "",
             f"Device {report.device} ({described(report.machine)}), {report.seconds:.1f} s, "
             f"seed {config.seed}, {config.pool} simulated grasps per category, {config.best} training grasps "
             f"per category and fold, t_dtheta {config.t_dtheta_deg} deg.",
             "", f"Thesis: {THESIS[config.experiment]}.", "", *_block("Results (both folds pooled)", report.results)]
    if report.online is not None:
        lines += ["## Off-line vs on-line learning on the same objects", ""]
        lines += _block("off-line (observing the haptic system)", report.online[Mode.OFFLINE])
        lines += _block("on-line (the simulator executes the recommended grasps)", report.online[Mode.ONLINE])
    lines += ["## Per fold", "", "| fold | mode | epochs | mistakes in last epoch | features F_2 / F_3 | sampled F_2 / F_3 |",
              "|---|---|---|---|---|---|"]
    for fold in report.folds:
        last = fold.epochs[-1]
        lines.append(f"| {fold.fold} | {fold.mode} | {len(fold.epochs)} | {last.mistakes:.2f} | "
                     f"{last.features_2} / {last.features_3} | {last.sampled_2} / {last.sampled_3} |")
    if report.seeds is not None:
        lines += ["", *_seed_table(report.seeds)]
    lines += ["", *[f"![{Path(f).stem}]({f})" for f in report.figures], ""]
    write_text(path, "\n".join(lines))


def _seed_table(study: SeedStudy) -> list[str]:
    """Per seed: poor-grasp fractions and reduction, orientation error; then the reductions' spread."""
    online = Mode.ONLINE in study.reduction
    head = "| seed | poor haptic | poor cued | reduction | error median / p90 (deg) | squares cued with 3 fingers |"
    head += " on-line poor cued | on-line reduction |" if online else ""
    lines = [f"## Seeds {study.runs[0].seed}-{study.runs[-1].seed}", "", head, "|---" * (8 if online else 6) + "|"]
    for e in study.runs:
        p, err = e.poor_grasp_fraction, e.orientation_error_deg
        squares = e.cued_fingers.get("square", {})
        row = (f"| {e.seed} | {p.haptic:.2f} | {p.cued:.2f} | {_percent(p.reduction)} | "
               f"{err.median:.1f} / {err.p90:.1f} | {squares.get('3', 0)} of {sum(squares.values())} |")
        if online and e.online is not None:
            q = e.online.poor_grasp_fraction
            row += f" {q.cued:.2f} | {_percent(q.reduction)} |"
        lines.append(row)
    lines.append("")
    for mode, r in study.reduction.items():
        cued, error = study.poor_cued[mode], study.error_median_deg[mode]
        lines.append(f"{mode}: {reduction_words(r)}; poor cued mean {cued.mean:.2f}, worst {cued.worst:.2f} (seed "
                     f"{cued.worst_seed}); median orientation error mean {error.mean:.1f} deg, worst "
                     f"{error.worst:.1f} deg (seed {error.worst_seed}).")
    return lines
