"""MRF fine matching (mrf-terrain-matching.txt Eqs. 4-14): energy terms, sign, sub-cell gain over TERCOM, IPE sensitivity."""

from __future__ import annotations

import numpy as np
import pytest

from hadal.errors import InputError
from hadal.matching import MapGrid, tercom
from hadal.matching.mrf import _gibbs, _shift_axis, mrf_refine
from hadal.matching.testing import AnalyticTerrain

H = 20.0


@pytest.fixture(scope="module")
def world():
    t = AnalyticTerrain.random(3)
    z, x, y = t.grid(90, 70, H, noise_m=0.5, seed=2)
    return t, MapGrid.from_any(z, x, y)


def _patch(t, px, py, rng, ny=15, nx=20, noise=1.0, bias=5.0):
    jj, ii = np.meshgrid(np.arange(nx), np.arange(ny))
    return t(px + jj * H, py + ii * H) + bias + rng.normal(0, noise, jj.shape)


def test_gibbs_energy_is_four_neighbourhood_sum():
    a = np.array([[0.0, 1.0, 3.0], [2.0, 2.0, np.nan]])
    u = _gibbs(a[None])[0]
    # cell (0,0): right (0-1)^2 + down (0-2)^2 = 5; cell (0,1): 1 + 4 + 1 = 6; (1,2) missing -> NaN
    assert u[0, 0] == 5.0 and u[0, 1] == (1 + 4 + 1) and u[1, 0] == 4 + 0 and np.isnan(u[1, 2])
    assert u[0, 2] == 4.0  # only its left neighbour is valid
    s = _shift_axis(a, np.array([0.5]), 1)[0]
    assert s[0, 0] == 0.5 and s[0, 1] == 2.0 and np.isnan(s[0, 2])


def test_sign_and_subcell_recovery_of_known_shift(world):
    t, g = world
    rng = np.random.default_rng(0)
    px, py = 600.0, 500.0
    patch = _patch(t, px, py, rng, noise=0.2)
    # patch assumed 0.4 cell east and 0.3 cell south of the truth: d = assumed - true = (+8, -6) m
    m = mrf_refine(patch, px + 8.0, py - 6.0, g)
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


def test_mrf_alone_fails_for_large_initial_error(world):
    """MRF paper §4.3: the method is sensitive to the initial positioning error -- hence the TERCOM coarse fix."""
    t, g = world
    rng = np.random.default_rng(2)
    px, py = 700.0, 600.0
    patch = _patch(t, px, py, rng)
    bad = mrf_refine(patch, px + 5 * H, py - 4 * H, g)
    assert not bad.converged or np.hypot(bad.x0_m - px, bad.y0_m - py) > H
    if not bad.converged:
        assert any("diverged" in w or "converge" in w for w in bad.warnings)


def test_weight_of_gibbs_prior(world):
    """T = 1 (the paper's implicit value) lets the m^2-valued Gibbs term swamp the data term: no refinement."""
    t, g = world
    rng = np.random.default_rng(3)
    patch = _patch(t, 640.0, 420.0, rng)
    stuck = mrf_refine(patch, 650.0, 412.0, g, temperature=1.0)
    assert abs(stuck.dx_m) < 1.0 and abs(stuck.dy_m) < 1.0  # prior dominates: barely moves
    ok = mrf_refine(patch, 650.0, 412.0, g)
    assert np.hypot(ok.x0_m - 640.0, ok.y0_m - 420.0) < 3.0


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
    line = np.full((9, 9), np.nan)
    line[4, :] = t(500 + np.arange(9) * H, 500.0)  # a single survey line: no gradient across it
    lm = mrf_refine(line, 500.0, 500.0, g, min_cells=4)
    assert any("y not refined" in w for w in lm.warnings) and lm.dy_m == 0.0
