"""Posterior fix with the joint dead-reckoning drift estimate, and the FFT crop (hadal.matching.posterior).

Oracles: the simulated truth (an analytic seafloor, a known piecewise-constant velocity bias added to the
dead-reckoned track), brute-force integration of the drift, and the same fix on a map embedded in a 3x larger
map (cropping to the search region plus the track's footprint must not change the result).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from factories import AnalyticTerrain, wiggly_track

from hadal.matching import MapGrid
from hadal.matching.posterior import _drift_basis, posterior_fix

H = 20.0


def _case(seed: int = 3):
    terrain = AnalyticTerrain.random(seed, relief_m=120.0, extent_m=4000.0)
    z, x, y = terrain.grid(200, 200, H, noise_m=0.3, seed=seed)
    g = MapGrid.from_any(z, x, y)
    rel = wiggly_track(150, 3000.0, seed=seed + 1)
    speed = 0.5  # m/s
    along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(rel, axis=0).T))])
    t = along / speed
    # true velocity bias (m/s): east 1.2 cm/s for the first half of the time, north -1.2 cm/s after
    u = np.where(t[:, None] < t[-1] / 2, [0.012, 0.0], [0.0, -0.012])
    drift = np.concatenate([[[0.0, 0.0]], np.cumsum(u[1:] * np.diff(t)[:, None], axis=0)])
    start = np.array([2000.0, 2000.0]) - (rel.min(axis=0) + rel.max(axis=0)) / 2
    true = start + rel + drift
    prof = terrain(true[:, 0], true[:, 1]) - 7.0 + np.random.default_rng(seed).normal(0, 0.5, rel.shape[0])
    return g, prof, rel, t, start, drift


def test_drift_basis_integrates_piecewise_constant_rates():
    tau = np.sort(np.random.default_rng(0).uniform(0, 1000, 200))
    tau[0] = 0.0
    B, edges = _drift_basis(tau, 250.0)
    assert B.shape == (200, 4) and edges[0] == 0 and edges[-1] == pytest.approx(tau[-1])
    U = np.array([[1.0, 0.0], [0.0, 2.0], [-1.0, 0.0], [0.5, 0.5]])
    fine = np.linspace(0, tau[-1], 200_001)  # brute force: integrate the rate of the segment each instant is in
    k = np.minimum(np.searchsorted(edges, fine, side="right") - 1, 3)
    w = np.cumsum(U[k] * np.gradient(fine)[:, None], axis=0) - U[k[0]] * np.gradient(fine)[0]
    ref = np.column_stack([np.interp(tau, fine, w[:, 0]), np.interp(tau, fine, w[:, 1])])
    assert np.abs(B @ U - ref).max() < 0.05 and np.all(B[0] == 0)


def test_joint_drift_recovers_the_start_and_the_drift():
    g, prof, rel, t, start, drift = _case()
    kw = dict(headings_deg=np.arange(-2, 2.01, 1.0), time_s=t, drift_segment=t[-1] / 4, drift_sigma=0.02)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # nothing may leak to the user
        f = posterior_fix(prof, rel, g, **kw)
        rigid = posterior_fix(prof, rel, g, **{**kw, "drift": False})
    err = np.hypot(f.start_x_m - start[0], f.start_y_m - start[1])
    err_rigid = np.hypot(rigid.start_x_m - start[0], rigid.start_y_m - start[1])
    d = f.refinement["drift"]
    assert d["applied"] and d["log_posterior_joint"] > d["log_posterior_rigid_map"]
    assert err < 0.5 * H and err < err_rigid, (err, err_rigid)
    assert f.mahalanobis(*start) < 3.0
    # the matched track with the estimated drift lies on the true track (the drift reaches 46 m); heading and
    # drift share the along-track rotation, so the track, not the drift alone, is compared
    on_track = np.hypot(*(f.apply(rel, t) - (start + rel + drift)).T)
    rigid_track = np.hypot(*(rigid.apply(rel) - (start + rel + drift)).T)
    assert on_track.max() < 0.75 * H and on_track.mean() < 0.5 * rigid_track.mean(), (on_track.max(), rigid_track.mean())


def test_crop_does_not_change_the_fix_and_bounds_the_work():
    g, prof, rel, t, start, _ = _case(5)
    big = np.random.default_rng(9).normal(g.depth_m.mean(), 80.0, (600, 600))
    big[200:400, 200:400] = g.depth_m
    x = (np.arange(600) - 200) * H
    gb = MapGrid.from_any(big, x, x)
    region = (start[0] - 400, start[0] + 400, start[1] - 400, start[1] + 400)
    kw = dict(headings_deg=(-1.0, 0.0, 1.0), region=region, drift=False)
    a = posterior_fix(prof, rel, g, **kw)
    b = posterior_fix(prof, rel, gb, **kw)
    assert (b.start_x_m, b.start_y_m) == pytest.approx((a.start_x_m, a.start_y_m), abs=1e-6)
    assert b.sigma_m == pytest.approx(a.sigma_m, rel=1e-6)
    assert b.posterior_cells.size < 0.25 * gb.depth_m.size  # the surfaces cover the crop, not the whole map


def test_refinement_is_never_worse_than_the_coarse_fix_and_leaks_no_warning():
    """refine_tercom: the refined pose's bilinear MSD (evaluated here directly, bias removed) is never above the
    coarse pose's under the same bilinear MSD, for several tracks; the optimiser emits no warning."""
    from hadal.matching import refine_tercom, tercom
    from hadal.matching.tercom import _rotate

    terrain = AnalyticTerrain.random(8, relief_m=60.0, extent_m=3000.0)
    z, x, y = terrain.grid(150, 150, H, noise_m=0.5, seed=1)
    g = MapGrid.from_any(z, x, y)

    def msd(pose, rel, prof):
        x0, y0, a, f = pose
        q = _rotate(rel, a) * f + [x0, y0]
        r = g.sample_bilinear(q[:, 0], q[:, 1]) - prof
        r = r[np.isfinite(r)]
        return float(np.mean((r - r.mean()) ** 2))

    for seed in range(4):
        rng = np.random.default_rng(seed)
        rel = wiggly_track(60, 1200.0, seed=seed)
        start = np.array([1500.0, 1500.0]) - (rel.min(0) + rel.max(0)) / 2
        prof = terrain(*(rel * 1.01 + start).T) + rng.normal(0, 1.0, 60)
        hs = np.arange(-2, 2.01, 1.0)
        with warnings.catch_warnings():
            warnings.simplefilter("error")
            c = tercom(prof, rel, g, headings_deg=hs)
            r = refine_tercom(prof, rel, g, c, heading_bounds_deg=(-2.5, 2.5))
        coarse = msd((c.start_x_m, c.start_y_m, c.heading_deg, c.scale), rel, prof)
        refined = msd((r.start_x_m, r.start_y_m, r.heading_deg, r.scale), rel, prof)
        assert refined <= coarse + 1e-9, (seed, refined, coarse)
