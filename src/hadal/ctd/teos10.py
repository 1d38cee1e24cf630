"""TEOS-10 quantities next to the EOS-80 ones (IOC, SCOR and IAPSO 2010; McDougall & Barker 2011, the GSW
toolbox), computed with ``gsw``:

* Absolute Salinity ``SA`` (g/kg): ``gsw.SA_from_SP`` (with the Absolute Salinity Anomaly atlas at the cast's
  position), Conservative Temperature ``CT``: ``gsw.CT_from_t``, potential temperature (reference 0 dbar):
  ``gsw.pt0_from_t``, potential density anomaly ``sigma0`` (0 dbar): ``gsw.sigma0``;
* N² (buoyancy frequency squared, s⁻²): ``gsw.Nsquared`` on a binned cast (pressure increasing), at the
  pressure mid-points, then linearly interpolated to the bin centres. Per-sample N² of a vehicle record is not
  meaningful (pressure is not monotonic): :func:`n_squared_at` gives each sample the N² of its binned cast at
  its pressure.
"""

from __future__ import annotations

import gsw
import numpy as np
from numpy.typing import ArrayLike


def teos10_columns(practical_salinity: ArrayLike, temperature_its90_degc: ArrayLike, pressure_dbar: ArrayLike,
                   longitude_deg: float, latitude_deg: float) -> dict[str, np.ndarray]:
    """``absolute_salinity_g_kg``, ``conservative_temperature_degc``, ``potential_temperature_degc`` and
    ``sigma0_kg_m3`` per sample (NaN where an input is NaN)."""
    sp = np.asarray(practical_salinity, dtype=np.float64)
    t = np.asarray(temperature_its90_degc, dtype=np.float64)
    p = np.asarray(pressure_dbar, dtype=np.float64)
    sa = np.asarray(gsw.SA_from_SP(sp, p, longitude_deg, latitude_deg), dtype=np.float64)
    ct = np.asarray(gsw.CT_from_t(sa, t, p), dtype=np.float64)
    return {"absolute_salinity_g_kg": sa, "conservative_temperature_degc": ct,
            "potential_temperature_degc": np.asarray(gsw.pt0_from_t(sa, t, p), dtype=np.float64),
            "sigma0_kg_m3": np.asarray(gsw.sigma0(sa, ct), dtype=np.float64)}


def n_squared_profile(pressure_dbar: ArrayLike, absolute_salinity_g_kg: ArrayLike,
                      conservative_temperature_degc: ArrayLike, latitude_deg: float) -> np.ndarray:
    """N² (s⁻²) of one binned cast at its levels ``pressure_dbar`` (increasing): ``gsw.Nsquared`` between
    consecutive levels with finite SA and CT, interpolated linearly to the levels; NaN outside the first and
    last mid-point and where fewer than two levels are finite."""
    p = np.asarray(pressure_dbar, dtype=np.float64)
    sa = np.asarray(absolute_salinity_g_kg, dtype=np.float64)
    ct = np.asarray(conservative_temperature_degc, dtype=np.float64)
    out = np.full(p.size, np.nan)
    ok = np.isfinite(p) & np.isfinite(sa) & np.isfinite(ct)
    if ok.sum() < 2:
        return out
    i = np.flatnonzero(ok)
    i = i[np.argsort(p[i], kind="stable")]
    n2, p_mid = gsw.Nsquared(sa[i], ct[i], p[i], lat=np.full(i.size, float(latitude_deg)))
    n2, p_mid = np.asarray(n2, dtype=np.float64), np.asarray(p_mid, dtype=np.float64)
    good = np.isfinite(n2) & np.isfinite(p_mid)
    if good.sum() == 0:
        return out
    n2, p_mid = n2[good], p_mid[good]
    inside = (p >= p_mid[0]) & (p <= p_mid[-1])
    out[inside] = np.interp(p[inside], p_mid, n2)
    return out


def n_squared_at(pressure_dbar: ArrayLike, levels_dbar: ArrayLike, n_squared_levels: ArrayLike) -> np.ndarray:
    """N² of a binned cast (``levels_dbar``, ``n_squared_levels``) linearly interpolated to ``pressure_dbar``;
    NaN outside the cast's finite levels."""
    p = np.asarray(pressure_dbar, dtype=np.float64)
    lv = np.asarray(levels_dbar, dtype=np.float64)
    n2 = np.asarray(n_squared_levels, dtype=np.float64)
    out = np.full(p.size, np.nan)
    ok = np.isfinite(lv) & np.isfinite(n2)
    if not ok.any():
        return out
    lv, n2 = lv[ok], n2[ok]
    order = np.argsort(lv)
    lv, n2 = lv[order], n2[order]
    inside = np.isfinite(p) & (p >= lv[0]) & (p <= lv[-1])
    out[inside] = np.interp(p[inside], lv, n2)
    return out
