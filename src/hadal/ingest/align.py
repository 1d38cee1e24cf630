"""Time alignment of sensor streams onto the CTD time base.

* :func:`clean_times` sorts a stream by time (stable), drops duplicated timestamps (first kept) and counts
  both the out-of-order samples and the duplicates (recorded in the product metadata).
* :func:`align_linear` interpolates linearly between the two valid samples that bracket each base time,
  but only when they are at most ``max_gap_s`` apart: no interpolation across a longer gap (or outside the
  stream's time span) - those base samples become NaN and later get QARTOD flag 9 (missing).
  ``circular=True`` interpolates angles (heading) on the unwrapped series and wraps back to [0, 360).
* :func:`align_nearest` takes the nearest sample (``pandas.merge_asof(direction="nearest")``) within
  ``max_gap_s``; used for the altimeter whose range is quantised (0.3 m) and whose dropouts (NaN) must not
  be bridged by interpolation.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

__all__ = ["clean_times", "align_linear", "align_nearest", "align_sensor"]


def clean_times(time_ns: np.ndarray, values: dict[str, np.ndarray]) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, int]]:
    """Sort by time and drop duplicate timestamps (keep the first in file order).

    Returns ``(time_ns, values, {"out_of_order": n, "duplicates": n})`` where ``out_of_order`` counts samples
    whose time is earlier than the previous sample's in file order.
    """
    t = np.asarray(time_ns, dtype=np.int64)
    n_ooo = int(np.count_nonzero(np.diff(t) < 0)) if t.size > 1 else 0
    order = np.argsort(t, kind="stable") if n_ooo else np.arange(t.size)
    ts = t[order]
    keep = np.ones(ts.size, dtype=bool)
    if ts.size > 1:
        keep[1:] = ts[1:] != ts[:-1]
    n_dup = int(ts.size - keep.sum())
    idx = order[keep]
    return t[idx], {k: np.asarray(v, dtype=np.float64)[idx] for k, v in values.items()}, {
        "out_of_order": n_ooo, "duplicates": n_dup}


def align_linear(base_ns: np.ndarray, t_ns: np.ndarray, v: np.ndarray, max_gap_s: float,
                 circular: bool = False) -> np.ndarray:
    """Linear interpolation of (``t_ns``, ``v``) (sorted, unique times) at ``base_ns`` with a gap limit.

    A base time exactly on a valid sample takes that sample; otherwise the bracketing valid samples must
    be at most ``max_gap_s`` apart, else NaN. ``circular``: ``v`` in degrees, interpolated on
    ``np.unwrap`` and returned modulo 360.
    """
    base = np.asarray(base_ns, dtype=np.int64)
    ok = np.isfinite(v)
    tv, vv = np.asarray(t_ns, dtype=np.int64)[ok], np.asarray(v, dtype=np.float64)[ok]
    out = np.full(base.shape, np.nan)
    if tv.size == 0:
        return out
    if circular:
        vv = np.rad2deg(np.unwrap(np.deg2rad(vv)))
    r = np.searchsorted(tv, base, side="left")  # tv[r-1] < base <= tv[r]
    exact = (r < tv.size) & (tv[np.minimum(r, tv.size - 1)] == base)
    inside = (r > 0) & (r < tv.size)
    rl = np.clip(r - 1, 0, tv.size - 1)
    rr = np.clip(r, 0, tv.size - 1)
    gap = (tv[rr] - tv[rl]) / 1e9
    use = (inside & (gap <= max_gap_s)) | exact
    # interpolate in float seconds relative to the first sample (int64 ns -> float64 loses nothing at ms)
    t0 = tv[0]
    out[use] = np.interp((base[use] - t0) / 1e9, (tv - t0) / 1e9, vv)
    if circular:
        out = np.mod(out, 360.0)
    return out


def align_nearest(base_ns: np.ndarray, t_ns: np.ndarray, v: np.ndarray, max_gap_s: float) -> np.ndarray:
    """Nearest sample (``merge_asof``, direction ``nearest``) within ``max_gap_s``; NaN samples stay NaN."""
    left = pd.DataFrame({"t": np.asarray(base_ns, dtype=np.int64)})
    right = pd.DataFrame({"t": np.asarray(t_ns, dtype=np.int64), "v": np.asarray(v, dtype=np.float64)})
    if right.empty:
        return np.full(left.shape[0], np.nan)
    order = np.argsort(left["t"].to_numpy(), kind="stable")
    merged = pd.merge_asof(left.iloc[order], right, on="t", direction="nearest",
                           tolerance=int(round(max_gap_s * 1e9)))
    out = np.empty(left.shape[0])
    out[order] = merged["v"].to_numpy(dtype=np.float64)
    return out


#: default method per variable (others: linear)
DEFAULT_METHODS: dict[str, str] = {"altitude_m": "nearest", "heading_deg": "circular"}


def align_sensor(base_ns: np.ndarray, t_ns: np.ndarray, values: dict[str, np.ndarray], max_gap_s: float,
                 methods: dict[str, str] | None = None) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Align all variables of one (cleaned) sensor stream onto ``base_ns``.

    Returns the aligned arrays and statistics: samples used, base samples left without data by gaps or
    outside the stream's span (``gap_filled_nan``) per variable.
    """
    methods = {**DEFAULT_METHODS, **(methods or {})}
    out, stats = {}, {"samples": int(np.asarray(t_ns).size), "max_gap_s": max_gap_s, "missing_after_alignment": {}}
    for var, v in values.items():
        m = methods.get(var, "linear")
        if m == "nearest":
            a = align_nearest(base_ns, t_ns, v, max_gap_s)
        else:
            a = align_linear(base_ns, t_ns, v, max_gap_s, circular=(m == "circular"))
        out[var] = a
        stats["missing_after_alignment"][var] = int(np.count_nonzero(~np.isfinite(a)))
    return out, stats
