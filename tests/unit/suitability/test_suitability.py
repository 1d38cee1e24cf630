"""Terrain suitability: TERCOM paper Eqs. (1)-(5) check values, block grid, proposed region."""

from __future__ import annotations

import json

import numpy as np
import pytest
import xarray as xr

from hadal.errors import InputError
from hadal.suitability import block_std_entropy, propose_region, suitability_map


@pytest.mark.parametrize(
    ("block", "sigma", "entropy"),
    [
        # 2 x 3: mean 3.5, sum of squared deviations 17.5, m(n-1) = 4 -> D = 4.375 (not 17.5/5 = 3.5)
        ([[1.0, 2, 3], [4, 5, 6]], np.sqrt(17.5 / 4), 1.6623769591928221),
        # flat: sigma 0, entropy log(mn)
        ([[10_000.0] * 4] * 3, 0.0, np.log(12)),
        # 3 x 2: m(n-1) = 3; deviations from 2: 1,0,1,1,0,1 -> 4/3
        ([[1.0, 3], [2, 2], [1, 3]], np.sqrt(4 / 3), -sum(v / 12 * np.log(v / 12) for v in (1, 3, 2, 2, 1, 3))),
    ],
)
def test_block_check_values(block, sigma, entropy):
    s, h, n = block_std_entropy(np.array(block))
    assert s == pytest.approx(sigma, rel=1e-12, abs=1e-12)
    assert h == pytest.approx(entropy, rel=1e-12)
    assert n == np.size(block)


def test_entropy_decreases_with_relief_and_needs_positive_depth():
    rng = np.random.default_rng(0)
    smooth = 10_000 + rng.normal(0, 1, (20, 20))
    rough = 10_000 + rng.normal(0, 200, (20, 20))
    s1, h1, _ = block_std_entropy(smooth)
    s2, h2, _ = block_std_entropy(rough)
    assert s2 > 100 * s1
    assert h2 < h1 < np.log(400)
    neg = smooth.copy()
    neg[0, 0] = -5.0  # elevation-like value: p_ij undefined
    assert np.isnan(block_std_entropy(neg)[1])


def test_missing_cells_use_valid_fraction():
    z = np.full((4, 4), 100.0)
    z[0, :3] = np.nan
    s, h, n = block_std_entropy(z, min_valid_fraction=0.5)
    assert (s, n) == (0.0, 13) and h == pytest.approx(np.log(13))
    assert np.isnan(block_std_entropy(z, min_valid_fraction=0.9)[0])


def _dtm(ny=40, nx=60, h=20.0, seed=1):
    rng = np.random.default_rng(seed)
    x = np.arange(nx) * h + 10.0
    y = np.arange(ny) * h - 300.0
    z = np.full((ny, nx), 10_000.0) + rng.normal(0, 0.5, (ny, nx))
    z[ny // 2 :, nx // 2 :] += rng.normal(0, 50, (ny - ny // 2, nx - nx // 2))  # rough north-east quarter
    return xr.Dataset({"depth_m": (("y", "x"), z)}, coords={"x": x, "y": y})


def test_suitability_map_blocks_and_coordinates():
    ds = _dtm()
    s = suitability_map(ds, 4, 6)
    assert s["std_m"].shape == (4, 6)
    assert s.attrs["block_rows_cells"] == 10 and s.attrs["block_cols_cells"] == 10
    assert s["x"].values[0] == pytest.approx(10.0 - 10 + 100)  # edge at x0 - h/2, centre 5 cells in
    assert s["y"].values[-1] == pytest.approx(-300 - 10 + 3.5 * 200)
    # block (0, 0) equals the direct computation on its cells
    direct = block_std_entropy(ds["depth_m"].values[:10, :10])
    assert s["std_m"].values[0, 0] == pytest.approx(direct[0]) and s["entropy"].values[0, 0] == pytest.approx(direct[1])
    ne, sw = s["std_m"].values[2:, 3:], s["std_m"].values[:2, :3]
    assert ne.min() > 10 * sw.max()
    assert (s["entropy"].values[2:, 3:].max() < s["entropy"].values[:2, :3].min())
    assert s["std_m"].attrs["units"] == "m"


def test_suitability_rejects_too_small_map_and_bad_input():
    with pytest.raises(InputError, match="too small"):
        suitability_map(_dtm(ny=10, nx=10), 44, 60)
    with pytest.raises(InputError, match="depth_m"):
        suitability_map(xr.Dataset({"z": (("y", "x"), np.ones((4, 4)))}, coords={"x": np.arange(4.0), "y": np.arange(4.0)}))


def test_propose_region_window_and_search():
    s = suitability_map(_dtm(), 4, 6)
    win = propose_region(s, 300.0, 0.0, 400.0, 300.0)
    assert win.method == "window"
    assert (win.x_min_m, win.x_max_m, win.y_min_m, win.y_max_m) == pytest.approx((100.0, 500.0, -150.0, 150.0))
    found = propose_region(s, 300.0, 0.0, 400.0, 300.0, search_radius_m=2000.0)
    assert found.mean_std_m > 10 * win.mean_std_m
    assert found.x_min_m >= 500 and found.y_min_m >= 0  # in the rough quarter
    json.dumps(found.as_dict())
    assert found.contains(found.x_min_m + 1, found.y_min_m + 1) and not found.contains(-1e6, 0)
    with pytest.raises(InputError):
        propose_region(s, 1e7, 1e7, 100.0, 100.0)


def test_real_etopo5_bermuda_rise_is_more_suitable_than_abyssal_plain(shared_data):
    """Real bathymetry (ETOPO5 near Bermuda, GMT test grid): the seamount blocks beat the abyssal plain."""
    with xr.open_dataset(shared_data / "bathy-real" / "tut_bathy.nc") as ds:
        z = -ds["z"].values.astype(float)  # elevation -> depth positive down (p_ij needs positive values)
    h = 9260.0  # 5 arc-minutes of latitude, as square cells
    dtm = xr.Dataset({"depth_m": (("y", "x"), z)}, coords={"x": np.arange(z.shape[1]) * h, "y": np.arange(z.shape[0]) * h})
    s = suitability_map(dtm, 6, 7)
    std, ent = s["std_m"].values, s["entropy"].values
    assert np.isfinite(std).all() and np.isfinite(ent).all()
    i = np.unravel_index(np.argmax(std), std.shape)
    j = np.unravel_index(np.argmin(std), std.shape)
    # the block containing the shallowest point (Bermuda platform) is the roughest
    r, c = np.unravel_index(np.argmin(z[: 6 * 10, : 7 * 10]), (60, 70))
    assert i == (r // 10, c // 10)
    assert ent[i] < ent[j] and std[i] > 20 * std[j]
