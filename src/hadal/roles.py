"""Which ``dive.yaml`` source list a file belongs to when its format alone does not say: a raster is a prior
map or laser bathymetry by its cell size, an xyz point set ship soundings or a laser scan by its coordinates and
extent. Read from a describer's report (:mod:`hadal.inspect`); used by ``hadal inspect`` and ``hadal init``
(which writes the choice into ``dive.yaml`` where the user can change it)."""

from __future__ import annotations

import math
from typing import Any

#: rasters with cells at most this size (m) are laser (micro-)bathymetry, coarser ones prior maps
LASER_MAX_CELL_M = 0.5
#: metric xyz point sets spanning less than this (m) are laser scans, wider ones ship soundings
LASER_MAX_EXTENT_M = 200.0


def xyz_role(info: dict[str, Any]) -> str:
    """``multibeam`` or ``laser`` for an xyz text file: geographic coordinates or a wide extent are soundings;
    a metric point set narrower than :data:`LASER_MAX_EXTENT_M` is a laser scan."""
    if crs_kind(info) == "geographic" or lonlat_centre(info) is not None:
        return "multibeam"
    ext = extent_m(info)
    return "laser" if ext is not None and ext < LASER_MAX_EXTENT_M else "multibeam"


def extent_m(info: dict[str, Any]) -> float | None:
    for key in ("x_range", "x_range_m"):
        xr_, yr_ = info.get(key), info.get(key.replace("x_", "y_"))
        if xr_ and yr_:
            return max(abs(xr_[1] - xr_[0]), abs(yr_[1] - yr_[0]))
    ext = info.get("extent")
    for a, b, c, d in (("x_min", "x_max", "y_min", "y_max"), ("xmin", "xmax", "ymin", "ymax")):
        if isinstance(ext, dict) and {a, b, c, d} <= set(ext) and all_finite(ext[a], ext[b], ext[c], ext[d]):
            return max(ext[b] - ext[a], ext[d] - ext[c])
    return None


def crs_kind(info: dict[str, Any]) -> str | None:
    crs = info.get("crs")
    return crs.get("kind") if isinstance(crs, dict) else info.get("crs_kind")


def grid_role(info: dict[str, Any]) -> str:
    """``laser`` for a metric raster with cells ≤ :data:`LASER_MAX_CELL_M`, else ``prior_grid``."""
    if crs_kind(info) == "geographic":
        return "prior_grid"
    res = info.get("resolution_m", info.get("resolution"))
    if isinstance(res, (list, tuple)):
        res = max(abs(float(r)) for r in res)
    try:
        return "laser" if res is not None and 0 < float(res) <= LASER_MAX_CELL_M else "prior_grid"
    except (TypeError, ValueError):
        return "prior_grid"


def all_finite(*v: Any) -> bool:
    return all(isinstance(x, (int, float)) and math.isfinite(x) for x in v)


def lonlat_centre(info: dict[str, Any]) -> tuple[float, float] | None:
    """Centre (lon, lat) of a file's geographic extent, from whichever form its describer reports."""
    for lo_key, la_key in (("longitude_deg", "latitude_deg"), ("lon_range", "lat_range"),
                           ("longitude_range", "latitude_range")):
        lo, la = info.get(lo_key), info.get(la_key)
        if isinstance(lo, (list, tuple)) and isinstance(la, (list, tuple)) and len(lo) == len(la) == 2 \
                and all_finite(*lo, *la):
            return (lo[0] + lo[1]) / 2, (la[0] + la[1]) / 2
    ext = info.get("extent") or {}
    if not isinstance(ext, dict):
        return None
    for keys in (("lon_min", "lon_max", "lat_min", "lat_max"), ("longitude_min", "longitude_max", "latitude_min",
                                                                 "latitude_max")):
        if set(keys) <= set(ext) and all_finite(*(ext[k] for k in keys)):
            return (ext[keys[0]] + ext[keys[1]]) / 2, (ext[keys[2]] + ext[keys[3]]) / 2
    if not {"xmin", "xmax", "ymin", "ymax"} <= set(ext) or not all_finite(*(ext[k] for k in ("xmin", "xmax", "ymin", "ymax"))):
        return None
    cx, cy = (ext["xmin"] + ext["xmax"]) / 2, (ext["ymin"] + ext["ymax"]) / 2
    kind = crs_kind(info)
    if kind == "geographic":
        return cx, cy
    crs: dict[str, Any] = info["crs"] if isinstance(info.get("crs"), dict) else {}
    if kind == "projected" and (crs.get("wkt") or crs.get("name")):
        try:
            from pyproj import CRS, Transformer

            src = CRS.from_user_input(crs.get("wkt") or crs.get("name"))
            lon, lat = Transformer.from_crs(src, "EPSG:4326", always_xy=True).transform(cx, cy)
            return (float(lon), float(lat)) if all_finite(lon, lat) else None
        except Exception:  # noqa: BLE001 - an unusable CRS just gives no position
            return None
    return None
