"""Sort-and-reduce gridding of scattered points (x, y, z) onto a regular grid.

The method is the one NOAA's *bathygrid* uses for its "simple mean / shoal / median" cells: compute
each point's flat cell index ``i = iy * nx + ix`` once, then reduce per cell with vectorised NumPy
primitives instead of a Python loop over cells:

* count/mean/std only (the fast path, :func:`cell_moments`): shifted sums ``n, sum(z - z0),
  sum((z - z0)**2)`` with ``np.bincount`` over cache-sized chunks in two threads, cells whose
  subtraction is ill-conditioned recomputed two-pass (so 10 000 m depths with mm spread are exact,
  where the textbook ``E[z^2] - E[z]^2`` cancels catastrophically);
* with median/min/max (:func:`cell_stats`, compiled): a counting sort of the points by block of
  ``2**14`` consecutive cells, then per block a counting sort by cell and per cell the two-pass mean/std
  and the sorted segment, after which the median of a cell of ``n`` points is
  ``(zs[(n-1)//2] + zs[n//2]) / 2`` and min/max are the segment ends - every pass streams, so it costs
  about the same in random and survey point order; the same kernels serve count/mean/std for points in
  scattered order (:func:`_scattered`) and :func:`reduce_cells`;
* the NumPy reference (no numba, small inputs: :func:`_reduce_cells_numpy`): two-pass ``bincount``
  mean/std and ``np.lexsort((z, i))`` to group the points by cell with each cell's values sorted; the
  per-cell median +- k MAD spike test (:func:`robust_outlier_mask`) uses the same segments.

Grid convention: cells are squares of side ``resolution``; the grid's lower-left *edge* ``(x0, y0)``
is snapped to an integer multiple of the resolution (so grids of different inputs align), ``x``/``y``
coordinates are cell *centres*, ascending. A point on a cell's lower/left edge belongs to that cell;
with explicit ``bounds`` a point exactly on the upper/right edge belongs to the last cell.
Empty cells hold NaN and ``count == 0``.
"""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, NamedTuple

from hadal.errors import InputError
from hadal.settings.grid import DEFAULT_MAX_CELLS

if TYPE_CHECKING:
    import numpy as np
    import xarray as xr

STATISTICS = ("mean", "median", "count", "std", "min", "max")

_STAT_ATTRS = {
    "mean": {"long_name": "mean of the points in the cell", "cell_methods": "area: mean"},
    "median": {"long_name": "median of the points in the cell", "cell_methods": "area: median"},
    "count": {"long_name": "number of points in the cell", "units": "1"},
    "std": {"long_name": "sample standard deviation (ddof=1) of the points in the cell",
            "cell_methods": "area: standard_deviation"},
    "min": {"long_name": "minimum of the points in the cell", "cell_methods": "area: minimum"},
    "max": {"long_name": "maximum of the points in the cell", "cell_methods": "area: maximum"},
}


@dataclass(frozen=True)
class GridSpec:
    """A regular grid: lower-left edge ``(x0, y0)``, square cells of ``resolution``, ``nx`` x ``ny`` cells."""

    x0: float
    y0: float
    resolution: float
    nx: int
    ny: int

    @property
    def n_cells(self) -> int:
        return self.nx * self.ny

    @property
    def x(self) -> np.ndarray:
        """Cell-centre x coordinates (ascending)."""
        import numpy as np

        return self.x0 + (np.arange(self.nx) + 0.5) * self.resolution

    @property
    def y(self) -> np.ndarray:
        """Cell-centre y coordinates (ascending)."""
        import numpy as np

        return self.y0 + (np.arange(self.ny) + 0.5) * self.resolution

    @property
    def bounds(self) -> tuple[float, float, float, float]:
        r = self.resolution
        return (self.x0, self.y0, self.x0 + self.nx * r, self.y0 + self.ny * r)

    def cell_index(self, x: np.ndarray, y: np.ndarray, *, check_inside: bool = True, finite: bool = False
                   ) -> tuple[np.ndarray, np.ndarray | None]:
        """Flat cell index (``iy * nx + ix``, int64) of each point and a mask of points inside the grid.

        With ``check_inside=False`` (the grid was built from these points' extent) the mask is None;
        indices are always clamped into the grid (NaN coordinates give an arbitrary valid index:
        filter them separately).
        """
        import numpy as np

        inv = 1.0 / self.resolution
        fx = np.subtract(x, self.x0)
        fx *= inv
        fy = np.subtract(y, self.y0)
        fy *= inv
        inside = None
        if check_inside:
            inside = fx >= 0.0
            inside &= fy >= 0.0
            inside &= fx <= self.nx
            inside &= fy <= self.ny
        with np.errstate(invalid="ignore"):
            np.floor(fx, out=fx)
            np.clip(fx, 0, self.nx - 1, out=fx)  # a point on the upper/right edge joins the last cell
            np.floor(fy, out=fy)
            np.clip(fy, 0, self.ny - 1, out=fy)
            fy *= self.nx
            fy += fx
            if not finite:
                np.nan_to_num(fy, copy=False)
            return fy.astype(np.int64), inside  # exact: integers < 2**53


def check_resolution(resolution: float, what: str = "resolution") -> float:
    try:
        r = float(resolution)
    except (TypeError, ValueError):
        raise InputError(f"grid {what} must be a number of metres, got {resolution!r}") from None
    if not math.isfinite(r) or r <= 0:
        raise InputError(f"grid {what} must be a positive finite number of metres, got {resolution!r}")
    return r


def make_grid_spec(
    resolution: float,
    bounds: Sequence[float],
    *,
    max_cells: int = DEFAULT_MAX_CELLS,
    snap: bool = False,
) -> GridSpec:
    """Grid covering ``bounds = (xmin, ymin, xmax, ymax)``.

    ``snap=False``: the grid starts exactly at ``(xmin, ymin)`` and has ``ceil(width / resolution)``
    columns. ``snap=True`` (used for a point extent): the lower-left edge snaps down to a multiple of
    ``resolution`` and the grid reaches past ``xmax``/``ymax``. Raises :class:`InputError` on a
    non-positive resolution, a degenerate extent (zero width or height) or more than ``max_cells`` cells.
    """
    r = check_resolution(resolution)
    if len(bounds) != 4:
        raise InputError(f"grid bounds must be (xmin, ymin, xmax, ymax), got {bounds!r}")
    xmin, ymin, xmax, ymax = (float(b) for b in bounds)
    if not all(math.isfinite(b) for b in (xmin, ymin, xmax, ymax)):
        raise InputError(f"grid bounds must be finite, got {bounds!r}")
    if xmax <= xmin or ymax <= ymin:
        what = "points' extent" if snap else "grid bounds"
        axis = "x" if xmax <= xmin else "y"
        raise InputError(
            f"degenerate {what} ({xmin:g}, {ymin:g}, {xmax:g}, {ymax:g}): zero width in {axis}; "
            "a grid needs an area (pass explicit bounds to grid a line of points)"
        )
    if snap:
        x0 = math.floor(xmin / r) * r
        y0 = math.floor(ymin / r) * r
        nx = int(math.floor((xmax - x0) / r)) + 1
        ny = int(math.floor((ymax - y0) / r)) + 1
    else:
        x0, y0 = xmin, ymin
        nx = max(1, math.ceil((xmax - xmin) / r - 1e-9))
        ny = max(1, math.ceil((ymax - ymin) / r - 1e-9))
    if nx * ny > max_cells:
        raise InputError(
            f"grid of {nx:,} x {ny:,} = {nx * ny:,} cells at {r:g} resolution exceeds the limit of "
            f"{max_cells:,} cells; use a coarser resolution, smaller bounds or raise max_cells"
        )
    return GridSpec(x0, y0, r, nx, ny)


def sorted_segments(idx: np.ndarray, z: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Group points by cell with each cell's values ascending.

    Returns ``(order, cells, starts, counts)``: ``z[order]`` is sorted by (cell, z); ``cells`` are the
    occupied cell indices (ascending), ``starts``/``counts`` their segments in ``z[order]``.
    """
    import numpy as np

    order = np.lexsort((z, idx))
    si = idx[order]
    brk = np.flatnonzero(si[1:] != si[:-1]) + 1
    starts = np.concatenate(([0], brk))
    counts = np.diff(np.append(starts, len(si)))
    return order, si[starts], starts, counts


def segment_median(zs: np.ndarray, starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """Median of each sorted segment ``zs[s:s+n]`` (mean of the two middle values for even ``n``)."""
    lo = zs[starts + (counts - 1) // 2]
    hi = zs[starts + counts // 2]
    return 0.5 * (lo + hi)


class CellRobustStats(NamedTuple):
    """Per-cell median and MAD of points grouped by cell (:func:`cell_robust_stats`)."""

    order: np.ndarray  # z[order] sorted by (cell, z)
    starts: np.ndarray  # segment start of each occupied cell in z[order]
    counts: np.ndarray  # points per occupied cell
    seg: np.ndarray  # per point in z[order] order: its occupied cell's number (0, 1, ...)
    median: np.ndarray  # per occupied cell
    mad: np.ndarray  # median absolute deviation from the cell median, per occupied cell
    dev: np.ndarray  # |z - cell median| per point, in z[order] order


def cell_robust_stats(idx: np.ndarray, z: np.ndarray) -> CellRobustStats:
    """Median and median absolute deviation (MAD) of ``z`` within each cell ``idx`` (non-negative cell indices).

    Computed once and shared by :func:`typical_cell_sigma` and :func:`robust_outlier_mask` (the multibeam spike
    test needs both on the same soundings). From :data:`_COMPILED_MIN_POINTS` points on, a compiled stable counting
    sort by cell and a per-cell sort (:func:`hadal.grid._kernels.segment_median_mad`): the same ``order`` as
    ``np.lexsort((z, idx))`` and the same medians, MADs and deviations as the NumPy path (two lexsorts, no Python
    loop) at 1/8-1/14 of its time (the sample dive's 3.45 M soundings in 1.0 M cells: 0.10-0.18 s against 1.45-1.48 s,
    identical results, measured; tests/unit/grid/test_grid_points.py compares both and pandas' group medians)."""
    import numpy as np

    kernels = _partition_kernels()
    n = len(z)
    ncells = int(idx.max()) + 1 if n else 0
    if (kernels is not None and n >= _COMPILED_MIN_POINTS and z.dtype == np.float64 and ncells <= 8 * n + (1 << 20)
            and int(idx.min()) >= 0 and bool(np.isfinite(z).all())):  # NaN: lexsort's order (last) on the NumPy path
        return _cell_robust_stats_compiled(kernels, idx, z, ncells)
    order, _cells, starts, counts = sorted_segments(idx, z)
    zs = z[order]
    seg = np.repeat(np.arange(len(starts)), counts)
    med = segment_median(zs, starts, counts)
    dev = np.abs(zs - med[seg])
    mad = segment_median(dev[np.lexsort((dev, seg))], starts, counts)  # |dev| sorted within each cell segment
    return CellRobustStats(order, starts, counts, seg, med, mad, dev)


def _cell_robust_stats_compiled(kernels, idx: np.ndarray, z: np.ndarray, ncells: int) -> CellRobustStats:
    """:func:`cell_robust_stats` by the compiled kernels (``ncells`` > every index)."""
    import numpy as np

    zc = np.ascontiguousarray(z, dtype=np.float64)
    order, cell_starts = kernels.cell_counting_order(np.ascontiguousarray(idx, dtype=np.int64), ncells)
    per_cell = np.diff(cell_starts)
    occupied = np.flatnonzero(per_cell)
    starts, counts = cell_starts[occupied], per_cell[occupied]
    med, mad, dev = np.empty(len(starts)), np.empty(len(starts)), np.empty(len(zc))
    kernels.segment_median_mad(order, zc, starts, counts, med, mad, dev, 4096)
    seg = np.repeat(np.arange(len(starts)), counts)
    return CellRobustStats(order, starts, counts, seg, med, mad, dev)


def robust_outlier_mask(
    idx: np.ndarray,
    z: np.ndarray,
    k: float = 3.5,
    *,
    floor=0.0,
    min_count: int = 3,
    stats: CellRobustStats | None = None,
) -> np.ndarray:
    """Per-cell robust spike test: True where ``|z - median| > k * max(1.4826 * MAD, floor)``.

    ``median`` and ``MAD`` (median absolute deviation) are those of the point's own cell; 1.4826 makes
    the MAD a consistent estimator of a Gaussian sigma (Rousseeuw & Croux 1993), so ``k = 3.5`` rejects
    ~0.05 % of pure Gaussian noise. ``floor`` is a minimum sigma (same units as ``z``): a scalar, or a
    callable mapping the cell medians to a per-cell sigma (e.g. a depth-proportional a-priori sounding
    uncertainty), so cells whose points agree closely do not reject ordinary noise. Cells with fewer
    than ``min_count`` points cannot be judged robustly and keep all their points. ``stats``: the
    :func:`cell_robust_stats` of ``(idx, z)`` when already computed.
    """
    import numpy as np

    n = len(z)
    if n == 0:
        return np.zeros(0, dtype=bool)
    st = cell_robust_stats(idx, z) if stats is None else stats
    fl = floor(st.median) if callable(floor) else np.full(len(st.median), float(floor))
    sigma = np.maximum(1.4826 * st.mad, fl)
    out_sorted = (st.dev > k * sigma[st.seg]) & (st.counts[st.seg] >= min_count)
    mask = np.empty(n, dtype=bool)
    mask[st.order] = out_sorted
    return mask


def typical_cell_sigma(idx: np.ndarray, z: np.ndarray, min_count: int = 5, *,
                       stats: CellRobustStats | None = None) -> float:
    """Median over the cells with >= ``min_count`` points of their robust sigma ``1.4826 * MAD``.

    A data-driven, outlier-resistant estimate of the point noise (plus sub-cell relief); NaN when no
    cell has enough points. ``stats``: the :func:`cell_robust_stats` of ``(idx, z)`` when already computed.
    """
    import numpy as np

    if len(z) == 0:
        return float("nan")
    st = cell_robust_stats(idx, z) if stats is None else stats
    big = st.counts >= min_count
    if not big.any():
        return float("nan")
    return float(1.4826 * np.median(st.mad[big]))


def distinct_xy(x, y) -> np.ndarray:
    """The distinct ``(x, y)`` positions, ``(M, 2)`` float64 sorted by x then y: the rows of
    ``np.unique(np.column_stack([x, y]), axis=0)`` from one ``np.lexsort`` and a neighbour comparison
    (``np.unique`` with ``axis`` sorts the rows as opaque records, ~20x slower on a laser cloud)."""
    import numpy as np

    x, y = np.asarray(x, np.float64).ravel(), np.asarray(y, np.float64).ravel()
    if x.size == 0:
        return np.empty((0, 2))
    o = np.lexsort((y, x))
    xs, ys = x[o], y[o]
    keep = np.empty(xs.size, bool)
    keep[0] = True
    np.not_equal(xs[1:], xs[:-1], out=keep[1:])
    keep[1:] |= ys[1:] != ys[:-1]
    return np.column_stack([xs[keep], ys[keep]])


def point_extent(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> tuple[tuple[float, float, float, float], int]:
    """``(xmin, ymin, xmax, ymax)`` of the points whose x, y and z are all finite, and the number of others.

    Raises :class:`InputError` for mismatched lengths, empty input or when no finite point is left.
    Works in chunks so no full-size temporary is allocated.
    """
    import numpy as np

    n = _check_lengths(x, y, z)
    fast = (float(x.min()), float(y.min()), float(x.max()), float(y.max()))
    if all(math.isfinite(v) for v in fast) and math.isfinite(float(z.min())) and math.isfinite(float(z.max())):
        return fast, 0  # NaN/inf would show up in the min or max
    ext = np.array([np.inf, np.inf, -np.inf, -np.inf])
    n_bad = 0
    for sl in _chunk_slices(n, _CHUNK):
        xc, yc = x[sl], y[sl]
        ok = np.isfinite(xc)
        ok &= np.isfinite(yc)
        ok &= np.isfinite(z[sl])
        nok = int(np.count_nonzero(ok))
        n_bad += len(xc) - nok
        if nok == 0:
            continue
        w = None if nok == len(xc) else ok
        ext[0] = min(ext[0], np.min(xc, where=w, initial=np.inf) if w is not None else xc.min())
        ext[1] = min(ext[1], np.min(yc, where=w, initial=np.inf) if w is not None else yc.min())
        ext[2] = max(ext[2], np.max(xc, where=w, initial=-np.inf) if w is not None else xc.max())
        ext[3] = max(ext[3], np.max(yc, where=w, initial=-np.inf) if w is not None else yc.max())
    if n_bad == n:
        raise InputError(f"all {n} points have NaN/inf coordinates; nothing to grid")
    return (float(ext[0]), float(ext[1]), float(ext[2]), float(ext[3])), n_bad


def _check_lengths(x: np.ndarray, y: np.ndarray, z: np.ndarray) -> int:
    if not (len(x) == len(y) == len(z)):
        raise InputError(f"x, y and z must have the same length (got {len(x)}, {len(y)}, {len(z)})")
    if len(x) == 0:
        raise InputError("no points to grid (empty point set)")
    return len(x)


def _as_f64(a) -> np.ndarray:
    import numpy as np

    a = np.asarray(a)
    if a.dtype != np.float64:
        a = a.astype(np.float64)
    return a.ravel()


_CHUNK = 1 << 18  # points per chunk: keeps temporaries in cache (and out of mmap/page-fault territory)


def _chunk_slices(n: int, size: int) -> list[slice]:
    return [slice(i, min(i + size, n)) for i in range(0, n, size)]


def _chunk_index(spec: GridSpec, x, y, z, check_inside: bool, all_finite: bool = False):
    """Cell indices and values of one chunk's valid points (finite and, if checked, inside the grid)."""
    import numpy as np

    if all_finite and not check_inside:
        return spec.cell_index(x, y, check_inside=False, finite=True)[0], z, 0, 0
    ok = np.isfinite(x)
    ok &= np.isfinite(y)
    ok &= np.isfinite(z)
    idx, inside = spec.cell_index(x, y, check_inside=check_inside)
    n_bad = len(x) - int(np.count_nonzero(ok))
    n_out = 0
    if inside is not None:
        n_out = int(np.count_nonzero(ok & ~inside))
        ok &= inside
    if n_bad or n_out:
        idx, z = idx[ok], z[ok]
    return idx, z, n_bad, n_out


#: cell_moments recomputes a cell exactly unless its M2 rounding bound is below this fraction of M2 ...
M2_RTOL = 1e-8
#: ... or the standard deviation's absolute error bound is below this (units of z; 1 micrometre for metres).
STD_ATOL = 1e-6


def cell_moments(
    x, y, z, spec: GridSpec, *, check_inside: bool = True, need_m2: bool = True, threads: int = 2,
    all_finite: bool = False,
) -> tuple[np.ndarray, np.ndarray, np.ndarray | None, int, int]:
    """Per-cell count, mean and sum of squared deviations (M2) of ``z``, in one read of the points.

    Method: "shifted data" sums (Chan, Golub & LeVeque 1983, SS3). With one shift ``z0`` (the median of
    a sample of z), ``S0 = n``, ``S1 = sum(z - z0)`` and ``S2 = sum((z - z0)**2)`` are accumulated per cell
    in one fused numba pass (:mod:`hadal.grid._kernels`, ``threads`` blocks in parallel; without numba
    ``np.bincount`` over cache-sized chunks, :func:`_cell_sums_numpy`), then
    ``mean = z0 + S1/n`` and
    ``M2 = S2 - S1**2/n``. The rounding error of ``M2`` is bounded by ``delta = 2 n eps S2``; its
    relative size ``delta / M2`` is the condition number of the subtraction times ``n eps``, large when
    the cell mean is far from ``z0`` compared with the spread. Every cell where ``delta`` exceeds both
    ``M2_RTOL * M2`` and ``STD_ATOL**2 * (n - 1)`` is recomputed exactly by the two-pass
    :func:`reduce_cells` in a second pass over just its points, so the std is always within 1e-8
    relative (typically 1e-14) or 1 micro-unit absolute - unlike the textbook ``E[z^2] - E[z]^2``,
    which loses everything for 10 km depths with mm spread.

    Points in scattered order over a grid whose sums do not fit in cache (:func:`_scattered`) take the
    block-partitioned path of :func:`cell_stats` instead (exact two-pass per cell, streaming passes only):
    the single pass would wait on a cache miss per point there.

    Returns ``(count int64, mean, M2 or None, n_nonfinite, n_outside)`` as flat arrays over the cells.
    """
    import numpy as np

    x, y, z = _as_f64(x), _as_f64(y), _as_f64(z)
    n = _check_lengths(x, y, z)
    if _scattered(x, y, spec):
        res = cell_stats(x, y, z, spec, ("count", "mean"), check_inside=check_inside, threads=threads,
                         _m2=need_m2)
        if res is not None:
            flat, bad, out = res
            m2 = flat.get("m2")
            if m2 is not None:
                np.nan_to_num(m2, copy=False, nan=0.0)  # empty cells: 0, as the single pass gives
            return flat["count"], flat["mean"], m2, bad, out
    sample = z[:: max(1, n // 1024)]
    sample = sample[np.isfinite(sample)]
    z0 = float(np.median(sample)) if len(sample) else 0.0
    kernel = _numba_kernel()
    if kernel is not None:
        cnt, s1, s2, bad, out = _cell_sums_numba(kernel, x, y, z, spec, z0, check_inside, threads)
    else:
        cnt, s1, s2, bad, out = _cell_sums_numpy(x, y, z, spec, z0, check_inside, all_finite, need_m2, threads)
    if bad == n:
        raise InputError(f"all {n} points have NaN/inf coordinates; nothing to grid")
    occ = cnt > 0
    mean = np.full(spec.n_cells, np.nan)
    np.divide(s1, cnt, out=mean, where=occ)
    m2 = None
    if need_m2:
        m2 = s2 - s1 * np.where(occ, mean, 0.0)  # S2 - S1**2 / n
        np.maximum(m2, 0.0, out=m2)
        m2[cnt == 1] = 0.0  # exact by definition
        delta = (2.0 * np.finfo(np.float64).eps) * cnt * s2
        ill = (cnt > 1) & (delta > M2_RTOL * m2) & (delta > STD_ATOL**2 * (cnt - 1))
        if ill.any():
            _exact_cells(x, y, z, spec, ill, mean, m2, z0, check_inside, all_finite)
    mean += z0
    return cnt, mean, m2, bad, out


def _cell_sums_numpy(x, y, z, spec: GridSpec, z0: float, check_inside: bool, all_finite: bool, need_m2: bool,
                     threads: int):
    """Shifted per-cell sums ``(S0, S1, S2, n_nonfinite, n_outside)`` with ``np.bincount`` over chunks
    (``threads`` workers sum alternate chunks; the index arithmetic releases the GIL). The reference
    implementation, used when numba is unavailable."""
    import numpy as np

    n = len(x)
    m = spec.n_cells
    size = max(_CHUNK, min(4 * m, 1 << 21))  # amortise the O(cells) accumulation over enough points
    slices = _chunk_slices(n, size)
    nw = max(1, min(threads, len(slices)))

    def work(w: int):
        s0 = np.zeros(m, dtype=np.int64)
        s1 = np.zeros(m)
        s2 = np.zeros(m) if need_m2 else None
        bad = out = 0
        for sl in slices[w::nw]:
            idx, zc, b, o = _chunk_index(spec, x[sl], y[sl], z[sl], check_inside, all_finite)
            bad += b
            out += o
            if len(idx) == 0:
                continue
            d = zc - z0
            s0 += np.bincount(idx, minlength=m)
            s1 += np.bincount(idx, weights=d, minlength=m)
            if need_m2:
                d *= d
                s2 += np.bincount(idx, weights=d, minlength=m)
        return s0, s1, s2, bad, out

    if nw == 1:
        parts = [work(0)]
    else:
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(nw) as ex:
            parts = list(ex.map(work, range(nw)))
    cnt, s1, s2, bad, out = parts[0]
    for c, t1, t2, b, o in parts[1:]:
        cnt += c
        s1 += t1
        if need_m2:
            s2 += t2
        bad += b
        out += o
    return cnt, s1, s2, bad, out


def _numba_kernel():
    """The compiled single-pass kernel (:mod:`hadal.grid._kernels`), or None without numba."""
    kernels = _partition_kernels()
    return None if kernels is None else kernels.shifted_cell_sums


#: the single-pass sums (24 bytes a cell) stay in cache up to this many bytes, whatever the point order
_CACHE_BYTES = 1 << 20
#: more distinct 64-byte lines of the sums touched per point of a window than this: scattered order
_SCATTER_LINES_PER_POINT = 0.25


def _scattered(x: np.ndarray, y: np.ndarray, spec: GridSpec, window: int = 4096, windows: int = 8) -> bool:
    """Whether the points come in an order that makes the single-pass sums miss the cache.

    A probe, not a proof: in ``windows`` windows of ``window`` consecutive points spread over the input,
    the number of distinct 64-byte lines of the ``(count, S1, S2)`` array they would touch, per point.
    Survey order (scan lines, pings, profiles) reuses a few lines (~0.05 a point); random order touches a
    new line per point (~1). Grids whose sums fit in :data:`_CACHE_BYTES` are never "scattered". Only the
    speed depends on the answer: both paths give the same statistics (to rounding).
    """
    import numpy as np

    n = len(x)
    if spec.n_cells * 24 <= _CACHE_BYTES or n < 4 * window or _partition_kernels() is None:
        return False
    fracs = []
    for s0 in np.linspace(0, n - window, windows).astype(np.int64):
        sl = slice(int(s0), int(s0) + window)
        idx, _ = spec.cell_index(x[sl], y[sl], check_inside=False)
        fracs.append(len(np.unique((idx * 24) >> 6)) / window)
    return float(np.median(fracs)) > _SCATTER_LINES_PER_POINT


def _partition_kernels():
    """The compiled partitioned-gridding kernels (:mod:`hadal.grid._kernels`), or None without numba."""
    if os.environ.get("HADAL_NO_NUMBA"):
        return None
    try:
        from hadal.grid import _kernels
    except ImportError:
        return None
    return _kernels


#: fewer points than this are reduced by the NumPy path (milliseconds), sparing the ~1 s of numba start-up
_COMPILED_MIN_POINTS = 32768
#: up to this many cells (a tile's, :mod:`hadal.grid.tiles`), :func:`reduce_cells` with median/min/max groups the
#: values by cell in one counting sort (:func:`hadal.grid._kernels.cell_grouped_stats`, the same bits as the block
#: path): 0.61x the CPU of block partition + block stats on the tiles of 2e7 survey soundings (same run, A B B A)
_GROUPED_MAX_CELLS = 1 << 20
#: cells per block of the partitioned path: a block's per-cell work arrays (~40 bytes a cell) stay in L2
_BLOCK_SHIFT = 14
_MAX_BLOCKS = 4096
#: the kernels keep a point's cell index within its block as uint16
_MAX_SHIFT = 16


#: points per chunk of the partition: a chunk's cell indices (int32, 256 kB) stay in L2 and its values in cache
#: (measured on 10 M random points over 1 M cells: 2**14 .. 2**17 within 25 %, 2**16 fastest) ...
_PART_CHUNK = 1 << 16
#: ... while its block segments average at least this many points (so the per-block reads stream)
_MIN_SEGMENT = 256


def _part_chunk(n_blocks: int) -> int:
    """Points per chunk of :func:`hadal.grid._kernels.partition_points` for ``n_blocks`` blocks."""
    return max(_PART_CHUNK, min(1 << 22, n_blocks * _MIN_SEGMENT))


def _block_shift(n_cells: int, threads: int) -> tuple[int, int]:
    """``(shift, nblocks)``: blocks of ``2**shift`` consecutive cells, at most ``2**14`` cells (cache-sized)
    unless that gives more than :data:`_MAX_BLOCKS` blocks (then up to ``2**16`` cells, the in-block index
    being uint16), and at least ``4 * threads`` blocks when the grid allows (so the per-block work spreads
    over the threads)."""
    shift = _BLOCK_SHIFT
    while shift > 6 and (n_cells >> shift) < 4 * threads:
        shift -= 1
    while (n_cells >> shift) > _MAX_BLOCKS and shift < _MAX_SHIFT:
        shift += 1
    return shift, (n_cells + (1 << shift) - 1) >> shift


def _partitioned_stats(kern, kb, zb, seg, shift: int, n_cells: int, stats: tuple[str, ...], ddof: int,
                       threads: int, raw_m2: bool = False) -> dict[str, np.ndarray]:
    """The statistics ``stats`` from the partitioned points (and, with ``raw_m2``, ``"m2"``: the per-cell sum of
    squared deviations, NaN in empty cells)."""
    want_m2 = "std" in stats or raw_m2
    want_sorted = any(s in stats for s in ("median", "min", "max"))
    count, mean, m2, med, zmin, zmax = kern.block_stats_kernel(kb, zb, seg, shift, n_cells, want_m2,
                                                               want_sorted, max(1, int(threads)))
    out = {"count": count, "mean": mean, "median": med, "min": zmin, "max": zmax}
    res = {s: out[s] for s in stats if s != "std"}
    if "std" in stats:
        res["std"] = _std(m2, count, ddof)
    if raw_m2:
        res["m2"] = m2
    return {s: res[s] for s in (*stats, "m2") if s in res}


def cell_stats(x, y, z, spec: GridSpec, statistics: Sequence[str] = ("mean", "median", "count", "std"), *,
               check_inside: bool = True, ddof: int = 1, threads: int = 2, _m2: bool = False
               ) -> tuple[dict[str, np.ndarray], int, int] | None:
    """All per-cell statistics of :func:`reduce_cells` straight from the points, compiled and cache-friendly:
    ``(flat statistics, n_nonfinite, n_outside)``, or None without numba, for fewer than
    :data:`_COMPILED_MIN_POINTS` points or for a grid of 2**31 cells or more; the NumPy
    :func:`point_indices` + :func:`_reduce_cells_numpy` path is the reference it is tested against.

    Method (:mod:`hadal.grid._kernels`): one read of the points in chunks of :func:`_part_chunk` points, each
    chunk's cell indices computed into a cache-resident buffer and the chunk counting-sorted by block of
    ``2**shift`` consecutive cells (:func:`_block_shift`) into its own slice of the output (no separate
    histogram pass over the input); then per block, its segments of all chunks in file order, a counting
    sort by cell (the histograms stay in L2) and per cell the mean and M2 (sums shifted by the cell's first
    value: exact at 10 km depths with mm spread, no cancellation; count/mean/std in one pass, the block
    recomputed two-pass where a cell's rounding bound is not negligible; two-pass with median/min/max), and,
    for median/min/max, the cell's values grouped in cache and the middle values selected (Hoare's
    quickselect; median = mean of the two middle values for an even count, as :func:`segment_median`), min and
    max scanned. Every pass streams through memory; none does random access into a grid-sized
    array, so random point order costs about as much as survey order. Memory: 10 bytes a point (uint16
    in-block cell index, float64 value) plus the chunks' block offsets.
    """
    x, y, z = _as_f64(x), _as_f64(y), _as_f64(z)
    n = _check_lengths(x, y, z)
    kern = _partition_kernels() if n >= _COMPILED_MIN_POINTS else None
    if kern is None or spec.n_cells >= 2**31 - 1:
        return None
    stats = _check_stats(statistics)
    nthreads = max(1, min(int(threads), max(1, n // 65536)))
    shift, nblocks = _block_shift(spec.n_cells, nthreads)
    kb, zb, seg, bad, out = kern.partition_points(
        x, y, z, float(spec.x0), float(spec.y0), 1.0 / spec.resolution, int(spec.nx), int(spec.ny),
        bool(check_inside), shift, nblocks, _part_chunk(nblocks), nthreads)
    if bad == n:
        raise InputError(f"all {n} points have NaN/inf coordinates; nothing to grid")
    flat = _partitioned_stats(kern, kb, zb, seg, shift, spec.n_cells, stats, ddof, nthreads, raw_m2=_m2)
    return flat, int(bad), int(out)


def _cell_sums_numba(kernel, x, y, z, spec: GridSpec, z0: float, check_inside: bool, threads: int):
    """Same sums as :func:`_cell_sums_numpy` in one fused pass: the index arithmetic of
    :meth:`GridSpec.cell_index` and the three accumulations per point, with (count, S1, S2) of a cell
    side by side in memory (one cache miss per point instead of three), ``threads`` contiguous
    blocks in parallel and their per-thread sums added."""
    import numpy as np

    nthreads = max(1, min(int(threads), max(1, len(x) // 65536)))
    acc, bad, out = kernel(x, y, z, float(spec.x0), float(spec.y0), 1.0 / spec.resolution, int(spec.nx),
                           int(spec.ny), float(z0), bool(check_inside), nthreads)
    return acc[:, 0].astype(np.int64), np.ascontiguousarray(acc[:, 1]), np.ascontiguousarray(acc[:, 2]), int(bad), int(out)


def _exact_cells(x, y, z, spec, ill, mean, m2, z0, check_inside, all_finite) -> None:
    """Recompute mean (minus ``z0``) and M2 of the ``ill`` cells two-pass from just their points."""
    import numpy as np

    idxs, zs = [], []
    for sl in _chunk_slices(len(x), 1 << 20):
        idx, zc, _, _ = _chunk_index(spec, x[sl], y[sl], z[sl], check_inside, all_finite)
        sel = ill[idx]
        idxs.append(idx[sel])
        zs.append(zc[sel])
    idx, zc = np.concatenate(idxs), np.concatenate(zs)
    cells, inv = np.unique(idx, return_inverse=True)
    r = reduce_cells(inv, zc, len(cells), ("count", "mean", "std"), ddof=0)
    mean[cells] = r["mean"] - z0
    m2[cells] = r["std"] ** 2 * r["count"]


def point_indices(x, y, z, spec: GridSpec, *, check_inside: bool = True
                  ) -> tuple[np.ndarray, np.ndarray, int, int]:
    """Flat cell index and value of every valid point (finite, inside the grid), plus the drop counts."""
    import numpy as np

    x, y, z = _as_f64(x), _as_f64(y), _as_f64(z)
    n = _check_lengths(x, y, z)
    idxs, zs = [], []
    bad = out = 0
    for sl in _chunk_slices(n, 1 << 20):
        idx, zc, b, o = _chunk_index(spec, x[sl], y[sl], z[sl], check_inside)
        idxs.append(idx)
        zs.append(zc if (b or o) else zc.copy())
        bad += b
        out += o
    if bad == n:
        raise InputError(f"all {n} points have NaN/inf coordinates; nothing to grid")
    return np.concatenate(idxs), np.concatenate(zs), bad, out


def reduce_cells(
    idx: np.ndarray,
    z: np.ndarray,
    n_cells: int,
    statistics: Sequence[str] = ("mean", "median", "count", "std"),
    *,
    ddof: int = 1,
    compiled: bool | None = None,
) -> dict[str, np.ndarray]:
    """Per-cell statistics of ``z`` grouped by flat cell index ``idx`` (0 <= idx < n_cells), as flat arrays.

    Float statistics are NaN in empty cells (and ``std`` where ``count <= ddof``); ``count`` is int64.
    With numba: the block-partitioned kernels of :func:`cell_stats`; otherwise (and as the reference,
    :func:`_reduce_cells_numpy`) a two-pass ``bincount`` for mean/std and the (cell, z) ``lexsort``
    for median/min/max. Both give a cell's statistics from that cell's own values in input order only, so a
    subset of the cells (a tile, :mod:`hadal.grid.tiles`) reduced alone gives the same bits, provided it takes
    the same path: ``compiled`` (None: compiled from :data:`_COMPILED_MIN_POINTS` points on) forces the choice
    the whole point set would have made (the compiled path still needs numba and fewer than 2**31 cells).
    """
    import numpy as np

    stats = _check_stats(statistics)
    idx = np.asarray(idx)
    if len(idx) != len(z):
        raise InputError(f"idx and z must have the same length (got {len(idx)}, {len(z)})")
    if len(idx) and (idx.min() < 0 or idx.max() >= n_cells):
        raise InputError(f"cell indices must lie in [0, {n_cells}) (got {idx.min()}..{idx.max()})")
    kern = _partition_kernels()
    if compiled is None:
        compiled = len(idx) >= _COMPILED_MIN_POINTS
    if kern is None or n_cells >= 2**31 - 1 or not compiled:
        return _reduce_cells_numpy(idx, z, n_cells, stats, ddof=ddof)
    z = _as_f64(z)
    if n_cells <= _GROUPED_MAX_CELLS and any(s in stats for s in ("median", "min", "max")):
        count, mean, m2, med, zmin, zmax = kern.cell_grouped_stats(idx, z, n_cells, "std" in stats)
        res = {"count": count, "mean": mean, "median": med, "min": zmin, "max": zmax}
        if "std" in stats:
            res["std"] = _std(m2, count, ddof)
        return {s: res[s] for s in stats}
    nthreads = max(1, min(2, len(idx) // 65536))
    shift, nblocks = _block_shift(n_cells, nthreads)
    kb, zb, seg = kern.partition_kernel(idx, z, shift, nblocks, _part_chunk(nblocks), nthreads)
    return _partitioned_stats(kern, kb, zb, seg, shift, n_cells, stats, ddof, nthreads)


def _reduce_cells_numpy(
    idx: np.ndarray,
    z: np.ndarray,
    n_cells: int,
    statistics: Sequence[str] = ("mean", "median", "count", "std"),
    *,
    ddof: int = 1,
) -> dict[str, np.ndarray]:
    """NumPy reference of :func:`reduce_cells` (two-pass ``bincount`` mean/std, (cell, z) ``lexsort``)."""
    import numpy as np

    stats = _check_stats(statistics)
    out: dict[str, np.ndarray] = {}
    count = np.bincount(idx, minlength=n_cells)
    if "mean" in stats or "std" in stats:
        mean = np.full(n_cells, np.nan)
        np.divide(np.bincount(idx, weights=z, minlength=n_cells), count, out=mean, where=count > 0)
        out["mean"] = mean
        if "std" in stats:
            d = z - mean[idx]
            d *= d
            out["std"] = _std(np.bincount(idx, weights=d, minlength=n_cells), count, ddof)
    if any(s in stats for s in ("median", "min", "max")):
        order, cells, starts, counts = sorted_segments(idx, z)
        zs = z[order]
        if "median" in stats:
            out["median"] = _scatter(n_cells, cells, segment_median(zs, starts, counts))
        if "min" in stats:
            out["min"] = _scatter(n_cells, cells, zs[starts])  # segments are sorted ascending
        if "max" in stats:
            out["max"] = _scatter(n_cells, cells, zs[starts + counts - 1])
    out["count"] = count
    return {s: out[s] for s in stats}


def _check_stats(statistics: Sequence[str]) -> tuple[str, ...]:
    stats = (statistics,) if isinstance(statistics, str) else tuple(statistics)
    unknown = [s for s in stats if s not in STATISTICS]
    if unknown or not stats:
        raise InputError(f"unknown grid statistic(s) {unknown}; choose from {', '.join(STATISTICS)}")
    return stats


def _scatter(n: int, cells: np.ndarray, values: np.ndarray) -> np.ndarray:
    import numpy as np

    full = np.full(n, np.nan)
    full[cells] = values
    return full


def _std(m2: np.ndarray, count: np.ndarray, ddof: int) -> np.ndarray:
    import numpy as np

    std = np.full(len(count), np.nan)
    ok = count > ddof
    np.divide(m2, count - ddof, out=std, where=ok)
    return np.sqrt(std, out=std, where=ok)


def grid_points(
    x,
    y,
    z,
    resolution: float,
    *,
    bounds: Sequence[float] | None = None,
    statistics: Sequence[str] = ("mean", "median", "count", "std"),
    ddof: int = 1,
    max_cells: int = DEFAULT_MAX_CELLS,
    z_attrs: dict | None = None,
    threads: int = 2,
) -> xr.Dataset:
    """Grid scattered points ``(x, y, z)`` into square cells of ``resolution`` (same units as x/y).

    Parameters
    ----------
    x, y, z : array-like, same length. Points with a NaN/inf coordinate are dropped and counted
        (``attrs["n_points_nonfinite"]``); all-NaN or empty input raises :class:`InputError`.
    resolution : cell size (> 0).
    bounds : ``(xmin, ymin, xmax, ymax)`` of the grid; points outside are dropped and counted
        (``attrs["n_points_outside"]``). Default: the points' extent, snapped to the resolution.
    statistics : any of ``mean, median, count, std, min, max`` (std is the sample std, ``ddof``).
        Without median/min/max the single-read chunked path (:func:`cell_moments`) is used.
    max_cells : refuse (InputError) grids larger than this.
    z_attrs : attributes (e.g. units) copied onto every float statistic.

    Returns
    -------
    xarray.Dataset with one ``(y, x)`` variable per statistic, cell-centre coordinates ``x``/``y``
    (ascending), empty cells NaN with ``count == 0``; attrs ``resolution``, ``n_points_used``,
    ``n_points_nonfinite``, ``n_points_outside``.
    """
    stats = _check_stats(statistics)
    x, y, z = _as_f64(x), _as_f64(y), _as_f64(z)
    check_resolution(resolution)
    n_bad0 = -1
    if bounds is None:
        ext, n_bad0 = point_extent(x, y, z)
        spec = make_grid_spec(resolution, ext, max_cells=max_cells, snap=True)
    else:
        _check_lengths(x, y, z)
        spec = make_grid_spec(resolution, bounds, max_cells=max_cells)
    check = bounds is not None
    if any(s in stats for s in ("median", "min", "max")):
        res = cell_stats(x, y, z, spec, stats, check_inside=check, ddof=ddof, threads=threads)
        if res is not None:
            flat, n_bad, n_out = res
            n_used = int(flat["count"].sum()) if "count" in flat else len(z) - n_bad - n_out
        else:
            idx, zz, n_bad, n_out = point_indices(x, y, z, spec, check_inside=check)
            flat = _reduce_cells_numpy(idx, zz, spec.n_cells, stats, ddof=ddof)
            n_used = len(zz)
    else:
        cnt, mean, m2, n_bad, n_out = cell_moments(x, y, z, spec, check_inside=check,
                                                  need_m2="std" in stats, threads=threads,
                                                  all_finite=n_bad0 == 0)
        flat = {"count": cnt, "mean": mean}
        if "std" in stats:
            flat["std"] = _std(m2, cnt, ddof)
        flat = {s: flat[s] for s in stats}
        n_used = int(cnt.sum())
    return to_dataset(spec, flat, z_attrs=z_attrs, attrs={
        "n_points_used": n_used, "n_points_nonfinite": int(n_bad), "n_points_outside": int(n_out),
    })


def to_dataset(spec: GridSpec, flat: dict[str, np.ndarray], *, z_attrs: dict | None = None,
               attrs: dict | None = None, names: dict[str, str] | None = None) -> xr.Dataset:
    """Wrap flat per-cell arrays into an ``(y, x)`` Dataset on ``spec``'s cell centres."""
    import xarray as xr

    names = names or {}
    data_vars = {}
    for stat, arr in flat.items():
        a = dict(_STAT_ATTRS.get(stat, {}))
        if stat != "count":
            a.update(z_attrs or {})
        data_vars[names.get(stat, stat)] = (("y", "x"), arr.reshape(spec.ny, spec.nx), a)
    ds = xr.Dataset(
        data_vars,
        coords={
            "x": ("x", spec.x, {"long_name": "cell centre x", "axis": "X"}),
            "y": ("y", spec.y, {"long_name": "cell centre y", "axis": "Y"}),
        },
    )
    ds.attrs.update({"resolution": spec.resolution, "grid_x0_edge": spec.x0, "grid_y0_edge": spec.y0})
    ds.attrs.update(attrs or {})
    return ds
