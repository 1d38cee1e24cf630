"""Pressure fusion (issue 17 §4): gain+offset fit, data-detected CTD saturation, sensor lag, continuity at the
switch, and a record that does not start at the surface. The truth is the synthetic pressure the sensors are
made from (independent of the fusion); the gauge is the accurate datum (Keller 0.01 %FS)."""

from __future__ import annotations

import numpy as np
import pytest

from hadal.depth import fuse_pressure
from hadal.settings import DeriveParams

DT = 2.0


def dive(max_p=10_950.0, speed=1.0, bottom_s=1800.0, seed=1):
    """Time (s) and true pressure (dbar) of a full-ocean dive: descent, bottom (±20 dbar), ascent."""
    t_desc = max_p / speed
    t = np.arange(0.0, 2 * t_desc + bottom_s, DT)
    p = np.where(t < t_desc, speed * t,
                 np.where(t < t_desc + bottom_s, max_p - 20 * np.sin(np.pi * (t - t_desc) / bottom_s),
                          max_p - speed * (t - t_desc - bottom_s)))
    p = np.convolve(np.pad(p, 15, mode="edge"), np.ones(31) / 31, mode="valid")  # no kinks: 60 s rounding
    return t, np.clip(p, 0.0, None), np.random.default_rng(seed)


def sensors(t, p, rng, *, gain=0.0, clip=10_500.0, lag_s=0.0, ctd_offset=-0.8, gauge_offset=0.3):
    """CTD = truth x (1 + gain) + offset + noise, clipped at ``clip``; gauge = truth + offset + noise, delayed
    by ``lag_s`` (it reads the pressure of ``lag_s`` seconds earlier)."""
    ctd = np.minimum(p * (1.0 + gain) + ctd_offset + rng.normal(0, 0.05, p.size), clip)
    p_late = np.interp(t - lag_s, t, p)
    gauge = p_late + gauge_offset + rng.normal(0, 0.05, p.size)
    return ctd, gauge


def max_step(x):
    return float(np.max(np.abs(np.diff(x))))


def test_gain_error_recovered_and_continuous_at_switch():
    t, p, rng = dive()
    ctd, gauge = sensors(t, p, rng, gain=5e-4)
    f = fuse_pressure(ctd, gauge, time_s=t, bias_window_dbar=(6000.0, 10_400.0))
    err = f.pressure_dbar - (p + 0.3)  # the gauge's datum
    assert f.gauge_gain == pytest.approx(1 / (1 + 5e-4), abs=2e-6)
    assert np.max(np.abs(err)) < 0.3  # noise-level everywhere (0.05 dbar sensor noise)
    assert abs(np.median(err[p < 100])) < 0.05  # the median-offset fusion was 4.1 dbar off here
    # continuous: no sample-to-sample step larger than the motion (2 dbar per 2 s) + noise
    assert max_step(f.pressure_dbar) < 2.0 * DT / 2 + 0.4
    assert f.switch_points and all(abs(s["ctd_minus_gauge_dbar"] or 0) < 0.3 for s in f.switch_points)
    assert f.n_blend > 0
    # the previous method (median offset only) fails this: metres off at the surface
    old = fuse_pressure(ctd, gauge, fit="offset", blend_dbar=0.0, estimate_lag=False,
                        bias_window_dbar=(6000.0, 10_400.0))
    assert abs(np.median((old.pressure_dbar - (p + 0.3))[p < 100])) > 3.0


def test_saturation_detected_from_a_flat_line():
    t, p, rng = dive()
    ctd, gauge = sensors(t, p, rng, clip=10_490.0)  # clips below the nominal 10 500 dbar range
    f = fuse_pressure(ctd, gauge, time_s=t)
    assert "flat line" in f.saturation_method and f.saturation_dbar == pytest.approx(10_490.0, abs=0.1)
    err = f.pressure_dbar - (p + 0.3)
    assert np.max(np.abs(err)) < 0.3  # a 410 dbar silent error with the threshold alone
    assert set(f.source[p > 10_500]) == {"gauge"}
    threshold_only = np.where(ctd < 10_495.0, ctd + 1.1, gauge)
    assert np.max(np.abs(threshold_only - (p + 0.3))) > 400  # what the 10 500 dbar threshold alone gives


def test_saturation_detected_from_divergence():
    """A CTD that does not flat-line but reads low and noisy past its range (compressing): found by its
    divergence from the gauge at the top of its range."""
    t, p, rng = dive()
    ctd, gauge = sensors(t, p, rng, clip=1e9)
    over = p > 10_300.0
    ctd[over] = 10_300.0 + 0.1 * (p[over] - 10_300.0) + rng.normal(0, 0.5, over.sum())
    f = fuse_pressure(ctd, gauge, time_s=t)
    assert "divergence" in f.saturation_method and f.saturation_dbar < 10_310
    assert np.max(np.abs(f.pressure_dbar - (p + 0.3))) < 0.5


@pytest.mark.parametrize("lag_s", [3.0, -2.0])
def test_lag_estimated_and_removed(lag_s):
    t, p, rng = dive()
    ctd, gauge = sensors(t, p, rng, lag_s=lag_s)
    f = fuse_pressure(ctd, gauge, time_s=t)
    assert f.lag_s == pytest.approx(lag_s, abs=0.1)
    assert f.gauge_bias_dbar == pytest.approx(1.1, abs=0.02) and f.gauge_gain == pytest.approx(1.0, abs=1e-5)
    deep = p > 10_600  # gauge only: shifted back onto the CTD's time
    err = f.pressure_dbar - (p + 0.3)
    assert np.max(np.abs(err[deep])) < 0.3
    # without the lag removal the speed-dependent error at the switch is ~|lag| dbar
    g = fuse_pressure(ctd, gauge, time_s=t, estimate_lag=False)
    assert np.max(np.abs((g.pressure_dbar - (p + 0.3))[(p > 10_400) & (p < 10_600)])) > 0.8 * abs(lag_s)


def test_all_errors_together_and_metadata():
    t, p, rng = dive()
    ctd, gauge = sensors(t, p, rng, gain=5e-4, clip=10_490.0, lag_s=2.5)
    f = fuse_pressure(ctd, gauge, time_s=t)
    assert f.lag_s == pytest.approx(2.5, abs=0.1)
    assert np.max(np.abs(f.pressure_dbar - (p + 0.3))) < 0.4
    d = f.to_dict()
    assert d["fit_method"] == "huber gain+offset" and d["fit_samples"] > 1000 and d["residual_mad_dbar"] < 0.2
    assert {"gain", "offset_dbar", "lag_s", "ctd_saturation_dbar", "switch_points"} <= set(d)
    assert d["samples"]["ctd"] + d["samples"]["gauge"] + d["samples"]["blend"] == p.size


def test_ctd_datum_and_no_time_base():
    t, p, rng = dive(max_p=11_000)
    ctd, gauge = sensors(t, p, rng, gain=5e-4)
    f = fuse_pressure(ctd, gauge, datum="ctd")  # no time: no lag estimate
    assert f.lag_note.startswith("no time base")
    ctd_scale = p * (1 + 5e-4) - 0.8
    assert np.max(np.abs(f.pressure_dbar - ctd_scale)) < 0.35


# ------------------------------------------------------------------ a record that does not start at the surface
LAT = 11.33


@pytest.fixture(scope="module")
def column():
    from test_depth import teos10_column  # true depth -> pressure via gsw.p_from_z with the column's own ψ

    return teos10_column(zmax=11_000.0, dz=2.0)


def test_mid_column_start_standard_ocean_within_its_stated_error(column):
    from hadal.depth import hydrostatic_depth, overlying_column

    d, p, sp, t = column
    s = d >= 5000.0  # logging started at 5000 m
    col = overlying_column(p[s], sp[s], t[s], LAT)
    assert col.method == "standard ocean (TEOS-10)" and "5085 dbar" in col.warning and col.error_m > 0.5
    h = hydrostatic_depth(p[s], sp[s], t[s], LAT, start_depth_m=col.start_depth_m)
    err = h - d[s]
    assert np.all(err <= 0.2) and np.all(-err <= col.error_m)  # too shallow, by less than the stated error
    assert np.min(err) < -2.0  # (this column's dynamic height anomaly: 3.7 m)
    # the first sample's in-situ density for the whole column (the previous behaviour): ~1 % too shallow
    old = hydrostatic_depth(p[s], sp[s], t[s], LAT)
    assert old[-1] - d[s][-1] < -40.0


def test_mid_column_start_with_a_user_profile(column):
    from hadal.depth import hydrostatic_depth, overlying_column

    d, p, sp, t = column
    s = d >= 5000.0
    cast = slice(0, None, 5)  # a 10 m-resolution site profile (e.g. a binned CTD cast)
    col = overlying_column(p[s], sp[s], t[s], LAT, profile=(p[cast], sp[cast], t[cast]))
    assert col.method == "user profile"
    h = hydrostatic_depth(p[s], sp[s], t[s], LAT, start_depth_m=col.start_depth_m)
    full = hydrostatic_depth(p, sp, t, LAT)  # the whole column from the surface: EOS-80 vs the TEOS-10 truth
    i = np.searchsorted(d[s], 10_900.0)
    assert abs(h[i] - 10_900.0) < 0.25 and np.max(np.abs(h - d[s])) < 0.25  # full-column accuracy: 0.17 m
    assert np.max(np.abs(h - full[s])) < 0.02


def test_record_starting_deep_uses_its_own_ascent(column):
    """Logging starts at 5000 dbar on the way down; the ascent reaches the surface: the record's own shallower
    samples give the overlying column (an upcast-only file is the same case)."""
    from hadal.depth import hydrostatic_depth, overlying_column

    d, p, sp, t = column
    down = d >= 5000.0
    sel = np.concatenate([np.flatnonzero(down), np.flatnonzero(np.ones(d.size, bool))[::-1]])
    col = overlying_column(p[sel], sp[sel], t[sel], LAT)
    assert col.method == "record profile" and col.error_m < 0.3
    h = hydrostatic_depth(p[sel], sp[sel], t[sel], LAT, start_depth_m=col.start_depth_m)
    full = hydrostatic_depth(p, sp, t, LAT)
    assert np.max(np.abs(h - d[sel])) < 0.25 and np.max(np.abs(h[:down.sum()] - full[down])) < 0.02
    up = overlying_column(p[::-1], sp[::-1], t[::-1], LAT)  # upcast only
    assert up.method == "record profile"
    assert np.max(np.abs(hydrostatic_depth(p[::-1], sp[::-1], t[::-1], LAT, start_depth_m=up.start_depth_m)
                         - d[::-1])) < 0.25
    assert overlying_column(p, sp, t, LAT).method == "surface"


def test_derive_recovers_depth_with_clipped_ctd_gain_error_and_lag():
    """Through derive_ctd (the stage's science): a CTD clipping at 10 490 dbar with flag 1 (not caught by the
    ingest range test), a 5e-4 gain error and a gauge 2 s late still give the true depth within 1 m at 10 900 m."""
    from test_derive import LON, synth_sensors

    from hadal.ctd import derive

    df, z, _ = synth_sensors(dt=4.0)
    t = (df["time"] - df["time"].iloc[0]).dt.total_seconds().to_numpy()
    pg = df["pressure_gauge_dbar"].to_numpy()
    df["pressure_gauge_dbar"] = np.interp(t - 2.0, t, pg)
    pc = df["pressure_ctd_dbar"].to_numpy() * (1 + 5e-4)
    df["pressure_ctd_dbar"] = np.minimum(pc, 10_490.0)
    df["pressure_ctd_dbar_qc"] = np.where(np.isfinite(pc), 1, 9).astype("uint8")  # clipping not flagged
    out, meta = derive.derive_ctd(df, LAT, LON, DeriveParams())
    i = int(np.argmax(z))
    assert abs(out["depth_m"].iloc[i] - z[i]) < 1.0 and np.nanmax(np.abs(out["depth_m"] - z)) < 1.0
    f = meta["pressure_fusion"]
    assert "flat line" in f["saturation_method"] and f["lag_s"] == pytest.approx(2.0, abs=0.3)
    assert f["gain"] == pytest.approx(1 / (1 + 5e-4), abs=1e-5) and f["switch_points"]
    assert meta["overlying_column"]["method"] == "surface"
