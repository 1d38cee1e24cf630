"""Inline geometry of the exact ring search over a uniform cell grid (:mod:`hadal.grid.knn_cells`), shared by the
compiled k-nearest-neighbour kernels (:mod:`hadal.grid._sor_kernels`, :mod:`hadal.grid._spike_kernels`): the cell a
point falls in, and a lower bound of the distance from the point to every point outside the block of rings searched
so far."""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(inline="always")
def home_cell(qu, qv, u0, v0, cs, ncu, ncv):  # pragma: no cover - compiled
    """``(cu, cv)``: the cell of the point ``(qu, qv)`` (clipped to the grid)."""
    return min(max(int((qu - u0) / cs), 0), ncu - 1), min(max(int((qv - v0) / cs), 0), ncv - 1)


@njit(inline="always")
def outside_bound(qu, qv, cu, cv, r, u0, v0, cs, ncu, ncv):  # pragma: no cover - compiled
    """Lower bound of the distance from ``(qu, qv)`` to any point outside the block of rings ``0..r`` about its cell
    ``(cu, cv)``, less a margin for the rounding of the cell assignment; ``inf`` when the block covers the grid."""
    bound = np.inf
    if cu - r > 0:
        bound = min(bound, qu - (u0 + (cu - r) * cs))
    if cu + r < ncu - 1:
        bound = min(bound, u0 + (cu + r + 1) * cs - qu)
    if cv - r > 0:
        bound = min(bound, qv - (v0 + (cv - r) * cs))
    if cv + r < ncv - 1:
        bound = min(bound, v0 + (cv + r + 1) * cs - qv)
    if bound == np.inf:
        return bound
    return bound - 1e-6 * cs
