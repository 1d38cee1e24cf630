"""How well can the sample dive's prior map place the bottom-track start at all? (issue 16, sample-seed goal)

For each generator seed (``hadal synth --small --seed S``; ``--full``: ``hadal synth --seed S``, the sample dive
that ``make demo`` runs; prepared as in bench/sample_seeds_tercom.py and
kept in ``--work``) this prints, for the start of the bottom track (map cell = 20 m):

* **CRLB**: the Cramér-Rao lower bound of the start position (radial, ``sqrt(tr C)``) for any unbiased
  estimator of the rigid pose (start x/y, heading, scale, depth bias; no drift, which only adds to it) from
  the measured profile on the **prior DTM**: Fisher information ``J^T J / s^2`` with ``J`` the pose
  derivatives of the *true* terrain (``truth/terrain.nc``) at the *true* sample positions, ``s`` the DTM's
  error along the true track (DTM minus truth, after the match stage's smoothing) and the samples counted
  as ``N / k`` independent ones, ``k = 1 + 2 sum rho(lag)`` from the autocorrelation of that map error along
  the track (the smoothing correlates the DTM's errors). An independent oracle: it uses the truth, which
  the estimator never sees.
* **With DR drift**: the same bound when the dead reckoning also drifts as the generator makes it drift
  (``truth.json`` ``dr_error``: a velocity noise of 3 mm/s with a 300 s Gaussian smoothing kernel, integrated from
  the bottom-track start): its depth error ``grad z . w`` is added to the measurement covariance (linearised), so
  the drift the terrain cannot tell apart from the pose is marginalised (:func:`drift_bound_start_m`; the errors
  ``s`` are the measured profile minus the map at the true positions, map and profile error together). Also on
  the true terrain as the map: the bound the drift alone sets.
* **P(within one cell)**: the probability that an efficient estimator (error ~ Gaussian with that bound's
  covariance) lands within 20 m, and the product over the seeds: the chance that any estimator meeting the
  bound is "within one cell on every seed" with this map.
* The start error of the posterior fix (the match stage's ``posterior_fix`` with its parameters) on the
  prior **DTM**, and on the **true terrain** used as the map (same code, same profile): what the method
  achieves when the map is not the limit.

Run: ``PYTHONPATH=src .venv/bin/python bench/sample_seeds_information.py [--seeds 20181006 1 2 ...] [--work DIR] [--full]``
(about 1-2 min a seed for a new seed, ~20 s for a prepared one).
"""

from __future__ import annotations

import argparse
import json
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


def crlb_start_m(g, terrain, tx, ty) -> tuple[np.ndarray, float, float]:
    """(2 x 2 CRLB covariance of the start, DTM error sigma along the track, correlation factor k) -- module
    docstring."""
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
    return C[:2, :2], float(np.sqrt(s2)), k_corr


def drift_covariance_m2(time_s: np.ndarray, sigma_v_m_s: float, corr_s: float, dt_s: float = 5.0) -> np.ndarray:
    """(N, N) covariance, per axis, of the dead-reckoning drift ``w(t_i) - w(t_0)`` of the generator's model
    (``truth.json`` ``dr_error``): a stationary velocity noise of ``sigma_v_m_s`` whose Gaussian smoothing kernel has
    a standard deviation of ``corr_s`` (hadal.synth.track.smooth_noise), i.e. the autocorrelation
    ``exp(-tau^2 / (4 corr_s^2))``, integrated on a ``dt_s`` grid."""
    t = np.asarray(time_s, float) - float(time_s[0])
    grid = np.arange(0.0, t[-1] + dt_s, dt_s)
    tau = grid[:, None] - grid[None, :]
    cv = sigma_v_m_s**2 * np.exp(-(tau**2) / (4.0 * corr_s**2))
    L = np.clip(t[:, None] - grid[None, :], 0.0, dt_s)  # (N, M) time spent in each grid step before t_i
    return L @ cv @ L.T


def drift_bound_start_m(g, terrain, tx, ty, prof, dr_error: dict) -> tuple[np.ndarray, float]:
    """(2 x 2 bound on the start's covariance, profile-minus-map error sigma at the truth) for any estimator of the rigid pose
    (start x/y, heading, scale, depth bias; flat priors) when the dead reckoning also drifts as the generator's
    velocity noise makes it: the drift's depth error ``grad z . w_i`` (linearised) is added to the measurement
    covariance, ``Sigma = s^2 k I + Zx Sw Zx + Zy Sw Zy``, and the bound is ``(J^T Sigma^-1 J)^-1`` -- the
    information the terrain has about the start once the drift it cannot tell apart from the pose is marginalised.
    ``s^2``, ``k``: the measured profile minus the map at the true positions (map error and profile error), its
    variance and AR integral time as in :func:`crlb_start_m`. Uses the truth (positions, terrain, drift model)."""
    from hadal.matching import MapGrid

    h = terrain.resolution_m
    gy, gx = np.gradient(terrain.depth_m, h)
    zx = MapGrid(gx, terrain.x_m, terrain.y_m, h).sample_bilinear(tx, ty)
    zy = MapGrid(gy, terrain.x_m, terrain.y_m, h).sample_bilinear(tx, ty)
    err = g.sample_bilinear(tx, ty) - np.asarray(prof.depth_m, float)
    ok = np.isfinite(zx) & np.isfinite(zy) & np.isfinite(err)
    e = err[ok] - err[ok].mean()
    s2 = float(np.mean(e**2))
    rho = [float(np.mean(e[:-k] * e[k:]) / s2) for k in range(1, 10)]
    k_corr = 1.0 + 2.0 * sum(r for r in rho if r > 0)
    sw = drift_covariance_m2(np.asarray(prof.time_s, float), float(dr_error["velocity_noise_m_s"]),
                             float(dr_error["velocity_noise_correlation_s"]))[np.ix_(ok, ok)]
    Zx, Zy = np.diag(zx[ok]), np.diag(zy[ok])
    cov = s2 * k_corr * np.eye(ok.sum()) + Zx @ sw @ Zx + Zy @ sw @ Zy
    rx, ry = tx[ok] - tx[0], ty[ok] - ty[0]
    J = np.column_stack([zx[ok], zy[ok], zx[ok] * ry - zy[ok] * rx, zx[ok] * rx + zy[ok] * ry, -np.ones(ok.sum())])
    C = np.linalg.inv(J.T @ np.linalg.solve(cov, J))
    return C[:2, :2], float(np.sqrt(s2))


def p_within(cov: np.ndarray, radius_m: float) -> float:
    """P(|e| <= radius_m) for a start error e ~ N(0, cov) (fixed draws)."""
    lam = np.clip(np.linalg.eigvalsh(cov), 0.0, None)
    z = np.random.default_rng(7).standard_normal((200_000, 2))
    return float(((z**2 @ lam) <= radius_m**2).mean())


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
    ap.add_argument("--full", action="store_true", help="the full sample dive (as `make demo`), not the small one")
    args = ap.parse_args()
    print("| seed | DTM error along track m | correlation k | CRLB start m | P(within 1 cell) | with DR drift: bound m | "
          "P(within 1 cell) | posterior on DTM: error m / sigma m | posterior on true terrain: error m / sigma m | "
          "with DR drift, true terrain: bound m |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    probs, probs_d, on_dtm, on_truth = [], [], [], []
    for seed in args.seeds:
        d = prepare(args.work, seed, small=not args.full)
        p, g, unc, terrain, prof, tx, ty = load(d)
        dr_error = json.loads((d / "dive" / "truth.json").read_text())["dr_error"]
        c_rigid, s_map, k = crlb_start_m(g, terrain, tx, ty)
        c_drift, _ = drift_bound_start_m(g, terrain, tx, ty, prof, dr_error)
        c_drift_true, _ = drift_bound_start_m(terrain, terrain, tx, ty, prof, dr_error)
        e_dtm, s_dtm = start_error_m(p, g, prof, tx, ty, unc)
        e_true, s_true = start_error_m(p, terrain, prof, tx, ty)
        probs.append(p_within(c_rigid, CELL_M))
        probs_d.append(p_within(c_drift, CELL_M))
        on_dtm.append(e_dtm)
        on_truth.append(e_true)
        print(f"| {seed} | {s_map:.2f} | {k:.1f} | {_radial(c_rigid):.1f} | {probs[-1]:.2f} | {_radial(c_drift):.1f} | "
              f"{probs_d[-1]:.2f} | {e_dtm:.1f} / {s_dtm:.1f} | {e_true:.1f} / {s_true:.1f} | {_radial(c_drift_true):.1f} |",
              flush=True)
    n = len(probs)
    print(f"\nchance that an efficient unbiased estimator is within one cell on all {n} seeds with this map: "
          f"{np.prod(probs):.3f} without the DR drift, {np.prod(probs_d):.3f} with it; posterior within one cell: "
          f"on the DTM {sum(e <= CELL_M for e in on_dtm)}/{n}, on the true terrain {sum(e <= CELL_M for e in on_truth)}/{n}")


def _radial(cov: np.ndarray) -> float:
    return float(np.sqrt(np.trace(cov)))

if __name__ == "__main__":
    main()
