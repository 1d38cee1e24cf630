"""Terrain-relative navigation as a posterior: point-mass-filter likelihood over position, heading, scale, bias.

TERCOM (``tercom.py``, [TERCOM Eqs. 15-17], §4.2) returns the offset of the best score; a score is
not a probability. Here the MSD surfaces over offsets x headings x scales [TERCOM Eq. 17] are turned
into a likelihood and a posterior, as point-mass filters for terrain-relative navigation do:

**Measurement model.** The measured depth of sample ``i`` is ``d_i = z(p_i) - b + e_i`` with the
track pose ``p_i = start + f R(a) (track_i - track_0)`` (heading error ``a``, scale ``f``), a constant
depth bias ``b`` and ``e_i ~ N(0, s^2)`` where ``s^2 = s_p^2 + s_map^2`` is the profile noise plus the
map error. With the MSD residual at an offset ``MSD_b = 1/N_v sum (d_BT - d_M - b_hat)^2`` [TERCOM
Eq. 17, bias at its closed-form optimum] the log-likelihood, bias marginalised under a flat prior, is

    ll = gamma * [ -N_v/2 log(2 pi s^2) - N_v MSD_b / (2 s^2) + 1/2 log(2 pi s^2 / N_v)
                   + (N - N_v) * c_miss ],   c_miss = -1/2 log(2 pi (v_map + s^2)) - 1/2

* ``N_v`` samples fall on valid map cells; a sample without a map depth (off the map, over a hole)
  is not dropped but scored with the map's own depth distribution (variance ``v_map`` over the
  search region): it carries no position information, but an offset cannot win by leaving the
  map's difficult parts (without this a track 30 % off the map is "fixed" elsewhere on the map).
* ``s^2`` is estimated from the data: the residual at the maximum-a-posteriori pose,
  ``s^2 = N_v MSD_b / (N_v - 5)`` (five fitted parameters: x, y, heading, scale, bias), floored by the
  DTM's ``uncertainty_m`` layer when it exists (the variance of the bilinear map it implies along the matched
  track, independent cell errors: :func:`_map_sigma2_at`; on the sample dive 5.6-6.7 m, where the smoothed DTM's
  error along the true track is 5.0-6.7 m with its common offset, 3.3-5.2 m without), and by a tiny
  numeric floor (the likelihood that ranks the offsets and modes; the main mode's covariance re-estimates both at
  the continuous MAP, *Reported*).
* ``gamma = N_eff / N_v``: the residuals along a track are correlated (real seafloor roughness, map
  interpolation error and dead-reckoning drift vary smoothly), so ``N_v`` samples do not carry ``N_v`` independent
  pieces of information. ``N_eff`` is estimated from the residuals at the MAP pose (*Correlated residuals*).

**Correlated residuals** (issue 47; :class:`hadal.matching.options.PosteriorNoiseOptions`). The residuals'
autocorrelation along the track is measured at the fix: ``rho_k``, the sample autocorrelation at lag ``k`` samples
(missing samples keep their place), truncated by Geyer's initial positive sequence (:func:`residual_autocorrelation`;
Geyer 1992, *Practical Markov chain Monte Carlo*, Statist. Sci. 7, 473-511, §3.3), ``K <= min(correlation_max_lag,
N_v / 4)``. Its effective sample size is ``N_eff = N_v / (1 + 2 sum_{k=1}^{K} rho_k)`` (:func:`effective_sample_size`,
the integrated autocorrelation time; for an AR(1) series ``N_v (1 - rho) / (1 + rho)``, for white noise ``N_v``).

* default ``correlation_model="hac"``: the main mode's covariance is the **HAC sandwich** of the fit
  (heteroscedasticity-and-autocorrelation consistent; Newey & West 1987, Econometrica 55, 703-708, with the truncated
  sample autocorrelation as the lag weights): ``C = A^-1 [(gamma / s^2)^2 s^2 J^T R J + L] A^-1`` with
  ``A = (gamma / s^2) J^T J + L`` (the tempered curvature, ``L`` the drift prior's precision) and
  ``R_ij = max(rho_|i-j|, 0)`` (:func:`_hac_meat`; negative lags are not credited: the residuals of a fit are
  anti-correlated by the fit itself, and on white noise the sample autocorrelation's negative values would narrow
  the covariance below the white-noise one). Without a prior it is ``s^2 (J^T J)^-1 J^T R J (J^T J)^-1`` whatever
  ``gamma``: the variance of the least-squares start under noise of correlation ``R``; with white residuals
  ``R = I`` it is the Laplace covariance ``A^-1``. It is floored, in every direction, by the covariance the same
  residual variance would give independent samples, ``(J^T J / s^2 + L)^-1`` (``C = C_w + [C - C_w]_+``, the
  positive part of the difference; the sample autocorrelation is noisy on short tracks and a fit is not credited
  with more than independent samples' information). (When ``J^T R J`` is not positive semi-definite, ``A^-1`` is
  kept.)
  The likelihood is tempered as before (``gamma`` from the lag-1 AR(1) equivalent below): the MAP, the posterior
  masses and the flags do not change, only the main mode's covariance;
* ``"acf"``: the same covariance and the likelihood tempered by ``N_eff / N_v`` of the autocorrelation sum (a
  sharper posterior; on the bench below a little worse: more false alarms, one confident wrong fix);
* ``"ar1"``: the previous model, ``gamma = (1 - rho_1) / (1 + rho_1)`` from the lag-1 autocorrelation alone and
  ``C = A^-1`` (the tempered Laplace covariance).

Why: tempering the curvature by ``gamma`` alone (``"ar1"``) treats the map-gradient regressors as if they were as
correlated along the track as the residuals. Real roughness is smooth at the sample spacing (lag-1 autocorrelation
high, decaying faster than ``rho_1^k``) while the terrain gradient under a meandering track changes from sample to
sample: the variance of the start grows by about ``1 + 2 sum rho_k rho^J_k`` (``rho^J`` the regressors'
autocorrelation), not ``1 + 2 sum rho_k``, let alone ``(1 + rho_1) / (1 - rho_1)``. On real along-track roughness
(bench/bench_terrain_calibration.py, 240 tracks on ETOPO5/ETOPO2 terrain, noise from EM302 ship soundings' residuals,
ETOPO2 and laser-bathymetry high-pass residuals, seed 0) ``"ar1"`` was too wide (unflagged fixes: 77 % within 1 DRMS,
median squared Mahalanobis distance 0.93 against 1.36 for a calibrated 2-D Gaussian); ``"hac"``: 62 % within 1 DRMS,
98 % within 2 DRMS, median 1.62 (held-out seed 1: 56 %, 93 %, 1.60); on white Gaussian noise 68 % / 95 % / 1.35 (``"ar1"``: 72 % / 95 % / 1.24).
**Deviation from the papers:** TERCOM [TERCOM Eq. 17] scores the MSD of independent samples and reports no
covariance; the MRF paper (Assumption 4) takes the residual as Gaussian white noise. Neither models correlated
residuals.

**Search edge** (issue 47; :class:`hadal.matching.options.SearchEdgeOptions`). A MAP heading or scale within a
quarter of the search step of a bound of its searched grid (``headings_deg``; ``scales`` with ``fine_scales``) says
the true pose may lie outside the search (a wrong pose then fits the track best and its covariance is confidently
wrong). The search is repeated once with that range widened ``edge_widen_factor`` times about its centre (same step;
at most ``edge_max_heading_range_deg`` / ``edge_max_scale_range``); when its MAP lies inside, its fix is reported;
if it is still at the (wider) bound, the first search's fix is reported and flagged: ``mismatch`` with reason
``at_search_edge``, a warning ``possible mismatch: search edge: ...``, ``summary()['covariance_trusted']`` false; ``search_edge`` (and ``summary()['search_edge']``) records the check,
the retry and the bounds.

**Coarse posterior (whole map).** The MSD of every start cell for every (heading, scale) pose comes
from the FFT route of ``tercom.py`` [TERCOM Eq. 17] (nearest-cell sampling); the posterior over start
cells is the likelihood marginalised over the poses (uniform prior on the searched grid). Its modes
(local maxima) are ranked by the mass within ``mode_radius_cells`` of them.

**Fine posterior (sub-cell, point-mass grid).** Around the main mode and the ``n_alt_modes`` next
modes the same likelihood is evaluated with the map sampled **bilinearly** at the un-snapped track
positions, on a grid of start offsets (``fine_step_cells``) x the poses that are plausible there.
All windows use one ``s^2`` and one ``gamma`` (estimated at the fine MAP): seeds are compared under
the same likelihood, by posterior mass, not by their lowest MSD. The windows' share of the coarse
mass is redistributed among them by their fine mass; the mass outside them keeps the coarse values.
The MAP is the fine grid's best point; a Nelder-Mead polish of it is kept only when it raises the
same log-likelihood (so refinement never makes the posterior worse; the coarse cell centre and pose
are on the fine grid, hence the fine MAP is never worse than the coarse fix).

**Joint drift (dead-reckoning error along the track).** The rigid pose cannot follow a dead-reckoning
error that grows along the track, so the start would be carried from the terrain that fixes the track by the
drift in between. After the grid, the MAP pose is refitted jointly with a drift ``w(tau) = sum_k B_k(tau) u_k``:
a velocity bias ``u_k`` (east, north) constant within segments of ``drift_segment`` (time ``tau`` in s when
``time_s`` is given, else along-track distance in m), integrated so that ``w`` is continuous and zero at the
first sample (the start is not moved by it). Measurement model ``d_i = z(p_i + w_i) - b + e_i``, prior
``u_k ~ N(0, drift_sigma^2)``; Levenberg-Marquardt on the same tempered log-likelihood (bilinear map, bias
profiled out, analytic bilinear gradient) plus the prior, over start x/y, heading, scale (within the searched
bounds; ``fine_scales`` widens the scale range) and the ``2K`` rates. The rigid fit's residuals are correlated
by the drift itself, so the noise variance and ``N_eff`` are re-estimated from the joint residuals (up to three
passes, each started from the rigid MAP). The joint fit replaces the rigid MAP only when it raises the
log-posterior over the rigid MAP (zero drift) under the same likelihood. The rates are marginalised in the main
mode's covariance (*Reported*: the drift the terrain cannot pin down widens it; in the grid fallback their Laplace
inflation, joint minus rigid, is added to the window's second moment). ``refinement.drift`` records the segments, rates, drift at the end and the inflation;
:meth:`PosteriorFix.apply` with ``tau`` places any track point with the drift. (A modelling choice beyond the
TERCOM paper, which matches a rigid track.)

**Crop.** The FFTs and the per-pose surfaces run on the map cropped to the search region plus the track's
footprint (every heading x scale) and a margin; with a region (the suitability stage's proposed one) the cost
and memory are those of the region, not of the map.

**Reported.** The MAP fix (start, heading, scale, bias) and the **main mode's covariance** ``C``
(``sigma_x_m``/``sigma_y_m``; radial DRMS ``sqrt(tr C)``, which a calibrated 2-D Gaussian error stays within 63 %
(circular) to 68 % (line-shaped ellipse) of the time and within twice 95-98 %; the 1-sigma and 2-sigma ellipses,
39 % / 86 % content), the posterior mass outside the main mode and the second mode. The whole posterior's second
moment about the MAP (every mode) is ``mixture_cov_m2``: it is not the fix's error scale (a mass of 1e-4 forty cells
away adds 0.16 cell^2), the mass elsewhere is reported (and flagged) as a probability instead.

``C`` is the Laplace covariance at the **continuous** MAP (:func:`_laplace_main_mode`): the fit of start x/y, the
free heading and scale, the drift rates (when applied, marginalised under their prior) and the bias, linearised
with the bilinear map gradients (``J``), with the noise variance ``s^2 = RSS / (N_v - p)`` and the tempering ``gamma``
re-estimated from the residuals at that MAP: ``C = ((gamma / s^2) J^T J + L)^-1``. The grid's ``s^2`` comes from its
best discrete pose (1 deg headings, 3 % scales), whose misfit is not noise: on a fixed real-terrain track it was
1.6-1.9 times the true noise sigma and the grid's second moment 3.7-14 times the Monte-Carlo spread of the fix
(bench/posterior_mc_fixed_track.py); the Laplace covariance at the continuous MAP matches that spread. A dead-reckoning
**random walk** (``drift_random_walk``, from the navigation's specification: the part of the DR error the drift
segments do not model) moves the start by the error it carries from the terrain that fixes the track: its share,
the least-squares sandwich ``(gamma / s^2)^2 q C J^T W J C`` with ``W_ij = min(tau_i, tau_j) g_i . g_j`` (``g`` the
map gradient at the samples, ``q = drift_random_walk^2``; :func:`_walk_information`), is added. Measured on the real-terrain calibration bench (bench/calibration_tercom.py,
320 trials a seed, the simulated walk given): errors within the DRMS 0.67-0.74 and within 2 DRMS 0.955-0.974 on
seeds 0-5 (the grid's second moment gave 0.71-0.78 and 0.95-0.97; with the walk withheld, seeds 0 and 1,
0.55-0.59 and 0.905-0.918, the long tracks' errors then beyond it). When the linearised fit is degenerate (fewer
valid samples with a map gradient than parameters + 3, a singular information matrix) the main window's own
second moment is used instead, widened for correlated residuals (:func:`_fit_dof_inflation`: ``(N_v - p) /
(N_v - tr(P R))``, the noise a fit absorbs from AR(1) residuals; :func:`_position_variance_ratio`: the White
sandwich over the tempered curvature) plus the drift's Laplace inflation; ``refinement.main_mode_covariance``
says which, with the noise and tempering used. **Mismatch** (``mismatch=True`` and a reason in ``reasons``):

* ``ambiguous``: more than ``max_mass_outside`` (20 %) of the posterior outside the main mode;
* ``over_holes``: the map has interior holes (empty cells not connected to its border; border-connected ones
  are outside its coverage) and, were the map under them to fit the track as well as its valid part does (each
  hole sample scored with the unbiased residual variance of the valid samples at its offset), more than
  ``max_mass_outside_holes`` (5 %) of the posterior would lie outside the main mode. The likelihood scores a
  sample over a hole with the map's whole depth distribution, which favours hole-free offsets: on real terrain
  with 40-50 % of the track over holes the MAP lands confidently on a hole-free spot elsewhere (the previous
  calibration's only misses); this test catches them;
* ``short_track``: fewer than ``min_samples`` profile samples;
* ``off_map``: fewer than ``min_valid_for_fix`` (50 %) of the samples on valid map cells at the fix
  (between that and ``min_valid_at_fix``, 90 %, a warning only: missing samples are in the likelihood,
  so a posterior that stays tight and unimodal on the rest is trusted);
* ``no_terrain_information``: the map relief under the matched track (std) below
  ``min_relief_to_noise`` x the noise ``s`` (a flat map).

``mass_outside_main_mode`` is the posterior probability that the error exceeds ``mode_radius_cells``
(3 cells); a broad posterior (weak terrain) and a competing mode both raise it. The DRMS is not used
as a flag: a tiny mass far away inflates the second moment without making the fix wrong. On the real-terrain
calibration bench it behaves as a probability (of the fixes with 10-20 % outside, about one in eight was more
than 3 cells off), so a 5 % threshold flagged mostly correct fixes of 20-24-sample tracks; 20 % was chosen on
bench seed 1 once the holes test caught the tracks over holes (their wrong fixes had 0-13 % outside) and
checked on seeds 2 and 3 (bench/calibration_tercom.py).
"""

from __future__ import annotations

import warnings as _warnings
from collections.abc import Sequence
from dataclasses import dataclass, field, replace

import numpy as np
from scipy import ndimage

from hadal.errors import InputError
from hadal.matching.mapgrid import MapGrid
from hadal.matching.options import PosteriorNoiseOptions, SearchEdgeOptions
from hadal.matching.tercom import (
    TercomResult,
    _FFTCorrelator,
    _required_samples,
    _rotate,
    _snap,
    _sums_all_offsets,
    _validate_inputs,
    pose_at_search_edge,
    search_edge_warning,
)
from hadal.settings.match import (
    DRIFT_SEGMENT_S,
    DRIFT_VELOCITY_SIGMA_M_S,
    MAX_MASS_OUTSIDE,
    MAX_MASS_OUTSIDE_HOLES,
    MIN_SAMPLES,
    MODE_RADIUS_CELLS,
)

N_PARAMS = 5  # x, y, heading, scale, bias
GAUSS_1SIGMA_CONTENT = 1 - np.exp(-0.5)  # 2-D Gaussian mass inside the 1-sigma ellipse
GAUSS_2SIGMA_CONTENT = 1 - np.exp(-2.0)


@dataclass
class PosteriorFix:
    """Posterior of the track start (module docstring). Positions are map metres (x east, y north)."""

    start_x_m: float
    start_y_m: float
    heading_deg: float
    scale: float
    bias_m: float
    mean_x_m: float
    mean_y_m: float
    cov_m2: np.ndarray
    mass_outside_main_mode: float
    mode_radius_m: float
    second_mode: dict | None
    noise_sigma_m: float
    map_sigma_m: float
    n_eff: float
    n_samples: int
    n_valid: int
    relief_to_noise: float
    mismatch: bool
    reasons: list[str]
    warnings: list[str]
    track_start_xy: tuple[float, float]
    posterior_cells: np.ndarray  # marginal posterior over start cells (map grid), sums to 1
    x_m: np.ndarray
    y_m: np.ndarray
    refinement: dict = field(default_factory=dict)
    modes: list[dict] = field(default_factory=list)
    drift_model: tuple | None = None  # (tau of the first sample, segment edges, (K, 2) rates, unit) or None
    mixture_cov_m2: np.ndarray | None = None  # second moment of the whole posterior (every mode) about the MAP
    search_edge: dict = field(default_factory=dict)  # the search-edge check, retry and flag (module docstring)

    @property
    def sigma_x_m(self) -> float:
        return float(np.sqrt(self.cov_m2[0, 0]))

    @property
    def sigma_y_m(self) -> float:
        return float(np.sqrt(self.cov_m2[1, 1]))

    @property
    def sigma_m(self) -> float:
        """Radial DRMS, ``sqrt(trace C)``."""
        return float(np.sqrt(np.trace(self.cov_m2)))

    @property
    def valid_fraction(self) -> float:
        return self.n_valid / self.n_samples if self.n_samples else 0.0

    def ellipse(self, k: float = 1.0) -> dict:
        """``k``-sigma ellipse of ``cov_m2``: semi-axes (m) and the major axis azimuth (deg clockwise from north)."""
        w, v = np.linalg.eigh(self.cov_m2)
        w = np.maximum(w, 0.0)
        major = v[:, 1]
        az = float(np.degrees(np.arctan2(major[0], major[1])) % 180.0)
        content = float(1 - np.exp(-0.5 * k * k))
        return {"semi_major_m": float(k * np.sqrt(w[1])), "semi_minor_m": float(k * np.sqrt(w[0])),
                "azimuth_deg": az, "gaussian_content": content}

    def mahalanobis(self, x_m: float, y_m: float) -> float:
        e = np.array([x_m - self.start_x_m, y_m - self.start_y_m])
        try:
            return float(np.sqrt(e @ np.linalg.solve(self.cov_m2, e)))
        except np.linalg.LinAlgError:
            return float("inf")

    def apply(self, track_xy, tau=None) -> np.ndarray:
        """Map positions of track points given in the input track's frame (as :meth:`TercomResult.apply`), plus
        the estimated drift at ``tau`` (their times, or along-track distances, in the unit of the fit) when given."""
        p = np.asarray(track_xy, float).reshape(-1, 2) - np.asarray(self.track_start_xy)
        out = _rotate(p, self.heading_deg) * self.scale + np.array([self.start_x_m, self.start_y_m])
        if tau is not None:
            out = out + self.drift_at(tau)
        return out

    def drift_at(self, tau) -> np.ndarray:
        """(M, 2) estimated dead-reckoning drift (m, east/north) at ``tau`` (zero at the first profile sample)."""
        tau = np.asarray(tau, float).ravel()
        if self.drift_model is None:
            return np.zeros((tau.size, 2))
        t0, edges, U, _ = self.drift_model
        B = np.clip((tau - t0)[:, None] - edges[None, :-1], 0.0, np.diff(edges)[None, :])
        return B @ U

    def summary(self) -> dict:
        """The ``posterior`` section of ``fix.json`` (JSON-ready, NaN left to ``json_clean``)."""
        return {
            "method": "point-mass posterior over start x/y x heading x scale (bias marginalised) from the MSD "
                      "likelihood [TERCOM Eq. 17]; noise variance and effective sample size estimated from the residuals",
            "map_fix": {"x_east_m": self.start_x_m, "y_north_m": self.start_y_m, "heading_error_deg": self.heading_deg,
                        "track_scale": self.scale, "bias_m": self.bias_m},
            "mean": {"x_east_m": self.mean_x_m, "y_north_m": self.mean_y_m},
            "covariance_m2": [[float(self.cov_m2[0, 0]), float(self.cov_m2[0, 1])],
                              [float(self.cov_m2[1, 0]), float(self.cov_m2[1, 1])]],
            "covariance_comment": "covariance of the main mode (Laplace at the MAP), east/north; the posterior's mass "
                                  "elsewhere is mass_outside_main_mode, its second moment over every mode "
                                  "mixture_covariance_m2",
            "mixture_covariance_m2": None if self.mixture_cov_m2 is None else
            [[float(self.mixture_cov_m2[0, 0]), float(self.mixture_cov_m2[0, 1])],
             [float(self.mixture_cov_m2[1, 0]), float(self.mixture_cov_m2[1, 1])]],
            "drms_m": self.sigma_m,
            "ellipse_1sigma": self.ellipse(1.0),
            "ellipse_2sigma": self.ellipse(2.0),
            "mass_outside_main_mode": self.mass_outside_main_mode,
            "main_mode_radius_m": self.mode_radius_m,
            "second_mode": self.second_mode,
            "modes": self.modes,
            "noise_sigma_m": self.noise_sigma_m,
            "map_sigma_m": self.map_sigma_m,
            "n_eff": self.n_eff,
            "n_samples": self.n_samples,
            "n_valid": self.n_valid,
            "valid_fraction": self.valid_fraction,
            "relief_to_noise": self.relief_to_noise,
            "mismatch": self.mismatch,
            "mismatch_reasons": list(self.reasons),
            "covariance_trusted": not self.mismatch,
            "search_edge": self.search_edge,
            "refinement": self.refinement,
            "drift": self.refinement.get("drift", {"applied": False}),
        }

    def to_tercom_result(self, coarse: TercomResult) -> TercomResult:
        """``coarse`` (the paper's search, its surfaces) with the pose, sigma, mismatch and warnings of the posterior."""
        hc = coarse.x_m[1] - coarse.x_m[0]  # cells of the coarse search's map (the posterior may hold a crop)
        g_rows = int(np.clip(np.rint((self.start_y_m - coarse.y_m[0]) / hc), 0, coarse.y_m.size - 1))
        g_cols = int(np.clip(np.rint((self.start_x_m - coarse.x_m[0]) / hc), 0, coarse.x_m.size - 1))
        sm = self.second_mode or {}
        keep = [w for w in coarse.warnings if "possible mismatch" not in w and "fall on invalid map cells" not in w]
        return replace(
            coarse, start_x_m=self.start_x_m, start_y_m=self.start_y_m, start_row=g_rows, start_col=g_cols,
            heading_deg=self.heading_deg, scale=self.scale, bias_m=self.bias_m, n_valid=self.n_valid,
            sigma_x_m=self.sigma_x_m, sigma_y_m=self.sigma_y_m, mismatch=self.mismatch,
            second_x_m=float(sm.get("x_east_m", np.nan)), second_y_m=float(sm.get("y_north_m", np.nan)),
            warnings=keep + list(self.warnings), search_edge=self.search_edge,
            refinement={"posterior": True, **self.refinement,
                        "coarse": {"x_east_m": coarse.start_x_m, "y_north_m": coarse.start_y_m,
                                   "heading_deg": coarse.heading_deg, "scale": coarse.scale, "score": coarse.score,
                                   "separation_ratio": coarse.separation_ratio,
                                   "comment": "the paper's cell-resolution TERCOM (MSD) search"}},
        )


# ------------------------------------------------------------------ likelihood helpers
def _loglik(msd, n_valid, n_total: int, s2: float, v_map: float, gamma: float):
    """Tempered log-likelihood of offsets from their bias-free MSD (module docstring)."""
    with np.errstate(invalid="ignore", divide="ignore"):
        nv = np.maximum(n_valid, 1.0)
        ll = (-0.5 * nv * np.log(2 * np.pi * s2) - nv * msd / (2 * s2) + 0.5 * np.log(2 * np.pi * s2 / nv)
              + (n_total - n_valid) * (-0.5 * np.log(2 * np.pi * (v_map + s2)) - 0.5))
    ll = gamma * ll
    return np.where(np.isfinite(ll), ll, -np.inf)


def _n_eff_ar1(res: np.ndarray) -> float:
    """AR(1) effective sample size of a residual sequence (NaNs dropped): ``n (1 - rho_1) / (1 + rho_1)``, ``rho_1`` the
    lag-1 autocorrelation clipped to [0, 0.95] (the previous model, ``correlation_model="ar1"``)."""
    r = res[np.isfinite(res)]
    n = r.size
    if n < 4:
        return float(max(n, 1))
    r = r - r.mean()
    den = float(r @ r)
    if den <= 0:
        return float(n)
    rho = float(r[1:] @ r[:-1]) / den
    rho = min(max(rho, 0.0), 0.95)
    return float(max(n * (1 - rho) / (1 + rho), 2.0))


def residual_autocorrelation(res, max_lag: int = 50) -> np.ndarray:
    """Autocorrelation ``rho_1 .. rho_K`` of a residual sequence along the track, truncated where it stops carrying
    signal: Geyer's initial positive sequence (Geyer 1992, *Practical Markov chain Monte Carlo*, Statist. Sci. 7,
    §3.3): with ``Gamma_m = rho_2m + rho_2m+1`` (``rho_0 = 1``) the lags from the first ``m`` with ``Gamma_m <= 0`` on
    are set to zero. Missing samples (NaN) keep their place (lags are along the track) and are left out of the sums:
    ``rho_k = sum_i r_i r_i+k / n_k / (sum_i r_i^2 / n)`` over the ``n_k`` valid pairs, ``r`` centred. ``K =
    min(max_lag, n / 4)``; returns an empty array for fewer than 8 valid samples."""
    r = np.asarray(res, float).ravel()
    ok = np.isfinite(r)
    n = int(ok.sum())
    K = int(min(max_lag, n // 4))
    if n < 8 or K < 1:
        return np.zeros(0)
    z = np.where(ok, r - r[ok].mean(), 0.0)
    c0 = float(z @ z) / n
    if not c0 > 0:
        return np.zeros(0)
    m = ok.astype(float)
    rho = np.array([float(z[:-k] @ z[k:]) / max(float(m[:-k] @ m[k:]), 1.0) / c0 for k in range(1, K + 1)])
    full = np.concatenate([[1.0], rho])  # full[k] = rho_k
    for mm in range(1, (K + 1) // 2 + 1):  # Gamma_0 = 1 + rho_1 > 0 always
        if full[2 * mm : 2 * mm + 2].sum() <= 0:
            rho[2 * mm - 1 :] = 0.0  # lags >= 2 mm
            break
    return rho


def effective_sample_size(res, max_lag: int = 50) -> float:
    """Effective number of independent samples of a residual sequence along the track,
    ``n_eff = n / (1 + 2 sum_k rho_k)`` (the integrated autocorrelation time; e.g. Kass et al. 1998; Geyer 1992), with
    ``rho_k`` from :func:`residual_autocorrelation`; between 2 and ``n`` (``n`` the valid samples; a negatively
    correlated sequence is not credited with more than ``n``). For an AR(1) series ``rho_k = rho^k`` it is
    ``n (1 - rho) / (1 + rho)``; for white noise ``n``."""
    r = np.asarray(res, float).ravel()
    n = int(np.isfinite(r).sum())
    if n < 8:
        return float(max(n, 1))
    rho = residual_autocorrelation(r, max_lag)
    tau = 1.0 + 2.0 * float(rho.sum())
    return float(min(max(n / max(tau, 1e-9), 2.0), n))


def _n_eff(res: np.ndarray, model: str = "ar1", max_lag: int = 50) -> float:
    """Effective sample size of the residuals under the noise model (:class:`PosteriorNoiseOptions`)."""
    return effective_sample_size(res, max_lag) if model == "acf" else _n_eff_ar1(res)


def _hac_meat(J: np.ndarray, ok: np.ndarray, rho: np.ndarray) -> np.ndarray:
    """``J^T R J`` for the residual correlation ``R_ij = rho_|i-j|`` (``rho_0 = 1``, lags along the track, samples
    outside ``ok`` left out): the middle of the HAC sandwich (Newey & West 1987, with the truncated sample
    autocorrelation as the weights)."""
    Jz = np.where(ok[:, None], J, 0.0)
    M = Jz.T @ Jz
    for k, rk in enumerate(rho, start=1):
        if rk != 0 and k < Jz.shape[0]:
            X = Jz[:-k].T @ Jz[k:]
            M += rk * (X + X.T)
    return M


def _pose_jacobian(gx: np.ndarray, gy: np.ndarray, rq: np.ndarray, f: float, B: np.ndarray | None) -> np.ndarray:
    """(N, 4 [+ 2K]) derivatives of the map depth at the track points with respect to start x, start y, heading
    (per degree), scale and, with the drift basis ``B``, the K (east, north) drift rates (interleaved), from the
    map gradient ``gx``, ``gy`` at the points and the rotated track ``rq``."""
    J = np.zeros((gx.size, 4 + (2 * B.shape[1] if B is not None else 0)))
    J[:, 0], J[:, 1] = gx, gy
    dq_da = np.column_stack([rq[:, 1], -rq[:, 0]]) * f * (np.pi / 180.0)
    J[:, 2] = gx * dq_da[:, 0] + gy * dq_da[:, 1]
    J[:, 3] = gx * rq[:, 0] + gy * rq[:, 1]
    if B is not None:
        J[:, 4::2] = gx[:, None] * B
        J[:, 5::2] = gy[:, None] * B
    return J


def _track_regression(g: MapGrid, d: np.ndarray, rel: np.ndarray, pose, start_xy, drift_xy, B, gamma: float,
                      drift_ridge: float, free_heading: bool, free_scale: bool):
    """The fit at the fix as a linear regression for :func:`_fit_dof_inflation` and :func:`_position_variance_ratio`:
    the Jacobian ``J`` (start x, start y, the free heading/scale, the drift rates with ``B``, the bias; zero rows for
    samples without a map depth, which keeps the along-track lags of the others), ``R J`` for the AR(1) correlation
    ``R_ij = rho^|i - j|`` of ``gamma = (1 - rho) / (1 + rho)``, the ridge (the drift prior), the valid samples and
    the number of parameters; None when too few samples are valid."""
    from scipy.signal import lfilter

    a, f = pose
    rq = _rotate(rel, a)
    q = rq * f + np.asarray(start_xy, float) + (0.0 if drift_xy is None else drift_xy)
    z, gx, gy = _bilinear_with_gradient(g, q[:, 0], q[:, 1])
    ok = np.isfinite(z) & np.isfinite(gx) & np.isfinite(gy) & np.isfinite(d)
    n = int(ok.sum())
    keep = [True, True, free_heading, free_scale] + [True] * (2 * B.shape[1] if B is not None else 0)
    J = np.column_stack([_pose_jacobian(gx, gy, rq, f, B)[:, keep], np.ones(d.size)])  # + the bias
    lam = np.array([0.0] * int(sum(keep[:4])) + [drift_ridge] * (len(keep) - 4) + [0.0])
    if n <= J.shape[1] + 1:
        return None
    J = np.where(ok[:, None], J, 0.0)
    gg = min(max(gamma, 1e-3), 1.0)
    rho = (1.0 - gg) / (1.0 + gg)
    # R J without forming R: causal + anti-causal AR(1) filters minus the diagonal
    RJ = lfilter([1.0], [1.0, -rho], J, axis=0) + lfilter([1.0], [1.0, -rho], J[::-1], axis=0)[::-1] - J
    return J, RJ, lam, n, N_PARAMS + len(keep) - 4


def _fit_dof_inflation(g: MapGrid, d: np.ndarray, rel: np.ndarray, pose, start_xy, drift_xy, B, gamma: float,
                       drift_ridge: float, free_heading: bool, free_scale: bool) -> float:
    """Widening ``(N_v - p) / (N_v - tr(P R))`` of the noise variance for residuals correlated along the track.

    The likelihood divides the residual sum of squares by ``N_v - p`` (``p`` fitted parameters: x, y, heading,
    scale, bias, plus the ``2K`` drift rates when the drift is applied), its expectation for independent noise.
    For noise with correlation matrix ``R`` the expectation is ``s^2 tr((I - P) R) = s^2 (N_v - tr(P R))`` with ``P``
    the fit's hat matrix (here the Jacobian ``J`` of the pose, bias and drift at the fix, bilinear map gradients;
    the drift rates with their Gaussian prior as a ridge, ``P = J (J^T J + L)^-1 J^T``) and ``R`` the AR(1)
    correlation ``rho^|i - j|`` of the effective sample size ``gamma = (1 - rho) / (1 + rho)``. Regressors that vary
    slowly along the track (a smooth terrain) absorb up to ``p / gamma`` samples' worth of noise, rough ones about
    ``p``. Never below 1 (the likelihood's estimate is kept as the lower bound); the divisor kept
    ``>= min(N_v - p, N_v / 4)``."""
    reg = _track_regression(g, d, rel, pose, start_xy, drift_xy, B, gamma, drift_ridge, free_heading, free_scale)
    if reg is None:
        return 1.0
    J, RJ, lam, n, p_used = reg
    A = J.T @ J + np.diag(lam)
    try:
        tr_pr = float(np.trace(np.linalg.solve(A, J.T @ RJ)))
    except np.linalg.LinAlgError:
        return 1.0
    return float(max(max(n - p_used, 1.0) / max(n - tr_pr, min(n - p_used, n / 4.0), 1.0), 1.0))


def _position_variance_ratio(g: MapGrid, d: np.ndarray, rel: np.ndarray, pose, start_xy, drift_xy, gamma: float,
                             free_heading: bool, free_scale: bool) -> float:
    """``gamma tr[(H^-1 J^T R J H^-1)_xy] / tr[(H^-1)_xy]`` (module docstring, *sandwich*): the start position's
    least-squares variance under AR(1) residuals of ``gamma`` (White sandwich, ``H = J^T J`` of the rigid pose and
    the bias at the fix) over the variance the tempered likelihood gives it (``H^-1 / gamma``); in ``(0, 1]``,
    1 when the fit is degenerate."""
    reg = _track_regression(g, d, rel, pose, start_xy, drift_xy, None, gamma, 0.0, free_heading, free_scale)
    if reg is None:
        return 1.0
    J, RJ, _, _, _ = reg
    try:
        Hi = np.linalg.inv(J.T @ J)
    except np.linalg.LinAlgError:
        return 1.0
    den = float(np.trace(Hi[:2, :2]))
    ratio = min(max(gamma, 1e-3), 1.0) * float(np.trace((Hi @ (J.T @ RJ) @ Hi)[:2, :2])) / den if den > 0 else 1.0
    return float(min(ratio, 1.0)) if np.isfinite(ratio) and ratio > 0 else 1.0


def _s2_from(msd: float, nv: float, floor2: float) -> float:
    dof = max(nv - N_PARAMS, 1.0)
    return float(max(msd * nv / dof, floor2))


def _bilinear_residuals(g: MapGrid, d: np.ndarray, rel: np.ndarray, pose, offsets_xy: np.ndarray,
                        drift_xy: np.ndarray | None = None) -> np.ndarray:
    """(M, N) map depth minus measured depth with the start at each of ``offsets_xy`` (M, 2), NaN where no map."""
    a, f = pose
    q = _rotate(rel, a) * f
    if drift_xy is not None:
        q = q + drift_xy
    return g.sample_bilinear(offsets_xy[:, :1] + q[None, :, 0], offsets_xy[:, 1:2] + q[None, :, 1]) - d[None, :]


def _msd_b(res: np.ndarray):
    """Bias-free MSD, valid count and bias per row of a residual matrix (NaN = missing)."""
    ok = np.isfinite(res)
    nv = ok.sum(axis=-1).astype(float)
    r = np.where(ok, res, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        b = r.sum(axis=-1) / nv
        msd = np.maximum((r * r).sum(axis=-1) / nv - b * b, 0.0)
    return np.where(nv > 0, msd, np.nan), nv, b


def _bilinear_with_gradient(g: MapGrid, x_m: np.ndarray, y_m: np.ndarray):
    """Bilinear depth and its gradient (dz/dx, dz/dy per metre) at map points; NaN outside or next to holes."""
    c, r = g.col_of(x_m), g.row_of(y_m)
    ny, nx = g.shape
    z = np.full(c.shape, np.nan)
    gx = np.full(c.shape, np.nan)
    gy = np.full(c.shape, np.nan)
    ok = (c >= 0) & (c <= nx - 1) & (r >= 0) & (r <= ny - 1)
    c0 = np.clip(np.floor(c[ok]).astype(int), 0, nx - 2)
    r0 = np.clip(np.floor(r[ok]).astype(int), 0, ny - 2)
    fc, fr = c[ok] - c0, r[ok] - r0
    Z = g.depth_m
    z00, z01, z10, z11 = Z[r0, c0], Z[r0, c0 + 1], Z[r0 + 1, c0], Z[r0 + 1, c0 + 1]
    z[ok] = z00 * (1 - fc) * (1 - fr) + z01 * fc * (1 - fr) + z10 * (1 - fc) * fr + z11 * fc * fr
    gx[ok] = ((z01 - z00) * (1 - fr) + (z11 - z10) * fr) / g.resolution_m
    gy[ok] = ((z10 - z00) * (1 - fc) + (z11 - z01) * fc) / g.resolution_m
    return z, gx, gy


def _holes_mass_outside(msd_all, n_all, n_hole_all, N: int, s2: float, v_map: float, gamma: float, n_min: float,
                        fix_cr: tuple[float, float], R: float) -> float:
    """Posterior mass more than ``R`` cells from the fix (column, row) when every sample over an interior hole is
    scored like the valid ones at its offset: its squared residual is the unbiased residual variance of the
    valid samples, ``nv MSD / (nv - 5)``; offsets with fewer than ``n_min`` valid samples stay impossible (they
    would be flagged off the map)."""
    P, ny, nx = msd_all.shape
    lls = []
    for k in range(P):
        nv = n_all[k].astype(float)
        nh = n_hole_all[k].astype(float)
        with np.errstate(invalid="ignore", divide="ignore"):
            m = msd_all[k].astype(float)
            var = m * nv / np.maximum(nv - N_PARAMS, 1.0)
            msd_h = (nv * m + nh * var) / np.maximum(nv + nh, 1.0)
        ok = np.isfinite(msd_h) & (nv >= n_min)
        lls.append(np.where(ok, _loglik(msd_h, nv + nh, N, s2, v_map, gamma), -np.inf))
    top = max(float(x.max()) for x in lls)
    if not np.isfinite(top):
        return 0.0
    pc = np.zeros((ny, nx))
    for x in lls:
        pc += np.exp(x - top)
    yy, xx = np.mgrid[0:ny, 0:nx]
    near = (xx - fix_cr[0]) ** 2 + (yy - fix_cr[1]) ** 2 <= R * R + 1e-9
    tot = float(pc.sum())
    return float(1.0 - pc[near].sum() / tot) if tot > 0 else 0.0


def _drift_basis(tau: np.ndarray, segment: float) -> tuple[np.ndarray, np.ndarray]:
    """(N, K) time (or distance) spent in each drift segment before each sample, and the K+1 segment edges.

    The drift ``w(tau) = sum_k B_k(tau) u_k`` is continuous, zero at the first sample, piecewise linear with a
    constant rate ``u_k`` (velocity bias) in each segment of length ``segment`` (the last one absorbs a remainder
    shorter than half a segment)."""
    t = tau - tau[0]
    total = float(t[-1])
    k = max(int(round(total / segment)), 1) if segment > 0 and total > 0 else 1
    edges = np.linspace(0.0, total, k + 1) if total > 0 else np.array([0.0, 1.0])
    B = np.clip(t[:, None] - edges[None, :-1], 0.0, np.diff(edges)[None, :])
    return B, edges


@dataclass
class _JointModel:
    """Objective of the joint drift fit: the data, the drift basis ``B`` (N, K), the Gaussian prior (precisions
    ``prior`` about ``centre``, over x, y, heading, scale and the ``2K`` rates) and the tempered likelihood."""

    g: MapGrid
    d: np.ndarray
    rel: np.ndarray
    B: np.ndarray
    prior: np.ndarray
    centre: np.ndarray
    s2: float
    gamma: float
    v_map: float
    n_req: int

    @property
    def n_par(self) -> int:
        return 4 + 2 * self.B.shape[1]

    def unpack(self, th):
        return th[0], th[1], th[2], th[3], th[4:].reshape(self.B.shape[1], 2)


def _joint_prior(K: int, sigma_u: float, sigma_heading_deg: float | None, sigma_scale: float | None):
    """Precisions and centre of the joint fit's Gaussian prior: the rates ``N(0, sigma_u^2)``, the heading and the
    scale (about 1) only when their sigmas are given."""
    n_par = 4 + 2 * K
    prior = np.zeros(n_par)
    prior[4:] = 1.0 / sigma_u ** 2
    if sigma_heading_deg:
        prior[2] = 1.0 / sigma_heading_deg ** 2
    if sigma_scale:
        prior[3] = 1.0 / sigma_scale ** 2
    centre = np.zeros(n_par)
    centre[3] = 1.0
    return prior, centre


def _joint_evaluate(m: _JointModel, th: np.ndarray, jac: bool):
    """Log-posterior of ``th`` (bias profiled out), and with ``jac`` the centred Jacobian of the residuals and the
    centred residuals (analytic bilinear gradient); ``-inf`` with too few valid samples."""
    N, B, n_par = m.d.size, m.B, m.n_par
    x0, y0, a, f, U = m.unpack(th)
    rq = _rotate(m.rel, a)
    q = rq * f + np.array([x0, y0]) + B @ U
    z, gx, gy = _bilinear_with_gradient(m.g, q[:, 0], q[:, 1])
    r = z - m.d
    ok = np.isfinite(r) & np.isfinite(gx) & np.isfinite(gy)
    nv = int(ok.sum())
    if nv < max(m.n_req, n_par // 2 + 3):
        return -np.inf, None, None, ok
    rc = r[ok] - r[ok].mean()
    msd = float(rc @ rc) / nv
    ll = float(_loglik(np.array([msd]), np.array([float(nv)]), N, m.s2, m.v_map, m.gamma)[0])
    ll -= 0.5 * float(np.sum(m.prior * (th - m.centre) ** 2))
    if not jac:
        return ll, None, None, ok
    J = _pose_jacobian(gx[ok], gy[ok], rq[ok], f, B[ok])
    J -= J.mean(axis=0)  # the bias is profiled out: centred residuals and Jacobian
    return ll, J, rc, ok


def _joint_lm(m: _JointModel, th, ll, J, rc, free, bounds_a, bounds_f, max_iter: int):
    """Levenberg-Marquardt ascent of the joint log-posterior from ``th`` (heading and scale clipped to their
    bounds, only the ``free`` parameters moved); the optimum, its log-posterior, Jacobian, residuals, iterations."""
    n_par = m.n_par
    lam, n_it = 1e-3, 0
    w = m.gamma / m.s2
    for _ in range(max_iter):
        n_it += 1
        A = w * (J.T @ J) + np.diag(m.prior)
        gvec = w * (J.T @ rc) + m.prior * (th - m.centre)
        Af = A[np.ix_(free, free)]
        step = np.zeros(n_par)
        improved = False
        for _ in range(12):
            M = Af + lam * np.diag(np.diag(Af)) + 1e-12 * np.trace(Af) * np.eye(Af.shape[0])
            try:
                step[free] = -np.linalg.solve(M, gvec[free])
            except np.linalg.LinAlgError:
                lam *= 10
                continue
            cand = th + step
            cand[2] = np.clip(cand[2], *bounds_a)
            cand[3] = np.clip(cand[3], *bounds_f)
            ll_c, J_c, rc_c, _ = _joint_evaluate(m, cand, True)
            if np.isfinite(ll_c) and ll_c > ll:
                gain = ll_c - ll
                th, ll, J, rc = cand, ll_c, J_c, rc_c
                lam = max(lam / 3, 1e-9)
                improved = True
                break
            lam *= 4
        if not improved or gain < 1e-6:
            break
    return th, ll, J, n_it


def _joint_drift_fit(g: MapGrid, d, rel, B, sigma_u: float, p0, bounds_a, bounds_f, s2: float, gamma: float,
                     v_map: float, n_req: int, max_iter: int = 40, sigma_heading_deg: float | None = None,
                     sigma_scale: float | None = None) -> dict:
    """Levenberg-Marquardt MAP of start x/y, heading, scale and the drift rates under the (tempered) likelihood of
    the module docstring plus the Gaussian drift prior; Laplace covariance of the start with and without drift."""
    K = B.shape[1]
    prior, centre = _joint_prior(K, sigma_u, sigma_heading_deg, sigma_scale)
    m = _JointModel(g, d, rel, B, prior, centre, s2, gamma, v_map, n_req)
    n_par = m.n_par
    th = np.concatenate([np.asarray(p0, float), np.zeros(2 * K)])
    free = np.ones(n_par, bool)
    free[2] = bounds_a[1] > bounds_a[0]
    free[3] = bounds_f[1] > bounds_f[0]
    ll0, J, rc, _ = _joint_evaluate(m, th, True)
    if not np.isfinite(ll0):
        return {"ok": False}
    th, ll, J, n_it = _joint_lm(m, th, ll0, J, rc, free, bounds_a, bounds_f, max_iter)
    A = (gamma / s2) * (J.T @ J) + np.diag(prior)
    Af = A[np.ix_(free, free)]
    try:
        cov_joint = np.linalg.pinv(Af, hermitian=True)[:2, :2]
        nr = int(free[:4].sum())
        cov_rigid = np.linalg.pinv(Af[:nr, :nr], hermitian=True)[:2, :2]
    except np.linalg.LinAlgError:
        return {"ok": False}
    ev, V = np.linalg.eigh(0.5 * ((cov_joint - cov_rigid) + (cov_joint - cov_rigid).T))
    infl = (V * np.maximum(ev, 0.0)) @ V.T
    x0, y0, a, f, U = m.unpack(th)
    return {"ok": True, "x": float(x0), "y": float(y0), "a": float(a), "f": float(f), "U": U, "ll": ll, "ll0": ll0,
            "iterations": n_it, "cov_joint": cov_joint, "cov_rigid": cov_rigid, "inflation": infl}


# ------------------------------------------------------------------ the steps of posterior_fix
_Pose = tuple[float, float, float, float]  # start x, start y (map metres), heading error (deg), track scale


@dataclass
class _Problem:
    """The validated inputs of :func:`posterior_fix`: the map (and its uncertainty layer) cropped to the search
    region plus the track's footprint, the search region in the crop's cells, the pose grid."""

    d: np.ndarray  # (N,) measured depths
    t: np.ndarray  # (N, 2) dead-reckoned track
    rel: np.ndarray  # (N, 2) track relative to its first sample
    g: MapGrid
    unc: MapGrid | None
    window: tuple[int, int, int, int]  # search region r0, r1, c0, c1 (cells of ``g``)
    headings: list[float]
    scale_list: list[float]
    fine_scale_list: list[float]
    poses: list[tuple[float, float]]  # coarse (heading, scale) grid
    n: int  # samples
    h: float  # cell size (m)
    v_map: float  # map depth variance over the search region (the score of a sample without a map depth)
    n_req: int  # fewest valid samples of a feasible offset
    floor2: float  # numeric floor of the noise variance
    corr_model: str = "hac"  # PosteriorNoiseOptions.correlation_model
    tempering: str = "ar1"  # the effective sample size tempering the likelihood: 'acf' or 'ar1'
    max_lag: int = 50  # PosteriorNoiseOptions.correlation_max_lag


@dataclass
class _Limits:
    """The thresholds of the mismatch flags (:func:`posterior_fix` parameters)."""

    min_samples: int
    min_valid_for_fix: float
    min_valid_at_fix: float
    min_relief_to_noise: float
    max_mass_outside: float
    max_mass_outside_holes: float
    mode_radius_cells: float


@dataclass
class _Coarse:
    """Coarse surfaces [TERCOM Eq. 17] per pose: snapped track cells, bias-free MSD, valid and interior-hole counts."""

    snapped: list[tuple[np.ndarray, np.ndarray]]
    msd_all: np.ndarray  # (P, ny, nx) float32, NaN where infeasible
    n_all: np.ndarray  # (P, ny, nx) valid samples (0 where infeasible)
    n_hole_all: np.ndarray | None  # (P, ny, nx) samples over interior holes; None when the map has none


@dataclass
class _CoarsePosterior:
    """Noise variance and tempering at the coarse MAP, the coarse log-likelihoods and the posterior over cells."""

    s2: float
    gamma: float
    ll: np.ndarray  # (P, ny, nx) float32 log-likelihoods
    pc: np.ndarray  # (ny, nx) posterior over start cells
    kp: int  # pose of the coarse MAP (last noise pass)
    rc: int  # flat cell of the coarse MAP (last noise pass)


@dataclass
class _Window:
    """A fine window about a coarse mode: its cell, plausible poses, start offsets and their bilinear MSD."""

    rc: tuple[int, int]
    poses: list[tuple[float, float]]
    offs: np.ndarray  # (M, 2) start offsets (map metres)
    msd: np.ndarray  # (len(poses), M) bias-free MSD, NaN where infeasible
    nv: np.ndarray  # valid samples (0 where infeasible)
    bias: np.ndarray


@dataclass
class _GridMap:
    """Window masses and the fine grid's MAP."""

    mw: np.ndarray  # posterior mass of each window
    out_mask: np.ndarray  # cells outside every window
    m_out_coarse: float  # coarse mass outside the windows
    best_w: int
    pose: _Pose
    ll_grid: float


@dataclass
class _DriftStep:
    """The joint drift step: the fix (moved when the drift is applied), the drift along the track, the Laplace
    inflation of the start covariance, ``refinement.drift``, the drift model and its basis and prior."""

    pose: _Pose
    drift_xy: np.ndarray
    inflation: np.ndarray
    info: dict
    model: tuple | None = None
    B: np.ndarray | None = None
    sigma: float = 0.0


def _prepare_inputs(profile_depth, track_xy, dtm, headings_deg, scales, fine_scales, uncertainty, region,
                    mode_radius_cells: float, min_valid_fraction: float) -> _Problem:
    """Validated profile, track, pose grid and map (cropped, :func:`_crop_to_footprint`); :class:`InputError` on
    inconsistent inputs."""
    d, t = _validate_inputs(profile_depth, track_xy)
    import xarray as xr

    if uncertainty is None and isinstance(dtm, xr.Dataset) and "uncertainty_m" in dtm:
        uncertainty = np.asarray(dtm["uncertainty_m"].transpose("y", "x").values, float)
    g = MapGrid.from_any(dtm)
    h = g.resolution_m
    N = d.size
    headings = [float(a) for a in headings_deg] or [0.0]
    scale_list = [float(f) for f in scales] or [1.0]
    fine_scale_list = sorted({*scale_list, *(float(f) for f in (fine_scales if fine_scales is not None else ()))})
    if min(fine_scale_list) <= 0:
        raise InputError(f"track scale factors must be > 0, got {fine_scale_list}")
    poses = [(a, f) for a in headings for f in scale_list]
    unc = None
    if uncertainty is not None:
        u = uncertainty.depth_m if isinstance(uncertainty, MapGrid) else np.asarray(
            getattr(uncertainty, "values", uncertainty), float)
        if u.shape != g.shape:
            raise InputError(f"uncertainty layer shape {u.shape} does not match the map {g.shape}")
        unc = MapGrid(np.where(np.isfinite(u), u, np.nan), g.x_m, g.y_m, h)

    rel = t - t[0]
    g, unc, window = _crop_to_footprint(g, unc, rel, headings, fine_scale_list, region, mode_radius_cells)
    if not np.isfinite(g.depth_m).any():
        raise InputError("the search region and the track's footprint hold no valid map cell")
    r0, r1, c0, c1 = window
    zr = g.depth_m[r0:r1, c0:c1]
    v_map = float(np.nanvar(zr)) if np.isfinite(zr).sum() > 1 else 0.0
    n_req = _required_samples(min_valid_fraction, N)
    # numeric floor of the noise: tiny against the profile's spread (a flat, noise-free map stays flat)
    floor2 = max((1e-3 * float(np.std(d))) ** 2, 1e-6)
    return _Problem(d, t, rel, g, unc, window, headings, scale_list, fine_scale_list, poses, N, h, v_map, n_req,
                    floor2)


def _crop_to_footprint(g: MapGrid, unc: MapGrid | None, rel: np.ndarray, headings: list[float],
                       fine_scale_list: list[float], region, mode_radius_cells: float):
    """The map and uncertainty layer cropped to the search region plus the track's footprint (every heading x
    scale, plus a margin for the fine windows and the drift), and the search region ``(r0, r1, c0, c1)`` in the
    crop's cells: the FFTs and the per-pose surfaces then cost the region, not the map."""
    h = g.resolution_m
    ny, nx = g.shape
    r0, r1, c0, c1 = g.region_window(region)
    ext = np.array([_rotate(rel, a) * f for a in headings for f in fine_scale_list])  # (P', N, 2)
    margin = int(np.ceil(mode_radius_cells)) + 8
    cr0 = max(r0 + int(np.floor(ext[..., 1].min() / h)) - margin, 0)
    cr1 = min(r1 + int(np.ceil(ext[..., 1].max() / h)) + margin, ny)
    cc0 = max(c0 + int(np.floor(ext[..., 0].min() / h)) - margin, 0)
    cc1 = min(c1 + int(np.ceil(ext[..., 0].max() / h)) + margin, nx)
    del ext
    if (cr0, cr1, cc0, cc1) != (0, ny, 0, nx):
        g = MapGrid(np.ascontiguousarray(g.depth_m[cr0:cr1, cc0:cc1]), g.x_m[cc0:cc1], g.y_m[cr0:cr1], h)
        if unc is not None:
            unc = MapGrid(np.ascontiguousarray(unc.depth_m[cr0:cr1, cc0:cc1]), g.x_m, g.y_m, h)
        r0, r1, c0, c1 = r0 - cr0, r1 - cr0, c0 - cc0, c1 - cc0
    return g, unc, (r0, r1, c0, c1)


def _coarse_surfaces(pb: _Problem, min_valid_fraction: float) -> _Coarse:
    """Coarse MSD surfaces [TERCOM Eq. 17] of every start cell for every pose (FFT route, nearest-cell sampling),
    restricted to the search region and the feasible offsets, and the per-pose interior-hole counts."""
    g, N = pb.g, pb.n
    ny, nx = g.shape
    r0, r1, c0, c1 = pb.window
    V = np.isfinite(g.depth_m)
    ref = float(np.nanmean(g.depth_m))
    D = np.where(V, g.depth_m - ref, 0.0)
    dc = pb.d - ref
    in_region = np.zeros((ny, nx), bool)
    in_region[r0:r1, c0:c1] = True

    snapped = [_snap(_rotate(pb.rel, a) * f, pb.h) for a, f in pb.poses]
    rmin = min(int(r.min()) for r, _ in snapped)
    rmax = max(int(r.max()) for r, _ in snapped)
    cmin = min(int(c.min()) for _, c in snapped)
    cmax = max(int(c.max()) for _, c in snapped)
    pad_lo, pad_hi = (max(0, -rmin), max(0, -cmin)), (max(0, rmax), max(0, cmax))
    corr = _FFTCorrelator({"V": V.astype(float), "D": D, "D2": D * D}, pad_lo, pad_hi)
    P = len(pb.poses)
    msd_all = np.full((P, ny, nx), np.nan, np.float32)
    n_all = np.zeros((P, ny, nx), np.uint16 if N < 65535 else np.uint32)
    for k, (rows, cols) in enumerate(snapped):
        n, s_r, s_r2, _ = _sums_all_offsets(corr, rows, cols, dc, False)
        feas = (n >= pb.n_req) & in_region
        with np.errstate(invalid="ignore", divide="ignore"):
            nn = np.where(feas, n, np.nan)
            b = s_r / nn
            msd = np.maximum(s_r2 / nn - b * b, 0.0)
        msd_all[k] = msd
        n_all[k] = np.where(feas, n, 0)
    n_hole_all = _interior_hole_counts(V, snapped, pad_lo, pad_hi, N)
    if not np.isfinite(msd_all).any():
        raise InputError(f"no feasible offset: the {N}-sample track does not fit on valid cells of the {ny} x {nx} "
                         f"map with min_valid_fraction={min_valid_fraction}")
    return _Coarse(snapped, msd_all, n_all, n_hole_all)


def _interior_hole_counts(V: np.ndarray, snapped, pad_lo, pad_hi, N: int) -> np.ndarray | None:
    """(P, ny, nx) samples over interior holes of the (cropped) map for each pose and start cell, for the holes
    test; None when there are none. Interior holes are empty cells not connected to the map's border (those are
    outside the map's coverage, e.g. the edges of a projected grid, and stay "off the map")."""
    lab, n_lab = ndimage.label(~V)
    edge_labels = np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]]))
    interior = (lab > 0) & ~np.isin(lab, edge_labels)
    if not interior.any():
        return None
    corr_h = _FFTCorrelator({"H": interior.astype(float)}, pad_lo, pad_hi)
    n_hole_all = np.zeros((len(snapped), *V.shape), np.int32)
    for k, (rows, cols) in enumerate(snapped):
        rmin_k, cmin_k = int(rows.min()), int(cols.min())
        (fc,) = corr_h.masks_fft(rows - rmin_k, cols - cmin_k, [np.ones(N)])
        n_hole_all[k] = np.rint(corr_h.inverse([corr_h.F["H"] * fc], rmin_k, cmin_k)[0]).astype(np.int32)
    return n_hole_all


def _map_sigma2_at(unc: MapGrid | None, xy: np.ndarray) -> float:
    """Mean variance of the bilinearly interpolated map along the track points ``xy`` from the per-cell standard
    uncertainty ``u`` (independent cell errors: ``sum_k w_k^2 u_k^2`` over the four cells of weights ``w_k``, between
    1/4 and 1 of a cell's ``u^2``); 0 without an uncertainty layer."""
    if unc is None:
        return 0.0
    c, r = unc.col_of(xy[:, 0]), unc.row_of(xy[:, 1])
    ny, nx = unc.shape
    ok = (c >= 0) & (c <= nx - 1) & (r >= 0) & (r <= ny - 1)
    if nx < 2 or ny < 2 or not ok.any():
        return 0.0
    c0 = np.clip(np.floor(c[ok]).astype(int), 0, nx - 2)
    r0 = np.clip(np.floor(r[ok]).astype(int), 0, ny - 2)
    fc, fr = c[ok] - c0, r[ok] - r0
    U2 = unc.depth_m ** 2
    v = (U2[r0, c0] * ((1 - fc) * (1 - fr)) ** 2 + U2[r0, c0 + 1] * (fc * (1 - fr)) ** 2
         + U2[r0 + 1, c0] * ((1 - fc) * fr) ** 2 + U2[r0 + 1, c0 + 1] * (fc * fr) ** 2)
    v = v[np.isfinite(v)]
    return float(np.mean(v)) if v.size else 0.0


def _coarse_posterior(cs: _Coarse, N: int, s2: float, gamma: float, v_map: float, ll_all: np.ndarray):
    """Coarse log-likelihoods (into ``ll_all``, float32) and the posterior over start cells, marginalised over the
    poses; one pose at a time (float64 temporaries of one map, not of P maps)."""
    P, ny, nx = cs.msd_all.shape
    for k_ in range(P):
        ll_all[k_] = _loglik(cs.msd_all[k_], cs.n_all[k_], N, s2, v_map, gamma)
    m = float(ll_all.max())
    pc = np.zeros((ny, nx))
    for k_ in range(P):
        pc += np.exp(ll_all[k_].astype(np.float64) - m)
    return ll_all, pc / pc.sum()


def _coarse_residuals(pb: _Problem, cs: _Coarse, k: int, r: int, c: int) -> np.ndarray:
    """Map depth (nearest cell) minus measured depth along the track of pose ``k`` started at cell ``(r, c)``."""
    ny, nx = pb.g.shape
    rows, cols = cs.snapped[k]
    rr, cc = rows + r, cols + c
    out = np.full(pb.n, np.nan)
    ins = (rr >= 0) & (rr < ny) & (cc >= 0) & (cc < nx)
    out[ins] = pb.g.depth_m[rr[ins], cc[ins]] - pb.d[ins]
    return out


def _coarse_noise(pb: _Problem, cs: _Coarse) -> _CoarsePosterior:
    """Noise variance and effective sample size at the coarse MAP (two passes, started from the lowest MSD with
    >= 90 % valid samples, else with any), and the coarse posterior under them."""
    N = pb.n
    P, ny, nx = cs.msd_all.shape
    msd_all, n_all = cs.msd_all, cs.n_all
    best_full, best_any = (np.inf, -1), (np.inf, -1)  # lowest MSD with >= 90 % valid samples / with any (per pose)
    for k_ in range(P):
        mk = np.where(np.isfinite(msd_all[k_]), msd_all[k_], np.inf)
        j_ = int(np.argmin(np.where(n_all[k_] >= 0.9 * N, mk, np.inf)))
        if mk.flat[j_] < best_full[0] and n_all[k_].flat[j_] >= 0.9 * N:
            best_full = (float(mk.flat[j_]), k_ * ny * nx + j_)
        j_ = int(np.argmin(np.where(n_all[k_] > 0, mk, np.inf)))
        if mk.flat[j_] < best_any[0]:
            best_any = (float(mk.flat[j_]), k_ * ny * nx + j_)
    k0 = best_full[1] if best_full[1] >= 0 else best_any[1]
    s2 = _s2_from(float(msd_all.flat[k0]), float(n_all.flat[k0]), pb.floor2)
    gamma = 1.0
    ll_all = np.empty((P, ny, nx), np.float32)
    for _ in range(2):
        ll, pc = _coarse_posterior(cs, N, s2, gamma, pb.v_map, ll_all)
        kbest = int(np.argmax(ll))
        kp, rc = divmod(kbest, ny * nx)
        r_, c_ = divmod(rc, nx)
        res_c = _coarse_residuals(pb, cs, kp, r_, c_)
        gamma = _n_eff(res_c, pb.tempering, pb.max_lag) / max(np.isfinite(res_c).sum(), 1)
        s2 = _s2_from(float(msd_all[kp, r_, c_]), float(n_all[kp, r_, c_]), pb.floor2)
    ll, pc = _coarse_posterior(cs, N, s2, gamma, pb.v_map, ll_all)
    return _CoarsePosterior(s2, gamma, ll, pc, kp, rc)


def _coarse_modes(pc: np.ndarray, R: float, n_alt_modes: int):
    """Posterior mass within ``R`` cells of every cell, and the coarse modes (local maxima ``2 R`` apart, the main
    one and up to ``n_alt_modes`` holding more than 1e-4) ranked by it."""
    nx = pc.shape[1]
    Ri = int(np.ceil(R))
    yy, xx = np.mgrid[-Ri : Ri + 1, -Ri : Ri + 1]
    disk = (xx * xx + yy * yy) <= R * R + 1e-9
    mass_r = ndimage.convolve(pc, disk.astype(float), mode="constant", cval=0.0)
    peaks = (pc == ndimage.maximum_filter(pc, size=3, mode="constant", cval=0.0)) & (pc > 0)
    pf = np.flatnonzero(peaks)
    pf = pf[np.argsort(-mass_r.flat[pf], kind="stable")]
    centres: list[tuple[int, int]] = []
    for fi in pf:
        r_, c_ = divmod(int(fi), nx)
        if all((r_ - a) ** 2 + (c_ - b) ** 2 > (2 * R) ** 2 for a, b in centres):
            centres.append((r_, c_))
        if len(centres) >= 1 + n_alt_modes:
            break
    centres = [centres[0]] + [cc for cc in centres[1:] if mass_r[cc] > 1e-4]
    return mass_r, centres


def _fine_windows(pb: _Problem, ll: np.ndarray, centres: list[tuple[int, int]], R: float, fine_step_cells: float):
    """The fine windows about the coarse modes (bilinear likelihood on a sub-cell grid of start offsets x the
    plausible poses), the cells they cover, the fine step (m) and the number of offsets a side."""
    g, h = pb.g, pb.h
    ny, nx = g.shape
    r0, r1, c0, c1 = pb.window
    P = len(pb.poses)
    Ri = int(np.ceil(R))
    step = fine_step_cells * h
    nh = int(np.ceil(R / fine_step_cells))
    grid1 = np.arange(-nh, nh + 1) * step
    oxy = np.array(np.meshgrid(grid1, grid1)).reshape(2, -1).T  # (M, 2) offsets about the window centre
    win_mask = np.zeros((ny, nx), bool)
    windows = []
    for (rw, cw) in centres:
        llw = ll[:, max(rw - Ri, 0) : rw + Ri + 1, max(cw - Ri, 0) : cw + Ri + 1].reshape(P, -1).max(axis=1)
        # plausible coarse poses, each expanded with the fine scales (the coarse pose itself is kept)
        pk = list(dict.fromkeys(p_ for k in range(P) if llw[k] > llw.max() - 12.0
                                for p_ in [pb.poses[k]] + [(pb.poses[k][0], fs) for fs in pb.fine_scale_list]))
        xc, yc = float(g.x_m[cw]), float(g.y_m[rw])
        offs = oxy + np.array([xc, yc])
        inr = ((offs[:, 0] >= g.x_m[c0] - 1e-6) & (offs[:, 0] <= g.x_m[c1 - 1] + 1e-6)
               & (offs[:, 1] >= g.y_m[r0] - 1e-6) & (offs[:, 1] <= g.y_m[r1 - 1] + 1e-6))
        msd_w = np.full((len(pk), len(offs)), np.nan)
        nv_w = np.zeros((len(pk), len(offs)))
        b_w = np.zeros((len(pk), len(offs)))
        for j, pose in enumerate(pk):
            m, nv, b = _msd_b(_bilinear_residuals(g, pb.d, pb.rel, pose, offs))
            ok = (nv >= pb.n_req) & inr
            msd_w[j] = np.where(ok, m, np.nan)
            nv_w[j] = np.where(ok, nv, 0)
            b_w[j] = b
        windows.append(_Window((rw, cw), pk, offs, msd_w, nv_w, b_w))
        dd = (np.arange(ny)[:, None] - rw) ** 2 + (np.arange(nx)[None, :] - cw) ** 2
        win_mask |= dd <= R * R + 1e-9
    return windows, win_mask, step, len(grid1)


def _fine_ll(w: _Window, N: int, s2: float, gamma: float, v_map: float) -> np.ndarray:
    """(poses, offsets) log-likelihood of a fine window."""
    return _loglik(w.msd, w.nv, N, s2, v_map, gamma)


def _fine_noise(pb: _Problem, w0: _Window, s2: float, gamma: float) -> tuple[float, float]:
    """Fine noise variance and tempering at the fine MAP of the main window (two passes; floored by the map
    uncertainty along the track); the coarse ones when the window has no feasible point."""
    fl = w0.msd
    fin = np.isfinite(fl) & (w0.nv >= 0.9 * pb.n)
    if not fin.any():
        fin = np.isfinite(fl)
    if not fin.any():  # no feasible fine point (bilinear needs both neighbours): fall back to the coarse likelihood
        return s2, gamma
    jj = int(np.argmin(np.where(fin, fl, np.inf)))
    s2f = _s2_from(float(fl.flat[jj]), float(w0.nv.flat[jj]), pb.floor2)
    gammaf = gamma
    for _ in range(2):
        llf = _fine_ll(w0, pb.n, s2f, gammaf, pb.v_map)
        jj = int(np.argmax(llf))
        j, mo = divmod(jj, llf.shape[1])
        res_f = _bilinear_residuals(pb.g, pb.d, pb.rel, w0.poses[j], w0.offs[mo : mo + 1])[0]
        gammaf = _n_eff(res_f, pb.tempering, pb.max_lag) / max(np.isfinite(res_f).sum(), 1)
        xy_fix = _rotate(pb.rel, w0.poses[j][0]) * w0.poses[j][1] + w0.offs[mo]
        s2f = max(_s2_from(float(fl.flat[jj]), float(w0.nv.flat[jj]), pb.floor2),
                  _map_sigma2_at(pb.unc, xy_fix) + pb.floor2)
    return s2f, gammaf


def _grid_map(windows: list[_Window], lls: list[np.ndarray], cp: _CoarsePosterior, win_mask: np.ndarray,
              mass_r: np.ndarray, step: float, h: float) -> _GridMap:
    """The windows' share of the coarse mass redistributed by their fine mass (the coarse masses within the mode
    radius when no window has any), and the best point of the heaviest window."""
    top = max(float(x.max()) for x in lls)
    cell_frac = (step / h) ** 2
    F = np.array([float(np.exp(x - top).sum()) * cell_frac for x in lls])
    MW = float(cp.pc[win_mask].sum())
    if F.sum() > 0:
        mw = MW * F / F.sum()
    else:
        mw = np.array([float(mass_r[w.rc]) for w in windows])
    out_mask = ~win_mask
    m_out_coarse = float(cp.pc[out_mask].sum())
    best_w = int(np.argmax(mw))
    wb, llb = windows[best_w], lls[best_w]
    jj = int(np.argmax(llb))
    j, mo = divmod(jj, llb.shape[1])
    a_map, f_map = wb.poses[j]
    x_map, y_map = (float(v) for v in wb.offs[mo])
    return _GridMap(mw, out_mask, m_out_coarse, best_w, (x_map, y_map, a_map, f_map), float(llb.flat[jj]))


def _coarse_fix_loglik(cp: _CoarsePosterior, w0: _Window, ll0: np.ndarray, poses, n_side: int):
    """Pose index of the coarse fix (the main window's cell centre, its best coarse pose) and its fine
    log-likelihood, for the record (-inf when that pose is not in the window)."""
    rc_c = w0.rc
    centre_idx = (n_side * n_side) // 2
    kc = int(np.argmax(cp.ll[:, rc_c[0], rc_c[1]]))
    ll_coarse_pt = (float(ll0[w0.poses.index(poses[kc]), centre_idx]) if poses[kc] in w0.poses
                    else float("-inf"))
    return kc, ll_coarse_pt


def _polish_negll(p, pb: _Problem, box, s2: float, gamma: float) -> float:
    """Negative fine log-likelihood of pose ``p`` (x, y, heading, scale); inf outside ``box`` (the heading and
    scale bounds, the window centre and half-width) or with too few valid samples."""
    x0_, y0_, a_, f_ = p
    ha, fa, xc, yc, half = box
    if not (ha[0] <= a_ <= ha[1] and fa[0] <= f_ <= fa[1] and abs(x0_ - xc) <= half and abs(y0_ - yc) <= half):
        return np.inf
    m, nv, _ = _msd_b(_bilinear_residuals(pb.g, pb.d, pb.rel, (a_, f_), np.array([[x0_, y0_]])))
    if nv[0] < pb.n_req:
        return np.inf
    return -float(_loglik(m, nv, pb.n, s2, pb.v_map, gamma)[0])


def _polish_simplex(x0v: np.ndarray, step: float, ha, fa, n_headings: int, n_scales: int):
    """Initial Nelder-Mead simplex about ``x0v`` (a fine step in x/y, half the grid steps in heading and scale,
    reflected inside the bounds) over the free coordinates, and their indices."""
    da_ = max((ha[1] - ha[0]) / max(n_headings - 1, 1), 0.1) if ha[1] > ha[0] else 0.0
    df_ = max((fa[1] - fa[0]) / max(n_scales - 1, 1), 0.002) if fa[1] > fa[0] else 0.0
    simplex = [x0v.copy()]
    for i, st in enumerate((step, step, da_ / 2, df_ / 2)):
        v = x0v.copy()
        v[i] += st if st > 0 else 0.0
        if i >= 2 and st > 0 and not (ha if i == 2 else fa)[0] <= v[i] <= (ha if i == 2 else fa)[1]:
            v[i] = x0v[i] - st
        simplex.append(v)
    free = [0, 1] + ([2] if da_ > 0 else []) + ([3] if df_ > 0 else [])
    return np.array(simplex)[[0] + [i + 1 for i in free]][:, free], free


def _polish(pb: _Problem, wb: _Window, pose: _Pose, ll_grid: float, s2f: float, gammaf: float, R: float,
            step: float) -> tuple[_Pose, bool, float]:
    """Nelder-Mead polish of the grid MAP under the same likelihood (within the winning window and the pose
    bounds), kept only when it raises it; the pose, whether it was polished, the log-likelihood at the pose."""
    h = pb.h
    ha = (min(pb.headings), max(pb.headings))
    fa = (min(pb.fine_scale_list), max(pb.fine_scale_list))
    box = (ha, fa, float(pb.g.x_m[wb.rc[1]]), float(pb.g.y_m[wb.rc[0]]), R * h)
    polished = False
    if np.isfinite(ll_grid):
        from scipy.optimize import minimize

        x0v = np.array(pose)
        sim, free = _polish_simplex(x0v, step, ha, fa, len(pb.headings), len(pb.fine_scale_list))

        def negf(v):
            p = x0v.copy()
            p[free] = v
            return _polish_negll(p, pb, box, s2f, gammaf)

        with _warnings.catch_warnings(), np.errstate(all="ignore"):
            _warnings.simplefilter("ignore")
            o = minimize(negf, x0v[free], method="Nelder-Mead",
                         options={"initial_simplex": sim, "xatol": 0.02 * h, "fatol": 1e-3, "maxiter": 400})
        if np.isfinite(o.fun) and -o.fun > ll_grid + 1e-9:
            p = x0v.copy()
            p[free] = o.x
            x_map, y_map, a_map, f_map = (float(v) for v in p)
            pose = (x_map, y_map, a_map, f_map)
            polished = True
    return pose, polished, float(-_polish_negll(np.array(pose), pb, box, s2f, gammaf))


def _drift_coordinate(pb: _Problem, time_s, drift_segment: float | None, drift_sigma: float | None):
    """Along-track coordinate ``tau`` of the drift (the sample times when given, else the distance travelled), the
    segment length, the prior sigma of the rates and the unit."""
    tau = _tau_of(pb, time_s)
    if time_s is not None:
        return tau, (drift_segment or DRIFT_SEGMENT_S), (drift_sigma or DRIFT_VELOCITY_SIGMA_M_S), "s"
    return tau, (drift_segment or max(float(tau[-1]) / 3.0, pb.h)), (drift_sigma or 0.005), "m"


def _tau_of(pb: _Problem, time_s) -> np.ndarray:
    """Along-track coordinate of the drift and the random walk: the sample times (s) when given (validated), else the
    distance travelled along the dead-reckoned track (m)."""
    N = pb.n
    if time_s is not None:
        tau = np.asarray(time_s, float).ravel()
        if tau.size != N or not np.isfinite(tau).all() or (np.diff(tau) < 0).any():
            raise InputError(f"time_s must be {N} finite, non-decreasing sample times")
        return tau
    return np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(pb.rel, axis=0).T))])


def _joint_drift_passes(pb: _Problem, B: np.ndarray, sig: float, pose: _Pose, s2f: float, gammaf: float,
                        heading_sigma_deg: float | None, scale_sigma: float | None):
    """The joint drift fit with the noise variance and N_eff re-estimated from its own residuals (the rigid fit's
    residuals are correlated by the very drift modelled here): up to three passes, each from the rigid MAP, so the
    rigid MAP and the joint one are compared under the same likelihood. The last fit, its s^2 and tempering."""
    bnd_a = (min(pb.headings), max(pb.headings))
    bnd_f = (min(pb.fine_scale_list), max(pb.fine_scale_list))
    g, d, rel = pb.g, pb.d, pb.rel
    s2j, gj = s2f, gammaf
    for _ in range(3):
        jf = _joint_drift_fit(g, d, rel, B, sig, pose, bnd_a, bnd_f, s2j, gj, pb.v_map, pb.n_req,
                              sigma_heading_deg=heading_sigma_deg, sigma_scale=scale_sigma)
        if not jf["ok"]:
            break
        rj = _bilinear_residuals(g, d, rel, (jf["a"], jf["f"]), np.array([[jf["x"], jf["y"]]]), B @ jf["U"])[0]
        okj = np.isfinite(rj)
        if okj.sum() <= N_PARAMS + 2 * B.shape[1]:
            break
        rc_ = rj[okj] - rj[okj].mean()
        s2_new = max(float(rc_ @ rc_) / (okj.sum() - N_PARAMS - 2 * B.shape[1]), s2f * 0.25, pb.floor2)
        g_new = max(_n_eff(rj, pb.tempering, pb.max_lag) / okj.sum(), gammaf)
        if abs(s2_new - s2j) <= 0.02 * s2j and abs(g_new - gj) <= 0.02 * gj:
            break
        s2j, gj = s2_new, g_new
    return jf, s2j, gj


def _drift_step(pb: _Problem, pose: _Pose, ll_map: float, s2f: float, gammaf: float, drift: bool, time_s,
                drift_segment: float | None, drift_sigma: float | None, heading_sigma_deg: float | None,
                scale_sigma: float | None, min_samples: int) -> _DriftStep:
    """Joint dead-reckoning drift (piecewise-constant rate) with the pose: same likelihood + the drift prior; kept
    only when it raises that log-posterior (the rigid MAP is its zero-drift point)."""
    N = pb.n
    out = _DriftStep(pose, np.zeros((N, 2)), np.zeros((2, 2)), {"applied": False})
    if not (drift and np.isfinite(ll_map) and N >= max(2 * min_samples, 12)):
        return out
    tau, seg, sig, unit = _drift_coordinate(pb, time_s, drift_segment, drift_sigma)
    B, edges = _drift_basis(tau, seg)
    jf, s2j, gj = _joint_drift_passes(pb, B, sig, pose, s2f, gammaf, heading_sigma_deg, scale_sigma)
    out.info = {"applied": False, "segments": int(B.shape[1]), "segment_length": float(np.diff(edges)[0]),
                "unit": unit, "prior_sigma_rate": sig}
    out.B, out.sigma = B, sig
    if jf["ok"] and jf["ll"] > jf["ll0"] + 1e-9:  # same objective at the rigid MAP (zero drift)
        x_map, y_map = pose[0], pose[1]
        out.info.update({
            "applied": True, "log_posterior_rigid_map": jf["ll0"], "log_posterior_joint": jf["ll"],
            "noise_sigma_m": float(np.sqrt(s2j)), "tempering": float(gj),
            "comment": "both log-posteriors under the joint fit's likelihood (noise, N_eff from its residuals)",
            "iterations": jf["iterations"], "moved_start_m": float(np.hypot(jf["x"] - x_map, jf["y"] - y_map)),
            "rates": jf["U"].tolist(), "drift_at_end_m": (B @ jf["U"])[-1].tolist(),
            "covariance_inflation_m2": jf["inflation"].tolist()})
        out.pose = (jf["x"], jf["y"], jf["a"], jf["f"])
        out.drift_xy = B @ jf["U"]
        out.inflation = jf["inflation"]
        out.model = (float(tau[0]), edges, jf["U"], unit)
    return out


def _fix_residuals(pb: _Problem, cs: _Coarse, cp: _CoarsePosterior, dr: _DriftStep) -> tuple[int, float]:
    """Valid samples and depth bias at the fix (bilinear; the coarse residuals when bilinear is undefined there)."""
    x_map, y_map, a_map, f_map = dr.pose
    res_map = _bilinear_residuals(pb.g, pb.d, pb.rel, (a_map, f_map), np.array([[x_map, y_map]]), dr.drift_xy)[0]
    if not np.isfinite(res_map).any():  # bilinear undefined at the fix (holes): use the coarse residuals
        res_map = _coarse_residuals(pb, cs, cp.kp, *divmod(cp.rc, pb.g.shape[1]))
    okm = np.isfinite(res_map)
    n_valid = int(okm.sum())
    bias = float(np.mean(res_map[okm])) if n_valid else float("nan")
    return n_valid, bias


def _main_mode_widening(pb: _Problem, dr: _DriftStep, s2f: float, gammaf: float) -> tuple[float, float, float]:
    """Widening ``kappa`` of the main window's second moment, the noise-dof inflation (:func:`_fit_dof_inflation`)
    and the sandwich ratio (:func:`_position_variance_ratio`).

    With the drift modelled, the main mode's width is that of the joint likelihood (its noise and N_eff), the
    rigid grid's (tempered by the drift-correlated residuals) rescaled by the ratio of the two precisions. The
    likelihood's noise variance divides the residuals by N_v - p; with correlated residuals the fit absorbed more
    of the noise: the main mode's width (and the drift's share) is widened by the ratio, the MAP, window masses and
    flags stay those of the likelihood. The sandwich ratio rescales the main window's second moment to the
    position variance under the correlated residuals (module docstring)."""
    x_map, y_map, a_map, f_map = dr.pose
    info = dr.info
    kappa = (float(np.clip((gammaf / s2f) / (info["tempering"] / info["noise_sigma_m"] ** 2), 0.1, 1.0))
             if info.get("applied") else 1.0)
    free_a = min(pb.headings) < max(pb.headings)
    free_f = min(pb.fine_scale_list) < max(pb.fine_scale_list)
    gamma_used = float(info["tempering"]) if info.get("applied") else float(gammaf)  # the tempering of the MAP fit
    if info.get("applied"):
        dof_inflation = _fit_dof_inflation(
            pb.g, pb.d, pb.rel, (a_map, f_map), (x_map, y_map), dr.drift_xy, dr.B, gamma_used,
            float(info["noise_sigma_m"]) ** 2 / (gamma_used * dr.sigma * dr.sigma), free_a, free_f)
    else:
        dof_inflation = _fit_dof_inflation(pb.g, pb.d, pb.rel, (a_map, f_map), (x_map, y_map), None, None,
                                           gamma_used, 0.0, free_a, free_f)
    sandwich = _position_variance_ratio(pb.g, pb.d, pb.rel, (a_map, f_map), (x_map, y_map), dr.drift_xy, gamma_used,
                                        free_a, free_f)
    return kappa * dof_inflation * sandwich, dof_inflation, sandwich


def _walk_information(J: np.ndarray, ok: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """``J^T W J`` for the dead-reckoning random walk, ``W_ij = min(tau_i, tau_j) (g_i . g_j)`` (per unit intensity):
    a position error ``w_i`` growing as a random walk from the first sample (``Cov(w_i, w_j) = q min(tau_i, tau_j)``
    per axis) changes the residual of sample ``i`` by ``-g_i . w_i``, ``g_i`` the map gradient there: the start
    x/y columns of the fit's Jacobian ``J`` (:func:`_pose_jacobian`). Computed without forming ``W``
    (``O(N p^2)``): ``sum_k dtau_k U_k^T U_k`` with ``U_k = sum_{i >= k} g_i J_i`` per axis (samples outside ``ok``
    left out)."""
    dtau = np.diff(tau - tau[0], prepend=0.0)
    Jz = np.where(ok[:, None], J, 0.0)
    M = np.zeros((J.shape[1], J.shape[1]))
    for axis in (0, 1):
        U = np.cumsum((Jz[:, axis:axis + 1] * Jz)[::-1], axis=0)[::-1]
        M += U.T @ (dtau[:, None] * U)
    return M


def _laplace_main_mode(pb: _Problem, dr: _DriftStep, free_heading: bool, free_scale: bool, tau: np.ndarray,
                       random_walk: float) -> tuple[np.ndarray | None, dict]:
    """Covariance of the start in the main mode: Laplace at the continuous MAP (module docstring, *Reported*).

    The fit at the MAP (start x/y, the free heading and scale, the drift rates when the drift is applied, the bias)
    linearised with the bilinear map gradients, ``J``; the noise variance ``s^2 = RSS / (N_v - p)`` and the AR(1)
    tempering ``gamma`` from the residuals **there** (floored by the map uncertainty along the track), the drift
    rates marginalised under their prior: ``C = ((gamma / s^2) J^T J + L)^-1``. With a dead-reckoning random walk of
    ``random_walk`` (m per sqrt of the unit of ``tau``, per axis) the estimator's covariance gains the walk's share,
    ``(gamma / s^2)^2 q C J^T W J C`` (:func:`_walk_information`, ``q = random_walk^2``): the sandwich of the
    least-squares fit under the walk-correlated residuals. None (and the reason) when the fit is degenerate."""
    x_map, y_map, a_map, f_map = dr.pose
    applied = bool(dr.info.get("applied"))
    B = dr.B if applied else None
    drift_xy = dr.drift_xy if applied else None
    reg = _track_regression(pb.g, pb.d, pb.rel, (a_map, f_map), (x_map, y_map), drift_xy, B, 1.0, 0.0,
                            free_heading, free_scale)
    if reg is None:
        return None, {"method": "grid", "why": "too few valid samples for the linearised fit"}
    J = reg[0]
    r = _bilinear_residuals(pb.g, pb.d, pb.rel, (a_map, f_map), np.array([[x_map, y_map]]), drift_xy)[0]
    ok = np.isfinite(r) & np.any(J != 0, axis=1)
    n, p = int(ok.sum()), J.shape[1]
    if n <= p + 2:
        return None, {"method": "grid", "why": f"{n} samples with a map gradient for {p} parameters"}
    rc = r[ok] - r[ok].mean()
    q_fix = _rotate(pb.rel, a_map) * f_map + np.array([x_map, y_map]) + (0.0 if drift_xy is None else drift_xy)
    s2 = max(float(rc @ rc) / (n - p), _map_sigma2_at(pb.unc, q_fix) + pb.floor2)
    rho = residual_autocorrelation(np.where(ok, r, np.nan), pb.max_lag) if pb.corr_model != "ar1" else None
    gam = min(max(_n_eff(np.where(ok, r, np.nan), pb.tempering, pb.max_lag) / n, 1e-3), 1.0)
    prior = np.zeros(p)
    if B is not None:
        k0 = p - 1 - 2 * B.shape[1]
        prior[k0:p - 1] = 1.0 / dr.sigma ** 2
    Jv = J[ok]
    info = {"method": "laplace", "noise_sigma_m": float(np.sqrt(s2)), "tempering": float(gam), "n_valid": n,
            "parameters": p, "random_walk": float(random_walk), "correlation_model": pb.corr_model}
    try:
        C = np.linalg.inv((gam / s2) * (Jv.T @ Jv) + np.diag(prior))
        if rho is not None:  # HAC sandwich (module docstring, *Correlated residuals*)
            meat = (gam / s2) ** 2 * s2 * _hac_meat(J, ok, np.maximum(rho, 0.0)) + np.diag(prior)
            if np.linalg.eigvalsh(0.5 * (meat + meat.T)).min() > -1e-9 * np.trace(meat):
                C_white = np.linalg.inv((1.0 / s2) * (Jv.T @ Jv) + np.diag(prior))  # independent samples
                ev, V = np.linalg.eigh(0.5 * ((C @ meat @ C - C_white) + (C @ meat @ C - C_white).T))
                C = C_white + (V * np.maximum(ev, 0.0)) @ V.T  # never narrower than independent samples'
                info.update({"correlation": "hac", "correlation_lags": int(np.count_nonzero(rho)),
                             "integrated_autocorrelation": float(1.0 + 2.0 * rho.sum())})
        if random_walk > 0:
            M = _walk_information(J, ok, tau)
            Ci = np.linalg.inv((gam / s2) * (Jv.T @ Jv) + np.diag(prior))
            walk = (gam / s2) ** 2 * random_walk ** 2 * (Ci @ M @ Ci)
            info["random_walk_share_m2"] = float(np.trace(walk[:2, :2]))
            C = C + walk
    except np.linalg.LinAlgError:
        return None, {"method": "grid", "why": "singular information matrix"}
    C2 = 0.5 * (C[:2, :2] + C[:2, :2].T)
    if not np.isfinite(C2).all() or np.linalg.eigvalsh(C2).min() <= 0:
        return None, {"method": "grid", "why": "covariance not positive definite"}
    return C2, info


def _window_moments(w: _Window, x_ll: np.ndarray, xhat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Mean of a fine window's posterior over its start offsets (poses marginalised) and its second moment about
    ``xhat``."""
    pw = np.exp(x_ll - x_ll.max()).sum(axis=0)
    pw = pw / pw.sum() if pw.sum() > 0 else np.full(pw.size, 1.0 / pw.size)
    e = w.offs - xhat
    return (pw[:, None] * w.offs).sum(axis=0), (pw[:, None, None] * e[:, :, None] * e[:, None, :]).sum(axis=0)


def _mixture_moments(g: MapGrid, windows: list[_Window], lls: list[np.ndarray], gm: _GridMap, pc: np.ndarray,
                     main_cov: np.ndarray, step: float, xhat: np.ndarray):
    """Second moment about the rigid MAP ``xhat`` and mean of the whole posterior: the fine windows (a mixture, the
    main one's own covariance ``main_cov``, the others' fine cells' spread) and the coarse cells outside them; the
    windows' means and masses (``modes``); the total mass."""
    h = g.resolution_m
    S = np.zeros((2, 2))
    mean = np.zeros(2)
    modes = []
    for iw, (w, x_ll, m_w) in enumerate(zip(windows, lls, gm.mw, strict=True)):
        mu, Sw = _window_moments(w, x_ll, xhat)
        S += m_w * (main_cov if iw == gm.best_w else Sw + np.eye(2) * step * step / 12)
        mean += m_w * mu
        modes.append({"x_east_m": float(mu[0]), "y_north_m": float(mu[1]), "mass": float(m_w)})
    if gm.m_out_coarse > 0:
        rr, cc = np.nonzero(gm.out_mask & (pc > 0))
        pw = pc[rr, cc]
        ex, ey = g.x_m[cc] - xhat[0], g.y_m[rr] - xhat[1]
        S += np.array([[np.sum(pw * ex * ex), np.sum(pw * ex * ey)], [np.sum(pw * ex * ey), np.sum(pw * ey * ey)]])
        S += gm.m_out_coarse * np.eye(2) * h * h / 12
        mean += np.array([np.sum(pw * g.x_m[cc]), np.sum(pw * g.y_m[rr])])
    tot = float(gm.mw.sum() + gm.m_out_coarse)
    S /= tot
    mean /= tot
    return S, mean, modes, tot


def _grid_main_moment(w: _Window, x_ll: np.ndarray, kappa: float, step: float, xhat: np.ndarray) -> np.ndarray:
    """The main window's own second moment about ``xhat`` widened by ``kappa`` (:func:`_main_mode_widening`), plus
    the fine cells' spread: the main mode's covariance when the Laplace one is undefined."""
    return kappa * _window_moments(w, x_ll, xhat)[1] + np.eye(2) * step * step / 12


def _second_mode(g: MapGrid, modes: list[dict], gm: _GridMap, mass_r: np.ndarray, tot: float, x_map: float,
                 y_map: float) -> dict | None:
    """The heaviest mode other than the main one (the other windows and the best coarse mode outside all windows),
    with its distance from the fix; None when there is none."""
    others = [m for i, m in enumerate(modes) if i != gm.best_w]
    if gm.m_out_coarse > 0:
        mo_ = np.where(gm.out_mask, mass_r, 0.0)
        f2 = int(np.argmax(mo_))
        r2, c2 = divmod(f2, g.shape[1])
        others.append({"x_east_m": float(g.x_m[c2]), "y_north_m": float(g.y_m[r2]), "mass": float(mo_[r2, c2] / tot)})
    second = max(others, key=lambda m: m["mass"]) if others else None
    if second is not None:
        second = {**second, "distance_m": float(np.hypot(second["x_east_m"] - x_map, second["y_north_m"] - y_map))}
    return second


def _terrain_relief(pb: _Problem, dr: _DriftStep, s_f: float):
    """Track points at the fix, the map relief (std) under them and its ratio to the noise ``s_f``."""
    x_map, y_map, a_map, f_map = dr.pose
    xy_fix = _rotate(pb.rel, a_map) * f_map + np.array([x_map, y_map]) + dr.drift_xy
    zf = pb.g.sample_bilinear(xy_fix[:, 0], xy_fix[:, 1])
    zf = zf[np.isfinite(zf)]
    relief = float(np.std(zf)) if zf.size > 1 else 0.0
    r2n = relief / s_f if s_f > 0 else float("inf")
    return xy_fix, relief, r2n


def _holes_test(pb: _Problem, cs: _Coarse, cp: _CoarsePosterior, pose: _Pose, R: float,
                min_valid_for_fix: float) -> float:
    """Posterior mass outside the main mode were the map under its interior holes to fit the track as well as its
    valid part does (:func:`_holes_mass_outside`); 0 without interior holes.

    The likelihood scores a sample over a hole with the map's whole depth distribution (it carries no position
    information), which favours hole-free offsets. Under the most optimistic alternative the posterior must still
    hold the fix; if more than max_mass_outside_holes of it then lies elsewhere, the fix depends on what the holes
    hide: flagged ``over_holes``."""
    if cs.n_hole_all is None:
        return 0.0
    x_map, y_map = pose[0], pose[1]
    fix_cr = (float(pb.g.col_of(np.array([x_map]))[0]), float(pb.g.row_of(np.array([y_map]))[0]))
    return _holes_mass_outside(cs.msd_all, cs.n_all, cs.n_hole_all, pb.n, cp.s2, pb.v_map, cp.gamma,
                               max(pb.n_req, min_valid_for_fix * pb.n), fix_cr, R)


def _mismatch_flags(lim: _Limits, N: int, n_valid: int, relief: float, r2n: float, s_f: float,
                    mass_out_holes: float, mass_out: float, second: dict | None, best_w: int):
    """Mismatch reasons and warnings (module docstring, *Mismatch*), in the order short track, off the map, no
    terrain information, over holes, ambiguous, and the note when the fine likelihood preferred another mode."""
    reasons: list[str] = []
    warns: list[str] = []
    if N < lim.min_samples:
        reasons.append("short_track")
        warns.append(f"possible mismatch: the profile has {N} samples (< {lim.min_samples}); too short to fix the track uniquely")
    vf = n_valid / N
    if vf < lim.min_valid_for_fix:
        reasons.append("off_map")
        warns.append(f"possible mismatch: {N - n_valid} of {N} samples ({100 * (1 - vf):.0f} %) have no map depth at the fix "
                     "(track off the map or over holes): too little terrain information")
    elif vf < lim.min_valid_at_fix:
        warns.append(f"{N - n_valid} of {N} samples ({100 * (1 - vf):.0f} %) have no map depth at the fix (track partly off "
                     "the map or over holes); the posterior rests on the others")
    if r2n < lim.min_relief_to_noise:
        reasons.append("no_terrain_information")
        warns.append(f"possible mismatch: map relief under the track (std {relief:.3g} m) is only {r2n:.2g} x the "
                     f"profile noise ({s_f:.3g} m): too little terrain information (flat map)")
    if mass_out_holes > lim.max_mass_outside_holes:
        reasons.append("over_holes")
        warns.append(f"possible mismatch: if the map under its holes fitted the track as well as elsewhere, "
                     f"{100 * mass_out_holes:.1f} % of the posterior mass would lie more than {lim.mode_radius_cells:g} "
                     "cells from the fix: the fix depends on what the map holes hide")
    if mass_out > lim.max_mass_outside:
        broad = second is None or second["mass"] < 0.5 * mass_out
        reasons.append("ambiguous")
        where = (f"; the next mode at ({second['x_east_m']:.0f}, {second['y_north_m']:.0f}) m holds {100 * second['mass']:.1f} %"
                 if second else "")
        what = "the posterior is spread over the map (too little terrain information)" if broad else "a second mode competes"
        warns.append(f"possible mismatch: {100 * mass_out:.1f} % of the posterior mass lies more than "
                     f"{lim.mode_radius_cells:g} cells from the fix: {what}{where}")
    if best_w != 0:
        warns.append("the fine (bilinear) likelihood preferred a different coarse mode than the cell-resolution search")
    return reasons, warns


def _refinement_record(g: MapGrid, step: float, windows: list[_Window], gm: _GridMap, lls_record: dict,
                       coarse_pose: tuple[float, float], cp: _CoarsePosterior, gammaf: float, dr: _DriftStep,
                       main_info: dict, has_holes: bool, mass_out_holes: float, holes_flag: bool) -> dict:
    """``PosteriorFix.refinement``: the fine grid, the log-likelihoods of the coarse fix, the grid MAP and the MAP,
    the coarse cell, the noise, the drift step and the holes test."""
    rc_c = windows[0].rc
    return {
        "method": "point-mass grid (bilinear map, sub-cell step) + Nelder-Mead polish under the same likelihood",
        "fine_step_m": step, "windows": len(windows), "winning_window": gm.best_w,
        **lls_record,
        "coarse_cell": {"x_east_m": float(g.x_m[rc_c[1]]), "y_north_m": float(g.y_m[rc_c[0]]),
                        "heading_error_deg": coarse_pose[0], "track_scale": coarse_pose[1]},
        "noise_sigma_coarse_m": float(np.sqrt(cp.s2)), "tempering": float(gammaf), "drift": dr.info,
        "main_mode_covariance": main_info,
        "holes_test": {"map_has_interior_holes": has_holes, "mass_outside_if_holes_fit": mass_out_holes,
                       "flagged": holes_flag},
    }


# ------------------------------------------------------------------ main entry
def posterior_fix(
    profile_depth,
    track_xy,
    dtm,
    *,
    headings_deg: Sequence[float] = (0.0,),
    scales: Sequence[float] = (1.0,),
    region: tuple[float, float, float, float] | None = None,
    uncertainty=None,
    min_valid_fraction: float = 0.3,
    mode_radius_cells: float = MODE_RADIUS_CELLS,
    fine_step_cells: float = 0.25,
    n_alt_modes: int = 3,
    max_mass_outside: float = MAX_MASS_OUTSIDE,
    max_mass_outside_holes: float = MAX_MASS_OUTSIDE_HOLES,
    min_samples: int = MIN_SAMPLES,
    min_valid_at_fix: float = 0.9,
    min_relief_to_noise: float = 1.0,
    min_valid_for_fix: float = 0.5,
    polish: bool = True,
    fine_scales: Sequence[float] | None = None,
    time_s=None,
    drift: bool = True,
    drift_segment: float | None = None,
    drift_sigma: float | None = None,
    heading_sigma_deg: float | None = None,
    scale_sigma: float | None = None,
    drift_random_walk: float | None = None,
    noise: PosteriorNoiseOptions | None = None,
    edge: SearchEdgeOptions | None = None,
) -> PosteriorFix:
    """Posterior fix of a measured depth profile on a map (module docstring).

    Parameters
    ----------
    profile_depth : measured seafloor depths ``d_M`` (m, positive down), (N,).
    track_xy : (N, 2) dead-reckoned x_east_m, y_north_m of the samples (any origin; matched relative to the first).
    dtm : reference map (``dtm`` Dataset with ``depth_m``, DataArray or :class:`MapGrid`). When a Dataset
        carries ``uncertainty_m`` it is used as the map error unless ``uncertainty`` is given.
    headings_deg, scales : the pose grid (heading errors in degrees clockwise; along-track scale factors).
    region : ``(x_min, x_max, y_min, y_max)`` map metres restricting the start position.
    uncertainty : per-cell map standard uncertainty (m) on the map grid (array, DataArray or MapGrid).
    min_valid_fraction : offsets with fewer valid samples are impossible (prior zero).
    fine_scales : extra scale factors tried in the fine windows (with the plausible coarse headings) and the
        bounds of the continuous scale fit (default: the coarse ``scales`` only).
    time_s : (N,) time of each sample (s, any origin): the dead-reckoning drift is then piecewise constant in
        time (``drift_segment`` s, prior ``drift_sigma`` m/s); without it in along-track distance
        (``drift_segment`` m, prior ``drift_sigma`` m per m travelled).
    drift : estimate the dead-reckoning drift jointly with the pose (module docstring, *Joint drift*).
    drift_random_walk : the dead reckoning's random walk beyond the drift, 1-sigma per axis per square root of the
        unit of ``tau`` (m/sqrt(s) with ``time_s``, else m/sqrt(m) travelled); it widens the main mode's covariance
        by the error it carries from the terrain that fixes the track to the start (module docstring,
        *Reported*). 0: none (a navigation error that is all drift); None: the ``match`` stage's default
        (:class:`hadal.matching.options.DeadReckoningOptions` ``drift_random_walk_m_per_sqrt_s``, per sqrt(m) when
        the track has no times, as at 1 m/s). Give your navigation's: the reported uncertainty depends on it.
    noise : the residuals' along-track correlation model (:class:`hadal.matching.options.PosteriorNoiseOptions`;
        default ``hac``: module docstring, *Correlated residuals*).
    edge : widen-and-retry and the flag of a MAP heading or scale at a bound of its search
        (:class:`hadal.matching.options.SearchEdgeOptions`; module docstring, *Search edge*).
    """
    args = {k: v for k, v in locals().items() if k not in ("edge",)}
    edge = edge if edge is not None else SearchEdgeOptions()
    f = _posterior_fix_once(**args)
    where = _at_edge(f, args["headings_deg"], args["scales"], args["fine_scales"])
    record: dict = {"at_edge": False, "retried": False, "first": where or None}
    if where and edge.edge_retry:
        wide = _widened_search(where, args["headings_deg"], args["scales"], args["fine_scales"], edge)
        if wide is not None:
            f2 = _posterior_fix_once(**{**args, **wide})
            where2 = _at_edge(f2, wide["headings_deg"], wide["scales"], wide["fine_scales"])
            record.update({"retried": True, "widened": {k: [float(min(v)), float(max(v))] for k, v in wide.items()
                                                         if v is not None},
                           "retry": {"x_east_m": f2.start_x_m, "y_north_m": f2.start_y_m,
                                     "heading_deg": f2.heading_deg, "scale": f2.scale, "at_edge": where2 or None}})
            if not where2:  # the wider search holds the optimum inside: its fix is reported
                f, where = f2, where2
            # else the first search's fix is reported, flagged (the wider one did not settle the pose either)
    if where:
        record.update({"at_edge": True, "bounds_hit": where})
        f.reasons.append("at_search_edge")
        f.warnings.append(search_edge_warning(where, "MAP", record["retried"]))
        f.mismatch = True
    f.search_edge = record
    f.refinement["search_edge"] = record
    return f


def _at_edge(f: PosteriorFix, headings_deg, scales, fine_scales) -> dict:
    """The MAP heading / scale within a quarter of the search step of a bound of a search that has a range
    (:func:`hadal.matching.tercom.pose_at_search_edge`; module docstring, *Search edge*); empty when inside."""
    fs = np.concatenate([np.asarray(scales, float).ravel(),
                         np.asarray(fine_scales if fine_scales is not None else [], float).ravel()])
    return pose_at_search_edge({"heading_deg": (f.heading_deg, headings_deg), "scale": (f.scale, fs)})


def _widen(grid: np.ndarray, factor: float, cap: float) -> np.ndarray | None:
    """``grid`` (equal steps about its centre) extended to ``factor`` x its half-range, at most ``cap``; None when it
    cannot grow."""
    grid = np.unique(np.asarray(grid, float))
    c = 0.5 * (grid[0] + grid[-1])
    half = 0.5 * (grid[-1] - grid[0])
    step = float(np.min(np.diff(grid)))
    new_half = min(factor * half, cap)
    if new_half <= half + 0.5 * step:
        return None
    k = int(np.floor(new_half / step + 1e-9))
    return np.round(c + np.arange(-k, k + 1) * step, 9)


def _widened_search(where: dict, headings_deg, scales, fine_scales, edge: SearchEdgeOptions) -> dict | None:
    """The retry's pose grids: the heading and/or scale ranges at whose bound the MAP sits widened by
    ``edge_widen_factor`` (capped); None when neither can grow."""
    hs = np.asarray(headings_deg, float)
    sc = np.asarray(scales, float)
    fsc = None if fine_scales is None else np.asarray(fine_scales, float)
    grew = False
    if "heading_deg" in where:
        w = _widen(hs, edge.edge_widen_factor, edge.edge_max_heading_range_deg)
        if w is not None:
            hs, grew = w, True
    if "scale" in where:
        for name in ("fine", "coarse"):
            arr = fsc if name == "fine" else sc
            if arr is None or np.unique(arr).size < 2:
                continue
            w = _widen(arr, edge.edge_widen_factor, edge.edge_max_scale_range)
            if w is not None and w.min() > 0:
                grew = True
                if name == "fine":
                    fsc = w
                else:
                    sc = w
    return {"headings_deg": hs, "scales": sc, "fine_scales": fsc} if grew else None


def _posterior_fix_once(profile_depth, track_xy, dtm, *, headings_deg, scales, region, uncertainty, min_valid_fraction,
                        mode_radius_cells, fine_step_cells, n_alt_modes, max_mass_outside, max_mass_outside_holes,
                        min_samples, min_valid_at_fix, min_relief_to_noise, min_valid_for_fix, polish, fine_scales,
                        time_s, drift, drift_segment, drift_sigma, heading_sigma_deg, scale_sigma, drift_random_walk,
                        noise) -> PosteriorFix:
    """One posterior fix on the given pose grid (:func:`posterior_fix` without the search-edge retry)."""
    noise = noise if noise is not None else PosteriorNoiseOptions()
    if drift_random_walk is None:
        from hadal.matching.options import DeadReckoningOptions

        drift_random_walk = float(DeadReckoningOptions.model_fields["drift_random_walk_m_per_sqrt_s"].default)
    if not (np.isfinite(drift_random_walk) and drift_random_walk >= 0):
        raise InputError(f"drift_random_walk must be a finite number >= 0, got {drift_random_walk!r}")
    pb = _prepare_inputs(profile_depth, track_xy, dtm, headings_deg, scales, fine_scales, uncertainty, region,
                         mode_radius_cells, min_valid_fraction)
    pb.corr_model, pb.max_lag = noise.correlation_model, int(noise.correlation_max_lag)
    pb.tempering = "acf" if noise.correlation_model == "acf" else "ar1"
    g, h, N = pb.g, pb.h, pb.n
    R = float(mode_radius_cells)
    # ---- coarse posterior (whole search region): surfaces, noise and N_eff at the coarse MAP, modes
    cs = _coarse_surfaces(pb, min_valid_fraction)
    cp = _coarse_noise(pb, cs)
    mass_r, centres = _coarse_modes(cp.pc, R, n_alt_modes)
    # ---- fine posterior: windows about the modes under one fine s^2 and gamma, window masses, grid MAP
    windows, win_mask, step, n_side = _fine_windows(pb, cp.ll, centres, R, fine_step_cells)
    s2f, gammaf = _fine_noise(pb, windows[0], cp.s2, cp.gamma)
    lls = [_fine_ll(w, N, s2f, gammaf, pb.v_map) for w in windows]
    gm = _grid_map(windows, lls, cp, win_mask, mass_r, step, h)
    kc, ll_coarse_pt = _coarse_fix_loglik(cp, windows[0], lls[0], pb.poses, n_side)
    if polish:
        pose, polished, ll_map = _polish(pb, windows[gm.best_w], gm.pose, gm.ll_grid, s2f, gammaf, R, step)
    else:
        pose, polished, ll_map = gm.pose, False, gm.ll_grid
    # ---- joint dead-reckoning drift; the fix's valid samples and bias
    x_rigid = np.array([pose[0], pose[1]])
    dr = _drift_step(pb, pose, ll_map, s2f, gammaf, drift, time_s, drift_segment, drift_sigma, heading_sigma_deg,
                     scale_sigma, min_samples)
    x_map, y_map, a_map, f_map = dr.pose
    n_valid, bias = _fix_residuals(pb, cs, cp, dr)
    # ---- the main mode's covariance (Laplace at the continuous MAP, drift rates marginalised, + the random walk;
    # the grid window's widened second moment when the linearised fit is degenerate), then the whole posterior's
    # moments: fine windows (mixture) + coarse cells outside them, about the rigid MAP (the grid is rigid)
    free_a, free_f = min(pb.headings) < max(pb.headings), min(pb.fine_scale_list) < max(pb.fine_scale_list)
    c_main, main_info = _laplace_main_mode(pb, dr, free_a, free_f, _tau_of(pb, time_s), float(drift_random_walk))
    if c_main is None:  # degenerate linearised fit: the main window's own (widened) second moment
        kappa, dof_inflation, sandwich = _main_mode_widening(pb, dr, s2f, gammaf)
        c_main = (_grid_main_moment(windows[gm.best_w], lls[gm.best_w], kappa, step, x_rigid)
                  + dr.inflation * dof_inflation)
        main_info.update({"noise_dof_inflation": float(dof_inflation), "sandwich_ratio": float(sandwich)})
    S, mean, modes, tot = _mixture_moments(g, windows, lls, gm, cp.pc, c_main, step, x_rigid)
    mean = mean + (np.array([x_map, y_map]) - x_rigid)
    mass_out = float(1.0 - gm.mw[gm.best_w] / tot)
    second = _second_mode(g, modes, gm, mass_r, tot, x_map, y_map)
    # ---- terrain information, holes test and flags
    s_f = float(np.sqrt(s2f))
    xy_fix, relief, r2n = _terrain_relief(pb, dr, s_f)
    mass_out_holes = _holes_test(pb, cs, cp, dr.pose, R, min_valid_for_fix)
    lim = _Limits(min_samples, min_valid_for_fix, min_valid_at_fix, min_relief_to_noise, max_mass_outside,
                  max_mass_outside_holes, mode_radius_cells)
    reasons, warns = _mismatch_flags(lim, N, n_valid, relief, r2n, s_f, mass_out_holes, mass_out, second, gm.best_w)
    refinement = _refinement_record(
        g, step, windows, gm, {"loglik_coarse_fix": ll_coarse_pt, "loglik_grid_map": gm.ll_grid, "loglik_map": ll_map,
                               "polished": polished},
        pb.poses[kc], cp, gammaf, dr, main_info, cs.n_hole_all is not None, mass_out_holes,
        mass_out_holes > max_mass_outside_holes)
    return PosteriorFix(
        start_x_m=x_map, start_y_m=y_map, heading_deg=a_map, scale=f_map, bias_m=bias,
        mean_x_m=float(mean[0]), mean_y_m=float(mean[1]), cov_m2=c_main, mixture_cov_m2=S,
        mass_outside_main_mode=mass_out,
        mode_radius_m=R * h, second_mode=second, noise_sigma_m=s_f,
        map_sigma_m=float(np.sqrt(_map_sigma2_at(pb.unc, xy_fix))), n_eff=float(gammaf * max(n_valid, 1)),
        n_samples=N, n_valid=n_valid, relief_to_noise=r2n, mismatch=bool(reasons), reasons=reasons, warnings=warns,
        track_start_xy=(float(pb.t[0, 0]), float(pb.t[0, 1])), posterior_cells=cp.pc.astype(np.float32), x_m=g.x_m,
        y_m=g.y_m, refinement=refinement, modes=modes, drift_model=dr.model,
    )
