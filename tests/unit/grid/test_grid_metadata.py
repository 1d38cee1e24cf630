"""Bathymetry grids read by their metadata (issue 43): units, sign, longitude convention, land, several grids.

Oracles: the grid files read independently with netCDF4 (its own scale_factor/units/coordinates) and scipy's
bilinear interpolation at the DTM cells' own lon/lat; synthetic grids whose values are known by construction.
"""

from __future__ import annotations

import json
import shutil
import warnings

import numpy as np
import pytest
import xarray as xr
import yaml
from scipy.interpolate import RegularGridInterpolator

from hadal.errors import InputError
from hadal.pipeline import make_context, run_stage

HI = "dives-real/gmt_HI_topo_04.nc"
KILAUEA = "dives-real/gmt_Kilauea.utm.nc"
PIXEL = "formats-real/gmt_depth_pixel.nc"


def _src(shared, rel):
    p = shared / rel
    if not p.is_file():
        pytest.skip(f"{rel} not in this copy of the shared data")
    return p


def _open(pv, name="dtm.nc"):
    with xr.open_dataset(pv.file(name), engine="h5netcdf") as ds:
        return ds.load()


def _hi_oracle(path):
    """(lat, lon 0-360, elevation in metres) of HI_topo from netCDF4: z with its scale_factor, times the metres
    per unit its own ``units`` attribute names."""
    import netCDF4

    with netCDF4.Dataset(path) as nc:
        assert nc["z"].units == "km"
        z = np.asarray(nc["z"][:], float) * 1000.0
        return np.asarray(nc["lat"][:], float), np.asarray(nc["lon"][:], float), z


def _init(raw):
    from hadal.dive_init import scan_dive_dir, write_init

    res = scan_dive_dir(raw)
    write_init(res)
    return res


def test_hi_topo_km_0360_is_a_prior_grid_with_land_masked(shared_data, tmp_path):
    src = _src(shared_data, HI)
    raw = tmp_path / "hi"
    raw.mkdir()
    shutil.copy(src, raw / src.name)
    res = _init(raw)
    assert res.dive["sources"] == {"prior_grid": [src.name]}  # the file says km and Topography: no hint needed
    mf = res.dive["map_frame"]
    assert mf["origin_longitude_deg"] == pytest.approx(202.5 - 360.0) and mf["origin_latitude_deg"] == 21.5
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = run_stage("dtm", make_context(raw, tmp_path / "store"))
    dtm = _open(out["dtm"])
    assert dtm.attrs["dtm_source"] == "prior_grid"
    assert "km" in dtm.attrs["prior_grid_z_units"] and "x 1000" in dtm.attrs["prior_grid_z_units"]
    assert "0-360" in dtm.attrs["prior_grid_lon_convention"]
    assert dtm.attrs["z_sign_detection"].startswith("name/units") and dtm.attrs["z_positive_source"] == "up"
    lon, lat = dtm["lon"].values, dtm["lat"].values
    has = np.isfinite(dtm["depth_m"].values) | (dtm["land"].values == 1)  # cells with a value: inside the file
    assert -165.0 <= lon[has].min() < -164.9 and -150.1 < lon[has].max() <= -150.0
    assert 18.0 <= lat[has].min() < 18.1 and 24.9 < lat[has].max() <= 25.0
    olat, olon, oz = _hi_oracle(src)
    interp = RegularGridInterpolator((olat, olon), oz, bounds_error=False, fill_value=np.nan)
    elev = interp(np.column_stack([lat.ravel(), np.mod(lon.ravel(), 360.0)])).reshape(lat.shape)
    dep, land = dtm["depth_m"].values, dtm["land"].values
    sea = np.isfinite(elev) & (elev <= 0)
    assert sea.sum() > 1000
    np.testing.assert_allclose(dep[sea], -elev[sea], atol=0.01)  # depth = -1000 x z_km, cell by cell
    on_land = np.isfinite(elev) & (elev > 0)
    assert on_land.sum() > 20  # the islands
    assert np.all(land[on_land] == 1) and np.all(np.isnan(dep[on_land]))
    assert np.all(land[sea] == 0)
    assert dtm.attrs["n_cells_land"] == int((land == 1).sum())
    assert np.nanmin(dep) >= 0 and np.nanmax(dep) <= 5784.0 + 1e-6  # never a negative depth, never deeper than the file
    # the report's DTM figure draws exactly the cells the oracle says are land, in the land colour
    from hadal.report.figures import LAND_COLOUR, FigureOptions, fig_dtm
    from hadal.report.load import DiveProducts

    dp = DiveProducts(dive="hi")
    dp.dtm = dtm
    r = fig_dtm(dp, FigureOptions(keep_figure=True, dpi=50))
    assert r.png and r.skipped is None and "Land" in r.caption
    ims = r.figure.axes[0].get_images()
    lay = [im for im in ims if im.cmap.N == 1 and im.cmap(0)[:3] == pytest.approx(
        tuple(int(LAND_COLOUR[k:k + 2], 16) / 255 for k in (1, 3, 5)))]
    assert len(lay) == 1
    drawn = ~np.ma.getmaskarray(lay[0].get_array())
    np.testing.assert_array_equal(drawn[np.isfinite(elev)], (elev > 0)[np.isfinite(elev)])
    assert "land" in [t.get_text() for t in r.figure.axes[0].get_legend().get_texts()]


def test_kilauea_land_dem_refused_in_one_line(shared_data, tmp_path):
    src = _src(shared_data, KILAUEA)
    import netCDF4

    with netCDF4.Dataset(src) as nc:  # the oracle: its own range
        z = np.asarray(nc["z"][:].compressed(), float)
    lo, hi = z.min(), z.max()
    raw = tmp_path / "kil"
    raw.mkdir()
    shutil.copy(src, raw / src.name)
    res = _init(raw)
    assert not res.dive["sources"]
    msg = [n for n in res.not_used if n.startswith(src.name)]
    assert msg and f"is land elevation ({lo:g}-{hi:g} m" in msg[0] and "no seafloor to grid" in msg[0]
    # listed by hand, the dtm stage refuses it with the same one line
    (raw / "dive.yaml").write_text(yaml.safe_dump({"dive_id": "K", "platform": "t", "sources": {"prior_grid": [src.name]},
                                                   "map_frame": {"origin_latitude_deg": 19.4,
                                                                 "origin_longitude_deg": -155.3}}))
    with pytest.raises(InputError, match=r"is land elevation \(0-1505 m.*no seafloor to grid") as ei:
        run_stage("dtm", make_context(raw, tmp_path / "store"))
    assert "\n" not in str(ei.value)


def test_unmarked_grid_gets_commented_hints_in_dive_yaml(shared_data, tmp_path):
    """gmt_depth_pixel.nc has no units and no sign metadata: init writes both guesses as commented hints, and the
    DTM read with them is the one read without them (the values are unchanged); land (716 m) is masked."""
    src = _src(shared_data, PIXEL)
    raw = tmp_path / "px"
    raw.mkdir()
    shutil.copy(src, raw / src.name)
    res = _init(raw)
    entry = res.dive["sources"]["prior_grid"][0]
    assert entry == {"path": src.name, "z_positive": "up", "z_units": "m"}
    text = (raw / "dive.yaml").read_text()
    assert "z_positive: up  # guessed: mixed signs" in text and "z_units: m  # assumed" in text
    assert yaml.safe_load(text)["sources"]["prior_grid"][0] == entry
    from hadal.dive import Dive

    Dive.model_validate(yaml.safe_load(text))


def _fine_grid(path, lon0, lon1, lat0, lat1, step):
    """A geographic depth grid that says so (positive down, standard_name, units m): depth = 3000 + 100 lon."""
    lon = np.arange(lon0, lon1 + step / 2, step)
    lat = np.arange(lat0, lat1 + step / 2, step)
    z = np.broadcast_to(3000.0 + 100.0 * (lon[None, :] - lon0) + 50.0 * (lat[:, None] - lat0), (lat.size, lon.size))
    ds = xr.Dataset({"depth": (("lat", "lon"), z.copy(), {"units": "m", "positive": "down",
                                                          "standard_name": "sea_floor_depth_below_sea_surface"})},
                    coords={"lat": ("lat", lat, {"units": "degrees_north"}),
                            "lon": ("lon", lon, {"units": "degrees_east"})})
    ds.to_netcdf(path)
    return lat, lon, z


def test_two_prior_grids_mosaicked_finer_wins_land_grid_refused_by_name(shared_data, tmp_path):
    src = _src(shared_data, HI)
    kil = _src(shared_data, KILAUEA)
    raw = tmp_path / "two"
    raw.mkdir()
    shutil.copy(src, raw / src.name)
    shutil.copy(kil, raw / kil.name)
    flat, flon, fz = _fine_grid(raw / "fine.nc", -158.5, -157.5, 20.5, 21.5, 0.02)
    # the coarse grid listed first: the finer one still wins where they overlap
    (raw / "dive.yaml").write_text(yaml.safe_dump({
        "dive_id": "M", "platform": "t", "sources": {"prior_grid": [src.name, "fine.nc", kil.name]},
        "map_frame": {"origin_latitude_deg": 21.0, "origin_longitude_deg": -158.0}}))
    (raw / "pipeline.yaml").write_text("grid: {prior_resolution_m: 2000}\n")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = run_stage("dtm", make_context(raw, tmp_path / "store"))
    dtm = _open(out["dtm"])
    assert dtm.attrs["prior_grid_files"] == f"{src.name}, fine.nc"
    per = {d["file"]: d for d in json.loads(dtm.attrs["prior_grid_sources"])}
    assert per["fine.nc"]["priority"] == 1 and per[src.name]["priority"] == 2
    assert per["fine.nc"]["n_cells_used"] > 100 and per[src.name]["n_cells_used"] > 1000
    assert kil.name in dtm.attrs["prior_grid_refused"] and "no seafloor" in dtm.attrs["prior_grid_refused"]
    assert set(out["dtm"].manifest()["readers"]) >= {src.name, "fine.nc"}
    lat, lon, dep = dtm["lat"].values, dtm["lon"].values, dtm["depth_m"].values
    s = dtm["prior_grid_source"].values
    fine = RegularGridInterpolator((flat, flon), fz, bounds_error=False, fill_value=np.nan)
    ef = fine(np.column_stack([lat.ravel(), lon.ravel()])).reshape(lat.shape)
    inside = np.isfinite(ef)
    assert inside.sum() > 100 and np.all(s[inside] == 1)  # every cell the fine grid covers comes from it
    np.testing.assert_allclose(dep[inside], ef[inside], atol=1e-6)
    olat, olon, oz = _hi_oracle(src)
    coarse = RegularGridInterpolator((olat, olon), oz, bounds_error=False, fill_value=np.nan)
    ec = coarse(np.column_stack([lat.ravel(), np.mod(lon.ravel(), 360.0)])).reshape(lat.shape)
    rest = (s == 0) & (ec <= 0)
    assert rest.sum() > 1000
    np.testing.assert_allclose(dep[rest], -ec[rest], atol=0.01)
    assert np.all(np.isnan(dep[(s == 0) & (ec > 0)])) and np.all(dtm["land"].values[(s == 0) & (ec > 0)] == 1)


def test_units_and_sign_from_metadata(tmp_path):
    """Units converted from the file's own word (km, ft, fathoms), unknown units refused, absent ones assumed and
    said; the sign from positive/standard_name/long_name before any value guess; land (elevation > 0) masked."""
    from hadal.geo import LocalFrame
    from hadal.grid.prior import prior_dtm, z_positive
    from hadal.grid.readers import read_grid

    lon = np.linspace(141.9, 142.1, 21)
    lat = np.linspace(11.2, 11.4, 21)
    base = np.linspace(-2.0, 0.5, 21)[None, :] * np.ones((21, 1))  # km, the east edge above sea level

    def write(name, z, **attrs):
        ds = xr.Dataset({"z": (("lat", "lon"), z, attrs)},
                        coords={"lat": ("lat", lat, {"units": "degrees_north"}),
                                "lon": ("lon", lon, {"units": "degrees_east"})})
        ds.to_netcdf(tmp_path / name)
        return tmp_path / name

    km = read_grid(write("km.nc", base, units="km"))
    np.testing.assert_allclose(km.values, base * 1000.0)
    ft = read_grid(write("ft.nc", base * 1000 / 0.3048, units="feet"))
    np.testing.assert_allclose(ft.values, base * 1000.0, rtol=1e-9)
    fm = read_grid(write("fm.nc", -base * 1000 / 1.8288, units="fathoms", positive="down"))
    np.testing.assert_allclose(fm.values, -base * 1000.0, rtol=1e-9)
    with pytest.raises(InputError, match=r"'degC', not a length unit"):
        read_grid(write("c.nc", base, units="degC"))
    none = read_grid(write("none.nc", base * 1000))
    assert none.attrs["z_units_assumed"] == 1 and "assumed" in none.attrs["z_units_source"]
    # an all-positive grid that says it is elevation is elevation, whatever the values
    up = read_grid(write("up.nc", np.full((21, 21), 1200.0), long_name="elevation above mean sea level"))
    assert z_positive(up)[0] == "up"
    dn = read_grid(write("dn.nc", np.full((21, 21), 1200.0), standard_name="sea_floor_depth_below_sea_surface"))
    assert z_positive(dn)[0] == "down"
    ds = prior_dtm(tmp_path / "km.nc", LocalFrame(11.3, 142.0))
    land = ds["land"].values == 1
    assert land.any() and np.all(np.isnan(ds["depth_m"].values[land]))
    assert np.nanmin(ds["depth_m"].values) >= 0


def test_0360_grid_across_the_antimeridian_keeps_its_geolocation(tmp_path):
    """A grid 170..190 E (across 180) is kept continuous; a lookup at -175 (= 185 E) finds its value there."""
    from hadal.geo import LocalFrame
    from hadal.grid.prior import prior_dtm
    from hadal.grid.readers import read_grid

    lon = np.arange(170.0, 190.01, 0.1)
    lat = np.arange(-30.0, -20.0 + 1e-9, 0.1)
    z = -(4000.0 + 10.0 * (lon[None, :] - 170.0)) * np.ones((lat.size, 1))
    xr.Dataset({"z": (("lat", "lon"), z, {"units": "m", "positive": "up"})},
               coords={"lat": ("lat", lat, {"units": "degrees_north"}),
                       "lon": ("lon", lon, {"units": "degrees_east"})}).to_netcdf(tmp_path / "am.nc")
    da = read_grid(tmp_path / "am.nc")
    assert "across 180" in da.attrs["lon_convention"]
    ds = prior_dtm(tmp_path / "am.nc", LocalFrame(-25.0, -175.0), resolution_m=5000)
    x, y = ds.x.values, ds.y.values
    j, i = np.argmin(np.abs(y)), np.argmin(np.abs(x))
    # at the frame origin (-175 = 185 E) the depth is 4000 + 10 x 15
    assert float(ds["depth_m"].values[j, i]) == pytest.approx(4150.0, abs=10.0 * 0.05 + 1.0)


def test_one_minute_km_grid_beside_a_cast_goes_to_dtm(shared_data, tmp_path):
    """A 1' geographic grid in km around a cast's position is a prior grid (dtm), never laser/landing: its
    coordinates say degrees, its units say km (before: 0.3 'm' of relief over 0.5 'm' read as a laser raster)."""
    from hadal.inspect import inspect_file

    cast = _src(shared_data, "ctd-real/seabird_sta0860.cnv")
    info = inspect_file(cast)
    lat0, lon0 = float(info["latitude_deg"]), float(info["longitude_deg"])
    raw = tmp_path / "castgrid"
    raw.mkdir()
    shutil.copy(cast, raw / cast.name)
    lon = lon0 - 0.25 + np.arange(31) / 60.0
    lat = lat0 - 0.25 + np.arange(31) / 60.0
    z = -(1.2 + 0.3 * np.sin(lon[None, :] * 20.0) * np.cos(lat[:, None] * 20.0))  # km, below sea level
    xr.Dataset({"z": (("lat", "lon"), z, {"units": "km"})},
               coords={"lat": ("lat", lat, {"units": "degrees_north"}),
                       "lon": ("lon", lon, {"units": "degrees_east"})}).to_netcdf(raw / "bathy_1min.nc")
    res = _init(raw)
    assert "laser" not in res.dive["sources"]
    assert [e if isinstance(e, str) else e["path"] for e in res.dive["sources"]["prior_grid"]] == ["bathy_1min.nc"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        dtm = _open(run_stage("dtm", make_context(raw, tmp_path / "store"))["dtm"])
    d = dtm["depth_m"].values
    assert 900.0 - 1e-6 <= np.nanmin(d) and np.nanmax(d) <= 1500.0 + 1e-6  # metres: -1000 x z_km
    assert 1000 < dtm.attrs["resolution"] < 2000  # 1' cells, not 0.0167 m


def test_geotiff_vertical_crs_units(tmp_path):
    """A GeoTIFF with a compound CRS whose vertical part is in US survey feet (EPSG:4326+6360, NAVD88 height
    (ftUS)): values converted by the CRS's own unit (pyproj reads it back as the oracle)."""
    rasterio = pytest.importorskip("rasterio")
    from pyproj import CRS
    from rasterio.transform import from_origin

    from hadal.grid.readers import read_grid

    ft = CRS.from_user_input("EPSG:4326+6360").sub_crs_list[1].axis_info[0].unit_conversion_factor
    metres = np.linspace(-3000.0, -2000.0, 20)[None, :] * np.ones((20, 1))
    with rasterio.open(tmp_path / "v.tif", "w", driver="GTiff", width=20, height=20, count=1, dtype="float64",
                       crs="EPSG:4326+6360", transform=from_origin(-80, 30, 0.01, 0.01)) as dst:
        dst.write(metres / ft, 1)
    da = read_grid(tmp_path / "v.tif")
    assert "US survey foot" in da.attrs["z_units_source"] and da.attrs["units"] == "m"
    np.testing.assert_allclose(np.sort(da.values.ravel()), np.sort(metres.ravel()), rtol=1e-12)
