"""The posterior's noise variance under correlated residuals (issue 16: the sample dive's posterior was overconfident).

Oracle: Monte-Carlo regressions with a known noise variance (1) and AR(1)-correlated noise, the regressors slowly
varying along the track as the pose derivatives of a smooth terrain are; ``RSS / dof`` with the degrees of freedom
:func:`hadal.matching.posterior._dof` gives for the effective sample size the posterior estimates from the same
residuals (the divisor behind the reported covariance's widening) must be unbiased there, where the classical
``RSS / (N - p)`` (the likelihood's :func:`~hadal.matching.posterior._s2_from`) is biased low.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from hadal.matching.posterior import N_PARAMS, _dof, _n_eff, _s2_from


def _ar1(rng, n: int, rho: float, reps: int) -> np.ndarray:
    w = rng.standard_normal((reps, n)) * np.sqrt(1.0 - rho * rho)
    w[:, 0] = rng.standard_normal(reps)
    return lfilter([1.0], [1.0, -rho], w, axis=1)


def _estimates(rho: float, reps: int = 600, n: int = 180, p: int = N_PARAMS):
    rng = np.random.default_rng(16)
    t = np.linspace(0.0, 1.0, n)
    J = np.column_stack([np.ones(n)] + [np.sin(2 * np.pi * (k + 1) * t + k) for k in range(p - 1)])
    E = _ar1(rng, n, rho, reps)
    beta = np.linalg.lstsq(J, E.T, rcond=None)[0]
    R = E - (J @ beta).T
    new, old = [], []
    for r in R:
        msd = float(r @ r) / n
        new.append(msd * n / _dof(n, _n_eff(r) / n, p))
        old.append(_s2_from(msd, n, 0.0))
    return float(np.mean(new)), float(np.mean(old))


def test_white_residuals_keep_the_classical_estimator():
    assert _s2_from(2.0, 100, 0.0) == pytest.approx(2.0 * 100 / (100 - N_PARAMS))
    assert _dof(100, 1.0) == 100 - N_PARAMS and _dof(3, 1.0) == 1.0
    assert _s2_from(2.0, 100, 5.0) == 5.0  # the floor still holds
    # a tiny effective sample size inflates at most four times (dof >= N / 4)
    assert _dof(40, 0.01) == pytest.approx(10.0)
    assert _dof(100, 0.5, 5) == pytest.approx(90.0)


@pytest.mark.parametrize("rho", [0.5, 0.8])
def test_correlated_residuals_unbiased_where_the_classical_estimator_is_low(rho):
    new, old = _estimates(rho)
    assert abs(new - 1.0) < 0.06, new
    assert old < 1.0 - (0.04 if rho == 0.5 else 0.15), old  # the bias the correction removes (MC: 0.94, 0.80)
