"""``hadal inspect``: what a file is (by content, :func:`hadal.formats.detect`) and what is in it.

Each kind has a describer in the module that reads it (MCAP topics and counts, CSV columns, .cnv channels
and header position, multibeam pings/beams/extent, grid size/resolution/CRS, point-cloud extent); this
module only dispatches and never raises for a bad file: the problem is reported in the ``error`` field.

Memory: a describer that decodes a file's content (every one but the CSV's, which reads bounded chunks) takes
``memory_limit_bytes`` and holds what it decodes against it as it decodes (:class:`hadal.budget.DecodeBudget`):
``hadal inspect --config`` passes the configuration's ``resources.max_memory_gb``, so a compression bomb is a
one-line ``error`` and a non-zero exit, not an exhausted machine.
"""

from __future__ import annotations

import importlib
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hadal.errors import HadalError
from hadal.formats import detect

#: kind -> candidate "module:function" describers (the first importable one is used)
DESCRIBERS: dict[str, tuple[str, ...]] = {
    "mcap": ("hadal.ingest.suggest:describe_mcap", "hadal.ingest.mcap_reader:describe_mcap"),
    "csv": ("hadal.ingest.suggest:describe_csv", "hadal.ingest.csv_reader:describe_csv"),
    "cnv": ("hadal.ingest.cnv:describe_cnv",),
    "seabird_hex": ("hadal.ingest.seabird_hex:describe_hex",),
    "xyz": ("hadal.grid.sonar:describe_multibeam",),
    "gsf": ("hadal.grid.sonar:describe_multibeam",),
    "kmall": ("hadal.grid.sonar:describe_multibeam",),
    "em_all": ("hadal.grid.sonar:describe_multibeam",),
    "s7k": ("hadal.grid.sonar:describe_multibeam",),
    "geotiff": ("hadal.grid.describe:describe_grid",),
    "netcdf": ("hadal.grid.describe:describe_grid",),
    "ply": ("hadal.grid.describe:describe_point_cloud",),
    "pcd": ("hadal.grid.describe:describe_point_cloud",),
    "las": ("hadal.grid.describe:describe_point_cloud",),
}


_RESERVED = ("path", "kind", "compression", "source", "description", "bytes")


def describer(kind: str) -> Callable[[Path], dict[str, Any]] | None:
    """The describe function for ``kind``, or ``None`` when hadal has none."""
    for spec in DESCRIBERS.get(kind, ()):
        mod, fn = spec.split(":")
        try:
            f = getattr(importlib.import_module(mod), fn, None)
        except ImportError:
            continue
        if callable(f):
            return f
    return None


def inspect_file(path: str | Path, *, memory_limit_bytes: float | None = None) -> dict[str, Any]:
    """Describe one file: ``path``, ``kind``, ``compression``, ``source`` (the dive.yaml list it belongs to),
    ``description``, the kind's own fields, and ``error`` (one line) when the file cannot be read (its read
    would pass ``memory_limit_bytes``, default :func:`hadal.budget.memory_limit_bytes`, included)."""
    p = Path(path)
    out: dict[str, Any] = {"path": str(p)}
    try:
        fk = detect(p)
    except HadalError as exc:
        return {**out, "kind": "unreadable", "error": str(exc)}
    out.update(kind=fk.kind, compression=fk.compression, source=fk.source, description=fk.description,
               bytes=p.stat().st_size)
    fn = describer(fk.kind)
    if fn is None:
        return out
    import inspect as _signature

    budget = {"memory_limit_bytes": memory_limit_bytes} if "memory_limit_bytes" in _signature.signature(
        fn).parameters else {}
    try:
        info = fn(p, **budget)
    except HadalError as exc:
        out["error"] = str(exc)
    except Exception as exc:  # noqa: BLE001 - inspect reports every file; an unexpected failure is one line too
        out["error"] = f"{p}: cannot be read ({type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''})"
    else:
        if fk.kind in ("geotiff", "netcdf"):  # a raster is a prior map or laser bathymetry by its cell size
            from hadal.roles import grid_role

            out["source"] = grid_role(info or {})
        elif fk.kind == "xyz":
            from hadal.roles import xyz_role

            out["source"] = xyz_role(info or {})
        for k, v in (info or {}).items():  # the detector's fields stay; a describer's own "kind" becomes "format"
            if k in _RESERVED:
                if k == "kind" and "format" not in info:
                    out["format"] = v
                continue
            out[k] = v
        if ov := overview(out):
            out["overview"] = ov
    return out


def _decimals(step: float, *, lo: int = 0, hi: int = 9) -> int:
    """Decimals that resolve a tenth of ``step`` (a cell size, or the precision of a sounding), within [lo, hi]."""
    if not (isinstance(step, (int, float)) and math.isfinite(step) and step > 0):
        return hi
    return int(min(hi, max(lo, math.ceil(-math.log10(step / 10.0)))))


def _pair(v: Any) -> tuple[float, float] | None:
    if isinstance(v, dict):
        v = [v.get("min"), v.get("max")]
    if isinstance(v, (list, tuple)) and len(v) == 2:
        try:
            a, b = float(v[0]), float(v[1])
        except (TypeError, ValueError):
            return None
        if math.isfinite(a) and math.isfinite(b):
            return a, b
    return None


def _parse_time(v: Any) -> Any:
    import datetime as dt

    if not isinstance(v, str) or not v:
        return None
    try:
        t = dt.datetime.fromisoformat(v.replace("Z", "+00:00"))
    except ValueError:
        return None
    return t if t.tzinfo is not None else t.replace(tzinfo=dt.UTC)


def _time_span(info: dict[str, Any]) -> str | None:
    """``start to end (duration)`` as mbinfo's Start/End of Data (ISO 8601 UTC, milliseconds when the file has them)."""
    start = info.get("time_start") or info.get("start_time") or info.get("start_time_utc") \
        or info.get("time_coverage_start")
    end = info.get("time_end") or info.get("end_time") or info.get("time_coverage_end")
    t0, t1 = _parse_time(start), _parse_time(end)
    if t0 is None:
        return None
    if t1 is None:
        return f"from {start}"
    secs = (t1 - t0).total_seconds()
    dur = f"{secs:.3f} s" if secs < 60 else (f"{secs / 60:.1f} min" if secs < 7200 else f"{secs / 3600:.2f} h")
    return f"{start} to {end} ({dur})"


def _bounds(info: dict[str, Any]) -> str | None:
    """Longitude/latitude (or x/y) limits, at the precision of what they bound: a grid's tenth of a cell, soundings
    to about 0.1 m (6 decimals of a degree, 1 of a metre), not the float's 17 digits."""
    lon, lat = _pair(info.get("longitude_deg") or info.get("lon_range")), \
        _pair(info.get("latitude_deg") or info.get("lat_range"))
    if lon and lat:
        return f"lon {lon[0]:.6f} to {lon[1]:.6f}, lat {lat[0]:.6f} to {lat[1]:.6f} (degrees)"
    x, y = _pair(info.get("x_m")), _pair(info.get("y_m"))
    if x and y:
        return f"x {x[0]:.1f} to {x[1]:.1f} m, y {y[0]:.1f} to {y[1]:.1f} m"
    ext = info.get("extent")
    if isinstance(ext, dict) and all(k in ext for k in ("xmin", "xmax", "ymin", "ymax")):
        cell: dict[str, Any] = info["cell_size"] if isinstance(info.get("cell_size"), dict) else {}
        crs: dict[str, Any] = info["crs"] if isinstance(info.get("crs"), dict) else {}
        geographic = (crs.get("kind") or info.get("crs_kind")) == "geographic" or cell.get("units") == "degrees"
        try:
            step = min(abs(float(cell["x"])), abs(float(cell["y"])))
        except (KeyError, TypeError, ValueError):
            step = 1e-6 if geographic else 0.01  # point clouds: about 0.1 m / 1 mm
        nd = _decimals(step, hi=9 if geographic else 3)
        unit = "degrees" if geographic else (cell.get("units") or "m")
        xs, ys = ("lon", "lat") if geographic else ("x", "y")
        return (f"{xs} {float(ext['xmin']):.{nd}f} to {float(ext['xmax']):.{nd}f}, "
                f"{ys} {float(ext['ymin']):.{nd}f} to {float(ext['ymax']):.{nd}f} ({unit})")
    return None


def _depths(info: dict[str, Any]) -> tuple[str, str] | None:
    """``("depth", ...)`` (soundings, positive down), ``("z", ...)`` (grids, clouds, with their ``positive``) or
    ``("pressure", ...)`` range, to the centimetre (millibar)."""
    d = _pair(info.get("depth_m")) or _pair(info.get("depth_range_m"))
    if d:
        return "depth", f"{d[0]:.2f} to {d[1]:.2f} m"
    z = info.get("z")
    zr = _pair(z) if isinstance(z, dict) else _pair(info.get("z_range"))
    if zr:
        units = (z.get("units") if isinstance(z, dict) else None) or "m"
        pos = f", positive {z['positive']}" if isinstance(z, dict) and z.get("positive") else ""
        return "z", f"{zr[0]:.2f} to {zr[1]:.2f} {units}{pos}"
    p = _pair(info.get("pressure_range_dbar"))
    return ("pressure", f"{p[0]:.3f} to {p[1]:.3f} dbar") if p else None


def _counts(info: dict[str, Any]) -> str | None:
    """mbinfo's totals: pings x beams, good soundings (share) and the rest; grid cells; points; messages; scans."""
    pings, per, good, dropped = (info.get(k) for k in ("pings", "beams_per_ping", "soundings", "dropped"))
    if isinstance(good, int):
        total = good + (dropped if isinstance(dropped, int) else 0)
        head = f"{pings} ping(s) x {per} beams = " if isinstance(pings, int) and isinstance(per, int) else (
            f"{pings} ping(s), " if isinstance(pings, int) else "")
        share = f" ({100.0 * good / total:.2f} %)" if total else ""
        return f"{head}{total} beams, {good} good{share}" + (f", {dropped} without a depth" if dropped else "")
    size = info.get("size")
    if isinstance(size, dict) and "nx" in size:
        nod = info.get("nodata_fraction")
        return f"{size['nx']} x {size['ny']} cells" + (f", {100.0 * nod:.1f} % no data" if isinstance(
            nod, (int, float)) else "")
    for key, what in (("points", "points"), ("message_count", "messages"), ("scans", "scans"), ("rows", "rows")):
        if isinstance(info.get(key), int):
            return f"{info[key]} {what}"
    return None


def overview(info: dict[str, Any]) -> dict[str, str]:
    """What ``mbinfo`` prints first, for any kind: ``time`` (start to end, duration), ``bounds`` (at the precision of
    the data), ``depth`` (or z/pressure range), ``counts`` (pings x beams, good soundings; cells; points; ...); only
    those the describer gave."""
    depth = _depths(info)
    out = {"time": _time_span(info), "bounds": _bounds(info), **({depth[0]: depth[1]} if depth else {}),
           "counts": _counts(info)}
    return {k: v for k, v in out.items() if v}


def summary_line(info: dict[str, Any]) -> str:
    """A short human summary of :func:`inspect_file`'s result for the terminal table: the :func:`overview` first,
    then the kind's own fields."""
    if info.get("error"):
        return info["error"]
    ov = overview(info)
    done = {"time": ("start_time_utc", "time_span"),
            "bounds": ("extent", "lon_range", "lat_range", "latitude_deg", "longitude_deg"),
            "depth": ("depth_range_m",), "z": ("z_range",), "pressure": ("pressure_range_dbar",),
            "counts": ("pings", "beams", "soundings", "points", "scans", "rows", "messages")}
    skip = {k for name in ov for k in done[name]}
    keys = ("instrument", "format", "reader", "profile", "topics", "channels", "messages", "scans", "rows",
            "pings", "beams", "soundings", "points", "shape", "resolution", "resolution_m", "crs", "crs_kind",
            "extent", "lon_range", "lat_range", "depth_range_m", "z_range", "pressure_range_dbar",
            "latitude_deg", "longitude_deg", "start_time_utc", "time_span", "binned")
    parts = [f"{k}: {v}" for k, v in ov.items()]
    for k in keys:
        if k in skip:
            continue
        v = info.get(k)
        if v in (None, "", [], {}):
            continue
        if isinstance(v, list) and v and isinstance(v[0], dict):
            names = [str(x.get("topic") or x.get("name") or x.get("column") or "") for x in v]
            v = f"{len(v)}: " + ", ".join(n for n in names[:8] if n) + (" ..." if len(v) > 8 else "")
        elif isinstance(v, list):
            v = ", ".join(str(x) for x in v[:8]) + (" ..." if len(v) > 8 else "")
        elif isinstance(v, dict):
            v = ", ".join(f"{a}={b}" for a, b in list(v.items())[:6])
        elif isinstance(v, float):
            v = f"{v:.6g}"
        parts.append(f"{k}: {v}")
    return "; ".join(parts) if parts else info.get("description", "")
