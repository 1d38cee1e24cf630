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

from hadal.grid._cell_search import home_cell, outside_bound
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


@njit(inline="always")
def _spike_one(x, y, z, p, nbr, nb, k, floor, mad_to_sigma, dx, dy, v, w, res, tmp):  # pragma: no cover - compiled
    """True where sounding ``p`` is a spike on the robust plane through its neighbours ``nbr[:nb]`` (indices into
    ``x``, ``y``, ``z``; the other arguments from ``dx`` on are scratch arrays of length ``nb``)."""
    for q in range(nb):
        jq = nbr[q]
        dx[q] = x[jq] - x[p]
        dy[q] = y[jq] - y[p]
        v[q] = z[jq]
        w[q] = 1.0
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
    return abs(z[p] - c0) > k * scale


@njit(inline="always")
def _scratch(nb):  # pragma: no cover - compiled
    """The scratch arrays of :func:`_spike_one` (``dx, dy, v, w, res, tmp``), length ``nb``."""
    return np.empty(nb), np.empty(nb), np.empty(nb), np.empty(nb), np.empty(nb), np.empty(nb)


@njit(parallel=True, cache=True, nogil=True)
def knn_spike_flags(x, y, z, s0, nbr, k, floor, mad_to_sigma, out):  # pragma: no cover - compiled
    """``out[s0 + i]`` for every row ``i`` of ``nbr`` (the neighbour indices of sounding ``s0 + i``, itself
    excluded): True where the sounding is a spike (:func:`hadal.grid.multibeam.knn_spike_mask_reference`)."""
    m, nb = nbr.shape
    for i in prange(m):
        dx, dy, v, w, res, tmp = _scratch(nb)
        out[s0 + i] = _spike_one(x, y, z, s0 + i, nbr[i], nb, k, floor, mad_to_sigma, dx, dy, v, w, res, tmp)


@njit(inline="always")
def _offer(bd, bi, orig, cnt, nb, d2, j):  # pragma: no cover - compiled
    """Insert point ``j`` at squared distance ``d2`` into ``bd[:cnt]``/``bi[:cnt]`` (capacity ``nb``), kept in
    ascending ``(d2, orig[j])`` order; returns the new count."""
    oj = orig[j]
    if cnt == nb:
        if d2 > bd[nb - 1] or (d2 == bd[nb - 1] and oj > orig[bi[nb - 1]]):
            return cnt
        t = nb - 1
    else:
        t = cnt
        cnt += 1
    while t > 0 and (bd[t - 1] > d2 or (bd[t - 1] == d2 and orig[bi[t - 1]] > oj)):
        bd[t] = bd[t - 1]
        bi[t] = bi[t - 1]
        t -= 1
    bd[t] = d2
    bi[t] = j
    return cnt


@njit(inline="always")
def _knn_cells(x, y, orig, i, starts, ncu, ncv, u0, v0, cs, nb, bd, bi):  # pragma: no cover - compiled
    """The ``nb`` nearest points of point ``i`` (itself excluded; horizontal distance) into ``bi`` (indices in cell
    order) by ascending ``(squared distance, original index)``; returns how many were found (``nb`` unless the
    cloud is smaller). Rings of cells about the point's cell are scanned until the ``nb``-th squared distance is
    below the squared distance to the searched block's edge (less a rounding margin), a lower bound of every
    distance outside it: exact, ties broken by the original index."""
    qx, qy = x[i], y[i]
    cu, cv = home_cell(qx, qy, u0, v0, cs, ncu, ncv)
    cnt = 0
    r = 0
    while True:
        lo_u, hi_u = max(cu - r, 0), min(cu + r, ncu - 1)
        for gv in range(max(cv - r, 0), min(cv + r, ncv - 1) + 1):
            row = gv * ncu
            if gv == cv - r or gv == cv + r:  # the ring's top or bottom row: all its cells, one run of points
                j0, j1 = starts[row + lo_u], starts[row + hi_u + 1]
                for j in range(j0, j1):
                    if j != i:
                        ddx = qx - x[j]
                        ddy = qy - y[j]
                        cnt = _offer(bd, bi, orig, cnt, nb, ddx * ddx + ddy * ddy, j)
            else:  # an interior row: only its two end cells are new
                for c in (cu - r, cu + r):
                    if 0 <= c <= ncu - 1:
                        for j in range(starts[row + c], starts[row + c + 1]):
                            if j != i:
                                ddx = qx - x[j]
                                ddy = qy - y[j]
                                cnt = _offer(bd, bi, orig, cnt, nb, ddx * ddx + ddy * ddy, j)
        bound = outside_bound(qx, qy, cu, cv, r, u0, v0, cs, ncu, ncv)
        if bound == np.inf:
            return cnt  # the block covers the whole grid
        if cnt == nb and bound > 0 and bd[nb - 1] < bound * bound:
            return cnt
        r += 1


@njit(parallel=True, cache=True, nogil=True)
def knn_spike_flags_cells(x, y, z, orig, starts, ncu, ncv, u0, v0, cs, nb, k, floor, mad_to_sigma, out,
                          block):  # pragma: no cover - compiled
    """``out[i]`` for every sounding ``i`` of ``x``, ``y``, ``z`` sorted by cell (:class:`hadal.grid.knn_cells.
    CellOrder`; ``orig`` their original indices, the tie-break): the spike test of :func:`knn_spike_flags` on its
    ``nb`` nearest soundings found by :func:`_knn_cells` (``nb`` < the number of soundings). Blocks of ``block``
    soundings in parallel, with their scratch arrays allocated once a block."""
    n = x.size
    for b in prange((n + block - 1) // block):
        bd = np.empty(nb)
        bi = np.empty(nb, np.int64)
        dx, dy, v, w, res, tmp = _scratch(nb)
        for i in range(b * block, min(n, (b + 1) * block)):
            _knn_cells(x, y, orig, i, starts, ncu, ncv, u0, v0, cs, nb, bd, bi)
            out[i] = _spike_one(x, y, z, i, bi, nb, k, floor, mad_to_sigma, dx, dy, v, w, res, tmp)


@njit(parallel=True, cache=True, nogil=True)
def knn_spike_flags_targets(x, y, z, orig, starts, ncu, ncv, u0, v0, cs, nb, k, floor, mad_to_sigma, targets, out,
                            kd2, block):  # pragma: no cover - compiled
    """:func:`knn_spike_flags_cells` for the soundings ``targets`` only (indices in cell order; the others are
    searched as neighbours but not tested): ``out[t]`` the flag of sounding ``targets[t]`` and ``kd2[t]`` the
    squared distance of its ``nb``-th neighbour (a tile's soundings tested among the tile and its halo,
    :func:`hadal.grid.tiles.spike_flags_tiled`, which checks with ``kd2`` that no sounding beyond the halo could
    have been a neighbour)."""
    n = targets.size
    for b in prange((n + block - 1) // block):
        bd = np.empty(nb)
        bi = np.empty(nb, np.int64)
        dx, dy, v, w, res, tmp = _scratch(nb)
        for t in range(b * block, min(n, (b + 1) * block)):
            i = targets[t]
            _knn_cells(x, y, orig, i, starts, ncu, ncv, u0, v0, cs, nb, bd, bi)
            out[t] = _spike_one(x, y, z, i, bi, nb, k, floor, mad_to_sigma, dx, dy, v, w, res, tmp)
            kd2[t] = bd[nb - 1]
