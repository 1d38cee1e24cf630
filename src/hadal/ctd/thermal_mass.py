"""CellTM: conductivity cell thermal-mass correction (SBE Data Processing manual, "Cell Thermal Mass").

The recursive filter of Lueck (1990) as SeaSoft implements it, with ``alpha`` the thermal anomaly amplitude and
``1/beta`` its time constant (s), conductivity in S/m, ``dt`` the sample interval (s)::

    a = 2 alpha / (dt beta + 2)
    b = 1 - 2 a / alpha
    dc/dT = 0.1 (1 + 0.006 (T - 20))
    ctm[n] = -b ctm[n-1] + a (dc/dT) (T[n] - T[n-1])
    c_corrected[n] = c[n] + ctm[n]

Sea-Bird's typical values: SBE 9plus alpha 0.03, 1/beta 7 s; SBE 19plus alpha 0.04, 1/beta 8 s.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike
from scipy.signal import lfilter


def cell_thermal_mass(temperature_degc: ArrayLike, conductivity_s_m: ArrayLike, alpha: float = 0.03,
                      beta_inverse_s: float = 7.0, sample_interval_s: float = 1.0) -> np.ndarray:
    """Conductivity (S/m) corrected for the cell's thermal mass.

    Missing temperatures are held at the last valid one (leading ones at the first valid one), so the
    temperature change across a gap counts once, at the first scan after it, and one missing temperature
    does not make every later conductivity NaN (a deviation from SeaSoft, which has no missing values inside
    a record); NaN conductivities stay NaN.
    """
    t = np.asarray(temperature_degc, dtype=np.float64)
    c = np.asarray(conductivity_s_m, dtype=np.float64)
    if not (alpha > 0 and beta_inverse_s > 0 and sample_interval_s > 0):
        raise ValueError("cell thermal mass: alpha, 1/beta and the sample interval must be > 0")
    a = 2.0 * alpha / (sample_interval_s / beta_inverse_s + 2.0)
    b = 1.0 - 2.0 * a / alpha
    ok = np.isfinite(t)
    if not ok.any():
        return c.copy()
    if not ok.all():  # forward fill, then back fill the leading gap
        idx = np.where(ok, np.arange(t.size), 0)
        np.maximum.accumulate(idx, out=idx)
        t = t[idx]
        t[: int(np.argmax(ok))] = t[int(np.argmax(ok))]
    dcdt = 0.1 * (1.0 + 0.006 * (t - 20.0))
    dt = np.empty_like(t)
    if t.size:
        dt[0] = 0.0
        np.subtract(t[1:], t[:-1], out=dt[1:])
    x = dcdt * dt
    return c + lfilter([a], [1.0, b], x)
