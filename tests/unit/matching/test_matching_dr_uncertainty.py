"""The dead-reckoning-only position uncertainty (navigation product without a match) covers the true error.

Oracle: the sample-dive generator (hadal.synth): its true horizontal path and its dead-reckoning channel (DR
held at zero during the unpowered descent, heading-bias/scale/noise errors on the bottom, held on the ascent),
built for several generator seeds without writing or ingesting any file. The brief (issue 18 item in issue 16):
the stated 1-sigma (DRMS) and 2-sigma must cover about 68 % and 95 % of the errors; the former 1 %-of-distance
model covered < 1 % (the descent drift is not dead-reckoned at all).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from hadal.geo import LocalFrame
from hadal.products.navigation import navigation_table, unreferenced_seconds


def _generated_dive(seed: int):
    """(ctd-like table at the DR sample times, true x, true y, frame, launch lon/lat) of generator seed ``seed``."""
    from hadal.synth import generate as gen
    from hadal.synth import scenario as sc
    from hadal.synth import sensors
    from hadal.synth.terrain import base_terrain
    from hadal.synth.water import WaterColumn

    r = gen._rngs(seed)
    frame = LocalFrame(sc.MAP_ORIGIN_LAT_DEG, sc.MAP_ORIGIN_LON_DEG)
    xy = [np.array(frame.to_xy(lon, lat), float) for lon, lat in (
        (sc.LAUNCH_LON_DEG, sc.LAUNCH_LAT_DEG), (sc.BOTTOM_START_LON_DEG, sc.BOTTOM_START_LAT_DEG),
        (sc.DEEPEST_LON_DEG, sc.DEEPEST_LAT_DEG))]
    ter, layout = base_terrain(r["terrain"])
    track, _ = gen._trajectory(ter, layout, r["track"], r["track2"], *xy)
    err = sensors.SensorErrors.draw(r["errors"])
    ch = sensors.simulate(track, ter, WaterColumn(sc.LAUNCH_LAT_DEG, sc.LAUNCH_LON_DEG), err,
                          sensors.SMALL_RATES_HZ, r["sensors"])["dr"]
    ts = ch["t_ms"] / 1000.0
    from hadal.synth.track import PHASES

    k = np.clip(np.searchsorted(track.t, ts, side="right") - 1, 0, len(track.t) - 1)
    ctd = pd.DataFrame({"time": sc.LAUNCH_TIME_UTC + pd.to_timedelta(ts, unit="s"),
                        "dr_east_m": ch["east"], "dr_north_m": ch["north"],
                        "phase": np.asarray(PHASES, dtype=object)[track.phase[k]]})
    return ctd, np.interp(ts, track.t, track.x), np.interp(ts, track.t, track.y), frame, \
        (sc.LAUNCH_LAT_DEG, sc.LAUNCH_LON_DEG)


@pytest.fixture(scope="module")
def dives():
    return [_generated_dive(s) for s in (20181006, 2, 7)]


def _ratios(dives, **model):
    out = []
    for ctd, tx, ty, frame, launch in dives:
        nav = navigation_table(ctd, frame, *launch, **model)
        err = np.hypot(nav["x_east_m"].to_numpy() - tx, nav["y_north_m"].to_numpy() - ty)
        out.append(err / nav["position_uncertainty_m"].to_numpy())
    return np.concatenate(out)


def test_dr_only_uncertainty_covers_the_generated_errors(dives):
    q = _ratios(dives)
    within1, within2 = float(np.mean(q <= 1)), float(np.mean(q <= 2))
    assert 0.55 <= within1 <= 0.85, within1  # DRMS of a circular 2-D Gaussian: 63 %; issue: ~68 %
    assert within2 >= 0.95, within2
    # the former model (1 % of the distance, no drift without a velocity reference) covered almost nothing
    old = _ratios(dives, dr_error_fraction=0.01, unreferenced_drift_m_per_sqrt_s=0.0)
    assert np.mean(old <= 2) < 0.05


def test_unreferenced_time_counts_only_held_dead_reckoning():
    # brute force: 1 Hz, DR held 100 s, moving at 0.3 m/s for 200 s, held 50 s
    ts = np.arange(351.0)
    e = np.concatenate([np.zeros(100), 0.3 * np.arange(1, 201), np.full(51, 60.0)])
    t_un = unreferenced_seconds(ts, e, np.zeros_like(e))
    # the +-30 s window blurs each transition by up to 30 s, never more
    assert 70 <= t_un[100] <= 100 and t_un[300] == pytest.approx(t_un[130], abs=1e-9)
    assert 20 <= t_un[-1] - t_un[300] <= 50
    assert np.all(np.diff(t_un) >= 0)


def test_navigation_defaults_are_the_match_stage_params():
    from hadal.settings import MatchParams as Params

    ctd = pd.DataFrame({"time": pd.date_range("2018-10-06", periods=4, freq="600s", tz="UTC"),
                        "dr_east_m": [0.0, 0.0, 0.0, 100.0], "dr_north_m": [0.0, 0.0, 0.0, 0.0]})
    frame = LocalFrame(11.33, 142.2)
    p = Params()
    a = navigation_table(ctd, frame, 11.33, 142.2)["position_uncertainty_m"]
    b = navigation_table(ctd, frame, 11.33, 142.2, dr_error_fraction=p.dr_error_fraction,
                         unreferenced_drift_m_per_sqrt_s=p.dr_unreferenced_drift_m_per_sqrt_s)["position_uncertainty_m"]
    assert np.array_equal(a.to_numpy(), b.to_numpy())
    # 10 min held at the launch: launch 10 m and the drift random walk in quadrature
    assert a.iloc[1] == pytest.approx(np.hypot(10.0, p.dr_unreferenced_drift_m_per_sqrt_s * np.sqrt(600.0)))


def test_matched_navigation_uncertainty_covers_descent_and_ascent(dives):
    """With a match (here the true bottom track, 1-sigma 20 m, as the matched positions): the adjusted descent and
    the ascent after the last fix are covered too (the ascent's drift is not uniform in time: the revealed descent
    rate alone covered ~20 % of its errors within 1 sigma)."""
    rng = np.random.default_rng(5)
    by_phase: dict[str, list[np.ndarray]] = {"descent": [], "ascent": []}
    for ctd, tx, ty, frame, launch in dives:
        bottom = (ctd["phase"] == "bottom").to_numpy()
        matched = pd.DataFrame({"time": ctd["time"][bottom],
                                "x_east_m": tx[bottom] + rng.normal(0, 14.0, bottom.sum()),
                                "y_north_m": ty[bottom] + rng.normal(0, 14.0, bottom.sum())})
        nav = navigation_table(ctd, frame, *launch, matched=matched, fix={"uncertainty_m": {"radial": 20.0}})
        q = np.hypot(nav["x_east_m"].to_numpy() - tx, nav["y_north_m"].to_numpy() - ty) \
            / nav["position_uncertainty_m"].to_numpy()
        for ph in by_phase:
            by_phase[ph].append(q[(ctd["phase"] == ph).to_numpy()])
    for ph, qs in by_phase.items():
        q = np.concatenate(qs)
        assert np.mean(q <= 2) >= 0.95, (ph, np.mean(q <= 2))
        assert np.mean(q <= 1) >= 0.5, (ph, np.mean(q <= 1))
