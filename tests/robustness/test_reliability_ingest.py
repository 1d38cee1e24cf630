"""Issue 14, classes 2-4 at the reader/library level: type confusion in logs, duplicate MCAP channels, time sanity.

The bad inputs are built here (MCAP with the ``mcap`` / ``mcap_ros2`` writers, CSV text, .cnv text) and the exact
outcome is checked: rejected counts, the one-line message, the flag. The stage-level cases are in
``tests/malformed/make_corpus.py`` (run by test_ingest_malformed.py and the reliability report).
"""

from __future__ import annotations

import json
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from hadal.errors import InputError
from hadal.ingest.build import build_sensor_table, read_mcap_sensors
from hadal.ingest.csv_reader import SensorSamples, _numeric, read_sensor_csv
from hadal.ingest.mcap_reader import read_mcap, ros2_field_type
from hadal.ingest.vehicle import VehicleConfig, default_vehicle_config_path, load_vehicle_config

sys.path.insert(0, str(Path(__file__).parents[1] / "malformed"))
from tiny_dive import REPO, messages  # noqa: E402

T0 = 1538866800 * 10**9  # 2018-10-06T23:00:00Z


def _json_mcap(path: Path, channels: list[tuple[str, str, bytes, list[tuple[int, dict]]]]) -> Path:
    from mcap.writer import Writer

    with open(path, "wb") as fh:
        w = Writer(fh)
        w.start()
        todo = []
        for topic, sname, sdata, lst in channels:
            sid = w.register_schema(sname, "jsonschema", sdata)
            todo.append((w.register_channel(topic, "json", sid), lst))
        for t, cid, m in sorted((t, cid, m) for cid, lst in todo for t, m in lst):
            w.add_message(cid, t, json.dumps(m).encode(), t)
        w.finish()
    return path


def _ctd_schema() -> bytes:
    return (REPO / "schemas" / "mcap" / "haidou_ctd.json").read_bytes()


# ---------------------------------------------------------------------------------------------- class 2
def test_numeric_rejects_every_non_number_and_never_coerces():
    arr, bad, types = _numeric([1.5, None, True, "3.2", [4.0], {"v": 1}, 7, False, np.float32(2.0)])
    assert bad.tolist() == [False, False, True, True, True, True, False, True, False]
    assert types == {"bool": 2, "string": 1, "array": 1, "object": 1}
    assert arr[0] == 1.5 and np.isnan(arr[1]) and arr[6] == 7.0 and arr[8] == 2.0
    assert np.isnan(arr[bad]).all() and arr.ndim == 1
    # all one-element arrays: once a 2-D array that reached qc.py
    arr, bad, types = _numeric([[1.0], [2.0]])
    assert arr.shape == (2,) and bad.all() and types == {"array": 2}


def test_mcap_json_bool_temperature_rejected_not_one_degree(tmp_path):
    ctd = messages(10.0)["/haidou/ctd"]
    ctd = [(t, {**m, "temp": True} if i in (3, 9) else m) for i, (t, m) in enumerate(ctd)]
    p = _json_mcap(tmp_path / "b.mcap", [("/haidou/ctd", "ctd", _ctd_schema(), ctd)])
    v = load_vehicle_config(default_vehicle_config_path())
    v = VehicleConfig(vehicle="t", time_base="ctd", sensors={"ctd": v.sensors["ctd"]})
    with pytest.warns(UserWarning, match=r"rejected 2 of 160 ctd sample\(s\).*temp: 2 \(bool 2\)"):
        sensors, _ = read_mcap_sensors([p], v)
    s = sensors["ctd"]
    assert len(s) == 158 and s.stats["rejected_samples"] == 2
    assert s.stats["rejected_values"]["temp"] == {"variable": "temperature_its90_degc", "count": 2, "types": {"bool": 2}}
    assert not np.any(s.values["temperature_its90_degc"] == 1.0)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        _, meta = build_sensor_table(sensors, v, max_gap_s={})
    assert meta["rejected_samples"]["ctd"]["samples"] == 2
    assert meta["rejected_samples"]["ctd"]["fields"] == {"temp": {"variable": "temperature_its90_degc", "count": 2}}


def test_csv_type_confused_cells_rejected_per_column(tmp_path):
    v = load_vehicle_config(default_vehicle_config_path())
    rows = ["time,conductivity_mS_cm,temperature_ITS90,pressure_dbar"]
    for i in range(20):
        t = np.datetime_as_string(np.datetime64(T0 + i * 10**9, "ns"), unit="ms") + "Z"
        temp = {4: "true", 7: "[2.5]", 11: '"{""a"": 1}"'}.get(i, "2.5")
        rows.append(f"{t},32.5,{temp},{'abc' if i == 15 else '100.0'}")
    p = tmp_path / "ctd.csv"
    p.write_text("\n".join(rows) + "\n")
    with pytest.warns(UserWarning, match=r"dropped 4 corrupt row\(s\) of 20 .*temperature_ITS90: 3.*pressure_dbar: 1"):
        s = read_sensor_csv(p, v.sensors["ctd"].csv, "ctd")
    assert len(s) == 16 and s.stats["rejected_samples"] == 4
    assert s.stats["rejected_values"]["temperature_ITS90"]["count"] == 3
    assert s.stats["rejected_values"]["pressure_dbar"]["count"] == 1


def test_sensor_samples_refuse_a_2d_array():
    with pytest.raises(InputError, match=r"shape \(3, 1\) for 3 sample time\(s\): not one number per sample"):
        SensorSamples("ctd", np.arange(3), {"temperature_its90_degc": np.ones((3, 1))}, "mcap:x", {}, [])


_ROS_DEF = ("std_msgs/Header header\nfloat64 pressure  # dbar\nbool valid\nfloat64[3] cov\nstring note\n"
            "uint8 MODE_A=1\nuint8 mode\n"
            "================================================================================\n"
            "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n"
            "================================================================================\n"
            "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n")


def test_ros2_field_types_from_the_schema():
    types = {f: ros2_field_type("acme/msg/Gauge", _ROS_DEF, f) for f in
             ("pressure", "valid", "cov", "cov.1", "note", "mode", "header", "header.stamp", "header.stamp.sec", "nope")}
    assert types == {"pressure": "float64", "valid": "bool", "cov": "float64[3]", "cov.1": "float64", "note": "string",
                     "mode": "uint8", "header": "std_msgs/Header", "header.stamp": "builtin_interfaces/Time",
                     "header.stamp.sec": "int32", "nope": None}


def _ros2_gauge(tmp_path: Path) -> Path:
    from mcap_ros2.writer import Writer

    p = tmp_path / "ros.mcap"
    with open(p, "wb") as fh:
        w = Writer(fh)
        sch = w.register_msgdef("acme/msg/Gauge", _ROS_DEF)
        for i in range(20):
            tn = T0 + i * 250_000_000
            w.write_message("/acme/gauge", sch, {"header": {"stamp": {"sec": tn // 10**9, "nanosec": tn % 10**9},
                                                            "frame_id": ""}, "pressure": 100.0 + i, "valid": True,
                                                 "cov": [0.1, 0.2, 0.3], "note": "", "mode": 1},
                            log_time=tn, publish_time=tn)
        w.finish()
    return p


@pytest.mark.parametrize("field,match", [
    ("valid", r"maps gauge's pressure_gauge_dbar to field 'valid' of topic /acme/gauge, which is a boolean \(bool\) "
              r"in the ROS 2 schema acme/msg/Gauge"),
    ("cov", r"which is an array \(float64\[3\]\).*map one element \('cov.0'\)"),
    ("note", r"which is a string \(string\)"),
    ("header.stamp", r"which is a sub-message \(builtin_interfaces/Time\)"),
])
def test_ros2_bool_or_array_mapped_to_a_number_is_refused(tmp_path, field, match):
    p = _ros2_gauge(tmp_path)
    cfg = {"time_base": "gauge", "sensors": {"gauge": {"mcap": {"topic": "/acme/gauge", "fields": {
        "pressure_gauge_dbar": {"field": field, "units": "dbar"}}}}}}
    with pytest.raises(InputError, match=match) as ei:
        read_mcap_sensors([p], VehicleConfig.model_validate(cfg))
    assert "\n" not in str(ei.value)


def test_ros2_numeric_and_array_element_mapping_accepted(tmp_path):
    p = _ros2_gauge(tmp_path)
    for field, first in (("pressure", 100.0), ("cov.1", 0.2), ("mode", 1.0)):
        cfg = {"time_base": "gauge", "sensors": {"gauge": {"mcap": {"topic": "/acme/gauge", "fields": {
            "pressure_gauge_dbar": {"field": field, "units": "dbar"}}}}}}
        s, _ = read_mcap_sensors([p], VehicleConfig.model_validate(cfg))
        assert len(s["gauge"]) == 20 and s["gauge"].values["pressure_gauge_dbar"][0] == pytest.approx(first)


# ---------------------------------------------------------------------------------------------- class 3
def test_two_channels_same_schema_merged_in_time_order(tmp_path):
    ctd = messages(10.0)["/haidou/ctd"]
    a, b = ctd[0::2] + ctd[1:9:2], ctd[1::2]  # 4 messages recorded on both channels
    p = _json_mcap(tmp_path / "two.mcap", [("/haidou/ctd", "ctd", _ctd_schema(), a),
                                           ("/haidou/ctd", "ctd", _ctd_schema(), b)])
    with pytest.warns(UserWarning, match=r"topic /haidou/ctd is recorded on 2 channels \(1, 2\) with the same schema "
                                         r"'ctd': merged in time order, 4 exact duplicate message\(s\) dropped"):
        data, rep = read_mcap(p)
    tp = data["/haidou/ctd"]
    assert [t for t, _ in ctd] == tp.log_time_ns.tolist() and tp.messages == [m for _, m in ctd]
    assert tp.channel_ids == [1, 2] and tp.duplicates_dropped == 4
    assert rep.duplicates_dropped == 4 and rep.messages_lost == 0 and rep.messages_read == 160
    assert rep.topics["/haidou/ctd"]["channel_ids"] == [1, 2]


def test_two_channels_different_schemas_refused(tmp_path):
    ctd = messages(5.0)["/haidou/ctd"]
    other = json.dumps({"title": "ctd2", "type": "object"}).encode()
    p = _json_mcap(tmp_path / "two.mcap", [("/haidou/ctd", "ctd", _ctd_schema(), ctd[::2]),
                                           ("/haidou/ctd", "ctd2", other, ctd[1::2])])
    with pytest.raises(InputError) as ei:
        read_mcap(p)
    msg = str(ei.value)
    assert "\n" not in msg
    assert ("topic /haidou/ctd is recorded on 2 channels with different schemas (channel 1: ctd [jsonschema/json]; "
            "channel 2: ctd2 [jsonschema/json])") in msg
    same_name = _json_mcap(tmp_path / "same.mcap", [("/haidou/ctd", "ctd", _ctd_schema(), ctd[::2]),
                                                    ("/haidou/ctd", "ctd", other, ctd[1::2])])
    with pytest.raises(InputError, match="same name, different definitions"):
        read_mcap(same_name)


# ---------------------------------------------------------------------------------------------- class 4
def _samples(name: str, t0_ns: int, n: int, rate_hz: float, var: str, fmt: str = "unix_ns",
             field: str = "log_time") -> SensorSamples:
    t = t0_ns + (np.arange(n) * (1e9 / rate_hz)).astype(np.int64)
    return SensorSamples(name, t, {var: np.full(n, 100.0)}, f"mcap:x:/{name}", {"time_format": fmt, "time_field": field}, [])


def _vehicle() -> VehicleConfig:
    return VehicleConfig.model_validate({"time_base": "ctd", "sensors": {
        "ctd": {"mcap": {"topic": "/c", "fields": {"pressure_ctd_dbar": {"field": "p", "units": "dbar"}}}},
        "gauge": {"mcap": {"topic": "/g", "fields": {"pressure_gauge_dbar": {"field": "p", "units": "dbar"}}}}}})


def test_log_time_in_ms_is_an_error_with_the_unit_guess():
    ctd = _samples("ctd", T0 // 10**6, 100, 16.0, "pressure_ctd_dbar")
    with pytest.raises(InputError, match=r"100 of 100 ctd sample time\(s\) lie outside the plausible range 1980-01-01"
                                         r".*log_time looks like milliseconds since 1970 \(unix_ms\), not nanoseconds"):
        build_sensor_table({"ctd": ctd}, _vehicle(), max_gap_s={})


def test_a_few_samples_dated_2100_are_dropped_and_flagged():
    ctd = _samples("ctd", T0, 160, 16.0, "pressure_ctd_dbar")
    g = _samples("gauge", T0, 40, 4.0, "pressure_gauge_dbar")
    g.time_ns[[5, 6]] += 82 * 365 * 86_400 * 10**9
    with pytest.warns(UserWarning, match=r"dropped 2 of 40 gauge sample\(s\) dated outside the plausible range"):
        df, meta = build_sensor_table({"ctd": ctd, "gauge": g}, _vehicle(), max_gap_s={"gauge": 2.0})
    assert meta["time_checks"]["implausible"]["gauge"]["dropped"] == 2
    assert any("plausible range" in n for n in meta["notes"])
    assert df["time"].max().year == 2018 and meta["time_checks"]["overlap"]["gauge"]["overlap"] > 0.9


def test_gauge_one_hour_off_warns_with_overlap_and_offset():
    ctd = _samples("ctd", T0, 160, 16.0, "pressure_ctd_dbar")
    g = _samples("gauge", T0 + 3600 * 10**9, 40, 4.0, "pressure_gauge_dbar")
    with pytest.warns(UserWarning, match=r"gauge overlaps the ctd time base by only 0% \(< 50%\); its data start "
                                         r"\+1 h 00 min \(a whole number of hours"):
        df, meta = build_sensor_table({"ctd": ctd, "gauge": g}, _vehicle(), max_gap_s={"gauge": 2.0})
    ov = meta["time_checks"]["overlap"]["gauge"]
    assert ov["overlap"] == 0.0 and ov["offset_s"] == pytest.approx(3600.0)
    assert bool((df["pressure_gauge_dbar_qc"] == 9).all())
    # a 30 % overlap is measured, not rounded away
    g2 = _samples("gauge", T0 + 7 * 10**9, 40, 4.0, "pressure_gauge_dbar")
    with pytest.warns(UserWarning, match=r"by only 30%"):
        _, meta = build_sensor_table({"ctd": ctd, "gauge": g2}, _vehicle(), max_gap_s={"gauge": 2.0})
    assert meta["time_checks"]["overlap"]["gauge"]["overlap"] == pytest.approx(2.9375 / 9.9375, abs=0.01)


def test_launch_window():
    ctd = _samples("ctd", T0 + 400 * 86_400 * 10**9, 160, 16.0, "pressure_ctd_dbar")
    with pytest.raises(InputError, match=r"160 of 160 ctd sample\(s\) lie outside the dive's launch window.*"
                                         r"starting \+400.0 days from the launch"):
        build_sensor_table({"ctd": ctd}, _vehicle(), max_gap_s={}, launch_ns=T0)
    with pytest.warns(UserWarning, match="launch window"):  # a cast (strict_launch=False): flagged, loudly
        _, meta = build_sensor_table({"ctd": ctd}, _vehicle(), max_gap_s={}, launch_ns=T0, strict_launch=False)
    assert meta["time_checks"]["outside_launch_window"]["ctd"]["samples"] == 160 and meta["notes"]
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        _, meta = build_sensor_table({"ctd": _samples("ctd", T0, 160, 16.0, "pressure_ctd_dbar")}, _vehicle(),
                                     max_gap_s={}, launch_ns=T0)
    assert meta["time_checks"]["launch_time"] == "2018-10-06T23:00:00Z" and meta["notes"] == []


def test_cnv_timeS_bad_flag_is_not_a_row_dated_1726(tmp_path):
    from hadal.ingest.build import read_cast

    rows = [f"{100.0 + i:11.3f}{2.5:11.4f}{3.25:11.6f}{(-9.990e-29 if i == 3 else 0.5 * i):11.3e}" for i in range(10)]
    p = tmp_path / "c.cnv"
    p.write_text("* Sea-Bird SBE 9 Data File:\n# nquan = 4\n# name 0 = prDM: Pressure, Digiquartz [db]\n"
                 "# name 1 = t090C: Temperature [ITS-90, deg C]\n# name 2 = c0S/m: Conductivity [S/m]\n"
                 "# name 3 = timeS: Time, Elapsed [seconds]\n# start_time = Oct 06 2018 23:00:00\n"
                 "# bad_flag = -9.990e-29\n*END*\n" + "\n".join(rows) + "\n")
    with pytest.warns(UserWarning, match=r"dropped 1 of 10 scan\(s\) whose time \(start_time \+ timeS\) is bad_flag"):
        s, _ = read_cast(p)
    assert len(s) == 9 and s.stats["bad_times"] == 1
    assert s.time_ns.min() == T0 and 100.0 + 3 not in s.values["pressure_ctd_dbar"].tolist()
