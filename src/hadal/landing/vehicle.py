"""Landing-vehicle model of Sangekar et al., "Autonomous landing of underwater vehicles using high
resolution bathymetry", §III-B1 ([Landing Eqs. 1-9]). Defaults are the paper's Table II.

All lengths in metres, forces in newtons, angles in degrees unless the name says ``_rad``.
"""

from __future__ import annotations

import math

import numpy as np

from hadal.settings.landing import Vehicle as VehicleSettings


class Vehicle(VehicleSettings):
    """The landing vehicle of :class:`hadal.settings.landing.Vehicle` (its Table II numbers, validated there) with
    the equations of Sangekar et al. §III-B1 that use them ([Landing Eqs. 1-9])."""

    @property
    def footprint_area_m2(self) -> float:
        """A_f = l_u b_u (m²), used by the safety cost ([Landing Eq. 12])."""
        return self.length_m * self.width_m

    @property
    def diagonal_m(self) -> float:
        """Diagonal of the vehicle footprint (m); sets the low-pass cut-off of [Landing Eq. 10] (f_c = 2/σ)."""
        return math.hypot(self.length_m, self.width_m)

    # ------------------------------------------------------------------ slope ([Landing Eqs. 1-6])
    def tilt_angle_rad(self, contact_distance_m: float | np.ndarray) -> float | np.ndarray:
        """[Landing Eq. 1] / [Landing Eq. 7]: largest tilt θ = atan(d F_R / (d_m F_B - d_g F_R)) the righting moment allows
        for a contact point at distance ``d`` (m) from the C_G-C_B centre line."""
        d = np.asarray(contact_distance_m, dtype=float)
        out = np.arctan(d * self.net_force_n / self.righting_denominator_nm)
        return float(out) if out.ndim == 0 else out

    @property
    def critical_slope_deg(self) -> float:
        """[Landing Eq. 2]: θc, the steepest slope the vehicle can land on at any orientation (d_ψ = b_u/2)."""
        return math.degrees(float(self.tilt_angle_rad(0.5 * self.width_m)))

    def current_force_limit_n(self, slope_deg: float | np.ndarray, friction: float | np.ndarray) -> np.ndarray:
        """[Landing Eq. 5]: largest current force F_C ≤ (F_G - F_B)(μ cos θ - sin θ) (N) before the landed vehicle
        slides down a slope θ with friction coefficient μ ([Landing Eqs. 3-4]); negative = slides even without current."""
        th = np.radians(np.asarray(slope_deg, dtype=float))
        return self.net_force_n * (np.asarray(friction, dtype=float) * np.cos(th) - np.sin(th))

    def admissible_current_m_s(self, slope_deg: float | np.ndarray, friction: float | np.ndarray) -> np.ndarray:
        """[Landing Eq. 6]: admissible current v_c = sqrt(2 F_C / (C_d ρ l_u h_u)) (m/s); 0 where the vehicle
        slides even in still water (F_C < 0, [Landing Eq. 5])."""
        fc = np.clip(self.current_force_limit_n(slope_deg, friction), 0.0, None)
        area = self.length_m * self.height_m
        return np.sqrt(2.0 * fc / (self.drag_coefficient * self.water_density_kg_m3 * area))

    # ------------------------------------------------------------------ protrusions ([Landing Eqs. 7-9])
    def protrusion_height_limit_m(self, contact_distance_m: float | np.ndarray) -> float | np.ndarray:
        """[Landing Eq. 8]: h_i = (b_u/2 + d_i) sin θ_i, the highest protrusion at distance d_i (m) from the
        C_G-C_B centre line on which the vehicle still settles (θ_i from [Landing Eq. 7])."""
        d = np.asarray(contact_distance_m, dtype=float)
        out = (0.5 * self.width_m + d) * np.sin(self.tilt_angle_rad(d))
        return float(out) if np.ndim(out) == 0 else out

    @property
    def critical_height_m(self) -> float:
        """[Landing Eq. 9]: h_c = b_u sin θc (m); any protrusion higher than this must not touch the vehicle."""
        return self.width_m * math.sin(math.radians(self.critical_slope_deg))

    def exclusion_table(self, step_m: float = 0.005) -> tuple[np.ndarray, np.ndarray]:
        """The paper's Fig. 15: distances d (0 .. b_u/2 in ``step_m`` steps, m) and the protrusion height
        limits h(d) ([Landing Eq. 8], m). The last entry is (b_u/2, h_c)."""
        n = int(math.floor(0.5 * self.width_m / step_m + 1e-9))
        d = np.append(np.arange(n + 1) * step_m, 0.5 * self.width_m)
        d = np.unique(d)
        return d, np.asarray(self.protrusion_height_limit_m(d))

    def exclusion_distance_m(self, height_m: float | np.ndarray, step_m: float = 0.005) -> np.ndarray:
        """C_G exclusion radius (m) around a protrusion of height h ≤ h_c, from the table of Fig. 15:
        the smallest tabulated d with h(d) ≥ h (rounded up to the next ``step_m``, conservative).
        NaN for h > h_c (handled by the heading-dependent footprint exclusion) and for non-finite h."""
        d_tab, h_tab = self.exclusion_table(step_m)
        h = np.asarray(height_m, dtype=float)
        idx = np.searchsorted(h_tab, h, side="left")
        out = np.where(idx < d_tab.size, d_tab[np.minimum(idx, d_tab.size - 1)], np.nan)
        out = np.where(h > self.critical_height_m + 1e-12, np.nan, out)
        return np.where(np.isfinite(h), out, np.nan)
