"""CPU time of the navigation smoother (:func:`hadal.navigation.smoother.smooth_positions`, issue 47) on long
16 Hz dives: the epoch smoother (defaults: a state per 1 s / 5 m of DR travel and per fix, samples interpolated)
against the full-rate smoother in the same run (``epoch_interval_s=0``: a state per sample, the estimates the
epochs reproduce), and with ``--baseline REV`` the smoother module of a git revision (e.g. the one before the
epochs). Printed per size: CPU seconds (``time.process_time``, after a warm-up call that compiles the kernels),
the ratio to the full-rate and baseline smoothers, and the epoch smoother's largest difference from the full-rate
one (mean over 1-sigma, covariance over trace).

The dive: 16 Hz, a descent to 6000 m drifting with a current, a bottom track at 1 m/s dead-reckoned with a
wandering heading, an ascent; fixes: launch, terrain (start of the bottom track), USBL mid-bottom, recovery GNSS.

Run: ``PYTHONPATH=src .venv/bin/python bench/bench_navigation_smoother_speed.py [--sizes 200000 570000]
[--baseline 67092fb]``.

Results (2026-12-06, 2 shared cores busy with other jobs, ``--baseline 67092fb`` = the smoother before the epochs;
CPU seconds):

=========  =========  ==========  =========  ==========  ==============  =============
samples    epochs     full rate   ratio      67092fb     ratio           max |dx| / 1σ
=========  =========  ==========  =========  ==========  ==============  =============
200 000    0.32       4.13        12.9       4.19        13.1            2.8e-6
570 000    0.87       12.34       14.1       12.09       13.8            1.3e-6
=========  =========  ==========  =========  ==========  ==============  =============

(largest covariance difference from the full-rate smoother: 8.7e-4 of the trace). On the full sample dive
(``hadal synth`` seed 20181006, 567 361 samples at 16 Hz, prepared by bench/sample_seeds_tercom.py ``prepare``):
:func:`hadal.products.navigation.smoothed_navigation` 16.0-16.4 s CPU before, 1.4-1.8 s after (3 runs each);
the whole ``match`` stage (which publishes the ``navigation`` product) 25.7 / 25.9 s CPU before, 11.0 / 9.7 s
after (alternating runs).
"""

from __future__ import annotations

import argparse
import importlib.util
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from hadal.navigation.smoother import Fix, smooth_positions
from hadal.settings.navigation import SmootherOptions


def dive(n: int, hz: float = 16.0, seed: int = 0):
    rng = np.random.default_rng(seed)
    t = np.arange(n) / hz
    n1, n2 = n // 3, 2 * n // 3
    depth = np.concatenate([np.linspace(0, 6000, n1), np.full(n2 - n1, 6000.0), np.linspace(6000, 0, n - n2)])
    ref = np.zeros(n, bool)
    ref[n1:n2] = True
    hd = np.cumsum(rng.normal(0, 0.002, n)) + 0.7
    v = np.where(ref, 1.0, 0.0) / hz
    d = np.stack([v * np.sin(hd), v * np.cos(hd)], 1)
    truth = np.cumsum(d + np.where(ref, 0.0, 1.0)[:, None] * np.array([0.15, -0.08]) / hz
                      + rng.normal(0, 0.02, (n, 2)), axis=0)
    spec = [(0, np.eye(2) * 25.0, "launch"), (n1, np.array([[400.0, 100.0], [100.0, 300.0]]), "terrain"),
            ((n1 + n2) // 2, np.eye(2) * 400.0, "usbl"), (n - 1, np.eye(2) * 9.0, "gnss")]
    z = [truth[i] + rng.multivariate_normal([0, 0], R) for i, R, _ in spec]
    fixes = [Fix(i, float(zi[0]), float(zi[1]), R, s) for (i, R, s), zi in zip(spec, z, strict=True)]
    return t, d, ref, fixes, depth


def _baseline(rev: str):
    src = subprocess.run(["git", "show", f"{rev}:src/hadal/navigation/smoother.py"], capture_output=True,
                         text=True, check=True).stdout
    path = Path(tempfile.mkdtemp(prefix="nav_baseline_")) / "smoother_baseline.py"
    path.write_text(src)
    spec = importlib.util.spec_from_file_location("smoother_baseline", path)
    assert spec is not None and spec.loader is not None
    mod = importlib.util.module_from_spec(spec)
    sys.modules["smoother_baseline"] = mod
    spec.loader.exec_module(mod)
    return mod


def _cpu(fn, *args, **kwargs):
    c0 = time.process_time()
    out = fn(*args, **kwargs)
    return time.process_time() - c0, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--sizes", type=int, nargs="+", default=[200_000, 570_000])
    ap.add_argument("--baseline", default=None, help="git revision of the smoother to compare with")
    args = ap.parse_args()
    base = _baseline(args.baseline) if args.baseline else None
    wt, wd, wref, wfix, wdepth = dive(2000)  # warm-up: the kernels compiled (or loaded) before timing
    smooth_positions(wt, wd, wref, wfix, SmootherOptions(), depth_m=wdepth)
    smooth_positions(wt, wd, wref, wfix, SmootherOptions(epoch_interval_s=0), depth_m=wdepth)
    if base is not None:
        base.smooth_positions(wt, wd, wref, wfix, base.SmootherOptions(), depth_m=wdepth)
    print(f"{'samples':>8} {'epoch s':>8} {'full s':>8} {'full/ep':>8} {'base s':>8} {'base/ep':>8} "
          f"{'max dx/sig':>10} {'max dP/tr':>10}")
    for n in args.sizes:
        t, d, ref, fixes, depth = dive(n)
        te, ep = _cpu(smooth_positions, t, d, ref, fixes, SmootherOptions(), depth_m=depth)
        tf, full = _cpu(smooth_positions, t, d, ref, fixes, SmootherOptions(epoch_interval_s=0), depth_m=depth)
        tb = np.nan
        if base is not None:
            tb, _ = _cpu(base.smooth_positions, t, d, ref, fixes, base.SmootherOptions(), depth_m=depth)
        tr = np.trace(full.cov_m2, axis1=1, axis2=2)
        dx = np.hypot(ep.x_m - full.x_m, ep.y_m - full.y_m) / np.sqrt(tr)
        dp = np.abs(ep.cov_m2 - full.cov_m2).max(axis=(1, 2)) / tr
        print(f"{n:>8} {te:>8.2f} {tf:>8.2f} {tf / te:>8.1f} {tb:>8.2f} {tb / te:>8.1f} {dx.max():>10.2e} "
              f"{dp.max():>10.2e}", flush=True)


if __name__ == "__main__":
    main()
