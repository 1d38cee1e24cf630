"""The navigation product from the smoother (hadal.products.navigation.smoothed_navigation, issue 47): GNSS fixes
used only at the surface, an inconsistent USBL fix rejected and named, the covariance carried into the CF
trajectory. Oracles: pyproj's geodesic distance to the fixes written into the table, the written covariance
read back with netCDF4."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from hadal.geo import LocalFrame
from hadal.settings.navigation import SmootherOptions

FRAME = LocalFrame(11.33, 142.2)
LAUNCH = (11.33, 142.2)


def _ctd(n=400, dt=10.0):
    """A still vehicle (no DR), at the surface for the first and last 3 samples, 100 m deep in between."""
    depth = np.full(n, 100.0)
    depth[:3] = depth[-3:] = 0.5
    t = pd.Timestamp("2024-05-01", tz="UTC") + pd.to_timedelta(np.arange(n) * dt, unit="s")
    phase = np.where(np.arange(n) < n // 2, "descent", "ascent")
    return pd.DataFrame({"time": t, "depth_m": depth, "dr_east_m": 0.0, "dr_north_m": 0.0, "phase": phase})


def test_gnss_used_only_at_the_surface_and_the_track_follows_it():
    from pyproj import Geod

    from hadal.products.navigation import smoothed_navigation

    ctd = _ctd()
    n = len(ctd)
    lat, lon = np.full(n, np.nan), np.full(n, np.nan)
    lat[-1], lon[-1] = 11.335, 142.205  # recovery fix ~750 m from the launch
    lat[200], lon[200] = 11.40, 142.30  # a "fix" logged while 100 m deep: refused (no GNSS under water)
    ctd["gnss_latitude_deg"], ctd["gnss_longitude_deg"] = lat, lon
    ctd["gnss_east_variance_m2"] = ctd["gnss_north_variance_m2"] = 4.0
    nav, sm, notes = smoothed_navigation(ctd, FRAME, *LAUNCH, options=SmootherOptions())
    assert list(sm.fixes["source"]) == ["launch", "gnss"] and int(sm.fixes["index"].iloc[1]) == n - 1
    assert "refused" in notes["gnss"]
    g = Geod(ellps="WGS84")
    _, _, d_end = g.inv(nav["lon"].iloc[-1], nav["lat"].iloc[-1], 142.205, 11.335)
    _, _, d_start = g.inv(nav["lon"].iloc[0], nav["lat"].iloc[0], LAUNCH[1], LAUNCH[0])
    assert d_end < 2.0 and d_start < 2.0
    # uncertainty: smallest at the fixes, largest between them (a bridge), never below the fix's own
    u = nav["position_uncertainty_m"].to_numpy()
    assert u[-1] <= np.sqrt(8.0) + 1e-6 and u[n // 2] > 10 * u[-1]
    cov = nav[["position_covariance_east_m2", "position_covariance_north_m2"]].to_numpy()
    np.testing.assert_allclose(np.sqrt(cov.sum(axis=1)), u)


def test_inconsistent_usbl_fix_is_rejected_and_named(tmp_path):
    from hadal.products.navigation import smoothed_navigation, smoother_summary

    ctd = _ctd()
    n = len(ctd)
    lat, lon = np.full(n, np.nan), np.full(n, np.nan)
    lat[-1], lon[-1] = 11.331, 142.201  # recovery ~155 m from the launch
    ctd["gnss_latitude_deg"], ctd["gnss_longitude_deg"] = lat, lon
    ulat, ulon = np.full(n, np.nan), np.full(n, np.nan)
    for i in (120, 280):  # two USBL fixes on the way, consistent; one 3 km off
        ulat[i], ulon[i] = 11.33 + 0.001 * i / n, 142.2 + 0.001 * i / n
    ulat[200], ulon[200] = 11.36, 142.2005
    ctd["usbl_latitude_deg"], ctd["usbl_longitude_deg"] = ulat, ulon
    ctd["usbl_east_variance_m2"] = ctd["usbl_north_variance_m2"] = 400.0
    nav, sm, notes = smoothed_navigation(ctd, FRAME, *LAUNCH)
    s = smoother_summary(nav, sm, notes)
    assert s["rejected_fixes"] == ["usbl at sample 200"]
    bad = [f for f in s["fixes"] if f["status"] == "rejected"]
    assert len(bad) == 1 and bad[0]["chi2_2dof"] > sm.gate_d2
    assert all(f["chi2_2dof"] is None or f["chi2_2dof"] < sm.gate_d2 for f in s["fixes"] if f["status"] == "used")
    assert s["surfacing"]["ellipse_2sigma"]["semi_major_m"] > s["surfacing"]["ellipse_1sigma"]["semi_major_m"]
    # the rejected fix does not pull the track: the same track as without it
    ctd2 = ctd.copy()
    ctd2.loc[200, ["usbl_latitude_deg", "usbl_longitude_deg"]] = np.nan
    nav2, _, _ = smoothed_navigation(ctd2, FRAME, *LAUNCH)
    np.testing.assert_allclose(nav["x_east_m"], nav2["x_east_m"], atol=1e-6)


def test_covariance_in_the_cf_trajectory(tmp_path):
    netCDF4 = pytest.importorskip("netCDF4")
    from hadal.products.io import write_netcdf
    from hadal.products.navigation import smoothed_navigation, trajectory_dataset

    ctd = _ctd(n=50)
    nav, _, _ = smoothed_navigation(ctd, FRAME, *LAUNCH)
    path = write_netcdf(trajectory_dataset(nav, ctd, "dive-7"), tmp_path / "navigation.nc", title="t", summary="s",
                        featureType="trajectory", dive_id="dive-7")
    with netCDF4.Dataset(path) as ds:
        for c in ("position_covariance_east_m2", "position_covariance_north_m2", "position_covariance_east_north_m2"):
            v = ds.variables[c]
            assert v.units == "m2" and set(v.coordinates.split()) == {"time", "lat", "lon", "depth_m"}
            np.testing.assert_allclose(v[:], nav[c].to_numpy())
