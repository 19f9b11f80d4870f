"""The accuracy-per-byte front: what each method stores per class against what it recognizes.

The method exists for few features, each worth its bytes (7.2.4); this benchmark measures that,
on the same splits and the same perturbed test views for every method:

- **ftorch**: every learner of one or more ``recognize`` runs (each seed's folds), packed as
  binary (:mod:`ftorch.recognition.packing`: features' parameters, cut-points, CPTs) and
  recognized back from exactly those bytes; one point per run (the runs differ in the options
  that set how much a learner keeps, e.g. ``--redundancy``).
- **SIFT matching** keeping the n strongest keypoints of each training view, n = 1, 2, 4, ...,
  all (queries use all of theirs); one byte per descriptor entry. Two forms (``SiftMatcher``):
  Lowe's ratio test per training view (``sift``, the robustness benchmark's peer) and across
  classes (``sift_across``, Lowe 2004 section 7.1), which holds up with few keypoints per view.
- **pixel 1-NN** on 8-bit images area-averaged to s x s pixels, s = 4, 8, 16, 32 (below the
  stored size), and as stored.
  As stored it cannot compare a two-object image of another size: its mean is over the sets it
  answers (flagged).

The test views are perturbed as the robustness benchmark perturbs them (same seed, same images).
Every learner weighs 1 / (seeds x its seed's folds), so each seed counts once; a peer's figure on a
fold weighs what the learners of that fold weigh, so peers and learners see the same splits in the
same proportions. Every method is scored by top-1 accuracy (one label per image: the learner's top
label, each peer's best class) and by def. 4.6's accuracy beside it; the methods are compared on
top-1, the one answer every method gives: a method's figure at a budget is its best mean top-1
accuracy within that many bytes per class.
"""
from __future__ import annotations

import json
import time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ftorch.errors import InputError
from ftorch.recognition.environment import ImageSet
from ftorch.recognition.learner import DistinctiveFeatureLearner
from ftorch.recognition.packing import pack, unpack
from ftorch.space.record import FeatureSpace
from training.records import OPTIONAL, Record

from ..data.datasets import Task
from .peers import PixelNN, SiftMatcher, score, score_ranked, sift_descriptors
from .protocol import RecordedTask, RunConfig, same_images, test_block
from .records import TestBlock, recognize_run
from .robustness import fold_sets, views

SIDES = (4, 8, 16, 32, None)  # pixel 1-NN image sides; None: as stored
BUDGETS = (256, 512, 1024, 2048, 4096, 8192, 16384)  # bytes per class in the budget table
METHODS = ("ftorch", "sift", "sift_across", "pixel_nn")
SIFTS = ("sift", "sift_across")  # the ratio test per training view, across classes (SiftMatcher)
TASK_KEYS = ("task", "data", "classes", "views", "size", "first_view")


@dataclass
class Point(Record):
    """One method at one setting: bytes stored per class, accuracy (def. 4.6) and top-1 accuracy per
    set, weighted over the learners' seeds and folds; ``mean`` and ``mean_top1`` over the sets it
    answers (``answered``)."""
    method: str
    setting: str
    bytes_per_class: float
    accuracy: dict[str, float]
    mean: float
    answered: int
    top1: dict[str, float]
    mean_top1: float


@dataclass
class BudgetRow(Record):
    """One budget (bytes per class): each method's best point within it, and whether ftorch's top-1
    accuracy is at or above every peer's (None: ftorch has no point within it)."""
    budget: int
    ftorch: Point | None
    sift: Point | None
    sift_across: Point | None
    pixel_nn: Point | None
    ftorch_leads: bool | None


@dataclass
class LearnerRow(Record):
    """One learner packed and recognized back: its run, setting, seed, fold, weight, bytes per class,
    network nodes, and accuracy (def. 4.6) and top-1 accuracy per set."""
    run: str
    setting: str
    seed: int
    fold: int
    weight: float
    bytes_per_class: float
    features: int
    accuracy: dict[str, float]
    top1: dict[str, float]


@dataclass
class Tradeoff(Record):
    """tradeoff.json: the runs, their task, the sets, the perturbations' seed, the folds' weights, every
    point, the budget table, every learner, the seconds taken and the machine."""
    runs: list[str]
    task: str
    data: str | None
    classes: list
    sets: list[str]
    seed: int
    fold_weights: dict[int, float]
    points: list[Point]
    budgets: list[BudgetRow]
    learners: list[LearnerRow]
    seconds: float
    machine: dict | None = field(default=None, metadata=OPTIONAL)


@dataclass
class Learner:
    """One learner of a run: its seed, fold, file and weight (module doc)."""
    run: Path
    seed: int
    fold: int
    path: Path
    weight: float = 0.0


def run_learners(run: Path) -> tuple[dict, list[Learner]]:
    """A recognize run's config and every learner it wrote (seed 0's folds, the other seeds' fold 1)."""
    with recognize_run(run, "--runs") as (report, config):
        folds = [int(f.fold) for f in report.folds]
        seeds = [int(s) for s in (report.seeds.seeds if report.seeds is not None else [report.seed])]
    learners = [Learner(run, seeds[0], k, run / f"fold{k}" / "learner.json") for k in folds]
    learners += [Learner(run, s, 1, run / f"seed{s}" / "fold1" / "learner.json") for s in seeds[1:]]
    for learner in learners:
        if not learner.path.is_file():
            raise InputError(f"--runs {run}: {learner.path} is missing (an unfinished run?)")
    per_seed = {s: sum(1 for x in learners if x.seed == s) for s in seeds}
    for learner in learners:
        learner.weight = 1 / (len(seeds) * per_seed[learner.seed])
    return config, learners


def settings(configs: list[dict], runs: list[Path]) -> list[str]:
    """A name for each run: the options in which the runs differ (else the folder's name); an option
    a run's config does not record ran at its value then (``configs`` come migrated: training.recognition.schema)."""
    configs = [{**RunConfig(RecordedTask.from_json(c).task).to_dict(), **c} for c in configs]
    keys = [k for k in configs[0] if k not in ("seed", "data", "device", "images") and len({json.dumps(c.get(k)) for c in configs}) > 1]
    return [", ".join(f"{k} {c.get(k)}" for k in keys) if keys else run.name for c, run in zip(configs, runs)]


def common_task(configs: list[dict], runs: list[Path], data: str | None) -> Task:
    """The one task all runs learned (same data, classes, views, size; for Plym the same seed),
    loaded, and checked to be the images each run learned (:func:`same_images`), so the same images."""
    tasks = [RecordedTask.from_json(c) for c in configs]
    first = tasks[0]
    keys = TASK_KEYS + (("seed",) if first.task == "plym" else ())
    for recorded, run in zip(tasks[1:], runs[1:]):
        differ = [k for k in keys if getattr(recorded, k) != getattr(first, k)]
        if differ:
            raise InputError(f"--runs {run} and {runs[0]} learned different tasks ({', '.join(differ)} differ): "
                             "the front compares methods on the same splits")
    task = first.load(data)
    for recorded, run in zip(tasks, runs):
        same_images(task, recorded.images, f"--runs {run}", data or first.data)
    return task


def fold_weights(learners: list[Learner]) -> dict[int, float]:
    """What each fold's test views weigh in a run's figures (module doc)."""
    weights: dict[int, float] = {}
    for x in learners:
        weights[x.fold] = weights.get(x.fold, 0.0) + x.weight
    return weights


def common_splits(loaded: list[tuple[dict, list[Learner]]], runs: list[Path]) -> dict[int, float]:
    """The fold weights all runs share; InputError where their folds or seeds differ: a run of one
    fold, or of more seeds (whose extra seeds train fold 1 only), tests other views or weighs them
    otherwise, so its figures and the peers' would not be on the same splits."""
    first = fold_weights(loaded[0][1])
    for (_, learners), run in zip(loaded[1:], runs[1:]):
        other = fold_weights(learners)
        if {k: round(w, 9) for k, w in other.items()} != {k: round(w, 9) for k, w in first.items()}:
            shown = lambda w: ", ".join(f"fold {k} {v:.2f}" for k, v in sorted(w.items()))  # noqa: E731
            raise InputError(f"--runs {run} and {runs[0]} did not test on the same splits (test views weighted "
                             f"{shown(other)} against {shown(first)}): give runs of the same --folds and --seeds")
    return first


def keypoint_budgets(largest: int) -> list[int | None]:
    """n = 1, 2, 4, ... below the largest keypoint count of a training view, then all (None)."""
    out, n = [], 1
    while n < largest:
        out.append(n)
        n *= 2
    return out + [None]


def packed(learner: DistinctiveFeatureLearner) -> tuple[DistinctiveFeatureLearner, float]:
    """The learner answering from its packed networks, and their bytes per class."""
    data = pack(learner.networks)
    learner.networks = unpack(data, list(learner.networks))
    return learner, len(data) / max(1, len(learner.networks))


def _point(method: str, setting: str, blocks: list[tuple[float, float, dict[str, TestBlock]]], sets: list[str]) -> Point:
    """A point from (weight, bytes per class, set -> test block) per learner or fold: its accuracy (def. 4.6)
    and top-1 accuracy weighted over them."""
    total = sum(w for w, _, _ in blocks)
    spent = sum(w * b for w, b, _ in blocks) / total
    answered = [s for s in sets if all(s in scores for _, _, scores in blocks)]

    def mean(figure) -> dict[str, float]:  # figure: of a test block
        return {s: sum(w * figure(scores[s]) for w, _, scores in blocks) / total for s in answered}

    accuracy, top1 = mean(lambda b: b.accuracy), mean(lambda b: b.top1)
    return Point(method, setting, spent, accuracy, float(np.mean(list(accuracy.values()))), len(answered),
                 top1, float(np.mean(list(top1.values()))))


def peer_points(task: Task, fold_weights: dict[int, float], kinds: list[str], seed: int, progress: bool) -> list[Point]:
    """SIFT at every keypoint budget and pixel 1-NN at every side, per fold on the same images."""
    classes = task.classes()
    blocks: dict[tuple[str, str], list] = {}
    for k, weight in fold_weights.items():
        train, test = task.fold(k)
        training = views(task, train)
        sets = fold_sets(*views(task, test), kinds, seed * 1000 + k)
        queries = {name: [sift_descriptors(x) for x in images] for name, (images, _) in sets.items()}
        found = [sift_descriptors(x) for x in training[0]]
        for method in SIFTS:
            full = SiftMatcher(across_classes=method == "sift_across").fit(*training, found)
            for n in keypoint_budgets(int(full.counts.max())):
                sift = full if n is None else full.strongest(n)
                acc = {name: score_ranked(sift.ranked(images, max(len(names) for names in labels), queries[name]), labels, classes)
                       for name, (images, labels) in sets.items()}
                blocks.setdefault((method, "all keypoints" if n is None else f"{n} keypoint{'s' * (n != 1)}"), []).append(
                    (weight, sift.storage_per_class(), acc))
        for side in [s for s in SIDES if s is None or s < min(training[0][0].shape)]:
            nn = PixelNN(side).fit(*training)
            acc = {name: score(nn.predict(images), labels, classes)
                   for name, (images, labels) in sets.items() if all(nn.supports(x.shape) for x in images)}
            shape = "x".join(map(str, training[0][0].shape)) if side is None else f"{side}x{side}"
            blocks.setdefault(("pixel_nn", f"{shape} pixels"), []).append((weight, nn.storage_per_class(), acc))
        if progress:
            print(f"peers: fold {k} done")
    return [_point(method, setting, b, ["clean", *[s for s in kinds if s != "clean"]]) for (method, setting), b in blocks.items()]


def learner_points(task: Task, runs: list[tuple[str, list[Learner]]], kinds: list[str], seed: int, space: FeatureSpace,
                   progress: bool) -> tuple[list[Point], list[LearnerRow]]:
    """Every run's learners, packed and recognized back, on every fold's sets: one point per run,
    and a row per learner."""
    classes = task.classes()
    rows, blocks = [], {setting: [] for setting, _ in runs}
    for k in sorted({x.fold for _, learners in runs for x in learners}):
        _, test = task.fold(k)
        sets = fold_sets(*views(task, test), kinds, seed * 1000 + k)
        envs = {name: ImageSet(images, labels, space, progress=progress) for name, (images, labels) in sets.items()}
        for setting, learners in runs:
            for x in (x for x in learners if x.fold == k):
                learner, spent = packed(DistinctiveFeatureLearner.load(x.path))
                acc = {name: test_block(learner.recognize_many(env, range(len(env))), env.labels, classes)
                       for name, env in envs.items()}
                blocks[setting].append((x.weight, spent, acc))
                rows.append(LearnerRow(str(x.run), setting, x.seed, k, x.weight, spent,
                                       sum(len(n.features) for n in learner.networks.values()),
                                       {name: a.accuracy for name, a in acc.items()}, {name: a.top1 for name, a in acc.items()}))
        del envs
    return [_point("ftorch", setting, b, list(kinds)) for setting, b in blocks.items()], rows


def best_within(points: list[Point], method: str, budget: float) -> Point | None:
    """The method's point of highest mean top-1 accuracy storing at most ``budget`` bytes per class."""
    within = [p for p in points if p.method == method and p.bytes_per_class <= budget]
    return max(within, key=lambda p: p.mean_top1, default=None)


def budget_rows(points: list[Point]) -> list[BudgetRow]:
    """Per budget: each method's best point within it, and whether ftorch is at or above every peer
    (top-1 accuracy)."""
    rows = []
    for budget in BUDGETS:
        best = {m: best_within(points, m, budget) for m in METHODS}
        ours = best["ftorch"]
        rows.append(BudgetRow(budget, **best, ftorch_leads=None if ours is None else all(p is None or ours.mean_top1 >= p.mean_top1
                                                                                      for m, p in best.items() if m != "ftorch")))
    return rows


def tradeoff(runs: list[Path], kinds: list[str], seed: int, space: FeatureSpace, data: str | None,
             progress: bool) -> Tradeoff:
    """The whole benchmark (module doc) as a JSON-ready result."""
    start = time.perf_counter()
    loaded = [run_learners(run) for run in runs]
    configs = [c for c, _ in loaded]
    task = common_task(configs, runs, data)
    named = list(zip(settings(configs, runs), [learners for _, learners in loaded]))
    weights = common_splits(loaded, runs)
    ours, rows = learner_points(task, named, kinds, seed, space, progress)
    peers = peer_points(task, weights, kinds, seed, progress)
    points = ours + peers
    first = RecordedTask.from_json(configs[0])
    return Tradeoff([str(r) for r in runs], first.task, data or first.data, first.classes, kinds, seed, weights, points,
                    budget_rows(points), rows, time.perf_counter() - start)


def _flag(point: Point, sets: int) -> str:
    return "" if point.answered == sets else f" ({point.answered} of {sets} sets)"


def table(result: Tradeoff) -> list[str]:
    """Markdown: every point (bytes per class, top-1 accuracy / accuracy (def. 4.6) per set, their
    means), then the budget table (best mean top-1 accuracy, def. 4.6's beside it)."""
    sets, n = result.sets, len(result.sets)
    lines = ["Each cell: top-1 accuracy / accuracy (def. 4.6); the methods are compared on top-1.", "",
             "| method | setting | bytes per class | " + " | ".join(sets) + " | mean |", "|---|---|---|" + "---|" * (n + 1)]
    for p in sorted(result.points, key=lambda p: (p.method, p.bytes_per_class)):
        lines.append(f"| {p.method} | {p.setting} | {p.bytes_per_class:,.0f} | "
                     + " | ".join(f"{p.top1[s]:.2f} / {p.accuracy[s]:.2f}" if s in p.accuracy else "n/a" for s in sets)
                     + f" | {p.mean_top1:.2f} / {p.mean:.2f}{_flag(p, n)} |")
    lines += ["", "Best mean top-1 accuracy within each budget (bytes per class; accuracy (def. 4.6) after the slash):", "",
              "| budget | ftorch | SIFT, ratio per view | SIFT, ratio across classes | pixel 1-NN | ftorch at or above every peer |",
              "|---|---|---|---|---|---|"]
    for row in result.budgets:
        best = [getattr(row, m) for m in METHODS]
        cells = [("—" if p is None else f"{p.mean_top1:.2f} / {p.mean:.2f} ({p.setting}){_flag(p, n)}") for p in best]
        lead = {None: "—", True: "yes", False: "no"}[row.ftorch_leads]
        lines.append(f"| {row.budget:,} | " + " | ".join(cells) + f" | {lead} |")
    return lines
