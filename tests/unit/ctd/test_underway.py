"""Underway records (hadal.ctd.underway: the rule, positions by time) and SeaSoft-binned casts (hadal.ctd.profile:
source_bins, prebinned_phases, prebinned_profile), on constructed records whose answer is known by construction.
The real files are tested in tests/realdata/test_real_dives.py (the file's own columns as the oracle)."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import yaml

from hadal.ctd.profile import prebinned_phases, prebinned_profile, source_bins
from hadal.ctd.underway import MIN_TRACK_M, distance_m, positions_at, underway_evidence


def _record(lat, lon, pressure=None, instrument="* Sea-Bird SBE 21 Data File:") -> pd.DataFrame:
    df = pd.DataFrame({"timeJ": np.arange(len(lat)) / 86400.0 + 236.0, "latitude": lat, "longitude": lon,
                       "t090C": np.full(len(lat), 27.0), "c0S/m": np.full(len(lat), 5.7)})
    if pressure is not None:
        df["prM"] = pressure
    df.attrs["instrument"] = instrument
    return df


def test_distance_is_the_mean_sphere_great_circle():
    # 1 degree of latitude on the mean sphere (R = 6371.0088 km) is 111.195 km
    assert distance_m(0.0, 0.0, np.array([1.0]), np.array([0.0]))[0] == pytest.approx(111_195.08, abs=1.0)
    assert distance_m(60.0, 10.0, np.array([60.0]), np.array([11.0]))[0] == pytest.approx(55_597.5, rel=1e-3)


def test_a_moving_record_at_constant_pressure_is_underway():
    lat = np.linspace(-0.863, -0.739, 50)  # 13.8 km north
    ev = underway_evidence(_record(lat, np.full(50, -38.0), np.zeros(50)))
    assert ev.underway and ev.max_distance_m == pytest.approx(13_788, rel=1e-3)
    assert ev.instrument_model == "SBE 21" and "thermosalinograph" in ev.reason
    assert underway_evidence(_record(lat, np.full(50, -38.0))).underway  # no pressure channel at all


def test_casts_are_not_underway():
    lat = np.linspace(10.0, 10.01, 50)  # drifts 1.1 km
    profiling = _record(lat, np.full(50, 140.0), np.linspace(0, 1000, 50), "* Sea-Bird SBE 9 Data File:")
    ev = underway_evidence(profiling)
    assert not ev.underway and "(> 2 dbar)" in ev.reason and ev.pressure_range_dbar > 900
    on_station = _record(10.0 + np.linspace(0, 0.5 * MIN_TRACK_M / 111_195.0, 50), np.full(50, 140.0), np.zeros(50))
    assert not underway_evidence(on_station).underway
    no_positions = _record(lat, np.full(50, 140.0), np.zeros(50)).drop(columns=["latitude", "longitude"])
    assert not underway_evidence(no_positions).underway
    bad = _record(np.full(50, np.nan), np.full(50, np.nan), np.zeros(50))
    assert not underway_evidence(bad).underway


def test_positions_at_matches_scan_times_exactly():
    scan_t = np.array([30, 10, 20], dtype=np.int64)
    lat, lon = np.array([3.0, 1.0, 2.0]), np.array([-3.0, -1.0, -2.0])
    got_lat, got_lon = positions_at(np.array([10, 20, 25, 30]), scan_t, lat, lon)
    np.testing.assert_array_equal(got_lat[[0, 1, 3]], [1.0, 2.0, 3.0])
    np.testing.assert_array_equal(got_lon[[0, 1, 3]], [-1.0, -2.0, -3.0])
    assert np.isnan(got_lat[2]) and np.isnan(got_lon[2])


def test_source_bins_read_from_the_header():
    meta = {"processing": [["binavg_bintype", "decibars"], ["binavg_binsize", "2"]],
            "interval": {"kind": "decibars", "value": 2.0}}
    assert source_bins(meta)["axis"] == "pressure" and source_bins(meta)["bin_size"] == 2.0
    assert source_bins({"processing": [], "interval": {"kind": "decibars", "value": 1.0}})["bin_size"] == 1.0
    depth = source_bins({"processing": [["binavg_bintype", "meters"], ["binavg_binsize", "0.5"]]})
    assert depth["axis"] == "depth" and depth["units"] == "m" and depth["bin_size"] == 0.5
    assert source_bins({"processing": [["binavg_bintype", "scans"], ["binavg_binsize", "24"]],
                        "interval": {"kind": "seconds", "value": 1.0}}) is None  # a time average, not a profile
    assert source_bins({"interval": {"kind": "seconds", "value": 0.25}}) is None
    assert source_bins(None) is None


def test_prebinned_phases_split_at_the_deepest_row():
    assert list(prebinned_phases([2, 4, 6, 4, 2])) == ["descent"] * 3 + ["ascent"] * 2
    assert list(prebinned_phases([2, 3, 4])) == ["descent"] * 3
    assert list(prebinned_phases([6, 4, 2])) == ["ascent"] * 3


def test_prebinned_profile_keeps_each_row_as_its_bin():
    p = np.array([2.08, 3.99, 6.01, 7.9, 6.07, 4.02])
    t = np.array([26.0, 25.0, 24.0, 23.0, 24.5, 25.5])
    df = pd.DataFrame({"pressure_dbar": p, "temperature_its90_degc": t, "phase": prebinned_phases(p)})
    bins = source_bins({"processing": [["binavg_bintype", "decibars"], ["binavg_binsize", "2"]]})
    ds = prebinned_profile(df, bins)
    np.testing.assert_array_equal(ds["pressure_dbar"].values, [2.0, 4.0, 6.0, 8.0])
    assert list(ds["cast"].values) == ["descent", "ascent"]
    np.testing.assert_array_equal(ds["temperature_its90_degc"].values[0], [26.0, 25.0, 24.0, 23.0])
    np.testing.assert_array_equal(ds["temperature_its90_degc"].values[1, :3], [np.nan, 25.5, 24.5])
    np.testing.assert_array_equal(ds["count"].values, [[1, 1, 1, 1], [0, 1, 1, 0]])
    assert ds.attrs["bin_size_dbar"] == 2.0 and "not re-binned" in ds["pressure_dbar"].attrs["comment"]
    one = prebinned_profile(df.iloc[:4].assign(phase=prebinned_phases(p[:4])), bins)
    assert list(one["cast"].values) == ["descent"]  # no empty ascent


def _dive(cnv):
    from hadal.dive import Dive

    return Dive.model_validate({"dive_id": "d", "sources": {"cnv": cnv}})


def test_plan_promises_a_trajectory_instead_of_a_profile_for_an_underway_only_dive():
    from hadal.stages.plan import plan_stages

    plan = plan_stages(_dive([{"path": "tsg.cnv", "kind": "underway"}]))
    made = {ps.name: set(ps.products) for ps in plan}
    assert made["derive"] == {"trajectory"}
    prof = next(ps for ps in plan if ps.name == "profile")
    assert not prof.run  # no ctd to bin (the profile stage), and the reason says why, not "run derive first"
    assert "stage derive makes trajectory for this dive, not ctd" in prof.reason and "first" not in prof.reason
    mixed = {ps.name: set(ps.products) for ps in plan_stages(_dive([{"path": "tsg.cnv", "kind": "underway"},
                                                                     "cast.cnv"]))}
    assert {"ctd", "trajectory"} <= mixed["derive"] and mixed["profile"] == {"profile"}
    plain = {ps.name: set(ps.products) for ps in plan_stages(_dive(["cast.cnv"]))}
    assert plain["derive"] == {"ctd"} and plain["profile"] == {"profile"}


def test_init_writes_the_choice_as_an_explicit_commented_entry(tmp_path):
    from hadal.dive_init import InitResult, render_dive_yaml

    res = InitResult(tmp_path, {"dive_id": "d", "sources": {"cnv": ["cast.cnv", {"path": "tsg.cnv",
                                                                                  "kind": "underway"}]}})
    res.source_notes["tsg.cnv"] = "kind: underway, hadal init's choice (evidence)"
    text = render_dive_yaml(res)
    lines = text.splitlines()
    i = lines.index("  - path: tsg.cnv")
    assert lines[i - 1] == "  # kind: underway, hadal init's choice (evidence)"
    assert yaml.safe_load(text)["sources"]["cnv"] == ["cast.cnv", {"path": "tsg.cnv", "kind": "underway"}]


def test_pressure_spikes_do_not_make_a_tsg_a_cast():
    lat = np.linspace(-0.863, -0.739, 500)
    pr = np.full(500, 3.0)
    pr[[10, 200]] = [40.0, -5.0]  # two spikes of the intake pressure sensor
    assert underway_evidence(_record(lat, np.full(500, -38.0), pr)).underway
