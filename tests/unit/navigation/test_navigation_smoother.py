"""The navigation smoother (hadal.navigation.smoother) against independent oracles: the batch weighted
least-squares solution of the same linear-Gaussian problem (numpy.linalg.lstsq; its estimate and inverse normal
matrix are the exact smoothed mean and covariance), the closed-form information-weighted mean of two fixes, an
explicit leave-one-out re-run for the gate statistic."""

from __future__ import annotations

import numpy as np
import pytest

from hadal.navigation.smoother import Fix, smooth_positions
from hadal.settings.navigation import SmootherOptions


def _van_loan(beta_bc, beta_bt, dt, s2_bc, s2_bt, coupled):
    """Exact discretisation of one axis of dx/dt = c_bc + c_bt (if ``coupled``), dc/dt = -beta c + white noise of
    spectral density 2 beta s2 (stationary variance s2) for each current component, by Van Loan's matrix
    exponential (Van Loan 1978, IEEE TAC 23(3)); state [x, c_bc, c_bt]."""
    from scipy.linalg import expm

    k = 1.0 if coupled else 0.0
    A = np.array([[0.0, k, k], [0.0, -beta_bc, 0.0], [0.0, 0.0, -beta_bt]])
    Qc = np.diag([0.0, 2 * beta_bc * s2_bc, 2 * beta_bt * s2_bt])
    M = expm(np.block([[-A, Qc], [np.zeros((3, 3)), A.T]]) * dt)
    F = M[3:, 3:].T
    return F, F @ M[:3, 3:]


def _batch_oracle(t, d, ref, fixes, opt, depth=None, inc_cov=None, prior_only=False):
    """Stack prior, process and fix equations of all states [x, y, cx, cy] x n, whitened; solve by lstsq."""
    n = t.size
    dt = np.diff(t, prepend=t[0])
    step = np.hypot(d[:, 0], d[:, 1])  # the process model's DR / random-walk variance per axis (independent)
    qpos = np.where(ref, opt.dr_variance_m2_per_m * step, opt.position_random_walk_m_per_sqrt_s ** 2 * dt) + 1e-6
    s2, s2t = opt.current_sigma_m_s ** 2, opt.barotropic_current_sigma_m_s ** 2
    dz = np.zeros(n) if depth is None else np.abs(np.diff(depth, prepend=depth[0]))
    rows, rhs = [], []

    def add(block_cols, mats, r, cov):
        L = np.linalg.cholesky(np.linalg.inv(cov))  # whitening: W = L', W'W = cov^-1
        A = np.zeros((len(r), 6 * n))
        for c, M in zip(block_cols, mats, strict=True):
            A[:, 6 * c:6 * c + 6] = M
        rows.append(L.T @ A)
        rhs.append(L.T @ r)

    x0 = np.array([fixes[0].x_m, fixes[0].y_m, 0, 0, 0, 0]) if fixes else np.zeros(6)
    add([0], [np.eye(6)], x0, np.diag([1e8, 1e8, s2, s2, s2t, s2t]))
    for k in range(1, n):
        beta = dz[k] / opt.current_vertical_correlation_m / dt[k] + 1 / opt.current_correlation_time_s
        f1, q1 = _van_loan(beta, 1 / opt.current_correlation_time_s, dt[k], s2, s2t, not ref[k])
        F = np.zeros((6, 6))
        Q = np.zeros((6, 6))
        for a in range(2):
            F[np.ix_([a, a + 2, a + 4], [a, a + 2, a + 4])] = f1
            Q[np.ix_([a, a + 2, a + 4], [a, a + 2, a + 4])] = q1
            Q[a, a] += qpos[k]
        if inc_cov is not None:
            Q[:2, :2] += inc_cov[k]
        u = np.array([d[k, 0], d[k, 1], 0, 0, 0, 0])
        add([k, k - 1], [np.eye(6), -F], u, Q)
    for f in [] if prior_only else fixes:
        H = np.zeros((2, 6))
        H[0, 0] = H[1, 1] = 1
        add([f.index], [H], np.array([f.x_m, f.y_m]), f.cov_m2)
    A, b = np.vstack(rows), np.concatenate(rhs)
    sol = np.linalg.lstsq(A, b, rcond=None)[0].reshape(n, 6)
    cov = np.linalg.inv(A.T @ A)
    if prior_only:
        return sol, cov
    P = np.array([cov[6 * k:6 * k + 2, 6 * k:6 * k + 2] for k in range(n)])
    return sol, P


def _fix_loglik(t, d, ref, fixes, opt, depth):
    """log p(z_2..z_m | z_1) of the fixes from the dense Gaussian of the process model (prior mean and full
    covariance of every state by the batch oracle, no Kalman recursion)."""
    from scipy.stats import multivariate_normal

    mu, cov = _batch_oracle(t, d, ref, fixes, opt, depth, prior_only=True)
    fs = sorted(fixes, key=lambda f: f.index)
    idx = np.concatenate([[6 * f.index, 6 * f.index + 1] for f in fs])
    z = np.concatenate([[f.x_m, f.y_m] for f in fs])
    C = cov[np.ix_(idx, idx)]
    for j, f in enumerate(fs):
        C[2 * j:2 * j + 2, 2 * j:2 * j + 2] += f.cov_m2
    m = mu.reshape(-1)[idx]
    return multivariate_normal(m, C).logpdf(z) - multivariate_normal(m[:2], C[:2, :2]).logpdf(z[:2])


def _problem(seed=3, n=40):
    """A dive-like track: drift with a current when unreferenced, DR increments when referenced; fixes drawn
    about the truth from their own covariance."""
    rng = np.random.default_rng(seed)
    t = np.cumsum(rng.uniform(5, 60, n)) - 5
    ref = np.zeros(n, bool)
    ref[12:28] = True  # a bottom track with a DR velocity reference in the middle
    d = np.where(ref[:, None], rng.normal(0, 20, (n, 2)), 0.0)
    dt = np.diff(t, prepend=t[0])
    truth = np.cumsum(d + np.where(ref[:, None], 0.0, np.array([0.03, 0.02]) * dt[:, None]), axis=0)
    spec = [(0, np.diag([25.0, 16.0]), "launch_gnss"), (14, np.array([[900.0, 300.0], [300.0, 400.0]]), "terrain"),
            (33, np.array([[100.0, -20.0], [-20.0, 60.0]]), "usbl"), (n - 1, np.diag([9.0, 9.0]), "recovery_gnss")]
    fixes = [Fix(i, *(truth[i] + rng.multivariate_normal([0, 0], R)), R, s) for i, R, s in spec]
    return t, d, ref, fixes


@pytest.mark.parametrize(("with_depth", "corr_time_s"), [(True, 21600.0), (True, 3600.0), (False, 1e6)])
def test_rts_equals_batch_least_squares(with_depth, corr_time_s):
    # with depth: the current decorrelates over the 2-3 km descent and ascent (a up to ~0.5 a step); without
    # depth and a 1e6 s correlation time every step's decorrelation is < 1e-4 (the series branch)
    t, d, ref, fixes = _problem()
    n = t.size
    depth = np.concatenate([np.linspace(0, 2500, 12), np.full(16, 2500.0) + np.arange(16.0), np.linspace(2515, 0, n - 28)])
    opt = SmootherOptions(current_sigma_m_s=0.1, barotropic_current_sigma_m_s=0.04, current_vertical_correlation_m=800.0,
                          current_correlation_time_s=corr_time_s, position_random_walk_m_per_sqrt_s=0.8,
                          dr_variance_m2_per_m=0.3, gate_probability=0.99999999, current_scale_points=1)
    out = smooth_positions(t, d, ref, fixes, opt, depth_m=depth if with_depth else None)
    assert (out.fixes["status"] == "used").all()
    sol, P = _batch_oracle(t, d, ref, fixes, opt, depth if with_depth else None)
    np.testing.assert_allclose(out.x_m, sol[:, 0], atol=1e-5 * 1000)
    np.testing.assert_allclose(out.y_m, sol[:, 1], atol=1e-5 * 1000)
    np.testing.assert_allclose(out.current_m_s, sol[:, 2:4] + sol[:, 4:6], atol=1e-6)
    np.testing.assert_allclose(out.cov_m2, P, rtol=1e-6, atol=1e-6)


def test_two_gnss_fixes_on_a_still_vehicle_give_the_information_weighted_mean():
    # no process noise, no drift: the posterior of a constant position is the information-weighted mean
    t = np.arange(5.0)
    d = np.zeros((5, 2))
    ref = np.ones(5, bool)
    R1, R2 = np.array([[4.0, 1.0], [1.0, 9.0]]), np.array([[16.0, -2.0], [-2.0, 1.0]])
    z1, z2 = np.array([3.0, -1.0]), np.array([-2.0, 4.0])
    opt = SmootherOptions(dr_variance_m2_per_m=0.0, gate_probability=0.9999, current_scale_points=1)
    out = smooth_positions(t, d, ref, [Fix(0, *z1, R1, "gnss"), Fix(4, *z2, R2, "gnss")], opt)
    I1, I2 = np.linalg.inv(R1), np.linalg.inv(R2)
    P = np.linalg.inv(I1 + I2)
    m = P @ (I1 @ z1 + I2 @ z2)
    for k in range(5):  # floor 1e-6 m^2 per step: negligible
        np.testing.assert_allclose([out.x_m[k], out.y_m[k]], m, atol=1e-4)
        np.testing.assert_allclose(out.cov_m2[k], P, atol=1e-4)


def test_gate_statistic_equals_leave_one_out_innovation_and_names_the_bad_fix():
    t, d, ref, fixes = _problem()
    opt = SmootherOptions(current_sigma_m_s=0.05, dr_variance_m2_per_m=0.3, current_scale_points=1)
    good = smooth_positions(t, d, ref, fixes, opt.model_copy(update={"gate_probability": 0.99999999}))
    # oracle: re-run without fix i; its innovation against that track, covariance R + P_loo
    for i, f in enumerate(fixes):
        loo = smooth_positions(t, d, ref, [g for j, g in enumerate(fixes) if j != i],
                               opt.model_copy(update={"gate_probability": 0.99999999}))
        r = np.array([f.x_m - loo.x_m[f.index], f.y_m - loo.y_m[f.index]])
        d2 = r @ np.linalg.solve(f.cov_m2 + loo.cov_m2[f.index], r)
        assert good.fixes["d2"][i] == pytest.approx(d2, rel=1e-4)  # the diffuse prior (1e8 m^2) is centred on the first fix
    # a USBL fix 400 m off: rejected and named, the others kept, the track not pulled towards it
    bad = [*fixes[:2], Fix(33, fixes[2].x_m + 400.0, fixes[2].y_m, fixes[2].cov_m2, "usbl"), fixes[3]]
    out = smooth_positions(t, d, ref, bad, opt)
    assert list(out.fixes["status"]) == ["used", "used", "rejected", "used"]
    assert out.rejected == ["usbl at sample 33"]
    assert out.fixes["d2"][2] > 100
    without = smooth_positions(t, d, ref, [fixes[0], fixes[1], fixes[3]], opt)
    np.testing.assert_allclose(out.x_m, without.x_m, atol=1e-6)


def test_no_fix_is_a_clear_error():
    from hadal.errors import InputError

    with pytest.raises(InputError, match="no position fix"):
        smooth_positions(np.arange(3.0), np.zeros((3, 2)), np.zeros(3, bool), [])
    with pytest.raises(InputError, match="outside 0..2"):
        smooth_positions(np.arange(3.0), np.zeros((3, 2)), np.zeros(3, bool), [Fix(3, 0.0, 0.0, np.eye(2), "gnss")])


def test_rts_with_increment_covariance_equals_batch_least_squares():
    # measured increments (DVL velocities x dt) with their own full 2x2 covariance per step
    t, d, ref, fixes = _problem(seed=8)
    rng = np.random.default_rng(8)
    L = rng.normal(0, 2.0, (t.size, 2, 2))
    inc = L @ np.swapaxes(L, 1, 2)
    opt = SmootherOptions(gate_probability=0.99999999, current_scale_points=1)
    out = smooth_positions(t, d, ref, fixes, opt, increment_cov_m2=inc)
    sol, P = _batch_oracle(t, d, ref, fixes, opt, inc_cov=inc)
    np.testing.assert_allclose(out.x_m, sol[:, 0], atol=1e-2)
    np.testing.assert_allclose(out.y_m, sol[:, 1], atol=1e-2)
    np.testing.assert_allclose(out.cov_m2, P, rtol=1e-6, atol=1e-6)


def test_current_scale_marginalised_by_the_fixes_likelihood():
    # oracle: per scale the batch least-squares track and the fixes' likelihood from the dense Gaussian of the
    # process model; the published track is their likelihood-weighted mixture (log-uniform prior on the grid)
    t, d, ref, fixes = _problem(seed=4)
    depth = np.concatenate([np.linspace(0, 2500, 12), np.full(16, 2500.0), np.linspace(2500, 0, t.size - 28)])
    opt = SmootherOptions(gate_probability=0.99999999, current_scale_range=(0.5, 2.0), current_scale_points=3,
                          current_vertical_correlation_m=800.0)
    out = smooth_positions(t, d, ref, fixes, opt, depth_m=depth)
    sols, Ps, lls = [], [], []
    for sc in (0.5, 1.0, 2.0):
        o = opt.model_copy(update={"current_sigma_m_s": sc * opt.current_sigma_m_s,
                                   "barotropic_current_sigma_m_s": sc * opt.barotropic_current_sigma_m_s})
        sol, P = _batch_oracle(t, d, ref, fixes, o, depth)
        sols.append(sol)
        Ps.append(P)
        lls.append(_fix_loglik(t, d, ref, fixes, o, depth))
    w = np.exp(np.array(lls) - max(lls))
    w /= w.sum()
    assert w.min() > 1e-3  # the test exercises a real mixture
    x = sum(wi * s[:, :2] for wi, s in zip(w, sols, strict=True))
    P = sum(wi * (Pi + np.einsum("ki,kj->kij", s[:, :2] - x, s[:, :2] - x)) for wi, s, Pi in zip(w, sols, Ps, strict=True))
    np.testing.assert_allclose(np.column_stack([out.x_m, out.y_m]), x, atol=1e-2)
    np.testing.assert_allclose(out.cov_m2, P, rtol=1e-5, atol=1e-4)


def test_bad_fix_rejected_before_the_mixture():
    # default options (current strength marginalised): the 400 m-off USBL fix is still rejected by name and
    # the published track is the one computed without it
    t, d, ref, fixes = _problem()
    bad = [*fixes[:2], Fix(33, fixes[2].x_m + 400.0, fixes[2].y_m, fixes[2].cov_m2, "usbl"), fixes[3]]
    opt = SmootherOptions(current_sigma_m_s=0.05, dr_variance_m2_per_m=0.3)
    out = smooth_positions(t, d, ref, bad, opt)
    assert out.rejected == ["usbl at sample 33"]
    without = smooth_positions(t, d, ref, [fixes[0], fixes[1], fixes[3]], opt)
    np.testing.assert_allclose(out.x_m, without.x_m, atol=1e-6)
    np.testing.assert_allclose(out.cov_m2, without.cov_m2, atol=1e-6)


def _fast_problem(seed=5, n=160, dt_s=0.25):
    """A short dive sampled at 4 Hz: drift when unreferenced (descent/ascent over 600 m each), DR increments
    of ~0.3 m a step when referenced; fixes at samples off any epoch grid."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt_s
    ref = np.zeros(n, bool)
    ref[50:110] = True
    d = np.where(ref[:, None], rng.normal(0.3, 0.1, (n, 2)), 0.0)
    depth = np.concatenate([np.linspace(0, 600, 50), np.full(60, 600.0), np.linspace(600, 0, n - 110)])
    truth = np.cumsum(d + np.where(ref[:, None], 0.0, np.array([0.2, -0.1]) * dt_s), axis=0)
    spec = [(0, np.diag([4.0, 4.0]), "launch_gnss"), (53, np.array([[30.0, 8.0], [8.0, 20.0]]), "terrain"),
            (97, np.diag([10.0, 10.0]), "usbl"), (n - 2, np.diag([4.0, 4.0]), "recovery_gnss")]
    fixes = [Fix(i, *(truth[i] + rng.multivariate_normal([0, 0], R)), R, s) for i, R, s in spec]
    return t, d, ref, fixes, depth


def test_epochs_exact_at_epochs_and_interpolation_bounded_against_batch_least_squares():
    # the state kept once per 2 s (8 samples) and every fix: the composed steps make the epochs' estimates exact
    # (equal to the batch least-squares solution over every sample); between epochs the interpolation's error
    # is bounded (module docstring, "Epochs")
    from hadal.navigation.smoother import epoch_indices

    t, d, ref, fixes, depth = _fast_problem()
    opt = SmootherOptions(current_sigma_m_s=0.3, barotropic_current_sigma_m_s=0.1, current_vertical_correlation_m=300.0,
                          current_correlation_time_s=600.0, position_random_walk_m_per_sqrt_s=0.3,
                          dr_variance_m2_per_m=0.05, gate_probability=0.99999999, current_scale_points=1,
                          epoch_interval_s=2.0, epoch_max_travel_m=1000.0)
    ep = epoch_indices(t, d, np.array([f.index for f in fixes]), opt)
    assert 20 < ep.size < 40 and {f.index for f in fixes} <= set(ep.tolist())
    out = smooth_positions(t, d, ref, fixes, opt, depth_m=depth)
    sol, P = _batch_oracle(t, d, ref, fixes, opt, depth)
    np.testing.assert_allclose(out.x_m[ep], sol[ep, 0], atol=1e-6 * 1000)
    np.testing.assert_allclose(out.y_m[ep], sol[ep, 1], atol=1e-6 * 1000)
    np.testing.assert_allclose(out.cov_m2[ep], P[ep], rtol=1e-6, atol=1e-8)
    # between epochs (strong currents, 2 s epochs, a 1-sigma of ~2.5 m: a hard case): the mean within 1 % of the
    # 1-sigma, the covariance within 3 % of its trace, never below the exact one (the bridge without the epochs'
    # cross-covariance over-counts by at most f (1 - f) of the interval's noise, measured: +3.7 % of the trace)
    sig = np.sqrt(np.trace(P, axis1=1, axis2=2))
    err = np.hypot(out.x_m - sol[:, 0], out.y_m - sol[:, 1])
    assert (err / sig).max() < 0.01
    tr, tr0 = np.trace(out.cov_m2, axis1=1, axis2=2), np.trace(P, axis1=1, axis2=2)
    assert (np.abs(out.cov_m2 - P).max(axis=(1, 2)) / tr0).max() < 0.03
    assert 0.9999 < (tr / tr0).min() and (tr / tr0).max() < 1.05


def test_epoch_smoother_matches_the_full_rate_smoother_on_a_16_hz_dive():
    # 16 Hz for 40 min: descent, bottom track at 1 m/s, ascent; launch, terrain, USBL and recovery fixes; the
    # default options (1 s / 5 m epochs, the currents' strength marginalised) against an epoch at every sample
    rng = np.random.default_rng(11)
    n, hz = 38400, 16.0
    t = np.arange(n) / hz
    n1, n2 = n // 3, 2 * n // 3
    depth = np.concatenate([np.linspace(0, 3000, n1), np.full(n2 - n1, 3000.0), np.linspace(3000, 0, n - n2)])
    ref = np.zeros(n, bool)
    ref[n1:n2] = True
    hd = np.cumsum(rng.normal(0, 0.002, n)) + 0.7
    v = np.where(ref, 1.0, 0.0) / hz
    d = np.stack([v * np.sin(hd), v * np.cos(hd)], 1)
    truth = np.cumsum(d + np.where(ref, 0.0, 1.0)[:, None] * np.array([0.15, -0.08]) / hz, axis=0)
    spec = [(0, np.eye(2) * 25.0, "launch"), (n1 + 7, np.array([[400.0, 100.0], [100.0, 300.0]]), "terrain"),
            ((n1 + n2) // 2 + 3, np.eye(2) * 400.0, "usbl"), (n - 1, np.eye(2) * 9.0, "gnss")]
    fixes = [Fix(i, *(truth[i] + rng.multivariate_normal([0, 0], R)), R, s) for i, R, s in spec]
    full = smooth_positions(t, d, ref, fixes, SmootherOptions(epoch_interval_s=0), depth_m=depth)
    out = smooth_positions(t, d, ref, fixes, SmootherOptions(), depth_m=depth)
    sig = np.sqrt(np.trace(full.cov_m2, axis1=1, axis2=2))
    assert (np.hypot(out.x_m - full.x_m, out.y_m - full.y_m) / sig).max() < 1e-3
    assert (np.abs(out.cov_m2 - full.cov_m2).max(axis=(1, 2)) / sig ** 2).max() < 0.005
    assert np.abs(out.current_m_s - full.current_m_s).max() < 1e-3
    np.testing.assert_allclose(out.fixes["d2"], full.fixes["d2"], rtol=1e-6)
