"""What is in a grid or point-cloud file, as JSON-serialisable dicts (for ``hadal inspect``).

:func:`describe_grid` and :func:`describe_point_cloud` read the file with the same readers as the
``grid`` stage, so what they report is what the pipeline will see. Failures are one-line
:class:`hadal.errors.InputError` naming the file.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import Any

import numpy as np

from hadal.errors import InputError
from hadal.grid.readers import (
    GridCRSWarning,
    looks_metric,
    read_grid,
    read_point_cloud_meta,
    reader_of,
    sniff_kind,
)


def _f(v) -> float | None:
    v = float(v)
    return v if np.isfinite(v) else None


def describe_grid(path: str | Path, *, variable: str | None = None, format: str | None = None,
                  crs: str | None = None, z_positive: str | None = None, z_units: str | None = None,
                  memory_limit_bytes: float | None = None) -> dict[str, Any]:
    """Format, reader and version, size, cell size, CRS (and ``looks_metric``: a geographic tag that only
    makes sense in metres), registration, extent (longitudes -180..180 for a 0-360 grid), z range in metres
    (``z.units_source``: from the file, converted, or assumed), sign (``z.positive``, ``z.sign_guessed`` when
    the file says nothing), ``z.land_fraction`` and ``z.no_seafloor`` (why a land DEM has nothing to grid)
    and nodata fraction of a grid."""
    from hadal.grid.prior import depth_and_land, describe_crs, is_guessed, native_resolution_m, no_seafloor
    from hadal.grid.prior import z_positive as sign_of

    p = Path(path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", GridCRSWarning)
        da = read_grid(p, variable=variable, format=format, crs=crs, z_units=z_units, max_bytes=memory_limit_bytes)
    a = da.attrs
    z = da.values[np.isfinite(da.values)]
    dx, dy = float(a.get("cell_size_x", 0)), float(a.get("cell_size_y", 0))
    h = 0.5 if a.get("registration") == "pixel" else 0.0
    xmin, xmax = float(da.x[0]) - h * dx, float(da.x[-1]) + h * dx
    ymin, ymax = float(da.y[0]) - h * dy, float(da.y[-1]) + h * dy
    pos, reason = sign_of(da, z_positive)
    geo_tag = a.get("crs_override", "") == "geographic tag ignored: local metric frame"
    tagged_geographic = a["crs_kind"] == "geographic" or geo_tag
    try:
        res_m = native_resolution_m(da)
    except InputError:
        res_m = None
    out: dict[str, Any] = {
        "path": str(p), "kind": "grid", "detected_as": sniff_kind(p), "format": a.get("format", ""),
        "reader": a.get("reader", ""), "variable": a.get("var_name", ""),
        "size": {"nx": int(da.sizes["x"]), "ny": int(da.sizes["y"]), "cells": int(da.size)},
        "cell_size": {"x": dx, "y": dy, "units": "degrees" if a["crs_kind"] == "geographic" else "m"},
        "resolution_m": res_m,
        "registration": a.get("registration", ""),
        "crs": {"kind": a["crs_kind"], "name": describe_crs(da), "wkt": a.get("crs_wkt", ""),
                "looks_metric": bool(geo_tag or (tagged_geographic and looks_metric(
                    xmax - xmin, ymax - ymin, float(z.max() - z.min()) if z.size else float("nan")))),
                "note": a.get("crs_override", a.get("crs_note", ""))},
        "extent": {"xmin": xmin, "xmax": xmax, "ymin": ymin, "ymax": ymax},
        "z": {"min": _f(z.min()) if z.size else None, "max": _f(z.max()) if z.size else None,
              "units": a.get("units", ""), "units_in_file": a.get("z_units_file", ""),
              "units_source": a.get("z_units_source", ""), "units_assumed": bool(a.get("z_units_assumed", 0)),
              "positive": pos, "sign_reason": reason, "sign_guessed": is_guessed(reason),
              "land_fraction": float(depth_and_land(z, pos)[1].mean()) if z.size else 0.0,
              "no_seafloor": no_seafloor(p.name, da, pos, reason)},
        "nodata": a.get("nodata", "") if a.get("nodata", "") != "" else None,
        "nodata_fraction": float(a.get("nodata_fraction", 0.0)),
    }
    if a.get("lon_convention"):
        out["lon_convention"] = a["lon_convention"]
    if caught:
        out["warnings"] = [str(w.message) for w in caught]
    return out


def describe_point_cloud(path: str | Path, *, format: str | None = None, columns: list[str] | None = None,
                         z_positive: str | None = None, memory_limit_bytes: float | None = None) -> dict[str, Any]:
    """Format, reader and version, point count, extent, z range and sign guess of a point cloud (read against the
    memory budget ``memory_limit_bytes``, :func:`hadal.grid.readers.read_point_cloud_meta`)."""
    import xarray as xr

    from hadal.grid.prior import z_positive as sign_of
    from hadal.grid.readers import _kind_of

    p = Path(path)
    kind = _kind_of(p, format)
    pts, meta = read_point_cloud_meta(p, format=format, columns=columns,
                                      hints={"z_positive": z_positive} if z_positive else None,
                                      memory_limit_bytes=memory_limit_bytes)
    ok = np.isfinite(pts).all(axis=1)
    q = pts[ok]
    if meta.get("z_positive"):  # LAS/PCD: the format's convention (hadal.grid.clouds), not the values' sign
        pos, reason = meta["z_positive"], meta["z_positive_from"]
    else:
        pos, reason = sign_of(xr.DataArray(q[:, 2]), z_positive) if len(q) else ("up", "no finite points")
    ext = {k: (_f(f(q[:, i])) if len(q) else None) for i, ax in enumerate("xyz")
           for k, f in ((f"{ax}min", np.min), (f"{ax}max", np.max))}
    area = ((ext["xmax"] - ext["xmin"]) * (ext["ymax"] - ext["ymin"])) if len(q) else 0.0
    out = {
        "path": str(p), "kind": "point_cloud", "format": kind, "reader": reader_of(kind),
        "points": int(len(pts)), "points_nonfinite": int((~ok).sum()),
        "extent": {k: ext[k] for k in ("xmin", "xmax", "ymin", "ymax")},
        "z": {"min": ext["zmin"], "max": ext["zmax"], "positive": pos, "sign_reason": reason},
        "density_per_m2": (float(len(q) / area) if area > 0 else None),
    }
    if meta.get("crs_kind") not in (None, "none"):  # extent in metres (x/y in xy_crs_wkt) or lon/lat degrees
        out["crs"] = {"kind": meta["crs_kind"], "name": meta.get("crs_name", ""), "wkt": meta.get("xy_crs_wkt", ""),
                      "from": meta.get("crs_from", "")}
        out["units"] = {"horizontal": meta.get("horizontal_units"), "vertical": meta.get("vertical_units"),
                        "vertical_from": meta.get("z_units_from")}
    return out
