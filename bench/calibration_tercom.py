"""Accuracy and calibration of the posterior terrain fix on real terrain (issue 16 acceptance).

Real grids: ``../shared/data/bathy-real/tut_bathy.nc`` (ETOPO5, 5', near Bermuda; 71 x 74 cells of
7.83 km after projection) and ``../shared/data/formats-real/gmt_depth_pixel.nc`` (GMT/ETOPO2 rough
seafloor, 566 x 566 cells of 3.54 km; each trial uses a random 150 x 150 window). Both are projected
onto a transverse-Mercator frame (:func:`factories.real_terrain`); the "true" seafloor is
a bicubic interpolant of the nodes, the map the nodes themselves (bilinear between them), so the map
error between nodes is real-terrain-sized.

Each trial (:func:`factories.simulate_case`) draws a track of 20-100 samples (one per cell
of travel; 3-8 for ``short``), noise 0-2 % of the map relief, a depth bias (+-50 m), heading error
(+-4 deg), scale error (+-3 %), a random-walk + velocity-bias drift, and a kind: ``clean``, ``drift``
(velocity bias up to 2 %), ``holes`` (40-50 % of samples over NaN blobs), ``off_map`` (25-35 % off
the map), ``flat`` (zero-relief map), ``short``. The fix searches headings -5..5 deg (1 deg) x scales
0.97/1.00/1.03 over the whole map (:func:`hadal.matching.posterior.posterior_fix`, with its joint
dead-reckoning drift estimate: the tracks have no times, so the drift rate is per metre travelled, three
segments, prior 0.5 %); the paper's TERCOM (MSD, heading 0, cell resolution) runs on the same trials as the
baseline.

Printed (goals from issue 16):
* within one cell (radial error <= 1 cell) for tracks >= 50 cells at noise <= 1 % (clean + drift): goal >= 95 %;
* calibration on unflagged fixes: errors within the reported radial 1-sigma (DRMS = sqrt(trace C)),
  goal 55-75 % (a calibrated 2-D Gaussian: 63 %), within 2 x DRMS goal >= 93 % (Gaussian: 98 %);
  also the Mahalanobis 1-/2-sigma ellipse content (Gaussian: 39 % / 86 %), the mean squared Mahalanobis
  distance (2 for a calibrated 2-D Gaussian, whatever the ellipses' shapes: the scale check that the coverage
  fractions, which also depend on the shape and the tails, are not) and what a Gaussian with each fix's own
  covariance would put within 1/2 DRMS (63-68 % / 95-98 %: elongated ellipses give more);
* flagged fraction of fixes more than 3 cells wrong: goal >= 95 %; false alarms (flagged fixes that
  are within 3 cells) on all trials and on the clean/drift trials: goal <= 5 %. The CSV also has the holes
  test's ``mass_outside_if_holes_fit`` (:func:`hadal.matching.posterior.posterior_fix`, ``over_holes``).
  Seeds 1 and 2 were used while developing the flags (the 20 % ambiguity threshold was chosen on seed 1);
  seed 3 is held out.

The per-kind table adds the median squared Mahalanobis distance of the unflagged fixes (a calibrated 2-D Gaussian:
1.39), which separates the two ways the fractions above can miss: a too-wide core (median below 1.39) and a heavy
tail (within 2 DRMS low).

The simulated dead reckoning's random walk (``--walk``, cells per sample and axis) is given to the fix as
``drift_random_walk`` (``walk x sqrt(h)`` m per sqrt(m) travelled, one sample a cell), as a user gives their
navigation's specification; ``--walk-given 0`` withholds it (a diagnostic). The reported covariance is that of the
posterior's main mode (Laplace at the continuous MAP, :mod:`hadal.matching.posterior`, *Reported*). Measured
2026-12-04, 320 trials a seed:

| seed | within 1 DRMS | within 2 DRMS | within one cell (long, low noise) | flagged of wrong | false alarms |
|---|---|---|---|---|---|
| 0 | 0.701 | 0.974 | 1.000 | 1.000 | 0.025 |
| 1 | 0.671 | 0.957 | 0.984 | 0.988 | 0.030 |
| 2 | 0.706 | 0.966 | 0.987 | 1.000 | 0.037 |
| 3 | 0.737 | 0.967 | 1.000 | 0.986 | 0.016 |
| 4 | 0.684 | 0.958 | 1.000 | 0.990 | 0.037 |
| 5 | 0.738 | 0.955 | 1.000 | 0.978 | 0.052 |

Other dead-reckoning qualities, walk given (seed 0): ``--walk 0.01`` 0.737 / 0.956, ``--walk 0.06`` 0.731 / 0.962
(within 1 / 2 DRMS; within one cell 1.000 / 0.988, flagged of wrong 1.000 / 0.976, false alarms 0.042 / 0.021).
With the walk withheld (seeds 0, 1): within 1 DRMS 0.589 / 0.554, within 2 DRMS 0.918 / 0.905 (the long tracks'
errors beyond the covariance). The previous report, the grid's second moment of every mode with the noise of the
best discrete pose: 0.714-0.775 and 0.948-0.974 (its core too wide, median squared Mahalanobis distance 0.84-0.87).
Pooled over the 1920 trials: within one cell 0.995, within 1 / 2 DRMS 0.706 / 0.963, flagged of wrong 0.990, false
alarms 0.033 (clean + drift 0.009). Seed 5's false alarms (12 of 231 fixes within 3 cells): one short track (3-8
samples, flagged by design), six ambiguous off-map or 22-32-sample tracks whose posterior is genuinely spread (20-70 %
outside the main mode), five over_holes flags (three on tracks over holes); the flags do not depend on the
covariance, and 12 is 1.6 binomial standard deviations above the pooled rate.

Run: ``PYTHONPATH=src .venv/bin/python bench/calibration_tercom.py [--trials 320] [--seed 0] [--out bench/results]``
(about 0.3 s a trial on one core).
"""

from __future__ import annotations

import argparse
import time
import warnings
from pathlib import Path

import _tests_path  # noqa: F401  (tests/ on sys.path)
import numpy as np
import pandas as pd
from factories import crop, real_terrain, simulate_case

from hadal.matching import tercom
from hadal.matching.posterior import posterior_fix

SHARED = Path(__file__).resolve().parents[2] / "shared" / "data"
GRIDS = {"tut_bathy": SHARED / "bathy-real" / "tut_bathy.nc", "gmt_depth_pixel": SHARED / "formats-real" / "gmt_depth_pixel.nc"}
KIND_WEIGHTS = {"clean": 0.50, "drift": 0.15, "holes": 0.10, "off_map": 0.10, "flat": 0.075, "short": 0.075}
HEADINGS = np.arange(-5, 5.01, 1.0)
SCALES = (0.97, 1.0, 1.03)
CROP = 150
_Z2 = np.random.default_rng(12345).standard_normal((20_000, 2)) ** 2  # fixed draws: Gaussian DRMS content


def gaussian_drms_content(cov: np.ndarray, k: float = 1.0) -> float:
    """P(|e| <= k * DRMS) for e ~ N(0, cov): 63 % (k = 1) for a circular error, up to 68 % for a line (chi^2_1)."""
    lam = np.clip(np.linalg.eigvalsh(np.asarray(cov, float)), 0.0, None)
    if not np.isfinite(lam).all() or lam.sum() <= 0:
        return float("nan")
    w = lam / lam.sum()
    return float(((_Z2 @ w) <= k * k).mean())


def load_worlds(grids=GRIDS):
    return {name: real_terrain(path) for name, path in grids.items()}


def run_trials(worlds: dict, trials: int, seed: int, kinds=None, baseline: bool = True,
               walk_cells: float = 0.03, walk_given: float = 1.0) -> pd.DataFrame:
    """``trials`` simulated fixes alternating over ``worlds``; one row per trial (errors in cells); ``walk_cells``:
    the dead-reckoning random walk of :func:`factories.simulate_case` (0: none, a diagnostic), given to the fix
    times ``walk_given`` (1: the navigation's specification known, as a user gives it; 0: not modelled)."""
    rng = np.random.default_rng(seed)
    names = list(worlds)
    kinds = kinds or list(KIND_WEIGHTS)
    p = np.array([KIND_WEIGHTS.get(k, 1.0) for k in kinds])
    p = p / p.sum()
    rows = []
    for i in range(trials):
        name = names[i % len(names)]
        g, truth = worlds[name]
        if max(g.shape) > CROP:
            r0 = int(rng.integers(0, g.shape[0] - CROP + 1))
            c0 = int(rng.integers(0, g.shape[1] - CROP + 1))
            g = crop(g, r0, c0, CROP)
        kind = str(rng.choice(kinds, p=p))
        c = simulate_case(g, truth, rng, kind, walk_cells=walk_cells)
        h = c["h"]
        t0 = time.perf_counter()
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # nothing may leak to the user
            # one sample per cell of travel: a walk of walk_cells * h per sample is walk_cells * sqrt(h) m/sqrt(m)
            f = posterior_fix(c["profile"], c["dr"], c["map"], headings_deg=HEADINGS, scales=SCALES,
                              drift_random_walk=walk_given * walk_cells * float(np.sqrt(h)))
        dt = time.perf_counter() - t0
        sx, sy = c["start"]
        err = float(np.hypot(f.start_x_m - sx, f.start_y_m - sy)) / h
        row = {"grid": name, "kind": kind, "n": c["n"], "noise_frac": c["noise_frac"], "heading_deg": c["heading_deg"],
               "scale": c["scale"], "velocity_bias": c["velocity_bias"], "error_cells": err,
               "drms_cells": f.sigma_m / h, "mahalanobis": f.mahalanobis(sx, sy), "mismatch": f.mismatch,
               "reasons": ",".join(f.reasons), "mass_outside": f.mass_outside_main_mode,
               "mass_outside_if_holes_fit": f.refinement.get("holes_test", {}).get("mass_outside_if_holes_fit", 0.0),
               "valid_fraction": f.valid_fraction, "gauss_within_1drms": gaussian_drms_content(f.cov_m2),
               "gauss_within_2drms": gaussian_drms_content(f.cov_m2, 2.0),
               "n_eff": f.n_eff, "seconds": dt}
        if baseline:
            try:
                b = tercom(c["profile"], c["dr"], c["map"], min_valid_fraction=0.5)
                row["paper_error_cells"] = float(np.hypot(b.start_x_m - sx, b.start_y_m - sy)) / h
                row["paper_mismatch"] = b.mismatch
            except Exception:  # noqa: BLE001 - the baseline may find no feasible offset
                row["paper_error_cells"], row["paper_mismatch"] = np.nan, False
        rows.append(row)
    return pd.DataFrame(rows)


def metrics(df: pd.DataFrame) -> dict:
    e, fl = df["error_cells"], df["mismatch"].astype(bool)
    terr = df["kind"].isin(["clean", "drift"])
    acc = df[terr & (df["n"] >= 50) & (df["noise_frac"] <= 0.01)]
    un = df[~fl]
    wrong = e > 3
    out = {
        "trials": len(df),
        "within_one_cell_long_lownoise": float((acc["error_cells"] <= 1).mean()) if len(acc) else np.nan,
        "n_long_lownoise": len(acc),
        "paper_tercom_within_one_cell_long_lownoise": float((acc["paper_error_cells"] <= 1).mean())
        if "paper_error_cells" in acc and len(acc) else np.nan,
        "median_error_cells_long_lownoise": float(acc["error_cells"].median()) if len(acc) else np.nan,
        "unflagged": len(un),
        "within_1drms_unflagged": float((un["error_cells"] <= un["drms_cells"]).mean()) if len(un) else np.nan,
        "within_2drms_unflagged": float((un["error_cells"] <= 2 * un["drms_cells"]).mean()) if len(un) else np.nan,
        "within_1drms_all": float((e <= df["drms_cells"]).mean()),
        "within_2drms_all": float((e <= 2 * df["drms_cells"]).mean()),
        "mahalanobis_le1_unflagged": float((un["mahalanobis"] <= 1).mean()) if len(un) else np.nan,
        "mahalanobis_le2_unflagged": float((un["mahalanobis"] <= 2).mean()) if len(un) else np.nan,
        "mean_mahalanobis2_unflagged": float((un["mahalanobis"] ** 2).mean()) if len(un) else np.nan,
        "gaussian_within_1drms_unflagged": float(un["gauss_within_1drms"].mean()) if len(un) else np.nan,
        "gaussian_within_2drms_unflagged": float(un["gauss_within_2drms"].mean()) if len(un) else np.nan,
        "wrong_gt3": int(wrong.sum()),
        "flagged_of_wrong_gt3": float(fl[wrong].mean()) if wrong.any() else np.nan,
        "false_alarms_all": float(fl[~wrong].mean()) if (~wrong).any() else np.nan,
        "false_alarms_clean_drift": float(fl[~wrong & terr].mean()) if (~wrong & terr).any() else np.nan,
        "paper_flagged_of_wrong_gt3": float(df.loc[df["paper_error_cells"] > 3, "paper_mismatch"].mean())
        if "paper_error_cells" in df and (df["paper_error_cells"] > 3).any() else np.nan,
        "mean_seconds": float(df["seconds"].mean()),
    }
    return out


GOALS = {"within_one_cell_long_lownoise": ">= 0.95", "within_1drms_unflagged": "0.55-0.75",
         "within_2drms_unflagged": ">= 0.93", "flagged_of_wrong_gt3": ">= 0.95", "false_alarms_all": "<= 0.05",
         "false_alarms_clean_drift": "<= 0.05", "mean_mahalanobis2_unflagged": "2 (calibrated 2-D Gaussian)"}


def to_markdown(m: dict, df: pd.DataFrame) -> str:
    lines = ["| metric | value | goal |", "|---|---|---|"]
    for k, v in m.items():
        lines.append(f"| {k} | {v:.3f} | {GOALS.get(k, '')} |" if isinstance(v, float) else f"| {k} | {v} | {GOALS.get(k, '')} |")
    lines += ["", "| grid | kind | trials | within 1 cell | > 3 cells wrong | flagged | flagged of wrong | within DRMS | "
                  "within 2 DRMS | median Mahalanobis^2 unflagged |", "|---|---|---|---|---|---|---|---|---|---|"]
    for (gname, kind), s in df.groupby(["grid", "kind"]):
        w = s["error_cells"] > 3
        lines.append(f"| {gname} | {kind} | {len(s)} | {(s['error_cells'] <= 1).mean():.2f} | {w.sum()} | "
                     f"{s['mismatch'].mean():.2f} | {s['mismatch'][w].mean() if w.any() else float('nan'):.2f} | "
                     f"{(s['error_cells'] <= s['drms_cells']).mean():.2f} | {(s['error_cells'] <= 2 * s['drms_cells']).mean():.2f} | "
                     f"{(s.loc[~s['mismatch'].astype(bool), 'mahalanobis'] ** 2).median():.2f} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--trials", type=int, default=320)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=Path("bench/results"))
    ap.add_argument("--walk", type=float, default=0.03,
                    help="dead-reckoning random walk, cells per sample and axis (0: none, a diagnostic)")
    ap.add_argument("--walk-given", type=float, default=1.0,
                    help="the random walk given to the fix (drift_random_walk) as a multiple of the simulated one "
                         "(1: the navigation's specification known; 0: not modelled, a diagnostic)")
    args = ap.parse_args()
    t0 = time.perf_counter()
    worlds = load_worlds()
    df = run_trials(worlds, args.trials, args.seed, walk_cells=args.walk, walk_given=args.walk_given)
    m = metrics(df)
    args.out.mkdir(parents=True, exist_ok=True)
    df.to_csv(args.out / "calibration_tercom.csv", index=False)
    text = (f"# Posterior terrain fix on real terrain: {args.trials} trials, seed {args.seed}, walk {args.walk:g} cell "
            f"(given x{args.walk_given:g}), "
            f"{time.perf_counter() - t0:.0f} s\n\n" + to_markdown(m, df) + "\n")
    (args.out / "calibration_tercom.md").write_text(text, encoding="utf-8")
    print(text)


if __name__ == "__main__":
    main()
