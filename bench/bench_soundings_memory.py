"""Peak memory of reading a large xyz.gz through the streaming multibeam reader vs plain pandas.read_csv.

Run on demand (not part of the tests)::

    .venv/bin/python bench/bench_soundings_memory.py [--points 10000000] [--keep FILE]

Writes ``points`` lon/lat/depth lines to a gzip file, then reads it in fresh subprocesses (so each peak is its
own) and prints, from ``resource.getrusage(RUSAGE_SELF).ru_maxrss``: the RSS after imports (baseline), the
peak, and (peak - baseline) / decoded size, the decoded size being ``points * 3 * 8`` bytes (float64). Paths:

* ``read_multibeam``  - :func:`hadal.grid.sonar.read_multibeam` (chunked pandas C parser, columns joined);
* ``iter_multibeam``  - only iterating the chunks (what a consumer that reduces per chunk pays);
* ``pandas.read_csv`` - one ``pd.read_csv(path, sep=r"\\s+", header=None)`` of the whole file.
"""

from __future__ import annotations

import argparse
import gzip
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

CHILD = r"""
import json, resource, sys, time
import numpy as np, pandas as pd
from hadal.grid.sonar import iter_multibeam, read_multibeam
mode, path = sys.argv[1], sys.argv[2]
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
t = time.perf_counter()
if mode == "read_multibeam":
    n = len(read_multibeam(path))
elif mode == "iter_multibeam":
    n = sum(len(c) for c in iter_multibeam(path))
else:
    n = len(pd.read_csv(path, sep=r"\s+", header=None))
dt = time.perf_counter() - t
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
print(json.dumps({"mode": mode, "n": n, "baseline": base, "peak": peak, "seconds": dt}))
"""


def write_xyz_gz(path: Path, n: int, seed: int = 0, chunk: int = 1_000_000) -> None:
    rng = np.random.default_rng(seed)
    with gzip.open(path, "wb", compresslevel=1) as fh:
        for s in range(0, n, chunk):
            m = min(chunk, n - s)
            a = np.column_stack([142.2 + rng.uniform(0, 0.5, m), 11.3 + rng.uniform(0, 0.5, m),
                                 8000 + rng.uniform(-500, 500, m)])
            np.savetxt(fh, a, fmt="%.7f %.7f %.2f")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=10_000_000)
    ap.add_argument("--keep", type=Path, default=None, help="write (or reuse) the xyz.gz here")
    ap.add_argument("--modes", default="read_multibeam,iter_multibeam,pandas.read_csv")
    a = ap.parse_args(argv)
    with tempfile.TemporaryDirectory() as td:
        path = a.keep or Path(td) / "soundings.xyz.gz"
        if not path.exists():
            t = time.perf_counter()
            write_xyz_gz(path, a.points)
            print(f"wrote {a.points:,} points to {path} ({path.stat().st_size / 2**20:.0f} MiB) in "
                  f"{time.perf_counter() - t:.0f} s")
        decoded = a.points * 3 * 8
        print(f"decoded float64 points: {decoded / 2**20:.0f} MiB")
        for mode in a.modes.split(","):
            r = subprocess.run([sys.executable, "-c", CHILD, mode, str(path)], capture_output=True, text=True)
            if r.returncode:
                print(f"{mode}: failed\n{r.stderr[-2000:]}")
                continue
            d = json.loads(r.stdout.strip().splitlines()[-1])
            extra = d["peak"] - d["baseline"]
            print(f"{mode:16s} n={d['n']:,}  baseline {d['baseline'] / 2**20:6.0f} MiB  peak {d['peak'] / 2**20:6.0f} "
                  f"MiB  (peak-baseline)/decoded {extra / decoded:5.2f}x  peak/decoded {d['peak'] / decoded:5.2f}x  "
                  f"{d['seconds']:.1f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
