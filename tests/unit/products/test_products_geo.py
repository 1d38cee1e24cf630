"""Geographic products (issue 18): navigation (best position per sample), landing sites in lat/lon with GeoJSON
footprints, the DTM as a Cloud-Optimized GeoTIFF in its own frame, cell for cell (issue 46), CF-DSG trajectory/profile files."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import xarray as xr
from pyproj import CRS, Geod, Transformer

from hadal.dive import LaserFrame
from hadal.geo import LocalFrame
from hadal.products import write_netcdf
from hadal.products.geo_landing import (
    footprint_corners,
    footprints_geojson,
    frame_to_lonlat,
    georeference_sites,
)
from hadal.products.navigation import navigation_table, trajectory_dataset

FRAME = LocalFrame(11.33, 142.20)
LAUNCH = (11.3371, 142.2097)  # lat, lon
GEOD = Geod(ellps="WGS84")


def _dive_table(n_desc=100, n_bot=50, n_asc=100):
    """A dive at 1 Hz: DR offsets (east = 1 m/s along the descent, 0 after), phases."""
    n = n_desc + n_bot + n_asc
    t = pd.date_range("2018-10-06T23:00:00", periods=n, freq="1s", tz="UTC")
    e = np.concatenate([np.arange(n_desc, dtype=float), np.full(n_bot + n_asc, float(n_desc - 1))])
    e[n_desc + n_bot:] += np.arange(n_asc) * 0.5
    nn = np.zeros(n)
    e[:3] = np.nan  # no DR before the first message
    nn[:3] = np.nan
    phase = ["descent"] * n_desc + ["bottom"] * n_bot + ["ascent"] * n_asc
    return pd.DataFrame({"time": t, "dr_east_m": e, "dr_north_m": nn, "depth_m": np.linspace(0, 5000, n),
                         "phase": phase})


def test_navigation_sources_and_the_adjustment_between_fixes():
    ctd = _dive_table()
    lx, ly = (float(v) for v in FRAME.to_xy(LAUNCH[1], LAUNCH[0]))
    bot = ctd[ctd.phase == "bottom"]
    # the match puts the bottom track 200 m north of dead reckoning
    matched = pd.DataFrame({"time": bot["time"], "x_east_m": lx + bot["dr_east_m"], "y_north_m": ly + 200.0})
    fix = {"uncertainty_m": {"radial": 12.0}}
    nav = navigation_table(ctd, FRAME, *LAUNCH, matched=matched, fix=fix, dr_error_fraction=0.01)
    src = nav["position_source"].astype(str)
    assert (src[:3] == "launch").all()
    assert (src[ctd.phase == "bottom"] == "matched").all()
    assert (src[3:100] == "dead_reckoned").all() and (src[150:] == "dead_reckoned").all()
    # descent: correction linear in time from 0 at the launch to +200 m north at the first matched sample
    dy = nav["y_north_m"].to_numpy() - ly
    assert dy[0] == pytest.approx(0.0, abs=1e-6)
    assert dy[50] == pytest.approx(200.0 * 50 / 100, rel=1e-6)
    # ascent keeps the last correction; x follows the DR offsets
    assert np.allclose(dy[150:], 200.0)
    assert nav["x_east_m"].iloc[-1] - lx == pytest.approx(99 + 99 * 0.5)
    # lat/lon are the map-frame positions projected (independent: pyproj with the frame's CRS)
    to_ll = Transformer.from_crs(FRAME.crs, CRS.from_epsg(4326), always_xy=True)
    lon, lat = to_ll.transform(nav["x_east_m"].to_numpy(), nav["y_north_m"].to_numpy())
    assert np.allclose(nav["lon"], lon, atol=1e-9) and np.allclose(nav["lat"], lat, atol=1e-9)
    # uncertainty: the fix's on the bottom, zero-growth at both ends of the descent, largest half-way
    u = nav["position_uncertainty_m"].to_numpy()
    assert np.allclose(u[100:150], 12.0)
    assert u[50] > u[10] and u[50] > u[95] and u[50] >= 0.5 * 200.0 * 0.99


def test_navigation_without_match_is_dead_reckoning_from_the_launch():
    ctd = _dive_table()
    nav = navigation_table(ctd, FRAME, *LAUNCH)
    az, _, dist = GEOD.inv(LAUNCH[1], LAUNCH[0], nav["lon"].iloc[99], nav["lat"].iloc[99])
    assert dist == pytest.approx(99.0, abs=0.01)  # DR offset 99 m east at sample 99
    assert az == pytest.approx(90.0, abs=0.05)
    assert set(nav["position_source"].astype(str)) == {"launch", "dead_reckoned"}


def test_navigation_trajectory_is_a_compliant_cf_dsg(tmp_path):
    pytest.importorskip("compliance_checker")
    from hadal.products.compliance import check_compliance

    ctd = _dive_table()
    ctd["temperature_its90_degc"] = np.linspace(20, 2, len(ctd))
    nav = navigation_table(ctd, FRAME, *LAUNCH)
    path = write_netcdf(trajectory_dataset(nav, ctd, "dive-7"), tmp_path / "navigation.nc", title="t", summary="s",
                        featureType="trajectory", cdm_data_type="Trajectory")
    rep = check_compliance(path)
    assert rep.ok, rep.describe()
    with xr.open_dataset(path) as ds:
        assert ds.attrs["featureType"] == "trajectory"
        assert ds["trajectory"].attrs["cf_role"] == "trajectory_id"
        assert set(ds["temperature_its90_degc"].encoding["coordinates"].split()) >= {"time", "lat", "lon", "depth_m"}


def test_profiles_are_cf_dsg_profiles(tmp_path):
    pytest.importorskip("compliance_checker")
    from hadal.products.compliance import check_compliance

    p = np.arange(5.0, 1000.0, 10.0)
    ds = xr.Dataset({"temperature_its90_degc": (("cast", "pressure_dbar"), np.ones((2, p.size)) * 3.0),
                     "time": ("cast", pd.to_datetime(["2018-10-06T23:00", "2018-10-07T08:00"]).to_numpy())},
                    coords={"pressure_dbar": p, "cast": ("cast", [0, 1], {"flag_values": [0, 1],
                                                                          "flag_meanings": "descent ascent"}),
                            "lat": 11.33, "lon": 142.2})
    path = write_netcdf(ds, tmp_path / "profile.nc", title="t", summary="s")
    rep = check_compliance(path)
    assert rep.ok, rep.describe()
    with xr.open_dataset(path) as out:  # two casts of a dive: a ragged trajectoryProfile (hadal.products.dsg)
        assert out.attrs["featureType"] == "trajectoryProfile"
        assert out["profile_id"].attrs["cf_role"] == "profile_id" and out["profile_id"].dims == ("profile",)
        assert out["lat"].dims == ("profile",) and out["time"].dims == ("profile",)
        assert int(out["row_size"].sum()) == out.sizes["obs"] == 2 * p.size


LF = LaserFrame(origin_latitude_deg=11.3371, origin_longitude_deg=142.2097, heading_deg=30.0)


def test_laser_frame_georeference_against_geodesics():
    # +y of the laser frame points 30 degrees east of north: (0, 100) is 100 m away at azimuth 30
    lon, lat = frame_to_lonlat([0.0, 100.0], [100.0, 0.0], LF)
    for k, want_az in ((0, 30.0), (1, 120.0)):
        az, _, dist = GEOD.inv(LF.origin_longitude_deg, LF.origin_latitude_deg, lon[k], lat[k])
        assert dist == pytest.approx(100.0, abs=0.01)
        assert (az % 360) == pytest.approx(want_az, abs=0.01)
    sites = pd.DataFrame({"x_m": [0.0], "y_m": [100.0], "heading_deg": [80.0]})
    g = georeference_sites(sites, LF)
    assert g["heading_true_deg"].iloc[0] == pytest.approx(110.0)
    assert georeference_sites(sites, None) is sites


def test_footprints_geojson_polygons_at_the_site_heading():
    sites = pd.DataFrame({"x_m": [10.0], "y_m": [5.0], "heading_deg": [80.0], "c_s": [0.6], "is_best": [True],
                          "submap": ["s1"]})
    gj = footprints_geojson(sites, LF, 1.7, 0.5)
    json.dumps(gj, allow_nan=False)
    ring = gj["features"][0]["geometry"]["coordinates"][0]
    assert ring[0] == ring[-1] and len(ring) == 5
    lons, lats = zip(*ring, strict=True)
    area, perim = GEOD.polygon_area_perimeter(lons, lats)
    assert area == pytest.approx(1.7 * 0.5, rel=1e-4)  # counter-clockwise (RFC 7946): positive area
    assert perim == pytest.approx(2 * (1.7 + 0.5), rel=1e-4)
    # the long side lies along the geographic heading 80 + 30
    az, _, d = GEOD.inv(lons[0], lats[0], lons[3], lats[3])
    long_side = (az % 180) if d > 1.0 else (GEOD.inv(lons[0], lats[0], lons[1], lats[1])[0] % 180)
    assert long_side == pytest.approx(110.0, abs=0.05)
    c = footprint_corners(0, 0, 0.0, 2.0, 1.0)
    assert np.allclose(sorted(c[:, 1]), [-1, -1, 1, 1]) and np.allclose(sorted(c[:, 0]), [-0.5, -0.5, 0.5, 0.5])
    assert footprints_geojson(sites, None, 1.7, 0.5) is None



def _pixel_lonlat(f, rows, cols):
    """Pixel centres of an open COG -> lon/lat with the CRS the file carries (pyproj from its WKT)."""
    import rasterio

    ex, ny = rasterio.transform.xy(f.transform, rows, cols)
    to_ll = Transformer.from_crs(CRS.from_wkt(f.crs.to_wkt()), CRS.from_epsg(4326), always_xy=True)
    return to_ll.transform(np.asarray(ex, float), np.asarray(ny, float))


def test_dtm_cog_is_the_grid_cell_for_cell_with_elevation_up(tmp_path):
    """The DTM COG is in the grid's own frame: every cell equals -depth of the NetCDF cell (float32), placed where
    geodesics from the frame origin put the cell centre (distance and azimuth, pyproj Geod: independent of the
    transverse Mercator formulae); uncertainty and count bands, band descriptions, units, nodata."""
    rasterio = pytest.importorskip("rasterio")
    pytest.importorskip("rio_cogeo")
    from rio_cogeo.cogeo import cog_validate

    from hadal.products.geotiff import NODATA, thumbnail_path, write_grid_cog

    x, y = np.arange(-2000.0, 2000.0, 20.0), np.arange(-1500.0, 1500.0, 20.0)
    X, Y = np.meshgrid(x, y)
    depth = 10000 + 0.05 * X - 0.02 * Y + 20 * np.sin(X / 300)
    depth[:10, :10] = np.nan
    depth[70, 100] = 10955.5  # the deepest cell: a warp would smooth it away
    unc = 2.0 + 0.001 * np.abs(X)
    cnt = (np.abs(X + Y) // 300).astype(np.int32)
    ds = xr.Dataset({"depth_m": (("y", "x"), depth, {"units": "m", "positive": "down", "long_name": "depth"}),
                     "uncertainty_m": (("y", "x"), unc, {"units": "m"}), "count": (("y", "x"), cnt),
                     "crs": ((), 0, {"crs_wkt": FRAME.crs.to_wkt()})}, coords={"x": x, "y": y})
    path = write_grid_cog(ds, tmp_path / "dtm.tif")
    ok, errors, _ = cog_validate(str(path), quiet=True)
    assert ok, errors
    assert thumbnail_path(path).is_file() and thumbnail_path(path).read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    with rasterio.open(path) as f:
        assert f.count == 3 and f.nodata == NODATA and f.units == ("m", "m", "1")
        assert [d.split(":")[0] for d in f.descriptions] == ["elevation", "uncertainty", "count"]
        assert "positive up" in f.descriptions[0] and f.tags(1)["positive"] == "up"
        assert f.res == (20.0, 20.0) and (f.width, f.height) == (x.size, y.size)
        assert CRS.from_wkt(f.crs.to_wkt()).equals(FRAME.crs, ignore_axis_order=True)
        el, u, n = f.read(1), f.read(2), f.read(3)
        rows, cols = np.meshgrid(np.arange(0, f.height, 7), np.arange(0, f.width, 11), indexing="ij")
        lon, lat = _pixel_lonlat(f, rows.ravel(), cols.ravel())
        st = f.tags(1)
    # north-up: COG row r is the NetCDF's row (ny - 1 - r)
    flip = depth[::-1]
    assert np.array_equal(el == NODATA, np.isnan(flip))
    ok = ~np.isnan(flip)
    assert np.array_equal(el[ok], (-flip[ok]).astype("float32"))
    assert np.array_equal(u, unc[::-1].astype("float32")) and np.array_equal(n, cnt[::-1].astype("float32"))
    assert el[el != NODATA].min() == pytest.approx(-10955.5, abs=1e-3)  # the extreme survives exactly
    assert float(st["STATISTICS_MINIMUM"]) == pytest.approx(-np.nanmax(depth), abs=1e-3)
    # placement: the cell centre (x, y) is at distance hypot(x, y) and azimuth atan2(x, y) from the origin
    cx, cy = x[cols.ravel()], y[::-1][rows.ravel()]
    az, _, dist = GEOD.inv(np.full(lon.size, FRAME.origin_longitude_deg), np.full(lat.size, FRAME.origin_latitude_deg),
                           lon, lat)
    far = dist > 1.0
    assert np.allclose(dist, np.hypot(cx, cy), atol=2e-3)
    assert np.allclose(np.radians(az[far]), np.arctan2(cx, cy)[far], atol=2e-6)


def test_dtm_bands_read_positive_by_metadata(tmp_path):
    from hadal.products.geotiff import dtm_bands

    z = np.full((3, 4), 100.0)
    mk = lambda attrs: xr.Dataset({"depth_m": (("y", "x"), z, attrs)}, coords={"x": np.arange(4.0), "y": np.arange(3.0)})  # noqa: E731
    assert dtm_bands(mk({"positive": "down"}))[0].values.max() == -100.0
    assert dtm_bands(mk({"positive": "up"}))[0].values.max() == 100.0
    assert dtm_bands(mk({"standard_name": "sea_floor_depth_below_sea_surface"}))[0].values.max() == -100.0
    with pytest.raises(ValueError, match="positive"):
        dtm_bands(mk({}))


def test_irregular_grid_is_refused(tmp_path):
    from hadal.products.geotiff import write_grid_cog

    x = np.array([0.0, 1.0, 2.5, 3.0])
    ds = xr.Dataset({"v": (("y", "x"), np.ones((2, 4)))}, coords={"x": x, "y": [0.0, 1.0]})
    with pytest.raises(ValueError, match="not regular"):
        write_grid_cog(ds, tmp_path / "v.tif", "v", frame=FRAME)

def test_suitability_cog_is_the_block_grid(tmp_path):
    """The suitability stage's COGs (its own build + write calls) hold its block values cell for cell, in the map
    frame (block centres placed by geodesics from the origin)."""
    rasterio = pytest.importorskip("rasterio")
    pytest.importorskip("rio_cogeo")
    from rio_cogeo.cogeo import cog_validate

    from hadal.products.geotiff import NODATA, write_grid_cog
    from hadal.settings import SuitabilityParams as Params
    from hadal.stages.suitability import COG_VARIABLES, build_suitability

    x, y = np.arange(-6000.0, 6000.0, 50.0), np.arange(-4000.0, 4000.0, 50.0)
    X, Y = np.meshgrid(x, y)
    rng = np.random.default_rng(3)
    depth = 10000 + 0.02 * X + 30 * np.sin(X / 700) * np.cos(Y / 900) + rng.normal(0, 2, X.shape)
    dtm = xr.Dataset({"depth_m": (("y", "x"), depth, {"units": "m", "positive": "down"}),
                      "crs": ((), 0, {"crs_wkt": FRAME.crs.to_wkt()})}, coords={"x": x, "y": y})
    suit = build_suitability(dtm, FRAME, 11.33, 142.20, Params())
    bx, by = suit["x"].values, suit["y"].values
    for v in COG_VARIABLES:
        path = write_grid_cog(suit, tmp_path / f"suitability_{v}.tif", v)
        assert cog_validate(str(path), quiet=True)[0]
        vals = suit[v].transpose("y", "x").values.astype(float)
        with rasterio.open(path) as f:
            band = f.read(1)
            lon, lat = _pixel_lonlat(f, [0, f.height - 1], [0, f.width - 1])
        want = vals[::-1] if by[1] > by[0] else vals
        assert np.array_equal(band == NODATA, np.isnan(want))
        assert np.allclose(band[band != NODATA], want[~np.isnan(want)], rtol=1e-6)
        cy = [by.max(), by.min()]
        _, _, dist = GEOD.inv([FRAME.origin_longitude_deg] * 2, [FRAME.origin_latitude_deg] * 2, lon, lat)
        assert np.allclose(dist, np.hypot([bx[0], bx[-1]], cy), atol=5e-3)


def test_laser_grid_cog_from_the_georeferenced_laser_frame(tmp_path):
    """A laser grid in its own frame, turned 35° and placed by dive.yaml laser_frame: the COG holds the grid's
    cells (rotated geotransform, no resampling) and each pixel centre lies where geodesics from the origin put the
    cell (distance and azimuth from the frame's +y axis, pyproj Geod). No vertical CRS is claimed."""
    rasterio = pytest.importorskip("rasterio")
    pytest.importorskip("rio_cogeo")
    from rio_cogeo.cogeo import cog_validate

    from hadal.products.geotiff import NODATA, write_grid_cog

    lf = LaserFrame(origin_latitude_deg=11.3371, origin_longitude_deg=142.2097, heading_deg=35.0)
    x, y = np.arange(0.0, 6.0, 0.02), np.arange(-2.0, 2.0, 0.02)
    X, Y = np.meshgrid(x, y)
    elev = -10900 + 0.3 * X - 0.1 * Y + 0.05 * np.sin(X * 3)
    elev[:5, :5] = np.nan
    cnt = np.where(np.isnan(elev), 0, 3)
    ds = xr.Dataset({"elevation_m": (("y", "x"), elev, {"units": "m", "positive": "up"}),
                     "count": (("y", "x"), cnt)}, coords={"x": x, "y": y})
    path = write_grid_cog(ds, tmp_path / "submap_00.tif", "elevation_m", laser_frame=lf)
    assert cog_validate(str(path), quiet=True)[0]
    with rasterio.open(path) as f:
        assert f.count == 2 and [d.split(":")[0] for d in f.descriptions] == ["elevation", "count"]
        assert not CRS.from_wkt(f.crs.to_wkt()).is_compound  # no vertical datum for relative elevations
        assert "5829" not in f.crs.to_wkt() and "5831" not in f.crs.to_wkt()
        band = f.read(1)
        rows, cols = np.meshgrid(np.arange(0, f.height, 9), np.arange(0, f.width, 13), indexing="ij")
        lon, lat = _pixel_lonlat(f, rows.ravel(), cols.ravel())
    flip = elev[::-1]
    assert np.array_equal(band == NODATA, np.isnan(flip))
    assert np.array_equal(band[band != NODATA], flip[~np.isnan(flip)].astype("float32"))
    az, _, dist = GEOD.inv(np.full(lon.size, lf.origin_longitude_deg), np.full(lat.size, lf.origin_latitude_deg),
                           lon, lat)
    rel = np.radians(np.asarray(az) - lf.heading_deg)  # azimuth from the frame's +y axis, clockwise
    fx, fy = dist * np.sin(rel), dist * np.cos(rel)
    assert np.allclose(fx, x[cols.ravel()], atol=1e-4) and np.allclose(fy, y[::-1][rows.ravel()], atol=1e-4)


def test_a_flagged_terrain_fix_is_not_a_smoother_measurement():
    """A terrain fix flagged as a possible mismatch (ambiguous, over holes, at the search edge) is refused by the
    navigation smoother by name: the smoothed track equals the one without a terrain fix, and an unflagged fix of
    the same position does pull the track (so the refusal is what changed it)."""
    from hadal.products.navigation import smoothed_navigation

    ctd = _dive_table()
    lx, ly = (float(v) for v in FRAME.to_xy(LAUNCH[1], LAUNCH[0]))
    bot = ctd[ctd.phase == "bottom"]
    matched = pd.DataFrame({"time": bot["time"], "x_east_m": lx + bot["dr_east_m"], "y_north_m": ly + 20.0})
    first = bot.index[0]
    fix = {"start": {"x_east_m": lx + float(bot["dr_east_m"].iloc[0]), "y_north_m": ly + 20.0},
           "uncertainty_m": {"covariance_m2": [[25.0, 0.0], [0.0, 25.0]]}, "mismatch": False}
    used, _, notes_used = smoothed_navigation(ctd, FRAME, *LAUNCH, matched=matched, fix=fix)
    flagged, _, notes_flagged = smoothed_navigation(ctd, FRAME, *LAUNCH, matched=matched,
                                                    fix={**fix, "mismatch": True})
    none, _, _ = smoothed_navigation(ctd, FRAME, *LAUNCH, matched=matched,
                                     fix={k: v for k, v in fix.items() if k != "uncertainty_m"})
    assert notes_used["terrain"].startswith("match fix.json")
    assert notes_flagged["terrain"].startswith("refused") and "mismatch" in notes_flagged["terrain"]
    assert np.allclose(flagged["y_north_m"], none["y_north_m"]) and np.allclose(flagged["x_east_m"], none["x_east_m"])
    assert abs(used["y_north_m"].iloc[first] - (ly + 20.0)) < abs(flagged["y_north_m"].iloc[first] - (ly + 20.0))
