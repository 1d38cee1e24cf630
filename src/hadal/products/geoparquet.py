"""GeoParquet 1.1 on hadal's tables with positions, and GeoJSON (RFC 7946) tracks, with pyarrow and numpy only.

A table whose columns include one latitude and one longitude (found by their metadata: CF ``standard_name``
``latitude``/``longitude`` or units ``degrees_north``/``degrees_east``, as :func:`hadal.products.io.write_parquet`
completes them from the variable registry) gets a ``geometry`` column of WKB points (ISO/OGC Simple Features
WKB: byte order 1 = little endian, type 1 = Point, x = longitude, y = latitude, IEEE-754 float64; a row without a
finite position is a null geometry) and the file key-value metadata ``geo`` of GeoParquet 1.1.0
(https://geoparquet.org/releases/v1.1.0/): ``primary_column``, ``encoding`` WKB, ``geometry_types``, ``crs`` as
PROJJSON (OGC:CRS84, longitude/latitude on WGS 84), ``bbox``. GDAL/OGR, GeoPandas, DuckDB spatial and QGIS then
read the table as points.

:func:`track_geojson` is the navigation as a GeoJSON ``LineString`` (longitude, latitude, WGS 84, as RFC 7946
requires) with the dive's id, time span and position sources as properties, for ``ogrinfo``/QGIS/web maps.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from typing import Any

import numpy as np
import pyarrow as pa

GEOPARQUET_VERSION = "1.1.0"
GEOMETRY_COLUMN = "geometry"
#: WKB of one 2-D point: byte order (1 byte), geometry type (uint32), x, y (float64)
WKB_POINT_BYTES = 21
_WKB_POINT = np.dtype([("order", "u1"), ("type", "<u4"), ("x", "<f8"), ("y", "<f8")])
#: coordinate decimals in GeoJSON: 1e-7 degree is 1.1 cm, below any position uncertainty hadal reports
GEOJSON_DECIMALS = 7


def wkb_points(x: Any, y: Any) -> pa.BinaryArray:
    """Little-endian WKB points (x, y) as a pyarrow binary array; a pair with a non-finite member is null."""
    x, y = np.asarray(x, dtype="<f8").ravel(), np.asarray(y, dtype="<f8").ravel()
    if x.shape != y.shape:
        raise ValueError(f"wkb_points: {x.size} x values for {y.size} y values")
    ok = np.isfinite(x) & np.isfinite(y)
    rec = np.empty(int(ok.sum()), dtype=_WKB_POINT)
    rec["order"], rec["type"], rec["x"], rec["y"] = 1, 1, x[ok], y[ok]
    offsets = np.zeros(x.size + 1, dtype=np.int32)
    offsets[1:] = np.cumsum(np.where(ok, WKB_POINT_BYTES, 0))
    validity = None if ok.all() else pa.py_buffer(np.packbits(ok, bitorder="little").tobytes())
    return pa.Array.from_buffers(pa.binary(), x.size, [validity, pa.py_buffer(offsets.tobytes()),
                                                       pa.py_buffer(rec.tobytes())], null_count=int((~ok).sum()))


def crs84_projjson() -> dict[str, Any]:
    """PROJJSON of OGC:CRS84 (WGS 84, longitude then latitude, degrees), GeoParquet's default CRS written out."""
    from pyproj import CRS

    return CRS.from_user_input("OGC:CRS84").to_json_dict()


def position_columns(fields: Mapping[str, Mapping[str, str]]) -> tuple[str, str] | None:
    """(longitude column, latitude column) of a table by its columns' metadata; ``lon``/``lat`` win when several
    are declared; None when the table has no single pair."""

    def pick(standard_name: str, units: str, preferred: str) -> str | None:
        found = [c for c, a in fields.items() if a.get("standard_name") == standard_name or a.get("units") == units]
        if preferred in found:
            return preferred
        return found[0] if len(found) == 1 else None

    lon, lat = pick("longitude", "degrees_east", "lon"), pick("latitude", "degrees_north", "lat")
    return (lon, lat) if lon and lat else None


def geo_metadata(lon: np.ndarray, lat: np.ndarray, *, lon_column: str, lat_column: str) -> dict[str, Any]:
    """The GeoParquet 1.1 ``geo`` metadata of a point column made from ``lon``/``lat``."""
    ok = np.isfinite(lon) & np.isfinite(lat)
    col: dict[str, Any] = {"encoding": "WKB", "geometry_types": ["Point"], "crs": crs84_projjson(), "edges": "planar"}
    if ok.any():
        col["bbox"] = [float(lon[ok].min()), float(lat[ok].min()), float(lon[ok].max()), float(lat[ok].max())]
    col["hadal:made_from"] = {"x": lon_column, "y": lat_column}
    return {"version": GEOPARQUET_VERSION, "primary_column": GEOMETRY_COLUMN, "columns": {GEOMETRY_COLUMN: col}}


def add_point_geometry(table: pa.Table, fields: Mapping[str, Mapping[str, str]]) -> tuple[pa.Table, dict | None]:
    """``table`` with a WKB ``geometry`` column from its position columns (last; one read back from an earlier
    product is made again from the positions), and the ``geo`` metadata; unchanged (and None) when the table has
    no position pair."""
    cols = position_columns({k: v for k, v in fields.items() if k != GEOMETRY_COLUMN})
    if cols is None:
        return table, None
    if GEOMETRY_COLUMN in table.column_names:
        table = table.remove_column(table.column_names.index(GEOMETRY_COLUMN))
    lon = np.asarray(table.column(cols[0]).to_numpy(zero_copy_only=False), dtype=float)
    lat = np.asarray(table.column(cols[1]).to_numpy(zero_copy_only=False), dtype=float)
    table = table.append_column(pa.field(GEOMETRY_COLUMN, pa.binary()), wkb_points(lon, lat))
    return table, geo_metadata(lon, lat, lon_column=cols[0], lat_column=cols[1])


def _thin(lon: np.ndarray, lat: np.ndarray, max_vertices: int) -> tuple[np.ndarray, np.ndarray]:
    """Every k-th finite position (the first and the last kept), at most ``max_vertices``; repeats dropped."""
    ok = np.isfinite(lon) & np.isfinite(lat)
    lon, lat = lon[ok], lat[ok]
    keep = np.ones(lon.size, bool)
    keep[1:] = (np.diff(lon) != 0) | (np.diff(lat) != 0)
    lon, lat = lon[keep], lat[keep]
    if lon.size > max_vertices:
        idx = np.unique(np.r_[np.linspace(0, lon.size - 1, max_vertices).round().astype(int)])
        lon, lat = lon[idx], lat[idx]
    return lon, lat


def track_geojson(lon: Any, lat: Any, properties: Mapping[str, Any], *, max_vertices: int = 20_000) -> dict | None:
    """A GeoJSON FeatureCollection (RFC 7946) with the track as one ``LineString`` feature (longitude, latitude,
    WGS 84, 7 decimals), thinned evenly to at most ``max_vertices``; None with fewer than two distinct positions.
    The bbox member is the track's."""
    x, y = _thin(np.asarray(lon, float), np.asarray(lat, float), max_vertices)
    if x.size < 2:
        return None
    coords = [[round(float(a), GEOJSON_DECIMALS), round(float(b), GEOJSON_DECIMALS)] for a, b in zip(x, y, strict=True)]
    bbox = [float(x.min()), float(y.min()), float(x.max()), float(y.max())]
    feature = {"type": "Feature", "bbox": bbox, "geometry": {"type": "LineString", "coordinates": coords},
               "properties": dict(properties)}
    return {"type": "FeatureCollection", "name": str(properties.get("name", "track")), "bbox": bbox,
            "features": [feature]}


def dumps(obj: Any) -> str:
    """Strict JSON (no NaN) for GeoJSON files."""
    return json.dumps(obj, allow_nan=False, separators=(",", ":"))


#: file name of the navigation track beside ``navigation.nc``
TRACK_FILE = "navigation_track.geojson"


def navigation_track(nav: Any, dive_id: str) -> dict | None:
    """The ``navigation`` table (``time``, ``lat``, ``lon``, ``position_source``, ``position_uncertainty_m``) as a
    GeoJSON track (:func:`track_geojson`) with the dive id, time span, samples per position source and the
    uncertainty range as properties."""
    import pandas as pd

    t = pd.to_datetime(nav["time"], utc=True).dropna() if "time" in nav else pd.Series([], dtype="datetime64[ns, UTC]")
    props: dict[str, Any] = {"name": f"{dive_id} track", "dive_id": dive_id, "source": "navigation.parquet",
                             "samples": int(len(nav))}
    if len(t):
        props["start_time"] = t.min().isoformat().replace("+00:00", "Z")
        props["end_time"] = t.max().isoformat().replace("+00:00", "Z")
    if "position_source" in nav:
        props["position_sources"] = {str(k): int(v) for k, v in nav["position_source"].astype(str).value_counts().items()}
    if "position_uncertainty_m" in nav:
        u = np.asarray(nav["position_uncertainty_m"], float)
        if np.isfinite(u).any():
            props["position_uncertainty_m_min"] = round(float(np.nanmin(u)), 3)
            props["position_uncertainty_m_max"] = round(float(np.nanmax(u)), 3)
    return track_geojson(nav["lon"].to_numpy(float), nav["lat"].to_numpy(float), props)


def write_navigation_track(nav: Any, path: Any, dive_id: str) -> Any:
    """Write :func:`navigation_track` to ``path`` (nothing when the track has fewer than two positions). Returns
    the path or None."""
    from pathlib import Path

    gj = navigation_track(nav, dive_id)
    if gj is None:
        return None
    path = Path(path)
    path.write_text(dumps(gj), encoding="utf-8")
    return path


def write_record_track(df: Any, path: Any, record_id: str) -> Any:
    """An underway record's track (its own per-scan ``lat``/``lon``, ``time``) as GeoJSON beside its NetCDF;
    nothing with fewer than two positions. Returns the path or None."""
    from pathlib import Path

    import pandas as pd

    props: dict[str, Any] = {"name": f"{record_id} track", "record_id": record_id, "scans": int(len(df))}
    t = pd.to_datetime(df["time"], utc=True).dropna() if "time" in df else None
    if t is not None and len(t):
        props["start_time"] = t.min().isoformat().replace("+00:00", "Z")
        props["end_time"] = t.max().isoformat().replace("+00:00", "Z")
    gj = track_geojson(np.asarray(df["lon"], float), np.asarray(df["lat"], float), props)
    if gj is None:
        return None
    path = Path(path)
    path.write_text(dumps(gj), encoding="utf-8")
    return path
