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
from dataclasses import fields
from pathlib import Path

import numpy as np
import torch

from ftorch import FeatureSpace
from ftorch.checkpoint import DAMAGED, load_checkpoint, save_checkpoint
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
from .report import grasp_columns, reduction_words, results, seed_study, write_markdown

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


def _quality(split: np.ndarray) -> dict | None:
    """A feature's quality split for the report (ftorch/grasp/learner.py), None where it has none."""
    power, cut, above, below = (float(v) for v in split)
    return {"ksd": power, "cut": cut, "mu0_above": above, "mu0_below": below} if power > 0 else None


def config(args, device) -> dict:
    return {"experiment": args.experiment, "seed": args.seed, "pool": args.pool, "best": args.best, "epochs": args.epochs,
            "size": args.size, "t_dtheta_deg": args.t_dtheta, "folds": args.folds, "online": args.online,
            "finger_choice": args.finger_choice, "mu0_split": learner_settings(args).mu0_split,
            "device": str(device)}


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
        step = entry["epoch"] + 1
        for tag in ("mistakes", "poor", "features_2", "features_3", "sampled_2", "sampled_3"):
            writer.add_scalar(f"epoch/{tag}", entry[tag], step)
        judged = [e is not None for e in predicted["error_deg"]]
        measured = [m for m, j in zip(predicted["measured_mu0"], judged) if j]
        writer.add_scalar("epoch/unpredicted", judged.count(False), step)
        writer.add_scalar("epoch/no_finger_choice", predicted["fingers"].count(None), step)
        writer.add_scalar("epoch/no_equilibrium", measured.count(None), step)
        _histogram(writer, "epoch/orientation_error_deg", predicted["error_deg"], step)
        _histogram(writer, "epoch/mu0_expected", predicted["expected_mu0"], step)
        _histogram(writer, "epoch/mu0_measured", measured, step)
        _histogram(writer, "epoch/fingers_chosen", predicted["fingers"], step)


def log_fold(writer, settings: dict, fold: GraspFold, evaluation: dict, pictures: dict) -> None:
    """The epochs (:func:`log_epochs`), then the fold's tests (step: the epochs trained): histograms of
    the orientation errors, probes and mu_0 (capped at MU0_CAP) that exist, the grasps without a
    prediction or without equilibrium counted, the report's summaries, hyper-parameters and figures
    (matplotlib charts with ``add_figure``, which closes them, RGB pictures with ``add_image``)."""
    log_epochs(writer, fold)
    step = len(fold.epochs)
    res = results([evaluation])
    errors = evaluation["orientation_errors_deg"]
    _histogram(writer, "fold/orientation_error_deg", errors, step)
    writer.add_scalar("fold/unpredicted", errors.count(None), step)
    for side in ("haptic", "cued"):
        mu0 = [g["mu0"] for g in evaluation[side]]
        writer.add_histogram(f"fold/probes_{side}", np.array([g["probes"] for g in evaluation[side]]), step)
        _histogram(writer, f"fold/mu0_{side}", [None if m is None else min(m, MU0_CAP) for m in mu0], step)
        writer.add_scalar(f"fold/no_equilibrium_{side}", mu0.count(None), step)
        writer.add_scalar(f"fold/probes_{side}_mean", res["probes"][side]["mean"], step)
        writer.add_scalar(f"fold/mu0_{side}_median", res["mu0"][side]["median"], step)
        writer.add_scalar(f"fold/poor_{side}", res["poor_grasp_fraction"][side], step)
    writer.add_scalar("fold/orientation_error_median_deg", res["orientation_error_deg"]["median"], step)
    writer.add_scalar("fold/orientation_error_p90_deg", res["orientation_error_deg"]["p90"], step)
    hparams = {k: v for k, v in settings.items() if isinstance(v, (int, float, str, bool))}
    metrics = {"hparam/orientation_error_median_deg": res["orientation_error_deg"]["median"],
               "hparam/poor_haptic": res["poor_grasp_fraction"]["haptic"], "hparam/poor_cued": res["poor_grasp_fraction"]["cued"]}
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


def _stored(path: Path, config: dict, fold: int) -> dict | None:
    """The checkpoint of a fold to resume (None where there is none); InputError for a damaged or foreign
    file, or one written under other settings."""
    if not path.is_file():
        return None
    data = load_checkpoint(path, FOLD_KIND)
    if data.get("config") != config or data.get("fold") != fold:
        raise InputError(f"{path}: written by a different run configuration; use another --out or delete it to start afresh")
    if not isinstance(data.get("done"), bool) or not isinstance(data.get("state"), dict) or \
            (data["done"] and not isinstance(data.get("entry"), dict)):
        raise InputError(f"{path}: damaged grasp fold checkpoint (no state, or an ended fold without its report entry)")
    return data


def _save(path: Path, config: dict, fold: GraspFold, entry: dict | None = None) -> None:
    """A fold's checkpoint: its state after the last epoch, and once it has ended (``entry``), its report entry."""
    save_checkpoint(path, FOLD_KIND, {"config": config, "fold": fold.k, "done": entry is not None,
                                      "state": fold.state_dict(), "entry": entry})


def seed_task(job: dict) -> dict:
    """One seed of the experiment: every fold, off-line (and on-line), into ``job['out']`` (report,
    figures, each fold's checkpoint in foldK/) and TensorBoard ``job['logdir']``/foldK; returns its
    report. With ``resume``, each fold goes on from its checkpoint (module doc). Picklable, for local
    processes and Ray (training/cli/parallel.py)."""
    from torch.utils.tensorboard import SummaryWriter

    args, seed, ledger = argparse.Namespace(**job["args"]), job["seed"], job["ledger"]
    out, logdir = Path(job["out"]), Path(job["logdir"])
    out.mkdir(parents=True, exist_ok=True)
    start = time.perf_counter()
    device = resolve_device(args.device)
    torch.manual_seed(seed)
    settings = {**config(args, device), "seed": seed}
    controller = HapticController()
    space = FeatureSpace().to(device)
    pool = simulate_pool(args.experiment, args.pool, seed, args.size, controller, not args.quiet)
    modes = ("offline", "online") if args.online else ("offline",)
    evaluations = {mode: [] for mode in modes}
    folds, figures = [], []
    for k in range(1, args.folds + 1):
        for mode in modes:
            name = f"fold{k}" + ("-online" if mode == "online" else "")
            checkpoint, fold_config = out / name / "checkpoint.json", {**settings, "mode": mode}
            stored = _stored(checkpoint, fold_config, k) if args.resume else None
            if stored is None or not stored["done"]:
                share_idle_cores()  # the last seeds of a --workers run take the idle cores
                learner = GraspLearner(learner_settings(args), seed=seed * 100 + k, device=device)
                fold = GraspFold(k, args.experiment, pool, args.best, space, learner, controller, seed, not args.quiet)
                if stored is not None:
                    try:
                        fold.load_state_dict(stored["state"])
                    except DAMAGED as err:
                        raise InputError(f"{checkpoint}: damaged grasp fold checkpoint ({type(err).__name__}: {err})") from None
                    for events in (logdir / name).glob(f"{EVENTS}*"):  # what an interrupted log may have left
                        events.unlink()
                ledger.files(checkpoint)
                fold.fit(args.epochs, online=mode == "online", after_epoch=lambda: _save(checkpoint, fold_config, fold))
                evaluation = fold.evaluate()
                which = f"{args.experiment}, seed {seed}, {name}"
                pictures = {"errors": error_figure(evaluation["orientation_errors_deg"], f"{which}: orientation errors"),
                            "grasps": grasp_figure(grasp_columns([evaluation], args.experiment), f"{which}: probes and mu_0"),
                            "features": recommended_features(fold, which)}
                ledger.events(logdir / name)
                with SummaryWriter(str(logdir / name)) as writer:
                    log_fold(writer, fold_config, fold, evaluation, pictures)
                ledger.files(out / f"{name}_features.png")
                save_rgb(out / f"{name}_features.png", pictures["features"])
                entry = {"fold": k, "mode": mode, "epochs": fold.epochs, **results([evaluation]), "tests": evaluation,
                         "features": {str(c): [dict(feature=f.to_dict(), model=m.to_dict() if m else None, quality=_quality(q))
                                               for f, m, q in zip(s.features, s.models, s.quality.T)]
                                      for c, s in learner.sets.items()}}
                _save(checkpoint, fold_config, fold, entry)
            else:
                entry = stored["entry"]
            evaluations[mode].append(entry["tests"])
            folds.append(entry)
            figures.append(f"{name}_features.png")
            last = entry["epochs"][-1]
            if not args.quiet:
                print(f"seed {seed} fold {k} {mode}: {len(entry['epochs'])} epochs, last with {last['mistakes']:.2f} "
                      f"mistakes; {last['features_2']} + {last['features_3']} features")
    offline = evaluations["offline"]
    ledger.files(*(out / name for name in ("errors.png", "grasps.png", "report.json", "report.md")))
    save_rgb(out / "errors.png", figure_rgb(error_figure([e for ev in offline for e in ev["orientation_errors_deg"]],
                                                         f"{args.experiment}, seed {seed}: orientation errors (figure 6.13)")))
    save_rgb(out / "grasps.png", figure_rgb(grasp_figure(grasp_columns(offline, args.experiment),
                                                         f"{args.experiment}, seed {seed}: probes and mu_0, haptic only vs "
                                                         "cued (figures 6.14, 6.17)")))
    figures = ["errors.png", "grasps.png", *figures]
    report = {"config": settings, "device": str(device), "machine": machine(device),
              "seconds": time.perf_counter() - start, **results(offline)}
    if args.online:
        report["online"] = {mode: results(evaluations[mode]) for mode in modes}
    report["folds"] = folds
    report["figures"] = figures
    write_json(out / "report.json", report)
    write_markdown(out / "report.md", report, figures)
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
    parallel = args.workers > 1 or args.ray is not None
    settings = {k: v for k, v in vars(args).items() if k not in ("run", "checkpoints")}
    settings["quiet"] = args.quiet or parallel  # one progress bar over the seeds instead
    seeds = range(args.seed, args.seed + args.seeds)
    jobs = [{"args": settings, "seed": s, "out": str(o), "logdir": str(t), "ledger": folder.ledger}
            for s, o, t in run_folders(args, out, logdir)]
    reports = run_jobs(seed_task, jobs, [f"seed {s}" for s in seeds], args, out, "seeds")
    report = reports[0]
    if args.seeds > 1:
        report["seeds"] = seed_study(reports)
        report["seconds"] = time.perf_counter() - start
        folder.ledger.files(out / "reductions.png")
        save_rgb(out / "reductions.png", figure_rgb(reduction_figure(report["seeds"],
                                                                     f"{args.experiment}, seeds {seeds[0]}-{seeds[-1]}")))
        report["figures"] = [*report["figures"], "reductions.png"]
        write_json(out / "report.json", report)
        write_markdown(out / "report.md", report, report["figures"])
    e, p = report["orientation_error_deg"], report["poor_grasp_fraction"]
    print(f"{args.experiment}, seed {args.seed}: orientation error median {e['median']:.1f} deg (p90 {e['p90']:.1f}); "
          f"poor grasps haptic {p['haptic']:.2f} -> cued {p['cued']:.2f}; probes {report['probes']['haptic']['mean']:.1f} "
          f"-> {report['probes']['cued']['mean']:.1f}")
    if args.online:
        on = report["online"]["online"]
        print(f"on-line: orientation error median {on['orientation_error_deg']['median']:.1f} deg; poor grasps cued "
              f"{on['poor_grasp_fraction']['cued']:.2f}")
    if args.seeds > 1:
        for mode, study in report["seeds"]["reduction"].items():
            cued, error = report["seeds"]["poor_cued"][mode], report["seeds"]["error_median_deg"][mode]
            print(f"{args.seeds} seeds, {mode}: {reduction_words(study, ' +- ')}; poor cued mean {cued['mean']:.2f}; "
                  f"median orientation error worst {error['worst']:.1f} deg (seed {error['worst_seed']})")
    print(f"{time.perf_counter() - start:.1f} s; report: {out / 'report.md'} and {out / 'report.json'}; "
          f"TensorBoard: tensorboard --logdir {logdir}")
    return 0


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

