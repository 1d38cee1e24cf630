"""Benchmarks and measured numbers of the landing-site analysis (issue 15). Single thread throughout.

Sections (``--only`` picks some; default all but ``reference``):

* ``submap``   one 25 m × 1.5 m submap at 10 mm, 37 headings: best wall / CPU time of ``--repeat`` runs
               (goal ≤ 1 s; the paper's MATLAB: 254.9 s, Table VI);
* ``diagonal`` the same submap surveyed at 45° in its north-up bounding grid, analysed in its along-track
               frame: time and ratio to the axis-aligned one (goal ≤ 1.5×);
* ``strip``    a 100 m × 10 m strip at 10 mm (10 M cells) in a child process, single-threaded and with the
               landing stage's default heading threads (``--threads``, default min(4, CPU cores)): wall and CPU
               time and the analysis' peak RSS (VmHWM after a reset; goals ≤ 20 s, ≤ 1.5 GB). On a shared
               machine wall time is not CPU time: the single-thread CPU time is the work;
* ``rocks``    fraction of a rock's height each protrusion measure keeps (opening = ours, the paper's literal
               Butterworth f_c = 2/σ, the reference C++ disc mean), widths 0.05-1.5 m, on 0° and θc slopes,
               and cells truly above h_c that a measure misses;
* ``pf``       A_r (Eq. 12) against a brute-force erosion search on random sites (scale error, time);
* ``noise``    the real Takuyo raster under 0/2/4/6 mm white noise: sites, best-site move, C_s change;
* ``reference`` direct morphology + per-cell lstsq for comparison with the FFT heading maps (slow).

Usage: PYTHONPATH=src .venv/bin/python bench/bench_landing.py [--only submap diagonal ...] [--repeat 3]
"""

from __future__ import annotations

import argparse
import math
import os
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import _tests_path  # noqa: F401  (tests/ on sys.path)
import numpy as np  # noqa: E402
import xarray as xr  # noqa: E402
from landing_fixtures import TAKUYO_RASTER  # noqa: E402
from scipy import ndimage as ndi  # noqa: E402

from hadal.landing import Vehicle, analyse_submap  # noqa: E402

V = Vehicle()
RASTER = Path(__file__).resolve().parents[2] / "shared" / "data" / TAKUYO_RASTER


def _terrain(al: np.ndarray, ac: np.ndarray, rng: np.random.Generator, length: float, width: float) -> np.ndarray:
    """Elevation at along/across-track positions: a 10-20° slope along, a 5 cm swell across, 40 rocks of
    3-20 cm radius and 1-25 cm height, 2 mm noise, ragged swath edges and a gap (NaN)."""
    slope = np.radians(10 + 10 * np.clip(al, 0, length) / length)
    z = np.tan(slope) * al + 0.05 * np.sin(ac * 2) + 0.002 * rng.standard_normal(al.shape)
    for _ in range(40):
        cy, cx, r, h = rng.uniform(0, length), rng.uniform(0, width), rng.uniform(0.03, 0.2), rng.uniform(0.01, 0.25)
        d2 = ((al - cy) ** 2 + (ac - cx) ** 2) / r**2
        z = z + np.where(d2 < 1, h * np.sqrt(np.clip(1 - d2, 0, 1)), 0)
    edge = 0.03 + 0.03 * np.sin(al / 0.5)
    inside = (al >= 0) & (al < length) & (ac >= edge) & (ac < width)
    gap = (al >= 10.0) & (al < 11.0) & (ac >= 0.6) & (ac < 0.9)
    return np.where(inside & ~gap, z - 1400.0, np.nan)


def synthetic_submap(seed: int = 0, heading_deg: float = 0.0, length: float = 25.0, width: float = 1.5,
                     cell: float = 0.01) -> xr.DataArray:
    """25 m x 1.5 m at 10 mm; ``heading_deg`` != 0 lays the same strip obliquely in its north-up bounding grid."""
    rng = np.random.default_rng(seed)
    a = math.radians(heading_deg)
    ea, ec = np.array([math.sin(a), math.cos(a)]), np.array([math.cos(a), -math.sin(a)])
    corners = np.array([s * length * ea + t * width * ec for s in (0, 1) for t in (0, 1)])
    lo, hi = corners.min(0), corners.max(0)
    x = lo[0] + cell * (np.arange(int(math.ceil((hi[0] - lo[0]) / cell))) + 0.5)
    y = lo[1] + cell * (np.arange(int(math.ceil((hi[1] - lo[1]) / cell))) + 0.5)
    X, Y = np.meshgrid(x, y)
    z = _terrain(X * ea[0] + Y * ea[1], X * ec[0] + Y * ec[1], rng, length, width)
    return xr.DataArray(z, dims=("y", "x"), coords={"y": y, "x": x}, attrs={"units": "m"})


def best_of(fn, repeat: int):
    best, best_cpu, out = math.inf, math.inf, None
    for _ in range(repeat):
        t, c = time.perf_counter(), time.process_time()
        out = fn()
        best = min(best, time.perf_counter() - t)
        best_cpu = min(best_cpu, time.process_time() - c)
    return best, best_cpu, out


def _warm_up() -> None:
    """Load the compiled (numba) kernels once, outside the timings."""
    analyse_submap(synthetic_submap(length=3.0), headings_deg=[0.0])


def bench_submap(repeat: int) -> float:
    _warm_up()
    g = synthetic_submap()
    t, c, r = best_of(lambda: analyse_submap(g), repeat)
    print(f"[submap] {g.shape[0]} x {g.shape[1]} cells (25 m x 1.5 m at 10 mm), 37 headings, 1 thread: "
          f"{t:.2f} s wall, {c:.2f} s CPU (goal <= 1 s; paper's MATLAB 254.9 s -> x{254.9 / t:.0f}); "
          f"load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores")
    print("  steps: " + ", ".join(f"{k} {v:.3f}s" for k, v in r.timings_s.items()))
    print(f"  {len(r.sites)} candidate sites; best C_s = {r.best['c_s']:.3f} at heading {r.best['heading_deg']:.0f}°"
          if r.best else "  no site")
    return t


def bench_diagonal(repeat: int) -> None:
    _warm_up()
    g0 = synthetic_submap(heading_deg=0.0)
    g1 = synthetic_submap(heading_deg=45.0)
    t0, c0, r0 = best_of(lambda: analyse_submap(g0), repeat)
    t1, c1, r1 = best_of(lambda: analyse_submap(g1), repeat)
    tg, cg, _ = best_of(lambda: analyse_submap(g1, frame="grid"), 1)
    print(f"[diagonal] 45° transect: bounding grid {g1.shape[0]} x {g1.shape[1]} ({g1.size / 1e6:.2f} M cells), "
          f"along-track frame {r1.elevation_m.shape} (rotation {r1.frame_rotation_deg:.1f}°)")
    print(f"  axis-aligned {t0:.2f} s ({c0:.2f} CPU), diagonal {t1:.2f} s ({c1:.2f} CPU): ratio x{t1 / t0:.2f} wall, "
          f"x{c1 / c0:.2f} CPU (goal <= 1.5); without the frame (frame='grid'): {tg:.2f} s = x{tg / t0:.1f}")
    if r0.best and r1.best:
        print(f"  best C_s axis-aligned {r0.best['c_s']:.3f} (heading {r0.best['heading_deg']:.0f}°), "
              f"diagonal {r1.best['c_s']:.3f} (heading {r1.best['heading_deg'] - 45:.0f}° relative to the strip)")


STRIP_CHILD = r"""
import os, sys, time, resource
os.environ["OMP_NUM_THREADS"] = "1"
import numpy as np, xarray as xr
from hadal.landing import analyse_submap
rng = np.random.default_rng(0)
cell, ny, nx = 0.01, 10000, 1000
y = np.arange(ny) * cell; x = np.arange(nx) * cell
z = (np.tan(np.radians(8)) * y)[:, None] + 0.05 * np.sin(x * 2)[None, :] + 0.002 * rng.standard_normal((ny, nx))
for _ in range(400):
    cy, cx, r, h = rng.uniform(0, ny * cell), rng.uniform(0, nx * cell), rng.uniform(0.03, 0.3), rng.uniform(0.01, 0.3)
    i0, i1 = max(0, int((cy - r) / cell)), min(ny, int((cy + r) / cell) + 1)
    j0, j1 = max(0, int((cx - r) / cell)), min(nx, int((cx + r) / cell) + 1)
    Y, X = np.mgrid[i0:i1, j0:j1] * cell
    d2 = ((Y - cy) ** 2 + (X - cx) ** 2) / r**2
    z[i0:i1, j0:j1] += np.where(d2 < 1, h * np.sqrt(np.clip(1 - d2, 0, 1)), 0)
g = xr.DataArray(z - 1400.0, dims=("y", "x"), coords={"y": y, "x": x}, attrs={"units": "m"})
del z
analyse_submap(g.isel(y=slice(0, 300), x=slice(0, 100)), headings_deg=[0.0])  # load the compiled kernels
import gc; gc.collect()
def hwm_kb():
    for line in open("/proc/self/status"):
        if line.startswith("VmHWM:"):
            return int(line.split()[1])
    return -1
def rss_kb():
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1])
    return -1
try:  # reset the peak-RSS mark (Linux): the peak below is the analysis' own (with the resident input)
    open("/proc/self/clear_refs", "w").write("5")
except OSError:
    pass
r0 = rss_kb()
t = time.perf_counter(); c = time.process_time()
res = analyse_submap(g, keep_heading_exclusion=False, workers=int(sys.argv[1]))
print(f"{time.perf_counter() - t:.2f} {time.process_time() - c:.2f} "
      f"{hwm_kb() / 1024:.0f} {r0 / 1024:.0f} {len(res.sites)} {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f}")
print({k: round(v, 2) for k, v in res.timings_s.items()})
"""


def bench_strip(threads: int | None = None) -> None:
    """The strip single-threaded (CPU time = the work) and with ``threads`` heading threads (default: the
    stage's auto, min(4, CPU cores); wall time)."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "PYTHONPATH": str(Path(__file__).resolve().parents[1] / "src")}
    for n in dict.fromkeys([1, threads or min(4, os.cpu_count() or 1)]):
        out = subprocess.run([sys.executable, "-c", STRIP_CHILD, str(n)], capture_output=True, text=True, env=env,
                             timeout=900)
        if out.returncode:
            print(f"[strip] failed: {out.stderr.strip().splitlines()[-1:]}")
            return
        first, steps = out.stdout.strip().splitlines()[-2:]
        wall, cpu, rss, rss0, n_sites, rss_all = first.split()
        print(f"[strip] 100 m x 10 m at 10 mm (10 M cells), 37 headings, {n} heading thread(s): {float(wall):.1f} s "
              f"wall (goal <= 20 s: x{float(wall) / 20:.2f}), {float(cpu):.1f} s CPU; peak RSS {float(rss) / 1024:.2f} GB "
              f"(x{float(rss) / 1024 / 1.5:.2f} of the 1.5 GB goal; RSS before it, interpreter + input, "
              f"{float(rss0) / 1024:.2f} GB; whole child incl. building the input {float(rss_all) / 1024:.2f} GB); "
              f"{n_sites} sites; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores (on a shared machine "
              "wall time is not CPU time)")
        from hadal.landing.sites import estimate_resources

        est = estimate_resources((10_000, 1_000), 37, keep_heading_exclusion=False, workers=n)["bytes"] / 2**30
        print(f"  steps: {steps}; check_resources' estimate {est:.2f} GiB against the analysis' measured "
              f"{(float(rss) - float(rss0)) / 1024:.2f} GiB above the input (an upper bound: x"
              f"{est / ((float(rss) - float(rss0)) / 1024):.2f})")


def bench_rocks() -> None:
    from landing_reference import disc_mean_height_map

    from hadal.landing.protrusion import protrusion_height_map

    cell = 0.01
    hc = V.critical_height_m
    widths = (0.05, 0.1, 0.2, 0.4, 0.6, 1.0, 1.5)
    print("[rocks] fraction of a 0.30 m rock's height kept (max over the rock), 10 mm cells; miss = cells truly "
          "> h_c read <= h_c (all heights 0.05-0.5 m)")
    print("  slope  shape     width_m  opening  butterworth  disc_mean   miss_opening  miss_butterworth  miss_disc")
    for slope in (0.0, V.critical_slope_deg):
        th = math.radians(slope)
        for flat in (True, False):
            for w in widths:
                row = {}
                miss = {"o": 0, "b": 0, "d": 0}
                for hh in (0.05, 0.1, 0.2, 0.3, 0.5):
                    n = int((w + 2 * V.diagonal_m + 0.6) / cell)
                    Y, X = np.mgrid[0:n, 0:n] * cell
                    r2 = ((X - n * cell / 2) ** 2 + (Y - n * cell / 2) ** 2) / (0.5 * w) ** 2
                    true = np.where(r2 <= 1, hh if flat else hh * np.sqrt(np.clip(1 - r2, 0, 1)), 0.0)
                    z = math.tan(th) * Y + true / math.cos(th)
                    o = protrusion_height_map(z, cell, V.diagonal_m)
                    b = protrusion_height_map(z, cell, V.diagonal_m, method="butterworth")
                    d = disc_mean_height_map(z, cell, V.diagonal_m) * math.cos(th)
                    must = true > hc + 1e-3
                    for k, m in (("o", o), ("b", b), ("d", d)):
                        miss[k] += int(np.sum(must & ~(m > hc)))
                    if hh == 0.3:
                        row = {k: float(np.nanmax(m[true > 0]) / hh) for k, m in (("o", o), ("b", b), ("d", d))}
                print(f"  {slope:5.1f}  {'flat top' if flat else 'dome':8s}  {w:6.2f}   {row['o']:6.2f}   {row['b']:9.2f}"
                      f"  {row['d']:9.2f}   {miss['o']:12d}  {miss['b']:16d}  {miss['d']:9d}")


def bench_pf() -> None:
    from hadal.landing.exclusion import footprint_mask
    from hadal.landing.sites import largest_aspect_rectangle_m2

    rng = np.random.default_rng(4)
    cell = 0.02
    errs, t_exact, t_brute, origin = [], 0.0, 0.0, 0.0
    for _ in range(4):
        m = ndi.gaussian_filter(rng.random((90, 110)), 6) > 0.5
        lab, _ = ndi.label(m)
        sizes = np.bincount(lab.ravel())
        sizes[0] = 0
        m = lab == sizes.argmax()
        for hd in (0.0, 35.0, -65.0, 90.0):
            t = time.perf_counter()
            a = largest_aspect_rectangle_m2(m, cell, hd, V.length_m, V.width_m)
            t_exact += time.perf_counter() - t
            s = math.sqrt(a / V.footprint_area_m2)
            t = time.perf_counter()
            lo, step = 0.0, 0.001
            mp = np.pad(m, 5)
            for sc in np.arange(step, 5, step):
                if ndi.binary_erosion(mp, footprint_mask(sc * V.length_m, sc * V.width_m, hd, cell), border_value=0).any():
                    lo = sc
                else:
                    break
            t_brute += time.perf_counter() - t
            errs.append((s - lo) / max(lo, 1e-9))
            b = largest_aspect_rectangle_m2(np.pad(m, ((7, 0), (0, 3))), cell, hd, V.length_m, V.width_m)
            origin = max(origin, abs(b - a) / a)
    print(f"[pf] A_r exact vs brute-force erosion search (scale step 0.001) on 16 site/heading cases: scale "
          f"{100 * min(errs):+.2f} .. {100 * max(errs):+.2f} % of the brute force (within one step); crop-origin "
          f"change {100 * origin:.2g} %; {1e3 * t_exact / 16:.1f} ms vs {1e3 * t_brute / 16:.0f} ms per case")


def bench_noise() -> None:
    from landing_fixtures import read_takuyo, resampled

    if not RASTER.is_file():
        print(f"[noise] {RASTER} not present")
        return
    t = read_takuyo(RASTER)
    # the same area resampled to 10 mm (mask by nearest cell, values bilinear), 8 m x 6 m around the best site
    b0 = analyse_submap(t, max_cell_fraction=0.2).best
    t10 = resampled(t, 0.01, (b0["y_m"] - 3.0, b0["y_m"] + 3.0, b0["x_m"] - 4.0, b0["x_m"] + 4.0))
    for label, grid_, win in (("100 mm", t, 0.03), ("100 mm", t, 0.1), ("10 mm crop", t10, 0.03), ("10 mm crop", t10, 0.1)):
        _noise_row(label, grid_, win)


def _noise_row(label: str, t: xr.DataArray, win: float) -> None:
    if True:
        base = analyse_submap(t, local_slope_window_m=win, max_cell_fraction=0.2)
        if base.best is None:
            print(f"[noise] {label}, window {win:.2f} m: no site without noise")
            return
        rng = np.random.default_rng(15)
        parts = [f"0 mm: {len(base.sites)} sites, C_s {base.best['c_s']:.3f}"]
        for sd in (0.002, 0.004, 0.006):
            r = analyse_submap(t + sd * rng.standard_normal(t.shape), local_slope_window_m=win, max_cell_fraction=0.2)
            if r.best is None:
                parts.append(f"{sd * 1e3:.0f} mm: no site")
                continue
            mv = math.hypot(r.best["x_m"] - base.best["x_m"], r.best["y_m"] - base.best["y_m"])
            parts.append(f"{sd * 1e3:.0f} mm: {len(r.sites)} sites, moved {mv:.2f} m, C_s {r.best['c_s']:.3f} "
                         f"({100 * (r.best['c_s'] / base.best['c_s'] - 1):+.0f} %)")
        print(f"[noise] Takuyo {label}, local-slope window {win:.2f} m: " + "; ".join(parts))


def bench_reference() -> None:
    from landing_reference import footprint_slope_reference_deg

    from hadal.landing.exclusion import HIGH_PROTRUSION, UNMAPPED, footprint_mask

    g = synthetic_submap()
    r1 = analyse_submap(g)
    z = r1.elevation_m
    se = footprint_mask(V.length_m, V.width_m, 0.0, 0.01)
    t = time.perf_counter()
    can_enter = ndi.binary_erosion(np.isfinite(z), se, border_value=0)
    high_ex = ndi.binary_dilation(r1.high_protrusion, se)
    t_morph = time.perf_counter() - t
    k = int(np.argmin(np.abs(r1.headings_deg)))
    ours = r1.exclusion[k]
    same = np.array_equal(can_enter, (ours & UNMAPPED) == 0) and np.array_equal(high_ex, (ours & HIGH_PROTRUSION) != 0)
    cells = np.argwhere(can_enter)
    pick = cells[np.random.default_rng(1).choice(len(cells), min(100, len(cells)), replace=False)]
    t = time.perf_counter()
    footprint_slope_reference_deg(z, 0.01, se, pick)
    t_fit = (time.perf_counter() - t) / max(1, len(pick)) * len(cells)
    print(f"[reference] heading 0°: direct morphology {t_morph:.2f} s (same maps: {same}), lstsq plane fit "
          f"{t_fit:.0f} s extrapolated -> x{(t_morph + t_fit) * 37 / r1.timings_s['total']:.0f} slower over 37 headings")


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--only", nargs="*", default=["submap", "diagonal", "strip", "rocks", "pf", "noise"])
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--threads", type=int, default=None, help="heading threads of the second strip run")
    a = ap.parse_args()
    for name in a.only:
        if name == "submap":
            bench_submap(a.repeat)
        elif name == "diagonal":
            bench_diagonal(a.repeat)
        elif name == "strip":
            bench_strip(a.threads)
        elif name == "rocks":
            bench_rocks()
        elif name == "pf":
            bench_pf()
        elif name == "noise":
            bench_noise()
        elif name == "reference":
            bench_reference()
        else:
            raise SystemExit(f"unknown section {name!r}")
        sys.stdout.flush()


if __name__ == "__main__":
    main()
