"""Peak memory and time of the posterior terrain fix: whole-map search vs the FFT cropped to the search region.

Each case runs in a fresh child interpreter: the map is built first, then the fix's own peak allocation is
measured with ``tracemalloc`` (numpy reports its buffers to it) and the process's peak RSS
(``resource.getrusage``) is printed too. Maps: the sample dive's size (886 x 1190 cells
at 20 m) and one 10x larger (2802 x 3763 cells); track 180 samples (3.5 km, the sample's bottom track), 37
headings (+-9 deg, 0.5 deg), the posterior's default fine scales. Region: the suitability stage's proposed
region size (5.8 x 3.7 km, TERCOM paper §4.2) around the true start. The peer is the same fix over the whole
map (same code path, no region): the crop must give the same fix, faster, with memory bounded by the region,
not the map.

Run: ``PYTHONPATH=src .venv/bin/python bench/memory_tercom.py [--skip-whole-large]`` (a few minutes; the
whole-map search on the 10x map needs ~3.5 GB and is skipped with ``--skip-whole-large``).
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys

CHILD = r"""
import json, resource, sys, time
import numpy as np
from hadal.matching import MapGrid
from hadal.matching.posterior import posterior_fix
import _tests_path  # noqa: F401  (tests/ on sys.path)
from factories import AnalyticTerrain, wiggly_track
ny, nx, use_region = int(sys.argv[1]), int(sys.argv[2]), sys.argv[3] == "1"
h = 20.0
t = AnalyticTerrain.random(11, extent_m=nx * h, n_bumps=6 * max(1, nx * ny // 1_000_000))
x, y = np.arange(nx) * h, np.arange(ny) * h
z = np.empty((ny, nx))
for r0 in range(0, ny, 64):  # in row blocks: the analytic terrain is (cells x waves) wide
    xx, yy = np.meshgrid(x, y[r0:r0 + 64])
    z[r0:r0 + 64] = t(xx, yy)
z += np.random.default_rng(0).normal(0, 0.3, z.shape)
g = MapGrid.from_any(z, x, y)
rel = wiggly_track(180, 3500.0, seed=2)
start = np.array([nx * h / 2, ny * h / 2]) - (rel.min(0) + rel.max(0)) / 2
true = rel + start
prof = t(true[:, 0], true[:, 1]) - 5.0
prof += np.random.default_rng(1).normal(0, 0.5, prof.size)
import gc, tracemalloc
gc.collect()
base = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
tracemalloc.start()  # numpy reports its buffers to tracemalloc: the fix's own peak, whatever the map build's peak was
region = (start[0] - 2900, start[0] + 2900, start[1] - 1850, start[1] + 1850) if use_region else None
t0 = time.perf_counter()
f = posterior_fix(prof, rel, g, headings_deg=np.round(np.arange(-9, 9.01, 0.5), 6), region=region,
                  fine_scales=np.linspace(0.95, 1.05, 5))
dt = time.perf_counter() - t0
traced_peak = tracemalloc.get_traced_memory()[1]
peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
print(json.dumps({"cells": ny * nx, "seconds": dt, "added_bytes": traced_peak, "rss_peak_bytes": peak, "rss_before_bytes": base,
                  "x": f.start_x_m, "y": f.start_y_m, "error_m": float(np.hypot(f.start_x_m - start[0], f.start_y_m - start[1]))}))
"""


def run(ny: int, nx: int, region: bool) -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, str(ny), str(nx), "1" if region else "0"],
                         capture_output=True, text=True, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--skip-whole-large", action="store_true")
    args = ap.parse_args()
    cases = [("sample map, whole map", 886, 1190, False), ("sample map, region", 886, 1190, True),
             ("10x map, region", 2802, 3763, True)]
    if not args.skip_whole_large:
        cases.append(("10x map, whole map", 2802, 3763, False))
    res = {}
    print("| case | cells | time s | fix peak alloc MB | B/cell of the map | process peak RSS MB | start error m |")
    print("|---|---|---|---|---|---|---|")
    for name, ny, nx, reg in cases:
        r = run(ny, nx, reg)
        res[name] = r
        print(f"| {name} | {r['cells']:,} | {r['seconds']:.2f} | {r['added_bytes'] / 2**20:.0f} | "
              f"{r['added_bytes'] / r['cells']:.0f} | {r['rss_peak_bytes'] / 2**20:.0f} | {r['error_m']:.1f} |", flush=True)
    a, b = res["sample map, whole map"], res["sample map, region"]
    print(f"\nsample map: region crop {a['seconds'] / b['seconds']:.1f}x faster, "
          f"{a['added_bytes'] / max(b['added_bytes'], 1):.1f}x less memory, same fix: "
          f"{abs(a['x'] - b['x']) < 1e-6 and abs(a['y'] - b['y']) < 1e-6}")
    c = res["10x map, region"]
    print(f"10x map with the region: {c['added_bytes'] / 2**20:.0f} MB added "
          f"(sample map with the region: {b['added_bytes'] / 2**20:.0f} MB): bounded by the region, not the map")
    print("(machine shared with other jobs: read the ratios)")


if __name__ == "__main__":
    main()
