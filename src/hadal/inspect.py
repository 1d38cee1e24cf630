"""``hadal inspect``: what a file is (by content, :func:`hadal.formats.detect`) and what is in it.

Each kind has a describer in the module that reads it (MCAP topics and counts, CSV columns, .cnv channels
and header position, multibeam pings/beams/extent, grid size/resolution/CRS, point-cloud extent); this
module only dispatches and never raises for a bad file: the problem is reported in the ``error`` field.
"""

from __future__ import annotations

import importlib
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


def inspect_file(path: str | Path) -> dict[str, Any]:
    """Describe one file: ``path``, ``kind``, ``compression``, ``source`` (the dive.yaml list it belongs to),
    ``description``, the kind's own fields, and ``error`` (one line) when the file cannot be read."""
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
    try:
        info = fn(p)
    except HadalError as exc:
        out["error"] = str(exc)
    except Exception as exc:  # noqa: BLE001 - inspect reports every file; an unexpected failure is one line too
        out["error"] = f"{p}: cannot be read ({type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''})"
    else:
        if fk.kind in ("geotiff", "netcdf"):  # a raster is a prior map or laser bathymetry by its cell size
            from hadal.dive_init import grid_role

            out["source"] = grid_role(info or {})
        elif fk.kind == "xyz":
            from hadal.dive_init import xyz_role

            out["source"] = xyz_role(info or {})
        for k, v in (info or {}).items():  # the detector's fields stay; a describer's own "kind" becomes "format"
            if k in _RESERVED:
                if k == "kind" and "format" not in info:
                    out["format"] = v
                continue
            out[k] = v
    return out


def summary_line(info: dict[str, Any]) -> str:
    """A short human summary of :func:`inspect_file`'s result for the terminal table."""
    if info.get("error"):
        return info["error"]
    keys = ("instrument", "format", "reader", "profile", "topics", "channels", "messages", "scans", "rows",
            "pings", "beams", "soundings", "points", "shape", "resolution", "resolution_m", "crs", "crs_kind",
            "extent", "lon_range", "lat_range", "depth_range_m", "z_range", "pressure_range_dbar",
            "latitude_deg", "longitude_deg", "start_time_utc", "time_span", "binned")
    parts = []
    for k in keys:
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
