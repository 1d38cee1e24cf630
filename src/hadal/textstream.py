"""Reading big text files as streams: bounded line length, counted rows, growable numeric columns.

The text readers (sensor CSV, xyz soundings and point clouds, .cnv) never hold a whole file: a :class:`LineScan`
sees every block on its way to the parser (:class:`ScannedStream`) and refuses a runaway line before anything
holds it; parsed values go into :class:`GrowableColumn` objects chunk by chunk.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np

from hadal.errors import InputError

__all__ = ["MAX_LINE_BYTES", "GrowableColumn", "LineScan", "ScannedStream", "check_line_lengths",
           "count_nonblank_lines"]

#: the longest line a text reader accepts: a row of a vehicle log or a .cnv data line is well under 1 KiB, so a
#: line of 1 MiB is not a row (a file without newlines, a binary blob, a runaway writer) and is refused, before
#: anything is parsed (pandas would hold it several times over)
MAX_LINE_BYTES = 1 << 20
_SCAN_BLOCK = 4 << 20


class LineScan:
    """One pass over a text stream in blocks (:meth:`feed`), in memory bounded by the block size whatever the
    file size: it refuses a line longer than ``limit`` bytes (one-line :class:`InputError`; old-Mac ``\\r`` line
    ends count as line ends) and counts the non-blank lines (blank: only white space). A block's unfinished last
    line (at most ``limit`` bytes) is carried into the next block."""

    _BLANK = re.compile(rb"^[ \t\r\v\f]*\n", re.MULTILINE)

    def __init__(self, path: str | Path, what: str = "line", limit: int | None = None):
        self.path, self.what = path, what
        self.limit = MAX_LINE_BYTES if limit is None else limit
        self.n_nonblank = 0
        self._line_no = 1        # 1-based number of the first line of the carried text
        self._carry = b""

    def _check(self, buf: bytes) -> None:
        """Refuse a line of ``buf`` (whole lines, or the unfinished last one) longer than the limit."""
        if len(buf) <= self.limit:
            return
        arr = np.frombuffer(buf, dtype=np.uint8)
        ends = np.concatenate([[-1], np.flatnonzero(arr == 10), [arr.size]])
        lengths = np.diff(ends) - 1
        for k in np.flatnonzero(lengths > self.limit):
            a, n = int(ends[k]) + 1, int(lengths[k])
            if buf.find(b"\r", a, a + n) < 0 or max(map(len, buf[a:a + n].split(b"\r"))) > self.limit:
                raise InputError(f"{self.path}: line {self._line_no + int(k)} is {n:,}+ bytes long: not a "
                                 f"{self.what} (the limit is {self.limit:,} bytes; is this really a text file "
                                 "with one record a line?)")

    def feed(self, block: bytes) -> None:
        buf = self._carry + bytes(block) if self._carry else bytes(block)
        cut = buf.rfind(b"\n") + 1
        whole, self._carry = buf[:cut], buf[cut:]
        self._check(whole)
        n = whole.count(b"\n")
        self.n_nonblank += n - len(self._BLANK.findall(whole))
        self._line_no += n
        self._check(self._carry)

    def finish(self) -> int:
        """The count of non-blank lines (the last line counted even without a final newline)."""
        return self.n_nonblank + int(bool(self._carry.strip()))


def _blocks_of(raw: bytes, size: int = _SCAN_BLOCK):
    view = memoryview(raw)
    for a in range(0, len(raw), size):
        yield view[a:a + size]


def check_line_lengths(raw: bytes, path: str | Path, what: str = "line", limit: int | None = None) -> None:
    """One-line :class:`InputError` when a line of ``raw`` is longer than ``limit`` (default
    :data:`MAX_LINE_BYTES`); see :class:`LineScan`."""
    scan = LineScan(path, what, limit)
    for b in _blocks_of(raw):
        scan.feed(b)


def count_nonblank_lines(raw: bytes) -> int:
    """Lines of ``raw`` holding something other than white space (``str.splitlines`` on ``\\n``/``\\r\\n``)."""
    scan = LineScan("", limit=len(raw) + 1)
    for b in _blocks_of(raw):
        scan.feed(b)
    return scan.finish()


class GrowableColumn:
    """A growable float64/int64 column filled chunk by chunk (amortised doubling; no list of chunk arrays)."""

    def __init__(self, capacity: int, dtype: Any):
        self.a = np.empty(max(capacity, 1), dtype=dtype)
        self.n = 0

    def extend(self, x: np.ndarray) -> None:
        if self.n + x.size > self.a.size:
            grown = np.empty(max(2 * self.a.size, self.n + x.size), dtype=self.a.dtype)
            grown[:self.n] = self.a[:self.n]
            self.a = grown
        self.a[self.n:self.n + x.size] = x
        self.n += x.size

    def values(self) -> np.ndarray:
        v = self.a[:self.n]
        return v.copy() if self.n < 0.9 * self.a.size else v


class ScannedStream:
    """A binary stream that feeds every block it hands out to a :class:`LineScan`: pandas reads the file once,
    and a runaway line is refused before the parser holds it."""

    #: pandas asks a stream's ``mode`` whether it is binary; a gzip/bz2 file answers with an int (issue 43: init
    #: could not describe a compressed CSV log)
    mode = "rb"

    def __init__(self, fh: Any, scan: LineScan):
        self._fh, self._scan = fh, scan

    def read(self, n: int = -1) -> bytes:
        b = self._fh.read(n)
        self._scan.feed(b)
        return b

    def __getattr__(self, name: str) -> Any:
        return getattr(self._fh, name)


