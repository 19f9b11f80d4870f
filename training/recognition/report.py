"""Reports of a recognition run: report.json and report.md with tables in the form of 4.2-4.4
(stage 0) and 5.1-5.3 (after expert learning), every stage, incremental tasks and seed studies."""
from __future__ import annotations

import json
import math
import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from scipy import stats

from ftorch.checkpoint import write_text
from ftorch.recognition.inference import Outcome
from training.cli.devices import described

from .protocol import RunConfig
from .records import (
    Averages,
    ConfusionRow,
    FeatureBlock,
    FoldEntry,
    Growth,
    PowerFit,
    Report,
    SeedGrowth,
    SeedStudy,
    Spread,
    StageAverage,
    StageEntry,
    TestBlock,
    mean_block,
)
from .schema import SCHEMA


@dataclass(frozen=True)
class ThesisRow:
    """An average row of the thesis's tables 4.2 and 5.1: its test and feature blocks (no top-1: the
    thesis reports none), cycles and presentations (NaN: not given)."""

    test: TestBlock
    features: FeatureBlock
    cycles: float
    presentations: float


def _thesis(accuracy, correct, wrong, ambiguous, confused, ignorant, bn, different, queried, sampled, cycles,
            presentations) -> ThesisRow:
    return ThesisRow(TestBlock(accuracy=accuracy, correct=correct, wrong=wrong, ambiguous=ambiguous, confused=confused,
                               ignorant=ignorant), FeatureBlock(bn, different, queried, sampled), cycles, presentations)


THESIS_TABLE_4_2 = {  # average rows of table 4.2 (stage 0), for comparison
    "coil": _thesis(.60, .50, .08, .09, 0.0, .33, 53, 38, 22.1, 691, 7, 420),
    "plym": _thesis(.59, .51, .04, .07, .01, .38, 85, 57, 27.1, 998, 8, 480),
}

THESIS_TABLE_5_1 = {  # average rows of table 5.1 (after expert learning); "-inc6" etc. are the incremental tasks
    "coil": _thesis(.82, .74, .03, .13, 0.0, .10, 17, 13, 8.8, 19326, 64, 3840),
    "coil-inc6": _thesis(.87, .81, .01, .11, 0.0, .08, 9, 9, 6.0, 15679, math.nan, 8925),
    "coil-inc10": _thesis(.81, .75, .01, .09, .01, .15, 31, 19, 12.7, 78723, math.nan, 50290),
    "plym": _thesis(.75, .67, .05, .15, 0.0, .13, 17, 14, 8.7, 29612, 139, 8244),
    "plym-inc8": _thesis(.80, .76, .02, .07, 0.0, .16, 19, 11, 7.9, 49631, math.nan, 25957),
}


def thesis_key(report: Report) -> str:
    """Key of the thesis's row for this run in THESIS_TABLE_5_1."""
    return f"{report.task}-inc{len(report.classes)}" if report.incremental else report.task


def average(folds: list[FoldEntry], which: int) -> StageAverage:
    """Mean over folds of the ``test`` and ``features`` blocks of stage ``which`` (0 = first, -1 = last);
    NaN (null, n/a) for a figure some fold's stage lacks, None where every one lacks it: ``top1`` of a
    stage tested before top-1 was reported, in a fold resumed from such a checkpoint (:func:`without_top1`)."""
    stages = [f.stages[which] for f in folds]
    return StageAverage(mean_block([s.test for s in stages]), mean_block([s.features for s in stages]))


def without_top1(folds: list[FoldEntry], names: list[str] | None = None) -> list[str]:
    """"NAME stage S" for every stage of ``folds`` (named ``names``, default "fold K") whose test block has
    no top-1 accuracy: one tested before ftorch reported it, kept by a fold resumed from a checkpoint
    of that version."""
    names = [f"fold {f.fold}" for f in folds] if names is None else names
    return [f"{name} stage {s.stage.stage}" for f, name in zip(folds, names) for s in f.stages if s.test.top1 is None]


def top1_note(folds: list[FoldEntry], names: list[str] | None = None) -> str | None:
    """One line naming the stages without top-1 accuracy (:func:`without_top1`), or None where every stage has it."""
    missing = without_top1(folds, names)
    if not missing:
        return None
    return (f"top-1 accuracy is not available (n/a) for {', '.join(missing)}: tested before ftorch reported it "
            "(resumed from an older checkpoint); train afresh for it")


def build_report(config: RunConfig, device: str, machine: dict, seconds: float, folds: list[FoldEntry],
                 seeds: SeedStudy | None = None) -> Report:
    return Report(config.task, list(config.classes), config.seed, device, machine, seconds, config.to_dict(), folds,
                  Averages(average(folds, 0), average(folds, -1)), seeds,
                  growth(folds) if folds and all(f.added for f in folds) else None, schema=SCHEMA)


def growth(folds: list[FoldEntry]) -> Growth:
    """Figure 5.19: features sampled so far against the number of classes taught, and the exponent b
    of sampled ~ a * classes**b fitted by least squares on log-log over the points of every fold
    (each fold's own fit too), with a 95% interval from the slope's standard error (t, n - 2 df)."""
    curves = {f.fold: _sampled_curve(f) for f in folds}
    pooled = _power_fit([p for points in curves.values() for p in points])
    return Growth({str(k): v for k, v in curves.items()}, {str(k): _power_fit(v) for k, v in curves.items()},
                  pooled.exponent, pooled.interval, pooled.scale, pooled.points)


def _sampled_curve(fold: FoldEntry) -> list[tuple[int, int]]:
    """(classes taught, features sampled so far) after each added class of an incremental fold."""
    return [(a.classes, int(total)) for a, total in zip(fold.added, np.cumsum([a.sampled for a in fold.added]))]


def _power_fit(points: list[tuple[int, int]]) -> PowerFit:
    """Least-squares line on log-log: its slope b, its scale a = exp(intercept) and a 95% interval of
    b from the slope's standard error. Not available (None) with fewer than two class counts (an
    incremental run of two classes has one), and the interval not with fewer than three points."""
    if len({p[0] for p in points}) < 2:
        return PowerFit(None, [None, None], None, len(points))
    x, y = np.log([p[0] for p in points]), np.log([max(p[1], 1) for p in points])
    line = stats.linregress(x, y)
    half = float(stats.t.ppf(0.975, len(points) - 2) * line.stderr) if len(points) > 2 else None
    return PowerFit(float(line.slope), [None, None] if half is None else [float(line.slope) - half, float(line.slope) + half],
                    float(np.exp(line.intercept)), len(points))


def growth_over_seeds(runs: list[FoldEntry], seeds: list[int]) -> SeedGrowth:
    """Figure 5.19's exponent b of one incremental fold trained with several seeds: each seed's own
    fit (:func:`_power_fit`), their mean and a 95% t-interval of the mean over seeds (n - 1 df), the
    spread that a single run's slope interval does not show."""
    curves = [_sampled_curve(r) for r in runs]
    exponents = [_power_fit(c).exponent for c in curves]
    mean, interval = None, [None, None]  # not available where a seed's fit is not
    if None not in exponents:
        mean = float(np.mean(exponents))
        half = float(stats.t.ppf(0.975, len(runs) - 1) * np.std(exponents, ddof=1) / math.sqrt(len(runs)))
        interval = [mean - half, mean + half]
    return SeedGrowth(seeds, runs[0].fold, exponents, mean, interval, {str(k): c for k, c in zip(seeds, curves)})


def seed_study(runs: list[FoldEntry], seeds: list[int]) -> SeedStudy:
    """Figure 5.5: novice (stage 0) vs expert (final stage) test accuracy and features queried of one
    fold trained with several seeds; a paired one-tailed t-test of expert > novice accuracy. In an
    incremental run the novice is stage 0 of the last class added, so both face every class."""
    novices = [_novice(r) for r in runs]
    experts = [r.stages[-1] for r in runs]
    novice = np.array([s.test.accuracy for s in novices])
    expert = np.array([s.test.accuracy for s in experts])
    test = stats.ttest_rel(expert, novice, alternative="greater")

    def spread(values) -> Spread:
        return Spread([float(v) for v in values], float(np.mean(values)), float(np.std(values, ddof=1)))

    def top1(stages: list[StageEntry]) -> Spread:  # NaN: a stage without it (without_top1)
        return spread([math.nan if s.test.top1 is None else s.test.top1 for s in stages])

    return SeedStudy(seeds=seeds, fold=runs[0].fold, novice=spread(novice), expert=spread(expert), novice_top1=top1(novices),
                     expert_top1=top1(experts), novice_queried=spread([s.features.queried for s in novices]),
                     expert_queried=spread([s.features.queried for s in experts]), t=float(test.statistic), p=float(test.pvalue))


def _novice(run: FoldEntry) -> StageEntry:
    """The run's first stage with its final class count: stage 0, or in an incremental run (alg. 5.4)
    stage 0 of the last class added."""
    final = run.stages[-1].stage.classes
    return next(s for s in run.stages if s.stage.classes == final)


def json_ready(value):
    """``value`` with every NaN or infinity replaced by None: JSON has no such numbers (Python's
    ``NaN`` is not JSON), so a figure that is not available is null in every report."""
    if isinstance(value, float):
        return value if math.isfinite(value) else None
    if isinstance(value, dict):
        return {k: json_ready(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [json_ready(v) for v in value]
    return value


def write_json(path: Path, report: dict) -> None:
    """``report`` as JSON (:func:`json_ready`: null where a figure is not available)."""
    write_text(path, json.dumps(json_ready(report), indent=2, allow_nan=False) + "\n")


def shown(value, spec: str = ".2f") -> str:
    """A figure as text: "n/a" where it is not available (None, or NaN before it is written)."""
    return "n/a" if value is None or (isinstance(value, float) and math.isnan(value)) else format(value, spec)


def _spread(spread: Spread) -> str:
    """A seed study's mean +- sd (3 decimals), n/a where not available."""
    return f"{shown(spread.mean, '.3f')} +- {shown(spread.sd, '.3f')}"


def _p(value: float | None) -> str:
    """Proportions as in the thesis: .50, blank for zero; n/a where not available (None or NaN)."""
    if value is None or math.isnan(value):
        return "n/a"
    return "" if value == 0 else f"{value:.2f}".lstrip("0") if value < 1 else f"{value:.2f}"


def cell(text) -> str:
    """``text`` as one Markdown table cell: a ``|`` escaped, a control character (a newline in a
    folder's name) written as its escape, so that a class name cannot break the table."""
    return re.sub(r"[\x00-\x1f\x7f]", lambda m: f"\\x{ord(m[0]):02x}", str(text)).replace("|", "\\|")


def _summary_row(task: str, n_classes: int, fold, test: TestBlock, features: FeatureBlock, cycles, presentations) -> str:
    cells = [task, str(n_classes), str(fold), _p(test.accuracy), _p(test.top1), *(_p(getattr(test, k)) for k in Outcome),
             f"{features.bn:.0f}", f"{features.different:.0f}", f"{features.queried:.1f}",
             f"{features.sampled:.0f}", "" if math.isnan(cycles) else f"{cycles:.0f}", f"{presentations:.0f}",
             f"{features.sampled / presentations:.1f}" if presentations else ""]
    return "| " + " | ".join(cells) + " |"


def summary_table(report: Report, which: int = 0) -> list[str]:
    """Table 4.2 (``which`` = 0) or 5.1 (-1): accuracy, top-1 accuracy beside it (n/a in the thesis's
    row: it reports none), outcome proportions, feature counts, cycles and presentations so far, per
    fold and averaged, with the thesis's average row; last, features sampled per presentation (alg.
    5.1's search, the thesis's 5.0 on COIL)."""
    head = ["| task | cls. | fold | acc. | top-1 | cor. | wrg. | amb. | cnf. | ign. | BN | dif. | qu'd | sp'd | cyc. | imgs. | "
            "sp'd/img. |", "|---" * 17 + "|"]
    rows, n = [], len(report.classes)
    task = f"{report.task}-inc" if report.incremental else report.task
    cycles = []  # all cycles up to and including the stage, as table 5.1 counts them
    for f in report.folds:
        s = f.stages[which]
        cycles.append(sum(t.stage.cycles for t in f.stages[:len(f.stages) + which + 1 if which < 0 else which + 1]))
        rows.append(_summary_row(task, n, f.fold, s.test, s.features, cycles[-1], s.stage.presentations))
    stages = [f.stages[which] for f in report.folds]
    avg = report.average.stage0 if which == 0 else report.average.final
    rows.append(_summary_row(task, n, "avg.", avg.test, avg.features,
                             np.mean(cycles), np.mean([s.stage.presentations for s in stages])))
    thesis = THESIS_TABLE_4_2.get(report.task) if which == 0 else THESIS_TABLE_5_1.get(thesis_key(report))
    if thesis and not (which == 0 and report.incremental):
        rows.append(_summary_row(f"{task} (thesis)", n, "avg.", thesis.test, thesis.features, thesis.cycles, thesis.presentations))
    return head + rows


def stage_table(fold: FoldEntry) -> list[str]:
    """Every stage of a fold (the data of figures 5.1 and 5.11): t_KSD (bold where met), KSD_min,
    test results and feature counts."""
    head = ["| stage | classes | t_KSD | KSD_min | cycles | acc. | top-1 | cor. | wrg. | amb. | cnf. | ign. | BN | dif. | qu'd | "
            "sp'd |", "|---" * 16 + "|"]
    rows = []
    for entry in fold.stages:
        s, test, features = entry.stage, entry.test, entry.features
        t = f"{s.t_ksd:.3f}"
        cells = [str(s.stage), str(s.classes), f"**{t}**" if s.target_met else t, f"{s.ksd_min:.3f}",
                 str(s.cycles), _p(test.accuracy), _p(test.top1), *(_p(getattr(test, k)) for k in Outcome),
                 str(features.bn), str(features.different), f"{features.queried:.1f}", str(features.sampled)]
        rows.append("| " + " | ".join(cells) + " |")
    return head + rows


def added_table(folds: list[FoldEntry]) -> list[str]:
    """Figure 5.13's data: features sampled and stages taken while each class was added."""
    head = ["| classes | class | " + " | ".join(f"fold {f.fold} sp'd | fold {f.fold} stages" for f in folds) + " |",
            "|---" * (2 + 2 * len(folds)) + "|"]
    rows = []
    for n, first in enumerate(folds[0].added):
        cells = [str(first.classes), cell(first.label)]
        for f in folds:
            cells += [str(f.added[n].sampled), str(f.added[n].stages)]
        rows.append("| " + " | ".join(cells) + " |")
    return head + rows


def confusion_table(rows: dict[Any, ConfusionRow], classes: list, proportions: bool = False) -> list[str]:
    """Table 4.3: recognized-as counts for correct/wrong results, amb./cnf./ign., features per class."""
    head = ["| class | " + " | ".join(map(cell, classes)) + " | amb. | cnf. | ign. | # feats. BN |",
            "|---" * (len(classes) + 5) + "|"]
    out, total = [], None

    def fmt(v):
        return _p(v) if proportions else ("" if v == 0 else str(int(v)))

    for c in classes:
        r = rows[c]
        n = r.total() if proportions else 1
        values = [r.recognized_as[k] / n for k in classes] + [v / n for v in (r.ambiguous, r.confused, r.ignorant)]
        total = values if total is None else [a + b for a, b in zip(total, values)]
        out.append(f"| {cell(c)} | " + " | ".join(fmt(v) for v in values) + f" | {r.features:.0f} |")
    label = "avg." if proportions else "sum"
    scale = len(classes) if proportions else 1
    feats = np.mean([rows[c].features for c in classes]) if proportions else sum(rows[c].features for c in classes)
    out.append(f"| {label} | " + " | ".join(fmt(v / scale) if proportions else str(int(v)) for v in total) + f" | {feats:.0f} |")
    return head + out


def ambiguity_table(rows: dict[Any, ConfusionRow], classes: list) -> list[str]:
    """Table 4.4: for ambiguous results, how often each class (diagonal) and its false positives occurred."""
    head = ["| class | " + " | ".join(map(cell, classes)) + " |", "|---" * (len(classes) + 1) + "|"]
    out = []
    for c in classes:
        r = rows[c]
        cells = [(f"*{r.ambiguous}*" if r.ambiguous else "") if k == c else
                 (str(r.ambiguous_with[k]) if r.ambiguous_with[k] else "") for k in classes]
        out.append(f"| {cell(c)} | " + " | ".join(cells) + " |")
    return head + out


def averaged_rows(folds: list[FoldEntry], classes: list, which: int) -> dict[Any, ConfusionRow]:
    """Per-class confusion rows as proportions of each class's test images, averaged over folds."""
    out = {}
    for c in classes:
        rows = [f.stages[which].confusion[c] for f in folds]

        def mean(count) -> float:  # of a count as a proportion of the class's test images
            return float(np.mean([count(r) / r.total() for r in rows]))

        out[c] = ConfusionRow(recognized_as={k: mean(lambda r: r.recognized_as[k]) for k in classes},
                              ambiguous=mean(lambda r: r.ambiguous), confused=mean(lambda r: r.confused),
                              ignorant=mean(lambda r: r.ignorant), features=float(np.mean([r.features for r in rows])))
    return out


def _confusion_sections(report: Report, which: int, table: str) -> list[str]:
    classes, lines = report.classes, []
    for f in report.folds:
        rows = f.stages[which].confusion
        taught = [c for c in classes if c in rows]
        lines += [f"### Fold {f.fold}: confusion (table {table[0]} form)", "", *confusion_table(rows, taught), "",
                  f"### Fold {f.fold}: ambiguous recognitions (table {table[1]} form)", "",
                  *ambiguity_table(rows, taught), ""]
    if len(report.folds) > 1:
        lines += ["### Average of the folds (proportions)", "",
                  *confusion_table(averaged_rows(report.folds, classes, which), classes, proportions=True), ""]
    return lines


COLUMNS = ("Columns, as in the thesis's tables: cls. classes; acc. accuracy (def. 4.6); top-1 (not in the thesis) the "
           "share of test views whose one label is a true class: the recognized class where one is, else alg. 4.4 "
           "continued on the recognized classes (or all, where none is) and the largest posterior; cor., wrg., amb., cnf., ign. "
           "the shares of test views recognized correct, wrong, ambiguous, confused, ignorant (def. 4.5; blank: 0); "
           "BN features in the class networks; dif. different features among them; qu'd features queried per "
           "recognition; sp'd features sampled; cyc. training cycles; imgs. training presentations; sp'd/img. "
           "features sampled per presentation; # feats. BN a class's network size. Confusion rows: a class's test "
           "views by what they were recognized as.")


def failing_section(folds: list[FoldEntry]) -> list[str]:
    """The training images the search failed on again and again (alg. 4.8, 5.1), per fold and stage:
    which image, which classes, how many searches; nothing where there are none."""
    rows = [f"| {f.fold} | {s.stage.stage} | {x.name} | {x.label} | {', '.join(map(str, x.against)) or '-'} | "
            f"{x.searches} |" for f in folds for s in f.stages for x in s.stage.failing or ()]
    if not rows:
        return []
    return ["## Training images the search failed on again and again", "",
            "Searches for a feature (alg. 4.8, 5.1) that found none, twice or more in one stage for the same image and "
            "classes: the class characterized, the classes it was to be told from.", "",
            "| fold | stage | image | class | against | failed searches |", "|---|---|---|---|---|---|", *rows, ""]


def write_markdown(path: Path, report: Report, figures: list[str]) -> None:
    classes, incremental = report.classes, report.incremental
    elsewhere = [f"fold {f.fold} on {described(f.machine)}" for f in report.folds
                 if f.machine != report.machine]  # with --ray, a fold may train on another node
    memory = "; ".join(f"{task} {mib:.0f}" for task, mib in (report.gpu_memory_mib or {}).items())
    lines = [f"# Recognition report: {report.task}{' (incremental, alg. 5.4)' if incremental else ''}", "",
             f"{len(classes)} classes, seed {report.seed}, device {report.device} "
             f"({described(report.machine)}), {report.seconds:.1f} s.", "",
             *([f"Folds trained on other machines: {'; '.join(elsewhere)}.", ""] if elsewhere else []),
             *([f"Peak GPU memory per task (torch's allocator, MiB): {memory}.", ""] if memory else []), COLUMNS, "",
             *([f"Note: {top1_note(report.folds)}.", ""] if without_top1(report.folds) else [])]
    expert = any(len(f.stages) > 1 for f in report.folds)
    if not incremental:
        lines += ["## Novices: after stage 0 (table 4.2 form)", "", *summary_table(report, 0), "",
                  *_confusion_sections(report, 0, ("4.3", "4.4"))]
    if expert or incremental:
        lines += ["## After expert learning: final stage (table 5.1 form)", "", *summary_table(report, -1), "",
                  *_confusion_sections(report, -1, ("5.2", "5.3"))]
        for f in report.folds:
            lines += [f"## Fold {f.fold}: every stage (t_KSD in bold where the target was met)", "", *stage_table(f), ""]
    if incremental:
        lines += ["## Features sampled per added class (figure 5.13 form)", "", *added_table(report.folds), ""]
        if report.growth is not None:
            g = report.growth
            low, high = g.interval
            lines += ["## Growth of the features sampled with the classes (figure 5.19)", "",
                      f"sampled so far ~ classes^b: b = {shown(g.exponent)} (95% interval {shown(low)} "
                      f"to {shown(high)}, {g.points} points of all folds; b > 1 is superlinear; not "
                      "available (n/a) with fewer than two class counts, the interval with fewer than three points); "
                      "per fold: " + ", ".join(f"fold {k} {shown(v.exponent)}" for k, v in g.folds.items()), ""]
    if report.peers is not None:
        lines += _peers_section(report)
    lines += failing_section(report.folds)
    if report.seeds is not None:
        lines += _seeds_section(report.seeds)
    if figures:
        lines += ["## Figures", "", "Learned features (figures 4.7, 4.8; 5.2 after expert stages) and the stage curves "
                  "(figure 5.1 form; growth.png: figure 5.19 for incremental runs).", ""]
        lines += [f"![{Path(p).stem}]({p})" for p in figures] + [""]
    write_text(path, "\n".join(lines))


def _peers_section(report: Report) -> list[str]:
    """``recognize --peers``: pixel 1-NN and SIFT matching beside the final stage, on the same splits."""
    peers, final = report.peers.average, report.average.final
    pixels, sift = peers["pixel_nn"], peers["sift"]
    return ["## Peers on the same splits (clean test views, mean over folds; compared on top-1 accuracy)", "",
            "Each method gives one label per image (ftorch its top label); def. 4.6's accuracy scores ftorch's "
            "open-world answer, the set of classes it recognizes, as the thesis does.", "",
            "| method | top-1 accuracy | accuracy (def. 4.6) | stores per class |", "|---|---|---|---|",
            f"| ftorch (final stage) | {shown(final.test.top1)} | {final.test.accuracy:.2f} | "
            f"{final.features.bn / len(report.classes):.1f} features (network nodes) |",
            f"| pixel 1-NN | {shown(pixels.clean_top1)} | {pixels.clean:.2f} | "
            f"{pixels.views_per_class:.0f} views, {pixels.bytes_per_class / 1024:.0f} kB |",
            f"| SIFT matching (ratio 0.75) | {shown(sift.clean_top1)} | {sift.clean:.2f} | "
            f"{sift.descriptors_per_view:.0f} descriptors per view, {sift.bytes_per_class / 1024:.0f} kB |", ""]

def _seeds_section(s: SeedStudy) -> list[str]:
    """Figure 5.5's seed study, and figure 5.19's exponent over seeds where incremental."""
    lines = [f"## Seeds (figure 5.5 form): fold {s.fold}, seeds {s.seeds[0]}-{s.seeds[-1]}", "",
             "| | novice | expert |", "|---|---|---|",
             f"| accuracy, mean +- sd | {s.novice.mean:.3f} +- {s.novice.sd:.3f} | {s.expert.mean:.3f} +- {s.expert.sd:.3f} |",
             *([f"| top-1 accuracy, mean +- sd | {_spread(s.novice_top1)} | {_spread(s.expert_top1)} |"]
               if s.novice_top1 is not None and s.expert_top1 is not None else []),
             f"| features queried, mean +- sd | {s.novice_queried.mean:.1f} +- {s.novice_queried.sd:.1f} | "
             f"{s.expert_queried.mean:.1f} +- {s.expert_queried.sd:.1f} |", "",
             f"Paired one-tailed t-test, expert > novice: t = {shown(s.t)}, p = {shown(s.p, '.2g')}"
             + (" (not available: expert and novice differ by the same amount on every seed, e.g. not at all)"
                if shown(s.p) == "n/a" else "") + ".", ""]
    if s.growth is not None:
        g = s.growth
        lines += [f"Growth of the features sampled with the classes (figure 5.19), fold {g.fold}: classes^b with "
                  f"b = {shown(g.mean)} on average over the seeds (95% interval {shown(g.interval[0])} to "
                  f"{shown(g.interval[1])}); per seed: " + ", ".join(f"{k} {shown(b)}" for k, b in zip(g.seeds, g.exponents)), ""]
    return lines
