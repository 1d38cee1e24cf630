"""LoopEdit: mark scans of pressure slowdowns and reversals bad (SBE Data Processing manual, "Loop Edit").

On the depth series (m, positive down; derive passes the Fofonoff-Millard depth of the pressure, as SeaSoft
converts pressure with the cast's latitude):

1. *Cast limits.* The downcast may start at the shallowest good scan before the first scan deeper than the
   maximum soak depth (with surface-soak removal: after the first good scan between the minimum and maximum
   soak depths). The upcast starts at the deepest scan after it. With ``use_deck_pressure_offset`` both soak
   depths are relative to the first scan's depth (the deck reading).
2. *Minimum velocity* (``fixed``): a downcast scan is bad unless the descent rates from the previous scan and
   to the next scan are both at least ``min_velocity_m_s`` (upcast: the ascent rates). *Percent of mean
   speed* (``percent``): a scan is bad unless its rate exceeds ``mean_speed_percent`` % of the mean rate over
   the previous ``window_s`` seconds (the first window: ``min_velocity_m_s``).
3. *Reversals.* A downcast scan not deeper than every earlier good downcast scan is bad (and, on the upcast,
   one not shallower than every earlier good upcast scan): the scans of a loop stay bad until the
   instrument passes the depth it turned at. Scans before the downcast start (the surface soak) are bad.

Scans already bad (``bad``) stay bad and are ignored in steps 1 and 3 (SeaSoft's "exclude scans marked
bad"). The rule set follows SeaSoft as reproduced by Sea-Bird's ``seabirdscientific.processing.loop_edit``;
step 3 is computed with running extrema instead of a scan loop: the deepest earlier *good* scan is also the
deepest earlier *not-already-bad* scan, because a scan that fails step 3 is never deeper than it.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from numpy.typing import ArrayLike


def _cast_limits(depth: np.ndarray, bad: np.ndarray, remove_surface_soak: bool, min_soak_m: float,
                 max_soak_m: float) -> tuple[int, int]:
    good = ~bad
    start = 0
    if remove_surface_soak:
        cand = np.flatnonzero((depth > min_soak_m) & (depth < max_soak_m) & good)
        start = int(cand[0]) if cand.size else 0
    deep = np.flatnonzero((depth > max_soak_m) & good)
    stop = int(deep[0]) if deep.size else depth.size  # never deeper than the soak: the whole record
    zone = np.where(good[start:stop], depth[start:stop], np.inf)
    if zone.size and np.isfinite(zone).any():
        min_n = int(np.argmin(zone)) + start
    else:
        min_n = start
    if min_n >= depth.size - 1:
        return min_n, depth.size - 1
    rest = np.where(np.isfinite(depth[min_n + 1:]), depth[min_n + 1:], -np.inf)
    return min_n, int(np.argmax(rest)) + min_n + 1


def _fixed_ok(depth: np.ndarray, dt: float, vmin: float, lo: int, hi: int, sign: float) -> np.ndarray:
    d = np.diff(depth)
    back = np.concatenate(([0.0], d)) * (sign / dt) >= vmin
    fwd = np.concatenate((d, [0.0])) * (sign / dt) >= vmin
    ok = back & fwd
    ok[:lo] = False
    ok[hi:] = False
    return ok


def _percent_ok(depth: np.ndarray, dt: float, vmin: float, pct: float, lo: int, hi: int, sign: float,
                L: int) -> np.ndarray:
    n = depth.size
    ok = np.zeros(n, dtype=bool)
    L = max(1, min(L, n))
    d = np.diff(depth) * (sign / dt)  # d[i-1]: rate into scan i
    head = min(L, n)
    if head > 1:
        ok[1:head] = (d[: head - 1] > vmin) & (d[1:head] > vmin) if head < n else np.concatenate(
            ((d[: head - 2] > vmin) & (d[1: head - 1] > vmin), [False]))
    if n > L:
        mean_rate = sign * (depth[L:] - depth[:-L]) / L / dt
        rate = d[L - 1:]
        ok[L:] = rate > mean_rate * pct / 100.0
    ok[:lo] = False
    ok[hi:] = False
    return ok


def loop_edit(depth_m: ArrayLike, sample_interval_s: float, *, min_velocity_m_s: float = 0.25,
              min_velocity_type: Literal["fixed", "percent"] = "fixed", window_s: float = 300.0,
              mean_speed_percent: float = 20.0, remove_surface_soak: bool = False, min_soak_depth_m: float = 5.0,
              max_soak_depth_m: float = 20.0, use_deck_pressure_offset: bool = True,
              bad: ArrayLike | None = None) -> np.ndarray:
    """Boolean mask of the scans LoopEdit marks bad (``True``), including those already ``bad``."""
    z = np.asarray(depth_m, dtype=np.float64)
    n = z.size
    prior = np.zeros(n, dtype=bool) if bad is None else np.asarray(bad, dtype=bool).copy()
    prior |= ~np.isfinite(z)
    if n == 0:
        return prior
    if not sample_interval_s > 0:
        raise ValueError(f"loop edit: sample interval must be > 0 s, got {sample_interval_s}")
    zf = np.where(np.isfinite(z), z, np.nan)
    if use_deck_pressure_offset:
        first = zf[np.isfinite(zf)]
        deck = float(first[0]) if first.size else 0.0
        min_soak_depth_m += deck
        max_soak_depth_m += deck
    lo, peak = _cast_limits(zf, prior, remove_surface_soak, min_soak_depth_m, max_soak_depth_m)
    zc = np.where(np.isfinite(zf), zf, 0.0)  # NaN depths are bad already; keep the rates finite
    if min_velocity_type == "fixed":
        down = _fixed_ok(zc, sample_interval_s, min_velocity_m_s, lo, peak + 1, 1.0)
        up = _fixed_ok(zc, sample_interval_s, min_velocity_m_s, peak, n, -1.0)
    elif min_velocity_type == "percent":
        L = int(window_s / sample_interval_s)
        down = _percent_ok(zc, sample_interval_s, min_velocity_m_s, mean_speed_percent, lo, peak, 1.0, L)
        up = _percent_ok(zc, sample_interval_s, min_velocity_m_s, mean_speed_percent, peak, n, -1.0, L)
    else:
        raise ValueError(f"loop edit: min_velocity_type must be 'fixed' or 'percent', got {min_velocity_type!r}")
    out = prior | (~down & ~up)
    # reversals: running extremum of the earlier not-yet-bad scans of the same cast (initial +-10 000 m)
    idx = np.arange(n)
    dom_down = (idx >= lo) & (idx < peak)
    cand = np.where(dom_down & ~out, zc, -1.0e4)
    run_max = np.maximum.accumulate(np.concatenate(([-1.0e4], cand[:-1])))
    good_down = dom_down & ~out & (zc > run_max)
    dom_up = idx >= peak
    cand = np.where(dom_up & ~out, zc, 1.0e4)
    run_min = np.minimum.accumulate(np.concatenate(([1.0e4], cand[:-1])))
    good_up = dom_up & ~out & (zc < run_min)
    return ~(good_down | good_up)
