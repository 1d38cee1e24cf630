"""ERDDAP/IOOS-ready DSG files (issue 46), read back with netCDF4 (a peer reader of xarray's writer):

* binned casts are a CF-1.8 contiguous ragged array: ``row_size`` sums to the ``obs`` dimension and each row
  holds exactly the cast's non-empty bins of ``make_profile`` (the oracle: its (cast, level) dataset); the ids are
  NC_CHAR with ``cf_role``; depth is the Z axis (``axis: Z``, positive down, m); ERDDAP's ``cdm_*`` attributes
  name the variables holding the ``cf_role``;
* casts are placed at their time on the ctd table's track (the ascent where the vehicle surfaced, not the launch);
* float32 where ``schemas/variables.yaml`` declares a precision float32 keeps (grids in m at cm precision),
  float64 kept where it does not (positions);
* laser grids: ACDD bounds are the mapped footprint turned by ``laser_frame`` (geodesic oracle: pyproj.Geod),
  no vertical datum for relative elevations.
"""

from __future__ import annotations

import netCDF4
import numpy as np
import pandas as pd
import pytest
import xarray as xr
from pyproj import Geod

from hadal.ctd.profile import make_profile
from hadal.dive import Dive, LaserFrame
from hadal.geo import LocalFrame
from hadal.products import dive_attributes, missing_acdd_fields, write_netcdf
from hadal.products.dsg import id_values, orthogonal_profile, place_casts
from hadal.products.navigation import dead_reckoned_lonlat, navigation_table, trajectory_dataset

FRAME = LocalFrame(11.33, 142.20)
LAUNCH = (11.3371, 142.2097)
GEOD = Geod(ellps="WGS84")


def _dive(**kw) -> Dive:
    return Dive(dive_id="dive-7", platform="Haidou",
                launch={"latitude_deg": LAUNCH[0], "longitude_deg": LAUNCH[1], "time_utc": "2018-10-06T23:00:00Z"},
                **kw)


def _path(tmp_path, product, name):
    d = tmp_path / "store" / "dive-7" / product / "v001"
    d.mkdir(parents=True)
    return d / name


def _ctd(n_desc=600, n_asc=400):
    """Descent to 1200 dbar and a shorter ascent, drifting east 0.8 m/s by dead reckoning (1.0 km at the surface)."""
    p = np.concatenate([np.linspace(2, 1200, n_desc), np.linspace(1200, 2, n_asc)])
    t = pd.date_range("2018-10-06T23:00:00", periods=p.size, freq="1s", tz="UTC")
    e = np.cumsum(np.full(p.size, 1.0))
    df = pd.DataFrame({"time": t, "pressure_dbar": p, "depth_m": p * 0.993,
                       "temperature_its90_degc": 2 + 20 * np.exp(-p / 300), "practical_salinity": 34.6 + p * 1e-5,
                       "dr_east_m": e, "dr_north_m": 0.0 * e,
                       "phase": ["descent"] * n_desc + ["ascent"] * n_asc})
    df["lat"], df["lon"] = dead_reckoned_lonlat(df, FRAME, *LAUNCH)
    return df


def test_profile_is_a_contiguous_ragged_array_read_back_with_netcdf4(tmp_path):
    ctd = _ctd()
    prof = make_profile(ctd, 10.0, latitude_deg=LAUNCH[0])
    path = write_netcdf(place_casts(prof, ctd), _path(tmp_path, "profile", "profile.nc"), title="t", summary="s",
                        **dive_attributes(_dive()))
    with netCDF4.Dataset(path) as nc:
        nc.set_auto_mask(False)
        n_obs = len(nc.dimensions["obs"])
        rows = nc["row_size"][:]
        assert nc["row_size"].sample_dimension == "obs" and int(rows.sum()) == n_obs
        assert len(nc.dimensions["profile"]) == 2 and len(nc.dimensions["trajectory"]) == 1
        # char ids (NC_CHAR, not NC_STRING) with cf_role; the dive as the trajectory of both casts
        pid = nc["profile_id"]
        assert pid.dtype == np.dtype("S1") and pid.dimensions == ("profile", "profile_strlen")
        assert pid.cf_role == "profile_id"
        assert [b"".join(r).decode() for r in pid[:]] == ["dive-7_descent", "dive-7_ascent"]
        assert nc["trajectory"].dtype == np.dtype("S1") and nc["trajectory"].cf_role == "trajectory_id"
        assert nc["trajectory_index"].instance_dimension == "trajectory"
        # depth is the Z axis
        z = nc["depth_m"]
        assert (z.axis, z.positive, z.units, z.standard_name) == ("Z", "down", "m", "depth")
        assert z.dimensions == ("obs",) and "axis" not in nc["pressure_dbar"].ncattrs()
        # ERDDAP: the cdm_* attributes name the cf_role variables and the per-profile ones
        assert nc.featureType == "trajectoryProfile" and nc.cdm_data_type == "TrajectoryProfile"
        assert nc.cdm_trajectory_variables == "trajectory"
        assert nc.cdm_profile_variables.split(",") == ["profile_id", "time", "lat", "lon"]
        for v in nc.subsetVariables.split(","):
            assert nc[v].dimensions[0] in ("profile", "trajectory")
        # each row: that cast's non-empty bins of make_profile, in order (oracle: the (cast, level) dataset)
        start = 0
        for k, r in enumerate(rows):
            keep = prof["count"].values[k] > 0
            assert r == keep.sum()
            np.testing.assert_allclose(nc["pressure_dbar"][start:start + r], prof["pressure_dbar"].values[keep])
            np.testing.assert_allclose(nc["temperature_its90_degc"][start:start + r],
                                       prof["temperature_its90_degc"].values[k, keep], atol=5e-5)
            np.testing.assert_allclose(nc["depth_m"][start:start + r], prof["depth_m"].values[k, keep], atol=5e-3)
            start += r
        # casts at their surface end on the track (oracle: the ctd table's own columns)
        np.testing.assert_allclose(nc["lat"][:], [ctd["lat"].iloc[0], ctd["lat"].iloc[-1]])
        np.testing.assert_allclose(nc["lon"][:], [ctd["lon"].iloc[0], ctd["lon"].iloc[-1]])
        _, _, d = GEOD.inv(nc["lon"][0], nc["lat"][0], nc["lon"][1], nc["lat"][1])
        assert d == pytest.approx(999.0, abs=1.0)  # the ascent surfaced 1 km from the launch
        times = netCDF4.num2date(nc["time"][:], nc["time"].units)
        assert [str(t)[:19] for t in times] == ["2018-10-06 23:00:00", str(ctd["time"].iloc[-1])[:19]]
        # float32 where the registry's precision allows, float64 for positions
        assert nc["temperature_its90_degc"].dtype == np.float32 and nc["lat"].dtype == np.float64
    # the report's reader gets the (cast, level) layout back
    with xr.open_dataset(path) as ds:
        back = orthogonal_profile(ds.load())
    assert list(back["cast"].values) == ["descent", "ascent"]
    np.testing.assert_allclose(back["temperature_its90_degc"].values, prof["temperature_its90_degc"].values,
                               atol=5e-5)


def test_one_cast_is_a_profile_and_a_scalar_position_is_said_to_be_the_header(tmp_path):
    ctd = _ctd().assign(phase="descent")
    prof = make_profile(ctd, 10.0, latitude_deg=LAUNCH[0], casts=("descent",))
    prof.coords["lat"], prof.coords["lon"] = 11.5, 142.5  # a header position (no per-sample navigation)
    path = write_netcdf(prof, _path(tmp_path, "cast_profiles", "cast01.nc"), title="t", summary="s",
                        **dive_attributes(_dive()))
    with netCDF4.Dataset(path) as nc:
        assert nc.featureType == "profile" and nc.cdm_data_type == "Profile" and "trajectory" not in nc.variables
        assert len(nc.dimensions["profile"]) == 1 and int(nc["row_size"][0]) == len(nc.dimensions["obs"])
        assert nc["lat"][:].tolist() == [11.5] and "header/launch" in nc["lat"].comment


def test_navigation_trajectory_id_is_nc_char(tmp_path):
    ctd = _ctd(100, 100)
    path = write_netcdf(trajectory_dataset(navigation_table(ctd, FRAME, *LAUNCH), ctd, "dive-7"),
                        _path(tmp_path, "navigation", "navigation.nc"), title="t", summary="s",
                        featureType="trajectory", **dive_attributes(_dive()))
    with netCDF4.Dataset(path) as nc:
        v = nc["trajectory"]
        assert v.dtype == np.dtype("S1") and v.dimensions == ("traj", "traj_strlen") and v.cf_role == "trajectory_id"
        assert int(nc["row_size"][0]) == len(nc.dimensions["obs"])
        assert nc.cdm_data_type == "Trajectory" and nc.cdm_trajectory_variables == "trajectory"
        assert nc["x_east_m"].dtype == np.float32 and nc["lat"].dtype == np.float64
    with xr.open_dataset(path) as ds:
        assert id_values(ds["trajectory"]) == ["dive-7"]


def test_grid_float32_within_the_declared_precision(tmp_path):
    x, y = np.arange(0.0, 2000.0, 20.0), np.arange(0.0, 1000.0, 20.0)
    X, Y = np.meshgrid(x, y)
    depth = 10900.0 + X / 37.0 + np.sin(Y / 50.0) * 13.3  # ~11 km: float32 spacing 1/1024 m
    lon, lat = FRAME.to_lonlat(X, Y)
    far = np.full(X.shape, 3.0e7)  # a value float32 cannot hold at 1 cm: stays float64
    ds = xr.Dataset({"depth_m": (("y", "x"), depth), "uncertainty_m": (("y", "x"), far),
                     "lat": (("y", "x"), lat), "lon": (("y", "x"), lon),
                     "crs": ((), 0, {"crs_wkt": FRAME.crs.to_wkt()})}, coords={"x": x, "y": y})
    path = write_netcdf(ds, _path(tmp_path, "dtm", "dtm.nc"), title="t", summary="s", **dive_attributes(_dive()))
    with netCDF4.Dataset(path) as nc:
        assert nc["depth_m"].dtype == np.float32 and nc["uncertainty_m"].dtype == np.float64
        assert nc["lat"].dtype == np.float64 and nc["x"].dtype == np.float64
        assert np.abs(nc["depth_m"][:].astype(float) - depth).max() <= 0.005  # half the registry's 0.01 m
        np.testing.assert_array_equal(nc["lat"][:], lat)
        assert "featureType" not in nc.ncattrs() and nc.cdm_data_type == "Grid"
        assert nc.geospatial_bounds_vertical_crs == "EPSG:5831"  # a depth below the sea surface


def test_laser_grid_footprint_is_the_turned_mapped_rectangle(tmp_path):
    lf = LaserFrame(origin_latitude_deg=LAUNCH[0], origin_longitude_deg=LAUNCH[1], heading_deg=30.0)
    x, y = np.arange(0.005, 5.0, 0.01), np.arange(-1.0, 1.0, 0.01) + 0.005
    elev = np.full((y.size, x.size), -0.2)
    elev[:, x > 4.0] = np.nan  # the last metre unmapped: the footprint is 4 m x 2 m
    ds = xr.Dataset({"elevation_m": (("y", "x"), elev)}, coords={"x": x, "y": y})
    path = write_netcdf(ds, _path(tmp_path, "laser_grids", "submap_01.nc"), title="t", summary="s",
                        **dive_attributes(_dive(laser_frame=lf)))
    with netCDF4.Dataset(path) as nc:
        attrs = {k: nc.getncattr(k) for k in nc.ncattrs()}
    assert "geospatial_bounds_vertical_crs" not in attrs and "geospatial_vertical_min" not in attrs
    ring = [tuple(map(float, p.split())) for p in attrs["geospatial_bounds"][10:-2].split(", ")]
    assert len(ring) == 5 and ring[0] == ring[-1]
    (la0, lo0), (la1, lo1), (la2, lo2) = ring[0], ring[1], ring[2]
    az01, _, d01 = GEOD.inv(lo0, la0, lo1, la1)  # along x (4.00 m), x turned to azimuth 120 deg
    az12, _, d12 = GEOD.inv(lo1, la1, lo2, la2)  # along y (2.00 m), y at the heading 30 deg
    assert d01 == pytest.approx(4.0, abs=0.01) and d12 == pytest.approx(2.0, abs=0.01)
    assert az01 == pytest.approx(120.0, abs=0.1) and az12 == pytest.approx(30.0, abs=0.1)
    lats, lons = [p[0] for p in ring], [p[1] for p in ring]
    assert attrs["geospatial_lat_min"] == pytest.approx(min(lats)) and attrs["geospatial_lon_max"] == pytest.approx(
        max(lons))
    _, _, d_launch = GEOD.inv(LAUNCH[1], LAUNCH[0], lo0, la0)  # the footprint starts at the frame's origin
    assert d_launch == pytest.approx(np.hypot(0.0, 1.0), abs=0.01)


def test_config_check_names_every_ioos_required_operator_field(monkeypatch):
    """Oracle: the IOOS-1.2 checker's own list of required global attributes (compliance_checker.ioos), less
    what hadal writes itself or derives (creator_institution from institution, publisher_* from the creator)."""
    ioos = pytest.importorskip("compliance_checker.ioos")
    req = [a[0] if isinstance(a, tuple) else a for a in ioos.IOOS1_2Check().required_atts]
    from hadal.products.metadata import OPERATOR_FIELDS

    for k in OPERATOR_FIELDS:
        monkeypatch.delenv(f"HADAL_{k.upper()}", raising=False)
    hadal_writes = {"Conventions", "featureType", "id", "platform_name", "standard_name_vocabulary", "summary",
                    "title", "creator_institution", "publisher_country", "publisher_email", "publisher_institution",
                    "publisher_url", "publisher_name"}
    missing = set(missing_acdd_fields(_dive()))
    assert {a for a in req if a not in hadal_writes} <= missing, sorted(set(req) - hadal_writes - missing)


def test_navigation_summary_gives_the_surfacing_position():
    """The manifest's surfacing position: the last sample's best position (here dead reckoning 1 m/s east for
    1000 s: 1000 m east of the launch by geodesic, azimuth 90 deg), with its uncertainty and source."""
    from hadal.products.navigation import navigation_summary

    ctd = _ctd()
    nav = navigation_table(ctd, FRAME, *LAUNCH)
    s = navigation_summary(nav)["surfacing"]
    az, _, d = GEOD.inv(LAUNCH[1], LAUNCH[0], s["longitude_deg"], s["latitude_deg"])
    assert d == pytest.approx(1000.0, abs=0.5) and az == pytest.approx(90.0, abs=0.2)
    assert s["source"] == "dead_reckoned" and s["uncertainty_m"] > 0
    assert s["time_utc"].startswith(str(ctd["time"].iloc[-1].isoformat())[:19])
