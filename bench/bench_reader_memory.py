"""Peak memory of the text readers on big inputs, as a ratio to the decoded data (the file's bytes).

Each case runs in a fresh subprocess; its peak RSS (``resource.getrusage(RUSAGE_CHILDREN).ru_maxrss`` of that child)
minus the interpreter+imports baseline is divided by the input size. Cases: a normal big vehicle CSV log (hadal's
``read_sensor_csv`` vs ``pandas.read_csv`` on the same file), a CSV whose one line is ``--line-mb`` long (hadal
refuses it; pandas reads it), and a big .cnv (``read_cnv`` vs ``pandas.read_csv`` on its body; goal <= 2).

``--mcap``: the MCAP decode factor per message encoding (the numbers behind
:data:`hadal.ingest.mcap_reader.MCAP_KEPT_COPIES_BY_ENCODING`). An MCAP file of ``--messages`` messages on one topic
is written with the ``mcap``/``mcap-ros2-support`` writers (zstd chunks of 1 MiB) for each encoding: JSON
(``{"p": 1.5, "t": 10.25, "c": 3.5}``), ROS 2 CDR of a fixed-size type (``builtin_interfaces/Time`` stamp + three
float64: hadal's vectorised decoder) and ROS 2 CDR of ``sensor_msgs/msg/FluidPressure`` (a ``std_msgs/Header`` with
its string ``frame_id``: mcap-ros2-support's ``DecoderFactory``). Each is read in a fresh interpreter through
:func:`hadal.ingest.build.read_mcap_sensors` (what the ingest stage calls) and, as the peer, by the ``mcap`` library's
own reader keeping every decoded message (``json.loads`` / ``mcap_ros2.reader.read_ros2_messages``). Printed: peak
``VmHWM`` above the after-imports ``VmHWM``, its ratio to what the budget counts (payload + ``MCAP_MESSAGE_OVERHEAD``
per message: the decode factor) and to the peer's peak.

    python bench/bench_reader_memory.py --mcap [--messages 1000000]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

CHILD = textwrap.dedent("""
    import json, resource, sys, time, warnings
    warnings.simplefilter("ignore")
    import numpy as np, pandas as pd
    from hadal.errors import HadalError
    from hadal.ingest.cnv import read_cnv
    from hadal.ingest.csv_reader import read_sensor_csv
    from hadal.ingest.vehicle import CsvSource
    kind, path = sys.argv[1], sys.argv[2]
    base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    t0 = time.perf_counter()
    err = None
    try:
        if kind == "hadal_csv":
            m = CsvSource.model_validate({"source": "ctd", "time": {"field": "t", "format": "unix_s"},
                                          "fields": {"pressure_ctd_dbar": {"field": "p", "units": "dbar"},
                                                     "temperature_its90_degc": {"field": "temp", "units": "degC_its90"}}})
            read_sensor_csv(path, m, "ctd")
        elif kind == "pandas_csv":
            pd.read_csv(path)
        elif kind == "hadal_cnv":
            read_cnv(path)
        elif kind == "pandas_cnv":  # peer: the .cnv body through pandas' C parser (header lines skipped)
            with open(path, encoding="latin-1") as fh:
                n_head = next(i for i, ln in enumerate(fh) if ln.strip() == "*END*") + 1
            pd.read_csv(path, sep="\\\\s+", header=None, skiprows=n_head, encoding="latin-1")
    except HadalError as exc:
        err = str(exc)[:160]
    peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
    print(json.dumps({"base": base, "peak": peak, "s": time.perf_counter() - t0, "error": err}))
""")


def _write_csv(path: Path, mb: float) -> None:
    rng_rows = int(mb * 2**20 / 40)
    with open(path, "w") as fh:
        fh.write("t,p,temp\n")
        step = 200_000
        t0 = 1.7e9
        for a in range(0, rng_rows, step):
            n = min(step, rng_rows - a)
            i = range(a, a + n)
            fh.write("".join(f"{t0 + k * 0.1:.3f},{1000 + k * 1e-4:.4f},{2 + (k % 997) * 1e-3:.4f}\n" for k in i))


def _write_long_line(path: Path, mb: float) -> None:
    with open(path, "wb") as fh:
        fh.write(b"t,p,temp\n1700000000.0,1000.0,")
        chunk = b"1" * (1 << 20)
        for _ in range(int(mb)):
            fh.write(chunk)
        fh.write(b"\n")


def _write_cnv(path: Path, mb: float) -> None:
    rows = int(mb * 2**20 / 44)
    with open(path, "w", encoding="latin-1") as fh:
        fh.write(f"* Sea-Bird SBE 9 Data File:\n# nquan = 4\n# nvalues = {rows}\n")
        fh.write("# name 0 = prDM: Pressure, Digiquartz [db]\n# name 1 = t090C: Temperature [ITS-90, deg C]\n")
        fh.write("# name 2 = c0S/m: Conductivity [S/m]\n# name 3 = timeS: Time, Elapsed [seconds]\n")
        fh.write("# interval = seconds: 0.041667\n# bad_flag = -9.990e-29\n*END*\n")
        for a in range(0, rows, 100_000):
            fh.write("".join(f"{k * 0.01:11.3f}{2 + (k % 500) * 1e-3:11.4f}{3.2:11.6f}{k / 24:11.3f}\n"
                             for k in range(a, min(rows, a + 100_000))))


def _measure(kind: str, path: Path) -> dict:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(__file__).resolve().parents[1] / "src"),
                                                        os.environ.get("PYTHONPATH", "")])}
    r = subprocess.run([sys.executable, "-c", CHILD, kind, str(path)], capture_output=True, text=True, env=env)
    if r.returncode != 0:
        return {"kind": kind, "failed": r.stderr.strip().splitlines()[-1:] or [f"exit {r.returncode}"]}
    out = json.loads(r.stdout.strip().splitlines()[-1])
    size = path.stat().st_size
    out.update(kind=kind, file_mb=size / 2**20, extra_mb=(out["peak"] - out["base"]) / 2**20,
               ratio=(out["peak"] - out["base"]) / size)
    return out


MCAP_CHILD = textwrap.dedent("""
    import json, sys, time, warnings
    warnings.simplefilter("ignore")
    from hadal.ingest.build import read_mcap_sensors
    from hadal.ingest.vehicle import VehicleConfig
    import mcap.reader, mcap_ros2.reader
    def hwm():
        with open("/proc/self/status") as f:
            return next(int(l.split()[1]) * 1024 for l in f if l.startswith("VmHWM:"))
    kind, enc, path, field = sys.argv[1:5]
    base = hwm()
    t0 = time.perf_counter()
    if kind == "hadal":
        v = VehicleConfig.model_validate({"time_base": "ctd", "sensors": {"ctd": {"mcap": {"topic": "/ctd",
            "fields": {"pressure_ctd_dbar": {"field": field, "units": "dbar"}}}}}})
        n = len(read_mcap_sensors([path], v)[0]["ctd"])
    elif enc == "json":
        with open(path, "rb") as f:
            kept = [json.loads(m.data) for _s, _c, m in mcap.reader.make_reader(f).iter_messages()]
        n = len(kept)
    else:
        kept = [m.ros_msg for m in mcap_ros2.reader.read_ros2_messages(path)]
        n = len(kept)
    print(json.dumps({"n": n, "base": base, "peak": hwm(), "s": time.perf_counter() - t0}))
""")

_TIME = "MSG: builtin_interfaces/Time\nint32 sec\nuint32 nanosec\n"
MCAP_CASES = {  # encoding: (ROS 2 type, message definition, field read) - JSON: no definition
    "json": (None, None, "p"),
    "cdr_fixed": ("hadal_bench/msg/Ctd", "builtin_interfaces/Time stamp\nfloat64 pressure\nfloat64 temperature\n"
                  "float64 conductivity\n" + "=" * 80 + "\n" + _TIME, "pressure"),
    "cdr": ("sensor_msgs/msg/FluidPressure", "std_msgs/Header header\nfloat64 fluid_pressure\nfloat64 variance\n"
            + "=" * 80 + "\nMSG: std_msgs/Header\nbuiltin_interfaces/Time stamp\nstring frame_id\n" + "=" * 80
            + "\n" + _TIME, "fluid_pressure"),
}


def _write_mcap(path: Path, enc: str, n: int) -> int:
    """``n`` messages on topic ``/ctd``, one every 10 ms; returns their payload bytes."""
    dtype, msgdef, _ = MCAP_CASES[enc]
    payload = 0
    with open(path, "wb") as f:
        if enc == "json":
            from mcap.writer import Writer

            w = Writer(f)
            w.start("", "hadal-bench")
            sid = w.register_schema("ctd", "jsonschema", b'{"type":"object"}')
            cid = w.register_channel("/ctd", "json", sid)
            for k in range(n):
                d = json.dumps({"p": 1.5 + k * 1e-6, "t": 10.25, "c": 3.5}).encode()
                payload += len(d)
                w.add_message(cid, log_time=k * 10_000_000, data=d, publish_time=k * 10_000_000)
            w.finish()
            return payload
        from mcap_ros2.writer import Writer as RosWriter

        w = RosWriter(f)
        schema = w.register_msgdef(dtype, msgdef)
        for k in range(n):
            stamp = {"sec": k // 100, "nanosec": (k % 100) * 10_000_000}
            msg = ({"stamp": stamp, "pressure": 1.5 + k * 1e-6, "temperature": 10.25, "conductivity": 3.5}
                   if enc == "cdr_fixed" else
                   {"header": {"stamp": stamp, "frame_id": "ctd"}, "fluid_pressure": 1.5e4 + k, "variance": 0.0})
            w.write_message("/ctd", schema, msg, log_time=k * 10_000_000)
        w.finish()
    from mcap.reader import make_reader

    with open(path, "rb") as f:
        return sum(len(m.data) for _s, _c, m in make_reader(f).iter_messages())


def mcap_factors(messages: int, tmp: Path) -> None:
    from hadal.ingest.mcap_reader import MCAP_MESSAGE_OVERHEAD

    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(__file__).resolve().parents[1] / "src"),
                                                        os.environ.get("PYTHONPATH", "")])}
    print(f"{'encoding':10} {'messages':>10} {'payload B':>9} {'counted MiB':>11} {'hadal MiB':>9} {'factor':>7} "
          f"{'peer MiB':>8} {'hadal/peer':>10} {'hadal s':>7} {'peer s':>6}")
    for enc, (_t, _d, field) in MCAP_CASES.items():
        p = tmp / f"{enc}.mcap"
        payload = _write_mcap(p, enc, messages)
        counted = payload + MCAP_MESSAGE_OVERHEAD * messages
        got = {}
        for kind in ("hadal", "peer"):
            r = subprocess.run([sys.executable, "-c", MCAP_CHILD, kind, enc, str(p), field], capture_output=True,
                               text=True, env=env)
            got[kind] = (json.loads(r.stdout.strip().splitlines()[-1]) if r.returncode == 0 else
                         {"failed": (r.stderr.strip().splitlines() or ["?"])[-1]})
        h, q = got["hadal"], got["peer"]
        if "failed" in h or "failed" in q:
            print(f"{enc:10} failed: {h.get('failed') or q.get('failed')}")
            continue
        he, qe = h["peak"] - h["base"], q["peak"] - q["base"]
        print(f"{enc:10} {h['n']:10,} {payload / messages:9.1f} {counted / 2**20:11.1f} {he / 2**20:9.0f} "
              f"{he / counted:7.2f} {qe / 2**20:8.0f} {he / qe:10.2f} {h['s']:7.1f} {q['s']:6.1f}", flush=True)
        p.unlink()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mb", type=float, default=100.0, help="size of the big CSV/.cnv files (MiB)")
    ap.add_argument("--line-mb", type=float, default=300.0, help="length of the one long CSV line (MiB)")
    ap.add_argument("--mcap", action="store_true", help="the MCAP decode factor per message encoding instead")
    ap.add_argument("--messages", type=int, default=1_000_000, help="(--mcap) messages per MCAP file")
    a = ap.parse_args()
    if a.mcap:
        with tempfile.TemporaryDirectory(prefix="hadal-bench-mcap-") as tmp:
            mcap_factors(a.messages, Path(tmp))
        return
    with tempfile.TemporaryDirectory(prefix="hadal-bench-mem-") as tmp:
        d = Path(tmp)
        cases = [("big.csv", _write_csv, a.mb, ("hadal_csv", "pandas_csv")),
                 ("longline.csv", _write_long_line, a.line_mb, ("hadal_csv", "pandas_csv")),
                 ("big.cnv", _write_cnv, a.mb, ("hadal_cnv", "pandas_cnv"))]
        print(f"{'file':14} {'reader':11} {'MiB':>7} {'peak-base MiB':>14} {'ratio':>6} {'s':>6}  note")
        for name, make, mb, kinds in cases:
            p = d / name
            make(p, mb)
            for kind in kinds:
                r = _measure(kind, p)
                if "failed" in r:
                    print(f"{name:14} {kind:11} failed: {r['failed']}")
                    continue
                note = f"refused: {r['error']}" if r["error"] else ""
                print(f"{name:14} {kind:11} {r['file_mb']:7.1f} {r['extra_mb']:14.1f} {r['ratio']:6.2f} "
                      f"{r['s']:6.1f}  {note}")
            p.unlink()


if __name__ == "__main__":
    main()
