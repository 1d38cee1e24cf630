"""C_G exclusion zones (Sangekar et al. §III-B2, Figs. 12-15 and 18).

For a landing heading α the centre of gravity C_G may not enter a cell when

* the vehicle footprint centred there would cover unmapped seafloor (binary erosion of the mapped area
  by the rotated vehicle rectangle, Fig. 13b)  → :data:`UNMAPPED`;
* the slope of the plane fitted over that footprint exceeds θc (Eq. 2, Fig. 13c-d)  → :data:`SLOPE`;
* it lies within the radius d_i(h) of a protrusion of height 5 mm ≤ h ≤ h_c (Eqs. 7-8, Fig. 15,
  heading independent, Fig. 18c)  → :data:`SMALL_PROTRUSION`;
* the footprint would touch a protrusion higher than h_c (Eq. 9; binary dilation of those protrusions
  by the rotated vehicle rectangle, Fig. 18d-e)  → :data:`HIGH_PROTRUSION`.

Headings are compass-style: α is measured clockwise from +y (north) towards +x (east); the vehicle's
long axis points along (x, y) = (sin α, cos α). α and α + 180° give the same footprint.

Implementation: the erosion, the dilation and the footprint plane fit are all correlations of fixed
images with the rotated footprint B, so they are done together by FFT (``scipy.fft``): per heading one
forward transform of B and four inverse transforms, instead of a morphological pass with an ~8500-cell
structuring element (the paper's MATLAB spent 1.8 + 1.1 s per heading here). The weighted sum
``unmapped + W * high`` (W a power of two above |B|) carries both counts through one transform.
The small-protrusion zone (a union of discs of varying radius) is an exact min-plus separable pass:
a cell q is excluded iff min_p(|q - p|² - r_p²) ≤ 0.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.fft as sfft

from hadal.landing.vehicle import Vehicle

UNMAPPED = np.uint8(1)
SLOPE = np.uint8(2)
SMALL_PROTRUSION = np.uint8(4)
HIGH_PROTRUSION = np.uint8(8)
EXCLUSION_FLAGS = {"unmapped": 1, "slope": 2, "small_protrusion": 4, "high_protrusion": 8}


def default_headings_deg(step_deg: float = 5.0) -> np.ndarray:
    """Landing headings -90° .. 90° in ``step_deg`` steps (the paper: 5°, 37 headings)."""
    n = int(round(180.0 / step_deg))
    return np.linspace(-90.0, 90.0, n + 1)


def footprint_offsets(length_m: float, width_m: float, heading_deg: float, cell_m: float) -> tuple[np.ndarray, np.ndarray]:
    """Row and column offsets (cells) of the grid cells whose centres lie inside the vehicle rectangle
    (``length_m`` × ``width_m``) centred on a cell, long axis at compass heading ``heading_deg``.
    Point-symmetric by construction."""
    a = math.radians(heading_deg)
    half = 0.5 * math.hypot(length_m, width_m) / cell_m
    R = int(math.ceil(half)) + 1
    v, u = np.mgrid[-R : R + 1, -R : R + 1].astype(float)  # v = row (y) offset, u = column (x) offset
    s = (u * math.sin(a) + v * math.cos(a)) * cell_m
    t = (u * math.cos(a) - v * math.sin(a)) * cell_m
    inside = (np.abs(s) <= 0.5 * length_m + 1e-9) & (np.abs(t) <= 0.5 * width_m + 1e-9)
    rr, cc = np.nonzero(inside)
    return rr - R, cc - R


def footprint_mask(length_m: float, width_m: float, heading_deg: float, cell_m: float) -> np.ndarray:
    """Boolean, odd-sized, centred structuring element of the rotated vehicle rectangle."""
    rr, cc = footprint_offsets(length_m, width_m, heading_deg, cell_m)
    R = int(max(np.abs(rr).max(), np.abs(cc).max()))
    out = np.zeros((2 * R + 1, 2 * R + 1), bool)
    out[rr + R, cc + R] = True
    return out


def small_protrusion_exclusion(radius_px: np.ndarray) -> np.ndarray:
    """Union of discs: True where some cell p with finite ``radius_px[p]`` (cells) has |q - p| ≤ r_p.

    Exact via a separable min-plus transform D(q) = min_p(|q-p|² - r_p²) restricted to offsets up to
    max r (larger offsets can never give D ≤ 0)."""
    r = np.asarray(radius_px, dtype=float)
    have = np.isfinite(r)
    if not have.any():
        return np.zeros(r.shape, bool)
    big = 1e12
    f = np.where(have, -(np.where(have, r, 0.0) ** 2), big)
    R = int(math.floor(np.nanmax(r)))
    g = f.copy()
    for d in range(1, R + 1):
        np.minimum(g[:, d:], f[:, :-d] + d * d, out=g[:, d:])
        np.minimum(g[:, :-d], f[:, d:] + d * d, out=g[:, :-d])
    h = g.copy()
    for d in range(1, R + 1):
        np.minimum(h[d:, :], g[:-d, :] + d * d, out=h[d:, :])
        np.minimum(h[:-d, :], g[d:, :] + d * d, out=h[:-d, :])
    return h <= 1e-9


def small_protrusion_exclusion_reference(radius_px: np.ndarray) -> np.ndarray:
    """Naive reference for :func:`small_protrusion_exclusion` (loop over protrusion cells)."""
    r = np.asarray(radius_px, dtype=float)
    out = np.zeros(r.shape, bool)
    Y, X = np.mgrid[0 : r.shape[0], 0 : r.shape[1]]
    for i, j in zip(*np.nonzero(np.isfinite(r)), strict=False):
        out |= (Y - i) ** 2 + (X - j) ** 2 <= r[i, j] ** 2 + 1e-9
    return out


@dataclass
class HeadingMaps:
    """Per-heading results of :meth:`HeadingCorrelator.compute` (all on the input grid)."""

    heading_deg: float
    offsets: tuple[np.ndarray, np.ndarray]  # footprint row/col offsets
    unmapped: np.ndarray  # bool: footprint would cover unmapped cells (C_G may not enter, Fig. 13b)
    high: np.ndarray  # bool: footprint would touch a protrusion h > h_c (Fig. 18e)
    slope_deg: np.ndarray  # footprint plane slope (deg), NaN where not computed (Fig. 13c)


class HeadingCorrelator:
    """Precomputes the FFTs of the fixed images once per submap; :meth:`compute` gives one heading.

    ``z``: elevation (m), NaN unmapped; ``high``: bool map of protrusions higher than h_c;
    ``static_excluded``: cells excluded whatever the heading (small protrusions) — the footprint slope is
    only evaluated where some cell could still be landable.

    The correlations run in single precision (twice as fast; counts are thresholded at 0.5 and the
    plane-fit sums Σuz, Σvz have no cancellation because the global plane is removed first — the tests
    compare against a float64 ``np.linalg.lstsq`` reference to 0.05°).
    """

    def __init__(self, z: np.ndarray, cell_m: float, vehicle: Vehicle, high: np.ndarray,
                 static_excluded: np.ndarray | None = None, fft_workers: int = 1):
        self.cell_m = float(cell_m)
        self.vehicle = vehicle
        self.workers = fft_workers
        z = np.asarray(z, dtype=float)
        ny, nx = z.shape
        self.shape = (ny, nx)
        valid = np.isfinite(z)
        R = int(math.ceil(0.5 * vehicle.diagonal_m / cell_m)) + 1
        # circular correlation: an output cell reads p + o, |o| <= R; one padding band of R cells after the
        # image serves both sides without aliasing (indices -R..-1 wrap to F-R..F-1 >= n)
        self.fshape = (sfft.next_fast_len(ny + R + 1, real=True), sfft.next_fast_len(nx + R + 1, real=True))
        # remove a global least-squares plane so the sums stay small (precision); added back later
        Y, X = np.mgrid[0:ny, 0:nx].astype(float)
        Y -= ny / 2.0
        X -= nx / 2.0
        A = np.column_stack([np.ones(valid.sum()), X[valid], Y[valid]])
        coef = np.linalg.lstsq(A, z[valid], rcond=None)[0] if valid.sum() >= 3 else np.array([0.0, 0.0, 0.0])
        self.plane = coef  # elevation = c + gx * X + gy * Y (X, Y in cells from the centre)
        z0 = np.where(valid, z - (coef[0] + coef[1] * X + coef[2] * Y), 0.0)
        self.high_any = bool(np.any(high))
        self.static = np.zeros(z.shape, bool) if static_excluded is None else np.asarray(static_excluded, bool)
        fs = self.fshape

        def tr(img: np.ndarray, fill: float = 0.0) -> np.ndarray:
            buf = np.full(fs, fill, dtype=np.float32)
            buf[:ny, :nx] = img
            return sfft.rfft2(buf, workers=self.workers)

        self.F_z = tr(z0)
        self.F_u = tr(~valid, fill=1.0)  # outside the grid counts as unmapped
        self.F_h = tr(np.asarray(high, bool)) if self.high_any else None

    def _kernel_spectrum(self, rr: np.ndarray, cc: np.ndarray, w: np.ndarray) -> np.ndarray:
        kern = np.zeros(self.fshape, np.float32)
        kern[rr % self.fshape[0], cc % self.fshape[1]] = w  # centred at the (wrapped) origin
        return sfft.rfft2(kern, workers=self.workers)

    def _corr(self, F: np.ndarray, FKc: np.ndarray) -> np.ndarray:
        """Correlation Σ_o img(p + o) K(o) = irfft(F_img · conj(F_K)); ``FKc`` is conj(F_K)."""
        ny, nx = self.shape
        return sfft.irfft2(F * FKc, s=self.fshape, workers=self.workers, overwrite_x=True)[:ny, :nx]

    def compute(self, heading_deg: float, need_slope: bool | None = None) -> HeadingMaps:
        """Footprint erosion/dilation and plane-fit slope for one heading. ``need_slope``: None = only
        where some cell is still landable after the boundary and protrusion exclusions; True = always."""
        v = self.vehicle
        rr, cc = footprint_offsets(v.length_m, v.width_m, heading_deg, self.cell_m)
        u = cc.astype(np.float32)
        w = rr.astype(np.float32)
        # B is point-symmetric (real spectrum), uB antisymmetric (imaginary spectrum): one transform gives both
        F1 = self._kernel_spectrum(rr, cc, 1.0 + u)
        FB = F1.real.astype(np.complex64)  # real spectrum: its own conjugate
        FuBc = (-1j * F1.imag).astype(np.complex64)  # conj of the imaginary spectrum of uB
        unmapped = self._corr(self.F_u, FB) > 0.5
        high = self._corr(self.F_h, FB) > 0.5 if self.high_any else np.zeros(self.shape, bool)
        slope = np.full(self.shape, np.nan, np.float32)
        if need_slope or (need_slope is None and np.any(~(unmapped | high | self.static))):
            FvB = self._kernel_spectrum(rr, cc, w)
            s_uz = self._corr(self.F_z, FuBc)
            s_vz = self._corr(self.F_z, np.conj(FvB))
            uu = float(np.sum(cc.astype(float) ** 2))
            vv = float(np.sum(rr.astype(float) ** 2))
            uv = float(np.sum(cc.astype(float) * rr))
            # single precision (the sums are small: the global plane was removed); gradient in m per cell
            det = uu * vv - uv * uv
            a = s_uz * np.float32(vv / det) - s_vz * np.float32(uv / det) + np.float32(self.plane[1])
            b = s_vz * np.float32(uu / det) - s_uz * np.float32(uv / det) + np.float32(self.plane[2])
            np.hypot(a, b, out=a)
            a *= np.float32(1.0 / self.cell_m)
            slope = np.degrees(np.arctan(a, out=a), out=a)
            slope[unmapped] = np.nan
        return HeadingMaps(heading_deg, (rr, cc), unmapped, high, slope)
