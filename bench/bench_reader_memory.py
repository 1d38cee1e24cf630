"""Peak memory of the text readers on big inputs, as a ratio to the decoded data (the file's bytes).

Each case runs in a fresh subprocess; its peak RSS (``resource.getrusage(RUSAGE_CHILDREN).ru_maxrss`` of that child)
minus the interpreter+imports baseline is divided by the input size. Cases: a normal big vehicle CSV log (hadal's
``read_sensor_csv`` vs ``pandas.read_csv`` on the same file), a CSV whose one line is ``--line-mb`` long (hadal
refuses it; pandas reads it), and a big .cnv (``read_cnv`` vs ``pandas.read_csv`` on its body; goal <= 2).

    python bench/bench_reader_memory.py [--mb 100] [--line-mb 300]
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


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--mb", type=float, default=100.0, help="size of the big CSV/.cnv files (MiB)")
    ap.add_argument("--line-mb", type=float, default=300.0, help="length of the one long CSV line (MiB)")
    a = ap.parse_args()
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
