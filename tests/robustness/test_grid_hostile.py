"""Hostile prior-grid / multibeam / point-cloud inputs (issue 14 hunt, findings 07, 08, 09, 13, 15, 16).

Each test builds a small input and checks it against an independent expectation: the analytic terrain the
input was made from, the float32 spacing numpy reports, or the number of soundings written to the file.
"""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import xarray as xr
import yaml

from hadal.errors import InputError
from hadal.geo import LocalFrame

LAT0, LON0 = 11.33, 142.2


def _elev(lat, lon):
    """Analytic elevation (m, negative down) of the test terrain (the hunt's _grid.py terrain)."""
    return -(8000.0 + 2000.0 * (lat - LAT0) + 1000.0 * np.sin((lon - LON0) * 20))


def _axes(n=41, step=0.001, lat0=LAT0, lon0=LON0):
    return lat0 - 0.02 + step * np.arange(n), lon0 - 0.02 + step * np.arange(n)


def _write_nc(p, z, dims, coords):
    xr.Dataset({"z": (dims, z)}, coords=coords).to_netcdf(p, engine="h5netcdf")


def _geo_tif(p, z, *, dtype="float32", nodata=None, scale=None, offset=None, tags=None):
    import rasterio
    from affine import Affine

    t = Affine(0.001, 0, LON0 - 0.0205, 0, -0.001, LAT0 + 0.0205)
    with rasterio.open(p, "w", driver="GTiff", height=z.shape[0], width=z.shape[1], count=1, dtype=dtype,
                       crs="EPSG:4326", transform=t, nodata=nodata) as dst:
        dst.write(z.astype(dtype), 1)
        if scale is not None:
            dst.scales, dst.offsets = (scale,), (offset,)
        if tags:
            dst.update_tags(**tags)
    rows, cols = np.mgrid[0:z.shape[0], 0:z.shape[1]]
    lat = LAT0 + 0.0205 - 0.001 * (rows + 0.5)
    lon = LON0 - 0.0205 + 0.001 * (cols + 0.5)
    return lat, lon


# ------------------------------------------------------------------ 16: z(time, lat, lon)
def test_netcdf_time_dimension_squeezed_or_refused_never_local_metric(tmp_path):
    """A length-1 leading dimension is squeezed (values and degree coordinates as written); several times are
    refused with a message naming the dimension and its length - never GDAL's band 1 as 1 mm metric cells."""
    from hadal.grid.prior import prior_dtm
    from hadal.grid.readers import read_grid

    lat, lon = _axes()
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    coords = {"lat": ("lat", lat, {"units": "degrees_north"}), "lon": ("lon", lon, {"units": "degrees_east"})}
    p1 = tmp_path / "one.nc"
    _write_nc(p1, _elev(la, lo)[None], ("time", "lat", "lon"), {**coords, "time": [0]})
    da = read_grid(p1)
    assert da.attrs["crs_kind"] == "geographic"
    np.testing.assert_allclose(da.x.values, lon)
    np.testing.assert_allclose(da.values, _elev(la, lo))

    p2 = tmp_path / "two.nc"
    _write_nc(p2, np.stack([_elev(la, lo), _elev(la, lo) - 5000]), ("time", "lat", "lon"), {**coords, "time": [0, 1]})
    with pytest.raises(InputError, match=r"z has dims \(time, lat, lon\) with 2 time values.*ncks -d time,0"):
        read_grid(p2)
    with pytest.raises(InputError, match="2 time values"):
        prior_dtm(p2, LocalFrame(LAT0, LON0))
    with pytest.raises(InputError, match="2 time values"):  # naming the variable does not pick a slice either
        read_grid(p2, variable="z")
    # a CF lat/lon netCDF with no grid variable hadal recognises is refused, not handed to GDAL's band 1
    p3 = tmp_path / "mask_only.nc"
    xr.Dataset({"mask": (("lat", "lon"), _elev(la, lo))}, coords=coords).to_netcdf(p3, engine="h5netcdf")
    with pytest.raises(InputError, match=r"CF lat/lon coordinates \(lat, lon\)"):
        read_grid(p3)
    assert read_grid(p3, variable="mask").attrs["crs_kind"] == "geographic"


# ------------------------------------------------------------------ 07: GeoTIFF scale/offset
def test_geotiff_band_scale_offset_applied(tmp_path):
    """int16 packed with GDAL scale 0.5, offset -8000: values are raw * 0.5 - 8000, i.e. the analytic terrain
    within half a packing step (0.25 m)."""
    import rasterio

    from hadal.grid.readers import read_grid

    p = tmp_path / "packed.tif"
    rows, cols = np.mgrid[0:41, 0:41]
    lat = LAT0 + 0.0205 - 0.001 * (rows + 0.5)
    lon = LON0 - 0.0205 + 0.001 * (cols + 0.5)
    truth = _elev(lat, lon)
    _geo_tif(p, np.rint((truth + 8000.0) / 0.5), dtype="int16", nodata=-32768, scale=0.5, offset=-8000.0)
    with rasterio.open(p) as src:
        assert src.scales[0] == 0.5 and src.offsets[0] == -8000.0  # the file really is packed
    da = read_grid(p)
    v = da.values[::-1, :]  # read_grid returns y ascending; the raster is north-up
    assert np.nanmax(np.abs(v - truth)) <= 0.25 + 1e-9
    assert "scale 0.5" in da.attrs["scale_offset"]


# ------------------------------------------------------------------ 08: impossible depths
def test_impossible_depths_masked_or_refused(tmp_path):
    """A -32767 fill without a nodata tag becomes nodata (the rest matches the terrain); a grid tagged feet is
    converted to metres; untagged feet and a lone 20 km value are refused in one line; a real 9 999 m hadal depth
    is kept."""
    from hadal.grid.prior import MAX_ABS_DEPTH_M, check_depth_plausible, prior_dtm

    assert 10_935 < MAX_ABS_DEPTH_M <= 12_000
    frame = LocalFrame(LAT0, LON0)
    rows, cols = np.mgrid[0:41, 0:41]
    lat = LAT0 + 0.0205 - 0.001 * (rows + 0.5)
    lon = LON0 - 0.0205 + 0.001 * (cols + 0.5)
    truth = _elev(lat, lon)
    pa = tmp_path / "fill.tif"
    _geo_tif(pa, np.where(lon > LON0 + 0.01, -32767.0, truth))
    ds = prior_dtm(pa, frame)
    dep = ds["depth_m"].values
    ok = np.isfinite(dep)
    assert np.nanmax(dep) < 9000  # the terrain's deepest cell is ~8 230 m in the kept part
    err = np.abs(dep[ok] - (-_elev(ds["lat"].values[ok], ds["lon"].values[ok])))
    assert np.median(err) < 0.5
    assert "-32767" in ds.attrs["prior_grid_depth_check"]

    pb = tmp_path / "feet.tif"  # tagged feet: converted to metres (the tag is the file's own word)
    _geo_tif(pb, truth / 0.3048, tags={"UNITS": "ft"})
    dsf = prior_dtm(pb, frame)
    okf = np.isfinite(dsf["depth_m"].values)
    errf = np.abs(dsf["depth_m"].values[okf] - (-_elev(dsf["lat"].values[okf], dsf["lon"].values[okf])))
    assert np.median(errf) < 0.5 and "x 0.3048" in dsf.attrs["prior_grid_z_units"]
    pc = tmp_path / "feet_untagged.tif"
    _geo_tif(pc, truth / 0.3048)
    with pytest.raises(InputError, match=r"look like feet"):
        prior_dtm(pc, frame)

    da = xr.DataArray(np.full((5, 5), -8000.0), dims=("y", "x"), attrs={"source": "g"})
    da.values[2, 2] = -20_000.0
    with pytest.raises(InputError, match=r"-20000.*fill value without a nodata tag"):
        check_depth_plausible(da)
    trench = xr.DataArray(np.linspace(9990.0, 10_010.0, 25).reshape(5, 5), dims=("y", "x"))
    trench.values[0, :2] = 9999.0
    out, note = check_depth_plausible(trench)
    assert note == "" and np.isfinite(out.values).all()


# ------------------------------------------------------------------ 09: antimeridian in -180..180
def test_netcdf_across_antimeridian_in_signed_longitudes(tmp_path):
    """179.98 .. 180, -179.999 .. -179.96: a regular 0.001 deg grid; the DTM matches the analytic terrain."""
    from hadal.grid.prior import prior_dtm

    def elev(la, lo):
        lo = np.where(lo > 180, lo - 360, lo)
        return -(8000.0 + 2000.0 * la + 1000.0 * np.sin(np.radians(lo) * 2000))

    lat = -0.02 + 0.001 * np.arange(41)
    lon = 179.98 + 0.001 * np.arange(41)
    lon = np.where(lon > 180, lon - 360, lon)
    la, lo = np.meshgrid(lat, lon, indexing="ij")
    p = tmp_path / "am.nc"
    _write_nc(p, elev(la, lo), ("lat", "lon"), {"lat": ("lat", lat, {"units": "degrees_north"}),
                                                "lon": ("lon", lon, {"units": "degrees_east"})})
    ds = prior_dtm(p, LocalFrame(0.0, 180.0))
    dep = ds["depth_m"].values
    ok = np.isfinite(dep)
    assert ok.mean() > 0.8
    err = np.abs(dep[ok] - (-elev(ds["lat"].values[ok], ds["lon"].values[ok])))
    assert np.median(err) < 0.5 and err.max() < 5.0


# ------------------------------------------------------------------ 15: duplicate multibeam sources
@pytest.mark.parametrize("how", ["same path twice", "identical copy"])
def test_duplicate_multibeam_sources_counted_once(tmp_path, caplog, how):
    """The soundings of one file listed twice (or copied under another name) are gridded once: the DTM's
    total count is at most the number of lines written, and the duplicate is named in a WARNING."""
    from hadal.pipeline import make_context, run_stage

    rng = np.random.default_rng(1)
    n = 4000
    x, y = rng.uniform(-200, 200, n), rng.uniform(-200, 200, n)
    dep = 8000 + 20 * np.sin(x / 100) + rng.normal(0, 0.5, n)
    lon, lat = LocalFrame(LAT0, LON0).to_lonlat(x, y)
    raw = tmp_path / "raw"
    (raw / "mb").mkdir(parents=True)
    np.savetxt(raw / "mb" / "a.xyz", np.column_stack([lon, lat, dep]), fmt="%.8f %.8f %.2f")
    listing = ["mb/a.xyz", "mb/a.xyz"]
    if how == "identical copy":
        shutil.copy(raw / "mb" / "a.xyz", raw / "mb" / "copy.xyz")
        listing = ["mb/a.xyz", "mb/copy.xyz"]
    (raw / "dive.yaml").write_text(yaml.safe_dump({
        "dive_id": "D1", "platform": "test",
        "map_frame": {"origin_latitude_deg": LAT0, "origin_longitude_deg": LON0},
        "sources": {"multibeam": listing}}))
    with caplog.at_level("WARNING"):
        out = run_stage("grid", make_context(raw, tmp_path / "store"))
    with xr.open_dataset(out["dtm"].file("dtm.nc"), engine="h5netcdf") as ds:
        total = int(np.nansum(ds["count"].values))
    assert 0.95 * n <= total <= n
    assert "dropped" in caplog.text and ("listed twice" in caplog.text or "identical content" in caplog.text)


# ------------------------------------------------------------------ 13: float32-quantised point cloud
def test_float32_utm_cloud_quantisation_detected():
    """A cloud at UTM-sized coordinates rounded through float32 sits on numpy's float32 spacing there
    (2**-5 m in x at 5.1e5, 2**-3 m in y at 1.25e6): 'auto' does not grid it finer than that, a pinned 10 mm
    cell is refused in one line, and the float64 cloud still gets the paper's 10 mm."""
    from hadal.grid.laser import coordinate_quantum_m, grid_laser

    rng = np.random.default_rng(2)
    m = 8000
    x, y = rng.uniform(0, 0.4, m), rng.uniform(0, 0.4, m)
    pts = np.column_stack([x + 512345.0, y + 1253456.0, -10900 + 0.02 * np.sin(x * 20) + rng.normal(0, 1e-3, m)])
    p32 = pts.astype(np.float32).astype(np.float64)
    qy = float(np.spacing(np.float32(1253456.0)))
    assert qy == 0.125
    assert coordinate_quantum_m(p32[:, 1]) == pytest.approx(qy)
    assert coordinate_quantum_m(pts[:, 1]) < 1e-3
    with pytest.warns(UserWarning, match="float32"):
        ds = grid_laser(p32, "auto", sor_neighbors=0)
    assert ds.attrs["resolution_m"] >= qy
    assert "quantised to 0.125 m" in ds.attrs["coordinate_quantisation"]
    assert ds.attrs["mapped_fraction"] > 0.7
    with pytest.raises(InputError, match=r"quantised to 0.125 m.*float32"):
        grid_laser(p32, 0.01, sor_neighbors=0)
    assert grid_laser(pts, "auto", sor_neighbors=0).attrs["resolution_m"] == pytest.approx(0.01)
    i, j = np.meshgrid(np.arange(30), np.arange(30))  # a 20 mm lattice near the origin: no precision lost
    lat = np.column_stack([0.02 * i.ravel(), 0.02 * j.ravel(), np.zeros(i.size)])
    with pytest.warns(UserWarning, match="lattice"):  # a pinned finer cell is the user's choice: warned only
        assert grid_laser(lat, 0.01, sor_neighbors=0).attrs["resolution_m"] == pytest.approx(0.01)


def test_multibeam_fill_soundings_dropped_feet_refused(tmp_path):
    """Soundings beyond 11.5 km (a 32767 / 99999 fill in the depth column) are dropped: the DTM counts exactly
    the plausible ones written; a file whose depths are all in feet is refused in one line."""
    from hadal.settings import GridParams as Params
    from hadal.stages.grid import make_dtm

    rng = np.random.default_rng(3)
    n = 3000
    frame = LocalFrame(LAT0, LON0)
    x, y = rng.uniform(-150, 150, n), rng.uniform(-150, 150, n)
    dep = 8000 + 10 * np.sin(x / 80) + rng.normal(0, 0.3, n)
    dep[:40], dep[40:60] = 32767.0, 99999.0
    lon, lat = frame.to_lonlat(x, y)
    f = tmp_path / "fill.xyz"
    np.savetxt(f, np.column_stack([lon, lat, dep]), fmt="%.8f %.8f %.2f")
    ds = make_dtm([f], frame, Params(spike_removal=False, fill_max_cells=0))
    assert int(np.nansum(ds["count"].values)) == n - 60
    assert ds.attrs["n_soundings_implausible"] == 60
    assert float(np.nanmax(ds["depth_m"].values)) < 8100
    g = tmp_path / "feet.xyz"
    np.savetxt(g, np.column_stack([lon, lat, (8000 + 10 * np.sin(x / 80)) / 0.3048]), fmt="%.8f %.8f %.2f")
    with pytest.raises(InputError, match=r"feet\?"):
        make_dtm([g], frame, Params())
