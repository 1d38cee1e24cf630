"""Benchmark: 1 M CTD scans through practical salinity + EOS-80 density + depth, hadal vs python-seawater.

Run: ``PYTHONPATH=src .venv/bin/python bench/bench_seawater.py [n_scans]``

Peer measured in the same run (the machine is shared; only the ratio is meaningful): python-seawater
(CSIRO SEAWATER port) ``sw.salt(C/C3515, t, p)``, ``sw.dens(S, t, p)``, ``sw.dpth(p, lat)``. hadal:
``practical_salinity``, ``density_eos80``, ``depth_fofonoff_millard`` (the same three formulas), plus the
hydrostatic depth (Eqs. 11-12) the ``derive`` stage actually uses, timed separately. Goal: >= 2x faster.
Each variant is run ``REPEATS`` times interleaved; the best time counts. Results are checked to agree.
hadal evaluates the formulas block-wise (cache-sized blocks, spread over ``hadal.seawater.THREADS``
threads; ``HADAL_SEAWATER_THREADS=1`` disables threading); the single-thread time is printed too.
"""

from __future__ import annotations

import sys
import time
import warnings

import numpy as np

from hadal import seawater as hsw
from hadal.depth import hydrostatic_depth

REPEATS = 7
LAT = 11.33


def scans(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A full-ocean-depth dive's CTD series: conductivity (S/m), ITS-90 temperature, pressure (dbar)."""
    rng = np.random.default_rng(0)
    depth = 10_900.0 * np.sin(np.linspace(0.0, np.pi, n)) + rng.normal(0, 0.05, n)
    depth = np.abs(depth)
    t = 1.5 + 27.5 * np.exp(-depth / 400.0) + 1e-4 * np.maximum(depth - 4000.0, 0.0) + rng.normal(0, 1e-3, n)
    sp = 34.7 - 0.5 * np.exp(-depth / 300.0) + rng.normal(0, 1e-3, n)
    p = hsw.depth_fofonoff_millard(1.0, LAT) ** -1 * depth * 1.02  # close enough to the pressure in dbar
    c = hsw.conductivity_from_salinity(sp, t, p)
    return c, t, p


def run_hadal(c, t, p):
    s = hsw.practical_salinity(c, t, p)
    rho = hsw.density_eos80(s, t, p)
    z = hsw.depth_fofonoff_millard(p, LAT)
    return s, rho, z


def run_peer(sw, c, t, p):
    s = sw.salt(c / hsw.C3515_S_M, t, p)
    rho = sw.dens(s, t, p)
    z = sw.dpth(p, LAT)
    return s, rho, z


def best(fn, *args) -> tuple[float, object]:
    t0 = time.perf_counter()
    out = fn(*args)
    return time.perf_counter() - t0, out


def main(n: int = 1_000_000) -> int:
    warnings.simplefilter("ignore")
    import seawater as sw

    c, t, p = scans(n)
    th, th1, tp, thyd = [], [], [], []
    threads = hsw.THREADS
    for _ in range(REPEATS):
        dt, ours = best(run_hadal, c, t, p)
        th.append(dt)
        hsw.THREADS = 1
        dt, _ = best(run_hadal, c, t, p)
        th1.append(dt)
        hsw.THREADS = threads
        dt, theirs = best(run_peer, sw, c, t, p)
        tp.append(dt)
        dt, _ = best(hydrostatic_depth, p, ours[0], t, LAT)
        thyd.append(dt)
    for a, b, name, tol in zip(ours, theirs, ("salinity", "density", "depth"), (1e-9, 1e-9, 1e-3), strict=True):
        err = float(np.max(np.abs(np.asarray(a) - np.asarray(b))))
        if err > tol:
            print(f"MISMATCH {name}: max |hadal - seawater| = {err:.3g}")
            return 1
    h, q = min(th), min(tp)
    print(f"{n:,} scans, best of {REPEATS} (salinity + density + F-M depth)")
    print(f"  python-seawater {sw.__version__:>8s}: {q * 1e3:8.1f} ms")
    print(f"  hadal ({threads} thread(s))      : {h * 1e3:8.1f} ms")
    print(f"  hadal (1 thread)        : {min(th1) * 1e3:8.1f} ms   ratio {q / min(th1):.2f}x")
    print(f"  ratio seawater / hadal  : {q / h:8.2f}x  (goal >= 2x)")
    print(f"  hadal hydrostatic depth (Eqs. 11-12, incl. its density): {min(thyd) * 1e3:.1f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main(int(sys.argv[1]) if len(sys.argv) > 1 else 1_000_000))
