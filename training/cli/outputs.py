"""Output folders, checked before any work is done, and never two runs mixed in one.

Every command calls :func:`writable_folder` for ``--out`` (and ``--logdir``) first, so a path
that is a file, cannot be created or cannot be written gives one line before a minute is spent.
``recognize``, ``incremental`` and ``grasp`` call :func:`run_folder` instead: a folder that already holds a
run is continued with ``--resume``, replaced with ``--overwrite`` (only the files runs write are
removed), and otherwise refused, since fold folders, seed folders and TensorBoard events of two
runs would mix.
"""
from __future__ import annotations

import re
import shutil
import sys
import tempfile
from pathlib import Path

from ftorch.errors import InputError

RUN_ENTRIES = re.compile(r"^(report\.(json|md)|(curves|errors|grasps|growth|reductions)\.png|fold\d+(-online)?(_features\.png)?|"
                         r"seed\d+|robustness)$")  # what recognize, incremental and grasp write in a run folder
EVENT_RUNS = re.compile(r"^(fold\d+(-online)?|seed\d+)$")  # TensorBoard runs in a log folder


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


def _runs(out: Path, logdir: Path) -> list[Path]:
    """What an earlier run wrote: in ``out`` the entries runs write (``RUN_ENTRIES``, not empty
    folders), in ``logdir`` the TensorBoard runs that hold event files and nothing else. Files of
    other names are never counted, so ``--overwrite`` never removes them."""
    found = [p for p in (out.iterdir() if out.is_dir() else []) if RUN_ENTRIES.match(p.name)
             and (not p.is_dir() or any(f.is_file() for f in p.rglob("*")))]
    if logdir.is_dir():
        for p in logdir.iterdir():
            files = [f for f in p.rglob("*") if f.is_file()] if p.is_dir() and EVENT_RUNS.match(p.name) else []
            if files and all(f.name.startswith("events.out.tfevents.") for f in files) and p not in found:
                found.append(p)
    return sorted(found)


def run_folder(out, logdir, resume: bool, overwrite: bool, can_resume: bool = True) -> tuple[Path, Path]:
    """``out`` and ``logdir`` checked (:func:`writable_folder`) and free for this run: refused where a
    run already is, unless resumed or overwritten (module doc)."""
    if resume and overwrite:
        raise InputError("--resume continues the run in --out and --overwrite replaces it: give one of them")
    out, logdir = writable_folder(out), Path(logdir)
    found = _runs(out, logdir)
    if resume:
        if not list(out.glob("fold*/checkpoint.json")) and not list(out.glob("seed*/fold*/checkpoint.json")):
            print(f"note: no checkpoint in {out}; --resume starts afresh", file=sys.stderr)
    elif found and not overwrite:
        names = ", ".join(str(p) for p in found[:3])
        raise InputError(f"--out {out} already holds a run ({names}{', ...' if len(found) > 3 else ''}); "
                         + ("--resume continues it, " if can_resume else "") + "--overwrite replaces it")
    else:
        for path in found:
            shutil.rmtree(path) if path.is_dir() else path.unlink()
    if logdir.exists() or not logdir.resolve().is_relative_to(out.resolve()):
        writable_folder(logdir, "--logdir")  # inside a writable out, it is made with its first events
    return out, logdir
