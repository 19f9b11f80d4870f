"""Figure 5.1 (and 5.11 for incremental tasks) as a PNG drawn with OpenCV: per fold, against the
stage, the test outcome proportions with t_KSD written at each stage (boxed where the target was
met), the feature counts, and the features sampled so far."""
from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from ftorch.draw import PALETTE, grid, save_rgb, titled

WIDTH, HEIGHT, MARGIN = 420, 200, 44
FONT = cv2.FONT_HERSHEY_SIMPLEX


def put_text(canvas, text: str, at: tuple[int, int], scale: float = 0.38, colour=(0, 0, 0)) -> None:
    cv2.putText(canvas, text, at, FONT, scale, colour, 1, cv2.LINE_AA)


def line_panel(xs: list[float], series: dict[str, list[float]], top: float | None = None,
               notes: list[tuple[str, bool]] | None = None) -> np.ndarray:
    """One line chart: named series against ``xs`` on a shared y axis from 0 to ``top`` (default:
    the largest value), a legend, and optional per-x notes (boxed where flagged)."""
    canvas = np.full((HEIGHT, WIDTH, 3), 255, np.uint8)
    left, right, upper, lower = MARGIN, WIDTH - 10, 18 if notes else 8, HEIGHT - 28
    values = [v for ys in series.values() for v in ys]
    top = top or max(max(values, default=1.0), 1e-9)
    span = max(max(xs) - min(xs), 1) if xs else 1

    def point(x, y) -> tuple[int, int]:
        return (int(left + (x - min(xs)) / span * (right - left)), int(lower - y / top * (lower - upper)))

    cv2.rectangle(canvas, (left, upper), (right, lower), (150, 150, 150), 1)
    for k in range(5):
        y = top * k / 4
        put_text(canvas, f"{y:.2f}" if top <= 1 else f"{y:.0f}", (2, point(min(xs), y)[1] + 4))
    for x in xs:
        put_text(canvas, str(int(x)), (point(x, 0)[0] - 4, lower + 13))
    for n, (name, ys) in enumerate(series.items()):
        colour = PALETTE[n % len(PALETTE)]
        pts = np.array([point(x, y) for x, y in zip(xs, ys)], np.int32)
        cv2.polylines(canvas, [pts], False, colour, 1, cv2.LINE_AA)
        for p in pts:
            cv2.circle(canvas, tuple(int(v) for v in p), 2, colour, -1, cv2.LINE_AA)
        put_text(canvas, name, (right - 70, upper + 12 + 11 * n), colour=colour)
    for x, (note, flagged) in zip(xs, notes or []):
        at = (min(point(x, 0)[0] - 10, WIDTH - 28), upper - 5)
        put_text(canvas, note, at, 0.32)
        if flagged:
            cv2.rectangle(canvas, (at[0] - 2, at[1] - 9), (at[0] + 24, at[1] + 3), (0, 0, 0), 1)
    return canvas


def fold_curves(fold: dict) -> np.ndarray:
    """The three panels of figure 5.1 for one fold, stacked."""
    stages = fold["stages"]
    xs = [s["step"] for s in stages]
    notes = [(f"{s['t_ksd']:.2f}".lstrip("0") if 0 < s["t_ksd"] < 1 else f"{s['t_ksd']:.0f}", s["target_met"]) for s in stages]
    outcomes = {k: [s["test"][k] for s in stages] for k in ("accuracy", "correct", "ambiguous", "ignorant", "wrong")}
    features = {"BN": [s["features"]["bn"] for s in stages], "different": [s["features"]["different"] for s in stages],
                "queried": [s["features"]["queried"] for s in stages]}
    sampled = {"sampled": [s["features"]["sampled"] for s in stages]}
    panels = [titled(line_panel(xs, outcomes, 1.0, notes), f"fold {fold['fold']}: test results (t_KSD above; boxed: met)"),
              titled(line_panel(xs, features), "features in the networks, different, queried per recognition"),
              titled(line_panel(xs, sampled), "features sampled (cumulative)")]
    if "classes" in stages[0] and stages[0]["classes"] != stages[-1]["classes"]:
        panels.append(titled(line_panel(xs, {"classes": [s["classes"] for s in stages]}), "classes taught"))
    return np.concatenate(panels, axis=0)


def write_curves(out: Path, report: dict) -> Path:
    """``out``/curves.png: the folds' curves side by side."""
    path = out / "curves.png"
    save_rgb(path, grid([fold_curves(f) for f in report["folds"]], len(report["folds"])))
    return path
