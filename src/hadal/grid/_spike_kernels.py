"""Compiled (numba) inner loop of :func:`hadal.grid.multibeam.knn_spike_mask`: per sounding, the robust plane
through its nearest neighbours and the spike test, exactly the steps of the NumPy reference
:func:`hadal.grid.multibeam.knn_spike_mask_reference` (weighted least-squares plane with the same tiny ridge,
two passes dropping neighbours beyond ``3 max(1.4826 MAD, floor)``, then ``k max(1.4826 median |kept
residual|, floor)``), one sounding at a time in registers instead of ``(chunk, neighbours)`` temporaries.
IEEE arithmetic (no fastmath): it differs from the reference only by summation order and by solving the
3 x 3 normal equations with Gaussian elimination (partial pivoting, as LAPACK's ``gesv``). Compiled on first
use and cached next to this file.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from hadal.grid._kernels import _sort_small


@njit(inline="always")
def _median_sorted_prefix(a, n):  # pragma: no cover - compiled
    """Median of ``a[:n]`` (sorted in place by :func:`hadal.grid._kernels._sort_small`); NaN if ``n == 0``."""
    if n == 0:
        return np.nan
    _sort_small(a[:n])
    h = n // 2
    if n % 2 == 1:
        return a[h]
    return (a[h - 1] + a[h]) / 2.0


@njit(inline="always")
def _plane(dx, dy, v, w, nb):  # pragma: no cover - compiled
    """``(c0, c1, c2)`` of the weighted least-squares plane ``v = c0 + c1 dx + c2 dy`` (ridge as the reference)."""
    s1 = sx = sy = sxx = syy = sxy = r0 = r1 = r2 = 0.0
    for q in range(nb):
        wq = w[q]
        a = dx[q]
        b = dy[q]
        s1 += wq
        sx += wq * a
        sy += wq * b
        sxx += wq * a * a
        syy += wq * b * b
        sxy += wq * a * b
        r0 += wq * v[q]
        r1 += wq * v[q] * a
        r2 += wq * v[q] * b
    ridge = 1e-6 * (sxx + syy) / max(s1, 1.0) + 1e-12
    m = np.empty((3, 4))
    m[0, 0], m[0, 1], m[0, 2], m[0, 3] = s1, sx, sy, r0
    m[1, 0], m[1, 1], m[1, 2], m[1, 3] = sx, sxx + ridge, sxy, r1
    m[2, 0], m[2, 1], m[2, 2], m[2, 3] = sy, sxy, syy + ridge, r2
    for c in range(3):  # Gaussian elimination with partial pivoting
        p = c
        for r in range(c + 1, 3):
            if abs(m[r, c]) > abs(m[p, c]):
                p = r
        if p != c:
            for k in range(4):
                t = m[c, k]
                m[c, k] = m[p, k]
                m[p, k] = t
        for r in range(c + 1, 3):
            f = m[r, c] / m[c, c]
            for k in range(c, 4):
                m[r, k] -= f * m[c, k]
    c2 = m[2, 3] / m[2, 2]
    c1 = (m[1, 3] - m[1, 2] * c2) / m[1, 1]
    c0 = (m[0, 3] - m[0, 1] * c1 - m[0, 2] * c2) / m[0, 0]
    return c0, c1, c2


@njit(parallel=True, cache=True, nogil=True)
def knn_spike_flags(x, y, z, s0, nbr, k, floor, mad_to_sigma, out):  # pragma: no cover - compiled
    """``out[s0 + i]`` for every row ``i`` of ``nbr`` (the neighbour indices of sounding ``s0 + i``, itself
    excluded): True where the sounding is a spike (:func:`hadal.grid.multibeam.knn_spike_mask_reference`)."""
    m, nb = nbr.shape
    for i in prange(m):
        p = s0 + i
        dx = np.empty(nb)
        dy = np.empty(nb)
        v = np.empty(nb)
        w = np.ones(nb)
        res = np.empty(nb)
        tmp = np.empty(nb)
        for q in range(nb):
            jq = nbr[i, q]
            dx[q] = x[jq] - x[p]
            dy[q] = y[jq] - y[p]
            v[q] = z[jq]
        c0 = 0.0
        for _ in range(2):
            c0, c1, c2 = _plane(dx, dy, v, w, nb)
            for q in range(nb):
                res[q] = v[q] - (c0 + c1 * dx[q] + c2 * dy[q])
                tmp[q] = abs(res[q])
            mad = mad_to_sigma * _median_sorted_prefix(tmp, nb)
            thr = 3.0 * max(mad, floor)
            for q in range(nb):
                w[q] = 1.0 if abs(res[q]) <= thr else 0.0
        n_kept = 0
        for q in range(nb):
            if w[q] > 0.0:
                tmp[n_kept] = abs(res[q])
                n_kept += 1
        scale = mad_to_sigma * _median_sorted_prefix(tmp, n_kept)
        if not np.isfinite(scale):
            scale = floor
        scale = max(scale, floor)
        out[p] = abs(z[p] - c0) > k * scale
