"""Writers used by every stage so products are uniformly self-describing.

* :func:`write_netcdf` writes an ``xarray.Dataset`` to NetCDF-4 and fills what the IOOS
  compliance-checker's CF-1.8 and ACDD-1.3 checks need, so stages only describe their science:
  global discovery attributes (``id``, ``naming_authority``, ``keywords``, ``license``, ``creator_*``,
  ``institution``, ``standard_name_vocabulary``, ``product_version``, ``processing_level``, ...),
  ``geospatial_*`` / ``time_coverage_*`` computed from the data, and per variable the attributes declared in
  ``schemas/variables.yaml`` (:mod:`hadal.registry`: ``units``, ``standard_name``, ``long_name``,
  ``coverage_content_type``, flags; a variable not declared there is refused), ``actual_range``, ``_FillValue``,
  ``coordinates`` (2-D lat/lon are promoted to coordinates), ``grid_mapping`` (any variable holding a
  ``grid_mapping_name``/``crs_wkt``), CF flag attributes for QARTOD ``*_qc`` and boolean flags.
* :func:`write_parquet` stores per-column ``units``/``standard_name``/``long_name`` (from the registry, the
  caller's win; an undeclared column is refused) as Arrow field metadata *and* as JSON in the file's
  key-value metadata (``hadal`` key: table metadata, ``columns``, provenance), so pandas (``df.attrs``),
  polars (``pl.read_parquet_metadata``), duckdb (``parquet_kv_metadata``) and pyarrow all see it.

Discovery attributes that describe the operator (creator, institution, project, license, ...) come from the
dive's ``dive.yaml`` ``metadata`` (else ``HADAL_<ATTRIBUTE>`` environment variables), never from a placeholder;
the ones given nowhere are listed in ``hadal_metadata_missing`` (:mod:`hadal.products.metadata`). String
attributes are written as NC_CHAR (fixed-length), which every netCDF reader (older GMT, Ferret, MATLAB) reads.
"""

from __future__ import annotations

import datetime as _dt
import json
import re
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import xarray as xr

from hadal import __version__
from hadal.errors import InputError
from hadal.products.cf import (
    STANDARD_NAME_VOCABULARY,
    is_axis_edge,
)
from hadal.products.compression import gzip_encoding
from hadal.products.dsg import dsg_global_attributes, is_binned_casts, ragged_profiles
from hadal.products.metadata import (
    HADAL_FACTS,
    current_dive,
    metadata_missing,
    product_attributes,
    relative_to_raw,
    store_relative,
)
from hadal.provenance import code_version
from hadal.registry import column_attrs, registry, storage_dtype, variable_attrs

#: Attributes of every NetCDF product that are facts about hadal (no operator placeholders: who made the data
#: comes from dive.yaml ``metadata`` or ``HADAL_<NAME>``, see :mod:`hadal.products.metadata`).
GLOBAL_DEFAULTS: dict[str, str] = dict(HADAL_FACTS)


def _now() -> str:
    return _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")


def _store_location(path: Path) -> tuple[str | None, str | None]:
    """(dive, product) when ``path`` is inside a store version or staging directory, else (None, None)."""
    parent = path.parent
    if parent.name.startswith(".staging-") or re.fullmatch(r"v\d{3,}", parent.name):
        return parent.parent.parent.name, parent.parent.name
    return None, None


def provenance(source: Any = None) -> dict[str, Any]:
    """Provenance block for a product file: hadal code version, creation time and, when ``source`` is a
    store ``Draft`` (or a mapping), its dive, product, parameters, upstream versions and input files."""
    out: dict[str, Any] = {"hadal_version": __version__, "code_version": code_version(), "created_utc": _now()}
    if source is None:
        return out
    if isinstance(source, Mapping):
        out.update(source)
        return out
    # a hadal.store.Draft (duck-typed to avoid an import cycle)
    out["dive"] = getattr(source, "dive", None)
    out["product"] = getattr(source, "product", None)
    out["parameters"] = getattr(source, "parameters", {})
    out["upstream"] = [{"product": u.product, "version": u.label, "path": store_relative(u.path)}
                       for u in getattr(source, "upstream", [])]
    _, raw_dir = current_dive(getattr(source, "path", None) and Path(source.path) / "x")
    out["inputs"] = [relative_to_raw(p, raw_dir) for p in getattr(source, "inputs", [])]
    if raw_dir is not None:
        out["inputs_relative_to"] = "the dive's raw directory"
    return out


# ---------------------------------------------------------------------------------------------- Parquet
def write_parquet(
    df: pd.DataFrame,
    path: str | Path,
    fields: Mapping[str, Mapping[str, str]] | None = None,
    metadata: Mapping[str, Any] | None = None,
    *,
    provenance_from: Any = None,
) -> Path:
    """Write ``df`` to Parquet (zstd) with self-describing metadata.

    ``fields[col] = {units, standard_name, long_name, ...}`` (completed from the variable registry,
    ``schemas/variables.yaml``; an undeclared column is refused) go into each Arrow field's metadata and,
    with ``metadata`` and a provenance block, into the file key-value metadata as JSON: ``hadal`` = ``{**metadata, "columns": {...},
    "provenance": {...}}``; the same JSON is stored as ``PANDAS_ATTRS`` so ``pd.read_parquet(p).attrs``
    returns it. ``provenance_from`` may be the store ``Draft`` being written (adds dive, product,
    parameters, upstream versions).

    A table with a latitude and a longitude column (by their metadata) also gets a WKB ``geometry`` column and
    the GeoParquet 1.1 ``geo`` metadata (:mod:`hadal.products.geoparquet`).
    """
    from hadal.products.geoparquet import GEOMETRY_COLUMN, add_point_geometry, geo_metadata, position_columns

    path = Path(path)
    if not isinstance(df, pd.DataFrame):
        raise InputError(f"write_parquet({path.name}): expected a pandas DataFrame, got {type(df).__name__}")
    schema = pa.Schema.from_pandas(df, preserve_index=False)
    fields = fields or {}
    cols = {f.name: column_attrs(f.name, fields.get(f.name), where=path.name) for f in schema}
    # GeoParquet 1.1: WKB points from the position columns (add_point_geometry, per row group) and the ``geo``
    # metadata of all of them
    pos = position_columns({k: v for k, v in cols.items() if k != GEOMETRY_COLUMN})
    geo = None
    if pos is not None:
        geo = geo_metadata(df[pos[0]].to_numpy(float), df[pos[1]].to_numpy(float), lon_column=pos[0],
                           lat_column=pos[1])
        cols[GEOMETRY_COLUMN] = column_attrs(GEOMETRY_COLUMN, fields.get(GEOMETRY_COLUMN), where=path.name)
    dive, product = _store_location(path)
    prov_src = provenance_from if provenance_from is not None else (
        {"dive": dive, "product": product} if dive else None)
    block = {**dict(metadata or {}), "columns": cols, "provenance": provenance(prov_src)}
    text = json.dumps(block, default=_json_default)

    def arrow_slice(a: int) -> pa.Table:
        table = pa.Table.from_pandas(df.iloc[a:a + PARQUET_ROW_GROUP_ROWS], schema=schema, preserve_index=False)
        return add_point_geometry(table, cols)[0]

    first = arrow_slice(0)
    new_fields = [f.with_metadata(cols[f.name]) if cols[f.name] else f for f in first.schema]
    schema_meta = dict(first.schema.metadata or {})
    schema_meta.pop(b"PANDAS_ATTRS", None)
    schema_meta[b"hadal"] = text.encode()
    schema_meta[b"PANDAS_ATTRS"] = json.dumps({"hadal": block}, default=_json_default).encode()
    if geo is not None:
        schema_meta[b"geo"] = json.dumps(geo, allow_nan=False).encode()
    out_schema = pa.schema(new_fields, metadata=schema_meta)
    # encoded in memory (compressed), then written with a free-space check and plain os.write: a full disk is one
    # OSError (ENOSPC) and no partial file. Converted and encoded one row group at a time (issue 48): the Arrow
    # copy of the table is one row group's, never the whole table's; the row groups are pq.write_table's
    # (PARQUET_ROW_GROUP_ROWS), so the file is the one a whole-table write makes.
    sink = pa.BufferOutputStream()
    with pq.ParquetWriter(sink, out_schema, compression="zstd",
                          use_dictionary=dictionary_columns(out_schema)) as writer:
        a = 0
        while True:
            writer.write_table(first.cast(out_schema), row_group_size=PARQUET_ROW_GROUP_ROWS)
            a += PARQUET_ROW_GROUP_ROWS
            if a >= len(df):
                break
            first = arrow_slice(a)
    del first
    _write_file(path, sink.getvalue())
    return path


#: rows of one Parquet row group: pyarrow's default maximum (``pq.write_table``), the unit :func:`write_parquet`
#: converts and encodes at a time
PARQUET_ROW_GROUP_ROWS = 1024 * 1024


def dictionary_columns(schema: pa.Schema) -> list[str]:
    """The columns Parquet dictionary-encodes: all but floating-point and time columns, whose values rarely repeat.
    Dictionary-encoding those first, as pyarrow does by default, is wasted work: on the sample dive's ctd table
    (567 k rows x 48 columns) writing took 0.67 s and 78.8 MB, against 0.32 s and 72.5 MB without it."""
    return [f.name for f in schema if not (pa.types.is_floating(f.type) or pa.types.is_temporal(f.type))]


def _write_file(path: Path, data: Any) -> None:
    from hadal.store import write_bytes_checked

    write_bytes_checked(path, memoryview(data), path.name)


def read_parquet_metadata(path: str | Path) -> tuple[dict[str, Any], dict[str, dict[str, str]]]:
    """Return (table metadata, per-column field metadata) written by :func:`write_parquet`."""
    schema = pq.read_schema(path)
    table_meta = json.loads((schema.metadata or {}).get(b"hadal", b"{}"))
    cols = {f.name: {k.decode(): v.decode() for k, v in (f.metadata or {}).items()} for f in schema}
    return table_meta, cols


def read_parquet_table(path: str | Path, columns: Sequence[str] | None = None
                       ) -> tuple[pd.DataFrame, dict[str, Any], dict[str, dict[str, str]]]:
    """A :func:`write_parquet` file opened once: (the table, or its ``columns`` that it has, as pandas; the table
    metadata; the per-column field metadata), what ``pd.read_parquet`` and :func:`read_parquet_metadata` give."""
    pf = pq.ParquetFile(path)
    try:
        schema = pf.schema_arrow
        names = None if columns is None else [c for c in columns if c in schema.names]
        df = pf.read(columns=names, use_pandas_metadata=True).to_pandas()
    finally:
        pf.close()
    table_meta = json.loads((schema.metadata or {}).get(b"hadal", b"{}"))
    cols = {f.name: {k.decode(): v.decode() for k, v in (f.metadata or {}).items()} for f in schema}
    return df, table_meta, cols


def json_clean(obj):
    """Replace NaN/inf by None and numpy scalars by Python ones so ``json.dumps`` writes strict JSON."""
    if isinstance(obj, dict):
        return {k: json_clean(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [json_clean(v) for v in obj]
    if isinstance(obj, (np.integer,)):
        return int(obj)
    if isinstance(obj, (float, np.floating)):
        return float(obj) if np.isfinite(obj) else None
    if isinstance(obj, np.bool_):
        return bool(obj)
    return obj


def _json_default(obj: Any) -> Any:
    if isinstance(obj, (np.integer, np.floating, np.bool_)):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, (_dt.datetime, _dt.date, pd.Timestamp)):
        return obj.isoformat()
    if hasattr(obj, "model_dump"):
        return obj.model_dump(mode="json")
    return str(obj)


# ---------------------------------------------------------------------------------------------- NetCDF
def _standard_name(name: str, var: xr.DataArray | xr.Variable) -> str | None:
    """The variable's own standard_name, else the one the registry declares for its name."""
    if var.attrs.get("standard_name"):
        return str(var.attrs["standard_name"])
    spec = registry().find(name)
    return spec.standard_name if spec is not None else None


def _is_lat(name: str, var: xr.DataArray | xr.Variable) -> bool:
    return _standard_name(name, var) == "latitude"


def _is_lon(name: str, var: xr.DataArray | xr.Variable) -> bool:
    return _standard_name(name, var) == "longitude"


def _is_grid_mapping(var: xr.DataArray | xr.Variable) -> bool:
    return any(k in var.attrs for k in ("grid_mapping_name", "crs_wkt", "spatial_ref", "proj4", "proj4text"))


def _finite_range(values: np.ndarray) -> tuple[Any, Any] | None:
    v = np.asarray(values)
    if v.size == 0 or not (np.issubdtype(v.dtype, np.number)) or np.issubdtype(v.dtype, np.bool_):
        return None
    if np.issubdtype(v.dtype, np.floating):
        v = v[np.isfinite(v)]
        if v.size == 0:
            return None
    return v.min(), v.max()


def _fill_grid_mapping(var: xr.DataArray | xr.Variable) -> None:
    """Complete a grid-mapping variable's CF attributes from its WKT/proj4 with pyproj."""
    wkt = var.attrs.get("crs_wkt")
    wkt_ok = isinstance(wkt, str) and wkt.lstrip()[:6].upper() in ("PROJCR", "GEOGCR", "PROJCS", "GEOGCS", "COMPOU", "BOUNDC")
    if "grid_mapping_name" in var.attrs and wkt_ok:
        return
    src = wkt or var.attrs.get("spatial_ref") or var.attrs.get("proj4") or var.attrs.get("proj4text")
    if not src:
        return
    try:
        from pyproj import CRS

        crs = CRS.from_user_input(src)
        cf = crs.to_cf()
    except Exception:  # pyproj cannot parse it: leave the caller's attributes alone
        return
    if not wkt_ok:  # e.g. a proj4 string stored as crs_wkt: replace it by real WKT
        var.attrs["crs_wkt"] = cf.get("crs_wkt", crs.to_wkt())
    for k, v in cf.items():
        var.attrs.setdefault(k, v)


def _cf_integer_type(var: xr.Variable) -> xr.Variable:
    """CF-1.8 §2.2 allows only signed byte/short/int: 64-bit integers become int32 and unsigned integers
    the smallest signed type holding every value (uint8 QARTOD flags -> int8), when the values fit."""
    if var.dtype.kind not in "iu" or var.dtype in (np.dtype("i1"), np.dtype("i2"), np.dtype("i4")):
        return var
    vals = np.asarray(var.values)
    lo, hi = (int(vals.min()), int(vals.max())) if vals.size else (0, 0)
    for k in ("flag_values", "flag_masks", "valid_min", "valid_max", "valid_range"):
        if k in var.attrs:
            a = np.asarray(var.attrs[k])
            if a.size:
                lo, hi = min(lo, int(a.min())), max(hi, int(a.max()))
    # signed 64-bit only to int32 (never narrower: readers doing arithmetic keep their range);
    # unsigned to the smallest signed type that holds every value (uint8 flags -> int8)
    for t in (("i1", "i2", "i4") if var.dtype.kind == "u" else ("i4",)):
        info = np.iinfo(t)
        if info.min <= lo and hi <= info.max:
            return var.astype(t)
    return var


def _prepare_variable(name: str, var: xr.Variable, *, is_coord: bool, is_dim_coord: bool,
                      grid_mapping: str | None, yx_dims: tuple[str, str] | None, where: str = "") -> xr.Variable:
    """``var`` with its CF attributes and encoding: the attributes ``schemas/variables.yaml`` declares for
    ``name`` (as a y/x map-grid layer when it lies on one), the caller's winning, plus the structural CF rules
    (time encoding, boolean flags, integer narrowing, ``_FillValue``, ``actual_range``, ``grid_mapping``). An
    undeclared variable raises :class:`hadal.registry.UndeclaredVariableError`."""
    on_grid = yx_dims is not None and set(yx_dims) <= set(var.dims)
    declared = variable_attrs(name, on_grid, where)
    declared_coverage = declared.pop("coverage_content_type", None)
    attrs = {**declared, **dict(var.attrs)}  # the caller's attributes win
    enc = dict(var.encoding)
    enc.pop("coordinates", None)  # xarray writes `coordinates` from the dataset's coordinates
    var = _cf_integer_type(xr.Variable(var.dims, var.data, attrs))
    enc.pop("dtype", None) if var.dtype.kind in "iu" else None
    if not is_dim_coord and storage_dtype(name, var.values) == "float32":  # precision declared in the registry
        var = var.astype("float32")
        enc.pop("dtype", None)
        if enc.get("zlib"):
            enc["shuffle"] = True  # byte-shuffled float32 deflates better (hadal.products.compression)
    if is_coord and var.ndim >= 2 and var.dtype.kind == "f" and not enc.get("zlib"):
        # 2-D latitude/longitude of a grid: smooth, so shuffle + deflate shrink them ~6x (float64 kept: cm positions)
        enc.update(gzip_encoding(tuple(min(s, 512) for s in var.shape), shuffle=True))
    if np.issubdtype(var.dtype, np.bool_):
        var = var.astype("i1")
        attrs.setdefault("flag_values", np.array([0, 1], dtype="i1"))
        attrs.setdefault("flag_meanings", f"not_{name} {name}")
        attrs.pop("units", None)
    for k in ("flag_values", "flag_masks"):
        if k in attrs and np.issubdtype(var.dtype, np.integer):
            attrs[k] = np.asarray(attrs[k]).astype(var.dtype)
    is_flag = "flag_values" in attrs or "flag_masks" in attrs
    is_time = np.issubdtype(var.dtype, np.datetime64)
    if is_time:
        attrs.setdefault("standard_name", "time")
        attrs.pop("units", None)  # xarray writes CF time units from the encoding
        enc.setdefault("units", "seconds since 1970-01-01T00:00:00Z")
        enc.setdefault("calendar", "standard")
        enc.setdefault("dtype", "f8")
        if var.size and np.isnat(np.asarray(var.values)).all():
            # xarray cannot encode an all-NaT variable (it derives a reference date from the data and fails
            # with a TypeError): write the CF encoding ourselves, every value missing
            var = xr.Variable(var.dims, np.full(var.shape, np.nan), var.attrs)
            attrs["units"], attrs["calendar"] = enc.pop("units"), enc.pop("calendar")
            enc.pop("dtype", None)
            enc["_FillValue"] = np.nan
    if str(attrs.get("standard_name", "")).endswith("number_of_observations"):
        attrs["units"] = "1"  # CF Appendix C: the number_of_observations modifier has units 1
    if is_dim_coord and attrs.get("units") == "dbar":
        attrs.setdefault("positive", "down")
        attrs.setdefault("axis", "Z")
    if attrs.get("standard_name") in ("depth", "sea_floor_depth_below_sea_surface"):
        attrs.setdefault("positive", "down")  # CF: these standard names are positive down
    if is_coord:
        attrs.setdefault("coverage_content_type", "coordinate")
    elif is_flag:
        attrs.setdefault("coverage_content_type", "qualityInformation")
    attrs.setdefault("coverage_content_type", declared_coverage or "physicalMeasurement")
    if grid_mapping and on_grid and not is_coord:
        attrs.setdefault("grid_mapping", grid_mapping)
    if is_dim_coord:
        enc["_FillValue"] = None  # CF §2.5.1: coordinate variables must not have missing values
        attrs.pop("_FillValue", None)
    elif not is_time and var.dtype.kind == "f":
        enc.setdefault("_FillValue", np.array(np.nan, dtype=var.dtype).item())
        attrs.pop("_FillValue", None)
    if not is_time and not is_flag and var.dtype.kind in "fiu" and "actual_range" not in attrs:
        rng = _finite_range(var.values)
        if rng is not None:
            attrs["actual_range"] = np.array(rng, dtype=var.dtype)
    if var.dtype.kind in "fiu":
        for k in ("actual_range", "valid_min", "valid_max", "valid_range"):
            if k in attrs:
                attrs[k] = np.asarray(attrs[k]).astype(var.dtype)
    attrs = {k: _attr_value(v) for k, v in attrs.items() if v is not None}
    out = xr.Variable(var.dims, var.data, attrs)
    out.encoding = enc
    return out


def _attr_value(v: Any) -> Any:
    if isinstance(v, (bool, np.bool_)):
        return "true" if v else "false"
    if isinstance(v, (dict, tuple, list)) and not (
        isinstance(v, (list, tuple)) and v and all(isinstance(x, (int, float)) and not isinstance(x, bool) for x in v)
    ):
        return json.dumps(v, default=_json_default)
    if isinstance(v, (_dt.datetime, _dt.date, pd.Timestamp)):
        return v.isoformat()
    if isinstance(v, Path):
        return str(v)
    return v


def _iso(t: Any) -> str:
    ts = pd.Timestamp(t)
    if ts.tzinfo is None:
        ts = ts.tz_localize("UTC")
    return ts.tz_convert("UTC").strftime("%Y-%m-%dT%H:%M:%SZ")


def _iso_duration(seconds: float) -> str:
    seconds = max(0.0, float(seconds))
    d, rem = divmod(seconds, 86400)
    h, rem = divmod(rem, 3600)
    m, s = divmod(rem, 60)
    out = "P" + (f"{int(d)}D" if d else "") + "T"
    return out + f"{int(h)}H{int(m)}M{s:.0f}S"


def _resolution(values: np.ndarray) -> float | None:
    v = np.unique(np.asarray(values, dtype=float)[np.isfinite(np.asarray(values, dtype=float))])
    if v.size < 2:
        return None
    return float(np.median(np.diff(v)))


def _z_coordinate(ds: xr.Dataset) -> str | None:
    """The vertical coordinate as the compliance checker finds it: a (dimension or auxiliary)
    coordinate with standard_name depth/height/altitude, else one with pressure units or ``positive``."""
    coords = [str(n) for n in ds.coords if np.issubdtype(ds[n].dtype, np.number)]
    for c in coords:  # a declared length Z axis first (a ragged profile's depth_m)
        if ds[c].attrs.get("axis") == "Z" and ds[c].attrs.get("standard_name") in ("depth", "height", "altitude"):
            return c
    for n in ds.dims:  # a depth dimension coordinate first (a depth-binned profile), before depth-like data
        if n in ds.coords and ds[n].attrs.get("standard_name") in ("depth", "height", "altitude"):
            return str(n)
    for n, v in ds.variables.items():  # the checker treats these standard names as coordinates anywhere
        if v.attrs.get("standard_name") in ("depth", "height", "altitude") and np.issubdtype(v.dtype, np.number):
            return str(n)
    for n in coords:
        a = ds[n].attrs
        if a.get("units") in ("dbar", "bar", "Pa", "hPa", "kPa", "decibar") or a.get("positive") in ("up", "down") \
                or a.get("axis") == "Z":
            return n
    return None


def _position_hint(pool: Mapping[str, Any], suffix: str) -> float | None:
    for k, v in pool.items():
        if str(k).endswith(suffix) and isinstance(v, (int, float, np.floating)) and np.isfinite(v):
            return float(v)
    return None


def _time_hint(pool: Mapping[str, Any]) -> pd.Timestamp | None:
    for k in ("time_coverage_start",) + tuple(k for k in pool if str(k).endswith(("time_utc", "_time"))):
        if k in pool and pool[k] not in (None, ""):
            try:
                return pd.Timestamp(pool[k])
            except (ValueError, TypeError):
                continue
    return None


_DIVE_KEY = "_hadal_dive"  # the Dive model passed through dive_attributes (popped before writing)


def dive_attributes(dive: Any) -> dict[str, Any]:
    """Global attributes describing a dive (``hadal.dive.Dive``): pass them to :func:`write_netcdf`
    (``write_netcdf(ds, path, title=..., summary=..., **dive_attributes(ctx.dive))``) so products without
    latitude/longitude or time variables (laser grids, landing maps, profiles) still get a position and time."""
    out: dict[str, Any] = {"dive_id": dive.dive_id, "platform_name": dive.platform, _DIVE_KEY: dive}
    if dive.launch is not None:
        out["launch_latitude_deg"] = dive.launch.latitude_deg
        out["launch_longitude_deg"] = dive.launch.longitude_deg
    if dive.launch is not None and dive.launch.time_utc is not None:
        out["launch_time_utc"] = pd.Timestamp(dive.launch.time_utc).isoformat()
    if dive.map_frame is not None:
        out["map_frame_origin_latitude_deg"] = dive.map_frame.origin_latitude_deg
        out["map_frame_origin_longitude_deg"] = dive.map_frame.origin_longitude_deg
    return out


def _sorted_unique(a: np.ndarray) -> np.ndarray:
    """``np.unique(a)`` (1-D), without the sort when ``a`` is already ascending (time series usually are)."""
    if a.size > 1 and bool((a[1:] >= a[:-1]).all()):
        return a[np.concatenate([[True], a[1:] != a[:-1]])]
    return np.unique(a)


#: vertical CRS of the standard names that are measured from the sea surface (ACDD geospatial_bounds_vertical_crs):
#: EPSG:5831 (instantaneous/mean sea level depth), EPSG:5829 (instantaneous height above sea level)
_VERTICAL_DATUM: dict[str, str] = {"depth": "EPSG:5831", "sea_floor_depth_below_sea_surface": "EPSG:5831",
                                   "sea_floor_depth_below_mean_sea_level": "EPSG:5831",
                                   "height_above_mean_sea_level": "EPSG:5829", "altitude": "EPSG:5829"}


def discovery_attributes(ds: xr.Dataset, hints: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """ACDD geospatial/vertical/time coverage attributes computed from the data of ``ds``.

    Latitude/longitude come from variables named ``lat``/``lon`` (or with those standard names); the
    vertical extent from the vertical coordinate (see :func:`_z_coordinate`), else from a depth-like
    variable with ``positive: down`` (2-D seafloor grids); time from datetime variables.
    """
    hints = dict(hints or {})
    out: dict[str, Any] = {}
    lats = [v.values for n, v in ds.variables.items() if _is_lat(str(n), v)]
    lons = [v.values for n, v in ds.variables.items() if _is_lon(str(n), v)]
    lat_rng = _finite_range(np.concatenate([np.ravel(a).astype(float) for a in lats])) if lats else None
    lon_rng = _finite_range(np.concatenate([np.ravel(a).astype(float) for a in lons])) if lons else None
    if lat_rng is not None and lon_rng is not None:
        la0, la1 = (float(x) for x in lat_rng)
        lo0, lo1 = (float(x) for x in lon_rng)
        out.update(geospatial_lat_min=la0, geospatial_lat_max=la1, geospatial_lon_min=lo0, geospatial_lon_max=lo1,
                   geospatial_lat_units="degrees_north", geospatial_lon_units="degrees_east",
                   geospatial_bounds_crs="EPSG:4326")
        if la0 == la1 and lo0 == lo1:
            out["geospatial_bounds"] = f"POINT ({la0} {lo0})"
        else:
            out["geospatial_bounds"] = f"POLYGON (({la0} {lo0}, {la0} {lo1}, {la1} {lo1}, {la1} {lo0}, {la0} {lo0}))"
        for key, arrs, axis in (("geospatial_lat_resolution", lats, 0), ("geospatial_lon_resolution", lons, 1)):
            a = np.asarray(arrs[0], dtype=float)
            line = a if a.ndim == 1 else (np.take(a, 0, axis=1 - axis) if a.ndim == 2 else np.ravel(a))
            r = _resolution(line) if line.size > 1 else None
            out[key] = f"{abs(r):.6g} degree" if r else "point"
    z = _z_coordinate(ds)
    zvals, zstd = None, None
    if z is not None:
        zvals, zunits = ds[z].values, ds[z].attrs.get("units", "m")
        positive = ds[z].attrs.get("positive", "down")
        zstd = ds[z].attrs.get("standard_name")
    else:
        for pos in ("down", "up"):
            for v in ds.variables.values():
                # a vertical field with a CF standard name (a seafloor depth or height); an elevation relative to
                # an arbitrary origin (laser grids) has none and gives no vertical extent (no datum it lacks)
                if np.issubdtype(v.dtype, np.number) and v.attrs.get("positive") == pos and \
                        v.attrs.get("standard_name") in _VERTICAL_DATUM:
                    zvals, zunits, positive = v.values, v.attrs.get("units", "m"), pos
                    zstd = v.attrs.get("standard_name")
                    break
            if zvals is not None:
                break
    if zvals is not None and (vr := _finite_range(zvals)) is not None:
        out.update(geospatial_vertical_min=float(vr[0]), geospatial_vertical_max=float(vr[1]),
                   geospatial_vertical_units=zunits, geospatial_vertical_positive=positive)
        if zunits == "m" and zstd in _VERTICAL_DATUM:  # a depth below / height above the sea surface (MSL)
            out["geospatial_bounds_vertical_crs"] = _VERTICAL_DATUM[zstd]
        r = _resolution(np.ravel(zvals)) if z is not None and np.ndim(zvals) == 1 else None
        out["geospatial_vertical_resolution"] = f"{r:.6g} {zunits}" if r else "point"
    times = [v.values for v in ds.variables.values() if np.issubdtype(v.dtype, np.datetime64)]
    t = np.concatenate([np.ravel(a) for a in times]) if times else np.array([], dtype="datetime64[ns]")
    t = t[~np.isnat(t)] if t.size else t
    if t.size:
        t0, t1 = t.min(), t.max()
        out.update(time_coverage_start=_iso(t0), time_coverage_end=_iso(t1),
                   time_coverage_duration=_iso_duration((t1 - t0) / np.timedelta64(1, "s")))
        u = _sorted_unique(t)
        dt = np.median(np.diff(u)) / np.timedelta64(1, "s") if u.size > 1 else 0.0
        out["time_coverage_resolution"] = (_iso_duration(dt) if dt >= 1 else f"PT{dt:.3g}S") if dt else "point"
    return out


def _add_scalar_fallbacks(out: xr.Dataset, pool: Mapping[str, Any], now: pd.Timestamp) -> xr.Dataset:
    """Give position/time-less datasets (profiles, MSD surfaces) CF scalar coordinates: position from
    ``*latitude_deg``/``*longitude_deg`` attributes (launch point, map-frame origin), time from
    ``time_coverage_start``/``*time_utc`` attributes, else the processing time (said so in long_name) - unless
    the attributes carry ``time_omitted`` (a cast without any time: no time rather than the processing time)."""
    names = {str(n) for n in out.variables}
    has_lat = any(_is_lat(n, out[n]) for n in names)
    has_lon = any(_is_lon(n, out[n]) for n in names)
    if not (has_lat and has_lon):
        la, lo = _position_hint(pool, "latitude_deg"), _position_hint(pool, "longitude_deg")
        if la is not None and lo is not None and "lat" not in names and "lon" not in names:
            out = out.assign_coords(
                lat=xr.Variable((), la, {"standard_name": "latitude", "units": "degrees_north",
                                         "long_name": "latitude of the product's reference position"}),
                lon=xr.Variable((), lo, {"standard_name": "longitude", "units": "degrees_east",
                                         "long_name": "longitude of the product's reference position"}))
    if not any(np.issubdtype(out[n].dtype, np.datetime64) for n in names) and "time" not in names:
        if pool.get("time_omitted"):  # the data have no time and the producer says none may be invented
            return out
        t = _time_hint(pool)
        what = "reference time of the product (from its metadata)"
        if t is None:
            t, what = now, "time of processing (the source data carry no acquisition time)"
        t = (t.tz_convert("UTC") if t.tzinfo else t).tz_localize(None) if isinstance(t, pd.Timestamp) else t
        out = out.assign_coords(time=xr.Variable((), np.datetime64(t, "ns"), {"long_name": what}))
    return out


def _string_dims_to_index(out: xr.Dataset) -> xr.Dataset:
    """String dimension coordinates (e.g. ``phase = ["descent", "ascent"]``) become integer coordinates with
    CF ``flag_values``/``flag_meanings`` (NetCDF coordinate variables must be numeric and monotonic)."""
    for dim in list(out.dims):
        if dim in out.coords and out[dim].dtype.kind in "OUS":
            labels = [str(v) for v in out[dim].values]
            meanings = " ".join(re.sub(r"\s+", "_", lab) for lab in labels)
            attrs = {**out[dim].attrs, "flag_values": np.arange(len(labels), dtype="i4"), "flag_meanings": meanings,
                     "long_name": out[dim].attrs.get("long_name", f"{dim} ({', '.join(f'{i} = {lab}' for i, lab in enumerate(labels))})")}
            out = out.assign_coords({dim: xr.Variable((dim,), np.arange(len(labels), dtype="i4"), attrs)})
    return out


#: the conventions every NetCDF product follows (IOOS-1.2 where it applies: see hadal.products.compliance)
CONVENTIONS = "CF-1.8, ACDD-1.3, IOOS-1.2"

#: name of the IOOS-1.2 platform container variable every data variable refers to (``platform`` attribute)
PLATFORM_VARIABLE = "platform"


def _add_platform_variable(out: xr.Dataset, glob: dict[str, Any], grid_mapping: str | None) -> xr.Dataset:
    """IOOS-1.2 / CF-1.8 platform container variable (a scalar holding the platform's attributes) and the
    ``platform`` attribute on every data variable naming it; only when the product names a platform."""
    gcmd = glob.pop("hadal_platform_gcmd", None)
    if not glob.get("platform") or PLATFORM_VARIABLE in out.variables:
        return out
    pattrs = {"long_name": glob.get("platform_name") or str(glob["platform"]),
              "comment": "container variable of the platform (vehicle) metadata; every data variable names it "
                         "in its platform attribute",
              "platform_type": str(glob["platform"]), "platform_vocabulary": glob.get("platform_vocabulary"),
              "platform_id": glob.get("platform_id"), "gcmd_platform_keyword": gcmd,
              "instrument": glob.get("instrument")}
    for n in list(out.data_vars):
        if str(n) != grid_mapping:
            out[n].attrs["platform"] = PLATFORM_VARIABLE
    out[PLATFORM_VARIABLE] = xr.Variable((), np.int8(0), {k: v for k, v in pattrs.items() if v})
    return out


def _promote_coordinates(out: xr.Dataset) -> xr.Dataset:
    """``out`` with its lat/lon data variables (2-D or any), 1-D axis edges along a coordinate and the variables
    named in a ``coordinates`` attribute made coordinates, and every ``coordinates`` attribute dropped (xarray
    writes them from the dataset's coordinates)."""
    # 2-D (or any) lat/lon data variables become coordinates so xarray writes `coordinates` attributes
    promote = [n for n, v in out.data_vars.items() if _is_lat(str(n), v) or _is_lon(str(n), v)
               or (is_axis_edge(str(n)) and v.ndim == 1 and v.dims[0] in out.coords)]
    for v in list(out.data_vars.values()):  # an explicit `coordinates` attribute: make those coordinates
        listed = str(v.attrs.get("coordinates", "")).split()
        promote += [c for c in listed if c in out.data_vars and c not in promote]
    if promote:
        out = out.set_coords(promote)
    for n in out.variables:  # xarray writes `coordinates` from the dataset's coordinates
        out[n].attrs.pop("coordinates", None)
    return out


def _complete_grid_mappings(out: xr.Dataset) -> tuple[xr.Dataset, list[str], str | None]:
    """``(out, names of its grid-mapping variables, the first of them or None)``: each grid-mapping variable
    (one holding ``grid_mapping_name``/``crs_wkt``) replaced by a scalar int32 data variable with its CF
    attributes completed (:func:`_fill_grid_mapping`)."""
    gm_names = [str(n) for n, v in out.variables.items() if _is_grid_mapping(v)]
    grid_mapping = gm_names[0] if gm_names else None
    for n in gm_names:
        gattrs = dict(out[n].attrs)
        tmp = xr.Variable((), np.int32(0), attrs=gattrs)
        _fill_grid_mapping(tmp)
        tmp.attrs.setdefault("long_name", "coordinate reference system of the map frame")
        tmp.attrs = {k: _attr_value(v) for k, v in tmp.attrs.items()}
        if n in out.coords:
            out = out.reset_coords(n)
        out[n] = tmp
    return out, gm_names, grid_mapping


def _prepare_variables(out: xr.Dataset, gm_names: list[str], grid_mapping: str | None,
                       yx: tuple[str, str] | None, where: str) -> xr.Dataset:
    """``out`` with every variable but the grid mappings completed by :func:`_prepare_variable` (registry
    attributes, ranges, fill values, ``grid_mapping`` on the ``yx`` grids); ``where`` names the file in errors."""
    new_vars = {}
    for n, v in out.variables.items():
        if str(n) in gm_names:
            continue
        new_vars[n] = _prepare_variable(str(n), v, is_coord=n in out.coords, is_dim_coord=n in out.dims,
                                        grid_mapping=grid_mapping, yx_dims=yx, where=where)
    for n, v in new_vars.items():
        if n in out.coords:
            out = out.assign_coords({n: v})
        else:
            out[n] = v
    return out


def _fix_platform(glob: dict[str, Any], own_platform: str | None) -> None:
    """In place: a caller's vehicle name given as ``platform`` is the ``platform_name`` (``platform`` is the
    dive's platform type); a caller's free-text platform drops ``platform_vocabulary``."""
    if glob.get("platform") is not None and glob.get("platform") == glob.get("platform_name") and own_platform:
        glob["platform"] = own_platform  # a caller's vehicle name: that is platform_name; platform is the type
    if glob.get("platform") not in (None, own_platform):
        glob.pop("platform_vocabulary", None)  # a caller's free-text platform is not a term of the vocabulary


def _local_grid_footprint(out: xr.Dataset, dive: Any) -> tuple[xr.Dataset, dict[str, Any] | None]:
    """A y/x grid without a grid mapping and without lat/lon is in the laser survey's local frame (the only
    un-projected frame hadal grids in): with ``dive.yaml`` ``laser_frame`` its ACDD extent is the rotated rectangle
    of its mapped cells (:func:`hadal.products.footprint.grid_footprint`) and its scalar reference position the
    footprint's centre; without one the grid is not georeferenced and the reference position says so."""
    if any(_is_lat(str(n), v) or _is_lon(str(n), v) for n, v in out.variables.items() if v.ndim > 0):
        return out, None
    from hadal.products.footprint import grid_footprint

    lf = getattr(dive, "laser_frame", None)
    fp = grid_footprint(out, lf) if lf is not None else None
    if fp is None:
        return out, {"hadal_georeference": "none: the grid is in the laser survey's local frame and dive.yaml gives "
                                           "no laser_frame; geospatial_* give the dive's launch position"}
    centre, attrs = fp
    return _footprint_reference(out, centre, attrs, "centre of the grid's mapped footprint (laser_frame of dive.yaml)"), attrs


def _footprint_reference(out: xr.Dataset, centre: tuple[float, float], attrs: Mapping[str, Any],
                         what: str) -> xr.Dataset:
    """``out`` with scalar ``lat``/``lon`` at the footprint's ``centre`` (lon, lat) and the footprint polygon's
    vertices ``footprint_lat``/``footprint_lon`` (the ring of ``attrs``' ``geospatial_bounds``), so readers and the
    ACDD extent checks find the extent in the data."""
    ring = [tuple(map(float, p.split())) for p in str(attrs["geospatial_bounds"])[10:-2].split(", ")]
    out = out.drop_vars([n for n in ("lat", "lon") if n in out.variables and out[n].ndim == 0])
    out = out.assign_coords(
        lat=xr.Variable((), centre[1], {"standard_name": "latitude", "units": "degrees_north", "long_name": what}),
        lon=xr.Variable((), centre[0], {"standard_name": "longitude", "units": "degrees_east", "long_name": what}))
    out["footprint_lat"] = xr.Variable(("footprint_vertex",), np.array([r[0] for r in ring]), {})
    out["footprint_lon"] = xr.Variable(("footprint_vertex",), np.array([r[1] for r in ring]), {})
    return out


def _crs_grid_footprint(out: xr.Dataset, gm: str) -> tuple[xr.Dataset, dict[str, Any] | None]:
    """A projected y/x grid without latitude/longitude variables: its ACDD extent from the mapped cells' rectangle
    in its grid mapping's CRS (:func:`hadal.products.footprint.crs_grid_footprint`), the scalar reference position
    its centre."""
    from hadal.products.footprint import crs_grid_footprint

    wkt = out[gm].attrs.get("crs_wkt")
    try:
        fp = crs_grid_footprint(out, str(wkt)) if wkt else None
    except Exception:  # noqa: BLE001 - pyproj cannot use the CRS: the grid keeps what it had
        fp = None
    if fp is None:
        return out, None
    centre, attrs = fp
    return _footprint_reference(out, centre, attrs, "centre of the grid's mapped footprint (its own CRS)"), attrs


def _global_attributes(ds: xr.Dataset, out: xr.Dataset, path: Path, attrs: dict[str, Any], *, title: str,
                       summary: str, dive_model: Any, provenance_from: Any, yx: tuple[str, str] | None,
                       now_iso: str) -> dict[str, Any]:
    """The product's global attributes before the platform variable: conventions, title/summary, the dive's
    product attributes, id (dive.product.stem), provenance, ``cdm_data_type``, creation dates (``now_iso``,
    ISO 8601 UTC), discovery attributes of ``out``, then ``ds.attrs`` and the caller's ``attrs`` (which win)."""
    dive, product = _store_location(path)
    dive = attrs.get("dive_id") or ds.attrs.get("dive_id") or dive
    prov = provenance(provenance_from) if provenance_from is not None else provenance(
        {"dive": dive, "product": product} if dive else None)
    stem = path.stem
    ident = ".".join(x for x in (dive, product if product and product != stem else None, stem) if x)
    cdm = "Grid" if yx else ("Trajectory" if "time" in out.dims else ("Profile" if _z_coordinate(out) else "Point"))
    glob: dict[str, Any] = {
        "Conventions": CONVENTIONS,
        "title": title,
        "summary": summary,
        **product_attributes(dive_model, product, {**ds.attrs, **attrs}),
        "id": ident,
        "source": f"hadal {__version__}",
        "standard_name_vocabulary": STANDARD_NAME_VOCABULARY,
        "product_version": prov["code_version"],
        "cdm_data_type": cdm,
        "date_created": now_iso,
        "date_modified": now_iso,
        "date_issued": now_iso,
        "date_metadata_modified": now_iso,
        "history": f"{now_iso} created by hadal {prov['code_version']}",
        "hadal_provenance": prov,
        **discovery_attributes(out),
        **{k: v for k, v in ds.attrs.items()},
        **attrs,
    }
    _fix_platform(glob, product_attributes(dive_model, product).get("platform"))
    return glob


def prepare_dataset(ds: xr.Dataset, path: str | Path, *, title: str, summary: str, **attrs: Any) -> xr.Dataset:
    """The dataset :func:`write_netcdf` writes: ``ds`` with CF/ACDD attributes completed (caller's win)."""
    path = Path(path)
    provenance_from = attrs.pop("provenance_from", None)
    dive_model = attrs.pop(_DIVE_KEY, None)
    if dive_model is None:
        dive_model, _ = current_dive(path)
    now_ts = pd.Timestamp.now(tz="UTC").floor("s")
    now = now_ts.isoformat()
    out = _promote_coordinates(ds.copy())
    out = _string_dims_to_index(out)
    dive_hints = {k: v for k, v in dive_attributes(dive_model).items() if k != _DIVE_KEY} if dive_model else {}
    out = _add_scalar_fallbacks(out, {**dive_hints, **ds.attrs, **attrs}, now_ts)
    if is_binned_casts(out):  # binned casts: a contiguous ragged array, one profile per cast (hadal.products.dsg)
        dive_id = attrs.get("dive_id") or ds.attrs.get("dive_id") or _store_location(path)[0]
        la = attrs.get("latitude_used_deg", ds.attrs.get("latitude_used_deg"))
        out = ragged_profiles(out, dive_id, latitude_deg=float(la) if la is not None else None)
    src_wkt = {**ds.attrs, **attrs}.get("source_crs_wkt")
    if {"y", "x"} <= set(out.dims) and src_wkt and not any(_is_grid_mapping(v) for v in out.variables.values()):
        # a grid on its source file's own projected CRS (a point cloud in UTM): CF grid mapping from that metadata
        out["crs"] = xr.Variable((), np.int32(0), {"crs_wkt": str(src_wkt),
                                                   "long_name": "coordinate reference system of the source file"})
    out, gm_names, grid_mapping = _complete_grid_mappings(out)
    yx = ("y", "x") if {"y", "x"} <= set(out.dims) else None
    footprint = None
    if yx and not gm_names:  # a grid in the laser survey's frame: its true footprint from dive.yaml laser_frame
        out, footprint = _local_grid_footprint(out, dive_model)
    elif yx and not any(_is_lat(str(n), v) for n, v in out.variables.items() if v.ndim > 0):
        out, footprint = _crs_grid_footprint(out, gm_names[0])  # a projected grid without lat/lon (a LAS in UTM)
    out = _prepare_variables(out, gm_names, grid_mapping, yx, path.name)
    dsg = dsg_global_attributes(out) if not yx else {}
    attrs = {**dsg, **attrs}
    glob = _global_attributes(ds, out, path, attrs, title=title, summary=summary, dive_model=dive_model,
                              provenance_from=provenance_from, yx=yx, now_iso=now)
    if footprint:
        glob.update(footprint)
    if yx:
        glob.pop("featureType", None)  # CF: featureType names a discrete sampling geometry, never a grid
    out = _add_platform_variable(out, glob, grid_mapping)
    glob.pop("hadal_metadata_missing", None)
    glob["hadal_metadata_missing"] = metadata_missing(glob)
    out.attrs = {k: _attr_value(v) for k, v in glob.items() if v is not None}
    return out


def _nc_char(attrs: Mapping[str, Any]) -> dict[str, Any]:
    """String attributes as fixed-length byte strings: h5netcdf/HDF5 stores them as fixed-length strings,
    which netCDF-C reads as NC_CHAR (classic text attributes) instead of netCDF-4 ``string``."""
    out = {}
    for k, v in attrs.items():
        if isinstance(v, str):
            if not v:
                continue  # HDF5 has no zero-length fixed string; an empty attribute says nothing
            v = np.bytes_(v.encode("utf-8"))
        out[k] = v
    return out


def as_nc_char(ds: xr.Dataset) -> xr.Dataset:
    """A shallow copy of ``ds`` whose global and variable string attributes are written as NC_CHAR."""
    out = ds.copy(deep=False)
    out.attrs = _nc_char(out.attrs)
    for n in out.variables:
        out[n].attrs = _nc_char(out[n].attrs)
    return out


def write_netcdf(ds: xr.Dataset, path: str | Path, *, title: str, summary: str, **attrs: Any) -> Path:
    """Write ``ds`` to NetCDF-4 with CF-1.8/ACDD-1.3 metadata completed (see module docstring).

    ``attrs`` become global attributes and override everything computed; the special keyword
    ``provenance_from=draft`` (the store ``Draft`` being written) adds dive, product, parameters and
    upstream versions to the ``hadal_provenance`` attribute.
    """
    path = Path(path)
    if not isinstance(ds, xr.Dataset):
        raise InputError(f"write_netcdf({path.name}): expected an xarray Dataset, got {type(ds).__name__}")
    from hadal.store import ensure_free_space

    # refuse early when even the uncompressed variables do not fit (a lower bound of the file size)
    ensure_free_space(path, netcdf_size_lower_bound(ds), path.name)
    out = prepare_dataset(ds, path, title=title, summary=summary, **attrs)
    # HDF5 never writes to the store: it encodes into memory, then the bytes are written with a free-space
    # check and plain os.write. HDF5 writing into a file on a full disk crashes the process (h5netcdf/h5py
    # close the file in __dealloc__ after a failed write: tracebacks, then a segfault), so it never does.
    _write_file(path, netcdf_bytes(as_nc_char(out)))
    return path


def write_dataset_exact(ds: xr.Dataset, path: str | Path) -> Path:
    """``ds`` as xarray's own NetCDF-4 encoding (:func:`netcdf_bytes`: values, dtypes and attributes read back
    exactly by :func:`read_dataset_exact`), without the CF/ACDD completion of :func:`write_netcdf`: a stage's
    internal hand-over to a later stage, not a user product. Written like every file of the store (free-space
    check, no partial file)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    _write_file(path, netcdf_bytes(ds))
    return path


def read_dataset_exact(path: str | Path) -> xr.Dataset:
    """The dataset :func:`write_dataset_exact` wrote, loaded, with no encoding left on it (a later
    :func:`write_netcdf` of it encodes it afresh, as it would the original)."""
    with xr.open_dataset(path, engine="h5netcdf") as src:
        ds = src.load()
    ds.encoding = {}
    for v in ds.variables.values():
        v.encoding = {}
    return ds


def netcdf_bytes(ds: xr.Dataset) -> memoryview:
    """The NetCDF-4 file of ``ds`` in memory, byte for byte what ``ds.to_netcdf(engine="h5netcdf")`` returns
    (tests/unit/products/test_products.py checks it), written through xarray's h5netcdf store with a plain lock.

    Why not ``to_netcdf`` itself: with dask installed it asks dask which scheduler is active, and that imports
    ``dask.distributed`` (~1.2 s of CPU, measured) in every process that writes a NetCDF file, the stage processes
    included, for a lock an in-memory write of loaded data does not need. The variables are loaded first (a lazy
    variable would otherwise be left to a dask writer that this path never runs)."""
    import io
    import threading

    from xarray.backends import H5NetCDFStore

    buf = io.BytesIO()
    store = H5NetCDFStore.open(buf, mode="w", lock=threading.Lock(), invalid_netcdf=False)
    try:
        ds.load().dump_to_store(store)
    finally:
        store.close()
    return buf.getbuffer()


#: Zarr format written: v2 (consolidated metadata) is read by every Zarr reader (zarr-python 2 and 3, GDAL,
#: xarray, R, Julia); v3 readers are fewer
ZARR_FORMAT = 2


def write_zarr(netcdf_path: str | Path, path: str | Path, *, chunk: int = 512) -> Path:
    """The NetCDF product ``netcdf_path`` (written by :func:`write_netcdf`) also as a Zarr store (a directory
    ``path``): the same variables, values, encodings and attributes (CF/ACDD/IOOS globals, grid mapping),
    chunked ``chunk`` x ``chunk`` along ``y``/``x`` (other dimensions whole), copied chunk by chunk (dask) so a
    large grid is never held whole. zarr is an optional dependency (``pip install 'hadal[zarr]'``); without it a
    one-line :class:`hadal.errors.ConfigError`."""
    netcdf_path, path = Path(netcdf_path), Path(path)
    try:
        import zarr  # noqa: F401 - the optional dependency, imported only to fail early and clearly
    except ImportError:
        from hadal.errors import ConfigError

        raise ConfigError(f"{path.name}: writing Zarr grids (grid.zarr: true) needs the zarr package, which is "
                          "not installed (pip install 'hadal[zarr]', or set grid.zarr: false)") from None
    from hadal.store import ensure_free_space

    if path.exists():
        raise InputError(f"{path} already exists (a Zarr store is written once, never overwritten)")
    with xr.open_dataset(netcdf_path, engine="h5netcdf", chunks={}) as src:
        ensure_free_space(path, netcdf_size_lower_bound(src), path.name)
        encoding = {}
        for n, v in src.variables.items():
            enc = {k: val for k, val in v.encoding.items() if k in ("dtype", "_FillValue", "units", "calendar",
                                                                      "scale_factor", "add_offset")}
            enc.setdefault("_FillValue", None)  # none in the NetCDF (coordinates): none in the Zarr either
            if v.ndim and n not in src.dims:
                enc["chunks"] = tuple(min(int(chunk), sz) if d in ("y", "x") else sz
                                      for d, sz in zip(v.dims, v.shape, strict=True))
            encoding[n] = enc
        ds = src.chunk({d: min(int(chunk), src.sizes[d]) if d in ("y", "x") else -1 for d in src.dims})
        for v in ds.variables.values():
            v.encoding = {}
        ds.to_zarr(path, mode="w-", zarr_format=ZARR_FORMAT, consolidated=True, encoding=encoding)
    return path


def netcdf_size_lower_bound(ds: xr.Dataset) -> int:
    """Bytes the NetCDF file of ``ds`` takes at least: the ``nbytes`` of its uncompressed variables."""
    total = 0
    for v in ds.variables.values():
        enc = v.encoding
        if not (enc.get("zlib") or enc.get("compression") or enc.get("compression_opts")):
            total += int(v.nbytes)
    return total
