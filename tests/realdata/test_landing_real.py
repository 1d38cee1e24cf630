"""Landing analysis on real deep-sea laser bathymetry: Takuyo-Daigo seamount, ~1380 m (ocean-perception
landing_area_detector data, 0.10 m cells in a local metric frame; read directly with rasterio)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import xarray as xr

from hadal.landing import Vehicle, analyse_submap
from hadal.landing.exclusion import footprint_offsets

RASTER = "bathy-real/LAD_Takuyo_B1_raster_100mm.tif"


@pytest.fixture(scope="module")
def takuyo(shared_data) -> xr.DataArray:
    rasterio = pytest.importorskip("rasterio")
    path = shared_data / RASTER
    if not path.is_file():
        pytest.skip(f"{path} not present")
    with rasterio.open(path) as ds:
        depth = ds.read(1).astype(float)
        nodata = ds.nodata
    depth[depth == (0.0 if nodata is None else nodata)] = np.nan
    ny, nx = depth.shape
    cell = 0.1  # the CRS tag wrongly says EPSG:4326; the cells are 0.10 m in a local frame
    # row 0 is the northern edge: y decreases with the row index
    y = -(np.arange(ny) + 0.5) * cell
    x = (np.arange(nx) + 0.5) * cell
    return xr.DataArray(depth, dims=("y", "x"), coords={"y": y, "x": x}, attrs={"units": "m", "positive": "down"})


@pytest.fixture(scope="module")
def result(takuyo):
    return analyse_submap(takuyo, max_cell_fraction=0.2)  # 0.10 m cells: explicit override of the 1/10 rule


def test_real_depth_range_and_slope(takuyo, result):
    d = takuyo.values
    assert 1379.0 < np.nanmin(d) < np.nanmax(d) < 1382.5
    # the seamount flank: gentle overall, steeper patches; median local slope below θc
    med = np.nanmedian(result.slope_local_deg)
    assert 1.0 < med < Vehicle().critical_slope_deg
    # the overall gradient of the strip (2 m over ~28 m) is a few degrees
    fp = result.footprint_slope_deg
    assert 0.5 < np.nanmedian(fp) < 10.0


def test_real_protrusions_are_centimetric(result):
    h = result.protrusion_height_m
    # heights above the ground of the opening (a lower envelope at the vehicle scale): the seafloor texture
    # reads a couple of cm, rocks much more
    assert np.nanpercentile(np.abs(h), 50) < 0.03
    assert 0.01 < np.nanpercentile(h, 99.9) < 0.3
    assert result.protrusion_candidate.sum() > 0


def test_real_sites_and_best_heading(takuyo, result):
    s = result.sites
    assert len(s) >= 5  # the paper found sites in every submap
    assert set(s["heading_deg"]) <= set(np.linspace(-90, 90, 37))
    assert ((s["c_s"] >= 0) & (s["c_s"] <= 1.5)).all()
    assert (s["radius_m"] >= 0.3 - 1e-9).all()
    best = result.best
    assert best is not None and best["c_s"] == s["c_s"].min()
    assert 0.0 < best["c_s"] < 0.7  # the paper's range on this seamount: 0.15-0.63
    # the mapped strip runs SW-NE: the best heading follows it (cf. the paper: heading ~ mapping direction)
    z = takuyo.values
    rows, cols = np.nonzero(np.isfinite(z))
    pts = np.column_stack([cols * 0.1, -rows * 0.1])
    w, v = np.linalg.eigh(np.cov((pts - pts.mean(0)).T))
    axis = v[:, 1]
    strip_heading = math.degrees(math.atan2(axis[0], axis[1]))
    strip_heading = (strip_heading + 90) % 180 - 90
    diff = abs((best["heading_deg"] - strip_heading + 90) % 180 - 90)
    assert diff <= 30.0
    # the landing footprint lies entirely on mapped seafloor and under θc
    # small grid: analysed on its own cells (no along-track re-gridding); row/col index the arrays
    assert result.frame_rotation_deg == 0.0
    i, j = int(best["row"]), int(best["col"])
    xw, yw = result.to_world(result.x_m[j], result.y_m[i])
    assert (float(xw), float(yw)) == pytest.approx((best["x_m"], best["y_m"]), abs=1e-9)
    # the site lies on mapped input cells (world -> input grid)
    gi = int(np.argmin(np.abs(takuyo["y"].values - best["y_m"])))
    gj = int(np.argmin(np.abs(takuyo["x"].values - best["x_m"])))
    assert np.isfinite(takuyo.values[gi, gj])
    rr, cc = footprint_offsets(1.7, 0.5, best["heading_deg"] - result.frame_rotation_deg, 0.1)
    assert np.isfinite(result.elevation_m[i + rr, j + cc]).all()
    assert best["slope_deg"] <= Vehicle().critical_slope_deg
    assert -1382.0 < best["elevation_m"] < -1379.0


def test_real_heading_dependence(takuyo, result):
    # the ~3 m wide strip: the summed site area peaks for headings along it and collapses across it
    area = result.sites.groupby("heading_deg")["area_m2"].sum().reindex(result.headings_deg, fill_value=0.0)
    z = takuyo.values
    rows, cols = np.nonzero(np.isfinite(z))
    pts = np.column_stack([cols * 0.1, -rows * 0.1])
    _, v = np.linalg.eigh(np.cov((pts - pts.mean(0)).T))
    strip = (math.degrees(math.atan2(v[0, 1], v[1, 1])) + 90) % 180 - 90
    peak = float(area.idxmax())
    assert abs((peak - strip + 90) % 180 - 90) <= 15.0
    across = (strip + 180) % 180 - 90  # perpendicular heading in -90..90
    k = int(np.argmin(np.abs(((result.headings_deg - across) + 90) % 180 - 90)))
    assert area.iloc[k] < 0.2 * area.max()
