"""Streaming MCAP ingest (issue 48): each topic decoded one MCAP chunk at a time into its sensor's columns gives
the same samples as decoding all its messages at once.

Oracle: the ``mcap`` library's own reader (``make_reader(...).iter_messages``) decoding every message (``json`` /
mcap-ros2-support's ``DecoderFactory``), all of a topic's messages handed to :func:`sensor_from_records` in one call.
"""

from __future__ import annotations

import json
import warnings
from pathlib import Path

import numpy as np
import pytest

from hadal.ingest.build import read_mcap_sensors
from hadal.ingest.csv_reader import sensor_from_records
from hadal.ingest.vehicle import VehicleConfig, load_vehicle_config


def _peer_messages(path: Path, topic: str) -> tuple[np.ndarray, list, int]:
    """(log times, decoded messages as dicts, chunks) of ``topic`` read by the mcap library itself."""
    from mcap.reader import make_reader
    from mcap_ros2.decoder import DecoderFactory

    from hadal.ingest.mcap_reader import to_dict

    dec = DecoderFactory()
    t, msgs = [], []
    with open(path, "rb") as fh:
        r = make_reader(fh)
        chunks = len(r.get_summary().chunk_indexes)
        for sch, ch, m in r.iter_messages(topics=[topic]):
            t.append(m.log_time)
            msgs.append(json.loads(m.data) if ch.message_encoding == "json"
                        else to_dict(dec.decoder_for(ch.message_encoding, sch)(m.data)))
    return np.asarray(t, dtype=np.int64), msgs, chunks


def _assert_same(streamed, whole) -> None:
    assert streamed.name == whole.name and streamed.source == whole.source
    np.testing.assert_array_equal(streamed.time_ns, whole.time_ns)
    assert streamed.values.keys() == whole.values.keys()
    for k in whole.values:
        np.testing.assert_array_equal(streamed.values[k], whole.values[k])  # bitwise, NaN where NaN
    assert streamed.conversions == whole.conversions
    st = {k: v for k, v in streamed.stats.items() if k != "time_field_alternatives"}
    assert st == whole.stats


def test_sample_dive_mcap_streamed_equals_whole_topic_read(small_dive):
    """The sample dive's JSON MCAP log (many zstd chunks a topic): every sensor equal, bitwise."""
    path = small_dive / "logs" / "haidou.mcap"
    vehicle = load_vehicle_config(small_dive / "vehicle.yaml")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        streamed, _ = read_mcap_sensors([path], vehicle)
    assert streamed
    for name, s in vehicle.sensors.items():
        if s.mcap is None:
            continue
        t, msgs, chunks = _peer_messages(path, s.mcap.topic)
        assert chunks > 1  # several parts per topic: the streaming is exercised
        whole = sensor_from_records(name, t, msgs, s.mcap, f"mcap:{path.name}")
        _assert_same(streamed[name], whole)


def _cdr_vehicle(topics: dict[str, dict]) -> VehicleConfig:
    return VehicleConfig.model_validate({
        "vehicle": "test", "time_base": "ctd",
        "sensors": {name: {"required": name == "ctd", "mcap": m} for name, m in topics.items()}})


FIXED = "float64 pressure\nfloat64 temperature\nfloat64 conductivity\nbuiltin_interfaces/Time stamp\n" \
        "================================================================================\n" \
        "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"


def test_ros2_cdr_streamed_over_chunks_equals_whole_read(tmp_path):
    """ROS 2 CDR in many small chunks: a fixed-size type (hadal's vectorised decoder) timed by its header stamp,
    a variable-size one (mcap-ros2-support's decoder: a string field) by log time; the streamed samples equal the
    whole-topic read of the mcap library's messages."""
    from mcap_ros2.writer import Writer

    rng = np.random.default_rng(48)
    n, t0 = 3000, 1_538_866_800
    ctd = [{"pressure": float(x), "temperature": float(y), "conductivity": float(z),
            "stamp": {"sec": t0 + i, "nanosec": int(ns)}}
           for i, (x, y, z, ns) in enumerate(zip(rng.normal(5000, 10, n), rng.normal(2, 0.1, n),
                                                 rng.normal(3.2, 0.01, n), rng.integers(0, 10**9, n), strict=True))]
    gauge = [{"frame_id": "g" * int(k), "pressure": float(x)}
             for k, x in zip(rng.integers(0, 9, n // 4), rng.normal(5000, 10, n // 4), strict=True)]
    p = tmp_path / "cdr.mcap"
    with open(p, "wb") as fh:
        w = Writer(fh, chunk_size=2048)
        schemas = {"/ctd": w.register_msgdef("hadal_test/msg/Ctd", FIXED),
                   "/gauge": w.register_msgdef("hadal_test/msg/Gauge", "string frame_id\nfloat64 pressure\n")}
        for i, m in enumerate(ctd):
            w.write_message("/ctd", schemas["/ctd"], m, log_time=(t0 + i) * 10**9 + 7, publish_time=0)
            if i % 4 == 0:
                w.write_message("/gauge", schemas["/gauge"], gauge[i // 4], log_time=(t0 + i) * 10**9 + 11,
                                publish_time=0)
        w.finish()
    vehicle = _cdr_vehicle({
        "ctd": {"topic": "/ctd", "time": {"field": "stamp", "format": "ros_time"},
                "fields": {"pressure_ctd_dbar": {"field": "pressure", "units": "dbar"},
                           "temperature_its90_degc": {"field": "temperature", "units": "degC_its90"},
                           "conductivity_s_m": {"field": "conductivity", "units": "S/m"}}},
        "gauge": {"topic": "/gauge", "time": {"field": "log_time", "format": "unix_ns"},
                  "fields": {"pressure_gauge_dbar": {"field": "pressure", "units": "dbar"}}}})
    streamed, reports = read_mcap_sensors([p], vehicle)
    assert reports[0]["messages_read"] == n + n // 4
    for name, s in vehicle.sensors.items():
        t, msgs, chunks = _peer_messages(p, s.mcap.topic)
        assert chunks > 10
        _assert_same(streamed[name], sensor_from_records(name, t, msgs, s.mcap, f"mcap:{p.name}"))


@pytest.mark.parametrize("name", ["rosbag2_test_bag_for_seek_0.mcap", "rosbag2_cdr_test_0.mcap"])
def test_real_ros2_bag_streamed_equals_whole_read(shared_data, name):
    """Real rosbag2 recordings (test_msgs BasicTypes): a numeric field mapped as a sensor, timed by log time."""
    path = shared_data / "mcap-real" / name
    topic = "topic1" if "seek" in name else "/test_topic"
    vehicle = _cdr_vehicle({"ctd": {"topic": topic, "time": {"field": "log_time", "format": "unix_ns"},
                                    "fields": {"pressure_ctd_dbar": {"field": "float64_value", "units": "dbar"},
                                               "temperature_its90_degc": {"field": "int32_value",
                                                                          "units": "degC_its90"}}}})
    streamed, _ = read_mcap_sensors([path], vehicle)
    t, msgs, _ = _peer_messages(path, topic)
    _assert_same(streamed["ctd"], sensor_from_records("ctd", t, msgs, vehicle.sensors["ctd"].mcap,
                                                      f"mcap:{path.name}"))
    assert len(streamed["ctd"].time_ns) == len(msgs) > 0
