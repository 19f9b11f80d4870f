"""``recognize`` and ``incremental``: the recognition protocol of 4.5 in training stages (alg. 5.3), and alg. 5.4."""
from __future__ import annotations

import argparse
import os
import shutil
import sys
import time
from dataclasses import dataclass, field, fields, replace
from enum import StrEnum
from pathlib import Path

import numpy as np
import torch

from ftorch import FeatureSpace
from ftorch.checkpoint import write_text
from ftorch.errors import InputError
from ftorch.recognition.learner import DistinctiveFeatureLearner
from ftorch.recognition.settings import LearnerSettings, frame_set, primitive_set
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
from training.recognition.records import FoldEntry, Report
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


@dataclass(frozen=True)
class TaskChoice:
    """The images a run asked for, as ``load_task`` takes them (the run's first seed: Plym renders by it)."""

    task: str
    data: str | None
    classes: int | None
    views: int | None
    size: int | None
    seed: int
    first_view: int

    @classmethod
    def of(cls, args) -> "TaskChoice":
        return cls(args.task, args.data, args.classes, args.views, args.size, args.seed, args.first_view)

    def load(self) -> Task:
        return load_task(self.task, self.data, self.classes, self.views, self.size, self.seed, self.first_view)


@dataclass(frozen=True)
class FoldJob:
    """One training task of a run, as local worker processes and Ray receive it (picklable): fold
    ``fold`` of the run ``config`` (its seed the task's, its learner settings built once, by the
    runner) into ``out``/foldK with TensorBoard in ``logdir``/foldK, every file recorded in the run's
    ``ledger`` first. ``records``: the view sets' records where computed before (:func:`shared_records`).
    ``device`` is the --device asked: a Ray node resolves ``auto`` to what it has, and the fold records
    that device."""

    config: RunConfig
    fold: int
    out: Path
    logdir: Path
    ledger: Ledger
    images: TaskChoice
    device: str
    progress: bool
    resume: bool
    checkpoint_every: float
    records: dict[tuple, ImageRecords] = field(default_factory=dict)


@dataclass(frozen=True)
class FoldResult:
    """What a training task returns: the fold's report entry (with the machine it trained on) and its
    figures' paths relative to the run folder."""

    entry: FoldEntry
    figures: list[str]


def shared_records(args, task: Task, folds: list[int], device: torch.device) -> dict[tuple, ImageRecords]:
    """The records of the view sets the jobs of ``folds`` train and test on, by their indices, each computed once.

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
    views = list(dict.fromkeys(tuple(indices) for k in folds for indices in task.fold(k)[1 if args.augment else 0:]))
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


def _train_fold(job: FoldJob, task: Task, space: FeatureSpace, records: dict[tuple, ImageRecords]
                ) -> tuple[FoldEntry, Fold, DistinctiveFeatureLearner, list]:
    """Run the ``job``'s fold, with the view sets' ``records`` where computed before
    (:func:`shared_records`), to which it adds those it computes (not augmented training sets, whose
    copies are drawn per fold); also returns the learned features' pictures. Files are recorded in
    the run's ledger before they are written."""
    from torch.utils.tensorboard import SummaryWriter

    config, k, seed = job.config, job.fold, job.config.seed
    train, test = task.fold(k)
    folder = job.out / f"fold{k}"
    job.ledger.files(folder / "checkpoint.json", folder / "learner.json")
    job.ledger.events(job.logdir / f"fold{k}")
    with SummaryWriter(str(job.logdir / f"fold{k}")) as writer:
        fold = Fold(k, image_set(task, train, space, job.progress, config.augment, seed, k, records.get(tuple(train))),
                    image_set(task, test, space, job.progress, records=records.get(tuple(test))), config,
                    folder, task.classes(), job.progress, writer, config.incremental)
        records.setdefault(tuple(test), fold.test.all_records)
        if not config.augment:
            records.setdefault(tuple(train), fold.train.all_records)
        entry, learner = fold.run(config.max_cycles, _stages(config.stages), resume=job.resume,
                                  checkpoint_every=job.checkpoint_every, before_cycle=share_idle_cores)
        pictures = feature_pictures(learner, fold.train, f"{task.name}, seed {seed}, fold {k}", len(train))
        if config.augment:
            pictures.append(("augmented", augmented_overview(fold.train, len(train), f"{task.name}, seed {seed}, fold {k}")))
        if not fold.finished_before:  # a resumed fold that had ended logged its results then
            log_run(writer, config, entry, pictures)
    return entry, fold, learner, pictures


def run_config(args, task: Task, settings: LearnerSettings, device: torch.device, incremental: bool) -> RunConfig:
    """The settings a run records (its first seed's): what ran (the task's classes, its views per class
    where all classes have as many, else None: all of each), not only what was asked."""
    counts = set(task.views_per_class().values())
    return RunConfig(task.name, str(Path(args.data).resolve()) if args.data else None, task.classes(),
                     counts.pop() if len(counts) == 1 else None,
                     args.first_view, 64 if args.size is None and task.name == "plym" else args.size, args.seed, settings,
                     device=str(device), stages=args.stages, max_cycles=args.max_cycles,
                     augment=args.augment, dynamic=args.dynamic, incremental=incremental, images=task.fingerprint)


def log_run(writer, config: RunConfig, entry: FoldEntry, pictures: list[tuple[str, np.ndarray]]) -> None:
    """Hyper-parameters with the final results (add_hparams, in the fold's own run), the learned
    features as images (figure 5.2) and the fold's stage curves (figure 5.1, ``figures/curves``),
    all at the final stage."""
    final = entry.stages[-1]
    step = final.stage.step
    hparams = {k: v for k, v in config.to_dict().items() if isinstance(v, (int, float, str, bool))}
    metrics = {"hparam/accuracy": final.test.accuracy, "hparam/correct": final.test.correct,
               **({"hparam/top1": final.test.top1} if final.test.top1 is not None else {}),
               "hparam/features": final.features.bn, "hparam/queried": final.features.queried,
               "hparam/stages": len(entry.stages)}
    writer.add_hparams(hparams, metrics, run_name=".", global_step=step)
    for name, picture in pictures:
        writer.add_image(f"features/{name}", picture, step, dataformats="HWC")
    writer.add_figure("figures/curves", fold_curves_figure(entry, config.to_dict()), step)


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

    def task(self, images: TaskChoice, device: torch.device) -> Task:
        """The run's data set, loaded once per run and device; the records kept only for the same run."""
        key = (images, str(device))
        if key != self._key:
            self.clear()
            self._key, self._task = key, images.load()
        return self._task


LOADED = LoadedTask()


def fold_task(job: FoldJob) -> FoldResult:
    """One training task: the ``job``'s fold (pictures, class networks as BIF, learner, checkpoint, TensorBoard),
    with the view sets' records computed before (:func:`shared_records`), or where none are, those
    this process computed for an earlier task (:data:`LOADED`).
    Returns the fold's report entry, with the machine it trained on (a Ray node may differ from the
    runner's), and its figures; picklable, for local processes and Ray."""
    device = resolve_device(job.device)
    start_memory(device)
    task = LOADED.task(job.images, device)
    space = FeatureSpace().to(device)
    job = replace(job, config=replace(job.config, device=str(device)))
    entry, fold, learner, pictures = _train_fold(job, task, space, job.records or LOADED.records)
    figures = [str(p.relative_to(job.out)) for p in save_pictures(pictures, fold.folder, job.ledger)]
    bif = {label: fold.folder / "networks" / class_files(label)[1] for label in learner.networks}
    job.ledger.files(*bif.values())
    for label, net in learner.networks.items():
        write_text(bif[label], net.to_bif())
    return FoldResult(replace(entry, machine=machine(device), gpu_memory_mib=peak_memory(device)), figures)


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
    settings = learner_settings(args)  # refuses bad parameters early
    start = time.perf_counter()
    out = Path(args.out or f"runs/{args.task}{'-inc' if incremental else ''}")
    apart({"--out": out, "--logdir": args.logdir}, {"--data": args.data})
    with RunFolder(out, Path(args.logdir) if args.logdir else out / "tensorboard", args.resume, args.overwrite,
                   Command.INCREMENTAL if incremental else Command.RECOGNIZE) as folder:
        args.checkpoints = out = folder.out  # where an interrupted run continues from (main)
        reach_ray(args.ray)
        torch.manual_seed(args.seed)
        LOADED.clear()  # each command loads its data afresh
        task = LOADED.task(TaskChoice.of(args), device)
        check_names(task.classes(), out)
        check_inputs(task, args.folds, args.augment, device, 1 if args.ray else min(args.workers, args.folds + args.seeds - 1))
        folder.clear()  # the inputs are good: only now is an old run replaced
        return _recognize(args, run_config(args, task, settings, device, incremental), device, task, folder, start)


def incremental_command(args) -> int:
    return recognize_command(args, incremental=True)


def _recognize(args, config: RunConfig, device: torch.device, task: Task, folder: RunFolder, start: float) -> int:
    """The body of :func:`recognize_command` once the run folder is held and the inputs checked."""
    out, logdir, ledger = folder.out, folder.logdir, folder.ledger
    parallel = args.workers > 1 or args.ray is not None
    images = TaskChoice.of(args)
    jobs = [FoldJob(replace(config, seed=s), k, o, t, ledger, images, args.device,
                    not (args.quiet or parallel),  # one progress bar over the tasks instead of one per fold
                    args.resume, args.checkpoint_every)
            for s, o, t in run_folders(args, out, logdir) for k in range(1, args.folds + 1 if s == args.seed else 2)]
    names = [f"fold {j.fold} seed {j.config.seed}" for j in jobs]
    records = shared_records(args, task, [job.fold for job in jobs], device)
    jobs = [replace(job, records=records) for job in jobs]
    results: list[FoldResult] = run_jobs(fold_task, jobs, names, args, out, "tasks")
    folds = [r.entry for r in results[: args.folds]]
    figures = [f for r in results[: args.folds] for f in r.figures]
    for k, entry in enumerate(folds, 1):
        for e in entry.stages:
            s = e.stage
            taught = f", {s.classes} classes" if config.incremental else ""
            print(f"fold {k} stage {s.stage}{taught} (t_KSD {s.t_ksd:.3f}{', met' if s.target_met else ''}): "
                  f"accuracy {e.test.accuracy:.2f}, top-1 {shown(e.test.top1)}, correct {e.test.correct:.2f}, "
                  f"{e.features.bn} features in the networks, {s.cycles} cycles")
    seeds = None
    if args.seeds > 1:
        runs = [folds[0]] + [r.entry for r in results[args.folds:]]
        seeds = seed_study(runs, list(range(args.seed, args.seed + args.seeds)))
        if config.incremental and all(len(r.added) > 1 for r in runs):
            seeds.growth = growth_over_seeds(runs, seeds.seeds)
    seconds = time.perf_counter() - start
    report = build_report(config, str(device), machine(device), seconds, folds, seeds)
    if device.type == "cuda":  # what each task (one process's at a time) held on the GPU it shared
        report.gpu_memory_mib = {name: r.entry.gpu_memory_mib for name, r in zip(names, results)}
    if args.peers:
        report.peers = split_peers(task, list(range(1, args.folds + 1)))
    grew = report.growth is not None and report.growth.exponent is not None
    pictures = {"curves.png": curves_figure} | ({"growth.png": growth_figure} if grew else {})
    ledger.files(*(out / name for name in ("report.json", "report.md", *pictures)))
    write_json(out / "report.json", report.to_json())
    for name, figure in pictures.items():
        save_rgb(out / name, figure_rgb(figure(report)))
        figures.append(name)
    write_markdown(out / "report.md", report, figures)
    _summary(report, [r.entry for r in results], names, args.seeds)
    print(f"report: {out / 'report.md'} and {out / 'report.json'}; TensorBoard: tensorboard --logdir {logdir}")
    return 0


def _summary(report: Report, entries: list[FoldEntry], names: list[str], n_seeds: int) -> None:
    """The run's averages printed, and the seed study's figures where there is one; a note on stderr
    where a stage of any seed's folds lacks top-1 accuracy."""
    avg, seeds = report.average.final, report.seeds
    note = top1_note(entries, names)
    if note:
        print(f"note: {note}", file=sys.stderr)
    print(f"average: accuracy {avg.test.accuracy:.2f}, top-1 {shown(avg.test.top1)}, correct {avg.test.correct:.2f}, "
          f"ignorant {avg.test.ignorant:.2f}, {avg.features.bn:.1f} features; {report.seconds:.1f} s")
    if seeds:
        print(f"{n_seeds} seeds, fold 1: novice accuracy {seeds.novice.mean:.2f} +- {seeds.novice.sd:.2f}, "
              f"expert {seeds.expert.mean:.2f} +- {seeds.expert.sd:.2f}, "
              f"one-tailed paired t-test p = {shown(seeds.p, '.2g')}; top-1 novice {shown(seeds.novice_top1.mean)}, "
              f"expert {shown(seeds.expert_top1.mean)}")
        g = seeds.growth
        if g is not None and g.mean is not None:
            print(f"{n_seeds} seeds, fold 1: features sampled ~ classes^b, b = {g.mean:.2f} "
                  f"(95% interval over seeds {g.interval[0]:.2f} to {g.interval[1]:.2f})")
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


@dataclass(frozen=True)
class OptionText:
    """How a settings field describes itself on the command line (``ftorch.settings.option``'s metadata)."""

    help: str
    metavar: str | None = None
    at_least: int | None = None
    at_most: int | None = None
    what: str | None = None


def _learner_options(p: argparse.ArgumentParser) -> None:
    """One option per learner setting, as :class:`LearnerSettings` describes it (its defaults: the measured best)."""
    for f in fields(LearnerSettings):
        flag, text, default = "--" + f.name.replace("_", "-"), OptionText(**f.metadata), f.default
        if isinstance(default, bool):
            p.add_argument(flag, action="store_true", help=f"{text.help} (default off)")
        elif isinstance(default, int):
            p.add_argument(flag, type=at_least(text.at_least, text.what, text.at_most), default=default,
                           metavar=text.metavar, help=f"{text.help} (default {default})")
        elif f.name == "primitives":
            p.add_argument(flag, type=primitives, default=",".join(default), metavar=text.metavar,
                           help=f"{text.help} (default {','.join(default)})")
        elif f.name == "regions":
            p.add_argument(flag, type=regions, default=",".join(default) or "none", metavar=text.metavar,
                           help=f"{text.help} (default {','.join(default) or 'none'})")
        elif isinstance(default, StrEnum):
            p.add_argument(flag, choices=[str(e) for e in type(default)], default=str(default),
                           help=f"{text.help} (default {default})")
        else:
            p.add_argument(flag, type=number, default=default, metavar=text.metavar,
                           help=f"{text.help} (default {default:g})")


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
