"""Stages `suitability` and `match` on a synthetic store: products, fix within one cell, errors publish nothing."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import xarray as xr
from factories import AnalyticTerrain, lawnmower

from hadal.dive import Dive, Launch, MapFrame
from hadal.errors import InputError, StageError
from hadal.geo import geodesic_distance_m, parse_degmin
from hadal.matching.budget import MRF_MIN_COVERAGE, grid_track_patch
from hadal.settings import MatchParams, PipelineConfig, SuitabilityParams
from hadal.stages import StageContext
from hadal.stages import match as match_stage
from hadal.stages import suitability as suit_stage
from hadal.store import ProductStore

H = 20.0
DRIFT = np.array([430.0, -260.0])  # true bottom start minus launch point, metres


def _dive() -> Dive:
    return Dive(dive_id="synthetic-dive", launch=Launch(latitude_deg=11.3371167, longitude_deg=142.2097167),
                map_frame=MapFrame(origin_latitude_deg=11.33, origin_longitude_deg=142.20))


def _world(tmp_path, *, track="wiggle", ctd_mutator=None, nan_hole=False):
    dive = _dive()
    frame = dive.frame()
    lx, ly = (float(v) for v in frame.to_xy(dive.launch.longitude_deg, dive.launch.latitude_deg))
    terrain = AnalyticTerrain.random(5, extent_m=3000.0)
    x = np.round(lx / H) * H + np.arange(-90, 90) * H
    y = np.round(ly / H) * H + np.arange(-80, 80) * H
    xx, yy = np.meshgrid(x, y)
    rng = np.random.default_rng(0)
    z = terrain(xx - x[0], yy - y[0]) + 6.0 + rng.normal(0, 0.3, xx.shape)  # map 6 m too deep
    if nan_hole:
        z[10:20, 10:30] = np.nan
    store = ProductStore(tmp_path / "store")
    with store.publish(dive.dive_id, "dtm") as d:
        xr.Dataset({"depth_m": (("y", "x"), z)}, coords={"x": x, "y": y}).to_netcdf(d.path / "dtm.nc", engine="h5netcdf")
    # bottom track: true positions and dead-reckoned ones (DR starts at the launch point: the drift is unknown)
    n = 1500
    rel = lawnmower(n, 600.0, 500.0, legs=4) if track == "lawnmower" else _wiggle(n, 1600.0)
    true = rel + np.array([lx, ly]) + DRIFT
    seafloor = terrain(true[:, 0] - x[0], true[:, 1] - y[0]) + rng.normal(0, 0.5, n)
    assert (true.min(axis=0) > [x[0], y[0]]).all() and (true.max(axis=0) < [x[-1], y[-1]]).all()
    dr = rel + np.cumsum(rng.normal(0, 0.02, (n, 2)), axis=0)
    t0 = pd.Timestamp("2018-10-06T23:00:00Z")
    nd = na = 20
    time = t0 + pd.to_timedelta(np.arange(nd + n + na), unit="s")
    phase = ["descent"] * nd + ["bottom"] * n + ["ascent"] * na
    alt = 5.0 + rng.normal(0, 0.1, n)
    depth_b = seafloor - alt
    depth = np.concatenate([np.linspace(0, depth_b[0], nd), depth_b, np.linspace(depth_b[-1], 0, na)])
    sf = np.concatenate([np.full(nd, np.nan), seafloor, np.full(na, np.nan)])
    sf[nd + 5] = np.nan  # altimeter dropout
    dre = np.concatenate([np.zeros(nd), dr[:, 0], np.full(na, dr[-1, 0])])
    drn = np.concatenate([np.zeros(nd), dr[:, 1], np.full(na, dr[-1, 1])])
    ctd = pd.DataFrame({"time": time, "depth_m": depth, "seafloor_depth_m": sf, "dr_east_m": dre, "dr_north_m": drn,
                        "phase": phase, "pressure_dbar": depth * 1.02})
    if ctd_mutator is not None:
        ctd = ctd_mutator(ctd)
    with store.publish(dive.dive_id, "ctd") as d:
        ctd.to_parquet(d.path / "ctd.parquet")
    i_deep = int(np.argmax(depth_b))
    truth = {"start": true[0], "deepest": true[i_deep], "deepest_depth": depth_b[i_deep], "launch": (lx, ly)}
    return dive, store, truth


def _wiggle(n, length):
    from factories import wiggly_track

    return wiggly_track(n, length, seed=4)


def _ctx(dive, store, tmp_path, **match_params):
    cfg = PipelineConfig(suitability=SuitabilityParams(n_blocks_y=10, n_blocks_x=12, region_size_x_m=1500.0,
                                                       region_size_y_m=1200.0),
                         match=MatchParams(**match_params))
    return StageContext(dive=dive, raw_dir=tmp_path, store=store, config=cfg)


def test_match_stage_recovers_start_and_publishes_products(tmp_path):
    dive, store, truth = _world(tmp_path)
    ctx = _ctx(dive, store, tmp_path)
    out = match_stage.run(ctx)
    pv = out["match"]
    assert {f["name"] for f in pv.manifest()["files"]} == {"msd_surface.nc", "matched_track.parquet", "fix.json"}
    assert [u["product"] for u in pv.manifest()["upstream"]] == ["dtm", "ctd"]
    fix = json.loads(pv.file("fix.json").read_text())
    sx, sy = fix["start"]["x_east_m"], fix["start"]["y_north_m"]
    assert max(abs(sx - truth["start"][0]), abs(sy - truth["start"][1])) <= H  # within one map cell
    assert fix["bias_m"] == pytest.approx(6.0, abs=1.0)
    assert not fix["mismatch"]
    frame = dive.frame()
    tlon, tlat = frame.to_lonlat(*truth["start"])
    assert geodesic_distance_m(fix["start"]["lon"], fix["start"]["lat"], tlon, tlat) < 1.5 * H
    assert parse_degmin(fix["start"]["position_degmin"].split(", ")[1]) == pytest.approx(fix["start"]["lat"], abs=1e-5)
    assert fix["drift_m"] == pytest.approx(np.hypot(*DRIFT), abs=1.5 * H)
    assert fix["best_offset_m"]["east"] == pytest.approx(DRIFT[0], abs=1.5 * H)
    deep = fix["deepest_point"]
    assert deep["depth_m"] == pytest.approx(truth["deepest_depth"], abs=0.01)
    assert np.hypot(deep["x_east_m"] - truth["deepest"][0], deep["y_north_m"] - truth["deepest"][1]) < 2 * H
    assert "°" in deep["position_degmin"] and deep["position_degmin"].endswith("N")
    assert fix["uncertainty_m"]["radial"] > 0
    track = pd.read_parquet(pv.file("matched_track.parquet"))
    assert len(track) == 1499 and {"lat", "lon", "x_east_m", "map_depth_m"} <= set(track.columns)
    assert np.nanmedian(np.abs(track["map_depth_minus_bias_m"] - track["seafloor_depth_m"])) < 2.0
    with xr.open_dataset(pv.file("msd_surface.nc")) as s:
        assert s["score"].dims == ("y", "x") and s.attrs["criterion"] == "msd"
        coarse = fix["refinement"]["coarse"]  # the surface is the cell-resolution search (paper §4.2)
        assert float(s["score"].sel(x=coarse["x_east_m"], y=coarse["y_north_m"])) == pytest.approx(coarse["score"], rel=1e-5)
        assert float(s["score"].min()) == pytest.approx(coarse["score"], rel=1e-5)
    fix = json.loads(match_stage.run(_ctx(dive, store, tmp_path, posterior=True))["match"].file("fix.json").read_text())
    assert geodesic_distance_m(fix["start"]["lon"], fix["start"]["lat"], tlon, tlat) < 1.5 * H
    post = fix["posterior"]  # the posterior summary (issue 16): calibrated ellipse, mode mass, no flag here
    assert not fix["mismatch"] and post["mass_outside_main_mode"] < 0.05 and post["mismatch_reasons"] == []
    e1 = post["ellipse_1sigma"]
    assert 0 < e1["semi_minor_m"] <= e1["semi_major_m"] and post["ellipse_2sigma"]["semi_major_m"] == pytest.approx(2 * e1["semi_major_m"])
    assert fix["uncertainty_m"]["radial"] == pytest.approx(post["drms_m"])
    assert post["refinement"]["loglik_map"] >= post["refinement"]["loglik_coarse_fix"]  # never worse than the coarse fix
    assert len(fix["dead_reckoning_track"]["x_east_m"]) == len(fix["dead_reckoning_track"]["y_north_m"]) > 2
    assert len(fix["dead_reckoning_track"]["lat"]) == len(fix["dead_reckoning_track"]["x_east_m"])
    # what a figure needs: the ellipse centre in lat/lon (the profile start), the posterior surface on the map grid
    cen = fix["uncertainty_m"]["ellipse_1sigma"]["centre"]
    assert (cen["x_east_m"], cen["y_north_m"]) == pytest.approx((fix["profile_start"]["x_east_m"], fix["profile_start"]["y_north_m"]))
    clon, clat = frame.to_lonlat(cen["x_east_m"], cen["y_north_m"])
    assert (cen["lon"], cen["lat"]) == pytest.approx((float(clon), float(clat)), abs=1e-9)
    assert "applied" in post["drift"]
    main = post["refinement"]["main_mode_covariance"]  # the stage gives the navigation's random walk to the fix
    assert main["method"] == "laplace" and main["random_walk"] == pytest.approx(0.07)
    mix = np.asarray(post["mixture_covariance_m2"])  # every mode: never narrower than the main mode's share
    assert np.trace(mix) >= (1 - post["mass_outside_main_mode"]) * np.trace(np.asarray(post["covariance_m2"])) - 1e-6
    out2 = match_stage.run(_ctx(dive, store, tmp_path, posterior=True))["match"]
    with xr.open_dataset(out2.file("msd_surface.nc")) as s:
        pps = s[post["surface"]["variable"]]
        assert float(pps.sum()) == pytest.approx(1.0, abs=1e-3)
        i = np.unravel_index(int(np.argmax(pps.values)), pps.shape)  # the most probable start cell is next to the fix
        assert np.hypot(float(s.x[i[1]]) - cen["x_east_m"], float(s.y[i[0]]) - cen["y_north_m"]) <= 2 * H


def test_suitability_stage_and_region_search(tmp_path):
    dive, store, truth = _world(tmp_path, nan_hole=True)
    ctx = _ctx(dive, store, tmp_path, region="suitability", heading_range_deg=2.0, heading_step_deg=1.0)
    with pytest.raises(StageError, match="suitability"):
        match_stage.run(ctx)
    sv = suit_stage.run(ctx)["suitability"]
    with xr.open_dataset(sv.file("suitability.nc")) as s:
        assert s["std_m"].shape == (10, 12) and s["lat"].shape == (10, 12)
        assert np.isfinite(s["std_m"]).all() and s["std_m"].attrs["units"] == "m"
        reg = json.loads(s.attrs["proposed_region"])
        assert reg["x_max_m"] - reg["x_min_m"] == pytest.approx(1500.0)
        assert s["in_region"].sum() > 0
    fix = json.loads(match_stage.run(ctx)["match"].file("fix.json").read_text())
    assert reg["x_min_m"] <= fix["start"]["x_east_m"] <= reg["x_max_m"]
    assert max(abs(fix["start"]["x_east_m"] - truth["start"][0]), abs(fix["start"]["y_north_m"] - truth["start"][1])) <= H
    assert fix["refinement"]["coarse"]["heading_deg"] in (-2.0, -1.0, 0.0, 1.0, 2.0)
    assert abs(fix["heading_error_deg"]) <= 2.5


def test_match_stage_does_not_claim_mrf_on_a_single_beam_track(tmp_path):
    """MRF matches a 2-D multibeam patch (MRF paper §2); a single-beam lawnmower track gridded on the map leaves
    most cells empty: the stage says so and runs no MRF (the fix is TERCOM's)."""
    dive, store, truth = _world(tmp_path, track="lawnmower")
    ctx = _ctx(dive, store, tmp_path, mrf=True, heading_range_deg=0.0, refine=False, posterior=False)
    fix = json.loads(match_stage.run(ctx)["match"].file("fix.json").read_text())
    assert fix["mrf"]["applied"] is False and "single-beam" in fix["mrf"]["reason"]
    assert fix["mrf"]["coverage"] < MRF_MIN_COVERAGE and "start" not in fix["mrf"]
    assert any("MRF not run" in w for w in fix["warnings"])
    e_tercom = np.hypot(fix["start"]["x_east_m"] - truth["start"][0], fix["start"]["y_north_m"] - truth["start"][1])
    assert e_tercom <= 1.5 * H


@pytest.mark.parametrize(
    ("mutator", "match"),
    [
        (lambda d: d.drop(columns=["seafloor_depth_m"]), "seafloor_depth_m"),
        (lambda d: d.assign(phase="descent"), "bottom"),
        (lambda d: d.assign(seafloor_depth_m=-d["seafloor_depth_m"]), "positive down"),
        (lambda d: d.assign(seafloor_depth_m=np.nan), "finite"),
    ],
)
def test_bad_ctd_raises_and_publishes_nothing(tmp_path, mutator, match):
    dive, store, _ = _world(tmp_path, ctd_mutator=mutator)
    with pytest.raises(InputError, match=match):
        match_stage.run(_ctx(dive, store, tmp_path))
    assert not store.has(dive.dive_id, "match")


def test_missing_upstream_and_truncated_dtm(tmp_path):
    dive = _dive()
    store = ProductStore(tmp_path / "store")
    ctx = _ctx(dive, store, tmp_path)
    with pytest.raises(StageError, match="dtm"):
        suit_stage.run(ctx)
    with store.publish(dive.dive_id, "dtm") as d:
        (d.path / "dtm.nc").write_bytes(b"\x89HDF\r\n\x1a\n truncated")
    with pytest.raises(InputError, match="dtm.nc"):
        suit_stage.run(ctx)
    assert not store.has(dive.dive_id, "suitability")


def test_params_defaults_are_the_papers():
    p = SuitabilityParams()
    assert (p.n_blocks_y, p.n_blocks_x, p.region_size_x_m, p.region_size_y_m) == (44, 60, 5800.0, 3700.0)
    m = MatchParams()
    assert m.criterion == "msd" and match_stage._headings(m).size == 37  # +-9 deg in 0.5 deg steps
    assert match_stage._headings(MatchParams(heading_range_deg=0.0)).tolist() == [0.0]
    assert match_stage._scales(m).tolist() == [1.0]
    assert match_stage._scales(MatchParams(scale_range=0.02)).tolist() == [0.98, 0.99, 1.0, 1.01, 1.02]
    assert suit_stage.STAGE.products == ("suitability",)
    assert match_stage.STAGE.reads == ("dtm", "ctd", "suitability")  # the fingerprint covers the optional region


def test_resample_along_track_bins_and_hover():
    from hadal.matching.fix import resample_along_track
    from hadal.products.io import json_clean

    x = np.r_[np.zeros(50), np.linspace(0, 100, 101)]  # 50 s hovering at the start, then 100 m east at 1 m/s
    y = np.zeros_like(x)
    z = np.r_[np.full(50, 10.0), 10.0 + np.linspace(0, 100, 101) * 0.1]
    p = resample_along_track(x, y, z, 20.0)
    assert p.depth_m.size == 6 and p.n_raw == 151  # bins [0,20) ... [80,100) and the end point at 100 m
    assert p.track_xy[0, 0] == pytest.approx(np.mean(np.r_[np.zeros(50), np.arange(20.0)]))  # hover collapses into bin 0
    assert np.all(np.diff(p.along_m) > 0)
    with pytest.raises(InputError):
        resample_along_track(x, y, z, 0.0)
    assert json.loads(json.dumps(json_clean({"a": np.float64("nan"), "b": [np.int64(3), np.bool_(True)]}))) == {"a": None, "b": [3, True]}


def test_grid_track_patch_cell_means():
    from hadal.matching import MapGrid

    g = MapGrid.from_any(np.zeros((10, 10)), np.arange(10) * H, np.arange(10) * H)
    xy = np.array([[40.0, 40.0], [44.0, 38.0], [60.0, 40.0]])
    patch, x0, y0 = grid_track_patch(xy, np.array([1.0, 3.0, 5.0]), g, margin_cells=1)
    assert (x0, y0) == (20.0, 20.0) and patch.shape == (3, 4)
    assert patch[1, 1] == 2.0 and patch[1, 2] == 5.0 and np.isnan(patch[0, 0])


def test_products_pass_cf_acdd_compliance(tmp_path):
    pytest.importorskip("compliance_checker")
    from hadal.products.compliance import check_compliance

    dive, store, _ = _world(tmp_path)
    ctx = _ctx(dive, store, tmp_path)
    sv = suit_stage.run(ctx)["suitability"]
    mv = match_stage.run(ctx)["match"]
    for f in (sv.file("suitability.nc"), mv.file("msd_surface.nc")):
        rep = check_compliance(f)
        assert rep.ok, rep.describe()
