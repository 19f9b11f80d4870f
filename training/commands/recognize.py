"""``recognize`` and ``incremental``: the recognition protocol of 4.5 in training stages (alg. 5.3), and alg. 5.4."""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import time
from dataclasses import fields
from pathlib import Path

import numpy as np
import torch

from ftorch import FeatureSpace
from ftorch.checkpoint import write_text
from ftorch.errors import InputError
from ftorch.recognition.learner import DistinctiveFeatureLearner
from ftorch.recognition.settings import Evidence, LearnerSettings, frame_set, primitive_set
from ftorch.recognition.stages import CYCLES_LIMIT, MAX_CYCLES, STAGES_LIMIT
from ftorch.space.draw import save_rgb
from ftorch.space.record import ImageRecords, require_memory
from training.cli.arguments import at_least, number
from training.cli.devices import machine, peak_memory, resolve_device, start_memory
from training.cli.jobs import check_seeds, device_options, run_folders, run_jobs, run_options
from training.cli.outputs import Command, Ledger, RunFolder, apart
from training.cli.parallel import reach_ray, share_idle_cores
from training.data.augment import overview as augmented_overview
from training.data.datasets import Task, load_task
from training.plots import curves_figure, figure_rgb, fold_curves_figure, growth_figure
from training.recognition.pictures import class_files, feature_pictures, save_pictures
from training.recognition.protocol import Fold, RunConfig, image_set
from training.recognition.report import (
    build_report,
    growth_over_seeds,
    seed_study,
    shown,
    top1_note,
    write_json,
    write_markdown,
)
from training.recognition.robustness import split_peers

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
    sets = {view: image_set(task, list(view), space, not args.quiet).all_records for view in views}
    if free is not None and sum(r.nbytes for r in sets.values()) > free:
        return {}  # the pyramids fit, their points did not
    return sets


# A fold's checkpoint is written at most once a minute (and at its end): a write compresses the
# value cache and the instance list anew, seconds per cycle at 20 COIL classes in 128x128.
CHECKPOINT_EVERY = 60


def primitives(text: str) -> str:
    """--primitives: a comma-separated choice of method 2's primitives, in their canonical order."""
    try:
        return ",".join(primitive_set(text))
    except InputError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def regions(text: str) -> str:
    """--regions: none, or a comma-separated choice of the frames a search bounds features in."""
    try:
        return ",".join(frame_set(text)) or "none"
    except InputError as err:
        raise argparse.ArgumentTypeError(str(err)) from None


def _stages(text: str) -> int | None:
    """--stages: auto, or a number of expert stages within what a schedule takes (:data:`STAGES_LIMIT`)."""
    if text == "auto":
        return None
    if text.isascii() and text.isdigit() and int(text) <= STAGES_LIMIT:  # "²".isdigit() holds too
        return int(text)
    raise InputError(f"--stages {text!r}: expected a number of expert stages (0 to {STAGES_LIMIT}) or auto")


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
        fold = Fold(k, image_set(task, train, space, progress, args.augment, seed, k, records.get(tuple(train))),
                    image_set(task, test, space, progress, records=records.get(tuple(test))), config,
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
                     augment=args.augment, dynamic=args.dynamic, incremental=incremental, images=task.fingerprint)


def log_run(writer, config: RunConfig, entry: dict, pictures: list[tuple[str, np.ndarray]]) -> None:
    """Hyper-parameters with the final results (add_hparams, in the fold's own run), the learned
    features as images (figure 5.2) and the fold's stage curves (figure 5.1, ``figures/curves``),
    all at the final stage."""
    final = entry["stages"][-1]
    hparams = {k: v for k, v in config.to_dict().items() if isinstance(v, (int, float, str, bool))}
    metrics = {"hparam/accuracy": final["test"]["accuracy"], "hparam/correct": final["test"]["correct"],
               **({"hparam/top1": final["test"]["top1"]} if "top1" in final["test"] else {}),
               "hparam/features": final["features"]["bn"], "hparam/queried": final["features"]["queried"],
               "hparam/stages": len(entry["stages"])}
    writer.add_hparams(hparams, metrics, run_name=".", global_step=final["step"])
    for name, picture in pictures:
        writer.add_image(f"features/{name}", picture, final["step"], dataformats="HWC")
    writer.add_figure("figures/curves", fold_curves_figure(entry, config.to_dict()), final["step"])


def _task_key(args) -> tuple:
    """The load_task arguments of a run, in load_task's order."""
    return args.task, args.data, args.classes, args.views, args.size, args.seed, args.first_view


class LoadedTask:
    """What a process loaded for the run it serves: the data set, by the load_task arguments and the
    device, and the records of its view sets that the process computed itself (Ray tasks, local
    workers without shared records), by view indices. Every seed's fold 1 trains and tests on the
    same views, so a worker computes them once, not once per seed.

    Lifetime: one per process (:data:`LOADED`); a command starts it afresh (:meth:`clear`), and a
    worker that serves a task of another run or device drops the old data set first (a Ray worker
    serves many runs)."""

    def __init__(self):
        self._key: tuple | None = None
        self._task: Task | None = None
        self.records: dict[tuple, ImageRecords] = {}

    def clear(self) -> None:
        self._key, self._task, self.records = None, None, {}

    def task(self, args, device: torch.device) -> Task:
        """The run's data set, loaded once per run and device; the records kept only for the same run."""
        key = (_task_key(args), str(device))
        if key != self._key:
            self.clear()
            self._key, self._task = key, load_task(*key[0])
        return self._task


LOADED = LoadedTask()


def fold_task(job: dict) -> dict:
    """One training task: fold ``job['fold']`` with ``job['seed']`` into ``job['out']``/foldK (pictures,
    class networks as BIF, learner, checkpoint) and TensorBoard into ``job['logdir']``/foldK, each
    file recorded in the run's ``job['ledger']``. ``job['records']``: the view sets' records where
    computed before (:func:`shared_records`); where none are, those this process computed for an
    earlier task (:data:`LOADED`).
    Returns the fold's report entry, with the machine it trained on (a Ray node may differ from the
    runner's), and its figures; picklable, for local processes and Ray."""
    args = argparse.Namespace(**job["args"])
    device = resolve_device(args.device)
    start_memory(device)
    task = LOADED.task(args, device)
    space = FeatureSpace().to(device)
    out, k, ledger = Path(job["out"]), job["fold"], job["ledger"]
    entry, fold, learner, pictures = _train_fold(args, task, k, job["seed"], space, out, Path(job["logdir"]),
                                                 job["incremental"], job.get("records") or LOADED.records, ledger)
    figures = [str(p.relative_to(out)) for p in save_pictures(pictures, fold.folder, ledger)]
    bif = {label: fold.folder / "networks" / class_files(label)[1] for label in learner.networks}
    ledger.files(*bif.values())
    for label, net in learner.networks.items():
        write_text(bif[label], net.to_bif())
    return {"entry": {**entry, "machine": machine(device), **peak_memory(device)}, "figures": figures}


def check_names(classes: list, out: Path) -> None:
    """Refuse a class whose files (:func:`class_files`) would have names longer than the file system
    takes: found before a fold is trained, not when its first figure is written."""
    try:
        limit = os.pathconf(out, "PC_NAME_MAX")
    except (OSError, ValueError, AttributeError):
        limit = 255
    for label in classes:
        name = max(class_files(label), key=lambda n: len(n.encode("utf-8")))
        if len(name.encode("utf-8")) > limit:
            raise InputError(f"class {str(label)[:40]!r}... has a name of {len(str(label).encode('utf-8'))} bytes: a run "
                             f"writes files named after each class ({name[-20:]!r} at the end), and {out}'s file system "
                             f"takes names of at most {limit} bytes; shorten the class folder's name")


def check_inputs(task: Task, folds: int, augment: int, device: torch.device, processes: int = 1) -> None:
    """Every input of a run, checked before anything is removed or computed (training/cli/outputs.py):
    every class trains in every fold, every image loads, and the view sets' pyramids fit in memory
    (on a GPU that ``processes`` share, each holds its own: :func:`shared_records`)."""
    task.check_folds(folds)
    shapes = task.shapes()
    space = FeatureSpace()
    sets = list(dict.fromkeys(tuple(view) for k in range(1, folds + 1) for view in task.fold(k)))
    need = sum(space.pyramid_nbytes([shapes[i] for i in view]) for view in sets)
    need += augment * max(space.pyramid_nbytes([shapes[i] for i in task.fold(k)[0]]) for k in range(1, folds + 1))
    need += space.matrices_nbytes(shapes)  # the filter matrices each process builds for the images' sizes
    height, width = (max(shape[d] for shape in shapes) for d in (0, 1))
    copies = processes if device.type == "cuda" else 1
    require_memory(need * copies, device, f"the {len(shapes)} images of the task (up to {height}x{width} pixels)"
                   + (f" in each of {copies} processes" if copies > 1 else ""))


def recognize_command(args, incremental: bool = False) -> int:
    device = resolve_device(args.device)
    _stages(args.stages)
    if args.dynamic and not args.augment:
        raise InputError("--dynamic draws each cycle's training views from the copies of --augment N: give N >= 1")
    check_seeds(args)
    learner_settings(args)  # refuses bad parameters early
    start = time.perf_counter()
    out = Path(args.out or f"runs/{args.task}{'-inc' if incremental else ''}")
    apart({"--out": out, "--logdir": args.logdir}, {"--data": args.data})
    with RunFolder(out, Path(args.logdir) if args.logdir else out / "tensorboard", args.resume, args.overwrite,
                   Command.INCREMENTAL if incremental else Command.RECOGNIZE) as folder:
        args.checkpoints = out = folder.out  # where an interrupted run continues from (main)
        reach_ray(args.ray)
        torch.manual_seed(args.seed)
        LOADED.clear()  # each command loads its data afresh
        task = LOADED.task(args, device)
        check_names(task.classes(), out)
        check_inputs(task, args.folds, args.augment, device, 1 if args.ray else min(args.workers, args.folds + args.seeds - 1))
        folder.clear()  # the inputs are good: only now is an old run replaced
        return _recognize(args, incremental, device, task, folder, start)


def incremental_command(args) -> int:
    return recognize_command(args, incremental=True)


def _recognize(args, incremental: bool, device: torch.device, task: Task, folder: RunFolder, start: float) -> int:
    """The body of :func:`recognize_command` once the run folder is held and the inputs checked."""
    out, logdir, ledger = folder.out, folder.logdir, folder.ledger
    parallel = args.workers > 1 or args.ray is not None
    settings = {k: v for k, v in vars(args).items() if k not in ("run", "checkpoints")}
    settings["quiet"] = args.quiet or parallel  # one progress bar over the tasks instead of one per fold
    jobs = [{"args": settings, "fold": k, "seed": s, "out": str(o), "logdir": str(t), "incremental": incremental,
             "ledger": ledger} for s, o, t in run_folders(args, out, logdir) for k in range(1, args.folds + 1 if s == args.seed else 2)]
    names = [f"fold {j['fold']} seed {j['seed']}" for j in jobs]
    records = shared_records(args, task, jobs, device)
    for job in jobs:
        job["records"] = records
    results = run_jobs(fold_task, jobs, names, args, out, "tasks")
    folds = [r["entry"] for r in results[: args.folds]]
    figures = [f for r in results[: args.folds] for f in r["figures"]]
    for k, entry in enumerate(folds, 1):
        for stage in entry["stages"]:
            taught = f", {stage['classes']} classes" if incremental else ""
            print(f"fold {k} stage {stage['stage']}{taught} "
                  f"(t_KSD {stage['t_ksd']:.3f}{', met' if stage['target_met'] else ''}): "
                  f"accuracy {stage['test']['accuracy']:.2f}, top-1 {shown(stage['test'].get('top1'))}, "
                  f"correct {stage['test']['correct']:.2f}, "
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
    if device.type == "cuda":  # what each task (one process's at a time) held on the GPU it shared
        report["gpu_memory_mib"] = {name: r["entry"]["gpu_memory_mib"] for name, r in zip(names, results)}
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
    note = top1_note([r["entry"] for r in results], names)  # every seed's folds: a figure of any may lack it
    if note:
        print(f"note: {note}", file=sys.stderr)
    print(f"average: accuracy {avg['test']['accuracy']:.2f}, top-1 {shown(avg['test'].get('top1'))}, "
          f"correct {avg['test']['correct']:.2f}, "
          f"ignorant {avg['test']['ignorant']:.2f}, {avg['features']['bn']:.1f} features; {seconds:.1f} s")
    if seeds:
        print(f"{args.seeds} seeds, fold 1: novice accuracy {seeds['novice']['mean']:.2f} +- {seeds['novice']['sd']:.2f}, "
              f"expert {seeds['expert']['mean']:.2f} +- {seeds['expert']['sd']:.2f}, "
              f"one-tailed paired t-test p = {shown(seeds['p'], '.2g')}; top-1 novice {shown(seeds['novice_top1']['mean'])}, "
              f"expert {shown(seeds['expert_top1']['mean'])}")
        if seeds.get("growth", {}).get("mean") is not None:
            g = seeds["growth"]
            print(f"{args.seeds} seeds, fold 1: features sampled ~ classes^b, b = {g['mean']:.2f} "
                  f"(95% interval over seeds {g['interval'][0]:.2f} to {g['interval'][1]:.2f})")
    print(f"report: {out / 'report.md'} and {out / 'report.json'}; TensorBoard: tensorboard --logdir {logdir}")
    return 0


def task_options(p: argparse.ArgumentParser, tasks: tuple[str, ...], default: str) -> None:
    """--task, --data, --classes, --views, --first-view, --device, --quiet: which images (recognize, evaluate)."""
    p.add_argument("--task", choices=tasks, default=default, help=f"data set (default {default})")
    p.add_argument("--data", help="image folder (coil: obj{k}__{view}.png files; folder: root/<class>/<image>)")
    p.add_argument("--classes", type=at_least(2, "a number of classes"), help="the first N classes: COIL objects 1..N "
                   "(default 6), class folders in name order or Plym solids (default all)")
    p.add_argument("--views", type=at_least(1, "a number of views"), help="views per class from --first-view on: "
                   "consecutive COIL views (default 20), images of a class folder in name order, Plym views (default all)")
    p.add_argument("--first-view", type=at_least(0, "a view number"), default=0, help="first view of each class (default 0)")
    device_options(p)


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
        elif f.name == "regions":
            p.add_argument(flag, type=regions, default=",".join(default) or "none", metavar=meta["metavar"],
                           help=f"{meta['help']} (default {','.join(default) or 'none'})")
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
    task_options(p, ("plym", "coil", "folder"), default)
    p.add_argument("--folds", type=int, choices=(1, 2), default=2, help="1 or 2 folds (default 2)")
    p.add_argument("--stages", default="auto", help="expert stages after stage 0 (0: chapter 4 learning only), "
                   "or auto: until t_KSD = 1 or two stages in a row miss their target (default auto)")
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
    p.add_argument("--max-cycles", type=at_least(1, "a number of cycles", CYCLES_LIMIT), default=MAX_CYCLES,
                   help="give up a stage after this many cycles (default 20, alg. 5.3)")
    run_options(p, "runs/TASK, runs/TASK-inc for incremental",
                repeated="repeat fold 1 with seeds SEED, SEED+1, ...: novice vs expert accuracy with a paired one-tailed "
                "t-test (figure 5.5; default 1)", jobs="folds and seeds", resume="continue each fold from its checkpoint in OUT")
    p.add_argument("--checkpoint-every", type=at_least(0, "a number of seconds", 86400), default=CHECKPOINT_EVERY,
                   metavar="SECONDS", help="write a fold's checkpoint after a cycle once this many seconds have passed "
                   f"since the last write (default {CHECKPOINT_EVERY}; 0: after every cycle)")


def add_parsers(commands) -> None:
    """The ``recognize`` and ``incremental`` sub-commands and their options."""
    p = commands.add_parser("recognize", help="recognition protocol of 4.5 with training stages (alg. 5.3)")
    _training_options(p, "plym")
    p.set_defaults(run=recognize_command)
    p = commands.add_parser("incremental", help="incremental task (alg. 5.4): classes added one at a time")
    _training_options(p, "coil")
    p.set_defaults(run=incremental_command)
