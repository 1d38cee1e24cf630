"""C_G exclusion zones (Sangekar et al. §III-B2, Figs. 12-15 and 18).

For a landing heading α the centre of gravity C_G may not enter a cell when

* the vehicle footprint centred there would cover unmapped seafloor (binary erosion of the mapped area
  by the rotated vehicle rectangle, Fig. 13b)  → :data:`UNMAPPED`;
* the slope of the plane fitted over that footprint exceeds θc ([Landing Eq. 2], Fig. 13c-d)  → :data:`SLOPE`;
* it lies within the radius d_i(h) of a protrusion of height 5 mm ≤ h ≤ h_c ([Landing Eqs. 7-8], Fig. 15,
  heading independent, Fig. 18c)  → :data:`SMALL_PROTRUSION`;
* the footprint would touch a protrusion higher than h_c ([Landing Eq. 9]; binary dilation of those protrusions
  by the rotated vehicle rectangle, Fig. 18d-e)  → :data:`HIGH_PROTRUSION`.

Headings are compass-style: α is measured clockwise from +y (north) towards +x (east); the vehicle's
long axis points along (x, y) = (sin α, cos α). α and α + 180° give the same footprint.

Implementation: the erosion of the mapped area and the dilation of the protrusions higher than h_c by the
rotated footprint B are exact integer operations on row runs (each row of B is one column interval, so a
run of source cells reaches an interval of every output row it touches: :mod:`hadal.landing._kernels`),
instead of a morphological pass with an ~8500-cell structuring element (the paper's MATLAB spent 1.8 + 1.1 s
per heading here). The footprint plane fit needs the correlations Σ u z and Σ v z with B: FFTs (``scipy.fft``,
single precision) in row tiles with an overlap of the footprint radius, the z spectra computed once per
submap. The small-protrusion zone (a union of discs of varying radius) is stamped exactly disc row by disc
row.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
import scipy.fft as sfft

from hadal.landing._kernels import any_free, plane_tangent, times_conj_imaginary
from hadal.landing.limits import TILE_CELLS
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

    Exact: each disc is stamped row by row as a column interval (:func:`hadal.landing._kernels.disc_union`,
    cost ∝ Σ disc diameters + cells); tests compare with a loop over the discs."""
    from hadal.landing._kernels import disc_union

    r = np.asarray(radius_px, dtype=float)
    have = np.isfinite(r)
    if not have.any():
        return np.zeros(r.shape, bool)
    ri, ci = np.nonzero(have)
    return disc_union(ri.astype(np.int64), ci.astype(np.int64), r[ri, ci], r.shape[0], r.shape[1])


@dataclass
class HeadingMaps:
    """Per-heading results of :meth:`HeadingCorrelator.compute` (all on the input grid)."""

    heading_deg: float
    offsets: tuple[np.ndarray, np.ndarray]  # footprint row/col offsets
    unmapped: np.ndarray  # bool: footprint would cover unmapped cells (C_G may not enter, Fig. 13b)
    high: np.ndarray  # bool: footprint would touch a protrusion h > h_c (Fig. 18e)
    tan_slope: np.ndarray  # float32 tangent of the footprint plane slope, NaN where not computed (Fig. 13c)

    @property
    def slope_deg(self) -> np.ndarray:
        """Footprint plane slope (deg), NaN where not computed (Fig. 13c)."""
        return np.degrees(np.arctan(self.tan_slope))

    def slope_at(self, row: int, col: int) -> float:
        return float(np.degrees(np.arctan(float(self.tan_slope[row, col]))))


def footprint_row_intervals(rr: np.ndarray, cc: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Row offsets of the footprint and, per row, its column interval [lo, hi] (the rotated rectangle is
    convex, so every row of its cells is one contiguous interval; checked)."""
    rows = np.unique(rr)
    lo = np.array([cc[rr == r].min() for r in rows], np.int64)
    hi = np.array([cc[rr == r].max() for r in rows], np.int64)
    if int(np.sum(hi - lo + 1)) != rr.size:  # pragma: no cover - a convex footprint never fails this
        raise AssertionError("footprint rows are not contiguous")
    return rows.astype(np.int64), lo, hi


class HeadingCorrelator:
    """Per-submap precomputation of the heading-dependent C_G exclusions; :meth:`compute` gives one heading.

    ``z``: elevation (m), NaN unmapped; ``high``: bool map of protrusions higher than h_c;
    ``static_excluded``: cells excluded whatever the heading (small protrusions) — the footprint slope is
    only evaluated when some cell could still be landable.

    * The erosion of the mapped area (Fig. 13b) and the dilation of the protrusions higher than h_c
      (Fig. 18e) by the rotated footprint are exact integer operations on row runs
      (:func:`hadal.landing._kernels.dilate_rows`): no FFT, cost ∝ runs × footprint rows.
    * The footprint plane fit (Fig. 13c) needs the correlations Σ u z and Σ v z with the rotated footprint:
      FFTs in single precision, in row tiles of about ``tile_cells`` cells with an overlap of the footprint
      radius R on each side (overlap-save: each tile's FFT holds its core rows plus R rows above and below,
      zero padding of R against wrap-around), so long strips are never transformed whole; the z spectra of the
      tiles are computed once and reused for every heading. Tiling changes only the float32 rounding
      (tests compare tiled and untiled maps). The plane-fit sums have no cancellation because a global plane
      is removed first; the tests compare against a float64 ``np.linalg.lstsq`` reference to 0.05°.
    """

    def __init__(self, z: np.ndarray, cell_m: float, vehicle: Vehicle, high: np.ndarray,
                 static_excluded: np.ndarray | None = None, fft_workers: int = 1, tile_cells: int = TILE_CELLS):
        from hadal.landing._kernels import row_runs  # compiled on first use

        self.cell_m = float(cell_m)
        self.vehicle = vehicle
        self.workers = fft_workers
        z = np.asarray(z, dtype=float)
        ny, nx = z.shape
        self.shape = (ny, nx)
        valid = np.isfinite(z)
        R = int(math.ceil(0.5 * vehicle.diagonal_m / cell_m)) + 1
        self.R = R
        fx = sfft.next_fast_len(nx + R + 1, real=True)
        core = max(4 * R, int(tile_cells) // fx)
        if ny <= core:
            self.tiles = [(0, ny)]
            fy = sfft.next_fast_len(ny + R + 1, real=True)
        else:
            nt = int(math.ceil(ny / core))
            core = int(math.ceil(ny / nt))
            self.tiles = [(k * core, min(ny, (k + 1) * core)) for k in range(nt)]
            fy = sfft.next_fast_len(core + 2 * R, real=True)  # overlap-save: core + R above + R below
        self.fshape = (fy, fx)
        # remove a global least-squares plane so the sums stay small (precision); added back later.
        # Normal equations from row-wise sums (no N x 3 design matrix: memory stays O(cells) in bytes)
        cy, cx = ny / 2.0, nx / 2.0
        S = np.zeros((3, 3))
        bz = np.zeros(3)
        xs = np.arange(nx, dtype=float) - cx
        for r0 in range(0, ny, 1024):
            r1 = min(ny, r0 + 1024)
            v = valid[r0:r1]
            zz = np.where(v, z[r0:r1], 0.0)
            ys = np.arange(r0, r1, dtype=float) - cy
            n_r = v.sum(axis=1).astype(float)
            sx_r = v @ xs
            sxx_r = v @ (xs * xs)
            sz_r = zz.sum(axis=1)
            sxz_r = zz @ xs
            S += np.array([[n_r.sum(), sx_r.sum(), n_r @ ys],
                           [sx_r.sum(), sxx_r.sum(), sx_r @ ys],
                           [n_r @ ys, sx_r @ ys, n_r @ (ys * ys)]])
            bz += np.array([sz_r.sum(), sxz_r.sum(), sz_r @ ys])
        coef = np.linalg.solve(S, bz) if valid.sum() >= 3 and abs(np.linalg.det(S)) > 1e-9 else np.zeros(3)
        self.plane = coef  # elevation = c + gx * X + gy * Y (X, Y in cells from the centre)
        self.high_any = bool(np.any(high))
        self.static = np.zeros(z.shape, bool) if static_excluded is None else np.asarray(static_excluded, bool)
        self._unmapped_runs = row_runs(~valid)
        self._high_runs = row_runs(np.ascontiguousarray(high, dtype=bool)) if self.high_any else None
        # z spectra of the tiles (overlap-save), reused for every heading
        self._spectra = []
        for r0, r1 in self.tiles:
            e0, e1 = max(0, r0 - R), min(ny, r1 + R)
            ys = (np.arange(e0, e1, dtype=float) - cy)[:, None]
            blk = z[e0:e1]
            buf = np.zeros(self.fshape, dtype=np.float32)
            buf[: e1 - e0, :nx] = np.where(np.isfinite(blk), blk - (coef[0] + coef[1] * xs[None, :] + coef[2] * ys), 0.0)
            self._spectra.append((e0, sfft.rfft2(buf, workers=self.workers)))

    def _kernel_spectrum(self, rr: np.ndarray, cc: np.ndarray, w: np.ndarray) -> np.ndarray:
        """rfft2 of the kernel centred at the (wrapped) origin; only its 2R + 1 rows are non-zero, so the row
        transforms are done on those rows only (rfft2 = fft over rows of rfft over columns)."""
        fy, fx = self.fshape
        R = int(np.abs(rr).max())
        kr = np.zeros((2 * R + 1, fx), np.float32)
        kr[rr + R, cc % fx] = w
        full = np.zeros((fy, fx // 2 + 1), np.complex64)
        full[np.arange(-R, R + 1) % fy] = sfft.rfft(kr, axis=1, workers=self.workers)
        return sfft.fft(full, axis=0, workers=self.workers, overwrite_x=True)

    def _dilate(self, runs, outside: bool, rows: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
        from hadal.landing._kernels import dilate_rows

        ny, nx = self.shape
        return dilate_rows(runs[0], runs[1], runs[2], ny, nx, rows, lo, hi, outside, 0, ny)

    def compute(self, heading_deg: float, need_slope: bool | None = None,
                out: np.ndarray | None = None) -> HeadingMaps:
        """Footprint erosion/dilation and plane-fit slope for one heading. ``need_slope``: None = only
        when some cell is still landable after the boundary and protrusion exclusions; True = always.
        ``out``: a float32 buffer of the grid's shape for the slope tangents (reused across headings by the
        caller; the returned maps then share it)."""
        v = self.vehicle
        ny, nx = self.shape
        rr, cc = footprint_offsets(v.length_m, v.width_m, heading_deg, self.cell_m)
        rows, lo, hi = footprint_row_intervals(rr, cc)
        unmapped = self._dilate(self._unmapped_runs, True, rows, lo, hi)
        high = self._dilate(self._high_runs, False, rows, lo, hi) if self.high_any else np.zeros(self.shape, bool)
        if need_slope or (need_slope is None and any_free(unmapped, high, self.static)):
            # every cell is written below (the tiles cover the grid)
            tan_slope = np.empty(self.shape, np.float32) if out is None else out
            u = cc.astype(np.float32)
            w = rr.astype(np.float32)
            # uB and vB are antisymmetric: purely imaginary spectra i a_u, i a_v (the real parts are rounding);
            # correlation = irfft(F_z conj(F_K))
            a_u = np.ascontiguousarray(self._kernel_spectrum(rr, cc, u).imag)
            a_v = np.ascontiguousarray(self._kernel_spectrum(rr, cc, w).imag)
            uu = float(np.sum(cc.astype(float) ** 2))
            vv = float(np.sum(rr.astype(float) ** 2))
            uv = float(np.sum(cc.astype(float) * rr))
            det = uu * vv - uv * uv
            k1, k2, k3 = np.float32(vv / det), np.float32(uv / det), np.float32(uu / det)
            gx, gy = np.float32(self.plane[1]), np.float32(self.plane[2])
            prod_u = np.empty(a_u.shape, np.complex64)
            prod_v = np.empty(a_u.shape, np.complex64)
            for (r0, r1), (e0, Fz) in zip(self.tiles, self._spectra, strict=True):
                q0, q1 = r0 - e0, r1 - e0
                times_conj_imaginary(Fz, a_u, a_v, prod_u, prod_v)
                s_uz = sfft.irfft2(prod_u, s=self.fshape, workers=self.workers, overwrite_x=True)[q0:q1, :nx]
                s_vz = sfft.irfft2(prod_v, s=self.fshape, workers=self.workers, overwrite_x=True)[q0:q1, :nx]
                # single precision (the sums are small: the global plane was removed); gradient in m per cell
                plane_tangent(s_uz, s_vz, k1, k2, k3, gx, gy, np.float32(1.0 / self.cell_m), unmapped[r0:r1],
                              tan_slope[r0:r1])
        else:
            tan_slope = np.full(self.shape, np.nan, np.float32)
        return HeadingMaps(heading_deg, (rr, cc), unmapped, high, tan_slope)
