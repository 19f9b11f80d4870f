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
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np

from ftorch.errors import InputError
from ftorch.recognition.environment import ImageSet
from ftorch.recognition.learner import DistinctiveFeatureLearner
from ftorch.recognition.packing import pack, unpack
from ftorch.space.record import FeatureSpace

from ..data.datasets import Task, load_task
from .peers import PixelNN, SiftMatcher, score, score_ranked, sift_descriptors
from .protocol import BEFORE, RunConfig, same_images, test_block
from .robustness import fold_sets, views

SIDES = (4, 8, 16, 32, None)  # pixel 1-NN image sides; None: as stored
BUDGETS = (256, 512, 1024, 2048, 4096, 8192, 16384)  # bytes per class in the budget table
METHODS = ("ftorch", "sift", "sift_across", "pixel_nn")
SIFTS = ("sift", "sift_across")  # the ratio test per training view, across classes (SiftMatcher)
TASK_KEYS = ("task", "data", "classes", "views", "size", "first_view")


@dataclass
class Point:
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
class Learner:
    """One learner of a run: its seed, fold, file and weight (module doc)."""
    run: Path
    seed: int
    fold: int
    path: Path
    weight: float = 0.0


def run_learners(run: Path) -> tuple[dict, list[Learner]]:
    """A recognize run's config and every learner it wrote (seed 0's folds, the other seeds' fold 1)."""
    try:
        report = json.loads((run / "report.json").read_text())
        config = report["config"]
        folds = [int(f["fold"]) for f in report["folds"]]
        seeds = [int(s) for s in (report.get("seeds") or {}).get("seeds", [config["seed"]])]
    except (OSError, ValueError, KeyError, TypeError) as err:
        raise InputError(f"--runs {run}: not a run folder of recognize ({type(err).__name__}: {err})") from None
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
    a run's config does not record (written before the option existed) ran at its value then (``BEFORE``)."""
    configs = [{**RunConfig(c["task"]).to_dict(), **BEFORE, **c} for c in configs]
    keys = [k for k in configs[0] if k not in ("seed", "data", "device", "images") and len({json.dumps(c.get(k)) for c in configs}) > 1]
    return [", ".join(f"{k} {c.get(k)}" for k in keys) if keys else run.name for c, run in zip(configs, runs)]


def common_task(configs: list[dict], runs: list[Path], data: str | None) -> Task:
    """The one task all runs learned (same data, classes, views, size; for Plym the same seed),
    loaded, and checked to be the images each run learned (:func:`same_images`), so the same images."""
    keys = TASK_KEYS + (("seed",) if configs[0]["task"] == "plym" else ())
    for config, run in zip(configs[1:], runs[1:]):
        differ = [k for k in keys if config.get(k) != configs[0].get(k)]
        if differ:
            raise InputError(f"--runs {run} and {runs[0]} learned different tasks ({', '.join(differ)} differ): "
                             "the front compares methods on the same splits")
    c = configs[0]
    task = load_task(c["task"], data or c["data"], len(c["classes"]), c["views"], c["size"], c["seed"], c["first_view"])
    for config, run in zip(configs, runs):
        same_images(task, config, f"--runs {run}", data or c["data"])
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


def _weighted(blocks: list[tuple[float, dict]]) -> dict[str, float]:
    total = sum(w for w, _ in blocks)
    return {name: sum(w * b[name] for w, b in blocks) / total for name in blocks[0][1]}


def _point(method: str, setting: str, blocks: list[tuple[float, float, dict]], sets: list[str]) -> Point:
    """A point from (weight, bytes per class, set -> test block (its "accuracy" and "top1")) per learner or fold."""
    total = sum(w for w, _, _ in blocks)
    spent = sum(w * b for w, b, _ in blocks) / total
    answered = [s for s in sets if all(s in scores for _, _, scores in blocks)]
    mean = {key: {s: sum(w * scores[s][key] for w, _, scores in blocks) / total for s in answered} for key in ("accuracy", "top1")}
    return Point(method, setting, spent, mean["accuracy"], float(np.mean(list(mean["accuracy"].values()))), len(answered),
                 mean["top1"], float(np.mean(list(mean["top1"].values()))))


def _scores(block: dict) -> dict:
    """What a point keeps of a test block (protocol.test_block): accuracy (def. 4.6) and top-1 accuracy."""
    return {"accuracy": block["accuracy"], "top1": block["top1"]}


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
                acc = {name: _scores(score_ranked(sift.ranked(images, max(len(names) for names in labels), queries[name]),
                                                  labels, classes)) for name, (images, labels) in sets.items()}
                blocks.setdefault((method, "all keypoints" if n is None else f"{n} keypoint{'s' * (n != 1)}"), []).append(
                    (weight, sift.storage_per_class(), acc))
        for side in [s for s in SIDES if s is None or s < min(training[0][0].shape)]:
            nn = PixelNN(side).fit(*training)
            acc = {name: _scores(score(nn.predict(images), labels, classes))
                   for name, (images, labels) in sets.items() if all(nn.supports(x.shape) for x in images)}
            shape = "x".join(map(str, training[0][0].shape)) if side is None else f"{side}x{side}"
            blocks.setdefault(("pixel_nn", f"{shape} pixels"), []).append((weight, nn.storage_per_class(), acc))
        if progress:
            print(f"peers: fold {k} done")
    return [_point(method, setting, b, ["clean", *[s for s in kinds if s != "clean"]]) for (method, setting), b in blocks.items()]


def learner_points(task: Task, runs: list[tuple[str, list[Learner]]], kinds: list[str], seed: int, space: FeatureSpace,
                   progress: bool) -> tuple[list[Point], list[dict]]:
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
                acc = {name: _scores(test_block(learner.recognize_many(env, range(len(env))), env.labels, classes))
                       for name, env in envs.items()}
                blocks[setting].append((x.weight, spent, acc))
                rows.append({"run": str(x.run), "setting": setting, "seed": x.seed, "fold": k, "weight": x.weight,
                             "bytes_per_class": spent, "features": sum(len(n.features) for n in learner.networks.values()),
                             "accuracy": {name: a["accuracy"] for name, a in acc.items()},
                             "top1": {name: a["top1"] for name, a in acc.items()}})
        del envs
    return [_point("ftorch", setting, b, list(kinds)) for setting, b in blocks.items()], rows


def best_within(points: list[Point], method: str, budget: float) -> Point | None:
    """The method's point of highest mean top-1 accuracy storing at most ``budget`` bytes per class."""
    within = [p for p in points if p.method == method and p.bytes_per_class <= budget]
    return max(within, key=lambda p: p.mean_top1, default=None)


def budget_rows(points: list[Point]) -> list[dict]:
    """Per budget: each method's best point within it, and whether ftorch is at or above every peer
    (top-1 accuracy)."""
    rows = []
    for budget in BUDGETS:
        best = {m: best_within(points, m, budget) for m in METHODS}
        ours = best["ftorch"]
        rows.append({"budget": budget, **{m: None if p is None else asdict(p) for m, p in best.items()},
                     "ftorch_leads": None if ours is None else all(p is None or ours.mean_top1 >= p.mean_top1
                                                                   for m, p in best.items() if m != "ftorch")})
    return rows


def tradeoff(runs: list[Path], kinds: list[str], seed: int, space: FeatureSpace, data: str | None,
             progress: bool) -> dict:
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
    return {"runs": [str(r) for r in runs], "task": configs[0]["task"], "data": data or configs[0]["data"],
            "classes": configs[0]["classes"], "sets": kinds, "seed": seed, "fold_weights": weights,
            "points": [asdict(p) for p in points], "budgets": budget_rows(points), "learners": rows,
            "seconds": time.perf_counter() - start}


def _flag(point: dict, sets: int) -> str:
    return "" if point["answered"] == sets else f" ({point['answered']} of {sets} sets)"


def table(result: dict) -> list[str]:
    """Markdown: every point (bytes per class, top-1 accuracy / accuracy (def. 4.6) per set, their
    means), then the budget table (best mean top-1 accuracy, def. 4.6's beside it)."""
    sets, n = result["sets"], len(result["sets"])
    lines = ["Each cell: top-1 accuracy / accuracy (def. 4.6); the methods are compared on top-1.", "",
             "| method | setting | bytes per class | " + " | ".join(sets) + " | mean |", "|---|---|---|" + "---|" * (n + 1)]
    for p in sorted(result["points"], key=lambda p: (p["method"], p["bytes_per_class"])):
        lines.append(f"| {p['method']} | {p['setting']} | {p['bytes_per_class']:,.0f} | "
                     + " | ".join(f"{p['top1'][s]:.2f} / {p['accuracy'][s]:.2f}" if s in p["accuracy"] else "n/a" for s in sets)
                     + f" | {p['mean_top1']:.2f} / {p['mean']:.2f}{_flag(p, n)} |")
    lines += ["", "Best mean top-1 accuracy within each budget (bytes per class; accuracy (def. 4.6) after the slash):", "",
              "| budget | ftorch | SIFT, ratio per view | SIFT, ratio across classes | pixel 1-NN | ftorch at or above every peer |",
              "|---|---|---|---|---|---|"]
    for row in result["budgets"]:
        cells = [("—" if row[m] is None else f"{row[m]['mean_top1']:.2f} / {row[m]['mean']:.2f} ({row[m]['setting']}){_flag(row[m], n)}")
                 for m in METHODS]
        lead = {None: "—", True: "yes", False: "no"}[row["ftorch_leads"]]
        lines.append(f"| {row['budget']:,} | " + " | ".join(cells) + f" | {lead} |")
    return lines
