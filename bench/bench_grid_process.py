"""Benchmark (issue 48): gridding a point file as a whole process, hadal against GMT, in one run.

The same survey-order soundings (the synthetic cruise of ``bench_grid_tiles.py``, ``--points`` of them, 20 m cells,
~40 a cell) as one binary file of float64 x, y, z triplets, gridded by:

* **hadal**: a fresh ``python`` process that imports hadal, reads the file (``np.fromfile``) and grids it
  (:func:`hadal.grid.points.grid_points`, mean/median/count/std on explicit bounds), the layers saved (``np.save``);
* **GMT**: ``gmt blockmean -E`` (mean, std, count: ``-Sn`` and ``-E`` are two runs' worth of output, so the mean
  and std run) plus ``gmt blockmedian`` on the same file and region: the two processes' CPU added, the larger
  peak RSS;
* with ``--moments``: count/mean/std alone, hadal's ``grid_points`` (statistics count/mean/std) against
  ``gmt blockmean -E``.

Each process is timed by ``/usr/bin/time`` (user + system CPU, maximum RSS); variants alternate A B B A so a
drifting machine load hits both alike; the medians of the CPU and the largest peak RSS are printed, with the
ratio. The medians of hadal and GMT are compared on the cells both give (GMT's ``blockmedian`` output is the
cell's median at the cell centre, ``-C``).

    PYTHONPATH=src .venv/bin/python bench/bench_grid_process.py [--points 1000000] [--repeats 2]

Goal (issue 48): gridding 1e6 points as a whole process costs no more CPU than GMT blockmean + blockmedian.
"""

from __future__ import annotations

import argparse
import json
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).parent))

import bench_grid_tiles as T  # noqa: E402  # the synthetic cruise's generator

HADAL = """
import sys, numpy as np
from hadal.grid.points import grid_points
f, side, res, stats, out = sys.argv[1], float(sys.argv[2]), float(sys.argv[3]), sys.argv[4].split(","), sys.argv[5]
a = np.fromfile(f).reshape(-1, 3)
ds = grid_points(a[:, 0], a[:, 1], a[:, 2], res, bounds=(0.0, 0.0, side, side), statistics=stats)
np.savez(out, xc=ds["x"].values, yc=ds["y"].values, **{s: ds[s].values for s in stats})
"""


def timed(cmd: list[str], **kw) -> dict:
    p = subprocess.run(["/usr/bin/time", "-f", "%M %U %S", *cmd], capture_output=True, **kw)
    if p.returncode:
        raise SystemExit(f"{cmd[0]} failed: {p.stderr.decode()[-2000:]}")
    kb, u, s = p.stderr.decode().strip().splitlines()[-1].split()
    return {"peak_rss": int(kb) * 1024, "cpu_s": float(u) + float(s), "stdout": p.stdout}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=1_000_000)
    ap.add_argument("--repeats", type=int, default=2, help="A B B A rounds")
    ap.add_argument("--moments", action="store_true", help="also count/mean/std alone against gmt blockmean")
    a = ap.parse_args(argv)
    gmt = shutil.which("gmt")
    if gmt is None:
        raise SystemExit("gmt is not on PATH (apt-get install gmt): nothing to compare with")
    lay = T.layout(a.points, 20.0, 40.0)
    side, res = lay["side_m"], lay["resolution_m"]
    region = [f"-R0/{side:g}/0/{side:g}", f"-I{res:g}", "-r"]
    with tempfile.TemporaryDirectory(prefix="hadal-bench-proc-") as td:
        d = Path(td)
        T.generate(d, lay, 1 << 21)
        x, y, z = (np.fromfile(d / f"{k}.f8") for k in "xyz")
        ok = np.isfinite(x)
        f = d / "xyz.bin"
        np.column_stack([x[ok], y[ok], z[ok]]).tofile(f)  # GMT's binary input has no NaN rows to skip
        py = [sys.executable, "-c", HADAL, str(f), f"{side!r}", f"{res!r}"]
        bm = [gmt, "blockmean", str(f), "-bi3d", "-bo5d", "-E", *region]
        bmed = [gmt, "blockmedian", str(f), "-bi3d", "-bo3d", "-C", *region]
        variants = {
            "hadal mean/median/count/std": lambda: [timed([*py, "mean,median,count,std", str(d / "h.npz")])],
            "gmt blockmean -E + blockmedian": lambda: [timed(bm), timed(bmed)],
        }
        if a.moments:
            variants["hadal count/mean/std"] = lambda: [timed([*py, "count,mean,std", str(d / "m.npz")])]
            variants["gmt blockmean -E"] = lambda: [timed(bm)]
        timed([*py, "count", str(d / "w.npz")])  # warm-up: numba's cache and the page cache
        rows: dict[str, list[dict]] = {k: [] for k in variants}
        names = list(variants)
        pairs = [names[i:i + 2] for i in range(0, len(names), 2)]
        for _ in range(a.repeats):
            for pa in pairs:
                for v in (pa[0], pa[1], pa[1], pa[0]):
                    rs = variants[v]()
                    rows[v].append({"cpu_s": sum(r["cpu_s"] for r in rs),
                                    "peak_rss": max(r["peak_rss"] for r in rs)})
        med = timed(bmed)["stdout"]
        g = np.frombuffer(med, np.float64).reshape(-1, 3)
        h = np.load(d / "h.npz")
        # blockmedian -C reports the median at the cell centre (-r: pixel registration): hadal's cell of that centre
        xc, yc = h["xc"], h["yc"]
        col = np.rint((g[:, 0] - xc[0]) / (xc[1] - xc[0])).astype(np.int64)
        row = np.rint((g[:, 1] - yc[0]) / (yc[1] - yc[0])).astype(np.int64)
        diff = np.abs(h["median"][row, col] - g[:, 2]) > 1e-9
        edge = (row == 0) | (row == len(yc) - 1) | (col == 0) | (col == len(xc) - 1)
        same = f"{int(diff.sum())} of {len(g)} cells differ, {int((diff & ~edge).sum())} of them inside the edge"
    print(f"{a.points:,} survey-order soundings, {lay['side_m'] / 1000:g} km square, {res:g} m cells; a whole "
          f"process each, A B B A x {a.repeats}")
    c = {v: float(np.median([r["cpu_s"] for r in rs])) for v, rs in rows.items()}
    m = {v: max(r["peak_rss"] for r in rs) for v, rs in rows.items()}
    runs = {v: ", ".join(f"{r['cpu_s']:.2f}" for r in rs) for v, rs in rows.items()}
    print("\n".join(f"  {v:32s} CPU {c[v]:6.2f} s (runs {runs[v]}), peak RSS {m[v] / 2**20:6.0f} MiB" for v in rows))
    r = c["hadal mean/median/count/std"] / c["gmt blockmean -E + blockmedian"]
    print(f"  hadal / GMT: CPU {r:.2f}x (goal <= 1: {'MET' if r <= 1 else 'NOT met'}), peak RSS "
          f"{m['hadal mean/median/count/std'] / m['gmt blockmean -E + blockmedian']:.2f}x")
    if a.moments:
        print(f"  count/mean/std: hadal / gmt blockmean CPU {c['hadal count/mean/std'] / c['gmt blockmean -E']:.2f}x,"
              f" peak RSS {m['hadal count/mean/std'] / m['gmt blockmean -E']:.2f}x")
    print(f"  medians, hadal vs gmt blockmedian -C on all of GMT's cells: {same} (points exactly on the region's "
          "edge: GMT and hadal bin them differently)")
    print(json.dumps({"cpu_s": c, "peak_rss": m}))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
