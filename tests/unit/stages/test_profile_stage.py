"""Stage ``profile`` (issue 46): the binned casts placed at the navigation product's position at the cast's time.

Oracles: the navigation product itself, read back from ``navigation.nc`` and interpolated here with pandas' time
interpolation (not the code's ``np.interp``); the generator's truth (``truth.json``: launch and surfacing); the
``ctd`` table's own rows for the fallbacks."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pytest
import xarray as xr

from hadal.pipeline import make_context, run_stage
from hadal.products.dsg import POSITION_SOURCES, id_values, place_casts
from hadal.products.io import write_parquet

T0 = pd.Timestamp("2018-10-06T23:00:00Z")


def _geod_m(lat1, lon1, lat2, lon2) -> float:
    from pyproj import Geod

    return float(Geod(ellps="WGS84").inv(lon1, lat1, lon2, lat2)[2])


def _nav_at(nav: pd.DataFrame, t: pd.Timestamp, cols: list[str]) -> pd.Series:
    """``nav`` (indexed by time) at ``t``: pandas time interpolation between its samples (the oracle)."""
    idx = nav.index.union(pd.DatetimeIndex([t]))
    return nav[cols].reindex(idx).interpolate(method="time").loc[t]


# ---------------------------------------------------------------- the pure placement, on a small synthetic dive
def _synthetic(n: int = 601, dt_s: float = 10.0):
    """A (cast, level) profile and a ctd table: descent, bottom, ascent; per-sample dead-reckoned lat/lon."""
    t = T0 + pd.to_timedelta(np.arange(n) * dt_s, unit="s")
    phase = np.array(["descent"] * 200 + ["bottom"] * 200 + ["ascent"] * (n - 400))
    ctd = pd.DataFrame({"time": t, "phase": phase, "pressure_dbar": np.r_[np.linspace(2, 4000, 200), [4000] * 200,
                                                                          np.linspace(4000, 2, n - 400)],
                        "lat": 11.0 + 1e-5 * np.arange(n), "lon": 142.0 - 2e-5 * np.arange(n)})
    prof = xr.Dataset({"temperature_its90_degc": (("cast", "pressure_dbar"), np.ones((2, 3)))},
                      coords={"cast": ["descent", "ascent"], "pressure_dbar": [5.0, 15.0, 25.0]})
    # the navigation on its own, coarser clock (7 s, starting 3 s late), 1.2 km off the dead reckoning at the end
    tn = T0 + pd.to_timedelta(3 + np.arange(0, n * dt_s, 7.0), unit="s")
    s = (tn - T0).total_seconds().to_numpy()
    nav = pd.DataFrame({"time": tn, "lat": 11.0 + 1.1e-6 * s, "lon": 142.0 + 1.3e-6 * s,
                        "position_covariance_east_m2": 4.0 + 0.01 * s, "position_covariance_north_m2": 9.0 + 0.02 * s})
    return prof, ctd, nav


def test_cast_at_the_navigation_position_at_its_time():
    prof, ctd, nav = _synthetic()
    out = place_casts(prof, ctd, navigation=nav, launch=(10.0, 140.0))
    ref = nav.set_index("time")
    for i, cast in enumerate(["descent", "ascent"]):
        rows = ctd[ctd["phase"] == cast]
        t = rows["time"].iloc[0] if cast == "descent" else rows["time"].iloc[-1]  # the cast's surface end
        assert pd.Timestamp(out["time"].values[i]).tz_localize("UTC") == t
        if t < ref.index[0]:  # before the navigation's first sample: the next source (the ctd's own position)
            assert POSITION_SOURCES[int(out["cast_position_source"].values[i])] == "ctd_dead_reckoning"
            assert out["lat"].values[i] == rows["lat"].iloc[0] and np.isnan(out["position_uncertainty_m"].values[i])
            continue
        want = _nav_at(ref, t, ["lat", "lon", "position_covariance_east_m2", "position_covariance_north_m2"])
        assert POSITION_SOURCES[int(out["cast_position_source"].values[i])] == "navigation"
        assert out["lat"].values[i] == pytest.approx(want["lat"], abs=1e-9)
        assert out["lon"].values[i] == pytest.approx(want["lon"], abs=1e-9)
        assert out["position_uncertainty_m"].values[i] == pytest.approx(
            np.sqrt(want["position_covariance_east_m2"] + want["position_covariance_north_m2"]), rel=1e-9)
    # the descent starts 3 s before the navigation: it degrades alone, the ascent is placed from the navigation
    assert [POSITION_SOURCES[int(v)] for v in out["cast_position_source"].values] == ["ctd_dead_reckoning", "navigation"]
    assert "navigation product" in out["lat"].attrs["comment"]
    assert np.array_equal(out["temperature_its90_degc"].values, prof["temperature_its90_degc"].values)


@pytest.mark.parametrize("drop, expected", [
    ((), "ctd_dead_reckoning"), (("ctd",), "cast_header"), (("ctd", "header"), "launch"),
    (("ctd", "header", "launch"), "nominal")])
def test_position_falls_back_in_order(drop, expected):
    prof, ctd, _ = _synthetic()
    if "ctd" in drop:
        ctd = ctd.drop(columns=["lat", "lon"])
    given = {"header": (12.5, 143.5), "launch": (13.0, 144.0), "nominal": (14.0, 145.0)}
    for k in drop:
        given.pop(k, None)
    out = place_casts(prof, ctd, navigation=None, **given)
    assert [POSITION_SOURCES[int(v)] for v in out["cast_position_source"].values] == [expected, expected]
    want = {"ctd_dead_reckoning": (ctd.get("lat", pd.Series([np.nan])).iloc[-1], None), "cast_header": (12.5, 143.5),
            "launch": (13.0, 144.0), "nominal": (14.0, 145.0)}[expected]
    assert out["lat"].values[1] == want[0]
    assert np.isnan(out["position_uncertainty_m"].values).all()  # only the navigation carries one


# ---------------------------------------------------------------- the sample dive, every stage
def test_sample_dive_casts_at_navigation_position(small_run):
    """Each cast of the sample dive at the smoothed navigation's position at its time (navigation.nc read back and
    interpolated here), recorded as such; the ascent where the vehicle surfaced, not at the launch."""
    ctx, versions = small_run
    truth = json.loads((ctx.raw_dir / "truth.json").read_text())
    ds = xr.open_dataset(versions["profile"].file("profile.nc"))
    nv = xr.open_dataset(versions["navigation"].file("navigation.nc"))
    nav = pd.DataFrame({"lat": nv["lat"].values, "lon": nv["lon"].values,
                        "var": nv["position_covariance_east_m2"].values + nv["position_covariance_north_m2"].values},
                       index=pd.DatetimeIndex(nv["time"].values))
    casts = ds["cast"].attrs["flag_meanings"].split()
    assert casts == ["descent", "ascent"] and id_values(ds["profile_id"])[1].endswith("_ascent")
    launch = truth["launch"]
    for i in range(len(casts)):
        want = _nav_at(nav, pd.Timestamp(ds["time"].values[i]), ["lat", "lon", "var"])
        assert ds["cast_position_source"].attrs["flag_meanings"].split()[int(ds["cast_position_source"].values[i])] == \
            "navigation"
        assert _geod_m(ds["lat"].values[i], ds["lon"].values[i], want["lat"], want["lon"]) < 0.05
        assert ds["position_uncertainty_m"].values[i] == pytest.approx(np.sqrt(want["var"]), rel=1e-3)
    surf = truth["surfacing"]
    off_launch = _geod_m(ds["lat"].values[1], ds["lon"].values[1], launch["latitude_deg"], launch["longitude_deg"])
    err = _geod_m(ds["lat"].values[1], ds["lon"].values[1], surf["latitude_deg"], surf["longitude_deg"])
    assert off_launch > 200.0 and err < 0.2 * off_launch  # the surfacing, not the launch
    assert pd.Timestamp(ds["time"].values[1]) == pd.Timestamp(surf["time"]).tz_convert(None)
    man = versions["profile"].manifest()
    assert [c["position_source"] for c in man["cast_positions"]] == ["navigation", "navigation"]
    assert "navigation" in {u["product"] for u in man["upstream"]}
    assert ds.attrs["cast_positions"] == "descent: navigation; ascent: navigation"
    # the report says where each cast is and from what, at the precision of its uncertainty
    rep = json.loads(versions["report"].file("summary.json").read_text())
    asc = rep["cast_positions"][1]
    assert asc["cast"] == "ascent" and asc["source"] == "navigation"
    assert asc["lat"] == pytest.approx(float(ds["lat"].values[1])) and asc["uncertainty_m"] > 0
    assert "ascent cast position (profile.nc)" in versions["report"].file("report.html").read_text()


# ---------------------------------------------------------------- without match: degrade, never fail
def _derived(tmp_path):
    from test_derive import _raw_dive, synth_sensors

    ctx = make_context(_raw_dive(tmp_path), tmp_path / "store")
    df, _, _ = synth_sensors(dt=20.0, max_depth=3000.0, bottom_s=600.0)
    with ctx.store.publish(ctx.dive_id, "sensors", parameters={}) as draft:
        write_parquet(df, draft.path / "sensors.parquet", metadata={"dive_id": ctx.dive_id})
    run_stage("derive", ctx)
    return ctx


def test_without_navigation_the_ctd_position_is_used(tmp_path):
    ctx = _derived(tmp_path)
    out = run_stage("profile", ctx)
    ds = xr.open_dataset(out["profile"].file("profile.nc"))
    ctd = pd.read_parquet(ctx.store.latest(ctx.dive_id, "ctd").file("ctd.parquet"))
    asc = ctd[ctd["phase"] == "ascent"].iloc[-1]
    assert [POSITION_SOURCES[int(v)] for v in ds["cast_position_source"].values] == ["ctd_dead_reckoning"] * 2
    assert ds["lat"].values[1] == pytest.approx(asc["lat"]) and ds["lon"].values[1] == pytest.approx(asc["lon"])
    assert out["profile"].manifest()["cast_positions"][1]["position_uncertainty_m"] is None


def test_unreadable_navigation_is_a_warning_and_a_fallback(tmp_path, caplog):
    ctx = _derived(tmp_path)
    with ctx.store.publish(ctx.dive_id, "navigation", parameters={}) as draft:
        (draft.path / "navigation.parquet").write_bytes(b"not parquet")
    with caplog.at_level("WARNING", logger="hadal"):
        out = run_stage("profile", ctx)
    assert any("navigation.parquet unreadable" in r.getMessage() for r in caplog.records)
    ds = xr.open_dataset(out["profile"].file("profile.nc"))
    assert [POSITION_SOURCES[int(v)] for v in ds["cast_position_source"].values] == ["ctd_dead_reckoning"] * 2


def test_ctd_position_without_dead_reckoning_is_not_claimed():
    """A table whose lat/lon are only the launch's (no DR offset known yet: a Sea-Bird cast, the descent's first
    samples) is not the vehicle's own position: the cast goes to the header (here), then the launch."""
    prof, ctd, _ = _synthetic()
    ctd["dr_east_m"] = np.where(np.arange(len(ctd)) < 450, np.nan, 1.0)  # DR from the 450th sample (in the ascent)
    ctd["dr_north_m"] = ctd["dr_east_m"]
    out = place_casts(prof, ctd, header=(12.5, 143.5), launch=(13.0, 144.0))
    assert [POSITION_SOURCES[int(v)] for v in out["cast_position_source"].values] == ["cast_header", "ctd_dead_reckoning"]
    assert out["lat"].values[1] == ctd["lat"].iloc[-1] and out["lat"].values[0] == 12.5


# ---------------------------------------------------------------- the casts are binned once, by derive
def test_casts_are_binned_once_and_profile_nc_holds_their_bin_means(tmp_path, monkeypatch, caplog):
    """derive bins the casts once (``bin_casts`` called once for derive + profile, its warnings logged once) and the
    profile stage places those bins: profile.nc's bin means are pandas' group means of ctd.parquet's accepted
    samples by phase and floor(pressure / 10 dbar) (the oracle, computed here from the published table)."""
    import hadal.ctd.derive as ctd_derive

    calls = []
    real = ctd_derive.bin_casts

    def counted(*args, **kwargs):
        calls.append(args[-1])
        return real(*args, **kwargs)

    monkeypatch.setattr(ctd_derive, "bin_casts", counted)
    with caplog.at_level("INFO", logger="hadal"):
        ctx = _derived(tmp_path)
        out = run_stage("profile", ctx)
    assert len(calls) == 1
    ctd = pd.read_parquet(ctx.store.latest(ctx.dive_id, "ctd").file("ctd.parquet"))
    ok = ctd["temperature_its90_degc_qc"].isin([1, 2]) if "temperature_its90_degc_qc" in ctd else True
    if "loop_edit_bad" in ctd:
        ok &= ~ctd["loop_edit_bad"].astype(bool)
    c = ctd[ok & ctd["phase"].isin(["descent", "ascent"])]
    want = c.groupby([c["phase"], np.floor(c["pressure_dbar"] / 10.0)])["temperature_its90_degc"].mean()
    ds = xr.open_dataset(out["profile"].file("profile.nc"))
    casts = ds["cast"].attrs["flag_meanings"].split()
    rows = np.repeat(np.arange(ds.sizes["profile"]), ds["row_size"].values)
    got = pd.Series(ds["temperature_its90_degc"].values.astype(float),
                    index=pd.MultiIndex.from_arrays([[casts[int(ds["cast"].values[r])] for r in rows],
                                                     np.floor(ds["pressure_dbar"].values.astype(float) / 10.0)]))
    got = got.dropna()
    assert len(got) > 100
    assert np.allclose(got.to_numpy(), want.reindex(got.index).to_numpy(), rtol=1e-6, atol=1e-5)


def test_binned_casts_kept_by_derive_read_back_exactly(tmp_path):
    """The hand-over file (xarray's own NetCDF encoding) gives back the dataset written: string casts, times with
    NaT, int8 flags with array attributes, NaN (oracle: xarray.testing.assert_identical on the original)."""
    from hadal.products.io import read_dataset_exact, write_dataset_exact

    t = np.array(["2018-10-06T23:00:00.123456789", "NaT"], dtype="datetime64[ns]")
    ds = xr.Dataset({"temperature_its90_degc": (("cast", "pressure_dbar"), [[1.5, np.nan], [2.25, 3.0]],
                                                {"units": "degree_Celsius"}),
                     "temperature_its90_degc_qc": (("cast", "pressure_dbar"), np.array([[1, 9], [1, 3]], "i1"),
                                                   {"flag_values": np.array([1, 3, 9], "i1"), "flag_meanings": "a b c"}),
                     "count": (("cast", "pressure_dbar"), np.array([[4, 0], [2, 7]], "i4")),
                     "time": ("cast", t, {"standard_name": "time"})},
                    coords={"cast": np.array(["descent", "ascent"], dtype=object), "pressure_dbar": [5.0, 15.0]},
                    attrs={"bin_size_dbar": 10.0, "profile_axis": "pressure"})
    back = read_dataset_exact(write_dataset_exact(ds, tmp_path / "internal" / "x.nc"))
    xr.testing.assert_identical(back, ds)
    assert back["count"].dtype == np.int32 and back["time"].dtype == ds["time"].dtype
    assert back["temperature_its90_degc_qc"].attrs["flag_values"].dtype == np.int8
    assert all(not v.encoding for v in back.variables.values())


def test_profile_of_a_ctd_version_without_binned_casts_is_a_one_line_error(tmp_path):
    """A ``ctd`` version published before derive kept its binned casts (only ctd.parquet) is named, with what to do."""
    import shutil

    from hadal.errors import InputError

    ctx = _derived(tmp_path)
    old = ctx.store.latest(ctx.dive_id, "ctd")
    with ctx.store.publish(ctx.dive_id, "ctd", parameters={}) as draft:
        shutil.copy(old.file("ctd.parquet"), draft.path / "ctd.parquet")
    ctx.pins.clear()
    with pytest.raises(InputError, match="no binned casts.*re-run derive") as exc:
        run_stage("profile", ctx)
    assert "\n" not in str(exc.value) and draft.result.label in str(exc.value)


def test_derive_and_profile_report_their_long_steps_through_the_progress(tmp_path):
    """derive's and profile's steps reach the run's Progress (what the terminal and the Prefect log show), each
    started and finished (hadal.progress.LogProgress's lines, read back from the log)."""
    import logging

    from hadal.progress import LogProgress

    records: list[str] = []

    class Keep(logging.Handler):
        def emit(self, record):
            records.append(record.getMessage())

    handler = Keep(level=logging.INFO)
    logging.getLogger("hadal").addHandler(handler)
    old = logging.getLogger("hadal").level
    logging.getLogger("hadal").setLevel(logging.INFO)
    try:
        from test_derive import _raw_dive, synth_sensors

        ctx = make_context(_raw_dive(tmp_path), tmp_path / "store")
        ctx.progress = LogProgress(interval_s=0.0, echo=False)
        df, _, _ = synth_sensors(dt=20.0, max_depth=3000.0, bottom_s=600.0)
        with ctx.store.publish(ctx.dive_id, "sensors", parameters={}) as draft:
            write_parquet(df, draft.path / "sensors.parquet", metadata={"dive_id": ctx.dive_id})
        run_stage("derive", ctx)
        run_stage("profile", ctx)
    finally:
        logging.getLogger("hadal").removeHandler(handler)
        logging.getLogger("hadal").setLevel(old)
    text = "\n".join(records)
    for what in ("derive: reading sensors.parquet", "derive: writing ctd", "profile: reading ctd and its binned casts"):
        assert f"{what}: started" in text and f"{what}: done" in text, (what, text[-2000:])
    assert sum("samples -> depth, TEOS-10, QC, profiles: done" in r for r in records) == 1
