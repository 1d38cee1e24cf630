"""Describe vehicle logs (MCAP, CSV) and suggest the vehicle channel mapping (hadal.ingest.suggest).

Independent references: the ``mcap`` library's own summary (counts, topics, times), rosbags' CDR
deserialiser (values of the real ROS 2 files) and rosbags' MCAP writer (the standard ROS 2 types written
here), scipy's Rotation (quaternions) and pyproj's Geod (GNSS positions).
"""

from __future__ import annotations

import dataclasses
import json
import warnings
from pathlib import Path

import numpy as np
import pytest
import yaml

from hadal.errors import InputError
from hadal.ingest.build import read_csv_sensors, read_mcap_sensors
from hadal.ingest.suggest import describe_csv, describe_mcap, render_vehicle_yaml, suggest_vehicle
from hadal.ingest.units import apply_transform, quaternion_to_euler_deg
from hadal.ingest.vehicle import default_vehicle_config_path, load_vehicle_config

REAL = ("rosbag2_cdr_test_0.mcap", "rosbag2_talker.mcap", "rosbag2_test_bag_for_seek_0.mcap")
T0 = 1538866800  # 2018-10-06T23:00:00Z


# ------------------------------------------------------------------------------------------------ real files


@pytest.mark.parametrize("name", REAL)
def test_describe_real_mcap_matches_mcap_summary(shared_data, name):
    from mcap.reader import make_reader

    path = shared_data / "mcap-real" / name
    d = describe_mcap(path)
    json.dumps(d, allow_nan=False)  # JSON-serialisable as it is
    with open(path, "rb") as fh:
        r = make_reader(fh)
        header, s = r.get_header(), r.get_summary()
    assert d["profile"] == header.profile == "ros2" and d["library"] == header.library
    assert d["message_count"] == d["messages_expected"] == s.statistics.message_count
    assert d["messages_lost"] == 0 and not d["truncated"] and d["summary"]
    assert d["chunks"]["read"] == d["chunks"]["expected"] == len(s.chunk_indexes) and d["chunks"]["lost"] == 0
    by_id = {c["id"]: c for c in d["channels"]}
    assert set(by_id) == set(s.channels)
    for cid, ch in s.channels.items():
        c = by_id[cid]
        sch = s.schemas[ch.schema_id]
        assert (c["topic"], c["message_encoding"], c["schema_name"], c["schema_encoding"]) == \
            (ch.topic, ch.message_encoding, sch.name, sch.encoding)
        assert c["message_count"] == c["messages_expected"] == s.statistics.channel_message_counts.get(cid, 0)
        assert c["message_type"].count("/msg/") == 1
    starts = [c["first_log_time_ns"] for c in d["channels"] if c["first_log_time_ns"] is not None]
    ends = [c["last_log_time_ns"] for c in d["channels"] if c["last_log_time_ns"] is not None]
    assert min(starts) == s.statistics.message_start_time and max(ends) == s.statistics.message_end_time
    assert d["start_time"] == str(np.datetime64(s.statistics.message_start_time, "ns").astype("datetime64[ms]")) + "Z"
    # every channel with messages had its first message decoded from the schema stored in the file
    for c in d["channels"]:
        assert c["decode_error"] is None
        assert bool(c["fields"]) == (c["message_count"] > 0)


def test_describe_real_fields(shared_data):
    d = describe_mcap(shared_data / "mcap-real" / "rosbag2_test_bag_for_seek_0.mcap")
    (c,) = d["channels"]
    assert c["message_type"] == "test_msgs/msg/BasicTypes" and c["schema_name"] == "test_msgs/BasicTypes"
    assert "int32_value" in c["fields"] and c["first_message"]["int32_value"] == 1
    assert c["first_log_time"] == "1970-01-01T00:00:01.000Z" and c["rate_hz"] == pytest.approx(10.0)
    talker = describe_mcap(shared_data / "mcap-real" / "rosbag2_talker.mcap")
    rosout = next(c for c in talker["channels"] if c["topic"] == "/rosout")
    assert {"stamp.sec", "stamp.nanosec", "msg", "level"} <= set(rosout["fields"])
    assert talker["chunks"]["compression"] == ["zstd"]


def _plain(o):
    if dataclasses.is_dataclass(o):
        return {f.name: _plain(getattr(o, f.name)) for f in dataclasses.fields(o)
                if not f.name.isupper() and f.name not in ("__msgtype__", "structure_needs_at_least_one_member")}
    if isinstance(o, np.ndarray):
        return o.tolist()
    if isinstance(o, (list, tuple)):
        return [_plain(x) for x in o]
    if isinstance(o, np.generic):
        return o.item()
    return o


def _rosbags_decode(path: Path) -> dict[str, list[dict]]:
    """Every message decoded by rosbags from the schema text stored in the file (names normalised to pkg/msg/T)."""
    pytest.importorskip("rosbags", reason="rosbags (test dependency) is not installed")
    from mcap.reader import make_reader
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    out: dict[str, list[dict]] = {}
    stores = {}
    with open(path, "rb") as fh:
        for sch, ch, msg in make_reader(fh).iter_messages():
            name = sch.name if "/msg/" in sch.name else sch.name.replace("/", "/msg/", 1)
            if sch.id not in stores:
                ts = get_typestore(Stores.EMPTY)
                parts = sch.data.decode().split("\n" + "=" * 80 + "\n")
                types = dict(get_types_from_msg(parts[0], name))
                for part in parts[1:]:
                    first, _, body = part.strip("\n").partition("\n")
                    sub = first.removeprefix("MSG: ").strip()
                    sub = sub if "/msg/" in sub else sub.replace("/", "/msg/", 1)
                    types.update(get_types_from_msg(body, sub))
                ts.register(types)
                stores[sch.id] = ts
            out.setdefault(ch.topic, []).append(_plain(stores[sch.id].deserialize_cdr(msg.data, name)))
    return out


def _same(a, b, key=""):
    """Equal values; ROS 2 ``byte`` is an unsigned octet: rosbags gives it as int8 (-1), mcap-ros2-support as
    uint8 (255) - the same bits. Empty messages: rosbags adds a placeholder member."""
    if isinstance(a, dict) and isinstance(b, dict):
        return set(a) == set(b) and all(_same(a[k], b[k], k) for k in a)
    if isinstance(a, list) and isinstance(b, (list, bytes)):
        return len(a) == len(b) and all(_same(x, y, key) for x, y in zip(a, b, strict=True))
    if isinstance(a, float) and isinstance(b, float) and np.isnan(a):
        return np.isnan(b)
    if isinstance(a, int) and isinstance(b, int) and key.startswith("byte"):
        return (a - b) % 256 == 0
    return a == b


@pytest.mark.parametrize("name", REAL)
def test_cdr_values_match_rosbags(shared_data, name):
    from hadal.ingest.mcap_reader import read_mcap

    path = shared_data / "mcap-real" / name
    ours, report = read_mcap(path)
    ref = _rosbags_decode(path)
    assert report.decode_errors == 0
    assert report.messages_read == sum(len(v) for v in ref.values()) == describe_mcap(path)["message_count"]
    for topic, msgs in ref.items():
        assert len(ours[topic].messages) == len(msgs)
        for a, b in zip(msgs, ours[topic].messages, strict=True):
            assert _same(a, b), (topic, a, b)


def test_real_talker_has_nothing_to_map(shared_data):
    s = suggest_vehicle([shared_data / "mcap-real" / "rosbag2_talker.mcap"])
    assert not s.ok and s.vehicle is None and s.config() is None
    reasons = {u["source"]: u["reason"] for u in s.unmapped}
    assert set(reasons) == {"/rosout", "/parameter_events", "/topic"}
    assert reasons["/parameter_events"] == "no messages" and "std_msgs/msg/String" in reasons["/topic"]
    assert yaml.safe_load(render_vehicle_yaml(s)) is None
    for name in REAL:  # none of the real files holds a sensor hadal knows
        assert not suggest_vehicle([shared_data / "mcap-real" / name]).ok


def test_ingest_of_unmapped_mcap_is_one_clear_error(shared_data):
    vehicle = load_vehicle_config(default_vehicle_config_path())
    with pytest.raises(InputError) as exc:
        read_mcap_sensors([shared_data / "mcap-real" / "rosbag2_talker.mcap"], vehicle)
    msg = str(exc.value)
    assert "\n" not in msg and "nothing to ingest" in msg and "/rosout" in msg and "/haidou/ctd" in msg


def test_describe_truncated_real_file(shared_data, tmp_path):
    b = (shared_data / "mcap-real" / "rosbag2_cdr_test_0.mcap").read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(b[: len(b) - 2000])  # into the summary: the data chunk is intact
    d = describe_mcap(cut)
    assert d["truncated"] and d["chunks"]["read"] == 1 and d["message_count"] == 7
    cut.write_bytes(b[: len(b) // 2])  # into the only chunk: nothing left, and no summary to count from
    d = describe_mcap(cut)
    assert d["truncated"] and d["message_count"] == 0 and d["messages_lost"] is None
    assert d["chunks"]["expected"] is None and d["problem"]
    json.dumps(d, allow_nan=False)


# ------------------------------------------------------------------------------------------------ damaged JSON MCAP


@pytest.fixture(scope="module")
def tiny_mcap(tmp_path_factory):
    import sys

    sys.path.insert(0, str(Path(__file__).parents[2] / "malformed"))
    from tiny_dive import messages, write_mcap

    msgs = messages(20.0)
    p = tmp_path_factory.mktemp("mcap") / "haidou.mcap"
    write_mcap(p, msgs, chunk_size=2048)
    return p, msgs


def test_describe_damaged_mcap_counts_lost_chunks(tiny_mcap, tmp_path):
    from mcap.reader import make_reader

    p, msgs = tiny_mcap
    total = sum(len(v) for v in msgs.values())
    d = describe_mcap(p)
    assert d["message_count"] == total and d["chunks"]["lost"] == 0
    assert {c["topic"]: c["message_count"] for c in d["channels"]} == {k: len(v) for k, v in msgs.items()}
    ctd = next(c for c in d["channels"] if c["topic"] == "/haidou/ctd")
    assert ctd["fields"] == ["stamp", "cond", "temp", "pres"] and ctd["rate_hz"] == pytest.approx(16.0)
    with open(p, "rb") as fh:
        chunks = make_reader(fh).get_summary().chunk_indexes
    b = bytearray(p.read_bytes())
    ci = chunks[1]
    b[ci.chunk_start_offset + ci.chunk_length // 2] ^= 0x5A
    flip = tmp_path / "flip.mcap"
    flip.write_bytes(bytes(b))
    d = describe_mcap(flip)
    assert d["chunks"]["corrupt"] == 1 and d["chunks"]["lost"] == 1 and d["chunks"]["expected"] == len(chunks)
    assert d["messages_expected"] == total and d["messages_lost"] == total - d["message_count"] > 0
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(p.read_bytes()[: chunks[len(chunks) // 2].chunk_start_offset + 100])
    d = describe_mcap(cut)
    assert d["truncated"] and d["chunks"]["read"] == len(chunks) // 2 and 0 < d["message_count"] < total
    assert d["messages_lost"] is None  # the footer is gone: how many is unknown
    s = suggest_vehicle([cut])  # still suggests from the intact chunks, and says the file is damaged
    assert s.ok and any("damaged" in c for c in s.checks)


# ------------------------------------------------------------------------------------------------ sample dive


@pytest.fixture(scope="module")
def sample_dive(small_dive):
    return small_dive


def test_sample_dive_suggestion_equals_haidou_yaml(sample_dive, tmp_path):
    dive = yaml.safe_load((sample_dive / "dive.yaml").read_text())
    csv = {k: sample_dive / v for k, v in dive["sources"]["csv"].items()}
    s = suggest_vehicle([sample_dive / "logs" / "haidou.mcap"], csv)
    assert s.ok and not s.unmapped
    got = s.config().model_dump()
    want = load_vehicle_config(default_vehicle_config_path()).model_dump()
    assert got.pop("vehicle") == "Haidou"  # from the channels' metadata
    want.pop("vehicle")
    assert got == want
    assert s.time_base == "ctd" and s.checks[0].startswith("time base: 'ctd'")
    assert s.mcap_used == [str(sample_dive / "logs" / "haidou.mcap")] and set(s.csv_used) == set(csv)
    assert not any(m["assumed"] for m in s.mapped)
    text = render_vehicle_yaml(s)
    assert yaml.safe_load(text) == s.vehicle and "# " in text
    (tmp_path / "suggested.yaml").write_text(text)
    assert load_vehicle_config(tmp_path / "suggested.yaml").model_dump()["sensors"] == want["sensors"]
    json.dumps(s.as_dict(), allow_nan=False)


def test_sample_dive_csv_only(sample_dive):
    csv = {p.stem: p for p in sorted((sample_dive / "csv").glob("*.csv"))}
    s = suggest_vehicle([], csv)
    cfg = s.config()
    assert cfg.time_base == "ctd"
    want = load_vehicle_config(default_vehicle_config_path())
    assert set(cfg.variables()) == set(want.variables())
    assert {n: s_.csv.fields for n, s_ in cfg.sensors.items()} == \
        {n: s_.csv.fields for n, s_ in want.sensors.items()}
    assert cfg.sensors["gauge"].csv.source == "keller" and all(s_.mcap is None for s_ in cfg.sensors.values())
    d = describe_csv(csv["ctd"])
    assert d["delimiter"] == "," and d["time_column"] == "time" and d["time_format"] == "iso8601"
    assert d["columns"] == ["time", "conductivity_mS_cm", "temperature_ITS90", "pressure_dbar"]
    assert d["rows"] == len((sample_dive / "csv" / "ctd.csv").read_text().splitlines()) - 1
    assert d["start_time"] == "2018-10-06T23:00:00.000Z" and d["sample_row"]["pressure_dbar"]
    assert describe_csv(csv["altimeter"])["first_values"]["altitude_m"]  # empty at the surface, found later


# ------------------------------------------------------------------------------------------------ CSV variants


def test_csv_semicolon_unix_time_and_units(tmp_path):
    p = tmp_path / "ctd.csv"
    rows = ["timestamp;Conductivity_mS_cm;Temp_degC;Pres_bar;sound_speed_m_s;status"]
    for i in range(50):
        rows.append(f"{T0 + i * 0.5:.3f};{35 + 0.01 * i:.3f};{2.5 - 0.001 * i:.4f};{100 + i:.2f};1500;ok")
    p.write_text("\n".join(rows) + "\n")
    d = describe_csv(p)
    assert d["delimiter"] == ";" and d["time_column"] == "timestamp" and d["time_format"] == "unix_s"
    assert d["rows"] == 50 and d["rate_hz"] == pytest.approx(2.0) and d["duration_s"] == pytest.approx(24.5)
    s = suggest_vehicle([], {"ctd": p})
    cfg = s.config()
    ctd = cfg.sensors["ctd"].csv
    assert ctd.delimiter == ";" and ctd.time.format == "unix_s"
    assert {v: (f.field, f.units) for v, f in ctd.fields.items()} == {
        "conductivity_s_m": ("Conductivity_mS_cm", "mS/cm"), "temperature_its90_degc": ("Temp_degC", "degC_its90"),
        "pressure_ctd_dbar": ("Pres_bar", "bar")}
    samples = read_csv_sensors({"ctd": p}, cfg)["ctd"]
    assert samples.values["pressure_ctd_dbar"][:2].tolist() == pytest.approx([1000.0, 1010.0])
    assert samples.values["conductivity_s_m"][0] == pytest.approx(3.5)
    assert samples.time_ns[1] - samples.time_ns[0] == 500_000_000


def test_csv_without_units_uses_magnitude_and_asks_to_check(tmp_path):
    p = tmp_path / "c.csv"
    p.write_text("time,cond,temp,pressure\n" + "".join(
        f"2018-10-06T23:00:{i:02d}Z,{56 + i * 0.01:.2f},{28.0:.2f},{i * 1.0:.1f}\n" for i in range(20)))
    s = suggest_vehicle([], {"c": p})
    m = {x["variable"]: x for x in s.mapped}
    alt = _write(p.with_name("alt.csv"), "time,range,valid\n2018-10-06T23:00:00Z,,false\n2018-10-06T23:00:01Z,12.5,true\n")
    assert suggest_vehicle([], {"alt": alt}).config().sensors["altimeter"].csv.valid_field == "valid"
    assert m["conductivity_s_m"]["units"] == "mS/cm" and m["conductivity_s_m"]["assumed"]
    assert m["temperature_its90_degc"]["units"] == "degC_its90"
    assert any("cond" in c and "check the unit" in c for c in s.checks)
    assert "CHECK THE UNIT" in render_vehicle_yaml(s)
    # the variables a dive needs and lacks are named; the optional ones (GNSS/USBL fixes, vendor salinity) are not
    missing = next(c for c in s.checks if c.startswith("not found in the logs"))
    assert "altitude_m" in missing and "heading_deg" in missing
    assert "gnss" not in missing and "usbl" not in missing and "vendor" not in missing


def test_gnss_channel_named_by_its_topic_gives_fixes_not_dead_reckoning(tmp_path):
    """A CSV key saying gps with latitude/longitude columns and their variances: GNSS fixes (gnss_*), in a sensor
    named gnss; the same columns under another name stay a dead-reckoned track (metres from the first fix)."""
    rows = "".join(f"2018-10-06T23:00:{i:02d}Z,11.3{i:02d},142.2,4.0,9.0\n" for i in range(20))
    gps = _write(tmp_path / "gps.csv", "time,latitude,longitude,east_variance,north_variance\n" + rows)
    cfg = suggest_vehicle([], {"gps": gps}).config()
    fx = cfg.sensors["gnss"].csv.fields
    assert (fx["gnss_latitude_deg"].field, fx["gnss_longitude_deg"].field) == ("latitude", "longitude")
    assert (fx["gnss_east_variance_m2"].field, fx["gnss_north_variance_m2"].field) == ("east_variance", "north_variance")
    assert "dr_east_m" not in cfg.variables()
    nav = _write(tmp_path / "nav.csv", "time,latitude,longitude\n" + "".join(r.rsplit(",", 2)[0] + "\n" for r in rows.splitlines()))
    cfg = suggest_vehicle([], {"nav": nav}).config()
    assert cfg.sensors[cfg.sensor_of("dr_east_m")].csv.fields["dr_east_m"].transform == "latlon_to_east_m"
    assert "gnss_latitude_deg" not in cfg.variables()


def test_csv_with_no_time_or_no_variables(tmp_path):
    a = tmp_path / "a.csv"
    a.write_text("x,y\n1,2\n3,4\n")
    b = tmp_path / "b.csv"
    b.write_text("time,voltage\n2018-10-06T23:00:00Z,12.1\n2018-10-06T23:00:01Z,12.0\n")
    s = suggest_vehicle([], {"a": a, "b": b})
    assert not s.ok
    reasons = {u["source"]: u["reason"] for u in s.unmapped}
    assert "time column" in reasons["a"] and "voltage" in reasons["b"]
    with pytest.raises(InputError, match="empty"):
        describe_csv(_write(tmp_path / "e.csv", ""))
    with pytest.raises(InputError, match="does not exist"):
        describe_csv(tmp_path / "nope.csv")


def _write(p: Path, text: str) -> Path:
    p.write_text(text)
    return p


# ------------------------------------------------------------------------------------------------ ROS 2 standard types


def _quat_from_marine(heading, pitch, roll):
    """ENU/FLU quaternion (x, y, z, w) of a marine heading/pitch/roll, with scipy (independent of hadal)."""
    from scipy.spatial.transform import Rotation

    return Rotation.from_euler("ZYX", np.column_stack([90.0 - heading, -pitch, roll]), degrees=True).as_quat()


def test_quaternion_transforms_against_scipy():
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(1)
    h, p, r = rng.uniform(0, 360, 200), rng.uniform(-80, 80, 200), rng.uniform(-170, 170, 200)
    q = _quat_from_marine(h, p, r)
    hh, pp, rr = quaternion_to_euler_deg(*q.T)
    assert np.allclose(np.mod(hh - h + 180, 360) - 180, 0, atol=1e-7)
    assert np.allclose(pp, p, atol=1e-7) and np.allclose(rr, r, atol=1e-7)
    # NED/FRD: yaw is the heading, pitch/roll as is
    qn = Rotation.from_euler("ZYX", np.column_stack([h, p, r]), degrees=True).as_quat()
    hn, pn, rn = quaternion_to_euler_deg(*qn.T, frame="ned")
    assert np.allclose(np.mod(hn - h + 180, 360) - 180, 0, atol=1e-7) and np.allclose(pn, p, atol=1e-7)
    # facing north, bow up 10 deg, unnormalised: still exact; a zero quaternion is missing
    q1 = _quat_from_marine(np.array([0.0]), np.array([10.0]), np.array([0.0]))[0] * 3
    assert apply_transform("quaternion_to_heading_deg", [[q1[0]], [q1[1]], [q1[2]], [q1[3]]])[0] == \
        pytest.approx(0.0, abs=1e-9)
    assert apply_transform("quaternion_to_pitch_deg", [[q1[0]], [q1[1]], [q1[2]], [q1[3]]])[0] == pytest.approx(10.0)
    assert np.isnan(apply_transform("quaternion_to_heading_deg", [[0.0], [0.0], [0.0], [0.0]])[0])


def _truth(t):
    s = t - T0
    return {"cond_ms_cm": 35.0 + 0.01 * s, "temp": 2.0 - 0.001 * s, "pres": 100.0 + 0.5 * s,
            "gauge": 101.0 + 0.5 * s, "alt": 50.0 - 0.2 * s, "heading": np.mod(350.0 + 1.5 * s, 360.0),
            "pitch": 5.0 * np.sin(s / 7), "roll": 3.0 * np.cos(s / 5), "east": 0.3 * s, "north": -0.4 * s,
            "speed": np.full_like(s, 0.5)}


def _write_ros_mcap(path: Path, *, odometry: bool = True, duration: float = 60.0) -> Path:
    """A rosbag2 MCAP written by rosbags (schemas generated by rosbags from its ROS 2 Humble type store)."""
    pytest.importorskip("rosbags", reason="rosbags (test dependency) is not installed")
    from rosbags.rosbag2 import StoragePlugin, Writer
    from rosbags.typesys import Stores, get_types_from_msg, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    ts.register(get_types_from_msg("std_msgs/Header header\nfloat64 conductivity\nfloat64 temperature\n"
                                   "float64 pressure\n", "hadal_test/msg/Ctd"))
    T = ts.types
    Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    V3, Q, P = T["geometry_msgs/msg/Vector3"], T["geometry_msgs/msg/Quaternion"], T["geometry_msgs/msg/Point"]
    z9, z36 = np.zeros(9), np.zeros(36)

    def hdr(tn):
        st = tn - 3_000_000  # the sensor stamp is 3 ms before the recorder's log_time
        return Header(stamp=Time(sec=int(st // 10**9), nanosec=int(st % 10**9)), frame_id="base_link")

    def msgs(rate, make):
        n = int(duration * rate)
        tn = T0 * 10**9 + np.arange(n, dtype=np.int64) * int(round(1e9 / rate))
        tr = _truth((tn - 3_000_000) / 1e9)
        return [(int(x), make(int(x), {k: float(v[i]) for k, v in tr.items()})) for i, x in enumerate(tn)]

    chans = {
        "/vehicle/ctd": ("hadal_test/msg/Ctd", msgs(4.0, lambda tn, v: T["hadal_test/msg/Ctd"](
            header=hdr(tn), conductivity=v["cond_ms_cm"], temperature=v["temp"], pressure=v["pres"]))),
        "/vehicle/water_temperature": ("sensor_msgs/msg/Temperature", msgs(1.0, lambda tn, v: T[
            "sensor_msgs/msg/Temperature"](header=hdr(tn), temperature=v["temp"] + 0.01, variance=0.0))),
        "/vehicle/depth": ("sensor_msgs/msg/FluidPressure", msgs(2.0, lambda tn, v: T[
            "sensor_msgs/msg/FluidPressure"](header=hdr(tn), fluid_pressure=(v["gauge"] + 10.1325) * 1e4,
                                             variance=0.0))),
        "/vehicle/altimeter": ("sensor_msgs/msg/Range", msgs(1.0, lambda tn, v: T["sensor_msgs/msg/Range"](
            header=hdr(tn), radiation_type=0, field_of_view=0.1, min_range=0.5, max_range=100.0, range=v["alt"]))),
        "/vehicle/imu": ("sensor_msgs/msg/Imu", msgs(5.0, lambda tn, v: T["sensor_msgs/msg/Imu"](
            header=hdr(tn), orientation=Q(*_quat_from_marine(np.array([v["heading"]]), np.array([v["pitch"]]),
                                                             np.array([v["roll"]]))[0]),
            orientation_covariance=z9, angular_velocity=V3(x=0.0, y=0.0, z=0.0), angular_velocity_covariance=z9,
            linear_acceleration=V3(x=0.0, y=0.0, z=9.8), linear_acceleration_covariance=z9))),
        "/vehicle/fix": ("sensor_msgs/msg/NavSatFix", msgs(0.5, lambda tn, v: T["sensor_msgs/msg/NavSatFix"](
            header=hdr(tn), status=T["sensor_msgs/msg/NavSatStatus"](status=0, service=1),
            latitude=11.33 + v["north"] / 110_000.0, longitude=142.2, altitude=0.0,
            position_covariance=np.array([4.0, 0.5, 0, 0.5, 9.0, 0, 0, 0, 16.0]), position_covariance_type=2))),
        "/vehicle/log": ("std_msgs/msg/String", msgs(0.2, lambda tn, v: T["std_msgs/msg/String"](data="hello"))),
    }
    if odometry:
        PwC, TwC = T["geometry_msgs/msg/PoseWithCovariance"], T["geometry_msgs/msg/TwistWithCovariance"]
        chans["/vehicle/odom"] = ("nav_msgs/msg/Odometry", msgs(1.0, lambda tn, v: T["nav_msgs/msg/Odometry"](
            header=hdr(tn), child_frame_id="base_link",
            pose=PwC(pose=T["geometry_msgs/msg/Pose"](position=P(x=v["east"], y=v["north"], z=-v["pres"]),
                                                       orientation=Q(x=0.0, y=0.0, z=0.0, w=1.0)), covariance=z36),
            twist=TwC(twist=T["geometry_msgs/msg/Twist"](linear=V3(x=0.3, y=0.4, z=0.0),
                                                          angular=V3(x=0.0, y=0.0, z=0.0)), covariance=z36))))
    else:
        chans["/vehicle/velocity"] = ("geometry_msgs/msg/TwistStamped", msgs(1.0, lambda tn, v: T[
            "geometry_msgs/msg/TwistStamped"](header=hdr(tn), twist=T["geometry_msgs/msg/Twist"](
                linear=V3(x=0.0, y=-0.5, z=0.1), angular=V3(x=0.0, y=0.0, z=0.0)))))
    bag = path.with_suffix("")
    with Writer(bag, version=9, storage_plugin=StoragePlugin.MCAP) as w:
        conns = {topic: w.add_connection(topic, mtype, typestore=ts) for topic, (mtype, _) in chans.items()}
        events = sorted((tn, topic, m) for topic, (_, lst) in chans.items() for tn, m in lst)
        for tn, topic, m in events:
            w.write(conns[topic], tn, ts.serialize_cdr(m, chans[topic][0]))
    (mcap,) = bag.glob("*.mcap")
    return mcap


@pytest.fixture(scope="module")
def ros_mcap(tmp_path_factory):
    return _write_ros_mcap(tmp_path_factory.mktemp("ros") / "vehicle.mcap")


def test_ros2_standard_types_suggest_and_ingest(ros_mcap):
    d = describe_mcap(ros_mcap)
    assert d["library"].startswith("rosbags") and d["profile"] == "ros2"
    types = {c["topic"]: c["message_type"] for c in d["channels"]}
    assert types["/vehicle/imu"] == "sensor_msgs/msg/Imu" and types["/vehicle/odom"] == "nav_msgs/msg/Odometry"

    s = suggest_vehicle([ros_mcap])
    cfg = s.config()
    assert cfg.time_base == "ctd" and cfg.sensors["ctd"].required and cfg.sensors["gauge"].required
    src = {v: (cfg.sensors[cfg.sensor_of(v)].mcap.topic) for v in cfg.variables()}
    assert src == {"conductivity_s_m": "/vehicle/ctd", "temperature_its90_degc": "/vehicle/ctd",
                   "pressure_ctd_dbar": "/vehicle/ctd", "pressure_gauge_dbar": "/vehicle/depth",
                   "altitude_m": "/vehicle/altimeter", "heading_deg": "/vehicle/imu", "pitch_deg": "/vehicle/imu",
                   "roll_deg": "/vehicle/imu", "dr_east_m": "/vehicle/odom", "dr_north_m": "/vehicle/odom",
                   "speed_m_s": "/vehicle/odom", "gnss_latitude_deg": "/vehicle/fix", "gnss_longitude_deg": "/vehicle/fix",
                   "gnss_east_variance_m2": "/vehicle/fix", "gnss_north_variance_m2": "/vehicle/fix"}
    gauge = cfg.sensors["gauge"].mcap
    assert gauge.fields["pressure_gauge_dbar"].units == "Pa" and gauge.fields["pressure_gauge_dbar"].offset == -10.1325
    assert gauge.time.field == "header.stamp" and gauge.time.format == "ros_time"
    assert cfg.sensors["ctd"].mcap.fields["conductivity_s_m"].units == "mS/cm"  # from the magnitude (35)
    why = {(u["source"], u.get("field")): u["reason"] for u in s.unmapped}
    assert "taken from /vehicle/ctd" in why[("/vehicle/water_temperature", "temperature")]
    assert any(k[0] == "/vehicle/fix" for k in why) and any(k[0] == "/vehicle/log" for k in why)
    assert any("taken from /vehicle/imu" in r for (t, _), r in why.items() if t == "/vehicle/odom")
    assert any("FluidPressure is absolute" in c for c in s.checks)

    # the rendered YAML is what ingest reads
    yml = ros_mcap.parent / "vehicle.yaml"
    yml.write_text(render_vehicle_yaml(s))
    cfg = load_vehicle_config(yml)
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        sensors, reports = read_mcap_sensors([ros_mcap], cfg)
    assert reports[0]["messages_lost"] == 0
    g = sensors["gauge"]
    t = g.time_ns / 1e9
    tr = _truth(t)
    assert g.time_ns[0] == T0 * 10**9 - 3_000_000  # header.stamp, not log_time
    assert np.allclose(g.values["pressure_gauge_dbar"], tr["gauge"], atol=1e-9)  # Pa -> dbar, minus 1 atm
    conv = {c["variable"]: c["formula"] for c in g.conversions}
    assert conv["pressure_gauge_dbar"] == "x + -10.1325"
    ctd = sensors["ctd"]
    trc = _truth(ctd.time_ns / 1e9)
    assert np.allclose(ctd.values["conductivity_s_m"], trc["cond_ms_cm"] / 10)
    assert np.allclose(ctd.values["pressure_ctd_dbar"], trc["pres"])
    att = sensors["attitude"]
    tra = _truth(att.time_ns / 1e9)
    dh = np.mod(att.values["heading_deg"] - tra["heading"] + 180, 360) - 180
    assert np.abs(dh).max() < 1e-9 and np.allclose(att.values["pitch_deg"], tra["pitch"], atol=1e-9)
    assert np.allclose(att.values["roll_deg"], tra["roll"], atol=1e-9)
    assert any(c["formula"] == "quaternion_to_heading_deg" for c in att.conversions)
    nav = sensors[cfg.sensor_of("dr_east_m")]
    trn = _truth(nav.time_ns / 1e9)
    assert np.allclose(nav.values["dr_east_m"], trn["east"]) and np.allclose(nav.values["dr_north_m"], trn["north"])
    assert np.allclose(nav.values["speed_m_s"], 0.5)
    assert np.allclose(sensors["altimeter"].values["altitude_m"], _truth(sensors["altimeter"].time_ns / 1e9)["alt"])
    # a NavSatFix is a GNSS fix (issue 47), not a dead-reckoned offset: latitude/longitude as written, the
    # position_covariance's east [0] and north [4] variances (ENU)
    fx = sensors[cfg.sensor_of("gnss_latitude_deg")]
    trf = _truth(fx.time_ns / 1e9)
    assert np.allclose(fx.values["gnss_latitude_deg"], 11.33 + trf["north"] / 110_000.0)
    assert np.allclose(fx.values["gnss_longitude_deg"], 142.2)
    assert np.allclose(fx.values["gnss_east_variance_m2"], 4.0) and np.allclose(fx.values["gnss_north_variance_m2"], 9.0)

    # and the whole table builds on the CTD time base
    from hadal.ingest.build import build_sensor_table

    table, meta = build_sensor_table(sensors, cfg, max_gap_s={})
    assert meta["time_base"] == "ctd" and table["pressure_gauge_dbar"].notna().mean() > 0.9
    assert table["heading_deg"].notna().mean() > 0.9
    # an optional column, present with its source: each 0.5 Hz fix at one CTD sample (its nearest), not interpolated
    got = table["gnss_latitude_deg"].dropna().to_numpy()
    assert got.size == fx.values["gnss_latitude_deg"].size
    np.testing.assert_allclose(np.sort(got), np.sort(fx.values["gnss_latitude_deg"]))


def test_ros2_gnss_positions_and_twist(tmp_path):
    """A NavSatFix is a GNSS fix (gnss_latitude/longitude_deg with its covariance; the navigation smoother uses
    it at the surface), not dead-reckoned offsets from the launch (issue 47)."""
    p = _write_ros_mcap(tmp_path / "nav.mcap", odometry=False)
    s = suggest_vehicle([p], launch=(11.33, 142.2))
    cfg = s.config()
    nav = cfg.sensors[cfg.sensor_of("gnss_latitude_deg")].mcap
    assert nav.topic == "/vehicle/fix" and nav.fields["gnss_latitude_deg"].field == "latitude"
    assert nav.fields["gnss_north_variance_m2"].field == "position_covariance.4"
    assert "dr_north_m" not in cfg.variables() and "dr_east_m" not in cfg.variables()
    assert cfg.sensors[cfg.sensor_of("speed_m_s")].mcap.topic == "/vehicle/velocity"
    sensors, _ = read_mcap_sensors([p], cfg)
    fix = sensors[cfg.sensor_of("gnss_latitude_deg")]
    lat = 11.33 + _truth(fix.time_ns / 1e9)["north"] / 110_000.0  # the values written into the messages
    assert np.allclose(fix.values["gnss_latitude_deg"], lat, atol=1e-12)
    assert np.allclose(fix.values["gnss_longitude_deg"], 142.2)
    assert np.allclose(fix.values["gnss_east_variance_m2"], 4.0)
    assert np.allclose(sensors[cfg.sensor_of("speed_m_s")].values["speed_m_s"], 0.5)


def test_custom_ros_ctd_units_from_msg_comments(tmp_path):
    """A vehicle's own CTD message: recognised by its field names, units read from the .msg comments
    (written with mcap-ros2-support's writer, a hand-written definition)."""
    from mcap_ros2.writer import Writer

    p = tmp_path / "custom.mcap"
    ctd_def = ("# SBE 49 sample\nstd_msgs/Header header\n"
               "float32 cond    # conductivity [mS/cm]\n"
               "float64 temp    # temperature, degC IPTS-68\n"
               "float64 pres    # sea pressure in bar\n"
               "uint8 STATUS_OK=0\nuint8 status\n"
               "================================================================================\n"
               "MSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n"
               "================================================================================\n"
               "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n")
    with open(p, "wb") as fh:
        w = Writer(fh)
        ctd = w.register_msgdef("acme_msgs/msg/Sbe49", ctd_def)
        alt = w.register_msgdef("std_msgs/msg/Float64", "float64 data\n")
        for i in range(40):
            tn = (T0 + i) * 10**9
            w.write_message("/acme/sbe49", ctd, {"header": {"stamp": {"sec": T0 + i, "nanosec": 0}, "frame_id": ""},
                                                 "cond": 35.0 + i * 0.1, "temp": 2.0, "pres": 100.0 + i,
                                                 "status": 0}, log_time=tn, publish_time=tn)
            w.write_message("/acme/altitude", alt, {"data": 20.0 - 0.1 * i}, log_time=tn + 1, publish_time=tn + 1)
        w.finish()
    d = describe_mcap(p)
    c = next(c for c in d["channels"] if c["topic"] == "/acme/sbe49")
    assert c["field_docs"] == {"cond": "conductivity [mS/cm]", "temp": "temperature, degC IPTS-68",
                               "pres": "sea pressure in bar"}
    s = suggest_vehicle([p])
    cfg = s.config()
    f = cfg.sensors["ctd"].mcap.fields
    assert (f["conductivity_s_m"].units, f["temperature_its90_degc"].units, f["pressure_ctd_dbar"].units) == \
        ("mS/cm", "degC_its68", "bar")
    assert not any(m["assumed"] for m in s.mapped if m["sensor"] == "ctd")
    alt = cfg.sensors["altimeter"].mcap
    assert alt.topic == "/acme/altitude" and alt.fields["altitude_m"].field == "data"
    sensors, _ = read_mcap_sensors([p], cfg)
    assert sensors["ctd"].values["pressure_ctd_dbar"][:2].tolist() == pytest.approx([1000.0, 1010.0])
    assert sensors["ctd"].values["temperature_its90_degc"][0] == pytest.approx(2.0 / 1.00024)
    assert sensors["altimeter"].values["altitude_m"][0] == pytest.approx(20.0)


@pytest.mark.parametrize("fm,match", [
    ({"field": ["a", "b"], "units": "m"}, "needs a 'transform'"),
    ({"field": ["a", "b"], "units": "deg", "transform": "quaternion_to_heading_deg"}, "takes 4 fields"),
    ({"field": ["x", "y", "z", "w"], "units": "rad", "transform": "quaternion_to_heading_deg"}, "set units: deg"),
    ({"field": ["x", "y", "z", "w"], "units": "deg", "transform": "euler_magic"}, "unknown transform"),
    ({"field": "h", "units": "deg", "origin": [1.0, 2.0]}, "origin"),
])
def test_vehicle_mapping_transform_validation(tmp_path, fm, match):
    cfg = {"time_base": "att", "sensors": {"att": {"mcap": {"topic": "/a", "fields": {"heading_deg": fm}}}}}
    p = tmp_path / "v.yaml"
    p.write_text(yaml.safe_dump(cfg))
    with pytest.raises(Exception, match=match):
        load_vehicle_config(p)


def test_ros_time_is_mcap_only(tmp_path):
    cfg = {"time_base": "g", "sensors": {"g": {"csv": {"source": "g", "time": {"field": "t", "format": "ros_time"},
                                                       "fields": {"pressure_gauge_dbar": {"field": "p",
                                                                                          "units": "dbar"}}}}}}
    p = tmp_path / "v.yaml"
    p.write_text(yaml.safe_dump(cfg))
    with pytest.raises(Exception, match="MCAP sources only"):
        load_vehicle_config(p)


def test_unmapped_mcap_with_csv_sensors(shared_data, tmp_path):
    """A ROS talker bag (nothing to map) next to a sensor CSV: the CSV makes the sensors, MCAP is not used."""
    p = _write(tmp_path / "gauge.csv", "time,pressure_dbar,depth_m,battery_v\n" + "".join(
        f"2018-10-06T23:00:{i:02d}Z,{i:.1f},{i:.1f},24.0\n" for i in range(10)))
    s = suggest_vehicle([shared_data / "mcap-real" / "rosbag2_talker.mcap"], {"gauge": p})
    cfg = s.config()
    assert cfg.time_base == "gauge" and cfg.sensors["gauge"].required and cfg.sensors["gauge"].mcap is None
    assert s.mcap_used == [] and s.csv_used == {"gauge": str(p)}
    assert any("ingest.source: csv" in c for c in s.checks)
    why = {u.get("field"): u["reason"] for u in s.unmapped if u["source"] == "gauge"}
    assert "pressure" in why["depth_m"] and why["battery_v"] == "not recognised as a hadal variable"


def test_usbl_channel_named_by_its_key_gives_usbl_fixes(tmp_path):
    """A CSV key saying usbl with latitude/longitude and their variances (the sample generator's csv/usbl.csv
    layout): USBL fixes (usbl_*, valid at any depth), not GNSS fixes nor a dead-reckoned track."""
    rows = "".join(f"2018-10-07T00:{i:02d}:00.000Z,11.3{i:02d},142.2,100.00,100.00\n" for i in range(20))
    usbl = _write(tmp_path / "usbl.csv", "time,latitude_deg,longitude_deg,east_variance_m2,north_variance_m2\n" + rows)
    cfg = suggest_vehicle([], {"usbl": usbl}).config()
    fx = cfg.sensors[cfg.sensor_of("usbl_latitude_deg")].csv.fields
    assert (fx["usbl_latitude_deg"].field, fx["usbl_longitude_deg"].field) == ("latitude_deg", "longitude_deg")
    assert (fx["usbl_east_variance_m2"].field, fx["usbl_north_variance_m2"].field) == ("east_variance_m2",
                                                                                      "north_variance_m2")
    assert cfg.sensor_of("usbl_latitude_deg") == "usbl"
    assert not {"dr_east_m", "gnss_latitude_deg"} & set(cfg.variables())
