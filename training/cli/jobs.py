"""The skeleton every run command shares (recognize, incremental, grasp).

A run is: options checked (:func:`check_seeds` and the command's own), the run folder held
(:class:`~training.cli.outputs.RunFolder`: locked, never mixed with another run, replaced only with
--overwrite and only once the inputs are good), a Ray cluster reached where asked, then independent
jobs (folds, seeds) run here, in local processes or on Ray (:func:`run_jobs`), and their results
folded into one report. The options that shape a run are the same words in every command
(:func:`run_options`).
"""
from __future__ import annotations

import argparse
from collections.abc import Callable, Sequence
from pathlib import Path

from ftorch.errors import InputError

from .arguments import MAX_SEED, at_least, seed
from .parallel import TasksFailed, run_tasks


def device_options(p: argparse.ArgumentParser, quiet: bool = True) -> None:
    """--device (and --quiet): every command's."""
    p.add_argument("--device", default="auto", help="cpu, cuda[:N] or auto (default)")
    if quiet:
        p.add_argument("--quiet", action="store_true", help="no progress bars")


def run_options(p: argparse.ArgumentParser, out: str, repeated: str, jobs: str, resume: str) -> None:
    """--seed, --seeds, --out, --logdir, --resume, --overwrite, --workers, --ray: ``out`` says where a run
    goes by default, ``repeated`` what --seeds repeats, ``jobs`` what the workers run, ``resume`` what
    --resume continues from."""
    p.add_argument("--seed", type=seed, default=0, help="seed of every random choice (default 0)")
    p.add_argument("--seeds", type=at_least(1, "a number of seeds", 1000), default=1, help=repeated)
    p.add_argument("--out", help=f"run folder (default {out})")
    p.add_argument("--logdir", help="TensorBoard folder (default OUT/tensorboard)")
    p.add_argument("--resume", action="store_true", help=resume)
    p.add_argument("--overwrite", action="store_true", help="replace the run already in OUT (without it, or --resume, "
                   "a folder that holds a run is refused)")
    p.add_argument("--workers", type=at_least(1, "a number of processes", 1024), default=1,
                   help=f"run the {jobs} as N local processes at once (default 1: one after another); the report is the same")
    p.add_argument("--ray", metavar="ADDRESS", help=f"run the {jobs} as tasks on a Ray cluster (ray.init address, e.g. "
                   "auto or ray://HEAD:10001; local: a local instance with --workers CPUs); needs the distributed extra")


def check_seeds(args) -> None:
    """--seed S --seeds N: the last seed, S + N - 1, must be a seed too."""
    if args.seed + args.seeds - 1 > MAX_SEED:
        raise InputError(f"--seed {args.seed} --seeds {args.seeds}: the last seed would pass {MAX_SEED}")


def run_folders(args, out: Path, logdir: Path) -> list[tuple[int, Path, Path]]:
    """(seed, run folder, TensorBoard folder) of each seed: the first in ``out`` itself, the others in
    ``out``/seedN and ``logdir``/seedN."""
    return [(s, out if s == args.seed else out / f"seed{s}", logdir if s == args.seed else logdir / f"seed{s}")
            for s in range(args.seed, args.seed + args.seeds)]


def run_jobs(function: Callable, jobs: Sequence, names: Sequence[str], args, out: Path, what: str) -> list:
    """``function`` on every job (training/cli/parallel.py), as --workers and --ray say, their results
    in the jobs' order; jobs that failed twice end the run with one line naming them."""
    try:
        return run_tasks(function, jobs, names, args.workers, args.ray, progress=not args.quiet)
    except TasksFailed as failed:
        raise InputError(f"{len(failed.failures)} of {len(jobs)} {what} failed twice ({failed}); "
                         f"the other {what}' folders in {out} are complete") from None
