"""The first steps of a child process hadal starts ahead of its work (a stage process, :mod:`hadal.stage_process`; a
figure helper, :mod:`hadal.forkpool`): guard it, close the pipe ends a fork copied, warm its imports.

A module at the bottom of the layers (it imports no stage and no orchestration): the process machinery above it
(:mod:`hadal.stage_process`) registers the pipe ends a later fork must close (:func:`add_inherited_ends`) instead of
the figure helpers importing it, so that the stages and the report can use :class:`hadal.forkpool.ForkPool` without
an import running back up to the orchestration.
"""

from __future__ import annotations

import importlib
import os
import signal
import threading
import time
from collections.abc import Callable

#: seconds between the child's checks that its parent is still alive
WATCHDOG_INTERVAL_S = 1.0

#: functions returning this process's pipe ends that a child forked now must close (:func:`add_inherited_ends`)
_END_SOURCES: list[Callable[[], list[int]]] = []


def add_inherited_ends(source: Callable[[], list[int]]) -> None:
    """Register ``source``: it returns this process's ends of pipes to children started earlier (e.g. the job pipes
    of the stage processes started ahead), which a child forked later closes (:func:`inherited_ends`)."""
    if source not in _END_SOURCES:
        _END_SOURCES.append(source)


def inherited_ends() -> list[int]:
    """Every registered pipe end (:func:`add_inherited_ends`) a child forked now must close first."""
    return [fd for source in _END_SOURCES for fd in source()]


def warm(entry: str) -> bool:
    """One entry of a stage's ``warm_imports``, done ahead of the stage (while Prefect's server boots, or in a stage
    process started ahead): ``"pkg.module"`` is imported; ``"pkg.module:function"`` is imported and the function
    called (a first-use cost that is not an import, e.g. matplotlib's first figure: :func:`hadal.mplwarm.first_draw`).
    False when it fails: the stage itself then reports the problem in its own words."""
    mod, _, func = entry.partition(":")
    try:
        m = importlib.import_module(mod)
        if func:
            getattr(m, func)()
    except Exception:  # noqa: BLE001 - the stage itself reports a broken import
        return False
    return True


def _watch_parent(parent_pid: int) -> None:
    while True:
        time.sleep(WATCHDOG_INTERVAL_S)
        if os.getppid() != parent_pid:
            os._exit(3)  # the parent is gone: never keep computing (or publishing) for nobody


def guard_child(parent_pid: int) -> None:
    """A stage process's (or a figure helper's) first step: ignore a terminal's Ctrl-C, stop by itself when its
    parent is gone, and take SIGTERM/SIGHUP plainly (a forked child would otherwise run the CLI's handlers, which end
    a whole run and say so)."""
    # Ctrl-C in a terminal reaches the whole process group: the parent decides (the CLI stops its children with
    # SIGTERM and says what was left unpublished), so the child does not die half-way with its own traceback
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    for sig in (signal.SIGTERM, signal.SIGHUP):
        signal.signal(sig, signal.SIG_DFL)
    threading.Thread(target=_watch_parent, args=(parent_pid,), daemon=True, name="parent-watchdog").start()


def start_child(parent_pid: int, inherited: tuple[int, ...], modules: tuple[str, ...]) -> None:
    """The first steps of a child started ahead (a stage process, a figure helper): close the ``inherited`` pipe
    ends a fork copied (the parent's ends of other children's pipes, else the parent closing one would never reach
    its child as EOF), :func:`guard_child`, then import ``modules`` (:func:`warm`)."""
    for fd in inherited:
        try:
            os.close(fd)
        except OSError:
            pass
    guard_child(parent_pid)
    for mod in modules:
        warm(mod)
