"""Vehicle depth from pressure, pressure-source fusion, seafloor depth and dive phases.

Implements §3.2.2 (Eqs. 11-12) and §4.1.3 of Ma et al. (2023) *TERCOM Challenger Deep*
(``papers/tercom-challenger-deep.md``): the depth is the hydrostatic integral of the measured in situ
specific volume, ``H_i = sum h_i``, ``h_i = (p_i - p_{i-1}) / (ρ_i g_i)`` with EOS-80 density (Eq. 13,
:func:`hadal.seawater.density_eos80`) and gravity at the current depth (Eq. 14, :func:`hadal.seawater.gravity`);
the seafloor depth is the vehicle depth plus the (sound-speed corrected) altimeter range (Fig. 10).

Cross-checks: :func:`hadal.seawater.depth_fofonoff_millard` (Eqs. 8-10, standard ocean) and the TEOS-10
height ``gsw.z_from_p`` with the dynamic height anomaly of the measured profile (:func:`depth_teos10`).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
import pandas as pd
from numpy.typing import ArrayLike

from hadal.errors import InputError
from hadal.seawater import (
    GRAV_C3_PER_M,
    density_eos80,
    depth_fofonoff_millard,
    gravity,
    sound_speed_chen_millero,
)

#: 1 dbar in Pa.
PA_PER_DBAR = 1.0e4

Integration = Literal["trapezoid", "rectangle"]


def _fill_by_index(values: np.ndarray, valid: np.ndarray) -> np.ndarray:
    """Linear interpolation over the sample index of the invalid entries (edges held)."""
    idx = np.arange(values.size)
    return np.interp(idx, idx[valid], values[valid])


def hydrostatic_depth(
    pressure_dbar: ArrayLike,
    salinity: ArrayLike,
    temperature_its90_degc: ArrayLike,
    latitude_deg: ArrayLike,
    *,
    integration: Integration = "trapezoid",
    density_kg_m3: ArrayLike | None = None,
    tolerance_m: float = 1e-9,
    max_iterations: int = 20,
) -> np.ndarray:
    """Depth (m, positive down) by integrating the hydrostatic equation along the sample series — Eqs. (11)-(12).

    ``H_i = Σ_{k<=i} h_k`` with ``h_k = Δp_k / (ρ_k g_k)``: ``Δp_k = (p_k - p_{k-1})·1e4`` Pa (sea pressure
    in dbar, 1 dbar = 1e4 Pa), ``ρ_k`` the EOS-80 in situ density (Eq. 13) of the sample and ``g_k`` the gravity
    (Eq. 14, :func:`hadal.seawater.gravity`) **at the depth reached so far** (``H_{k-1}``), not the
    Fofonoff-Millard column-mean gravity (that would cost ~5 m at 10 000 dbar).

    * First sample: the series starts below the surface at ``p_0``; its offset is ``h_0 = p_0 / (ρ_0 g(0))``
      (the water between the surface and the first sample is taken to have the first sample's density).
    * Non-monotonic pressure (the vehicle goes up and down, hovers near the seafloor): the increments are
      signed, so the sum telescopes — going down and back up to the same pressure through the same water
      returns to the same depth.
    * NaN pressure: the sample is skipped (its depth is NaN) and the next valid sample's increment is taken
      from the last valid pressure. NaN density (e.g. a conductivity dropout) at a valid pressure: the
      density is interpolated over the sample index from its valid neighbours (held at the ends).
    * ``integration="rectangle"`` is Eq. (12) as printed (ρ and g of the interval's end sample, g at
      ``H_{k-1}``); ``"trapezoid"`` (default) averages ``1/(ρ g)`` of the two ends of each interval, i.e.
      second-order accurate in Δp. The rectangle rule is biased shallow by ½ Σ Δp Δ(1/ρg), which grows with
      the step: at 11 000 dbar ≈ 1.5 mm for a 16 Hz CTD at 1 m/s (Δp ≈ 0.06 dbar), 1 cm at 0.5 dbar steps
      and 0.24 m at 10 dbar steps (binned casts); the trapezoid removes it (``tests/test_depth.py``).

    ``g`` depends on the depth being computed, so the sum is solved by fixed-point iteration
    (``H ← cumsum(h(g(H)))``, vectorised) started from the Fofonoff-Millard depth; the error shrinks by a
    factor ~C3·H ≈ 2.5e-3 per iteration, so 3-4 iterations reach ``tolerance_m``. The sequential recursion
    of Eq. (12) is the fixed point (``tests/test_depth.py`` checks both agree to 1e-8 m). With the trapezoid
    rule the first interval (surface to ``p_0``) also averages ``g`` over its ends.

    Parameters: ``pressure_dbar`` (1-D, time order), ``salinity`` (practical), ``temperature_its90_degc``,
    ``latitude_deg`` (scalar or per sample). ``density_kg_m3`` may be passed to reuse a computed density.
    Returns the depth array (NaN where the pressure is NaN). Raises :class:`hadal.errors.InputError` when
    there is no valid density at all.
    """
    p = np.asarray(pressure_dbar, dtype=np.float64)
    if p.ndim != 1:
        raise InputError(f"hydrostatic_depth: pressure must be a 1-D series, got shape {p.shape}")
    out = np.full(p.shape, np.nan)
    valid = np.isfinite(p)
    if not valid.any():
        return out
    if density_kg_m3 is None:
        rho = density_eos80(np.broadcast_to(salinity, p.shape), np.broadcast_to(temperature_its90_degc, p.shape), p)
    else:
        rho = np.broadcast_to(np.asarray(density_kg_m3, dtype=np.float64), p.shape).copy()
    lat = np.asarray(latitude_deg, dtype=np.float64)
    lv = lat if lat.ndim == 0 else np.broadcast_to(lat, p.shape)[valid]
    if not np.all(np.isfinite(lv)):
        raise InputError("hydrostatic_depth: latitude is NaN/inf where pressure is valid")
    pv, rv = p[valid], rho[valid]
    rok = np.isfinite(rv) & (rv > 0)
    if not rok.any():
        raise InputError("hydrostatic_depth: no valid density (salinity/temperature all NaN)")
    if not rok.all():
        rv = _fill_by_index(rv, rok)
    if integration not in ("trapezoid", "rectangle"):
        raise ValueError(f"integration must be 'trapezoid' or 'rectangle', not {integration!r}")
    dp_pa = np.diff(pv, prepend=0.0) * PA_PER_DBAR  # first increment from the surface: h_0 = p_0/(ρ_0 g_0)
    rho_g0 = rv * gravity(lv, 0.0)  # ρ g(φ, 0); g(φ, H) = g(φ, 0) (1 + C3 H), Eq. (14)
    # start from the Fofonoff-Millard depth (within ~10 m): the fixed point then converges in 3-4 iterations
    depth = depth_fofonoff_millard(pv, lv)
    inv = np.empty(pv.size + 1)
    for _ in range(max_iterations):
        if integration == "rectangle":
            h_prev = np.concatenate(([0.0], depth[:-1]))  # H_{i-1}
            h = dp_pa / (rho_g0 * (1.0 + GRAV_C3_PER_M * h_prev))
        else:
            # 1/(ρ g) at both ends of each interval; the start of the first one is the surface (H = 0)
            inv[0] = 1.0 / rho_g0.flat[0]
            np.divide(1.0, rho_g0 * (1.0 + GRAV_C3_PER_M * depth), out=inv[1:])
            h = (inv[:-1] + inv[1:]) * (0.5 * dp_pa)
        new = np.cumsum(h)
        change = float(np.max(np.abs(new - depth)))
        depth = new
        if change < tolerance_m:
            break
    out[valid] = depth
    return out


# --------------------------------------------------------------------------------------------- TEOS-10
def dynamic_height_anomaly(pressure_dbar: ArrayLike, salinity: ArrayLike, temperature_its90_degc: ArrayLike,
                           longitude_deg: float, latitude_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """TEOS-10 dynamic height anomaly ψ (m² s⁻², p_ref = 0) of a monotonic profile (e.g. the binned descent).

    Returns ``(pressure_dbar, psi)`` with a 0 dbar point prepended when the profile starts below the surface
    (its top water properties held up to the surface), as ``gsw.z_from_p`` needs ψ referred to 0 dbar.
    Uses ``gsw.SA_from_SP``, ``gsw.CT_from_t`` and ``gsw.geo_strf_dyn_height``.
    """
    import gsw

    p = np.asarray(pressure_dbar, dtype=np.float64)
    sp = np.asarray(salinity, dtype=np.float64)
    t = np.asarray(temperature_its90_degc, dtype=np.float64)
    ok = np.isfinite(p) & np.isfinite(sp) & np.isfinite(t)
    p, sp, t = p[ok], sp[ok], t[ok]
    if p.size < 2:
        raise InputError("dynamic_height_anomaly: fewer than 2 valid profile levels")
    order = np.argsort(p, kind="stable")
    p, sp, t = p[order], sp[order], t[order]
    keep = np.concatenate(([True], np.diff(p) > 0))
    p, sp, t = p[keep], sp[keep], t[keep]
    if p[0] > 0:
        p, sp, t = np.concatenate(([0.0], p)), np.concatenate((sp[:1], sp)), np.concatenate((t[:1], t))
    sa = gsw.SA_from_SP(sp, p, longitude_deg, latitude_deg)
    ct = gsw.CT_from_t(sa, t, p)
    psi = gsw.geo_strf_dyn_height(sa, ct, p, p_ref=0.0, interp_method="linear")
    return p, np.asarray(psi, dtype=np.float64)


def depth_teos10(pressure_dbar: ArrayLike, latitude_deg: ArrayLike, profile_pressure_dbar: ArrayLike | None = None,
                 profile_psi: ArrayLike | None = None) -> np.ndarray:
    """TEOS-10 depth (m, positive down): ``-gsw.z_from_p(p, lat, ψ(p))`` (IOC et al. 2010, Eq. 3.32.3).

    ``ψ`` (dynamic height anomaly, p_ref = 0, from :func:`dynamic_height_anomaly` of the descent profile) is
    interpolated linearly in pressure at each sample and extrapolated below the profile with its last
    slope; without a profile ψ = 0 (the standard ocean SA = 35.16504 g/kg, CT = 0 °C).
    """
    import gsw

    p = np.asarray(pressure_dbar, dtype=np.float64)
    psi = np.zeros_like(p)
    if profile_pressure_dbar is not None and profile_psi is not None:
        pp = np.asarray(profile_pressure_dbar, dtype=np.float64)
        pv = np.asarray(profile_psi, dtype=np.float64)
        psi = np.interp(p, pp, pv)
        if pp.size >= 2:
            slope_hi = (pv[-1] - pv[-2]) / (pp[-1] - pp[-2])
            below = p > pp[-1]
            psi[below] = pv[-1] + slope_hi * (p[below] - pp[-1])
        psi[~np.isfinite(p)] = np.nan
    return -np.asarray(gsw.z_from_p(p, latitude_deg, geo_strf_dyn_height=psi), dtype=np.float64)


# ---------------------------------------------------------------------------------- pressure fusion
@dataclass(frozen=True)
class PressureFusion:
    """Result of :func:`fuse_pressure`."""

    pressure_dbar: np.ndarray
    source: np.ndarray  # object array of "ctd" / "gauge" / "" (no pressure)
    gauge_bias_dbar: float  # median(gauge - ctd) on the overlap (added to the CTD on the gauge datum)
    bias_samples: int  # overlap samples used for the bias
    bias_mad_dbar: float  # robust spread (1.4826 MAD) of gauge - ctd on the overlap
    n_ctd: int
    n_gauge: int


def fuse_pressure(
    pressure_ctd_dbar: ArrayLike,
    pressure_gauge_dbar: ArrayLike,
    *,
    ctd_ok: ArrayLike | None = None,
    gauge_ok: ArrayLike | None = None,
    ctd_saturation_dbar: float = 10_500.0,
    saturation_margin_dbar: float = 5.0,
    bias_window_dbar: tuple[float, float] = (6000.0, 10_400.0),
    min_bias_samples: int = 20,
    datum: Literal["gauge", "ctd"] = "gauge",
) -> PressureFusion:
    """Fuse the CTD (SBE49, 0-10 500 dbar, ±0.1 %FS) and high-range gauge (Keller PA-33X, 0-12 000 dbar,
    0.01 %FS) pressures into one series (paper §3.2.1, Tables 2-3).

    The CTD pressure is used where it is valid (``ctd_ok``, e.g. QARTOD flag 1/2 from ingest) and below
    ``ctd_saturation_dbar - saturation_margin_dbar``; elsewhere the gauge. The two are put on one datum with
    ``bias = median(gauge - ctd)`` over the overlap where both are valid and the CTD reads inside
    ``bias_window_dbar`` (deep, where both sensors see the same water); with fewer than ``min_bias_samples``
    there the whole overlap is used, with none the bias is 0.

    ``datum="gauge"`` (default): the series is on the gauge's datum (CTD + bias where the CTD is used, gauge
    where it saturates) because the gauge is the more accurate sensor (0.01 %FS = ±1.2 dbar against the
    SBE49's 0.1 %FS = ±10.5 dbar): a constant CTD offset would otherwise go straight into every depth.
    ``datum="ctd"``: CTD where valid, ``gauge - bias`` elsewhere (the CTD's datum). Either way the series
    is continuous where the source switches.
    """
    pc = np.asarray(pressure_ctd_dbar, dtype=np.float64)
    pg = np.asarray(pressure_gauge_dbar, dtype=np.float64)
    if pc.shape != pg.shape:
        raise InputError(f"fuse_pressure: CTD and gauge series differ in length ({pc.size} vs {pg.size})")
    cok = np.isfinite(pc) & (np.ones_like(pc, bool) if ctd_ok is None else np.asarray(ctd_ok, bool))
    gok = np.isfinite(pg) & (np.ones_like(pg, bool) if gauge_ok is None else np.asarray(gauge_ok, bool))
    cok &= pc < ctd_saturation_dbar - saturation_margin_dbar
    both = cok & gok
    win = both & (pc >= bias_window_dbar[0]) & (pc <= bias_window_dbar[1])
    use = win if win.sum() >= min_bias_samples else both
    if use.any():
        diff = pg[use] - pc[use]
        bias = float(np.median(diff))
        mad = float(1.4826 * np.median(np.abs(diff - bias)))
    else:
        bias, mad = 0.0, float("nan")
    if datum not in ("gauge", "ctd"):
        raise ValueError(f"datum must be 'gauge' or 'ctd', not {datum!r}")
    shift_ctd, shift_gauge = (bias, 0.0) if datum == "gauge" else (0.0, -bias)
    fused = np.where(cok, pc + shift_ctd, np.where(gok, pg + shift_gauge, np.nan))
    source = np.where(cok, "ctd", np.where(gok, "gauge", "")).astype(object)
    return PressureFusion(fused, source, bias, int(use.sum()), mad, int(cok.sum()), int((~cok & gok).sum()))


# ------------------------------------------------------------------------------------ altitude, phases
def correct_altitude(altitude_m: ArrayLike, salinity: ArrayLike, temperature_its90_degc: ArrayLike,
                     pressure_dbar: ArrayLike, *, nominal_sound_speed_m_s: float = 1500.0,
                     density_kg_m3: ArrayLike | float = 1050.0, latitude_deg: float = 0.0) -> np.ndarray:
    """Altimeter range corrected for the true sound speed: ``range · c̄ / c_nominal`` (m).

    The echosounder converts travel time to range with ``c_nominal``; ``c̄`` is the Chen-Millero sound speed
    (:func:`hadal.seawater.sound_speed_chen_millero`) of the vehicle's water evaluated at the pressure half
    way down the acoustic path (``p + ½ range·ρ g / 1e4``): near the seafloor T and S are nearly uniform
    over ≤ 100 m while c grows ~0.017 m s⁻¹ per metre with pressure, so this is the path-mean speed to
    < 1 mm over 100 m. NaN ranges stay NaN.
    """
    a = np.asarray(altitude_m, dtype=np.float64)
    p = np.asarray(pressure_dbar, dtype=np.float64)
    g = gravity(latitude_deg, 0.0)
    p_mid = p + 0.5 * a * np.asarray(density_kg_m3, dtype=np.float64) * g / PA_PER_DBAR
    c = sound_speed_chen_millero(salinity, temperature_its90_degc, np.where(np.isfinite(a), p_mid, p))
    return a * c / nominal_sound_speed_m_s


PHASES = ("descent", "bottom", "ascent")


def segment_phases(time: ArrayLike, depth_m: ArrayLike, *, smoothing_s: float = 60.0,
                   vertical_speed_threshold_m_s: float = 0.2, deep_fraction: float = 0.5) -> np.ndarray:
    """Dive phases ``descent`` / ``bottom`` / ``ascent`` per sample from the depth series (paper §4.1.3, Fig. 9).

    Depth is smoothed by a centred ``smoothing_s`` rolling mean and differentiated in time. The descent ends
    at the first sample deeper than ``deep_fraction`` × max depth whose vertical speed falls below
    ``vertical_speed_threshold_m_s``; the ascent starts after the last such sample whose speed is above
    ``-vertical_speed_threshold_m_s``; the bottom phase lies between. A pure profile (no bottom time) splits
    at the deepest sample. NaN depths take the phase of their position in time. ``time``: datetimes or
    seconds (numeric), in increasing order.
    """
    tarr = np.asarray(time)
    d = np.asarray(depth_m, dtype=np.float64)
    n = d.size
    out = np.full(n, "descent", dtype=object)
    ok = np.isfinite(d)
    if n == 0 or not ok.any():
        return out
    if tarr.dtype.kind in "iuf":  # seconds
        ts = tarr.astype(np.float64) - float(tarr[0])
    else:
        t = pd.to_datetime(pd.Series(tarr), utc=True)
        ts = (t - t.iloc[0]).dt.total_seconds().to_numpy()
    s = pd.Series(d[ok], index=pd.to_datetime(ts[ok], unit="s"))
    sm = s.rolling(f"{max(smoothing_s, 1e-3)}s", center=True, min_periods=1).mean().to_numpy()
    tv = ts[ok]
    w = np.gradient(sm, tv) if sm.size >= 2 else np.zeros_like(sm)
    dmax = np.nanmax(sm)
    deep = sm >= deep_fraction * dmax
    i_max = int(np.argmax(sm))
    stop_down = np.flatnonzero(deep & (w < vertical_speed_threshold_m_s))
    stop_up = np.flatnonzero(deep & (w > -vertical_speed_threshold_m_s))
    i_bottom = int(stop_down[0]) if stop_down.size else i_max
    i_ascent = int(stop_up[-1]) + 1 if stop_up.size else i_max + 1
    i_bottom = min(i_bottom, i_max)
    i_ascent = max(i_ascent, i_max + 1, i_bottom)
    t_bottom, t_ascent = tv[i_bottom], tv[i_ascent] if i_ascent < tv.size else np.inf
    out[ts >= t_bottom] = "bottom"
    out[ts >= t_ascent] = "ascent"
    return out


def seafloor_depth(depth_m: ArrayLike, altitude_corrected_m: ArrayLike) -> np.ndarray:
    """Seafloor depth (m, positive down) = vehicle depth + corrected altitude (paper Fig. 10); NaN where
    either is invalid."""
    return np.asarray(depth_m, dtype=np.float64) + np.asarray(altitude_corrected_m, dtype=np.float64)
