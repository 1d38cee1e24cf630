"""Slope maps by least-squares plane fits (Sangekar et al. §III-B2, Figs. 13c, 16a, 18a).

* :func:`local_slope_deg` — per-cell slope of the plane fitted over a small square window, with the
  x, y, z moments summed by box filters (NaN-aware: each window uses only its mapped cells). This is the
  slope map used to find protrusion candidates (slope > θc, Fig. 16b).

The footprint-mean slope (Fig. 13c) comes from window sums by FFT correlation with the rotated vehicle
footprint (:mod:`hadal.landing.exclusion`); its direct per-cell plane fit, the tests' reference, is in
``tests/landing_reference.py``.
"""

from __future__ import annotations

import numpy as np
from scipy import ndimage as ndi


def local_slope_deg(z: np.ndarray, cell_m: float, window_px: int = 3, min_fraction: float = 0.5,
                    chunk_cells: int = 1_000_000) -> np.ndarray:
    """Slope (degrees) of the least-squares plane over a ``window_px`` window around every cell (see
    :func:`_local_slope_block`), computed in row chunks of about ``chunk_cells`` cells with a half-window
    overlap (box filters are local, so the result is identical; memory stays bounded on large grids)."""
    z = np.asarray(z, dtype=float)
    ny, nx = z.shape
    rows = max(int(window_px), chunk_cells // max(1, nx))
    if ny <= rows:
        return _local_slope_block(z, cell_m, window_px, min_fraction)
    half = int(window_px) // 2 + 1
    out = np.empty(z.shape)
    for r0 in range(0, ny, rows):
        r1 = min(ny, r0 + rows)
        a0, a1 = max(0, r0 - half), min(ny, r1 + half)
        blk = z[a0:a1]
        if np.isfinite(blk).all() and nx > 3 * half:
            out[r0:r1] = _full_window_slope(blk, cell_m, window_px)[r0 - a0 : r1 - a0]
            # windows crossing the grid edge are incomplete: the general fit there (bands of the window width)
            w3 = 3 * half
            out[r0:r1, :half] = _local_slope_block(blk[:, :w3], cell_m, window_px, min_fraction)[r0 - a0 : r1 - a0, :half]
            out[r0:r1, nx - half:] = _local_slope_block(blk[:, nx - w3:], cell_m, window_px,
                                                        min_fraction)[r0 - a0 : r1 - a0, w3 - half:]
            for e0, e1 in ((0, min(ny, w3)), (max(0, ny - w3), ny)):  # top / bottom grid edges
                lo, hi = max(r0, e0 if e0 == 0 else ny - half), min(r1, half if e0 == 0 else ny)
                if lo < hi:
                    out[lo:hi] = _local_slope_block(z[e0:e1], cell_m, window_px, min_fraction)[lo - e0 : hi - e0]
        else:
            out[r0:r1] = _local_slope_block(blk, cell_m, window_px, min_fraction)[r0 - a0 : r1 - a0]
    return out


def _full_window_slope(z: np.ndarray, cell_m: float, window_px: int) -> np.ndarray:
    """The plane-fit slope of :func:`_local_slope_block` where every window is fully mapped: with coordinates
    centred on the window Σu = Σv = Σuv = 0 and Σuu = Σvv = w Σk², so the gradient is (Σuz, Σvz) / Σuu, each a
    separable ramp x box correlation (4 one-dimensional passes instead of the 18 of the general moments). Valid
    only away from the grid edges (the caller recomputes those bands with the general fit)."""
    w = int(window_px)
    h = w // 2
    ramp = np.arange(-h, h + 1, dtype=float)
    suu = w * float(np.sum(ramp * ramp))
    zz = z - float(np.mean(z))
    a = ndi.uniform_filter1d(ndi.correlate1d(zz, ramp, axis=1, mode="constant"), w, axis=0, mode="constant")
    b = ndi.uniform_filter1d(ndi.correlate1d(zz, ramp, axis=0, mode="constant"), w, axis=1, mode="constant")
    g = np.hypot(a, b)
    g *= w / (suu * cell_m)
    return np.degrees(np.arctan(g, out=g), out=g)


def _local_slope_block(z: np.ndarray, cell_m: float, window_px: int = 3, min_fraction: float = 0.5) -> np.ndarray:
    """Slope (degrees) of the least-squares plane z = c + a x + b y fitted over a ``window_px`` square
    window around every cell. Moments Σ1, Σx, Σy, Σz, Σxx, Σxy, Σyy, Σxz, Σyz of the mapped cells are
    box-filtered (``scipy.ndimage.uniform_filter``) so the whole map costs a handful of passes; windows
    with fewer than ``min_fraction`` mapped cells, or unmapped centres, give NaN.

    ``z``: elevation (m) on a regular grid (rows = y, columns = x), NaN = unmapped; ``cell_m``: cell size (m).
    """
    z = np.asarray(z, dtype=float)
    w = int(window_px)
    if w < 2:
        raise ValueError("window_px must be >= 2")
    valid = np.isfinite(z)
    if not valid.any():
        return np.full(z.shape, np.nan)
    zref = float(np.nanmean(z))
    m = valid.astype(float)
    zz = np.where(valid, z - zref, 0.0)
    ny, nx = z.shape
    # coordinates relative to each window's centre are obtained from global index moments:
    # Σu = Σx - X n, Σuu = Σxx - 2 X Σx + X² n, ... (indices are small, float64 is exact enough)
    Y, X = np.mgrid[0:ny, 0:nx].astype(float)

    def box(a: np.ndarray) -> np.ndarray:
        return ndi.uniform_filter(a, size=w, mode="constant", cval=0.0) * (w * w)

    n = box(m)
    sx, sy, sz = box(m * X), box(m * Y), box(zz)
    sxx, syy, sxy = box(m * X * X), box(m * Y * Y), box(m * X * Y)
    sxz, syz = box(X * zz), box(Y * zz)
    with np.errstate(invalid="ignore", divide="ignore"):
        mx, my, mz = sx / n, sy / n, sz / n
        cxx = sxx / n - mx * mx
        cyy = syy / n - my * my
        cxy = sxy / n - mx * my
        cxz = sxz / n - mx * mz
        cyz = syz / n - my * mz
        det = cxx * cyy - cxy * cxy
        a = (cyy * cxz - cxy * cyz) / det
        b = (cxx * cyz - cxy * cxz) / det
        slope = np.degrees(np.arctan(np.hypot(a, b) / cell_m))
    ok = valid & (n >= min_fraction * w * w) & (det > 1e-9)
    return np.where(ok, slope, np.nan)
