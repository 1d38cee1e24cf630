"""The vectorised QARTOD spike test against ``ioos_qc.qartod.spike_test`` (the oracle), flag for flag."""

from __future__ import annotations

import numpy as np
import pytest
from ioos_qc import qartod

from hadal.ingest.qc import spike_test_flags


def _oracle(x, suspect, fail):
    return np.ma.filled(qartod.spike_test(inp=x, suspect_threshold=suspect, fail_threshold=fail), 2).astype(np.uint8)


def _series(rng, n, kind):
    x = np.cumsum(rng.normal(0, 1, n)) + 1e4
    spikes = rng.random(n) < 0.05
    x[spikes] += rng.choice([-1, 1], spikes.sum()) * rng.uniform(0, 30, spikes.sum())
    if kind in ("nan", "mixed"):
        x[rng.random(n) < 0.1] = np.nan
        if n > 10:
            x[3:7] = np.nan  # a run
    if kind in ("inf", "mixed"):
        x[rng.random(n) < 0.03] = rng.choice([np.inf, -np.inf])
    if kind == "huge":  # neighbours' sum near or past overflow, and differences that overflow
        x[rng.random(n) < 0.2] = rng.choice([1.7e308, -1.7e308])
    return x


KINDS = ["clean", "nan", "inf", "mixed", "huge"]
THRESHOLDS = [(3.0, 8.0), (3.0, None), (None, 8.0), (0.0, 8.0), (3.0, np.inf), (None, None), (5.0, 2.0)]


@pytest.mark.parametrize("kind", KINDS)
@pytest.mark.parametrize("thresholds", THRESHOLDS)
def test_equals_ioos_qc_flag_for_flag(kind, thresholds):
    rng = np.random.default_rng(100 * KINDS.index(kind) + THRESHOLDS.index(thresholds))
    for n in (1, 2, 3, 4, 50, 2000):
        x = _series(rng, n, kind)
        got = spike_test_flags(x, *thresholds)
        assert got.dtype == np.uint8
        np.testing.assert_array_equal(got, _oracle(x, *thresholds), err_msg=f"{kind} n={n} {thresholds}")


def test_flags_spikes_and_their_missing_neighbours():
    x = np.array([0.0, 0.0, 10.0, 0.0, 0.0, np.nan, 0.0, 0.0, 4.0, 0.0])
    f = spike_test_flags(x, 3.0, 8.0)
    # the 10 spike fails, its neighbours see half of it (5 > 3: suspect); 4 is suspect and its neighbours see
    # 2 (< 3: pass); NaN is 9, its neighbours 2 (not evaluated); both ends 2
    assert f.tolist() == [2, 3, 4, 3, 2, 9, 2, 1, 3, 2]
