"""A STAC catalog of a product store (pystac): browse and search a cruise's dives with standard tools.

Layout (written by :func:`write_store_catalog`, rewritten after every report, atomically per file)::

    <store>/catalog.json            STAC Catalog (id ``hadal-store``), one child link per dive
    <store>/<dive>/stac-item.json   STAC Item: the dive - geometry and bbox of its full footprint (the convex hull
                                    of its track and of the footprints of its grids and NetCDF files), start/end
                                    time, platform, instruments; every file of every version of every product as
                                    an asset (the latest as ``<product>/<file>``, older ones as
                                    ``<product>/<vNNN>/<file>``; ``hadal:version``/``hadal:latest`` on each)

Extensions: ``file`` v2.1.0 (``file:size`` and ``file:checksum``: the SHA-256 of the version's manifest as a
multihash, ``1220`` + hex digest), ``projection`` v2.0.0 on every COG (``proj:code`` when the CRS has an
authority code, else null, ``proj:wkt2``, ``proj:shape``, ``proj:transform``) and ``raster`` v1.1.0
(``raster:bands``: data type, nodata, unit, statistics, spatial resolution). ``*_thumbnail.png`` files are
``thumbnail`` assets. hadal-specific fields are namespaced ``hadal:``.

Validation (:func:`validate_store_catalog`, offline: no network here or on CI): the STAC core JSON schemas that
pystac ships, and :func:`check_extension_fields`, an offline check of the extension fields against the
extensions' field definitions (types, shapes, multihash). The extensions' own JSON schemas are used when a
directory holding them is given (``schema_dir``: ``projection.json``, ``raster.json``, ``file.json``).
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import os
import re
import uuid
from pathlib import Path
from typing import Any

import numpy as np

CATALOG_ID = "hadal-store"

#: file suffix -> (media type, roles)
MEDIA_TYPES: dict[str, tuple[str, list[str]]] = {
    ".parquet": ("application/vnd.apache.parquet", ["data"]),
    ".nc": ("application/netcdf", ["data"]),
    ".tif": ("image/tiff; application=geotiff; profile=cloud-optimized", ["data"]),
    ".geojson": ("application/geo+json", ["data"]),
    ".json": ("application/json", ["metadata"]),
    ".html": ("text/html", ["overview"]),
    ".png": ("image/png", ["visual"]),
    ".zarr": ("application/vnd+zarr", ["data"]),  # a Zarr store (directory): one asset (pystac MediaType.ZARR)
}
ZARR_MEDIA_TYPE = MEDIA_TYPES[".zarr"][0]


def _asset_paths(root: Path) -> list[Path]:
    """The files of a product version, a Zarr store (``*.zarr`` directory) counted as one asset."""
    out: set[Path] = set()
    for f in root.rglob("*"):
        if not f.is_file():
            continue
        rel = f.relative_to(root)
        store = next((i for i, part in enumerate(rel.parts[:-1]) if part.lower().endswith(".zarr")), None)
        out.add(root.joinpath(*rel.parts[:store + 1]) if store is not None else f)
    return sorted(out)


def _all_versions(store: Any, dive: str) -> dict[str, list[tuple[Any, list[tuple[str, dict[str, Any]]]]]]:
    """{product: [(version, manifest file records)], oldest first} of the versions whose layout is as published
    (a version without a readable, well-formed manifest, or with a symlinked or unlisted file, is left out)."""
    out: dict[str, list[tuple[Any, list[tuple[str, dict[str, Any]]]]]] = {}
    for product in store.products(dive):
        for pv in store.versions(dive, product):
            try:
                out.setdefault(product, []).append((pv, store.check_layout(pv)))
            except Exception:  # noqa: BLE001 - a version that is not as published is not catalogued
                continue
        if not out.get(product):
            out.pop(product, None)
    return out


def multihash_sha256(hex_digest: str) -> str:
    """A SHA-256 hex digest as a multihash (https://multiformats.io/multihash/: code 0x12 sha2-256, length 0x20),
    the form of the STAC ``file:checksum`` field."""
    if not re.fullmatch(r"[0-9a-fA-F]{64}", hex_digest or ""):
        raise ValueError(f"not a SHA-256 hex digest: {hex_digest!r}")
    return "1220" + hex_digest.lower()


def _track(versions: dict[str, Any]) -> tuple[np.ndarray | None, np.ndarray | None, Any, Any]:
    """(lon, lat, start, end) of the navigation (else ctd) track of the latest versions."""
    import pandas as pd

    for product, name in (("navigation", "navigation.parquet"), ("ctd", "ctd.parquet")):
        pv = versions.get(product)
        if pv is None or not (pv.path / name).is_file():
            continue
        try:
            df = pd.read_parquet(pv.path / name, columns=["time", "lat", "lon"])
        except Exception:  # noqa: BLE001 - no position columns: try the next source
            continue
        lat, lon = df["lat"].to_numpy(float), df["lon"].to_numpy(float)
        ok = np.isfinite(lat) & np.isfinite(lon)
        if ok.any():
            t = pd.to_datetime(df["time"], utc=True).dropna()
            start, end = (t.min().to_pydatetime(), t.max().to_pydatetime()) if len(t) else (None, None)
            return lon[ok], lat[ok], start, end
    return None, None, None, None


def cog_footprint_lonlat(path: Path, per_side: int = 16) -> np.ndarray | None:
    """(n, 2) lon/lat of points along the edges of a GeoTIFF's raster (its true, possibly rotated, footprint),
    through the file's own CRS (rasterio + pyproj); None when the file has no CRS or cannot be read."""
    try:
        import rasterio
        from pyproj import CRS, Transformer

        with rasterio.open(path) as f:
            if f.crs is None:
                return None
            w, h, T, wkt = f.width, f.height, f.transform, f.crs.to_wkt()
    except Exception:  # noqa: BLE001 - not a readable georeferenced raster
        return None
    s = np.linspace(0.0, 1.0, per_side)
    cols = np.concatenate([s * w, np.full(per_side, float(w)), s[::-1] * w, np.zeros(per_side)])
    rows = np.concatenate([np.zeros(per_side), s * h, np.full(per_side, float(h)), s[::-1] * h])
    x, y = T.a * cols + T.b * rows + T.c, T.d * cols + T.e * rows + T.f
    lon, lat = Transformer.from_crs(CRS.from_wkt(wkt), CRS.from_epsg(4326), always_xy=True).transform(x, y)
    pts = np.column_stack([lon, lat])
    return pts[np.isfinite(pts).all(axis=1)]


def _footprint_points(versions: dict[str, Any]) -> tuple[list[np.ndarray], list[Any], list[Any]]:
    """Points of the footprints of the grids (COGs) and NetCDF files of the latest versions, and the NetCDF
    files' time_coverage_start/end."""
    import pandas as pd

    pts, starts, ends = [], [], []
    for pv in versions.values():
        for f in sorted(pv.path.glob("*.tif")):
            fp = cog_footprint_lonlat(f)
            if fp is not None and len(fp):
                pts.append(fp)
        for f in sorted(pv.path.glob("*.nc")):
            a = _nc_attrs(f)
            try:
                x0, y0 = float(a["geospatial_lon_min"]), float(a["geospatial_lat_min"])
                x1, y1 = float(a["geospatial_lon_max"]), float(a["geospatial_lat_max"])
                pts.append(np.array([[x0, y0], [x1, y0], [x1, y1], [x0, y1]]))
            except (KeyError, TypeError, ValueError):
                pass
            for k, acc in (("time_coverage_start", starts), ("time_coverage_end", ends)):
                try:
                    acc.append(pd.Timestamp(a[k]).to_pydatetime())
                except (KeyError, TypeError, ValueError):
                    continue
    return pts, starts, ends


def convex_hull(points: np.ndarray) -> np.ndarray:
    """Counter-clockwise convex hull (Andrew's monotone chain) of (n, 2) points, without the closing point."""
    p = np.unique(np.asarray(points, float), axis=0)
    if len(p) < 3:
        return p

    def half(seq: np.ndarray) -> list[np.ndarray]:
        out: list[np.ndarray] = []
        for q in seq:
            while len(out) >= 2 and ((out[-1][0] - out[-2][0]) * (q[1] - out[-2][1])
                                     - (out[-1][1] - out[-2][1]) * (q[0] - out[-2][0])) <= 0:
                out.pop()
            out.append(q)
        return out

    lower, upper = half(p), half(p[::-1])
    return np.array(lower[:-1] + upper[:-1])


def _extent(versions: dict[str, Any]) -> tuple[list[float] | None, Any, Any, Any]:
    """(bbox, geometry, start, end) of a dive: the convex hull of its full footprint - the navigation (else ctd)
    track and the footprints of its grids and NetCDF files - as a Polygon (a LineString or Point when the
    footprint is degenerate); times from the track, else the NetCDF files' time_coverage_*. Longitudes are taken
    in [-180, 180] (a footprint across the antimeridian is not split)."""
    lon, lat, start, end = _track(versions)
    pts, starts, ends = _footprint_points(versions)
    if lon is not None:
        step = max(1, lon.size // 2000)
        pts.append(np.column_stack([lon[::step], lat[::step]]))
        pts.append(np.array([[lon[-1], lat[-1]]]))
    if start is None and starts:
        start = min(starts)
    if end is None and ends:
        end = max(ends)
    if not pts:
        return None, None, start, end
    allp = np.concatenate(pts)
    allp = allp[np.isfinite(allp).all(axis=1)]
    if not len(allp):
        return None, None, start, end
    bbox = [float(allp[:, 0].min()), float(allp[:, 1].min()), float(allp[:, 0].max()), float(allp[:, 1].max())]
    hull = convex_hull(allp)
    rnd = [[round(float(a), 8), round(float(b), 8)] for a, b in hull]
    if len(hull) >= 3:
        geometry: Any = {"type": "Polygon", "coordinates": [rnd + [rnd[0]]]}
    elif len(hull) == 2:
        geometry = {"type": "LineString", "coordinates": rnd}
    else:
        geometry = {"type": "Point", "coordinates": rnd[0]}
    return bbox, geometry, start, end


def _nc_attrs(path: Path) -> dict[str, Any]:
    try:
        import h5py

        with h5py.File(path, "r") as f:
            out = {}
            for k in ("geospatial_lon_min", "geospatial_lat_min", "geospatial_lon_max", "geospatial_lat_max",
                      "time_coverage_start", "time_coverage_end", "instrument", "platform_name", "license"):
                if k in f.attrs:
                    v = f.attrs[k]
                    out[k] = v.decode("utf-8", "replace") if isinstance(v, bytes) else (
                        v.item() if hasattr(v, "item") else v)
            return out
    except Exception:  # noqa: BLE001 - unreadable file: no extent from it
        return {}


def cog_asset_fields(path: Path) -> dict[str, Any]:
    """``proj:*`` and ``raster:bands`` of a GeoTIFF from its header (rasterio; statistics from the bands'
    ``STATISTICS_*`` metadata that :func:`hadal.products.geotiff.write_grid_cog` writes); {} if unreadable."""
    try:
        import rasterio
        from pyproj import CRS

        with rasterio.open(path) as f:
            out: dict[str, Any] = {"proj:shape": [f.height, f.width], "proj:transform": [float(v) for v in f.transform[:6]]}
            if f.crs is not None:
                crs = CRS.from_wkt(f.crs.to_wkt())
                auth = crs.to_authority(min_confidence=100)
                out["proj:code"] = f"{auth[0]}:{auth[1]}" if auth else None
                out["proj:wkt2"] = crs.to_wkt()
            res = float(math.hypot(f.transform.a, f.transform.d))
            bands = []
            for i in range(1, f.count + 1):
                tags = f.tags(i)
                b: dict[str, Any] = {"data_type": str(f.dtypes[i - 1]), "spatial_resolution": res}
                nod = f.nodatavals[i - 1]
                if nod is not None:
                    b["nodata"] = "nan" if math.isnan(nod) else float(nod)
                if f.units[i - 1]:
                    b["unit"] = str(f.units[i - 1])
                stats = {k: float(tags[f"STATISTICS_{k.upper()}"]) for k in ("minimum", "maximum", "mean", "stddev",
                                                                             "valid_percent")
                         if f"STATISTICS_{k.upper()}" in tags}
                if stats:
                    b["statistics"] = stats
                if f.descriptions[i - 1]:
                    b["hadal:description"] = str(f.descriptions[i - 1])
                bands.append(b)
            out["raster:bands"] = bands
            return out
    except Exception:  # noqa: BLE001 - not a readable raster: no projection/raster fields
        return {}


def _file_fields(f: Path, entry: dict[str, Any] | None) -> dict[str, Any]:
    """``file:size`` and ``file:checksum`` (multihash of the SHA-256) of a file, from its manifest record (the
    version's own manifest.json is hashed here); {} for a Zarr store (a directory)."""
    if f.is_dir():
        return {}
    if entry and isinstance(entry.get("sha256"), str) and isinstance(entry.get("bytes"), int):
        return {"file:size": int(entry["bytes"]), "file:checksum": multihash_sha256(entry["sha256"])}
    from hadal.store import sha256_file

    return {"file:size": f.stat().st_size, "file:checksum": multihash_sha256(sha256_file(f))}


def _asset(item: Any, key: str, product: str, pv: Any, f: Path, entry: dict | None, latest: bool) -> None:
    import pystac

    rel = f.relative_to(pv.path).as_posix()
    media, roles = MEDIA_TYPES.get(f.suffix.lower(), ("application/octet-stream", ["data"]))
    if f.name == "manifest.json":
        roles = ["metadata"]
    elif f.name.endswith("_thumbnail.png"):
        roles = ["thumbnail"]
    extra: dict[str, Any] = {"hadal:version": pv.label, "hadal:latest": latest, **_file_fields(f, entry)}
    if f.suffix.lower() in (".tif", ".tiff"):
        extra.update(cog_asset_fields(f))
    title = f"{product} {pv.label}: {rel}" + ("" if latest else " (superseded)")
    item.add_asset(key, pystac.Asset(href=f"./{product}/{pv.label}/{rel}", media_type=media, roles=roles,
                                     title=title, extra_fields=extra))


#: the extensions the items use (pystac's schema URIs)
EXTENSIONS = ("https://stac-extensions.github.io/projection/v2.0.0/schema.json",
              "https://stac-extensions.github.io/raster/v1.1.0/schema.json",
              "https://stac-extensions.github.io/file/v2.1.0/schema.json")


def dive_item(store: Any, dive: str) -> Any:
    """The STAC Item of one dive (pystac.Item): every file of every version of each product as an asset."""
    import pystac

    allv = _all_versions(store, dive)
    versions = {p: vs[-1][0] for p, vs in allv.items()}
    bbox, geometry, start, end = _extent(versions)
    now = _dt.datetime.now(_dt.UTC).replace(microsecond=0)
    start = start or end or now
    end = end or start
    instruments, platform, license_ = set(), None, None
    for pv in versions.values():
        for f in sorted(pv.path.glob("*.nc"))[:3]:
            a = _nc_attrs(f)
            instruments |= {s.strip() for s in str(a.get("instrument", "")).split(",") if s.strip()}
            platform = platform or a.get("platform_name")
            license_ = license_ or a.get("license")
    props: dict[str, Any] = {"title": f"dive {dive}", "hadal:dive_id": dive,
                             "hadal:product_versions": {p: pv.label for p, pv in versions.items()},
                             "hadal:all_versions": {p: [v.label for v, _ in vs] for p, vs in allv.items()},
                             "start_datetime": _iso(start), "end_datetime": _iso(end)}
    if platform:
        props["platform"] = str(platform)
    if instruments:
        props["instruments"] = sorted(instruments)
    if license_:  # STAC wants an SPDX id, else "other" (the text is kept)
        spdx = re.fullmatch(r"[\w\-.+]+", str(license_).strip())
        props["license"] = str(license_).strip() if spdx else "other"
        if not spdx:
            props["hadal:license_text"] = str(license_)
    item = pystac.Item(id=dive, geometry=geometry, bbox=bbox, datetime=None, start_datetime=start,
                       end_datetime=end, properties=props, stac_extensions=list(EXTENSIONS))
    for product, vs in allv.items():
        for pv, entries in vs:
            latest = pv is versions[product]
            records = dict(entries)
            for f in _asset_paths(pv.path):
                rel = f.relative_to(pv.path).as_posix()
                key = f"{product}/{rel}" if latest else f"{product}/{pv.label}/{rel}"
                _asset(item, key, product, pv, f, records.get(rel), latest)
    return item


def _iso(t: Any) -> str:
    t = t.astimezone(_dt.UTC) if t.tzinfo else t.replace(tzinfo=_dt.UTC)
    return t.replace(microsecond=0).isoformat().replace("+00:00", "Z")


def store_catalog(store: Any) -> tuple[Any, dict[str, Any]]:
    """(pystac.Catalog, {dive: Item}) of every dive of ``store`` (nothing written)."""
    import pystac

    cat = pystac.Catalog(id=CATALOG_ID, description=f"hadal product store {Path(store.root).name}: one item per dive",
                         title="hadal product store")
    items = {}
    for dive in store.dives():
        if not store.products(dive):
            continue
        items[dive] = dive_item(store, dive)
        cat.add_item(items[dive])
    return cat, items


def _write_json(path: Path, obj: dict[str, Any]) -> None:
    tmp = path.with_name(f".{path.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}")
    tmp.write_text(json.dumps(obj, indent=2, allow_nan=False), encoding="utf-8")
    os.replace(tmp, path)


#: file name of a dive's STAC Item, beside its products (never ``<dive>.json``: dive ``dive`` would overwrite its
#: ``dive.json`` identity record)
ITEM_FILE = "stac-item.json"


def write_store_catalog(store: Any) -> Path:
    """Write ``<store>/catalog.json`` and ``<store>/<dive>/stac-item.json`` (relative links). Returns the catalog
    path."""
    root = Path(store.root)
    cat, items = store_catalog(store)
    cat.normalize_hrefs(str(root), strategy=_DiveLayout())
    for dive, item in items.items():  # a fixed name: '<dive>.json' would be the identity record of dive 'dive'
        item.set_self_href(str(root / dive / ITEM_FILE))
    for dive, item in items.items():
        d = _relative_links(item.to_dict(include_self_link=False, transform_hrefs=False), root / dive)
        _write_json(root / dive / ITEM_FILE, d)
    c = _relative_links(cat.to_dict(include_self_link=False, transform_hrefs=False), root)
    _write_json(root / "catalog.json", c)
    return root / "catalog.json"


def _relative_links(d: dict[str, Any], base: Path) -> dict[str, Any]:
    """Links relative to the directory of the file (a self-contained catalog: the store can be moved)."""
    for link in d.get("links", []):
        href = str(link.get("href", ""))
        if href.startswith("/"):
            rel = os.path.relpath(href, start=base)
            link["href"] = rel if rel.startswith(".") else f"./{rel}"
    return d


class _DiveLayout:
    """pystac layout strategy: items at ``<root>/<dive>/stac-item.json`` (beside the dive's products)."""

    def __new__(cls) -> Any:
        from pystac.layout import TemplateLayoutStrategy

        return TemplateLayoutStrategy(item_template="${id}")


_DATA_TYPES = {"int8", "int16", "int32", "int64", "uint8", "uint16", "uint32", "uint64", "float16", "float32",
               "float64", "cint16", "cint32", "cfloat32", "cfloat64", "other"}
_STATS = {"mean", "minimum", "maximum", "stddev", "valid_percent"}


def _is_num(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v)


def check_extension_fields(item: dict[str, Any]) -> list[str]:
    """Offline check of an Item's ``proj:``, ``raster:`` and ``file:`` fields against the field definitions of the
    projection v2.0.0, raster v1.1.0 and file v2.1.0 extensions (types, array shapes, enumerations, multihash
    form), and that an Item using them declares them in ``stac_extensions``. Returns problems (empty = valid)."""
    out: list[str] = []
    used: set[str] = set()
    declared = set(item.get("stac_extensions", []))
    places = [("properties", item.get("properties", {}))] + [(f"asset {k}", v) for k, v in item.get("assets", {}).items()]
    for where, d in places:
        for k, v in d.items():
            prefix = k.split(":", 1)[0] if ":" in k else None
            if prefix in ("proj", "raster", "file"):
                used.add(prefix)
            if k == "proj:code" and not (v is None or isinstance(v, str)):
                out.append(f"{where}: proj:code must be a string or null")
            elif k == "proj:wkt2" and not (v is None or isinstance(v, str)):
                out.append(f"{where}: proj:wkt2 must be a string or null")
            elif k == "proj:shape" and not (isinstance(v, list) and len(v) == 2
                                            and all(isinstance(n, int) and not isinstance(n, bool) for n in v)):
                out.append(f"{where}: proj:shape must be 2 integers [rows, cols]")
            elif k == "proj:transform" and not (isinstance(v, list) and len(v) in (6, 9) and all(map(_is_num, v))):
                out.append(f"{where}: proj:transform must be 6 or 9 numbers")
            elif k == "proj:bbox" and not (isinstance(v, list) and len(v) in (4, 6) and all(map(_is_num, v))):
                out.append(f"{where}: proj:bbox must be 4 or 6 numbers")
            elif k == "file:size" and not (isinstance(v, int) and not isinstance(v, bool) and v >= 0):
                out.append(f"{where}: file:size must be a non-negative integer")
            elif k == "file:checksum" and not (isinstance(v, str) and re.fullmatch(r"[a-f0-9]+", v)):
                out.append(f"{where}: file:checksum must be a lower-case hex multihash")
            elif k == "raster:bands":
                out += _check_bands(where, v)
            elif prefix in ("proj", "raster", "file") and k not in _KNOWN_FIELDS:
                out.append(f"{where}: {k} is not a field of its extension")
    for prefix in sorted(used):
        if not any(f"/{_EXT_NAMES[prefix]}/" in u for u in declared):
            out.append(f"item uses {prefix}: fields but does not list the extension in stac_extensions")
    return out


_EXT_NAMES = {"proj": "projection", "raster": "raster", "file": "file"}
_KNOWN_FIELDS = {"proj:code", "proj:wkt2", "proj:projjson", "proj:geometry", "proj:bbox", "proj:centroid",
                 "proj:shape", "proj:transform", "raster:bands", "file:byte_order", "file:checksum",
                 "file:header_size", "file:size", "file:values", "file:local_path"}


def _check_bands(where: str, bands: Any) -> list[str]:
    if not isinstance(bands, list) or not bands:
        return [f"{where}: raster:bands must be a non-empty array"]
    out = []
    for i, b in enumerate(bands):
        if not isinstance(b, dict) or not b:
            out.append(f"{where}: raster:bands[{i}] must be a non-empty object")
            continue
        if "data_type" in b and b["data_type"] not in _DATA_TYPES:
            out.append(f"{where}: raster:bands[{i}].data_type {b['data_type']!r} is not a raster data type")
        if "nodata" in b and not (_is_num(b["nodata"]) or b["nodata"] in ("nan", "inf", "-inf")):
            out.append(f"{where}: raster:bands[{i}].nodata must be a number or nan/inf/-inf")
        if "unit" in b and not isinstance(b["unit"], str):
            out.append(f"{where}: raster:bands[{i}].unit must be a string")
        if "spatial_resolution" in b and not _is_num(b["spatial_resolution"]):
            out.append(f"{where}: raster:bands[{i}].spatial_resolution must be a number")
        st = b.get("statistics")
        if st is not None and not (isinstance(st, dict) and st and set(st) <= _STATS and all(map(_is_num, st.values()))):
            out.append(f"{where}: raster:bands[{i}].statistics must hold numbers among {sorted(_STATS)}")
    return out


def _schema_problems(d: dict[str, Any], schema_dir: Path) -> list[str]:
    """The extensions' own JSON schemas (``projection.json``, ``raster.json``, ``file.json`` in ``schema_dir``)."""
    import jsonschema

    out = []
    for name in ("projection", "raster", "file"):
        f = schema_dir / f"{name}.json"
        if not f.is_file():
            out.append(f"no {name} extension schema in {schema_dir}")
            continue
        try:
            jsonschema.validate(d, json.loads(f.read_text(encoding="utf-8")))
        except jsonschema.ValidationError as exc:
            out.append(f"{name} extension schema: {exc.message}")
    return out


def validate_store_catalog(root: str | os.PathLike[str], *, schema_dir: str | os.PathLike[str] | None = None,
                           verify_checksums: bool = False) -> list[str]:
    """Validate ``<root>/catalog.json`` and every item: the STAC core schemas (pystac + jsonschema, offline:
    pystac ships them), the extension fields (:func:`check_extension_fields`; with ``schema_dir``, also the
    extensions' JSON schemas), every asset present and, with ``verify_checksums``, its ``file:size`` and
    ``file:checksum`` equal to the file's. Returns a list of problems (empty = valid)."""
    import pystac
    from pystac.validation import validate_dict

    from hadal.store import sha256_file

    problems = []
    cat = pystac.Catalog.from_file(str(Path(root) / "catalog.json"))
    try:
        cat.validate()
    except pystac.errors.STACValidationError as exc:
        problems.append(f"catalog: {exc}")
    for item in cat.get_items(recursive=True):
        d = item.to_dict(include_self_link=False, transform_hrefs=False)
        try:  # core only: the extension schemas live on the network (checked below, offline)
            validate_dict(d, stac_object_type=pystac.STACObjectType.ITEM, extensions=[])
        except pystac.errors.STACValidationError as exc:
            problems.append(f"item {item.id}: {exc}")
        problems += [f"item {item.id}: {q}" for q in check_extension_fields(d)]
        if schema_dir is not None:
            problems += [f"item {item.id}: {q}" for q in _schema_problems(d, Path(schema_dir))]
        for key, a in item.assets.items():
            target = Path(a.get_absolute_href())
            ok = target.is_dir() and any(target.iterdir()) if a.media_type == ZARR_MEDIA_TYPE else target.is_file()
            if not ok:
                problems.append(f"item {item.id}: asset {key} -> missing file {a.href}")
            elif verify_checksums and target.is_file() and "file:checksum" in a.extra_fields:
                if a.extra_fields["file:checksum"] != multihash_sha256(sha256_file(target)) or \
                        a.extra_fields.get("file:size") != target.stat().st_size:
                    problems.append(f"item {item.id}: asset {key} -> {a.href} differs from its file:checksum/size")
    return problems
