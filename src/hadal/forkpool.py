"""Draw independent figures (or any CPU-bound calls that hold the GIL) in forked child processes beside this one.

Why: matplotlib's Agg rendering holds the GIL (threads gain nothing), and a stage that draws several figures after its
science (``landing``: one per submap and four for the dive; ``report``: a dozen) ran them one after the other on one
core while the other core idled at the end of a run. A forked child starts in milliseconds and inherits the data
(copy-on-write), so nothing but the call's result crosses the process boundary.

:class:`ForkPool` ``.submit(fn, *args)`` runs ``fn(*args)`` in a forked child when fewer than ``workers - 1`` children
are busy, else here and now (so this process does its share: greedy balancing without a scheduler); ``.results()``
waits for the children and returns every call's result in submission order. A call that raises, in a child or here,
raises from ``results()`` (the first one); a child that dies without an answer (killed, out of memory) is not fatal:
its call is run again here. Where a fork is not safe or not possible (not Linux; ``workers`` < 2; inside a daemonic
process; not the main thread, :func:`can_fork`) every call runs here, in order, exactly as a plain loop would.

Inside a flow the stages run in task threads, where a fork is not safe: there every call runs here, in order.

Forked children exit with ``os._exit`` (no atexit hooks, no module teardown; multiprocessing flushes this process's
standard streams before each fork, so pending output is not printed twice). Results travel through a pipe (pickled), so they must be
picklable (bytes, paths, small dataclasses); a matplotlib Figure is not.
"""

from __future__ import annotations

import multiprocessing as mp
import os
import sys
import threading
import warnings
from collections.abc import Callable
from typing import Any


def can_fork() -> bool:
    """Whether :class:`ForkPool` forks here: Linux (fork is the platform's own start method), not inside a daemonic
    process (which may not have children), and from the process's main thread only: a fork from a worker thread
    beside an event loop's threads (a Dask worker running the report) left a child hung on a lock one of them held,
    so a flow's task threads draw in turn."""
    return (sys.platform.startswith("linux") and not mp.current_process().daemon
            and threading.current_thread() is threading.main_thread())


def default_workers() -> int:
    """Processes a pool draws with by default: 2 where the machine has 2 or more cores and the pool can fork here
    (:func:`can_fork`), else 1."""
    return 2 if (os.cpu_count() or 1) >= 2 and can_fork() else 1


def _answer(conn: Any, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
    """Run ``fn(*args)`` and send ``(True, result)`` on ``conn``, or ``(False, why)`` when it raises or its result does
    not pickle (the parent then re-runs the call itself, which raises the error with its traceback). A broken
    pipe (the parent gone) raises OSError."""
    try:
        out: tuple[bool, Any] = (True, fn(*args))
    except BaseException as exc:  # noqa: BLE001 - sent back; the parent re-runs the call to raise it itself
        out = (False, f"{type(exc).__name__}: {exc}")
    try:
        conn.send(out)
    except (OSError, EOFError):
        raise
    except Exception as exc:  # noqa: BLE001 - an unpicklable result: the parent re-runs the call
        conn.send((False, f"result not picklable ({type(exc).__name__}: {exc})"))


def _child_main(conn: Any, fn: Callable[..., Any], args: tuple[Any, ...]) -> None:
    try:
        _answer(conn, fn, args)
    finally:
        conn.close()


class ForkPool:
    """Run calls in up to ``workers - 1`` forked children beside this process (module docstring)."""

    def __init__(self, workers: int = 1):
        if int(workers) < 1:
            raise ValueError(f"workers must be at least 1, got {workers}")
        self.workers = int(workers) if can_fork() else 1  # a fork here when it is safe, else a plain loop
        self._ctx = mp.get_context("fork") if self.workers > 1 else None
        self._n = 0  # calls submitted
        self._done: dict[int, Any] = {}
        # call index -> (process, parent end of its pipe, the call: kept only while a child runs it, for a re-run)
        self._running: dict[int, tuple[Any, Any, Callable[..., Any], tuple[Any, ...]]] = {}

    def submit(self, fn: Callable[..., Any], *args: Any) -> None:
        """Run ``fn(*args)`` in a forked child if one is free, else here (now)."""
        i = self._n
        self._n += 1
        self._reap(block=False)
        if self._ctx is None or len(self._running) >= self.workers - 1:
            self._done[i] = fn(*args)
            return
        parent_end, child_end = self._ctx.Pipe(duplex=False)
        proc = self._ctx.Process(target=_child_main, args=(child_end, fn, args), daemon=True, name=f"hadal-fork-{i}")
        with warnings.catch_warnings():  # Python >= 3.12 warns about fork() in a threaded process; the child only
            warnings.simplefilter("ignore", DeprecationWarning)  # draws (no locks of the other threads taken)
            try:
                proc.start()
            except OSError:  # no process to spare: run it here
                parent_end.close()
                child_end.close()
                self._done[i] = fn(*args)
                return
        child_end.close()
        self._running[i] = (proc, parent_end, fn, args)

    def _reap(self, block: bool) -> None:
        """Collect the answers of finished children (all of them with ``block``); a child without an answer has its
        call re-run here."""
        for i, (proc, conn, fn, args) in list(self._running.items()):
            if not block and not conn.poll():
                continue
            try:
                ok, value = conn.recv()
            except (EOFError, OSError):  # died without an answer (killed, out of memory): do it here
                ok, value = False, None
            finally:
                conn.close()
                proc.join()
            del self._running[i]
            if ok:
                self._done[i] = value
            else:  # re-run here: the same call raises the same error here (with its traceback), or succeeds
                self._done[i] = fn(*args)

    def results(self) -> list[Any]:
        """Every call's result, in submission order (waits for the children)."""
        self._reap(block=True)  # every call is now done: here, by a child, or re-run here
        return [self._done[i] for i in range(self._n)]

    def close(self) -> None:
        """Stop children still running (after an error in this process)."""
        for proc, conn, _, _ in self._running.values():
            if proc.is_alive():
                proc.terminate()
            proc.join()
            conn.close()
        self._running.clear()

    def __enter__(self) -> ForkPool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

