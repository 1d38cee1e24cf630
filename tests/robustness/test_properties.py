"""Property-based tests (hypothesis): seawater and depth functions, point gridding, TERCOM shift recovery."""

from __future__ import annotations

import gsw
import numpy as np
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from hadal.depth import hydrostatic_depth
from hadal.grid import grid_points
from hadal.matching.mapgrid import MapGrid
from hadal.matching.tercom import tercom
from hadal.seawater import density_eos80, depth_fofonoff_millard, practical_salinity

PROPS = settings(max_examples=50, deadline=None, suppress_health_check=[HealthCheck.too_slow])

salinity = st.floats(2.0, 42.0)
temperature = st.floats(-2.0, 35.0)
pressure = st.floats(0.0, 11_000.0)
latitude = st.floats(-90.0, 90.0)


def _sorted_distinct(values, min_gap: float) -> np.ndarray:
    a = np.unique(np.asarray(values, dtype=float))
    return a[np.concatenate([[True], np.diff(a) >= min_gap])]


# ---------------------------------------------------------------------------------------------- seawater
@PROPS
@given(sp=salinity, t=temperature, p=pressure)
def test_practical_salinity_inverts_gsw_c_from_sp(sp, t, p):
    """PSS-78 round trip: SP -> C (gsw.C_from_SP, mS/cm) -> S/m -> practical_salinity == SP within 1e-4."""
    c_s_m = float(gsw.C_from_SP(sp, t, p)) / 10.0
    assert abs(float(practical_salinity(c_s_m, t, p)) - sp) < 1e-4


@PROPS
@given(c=st.lists(st.floats(0.3, 7.0), min_size=2, max_size=40), t=temperature, p=pressure)
def test_practical_salinity_increases_with_conductivity(c, t, p):
    cs = _sorted_distinct(c, 1e-6)
    assume(len(cs) >= 2)
    sp = practical_salinity(cs, np.full(cs.size, t), np.full(cs.size, p))
    assert np.all(np.isfinite(sp))
    assert np.all(np.diff(sp) > 0)


@PROPS
@given(p=st.lists(pressure, min_size=2, max_size=40), sp=st.floats(0.0, 42.0), t=st.floats(-2.0, 40.0))
def test_density_eos80_increases_with_pressure(p, sp, t):
    ps = _sorted_distinct(p, 1e-3)
    assume(len(ps) >= 2)
    rho = density_eos80(np.full(ps.size, sp), np.full(ps.size, t), ps)
    assert np.all(np.diff(rho) > 0)


@PROPS
@given(p=st.lists(st.floats(0.0, 12_000.0), min_size=2, max_size=40), lat=latitude)
def test_fofonoff_millard_depth_increases_with_pressure(p, lat):
    ps = _sorted_distinct(p, 1e-3)
    assume(len(ps) >= 2)
    z = depth_fofonoff_millard(ps, np.full(ps.size, lat))
    assert z[0] >= -1e-9 and np.all(np.diff(z) > 0)


@PROPS
@given(p=st.lists(pressure, min_size=2, max_size=60), sp=salinity, t=temperature, lat=latitude)
def test_hydrostatic_depth_increases_with_pressure(p, sp, t, lat):
    """For a monotonic pressure series through uniform water the integrated depth is monotonic too."""
    ps = _sorted_distinct(p, 1e-2)
    assume(len(ps) >= 2)
    n = ps.size
    z = hydrostatic_depth(ps, np.full(n, sp), np.full(n, t), lat)
    assert np.all(np.isfinite(z)) and z[0] >= 0
    assert np.all(np.diff(z) > 0)
    # gross consistency with the standard-ocean depth: densities differ by at most ~4 % over these S, T
    assert np.allclose(z, depth_fofonoff_millard(ps, np.full(n, lat)), rtol=0.04, atol=0.5)


# ---------------------------------------------------------------------------------------------- gridding
@st.composite
def point_sets(draw):
    n = draw(st.integers(1, 300))
    xyz = draw(arrays(np.float64, (n, 3), elements=st.floats(-50.0, 50.0)))
    n_nan = draw(st.integers(0, min(5, n - 1)))
    if n_nan:
        xyz[draw(st.permutations(range(n)))[:n_nan], draw(st.integers(0, 2))] = np.nan
    res = draw(st.sampled_from([0.5, 1.0, 2.5, 7.0]))
    perm = np.array(draw(st.permutations(range(n))))
    return xyz, res, perm


@PROPS
@given(point_sets())
def test_grid_points_is_permutation_invariant_and_counts_every_point(case):
    xyz, res, perm = case
    finite = np.isfinite(xyz).all(axis=1)
    assume(finite.any())
    stats = ("mean", "count", "std")
    box = (-51.0, -51.0, 51.0, 51.0)  # every point inside (a point extent may be degenerate: one point)
    a = grid_points(xyz[:, 0], xyz[:, 1], xyz[:, 2], res, bounds=box, statistics=stats)
    b = grid_points(xyz[perm, 0], xyz[perm, 1], xyz[perm, 2], res, bounds=box, statistics=stats)
    assert np.array_equal(a["count"].values, b["count"].values)
    np.testing.assert_allclose(a["mean"].values, b["mean"].values, rtol=1e-12, atol=1e-12, equal_nan=True)
    np.testing.assert_allclose(a["std"].values, b["std"].values, rtol=1e-9, atol=1e-9, equal_nan=True)
    assert int(a["count"].values.sum()) == int(finite.sum())
    assert a.attrs["n_points_nonfinite"] == int((~finite).sum())


@PROPS
@given(point_sets(), st.tuples(st.floats(-60, 0), st.floats(-60, 0), st.floats(1, 60), st.floats(1, 60)))
def test_grid_points_with_bounds_counts_points_inside(case, box):
    """Counts sum to the finite points inside the grid; the others are counted as outside."""
    xyz, res, perm = case
    x0, y0, w, h = box
    bounds = (x0, y0, x0 + w, y0 + h)
    finite = np.isfinite(xyz).all(axis=1)
    assume(finite.any())
    a = grid_points(xyz[perm, 0], xyz[perm, 1], xyz[perm, 2], res, bounds=bounds, statistics=("count", "mean"))
    total = int(a["count"].values.sum())
    assert total + a.attrs["n_points_outside"] + a.attrs["n_points_nonfinite"] == len(xyz)
    inside = finite & (xyz[:, 0] > x0 + 1e-9) & (xyz[:, 0] < x0 + w - 1e-9) \
        & (xyz[:, 1] > y0 + 1e-9) & (xyz[:, 1] < y0 + h - 1e-9)
    assert total >= int(inside.sum())  # points strictly inside are never lost (edges: grid snapping)


# ---------------------------------------------------------------------------------------------- TERCOM
@st.composite
def tercom_cases(draw):
    seed = draw(st.integers(0, 2**32 - 1))
    shift = (draw(st.integers(-8, 8)), draw(st.integers(-8, 8)))
    bias = draw(st.booleans())
    return seed, shift, bias


def _terrain(rng: np.random.Generator, n: int) -> np.ndarray:
    """Smooth random terrain (m, positive down): random Gaussian hills and hollows on a gentle slope."""
    yy, xx = np.mgrid[0:n, 0:n].astype(float)
    z = 8000.0 + rng.uniform(-1, 1) * xx + rng.uniform(-1, 1) * yy
    for _ in range(8):
        cy, cx = rng.uniform(0, n, 2)
        s = rng.uniform(4.0, 12.0)
        z += rng.choice([-1, 1]) * rng.uniform(20.0, 80.0) * np.exp(-((xx - cx) ** 2 + (yy - cy) ** 2) / (2 * s * s))
    return z


@PROPS
@given(tercom_cases())
def test_tercom_recovers_a_map_shift(case):
    """Profile measured on map M along a track; on M shifted by (dr, dc) cells TERCOM moves the fix by (dr, dc)."""
    seed, (dr, dc), bias = case
    rng = np.random.default_rng(seed)
    h, pad, n = 10.0, 10, 60
    big = _terrain(rng, n + 2 * pad)
    x = np.arange(n) * h
    m = MapGrid.from_any(big[pad:pad + n, pad:pad + n], x, x)
    shifted = MapGrid.from_any(big[pad - dr:pad - dr + n, pad - dc:pad - dc + n], x, x)  # feature (r,c) -> (r+dr, c+dc)
    # a 2-D random-walk track on cell centres around the middle of the map
    steps = rng.integers(-2, 3, size=(40, 2))
    rc = np.clip(np.cumsum(steps, axis=0), -14, 14) + n // 2
    profile = m.depth_m[rc[:, 0], rc[:, 1]] + (7.5 if bias else 0.0)
    assume(np.ptp(rc[:, 0]) >= 3 and np.ptp(rc[:, 1]) >= 3)
    track = np.column_stack([x[rc[:, 1]], x[rc[:, 0]]]) + 1234.5  # any origin: matched relative to its start
    base = tercom(profile, track, m, estimate_bias=bias, min_valid_fraction=1.0)
    moved = tercom(profile, track, shifted, estimate_bias=bias, min_valid_fraction=1.0)
    assert (base.start_row, base.start_col) == (rc[0, 0], rc[0, 1])
    assert (moved.start_row - base.start_row, moved.start_col - base.start_col) == (dr, dc)
    assert abs(moved.start_x_m - base.start_x_m - dc * h) < 1e-6 and abs(moved.start_y_m - base.start_y_m - dr * h) < 1e-6
