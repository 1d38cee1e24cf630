"""Compiled (numba) inner loops of :mod:`hadal.grid.points`: the single-pass shifted sums of
:func:`~hadal.grid.points.cell_moments` and the block-partitioned statistics of
:func:`~hadal.grid.points.cell_stats` (below).

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
            keep = _keep(xi, yi, zi, x0, y0, inv_h, nx, ny, check_inside)
            if keep == 1:
                nb += 1
                continue
            if keep == 2:
                no += 1
                continue
            k = _cell_of(xi, yi, x0, y0, inv_h, nx, ny)
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


# --- Partitioned gridding (count/mean/std/median/min/max), used by hadal.grid.points.cell_stats -----------------
#
# Three passes, every one of them streaming or cache-resident (no random access into a grid-sized array):
# 1. per-thread histograms of the blocks of ``2**shift`` consecutive cells (cell index as ``shifted_cell_sums``
#    computes it; NaN/inf and outside points skipped and counted);
# 2. a stable counting sort of the points by block (prefix sums, then the cell index recomputed and the point's
#    in-block index (uint16) and value scattered to a few hundred sequential output streams) - 1 and 2 are
#    ``partition_points`` (``partition_kernel`` from given cell indices);
# 3. ``block_stats_kernel``: per block (in parallel), a counting sort by cell inside the block (its
#    histograms fit in L2), then per cell: count, mean and M2 two-pass (shifted by the cell's first value,
#    so 10 km depths with mm spread lose nothing), min/max and the median of the sorted segment.


@njit(parallel=True, cache=True, nogil=True)
def partition_kernel(k, z, shift, nblocks, nthreads):  # pragma: no cover - compiled
    """Stable counting sort of the points with ``k >= 0`` by block ``k >> shift`` (``shift <= 16``).

    Returns ``(kb uint16, zb, bstart)``: the cell indices *within their block* (``k & (2**shift - 1)``) and
    values grouped by block, block ``b`` in ``[bstart[b], bstart[b + 1])``, file order kept within a block."""
    n = k.size
    chunk = (n + nthreads - 1) // nthreads
    hist = np.zeros((nthreads, nblocks), np.int64)
    for t in prange(nthreads):
        h = hist[t]
        for i in range(t * chunk, min(n, (t + 1) * chunk)):
            kk = k[i]
            if kk >= 0:
                h[kk >> shift] += 1
    bstart, off, pos = _block_offsets(hist)
    kb = np.empty(pos, np.uint16)
    zb = np.empty(pos, np.float64)
    mask = (1 << shift) - 1
    for t in prange(nthreads):
        o = off[t]
        for i in range(t * chunk, min(n, (t + 1) * chunk)):
            kk = k[i]
            if kk >= 0:
                b = kk >> shift
                p = o[b]
                kb[p] = kk & mask
                zb[p] = z[i]
                o[b] = p + 1
    return kb, zb, bstart


@njit(cache=True, nogil=True)
def _sort_small(a):  # pragma: no cover - compiled
    """Sort ``a`` in place: insertion sort for short segments, NumPy's sort otherwise."""
    n = a.size
    if n > 24:
        a[:] = np.sort(a)
        return
    for i in range(1, n):
        v = a[i]
        j = i - 1
        while j >= 0 and a[j] > v:
            a[j + 1] = a[j]
            j -= 1
        a[j + 1] = v


@njit(parallel=True, cache=True, nogil=True)
def block_stats_kernel(kb, zb, bstart, shift, m, want_m2, want_sorted, nthreads):  # pragma: no cover - compiled
    """Per-cell ``count`` (int64), ``mean``, ``m2`` (sum of squared deviations from the mean; empty when
    not ``want_m2``) and, with ``want_sorted``, ``median``/``min``/``max``, over ``m`` cells from the
    block-partitioned points of :func:`partition_kernel` (``kb``: cell index within the block). Empty cells:
    count 0, NaN elsewhere."""
    nblocks = bstart.size - 1
    count = np.zeros(m, np.int64)
    mean = np.full(m, np.nan)
    m2 = np.full(m if want_m2 else 0, np.nan)
    ms = m if want_sorted else 0
    med = np.full(ms, np.nan)
    zmin = np.full(ms, np.nan)
    zmax = np.full(ms, np.nan)
    bs = 1 << shift
    for t in prange(nthreads):
        cnt = np.zeros(bs, np.int64)
        ref = np.zeros(bs)
        s1 = np.zeros(bs)
        s2 = np.zeros(bs)
        for b in range(t, nblocks, nthreads):
            lo = bstart[b]
            hi = bstart[b + 1]
            if hi == lo:
                continue
            base = b << shift
            sz = min(bs, m - base)
            cnt[:sz] = 0
            s1[:sz] = 0.0
            s2[:sz] = 0.0
            for p in range(lo, hi):
                j = kb[p]
                zi = zb[p]
                if cnt[j] == 0:
                    ref[j] = zi
                cnt[j] += 1
                s1[j] += zi - ref[j]
            for j in range(sz):
                c = cnt[j]
                if c > 0:
                    s1[j] = ref[j] + s1[j] / c  # now the mean
                    count[base + j] = c
                    mean[base + j] = s1[j]
            if want_m2:
                for p in range(lo, hi):
                    j = kb[p]
                    d = zb[p] - s1[j]
                    s2[j] += d * d
                for j in range(sz):
                    if cnt[j] > 0:
                        m2[base + j] = s2[j]
            if want_sorted:
                # counting sort by cell inside the block, then sort each cell's segment
                start = np.empty(sz + 1, np.int64)
                acc = 0
                for j in range(sz):
                    start[j] = acc
                    acc += cnt[j]
                start[sz] = acc
                fill = start[:sz].copy()
                buf = np.empty(hi - lo)
                for p in range(lo, hi):
                    j = kb[p]
                    buf[fill[j]] = zb[p]
                    fill[j] += 1
                for j in range(sz):
                    c = cnt[j]
                    if c == 0:
                        continue
                    a = start[j]
                    seg = buf[a:a + c]
                    _sort_small(seg)
                    med[base + j] = 0.5 * (seg[(c - 1) // 2] + seg[c // 2])
                    zmin[base + j] = seg[0]
                    zmax[base + j] = seg[c - 1]
    return count, mean, m2, med, zmin, zmax


@njit(inline="always")
def _block_offsets(hist):  # pragma: no cover - compiled
    """From per-thread block histograms ``hist`` (nthreads, nblocks): the blocks' start offsets ``bstart``
    (nblocks + 1), each thread's write offset per block ``off`` (threads in order within a block: file order
    kept) and the total count."""
    nthreads, nblocks = hist.shape
    bstart = np.zeros(nblocks + 1, np.int64)
    off = np.empty((nthreads, nblocks), np.int64)
    pos = 0
    for b in range(nblocks):
        bstart[b] = pos
        for t in range(nthreads):
            off[t, b] = pos
            pos += hist[t, b]
    bstart[nblocks] = pos
    return bstart, off, pos


@njit(inline="always")
def _cell_of(xi, yi, x0, y0, inv_h, nx, ny):  # pragma: no cover - compiled
    """Cell index of a finite point, clamped into the grid: floor and clamp in floating point before the integer
    conversion (any finite value is safe); a point on the upper/right edge joins the last cell."""
    fx = (xi - x0) * inv_h
    fy = (yi - y0) * inv_h
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
    return r * nx + c


@njit(inline="always")
def _keep(xi, yi, zi, x0, y0, inv_h, nx, ny, check_inside):  # pragma: no cover - compiled
    """0: grid the point; 1: a NaN/inf coordinate; 2: outside the grid (only with ``check_inside``)."""
    if not (np.isfinite(xi) and np.isfinite(yi) and np.isfinite(zi)):
        return 1
    if check_inside:
        fx = (xi - x0) * inv_h
        fy = (yi - y0) * inv_h
        if fx < 0.0 or fy < 0.0 or fx > nx or fy > ny:
            return 2
    return 0


@njit(parallel=True, cache=True, nogil=True)
def partition_points(x, y, z, x0, y0, inv_h, nx, ny, check_inside, shift, nblocks, nthreads):  # pragma: no cover
    """:func:`partition_kernel` straight from the points (``shift <= 16``): a first pass counts the block
    histograms (and the NaN/inf and outside points, skipped as :func:`shifted_cell_sums` skips them), the
    second recomputes each point's cell index (measured: the same CPU time as storing and re-reading an int32
    index, without its 4 bytes a point) and scatters its in-block index (uint16) and value to its block.
    Memory: 10 bytes a point (16 before: an int32 global index). Returns
    ``(kb, zb, bstart, n_nonfinite, n_outside)``."""
    n = x.size
    bad = np.zeros(nthreads, np.int64)
    out = np.zeros(nthreads, np.int64)
    hist = np.zeros((nthreads, nblocks), np.int64)
    chunk = (n + nthreads - 1) // nthreads
    for t in prange(nthreads):
        h = hist[t]
        nb = 0
        no = 0
        for i in range(t * chunk, min(n, (t + 1) * chunk)):
            xi = x[i]
            yi = y[i]
            why = _keep(xi, yi, z[i], x0, y0, inv_h, nx, ny, check_inside)
            if why == 1:
                nb += 1
            elif why == 2:
                no += 1
            else:
                h[_cell_of(xi, yi, x0, y0, inv_h, nx, ny) >> shift] += 1
        bad[t] = nb
        out[t] = no
    bstart, off, pos = _block_offsets(hist)
    kb = np.empty(pos, np.uint16)
    zb = np.empty(pos, np.float64)
    mask = (1 << shift) - 1
    for t in prange(nthreads):
        o = off[t]
        for i in range(t * chunk, min(n, (t + 1) * chunk)):
            xi = x[i]
            yi = y[i]
            zi = z[i]
            if _keep(xi, yi, zi, x0, y0, inv_h, nx, ny, check_inside) != 0:
                continue
            kk = _cell_of(xi, yi, x0, y0, inv_h, nx, ny)
            b = kk >> shift
            p = o[b]
            kb[p] = kk & mask
            zb[p] = zi
            o[b] = p + 1
    return kb, zb, bstart, bad.sum(), out.sum()
