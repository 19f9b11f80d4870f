"""Running independent tasks (folds, seeds) one after another, in local processes, or on a Ray cluster.

A task is a picklable function and its argument; every task writes only its own run folder,
so tasks cannot disturb one another, and the results come back in the order the tasks were
given, whatever order they finish in. The report built from them is therefore the sequential
one. A task that raises is reported and run once more; one that fails again is reported with
its error, the others still finish, and :class:`TasksFailed` names every failure. A bad input,
an interruption, and a full, over-quota or read-only disk are not the task's fault, and running it
again cannot help: they end the run at once (one line, as every command error).

- ``workers=1`` and no Ray: in this process, one after another.
- ``workers=N``: N local processes (``spawn``), each with ``cores // N`` torch threads. Once fewer
  tasks are left than workers, the busy ones take the idle workers' cores: a task calls
  :func:`share_idle_cores` between its steps (a fold before each cycle, a grasp seed before each
  fold), which sets its threads to ``cores // busy workers``. Seeds differ in length, so the last
  task would otherwise run on one core while the others idle. Results do not depend on the
  thread count (the sequential run, with all cores in one process, gives the same report). A
  worker watches its parent: if the runner dies without ending it (SIGKILL), the worker exits
  within a second instead of finishing its task and then waiting for ever to hand it over.
  Workers ignore SIGINT from their start: a Ctrl-C reaches the whole process group, and it is the
  runner's to take; the runner then ends them (:func:`_stop`). They hold no named semaphore (tqdm's
  lock is a thread lock there), so none is left for the resource tracker to release, and warn
  about, after them.
- ``ray=ADDRESS``: Ray tasks of one CPU each (``ray.init(address=ADDRESS)``; ``local`` starts a
  local instance with ``workers`` CPUs). The address must be ``local``, ``auto``, ``HOST:PORT`` or
  ``ray://HOST[:PORT]``; a HOST:PORT is first reached over TCP with a timeout of
  ``CONNECT_TIMEOUT`` seconds, so a wrong address is one line, not a hang. Ray is an optional
  extra: ``pip install -e ".[distributed]"``.
"""
from __future__ import annotations

import errno
import logging
import os
import re
import signal
import socket
import threading
import time
from collections.abc import Callable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from functools import partial
from multiprocessing import get_context

import torch
from tqdm import tqdm

from ftorch.errors import InputError

RETRIES = 1
CORES = os.cpu_count() or 1
CONNECT_TIMEOUT = 10.0  # seconds to reach a Ray address
WATCH_PARENT = 1.0  # seconds between a worker's looks at its parent
NO_ROOM = (errno.ENOSPC, errno.EDQUOT, errno.EROFS)  # disk errors that a second run of a task meets again
RAY_ADDRESS = re.compile(r"^(?P<client>ray://)?(?P<host>[A-Za-z0-9](?:[A-Za-z0-9.-]*[A-Za-z0-9])?|\[[0-9A-Fa-f:.]+\])"
                         r"(?::(?P<port>\d{1,5}))?$")
RAY_CLIENT_PORT = 10001

_busy = None  # in a local worker process: the count of busy workers, shared with the runner


class TasksFailed(RuntimeError):
    """Some tasks failed twice; ``failures`` maps each one's name to its last error."""

    def __init__(self, failures: dict[str, str]):
        self.failures = failures
        super().__init__("; ".join(f"{name} failed twice: {error}" for name, error in failures.items()))


def _with_threads(function: Callable, threads: int, argument):
    """``function(argument)`` with ``threads`` torch threads: the body of a worker process's or a
    Ray task's call (module level, so both can pickle it)."""
    torch.set_num_threads(threads)
    return function(argument)


class _Fatal:
    """What a Ray task returns instead of raising a fatal error (:func:`_fatal`), so that Ray does
    not run it again; the runner raises the error."""

    def __init__(self, error: BaseException):
        self.error = error


def _on_cluster(function: Callable, threads: int, argument):
    """A Ray task's call: :func:`_with_threads`, a fatal error returned as :class:`_Fatal`."""
    try:
        return _with_threads(function, threads, argument)
    except Exception as error:  # noqa: BLE001 - only fatal ones are kept from Ray's retry
        if _fatal(error):
            return _Fatal(error)
        raise


def _start_worker(busy) -> None:
    """A local worker process's initializer: ignore SIGINT (it came blocked from :func:`_submit`),
    write progress bars under a thread lock instead of tqdm's default multiprocessing one (a named
    semaphore of this process, left to the resource tracker when :func:`_stop` ends it), remember the
    runner's count of busy workers, and watch the runner (module doc)."""
    global _busy
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    if hasattr(signal, "pthread_sigmask"):
        signal.pthread_sigmask(signal.SIG_UNBLOCK, {signal.SIGINT})
    tqdm.set_lock(threading.RLock())
    _busy = busy
    threading.Thread(target=_watch_parent, args=(os.getppid(),), name="watch-parent", daemon=True).start()


def _watch_parent(parent: int) -> None:
    """End this worker process once its parent ``parent`` is gone (it is then adopted by another)."""
    while os.getppid() == parent:
        time.sleep(WATCH_PARENT)
    os._exit(1)


def _fatal(error: BaseException) -> bool:
    """An error that ends the run instead of a second try (module doc)."""
    return isinstance(error, (InputError, KeyboardInterrupt)) or (isinstance(error, OSError) and error.errno in NO_ROOM)


def share_idle_cores() -> None:
    """In a local worker process: use ``cores // busy workers`` torch threads, so that the last
    tasks take the cores of workers that have run out of tasks. Elsewhere it does nothing."""
    if _busy is not None:
        threads = max(1, CORES // max(1, _busy.value))
        if threads != torch.get_num_threads():
            torch.set_num_threads(threads)


def _describe(error: BaseException) -> str:
    return f"{type(error).__name__}: {error}"


def run_tasks(function: Callable, arguments: Sequence, names: Sequence[str], workers: int = 1,
              ray: str | None = None, progress: bool = True) -> list:
    """``[function(a) for a in arguments]``, run as the module docstring says."""
    if workers < 1:
        raise InputError(f"--workers {workers}: expected at least 1")
    if ray is not None:
        return _on_ray(function, arguments, names, workers, ray, progress)
    if workers == 1 or len(arguments) == 1:
        return _here(function, arguments, names)
    return _in_processes(function, arguments, names, workers, progress)


def _here(function: Callable, arguments: Sequence, names: Sequence[str]) -> list:
    results, failures = [], {}
    for argument, name in zip(arguments, names):
        for attempt in range(RETRIES + 1):
            try:
                results.append(function(argument))
                break
            except Exception as error:  # noqa: BLE001 - reported, retried once, then named
                if _fatal(error):
                    raise
                print(f"{name} failed ({_describe(error)}); {'running it again' if attempt < RETRIES else 'giving up'}")
                if attempt == RETRIES:
                    failures[name] = _describe(error)
                    results.append(None)
    if failures:
        raise TasksFailed(failures)
    return results


def _in_processes(function: Callable, arguments: Sequence, names: Sequence[str], workers: int, progress: bool) -> list:
    call = partial(_with_threads, function, max(1, CORES // workers))
    results: list = [None] * len(arguments)
    failures: dict[str, str] = {}
    attempts = [0] * len(arguments)
    context = get_context("spawn")
    busy = context.Value("i", min(workers, len(arguments)))  # more workers than tasks: share from the start
    pool = ProcessPoolExecutor(workers, mp_context=context, initializer=_start_worker, initargs=(busy,))
    try:
        with tqdm(total=len(arguments), desc="tasks", unit="task", disable=not progress) as bar:
            pending = {_submit(pool, call, a): i for i, a in enumerate(arguments)}
            while pending:
                future = next(as_completed(pending))
                i = pending.pop(future)
                try:
                    results[i] = future.result()
                    bar.update(1)
                except Exception as error:  # noqa: BLE001 - reported, retried once, then named
                    if _fatal(error):
                        raise
                    attempts[i] += 1
                    again = attempts[i] <= RETRIES
                    bar.write(f"{names[i]} failed ({_describe(error)}); {'running it again' if again else 'giving up'}")
                    if again:
                        pending[_submit(pool, call, arguments[i])] = i
                    else:
                        failures[names[i]] = _describe(error)
                        bar.update(1)
                busy.value = min(workers, len(pending))  # fewer than workers: the rest take the idle cores
    except BaseException:
        _stop(pool)
        raise
    finally:
        pool.shutdown(wait=True)  # at once after _stop; otherwise every task has finished
    if failures:
        raise TasksFailed(failures)
    return results


def _submit(pool: ProcessPoolExecutor, call: Callable, argument):
    """``pool.submit(call, argument)`` with SIGINT blocked in this thread meanwhile (as multiprocessing
    starts its resource tracker): a worker process that it starts inherits the mask, so a Ctrl-C
    cannot interrupt the worker's start (a traceback from the middle of importing torch) before
    :func:`_start_worker` ignores SIGINT. A Ctrl-C meanwhile is only delayed to the unblock, or
    taken at once by another thread of this process."""
    if not hasattr(signal, "pthread_sigmask"):
        return pool.submit(call, argument)
    mask = signal.pthread_sigmask(signal.SIG_BLOCK, {signal.SIGINT})
    try:
        return pool.submit(call, argument)
    finally:
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)


def _stop(pool: ProcessPoolExecutor) -> None:
    """Interrupted (Ctrl-C, SIGTERM) or refused: end the workers now instead of waiting for their
    tasks, so that none outlives the runner (a task's files are written atomically, so a killed
    task leaves its last checkpoint whole). The executor has no public way to end busy workers
    before Python 3.14 (``terminate_workers``), hence its process table."""
    for process in list(getattr(pool, "_processes", {}).values()):
        process.terminate()
    pool.shutdown(wait=False, cancel_futures=True)


def _on_ray(function: Callable, arguments: Sequence, names: Sequence[str], workers: int, address: str,
            progress: bool) -> list:
    try:
        import ray
    except ImportError:
        raise InputError("--ray needs Ray: pip install -e \".[distributed]\"") from None
    started = not ray.is_initialized()
    if started:
        reach_ray(address)
        try:
            if address == "local":
                ray.init(num_cpus=workers, include_dashboard=False, log_to_driver=False, logging_level=logging.ERROR)
            else:
                ray.init(address=address, log_to_driver=False, logging_level=logging.ERROR)
        except Exception as error:  # noqa: BLE001 - Ray raises ConnectionError, RuntimeError, ValueError...
            first = str(error).strip().splitlines()[0] if str(error).strip() else type(error).__name__
            raise InputError(f"--ray {address}: could not connect ({first})") from None
    try:
        remote = ray.remote(num_cpus=1, max_retries=RETRIES, retry_exceptions=True)(_on_cluster)
        refs = [remote.remote(function, 1, a) for a in arguments]  # Ray gives each task one CPU
        index = {ref: i for i, ref in enumerate(refs)}
        results: list = [None] * len(arguments)
        failures: dict[str, str] = {}
        todo = list(refs)
        start = time.perf_counter()
        with tqdm(total=len(refs), desc="ray tasks", unit="task", disable=not progress) as bar:
            while todo:
                done, todo = ray.wait(todo, num_returns=1)
                i = index[done[0]]
                try:
                    results[i] = ray.get(done[0])
                except Exception as error:  # noqa: BLE001 - Ray already ran it again (retry_exceptions)
                    cause = getattr(error, "cause", None) or error
                    failures[names[i]] = _describe(cause) if not isinstance(cause, str) else cause
                    bar.write(f"{names[i]} failed twice on the cluster: {failures[names[i]]}")
                if isinstance(results[i], _Fatal):
                    raise results[i].error
                bar.update(1)
        if failures:
            raise TasksFailed(failures)
        if progress:
            print(f"{len(refs)} Ray tasks in {time.perf_counter() - start:.1f} s")
        return results
    finally:
        if started:
            ray.shutdown()


def reach_ray(address: str | None) -> None:
    """Refuse a Ray address of the wrong form, or one whose HOST:PORT does not answer over TCP within
    ``CONNECT_TIMEOUT`` seconds (``local`` and ``auto`` are Ray's to find; None: no Ray), and any
    address where Ray is not installed. Commands
    call it among their input checks, before an old run is replaced."""
    if address is None:
        return
    match = RAY_ADDRESS.match(address)
    if address not in ("local", "auto") and (match is None or (match["port"] is None and not match["client"])
                                             or not 0 < int(match["port"] or RAY_CLIENT_PORT) < 65536):
        raise InputError(f"--ray {address!r}: expected local, auto, HOST:PORT (a cluster's head, e.g. 10.0.0.5:6379) "
                         "or ray://HOST[:PORT] (Ray Client)")
    try:
        import ray  # noqa: F401 - only whether it is installed
    except ImportError:
        raise InputError("--ray needs Ray: pip install -e \".[distributed]\"") from None
    if address in ("local", "auto"):
        return
    host, port = match["host"].strip("[]"), int(match["port"] or RAY_CLIENT_PORT)
    try:
        socket.create_connection((host, port), timeout=CONNECT_TIMEOUT).close()
    except OSError as err:
        reason = f"no answer within {CONNECT_TIMEOUT:g} s" if isinstance(err, TimeoutError) else (err.strerror or str(err))
        raise InputError(f"--ray {address}: cannot reach a Ray cluster there ({reason}); start one with "
                         "'ray start --head' or check the address") from None
