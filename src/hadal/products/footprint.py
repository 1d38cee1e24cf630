"""The true footprint of a grid in the laser survey's local frame (laser grids, landing maps), for ACDD.

A laser grid's x/y are metres in the survey's own frame, which ``dive.yaml`` ``laser_frame`` places on the Earth
(origin latitude/longitude, heading of +y). Its footprint is the rectangle of its mapped cells (cell edges, not
centres) turned by the heading: ACDD ``geospatial_bounds`` is that polygon in WGS 84 (WKT, latitude first as
EPSG:4326 orders its axes, like every hadal product), ``geospatial_lat/lon_min/max`` its extremes
(:func:`hadal.products.geo_landing.frame_to_lonlat`, the transform of the landing sites and the laser COGs).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import xarray as xr


def _mapped_mask(ds: xr.Dataset) -> np.ndarray | None:
    """Cells of the (y, x) grid holding a value in any floating (y, x) layer (all cells when none has NaNs)."""
    mask = None
    for v in ds.data_vars.values():
        if v.dims == ("y", "x") and v.dtype.kind == "f":
            m = np.isfinite(np.asarray(v.values))
            mask = m if mask is None else (mask | m)
    return mask


def grid_footprint(ds: xr.Dataset, laser_frame: Any) -> tuple[tuple[float, float], dict[str, Any]] | None:
    """((lon, lat) of the footprint's centre, ACDD ``geospatial_*`` attributes) of the mapped cells of the
    ``(y, x)`` grid ``ds`` in ``laser_frame``; ``None`` when no cell is mapped or the axes are missing."""
    from hadal.products.geo_landing import frame_to_lonlat

    out = _footprint(ds, lambda x, y: frame_to_lonlat(x, y, laser_frame))
    if out is None:
        return None
    centre, attrs, (w, h) = out
    attrs["hadal_georeference"] = (
        f"x/y in the laser survey's local frame: origin {laser_frame.origin_latitude_deg:.8f} N "
        f"{laser_frame.origin_longitude_deg:.8f} E, +y at {float(laser_frame.heading_deg):g} deg from true north "
        f"(dive.yaml laser_frame); geospatial_bounds is the mapped {w:.3f} m x {h:.3f} m rectangle")
    return centre, attrs


def crs_grid_footprint(ds: xr.Dataset, crs_wkt: str) -> tuple[tuple[float, float], dict[str, Any]] | None:
    """:func:`grid_footprint` of a grid whose x/y are in the projected CRS ``crs_wkt`` (its grid mapping), for a
    grid without latitude/longitude variables (a point cloud's own UTM grid): the mapped rectangle's corners
    transformed to WGS 84 with pyproj."""
    from pyproj import CRS, Transformer

    tr = Transformer.from_crs(CRS.from_wkt(crs_wkt), CRS.from_epsg(4326), always_xy=True)
    out = _footprint(ds, lambda x, y: tuple(np.asarray(v, float) for v in tr.transform(x, y)))
    return None if out is None else out[:2]


def _footprint(ds: xr.Dataset, to_lonlat: Any) -> tuple[tuple[float, float], dict[str, Any], tuple[float, float]] | None:
    if "x" not in ds.coords or "y" not in ds.coords or ds.sizes.get("x", 0) < 1 or ds.sizes.get("y", 0) < 1:
        return None
    x, y = np.asarray(ds["x"].values, float), np.asarray(ds["y"].values, float)
    mask = _mapped_mask(ds)
    if mask is not None:
        if not mask.any():
            return None
        rows, cols = np.flatnonzero(mask.any(axis=1)), np.flatnonzero(mask.any(axis=0))
    else:
        rows, cols = np.arange(y.size), np.arange(x.size)
    dx = float(np.median(np.abs(np.diff(x)))) if x.size > 1 else 0.0
    dy = float(np.median(np.abs(np.diff(y)))) if y.size > 1 else 0.0
    x0, x1 = float(x[cols].min()) - dx / 2, float(x[cols].max()) + dx / 2
    y0, y1 = float(y[rows].min()) - dy / 2, float(y[rows].max()) + dy / 2
    cx, cy = np.array([x0, x1, x1, x0, x0]), np.array([y0, y0, y1, y1, y0])
    lon, lat = to_lonlat(cx, cy)
    clon, clat = to_lonlat(np.array([(x0 + x1) / 2]), np.array([(y0 + y1) / 2]))
    ring = ", ".join(f"{la:.8f} {lo:.8f}" for la, lo in zip(lat, lon, strict=True))
    attrs = {"geospatial_bounds": f"POLYGON (({ring}))", "geospatial_bounds_crs": "EPSG:4326",
             "geospatial_lat_min": float(lat.min()), "geospatial_lat_max": float(lat.max()),
             "geospatial_lon_min": float(lon.min()), "geospatial_lon_max": float(lon.max()),
             "geospatial_lat_units": "degrees_north", "geospatial_lon_units": "degrees_east",
             "geospatial_lat_resolution": f"{dy:g} m", "geospatial_lon_resolution": f"{dx:g} m"}
    return (float(clon[0]), float(clat[0])), attrs, (x1 - x0, y1 - y0)
