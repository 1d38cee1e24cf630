"""Benchmark: landing-site analysis of one 25 m x 1.5 m submap at 10 mm with all 37 headings.

Goal: <= 2.5 s single thread (Sangekar et al., Table VI: 254.9 s in MATLAB on one thread).

Printed in the same run:
* ``analyse_submap`` with 1 and 2 heading workers (best of ``--repeat`` runs each);
* a straightforward reference measured on the same grid: per heading, ``scipy.ndimage.binary_erosion`` /
  ``binary_dilation`` with the rotated ~8 700-cell footprint (the direct morphology of the paper's
  Fig. 12) and a per-cell ``np.linalg.lstsq`` plane fit over the footprint. Because that takes minutes,
  it is timed on ``--ref-headings`` headings (morphology in full, the plane fit on ``--ref-cells``
  cells) and extrapolated linearly to every admissible cell and all 37 headings — the printed ratio
  says so. The reference's exclusion maps are also checked against ours for equality.

Usage: PYTHONPATH=src .venv/bin/python bench/bench_landing.py [--grid submap.nc] [--repeat 2]
"""

from __future__ import annotations

import argparse
import math
import os
import time

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import xarray as xr  # noqa: E402
from scipy import ndimage as ndi  # noqa: E402

from hadal.landing import Vehicle, analyse_submap  # noqa: E402
from hadal.landing.exclusion import HIGH_PROTRUSION, UNMAPPED, footprint_mask  # noqa: E402
from hadal.landing.slope import footprint_slope_reference_deg  # noqa: E402


def synthetic_submap(seed: int = 0) -> xr.DataArray:
    """25 m x 1.5 m at 10 mm: a 10-20° slope, rocks of 1-25 cm, noise, ragged swath edges and a gap."""
    rng = np.random.default_rng(seed)
    cell, ny, nx = 0.01, 2500, 150
    Y, X = np.mgrid[0:ny, 0:nx] * cell
    slope = np.radians(10 + 10 * Y / 25.0)
    z = np.cumsum(np.tan(slope[:, :1]) * cell, axis=0) + 0.05 * np.sin(X * 2) + 0.002 * rng.standard_normal((ny, nx))
    for _ in range(40):
        cy, cx, r, h = rng.uniform(0, 25), rng.uniform(0, 1.5), rng.uniform(0.03, 0.2), rng.uniform(0.01, 0.25)
        d2 = ((Y - cy) ** 2 + (X - cx) ** 2) / r**2
        z = z + np.where(d2 < 1, h * np.sqrt(np.clip(1 - d2, 0, 1)), 0)
    edge = (3 + 3 * np.sin(np.arange(ny) / 50.0)).astype(int)
    z[X < edge[:, None] * cell] = np.nan
    z[1000:1100, 60:90] = np.nan
    return xr.DataArray(z - 1400.0, dims=("y", "x"), coords={"y": np.arange(ny) * cell, "x": np.arange(nx) * cell},
                        attrs={"units": "m"})


def best_of(fn, repeat: int):
    """Best wall time and best process CPU time (CPU time is less sensitive to other users of the machine)."""
    best, best_cpu, out = math.inf, math.inf, None
    for _ in range(repeat):
        t, c = time.perf_counter(), time.process_time()
        out = fn()
        best = min(best, time.perf_counter() - t)
        best_cpu = min(best_cpu, time.process_time() - c)
    return best, best_cpu, out


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--grid", help="NetCDF with elevation_m(y, x) instead of the synthetic submap")
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--ref-headings", type=float, nargs="*", default=[0.0])
    ap.add_argument("--ref-cells", type=int, default=100)
    a = ap.parse_args()
    if a.grid:
        with xr.open_dataset(a.grid) as ds:
            g = ds["elevation_m"].load()
    else:
        g = synthetic_submap()
    ny, nx = g.shape
    print(f"grid {ny} x {nx} cells ({ny * 0.01:.1f} m x {nx * 0.01:.2f} m at 10 mm), 37 headings")

    t1, c1, r1 = best_of(lambda: analyse_submap(g, workers=1), a.repeat)
    t2, c2, r2 = best_of(lambda: analyse_submap(g, workers=2), a.repeat)
    assert r1.sites.equals(r2.sites)
    print(f"analyse_submap, 1 worker : {t1:6.2f} s wall, {c1:5.2f} s CPU  (goal <= 2.5 s; paper's MATLAB: 254.9 s -> x{254.9 / t1:.0f})")
    print(f"analyse_submap, 2 workers: {t2:6.2f} s wall, {c2:5.2f} s CPU  (wall speed-up x{t1 / t2:.2f}; load average "
          f"{os.getloadavg()[0]:.1f} on {os.cpu_count()} cores)")
    print("  steps (1 worker): " + ", ".join(f"{k} {v:.2f}s" for k, v in r1.timings_s.items()))
    print(f"  {len(r1.sites)} candidate sites; best C_s = {r1.best['c_s']:.3f} at heading {r1.best['heading_deg']:.0f}°"
          if r1.best else "  no site")

    # ---- straightforward reference (direct morphology + per-cell lstsq), timed on a subset, extrapolated
    v = Vehicle()
    z = r1.elevation_m
    mapped = np.isfinite(z)
    high = r1.high_protrusion
    per_heading = []
    rng = np.random.default_rng(1)
    for hd in a.ref_headings:
        k = int(np.argmin(np.abs(r1.headings_deg - hd)))
        se = footprint_mask(v.length_m, v.width_m, float(r1.headings_deg[k]), 0.01)
        t = time.perf_counter()
        can_enter = ndi.binary_erosion(mapped, se, border_value=0)
        high_ex = ndi.binary_dilation(high, se)
        t_morph = time.perf_counter() - t
        ours = r1.exclusion[k]
        same = np.array_equal(can_enter, (ours & UNMAPPED) == 0) and np.array_equal(high_ex, (ours & HIGH_PROTRUSION) != 0)
        cells = np.argwhere(can_enter)
        n_adm = len(cells)
        pick = cells[rng.choice(n_adm, min(a.ref_cells, n_adm), replace=False)] if n_adm else cells
        t = time.perf_counter()
        footprint_slope_reference_deg(z, 0.01, se, pick)
        t_fit = (time.perf_counter() - t) / max(1, len(pick)) * n_adm
        per_heading.append(t_morph + t_fit)
        print(f"  reference heading {r1.headings_deg[k]:+.0f}°: morphology {t_morph:.2f} s (same maps as ours: {same}), "
              f"lstsq plane fit {t_fit:.1f} s extrapolated from {len(pick)} to {n_adm} cells")
    shared = r1.timings_s["slope_map"] + r1.timings_s["protrusion_map"] + r1.timings_s["small_protrusion_exclusion"]
    t_ref = shared + float(np.mean(per_heading)) * 37
    print(f"reference (extrapolated to 37 headings): {t_ref:8.1f} s  -> ours x{t_ref / t1:.0f} faster single-threaded")


if __name__ == "__main__":
    main()
