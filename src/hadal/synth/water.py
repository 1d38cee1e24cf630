"""True water column of the sample dive: a western-Pacific (Mariana Trench) T/S profile in TEOS-10.

The profile is defined as practical salinity SP(p) and potential temperature theta(p) (reference 0 dbar)
on anchor points (PCHIP between them), shaped after western tropical Pacific climatology: a ~29 °C
mixed layer with the salty North Pacific Tropical Water below it (SP ~34.85 at 150 dbar), a
thermocline, the fresher intermediate water near 500-700 dbar, theta ~1.2 °C at 4000 dbar and
~1.0 °C in the trench. In-situ temperature follows from TEOS-10 (gsw.t_from_CT) and therefore
rises adiabatically below ~4500 dbar to ~2.5 °C at the bottom, as Haidou's CTD recorded (TERCOM
paper Fig. 8). Conductivity comes from gsw.C_from_SP.

Depth <-> pressure is the TEOS-10 relation with the dynamic height anomaly of this same profile
(gsw.z_from_p / gsw.p_from_z with geo_strf_dyn_height, p_ref = 0) on a 1 dbar grid; this is the
ground truth that the pipeline's hydrostatic depth integration ([TERCOM Eqs. 11-14]) is tested against.
This module must not use hadal.seawater / hadal.depth (the code under test).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import gsw
import numpy as np
from scipy.interpolate import PchipInterpolator

#: (pressure dbar, practical salinity) anchor points.
_SP_ANCHORS = np.array([
    (0, 34.30), (40, 34.31), (80, 34.45), (120, 34.72), (160, 34.86), (220, 34.78), (300, 34.62),
    (450, 34.42), (600, 34.36), (800, 34.40), (1000, 34.46), (1500, 34.56), (2000, 34.62),
    (3000, 34.665), (4000, 34.685), (5000, 34.692), (7000, 34.697), (12000, 34.700),
])
#: (pressure dbar, potential temperature °C) anchor points.
_PT_ANCHORS = np.array([
    (0, 29.40), (40, 29.30), (70, 28.70), (100, 26.50), (130, 23.00), (170, 19.00), (220, 15.50),
    (300, 11.80), (400, 9.20), (550, 7.00), (800, 4.90), (1000, 4.00), (1500, 2.65), (2000, 2.00),
    (3000, 1.45), (4000, 1.20), (5000, 1.08), (6000, 1.03), (8000, 1.005), (12000, 1.000),
])

#: Pressure grid of the depth <-> pressure table (dbar).
P_MAX_DBAR = 12000.0
P_STEP_DBAR = 1.0


@dataclass(frozen=True)
class WaterColumn:
    """The true water column at ``latitude_deg``/``longitude_deg``, functions of pressure."""

    latitude_deg: float
    longitude_deg: float

    @cached_property
    def _sp(self) -> PchipInterpolator:
        return PchipInterpolator(_SP_ANCHORS[:, 0], _SP_ANCHORS[:, 1])

    @cached_property
    def _pt(self) -> PchipInterpolator:
        return PchipInterpolator(_PT_ANCHORS[:, 0], _PT_ANCHORS[:, 1])

    def state(self, pressure_dbar, heave_dbar=0.0) -> dict[str, np.ndarray]:
        """SP, SA, CT, in-situ t (ITS-90), conductivity (S/m) and sound speed at ``pressure_dbar``.

        ``heave_dbar`` displaces the T/S structure vertically (internal waves): the water found at p is
        the mean-profile water of p + heave.
        """
        p = np.clip(np.asarray(pressure_dbar, float), 0.0, P_MAX_DBAR)
        pe = np.clip(p + heave_dbar, 0.0, P_MAX_DBAR)
        sp = self._sp(pe)
        pt = self._pt(pe)
        sa = gsw.SA_from_SP(sp, p, self.longitude_deg, self.latitude_deg)
        ct = gsw.CT_from_pt(sa, pt)
        t = gsw.t_from_CT(sa, ct, p)
        c_s_m = gsw.C_from_SP(sp, t, p) / 10.0  # mS/cm -> S/m
        return {"SP": sp, "SA": sa, "CT": ct, "t": t, "pt": pt, "C_S_m": c_s_m,
                "sound_speed_m_s": gsw.sound_speed(sa, ct, p)}

    @cached_property
    def table(self) -> dict[str, np.ndarray]:
        """Pressure grid (dbar), dynamic height anomaly (m^2/s^2, p_ref 0) and TEOS-10 depth (m, positive down)."""
        p = np.arange(0.0, P_MAX_DBAR + P_STEP_DBAR / 2, P_STEP_DBAR)
        s = self.state(p)
        dh = gsw.geo_strf_dyn_height(s["SA"], s["CT"], p, p_ref=0)
        depth = -gsw.z_from_p(p, self.latitude_deg, geo_strf_dyn_height=dh)
        if not np.all(np.diff(depth) > 0):
            raise RuntimeError("synth water column: depth is not monotonic in pressure")
        return {"p": p, "dyn_height": dh, "depth": depth}

    def pressure_from_depth(self, depth_m) -> np.ndarray:
        """True sea pressure (dbar) at ``depth_m`` (m, positive down): inverse of the TEOS-10 table."""
        tab = self.table
        d = np.asarray(depth_m, float)
        return np.interp(d, tab["depth"], tab["p"])

    def depth_from_pressure(self, pressure_dbar) -> np.ndarray:
        """TEOS-10 depth (m, positive down) of ``pressure_dbar`` with this profile's dynamic height."""
        tab = self.table
        return np.interp(np.asarray(pressure_dbar, float), tab["p"], tab["depth"])

    def check_roundtrip(self, depth_m) -> float:
        """Max |depth - depth(p_from_z(...))| in metres using gsw.p_from_z directly (self-consistency check)."""
        tab = self.table
        d = np.asarray(depth_m, float)
        p = self.pressure_from_depth(d)
        dh = np.interp(p, tab["p"], tab["dyn_height"])
        p2 = gsw.p_from_z(-d, self.latitude_deg, geo_strf_dyn_height=dh)
        return float(np.max(np.abs(self.depth_from_pressure(p2) - d)))

    def summary(self, step_dbar: float = 500.0) -> list[dict]:
        """A coarse table of the true profile for truth.json."""
        p = np.arange(0.0, 11500.0, step_dbar)
        s = self.state(p)
        d = self.depth_from_pressure(p)
        return [
            {"pressure_dbar": float(p[i]), "depth_m": round(float(d[i]), 3),
             "practical_salinity": round(float(s["SP"][i]), 4),
             "temperature_its90_degc": round(float(s["t"][i]), 4),
             "potential_temperature_degc": round(float(s["pt"][i]), 4),
             "conductivity_s_m": round(float(s["C_S_m"][i]), 5),
             "sound_speed_m_s": round(float(s["sound_speed_m_s"][i]), 3)}
            for i in range(len(p))
        ]
