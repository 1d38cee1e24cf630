"""Filter: Sea-Bird's low-pass filter (SBE Data Processing manual, "Filter", low-pass filters A and B).

A single-pole filter of time constant ``Gamma`` (s) in its bilinear (Tustin) form, ``dt`` the sample interval::

    A = 1 / (1 + 2 Gamma / dt)
    B = A (1 - 2 Gamma / dt)
    y[n] = A (x[n] + x[n-1]) - B y[n-1]

run forward and then backward over the record so the result has no phase shift. Each pass starts in steady
state on its first value (SeaSoft's start-up; ``scipy.signal.lfilter_zi``). Sea-Bird's typical time constants:
SBE 911plus pressure 0.15 s; SBE 19plus pressure 1.0 s, conductivity and temperature 0.5 s.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.signal import lfilter, lfilter_zi


def low_pass_filter(x: ArrayLike, time_constant_s: float, sample_interval_s: float) -> np.ndarray:
    """``x`` low-pass filtered forward and backward with time constant ``time_constant_s``.

    NaN values (bad scans) are bridged by linear interpolation for the filter and are NaN again in the result
    (SeaSoft filters through flagged scans too); an all-NaN input is returned unchanged.
    """
    v = np.asarray(x, dtype=np.float64)
    if not (time_constant_s > 0 and sample_interval_s > 0):
        raise ValueError("low-pass filter: time constant and sample interval must be > 0 s")
    ok = np.isfinite(v)
    if not ok.any():
        return v.copy()
    w = v if ok.all() else np.interp(np.arange(v.size), np.flatnonzero(ok), v[ok])
    r = 2.0 * float(time_constant_s) / float(sample_interval_s)
    a = 1.0 / (1.0 + r)
    b = a * (1.0 - r)
    num, den = [a, a], [1.0, b]
    zi = lfilter_zi(num, den)
    y, _ = lfilter(num, den, w, zi=zi * w[0])
    y = y[::-1]
    y, _ = lfilter(num, den, y, zi=zi * y[0])
    y = y[::-1].copy()
    y[~ok] = np.nan
    return y
