"""Product writers: every NetCDF product passes compliance-checker CF-1.8 + ACDD-1.3; Parquet metadata is
readable by pyarrow, pandas, polars and duckdb."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import xarray as xr

from hadal.errors import InputError
from hadal.geo import LocalFrame
from hadal.products import read_parquet_metadata, write_netcdf, write_parquet
from hadal.products.cf import units_from_name
from hadal.store import ProductStore

pytest.importorskip("compliance_checker")
from hadal.products.compliance import check_compliance  # noqa: E402

FRAME = LocalFrame(11.33, 142.20)


def dtm_like() -> xr.Dataset:
    """Like grid's dtm.nc: x/y in the map frame, 2-D lat/lon, crs grid mapping, a boolean flag."""
    x = np.arange(0.0, 400.0, 20.0)
    y = np.arange(0.0, 300.0, 20.0)
    X, Y = np.meshgrid(x, y)
    depth = 10900 - 0.5 * X + 0.2 * Y + 5 * np.sin(X / 50)
    lon, lat = FRAME.to_lonlat(X, Y)
    depth[0, 0] = np.nan
    return xr.Dataset(
        {
            "depth_m": (("y", "x"), depth),
            "depth_median_m": (("y", "x"), depth + 0.1),
            "count": (("y", "x"), np.full(depth.shape, 3, "i4")),
            "depth_std_m": (("y", "x"), np.ones_like(depth)),
            "uncertainty_m": (("y", "x"), np.full_like(depth, 2.5)),
            "filled": (("y", "x"), np.isnan(depth)),
            "lat": (("y", "x"), lat),
            "lon": (("y", "x"), lon),
            "crs": ((), 0, {"crs_wkt": FRAME.crs.to_wkt()}),
        },
        coords={"x": x, "y": y},
        attrs={"map_frame_origin_latitude_deg": 11.33, "map_frame_origin_longitude_deg": 142.2, "resolution_m": 20.0},
    )


def profile_like() -> xr.Dataset:
    """Like derive's profile.nc: pressure bins x phase (string labels), no lat/lon or time variables."""
    p = np.arange(5.0, 10900.0, 10.0)
    ones = np.ones((2, p.size))
    return xr.Dataset(
        {
            "temperature_its90_degc": (("phase", "pressure_dbar"), ones * (1.5 + np.exp(-p / 500))),
            "practical_salinity": (("phase", "pressure_dbar"), ones * 34.7),
            "density_kg_m3": (("phase", "pressure_dbar"), ones * (1028 + p / 200)),
            "gravity_m_s2": (("phase", "pressure_dbar"), ones * (9.78 + p * 2e-6)),
            "depth_m": (("phase", "pressure_dbar"), ones * p * 0.99),
            "count": (("phase", "pressure_dbar"), np.ones((2, p.size), "i4")),
        },
        coords={"pressure_dbar": p, "phase": ["descent", "ascent"]},
        attrs={"launch_latitude_deg": 11.337, "launch_longitude_deg": 142.21,
               "launch_time_utc": "2018-10-06T23:00:00Z", "bin_size_dbar": 10.0},
    )


def suitability_like() -> xr.Dataset:
    """Like suitability.nc: per-block std and entropy on a block grid plus a proposed-region flag."""
    bx = np.arange(0.0, 4000.0, 100.0) + 50
    by = np.arange(0.0, 3000.0, 100.0) + 50
    s = np.random.default_rng(0).random((by.size, bx.size))
    X, Y = np.meshgrid(bx, by)
    lon, lat = FRAME.to_lonlat(X, Y)
    return xr.Dataset(
        {"std_m": (("y", "x"), s * 10), "entropy": (("y", "x"), s), "in_region": (("y", "x"), s > 0.5),
         "lat": (("y", "x"), lat), "lon": (("y", "x"), lon),
         "crs": ((), 0, {"proj4": FRAME.crs.to_proj4()})},
        coords={"x": bx, "y": by},
    )


def msd_like() -> xr.Dataset:
    """Like match's msd_surface.nc: MSD over candidate start positions, plus a time-stamped track."""
    x = np.arange(-500.0, 500.0, 20.0)
    y = np.arange(-400.0, 400.0, 20.0)
    X, Y = np.meshgrid(x, y)
    lon, lat = FRAME.to_lonlat(X, Y)
    return xr.Dataset({"score": (("y", "x"), (X - 100) ** 2 / 1e3 + (Y + 50) ** 2 / 1e3 + 3),
                       "lat": (("y", "x"), lat), "lon": (("y", "x"), lon)}, coords={"x": x, "y": y})


def track_like() -> xr.Dataset:
    t = pd.date_range("2018-10-06T23:00:00", periods=50, freq="1s")
    x = np.linspace(0, 100, 50)
    lon, lat = FRAME.to_lonlat(x, x / 2)
    return xr.Dataset({"seafloor_depth_m": ("time", 10900 + np.sin(x)), "lat": ("time", lat),
                       "lon": ("time", lon), "depth_m": ("time", np.linspace(10800, 10890, 50)),
                       "altitude_m_qc": ("time", np.ones(50, "u1"))}, coords={"time": t})


def landing_maps_like() -> xr.Dataset:
    """Like landing's submap_NN_maps.nc: local laser frame (no lat/lon), 0/1 int8 masks, uint8 bit flags."""
    x = np.arange(0.0, 2.0, 0.01)
    X, Y = np.meshgrid(x, x)
    el = (0.05 * np.sin(X * 2)).astype(np.float32)
    return xr.Dataset(
        {"elevation_m": (("y", "x"), el, {"units": "m", "positive": "up"}),
         "slope_local_deg": (("y", "x"), np.abs(el) * 10),
         "footprint_slope_deg": (("y", "x"), np.abs(el) * 5),
         "protrusion_candidate": (("y", "x"), (el > 0.04).astype(np.int8)),
         "final_site": (("y", "x"), ((X - 1) ** 2 + (Y - 1) ** 2 < 0.1).astype(np.int8), {"long_name": "site"}),
         "exclusion": (("heading", "y", "x"), np.zeros((3, x.size, x.size), np.uint8),
                       {"flag_masks": np.array([1, 2, 4], np.uint8), "flag_meanings": "slope protrusion edge"})},
        coords={"x": x, "y": x, "heading": [-45.0, 0.0, 45.0]},
    )


DIVE_HINTS = {"launch_latitude_deg": 11.3371167, "launch_longitude_deg": 142.2097167,
              "launch_time_utc": "2018-10-06T23:00:00+00:00", "dive_id": "dive-7"}


@pytest.mark.parametrize("make", [dtm_like, profile_like, suitability_like, msd_like, track_like, landing_maps_like])
def test_netcdf_products_pass_cf_and_acdd(tmp_path, make):
    hints = DIVE_HINTS if make is landing_maps_like else {}  # what dive_attributes(ctx.dive) gives a stage
    path = write_netcdf(make(), tmp_path / f"{make.__name__}.nc", title=f"hadal {make.__name__}",
                        summary="synthetic product in the shape of the pipeline's products", **hints)
    rep = check_compliance(path)
    assert rep.ok, rep.describe()
    # the only tolerated findings are the documented exceptions
    assert all(f.allowed for f in rep.findings)


def test_compliance_helper_detects_real_problems(tmp_path):
    """A file written without the writer (plain xarray) fails: the check is not vacuous."""
    p = tmp_path / "plain.nc"
    dtm_like().to_netcdf(p, engine="h5netcdf")
    rep = check_compliance(p)
    assert not rep.ok
    names = " ".join(f.name for f in rep.failures)
    assert "Global Attributes" in names


def test_netcdf_attributes_derived_from_data(tmp_path):
    path = write_netcdf(dtm_like(), tmp_path / "dtm.nc", title="t", summary="s", institution="Test Lab")
    ds = xr.open_dataset(path, engine="h5netcdf")
    lat = ds["lat"].values
    assert ds.attrs["geospatial_lat_min"] == pytest.approx(float(np.nanmin(lat)))
    assert ds.attrs["geospatial_lat_max"] == pytest.approx(float(np.nanmax(lat)))
    assert ds.attrs["geospatial_vertical_max"] == pytest.approx(float(np.nanmax(ds["depth_m"].values)))
    assert ds.attrs["institution"] == "Test Lab"  # caller's attributes win
    assert ds["depth_m"].attrs["grid_mapping"] == "crs"
    assert ds["depth_m"].attrs["units"] == "m"
    assert ds["depth_m"].attrs["standard_name"] == "sea_floor_depth_below_sea_surface"
    assert ds["depth_std_m"].attrs["cell_methods"] == "area: standard_deviation"
    assert ds["crs"].attrs["grid_mapping_name"] == "transverse_mercator"
    assert set(ds.coords) >= {"lat", "lon", "x", "y"}
    assert np.isnan(ds["depth_m"].values[0, 0])  # _FillValue round-trips as NaN
    assert ds["filled"].attrs["flag_meanings"] == "not_filled filled"
    prov = json.loads(ds.attrs["hadal_provenance"])
    assert prov["hadal_version"] and prov["code_version"]
    ds.close()


def test_netcdf_profile_and_store_identity(tmp_path):
    store = ProductStore(tmp_path / "store")
    with store.publish("dive-7", "profile", parameters={"bin_size_dbar": 10}) as draft:
        write_netcdf(profile_like(), draft.path / "profile.nc", title="t", summary="s", provenance_from=draft)
    ds = xr.open_dataset(draft.result.path / "profile.nc", engine="h5netcdf")
    assert ds.attrs["id"] == "dive-7.profile"
    assert ds.attrs["time_coverage_start"] == "2018-10-06T23:00:00Z"
    assert float(ds["lat"]) == pytest.approx(11.337)
    assert "descent" in ds["phase"].attrs["flag_meanings"]
    prov = json.loads(ds.attrs["hadal_provenance"])
    assert prov["dive"] == "dive-7" and prov["parameters"] == {"bin_size_dbar": 10}
    ds.close()


def test_dive_attributes_give_position_and_time(tmp_path):
    from factories import write_fake_dive

    from hadal.dive import load_dive
    from hadal.products import dive_attributes

    dive, _ = load_dive(write_fake_dive(tmp_path / "raw", "dive-9"))
    attrs = dive_attributes(dive)
    assert attrs["dive_id"] == "dive-9" and attrs["launch_latitude_deg"] == pytest.approx(11.3371167)
    path = write_netcdf(landing_maps_like(), tmp_path / "m.nc", title="t", summary="s", **attrs)
    ds = xr.open_dataset(path, engine="h5netcdf")
    assert ds.attrs["geospatial_lat_min"] == pytest.approx(11.3371167)
    assert ds.attrs["time_coverage_start"] == "2018-10-06T23:00:00Z"
    assert ds["exclusion"].dtype == np.int8 and ds["final_site"].attrs["flag_meanings"] == "not_final_site final_site"
    ds.close()


def test_write_netcdf_rejects_non_dataset(tmp_path):
    with pytest.raises(InputError, match="xarray Dataset"):
        write_netcdf({"a": 1}, tmp_path / "x.nc", title="t", summary="s")  # type: ignore[arg-type]
    assert not (tmp_path / "x.nc").exists()


def test_netcdf_bytes_equal_xarray_to_netcdf(tmp_path):
    """hadal writes NetCDF through xarray's h5netcdf store (no dask scheduler query): the file is byte for byte what
    ``Dataset.to_netcdf(engine="h5netcdf")`` writes, for a grid (flags, NaN, grid mapping, compression), a profile
    (string labels, NC_CHAR attributes) and a time series (datetimes, fill values)."""
    from hadal.products.io import as_nc_char, netcdf_bytes, prepare_dataset

    t = pd.date_range("2018-10-06T23:00:00", periods=500, freq="1s").to_numpy()
    series = xr.Dataset({"depth_m": ("time", np.linspace(0, 10900, 500)),
                         "loop_edit_bad": ("time", np.arange(500) % 3 == 0)}, coords={"time": t})
    series["depth_m"].encoding.update(zlib=True, complevel=4, _FillValue=-9999.0)
    for name, ds in (("dtm", dtm_like()), ("profile", profile_like()), ("series", series)):
        out = as_nc_char(prepare_dataset(ds, tmp_path / f"{name}.nc", title=name, summary=f"{name} check"))
        assert bytes(netcdf_bytes(out)) == bytes(out.to_netcdf(engine="h5netcdf")), name


def test_gzip_encoding_read_by_netcdf_c(tmp_path):
    """Variables compressed with :func:`hadal.products.compression.gzip_encoding` are plain deflate that netCDF-C
    (netCDF4-python, an independent reader) decodes exactly, chunked as asked."""
    netCDF4 = pytest.importorskip("netCDF4")
    from hadal.products.compression import GZIP_LEVEL, gzip_encoding

    rng = np.random.default_rng(3)
    ds = dtm_like()
    depth = np.round(ds["depth_m"].values + rng.normal(0, 0.01, ds["depth_m"].shape), 2)  # terrain-like noise
    ds["depth_m"] = (ds["depth_m"].dims, depth, ds["depth_m"].attrs)
    ds["depth_m"].encoding.update(gzip_encoding((4, 5)))
    path = write_netcdf(ds, tmp_path / "g.nc", title="t", summary="s")
    with netCDF4.Dataset(path) as nc:
        v = nc.variables["depth_m"]
        v.set_auto_mask(False)
        filters = v.filters()
        # depth_m is stored as float32 (schemas/variables.yaml precision 0.01 m), byte-shuffled
        assert filters["zlib"] is True and filters["complevel"] == GZIP_LEVEL and filters["shuffle"]
        assert v.chunking() == [4, 5] and v.dtype == np.float32
        np.testing.assert_array_equal(np.asarray(v[:]), depth.astype(np.float32))
        assert np.nanmax(np.abs(np.asarray(v[:], float) - depth)) <= 0.005


def test_writing_netcdf_does_not_import_dask_distributed(tmp_path):
    """Writing a product must not pull in ``dask.distributed`` (the scheduler query of ``to_netcdf``), ~1.2 s of
    imports in each stage process (a fresh interpreter, so earlier tests' imports do not count)."""
    import subprocess
    import sys

    code = ("import sys, numpy as np, xarray as xr\n"
            "from hadal.products import write_netcdf\n"
            "ds = xr.Dataset({'depth_m': ('x', np.arange(3.0))}, coords={'x': np.arange(3.0)})\n"
            f"write_netcdf(ds, {str(tmp_path / 'a.nc')!r}, title='t', summary='s')\n"
            "print('distributed' in sys.modules, 'dask.distributed' in sys.modules)\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["False", "False"]
    with xr.open_dataset(tmp_path / "a.nc", engine="h5netcdf") as back:
        assert back["depth_m"].values.tolist() == [0.0, 1.0, 2.0]


def test_units_from_name_table():
    cases = {"pressure_dbar": "dbar", "temperature_its90_degc": "degree_C", "density_kg_m3": "kg m-3",
             "gravity_m_s2": "m s-2", "sound_speed_m_s": "m s-1", "conductivity_s_m": "S m-1", "depth_m": "m",
             "heading_deg": "degree", "practical_salinity": "1", "phase": None}
    assert {k: units_from_name(k) for k in cases} == cases


@pytest.fixture
def ctd_parquet(tmp_path):
    n = 20
    df = pd.DataFrame({
        "time": pd.date_range("2018-10-06T23:00:00Z", periods=n, freq="62500us"),
        "pressure_dbar": np.linspace(0, 100, n), "temperature_its90_degc": np.linspace(20, 10, n),
        "practical_salinity": np.full(n, 34.6), "depth_m": np.linspace(0, 99, n),
        "pressure_ctd_dbar_qc": np.ones(n, "u1"), "phase": ["descent"] * n,
    })
    path = write_parquet(df, tmp_path / "ctd.parquet", fields={"depth_m": {"long_name": "custom depth"}},
                         metadata={"gauge_bias_dbar": 1.25, "deepest_point": {"depth_m": 99.0}})
    return path, df


def test_parquet_metadata_pyarrow(ctd_parquet):
    path, _ = ctd_parquet
    table_meta, cols = read_parquet_metadata(path)
    assert table_meta["gauge_bias_dbar"] == 1.25
    assert table_meta["provenance"]["hadal_version"]
    assert cols["temperature_its90_degc"]["standard_name"] == "sea_water_temperature"
    assert cols["temperature_its90_degc"]["units"] == "degree_C"
    assert cols["depth_m"]["long_name"] == "custom depth"  # caller wins
    assert cols["pressure_ctd_dbar_qc"]["flag_meanings"].startswith("pass")


def test_parquet_metadata_pandas(ctd_parquet):
    path, df = ctd_parquet
    back = pd.read_parquet(path)
    pd.testing.assert_frame_equal(back, df, check_dtype=False)
    meta = back.attrs["hadal"]
    assert meta["columns"]["pressure_dbar"]["standard_name"] == "sea_water_pressure"
    assert meta["deepest_point"]["depth_m"] == 99.0


def test_parquet_metadata_polars(ctd_parquet):
    pl = pytest.importorskip("polars")
    path, _ = ctd_parquet
    kv = pl.read_parquet_metadata(path)
    meta = json.loads(kv["hadal"])
    assert meta["columns"]["practical_salinity"]["standard_name"] == "sea_water_practical_salinity"
    assert pl.read_parquet(path).height == 20


def test_parquet_metadata_duckdb(ctd_parquet):
    duckdb = pytest.importorskip("duckdb")
    path, _ = ctd_parquet
    rows = duckdb.sql(f"SELECT key, value FROM parquet_kv_metadata('{path}')").fetchall()
    kv = {k.decode(): v.decode() for k, v in rows}
    meta = json.loads(kv["hadal"])
    assert meta["columns"]["depth_m"]["units"] == "m"
    assert meta["provenance"]["code_version"]
    assert duckdb.sql(f"SELECT max(depth_m) FROM '{path}'").fetchall()[0][0] == pytest.approx(99.0)


def test_parquet_dictionary_encodes_labels_not_measurements(tmp_path):
    """Strings and flags are dictionary-encoded, floats and times are not (pyarrow's own column metadata says so);
    every value reads back exactly, with pandas and pyarrow."""
    import pyarrow.parquet as pq

    rng = np.random.default_rng(0)
    n = 5000
    df = pd.DataFrame({"time": pd.date_range("2018-10-06T23:00:00Z", periods=n, freq="100ms"),
                       "depth_m": rng.uniform(0, 10900, n), "phase": np.repeat(["descent", "bottom"], n // 2),
                       "loop_edit_bad": rng.random(n) < 0.1})
    path = write_parquet(df, tmp_path / "t.parquet")
    meta = pq.ParquetFile(path).metadata
    enc = {meta.schema.column(i).name: set(meta.row_group(0).column(i).encodings) for i in range(meta.num_columns)}
    dict_enc = {"PLAIN_DICTIONARY", "RLE_DICTIONARY"}
    assert enc["phase"] & dict_enc and not enc["depth_m"] & dict_enc and not enc["time"] & dict_enc, enc
    pd.testing.assert_frame_equal(pd.read_parquet(path), df, check_dtype=False)
    assert pq.read_table(path).column("depth_m").to_numpy().tolist() == df["depth_m"].tolist()


def test_write_parquet_rejects_non_dataframe(tmp_path):
    with pytest.raises(InputError, match="DataFrame"):
        write_parquet([1, 2], tmp_path / "x.parquet")  # type: ignore[arg-type]


def test_real_products_of_the_small_sample_dive_are_compliant(small_run):
    """Every NetCDF file the pipeline publishes for the small sample dive passes CF + ACDD."""
    ctx, out = small_run
    # the files a version publishes (its top level; internal/ holds a stage's hand-over to a later stage, such as
    # derive's binned casts, written exactly in xarray's encoding and not a product: docs/architecture.md)
    files = sorted(f for pv in out.values() for f in pv.path.glob("*.nc"))
    assert {f.name for f in files} >= {"dtm.nc", "profile.nc", "suitability.nc", "msd_surface.nc"}
    assert any(f.name.startswith("submap_") for f in files)
    bad = [rep.describe() for rep in map(check_compliance, files) if not rep.ok]
    assert not bad, "\n".join(bad)


def test_small_sample_dive_products_are_geographic_strict_and_catalogued(small_run):
    """Issue 18 on the real pipeline output: navigation for every sample, ctd lat/lon, DTM COG, strict JSON,
    manifests with software versions, provenance paths relative to the raw directory, a valid STAC catalog."""
    ctx, out = small_run
    nav = pd.read_parquet(out["navigation"].file("navigation.parquet"))
    ctd = pd.read_parquet(out["ctd"].file("ctd.parquet"))
    assert len(nav) == len(ctd) and {"lat", "lon"} <= set(ctd.columns)
    assert set(nav["position_source"].astype(str)) >= {"matched", "dead_reckoned"}
    assert np.isfinite(nav[["lat", "lon", "position_uncertainty_m"]].to_numpy()).all()
    tif = out["dtm"].file("dtm.tif")
    rio_cogeo = pytest.importorskip("rio_cogeo.cogeo")
    assert rio_cogeo.cog_validate(str(tif), quiet=True)[0]
    def strict(c):
        raise AssertionError(f"non-strict JSON constant {c}")

    for f in ctx.store.root.rglob("*.json"):
        json.loads(f.read_text(), parse_constant=strict)
    raw = str(ctx.raw_dir)
    for pv in out.values():
        m = pv.manifest()
        assert m["software"]["libraries"]["numpy"] == np.__version__
        for f in pv.path.glob("*.nc"):
            with xr.open_dataset(f) as ds:
                prov = ds.attrs["hadal_provenance"]
                assert raw not in prov and str(ctx.store.root) not in prov, f
    with xr.open_dataset(out["dtm"].file("dtm.nc")) as ds:
        assert "MULTIBEAM" in ds.attrs["instrument"].upper() and "CTD" not in ds.attrs["instrument"]
    pytest.importorskip("pystac")
    from hadal.products.stac import validate_store_catalog

    assert validate_store_catalog(ctx.store.root) == []


@pytest.mark.parametrize("order", ["ascending", "shuffled", "one", "empty"])
def test_time_coverage_resolution_unique_times_match_numpy(order):
    """The time resolution's distinct times (sorted fast path or np.unique) are np.unique's."""
    from hadal.products.io import _sorted_unique

    rng = np.random.default_rng(5)
    t = np.sort(rng.integers(0, 400, 3000)).astype("datetime64[s]").astype("datetime64[ns]")
    t = {"ascending": t, "shuffled": rng.permutation(t), "one": t[:1], "empty": t[:0]}[order]
    np.testing.assert_array_equal(_sorted_unique(t), np.unique(t))
