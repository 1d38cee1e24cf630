"""BinAvg: average scans into pressure (or depth) bins, downcast and upcast apart (SBE Data Processing
manual, "Bin Average").

Bins are centred on multiples of ``bin_size``: bin ``k`` (``k >= 1``) holds the downcast scans with
``(k - 1/2) bin_size <= z < (k + 1/2) bin_size`` and the upcast scans with
``(k - 1/2) bin_size < z <= (k + 1/2) bin_size``. The record is split at its deepest good scan; the bin
containing it is one bin shared by both casts (SeaSoft's turn-around bin). The surface bin ``k = 0`` is
left out (SeaSoft's "surface bin" option is not implemented). Bad scans (``bad``, e.g. LoopEdit's or any
WildEdit flag) are left out entirely; NaN values of a variable are left out of that variable's mean only.
Bins with fewer than ``min_scans`` or more than ``max_scans`` scans are dropped. Every variable's mean is
the plain mean of its scans in the bin (also the binning variable itself, so ``prdM`` is the bin's mean
pressure, not its centre, as in SeaSoft's output). Computed with ``np.bincount`` (O(n)).

Deviation from ``seabirdscientific.processing.bin_average``: it always drops the shallowest upcast bin (meant
for the surface bin), also when the upcast ends below it; here a full upcast bin is kept (on casts that
reach the surface, as SeaSoft's test casts, both give the same bins).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from hadal.errors import InputError


@dataclass
class BinAverage:
    """Result of :func:`bin_average`, one entry per bin in file order (downcast bins by increasing ``z``,
    then upcast bins by decreasing ``z``)."""

    centre: np.ndarray  #: bin centre (``k * bin_size``)
    cast: np.ndarray  #: "descent" or "ascent" (the turn-around bin: "descent")
    nbin: np.ndarray  #: scans in the bin
    means: dict[str, np.ndarray] = field(default_factory=dict)


def bin_average(z: ArrayLike, values: Mapping[str, ArrayLike], bin_size: float, *, bad: ArrayLike | None = None,
                cast: Literal["both", "descent", "ascent"] = "both", min_scans: int = 1,
                max_scans: int | None = None) -> BinAverage:
    """Bin means of ``values`` by ``z`` (pressure in dbar or depth in m) in ``bin_size`` bins."""
    zz = np.asarray(z, dtype=np.float64)
    if not bin_size > 0:
        raise InputError(f"bin average: bin size must be > 0, got {bin_size}")
    keep = np.isfinite(zz)
    if bad is not None:
        keep &= ~np.asarray(bad, dtype=bool)
    idx = np.flatnonzero(keep)
    if idx.size == 0:
        raise InputError("bin average: no good scan with a finite pressure/depth")
    c = zz[idx] / float(bin_size)
    peak = int(np.argmax(c))
    k = np.empty(idx.size, dtype=np.int64)
    k[:peak] = np.floor(c[:peak] + 0.5)  # downcast: [k - 1/2, k + 1/2)
    k[peak:] = np.ceil(c[peak:] - 0.5)  # upcast: (k - 1/2, k + 1/2]
    kp = int(np.floor(c[peak] + 0.5))  # the deepest scan's bin (downcast rule), shared by the upcast
    k[peak] = kp
    # group number in file order: downcast k, upcast 2 kp - k (the turn-around bin is shared)
    g = k.copy()
    g[peak:] = 2 * kp - k[peak:]
    sel = k >= 1
    if cast == "descent":
        # SeaSoft's downcast-only averaging keeps the scan right after the deepest one (seabirdscientific)
        sel &= np.arange(idx.size) <= peak + 1
    elif cast == "ascent":
        sel &= np.arange(idx.size) >= peak
        sel &= g > kp  # SeaSoft drops the turn-around bin from an upcast-only average
    elif cast != "both":
        raise InputError(f"bin average: cast must be both, descent or ascent, got {cast!r}")
    gi = g[sel]
    if gi.size == 0:
        raise InputError("bin average: no scan deeper than half a bin")
    g0 = int(gi.min())
    gi = gi - g0
    m = int(gi.max()) + 1
    nbin = np.bincount(gi, minlength=m)
    used = nbin >= max(1, int(min_scans))
    if max_scans is not None:
        used &= nbin <= int(max_scans)
    groups = np.flatnonzero(used)
    kk = np.where(groups + g0 <= kp, groups + g0, 2 * kp - (groups + g0))
    out = BinAverage(centre=kk * float(bin_size),
                     cast=np.where(groups + g0 <= kp, "descent", "ascent").astype(object),
                     nbin=nbin[groups])
    rows = idx[sel]
    for name, v in values.items():
        x = np.asarray(v, dtype=np.float64)[rows]
        fin = np.isfinite(x)
        s = np.bincount(gi[fin], weights=x[fin], minlength=m)
        cnt = np.bincount(gi[fin], minlength=m)
        with np.errstate(invalid="ignore", divide="ignore"):
            out.means[name] = np.where(cnt > 0, s / np.maximum(cnt, 1), np.nan)[groups]
    return out
