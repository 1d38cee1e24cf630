"""Benchmark: gridding 10 M points (count/mean/std) with hadal.grid.grid_points vs its peers.

Peers measured in the same run, on the same points:
* ``scipy.stats.binned_statistic_2d`` - three calls (count, mean, std), what a user needs for the same grid;
* ``open3d`` ``PointCloud.voxel_down_sample`` with the cell size as voxel size - the mean only (no count/std),
  timed without and with building the ``PointCloud`` from the NumPy array.

Two point orders: random (worst case for cache locality) and survey order (points arrive along
scan lines, as multibeam pings and laser profiles do). Each timing is the best of ``--repeat`` runs
(the machine is shared; the minimum is the least disturbed measurement).

Run: ``PYTHONPATH=src .venv/bin/python bench/bench_grid.py [--points 10000000] [--repeat 3]``
Goal: >= 40 M points/s for count/mean/std on 2 cores.
"""

from __future__ import annotations

import argparse
import os
import time

import numpy as np


def best_of(fn, repeat: int) -> float:
    best = np.inf
    for _ in range(repeat):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def measure(xs, ys, zs, res: float, repeat: int, with_scipy: bool) -> dict[str, float]:
    import open3d as o3d
    from scipy.stats import binned_statistic_2d

    from hadal.grid import grid_points

    ds = grid_points(xs, ys, zs, res, statistics=("count", "mean", "std"))  # warm-up + check
    t_h = best_of(lambda: grid_points(xs, ys, zs, res, statistics=("count", "mean", "std")), repeat)
    pts = np.column_stack([xs, ys, zs])
    t_o3d_build = best_of(lambda: o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts)), 1)
    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    t_o3d = best_of(lambda: pc.voxel_down_sample(res), repeat)
    row = {"hadal count/mean/std": t_h, "open3d voxel mean": t_o3d, "open3d build+voxel": t_o3d + t_o3d_build}
    if with_scipy:
        xe = ds.attrs["grid_x0_edge"] + res * np.arange(ds.sizes["x"] + 1)
        ye = ds.attrs["grid_y0_edge"] + res * np.arange(ds.sizes["y"] + 1)

        def scipy3():
            for stat in ("count", "mean", "std"):
                binned_statistic_2d(ys, xs, zs, stat, bins=[ye, xe])

        row["scipy binned_statistic_2d x3"] = best_of(scipy3, 1)
        sc = binned_statistic_2d(ys, xs, zs, "mean", bins=[ye, xe]).statistic
        assert np.allclose(sc, ds["mean"].values, equal_nan=True, rtol=0, atol=1e-9), "mean differs from scipy"
    return row


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=10_000_000)
    ap.add_argument("--extent", type=float, default=1000.0, help="square extent (m); 1 m cells")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--skip-scipy", action="store_true")
    args = ap.parse_args()

    n, ext, res = args.points, args.extent, 1.0
    rng = np.random.default_rng(42)
    x = rng.uniform(0, ext, n)
    y = rng.uniform(0, ext, n)
    z = -4000.0 + 0.01 * x + rng.normal(0, 0.5, n)
    survey = np.lexsort((x, np.floor(y / res)))  # along-line order: row by row
    print(f"{n:,} points, {ext:g} m x {ext:g} m, {res:g} m cells ({int(ext / res) ** 2:,} cells), "
          f"{os.cpu_count()} CPUs, best of {args.repeat}")

    results = {}
    for order_name, order in (("random", None), ("survey", survey)):
        xs, ys, zs = (x, y, z) if order is None else (x[order], y[order], z[order])
        results[order_name] = measure(xs, ys, zs, res, args.repeat, not args.skip_scipy)

    for order_name, row in results.items():
        print(f"\n[{order_name} order]")
        th = row["hadal count/mean/std"]
        for name, t in row.items():
            ratio = "" if t is th else f"   hadal is {t / th:5.2f}x faster"
            print(f"  {name:30s} {t:7.3f} s  {n / t / 1e6:7.1f} M points/s{ratio}")
        goal = n / th / 1e6
        print(f"  goal >= 40 M points/s: {'MET' if goal >= 40 else 'NOT met'} ({goal:.1f})")


if __name__ == "__main__":
    main()
