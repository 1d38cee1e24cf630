"""Compiled (numba) kernels of the landing analysis: exact binary dilation by the rotated vehicle footprint
from row runs, and the exact squared Euclidean distance transform (Felzenszwalb & Huttenlocher, "Distance
transforms of sampled functions", Theory of Computing 8, 2012, §2.1 lower envelope of parabolas).

Dilation: the footprint's cells in row offset r form one contiguous column interval [lo_r, hi_r] (the
footprint is convex), so a horizontal run [a, b] of source cells in row i reaches output row i - r at
columns [a - hi_r, b - lo_r]. Intervals are accumulated in a per-row difference buffer: the cost is
(number of runs within the footprint's reach) x (footprint rows) + cells, instead of an FFT of the whole grid
— exact integer arithmetic, no threshold. Compiled on first use and cached next to this file.
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def row_runs(mask):  # pragma: no cover - compiled
    """Runs of True per row of a 2-D bool array as CSR: (row_ptr (ny + 1), start, end) (inclusive ends)."""
    ny, nx = mask.shape
    cnt = 0
    for i in range(ny):
        prev = False
        for j in range(nx):
            v = mask[i, j]
            if v and not prev:
                cnt += 1
            prev = v
    ptr = np.zeros(ny + 1, np.int64)
    a = np.empty(cnt, np.int64)
    b = np.empty(cnt, np.int64)
    k = 0
    for i in range(ny):
        prev = False
        for j in range(nx):
            v = mask[i, j]
            if v and not prev:
                a[k] = j
            if prev and not v:
                b[k] = j - 1
                k += 1
            prev = v
        if prev:
            b[k] = nx - 1
            k += 1
        ptr[i + 1] = k
    return ptr, a, b


@njit(cache=True, nogil=True)
def dilate_rows(ptr, ra, rb, ny, nx, off_r, off_lo, off_hi, outside, r0, r1):  # pragma: no cover - compiled
    """Output rows r0..r1-1 of the dilation (= correlation, the footprint being point-symmetric) of the set
    given by its row runs (``ptr``/``ra``/``rb``, rows 0..ny-1) by a footprint with row offsets ``off_r`` and
    column intervals [``off_lo``, ``off_hi``]: True where some footprint cell lands on the set. ``outside``:
    the exterior of the grid counts as part of the set (the unmapped erosion, Fig. 13b)."""
    out = np.zeros((r1 - r0, nx), np.bool_)
    diff = np.zeros(nx + 1, np.int32)
    for p in range(r0, r1):
        diff[:] = 0
        full = False
        for t in range(off_r.size):
            i = p + off_r[t]
            lo = off_lo[t]
            hi = off_hi[t]
            if i < 0 or i >= ny:
                if outside:
                    full = True
                    break
                continue
            if outside:  # the columns beyond the left / right grid edges
                j1 = -1 - lo
                if j1 >= 0:
                    diff[0] += 1
                    diff[min(j1, nx - 1) + 1] -= 1
                j0 = nx - hi
                if j0 <= nx - 1:
                    diff[max(j0, 0)] += 1
                    diff[nx] -= 1
            for k in range(ptr[i], ptr[i + 1]):
                j0 = ra[k] - hi
                j1 = rb[k] - lo
                if j1 < 0 or j0 > nx - 1:
                    continue
                diff[max(j0, 0)] += 1
                diff[min(j1, nx - 1) + 1] -= 1
        q = p - r0
        if full:
            out[q, :] = True
            continue
        s = 0
        for j in range(nx):
            s += diff[j]
            out[q, j] = s > 0
    return out


@njit(cache=True, nogil=True)
def squared_edt(inside):  # pragma: no cover - compiled
    """Exact squared Euclidean distance (cells², float32) from every True cell of ``inside`` to the nearest
    False cell or the grid exterior (cells beyond the edges count as False: scipy's
    ``distance_transform_edt`` of ``np.pad(inside, 1)``); 0 on False cells."""
    g = np.empty(inside.shape, np.float32)
    squared_edt_into(inside, g)
    return g


@njit(cache=True, nogil=True)
def squared_edt_into(inside, g):  # pragma: no cover - compiled
    """:func:`squared_edt` written into ``g`` (float32, the shape of ``inside``; a reused buffer: a fresh
    40 MB array per heading of a 10 M-cell strip costs its page faults every time).

    Columns: the 1-D distance to the nearest False cell by two scans. Rows: the lower envelope of the parabolas
    (j - p)² + g(p)² (F&H §2.1) in exact integer arithmetic without division — the intersection tests are
    cross-multiplied (s(b, q) <= s(a, b) ⟺ (F_q - F_b)(b - a) <= (F_b - F_a)(q - b), F_p = g(p)² + p²)."""
    ny, nx = inside.shape
    last = np.full(nx, -1, np.int64)
    for i in range(ny):
        for j in range(nx):
            if inside[i, j]:
                g[i, j] = i - last[j]
            else:
                g[i, j] = 0.0
                last[j] = i
    last[:] = ny
    for i in range(ny - 1, -1, -1):
        for j in range(nx):
            if inside[i, j]:
                dd = last[j] - i
                if dd < g[i, j]:
                    g[i, j] = dd
            else:
                last[j] = i
    n = nx + 2  # one False cell beyond each edge
    F = np.empty(n, np.int64)
    v = np.empty(n, np.int64)
    for i in range(ny):
        any_in = False
        F[0] = 0
        F[n - 1] = (n - 1) * (n - 1)
        for j in range(nx):
            x = np.int64(g[i, j])
            F[j + 1] = x * x + (j + 1) * (j + 1)
            if x > 0:
                any_in = True
        if not any_in:
            continue
        k = 0
        v[0] = 0
        for q in range(1, n):
            fq = F[q]
            while k >= 1:
                b = v[k]
                a = v[k - 1]
                if (fq - F[b]) * (b - a) <= (F[b] - F[a]) * (q - b):
                    k -= 1
                else:
                    break
            k += 1
            v[k] = q
        top = k
        k = 0
        for q in range(1, n - 1):
            if not inside[i, q - 1]:
                continue  # already 0
            while k < top and F[v[k + 1]] - F[v[k]] < 2 * q * (v[k + 1] - v[k]):
                k += 1
            p = v[k]
            g[i, q - 1] = F[p] - p * p + (q - p) * (q - p)


@njit(cache=True, nogil=True)
def disc_union(ri, ci, rad, ny, nx):  # pragma: no cover - compiled
    """True where some disc (centre ``ri``/``ci``, radius ``rad`` cells) holds the cell centre:
    (y - i)² + (x - j)² ≤ r² (+1e-9), stamped as one column interval per disc row into a difference buffer."""
    diff = np.zeros((ny, nx + 1), np.int32)
    for k in range(ri.size):
        i = ri[k]
        j = ci[k]
        r2 = rad[k] * rad[k] + 1e-9
        R = int(np.floor(rad[k] + 1e-9))
        for dy in range(-R, R + 1):
            y = i + dy
            if y < 0 or y >= ny:
                continue
            rem = r2 - dy * dy
            if rem < 0:
                continue
            w = int(np.floor(np.sqrt(rem)))
            while (w + 1) * (w + 1) <= rem:
                w += 1
            while w > 0 and w * w > rem:
                w -= 1
            j0 = max(j - w, 0)
            j1 = min(j + w, nx - 1)
            if j0 > j1:
                continue
            diff[y, j0] += 1
            diff[y, j1 + 1] -= 1
    out = np.zeros((ny, nx), np.bool_)
    for y in range(ny):
        s = 0
        for x in range(nx):
            s += diff[y, x]
            out[y, x] = s > 0
    return out


@njit(cache=True, nogil=True)
def any_free(unmapped, high, static):  # pragma: no cover - compiled
    """True when some cell is in none of the three bool maps."""
    ny, nx = unmapped.shape
    for i in range(ny):
        for j in range(nx):
            if not (unmapped[i, j] or high[i, j] or static[i, j]):
                return True
    return False


@njit(cache=True, nogil=True)
def plane_tangent(s_uz, s_vz, k1, k2, k3, gx, gy, inv_cell, unmapped, out):  # pragma: no cover - compiled
    """Footprint plane-fit slope tangent from the correlations Σuz, Σvz (float32, one pass):
    a = Σuz k1 - Σvz k2 + gx, b = Σvz k3 - Σuz k2 + gy (m per cell), out = hypot(a, b) / cell (NaN where
    ``unmapped``)."""
    ny, nx = out.shape
    for i in range(ny):
        for j in range(nx):
            if unmapped[i, j]:
                out[i, j] = np.nan
                continue
            su = s_uz[i, j]
            sv = s_vz[i, j]
            a = su * k1 - sv * k2 + gx
            b = sv * k3 - su * k2 + gy
            out[i, j] = np.sqrt(a * a + b * b) * inv_cell


@njit(cache=True, nogil=True)
def times_conj_imaginary(fz, a_u, a_v, out_u, out_v):  # pragma: no cover - compiled
    """out_u = fz · conj(i a_u), out_v = fz · conj(i a_v) for real ``a_u``/``a_v`` (the spectra of the
    antisymmetric kernels uB, vB are purely imaginary): (x + iy)(-i a) = a y - i a x, one read of ``fz``."""
    ny, nx = fz.shape
    for i in range(ny):
        for j in range(nx):
            z = fz[i, j]
            au = a_u[i, j]
            av = a_v[i, j]
            out_u[i, j] = complex(au * z.imag, -au * z.real)
            out_v[i, j] = complex(av * z.imag, -av * z.real)


@njit(cache=True, nogil=True)
def combine_exclusion(static_bits, unmapped, high, tan_slope, tan_c, f_unmapped, f_slope, f_high, ok):  # pragma: no cover
    """Exclusion bit flags of one heading (static | unmapped | slope > θc | high), the cells where C_G may land
    written into the bool array ``ok`` (flags 0), and their bounding box (r0, r1, c0, c1; r0 = -1 when none), in
    one pass."""
    ny, nx = unmapped.shape
    ex = np.empty((ny, nx), np.uint8)
    r0, r1, c0, c1 = -1, -1, nx, -1
    for i in range(ny):
        for j in range(nx):
            e = static_bits[i, j]
            if unmapped[i, j]:
                e |= f_unmapped
            if high[i, j]:
                e |= f_high
            if tan_slope[i, j] > tan_c:  # NaN compares False
                e |= f_slope
            ex[i, j] = e
            ok[i, j] = e == 0
            if e == 0:
                if r0 < 0:
                    r0 = i
                r1 = i
                if j < c0:
                    c0 = j
                if j > c1:
                    c1 = j
    return ex, r0, r1 + 1, c0, c1 + 1


@njit(cache=True, nogil=True)
def site_stats(lab, d2, n, min_r2):  # pragma: no cover - compiled
    """Per 8-connected site label 1..n: area (cells), bounding box, the largest squared inscribed-circle
    radius dmax2 (only where >= ``min_r2``, else -1) and the landing cell: among the cells at dmax2 the one
    nearest their mean position (ties: smallest row, then column)."""
    ny, nx = lab.shape
    area = np.zeros(n + 1, np.int64)
    rmin = np.full(n + 1, ny, np.int64)
    rmax = np.full(n + 1, -1, np.int64)
    cmin = np.full(n + 1, nx, np.int64)
    cmax = np.full(n + 1, -1, np.int64)
    dmax2 = np.full(n + 1, -1.0)
    for i in range(ny):  # by runs of one label along the row: the per-label updates once per run
        j = 0
        while j < nx:
            k = lab[i, j]
            if k == 0:
                j += 1
                continue
            j0 = j
            dm = d2[i, j]
            j += 1
            while j < nx and lab[i, j] == k:
                d = d2[i, j]
                if d > dm:
                    dm = d
                j += 1
            area[k] += j - j0
            if rmin[k] > i:
                rmin[k] = i
            rmax[k] = i  # rows arrive in order
            if j0 < cmin[k]:
                cmin[k] = j0
            if j - 1 > cmax[k]:
                cmax[k] = j - 1
            if dm >= min_r2 and dm > dmax2[k]:
                dmax2[k] = dm
    sr = np.zeros(n + 1)
    sc = np.zeros(n + 1)
    cnt = np.zeros(n + 1)
    for i in range(ny):
        for j in range(nx):
            k = lab[i, j]
            if k > 0 and dmax2[k] >= 0 and d2[i, j] == dmax2[k]:
                sr[k] += i
                sc[k] += j
                cnt[k] += 1
    best_r = np.full(n + 1, -1, np.int64)
    best_c = np.full(n + 1, -1, np.int64)
    best_d = np.full(n + 1, np.inf)
    for k in range(n + 1):
        if cnt[k] > 0:
            sr[k] /= cnt[k]
            sc[k] /= cnt[k]
    for i in range(ny):
        for j in range(nx):
            k = lab[i, j]
            if k > 0 and dmax2[k] >= 0 and d2[i, j] == dmax2[k]:
                dd = (i - sr[k]) ** 2 + (j - sc[k]) ** 2
                if dd < best_d[k]:
                    best_d[k] = dd
                    best_r[k] = i
                    best_c[k] = j
    return area, rmin, rmax + 1, cmin, cmax + 1, dmax2, best_r, best_c


@njit(cache=True, nogil=True, inline="always")
def _append_cell(br, bc, nb, i, j):  # pragma: no cover - compiled
    """Store (i, j) at index ``nb`` of the growing (rows, cols) buffers, doubling them when full; returns them."""
    if nb == br.size:
        br2 = np.empty(2 * br.size, np.int64)
        bc2 = np.empty(2 * br.size, np.int64)
        br2[:nb] = br
        bc2[:nb] = bc
        br, bc = br2, bc2
    br[nb] = i
    bc[nb] = j
    return br, bc


@njit(cache=True, nogil=True)
def outer_border_of(lab, lid):  # pragma: no cover - compiled
    """Cells outside the set ``lab == lid`` (including the one-cell ring beyond its edges) that are 8-adjacent
    to it: (rows, cols) in ``lab``'s index frame (-1 and ny / nx for the ring), row-major, and the number of
    cells of the set (a site of a label array, without building its mask; :func:`outer_border` for a bool
    mask). Same output as a 9-neighbour test per cell, from a vertical 3-row OR per row (one buffer of
    nx + 4) then a horizontal 3-OR: ~4 byte operations per cell instead of 9 bounds-checked lookups."""
    ny, nx = lab.shape
    br = np.empty(2 * (ny + nx) + 16, np.int64)
    bc = np.empty(br.size, np.int64)
    nb = 0
    n_in = 0
    vor = np.zeros(nx + 4, np.uint8)  # vor[j + 2]: the set at (i-1, j), (i, j) or (i+1, j); zero beyond the edges
    for i in range(-1, ny + 1):
        any_v = False
        for j in range(nx):
            x = False
            if i >= 1:
                x = lab[i - 1, j] == lid
            if 0 <= i < ny and lab[i, j] == lid:
                x = True
                n_in += 1
            if i + 1 < ny and lab[i + 1, j] == lid:
                x = True
            vor[j + 2] = x
            if x:
                any_v = True
        if not any_v:
            continue
        inside_row = 0 <= i < ny
        for j in range(-1, nx + 1):
            if not (vor[j + 1] | vor[j + 2] | vor[j + 3]):
                continue
            if inside_row and 0 <= j < nx and lab[i, j] == lid:
                continue
            br, bc = _append_cell(br, bc, nb, i, j)
            nb += 1
    return br[:nb], bc[:nb], n_in


@njit(cache=True, nogil=True)
def outer_border(m):  # pragma: no cover - compiled
    """:func:`outer_border_of` the True set of the bool mask ``m``."""
    return outer_border_of(m, True)


@njit(cache=True, nogil=True)
def site_cells_at_least(lab, lid, c2, thr):  # pragma: no cover - compiled
    """(rows, cols), row-major, of the cells with ``lab == lid`` and ``c2 >= thr``."""
    ny, nx = lab.shape
    n = 0
    for i in range(ny):
        for j in range(nx):
            if lab[i, j] == lid and c2[i, j] >= thr:
                n += 1
    rows = np.empty(n, np.int64)
    cols = np.empty(n, np.int64)
    k = 0
    for i in range(ny):
        for j in range(nx):
            if lab[i, j] == lid and c2[i, j] >= thr:
                rows[k] = i
                cols[k] = j
                k += 1
    return rows, cols
