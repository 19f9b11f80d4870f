"""``tradeoff``: accuracy against bytes stored per class, against the peers."""
from __future__ import annotations

from contextlib import ExitStack
from pathlib import Path

from ftorch import FeatureSpace
from ftorch.checkpoint import write_text
from ftorch.errors import InputError
from ftorch.space.draw import save_rgb
from training.cli.arguments import seed
from training.cli.devices import described, machine, resolve_device
from training.cli.jobs import device_options
from training.cli.outputs import Command, RunFolder, apart, locked
from training.plots import figure_rgb, tradeoff_figure
from training.recognition.report import (
    write_json,
)
from training.recognition.robustness import SETS, perturbations
from training.recognition.tradeoff import table as tradeoff_table
from training.recognition.tradeoff import tradeoff


def tradeoff_command(args) -> int:
    """The accuracy-per-byte front of recognize runs against the peers (training/recognition/tradeoff.py)."""
    from torch.utils.tensorboard import SummaryWriter

    device = resolve_device(args.device)
    kinds = perturbations(args.perturb)
    runs = [Path(r) for r in dict.fromkeys(args.runs)]
    out = Path(args.out)
    for run in runs:  # the front is written beside the runs and their images, not inside one
        apart({"--out": out}, {"--runs": run, "--data": args.data})
    with ExitStack() as held:
        for run in runs:  # a run still being written is refused, and none changes meanwhile
            if not run.is_dir():
                raise InputError(f"--runs {run}: no such run folder")
            held.enter_context(locked(run, "--runs"))
        folder = held.enter_context(RunFolder(out, out / "tensorboard", False, args.overwrite, Command.TRADEOFF, can_resume=False))
        result = tradeoff(runs, kinds, args.seed, FeatureSpace().to(device), args.data, not args.quiet)
        folder.clear()
        result.machine = machine(device)
        heading = (f"{result.task}, {len(result.classes)} classes, {len(runs)} run(s), perturbation seed {args.seed}: "
                   "top-1 accuracy against bytes stored per class")
        folder.ledger.files(out / "tradeoff.json", out / "tradeoff.md", out / "front.png")
        folder.ledger.events(out / "tensorboard")
        write_json(out / "tradeoff.json", result.to_json())
        front = figure_rgb(tradeoff_figure(result, heading))  # drawn once, for the PNG and TensorBoard
        save_rgb(out / "front.png", front)
        lines = [f"# Accuracy per byte: {result.task}", "", f"Runs {', '.join(result.runs)}; sets {', '.join(kinds)}; "
                 f"{described(result.machine)}, {result.seconds:.1f} s. Top-1 accuracy (one label per image: ftorch's "
                 "top label, each peer's best class), on which the methods are compared, and accuracy (def. 4.6, "
                 "ftorch's open-world answer as the thesis scores it), each seed weighted equally; bytes: what each "
                 "method stores per class (training/recognition/tradeoff.py).", "",
                 *tradeoff_table(result), "", "![the front](front.png)", ""]
        write_text(out / "tradeoff.md", "\n".join(lines))
        with SummaryWriter(str(out / "tensorboard")) as writer:
            writer.add_image("tradeoff/front", front, 0, dataformats="HWC")
            writer.add_text("tradeoff/table", "\n".join(tradeoff_table(result)), 0)
    print("\n".join(tradeoff_table(result)))
    print(f"report: {out / 'tradeoff.md'}, {out / 'tradeoff.json'} and {out / 'front.png'}")
    return 0


def add_parser(commands) -> None:
    """The ``tradeoff`` sub-command and its options."""
    p = commands.add_parser("tradeoff", help="accuracy against bytes stored per class, against SIFT and pixel 1-NN")
    p.add_argument("--runs", nargs="+", required=True, metavar="RUN", help="run folders written by recognize on one "
                   "task (e.g. with different --redundancy); every seed's learners are used")
    p.add_argument("--data", help="the runs' image folder, where it has moved (default: as recorded in the runs)")
    p.add_argument("--perturb", default="all", help=f"all (default) or a comma-separated list of {', '.join(SETS)}")
    p.add_argument("--seed", type=seed, default=0, help="seed of the perturbations (default 0)")
    p.add_argument("--out", default="runs/tradeoff", help="output folder (default runs/tradeoff)")
    p.add_argument("--overwrite", action="store_true", help="replace the front already in OUT")
    device_options(p)
    p.set_defaults(run=tradeoff_command)
