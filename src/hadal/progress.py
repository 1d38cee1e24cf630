"""Progress reporting for long steps: a rich progress bar on a terminal, periodic log lines otherwise.

Both log, on the ``hadal.progress`` logger (INFO), a line when a tracked step starts, at most every ``interval_s``
seconds while it runs, and when it ends (with its duration): those lines reach the Prefect run's logs (``hadal``
records are routed there, also from a stage's own process) and CI logs. A stage running in its own process (no
terminal bar there: two such stages run side by side) writes the same lines to its terminal when it has one.
"""

from __future__ import annotations

import logging
import os
import sys
import time
from collections.abc import Iterable, Iterator
from typing import TypeVar

from hadal.steps import NullProgress, Progress

T = TypeVar("T")
log = logging.getLogger("hadal.progress")


def _fmt_count(n: int, total: int | None) -> str:
    if total:
        return f"{n}/{total} ({100.0 * n / total:.0f} %)"
    return f"{n}/?"


class _Ticker:
    """The progress lines of one tracked loop: start, every ``interval_s`` seconds, end (:mod:`hadal.progress`)."""

    def __init__(self, description: str, total: int | None, interval_s: float, echo: bool) -> None:
        self.description, self.total, self.interval_s, self.echo = description, total, interval_s, echo
        self.t0 = self.last = time.monotonic()

    def say(self, text: str) -> None:
        log.info("%s", text)
        if self.echo:
            print(f"  {text}", file=sys.stderr, flush=True)

    def start(self) -> None:
        self.say(f"{self.description}: started" + (f" ({self.total} steps)" if self.total and self.total > 1 else ""))

    def tick(self, n: int) -> None:
        now = time.monotonic()
        if now - self.last >= self.interval_s and not (self.total and n >= self.total):  # the end line says it
            self.last = now
            self.say(f"{self.description}: {_fmt_count(n, self.total)}, {now - self.t0:.0f} s")

    def end(self, n: int) -> None:
        self.say(f"{self.description}: done, {n} step(s) in {time.monotonic() - self.t0:.1f} s")


class RichProgress:
    """Shows a transient rich progress bar per tracked loop (and logs its lines, :class:`_Ticker`)."""

    def __init__(self, interval_s: float = 10.0):
        self.interval_s = interval_s

    def track(self, it: Iterable[T], description: str, total: int | None = None) -> Iterator[T]:
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

        if total is None and hasattr(it, "__len__"):
            total = len(it)  # type: ignore[arg-type]
        tick = _Ticker(description, total, self.interval_s, echo=False)
        with Progress(
            TextColumn("[bold blue]{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
            transient=True,
        ) as bar:
            task = bar.add_task(description, total=total)
            tick.start()
            n = 0
            for item in it:
                yield item
                n += 1
                bar.advance(task)
                tick.tick(n)
            tick.end(n)


class LogProgress:
    """Logs progress: a line at the start and end of each tracked loop and at most every ``interval_s`` seconds in
    between (for CI logs, Prefect workers and stages in their own process); ``echo`` (default: stderr is a terminal)
    also prints the lines there."""

    def __init__(self, interval_s: float = 10.0, echo: bool | None = None):
        self.interval_s = interval_s
        self.echo = sys.stderr.isatty() if echo is None else echo

    def track(self, it: Iterable[T], description: str, total: int | None = None) -> Iterator[T]:
        if total is None and hasattr(it, "__len__"):
            total = len(it)  # type: ignore[arg-type]
        tick = _Ticker(description, total, self.interval_s, self.echo)
        tick.start()
        n = 0
        for item in it:
            yield item
            n += 1
            tick.tick(n)
        tick.end(n)


def default_progress() -> Progress:
    """Rich bar on an interactive terminal, log lines otherwise; ``HADAL_PROGRESS=0`` silences it."""
    mode = os.environ.get("HADAL_PROGRESS", "auto")
    if mode == "0":
        return NullProgress()
    if mode == "rich" or (mode == "auto" and sys.stderr.isatty()):
        return RichProgress()
    return LogProgress(echo=False)
