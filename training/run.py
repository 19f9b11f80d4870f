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
  explain --learner PATH IMAGE... --out DIR   a saved learner's recognition of each image
                               traced (alg. 4.4): DIR/<image>.json (each query's feature, value,
                               presence per network, location, beliefs) and DIR/<image>.png.
With no command at all it runs recognize on the built-in Plym-like task into runs/plym.
"""
from __future__ import annotations

import os
import signal
import sys

if __name__ == "__main__":  # Ctrl-C while torch is still loading is one line too (main takes over after)
    def _loading_interrupted(*_) -> None:
        """Nothing is written before main, so the process ends at once (and a second Ctrl-C is
        ignored); SystemExit raised here could land in Python code that torch's C++ is running
        while it loads, which then aborts ("terminate called ..., SIGABRT")."""
        signal.signal(signal.SIGINT, signal.SIG_IGN)
        print("interrupted", file=sys.stderr, flush=True)
        os._exit(130)

    signal.signal(signal.SIGINT, _loading_interrupted)

import argparse  # noqa: E402
import threading  # noqa: E402
from pathlib import Path  # noqa: E402

from ftorch.errors import InputError  # noqa: E402
from training.cli.arguments import Parser  # noqa: E402
from training.commands import evaluate, explain, recognize, robustness, salient, tradeoff  # noqa: E402
from training.grasping.command import add_parser as add_grasp_parser  # noqa: E402


def parser() -> argparse.ArgumentParser:
    """The command line: one sub-command per module of training/commands (grasp: training/grasping/command.py)."""
    top = Parser(prog="ftorch" if Path(sys.argv[0]).name == "ftorch" else "python -m training.run",
                 description=__doc__.split("\n\n")[0])
    commands = top.add_subparsers(dest="command")
    recognize.add_parsers(commands)
    add_grasp_parser(commands)
    for command in (evaluate, robustness, tradeoff, salient, explain):
        command.add_parser(commands)
    return top


def _interrupted(*_) -> None:
    """SIGINT (Ctrl-C) or SIGTERM (a cluster's scheduler, kill, timeout): the first one stops the run
    as a KeyboardInterrupt; any later one is ignored. Otherwise a second Ctrl-C in quick succession
    raised another KeyboardInterrupt in the first one's cleanup (the end of the workers, the join of
    the process pool's thread at exit: "Exception ignored in threading._shutdown") or, once Python had
    put SIGINT's default action back on its way out, killed the runner (exit status -2, not 130).
    SIG_IGN, unlike a Python handler, is kept until the process has ended."""
    sys.unraisablehook = _RaceIgnored(sys.unraisablehook)
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
    raise KeyboardInterrupt


class _RaceIgnored:
    """``sys.unraisablehook`` once the run is interrupted: a signal that came a moment before SIG_IGN
    was set is reported by Python as "Signal N ignored due to race condition" (bpo-43406), a line
    for a signal that was meant to be ignored, so it is dropped; anything else goes to ``hook``."""

    def __init__(self, hook):
        self.hook = hook

    def __call__(self, unraisable) -> None:
        if not (isinstance(unraisable.exc_value, OSError)
                and str(unraisable.exc_value).endswith("ignored due to race condition")):
            self.hook(unraisable)


def _thread_failed(failure) -> None:
    """A background thread's exception: an OSError (TensorBoard's event writer on a full disk) is
    raised again in the main thread at its next write and reported there in one line, so it is
    not printed here as a traceback; anything else is."""
    if not issubclass(failure.exc_type, OSError):
        threading.__excepthook__(failure)


def main(argv: list[str] | None = None) -> int:
    signal.signal(signal.SIGINT, _interrupted)
    signal.signal(signal.SIGTERM, _interrupted)
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
        done = "epochs" if args.command == "grasp" else "cycles"  # what a checkpoint is written after
        print("interrupted" + (f"; the checkpoints in {where} keep the {done} finished up to their last write: run the same "
                               "command with --resume to continue" if where else ""), file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
