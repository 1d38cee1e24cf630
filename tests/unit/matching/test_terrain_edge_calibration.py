"""Issue 47, terrain part: search-edge flags (TERCOM, posterior, MRF) and the residuals' effective sample size.

Oracles: synthetic terrain whose true offset / heading is known (the track or patch is cut from the analytic seafloor
at a chosen pose), and the closed forms of the effective sample size: ``n`` for white noise, ``n (1 - rho) / (1 + rho)``
for an AR(1) series (``rho_k = rho^k``: ``1 + 2 sum rho^k = (1 + rho) / (1 - rho)``).
"""

from __future__ import annotations

import warnings

import numpy as np
import pytest
from factories import AnalyticTerrain, wiggly_track
from scipy.signal import lfilter

from hadal.matching import MapGrid, tercom
from hadal.matching.mrf import mrf_refine
from hadal.matching.options import PosteriorNoiseOptions, SearchEdgeOptions
from hadal.matching.posterior import effective_sample_size, posterior_fix, residual_autocorrelation
from hadal.matching.tercom import _rotate

H = 20.0


@pytest.fixture(scope="module")
def world():
    t = AnalyticTerrain.random(7, relief_m=150.0)
    z, x, y = t.grid(140, 140, H, noise_m=0.3, seed=1)
    return t, MapGrid.from_any(z, x, y)


def _track_case(t, heading_deg: float, n: int = 70, seed: int = 3):
    """Dead-reckoned track and profile whose TRUE track is the DR track rotated by ``heading_deg`` about its start
    (oracle: the pose the profile was cut at)."""
    rng = np.random.default_rng(seed)
    dr = wiggly_track(n, n * H * 0.9, seed=seed)
    start = np.array([1400.0, 1300.0])
    true = _rotate(dr - dr[0], heading_deg) + start
    prof = t(true[:, 0], true[:, 1]) - 7.0 + rng.normal(0, 0.5, n)
    return prof, dr, start


def _fix(prof, dr, g, **kw):
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        return posterior_fix(prof, dr, g, headings_deg=np.arange(-4, 4.01, 1.0), scales=(1.0,), drift=False,
                             drift_random_walk=0.0, **kw)


def test_posterior_edge_flag_fires_outside_the_heading_search(world):
    t, g = world
    prof, dr, start = _track_case(t, 15.0)  # truth 15 deg, search +-4 deg (retry +-8)
    f = _fix(prof, dr, g)
    assert f.search_edge["retried"] and f.search_edge["at_edge"]
    assert f.mismatch and "at_search_edge" in f.reasons
    assert any(w.startswith("possible mismatch: search edge") for w in f.warnings)
    assert f.summary()["covariance_trusted"] is False and f.summary()["search_edge"]["at_edge"]
    # no retry: flagged at the first search's bound
    f0 = _fix(prof, dr, g, edge=SearchEdgeOptions(edge_retry=False))
    assert f0.search_edge["at_edge"] and not f0.search_edge["retried"] and abs(abs(f0.heading_deg) - 4.0) < 0.3


def test_posterior_edge_flag_does_not_fire_inside_and_retry_recovers(world):
    t, g = world
    prof, dr, start = _track_case(t, 1.5)
    f = _fix(prof, dr, g)
    assert not f.search_edge["at_edge"] and "at_search_edge" not in f.reasons
    assert np.hypot(f.start_x_m - start[0], f.start_y_m - start[1]) < H
    # truth 6 deg: at the +-4 bound first, inside the widened +-8 search: recovered, not flagged
    prof, dr, start = _track_case(t, 6.0)
    f = _fix(prof, dr, g)
    assert f.search_edge["retried"] and not f.search_edge["at_edge"] and "at_search_edge" not in f.reasons
    assert abs(f.heading_deg - 6.0) < 1.0 and np.hypot(f.start_x_m - start[0], f.start_y_m - start[1]) < H


def test_tercom_flags_heading_at_its_search_bound(world):
    t, g = world
    prof, dr, _ = _track_case(t, 15.0)
    r = tercom(prof, dr, g, headings_deg=np.arange(-4, 4.01, 1.0))
    assert r.search_edge["at_edge"] and r.mismatch and abs(r.heading_deg) == 4.0
    assert any("search edge" in w for w in r.warnings)
    prof, dr, _ = _track_case(t, 1.0)
    r = tercom(prof, dr, g, headings_deg=np.arange(-4, 4.01, 1.0))
    assert not r.search_edge["at_edge"] and not any("search edge" in w for w in r.warnings)


def _smooth_world():
    """A broad seafloor (one 1.2 km-wide seamount on a slope): the coarse MRF misfit falls towards the truth, so
    a search that does not reach the truth has its minimum on its rim."""
    x = np.arange(160) * H
    y = np.arange(160) * H
    X, Y = np.meshgrid(x, y)

    def z(xx, yy):
        return 4000.0 + 0.05 * xx + 300.0 * np.exp(-((xx - 1600.0) ** 2 + (yy - 1600.0) ** 2) / (2 * 600.0 ** 2))

    return z, MapGrid.from_any(z(X, Y), x, y)


def _mrf_patch(z, px, py, ny=30, nx=40):
    jj, ii = np.meshgrid(np.arange(nx), np.arange(ny))
    return z(px + jj * H, py + ii * H) + 3.0 + np.random.default_rng(0).normal(0, 0.3, jj.shape)


def test_mrf_edge_flag_outside_the_search_and_not_inside():
    z, g = _smooth_world()
    px, py = 1200.0, 1300.0
    patch = _mrf_patch(z, px, py)
    # truth 20 cells away, search 6 cells, retry at most 10: still at the edge -> refused, named, no fix
    edge = SearchEdgeOptions(mrf_edge_max_radius_cells=10.0)
    m = mrf_refine(patch, px + 20 * H, py, g, max_total_shift_cells=6.0, edge=edge)
    assert not m.converged and (m.x0_m, m.y0_m) == (px + 20 * H, py)
    assert any(w.startswith("possible mismatch: search edge") for w in m.warnings) and m.search_edge["at_edge"]
    # truth 4 cells away inside a 10-cell search: no edge warning, fix within a quarter cell
    m = mrf_refine(patch, px + 4 * H, py - 2 * H, g, max_total_shift_cells=10.0, edge=edge)
    assert not any("search edge" in w for w in m.warnings)
    assert m.converged and np.hypot(m.x0_m - px, m.y0_m - py) < 0.25 * H
    # truth 9 cells away, search 6 (at its edge) -> widened once to 12: recovered
    m = mrf_refine(patch, px + 9 * H, py, g, max_total_shift_cells=6.0, edge=SearchEdgeOptions())
    assert m.search_edge["retried"] and not m.search_edge["at_edge"] and not any("search edge" in w for w in m.warnings)
    assert m.converged and np.hypot(m.x0_m - px, m.y0_m - py) < 0.25 * H


def test_effective_sample_size_white_noise_is_n():
    rng = np.random.default_rng(11)
    vals = [effective_sample_size(rng.standard_normal(2000), 100) for _ in range(40)]
    assert np.mean(vals) == pytest.approx(2000, rel=0.08)
    assert max(vals) <= 2000


@pytest.mark.parametrize("rho", [0.3, 0.6, 0.85])
def test_effective_sample_size_matches_ar1_closed_form(rho):
    rng = np.random.default_rng(int(rho * 100))
    n = 3000
    vals = [effective_sample_size(lfilter([1.0], [1.0, -rho], rng.standard_normal(n)), 200) for _ in range(40)]
    assert np.mean(vals) == pytest.approx(n * (1 - rho) / (1 + rho), rel=0.08)
    # the autocorrelation itself follows rho^k at the first lags
    r = residual_autocorrelation(lfilter([1.0], [1.0, -rho], rng.standard_normal(20000)), 10)
    assert r[:3] == pytest.approx(rho ** np.arange(1, 4), abs=0.03)


def test_effective_sample_size_keeps_lags_over_missing_samples():
    """NaN samples keep their place along the track: an AR(1) series with 10 % missing still gives the closed form
    on the valid samples."""
    rng = np.random.default_rng(5)
    rho, n = 0.6, 3000
    vals = []
    for _ in range(30):
        x = lfilter([1.0], [1.0, -rho], rng.standard_normal(n))
        x[rng.random(n) < 0.1] = np.nan
        vals.append(effective_sample_size(x, 200) / np.isfinite(x).sum())
    assert np.mean(vals) == pytest.approx((1 - rho) / (1 + rho), rel=0.1)


def test_noise_options_are_bounded():
    from pydantic import ValidationError

    with pytest.raises(ValidationError):
        PosteriorNoiseOptions(correlation_max_lag=0)
    with pytest.raises(ValidationError):
        SearchEdgeOptions(edge_widen_factor=1.0)
    with pytest.raises(ValidationError):
        SearchEdgeOptions(edge_max_heading_range_deg=90)
