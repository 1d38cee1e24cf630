"""Prior grids as the reference DTM and laser inputs of any kind/name, through make_context + run_stage.

Oracles read the source files independently (netCDF4 / rasterio) and interpolate with scipy.
"""

from __future__ import annotations

import json
import shutil

import numpy as np
import pytest
import xarray as xr
import yaml
from scipy.interpolate import RegularGridInterpolator

from hadal.errors import InputError
from hadal.pipeline import make_context, run_stage

TAKUYO = "bathy-real/LAD_Takuyo_B1_raster_100mm.tif"


def _dive(raw, sources, **extra):
    raw.mkdir(parents=True, exist_ok=True)
    (raw / "dive.yaml").write_text(yaml.safe_dump({"dive_id": "P001", "platform": "test", "sources": sources,
                                                   **extra}))
    return raw


def _open(pv, name="dtm.nc"):
    with xr.open_dataset(pv.file(name), engine="h5netcdf") as ds:
        return ds.load()


def _check_against(dtm, lon_src, lat_src, z_src, sign, n=400, tol=0.05):
    """DTM cell depths vs bilinear interpolation of the source (independently read) at the cells' lon/lat."""
    interp = RegularGridInterpolator((lat_src, lon_src), z_src, method="linear", bounds_error=False,
                                     fill_value=np.nan)
    lat, lon, dep = dtm["lat"].values, dtm["lon"].values, dtm["depth_m"].values
    ok = np.isfinite(dep)
    idx = np.flatnonzero(ok.ravel())
    pick = np.random.default_rng(0).choice(idx, size=min(n, idx.size), replace=False)
    exp = sign * interp(np.column_stack([lat.ravel()[pick], lon.ravel()[pick]]))
    got = dep.ravel()[pick]
    m = np.isfinite(exp)
    assert m.sum() > 0.9 * len(pick)
    err = np.abs(got[m] - exp[m])
    assert err.max() < tol, err.max()
    return float(err.max()), int(m.sum())


def _nodes_check(dtm, frame, lon_src, lat_src, z_src, sign):
    """At source nodes the DTM (interpolated to the node) lies within the node's 3x3 neighbourhood range."""
    rng = np.random.default_rng(1)
    n_ok = 0
    for _ in range(200):
        j, i = rng.integers(2, len(lat_src) - 2), rng.integers(2, len(lon_src) - 2)
        x, y = frame.to_xy(lon_src[i], lat_src[j])
        v = float(dtm["depth_m"].interp(x=float(x), y=float(y)).item())
        if not np.isfinite(v):
            continue
        nb = sign * z_src[j - 1:j + 2, i - 1:i + 2]
        assert nb.min() - 1e-6 <= v <= nb.max() + 1e-6
        n_ok += 1
    assert n_ok > 50


@pytest.mark.parametrize("name, rel, origin, registration", [
    ("etopo5", "bathy-real/tut_bathy.nc", (32.5, -63.0), "gridline"),
    ("gmt_pixel", "formats-real/gmt_depth_pixel.nc", (-17.5, -12.5), "pixel"),
])
def test_prior_grid_only_dive_netcdf(shared_data, tmp_path, name, rel, origin, registration):
    netCDF4 = pytest.importorskip("netCDF4")
    src = shared_data / rel
    if not src.is_file():
        pytest.skip(f"{src} not present")
    raw = tmp_path / "raw"
    (raw / "maps").mkdir(parents=True)
    shutil.copy(src, raw / "maps" / "prior.grd")  # the name says nothing: content decides
    _dive(raw, {"prior_grid": ["maps/prior.grd"]},
          map_frame={"origin_latitude_deg": origin[0], "origin_longitude_deg": origin[1]})
    # km-scale cells: the paper's 5.8 x 3.7 km region is smaller than one suitability block here
    (raw / "pipeline.yaml").write_text("suitability: {region_size_x_m: 400000, region_size_y_m: 400000}\n")
    ctx = make_context(raw, tmp_path / "store")
    out = run_stage("grid", ctx)
    assert set(out) == {"dtm"}
    dtm = _open(out["dtm"])
    assert dtm.attrs["dtm_source"] == "prior_grid" and dtm.attrs["prior_grid_registration"] == registration
    assert dtm.attrs["z_positive_source"] == "up" and dtm.attrs["z_sign_flipped"] == 1
    assert dtm["depth_m"].attrs["positive"] == "down" and "count" not in dtm and "lat" in dtm.variables
    assert "count" in dtm.attrs["layers_absent"]
    with netCDF4.Dataset(src) as nc:
        xname, yname = [d for d in nc["z"].dimensions][::-1]
        lon, lat = np.asarray(nc[xname][:], float), np.asarray(nc[yname][:], float)
        z = np.ma.filled(nc["z"][:].astype(float), np.nan)
    err, n = _check_against(dtm, lon, lat, z, sign=-1.0)
    _nodes_check(dtm, ctx.dive.frame(), lon, lat, z, sign=-1.0)
    # native resolution: cell side in metres at the centre, not the multibeam 20 m
    assert 1000 < dtm.attrs["resolution"] < 10_000
    assert float(np.nanmedian(dtm["depth_m"])) > 1000  # oceanic depths, positive down
    man = out["dtm"].manifest()
    assert "xarray" in man["readers"]["prior.grd"]
    s = run_stage("suitability", ctx)["suitability"]
    suit = _open(s, "suitability.nc")
    assert np.isfinite(suit["std_m"].values).any()
    print(f"{name}: max |DTM - bilinear(source)| = {err:.3g} m over {n} cells")


def _write_utm_tiff(path, *, depths: bool, nodata=-9999.0):
    rasterio = pytest.importorskip("rasterio")
    from pyproj import Transformer
    from rasterio.transform import from_origin

    ny, nx, cell = 80, 100, 50.0
    cx, cy = Transformer.from_crs("EPSG:4326", "EPSG:32654", always_xy=True).transform(141.0, 32.5)
    x0, y0 = round(cx) - nx * cell / 2, round(cy) + ny * cell / 2  # UTM 54N, centred near 32.5N 141E
    xc = x0 + (np.arange(nx) + 0.5) * cell
    yc = y0 - (np.arange(ny) + 0.5) * cell
    X, Y = np.meshgrid(xc, yc)
    elev = -6000.0 + 300.0 * np.sin((X - x0) / 700.0) * np.cos((Y - y0) / 900.0) + 0.05 * (X - x0)
    a = (-elev if depths else elev).astype("float32")
    a[:5, :7] = nodata
    with rasterio.open(path, "w", driver="GTiff", width=nx, height=ny, count=1, dtype="float32",
                       crs="EPSG:32654", transform=from_origin(x0, y0, cell, cell), nodata=nodata) as dst:
        dst.write(a, 1)
    return cell


@pytest.mark.parametrize("depths", [False, True])
def test_prior_grid_utm_geotiff(tmp_path, depths):
    rasterio = pytest.importorskip("rasterio")
    from pyproj import Transformer

    raw = tmp_path / "raw"
    raw.mkdir()
    cell = _write_utm_tiff(raw / "prior_map", depths=depths)  # no extension at all
    _dive(raw, {"prior_grid": ["prior_map"]}, launch={"latitude_deg": 32.5, "longitude_deg": 141.0})
    ctx = make_context(raw, tmp_path / "store")
    dtm = _open(run_stage("grid", ctx)["dtm"])
    assert dtm.attrs["resolution"] == pytest.approx(cell)
    assert dtm.attrs["z_positive_source"] == ("down" if depths else "up")
    assert "32654" in dtm.attrs["prior_grid_crs"] and dtm.attrs["prior_grid_format"] == "GeoTIFF"
    with rasterio.open(raw / "prior_map") as src:  # the oracle: rasterio + scipy bilinear in UTM
        a = src.read(1).astype(float)
        a[a == src.nodata] = np.nan
        t = src.transform
    ny, nx = a.shape
    xc = t.c + (np.arange(nx) + 0.5) * t.a
    yc = (t.f + (np.arange(ny) + 0.5) * t.e)[::-1]
    interp = RegularGridInterpolator((yc, xc), a[::-1], bounds_error=False, fill_value=np.nan)
    to_utm = Transformer.from_crs("EPSG:4326", "EPSG:32654", always_xy=True)
    ux, uy = to_utm.transform(dtm["lon"].values.ravel(), dtm["lat"].values.ravel())
    exp = interp(np.column_stack([uy, ux])) * (1.0 if depths else -1.0)
    got = dtm["depth_m"].values.ravel()
    m = np.isfinite(exp) & np.isfinite(got)
    assert m.sum() > 0.8 * np.isfinite(got).sum()
    assert np.max(np.abs(got[m] - exp[m])) < 0.01
    assert np.all(got[np.isfinite(got)] > 5000)  # depths positive down whichever way the file stored them
    run_stage("suitability", ctx)


def test_prior_grid_sign_hint_and_bad_input(tmp_path):
    pytest.importorskip("rasterio")
    raw = tmp_path / "raw"
    raw.mkdir()
    _write_utm_tiff(raw / "depths.tif", depths=True)
    (raw / "junk.nc").write_bytes(b"CDF\x01 truncated")
    _dive(raw, {"prior_grid": [{"path": "depths.tif", "z_positive": "up"}]},
          map_frame={"origin_latitude_deg": 32.5, "origin_longitude_deg": 141.0})
    (raw / "pipeline.yaml").write_text("grid: {dtm_resolution_m: 20}\n")
    # as declared (wrongly): the hint wins, so 5500-6200 m "elevations" are all land: refused, never negative depths
    with pytest.raises(InputError, match=r"depths.tif is land elevation .*z_positive given in dive.yaml.*no seafloor"):
        run_stage("grid", make_context(raw, tmp_path / "s1"))
    _dive(raw, {"prior_grid": ["junk.nc"]}, map_frame={"origin_latitude_deg": 32.5, "origin_longitude_deg": 141.0})
    with pytest.raises(InputError, match="junk.nc") as ei:
        run_stage("grid", make_context(raw, tmp_path / "s2"))
    assert "\n" not in str(ei.value)
    assert not (tmp_path / "s2" / "P001").exists() or not any((tmp_path / "s2" / "P001").glob("*/v*"))
    # a grid that does not cover the map frame
    _dive(raw, {"prior_grid": ["depths.tif"]}, map_frame={"origin_latitude_deg": -40.0, "origin_longitude_deg": 10.0})
    with pytest.raises(InputError, match="depths.tif"):
        run_stage("grid", make_context(raw, tmp_path / "s3"))


def test_multibeam_wins_over_prior_grid(tmp_path):
    import gzip

    from hadal.geo import LocalFrame

    raw = tmp_path / "raw"
    raw.mkdir()
    _write_utm_tiff(raw / "prior.tif", depths=False)
    frame = LocalFrame(32.5, 141.0)
    rng = np.random.default_rng(0)
    x, y = rng.uniform(-800, 800, 3000), rng.uniform(-600, 600, 3000)
    lon, lat = frame.to_lonlat(x, y)
    with gzip.open(raw / "mb.xyz.gz", "wt") as fh:
        np.savetxt(fh, np.column_stack([lon, lat, 6000 + 0.01 * x]), fmt="%.8f %.8f %.3f")
    _dive(raw, {"multibeam": ["mb.xyz.gz"], "prior_grid": ["prior.tif"]},
          map_frame={"origin_latitude_deg": 32.5, "origin_longitude_deg": 141.0})
    (raw / "pipeline.yaml").write_text("grid: {dtm_resolution_m: 20}\n")
    dtm = _open(run_stage("grid", make_context(raw, tmp_path / "s1"))["dtm"])
    assert dtm.attrs["dtm_source"] == "multibeam" and dtm.attrs["prior_grid_use"].startswith("ignored")
    assert dtm.attrs["resolution"] == 20.0
    (raw / "pipeline.yaml").write_text("grid: {prior_fill: true, fill_max_cells: 0, dtm_resolution_m: 20}\n")
    dtm2 = _open(run_stage("grid", make_context(raw, tmp_path / "s2"))["dtm"])
    assert dtm2.attrs["prior_grid_use"].startswith("multibeam wins")
    assert int((dtm2["filled"] == 2).sum()) == dtm2.attrs["n_cells_prior_filled"] > 0
    assert np.isfinite(dtm2["depth_m"]).sum() >= np.isfinite(dtm["depth_m"]).sum()
    meas = dtm2["count"].values > 0
    np.testing.assert_array_equal(dtm2["depth_m"].values[meas], dtm["depth_m"].values[meas])


def test_laser_only_dive_takuyo_raster_grid_to_landing(shared_data, tmp_path):
    pytest.importorskip("rasterio")
    src = shared_data / TAKUYO
    if not src.is_file():
        pytest.skip(f"{src} not present")
    raw = tmp_path / "raw"
    (raw / "laser").mkdir(parents=True)
    shutil.copy(src, raw / "laser" / "takuyo_b1.raster")
    _dive(raw, {"laser": ["laser/takuyo_b1.raster"]})  # no launch, no map frame: not needed here
    (raw / "pipeline.yaml").write_text("landing: {heading_step_deg: 10, figures: false}\n")
    ctx = make_context(raw, tmp_path / "store")
    out = run_stage("grid", ctx)
    assert set(out) == {"laser_grids"}
    lg = _open(out["laser_grids"], "takuyo_b1.nc")
    assert lg.attrs["resolution"] == pytest.approx(0.1)  # its own resolution, not 10 mm
    assert lg.sizes["x"] == 219 and lg.sizes["y"] == 185 and "count" not in lg
    assert lg.attrs["z_positive_source"] == "down" and lg["elevation_m"].attrs["positive"] == "up"
    v = lg["elevation_m"].values
    assert -1382.0 < np.nanmin(v) < np.nanmax(v) < -1379.0
    assert 0.10 < np.isfinite(v).mean() < 0.16
    assert "local metric" in lg.attrs["source_crs_override"]
    assert "rasterio" in out["laser_grids"].manifest()["readers"]["takuyo_b1.raster"]
    # 0.1 m cells are 1/5 of the 0.5 m vehicle: refused by the 1/10 rule unless the user raises the limit
    with pytest.raises(InputError, match="too coarse"):
        run_stage("landing", ctx)
    (raw / "pipeline.yaml").write_text("landing: {heading_step_deg: 10, figures: false, max_cell_fraction: 0.2}\n")
    ctx = make_context(raw, tmp_path / "store")
    land = run_stage("landing", ctx)["landing"]
    import pandas as pd

    sites = pd.read_parquet(land.file("landing_sites.parquet"))
    assert len(sites) >= 5 and set(sites["submap"]) == {"takuyo_b1"}
    best = sites[sites["is_best"]].iloc[0]
    assert 0.0 < best["c_s"] < 0.7 and -1382.0 < best["elevation_m"] < -1379.0
    assert (land.path / "takuyo_b1_maps.nc").is_file()


def _ply(path, pts):
    head = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(pts)}\n"
            "property double x\nproperty double y\nproperty double z\nend_header\n").encode()
    path.write_bytes(head + np.asarray(pts, "<f8").tobytes())


def test_laser_point_clouds_of_any_name_are_analysed(tmp_path):
    laspy = pytest.importorskip("laspy")
    o3d = pytest.importorskip("open3d")
    rng = np.random.default_rng(3)
    raw = tmp_path / "raw"
    (raw / "a").mkdir(parents=True)
    (raw / "b").mkdir()

    def cloud(m=60_000, depth=False):
        x, y = rng.uniform(0, 1.5, m), rng.uniform(0, 1.2, m)
        z = -1400 + 0.05 * x + 0.002 * rng.normal(size=m)
        return np.column_stack([x, y, -z if depth else z])

    _ply(raw / "a" / "scan", cloud())                                   # PLY without extension
    _ply(raw / "b" / "scan.ply", cloud())                               # same stem
    o3d.io.write_point_cloud(str(raw / "dive3.pcd"), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(cloud())))
    (raw / "dive3.pcd").rename(raw / "dive3.cloud")                     # binary PCD, odd extension
    pts = cloud(depth=True)                                             # LAS holding depths
    hdr = laspy.LasHeader(point_format=0, version="1.2")
    hdr.scales, hdr.offsets = [0.0005] * 3, [0.0, 0.0, 1400.0]
    las = laspy.LasData(hdr)
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    las.write(raw / "survey.bin")
    np.savetxt(raw / "pts.txt", cloud(20_000), header="x,y,z", delimiter=",", comments="")
    las.write(raw / "survey_up.bin")  # the same depths, not declared: LAS Z is elevation (ASPRS), kept as such
    _dive(raw, {"laser": ["a/scan", "b/scan.ply", "dive3.cloud", {"path": "survey.bin", "z_positive": "down"},
                         "survey_up.bin", "pts.txt"]})
    (raw / "pipeline.yaml").write_text("grid: {laser_resolution_m: 0.02, laser_sor_neighbors: 0}\n"
                                       "landing: {heading_step_deg: 45, figures: false, min_site_radius_m: 0.1}\n")
    ctx = make_context(raw, tmp_path / "store")
    lgv = run_stage("grid", ctx)["laser_grids"]
    names = sorted(f["name"] for f in lgv.manifest()["files"])
    assert names == ["dive3.nc", "pts.nc", "scan.nc", "scan_ply.nc", "survey.nc", "survey_up.nc"]
    las_grid = _open(lgv, "survey.nc")  # depths declared in dive.yaml: negated
    assert las_grid.attrs["source_format"] == "las" and las_grid.attrs["z_positive_source"] == "down"
    assert las_grid.attrs["z_sign_detection"] == "z_positive given in dive.yaml"
    assert -1401 < float(np.nanmean(las_grid["elevation_m"])) < -1399
    las_up = _open(lgv, "survey_up.nc")  # not declared: the file's Z is elevation, never negated by its sign
    assert las_up.attrs["z_positive_source"] == "up" and las_up.attrs["z_sign_flipped"] == 0
    assert 1399 < float(np.nanmean(las_up["elevation_m"])) < 1401
    for n in names:
        g = _open(lgv, n)
        assert {"elevation_m", "count"} <= set(g.data_vars) and g.attrs["resolution"] == 0.02
    land = run_stage("landing", ctx)["landing"]
    maps = sorted(p.name for p in land.path.glob("*_maps.nc"))
    assert maps == [n.replace(".nc", "_maps.nc") for n in names]


def test_bad_laser_inputs_name_the_file(tmp_path):
    raw = tmp_path / "raw"
    raw.mkdir()
    _ply(raw / "ok.ply", np.random.default_rng(0).normal(size=(100, 3)))
    (raw / "notes.txt").write_text("this is not a point cloud\nat all\n")
    _dive(raw, {"laser": ["ok.ply", "notes.txt"]})
    with pytest.raises(InputError, match="notes.txt") as ei:
        run_stage("grid", make_context(raw, tmp_path / "store"))
    assert "\n" not in str(ei.value)
    assert not (tmp_path / "store" / "P001").exists() or not any((tmp_path / "store" / "P001").glob("*/v*"))
    rasterio = pytest.importorskip("rasterio")
    from rasterio.transform import from_origin

    with rasterio.open(raw / "empty.tif", "w", driver="GTiff", width=4, height=4, count=1, dtype="float32",
                       transform=from_origin(0, 4, 1, 1), nodata=0.0) as dst:
        dst.write(np.zeros((4, 4), "float32"), 1)
    _dive(raw, {"laser": ["empty.tif"]})
    with pytest.raises(InputError, match="empty.tif.*no valid"):
        run_stage("grid", make_context(raw, tmp_path / "store"))


def test_describe_grid_and_point_cloud(shared_data, tmp_path):
    from hadal.grid.describe import describe_grid, describe_point_cloud

    d = describe_grid(shared_data / TAKUYO)
    json.dumps(d)
    assert d["format"] == "GeoTIFF" and "rasterio" in d["reader"] and d["crs"]["looks_metric"] is True
    assert d["size"] == {"nx": 219, "ny": 185, "cells": 219 * 185} and d["resolution_m"] == pytest.approx(0.1)
    assert d["z"]["positive"] == "down" and 0.8 < d["nodata_fraction"] < 0.9
    g = describe_grid(shared_data / "formats-real" / "gmt_depth_pixel.nc")
    json.dumps(g)
    assert g["registration"] == "pixel" and g["extent"] == {"xmin": -30.0, "xmax": 5.0, "ymin": -30.0, "ymax": -5.0}
    assert g["crs"]["kind"] == "geographic" and not g["crs"]["looks_metric"] and g["z"]["positive"] == "up"
    e = describe_grid(shared_data / "bathy-real" / "tut_bathy.nc")
    assert e["registration"] == "gridline" and e["z"]["min"] == -5475.0 and e["extent"]["xmin"] == -66.0
    _ply(tmp_path / "c", np.column_stack([np.linspace(0, 2, 50), np.linspace(0, 1, 50), np.full(50, -1400.0)]))
    c = describe_point_cloud(tmp_path / "c")
    json.dumps(c)
    assert c["format"] == "ply" and c["points"] == 50 and c["extent"]["xmax"] == 2.0 and c["z"]["positive"] == "up"
    assert "open3d" in c["reader"]
    with pytest.raises(InputError, match="nope"):
        describe_grid(tmp_path / "nope.tif")
