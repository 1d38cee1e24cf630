"""Split a CTD record into its descent (downcast) and ascent (upcast) at the deepest good scan.

As SBE Data Processing's "split" / BinAvg cast selection and ``seabirdscientific.processing.find_downcast`` /
``find_upcast``: the downcast runs from the shallowest good scan deeper than ``min_depth`` before the
deepest good scan to that deepest scan; the upcast from the deepest good scan to the last good scan deeper
than ``min_depth``. Works on pressure (dbar) or depth (m) alike.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from hadal.errors import InputError


def _valid(z: np.ndarray, bad: ArrayLike | None) -> np.ndarray:
    ok = np.isfinite(z)
    if bad is not None:
        ok &= ~np.asarray(bad, dtype=bool)
    if not ok.any():
        raise InputError("cast split: every scan is bad or missing")
    return ok


def find_downcast(z: ArrayLike, bad: ArrayLike | None = None, min_depth: float = -np.inf) -> tuple[int, int]:
    """``(start, end)`` scan indices (inclusive) of the downcast."""
    v = np.asarray(z, dtype=np.float64)
    ok = _valid(v, bad)
    end = int(np.argmax(np.where(ok, v, -np.inf)))
    cand = ok[: end + 1] & (v[: end + 1] > min_depth)
    if not cand.any():
        return end, end
    return int(np.argmin(np.where(cand, v[: end + 1], np.inf))), end


def find_upcast(z: ArrayLike, bad: ArrayLike | None = None, min_depth: float = -np.inf) -> tuple[int, int]:
    """``(start, end)`` scan indices (inclusive) of the upcast."""
    v = np.asarray(z, dtype=np.float64)
    ok = _valid(v, bad)
    start = int(np.argmax(np.where(ok, v, -np.inf)))
    cand = np.flatnonzero(ok[start:] & (v[start:] > min_depth))
    return start, start + int(cand[-1]) if cand.size else start


def cast_labels(z: ArrayLike, bad: ArrayLike | None = None, min_depth: float = -np.inf) -> np.ndarray:
    """Per scan ``"descent"``, ``"ascent"`` or ``""`` (outside both casts); the deepest scan is descent."""
    v = np.asarray(z, dtype=np.float64)
    d0, d1 = find_downcast(v, bad, min_depth)
    u0, u1 = find_upcast(v, bad, min_depth)
    out = np.full(v.size, "", dtype=object)
    out[u0 + 1: u1 + 1] = "ascent"
    out[d0: d1 + 1] = "descent"
    return out
