"""Benchmark: MCAP messages/s through hadal's reader vs a plain ``make_reader`` + ``json.loads`` loop.

Run: ``PYTHONPATH=src .venv/bin/python bench/bench_ingest.py [path/to/haidou.mcap]``

Default input: the sample dive's MCAP (``/tmp/hadal-sample-full``, else ``/tmp/hadal-sample-small``, else a
60 s tiny dive written with ``tests/malformed/tiny_dive.py``). Peer measured in the same run (the machine is
shared; only the ratio is meaningful): ``mcap.reader.make_reader(f).iter_messages()`` with ``json.loads`` on
every payload. hadal: :func:`hadal.ingest.read_mcap` (one sequential ``StreamReader`` pass that skips the
index records, decompresses and CRC-checks each chunk on its own so damaged files can be recovered, walks
the chunk with ``struct``, decodes each topic's JSON in one call, and accounts for lost messages). Both
decode every message of every topic. Variants run ``REPEATS`` times interleaved; the best time counts.
The full ``ingest`` table build (read + convert + align + QC + validate, no publish) is timed as well.
"""

from __future__ import annotations

import json
import sys
import tempfile
import time
import warnings
from pathlib import Path

REPEATS = 3
ROOT = Path(__file__).resolve().parents[1]


def _input() -> Path:
    if len(sys.argv) > 1:
        return Path(sys.argv[1])
    for d in ("/tmp/hadal-sample-full", "/tmp/hadal-sample-small"):
        p = Path(d) / "logs" / "haidou.mcap"
        if p.is_file():
            return p
    sys.path.insert(0, str(ROOT / "tests" / "malformed"))
    from tiny_dive import write_dive

    return write_dive(Path(tempfile.mkdtemp()) / "tiny", 60.0) / "logs" / "haidou.mcap"


def plain(path: Path) -> int:
    from mcap.reader import make_reader

    n = 0
    with open(path, "rb") as fh:
        for _schema, _channel, message in make_reader(fh).iter_messages(log_time_order=False):
            json.loads(message.data)
            n += 1
    return n


def hadal_reader(path: Path) -> int:
    from hadal.ingest import read_mcap

    data, report = read_mcap(path)
    assert report.messages_lost == 0, report
    return sum(len(t.messages) for t in data.values())


def table(path: Path) -> int:
    from hadal.ingest import build_sensor_table, load_vehicle_config, read_mcap_sensors

    raw = path.parent.parent
    vpath = raw / "vehicle.yaml"
    if not vpath.is_file():
        from hadal.ingest import default_vehicle_config_path

        vpath = default_vehicle_config_path()
    vehicle = load_vehicle_config(vpath)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        sensors, _ = read_mcap_sensors([path], vehicle)
        df, _ = build_sensor_table(sensors, vehicle, max_gap_s={"gauge": 2.0, "altimeter": 1.5, "attitude": 2.0,
                                                                "position": 5.0})
    return len(df)


def main() -> None:
    path = _input()
    print(f"input: {path} ({path.stat().st_size / 1e6:.1f} MB)")
    best = {"plain make_reader + json.loads": float("inf"), "hadal.ingest.read_mcap": float("inf")}
    counts = {}
    for _ in range(REPEATS):
        for name, fn in (("plain make_reader + json.loads", plain), ("hadal.ingest.read_mcap", hadal_reader)):
            t0 = time.perf_counter()
            counts[name] = fn(path)
            best[name] = min(best[name], time.perf_counter() - t0)
    a, b = counts.values()
    assert a == b, counts
    for name, t in best.items():
        print(f"{name:34s} {counts[name]:>9d} msgs  {t:7.3f} s  {counts[name] / t:>10.0f} msgs/s")
    ratio = best["plain make_reader + json.loads"] / best["hadal.ingest.read_mcap"]
    print(f"ratio hadal / plain (msgs/s): {ratio:.2f}x")
    t0 = time.perf_counter()
    rows = table(path)
    dt = time.perf_counter() - t0
    print(f"full sensor table (read+convert+align+QC+validate): {rows} rows, {dt:.2f} s, {counts[name] / dt:.0f} msgs/s")


if __name__ == "__main__":
    main()
