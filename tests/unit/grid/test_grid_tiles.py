"""Out-of-core gridding (hadal.grid.tiles, issue 48): the tiled grid equals the in-memory grid bit for bit.

Oracles: the in-memory functions (:func:`hadal.grid.points.grid_points`, :func:`hadal.grid.multibeam._dtm_layers`)
and an independent pandas groupby of the points by cell for count/mean/std/median/min/max.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from hadal.errors import InputError
from hadal.grid import points as P
from hadal.grid.multibeam import _dtm_layers
from hadal.grid.tiles import (
    TilePartition,
    TileScheme,
    choose_tile_cells,
    dtm_layers_tiled,
    grid_tiled,
    iter_array_chunks,
    partition_chunks,
)

ALL = ("mean", "median", "count", "std", "min", "max")
MOMENTS = ("count", "mean", "std")


def _points(n: int, seed: int = 0, *, res: float = 2.0, ext=(100.0, 70.0)):
    """Points over ``(0, 0, *ext)`` with a share exactly on cell edges (so on tile seams too), on the grid's
    upper/right edge, NaN/inf and outside, deep values with mm spread (a hard case for the moments)."""
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(0, ext[0], n), rng.uniform(0, ext[1], n)
    e = rng.random(n) < 0.05
    x[e] = res * rng.integers(0, int(ext[0] / res) + 1, e.sum())  # on vertical cell edges, incl. x = xmax
    e = rng.random(n) < 0.05
    y[e] = res * rng.integers(0, int(ext[1] / res) + 1, e.sum())
    z = 10_000.0 + 0.001 * rng.normal(size=n) + 0.01 * x
    z[rng.random(n) < 0.01] = 10_000.5  # ties for the median
    x[3], y[5], z[7], x[11] = np.nan, np.inf, -np.inf, ext[0] + 1.0  # non-finite and one outside
    return x, y, z


def _assert_same(a, b, stats):
    for s in stats:
        np.testing.assert_array_equal(a[s].values, b[s].values, err_msg=s)  # NaN == NaN here


@pytest.mark.parametrize("tile_cells", [1, 7, 16, 50, 1000])  # 1000: a single tile
@pytest.mark.parametrize("n", [5000, 60_000])  # below and above the compiled path's threshold
def test_tiled_equals_in_memory_grid_bit_for_bit(tile_cells, n):
    x, y, z = _points(n)
    bounds = (0.0, 0.0, 100.0, 70.0)
    ref = P.grid_points(x, y, z, 2.0, bounds=bounds, statistics=ALL)
    got = grid_tiled(iter_array_chunks(x, y, z, 777), P.make_grid_spec(2.0, bounds), ALL, tile_cells=tile_cells)
    _assert_same(ref, got, ALL)
    for k in ("n_points_used", "n_points_nonfinite", "n_points_outside"):
        assert got.attrs[k] == ref.attrs[k], k
    assert got.attrs["n_points_outside"] == 1 and got.attrs["n_points_nonfinite"] == 3
    np.testing.assert_array_equal(ref.x, got.x)
    np.testing.assert_array_equal(ref.y, got.y)


def test_tiled_moments_count_identical_mean_std_to_rounding():
    x, y, z = _points(60_000, 1)
    bounds = (0.0, 0.0, 100.0, 70.0)
    ref = P.grid_points(x, y, z, 2.0, bounds=bounds, statistics=MOMENTS)
    got = grid_tiled(iter_array_chunks(x, y, z, 5000), P.make_grid_spec(2.0, bounds), MOMENTS, tile_cells=9)
    np.testing.assert_array_equal(ref["count"].values, got["count"].values)
    np.testing.assert_allclose(got["mean"].values, ref["mean"].values, rtol=1e-15, equal_nan=True)
    # cell_moments' own bound: 1e-8 relative or 1 micrometre absolute (hadal.grid.points.M2_RTOL / STD_ATOL)
    np.testing.assert_allclose(got["std"].values, ref["std"].values, rtol=1e-8, atol=1e-6, equal_nan=True)


def test_tiled_matches_pandas_groupby():
    x, y, z = _points(40_000, 2)
    spec = P.make_grid_spec(2.0, (0.0, 0.0, 100.0, 70.0))
    got = grid_tiled(iter_array_chunks(x, y, z, 3000), spec, ALL, tile_cells=8)
    ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(z) & (x <= 100.0)
    ix = np.minimum(np.floor(x[ok] / 2.0), spec.nx - 1).astype(int)  # the upper edge joins the last cell
    iy = np.minimum(np.floor(y[ok] / 2.0), spec.ny - 1).astype(int)
    g = pd.DataFrame({"c": iy * spec.nx + ix, "z": z[ok]}).groupby("c")["z"]
    ref = {"count": g.count(), "mean": g.mean(), "std": g.std(ddof=1), "median": g.median(), "min": g.min(),
           "max": g.max()}
    for s, v in ref.items():  # pandas' std is one-pass (~1e-12 m off at 10 km depths with mm spread)
        full = np.full(spec.n_cells, 0 if s == "count" else np.nan)
        full[v.index.to_numpy()] = v.to_numpy()
        np.testing.assert_allclose(got[s].values.ravel(), full, rtol=1e-12, atol=1e-10 if s == "std" else 0,
                                   equal_nan=True, err_msg=s)
    for s in ("count", "median", "min", "max"):  # order statistics: exact
        full = np.full(spec.n_cells, 0 if s == "count" else np.nan)
        full[ref[s].index.to_numpy()] = ref[s].to_numpy()
        np.testing.assert_array_equal(got[s].values.ravel(), full, err_msg=s)


def test_without_numba_same_bits(monkeypatch):
    monkeypatch.setenv("HADAL_NO_NUMBA", "1")
    x, y, z = _points(40_000, 3)
    bounds = (0.0, 0.0, 100.0, 70.0)
    ref = P.grid_points(x, y, z, 2.0, bounds=bounds, statistics=ALL)
    got = grid_tiled(iter_array_chunks(x, y, z, 4096), P.make_grid_spec(2.0, bounds), ALL, tile_cells=11)
    _assert_same(ref, got, ALL)


def test_empty_tiles_and_clamped_extent_grid():
    """Points in two far corners: most tiles empty; a grid from the points' extent (no bounds): clamped, as
    grid_points without bounds."""
    rng = np.random.default_rng(4)
    x = np.concatenate([rng.uniform(0, 3, 40_000), rng.uniform(95, 100, 40_000)])
    y = np.concatenate([rng.uniform(0, 3, 40_000), rng.uniform(60, 70, 40_000)])
    z = rng.normal(5000, 1, len(x))
    ref = P.grid_points(x, y, z, 1.0, statistics=ALL)
    ext, _ = P.point_extent(x, y, z)
    spec = P.make_grid_spec(1.0, ext, snap=True)
    with partition_chunks(iter_array_chunks(x, y, z, 10_000), spec, tile_cells=10, check_inside=False) as part:
        assert sum(1 for c in part.tile_points if c == 0) > part.scheme.n_tiles // 2
    got = grid_tiled(iter_array_chunks(x, y, z, 10_000), spec, ALL, tile_cells=10, check_inside=False)
    _assert_same(ref, got, ALL)


def test_dtm_layers_tiled_equal_in_memory_dtm_layers(tmp_path):
    x, y, z = _points(80_000, 5)
    ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(z) & (x <= 100.0)
    x, y, z = x[ok], y[ok], z[ok]
    x[np.abs(x - 50) < 1.5] = np.nan  # an empty band: holes of 1-2 cells get filled, others not
    spec = P.make_grid_spec(2.0, (0.0, 0.0, 100.0, 70.0))
    keep = np.isfinite(x)
    idx, _ = spec.cell_index(x[keep], y[keep], check_inside=False)
    ref, ref_filled = _dtm_layers(spec, idx, z[keep], 4, 0.5, 0.001, 3.0)
    with partition_chunks(iter_array_chunks(x[keep], y[keep], z[keep], 9000), spec, tile_cells=13,
                          scratch_dir=tmp_path) as part:
        got, filled = dtm_layers_tiled(part, fill_max_cells=4)
    np.testing.assert_array_equal(ref_filled, filled)
    assert set(ref) == set(got)
    for k in ref:
        assert ref[k].dtype == got[k].dtype, k
        np.testing.assert_array_equal(ref[k], got[k], err_msg=k)
    assert list(tmp_path.iterdir()) == []  # the scratch directory is removed


def test_tile_scheme_windows_cover_the_grid_once():
    spec = P.make_grid_spec(1.0, (0.0, 0.0, 23.0, 10.0))
    sc = TileScheme(spec, 7)
    assert (sc.ntx, sc.nty) == (4, 2)
    cover = np.zeros((spec.ny, spec.nx), int)
    for t in range(sc.n_tiles):
        r0, r1, c0, c1 = sc.window(t)
        cover[r0:r1, c0:c1] += 1
        ts = sc.tile_spec(t)
        np.testing.assert_array_equal(ts.x, spec.x[c0:c1])
        np.testing.assert_array_equal(ts.y, spec.y[r0:r1])
    assert (cover == 1).all()
    assert choose_tile_cells(spec) == 23  # a grid smaller than a default tile: one tile
    big = P.make_grid_spec(1.0, (0.0, 0.0, 10_000.0, 10_000.0), max_cells=10**9)
    assert choose_tile_cells(big, expected_points=10**9) == int((2**21 / 10) ** 0.5)


def test_bad_input_one_line_errors(tmp_path):
    spec = P.make_grid_spec(1.0, (0.0, 0.0, 10.0, 10.0))
    with pytest.raises(InputError, match="NaN/inf"):
        grid_tiled([(np.full(5, np.nan), np.ones(5), np.ones(5))], spec, scratch_dir=tmp_path)
    with pytest.raises(InputError, match="no points"):
        grid_tiled([], spec, scratch_dir=tmp_path)
    with pytest.raises(InputError, match="same length"):
        grid_tiled([(np.ones(3), np.ones(2), np.ones(3))], spec, scratch_dir=tmp_path)
    with pytest.raises(InputError, match="scratch directory"):
        TilePartition(TileScheme(spec, 4), scratch_dir=tmp_path / "missing")
    with pytest.raises(InputError, match="tile_cells"):
        TileScheme(spec, 0)
    assert list(tmp_path.iterdir()) == []


def test_full_disk_is_a_one_line_error(tmp_path, monkeypatch):
    from hadal.grid import tiles

    monkeypatch.setattr(tiles, "_free_bytes", lambda p: 1000)
    spec = P.make_grid_spec(1.0, (0.0, 0.0, 10.0, 10.0))
    with pytest.raises(InputError, match="GiB free") as e:
        grid_tiled([(np.ones(5), np.ones(5), np.ones(5))], spec, scratch_dir=tmp_path)
    assert "\n" not in str(e.value)
    assert list(tmp_path.iterdir()) == []


def _seam_soundings(n: int, seed: int, *, res: float = 20.0, tile_cells: int = 16, ext=(2000.0, 1500.0)):
    """A sloping, wavy seafloor with spikes a share of which sit within a few metres of tile seams (every
    ``res * tile_cells`` metres, both axes), and a patch of soundings on a lattice (equal neighbour distances:
    the tie rule matters)."""
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(0, ext[0], n), rng.uniform(0, ext[1], n)
    lat = rng.random(n) < 0.05
    x[lat] = 600.0 + 2.0 * rng.integers(0, 40, lat.sum())  # a lattice across the seam at x = 640
    y[lat] = 620.0 + 2.0 * rng.integers(0, 40, lat.sum())
    z = 3000 + 0.05 * x + 5 * np.sin(y / 100) + rng.normal(0, 0.3, n)
    sp = rng.choice(n, n // 400, replace=False)
    seam = res * tile_cells
    h = len(sp) // 2
    x[sp[:h]] = seam * rng.integers(1, int(ext[0] // seam), h) + rng.uniform(-3, 3, h)
    y[sp[h:]] = seam * rng.integers(1, int(ext[1] // seam), len(sp) - h) + rng.uniform(-3, 3, len(sp) - h)
    z[sp] += rng.choice([-1, 1], len(sp)) * rng.uniform(5, 50, len(sp))
    return x, y, z, sp


@pytest.mark.parametrize(("tile_cells", "halo_cells"), [(16, None), (5, 1), (3, None)])
def test_tiled_spike_flags_equal_in_memory_on_seams(tmp_path, tile_cells, halo_cells):
    """Spikes on tile seams: the tiled spike test (halo; halo 1 cell forces the halo to grow for some soundings)
    flags exactly the soundings the in-memory test of the whole set flags."""
    from hadal.grid.multibeam import spike_mask
    from hadal.grid.tiles import spike_flags_tiled

    x, y, z, sp = _seam_soundings(60_000, 7, tile_cells=tile_cells)
    ext, _ = P.point_extent(x, y, z)
    spec = P.make_grid_spec(20.0, ext, snap=True)
    idx, _ = spec.cell_index(x, y, check_inside=False)
    ref, ref_sigma0 = spike_mask(idx, x, y, z)
    assert ref[sp].mean() > 0.9  # the seam spikes are caught
    part = TilePartition(TileScheme(spec, tile_cells), scratch_dir=tmp_path, check_inside=False, with_xy=True)
    with part:
        for c in iter_array_chunks(x, y, z, 7000):
            part.add(*c)
        n_sp, sigma0 = spike_flags_tiled(part, halo_cells=halo_cells)
        got = np.zeros(len(z), bool)
        for t in range(part.scheme.n_tiles):
            if part.tile_points[t]:
                got[part.tile_xy_of(t)[2]] = ~part.kept_of(t)
    assert sigma0 == ref_sigma0
    np.testing.assert_array_equal(got, ref)
    assert n_sp == int(ref.sum())
    assert list(tmp_path.iterdir()) == []


def test_tiled_neighbour_test_equals_brute_force_reference(tmp_path):
    """Independent oracle: the NumPy reference of the neighbour test on brute-force neighbours (all pairwise
    distances, ties by input index), on a lattice (many equal distances) cut by seams every 3 cells."""
    from hadal.grid.multibeam import knn_spike_mask_reference
    from hadal.grid.tiles import knn_spike_flags_tile

    rng = np.random.default_rng(8)
    g = np.arange(0.0, 60.0, 1.5)
    x, y = (a.ravel() for a in np.meshgrid(g, g))
    extra = rng.uniform(0, 59, (2, 800))
    x, y = np.concatenate([x, extra[0]]), np.concatenate([y, extra[1]])
    z = 100 + 0.1 * x + rng.normal(0, 0.2, len(x))
    z[rng.choice(len(z), 30, replace=False)] += 8.0
    d2 = (x[:, None] - x[None]) ** 2 + (y[:, None] - y[None]) ** 2
    np.fill_diagonal(d2, np.inf)
    nbr = np.lexsort((np.broadcast_to(np.arange(len(x)), d2.shape), d2), axis=1)[:, :16]
    ref = knn_spike_mask_reference(x, y, z, k=4.0, neighbours=16, floor=0.5, neighbour_index=nbr)
    spec = P.make_grid_spec(5.0, P.point_extent(x, y, z)[0], snap=True)
    with TilePartition(TileScheme(spec, 3), scratch_dir=tmp_path, check_inside=False, with_xy=True) as part:
        part.add(x, y, z)
        got = np.zeros(len(z), bool)
        for t in range(part.scheme.n_tiles):
            if part.tile_points[t]:
                got[part.tile_xy_of(t)[2]] = knn_spike_flags_tile(part, t, neighbours=16, k=4.0, floor=0.5)
    assert ref.sum() >= 25
    np.testing.assert_array_equal(got, ref)


@pytest.mark.parametrize("bounds", [None, (100.0, 200.0, 1900.0, 1400.0)])
def test_grid_multibeam_tiled_equals_grid_multibeam(tmp_path, bounds):
    """The whole tiled DTM (spike test with halos, layers, hole filling, counts) equals grid_multibeam's."""
    from hadal.grid.multibeam import grid_multibeam
    from hadal.grid.tiles import grid_multibeam_tiled

    x, y, z, _ = _seam_soundings(80_000, 9)
    x[:3] = np.nan
    ref = grid_multibeam(x, y, z, 20.0, bounds=bounds)
    if bounds is None:
        ok = np.isfinite(x)
        spec = P.make_grid_spec(20.0, P.point_extent(x[ok], y[ok], z[ok])[0], snap=True)
    else:
        spec = P.make_grid_spec(20.0, bounds)
    got = grid_multibeam_tiled(iter_array_chunks(x, y, z, 9999), spec, check_inside=bounds is not None,
                               tile_cells=16, scratch_dir=tmp_path)
    assert set(ref.data_vars) == set(got.data_vars)
    for v in ref.data_vars:
        np.testing.assert_array_equal(ref[v].values, got[v].values, err_msg=v)
    for k, v in ref.attrs.items():
        assert got.attrs[k] == v or (v != v and got.attrs[k] != got.attrs[k]), k
    assert got.attrs["n_soundings_spikes"] > 100
    assert list(tmp_path.iterdir()) == []


def test_tiled_spike_flags_sparse_halo_grows(tmp_path, monkeypatch):
    """Sparse soundings (a few a tile): a 1-cell halo cannot hold 16 neighbours, so it grows (more halo reads
    than tiles) and the flags still equal the in-memory ones."""
    from hadal.grid import tiles
    from hadal.grid.multibeam import spike_mask

    x, y, z, _ = _seam_soundings(4000, 10, tile_cells=5)
    spec = P.make_grid_spec(20.0, P.point_extent(x, y, z)[0], snap=True)
    idx, _ = spec.cell_index(x, y, check_inside=False)
    ref, _ = spike_mask(idx, x, y, z)
    calls = []
    real = tiles._halo_points
    monkeypatch.setattr(tiles, "_halo_points", lambda *a: calls.append(a[1]) or real(*a))
    with TilePartition(TileScheme(spec, 5), scratch_dir=tmp_path, check_inside=False, with_xy=True) as part:
        part.add(x, y, z)
        tiles.spike_flags_tiled(part, halo_cells=1)
        got = np.zeros(len(z), bool)
        for t in range(part.scheme.n_tiles):
            if part.tile_points[t]:
                got[part.tile_xy_of(t)[2]] = ~part.kept_of(t)
        assert len(calls) > 2 * sum(1 for c in part.tile_points if c)
    np.testing.assert_array_equal(got, ref)


def test_dtm_stage_out_of_core_above_the_budget_same_dtm(small_dive, tmp_path, monkeypatch):
    """The dtm stage's gridding (make_dtm) on the small sample dive: under a memory budget its soundings' gridding
    exceeds (but their reading does not: the readers' own budget, hadal.grid.sonar.SOUNDING_READ_COST, counts
    their fixed cost and the soundings kept) it grids out of core (tiles recorded) and gives the in-memory DTM's
    arrays and counts."""
    import tempfile

    from hadal.dive import load_dive, resolve_source
    from hadal.settings import GridParams as Params
    from hadal.stages.grid import DTM_BYTES_PER_SOUNDING, make_dtm

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # the tiles' scratch directory
    dive, raw = load_dive(small_dive)
    files = [resolve_source(raw, f) for f in dive.sources.multibeam]
    ref = make_dtm(files, dive.frame(), Params(dtm_resolution_m=20.0))
    assert "n_tiles" not in ref.attrs
    n = ref.attrs["n_soundings_input"]
    got = make_dtm(files, dive.frame(), Params(dtm_resolution_m=20.0),
                   memory_limit_bytes=0.8 * DTM_BYTES_PER_SOUNDING * n)
    assert got.attrs["n_tiles"] >= 1
    for v in ref.data_vars:
        np.testing.assert_array_equal(ref[v].values, got[v].values, err_msg=v)
    for k in ("n_soundings_input", "n_soundings_spikes", "n_soundings_used", "n_cells_filled"):
        assert ref.attrs[k] == got.attrs[k], k
    assert list(tmp_path.iterdir()) == []


def test_partition_with_positions_numpy_reference(tmp_path, monkeypatch):
    """The partition with positions (x, y, input index) by the compiled kernel equals the NumPy reference's,
    and every tile's points are in their tile's cells, in input order."""
    x, y, z = _points(20_000, 11)
    spec = P.make_grid_spec(2.0, (0.0, 0.0, 100.0, 70.0))
    got = []
    for no_numba in (False, True):
        if no_numba:
            monkeypatch.setenv("HADAL_NO_NUMBA", "1")
        with TilePartition(TileScheme(spec, 7), scratch_dir=tmp_path, with_xy=True) as part:
            for c in iter_array_chunks(x, y, z, 3333):
                part.add(*c)
            got.append([(*part.tile_points_of(t), *part.tile_xy_of(t)) for t in range(part.scheme.n_tiles)])
            for t, (cells, zt, xt, yt, gi) in enumerate(got[-1]):
                r0, _, c0, c1 = part.scheme.window(t)
                idx, _ = spec.cell_index(xt, yt)
                np.testing.assert_array_equal(idx, (r0 + cells // (c1 - c0)) * spec.nx + c0 + cells % (c1 - c0))
                np.testing.assert_array_equal(zt, z[gi])
                assert (np.diff(gi) > 0).all()
    for a, b in zip(*got, strict=True):
        for u, v in zip(a, b, strict=True):
            np.testing.assert_array_equal(u, v)


@pytest.mark.parametrize("per_cell", [3, 40, 300])  # insertion sort, selection, NumPy sort sizes
def test_block_median_by_selection_equals_pandas(per_cell):
    """The compiled per-cell median (selection of the middle values, no sort) against pandas' group median,
    with ties and even and odd counts; min/max too."""
    rng = np.random.default_rng(per_cell)
    m = 4000 // per_cell + 7
    idx = rng.integers(0, m, 40_000 + per_cell * 50)
    z = np.round(rng.normal(1000, 1, len(idx)), 2)  # many ties
    got = P.reduce_cells(idx, z, m, ("median", "min", "max", "count"), compiled=True)
    g = pd.DataFrame({"c": idx, "z": z}).groupby("c")["z"]
    for s, ref in (("median", g.median()), ("min", g.min()), ("max", g.max())):
        full = np.full(m, np.nan)
        full[ref.index.to_numpy()] = ref.to_numpy()
        np.testing.assert_array_equal(got[s], full, err_msg=s)


def test_dtm_stage_streams_soundings_to_disk_same_dtm(tmp_path, monkeypatch):
    """Soundings streamed to disk as they are read (hadal.grid.soundings.SpilledSoundings: issue 48, readers into
    tiles): three xyz files read in chunks of 3 000, with NaN, implausible depths (a fill value) and automatic
    resolution. Out of core from the first chunk, and spilled mid-read (above a budget the second file crosses),
    the DTM equals the in-memory one (oracle: hadal.grid.multibeam.grid_multibeam through make_dtm) array for
    array, resolution choice and counts included; no chunk larger than the reader's went to disk, the accumulator
    never held more than the spill threshold, and the scratch directory is removed."""
    import tempfile

    from hadal.geo import LocalFrame
    from hadal.grid import soundings as S
    from hadal.grid.sonar import ColumnAccumulator
    from hadal.settings import GridParams as Params
    from hadal.stages import grid as G
    from hadal.stages.grid import make_dtm

    scratch = tmp_path / "scratch"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    rng = np.random.default_rng(48)
    files, n_all = [], 0
    for k, n in enumerate((7_000, 11_000, 5_000)):
        x, y = rng.uniform(0, 900, n) + 300 * k, rng.uniform(0, 600, n)
        z = 5000 + 0.05 * x - 0.03 * y + rng.normal(0, 0.4, n)
        z[rng.random(n) < 0.002] += 80.0  # spikes
        z[rng.random(n) < 0.001] = 99999.0  # a fill value: implausible, dropped and counted
        x[rng.random(n) < 0.001] = np.nan
        f = tmp_path / f"mb{k}.xyz"
        np.savetxt(f, np.column_stack([x, y, z]), fmt="%.3f")
        files.append(f)
        n_all += n
    from hadal.dive import SourceFile

    hints = [SourceFile(path=f.name, crs="local", z_positive="down") for f in files]
    frame = LocalFrame(11.3, 142.2)
    p = Params(dtm_resolution_m="auto")
    ref = make_dtm(files, frame, p, hints, chunk_points=3_000, out_of_core=False)
    assert ref.attrs["n_soundings_implausible"] > 0 and "n_tiles" not in ref.attrs
    assert ref.attrs["n_soundings_spikes"] > 0 and ref.attrs["n_soundings_nonfinite"] > 0

    sizes: list[int] = []
    add = S.SpilledSoundings.add
    monkeypatch.setattr(S.SpilledSoundings, "add", lambda self, x, y, z: (sizes.append(len(z)), add(self, x, y, z)))
    held: list[int] = []
    acc_add = ColumnAccumulator.add
    monkeypatch.setattr(ColumnAccumulator, "add", lambda self, *c: (acc_add(self, *c), held.append(self.n)))
    # the in-memory threshold: 10 000 soundings, crossed in file 2 (a budget the readers' fixed cost fits in)
    monkeypatch.setattr(G, "DTM_BYTES_PER_SOUNDING", 2**30 / 10_000.5)
    for kw in ({"out_of_core": True}, {"memory_limit_bytes": 2**30}):
        sizes.clear()
        held.clear()
        got = make_dtm(files, frame, p, hints, chunk_points=3_000, **kw)
        assert got.attrs["n_tiles"] >= 1, kw
        assert sum(sizes) == n_all and max(sizes) <= (3_000 if kw.get("out_of_core") else 10_000), kw
        assert max(held, default=0) <= (0 if kw.get("out_of_core") else 10_000), kw
        for v in ref.data_vars:
            np.testing.assert_array_equal(ref[v].values, got[v].values, err_msg=f"{v} {kw}")
        for k in ("n_soundings_input", "n_soundings_nonfinite", "n_soundings_implausible", "n_soundings_spikes",
                  "n_soundings_used", "n_cells_filled", "resolution_m", "resolution_choice"):
            assert ref.attrs[k] == got.attrs[k], (k, kw)
        assert list(scratch.iterdir()) == [], kw


def test_dtm_stage_streamed_most_soundings_implausible_one_line(tmp_path, monkeypatch):
    """Out of core, soundings mostly beyond any ocean depth (feet) are refused in the in-memory path's one line."""
    import tempfile

    from hadal.dive import SourceFile
    from hadal.geo import LocalFrame
    from hadal.settings import GridParams as Params
    from hadal.stages.grid import make_dtm

    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    rng = np.random.default_rng(1)
    f = tmp_path / "feet.xyz"
    np.savetxt(f, np.column_stack([rng.uniform(0, 500, 2000), rng.uniform(0, 500, 2000),
                                   rng.uniform(30000, 36000, 2000)]), fmt="%.3f")
    hint = [SourceFile(path=f.name, crs="local")]
    msgs = []
    for ooc in (False, True):
        with pytest.raises(InputError, match=r"feet\?") as e:
            make_dtm([f], LocalFrame(11.3, 142.2), Params(dtm_resolution_m=20.0), hint, out_of_core=ooc)
        msgs.append(str(e.value))
    assert msgs[0] == msgs[1] and "\n" not in msgs[1]
    assert [p.name for p in tmp_path.iterdir()] == ["feet.xyz"]


@pytest.mark.parametrize("step", [1, 3, 7, 1000])
def test_spilled_soundings_read_back_and_subsample(tmp_path, step):
    """SpilledSoundings: chunks read back equal what was written minus the implausible soundings, the statistics
    equal NumPy's on the whole arrays, and the automatic resolution's subsample is ``x[ok][::step]`` whatever the
    chunk boundaries (oracle: NumPy on the concatenated arrays)."""
    from hadal.grid.prior import MAX_ABS_DEPTH_M
    from hadal.grid.soundings import SpilledSoundings

    rng = np.random.default_rng(step)
    x, y, z = rng.uniform(-50, 50, 10_007), rng.uniform(0, 9, 10_007), rng.uniform(10, 11_000, 10_007)
    x[rng.random(x.size) < 0.01] = np.nan
    z[rng.random(x.size) < 0.01] = np.inf
    z[rng.random(x.size) < 0.01] = -1e6
    with SpilledSoundings(tmp_path) as sp:
        for a in range(0, x.size, 997):
            sp.add(x[a:a + 997], y[a:a + 997], z[a:a + 997])
        keep = ~(np.isfinite(z) & (np.abs(z) > MAX_ABS_DEPTH_M))
        got = [np.concatenate(c) for c in zip(*sp.chunks(1234), strict=True)]
        for g, w in zip(got, (x[keep], y[keep], z[keep]), strict=True):
            np.testing.assert_array_equal(g, w)
        ok = keep & np.isfinite(x) & np.isfinite(y)
        assert (sp.n, sp.n_implausible, sp.n_xy) == (x.size, int((~keep).sum()), int(ok.sum()))
        assert sp.extent_xy == (x[ok].min(), y[ok].min(), x[ok].max(), y[ok].max())
        ok3 = ok & np.isfinite(z)
        assert sp.extent == (x[ok3].min(), y[ok3].min(), x[ok3].max(), y[ok3].max())
        xs, ys = sp.xy_subsample(step, chunk_points=1111)
        np.testing.assert_array_equal(xs, x[ok][::step])
        np.testing.assert_array_equal(ys, y[ok][::step])
        assert sp.abs_depth_median() == np.median(np.abs(z))
        d = sp.dir
    assert not d.exists()
