"""AlignCTD: advance a channel in time relative to pressure (SBE Data Processing manual, "Align CTD").

A positive advance moves the channel's values earlier: the aligned value at scan ``i`` is the value the
sensor read ``advance_s`` later, ``x(t_i + advance_s)``, linearly interpolated between scans when the
advance is not a multiple of the sample interval. Scans whose source time falls outside the record have
no value (SeaSoft writes the bad flag; here NaN). An advance so long that *no* scan has a source inside the
record would blank the channel: that is a one-line :class:`~hadal.errors.InputError` (the processing chain
then leaves the channel unaligned and says so in its log).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from hadal.errors import InputError


def align_ctd(x: ArrayLike, advance_s: float, sample_interval_s: float) -> np.ndarray:
    """``x`` advanced by ``advance_s`` seconds (negative: delayed) on a uniform ``sample_interval_s`` grid.

    An advance that is a whole number of scans is a pure shift (exact); otherwise the two neighbouring scans
    are interpolated linearly, as AlignCTD does. NaN values stay NaN and spread to the interpolated
    neighbours only. An advance not shorter than the record (no scan would keep a value) is an
    :class:`~hadal.errors.InputError`.
    """
    v = np.asarray(x, dtype=np.float64)
    if not sample_interval_s > 0:
        raise ValueError(f"sample interval must be > 0 s, got {sample_interval_s}")
    n = v.size
    shift = float(advance_s) / float(sample_interval_s)
    if not np.isfinite(shift):
        raise InputError(f"AlignCTD: advance {advance_s} s is not a finite number of scans")
    out = np.full(n, np.nan)
    k = int(np.floor(shift))
    frac = shift - k
    whole = abs(frac) < 1e-9 or abs(frac - 1) < 1e-9
    if n and (abs(round(shift)) >= n if whole else max(0, -k) >= min(n, n - k - 1)):
        raise InputError(f"AlignCTD: an advance of {advance_s:g} s ({shift:g} scans at {sample_interval_s:g} s) is "
                         f"not shorter than the record ({n} scans): no scan would keep a value")
    if whole:  # whole number of scans
        k = int(round(shift))
        if k >= 0:
            out[: n - k] = v[k:]
        else:
            out[-k:] = v[: n + k]
        return out
    # out[i] = (1 - frac) * v[i + k] + frac * v[i + k + 1] where both indices are inside the record
    lo = max(0, -k)
    hi = min(n, n - k - 1)
    if hi > lo:
        out[lo:hi] = (1.0 - frac) * v[lo + k: hi + k] + frac * v[lo + k + 1: hi + k + 1]
    return out
