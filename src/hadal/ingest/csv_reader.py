"""Sensor CSV reader: configurable columns, units and time formats (``vehicle.yaml`` ``csv`` mappings).

Rows with the wrong number of fields, an unparseable time or a non-numeric value in a mapped column are
*corrupt*: they are dropped, counted and reported with a warning. Empty cells are *missing* values (NaN,
e.g. an altimeter dropout) and are kept.
"""

from __future__ import annotations

import io
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from hadal.errors import InputError
from hadal.ingest.units import convert
from hadal.ingest.vehicle import CsvSource, McapSource

__all__ = ["parse_time", "read_sensor_csv", "SensorSamples", "sensor_from_records"]


class SensorSamples:
    """One sensor's samples: ``time_ns`` (int64 ns since the Unix epoch, UTC) and canonical-unit variables."""

    def __init__(self, name: str, time_ns: np.ndarray, values: dict[str, np.ndarray], source: str,
                 stats: dict[str, Any], conversions: list[dict[str, Any]]):
        self.name = name
        self.time_ns = np.asarray(time_ns, dtype=np.int64)
        self.values = {k: np.asarray(v, dtype=np.float64) for k, v in values.items()}
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


def read_sensor_csv(path: str | Path, mapping: CsvSource, sensor: str = "sensor") -> SensorSamples:
    """Read one sensor CSV file with ``mapping`` (columns, units, time format, delimiter).

    Raises :class:`InputError` when the file is missing/empty, has no header, lacks a mapped column, or
    has no usable row. Corrupt rows are dropped with a warning (count in ``stats["corrupt_rows"]``).
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: CSV file does not exist")
    raw = path.read_bytes()
    if not raw.strip():
        raise InputError(f"{path}: CSV file is empty")
    text = raw.decode("utf-8", errors="replace")
    n_lines = sum(1 for ln in text.splitlines() if ln.strip())
    try:
        df = pd.read_csv(io.StringIO(text), sep=mapping.delimiter, dtype=str, keep_default_na=False,
                         on_bad_lines="skip", skipinitialspace=True, engine="c")
    except (pd.errors.ParserError, pd.errors.EmptyDataError, ValueError) as exc:
        raise InputError(f"{path}: not a readable CSV file ({str(exc).splitlines()[0]})") from None
    df.columns = [str(c).strip() for c in df.columns]
    needed = [mapping.time.field] + [fm.field for fm in mapping.fields.values()]
    if mapping.valid_field:
        needed.append(mapping.valid_field)
    missing = [c for c in needed if c not in df.columns]
    if missing:
        raise InputError(f"{path}: missing column(s) {', '.join(repr(c) for c in missing)} required by the "
                         f"vehicle config for sensor {sensor!r} (have: {', '.join(df.columns[:12])})")
    bad_shape = max(n_lines - 1 - len(df), 0)  # rows pandas skipped for a wrong field count

    t = parse_time(df[mapping.time.field].str.strip(), mapping.time.format)
    corrupt = _nat_mask(t)
    values: dict[str, np.ndarray] = {}
    conversions = []
    for var, fm in mapping.fields.items():
        col = df[fm.field].str.strip()
        empty = col.isin(["", "nan", "NaN", "NA", "null", "None"])
        num = pd.to_numeric(col.where(~empty, None), errors="coerce").to_numpy(dtype=np.float64)
        corrupt |= np.isnan(num) & ~empty.to_numpy()
        v, rec = convert(num, fm.units, var)
        values[var] = v
        if rec:
            conversions.append({**rec, "sensor": sensor, "source": f"csv:{path.name}:{fm.field}"})
    if mapping.valid_field:
        ok = df[mapping.valid_field].str.strip().str.lower().isin(["1", "true", "yes", "t"]).to_numpy()
        for var in values:
            values[var] = np.where(ok, values[var], np.nan)
    n_corrupt = int(corrupt.sum()) + bad_shape
    if n_corrupt:
        warnings.warn(f"{path.name}: dropped {n_corrupt} corrupt row(s) of {n_lines - 1}", stacklevel=2)
    keep = ~corrupt
    if not keep.any():
        raise InputError(f"{path}: no usable rows (all {len(df)} rows have an unparseable time or value)")
    stats = {"rows": int(n_lines - 1), "corrupt_rows": n_corrupt}
    return SensorSamples(sensor, t[keep], {k: v[keep] for k, v in values.items()}, f"csv:{path.name}",
                         stats, conversions)


def sensor_from_records(name: str, log_time_ns: np.ndarray, messages: list[dict[str, Any]],
                        mapping: McapSource, source: str) -> SensorSamples:
    """Build :class:`SensorSamples` from decoded MCAP messages with an ``mcap`` mapping.

    Raises :class:`InputError` when a mapped field is absent from every message; a message lacking a
    field or holding a non-numeric value gives NaN (``null`` = missing) and non-numeric values are counted
    as ``stats["bad_values"]``.
    """
    n = len(messages)
    if mapping.time.field == "log_time":
        t = parse_time(np.asarray(log_time_ns, dtype=np.int64), mapping.time.format)
    else:
        t = parse_time([m.get(mapping.time.field) for m in messages], mapping.time.format)
    values, conversions, bad = {}, [], 0
    for var, fm in mapping.fields.items():
        col = [m.get(fm.field) for m in messages]
        if n and all(c is None for c in col) and not any(fm.field in m for m in messages[:1000]):
            raise InputError(f"{source}: topic {mapping.topic} has no field {fm.field!r} "
                             f"(vehicle config maps it to {var})")
        try:  # fast path: numbers and nulls (None -> NaN)
            arr = np.array(col, dtype=np.float64)
        except (TypeError, ValueError):  # strings, lists, ...: coerce and count the non-numeric values
            ser = pd.Series(col, dtype=object)
            ser = ser.where(~ser.map(lambda v: isinstance(v, bool)), None)  # a boolean is not a measurement
            arr = pd.to_numeric(ser, errors="coerce").to_numpy(dtype=np.float64)
            bad += int((~ser.isna().to_numpy() & np.isnan(arr)).sum())
        v, rec = convert(arr, fm.units, var)
        values[var] = v
        if rec:
            conversions.append({**rec, "sensor": name, "source": f"{source}:{mapping.topic}:{fm.field}"})
    if mapping.valid_field:
        ok = np.array([m.get(mapping.valid_field) is True or m.get(mapping.valid_field) == 1 for m in messages],
                      dtype=bool)
        for var in values:
            values[var] = np.where(ok, values[var], np.nan)
    bad_t = _nat_mask(t)
    keep = ~bad_t
    stats = {"messages": n, "bad_values": bad, "bad_times": int(bad_t.sum())}
    return SensorSamples(name, t[keep], {k: v[keep] for k, v in values.items()}, source, stats, conversions)
