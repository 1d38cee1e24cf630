"""grid_points: check values, agreement with scipy, numerical exactness, bad input."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.stats import binned_statistic_2d

from hadal.errors import HadalError, InputError
from hadal.grid import grid_points, make_grid_spec, reduce_cells, robust_outlier_mask
from hadal.grid import points as P

# Hand-made check values: 1 m cells, bounds (0, 0, 2, 2) -> 2 x 2 cells.
#   cell (y=0, x=0): z = 1, 2, 6      mean 3, median 2, std sqrt(7), min 1, max 6
#   cell (y=0, x=1): z = 10           mean 10, median 10, std NaN (n=1)
#   cell (y=1, x=0): empty            NaN, count 0
#   cell (y=1, x=1): z = 4, 8         mean 6, median 6, std sqrt(8)
#   the point (2.0, 2.0) lies on the upper-right edge and belongs to cell (1, 1).
CHECK_POINTS = [(0.1, 0.1, 1.0), (0.5, 0.9, 2.0), (0.99, 0.0, 6.0), (1.5, 0.5, 10.0), (1.2, 1.7, 4.0), (2.0, 2.0, 8.0)]
CHECK = {
    "mean": [[3.0, 10.0], [np.nan, 6.0]],
    "median": [[2.0, 10.0], [np.nan, 6.0]],
    "count": [[3, 1], [0, 2]],
    "std": [[np.sqrt(7.0), np.nan], [np.nan, np.sqrt(8.0)]],
    "min": [[1.0, 10.0], [np.nan, 4.0]],
    "max": [[6.0, 10.0], [np.nan, 8.0]],
}


@pytest.mark.parametrize("stats", [P.STATISTICS, ("count", "mean", "std")])
def test_check_values(stats):
    x, y, z = np.array(CHECK_POINTS).T
    ds = grid_points(x, y, z, 1.0, bounds=(0, 0, 2, 2), statistics=stats)
    np.testing.assert_array_equal(ds.x, [0.5, 1.5])
    np.testing.assert_array_equal(ds.y, [0.5, 1.5])
    for s in stats:
        np.testing.assert_allclose(ds[s].values, CHECK[s], rtol=1e-15, equal_nan=True, err_msg=s)
    assert ds.attrs["n_points_used"] == 6 and ds.attrs["n_points_outside"] == 0


def test_matches_scipy_binned_statistic():
    rng = np.random.default_rng(3)
    x, y = rng.uniform(-7.3, 12.1, 5000), rng.uniform(3.0, 9.0, 5000)
    z = rng.normal(100, 5, 5000)
    ds = grid_points(x, y, z, 0.7, statistics=("mean", "median", "count", "std", "min", "max"))
    r = ds.attrs["resolution"]
    xe = ds.attrs["grid_x0_edge"] + r * np.arange(ds.sizes["x"] + 1)
    ye = ds.attrs["grid_y0_edge"] + r * np.arange(ds.sizes["y"] + 1)
    assert np.all(np.diff(ds.x) > 0) and np.all(np.diff(ds.y) > 0)
    for stat, ref in [("mean", "mean"), ("median", "median"), ("count", "count"), ("min", "min"), ("max", "max"),
                      ("std", lambda v: np.std(v, ddof=1) if len(v) > 1 else np.nan)]:
        exp = binned_statistic_2d(y, x, z, ref, bins=[ye, xe]).statistic
        if stat != "count":
            exp[binned_statistic_2d(y, x, z, "count", bins=[ye, xe]).statistic == 0] = np.nan
        np.testing.assert_allclose(ds[stat].values, exp, rtol=1e-12, atol=1e-12, equal_nan=True, err_msg=stat)


def test_empty_cells_nan_count_zero():
    ds = grid_points([0.5, 9.5], [0.5, 9.5], [1.0, 2.0], 1.0)
    assert ds.sizes == {"y": 10, "x": 10}
    assert int(ds["count"].sum()) == 2 and int((ds["count"] == 0).sum()) == 98
    assert np.isnan(ds["mean"].values).sum() == 98 and np.isnan(ds["median"].values).sum() == 98
    assert ds["count"].dtype.kind == "i"


def test_grid_origin_snaps_to_resolution():
    ds = grid_points([12.3, 47.9], [-3.2, 5.5], [1, 2], 5.0)
    assert ds.attrs["grid_x0_edge"] == 10.0 and ds.attrs["grid_y0_edge"] == -5.0
    np.testing.assert_array_equal(ds.x, [12.5, 17.5, 22.5, 27.5, 32.5, 37.5, 42.5, 47.5])


def test_chunked_moments_exact_at_hadal_depth(monkeypatch):
    """Mean/std of 10 km depths with 1 mm spread, through many chunks and both threads: no cancellation."""
    monkeypatch.setattr(P, "_CHUNK", 64)
    rng = np.random.default_rng(5)
    n = 20_000
    cell = rng.integers(0, 4, n)
    x = cell + 0.5
    y = np.full(n, 0.5)
    z = 10_000.0 + rng.normal(0, 1e-3, n)
    for threads in (1, 2):
        ds = grid_points(x, y, z, 1.0, bounds=(0, 0, 4, 1), statistics=("count", "mean", "std"), threads=threads)
        for c in range(4):
            v = z[cell == c]
            assert ds["count"].values[0, c] == len(v)
            assert ds["mean"].values[0, c] == pytest.approx(np.mean(v), abs=1e-11)
            assert ds["std"].values[0, c] == pytest.approx(np.std(v, ddof=1), rel=1e-8)


def test_fast_and_sorted_paths_agree():
    rng = np.random.default_rng(9)
    x, y, z = rng.uniform(0, 50, 3000), rng.uniform(0, 20, 3000), rng.normal(-1400, 0.3, 3000)
    a = grid_points(x, y, z, 2.0, statistics=("count", "mean", "std"))
    b = grid_points(x, y, z, 2.0, statistics=("count", "mean", "std", "median"))
    for s in ("count", "mean", "std"):
        np.testing.assert_allclose(a[s], b[s], rtol=1e-12, equal_nan=True)


def test_nonfinite_points_dropped_and_counted():
    x = np.array([0.5, np.nan, 1.5, 2.5, 0.2])
    y = np.array([0.5, 0.5, np.inf, 0.5, 0.7])
    z = np.array([1.0, 2.0, 3.0, -np.inf, 5.0])
    for stats in (("count", "mean"), ("median", "count")):
        ds = grid_points(x, y, z, 1.0, statistics=stats)
        assert ds.attrs["n_points_nonfinite"] == 3 and ds.attrs["n_points_used"] == 2
        assert ds.sizes["x"] == 1 and int(ds["count"].sum()) == 2


def test_points_outside_bounds_counted():
    ds = grid_points([0.5, 5.0, -0.1, 1.0], [0.5, 0.5, 0.5, 1.0], [1, 2, 3, 4], 1.0, bounds=(0, 0, 1, 1))
    assert ds.attrs["n_points_outside"] == 2
    assert int(ds["count"].sum()) == 2  # (1.0, 1.0) is on the upper-right edge: inside


@pytest.mark.parametrize(
    "kwargs, match",
    [
        ({"x": [], "y": [], "z": []}, "empty"),
        ({"x": [np.nan, 1.0], "y": [1.0, np.inf], "z": [1.0, 2.0]}, "NaN/inf"),
        ({"x": [1.0, 1.0, 1.0], "y": [0.0, 1.0, 2.0], "z": [1, 2, 3]}, "degenerate"),
        ({"x": [0.0, 1.0], "y": [0.0, 1.0], "z": [1, 2], "resolution": 0}, "positive"),
        ({"x": [0.0, 1.0], "y": [0.0, 1.0], "z": [1, 2], "resolution": -1.0}, "positive"),
        ({"x": [0.0, 1.0], "y": [0.0, 1.0], "z": [1, 2], "resolution": float("nan")}, "positive"),
        ({"x": [0.0, 1e6], "y": [0.0, 1e6], "z": [1, 2], "resolution": 0.01}, "exceeds the limit"),
        ({"x": [0.0, 1.0], "y": [0.0, 1.0], "z": [1]}, "same length"),
        ({"x": [0.0, 1.0], "y": [0.0, 1.0], "z": [1, 2], "bounds": (0, 0, 0, 1)}, "degenerate"),
        ({"x": [0.0, 1.0], "y": [0.0, 1.0], "z": [1, 2], "statistics": ("mode",)}, "unknown"),
    ],
)
def test_bad_input_clear_errors(kwargs, match):
    kw = {"resolution": 1.0, **kwargs}
    with pytest.raises(InputError, match=match) as ei:
        grid_points(kw.pop("x"), kw.pop("y"), kw.pop("z"), kw.pop("resolution"), **kw)
    assert "\n" not in str(ei.value) and isinstance(ei.value, HadalError)


def test_max_cells_message_names_size():
    with pytest.raises(InputError, match=r"1,000 x 1,000 = 1,000,000 cells"):
        make_grid_spec(1.0, (0, 0, 1000, 1000), max_cells=999_999)


def test_robust_outlier_mask_finds_spikes_only():
    rng = np.random.default_rng(2)
    idx = np.repeat(np.arange(50), 20)
    z = rng.normal(0, 1, idx.size)
    spikes = rng.choice(idx.size, 25, replace=False)
    z[spikes] += rng.choice([-1, 1], 25) * rng.uniform(15, 50, 25)
    m = robust_outlier_mask(idx, z, 3.5)
    assert set(np.flatnonzero(m)) >= set(spikes)
    assert m.sum() - 25 <= 10  # <= 1 % false positives: a 20-point MAD is itself noisy
    # small cells are never judged
    assert not robust_outlier_mask(np.array([0, 0]), np.array([0.0, 100.0])).any()


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_cell_robust_tests_match_a_per_cell_median_loop(seed):
    """robust_outlier_mask and typical_cell_sigma (from one shared cell_robust_stats, as the multibeam spike test
    calls them, and each on its own) against a plain loop over the cells with np.median: unsorted cells of 1-40
    points, ties (quantised values), a callable floor."""
    from hadal.grid.points import cell_robust_stats, typical_cell_sigma

    rng = np.random.default_rng(seed)
    idx = rng.integers(0, 300, 4000) * 7  # sparse cell ids, random order
    z = np.round(rng.standard_t(3, idx.size) * 2.0, 1)  # heavy tails and ties
    k, min_count = 3.0, 4

    def floor(med):
        return 0.05 * np.abs(med) + 0.2

    want = np.zeros(idx.size, bool)
    mads = []
    for c in np.unique(idx):
        sel = np.flatnonzero(idx == c)
        med = np.median(z[sel])
        mad = np.median(np.abs(z[sel] - med))
        if sel.size >= 5:
            mads.append(1.4826 * mad)
        if sel.size >= min_count:
            want[sel] = np.abs(z[sel] - med) > k * max(1.4826 * mad, float(floor(np.array([med]))[0]))
    assert 0 < want.sum() < want.size // 10  # the oracle flags some, not most
    stats = cell_robust_stats(idx, z)
    for st in (stats, None):
        np.testing.assert_array_equal(robust_outlier_mask(idx, z, k, floor=floor, min_count=min_count, stats=st), want)
        assert typical_cell_sigma(idx, z, 5, stats=st) == pytest.approx(float(np.median(mads)), rel=1e-12)


def test_compiled_cell_robust_stats_match_lexsort_and_pandas(monkeypatch):
    """The compiled cell_robust_stats (from 32768 points on) against np.lexsort's order, pandas' group medians and
    MADs (an independent oracle) and the NumPy path field by field: random order, sparse cell ids, cells of 1 to
    ~300 points (the insertion sort, the merge sort above 24 and the scratch growth above 64), ties."""
    import pandas as pd

    from hadal.grid.points import cell_robust_stats

    rng = np.random.default_rng(11)
    small = rng.integers(0, 20_000, 60_000) * 3
    big = np.repeat(np.array([1, 7, 30_001]), [300, 65, 25])  # cells past the insertion sort and the scratch size
    idx = rng.permutation(np.concatenate([small, big]))
    z = np.round(rng.standard_t(3, idx.size) * 3.0 - 6000.0, 1)  # heavy tails and many ties
    assert P._partition_kernels() is not None and idx.size >= P._COMPILED_MIN_POINTS
    st = cell_robust_stats(idx, z)
    np.testing.assert_array_equal(st.order, np.lexsort((z, idx)))
    g = pd.Series(z).groupby(idx)
    med = g.median()
    mad = (pd.Series(z) - med.reindex(idx).to_numpy()).abs().groupby(idx).median()
    np.testing.assert_array_equal(st.median, med.to_numpy())
    np.testing.assert_array_equal(st.mad, mad.to_numpy())
    np.testing.assert_array_equal(st.counts, g.size().to_numpy())
    monkeypatch.setattr(P, "_partition_kernels", lambda: None)
    ref = cell_robust_stats(idx, z)
    for f in ref._fields:
        np.testing.assert_array_equal(getattr(st, f), getattr(ref, f), err_msg=f)


def test_cell_robust_stats_with_nan_keep_lexsort_order():
    """A NaN value (public robust_outlier_mask input) keeps np.lexsort's order (NaN last in its cell) also where the
    compiled path would otherwise run."""
    from hadal.grid.points import cell_robust_stats

    rng = np.random.default_rng(5)
    idx = rng.integers(0, 5000, 40_000)
    z = rng.normal(0.0, 1.0, idx.size)
    z[::997] = np.nan
    st = cell_robust_stats(idx, z)
    np.testing.assert_array_equal(st.order, np.lexsort((z, idx)))


def test_ill_conditioned_cells_recomputed_exactly(monkeypatch):
    """Cells 10 km from the shift with 1 mm spread and quantised (identical) values: exact std."""
    calls = []
    orig = P._exact_cells
    monkeypatch.setattr(P, "_exact_cells", lambda *a, **k: calls.append(1) or orig(*a, **k))
    rng = np.random.default_rng(8)
    n = 3000
    cell = rng.integers(0, 3, n)
    z = np.where(cell == 0, 0.0, 10_000.0) + rng.normal(0, 1e-3, n)
    z[cell == 2] = 10_000.001  # identical values: std exactly 0
    ds = grid_points(cell + 0.5, np.full(n, 0.5), z, 1.0, bounds=(0, 0, 3, 1), statistics=("count", "mean", "std"))
    assert calls, "the exact second pass was not used"
    for c in range(3):
        v = z[cell == c]
        assert ds["std"].values[0, c] == pytest.approx(np.std(v, ddof=1), rel=1e-12, abs=1e-11)
        assert ds["mean"].values[0, c] == pytest.approx(np.mean(v), rel=1e-15)


@pytest.mark.parametrize("check_inside", [True, False])
def test_compiled_kernel_matches_the_bincount_reference(check_inside):
    """The fused numba pass and the np.bincount path give the same counts, and sums to rounding,
    including NaN/inf points, points outside the grid and points exactly on its upper/right edge."""
    from hadal.grid.points import GridSpec, _cell_sums_numba, _cell_sums_numpy, _numba_kernel

    kernel = _numba_kernel()
    if kernel is None:
        pytest.skip("numba not installed")
    rng = np.random.default_rng(7)
    n = 300_000
    x, y = rng.uniform(-5, 105, n), rng.uniform(-5, 55, n)
    z = rng.normal(-4000.0, 2.0, n)
    x[:10], y[:10] = 100.0, 50.0  # on the upper/right edge: joins the last cell
    x[10:20] = np.nan
    z[20:30] = np.inf
    spec = GridSpec(x0=0.0, y0=0.0, resolution=0.5, nx=200, ny=100)
    ref = _cell_sums_numpy(x, y, z, spec, -4000.0, check_inside, False, True, 2)
    for threads in (1, 2):
        got = _cell_sums_numba(kernel, x, y, z, spec, -4000.0, check_inside, threads)
        np.testing.assert_array_equal(got[0], ref[0])
        np.testing.assert_allclose(got[1], ref[1], rtol=1e-10, atol=1e-9)
        np.testing.assert_allclose(got[2], ref[2], rtol=1e-10, atol=1e-9)
        assert got[3:] == ref[3:] and got[3] == 20


def _pandas_oracle(x, y, z, x0, y0, res, nx, ny, ddof=1):
    """Independent per-cell statistics: cells by np.digitize on explicit edges (upper/right edge point in the
    last cell, as binned_statistic_2d does), statistics by pandas groupby."""
    import pandas as pd

    ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(z)
    xe, ye = x0 + res * np.arange(nx + 1), y0 + res * np.arange(ny + 1)
    ok &= (x >= xe[0]) & (x <= xe[-1]) & (y >= ye[0]) & (y <= ye[-1])
    ix = np.clip(np.digitize(x[ok], xe) - 1, 0, nx - 1)
    iy = np.clip(np.digitize(y[ok], ye) - 1, 0, ny - 1)
    g = pd.Series(z[ok]).groupby(iy * nx + ix)
    full = {}
    for stat, s in (("count", g.count()), ("mean", g.mean()), ("median", g.median()), ("std", g.std(ddof=ddof)),
                    ("min", g.min()), ("max", g.max())):
        a = np.zeros(nx * ny, np.int64) if stat == "count" else np.full(nx * ny, np.nan)
        a[s.index.to_numpy()] = s.to_numpy()
        full[stat] = a.reshape(ny, nx)
    return full


def _jittered_points(rng, n, nx, ny, res, x0=0.0, y0=0.0):
    """Points well inside random cells (no rounding question at cell edges), a Poisson count per cell
    with a few crowded cells (> 24 points: the sort branch) and a few on the grid's upper/right edge."""
    cx = rng.integers(0, nx, n)
    cy = rng.integers(0, ny, n)
    cx[: n // 20] = 3  # crowded cells
    cy[: n // 20] = rng.integers(0, 3, n // 20)
    x = x0 + (cx + 0.5 + rng.uniform(-0.45, 0.45, n)) * res
    y = y0 + (cy + 0.5 + rng.uniform(-0.45, 0.45, n)) * res
    x[-5:], y[-5:] = x0 + nx * res, y0 + ny * res
    z = rng.normal(-8000.0, 3.0, n).round(2)  # ties: medians of equal middle values
    return x, y, z


@pytest.mark.parametrize("no_numba", [False, True])
def test_all_statistics_match_pandas_groupby(monkeypatch, no_numba):
    """The compiled partitioned path (and the NumPy reference without numba) against pandas, with NaN/inf
    points, points outside explicit bounds, crowded cells, even and odd counts, tied values."""
    if no_numba:
        monkeypatch.setenv("HADAL_NO_NUMBA", "1")
    elif P._partition_kernels() is None:
        pytest.skip("numba not installed")
    rng = np.random.default_rng(11)
    nx, ny, res = 70, 40, 0.5
    x, y, z = _jittered_points(rng, 60_000, nx, ny, res, x0=-10.0, y0=20.0)
    x[100:110] = np.nan
    z[110:120] = -np.inf
    x[120:130] = -10.0 - 3.0  # outside
    bounds = (-10.0, 20.0, -10.0 + nx * res, 20.0 + ny * res)
    exp = _pandas_oracle(x, y, z, -10.0, 20.0, res, nx, ny)
    for threads in (1, 2):
        ds = grid_points(x, y, z, res, bounds=bounds, statistics=P.STATISTICS, threads=threads)
        assert ds.attrs["n_points_nonfinite"] == 20 and ds.attrs["n_points_outside"] == 10
        assert ds.attrs["n_points_used"] == 60_000 - 30
        for s in P.STATISTICS:
            np.testing.assert_allclose(ds[s].values, exp[s], rtol=1e-13, atol=1e-9, equal_nan=True, err_msg=s)
        assert int(ds["count"].max()) > 24


def test_reduce_cells_compiled_matches_reference_and_pandas():
    import pandas as pd

    if P._partition_kernels() is None:
        pytest.skip("numba not installed")
    rng = np.random.default_rng(12)
    n, m = 50_000, 30_000
    idx = rng.integers(0, m, n)
    idx[:2000] = 17
    z = rng.normal(10_000.0, 1e-3, n)
    got = reduce_cells(idx, z, m, P.STATISTICS, ddof=1)
    ref = P._reduce_cells_numpy(idx, z, m, P.STATISTICS, ddof=1)
    g = pd.Series(z).groupby(idx)
    for s in P.STATISTICS:
        np.testing.assert_allclose(got[s], ref[s], rtol=1e-12, equal_nan=True, err_msg=s)
        o = {"count": g.count(), "mean": g.mean(), "median": g.median(), "std": g.std(), "min": g.min(),
             "max": g.max()}[s]
        # pandas' one-pass (Welford) std carries ~eps * 10 km = 2e-12 absolute error here
        np.testing.assert_allclose(got[s][o.index.to_numpy()], o.to_numpy(), rtol=1e-12, atol=1e-11, err_msg=s)
    for c in rng.choice(np.unique(idx), 50):  # brute force, cell by cell
        v = z[idx == c]
        assert got["median"][c] == np.median(v) and got["mean"][c] == pytest.approx(np.mean(v), abs=2e-12)
        if len(v) > 1:
            assert got["std"][c] == pytest.approx(np.std(v, ddof=1), rel=1e-6, abs=1e-13)
    # 10 km values with 1 micrometre-scale spread: the two-pass std has no cancellation
    v = z[idx == 17]
    assert got["std"][17] == pytest.approx(np.std(v, ddof=1), rel=1e-9)
    assert got["mean"][17] == pytest.approx(np.mean(v), abs=1e-11)
    with pytest.raises(InputError, match="cell indices"):
        reduce_cells(np.full(5000, m), z[:5000], m)


def test_random_order_takes_the_partitioned_path_with_the_same_result():
    """Points in random order over a grid whose sums exceed the cache go through the partitioned kernels;
    survey order through the single pass; both equal the pandas oracle (count/mean/std)."""
    if P._partition_kernels() is None:
        pytest.skip("numba not installed")
    rng = np.random.default_rng(13)
    nx, ny, res = 300, 200, 1.0
    x, y, z = _jittered_points(rng, 200_000, nx, ny, res)
    z = 10_000.0 + rng.normal(0, 1e-3, len(z))
    spec = make_grid_spec(res, (0, 0, nx, ny))
    order = np.lexsort((x, np.floor(y)))
    assert P._scattered(x, y, spec) and not P._scattered(x[order], y[order], spec)
    exp = _pandas_oracle(x, y, z, 0.0, 0.0, res, nx, ny)
    for xs, ys, zs in ((x, y, z), (x[order], y[order], z[order])):
        ds = grid_points(xs, ys, zs, res, bounds=(0, 0, nx, ny), statistics=("count", "mean", "std"))
        np.testing.assert_array_equal(ds["count"].values, exp["count"])
        np.testing.assert_allclose(ds["mean"].values, exp["mean"], rtol=1e-15, atol=1e-11, equal_nan=True)
        np.testing.assert_allclose(ds["std"].values, exp["std"], rtol=1e-8, atol=1e-11, equal_nan=True)  # pandas: Welford
        cnt, mean, m2, bad, out = P.cell_moments(xs, ys, zs, spec)
        assert (m2[cnt == 0] == 0).all() and bad == 0 and out == 0


def test_partition_in_many_chunks_matches_the_reference(monkeypatch):
    """The chunked partition (many chunks of a few points per block, NaN/inf and outside points in them) and the
    one-pass block M2 (with its two-pass fallback for a cell whose first value is far from the others) equal the
    NumPy reference."""
    if P._partition_kernels() is None:
        pytest.skip("numba not installed")
    monkeypatch.setattr(P, "_PART_CHUNK", 1000)
    monkeypatch.setattr(P, "_MIN_SEGMENT", 1)
    rng = np.random.default_rng(21)
    nx, ny, res = 400, 300, 1.0
    n = 120_003
    x, y = rng.uniform(0, nx, n), rng.uniform(0, ny, n)
    z = rng.normal(-6000.0, 0.2, n)
    x[3005:3500:7] = np.nan
    y[3007:3900:11] = ny + 5.0  # outside
    x[:2000], y[:2000] = 10.5, 20.5  # one crowded cell: an outlier first, then mm spread
    z[0] = -5000.0
    z[1:2000] = rng.normal(-6000.0, 1e-3, 1999)
    spec = make_grid_spec(res, (0, 0, nx, ny))
    idx, zz, bad, out = P.point_indices(x, y, z, spec)
    moments = ("count", "mean", "std")
    for stats in (moments, P.STATISTICS):
        ref = P._reduce_cells_numpy(idx, zz, spec.n_cells, stats)
        got, b2, o2 = P.cell_stats(x, y, z, spec, stats)
        assert (b2, o2) == (bad, out)
        red = reduce_cells(idx, zz, spec.n_cells, stats)
        for s in stats:
            np.testing.assert_allclose(got[s], ref[s], rtol=1e-12, equal_nan=True, err_msg=s)
            np.testing.assert_allclose(red[s], ref[s], rtol=1e-12, equal_nan=True, err_msg=s)
    c = 20 * nx + 10
    v = zz[idx == c]
    assert got["std"][c] == pytest.approx(np.std(v, ddof=1), rel=1e-12)
    cnt, mean, m2, _, _ = P.cell_moments(x, y, z, spec)
    np.testing.assert_allclose(m2[c], np.var(v) * len(v), rtol=1e-12)


def test_distinct_xy_matches_numpy_unique_rows():
    """distinct_xy (lexsort + neighbour comparison) returns np.unique(..., axis=0)'s rows, in its order."""
    from hadal.grid.points import distinct_xy

    rng = np.random.default_rng(7)
    x = np.round(rng.uniform(0, 1, 20_000), 2)  # many exact duplicates and shared x with different y
    y = np.round(rng.uniform(0, 1, 20_000), 2)
    x[::5] = 0.5
    want = np.unique(np.column_stack([x, y]), axis=0)
    got = distinct_xy(x, y)
    assert got.shape == want.shape and got.dtype == np.float64
    np.testing.assert_array_equal(got, want)
    assert distinct_xy(np.array([]), np.array([])).shape == (0, 2)
    np.testing.assert_array_equal(distinct_xy([1.0], [2.0]), [[1.0, 2.0]])
