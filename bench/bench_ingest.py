"""Benchmark: MCAP messages/s through hadal's reader vs a plain ``make_reader`` + ``json.loads`` loop.

Run: ``PYTHONPATH=src .venv/bin/python bench/bench_ingest.py [path/to/haidou.mcap]``

Default input: the sample dive's MCAP (``/tmp/hadal-sample-full``, else ``/tmp/hadal-sample-small``, else a
60 s tiny dive written with ``tests/malformed/tiny_dive.py``). Peer measured in the same run (the machine is
shared; only the ratio is meaningful): ``mcap.reader.make_reader(f).iter_messages()`` with ``json.loads`` on
every payload. hadal: :func:`hadal.ingest.read_mcap` (one sequential ``StreamReader`` pass that skips the
index records, decompresses and CRC-checks each chunk on its own so damaged files can be recovered, walks
the chunk with a compiled kernel, gathers each channel's payloads of a chunk into one JSON array decoded
by msgspec in one call, and accounts for lost messages). Both
decode every message of every topic. Variants run ``REPEATS`` times interleaved; the best time counts.
The full ``ingest`` table build (read + convert + align + QC + validate, no publish) is timed as well.

"before": the committed ``src/hadal/ingest/mcap_reader.py`` (``git show HEAD:...``, loaded as a separate
module) in the same run, so that the speed-up of uncommitted work is measured against the same load; it
is left out when git or the committed file is missing. Wall and CPU time are printed (the machine may be
shared: compare the ratios). Goal (issue 19): >= 3x the pre-issue-19 reader (131 k msgs/s on the
sample dive, 4.3x the plain loop).
"""

from __future__ import annotations

import importlib.util
import json
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path

REPEATS = 2
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


def hadal_reader(path: Path, module=None) -> int:
    if module is None:
        from hadal.ingest import read_mcap
    else:
        read_mcap = module.read_mcap
    data, report = read_mcap(path)
    assert report.messages_lost == 0, report
    return sum(len(t.messages) for t in data.values())


def committed_reader():
    """The committed mcap_reader.py as a module of its own, or None."""
    try:
        src = subprocess.run(["git", "show", "HEAD:src/hadal/ingest/mcap_reader.py"], cwd=ROOT, check=True,
                             capture_output=True).stdout
    except (OSError, subprocess.CalledProcessError):
        return None
    f = Path(tempfile.mkdtemp()) / "mcap_reader_committed.py"
    f.write_bytes(src)
    spec = importlib.util.spec_from_file_location("mcap_reader_committed", f)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod
    spec.loader.exec_module(mod)
    return mod


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
    print(f"input: {path} ({path.stat().st_size / 1e6:.1f} MB), best of {REPEATS}")
    before = committed_reader()
    variants = {"plain make_reader + json.loads": plain, "hadal.ingest.read_mcap": hadal_reader}
    if before is not None:
        variants["hadal read_mcap, committed (before)"] = lambda p: hadal_reader(p, before)
    hadal_reader(path)  # warm-up: numba start-up, page cache
    best = {name: (float("inf"), float("inf")) for name in variants}
    counts = {}
    for _ in range(REPEATS):
        for name, fn in variants.items():
            c0, t0 = time.process_time(), time.perf_counter()
            counts[name] = fn(path)
            best[name] = min(best[name], (time.perf_counter() - t0, time.process_time() - c0))
    assert len(set(counts.values())) == 1, counts
    for name, (t, c) in best.items():
        print(f"{name:36s} {counts[name]:>9d} msgs  {t:7.3f} s wall {c:7.3f} s CPU  {counts[name] / t:>10.0f} msgs/s")
    now = best["hadal.ingest.read_mcap"]
    for name, (t, c) in best.items():
        if name != "hadal.ingest.read_mcap":
            print(f"ratio hadal / {name}: {t / now[0]:.2f}x (wall), {c / now[1]:.2f}x (CPU)")
    if before is not None:
        r = best["hadal read_mcap, committed (before)"][0] / now[0]
        print(f"goal >= 3x the reader before issue 19: {'MET' if r >= 3 else 'NOT met'} ({r:.2f}x wall)")
    t0 = time.perf_counter()
    rows = table(path)
    dt = time.perf_counter() - t0
    n = counts["hadal.ingest.read_mcap"]
    print(f"full sensor table (read+convert+align+QC+validate): {rows} rows, {dt:.2f} s, {n / dt:.0f} msgs/s")


if __name__ == "__main__":
    main()
