"""Stage ingest end to end on a tiny dive (MCAP and CSV) and, when present, the generated sample dive."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest
import yaml

from hadal.dive import load_dive
from hadal.errors import InputError
from hadal.products import read_parquet_metadata
from hadal.settings import PipelineConfig
from hadal.stages import StageContext, ingest
from hadal.store import ProductStore, sha256_file

sys.path.insert(0, str(Path(__file__).parents[2] / "malformed"))
from tiny_dive import T0, truth, write_dive  # noqa: E402


def _run(raw: Path, store: Path, **params):
    dive, rdir = load_dive(raw)
    ctx = StageContext(dive=dive, raw_dir=rdir, store=ProductStore(store),
                       config=PipelineConfig.model_validate({"ingest": params}))
    pv = ingest.run(ctx)["sensors"]
    path = pv.file("sensors.parquet")
    meta, cols = read_parquet_metadata(path)
    return pv, pd.read_parquet(path), meta, cols


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    d = tmp_path_factory.mktemp("dive")
    raw = write_dive(d / "raw", 30.0)
    return {src: _run(raw, d / "store", source=src) for src in ("mcap", "csv")}, raw


def test_stage_contract(runs):
    (pv, df, meta, cols), raw = runs[0]["mcap"], runs[1]
    assert ingest.STAGE.products == ("sensors", "casts") and ingest.STAGE.reads == ()
    expected = ["time", "conductivity_s_m", "temperature_its90_degc", "pressure_ctd_dbar", "pressure_gauge_dbar",
                "altitude_m", "heading_deg", "pitch_deg", "roll_deg", "dr_east_m", "dr_north_m", "speed_m_s"]
    assert list(df.columns[:12]) == expected
    assert set(df.columns[12:]) == {f"{c}_qc" for c in expected[1:]}
    schema = pq.read_schema(pv.file("sensors.parquet"))
    assert str(schema.field("time").type) == "timestamp[ns, tz=UTC]"
    assert str(schema.field("pressure_ctd_dbar_qc").type) == "uint8"
    assert cols["conductivity_s_m"]["units"] == "S m-1"
    assert cols["conductivity_s_m"]["standard_name"] == "sea_water_electrical_conductivity"
    assert cols["pressure_ctd_dbar_qc"]["flag_values"] == "1 2 3 4 9"
    assert len(df) == 30 * 16 and meta["time_base_rate_hz"] == pytest.approx(16.0, rel=1e-3)
    assert meta["dive_id"] == "tiny-dive" and meta["source_kind"] == "mcap" and meta["messages_lost"] == 0
    man = pv.manifest()
    by_path = {i["path"]: i["sha256"] for i in man["inputs"]}
    mcap = (raw / "logs" / "haidou.mcap").resolve()
    assert by_path[str(mcap)] == sha256_file(mcap)
    assert any(s["sha256"] == sha256_file(mcap) for s in meta["sources"])
    assert man["parameters"]["source"] == "mcap"


def test_values_match_truth(runs):
    _, df, meta, _ = runs[0]["mcap"]
    t = df["time"].astype("int64").to_numpy() / 1e9
    tr = truth(t)
    np.testing.assert_allclose(df["conductivity_s_m"], tr["cond"], atol=1e-12)
    ok = df["pressure_gauge_dbar_qc"] == 1
    np.testing.assert_allclose(df.loc[ok, "pressure_gauge_dbar"], tr["pressure"][ok], atol=1e-6)  # linear truth
    ok = df["dr_east_m_qc"] == 1
    np.testing.assert_allclose(df.loc[ok, "dr_east_m"], tr["east"][ok], atol=1e-6)
    h = df["heading_deg"].to_numpy()
    d = np.abs((h - tr["heading"] + 180) % 360 - 180)
    assert np.nanmax(d) < 1e-6  # circular interpolation across 360 -> 0
    # the altimeter's nearest-sample alignment keeps dropouts as NaN + flag 9
    assert (df["altitude_m_qc"] == 9).sum() == df["altitude_m"].isna().sum() > 0
    # last DR sample at T0+29 s: later CTD samples are outside the stream -> 9
    assert (df.loc[t > T0 + 29.0 + 1e-9, "dr_east_m_qc"] == 9).all()


def test_mcap_and_csv_agree(runs):
    _, a, _, _ = runs[0]["mcap"]
    _, b, meta_csv, _ = runs[0]["csv"]
    assert meta_csv["source_kind"] == "csv"
    conv = {(c["variable"], c["from"]) for c in meta_csv["unit_conversions"]}
    assert conv == {("conductivity_s_m", "mS/cm"), ("pressure_gauge_dbar", "bar")}
    assert (a["time"] == b["time"]).all()
    for col in a.columns[1:12]:
        np.testing.assert_allclose(a[col], b[col], rtol=1e-12, atol=1e-9, err_msg=col)
    for col in a.columns[12:]:
        assert (a[col] == b[col]).all(), col


def test_versions_and_reproducibility(runs, tmp_path):
    raw = runs[1]
    pv1, df1, _, _ = _run(raw, tmp_path / "s", source="mcap")
    pv2, df2, _, _ = _run(raw, tmp_path / "s", source="mcap")
    assert (pv1.version, pv2.version) == (1, 2)
    pd.testing.assert_frame_equal(df1, df2)


def test_sample_dive(small_run):
    ctx, out = small_run
    path = out["sensors"].file("sensors.parquet")
    meta, _ = read_parquet_metadata(path)
    df = pd.read_parquet(path)
    from hadal.ingest import mcap_info

    n_ctd = next(c["messages"] for c in mcap_info(ctx.raw_dir / "logs" / "haidou.mcap") if c["topic"] == "/haidou/ctd")
    assert len(df) == n_ctd > 1000  # the CTD is the time base (16 Hz full dive; reduced rate in the small one)
    assert meta["time_base_rate_hz"] > 0
    assert df["time"].is_monotonic_increasing and df["time"].is_unique
    assert (df["conductivity_s_m_qc"] == 1).mean() > 0.9
    assert meta["messages_lost"] == 0
    assert (df["pressure_ctd_dbar_qc"] == 4).sum() == (df["pressure_ctd_dbar"] >= 10_500).sum()
    for var in ("heading_deg", "dr_east_m", "pressure_gauge_dbar"):
        assert (df[f"{var}_qc"] == 1).mean() > 0.9, var


def test_cnv_source(shared_data, tmp_path):
    """A dive whose only sensor log is a Sea-Bird .cnv (SBE 19plus, 4 Hz): CTD-only table, others flag 9."""
    import shutil

    raw = write_dive(tmp_path / "raw", 5.0)
    shutil.copy(shared_data / "ctd-real" / "sbs_19plus_V2_CTD-processing_example.cnv", raw / "cast.cnv")
    y = yaml.safe_load((raw / "dive.yaml").read_text())
    y["sources"] = {"cnv": ["cast.cnv"]}
    (raw / "dive.yaml").write_text(yaml.safe_dump(y))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        pv, df, meta, _ = _run(raw, tmp_path / "store")
    assert meta["source_kind"] == "cnv" and len(df) == 3069
    assert meta["time_base_rate_hz"] == pytest.approx(4.0)
    assert df["time"].iloc[0] == pd.Timestamp("2016-12-10T06:16:51Z")
    assert df["conductivity_s_m"].iloc[0] == pytest.approx(0.008453)
    assert df["pressure_ctd_dbar"].iloc[0] == pytest.approx(-0.105)
    assert (df["pressure_gauge_dbar_qc"] == 9).all() and (df["heading_deg_qc"] == 9).all()
    assert (df["temperature_its90_degc_qc"] == 1).mean() > 0.95
    assert meta["read_stats"]["ctd"]["channels"]["temperature_its90_degc"] == "tv290C"


def test_cnv_its68_conversion_recorded(shared_data):
    from hadal.ingest import cnv_sensor_samples, read_cnv

    df = read_cnv(shared_data / "ctd-real" / "seabird_dPIRX010.cnv")
    s = cnv_sensor_samples(df)
    assert s.stats["time"] == "start_time + timeS" and len(s) == 1014
    assert s.time_ns[1] - s.time_ns[0] == 13_522_000_000  # timeS 0.625 -> 14.147
    df.attrs["start_time_utc"] = None
    with pytest.raises(InputError, match="no time channel"):
        cnv_sensor_samples(df)
    # an ITS-68 column is converted (T90 = T68 / 1.00024) and recorded
    df2 = read_cnv(shared_data / "ctd-real" / "pyctd_CTD_with_sigma_e00.cnv")
    df2["timeS"] = np.arange(len(df2)) * 1.0
    s2 = cnv_sensor_samples(df2)
    assert s2.values["temperature_its90_degc"][0] == pytest.approx(19.7225 / 1.00024)
    assert s2.conversions[0]["formula"] == "T90 = T68 / 1.00024"
