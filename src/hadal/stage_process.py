"""Run one stage in a fresh child process, so that CPU-bound stages running at the same time do not share one GIL.

Why: the flow runs stages whose inputs are ready concurrently (``flows/post_cruise.py``), but several of the heavy
steps hold the GIL for seconds (open3d's ``remove_statistical_outlier`` was measured to hold it: a Python thread
spinning beside it got 1/75 of its solo rate), so two threads gained little on a 2-core machine: the DTM stage took
27–29 s beside the laser stage against 11 s alone. A stage whose record says ``process=True`` (dtm, laser)
runs in its own (``spawn``-ed) process when it can overlap another
stage of the run (match and landing too
measured slower: a child pays ~1.5 s of imports, and their kernels already release the GIL;
``docs/operations.md``).

The parent (a flow's task thread) keeps everything Prefect: the child is Prefect-free and gets plain values
(raw dir, store root, config path, pins, run ids). Its log records come back through a queue and are re-emitted in
the parent's thread (so they reach the Prefect run logger, the console and the stage's warnings artifact as if
logged there); its result is ``{product: version directory}``; its exception comes back as the same exception (else
a :class:`~hadal.errors.StageError` with its one-line text). A child that dies without an answer (killed, out of
memory) is a :class:`~hadal.errors.StageError` naming its exit code; a child whose parent dies exits by itself
(watchdog), and the CLI stops its children on an interrupt. Nothing is half-published either way: products are
published atomically from a staging directory (:mod:`hadal.store`).
"""

from __future__ import annotations

import logging
import logging.handlers
import multiprocessing as mp
import os
import pickle
import queue as _queue
import signal
import sys
import threading
import time
import traceback
import warnings
from typing import Any

from hadal.errors import HadalError, StageError

#: seconds between the child's checks that its parent is still alive
WATCHDOG_INTERVAL_S = 1.0
#: -W option of the resource tracker: no "leaked semaphore objects to clean up" warning after an interrupt
_QUIET_TRACKER = "ignore:resource_tracker:UserWarning"


def can_isolate() -> bool:
    """False where a child process cannot be started (inside a daemonic process, e.g. a multiprocessing pool)."""
    return not mp.current_process().daemon


def _watch_parent(parent_pid: int) -> None:
    while True:
        time.sleep(WATCHDOG_INTERVAL_S)
        if os.getppid() != parent_pid:
            os._exit(3)  # the parent is gone: never keep computing (or publishing) for nobody


def _portable(exc: BaseException) -> BaseException:
    """``exc`` if it survives a pickle round trip, else a :class:`StageError` (HadalError) or RuntimeError with the
    first line of its text (its type named for a RuntimeError)."""
    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:  # noqa: BLE001 - any exception that cannot cross the process boundary is replaced
        text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        out: BaseException = StageError(text) if isinstance(exc, HadalError) else RuntimeError(
            f"{type(exc).__name__}: {text}")
        return out


def guard_child(parent_pid: int) -> None:
    """A stage process's first step: ignore a terminal's Ctrl-C, stop by itself when its parent is gone, and take
    SIGTERM/SIGHUP plainly."""
    # Ctrl-C in a terminal reaches the whole process group: the parent decides (the CLI stops its children with
    # SIGTERM and says what was left unpublished), so the child does not die half-way with its own traceback
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_DFL)
    threading.Thread(target=_watch_parent, args=(parent_pid,), daemon=True, name="parent-watchdog").start()


def _child(q: Any, name: str, kwargs: dict[str, Any], log_level: int, progress: bool, parent_pid: int,
           warning_filters: list[Any]) -> None:
    guard_child(parent_pid)
    _run_job(q, name, kwargs, log_level, progress, warning_filters)


def _run_job(q: Any, name: str, kwargs: dict[str, Any], log_level: int, progress: bool,
             warning_filters: list[Any]) -> None:
    """Run stage ``name`` in this (stage) process, its log records, warnings and answer sent back on ``q``."""
    for logger_name, level in (("hadal", log_level), ("py.warnings", logging.WARNING)):
        lg = logging.getLogger(logger_name)
        for h in list(lg.handlers):
            lg.removeHandler(h)
        lg.addHandler(logging.handlers.QueueHandler(q))
        lg.setLevel(level)
        lg.propagate = False
    warnings.filters[:] = warning_filters  # type: ignore[index]  # the parent's filters (e.g. the CLI's ignores)
    logging.captureWarnings(True)  # a warning goes back as a record of "py.warnings", shown by the parent
    try:
        from hadal.pipeline import make_context, pin_paths, run_stage
        from hadal.progress import LogProgress
        from hadal.stages import NullProgress

        ctx = make_context(kwargs["raw_dir"], kwargs.get("store_root"), kwargs.get("config_path"),
                           progress=LogProgress() if progress else NullProgress())
        pin_paths(ctx, kwargs.get("pins"))
        ctx.failed, ctx.failed_skips = dict(kwargs.get("failed") or {}), dict(kwargs.get("failed_skips") or {})
        out = run_stage(name, ctx, kwargs.get("run_info"))
        q.put(("result", {product: str(pv.path) for product, pv in out.items()}))
    except BaseException as exc:  # noqa: BLE001 - every failure goes back to the parent, which raises it
        if not isinstance(exc, HadalError):
            exc.add_note("in the stage's process:\n" + "".join(traceback.format_exception(exc)).rstrip())
        q.put(("error", _portable(exc)))
    finally:
        q.close()
        q.join_thread()


def _quiet_tracker() -> None:
    if _QUIET_TRACKER not in sys.warnoptions:
        # multiprocessing's resource tracker (started with the first child, given this interpreter's -W flags)
        # removes the queue's semaphores when a killed run leaves them, and would warn about it on the terminal
        # after every Ctrl-C; the clean-up is its job, the warning only noise
        sys.warnoptions.append(_QUIET_TRACKER)


def _warning_filters() -> list[Any]:
    """The parent's warning filters that can be sent to the child (those with a picklable category)."""
    out = []
    for f in warnings.filters:
        try:
            pickle.dumps(f)
        except Exception:  # noqa: BLE001 - e.g. a category class defined in a local scope
            continue
        out.append(f)
    return out


def _reemit(record: logging.LogRecord) -> None:
    """Handle a child's record in this thread, as if it had been logged here (thread-filtering handlers see it)."""
    record.thread = threading.get_ident()
    record.threadName = threading.current_thread().name
    record.process = os.getpid()
    if record.name == "py.warnings":  # shown as this process shows a warning (its filters already applied)
        record.msg = record.getMessage().rstrip()
        lg = logging.getLogger("py.warnings")
        if lg.handlers or logging.getLogger().handlers:
            lg.handle(record)
        else:
            sys.stderr.write(record.msg + "\n")
        return
    lg = logging.getLogger(record.name)
    if lg.isEnabledFor(record.levelno):
        lg.handle(record)


def _reap(proc: Any, q: Any) -> None:
    """Wait for a stage process to exit (killed after 30 s) and close its queue."""
    proc.join(timeout=30)
    if proc.is_alive():
        proc.kill()
        proc.join(timeout=5)
    q.close()


def run_stage_in_process(name: str, *, raw_dir: str, store_root: str | None = None, config_path: str | None = None,
                         pins: dict[str, str] | None = None, failed: dict[str, str] | None = None,
                         failed_skips: dict[str, str] | None = None, run_info: dict[str, Any] | None = None,
                         progress: bool = True) -> dict[str, str]:
    """Run stage ``name`` (:func:`hadal.pipeline.run_stage`) in a fresh ``spawn`` child process; returns ``{product: version directory}``. Blocks the calling thread, which
    re-emits the child's log records."""
    _quiet_tracker()
    spawn = mp.get_context("spawn")
    kwargs = {"raw_dir": str(raw_dir), "store_root": None if store_root is None else str(store_root),
              "config_path": None if config_path is None else str(config_path), "pins": dict(pins or {}),
              "failed": dict(failed or {}), "failed_skips": dict(failed_skips or {}), "run_info": dict(run_info or {})}
    level = logging.getLogger("hadal").getEffectiveLevel()
    job = (name, kwargs, level, progress, os.getpid(), _warning_filters())
    q = spawn.Queue()
    proc = spawn.Process(target=_child, args=(q, *job), name=f"hadal-stage-{name}", daemon=False)
    proc.start()
    answer: tuple[str, Any] | None = None
    try:
        while answer is None:
            try:
                item = q.get(timeout=0.5)
            except _queue.Empty:
                if proc.is_alive():
                    continue
                try:  # the last messages may have arrived just before it exited
                    item = q.get(timeout=0.5)
                except _queue.Empty:
                    break
            except Exception as exc:  # noqa: BLE001 - an answer that cannot be unpickled here
                raise StageError(f"stage {name}: unreadable answer from its process ({exc})") from None
            if isinstance(item, logging.LogRecord):  # QueueHandler puts bare records
                _reemit(item)
            else:
                answer = item
    except BaseException:
        if proc.is_alive():
            proc.terminate()
        _reap(proc, q)
        raise
    if answer is None:
        _reap(proc, q)
        code = proc.exitcode
        if code is not None and code < 0:
            sig = -code
            why = f"killed by signal {sig}" + ("; out of memory? (the kernel's OOM killer sends it)" if sig == 9 else "")
        else:
            why = f"exit code {code}"
        raise StageError(f"stage {name}: its process ended without an answer ({why})")
    # answered: its interpreter's exit (atexit hooks, module teardown: ~0.7 s after the heavy stages) is not waited
    # for here, where the flow's next stage waits; a daemon thread reaps it
    threading.Thread(target=_reap, args=(proc, q), daemon=True, name=f"reap-{proc.name}").start()
    kind, payload = answer
    if kind == "error":
        raise payload
    return payload
