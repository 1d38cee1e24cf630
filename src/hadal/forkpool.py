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

Inside a flow the stages run in task threads, where a fork is not safe. For them the CLI forks **helpers** ahead
(:func:`start_helpers`): processes forked from the main thread just before the flow starts, while it is still the
process's only thread, which then draw for any thread's pool (:func:`helpers_running`). A helper has every module
imported by then; the call and its arguments travel to it pickled, the result back. An argument many calls share
(the report's products, 340 MB pickled on the sample dive) is wrapped by :meth:`ForkPool.share`: it is sent to a
helper once, not with every call. A pool queues at most one call per helper it works with and draws the others
itself (greedy balancing as above), and a call a helper cannot answer (an exception, an unpicklable argument or
result, a helper killed) is run again here.

Forked children exit with ``os._exit`` (no atexit hooks, no module teardown; multiprocessing flushes this process's
standard streams before each fork, so pending output is not printed twice). Results travel through a pipe (pickled), so they must be
picklable (bytes, paths, small dataclasses); a matplotlib Figure is not.
"""

from __future__ import annotations

import collections
import itertools
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
    """Processes a pool draws with by default: 2 where the machine has 2 or more cores and the pool can use a second
    process here (a fork, :func:`can_fork`, or a helper forked ahead, :func:`helpers_running`), else 1."""
    return 2 if (os.cpu_count() or 1) >= 2 and (can_fork() or helpers_running()) else 1


def _helper_main(conn: Any, parent_pid: int, modules: tuple[str, ...], parent_ends: tuple[int, ...]) -> None:
    """A helper's loop over the parent's messages (:meth:`_Helper.send`): ``s`` keeps a shared argument, ``d`` forgets
    it, ``c`` runs a call and answers ``(True, result)`` or ``(False, why)``; EOF (the parent stops it or is gone):
    exit. ``parent_ends``: the parent's ends of the helpers' pipes (its own and the earlier helpers') and of the stage
    processes' job pipes, copied by the fork and closed first, else the parent closing one would never reach its
    child as EOF."""
    import pickle

    from hadal.childproc import start_child

    start_child(parent_pid, parent_ends, modules)
    shared: dict[int, Any] = {}
    while True:
        try:
            kind = conn.recv_bytes()
            raw = conn.recv_bytes()
        except (EOFError, OSError):
            return
        try:
            body = pickle.loads(raw)
        except Exception as exc:  # noqa: BLE001 - e.g. a class this helper cannot import
            body, why = None, f"{type(exc).__name__}: {exc}"
        del raw
        if kind == b"s":  # (token, object); one that did not unpickle is missing: its calls are re-run by the parent
            if body is not None:
                shared[body[0]] = body[1]
            continue
        if kind == b"d":
            shared.pop(body, None)
            continue
        try:
            if body is None:
                conn.send((False, f"call not readable here ({why})"))
            else:
                fn, args = body
                _answer(conn, _call_with, (fn, args, shared))  # a missing shared object: an answer, not a crash
        except (OSError, EOFError):  # the parent is gone
            return


def _pickled(body: Any) -> bytes:
    import pickle

    return pickle.dumps(body, protocol=pickle.HIGHEST_PROTOCOL)


class Shared:
    """An argument of many calls of a pool (:meth:`ForkPool.share`): pickled once and sent to a helper once."""

    _tokens = itertools.count(1)  # next() on a count is atomic under the GIL: one token per object, any thread

    def __init__(self, obj: Any):
        self.token = next(Shared._tokens)
        self.obj = obj
        self._bytes: bytes | None = None
        self._lock = threading.Lock()

    def free(self) -> None:
        """Forget the pickle (every helper holds the object)."""
        with self._lock:
            self._bytes = None

    def message(self) -> bytes:
        """Its ``s`` message's body to a helper (pickled at the first helper that needs it, kept for the others)."""
        with self._lock:  # two feeders must not pickle a large object twice at once
            if self._bytes is None:
                self._bytes = _pickled((self.token, self.obj))
            return self._bytes

    def __reduce__(self):  # in a call's arguments only its token travels (the helper holds the object)
        return (_shared_ref, (self.token,))


def _shared_ref(token: int) -> Shared:
    ref = Shared.__new__(Shared)
    ref.token, ref.obj, ref._bytes, ref._lock = token, None, None, threading.Lock()
    return ref


class _Helper:
    """One helper process forked ahead: its process, the parent's end of its pipe, whether a pool's call holds it,
    and the shared arguments it holds."""

    def __init__(self, modules: tuple[str, ...], others: list[_Helper]):
        ctx = mp.get_context("fork")
        self.conn, child = ctx.Pipe(duplex=True)
        from hadal.childproc import inherited_ends

        ends = (self.conn.fileno(), *(o.conn.fileno() for o in others), *inherited_ends())
        self.proc = ctx.Process(target=_helper_main, args=(child, os.getpid(), modules, ends), daemon=True,
                                name="hadal-figure-helper")
        self.proc.start()
        child.close()
        self.busy = False
        self.holds: set[int] = set()
        self.send_lock = threading.Lock()

    def send(self, kind: bytes, body: bytes) -> None:
        """A message to the helper (:func:`_helper_main`): its kind (``s`` share, ``d`` drop, ``c`` call), then its
        pickled body, as two messages on the pipe (no copy of a large body to prefix it)."""
        with self.send_lock:
            self.conn.send_bytes(kind)
            self.conn.send_bytes(body)

    def stop(self) -> None:
        try:
            self.conn.close()  # EOF: the helper exits
        except OSError:
            pass
        self.proc.join(timeout=5)
        if self.proc.is_alive():
            self.proc.kill()
            self.proc.join()


class _Helpers:
    """The helpers forked ahead (:func:`start_helpers`); each runs one pool call at a time, for any thread."""

    def __init__(self, n: int, modules: tuple[str, ...]):
        self.lock = threading.Lock()
        self.all: list[_Helper] = []
        try:
            for _ in range(int(n)):
                self.all.append(_Helper(modules, self.all))
        except BaseException:
            self.stop()
            raise

    def acquire(self) -> _Helper | None:
        """An idle live helper, now held by the caller, or None."""
        with self.lock:
            for h in self.all:
                if not h.busy and h.proc.is_alive():
                    h.busy = True
                    return h
        return None

    def release(self, h: _Helper, *, dead: bool = False) -> None:
        with self.lock:
            h.busy = False
            if dead and h in self.all:
                self.all.remove(h)
        if dead:
            h.stop()

    def drop(self, tokens: set[int]) -> None:
        """Tell the helpers holding ``tokens`` to forget them (queued behind a call a helper runs)."""
        with self.lock:
            todo = [(h, h.holds & tokens) for h in self.all]
            for h, mine in todo:
                h.holds -= mine
        for h, mine in todo:
            for t in mine:
                try:
                    h.send(b"d", _pickled(t))
                except OSError:
                    pass

    def stop(self) -> None:
        with self.lock:
            helpers, self.all = self.all, []
        for h in helpers:
            h.stop()


_HELPERS: list[_Helpers] = []  # this process's helpers (at most one set; started and stopped by the CLI)


def start_helpers(n: int, modules: tuple[str, ...] = ()) -> bool:
    """Fork ``n`` helper processes now (module docstring), which first import ``modules`` (entries of a stage's
    ``warm_imports``); True if they run. Only from the main thread of a process whose only thread it is (a fork beside
    other threads may copy a lock one of them holds), on Linux, and not inside a daemonic process; otherwise, or when
    no process can be started, False and nothing changes. Stop them with :func:`stop_helpers`."""
    if n < 1 or _HELPERS or not can_fork() or threading.active_count() != 1:
        return False
    sys.stdout.flush()  # the fork copies unflushed output: written once, here
    sys.stderr.flush()
    try:
        _HELPERS.append(_Helpers(n, modules))
    except OSError:  # no process to spare (a process limit, ...): pools run their calls here
        return False
    return True


def helpers_running() -> bool:
    """Whether helpers forked ahead (:func:`start_helpers`) are available to this process's pools."""
    return bool(_HELPERS)


def stop_helpers() -> None:
    """Stop the helpers (each after the call it runs, if any)."""
    while _HELPERS:
        _HELPERS.pop().stop()


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
    """Run calls in up to ``workers - 1`` forked children (or helpers) beside this process (module docstring)."""

    def __init__(self, workers: int = 1):
        if int(workers) < 1:
            raise ValueError(f"workers must be at least 1, got {workers}")
        # a fork here when it is safe, else the helpers forked ahead (a flow's task thread), else a plain loop
        forks = can_fork()
        self._helpers = _HELPERS[0] if not forks and _HELPERS else None
        self.workers = int(workers) if forks or self._helpers is not None else 1
        self._ctx = mp.get_context("fork") if self.workers > 1 and self._helpers is None else None
        self._n = 0  # calls submitted
        self._done: dict[int, Any] = {}
        # call index -> (process, parent end of its pipe, the call: kept only while a child runs it, for a re-run)
        self._running: dict[int, tuple[Any, Any, Callable[..., Any], tuple[Any, ...]]] = {}
        # with helpers: calls not started yet (taken by a helper's feeder thread, or here in results()), the calls
        # a helper could not answer (re-run here), the feeder threads, and the shared arguments' tokens
        self._queue: collections.deque[tuple[int, Callable[..., Any], tuple[Any, ...]]] = collections.deque()
        self._qlock = threading.Lock()
        self._failed: dict[int, tuple[Callable[..., Any], tuple[Any, ...]]] = {}
        self._feeders: list[threading.Thread] = []
        self._shared: set[int] = set()

    def share(self, obj: Any) -> Any:
        """``obj`` as an argument of many calls: with helpers a :class:`Shared` (sent to each helper once), else
        ``obj`` itself (a forked child inherits it)."""
        if self._helpers is None or self.workers < 2:
            return obj
        sh = Shared(obj)
        self._shared.add(sh.token)
        return sh

    def submit(self, fn: Callable[..., Any], *args: Any) -> None:
        """Run ``fn(*args)`` in a forked child if one is free, else here (now). With helpers: queued for this pool's
        helper (one taken now if idle), unless the queue already holds a call for each of them: then here (now),
        so calls (and their arguments) do not pile up behind a busy or missing helper."""
        i = self._n
        self._n += 1
        if self._helpers is not None and self.workers > 1:
            with self._qlock:
                self._queue.append((i, fn, args))
            live = sum(t.is_alive() for t in self._feeders)
            if live < self.workers - 1 and (h := self._helpers.acquire()) is not None:
                t = threading.Thread(target=self._feed, args=(h,), daemon=True, name="hadal-figure-feeder")
                self._feeders.append(t)
                t.start()
                return
            with self._qlock:  # no helper free: keep at most one waiting call per working helper
                here = len(self._queue) > live and self._queue[-1][0] == i
                if here:
                    self._queue.pop()
            if here:
                self._done[i] = _call(fn, args)
            return
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

    def _take(self) -> tuple[int, Callable[..., Any], tuple[Any, ...]] | None:
        with self._qlock:
            return self._queue.popleft() if self._queue else None

    def _feed(self, h: _Helper) -> None:
        """A feeder thread: helper ``h`` runs queued calls, one after the other, until the queue is empty; a call it
        cannot answer goes to :attr:`_failed` (re-run here); a helper gone ends the feeder."""
        helpers = self._helpers
        assert helpers is not None
        dead = False
        try:
            while (job := self._take()) is not None:
                i, fn, args = job
                sent = self._send_call(h, fn, args)
                if sent != "sent":
                    self._failed[i] = (fn, args)
                    if sent == "gone":
                        dead = True
                        return
                    continue
                try:
                    ok, value = h.conn.recv()
                except (EOFError, OSError):  # killed without an answer (out of memory, ...): re-run here
                    self._failed[i] = (fn, args)
                    dead = True
                    return
                except Exception:  # noqa: BLE001 - an answer that does not unpickle here: re-run here
                    ok, value = False, None
                if ok:
                    self._done[i] = value
                else:
                    self._failed[i] = (fn, args)
        finally:
            helpers.release(h, dead=dead)

    def _send_call(self, h: _Helper, fn: Callable[..., Any], args: tuple[Any, ...]) -> str:
        """Send a call (and the shared arguments ``h`` lacks) to helper ``h``: ``"sent"``, ``"unpicklable"`` (the
        call or a shared argument; nothing of it sent) or ``"gone"`` (the helper's pipe is broken)."""
        helpers = self._helpers
        assert helpers is not None
        try:
            call = _pickled((fn, args))
            shares = [(a, a.message()) for a in args if isinstance(a, Shared) and a.token not in h.holds]
        except Exception:  # noqa: BLE001 - e.g. a lambda: run here
            return "unpicklable"
        try:
            for a, body in shares:
                h.send(b"s", body)
                with helpers.lock:
                    h.holds.add(a.token)
                    if all(a.token in o.holds for o in helpers.all):
                        a.free()  # every helper has it: no need for its pickle here
            h.send(b"c", call)
        except (OSError, ValueError):  # a broken pipe (the helper killed), or a closed one (stopped)
            return "gone"
        return "sent"

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
        """Every call's result, in submission order (waits for the children). With helpers this thread takes the
        queued calls too, while the helpers finish theirs."""
        while (job := self._take()) is not None:
            i, fn, args = job
            self._done[i] = _call(fn, args)
        for t in self._feeders:
            t.join()
        self._feeders = []
        for i in sorted(self._failed):  # re-run here: raises the call's error with its traceback, or succeeds
            fn, args = self._failed.pop(i)
            self._done[i] = _call(fn, args)
        self._reap(block=True)  # every call is now done: here, by a child, or re-run here
        self._drop_shared()
        return [self._done[i] for i in range(self._n)]

    def _drop_shared(self) -> None:
        if self._shared and self._helpers is not None:
            self._helpers.drop(self._shared)
        self._shared = set()

    def close(self) -> None:
        """Stop children still running (after an error in this process); queued calls are dropped and the helpers'
        feeders end after the call each runs (a helper's call cannot be taken back)."""
        for proc, conn, _, _ in self._running.values():
            if proc.is_alive():
                proc.terminate()
            proc.join()
            conn.close()
        self._running.clear()
        with self._qlock:
            self._queue.clear()
        for t in self._feeders:
            t.join()
        self._feeders = []
        self._drop_shared()

    def __enter__(self) -> ForkPool:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _call(fn: Callable[..., Any], args: tuple[Any, ...]) -> Any:
    """``fn(*args)`` here, shared arguments unwrapped."""
    return fn(*(a.obj if isinstance(a, Shared) else a for a in args))


def _call_with(fn: Callable[..., Any], args: tuple[Any, ...], shared: dict[int, Any]) -> Any:
    """``fn(*args)`` in a helper, shared arguments taken from the objects it holds (``shared``, by token)."""
    return fn(*(shared[a.token] if isinstance(a, Shared) else a for a in args))
