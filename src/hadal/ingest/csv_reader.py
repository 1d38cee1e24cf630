"""Sensor CSV reader: configurable columns, units and time formats (``vehicle.yaml`` ``csv`` mappings).

Files are read plain or gzip/bz2/xz-compressed (by content, :func:`hadal.formats.read_bytes`). Rows with the
wrong number of fields, an unparseable time or a non-numeric value in a mapped column are
*corrupt*: they are dropped, counted and reported with a warning. Empty cells are *missing* values (NaN,
e.g. an altimeter dropout) and are kept.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from hadal.budget import DecodeBudget
from hadal.errors import ConfigError, InputError
from hadal.formats import decompress_errors, open_binary, read_text_head, text_encoding_of
from hadal.ingest.align import time_unit_hint
from hadal.ingest.glider import glider_kind
from hadal.ingest.units import CANONICAL_UNITS, TRANSFORMS, apply_transform, convert, normalise_unit
from hadal.ingest.vehicle import CsvSource, FieldMap, McapSource
from hadal.textstream import (
    MAX_LINE_BYTES,
    GrowableColumn,
    LineScan,
    ScannedStream,
    check_line_lengths,
    count_nonblank_lines,
)

__all__ = ["describe_csv", "parse_time", "read_sensor_csv", "SensorSamples", "sensor_from_records", "field_getter",
           "map_variable", "check_line_lengths", "count_nonblank_lines", "MAX_LINE_BYTES", "LineScan"]


class SensorSamples:
    """One sensor's samples: ``time_ns`` (int64 ns since the Unix epoch, UTC) and canonical-unit variables."""

    def __init__(self, name: str, time_ns: np.ndarray, values: dict[str, np.ndarray], source: str,
                 stats: dict[str, Any], conversions: list[dict[str, Any]]):
        self.name = name
        self.time_ns = np.asarray(time_ns, dtype=np.int64).reshape(-1)
        self.values = {k: np.asarray(v, dtype=np.float64) for k, v in values.items()}
        for k, v in self.values.items():  # one finite-or-NaN number per sample, never a 2-D array
            if v.shape != self.time_ns.shape:
                raise InputError(f"{source}: {name} variable {k} has shape {v.shape} for {self.time_ns.size} "
                                 "sample time(s): not one number per sample")
        self.source = source
        self.stats = stats
        self.conversions = conversions

    def __len__(self) -> int:
        return int(self.time_ns.size)


def parse_time(values: Any, fmt: str) -> np.ndarray:
    """Parse times to int64 ns since the Unix epoch (UTC); unparseable entries become ``NaT``'s int value
    (``np.iinfo(int64).min``). ``fmt``: ``unix_ns``, ``unix_ms``, ``unix_s``, ``iso8601`` or a strftime pattern
    (naive times are taken as UTC)."""
    s = pd.Series(values)
    if fmt in ("unix_ns", "unix_ms", "unix_s"):
        num = pd.to_numeric(s, errors="coerce").to_numpy(dtype=np.float64)
        scale = {"unix_ns": 1.0, "unix_ms": 1e6, "unix_s": 1e9}[fmt]
        out = np.full(num.shape, np.iinfo(np.int64).min, dtype=np.int64)
        ok = np.isfinite(num) & (np.abs(num * scale) < 9.2e18)
        if fmt == "unix_ns" and s.dtype.kind in "iu":
            out[ok] = s.to_numpy(dtype=np.int64)[ok]
        else:
            out[ok] = np.round(num[ok] * scale).astype(np.int64)
        return out
    kw = {"format": "ISO8601"} if fmt == "iso8601" else {"format": fmt}
    t = pd.to_datetime(s.astype("string"), utc=True, errors="coerce", **kw)
    return t.dt.as_unit("ns").to_numpy(dtype="datetime64[ns]").astype(np.int64)


def _nat_mask(t: np.ndarray) -> np.ndarray:
    return t == np.iinfo(np.int64).min


#: rows parsed per chunk by :func:`read_sensor_csv` (a chunk's text columns cost ~60 B a cell as Python strings)
CSV_CHUNK_ROWS = 200_000
_EMPTY_CELLS = ["", "nan", "NaN", "NA", "null", "None"]


def csv_head(path: Path, what: str = "CSV") -> tuple[bytes, str | None]:
    """The first (decompressed) :data:`MAX_LINE_BYTES` + 1 bytes of a text table and its compression
    (:func:`hadal.formats.read_text_head`: missing, unreadable, empty and binary files are one-line errors)."""
    return read_text_head(path, what, MAX_LINE_BYTES + 1)


def _csv_chunks(path: Path, sep: str, compression: str | None, scan: LineScan | None = None, **kw: Any):
    """``pandas.read_csv`` chunks of the (decompressed) stream (``nrows``: one frame), damaged streams and parser
    failures as one-line errors. With ``scan``, the stream passes through it (line lengths, row count)."""
    kw = {"dtype": str, "keep_default_na": False, "encoding": "utf-8", **kw}
    if sep == " ":  # space-delimited text (Slocum dbd2asc, loggers' aligned columns): any run of blanks
        sep = r"\s+"
    with open_binary(path) as fh, decompress_errors(path, compression, "CSV"):
        try:
            reader = pd.read_csv(fh if scan is None else ScannedStream(fh, scan), sep=sep, on_bad_lines="skip",
                                 skipinitialspace=True, engine="c", encoding_errors="replace", **kw)
            if "chunksize" not in kw:
                yield reader
                return
            with reader:
                yield from reader
        except InputError:
            raise
        except (pd.errors.ParserError, pd.errors.EmptyDataError, ValueError) as exc:
            raise InputError(f"{path}: not a readable CSV file ({str(exc).splitlines()[0]})") from None


def _leading_comments(head: bytes, encoding: str) -> tuple[int, int, str]:
    """Lines above the header that are ``#`` comments (or blank) - skipped, as loggers write a
    ``# logged by ...`` preamble: their number, the number of non-blank ones, and the header line itself
    (from the first bytes ``head``)."""
    lines = head.decode(encoding, errors="replace").lstrip("\ufeff").splitlines()
    n = 0
    while n < len(lines) and (not lines[n].strip() or lines[n].lstrip().startswith("#")):
        n += 1
    n_text = sum(1 for x in lines[:n] if x.strip())
    if not (n < len(lines) and n_text):
        return 0, 0, (lines[0] if lines else "")
    return n, n_text, lines[n]


class _Layout:
    """Where a text table's column names and data are: the lines skipped (``skiprows`` for pandas), how many of
    them are not blank, the column-name line, the delimiter the format fixes (``None``: the mapping's) and a
    Slocum dbd2asc header block (:func:`hadal.ingest.glider.dbd_asc_header`) when there is one."""

    def __init__(self, head: bytes, encoding: str) -> None:
        from hadal.ingest.glider import dbd_asc_header

        text = head.decode(encoding, errors="replace")
        self.dbd = dbd_asc_header(text)
        self.delimiter: str | None = None
        if self.dbd is not None:  # the header block says how many tag and label lines there are
            n, k = self.dbd.n_tag_lines, self.dbd.n_label_lines
            self.skiprows: int | list[int] = [*range(n), *range(n + 1, n + k)]
            self.n_text = n + k - 1
            self.header_line = " ".join(self.dbd.names)
            self.delimiter = " "
            return
        n_comment, self.n_text, self.header_line = _leading_comments(head, encoding)
        self.skiprows = n_comment

    def skip(self) -> dict[str, Any]:
        return {"skiprows": self.skiprows} if self.skiprows else {}


def _check_file_units(path: Path, mapping: CsvSource, units: dict[str, str]) -> None:
    """Warn when a mapped column's unit in the file's own units line (Slocum dbd2asc) is not the mapping's."""
    from hadal.ingest.glider import unit_of_label

    for var, fm in mapping.fields.items():
        if fm.transform is not None or fm.field not in units:
            continue
        unit = unit_of_label(units[fm.field])
        try:
            same = unit is not None and normalise_unit(unit) == normalise_unit(fm.units)
        except ConfigError:
            same = False
        if not same:
            warnings.warn(f"{path.name}: column {fm.field!r} is in {units[fm.field]!r} by the file's units line, "
                          f"but the vehicle config says {fm.units!r} for {var}: check vehicle.yaml", stacklevel=3)


def _check_header(path: Path, line: str, delimiter: str, needed: list[str], sensor: str) -> None:
    """A mapped column named twice in the raw header line is ambiguous (pandas would rename the second one
    ``name.1`` and the first would be used silently): one-line :class:`InputError` naming it."""
    import csv
    from collections import Counter

    try:
        names = [c.strip() for c in next(csv.reader([line], delimiter=delimiter, skipinitialspace=True))]
    except (csv.Error, StopIteration):
        return
    count = Counter(names)
    dup = [c for c in dict.fromkeys(needed) if count.get(c, 0) > 1]
    if dup:
        pos = [i + 1 for i, c in enumerate(names) if c == dup[0]]
        raise InputError(f"{path}: column {dup[0]!r} (mapped for sensor {sensor!r}) appears {count[dup[0]]} times "
                         f"in the header (columns {', '.join(map(str, pos))}): ambiguous - rename or remove one")


def _check_columns(path: Path, columns: list[str], header_line: str, mapping: CsvSource, sensor: str) -> None:
    """Every mapped column present once in the header; else a one-line :class:`InputError` (naming a likely
    wrong delimiter when the header came out as one column)."""
    needed = [mapping.time.field] + [f for fm in mapping.fields.values() for f in fm.inputs()]
    if mapping.valid_field:
        needed.append(mapping.valid_field)
    _check_header(path, header_line, mapping.delimiter, needed, sensor)
    missing = [c for c in needed if c not in columns]
    if missing:
        why = ""
        if len(columns) == 1:
            other = [d for d in (";", "\t", ",", "|") if d != mapping.delimiter and d in columns[0]]
            if other:
                shown = {"\t": "\\t"}.get(other[0], other[0])
                why = (f": the header is one column {columns[0][:60]!r}: is the delimiter {shown!r}? set "
                       f"csv.delimiter: {shown!r} for sensor {sensor!r} in vehicle.yaml")
        raise InputError(f"{path}: missing column(s) {', '.join(repr(c) for c in missing)} required by the "
                         f"vehicle config for sensor {sensor!r} (have: {', '.join(columns[:12])}){why}")


def _chunk_numbers(chunk: pd.DataFrame, inputs: list[tuple[str, str]], per_col: dict[str, dict[str, Any]],
                   corrupt: np.ndarray) -> dict[tuple[str, str], np.ndarray]:
    """One chunk's mapped input columns as float64; a cell that is not a number marks its row in ``corrupt``
    (in place) and is counted, with examples, in ``per_col``."""
    nums = {}
    for var, f in inputs:
        col = chunk[f]
        if col.dtype.kind in "iuf":  # pandas parsed every cell as a number (or one of the empty cells)
            num, bad = col.to_numpy(dtype=np.float64), np.zeros(len(col), dtype=bool)
        else:  # some cell is not a number: find which, never coerce ('true' is not 1.0)
            col = col.astype(object).where(col.notna(), "").astype(str).str.strip()
            empty = col.isin(_EMPTY_CELLS)
            num = pd.to_numeric(col.where(~empty, None), errors="coerce").to_numpy(dtype=np.float64)
            bad = np.isnan(num) & ~empty.to_numpy()
        if bad.any():  # 'true', '[1.5]', '{}', '3,2', 'abc': rejected (the row), never coerced
            d = per_col.setdefault(f, {"variable": var, "count": 0, "examples": []})
            d["variable"] = var
            d["count"] += int(bad.sum())
            if len(d["examples"]) < 3:
                d["examples"] = sorted(set(d["examples"]) | {str(x)[:20] for x in col[bad].head(50)})[:3]
        corrupt |= bad
        nums[(var, f)] = num
    return nums


#: working copies of the kept columns a sensor CSV's memory budget counts (:class:`hadal.budget.DecodeBudget`):
#: the growable columns, their trimmed values, the unit-converted and validity-masked variables of the samples
CSV_WORKING_COPIES = 3.0


class _CsvRows:
    """The good rows of a sensor CSV, kept as numbers chunk by chunk (:func:`read_sensor_csv`), and the counts
    of the rows dropped."""

    def __init__(self, path: Path, mapping: CsvSource) -> None:
        capacity = max(path.stat().st_size // 64, 1024)  # a first guess of the rows; the columns grow as needed
        self.mapping = mapping
        self.t_out = GrowableColumn(capacity, np.int64)
        self.inputs = [(var, f) for var, fm in mapping.fields.items() for f in fm.inputs()]
        self.num_out = {vf: GrowableColumn(capacity, np.float64) for vf in self.inputs}
        self.ok_out = GrowableColumn(capacity, np.bool_) if mapping.valid_field else None
        self.per_col: dict[str, dict[str, Any]] = {}
        self.n_rows = self.n_bad_time = self.n_rejected = 0
        self.bad_time_values: list[np.ndarray] = []

    def nbytes(self) -> int:
        """Bytes the kept columns hold (their capacity)."""
        cols = [self.t_out, *self.num_out.values(), *([self.ok_out] if self.ok_out is not None else [])]
        return sum(c.a.nbytes for c in cols)

    def add(self, chunk: pd.DataFrame) -> None:
        """One parsed chunk: its rows with a good time and good numbers are kept."""
        mapping = self.mapping
        chunk.columns = [str(c).strip() for c in chunk.columns]
        self.n_rows += len(chunk)
        tcol = chunk[mapping.time.field]
        if tcol.dtype.kind not in "iuf":
            tcol = tcol.astype(object).where(tcol.notna(), "").astype(str).str.strip()
        t = parse_time(tcol, mapping.time.format)
        bad_time = _nat_mask(t)
        corrupt = bad_time.copy()
        nums = _chunk_numbers(chunk, self.inputs, self.per_col, corrupt)
        if bad_time.any() and mapping.time.format.startswith("unix_"):
            self.bad_time_values.append(pd.to_numeric(tcol[bad_time], errors="coerce").to_numpy(np.float64))
        self.n_bad_time += int(bad_time.sum())
        self.n_rejected += int((corrupt & ~bad_time).sum())
        keep = ~corrupt
        self.t_out.extend(t[keep])
        for vf, num in nums.items():
            self.num_out[vf].extend(num[keep])
        if self.ok_out is not None:
            ok = chunk[mapping.valid_field].fillna("").str.strip().str.lower().isin(["1", "true", "yes", "t"])
            ok = ok.to_numpy()
            self.ok_out.extend(ok[keep])


def _warn_corrupt(path: Path, mapping: CsvSource, rows: _CsvRows, n_lines: int, bad_shape: int, n_corrupt: int,
                  hint: str | None) -> None:
    """The one warning about dropped rows (why, with examples), raised at read_sensor_csv's caller."""
    parts = []
    if bad_shape:
        parts.append(f"{bad_shape} with a wrong number of fields")
    if rows.n_bad_time:
        parts.append(f"{rows.n_bad_time} with an unparseable time in {mapping.time.field!r} "
                     f"({mapping.time.format}{'; it ' + hint if hint else ''})")
    if rows.per_col:
        parts.append("non-numeric values: " + "; ".join(
            f"{c}: {d['count']} (e.g. {', '.join(repr(x) for x in d['examples'])})" for c, d in rows.per_col.items()))
    warnings.warn(f"{path.name}: dropped {n_corrupt} corrupt row(s) of {n_lines - 1} ({'; '.join(parts)})",
                  stacklevel=3)


def _mapped_values(path: Path, mapping: CsvSource, rows: _CsvRows, sensor: str
                   ) -> tuple[dict[str, np.ndarray], list[Any]]:
    """Each mapped variable from its input columns (units converted; NaN where the validity column says not
    valid), and the conversion records."""
    values: dict[str, np.ndarray] = {}
    conversions = []
    for var, fm in mapping.fields.items():
        cols = [rows.num_out.pop((var, f)).values() for f in fm.inputs()]
        values[var], recs = map_variable(var, fm, cols, sensor, f"csv:{path.name}")
        conversions.extend(recs)
        if rows.ok_out is not None:
            values[var] = np.where(rows.ok_out.values(), values[var], np.nan)
    return values, conversions


def read_sensor_csv(path: str | Path, mapping: CsvSource, sensor: str = "sensor", *,
                    memory_limit_bytes: float | None = None) -> SensorSamples:
    """Read one sensor CSV file with ``mapping`` (columns, units, time format, delimiter).

    Raises :class:`InputError` when the file is missing/empty, has no header, lacks a mapped column, or
    has no usable row. Corrupt rows are dropped with a warning (count in ``stats["corrupt_rows"]``).

    Memory: the file is never held whole. It is read once, as a stream: a :class:`LineScan` on the way bounds
    the line length and counts the rows, and pandas parses :data:`CSV_CHUNK_ROWS` rows at a time, of which the
    good rows of the mapped columns are kept as numbers. Peak memory is the decoded numbers plus one chunk.
    """
    path = Path(path)
    head, compression = csv_head(path)
    scan = LineScan(path, "CSV row")
    scan_head = LineScan(path, "CSV row")
    scan_head.feed(head)  # the header line itself is bounded before pandas reads it
    encoding = text_encoding_of(head)
    layout = _Layout(head, encoding)
    n_comment_text, header_line, skip = layout.n_text, layout.header_line, layout.skip()
    delimiter = layout.delimiter or mapping.delimiter
    if delimiter != mapping.delimiter:
        mapping = mapping.model_copy(update={"delimiter": delimiter})
    header = next(_csv_chunks(path, delimiter, compression, nrows=0, encoding=encoding, **skip))
    columns = [str(c).strip() for c in header.columns]
    _check_columns(path, columns, header_line, mapping, sensor)
    if layout.dbd is not None:
        _check_file_units(path, mapping, layout.dbd.units_of())
    rows = _CsvRows(path, mapping)
    budget = DecodeBudget(path, "CSV file", copies=CSV_WORKING_COPIES, limit_bytes=memory_limit_bytes)
    # numbers are parsed by pandas' C parser (a column with any other cell comes back as text and is checked
    # cell by cell); the time column stays text unless it is a plain number, the validity column always.
    # Every column is parsed (``usecols`` would hide rows with too many fields from ``on_bad_lines``); a
    # chunk's unmapped columns are dropped with it.
    raw_name = {str(c).strip(): c for c in header.columns}
    as_text = [mapping.valid_field] if mapping.valid_field else []
    if not mapping.time.format.startswith("unix_"):
        as_text.append(mapping.time.field)
    for chunk in _csv_chunks(path, mapping.delimiter, compression, scan, chunksize=CSV_CHUNK_ROWS,
                             dtype={raw_name[c]: str for c in as_text}, na_values=_EMPTY_CELLS, encoding=encoding,
                             **skip):
        rows.add(chunk)
        budget.hold(rows.nbytes(), f"{rows.n_rows:,} rows so far")
        del chunk
    n_lines = scan.finish()
    bad_shape = max(n_lines - 1 - n_comment_text - rows.n_rows, 0)  # rows pandas skipped for a wrong field count
    n_corrupt = rows.n_bad_time + rows.n_rejected + bad_shape
    hint = None
    if rows.bad_time_values:
        hint = time_unit_hint(np.concatenate(rows.bad_time_values), mapping.time.format)
    if n_corrupt:
        _warn_corrupt(path, mapping, rows, n_lines, bad_shape, n_corrupt, hint)
    if rows.t_out.n == 0:
        raise InputError(f"{path}: no usable rows (all {rows.n_rows} rows have an unparseable time or value"
                         + (f"; time column {mapping.time.field!r} {hint}" if hint else "") + ")")
    values, conversions = _mapped_values(path, mapping, rows, sensor)
    times = rows.t_out.values()
    n_not_updated = 0
    sparse = glider_kind(columns, layout.dbd) is not None
    if sparse:  # glider logs: an empty cell / NaN is a sensor not sampled in that row (dbd2asc cycles, SeaExplorer
        # payload rows of other instruments); a row with none of this sensor's values is no sample of it
        keep = np.zeros(times.shape, dtype=bool)
        for v in values.values():
            keep |= np.isfinite(v)
        if keep.any():  # else every value is missing: kept as such, the channels are flagged downstream
            n_not_updated = int((~keep).sum())
            times, values = times[keep], {k: v[keep] for k, v in values.items()}
    stats = {"rows": int(n_lines - 1 - n_comment_text), "comment_lines": n_comment_text, "corrupt_rows": n_corrupt,
             "bad_times": rows.n_bad_time, "wrong_field_count": bad_shape, "rejected_samples": rows.n_rejected,
             "rejected_values": rows.per_col, "time_field": mapping.time.field, "time_format": mapping.time.format}
    if sparse:
        stats["rows_not_updated"] = n_not_updated
    return SensorSamples(sensor, times, values, f"csv:{path.name}", stats, conversions)


def field_column(messages: list[Any], path: str) -> list[Any]:
    """The (dotted) field ``path`` of every decoded message (:func:`field_getter`; a plain key read inline, without
    a call per message: 0.5 s of the sample dive's MCAP ingest went to those calls)."""
    if "." not in path:
        return [m.get(path) for m in messages]
    get = field_getter(path)
    return [get(m) for m in messages]


def field_getter(path: str) -> Any:
    """Getter for a (dotted) field of a decoded message: ``"pres"``, ``"header.stamp.sec"``,
    ``"position_covariance.0"``. A key containing the dots itself (a flat JSON key) is found first;
    a missing field gives ``None``."""
    parts = path.split(".")
    if len(parts) == 1:
        return lambda m: m.get(path)

    def get(m: Any) -> Any:
        v = m.get(path)
        if v is not None:
            return v
        for p in parts:
            if isinstance(m, dict):
                m = m.get(p)
            elif isinstance(m, (list, tuple)) and p.isdigit() and int(p) < len(m):
                m = m[int(p)]
            else:
                return None
            if m is None:
                return None
        return m
    return get


def _has_field(m: dict[str, Any], path: str) -> bool:
    if path in m:
        return True
    parts = path.split(".")
    for p in parts[:-1]:
        m = m.get(p) if isinstance(m, dict) else None
        if m is None:
            return False
    if isinstance(m, (list, tuple)):
        return parts[-1].isdigit() and int(parts[-1]) < len(m)
    return isinstance(m, dict) and parts[-1] in m


_NUMBER_TYPES = (int, float, np.integer, np.floating)


def _type_name(v: Any) -> str:
    if isinstance(v, (bool, np.bool_)):
        return "bool"
    if isinstance(v, str):
        return "string"
    if isinstance(v, (list, tuple, np.ndarray)):
        return "array"
    if isinstance(v, dict):
        return "object"
    return type(v).__name__


def _numeric(col: list[Any]) -> tuple[np.ndarray, np.ndarray, dict[str, int]]:
    """Values -> float64; ``None``/null is a missing value (NaN). Anything that is not a number - a boolean,
    a string (even ``"3.2"``), an array, an object - is *rejected*, never coerced: returns the values (NaN
    where rejected), the rejected mask and the rejected count per JSON type (``{"bool": 3}``)."""
    kinds = set(map(type, col))
    if kinds <= {float, int, type(None)}:  # fast path: plain numbers and nulls (bool is its own type)
        try:
            return np.array(col, dtype=np.float64), np.zeros(len(col), dtype=bool), {}
        except (OverflowError, TypeError, ValueError):
            pass
    arr = np.full(len(col), np.nan)
    bad = np.zeros(len(col), dtype=bool)
    types: dict[str, int] = {}
    for i, v in enumerate(col):
        if v is None:
            continue
        if isinstance(v, _NUMBER_TYPES) and not isinstance(v, (bool, np.bool_)):
            try:
                arr[i] = float(v)
                continue
            except (OverflowError, ValueError):
                pass
        bad[i] = True
        k = _type_name(v)
        types[k] = types.get(k, 0) + 1
    return arr, bad, types


def _rejected_text(per_field: dict[str, dict[str, Any]]) -> str:
    """``temp: 3 (bool 2, array 1); pres: 1 (string 1)``"""
    return "; ".join(f"{f}: {d['count']}" + (" (" + ", ".join(f"{k} {n}" for k, n in d["types"].items()) + ")"
                                             if d.get("types") else "")
                     for f, d in per_field.items())


def _time_values(values: list[Any], fmt: str) -> tuple[list[Any], dict[str, int]]:
    """Time field values of the right JSON type for ``fmt`` (numbers for unix_*, strings for iso8601 or a
    strftime pattern); others (a boolean, a number-as-string, an array ...) become ``None`` (NaT), counted
    by type."""
    numeric = fmt.startswith("unix_")
    out: list[Any] = []
    types: dict[str, int] = {}
    for v in values:
        ok = v is None or ((isinstance(v, _NUMBER_TYPES) and not isinstance(v, (bool, np.bool_))) if numeric
                           else isinstance(v, str))
        if not ok:
            k = _type_name(v)
            types[k] = types.get(k, 0) + 1
            v = None
        out.append(v)
    return out, types


def _ros_time_ns(values: list[Any]) -> np.ndarray:
    """ROS ``builtin_interfaces/Time`` sub-messages ({sec, nanosec}; ROS 1 {secs, nsecs}) -> int64 ns (NaT int)."""
    out = np.full(len(values), np.iinfo(np.int64).min, dtype=np.int64)
    for i, v in enumerate(values):
        if isinstance(v, dict):
            sec = v.get("sec", v.get("secs"))
            ns = v.get("nanosec", v.get("nsecs", 0))
            if isinstance(sec, (int, float)) and isinstance(ns, (int, float)) and not isinstance(sec, bool):
                out[i] = int(sec) * 1_000_000_000 + int(ns)
    return out


def _fill_to_nan(x: np.ndarray, fill_values: list[float]) -> np.ndarray:
    """``x`` with its fill values (source values meaning "no measurement") as NaN."""
    x = np.asarray(x, dtype=np.float64)
    return np.where(np.isin(x, np.asarray(fill_values, dtype=np.float64)), np.nan, x)


def map_variable(var: str, fm: FieldMap, columns: list[np.ndarray], sensor: str, source: str
                 ) -> tuple[np.ndarray, list[dict[str, Any]]]:
    """One variable from its source column(s): transform (if any), unit conversion, offset.

    Returns the canonical-unit values and the conversion records (for the product metadata)."""
    records: list[dict[str, Any]] = []
    where = f"{source}:{fm.label()}"
    if fm.fill_values:
        filled = [_fill_to_nan(c, fm.fill_values) for c in columns]
        n_fill = int(sum(int((np.isnan(f) & ~np.isnan(np.asarray(c, dtype=np.float64))).sum())
                         for f, c in zip(filled, columns, strict=True)))
        columns = filled
        fills = ", ".join(f"{v:g}" for v in fm.fill_values)
        records.append({"variable": var, "from": ", ".join(fm.inputs()), "to": "missing (NaN)",
                        "formula": f"fill value(s) {fills} -> missing", "count": n_fill,
                        "sensor": sensor, "source": where})
        if n_fill:  # named: the mapping's fill values are missing data (flag 9), never values
            warnings.warn(f"{where}: {n_fill} {var} value(s) are the mapping's fill value(s) {fills} "
                          "(no data): missing (flag 9)", stacklevel=2)
    if fm.transform is not None:
        x = apply_transform(fm.transform, columns, fm.origin)
        t = TRANSFORMS[fm.transform][0]
        records.append({"variable": var, "from": ", ".join(fm.inputs()), "to": t.unit or fm.units,
                        "formula": fm.transform + (f" (origin {list(fm.origin)})" if fm.origin else ""),
                        "sensor": sensor, "source": where})
    else:
        x = columns[0]
    v, rec = convert(x, fm.units, var)
    if rec:
        records.append({**rec, "sensor": sensor, "source": where})
    if fm.offset:
        v = v + fm.offset
        records.append({"variable": var, "from": CANONICAL_UNITS[var], "to": CANONICAL_UNITS[var],
                        "formula": f"x + {fm.offset:.10g}", "sensor": sensor, "source": where})
    return v, records


def sensor_from_records(name: str, log_time_ns: np.ndarray, messages: list[dict[str, Any]],
                        mapping: McapSource, source: str) -> SensorSamples:
    """Build :class:`SensorSamples` from decoded MCAP messages with an ``mcap`` mapping.

    Fields may be dotted paths into nested (ROS 2) messages; transforms, units and offsets are applied as
    the mapping says (:func:`map_variable`). Raises :class:`InputError` when a mapped field is absent from
    every message. A message lacking a field or holding ``null`` gives NaN (missing). A value that is not a
    number (a JSON ``true``, ``"3.2"``, ``[3.2]``, an object) is never coerced: the whole sample (message) is
    rejected, counted per field and type in ``stats["rejected_values"]`` (``stats["rejected_samples"]`` in
    all) and warned about. A time field of the wrong type (or unparseable) rejects the sample too
    (``stats["bad_times"]``).

    The messages of one call are one part of :class:`RecordParts` (the MCAP reader feeds it chunk by chunk,
    so that a topic's decoded messages are never all held at once; same result).
    """
    parts = RecordParts(mapping, source)
    parts.add(log_time_ns, messages)
    return parts.samples(name)


#: a mapped field (or the time field) is looked for in the first this many messages before "has no field"
_FIELD_PROBE_MESSAGES = 1000


class RecordParts:
    """Decoded MCAP messages of one sensor's topic taken part by part (:meth:`add`: each part's mapped fields
    become NumPy columns and its message objects can be dropped), then one :class:`SensorSamples`
    (:meth:`samples`) equal to what all the messages at once give: every step is per message (field lookup,
    :func:`_numeric`, :func:`_time_values`, :func:`parse_time`) except the checks that look at the first
    :data:`_FIELD_PROBE_MESSAGES` messages, which follow the parts' offsets, and the integer ``unix_ns`` time
    path, which is taken only when every part's times are integers (as one ``pandas.Series`` of them all)."""

    def __init__(self, mapping: McapSource, source: str) -> None:
        self.mapping, self.source = mapping, source
        self.n = 0
        self.times: list[np.ndarray] = []  # int64 ns per part (log_time, ros_time, or unix_* / strings parsed)
        self.time_num: list[np.ndarray] = []  # unix_ns: each part's times as float64 (pandas' to_numeric)
        self.time_int = True  # unix_ns: every part's times were integers (the exact integer path)
        self.time_types: dict[str, int] = {}
        self.time_seen = False
        # per (variable, input field): each part's float64 column (a field may feed two variables)
        self.cols: dict[tuple[str, str], list[np.ndarray]] = {(var, f): [] for var, fm in mapping.fields.items()
                                                              for f in fm.inputs()}
        self.field_seen = {f: False for _, f in self.cols}  # a non-null value, or the field in a probed message
        self.rejected: list[np.ndarray] = []
        self.per_field: dict[str, dict[str, Any]] = {}
        self.valid: list[np.ndarray] = []
        self.first: dict[str, Any] | None = None

    def add(self, log_time_ns: np.ndarray, messages: list[dict[str, Any]]) -> None:
        """One part: the log times and decoded messages (dicts) of consecutive messages of the topic."""
        m, n = self.mapping, len(messages)
        probe = messages[:max(_FIELD_PROBE_MESSAGES - self.n, 0)]
        if n and self.first is None:
            self.first = messages[0]
        if m.time.field == "log_time":
            self.times.append(parse_time(np.asarray(log_time_ns, dtype=np.int64), m.time.format))
        else:
            self.time_seen = self.time_seen or any(_has_field(x, m.time.field) for x in probe)
            if m.time.format == "ros_time":
                self.times.append(_ros_time_ns(field_column(messages, m.time.field)))
            else:
                tv, types = _time_values(field_column(messages, m.time.field), m.time.format)
                for k, c in types.items():
                    self.time_types[k] = self.time_types.get(k, 0) + c
                self._add_times(tv)
        rejected = np.zeros(n, dtype=bool)
        for var, fm in m.fields.items():
            for f in fm.inputs():
                col = field_column(messages, f)
                if not self.field_seen[f] and (not all(c is None for c in col)
                                               or any(_has_field(x, f) for x in probe)):
                    self.field_seen[f] = True
                arr, bad, types = _numeric(col)
                del col
                if bad.any():
                    rejected |= bad
                    d = self.per_field.setdefault(f, {"variable": var, "count": 0, "types": {}})
                    d["count"] += int(bad.sum())
                    for k, c in types.items():
                        d["types"][k] = d["types"].get(k, 0) + c
                self.cols[var, f].append(arr)
        self.rejected.append(rejected)
        if m.valid_field:
            self.valid.append(np.array([v is True or v == 1 for v in field_column(messages, m.valid_field)],
                                       dtype=bool))
        self.n += n

    def _add_times(self, tv: list[Any]) -> None:
        fmt = self.mapping.time.format
        if fmt != "unix_ns":
            self.times.append(parse_time(tv, fmt))
            return
        if not tv:
            return
        s = pd.Series(tv)
        self.time_num.append(pd.to_numeric(s, errors="coerce").to_numpy(dtype=np.float64))
        self.time_int = self.time_int and s.dtype.kind in "iu"
        self.times.append(s.to_numpy(dtype=np.int64) if s.dtype.kind in "iu" else np.zeros(0, dtype=np.int64))

    def _time_ns(self) -> np.ndarray:
        if self.mapping.time.field == "log_time" or self.mapping.time.format != "unix_ns":
            return np.concatenate(self.times) if self.times else np.zeros(0, dtype=np.int64)
        # parse_time's unix_ns on all the values at once: the integers as they are when all parts are integers
        num = np.concatenate(self.time_num) if self.time_num else np.zeros(0)
        out = np.full(num.shape, np.iinfo(np.int64).min, dtype=np.int64)
        ok = np.isfinite(num) & (np.abs(num) < 9.2e18)
        if self.time_int and self.times:
            out[ok] = np.concatenate(self.times)[ok]
        else:
            out[ok] = np.round(num[ok]).astype(np.int64)
        return out

    def samples(self, name: str) -> SensorSamples:
        """The :class:`SensorSamples` of every part added (see :func:`sensor_from_records`)."""
        m, n, source = self.mapping, self.n, self.source
        where = f"{source}:{m.topic}"
        if m.time.field != "log_time" and n and not self.time_seen:
            raise InputError(f"{source}: topic {m.topic} has no time field {m.time.field!r}")
        t = self._time_ns()
        self.times = self.time_num = []
        values, conversions = {}, []
        for var, fm in m.fields.items():
            cols = []
            for f in fm.inputs():
                if n and not self.field_seen[f]:
                    raise InputError(f"{source}: topic {m.topic} has no field {f!r} (vehicle config maps it to {var})")
                cols.append(np.concatenate(self.cols[var, f]) if self.cols[var, f] else np.zeros(0))
                self.cols[var, f] = []
            values[var], recs = map_variable(var, fm, cols, name, where)
            conversions.extend(recs)
        if m.valid_field:
            ok = np.concatenate(self.valid) if self.valid else np.zeros(0, dtype=bool)
            for var in values:
                values[var] = np.where(ok, values[var], np.nan)
        rejected = np.concatenate(self.rejected) if self.rejected else np.zeros(0, dtype=bool)
        per_field, time_types = self.per_field, self.time_types
        bad_t = _nat_mask(t)
        if per_field:
            warnings.warn(f"{where}: rejected {int(rejected.sum())} of {n} {name} sample(s) holding a value that is "
                          f"not a number ({_rejected_text(per_field)}); values are never coerced", stacklevel=2)
        if bad_t.any():
            why = (" (" + ", ".join(f"{k} {c}" for k, c in time_types.items()) + " where "
                   + ("a number" if m.time.format.startswith("unix_") else "a string") + " belongs)"
                   if time_types else "")
            warnings.warn(f"{where}: dropped {int(bad_t.sum())} of {n} {name} sample(s) without a valid time in "
                          f"{m.time.field!r} ({m.time.format}){why}", stacklevel=2)
        keep = ~(bad_t | rejected)
        stats = {"messages": n, "bad_values": int(sum(d["count"] for d in per_field.values())),
                 "bad_times": int(bad_t.sum()), "rejected_samples": int(rejected.sum()), "rejected_values": per_field,
                 "time_field": m.time.field, "time_format": m.time.format}
        if time_types:
            stats["bad_time_types"] = time_types
        return SensorSamples(name, t[keep], {k: v[keep] for k, v in values.items()}, source, stats, conversions)


# --------------------------------------------------------------------------------------------------------------
# describe: what is in a sensor CSV file (``hadal inspect``, ``hadal init``)
# --------------------------------------------------------------------------------------------------------------

_TIME_NAMES = ("time", "timestamp", "datetime", "date_time", "time_utc", "utc", "utc_time", "stamp", "t",
               "time_s", "unix_time", "epoch", "log_time", "timestamp_ns", "time_ns", "time_ms")


def _guess_time_format(values: list[str]) -> str | None:
    """``iso8601`` / ``unix_s`` / ``unix_ms`` / ``unix_ns`` when every non-empty value parses as such."""
    vals = [v.strip() for v in values if v and v.strip()]
    if not vals:
        return None
    num = pd.to_numeric(pd.Series(vals), errors="coerce").to_numpy(dtype=np.float64)
    if np.isfinite(num).all():
        med = float(np.median(np.abs(num)))
        # seconds since 1970 between ~1973 and ~2286, then ms and ns of the same span
        for fmt, lo, hi in (("unix_s", 1e8, 1e10), ("unix_ms", 1e11, 1e13), ("unix_ns", 1e17, 1e19)):
            if lo <= med < hi:
                return fmt
        return None
    t = parse_time(vals, "iso8601")
    if not _nat_mask(t).any():
        return "iso8601"
    for fmt in _DAY_FIRST:  # European loggers (SeaExplorer 21/07/2019 23:24:49): day first, never month first
        if not _nat_mask(parse_time(vals, fmt)).any():
            return fmt
    return None


#: day-first date-time patterns tried after ISO 8601 (``DD/MM/YYYY``, ``DD.MM.YYYY``, with or without fractions)
_DAY_FIRST = ("%d/%m/%Y %H:%M:%S", "%d/%m/%Y %H:%M:%S.%f", "%d.%m.%Y %H:%M:%S", "%d.%m.%Y %H:%M:%S.%f")


def describe_csv(path: str | Path, *, sample_rows: int = 2000) -> dict[str, Any]:
    """What is in a sensor CSV file, as a JSON-serialisable dict (``hadal inspect``, ``hadal init``).

    Keys: ``path``, ``format`` (``"csv"``), ``size_bytes``, ``delimiter`` (sniffed among ``, ; TAB |``),
    ``columns``, ``sample_row`` (the first data row, column -> text), ``first_values`` (first non-empty value
    of each column), ``rows`` (data rows), ``numeric_columns``,
    ``time_column`` / ``time_format`` (guessed from the name and the values: ``iso8601``, ``unix_s``,
    ``unix_ms``, ``unix_ns``; ``None`` when no column looks like a time), ``start_time`` / ``end_time``
    (ISO 8601 UTC), ``duration_s`` and ``rate_hz``; for glider logs (:mod:`hadal.ingest.glider`) ``glider``
    (``seaexplorer``/``slocum``, else ``None``), ``units`` and ``header_tags`` (a Slocum dbd2asc file's units line
    and header block) and ``track`` (first position and lat/lon ranges of its NMEA positions). Raises :class:`InputError` when the file is missing, empty,
    binary or has no header row.
    """
    import csv as _csv

    path = Path(path)
    head, compression = csv_head(path)
    LineScan(path, "CSV row").feed(head)
    encoding = text_encoding_of(head)
    text = head.decode("utf-8-sig" if encoding == "utf-8" else encoding, errors="replace")
    layout = _Layout(head, encoding)
    lines = [ln for ln in text.splitlines()[:200] if ln.strip()]
    sniff = "\n".join(lines[:50])
    if layout.delimiter is not None:  # the format fixes it (Slocum dbd2asc: blanks)
        delim = layout.delimiter
    else:
        try:
            delim = _csv.Sniffer().sniff(sniff, delimiters=",;\t|").delimiter
        except _csv.Error:
            counts = {d: lines[0].count(d) for d in ",;\t|"}
            delim = max(counts, key=counts.__getitem__) if max(counts.values()) else ","
    skip = layout.skip() if layout.dbd is not None else {}
    glider = None
    track = None
    # one streamed pass in chunks: the first chunk gives the columns, the sample row, which columns are numeric
    # and the time column; every chunk adds its rows, first values still missing and its time span
    columns: list[str] = []
    sample: dict[str, str] = {}
    numeric: list[str] = []
    first_values: dict[str, str] = {}
    tcol, tfmt = None, None
    n_rows, n_t, t0, t1 = 0, 0, None, None
    for k, df in enumerate(_csv_chunks(path, delim, compression, LineScan(path, "CSV row"),
                                       chunksize=max(sample_rows, CSV_CHUNK_ROWS),
                                       encoding="utf-8-sig" if encoding == "utf-8" else encoding, **skip)):
        df.columns = [str(c).strip() for c in df.columns]
        if k == 0:
            columns = list(df.columns)
            if not columns or all(pd.to_numeric(pd.Series(columns), errors="coerce").notna()):
                raise InputError(f"{path}: no header row (the first line holds numbers, not column names)")
            sample = {c: str(v) for c, v in zip(columns, df.iloc[0].tolist(), strict=True)} if len(df) else {}
        n_rows += len(df)
        for c in columns:
            if c not in first_values:  # its first values: numeric when 95 % of (up to) sample_rows of them are
                col = df[c].str.strip()
                filled = col[~col.isin(_EMPTY_CELLS)]
                if len(filled):
                    first_values[c] = str(filled.iloc[0])
                    if pd.to_numeric(filled.head(sample_rows), errors="coerce").notna().mean() > 0.95:
                        numeric.append(c)
        if k == 0:
            tcol, tfmt, glider = _time_of_table(columns, numeric, df.head(sample_rows), layout)
            if glider is not None:
                track = _GliderTrack(glider, columns, layout)
        if track is not None:
            track.add(df)
        if tcol is not None:
            t = parse_time(df[tcol].str.strip(), tfmt)
            t = t[~_nat_mask(t)]
            if t.size:
                n_t += t.size
                t0 = int(t.min()) if t0 is None else min(t0, int(t.min()))
                t1 = int(t.max()) if t1 is None else max(t1, int(t.max()))
    if not columns:
        raise InputError(f"{path}: not a readable CSV file (no columns)")
    numeric = [c for c in columns if c in set(numeric)]
    out: dict[str, Any] = {
        "path": str(path), "format": "csv", "size_bytes": path.stat().st_size, "delimiter": delim, "columns": columns,
        "sample_row": sample, "first_values": first_values, "rows": int(n_rows), "numeric_columns": numeric,
        "time_column": tcol, "time_format": tfmt, "start_time": None, "end_time": None, "duration_s": None,
        "rate_hz": None, "glider": glider, "units": layout.dbd.units_of() if layout.dbd is not None else {},
        "header_tags": dict(layout.dbd.tags) if layout.dbd is not None else {},
        "track": track.summary() if track is not None else None,
    }
    if n_t and t0 is not None and t1 is not None:
        iso = [str(np.datetime64(x, "ns").astype("datetime64[ms]")) + "Z" for x in (t0, t1)]
        out.update(start_time=iso[0], end_time=iso[1], duration_s=(t1 - t0) / 1e9,
                   rate_hz=(n_t - 1) / ((t1 - t0) / 1e9) if t1 > t0 else None)
    return out


class _GliderTrack:
    """The geographic extent and first position of a glider log's NMEA position columns, chunk by chunk."""

    def __init__(self, kind: str, columns: list[str], layout: _Layout) -> None:
        from hadal.ingest.glider import glider_fields

        _, fields, _ = glider_fields(kind, columns, layout.dbd.units_of() if layout.dbd is not None else {})
        pair = next((f.field for f in fields if f.transform and f.transform.startswith("latlon_ddmm")), None)
        self.pair = list(pair) if isinstance(pair, list) else None
        self.lat: list[float] = []
        self.lon: list[float] = []
        self.first: tuple[float, float] | None = None

    def add(self, df: pd.DataFrame) -> None:
        from hadal.ingest.glider import nmea_to_deg

        if self.pair is None:
            return
        la, lo = (nmea_to_deg(pd.to_numeric(df[c].str.strip(), errors="coerce").to_numpy(np.float64))
                  for c in self.pair)
        ok = np.isfinite(la) & np.isfinite(lo) & (np.abs(la) <= 90) & (np.abs(lo) <= 180)
        if not ok.any():
            return
        if self.first is None:
            i = int(np.argmax(ok))
            self.first = (float(la[i]), float(lo[i]))
        self.lat += [float(la[ok].min()), float(la[ok].max())]
        self.lon += [float(lo[ok].min()), float(lo[ok].max())]

    def summary(self) -> dict[str, Any] | None:
        if self.first is None or self.pair is None:
            return None
        return {"columns": self.pair, "first_deg": list(self.first), "latitude_deg": [min(self.lat), max(self.lat)],
                "longitude_deg": [min(self.lon), max(self.lon)]}


def _time_of_table(columns: list[str], numeric: list[str], head_df: pd.DataFrame, layout: _Layout
                   ) -> tuple[str | None, str | None, str | None]:
    """The time column, its format and the glider kind (:func:`hadal.ingest.glider.glider_kind`) of a table: a
    glider log's time column by its kind's convention (checked against the values), else :func:`_time_column`."""
    from hadal.ingest.glider import glider_fields, glider_kind

    glider = glider_kind(columns, layout.dbd)
    if glider is not None:
        time, _, _ = glider_fields(glider, columns, layout.dbd.units_of() if layout.dbd is not None else {})
        if time is not None:
            vals = [str(v).strip() for v in head_df[time["field"]].tolist() if str(v).strip() not in _EMPTY_CELLS]
            if vals and not _nat_mask(parse_time(vals, time["format"])).all():
                return time["field"], time["format"], glider
    tcol, tfmt = _time_column(columns, numeric, head_df)
    return tcol, tfmt, glider


def _time_column(columns: list[str], numeric: list[str], head_df: pd.DataFrame) -> tuple[str | None, str | None]:
    """The time column of a table and its format: a time-like name first, then any column whose values parse
    as times."""
    by_name = sorted((c for c in columns if c.lower() in _TIME_NAMES), key=lambda c: _TIME_NAMES.index(c.lower()))
    candidates = by_name + [c for c in columns if c not in by_name and c not in numeric] + \
        [c for c in columns if c not in by_name and c in numeric]
    for c in candidates:
        fmt = _guess_time_format(head_df[c].tolist())
        if fmt is not None and (c in by_name or fmt == "iso8601" or "%" in fmt
                                or c.lower().startswith(("time", "unix", "epoch"))):
            return c, fmt
    return None, None
