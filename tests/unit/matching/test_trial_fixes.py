"""New-user trial failures, each fixed as a class and checked against an independent oracle.

1. truncated grids (netCDF classic / 64-bit offset / netCDF-4, GeoTIFF) -> one-line InputError, also in inspect;
2. a cropped prior grid says so (WARNING, kept bounds, area and depth range lost, in the manifest summary);
3. laser point clouds at coarse spacing: ``laser_resolution_m: auto``;
4. a time-less (pressure-binned) cast takes its header start time, never the processing time;
5. SeaSoft LoopEdit flags -> QARTOD 4 on the CTD variables, excluded from the binned profile;
6. an empty file is "empty (0 bytes)".
"""

from __future__ import annotations

import datetime as dt
import logging
import shutil
import sys
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import xarray as xr
import yaml

from hadal.errors import InputError
from hadal.geo import LocalFrame
from hadal.grid.readers import netcdf_classic_min_size, read_grid

TUT = "bathy-real/tut_bathy.nc"
TAKUYO = "bathy-real/LAD_Takuyo_B1_raster_100mm.tif"
LOOPEDIT = "formats-real/sbs_SBE19plus_01906398_2019_07_15_0033_cropped_loopedit.cnv"


def _one_line_truncated(path: Path, fn=read_grid):
    with pytest.raises(InputError) as ei:
        fn(path)
    msg = str(ei.value)
    assert "\n" not in msg and "truncated" in msg and path.name in msg, msg
    return msg


def _grid_ds(ny=61, nx=73, seed=0) -> xr.Dataset:
    rng = np.random.default_rng(seed)
    z = -4000 + rng.normal(0, 300, (ny, nx)).astype(np.float32)
    return xr.Dataset({"z": (("lat", "lon"), z, {"units": "m"})},
                      coords={"lat": ("lat", np.linspace(30, 35, ny), {"units": "degrees_north"}),
                              "lon": ("lon", np.linspace(-66, -60, nx), {"units": "degrees_east"})})


# ---------------------------------------------------------------------------------------------- 1 truncation
def test_real_truncated_classic_netcdf(shared_data, tmp_path):
    from scipy.io import netcdf_file

    from hadal.grid.describe import describe_grid

    src = shared_data / TUT
    full = src.read_bytes()
    with netcdf_file(src, "r", mmap=False) as nc:  # oracle: scipy's own netCDF-3 reader
        ref = np.array(nc.variables["z"].data, dtype=float)
        y = np.array(nc.variables["y"].data, dtype=float)
    assert y[0] < y[-1]  # rows already south to north, as read_grid returns them
    assert np.array_equal(read_grid(src).values, ref)
    header, need = netcdf_classic_min_size(full)
    assert header < need <= len(full) < need + 4  # the complete file: only the 4-byte padding after the data
    for cut in (9000, header + 1, need - 1, header - 10, 100):
        p = tmp_path / f"cut{cut}.nc"
        p.write_bytes(full[:cut])
        msg = _one_line_truncated(p)
        if cut > header:
            assert f"{cut} bytes, the header implies at least {need}" in msg
        _one_line_truncated(p, describe_grid)  # hadal inspect reports it too


@pytest.mark.parametrize("fmt", ["NETCDF3_CLASSIC", "NETCDF3_64BIT", "NETCDF4", "NETCDF4_CLASSIC"])
def test_truncated_netcdf_any_flavour(tmp_path, fmt):
    pytest.importorskip("netCDF4")
    p = tmp_path / "g.nc"
    ds = _grid_ds()
    enc = {"z": {"zlib": True}} if fmt.startswith("NETCDF4") else {}
    ds.to_netcdf(p, format=fmt, engine="netcdf4", encoding=enc)
    full = p.read_bytes()
    da = read_grid(p)  # the complete file reads, value for value
    assert np.array_equal(da.values, ds["z"].values.astype(float))
    for frac in (0.5, 0.9, 0.99):
        q = tmp_path / f"cut{frac}.nc"
        q.write_bytes(full[:int(len(full) * frac)])
        _one_line_truncated(q)


def test_truncated_classic_netcdf_with_record_dimension(tmp_path):
    netCDF4 = pytest.importorskip("netCDF4")
    p = tmp_path / "rec.nc"
    with netCDF4.Dataset(p, "w", format="NETCDF3_CLASSIC") as nc:
        nc.createDimension("lat", None)
        nc.createDimension("lon", 40)
        nc.createVariable("lon", "f8", ("lon",))[:] = np.linspace(0, 1, 40)
        nc.createVariable("lat", "f8", ("lat",))[:] = np.linspace(0, 1, 30)
        nc.createVariable("z", "f4", ("lat", "lon"))[:] = np.arange(1200, dtype="f4").reshape(30, 40)
        nc["lon"].units, nc["lat"].units = "degrees_east", "degrees_north"
    full = p.read_bytes()
    _, need = netcdf_classic_min_size(full)
    assert need <= len(full) < need + 4
    read_grid(p)
    q = tmp_path / "cut.nc"
    q.write_bytes(full[:need - 8])
    _one_line_truncated(q)


def test_truncated_geotiff(tmp_path):
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import from_origin

    p = tmp_path / "g.tif"
    z = np.random.default_rng(1).normal(-3000, 50, (300, 200)).astype("f4")
    with rasterio.open(p, "w", driver="GTiff", height=300, width=200, count=1, dtype="float32", crs="EPSG:32654",
                       transform=from_origin(500000, 3600000, 10, 10), tiled=False) as dst:
        dst.write(z, 1)
    assert np.array_equal(read_grid(p).values[::-1], z.astype(float))
    full = p.read_bytes()
    for cut in (len(full) // 2, len(full) - 100):
        q = tmp_path / f"cut{cut}.tif"
        q.write_bytes(full[:cut])
        _one_line_truncated(q)


# ---------------------------------------------------------------------------------------------- 2 prior crop
def _big_prior(path: Path, lat0=-17.5, lon0=-12.5):
    """35 x 25 deg geographic grid, depth = 5000 + 40 m per degree of latitude (independent of longitude)."""
    lon = np.arange(lon0 - 17.5 + 1 / 60, lon0 + 17.5, 1 / 30)
    lat = np.arange(lat0 - 12.5 + 1 / 60, lat0 + 12.5, 1 / 30)
    depth = 5000 + 40 * (lat - lat0)[:, None] + 0 * lon[None, :]
    xr.Dataset({"depth": (("lat", "lon"), depth, {"units": "m", "positive": "down"})},
               coords={"lat": ("lat", lat, {"units": "degrees_north"}),
                       "lon": ("lon", lon, {"units": "degrees_east"})}).to_netcdf(path)
    return lon, lat, depth


def test_prior_crop_is_reported(tmp_path, caplog):
    from pyproj import Geod, Transformer

    from hadal.pipeline import make_context, run_stage

    lat0, lon0 = -17.5, -12.5
    raw = tmp_path / "raw"
    raw.mkdir()
    lon, lat, depth = _big_prior(raw / "prior.nc", lat0, lon0)
    (raw / "dive.yaml").write_text(yaml.safe_dump({
        "dive_id": "C1", "platform": "test", "sources": {"prior_grid": ["prior.nc"]},
        "map_frame": {"origin_latitude_deg": lat0, "origin_longitude_deg": lon0}}))
    (raw / "pipeline.yaml").write_text("grid: {prior_resolution_m: 20000}\n"
                                       "suitability: {region_size_x_m: 400000, region_size_y_m: 400000}\n")
    with caplog.at_level(logging.WARNING):
        out = run_stage("grid", make_context(raw, tmp_path / "store"))
    warn = [r for r in caplog.records if r.levelno == logging.WARNING and "cropped" in r.getMessage()]
    assert warn and "prior.nc" in warn[0].getMessage()
    summary = out["dtm"].manifest()["summary"]
    with xr.open_dataset(out["dtm"].file("dtm.nc"), engine="h5netcdf") as ds:
        a = dict(ds.attrs)
    for k in ("prior_grid_cropped_to_m", "prior_grid_crop_area_fraction_lost", "prior_grid_kept_lat_max",
              "prior_grid_crop_depth_range_lost_fraction"):
        assert k in a and summary[k] == pytest.approx(a[k]), k

    # oracle 1: the kept lat limits are those of the 2000 km square's edges (TM inverse with pyproj directly;
    # in the southern hemisphere the parallels curve south away from the meridian: the corners reach furthest)
    tm = Transformer.from_crs(f"+proj=tmerc +lat_0={lat0} +lon_0={lon0} +k=1 +datum=WGS84", "EPSG:4326",
                              always_xy=True)
    edge = np.linspace(-1e6, 1e6, 2001)
    _, lat_top = tm.transform(edge, np.full_like(edge, 1e6))
    _, lat_bot = tm.transform(edge, np.full_like(edge, -1e6))
    lat_n, lat_s = float(np.max(lat_top)), float(np.min(lat_bot))
    assert Geod(ellps="WGS84").fwd(lon0, lat0, 0, 1e6)[1] < lat_n  # not just the meridian arc
    assert a["prior_grid_kept_lat_max"] == pytest.approx(lat_n, abs=1 / 30)
    assert a["prior_grid_kept_lat_min"] == pytest.approx(lat_s, abs=1 / 30)
    # ... so the kept depth range is that of those latitudes (depth is linear in latitude)
    kept = (40 * (lat_n - lat_s))
    src = 40 * (lat[-1] - lat[0])
    assert a["prior_grid_kept_depth_max_m"] - a["prior_grid_kept_depth_min_m"] == pytest.approx(kept, abs=3)
    assert a["prior_grid_crop_depth_range_lost_fraction"] == pytest.approx(1 - kept / src, abs=0.01)
    assert a["prior_grid_source_depth_max_m"] == pytest.approx(depth.max())
    # oracle 2: Monte-Carlo area fraction outside the 2000 km square (uniform on the sphere, pyproj directly)
    rng = np.random.default_rng(3)
    n = 200_000
    lo = rng.uniform(lon[0] - 1 / 60, lon[-1] + 1 / 60, n)
    s0, s1 = np.sin(np.radians(lat[0] - 1 / 60)), np.sin(np.radians(lat[-1] + 1 / 60))
    la = np.degrees(np.arcsin(rng.uniform(s0, s1, n)))
    fwd = Transformer.from_crs("EPSG:4326", f"+proj=tmerc +lat_0={lat0} +lon_0={lon0} +k=1 +datum=WGS84",
                               always_xy=True)
    x, y = fwd.transform(lo, la)
    lost = 1 - np.mean((np.abs(x) <= 1e6) & (np.abs(y) <= 1e6))
    assert a["prior_grid_crop_area_fraction_lost"] == pytest.approx(lost, abs=0.01)
    assert 0.5 < lost < 0.7


def test_prior_inside_extent_is_not_cropped(tmp_path):
    from hadal.grid.prior import prior_dtm

    p = tmp_path / "small.nc"
    _grid_ds().to_netcdf(p)
    ds = prior_dtm(p, LocalFrame(32.5, -63.0))
    assert not any(k.startswith(("prior_grid_crop", "prior_grid_kept")) for k in ds.attrs)


def test_real_gmt_grid_crop_numbers(shared_data):
    from hadal.grid.prior import prior_dtm

    ds = prior_dtm(shared_data / "formats-real/gmt_depth_pixel.nc", LocalFrame(-17.5, -12.5))
    raw = read_grid(shared_data / "formats-real/gmt_depth_pixel.nc")
    assert ds.attrs["prior_grid_source_depth_max_m"] == pytest.approx(-float(raw.min()))
    assert ds.attrs["prior_grid_kept_depth_max_m"] < ds.attrs["prior_grid_source_depth_max_m"]
    assert 0.5 < ds.attrs["prior_grid_crop_area_fraction_lost"] < 0.7


# ---------------------------------------------------------------------------------------------- 3 laser auto
@pytest.mark.parametrize("s", [0.1, 0.037, 0.25])
def test_laser_auto_on_lattice_maps_its_cells(s):
    from hadal.grid.laser import grid_laser

    rng = np.random.default_rng(int(s * 1000))
    x0, y0 = rng.uniform(-50, 50, 2)
    gx, gy = np.meshgrid(x0 + s * np.arange(120), y0 + s * np.arange(90))
    z = -1000 + 0.05 * gx + 0.02 * np.sin(gy)
    pts = np.column_stack([gx.ravel(), gy.ravel(), z.ravel()])
    ds = grid_laser(pts, "auto")
    r = ds.attrs["resolution"]
    assert r == pytest.approx(s, rel=0.01) and "auto" in ds.attrs["resolution_choice"]
    # oracle: the lattice binned with numpy on the product's own cell edges
    ex = np.append(ds.x.values - r / 2, ds.x.values[-1] + r / 2)
    ey = np.append(ds.y.values - r / 2, ds.y.values[-1] + r / 2)
    h, _, _ = np.histogram2d(pts[:, 1], pts[:, 0], bins=[ey, ex])
    assert np.array_equal(h.astype(int), ds["count"].values)
    assert (h > 0).mean() >= 0.9 and ds.attrs["mapped_fraction"] >= 0.9


def test_laser_auto_keeps_10mm_for_dense_clouds():
    from hadal.grid.laser import G_RES_M, grid_laser

    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(0, 1, 40_000), rng.uniform(0, 0.5, 40_000), rng.normal(-1400, 1e-3, 40_000)])
    ds = grid_laser(pts, "auto")
    assert ds.attrs["resolution"] == G_RES_M and "10 mm" in ds.attrs["resolution_choice"]


def test_sample_dive_laser_submap_is_10mm(small_dive):
    from hadal.grid.laser import G_RES_M, auto_resolution_m, grid_laser
    from hadal.grid.readers import read_point_cloud
    from hadal.settings import GridParams as Params

    assert Params().laser_resolution_m == "auto"
    pts = read_point_cloud(small_dive / "laser" / "submap_01.ply")
    res, info = auto_resolution_m(pts)
    assert res == G_RES_M and info["nn_quantile_m"] < G_RES_M
    ds = grid_laser(pts[::4], "auto", sor_neighbors=0)  # a quarter of the points: still denser than 10 mm
    assert ds.attrs["resolution"] == G_RES_M


def test_takuyo_points_grid_like_the_raster(shared_data):
    """The Takuyo raster's points (0.1 m) gridded with 'auto' reproduce the raster (the oracle) cell for cell."""
    from hadal.grid.laser import grid_laser, laser_grid_from_raster

    da = read_grid(shared_data / TAKUYO, crs_kind="local_metric")
    gx, gy = np.meshgrid(da.x.values, da.y.values)
    ok = np.isfinite(da.values)
    pts = np.column_stack([gx[ok], gy[ok], da.values[ok]])
    ds = grid_laser(pts, "auto")
    ref = laser_grid_from_raster(da, z_positive="up")
    assert ds.attrs["resolution"] == pytest.approx(ref.attrs["resolution"])
    sub = ref.elevation_m.sel(x=ds.x, y=ds.y, method="nearest")
    assert np.allclose(sub.x.values, ds.x.values, atol=1e-6) and np.allclose(sub.y.values, ds.y.values, atol=1e-6)
    both = np.isfinite(ds.elevation_m.values) & np.isfinite(sub.values)
    assert both.sum() >= 0.99 * ok.sum()
    assert np.allclose(ds.elevation_m.values[both], sub.values[both], atol=1e-6)
    assert int(ds["count"].max()) == 1


# ---------------------------------------------------------------------------------------------- 4 cast time
def _cast_run(tmp_path, src: Path, stages=("ingest", "derive", "profile")):
    sys.path.insert(0, str(Path(__file__).parents[2]))
    from test_cnv_casts import _run

    raw = tmp_path / "raw"
    raw.mkdir(parents=True, exist_ok=True)
    shutil.copy(src, raw / src.name)
    (raw / "dive.yaml").write_text(yaml.safe_dump({"dive_id": "cast", "sources": {"cnv": [src.name]}}))
    return _run(raw, tmp_path / "store", stages)[1]


def test_timeless_cast_uses_header_start_time(shared_data, tmp_path):
    src = shared_data / "ctd-real/seabird_sta0860.cnv"
    line = next(ln for ln in src.read_text(encoding="latin-1").splitlines() if ln.startswith("# start_time"))
    oracle = dt.datetime.strptime(line.split("=", 1)[1].split("[")[0].strip(), "%b %d %Y %H:%M:%S")
    out = _cast_run(tmp_path, src)
    with xr.open_dataset(out["profile"].file("profile.nc"), engine="h5netcdf") as ds:
        assert ds.attrs["time_coverage_start"] == oracle.strftime("%Y-%m-%dT%H:%M:%SZ") == "2008-08-28T12:33:46Z"
        assert ds.attrs["time_coverage_end"] == ds.attrs["time_coverage_start"]
        assert ds["time"].dims == ("profile",)  # one time per cast (ragged profiles, hadal.products.dsg)
        assert (pd.to_datetime(ds["time"].values) == pd.Timestamp(oracle)).all()
        assert "processing" not in ds["time"].attrs.get("long_name", "")


def test_timeless_cast_without_start_time_has_no_time(shared_data, tmp_path):
    text = (shared_data / "ctd-real/seabird_sta0860.cnv").read_text(encoding="latin-1")
    src = tmp_path / "nostart.cnv"
    src.write_text("\n".join(ln for ln in text.splitlines() if not ln.startswith("# start_time")) + "\n",
                   encoding="latin-1")
    out = _cast_run(tmp_path / "run", src)
    with xr.open_dataset(out["profile"].file("profile.nc"), engine="h5netcdf") as ds:
        assert "time" not in ds.variables and "time_coverage_start" not in ds.attrs


def test_time_omitted_means_no_processing_time(tmp_path):
    from hadal.products.io import write_netcdf

    ds = xr.Dataset({"temperature_its90_degc": (("pressure_dbar",), np.arange(3.0))},
                    coords={"pressure_dbar": np.arange(3.0)}, attrs={"time_omitted": "none"})
    p = write_netcdf(ds, tmp_path / "a.nc", title="t", summary="s")
    with xr.open_dataset(p, engine="h5netcdf") as out:
        assert "time" not in out.variables and "time_coverage_start" not in out.attrs


# ---------------------------------------------------------------------------------------------- 5 LoopEdit
def _raw_cnv(path: Path) -> np.ndarray:
    """Oracle reader: the data lines after *END* as numbers (11-character columns, whitespace separated)."""
    lines = path.read_text(encoding="latin-1").splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.strip() == "*END*")
    return np.array([[float(v) for v in ln.split()] for ln in lines[k + 1:] if ln.strip()])


def test_loopedit_flags_become_qartod_4(shared_data, tmp_path):
    from hadal.ctd.profile import bin_edges
    from hadal.products.io import read_parquet_metadata

    src = shared_data / LOOPEDIT
    raw = _raw_cnv(src)  # columns: timeS, c0mS/cm, prdM, tv290C, flag
    bad = raw[:, 4] != 0
    assert bad.sum() == 76 and len(raw) == 400
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = _cast_run(tmp_path, src)
    sensors = pd.read_parquet(out["sensors"].file("sensors.parquet"))
    meta, _ = read_parquet_metadata(out["sensors"].file("sensors.parquet"))
    assert len(sensors) == 400  # flagged, not deleted
    for var in ("pressure_ctd_dbar", "temperature_its90_degc", "conductivity_s_m"):
        assert np.array_equal(sensors[f"{var}_qc"].to_numpy() == 4, bad), var
        assert meta["qc_counts"][var].get("4") == 76
    assert meta["seasoft_flags"]["scans_flagged"] == 76
    assert np.allclose(sensors["temperature_its90_degc"].to_numpy(), raw[:, 3])  # values kept

    # derive: the binned profile is the mean of the unflagged scans only (oracle: numpy on the raw columns)
    ctd = pd.read_parquet(out["ctd"].file("ctd.parquet"))
    from hadal.products.dsg import orthogonal_profile  # the ragged casts back on their bins

    with xr.open_dataset(out["profile"].file("profile.nc"), engine="h5netcdf") as prof:
        prof = orthogonal_profile(prof.load())
    binsz = float(prof["pressure_dbar"].values[1] - prof["pressure_dbar"].values[0]) if prof.sizes[
        "pressure_dbar"] > 1 else 10.0
    edges = bin_edges(ctd["pressure_dbar"].to_numpy(), binsz)
    pres = ctd["pressure_dbar"].to_numpy()
    for k, cast in enumerate(["descent", "ascent"]):
        sel = (ctd["phase"] == cast).to_numpy() & ~bad & np.isfinite(pres)
        idx = np.digitize(pres[sel], edges) - 1
        for b in range(prof.sizes["pressure_dbar"]):
            v = raw[sel, 3][idx == b]
            got = float(prof["temperature_its90_degc"].values[k, b])
            if v.size:
                assert got == pytest.approx(v.mean(), abs=5e-5), (cast, b)  # float32: registry 1e-4 degC
            else:
                assert np.isnan(got)
    # and no flagged scan is counted
    both = (ctd["phase"].isin(["descent", "ascent"])).to_numpy() & ~bad & np.isfinite(pres)
    assert int(prof["count"].values.sum()) <= int(both.sum())


def test_seasoft_bad_scans_rule():
    from hadal.ingest.cnv import seasoft_bad_scans

    df = pd.DataFrame({"prdM": [1.0, 2, 3, 4], "flag": [0.0, np.nan, 1.0, 0.0]})
    assert seasoft_bad_scans(df).tolist() == [False, True, True, False]
    assert seasoft_bad_scans(df.drop(columns="flag")) is None
    const = pd.DataFrame({"flag": [222.0, 222.0, np.nan, 222.0]})  # a constant is not scan marking
    assert seasoft_bad_scans(const).tolist() == [False, False, True, False]


# ---------------------------------------------------------------------------------------------- 6 empty file
def test_empty_file_kind(tmp_path):
    from hadal.formats import detect
    from hadal.inspect import inspect_file

    p = tmp_path / "nothing.nc"
    p.write_bytes(b"")
    fk = detect(p)
    assert fk.kind == "empty" and fk.description == "empty (0 bytes)" and fk.source is None
    info = inspect_file(p)
    assert info["kind"] == "empty" and info["description"] == "empty (0 bytes)"
