"""DVL velocities and pose fixes as smoother sources (hadal.navigation.sources, issue 47) against independent
oracles: the known truth of simulated tracks (Monte Carlo: the reported covariance against the empirical
scatter of the errors), the batch least-squares solution, and rotations whose result is known by geometry."""

from __future__ import annotations

import numpy as np
import pytest

from hadal.navigation.smoother import CHI2_2DOF_2SIGMA, Fix, smooth_positions
from hadal.navigation.sources import body_to_enu, pose_fixes, velocity_increments
from hadal.settings.navigation import SmootherOptions


def test_body_to_enu_by_geometry():
    # heading 90 deg (east): forward is east, left is north; heading 0: forward north, left west
    v, c = body_to_enu(np.array([1.0, 1.0]), np.array([0.0, 2.0]), np.array([90.0, 0.0]),
                       np.array([np.diag([4.0, 1.0]), np.diag([4.0, 1.0])]))
    np.testing.assert_allclose(v, [[1.0, 0.0], [-2.0, 1.0]], atol=1e-12)
    np.testing.assert_allclose(c[0], np.diag([4.0, 1.0]), atol=1e-12)  # forward variance now east
    np.testing.assert_allclose(c[1], np.diag([1.0, 4.0]), atol=1e-12)  # forward variance now north
    # heading 45: a forward speed of sqrt(2) is 1 m/s east and 1 m/s north
    v, _ = body_to_enu(np.array([np.sqrt(2.0)]), np.array([0.0]), np.array([45.0]))
    np.testing.assert_allclose(v, [[1.0, 1.0]], atol=1e-12)


def test_velocity_increments_steps_and_fallbacks():
    t = np.array([0.0, 1.0, 3.0, 4.0])
    v = np.array([[1.0, 2.0], [3.0, 4.0], [np.nan, 0.0], [5.0, 5.0]])
    cov = np.array([np.eye(2) * 0.01, np.full((2, 2), np.nan), np.eye(2), np.eye(2)])
    d, ref, c, ok = velocity_increments(t, v, cov, over_ground=True, sigma_m_s=0.2)
    np.testing.assert_allclose(d, [[0, 0], [1, 2], [6, 8], [0, 0]])  # v at the step's start x dt
    assert list(ok) == [False, True, True, False]  # no velocity before the first sample; NaN at sample 2
    np.testing.assert_allclose(c[1], np.eye(2) * 0.01)
    np.testing.assert_allclose(c[2], np.eye(2) * 0.04 * 4)  # NaN covariance: sigma_m_s^2 dt^2
    assert list(ref) == [False, True, True, False]
    _, ref_wt, _, _ = velocity_increments(t, v, cov, over_ground=False, sigma_m_s=0.2)
    assert not ref_wt.any()  # water track: the current is added by the smoother


def _bottom_track_run(rng, n=600, dt=2.0, sigma_v=0.05):
    """A meandering bottom track at 1 m/s; DVL bottom track = truth + white noise; one launch GNSS fix."""
    t = np.arange(n) * dt
    hd = np.cumsum(rng.normal(0, 0.03, n))
    vt = np.column_stack([np.sin(hd), np.cos(hd)])
    truth = np.vstack([[0.0, 0.0], np.cumsum(vt[:-1] * dt, axis=0)])
    vm = vt + rng.normal(0, sigma_v, (n, 2))
    d, ref, cov, ok = velocity_increments(t, vm, np.repeat(np.eye(2)[None] * sigma_v ** 2, n, 0), True, 1.0)
    z = truth[0] + rng.normal(0, 3.0, 2)
    return t, d, ref, cov, truth, [Fix(0, *z, np.eye(2) * 9.0, "launch")]


def test_bottom_track_covariance_matches_the_truths_scatter():
    # Monte Carlo over independent dives: the end error's empirical covariance against the reported one, and
    # the 2-sigma coverage of every sample (95.4 % expected; binomial tolerance over correlated samples)
    rng = np.random.default_rng(11)
    opt = SmootherOptions(dr_variance_m2_per_m=0.0)
    errs, d2s, reported = [], [], None
    for _ in range(200):
        t, d, ref, cov, truth, fixes = _bottom_track_run(rng)
        out = smooth_positions(t, d, ref, fixes, opt, increment_cov_m2=cov)
        e = np.column_stack([out.x_m - truth[:, 0], out.y_m - truth[:, 1]])
        errs.append(e[-1])
        reported = out.cov_m2[-1]
        d2s.append(np.einsum("ki,kij,kj->k", e, np.linalg.inv(out.cov_m2), e))
    emp = np.cov(np.array(errs).T)
    # the truth: 9 m^2 launch + 599 steps x (0.05 x 2)^2 = 14.99 m^2 per axis
    np.testing.assert_allclose(np.diag(reported), [9 + 599 * 0.01] * 2, rtol=1e-3)
    np.testing.assert_allclose(np.diag(emp), np.diag(reported), rtol=0.25)  # 200 draws: ~10 % sampling error
    assert np.mean(np.concatenate(d2s) <= CHI2_2DOF_2SIGMA) == pytest.approx(0.954, abs=0.04)


def test_water_track_recovers_the_current_between_two_fixes():
    # water-track velocities (through the water) and a steady 0.2/-0.1 m/s current: with GNSS fixes at both
    # ends the smoother's current state (the current the DR does not see) takes the true current and the
    # track the truth, each within its reported uncertainty
    rng = np.random.default_rng(5)
    n, dt = 900, 2.0
    t = np.arange(n) * dt
    vw = np.column_stack([np.full(n, 0.8), np.full(n, 0.3)])
    cur = np.array([0.2, -0.1])
    truth = np.vstack([[0.0, 0.0], np.cumsum((vw[:-1] + cur) * dt, axis=0)])
    d, ref, cov, _ = velocity_increments(t, vw + rng.normal(0, 0.02, (n, 2)), None, False, 0.02)
    fixes = [Fix(0, *(truth[0] + rng.normal(0, 3, 2)), np.eye(2) * 9, "launch"),
             Fix(n - 1, *(truth[-1] + rng.normal(0, 3, 2)), np.eye(2) * 9, "gnss")]
    out = smooth_positions(t, d, ref, fixes, SmootherOptions(), increment_cov_m2=cov)
    np.testing.assert_allclose(out.current_m_s[n // 2], cur, atol=0.01)
    e = np.column_stack([out.x_m - truth[:, 0], out.y_m - truth[:, 1]])
    d2 = np.einsum("ki,kij,kj->k", e, np.linalg.inv(out.cov_m2), e)
    assert d2.max() < 13.8  # chi-square 2 dof, 99.9 %


def test_pose_fixes_thinned_with_their_covariance():
    t = np.arange(0.0, 30.0, 0.5)
    x, y = np.arange(t.size, dtype=float), -np.arange(t.size, dtype=float)
    cov = np.repeat(np.array([[4.0, 1.0], [1.0, 9.0]])[None], t.size, 0)
    cov[20] = np.nan  # a pose without a covariance: the configured sigma
    x[1] = np.nan
    f = pose_fixes(t, x, y, cov, sigma_m=7.0, min_interval_s=10.0)
    assert [g.index for g in f] == [0, 20, 40]
    np.testing.assert_allclose(f[0].cov_m2, [[4.0, 1.0], [1.0, 9.0]])
    np.testing.assert_allclose(f[1].cov_m2, np.eye(2) * 49.0)
    assert (f[2].x_m, f[2].y_m, f[2].source) == (40.0, -40.0, "pose")
