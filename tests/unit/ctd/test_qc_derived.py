"""QARTOD flags on derived variables (issue 17 §3): range checks on the inputs, impossible results flagged 4,
thresholds from the shipped YAML, flag metadata in Parquet and CF ancillary variables in NetCDF.

Oracle: the QARTOD gross-range rule written out sample by sample (below), and hand-made cases whose flag is
known (T = 99 °C, latitude 91°, a density of 1200 kg m-3)."""

from __future__ import annotations

import math

import numpy as np
import pandas as pd
import pytest
import yaml

from hadal.errors import ConfigError
from hadal.qc_derived import (
    DERIVED,
    DerivedVariableQC,
    apply_to_table,
    flags_for,
    load_qc_config,
    qc_derived_table,
)
from hadal.settings import DeriveParams

LAT, LON = 11.33, 142.2


def brute_force_range_flag(x: float, fail: tuple[float, float] | None, suspect: tuple[float, float] | None) -> int:
    """IOOS QARTOD manual gross range test, one value: 9 missing, 4 outside the fail span, 3 outside the suspect
    span, else 1."""
    if not math.isfinite(x):
        return 9
    if fail and (x < fail[0] or x > fail[1]):
        return 4
    if suspect and (x < suspect[0] or x > suspect[1]):
        return 3
    return 1


def test_shipped_yaml_is_typed_and_documented():
    from importlib import resources

    text = resources.files("hadal").joinpath("data/qc_derived.yaml").read_text(encoding="utf-8")
    raw = yaml.safe_load(text)
    cfg = load_qc_config()
    assert set(DERIVED) <= set(cfg.derived) and {"temperature_its90_degc", "latitude_deg"} <= set(cfg.inputs)
    assert all(isinstance(v, DerivedVariableQC) for v in cfg.derived.values())
    assert set(raw["derived"]) == set(cfg.derived)
    for name in list(raw["inputs"]) + list(raw["derived"]):  # every entry carries a comment saying why
        line = next(ln for ln in text.splitlines() if ln.strip().startswith(f"{name}:"))
        assert "#" in line, name


@pytest.mark.parametrize("name", ["practical_salinity", "density_kg_m3", "sound_speed_m_s", "depth_m",
                                  "temperature_its90_degc", "pressure_dbar"])
def test_range_flags_match_the_qartod_rule(name):
    cfg = load_qc_config()
    c = cfg.derived.get(name) or cfg.inputs[name]
    c = c.model_copy(update={"spike_suspect": None, "spike_fail": None})
    lo, hi = c.fail_span
    rng = np.random.default_rng(0)
    x = rng.uniform(lo - 0.2 * (hi - lo), hi + 0.2 * (hi - lo), 2000)
    x[::97] = np.nan
    x[1:4] = [lo, hi, c.suspect_span[0]]  # the span ends themselves pass
    got = flags_for(x, c)
    want = [brute_force_range_flag(v, c.fail_span, c.suspect_span) for v in x]
    np.testing.assert_array_equal(got, want)


def _table(n=50):
    p = np.linspace(10.0, 6000.0, n)
    return pd.DataFrame({"temperature_its90_degc": np.full(n, 2.0), "conductivity_s_m": np.full(n, 3.2),
                         "pressure_dbar": p, "practical_salinity": np.full(n, 34.7),
                         "density_kg_m3": np.linspace(1028.0, 1055.0, n), "sound_speed_m_s": np.full(n, 1500.0),
                         "depth_m": p * 0.99, "altitude_m": np.full(n, 40.0), "seafloor_depth_m": p * 0.99 + 40})


def test_input_temperature_99_flags_what_it_made_4():
    df = _table()
    df.loc[7, "temperature_its90_degc"] = 99.0
    f = qc_derived_table(df, load_qc_config(), latitude_deg=LAT, longitude_deg=LON)
    assert f["temperature_its90_degc_range_qc"][7] == 4
    for var in ("practical_salinity", "density_kg_m3", "sound_speed_m_s"):
        assert f[f"{var}_qc"][7] == 4 and set(np.delete(f[f"{var}_qc"], 7)) == {1}
    assert f["depth_m_qc"][7] == 1  # depth does not depend on T (through the density only, by ~1e-5)


def test_latitude_91_flags_depths_4_not_salinity():
    df = _table()
    f = qc_derived_table(df, load_qc_config(), latitude_deg=91.0, longitude_deg=LON)
    assert set(f["depth_m_qc"]) == {4} and set(f["seafloor_depth_m_qc"]) == {4}
    assert set(f["practical_salinity_qc"]) == {1}


def test_physically_impossible_results_flagged_4_and_missing_9():
    df = _table()
    df.loc[3, "density_kg_m3"] = 1200.0
    df.loc[4, "depth_m"] = 12_500.0
    df.loc[5, "sound_speed_m_s"] = 1200.0
    df.loc[6, "practical_salinity"] = np.nan
    df.loc[10:14, "practical_salinity"] = 45.0  # outside PSS-78's 2-42 (no spike inside the block): suspect
    f = qc_derived_table(df, load_qc_config(), latitude_deg=LAT)
    assert f["density_kg_m3_qc"][3] == 4 and f["depth_m_qc"][4] == 4 and f["sound_speed_m_s_qc"][5] == 4
    assert f["practical_salinity_qc"][6] == 9 and f["practical_salinity_qc"][12] == 3


def test_spike_in_salinity_suspect_or_fail():
    df = _table()
    df.loc[20, "practical_salinity"] = 34.9  # 0.2 above both neighbours: suspect (0.1 < 0.2 < 0.5)
    df.loc[30, "practical_salinity"] = 35.5  # 0.8: fail
    f = qc_derived_table(df, load_qc_config(), latitude_deg=LAT)["practical_salinity_qc"]
    assert f[20] == 3 and f[30] == 4


def test_overrides_merge_and_bad_overrides_are_config_errors():
    cfg = load_qc_config({"depth_m": {"fail_span": [-10, 12_000], "suspect_span": [-2, 11_900]}})
    assert cfg.derived["depth_m"].fail_span == (-10.0, 12_000.0)
    assert cfg.derived["depth_m"].depends_on == ["pressure_dbar", "latitude_deg"]  # the rest kept
    with pytest.raises(ConfigError, match="unknown variable"):
        load_qc_config({"salinty": {"fail_span": [0, 1]}})
    with pytest.raises(ConfigError, match="suspect_span must lie inside"):
        load_qc_config({"depth_m": {"fail_span": [0, 100]}})
    from pydantic import ValidationError


    with pytest.raises(ValidationError, match="unknown variable"):
        DeriveParams(qc_thresholds={"nope": {"fail_span": [0, 1]}})
    with pytest.raises(ValidationError):
        DeriveParams(qc_thresholds={"depth_m": {"fail_span": [5, 1]}})


def test_apply_to_table_merges_input_flags_and_summarises():
    df = _table()
    df["temperature_its90_degc_qc"] = np.ones(len(df), np.uint8)
    df.loc[2, "temperature_its90_degc_qc"] = 3  # from ingest (spike)
    df.loc[7, "temperature_its90_degc"] = 99.0
    meta = apply_to_table(df, load_qc_config(), latitude_deg=91.0, longitude_deg=LON)
    t = df["temperature_its90_degc_qc"].to_numpy()
    assert t[2] == 3 and t[7] == 4 and "pressure_dbar_qc" in df
    assert meta["position"]["latitude_deg"] == {"value": 91.0, "flag": 4}
    s = meta["summary"]
    assert s["depth_m"]["counts"]["fail"] == len(df) and s["practical_salinity"]["counts"]["fail"] == 1
    assert meta["flag_meanings"]["4"] == "fail"


def test_derive_stage_writes_flags_metadata_and_ancillary_variables(tmp_path):
    """Through the stage: <var>_qc columns with CF flag field metadata and ancillary_variables in ctd.parquet,
    CF ancillary flag variables in profile.nc, the per-variable summary in the metadata and the manifest."""
    import xarray as xr
    from test_derive import _publish_sensors, _raw_dive, synth_sensors

    from hadal.pipeline import make_context, run_stage
    from hadal.products.io import read_parquet_metadata

    df, _, _ = synth_sensors(dt=20.0, max_depth=6000.0, bottom_s=600.0)
    df = df.drop(columns=["temperature_its90_degc_qc"])
    df.loc[100, "temperature_its90_degc"] = 99.0  # no ingest flag for it: only derive's range check sees it
    ctx = make_context(_raw_dive(tmp_path), tmp_path / "store")
    _publish_sensors(ctx, df)
    out = run_stage("derive", ctx) | run_stage("profile", ctx)
    path = out["ctd"].file("ctd.parquet")
    ctd = pd.read_parquet(path)
    meta, fields = read_parquet_metadata(path)
    for var in DERIVED:
        assert ctd[f"{var}_qc"].dtype == np.uint8
        assert fields[var]["ancillary_variables"] == f"{var}_qc"
        assert fields[f"{var}_qc"]["flag_meanings"] == "pass not_evaluated suspect fail missing"
        assert fields[f"{var}_qc"]["flag_values"] == "1 2 3 4 9" and "QARTOD" in fields[f"{var}_qc"]["comment"]
    assert ctd["temperature_its90_degc_qc"].iloc[100] == 4 and ctd["practical_salinity_qc"].iloc[100] == 4
    assert ctd["practical_salinity_qc"].drop(index=100).isin([1]).mean() > 0.99
    s = meta["qc_derived"]["summary"]
    assert s["practical_salinity"]["counts"]["fail"] >= 1 and set(s) == set(DERIVED)
    assert out["ctd"].manifest()["summary"]["qc_flags"]["depth_m"]["pass"] > 0
    with xr.open_dataset(out["profile"].file("profile.nc")) as ds:
        for var in ("practical_salinity", "density_kg_m3", "sound_speed_m_s", "depth_m"):
            assert ds[var].attrs["ancillary_variables"] == f"{var}_qc"
            q = ds[f"{var}_qc"]
            assert q.attrs["flag_meanings"] == "pass not_evaluated suspect fail missing"
            assert list(np.asarray(q.attrs["flag_values"])) == [1, 2, 3, 4, 9]
    assert "profile" in meta["qc_derived"]
