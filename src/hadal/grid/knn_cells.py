"""The uniform lateral cell grid behind hadal's exact k-nearest-neighbour searches (laser SOR and spacing,
:mod:`hadal.grid._sor_kernels`; the multibeam neighbour spike test, :mod:`hadal.grid._spike_kernels`).

Points are binned on two axes into square cells of about :data:`POINTS_PER_CELL` x ``k`` points at the mean
density and sorted by cell, so a compiled search can scan rings of cells (each row of a ring one contiguous run of
points) until the k-th distance is within the searched block (exact, like a k-d tree, at a fraction of its cost on
survey-like clouds of even density). Clouds the grid does not suit (no extent, or one cell holding a large part of
the points) are reported as such and go to a k-d tree."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

#: lateral cell: about this many points a cell at the cloud's mean density
POINTS_PER_CELL = 0.5  # x k: the k-th neighbour then lies within the 3 x 3 block of cells for most points


def uniform_cells(pts: np.ndarray, lo: np.ndarray, a0: int, a1: int, k: int):
    """Uniform cells over columns ``a0``, ``a1`` of ``pts`` (about :data:`POINTS_PER_CELL` x ``k`` points a cell at
    the mean density, at most ~4 cells a point): ``(search work sum(count^2), cell size, ncu, ncv, cell of every
    point, counts)``, or None without extent in that plane."""
    n = len(pts)
    ext_u, ext_v = float(pts[:, a0].max() - lo[a0]), float(pts[:, a1].max() - lo[a1])
    area = ext_u * ext_v
    if not (area > 0 and np.isfinite(area)):
        return None
    cs = float(np.sqrt(POINTS_PER_CELL * k * area / n))
    if not (cs > 0 and max(ext_u, ext_v) / cs < 2.0**62):
        return None
    ncu, ncv = int(ext_u / cs) + 1, int(ext_v / cs) + 1
    if ncu * ncv > 4 * n + 16:  # thin clouds
        cs *= float(np.sqrt(ncu * ncv / (4 * n + 16)))
        ncu, ncv = int(ext_u / cs) + 1, int(ext_v / cs) + 1
    if max(ncu, ncv) > 4 * n + 16:  # a needle-thin extent (e.g. 1e30 m by 1e-30 m): no uniform grid suits it
        return None
    cu = np.minimum((pts[:, a0] - lo[a0]) / cs, ncu - 1).astype(np.int64)
    cv = np.minimum((pts[:, a1] - lo[a1]) / cs, ncv - 1).astype(np.int64)
    cell = cv * ncu + cu
    counts = np.bincount(cell, minlength=ncu * ncv)
    return int((counts.astype(np.int64) ** 2).sum()), cs, ncu, ncv, cell, counts


def too_dense(counts: np.ndarray, n: int, k: int) -> bool:
    """True when one cell holds more than ``max(64 k, 1 %)`` of the ``n`` points: a dense blob the uniform grid
    would search point by point (the caller falls back to a k-d tree)."""
    return int(counts.max()) > max(64 * k, n // 100)


@dataclass(frozen=True)
class CellOrder:
    """Points sorted by cell: point ``order[i]`` is the ``i``-th in cell order; cell ``c = cv * ncu + cu`` holds the
    sorted points ``starts[c]:starts[c + 1]``; ``u0``, ``v0`` the grid's corner, ``cs`` the cell size (m)."""

    order: np.ndarray
    starts: np.ndarray
    ncu: int
    ncv: int
    u0: float
    v0: float
    cs: float


def lateral_cell_order(x: np.ndarray, y: np.ndarray, k: int) -> CellOrder | None:
    """:class:`CellOrder` of the points ``(x, y)`` on the x/y plane for a ``k``-neighbour search, or None when the grid
    does not suit them (no extent, or :func:`too_dense`)."""
    pts = np.column_stack([x, y])
    lo = pts.min(axis=0)
    binned = uniform_cells(pts, lo, 0, 1, k)
    if binned is None:
        return None
    if too_dense(binned[5], len(pts), k):
        return None
    return sorted_by_cell(binned, float(lo[0]), float(lo[1]))


def sorted_by_cell(binned, u0: float, v0: float) -> CellOrder:
    """The :class:`CellOrder` of points binned by :func:`uniform_cells` (its return value ``binned``) over a grid whose
    corner is ``(u0, v0)``."""
    _, cs, ncu, ncv, cell, counts = binned
    order = np.argsort(cell, kind="stable")
    starts = np.zeros(ncu * ncv + 1, np.int64)
    np.cumsum(counts, out=starts[1:])
    return CellOrder(order, starts, ncu, ncv, u0, v0, cs)
