"""The posterior's noise-variance widening under correlated residuals (issue 16: the sample dive's posterior was
overconfident).

Oracle: Monte-Carlo. AR(1)-correlated noise of variance 1 along a track on a map; the pose + bias (+ drift) fit is
a least-squares regression on the map's gradients at the track (computed here by central differences of the map's
bilinear sampler, not by the code under test); ``(N - p) / mean(RSS)`` over many noise draws is the factor by which the
classical ``RSS / (N - p)`` underestimates the noise variance. :func:`hadal.matching.posterior._fit_dof_inflation`
must give that factor from the analytic expectation, on a smooth terrain (where it approaches ``1 / gamma`` times
the parameters' share) and on a rough one (near 1).

The same Monte-Carlo fits give the start position's true spread under the correlated noise:
:func:`hadal.matching.posterior._position_variance_ratio` (the reported main mode's rescaling) must turn the
tempered variance ``tr(H^-1)_xy / gamma`` into it (about 1 on a smooth terrain, well below 1 on a rough one).
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.signal import lfilter

from hadal.matching import MapGrid
from hadal.matching.posterior import N_PARAMS, _drift_basis, _fit_dof_inflation, _position_variance_ratio

H = 10.0


def _terrain(kind: str):
    if kind == "smooth":
        return lambda x, y: 40 * np.sin(x / 700.0) + 30 * np.cos(y / 500.0) + 0.01 * x
    rng = np.random.default_rng(3)
    kx, ky, ph = rng.uniform(0.02, 0.2, 40), rng.uniform(0.02, 0.2, 40), rng.uniform(0, 2 * np.pi, 40)
    return lambda x, y: sum(3 * np.sin(kx[i] * x + ky[i] * y + ph[i]) for i in range(40))


def _case(kind: str, drift: bool):
    z = _terrain(kind)
    x = np.arange(0.0, 4000.0, H)
    y = np.arange(0.0, 3000.0, H)
    X, Y = np.meshgrid(x, y)
    g = MapGrid(z(X, Y), x, y, H)
    n = 200
    t = np.linspace(0.0, 1.0, n)
    rel = np.column_stack([1500 * t, 400 * np.sin(3 * t)])
    start = np.array([1000.0, 1200.0])
    q = rel + start
    e = 1e-4  # the gradient of the map as the fit sees it (bilinear between nodes), by central differences
    gx = (g.sample_bilinear(q[:, 0] + e, q[:, 1]) - g.sample_bilinear(q[:, 0] - e, q[:, 1])) / (2 * e)
    gy = (g.sample_bilinear(q[:, 0], q[:, 1] + e) - g.sample_bilinear(q[:, 0], q[:, 1] - e)) / (2 * e)
    J = [gx, gy, (gx * rel[:, 1] - gy * rel[:, 0]) * np.pi / 180.0, gx * rel[:, 0] + gy * rel[:, 1], np.ones(n)]
    B = None
    if drift:
        B, _ = _drift_basis(np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(rel, axis=0).T))]), 500.0)
        J += [gx[:, None] * B, gy[:, None] * B]
    J = np.column_stack(J)
    return g, z(q[:, 0], q[:, 1]), rel, start, B, J


def _mc_fits(J: np.ndarray, rho: float, reps: int = 3000):
    """Least-squares parameters and residual sums of squares of ``reps`` draws of unit-variance AR(1) noise."""
    rng = np.random.default_rng(16)
    n = J.shape[0]
    w = rng.standard_normal((reps, n)) * np.sqrt(1.0 - rho * rho)
    w[:, 0] = rng.standard_normal(reps)
    E = lfilter([1.0], [1.0, -rho], w, axis=1)
    beta = np.linalg.lstsq(J, E.T, rcond=None)[0]
    rss = ((E - (J @ beta).T) ** 2).sum(axis=1)
    return beta, rss


def _mc_factor(J: np.ndarray, rho: float, reps: int = 3000) -> float:
    _, rss = _mc_fits(J, rho, reps)
    return (J.shape[0] - J.shape[1]) / float(rss.mean())


@pytest.mark.parametrize(("kind", "rho", "drift"), [("smooth", 0.8, False), ("smooth", 0.5, False),
                                                    ("rough", 0.8, False), ("smooth", 0.8, True)])
def test_widening_equals_the_monte_carlo_bias_of_the_classical_estimator(kind, rho, drift):
    g, d, rel, start, B, J = _case(kind, drift)
    gamma = (1 - rho) / (1 + rho)
    mc = _mc_factor(J, rho)
    got = _fit_dof_inflation(g, d, rel, (0.0, 1.0), start, None, B, gamma, 0.0, True, True)
    assert got == pytest.approx(max(mc, 1.0), rel=0.03), (got, mc)
    if kind == "smooth" and rho == 0.8:
        assert got > 1.15  # a smooth terrain's fit absorbs the correlated noise: the classical estimate is low


def test_independent_residuals_are_not_widened():
    g, d, rel, start, _, J = _case("smooth", False)
    assert J.shape[1] == N_PARAMS
    assert _fit_dof_inflation(g, d, rel, (0.0, 1.0), start, None, None, 1.0, 0.0, True, True) == pytest.approx(1.0)
    # a tiny effective sample size: bounded by the N / 4 divisor floor
    assert _fit_dof_inflation(g, d, rel, (0.0, 1.0), start, None, None, 1e-3, 0.0, True, True) <= 4.0


@pytest.mark.parametrize(("kind", "rho"), [("smooth", 0.8), ("rough", 0.8), ("rough", 0.5)])
def test_sandwich_ratio_gives_the_monte_carlo_spread_of_the_start(kind, rho):
    g, d, rel, start, _, J = _case(kind, False)
    gamma = (1 - rho) / (1 + rho)
    beta, _ = _mc_fits(J, rho, reps=4000)
    mc_var = float(np.var(beta[0]) + np.var(beta[1]))  # the start's spread over the noise draws (m^2, unit noise)
    tempered_var = float(np.trace(np.linalg.inv(J.T @ J)[:2, :2])) / gamma  # what the tempered likelihood reports
    got = _position_variance_ratio(g, d, rel, (0.0, 1.0), start, None, gamma, True, True)
    assert got == pytest.approx(min(mc_var / tempered_var, 1.0), rel=0.06), (got, mc_var / tempered_var)
    if kind == "rough":
        assert got < 0.6  # rough terrain: the position is better known than N_eff of the residuals says
    else:
        assert got > 0.7  # smooth terrain: the gradients are as correlated as the noise, the tempering about right


def test_sandwich_ratio_is_one_for_independent_residuals():
    g, d, rel, start, _, _ = _case("rough", False)
    assert _position_variance_ratio(g, d, rel, (0.0, 1.0), start, None, 1.0, True, True) == pytest.approx(1.0)
