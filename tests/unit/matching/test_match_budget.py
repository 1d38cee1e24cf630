"""The match stage's pure science (hadal.matching.budget): the fix's uncertainty budget, the posterior record and the
MRF step, against closed forms and known shifts; the options model (hadal.matching.options) declared once."""

from __future__ import annotations

import numpy as np
import pytest
from factories import AnalyticTerrain

from hadal.geo import LocalFrame
from hadal.matching import MapGrid
from hadal.matching.budget import (
    MRF_MIN_COVERAGE,
    information_distance_m,
    mrf_step,
    posterior_record,
    uncertainty_budget,
)
from hadal.matching.tercom import TercomResult

H = 20.0


def _result(sx=3.0, sy=4.0, start=(100.0, 200.0)) -> TercomResult:
    z = np.zeros((3, 3))
    return TercomResult(
        criterion="msd", start_x_m=start[0], start_y_m=start[1], start_row=0, start_col=0, heading_deg=0.0, score=1.0,
        bias_m=0.0, n_samples=3, n_valid=3, surface=z, surface_all_headings=z, bias_surface=None, x_m=np.arange(3.0),
        y_m=np.arange(3.0), heading_scores={0.0: 1.0}, second_score=np.nan, second_x_m=np.nan, second_y_m=np.nan,
        separation_ratio=np.inf, mismatch=False, sigma_x_m=sx, sigma_y_m=sy, track_start_xy=(0.0, 0.0))


def _quadratic_map(a=1e-3):
    x = np.arange(200) * H
    y = np.arange(50) * H
    xx, _ = np.meshgrid(x, y)
    return MapGrid.from_any(5000.0 + a * xx ** 2, x, y)


def test_information_distance_is_the_gradient_squared_weighted_centroid():
    """depth = c + a x^2: gradient 2 a x (np.gradient is exact on a quadratic in the interior, bilinear sampling exact
    on a linear field), so the weights are x^2 and the centroid sum(x^2 s)/sum(x^2) in closed form."""
    g = _quadratic_map()
    track = np.column_stack([np.linspace(0.0, 1500.0, 31), np.zeros(31)])  # relative track, along +x
    along = track[:, 0].copy()
    res = _result(start=(1000.0, 500.0))  # matched positions x = 1000 .. 2500 (interior of the map)
    x = 1000.0 + track[:, 0]
    expected = float(np.sum(x ** 2 * along) / np.sum(x ** 2))
    assert information_distance_m(res, track, along, g) == pytest.approx(expected, rel=1e-12)
    # a flat map carries no information: the start is carried to the middle of the track
    flat = MapGrid.from_any(np.full((50, 200), 5000.0), g.x_m, g.y_m)
    assert information_distance_m(res, track, along, flat) == pytest.approx(750.0)


def test_uncertainty_budget_adds_the_dead_reckoning_term_in_quadrature():
    g = _quadratic_map()
    track = np.column_stack([np.linspace(0.0, 1500.0, 31), np.zeros(31)])
    along = track[:, 0].copy()
    res = _result(sx=3.0, sy=4.0, start=(1000.0, 500.0))
    x = 1000.0 + track[:, 0]
    d = float(np.sum(x ** 2 * along) / np.sum(x ** 2))
    f = 0.02
    b = uncertainty_budget(res, track, along, g, dr_error_fraction=f, posterior_used=False)
    per_axis = f * d / np.sqrt(2.0)
    assert b.result.sigma_x_m == pytest.approx(np.sqrt(9.0 + per_axis ** 2), rel=1e-12)
    assert b.result.sigma_y_m == pytest.approx(np.sqrt(16.0 + per_axis ** 2), rel=1e-12)
    # radial: sqrt(match^2 + (f d)^2), the DR term radial = f x information distance
    assert b.result.sigma_m == pytest.approx(np.sqrt(25.0 + (f * d) ** 2), rel=1e-12)
    c = b.components
    assert c["match_radial"] == 5.0 and c["dead_reckoning_radial"] == pytest.approx(f * d, rel=1e-12)
    assert c["information_distance_m"] == pytest.approx(d, rel=1e-12) and c["dr_error_fraction"] == f
    assert "dead reckoning" in c["comment"]
    assert (res.sigma_x_m, res.sigma_y_m) == (3.0, 4.0)  # the input result is not modified
    # the posterior second moment is the whole budget: no separate DR term
    p = uncertainty_budget(res, track, along, g, dr_error_fraction=f, posterior_used=True)
    assert (p.result.sigma_x_m, p.result.sigma_y_m) == (3.0, 4.0) and p.components["dead_reckoning_radial"] == 0.0
    assert "posterior" in p.components["comment"]


class _Post:
    """Stand-in for a PosteriorFix: what posterior_record reads."""

    start_x_m, start_y_m = 120.0, -80.0
    reasons = ("ambiguous",)

    def summary(self):
        return {"covariance_m2": [[4.0, 0.0], [0.0, 9.0]], "drms_m": np.sqrt(13.0)}

    def ellipse(self, k):
        return {"semi_major_m": 3.0 * k, "semi_minor_m": 2.0 * k, "azimuth_deg": 0.0}


def test_posterior_record_ellipse_centre_and_dead_reckoning_track():
    import pandas as pd

    frame = LocalFrame(11.33, 142.2)
    bottom = pd.DataFrame({"dr_east_m": np.arange(25.0), "dr_north_m": -2.0 * np.arange(25.0)})
    fix = {"launch": {"x_east_m": 1000.0, "y_north_m": 2000.0}, "uncertainty_m": {"radial": 1.0}}
    out = posterior_record(_Post(), fix, frame, bottom, True)
    # every 10th sample (0, 10, 20) and the last (24), launch + DR offsets
    assert out["dead_reckoning_track"]["x_east_m"] == [1000.0, 1010.0, 1020.0, 1024.0]
    assert out["dead_reckoning_track"]["y_north_m"] == [2000.0, 1980.0, 1960.0, 1952.0]
    lon, lat = frame.to_lonlat(1024.0, 1952.0)
    assert (out["dead_reckoning_track"]["lon"][-1], out["dead_reckoning_track"]["lat"][-1]) == pytest.approx((lon, lat))
    e1 = out["uncertainty_m"]["ellipse_1sigma"]
    assert out["uncertainty_m"]["radial"] == 1.0 and e1["semi_major_m"] == 3.0
    assert out["uncertainty_m"]["ellipse_2sigma"]["semi_major_m"] == 6.0
    assert (e1["centre"]["x_east_m"], e1["centre"]["y_north_m"]) == (120.0, -80.0)
    assert out["mismatch_reasons"] == ["ambiguous"] and out["posterior"]["used_for_fix"] is True
    rec = posterior_record(_Post(), fix, frame, bottom, False)
    assert "uncertainty_m" not in rec and "mismatch_reasons" not in rec and "comment" in rec["posterior"]


def test_mrf_step_refuses_a_single_beam_track_with_its_coverage():
    """A diagonal line through k cells: the patch interior is k x k cells of which k hold soundings (coverage 1/k)."""
    g = MapGrid.from_any(np.zeros((60, 60)), np.arange(60) * H, np.arange(60) * H)
    k = 20
    xy = np.column_stack([(10 + np.arange(k)) * H, (10 + np.arange(k)) * H])
    entry, warnings = mrf_step(xy, np.full(k, 100.0), g, g, (200.0, 200.0), LocalFrame(11.33, 142.2),
                               max_shift_cells=1.5, max_total_shift_cells=25.0, prior="gibbs")
    assert entry["applied"] is False and entry["coverage"] == pytest.approx(1.0 / k) and 1.0 / k < MRF_MIN_COVERAGE
    assert "single-beam" in warnings[0] and "start" not in entry


def test_mrf_step_moves_the_start_by_a_known_shift():
    """A 2-D swath of the true terrain whose assumed positions are (+2, -1) cells off (assumed minus true; the
    swath is gridded on the map cells, so a whole-cell shift): MRF finds it and moves the start by minus it."""
    t = AnalyticTerrain.random(3)
    z, x, y = t.grid(90, 70, H, noise_m=0.5, seed=2)
    g = MapGrid.from_any(z, x, y)
    rng = np.random.default_rng(0)
    jj, ii = np.meshgrid(np.arange(20), np.arange(15))
    true = np.column_stack([600.0 + jj.ravel() * H, 500.0 + ii.ravel() * H])
    depth = t(true[:, 0], true[:, 1]) + 5.0 + rng.normal(0, 0.2, true.shape[0])
    assumed = true + np.array([40.0, -20.0])
    frame = LocalFrame(11.33, 142.2)
    entry, warnings = mrf_step(assumed, depth, g, g, (700.0, 650.0), frame, max_shift_cells=1.5,
                               max_total_shift_cells=25.0, prior="gibbs")
    assert entry["applied"] is True and not warnings
    assert entry["dx_m"] == pytest.approx(40.0, abs=1.0) and entry["dy_m"] == pytest.approx(-20.0, abs=1.0)
    st = entry["start"]
    assert (st["x_east_m"], st["y_north_m"]) == pytest.approx((700.0 - entry["dx_m"], 650.0 - entry["dy_m"]))
    assert (st["lon"], st["lat"]) == pytest.approx(tuple(float(v) for v in frame.to_lonlat(st["x_east_m"], st["y_north_m"])))


def test_options_declared_once_and_read_by_the_stage_and_navigation():
    import inspect

    from hadal.matching import refine_tercom, tercom
    from hadal.matching.options import DeadReckoningOptions, TercomOptions
    from hadal.settings import MatchParams as Params

    assert issubclass(Params, TercomOptions) and issubclass(Params, DeadReckoningOptions)
    for opt in (TercomOptions, DeadReckoningOptions):
        for name, f in opt.model_fields.items():  # the stage does not re-declare them
            assert Params.model_fields[name].default == f.default, name
            assert name not in Params.__annotations__, name
    for fn in (tercom, refine_tercom):  # the functions declare no defaults of the options
        params = inspect.signature(fn).parameters
        assert not set(params) & (set(TercomOptions.model_fields) - {"criterion"}), fn.__name__
    assert inspect.signature(tercom).parameters["criterion"].default is None


def test_matched_track_keeps_the_time_column_and_places_samples_by_the_result():
    """matched_track: the bottom samples' tz-aware times pass through unchanged (dtype and values; no object-array
    round trip) and each sample is placed at start + (track - the result's track start, here (0, 0)) (heading 0)
    plus the drift."""
    import pandas as pd

    from hadal.matching.fix import matched_track

    n = 50
    t = pd.date_range("2026-12-04 10:00", periods=n, freq="250ms", tz="UTC")
    bottom = pd.DataFrame({"time": t, "dr_east_m": np.arange(n) * 2.0 + 7.0, "dr_north_m": np.full(n, -3.0),
                           "depth_m": np.full(n, 5000.0), "seafloor_depth_m": np.full(n, 5010.0)},
                          index=np.arange(100, 100 + n))
    drift = np.column_stack([np.linspace(0, 1, n), np.zeros(n)])
    out = matched_track(bottom, _result(start=(100.0, 200.0)), LocalFrame(11.33, 142.2), drift_xy=drift)
    assert out["time"].dtype == bottom["time"].dtype
    assert (out["time"].to_numpy() == bottom["time"].to_numpy()).all()
    np.testing.assert_allclose(out["x_east_m"], 107.0 + np.arange(n) * 2.0 + drift[:, 0])
    np.testing.assert_allclose(out["y_north_m"], 197.0)
