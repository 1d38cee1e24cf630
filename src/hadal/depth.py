"""Vehicle depth from pressure, pressure-source fusion, seafloor depth and dive phases.

Implements §3.2.2 ([TERCOM Eqs. 11-12]) and §4.1.3 of Ma et al. (2023) *TERCOM Challenger Deep*
(``papers/tercom-challenger-deep.md``): the depth is the hydrostatic integral of the measured in situ
specific volume, ``H_i = sum h_i``, ``h_i = (p_i - p_{i-1}) / (ρ_i g_i)`` with EOS-80 density ([TERCOM Eq. 13],
:func:`hadal.seawater.density_eos80`) and gravity at the current depth ([TERCOM Eq. 14], :func:`hadal.seawater.gravity`);
the seafloor depth is the vehicle depth plus the (sound-speed corrected) altimeter range (Fig. 10).

Cross-checks: :func:`hadal.seawater.depth_fofonoff_millard` ([TERCOM Eqs. 8-10], standard ocean) and the TEOS-10
height ``gsw.z_from_p`` with the dynamic height anomaly of the measured profile (:func:`depth_teos10`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

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


#: samples per block of :func:`hydrostatic_depth` (the fixed point is solved block by block, carrying the depth)
DEPTH_BLOCK = 1 << 16


def _fill_density(rho: np.ndarray, valid: np.ndarray, good: np.ndarray) -> None:
    """Linear interpolation over the sample index, in place, of ``rho`` where the pressure is ``valid`` but
    the density is not ``good`` (edges held). Memory: one index array of the good samples."""
    bad = np.flatnonzero(valid & ~good)
    gi = np.flatnonzero(good)
    k = np.searchsorted(gi, bad)
    lo = gi[np.clip(k - 1, 0, gi.size - 1)]
    hi = gi[np.clip(k, 0, gi.size - 1)]
    span = (hi - lo).astype(np.float64)
    w = np.where(span > 0, (bad - lo) / np.where(span > 0, span, 1.0), 0.0)
    rho[bad] = rho[lo] + w * (rho[hi] - rho[lo])


def _depth_density(p: np.ndarray, salinity: ArrayLike, temperature_its90_degc: ArrayLike,
                   density_kg_m3: ArrayLike | None) -> tuple[np.ndarray, bool]:
    """``(density, owned)`` of :func:`hydrostatic_depth`: EOS-80 ([TERCOM Eq. 13]) unless passed, broadcast to
    ``p``; ``owned``: it may be changed in place (not the caller's array)."""
    if density_kg_m3 is None:
        rho = density_eos80(salinity, temperature_its90_degc, p)
        if rho.shape != p.shape:
            rho = np.broadcast_to(rho, p.shape).copy()
        owned = True
    else:
        rho = np.asarray(density_kg_m3, dtype=np.float64)
        owned = False
        if rho.shape != p.shape:
            rho, owned = np.broadcast_to(rho, p.shape).copy(), True
    return rho, owned


def _fill_density_gaps(rho: np.ndarray, owned: bool, valid: np.ndarray) -> np.ndarray:
    """``rho`` with its gaps at valid pressures filled (copied first unless ``owned``); an :class:`InputError`
    when no density is valid."""
    with np.errstate(invalid="ignore"):
        good = valid & np.isfinite(rho) & (rho > 0)
    if not good.any():
        raise InputError("hydrostatic_depth: no valid density (salinity/temperature all NaN)")
    if np.count_nonzero(good) != np.count_nonzero(valid):
        if not owned:
            rho = rho.copy()
        _fill_density(rho, valid, good)
    return rho


@dataclass(frozen=True)
class _DepthCarry:
    """(pressure, depth, 1/(ρ g)) of the last valid sample, carried from one block of :func:`hydrostatic_depth`
    to the next."""

    pressure_dbar: float
    depth_m: float
    inv_rho_g: float


def _depth_block(pv: np.ndarray, rho_g0: np.ndarray, lat_fm: Any, prev: _DepthCarry, integration: Integration,
                 tolerance_m: float, max_iterations: int) -> np.ndarray:
    """Depths of one block of valid samples by the fixed-point iteration of [TERCOM Eqs. 11-12] (``rho_g0`` =
    ρ g(φ, 0), the gravity at depth H being ``g(φ, 0)(1 + C3 H)``, [TERCOM Eq. 14]), started from the
    Fofonoff-Millard depth (latitude ``lat_fm``) and carried on from ``prev``."""
    p_prev, h_prev0, inv_prev = prev.pressure_dbar, prev.depth_m, prev.inv_rho_g
    dp_pa = np.diff(pv, prepend=p_prev)
    dp_pa *= PA_PER_DBAR
    fm_prev = float(depth_fofonoff_millard(p_prev, lat_fm if np.ndim(lat_fm) == 0 else lat_fm[0]))
    depth = depth_fofonoff_millard(pv, lat_fm) - fm_prev + h_prev0
    inv = np.empty(pv.size + 1)
    inv[0] = inv_prev
    for _ in range(max_iterations):
        if integration == "rectangle":
            hp = np.concatenate(([h_prev0], depth[:-1]))  # H_{i-1}
            hp *= GRAV_C3_PER_M
            hp += 1.0
            hp *= rho_g0
            h = np.divide(dp_pa, hp, out=hp)
        else:
            np.multiply(depth, GRAV_C3_PER_M, out=inv[1:])
            inv[1:] += 1.0
            inv[1:] *= rho_g0
            np.divide(1.0, inv[1:], out=inv[1:])
            h = inv[:-1] + inv[1:]
            h *= dp_pa
            h *= 0.5
        new = np.cumsum(h, out=h)
        new += h_prev0
        change = float(np.max(np.abs(new - depth)))
        depth = new
        if change < tolerance_m:
            break
    return depth


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
    start_depth_m: float | None = None,
) -> np.ndarray:
    """Depth (m, positive down) by integrating the hydrostatic equation along the sample series — [TERCOM Eqs. 11-12].

    ``H_i = Σ_{k<=i} h_k`` with ``h_k = Δp_k / (ρ_k g_k)``: ``Δp_k = (p_k - p_{k-1})·1e4`` Pa (sea pressure
    in dbar, 1 dbar = 1e4 Pa), ``ρ_k`` the EOS-80 in situ density ([TERCOM Eq. 13]) of the sample and ``g_k`` the gravity
    ([TERCOM Eq. 14], :func:`hadal.seawater.gravity`) **at the depth reached so far** (``H_{k-1}``), not the
    Fofonoff-Millard column-mean gravity (that would cost ~5 m at 10 000 dbar).

    * First sample: without ``start_depth_m`` the series is taken to start below the surface at ``p_0`` with
      ``h_0 = p_0 / (ρ_0 g(0))`` (the water above the first sample has the first sample's density: right for
      a record starting near the surface, ~1 % of the depth wrong for one starting at 5000 dbar). With
      ``start_depth_m`` (the depth of the first valid sample from a model of the overlying column,
      :func:`overlying_column`) the sum starts there.
    * Non-monotonic pressure (the vehicle goes up and down, hovers near the seafloor): the increments are
      signed, so the sum telescopes — going down and back up to the same pressure through the same water
      returns to the same depth.
    * NaN pressure: the sample is skipped (its depth is NaN) and the next valid sample's increment is taken
      from the last valid pressure. NaN density (e.g. a conductivity dropout) at a valid pressure: the
      density is interpolated linearly over the sample index from its valid neighbours (held at the ends).
    * ``integration="rectangle"`` is [TERCOM Eq. 12] as printed (ρ and g of the interval's end sample, g at
      ``H_{k-1}``); ``"trapezoid"`` (default) averages ``1/(ρ g)`` of the two ends of each interval, i.e.
      second-order accurate in Δp. The rectangle rule is biased shallow by ½ Σ Δp Δ(1/ρg), which grows with
      the step: at 11 000 dbar ≈ 1.5 mm for a 16 Hz CTD at 1 m/s (Δp ≈ 0.06 dbar), 1 cm at 0.5 dbar steps
      and 0.24 m at 10 dbar steps (binned casts); the trapezoid removes it (``tests/unit/ctd/test_depth.py``).

    ``g`` depends on the depth being computed, so the sum is solved by fixed-point iteration
    (``H ← H_0 + cumsum(h(g(H)))``, vectorised) started from the Fofonoff-Millard depth, block by block
    (:data:`DEPTH_BLOCK` samples, the last depth carried into the next block); the error shrinks by a factor
    ~C3·H ≈ 2.5e-3 per iteration, so 3-4 iterations reach ``tolerance_m``. The sequential recursion of
    [TERCOM Eq. 12] is the fixed point (``tests/unit/ctd/test_depth.py`` checks both agree to 1e-8 m). With the trapezoid rule
    the first interval (surface to ``p_0``) also averages ``g`` over its ends. Memory: the output, the
    density when it is not passed (and a filled copy when it has gaps), and per-block temporaries
    (``bench/bench_depth_memory.py``: <= 3x the output).

    Parameters: ``pressure_dbar`` (1-D, time order), ``salinity`` (practical), ``temperature_its90_degc``,
    ``latitude_deg`` (scalar or per sample). ``density_kg_m3`` may be passed to reuse a computed density.
    Returns the depth array (NaN where the pressure is NaN). Raises :class:`hadal.errors.InputError` when
    there is no valid density at all.
    """
    p = np.asarray(pressure_dbar, dtype=np.float64)
    if p.ndim != 1:
        raise InputError(f"hydrostatic_depth: pressure must be a 1-D series, got shape {p.shape}")
    if integration not in ("trapezoid", "rectangle"):
        raise ValueError(f"integration must be 'trapezoid' or 'rectangle', not {integration!r}")
    out = np.full(p.shape, np.nan)
    valid = np.isfinite(p)
    if not valid.any():
        return out
    rho, owned = _depth_density(p, salinity, temperature_its90_degc, density_kg_m3)
    lat = np.asarray(latitude_deg, dtype=np.float64)
    lat_arr = None if lat.ndim == 0 else np.broadcast_to(lat, p.shape)
    if not (np.isfinite(lat) if lat_arr is None else np.all(np.isfinite(lat_arr[valid]))):
        raise InputError("hydrostatic_depth: latitude is NaN/inf where pressure is valid")
    rho = _fill_density_gaps(rho, owned, valid)
    g0 = gravity(lat, 0.0)  # ρ g(φ, H) = ρ g(φ, 0) (1 + C3 H), [TERCOM Eq. 14]
    prev: _DepthCarry | None = None  # the last valid sample
    for a in range(0, p.size, DEPTH_BLOCK):
        sl = slice(a, a + DEPTH_BLOCK)
        v = valid[sl]
        if not v.any():
            continue
        pv = p[sl][v]
        rho_g0 = rho[sl][v] * (g0 if lat_arr is None else gravity(lat_arr[sl][v], 0.0))
        lv = lat if lat_arr is None else lat_arr[sl][v]
        if prev is None:
            if start_depth_m is None:  # from the surface, the first sample's density above it
                prev = _DepthCarry(0.0, 0.0, 1.0 / float(rho_g0[0]))
            else:
                h0 = float(start_depth_m)
                prev = _DepthCarry(float(pv[0]), h0, 1.0 / float(rho_g0[0] * (1.0 + GRAV_C3_PER_M * h0)))
        depth = _depth_block(pv, rho_g0, lv, prev, integration, tolerance_m, max_iterations)
        out[a:a + DEPTH_BLOCK][v] = depth
        prev = _DepthCarry(float(pv[-1]), float(depth[-1]),
                           1.0 / float(rho_g0[-1] * (1.0 + GRAV_C3_PER_M * depth[-1])))
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
    """TEOS-10 depth (m, positive down): ``-gsw.z_from_p(p, lat, ψ(p))`` (IOC et al. 2010, [TEOS-10 Eq. 3.32.3]).

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


# ------------------------------------------------------------------------ a record not starting at the surface
@dataclass(frozen=True)
class OverlyingColumn:
    """Depth of a record's first valid sample from a model of the water above it (:func:`overlying_column`)."""

    pressure_dbar: float  # first valid sample
    depth_m: float  # its depth
    method: str  # "surface", "user profile", "record profile" or "standard ocean (TEOS-10)"
    error_m: float  # estimated error of depth_m (m)
    warning: str | None

    @property
    def start_depth_m(self) -> float | None:
        """``start_depth_m`` for :func:`hydrostatic_depth` (``None`` for a record starting at the surface)."""
        return None if self.method == "surface" else self.depth_m

    def to_dict(self) -> dict[str, Any]:
        return {"first_pressure_dbar": round(self.pressure_dbar, 3), "first_depth_m": round(self.depth_m, 3),
                "method": self.method, "estimated_error_m": round(self.error_m, 3), "warning": self.warning}


def _warm_column_psi(pressure_dbar: float, latitude_deg: float) -> float:
    """Dynamic height anomaly ψ (m² s⁻², p_ref 0) at ``pressure_dbar`` of a warm tropical column, the bound the
    standard-ocean estimate is compared with: T = 3 + 28 exp(-z/600 m) °C, SP = 34.5 (warmer and fresher
    than the observed tropical Pacific, so |ψ|/g bounds the standard ocean's error there: 6.7 m at 5000 dbar,
    against 3.7 m for a Challenger-Deep-like column)."""
    import gsw

    p = np.linspace(0.0, max(float(pressure_dbar), 1.0), 400)
    z = -np.asarray(gsw.z_from_p(p, latitude_deg))
    t = 3.0 + 28.0 * np.exp(-z / 600.0)
    sa = gsw.SA_from_SP(np.full_like(p, 34.5), p, 0.0, latitude_deg)
    ct = gsw.CT_from_t(sa, t, p)
    return float(gsw.geo_strf_dyn_height(sa, ct, p, p_ref=0.0)[-1])


def _profile_depth(p_levels: np.ndarray, rho_levels: np.ndarray, p0: float, latitude_deg: float
                   ) -> tuple[float, float]:
    """(depth at ``p0``, |trapezoid - rectangle|) of a density profile by the hydrostatic integral from 0 dbar
    (the top level's density held up to the surface)."""
    pp = np.concatenate(([0.0], p_levels[p_levels < p0], [p0]))
    rr = np.concatenate((rho_levels[:1], rho_levels[p_levels < p0], [np.interp(p0, p_levels, rho_levels)]))
    d_t = hydrostatic_depth(pp, 35.0, 0.0, latitude_deg, density_kg_m3=rr)[-1]
    d_r = hydrostatic_depth(pp, 35.0, 0.0, latitude_deg, density_kg_m3=rr, integration="rectangle")[-1]
    return float(d_t), float(abs(d_t - d_r))


@dataclass(frozen=True)
class UserProfile:
    """A user-supplied profile of the water above a record (:func:`read_overlying_profile`): strictly
    increasing ``pressure_dbar`` from near the surface and the in situ ``density_kg_m3`` at each level."""

    pressure_dbar: np.ndarray
    density_kg_m3: np.ndarray
    source: str  #: the file
    basis: str  #: where the density comes from
    columns: dict[str, str]  #: variable -> the file's column used
    sha256: str = ""
    conversions: tuple[dict[str, Any], ...] = ()

    def to_dict(self) -> dict[str, Any]:
        return {"file": self.source, "sha256": self.sha256, "levels": int(self.pressure_dbar.size),
                "pressure_range_dbar": [round(float(self.pressure_dbar[0]), 3), round(float(self.pressure_dbar[-1]), 3)],
                "density_from": self.basis, "columns": dict(self.columns), "conversions": list(self.conversions)}


def overlying_column(
    pressure_dbar: ArrayLike,
    salinity: ArrayLike,
    temperature_its90_degc: ArrayLike,
    latitude_deg: float,
    *,
    density_kg_m3: ArrayLike | None = None,
    profile: tuple[ArrayLike, ArrayLike, ArrayLike] | UserProfile | None = None,
    surface_dbar: float = 20.0,
    bin_dbar: float = 10.0,
) -> OverlyingColumn:
    """The depth of a record's first valid sample when the record does not start at the surface (an upcast-only
    file, a logger started at 5000 dbar), from a documented model of the overlying water, in this order:

    1. ``surface``: the first sample is within ``surface_dbar`` of the surface: the first sample's density
       above it (:func:`hydrostatic_depth` without ``start_depth_m``; < 1 mm at 20 dbar);
    2. ``user profile``: ``profile = (pressure_dbar, practical salinity, ITS-90 temperature)`` (e.g. a cast or a
       climatology at the site) reaching within ``surface_dbar`` of the surface and down to the first sample:
       the hydrostatic integral of its EOS-80 density ([TERCOM Eqs. 11-13]). A :class:`UserProfile` (a file,
       ``derive.overlying_profile``) gives its densities directly and must cover the water above: one that does
       not reach the first sample (within ``bin_dbar``) is an :class:`InputError` naming the file, not a silent
       fall back to 3-4;
    3. ``record profile``: the record's own later samples shallower than the first one (the ascent of a dive
       whose logging started late, or the upcast itself), pressure-binned (``bin_dbar``), when they reach
       within ``surface_dbar`` of the surface: the same integral;
    4. ``standard ocean (TEOS-10)``: ``-gsw.z_from_p(p0, lat)`` (SA = 35.16504 g/kg, CT = 0 °C, dynamic height
       anomaly 0). Real water is warmer, so this is too shallow by |ψ(p0)|/g; the error is estimated with the ψ
       of a warm tropical column (:func:`_warm_column_psi`, 6.7 m at 5000 dbar) and a warning is returned.

    The estimated error of 2-3 is the trapezoid-rectangle difference of the binned integral (the integration
    error) — the water above may have changed between the profile and the record, which it does not include.
    Using the first sample's in-situ density for the whole column instead (the compressed deep water for the
    whole column) is ~1 % of the depth too shallow: -55 m at 10 950 m for a record starting at 5000 dbar
    (``tests/unit/ctd/test_depth_fusion.py``).
    """
    import gsw

    p = np.asarray(pressure_dbar, dtype=np.float64)
    rho = (density_eos80(salinity, temperature_its90_degc, p) if density_kg_m3 is None
           else np.asarray(density_kg_m3, dtype=np.float64))
    rho = np.broadcast_to(rho, p.shape)
    ok = np.isfinite(p) & np.isfinite(rho) & (rho > 0)
    if not ok.any():
        raise InputError("overlying_column: no sample with a valid pressure and density")
    i0 = int(np.flatnonzero(ok)[0])
    p0 = float(p[i0])
    g0 = float(gravity(latitude_deg, 0.0))
    if p0 <= surface_dbar:
        d0 = p0 * PA_PER_DBAR / (float(rho[i0]) * g0)
        return OverlyingColumn(p0, d0, "surface", abs(d0) * 1e-3, None)

    if profile is not None:
        if isinstance(profile, UserProfile):
            pp, pr = profile.pressure_dbar, profile.density_kg_m3
        else:
            pp, ps, pt = (np.asarray(x, dtype=np.float64) for x in profile)
            pp, ps, pt = np.broadcast_arrays(pp, ps, pt)
            pr = density_eos80(ps, pt, pp)
        m = np.isfinite(pp) & np.isfinite(pr)
        order = np.argsort(pp[m], kind="stable")
        pp, pr = pp[m][order], pr[m][order]
        covers = pp.size >= 2 and pp[0] <= surface_dbar and pp[-1] >= p0 - bin_dbar
        if not covers and isinstance(profile, UserProfile):
            raise InputError(f"{profile.source}: overlying profile covers {pp[0]:.1f} to {pp[-1]:.1f} dbar but the "
                             f"record starts at {p0:.1f} dbar: it must reach from within {surface_dbar:g} dbar of "
                             f"the surface down to the record's first sample (within {bin_dbar:g} dbar)")
        if covers:
            d0, err = _profile_depth(pp, pr, p0, latitude_deg)
            return OverlyingColumn(p0, d0, "user profile", err,
                                   f"record starts at {p0:.0f} dbar: depth of the first sample from the supplied "
                                   f"profile, {d0:.2f} m (estimated error {err:.2f} m plus any change of the "
                                   "water since the profile)")
    above = ok & (p < p0)
    if above.any() and float(np.min(p[above])) <= surface_dbar:
        k = np.floor(p[above] / bin_dbar).astype(np.int64)
        cnt = np.bincount(k)
        have = cnt > 0
        lev = (np.bincount(k, weights=p[above])[have] / cnt[have])
        rb = (np.bincount(k, weights=rho[above])[have] / cnt[have])
        if lev.size >= 2 and float(np.max(np.diff(np.concatenate(([0.0], lev, [p0]))))) <= 50 * bin_dbar:
            d0, err = _profile_depth(lev, rb, p0, latitude_deg)
            return OverlyingColumn(p0, d0, "record profile", err,
                                   f"record starts at {p0:.0f} dbar: depth of the first sample from the record's own "
                                   f"shallower samples ({int(above.sum())} in {lev.size} bins), {d0:.2f} m "
                                   f"(estimated error {err:.2f} m)")
    d0 = float(-gsw.z_from_p(p0, latitude_deg))
    err = abs(_warm_column_psi(p0, latitude_deg)) / float(gsw.grav(latitude_deg, p0))
    return OverlyingColumn(p0, d0, "standard ocean (TEOS-10)", err,
                           f"record starts at {p0:.0f} dbar and no profile covers the water above: the first "
                           f"sample's depth is the TEOS-10 standard ocean's, {d0:.2f} m; estimated error up to "
                           f"+{err:.2f} m (real water is warmer: deeper); supply a profile of the site to remove it")


# ------------------------------------------------------------------- the user's overlying profile (a file)
#: plausible ranges of a profile's values: outside them the column's unit is wrong (sigma given as density ...)
PROFILE_VALUE_RANGES = {"pressure": (-5.0, 12_000.0, "dbar"), "temperature": (-3.0, 45.0, "degC"),
                        "salinity": (0.0, 45.0, "PSS-78"), "density": (950.0, 1100.0, "kg m-3")}
#: CSV column names (lower case) of each quantity; a name with its unit as suffix needs no unit
_PROFILE_NAMES = {
    "pressure": ("pressure", "pres", "prdm", "prsm", "sea_water_pressure"),
    "temperature": ("temperature", "temp", "t", "t090c", "sea_water_temperature"),
    "salinity": ("salinity", "sal", "sal00", "psal", "sp", "practical_salinity", "sea_water_practical_salinity"),
    "density": ("density", "rho", "density00", "sea_water_density"),
}
_PROFILE_SUFFIXED = {"pressure_dbar": ("pressure", "dbar"), "temperature_its90_degc": ("temperature", "degC_its90"),
                     "temperature_its68_degc": ("temperature", "degC_its68"), "density_kg_m3": ("density", "kg/m3")}
_SALINITY_UNITS = ("", "1", "psu", "pss-78", "pss78", "pss", "practical")
_DENSITY_UNITS = {"kg/m3": 1.0, "kgm-3": 1.0, "kg/m^3": 1.0, "kg/m**3": 1.0, "g/cm3": 1000.0, "g/cm^3": 1000.0,
                  "g/ml": 1000.0, "density,kg/m^3": 1.0}
_HEADER_RE = re.compile(r"^\s*(.*?)\s*(?:[\[(]\s*([^\])]*?)\s*[\])])?\s*$")


def _csv_profile_columns(path: Path) -> tuple[dict[str, tuple[str, np.ndarray, str]], str]:
    """``{quantity: (column, values, unit)}`` of a CSV profile (header ``name``, ``name [unit]``, ``name (unit)``
    or hadal's ``pressure_dbar`` / ``temperature_its90_degc`` / ``practical_salinity`` / ``density_kg_m3``),
    read with hadal's CSV machinery (:mod:`hadal.ingest.csv_reader`: compression, encodings, ``#`` preamble)."""
    from hadal.formats import text_encoding_of
    from hadal.ingest.csv_reader import _csv_chunks, _leading_comments, csv_head, describe_csv

    head, compression = csv_head(path, "overlying profile CSV")
    delim = describe_csv(path)["delimiter"]
    encoding = text_encoding_of(head)
    n_comment, _, _ = _leading_comments(head, encoding)
    frame = next(_csv_chunks(path, delim, compression, encoding="utf-8-sig" if encoding == "utf-8" else encoding,
                             **({"skiprows": n_comment} if n_comment else {})))
    found: dict[str, tuple[str, np.ndarray, str]] = {}
    for raw in frame.columns:
        col = str(raw).strip()
        m = _HEADER_RE.match(col)
        name, unit = (m.group(1).lower(), m.group(2)) if m else (col.lower(), None)
        if name in _PROFILE_SUFFIXED and unit is None:
            qty, unit = _PROFILE_SUFFIXED[name]
        else:
            qty = next((q for q, names in _PROFILE_NAMES.items() if name in names), None)
        if qty is None or qty in found:
            continue
        if unit is None and qty != "salinity":
            raise InputError(f"{path}: column {col!r} has no unit: write it as '{qty} [unit]' or name it "
                             f"{ {'pressure': 'pressure_dbar', 'temperature': 'temperature_its90_degc', 'density': 'density_kg_m3'}[qty]}")
        text = frame[raw].astype(str).str.strip()
        empty = text.isin(["", "nan", "NaN", "NA"])
        vals = pd.to_numeric(text.where(~empty, None), errors="coerce").to_numpy(np.float64)
        bad = np.flatnonzero(np.isnan(vals) & ~empty.to_numpy())
        if bad.size:
            raise InputError(f"{path}: column {col!r} row {int(bad[0]) + 1} is not a number ({text.iloc[bad[0]][:20]!r})")
        found[qty] = (col, vals, unit or "")
    return found, "csv"


def _cnv_profile_columns(path: Path, max_bytes: float | None = None
                         ) -> tuple[dict[str, tuple[str, np.ndarray, str]], str]:
    """``{quantity: (column, values, unit)}`` of a Sea-Bird cast (:func:`hadal.ingest.cnv.read_seabird`, against the
    memory budget ``max_bytes``): pressure, temperature, salinity (``sal00``, else from conductivity) and density
    (``density00``)."""
    from hadal.ingest.cnv import CNV_CONDUCTIVITY, CNV_PRESSURE, CNV_TEMPERATURE, read_seabird
    from hadal.ingest.units import convert

    df = read_seabird(path, max_bytes=max_bytes)
    found: dict[str, tuple[str, np.ndarray, str]] = {}
    for qty, table in (("pressure", CNV_PRESSURE), ("temperature", CNV_TEMPERATURE)):
        col = next(((c, u) for c, u in table if c in df.columns), None)
        if col is not None:
            found[qty] = (col[0], df[col[0]].to_numpy(np.float64), col[1])
    sal = next((c for c in ("sal00", "sal11") if c in df.columns), None)
    if sal is not None:
        found["salinity"] = (sal, df[sal].to_numpy(np.float64), "")
    elif {"pressure", "temperature"} <= set(found):
        cc = next(((c, u) for c, u in CNV_CONDUCTIVITY if c in df.columns), None)
        if cc is not None:  # PSS-78 from the conductivity (as the record's own salinity)
            from hadal.seawater import practical_salinity

            c, _ = convert(df[cc[0]].to_numpy(np.float64), cc[1], "conductivity_s_m")
            p, _ = convert(found["pressure"][1], found["pressure"][2], "pressure_ctd_dbar")
            t, _ = convert(found["temperature"][1], found["temperature"][2], "temperature_its90_degc")
            found["salinity"] = (f"PSS-78 of {cc[0]}", practical_salinity(c, t, p), "")
    rho = next((c for c in ("density00", "density11") if c in df.columns), None)
    if rho is not None:
        found["density"] = (rho, df[rho].to_numpy(np.float64), "kg/m3")
    return found, "cnv"


def _profile_file_columns(path: Path, max_bytes: float | None = None
                          ) -> tuple[dict[str, tuple[str, np.ndarray, str]], str, bool]:
    """``(found columns, format, use temperature + salinity)`` of a user's overlying profile file (steps of
    :func:`read_overlying_profile`: the file exists, is a CSV or a Sea-Bird cast, has pressure and either
    temperature + salinity or density)."""
    from hadal.errors import ConfigError
    from hadal.formats import KINDS, detect

    if not path.is_file():
        raise ConfigError(f"{path}: derive.overlying_profile does not exist (a path relative to the dive's raw "
                          "directory, or absolute)")
    kind = detect(path, strict=False).kind
    if kind in ("cnv", "seabird_hex"):
        found, fmt = _cnv_profile_columns(path, max_bytes)
    elif kind in ("csv", "xyz"):
        found, fmt = _csv_profile_columns(path)
    else:
        raise InputError(f"{path}: overlying profile is a {KINDS.get(kind, kind)}, not a CSV or Sea-Bird .cnv profile")
    have = ", ".join(f"{q}: {c}" for q, (c, _, _) in found.items()) or "none recognised"
    if "pressure" not in found:
        raise InputError(f"{path}: overlying profile has no pressure column (pressure_dbar, 'pressure [dbar]', "
                         f"prDM; found {have})")
    use_ts = "temperature" in found and "salinity" in found
    if not use_ts and "density" not in found:
        raise InputError(f"{path}: overlying profile needs temperature and practical salinity, or density "
                         f"(found {have})")
    return found, fmt, use_ts


def _profile_values(path: Path, found: dict[str, tuple[str, np.ndarray, str]], use_ts: bool
                    ) -> tuple[dict[str, np.ndarray], list[dict[str, Any]]]:
    """``({quantity: values in hadal's units}, unit conversions)`` of a profile's columns, each unit and
    :data:`PROFILE_VALUE_RANGES` checked."""
    from hadal.errors import ConfigError
    from hadal.ingest.units import convert

    conversions: list[dict[str, Any]] = []
    values: dict[str, np.ndarray] = {}
    for qty, var in (("pressure", "pressure_ctd_dbar"), ("temperature", "temperature_its90_degc")):
        if qty in found and (qty == "pressure" or use_ts):
            col, v, unit = found[qty]
            try:
                values[qty], rec = convert(v, unit, var)
            except ConfigError as exc:
                raise InputError(f"{path}: column {col!r}: wrong unit for {qty} ({exc})") from None
            if rec:
                conversions.append({**rec, "source": col})
    if use_ts:
        col, v, unit = found["salinity"]
        if unit.strip().lower() not in _SALINITY_UNITS:
            raise InputError(f"{path}: column {col!r}: unit {unit!r} is not practical salinity (PSS-78, unitless; "
                             "absolute salinity in g/kg is not accepted)")
        values["salinity"] = v
    else:
        col, v, unit = found["density"]
        key = unit.replace(" ", "").lower()
        if key not in _DENSITY_UNITS:
            raise InputError(f"{path}: column {col!r}: unit {unit!r} is not a density (kg/m3 or g/cm3; sigma-t or "
                             "sigma-theta anomalies are not accepted)")
        values["density"] = v * _DENSITY_UNITS[key]
    for qty, v in values.items():
        lo, hi, u = PROFILE_VALUE_RANGES[qty]
        fin = v[np.isfinite(v)]
        if fin.size and (fin.min() < lo or fin.max() > hi):
            col = found[qty][0]
            raise InputError(f"{path}: column {col!r}: {qty} from {fin.min():.4g} to {fin.max():.4g} {u} is outside "
                             f"{lo:g} to {hi:g} {u}: wrong unit?")
    return values, conversions


def _monotonic_pressure(path: Path, pressure: np.ndarray) -> tuple[np.ndarray, np.ndarray, float]:
    """``(finite pressures, their mask, +1 increasing / -1 decreasing)``; an :class:`InputError` for fewer than
    2 or a pressure that is not strictly monotonic."""
    keep = np.isfinite(pressure)
    p = pressure[keep]
    if p.size < 2:
        raise InputError(f"{path}: overlying profile has {p.size} row(s) with a pressure: need at least 2")
    d = np.diff(p)
    sign = 1.0 if d[0] > 0 else -1.0
    bad = np.flatnonzero(~(sign * d > 0))
    if bad.size:
        i = int(bad[0]) + 1
        raise InputError(f"{path}: pressure is not strictly monotonic ({p[i]:.2f} dbar after {p[i - 1]:.2f} dbar, "
                         f"level {i + 1}): give one binned cast (e.g. SeaSoft BinAvg output), not a record with "
                         "loops or repeats")
    return p, keep, sign


def _file_sha256(path: Path) -> str:
    import hashlib

    h = hashlib.sha256()
    with path.open("rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def read_overlying_profile(path: str | Path, *, surface_dbar: float = 20.0,
                           max_bytes: float | None = None) -> UserProfile:
    """Read and check a user's profile of the water above a record (``derive.overlying_profile``): a CSV or a
    Sea-Bird .cnv (.hex) with pressure and temperature + practical salinity, or in situ density.

    The density is EOS-80 ([TERCOM Eq. 13], as the record's) of the temperature and salinity when the file has both, else
    its density column. Each mistake is a one-line error naming the file: a missing file (:class:`ConfigError`,
    the setting points at nothing), an unreadable file, a missing column, a unit that is not one of the quantity
    (or no unit), values outside :data:`PROFILE_VALUE_RANGES` (a wrong unit: sigma for density, kPa for dbar),
    a pressure that is not strictly monotonic (a record with loops, not one binned cast), or that starts deeper
    than ``surface_dbar`` (:class:`InputError`). Whether it reaches the record's first sample is checked by
    :func:`overlying_column`. A Sea-Bird file is read against the memory budget ``max_bytes`` (the derive stage's
    ``resources.max_memory_gb``; default :func:`hadal.budget.memory_limit_bytes`); a CSV's first chunk only."""
    path = Path(path)
    found, fmt, use_ts = _profile_file_columns(path, max_bytes)
    values, conversions = _profile_values(path, found, use_ts)
    p, keep, sign = _monotonic_pressure(path, values["pressure"])
    if use_ts:
        rho = density_eos80(values["salinity"][keep], values["temperature"][keep], p)
        basis = f"EOS-80 density (Eq. 13) of {found['temperature'][0]} and {found['salinity'][0]}"
        cols = {"pressure_dbar": found["pressure"][0], "temperature_its90_degc": found["temperature"][0],
                "practical_salinity": found["salinity"][0]}
    else:
        rho = values["density"][keep]
        basis = f"density column {found['density'][0]}"
        cols = {"pressure_dbar": found["pressure"][0], "density_kg_m3": found["density"][0]}
    ok = np.isfinite(rho)
    if sign < 0:
        p, rho = p[::-1], rho[::-1]
        ok = ok[::-1]
    p, rho = p[ok], rho[ok]
    if p.size < 2:
        raise InputError(f"{path}: overlying profile has fewer than 2 levels with a valid density")
    if p[0] > surface_dbar:
        raise InputError(f"{path}: overlying profile starts at {p[0]:.1f} dbar, deeper than "
                         f"derive.surface_start_dbar ({surface_dbar:g} dbar): it must reach the surface")
    return UserProfile(np.ascontiguousarray(p), np.ascontiguousarray(rho), str(path), f"{basis} ({fmt})", cols,
                       _file_sha256(path), tuple(conversions))

# ---------------------------------------------------------------------------------- pressure fusion
@dataclass(frozen=True)
class PressureFusion:
    """Result of :func:`fuse_pressure` (all pressures in dbar)."""

    pressure_dbar: np.ndarray
    source: np.ndarray  # object array of "ctd" / "gauge" / "blend" / "" (no pressure)
    gauge_bias_dbar: float  # fitted offset a of gauge = a + b * ctd (the gauge-CTD difference at 0 dbar)
    bias_samples: int  # overlap samples used for the fit
    bias_mad_dbar: float  # robust spread (1.4826 MAD) of the fit residual on the overlap
    n_ctd: int  # samples where the (corrected) CTD is used alone
    n_gauge: int  # samples where the gauge is used alone
    gauge_gain: float = 1.0  # fitted gain b of gauge = a + b * ctd
    fit_method: str = "none"
    fit_rms_dbar: float = float("nan")  # RMS of the fit residual (after removing divergent samples)
    lag_s: float = 0.0  # the gauge lags the CTD by this (s); removed by shifting the gauge
    lag_note: str = "no time base: lag not estimated"
    saturation_dbar: float = float("nan")  # CTD pressure from which it is not used (detected or nominal)
    saturation_method: str = "nominal range"
    divergent_samples: int = 0  # overlap samples where |gauge - fit(ctd)| exceeds the divergence limit
    divergence_limit_dbar: float = float("nan")
    n_blend: int = 0
    blend_dbar: float = 0.0
    switch_points: tuple[dict[str, Any], ...] = ()

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready summary for the product metadata (no arrays)."""
        def r(x: float, n: int = 6) -> float | None:
            return None if x is None or not np.isfinite(x) else round(float(x), n)

        return {"fit_method": self.fit_method, "gain": r(self.gauge_gain, 9), "offset_dbar": r(self.gauge_bias_dbar, 4),
                "fit_samples": self.bias_samples, "residual_mad_dbar": r(self.bias_mad_dbar, 4),
                "residual_rms_dbar": r(self.fit_rms_dbar, 4), "lag_s": r(self.lag_s, 3), "lag_note": self.lag_note,
                "ctd_saturation_dbar": r(self.saturation_dbar, 3), "saturation_method": self.saturation_method,
                "divergent_samples": self.divergent_samples, "divergence_limit_dbar": r(self.divergence_limit_dbar, 3),
                "blend_dbar": self.blend_dbar, "samples": {"ctd": self.n_ctd, "gauge": self.n_gauge,
                                                           "blend": self.n_blend},
                "switch_points": list(self.switch_points)}


#: most overlap samples the robust fit uses (evenly spaced subsample beyond that)
FIT_MAX_SAMPLES = 200_000


def _robust_linear_fit(x: np.ndarray, y: np.ndarray, columns: int) -> tuple[np.ndarray, float]:
    """Huber M-estimate of ``y = X @ beta`` (``X`` = ``[1, x_1, ...]``, ``x`` of shape (n, columns-1)) with
    ``scipy.optimize.least_squares(loss="huber")``, the Huber scale 1.345 x the robust (MAD) spread of the
    starting residual (Huber 1964; Holland & Welsch 1977). The start is the Theil-Sen line
    (``scipy.stats.theilslopes``, Sen 1968) for one regressor, least squares otherwise.
    Returns ``(beta, residual MAD spread)``."""

    from scipy.optimize import least_squares

    xm = np.column_stack([np.ones(y.size), x.reshape(y.size, columns - 1)])
    scale = np.max(np.abs(xm), axis=0)
    scale[scale == 0] = 1.0
    xs = xm / scale  # conditioned columns
    if columns == 2:  # start from Theil-Sen (breakdown point 29 %): a clipped CTD cannot drag the start
        from scipy.stats import theilslopes

        sub = _subsample(np.arange(y.size), 1500)
        slope, icpt = theilslopes(y[sub], xm[sub, 1])[:2]
        beta0 = np.array([icpt, slope]) * scale
    else:
        beta0 = np.linalg.lstsq(xs, y, rcond=None)[0]
    r0 = y - xs @ beta0
    mad = 1.4826 * float(np.median(np.abs(r0 - np.median(r0))))
    f_scale = 1.345 * max(mad, 1e-6)
    res = least_squares(lambda b: xs @ b - y, beta0, jac=lambda b: xs, loss="huber", f_scale=f_scale,
                        method="trf", x_scale="jac")
    beta = res.x / scale
    r = y - xm @ beta
    return beta, 1.4826 * float(np.median(np.abs(r - np.median(r))))


def _subsample(idx: np.ndarray, n: int = FIT_MAX_SAMPLES) -> np.ndarray:
    return idx if idx.size <= n else idx[np.linspace(0, idx.size - 1, n).astype(np.int64)]


def _velocity_dbar_s(p: np.ndarray, t: np.ndarray, ok: np.ndarray, window_s: float) -> np.ndarray:
    """dp/dt (dbar/s) of ``p`` where ``ok``, from a centred ``window_s`` moving mean (NaN elsewhere)."""
    v = np.full(p.size, np.nan)
    idx = np.flatnonzero(ok)
    if idx.size < 3:
        return v
    s = pd.Series(p[idx], index=pd.to_datetime(t[idx], unit="s"))
    sm = s.rolling(f"{max(window_s, 1e-3)}s", center=True, min_periods=1).mean().to_numpy()
    v[idx] = np.gradient(sm, t[idx])
    return v


def _fusion_inputs(pressure_ctd_dbar: ArrayLike, pressure_gauge_dbar: ArrayLike, time_s: ArrayLike | None,
                   ctd_ok: ArrayLike | None, gauge_ok: ArrayLike | None, datum: str, fit: str
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray | None]:
    """Checked inputs of :func:`fuse_pressure`: ``(ctd, gauge, ctd valid, gauge valid, time or None)`` (a time
    base of the wrong length or with non-finite values is dropped)."""
    pc = np.asarray(pressure_ctd_dbar, dtype=np.float64)
    pg_raw = np.asarray(pressure_gauge_dbar, dtype=np.float64)
    if pc.shape != pg_raw.shape:
        raise InputError(f"fuse_pressure: CTD and gauge series differ in length ({pc.size} vs {pg_raw.size})")
    if datum not in ("gauge", "ctd"):
        raise ValueError(f"datum must be 'gauge' or 'ctd', not {datum!r}")
    if fit not in ("gain_offset", "offset"):
        raise ValueError(f"fit must be 'gain_offset' or 'offset', not {fit!r}")
    n = pc.size
    cok = np.isfinite(pc) & (np.ones(n, bool) if ctd_ok is None else np.asarray(ctd_ok, bool))
    gok = np.isfinite(pg_raw) & (np.ones(n, bool) if gauge_ok is None else np.asarray(gauge_ok, bool))
    t = None if time_s is None else np.asarray(time_s, dtype=np.float64)
    if t is not None and (t.shape != pc.shape or not np.all(np.isfinite(t))):
        t = None
    return pc, pg_raw, cok, gok, t


def _flat_line_saturation(pc: np.ndarray, pg_raw: np.ndarray, cok: np.ndarray, gok: np.ndarray,
                          ctd_saturation_dbar: float, flat_tolerance_dbar: float, min_flat_samples: int
                          ) -> tuple[float, str]:
    """Step 3a of :func:`fuse_pressure`: ``(saturation, method)`` from the nominal range, lowered to the CTD's
    clipping value where it reads a flat line at its top while the gauge moves."""
    sat, sat_method = float(ctd_saturation_dbar), "nominal range"
    if cok.any():
        top = float(np.max(pc[cok]))
        flat = cok & (pc >= top - flat_tolerance_dbar)
        if flat.sum() >= min_flat_samples and (gok & flat).any():
            g_flat = pg_raw[gok & flat]
            if float(g_flat.max() - g_flat.min()) > max(1.0, 20 * flat_tolerance_dbar) and top < sat:
                sat, sat_method = top - flat_tolerance_dbar, f"flat line at {top:.3f} dbar (CTD clipping)"
    return sat, sat_method


@dataclass(frozen=True)
class _OverlapFit:
    """The overlap selection and the gain/offset fit of :func:`fuse_pressure` (steps 1-2)."""

    pc: np.ndarray
    bias_window_dbar: tuple[float, float]
    min_bias_samples: int
    fit: str

    def overlap(self, usable: np.ndarray, gok: np.ndarray, excl: np.ndarray) -> np.ndarray:
        """Indices of the overlap (both valid, not ``excl``) inside the bias window (all of it when too few)."""
        pc = self.pc
        both = usable & gok & ~excl
        win = both & (pc >= self.bias_window_dbar[0]) & (pc <= self.bias_window_dbar[1])
        return np.flatnonzero(win if win.sum() >= self.min_bias_samples else both)

    def line(self, idx: np.ndarray, gauge: np.ndarray) -> tuple[float, float, float]:
        """``(a, b, MAD spread)`` of ``gauge = a + b · ctd`` on ``idx`` (median offset with ``b = 1`` when
        ``fit="offset"`` or the overlap is too small or too flat)."""
        pc = self.pc
        if idx.size == 0:
            return 0.0, 1.0, float("nan")
        d = gauge[idx] - pc[idx]
        if self.fit == "offset" or idx.size < max(self.min_bias_samples, 3) or np.ptp(pc[idx]) < 1.0:
            off = float(np.median(d))
            return off, 1.0, 1.4826 * float(np.median(np.abs(d - off)))
        beta, s = _robust_linear_fit(pc[idx], gauge[idx], 2)
        return float(beta[0]), float(beta[1]), s


def _estimate_lag(of: _OverlapFit, pg_raw: np.ndarray, t: np.ndarray, usable: np.ndarray, gok: np.ndarray,
                  gross: np.ndarray, velocity_window_s: float, max_lag_s: float
                  ) -> tuple[np.ndarray, float, str, np.ndarray]:
    """Step 1 of :func:`fuse_pressure`: ``(shifted gauge, lag, note, gauge valid)`` by the robust regression of
    gauge - ctd on the CTD's vertical speed, refined on the shifted gauge."""
    pc, n = of.pc, of.pc.size
    pg = pg_raw
    lag = 0.0
    w = _velocity_dbar_s(pc, t, usable, velocity_window_s)
    idx = _subsample(of.overlap(usable, gok, ~np.isfinite(w) | gross))
    if idx.size >= 10 and np.std(w[idx]) > 0.05:
        total = 0.0
        for _ in range(3):
            idx = idx[np.isfinite(pg[idx])]
            if idx.size < 10:
                break
            beta, _s = _robust_linear_fit(np.column_stack([pc[idx], w[idx]]), pg[idx] - pc[idx], 3)
            step = -float(beta[2]) / (1.0 + float(beta[1]))
            total = float(np.clip(total + step, -max_lag_s, max_lag_s))
            gi = np.flatnonzero(gok)
            pg = np.full(n, np.nan)
            pg[gi] = np.interp(t[gi] + total, t[gi], pg_raw[gi], left=np.nan, right=np.nan)
            if abs(step) < 1e-3:
                break
        lag = total
        lag_note = ("estimated by robust regression of gauge - ctd on the CTD's vertical speed; the gauge "
                    f"is shifted by {lag:+.3f} s")
        gok = gok & np.isfinite(pg)
    else:
        lag_note = "vertical speed does not vary enough on the overlap to separate lag from offset: lag 0"
    return pg, lag, lag_note, gok


@dataclass
class _Fit:
    """The fit of :func:`fuse_pressure` after steps 2 and 3b (``gauge = a + b · ctd``) and the saturation."""

    a: float = 0.0
    b: float = 1.0
    mad: float = float("nan")
    rms: float = float("nan")
    n_fit: int = 0
    method: str = "none"
    divergent: np.ndarray | None = None
    div_limit: float = float("nan")
    sat: float = float("nan")
    sat_method: str = ""


def _fit_with_divergence(of: _OverlapFit, pg: np.ndarray, usable: np.ndarray, gok: np.ndarray, gross: np.ndarray,
                         res: _Fit, *, divergence_sigma: float, divergence_floor_dbar: float, min_flat_samples: int,
                         saturation_margin_dbar: float) -> None:
    """Steps 2 and 3b of :func:`fuse_pressure`, in place on ``res`` (and ``usable``): the fit on the overlap, the
    saturation lowered where the CTD diverges from the gauge at the top of its range, the fit redone without
    the divergent samples."""
    pc = of.pc
    idx = of.overlap(usable, gok, gross)
    if not idx.size:
        return
    res.a, res.b, res.mad = of.line(_subsample(idx), pg)
    res.method = "huber gain+offset" if of.fit == "gain_offset" and res.b != 1.0 else "median offset"
    # --- 3b. divergence from the gauge (the CTD reading low at the top of its range: saturation)
    both = usable & gok
    r = np.where(both, pg - (res.a + res.b * pc), 0.0)
    res.div_limit = max(divergence_sigma * (res.mad if np.isfinite(res.mad) else 0.0), divergence_floor_dbar)
    divergent = both & (np.abs(r) > res.div_limit)
    res.divergent = divergent
    # the lowest CTD pressure from which >= 90 % of the overlap samples above it read low by more than
    # the limit (divergence that persists to the top of the CTD's range, not an isolated spike)
    bi = np.flatnonzero(both)
    order = bi[np.argsort(pc[bi], kind="stable")[::-1]]
    low = (divergent & (r > 0))[order]
    frac = np.cumsum(low) / np.arange(1, order.size + 1)
    ok_top = np.flatnonzero((frac >= 0.9) & low & (np.arange(order.size) + 1 >= min_flat_samples))
    if ok_top.size and low[:min_flat_samples].all():
        new_sat = float(pc[order[ok_top[-1]]])
        if new_sat < res.sat:
            res.sat, res.sat_method = new_sat, f"divergence from the gauge from {new_sat:.3f} dbar"
            usable &= pc < res.sat - saturation_margin_dbar
    if divergent.any():
        idx = of.overlap(usable, gok, divergent)
        if idx.size:
            res.a, res.b, res.mad = of.line(_subsample(idx), pg)
    res.n_fit = int(idx.size)
    rr = pg[idx] - (res.a + res.b * pc[idx])
    res.rms = float(np.sqrt(np.mean(rr ** 2))) if rr.size else float("nan")


def _blend_series(pc: np.ndarray, pg: np.ndarray, usable: np.ndarray, gok: np.ndarray, res: _Fit,
                  saturation_margin_dbar: float, blend_dbar: float, datum: str
                  ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Step 4 of :func:`fuse_pressure`: ``(fused, source, ctd on the datum, gauge on the datum)``, crossing over
    linearly (weights in gauge pressure) over ``blend_dbar`` below the switch pressure."""
    a, b = res.a, res.b
    ctd_on_gauge = a + b * pc
    p_switch_g = a + b * (res.sat - saturation_margin_dbar)
    wgt = np.where(usable, 1.0, 0.0)
    both = usable & gok
    if blend_dbar > 0 and both.any():
        wgt[both] = np.clip((p_switch_g - pg[both]) / blend_dbar, 0.0, 1.0)
    wgt[usable & ~gok] = 1.0
    if datum == "gauge":
        c_val, g_val = ctd_on_gauge, pg
    else:
        c_val, g_val = pc, (pg - a) / b
    fused = np.where(wgt >= 1.0, c_val, np.where(wgt <= 0.0, g_val, wgt * c_val + (1.0 - wgt) * g_val))
    has_g = gok
    fused = np.where(usable | has_g, fused, np.nan)
    source = np.full(pc.size, "", dtype=object)
    source[(wgt >= 1.0) & usable] = "ctd"
    source[(wgt <= 0.0) & has_g] = "gauge"
    source[(wgt > 0.0) & (wgt < 1.0)] = "blend"
    return fused, source, c_val, g_val


def _switch_points(fused: np.ndarray, source: np.ndarray, c_val: np.ndarray, g_val: np.ndarray,
                   usable: np.ndarray, has_g: np.ndarray, max_switch_points: int) -> list[dict[str, Any]]:
    """Where the source changes between ctd and gauge (through a blend or not), at most ``max_switch_points``."""
    switches: list[dict[str, Any]] = []
    lab = np.where(source == "ctd", 1, np.where(source == "gauge", 2, np.where(source == "blend", 3, 0)))
    seen = np.flatnonzero(lab > 0)
    if seen.size > 1:
        ch = seen[1:][lab[seen[1:]] != lab[seen[:-1]]]
        for i in ch[:max_switch_points]:
            j = seen[np.searchsorted(seen, i) - 1]
            step = float(c_val[i] - g_val[i]) if usable[i] and has_g[i] else float("nan")
            switches.append({"index": int(i), "pressure_dbar": round(float(fused[i]), 3),
                             "from": str(source[j]), "to": str(source[i]),
                             "ctd_minus_gauge_dbar": None if not np.isfinite(step) else round(step, 4)})
    return switches


def fuse_pressure(
    pressure_ctd_dbar: ArrayLike,
    pressure_gauge_dbar: ArrayLike,
    *,
    time_s: ArrayLike | None = None,
    ctd_ok: ArrayLike | None = None,
    gauge_ok: ArrayLike | None = None,
    ctd_saturation_dbar: float = 10_500.0,
    saturation_margin_dbar: float = 5.0,
    bias_window_dbar: tuple[float, float] = (-100.0, 10_400.0),
    min_bias_samples: int = 20,
    datum: Literal["gauge", "ctd"] = "gauge",
    fit: Literal["gain_offset", "offset"] = "gain_offset",
    blend_dbar: float = 20.0,
    estimate_lag: bool = True,
    max_lag_s: float = 30.0,
    velocity_window_s: float = 10.0,
    flat_tolerance_dbar: float = 0.05,
    min_flat_samples: int = 5,
    divergence_sigma: float = 8.0,
    divergence_floor_dbar: float = 2.0,
    max_switch_points: int = 20,
) -> PressureFusion:
    """Fuse the CTD (SBE49, 0-10 500 dbar, ±0.1 %FS) and high-range gauge (Keller PA-33X, 0-12 000 dbar,
    0.01 %FS) pressures into one continuous series (paper §3.2.1, Tables 2-3).

    1. **Lag** (``time_s`` given, ``estimate_lag``): the gauge reading at ``t`` is the CTD's at ``t - τ``:
       ``gauge - ctd ≈ a' + (b-1) ctd - b τ dp/dt`` to first order, so ``τ`` is the robust regression
       coefficient of the difference on the CTD's vertical speed (moving mean over ``velocity_window_s``),
       refined once on the shifted gauge; the gauge is then shifted by ``τ`` (linear interpolation in time).
       It needs the speed to vary over the overlap (descent and ascent); otherwise ``τ = 0`` and ``lag_note``
       says why. ``|τ| <= max_lag_s``.
    2. **Gain and offset** (``fit="gain_offset"``): ``gauge = a + b · ctd`` by a Huber M-estimator
       (:func:`_robust_linear_fit`, ``scipy.optimize.least_squares``) over the overlap where both are valid
       and the CTD reads inside ``bias_window_dbar`` (the whole overlap when fewer than ``min_bias_samples``);
       ``fit="offset"``: ``b = 1`` and ``a`` the median difference (the previous behaviour). A CTD gain error
       of 5e-4 costs 5 dbar at 10 000 dbar, which a median offset turns into ~4 dbar at the surface and a
       jump where the source switches (``tests/unit/ctd/test_depth_fusion.py``).
    3. **Saturation from the data**, not only ``ctd_saturation_dbar``: a *flat line* at the CTD's top
       (``>= min_flat_samples`` samples within ``flat_tolerance_dbar`` of its maximum while the gauge moves
       by more than 1 dbar) or *divergence* from the gauge at the top of the CTD's range (residual of the fit
       above ``max(divergence_sigma · σ, divergence_floor_dbar)``, the CTD reading low) lowers the
       saturation pressure to the CTD's clipping value; the CTD is not used from ``saturation - margin`` up.
       The fit is redone without the divergent samples.
    4. **Continuity**: on the gauge's datum (default; the more accurate sensor, 0.01 %FS) the CTD is mapped
       with ``a + b · ctd``; below the switch pressure the series crosses over linearly from the corrected CTD
       to the gauge over ``blend_dbar`` (weights in gauge pressure), so it has no step at the switch.
       ``datum="ctd"``: the gauge is mapped onto the CTD with ``(gauge - a) / b`` instead.

    The fit, its residual, the lag, the saturation found and the switch points (sample index, pressure,
    from/to, the step the blend removed) are in the result (:meth:`PressureFusion.to_dict`).
    """
    pc, pg_raw, cok, gok, t = _fusion_inputs(pressure_ctd_dbar, pressure_gauge_dbar, time_s, ctd_ok, gauge_ok,
                                             datum, fit)
    n = pc.size
    # --- 3a. saturation: nominal range, then a flat line at the CTD's top
    sat, sat_method = _flat_line_saturation(pc, pg_raw, cok, gok, ctd_saturation_dbar, flat_tolerance_dbar,
                                            min_flat_samples)
    usable = cok & (pc < sat - saturation_margin_dbar)

    # --- 1. lag and 2. fit on the overlap
    pg = pg_raw
    lag, lag_note = 0.0, "no time base: lag not estimated" if t is None else "not estimated"
    of = _OverlapFit(pc, bias_window_dbar, min_bias_samples, fit)
    gross = np.zeros(n, bool)  # far off a first robust line (a clipped CTD): kept out of the lag regression
    idx0 = of.overlap(usable, gok, gross)
    if idx0.size >= max(min_bias_samples, 3) and fit == "gain_offset" and np.ptp(pc[idx0]) >= 1.0:
        a0, b0, s0 = of.line(_subsample(idx0), pg)
        gross = usable & gok & (np.abs(pg - (a0 + b0 * pc)) > max(divergence_sigma * s0, divergence_floor_dbar))
    if t is not None and estimate_lag and (usable & gok).sum() >= max(min_bias_samples, 10):
        pg, lag, lag_note, gok = _estimate_lag(of, pg_raw, t, usable, gok, gross, velocity_window_s, max_lag_s)

    res = _Fit(sat=sat, sat_method=sat_method)
    _fit_with_divergence(of, pg, usable, gok, gross, res, divergence_sigma=divergence_sigma,
                         divergence_floor_dbar=divergence_floor_dbar, min_flat_samples=min_flat_samples,
                         saturation_margin_dbar=saturation_margin_dbar)
    divergent = np.zeros(n, bool) if res.divergent is None else res.divergent

    # --- 4. continuous series on one datum, crossing over below the switch pressure
    fused, source, c_val, g_val = _blend_series(pc, pg, usable, gok, res, saturation_margin_dbar, blend_dbar, datum)
    switches = _switch_points(fused, source, c_val, g_val, usable, gok, max_switch_points)
    return PressureFusion(
        fused, source, float(res.a), res.n_fit, float(res.mad), int((source == "ctd").sum()),
        int((source == "gauge").sum()), gauge_gain=float(res.b), fit_method=res.method, fit_rms_dbar=res.rms,
        lag_s=float(lag), lag_note=lag_note, saturation_dbar=float(res.sat), saturation_method=res.sat_method,
        divergent_samples=int(divergent.sum()), divergence_limit_dbar=res.div_limit,
        n_blend=int((source == "blend").sum()), blend_dbar=float(blend_dbar), switch_points=tuple(switches))

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
    # a pandas column of datetimes stays one: np.asarray of a tz-aware one is an object array of Timestamps
    # (0.9 s for the sample dive's 567 k samples, parsed back by to_datetime)
    pandas_times = isinstance(time, (pd.Series, pd.Index)) and not pd.api.types.is_numeric_dtype(time.dtype)
    tarr = None if pandas_times else np.asarray(time)
    d = np.asarray(depth_m, dtype=np.float64)
    n = d.size
    out = np.full(n, "descent", dtype=object)
    ok = np.isfinite(d)
    if n == 0 or not ok.any():
        return out
    if tarr is not None and tarr.dtype.kind in "iuf":  # seconds
        ts = tarr.astype(np.float64) - float(tarr[0])
    else:
        t = pd.Series(pd.to_datetime(time if tarr is None else pd.Series(tarr), utc=True))
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
