"""The posterior fix's reported covariance (its main mode, Laplace at the continuous MAP) against Monte-Carlo.

Oracle: the spread of the fix itself over many redraws of what is random on a fixed track and map (the profile
noise; the dead reckoning's drift rates, drawn from the prior the posterior assumes; its random walk), computed
here from the fixes' errors, not by the code under test. The reported covariance (averaged over the draws) must
match that spread; with the random walk not given, it must be visibly too small (the walk is what carries the
terrain's fix to the start).
"""

from __future__ import annotations

import numpy as np
import pytest

from hadal.matching import MapGrid
from hadal.matching.posterior import posterior_fix

H = 10.0
DRIFT_PRIOR = 0.005  # posterior_fix's default drift-rate prior without sample times (m per m travelled)


def _world():
    x = np.arange(0.0, 3000.0, H)
    y = np.arange(0.0, 2400.0, H)
    X, Y = np.meshgrid(x, y)
    def z(x, y):  # a few incommensurate undulations on a bowl: one clear mode
        return (3000 + 40 * np.sin(x / 300.0) * np.cos(y / 260.0) + 30 * np.cos(y / 170.0 + x / 500.0)
                + 20 * np.sin(x / 90.0 + y / 130.0) + 2e-5 * ((x - 1500) ** 2 + (y - 1200) ** 2))
    g = MapGrid(z(X, Y), x, y, H)
    n = 80
    s = np.arange(n) * H  # one sample per cell of travel
    rel = np.column_stack([s * np.cos(0.4), s * np.sin(0.4) + 60 * np.sin(s / 150.0)])
    return g, z, rel, np.array([900.0, 700.0])


def _mc(noise_m: float, walk_m_per_sqrt_m: float, given: float, reps: int = 80):
    """Errors of the fix (m) and its reported covariances over ``reps`` draws of noise and random walk."""
    g, z, rel, start = _world()
    rng = np.random.default_rng(1616)
    tau = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(rel, axis=0).T))])
    errs, covs, methods = [], [], set()
    seg = tau[-1] / 3.0  # the fix's default drift model without times: 3 segments, rates ~ N(0, 0.5 %) per axis
    edges = np.arange(3) * seg
    for _ in range(reps):
        rates = rng.normal(0.0, DRIFT_PRIOR, (3, 2))  # drawn from the prior the posterior assumes
        drift = np.clip(tau[:, None] - edges[None, :], 0.0, seg) @ rates
        steps = rng.standard_normal((rel.shape[0], 2)) * walk_m_per_sqrt_m * np.sqrt(np.diff(tau, prepend=0.0))[:, None]
        q = start + rel + drift + np.cumsum(steps, axis=0)  # the true track: drift and walk zero at the first sample
        d = z(q[:, 0], q[:, 1]) + rng.normal(0.0, noise_m, rel.shape[0])
        f = posterior_fix(d, rel, g, drift_random_walk=given)
        assert not f.mismatch, f.reasons
        errs.append([f.start_x_m - start[0], f.start_y_m - start[1]])
        covs.append(f.cov_m2)
        methods.add(f.refinement["main_mode_covariance"]["method"])
    assert methods == {"laplace"}
    errs = np.asarray(errs)
    return errs, np.mean(covs, axis=0)


def _ratio(errs: np.ndarray, cov: np.ndarray) -> float:
    """Reported trace over the Monte-Carlo mean squared error (about the truth: a bias counts)."""
    return float(np.trace(cov) / np.mean(np.sum(errs ** 2, axis=1)))


def test_reported_covariance_is_the_monte_carlo_spread_of_the_fix_under_noise():
    errs, cov = _mc(noise_m=1.0, walk_m_per_sqrt_m=0.0, given=0.0)
    assert 0.6 <= _ratio(errs, cov) <= 1.6, (_ratio(errs, cov), np.trace(cov), np.mean(np.sum(errs ** 2, axis=1)))


@pytest.mark.parametrize("given", [1.0, 0.0])
def test_the_random_walk_given_widens_the_covariance_to_the_monte_carlo_spread(given):
    walk = 0.15  # m per sqrt(m): 1.3 m after the 80-sample track, against 0.5 m of noise
    errs, cov = _mc(noise_m=0.5, walk_m_per_sqrt_m=walk, given=given * walk)
    r = _ratio(errs, cov)
    if given:
        assert 0.6 <= r <= 1.6, r
    else:
        assert r < 0.5, r  # without the walk the fix claims what the terrain alone would give


def test_map_error_floor_is_the_variance_of_the_bilinear_map():
    """The DTM's per-cell uncertainty as the variance of the interpolated map at the track (the noise floor):
    against Monte-Carlo draws of independent cell errors interpolated by the map's own bilinear sampler."""
    from hadal.matching.posterior import _map_sigma2_at

    rng = np.random.default_rng(5)
    x, y = np.arange(0.0, 200.0, H), np.arange(0.0, 150.0, H)
    u = rng.uniform(0.5, 3.0, (y.size, x.size))
    unc = MapGrid(u, x, y, H)
    pts = np.column_stack([rng.uniform(10, 180, 40), rng.uniform(10, 130, 40)])
    draws = np.array([MapGrid(rng.standard_normal(u.shape) * u, x, y, H).sample_bilinear(pts[:, 0], pts[:, 1])
                      for _ in range(4000)])
    assert _map_sigma2_at(unc, pts) == pytest.approx(float(np.mean(draws.var(axis=0))), rel=0.05)
    centre = np.array([[x[5], y[4]]])  # on a cell centre the cell's own variance; between four cells a quarter
    assert _map_sigma2_at(unc, centre) == pytest.approx(u[4, 5] ** 2)
    mid = np.array([[x[5] + H / 2, y[4] + H / 2]])
    assert _map_sigma2_at(unc, mid) == pytest.approx(np.sum(u[4:6, 5:7] ** 2) / 16)
    assert _map_sigma2_at(None, pts) == 0.0


@pytest.mark.parametrize("bad", [-0.1, float("nan"), float("inf")])
def test_a_bad_random_walk_is_a_one_line_input_error(bad):
    from hadal.errors import InputError

    g, z, rel, start = _world()
    d = z(start[0] + rel[:, 0], start[1] + rel[:, 1])
    with pytest.raises(InputError, match="drift_random_walk"):
        posterior_fix(d, rel, g, drift_random_walk=bad)


def test_the_default_random_walk_is_the_stage_default_declared_once():
    from hadal.matching.options import DeadReckoningOptions
    from hadal.settings import MatchParams as Params
    from hadal.stages.match import posterior_options

    g, z, rel, start = _world()
    d = z(start[0] + rel[:, 0], start[1] + rel[:, 1])
    f = posterior_fix(d, rel, g)
    declared = DeadReckoningOptions.model_fields["drift_random_walk_m_per_sqrt_s"].default
    assert f.refinement["main_mode_covariance"]["random_walk"] == declared > 0
    assert posterior_options(Params())["drift_random_walk"] == declared
