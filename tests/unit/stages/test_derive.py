"""Stage ``derive`` end to end: a synthetic full-ocean-depth dive whose pressure comes from TEOS-10
(``gsw.p_from_z`` with dynamic height), published as a ``sensors`` product, through ``run_stage("derive")``."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import xarray as xr
import yaml
from pydantic import ValidationError

from hadal.ctd.derive import derive_ctd
from hadal.errors import InputError, StageError
from hadal.pipeline import make_context, run_stage
from hadal.products.dsg import orthogonal_profile
from hadal.products.io import read_parquet_metadata, write_parquet
from hadal.settings import DeriveParams
from hadal.stages import derive

gsw = pytest.importorskip("gsw")

LAT, LON = 11.33, 142.2
T0 = pd.Timestamp("2018-10-06T23:00:00Z")
CTD_COLUMNS = [
    "time", "conductivity_s_m", "temperature_its90_degc", "pressure_ctd_dbar", "pressure_gauge_dbar", "altitude_m",
    "heading_deg", "pitch_deg", "roll_deg", "dr_east_m", "dr_north_m", "speed_m_s", "pressure_dbar",
    "pressure_source", "practical_salinity", "density_kg_m3", "gravity_m_s2", "depth_m", "depth_fofonoff_millard_m",
    "depth_teos10_m", "sound_speed_m_s", "altitude_corrected_m", "seafloor_depth_m", "phase",
]


def _column(zmax=11_200.0, dz=2.0):
    d = np.arange(0.0, zmax + dz / 2, dz)
    t = 1.5 + 27.5 * np.exp(-d / 400.0) + 1.0e-4 * np.maximum(d - 4000.0, 0.0)
    sp = 34.7 - 0.5 * np.exp(-d / 300.0)
    p = gsw.p_from_z(-d, LAT)
    for _ in range(3):
        sa = gsw.SA_from_SP(sp, p, LON, LAT)
        ct = gsw.CT_from_t(sa, t, p)
        p = gsw.p_from_z(-d, LAT, geo_strf_dyn_height=gsw.geo_strf_dyn_height(sa, ct, p, p_ref=0))
    return d, p, sp, t


def synth_sensors(dt=4.0, max_depth=10_900.0, bottom_s=1800.0, speed=1.0, ctd_offset=-0.8, gauge_offset=0.3,
                  seed=0):
    """A sensors table as ingest writes it (contract columns + QARTOD flags) and the true depth/seafloor.
    Pressure offsets as the sample-dive sensor models: SBE49 within its +-0.1 %FS, Keller ~0.01 %FS."""
    rng = np.random.default_rng(seed)
    t_desc = max_depth / speed
    tt = np.arange(0.0, 2 * t_desc + bottom_s, dt)
    z = np.where(tt < t_desc, 2.0 + speed * tt,
                 np.where(tt < t_desc + bottom_s, max_depth - 30 * np.sin(np.pi * (tt - t_desc) / bottom_s),
                          max_depth - speed * (tt - t_desc - bottom_s)))
    z = np.clip(z, 1.0, max_depth)
    d, p, sp, t = _column()
    P, S, T = np.interp(z, d, p), np.interp(z, d, sp), np.interp(z, d, t)
    C = gsw.C_from_SP(S, T, P) / 10.0  # mS/cm -> S/m
    near = (tt > t_desc - 60) & (tt < t_desc + bottom_s + 60)
    alt_true = np.where(near, 50.0 + 10 * np.cos(tt / 300.0), np.nan)
    sa = gsw.SA_from_SP(S, P, LON, LAT)
    c_path = gsw.sound_speed_t_exact(sa, T, P + 0.5 * np.nan_to_num(alt_true) * 1.05)
    df = pd.DataFrame({
        "time": T0 + pd.to_timedelta(tt, unit="s"),
        "conductivity_s_m": C, "temperature_its90_degc": T,
        "pressure_ctd_dbar": np.minimum(P + ctd_offset + rng.normal(0, 0.1, tt.size), 10_500.0),
        "pressure_gauge_dbar": P + gauge_offset + rng.normal(0, 0.05, tt.size),
        "altitude_m": np.round(alt_true * 1500.0 / c_path / 0.3) * 0.3,  # 0.3 m resolution, 1500 m/s nominal
        "heading_deg": 0.0, "pitch_deg": 0.0, "roll_deg": 0.0,
        "dr_east_m": 0.1 * tt, "dr_north_m": -0.05 * tt, "speed_m_s": 0.5,
    })
    for c in ("conductivity_s_m", "temperature_its90_degc", "pressure_ctd_dbar", "pressure_gauge_dbar", "altitude_m"):
        df[c + "_qc"] = np.where(np.isfinite(df[c]), 1, 9).astype("uint8")
    df.loc[df["pressure_ctd_dbar"] >= 10_500.0, "pressure_ctd_dbar_qc"] = 4
    return df, z, z + alt_true


@pytest.fixture(scope="module")
def synth():
    return synth_sensors()


def _raw_dive(tmp: Path) -> Path:
    raw = tmp / "raw"
    raw.mkdir(parents=True, exist_ok=True)
    dive = {"dive_id": "D001", "platform": "test", "launch": {"latitude_deg": LAT, "longitude_deg": LON},
            "map_frame": {"origin_latitude_deg": 11.33, "origin_longitude_deg": 142.2}}
    (raw / "dive.yaml").write_text(yaml.safe_dump(dive))
    return raw


def _publish_sensors(ctx, df: pd.DataFrame) -> None:
    with ctx.store.publish(ctx.dive_id, "sensors", parameters={}) as draft:
        write_parquet(df, draft.path / "sensors.parquet", metadata={"dive_id": ctx.dive_id})


@pytest.fixture(scope="module")
def derived(synth, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("derive")
    ctx = make_context(_raw_dive(tmp), tmp / "store")
    _publish_sensors(ctx, synth[0])
    out = run_stage("derive", ctx)
    out |= run_stage("profile", ctx)  # the binned casts: the profile stage (after match when the dive has one)
    return ctx, out


def test_stage_contract():
    assert derive.STAGE.products == ("ctd", "cast_profiles", "trajectory")
    assert derive.STAGE.reads == ("sensors", "casts")
    p = DeriveParams()
    assert p.profile_bin_dbar == 10.0 and p.nominal_sound_speed_m_s == 1500.0 and p.latitude_deg is None
    with pytest.raises(ValidationError):
        DeriveParams(profile_bin_dbar=0)
    with pytest.raises(ValidationError):
        DeriveParams(gauge_bias_window_dbar=(10_000, 6000))
    with pytest.raises(ValidationError):
        DeriveParams(unknown=1)


def test_ctd_product_recovers_true_depth(derived, synth):
    _, z, seafloor = synth
    _, out = derived
    assert set(out) == {"ctd", "profile"}
    df = pd.read_parquet(out["ctd"].file("ctd.parquet"))
    assert list(df.columns[: len(CTD_COLUMNS)]) != [] and set(CTD_COLUMNS) <= set(df.columns)
    i = int(np.argmax(z))
    assert z[i] == pytest.approx(10_900.0)
    # acceptance: true depth within 1 m at 10 900 m (pressure there comes from the gauge: CTD saturated)
    assert df["pressure_source"].iloc[i] == "gauge"
    assert abs(df["depth_m"].iloc[i] - z[i]) < 1.0
    assert np.nanmax(np.abs(df["depth_m"] - z)) < 1.0  # gauge datum (0.3 dbar offset) and noise included
    assert abs(df["depth_fofonoff_millard_m"].iloc[i] - z[i]) > 5.0
    assert abs(df["depth_teos10_m"].iloc[i] - z[i]) < 1.0
    ok = np.isfinite(seafloor)
    assert df["seafloor_depth_m"].notna().to_numpy()[ok].mean() > 0.95
    assert np.nanmax(np.abs(df["seafloor_depth_m"].to_numpy()[ok] - seafloor[ok])) < 1.5
    assert df["seafloor_depth_m"].isna().to_numpy()[~ok].all()
    assert set(df["phase"]) == {"descent", "bottom", "ascent"}
    assert df["phase"].iloc[0] == "descent" and df["phase"].iloc[-1] == "ascent"
    g = df["gravity_m_s2"].to_numpy()
    assert g[i] > g[0]  # gravity increases with depth
    assert df["practical_salinity"].iloc[i] == pytest.approx(34.7, abs=1e-3)


def test_ctd_metadata(derived, synth):
    _, z, _ = synth
    _, out = derived
    meta, cols = read_parquet_metadata(out["ctd"].file("ctd.parquet"))
    assert meta["gauge_bias_dbar"] == pytest.approx(1.1, abs=0.03) and meta["gauge_bias_samples"] > 100
    assert meta["pressure_datum"] == "gauge"
    assert meta["latitude_deg"] == LAT and meta["latitude_source"] == "dive launch"
    dp = meta["deepest_point"]
    assert abs(dp["depth_m"] - 10_900.0) < 1.0
    assert {"time", "dr_east_m", "dr_north_m", "longitude_deg", "latitude_deg"} <= set(dp)
    assert abs(dp["latitude_deg"] - LAT) < 0.01 and abs(dp["longitude_deg"] - LON) < 0.02
    comp = meta["depth_comparison"]
    assert comp["hydrostatic_minus_fofonoff_millard"]["max_abs_m"] > 5.0
    assert comp["hydrostatic_minus_teos10"]["max_abs_m"] < 1.5
    assert set(meta["phases"]) == {"descent", "bottom", "ascent"}
    for c in ("depth_m", "density_kg_m3", "practical_salinity", "sound_speed_m_s", "seafloor_depth_m"):
        assert cols[c].get("units") and cols[c].get("standard_name") and cols[c].get("long_name"), c
    assert cols["gravity_m_s2"]["units"] == "m s-2"
    man = out["ctd"].manifest()
    assert man["upstream"] and "deepest_point" in json.dumps(man)


def test_profile_product(derived):
    _, out = derived
    raw = xr.open_dataset(out["profile"].file("profile.nc"), engine="h5netcdf")
    # the casts as CF flags of the ragged file's profiles (hadal.products.dsg), read back on their bins
    assert raw.sizes["profile"] == 2 and raw["cast"].attrs["flag_meanings"] == "descent ascent"
    assert int(raw["row_size"].sum()) == raw.sizes["obs"]
    ds = orthogonal_profile(raw.load())
    assert list(ds["cast"].values) == ["descent", "ascent"]
    assert float(ds["pressure_dbar"][1] - ds["pressure_dbar"][0]) == pytest.approx(10.0)
    for v in ("temperature_its90_degc", "conductivity_s_m", "practical_salinity", "density_kg_m3",
              "gravity_m_s2", "depth_m", "depth_fofonoff_millard_m", "depth_teos10_m", "sound_speed_m_s", "count"):
        assert v in ds and ds[v].dims == ("cast", "pressure_dbar"), v
        assert ds[v].attrs.get("units"), v
        if v not in ("gravity_m_s2", "count"):
            assert ds[v].attrs.get("standard_name"), v
    assert int(ds["count"].sum()) > 0.9 * len(pd.read_parquet(out["ctd"].file("ctd.parquet"), columns=["phase"])
                                             .query("phase != 'bottom'"))
    deep = ds["depth_m"].isel(cast=0).dropna("pressure_dbar")
    assert float(deep.max()) > 10_800 and np.all(np.diff(deep.values) > 0)


def test_profile_passes_cf_acdd_compliance(derived):
    pytest.importorskip("compliance_checker")
    from hadal.products.compliance import check_compliance

    _, out = derived
    rep = check_compliance(out["profile"].file("profile.nc"))
    assert rep.ok, rep.describe()


def test_missing_upstream_and_bad_sensors_publish_nothing(tmp_path, synth):
    raw = _raw_dive(tmp_path)
    ctx = make_context(raw, tmp_path / "store")
    with pytest.raises(StageError, match="sensors"):
        run_stage("derive", ctx)
    _publish_sensors(ctx, synth[0].drop(columns=["conductivity_s_m"]).iloc[:50])
    with pytest.raises(InputError, match="conductivity_s_m"):
        run_stage("derive", ctx)
    bad = synth[0].iloc[:50].copy()
    bad["pressure_ctd_dbar"] = np.nan
    bad["pressure_gauge_dbar"] = np.nan
    _publish_sensors(ctx, bad)
    with pytest.raises(InputError, match="no valid pressure"):
        run_stage("derive", ctx)
    assert not ctx.store.has("D001", "ctd") and not ctx.store.has("D001", "profile")


def test_latitude_override_and_rectangle_rule(tmp_path, synth):
    raw = _raw_dive(tmp_path)
    (raw / "pipeline.yaml").write_text(yaml.safe_dump({"derive": {"latitude_deg": 45.0,
                                                                   "depth_integration": "rectangle"}}))
    ctx = make_context(raw, tmp_path / "store")
    _publish_sensors(ctx, synth[0].iloc[::10].reset_index(drop=True))
    out = run_stage("derive", ctx)
    meta, _ = read_parquet_metadata(out["ctd"].file("ctd.parquet"))
    assert meta["latitude_deg"] == 45.0 and "rectangle" in meta["depth_method"]
    assert meta["latitude_source"] == "derive.latitude_deg parameter"


def test_sample_dive_true_depth(small_run):
    """Acceptance on the synthetic sample dive (``hadal synth``, pressure from TEOS-10 ``gsw.p_from_z`` with
    dynamic height): true depth within 1 m at ~10 900 m, the deepest point reported."""
    ctx, out = small_run
    raw = ctx.raw_dir
    df = pd.read_parquet(out["ctd"].file("ctd.parquet"))
    truth = pd.read_parquet(raw / "truth" / "track.parquet")
    t0 = pd.Timestamp(df["time"].iloc[0])

    def seconds(s):
        return (pd.to_datetime(s, utc=True) - t0).dt.total_seconds().to_numpy()

    true_depth = np.interp(seconds(df["time"]), seconds(truth["time"]), truth["depth_m"].to_numpy())
    i = int(np.nanargmax(true_depth))
    assert true_depth[i] > 10_800
    assert abs(df["depth_m"].iloc[i] - true_depth[i]) < 1.0
    assert np.nanmedian(np.abs(df["depth_m"].to_numpy() - true_depth)) < 1.0
    assert abs(df["depth_fofonoff_millard_m"].iloc[i] - true_depth[i]) > 3.0
    meta, _ = read_parquet_metadata(out["ctd"].file("ctd.parquet"))
    assert abs(meta["deepest_point"]["depth_m"] - float(np.nanmax(true_depth))) < 1.0


def test_derive_ctd_without_gauge_or_altimeter(synth):
    """A CTD-only cast (e.g. read from a .cnv): no gauge, no altimeter; depth still computed, seafloor NaN."""
    df = synth[0].drop(columns=["pressure_gauge_dbar", "pressure_gauge_dbar_qc", "altitude_m", "altitude_m_qc"])
    df = df[df["pressure_ctd_dbar"] < 5000].iloc[::5].reset_index(drop=True)
    out, meta = derive_ctd(df, LAT, LON, DeriveParams())
    assert set(out["pressure_source"]) == {"ctd"} and meta["gauge_bias_dbar"] == 0.0
    assert out["seafloor_depth_m"].isna().all() and out["altitude_corrected_m"].isna().all()
    assert np.isfinite(out["depth_m"]).all() and "deepest_seafloor" not in meta
    # flagged-bad temperature samples give NaN salinity/density but the depth integral bridges them
    df.loc[100:110, "temperature_its90_degc_qc"] = 4
    out2, _ = derive_ctd(df, LAT, LON, DeriveParams())
    assert out2["practical_salinity"].iloc[100:111].isna().all()
    assert np.nanmax(np.abs(out2["depth_m"] - out["depth_m"])) < 0.05


TEOS10 = {"absolute_salinity_g_kg": "sea_water_absolute_salinity",
          "conservative_temperature_degc": "sea_water_conservative_temperature",
          "potential_temperature_degc": "sea_water_potential_temperature", "sigma0_kg_m3": "sea_water_sigma_theta",
          "buoyancy_frequency_squared_s2": "square_of_brunt_vaisala_frequency_in_sea_water"}


def test_teos10_columns_in_ctd_and_profile(derived, synth):
    """TEOS-10 next to EOS-80: values against gsw on the dive's own salinity/temperature, CF names in both."""
    _, out = derived
    df = pd.read_parquet(out["ctd"].file("ctd.parquet"))
    _, cols = read_parquet_metadata(out["ctd"].file("ctd.parquet"))
    for name, std in TEOS10.items():
        assert cols[name]["standard_name"] == std and cols[name]["units"], name
    p = df["pressure_dbar"].to_numpy()
    sa = gsw.SA_from_SP(df["practical_salinity"].to_numpy(), p, LON, LAT)
    ct = gsw.CT_from_t(sa, df["temperature_its90_degc"].to_numpy(), p)
    assert np.nanmax(np.abs(df["absolute_salinity_g_kg"] - sa)) < 1e-12
    assert np.nanmax(np.abs(df["conservative_temperature_degc"] - ct)) < 1e-12
    assert np.nanmax(np.abs(df["sigma0_kg_m3"] - gsw.sigma0(sa, ct))) < 1e-12
    # the synthetic column is stably stratified: N² > 0 nearly everywhere, ~1e-5 s-2 or less in the deep
    n2 = df["buoyancy_frequency_squared_s2"].to_numpy()
    assert np.isfinite(n2).mean() > 0.95 and (n2[np.isfinite(n2)] > 0).mean() > 0.95
    ds = orthogonal_profile(xr.open_dataset(out["profile"].file("profile.nc"), engine="h5netcdf").load())
    for name, std in TEOS10.items():
        assert ds[name].attrs["standard_name"] == std and ds[name].dims == ("cast", "pressure_dbar"), name
    assert float(ds["sigma0_kg_m3"].isel(cast=0).max()) == pytest.approx(
        float(np.nanmax(gsw.sigma0(sa, ct))), abs=0.01)


def test_chain_parameters_in_manifest(tmp_path, synth):
    raw = _raw_dive(tmp_path)
    chain = {"wild_edit": True, "filter_temperature_s": 0.5, "align_conductivity_s": 0.5, "cell_thermal_mass": True,
             "loop_edit": True, "loop_edit_min_velocity_m_s": 0.1, "profile_binning": "seabird"}
    (raw / "pipeline.yaml").write_text(yaml.safe_dump({"derive": chain}))
    ctx = make_context(raw, tmp_path / "store")
    _publish_sensors(ctx, synth[0].iloc[::4].reset_index(drop=True))
    out = run_stage("derive", ctx)
    out |= run_stage("profile", ctx)
    for prod in ("ctd", "profile"):
        params = json.dumps(out[prod].manifest())
        for k in chain:
            assert f'"{k}"' in params, (prod, k)
    meta, _ = read_parquet_metadata(out["ctd"].file("ctd.parquet"))
    assert [s["step"] for s in meta["ctd_processing"]] == ["wild_edit", "filter", "align_ctd", "cell_thermal_mass",
                                                           "loop_edit"]
    df = pd.read_parquet(out["ctd"].file("ctd.parquet"))
    # the bottom phase (slow, back and forth) is what LoopEdit removes
    bad = df["loop_edit_bad"].to_numpy()
    assert bad[(df["phase"] == "bottom").to_numpy()].mean() > 0.5 and bad[(df["phase"] == "descent").to_numpy()].mean() < 0.05
    ds = orthogonal_profile(xr.open_dataset(out["profile"].file("profile.nc"), engine="h5netcdf").load())
    # SeaSoft BinAvg centres k x 10 dbar, k >= 1 (the ragged file keeps the non-empty bins only)
    centres = ds["pressure_dbar"].values
    assert ds.attrs.get("binning") == "seabird BinAvg" and centres[0] >= 10.0
    np.testing.assert_allclose(centres / 10.0, np.rint(centres / 10.0))
