"""MRF convergence range on real terrain: fraction of patches fixed within 0.5 cell vs initial offset (issue 16).

Grids nobody here wrote: ``../shared/data/bathy-real/tut_bathy.nc`` (71 x 74 cells of 7.83 km after
projection) and ``../shared/data/formats-real/gmt_depth_pixel.nc`` (GMT/ETOPO2, 566 x 566 cells of 3.54 km),
projected by :func:`factories.real_terrain`: the map is the grid nodes (bilinear between them),
the "true" seafloor a bicubic interpolant of the nodes, so the patch is off-node real terrain, not the map.

Each trial cuts a 40 x 30-cell real-time terrain patch (the paper's Simulation 1 size) at a random
sub-cell position from the truth, adds a depth bias (+-50 m) and Gaussian sounding noise (``--noise``,
fraction of the patch's depth range; the MRF paper gives no sounding noise, its GS+ multibeam in 5-40 m
of water is a few decimetres on metres of relief, ~1 %), and starts MRF from an assumed position offset by
``r`` cells (r = 0..30) in a random direction. Printed per offset: fraction within 0.5 cell (flagged fixes
count as failures), fraction flagged, median radial error of the unflagged fixes, for

* ``old``: the previous implementation (``coarse=False, prior="window", max_total_shift_cells=3``:
  linearised Eqs. 7-13 only, Gibbs term of the measured window with ``T = U(I_R)``, 3-cell cap);
* ``new``: ``mrf_refine`` defaults (exact data term over shifts up to 25 cells, then Eqs. 7-13 on the
  Gibbs-restored patch).

Then the Gibbs prior's effect, ``prior="gibbs"`` vs ``"none"`` on the same trials: the flattest windows of the
GMT grid (low texture) with sounding noise and/or DTM noise (added to the map nodes), and random (textured)
windows.

Run: ``PYTHONPATH=src .venv/bin/python bench/mrf_convergence.py [--trials 10] [--seed 0] [--noise 0.01]``
(about 0.1 s a trial for ``new``; the machine may be shared, so timings are not printed).
"""

from __future__ import annotations

import argparse
from pathlib import Path

import _tests_path  # noqa: F401  (tests/ on sys.path)
import numpy as np
from factories import cut_patch, real_terrain

from hadal.matching.mrf import mrf_refine

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
GRIDS = {"tut_bathy": SHARED / "bathy-real" / "tut_bathy.nc", "gmt_depth_pixel": SHARED / "formats-real" / "gmt_depth_pixel.nc"}
OFFSETS = (0, 1, 2, 3, 5, 10, 15, 20, 25, 27, 30)
OLD = {"coarse": False, "prior": "window", "max_total_shift_cells": 3.0}
NEW: dict = {}
NY, NX = 30, 40


def trial(g, truth, rng, r_cells, noise_frac, kwargs_list):
    patch, x0, y0 = cut_patch(g, truth, rng, noise_frac, ny=NY, nx=NX)
    a = rng.uniform(0, 2 * np.pi)
    h = g.resolution_m
    ax, ay = x0 + r_cells * h * np.cos(a), y0 + r_cells * h * np.sin(a)
    out = []
    for kw in kwargs_list:
        m = mrf_refine(patch, ax, ay, g, **kw)
        err = np.hypot(m.x0_m - x0, m.y0_m - y0) / h
        out.append((err, not m.converged))
    return out


def convergence_table(worlds, trials, seed, noise_frac):
    rng = np.random.default_rng(seed)
    print(f"\nconvergence vs initial offset (patch {NX} x {NY}, noise {100 * noise_frac:g} % of patch range, "
          f"{trials} trials per offset per grid, both grids)")
    print(f"{'offset':>7} | {'old <=0.5':>9} {'flag':>5} {'med':>6} | {'new <=0.5':>9} {'flag':>5} {'med':>6}")
    for r in OFFSETS:
        res = []
        for _name, (g, truth) in worlds.items():
            for _ in range(trials):
                res.append(trial(g, truth, rng, r, noise_frac, [OLD, NEW]))
        res = np.array(res, float)  # (n, 2 methods, (err, flagged))
        cols = []
        for k in range(2):
            err, fl = res[:, k, 0], res[:, k, 1] > 0
            ok = (err <= 0.5) & ~fl
            med = np.median(err[~fl]) if (~fl).any() else np.nan
            cols.append(f"{100 * ok.mean():8.0f}% {100 * fl.mean():4.0f}% {med:6.2f}")
        print(f"{r:7d} | {cols[0]} | {cols[1]}")


def flattest_windows(g, k, rng):
    """``k`` (row, col) corners of the lowest-relief 40 x 30 windows of ``g`` (coarse scan)."""
    cand = []
    for r in range(2, g.shape[0] - NY - 3, 10):
        for c in range(2, g.shape[1] - NX - 3, 10):
            w = g.depth_m[r : r + NY, c : c + NX]
            if np.isfinite(w).all():
                cand.append((float(np.std(np.diff(w, axis=1))), r, c))
    cand.sort()
    return [(r, c) for _, r, c in cand[:k]]


def prior_table(worlds, trials, seed):
    """Gibbs prior on vs off, paired trials on the GMT grid: RMS / median radial error (cells), share > 1 cell."""
    from hadal.matching.mapgrid import MapGrid

    rng = np.random.default_rng(seed + 1)
    g, truth = worlds["gmt_depth_pixel"]
    h = g.resolution_m
    flat = flattest_windows(g, 2 * trials, rng)
    print("\nGibbs prior effect (paired trials, offset 0-3 cells, GMT grid; noise as a fraction of the patch range; "
          "DTM noise added to the map nodes): RMS / median radial error (cells), share > 1 cell")
    print(f"{'case':>46} | {'gibbs RMS':>9} {'med':>5} {'>1':>4} | {'none RMS':>9} {'med':>5} {'>1':>4} | {'|diff| mean':>11}")
    for label, pn, mn, where in (("low texture, soundings 10 %, DTM exact", 0.10, 0.0, flat),
                                 ("low texture, soundings 20 %, DTM exact", 0.20, 0.0, flat),
                                 ("low texture, soundings 10 %, DTM 20 %", 0.10, 0.20, flat),
                                 ("low texture, soundings 20 %, DTM 20 %", 0.20, 0.20, flat),
                                 ("low texture, soundings 2 %, DTM 20 %", 0.02, 0.20, flat),
                                 ("random windows, soundings 1 %, DTM exact", 0.01, 0.0, [None] * len(flat)),
                                 ("random windows, soundings 5 %, DTM 5 %", 0.05, 0.05, [None] * len(flat))):
        res = []
        for rc in where:
            r0, c0 = (None, None) if rc is None else rc
            patch, x0, y0 = cut_patch(g, truth, rng, pn, r0=r0, c0=c0, ny=NY, nx=NX)
            rel = np.ptp(patch) / (1 + 4 * pn)
            gm = MapGrid(g.depth_m + rng.normal(0, mn * rel, g.shape), g.x_m, g.y_m, h) if mn else g
            a, rr = rng.uniform(0, 2 * np.pi), rng.uniform(0, 3)
            res.append([np.hypot(m.x0_m - x0, m.y0_m - y0) / h for m in
                        (mrf_refine(patch, x0 + rr * h * np.cos(a), y0 + rr * h * np.sin(a), gm, prior=p)
                         for p in ("gibbs", "none"))])
        res = np.array(res)
        cols = [f"{np.sqrt(np.mean(res[:, k] ** 2)):9.3f} {np.median(res[:, k]):5.2f} {100 * np.mean(res[:, k] > 1):3.0f}%"
                for k in range(2)]
        print(f"{label:>46} | {cols[0]} | {cols[1]} | {np.mean(np.abs(res[:, 0] - res[:, 1])):11.3f}")


def main():
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=10)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--noise", type=float, default=0.01)
    ap.add_argument("--no-prior", action="store_true", help="skip the prior-effect table")
    a = ap.parse_args()
    worlds = {k: real_terrain(p) for k, p in GRIDS.items() if p.exists()}
    if len(worlds) < len(GRIDS):
        raise SystemExit(f"real grids missing under {SHARED}")
    convergence_table(worlds, a.trials, a.seed, a.noise)
    if not a.no_prior:
        prior_table(worlds, a.trials, a.seed)


if __name__ == "__main__":
    main()
