"""One linear-Gaussian smoother of the vehicle's horizontal position over the whole dive (issue 47).

State (map frame, metres; per sample ``k``)::

    s_k = [x_east_m, y_north_m, cbc_east_m_s, cbc_north_m_s, cbt_east_m_s, cbt_north_m_s]

``c = cbc + cbt`` is the drift velocity the dead reckoning does not see: the current that carries an unpowered
vehicle while its DR has no velocity reference (descent, ascent, DR held, water-track DVL), and any slow DR
velocity bias. It is split as the ocean's currents are (their kinetic energy sits mostly in the barotropic and
first baroclinic modes, Wunsch 1997, J. Phys. Oceanogr. 27(8)):

* ``cbc``, the depth-varying (baroclinic) part: a first-order Gauss-Markov (Ornstein-Uhlenbeck) process per
  axis with the stationary 1-sigma ``current_sigma_m_s`` that decorrelates with the depth the vehicle traverses
  (vertical correlation length ``current_vertical_correlation_m``: a sinking vehicle crosses water layers whose
  currents differ) and with time (``current_correlation_time_s``: tides, inertial motion);
* ``cbt``, the depth-coherent (barotropic) part: the same process with ``barotropic_current_sigma_m_s``,
  decorrelating with time only (the same drift at every depth; shared by the descent and the ascent as far as
  the time between them allows).

Both start from their stationary distribution ``N(0, sigma^2)``. Over a step of ``dt`` s in which the depth
changes by ``dz`` m the dimensionless decorrelation is

    a_bc = |dz| / current_vertical_correlation_m + dt / current_correlation_time_s,
    a_bt = dt / current_correlation_time_s,   phi = exp(-a)

(the rate ``beta = a / dt`` is taken constant over the step). Each component is the integrated
Ornstein-Uhlenbeck ("Singer") model of target tracking (Singer 1970, IEEE Trans. AES-6(4); Bar-Shalom, Li &
Kirubarajan 2001, *Estimation with Applications to Tracking and Navigation*, §8.2.3) with its exact
discretisation (checked against Van Loan's matrix exponential, tests/unit/navigation/test_navigation_smoother.py). Unlike a
random walk with a small prior, the current's variability is as large as its mean, so a drift concentrated in
part of the descent (strong upper-ocean currents) is covered, and the position uncertainty between two fixes
grows like a random walk of diffusivity ``2 sigma^2 tau`` (``tau`` the correlation time of the traversal) plus
the barotropic drift, rather than at a hand-set rate. The defaults are the ocean's, not fitted to a bench
(bench/bench_navigation_coverage.py reports the coverage they give).

The currents' strength on a given dive is not known beforehand, but the fixes reveal it (a drift of 900 m
between the launch and the terrain fix is unlikely under weak currents): both 1-sigmas are multiplied by a factor
``s`` with a log-uniform prior over ``current_scale_range`` (a grid of ``current_scale_points``), the smoother
runs for every ``s``, and the published track is the posterior mixture, weighted by the fixes' likelihood
``p(z | s)`` (the Kalman filter's prediction-error decomposition, Schweppe 1965, IEEE Trans. IT-11(1); the
first fix, met by the diffuse position prior, excluded): mean ``sum w_s x_s``, covariance
``sum w_s (P_s + (x_s - x)(x_s - x)')`` (Bayesian marginalisation of a hyperparameter over a grid; tested
against the dense Gaussian likelihood and batch least squares). The gate and the fixes' residuals/chi-squares
use the model at ``s = 1``, where the chi-square is exactly the leave-one-out statistic.

Process, from sample ``k-1`` to ``k`` (DR increment ``d``, per axis independent; written for one current
component, the position integrates both, whose noises are independent)::

    c_k = phi c_{k-1} + w_c,        var(w_c) = sigma^2 (1 - phi^2)
    referenced step (DR moving: DVL/INS velocity reference, or the terrain-matched track)
        x_k = x_{k-1} + d + w_x,   var(w_x) = dr_variance_m2_per_m * |d| + floor
    unreferenced step (DR held: the vehicle drifts with the water)
        x_k = x_{k-1} + d + dt (1 - phi) / a  c_{k-1} + w_x,
        var(w_x) = sigma^2 dt^2 (2a - 3 + 4 phi - phi^2) / a^2
                   + position_random_walk_m_per_sqrt_s^2 dt + floor,
        cov(w_x, w_c) = sigma^2 dt (1 - phi)^2 / a

Measurements: absolute position fixes ``z = [x, y] + v``, ``v ~ N(0, R)`` with their full 2x2 covariance ``R``
(launch and recovery GNSS, USBL/LBL, the terrain fix's posterior covariance).

Estimator: Kalman filter forward, Rauch-Tung-Striebel backward pass (Rauch, Tung & Striebel 1965, AIAA J.
3(8); Särkkä 2013, *Bayesian Filtering and Smoothing*, Alg. 8.2), the scheme of oplab_pipeline's AUV
navigation (``src/auv_nav/localisation/ekf.py``: a 12-state EKF over position, attitude and body velocities
fed by DVL, depth, orientation and USBL fixes, whose USBL sigma defaults to offset + factor x slant range, with a
forward Mahalanobis gate on the innovations and an RTS pass over the stored states). Here the state is linear
(the DR/DVL integration is done upstream), so the smoother is exact: its mean and covariance equal the batch
least-squares solution (tests/unit/navigation/test_navigation_smoother.py); and the gate tests every fix against the smoothed
track of all the *other* fixes, not only the past ones.

Epochs: the state is not kept per sample (16 Hz over a 10 h dive is ~570 000 states, nine times over for the
scale mixture) but on epochs: the first and the last sample, every fix's sample, and the first sample of every
new ``epoch_interval_s`` (1 s) of time or ``epoch_max_travel_m`` (5 m) of DR travel. The steps between two epochs
are composed exactly (the model is linear: ``F = F_m ... F_1``, ``Q = sum F_m..j+1 Q_j F_m..j+1'``, the DR
increments and the position noise beyond the currents' summed, since the position's transition is the identity),
so the filter/smoother on the epochs gives exactly the full-rate smoother's estimates at the epochs (tested against
batch least squares over every sample). A sample between epochs ``e`` and ``e+1`` is interpolated: its mean is
the epoch's plus the DR increment and the drift of the epoch's current since it (exact propagation) plus the
fraction ``f`` (the interval's position noise accrued by the sample) of the rest of the interval's smoothed
correction; its covariance ``(1 - f) P_e + f P_e+1 + f (1 - f) Q`` (the Brownian bridge of a random walk of
accrued noise ``Q`` between its two smoothed ends, e.g. Karatzas & Shreve 1991, §5.6.B, with the ends' cross-
covariance replaced by its upper bound: conservative by at most ``f (1 - f) Q``). Measured errors (tests): on a
16 Hz dive with the defaults, mean within 1e-4 of the 1-sigma and covariance within 0.2 % of the full-rate
smoother; on a hard case (2 s epochs, 0.3 m/s currents, 1-sigma ~2.5 m), mean within 0.4 % of the 1-sigma and
the covariance's trace 0 to +3.7 % over the exact one.

Consistency of the fixes (the "w-test" of geodesy generalised to 2-D, Baarda 1968; Teunissen 2006,
*Testing theory*): for a fix used in the solution the residual ``r = z - x_s`` has covariance ``R - P_s``
and ``d^2 = r' (R - P_s)^-1 r`` is exactly the squared Mahalanobis distance of the fix from the smoothed
track computed *without it* (leave-one-out innovation), chi-square with 2 degrees of freedom. The fix with the
``d^2`` above the gate (``gate_probability``) whose removal leaves the others most consistent (smallest sum of
their ``d^2``; a bad fix also inflates its neighbours' statistics) is rejected, named, and the smoother re-run,
until every remaining fix passes; a fix no other source checks (``R - P_s`` ~ 0, no redundancy) is reported untestable.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import pandas as pd
from numba import njit

from hadal.settings.navigation import SmootherOptions

#: chi-square 2 dof quantiles of the 1-sigma and 2-sigma contents (68.27 %, 95.45 %): the 2-D ellipses
CHI2_2DOF_1SIGMA = 2.2957489
CHI2_2DOF_2SIGMA = 6.1800743
#: state size: position east/north, baroclinic current east/north, barotropic current east/north
N_STATE = 6


@dataclass(frozen=True)
class Fix:
    """One absolute position fix at sample ``index``: map frame ``x_m``/``y_m`` and its 2x2 covariance (m^2)."""

    index: int
    x_m: float
    y_m: float
    cov_m2: np.ndarray
    source: str
    time: object = None


@dataclass(frozen=True)
class SmoothedTrack:
    """:func:`smooth_positions`' result: per sample the smoothed position, its 2x2 covariance and the drift
    velocity; per fix its residual, chi-square and status (``fixes``)."""

    x_m: np.ndarray
    y_m: np.ndarray
    cov_m2: np.ndarray  # (n, 2, 2)
    current_m_s: np.ndarray  # (n, 2)
    fixes: pd.DataFrame
    gate_d2: float

    @property
    def rejected(self) -> list[str]:
        f = self.fixes
        return [f"{s} at sample {i}" for s, i in zip(f["source"][f["status"] == "rejected"],
                                                     f["index"][f["status"] == "rejected"], strict=True)]


def chi2_2dof_quantile(p: float) -> float:
    """Quantile of the chi-square distribution with 2 degrees of freedom (closed form: -2 ln(1 - p))."""
    return float(-2.0 * np.log1p(-p))


def ellipse(cov_m2: np.ndarray, d2: float = CHI2_2DOF_1SIGMA) -> dict[str, float]:
    """The ellipse ``x' C^-1 x = d2`` of a 2x2 covariance: semi-axes (m) and the major axis' azimuth (deg
    clockwise from north); ``d2`` 2.30 -> 68.3 % (1-sigma) content, 6.18 -> 95.4 % (2-sigma)."""
    w, v = np.linalg.eigh(np.asarray(cov_m2, float))
    w = np.maximum(w, 0.0)
    major = v[:, 1]
    return {"semi_major_m": float(np.sqrt(d2 * w[1])), "semi_minor_m": float(np.sqrt(d2 * w[0])),
            "azimuth_deg": float(np.degrees(np.arctan2(major[0], major[1])) % 180.0),
            "content": float(1.0 - np.exp(-0.5 * d2))}


def process_variances(dt_s: np.ndarray, d_m: np.ndarray, referenced: np.ndarray,
                      options: SmootherOptions, increment_cov_m2: np.ndarray | None = None) -> np.ndarray:
    """Per-step 2x2 position covariance (m^2, shape (n, 2, 2)) of the process model (module docstring) beyond the
    current's: the DR/random-walk variance per axis plus ``increment_cov_m2`` (n, 2, 2), the measured increments'
    own covariance (a DVL velocity's covariance x dt^2, :func:`hadal.navigation.sources.velocity_increments`)."""
    step = np.hypot(d_m[:, 0], d_m[:, 1])
    q = np.where(referenced, options.dr_variance_m2_per_m * step,
                 options.position_random_walk_m_per_sqrt_s ** 2 * dt_s)
    out = (q + 1e-6)[:, None, None] * np.eye(2)  # floor: keeps every step's covariance positive definite
    if increment_cov_m2 is not None:
        c = np.asarray(increment_cov_m2, float).reshape(-1, 2, 2)
        out = out + np.where(np.isfinite(c), c, 0.0)
    return out


def decorrelation(dt_s: np.ndarray, depth_m: np.ndarray | None, options: SmootherOptions) -> np.ndarray:
    """Per-step dimensionless decorrelation ``a`` of the current (module docstring): traversed depth over the
    vertical correlation length plus elapsed time over the correlation time. Missing depths: no vertical term."""
    a = np.asarray(dt_s, float) / options.current_correlation_time_s
    if depth_m is not None:
        z = pd.Series(np.asarray(depth_m, float)).ffill().bfill().to_numpy()
        dz = np.abs(np.diff(z, prepend=z[:1]))
        a = a + np.where(np.isfinite(dz), dz, 0.0) / options.current_vertical_correlation_m
    return a


@njit(cache=True, nogil=True)
def _ou_terms(dt, a, s2):  # pragma: no cover - compiled
    """Exact integrated Ornstein-Uhlenbeck step (rate a/dt over dt): phi, gain G of the position on the current,
    and the noise covariances Qcc, Qxc, Qxx of one axis (series for small ``a``: no cancellation)."""
    if a < 1e-4:
        phi = 1.0 - a + a * a / 2.0
        G = dt * (1.0 - a / 2.0 + a * a / 6.0)
        Qcc = s2 * (2.0 * a - 2.0 * a * a + 4.0 * a ** 3 / 3.0)
        Qxc = s2 * dt * (a - a * a + 7.0 * a ** 3 / 12.0)
        Qxx = s2 * dt * dt * (2.0 * a / 3.0 - a * a / 2.0)
    else:
        e = np.expm1(-a)
        phi = 1.0 + e
        G = -dt * e / a
        Qcc = s2 * (1.0 - phi * phi)
        Qxc = s2 * dt * e * e / a
        Qxx = s2 * dt * dt * (2.0 * a + 2.0 * e - e * e) / (a * a)
    return phi, G, Qcc, Qxc, Qxx


@njit(cache=True, nogil=True)
def _compose(dt, a_bc, a_bt, ref, eidx):  # pragma: no cover - compiled
    """The steps between two epochs composed exactly, per current component (0 baroclinic, 1 barotropic) and
    axis at unit variance (``s2 = 1``; module docstring, "Epochs"): for epoch ``e`` (steps ``eidx[e-1]+1 ..
    eidx[e]``) ``comp[e, c] = [G, phi, Qxx, Qxc, Qcc]``, the position's gain on the current, the current's decay and
    the noise covariance of (position, current) accrued over the steps (``F_m ... F_1``, ``sum F Q F'``); and per
    sample, from its epoch's start to ``k``, the position noise ``Qxx`` accrued (``acc[k, c]``) and the position's
    gain on the current (``acc[k, 2 + c]``)."""
    n = dt.shape[0]
    m = eidx.shape[0]
    comp = np.zeros((m, 2, 5))
    acc = np.zeros((n, 4))
    Gt = np.zeros(2)
    Pt = np.ones(2)
    qxx = np.zeros(2)
    qxc = np.zeros(2)
    qcc = np.zeros(2)
    comp[0, 0, 1] = comp[0, 1, 1] = 1.0
    e = 0
    for k in range(1, n):
        for c in range(2):
            phi, G, Qcc, Qxc, Qxx = _ou_terms(dt[k], a_bc[k] if c == 0 else a_bt[k], 1.0)
            if ref[k]:  # referenced step: the position does not integrate the current
                G = Qxc = Qxx = 0.0
            xx = qxx[c] + 2.0 * G * qxc[c] + G * G * qcc[c] + Qxx
            xc = phi * (qxc[c] + G * qcc[c]) + Qxc
            qcc[c] = phi * phi * qcc[c] + Qcc
            qxx[c] = xx
            qxc[c] = xc
            Gt[c] += G * Pt[c]
            Pt[c] *= phi
            acc[k, c] = xx
            acc[k, 2 + c] = Gt[c]
        if e + 1 < m and k == eidx[e + 1]:
            e += 1
            for c in range(2):
                comp[e, c, 0] = Gt[c]
                comp[e, c, 1] = Pt[c]
                comp[e, c, 2] = qxx[c]
                comp[e, c, 3] = qxc[c]
                comp[e, c, 4] = qcc[c]
                Gt[c] = qxx[c] = qxc[c] = qcc[c] = 0.0
                Pt[c] = 1.0
    return comp, acc


@njit(cache=True, nogil=True)
def _transition(comp, qpos, s2_bc, s2_bt):  # pragma: no cover - compiled
    """F, Q from one epoch to the next, state [x, y, c_bc east/north, c_bt east/north] (module docstring): the
    two current components are independent Ornstein-Uhlenbeck processes (``comp`` of :func:`_compose`, scaled by
    their variances), the position integrates their sum where the steps are unreferenced; ``qpos`` the 2x2
    position noise beyond the currents' accrued over the steps."""
    F = np.eye(N_STATE)
    Q = np.zeros((N_STATE, N_STATE))
    Q[:2, :2] = qpos
    for ci in range(2):
        col = 2 + 2 * ci
        s2 = s2_bc if ci == 0 else s2_bt
        for i in range(2):
            F[col + i, col + i] = comp[ci, 1]
            F[i, col + i] = comp[ci, 0]
            Q[i, i] += s2 * comp[ci, 2]
            Q[i, col + i] = Q[col + i, i] = s2 * comp[ci, 3]
            Q[col + i, col + i] = s2 * comp[ci, 4]
    return F, Q


@njit(cache=True, nogil=True)
def _mm(A, B):  # pragma: no cover - compiled
    """A @ B for small matrices (plain loops: no BLAS call per 6x6 product)."""
    n, m, q = A.shape[0], A.shape[1], B.shape[1]
    C = np.zeros((n, q))
    for i in range(n):
        for k in range(m):
            a = A[i, k]
            if a != 0.0:
                for j in range(q):
                    C[i, j] += a * B[k, j]
    return C


@njit(cache=True, nogil=True)
def _mv(A, x):  # pragma: no cover - compiled
    out = np.zeros(A.shape[0])
    for i in range(A.shape[0]):
        for k in range(A.shape[1]):
            out[i] += A[i, k] * x[k]
    return out


@njit(cache=True, nogil=True)
def _rts(comp, d, qpos, s2_bc, s2_bt, x0, P0, fidx, fz, fR, smooth):  # pragma: no cover - compiled
    """Kalman filter + RTS smoother over the epochs (module docstring): ``comp`` (:func:`_compose`), ``d`` the
    DR increments and ``qpos`` the position noise summed from one epoch to the next. Fixes sorted by epoch index
    ``fidx``. Returns the smoothed states (n, N_STATE), position covariances (n, 2, 2) and the fixes'
    log-likelihood."""
    n = comp.shape[0]
    xf = np.empty((n, N_STATE))
    Pf = np.empty((n, N_STATE, N_STATE))
    x = x0.copy()
    P = P0.copy()
    j = 0
    m = fidx.shape[0]
    ll = 0.0
    for k in range(n):
        if k > 0:
            F, Q = _transition(comp[k], qpos[k], s2_bc, s2_bt)
            x = _mv(F, x)
            x[0] += d[k, 0]
            x[1] += d[k, 1]
            P = _mm(_mm(F, P), F.T) + Q
        while j < m and fidx[j] == k:
            S = P[:2, :2] + fR[j]
            Si = np.linalg.inv(S)
            r = fz[j] - x[:2]
            if j > 0:  # the first fix meets the diffuse position prior: no information on the process
                ll -= 0.5 * (np.log(np.linalg.det(S)) + r @ Si @ r + 2.0 * np.log(2.0 * np.pi))
            K = np.ascontiguousarray(P[:, :2]) @ Si
            x = x + K @ r
            IKH = np.eye(N_STATE)
            IKH[:, :2] -= K
            P = IKH @ P @ IKH.T + K @ fR[j] @ K.T  # Joseph form
            j += 1
        xf[k] = x
        Pf[k] = 0.5 * (P + P.T)
    if not smooth:  # the fixes' likelihood only
        return xf[:0], np.empty((0, 2, 2)), ll
    xs = np.empty((n, N_STATE))
    Ps2 = np.empty((n, 2, 2))
    xs[n - 1] = xf[n - 1]
    Ps = Pf[n - 1].copy()
    Ps2[n - 1] = Ps[:2, :2]
    for k in range(n - 2, -1, -1):
        F, Q = _transition(comp[k + 1], qpos[k + 1], s2_bc, s2_bt)
        PfFt = _mm(Pf[k], F.T)
        Pp = _mm(F, PfFt) + Q
        xp = _mv(F, xf[k])
        xp[0] += d[k + 1, 0]
        xp[1] += d[k + 1, 1]
        G = _mm(PfFt, np.linalg.inv(Pp))
        xs[k] = xf[k] + _mv(G, xs[k + 1] - xp)
        Ps = Pf[k] + _mm(_mm(G, Ps - Pp), G.T)
        Ps = 0.5 * (Ps + Ps.T)
        Ps2[k] = Ps[:2, :2]
    return xs, Ps2, ll


@dataclass(frozen=True)
class _Epochs:
    """The smoother's problem on its epochs (module docstring, "Epochs"): sample index of every epoch, the steps
    between epochs composed (``comp``, :func:`_compose`), the DR increments ``d`` and position noise ``qpos``
    summed from the previous epoch; per sample the position noise accrued since its epoch's start (``acc`` per
    current component at unit variance, ``qcum`` the 2x2 beyond the currents') for the interpolation."""

    eidx: np.ndarray
    comp: np.ndarray
    d: np.ndarray
    qpos: np.ndarray
    acc: np.ndarray
    qcum: np.ndarray
    dcum: np.ndarray


def epoch_indices(t_s: np.ndarray, d_m: np.ndarray, fix_index: np.ndarray, options: SmootherOptions) -> np.ndarray:
    """Sample indices of the smoother's epochs: the first and the last sample, every fix's sample, and the first
    sample of every new ``epoch_interval_s`` of time or ``epoch_max_travel_m`` of dead-reckoned travel (every
    sample when ``epoch_interval_s`` is 0)."""
    n = t_s.size
    if options.epoch_interval_s == 0 or n < 3:
        return np.arange(n, dtype=np.int64)
    tb = np.floor((t_s - t_s[0]) / options.epoch_interval_s)
    step = np.hypot(d_m[:, 0], d_m[:, 1])
    step[0] = 0.0
    db = np.floor(np.cumsum(step) / options.epoch_max_travel_m)
    new = np.zeros(n, bool)
    new[0] = new[-1] = True
    new[1:] |= (tb[1:] != tb[:-1]) | (db[1:] != db[:-1])
    new[np.asarray(fix_index, np.int64)] = True
    return np.flatnonzero(new).astype(np.int64)


def _epochs(t_s, d_m, referenced, fix_index, options: SmootherOptions, a: np.ndarray,
            increment_cov_m2: np.ndarray | None) -> _Epochs:
    dt = np.clip(np.diff(np.asarray(t_s, float), prepend=float(t_s[0])), 0.0, None)
    qpos = process_variances(dt, d_m, referenced, options, increment_cov_m2)
    qpos[0] = 0.0
    d = np.array(d_m, float)
    d[0] = 0.0
    eidx = epoch_indices(np.asarray(t_s, float), d, fix_index, options)
    comp, acc = _compose(dt, np.ascontiguousarray(a, float), dt / options.current_correlation_time_s,
                         np.ascontiguousarray(referenced, np.bool_), eidx)
    dcum = np.cumsum(d, axis=0)
    qcum = np.cumsum(qpos, axis=0)
    de = np.diff(dcum[eidx], axis=0, prepend=np.zeros((1, 2)))
    qe = np.diff(qcum[eidx], axis=0, prepend=np.zeros((1, 2, 2)))
    return _Epochs(eidx, comp, np.ascontiguousarray(de), np.ascontiguousarray(qe), acc, qcum, dcum)


def _run(ep: _Epochs, fixes: list[Fix], use: np.ndarray, options: SmootherOptions, scale: float = 1.0,
         smooth: bool = True):
    """Smoothed states, position covariances (on the epochs) and the fixes' log-likelihood (prediction-error
    decomposition, the first fix excluded) with the currents' 1-sigma multiplied by ``scale``; ``fixes`` indexed
    by epoch."""
    sel = [f for f, u in zip(fixes, use, strict=True) if u]
    order = np.argsort([f.index for f in sel], kind="stable")
    sel = [sel[i] for i in order]
    fidx = np.array([f.index for f in sel], np.int64)
    fz = np.array([[f.x_m, f.y_m] for f in sel], float).reshape(-1, 2)
    fR = np.array([f.cov_m2 for f in sel], float).reshape(-1, 2, 2)
    # prior: diffuse position about the first fix (the fixes carry the information), currents at their
    # stationary distributions N(0, sigma^2)
    x0 = np.zeros(N_STATE)
    if len(sel):
        x0[:2] = fz[0]
    s2_bc = (scale * options.current_sigma_m_s) ** 2
    s2_bt = (scale * options.barotropic_current_sigma_m_s) ** 2
    P0 = np.diag([1e8, 1e8, s2_bc, s2_bc, s2_bt, s2_bt])
    return _rts(ep.comp, ep.d, ep.qpos, s2_bc, s2_bt, x0, P0, fidx, fz, fR, smooth)


def interpolate_epochs(ep: _Epochs, xs: np.ndarray, Ps: np.ndarray, s2_bc: float, s2_bt: float
                       ) -> tuple[np.ndarray, np.ndarray]:
    """Every sample's state and 2x2 position covariance from the smoothed epochs (module docstring, "Epochs"):
    between epochs ``e`` and ``e+1``, with ``f`` the fraction of the interval's position noise accrued by the
    sample, the mean is the epoch's plus the DR increment since it plus ``f`` times the smoothed correction of
    the interval, and the covariance ``(1 - f) P_e + f P_e+1 + f (1 - f) Q`` (a Brownian bridge over the
    interval's accrued noise ``Q``; ``s2_*`` the currents' variances it is evaluated with)."""
    n = ep.acc.shape[0]
    eidx = ep.eidx
    if eidx.size == n:
        return xs, Ps
    j = np.searchsorted(eidx, np.arange(n), side="left")  # the epoch ending the interval of each sample
    j0 = np.maximum(j - 1, 0)
    cur = s2_bc * ep.acc[:, 0] + s2_bt * ep.acc[:, 1]
    # position noise accrued since the interval's start epoch (per axis, trace / 2), at the sample and at its end
    qs = ep.qcum - ep.qcum[eidx[j0]]
    vk = cur + 0.5 * (qs[:, 0, 0] + qs[:, 1, 1])
    vend = vk[eidx[j]]
    f = np.where(vend > 0, vk / np.where(vend > 0, vend, 1.0), 1.0)
    f = np.where(j == 0, 1.0, np.clip(f, 0.0, 1.0))  # the first sample is an epoch
    # the DR increment and the drift of the start epoch's current since the start epoch, exactly; the rest of
    # the interval's smoothed correction in proportion to the noise accrued
    du = ep.dcum - ep.dcum[eidx[j0]] + ep.acc[:, 2:3] * xs[j0, 2:4] + ep.acc[:, 3:4] * xs[j0, 4:6]
    corr = xs[j, :2] - xs[j0, :2] - du[eidx[j]]
    out = (1.0 - f)[:, None] * xs[j0] + f[:, None] * xs[j]  # the currents: linear
    out[:, :2] = xs[j0, :2] + du + f[:, None] * corr
    Qend = qs[eidx[j]] + (s2_bc * ep.comp[j, 0, 2] + s2_bt * ep.comp[j, 1, 2])[:, None, None] * np.eye(2)
    P = ((1.0 - f)[:, None, None] * Ps[j0] + f[:, None, None] * Ps[j]
         + (f * (1.0 - f))[:, None, None] * Qend)
    return out, P


def _fix_tests(xs: np.ndarray, Ps: np.ndarray, fixes: list[Fix], use: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Residual (z - x_s) and leave-one-out squared Mahalanobis distance of every fix (NaN: untestable)."""
    res = np.empty((len(fixes), 2))
    d2 = np.full(len(fixes), np.nan)
    for i, f in enumerate(fixes):
        r = np.array([f.x_m - xs[f.index, 0], f.y_m - xs[f.index, 1]])
        res[i] = r
        R = np.asarray(f.cov_m2, float)
        C = R - Ps[f.index] if use[i] else R + Ps[f.index]
        w = np.linalg.eigvalsh(C)
        if w[0] > 1e-6 * max(float(np.trace(R)), 1e-12):
            d2[i] = float(r @ np.linalg.solve(C, r))
    return res, d2


def current_scales(options: SmootherOptions) -> np.ndarray:
    """The grid of current 1-sigma multipliers (log-spaced over ``current_scale_range``, ``current_scale_points``)."""
    lo, hi = options.current_scale_range
    return np.geomspace(lo, hi, options.current_scale_points) if options.current_scale_points > 1 else np.ones(1)


def marginal_over_current_scale(ep: _Epochs, fixes: list[Fix], use: np.ndarray, options: SmootherOptions):
    """The smoothed track with the currents' strength marginalised (module docstring): one smoother per scale
    ``s`` of :func:`current_scales` (log-uniform prior), weighted by the fixes' likelihood ``p(z | s)``; the
    mixture's mean and covariance (``sum w_i (P_i + (x_i - x)(x_i - x)')``); the weights from forward passes,
    the backward pass only for scales of weight >= 1e-6 x the largest. On the epochs (``fixes`` indexed by
    epoch); returns (states, position covariances, weights)."""
    scales = current_scales(options)
    ll = np.array([_run(ep, fixes, use, options, float(s), smooth=False)[2] for s in scales])
    w = np.exp(ll - ll.max())
    w /= w.sum()
    keep = w >= 1e-6 * w.max()  # scales the fixes exclude are not smoothed (their weight is below 1e-6)
    w = np.where(keep, w, 0.0) / w[keep].sum()
    runs = [_run(ep, fixes, use, options, float(s)) if k else None for s, k in zip(scales, keep, strict=True)]
    xs = sum(wi * r[0] for wi, r in zip(w, runs, strict=True) if r is not None)
    Ps = np.zeros((ep.eidx.size, 2, 2))
    for wi, r in zip(w, runs, strict=True):
        if r is None:
            continue
        dx = r[0][:, :2] - xs[:, :2]
        Ps += wi * (r[1] + dx[:, :, None] * dx[:, None, :])
    return xs, Ps, w


def smooth_positions(t_s, dr_increment_m, referenced, fixes: list[Fix],
                     options: SmootherOptions | None = None, depth_m=None,
                     increment_cov_m2=None) -> SmoothedTrack:
    """Smoothed position and 2x2 covariance of every sample (module docstring).

    ``t_s`` (n,) sample times (s, non-decreasing); ``dr_increment_m`` (n, 2) east/north dead-reckoned
    displacement from sample ``k-1`` to ``k`` (row 0 unused); ``referenced`` (n,) bool, the step to ``k`` had a
    velocity reference (DR moving); ``fixes``: absolute fixes (at least one); ``depth_m`` (n,) the vehicle's depth
    (m, positive down; the current decorrelates with the depth traversed; None: time only);
    ``increment_cov_m2`` (n, 2, 2) the increments' own covariance (measured velocities, e.g. DVL). Inconsistent fixes are rejected by
    the chi-square gate, one at a time, worst first (``fixes`` table: ``status`` used / rejected, ``d2``)."""
    from hadal.errors import InputError

    options = options or SmootherOptions()
    t_s = np.asarray(t_s, float)
    d_m = np.asarray(dr_increment_m, float).reshape(-1, 2)
    n = t_s.size
    if n == 0:
        raise InputError("navigation smoother: no samples")
    if not fixes:
        raise InputError("navigation smoother: no position fix (launch, GNSS, USBL or terrain); nothing anchors the track")
    d_m = np.where(np.isfinite(d_m), d_m, 0.0)
    idx = np.array([f.index for f in fixes], np.int64)
    if idx.min() < 0 or idx.max() >= n:
        raise InputError(f"navigation smoother: a fix's sample index is outside 0..{n - 1}")
    gate = chi2_2dof_quantile(options.gate_probability)
    use = np.ones(len(fixes), bool)
    a = decorrelation(np.clip(np.diff(t_s, prepend=t_s[:1]), 0.0, None), depth_m, options)
    ep = _epochs(t_s, d_m, referenced, idx, options, a, increment_cov_m2)
    efix = [replace(f, index=int(e)) for f, e in zip(fixes, np.searchsorted(ep.eidx, idx), strict=True)]
    xs, Ps, _ = _run(ep, efix, use, options)
    res, d2 = _fix_tests(xs, Ps, efix, use)
    while (~use).sum() < options.max_rejections and use.sum() > 1:
        failing = np.flatnonzero(use & np.isfinite(d2) & (d2 > gate))
        if failing.size == 0:
            break
        # one bad fix also pulls the others' leave-one-out residuals (a precise recovery fix can fail for a bad
        # USBL fix before it): reject the failing fix whose removal leaves the others most consistent (smallest
        # sum of their chi-squares), not merely the largest chi-square
        best = None
        for i in failing[np.argsort(-d2[failing])][:20]:
            u = use.copy()
            u[i] = False
            xs_i, Ps_i, _ = _run(ep, efix, u, options)
            res_i, d2_i = _fix_tests(xs_i, Ps_i, efix, u)
            score = float(np.nansum(np.where(u, d2_i, 0.0)))
            if best is None or score < best[0]:
                best = (score, i, xs_i, Ps_i, res_i, d2_i)
        assert best is not None  # failing is not empty
        _, i, xs, Ps, res, d2 = best
        use[i] = False
    s2 = (options.current_sigma_m_s ** 2, options.barotropic_current_sigma_m_s ** 2)
    if options.current_scale_points > 1 and use.sum() > 1:
        # the published track: the currents' strength marginalised; the fixes' residuals and chi-squares stay
        # those of the gate's Gaussian model (scale 1), where d2 is exactly the leave-one-out statistic
        xs, Ps, w = marginal_over_current_scale(ep, efix, use, options)
        m2 = float(np.sum(w * current_scales(options) ** 2))  # the mixture's mean current variance factor
        s2 = (s2[0] * m2, s2[1] * m2)
    xs, Ps = interpolate_epochs(ep, xs, Ps, *s2)
    fx = pd.DataFrame({
        "source": [f.source for f in fixes], "index": [f.index for f in fixes], "time": [f.time for f in fixes],
        "x_east_m": [f.x_m for f in fixes], "y_north_m": [f.y_m for f in fixes],
        "residual_east_m": res[:, 0], "residual_north_m": res[:, 1], "d2": d2,
        "status": np.where(use, "used", "rejected")})
    return SmoothedTrack(xs[:, 0].copy(), xs[:, 1].copy(), Ps, xs[:, 2:4] + xs[:, 4:6], fx, gate)
