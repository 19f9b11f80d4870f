"""Output folders, checked before any work is done, and never two runs mixed in one.

Every command calls :func:`writable_folder` for ``--out`` (and ``--logdir``) first, so a path
that is a file, cannot be created or cannot be written gives one line before a minute is spent.
``recognize`` and ``incremental`` also call :func:`run_folder`: a folder that already holds a
run is continued with ``--resume``, replaced with ``--overwrite`` (only the files runs write are
removed), and otherwise refused, since fold folders, seed folders and TensorBoard events of two
runs would mix.
"""
from __future__ import annotations

import shutil
import sys
import tempfile
from pathlib import Path

from ftorch.errors import InputError

RUN_ENTRIES = ("report.json", "report.md", "curves.png", "errors.png", "grasps.png", "fold*", "seed*", "tensorboard",
               "robustness")  # what recognize, incremental and grasp write in a run folder


def writable_folder(path, option: str = "--out") -> Path:
    """``path`` as a folder that exists and can be written (created where missing); InputError if not."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise InputError(f"{option} {path}: a file is there, not a folder")
    try:
        path.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=path) as probe:
            probe.write(b"ftorch")
            probe.flush()
    except OSError as err:
        raise InputError(f"{option} {path}: cannot write there ({err.strerror or err})") from None
    return path


def _runs(folder: Path) -> list[Path]:
    """What runs write in ``folder``: checkpoints, reports, fold and seed folders, TensorBoard events
    (empty folders left by a run that stopped at its first check do not count)."""
    return sorted({p for pattern in RUN_ENTRIES for p in folder.glob(pattern)
                   if not p.is_dir() or any(f.is_file() for f in p.rglob("*"))})


def run_folder(out, logdir, resume: bool, overwrite: bool) -> tuple[Path, Path]:
    """``out`` and ``logdir`` checked (:func:`writable_folder`) and free for this run: refused where a
    run already is, unless resumed or overwritten (module doc)."""
    if resume and overwrite:
        raise InputError("--resume continues the run in --out and --overwrite replaces it: give one of them")
    out, logdir = writable_folder(out), Path(logdir)
    folders = [out] if logdir == out / "tensorboard" else [out, logdir]
    found = [p for folder in folders for p in _runs(folder)]
    if resume:
        if not list(out.glob("fold*/checkpoint.json")) and not list(out.glob("seed*/fold*/checkpoint.json")):
            print(f"note: no checkpoint in {out}; --resume starts afresh", file=sys.stderr)
    elif found and not overwrite:
        names = ", ".join(str(p.relative_to(p.parent.parent)) for p in found[:3])
        raise InputError(f"--out {out}: already holds a run ({names}{', ...' if len(found) > 3 else ''}); "
                         "--resume continues it, --overwrite replaces it")
    else:
        for path in found:
            shutil.rmtree(path) if path.is_dir() else path.unlink()
    if logdir.exists() or not logdir.resolve().is_relative_to(out.resolve()):
        writable_folder(logdir, "--logdir")  # inside a writable out, it is made with its first events
    return out, logdir
