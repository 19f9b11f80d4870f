"""The ftorch command line: ftorch [COMMAND ...], or python -m training.run [COMMAND ...].

Commands:
  recognize --task coil|folder|plym ...   the recognition protocol of 4.5 (two-fold cross
                               validation) in training stages (alg. 5.3): report.json,
                               report.md, feature figures, TensorBoard logs and a resumable
                               checkpoint per fold.
  incremental --task coil --classes 10 ...   the incremental task of alg. 5.4: classes added
                               one at a time, each trained in stages; same outputs.
  grasp --experiment clean|noisy|cue|mixed [--online]   the grasp pre-shaping experiments
                               of chapter 6 on the built-in grasp simulator: report.json,
                               report.md with histograms (figures 6.13, 6.14, 6.17), TensorBoard.
  evaluate --learner PATH --data DIR     recognize another image set with a saved learner.
  robustness --run RUN [--peers]         a recognize run's learners (and pixel 1-NN, SIFT
                               matching) on rotated, cluttered, occluded and paired test views.
  tradeoff --runs RUN...       accuracy against bytes stored per class: the runs' learners
                               packed as binary, SIFT matching with the n strongest keypoints
                               per view, pixel 1-NN at s x s, on the same (perturbed) views.
  salient IMAGE... --out DIR   salient edgels and texels drawn as in figure 3.9, one PNG per
                               image, counts printed and written to DIR/salient.json.
                               Without images it uses the built-in scene.
With no command at all it runs recognize on the built-in Plym-like task into runs/plym.
"""
from __future__ import annotations

import signal
import sys

if __name__ == "__main__":  # Ctrl-C while torch is still loading is one line too (main takes over after)
    signal.signal(signal.SIGINT, lambda *_: (print("interrupted", file=sys.stderr), sys.exit(130)))

import argparse  # noqa: E402
import json  # noqa: E402
import math  # noqa: E402
import shutil  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
from contextlib import ExitStack, nullcontext
from dataclasses import fields, replace
from pathlib import Path

import numpy as np
import torch

from ftorch import FeatureSpace, load_image
from ftorch.checkpoint import write_text
from ftorch.errors import InputError
from ftorch.recognition.candidates import primitive_set
from ftorch.recognition.environment import ImageSet
from ftorch.recognition.learner import DistinctiveFeatureLearner
from ftorch.recognition.settings import Evidence, LearnerSettings
from ftorch.space.draw import draw_features, draw_salient, feature_legend, grid, save_rgb, titled
from ftorch.space.record import ImageRecords, require_memory
from training.cli.arguments import MAX_SEED, Parser, at_least, number, seed
from training.cli.devices import described, machine, resolve_device
from training.cli.outputs import Ledger, RunFolder, locked, writable_folder
from training.cli.parallel import TasksFailed, reach_ray, run_tasks, share_idle_cores
from training.data.augment import augment
from training.data.augment import overview as augmented_overview
from training.data.builtin import builtin_scene
from training.data.datasets import Task, load_task, reduced
from training.grasping.command import add_parser as add_grasp_parser
from training.plots import curves_figure, feature_types_figure, figure_rgb, fold_curves_figure, growth_figure, tradeoff_figure
from training.recognition.protocol import Fold, RunConfig, confusion, feature_block, load_learner, test_block
from training.recognition.report import (
    COLUMNS,
    ambiguity_table,
    build_report,
    confusion_table,
    growth_over_seeds,
    seed_study,
    shown,
    write_json,
    write_markdown,
)
from training.recognition.robustness import SETS, feature_tables, fold_robustness, split_peers
from training.recognition.robustness import average as average_robustness
from training.recognition.robustness import table as robustness_table
from training.recognition.tradeoff import table as tradeoff_table
from training.recognition.tradeoff import tradeoff


def salient(args) -> int:
    device = resolve_device(args.device)
    if not 0 < args.truncate <= 10:
        raise InputError(f"--truncate {args.truncate}: expected a kernel radius in (0, 10] sigmas")
    out = writable_folder(args.out)
    if args.images:
        names = [Path(p) for p in args.images]
        images = [load_image(p) for p in names]
    else:
        names = [Path("builtin-scene.png")]
        images = [torch.from_numpy(builtin_scene())]
    space = FeatureSpace(truncate=args.truncate).to(device)
    with torch.no_grad():
        records = space.records(images, progress=len(images) > 4, names=[str(p) for p in names])
    counts = records.counts()
    summary = []
    stems = [name.stem for name in names]
    clash = len(set(stems)) < len(stems)  # a/x.png and b/x.png: number every figure, so none is lost
    for n, (name, image) in enumerate(zip(names, images)):
        stem = f"{n + 1}-{stems[n]}" if clash else stems[n]
        target = out / f"{stem}_salient.png"
        row = {"image": str(name), "edgels": counts["edgels"][n], "blobs": counts["blobs"][n],
               "corners": counts["corners"][n], "figure": str(target)}
        row["texels"] = row["blobs"] + row["corners"]
        save_rgb(target, titled(draw_salient(records, n, image),
                                f"{name.name}: {row['edgels']} edgels (left: segments of 2 sigma); {row['blobs']} blobs "
                                f"(circles) and {row['corners']} corners (squares) of radius sigma"))
        summary.append(row)
        print(f"{name}: {row['edgels']} edgels, {row['texels']} texels "
              f"({row['blobs']} blobs, {row['corners']} corners) -> {target}")
    write_text(out / "salient.json", json.dumps(summary, indent=2) + "\n")
    return 0


def _image_set(task: Task, indices: list[int], space: FeatureSpace, progress: bool, copies: int = 0,
               seed: int = 0, fold: int = 0, records: ImageRecords | None = None) -> ImageSet:
    """Views ``indices`` of the task, followed by ``copies`` augmented copies of each (training.data.augment);
    ``records``: the views' records where they were computed before (without copies only)."""
    # with copies the views are loaded here once, for the copies and the set alike
    images = [task.view(i) if copies else task.images[i] for i in indices]
    labels, names = [{task.labels[i]} for i in indices], [task.names[i] for i in indices]
    extra, extra_labels = augment(images, labels, copies, seed, fold)
    names += [f"{name}~{n + 1}" for n in range(copies) for name in names]
    return ImageSet(images + extra, labels + extra_labels, space, names=names, progress=progress,
                    records=None if copies else records)


SHARED_MEMORY = "/dev/shm"  # where torch's shared CPU tensors live on Linux


def shared_records(args, task: Task, jobs: list[dict], device: torch.device) -> dict[tuple, ImageRecords]:
    """The records of the view sets the jobs train and test on, by their indices, each computed once.

    Fold 2 trains on fold 1's test views and tests on its training views, and every seed's fold 1
    uses the same views, so computing them per job repeated the same work (in the same batches: the
    records are the same bit for bit). Local worker processes receive them through torch's shared
    memory, so every pyramid is in memory once, however many workers use it. Ray tasks, which may
    run on other machines, compute their own, and so do local processes on a GPU (no CUDA memory
    is passed between processes), each view set once per process (:func:`fold_task`); augmented
    training sets too (their copies are drawn per fold).
    """
    if args.ray is not None or (args.workers > 1 and device.type != "cpu"):
        return {}
    views = list(dict.fromkeys(tuple(indices) for job in jobs
                               for indices in task.fold(job["fold"])[1 if args.augment else 0:]))
    space = FeatureSpace().to(device)
    free = shutil.disk_usage(SHARED_MEMORY).free if args.workers > 1 and Path(SHARED_MEMORY).is_dir() else None
    # e.g. a container's 64 MB /dev/shm: the workers compute their own, as on Ray; known from the
    # images' sizes before any is computed, where the pyramids alone would not fit
    if free is not None and sum(space.pyramid_nbytes([task.view(i) for i in view]) for view in views) > free:
        return {}
    sets = {view: _image_set(task, list(view), space, not args.quiet).all_records for view in views}
    if free is not None and sum(r.nbytes for r in sets.values()) > free:
        return {}  # the pyramids fit, their points did not
    return sets


def feature_pictures(learner: DistinctiveFeatureLearner, env: ImageSet, heading: str = "learned features",
                     views: int | None = None) -> list[tuple[str, np.ndarray]]:
    """Figure 4.7 / 5.2 ("features": each class's features present in its middle training view)
    and figure 4.8 ("<class>_features": the first class's features in every training view of it
    where they are present), as (name, RGB uint8 picture), titled with ``heading`` (task, seed, fold).
    Only the first ``views`` images of ``env`` are drawn (all by default; the originals, not the
    augmented copies that follow them)."""
    pictures, panels = [], []
    shown = env.labels[:views]

    def present(label, image: int) -> tuple[list, list[int]]:
        net = learner.networks[label]
        values = env.values(net.features, [image])[:, 0] if net.features else np.zeros(0)
        keep = [k for k, f in enumerate(net.features) if values[k] > net.threshold[f]]
        return [net.features[k] for k in keep], [k + 1 for k in keep]

    classes = sorted(learner.networks, key=str)
    for label in classes:
        of_class = [i for i, labels in enumerate(shown) if label in labels]
        if of_class:
            middle = of_class[len(of_class) // 2]
            features, ids = present(label, middle)
            panels.append(titled(draw_features(env.all_records, middle, env.images[middle], features, ids, legend=True),
                                 f"{label}: {len(features)} of {len(learner.networks[label].features)} present"))
    if panels:
        pictures.append(("features", titled(grid(panels, min(4, len(panels))),
                                            f"{heading}: each class's features present in its middle training view")))
    if classes:
        first = classes[0]
        of_class = [i for i, labels in enumerate(shown) if first in labels]
        drawn = [titled(draw_features(env.all_records, i, env.images[i], *present(first, i)), env.names[i]) for i in of_class]
        every = grid(drawn, min(5, len(drawn)))
        net = learner.networks[first]
        key = feature_legend(net.features, range(1, len(net.features) + 1), every.shape[1])
        pictures.append((f"{first}_features", titled(np.concatenate([every, key]), f"{heading}: {first}'s features in its training views")))
    return pictures


def save_pictures(pictures: list[tuple[str, np.ndarray]], folder: Path, ledger: Ledger) -> list[Path]:
    """Pictures of :func:`feature_pictures` as PNG files ``folder``/<name>.png, recorded in ``ledger`` first."""
    paths = [folder / f"{name}.png" for name, _ in pictures]
    ledger.files(*paths)
    for path, (_, picture) in zip(paths, pictures):
        save_rgb(path, picture)
    return paths


# A fold's checkpoint is written at most once a minute (and at its end): a write compresses the
# value cache and the instance list anew, seconds per cycle at 20 COIL classes in 128x128.
CHECKPOINT_EVERY = 60


def primitives(text: str) -> str:
    """--primitives: a comma-separated choice of method 2's primitives, in their canonical order."""
    try:
        return ",".join(primitive_set(text))
    except InputError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


MAX_STAGES = 100


def _stages(text: str) -> int | None:
    if text == "auto":
        return None
    if text.isascii() and text.isdigit() and int(text) <= MAX_STAGES:  # "²".isdigit() holds too
        return int(text)
    raise InputError(f"--stages {text!r}: expected a number of expert stages (0 to {MAX_STAGES}) or auto")


def _train_fold(args, task: Task, k: int, seed: int, space: FeatureSpace, out: Path, logdir: Path,
                incremental: bool, records: dict[tuple, ImageRecords], ledger: Ledger
                ) -> tuple[dict, Fold, DistinctiveFeatureLearner, list]:
    """Run fold ``k`` with ``seed`` into ``out``/fold{k}, TensorBoard into ``logdir``/fold{k}, with
    the view sets' ``records`` where computed before (:func:`shared_records`), to which it adds
    those it computes (not augmented training sets, whose copies are drawn per fold); also returns
    the learned features' pictures. Files are recorded in the run's ``ledger`` before they are written."""
    from torch.utils.tensorboard import SummaryWriter

    config = run_config(args, task, seed, incremental)
    train, test = task.fold(k)
    progress = not args.quiet
    folder = out / f"fold{k}"
    ledger.files(folder / "checkpoint.json", folder / "learner.json")
    ledger.events(logdir / f"fold{k}")
    with SummaryWriter(str(logdir / f"fold{k}")) as writer:
        fold = Fold(k, _image_set(task, train, space, progress, args.augment, seed, k, records.get(tuple(train))),
                    _image_set(task, test, space, progress, records=records.get(tuple(test))), config,
                    folder, task.classes(), progress, writer, incremental)
        records.setdefault(tuple(test), fold.test.all_records)
        if not args.augment:
            records.setdefault(tuple(train), fold.train.all_records)
        entry, learner = fold.run(args.max_cycles, _stages(args.stages), resume=args.resume,
                                  checkpoint_every=args.checkpoint_every, before_cycle=share_idle_cores)
        pictures = feature_pictures(learner, fold.train, f"{task.name}, seed {seed}, fold {k}", len(train))
        if args.augment:
            pictures.append(("augmented", augmented_overview(fold.train, len(train), f"{task.name}, seed {seed}, fold {k}")))
        if not fold.finished_before:  # a resumed fold that had ended logged its results then
            log_run(writer, config, entry, pictures)
    return entry, fold, learner, pictures


def run_config(args, task: Task, seed: int, incremental: bool) -> RunConfig:
    """The settings a run records: what ran (the task's classes, its views per class where all classes
    have as many, else None: all of each), not only what was asked."""
    counts = set(task.views_per_class().values())
    return RunConfig(task.name, str(Path(args.data).resolve()) if args.data else None, task.classes(),
                     counts.pop() if len(counts) == 1 else None,
                     args.first_view, 64 if args.size is None and task.name == "plym" else args.size, seed,
                     learner_settings(args),
                     device=str(resolve_device(args.device)), stages=args.stages, max_cycles=args.max_cycles,
                     augment=args.augment, dynamic=args.dynamic, incremental=incremental)


def log_run(writer, config: RunConfig, entry: dict, pictures: list[tuple[str, np.ndarray]]) -> None:
    """Hyper-parameters with the final results (add_hparams, in the fold's own run), the learned
    features as images (figure 5.2) and the fold's stage curves (figure 5.1, ``figures/curves``),
    all at the final stage."""
    final = entry["stages"][-1]
    hparams = {k: v for k, v in config.to_dict().items() if isinstance(v, (int, float, str, bool))}
    metrics = {"hparam/accuracy": final["test"]["accuracy"], "hparam/correct": final["test"]["correct"],
               "hparam/features": final["features"]["bn"], "hparam/queried": final["features"]["queried"],
               "hparam/stages": len(entry["stages"])}
    writer.add_hparams(hparams, metrics, run_name=".", global_step=final["step"])
    for name, picture in pictures:
        writer.add_image(f"features/{name}", picture, final["step"], dataformats="HWC")
    writer.add_figure("figures/curves", fold_curves_figure(entry, config.to_dict()), final["step"])


# what this process loaded for its last run, by the load_task arguments and the device: the data
# set, and the records of its views that the process computed itself (Ray tasks, local workers
# without shared records), by view indices. Every seed's fold 1 trains and tests on the same
# views, so a worker computes them once, not once per seed.
_LOADED: dict[tuple, tuple[Task, dict[tuple, ImageRecords]]] = {}


def _task_key(args) -> tuple:
    """The load_task arguments of a run, in load_task's order."""
    return args.task, args.data, args.classes, args.views, args.size, args.seed, args.first_view


def _loaded(args, device: torch.device) -> tuple[Task, dict[tuple, ImageRecords]]:
    """The data set of a run and the records this process computed for its views (``_LOADED``)."""
    key = (_task_key(args), str(device))
    if key not in _LOADED:
        _LOADED.clear()
        _LOADED[key] = (load_task(*key[0]), {})
    return _LOADED[key]


def fold_task(job: dict) -> dict:
    """One training task: fold ``job['fold']`` with ``job['seed']`` into ``job['out']``/foldK (pictures,
    class networks as BIF, learner, checkpoint) and TensorBoard into ``job['logdir']``/foldK, each
    file recorded in the run's ``job['ledger']``. ``job['records']``: the view sets' records where
    computed before (:func:`shared_records`); where none are, those this process computed for an
    earlier task (:func:`_loaded`).
    Returns the fold's report entry, with the machine it trained on (a Ray node may differ from the
    runner's), and its figures; picklable, for local processes and Ray."""
    args = argparse.Namespace(**job["args"])
    device = resolve_device(args.device)
    task, own = _loaded(args, device)
    space = FeatureSpace().to(device)
    out, k, ledger = Path(job["out"]), job["fold"], job["ledger"]
    entry, fold, learner, pictures = _train_fold(args, task, k, job["seed"], space, out, Path(job["logdir"]),
                                                 job["incremental"], job.get("records") or own, ledger)
    figures = [str(p.relative_to(out)) for p in save_pictures(pictures, fold.folder, ledger)]
    bif = {label: fold.folder / "networks" / f"{label}.bif" for label in learner.networks}
    ledger.files(*bif.values())
    for label, net in learner.networks.items():
        write_text(bif[label], net.to_bif())
    return {"entry": {**entry, "machine": machine(device)}, "figures": figures}


def check_inputs(task: Task, folds: int, augment: int, device: torch.device) -> None:
    """Every input of a run, checked before anything is removed or computed (training/cli/outputs.py):
    every class trains in every fold, every image loads, and the view sets' pyramids fit in memory."""
    task.check_folds(folds)
    shapes = task.shapes()
    space = FeatureSpace()
    sets = list(dict.fromkeys(tuple(view) for k in range(1, folds + 1) for view in task.fold(k)))
    need = sum(space.pyramid_nbytes([shapes[i] for i in view]) for view in sets)
    need += augment * max(space.pyramid_nbytes([shapes[i] for i in task.fold(k)[0]]) for k in range(1, folds + 1))
    height, width = (max(shape[d] for shape in shapes) for d in (0, 1))
    require_memory(need, device, f"the {len(shapes)} images of the task (up to {height}x{width} pixels)")


def recognize_command(args, incremental: bool = False) -> int:
    device = resolve_device(args.device)
    _stages(args.stages)
    if args.dynamic and not args.augment:
        raise InputError("--dynamic draws each cycle's training views from the copies of --augment N: give N >= 1")
    if args.seed + args.seeds - 1 > MAX_SEED:
        raise InputError(f"--seed {args.seed} --seeds {args.seeds}: the last seed would pass {MAX_SEED}")
    learner_settings(args)  # refuses bad parameters early
    start = time.perf_counter()
    out = Path(args.out or f"runs/{args.task}{'-inc' if incremental else ''}")
    with RunFolder(out, Path(args.logdir) if args.logdir else out / "tensorboard", args.resume, args.overwrite) as folder:
        args.checkpoints = out = folder.out  # where an interrupted run continues from (main)
        reach_ray(args.ray)
        torch.manual_seed(args.seed)
        _LOADED.clear()  # each command loads its data afresh
        task, _ = _loaded(args, device)
        check_inputs(task, args.folds, args.augment, device)
        folder.clear()  # the inputs are good: only now is an old run replaced
        return _recognize(args, incremental, device, task, folder, start)


def _recognize(args, incremental: bool, device: torch.device, task: Task, folder: RunFolder, start: float) -> int:
    """The body of :func:`recognize_command` once the run folder is held and the inputs checked."""
    out, logdir, ledger = folder.out, folder.logdir, folder.ledger
    parallel = args.workers > 1 or args.ray is not None
    settings = {k: v for k, v in vars(args).items() if k not in ("run", "checkpoints")}
    settings["quiet"] = args.quiet or parallel  # one progress bar over the tasks instead of one per fold
    jobs = [{"args": settings, "fold": k, "seed": args.seed, "out": str(out), "logdir": str(logdir),
             "incremental": incremental, "ledger": ledger} for k in range(1, args.folds + 1)]
    jobs += [{"args": settings, "fold": 1, "seed": args.seed + n, "out": str(out / f"seed{args.seed + n}"),
              "logdir": str(logdir / f"seed{args.seed + n}"), "incremental": incremental, "ledger": ledger}
             for n in range(1, args.seeds)]
    names = [f"fold {j['fold']} seed {j['seed']}" for j in jobs]
    records = shared_records(args, task, jobs, device)
    for job in jobs:
        job["records"] = records
    try:
        results = run_tasks(fold_task, jobs, names, args.workers, args.ray, progress=not args.quiet)
    except TasksFailed as failed:
        raise InputError(f"{len(failed.failures)} of {len(jobs)} tasks failed twice ({failed}); "
                         f"the other tasks' folders in {out} are complete") from None
    folds = [r["entry"] for r in results[: args.folds]]
    figures = [f for r in results[: args.folds] for f in r["figures"]]
    for k, entry in enumerate(folds, 1):
        for stage in entry["stages"]:
            taught = f", {stage['classes']} classes" if incremental else ""
            print(f"fold {k} stage {stage['stage']}{taught} "
                  f"(t_KSD {stage['t_ksd']:.3f}{', met' if stage['target_met'] else ''}): "
                  f"accuracy {stage['test']['accuracy']:.2f}, correct {stage['test']['correct']:.2f}, "
                  f"{stage['features']['bn']} features in the networks, {stage['cycles']} cycles")
    seeds = None
    if args.seeds > 1:
        runs = [folds[0]] + [r["entry"] for r in results[args.folds:]]
        seeds = seed_study(runs, list(range(args.seed, args.seed + args.seeds)))
        if incremental and all(len(r["added"]) > 1 for r in runs):
            seeds["growth"] = growth_over_seeds(runs, seeds["seeds"])
    seconds = time.perf_counter() - start
    report = build_report(run_config(args, task, args.seed, incremental).to_dict(), str(device), machine(device), seconds,
                          folds, seeds)
    if args.peers:
        report["peers"] = split_peers(task, list(range(1, args.folds + 1)))
    grew = report.get("growth", {}).get("exponent") is not None
    pictures = {"curves.png": curves_figure} | ({"growth.png": growth_figure} if grew else {})
    ledger.files(*(out / name for name in ("report.json", "report.md", *pictures)))
    write_json(out / "report.json", report)
    for name, figure in pictures.items():
        save_rgb(out / name, figure_rgb(figure(report)))
        figures.append(name)
    write_markdown(out / "report.md", report, figures)
    avg = report["average"]["final"]
    print(f"average: accuracy {avg['test']['accuracy']:.2f}, correct {avg['test']['correct']:.2f}, "
          f"ignorant {avg['test']['ignorant']:.2f}, {avg['features']['bn']:.1f} features; {seconds:.1f} s")
    if seeds:
        print(f"{args.seeds} seeds, fold 1: novice accuracy {seeds['novice']['mean']:.2f} +- {seeds['novice']['sd']:.2f}, "
              f"expert {seeds['expert']['mean']:.2f} +- {seeds['expert']['sd']:.2f}, "
              f"one-tailed paired t-test p = {shown(seeds['p'], '.2g')}")
        if seeds.get("growth", {}).get("mean") is not None:
            g = seeds["growth"]
            print(f"{args.seeds} seeds, fold 1: features sampled ~ classes^b, b = {g['mean']:.2f} "
                  f"(95% interval over seeds {g['interval'][0]:.2f} to {g['interval'][1]:.2f})")
    print(f"report: {out / 'report.md'} and {out / 'report.json'}; TensorBoard: tensorboard --logdir {logdir}")
    return 0


SIDE_TOLERANCE = math.sqrt(2)  # one step of the half-octave scale space (DESIGN.md)


def at_learned_size(task: Task, learner: DistinctiveFeatureLearner, args) -> Task:
    """The task's images at the size the learner learned from (its ``sides``): features are measured
    at absolute scales in pixels, so a learner recognizes images of another size as other objects.
    Without ``--size``, images larger than a learner's single learned side are area-averaged down to
    it (``args.size`` records it); an image whose shorter side then lies more than one scale step
    (a factor of sqrt 2) outside the learned sides is refused. Learners saved before sides were
    recorded are taken as they are."""
    if learner.sides is None:
        print(f"note: {args.learner} does not record the image size it learned from; the images are "
              "recognized as stored (--size reduces them)", file=sys.stderr)
        return task
    low, high = learner.sides
    shapes = task.shapes()
    if args.size is None and low == high and any(min(shape) > low for shape in shapes):
        task = replace(task, images=[reduced(image, low) if min(shape) > low else image
                                     for image, shape in zip(task.images, shapes)])
        args.size = low
        print(f"note: images area-averaged to the learned shorter side of {low} pixels (--size {low})", file=sys.stderr)
        shapes = task.shapes()
    off = [i for i, shape in enumerate(shapes) if not low / SIDE_TOLERANCE <= min(shape) <= high * SIDE_TOLERANCE]
    if off:
        learned = f"{low}" if low == high else f"{low} to {high}"
        raise InputError(f"--learner {args.learner} learned from images whose shorter side is {learned} pixels; "
                         f"{len(off)} of these are not within a scale step of that (e.g. {task.names[off[0]]}, "
                         f"{shapes[off[0]][0]}x{shapes[off[0]][1]}): give images of the learned size "
                         f"({'--size ' + str(low) + ' reduces larger ones' if args.size is None else 'another --size'})")
    return task


def evaluate_command(args) -> int:
    device = resolve_device(args.device)
    out = writable_folder(args.out)
    learner = load_learner(args.learner)
    networks = {str(c): net for c, net in learner.networks.items()}  # classes by name, as folders and COIL name them
    if len(networks) < len(learner.networks):
        raise InputError(f"--learner {args.learner}: two classes have the same name as text "
                         f"({', '.join(sorted(map(repr, learner.networks), key=str))}), so images cannot name them apart")
    task = at_learned_size(load_task(args.task, args.data, args.classes, args.views, args.size, first_view=args.first_view),
                           learner, args)
    unknown = sorted(set(task.labels) - set(networks))
    if unknown:
        print(f"note: classes {', '.join(unknown)} of {args.data} are unknown to the learner", file=sys.stderr)
    classes = sorted(set(networks) | set(task.labels), key=str)
    env = _image_set(task, list(range(len(task.images))), FeatureSpace().to(device), not args.quiet)
    recognitions = [replace(r, recognized={str(c) for c in r.recognized}) for r in learner.recognize_many(env, range(len(env)))]
    result = {"checkpoint": str(args.learner), "data": str(args.data), "classes": classes, "size": args.size,
              "test": test_block(recognitions, env.labels, classes), "features": feature_block(learner, recognitions),
              "confusion": confusion(recognitions, env.labels, classes, networks),
              "images": [{"image": name, "true": sorted(map(str, t)), "recognized": sorted(map(str, r.recognized))}
                         for name, t, r in zip(env.names, env.labels, recognitions)]}
    write_json(out / "evaluate.json", result)
    lines = [f"# Evaluation of {args.learner} on {args.data}", "",
             f"accuracy {result['test']['accuracy']:.2f}; "
             + ", ".join(f"{k} {v:.2f}" for k, v in result["test"].items() if k != "accuracy"),
             "", COLUMNS, "", "## Confusion (table 4.3 form)", "", *confusion_table(result["confusion"], classes), "",
             "## Ambiguous recognitions (table 4.4 form)", "", *ambiguity_table(result["confusion"], classes), ""]
    write_text(out / "evaluate.md", "\n".join(lines))
    print(f"{len(env)} images: accuracy {result['test']['accuracy']:.2f}, correct {result['test']['correct']:.2f}; "
          f"report: {out / 'evaluate.md'}")
    return 0


def _perturbations(text: str) -> list[str]:
    kinds = list(SETS) if text == "all" else [k.strip() for k in text.split(",") if k.strip()]
    unknown = [k for k in kinds if k not in SETS]
    if unknown or not kinds:
        raise InputError(f"--perturb {text!r}: expected all or a comma-separated list of {', '.join(SETS)}")
    return list(dict.fromkeys(kinds))


def robustness_command(args) -> int:
    """The robustness benchmark on a recognize run's folds (training/recognition/robustness.py)."""
    device = resolve_device(args.device)
    kinds = _perturbations(args.perturb)
    if args.test_information is not None:
        LearnerSettings(test_information=args.test_information)  # refuses a bad threshold early
    run = Path(args.run_folder)
    out = writable_folder(args.out if args.out else run / "robustness") if args.out or run.is_dir() else None
    # results written inside the run folder belong to the run: the run is locked meanwhile, and they
    # are recorded in its ledger, so --overwrite of the run replaces them and nothing else
    inside = out is not None and out.absolute().is_relative_to(run.absolute())
    with locked(run, "--run") if inside else nullcontext():
        return _robustness(args, device, kinds, run, out, Ledger(str(run)) if inside else None)


def _robustness(args, device: torch.device, kinds: list[str], run: Path, out: Path, ledger: Ledger | None) -> int:
    """The body of :func:`robustness_command` once its output folder is held."""
    try:
        report = json.loads((run / "report.json").read_text())
        config = report["config"]
        data = args.data or config["data"]
        task = load_task(config["task"], data, len(config["classes"]), config["views"],
                         config["size"], config["seed"], config["first_view"])
        folds = [f["fold"] for f in report["folds"]]
        if not folds:
            raise ValueError("no folds")
    except (OSError, ValueError, KeyError, TypeError, IndexError, RecursionError) as err:
        raise InputError(f"--run {run}: not a run folder of recognize ({type(err).__name__}: {err})") from None
    start = time.perf_counter()
    space = FeatureSpace().to(device)
    answering = {"evidence": args.evidence} if args.evidence != "learned" else {}
    if args.test_information is not None:
        answering["test_information"] = args.test_information
    results = []
    for k in folds:
        learner = DistinctiveFeatureLearner.load(run / f"fold{k}" / "learner.json").set_params(**answering)
        results.append(fold_robustness(task, k, learner, kinds, args.seed, space, args.peers, out, not args.quiet, ledger))
    result = {"run": str(run), "data": str(data), "seed": args.seed, "sets": kinds,
              "evidence": args.evidence, "test_information": args.test_information, "learner": config, "folds": results,
              "average": average_robustness(results), "machine": machine(device),
              "seconds": time.perf_counter() - start}
    types = result["average"].get("types")
    if ledger is not None:
        ledger.files(out / "robustness.json", out / "robustness.md", *([out / "features.png"] if types else []))
    write_json(out / "robustness.json", result)
    if types:
        save_rgb(out / "features.png", figure_rgb(feature_types_figure(types, f"{run}: which features survive, "
                                                                              f"perturbation seed {args.seed}")))
    lines = [f"# Robustness of {run}", "", f"{len(folds)} folds, perturbation seed {args.seed}, evidence {args.evidence}, "
             f"{described(result['machine'])}, {result['seconds']:.1f} s. Accuracy (def. 4.6) and, in brackets, the "
             "ignorant share (def. 4.5), "
             "mean over folds; \"flipped\": the share of (network node, test view) whose state differs from "
             "the clean view's.", "", *robustness_table(result), "",
             *[f"![fold {k}](fold{k}/overview.png)" for k in folds], "", *feature_tables(result),
             *(["![which features survive](features.png)", ""] if types else [])]
    write_text(out / "robustness.md", "\n".join(lines))
    print("\n".join(robustness_table(result)))
    print(f"report: {out / 'robustness.md'} and {out / 'robustness.json'}; perturbed images in {out}/foldK/SET/")
    return 0


def tradeoff_command(args) -> int:
    """The accuracy-per-byte front of recognize runs against the peers (training/recognition/tradeoff.py)."""
    from torch.utils.tensorboard import SummaryWriter

    device = resolve_device(args.device)
    kinds = _perturbations(args.perturb)
    runs = [Path(r) for r in dict.fromkeys(args.runs)]
    out = Path(args.out)
    for run in runs:
        if out.absolute().is_relative_to(run.absolute()) or run.absolute().is_relative_to(out.absolute()):
            raise InputError(f"--out {out} and --runs {run}: the front is written beside the runs, not inside one")
    with ExitStack() as held:
        for run in runs:  # a run still being written is refused, and none changes meanwhile
            if not run.is_dir():
                raise InputError(f"--runs {run}: no such run folder")
            held.enter_context(locked(run, "--runs"))
        folder = held.enter_context(RunFolder(out, out / "tensorboard", False, args.overwrite, can_resume=False))
        result = tradeoff(runs, kinds, args.seed, FeatureSpace().to(device), args.data, not args.quiet)
        folder.clear()
        result["machine"] = machine(device)
        heading = (f"{result['task']}, {len(result['classes'])} classes, {len(runs)} run(s), perturbation seed {args.seed}: "
                   "accuracy against bytes stored per class")
        folder.ledger.files(out / "tradeoff.json", out / "tradeoff.md", out / "front.png")
        folder.ledger.events(out / "tensorboard")
        write_json(out / "tradeoff.json", result)
        front = figure_rgb(tradeoff_figure(result, heading))  # drawn once, for the PNG and TensorBoard
        save_rgb(out / "front.png", front)
        lines = [f"# Accuracy per byte: {result['task']}", "", f"Runs {', '.join(result['runs'])}; sets {', '.join(kinds)}; "
                 f"{described(result['machine'])}, {result['seconds']:.1f} s. Accuracy (def. 4.6), each seed weighted "
                 "equally; bytes: what each method stores per class (training/recognition/tradeoff.py).", "",
                 *tradeoff_table(result), "", "![the front](front.png)", ""]
        write_text(out / "tradeoff.md", "\n".join(lines))
        with SummaryWriter(str(out / "tensorboard")) as writer:
            writer.add_image("tradeoff/front", front, 0, dataformats="HWC")
            writer.add_text("tradeoff/table", "\n".join(tradeoff_table(result)), 0)
    print("\n".join(tradeoff_table(result)))
    print(f"report: {out / 'tradeoff.md'}, {out / 'tradeoff.json'} and {out / 'front.png'}")
    return 0


def _task_options(p: argparse.ArgumentParser, tasks: tuple[str, ...], default: str) -> None:
    p.add_argument("--task", choices=tasks, default=default, help=f"data set (default {default})")
    p.add_argument("--data", help="image folder (coil: obj{k}__{view}.png files; folder: root/<class>/<image>)")
    p.add_argument("--classes", type=at_least(2, "a number of classes"), help="the first N classes: COIL objects 1..N "
                   "(default 6), class folders in name order or Plym solids (default all)")
    p.add_argument("--views", type=at_least(1, "a number of views"), help="views per class from --first-view on: "
                   "consecutive COIL views (default 20), images of a class folder in name order, Plym views (default all)")
    p.add_argument("--first-view", type=at_least(0, "a view number"), default=0, help="first view of each class (default 0)")
    p.add_argument("--device", default="auto", help="cpu, cuda[:N] or auto (default)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")


def _learner_options(p: argparse.ArgumentParser) -> None:
    """One option per learner setting, as :class:`LearnerSettings` describes it (its defaults: the measured best)."""
    for f in fields(LearnerSettings):
        flag, meta, default = "--" + f.name.replace("_", "-"), f.metadata, f.default
        if isinstance(default, bool):
            p.add_argument(flag, action="store_true", help=f"{meta['help']} (default off)")
        elif isinstance(default, int):
            p.add_argument(flag, type=at_least(meta["at_least"], meta["what"], meta["at_most"]), default=default,
                           metavar=meta["metavar"], help=f"{meta['help']} (default {default})")
        elif f.name == "primitives":
            p.add_argument(flag, type=primitives, default=",".join(default), metavar=meta["metavar"],
                           help=f"{meta['help']} (default {','.join(default)})")
        elif f.name == "evidence":
            p.add_argument(flag, choices=[str(e) for e in Evidence], default=str(default),
                           help=f"{meta['help']} (default {default})")
        else:
            p.add_argument(flag, type=number, default=default, metavar=meta["metavar"],
                           help=f"{meta['help']} (default {default:g})")


def learner_settings(args) -> LearnerSettings:
    """The learner's settings from the command line; InputError for a value out of range."""
    return LearnerSettings(**{k: getattr(args, k) for k in LearnerSettings.names()})


def _training_options(p: argparse.ArgumentParser, default: str) -> None:
    _task_options(p, ("plym", "coil", "folder"), default)
    p.add_argument("--folds", type=int, choices=(1, 2), default=2, help="1 or 2 folds (default 2)")
    p.add_argument("--stages", default="auto", help="expert stages after stage 0 (0: chapter 4 learning only), "
                   "or auto: until t_KSD = 1 or two stages in a row miss their target (default auto)")
    p.add_argument("--seed", type=seed, default=0, help="seed of every random choice (default 0)")
    p.add_argument("--seeds", type=at_least(1, "a number of seeds", 1000), default=1,
                   help="repeat fold 1 with seeds SEED, SEED+1, ...: novice vs expert accuracy with a paired one-tailed "
                   "t-test (figure 5.5; default 1)")
    p.add_argument("--size", type=at_least(9, "an image side in pixels", 8192),
                   help="image side in pixels: Plym renders at it (default 64); "
                   "COIL and class-folder images are area-averaged down to that shorter side on load (default: as stored)")
    _learner_options(p)
    p.add_argument("--peers", action="store_true", help="also pixel 1-NN and OpenCV SIFT matching on the same splits")
    p.add_argument("--augment", type=at_least(0, "a number of copies", 100), default=0, metavar="N",
                   help="also train on N perturbed copies of each training view: rotated and scaled, half of them "
                        "occluded, half on procedural clutter (training/data/augment.py; default 0)")
    p.add_argument("--dynamic", action="store_true",
                   help="with --augment N: each cycle presents one version of every training view, drawn from the view "
                        "and its N copies, and a stage ends once the original views are learned (default off: every "
                        "copy is a training view of its own)")
    p.add_argument("--max-cycles", type=at_least(1, "a number of cycles", 1000), default=20,
                   help="give up a stage after this many cycles (default 20, alg. 5.3)")
    p.add_argument("--out", help="run folder (default runs/TASK, runs/TASK-inc for incremental)")
    p.add_argument("--logdir", help="TensorBoard folder (default OUT/tensorboard)")
    p.add_argument("--resume", action="store_true", help="continue each fold from its checkpoint in OUT")
    p.add_argument("--checkpoint-every", type=at_least(0, "a number of seconds", 86400), default=CHECKPOINT_EVERY,
                   metavar="SECONDS", help="write a fold's checkpoint after a cycle once this many seconds have passed "
                   f"since the last write (default {CHECKPOINT_EVERY}; 0: after every cycle)")
    p.add_argument("--overwrite", action="store_true", help="replace the run already in OUT (without it, or --resume, "
                   "a folder that holds a run is refused)")
    p.add_argument("--workers", type=at_least(1, "a number of processes", 1024), default=1,
                   help="run the folds and seeds as N local processes at once "
                   "(default 1: one after another); the report is the same")
    p.add_argument("--ray", metavar="ADDRESS", help="run the folds and seeds as tasks on a Ray cluster (ray.init "
                   "address, e.g. auto or ray://HEAD:10001; local: a local instance with --workers CPUs); "
                   "needs the distributed extra")


def parser() -> argparse.ArgumentParser:
    top = Parser(prog="ftorch" if Path(sys.argv[0]).name == "ftorch" else "python -m training.run",
                 description=__doc__.split("\n\n")[0])
    commands = top.add_subparsers(dest="command")
    p = commands.add_parser("recognize", help="recognition protocol of 4.5 with training stages (alg. 5.3)")
    _training_options(p, "plym")
    p.set_defaults(run=recognize_command)
    p = commands.add_parser("incremental", help="incremental task (alg. 5.4): classes added one at a time")
    _training_options(p, "coil")
    p.set_defaults(run=lambda args: recognize_command(args, incremental=True))
    add_grasp_parser(commands)
    p = commands.add_parser("evaluate", help="recognize another image set with a saved learner")
    p.add_argument("--learner", required=True, help="a learner.json written by recognize, or a fold's checkpoint.json")
    _task_options(p, ("coil", "folder"), "coil")
    p.add_argument("--size", type=at_least(9, "an image side in pixels", 8192), help="area-average the images down to this "
                   "shorter side (default: the side the learner learned from, where it learned from one)")
    p.add_argument("--out", default="runs/evaluate", help="output folder (default runs/evaluate)")
    p.set_defaults(run=evaluate_command)
    p = commands.add_parser("robustness", help="a run's learners and the peers on perturbed test views (7.2)")
    p.add_argument("--run", dest="run_folder", metavar="RUN", required=True,
                   help="a run folder written by recognize (report.json, foldK/learner.json)")
    p.add_argument("--data", help="the run's image folder, where it has moved (default: as recorded in the run)")
    p.add_argument("--perturb", default="all", help=f"all (default) or a comma-separated list of {', '.join(SETS)}")
    p.add_argument("--peers", action="store_true", help="also pixel 1-NN and OpenCV SIFT matching on the same images")
    p.add_argument("--evidence", choices=("learned", *Evidence), default="learned",
                   help="recognize with the evidence mode the learner was trained with (default) or another")
    p.add_argument("--test-information", type=number, metavar="BITS",
                   help="stop each recognition at this many bits instead of the learner's own threshold")
    p.add_argument("--seed", type=seed, default=0, help="seed of the perturbations (default 0)")
    p.add_argument("--out", help="output folder (default RUN/robustness)")
    p.add_argument("--device", default="auto", help="cpu, cuda[:N] or auto (default)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(run=robustness_command)
    p = commands.add_parser("tradeoff", help="accuracy against bytes stored per class, against SIFT and pixel 1-NN")
    p.add_argument("--runs", nargs="+", required=True, metavar="RUN", help="run folders written by recognize on one "
                   "task (e.g. with different --redundancy); every seed's learners are used")
    p.add_argument("--data", help="the runs' image folder, where it has moved (default: as recorded in the runs)")
    p.add_argument("--perturb", default="all", help=f"all (default) or a comma-separated list of {', '.join(SETS)}")
    p.add_argument("--seed", type=seed, default=0, help="seed of the perturbations (default 0)")
    p.add_argument("--out", default="runs/tradeoff", help="output folder (default runs/tradeoff)")
    p.add_argument("--overwrite", action="store_true", help="replace the front already in OUT")
    p.add_argument("--device", default="auto", help="cpu, cuda[:N] or auto (default)")
    p.add_argument("--quiet", action="store_true", help="no progress bars")
    p.set_defaults(run=tradeoff_command)
    p = commands.add_parser("salient", help="draw salient edgels and texels (figure 3.9)")
    p.add_argument("images", nargs="*", help="image files (default: the built-in scene)")
    p.add_argument("--out", default="runs/salient", help="output folder (default: runs/salient)")
    p.add_argument("--device", default="auto", help="cpu, cuda[:N] or auto (default)")
    p.add_argument("--truncate", type=number, default=3.0, help="kernel radius in sigmas (default 3)")
    p.set_defaults(run=salient)
    return top


def _terminated(*_) -> None:
    raise KeyboardInterrupt  # SIGTERM (a cluster's scheduler, kill) stops a run as Ctrl-C does


def _thread_failed(failure) -> None:
    """A background thread's exception: an OSError (TensorBoard's event writer on a full disk) is
    raised again in the main thread at its next write and reported there in one line, so it is
    not printed here as a traceback; anything else is."""
    if not issubclass(failure.exc_type, OSError):
        threading.__excepthook__(failure)


def main(argv: list[str] | None = None) -> int:
    signal.signal(signal.SIGINT, signal.default_int_handler)
    signal.signal(signal.SIGTERM, _terminated)
    threading.excepthook = _thread_failed
    argv = sys.argv[1:] if argv is None else argv
    args = parser().parse_args(argv or ["recognize"])
    try:
        return args.run(args)
    except InputError as err:
        print(f"error: {err}", file=sys.stderr)
        return 2
    except OSError as err:  # e.g. a disk that filled up while writing; writes are atomic, nothing half-written
        print(f"error: {err.filename}: {err.strerror or err}" if err.filename else f"error: {err.strerror or err}",
              file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        where = getattr(args, "checkpoints", None)
        print("interrupted" + (f"; the checkpoints in {where} keep the cycles finished up to their last write: run the same command "
                               "with --resume to continue" if where else ""), file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
