"""MRF fine matching on the vehicle's own swath (``sources.vehicle_swath``, ``match.mrf: true``) in the match stage.

Oracle: the small sample dive's ground truth. A swath is synthesised from the generator's true terrain along the true
bottom track (beams across the true course) and logged, as the vehicle's own multibeam would log it, at the
vehicle's dead-reckoned navigation (launch + dead reckoning, beams across the dead-reckoned course). The stage must
place it on the map through the fix, grid it into a 2-D patch and run MRF; the MRF start is compared with the true
position of the first bottom sample, never with the code's own output.
"""

from __future__ import annotations

import gzip
import json
import os
import shutil

import numpy as np
import pandas as pd
import pytest
import xarray as xr
import yaml

from hadal.geo import LocalFrame
from hadal.matching import MapGrid
from hadal.pipeline import make_context, run_stage


def _unit(v: np.ndarray) -> np.ndarray:
    return v / np.maximum(np.linalg.norm(v, axis=1, keepdims=True), 1e-9)


def _swath(small_dive, ctd: pd.DataFrame, frame: LocalFrame, half_width_m: float, rng) -> np.ndarray:
    """(lon, lat, depth) of a swath: true terrain under beams across the true course, logged at the dead-reckoned
    position with beams across the dead-reckoned course (every 10th bottom sample, 21 beams)."""
    b = ctd[(ctd["phase"] == "bottom")].dropna(subset=["dr_east_m", "dr_north_m"]).iloc[::10]
    truth = pd.read_parquet(small_dive / "truth" / "track.parquet")
    tt = truth["time"].astype("int64").to_numpy()
    tb = b["time"].astype("int64").to_numpy()
    true_xy = np.column_stack([np.interp(tb, tt, truth[c].to_numpy(float)) for c in ("x_east_m", "y_north_m")])
    launch = json.loads((small_dive / "truth.json").read_text())["launch"]
    dr_xy = b[["dr_east_m", "dr_north_m"]].to_numpy(float) + [launch["x_east_m"], launch["y_north_m"]]
    n_true = _unit(np.gradient(true_xy, axis=0))[:, ::-1] * [1, -1]  # across the course (right-hand normal)
    n_dr = _unit(np.gradient(dr_xy, axis=0))[:, ::-1] * [1, -1]
    off = np.linspace(-half_width_m, half_width_m, 21)
    at_true = (true_xy[:, None, :] + off[None, :, None] * n_true[:, None, :]).reshape(-1, 2)
    logged = (dr_xy[:, None, :] + off[None, :, None] * n_dr[:, None, :]).reshape(-1, 2)
    with xr.open_dataset(small_dive / "truth" / "terrain.nc") as t:
        ter = MapGrid.from_any(t["depth_m"].load())
    depth = ter.sample_bilinear(at_true[:, 0], at_true[:, 1]) + rng.normal(0, 0.5, len(at_true))
    lon, lat = frame.to_lonlat(logged[:, 0], logged[:, 1])
    ok = np.isfinite(depth)
    return np.column_stack([lon, lat, depth])[ok]


def _dive_copy(small_dive, small_run, tmp_path):
    """A raw directory of the small dive (its files linked; dive.yaml and pipeline.yaml to be rewritten) and a copy of
    the small run's store, the dive's identity record moved to the new raw directory."""
    ctx0, _ = small_run
    raw = tmp_path / "raw"
    raw.mkdir()
    for item in small_dive.iterdir():
        if item.name not in ("dive.yaml", "pipeline.yaml"):
            os.symlink(item, raw / item.name)
    store = tmp_path / "store"
    shutil.copytree(ctx0.store.root, store, symlinks=True)
    (store / ctx0.dive_id / "dive.json").unlink()
    return raw, store


def _run_match_with_swath(small_dive, small_run, tmp_path, half_width_m: float):
    _, pins = small_run
    raw, store = _dive_copy(small_dive, small_run, tmp_path)
    dive = yaml.safe_load((small_dive / "dive.yaml").read_text())
    frame = LocalFrame(dive["map_frame"]["origin_latitude_deg"], dive["map_frame"]["origin_longitude_deg"])
    ctd = pd.read_parquet(pins["ctd"].file("ctd.parquet"), columns=["time", "phase", "dr_east_m", "dr_north_m"])
    sw = _swath(small_dive, ctd, frame, half_width_m, np.random.default_rng(3))
    (raw / "swath").mkdir()
    with gzip.open(raw / "swath" / "vehicle_swath.xyz.gz", "wt") as fh:
        np.savetxt(fh, sw, fmt="%.9f %.9f %.3f")
    dive["sources"]["vehicle_swath"] = ["swath/vehicle_swath.xyz.gz"]
    (raw / "dive.yaml").write_text(yaml.safe_dump(dive))
    cfg = yaml.safe_load((small_dive / "pipeline.yaml").read_text()) or {}
    cfg.setdefault("match", {})["mrf"] = True
    (raw / "pipeline.yaml").write_text(yaml.safe_dump(cfg))
    ctx = make_context(raw, store)
    out = run_stage("match", ctx)
    fix = json.loads(out["match"].file("fix.json").read_text())
    truth = pd.read_parquet(small_dive / "truth" / "track.parquet")
    t0 = pd.Timestamp(fix["start"]["time"]).value
    true0 = np.array([np.interp(t0, truth["time"].astype("int64"), truth[c]) for c in ("x_east_m", "y_north_m")])
    return fix, true0


def test_mrf_on_the_vehicle_swath_is_within_a_cell_of_the_truth_or_refused_for_texture(small_dive, small_run, tmp_path):
    """A 240 m swath (12 cells of 20 m) on the small sample dive: the stage places it by the fix and grids the first 40
    cells of track into a 2-D patch (sounded cells with four sounded neighbours >= 50 %). MRF either moves the start
    to within one cell of the true position, or refuses for the reason its texture check gives (Cramér-Rao 1 sigma
    above half a cell against this noisy 1.3-soundings-a-cell DTM), never applies a shift that misses."""
    fix, true0 = _run_match_with_swath(small_dive, small_run, tmp_path, 120.0)
    m = fix["mrf"]
    assert m["patch_source"] == "vehicle_swath" and m["n_swath_soundings_not_placed"] == 0, m
    assert m["patch_length_m"] == 800.0 and 0 < m["n_swath_soundings_in_patch"] < m["n_swath_soundings"]
    assert m["coverage"] >= 0.5, m
    err_fix = float(np.hypot(fix["start"]["x_east_m"] - true0[0], fix["start"]["y_north_m"] - true0[1]))
    if m["applied"]:
        err_mrf = float(np.hypot(m["start"]["x_east_m"] - true0[0], m["start"]["y_north_m"] - true0[1]))
        print(f"\nstart error: posterior fix {err_fix:.1f} m, MRF on the vehicle swath {err_mrf:.1f} m")
        assert err_mrf < 20.0
    else:
        print(f"\nstart error: posterior fix {err_fix:.1f} m; MRF refused: {m['warnings']}")
        assert any("too little terrain texture" in w for w in m["warnings"]), m


def test_a_narrow_vehicle_swath_is_refused_with_the_reason(small_dive, small_run, tmp_path):
    """A 30 m swath is under two 20 m cells wide: no 2-D patch at the map's cell size, MRF not run, said so."""
    fix, _ = _run_match_with_swath(small_dive, small_run, tmp_path, 15.0)
    m = fix["mrf"]
    assert m["patch_source"] == "vehicle_swath" and not m["applied"] and m["coverage"] < 0.5
    assert "too narrow or sparse" in m["reason"]
    assert any("too narrow or sparse" in w for w in fix["warnings"])


def test_vehicle_swath_outside_the_bottom_track_is_a_one_line_error(small_dive, small_run, tmp_path):
    """Soundings not positioned by the vehicle's navigation (here 50 km away): a one-line InputError naming the file."""
    from hadal.errors import InputError

    raw, store = _dive_copy(small_dive, small_run, tmp_path)
    dive = yaml.safe_load((small_dive / "dive.yaml").read_text())
    (raw / "swath").mkdir()
    lon0, lat0 = dive["launch"]["longitude_deg"] + 0.5, dive["launch"]["latitude_deg"]
    (raw / "swath" / "far.xyz").write_text("".join(f"{lon0 + 1e-4 * i:.7f} {lat0:.7f} 10900.0\n" for i in range(50)))
    dive["sources"]["vehicle_swath"] = ["swath/far.xyz"]
    (raw / "dive.yaml").write_text(yaml.safe_dump(dive))
    cfg = yaml.safe_load((small_dive / "pipeline.yaml").read_text()) or {}
    cfg.setdefault("match", {})["mrf"] = True
    (raw / "pipeline.yaml").write_text(yaml.safe_dump(cfg))
    with pytest.raises(InputError, match=r"far\.xyz: none of the 50 vehicle swath soundings") as ei:
        run_stage("match", make_context(raw, store))
    assert "\n" not in str(ei.value)


@pytest.mark.parametrize("err_cells", [(1.4, -0.9), (-6.0, 4.0)])
def test_swath_placed_by_a_wrong_fix_is_corrected_by_mrf_on_real_terrain(shared_data, err_cells):
    """Library chain on a real grid (ETOPO5 tut_bathy): a vehicle swath logged in its dead-reckoned navigation (heading
    bias, scale error and a drift growing with time) is placed by a fix whose start is wrong by a known offset and
    whose pose and drift are right (:func:`swath_on_map`), gridded and matched by MRF (:func:`mrf_step`): the MRF
    start must recover the true start (oracle: the offset the test put in) to a small fraction of a cell."""
    from factories import real_terrain

    from hadal.matching.budget import mrf_step, swath_on_map
    from hadal.matching.tercom import TercomResult, _rotate

    path = shared_data / "bathy-real" / "tut_bathy.nc"
    if not path.is_file():
        pytest.skip(f"{path} not present")
    g, truth = real_terrain(path)
    h = g.resolution_m
    rng = np.random.default_rng(11)
    # a 60-cell dead-reckoned track with a turn, its start in the grid's textured interior
    n = 120
    course = np.deg2rad(np.where(np.arange(n) < 60, 70.0, 20.0))
    dr = np.concatenate([[[0.0, 0.0]], np.cumsum(0.5 * h * np.column_stack([np.sin(course), np.cos(course)])[1:], 0)])
    heading_bias, scale = 2.0, 1.02  # the fix's pose: map = R(heading) * scale * dr + start + drift
    p0 = np.array([g.x_m[0] + 0.35 * (g.x_m[-1] - g.x_m[0]), g.y_m[0] + 0.35 * (g.y_m[-1] - g.y_m[0])])
    drift = np.column_stack([np.linspace(0, 1.5 * h, n), np.linspace(0, -0.8 * h, n)])
    normal = np.column_stack([np.cos(course), -np.sin(course)])  # across the dead-reckoned course
    off = np.linspace(-8 * h, 8 * h, 33)
    q = (dr[:, None, :] + off[None, :, None] * normal[:, None, :]).reshape(-1, 2)  # logged (dead-reckoned) beams
    at_true = _rotate(q, heading_bias) * scale + p0 + np.repeat(drift, off.size, axis=0)
    depth = truth(at_true[:, 0], at_true[:, 1]) + rng.normal(0, 0.5, len(at_true))
    ok = np.isfinite(depth)
    assert ok.mean() > 0.95
    e = np.array(err_cells) * h
    res = TercomResult("msd", p0[0] + e[0], p0[1] + e[1], 0, 0, heading_bias, 0.0, 0.0, n, n, np.zeros((1, 1)),
                       np.zeros((1, 1)), None, g.x_m, g.y_m, {}, np.nan, np.nan, np.nan, np.nan, False, h, h, (0.0, 0.0),
                       scale=scale)
    track_map = res.apply(dr) + drift  # what the match stage's matched track holds (the drift estimate included)
    xy, placed, row = swath_on_map(q[ok], dr, track_map, res, max_offset_m=20 * h)
    # placed where the fix puts them: off by its error, plus the drift difference to the nearest track sample (the
    # swath carries no time per sounding; the drift grows 1.5 cells over the track here)
    dev = np.hypot(*(xy - at_true[ok] - e).T) / h
    assert placed.all() and np.median(dev) < 0.01 and dev.max() < 0.3, (np.median(dev), dev.max())  # inside the turn
    entry, warns = mrf_step(xy, depth[ok], g, g, (res.start_x_m, res.start_y_m), LocalFrame(0.0, 0.0),
                            max_shift_cells=1.5, max_total_shift_cells=25.0, prior="gibbs", patch_source="vehicle_swath")
    assert entry["applied"] and entry["patch_source"] == "vehicle_swath", (entry, warns)
    err = np.hypot(entry["start"]["x_east_m"] - p0[0], entry["start"]["y_north_m"] - p0[1]) / h
    print(f"\nfix error {np.hypot(*err_cells):.2f} cells -> MRF on the swath {err:.3f} cells")
    assert err < 0.25
