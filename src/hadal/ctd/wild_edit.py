"""WildEdit: block-wise two-pass standard-deviation rejection (SBE Data Processing manual, "Wild Edit").

For each block of ``scans_per_block`` scans:

1. compute the mean and standard deviation of the block and set aside (temporarily) every value at least
   ``std_pass_1`` standard deviations from the mean;
2. recompute mean and standard deviation without them, and mark bad every value of the block more than
   ``std_pass_2`` standard deviations *and* more than ``min_delta`` from that mean.

The last, partial block is judged with the statistics of the last ``scans_per_block`` scans of the record
(SeaSoft back-fills it from the previous block). With ``exclude_bad`` the scans already bad are left out
of the statistics. Standard deviations are sample ones (n - 1); NaN values take no part. The rules (``>=``
in pass 1, ``>`` in pass 2) are those of Sea-Bird's ``seabirdscientific.processing.wild_edit``, which
reproduces SeaSoft's output exactly; here all blocks are evaluated at once (a 2-D array).
"""

from __future__ import annotations

import warnings

import numpy as np
from numpy.typing import ArrayLike


def _block_flags(x: np.ndarray, use: np.ndarray, s1: float, s2: float, min_delta: float) -> np.ndarray:
    """x, use: (blocks, N). Returns the (blocks, N) mask of wild values."""
    v = np.where(use, x, np.nan)
    with warnings.catch_warnings(), np.errstate(invalid="ignore", divide="ignore"):
        warnings.simplefilter("ignore", RuntimeWarning)
        m1 = np.nanmean(v, axis=1, keepdims=True)
        sd1 = np.nanstd(v, axis=1, ddof=1, keepdims=True)
        v = np.where(np.abs(v - m1) >= sd1 * s1, np.nan, v)
        m2 = np.nanmean(v, axis=1, keepdims=True)
        sd2 = np.nanstd(v, axis=1, ddof=1, keepdims=True)
        dev = np.abs(x - m2)
        return (dev > sd2 * s2) & (dev > min_delta)


def wild_edit(x: ArrayLike, *, std_pass_1: float = 2.0, std_pass_2: float = 20.0, scans_per_block: int = 100,
              min_delta: float = 0.0, bad: ArrayLike | None = None, exclude_bad: bool = False) -> np.ndarray:
    """Boolean mask (``True`` = wild) of the values WildEdit replaces by the bad flag.

    Defaults are SeaSoft's (pass 1: 2 std, pass 2: 20 std, 100 scans per block, keep data within 0 of the
    mean). ``bad`` (with ``exclude_bad``) are scans left out of the statistics, e.g. LoopEdit's.
    """
    v = np.asarray(x, dtype=np.float64)
    n = v.size
    N = int(scans_per_block)
    if N < 2:
        raise ValueError(f"wild edit: scans_per_block must be >= 2, got {scans_per_block}")
    use = np.isfinite(v)
    if exclude_bad and bad is not None:
        use &= ~np.asarray(bad, dtype=bool)
    out = np.zeros(n, dtype=bool)
    nb = n // N
    if nb:
        out[: nb * N] = _block_flags(v[: nb * N].reshape(nb, N), use[: nb * N].reshape(nb, N), std_pass_1,
                                     std_pass_2, min_delta).ravel()
    rest = n - nb * N
    if rest:
        lo = max(0, n - N)
        tail = _block_flags(v[lo:][None, :], use[lo:][None, :], std_pass_1, std_pass_2, min_delta)[0]
        out[nb * N:] = tail[tail.size - rest:]
    return out & np.isfinite(v)
