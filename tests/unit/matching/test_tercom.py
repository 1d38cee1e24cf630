"""TERCOM (COR/MAD/MSD, Eqs. 15-17): FFT route vs a direct loop, recovery of known offsets, warnings, bad input."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import xarray as xr
from factories import AnalyticTerrain, wiggly_track

from hadal.errors import InputError
from hadal.matching import MapGrid, refine_tercom, tercom, tercom_direct

H = 20.0


@pytest.fixture(scope="module")
def terrain():
    t = AnalyticTerrain.random(3)
    z, x, y = t.grid(110, 90, H, noise_m=0.5, seed=1)
    return t, MapGrid.from_any(z, x, y)


def _case(t, g, seed=0, n=50, length=900.0, bias=-4.0, noise=1.0, dr_noise=3.0, center=(1100.0, 900.0)):
    """Measured profile and DR track of a random track whose bounding box is centred on ``center``.

    Returns (profile, dr_track, true_start)."""
    rng = np.random.default_rng(seed)
    tr = wiggly_track(n, length, seed=seed)
    start = np.asarray(center) - (tr.min(axis=0) + tr.max(axis=0)) / 2 + rng.uniform(-H / 2, H / 2, 2)
    true = tr + start
    assert true.min() > 0 and true[:, 0].max() < g.x_m[-1] and true[:, 1].max() < g.y_m[-1]
    prof = t(true[:, 0], true[:, 1]) + bias + rng.normal(0, noise, n)
    dr = tr + rng.normal(0, dr_noise, tr.shape) + np.array([437.0, -211.0])  # DR frame offset (launch-relative)
    return prof, dr, start


@pytest.mark.parametrize("criterion", ["msd", "mad", "cor"])
@pytest.mark.parametrize("estimate_bias", [True, False])
@pytest.mark.parametrize("heading", [0.0, 4.5])
def test_fft_equals_direct_loop(terrain, criterion, estimate_bias, heading):
    t, g = terrain
    z = g.depth_m.copy()
    z[40:44, 50:60] = np.nan  # holes in the map must be masked out
    gh = MapGrid(z, g.x_m, g.y_m, g.resolution_m)
    prof, dr, _ = _case(t, g, seed=5, n=30, length=500.0)
    res = tercom(prof, dr, gh, criterion, estimate_bias=estimate_bias, headings_deg=[heading], min_valid_fraction=0.9)
    starts = np.argwhere(np.ones(gh.shape, bool))[::7]
    direct = tercom_direct(prof, dr, gh, starts, criterion, estimate_bias=estimate_bias, heading_deg=heading,
                           min_valid_fraction=0.9)
    fft = res.surface[starts[:, 0], starts[:, 1]]
    assert np.array_equal(np.isnan(direct), np.isnan(fft))  # same feasible set (holes, map edges)
    assert np.isnan(direct).any() and np.isfinite(direct).sum() > 100
    ok = np.isfinite(direct)
    np.testing.assert_allclose(fft[ok], direct[ok], rtol=1e-9, atol=1e-6)


def test_msd_recovers_start_within_one_cell_with_bias_noise_and_dr_offset(terrain):
    t, g = terrain
    errs = []
    for seed in range(6):
        prof, dr, start = _case(t, g, seed=seed, center=(800.0 + 97 * seed, 700.0 + 71 * seed))
        r = tercom(prof, dr, g)
        errs.append(max(abs(r.start_x_m - start[0]), abs(r.start_y_m - start[1])))
        assert r.bias_m == pytest.approx(4.0, abs=1.5)  # map minus measured
        assert not r.mismatch and r.separation_ratio > 1.2
        assert r.sigma_x_m >= H / np.sqrt(12) - 1e-9 and r.sigma_m < 3 * H
        # the whole map is searched: the surface is defined over most of it
        assert np.isfinite(r.surface).mean() > 0.3
    assert max(errs) <= H


def test_matched_track_apply_and_geometry(terrain):
    t, g = terrain
    prof, dr, _ = _case(t, g, seed=2, dr_noise=0.0)
    r = tercom(prof, dr, g)
    m = r.apply(dr)
    assert m[0] == pytest.approx([r.start_x_m, r.start_y_m])
    np.testing.assert_allclose(np.diff(m, axis=0), np.diff(dr, axis=0), atol=1e-9)  # heading 0: a translation


def test_heading_search_recovers_rotated_track(terrain):
    t, g = terrain
    rng = np.random.default_rng(7)
    tr = wiggly_track(80, 1500, seed=11)
    a = np.deg2rad(6.0)  # DR heading is 6 deg off: true = DR rotated clockwise by 6 deg
    rot = np.column_stack([tr[:, 0] * np.cos(a) + tr[:, 1] * np.sin(a), -tr[:, 0] * np.sin(a) + tr[:, 1] * np.cos(a)])
    start = np.array([1100.0, 900.0]) - (rot.min(axis=0) + rot.max(axis=0)) / 2
    true = rot + start
    assert true.min() > 0 and true[:, 0].max() < g.x_m[-1] and true[:, 1].max() < g.y_m[-1]
    prof = t(true[:, 0], true[:, 1]) + rng.normal(0, 0.5, tr.shape[0])
    r0 = tercom(prof, tr, g)
    r = tercom(prof, tr, g, headings_deg=np.arange(-9, 9.01, 0.5), precision="double")
    assert len(r.heading_scores) == 37
    assert abs(r.heading_deg - 6.0) <= 1.0
    assert r.score < r0.score
    assert max(abs(r.start_x_m - start[0]), abs(r.start_y_m - start[1])) <= H
    m = r.apply(tr)
    assert np.median(np.hypot(*(m - true).T)) < 1.5 * H
    # mixed precision (float32 screening, float64 check of the best 3 headings) returns the same fix
    rm = tercom(prof, tr, g, headings_deg=np.arange(-9, 9.01, 0.5), precision="mixed")
    assert (rm.start_row, rm.start_col, rm.heading_deg) == (r.start_row, r.start_col, r.heading_deg)
    assert rm.score == pytest.approx(r.score, rel=1e-9)
    np.testing.assert_allclose(rm.surface_all_headings, r.surface_all_headings, rtol=1e-3, atol=1e-2)


def test_repetitive_terrain_triggers_mismatch_warning():
    x = np.arange(120) * H
    y = np.arange(60) * H
    xx, yy = np.meshgrid(x, y)
    z = 10_000 + 50 * np.sin(2 * np.pi * xx / 400.0) + 30 * np.sin(2 * np.pi * yy / 300.0)  # periodic: ambiguous
    tr = wiggly_track(40, 600, seed=1)
    start = np.array([1000.0, 400.0])
    prof = 10_000 + 50 * np.sin(2 * np.pi * (tr[:, 0] + start[0]) / 400.0) + 30 * np.sin(2 * np.pi * (tr[:, 1] + start[1]) / 300.0)
    r = tercom(prof, tr, MapGrid.from_any(z, x, y))
    assert r.mismatch and any("mismatch" in w for w in r.warnings)
    assert r.separation_ratio < 1.2


def test_cor_is_as_written_and_misleads_on_deep_terrain(terrain):
    """Eq. (15) without centring is dominated by the mean depth (the paper: 'COR may lead to a mismatch')."""
    t, g = terrain
    prof, dr, _ = _case(t, g, seed=3, n=20, length=400.0)
    r = tercom(prof, dr, g, "cor", estimate_bias=False)
    j = (r.start_row, r.start_col)
    assert r.surface[j] == np.nanmax(r.surface)
    direct = tercom_direct(prof, dr, g, [j], "cor", estimate_bias=False)
    assert r.surface[j] == pytest.approx(direct[0], rel=1e-12)


def test_region_restricts_search_and_edge_warning(terrain):
    t, g = terrain
    prof, dr, start = _case(t, g, seed=0, center=(900.0, 700.0))
    sx, sy = start
    r = tercom(prof, dr, g, region=(sx - 200, sx + 200, sy - 200, sy + 200))
    assert max(abs(r.start_x_m - sx), abs(r.start_y_m - sy)) <= H
    assert np.isfinite(r.surface).sum() <= 21 * 21
    assert np.isnan(r.surface[:, : int(g.col_of(sx - 220))]).all() and np.isnan(r.surface[: int(g.row_of(sy - 220))]).all()
    r2 = tercom(prof, dr, g, region=(sx + 100, sx + 400, sy - 200, sy + 200))  # true start outside: best on the edge
    assert any("edge" in w for w in r2.warnings)


@pytest.mark.parametrize(
    ("kwargs", "match"),
    [
        ({"profile_depth": [1.0, 2.0, 3.0], "track_xy": np.zeros((4, 2))}, "3 depths"),
        ({"profile_depth": [1.0, np.nan, 3.0], "track_xy": np.zeros((3, 2))}, "NaN"),
        ({"profile_depth": [1.0, 2.0], "track_xy": np.zeros((2, 2))}, "at least 3"),
        ({"profile_depth": [1.0, 2.0, 3.0], "track_xy": np.zeros(3)}, "shape"),
        ({"profile_depth": [1.0, 2.0, 3.0], "track_xy": [[0, 0], [5000, 0], [9000, 0]]}, "no feasible"),
        ({"profile_depth": [1.0, 2.0, 3.0], "track_xy": np.zeros((3, 2)), "criterion": "lsq"}, "criterion"),
        ({"profile_depth": [1.0, 2.0, 3.0], "track_xy": np.zeros((3, 2)), "precision": "half"}, "precision"),
        ({"profile_depth": [1.0, 2.0, 3.0], "track_xy": np.zeros((3, 2)), "region": (1e6, 2e6, 0, 1)}, "overlap"),
    ],
)
def test_bad_input_raises_clear_errors(terrain, kwargs, match):
    _, g = terrain
    with pytest.raises(InputError, match=match):
        tercom(dtm=g, **kwargs)


def test_map_validation():
    with pytest.raises(InputError, match="square"):
        MapGrid.from_any(np.ones((3, 3)), [0, 1, 2], [0, 2, 4])
    with pytest.raises(InputError, match="no finite"):
        MapGrid.from_any(np.full((3, 3), np.nan), [0, 1, 2], [0, 1, 2])
    # descending y (north-up rasters) is flipped, not rejected
    z = np.arange(9.0).reshape(3, 3)
    g = MapGrid.from_any(xr.DataArray(z, dims=("y", "x"), coords={"x": [0.0, 1, 2], "y": [2.0, 1, 0]}))
    assert g.y_m[0] == 0 and g.depth_m[0, 0] == 6.0


def test_sample_dive_truth_terrain_and_dr_recover_bottom_start(small_dive):
    """Sample dive: true seafloor depths (+ noise) along the bottom phase, the vehicle's own dead reckoning
    (csv/dr.csv: heading bias, scale error, correlated velocity noise) and the true terrain as a map 4.74 m
    too deep: the whole bottom track, coarse search with headings +-9 deg, then the sub-cell refinement
    (heading, scale), recovers the start of the bottom track within one map cell (20 m)."""
    truth = json.loads((small_dive / "truth.json").read_text())
    st = truth["bottom_track_start"]
    with xr.open_dataset(small_dive / "truth" / "terrain.nc") as ds:
        lx, ly = truth["launch"]["x_east_m"], truth["launch"]["y_north_m"]
        ds = ds.sel(x=slice(lx - 3000, lx + 3000), y=slice(ly - 2500, ly + 3500)).load()  # keep the test fast
    g = MapGrid.from_any(ds["depth_m"] + 4.74)
    trk = pd.read_parquet(small_dive / "truth" / "track.parquet")
    bottom = trk[trk["phase"] == "bottom"].sort_values("time")
    bottom = bottom.assign(time=bottom["time"].dt.as_unit("ns"))
    dr = pd.read_csv(small_dive / "csv" / "dr.csv")
    dr["time"] = pd.to_datetime(dr["time"], utc=True).dt.as_unit("ns")
    m = pd.merge_asof(bottom, dr.sort_values("time"), on="time", direction="nearest")
    from hadal.matching.fix import resample_along_track

    rng = np.random.default_rng(0)
    meas = m["seafloor_depth_m"].to_numpy() + rng.normal(0, 0.5, len(m))
    prof = resample_along_track(m["east_m"], m["north_m"], meas, g.resolution_m)
    r = tercom(prof.depth_m, prof.track_xy, g, headings_deg=np.arange(-9, 9.01, 0.5), precision="mixed",
               min_valid_fraction=0.8)
    rr = refine_tercom(prof.depth_m, prof.track_xy, g, r, heading_bounds_deg=(-9.25, 9.25))
    start = rr.apply(m[["east_m", "north_m"]].to_numpy()[:1])[0]
    assert np.hypot(start[0] - st["x_east_m"], start[1] - st["y_north_m"]) <= g.resolution_m
    assert rr.bias_m == pytest.approx(4.74, abs=1.0) and not rr.mismatch
    assert rr.scale == pytest.approx(1 / (1 + truth["dr_error"]["scale_error"]), abs=0.01)


def test_refinement_recovers_sub_cell_offset_heading_and_scale():
    """A track rotated by 1.3 deg and stretched by 2 % at a sub-cell offset: the coarse search can only
    snap to cells and steps; the refinement recovers the pose (bilinear map, Nelder-Mead)."""
    rng = np.random.default_rng(3)
    t = AnalyticTerrain.random(5, relief_m=200.0)
    g = MapGrid.from_any(*t.grid(160, 160, H))
    tr = wiggly_track(120, 1800.0, seed=11)
    true_start = np.array([1013.7, 1207.3])
    a, sc = np.deg2rad(1.3), 0.98
    rel = tr - tr[0]
    rot = np.column_stack([rel[:, 0] * np.cos(a) + rel[:, 1] * np.sin(a), -rel[:, 0] * np.sin(a) + rel[:, 1] * np.cos(a)])
    true = rot * sc + true_start
    prof = t(true[:, 0], true[:, 1]) - 3.0 + rng.normal(0, 0.2, len(tr))
    r = tercom(prof, tr, g, headings_deg=np.arange(-3, 3.01, 0.5))
    rr = refine_tercom(prof, tr, g, r, heading_bounds_deg=(-3.25, 3.25), scale_bounds=(0.95, 1.05))
    coarse_err = np.hypot(r.start_x_m - true_start[0], r.start_y_m - true_start[1])
    fine_err = np.hypot(rr.start_x_m - true_start[0], rr.start_y_m - true_start[1])
    assert fine_err < 2.0 and fine_err < coarse_err
    assert rr.heading_deg == pytest.approx(1.3, abs=0.1) and rr.scale == pytest.approx(0.98, abs=0.002)
    assert rr.bias_m == pytest.approx(3.0, abs=0.2) and rr.refinement["seeds"] >= 1
    with pytest.raises(InputError, match="MSD only"):
        refine_tercom(prof, tr, g, tercom(prof, tr, g, "cor"))
    # without bias estimation the refined fit keeps bias 0 (the user's setting), and a narrow heading
    # range on one side of the seed is still explored (no collapsed simplex)
    rn = refine_tercom(prof, tr, g, tercom(prof, tr, g, estimate_bias=False), estimate_bias=False,
                       heading_bounds_deg=(1.2, 1.25), scale_bounds=(0.95, 1.05))
    assert rn.bias_m == 0.0 and 1.2 < rn.heading_deg <= 1.25
    # the refined start stays inside a requested region
    box = (true_start[0] + 30, true_start[0] + 200, true_start[1] - 100, true_start[1] + 100)
    rb = refine_tercom(prof, tr, g, tercom(prof, tr, g, headings_deg=np.arange(-3, 3.01, 0.5), region=box),
                       heading_bounds_deg=(-3.25, 3.25), region=box)
    assert rb.refinement is not None
    assert box[0] <= rb.start_x_m <= box[1] and box[2] <= rb.start_y_m <= box[3]


def test_real_etopo5_terrain_recovers_offset(shared_data):
    """Real relief (ETOPO5 near Bermuda) as the reference map: a noisy profile along a track is matched to its cell.

    The relief changes by hundreds of metres per cell here, so the track is laid on cell centres
    (sub-cell positions would measure the nearest-cell sampling error, not the matching)."""
    with xr.open_dataset(shared_data / "bathy-real" / "tut_bathy.nc") as ds:
        z = -ds["z"].values.astype(float)
    g = MapGrid.from_any(z, np.arange(z.shape[1]) * H, np.arange(z.shape[0]) * H)
    rng = np.random.default_rng(0)
    for _ in range(5):
        tr = np.round(wiggly_track(40, 300.0, seed=int(rng.integers(1000))) / H) * H
        start = np.round(np.array([rng.uniform(200, 1000), rng.uniform(200, 800)]) / H) * H
        true = tr + start
        prof = g.sample_bilinear(true[:, 0], true[:, 1]) + 30.0 + rng.normal(0, 5.0, len(tr))
        r = tercom(prof, tr + 1000.0, g)
        assert (r.start_x_m, r.start_y_m) == pytest.approx(tuple(start))
        assert r.bias_m == pytest.approx(-30.0, abs=5.0) and not r.mismatch


def test_mapgrid_filled_normalised_convolution():
    z = np.full((20, 20), 100.0)
    z[5:8, 5:8] = np.nan  # a hole in a flat map is filled with the flat value
    z[15, 15] = 200.0
    g = MapGrid.from_any(z, np.arange(20.0), np.arange(20.0))
    f = g.filled(1.0)
    assert np.isfinite(f.depth_m).all() and np.allclose(f.depth_m[5:8, 5:8], 100.0)
    assert f.depth_m[15, 15] == 200.0  # measured cells kept
    s = g.filled(1.0, smooth_all=True)
    assert 100.0 < s.depth_m[15, 15] < 200.0 and s.depth_m[15, 16] > 100.0  # low-passed everywhere
    assert g.filled(0.0) is g
