"""STAC catalog of a product store (issues 18, 46): one Item per dive, every version of every product as assets
with file (size, SHA-256 multihash), projection and raster fields, thumbnails, the full footprint; validated
offline against the STAC core JSON schemas (pystac + jsonschema: pystac ships them) and an offline check of the
extension fields (hadal.products.stac.check_extension_fields); against the extensions' own JSON schemas when
HADAL_STAC_EXTENSION_SCHEMAS names a directory holding them (none is shipped: they live on the network)."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import xarray as xr
from pyproj import CRS

pytest.importorskip("pystac")
pytest.importorskip("jsonschema")

from hadal.geo import LocalFrame  # noqa: E402
from hadal.products import write_netcdf, write_parquet  # noqa: E402
from hadal.products.stac import validate_store_catalog, write_store_catalog  # noqa: E402
from hadal.store import ProductStore  # noqa: E402

FRAME = LocalFrame(11.33, 142.2)


def _store(tmp_path) -> ProductStore:
    store = ProductStore(tmp_path / "store")
    t = pd.date_range("2018-10-06T23:00:00", periods=200, freq="10s", tz="UTC")
    lon, lat = FRAME.to_lonlat(np.linspace(0, 900, 200), np.linspace(0, 400, 200))
    nav = pd.DataFrame({"time": t, "lat": lat, "lon": lon, "depth_m": np.linspace(0, 10000, 200)})
    for dive in ("dive-a", "dive-b"):
        with store.publish(dive, "navigation") as d:
            write_parquet(nav, d.path / "navigation.parquet")
    with store.publish("dive-a", "navigation") as d:  # a second version: both are catalogued
        write_parquet(nav, d.path / "navigation.parquet")
    # the DTM reaches 2 km south-west of the track: the item's footprint is the track's and the grid's
    x, y = np.arange(-2000.0, 400.0, 20.0), np.arange(-2000.0, 200.0, 20.0)
    X, Y = np.meshgrid(x, y)
    glon, glat = FRAME.to_lonlat(X, Y)
    dtm = xr.Dataset({"depth_m": (("y", "x"), 10900 + X / 100, {"positive": "down", "units": "m"}),
                      "lat": (("y", "x"), glat), "lon": (("y", "x"), glon),
                      "crs": ((), 0, {"crs_wkt": FRAME.crs.to_wkt()})}, coords={"x": x, "y": y})
    with store.publish("dive-a", "dtm") as d:
        write_netcdf(dtm, d.path / "dtm.nc", title="t", summary="s")
        from hadal.products.geotiff import write_grid_cog

        write_grid_cog(dtm, d.path / "dtm.tif")
    return store


def test_catalog_validates_and_describes_every_dive(tmp_path):
    import hashlib

    store = _store(tmp_path)
    cat = write_store_catalog(store)
    problems = validate_store_catalog(store.root, verify_checksums=True)
    assert problems == []
    c = json.loads(cat.read_text())
    assert c["type"] == "Catalog" and {ln["href"] for ln in c["links"] if ln["rel"] == "item"} == {
        "./dive-a/stac-item.json", "./dive-b/stac-item.json"}
    item = json.loads((store.root / "dive-a" / "stac-item.json").read_text())
    nav = pd.read_parquet(store.latest("dive-a", "navigation").file("navigation.parquet"))
    # full footprint: the track and the DTM's cells (corners through pyproj, independent of the COG reader)
    clon, clat = FRAME.to_lonlat(np.array([-2010.0, 390.0, 390.0, -2010.0]), np.array([-2010.0, -2010.0, 190.0, 190.0]))
    want = [min(nav.lon.min(), clon.min()), min(nav.lat.min(), clat.min()), max(nav.lon.max(), clon.max()),
            max(nav.lat.max(), clat.max())]
    assert item["bbox"] == pytest.approx(want, abs=1e-7)
    assert item["geometry"]["type"] == "Polygon"
    from matplotlib.path import Path as MPath

    ring = MPath(np.array(item["geometry"]["coordinates"][0]))
    assert ring.contains_points(np.c_[nav.lon, nav.lat][5:-5], radius=1e-9).all() or \
        ring.contains_points(np.c_[nav.lon, nav.lat][5:-5], radius=-1e-9).all()
    assert item["properties"]["start_datetime"] == "2018-10-06T23:00:00Z"
    assert item["properties"]["end_datetime"] == "2018-10-06T23:33:10Z"
    assert item["properties"]["datetime"] is None
    # every version: the latest under its product, the first one under its label
    assert {"navigation/navigation.parquet", "navigation/manifest.json", "dtm/dtm.nc",
            "navigation/v001/navigation.parquet"} <= set(item["assets"])
    assert item["properties"]["hadal:all_versions"]["navigation"] == ["v001", "v002"]
    assert item["assets"]["navigation/navigation.parquet"]["hadal:latest"] is True
    assert item["assets"]["navigation/v001/navigation.parquet"]["href"] == "./navigation/v001/navigation.parquet"
    assert item["assets"]["dtm/dtm.nc"]["href"] == "./dtm/v001/dtm.nc"
    assert item["assets"]["dtm/dtm.nc"]["type"] == "application/netcdf"
    assert all(not a["href"].startswith("/") for a in item["assets"].values())
    # file: the multihash of hashlib's SHA-256 and the size of each file
    for key, a in item["assets"].items():
        f = store.root / "dive-a" / a["href"]
        assert a["file:size"] == f.stat().st_size, key
        assert a["file:checksum"] == "1220" + hashlib.sha256(f.read_bytes()).hexdigest(), key
    assert set(item["stac_extensions"]) >= {"https://stac-extensions.github.io/projection/v2.0.0/schema.json",
                                           "https://stac-extensions.github.io/raster/v1.1.0/schema.json",
                                           "https://stac-extensions.github.io/file/v2.1.0/schema.json"}
    # proj and raster on the COG, against rasterio's reading of the file
    import rasterio

    cog = item["assets"]["dtm/dtm.tif"]
    with rasterio.open(store.latest("dive-a", "dtm").file("dtm.tif")) as f:
        assert cog["proj:shape"] == [f.height, f.width] and cog["proj:transform"] == list(f.transform)[:6]
        assert CRS.from_wkt(cog["proj:wkt2"]).equals(FRAME.crs, ignore_axis_order=True)
        assert cog["proj:code"] is None  # a local frame has no authority code
        b = cog["raster:bands"]
        assert [x["data_type"] for x in b] == list(f.dtypes) and [x["nodata"] for x in b] == list(f.nodatavals)
        el = f.read(1, masked=True)
        assert b[0]["statistics"]["minimum"] == pytest.approx(float(el.min()), abs=1e-3)
        assert b[0]["unit"] == "m" and b[0]["spatial_resolution"] == 20.0
    assert item["assets"]["dtm/dtm_thumbnail.png"]["roles"] == ["thumbnail"]
    # self-contained: the store can be moved and the catalog still resolves
    moved = tmp_path / "moved"
    shutil.copytree(store.root, moved)
    assert validate_store_catalog(moved) == []


def test_multihash_is_hashlib_sha256_with_its_prefix():
    import hashlib

    from hadal.products.stac import multihash_sha256

    h = hashlib.sha256(b"hadal").hexdigest()
    mh = bytes.fromhex(multihash_sha256(h))
    assert mh[0] == 0x12 and mh[1] == 32 and mh[2:] == hashlib.sha256(b"hadal").digest()
    with pytest.raises(ValueError):
        multihash_sha256("abc")


def test_extension_field_check_catches_wrong_fields():
    from hadal.products.stac import EXTENSIONS, check_extension_fields

    good = {"stac_extensions": list(EXTENSIONS), "properties": {},
            "assets": {"a": {"proj:shape": [2, 3], "proj:transform": [1, 0, 0, 0, -1, 0], "proj:code": None,
                             "file:size": 3, "file:checksum": "1220" + "ab" * 32,
                             "raster:bands": [{"data_type": "float32", "nodata": -32768.0,
                                               "statistics": {"minimum": 1.0}}]}}}
    assert check_extension_fields(good) == []
    bad = json.loads(json.dumps(good))
    bad["assets"]["a"].update({"proj:shape": [2.5, 3], "file:checksum": "XYZ", "proj:epsg": 4326})
    bad["assets"]["a"]["raster:bands"][0]["data_type"] = "double"
    bad["stac_extensions"] = []
    problems = "\n".join(check_extension_fields(bad))
    for want in ("proj:shape", "file:checksum", "proj:epsg", "data_type", "stac_extensions"):
        assert want in problems


#: the extensions' own JSON schemas, vendored (tests/data/stac-extensions/README.md: source, tag, commit)
EXTENSION_SCHEMAS = Path(__file__).resolve().parents[2] / "data" / "stac-extensions"


def test_items_validate_against_the_extensions_json_schemas(tmp_path):
    """Every item against the projection v2.0.0, raster v1.1.0 and file v2.1.0 JSON schemas (the oracle: the
    extensions' own schemas, not hadal's field check); a wrong field in one asset is caught by them."""
    store = _store(tmp_path)
    write_store_catalog(store)
    assert validate_store_catalog(store.root, schema_dir=EXTENSION_SCHEMAS) == []
    p = store.root / "dive-a" / "stac-item.json"
    item = json.loads(p.read_text())
    asset = next(a for a in item["assets"].values() if "proj:shape" in a)
    asset["proj:shape"] = [2.5, -3]
    asset["file:size"] = "big"
    p.write_text(json.dumps(item))
    problems = "\n".join(validate_store_catalog(store.root, schema_dir=EXTENSION_SCHEMAS))
    assert "projection extension schema" in problems and "file extension schema" in problems


def test_validation_catches_broken_items_and_missing_assets(tmp_path):
    store = _store(tmp_path)
    write_store_catalog(store)
    p = store.root / "dive-b" / "stac-item.json"
    item = json.loads(p.read_text())
    del item["bbox"]  # a Feature with a geometry must have a bbox in STAC
    item["properties"]["start_datetime"] = "not a time"
    p.write_text(json.dumps(item))
    (store.latest("dive-a", "dtm").path / "dtm.nc").unlink()
    try:
        problems = validate_store_catalog(store.root)
    except Exception as exc:  # pragma: no cover
        pytest.skip(f"STAC schemas not available: {exc}")
    assert any("item dive-b" in q for q in problems)
    assert any("missing file ./dtm/v001/dtm.nc" in q for q in problems)


def test_dive_named_dive_keeps_its_identity_record(tmp_path):
    """A dive whose id is ``dive``: its STAC Item must not overwrite ``<store>/dive/dive.json`` (the identity
    record ``claim_dive`` checks; it did, and the next stage then refused the dive as someone else's)."""
    from hadal.products.stac import write_store_catalog
    from hadal.store import ProductStore

    st = ProductStore(tmp_path / "store")
    with st.publish("dive", "notes", parameters={}) as draft:
        (draft.path / "a.txt").write_text("a")
    raw = tmp_path / "raw"
    raw.mkdir()
    st.claim_dive("dive", raw, "fp1")
    before = (st.root / "dive" / "dive.json").read_text()
    write_store_catalog(st)
    assert (st.root / "dive" / "dive.json").read_text() == before
    st.claim_dive("dive", raw, "fp1", check_only=True)  # still ours
    assert (st.root / "dive" / "stac-item.json").is_file()
