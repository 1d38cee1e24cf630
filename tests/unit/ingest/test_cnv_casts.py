"""Every real Sea-Bird cast through read_cnv -> ingest -> derive -> report, alone or next to vehicle logs.

Dives are built in tmp_path with a dive.yaml that lists only the cast (no launch, no map frame). SeaSoft's own
derived columns are the oracle for derive's results (tolerances in ../shared/data/README.md).
"""

from __future__ import annotations

import bz2
import gzip
import json
import lzma
import shutil
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml

from hadal import seawater as sw
from hadal.errors import HadalError, InputError
from hadal.ingest.cnv import NO_TIME_BASE, describe_cnv, read_cnv, read_seabird, seabird_kind
from hadal.products.io import read_parquet_metadata

CTD_REAL = ["seabird_sta0860.cnv", "seabird_dPIRX010.cnv", "sbs_19plus_V2_CTD-processing_example.cnv",
            "oceissues644_02dk.cnv", "pyctd_CTD_with_sigma_e00.cnv"]
FORMATS_REAL = ["sbs_SBE19plus_01906398_2019_07_15_0033_cropped.cnv",
                "sbs_SBE19plus_01906398_2019_07_15_0033_cropped_loopedit.cnv",
                "sbs_SBE19plus_01906398_2019_07_15_0033_cropped_loopedit_wildedit.cnv",
                "sbs_SBE19plus_01906398_2019_07_15_0033_cropped_binavg.cnv"]
#: casts without a time channel (pressure-binned): processed as profiles
BINNED_NO_TIME = {"seabird_sta0860.cnv", "oceissues644_02dk.cnv", "pyctd_CTD_with_sigma_e00.cnv"}


def _src(shared: Path, name: str) -> Path:
    return shared / ("ctd-real" if name in CTD_REAL else "formats-real") / name


def _cast_dive(tmp: Path, shared: Path, name: str, **extra) -> Path:
    raw = tmp / "raw"
    raw.mkdir(parents=True, exist_ok=True)
    shutil.copy(_src(shared, name), raw / name)
    (raw / "dive.yaml").write_text(yaml.safe_dump({"dive_id": "cast", "sources": {"cnv": [name]}, **extra}))
    return raw


def _run(raw: Path, store: Path, stages=("ingest", "derive", "profile", "report")):
    from hadal.pipeline import make_context, run_stage

    ctx = make_context(raw, store)
    out = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for st in stages:
            out.update(run_stage(st, ctx))
    return ctx, out


# ---------------------------------------------------------------------------------------------- reader
@pytest.mark.parametrize("name", CTD_REAL + FORMATS_REAL)
def test_reader_details(shared_data, name):
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        df = read_cnv(_src(shared_data, name))
    a = df.attrs
    json.dumps(a)
    # no false 'truncated or edited' warning: only the cropped oce-issues file really is truncated
    trunc = [x for x in w if "truncated" in str(x.message)]
    assert bool(trunc) == (name == "oceissues644_02dk.cnv") == a["truncated"]
    # SeaSoft processing lines are processing, not comments (loopedit_surfaceSoak:, wfilter_action X = ...)
    assert not any(c.split("_")[0].islower() and "_" in c.split()[0] for c in a["header_comments"])
    keys = [k for k, _ in a["processing"]]
    if any(k.startswith("loopedit_") for k in keys):
        assert all(not c.lower().startswith("loopedit") for c in a["header_comments"])
    assert a["binned"] == (name in BINNED_NO_TIME or name.endswith(("binavg.cnv", "dPIRX010.cnv")))
    if name not in ("seabird_sta0860.cnv", "seabird_dPIRX010.cnv"):  # SeaSoft 7 files carry the XML block
        sx = a["sensors_xml"]
        assert sx and all({"channel", "type", "serial_number", "calibration_date"} <= set(s) for s in sx)
        temp = next(s for s in sx if s["type"] == "TemperatureSensor")
        assert temp["serial_number"] and temp["calibration_date"] and temp["coefficients"]
    for c in a["channels"]:
        assert isinstance(c["notes"], dict)


def test_processing_lines_and_channel_notes(shared_data, tmp_path):
    py = read_cnv(_src(shared_data, "pyctd_CTD_with_sigma_e00.cnv")).attrs
    proc = dict((k, v) for k, v in py["processing"])
    assert proc["loopedit_surfaceSoak"] == "minDepth = 5.0, maxDepth = 40, useDeckPress = 1"
    assert proc["wfilter_action prDM"] == "gaussian, 5, 1, 0"
    oce = read_cnv(_src(shared_data, "oceissues644_02dk.cnv")).attrs
    assert "Flag_code:  0 = no QC; 2 = good; 6 = interpolated;" in oce["header_comments"]
    assert next(s for s in oce["sensors_xml"] if s["channel"] == 1)["calibration_date"] == "26-Sep-12"
    sta = read_cnv(_src(shared_data, "seabird_sta0860.cnv")).attrs
    ox = next(c for c in sta["channels"] if c["column"] == "sbeox0ML/L")
    assert ox["notes"] == {"WS": 2.0}
    # a per-channel latitude note (SeaSoft 'depSM: Depth [salt water, m], lat = 69.41') is read
    text = _src(shared_data, "oceissues644_02dk.cnv").read_bytes().replace(
        b"# name 2 = depSM: Depth [salt water, m]", b"# name 2 = depSM: Depth [salt water, m], lat = 69.41")
    (tmp_path / "lat.cnv").write_bytes(text)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        a = read_cnv(tmp_path / "lat.cnv").attrs
    assert a["channel_latitude_deg"] == {"depSM": pytest.approx(69.41)}


def test_label_line_after_end_not_a_row(tmp_path):
    text = ("* Sea-Bird SBE 9 Data File:\n# nquan = 2\n# nvalues = 2\n# name 0 = prDM: Pressure [db]\n"
            "# name 1 = t090C: Temperature [ITS-90, deg C]\n*END*\n      prDM      t090C\n"
            "      1.000     2.0000\n      2.000     2.1000\n")
    (tmp_path / "l.cnv").write_text(text)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no 'truncated' and no 'dropped' warning
        df = read_cnv(tmp_path / "l.cnv")
    assert len(df) == 2 and df.attrs["column_labels"] == ["prDM", "t090C"] and not df.attrs["truncated"]


@pytest.mark.parametrize("name", CTD_REAL + FORMATS_REAL)
def test_compressed_copies_read_identically(shared_data, tmp_path, name):
    src = _src(shared_data, name)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ref = read_cnv(src)
        for comp, fn in (("gzip", gzip.compress), ("bz2", bz2.compress), ("xz", lzma.compress)):
            # detected by magic bytes, not extension: the xz copy keeps a plain '.cnv' name
            q = tmp_path / (f"{name}.{comp}" if comp != "xz" else f"xz_{name}")
            q.write_bytes(fn(src.read_bytes()))
            df = read_seabird(q)
            pd.testing.assert_frame_equal(df, ref)
            assert df.attrs["compression"] == comp
            assert {k: v for k, v in df.attrs.items() if k not in ("source", "compression")} == \
                   {k: v for k, v in ref.attrs.items() if k not in ("source", "compression")}


def test_corrupt_compressed_is_one_line_error(shared_data, tmp_path):
    q = tmp_path / "cast.cnv.gz"
    q.write_bytes(gzip.compress(_src(shared_data, "seabird_sta0860.cnv").read_bytes())[:500])
    with pytest.raises(InputError, match=r"cast\.cnv\.gz: corrupt or truncated gzip") as ei:
        read_seabird(q)
    assert "\n" not in str(ei.value)


def test_describe_cnv(shared_data, tmp_path):
    q = tmp_path / "sta.cnv.bz2"
    q.write_bytes(bz2.compress(_src(shared_data, "seabird_sta0860.cnv").read_bytes()))
    d = describe_cnv(q)
    json.dumps(d)
    assert d["compression"] == "bz2" and d["scans"] == 88 and d["binned"] and d["profile"]
    assert d["time_base"] == NO_TIME_BASE and d["pressure_range_dbar"] == [3.0, 90.0]
    assert d["latitude_deg"] == pytest.approx(-(25 + 27.85 / 60)) and d["start_time_utc"].startswith("2008-08-28")
    assert {"units": "db", "column": "prDM"}.items() <= next(c for c in d["channels"] if c["column"] == "prDM").items()
    assert d["processing_steps"][:3] == ["datcnv", "wildedit", "celltm"]
    d2 = describe_cnv(_src(shared_data, "sbs_SBE19plus_01906398_2019_07_15_0033_cropped.cnv"))
    assert d2["time_base"] == "start_time + timeS" and not d2["profile"] and d2["compression"] is None
    assert d2["sensors"][0]["serial_number"] == "6398"


def test_seabird_dispatch(shared_data, tmp_path):
    hexf = shared_data / "formats-real" / "sbs_19plus_V2.hex"
    assert seabird_kind(hexf) == "hex"
    assert seabird_kind(_src(shared_data, "seabird_sta0860.cnv")) == "cnv"
    (tmp_path / "x.cnv").write_text("hello\nworld\n")
    with pytest.raises(InputError, match="x.cnv: not a Sea-Bird .cnv or .hex"):
        read_seabird(tmp_path / "x.cnv")
    try:
        import hadal.ingest.seabird_hex  # noqa: F401
    except ImportError:
        pytest.skip("hadal.ingest.seabird_hex (raw .hex conversion) is not written yet")
    df = read_seabird(hexf)
    ref = read_cnv(_src(shared_data, "sbs_19plus_V2_CTD-processing_example.cnv"))
    assert {"prdM", "c0S/m"} <= set(df.columns) and len(df) == len(ref)


# ---------------------------------------------------------------------------------------------- stages
@pytest.mark.parametrize("name", CTD_REAL + FORMATS_REAL)
def test_real_cast_through_ingest_derive_report(shared_data, tmp_path, name):
    raw = _cast_dive(tmp_path, shared_data, name)
    ctx, out = _run(raw, tmp_path / "store")
    assert {"sensors", "ctd", "profile", "report"} <= set(out) and "casts" not in out
    sensors = pd.read_parquet(out["sensors"].file("sensors.parquet"))
    smeta, _ = read_parquet_metadata(out["sensors"].file("sensors.parquet"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cast = read_cnv(_src(shared_data, name))
    assert smeta["cast"]["nvalues"] == len(cast)
    ctd = pd.read_parquet(out["ctd"].file("ctd.parquet"))
    cmeta, _ = read_parquet_metadata(out["ctd"].file("ctd.parquet"))
    if name in BINNED_NO_TIME:
        assert smeta["time_base"] == NO_TIME_BASE and sensors["time"].isna().all() and len(sensors) == len(cast)
        assert smeta["time_coverage_start"] is None
        assert cmeta["time_base"] == NO_TIME_BASE and (ctd["phase"] == "descent").all()
        assert ctd["pressure_dbar"].is_monotonic_increasing
    else:
        assert sensors["time"].notna().all()
    lat = cast.attrs["latitude_deg"]
    if lat is not None:
        assert cmeta["latitude_source"].startswith("cast header") and cmeta["latitude_deg"] == pytest.approx(lat)
        assert "latitude_warning" not in cmeta
    else:  # no latitude anywhere: 45 deg, loudly, with the depth error stated
        assert cmeta["latitude_deg"] == 45.0 and "45 deg" in cmeta["latitude_warning"]
        assert cmeta["latitude_depth_error_max_m"] > 0
    assert "dr_east_m" not in cmeta["deepest_point"] and np.isfinite(ctd["depth_m"]).any()
    summary = json.loads(out["report"].file("summary.json").read_text())
    assert summary["figures"]["fig08_ctd_profiles"] == "ok"
    if name in BINNED_NO_TIME:
        assert summary["figures"]["fig09_depth_time"] == "ok"  # depth against pressure instead of time
        assert "start_utc" not in summary and summary["max_depth_pressure_dbar"] == pytest.approx(cast["prDM"].max())


def _seasoft(cast: pd.DataFrame, prefix: str) -> str | None:
    return next((c for c in cast.columns if c.startswith(prefix) and c.endswith("00")), None)


@pytest.mark.parametrize("name", sorted(BINNED_NO_TIME))
def test_binned_casts_against_seasoft(shared_data, tmp_path, name):
    """derive's salinity / density / depth vs SeaSoft's sal00, sigma-t00 / sigma-theta (sigma-é00), depSM."""
    raw = _cast_dive(tmp_path, shared_data, name)
    _, out = _run(raw, tmp_path / "store", ("ingest", "derive", "profile"))
    ctd = pd.read_parquet(out["ctd"].file("ctd.parquet"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        cast = read_cnv(_src(shared_data, name))
    sp, t, p = (ctd[c].to_numpy() for c in ("practical_salinity", "temperature_its90_degc", "pressure_dbar"))
    ok = np.isfinite(sp) & (sp > 2) & np.isfinite(cast["sal00"].to_numpy())
    assert ok.mean() > 0.9
    err = np.abs(sp - cast["sal00"].to_numpy())[ok]
    if name.startswith("pyctd"):  # bin averages of scan salinity vs salinity of averaged C/T (README: ~2e-3)
        assert np.median(err) < 1e-4 and np.quantile(err, 0.95) < 2e-3
    else:
        assert err.max() < 1e-4
    if "sigma-t00" in cast:
        e = np.abs(sw.sigma_t(sp, t) - cast["sigma-t00"].to_numpy())[ok]
        assert e.max() < 1e-4
    if (k := _seasoft(cast, "sigma-é")) is not None:
        e = np.abs(sw.sigma_theta(sp, t, p) - cast[k].to_numpy())[ok]
        if name.startswith("pyctd"):
            assert np.median(e) < 1e-4 and np.quantile(e, 0.95) < 2e-3
        else:
            assert e.max() < 1e-4
    if "depSM" in cast:  # Fofonoff-Millard with the header latitude (derive took it from the cast header)
        e = np.abs(ctd["depth_fofonoff_millard_m"].to_numpy() - cast["depSM"].to_numpy())
        assert np.nanmax(e) < 1e-3
    # the hydrostatic depth (in situ density) and Fofonoff-Millard (standard ocean) differ by < 0.5 % of depth
    diff = np.abs(ctd["depth_m"] - ctd["depth_fofonoff_millard_m"]).to_numpy()
    assert np.nanmax(diff - 0.005 * ctd["depth_m"].to_numpy()) < 0.02


def test_profile_qc_documented(shared_data, tmp_path):
    raw = _cast_dive(tmp_path, shared_data, "seabird_sta0860.cnv")
    _, out = _run(raw, tmp_path / "store", ("ingest",))
    meta, _ = read_parquet_metadata(out["sensors"].file("sensors.parquet"))
    assert "flat-line test not evaluated" in meta["qc_note"]
    df = pd.read_parquet(out["sensors"].file("sensors.parquet"))
    assert (df["temperature_its90_degc_qc"] == 1).mean() > 0.9 and (df["altitude_m_qc"] == 9).all()


def test_bad_cast_is_one_line_error_no_product(tmp_path):
    raw = tmp_path / "raw"
    raw.mkdir()
    (raw / "junk.cnv").write_text("not a cast\n")
    (raw / "dive.yaml").write_text(yaml.safe_dump({"dive_id": "bad", "sources": {"cnv": ["junk.cnv"]}}))
    with pytest.raises(HadalError, match="junk.cnv") as ei:
        _run(raw, tmp_path / "store", ("ingest",))
    assert "\n" not in str(ei.value)
    from hadal.store import ProductStore

    assert not ProductStore(tmp_path / "store").has("bad", "sensors")


# ---------------------------------------------------------------------------------------------- several sources
def test_several_casts_none_ignored(shared_data, tmp_path):
    raw = _cast_dive(tmp_path, shared_data, "seabird_sta0860.cnv")
    shutil.copy(_src(shared_data, "oceissues644_02dk.cnv"), raw / "oce.cnv")
    (raw / "sbs.cnv.gz").write_bytes(gzip.compress(_src(shared_data, FORMATS_REAL[0]).read_bytes()))
    y = yaml.safe_load((raw / "dive.yaml").read_text())
    y["sources"]["cnv"] = ["seabird_sta0860.cnv", "oce.cnv", {"path": "sbs.cnv.gz"}]
    (raw / "dive.yaml").write_text(yaml.safe_dump(y))
    _, out = _run(raw, tmp_path / "store", ("ingest", "derive"))
    idx = json.loads(out["casts"].file("casts.json").read_text())["casts"]
    assert [c["cast_id"] for c in idx] == ["cast01_oce", "cast02_sbs"]
    assert idx[0]["time_base"] == NO_TIME_BASE and idx[1]["time_base"] != NO_TIME_BASE
    cp = json.loads(out["cast_profiles"].file("cast_profiles.json").read_text())["casts"]
    assert cp[0]["latitude_source"].startswith("cast header") and cp[1]["latitude_deg"] == 45.0
    assert cp[1]["latitude_warning"]
    assert out["cast_profiles"].file("cast01_oce.nc").is_file()


def test_mcap_plus_cnv_both_ingested(shared_data, small_dive, tmp_path):
    raw = Path(shutil.copytree(small_dive, tmp_path / "dive"))
    shutil.copy(_src(shared_data, "seabird_sta0860.cnv"), raw / "ship_cast.cnv")
    y = yaml.safe_load((raw / "dive.yaml").read_text())
    y["sources"]["cnv"] = ["ship_cast.cnv"]
    (raw / "dive.yaml").write_text(yaml.safe_dump(y))
    _, out = _run(raw, tmp_path / "store", ("ingest", "derive"))
    smeta, _ = read_parquet_metadata(out["sensors"].file("sensors.parquet"))
    assert smeta["source_kind"] == "mcap" and smeta["external_casts"][0]["cast_id"] == "cast00_ship_cast"
    assert smeta["ignored_sources"] and smeta["ignored_sources"][0]["kind"] == "csv"  # said, not silent
    cast = pd.read_parquet(out["casts"].file("cast00_ship_cast.parquet"))
    assert len(cast) == 88 and cast["time"].isna().all()
    cp = pd.read_parquet(out["cast_profiles"].file("cast00_ship_cast.parquet"))
    cm, _ = read_parquet_metadata(out["cast_profiles"].file("cast00_ship_cast.parquet"))
    assert cm["latitude_source"].startswith("cast header")  # the ship cast's own position, not the launch
    assert np.nanmax(np.abs(cp["practical_salinity"] - read_cnv(_src(shared_data, "seabird_sta0860.cnv"))["sal00"])) < 1e-4
    ctd = pd.read_parquet(out["ctd"].file("ctd.parquet"))
    assert ctd["depth_m"].max() > 1000  # the vehicle's dive, unchanged
    # ingest.source: cnv makes the cast win; the vehicle logs are then listed as not used
    (raw / "pipeline.yaml").write_text(yaml.safe_dump({"ingest": {"source": "cnv"}}))
    _, out2 = _run(raw, tmp_path / "store", ("ingest",))
    m2, _ = read_parquet_metadata(out2["sensors"].file("sensors.parquet"))
    assert m2["source_kind"] == "cnv" and m2["time_base"] == NO_TIME_BASE
    assert {d["kind"] for d in m2["ignored_sources"]} == {"mcap", "csv"} and "casts" not in out2
