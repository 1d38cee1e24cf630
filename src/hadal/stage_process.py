"""Run one stage in a fresh child process, so that CPU-bound stages running at the same time do not share one GIL.

Why: the flow runs stages whose inputs are ready concurrently (``flows/post_cruise.py``), but several of the heavy
steps hold the GIL for seconds (open3d's ``remove_statistical_outlier`` was measured to hold it: a Python thread
spinning beside it got 1/75 of its solo rate), so two threads gained little on a 2-core machine: the DTM stage took
27–29 s beside the laser stage against 11 s alone. A stage whose record says ``process=True`` (dtm, laser)
runs in its own process (forked ahead by the CLI, else a ``spawn``-ed interpreter) when it can overlap another
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
import sys
import threading
import traceback
import warnings
from typing import Any

from hadal.childproc import add_inherited_ends, guard_child, start_child
from hadal.errors import HadalError, StageError
from hadal.forkpool import can_fork

#: -W option of the resource tracker: no "leaked semaphore objects to clean up" warning after an interrupt
_QUIET_TRACKER = "ignore:resource_tracker:UserWarning"


def can_isolate() -> bool:
    """False where a child process cannot be started (inside a daemonic process, e.g. a multiprocessing pool)."""
    return not mp.current_process().daemon


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


class _Warm:
    """A child started ahead by :func:`prestart`: its process, its log/answer queue and the parent's end of its job
    pipe."""

    def __init__(self, proc: Any, q: Any, conn: Any):
        self.proc, self.q, self.conn = proc, q, conn


#: children started ahead, by stage name (this process's own; taken by :func:`run_stage_in_process`)
_WARM: dict[str, _Warm] = {}
_WARM_LOCK = threading.Lock()


def _warm_child(q: Any, conn: Any, parent_pid: int, modules: tuple[str, ...],
                parent_ends: tuple[int, ...] = ()) -> None:
    """A stage process started ahead: warm ``modules`` (the stage's ``warm_imports``, :func:`hadal.childproc.warm`), then
    wait for the job (the arguments of :func:`_child`) on ``conn`` and run it; EOF (the parent exits or no longer
    needs it): exit. ``parent_ends``: a forked child's copies of the parent's ends of the job pipes (its own and
    those of the processes started before it, :func:`warm_pipe_ends`), closed first, else the parent closing one
    would never reach its child as EOF."""
    start_child(parent_pid, parent_ends, modules)
    try:
        name, kwargs, log_level, progress, _, warning_filters = conn.recv()  # the arguments of _child
    except (EOFError, OSError):
        return
    finally:
        conn.close()
    _run_job(q, name, kwargs, log_level, progress, warning_filters)


def can_fork_ahead() -> bool:
    """Whether :func:`prestart` can fork the stage processes here now: Linux, the main thread, no other thread (a
    fork beside other threads may copy a lock one of them holds; :mod:`hadal.forkpool`), and no parallel region of
    numba's kernels launched yet (its OpenMP threading layer hangs a forked child's first parallel kernel once the
    parent has started its thread pool; the gridding stages run such kernels)."""
    par = sys.modules.get("numba.np.ufunc.parallel")
    return can_fork() and threading.active_count() == 1 and not getattr(par, "_is_initialized", False)


def prestart(names: Any, *, fork: bool = False) -> list[str]:
    """Start the processes of the stages ``names`` ahead of their turn (each importing its stage's ``warm_imports``,
    :mod:`hadal.stages`), so that :func:`run_stage_in_process` hands a stage to a process that has already paid its
    start. ``fork`` (where :func:`can_fork_ahead`, else spawned): forked from this process, inheriting every module
    it has imported (the CLI forks them just before the flow starts, having imported the stages' modules while
    Prefect's temporary server booted); spawned, each pays about 1-1.5 s of imports (the CLI spawns them while the
    server boots where it cannot fork). A process not used by the time this one exits is told to stop (EOF on its
    job pipe) and joined. Returns the stages started (not those already started or running)."""
    from hadal.stages.graph import stage

    forked = fork and can_fork_ahead()
    ctx: Any = mp.get_context("fork" if forked else "spawn")  # a fork or spawn context (both have Process)
    started = []
    for name in names:
        with _WARM_LOCK:
            if name in _WARM:
                continue
            _quiet_tracker()
            q = ctx.Queue()
            parent_end, child_end = ctx.Pipe()
            mods = stage(name).warm_imports
            ends = (parent_end.fileno(), *_warm_pipe_ends_locked()) if forked else ()
            proc = ctx.Process(target=_warm_child, args=(q, child_end, os.getpid(), mods, ends),
                               name=f"hadal-stage-{name}", daemon=False)
            proc.start()
            child_end.close()
            if not _WARM:
                import atexit

                atexit.register(_stop_warm)  # after multiprocessing's own exit hook was registered: runs before it
            _WARM[name] = _Warm(proc, q, parent_end)
            started.append(name)
    return started


def _warm_pipe_ends_locked() -> list[int]:
    return [w.conn.fileno() for w in _WARM.values() if not w.conn.closed]


def warm_pipe_ends() -> list[int]:
    """This process's ends of the job pipes of the stage processes started ahead and not yet given their job: a
    child forked later closes its copies of them (:mod:`hadal.forkpool`'s helpers), so that EOF reaches them."""
    with _WARM_LOCK:
        return _warm_pipe_ends_locked()


add_inherited_ends(warm_pipe_ends)  # the figure helpers forked later close them (hadal.childproc)


def _stop_warm() -> None:
    """Stop the children started ahead and never used (EOF on their job pipes; terminated after 5 s)."""
    with _WARM_LOCK:
        left = list(_WARM.values())
        _WARM.clear()
    for w in left:
        w.conn.close()
    for w in left:
        w.proc.join(timeout=5)
        if w.proc.is_alive():
            w.proc.terminate()
            w.proc.join(timeout=5)
        w.q.close()


def _take_warm(name: str) -> _Warm | None:
    """The live child started ahead for stage ``name`` (removed from the pool), or None."""
    with _WARM_LOCK:
        w = _WARM.pop(name, None)
    if w is None:
        return None
    if w.proc.is_alive():
        return w
    w.conn.close()
    w.q.close()
    return None


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
    """Run stage ``name`` (:func:`hadal.pipeline.run_stage`) in a ``spawn`` child process (the one :func:`prestart`
    started for it, else a fresh one); returns ``{product: version directory}``. Blocks the calling thread, which
    re-emits the child's log records."""
    _quiet_tracker()
    spawn = mp.get_context("spawn")
    kwargs = {"raw_dir": str(raw_dir), "store_root": None if store_root is None else str(store_root),
              "config_path": None if config_path is None else str(config_path), "pins": dict(pins or {}),
              "failed": dict(failed or {}), "failed_skips": dict(failed_skips or {}), "run_info": dict(run_info or {})}
    level = logging.getLogger("hadal").getEffectiveLevel()
    job = (name, kwargs, level, progress, os.getpid(), _warning_filters())
    warm = _take_warm(name)
    if warm is not None:
        proc, q = warm.proc, warm.q
        try:
            warm.conn.send(job)
        except (OSError, ValueError):  # it died between the check and the send: the answer loop below reports it
            pass
        finally:
            warm.conn.close()
    else:
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
