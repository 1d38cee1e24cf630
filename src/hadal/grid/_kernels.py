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

import os

import numba
import numpy as np
from numba import njit, prange

if not {"NUMBA_THREADING_LAYER", "NUMBA_THREADING_LAYER_PRIORITY"} & set(os.environ):
    # numba's parallel kernels try its TBB threading layer first; next to the older TBB that open3d loads it warns
    # ("requires TBB version 2021 update 6") and falls back to OpenMP. Asking for OpenMP first gives that same layer
    # without the warning (every hadal run printed it). A user's NUMBA_THREADING_LAYER[_PRIORITY] is left alone.
    numba.config.THREADING_LAYER_PRIORITY = ["omp", "workqueue", "tbb"]  # type: ignore[attr-defined]


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
# Two passes, both streaming or cache-resident (no random access into a grid-sized array):
# 1. ``partition_points`` (``partition_kernel`` from given cell indices): the points in chunks of ``chunk``
#    consecutive points (the threads take contiguous runs of chunks). Per chunk: the cell index of every point
#    (as ``shifted_cell_sums`` computes it; NaN/inf and outside points skipped and counted) into a chunk-sized
#    buffer (L2), the histogram of the blocks of ``2**shift`` consecutive cells, then a stable counting sort of
#    the chunk's points by block, written (in-block index uint16, value float64) into the chunk's own slice of
#    the output: the input is read once, and no global histogram pass is needed. ``seg[c, b]`` is where block
#    ``b``'s segment of chunk ``c`` starts (``seg[c, nblocks]``: the end of chunk ``c``'s valid points);
# 2. ``block_stats_kernel``: per block (in parallel), its segments of every chunk in order (file order kept),
#    a counting sort by cell inside the block (its histograms fit in L2), then per cell: count, mean and M2
#    from sums shifted by the cell's first value (so 10 km depths with mm spread lose nothing; a block where
#    a cell's rounding bound exceeds ``_BLOCK_M2_RTOL`` is recomputed two-pass) or, with median/min/max, two-pass
#    over the cell's grouped values (as the NumPy reference), min/max and the median of the sorted segment.


#: ``block_stats_kernel`` takes a block's one-pass M2 (sums shifted by each cell's first value) unless a cell's
#: rounding bound ``2 eps n S2`` exceeds this fraction of its M2; then the block is recomputed two-pass
_BLOCK_M2_RTOL = 1e-13
_EPS2 = 2.0 * np.finfo(np.float64).eps


@njit(inline="always")
def _partition_chunk(k, z, lo, h, row, kb, zb, shift):  # pragma: no cover - compiled
    """Stable counting sort of the points ``lo .. lo + k.size`` (cell indices ``k``, ``-1``: skip; ``h``: their
    block histogram, used up as the write pointers) by block into ``kb``/``zb[lo:]``; ``row`` (nblocks + 1)
    receives the blocks' segment starts and the end."""
    nblocks = h.size
    pos = lo
    for b in range(nblocks):
        row[b] = pos
        hb = h[b]
        h[b] = pos
        pos += hb
    row[nblocks] = pos
    mask = (1 << shift) - 1
    for i in range(k.size):
        kk = k[i]
        if kk >= 0:
            b = kk >> shift
            p = h[b]
            kb[p] = kk & mask
            zb[p] = z[lo + i]
            h[b] = p + 1


@njit(parallel=True, cache=True, nogil=True)
def partition_kernel(k, z, shift, nblocks, chunk, nthreads):  # pragma: no cover - compiled
    """Chunked stable counting sort of the points with ``k >= 0`` by block ``k >> shift`` (``shift <= 16``).

    Returns ``(kb uint16, zb, seg)``: the cell indices *within their block* (``k & (2**shift - 1)``) and values,
    block ``b``'s points of chunk ``c`` in ``[seg[c, b], seg[c, b + 1])``, file order kept within a block."""
    n = k.size
    nchunks = max(1, (n + chunk - 1) // chunk)
    seg = np.empty((nchunks, nblocks + 1), np.int64)
    kb = np.empty(n, np.uint16)
    zb = np.empty(n, np.float64)
    per = (nchunks + nthreads - 1) // nthreads
    for t in prange(nthreads):
        h = np.empty(nblocks, np.int64)
        for ci in range(t * per, min(nchunks, (t + 1) * per)):
            lo = ci * chunk
            hi = min(n, lo + chunk)
            h[:] = 0
            for i in range(lo, hi):
                kk = k[i]
                if kk >= 0:
                    h[kk >> shift] += 1
            _partition_chunk(k[lo:hi], z, lo, h, seg[ci], kb, zb, shift)
    return kb, zb, seg


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


#: cells of more values than this take their median by selection (:func:`_select`), fewer by insertion sort
_SELECT_MIN = 16


@njit(cache=True, nogil=True)
def _select(a, k):  # pragma: no cover - compiled
    """Partially order ``a`` in place so that ``a[k]`` is its ``k``-th smallest value, every value before it
    ``<=`` and every value after it ``>=`` (Hoare's FIND / quickselect, C. A. R. Hoare, CACM 4(7) 321, 1961;
    median-of-three pivot); no allocation. ``a`` must hold no NaN."""
    lo = 0
    hi = a.size - 1
    while hi > lo:
        if hi - lo < 16:  # insertion sort of the small remainder
            for i in range(lo + 1, hi + 1):
                v = a[i]
                q = i - 1
                while q >= lo and a[q] > v:
                    a[q + 1] = a[q]
                    q -= 1
                a[q + 1] = v
            return
        mid = (lo + hi) >> 1
        if a[mid] < a[lo]:
            a[mid], a[lo] = a[lo], a[mid]
        if a[hi] < a[lo]:
            a[hi], a[lo] = a[lo], a[hi]
        if a[hi] < a[mid]:
            a[hi], a[mid] = a[mid], a[hi]
        pivot = a[mid]
        i = lo
        q = hi
        while i <= q:
            while a[i] < pivot:
                i += 1
            while a[q] > pivot:
                q -= 1
            if i <= q:
                a[i], a[q] = a[q], a[i]
                i += 1
                q -= 1
        if k <= q:
            hi = q
        elif k >= i:
            lo = i
        else:
            return


@njit(inline="always")
def _block_shifted_sums(kb, zb, seg, b, sz, cnt, ref, s1, s2):  # pragma: no cover - compiled
    """Block ``b``'s per-cell count and sums shifted by each cell's first value (``ref``) into ``cnt``/``s1``/
    ``s2``; then ``s1`` holds the cells' means and ``s2`` their one-pass M2. Returns whether any cell's rounding
    bound ``2 eps n S2`` exceeds ``_BLOCK_M2_RTOL`` of its M2 (the block must then be recomputed two-pass)."""
    cnt[:sz] = 0
    s1[:sz] = 0.0
    s2[:sz] = 0.0
    for ci in range(seg.shape[0]):
        for p in range(seg[ci, b], seg[ci, b + 1]):
            j = kb[p]
            zi = zb[p]
            if cnt[j] == 0:
                ref[j] = zi
            cnt[j] += 1
            d = zi - ref[j]
            s1[j] += d
            s2[j] += d * d
    ill = False
    for j in range(sz):
        c = cnt[j]
        if c > 0:
            u = s1[j] / c
            mj = max(s2[j] - s1[j] * u, 0.0)  # shifted sums: M2 = S2 - S1**2 / n
            ill |= _EPS2 * c * s2[j] > _BLOCK_M2_RTOL * mj  # its rounding bound is too large
            s1[j] = ref[j] + u  # now the mean
            s2[j] = mj
    return ill


@njit(inline="always")
def _block_two_pass_m2(kb, zb, seg, b, sz, mean, s2):  # pragma: no cover - compiled
    """Block ``b``'s per-cell M2 recomputed two-pass about the cells' ``mean`` into ``s2``."""
    s2[:sz] = 0.0
    for ci in range(seg.shape[0]):
        for p in range(seg[ci, b], seg[ci, b + 1]):
            j = kb[p]
            d = zb[p] - mean[j]
            s2[j] += d * d


@njit(inline="always")
def _cell_starts(cnt, sz):  # pragma: no cover - compiled
    """The counting sort's cell starts (``sz + 1``, the last the total) and write pointers of counts ``cnt``."""
    start = np.empty(sz + 1, np.int64)
    acc = 0
    for j in range(sz):
        start[j] = acc
        acc += cnt[j]
    start[sz] = acc
    return start, start[:sz].copy()


@njit(inline="always")
def _block_grouped_values(kb, zb, seg, b, sz, cnt, total):  # pragma: no cover - compiled
    """Block ``b``'s ``total`` values grouped by cell (a counting sort, file order kept inside a cell):
    ``(buf, start)``, cell ``j``'s values in ``buf[start[j]:start[j + 1]]``."""
    start, fill = _cell_starts(cnt, sz)
    buf = np.empty(total)
    for ci in range(seg.shape[0]):
        for p in range(seg[ci, b], seg[ci, b + 1]):
            j = kb[p]
            buf[fill[j]] = zb[p]
            fill[j] += 1
    return buf, start


@njit(inline="always")
def _block_sorted_stats(buf, start, sz, base, cnt, count, mean, want_m2, m2, med, zmin, zmax):  # pragma: no cover
    """Per cell of a block grouped by :func:`_block_grouped_values`: count, the mean (the bits of
    :func:`_block_shifted_sums`: the same sums in the same order), (with ``want_m2``) the two-pass M2 about it over
    the cell's values in file order, then median (by selection, :func:`_select`), min and max."""
    for j in range(sz):
        c = cnt[j]
        if c == 0:
            continue
        a = start[j]
        cs = buf[a:a + c]
        ref = cs[0]  # the mean as _block_shifted_sums makes it: sums shifted by the first value, in file order
        s1 = 0.0
        for q in range(c):
            s1 += cs[q] - ref
        mu = ref + s1 / c
        count[base + j] = c
        mean[base + j] = mu
        if want_m2:  # two-pass about the mean over the cell's values (in file order), in cache
            q2 = 0.0
            for q in range(c):
                d = cs[q] - mu
                q2 += d * d
            m2[base + j] = q2
        if c <= _SELECT_MIN:
            _sort_small(cs)
            med[base + j] = 0.5 * (cs[(c - 1) // 2] + cs[c // 2])
            zmin[base + j] = cs[0]
            zmax[base + j] = cs[c - 1]
            continue
        lo = hi = cs[0]
        finite = True
        for q in range(c):
            v = cs[q]
            if v < lo:
                lo = v
            if v > hi:
                hi = v
            finite &= v == v
        zmin[base + j] = lo
        zmax[base + j] = hi
        if not finite:  # NaN: the sort's order (NaN last), as before
            _sort_small(cs)
            med[base + j] = 0.5 * (cs[(c - 1) // 2] + cs[c // 2])
            zmin[base + j] = cs[0]
            zmax[base + j] = cs[c - 1]
            continue
        h = (c - 1) // 2
        _select(cs, h)
        if c % 2 == 1:
            med[base + j] = cs[h]
        else:  # the upper middle value: the smallest of the values after the lower one
            u = cs[h + 1]
            for q in range(h + 2, c):
                if cs[q] < u:
                    u = cs[q]
            med[base + j] = 0.5 * (cs[h] + u)


@njit(parallel=True, cache=True, nogil=True)
def block_stats_kernel(kb, zb, seg, shift, m, want_m2, want_sorted, nthreads):  # pragma: no cover - compiled
    """Per-cell ``count`` (int64), ``mean``, ``m2`` (sum of squared deviations from the mean; empty when
    not ``want_m2``) and, with ``want_sorted``, ``median``/``min``/``max``, over ``m`` cells from the
    block-partitioned points of :func:`partition_kernel` (``kb``: cell index within the block; ``seg``: the
    chunks' block segments). Empty cells: count 0, NaN elsewhere. The blocks are shared round-robin by the
    threads; each block's steps are the inlined helpers above."""
    nseg = seg.shape[0]
    nblocks = seg.shape[1] - 1
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
            total = 0
            for ci in range(nseg):
                total += seg[ci, b + 1] - seg[ci, b]
            if total == 0:
                continue
            base = b << shift
            sz = min(bs, m - base)
            if want_sorted:  # count, group by cell, then every statistic from the cell's own values
                cnt[:sz] = 0
                for ci in range(nseg):
                    for p in range(seg[ci, b], seg[ci, b + 1]):
                        cnt[kb[p]] += 1
                buf, start = _block_grouped_values(kb, zb, seg, b, sz, cnt, total)
                _block_sorted_stats(buf, start, sz, base, cnt, count, mean, want_m2, m2, med, zmin, zmax)
                continue
            ill = _block_shifted_sums(kb, zb, seg, b, sz, cnt, ref, s1, s2)  # s1: the means
            for j in range(sz):
                if cnt[j] > 0:
                    count[base + j] = cnt[j]
                    mean[base + j] = s1[j]
            if want_m2:
                if ill:  # recompute the block two-pass about the means (mean unchanged)
                    _block_two_pass_m2(kb, zb, seg, b, sz, s1, s2)
                for j in range(sz):
                    if cnt[j] > 0:
                        m2[base + j] = s2[j]
    return count, mean, m2, med, zmin, zmax


@njit(cache=True, nogil=True)
def cell_grouped_stats(k, z, m, want_m2):  # pragma: no cover - compiled
    """:func:`block_stats_kernel` with ``want_sorted`` for points already indexed ``k`` (``0 <= k < m``) over a
    few cells (a tile): one counting sort of the values by cell (file order kept inside a cell), then every
    cell's statistics in one pass over the grouped values (:func:`_block_sorted_stats`, so the same bits), no
    block partition first. Single-threaded (CPU time, not latency, is what a tile costs)."""
    count = np.zeros(m, np.int64)
    mean = np.full(m, np.nan)
    m2 = np.full(m if want_m2 else 0, np.nan)
    med = np.full(m, np.nan)
    zmin = np.full(m, np.nan)
    zmax = np.full(m, np.nan)
    cnt = np.zeros(m, np.int64)
    for i in range(k.size):
        cnt[k[i]] += 1
    start, fill = _cell_starts(cnt, m)
    buf = np.empty(start[m])
    for i in range(k.size):
        j = k[i]
        buf[fill[j]] = z[i]
        fill[j] += 1
    _block_sorted_stats(buf, start, m, 0, cnt, count, mean, want_m2, m2, med, zmin, zmax)
    return count, mean, m2, med, zmin, zmax


@njit(inline="always")
def _cell_of(xi, yi, x0, y0, inv_h, nx, ny):  # pragma: no cover - compiled
    """Cell index of a finite point, clamped into the grid: floor and clamp in floating point before the integer
    conversion (any finite value is safe); a point on the upper/right edge joins the last cell."""
    r, c = _cell_rc(xi, yi, x0, y0, inv_h, nx, ny)
    return r * nx + c


@njit(inline="always")
def _cell_rc(xi, yi, x0, y0, inv_h, nx, ny):  # pragma: no cover - compiled
    """``(row, column)`` of :func:`_cell_of`'s cell."""
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
    return r, c


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


@njit(cache=True, nogil=True)
def _chunk_cells(x, y, z, lo, hi, x0, y0, inv_h, nx, ny, check_inside, shift, k, h):  # pragma: no cover - compiled
    """Cell index ``k[i - lo]`` of the points ``lo .. hi`` (``-1``: NaN/inf or outside) and their block histogram
    ``h``; returns the numbers of NaN/inf and of outside points."""
    h[:] = 0
    nb = 0
    no = 0
    for i in range(lo, hi):
        xi = x[i]
        yi = y[i]
        why = _keep(xi, yi, z[i], x0, y0, inv_h, nx, ny, check_inside)
        if why == 0:
            kk = _cell_of(xi, yi, x0, y0, inv_h, nx, ny)
            k[i - lo] = kk
            h[kk >> shift] += 1
        else:
            k[i - lo] = -1
            if why == 1:
                nb += 1
            else:
                no += 1
    return nb, no


@njit(parallel=True, cache=True, nogil=True)
def partition_points(x, y, z, x0, y0, inv_h, nx, ny, check_inside, shift, nblocks, chunk, nthreads):  # pragma: no cover
    """:func:`partition_kernel` straight from the points (``shift <= 16``), reading them once: per chunk, the
    cell indices (NaN/inf and outside points skipped and counted, as :func:`shifted_cell_sums` skips them) go
    to a chunk-sized buffer that stays in cache, then the chunk is sorted by block into its slice of the
    output. Memory: 10 bytes a point (uint16 in-block index, float64 value) plus the ``(nchunks, nblocks + 1)``
    segment table. Returns ``(kb, zb, seg, n_nonfinite, n_outside)``."""
    n = x.size
    nchunks = max(1, (n + chunk - 1) // chunk)
    seg = np.empty((nchunks, nblocks + 1), np.int64)
    kb = np.empty(n, np.uint16)
    zb = np.empty(n, np.float64)
    bad = np.zeros(nthreads, np.int64)
    out = np.zeros(nthreads, np.int64)
    per = (nchunks + nthreads - 1) // nthreads
    for t in prange(nthreads):
        h = np.empty(nblocks, np.int64)
        kbuf = np.empty(chunk, np.int32)  # grids of < 2**31 cells
        nb = 0
        no = 0
        for ci in range(t * per, min(nchunks, (t + 1) * per)):
            lo = ci * chunk
            hi = min(n, lo + chunk)
            why = _chunk_cells(x, y, z, lo, hi, x0, y0, inv_h, nx, ny, check_inside, shift, kbuf, h)
            nb += why[0]
            no += why[1]
            _partition_chunk(kbuf[:hi - lo], z, lo, h, seg[ci], kb, zb, shift)
        bad[t] = nb
        out[t] = no
    return kb, zb, seg, bad.sum(), out.sum()


@njit(cache=True, nogil=True)
def cell_counting_order(idx, ncells):  # pragma: no cover - compiled
    """``(order, starts)``: the points grouped by cell in a stable counting sort (``idx[order]`` ascending, points of
    one cell in their input order, as ``np.argsort(idx, kind="stable")``); ``starts[c]:starts[c + 1]`` is cell
    ``c``'s run in ``order`` (``ncells + 1`` entries)."""
    n = idx.size
    starts = np.zeros(ncells + 1, np.int64)
    for i in range(n):
        starts[idx[i] + 1] += 1
    for c in range(ncells):
        starts[c + 1] += starts[c]
    pos = starts[:-1].copy()
    order = np.empty(n, np.int64)
    for i in range(n):
        c = idx[i]
        order[pos[c]] = i
        pos[c] += 1
    return order, starts


@njit(inline="always")
def _stable_sort_run_by_z(order, z, s, m):  # pragma: no cover - compiled
    """Sort ``order[s:s + m]`` by ``z`` of its entries, equal values keeping their order (stable)."""
    if m > 24:
        run = order[s:s + m].copy()
        zr = np.empty(m)
        for q in range(m):
            zr[q] = z[run[q]]
        o = np.argsort(zr, kind="mergesort")
        for q in range(m):
            order[s + q] = run[o[q]]
        return
    for i in range(s + 1, s + m):
        v = order[i]
        zv = z[v]
        j = i - 1
        while j >= s and z[order[j]] > zv:
            order[j + 1] = order[j]
            j -= 1
        order[j + 1] = v


@njit(parallel=True, cache=True, nogil=True)
def segment_median_mad(order, z, starts, counts, med, mad, dev, block):  # pragma: no cover - compiled
    """For every segment ``order[starts[s]:starts[s] + counts[s]]`` (one cell's points): sort it by ``z`` (stable,
    in place), then ``med[s]`` = its median, ``dev`` = ``|z - med|`` of its points (in ``order``'s order) and
    ``mad[s]`` = the median of those deviations; a median of an even count is ``0.5 * (lower + upper)``, as
    :func:`hadal.grid.points.segment_median`. Blocks of ``block`` segments in parallel, one scratch array a block."""
    nseg = starts.size
    for b in prange((nseg + block - 1) // block):
        tmp = np.empty(64)
        for s in range(b * block, min(nseg, (b + 1) * block)):
            s0 = starts[s]
            m = counts[s]
            _stable_sort_run_by_z(order, z, s0, m)
            md = 0.5 * (z[order[s0 + (m - 1) // 2]] + z[order[s0 + m // 2]])
            med[s] = md
            if m > tmp.size:
                tmp = np.empty(2 * m)
            for q in range(m):
                d = abs(z[order[s0 + q]] - md)
                dev[s0 + q] = d
                tmp[q] = d
            _sort_small(tmp[:m])
            mad[s] = 0.5 * (tmp[(m - 1) // 2] + tmp[m // 2])


# --- Out-of-core gridding (hadal.grid.tiles): one chunk of points -> per-tile runs of (cell in tile, value) -------


@njit(cache=True, nogil=True)
def _tile_of_points(x, y, z, x0, y0, inv_h, nx, ny, check_inside, tile_cells, ntx, n_tiles):  # pragma: no cover
    """Per point of a chunk: its tile (-1: skipped) and its cell index inside the tile, the tiles' start offsets
    of a counting sort, and the NaN/inf and outside counts (the shared first pass of :func:`tile_partition_chunk`
    and :func:`tile_partition_order`)."""
    n = x.size
    col_tile = np.empty(nx, np.int64)
    col_in = np.empty(nx, np.int64)
    width = np.empty(nx, np.int64)
    for c in range(nx):
        tx = c // tile_cells
        col_tile[c] = tx
        col_in[c] = c - tx * tile_cells
        width[c] = min(tile_cells, nx - tx * tile_cells)
    row_tile = np.empty(ny, np.int64)
    row_in = np.empty(ny, np.int64)
    for r in range(ny):
        ty = r // tile_cells
        row_tile[r] = ty * ntx
        row_in[r] = r - ty * tile_cells
    tile = np.empty(n, np.int32)
    loc = np.empty(n, np.int32)
    starts = np.zeros(n_tiles + 1, np.int64)
    nb = 0
    no = 0
    for i in range(n):
        xi = x[i]
        yi = y[i]
        why = _keep(xi, yi, z[i], x0, y0, inv_h, nx, ny, check_inside)
        if why != 0:
            tile[i] = -1
            if why == 1:
                nb += 1
            else:
                no += 1
            continue
        r, c = _cell_rc(xi, yi, x0, y0, inv_h, nx, ny)
        t = row_tile[r] + col_tile[c]
        tile[i] = t
        loc[i] = row_in[r] * width[c] + col_in[c]
        starts[t + 1] += 1
    for t in range(n_tiles):
        starts[t + 1] += starts[t]
    return tile, loc, starts, nb, no


@njit(cache=True, nogil=True)
def tile_partition_chunk(x, y, z, x0, y0, inv_h, nx, ny, check_inside, tile_cells, ntx, n_tiles):  # pragma: no cover
    """One chunk of points grouped by tile of ``tile_cells x tile_cells`` whole cells (``ntx`` tiles a row).

    The cell of a point is :func:`_cell_of`'s (the in-memory kernels' own rule, NaN/inf and, with
    ``check_inside``, outside points skipped and counted by :func:`_keep`); its tile and its index inside the
    tile (row-major over the tile's own width, the last column/row of tiles being narrower) follow from the cell's
    row and column by integer tables (no division a point), so a point on a seam lands in exactly the cell the
    in-memory grid gives it. A stable counting sort by tile: tile ``t``'s points are ``local[starts[t]:starts[t +
    1]]`` (int32) and ``zs[...]``, in chunk order. Returns ``(starts, local, zs, n_nonfinite, n_outside)``."""
    tile, loc, starts, nb, no = _tile_of_points(x, y, z, x0, y0, inv_h, nx, ny, check_inside, tile_cells, ntx,
                                                n_tiles)
    pos = starts[:-1].copy()
    local = np.empty(starts[n_tiles], np.int32)
    zs = np.empty(starts[n_tiles], np.float64)
    for i in range(x.size):
        t = tile[i]
        if t >= 0:
            p = pos[t]
            local[p] = loc[i]
            zs[p] = z[i]
            pos[t] = p + 1
    return starts, local, zs, nb, no


@njit(cache=True, nogil=True)
def tile_partition_order(x, y, z, x0, y0, inv_h, nx, ny, check_inside, tile_cells, ntx, n_tiles):  # pragma: no cover
    """:func:`tile_partition_chunk` returning the chunk positions of the grouped points instead of their values
    (the DTM's tiles keep x, y, depth and the input index of each sounding: the caller gathers them by ``src``).
    Returns ``(starts, local, src, n_nonfinite, n_outside)``, ``src`` int64 in chunk order within each tile."""
    tile, loc, starts, nb, no = _tile_of_points(x, y, z, x0, y0, inv_h, nx, ny, check_inside, tile_cells, ntx,
                                                n_tiles)
    pos = starts[:-1].copy()
    local = np.empty(starts[n_tiles], np.int32)
    src = np.empty(starts[n_tiles], np.int64)
    for i in range(x.size):
        t = tile[i]
        if t >= 0:
            p = pos[t]
            local[p] = loc[i]
            src[p] = i
            pos[t] = p + 1
    return starts, local, src, nb, no

