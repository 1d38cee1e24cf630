"""How well can the sample dive's prior map place the bottom-track start at all? (issue 16, sample-seed goal)

For each generator seed (``hadal synth --small --seed S``, prepared as in bench/sample_seeds_tercom.py and
kept in ``--work``) this prints, for the start of the bottom track (map cell = 20 m):

* **CRLB**: the Cramér-Rao lower bound of the start position (radial, ``sqrt(tr C)``) for any unbiased
  estimator of the rigid pose (start x/y, heading, scale, depth bias; no drift, which only adds to it) from
  the measured profile on the **prior DTM**: Fisher information ``J^T J / s^2`` with ``J`` the pose
  derivatives of the *true* terrain (``truth/terrain.nc``) at the *true* sample positions, ``s`` the DTM's
  error along the true track (DTM minus truth, after the match stage's smoothing) and the samples counted
  as ``N / k`` independent ones, ``k = 1 + 2 sum rho(lag)`` from the autocorrelation of that map error along
  the track (the smoothing correlates the DTM's errors). An independent oracle: it uses the truth, which
  the estimator never sees.
* **P(within one cell)**: the probability that an efficient estimator (error ~ circular Gaussian with that
  CRLB) lands within 20 m, and the product over the seeds: the chance that any unbiased estimator meets
  "within one cell on every seed" with this map.
* The start error of the posterior fix (the match stage's ``posterior_fix`` with its parameters) on the
  prior **DTM**, and on the **true terrain** used as the map (same code, same profile): what the method
  achieves when the map is not the limit.

Run: ``PYTHONPATH=src .venv/bin/python bench/sample_seeds_information.py [--seeds 20181006 1 2 ...] [--work DIR]``
(about 1-2 min a seed for a new seed, ~20 s for a prepared one).
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np
import pandas as pd

sys.path.insert(0, str(Path(__file__).resolve().parent))

from sample_seeds_tercom import _seconds, prepare  # noqa: E402  (bench/ is on the path above)

CELL_M = 20.0


def load(d: Path):
    """(match params, smoothed DTM grid, its per-cell uncertainty layer or None, true terrain grid, profile, true
    x/y of the profile samples)."""
    import xarray as xr

    from hadal.matching import MapGrid
    from hadal.matching.fix import bottom_seconds, profile_from_ctd
    from hadal.pipeline import make_context
    from hadal.products.readers import open_dtm
    from hadal.stages.match import matching_dtm, read_ctd

    ctx = make_context(d / "dive", d / "store")
    p = ctx.config.match
    dtm = open_dtm(ctx.upstream("dtm"))
    g, _, _ = matching_dtm(MapGrid.from_any(dtm), p)
    unc = dtm["uncertainty_m"].transpose("y", "x").values if "uncertainty_m" in dtm else None  # as the stage
    prof, bottom = profile_from_ctd(read_ctd(ctx.upstream("ctd")), g.resolution_m)
    truth = pd.read_parquet(d / "dive" / "truth" / "track.parquet")
    ts = _seconds(truth["time"])
    tp = prof.time_s + bottom_seconds(bottom)[0]
    tx, ty = np.interp(tp, ts, truth["x_east_m"]), np.interp(tp, ts, truth["y_north_m"])
    with xr.open_dataset(d / "dive" / "truth" / "terrain.nc") as t:
        terrain = MapGrid(t["depth_m"].transpose("y", "x").values.astype(float), t["x"].values, t["y"].values,
                          float(t["x"].values[1] - t["x"].values[0]))
    return p, g, unc, terrain, prof, tx, ty


def crlb_start_m(g, terrain, tx, ty) -> tuple[float, float, float]:
    """(radial CRLB of the start, DTM error sigma along the track, correlation factor k) -- module docstring."""
    from hadal.matching import MapGrid

    h = terrain.resolution_m
    gy, gx = np.gradient(terrain.depth_m, h)
    zx = MapGrid(gx, terrain.x_m, terrain.y_m, h).sample_bilinear(tx, ty)
    zy = MapGrid(gy, terrain.x_m, terrain.y_m, h).sample_bilinear(tx, ty)
    err = g.sample_bilinear(tx, ty) - terrain.sample_bilinear(tx, ty)
    ok = np.isfinite(zx) & np.isfinite(zy) & np.isfinite(err)
    e = err[ok] - err[ok].mean()
    s2 = float(np.mean(e**2))
    rho = [float(np.mean(e[:-k] * e[k:]) / s2) for k in range(1, 10)]
    k_corr = 1.0 + 2.0 * sum(r for r in rho if r > 0)  # positive lags only: a conservative integral time
    rx, ry = tx[ok] - tx[0], ty[ok] - ty[0]
    J = np.column_stack([zx[ok], zy[ok], zx[ok] * ry - zy[ok] * rx, zx[ok] * rx + zy[ok] * ry, -np.ones(ok.sum())])
    C = np.linalg.inv(J.T @ J / (s2 * k_corr))
    return float(np.sqrt(C[0, 0] + C[1, 1])), float(np.sqrt(s2)), k_corr


def start_error_m(p, grid, prof, tx, ty, uncertainty=None) -> tuple[float, float]:
    """(start error, reported radial sigma) of the posterior fix on ``grid`` with the stage's parameters."""
    from hadal.matching.posterior import posterior_fix
    from hadal.stages.match import posterior_options

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        post = posterior_fix(prof.depth_m, prof.track_xy, grid, time_s=prof.time_s, uncertainty=uncertainty,
                             **posterior_options(p))
    xy = post.apply(prof.track_xy[:1], prof.time_s[:1])
    return float(np.hypot(xy[0, 0] - tx[0], xy[0, 1] - ty[0])), post.sigma_m


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[20181006, 1, 2, 3, 4, 5, 6, 7, 8, 9])
    ap.add_argument("--work", type=Path, default=Path("/tmp/hadal-sample-seeds"))
    args = ap.parse_args()
    print("| seed | DTM error along track m | correlation k | CRLB start m | P(within 1 cell) | "
          "posterior on DTM: error m / sigma m | posterior on true terrain: error m / sigma m |")
    print("|---|---|---|---|---|---|---|")
    probs, on_dtm, on_truth = [], [], []
    for seed in args.seeds:
        d = prepare(args.work, seed)
        p, g, unc, terrain, prof, tx, ty = load(d)
        crlb, s_map, k = crlb_start_m(g, terrain, tx, ty)
        per_axis = crlb / np.sqrt(2.0)
        prob = 1.0 - np.exp(-(CELL_M**2) / (2 * per_axis**2))
        e_dtm, s_dtm = start_error_m(p, g, prof, tx, ty, unc)
        e_true, s_true = start_error_m(p, terrain, prof, tx, ty)
        probs.append(prob)
        on_dtm.append(e_dtm)
        on_truth.append(e_true)
        print(f"| {seed} | {s_map:.2f} | {k:.1f} | {crlb:.1f} | {prob:.2f} | {e_dtm:.1f} / {s_dtm:.1f} | "
              f"{e_true:.1f} / {s_true:.1f} |", flush=True)
    n = len(probs)
    print(f"\nchance that an efficient unbiased estimator is within one cell on all {n} seeds with this map: "
          f"{np.prod(probs):.3f}; posterior within one cell: on the DTM {sum(e <= CELL_M for e in on_dtm)}/{n}, "
          f"on the true terrain {sum(e <= CELL_M for e in on_truth)}/{n}")


if __name__ == "__main__":
    main()
