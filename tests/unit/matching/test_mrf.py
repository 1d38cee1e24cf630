"""MRF matching (mrf-terrain-matching.txt Eqs. 1-14): energy terms, sign, sub-cell accuracy, convergence range on
real terrain (oracle: the known offset a patch was cut at from a real grid), the Gibbs prior's effect, refusals."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from factories import AnalyticTerrain, cut_patch

from hadal.errors import InputError
from hadal.matching import MapGrid, tercom
from hadal.matching.mrf import GibbsFilter, _gibbs, _shift_axis, gibbs_temperature, mrf_refine
from hadal.matching.options import SearchEdgeOptions

H = 20.0
SHARED = Path(__file__).resolve().parents[4] / "shared" / "data"
REAL = {"tut_bathy": SHARED / "bathy-real" / "tut_bathy.nc", "gmt_depth_pixel": SHARED / "formats-real" / "gmt_depth_pixel.nc"}
OLD = {"coarse": False, "prior": "window", "max_total_shift_cells": 3.0}  # the previous implementation


@pytest.fixture(scope="module")
def world():
    t = AnalyticTerrain.random(3)
    z, x, y = t.grid(90, 70, H, noise_m=0.5, seed=2)
    return t, MapGrid.from_any(z, x, y)


@pytest.fixture(scope="module")
def real():
    if not all(p.exists() for p in REAL.values()):
        pytest.skip("real grids under ../shared/data absent")
    from factories import real_terrain

    return {k: real_terrain(p) for k, p in REAL.items()}


def _patch(t, px, py, rng, ny=15, nx=20, noise=1.0, bias=5.0):
    jj, ii = np.meshgrid(np.arange(nx), np.arange(ny))
    return t(px + jj * H, py + ii * H) + bias + rng.normal(0, noise, jj.shape)


def _start(x0, y0, h, r_cells, rng):
    a = rng.uniform(0, 2 * np.pi)
    return x0 + r_cells * h * np.cos(a), y0 + r_cells * h * np.sin(a)


def test_gibbs_energy_is_four_neighbourhood_sum():
    a = np.array([[0.0, 1.0, 3.0], [2.0, 2.0, np.nan]])
    u = _gibbs(a[None])[0]
    # cell (0,0): right (0-1)^2 + down (0-2)^2 = 5; cell (0,1): 1 + 4 + 1 = 6; (1,2) missing -> NaN
    assert u[0, 0] == 5.0 and u[0, 1] == (1 + 4 + 1) and u[1, 0] == 4 + 0 and np.isnan(u[1, 2])
    assert u[0, 2] == 4.0  # only its left neighbour is valid
    s = _shift_axis(a, np.array([0.5]), 1)[0]
    assert s[0, 0] == 0.5 and s[0, 1] == 2.0 and np.isnan(s[0, 2])


def test_gibbs_restoration_is_the_map_of_eqs_2_to_4():
    """Oracle: direct numerical minimisation of sum (I - M)^2 / (2 s^2) + U(I) / T (Eq. 4 summed as written)."""
    from scipy.optimize import minimize

    rng = np.random.default_rng(0)
    m = rng.normal(0, 1, (5, 6))
    m[2, 3] = np.nan
    s_n, T = 0.7, 3.0
    valid = np.isfinite(m)

    def energy(v):
        z = np.full(m.shape, np.nan)
        z[valid] = v
        return np.nansum((z - m) ** 2) / (2 * s_n ** 2) + np.nansum(_gibbs(z[None])[0]) / T

    ref = minimize(energy, m[valid], method="BFGS", options={"gtol": 1e-10}).x
    out = GibbsFilter(s_n, T)(m)
    assert np.isnan(out[2, 3]) and np.allclose(out[valid], ref, atol=1e-5)
    assert gibbs_temperature(m, 0.0) == pytest.approx(4 * np.mean(np.r_[np.diff(m, axis=0).ravel(), np.diff(m, axis=1).ravel()][
        np.isfinite(np.r_[np.diff(m, axis=0).ravel(), np.diff(m, axis=1).ravel()])] ** 2))


def test_sign_and_subcell_recovery_of_known_shift(world):
    t, g = world
    rng = np.random.default_rng(0)
    px, py = 600.0, 500.0
    patch = _patch(t, px, py, rng, noise=0.2)
    # patch assumed 0.4 cell east and 0.3 cell south of the truth: d = assumed - true = (+8, -6) m
    for kw in ({}, OLD):
        m = mrf_refine(patch, px + 8.0, py - 6.0, g, **kw)
        assert m.converged and not m.warnings
        assert m.dx_m == pytest.approx(8.0, abs=1.0) and m.dy_m == pytest.approx(-6.0, abs=1.0)
        assert np.hypot(m.x0_m - px, m.y0_m - py) < 1.0


def test_mrf_improves_tercom_coarse_fix_to_subcell(world):
    """MRF paper Simulation 3: MSD rough fix (error ~ half a cell) then MRF precise fix (error << cell)."""
    t, g = world
    rng = np.random.default_rng(1)
    jj, ii = np.meshgrid(np.arange(20), np.arange(15))
    rel = np.column_stack([(jj * H).ravel(), (ii * H).ravel()])
    e_t, e_m = [], []
    for _ in range(8):
        px, py = rng.uniform(300, 1000), rng.uniform(300, 800)
        patch = _patch(t, px, py, rng)
        r = tercom(patch.ravel(), rel + rng.uniform(-500, 500, 2), g)  # unknown absolute position
        m = mrf_refine(patch, r.start_x_m, r.start_y_m, g)
        e_t.append(np.hypot(r.start_x_m - px, r.start_y_m - py))
        e_m.append(np.hypot(m.x0_m - px, m.y0_m - py))
    e_t, e_m = np.array(e_t), np.array(e_m)
    assert e_t.max() <= 1.5 * H  # TERCOM: right cell, quantised
    assert e_m.mean() < 0.4 * e_t.mean() and e_m.mean() < 0.2 * H
    assert (e_m < e_t).mean() >= 0.75


def test_converges_from_20_to_25_cells_on_real_terrain(real):
    """MRF paper §4.3 Simulation 1: results from IPEs of 20 and 25 cells (40 x 30 patch). Oracle: the cut offset."""
    rng = np.random.default_rng(7)
    for name, (g, truth) in real.items():
        h = g.resolution_m
        for r_cells in (20, 23, 25):
            patch, x0, y0 = cut_patch(g, truth, rng, 0.01)
            ax, ay = _start(x0, y0, h, r_cells, rng)
            m = mrf_refine(patch, ax, ay, g)
            assert m.converged and not m.warnings, (name, r_cells, m.warnings)
            assert np.hypot(m.x0_m - x0, m.y0_m - y0) < 0.5 * h, (name, r_cells)  # sub-cell from 20-25 cells
            old = mrf_refine(patch, ax, ay, g, **OLD)  # linearised only, 3-cell cap: no fix from that far
            assert not old.converged or np.hypot(old.x0_m - x0, old.y0_m - y0) > 5 * h
        for _ in range(2):  # beyond the range (25 cells + guard ring): flagged, not a wrong fix
            patch, x0, y0 = cut_patch(g, truth, rng, 0.01)
            start = _start(x0, y0, h, 34, rng)
            far = mrf_refine(patch, *start, g, edge=SearchEdgeOptions(edge_retry=False))
            assert not far.converged and far.warnings, name
            # issue 47: a minimum at the search edge widens the search once (50 cells): recovered, or refused
            wide = mrf_refine(patch, *start, g)
            assert not wide.converged or (wide.search_edge["retried"]
                                          and np.hypot(wide.x0_m - x0, wide.y0_m - y0) < 0.5 * h), name


def test_subcell_accuracy_on_real_terrain(real):
    rng = np.random.default_rng(8)
    errs = []
    for g, truth in real.values():
        for _ in range(4):
            patch, x0, y0 = cut_patch(g, truth, rng, 0.01)
            m = mrf_refine(patch, *_start(x0, y0, g.resolution_m, rng.uniform(0, 10), rng), g)
            assert m.converged
            errs.append(np.hypot(m.x0_m - x0, m.y0_m - y0) / g.resolution_m)
    assert np.median(errs) < 0.1 and max(errs) < 0.3  # cells (map = nodes, truth = bicubic between them)


def _flattest(g, k, ny=30, nx=40):
    cand = []
    for r in range(2, g.shape[0] - ny - 3, 10):
        for c in range(2, g.shape[1] - nx - 3, 10):
            w = g.depth_m[r : r + ny, c : c + nx]
            if np.isfinite(w).all():
                cand.append((float(np.std(np.diff(w, axis=1))), r, c))
    return [(r, c) for _, r, c in sorted(cand)[:k]]


def test_gibbs_prior_helps_on_low_texture_noisy_data_and_not_hurts_on_texture(real):
    """Low-texture real windows, noisy soundings (10 % of the range) and a noisy DTM (20 %): Eq. (7)'s gradient of the
    measured terrain is mostly noise and the Gibbs prior (MAP terrain, both sides through it) gives smaller errors than
    the raw soundings, changing fixes by more than the 0.08 cell of the literal Eq. (9). Textured terrain: no harm."""
    g, truth = real["gmt_depth_pixel"]
    h = g.resolution_m
    rng = np.random.default_rng(12)
    err = {"gibbs": [], "none": []}
    for rc in _flattest(g, 12):
        patch, x0, y0 = cut_patch(g, truth, rng, 0.10, *rc)
        noisy = MapGrid(g.depth_m + rng.normal(0, 0.2 * np.ptp(patch) / 1.4, g.shape), g.x_m, g.y_m, h)
        ax, ay = _start(x0, y0, h, rng.uniform(0, 3), rng)
        for prior in err:
            m = mrf_refine(patch, ax, ay, noisy, prior=prior)
            err[prior].append(np.hypot(m.x0_m - x0, m.y0_m - y0) / h)
    eg, en = np.array(err["gibbs"]), np.array(err["none"])
    assert np.sqrt(np.mean(eg ** 2)) < 0.9 * np.sqrt(np.mean(en ** 2)), (eg, en)
    assert np.mean(np.abs(eg - en)) > 0.08
    for _ in range(4):
        patch, x0, y0 = cut_patch(g, truth, rng, 0.01)
        ax, ay = _start(x0, y0, h, rng.uniform(0, 10), rng)
        a, b = (mrf_refine(patch, ax, ay, g, prior=p) for p in ("gibbs", "none"))
        ea, eb = (np.hypot(m.x0_m - x0, m.y0_m - y0) / h for m in (a, b))
        assert a.converged and b.converged and ea < 0.2 and abs(ea - eb) < 0.05


def test_refuses_patch_without_texture(world):
    t, g = world
    rng = np.random.default_rng(5)
    flat_map = MapGrid(np.full(g.shape, 1000.0), g.x_m, g.y_m, g.resolution_m)
    patch = 1000.0 + rng.normal(0, 0.5, (15, 20))
    m = mrf_refine(patch, 600.0, 500.0, flat_map)
    assert not m.converged and (m.x0_m, m.y0_m) == (600.0, 500.0) and any("texture" in w for w in m.warnings)
    z = mrf_refine(np.full((15, 20), 1000.0), 600.0, 500.0, g)
    assert not z.converged and any("no relief" in w for w in z.warnings)


def test_flags_offset_beyond_search_range(world):
    t, g = world
    rng = np.random.default_rng(6)
    patch = _patch(t, 700.0, 600.0, rng)
    m = mrf_refine(patch, 700.0 + 12 * H, 600.0 - 9 * H, g, max_total_shift_cells=5.0)  # 15 cells off, range 5
    assert not m.converged and (m.x0_m, m.y0_m) == (700.0 + 12 * H, 600.0 - 9 * H)
    ok = mrf_refine(patch, 700.0 + 12 * H, 600.0 - 9 * H, g)
    assert ok.converged and np.hypot(ok.x0_m - 700.0, ok.y0_m - 600.0) < 0.3 * H


def test_missing_cells_and_bad_input(world):
    t, g = world
    rng = np.random.default_rng(4)
    patch = _patch(t, 500.0, 500.0, rng)
    patch[5:8, 4:9] = np.nan
    m = mrf_refine(patch, 507.0, 495.0, g)
    assert m.converged and np.hypot(m.x0_m - 500.0, m.y0_m - 500.0) < 3.0
    with pytest.raises(InputError, match="2-D"):
        mrf_refine(np.ones(10), 0.0, 0.0, g)
    with pytest.raises(InputError, match="valid cells"):
        mrf_refine(np.full((5, 5), np.nan), 0.0, 0.0, g)
    with pytest.raises(InputError, match="prior"):
        mrf_refine(patch, 500.0, 500.0, g, prior="bogus")
    line = np.full((9, 9), np.nan)
    line[4, :] = t(500 + np.arange(9) * H, 500.0)  # a single survey line: no gradient across it
    lm = mrf_refine(line, 500.0, 500.0, g, min_cells=4)
    assert not lm.converged and lm.dy_m == 0.0 and any("texture" in w for w in lm.warnings)
    lo = mrf_refine(line, 500.0, 500.0, g, min_cells=4, **OLD)
    assert any("y not refined" in w for w in lo.warnings) and lo.dy_m == 0.0
