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
import logging
import math
import re
import warnings
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from hadal.errors import InputError

log = logging.getLogger(__name__)

__all__ = ["read_cnv", "parse_latlon", "cnv_time_ns", "cnv_sensor_samples", "CNV_DEFAULT_BAD_FLAG"]

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


def _parse_rows(lines: list[str], nquan: int, path: Path, first_line_no: int) -> tuple[np.ndarray, list[int]]:
    """Numeric rows; a line with the wrong token count is re-read as 11-character fields (SeaSoft columns
    can touch, e.g. ``-123.4567-99.12``); lines that still fail are dropped and their numbers returned."""
    rows: list[list[float]] = []
    bad: list[int] = []
    for i, line in enumerate(lines):
        if not line.strip():
            continue
        toks = line.split()
        if len(toks) != nquan:
            width = len(line.rstrip())
            if width == nquan * _FIELD_WIDTH:
                toks = [line[k * _FIELD_WIDTH:(k + 1) * _FIELD_WIDTH] for k in range(nquan)]
            else:
                bad.append(first_line_no + i)
                continue
        try:
            rows.append([float(t) for t in toks])
        except ValueError:
            bad.append(first_line_no + i)
    arr = np.asarray(rows, dtype=np.float64).reshape(-1, nquan)
    return arr, bad


def read_cnv(path: str | Path) -> pd.DataFrame:
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
    * ``bad_flag`` (float; those values became NaN), ``bad_values`` (count replaced);
    * ``processing``: SeaSoft processing lines in file order, ``[[key, value], ...]``
      (``datcnv_date``, ``wildedit_vars``, ``Derive_in``, ...);
    * ``sensors`` (``# sensor i = ...`` lines), ``user_header`` (``**`` lines), ``instrument_header``;
    * ``nquan``, ``nvalues_declared``, ``nvalues`` (rows read), ``rows_dropped`` (line numbers of
      unparseable data lines, dropped with a warning).

    Raises :class:`~hadal.errors.InputError` (one line, naming the file) when the file is missing, empty,
    has no ``*END*`` line, no ``# name`` lines, or no readable data rows.
    """
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path}: CNV file does not exist")
    raw = path.read_bytes()
    if not raw.strip():
        raise InputError(f"{path}: CNV file is empty")
    text = raw.decode("latin-1")  # SeaSoft writes Windows-1252/Latin-1 (e.g. 'sigma-\xe900')
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    end = next((i for i, ln in enumerate(lines) if ln.strip().upper() == "*END*"), None)
    if end is None:
        raise InputError(f"{path}: not a Sea-Bird .cnv file (no '*END*' line after the header)")
    header = lines[:end]

    names: dict[int, tuple[str, str]] = {}
    spans: dict[int, list[float] | None] = {}
    kv: dict[str, str] = {}
    processing: list[list[str]] = []
    sensors: list[str] = []
    user: list[str] = []
    instr: list[str] = []
    comments: list[str] = []
    lat = lon = None
    lat_src = lon_src = None
    nmea_utc = None
    for ln in header:
        s = ln.strip()
        if not s:
            continue
        if s.startswith("*"):
            (user if s.startswith("**") else instr).append(s.lstrip("*").strip())
            m = _POS_RE.match(s)
            if m:
                key = m.group(1).lower()
                is_lat = key.startswith("lat")
                val = parse_latlon(m.group(2), is_latitude=is_lat)
                # a '**' user line wins over the NMEA line only when the NMEA one is missing/unreadable
                if is_lat and val is not None and (lat is None or lat_src == "nmea" and s.startswith("**")):
                    lat, lat_src = val, ("user" if s.startswith("**") else "nmea")
                elif not is_lat and val is not None and (lon is None or lon_src == "nmea" and s.startswith("**")):
                    lon, lon_src = val, ("user" if s.startswith("**") else "nmea")
            m = re.match(r"^\*\s*NMEA UTC \(Time\)\s*=\s*(.+)$", s, re.I)
            if m:
                nmea_utc = _parse_time(m.group(1))[0]
            continue
        if not s.startswith("#"):
            continue
        if re.match(r"^#\s*</?[A-Za-z!]", s):
            continue  # XML sensor block (SeaSoft 7)
        m = _NAME_RE.match(s)
        if m:
            names[int(m.group(1))] = (m.group(2).strip(), m.group(3).strip())
            continue
        m = _SPAN_RE.match(s)
        if m:
            try:
                lo, hi = (float(x) for x in m.group(2).split(",")[:2])
                spans[int(m.group(1))] = [lo, hi]
            except ValueError:
                spans[int(m.group(1))] = None
            continue
        if re.match(r"^#\s*sensor\s+\d+\s*=", s):
            sensors.append(s.lstrip("#").strip())
            continue
        m = _KV_RE.match(s)
        if m:
            key, val = m.group(1).strip(), m.group(2).strip()
            if key.lower() in _RESERVED:
                kv[key.lower()] = val
            elif re.fullmatch(r"[A-Za-z][A-Za-z0-9_]*", key):
                processing.append([key, val])  # '<module>_<key> = value' SeaSoft processing line
            else:
                comments.append(s.lstrip("#").strip())
        else:
            comments.append(s.lstrip("#").strip())

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
        warnings.warn(f"{path.name}: header lacks '# name' lines for channel(s) {missing}; named 'col<i>'", stacklevel=2)
    short = [names.get(i, (f"col{i}", ""))[0] for i in range(nquan)]
    columns = _unique_names(short)

    data, bad_lines = _parse_rows(lines[end + 1:], nquan, path, end + 2)
    if bad_lines:
        warnings.warn(
            f"{path.name}: dropped {len(bad_lines)} unreadable data line(s) (first at line {bad_lines[0]})",
            stacklevel=2,
        )
    if data.shape[0] == 0:
        raise InputError(f"{path}: CNV file has no readable data rows after '*END*'")

    bad_flag = CNV_DEFAULT_BAD_FLAG
    if "bad_flag" in kv:
        try:
            bad_flag = float(kv["bad_flag"])
        except ValueError:
            pass
    is_bad = np.isclose(data, bad_flag, rtol=1e-6, atol=0.0) if bad_flag != 0 else (data == 0)
    n_bad = int(is_bad.sum())
    data = np.where(is_bad, np.nan, data)
    df = pd.DataFrame(data, columns=columns)

    channels = []
    for i in range(nquan):
        nm, long = names.get(i, (f"col{i}", ""))
        um = _UNITS_RE.search(long)
        units = um.group(1).strip() if um else ""
        channels.append({"index": i, "name": nm, "column": columns[i], "long_name": long,
                         "units": units, "span": spans.get(i)})
    start_iso, start_note = _parse_time(kv.get("start_time", ""))
    interval = None
    if "interval" in kv:
        mi = re.match(r"^\s*([A-Za-z_ ]+?)\s*:\s*([-+0-9.eE]+)", kv["interval"])
        if mi:
            interval = {"kind": mi.group(1).strip(), "value": float(mi.group(2))}

    def _int(k: str) -> int | None:
        try:
            return int(kv[k])
        except (KeyError, ValueError):
            return None

    nvalues_declared = _int("nvalues")
    if nvalues_declared is not None and nvalues_declared != data.shape[0] + len(bad_lines):
        warnings.warn(f"{path.name}: header declares nvalues = {nvalues_declared} but the file holds "
                      f"{data.shape[0] + len(bad_lines)} data rows (truncated or edited file)", stacklevel=2)
    attrs: dict[str, Any] = {
        "source": str(path),
        "format": "Sea-Bird SeaSoft .cnv",
        "instrument": instr[0] if instr else None,
        "channels": channels,
        "units": {c["column"]: c["units"] for c in channels},
        "latitude_deg": lat,
        "longitude_deg": lon,
        "position_source": {"latitude": lat_src, "longitude": lon_src},
        "start_time_utc": start_iso,
        "start_time_note": start_note,
        "nmea_utc": nmea_utc,
        "interval": interval,
        "bad_flag": bad_flag,
        "bad_values": n_bad,
        "processing": processing,
        "sensors": sensors,
        "user_header": user,
        "instrument_header": instr,
        "header_comments": comments,
        "nquan": nquan,
        "nvalues_declared": nvalues_declared,
        "nvalues": int(data.shape[0]),
        "truncated": bool(nvalues_declared is not None and nvalues_declared > data.shape[0] + len(bad_lines)),
        "rows_dropped": bad_lines,
    }
    df.attrs.update(attrs)
    return df


# ------------------------------------------------------------------------------ CNV as a sensor source
#: SeaSoft short names of the primary CTD channels, in order of preference -> unit for hadal.ingest.units
CNV_PRESSURE = (("prDM", "dbar"), ("prdM", "dbar"), ("prSM", "dbar"), ("prM", "dbar"), ("pr", "dbar"))
CNV_TEMPERATURE = (("t090C", "degC_its90"), ("tv290C", "degC_its90"), ("t090", "degC_its90"),
                   ("t068C", "degC_its68"), ("tv268C", "degC_its68"), ("t068", "degC_its68"))
CNV_CONDUCTIVITY = (("c0S/m", "S/m"), ("c0mS/cm", "mS/cm"), ("c0uS/cm", "uS/cm"))


def cnv_time_ns(df: pd.DataFrame) -> tuple[np.ndarray, str]:
    """Sample times (int64 ns since the Unix epoch) of a :func:`read_cnv` frame and how they were found.

    ``timeS`` (elapsed s) + ``start_time``; ``timeY`` (Unix s); ``timeJ`` (day of year, 1 = Jan 1 00:00, of
    the start year); else a time-interval file (``# interval = seconds: dt``) gives ``start + i * dt``.
    Pressure-binned files without a time channel raise :class:`InputError`.
    """
    a = df.attrs
    path = a.get("source", "cnv")
    start = pd.Timestamp(a["start_time_utc"]) if a.get("start_time_utc") else None
    if "timeY" in df:
        return (df["timeY"].to_numpy(dtype=np.float64) * 1e9).round().astype(np.int64), "timeY (Unix seconds)"
    if start is not None and "timeS" in df:
        return start.value + (df["timeS"].to_numpy(dtype=np.float64) * 1e9).round().astype(np.int64), \
            "start_time + timeS"
    if start is not None and "timeJ" in df:
        jan1 = pd.Timestamp(year=start.year, month=1, day=1, tz="UTC").value
        return jan1 + ((df["timeJ"].to_numpy(dtype=np.float64) - 1.0) * 86400e9).round().astype(np.int64), \
            "start year + timeJ"
    iv = a.get("interval") or {}
    if start is not None and iv.get("kind") == "seconds" and iv.get("value", 0) > 0:
        dt_ns = int(round(iv["value"] * 1e9))
        return start.value + np.arange(len(df), dtype=np.int64) * dt_ns, f"start_time + i * {iv['value']:g} s"
    raise InputError(f"{path}: no time channel (timeS/timeJ/timeY or a 'seconds' interval with start_time); "
                     f"a pressure-binned cast cannot be put on a time base")


def cnv_sensor_samples(df: pd.DataFrame, name: str = "ctd") -> Any:
    """A :func:`read_cnv` frame as the CTD's :class:`~hadal.ingest.csv_reader.SensorSamples` (primary
    pressure/temperature/conductivity channels, converted to hadal units; conversions recorded)."""
    from hadal.ingest.csv_reader import SensorSamples
    from hadal.ingest.units import convert

    path = df.attrs.get("source", "cnv")
    t, how = cnv_time_ns(df)
    values, conversions, used = {}, [], {}
    for var, table in (("pressure_ctd_dbar", CNV_PRESSURE), ("temperature_its90_degc", CNV_TEMPERATURE),
                       ("conductivity_s_m", CNV_CONDUCTIVITY)):
        col = next(((c, u) for c, u in table if c in df.columns), None)
        if col is None:
            raise InputError(f"{path}: no {var.split('_')[0]} channel (looked for {', '.join(c for c, _ in table)})")
        v, rec = convert(df[col[0]].to_numpy(dtype=np.float64), col[1], var)
        values[var] = v
        used[var] = col[0]
        if rec:
            conversions.append({**rec, "sensor": name, "source": f"cnv:{Path(path).name}:{col[0]}"})
    stats = {"rows": int(len(df)), "time": how, "channels": used, "bad_values": int(df.attrs.get("bad_values", 0)),
             "rows_dropped": len(df.attrs.get("rows_dropped", []))}
    return SensorSamples(name, t, values, f"cnv:{Path(path).name}", stats, conversions)
