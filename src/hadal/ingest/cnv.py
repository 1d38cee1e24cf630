"""Sea-Bird SeaSoft ``.cnv`` reader (ASCII converted CTD data).

A ``.cnv`` file is a header followed by ``*END*`` and whitespace-separated numeric rows (each value in an
11-character field). Header lines:

* ``* ...``  instrument/deck-unit lines (``* NMEA Latitude = 69 24.75 N``, ``* System UTC = ...``);
* ``** ...`` user lines typed at acquisition (``** Latitude: 25 27.85 S``, ``** Station: 0860``);
* ``# ...`` SeaSoft lines: ``# nquan``, ``# nvalues``, ``# name i = short: long [units]``,
  ``# span i = lo, hi``, ``# interval``, ``# start_time``, ``# bad_flag``, ``# sensor ...`` and one
  ``# <module>_<key> = value`` line per processing step (``datcnv_date``, ``wildedit_vars``, ...).

:func:`read_cnv` keeps the column names exactly as written (``prDM``, ``t090C``, ``c0S/m``, ``sal00``,
``sigma-é00``; the file encoding is Latin-1). SeaSoft's ``bad_flag`` value becomes NaN. The header goes
into ``df.attrs`` (JSON-serialisable values only).

Reference: Sea-Bird Scientific, *SBE Data Processing* manual (Seasoft V2), section "Data Conversion /
.cnv file format" (header tags, 11-character columns, bad_flag -9.990e-29).
"""

from __future__ import annotations

import datetime as _dt
import itertools
import logging
import math
import re
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from hadal.budget import DecodeBudget
from hadal.errors import InputError
from hadal.formats import compression_of, detect, iter_blocks, read_bytes
from hadal.ingest.csv_reader import MAX_LINE_BYTES

log = logging.getLogger(__name__)

__all__ = ["read_cnv", "read_seabird", "describe_cnv", "seabird_kind", "parse_latlon", "cnv_time_ns",
           "cnv_sensor_samples", "CNV_DEFAULT_BAD_FLAG", "NO_TIME_BASE"]

#: ``time_base`` recorded for a cast without a time channel (pressure-binned): its rows are in pressure order
NO_TIME_BASE = "none (pressure-binned cast)"

CNV_DEFAULT_BAD_FLAG = -9.990e-29
_FIELD_WIDTH = 11  # SeaSoft writes every value in an 11-character field

_NAME_RE = re.compile(r"^#\s*name\s+(\d+)\s*=\s*([^:]*?)\s*:\s*(.*)$")
_SPAN_RE = re.compile(r"^#\s*span\s+(\d+)\s*=\s*(.*)$")
_KV_RE = re.compile(r"^#\s*([^=]+?)\s*=\s*(.*)$")
_UNITS_RE = re.compile(r"\[([^\]]*)\]\s*(?:,.*)?$")
# user/NMEA position lines: "* NMEA Latitude = 69 24.75 N", "** Latitude: 25 27.85 S", "** Lat = -25.46"
_POS_RE = re.compile(r"^\*{1,2}\s*(?:NMEA\s+)?(lat(?:itude)?|lon(?:gitude)?|long)\b\s*[:=]\s*(.+)$", re.I)
_TIME_FORMATS = ("%b %d %Y %H:%M:%S", "%b %d %Y %H:%M", "%d %b %Y %H:%M:%S")
_RESERVED = {"nquan", "nvalues", "units", "interval", "start_time", "bad_flag"}
# a SeaSoft processing line: '<module>_<key>...' with a lower-case module name ('datcnv_date = ...',
# 'loopedit_surfaceSoak: minDepth = 5.0, ...', 'wfilter_action prDM = median, 21', 'file_type = ascii')
_PROC_RE = re.compile(r"^#\s*([a-z][a-z0-9]*_[A-Za-z0-9_]+)(.*)$")
# channel notes after the units: '[salt water, m], lat = 69.41', '[ml/l], WS = 2', 'minP = 0, minS = 0'
_NOTE_RE = re.compile(r"([A-Za-z][A-Za-z0-9_ ]*?)\s*=\s*([^,]+)")


def parse_latlon(text: str, *, is_latitude: bool) -> float | None:
    """Decimal degrees from a header position string, or ``None`` when it cannot be read.

    Accepts ``"69 24.75 N"``, ``"25°27.85'S"``, ``"N 25 27.85"``, ``"25 27 51 S"`` (d m s),
    ``"-25.464"``, ``"25:27.85S"``. Southern/western hemispheres are negative. Values outside
    ±90 (latitude) / ±180 (longitude) give ``None``.
    """
    s = text.strip().split("[")[0]
    if not s or s.lower() in ("none", "n/a", "na"):
        return None
    hemi = re.findall(r"[NSEWnsew]\b|[NSEWnsew]$|^[NSEWnsew]", s)
    sign = 1.0
    if hemi:
        h = hemi[-1].upper()
        if h in ("S", "W"):
            sign = -1.0
        if (h in ("N", "S")) != is_latitude:
            return None  # a longitude hemisphere on a latitude line (or vice versa)
    nums = re.findall(r"[-+]?\d+(?:\.\d*)?|[-+]?\.\d+", s)
    if not nums or len(nums) > 3:
        return None
    neg = nums[0].startswith("-")
    vals = [abs(float(n)) for n in nums]
    if neg:
        sign = -1.0  # "-25.46" (a hemisphere letter as well must agree: "-25.46 S" is still south)
    if any(n.startswith(("-", "+")) for n in nums[1:]):
        return None
    if (len(vals) > 1 and vals[1] >= 60) or (len(vals) > 2 and vals[2] >= 60):
        return None
    deg = vals[0] + (vals[1] / 60.0 if len(vals) > 1 else 0.0) + (vals[2] / 3600.0 if len(vals) > 2 else 0.0)
    deg *= sign
    lim = 90.0 if is_latitude else 180.0
    return deg if math.isfinite(deg) and abs(deg) <= lim else None


def _parse_time(text: str) -> tuple[str | None, str | None]:
    """(ISO-8601 UTC string, bracketed source note) from ``Jul 24 2013 13:18:00 [NMEA time, header]``."""
    note = None
    m = re.search(r"\[([^\]]*)\]", text)
    if m:
        note = m.group(1).strip()
        text = text[: m.start()]
    t = " ".join(text.split())
    for fmt in _TIME_FORMATS:
        try:
            return _dt.datetime.strptime(t, fmt).replace(tzinfo=_dt.UTC).isoformat(), note
        except ValueError:
            continue
    return None, note


#: a header ``start_time`` more than this after the clock it is checked against disagrees with it (a day: the
#: instrument's and the PC's clocks, time zones)
START_TIME_AFTER_TOLERANCE_S = 86_400.0
#: a ``start_time`` more than this before the ``System UpLoad Time`` is implausible (an instrument's memory is
#: uploaded days to a few years after its deployment, never decades: 1903 for 2003 is a two-digit year)
START_TIME_MAX_AGE_YEARS = 10


def checked_start_time(start_iso: str | None, start_text: str, nmea_utc: str | None,
                       clock: dict[str, tuple[str | None, str]]) -> tuple[str | None, str | None]:
    """The header's ``start_time`` checked against the header's own clocks; returns (the time to use, a note
    saying what was corrected, or ``None`` when nothing was).

    The reference is the first of ``NMEA UTC (Time)`` (GPS, written when acquisition started), ``System UTC``
    (the acquisition PC's clock, same moment) and ``System UpLoad Time`` (when the data were read from the
    instrument: after the cast). With NMEA or System UTC, a ``start_time`` more than
    :data:`START_TIME_AFTER_TOLERANCE_S` from it disagrees and the reference is used. With only the upload
    time, a ``start_time`` after it (beyond the tolerance) or more than :data:`START_TIME_MAX_AGE_YEARS` years
    before it disagrees; then a start_time that falls within that window once its century is the upload's
    (SeaSoft's two-digit years: ``Oct 15 1903`` uploaded ``Oct 15 2003``) gets that century, else the upload
    time is used (an upper bound of the cast's time)."""
    import pandas as pd

    if start_iso is None:
        return None, None
    start = pd.Timestamp(start_iso)
    shown = " ".join(start_text.split("[")[0].split())
    for key, label in (("nmea", "NMEA UTC (Time)"), ("system_utc", "System UTC")):
        iso, text = (nmea_utc, nmea_utc) if key == "nmea" else clock.get(key, (None, ""))
        if iso is None:
            continue
        ref = pd.Timestamp(iso)
        if abs((start - ref).total_seconds()) <= START_TIME_AFTER_TOLERANCE_S:
            return start_iso, None
        return ref.isoformat(), (f"start_time {shown} disagrees with {label} {text} (by "
                                 f"{_span_text((start - ref).total_seconds())}); used {label}: {ref.isoformat()}")
    iso, text = clock.get("upload_time", (None, ""))
    if iso is None:
        return start_iso, None
    up = pd.Timestamp(iso)
    earliest = up - pd.DateOffset(years=START_TIME_MAX_AGE_YEARS)
    late = (start - up).total_seconds() > START_TIME_AFTER_TOLERANCE_S
    if not late and start >= earliest:
        return start_iso, None
    why = (f"start_time {shown} disagrees with System UpLoad Time {text} (it is "
           f"{_span_text((start - up).total_seconds())} {'after' if late else 'before'} it)")
    century = up.year // 100 * 100 + start.year % 100
    for year in (century, century - 100):
        try:
            fixed = start.replace(year=year)
        except ValueError:  # Feb 29 of a year that is not a leap year
            continue
        if earliest <= fixed and (fixed - up).total_seconds() <= START_TIME_AFTER_TOLERANCE_S:
            return fixed.isoformat(), (f"{why}; used the start_time with the upload's century (a two-digit "
                                       f"year): {fixed.isoformat()}")
    return up.isoformat(), f"{why}; used System UpLoad Time (the cast ended before it): {up.isoformat()}"


def _span_text(seconds: float) -> str:
    """``'100 years'``, ``'3 days'``, ``'5 h'`` for a time difference (sign dropped)."""
    s = abs(seconds)
    if s >= 365.25 * 86_400:
        return f"{s / (365.25 * 86_400):.0f} years"
    if s >= 86_400:
        return f"{s / 86_400:.0f} days"
    return f"{s / 3600:.1f} h"


def _unique_names(names: Sequence[str]) -> list[str]:
    """Duplicate column names get pandas' ``.1``, ``.2`` suffixes (``scan``, ``scan.1``)."""
    seen: dict[str, int] = {}
    out = []
    for n in names:
        if n in seen:
            seen[n] += 1
            out.append(f"{n}.{seen[n]}")
        else:
            seen[n] = 0
            out.append(n)
    return out


def _processing_line(s: str) -> list[str] | None:
    """``[key, value]`` of a SeaSoft processing line, or ``None`` when ``s`` is not one."""
    m = _PROC_RE.match(s)
    if not m:
        return None
    key, rest = m.group(1), m.group(2).strip()
    if rest.startswith("="):
        return [key, rest[1:].strip()]
    if rest.startswith(":"):
        return [key, rest[1:].strip()]
    if "=" in rest:  # 'wfilter_action prDM = median, 21'
        sub, val = rest.split("=", 1)
        return [f"{key} {sub.strip()}".strip(), val.strip()]
    return [key, rest]


def _num(text: str | None) -> float | str | None:
    if text is None:
        return None
    t = text.strip()
    try:
        v = float(t)
    except ValueError:
        return t
    return v if math.isfinite(v) else t


def _parse_sensors_xml(lines: list[str]) -> tuple[list[dict[str, Any]] | None, str | None]:
    """The ``# <Sensors count=..>`` block (SeaSoft 7 .xmlcon copy) as one dict per ``<sensor Channel=..>``:
    ``channel``, ``type`` (element name, e.g. ``TemperatureSensor``), ``sensor_id``, ``serial_number``,
    ``calibration_date``, ``description`` (the ``<!-- Frequency 0, Temperature -->`` comment) and
    ``coefficients`` (numeric leaves, nested ones as ``Coefficients[equation=1].G``). ``(None, error)``
    when the block is not well-formed XML."""
    import xml.etree.ElementTree as ET

    text = "\n".join(lines)
    try:
        parser = ET.XMLParser(target=ET.TreeBuilder(insert_comments=True))
        root = ET.fromstring(text, parser=parser)
    except ET.ParseError as exc:
        return None, f"sensor XML block is not well-formed ({exc})"
    out: list[dict[str, Any]] = []
    for sen in root.iter("sensor"):
        ch = sen.get("Channel")
        d: dict[str, Any] = {"channel": int(ch) if ch and ch.strip().isdigit() else ch, "type": None, "sensor_id": None,
                             "serial_number": None, "calibration_date": None, "description": None,
                             "coefficients": {}}
        for child in sen:
            if child.tag is ET.Comment:
                d["description"] = (child.text or "").strip() or None
                continue
            d["type"] = child.tag
            d["sensor_id"] = _num(child.get("SensorID"))

            def walk(el: Any, prefix: str, d: dict[str, Any] = d) -> None:
                for sub in el:
                    if sub.tag is ET.Comment:
                        continue
                    tag = sub.tag
                    if tag == "SerialNumber":
                        d["serial_number"] = (sub.text or "").strip() or None
                    elif tag == "CalibrationDate":
                        d["calibration_date"] = (sub.text or "").strip() or None
                    elif len(sub):
                        label = tag + "".join(f"[{k}={v}]" for k, v in sub.attrib.items())
                        walk(sub, f"{prefix}{label}.", d)
                    else:
                        d["coefficients"][prefix + tag] = _num(sub.text)

            walk(child, "")
        out.append(d)
    return out, None


def _channel_notes(long_name: str) -> dict[str, Any]:
    """``key = value`` notes after a channel's units (``lat = 69.41``, ``WS = 2``), values numeric when they can be."""
    i = long_name.rfind("]")
    tail = long_name[i + 1:] if i >= 0 else ""
    return {m.group(1).strip(): _num(m.group(2)) for m in _NOTE_RE.finditer(tail)}


def _is_label_line(line: str) -> bool:
    """A line of column labels right after ``*END*`` (no token is a number; some tools write one): not data."""
    toks = line.split()
    if not toks:
        return False
    for t in toks:
        try:
            float(t)
            return False
        except ValueError:
            continue
    return True


def _parse_line_slow(line: str, nquan: int) -> list[float] | None:
    """One data line's values, or ``None``: whitespace-separated, else re-read as 11-character fields (SeaSoft
    columns can touch, e.g. ``-123.4567-99.12``)."""
    toks = line.split()
    if len(toks) != nquan:
        if len(line.rstrip()) != nquan * _FIELD_WIDTH:
            return None
        toks = [line[k * _FIELD_WIDTH:(k + 1) * _FIELD_WIDTH] for k in range(nquan)]
    try:
        return [float(t) for t in toks]
    except ValueError:
        return None


#: bytes per piece of the .cnv body parsed at once (its temporaries, ~10x this, bound the reader's extra memory)
_PIECE_BYTES = 1 << 20
_WS = np.zeros(256, dtype=bool)
_WS[[9, 10, 11, 12, 13, 32]] = True
#: bytes of a plain numeric body (white space, digits, sign, point, exponent): parsed by ``np.fromstring``
_PLAIN = _WS.copy()
_PLAIN[np.frombuffer(b"0123456789+-.eE", dtype=np.uint8)] = True
#: the first capacity of the row array when the body's size is unknown (compressed input): 64 MiB, then it grows
_FIRST_CAPACITY_BYTES = 64 << 20


class _RowSink:
    """The data rows of a .cnv, parsed piece by piece (whole lines) into one preallocated float64 array.

    Memory: the array (rows x nquan x 8 B) plus one piece's temporaries. The capacity is an estimate (the body's
    bytes over the first piece's bytes per line, or the header's ``nvalues``); when it is exceeded the array
    grows by 1.5x (the untouched tail of an over-estimate is never written, so it costs no resident memory).
    A piece whose every non-blank line has ``nquan`` tokens is converted in one NumPy call; otherwise its lines
    are read one by one (fixed-width fallback, unreadable lines dropped and their numbers kept)."""

    def __init__(self, nquan: int, bad_flag: float, capacity_hint: int | None, body_bytes: int | None,
                 budget: DecodeBudget | None = None):
        self.nquan, self.bad_flag = nquan, bad_flag
        self.budget = budget
        self.hint, self.body_bytes = capacity_hint, body_bytes
        self.a: np.ndarray | None = None
        self.n = 0
        self.n_bad = 0
        self.bad_lines: list[int] = []
        #: values per rejected line -> how many lines (names the column-count mismatch when no row is readable)
        self.bad_counts: dict[int, int] = {}

    def _reserve(self, extra: int, piece_bytes: int, piece_rows: int) -> None:
        need = self.n + extra
        if self.a is None:
            # the header's nvalues is a hint, never trusted for memory: it is capped by what the body can hold
            # (uncompressed), or by a first capacity of _FIRST_CAPACITY_BYTES (compressed: the decompressed size is
            # unknown), and the array grows as rows arrive (a gzip .cnv declaring 2e9 scans once asked for 119 GiB)
            cap = self.hint or 0
            if self.body_bytes is not None and piece_rows:
                est = int(self.body_bytes / (piece_bytes / piece_rows) * 1.02) + 16
                cap = est if not cap else min(max(cap, need), est)
            elif cap:
                cap = min(cap, max(_FIRST_CAPACITY_BYTES // (8 * self.nquan), 16))
            cap = max(cap, need, 16)
            self._hold(cap, need)
            self.a = np.empty((cap, self.nquan), dtype=np.float64)
        elif need > self.a.shape[0]:
            cap = max(need, int(self.a.shape[0] * 1.5) + 16)
            self._hold(cap, need)
            grown = np.empty((cap, self.nquan), dtype=np.float64)
            grown[:self.n] = self.a[:self.n]
            self.a = grown

    def _hold(self, cap: int, rows: int) -> None:
        """The budget (:class:`hadal.budget.DecodeBudget`) before an array of ``cap`` rows is allocated."""
        if self.budget is not None:
            self.budget.hold(cap * self.nquan * 8.0,
                             f"{rows:,} scans of {self.nquan} channels so far")

    def _store(self, vals: np.ndarray, piece_bytes: int) -> None:
        # bad_flag = 0 is substituted after the whole body is read (_apply_zero_bad_flag: per channel, not in the
        # flag/time/count channels, where 0 is a real value)
        is_bad = np.isclose(vals, self.bad_flag, rtol=1e-6, atol=0.0) if self.bad_flag != 0 else None
        nb = 0 if is_bad is None else int(np.count_nonzero(is_bad))
        if nb:
            vals[is_bad] = np.nan
            self.n_bad += nb
        self._reserve(vals.shape[0], piece_bytes, vals.shape[0])
        assert self.a is not None
        self.a[self.n:self.n + vals.shape[0]] = vals
        self.n += vals.shape[0]

    def feed(self, piece: bytes, first_line_no: int) -> None:
        """Parse ``piece`` (whole lines, ``\\n``-separated; its first line is line ``first_line_no``)."""
        if not piece.strip():
            return
        buf = np.frombuffer(piece, dtype=np.uint8)
        ws = (buf >= 9) & (buf <= 13)  # bytes.split()'s white space: \t \n \v \f \r and space
        ws |= buf == 32
        starts = ~ws
        starts[1:] &= ws[:-1]
        ts = np.flatnonzero(starts)  # token starts
        nl = np.flatnonzero(buf == 10)
        if buf[-1] != 10:  # a last line without its line end
            nl = np.append(nl, buf.size)
        counts = np.diff(np.searchsorted(ts, nl), prepend=0)  # tokens per line
        if np.all((counts == self.nquan) | (counts == 0)):
            vals = None
            if not np.bincount(buf, minlength=256)[~_PLAIN].any():  # digits, signs, '.', 'e', white space only
                with warnings.catch_warnings():
                    warnings.simplefilter("error", DeprecationWarning)
                    try:
                        vals = np.fromstring(piece, dtype=np.float64, sep=" ")
                    except (ValueError, DeprecationWarning):  # an unparsable token: read it the slow way
                        vals = None
                if vals is not None and vals.size != int(counts.sum()):
                    vals = None
            if vals is None:
                try:
                    vals = np.array(piece.split(), dtype=np.float64)
                except ValueError:
                    vals = None
            if vals is not None:
                self._store(vals.reshape(-1, self.nquan), len(piece))
                return
        rows: list[list[float]] = []
        for i, line in enumerate(piece.decode("latin-1").split("\n")):
            if not line.strip():
                continue
            v = _parse_line_slow(line, self.nquan)
            if v is None:
                self.bad_lines.append(first_line_no + i)
                k = len(line.split())
                self.bad_counts[k] = self.bad_counts.get(k, 0) + 1
            else:
                rows.append(v)
        if rows:
            self._store(np.array(rows, dtype=np.float64).reshape(-1, self.nquan), len(piece))

    def result(self) -> np.ndarray:
        if self.a is None:
            return np.empty((0, self.nquan), dtype=np.float64)
        return self.a[:self.n]


def _too_long(path: Path, line_no: int, n: int) -> None:
    raise InputError(f"{path}: line {line_no} is {n:,}+ bytes long: not a .cnv header or data line (the limit is "
                     f"{MAX_LINE_BYTES:,} bytes; is this really a Sea-Bird .cnv?)")


def _pieces(path: Path):
    """``(compression, file size)`` then the decompressed content as pieces of whole lines (``\\n`` line ends;
    ``\\r\\n`` and old-Mac ``\\r`` normalised), in memory bounded by the block size: a line longer than
    :data:`~hadal.ingest.csv_reader.MAX_LINE_BYTES` is a one-line :class:`InputError` (not a text file)."""
    blocks = iter_blocks(path, "CNV", block_bytes=_PIECE_BYTES)
    first = next(blocks, b"")  # the one-line errors of a missing/unreadable file or a damaged stream
    with open(path, "rb") as fh:
        comp = compression_of(fh.read(8))
    yield comp, path.stat().st_size
    carry = b""
    line_no = 1  # number of the first line of the carry
    for block in itertools.chain((first,) if first else (), blocks):
        buf = carry + block if carry else bytes(block)
        cut = buf.rfind(b"\n") + 1
        if cut == 0:  # old-Mac '\r' line ends; a final '\r' may still be the first half of a '\r\n'
            cut = buf.rfind(b"\r", 0, len(buf) - 1) + 1
        piece, carry = buf[:cut], buf[cut:]
        if len(carry) > MAX_LINE_BYTES:
            _too_long(path, line_no + piece.count(b"\n"), len(carry))
        if piece:
            piece = piece.replace(b"\r\n", b"\n").replace(b"\r", b"\n")
            if len(piece) > MAX_LINE_BYTES:
                ends = np.flatnonzero(np.frombuffer(piece, dtype=np.uint8) == 10)
                lengths = np.diff(ends, prepend=-1) - 1
                k = int(np.argmax(lengths))
                if lengths[k] > MAX_LINE_BYTES:
                    _too_long(path, line_no + k, int(lengths[k]))
            line_no += piece.count(b"\n")
            yield piece
    if carry:
        yield carry.replace(b"\r\n", b"\n").replace(b"\r", b"\n")


class _HeaderLines:
    """What :func:`_parse_header` collects from the ``*`` and ``#`` header lines, one line at a time."""

    def __init__(self) -> None:
        self.names: dict[int, tuple[str, str]] = {}
        self.spans: dict[int, list[float] | None] = {}
        self.kv: dict[str, str] = {}
        self.processing: list[list[str]] = []
        self.sensors: list[str] = []
        self.user: list[str] = []
        self.instr: list[str] = []
        self.comments: list[str] = []
        self.xml_lines: list[str] = []
        self.in_xml = False
        self.lat: float | None = None
        self.lon: float | None = None
        self.lat_src: str | None = None
        self.lon_src: str | None = None
        self.nmea_utc: str | None = None
        #: ``System UpLoad Time`` / ``System UTC`` lines: key -> (ISO time or None, text as written)
        self.clock: dict[str, tuple[str | None, str]] = {}

    def star_line(self, s: str) -> None:
        """A ``*`` (instrument) or ``**`` (user) line: kept, and read for the position and NMEA time."""
        (self.user if s.startswith("**") else self.instr).append(s.lstrip("*").strip())
        m = _POS_RE.match(s)
        if m:
            key = m.group(1).lower()
            is_lat = key.startswith("lat")
            val = parse_latlon(m.group(2), is_latitude=is_lat)
            # a '**' user line wins over the NMEA line only when the NMEA one is missing/unreadable
            if is_lat and val is not None and (self.lat is None or self.lat_src == "nmea" and s.startswith("**")):
                self.lat, self.lat_src = val, ("user" if s.startswith("**") else "nmea")
            elif not is_lat and val is not None and (self.lon is None
                                                     or self.lon_src == "nmea" and s.startswith("**")):
                self.lon, self.lon_src = val, ("user" if s.startswith("**") else "nmea")
        m = re.match(r"^\*\s*NMEA UTC \(Time\)\s*=\s*(.+)$", s, re.I)
        if m:
            self.nmea_utc = _parse_time(m.group(1))[0]
        m = re.match(r"^\*\s*System\s+(UpLoad Time|UTC)\s*=\s*(.+)$", s, re.I)
        if m:
            key = "system_utc" if m.group(1).upper() == "UTC" else "upload_time"
            self.clock[key] = (_parse_time(m.group(2))[0], " ".join(m.group(2).split()))

    def hash_line(self, s: str) -> None:
        """A ``#`` line: sensor XML, channel name / span, sensor, processing or key = value line, else a comment."""
        body = s[1:].strip()
        if self.in_xml or re.match(r"^<Sensors\b", body):
            self.in_xml = not body.startswith("</Sensors")
            self.xml_lines.append(body)
            return
        if re.match(r"^</?[A-Za-z!]", body):
            return  # other XML lines outside the sensor block
        m = _NAME_RE.match(s)
        if m:
            self.names[int(m.group(1))] = (m.group(2).strip(), m.group(3).strip())
            return
        m = _SPAN_RE.match(s)
        if m:
            try:
                lo, hi = (float(x) for x in m.group(2).split(",")[:2])
                self.spans[int(m.group(1))] = [lo, hi]
            except ValueError:
                self.spans[int(m.group(1))] = None
            return
        if re.match(r"^#\s*sensor\s+\d+\s*=", s):
            self.sensors.append(s.lstrip("#").strip())
            return
        proc = _processing_line(s)
        if proc is not None and proc[0].lower() not in _RESERVED:
            self.processing.append(proc)
            return
        m = _KV_RE.match(s)
        if m:
            key, val = m.group(1).strip(), m.group(2).strip()
            if key.lower() in _RESERVED:
                self.kv[key.lower()] = val
            elif re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", key):
                self.processing.append([key, val])  # '<module>_<key> = value' SeaSoft processing line
            else:
                self.comments.append(s.lstrip("#").strip())
        else:
            self.comments.append(s.lstrip("#").strip())


def _header_columns(names: dict[int, tuple[str, str]], kv: dict[str, str], path: Path) -> tuple[int, list[str]]:
    """The number of channels (``# nquan``, else the highest ``# name`` index + 1) and unique column names;
    warns (at read_cnv's caller) about channels without a ``# name`` line."""
    if not names:
        raise InputError(f"{path}: CNV header has no '# name N = ...' channel lines")
    try:
        nquan = int(kv["nquan"]) if "nquan" in kv else max(names) + 1
    except ValueError:
        raise InputError(f"{path}: CNV header has an invalid '# nquan = {kv['nquan']}'") from None
    if nquan <= 0 or nquan > 10_000:
        raise InputError(f"{path}: CNV header declares nquan = {nquan}")
    missing = [i for i in range(nquan) if i not in names]
    if missing:
        warnings.warn(f"{path.name}: header lacks '# name' lines for channel(s) {missing}; named 'col<i>'",
                      stacklevel=5)  # _parse_header <- _stream_cnv <- read_cnv <- its caller
    short = [names.get(i, (f"col{i}", ""))[0] for i in range(nquan)]
    return nquan, _unique_names(short)


def _header_hints(kv: dict[str, str]) -> tuple[float, int | None]:
    """The header's ``bad_flag`` (SeaSoft's default when absent/unreadable) and a plausible ``nvalues``."""
    bad_flag = CNV_DEFAULT_BAD_FLAG
    if "bad_flag" in kv:
        try:
            bad_flag = float(kv["bad_flag"])
        except ValueError:
            pass
    try:
        nvalues_hint: int | None = int(kv["nvalues"])
    except (KeyError, ValueError):
        nvalues_hint = None
    if nvalues_hint is not None and not 0 < nvalues_hint < 1 << 31:
        nvalues_hint = None
    return bad_flag, nvalues_hint


def _parse_header(header: list[str], path: Path) -> dict[str, Any]:
    """The header lines before ``*END*`` parsed (channel names, spans, key/values, processing, positions, ...)."""
    h = _HeaderLines()
    for ln in header:
        s = ln.strip()
        if not s:
            continue
        if s.startswith("*"):
            h.star_line(s)
        elif s.startswith("#"):
            h.hash_line(s)
    nquan, columns = _header_columns(h.names, h.kv, path)
    bad_flag, nvalues_hint = _header_hints(h.kv)
    return {"names": h.names, "spans": h.spans, "kv": h.kv, "processing": h.processing, "sensors": h.sensors,
            "user": h.user, "instr": h.instr, "comments": h.comments, "xml_lines": h.xml_lines, "lat": h.lat,
            "lon": h.lon, "lat_src": h.lat_src, "lon_src": h.lon_src, "nmea_utc": h.nmea_utc, "clock": h.clock,
            "nquan": nquan,
            "columns": columns, "bad_flag": bad_flag, "nvalues_hint": nvalues_hint}


#: channels where 0 is a real value, never SeaSoft's bad marker: the scan flag (0 = good), counters (scan number,
#: bottles fired, scans per bin), pump status and the time channels (elapsed time 0 at the first scan)
_ZERO_IS_REAL = {"flag", "scan", "nbf", "nbin", "pumps", "times", "timej", "timey", "timek", "timem", "timeh",
                 "timen", "timeq"}


def _apply_zero_bad_flag(data: np.ndarray, columns: Sequence[str], path: Path) -> int:
    """``# bad_flag = 0`` applied to ``data`` in place; returns the number of values made NaN.

    0 is an ambiguous bad marker: it collides with real zeros (SeaSoft's ``flag`` channel, where 0 means good;
    counters; elapsed time at the first scan; an unused user polynomial; PAR in the dark; conductivity in air).
    So it is applied only where a 0 can plausibly mean "bad": not in :data:`_ZERO_IS_REAL` channels, not in a
    channel that is 0 on every scan (a constant, not a bad channel); elsewhere every exact 0 becomes NaN and a
    warning names the channels and counts, so that a real 0 wrongly blanked is visible. (Deviation from SeaSoft,
    which compares every value with bad_flag: applied verbatim, bad_flag 0 once flagged a whole intact cast bad
    through its flag channel.)"""
    hit: list[str] = []
    n_bad = 0
    for j, col in enumerate(columns):
        base = str(col).split(".")[0].strip().lower()
        if base in _ZERO_IS_REAL:
            continue
        z = data[:, j] == 0
        nz = int(np.count_nonzero(z))
        if not nz or nz == data.shape[0]:
            continue
        data[z, j] = np.nan
        n_bad += nz
        hit.append(f"{col} ({nz})")
    msg = (f"{path.name}: header says '# bad_flag = 0', which collides with real zeros; 0 was not treated as bad "
           "in the flag, scan-count and time channels nor in all-zero channels")
    msg += f"; zeros made NaN in: {', '.join(hit)}" if hit else "; no other channel holds a 0"
    warnings.warn(msg, stacklevel=3)
    return n_bad


def _strip_label_line(piece: bytes) -> tuple[list[str] | None, bytes]:
    """The column labels of a label line right after ``*END*`` (:func:`_is_label_line`; some tools write one)
    and ``piece`` with that line blanked (line numbers kept); ``(None, piece)`` without one."""
    a = 0
    while a < len(piece):
        b = piece.find(b"\n", a)
        b = len(piece) if b < 0 else b
        line = piece[a:b].decode("latin-1")
        if line.strip():
            if not _is_label_line(line):
                return None, piece
            return line.split(), piece[:a] + piece[b:]
        a = b + 1
    return None, piece


#: working copies of a .cnv's scans counted by its memory budget: the row array, the growth copy (1.5x) and the
#: float64 channel arrays of the sensor samples and the sensors table the ingest stage builds from it (measured:
#: read_cnv + cnv_sensor_samples of 5e6 scans x 4 channels peaked 2.4x the array above the
#: interpreter; the stage's table adds one more)
CNV_WORKING_COPIES = 4.0


def _stream_cnv(path: Path, max_bytes: float | None = None) -> tuple[str | None, dict[str, Any], _RowSink,
                                                                     list[str] | None]:
    """One streaming pass over ``path``: the header lines up to ``*END*`` (parsed by :func:`_parse_header`),
    then each body piece fed to a :class:`_RowSink` (never the whole file in memory). Returns (compression,
    parsed header, the filled sink, the labels of a label line after ``*END*`` or None)."""
    pieces = _pieces(path)
    compression, file_size = next(pieces)
    header: list[str] = []
    hdr: dict[str, Any] | None = None
    sink: _RowSink | None = None
    column_labels: list[str] | None = None
    labels_checked = False
    line_no = 1  # number of the next line
    any_content = False
    for piece in pieces:
        any_content = any_content or bool(piece.strip())
        if hdr is None:
            lines = piece.decode("latin-1").split("\n")
            if lines and lines[-1] == "":
                lines.pop()  # the piece ends with a line end
            k = next((i for i, ln in enumerate(lines) if ln.strip().upper() == "*END*"), None)
            if k is None:
                header.extend(lines)
                line_no += len(lines)
                continue
            header.extend(lines[:k])
            line_no += k + 1
            hdr = _parse_header(header, path)
            header_bytes = sum(len(x) + 1 for x in header) + len(lines[k]) + 1
            sink = _RowSink(hdr["nquan"], hdr["bad_flag"], hdr["nvalues_hint"],
                            None if compression is not None or file_size is None
                            else max(file_size - header_bytes, 0),
                            DecodeBudget(path, "CNV file", copies=CNV_WORKING_COPIES, limit_bytes=max_bytes))
            rest = lines[k + 1:]
            piece = ("\n".join(rest) + "\n").encode("latin-1") if rest else b""
            if not piece:
                continue
        assert sink is not None
        if not labels_checked and piece.strip():
            labels_checked = True
            column_labels, piece = _strip_label_line(piece)
        try:
            sink.feed(piece, line_no)
        except MemoryError:  # a body (decompressed) too large for this machine: one line, not a traceback
            raise InputError(f"{path}: CNV body too large to hold in memory ({sink.n:,}+ scans x {sink.nquan} "
                             f"channels read so far, line {line_no})") from None
        line_no += piece.count(b"\n") + (0 if piece.endswith(b"\n") else 1)
    if not any_content:
        raise InputError(f"{path}: CNV file is empty")
    if hdr is None or sink is None:
        raise InputError(f"{path}: not a Sea-Bird .cnv file (no '*END*' line after the header)")
    return compression, hdr, sink, column_labels


def _check_rows(path: Path, h: dict[str, Any], data: np.ndarray, bad_lines: list[int],
                bad_counts: dict[int, int]) -> None:
    """Refuse a body without a readable row (naming a column-count mismatch); warn (at read_cnv's caller)
    about dropped lines."""
    nquan, kv, names = h["nquan"], h["kv"], h["names"]
    mismatch = ""
    if bad_counts:
        k_top = max(bad_counts, key=lambda k: bad_counts[k])
        if k_top and k_top != nquan:
            mismatch = (f"; {bad_counts[k_top]} of them have {k_top} values, the header declares {nquan} columns "
                        f"('# nquan = {kv.get('nquan', '?')}', {len(names)} '# name' lines)")
    if data.shape[0] == 0:
        raise InputError(f"{path}: CNV file has no readable data rows after '*END*'"
                         + (f": rows have {k_top} values, the header declares {nquan} columns "
                            f"('# nquan = {kv.get('nquan', '?')}', {len(names)} '# name' lines)" if mismatch else ""))
    if bad_lines:
        warnings.warn(
            f"{path.name}: dropped {len(bad_lines)} unreadable data line(s) (first at line {bad_lines[0]}){mismatch}",
            stacklevel=3,
        )


def _cnv_channels(h: dict[str, Any]) -> list[dict[str, Any]]:
    """read_cnv's ``attrs['channels']``: one dict per column (name, long name, units, span, notes, latitude)."""
    names, spans, columns = h["names"], h["spans"], h["columns"]
    channels = []
    for i in range(h["nquan"]):
        nm, long = names.get(i, (f"col{i}", ""))
        um = _UNITS_RE.search(long)
        units = um.group(1).strip() if um else ""
        notes = _channel_notes(long)
        ch_lat = notes.get("lat", notes.get("latitude"))
        channels.append({"index": i, "name": nm, "column": columns[i], "long_name": long,
                         "units": units, "span": spans.get(i), "notes": notes,
                         "latitude_deg": float(ch_lat) if isinstance(ch_lat, float) and abs(ch_lat) <= 90 else None})
    return channels


def _cnv_interval(kv: dict[str, str]) -> dict[str, Any] | None:
    """The header's ``# interval = <kind>: <value>`` as ``{"kind", "value"}`` (None when absent/unreadable)."""
    if "interval" in kv:
        mi = re.match(r"^\s*([A-Za-z_ ]+?)\s*:\s*([-+0-9.eE]+)", kv["interval"])
        if mi:
            return {"kind": mi.group(1).strip(), "value": float(mi.group(2))}
    return None


def _cnv_attrs(path: Path, compression: str | None, h: dict[str, Any], channels: list[dict[str, Any]],
               data: np.ndarray, bad_lines: list[int], n_bad: int, column_labels: list[str] | None
               ) -> dict[str, Any]:
    """read_cnv's ``df.attrs``; warns (at read_cnv's caller) about a wrong ``nvalues`` or unreadable sensor XML."""
    kv, processing, instr, xml_lines, columns = h["kv"], h["processing"], h["instr"], h["xml_lines"], h["columns"]
    start_iso, start_note = _parse_time(kv.get("start_time", ""))
    start_file = start_iso
    start_iso, start_fix = checked_start_time(start_iso, kv.get("start_time", ""), h["nmea_utc"], h["clock"])
    if start_fix:
        warnings.warn(f"{path.name}: {start_fix}", stacklevel=3)
    interval = _cnv_interval(kv)
    try:
        nvalues_declared: int | None = int(kv["nvalues"])
    except (KeyError, ValueError):
        nvalues_declared = None
    if nvalues_declared is not None and nvalues_declared != data.shape[0] + len(bad_lines):
        warnings.warn(f"{path.name}: header declares nvalues = {nvalues_declared} but the file holds "
                      f"{data.shape[0] + len(bad_lines)} data rows (truncated or edited file)", stacklevel=3)
    sensors_xml, xml_error = _parse_sensors_xml(xml_lines) if xml_lines else (None, None)
    if xml_error:
        warnings.warn(f"{path.name}: {xml_error}; kept as text in attrs['sensors_xml_text']", stacklevel=3)
    serial = re.search(r"SerialNumber='([^']*)'", " ".join(instr))
    channel_lat = {c["column"]: c["latitude_deg"] for c in channels if c["latitude_deg"] is not None}
    time_cols = [c for c in ("timeS", "timeJ", "timeY", "timeK", "timeM", "timeH", "timeN", "timeQ")
                 if c in columns]
    lat, lat_src = h["lat"], h["lat_src"]
    if lat is None and len(set(channel_lat.values())) == 1:
        # no NMEA/user latitude, but SeaSoft wrote the one it used into a channel name ('depSM: Depth [salt water,
        # m], lat = 48.38'): the operator's latitude for this cast, recorded by the vendor's software
        col, lat = next(iter(channel_lat.items()))
        lat_src = f"channel {col} note 'lat = {lat:g}' (the latitude SeaSoft used)"
    return {
        "source": str(path),
        "compression": compression,
        "format": "Sea-Bird SeaSoft .cnv",
        "instrument": instr[0] if instr else None,
        "channels": channels,
        "units": {c["column"]: c["units"] for c in channels},
        "latitude_deg": lat,
        "longitude_deg": h["lon"],
        "position_source": {"latitude": lat_src, "longitude": h["lon_src"]},
        "start_time_utc": start_iso,
        "start_time_note": start_note,
        "start_time_file": start_file,
        "start_time_correction": start_fix,
        "nmea_utc": h["nmea_utc"],
        "upload_time_utc": (h["clock"].get("upload_time") or (None,))[0],
        "system_utc": (h["clock"].get("system_utc") or (None,))[0],
        "interval": interval,
        "bad_flag": h["bad_flag"],
        "bad_values": n_bad,
        "processing": processing,
        "sensors": h["sensors"],
        "sensors_xml": sensors_xml,
        "sensors_xml_text": "\n".join(xml_lines) if xml_error else None,
        "instrument_serial": serial.group(1) if serial else None,
        "channel_latitude_deg": channel_lat,
        "column_labels": column_labels,
        "time_channels": time_cols,
        "binned": bool((interval or {}).get("kind") in ("decibars", "meters", "scans")
                       or any(k.startswith("binavg_") for k, _ in processing)),
        "user_header": h["user"],
        "instrument_header": instr,
        "header_comments": h["comments"],
        "nquan": h["nquan"],
        "nvalues_declared": nvalues_declared,
        "nvalues": int(data.shape[0]),
        "truncated": bool(nvalues_declared is not None and nvalues_declared > data.shape[0] + len(bad_lines)),
        "rows_dropped": bad_lines,
    }


def read_cnv(path: str | Path, *, max_bytes: float | None = None) -> pd.DataFrame:
    """Read a Sea-Bird ``.cnv`` file into a DataFrame with the file's column names.

    ``df.attrs`` holds the header (all JSON-serialisable):

    * ``source`` (path), ``instrument`` (first header line, e.g. ``Sea-Bird SBE 9 Data File:``);
    * ``channels``: list of ``{index, name, column, long_name, units, span}`` (``units`` is the bracketed
      text, e.g. ``"ITS-90, deg C"``, ``"db"``, ``"S/m"``; ``span`` the header ``[lo, hi]`` or ``None``);
      ``units``: ``{column: units}``;
    * ``latitude_deg`` / ``longitude_deg``: decimal degrees from ``* NMEA Latitude = ...`` /
      ``** Latitude: ...`` lines (``None`` when absent or unreadable);
    * ``start_time_utc`` (ISO-8601, ``None`` when absent), ``start_time_note`` (SeaSoft's bracket text),
      ``nmea_utc`` when present;
    * ``interval``: ``{"kind": "decibars"|"seconds"|..., "value": float}``;
    * ``bad_flag`` (float; those values became NaN; ``bad_flag = 0`` is ambiguous and applied only where a 0 can
      mean "bad", never in the ``flag``/count/time channels, with a warning: :func:`_apply_zero_bad_flag`),
      ``bad_values`` (count replaced);
    * ``processing``: SeaSoft processing lines in file order, ``[[key, value], ...]``
      (``datcnv_date``, ``wildedit_vars``, ``Derive_in``, ...);
    * ``sensors`` (``# sensor i = ...`` lines), ``user_header`` (``**`` lines), ``instrument_header``;
    * ``nquan``, ``nvalues_declared``, ``nvalues`` (rows read), ``rows_dropped`` (line numbers of
      unparseable data lines, dropped with a warning).

    The header's ``nvalues`` is only a capacity hint, capped by the body size (or 64 MiB for compressed input),
    never trusted for memory; a count that disagrees with the rows is a warning.

    Raises :class:`~hadal.errors.InputError` (one line, naming the file) when the file is missing, empty,
    has no ``*END*`` line, no ``# name`` lines, or no readable data rows (naming a column-count mismatch: rows
    of N values under a header of M columns), and when its scans with their working copies would need more than
    ``max_bytes`` (default: the memory budget, :class:`hadal.budget.DecodeBudget`), checked as the body decodes.
    """
    path = Path(path)
    compression, h, sink, column_labels = _stream_cnv(path, max_bytes)
    data, bad_lines, n_bad, bad_counts = sink.result(), sink.bad_lines, sink.n_bad, sink.bad_counts
    del sink
    _check_rows(path, h, data, bad_lines, bad_counts)
    if h["bad_flag"] == 0:
        n_bad = _apply_zero_bad_flag(data, h["columns"], path)
    df = pd.DataFrame(data, columns=h["columns"], copy=False)
    df.attrs.update(_cnv_attrs(path, compression, h, _cnv_channels(h), data, bad_lines, n_bad, column_labels))
    return df


# ------------------------------------------------------------------------------ CNV as a sensor source
#: SeaSoft short names of the primary CTD channels, in order of preference -> unit for hadal.ingest.units
CNV_PRESSURE = (("prDM", "dbar"), ("prdM", "dbar"), ("prSM", "dbar"), ("prM", "dbar"), ("pr", "dbar"))
CNV_TEMPERATURE = (("t090C", "degC_its90"), ("tv290C", "degC_its90"), ("t090", "degC_its90"),
                   ("t068C", "degC_its68"), ("tv268C", "degC_its68"), ("t068", "degC_its68"),
                   # the secondary sensor pair of a dual CTD (SeaSoft "Temperature, 2"), when the file has no primary
                   ("t190C", "degC_its90"), ("t190", "degC_its90"), ("t168C", "degC_its68"), ("t168", "degC_its68"))
CNV_CONDUCTIVITY = (("c0S/m", "S/m"), ("c0mS/cm", "mS/cm"), ("c0uS/cm", "uS/cm"),
                    ("c1S/m", "S/m"), ("c1mS/cm", "mS/cm"), ("c1uS/cm", "uS/cm"))
#: SeaSoft depth channels (salt water, Fofonoff-Millard / UNESCO 44): the pressure of a cast exported with depth
#: and no pressure channel is recovered from it (:func:`pressure_from_depsm`)
CNV_DEPTH = ("depSM", "depS")
#: SeaSoft's practical salinity channels (PSS-78), primary first: used only when the cast has no conductivity
#: channel (seabirdscientific's sbs_variables.json: ``sal00`` = ``psal0``/``practicalSalinity``, ``sal11`` =
#: ``psal1``)
CNV_SALINITY = ("sal00", "psal0", "practicalSalinity", "sal11", "psal1")
#: the sensors-table variable of the vendor's salinity (an optional column of ``schemas/sensors.yaml``)
VENDOR_SALINITY = "practical_salinity_vendor"
#: A/D full-scale voltage of the Sea-Bird CTDs an altimeter is cabled to (SBE 9plus, 19plus, 25: 0-5 V)
SEABIRD_AD_FULL_SCALE_V = 5.0
#: an altimeter reading at or above this fraction of its full-scale range is "no bottom" (no echo). Sea-Bird
#: application note AN95: a Benthos PSA-916 outputs 4.98 V of 5 V (99.6 %) when no echo is received; units in
#: the field read 4.93-4.94 V (98.6-98.8 %, measured on pyctd_CTD-spiked-unfiltered.cnv), and the A/D clips
#: at 5 V (100 %): 97 % leaves a margin below both and costs the top 3 % of the range
ALTIMETER_NO_ECHO_FRACTION = 0.97


_NAT = np.iinfo(np.int64).min


def _ns(x_ns: np.ndarray, origin: int = 0) -> np.ndarray:
    """``origin + x`` as int64 ns; a NaN (bad_flag) or out-of-range time is NaT (int64 min), never a wrapped
    integer (a ``timeS`` equal to bad_flag once gave a row dated 1726)."""
    x = np.asarray(x_ns, dtype=np.float64) + float(origin)
    out = np.full(x.shape, _NAT, dtype=np.int64)
    ok = np.isfinite(x) & (np.abs(x) < 9.2e18)
    out[ok] = np.round(np.asarray(x_ns, dtype=np.float64)[ok]).astype(np.int64) + origin
    return out


def _timej_ns(jd: np.ndarray, start: pd.Timestamp) -> np.ndarray:
    """``timeJ`` (SeaSoft Julian day: 1.0 = Jan 1 00:00 of the year) as int64 ns, across New Year.

    timeJ carries no year. The first valid scan's year is the start_time's year, or the one before/after when
    its day is more than half a year from the start's day (a start_time of Jan 1 00:00:30 with scans from Dec 31).
    Then every drop of more than half a year between consecutive valid scans is a New Year: the days after it
    count from Jan 1 of the next year (a cast from Dec 31 23:59 to Jan 1 00:01 once had its last minute dated
    364 days before its start)."""
    jd = np.asarray(jd, dtype=np.float64)
    ok = np.flatnonzero(np.isfinite(jd))
    out_days = np.full(jd.shape, np.nan)
    if ok.size:
        start_day = (start - pd.Timestamp(year=start.year, month=1, day=1, tz="UTC")).total_seconds() / 86400 + 1
        year = start.year
        half = 366 / 2
        if jd[ok[0]] < start_day - half:
            year += 1
        elif jd[ok[0]] > start_day + half:
            year -= 1
        v = jd[ok]
        # index (into v) of each New Year: a drop of more than half a year
        wraps = np.flatnonzero(np.diff(v) < -half) + 1
        base = pd.Timestamp(year=year, month=1, day=1, tz="UTC")
        offsets = np.zeros(v.size)  # days from ``base`` to Jan 1 of each scan's year
        off = 0.0
        y = year
        for w in wraps:
            off += 366.0 if _is_leap(y) else 365.0
            y += 1
            offsets[w:] = off
        out_days[ok] = v - 1.0 + offsets
        return _ns(out_days * 86400e9, base.value)
    return _ns(out_days, 0)


def _is_leap(y: int) -> bool:
    return y % 4 == 0 and (y % 100 != 0 or y % 400 == 0)


def cnv_time_ns(df: pd.DataFrame) -> tuple[np.ndarray, str]:
    """Sample times (int64 ns since the Unix epoch) of a :func:`read_cnv` frame and how they were found.

    ``timeS`` (elapsed s) + ``start_time``; ``timeY`` (Unix s); ``timeJ`` (day of year, 1 = Jan 1 00:00, of
    the start year, rolled into the next year at a New Year: :func:`_timej_ns`); else a time-interval file (``# interval = seconds: dt``) gives ``start + i * dt``.
    Pressure-binned files without a time channel raise :class:`InputError`.
    """
    a = df.attrs
    path = a.get("source", "cnv")
    start = pd.Timestamp(a["start_time_utc"]) if a.get("start_time_utc") else None
    if "timeY" in df:
        return _ns(df["timeY"].to_numpy(dtype=np.float64) * 1e9), "timeY (Unix seconds)"
    if start is not None and "timeS" in df:
        return _ns(df["timeS"].to_numpy(dtype=np.float64) * 1e9, start.value), "start_time + timeS"
    if start is not None and "timeJ" in df:
        return _timej_ns(df["timeJ"].to_numpy(dtype=np.float64), start), "start year + timeJ"
    iv = a.get("interval") or {}
    if start is not None and iv.get("kind") == "seconds" and iv.get("value", 0) > 0:
        dt_ns = int(round(iv["value"] * 1e9))
        return start.value + np.arange(len(df), dtype=np.int64) * dt_ns, f"start_time + i * {iv['value']:g} s"
    raise InputError(f"{path}: no time channel (timeS/timeJ/timeY or a 'seconds' interval with start_time); "
                     f"a pressure-binned cast cannot be put on a time base")


def cnv_sensor_samples(df: pd.DataFrame, name: str = "ctd", *, allow_no_time: bool = False) -> Any:
    """A :func:`read_cnv` frame as the CTD's :class:`~hadal.ingest.csv_reader.SensorSamples` (primary
    pressure/temperature/conductivity channels, converted to hadal units; conversions recorded).

    A cast without a time channel (pressure-binned) raises :class:`InputError` unless ``allow_no_time``:
    then ``time_ns`` is ``None`` and ``stats["time"]`` is :data:`NO_TIME_BASE` (no time is invented)."""
    from hadal.ingest.csv_reader import SensorSamples
    from hadal.ingest.units import convert

    path = df.attrs.get("source", "cnv")
    try:
        t, how = cnv_time_ns(df)
    except InputError:
        if not allow_no_time:
            raise
        t, how = np.full(len(df), np.iinfo(np.int64).min, dtype=np.int64), NO_TIME_BASE
    bad_t = t == _NAT
    n_bad_t = int(bad_t.sum()) if how != NO_TIME_BASE else 0
    if n_bad_t == len(df) and len(df):
        raise InputError(f"{path}: every scan's time ({how}) is bad_flag or not a number: no time base")
    if n_bad_t:
        warnings.warn(f"{Path(path).name}: dropped {n_bad_t} of {len(df)} scan(s) whose time ({how}) is bad_flag "
                      "or not a number", stacklevel=2)
        df = df.loc[~bad_t]
        t = t[~bad_t]
    values: dict[str, Any] = {}
    conversions: list[Any] = []
    used: dict[str, Any] = {}
    stats: dict[str, Any] = {}
    for var, table in (("pressure_ctd_dbar", CNV_PRESSURE), ("temperature_its90_degc", CNV_TEMPERATURE),
                       ("conductivity_s_m", CNV_CONDUCTIVITY)):
        col = next(((c, u) for c, u in table if c in df.columns), None)
        if col is None and var == "conductivity_s_m" and _vendor_salinity(df, values, used, stats):
            continue
        if col is None and var == "pressure_ctd_dbar" and _pressure_from_depth(df, values, used, stats):
            continue
        if col is None:
            raise InputError(f"{path}: no {var.split('_')[0]} channel (looked for {', '.join(c for c, _ in table)}"
                             f"{'' if var != 'conductivity_s_m' else '; nor a SeaSoft salinity channel: ' + ', '.join(CNV_SALINITY)})")
        raw = df[col[0]].to_numpy(dtype=np.float64)
        if len(raw) and not np.isfinite(raw).any():
            warnings.warn(f"{Path(path).name}: CTD {var.split('_')[0]} channel '{col[0]}' has no valid value on any "
                          f"of its {len(raw)} scan(s) (all bad_flag or not a number): published as missing "
                          "throughout", stacklevel=2)
        v, rec = convert(raw, col[1], var)
        values[var] = v
        used[var] = col[0]
        if rec:
            conversions.append({**rec, "sensor": name, "source": f"cnv:{Path(path).name}:{col[0]}"})
    alt = _altimeter(df, name, path)
    if alt is not None:
        values["altitude_m"], alt_rec, alt_conv = alt
        used["altitude_m"] = alt_rec["channel"]
        stats["altimeter"] = alt_rec
        if alt_conv:
            conversions.append({**alt_conv, "sensor": name, "source": f"cnv:{Path(path).name}:{alt_rec['channel']}"})
    stats = {"rows": int(len(df)), "time": how, "channels": used, "bad_values": int(df.attrs.get("bad_values", 0)),
             "rows_dropped": len(df.attrs.get("rows_dropped", [])), "bad_times": n_bad_t, **stats}
    bad = seasoft_bad_scans(df)
    if bad is not None:
        # SeaSoft's scan flags (LoopEdit, WildEdit, ...): carried as a 0/1 pseudo-variable so that it follows the
        # samples through sorting and de-duplication; ingest turns it into QARTOD flag 4 on the CTD variables
        values[SEASOFT_BAD_SCAN] = bad.astype(np.float64)
        stats["seasoft_flagged_scans"] = int(bad.sum())
        stats["seasoft_flag_channel"] = str(next(c for c in df.columns if str(c).strip().lower() == "flag"))
    return SensorSamples(name, t, values, f"cnv:{Path(path).name}", stats, conversions)


def pressure_from_depsm(depth_m: np.ndarray, latitude_deg: float, iterations: int = 6) -> np.ndarray:
    """Sea pressure (dbar) whose Fofonoff-Millard depth (:func:`hadal.seawater.depth_fofonoff_millard`, SeaSoft's
    ``depSM``, UNESCO 44) is ``depth_m`` at ``latitude_deg``: the formula inverted by Newton's method (derivative
    by a 0.01 dbar difference); < 1e-6 dbar after 6 steps from ``p = 1.01 d``."""
    from hadal.seawater import depth_fofonoff_millard

    d = np.asarray(depth_m, np.float64)
    p = 1.01 * d
    for _ in range(iterations):
        f = depth_fofonoff_millard(p, latitude_deg) - d
        df_dp = (depth_fofonoff_millard(p + 0.01, latitude_deg) - depth_fofonoff_millard(p, latitude_deg)) / 0.01
        p = p - f / df_dp
    return p


def _pressure_from_depth(df: pd.DataFrame, values: dict[str, np.ndarray], used: dict[str, str],
                         stats: dict[str, Any]) -> bool:
    """A cast exported with a depth channel (:data:`CNV_DEPTH`) but no pressure channel: the pressure whose
    SeaSoft depth it is (:func:`pressure_from_depsm`) at the latitude SeaSoft used (the channel's ``lat =`` note,
    else the header position; without either 45°, said in the warning). ``False`` without a depth channel."""
    col = next((c for c in CNV_DEPTH if c in df.columns), None)
    if col is None:
        return False
    lat = (df.attrs.get("channel_latitude_deg") or {}).get(col, df.attrs.get("latitude_deg"))
    where = "its header" if lat is not None else "none in the file: 45°"
    lat = 45.0 if lat is None else float(lat)
    values["pressure_ctd_dbar"] = pressure_from_depsm(df[col].to_numpy(dtype=np.float64), lat)
    used["pressure_ctd_dbar"] = col
    stats["pressure_method"] = (f"from SeaSoft {col} (Fofonoff-Millard depth, UNESCO 44) inverted at latitude "
                                f"{lat:g} ({where}); the file has no pressure channel")
    path = Path(str(df.attrs.get("source", "cnv")))
    warnings.warn(f"{path.name}: no pressure channel: pressure {stats['pressure_method'].split('; ')[0]}",
                  stacklevel=3)
    return True


def _vendor_salinity(df: pd.DataFrame, values: dict[str, np.ndarray], used: dict[str, str],
                     stats: dict[str, Any]) -> bool:
    """A cast without a conductivity channel: SeaSoft's practical salinity (:data:`CNV_SALINITY`) as
    :data:`VENDOR_SALINITY`; conductivity is left out (the sensors table has it all missing, flag 9; it is never
    back-computed from the salinity). Fills
    ``values``/``used``/``stats`` (``salinity_method``) and warns; ``False`` when the cast has no salinity
    channel either."""
    col = next((c for c in CNV_SALINITY if c in df.columns), None)
    if col is None:
        return False
    path = Path(str(df.attrs.get("source", "cnv")))
    values[VENDOR_SALINITY] = df[col].to_numpy(dtype=np.float64)
    used[VENDOR_SALINITY] = col
    method = f"SeaSoft {col} (vendor), no conductivity channel"
    stats["salinity_method"] = method
    warnings.warn(f"{path.name}: no conductivity channel: practical salinity is the vendor's ({method}); "
                  "conductivity is published as missing (flag 9)", stacklevel=3)
    return True


def _sbs_altimeter_channels() -> dict[str, str]:
    """SeaSoft altimeter channel names -> unit token: the entries titled 'Altimeter' of seabirdscientific's
    variable list (``resources/sbs_variables.json``: ``altM`` [m], ``altF`` [ft]; ``altV``, in volts, is not a
    range and is left out). Without seabirdscientific: ``altM`` and ``altF``."""
    import json
    from importlib import resources

    out: dict[str, str] = {}
    try:
        text = resources.files("seabirdscientific").joinpath("resources/sbs_variables.json").read_text("utf-8")
        entries = json.loads(text)
    except (ImportError, OSError, ValueError):
        entries = []
    for e in entries:
        if not isinstance(e, dict) or e.get("title") != "Altimeter" or e.get("units") not in ("m", "ft"):
            continue
        for n in [e.get("name"), *(e.get("aliases") or [])]:
            if n:
                out[str(n)] = str(e["units"])
    return out or {"altM": "m", "altF": "ft"}


def altimeter_full_scale_m(attrs: dict[str, Any]) -> tuple[float | None, str | None]:
    """The altimeter's full-scale range (m) from the cast's sensor XML (``AltimeterSensor`` ScaleFactor and
    Offset) and how it was found: SeaSoft's altimeter equation (Sea-Bird application note AN95) is
    ``height = 300 * V / ScaleFactor + Offset``, so the full scale of the CTD's 0-5 V A/D channel is
    ``300 * 5 / ScaleFactor + Offset``. ``(None, None)`` when the header has no altimeter calibration."""
    for sen in attrs.get("sensors_xml") or []:
        if sen.get("type") != "AltimeterSensor":
            continue
        co = sen.get("coefficients") or {}
        sf, off = co.get("ScaleFactor"), co.get("Offset", 0.0)
        if isinstance(sf, float) and sf > 0 and isinstance(off, float):
            fs = 300.0 * SEABIRD_AD_FULL_SCALE_V / sf + off
            return fs, (f"sensor XML AltimeterSensor (S/N {sen.get('serial_number')}): 300 x "
                        f"{SEABIRD_AD_FULL_SCALE_V:g} V / ScaleFactor {sf:g} + Offset {off:g} = {fs:.4g} m")
    return None, None


def _altimeter(df: pd.DataFrame, name: str, path: str) -> tuple[np.ndarray, dict[str, Any], dict[str, Any] | None] | None:
    """The cast's altimeter channel (:func:`_sbs_altimeter_channels`) as ``altitude_m`` (m), with its no-echo
    readings made missing: readings at or above :data:`ALTIMETER_NO_ECHO_FRACTION` of the full-scale range
    (:func:`altimeter_full_scale_m`, from the header's calibration) are the altimeter's "no bottom" output, not
    ranges. Without a calibration in the header the full scale is the channel's maximum when at least
    :data:`_PLATEAU_MIN_FRACTION` of the readings sit within the same margin of it (a plateau: the saturated
    output), warned as a fallback. Returns (values, record for the read stats, unit conversion record) or
    ``None`` without an altimeter channel."""
    from hadal.ingest.units import convert

    names = _sbs_altimeter_channels()
    col = next((c for c in df.columns if str(c) in names), None)
    if col is None:
        return None
    unit = names[str(col)]
    v, conv = convert(df[col].to_numpy(dtype=np.float64), unit, "altitude_m")
    v = np.array(v, dtype=np.float64)
    fs, how = altimeter_full_scale_m(df.attrs)
    fin = v[np.isfinite(v)]
    if fs is None and fin.size:
        top = float(fin.max())
        near = np.count_nonzero(fin >= ALTIMETER_NO_ECHO_FRACTION * top)
        if top > 0 and near >= _PLATEAU_MIN_FRACTION * fin.size:
            fs = top
            how = (f"no altimeter calibration in the header: the channel's maximum {top:.4g} m, where "
                   f"{near} of {fin.size} readings sit (a saturated plateau)")
    rec: dict[str, Any] = {"channel": str(col), "units": unit, "full_scale_m": fs, "full_scale_source": how,
                           "no_echo_fraction": ALTIMETER_NO_ECHO_FRACTION, "no_echo_readings": 0}
    if fs is not None:
        limit = ALTIMETER_NO_ECHO_FRACTION * fs
        no_echo = np.isfinite(v) & (v >= limit)
        n = int(no_echo.sum())
        v[no_echo] = np.nan
        rec.update({"no_echo_threshold_m": limit, "no_echo_readings": n})
        if n:
            warnings.warn(f"{Path(path).name}: altimeter '{col}': {n} of {v.size} readings at or above "
                          f"{limit:.4g} m ({100 * ALTIMETER_NO_ECHO_FRACTION:g} % of its {fs:.4g} m full scale) are "
                          "its no-bottom output: missing (flag 9)", stacklevel=3)
    else:
        rec["no_echo_note"] = ("no altimeter calibration in the header and no saturated plateau: no reading is "
                               "treated as the no-bottom output")
    return v, rec, conv


#: fallback full scale (no calibration): the maximum is the saturated output when this fraction of readings sit at it
_PLATEAU_MIN_FRACTION = 0.1


#: the :class:`SensorSamples` pseudo-variable of SeaSoft's scan flags (1.0 = scan marked bad)
SEASOFT_BAD_SCAN = "seasoft_bad_scan"


def seasoft_bad_scans(df: pd.DataFrame) -> np.ndarray | None:
    """True for the scans SeaSoft marked bad in a .cnv's ``flag`` channel (LoopEdit/WildEdit/...: the flag
    value is non-zero, normally ``bad_flag``, which :func:`read_cnv` turns into NaN); ``None`` without one.

    A channel with the same non-zero value on every scan (seen: 222 throughout a binned cast) is not scan
    marking: then only ``bad_flag`` scans count."""
    col = next((c for c in df.columns if str(c).strip().lower() == "flag"), None)
    if col is None:
        return None
    f = pd.to_numeric(df[col], errors="coerce").to_numpy(np.float64)
    fin = np.isfinite(f)
    nonzero = fin & (f != 0)
    if fin.any() and nonzero[fin].all() and np.unique(f[fin]).size == 1:
        return ~fin
    return ~fin | nonzero


# ------------------------------------------------------------------------------ .cnv / .hex dispatch, description
def seabird_kind(path: str | Path) -> str:
    """``'cnv'`` or ``'hex'`` from the content (:func:`hadal.formats.detect`, compressed files included): a .cnv
    has ``# name N =`` header lines, a raw .hex has ``*END*`` followed by lines of hex digits. Anything else is
    an :class:`InputError`."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: Sea-Bird file does not exist")
    kind = {"cnv": "cnv", "seabird_hex": "hex"}.get(detect(path, strict=False).kind)
    if kind is not None:
        return kind
    text = read_bytes(path, "Sea-Bird")[0].decode("latin-1")  # also says when a compressed stream is damaged
    if not any(ln.strip().upper() == "*END*" for ln in text.replace("\r", "\n").split("\n")):
        raise InputError(f"{path}: not a Sea-Bird .cnv or .hex file (no '*END*' line after the header)")
    raise InputError(f"{path}: not a Sea-Bird .cnv or .hex file (no '# name N = ...' channel lines and no "
                     "hex scan lines after '*END*')")


def read_seabird(path: str | Path, *, max_bytes: float | None = None) -> pd.DataFrame:
    """Read a Sea-Bird cast, .cnv or raw .hex, whatever its extension or compression (dispatch on content),
    against the memory budget ``max_bytes`` (the stage's ``resources.max_memory_gb``; default
    :func:`hadal.budget.memory_limit_bytes` of the defaults).

    A .hex is converted by :func:`hadal.ingest.seabird_hex.read_hex` (imported only when needed) into a
    frame shaped like :func:`read_cnv`'s (same column names and attrs)."""
    path = Path(path)
    kind = seabird_kind(path)
    if kind == "cnv":
        return read_cnv(path, max_bytes=max_bytes)
    try:
        from hadal.ingest.seabird_hex import read_hex  # type: ignore[import-not-found]
    except ImportError:
        raise InputError(f"{path}: raw Sea-Bird .hex file, but this hadal has no .hex converter "
                         "(hadal.ingest.seabird_hex); convert it with SeaSoft DatCnv to .cnv") from None
    try:
        df = read_hex(path, max_bytes=max_bytes)
    except InputError:
        raise
    except Exception as exc:  # a converter bug or an unreadable file: one line naming the file
        raise InputError(f"{path}: cannot convert Sea-Bird .hex ({type(exc).__name__}: {exc})") from None
    df.attrs.setdefault("source", str(path))
    df.attrs.setdefault("format", "Sea-Bird raw .hex")
    return df


def describe_cnv(path: str | Path, *, memory_limit_bytes: float | None = None) -> dict[str, Any]:
    """What a Sea-Bird cast holds, for ``hadal inspect`` (JSON-serialisable): format, compression,
    instrument (and serial), channels with units, header position and start time, scans, pressure range,
    binned profile or time series (and the time channel), SeaSoft processing steps, sensors (serial numbers,
    calibration dates). Raises :class:`InputError` like :func:`read_seabird` (read against the memory budget
    ``memory_limit_bytes``)."""
    import warnings as _w

    with _w.catch_warnings(record=True) as caught:
        _w.simplefilter("always")
        df = read_seabird(path, max_bytes=memory_limit_bytes)
    a = df.attrs
    p_col = next((c for c, _ in CNV_PRESSURE if c in df.columns), None)
    prange = None
    if p_col is not None and df[p_col].notna().any():
        prange = [float(df[p_col].min()), float(df[p_col].max())]
    try:
        _, how = cnv_time_ns(df)
        time_base = how
    except InputError:
        time_base = NO_TIME_BASE
    steps: list[str] = []
    for k, _ in a.get("processing") or []:
        mod = k.split("_", 1)[0]
        if mod != "file" and mod not in steps:
            steps.append(mod)
    sensors = [{k: x.get(k) for k in ("channel", "type", "serial_number", "calibration_date", "description")}
               for x in (a.get("sensors_xml") or [])]
    return {
        "path": str(path),
        "kind": "sea-bird-hex" if a.get("format") == "Sea-Bird raw .hex" else "sea-bird-cnv",
        "format": a.get("format"),
        "compression": a.get("compression"),
        "instrument": a.get("instrument"),
        "instrument_serial": a.get("instrument_serial"),
        "channels": [{"column": c["column"], "long_name": c["long_name"], "units": c["units"]}
                     for c in a.get("channels", [])],
        "latitude_deg": a.get("latitude_deg"),
        "longitude_deg": a.get("longitude_deg"),
        "position_source": a.get("position_source"),
        "start_time_utc": a.get("start_time_utc"),
        "scans": int(len(df)),
        "scans_declared": a.get("nvalues_declared"),
        "truncated": a.get("truncated"),
        "pressure_channel": p_col,
        "pressure_range_dbar": prange,
        "binned": bool(a.get("binned")),
        "interval": a.get("interval"),
        "time_base": time_base,
        "profile": time_base == NO_TIME_BASE,
        "processing_steps": steps,
        "sensors": sensors,
        "channel_latitude_deg": a.get("channel_latitude_deg") or {},
        "warnings": [str(w.message) for w in caught],
    }
