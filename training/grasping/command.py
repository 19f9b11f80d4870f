"""``python -m training.run grasp``: the chapter 6 experiments with reports, figures and TensorBoard logs.

Each fold writes its checkpoint (OUT/foldK/checkpoint.json, OUT/foldK-online/... with ``--online``)
after every epoch and once it has ended, so ``--resume`` continues an interrupted run from the last
finished epoch of each fold to the same report.json (seconds aside): a fold that had ended gives its
stored report entry, one that had not trains on from its last epoch (training/grasping/experiment.py
says why that is exact). A fold's TensorBoard run is written when the fold ends (a resumed fold that
had not ended replaces what an interrupted write may have left); per epoch it holds what the learner
predicted before each training grasp's outcome (``epoch/...``, step: the epoch, 1 first), per fold the
tests (``fold/...``, step: the epochs trained). Grasps without a prediction are counted
(``epoch/unpredicted``, ``fold/unpredicted``), not drawn into the histograms; so are grasps without
equilibrium (an infinite mu_0, ``.../no_equilibrium...``).
"""
from __future__ import annotations

import argparse
import math
import time
from dataclasses import dataclass, fields, replace
from pathlib import Path

import numpy as np
import torch

from ftorch import FeatureSpace
from ftorch.checkpoint import load_checkpoint, reading, save_checkpoint, schema_of
from ftorch.errors import InputError
from ftorch.grasp.learner import GraspLearner
from ftorch.grasp.settings import MU0_CAP, FingerChoice, GraspSettings
from ftorch.space.draw import draw_features, grid, save_rgb, titled
from training.cli.arguments import at_least, number
from training.cli.devices import machine, resolve_device
from training.cli.jobs import check_seeds, device_options, run_folders, run_jobs, run_options
from training.cli.outputs import EVENTS, Command, RunFolder
from training.cli.parallel import reach_ray, share_idle_cores
from training.plots import figure_rgb
from training.recognition.report import write_json

from .experiment import EXPERIMENTS, GraspFold, simulate_pool
from .figures import error_figure, grasp_figure, reduction_figure
from .haptics import HapticController
from .records import FoldEntry, FoldTests, GraspReport, Mode, RunConfig, SeedJob
from .report import grasp_columns, reduction_words, results, seed_study, write_markdown
from .schema import SCHEMA

FOLD_KIND = "grasp-fold"
OPTIONS = ("t_dtheta", "finger_choice", "mu0_split")  # the learner's settings on the command line and in the report


def _check(args) -> None:
    if args.pool < 4:
        raise InputError(f"--pool {args.pool}: expected at least 4 simulated grasps per category")
    if not 1 <= args.best <= args.pool // 2:
        raise InputError(f"--best {args.best}: expected 1 to {args.pool // 2} (half of --pool {args.pool})")
    if args.epochs < 1:
        raise InputError(f"--epochs {args.epochs}: expected at least 1")
    if args.size < 32:
        raise InputError(f"--size {args.size}: expected at least 32 pixels")
    if not 0 < args.t_dtheta < 180:
        raise InputError(f"--t-dtheta {args.t_dtheta}: expected degrees in (0, 180)")
    if args.folds not in (1, 2):
        raise InputError(f"--folds {args.folds}: expected 1 or 2")
    learner_settings(args)


def learner_settings(args) -> GraspSettings:
    """The learner's settings from the command line (``--t-dtheta`` in degrees; InputError for a value out
    of range). ``--mu0-split`` serves ``--finger-choice quality`` only: thesis and pooled learn from
    orientation mistakes alone, as the thesis does."""
    settings = GraspSettings(t_dtheta=math.radians(args.t_dtheta), finger_choice=args.finger_choice,
                             mu0_split=args.mu0_split)
    return settings if settings.finger_choice is FingerChoice.QUALITY else settings.replace(mu0_split=None)


def run_config(args) -> RunConfig:
    """The settings a run records, from the command line (``device`` as asked: each seed's job resolves it)."""
    return RunConfig(args.experiment, args.seed, args.pool, args.best, args.epochs, args.size, args.t_dtheta, args.folds,
                     args.online, args.finger_choice, learner_settings(args).mu0_split, args.device)


def _quality(split: np.ndarray) -> dict | None:
    """A feature's quality split for the report (ftorch/grasp/learner.py), None where it has none."""
    power, cut, above, below = (float(v) for v in split)
    return {"ksd": power, "cut": cut, "mu0_above": above, "mu0_below": below} if power > 0 else None


def _learned_features(learner: GraspLearner) -> dict:
    """Every learned feature with its model and quality split, by finger count (JSON-ready, for the report)."""
    return {str(c): [dict(feature=f.to_dict(), model=m.to_dict() if m else None, quality=_quality(q))
                     for f, m, q in zip(s.features, s.models, s.quality.T)]
            for c, s in learner.sets.items()}


def _histogram(writer, tag: str, values: list, step: int) -> None:
    """A histogram of the values that exist (None: no prediction, or no equilibrium, is left out)."""
    data = np.array([v for v in values if v is not None], dtype=float)
    if len(data):
        writer.add_histogram(tag, data, step)


def log_epochs(writer, fold: GraspFold) -> None:
    """Per training epoch (step: the epoch, 1 first): the report's epoch log, and what the learner predicted
    before each grasp's outcome: orientation errors, E[mu_0] and the measured mu_0 of the grasps with a
    prediction, the fingers it would choose; the grasps without a prediction (without a finger choice,
    without equilibrium) counted."""
    for entry, predicted in zip(fold.epochs, fold.predictions):
        step = entry.epoch + 1
        for tag, value in (("mistakes", entry.mistakes), ("poor", entry.poor), ("features_2", entry.features_2),
                           ("features_3", entry.features_3), ("sampled_2", entry.sampled_2), ("sampled_3", entry.sampled_3)):
            writer.add_scalar(f"epoch/{tag}", value, step)
        judged = [e is not None for e in predicted.error_deg]
        measured = [m for m, j in zip(predicted.measured_mu0, judged) if j]
        writer.add_scalar("epoch/unpredicted", judged.count(False), step)
        writer.add_scalar("epoch/no_finger_choice", predicted.fingers.count(None), step)
        writer.add_scalar("epoch/no_equilibrium", measured.count(None), step)
        _histogram(writer, "epoch/orientation_error_deg", predicted.error_deg, step)
        _histogram(writer, "epoch/mu0_expected", predicted.expected_mu0, step)
        _histogram(writer, "epoch/mu0_measured", measured, step)
        _histogram(writer, "epoch/fingers_chosen", predicted.fingers, step)


def log_fold(writer, settings: dict, fold: GraspFold, evaluation: FoldTests, pictures: dict) -> None:
    """The epochs (:func:`log_epochs`), then the fold's tests (step: the epochs trained): histograms of
    the orientation errors, probes and mu_0 (capped at MU0_CAP) that exist, the grasps without a
    prediction or without equilibrium counted, the report's summaries, hyper-parameters and figures
    (matplotlib charts with ``add_figure``, which closes them, RGB pictures with ``add_image``)."""
    log_epochs(writer, fold)
    step = len(fold.epochs)
    res = results([evaluation])
    errors = evaluation.orientation_errors_deg
    _histogram(writer, "fold/orientation_error_deg", errors, step)
    writer.add_scalar("fold/unpredicted", errors.count(None), step)
    poor = res.poor_grasp_fraction
    for side, grasps, mu0, probes, poor_share in (("haptic", evaluation.haptic, res.mu0.haptic, res.probes.haptic, poor.haptic),
                                                  ("cued", evaluation.cued, res.mu0.cued, res.probes.cued, poor.cued)):
        measured = [g.mu0 for g in grasps]
        writer.add_histogram(f"fold/probes_{side}", np.array([g.probes for g in grasps]), step)
        _histogram(writer, f"fold/mu0_{side}", [None if m is None else min(m, MU0_CAP) for m in measured], step)
        writer.add_scalar(f"fold/no_equilibrium_{side}", measured.count(None), step)
        writer.add_scalar(f"fold/probes_{side}_mean", probes.mean, step)
        writer.add_scalar(f"fold/mu0_{side}_median", mu0.median, step)
        writer.add_scalar(f"fold/poor_{side}", poor_share, step)
    error = res.orientation_error_deg
    writer.add_scalar("fold/orientation_error_median_deg", error.median, step)
    writer.add_scalar("fold/orientation_error_p90_deg", error.p90, step)
    hparams = {k: v for k, v in settings.items() if isinstance(v, (int, float, str, bool))}
    metrics = {"hparam/orientation_error_median_deg": error.median, "hparam/poor_haptic": poor.haptic,
               "hparam/poor_cued": poor.cued}
    writer.add_hparams(hparams, metrics, run_name=".", global_step=step)
    for name, picture in pictures.items():
        if isinstance(picture, np.ndarray):
            writer.add_image(f"fold/figure_{name}", picture, step, dataformats="HWC")
        else:
            writer.add_figure(f"fold/figure_{name}", picture, step)


def recommended_features(fold: GraspFold, heading: str, per_kind: int = 3) -> np.ndarray:
    """Figures 6.15 / 6.16: the feature f*_c behind the recommendation, drawn on held-out images,
    titled with ``heading`` (experiment, seed, fold)."""
    panels, shown = [], {}
    for trial in fold.objects:
        if shown.get(trial.kind, 0) >= per_kind:
            continue
        cue = fold.recommendation(trial)
        if cue is None:
            continue
        shown[trial.kind] = shown.get(trial.kind, 0) + 1
        picture = draw_features(fold.records[trial.key], 0, trial.image, [cue.feature], [1], min_side=256, legend=True)
        panels.append(titled(picture, f"{trial.kind} {cue.fingers}f KSD {cue.ksd:.2f} E[mu0] {cue.expected_mu0:.2f}"))
    if not panels:
        return titled(np.full((64, 512, 3), 255, np.uint8), f"{heading}: no recommendation on the test images")
    return titled(grid(panels, per_kind), f"{heading}: the feature behind each recommendation (figures 6.15, 6.16)")


@dataclass(frozen=True)
class StoredFold:
    """A fold's checkpoint as resuming reads it: its state after the last epoch (:meth:`GraspFold.state_dict`)
    and, where the fold had ended, its report entry (None where it had not)."""

    state: dict
    entry: FoldEntry | None


def _stored(path: Path, config: dict, fold: int) -> StoredFold | None:
    """The checkpoint of a fold to resume (None where there is none); InputError for a damaged or foreign
    file, or one written under other settings."""
    if not path.is_file():
        return None
    data = load_checkpoint(path, FOLD_KIND)
    with reading(path, "grasp fold checkpoint"):
        schema_of(data.get("schema"), "a grasp fold checkpoint", SCHEMA)
    if data.get("config") != config or data.get("fold") != fold:
        raise InputError(f"{path}: written by a different run configuration; use another --out or delete it to start afresh")
    done, state, entry = data.get("done"), data.get("state"), data.get("entry")
    if not isinstance(done, bool) or not isinstance(state, dict) or (done and not isinstance(entry, dict)):
        raise InputError(f"{path}: damaged grasp fold checkpoint (no state, or an ended fold without its report entry)")
    with reading(path, "grasp fold checkpoint"):
        return StoredFold(state, FoldEntry.from_json(entry) if done else None)


def _save(path: Path, config: dict, fold: GraspFold, entry: FoldEntry | None = None) -> None:
    """A fold's checkpoint: its state after the last epoch, and once it has ended (``entry``), its report entry."""
    save_checkpoint(path, FOLD_KIND, {"config": config, "fold": fold.k, "done": entry is not None,
                                      "state": fold.state_dict(), "entry": None if entry is None else entry.to_json(),
                                      "schema": SCHEMA})


def _fold_name(k: int, mode: Mode) -> str:
    return f"fold{k}" + ("-online" if mode is Mode.ONLINE else "")


def _run_fold(job: SeedJob, config: RunConfig, k: int, mode: Mode, pool: dict, space: FeatureSpace,
              controller: HapticController) -> FoldEntry:
    """Fold ``k`` in ``mode``: its stored entry where its checkpoint says it ended; else trained (on from its
    checkpoint with ``resume``), tested, logged to TensorBoard, drawn, and its checkpoint saved."""
    from torch.utils.tensorboard import SummaryWriter

    out, logdir, name = Path(job.out), Path(job.logdir), _fold_name(k, mode)
    checkpoint, fold_config = out / name / "checkpoint.json", config.fold_config(mode)
    stored = _stored(checkpoint, fold_config, k) if job.resume else None
    if stored is not None and stored.entry is not None:
        return stored.entry
    share_idle_cores()  # the last seeds of a --workers run take the idle cores
    fold = GraspFold(k, config.experiment, pool, config.best, space, config.new_learner(k), controller, config.seed,
                     not job.quiet)
    if stored is not None:
        with reading(checkpoint, "grasp fold checkpoint"):
            fold.load_state_dict(stored.state)
        for events in (logdir / name).glob(f"{EVENTS}*"):  # what an interrupted log may have left
            events.unlink()
    job.ledger.files(checkpoint)
    fold.fit(config.epochs, online=mode is Mode.ONLINE, after_epoch=lambda: _save(checkpoint, fold_config, fold))
    evaluation = fold.evaluate()
    which = f"{config.experiment}, seed {config.seed}, {name}"
    features = recommended_features(fold, which)
    pictures = {"errors": error_figure(evaluation.orientation_errors_deg, f"{which}: orientation errors"),
                "grasps": grasp_figure(grasp_columns([evaluation], config.experiment), f"{which}: probes and mu_0"),
                "features": features}
    job.ledger.events(logdir / name)
    with SummaryWriter(str(logdir / name)) as writer:
        log_fold(writer, fold_config, fold, evaluation, pictures)
    job.ledger.files(out / f"{name}_features.png")
    save_rgb(out / f"{name}_features.png", features)
    entry = FoldEntry(k, mode, fold.epochs, results([evaluation]), evaluation, _learned_features(fold.learner))
    _save(checkpoint, fold_config, fold, entry)
    return entry


def seed_task(job: SeedJob) -> GraspReport:
    """One seed of the experiment: every fold, off-line (and on-line), into ``job.out`` (report, figures,
    each fold's checkpoint in foldK/) and TensorBoard ``job.logdir``/foldK; returns its report. With
    ``resume``, each fold goes on from its checkpoint (module doc). Picklable, for local processes and
    Ray (training/cli/parallel.py)."""
    out = Path(job.out)
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    device = resolve_device(job.config.device)
    config = replace(job.config, device=str(device))  # resolved where the job runs (a Ray task's machine)
    torch.manual_seed(config.seed)
    controller = HapticController()
    space = FeatureSpace().to(device)
    pool = simulate_pool(config.experiment, config.pool, config.seed, config.size, controller, not job.quiet)
    evaluations: dict[Mode, list[FoldTests]] = {mode: [] for mode in config.modes()}
    folds, figures = [], []
    for k in range(1, config.folds + 1):
        for mode in config.modes():
            entry = _run_fold(job, config, k, mode, pool, space, controller)
            evaluations[mode].append(entry.tests)
            folds.append(entry)
            figures.append(f"{_fold_name(k, mode)}_features.png")
            last = entry.epochs[-1]
            if not job.quiet:
                print(f"seed {config.seed} fold {k} {mode}: {len(entry.epochs)} epochs, last with {last.mistakes:.2f} "
                      f"mistakes; {last.features_2} + {last.features_3} features")
    offline = evaluations[Mode.OFFLINE]
    job.ledger.files(*(out / name for name in ("errors.png", "grasps.png", "report.json", "report.md")))
    save_rgb(out / "errors.png", figure_rgb(error_figure([e for ev in offline for e in ev.orientation_errors_deg],
                                                         f"{config.experiment}, seed {config.seed}: orientation errors "
                                                         "(figure 6.13)")))
    save_rgb(out / "grasps.png", figure_rgb(grasp_figure(grasp_columns(offline, config.experiment),
                                                         f"{config.experiment}, seed {config.seed}: probes and mu_0, "
                                                         "haptic only vs cued (figures 6.14, 6.17)")))
    pooled = {mode: results(evaluations[mode]) for mode in config.modes()}
    report = GraspReport(config, str(device), machine(device), time.perf_counter() - start, pooled[Mode.OFFLINE],
                         pooled if config.online else None,
                         folds, ["errors.png", "grasps.png", *figures], schema=SCHEMA)
    write_json(out / "report.json", report.to_json())
    write_markdown(out / "report.md", report)
    return report


def grasp_command(args) -> int:
    _check(args)
    resolve_device(args.device)
    check_seeds(args)
    start = time.perf_counter()
    out = Path(args.out or f"runs/grasp-{args.experiment}")
    with RunFolder(out, Path(args.logdir) if args.logdir else out / "tensorboard", args.resume, args.overwrite,
                   Command.GRASP) as folder:
        args.checkpoints = folder.out  # where an interrupted run continues from (training/run.py main)
        reach_ray(args.ray)
        folder.clear()  # the inputs are checked (the simulator needs no files)
        return _grasp(args, folder, start)


def _grasp(args, folder: RunFolder, start: float) -> int:
    """The body of :func:`grasp_command` once the run folder is held."""
    out, logdir = folder.out, folder.logdir
    quiet = args.quiet or args.workers > 1 or args.ray is not None  # one progress bar over the seeds instead
    config, seeds = run_config(args), range(args.seed, args.seed + args.seeds)
    jobs = [SeedJob(replace(config, seed=s), str(o), str(t), folder.ledger, quiet, args.resume)
            for s, o, t in run_folders(args, out, logdir)]
    reports = run_jobs(seed_task, jobs, [f"seed {s}" for s in seeds], args, out, "seeds")
    report = reports[0]
    if args.seeds > 1:
        study = seed_study(reports)
        folder.ledger.files(out / "reductions.png")
        save_rgb(out / "reductions.png", figure_rgb(reduction_figure(study, f"{args.experiment}, seeds {seeds[0]}-{seeds[-1]}")))
        report = replace(report, seconds=time.perf_counter() - start, figures=[*report.figures, "reductions.png"], seeds=study)
        write_json(out / "report.json", report.to_json())
        write_markdown(out / "report.md", report)
    _summarize(args, report, start, out, logdir)
    return 0


def _summarize(args, report: GraspReport, start: float, out: Path, logdir: Path) -> None:
    """The run's last lines: its results (on-line, and over the seeds, where run), time and where it went."""
    res = report.results
    e, p, probes = res.orientation_error_deg, res.poor_grasp_fraction, res.probes
    print(f"{args.experiment}, seed {args.seed}: orientation error median {e.median:.1f} deg (p90 {e.p90:.1f}); "
          f"poor grasps haptic {p.haptic:.2f} -> cued {p.cued:.2f}; probes {probes.haptic.mean:.1f} -> {probes.cued.mean:.1f}")
    if report.online is not None:
        on = report.online[Mode.ONLINE]
        print(f"on-line: orientation error median {on.orientation_error_deg.median:.1f} deg; poor grasps cued "
              f"{on.poor_grasp_fraction.cued:.2f}")
    if report.seeds is not None:
        study = report.seeds
        for mode, spread in study.reduction.items():
            cued, error = study.poor_cued[mode], study.error_median_deg[mode]
            print(f"{args.seeds} seeds, {mode}: {reduction_words(spread, ' +- ')}; poor cued mean {cued.mean:.2f}; "
                  f"median orientation error worst {error.worst:.1f} deg (seed {error.worst_seed})")
    print(f"{time.perf_counter() - start:.1f} s; report: {out / 'report.md'} and {out / 'report.json'}; "
          f"TensorBoard: tensorboard --logdir {logdir}")
def _learner_options(p: argparse.ArgumentParser) -> None:
    """``OPTIONS`` as :class:`GraspSettings` describes them, with its defaults (the measured best);
    ``--t-dtheta`` in degrees."""
    defaults = GraspSettings()
    for f in fields(GraspSettings):
        if f.name not in OPTIONS:
            continue
        flag, default, text = "--" + f.name.replace("_", "-"), getattr(defaults, f.name), f.metadata["help"]
        if f.name == "t_dtheta":
            p.add_argument(flag, type=number, default=math.degrees(default), metavar=f.metadata["metavar"],
                           help=f"{text}, in degrees (default {math.degrees(default):g})")
        elif f.name == "finger_choice":
            p.add_argument(flag, choices=[str(c) for c in FingerChoice], default=str(default),
                           help=f"{text} (default {default}; see ftorch/grasp/learner.py)")
        else:
            p.add_argument(flag, type=number, default=default, metavar=f.metadata["metavar"],
                           help=f"{text}, with --finger-choice quality (default {default:g})")


def add_parser(commands) -> None:
    """The ``grasp`` sub-command and its options."""
    p = commands.add_parser("grasp", help="grasp pre-shaping experiments of chapter 6 (figures 6.13, 6.14, 6.17)")
    p.add_argument("--experiment", choices=EXPERIMENTS, default="clean",
                   help="clean (6.13a), noisy (6.13b), cue (6.14) or mixed (6.17; default clean)")
    p.add_argument("--pool", type=at_least(1, "a number of grasps", 100000), default=80,
                   help="simulated grasps per category (object kind and fingers; default 80)")
    p.add_argument("--best", type=at_least(1, "a number of grasps", 100000), default=20,
                   help="training grasps per category and fold (default 20)")
    p.add_argument("--epochs", type=at_least(1, "a number of passes", 1000), default=10,
                   help="passes over the training grasps (default 10)")
    _learner_options(p)
    p.add_argument("--size", type=at_least(1, "an image side in pixels", 1024), default=64, help="camera image side in pixels (default 64)")
    p.add_argument("--folds", type=int, choices=(1, 2), default=2, help="1 or 2 folds (default 2)")
    p.add_argument("--online", action="store_true", help="also learn on-line on the same objects, executing the "
                   "recommended grasps, and report off-line vs on-line")
    device_options(p)
    run_options(p, "runs/grasp-EXPERIMENT", repeated="repeat the experiment with seeds SEED, SEED+1, ... (into OUT/seedN): "
                "per-seed results and the spread of the reductions (default 1)", jobs="seeds",
                resume="continue each fold from its checkpoint in OUT (after its last epoch)")
    p.set_defaults(run=grasp_command)

