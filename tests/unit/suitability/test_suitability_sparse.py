"""Terrain suitability on a DTM gridded from sparse ship soundings (issue 43): most cells empty, the launch point
between two tracks. The region moves to the nearest evaluated blocks (said in one line, with the coverage); a DTM
with no evaluable block is skipped with a one-line reason naming its coverage, never a failure or a traceback.

Oracles: the DTM's own cells counted with numpy (coverage), the block statistics recomputed here from the DTM
cells ([TERCOM Eqs. 1-3] written out), geometry of the tracks sampled from the real ETOPO5 grid (tut_bathy.nc).
"""

from __future__ import annotations

import json
import re
import warnings

import numpy as np
import pytest
import xarray as xr

from hadal.suitability import propose_region_near, sparse_skip_reason, suitability_map


def _tracks_dtm(rows=(5, 25), ny=40, nx=60, h=100.0):
    """A DTM whose only depths are east-west track lines at ``rows`` (two cells wide), 4000-4100 m."""
    z = np.full((ny, nx), np.nan)
    rng = np.random.default_rng(3)
    for r in rows:
        z[r:r + 2, :] = 4000 + 100 * rng.random((2, nx))
    x, y = np.arange(nx) * h - nx * h / 2, np.arange(ny) * h - ny * h / 2
    return xr.Dataset({"depth_m": (("y", "x"), z)}, coords={"x": x, "y": y})


def test_region_moves_to_the_nearest_evaluated_blocks_between_tracks():
    dtm = _tracks_dtm(rows=(6, 24))  # tracks at y = -1400 m and +400 m
    s = suitability_map(dtm, 20, 30)  # 2 x 2 cell blocks: the tracks' blocks are complete, the rest empty
    ok = np.isfinite(s["std_m"].values)
    assert ok.sum() == 2 * 30 and set(np.nonzero(ok)[0]) == {3, 12}
    # an evaluated block's std is that of its 4 cells (TERCOM Eqs. 1-3, normaliser m(n-1) = 2)
    v = dtm["depth_m"].values[24:26, 0:2].ravel()
    assert s["std_m"].values[12, 0] == pytest.approx(np.sqrt(((v - v.mean()) ** 2).sum() / 2))
    # launch at (0, 0) m, between the tracks: no window of 1000 x 600 m there holds an evaluated block
    reg, note = propose_region_near(s, 0.0, 0.0, 1000.0, 600.0)
    assert "nearest evaluated block" in note and "\n" not in note
    near_y = float(s["y"].values[12])  # the track at +400 m is nearer than the one at -1400 m
    assert reg.y_min_m <= near_y <= reg.y_max_m and reg.method == "nearest evaluated blocks"
    got_km = float(re.search(r"([\d.]+) km away", note).group(1))
    assert got_km == pytest.approx(np.min(np.hypot(s["x"].values, near_y)) / 1000, abs=0.005)


def test_window_with_evaluated_blocks_is_unchanged():
    dtm = _tracks_dtm(rows=(18, 20))
    s = suitability_map(dtm, 20, 30)
    reg, note = propose_region_near(s, 0.0, 0.0, 1000.0, 600.0)
    assert note == "" and reg.method == "window"


def test_no_evaluable_block_is_a_skip_reason_naming_the_coverage():
    dtm = _tracks_dtm(rows=())
    z = dtm["depth_m"].values
    z[::4, ::4] = 4000.0  # isolated spot soundings: 1 cell in 4 of every other 2 x 2 block
    why = sparse_skip_reason(dtm, 44, 60, 0.5)
    pct = 100 * np.isfinite(z).mean()
    assert why is not None and "\n" not in why and f"{pct:.1f} % of the DTM's 40 x 60 cells" in why
    assert "0 of 600 blocks" in why
    assert sparse_skip_reason(_tracks_dtm(), 44, 60, 0.5) is None


def test_ship_track_dive_publishes_suitability_with_a_region_note(shared_data, tmp_path):
    """A dive of ship soundings in lon/lat xyz along four east-west tracks 0.1 deg apart, sampled every 0.002 deg
    from the real ETOPO5 grid: the DTM is mostly empty; suitability publishes, its region lies on a track."""
    from hadal.dive_init import scan_dive_dir, write_init
    from hadal.pipeline import make_context, run_pipeline

    with xr.open_dataset(shared_data / "bathy-real" / "tut_bathy.nc") as ds:
        z = ds["z"].load()
    lat0, lon0 = float(z["y"].mean()), float(z["x"].mean())
    rows = []
    for la in lat0 + np.array([-0.15, -0.05, 0.05, 0.15]):
        lo = np.arange(lon0 - 0.25, lon0 + 0.25, 0.002)
        dep = -z.interp(x=xr.DataArray(lo), y=xr.DataArray(np.full(lo.size, la))).values
        rows.append(np.column_stack([lo, np.full(lo.size, la), dep]))
    raw = tmp_path / "ship"
    (raw / "raw").mkdir(parents=True)
    np.savetxt(raw / "raw" / "ship_track.xyz", np.vstack(rows), fmt="%.6f %.6f %.2f")
    write_init(scan_dive_dir(raw))
    ctx = make_context(raw, tmp_path / "store")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_pipeline(ctx)
    assert {"dtm", "suitability", "report"} <= set(ctx.store.products(ctx.dive_id))
    dtm = xr.open_dataset(ctx.store.latest(ctx.dive_id, "dtm").file("dtm.nc"), engine="h5netcdf")
    cover = float(np.isfinite(dtm["depth_m"].values).mean())
    assert cover < 0.2  # mostly empty cells
    s = xr.open_dataset(ctx.store.latest(ctx.dive_id, "suitability").file("suitability.nc"), engine="h5netcdf")
    note = s.attrs["region_coverage_note"]
    assert f"{100 * cover:.1f} % of the DTM" in note
    reg = json.loads(s.attrs["proposed_region"])
    inside = (s["in_region"].values == 1) & np.isfinite(s["std_m"].values)
    assert reg["method"] == "nearest evaluated blocks" and inside.any()


def test_spot_soundings_dive_skips_suitability_in_one_line(shared_data, tmp_path):
    """Isolated spot soundings 5 km apart: no DTM block can be evaluated, suitability is skipped with the
    coverage named (the report lists it), nothing fails."""
    from hadal.dive_init import scan_dive_dir, write_init
    from hadal.pipeline import make_context, run_pipeline

    raw = tmp_path / "spots"
    (raw / "raw").mkdir(parents=True)
    lo, la = np.meshgrid(np.arange(-63.25, -62.75, 0.05), np.arange(32.35, 32.65, 0.05))
    with xr.open_dataset(shared_data / "bathy-real" / "tut_bathy.nc") as ds:
        dep = -ds["z"].interp(x=xr.DataArray(lo.ravel()), y=xr.DataArray(la.ravel())).values
    np.savetxt(raw / "raw" / "spots.xyz", np.column_stack([lo.ravel(), la.ravel(), dep]), fmt="%.6f %.6f %.2f")
    write_init(scan_dive_dir(raw))
    from hadal.settings import load_config

    cfg = load_config(None)
    cfg.grid.dtm_resolution_m = 500.0  # a user's fixed DTM resolution, finer than the spot spacing
    ctx = make_context(raw, tmp_path / "store", config=cfg)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_pipeline(ctx)
    prods = set(ctx.store.products(ctx.dive_id))
    summary = json.loads(ctx.store.latest(ctx.dive_id, "report").file("summary.json").read_text())
    skipped = {k["stage"]: k["reason"] for k in summary["skipped_stages"]}
    assert "suitability" not in prods
    assert "dtm" in prods and "no block of the DTM can be evaluated" in skipped["suitability"]
    assert "\n" not in skipped["suitability"] and "cells have a depth" in skipped["suitability"]

