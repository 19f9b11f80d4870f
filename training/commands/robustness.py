"""``robustness``: a run's learners and the peers on perturbed test views (7.2)."""
from __future__ import annotations

import json
import time
from pathlib import Path

import torch

from ftorch import FeatureSpace
from ftorch.checkpoint import write_text
from ftorch.errors import InputError
from ftorch.recognition.learner import DistinctiveFeatureLearner
from ftorch.recognition.settings import Evidence, LearnerSettings
from ftorch.space.draw import save_rgb
from training.cli.arguments import number, seed
from training.cli.devices import described, machine, resolve_device
from training.cli.jobs import device_options
from training.cli.outputs import Command, Ledger, RunFolder, apart, locked, writable_folder
from training.plots import feature_types_figure, figure_rgb
from training.recognition.protocol import RecordedTask, same_images
from training.recognition.records import recognize_run
from training.recognition.report import (
    write_json,
)
from training.recognition.robustness import SETS, TABLE_CELLS, Robustness, feature_tables, fold_robustness, perturbations
from training.recognition.robustness import average as average_robustness
from training.recognition.robustness import table as robustness_table


def robustness_command(args) -> int:
    """The robustness benchmark on a recognize run's folds (training/recognition/robustness.py)."""
    device = resolve_device(args.device)
    kinds = perturbations(args.perturb)
    if args.test_information is not None:
        LearnerSettings(test_information=args.test_information)  # refuses a bad threshold early
    run = Path(args.run_folder)
    out = Path(args.out) if args.out else run / "robustness"
    apart({"--out": out}, {"--data": args.data or _recorded_data(run)})  # before a folder is made, let alone written
    if args.out:
        writable_folder(out)  # a file there, or a folder that cannot be written: before the run is read
    if not run.is_dir():
        raise InputError(f"--run {run}: not a run folder of recognize (no such folder)")
    # results written inside the run folder belong to the run: the run is locked meanwhile, and they
    # are recorded in its ledger, so --overwrite of the run replaces them and nothing else; elsewhere
    # the folder is robustness's own (a run of another command there is refused)
    if out.absolute().is_relative_to(run.absolute()):
        with locked(run, "--run"):
            return _robustness(args, device, kinds, run, writable_folder(out), Ledger(str(run)))
    with RunFolder(out, out, False, True, Command.ROBUSTNESS, can_resume=False) as folder:
        return _robustness(args, device, kinds, run, folder.out, folder.ledger)


def _recorded_data(run: Path) -> str | None:
    """The image folder the run's report records (None where it records none, or is no report)."""
    try:
        data = json.loads((run / "report.json").read_text())["config"]["data"]  # before the run is checked: only this
    except (OSError, ValueError, KeyError, TypeError, RecursionError):
        return None
    return data if isinstance(data, str) else None


def _robustness(args, device: torch.device, kinds: list[str], run: Path, out: Path, ledger: Ledger) -> int:
    """The body of :func:`robustness_command` once its output folder is held."""
    with recognize_run(run, "--run") as (report, config):
        recorded = RecordedTask.from_json(config)
        data = args.data or recorded.data
        folds = [f.fold for f in report.folds]
        if not folds:
            raise ValueError("no folds")
    task = recorded.load(data)  # outside the try: its own refusals (a missing --data) are one line already
    same_images(task, recorded.images, f"--run {run}", data)
    start = time.perf_counter()
    space = FeatureSpace().to(device)
    answering = {"evidence": args.evidence} if args.evidence != "learned" else {}
    if args.test_information is not None:
        answering["test_information"] = args.test_information
    results = []
    for k in folds:
        learner = DistinctiveFeatureLearner.load(run / f"fold{k}" / "learner.json").set_params(**answering)
        results.append(fold_robustness(task, k, learner, kinds, args.seed, space, args.peers, out, not args.quiet, ledger))
    result = Robustness(str(run), str(data), args.seed, kinds, args.evidence, args.test_information, report.config, results,
                        average_robustness(results), machine(device), time.perf_counter() - start)
    types = result.average.types
    ledger.files(out / "robustness.json", out / "robustness.md", *([out / "features.png"] if types else []))
    write_json(out / "robustness.json", result.to_json())
    if types:
        save_rgb(out / "features.png", figure_rgb(feature_types_figure(types, f"{run}: which features survive, "
                                                                              f"perturbation seed {args.seed}")))
    lines = [f"# Robustness of {run}", "", f"{len(folds)} folds, perturbation seed {args.seed}, evidence {args.evidence}, "
             f"{described(result.machine)}, {result.seconds:.1f} s. Each method's cells: {TABLE_CELLS}, "
             "mean over folds. Ours is set against the peers on top-1 accuracy (one label per image, as each peer "
             "answers); def. 4.6's accuracy is the thesis's figure for its open-world answer. \"flipped\": the share of "
             "(network node, test view) whose state differs from the clean view's.", "", *robustness_table(result), "",
             *[f"![fold {k}](fold{k}/overview.png)" for k in folds], "", *feature_tables(result),
             *(["![which features survive](features.png)", ""] if types else [])]
    write_text(out / "robustness.md", "\n".join(lines))
    print("\n".join(robustness_table(result)))
    print(f"report: {out / 'robustness.md'} and {out / 'robustness.json'}; perturbed images in {out}/foldK/SET/")
    return 0


def add_parser(commands) -> None:
    """The ``robustness`` sub-command and its options."""
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
    device_options(p)
    p.set_defaults(run=robustness_command)
