"""Laser clouds -> 10 mm elevation grids (Sangekar et al. SIII-A)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from hadal.errors import InputError
from hadal.grid import G_RES_M, grid_laser


def _cloud(n=60_000, seed=0, outliers=200):
    rng = np.random.default_rng(seed)
    x, y = rng.uniform(0, 1.0, n), rng.uniform(0, 0.5, n)
    z = -1400.0 + 0.05 * x + 0.002 * rng.normal(size=n)  # 5 % slope, 2 mm noise
    bump = (x - 0.5) ** 2 + (y - 0.25) ** 2 < 0.05**2  # a 5 cm tall, 10 cm wide boulder
    z[bump] += 0.05
    pts = np.column_stack([x, y, z])
    out = rng.choice(n, outliers, replace=False)
    pts[out, 2] += rng.uniform(0.3, 1.0, outliers)  # returns from particles above the seafloor
    return pts, bump, out


def test_grid_is_uniform_10mm_and_resolves_boulder():
    pts, bump, _ = _cloud()
    ds = grid_laser(pts)
    assert G_RES_M == 0.01 and ds.attrs["resolution"] == 0.01
    np.testing.assert_allclose(np.diff(ds.x), 0.01)
    np.testing.assert_allclose(np.diff(ds.y), 0.01)
    assert ds.sizes == {"y": 50, "x": 100}
    assert set(ds.data_vars) == {"elevation_m", "elevation_std_m", "count"}
    top = float(ds["elevation_m"].sel(x=0.5, y=0.25, method="nearest"))
    side = float(ds["elevation_m"].sel(x=0.5, y=0.45, method="nearest"))
    assert top - side == pytest.approx(0.05, abs=0.005)
    # outliers removed by open3d statistical outlier removal: no cell far above the surface
    expected = -1400.0 + 0.05 * ds.x + 0.05 * (((ds.x - 0.5) ** 2 + (ds.y - 0.25) ** 2) < 0.04**2)
    resid = (ds["elevation_m"] - expected).values
    assert np.nanmax(np.abs(resid)) < 0.06
    assert 150 <= ds.attrs["n_points_outliers"] <= 220  # edge points flagged by SOR stay
    assert ds["elevation_m"].attrs["units"] == "m"


def test_unmapped_cells_are_nan():
    pts, _, _ = _cloud(n=30_000, outliers=0)
    keep = ~((pts[:, 0] > 0.2) & (pts[:, 0] < 0.4))  # a 20 cm gap between scan lines
    ds = grid_laser(pts[keep], sor_neighbors=0)
    gap = ds.sel(x=slice(0.21, 0.39))
    assert np.isnan(gap["elevation_m"]).all() and (gap["count"] == 0).all()
    assert 0 < ds.attrs["mapped_fraction"] < 1
    assert ds.attrs["n_points_used"] == keep.sum()


def test_voxel_downsampling_option():
    pts, _, _ = _cloud(n=50_000, outliers=0)
    ds = grid_laser(pts, voxel_size_m=0.005, sor_neighbors=0)
    assert ds.attrs["n_points_after_voxel"] < 50_000
    assert int(ds["count"].sum()) == ds.attrs["n_points_after_voxel"]


def test_bad_clouds():
    with pytest.raises(InputError, match="empty"):
        grid_laser(np.zeros((0, 3)))
    with pytest.raises(InputError, match=r"\(N, 3\)"):
        grid_laser(np.zeros((10, 2)))
    with pytest.raises(InputError, match="NaN/inf"):
        grid_laser(np.full((5, 3), np.nan))
    with pytest.raises(InputError, match="must hold numbers"):
        grid_laser(np.array([["a", "b", "c"]] * 30))
    with pytest.raises(InputError, match="degenerate"):
        grid_laser(np.column_stack([np.zeros(50), np.linspace(0, 1, 50), np.zeros(50)]), sor_neighbors=0)
    with pytest.raises(InputError, match="exceeds the limit"):
        grid_laser(np.array([[0, 0, 0], [500.0, 500.0, 1.0]]), sor_neighbors=0)
    pts, _, _ = _cloud(n=2000, outliers=0)
    pts[:10, 2] = np.nan
    ds = grid_laser(pts, sor_neighbors=0)
    assert ds.attrs["n_points_nonfinite"] == 10 and int(ds["count"].sum()) == 1990


def test_sample_dive_laser_submap_against_truth(small_dive):
    """The sample submap: 10 mm grid inside the true elevation range, its swath gap and hole unmapped."""
    from hadal.grid import read_point_cloud

    raw = small_dive
    truth = json.loads((raw / "truth.json").read_text())["laser"]["submaps"][0]
    ds = grid_laser(read_point_cloud(raw / truth["file"]))
    assert ds.attrs["n_points_input"] == truth["n_points"]
    el = ds["elevation_m"]
    assert truth["z_min"] - 0.005 <= float(el.min()) and float(el.max()) <= truth["z_max"] + 0.005
    assert ds.attrs["n_points_outliers"] < 0.02 * truth["n_points"]
    g0, g1 = truth["swath_gaps_x_m"][0]
    gap = el.sel(x=slice(g0 + 0.02, g1 - 0.02))
    assert np.isnan(gap).all()
    hx, hy, hr = truth["holes_xyr_m"][0]
    xx, yy = np.meshgrid(el.x.values, el.y.values)
    inner = np.hypot(xx - hx, yy - hy) < hr - 0.03
    assert inner.sum() > 50 and np.isnan(el.values[inner]).all()
    assert float(ds["elevation_std_m"].median()) < 3 * truth["range_noise_m"]
