"""Time alignment of sensor streams onto the CTD time base.

* :func:`clean_times` drops backward clock jumps, sorts a stream by time (stable), drops identical rows and
  spreads distinct samples that share a coarse time stamp over the stamp interval; every step is counted
  (recorded in the product metadata).
* :func:`align_linear` interpolates linearly between the two valid samples that bracket each base time,
  but only when they are at most ``max_gap_s`` apart: no interpolation across a longer gap (or outside the
  stream's time span) - those base samples become NaN and later get QARTOD flag 9 (missing).
  ``circular=True`` interpolates angles (heading) on the unwrapped series and wraps back to [0, 360).
* :func:`align_nearest` takes the nearest sample (``pandas.merge_asof(direction="nearest")``) within
  ``max_gap_s``; used for the altimeter whose range is quantised (0.3 m) and whose dropouts (NaN) must not
  be bridged by interpolation.
* :func:`align_fix` puts each fix of a sparse GNSS/USBL stream at its nearest base sample only.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

__all__ = ["clean_times", "align_linear", "align_nearest", "align_fix", "align_sensor", "plausible_window", "time_unit_hint",
           "overlap_stats", "out_of_range", "describe_offset", "iso_ns"]


#: a row whose time is behind the latest earlier time by more than this (or 10 sampling intervals, whichever
#: is larger) is part of a backward clock jump, not a reordered sample
JUMP_BACK_MIN_S = 1.0
#: more than this fraction of a stream's rows in backward clock jumps: refuse (the clock is unusable)
JUMP_BACK_MAX_FRACTION = 0.5


def _identical_rows(ts: np.ndarray, vals: list[np.ndarray]) -> np.ndarray:
    """Mask (over the time-sorted rows) of rows identical to an earlier row: same time and same value in every
    variable (NaN equal to NaN); the first of each set of identical rows is not marked."""
    n = ts.size
    dup = np.zeros(n, dtype=bool)
    same_t = np.zeros(n, dtype=bool)
    same_t[1:] = ts[1:] == ts[:-1]
    if not same_t.any():
        return dup
    # only rows in a group of equal times take part; sort them by (time, values), file order kept for ties
    grp = same_t.copy()
    grp[:-1] |= same_t[1:]
    idx = np.flatnonzero(grp)
    keys = [np.nan_to_num(v[idx], nan=np.inf) for v in vals] + [np.isnan(v[idx]) for v in vals]
    order = np.lexsort((idx, *keys, ts[idx]))  # last key first: time, then values, then file order
    j = idx[order]
    eq = ts[j[1:]] == ts[j[:-1]]
    for v in vals:
        a, b = v[j[1:]], v[j[:-1]]
        eq &= (a == b) | (np.isnan(a) & np.isnan(b))
    dup[j[1:][eq]] = True
    return dup


def clean_times(time_ns: np.ndarray, values: dict[str, np.ndarray]) -> tuple[np.ndarray, dict[str, np.ndarray], dict[str, Any]]:
    """Put a stream's rows in time order; drop backward clock jumps and identical rows; spread coarse stamps.

    In this order:

    1. **Backward clock jumps** (file order): a row whose time is behind the latest earlier time by more
       than ``max(JUMP_BACK_MIN_S, 10 sampling intervals)`` belongs to a clock jump; those rows overlap data
       already logged and their times cannot be trusted, so they are dropped (``clock_jump_rows``, the
       number of jumps and the largest jump ``clock_jump_max_s`` are returned). More than
       :data:`JUMP_BACK_MAX_FRACTION` of the rows in jumps is an :class:`~hadal.errors.InputError`.
    2. Smaller inversions are sorted (stable); ``out_of_order`` counts the rows behind an earlier time (rows
       affected, not inversions).
    3. **Duplicates** are rows identical to another in time *and* every value: dropped (``duplicates``).
    4. **Coarse time stamps**: rows that share a time stamp but hold different values are distinct samples
       logged with a coarse clock (a logger stamping once per write batch, whole-second text times). They
       are spread evenly over the stamp interval, in file order: the ``i``-th of ``k`` rows stamped ``T``
       gets ``T + i (T' - T) / k`` where ``T'`` is the next distinct stamp (the median stamp interval after
       the last one) - each stamp is taken as the start of its batch, so times can be late by up to one
       interval when the logger stamps the end. ``coarse_rows`` counts them, ``coarse_resolution_s`` is the
       median interval between distinct stamps of those groups and ``coarse_max_per_stamp`` the largest group.
    """
    from hadal.errors import InputError

    t = np.asarray(time_ns, dtype=np.int64)
    vals = {k: np.asarray(v, dtype=np.float64) for k, v in values.items()}
    st: dict[str, Any] = {"out_of_order": 0, "duplicates": 0, "clock_jump_rows": 0, "clock_jumps": 0,
                          "clock_jump_max_s": 0.0, "coarse_rows": 0, "coarse_resolution_s": None,
                          "coarse_max_per_stamp": 1}
    if t.size < 2:
        return t.copy(), vals, st
    d = np.diff(t)
    if (d < 0).any():
        prev_max = np.maximum.accumulate(t)[:-1]
        behind_by = np.zeros(t.size, dtype=np.int64)
        behind_by[1:] = np.maximum(prev_max - t[1:], 0)
        nz = np.abs(d[d != 0])
        step = float(np.median(nz)) if nz.size else 0.0
        tol = max(JUMP_BACK_MIN_S * 1e9, 10.0 * step)
        # a jump starts at one backward step larger than ``tol`` and lasts while the rows stay behind the
        # latest time before it (a file in reverse order steps back a little every row: sorted, not a jump)
        starts = np.flatnonzero(d < -tol) + 1
        if starts.size > 100:  # a shuffled stream: every row far behind the running maximum
            jump = behind_by > tol
        else:
            jump = np.zeros(t.size, dtype=bool)
            for s0 in starts.tolist():
                ahead = np.flatnonzero(t[s0:] >= prev_max[s0 - 1])
                jump[s0:s0 + (int(ahead[0]) if ahead.size else t.size - s0)] = True
        n_jump = int(jump.sum())
        if n_jump:
            starts = np.flatnonzero(jump & ~np.r_[False, jump[:-1]])
            step = float(np.median(d[d > 0])) if (d > 0).any() else 0.0
            st.update(clock_jump_rows=n_jump, clock_jumps=int(starts.size),
                      clock_jump_max_s=(float(behind_by[starts].max()) + step) / 1e9)
            if n_jump > JUMP_BACK_MAX_FRACTION * t.size:
                raise InputError(f"{n_jump} of {t.size} rows lie in backward clock jump(s) (up to "
                                 f"{st['clock_jump_max_s']:.3g} s back): the logger clock is unusable")
            keep = ~jump
            t, vals, behind_by = t[keep], {k: v[keep] for k, v in vals.items()}, behind_by[keep]
        st["out_of_order"] = int(np.count_nonzero(behind_by > 0))
    order = np.argsort(t, kind="stable") if st["out_of_order"] else np.arange(t.size)
    ts = t[order]
    vs = {k: v[order] for k, v in vals.items()}
    dup = _identical_rows(ts, list(vs.values()))
    if dup.any():
        st["duplicates"] = int(dup.sum())
        ts, vs = ts[~dup], {k: v[~dup] for k, v in vs.items()}
    if ts.size > 1 and (ts[1:] == ts[:-1]).any():
        new = np.r_[True, ts[1:] != ts[:-1]]
        gid = np.cumsum(new) - 1
        gstart = np.flatnonzero(new)
        gsize = np.diff(np.r_[gstart, ts.size])
        gt = ts[gstart]
        gaps = np.diff(gt)
        multi = gsize > 1
        mgaps = gaps[multi[:-1]] if gaps.size else gaps
        med = int(np.median(gaps)) if gaps.size else 0
        nxt = np.r_[gaps, med]  # the stamp interval of each group
        rank = np.arange(ts.size) - gstart[gid]
        ts = ts + (rank * nxt[gid]) // gsize[gid]
        st.update(coarse_rows=int(gsize[multi].sum()), coarse_max_per_stamp=int(gsize.max()),
                  coarse_resolution_s=float(np.median(mgaps if mgaps.size else nxt[multi])) / 1e9)
        # sub-ns collisions (an interval shorter than its group) stay equal: keep the first of those
        ok = np.r_[True, ts[1:] > ts[:-1]]
        if not ok.all():
            st["duplicates"] += int((~ok).sum())
            ts, vs = ts[ok], {k: v[ok] for k, v in vs.items()}
    return ts, vs, st


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


def align_fix(base_ns: np.ndarray, t_ns: np.ndarray, v: np.ndarray, max_gap_s: float) -> np.ndarray:
    """Each sample of a sparse fix stream (GNSS, USBL) at the one base sample nearest its time (within
    ``max_gap_s``), NaN elsewhere: a fix is one measurement, not a series to interpolate or repeat (a USBL fix
    every few minutes spread over the base samples between them would be taken for many independent fixes).
    Two fixes nearest the same base sample: the later one."""
    base = np.asarray(base_ns, np.int64)
    out = np.full(base.size, np.nan)
    t = np.asarray(t_ns, np.int64)
    vv = np.asarray(v, float)
    if base.size == 0 or t.size == 0:
        return out
    j = np.clip(np.searchsorted(base, t), 1, max(base.size - 1, 1)) if base.size > 1 else np.zeros(t.size, np.int64)
    if base.size > 1:
        j = np.where(np.abs(base[j - 1] - t) <= np.abs(base[j] - t), j - 1, j)
    ok = (np.abs(base[j] - t) <= max_gap_s * 1e9) & np.isfinite(vv)
    out[j[ok]] = vv[ok]
    return out


#: variables of fix streams: each fix at its nearest base sample (:func:`align_fix`)
FIX_VARIABLES = tuple(f"{s}_{v}" for s in ("gnss", "usbl")
                      for v in ("latitude_deg", "longitude_deg", "east_variance_m2", "north_variance_m2"))
#: default method per variable (others: linear)
DEFAULT_METHODS: dict[str, str] = {"altitude_m": "nearest", "heading_deg": "circular",
                                   **dict.fromkeys(FIX_VARIABLES, "fix")}


def align_sensor(base_ns: np.ndarray, t_ns: np.ndarray, values: dict[str, np.ndarray], max_gap_s: float,
                 methods: dict[str, str] | None = None, nearest_max_gap_s: float | None = None
                 ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """Align all variables of one (cleaned) sensor stream onto ``base_ns``.

    ``nearest_max_gap_s``: the tolerance of the variables aligned to their nearest sample (default
    ``max_gap_s``); a held value is one reading, not an interpolation, so its tolerance is how far from that
    reading it still stands for the vehicle (an altitude held for a minute of a glider's dive is metres wrong).

    Returns the aligned arrays and statistics: samples used, base samples left without data by gaps or
    outside the stream's span (``gap_filled_nan``) per variable.
    """
    methods = {**DEFAULT_METHODS, **(methods or {})}
    near_gap = max_gap_s if nearest_max_gap_s is None else nearest_max_gap_s
    out, stats = {}, {"samples": int(np.asarray(t_ns).size), "max_gap_s": max_gap_s, "missing_after_alignment": {}}
    for var, v in values.items():
        m = methods.get(var, "linear")
        if m == "nearest":
            if near_gap != max_gap_s:
                stats.setdefault("nearest_max_gap_s", near_gap)
            a = align_nearest(base_ns, t_ns, v, near_gap)
        elif m == "fix":
            a = align_fix(base_ns, t_ns, v, max_gap_s)
        else:
            a = align_linear(base_ns, t_ns, v, max_gap_s, circular=(m == "circular"))
        out[var] = a
        stats["missing_after_alignment"][var] = int(np.count_nonzero(~np.isfinite(a)))
    return out, stats


# --------------------------------------------------------------------------------------------------------------
# time sanity: plausible range, unit guesses, overlap with the time base
# --------------------------------------------------------------------------------------------------------------

#: earliest plausible sample time (ns since the Unix epoch): 1980-01-01T00:00:00Z
PLAUSIBLE_START_NS = 315_532_800 * 1_000_000_000
#: latest plausible sample time: now + this (ns)
PLAUSIBLE_FUTURE_NS = 86_400 * 1_000_000_000
_NAT = np.iinfo(np.int64).min

#: unit -> ns per unit (for unit guesses)
_UNITS = (("seconds", "unix_s", 1e9), ("milliseconds", "unix_ms", 1e6), ("microseconds", "unix_us", 1e3),
          ("nanoseconds", "unix_ns", 1.0))


def plausible_window() -> tuple[int, int]:
    """(start, end) in ns since the epoch of plausible data times: 1980-01-01 .. now + 1 day."""
    import time

    return PLAUSIBLE_START_NS, time.time_ns() + PLAUSIBLE_FUTURE_NS


def iso_ns(t: int) -> str:
    """``YYYY-MM-DDTHH:MM:SSZ`` of ns since the epoch (any int64)."""
    return str(np.datetime64(int(t), "ns").astype("datetime64[s]")) + "Z"


def time_unit_hint(raw: np.ndarray | float, declared: str) -> str | None:
    """A guess of the real unit of numeric times that are implausible in their ``declared`` unit
    (``unix_ns``/``unix_ms``/``unix_s``): ``"looks like milliseconds since 1970 (unix_ms), not nanoseconds"``;
    ``None`` when no unit makes the median value plausible. ``raw``: the numbers as logged."""
    scale = {"unix_ns": 1.0, "unix_ms": 1e6, "unix_s": 1e9, "log_time": 1.0}.get(declared)
    if scale is None:
        return None
    x = np.asarray(raw, dtype=np.float64).ravel()
    x = x[np.isfinite(x)]
    if x.size == 0:
        return None
    med = float(np.median(x))
    lo, hi = plausible_window()
    name_of = {s: n for n, _, s in _UNITS}
    for name, fmt, s in _UNITS:
        if s != scale and lo <= med * s <= hi:
            return (f"looks like {name} since 1970 ({fmt}), not {name_of.get(scale, declared)}"
                    f" (median {med:.6g} -> {iso_ns(int(med * s))})")
    return None


def out_of_range(t_ns: np.ndarray, lo: int, hi: int) -> np.ndarray:
    """Mask of times outside [lo, hi] (NaT counts as outside)."""
    t = np.asarray(t_ns, dtype=np.int64)
    return (t < lo) | (t > hi) | (t == _NAT)


def overlap_stats(base_ns: np.ndarray, t_ns: np.ndarray) -> dict[str, float]:
    """How a sensor's time span overlaps the time base's: ``overlap`` (fraction of the time base's span
    covered by the sensor's span, 0..1), ``offset_s`` (sensor start - time-base start) and
    ``midpoint_offset_s`` (sensor span midpoint - time-base span midpoint). Both arrays sorted."""
    b0, b1 = int(base_ns[0]), int(base_ns[-1])
    s0, s1 = int(t_ns[0]), int(t_ns[-1])
    span = b1 - b0
    inter = max(0, min(b1, s1) - max(b0, s0))
    if span > 0:
        frac = inter / span
    else:
        frac = 1.0 if s0 <= b0 <= s1 else 0.0
    return {"overlap": float(frac), "offset_s": (s0 - b0) / 1e9,
            "midpoint_offset_s": ((s0 + s1) / 2 - (b0 + b1) / 2) / 1e9}


def describe_offset(offset_s: float, hint: bool = True) -> str:
    """``+1 h 00 min`` style text of an offset; a time-zone hint when it is close to whole hours."""
    sign = "+" if offset_s >= 0 else "-"
    a = abs(offset_s)
    if a < 120:
        txt = f"{sign}{a:.1f} s"
    elif a < 2 * 86400:
        txt = f"{sign}{int(a // 3600)} h {int(a % 3600 // 60):02d} min"
    else:
        txt = f"{sign}{a / 86400:.1f} days"
    hours = a / 3600
    if hint and 0.9 <= hours <= 14.5 and abs(hours - round(hours * 2) / 2) < 0.02:
        txt += " (a whole number of hours: a time-zone or clock setting?)"
    return txt
