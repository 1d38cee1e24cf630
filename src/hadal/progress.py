"""Progress reporting for long steps: a rich progress bar on a terminal, periodic log lines otherwise."""

from __future__ import annotations

import logging
import os
import sys
import time
from collections.abc import Iterable, Iterator
from typing import TypeVar

from hadal.stages import NullProgress, Progress

T = TypeVar("T")
log = logging.getLogger("hadal.progress")


class RichProgress:
    """Shows a transient rich progress bar per tracked loop."""

    def track(self, it: Iterable[T], description: str, total: int | None = None) -> Iterator[T]:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        if total is None and hasattr(it, "__len__"):
            total = len(it)  # type: ignore[arg-type]
        with Progress(
            TextColumn("[bold blue]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
            transient=True,
        ) as bar:
            task = bar.add_task(description, total=total)
            for item in it:
                yield item
                bar.advance(task)


class LogProgress:
    """Logs progress at most every ``interval_s`` seconds (for CI logs and Prefect workers)."""

    def __init__(self, interval_s: float = 10.0):
        self.interval_s = interval_s

    def track(self, it: Iterable[T], description: str, total: int | None = None) -> Iterator[T]:
        if total is None and hasattr(it, "__len__"):
            total = len(it)  # type: ignore[arg-type]
        t0 = last = time.monotonic()
        n = 0
        for item in it:
            yield item
            n += 1
            now = time.monotonic()
            if now - last >= self.interval_s:
                last = now
                log.info("%s: %d/%s (%.0f s)", description, n, total if total is not None else "?", now - t0)


def default_progress() -> Progress:
    """Rich bar on an interactive terminal, log lines otherwise; ``HADAL_PROGRESS=0`` silences it."""
    mode = os.environ.get("HADAL_PROGRESS", "auto")
    if mode == "0":
        return NullProgress()
    if mode == "rich" or (mode == "auto" and sys.stderr.isatty()):
        return RichProgress()
    return LogProgress()
