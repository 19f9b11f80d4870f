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

import errno
import fcntl
import json
import os
import re
import socket
import stat
import sys
import tempfile
import time
from contextlib import contextmanager
from dataclasses import dataclass
from enum import StrEnum
from pathlib import Path

from ftorch.checkpoint import Target, write_target, write_text
from ftorch.errors import InputError

LEDGER, LOCK = ".ftorch-run", ".ftorch-lock"


class Command(StrEnum):
    """The commands that write a folder: a folder holds the output of one of them at a time."""

    RECOGNIZE = "recognize"
    INCREMENTAL = "incremental"
    GRASP = "grasp"
    EVALUATE = "evaluate"
    ROBUSTNESS = "robustness"
    TRADEOFF = "tradeoff"
    SALIENT = "salient"
    EXPLAIN = "explain"


# the report each command writes at the top of its folder: how a folder is known whose ledger does not name its command
REPORTS = {"tradeoff.json": Command.TRADEOFF, "robustness.json": Command.ROBUSTNESS, "evaluate.json": Command.EVALUATE,
           "salient.json": Command.SALIENT}
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


def apart(outputs: dict[str, object], inputs: dict[str, object]) -> None:
    """InputError where an output folder (by option) lies inside an input folder or holds one: a
    run's pictures written into its class folders become a class of the next run, perturbed views
    written into a data set become part of it. Paths are compared resolved (links followed); None
    (an option not given) is skipped."""
    for output, out in outputs.items():
        for given, source in inputs.items():
            if out is None or source is None:
                continue
            where, what = Path(out).resolve(), Path(source).resolve()
            if where.is_relative_to(what) or what.is_relative_to(where):
                relation = "is" if where == what else "lies inside" if where.is_relative_to(what) else "holds"
                raise InputError(f"{output} {out} {relation} {given} {source}: what is written there would be read as "
                                 f"input by the next run; choose an {output} outside it")


def writable_file(path, option: str) -> Path:
    """``path`` as a file that can be written (its folder created where missing); InputError if not,
    before any work is done (e.g. a benchmark's ``--json``). A pipe, /dev/null or the process's own
    output is written in place; a folder, a device or a socket is refused (:func:`write_target`)."""
    path = Path(path)
    try:
        target = write_target(path)
    except InputError as err:
        raise InputError(f"{option} {err}") from None
    if target is Target.IN_PLACE:
        if not os.access(path, os.W_OK):
            raise InputError(f"{option} {path}: cannot write there")
        return path
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

    def start(self, command: Command) -> None:
        """A new ledger, of a run of ``command`` (its first line)."""
        os.close(_open_own(self.path, os.O_WRONLY | os.O_CREAT))  # refuses a link or a special file there
        write_text(self.path, json.dumps({"command": str(command)}) + "\n")

    def command(self) -> Command | None:
        """The command the ledger's run is of; None where it does not say (a ledger written before it did)."""
        if not self.path.is_file() or self.path.is_symlink():
            return None
        try:
            with open(self.path, encoding="utf-8", errors="replace") as ledger:
                first = json.loads(ledger.readline())
            return Command(first["command"])
        except (OSError, ValueError, KeyError, TypeError):
            return None

    def files(self, *paths) -> None:
        """Record files about to be written."""
        self._append([{"file": self._entry(p)} for p in paths])

    def events(self, *folders) -> None:
        """Record TensorBoard run folders about to be written."""
        self._append([{"events": self._entry(p)} for p in folders])

    def _append(self, entries: list[dict]) -> None:
        # one write of whole lines in append mode: appends of several processes do not interleave
        self.path.parent.mkdir(parents=True, exist_ok=True)
        with os.fdopen(_open_own(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT), "a", encoding="utf-8") as ledger:
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


def _open_own(path: Path, flags: int) -> int:
    """A descriptor of ftorch's own bookkeeping file ``path`` (the lock, the ledger), opened with
    ``flags``; InputError where something else is there (a link, a pipe, a device): writing through
    it would change a file that is not the run's."""
    try:
        handle = os.open(path, flags | os.O_NOFOLLOW | os.O_NONBLOCK | getattr(os, "O_CLOEXEC", 0), 0o666)
    except OSError as err:
        if os.path.islink(path) or err.errno in (errno.ELOOP, errno.ENXIO):
            raise InputError(f"{path}: ftorch keeps its own file there, and something else is there "
                             "(a link or a special file); remove it") from None
        raise
    if not stat.S_ISREG(os.fstat(handle).st_mode):
        os.close(handle)
        raise InputError(f"{path}: ftorch keeps its own file there, and something else is there (not a regular "
                         "file); remove it")
    os.set_blocking(handle, True)
    return handle


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
    handle = _open_own(folder / LOCK, os.O_RDWR | os.O_CREAT)
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


def _names(paths: list[Path]) -> str:
    """The first three of ``paths``, for a message."""
    return ", ".join(str(p) for p in paths[:3]) + (", ..." if len(paths) > 3 else "")


def _reported_command(out: Path) -> Command | None:
    """The command whose output ``out`` holds, told by its report (for folders whose ledger does not
    name it): recognize, incremental and grasp by report.json's settings, the others by their report's name."""
    for name, command in REPORTS.items():
        if (out / name).is_file():
            return command
    try:
        config = json.loads((out / "report.json").read_text(encoding="utf-8"))["config"]
    except (OSError, ValueError, KeyError, TypeError, RecursionError):
        return None
    if not isinstance(config, dict):
        return None
    if "experiment" in config:
        return Command.GRASP
    return Command.INCREMENTAL if config.get("incremental") else Command.RECOGNIZE


class RunFolder:
    """A run's ``out`` and ``logdir`` held for the run (module doc): ``with RunFolder(...) as folder``
    locks them and decides, ``folder.clear()`` removes the old run once the inputs are checked,
    ``folder.ledger`` records what the new run writes. ``evaluate``, ``salient`` and ``robustness``
    hold theirs with ``overwrite`` and never clear it: each writes its files over its own earlier
    ones, atomically, so a failed write (a full disk) keeps the earlier file whole."""

    def __init__(self, out, logdir, resume: bool, overwrite: bool, command: Command, can_resume: bool = True):
        if resume and overwrite:
            raise InputError("--resume continues the run in --out and --overwrite replaces it: give one of them")
        self.out = writable_folder(out)
        self.logdir = Path(logdir)
        self.resume, self.overwrite, self.can_resume = resume, overwrite, can_resume
        self.command = Command(command)
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
        """Refuse a folder that holds another command's run, a log folder that holds another run's
        TensorBoard runs, and a folder that holds a run, unless resumed or overwritten; then start
        the ledger where the folder holds no run."""
        found = self._found()
        holder = (self.ledger.command() or _reported_command(self.out)) if found else None
        if holder is not None and holder is not self.command:
            raise InputError(f"--out {self.out} holds a run of {holder} ({_names(found)}); {self.command} does not "
                             "write into another command's folder, with or without --overwrite: choose another --out")
        self._check_logdir()
        if not found:
            self.ledger.start(self.command)
        if self.resume:
            if not list(self.out.glob("fold*/checkpoint.json")) and not list(self.out.glob("seed*/fold*/checkpoint.json")):
                print(f"note: no checkpoint in {self.out}; --resume starts afresh", file=sys.stderr)
        elif found and not self.overwrite:
            raise InputError(f"--out {self.out} already holds a run ({_names(found)}); "
                             + ("--resume continues it, " if self.can_resume else "") + "--overwrite replaces it")

    def _found(self) -> list[Path]:
        """What the run in OUT wrote that is still there (module doc); empty where it holds none."""
        return self._recorded() if self.ledger.path.is_file() else _legacy_runs(self.out, self.logdir)[0]

    def _check_logdir(self) -> None:
        """A log folder outside OUT belongs to one run folder at a time: refuse it where its
        TensorBoard runs hold event files that this run's ledger does not record."""
        if self._logdir_inside() or not self.logdir.is_dir():
            return
        mine = {path.absolute() for kind, path in self.ledger.entries() if kind == "events"}
        theirs = sorted({f.parent for run in self.logdir.iterdir() if run.is_dir() and EVENT_RUNS.match(run.name)
                         for f in run.rglob(f"{EVENTS}*") if f.parent.absolute() not in mine})
        if theirs:
            raise InputError(f"--logdir {self.logdir} holds the TensorBoard runs of another run folder ({_names(theirs)}); "
                             "a log folder belongs to one run folder: choose another --logdir")

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
        self.ledger.start(self.command)

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
