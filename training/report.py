"""Reports of a recognition run: report.json and report.md with tables in the form of 4.2, 4.3 and 4.4."""
from __future__ import annotations

import json
from pathlib import Path

import numpy as np

from .protocol import OUTCOMES

THESIS_TABLE_4_2 = {  # average rows of table 4.2 (stage 0), for comparison
    "coil": {"accuracy": .60, "correct": .50, "wrong": .08, "ambiguous": .09, "confused": 0.0, "ignorant": .33,
             "bn": 53, "different": 38, "queried": 22.1, "sampled": 691, "cycles": 7, "presentations": 420},
    "plym": {"accuracy": .59, "correct": .51, "wrong": .04, "ambiguous": .07, "confused": .01, "ignorant": .38,
             "bn": 85, "different": 57, "queried": 27.1, "sampled": 998, "cycles": 8, "presentations": 480},
}


def average(folds: list[dict], which: int) -> dict:
    """Mean over folds of the ``test`` and ``features`` blocks of stage ``which`` (0 = first, -1 = last)."""
    stages = [f["stages"][which] for f in folds]
    return {block: {k: float(np.mean([s[block][k] for s in stages])) for k in stages[0][block]}
            for block in ("test", "features")}


def build_report(config: dict, device: str, seconds: float, folds: list[dict]) -> dict:
    return {"task": config["task"], "classes": config["classes"], "seed": config["seed"], "device": device,
            "seconds": seconds, "config": config, "folds": folds,
            "average": {"stage0": average(folds, 0), "final": average(folds, -1)}}


def write_json(path: Path, report: dict) -> None:
    path.write_text(json.dumps(report, indent=2) + "\n")


def _p(value: float) -> str:
    """Proportions as in the thesis: .50, blank for zero."""
    return "" if value == 0 else f"{value:.2f}".lstrip("0") if value < 1 else f"{value:.2f}"


def _summary_row(task: str, n_classes: int, fold, test: dict, features: dict, cycles, presentations) -> str:
    cells = [task, str(n_classes), str(fold), _p(test["accuracy"]), *(_p(test[k]) for k in OUTCOMES),
             f"{features['bn']:.0f}", f"{features['different']:.0f}", f"{features['queried']:.1f}",
             f"{features['sampled']:.0f}", f"{cycles:.0f}", f"{presentations:.0f}"]
    return "| " + " | ".join(cells) + " |"


def summary_table(report: dict, which: int = 0) -> list[str]:
    """Table 4.2: accuracy, outcome proportions, feature counts, cycles and presentations per fold."""
    head = ["| task | cls. | fold | acc. | cor. | wrg. | amb. | cnf. | ign. | BN | dif. | qu'd | sp'd | cyc. | imgs. |",
            "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]
    rows, n = [], len(report["classes"])
    for f in report["folds"]:
        s = f["stages"][which]
        rows.append(_summary_row(report["task"], n, f["fold"], s["test"], s["features"], s["cycles"], s["presentations"]))
    stages = [f["stages"][which] for f in report["folds"]]
    avg = report["average"]["stage0" if which == 0 else "final"]
    rows.append(_summary_row(report["task"], n, "avg.", avg["test"], avg["features"],
                             np.mean([s["cycles"] for s in stages]), np.mean([s["presentations"] for s in stages])))
    thesis = THESIS_TABLE_4_2.get(report["task"])
    if thesis and which == 0:
        rows.append(_summary_row(f"{report['task']} (thesis)", n, "avg.", thesis, thesis, thesis["cycles"], thesis["presentations"]))
    return head + rows


def confusion_table(rows: dict, classes: list, proportions: bool = False) -> list[str]:
    """Table 4.3: recognized-as counts for correct/wrong results, amb./cnf./ign., features per class."""
    head = ["| class | " + " | ".join(classes) + " | amb. | cnf. | ign. | # feats. BN |",
            "|---" * (len(classes) + 5) + "|"]
    out, total = [], None

    def fmt(v):
        return _p(v) if proportions else ("" if v == 0 else str(int(v)))

    for c in classes:
        r = rows[c]
        n = sum(r["as"].values()) + r["ambiguous"] + r["confused"] + r["ignorant"] if proportions else 1
        values = [r["as"][k] / max(n, 1) for k in classes] + [r[k] / max(n, 1) for k in ("ambiguous", "confused", "ignorant")]
        total = values if total is None else [a + b for a, b in zip(total, values)]
        out.append(f"| {c} | " + " | ".join(fmt(v) for v in values) + f" | {r['features']:.0f} |")
    label = "avg." if proportions else "sum"
    scale = len(classes) if proportions else 1
    feats = np.mean([rows[c]["features"] for c in classes]) if proportions else sum(rows[c]["features"] for c in classes)
    out.append(f"| {label} | " + " | ".join(fmt(v / scale) if proportions else str(int(v)) for v in total) + f" | {feats:.0f} |")
    return head + out


def ambiguity_table(rows: dict, classes: list) -> list[str]:
    """Table 4.4: for ambiguous results, how often each class (diagonal) and its false positives occurred."""
    head = ["| class | " + " | ".join(classes) + " |", "|---" * (len(classes) + 1) + "|"]
    out = []
    for c in classes:
        cells = [(f"*{rows[c]['ambiguous']}*" if rows[c]["ambiguous"] else "") if k == c else
                 (str(rows[c]["ambiguous_with"][k]) if rows[c]["ambiguous_with"][k] else "") for k in classes]
        out.append(f"| {c} | " + " | ".join(cells) + " |")
    return head + out


def averaged_rows(folds: list[dict], classes: list, which: int) -> dict:
    """Per-class confusion rows as proportions of each class's test images, averaged over folds."""
    out = {}
    for c in classes:
        rows = [f["stages"][which]["confusion"][c] for f in folds]
        totals = [max(sum(r["as"].values()) + r["ambiguous"] + r["confused"] + r["ignorant"], 1) for r in rows]
        out[c] = {"as": {k: float(np.mean([r["as"][k] / t for r, t in zip(rows, totals)])) for k in classes},
                  **{k: float(np.mean([r[k] / t for r, t in zip(rows, totals)])) for k in ("ambiguous", "confused", "ignorant")},
                  "features": float(np.mean([r["features"] for r in rows]))}
    return out


def write_markdown(path: Path, report: dict, figures: list[str]) -> None:
    classes = report["classes"]
    lines = [f"# Recognition report: {report['task']}", "",
             f"{len(classes)} classes, seed {report['seed']}, device {report['device']}, {report['seconds']:.1f} s.", "",
             "## Summary (table 4.2 form)", "", *summary_table(report), ""]
    for f in report["folds"]:
        stage = f["stages"][0]
        lines += [f"## Fold {f['fold']}: confusion (table 4.3 form)", "", *confusion_table(stage["confusion"], classes), "",
                  f"### Fold {f['fold']}: ambiguous recognitions (table 4.4 form)", "",
                  *ambiguity_table(stage["confusion"], classes), ""]
    if len(report["folds"]) > 1:
        lines += ["## Average of the folds (proportions, table 4.3 form)", "",
                  *confusion_table(averaged_rows(report["folds"], classes, 0), classes, proportions=True), ""]
    if figures:
        lines += ["## Learned features (figures 4.7 and 4.8 form)", ""] + [f"![{Path(p).stem}]({p})" for p in figures] + [""]
    path.write_text("\n".join(lines))
