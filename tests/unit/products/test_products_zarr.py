"""Optional Zarr copies of the grids (issue 18: ``grid.zarr: true``): the Zarr store opens with xarray and equals
the NetCDF grid exactly (values, encodings, CF attributes, grid mapping), is chunked as asked, is recorded in the
manifest and as one STAC asset with the Zarr media type; without zarr, a one-line ConfigError."""

from __future__ import annotations

import json

import numpy as np
import pytest
import xarray as xr

from hadal.errors import ConfigError, InputError
from hadal.geo import LocalFrame

FRAME = LocalFrame(11.33, 142.20)


def _grid() -> xr.Dataset:
    x, y = np.arange(0.0, 3000.0, 20.0), np.arange(0.0, 1700.0, 20.0)
    X, Y = np.meshgrid(x, y)
    lon, lat = FRAME.to_lonlat(X, Y)
    depth = 10900 + X / 100 + np.sin(Y / 90)
    depth[:4, :5] = np.nan
    return xr.Dataset({"depth_m": (("y", "x"), depth), "count": (("y", "x"), np.arange(X.size).reshape(X.shape) % 7),
                       "lat": (("y", "x"), lat), "lon": (("y", "x"), lon),
                       "crs": ((), 0, {"crs_wkt": FRAME.crs.to_wkt()})}, coords={"x": x, "y": y})


def test_zarr_equals_the_netcdf_grid_exactly(tmp_path):
    pytest.importorskip("zarr")
    from hadal.products.io import write_netcdf, write_zarr

    nc = write_netcdf(_grid(), tmp_path / "dtm.nc", title="t", summary="s")
    zp = write_zarr(nc, tmp_path / "dtm.zarr", chunk=64)
    with xr.open_dataset(nc) as a, xr.open_zarr(zp) as b:
        xr.testing.assert_identical(a, b.load())  # values, coordinates, every attribute (global and variable)
        assert b["depth_m"].attrs["grid_mapping"] == "crs" and "crs_wkt" in b["crs"].attrs
        assert b["depth_m"].encoding["chunks"] == (64, 64) and b["count"].dtype == a["count"].dtype
        assert b.attrs["Conventions"] == a.attrs["Conventions"] and np.isnan(b["depth_m"].values[0, 0])
    with xr.open_dataset(nc, decode_cf=False) as a, xr.open_zarr(zp, decode_cf=False) as b:
        xr.testing.assert_identical(a, b.load())  # the raw encoded values and _FillValue too
    with pytest.raises(InputError, match="already exists"):  # never overwrites
        write_zarr(nc, zp)


def test_grid_stage_writes_zarr_in_manifest_and_stac(small_dive, tmp_path):
    """The grid stage with grid.zarr: true: dtm.zarr and each laser grid's .zarr beside the NetCDF, their files
    in the manifest, one STAC asset per store (application/vnd+zarr), and the catalog still validates."""
    pytest.importorskip("zarr")
    import warnings

    from hadal.pipeline import make_context, run_stage
    from hadal.settings import PipelineConfig

    # laser outlier removal and spike tests off: the Zarr plumbing is under test, not the gridding (fast)
    cfg = PipelineConfig.model_validate({"grid": {"zarr": True, "zarr_chunk": 64, "laser_sor_neighbors": 0,
                                                  "spike_removal": False, "dtm_resolution_m": 100.0,
                                                  "laser_resolution_m": 0.05}})
    ctx = make_context(small_dive, tmp_path / "store", cfg)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = run_stage("grid", ctx)
    dtm = out["dtm"]
    with xr.open_dataset(dtm.file("dtm.nc")) as a, xr.open_zarr(dtm.path / "dtm.zarr") as b:
        xr.testing.assert_identical(a, b.load())
    names = {f["name"] for f in dtm.manifest()["files"]}
    assert {"dtm.nc", "dtm.tif", "dtm.zarr/.zmetadata"} <= names
    assert any(n.startswith("dtm.zarr/depth_m/") for n in names)
    laser = out["laser_grids"]
    for nc in laser.path.glob("*.nc"):
        with xr.open_dataset(nc) as a, xr.open_zarr(nc.with_suffix(".zarr")) as b:
            xr.testing.assert_identical(a, b.load())
    pytest.importorskip("pystac")
    from hadal.products.stac import dive_item, validate_store_catalog, write_store_catalog

    item = dive_item(ctx.store, ctx.dive_id)
    zarr_assets = {k: a for k, a in item.assets.items() if k.endswith(".zarr")}
    assert "dtm/dtm.zarr" in zarr_assets and len(zarr_assets) == 1 + len(list(laser.path.glob("*.nc")))
    assert all(a.media_type == "application/vnd+zarr" and a.roles == ["data"] for a in zarr_assets.values())
    assert not any(".zarr/" in k for k in item.assets)  # the store's chunks are not assets of their own
    json.dumps(item.to_dict(), allow_nan=False)
    write_store_catalog(ctx.store)
    assert validate_store_catalog(ctx.store.root) == []


def test_zarr_setting_without_zarr_is_a_one_line_config_error(monkeypatch, tmp_path):
    import importlib.util
    import sys

    from hadal.settings import load_config

    real = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a: None if name == "zarr" else real(name, *a))
    cfg = tmp_path / "pipeline.yaml"
    cfg.write_text("grid:\n  zarr: true\n")
    with pytest.raises(ConfigError, match=r"grid\.zarr.*zarr package is not installed") as exc:
        load_config(cfg)
    assert "\n" not in str(exc.value)
    assert load_config(None).grid.zarr is False  # default off
    from hadal.products.io import write_netcdf, write_zarr

    nc = write_netcdf(_grid(), tmp_path / "dtm.nc", title="t", summary="s")
    monkeypatch.setitem(sys.modules, "zarr", None)  # import zarr now raises ImportError
    with pytest.raises(ConfigError, match="needs the zarr package") as exc:
        write_zarr(nc, tmp_path / "dtm.zarr")
    assert "\n" not in str(exc.value) and not (tmp_path / "dtm.zarr").exists()
