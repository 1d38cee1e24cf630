"""Is the stated dead-reckoning-only uncertainty honest? Coverage of the navigation product's 1-/2-sigma on
generated dives (issue 18 item, issue 16 bench family).

For each generator seed (``hadal synth --small --seed S``, prepared by bench/sample_seeds_tercom.py's
``prepare`` and kept in ``--work``), the navigation table is built from ``ctd`` alone (no match: launch +
dead-reckoned offsets, :func:`hadal.products.navigation.navigation_table`) and compared with the generator's
true track (``truth/track.parquet``). Printed per phase: the median radial error, the median stated 1-sigma
radial uncertainty (DRMS) and the fractions of samples whose error lies within 1 and 2 sigma (for a circular
2-D Gaussian and DRMS: 63 % and 98 %; the issue asks ~68 % / ~95 %). With ``--match`` the same for the
navigation product published by ``match`` (the matched start corrects the descent and the ascent).

Run: ``PYTHONPATH=src .venv/bin/python bench/dr_uncertainty_tercom.py [--seeds 20181006 1 2] [--work DIR]``
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


def _seconds(s) -> np.ndarray:
    return pd.to_datetime(s, utc=True).astype("int64").to_numpy() / 1e9


def errors(d: Path, nav: pd.DataFrame | None = None, **model) -> pd.DataFrame:
    """Per-sample radial error of the (DR-only unless ``nav`` is given) navigation table against the truth."""
    from hadal.pipeline import make_context
    from hadal.products.navigation import navigation_table
    from hadal.stages.match import read_ctd

    ctx = make_context(d / "dive", d / "store")
    ctd = read_ctd(ctx.store.latest(ctx.dive_id, "ctd"))
    if nav is None:
        nav = navigation_table(ctd, ctx.dive.frame(), ctx.dive.launch.latitude_deg, ctx.dive.launch.longitude_deg,
                               **model)
    tr = pd.read_parquet(d / "dive" / "truth" / "track.parquet")
    tt, tn = _seconds(tr["time"]), _seconds(nav["time"])
    ex = nav["x_east_m"].to_numpy() - np.interp(tn, tt, tr["x_east_m"])
    ey = nav["y_north_m"].to_numpy() - np.interp(tn, tt, tr["y_north_m"])
    e = ctd["dr_east_m"].ffill().fillna(0.0).to_numpy()
    n = ctd["dr_north_m"].ffill().fillna(0.0).to_numpy()
    return pd.DataFrame({"phase": ctd["phase"].astype(str).to_numpy(), "error_m": np.hypot(ex, ey),
                         "sigma_m": nav["position_uncertainty_m"].to_numpy(float), "ex_m": ex, "ey_m": ey,
                         "dr_dist_m": np.cumsum(np.hypot(np.diff(e, prepend=e[:1]), np.diff(n, prepend=n[:1])))})


def bottom_fraction(e: pd.DataFrame) -> float:
    """DR-only error grown along the bottom track per distance dead-reckoned (end minus start of the bottom)."""
    b = np.flatnonzero(e["phase"].to_numpy() == "bottom")
    i, j = b[0], b[-1]
    grown = np.hypot(e["ex_m"].iloc[j] - e["ex_m"].iloc[i], e["ey_m"].iloc[j] - e["ey_m"].iloc[i])
    return float(grown / (e["dr_dist_m"].iloc[j] - e["dr_dist_m"].iloc[i]))


def summary(e: pd.DataFrame) -> dict:
    r = e["error_m"] / e["sigma_m"]
    return {"n": len(e), "median_error_m": float(e["error_m"].median()), "median_sigma_m": float(e["sigma_m"].median()),
            "within_1sigma": float((r <= 1).mean()), "within_2sigma": float((r <= 2).mean())}


def matched_nav(d: Path) -> pd.DataFrame:
    from hadal.pipeline import make_context
    from hadal.stages import match as ms

    ctx = make_context(d / "dive", d / "store")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = ms.run(ctx)
    return pd.read_parquet(out["navigation"].file("navigation.parquet"))


def main() -> None:
    from sample_seeds_tercom import prepare

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[20181006, 1, 2])
    ap.add_argument("--work", type=Path, default=Path("/tmp/hadal-sample-seeds"))
    ap.add_argument("--match", action="store_true", help="also the navigation product published by match")
    args = ap.parse_args()
    kinds = ["dr_only"] + (["matched"] if args.match else [])
    allrows: dict[str, list[pd.DataFrame]] = {k: [] for k in kinds}
    fractions = []
    print("| seed | navigation | phase | median error m | median 1-sigma m | within 1 sigma | within 2 sigma |")
    print("|---|---|---|---|---|---|---|")
    for seed in args.seeds:
        d = prepare(args.work, seed)
        for kind in kinds:
            e = errors(d) if kind == "dr_only" else errors(d, matched_nav(d))
            allrows[kind].append(e)
            if kind == "dr_only":
                fractions.append(bottom_fraction(e))
            for ph in ("descent", "bottom", "ascent", "all"):
                s = summary(e if ph == "all" else e[e["phase"] == ph])
                print(f"| {seed} | {kind} | {ph} | {s['median_error_m']:.0f} | {s['median_sigma_m']:.0f} | "
                      f"{100 * s['within_1sigma']:.0f} % | {100 * s['within_2sigma']:.0f} % |", flush=True)
    for kind in kinds:
        s = summary(pd.concat(allrows[kind]))
        print(f"\n{kind}, all seeds: within 1 sigma {100 * s['within_1sigma']:.1f} %, within 2 sigma "
              f"{100 * s['within_2sigma']:.1f} % (median error {s['median_error_m']:.0f} m, median sigma "
              f"{s['median_sigma_m']:.0f} m)")
    print("\nDR-only error grown along the bottom track / distance dead-reckoned: "
          + ", ".join(f"{100 * f:.2f} %" for f in fractions) + f" (max {100 * max(fractions):.2f} %)")
    print(json.dumps({"seeds": args.seeds}))


if __name__ == "__main__":
    main()
