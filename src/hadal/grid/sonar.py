"""Multibeam soundings as users have them: dispatch by content, stream in chunks, one-line errors.

Public API (pure functions, no global state):

* :func:`iter_multibeam` - yield the soundings of one file as DataFrame chunks (``chunk_points`` rows at most
  for text, whole pings for swath formats), columns ``longitude_deg, latitude_deg, depth_m`` (geographic) or
  ``x_m, y_m, depth_m`` (projected text soundings); depth is positive down, metres;
* :func:`read_multibeam` - the same as one DataFrame, with ``attrs`` saying which reader (and version) read it,
  the detected format and the counts (pings, beams per ping, soundings, dropped);
* :func:`describe_multibeam` - a JSON-serialisable summary (format, reader, pings, beams, extent, depth range,
  time span) for ``hadal inspect``;
* :func:`sniff_multibeam` - the format (``xyz``, ``gsf``, ``kmall``, ``em_all``, ``s7k``) and compression
  (``gzip``, ``bz2``, ``xz`` or ``None``) from the file's content (:func:`hadal.formats.detect`), never its name.

Formats (spec each reader follows in brackets):

* xyz text, plain or gzip/bzip2/xz compressed: whitespace-, comma- or semicolon-separated, ``#`` comments, an
  optional header naming the columns; lon/lat or projected x/y (from the header, the declared CRS or the value
  ranges); depth positive down or elevation positive up (declared, from the header name, else from the sign of
  the first chunk's median). Streamed with pandas' chunked C parser (``bench/bench_soundings_memory.py``
  measures the peak against the decoded float64 points);
* GSF [Leidos GSF 3.x spec] through the maintained ``gsfpy`` bindings of libgsf (:func:`hadal.grid.readers.read_gsf`);
* Kongsberg KMALL [Kongsberg doc. 410224 "EM datagrams on *.kmall format", rev F-I]: the file is walked datagram
  by datagram here (length prefix, ``#XXX`` identifier, length repeated at the end, partitions joined) and each
  ``#MRZ`` datagram is decoded by ``pykmall`` (module ``KMALL``); a sounding's position is the ping's
  (``pingInfo.latitude_deg/longitude_deg``) plus its ``x_reRefPoint_m`` (forward) / ``y_reRefPoint_m``
  (starboard) rotated by ``headingVessel_deg`` (WGS84 geodesic); depth = ``z_reRefPoint_m -
  z_waterLevelReRefPoint_m`` (below the water line, positive down); rejected detections (``detectionType`` 2)
  and no-detection beams (``detectionMethod`` 0) are dropped and counted;
* Kongsberg EM ``.all`` [Kongsberg doc. 850-160692 "EM Series Multibeam echo sounders datagram formats"]:
  a small reader written here (see :func:`_iter_em_all` for why there is no library) of the Depth ``D``
  (0x44), XYZ 88 ``X`` (0x58) and Position ``P`` (0x50) datagrams, either byte order, checksums verified;
* Reson/Teledyne 7k ``.s7k`` [Teledyne RESON "Data Format Definition 7k", DRF v5]: records walked and counted;
  georeferenced soundings read from 7027 raw-detection records that carry the optional bathymetry block; a
  file with none says so in one line.

Every failure (missing, empty, truncated, corrupt, wrong format, no pings) is a one-line
:class:`hadal.errors.InputError` naming the file.

Memory (issue 45): a file's size says little about its soundings (a compressed file of repeated pings, a header's
counts are claims), so every reader is held against one :class:`hadal.budget.DecodeBudget` per file as it decodes
(:class:`SoundingBudget`): the measured cost of its reader (:data:`SOUNDING_READ_COST`: a fixed part plus bytes per
sounding decoded so far, working copies included), plus what a reader holds undecoded (KMALL partitions waiting
for their other parts); past it, a one-line ``InputError`` naming the file and the limit. The limit is the stage's
(``memory_limit_bytes``: ``resources.max_memory_gb`` when set), else the machine's, cgroup's or ``RLIMIT_AS``'s.
"""

from __future__ import annotations

import contextlib
import datetime as _dt
import io
import math
import struct
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from hadal.errors import InputError
from hadal.formats import SWATH_KINDS, decompress_errors, detect, is_text, open_binary

GEO_COLUMNS = ("longitude_deg", "latitude_deg", "depth_m")
PROJ_COLUMNS = ("x_m", "y_m", "depth_m")
DEFAULT_CHUNK_POINTS = 250_000
FORMATS = ("xyz", *SWATH_KINDS)

_HEAD_BYTES = 65536

#: Peak memory of reading one multibeam file, per reader: ``(fixed bytes, bytes per sounding)``, working copies
#: included (the reader's decoded pings, its consumer's accumulated columns and final block; EM .all keeps every ping
#: until the navigation is known; GSF's parent reads the child's Parquet one row group at a time). Measured with
#: ``bench/bench_soundings_memory.py --points 1250000,5000000`` (files made of a real file's pings, gzip; a fresh
#: interpreter per read, ``VmHWM`` above the after-imports ``VmHWM``; the slope between the two sizes, the intercept
#: at the larger), the larger of the DTM stage's read (:func:`hadal.grid.soundings.read_soundings_xy`) and
#: :func:`read_multibeam`; slope x 1.1 rounded up to a byte, intercept x 1.1 rounded up to 8 MiB. Measured (B per
#: sounding, fixed MB): xyz 29.9, 77; s7k 34.4, 93; EM .all 52.0, 83; KMALL 40.0, 147; GSF 43.6, 122; the GSF child
#: (``gsf_child``: the libgsf child process of :func:`hadal.grid.readers.read_gsf`, which holds its own budget and
#: writes its soundings a row group at a time; it counts them at the parent's cost, which they will need) 10.2, 69.
#: Counted before: 84 B a sounding for every reader; GSF 99
#: (92.0 measured) and its child 97 (87.8) while the parent loaded the child's whole table and the child its own.
SOUNDING_READ_COST: dict[str, tuple[float, float]] = {
    "xyz": (88 << 20, 33.0), "s7k": (104 << 20, 38.0), "em_all": (88 << 20, 58.0), "kmall": (160 << 20, 44.0),
    "gsf": (136 << 20, 48.0), "gsf_child": (80 << 20, 12.0),
}
#: bytes one sounding kept from earlier files holds while the next file is read: x, y, depth as float64 in the
#: consumer's :class:`ColumnAccumulator` (counted, not measured: 3 x 8 bytes)
HELD_SOUNDING_BYTES = 24


class SoundingBudget:
    """The memory budget of one multibeam read (:class:`hadal.budget.DecodeBudget`): the measured cost of its reader
    (:data:`SOUNDING_READ_COST`: fixed + soundings decoded so far x bytes per sounding), the ``held_soundings`` a
    caller already keeps from earlier files (x :data:`HELD_SOUNDING_BYTES`) and undecoded bytes a reader holds;
    refused in one line naming the file. ``limit_bytes``: the stage's budget (``resources.max_memory_gb``, see
    :func:`hadal.budget.memory_limit_bytes`); default the machine's, cgroup's or ``RLIMIT_AS``'s."""

    def __init__(self, p: Path, what: str, held_soundings: int = 0, *, reader: str = "xyz",
                 limit_bytes: float | None = None):
        from hadal.budget import DecodeBudget

        self.fixed, self.per_sounding = SOUNDING_READ_COST[reader]
        self.budget = DecodeBudget(p, what, limit_bytes=limit_bytes)
        self.held = int(held_soundings)
        self.n = 0

    @property
    def limit(self) -> float:
        """The limit (bytes) this budget holds the read against."""
        return self.budget.limit

    def add(self, soundings: int, pending_bytes: float = 0.0) -> None:
        """Count ``soundings`` more decoded; ``pending_bytes``: raw bytes the reader holds besides them."""
        self.n += int(soundings)
        more = f", {pending_bytes:,.0f} bytes of datagrams pending" if pending_bytes else ""
        before = f", {self.held:,} kept from earlier files" if self.held else ""
        self.budget.hold(self.fixed + self.n * self.per_sounding + self.held * HELD_SOUNDING_BYTES + pending_bytes,
                         f"{self.n:,} soundings so far{before}{more}")


# ------------------------------------------------------------------ hints, opening, sniffing
def _hint(hints, name: str):
    """A hint's value from a :class:`hadal.dive.SourceFile` (or a mapping, or None)."""
    if hints is None:
        return None
    if isinstance(hints, dict):
        return hints.get(name)
    return getattr(hints, name, None)


def _require(path) -> Path:
    p = Path(str(path))
    if not p.is_file():
        raise InputError(f"multibeam file {p} does not exist")
    if p.stat().st_size == 0:
        raise InputError(f"multibeam file {p} is empty")
    return p


@contextlib.contextmanager
def _reading(p: Path, comp: str | None):
    """Binary handle on the decompressed content (:func:`hadal.formats.open_binary`); read failures (truncated
    or corrupt gzip/bz2/xz) are one-line InputErrors (:func:`hadal.formats.decompress_errors`)."""
    with decompress_errors(p, comp), open_binary(p) as fh:
        yield fh


def sniff_multibeam(path) -> dict:
    """``{"format": kind, "compression": None|"gzip"|"bz2"|"xz"}`` from the file's content
    (:func:`hadal.formats.detect`): a swath kind, ``xyz`` for any text (the xyz reader says what is wrong
    with text that is not soundings) or ``unknown``.

    ``format`` is one of :data:`FORMATS` or ``"unknown"``.
    """
    p = _require(path)
    fk = detect(p, strict=False)
    kind = fk.kind if fk.kind in SWATH_KINDS else "xyz" if fk.text else "unknown"
    if fk.compression is not None and kind == "unknown":  # nothing decoded: say why
        with _reading(p, fk.compression) as fh:
            if not fh.read(1):
                raise InputError(f"{p}: compressed ({fk.compression}) file decompresses to nothing")
    return {"format": kind, "compression": fk.compression}


# ------------------------------------------------------------------ public API
def iter_multibeam(path, hints=None, chunk_points: int = DEFAULT_CHUNK_POINTS,
                   info: dict | None = None, *, held_soundings: int = 0,
                   memory_limit_bytes: float | None = None, streamed: bool = False) -> Iterator[pd.DataFrame]:
    """Yield the soundings of ``path`` as DataFrame chunks (depth positive down, metres).

    Columns are ``longitude_deg, latitude_deg, depth_m`` (plus ``ping`` for swath formats), or ``x_m, y_m,
    depth_m`` for projected text soundings. ``hints`` is a :class:`hadal.dive.SourceFile` (``format``,
    ``z_positive``, ``crs``, ``columns``; each defaults to detection). ``info``, when given, is filled with
    the reader's metadata (``reader``, ``format``, ``compression``, ``crs_kind``, counts ...); the counts are
    final once the iterator is exhausted. Text chunks hold at most ``chunk_points`` rows; swath chunks hold
    whole pings (about ``chunk_points`` soundings). The soundings are held against the memory budget as they
    decode (:class:`SoundingBudget`; ``held_soundings``: what the caller already keeps from earlier files;
    ``memory_limit_bytes``: the limit, default :func:`hadal.budget.memory_limit_bytes` of the defaults);
    ``streamed``: the caller keeps no chunk in memory (it writes them to disk), so a reader that yields as it
    decodes (xyz, KMALL, s7k) holds only its current chunk; GSF and EM .all, which decode the whole file first,
    are counted whole either way.
    """
    if chunk_points < 1:
        raise ValueError("chunk_points must be >= 1")
    p = _require(path)
    info = {} if info is None else info
    sn = sniff_multibeam(p)
    fmt = _hint(hints, "format")
    if fmt is not None:
        fmt = {"all": "em_all", "xyz.gz": "xyz", "csv": "xyz", "txt": "xyz"}.get(str(fmt).lower(), str(fmt).lower())
        if fmt not in FORMATS:
            raise InputError(f"{p}: format {fmt!r} is not a multibeam format (use one of {', '.join(FORMATS)})")
        if sn["format"] not in (fmt, "unknown") and not (fmt == "xyz" and sn["format"] != "unknown"):
            raise InputError(f"{p}: declared format {fmt!r} but the content is {sn['format']!r}")
    else:
        fmt = sn["format"]
    info.update({"path": str(p), "format": fmt, "compression": sn["compression"]})
    if fmt == "unknown":
        raise InputError(f"{p}: cannot parse soundings (binary content that is not GSF, KMALL, EM .all or .s7k)")
    budget = SoundingBudget(p, "multibeam file" if fmt == "xyz" else f"{fmt} multibeam file", held_soundings,
                            reader=fmt, limit_bytes=memory_limit_bytes)
    if fmt == "xyz":
        gen = _iter_xyz(p, sn["compression"], hints, chunk_points, info)
    elif fmt == "gsf":
        gen = _iter_gsf(p, sn["compression"], chunk_points, info, budget)
    elif fmt == "kmall":
        gen = _iter_kmall(p, sn["compression"], chunk_points, info, budget)
    elif fmt == "em_all":
        gen = _iter_em_all(p, sn["compression"], chunk_points, info, budget)
    else:
        gen = _iter_s7k(p, sn["compression"], chunk_points, info)
    counted = fmt in ("gsf", "em_all")  # these count their soundings as they decode them
    for chunk in gen:
        if not counted:
            budget.add(len(chunk))
            if streamed:
                budget.n = 0
        yield chunk


def read_multibeam(path, hints=None, *, memory_limit_bytes: float | None = None) -> pd.DataFrame:
    """All soundings of ``path`` as one DataFrame (see :func:`iter_multibeam`, ``memory_limit_bytes`` its memory
    budget), ``attrs`` = the reader's info.

    Chunks are gathered by :class:`ColumnAccumulator`, so the peak is about 1x the decoded points plus one
    segment and one parser chunk (``bench/bench_soundings_memory.py``).
    """
    info: dict = {}
    acc: ColumnAccumulator | None = None
    fcols: list[str] = []
    other: dict[str, list[np.ndarray]] = {}
    for ch in iter_multibeam(path, hints, info=info, memory_limit_bytes=memory_limit_bytes):
        if acc is None:
            fcols = [c for c in ch.columns if ch[c].dtype.kind == "f"]
            other = {c: [] for c in ch.columns if c not in fcols}
            acc = ColumnAccumulator(len(fcols))
        acc.add(*(ch[c].to_numpy() for c in fcols))
        for c in other:
            other[c].append(ch[c].to_numpy())
        del ch
    if acc is None or acc.n == 0:
        raise InputError(f"{Path(str(path))}: no soundings")
    df = pd.DataFrame(acc.finish().T, columns=fcols, copy=False)
    for c in list(other):
        df[c] = np.concatenate(other.pop(c))
    df.attrs.update(info)
    return df


class ColumnAccumulator:
    """Collects float64 columns chunk by chunk into one ``(ncols, n)`` block with a peak of about 1x the data.

    Chunks are copied into fixed segments of ``segment_points`` rows (>= 32 MiB each, so the C allocator
    maps them with mmap and really returns them when freed, instead of fragmenting the heap with many small
    chunk arrays); :meth:`finish` copies the segments into the final block one by one, freeing each, and the
    final block's pages become resident only as they are written.
    """

    def __init__(self, ncols: int, segment_points: int = 2_000_000):
        self.ncols, self.seg_n = ncols, max(1, segment_points)
        self.segments: list[np.ndarray] = []
        self.fill = 0  # rows used in the last segment
        self.n = 0

    def add(self, *cols: np.ndarray) -> None:
        m = len(cols[0])
        o = 0
        while o < m:
            if not self.segments or self.fill == self.seg_n:
                self.segments.append(np.empty((self.ncols, self.seg_n), np.float64))
                self.fill = 0
            k = min(m - o, self.seg_n - self.fill)
            seg = self.segments[-1]
            for i, c in enumerate(cols):
                seg[i, self.fill:self.fill + k] = c[o:o + k]
            self.fill += k
            o += k
        self.n += m

    def finish(self) -> np.ndarray:
        """The ``(ncols, n)`` block (the accumulator is emptied)."""
        if len(self.segments) == 1 and self.fill == self.seg_n:
            return self.segments.pop()
        out = np.empty((self.ncols, self.n), np.float64)
        o = 0
        self.segments.reverse()
        while self.segments:
            seg = self.segments.pop()
            k = self.seg_n if self.segments else self.fill
            out[:, o:o + k] = seg[:, :k]
            o += k
            del seg
        return out


def describe_multibeam(path, hints=None, *, memory_limit_bytes: float | None = None) -> dict:
    """JSON-serialisable summary of a multibeam file (streamed; nothing kept but the statistics).

    Keys: ``path, format, compression, reader, crs_kind, soundings, pings, beams_per_ping, dropped,
    longitude_deg``/``latitude_deg`` (or ``x_m``/``y_m``) ``[min, max]``, ``depth_m [min, max]``,
    ``time_start``/``time_end`` (ISO 8601 UTC, swath formats) and the reader's other scalar attributes.
    ``memory_limit_bytes``: the budget of the read (:func:`iter_multibeam`).
    """
    info: dict = {}
    n = 0
    ext: dict[str, list[float]] = {}
    for chunk in iter_multibeam(path, hints, info=info, memory_limit_bytes=memory_limit_bytes):
        n += len(chunk)
        for c in chunk.columns:
            if c == "ping":
                continue
            v = chunk[c].to_numpy()
            v = v[np.isfinite(v)]
            if len(v):
                lo, hi = float(v.min()), float(v.max())
                if c in ext:
                    ext[c] = [min(ext[c][0], lo), max(ext[c][1], hi)]
                else:
                    ext[c] = [lo, hi]
    out: dict[str, Any] = {k: _jsonable(v) for k, v in info.items()}
    out["soundings"] = n
    out.update({k: v for k, v in ext.items()})
    return out


def _jsonable(v):
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (np.floating,)):
        return float(v)
    if isinstance(v, (list, tuple)):
        return [_jsonable(x) for x in v]
    if isinstance(v, dict):
        return {str(k): _jsonable(x) for k, x in v.items()}
    if v is None or isinstance(v, (str, int, float, bool)):
        return v
    return str(v)


def _iso(t_s: float | None) -> str | None:
    if t_s is None or not math.isfinite(t_s):
        return None
    return _dt.datetime.fromtimestamp(t_s, tz=_dt.UTC).isoformat().replace("+00:00", "Z")


def _georef(lon0, lat0, heading_deg, along_m, across_m):
    """Sounding lon/lat: the ping position plus (along = forward, across = starboard) offsets rotated by the
    heading, on the WGS84 ellipsoid (pyproj ``Geod.fwd``). Arrays broadcast per sounding."""
    from pyproj import Geod

    h = np.radians(np.asarray(heading_deg, np.float64))
    along = np.asarray(along_m, np.float64)
    across = np.asarray(across_m, np.float64)
    east = along * np.sin(h) + across * np.cos(h)
    north = along * np.cos(h) - across * np.sin(h)
    az = np.degrees(np.arctan2(east, north))
    dist = np.hypot(east, north)
    lon0, lat0, az, dist = np.broadcast_arrays(np.asarray(lon0, np.float64), np.asarray(lat0, np.float64), az, dist)
    lo, la, _ = Geod(ellps="WGS84").fwd(lon0.ravel(), lat0.ravel(), az.ravel(), dist.ravel())
    lo = np.asarray(lo)
    lo = np.where(lo > 180, lo - 360, np.where(lo < -180, lo + 360, lo))
    return lo, np.asarray(la)


class _PingBatcher:
    """Collects per-ping arrays and emits DataFrames of about ``chunk_points`` soundings."""

    def __init__(self, chunk_points: int):
        self.n = chunk_points
        self.parts: list[tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = []
        self.size = 0

    def add(self, lon, lat, dep, ping: int) -> pd.DataFrame | None:
        self.parts.append((lon, lat, dep, np.full(len(dep), ping, np.int32)))
        self.size += len(dep)
        return self.flush() if self.size >= self.n else None

    def rest(self) -> Iterator[pd.DataFrame]:
        """The last, partial chunk (if any)."""
        out = self.flush()
        if out is not None:
            yield out

    def flush(self) -> pd.DataFrame | None:
        if not self.parts:
            return None
        lon, lat, dep, ping = (np.concatenate(x) for x in zip(*self.parts, strict=True))
        self.parts, self.size = [], 0
        return pd.DataFrame({"longitude_deg": lon, "latitude_deg": lat, "depth_m": dep, "ping": ping}, copy=False)


# ------------------------------------------------------------------ xyz text
_LON = {"lon", "long", "longitude", "longitude_deg", "lon_deg", "longitude_degrees", "lng"}
_LAT = {"lat", "latitude", "latitude_deg", "lat_deg", "latitude_degrees"}
_EAST = {"easting", "east", "x_m", "e", "easting_m", "x_east_m"}
_NORTH = {"northing", "north", "y_m", "n", "northing_m", "y_north_m"}
_X = {"x"} | _LON | _EAST
_Y = {"y"} | _LAT | _NORTH
_DEPTH = {"depth", "depth_m", "d", "depth_meters", "depth_metres", "bathy_depth"}
_ELEV = {"elevation", "elev", "elevation_m", "height", "height_m", "h", "topo", "altitude", "z_up", "bathymetry"}
_Z = {"z", "z_m", "value"} | _DEPTH | _ELEV


def _norm(name: str) -> str:
    return name.strip().strip('"\'').lower().replace(" ", "_").replace("(m)", "m").replace("[m]", "m").strip("_")


def _map_columns(names: list[str]) -> tuple[int, int, int] | None:
    """Indices of x, y, z in ``names`` (normalised), or None when they are not all recognised."""
    n = [_norm(x) for x in names]
    try:
        ix = next(i for i, v in enumerate(n) if v in _X)
        iy = next(i for i, v in enumerate(n) if v in _Y)
        iz = next(i for i, v in enumerate(n) if v in _Z and i not in (ix, iy))
    except StopIteration:
        return None
    return ix, iy, iz


def _crs_kind_from_hint(crs: str | None) -> str | None:
    if crs is None:
        return None
    c = str(crs).strip()
    if c.lower() in ("local", "local_metric"):
        return "projected"
    try:
        from pyproj import CRS

        return "geographic" if CRS.from_user_input(c).is_geographic else "projected"
    except Exception:  # noqa: BLE001 - pyproj raises CRSError and others
        raise InputError(f"crs {c!r} is not a CRS pyproj understands (use e.g. 'EPSG:4326', 'EPSG:32654' or 'local')") from None


class _Reader(io.RawIOBase):
    """Serves ``head`` then the rest of ``inner``; keeps the last 8 KiB read (to check the last line)."""

    def __init__(self, head: bytes, inner):
        self.head, self.inner, self.tail = head, inner, b""

    def readable(self) -> bool:
        return True

    def readinto(self, b) -> int:
        if self.head:
            n = min(len(b), len(self.head))
            b[:n] = self.head[:n]
            self.head = self.head[n:]
        else:
            n = self.inner.readinto(b) or 0
        if n:
            self.tail = (self.tail + bytes(b[:n]))[-8192:]
        return n


def _tokens(line: str, sep: str) -> list[str]:
    return [t for t in (line.split(sep) if sep != "ws" else line.split()) if t.strip() != ""]


def _not_number(tok: str) -> bool:
    try:
        float(tok)
    except ValueError:
        return True
    return False


def _xyz_head(raw) -> tuple[bytes, list[str], int | None]:
    """The first decoded bytes of an xyz stream, read ``_HEAD_BYTES`` at a time (at most about 17 x
    ``_HEAD_BYTES``) until they hold the first data line: ``(head, complete lines of head, index of the first
    data line or None)``; comment lines start with ``#`` or ``%``."""
    head = raw.read(_HEAD_BYTES)
    while True:  # make sure the head holds the first data line
        text = head.decode("utf-8", errors="replace")
        lines = text.split("\n")
        complete = lines if len(head) < _HEAD_BYTES else lines[:-1]
        first_i = next((i for i, ln in enumerate(complete)
                        if (t := ln.strip()) and not t.startswith(("#", "%"))), None)
        if first_i is not None or len(head) % _HEAD_BYTES or len(head) > 16 * _HEAD_BYTES:
            break
        more = raw.read(_HEAD_BYTES)
        if not more:
            break
        head += more
    return head, complete, first_i


def _xyz_layout(complete: list[str], first_i: int) -> tuple[str, bool, list[str] | None, int, int]:
    """``(separator, has_header, header_names, first_sounding_line_index, n_columns)`` of an xyz text from its
    first data line ``complete[first_i]``: the separator is ``","``, ``";"`` or ``"ws"`` (whitespace); a first
    line with a non-numeric token is a header, and the column count is then that of the next data line."""
    first = complete[first_i].strip()
    sep = "," if "," in first else (";" if ";" in first else "ws")
    toks = _tokens(first, sep)
    header = any(_not_number(t) for t in toks)
    names = [t.strip() for t in toks] if header else None
    data_i = first_i + 1 if header else first_i
    if header:  # the first data line (for the column count)
        nxt = next((ln.strip() for ln in complete[data_i:] if (t := ln.strip()) and not t.startswith(("#", "%"))), None)
        ncols = len(_tokens(nxt, sep)) if nxt else len(toks)
    else:
        ncols = len(toks)
    return sep, header, names, data_i, ncols


def _xyz_columns(p: Path, hints, header: bool, names: list[str] | None,
                 ncols: int) -> tuple[tuple[int, int, int], list[str] | None, int]:
    """``(x/y/z column indices, normalised column names or None, columns needed)`` from the declared
    ``columns`` hint, else the header, else the first three columns; InputError when they do not fit."""
    declared = _hint(hints, "columns")
    if declared:
        idx = _map_columns(list(declared))
        if idx is None:
            raise InputError(f"{p}: declared columns {list(declared)} must name x/lon, y/lat and z/depth/elevation")
        col_names = [_norm(x) for x in declared]
    elif header and (idx := _map_columns(names)) is not None:
        col_names = [_norm(x) for x in names]
    else:
        idx, col_names = (0, 1, 2), None
    need = max(idx) + 1
    if ncols < need:
        raise InputError(f"{p}: expected {need} columns (x/lon, y/lat, z/depth), found {ncols}")
    return idx, col_names, need


def _xyz_named_conventions(hints, col_names: list[str] | None,
                           idx: tuple[int, int, int]) -> tuple[str | None, str | None, str | None, str | None]:
    """``(crs_kind, crs_from, z_positive, z_positive_from)`` declared in ``hints``, else told by the header's
    column names ("declared" / "header"); None where neither says (then decided from the values)."""
    # horizontal CRS
    crs_kind = _crs_kind_from_hint(_hint(hints, "crs"))
    crs_how = "declared" if crs_kind else None
    if crs_kind is None and col_names is not None:
        xn, yn = col_names[idx[0]], col_names[idx[1]]
        if xn in _LON or yn in _LAT:
            crs_kind, crs_how = "geographic", "header"
        elif xn in _EAST or yn in _NORTH:
            crs_kind, crs_how = "projected", "header"
    # vertical convention
    zpos = _hint(hints, "z_positive")
    z_how = "declared" if zpos else None
    if zpos is None and col_names is not None:
        zn = col_names[idx[2]]
        if zn in _DEPTH:
            zpos, z_how = "down", "header"
        elif zn in _ELEV:
            zpos, z_how = "up", "header"
    return crs_kind, crs_how, zpos, z_how


def _xyz_value_conventions(x: np.ndarray, y: np.ndarray, z: np.ndarray, crs_kind: str | None, crs_how: str | None,
                           zpos: str | None, z_how: str | None) -> tuple[str, str | None, str, str | None]:
    """The CRS kind and z sign still undecided, from the first chunk's values ("values"): lon/lat-like ranges
    are geographic (:func:`_detect_crs_kind`), a negative median z (m) means elevations (positive up)."""
    if crs_kind is None:
        crs_kind, crs_how = _detect_crs_kind(x, y), "values"
    if zpos is None:
        fz = z[np.isfinite(z)]
        zpos = "up" if len(fz) and float(np.median(fz)) < 0 else "down"
        z_how = "values"
    return crs_kind, crs_how, zpos, z_how


def _xyz_csv_chunks(p: Path, buf, sep: str, data_i: int, idx: tuple[int, int, int], chunk_points: int):
    """pandas' chunked C parser over ``buf`` (the x/y/z columns ``idx``, ``chunk_points`` rows a chunk, from
    line ``data_i``); an empty iterator for no data, parse failures are one-line InputErrors."""
    try:
        return pd.read_csv(
            buf, sep=r"\s+" if sep == "ws" else sep, header=None, skiprows=data_i, comment="#",
            usecols=list(idx), chunksize=chunk_points, engine="c", skipinitialspace=sep != "ws",
            encoding="utf-8", encoding_errors="replace", skip_blank_lines=True, low_memory=True,
        )
    except pd.errors.EmptyDataError:
        return iter(())
    except (pd.errors.ParserError, ValueError) as exc:
        raise InputError(f"{p}: cannot parse soundings ({str(exc).splitlines()[0]})") from None


def _next_xyz_chunk(p: Path, chunks) -> pd.DataFrame | None:
    """The next parsed chunk, or None at the end; parse and decode failures are one-line InputErrors."""
    try:
        return next(chunks)
    except StopIteration:
        return None
    except pd.errors.EmptyDataError:
        return None
    except (pd.errors.ParserError, ValueError, UnicodeDecodeError) as exc:
        raise InputError(f"{p}: cannot parse soundings ({str(exc).splitlines()[0]})") from None


def _xyz_float_columns(p: Path, df: pd.DataFrame, idx: tuple[int, int, int], out_cols: tuple[str, ...] | None,
                       rows: int) -> list[np.ndarray]:
    """The x, y, z columns ``idx`` of one parsed chunk as float64 copies (NaN/inf kept); fewer than 3 columns
    or a value that is not a number is an InputError naming the column and its data row (``rows`` before)."""
    if df.shape[1] < 3:
        raise InputError(f"{p}: expected 3 columns (x/lon, y/lat, z/depth), found {df.shape[1]}")
    arrs = []
    tmp_names = ("x", "y", "depth_m")
    for k, (ci, nm) in enumerate(zip(idx, tmp_names, strict=True)):
        s = df[ci]
        if s.dtype.kind not in "fi":
            conv = pd.to_numeric(s, errors="coerce")
            bad = conv.isna() & s.notna() & ~s.astype(str).str.strip().str.lower().isin(
                ("nan", "-nan", "inf", "-inf", "+inf", "na", ""))
            if bad.any():
                i = int(np.flatnonzero(bad.to_numpy())[0])
                shown = nm if k == 2 else (out_cols[k] if out_cols else ("longitude_deg", "latitude_deg")[k])
                raise InputError(f"{p}: non-numeric {shown} {s.iloc[i]!r} on data row {rows + i + 1}")
            s = conv
        arrs.append(s.to_numpy(np.float64, copy=True))
    return arrs


def _check_xyz_end(p: Path, rows: int, header: bool, tail: bytes, sep: str, need: int) -> None:
    """InputError for a file without soundings, or whose last data line (in ``tail``, the last bytes read) has
    fewer than ``need`` values (a truncated file)."""
    if rows == 0:
        raise InputError(f"{p}: no soundings (header only)" if header else f"{p}: no soundings")
    last = next((t for ln in reversed(tail.decode("utf-8", errors="replace").split("\n"))
                 if (t := ln.strip()) and not t.startswith(("#", "%"))), None)
    if last is not None and len(_tokens(last, sep)) < need:
        raise InputError(f"{p}: last line {last[:60]!r} has fewer than {need} values (truncated file?)")


def _iter_xyz(p: Path, comp: str | None, hints, chunk_points: int, info: dict, *,
              check_ranges: bool = True) -> Iterator[pd.DataFrame]:
    """Stream an xyz text file (see the module docstring). Rows with NaN/inf are kept (the gridder counts
    them); a short last line (truncated file), non-numeric values, out-of-range lon/lat are InputErrors."""
    info.update({"reader": "hadal xyz", "format": "xyz", "pings": None, "beams_per_ping": None, "dropped": 0})
    with _reading(p, comp) as raw:
        head, complete, first_i = _xyz_head(raw)
        if not is_text(head):
            raise InputError(f"{p}: cannot parse soundings (binary content, not xyz text)")
        if first_i is None:
            raise InputError(f"{p}: no soundings (file has no data lines)")
        sep, header, names, data_i, ncols = _xyz_layout(complete, first_i)
        idx, col_names, need = _xyz_columns(p, hints, header, names, ncols)
        crs_kind, crs_how, zpos, z_how = _xyz_named_conventions(hints, col_names, idx)
        info.update({"header": names, "separator": {"ws": "whitespace"}.get(sep, sep), "columns_used": list(idx)})
        reader = _Reader(head, raw)
        buf = io.BufferedReader(reader, 1 << 20)
        chunks = _xyz_csv_chunks(p, buf, sep, data_i, idx, chunk_points)
        rows = 0
        out_cols = None
        while (df := _next_xyz_chunk(p, chunks)) is not None:
            arrs = _xyz_float_columns(p, df, idx, out_cols, rows)
            del df
            x, y, z = arrs
            if out_cols is None:  # first chunk: decide CRS kind and z sign
                crs_kind, crs_how, zpos, z_how = _xyz_value_conventions(x, y, z, crs_kind, crs_how, zpos, z_how)
                out_cols = GEO_COLUMNS if crs_kind == "geographic" else PROJ_COLUMNS
                info.update({"crs_kind": crs_kind, "crs_from": crs_how, "crs": _hint(hints, "crs"),
                             "z_positive": zpos, "z_positive_from": z_how})
            if crs_kind == "geographic" and check_ranges:
                _check_lonlat(p, x, y)
            if zpos == "up":
                np.negative(z, out=z)
            rows += len(z)
            info["soundings"] = rows
            chunk = pd.DataFrame({out_cols[0]: x, out_cols[1]: y, "depth_m": z}, copy=False)
            del x, y, z, arrs
            yield chunk
        buf.close()
    _check_xyz_end(p, rows, header, reader.tail, sep, need)
    info["soundings"] = rows


def _detect_crs_kind(x: np.ndarray, y: np.ndarray) -> str:
    """'geographic' when the values fit lon/lat, else 'projected' (metres); lat/lon swapped is refused."""
    fx, fy = x[np.isfinite(x)], y[np.isfinite(y)]
    if not len(fx) or not len(fy):
        return "geographic"
    xmin, xmax, aymax = fx.min(), fx.max(), np.abs(fy).max()
    if xmin >= -180 and xmax <= 360 and aymax <= 90:
        return "geographic"
    if xmin >= -180 and xmax <= 360 and aymax <= 360:
        return "geographic"  # lon/lat-like values with |lat| > 90: swapped columns, refused by the range check
    return "projected"


def _check_lonlat(p: Path, lon: np.ndarray, lat: np.ndarray) -> None:
    with np.errstate(invalid="ignore"):
        if np.any(np.abs(lat) > 90):
            raise InputError(f"{p}: latitude out of [-90, 90] (max |lat| {np.nanmax(np.abs(lat)):g}); columns must "
                             "be longitude latitude depth (or name them in a header / declare crs in dive.yaml)")
        if np.any((lon < -180) | (lon > 360)):
            raise InputError(f"{p}: longitude out of [-180, 360] ({np.nanmin(lon):g}..{np.nanmax(lon):g})")


# ------------------------------------------------------------------ GSF
#: free space left in the temporary directory when a compressed GSF is decompressed there (bytes)
_GSF_TMP_RESERVE = 1 << 30


def _iter_gsf(p: Path, comp: str | None, chunk_points: int, info: dict,
              budget: SoundingBudget | None = None) -> Iterator[pd.DataFrame]:
    """GSF via :func:`hadal.grid.readers.iter_gsf` (libgsf in a child process; gsfpy/libgsf needs a real file:
    compressed GSF is decompressed to a temporary file first, refused in one line before it would leave less than
    :data:`_GSF_TMP_RESERVE` free there), its row groups of ``chunk_points`` soundings yielded as they are read.
    ``budget``: the child process holds its soundings against its own budget as it decodes; this process counts
    them (from the child's attributes) before reading the first row group."""
    from hadal.grid.readers import iter_gsf

    def chunks(src: Path) -> Iterator[pd.DataFrame]:
        for i, ch in enumerate(iter_gsf(src, budget=budget, chunk_points=chunk_points)):
            if i == 0:  # the reader's attributes, before the first chunk reaches the caller
                info.update({k: v for k, v in ch.attrs.items() if k != "path"})
                info.update({"format": "gsf", "compression": comp, "crs_kind": "geographic", "z_positive": "down"})
            yield ch

    if comp is None:
        yield from chunks(p)
    else:
        import shutil
        import tempfile

        with tempfile.TemporaryDirectory(prefix="hadal-gsf-") as td:
            tmp = Path(td) / (p.stem + ".gsf")
            room = shutil.disk_usage(td).free - _GSF_TMP_RESERVE
            with _reading(p, comp) as src, open(tmp, "wb") as dst:
                written = 0
                while block := src.read(1 << 20):
                    written += len(block)
                    if written > room:  # a compressed file's size says nothing of what it decompresses to
                        from hadal.budget import format_bytes

                        raise InputError(f"{p}: decompressing this {comp} GSF file needs more than "
                                         f"{format_bytes(written)} of free space in {Path(td).parent} (GSF is read "
                                         f"from a plain file; {format_bytes(_GSF_TMP_RESERVE)} are kept free): "
                                         "decompress it where there is room, or set TMPDIR")
                    dst.write(block)
            try:
                yield from chunks(tmp)
            except InputError as exc:
                raise InputError(str(exc).replace(str(tmp), str(p))) from None


# ------------------------------------------------------------------ KMALL (pykmall)
def _read_exact(fh, n: int) -> bytes:
    b = fh.read(n)
    return b if b is not None else b""


def _read_lead(fh, n: int, p: Path, ext: str, partial: str) -> bytes:
    """The ``n``-byte lead (length, record frame) of the next record: ``b""`` at a clean end of the file; a partial
    one is a ``truncated <ext> file (<partial>)`` InputError (``{got}`` in ``partial``: the bytes read)."""
    lead = _read_exact(fh, n)
    if 0 < len(lead) < n:
        raise InputError(f"{p}: truncated {ext} file ({partial.format(got=len(lead))})")
    return lead


def _datagrams(p: Path, fh, ext: str, order_of, limits: tuple[int, int], *,
               length_counts_itself: bool) -> Iterator[tuple[int, int, bytes, bytes]]:
    """Walk length-prefixed datagrams (Kongsberg .kmall / .all): yield ``(k, offset, lead, body)`` with the
    u32 length ``lead`` and the ``body`` after it. ``order_of(lead)`` gives the byte order (``<``/``>``);
    the length is within ``limits`` and counts its own 4 bytes when ``length_counts_itself`` (.kmall).
    A partial length or body is a ``truncated .ext`` InputError, a length out of limits ``corrupt .ext``."""
    off = k = 0
    while True:
        lead = _read_lead(fh, 4, p, ext, f"{{got}} stray bytes at byte {off}")
        if not lead:
            return
        n = struct.unpack(order_of(lead) + "I", lead)[0]
        if n < limits[0] or n > limits[1]:
            raise InputError(f"{p}: corrupt {ext} file (datagram {k} at byte {off} declares {n} bytes)")
        want = n - 4 if length_counts_itself else n
        body = _read_exact(fh, want)
        if len(body) < want:
            raise InputError(f"{p}: truncated {ext} file (datagram {k} at byte {off} declares {n} bytes, "
                             f"{len(body) + n - want} remain)")
        yield k, off, lead, body
        off += 4 + want
        k += 1


def _iter_kmall(p: Path, comp: str | None, chunk_points: int, info: dict,
                budget: SoundingBudget | None = None) -> Iterator[pd.DataFrame]:
    """Kongsberg KMALL: datagrams walked here, ``#MRZ`` decoded by pykmall (see the module docstring). Partitions
    of a datagram waiting for their other parts are held against ``budget`` (a file of partitions that never
    complete, or one datagram split into 65,535 parts, would otherwise grow without bound)."""
    try:
        import importlib.metadata as md

        import KMALL
        ver = md.version("pykmall")
    except ImportError:
        raise InputError(f"{p}: reading .kmall needs the pykmall package (pip install pykmall)") from None
    info.update({"reader": f"pykmall {ver}", "format": "kmall", "crs_kind": "geographic", "z_positive": "down"})
    types: Counter = Counter()
    batch = _PingBatcher(chunk_points)
    pings: list[int] = []
    beams_max = 0
    n_soundings = dropped = 0
    t0 = t1 = None
    pending: dict[int, list[bytes]] = {}
    track: list[tuple[float, float]] = []
    with _reading(p, comp) as fh:
        for _k, off, lead, body in _datagrams(p, fh, ".kmall", lambda _lead: "<", (24, 1 << 26),
                                              length_counts_itself=True):
            n = len(body) + 4
            ident = body[:4]
            if ident[:1] != b"#" or not ident[1:].isalpha():
                raise InputError(f"{p}: corrupt .kmall file (no #XXX datagram identifier at byte {off + 4})")
            if struct.unpack("<I", body[-4:])[0] != n:
                raise InputError(f"{p}: corrupt .kmall file (datagram {ident.decode(errors='replace')} at byte {off}: "
                                 "trailing length does not match)")
            types[ident.decode()] += 1
            dgm = lead + body
            if ident in (b"#MRZ",):
                # EMdgmMpartition follows the 20-byte header: u16 numOfDgms, u16 dgmNum
                num, part = struct.unpack_from("<HH", dgm, 20)
                if num > 1:
                    pending.setdefault(struct.unpack_from("<Q", dgm, 12)[0], []).append(dgm)
                    parts = pending[struct.unpack_from("<Q", dgm, 12)[0]]
                    if len(parts) < num:
                        if budget is not None:
                            budget.add(0, 2.0 * sum(len(d) for ps in pending.values() for d in ps))  # + the join
                        continue
                    dgm = _join_partitions(parts)
                    pending.pop(struct.unpack_from("<Q", parts[0], 12)[0], None)
                res = _decode_mrz(p, KMALL, dgm, off)
                if res is not None:
                    lon, lat, dep, nb, ping_cnt, t, pos = res
                    track.append(pos)
                    beams_max = max(beams_max, nb)
                    pings.append(ping_cnt)
                    dropped += nb - len(dep)
                    n_soundings += len(dep)
                    t0 = t if t0 is None else min(t0, t)
                    t1 = t if t1 is None else max(t1, t)
                    out = batch.add(lon, lat, dep, len(pings) - 1)
                    if out is not None:
                        yield out
    if not types:
        raise InputError(f"{p}: no datagrams in the .kmall file")
    if not pings:
        listed = ", ".join(f"{t} x{c}" for t, c in types.items())
        raise InputError(f"{p}: .kmall file contains no bathymetry pings (no #MRZ datagrams; has {listed})")
    info.update({"pings": len(set(pings)), "swaths": len(pings), "beams_per_ping": beams_max,
                 "soundings": n_soundings, "dropped": dropped, "datagrams": dict(types),
                 "track_start": list(track[0]), "track_end": list(track[-1]),
                 "time_start": _iso(t0), "time_end": _iso(t1)})
    if n_soundings == 0:
        raise InputError(f"{p}: .kmall file has {len(pings)} pings but no valid soundings")
    yield from batch.rest()


def _join_partitions(parts: list[bytes]) -> bytes:
    """Rejoin a partitioned KMALL datagram: header + partition {1, 1} + every partition's body, length fixed."""
    parts = sorted(parts, key=lambda d: struct.unpack_from("<H", d, 22)[0])
    bodies = b"".join(d[24:-4] for d in parts)
    head = bytearray(parts[0][:24])
    struct.pack_into("<HH", head, 20, 1, 1)
    n = len(head) + len(bodies) + 4
    struct.pack_into("<I", head, 0, n)
    return bytes(head) + bodies + struct.pack("<I", n)


def _decode_mrz(p: Path, KMALL, dgm: bytes, off: int):
    """(lon, lat, depth, n_beams, ping_counter, time_s) of one #MRZ datagram decoded by pykmall."""
    km = KMALL.kmall(None)
    km.FID = io.BytesIO(dgm)
    km.file_size = len(dgm)
    try:
        with contextlib.redirect_stdout(io.StringIO()):
            dg = km.read_EMdgmMRZ()
    except Exception as exc:  # noqa: BLE001 - pykmall raises struct.error, KeyError, IndexError ...
        raise InputError(f"{p}: corrupt #MRZ datagram at byte {off} ({type(exc).__name__}: "
                         f"{str(exc).splitlines()[0] if str(exc) else ''})") from None
    pi, s = dg["pingInfo"], dg["sounding"]
    nb = len(s.get("z_reRefPoint_m", []))
    if nb == 0:
        return None
    z = np.asarray(s["z_reRefPoint_m"], np.float64)
    x = np.asarray(s["x_reRefPoint_m"], np.float64)
    y = np.asarray(s["y_reRefPoint_m"], np.float64)
    det_type = np.asarray(s["detectionType"])
    det_meth = np.asarray(s["detectionMethod"])
    lat0, lon0 = float(pi["latitude_deg"]), float(pi["longitude_deg"])
    if not (abs(lat0) <= 90 and abs(lon0) <= 360):
        raise InputError(f"{p}: #MRZ datagram at byte {off} has no valid position (lat {lat0:g}, lon {lon0:g})")
    keep = (det_type != 2) & (det_meth != 0) & np.isfinite(z) & np.isfinite(x) & np.isfinite(y)
    dep = z - float(pi["z_waterLevelReRefPoint_m"])
    lon, lat = _georef(lon0, lat0, float(pi["headingVessel_deg"]), x[keep], y[keep])
    return (lon, lat, dep[keep], nb, int(dg["cmnPart"]["pingCnt"]), float(dg["header"]["dgtime"]),
            (lon0 if lon0 <= 180 else lon0 - 360, lat0))


# ------------------------------------------------------------------ Kongsberg EM .all
_EM_SIGNED_DEPTH_EXCEPT = (120, 300)  # Depth datagram: z is unsigned for EM 120 / EM 300, signed otherwise
_EM_INVALID_INT = 0x7FFFFFFF
#: EM model numbers of ``.all`` datagrams (MB-System mbsys_simrad2.h / mbsys_simrad3.h, the models its
#: mbr_em300raw / mbr_em710raw readers accept; 3001-3008 are EM 3000D heads, 3020 is the EM 3002)
EM_ALL_MODELS: dict[int, str] = {
    120: "EM 120", 122: "EM 122", 124: "EM 124", 300: "EM 300", 302: "EM 302", 304: "EM 304", 710: "EM 710",
    712: "EM 712", 850: "ME 70/EM 850", 1002: "EM 1002", 2000: "EM 2000", 2040: "EM 2040", 2045: "EM 2040C",
    3000: "EM 3000", **{3000 + h: f"EM 3000D head {h}" for h in range(1, 9)}, 3020: "EM 3002",
    30: "M3"}


def em_all_byte_order(p: Path, head: bytes) -> str:
    """Byte order (``<``/``>``) of a Kongsberg ``.all`` file from its first datagram's own fields: u32 length,
    STX 0x02, type, u16 EM model. The model number names the order: it is a known EM model
    (:data:`EM_ALL_MODELS`) read one way only (MB-System ``mbr_em300raw_rd_data`` decides the same way). A
    model known in neither order is a one-line InputError naming the number; should a number be known both ways,
    the length that fits decides."""
    if len(head) < 8:
        raise InputError(f"{p}: truncated .all file ({len(head)} bytes)")
    if head[4] != 0x02:
        raise InputError(f"{p}: not a Kongsberg .all file (no STX 0x02 after the first datagram length)")
    m_le, m_be = struct.unpack("<H", head[6:8])[0], struct.unpack(">H", head[6:8])[0]
    le_ok, be_ok = m_le in EM_ALL_MODELS, m_be in EM_ALL_MODELS
    if le_ok != be_ok:
        return "<" if le_ok else ">"
    if le_ok:  # a number valid both ways (none of today's models): the length within bounds decides
        return "<" if 16 <= struct.unpack("<I", head[:4])[0] <= (1 << 24) else ">"
    raise InputError(f"{p}: Kongsberg .all datagram of an unknown EM model number {m_le} (little-endian; "
                     f"{m_be} big-endian): not one of {', '.join(str(m) for m in sorted(EM_ALL_MODELS))}")


def _em_time(date: int, ms: int) -> float:
    """EM date (yyyymmdd) + milliseconds since midnight -> POSIX seconds (UTC)."""
    y, m, d = date // 10000, (date // 100) % 100, date % 100
    try:
        base = _dt.datetime(y, m, d, tzinfo=_dt.UTC).timestamp()
    except ValueError:
        return float("nan")
    return base + ms / 1000.0


def _iter_em_all(p: Path, comp: str | None, chunk_points: int, info: dict,
                 budget: SoundingBudget | None = None) -> Iterator[pd.DataFrame]:
    """Kongsberg EM ``.all`` soundings from Depth (0x44) or XYZ 88 (0x58) and Position (0x50) datagrams.

    Why not a library: no maintained Python reader of ``.all`` exists on PyPI (``pyall`` there is an unrelated
    package; the Kongsberg reader of that name was never published, and pykmall reads only ``.kmall``);
    MB-System (C, GPL) is not a Python dependency. This reader follows Kongsberg's "EM Series datagram
    formats" (850-160692) and was checked against MB-System's ``mbr_em300raw.c`` / ``mbr_em710raw.c``:

    * every datagram: u32 byte count (excluding itself), STX 0x02, u8 type, u16 EM model, u32 date yyyymmdd,
      u32 ms since midnight, u16 counter, u16 serial, ..., ETX 0x03, u16 checksum = sum of the bytes between
      STX and ETX. The byte order (little- or big-endian) is the one in which the first datagram's model number
      is a known EM model (:func:`em_all_byte_order`; an unknown model is refused naming its number);
      checksums of the datagrams read are verified (a mismatch is a corrupt file);
    * Position ``P``: i32 latitude (deg * 2e7), i32 longitude (deg * 1e7), u16 fix quality (cm), u16 speed over
      ground (cm/s), u16 course, u16 heading (0.01 deg), u8 system, u8 n, n bytes input sentence;
    * Depth ``D``: u16 heading (0.01 deg), u16 sound speed (dm/s), u16 transmit transducer depth re water
      level (cm), u8 max beams, u8 N, u8 z resolution (cm), u8 x/y resolution (cm), u16 sampling rate; N beams
      of {depth z (u16 for EM 120/300, else i16), i16 across y, i16 along x, i16 depression, u16 azimuth,
      u16 range, u8 quality, u8 window, i8 reflectivity, u8 beam number}; i8 transducer-depth offset
      multiplier (x 65536 cm). Depth below the water line = z * zres + transducer depth; z = 0 is no detection.
      Model differences (MB-System ``mbr_em300raw_rd_bath``): z unsigned for EM 120/300; the offset multiplier
      ignored for EM 3000-family (model >= 3000: EM3000, EM3000D heads 3001-3008, EM3002) processors older than
      software 2.0.0 (``PSV=`` of the installation datagram ``I``); a Depth datagram with more beams than its
      maximum or beam numbers out of order is a broken record, dropped and counted (``depth_datagrams_broken``);
      EM3000D/EM3002 heads come as separate Depth datagrams (each positioned on its own);
    * XYZ 88 ``X``: u16 heading, u16 sound speed, f32 transducer depth (m), u16 N, u16 valid, f32 sampling
      rate, u8 scanning info, 3 spare; N beams of {f32 z, f32 y across, f32 x along, u16 window, u8 quality,
      i8 incidence adjustment, u8 detection info (bit 7 = invalid), i8 cleaning, i16 reflectivity}.

    The ping position is interpolated linearly in time between Position fixes; before the first or after the
    last fix it is dead-reckoned from that fix along the ping heading at the fix's speed over ground (as
    MB-System's ``mb_navint_interp`` does). Beams are then placed with :func:`_georef` (x forward, y starboard).
    Pings are kept (x, y, z per beam, float32) until all positions are known, then emitted in chunks.
    """
    info.update({"reader": "hadal em_all 1", "format": "em_all", "crs_kind": "geographic", "z_positive": "down"})
    types: Counter = Counter()
    fixes: list[tuple[float, float, float, float]] = []  # time, lat, lon, speed m/s
    pings: list[tuple] = []
    model = None
    psv: int | None = None  # processor software version (MB-System's i1*10000 + i2*100 + i3), from PSV=
    broken = 0

    with _reading(p, comp) as raw:
        head = _read_exact(raw, 8)
        order = em_all_byte_order(p, head) if head else "<"
        fh = io.BufferedReader(_Reader(head, raw))
        for k, off, _lead, body in _datagrams(p, fh, ".all", lambda _lead: order, (16, 1 << 24),
                                              length_counts_itself=False):
            if body[0] != 0x02:
                raise InputError(f"{p}: corrupt .all file (no STX at byte {off + 4}, datagram {k})")
            typ = body[1]
            types[chr(typ) if 32 < typ < 127 else hex(typ)] += 1
            if typ == 0x49 and (v := _em_psv_version(body)) is not None:  # installation parameters: PSV=
                psv = v
            if typ in (0x50, 0x44, 0x58):
                if body[-3] != 0x03:
                    raise InputError(f"{p}: corrupt .all file (datagram {chr(typ)} at byte {off} has no ETX)")
                cs = struct.unpack(order + "H", body[-2:])[0]
                if cs != (_byte_sum(body, 1, len(body) - 3) & 0xFFFF):
                    raise InputError(f"{p}: corrupt .all file (checksum mismatch in {chr(typ)} datagram at byte {off})")
                model, date, ms = struct.unpack_from(order + "HII", body, 2)
                if model not in EM_ALL_MODELS:
                    raise InputError(f"{p}: {chr(typ)} datagram at byte {off} of an unknown EM model number {model}")
                t = _em_time(date, ms)
                n_pings = len(pings)
                try:
                    if typ == 0x50:
                        lat_i, lon_i, _q, spd = struct.unpack_from(order + "iiHH", body, 16)
                        if lat_i != _EM_INVALID_INT and lon_i != _EM_INVALID_INT:
                            fixes.append((t, lat_i * 5e-8, lon_i * 1e-7, spd * 0.01 if spd not in (0, 0xFFFF) else np.nan))
                    elif typ == 0x44:
                        ping = _em_depth(body, order, model, t, psv)
                        if ping is None:
                            broken += 1
                        else:
                            pings.append(ping)
                    else:
                        pings.append(_em_xyz88(body, order, t))
                except (struct.error, ValueError):  # ValueError: np.frombuffer past the datagram's end
                    raise InputError(f"{p}: corrupt .all file ({chr(typ)} datagram at byte {off} is too short "
                                     "for its beam count)") from None
                if budget is not None and len(pings) > n_pings:  # every ping is kept until the navigation is known
                    budget.add(len(pings[-1][2]))
    if not types:
        raise InputError(f"{p}: no datagrams in the .all file")
    listed = ", ".join(f"{t} x{c}" for t, c in types.items())
    if not pings and broken:
        raise InputError(f"{p}: .all file has {broken} Depth datagrams, all broken (beam numbers out of order or "
                         "above the maximum)")
    if not pings:
        raise InputError(f"{p}: .all file contains no bathymetry pings (no Depth/XYZ 88 datagrams; has {listed})")
    if not fixes:
        raise InputError(f"{p}: .all file has {len(pings)} pings but no Position datagrams (cannot georeference)")
    fixes.sort()
    ft = np.array([f[0] for f in fixes])
    flat = np.array([f[1] for f in fixes])
    flon = np.unwrap(np.array([f[2] for f in fixes]), period=360.0)
    fspd = np.array([f[3] for f in fixes])
    from pyproj import Geod

    geod = Geod(ellps="WGS84")
    batch = _PingBatcher(chunk_points)
    n_sound = dropped = extrap = 0
    beams_max = 0
    times: list[float] = []
    track: list[tuple[float, float]] = []
    for i, (t, heading, z, y, x, nmax) in enumerate(pings):
        beams_max = max(beams_max, nmax)
        dropped += nmax - len(z)
        times.append(t)
        if len(z) == 0:
            continue
        if ft[0] <= t <= ft[-1] and len(ft) > 1:
            lat0, lon0 = float(np.interp(t, ft, flat)), float(np.interp(t, ft, flon))
        else:
            j = 0 if t < ft[0] else len(ft) - 1
            dd = (t - ft[j]) * _fix_speed(ft, flat, flon, fspd, j)
            lo, la, _ = geod.fwd(flon[j], flat[j], heading if dd >= 0 else heading + 180.0, abs(dd))
            lat0, lon0 = float(la), float(lo)
            extrap += 1
        track.append((lon0 if lon0 <= 180 else lon0 - 360, lat0))
        lon, lat = _georef(lon0, lat0, heading, x, y)
        n_sound += len(z)
        out = batch.add(lon, lat, z.astype(np.float64), i)
        if out is not None:
            yield out
    info.update({"pings": len(pings), "beams_per_ping": beams_max, "soundings": n_sound, "dropped": dropped,
                 "byte_order": "little" if order == "<" else "big", "em_model": model,
                 "processor_software": psv, "depth_datagrams_broken": broken,
                 "position_fixes": len(fixes), "pings_extrapolated": extrap, "datagrams": dict(types),
                 "track_start": list(track[0]) if track else None, "track_end": list(track[-1]) if track else None,
                 "time_start": _iso(min(times)), "time_end": _iso(max(times))})
    if n_sound == 0:
        raise InputError(f"{p}: .all file has {len(pings)} pings but no valid soundings")
    yield from batch.rest()


def _fix_speed(ft, flat, flon, fspd, j: int) -> float:
    """Speed over ground (m/s) at fix ``j``: the Position datagram's, else averaged over up to 50 fixes either
    side (MB-System ``mb_navint_interp``); 0 when unknown."""
    if np.isfinite(fspd[j]):
        return float(fspd[j])
    i0, i1 = max(j - 50, 0), min(j + 50, len(ft) - 1)
    if i1 == i0 or ft[i1] <= ft[i0]:
        return 0.0
    from pyproj import Geod

    _, _, d = Geod(ellps="WGS84").inv(flon[i0], flat[i0], flon[i1], flat[i1])
    return float(d) / float(ft[i1] - ft[i0])


def _em_psv_version(body: bytes) -> int | None:
    """The processor software version ``PSV=a.b.c`` of an installation parameters datagram as MB-System's
    ``mbr_em300raw_rd_start`` codes it (``c + 100 b + 10000 a``), or None."""
    import re

    m = re.search(rb"PSV=(\d+)\.(\d+)\.(\d+)", body)
    return int(m.group(3)) + 100 * int(m.group(2)) + 10000 * int(m.group(1)) if m else None


def _em_depth(body: bytes, order: str, model: int, t: float, psv: int | None = None):
    """Depth (0x44) datagram -> (time, heading deg, depth m, across m, along m, max beams), or None for a broken
    record (MB-System ``mbr_em300raw_rd_bath``: more beams than the maximum, beam numbers not increasing or above
    the maximum - "these do happen"). The transducer-depth offset multiplier is ignored for EM 3000-family
    processors older than software 2.0.0 (PSV < 20000, as MB-System), which did not write it."""
    heading, _ssv, tdepth, nmax, nb, zres, xyres, _sr = struct.unpack_from(order + "HHHBBBBH", body, 16)
    beams = np.frombuffer(body, dtype=np.dtype([
        ("z", order + ("u2" if model in _EM_SIGNED_DEPTH_EXCEPT else "i2")), ("y", order + "i2"),
        ("x", order + "i2"), ("depr", order + "i2"), ("az", order + "u2"), ("range", order + "u2"),
        ("q", "u1"), ("win", "u1"), ("refl", "i1"), ("beam", "u1")]), count=nb, offset=28)
    mult = struct.unpack_from("b", body, 28 + 16 * nb)[0]
    if model >= 3000 and psv is not None and 0 < psv < 20000:
        mult = 0
    bn = beams["beam"].astype(np.int64)
    if nb > nmax or (nb and (bn[0] > nmax or np.any(np.diff(bn) < 0) or bn.max() > nmax)):
        return None
    ok = beams["z"] != 0
    depth = beams["z"][ok] * (0.01 * zres) + 0.01 * tdepth + 655.36 * mult
    return (t, 0.01 * heading, depth.astype(np.float32), (beams["y"][ok] * (0.01 * xyres)).astype(np.float32),
            (beams["x"][ok] * (0.01 * xyres)).astype(np.float32), max(int(nmax), int(nb)))


def _em_xyz88(body: bytes, order: str, t: float):
    """XYZ 88 (0x58) datagram -> (time, heading deg, depth m, across m, along m, beams)."""
    heading, _ssv, tdepth, nb, _nvalid, _sr = struct.unpack_from(order + "HHfHHf", body, 16)
    beams = np.frombuffer(body, dtype=np.dtype([
        ("z", order + "f4"), ("y", order + "f4"), ("x", order + "f4"), ("win", order + "u2"), ("q", "u1"),
        ("iba", "i1"), ("det", "u1"), ("clean", "i1"), ("refl", order + "i2")]), count=nb, offset=36)
    ok = ((beams["det"] & 0x80) == 0) & np.isfinite(beams["z"])
    return (t, 0.01 * heading, (beams["z"][ok] + tdepth).astype(np.float32), beams["y"][ok].astype(np.float32),
            beams["x"][ok].astype(np.float32), int(nb))


def _byte_sum(b: bytes, start: int, end: int) -> int:
    """The sum of the unsigned bytes ``b[start:end]`` (the .all and .s7k checksums), without a copy and at C speed
    (a 7k record may declare 256 MiB: Python's ``sum`` over it took seconds per record)."""
    return int(np.frombuffer(b, np.uint8, count=max(end - start, 0), offset=start).sum(dtype=np.uint64))


# ------------------------------------------------------------------ Reson 7k .s7k
_S7K_DRF = struct.Struct("<HHIIII10sHIIHHIHHIII")  # 64 bytes


def _iter_s7k(p: Path, comp: str | None, chunk_points: int, info: dict) -> Iterator[pd.DataFrame]:
    """Reson/Teledyne 7k records (DRF: u16 version, u16 offset, u32 sync 0x0000FFFF, u32 size, u32 optional
    data offset, u32 optional id, 7KTIME, u16 record version, u32 record type, ...; 64 bytes; u32 checksum
    at the end when flag bit 0 is set). Soundings come from 7027 raw-detection records whose optional data
    (f32 frequency, f64 latitude rad, f64 longitude rad, f32 heading rad, u8 height source, f32 tide, roll,
    pitch, heave, vehicle depth; then per detection f32 depth, alongtrack, acrosstrack, pointing, azimuth)
    carries the georeferenced bathymetry. 7006 (legacy bathymetry) and 7027 without optional data would need
    ray tracing with the sound-speed profile: such files get a one-line error saying so."""
    info.update({"reader": "hadal s7k 1", "format": "s7k", "crs_kind": "geographic", "z_positive": "down"})
    types: Counter = Counter()
    batch = _PingBatcher(chunk_points)
    n_pings = n_sound = dropped = beams_max = 0
    t0 = t1 = None
    off = 0
    with _reading(p, comp) as fh:
        while True:
            drf = _read_lead(fh, 64, p, ".s7k", f"partial record frame at byte {off}")
            if not drf:
                break
            (_ver, _o, sync, size, opt_off, _opt_id, t7k, _rv, rtype, _dev, _r1, _se, _r2, flags, _r3, _r4,
             _ft, _fn) = _S7K_DRF.unpack(drf)
            if sync != 0x0000FFFF:
                raise InputError(f"{p}: corrupt .s7k file (no 7k sync pattern at byte {off + 4})")
            if size < 68 or size > (1 << 28):
                raise InputError(f"{p}: corrupt .s7k file (record at byte {off} declares {size} bytes)")
            rest = _read_exact(fh, size - 64)
            if len(rest) < size - 64:
                raise InputError(f"{p}: truncated .s7k file (record {rtype} at byte {off} declares {size} bytes, "
                                 f"{len(rest) + 64} remain)")
            rec = drf + rest
            if flags & 1:
                if struct.unpack_from("<I", rec, size - 4)[0] != (_byte_sum(rec, 0, size - 4) & 0xFFFFFFFF):
                    raise InputError(f"{p}: corrupt .s7k file (checksum mismatch in record {rtype} at byte {off})")
            types[rtype] += 1
            if rtype == 7027 and opt_off:
                res = _s7k_7027(p, rec, opt_off, off)
                if res is not None:
                    lon, lat, dep, nb = res
                    t = _s7k_time(t7k)
                    t0 = t if t0 is None else min(t0, t)
                    t1 = t if t1 is None else max(t1, t)
                    beams_max = max(beams_max, nb)
                    dropped += nb - len(dep)
                    n_sound += len(dep)
                    out = batch.add(lon, lat, dep, n_pings)
                    n_pings += 1
                    if out is not None:
                        yield out
            off += size
    listed = ", ".join(f"{t} x{c}" for t, c in sorted(types.items()))
    if not types:
        raise InputError(f"{p}: no records in the .s7k file")
    if n_pings == 0:
        if types.get(7027) or types.get(7006):
            raise InputError(f"{p}: .s7k file has bathymetry records (7027/7006) without georeferenced soundings "
                             f"(records: {listed}); process it with MB-System or the vendor software first")
        raise InputError(f"{p}: .s7k file contains no bathymetry pings (no 7027 records; records: {listed})")
    info.update({"pings": n_pings, "beams_per_ping": beams_max, "soundings": n_sound, "dropped": dropped,
                 "records": {str(k): v for k, v in types.items()}, "time_start": _iso(t0), "time_end": _iso(t1)})
    yield from batch.rest()


def _s7k_time(t7k: bytes) -> float:
    """7KTIME: u16 year, u16 day of year (1-366), f32 seconds, u8 hours, u8 minutes -> POSIX seconds."""
    year, day, sec, hh, mm = struct.unpack("<HHfBB", t7k)
    try:
        base = _dt.datetime(year, 1, 1, tzinfo=_dt.UTC).timestamp()
    except ValueError:
        return float("nan")
    return base + (day - 1) * 86400.0 + hh * 3600.0 + mm * 60.0 + sec


def _s7k_7027(p: Path, rec: bytes, opt_off: int, off: int):
    """7027 record with optional bathymetry -> (lon, lat, depth, n detections)."""
    try:
        nb, field = struct.unpack_from("<II", rec, 64 + 14)
        if nb == 0:
            return None
        _freq, lat_r, lon_r, head_r = struct.unpack_from("<fddf", rec, opt_off)
        bath = np.frombuffer(rec, dtype="<f4", count=5 * nb, offset=opt_off + 45).reshape(nb, 5)
    except (struct.error, ValueError):
        raise InputError(f"{p}: corrupt .s7k file (7027 record at byte {off} is shorter than its detections)") from None
    depth, along, across = (bath[:, i].astype(np.float64) for i in range(3))
    ok = np.isfinite(depth) & (depth != 0) & np.isfinite(along) & np.isfinite(across)
    lon, lat = _georef(math.degrees(lon_r), math.degrees(lat_r), math.degrees(head_r), along[ok], across[ok])
    return lon, lat, depth[ok], int(nb)
