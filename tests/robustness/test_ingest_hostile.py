"""Hostile-input classes of issue 14 (tester's hunt, findings 03-06, 10-12, 14, 18): each test builds a small
input and checks against an expectation computed independently (arithmetic on the input, the literal value
written, the MCAP spec), not against the code's own output."""

from __future__ import annotations

import gzip
import json
import warnings

import numpy as np
import pytest

from hadal.errors import ConfigError, InputError
from hadal.ingest.align import clean_times
from hadal.ingest.build import build_sensor_table, read_mcap_sensors
from hadal.ingest.csv_reader import SensorSamples, read_sensor_csv
from hadal.ingest.vehicle import VehicleConfig, default_vehicle_config_path, load_vehicle_config

T0 = 1_538_866_800 * 10**9  # 2018-10-06T23:00:00Z


def _vehicle(*names: str) -> VehicleConfig:
    v = load_vehicle_config(default_vehicle_config_path())
    return VehicleConfig(vehicle="t", time_base="ctd", sensors={n: v.sensors[n] for n in ("ctd", *names)})


def _ctd(t: np.ndarray, **over: np.ndarray) -> SensorSamples:
    n = t.size
    vals = {"conductivity_s_m": np.full(n, 3.2), "temperature_its90_degc": np.linspace(2.0, 2.5, n),
            "pressure_ctd_dbar": np.linspace(100.0, 200.0, n), **over}
    return SensorSamples("ctd", t, vals, "csv:ctd.csv", {}, [])


# ---------------------------------------------------------------------------- 05: log_time above int64
@pytest.fixture(params=["python", "compiled"])
def walk(request, monkeypatch):
    from hadal.ingest import mcap_reader as MR

    if request.param == "compiled":
        if MR._chunk_kernels() is None:
            pytest.skip("numba not installed")
        monkeypatch.setattr(MR, "_COMPILED_MIN_BYTES", 0)
    else:
        monkeypatch.setattr(MR, "_COMPILED_MIN_BYTES", 2**62)
    return request.param


def _json_mcap(path, topic, payloads, log_times, chunk_size=1 << 20):
    from mcap.writer import Writer

    with open(path, "wb") as fh:
        w = Writer(fh, chunk_size=chunk_size)
        w.start(profile="", library="hadal-tests")
        sid = w.register_schema(name="ctd", encoding="jsonschema", data=b"{}")
        cid = w.register_channel(topic=topic, message_encoding="json", schema_id=sid)
        for i, (lt, d) in enumerate(zip(log_times, payloads, strict=True)):
            w.add_message(channel_id=cid, log_time=lt, publish_time=0, sequence=i, data=d)
        w.finish()
    return path


def test_mcap_log_time_2_pow_63_is_one_bad_time_not_a_corrupt_chunk(tmp_path, walk):
    from hadal.ingest import read_mcap

    times = [T0 + i * 62_500_000 for i in range(36)]
    times[17] = 2**63  # valid MCAP u64 (spec: log_time uint64), above int64
    p = _json_mcap(tmp_path / "a.mcap", "/haidou/ctd",
                   [json.dumps({"i": i}).encode() for i in range(36)], times)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        data, report = read_mcap(p)
    assert report.corrupt_chunks == 0
    tp = data["/haidou/ctd"]
    assert [m["i"] for m in tp.messages] == list(range(36))  # the chunk is kept whole
    got = tp.log_time_ns.tolist()
    assert got[:17] + got[18:] == times[:17] + times[18:]
    assert got[17] > T0 + 10**18  # implausible: rejected later as one bad time


# ---------------------------------------------------------------------------- 10: duplicate YAML keys
def test_yaml_duplicate_keys_refused_at_any_depth_with_both_lines(tmp_path):
    from hadal.yamlfile import load_yaml_mapping

    p = tmp_path / "dive.yaml"
    p.write_text("dive_id: a\nlaunch: {time_utc: x}\ndive_id: b\n")
    with pytest.raises(ConfigError, match=r"duplicate key 'dive_id' at lines 1 and 3"):
        load_yaml_mapping(p, "dive description")
    p.write_text("derive:\n  profile_bin_dbar: 5.0\n  x: 1\n  profile_bin_dbar: 10.0\n")
    with pytest.raises(ConfigError, match=r"duplicate key 'profile_bin_dbar' at lines 2 and 4"):
        load_yaml_mapping(p, "configuration file")
    p.write_text("base: &b {a: 1}\nother:\n  <<: *b\n  c: 2\n")  # merge keys are not duplicates
    assert load_yaml_mapping(p, "x")["other"] == {"a": 1, "c": 2}
    v = tmp_path / "vehicle.yaml"
    text = default_vehicle_config_path().read_text(encoding="utf-8")
    v.write_text(text + "time_base: ctd\n")
    n_first = next(i for i, ln in enumerate(text.splitlines(), 1) if ln.startswith("time_base:"))
    with pytest.raises(ConfigError, match=rf"duplicate key 'time_base' at lines {n_first} and "
                                          rf"{len(text.splitlines()) + 1}"):
        load_vehicle_config(v)


# ---------------------------------------------------------------------------- 04: coarse time stamps
def test_coarse_time_stamps_spread_not_dropped_identical_rows_dropped():
    stamps = np.repeat(np.arange(20), 16) * 10**9  # 16 Hz logged with whole-second times
    x = np.arange(320.0)
    t, v, st = clean_times(T0 + stamps, {"x": x})
    assert t.size == 320
    np.testing.assert_array_equal(v["x"], x)  # file order kept
    np.testing.assert_array_equal(t - T0, np.arange(320) * 62_500_000)  # i/16 s: 1 s / 16 per row
    assert st["coarse_rows"] == 320 and st["coarse_resolution_s"] == 1.0 and st["duplicates"] == 0
    # rows identical in time AND values are duplicates; same time, other values are not
    t2 = np.array([0, 1, 1, 1, 2]) * 10**9
    _, v2, st2 = clean_times(t2, {"x": np.array([0.0, 5.0, 5.0, 6.0, 2.0]), "y": np.array([0, np.nan, np.nan, 1, 2])})
    assert st2["duplicates"] == 1 and v2["x"].tolist() == [0.0, 5.0, 6.0, 2.0]


def test_coarse_csv_times_publish_every_row_with_a_warning(tmp_path):
    v = load_vehicle_config(default_vehicle_config_path())
    p = tmp_path / "ctd.csv"
    rows = [f"2018-10-06T23:00:{i // 16:02d}Z,32.0,{2.0 + i * 1e-3:.4f},{100 + i * 0.1:.2f}" for i in range(160)]
    p.write_text("time,conductivity_mS_cm,temperature_ITS90,pressure_dbar\n" + "\n".join(rows) + "\n")
    s = read_sensor_csv(p, v.sensors["ctd"].csv, "ctd")
    with pytest.warns(UserWarning, match=r"160 ctd row\(s\) share their time stamp.*effective resolution 1 s"):
        df, _ = build_sensor_table({"ctd": s}, _vehicle(), max_gap_s={})
    assert len(df) == 160
    np.testing.assert_allclose(df["pressure_ctd_dbar"].to_numpy(), 100 + np.arange(160) * 0.1)


# ---------------------------------------------------------------------------- 12: clock jump back
def test_clock_jump_back_rows_counted_and_dropped():
    sec = np.r_[np.arange(0, 100, 0.0625), np.arange(40, 50, 0.0625), np.arange(100, 200, 0.0625)]
    t = T0 + np.round(sec * 1e9).astype(np.int64)
    with pytest.warns(UserWarning, match=r"160 ctd row\(s\) in 1 backward clock jump\(s\) \(up to 60 s back\)"):
        df, meta = build_sensor_table({"ctd": _ctd(t, pressure_ctd_dbar=sec + 100)}, _vehicle(), max_gap_s={})
    assert len(df) == 3200  # 200 s at 16 Hz, the 10 s jump (160 rows) out
    assert meta["alignment"]["ctd"]["clock_jump_rows"] == 160
    assert df["time"].iloc[0].value == T0 and df["pressure_ctd_dbar"].is_monotonic_increasing
    # a file written in reverse order steps back a little every row: sorted, nothing dropped
    r = (T0 + np.arange(200) * 1_100_000_000)[::-1]
    ts, _, st = clean_times(r, {"x": np.arange(200.0)})
    assert ts.size == 200 and st["clock_jump_rows"] == 0 and st["out_of_order"] == 199


# ---------------------------------------------------------------------------- 03: all-missing variables
def test_time_base_without_valid_values_refused_and_empty_variables_warned():
    t = T0 + np.arange(100) * 62_500_000
    nan = np.full(100, np.nan)
    with pytest.raises(InputError, match=r"time-base sensor 'ctd' has no valid value in conductivity_s_m, "
                                         r"temperature_its90_degc, pressure_ctd_dbar"), \
            pytest.warns(UserWarning, match="has no valid value in any of its 100 row"):
        build_sensor_table({"ctd": _ctd(t, conductivity_s_m=nan, temperature_its90_degc=nan,
                                        pressure_ctd_dbar=nan)}, _vehicle(), max_gap_s={})
    with pytest.warns(UserWarning, match=r"ctd temperature_its90_degc has no valid value in any of its 100 row"):
        df, _ = build_sensor_table({"ctd": _ctd(t, temperature_its90_degc=nan)}, _vehicle(), max_gap_s={})
    assert df["temperature_its90_degc"].isna().all() and len(df) == 100


# ---------------------------------------------------------------------------- 11, 14: CSV header
def test_csv_duplicate_mapped_column_refused(tmp_path):
    v = load_vehicle_config(default_vehicle_config_path())
    p = tmp_path / "ctd.csv"
    p.write_text("time,conductivity_mS_cm,temperature_ITS90,pressure_dbar,temperature_ITS90\n"
                 "2018-10-06T23:00:00Z,32,2.5,100,9.9\n2018-10-06T23:00:01Z,32,2.6,101,9.9\n")
    with pytest.raises(InputError, match=r"column 'temperature_ITS90'.*appears 2 times.*columns 3, 5"):
        read_sensor_csv(p, v.sensors["ctd"].csv, "ctd")


def test_csv_semicolon_named_and_comment_lines_skipped(tmp_path):
    v = load_vehicle_config(default_vehicle_config_path())
    p = tmp_path / "ctd.csv"
    body = ["2018-10-06T23:00:00Z,32,2.5,100", "2018-10-06T23:00:01Z,32,2.6,101"]
    p.write_text("time;conductivity_mS_cm;temperature_ITS90;pressure_dbar\n"
                 + "\n".join(b.replace(",", ";") for b in body) + "\n")
    with pytest.raises(InputError, match=r"header is one column .*is the delimiter ';'\? set csv.delimiter"):
        read_sensor_csv(p, v.sensors["ctd"].csv, "ctd")
    p.write_text("# logged by haidou\n# serial 1234, 16 Hz\ntime,conductivity_mS_cm,temperature_ITS90,pressure_dbar\n"
                 + "\n".join(body) + "\n")
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "corrupt row" warning for the comment lines
        s = read_sensor_csv(p, v.sensors["ctd"].csv, "ctd")
    assert s.values["pressure_ctd_dbar"].tolist() == [100.0, 101.0]
    assert s.stats["corrupt_rows"] == 0 and s.stats["rows"] == 2


# ---------------------------------------------------------------------------- 18: QC overrides, key names
def test_partial_qc_override_merged_per_test_and_misspelt_names_refused():
    from hadal.ingest.qc import merge_qc, qc_flags
    from hadal.settings import IngestParams as Params

    p = Params.model_validate({"qc": {"pressure_ctd_dbar": {"fail_span": [-10, 11000]}}})
    q = merge_qc(p.qc)["pressure_ctd_dbar"]
    # the packaged defaults (qc.py docstring: SBE49 saturation 10 500 dbar; spike 5/20 dbar; flat line 60/300 s)
    assert (q.saturation, q.spike_suspect, q.spike_fail, q.flat_line_fail_s) == (10_500.0, 5.0, 20.0, 300.0)
    t = T0 + np.arange(5) * 62_500_000
    assert int(qc_flags(np.array([5000.0, 5000.1, 10_500.0, 5000.2, 5000.3]), t, q)[2]) == 4
    with pytest.raises(ConfigError, match=r"unknown variable 'presure_ctd_dbar'"):
        merge_qc({"presure_ctd_dbar": {"fail_span": [0, 1]}})
    tt = T0 + np.arange(50) * 62_500_000
    with pytest.raises(ConfigError, match=r"ingest.max_gap_s: unknown sensor 'guage'"):
        build_sensor_table({"ctd": _ctd(tt)}, _vehicle("gauge"), max_gap_s={"guage": 3600.0})


# ---------------------------------------------------------------------------- 06: undecodable payloads
def test_all_payloads_undecodable_names_topic_encoding_and_first_error(tmp_path):
    msgs = [gzip.compress(json.dumps({"cond": 3.2, "temp": 2.0, "pres": 100.0 + i}).encode()) for i in range(40)]
    p = _json_mcap(tmp_path / "g.mcap", "/haidou/ctd", msgs, [T0 + i * 62_500_000 for i in range(40)])
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(InputError, match=r"none of the 40 message\(s\) on topic /haidou/ctd could be decoded "
                                             r"\(message encoding 'json'.*starting 1f 8b"):
            read_mcap_sensors([p], _vehicle())


def test_one_topic_undecodable_names_it_not_missing(tmp_path):
    from mcap.writer import Writer

    p = tmp_path / "h.mcap"
    with open(p, "wb") as fh:
        w = Writer(fh)
        w.start(profile="", library="hadal-tests")
        sid = w.register_schema(name="x", encoding="jsonschema", data=b"{}")
        ctd = w.register_channel(topic="/haidou/ctd", message_encoding="json", schema_id=sid)
        alt = w.register_channel(topic="/haidou/altimeter", message_encoding="json", schema_id=sid)
        for i in range(20):
            w.add_message(channel_id=ctd, log_time=T0 + i * 62_500_000, publish_time=0, sequence=i,
                          data=b"\xff\xfegarbage")
            w.add_message(channel_id=alt, log_time=T0 + i * 62_500_000, publish_time=0, sequence=i,
                          data=b'{"range": 10.0}')
        w.finish()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        with pytest.raises(InputError, match=r"none of the 20 message\(s\) on topic /haidou/ctd \(sensor 'ctd'\) "
                                             r"could be decoded \(message encoding 'json'\).*starting ff fe"):
            read_mcap_sensors([p], _vehicle("altimeter"))
