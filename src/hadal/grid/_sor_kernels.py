"""Compiled (numba) statistical outlier removal of :func:`hadal.grid.laser.sor_outlier_mask`: the mean distance of
every point to its ``k`` nearest neighbours (itself included, at distance 0) by an exact search of a uniform
lateral cell grid, and open3d's threshold on it.

Exactly the arithmetic of open3d's ``PointCloud::RemoveStatisticalOutliers`` (0.x, nanoflann exact k-NN): squared
distances ``((qx - px)^2 + (qy - py)^2) + (qz - pz)^2`` in float64 (nanoflann's ``L2_Adaptor`` order for 3-D
points), square roots summed in ascending order, the cloud mean and standard deviation accumulated sequentially in
point order over the points with a positive mean distance (Bessel-corrected over all points), a point kept when its
mean distance is positive and below ``mean + std_ratio * std``. Ties between equal distances do not matter: only
the multiset of the k smallest distances enters. IEEE arithmetic (no fastmath); the points' searches in parallel
blocks (numba threads), the cloud statistics sequential. Compiled on first use and cached next to this file.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange

from hadal.grid import _kernels  # noqa: F401 - sets numba's threading layer (OpenMP first) before a parallel call
from hadal.grid._cell_search import home_cell, outside_bound


@njit(inline="always")
def _insert(best, cnt, k, d2):  # pragma: no cover - compiled
    """Insert ``d2`` into the ascending ``best[:cnt]`` (capacity ``k``); returns the new count."""
    if cnt == k:
        if not d2 < best[k - 1]:
            return cnt
        j = k - 1
    else:
        j = cnt
        cnt += 1
    while j > 0 and best[j - 1] > d2:
        best[j] = best[j - 1]
        j -= 1
    best[j] = d2
    return cnt


@njit(inline="always")
def _scan(x, y, z, qx, qy, qz, j0, j1, best, cnt, k, buf):  # pragma: no cover - compiled
    """Offer the points ``j0:j1`` (contiguous: cells of one row) to ``best``; returns the new count."""
    m = j1 - j0
    for t in range(m):  # the distances first, in a loop of their own
        dx = qx - x[j0 + t]
        dy = qy - y[j0 + t]
        dz = qz - z[j0 + t]
        buf[t] = dx * dx + dy * dy + dz * dz
    for t in range(m):
        cnt = _insert(best, cnt, k, buf[t])  # rejects at once what is not below the k-th
    return cnt


@njit(inline="always")
def _mean_knn_distance_one(x, y, z, u, v, i, starts, ncu, ncv, u0, v0, cs, k, best, buf):  # pragma: no cover - compiled
    """Mean Euclidean distance of point ``i`` to its ``k`` nearest points (itself included); -1 without any (scratch:
    ``best`` of length ``k``, ``buf`` of three cells' points)."""
    qx, qy, qz = x[i], y[i], z[i]
    cu, cv = home_cell(u[i], v[i], u0, v0, cs, ncu, ncv)
    cnt = 0
    r = 0
    while True:
        lo_u, hi_u = max(cu - r, 0), min(cu + r, ncu - 1)
        for gv in range(max(cv - r, 0), min(cv + r, ncv - 1) + 1):
            row = gv * ncu
            if gv == cv - r or gv == cv + r:  # the ring's top or bottom row: all its cells
                c0 = lo_u
                while c0 <= hi_u:  # in runs of at most 3 cells (the scratch buffer's size)
                    c1 = min(c0 + 2, hi_u)
                    cnt = _scan(x, y, z, qx, qy, qz, starts[row + c0], starts[row + c1 + 1], best, cnt, k, buf)
                    c0 = c1 + 1
            else:  # an interior row: only its two end cells are new
                if cu - r >= 0:
                    cnt = _scan(x, y, z, qx, qy, qz, starts[row + cu - r], starts[row + cu - r + 1], best, cnt,
                                k, buf)
                if cu + r <= ncu - 1:
                    cnt = _scan(x, y, z, qx, qy, qz, starts[row + cu + r], starts[row + cu + r + 1], best, cnt,
                                k, buf)
        bound = outside_bound(u[i], v[i], cu, cv, r, u0, v0, cs, ncu, ncv)
        if bound == np.inf:
            break  # the block covers the whole grid
        if cnt == k and bound > 0 and best[k - 1] <= bound * bound:
            break
        r += 1
    s = 0.0
    for j in range(cnt):
        s += np.sqrt(best[j])
    return s / cnt if cnt > 0 else -1.0


@njit(parallel=True, cache=True, nogil=True)
def knn_mean_distance(x, y, z, u, v, starts, ncu, ncv, u0, v0, cs, k, out, block):  # pragma: no cover - compiled
    """``out[i]``: mean Euclidean distance of point ``i`` to its ``k`` nearest points (itself included).

    The points are sorted by lateral cell: cell ``c = cv * ncu + cu`` (``cu = floor((u - u0) / cs)``, clipped) holds
    points ``starts[c]:starts[c + 1]``; ``u``, ``v`` are the two binned coordinates (two of x, y, z). Rings of cells
    about the point's cell are searched until the k-th squared distance is no larger than the squared distance from
    the point to the searched block's edge (a lower bound of the distance of every point outside it); the cells of
    a ring's row are contiguous in memory and scanned as one run. Blocks of ``block`` points in parallel (each
    point's result is its own: the same values on any number of threads), scratch allocated once a block."""
    nbuf = max(int(np.max(np.diff(starts))), 1) * 3
    n = x.size
    for b in prange((n + block - 1) // block):
        best = np.empty(k)
        buf = np.empty(nbuf)
        for i in range(b * block, min(n, (b + 1) * block)):
            out[i] = _mean_knn_distance_one(x, y, z, u, v, i, starts, ncu, ncv, u0, v0, cs, k, best, buf)


@njit(cache=True, nogil=True)
def sor_keep(avg, std_ratio):  # pragma: no cover - compiled
    """open3d's keep rule on the mean neighbour distances ``avg`` (in point order): positive and below
    ``mean + std_ratio * std``, the mean over the positive ones divided by all points, the standard deviation
    Bessel-corrected over all points (both accumulated sequentially, as ``std::accumulate``/``inner_product``)."""
    n = avg.size
    s = 0.0
    for i in range(n):
        if avg[i] > 0:
            s += avg[i]
    mean = s / n
    sq = 0.0
    for i in range(n):
        if avg[i] > 0:
            sq += (avg[i] - mean) * (avg[i] - mean)
    thr = mean + std_ratio * np.sqrt(sq / (n - 1))
    keep = np.empty(n, np.bool_)
    for i in range(n):
        keep[i] = avg[i] > 0 and avg[i] < thr
    return keep
