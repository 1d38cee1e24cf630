"""Compiled (numba) inner loop of :func:`hadal.grid.points.cell_moments`.

One pass over the points: cell index exactly as :meth:`hadal.grid.points.GridSpec.cell_index` computes it
(``floor((x - x0) * (1 / h))``, points on the upper/right edge join the last cell, outside points counted
and skipped when ``check_inside``, clamped into the grid otherwise), then count, ``sum(z - z0)`` and
``sum((z - z0)**2)`` accumulated into one ``(cells, 3)`` array per thread, so the three sums of a cell
share a cache line. IEEE arithmetic (no fastmath): the sums differ from the ``np.bincount`` reference
only by summation order. Compiled on first use and cached next to this file.
"""

from __future__ import annotations

import numpy as np
from numba import njit, prange


@njit(parallel=True, cache=True, nogil=True)
def shifted_cell_sums(x, y, z, x0, y0, inv_h, nx, ny, z0, check_inside, nthreads):  # pragma: no cover - compiled
    n = x.size
    m = nx * ny
    acc = np.zeros((nthreads, m, 3))
    bad = np.zeros(nthreads, np.int64)
    out = np.zeros(nthreads, np.int64)
    chunk = (n + nthreads - 1) // nthreads
    for t in prange(nthreads):
        a = acc[t]
        lo = t * chunk
        hi = min(n, lo + chunk)
        nb = 0
        no = 0
        for i in range(lo, hi):
            xi = x[i]
            yi = y[i]
            zi = z[i]
            if not (np.isfinite(xi) and np.isfinite(yi) and np.isfinite(zi)):
                nb += 1
                continue
            fx = (xi - x0) * inv_h
            fy = (yi - y0) * inv_h
            if check_inside and (fx < 0.0 or fy < 0.0 or fx > nx or fy > ny):
                no += 1
                continue
            # floor + clamp in floating point before the integer conversion (any finite value is safe);
            # a point on the upper/right edge joins the last cell
            if fx >= nx:
                c = nx - 1
            elif fx < 0.0:
                c = 0
            else:
                c = int(fx)  # truncation == floor for fx >= 0
            if fy >= ny:
                r = ny - 1
            elif fy < 0.0:
                r = 0
            else:
                r = int(fy)
            k = r * nx + c
            d = zi - z0
            a[k, 0] += 1.0
            a[k, 1] += d
            a[k, 2] += d * d
        bad[t] = nb
        out[t] = no
    tot = acc[0].copy()
    for t in range(1, nthreads):
        tot += acc[t]
    return tot, bad.sum(), out.sum()
