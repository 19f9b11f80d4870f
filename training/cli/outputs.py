"""Output folders, checked before any work is done, never shared by two runs, and never emptied of a user's files.

Every command calls :func:`writable_folder` for ``--out`` (and ``--logdir``) first, so a path
that is a file, cannot be created or cannot be written gives one line before a minute is spent.
``recognize``, ``incremental`` and ``grasp`` hold their folder as a :class:`RunFolder`:

- **A lock.** The run holds an exclusive ``flock`` on ``OUT/.ftorch-lock`` (and on the log
  folder's, where that lies outside OUT) for as long as it lives, ``--workers`` and Ray tasks
  included, since the runner waits for them. A second run in the same folder, or ``--resume`` of a
  run still going, is refused with one line naming the holder. The kernel drops the lock with the
  process that held it, so a run that was killed (even by SIGKILL) leaves a stale lock file that
  the next run simply takes over.
- **A ledger** of what the run writes: ``OUT/.ftorch-run``, one JSON line per file (``{"file":
  PATH}``) or TensorBoard run folder (``{"events": PATH}``), appended by whichever process
  writes it, *before* it writes it, so an interrupted run's ledger holds everything it left.
  Paths are relative to OUT, or absolute where they lie outside it (a ``--logdir`` elsewhere).
- **Overwrite removes only what a ledger records**: files, and the ``events.out.tfevents.*`` files
  of recorded TensorBoard runs, each only where it lies inside OUT or the log folder (a ledger
  that names other paths, or links out of them, removes nothing there); folders left empty go
  too. A user's files are never removed, whatever their names. The removal happens in
  :meth:`RunFolder.clear`, which a command calls only once every input has been checked (data,
  images, memory), so that a typo in ``--data`` or a bad image loses nothing. A folder written
  before ledgers existed has its TensorBoard event files removed and nothing else (a note names
  what is kept).
- A folder that holds a run (a ledger naming files that exist, or what runs write, from before
  ledgers) is refused unless ``--resume`` continues it or ``--overwrite`` replaces it.
"""
from __future__ import annotations

import fcntl
import json
import os
import re
import socket
import sys
import tempfile
import time
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from ftorch.checkpoint import write_text
from ftorch.errors import InputError

LEDGER, LOCK = ".ftorch-run", ".ftorch-lock"
EVENTS = "events.out.tfevents."  # the prefix of every TensorBoard event file
# what recognize, incremental and grasp wrote in a run folder before ledgers: how such a folder is known
RUN_ENTRIES = re.compile(r"^(report\.(json|md)|(curves|errors|grasps|growth|reductions)\.png|fold\d+(-online)?(_features\.png)?|"
                         r"seed\d+|robustness)$")
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


def writable_file(path, option: str) -> Path:
    """``path`` as a file that can be written (its folder created where missing); InputError if not,
    before any work is done (e.g. a benchmark's ``--json``)."""
    path = Path(path)
    if path.is_dir():
        raise InputError(f"{option} {path}: a folder is there, not a file")
    writable_folder(path.parent, option)
    if path.exists() and not os.access(path, os.W_OK):
        raise InputError(f"{option} {path}: cannot write there (the file is read-only)")
    return path


@dataclass(frozen=True)
class Ledger:
    """The ledger of a run folder ``root`` (module doc); picklable, so that worker processes and
    Ray tasks record what they write in the runner's ledger."""

    root: str

    @property
    def path(self) -> Path:
        return Path(self.root) / LEDGER

    def _entry(self, path) -> str:
        path, root = Path(path).absolute(), Path(self.root).absolute()
        return str(path.relative_to(root)) if path.is_relative_to(root) else str(path)

    def files(self, *paths) -> None:
        """Record files about to be written."""
        self._append([{"file": self._entry(p)} for p in paths])

    def events(self, *folders) -> None:
        """Record TensorBoard run folders about to be written."""
        self._append([{"events": self._entry(p)} for p in folders])

    def _append(self, entries: list[dict]) -> None:
        # one write of whole lines in append mode: appends of several processes do not interleave
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with open(self.path, "a", encoding="utf-8") as ledger:
            ledger.write("".join(json.dumps(e) + "\n" for e in entries))

    def entries(self) -> list[tuple[str, Path]]:
        """(kind, absolute path) of every entry; lines that are not entries (cut short, foreign) are skipped."""
        if not self.path.is_file():
            return []
        out = []
        for line in self.path.read_text(encoding="utf-8", errors="replace").splitlines():
            try:
                entry = json.loads(line)
            except ValueError:
                continue
            if isinstance(entry, dict) and len(entry) == 1:
                ((kind, path),) = entry.items()
                if kind in ("file", "events") and isinstance(path, str) and path:
                    out.append((kind, Path(self.root) / path))
        return out


def _holder(handle: int) -> str:
    """Who holds a lock, as its file says (written by :func:`_lock`)."""
    try:
        info = json.loads(os.pread(handle, 4096, 0).decode("utf-8"))
        return f"pid {info['pid']} on {info['host']}, since {info['started']}"
    except (OSError, ValueError, KeyError, TypeError):
        return "another process"


def _lock(folder: Path, option: str) -> int:
    """An exclusive lock on ``folder``/.ftorch-lock held by this process (its descriptor); InputError
    naming the holder where another live process holds it."""
    handle = os.open(folder / LOCK, os.O_RDWR | os.O_CREAT | getattr(os, "O_CLOEXEC", 0), 0o666)
    try:
        fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = _holder(handle)
        os.close(handle)
        raise InputError(f"{option} {folder}: another run is writing there ({holder}); wait for it to end, "
                         "or choose another folder") from None
    info = {"pid": os.getpid(), "host": socket.gethostname(), "started": time.strftime("%Y-%m-%d %H:%M:%S")}
    os.ftruncate(handle, 0)
    os.pwrite(handle, json.dumps(info).encode("utf-8"), 0)
    return handle


@contextmanager
def locked(folder: Path, option: str):
    """``folder`` locked for the ``with`` block (:func:`_lock`), e.g. a run folder that another
    command writes into (robustness results)."""
    handle = _lock(Path(folder), option)
    try:
        yield
    finally:
        os.close(handle)


def _inside(path: Path, roots: list[Path]) -> bool:
    """``path`` (not following a link at its end) lies inside one of ``roots``."""
    where = path.parent.resolve() / path.name
    return any(where.is_relative_to(root) for root in roots)


def _legacy_runs(out: Path, logdir: Path) -> tuple[list[Path], list[Path]]:
    """A folder written before ledgers: the entries runs write in ``out`` (not empty folders), and the
    TensorBoard event files in ``logdir``'s run folders."""
    found = [p for p in out.iterdir() if RUN_ENTRIES.match(p.name) and (not p.is_dir() or any(f.is_file() for f in p.rglob("*")))]
    events = [f for p in (logdir.iterdir() if logdir.is_dir() else []) if p.is_dir() and EVENT_RUNS.match(p.name)
              for f in p.rglob(f"{EVENTS}*") if f.is_file()]
    return sorted(found), sorted(events)


class RunFolder:
    """A run's ``out`` and ``logdir`` held for the run (module doc): ``with RunFolder(...) as folder``
    locks them and decides, ``folder.clear()`` removes the old run once the inputs are checked,
    ``folder.ledger`` records what the new run writes."""

    def __init__(self, out, logdir, resume: bool, overwrite: bool, can_resume: bool = True):
        if resume and overwrite:
            raise InputError("--resume continues the run in --out and --overwrite replaces it: give one of them")
        self.out = writable_folder(out)
        self.logdir = Path(logdir)
        self.resume, self.overwrite, self.can_resume = resume, overwrite, can_resume
        self.ledger = Ledger(str(self.out))
        self._locks: list[int] = []

    def __enter__(self) -> "RunFolder":
        try:
            self._locks.append(_lock(self.out, "--out"))
            if not self._logdir_inside():
                writable_folder(self.logdir, "--logdir")
                self._locks.append(_lock(self.logdir, "--logdir"))
            self._check()
        except BaseException:
            self._release()
            raise
        return self

    def __exit__(self, *_) -> None:
        self._release()

    def _release(self) -> None:
        for handle in self._locks:
            os.close(handle)  # closing the descriptor drops its flock
        self._locks = []

    def _logdir_inside(self) -> bool:
        return self.logdir.absolute().is_relative_to(self.out.absolute())

    def _roots(self) -> list[Path]:
        return [self.out.resolve(), self.logdir.resolve()]

    def _recorded(self) -> list[Path]:
        """What the ledger records that is there to remove, each inside OUT or the log folder."""
        out = []
        for kind, path in self.ledger.entries():
            if not _inside(path, self._roots()):
                continue
            if kind == "file" and (path.is_file() or path.is_symlink()):
                out.append(path)
            elif kind == "events" and path.is_dir() and not path.is_symlink():
                out += [f for f in path.glob(f"{EVENTS}*") if f.is_file() or f.is_symlink()]
        return list(dict.fromkeys(out))

    def _check(self) -> None:
        """Refuse a folder that holds a run, unless resumed or overwritten."""
        if self.resume:
            if not list(self.out.glob("fold*/checkpoint.json")) and not list(self.out.glob("seed*/fold*/checkpoint.json")):
                print(f"note: no checkpoint in {self.out}; --resume starts afresh", file=sys.stderr)
            return
        if self.overwrite:
            return
        found = self._recorded() if self.ledger.path.is_file() else _legacy_runs(self.out, self.logdir)[0]
        if found:
            names = ", ".join(str(p) for p in found[:3])
            raise InputError(f"--out {self.out} already holds a run ({names}{', ...' if len(found) > 3 else ''}); "
                             + ("--resume continues it, " if self.can_resume else "") + "--overwrite replaces it")

    def clear(self) -> None:
        """With ``--overwrite``: remove what the old run wrote (module doc) and start a new ledger.
        Call it once the new run's inputs are checked."""
        if not self.overwrite:
            return
        if self.ledger.path.is_file():
            removed = self._recorded()
        else:
            found, removed = _legacy_runs(self.out, self.logdir)
            if found:
                print(f"note: {self.out} has no ledger of a run; its files are kept (among them "
                      f"{', '.join(p.name for p in found[:3])}{', ...' if len(found) > 3 else ''}), "
                      "and the new run writes beside them", file=sys.stderr)
        for path in removed:
            path.unlink(missing_ok=True)
        for folder in sorted({p.parent for p in removed}, key=lambda p: len(p.parts), reverse=True):
            self._remove_empty(folder)
        write_text(self.ledger.path, "")

    def _remove_empty(self, folder: Path) -> None:
        """``folder`` and its parents, while empty, up to OUT or the log folder (kept)."""
        roots = {self.out.absolute(), self.logdir.absolute()}
        folder = folder.absolute()
        while folder not in roots and any(folder.is_relative_to(r) for r in roots):
            try:
                folder.rmdir()
            except OSError:
                return  # not empty (a user's file, a folder of theirs) or gone
            folder = folder.parent
