"""MCAP reader: real ROS 2 CDR files, JSON channels of the sample-dive contract, damaged files."""

from __future__ import annotations

import sys
import warnings
from pathlib import Path

import numpy as np
import pytest

from hadal.errors import InputError
from hadal.ingest import mcap_info, read_mcap, read_mcap_tables

sys.path.insert(0, str(Path(__file__).parents[2] / "malformed"))
from tiny_dive import TOPICS, messages, write_mcap  # noqa: E402

REAL = {  # file -> {topic: (schema, count)}
    "rosbag2_cdr_test_0.mcap": {"/test_topic": ("test_msgs/msg/BasicTypes", 3),
                                "/array_topic": ("test_msgs/msg/Arrays", 4)},
    "rosbag2_talker.mcap": {"/rosout": ("rcl_interfaces/msg/Log", 10),
                            "/parameter_events": ("rcl_interfaces/msg/ParameterEvent", 0),
                            "/topic": ("std_msgs/msg/String", 10)},
    "rosbag2_test_bag_for_seek_0.mcap": {"topic1": ("test_msgs/BasicTypes", 5)},
}


@pytest.mark.parametrize("name", sorted(REAL))
def test_real_ros2_files(shared_data, name, walk):
    path = shared_data / "mcap-real" / name
    info = {c["topic"]: (c["schema"], c["messages"]) for c in mcap_info(path)}
    assert info == REAL[name]
    assert all(c["message_encoding"] == "cdr" and c["schema_encoding"] == "ros2msg" for c in mcap_info(path))
    tables, report = read_mcap_tables(path)
    assert report.messages_lost == 0 and not report.damaged
    for topic, (_, n) in REAL[name].items():
        assert len(tables[topic]) == n
        assert np.all(np.diff(tables[topic]["log_time_ns"].to_numpy()) >= 0)


def test_real_ros2_decoded_values(shared_data):
    tables, _ = read_mcap_tables(shared_data / "mcap-real" / "rosbag2_talker.mcap")
    assert tables["/topic"]["data"].tolist() == [f"Hello, world! {i}" for i in range(10)]
    rosout = tables["/rosout"]
    assert {"stamp.sec", "stamp.nanosec", "level", "msg"} <= set(rosout.columns)  # nested Time flattened
    assert rosout["level"].eq(20).all()
    seek, _ = read_mcap_tables(shared_data / "mcap-real" / "rosbag2_test_bag_for_seek_0.mcap")
    assert seek["topic1"]["int32_value"].tolist() == [1, 2, 3, 4, 5]
    cdr, _ = read_mcap(shared_data / "mcap-real" / "rosbag2_cdr_test_0.mcap", ["/array_topic"])
    m = cdr["/array_topic"].messages[0]
    assert m["string_values"] == ["Complex Hello1", "Complex Hello2", "Complex Hello3"]
    assert m["basic_types_values"][0]["int32_value"] == 0  # nested message lists become dicts
    assert m["int64_values_default"][1] == 9223372036854775807


@pytest.fixture(params=["python", "compiled"])
def walk(request, monkeypatch):
    """Run a test with the pure-Python chunk walk and with the compiled one (forced for small files)."""
    from hadal.ingest import mcap_reader as MR

    if request.param == "compiled":
        if MR._chunk_kernels() is None:
            pytest.skip("numba not installed")
        monkeypatch.setattr(MR, "_COMPILED_MIN_BYTES", 0)
    else:
        monkeypatch.setattr(MR, "_COMPILED_MIN_BYTES", 2**62)
    return request.param


def _plain(path, topics=None):
    """Oracle: mcap's own reader and json.loads, per message; {topic: (log times, decoded objects)}."""
    import json

    from mcap.reader import make_reader

    out = {}
    with open(path, "rb") as fh:
        for _s, ch, m in make_reader(fh).iter_messages(topics=topics, log_time_order=False):
            t, v = out.setdefault(ch.topic, ([], []))
            try:
                d = json.loads(m.data)
            except ValueError:
                continue
            if isinstance(d, dict):
                t.append(m.log_time)
                v.append(d)
    return out


@pytest.fixture(scope="module")
def tiny_mcap(tmp_path_factory):
    msgs = messages(20.0)
    p = tmp_path_factory.mktemp("mcap") / "haidou.mcap"
    write_mcap(p, msgs, chunk_size=2048)
    return p, msgs


def test_json_channels_roundtrip(tiny_mcap, walk):
    p, msgs = tiny_mcap
    data, report = read_mcap(p)
    assert set(data) == set(TOPICS)
    for topic, lst in msgs.items():
        tp = data[topic]
        assert tp.message_encoding == "json" and tp.schema_encoding == "jsonschema"
        assert tp.log_time_ns.tolist() == [t for t, _ in lst]
        assert tp.messages == [m for _, m in lst]
    assert report.messages_read == report.messages_expected == sum(len(v) for v in msgs.values())
    assert report.messages_lost == 0
    only, rep2 = read_mcap(p, ["/haidou/keller"])
    assert list(only) == ["/haidou/keller"] and rep2.messages_expected == len(msgs["/haidou/keller"])


def test_truncated_mcap_recovers_intact_chunks(tiny_mcap, tmp_path, walk):
    p, msgs = tiny_mcap
    total = sum(len(v) for v in msgs.values())
    b = p.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(b[: len(b) * 6 // 10])
    with pytest.warns(UserWarning, match="unknown number of message"):
        data, report = read_mcap(cut)
    assert report.truncated and report.messages_lost is None and report.messages_expected is None
    assert 0 < report.messages_read < total
    # recovered messages are exact prefixes of each topic
    for topic, tp in data.items():
        assert tp.messages == [m for _, m in msgs[topic]][: len(tp.messages)]


def test_corrupt_chunk_is_skipped_and_counted(tiny_mcap, tmp_path, walk):
    from mcap.reader import make_reader

    p, msgs = tiny_mcap
    total = sum(len(v) for v in msgs.values())
    with open(p, "rb") as fh:
        chunks = make_reader(fh).get_summary().chunk_indexes
    assert len(chunks) > 3
    ci = chunks[1]
    b = bytearray(p.read_bytes())
    mid = ci.chunk_start_offset + ci.chunk_length // 2
    b[mid] ^= 0x5A
    bad = tmp_path / "flip.mcap"
    bad.write_bytes(bytes(b))
    with pytest.warns(UserWarning, match="corrupt chunk"):
        data, report = read_mcap(bad)
    assert report.corrupt_chunks == 1 and not report.truncated
    assert report.messages_expected == total
    assert report.messages_lost == total - report.messages_read > 0
    # messages after the corrupt chunk were recovered too
    last = max(tp.log_time_ns.max() for tp in data.values())
    assert last == max(t for lst in msgs.values() for t, _ in lst)


def test_truncated_ros2_file(shared_data, tmp_path, walk):
    b = (shared_data / "mcap-real" / "rosbag2_talker.mcap").read_bytes()
    cut = tmp_path / "talker_cut.mcap"
    cut.write_bytes(b[: len(b) // 2])
    with warnings.catch_warnings(record=True):
        warnings.simplefilter("always")
        _, report = read_mcap(cut)
    assert report.truncated and report.messages_lost is None


@pytest.mark.parametrize("content,match", [(b"", "empty"), (b"hello world, not mcap", "not an MCAP")])
def test_not_mcap(tmp_path, content, match):
    p = tmp_path / "x.mcap"
    p.write_bytes(content)
    with pytest.raises(InputError, match=match):
        read_mcap(p)
    with pytest.raises(InputError, match="does not exist"):
        read_mcap(tmp_path / "nope.mcap")


def test_nested_fields_transforms_offset_and_ros_time():
    """Mapping features for decoded ROS 2 messages: dotted fields, header.stamp time, transform, offset."""
    from hadal.ingest.csv_reader import sensor_from_records
    from hadal.ingest.vehicle import McapSource

    t0 = 1538866800
    msgs = [{"header": {"stamp": {"sec": t0 + i, "nanosec": 250_000_000}},
             "fluid_pressure": 101325.0 + 1e4 * i,
             "orientation": {"x": 0.0, "y": 0.0, "z": 0.0, "w": 1.0},  # identity in ENU: facing east
             "twist": {"linear": {"x": 3.0, "y": 4.0}}} for i in range(5)]
    m = McapSource.model_validate({
        "topic": "/t", "time": {"field": "header.stamp", "format": "ros_time"},
        "fields": {"pressure_gauge_dbar": {"field": "fluid_pressure", "units": "Pa", "offset": -10.1325},
                   "heading_deg": {"field": ["orientation.x", "orientation.y", "orientation.z", "orientation.w"],
                                   "units": "deg", "transform": "quaternion_to_heading_deg"},
                   "speed_m_s": {"field": ["twist.linear.x", "twist.linear.y"], "units": "cm/s",
                                 "transform": "vector_norm"}}})
    s = sensor_from_records("nav", np.zeros(5, dtype=np.int64), msgs, m, "mcap:x.mcap")
    assert s.time_ns.tolist() == [(t0 + i) * 10**9 + 250_000_000 for i in range(5)]
    assert s.values["pressure_gauge_dbar"].tolist() == pytest.approx([0.0, 1.0, 2.0, 3.0, 4.0], abs=1e-9)
    assert s.values["heading_deg"].tolist() == pytest.approx([90.0] * 5)
    assert s.values["speed_m_s"].tolist() == pytest.approx([0.05] * 5)
    formulas = [(c["variable"], c["formula"]) for c in s.conversions]
    assert ("pressure_gauge_dbar", "x * 0.0001") in formulas and ("pressure_gauge_dbar", "x + -10.1325") in formulas
    assert ("heading_deg", "quaternion_to_heading_deg") in formulas and ("speed_m_s", "vector_norm") in formulas
    bad = McapSource.model_validate({"topic": "/t", "fields": {"altitude_m": {"field": "range.value", "units": "m"}}})
    with pytest.raises(InputError, match="no field 'range.value'"):
        sensor_from_records("alt", np.arange(5), msgs, bad, "mcap:x.mcap")


def test_no_mapped_topic_is_one_line_input_error(tiny_mcap):
    from hadal.ingest.build import read_mcap_sensors
    from hadal.ingest.vehicle import VehicleConfig

    p, _ = tiny_mcap
    v = VehicleConfig.model_validate({"time_base": "g", "sensors": {"g": {"mcap": {
        "topic": "/other/pressure", "fields": {"pressure_gauge_dbar": {"field": "p", "units": "dbar"}}}}}})
    with pytest.raises(InputError) as exc:
        read_mcap_sensors([p], v)
    msg = str(exc.value)
    assert "\n" not in msg and "nothing to ingest" in msg and "/other/pressure" in msg and "/haidou/ctd" in msg


def test_csv_latlon_transform(tmp_path):
    from hadal.ingest.csv_reader import read_sensor_csv
    from hadal.ingest.vehicle import CsvSource

    p = tmp_path / "gps.csv"
    p.write_text("time,lat,lon\n2018-10-06T23:00:00Z,11.33,142.2\n2018-10-06T23:00:01Z,11.331,142.2\n")
    m = CsvSource.model_validate({"source": "gps", "fields": {
        "dr_north_m": {"field": ["lat", "lon"], "units": "m", "transform": "latlon_to_north_m"},
        "dr_east_m": {"field": ["lat", "lon"], "units": "m", "transform": "latlon_to_east_m",
                      "origin": [11.33, 142.19]}}})
    s = read_sensor_csv(p, m, "gps")
    assert s.values["dr_north_m"][0] == 0.0 and s.values["dr_north_m"][1] == pytest.approx(110.6, abs=0.5)
    assert s.values["dr_east_m"][0] == pytest.approx(0.01 * 111_320 * np.cos(np.radians(11.33)), rel=2e-3)


def test_payload_edge_cases_decode_like_json_loads(tmp_path, walk):
    """Messages msgspec refuses but json.loads accepts (NaN, Infinity, integers beyond 64 bits, lone
    surrogates) decode as json.loads decodes them; corrupt, empty and non-object payloads are counted as
    decode errors, exactly as the plain reader loop with json.loads sees them."""
    from mcap.writer import CompressionType, Writer

    payloads = [b'{"a": 1.5, "b": [1, 2], "c": {"d": null}}', b'{"v": NaN, "w": -Infinity}', b'{"big": 1' + b"0" * 30
                + b"}", b'{"s": "\\ud800"}', b'{"broken": ', b"", b"[1, 2]", b"3", b'{"ok": true}', b'{"x": 1} {"y": 2}']
    p = tmp_path / "edge.mcap"
    with open(p, "wb") as fh:
        w = Writer(fh, chunk_size=64, compression=CompressionType.LZ4)
        w.start(profile="", library="hadal-tests")
        sid = w.register_schema(name="e", encoding="jsonschema", data=b"{}")
        a = w.register_channel(topic="/a", message_encoding="json", schema_id=sid)
        b = w.register_channel(topic="/b", message_encoding="json", schema_id=sid)
        for i in range(300):
            w.add_message(channel_id=a if i % 3 else b, log_time=1_000 + i, publish_time=0, sequence=i,
                          data=payloads[i % len(payloads)])
        w.finish()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        data, report = read_mcap(p)
    exp = _plain(p)
    for topic, (t, v) in exp.items():
        assert data[topic].log_time_ns.tolist() == t
        got = data[topic].messages
        assert len(got) == len(v)
        assert all(g == e or (g.keys() == e.keys() and "v" in g and np.isnan(g["v"])) for g, e in zip(got, v, strict=True))
    assert report.decode_errors == 300 - sum(len(v) for _, v in exp.values()) > 0
    assert report.messages_read == sum(len(v) for _, v in exp.values())


def test_compiled_and_python_walks_agree_on_real_files(shared_data, monkeypatch):
    """Same decoded values, log times and report from both chunk walks on the real ROS 2 files (CDR)."""
    from hadal.ingest import mcap_reader as MR

    if MR._chunk_kernels() is None:
        pytest.skip("numba not installed")
    for f in sorted((shared_data / "mcap-real").glob("*.mcap")):
        res = []
        for limit in (2**62, 0):
            monkeypatch.setattr(MR, "_COMPILED_MIN_BYTES", limit)
            data, report = read_mcap(f)
            res.append(({k: (v.log_time_ns.tolist(), v.messages) for k, v in data.items()}, report.as_dict()))
        assert res[0] == res[1], f.name


@pytest.mark.parametrize("damage", ["header", "record", "short_message"])
def test_compiled_walk_refuses_damaged_chunks_like_the_python_walk(damage):
    import struct

    from hadal.ingest import mcap_reader as MR

    kern = MR._chunk_kernels()
    if kern is None:
        pytest.skip("numba not installed")
    good = struct.pack("<BQHIQQ", 5, 22 + 3, 7, 1, 123, 0) + b"abc"
    data = {"header": good + b"\x05\x01", "record": good + struct.pack("<BQ", 5, 100) + b"x" * 30,
            "short_message": good + struct.pack("<BQ", 5, 10) + b"x" * 10}[damage]
    for k in (None, kern):
        with pytest.raises(ValueError):
            MR._chunk_channels(data, k)
    others, per = MR._chunk_channels(good * 3, kern)
    assert others == [] and per[7][0].tolist() == [123] * 3 and per[7][2].tolist() == [3] * 3
    assert bytes(per[7][1]) == b"[abc,abc,abc]"


FIXED_MSGDEF = """bool ok
int8 a
float64 depth
uint16 b
builtin_interfaces/Time stamp
float32[3] acc
uint8[2] raw
int64 big
================================================================================
MSG: builtin_interfaces/Time
int32 sec
uint32 nanosec
"""


def test_fixed_layout_cdr_decoded_vectorised_equal_to_mcap_ros2(tmp_path, monkeypatch):
    """A fixed-size ROS 2 type (primitives, fixed arrays, a nested Time) takes the vectorised decoder and
    gives what mcap-ros2-support's decoder (+ to_dict) gives message by message; a type with a string
    does not take it."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory
    from mcap_ros2.writer import Writer

    from hadal.ingest import mcap_reader as MR

    rng = np.random.default_rng(4)
    N = 500
    p = tmp_path / "fixed.mcap"
    with open(p, "wb") as fh:
        w = Writer(fh, chunk_size=4096)
        fixed = w.register_msgdef("hadal_test/msg/Fixed", FIXED_MSGDEF)
        text = w.register_msgdef("hadal_test/msg/Text", "string name\nfloat64 v\n")
        for i in range(N):
            w.write_message("/fixed", fixed, {
                "ok": bool(i % 2), "a": int(rng.integers(-128, 128)), "depth": float(rng.normal(-8000, 50)),
                "b": int(rng.integers(0, 65536)), "stamp": {"sec": 1538866800 + i, "nanosec": int(rng.integers(0, 10**9))},
                "acc": rng.normal(0, 1, 3).astype(np.float32).tolist(), "raw": [i % 256, 7], "big": -(2**62) + i},
                log_time=1000 + i, publish_time=1000 + i)
            w.write_message("/text", text, {"name": f"n{i}", "v": float(i)}, log_time=1000 + i, publish_time=0)
        w.finish()
    calls = []
    orig = MR._cdr_fixed_layout_of
    monkeypatch.setattr(MR, "_cdr_fixed_layout_of",
                        lambda b, s: (lambda r: calls.append((s.name, r is not None)) or r)(orig(b, s)))
    data, report = read_mcap(p)
    assert sorted(calls) == [("hadal_test/msg/Fixed", True), ("hadal_test/msg/Text", False)]
    assert report.decode_errors == 0 and report.messages_read == 2 * N
    dec = DecoderFactory()
    for topic in ("/fixed", "/text"):
        with open(p, "rb") as fh:
            exp = [MR.to_dict(dec.decoder_for(ch.message_encoding, s)(m.data))
                   for s, ch, m in make_reader(fh).iter_messages(topics=[topic])]
        assert data[topic].messages == exp
        assert data[topic].log_time_ns.tolist() == [1000 + i for i in range(N)]
