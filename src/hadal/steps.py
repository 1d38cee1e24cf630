"""One long step of a computation reported through a progress object (the :class:`Progress` protocol:
``.track(iterable, description, total)``), without the science importing the stages or the progress module."""

from __future__ import annotations

from collections.abc import Iterable, Iterator
from contextlib import contextmanager
from typing import Any, Protocol, TypeVar

T = TypeVar("T")


class Progress(Protocol):
    def track(self, it: Iterable[T], description: str, total: int | None = None) -> Iterator[T]: ...


class NullProgress:
    """Progress reporter that reports nothing (library default)."""

    def track(self, it: Iterable[T], description: str, total: int | None = None) -> Iterator[T]:
        yield from it


@contextmanager
def step(progress: Any, description: str) -> Iterator[None]:
    """``with step(progress, "dtm: spike test of 1,362,682 soundings"): ...`` - the block as one tracked step (a
    start line, an end line with its duration, a bar on a terminal: :mod:`hadal.progress`); nothing when
    ``progress`` is ``None``."""
    if progress is None:
        yield
        return
    it = iter(progress.track([None], description, total=1))
    next(it)
    yield
    next(it, None)


def tracked(progress: Any, it: Iterable[T], description: str, total: int | None = None) -> Iterable[T]:
    """``progress.track(it, description, total)``, or ``it`` itself when ``progress`` is ``None``."""
    return it if progress is None else progress.track(it, description, total=total)
