"""Benchmark: gridding 10 M points with hadal.grid.grid_points vs GMT, scipy and open3d, in one run.

Two workloads, both on the same points, in two point orders - random (worst case for cache locality)
and survey order (points arrive along scan lines, as multibeam pings and laser profiles do):

* the default grid (mean, median, count, std) against ``gmt blockmedian -C`` (the Debian package ``gmt``;
  binary float64 x,y,z in, binary out to /dev/null, the medians checked equal to hadal's) and against
  hadal's own NumPy reference path (``np.lexsort`` by (cell, z): the median path before issue 19);
* count/mean/std against hadal's fused single pass over the points (what it used in every point order
  before issue 19), ``gmt xyz2grd -Am`` (mean), ``scipy.stats.binned_statistic_2d`` (three calls)
  and open3d ``PointCloud.voxel_down_sample`` (the mean only, without and with building the PointCloud).

GMT is skipped with a message when ``gmt`` is not on PATH (``apt-get install gmt``); ``--skip-scipy``,
``--skip-open3d`` skip those peers. Each timing is the best of ``--repeat`` runs (GMT: ``--gmt-repeat``);
wall time and CPU time (all threads, and GMT's child-process CPU) are printed: the machine may be shared,
so compare ratios from one run. Warm-up calls (numba start-up, first-touch of the inputs) are not timed.

Run: ``PYTHONPATH=src .venv/bin/python bench/bench_grid.py [--points 10000000] [--repeat 3]``
Goals (issue 19): default grid >= 3x faster than ``gmt blockmedian``; count/mean/std >= 40 M points/s in
both point orders.
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import numpy as np

DEFAULT_STATS = ("mean", "median", "count", "std")
MOMENTS = ("count", "mean", "std")


def best_of(fn, repeat: int) -> tuple[float, float]:
    """Best (wall, CPU) seconds of ``repeat`` calls; CPU is this process's user+system time."""
    best = (np.inf, np.inf)
    for _ in range(repeat):
        c0, t0 = time.process_time(), time.perf_counter()
        fn()
        best = min(best, (time.perf_counter() - t0, time.process_time() - c0))
    return best


def run_gmt(args: list[str], repeat: int) -> tuple[tuple[float, float], bytes]:
    """Best (wall, child CPU) of ``repeat`` runs of ``gmt args``, and the last run's stdout."""
    best, out = (np.inf, np.inf), b""
    for _ in range(repeat):
        r0 = resource.getrusage(resource.RUSAGE_CHILDREN)
        t0 = time.perf_counter()
        p = subprocess.run(["gmt", *args], capture_output=True, check=True)
        wall = time.perf_counter() - t0
        r1 = resource.getrusage(resource.RUSAGE_CHILDREN)
        cpu = (r1.ru_utime - r0.ru_utime) + (r1.ru_stime - r0.ru_stime)
        best, out = min(best, (wall, cpu)), p.stdout
    return best, out


def measure(xs, ys, zs, res: float, ext: float, args, tmp: Path) -> dict[str, tuple[float, float]]:
    from hadal.grid import grid_points
    from hadal.grid import points as P

    bounds = (0.0, 0.0, ext, ext)
    row: dict[str, tuple[float, float]] = {}
    ds = grid_points(xs, ys, zs, res, bounds=bounds, statistics=DEFAULT_STATS)  # warm-up (numba start-up)
    grid_points(xs, ys, zs, res, bounds=bounds, statistics=MOMENTS)
    row["hadal default (mean/median/count/std)"] = best_of(
        lambda: grid_points(xs, ys, zs, res, bounds=bounds, statistics=DEFAULT_STATS), args.repeat)

    def numpy_reference():
        spec = P.make_grid_spec(res, bounds)
        idx, zz, _, _ = P.point_indices(xs, ys, zs, spec)
        P._reduce_cells_numpy(idx, zz, spec.n_cells, DEFAULT_STATS)

    row["hadal NumPy lexsort path (before)"] = best_of(numpy_reference, 1)
    row["hadal count/mean/std"] = best_of(lambda: grid_points(xs, ys, zs, res, bounds=bounds, statistics=MOMENTS),
                                          args.repeat)
    scattered = P._scattered
    try:  # the fused single pass over the points, whatever their order (count/mean/std before issue 19)
        P._scattered = lambda *a, **k: False
        row["hadal single-pass kernel (before)"] = best_of(
            lambda: grid_points(xs, ys, zs, res, bounds=bounds, statistics=MOMENTS), args.repeat)
    finally:
        P._scattered = scattered
    if shutil.which("gmt"):
        f = tmp / "points.bin"
        np.column_stack([xs, ys, zs]).tofile(f)
        region = [f"-R0/{ext:g}/0/{ext:g}", f"-I{res:g}", "-r"]
        row["gmt blockmedian -C"], out = run_gmt(["blockmedian", str(f), "-bi3d", "-bo3d", "-C", *region],
                                                 args.gmt_repeat)
        g = np.frombuffer(out).reshape(-1, 3)
        ix, iy = np.floor(g[:, 0] / res).astype(int), np.floor(g[:, 1] / res).astype(int)
        diff = np.abs(ds["median"].values[iy, ix] - g[:, 2])
        assert len(g) == int((ds["count"].values > 0).sum()) and diff.max() <= 1e-9, "medians differ from GMT"
        row["gmt xyz2grd -Am (mean only)"], _ = run_gmt(
            ["xyz2grd", str(f), "-bi3d", "-Am", *region, f"-G{tmp / 'mean.nc'}"], args.gmt_repeat)
        f.unlink()
    if not args.skip_open3d:
        import open3d as o3d

        pts = np.column_stack([xs, ys, zs])
        t_build = best_of(lambda: o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts)), 1)
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
        t = best_of(lambda: pc.voxel_down_sample(res), args.repeat)
        row["open3d voxel mean"] = t
        row["open3d build+voxel"] = (t[0] + t_build[0], t[1] + t_build[1])
    if not args.skip_scipy:
        from scipy.stats import binned_statistic_2d

        edges = res * np.arange(int(round(ext / res)) + 1)

        def scipy3():
            for stat in MOMENTS:
                binned_statistic_2d(ys, xs, zs, stat, bins=[edges, edges])

        row["scipy binned_statistic_2d x3"] = best_of(scipy3, 1)
        sc = binned_statistic_2d(ys, xs, zs, "mean", bins=[edges, edges]).statistic
        assert np.allclose(sc, ds["mean"].values, equal_nan=True, rtol=0, atol=1e-9), "mean differs from scipy"
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=10_000_000)
    ap.add_argument("--extent", type=float, default=1000.0, help="square extent (m); 1 m cells")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--gmt-repeat", type=int, default=1)
    ap.add_argument("--skip-scipy", action="store_true")
    ap.add_argument("--skip-open3d", action="store_true")
    ap.add_argument("--orders", default="random,survey")
    args = ap.parse_args()

    n, ext, res = args.points, args.extent, 1.0
    rng = np.random.default_rng(42)
    x = rng.uniform(0, ext, n)
    y = rng.uniform(0, ext, n)
    z = -4000.0 + 0.01 * x + rng.normal(0, 0.5, n)
    print(f"{n:,} points, {ext:g} m x {ext:g} m, {res:g} m cells ({int(ext / res) ** 2:,} cells), "
          f"{os.cpu_count()} CPUs (load average {os.getloadavg()[0]:.1f}), best of {args.repeat}")
    if not shutil.which("gmt"):
        print("gmt not found on PATH: the GMT comparison is skipped (apt-get install gmt)")

    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        for order_name in args.orders.split(","):
            if order_name == "random":
                xs, ys, zs = x, y, z
            else:
                o = np.lexsort((x, np.floor(y / res)))  # along-line order: row by row
                xs, ys, zs = x[o], y[o], z[o]
            results[order_name] = measure(xs, ys, zs, res, ext, args, Path(tmp))

    for order_name, row in results.items():
        print(f"\n[{order_name} order]                        wall        CPU      wall rate")
        for name, (w, c) in row.items():
            print(f"  {name:38s} {w:7.3f} s  {c:7.3f} s  {n / w / 1e6:7.1f} M points/s")
        tm, td = row["hadal count/mean/std"], row["hadal default (mean/median/count/std)"]
        for name, (w, c) in row.items():
            if name.startswith("hadal"):
                continue
            ref = td if ("blockmedian" in name) else tm
            print(f"  {'hadal default' if ref is td else 'hadal count/mean/std'} vs {name}: "
                  f"{w / ref[0]:5.2f}x faster (wall), {c / ref[1]:5.2f}x (CPU)")
        before = row["hadal NumPy lexsort path (before)"]
        print(f"  hadal default vs the NumPy lexsort path: {before[0] / td[0]:5.2f}x (wall), "
              f"{before[1] / td[1]:5.2f}x (CPU)")
        sp = row["hadal single-pass kernel (before)"]
        print(f"  hadal count/mean/std vs the single-pass kernel: {sp[0] / tm[0]:5.2f}x (wall), "
              f"{sp[1] / tm[1]:5.2f}x (CPU)")
        rate = n / tm[0] / 1e6
        print(f"  goal count/mean/std >= 40 M points/s: {'MET' if rate >= 40 else 'NOT met'} ({rate:.1f}; "
              f"{n / tm[1] / 1e6:.1f} per CPU-second)")
        if "gmt blockmedian -C" in row:
            r = row["gmt blockmedian -C"][0] / td[0]
            print(f"  goal default grid >= 3x gmt blockmedian: {'MET' if r >= 3 else 'NOT met'} ({r:.1f}x)")


if __name__ == "__main__":
    main()
