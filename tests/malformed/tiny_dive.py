"""Write a tiny raw dive directory following docs/architecture.md (MCAP channels + CSV variants).

Independent of hadal's readers (it writes with ``mcap.writer.Writer`` and plain ``csv``), so tests of the
readers compare against values chosen here. Used by tests/test_ingest_*.py and make_corpus.py.
"""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import yaml

REPO = Path(__file__).resolve().parents[2]
T0 = 1538866800.0  # 2018-10-06T23:00:00Z
TOPICS = {  # topic -> (rate Hz, schema file)
    "/haidou/ctd": (16.0, "haidou_ctd.json"),
    "/haidou/keller": (4.0, "haidou_keller.json"),
    "/haidou/altimeter": (2.0, "haidou_altimeter.json"),
    "/haidou/attitude": (10.0, "haidou_attitude.json"),
    "/haidou/dr": (1.0, "haidou_dr.json"),
}


def truth(t: np.ndarray) -> dict[str, np.ndarray]:
    """Smooth 'true' signals (canonical units) at Unix times ``t`` (s)."""
    s = t - T0
    ph = np.mod(s, 200.0)
    tri = np.where(ph < 100.0, ph, 200.0 - ph)  # piecewise-linear 0..100..0 with period 200 s
    p = 10_400.0 + 2.0 * tri  # crosses the SBE49 saturation (10 500 dbar) at s = 50
    return {
        "cond": 3.25 + 1e-4 * s, "temp": 2.5 - 1e-3 * s, "pres": np.minimum(p, 10_500.0), "pressure": p + 1.5,
        "range": 80.0 - 0.5 * tri, "heading": np.mod(350.0 + 0.5 * s, 360.0), "pitch": 2.0 * np.sin(s / 10),
        "roll": 1.0 * np.cos(s / 10), "east": 0.5 * s, "north": -0.25 * s, "speed": np.full_like(s, 0.56),
    }


def messages(duration_s: float = 60.0) -> dict[str, list[tuple[int, dict]]]:
    out: dict[str, list[tuple[int, dict]]] = {}
    for topic, (rate, _) in TOPICS.items():
        t_ns = int(T0) * 10**9 + np.arange(int(duration_s * rate), dtype=np.int64) * int(round(1e9 / rate))
        t = t_ns / 1e9
        tr = truth(t)
        msgs = []
        for i, ti in enumerate(t):
            stamp = float(ti)
            if topic.endswith("ctd"):
                m = {"stamp": stamp, "cond": tr["cond"][i], "temp": tr["temp"][i], "pres": tr["pres"][i]}
            elif topic.endswith("keller"):
                m = {"stamp": stamp, "pressure": tr["pressure"][i]}
            elif topic.endswith("altimeter"):
                drop = i % 7 == 3
                m = {"stamp": stamp, "range": None if drop else float(np.round(tr["range"][i] / 0.3) * 0.3),
                     "valid": not drop}
            elif topic.endswith("attitude"):
                m = {"stamp": stamp, "heading": tr["heading"][i], "pitch": tr["pitch"][i], "roll": tr["roll"][i]}
            else:
                m = {"stamp": stamp, "east": tr["east"][i], "north": tr["north"][i], "speed": tr["speed"][i]}
            msgs.append((int(t_ns[i]), {k: (float(v) if isinstance(v, np.floating) else v) for k, v in m.items()}))
        out[topic] = msgs
    return out


def write_mcap(path: Path, msgs: dict[str, list[tuple[int, dict]]], chunk_size: int = 4096, sort: bool = True) -> None:
    """Write ``msgs`` as JSON channels; ``sort=False`` keeps each topic's given order (topics one after another)."""
    from mcap.writer import CompressionType, Writer

    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "wb") as fh:
        w = Writer(fh, chunk_size=chunk_size, compression=CompressionType.ZSTD)
        w.start(profile="", library="hadal-tests")
        chans = {}
        for topic, (_, sfile) in TOPICS.items():
            if topic not in msgs:
                continue
            sdata = (REPO / "schemas" / "mcap" / sfile).read_bytes()
            sid = w.register_schema(name=topic.rsplit("/", 1)[-1], encoding="jsonschema", data=sdata)
            chans[topic] = w.register_channel(topic=topic, message_encoding="json", schema_id=sid)
        merged = [(t, topic, m) for topic, lst in msgs.items() for t, m in lst]
        if sort:
            merged.sort(key=lambda x: (x[0], x[1]))
        for seq, (t, topic, m) in enumerate(merged):
            w.add_message(channel_id=chans[topic], log_time=t, publish_time=t, sequence=seq,
                          data=json.dumps(m).encode())
        w.finish()


def _iso(t_ns: int) -> str:
    return np.datetime_as_string(np.datetime64(t_ns, "ns"), unit="us") + "Z"


def write_csvs(csv_dir: Path, msgs: dict[str, list[tuple[int, dict]]]) -> dict[str, str]:
    csv_dir.mkdir(parents=True, exist_ok=True)
    spec = {
        "ctd": ("/haidou/ctd", "ctd.csv", ["conductivity_mS_cm", "temperature_ITS90", "pressure_dbar"],
                lambda m: [m["cond"] * 10.0, m["temp"], m["pres"]]),
        "gauge": ("/haidou/keller", "keller.csv", ["pressure_bar"], lambda m: [m["pressure"] / 10.0]),
        "altimeter": ("/haidou/altimeter", "altimeter.csv", ["altitude_m"],
                      lambda m: ["" if m["range"] is None else m["range"]]),
        "attitude": ("/haidou/attitude", "attitude.csv", ["heading_deg", "pitch_deg", "roll_deg"],
                     lambda m: [m["heading"], m["pitch"], m["roll"]]),
        "dr": ("/haidou/dr", "dr.csv", ["east_m", "north_m", "speed_m_s"], lambda m: [m["east"], m["north"], m["speed"]]),
    }
    out = {}
    for key, (topic, fname, cols, fn) in spec.items():
        lines = [",".join(["time"] + cols)]
        for t, m in msgs[topic]:
            lines.append(",".join([_iso(t)] + [v if isinstance(v, str) else repr(float(v)) for v in fn(m)]))
        (csv_dir / fname).write_text("\n".join(lines) + "\n")
        out[key] = f"csv/{fname}"
    return out


def write_dive(dest: Path, duration_s: float = 60.0, *, mcap: bool = True, csv: bool = True,
               dive_id: str = "tiny-dive") -> Path:
    """A raw dive directory: dive.yaml, vehicle.yaml (packaged haidou mapping), logs/haidou.mcap, csv/*.csv."""
    dest = Path(dest)
    dest.mkdir(parents=True, exist_ok=True)
    msgs = messages(duration_s)
    sources: dict = {"mcap": [], "csv": {}}
    if mcap:
        write_mcap(dest / "logs" / "haidou.mcap", msgs)
        sources["mcap"] = ["logs/haidou.mcap"]
    if csv:
        sources["csv"] = write_csvs(dest / "csv", msgs)
    shutil.copy(REPO / "src" / "hadal" / "data" / "vehicles" / "haidou.yaml", dest / "vehicle.yaml")
    dive = {"dive_id": dive_id, "platform": "Haidou", "vehicle_config": "vehicle.yaml",
            "launch": {"time_utc": "2018-10-06T23:00:00Z", "latitude_deg": 11.3371167, "longitude_deg": 142.2097167},
            "sources": sources}
    (dest / "dive.yaml").write_text(yaml.safe_dump(dive, sort_keys=False))
    return dest
