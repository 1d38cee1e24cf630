"""Straightforward reference implementations of the landing analysis, for the tests and benches only (not shipped):
a direct per-cell plane fit, a loop over protrusion discs, and the reference C++ implementation's disc-mean height."""

from __future__ import annotations

import numpy as np


def footprint_slope_reference_deg(
    z: np.ndarray, cell_m: float, footprint: np.ndarray, cells: np.ndarray
) -> np.ndarray:
    """Straightforward reference: for each (row, col) in ``cells`` fit z = c + a x + b y by
    ``np.linalg.lstsq`` over the mapped cells under the boolean ``footprint`` (odd-sized, centred)
    and return the slope in degrees (NaN where fewer than 3 mapped cells)."""
    z = np.asarray(z, dtype=float)
    ky, kx = footprint.shape
    oy, ox = np.nonzero(footprint)
    oy = oy - ky // 2
    ox = ox - kx // 2
    out = np.full(len(cells), np.nan)
    for k, (r, c) in enumerate(np.asarray(cells)):
        rr, cc = r + oy, c + ox
        inside = (rr >= 0) & (rr < z.shape[0]) & (cc >= 0) & (cc < z.shape[1])
        zz = z[rr[inside], cc[inside]]
        ok = np.isfinite(zz)
        if ok.sum() < 3:
            continue
        A = np.column_stack([np.ones(ok.sum()), ox[inside][ok] * cell_m, oy[inside][ok] * cell_m])
        coef = np.linalg.lstsq(A, zz[ok], rcond=None)[0]
        out[k] = np.degrees(np.arctan(np.hypot(coef[1], coef[2])))
    return out


def small_protrusion_exclusion_reference(radius_px: np.ndarray) -> np.ndarray:
    """Naive reference for :func:`hadal.landing.exclusion.small_protrusion_exclusion` (loop over protrusion
    cells)."""
    r = np.asarray(radius_px, dtype=float)
    out = np.zeros(r.shape, bool)
    Y, X = np.mgrid[0 : r.shape[0], 0 : r.shape[1]]
    for i, j in zip(*np.nonzero(np.isfinite(r)), strict=False):
        out |= (Y - i) ** 2 + (X - j) ** 2 <= r[i, j] ** 2 + 1e-9
    return out


def disc_mean_height_map(z: np.ndarray, cell_m: float, diagonal_m: float) -> np.ndarray:
    """The reference C++ implementation's height (for comparison only): z minus the mean of the mapped
    cells over a disc of diameter ``diagonal_m``."""
    from scipy.signal import fftconvolve

    z = np.asarray(z, float)
    v = np.isfinite(z)
    r = int(round(0.5 * diagonal_m / cell_m))
    yy, xx = np.mgrid[-r : r + 1, -r : r + 1]
    disc = (yy**2 + xx**2 <= r * r).astype(float)
    z0 = np.where(v, z - np.nanmean(z), 0.0)
    s = fftconvolve(z0, disc, mode="same")
    n = fftconvolve(v.astype(float), disc, mode="same")
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(v, z0 - s / np.maximum(n, 1e-9), np.nan)
