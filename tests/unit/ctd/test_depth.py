"""hadal.depth: hydrostatic depth (Eqs. 11-12) against a TEOS-10 water column, pressure fusion, altitude, phases."""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from hadal import seawater as sw
from hadal.depth import (
    correct_altitude,
    depth_teos10,
    dynamic_height_anomaly,
    fuse_pressure,
    hydrostatic_depth,
    segment_phases,
)
from hadal.errors import InputError

gsw = pytest.importorskip("gsw")

LAT, LON = 11.33, 142.2


def teos10_column(zmax=11_000.0, dz=1.0, lat=LAT, lon=LON):
    """A Challenger-Deep-like column: true depth d (m) -> pressure from ``gsw.p_from_z`` with the dynamic
    height anomaly of its own T/S profile (how the sample dive's pressure is generated), SP, in situ t90."""
    d = np.arange(0.0, zmax + dz / 2, dz)
    t = 1.5 + 27.5 * np.exp(-d / 400.0) + 1.0e-4 * np.maximum(d - 4000.0, 0.0)
    sp = 34.7 - 0.5 * np.exp(-d / 300.0)
    p = gsw.p_from_z(-d, lat)
    for _ in range(3):
        sa = gsw.SA_from_SP(sp, p, lon, lat)
        ct = gsw.CT_from_t(sa, t, p)
        p = gsw.p_from_z(-d, lat, geo_strf_dyn_height=gsw.geo_strf_dyn_height(sa, ct, p, p_ref=0))
    return d, p, sp, t


@pytest.fixture(scope="module")
def column():
    return teos10_column()


@pytest.mark.parametrize("integration", ["trapezoid", "rectangle"])
def test_recovers_true_depth_within_1m_at_10900m(column, integration):
    d, p, sp, t = column
    h = hydrostatic_depth(p, sp, t, LAT, integration=integration)
    i = np.searchsorted(d, 10_900.0)
    assert p[i] > 11_200  # full ocean depth
    assert abs(h[i] - d[i]) < 1.0
    assert np.max(np.abs(h - d)) < 1.0
    # Fofonoff-Millard (standard ocean, column-mean gravity) is several metres off at this depth
    fm = sw.depth_fofonoff_millard(p, LAT)
    assert abs(fm[i] - d[i]) > 5.0


def test_paper_printed_gravity_sign_would_cost_metres(column):
    """Eq. (14) as printed, (1 - C3 H), makes g decrease with depth: ~13 m too deep at 10 900 m."""
    d, p, sp, t = column
    rho = sw.density_eos80(sp, t, p)
    g_wrong = sw.gravity(LAT, 0.0) * (1.0 - 2.26e-7 * d)  # evaluated on the true depth
    h_wrong = np.cumsum(np.diff(p, prepend=0.0) * 1e4 / (rho * g_wrong))
    i = np.searchsorted(d, 10_900.0)
    assert h_wrong[i] - d[i] > 10.0
    h = hydrostatic_depth(p, sp, t, LAT)
    assert abs(h[i] - d[i]) < 1.0


def test_fixed_point_equals_sequential_eq12():
    """The vectorised fixed point reproduces the literal sequential recursion of Eq. (12)."""
    d, p, sp, t = teos10_column(zmax=6000.0, dz=50.0)
    rho = sw.density_eos80(sp, t, p)
    h_seq = np.empty_like(p)
    depth, prev = 0.0, 0.0
    for i in range(p.size):
        depth += (p[i] - prev) * 1e4 / (rho[i] * sw.gravity(LAT, depth))
        prev = p[i]
        h_seq[i] = depth
    np.testing.assert_allclose(hydrostatic_depth(p, sp, t, LAT, integration="rectangle"), h_seq, atol=1e-8)


def test_trapezoid_beats_rectangle_on_sparse_profiles(column):
    d, p, sp, t = column
    sel = slice(0, None, 10)  # 10 m spacing
    e_trap = hydrostatic_depth(p[sel], sp[sel], t[sel], LAT, integration="trapezoid")[-1] - d[sel][-1]
    e_rect = hydrostatic_depth(p[sel], sp[sel], t[sel], LAT, integration="rectangle")[-1] - d[sel][-1]
    e_dense = hydrostatic_depth(p, sp, t, LAT)[-1] - d[-1]
    assert abs(e_trap - e_dense) < 0.01
    assert e_rect < e_trap - 0.1  # the rectangle rule is biased shallow (rho of the deeper end)


def test_surface_offset_of_first_sample():
    """A series that starts at 100 dbar gives the same depths as one starting at the surface when the water
    above the first sample has its density (h_0 = p_0 / (rho_0 g_0)); g(0) over the first 100 m costs < 2 mm."""
    p = np.arange(0.0, 1000.1, 1.0)
    full = hydrostatic_depth(p, 35.0, 2.0, LAT, density_kg_m3=1030.0)
    part = hydrostatic_depth(p[100:], 35.0, 2.0, LAT, density_kg_m3=1030.0)
    np.testing.assert_allclose(part, full[100:], atol=2e-3)
    rect = hydrostatic_depth(p[100:], 35.0, 2.0, LAT, density_kg_m3=1030.0, integration="rectangle")
    assert rect[0] == pytest.approx(100e4 / (1030.0 * sw.gravity(LAT, 0.0)), rel=1e-12)
    assert part[0] == pytest.approx(rect[0], rel=2e-5)  # trapezoid: g averaged over the first 100 m
    # with EOS-80 density the offset uses rho(first sample): 100 m * (rho(100) - rho(0..100))/rho ~ 2 cm
    real = hydrostatic_depth(p[100:], 35.0, 2.0, LAT, integration="rectangle")
    assert real[0] == pytest.approx(100e4 / (sw.density_eos80(35, 2, 100) * sw.gravity(LAT, 0.0)), rel=1e-12)


def test_non_monotonic_pressure_telescopes():
    """Down, up and down again through the same water: the depth at a pressure does not depend on the path."""
    down = np.arange(0.0, 2000.0, 0.5)
    p = np.concatenate([down, down[::-1][1:1000], down[-1000:]])
    h = hydrostatic_depth(p, 35.0, 2.0, LAT)
    first = h[down.size - 1]
    assert h[-1] == pytest.approx(first, abs=1e-6)
    pref = hydrostatic_depth(down, 35.0, 2.0, LAT)
    j = down.size + 998  # bottom of the "up" leg
    assert h[j] == pytest.approx(pref[np.searchsorted(down, p[j])], abs=1e-6)


def test_nan_pressure_skipped_and_nan_density_interpolated():
    p = np.arange(0.0, 3000.0, 2.0)
    sp = np.full_like(p, 34.7)
    t = np.full_like(p, 2.0)
    ref = hydrostatic_depth(p, sp, t, LAT)
    p2 = p.copy()
    p2[[10, 500, 501]] = np.nan
    h2 = hydrostatic_depth(p2, sp, t, LAT)
    assert np.isnan(h2[[10, 500, 501]]).all()
    ok = np.isfinite(p2)
    np.testing.assert_allclose(h2[ok], ref[ok], atol=1e-6)
    sp2 = sp.copy()
    sp2[200:300] = np.nan  # a 200 dbar conductivity dropout: density interpolated linearly across it
    np.testing.assert_allclose(hydrostatic_depth(p, sp2, t, LAT), ref, atol=1e-3)
    assert np.isnan(hydrostatic_depth(np.full(5, np.nan), 35.0, 2.0, LAT)).all()
    with pytest.raises(InputError, match="no valid density"):
        hydrostatic_depth(p, np.nan, 2.0, LAT)


def test_teos10_depth_with_dynamic_height_matches_truth(column):
    d, p, sp, t = column
    sel = slice(0, None, 10)
    pp, psi = dynamic_height_anomaly(p[sel], sp[sel], t[sel], LON, LAT)
    z = depth_teos10(p, LAT, pp, psi)
    assert np.max(np.abs(z - d)) < 0.05
    # without the profile (standard ocean), TEOS-10 is off by metres like F-M
    assert abs(depth_teos10(p[-1:], LAT)[0] - d[-1]) > 3.0


def test_fuse_pressure_bias_and_saturation():
    rng = np.random.default_rng(3)
    truth = np.linspace(0, 11_000, 20_000)
    ctd = np.minimum(truth - 0.8 + rng.normal(0, 0.05, truth.size), 10_500.0)  # SBE49: offset, saturates
    gauge = truth + 0.5 + rng.normal(0, 0.3, truth.size)  # Keller: the more accurate datum
    f = fuse_pressure(ctd, gauge)
    assert f.gauge_bias_dbar == pytest.approx(1.3, abs=0.03)
    assert f.bias_samples > 1000
    deep = truth > 10_500
    assert set(f.source[deep]) == {"gauge"} and f.source[0] == "ctd"
    # default: the gauge's datum everywhere (CTD + bias, then gauge): continuous across the switch
    err = f.pressure_dbar - truth
    assert abs(np.median(err[~deep]) - 0.5) < 0.03 and abs(np.median(err[deep]) - 0.5) < 0.05
    # the CTD's datum: gauge - bias where the CTD saturates
    fc = fuse_pressure(ctd, gauge, datum="ctd")
    err = fc.pressure_dbar - truth
    assert abs(np.median(err[~deep]) + 0.8) < 0.03 and abs(np.median(err[deep]) + 0.8) < 0.05
    # flagged-bad CTD samples are replaced too; no gauge at all: NaN where the CTD saturates
    ok = np.ones(truth.size, bool)
    ok[:100] = False
    f2 = fuse_pressure(ctd, np.full_like(ctd, np.nan), ctd_ok=ok)
    assert np.isnan(f2.pressure_dbar[:100]).all() and np.isnan(f2.pressure_dbar[deep]).all()
    assert f2.gauge_bias_dbar == 0.0 and set(f2.source[:100]) == {""}
    use = ok & (ctd < 10_495.0)  # saturation margin 5 dbar
    np.testing.assert_array_equal(f2.pressure_dbar[use], ctd[use])
    assert np.isnan(f2.pressure_dbar[~use]).all()
    with pytest.raises(InputError):
        fuse_pressure(ctd, gauge[:-1])


def test_correct_altitude_scales_by_sound_speed():
    a = np.array([10.0, np.nan, 80.0])
    out = correct_altitude(a, 34.7, 2.0, 10_000.0, nominal_sound_speed_m_s=1500.0)
    c = sw.sound_speed_chen_millero(34.7, 2.0, 10_000.0)
    assert np.isnan(out[1])
    assert out[0] == pytest.approx(10.0 * c / 1500.0, rel=1e-4)
    assert out[0] > 10.8  # ~1630 m/s at 10 000 dbar and 2 degC
    # the path-mean speed is a little faster for a longer range (pressure increases downwards)
    assert out[2] / 80.0 > out[0] / 10.0


def test_segment_phases():
    t = pd.date_range("2020-01-01", periods=3000, freq="2s", tz="UTC")
    s = np.arange(3000) * 2.0
    d = np.where(s < 2000, s, np.where(s < 4000, 2000 + 5 * np.sin(s / 100), 2000 - (s - 4000)))
    ph = segment_phases(t, d)
    assert ph[0] == "descent" and ph[-1] == "ascent"
    b = np.flatnonzero(ph == "bottom")
    assert abs(s[b[0]] - 2000) < 60 and abs(s[b[-1]] - 4000) < 60
    # pure profile (no bottom time): split at the deepest sample
    d2 = np.where(s < 3000, s, 6000 - s)
    ph2 = segment_phases(t, d2)
    assert ph2[0] == "descent" and ph2[-1] == "ascent" and (ph2 == "bottom").sum() < 40


def test_segment_phases_numeric_seconds_and_edge_cases():
    s = np.arange(0.0, 6000.0, 2.0)
    d = np.where(s < 3000, s, 6000 - s)
    ph = segment_phases(s, d)
    assert ph[0] == "descent" and ph[-1] == "ascent"
    assert (segment_phases(s, np.full(s.size, np.nan)) == "descent").all()
    assert segment_phases(np.array([]), np.array([])).size == 0


def test_segment_phases_same_for_every_time_form():
    """The phases from a time axis given as a tz-aware / naive pandas column, a DatetimeIndex, numpy datetime64 or
    Python datetimes match those from plain seconds (irregular sampling, a non-UTC zone)."""
    rng = np.random.default_rng(4)
    sec = np.cumsum(rng.uniform(0.5, 3.5, 4000))
    d = np.where(sec < 2500, sec, np.where(sec < 5000, 2500 + 5 * np.sin(sec / 90), 7500 - sec))
    want = segment_phases(sec, d)
    assert {"descent", "bottom", "ascent"} <= set(want)
    t0 = pd.Timestamp("2018-10-07 08:00", tz="Asia/Tokyo")
    aware = pd.Series(t0 + pd.to_timedelta(sec, unit="s"))
    forms = [aware, aware.dt.tz_convert("UTC"), aware.dt.tz_localize(None), pd.DatetimeIndex(aware),
             aware.dt.tz_convert("UTC").to_numpy(), list(aware)]
    for form in forms:
        np.testing.assert_array_equal(segment_phases(form, d), want)


def test_real_cast_hydrostatic_minus_fm_is_geopotential_anomaly(shared_data):
    """Eq. (8) on a real SBE 9 cast (oce-issues 644, 566 dbar, 69.4 N): the hydrostatic depth exceeds the
    standard-ocean F-M depth by the geopotential anomaly term dD/9.8 (dD = integral of delta dp)."""
    import warnings

    path = shared_data / "ctd-real" / "oceissues644_02dk.cnv"
    if not path.is_file():
        pytest.skip(f"{path} not present")
    ingest = pytest.importorskip("hadal.ingest")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        df = ingest.read_cnv(path)
    lat = df.attrs["latitude_deg"]
    p, t = df["prDM"].to_numpy(float), df["t090C"].to_numpy(float)
    s = sw.practical_salinity(df["c0mS/cm"].to_numpy(float) / 10.0, t, p)
    h = hydrostatic_depth(p, s, t, lat)
    fm = sw.depth_fofonoff_millard(p, lat)
    delta = sw.specific_volume_anomaly(s, t, p)
    dd = np.concatenate(([delta[0] * p[0]], 0.5 * (delta[1:] + delta[:-1]) * np.diff(p))).cumsum() * 1e4
    assert 0.3 < h[-1] - fm[-1] < 0.6
    np.testing.assert_allclose(h - fm, dd / 9.8, atol=5e-3)
