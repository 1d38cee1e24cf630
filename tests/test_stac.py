"""STAC catalog of a product store (issue 18): one Item per dive, products as assets, geometry and time span,
validated against the STAC core JSON schemas (pystac + jsonschema; offline: pystac ships the core schemas)."""

from __future__ import annotations

import json
import shutil

import numpy as np
import pandas as pd
import pytest
import xarray as xr

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
    x, y = np.arange(0.0, 400.0, 20.0), np.arange(0.0, 200.0, 20.0)
    X, Y = np.meshgrid(x, y)
    glon, glat = FRAME.to_lonlat(X, Y)
    dtm = xr.Dataset({"depth_m": (("y", "x"), 10900 + X / 100), "lat": (("y", "x"), glat),
                      "lon": (("y", "x"), glon)}, coords={"x": x, "y": y})
    with store.publish("dive-a", "dtm") as d:
        write_netcdf(dtm, d.path / "dtm.nc", title="t", summary="s")
    return store


def test_catalog_validates_and_describes_every_dive(tmp_path):
    store = _store(tmp_path)
    cat = write_store_catalog(store)
    try:
        problems = validate_store_catalog(store.root)
    except Exception as exc:  # pragma: no cover - a schema that pystac could not resolve offline
        pytest.skip(f"STAC schemas not available: {exc}")
    assert problems == []
    c = json.loads(cat.read_text())
    assert c["type"] == "Catalog" and {ln["href"] for ln in c["links"] if ln["rel"] == "item"} == {
        "./dive-a/stac-item.json", "./dive-b/stac-item.json"}
    item = json.loads((store.root / "dive-a" / "stac-item.json").read_text())
    nav = pd.read_parquet(store.latest("dive-a", "navigation").file("navigation.parquet"))
    assert item["bbox"] == pytest.approx([nav.lon.min(), nav.lat.min(), nav.lon.max(), nav.lat.max()])
    assert item["geometry"]["type"] == "LineString"
    assert item["properties"]["start_datetime"] == "2018-10-06T23:00:00Z"
    assert item["properties"]["end_datetime"] == "2018-10-06T23:33:10Z"
    assert item["properties"]["datetime"] is None
    assert {"navigation/navigation.parquet", "navigation/manifest.json", "dtm/dtm.nc"} <= set(item["assets"])
    assert item["assets"]["dtm/dtm.nc"]["href"] == "./dtm/v001/dtm.nc"
    assert item["assets"]["dtm/dtm.nc"]["type"] == "application/netcdf"
    assert all(not a["href"].startswith("/") for a in item["assets"].values())
    # self-contained: the store can be moved and the catalog still resolves
    moved = tmp_path / "moved"
    shutil.copytree(store.root, moved)
    assert validate_store_catalog(moved) == []


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
