"""Benchmark (issue 48): out-of-core gridding of a synthetic cruise generated on disk in chunks.

Steps, each measured in its own fresh child process (so each peak RSS, ``VmHWM`` of ``/proc/self/status``, is its
own; CPU is the child's user+system time over all its threads):

1. **generate** (once; reused with ``--data DIR``): ``--points`` soundings of a lawnmower survey (lines along x,
   swaths overlapping the neighbouring lines, soundings in ping order along each line, a smooth seafloor of
   5.5-6.5 km plus 0.5 m noise, one sounding in 10 000 NaN) written in chunks as three raw float64 files
   ``x.f8 y.f8 z.f8``; about ``--points-per-cell`` soundings a ``--resolution`` cell;
2. **tiled**: :func:`hadal.grid.tiles.grid_tiled` of all the soundings, read back in chunks of ``--chunk`` points
   (mean, median, count, std: the DTM's statistics): soundings per CPU-second, peak RSS, and the CPU ratio to a
   streaming ``np.bincount`` count/mean/std of the same soundings in the same run; **tiled_moments**: the
   same for count/mean/std alone;
3. **equal**: the first ``--subset`` soundings gridded in memory (:func:`hadal.grid.points.grid_points`, same grid)
   and tiled: every layer compared bit for bit (count/mean/std alone: count bit for bit, mean/std to rounding);
4. **moments memory** (``--moments-points``, default 3e7): count/mean/std tiled against a streaming NumPy
   ``bincount`` reference (chunks of the same size; what GMT blockmean does: per-cell sums, points streamed;
   GMT itself is used when ``gmt`` is on PATH) and against the in-memory ``grid_points``: peak RSS and CPU.

Run (defaults: 1e8 soundings, ~3 GB of input and 1.2 GB of tiles on disk, a few minutes)::

    PYTHONPATH=src .venv/bin/python bench/bench_grid_tiles.py [--points 100000000] [--data DIR]

The issue's acceptance run (1e9 soundings: 24 GB of input plus 12 GB of tiles on disk)::

    PYTHONPATH=src .venv/bin/python bench/bench_grid_tiles.py --points 1000000000 --data /big/disk/cruise

Goals (issue 48): 1e9 soundings at peak RSS <= 4 GB, equal to the in-memory grid on a 1e7 subset, >= 25 M
soundings per CPU-second; count/mean/std memory within 2x GMT blockmean's at 3e7 points. The machine may be shared:
CPU time, not wall time, is the rate's measure.
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

DEFAULT_STATS = ("mean", "median", "count", "std")
MOMENTS = ("count", "mean", "std")
SWATH_OVER_SPACING = 1.5  # swath width / line spacing: neighbouring swaths overlap by half a line spacing


def layout(points: int, resolution: float, points_per_cell: float) -> dict:
    """The synthetic cruise's geometry: a square survey of about ``points / points_per_cell`` cells."""
    cells = max(1.0, points / points_per_cell)
    side = max(8, int(np.sqrt(cells))) * resolution
    spacing = 2000.0 if side > 20000 else side / 10
    n_lines = max(2, int(round(side / spacing)))
    return {"points": points, "side_m": side, "spacing_m": spacing, "n_lines": n_lines, "resolution_m": resolution}


def generate(d: Path, lay: dict, chunk: int, seed: int = 48) -> None:
    """Write the cruise's soundings in chunks (module doc, step 1)."""
    rng = np.random.default_rng(seed)
    n, side, sp, nl = lay["points"], lay["side_m"], lay["spacing_m"], lay["n_lines"]
    per_line = -(-n // nl)
    half = 0.5 * SWATH_OVER_SPACING * sp
    fh = {k: open(d / f"{k}.f8", "wb") for k in "xyz"}
    try:
        for a in range(0, n, chunk):
            i = np.arange(a, min(n, a + chunk))
            line = i // per_line
            s = ((i % per_line) + rng.uniform(0, 1, len(i))) * (side / per_line)
            x = np.where(line % 2 == 0, s, side - s)  # lawnmower: every other line backwards
            x = np.clip(x, 0.0, side)
            y = np.clip((line + 0.5) * sp + rng.uniform(-half, half, len(i)), 0.0, side)
            z = 6000.0 + 500.0 * np.sin(x / 7000.0) * np.cos(y / 9000.0) + 0.02 * (x - y) + rng.normal(0, 0.5, len(i))
            x[(i % 10_000) == 17] = np.nan
            for k, v in zip("xyz", (x, y, z), strict=True):
                v.tofile(fh[k])
    finally:
        for f in fh.values():
            f.close()


def read_chunks(d: Path, n: int, chunk: int):
    """``(x, y, z)`` chunks of the first ``n`` soundings read from the raw files."""
    for a in range(0, n, chunk):
        m = min(chunk, n - a)
        yield tuple(np.fromfile(d / f"{k}.f8", dtype=np.float64, count=m, offset=8 * a) for k in "xyz")


def vm_hwm_bytes() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    return -1


def child(args) -> None:
    """One measured step in this (fresh) process; prints one JSON line."""
    from hadal.grid.points import grid_points, make_grid_spec
    from hadal.grid.tiles import grid_tiled

    d = Path(args.data)
    lay = json.loads((d / "layout.json").read_text())
    spec = make_grid_spec(lay["resolution_m"], (0.0, 0.0, lay["side_m"], lay["side_m"]),
                          max_cells=2_000_000_000)
    n = min(args.n, lay["points"])
    stats = MOMENTS if args.step.startswith("moments") else DEFAULT_STATS
    scratch = args.scratch or str(d)
    out: dict = {"step": args.step, "n": n, "cells": spec.n_cells}
    if args.step == "warmup":  # numba's compiled kernels loaded/compiled once, outside the measured steps
        m = 100_000
        grid_tiled(read_chunks(d, m, m), spec, DEFAULT_STATS, scratch_dir=scratch)
        grid_tiled(read_chunks(d, m, m), spec, MOMENTS, scratch_dir=scratch)
        grid_points(*next(read_chunks(d, m, m)), lay["resolution_m"], bounds=spec.bounds, statistics=DEFAULT_STATS)
        print(json.dumps(out))
        return
    if args.step in ("tiled", "moments_tiled"):  # numba's start-up (loading the cached kernels) not timed
        grid_tiled(read_chunks(d, 50_000, 50_000), spec, stats, scratch_dir=scratch)
    base = vm_hwm_bytes()
    c0, t0 = time.process_time(), time.perf_counter()
    if args.step in ("tiled", "moments_tiled"):
        ds = grid_tiled(read_chunks(d, n, args.chunk), spec, stats, scratch_dir=scratch, expected_points=n,
                        tile_cells=args.tile_cells)
        out.update(tile_cells=ds.attrs["tile_cells"], n_tiles=ds.attrs["n_tiles"],
                   used=ds.attrs["n_points_used"], nonfinite=ds.attrs["n_points_nonfinite"])
    elif args.step == "moments_bincount":  # streaming per-cell sums, the blockmean way
        m = spec.n_cells
        cnt, s1, s2 = np.zeros(m), np.zeros(m), np.zeros(m)
        for x, y, z in read_chunks(d, n, args.chunk):
            ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(z)
            idx, _ = spec.cell_index(x[ok], y[ok], check_inside=False)
            zz = z[ok] - 6000.0
            cnt += np.bincount(idx, minlength=m)
            s1 += np.bincount(idx, zz, minlength=m)
            s2 += np.bincount(idx, zz * zz, minlength=m)
        out["used"] = int(cnt.sum())
    elif args.step in ("moments_inmemory", "inmemory"):
        x, y, z = (np.fromfile(d / f"{k}.f8", dtype=np.float64, count=n) for k in "xyz")
        ds = grid_points(x, y, z, lay["resolution_m"], bounds=spec.bounds, statistics=stats)
        out["used"] = ds.attrs["n_points_used"]
    elif args.step == "equal":
        x, y, z = (np.fromfile(d / f"{k}.f8", dtype=np.float64, count=n) for k in "xyz")
        for st in (DEFAULT_STATS, MOMENTS):
            a = grid_points(x, y, z, lay["resolution_m"], bounds=spec.bounds, statistics=st)
            b = grid_tiled(read_chunks(d, n, args.chunk), spec, st, scratch_dir=scratch, tile_cells=args.tile_cells,
                           expected_points=n)
            res = {}
            for s in st:
                u, v = a[s].values, b[s].values
                same = bool(np.array_equal(u, v, equal_nan=True))
                diff = 0.0 if same else float(np.nanmax(np.abs(u - v) / np.maximum(np.abs(u), 1e-300)))
                res[s] = "identical" if same else f"max relative difference {diff:.1e}"
            out["/".join(st)] = res
            out["tiles"] = b.attrs["n_tiles"]
    else:
        raise SystemExit(f"unknown step {args.step}")
    out.update(cpu_s=time.process_time() - c0, wall_s=time.perf_counter() - t0, peak_rss=vm_hwm_bytes(),
               rss_after_imports=base)
    print(json.dumps(out))


def run_child(script: str, step: str, data: Path, n: int, a) -> dict:
    cmd = [sys.executable, script, "--child", step, "--data", str(data), "--n", str(n), "--chunk", str(a.chunk)]
    if a.tile_cells:
        cmd += ["--tile-cells", str(a.tile_cells)]
    if a.scratch:
        cmd += ["--scratch", a.scratch]
    r = subprocess.run(cmd, capture_output=True, text=True)
    if r.returncode:
        raise SystemExit(f"step {step} failed:\n{r.stderr[-3000:]}")
    return json.loads(r.stdout.strip().splitlines()[-1])


def gmt_blockmean(data: Path, n: int, lay: dict) -> dict | None:
    """GMT blockmean's peak RSS and CPU on the first ``n`` soundings (binary x, y, z), when gmt is installed."""
    if not shutil.which("gmt"):
        return None
    f = data / "xyz_interleaved.bin"
    with open(f, "wb") as fh:
        for x, y, z in read_chunks(data, n, 1 << 22):
            np.column_stack([x, y, z]).tofile(fh)
    side, r = lay["side_m"], lay["resolution_m"]
    cmd = ["/usr/bin/time", "-f", "%M %U %S", "gmt", "blockmean", str(f), "-bi3d", "-bo3d", "-Sn",
           f"-R0/{side:g}/0/{side:g}", f"-I{r:g}", "-r"]
    p = subprocess.run(cmd, capture_output=True)
    f.unlink()
    kb, u, s = p.stderr.decode().strip().splitlines()[-1].split()
    return {"peak_rss": int(kb) * 1024, "cpu_s": float(u) + float(s)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=100_000_000)
    ap.add_argument("--resolution", type=float, default=20.0)
    ap.add_argument("--points-per-cell", type=float, default=40.0)
    ap.add_argument("--chunk", type=int, default=1 << 21, help="points read per chunk")
    ap.add_argument("--subset", type=int, default=10_000_000, help="soundings of the equality check")
    ap.add_argument("--moments-points", type=int, default=30_000_000)
    ap.add_argument("--tile-cells", type=int, default=None)
    ap.add_argument("--data", default=None, help="directory of the generated cruise (kept; reused when present)")
    ap.add_argument("--scratch", default=None, help="scratch directory of the tiles (default: the data directory)")
    ap.add_argument("--steps", default="tiled,tiled_moments,equal,moments")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--n", type=int, default=0, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        a.step = a.child
        child(a)
        return 0
    tmp = None
    if a.data is None:
        tmp = tempfile.mkdtemp(prefix="hadal-cruise-")
        a.data = tmp
    d = Path(a.data)
    d.mkdir(parents=True, exist_ok=True)
    try:
        lay = layout(a.points, a.resolution, a.points_per_cell)
        lj = d / "layout.json"
        if not (lj.exists() and json.loads(lj.read_text()) == lay):
            need = a.points * (24 + 12)
            free = shutil.disk_usage(d).free
            if free < need:
                raise SystemExit(f"{d}: {free / 2**30:.1f} GiB free, the cruise and its tiles need "
                                 f"{need / 2**30:.1f} GiB")
            t = time.perf_counter()
            generate(d, lay, a.chunk)
            lj.write_text(json.dumps(lay))
            print(f"generated {a.points:,} soundings in {time.perf_counter() - t:.0f} s -> {d}")
        cells = int(round(lay["side_m"] / a.resolution)) ** 2
        print(f"synthetic cruise: {a.points:,} soundings, {lay['n_lines']} lines over {lay['side_m'] / 1000:g} km "
              f"square, {a.resolution:g} m cells ({cells:,}), chunks of {a.chunk:,}; {os.cpu_count()} CPUs, load "
              f"{os.getloadavg()[0]:.1f}")
        script = os.path.abspath(__file__)
        run_child(script, "warmup", d, 0, a)
        steps = a.steps.split(",")
        if "tiled" in steps:
            r = run_child(script, "tiled", d, a.points, a)
            print(f"tiled grid (mean/median/count/std) of {r['n']:,} soundings: {r['cpu_s']:.1f} CPU-s, "
                  f"{r['wall_s']:.1f} s wall, {r['n'] / r['cpu_s'] / 1e6:.1f} M soundings per CPU-second, peak RSS "
                  f"{r['peak_rss'] / 2**30:.2f} GiB (after imports {r['rss_after_imports'] / 2**20:.0f} MiB); "
                  f"{r['n_tiles']} tiles of {r['tile_cells']} cells, {r['used']:,} used, {r['nonfinite']:,} NaN")
            print(f"  goal >= 25 M soundings per CPU-second: {'MET' if r['n'] / r['cpu_s'] >= 25e6 else 'NOT met'}; "
                  f"peak RSS <= 4 GB: {'MET' if r['peak_rss'] <= 4e9 else 'NOT met'} (at {r['n']:,} soundings)")
            ref = run_child(script, "moments_bincount", d, a.points, a)  # the peer, same soundings, same run
            print(f"  reference in the same run: streaming np.bincount count/mean/std of the same soundings "
                  f"{ref['cpu_s']:.1f} CPU-s ({ref['n'] / ref['cpu_s'] / 1e6:.1f} M/CPU-s); tiled with median / "
                  f"reference: {r['cpu_s'] / ref['cpu_s']:.2f}x CPU")
        if "tiled_moments" in steps:
            r = run_child(script, "moments_tiled", d, a.points, a)
            print(f"tiled grid (count/mean/std) of {r['n']:,} soundings: {r['cpu_s']:.1f} CPU-s, {r['wall_s']:.1f} s "
                  f"wall, {r['n'] / r['cpu_s'] / 1e6:.1f} M soundings per CPU-second, peak RSS "
                  f"{r['peak_rss'] / 2**30:.2f} GiB; {r['n_tiles']} tiles of {r['tile_cells']} cells")
        if "equal" in steps:
            n = min(a.subset, a.points)
            r = run_child(script, "equal", d, n, a)
            print(f"equality on the first {n:,} soundings ({r['tiles']} tiles), tiled vs in-memory grid_points:")
            for k, v in r.items():
                if isinstance(v, dict):
                    print(f"  {k}: " + ", ".join(f"{s} {w}" for s, w in v.items()))
        if "moments" in steps:
            n = min(a.moments_points, a.points)
            rows = {s: run_child(script, s, d, n, a) for s in ("moments_tiled", "moments_bincount",
                                                                "moments_inmemory")}
            g = gmt_blockmean(d, n, lay)
            print(f"count/mean/std of {n:,} soundings:               peak RSS     CPU")
            for s, r in rows.items():
                print(f"  {s:24s} {r['peak_rss'] / 2**20:8.0f} MiB {r['cpu_s']:7.1f} s")
            ref = g or rows["moments_bincount"]
            what = "gmt blockmean" if g else "the streaming bincount reference (gmt not installed)"
            if g:
                print(f"  {'gmt blockmean':24s} {g['peak_rss'] / 2**20:8.0f} MiB {g['cpu_s']:7.1f} s")
            ratio = rows["moments_tiled"]["peak_rss"] / ref["peak_rss"]
            print(f"  tiled / {what}: {ratio:.2f}x peak RSS (goal <= 2x: {'MET' if ratio <= 2 else 'NOT met'})")
    finally:
        if tmp:
            shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
