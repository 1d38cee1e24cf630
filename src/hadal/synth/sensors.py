"""Sensor models of the sample dive (TERCOM paper §2.1 Table 1, §3.2.1 Tables 2-4).

Every sensor samples the true state (:class:`hadal.synth.track.Track`, :class:`hadal.synth.water.WaterColumn`)
at its own clock (own rate, phase and +-1 ms jitter, times in integer milliseconds so that the MCAP and CSV
variants carry identical samples) and adds its own errors. Values are quantised to the decimals they are
written with, so the MCAP (JSON) and CSV files hold exactly the same numbers.

* SBE49 CTD (Table 3): T noise 0.001 °C (accuracy +-0.002), C noise 0.00015 S/m (+-0.0003), pressure with a
  constant offset within the +-0.1 %FS accuracy plus 0.1 dbar noise, **saturating at 10 500 dbar** (its range).
* Keller PA-33X (Table 2): 0-12 000 dbar, constant offset ~0.5 dbar (0.01 %FS class), 0.05 dbar noise,
  quantised to the 0.002 %FS = 0.24 dbar resolution.
* 400 kHz altimeter (Table 4): range computed with a nominal 1500 m/s sound speed (the true local speed is
  ~1650 m/s at the bottom, so the raw range reads ~10 % short), 0.3 m resolution, nothing beyond 100 m,
  ~2 % random dropouts.
* Attitude: compass heading = true heading + a constant compass bias + noise; small pitch/roll motions.
* GNSS (issue 47): 1 Hz fixes while the vehicle is at the surface, the first and last ``GNSS_SURFACE_S``
  seconds of the dive (launch and recovery), true position + white noise of ``GNSS_SIGMA_M`` per axis, with
  that variance logged as NavSatFix's position covariance; its own random stream, so the other channels are
  unchanged.
* USBL (optional, ``hadal synth --usbl-interval-s``): one fix every ``interval_s`` seconds from launch to
  recovery, the ship over the launch point; 1-sigma per axis ``USBL_RANGE_FRACTION`` x the slant range (at
  least ``USBL_MIN_SIGMA_M``), the error model of deep-water USBL systems' accuracy specifications and of
  oplab_pipeline's USBL sigma (offset + factor x range); that variance logged with the fix (east/north, m^2).
  Its own random stream: the other channels are unchanged.
* Dead reckoning: integrates the compass-rotated, scale-biased true velocity (+ correlated noise) from the
  start of the bottom track, where it believes it is at the launch point; 0 during the descent (no
  velocity reference), held during the ascent.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hadal.synth.terrain import Terrain
from hadal.synth.track import Track, smooth_noise
from hadal.synth.water import WaterColumn

SBE49_MAX_DBAR = 10500.0
KELLER_MAX_DBAR = 12000.0
KELLER_RESOLUTION_DBAR = 0.002e-2 * KELLER_MAX_DBAR  # 0.24 dbar
ALTIMETER_NOMINAL_SOUND_SPEED_M_S = 1500.0
ALTIMETER_RESOLUTION_M = 0.3
ALTIMETER_MAX_RANGE_M = 100.0

FULL_RATES_HZ = {"ctd": 16.0, "keller": 4.0, "altimeter": 2.0, "attitude": 10.0, "dr": 1.0}
SMALL_RATES_HZ = {"ctd": 2.0, "keller": 0.5, "altimeter": 0.5, "attitude": 0.5, "dr": 0.5}
#: per-sensor clock phase (ms) relative to the launch time
PHASE_MS = {"ctd": 0, "keller": 37, "altimeter": 113, "attitude": 51, "dr": 250}


@dataclass(frozen=True)
class SensorErrors:
    ctd_pressure_offset_dbar: float
    keller_offset_dbar: float
    compass_bias_deg: float
    dr_scale_error: float
    # DVL bottom-track velocity noise, correlated over 300 s (a few mm/s at 10 m altitude)
    dr_velocity_noise_m_s: float = 0.003
    ctd_pressure_noise_dbar: float = 0.1
    ctd_temperature_noise_degc: float = 0.001
    ctd_conductivity_noise_s_m: float = 0.00015
    keller_noise_dbar: float = 0.05
    altimeter_noise_m: float = 0.05
    altimeter_dropout_fraction: float = 0.02
    heading_noise_deg: float = 0.3

    @classmethod
    def draw(cls, rng: np.random.Generator) -> SensorErrors:
        sign = 1.0 if rng.random() < 0.5 else -1.0
        return cls(
            ctd_pressure_offset_dbar=round(float(rng.uniform(-1.0, 1.0)), 3),
            keller_offset_dbar=round(float(rng.uniform(0.4, 0.6)), 3),
            compass_bias_deg=round(sign * float(rng.uniform(1.0, 2.5)), 3),
            dr_scale_error=round(float(rng.choice([-1.0, 1.0]) * rng.uniform(0.01, 0.03)), 4),
        )


def sample_times_ms(rate_hz: float, duration_s: float, phase_ms: int, rng: np.random.Generator,
                    jitter: bool) -> np.ndarray:
    """Integer-millisecond sample times (relative to launch) of a sensor clock."""
    n = int(np.floor((duration_s * 1000 - phase_ms) * rate_hz / 1000.0)) + 1
    t = phase_ms + np.round(np.arange(n) * (1000.0 / rate_hz)).astype(np.int64)
    if jitter:
        t = t + rng.integers(-1, 2, n)
    return t


def simulate(track: Track, terrain: Terrain, water: WaterColumn, err: SensorErrors,
             rates: dict[str, float], rng: np.random.Generator) -> dict[str, dict[str, np.ndarray]]:
    """All five channels: ``{name: {"t_ms": int64 ms since launch, field: values...}}`` (vehicle field names)."""
    dur = float(track.t[-1])
    out: dict[str, dict[str, np.ndarray]] = {}

    # --- CTD
    t_ms = sample_times_ms(rates["ctd"], dur, PHASE_MS["ctd"], rng, jitter=False)
    st = track.at(t_ms / 1000.0, terrain)
    p_true = water.pressure_from_depth(st["depth"])
    heave = 4.0 * smooth_noise(rng, len(t_ms), 600.0 * rates["ctd"])  # internal waves (dbar)
    ws = water.state(p_true, heave)
    n = len(t_ms)
    temp = ws["t"] + rng.normal(0.0, err.ctd_temperature_noise_degc, n)
    cond = ws["C_S_m"] + rng.normal(0.0, err.ctd_conductivity_noise_s_m, n)
    pres = p_true + err.ctd_pressure_offset_dbar + rng.normal(0.0, err.ctd_pressure_noise_dbar, n)
    pres = np.minimum(pres, SBE49_MAX_DBAR)
    out["ctd"] = {"t_ms": t_ms, "cond": np.round(cond, 5), "temp": np.round(temp, 4), "pres": np.round(pres, 3)}

    # --- Keller PA-33X
    t_ms = sample_times_ms(rates["keller"], dur, PHASE_MS["keller"], rng, jitter=True)
    st = track.at(t_ms / 1000.0, terrain)
    p_true = water.pressure_from_depth(st["depth"])
    pk = p_true + err.keller_offset_dbar + rng.normal(0.0, err.keller_noise_dbar, len(t_ms))
    pk = np.clip(np.round(pk / KELLER_RESOLUTION_DBAR) * KELLER_RESOLUTION_DBAR, 0.0, KELLER_MAX_DBAR)
    out["keller"] = {"t_ms": t_ms, "pressure": np.round(pk, 2)}

    # --- altimeter (ranges assume the nominal sound speed)
    t_ms = sample_times_ms(rates["altimeter"], dur, PHASE_MS["altimeter"], rng, jitter=True)
    st = track.at(t_ms / 1000.0, terrain)
    alt = st["altitude"]
    near = alt < 1.3 * ALTIMETER_MAX_RANGE_M
    c = np.full(len(t_ms), ALTIMETER_NOMINAL_SOUND_SPEED_M_S)
    if near.any():
        p_near = water.pressure_from_depth(st["depth"][near])
        c[near] = water.state(p_near)["sound_speed_m_s"]
    rng_m = alt * ALTIMETER_NOMINAL_SOUND_SPEED_M_S / c + rng.normal(0.0, err.altimeter_noise_m, len(t_ms))
    rng_m = np.round(np.round(rng_m / ALTIMETER_RESOLUTION_M) * ALTIMETER_RESOLUTION_M, 1)
    valid = (rng_m <= ALTIMETER_MAX_RANGE_M) & (rng_m > 0) & (rng.random(len(t_ms)) >= err.altimeter_dropout_fraction)
    out["altimeter"] = {"t_ms": t_ms, "range": np.where(valid, rng_m, np.nan), "valid": valid}

    # --- attitude
    t_ms = sample_times_ms(rates["attitude"], dur, PHASE_MS["attitude"], rng, jitter=True)
    ts = t_ms / 1000.0
    st = track.at(ts, terrain)
    n = len(t_ms)
    r = rates["attitude"]
    heading = (st["heading"] + err.compass_bias_deg + rng.normal(0.0, err.heading_noise_deg, n)) % 360.0
    ph = st["phase"]
    pitch = np.where(ph == 0, -3.0, np.where(ph == 2, 3.0, 0.5)) + 1.0 * smooth_noise(rng, n, 5.0 * r) \
        + rng.normal(0.0, 0.1, n)
    roll = 1.2 * np.sin(2 * np.pi * ts / 6.3) * (0.5 + 0.5 * np.abs(smooth_noise(rng, n, 60.0 * r))) \
        + rng.normal(0.0, 0.1, n)
    out["attitude"] = {"t_ms": t_ms, "heading": np.round(heading, 2) % 360.0, "pitch": np.round(pitch, 2),
                       "roll": np.round(roll, 2)}

    # --- dead reckoning (relative to the launch point)
    t_ms = sample_times_ms(rates["dr"], dur, PHASE_MS["dr"], rng, jitter=True)
    ts = t_ms / 1000.0
    st = track.at(ts, terrain)
    n = len(t_ms)
    t_b0 = float(track.t[track.i_bottom_start])
    t_b1 = float(track.t[track.i_bottom_end])
    on = (ts >= t_b0) & (ts <= t_b1)
    b = np.radians(err.compass_bias_deg)
    k = 1.0 + err.dr_scale_error
    ve = k * (np.cos(b) * st["vx"] + np.sin(b) * st["vy"])
    vn = k * (-np.sin(b) * st["vx"] + np.cos(b) * st["vy"])
    noise_e = err.dr_velocity_noise_m_s * smooth_noise(rng, n, 300.0 * rates["dr"])
    noise_n = err.dr_velocity_noise_m_s * smooth_noise(rng, n, 300.0 * rates["dr"])
    ve = np.where(on, ve + noise_e, 0.0)
    vn = np.where(on, vn + noise_n, 0.0)
    dt = np.diff(ts, prepend=ts[0])
    east = np.cumsum(0.5 * (ve + np.concatenate([[0.0], ve[:-1]])) * dt)
    north = np.cumsum(0.5 * (vn + np.concatenate([[0.0], vn[:-1]])) * dt)
    out["dr"] = {"t_ms": t_ms, "east": np.round(east, 3), "north": np.round(north, 3),
                 "speed": np.round(np.hypot(ve, vn), 3)}
    return out


GNSS_SIGMA_M = 3.0
GNSS_SURFACE_S = 5


def simulate_gnss(track: Track, frame, rng: np.random.Generator, t0_phase_ms: int = 0) -> dict[str, np.ndarray]:
    """GNSS fixes at the surface (module docstring): ``{"t_ms", "latitude", "longitude", "east_variance",
    "north_variance"}``; positions in degrees (WGS 84) from the true map position through ``frame``."""
    dur = float(track.t[-1])
    t_s = np.concatenate([np.arange(GNSS_SURFACE_S, dtype=float), dur - np.arange(GNSS_SURFACE_S)[::-1]])
    t_ms = np.round(t_s * 1000).astype(np.int64) + t0_phase_ms
    x = np.interp(t_s, track.t, track.x) + rng.normal(0.0, GNSS_SIGMA_M, t_s.size)
    y = np.interp(t_s, track.t, track.y) + rng.normal(0.0, GNSS_SIGMA_M, t_s.size)
    lon, lat = frame.to_lonlat(x, y)
    var = np.full(t_s.size, GNSS_SIGMA_M ** 2)
    return {"t_ms": t_ms, "latitude": np.round(np.asarray(lat, float), 8), "longitude": np.round(np.asarray(lon, float), 8),
            "east_variance": var, "north_variance": var.copy()}


#: USBL 1-sigma per axis: this fraction of the slant range from the ship (1 %: a deep-water USBL with a
#: heading/attitude-limited angular accuracy of ~0.5 deg), at least USBL_MIN_SIGMA_M
USBL_RANGE_FRACTION = 0.01
USBL_MIN_SIGMA_M = 2.0


def simulate_usbl(track: Track, frame, rng: np.random.Generator, interval_s: float,
                  ship_xy: tuple[float, float], t0_phase_ms: int = 0) -> dict[str, np.ndarray]:
    """USBL fixes (module docstring) every ``interval_s`` s from ``interval_s`` after launch to the surfacing,
    ship at ``ship_xy`` (map frame, m): ``{"t_ms", "latitude", "longitude", "east_variance", "north_variance",
    "sigma_m"}``; positions in degrees (WGS 84) from the true map position through ``frame``."""
    dur = float(track.t[-1])
    t_s = np.arange(float(interval_s), dur, float(interval_s))
    t_ms = np.round(t_s * 1000).astype(np.int64) + t0_phase_ms
    tx, ty = np.interp(t_s, track.t, track.x), np.interp(t_s, track.t, track.y)
    depth = np.interp(t_s, track.t, track.depth)
    slant = np.sqrt((tx - ship_xy[0]) ** 2 + (ty - ship_xy[1]) ** 2 + depth ** 2)
    sigma = np.round(np.maximum(USBL_RANGE_FRACTION * slant, USBL_MIN_SIGMA_M), 2)
    x = tx + rng.normal(0.0, 1.0, t_s.size) * sigma
    y = ty + rng.normal(0.0, 1.0, t_s.size) * sigma
    lon, lat = frame.to_lonlat(x, y)
    var = np.round(sigma ** 2, 2)
    return {"t_ms": t_ms, "latitude": np.round(np.atleast_1d(np.asarray(lat, float)), 8),
            "longitude": np.round(np.atleast_1d(np.asarray(lon, float)), 8),
            "east_variance": var, "north_variance": var.copy(), "sigma_m": sigma}
