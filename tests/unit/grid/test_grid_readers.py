"""Readers: XYZ/CSV soundings, PLY/PCD/LAS clouds, GeoTIFF/NetCDF grids and GSF, on synthetic and real files."""

from __future__ import annotations

import gzip
import warnings

import numpy as np
import pytest

from hadal.errors import InputError
from hadal.grid import GridCRSWarning, looks_metric, read_grid, read_gsf, read_point_cloud, read_soundings

SOUND = np.array([[142.2, 11.33, 8000.5], [142.21, 11.34, 8100.25], [142.22, 11.35, 7999.0]])


def _write_ply_f64(path, pts, n_header=None):
    n_header = len(pts) if n_header is None else n_header
    head = (f"ply\nformat binary_little_endian 1.0\nelement vertex {n_header}\n"
            "property double x\nproperty double y\nproperty double z\nend_header\n").encode()
    path.write_bytes(head + np.asarray(pts, "<f8").tobytes())


@pytest.mark.parametrize("fmt", ["space_gz", "csv_header", "tabs_comment"])
def test_read_soundings_variants(tmp_path, fmt):
    if fmt == "space_gz":
        p = tmp_path / "em122_line01.xyz.gz"
        with gzip.open(p, "wt") as fh:
            np.savetxt(fh, SOUND, fmt="%.6f %.6f %.3f")
    elif fmt == "csv_header":
        p = tmp_path / "s.csv"
        p.write_text("lon,lat,depth\n" + "\n".join(",".join(map(str, r)) for r in SOUND) + "\n")
    else:
        p = tmp_path / "s.xyz"
        p.write_text("# EM122\n" + "\n".join("\t".join(map(str, r)) for r in SOUND) + "\n")
    df = read_soundings(p)
    assert list(df.columns) == ["longitude_deg", "latitude_deg", "depth_m"]
    np.testing.assert_allclose(df.to_numpy(), SOUND)


def test_read_soundings_nan_kept_for_gridder(tmp_path):
    p = tmp_path / "s.xyz"
    p.write_text("142.2 11.33 8000\n142.2 11.33 nan\n142.2 11.34 8001\n")
    assert read_soundings(p)["depth_m"].isna().sum() == 1


@pytest.mark.parametrize(
    "content, match",
    [
        (b"", "empty"),
        (b"# only a comment\n", "no soundings"),
        (b"142.2 11.33 8000\n142.2 11.33\n", "truncated"),
        (b"142.2 11.33 8000\n142.2 abc 8001\n", "non-numeric"),
        (b"142.2 11.33\n142.3 11.34\n", "expected 3 columns"),
        (b"11.33 142.2 8000\n11.34 142.3 8000\n", "latitude out of"),
    ],
)
def test_read_soundings_bad(tmp_path, content, match):
    p = tmp_path / "bad.xyz"
    p.write_bytes(content)
    with pytest.raises(InputError, match=match) as ei:
        read_soundings(p)
    assert "\n" not in str(ei.value)


def test_read_soundings_elevations_become_depths(tmp_path):
    """All-negative values are elevations (positive up): converted to depth positive down and recorded."""
    p = tmp_path / "elev.xyz"
    p.write_bytes(b"142.2 11.33 -8000\n142.3 11.34 -8001\n")
    df = read_soundings(p)
    np.testing.assert_allclose(df["depth_m"], [8000, 8001])
    assert (df.attrs["z_positive"], df.attrs["z_positive_from"]) == ("up", "values")


def test_read_soundings_truncated_gzip_and_missing(tmp_path):
    p = tmp_path / "t.xyz.gz"
    with gzip.open(p, "wt") as fh:
        np.savetxt(fh, np.tile(SOUND, (2000, 1)))
    p.write_bytes(p.read_bytes()[:-200])
    with pytest.raises(InputError, match="truncated gzip"):
        read_soundings(p)
    with pytest.raises(InputError, match="does not exist"):
        read_soundings(tmp_path / "nope.xyz.gz")


def test_point_clouds_ply_pcd_las(tmp_path):
    import laspy
    import open3d as o3d

    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(0, 5, 500), rng.uniform(0, 2, 500), -1400 + rng.normal(0, 0.01, 500)])
    _write_ply_f64(tmp_path / "submap_01.ply", pts)
    np.testing.assert_array_equal(read_point_cloud(tmp_path / "submap_01.ply"), pts)
    o3d.io.write_point_cloud(str(tmp_path / "c.pcd"), o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts)))
    np.testing.assert_allclose(read_point_cloud(tmp_path / "c.pcd"), pts, atol=1e-6)
    hdr = laspy.LasHeader(point_format=0, version="1.2")
    hdr.scales = [0.001, 0.001, 0.001]
    hdr.offsets = [0.0, 0.0, -1400.0]
    las = laspy.LasData(hdr)
    las.x, las.y, las.z = pts[:, 0], pts[:, 1], pts[:, 2]
    las.write(tmp_path / "c.las")
    np.testing.assert_allclose(read_point_cloud(tmp_path / "c.las"), pts, atol=6e-4)


def test_point_cloud_bad(tmp_path):
    pts = np.random.default_rng(1).normal(size=(100, 3))
    _write_ply_f64(tmp_path / "trunc.ply", pts, n_header=200)
    with pytest.raises(InputError, match="truncated|no points"):
        read_point_cloud(tmp_path / "trunc.ply")
    (tmp_path / "junk.ply").write_bytes(b"not a ply file at all")
    with pytest.raises(InputError, match="unsupported point cloud format"):  # content decides, not the name
        read_point_cloud(tmp_path / "junk.ply")
    (tmp_path / "x.obj").write_text("v 0 0 0\n")
    with pytest.raises(InputError, match="unsupported"):
        read_point_cloud(tmp_path / "x.obj")
    (tmp_path / "bad.las").write_bytes(b"LASF" + b"\0" * 50)
    with pytest.raises(InputError, match="cannot read LAS"):
        read_point_cloud(tmp_path / "bad.las")


def test_looks_metric_rule():
    assert looks_metric(21.9, 18.5, 2.26)          # laser raster: 2 m relief over 28 "degrees"
    assert not looks_metric(6.0, 5.0, 5386.0)     # ETOPO near Bermuda in degrees
    assert looks_metric(500.0, 100.0, 50.0)       # extent impossible in degrees
    assert not looks_metric(1.0, 1.0, 0.0)        # flat: cannot tell -> trust the tag


def test_real_etopo_netcdf(shared_data):
    da = read_grid(shared_data / "bathy-real" / "tut_bathy.nc")
    assert da.attrs["crs_kind"] == "geographic" and da.dims == ("y", "x")
    assert da.shape == (61, 73)
    assert float(da.min()) == -5475.0 and float(da.max()) == -89.0
    assert float(da.x[0]) == -66.0 and float(da.y[-1]) == 35.0
    assert np.all(np.diff(da.x) > 0) and np.all(np.diff(da.y) > 0)


def test_real_laser_geotiff_mislabelled_crs(shared_data):
    path = shared_data / "bathy-real" / "LAD_Takuyo_B1_raster_100mm.tif"
    with pytest.warns(GridCRSWarning, match="local metric"):
        da = read_grid(path)
    assert da.attrs["crs_kind"] == "local_metric" and da["x"].attrs["units"] == "m"
    assert da.attrs["cell_size_x"] == pytest.approx(0.10) and da.shape == (185, 219)
    np.testing.assert_allclose(np.diff(da.x), 0.1, atol=1e-9)
    assert np.all(np.diff(da.y) > 0)
    v = da.values[np.isfinite(da.values)]
    assert 0.10 < v.size / da.size < 0.16  # nodata 0 -> NaN (87 % of the raster is unmapped)
    assert 1379.0 < v.min() and v.max() < 1382.0  # ~1380 m at Takuyo-Daigo
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        forced = read_grid(path, crs_kind="geographic")  # explicit override: no detection
    assert forced.attrs["crs_kind"] == "geographic"


def test_real_gsf(shared_data):
    df = read_gsf(shared_data / "bathy-real" / "0029_20160323_185603_EX1604_MB.gsf.mb121")
    assert df["ping"].nunique() == 8 and len(df) == 2369  # 8 x 432 beams, flagged beams dropped
    assert 3849.0 <= df["depth_m"].min() and df["depth_m"].max() <= 4309.0
    assert df["latitude_deg"].between(8.6, 8.8).all() and df["longitude_deg"].between(167.4, 167.6).all()
    everything = read_gsf(shared_data / "bathy-real" / "0029_20160323_185603_EX1604_MB.gsf.mb121",
                          include_flagged=True)
    assert len(everything) > len(df) and everything["depth_m"].max() == pytest.approx(4308.82)


def test_real_laser_raster_regrid_round_trip(shared_data):
    """Cell centres of the real 0.10 m laser raster, gridded back at 0.10 m, reproduce it exactly;
    at 0.20 m each cell is the mean of its 2 x 2 block."""
    from hadal.grid import grid_points

    with pytest.warns(GridCRSWarning):
        da = read_grid(shared_data / "bathy-real" / "LAD_Takuyo_B1_raster_100mm.tif")
    xx, yy = np.meshgrid(da.x.values, da.y.values)
    ok = np.isfinite(da.values)
    x0, y0 = float(da.x[0]) - 0.05, float(da.y[0]) - 0.05
    bounds = (x0, y0, x0 + 0.1 * da.sizes["x"], y0 + 0.1 * da.sizes["y"])
    g = grid_points(xx[ok], yy[ok], da.values[ok], 0.1, bounds=bounds, statistics=("mean", "count"))
    np.testing.assert_allclose(g["mean"].values, da.values, equal_nan=True, rtol=0, atol=1e-9)
    assert int(g["count"].max()) == 1
    g2 = grid_points(xx[ok], yy[ok], da.values[ok], 0.2, bounds=bounds, statistics=("mean", "count"))
    blk = da.values[:184, :218].reshape(92, 2, 109, 2)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        exp = np.nanmean(blk, axis=(1, 3))
    np.testing.assert_allclose(g2["mean"].values[:92, :109], exp, equal_nan=True, atol=1e-9)


def test_real_gsf_gridded_to_dtm(shared_data):
    """The real EM302 swath, projected into a local frame and gridded: a plausible 4 km-deep DTM."""
    from hadal.geo import LocalFrame
    from hadal.grid import grid_multibeam

    df = read_gsf(shared_data / "bathy-real" / "0029_20160323_185603_EX1604_MB.gsf.mb121")
    frame = LocalFrame(float(df["latitude_deg"].mean()), float(df["longitude_deg"].mean()))
    x, y = frame.to_xy(df["longitude_deg"], df["latitude_deg"])
    ds = grid_multibeam(x, y, df["depth_m"].to_numpy(), 200.0)
    assert ds.attrs["n_soundings_used"] + ds.attrs["n_soundings_spikes"] == len(df)
    assert ds.attrs["n_soundings_spikes"] < 0.02 * len(df)  # an edited swath has few spikes left
    assert 3849.0 <= float(ds["depth_m"].min()) and float(ds["depth_m"].max()) <= 4309.0
    assert 4.0 < ds.sizes["x"] * 0.2 < 12.0  # ~8 km swath at 4 km depth (EM302, +-65 deg)
