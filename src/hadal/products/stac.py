"""A STAC catalog of a product store (pystac): browse and search a cruise's dives with standard tools.

Layout (written by :func:`write_store_catalog`, rewritten after every report, atomically per file)::

    <store>/catalog.json            STAC Catalog (id ``hadal-store``), one child link per dive
    <store>/<dive>/stac-item.json      STAC Item: the dive - geometry (its track, else the footprint of its grids),
                                    start/end time, platform, instruments; every file of the latest version of
                                    every product as an asset (``<product>/<vNNN>/<file>``, relative hrefs)

Only STAC core fields are used (no extensions), so the catalog validates offline against the core JSON schemas
that pystac ships. hadal-specific fields are namespaced ``hadal:`` (product versions, dive id).
"""

from __future__ import annotations

import datetime as _dt
import json
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


def _latest_versions(store: Any, dive: str) -> dict[str, Any]:
    out = {}
    for product in store.products(dive):
        try:
            pv = store.latest(dive, product)
            store.check_layout(pv)  # no symlinked file or directory, no name outside the version is catalogued
            out[product] = pv
        except Exception:  # noqa: BLE001 - a product without a readable, well-formed version is left out
            continue
    return out


def _extent(versions: dict[str, Any]) -> tuple[list[float] | None, Any, Any, Any]:
    """(bbox, geometry, start, end) of a dive from its products: the navigation (else ctd) track, else the
    geospatial attributes of its NetCDF files; times from the track or time_coverage_*."""
    import pandas as pd

    lon = lat = None
    start = end = None
    for product, name in (("navigation", "navigation.parquet"), ("ctd", "ctd.parquet")):
        pv = versions.get(product)
        if pv is None or not (pv.path / name).is_file():
            continue
        try:
            cols = ["time", "lat", "lon"]
            df = pd.read_parquet(pv.path / name, columns=cols)
        except Exception:  # noqa: BLE001 - no position columns: try the next source
            continue
        ok = np.isfinite(df["lat"].to_numpy(float)) & np.isfinite(df["lon"].to_numpy(float))
        if ok.any():
            step = max(1, int(ok.sum()) // 500)
            lat = df["lat"].to_numpy(float)[ok][::step]
            lon = df["lon"].to_numpy(float)[ok][::step]
            t = pd.to_datetime(df["time"], utc=True).dropna()
            if len(t):
                start, end = t.min().to_pydatetime(), t.max().to_pydatetime()
            break
    boxes, starts, ends = [], [], []
    start_track = start
    for pv in versions.values():
        for f in sorted(pv.path.glob("*.nc")):
            a = _nc_attrs(f)
            try:
                boxes.append([float(a["geospatial_lon_min"]), float(a["geospatial_lat_min"]),
                              float(a["geospatial_lon_max"]), float(a["geospatial_lat_max"])])
            except (KeyError, TypeError, ValueError):
                pass
            if start_track is None:
                for k, acc in (("time_coverage_start", starts), ("time_coverage_end", ends)):
                    try:
                        acc.append(pd.Timestamp(a[k]).to_pydatetime())
                    except (KeyError, TypeError, ValueError):
                        continue
    if start_track is None and starts:
        start = min(starts)
    if start_track is None and ends:
        end = max(ends)
    if lat is not None and lat.size >= 2:
        coords = [[round(float(a), 7), round(float(b), 7)] for a, b in zip(lon, lat, strict=True)]
        geometry: Any = {"type": "LineString", "coordinates": coords}
        bbox = [float(lon.min()), float(lat.min()), float(lon.max()), float(lat.max())]
        return bbox, geometry, start, end
    if boxes:
        b = np.array(boxes)
        bbox = [float(b[:, 0].min()), float(b[:, 1].min()), float(b[:, 2].max()), float(b[:, 3].max())]
        if bbox[0] == bbox[2] and bbox[1] == bbox[3]:
            return bbox, {"type": "Point", "coordinates": [bbox[0], bbox[1]]}, start, end
        x0, y0, x1, y1 = bbox
        ring = [[x0, y0], [x1, y0], [x1, y1], [x0, y1], [x0, y0]]
        return bbox, {"type": "Polygon", "coordinates": [ring]}, start, end
    return None, None, start, end


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


def dive_item(store: Any, dive: str) -> Any:
    """The STAC Item of one dive (pystac.Item), assets = files of the latest version of each product."""
    import pystac

    versions = _latest_versions(store, dive)
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
                       end_datetime=end, properties=props)
    for product, pv in versions.items():
        for f in _asset_paths(pv.path):
            rel = f.relative_to(pv.path).as_posix()
            media, roles = MEDIA_TYPES.get(f.suffix.lower(), ("application/octet-stream", ["data"]))
            if f.name == "manifest.json":
                roles = ["metadata"]
            key = f"{product}/{rel}"
            item.add_asset(key, pystac.Asset(href=f"./{product}/{pv.label}/{rel}", media_type=media, roles=roles,
                                             title=f"{product} {pv.label}: {rel}"))
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


def validate_store_catalog(root: str | os.PathLike[str]) -> list[str]:
    """Validate ``<root>/catalog.json`` and every item against the STAC core schemas (pystac + jsonschema,
    offline: pystac ships the core schemas). Returns a list of problems (empty = valid)."""
    import pystac

    problems = []
    cat = pystac.Catalog.from_file(str(Path(root) / "catalog.json"))
    try:
        cat.validate()
    except pystac.errors.STACValidationError as exc:
        problems.append(f"catalog: {exc}")
    for item in cat.get_items(recursive=True):
        try:
            item.validate()
        except pystac.errors.STACValidationError as exc:
            problems.append(f"item {item.id}: {exc}")
        for key, a in item.assets.items():
            target = Path(a.get_absolute_href())
            ok = target.is_dir() and any(target.iterdir()) if a.media_type == ZARR_MEDIA_TYPE else target.is_file()
            if not ok:
                problems.append(f"item {item.id}: asset {key} -> missing file {a.href}")
    return problems
