"""Benchmark: the multibeam neighbour spike test (:func:`hadal.grid.multibeam.knn_spike_mask`, exact grid k-NN
fused with the robust plane test) against the same test on scipy ``cKDTree`` neighbours (the code before this
benchmark; ``query(k=17, workers=2)`` then the same compiled plane test), in one run, flags checked equal.

Clouds: the sample dive's multibeam soundings (``--dive``, default ``data/raw/haidou-challenger-deep``; made by
``make demo``), a synthetic trench wall of ``--points`` soundings with 2 % spikes, and the real EX1604 GSF
(``../shared/data/bathy-real``) when present. Each timing is the best of ``--repeat`` runs, wall and CPU (all
threads); the machine may be shared, so compare the ratios of one run. Warm-up calls are not timed.

Run: ``PYTHONPATH=src .venv/bin/python bench/bench_spike_test.py [--points 3000000] [--repeat 3]``
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np

from hadal.geo import LocalFrame
from hadal.grid.multibeam import MAD_TO_SIGMA, _neighbour_chunks, knn_spike_mask


def ckdtree_spike_mask(x, y, z, *, k=4.0, neighbours=16, floor=0.5, chunk=100_000):
    """The previous implementation: scipy cKDTree neighbours (2 workers), then the compiled plane test."""
    from hadal.grid._spike_kernels import knn_spike_flags

    out = np.zeros(len(z), dtype=bool)
    for s0, _, j in _neighbour_chunks(x, y, neighbours, chunk):
        knn_spike_flags(x, y, z, s0, np.ascontiguousarray(j, dtype=np.int64), float(k), float(floor), MAD_TO_SIGMA,
                        out)
    return out


def best_of(fn, repeat: int):
    best, res = (np.inf, np.inf), None
    for _ in range(repeat):
        c0, t0 = time.process_time(), time.perf_counter()
        res = fn()
        best = min(best, (time.perf_counter() - t0, time.process_time() - c0))
    return best, res


def sample_soundings(dive: Path):
    from hadal.dive import load_dive, resolve_source
    from hadal.grid.sonar import iter_multibeam

    d, raw = load_dive(dive)
    frame = d.frame()
    xs, ys, zs = [], [], []
    for f in d.sources.multibeam:
        for ch in iter_multibeam(resolve_source(raw, f)):
            x, y = frame.to_xy(ch["longitude_deg"].to_numpy(), ch["latitude_deg"].to_numpy())
            xs.append(x), ys.append(y), zs.append(ch["depth_m"].to_numpy(np.float64))
    return np.concatenate(xs), np.concatenate(ys), np.concatenate(zs)


def trench_wall(n: int, seed: int = 0):
    rng = np.random.default_rng(seed)
    side = 5.0 * np.sqrt(n)
    x, y = rng.uniform(0, side, n), rng.uniform(0, side, n)
    z = 8000 + 0.4 * x + 60 * np.sin(y / 250) + rng.normal(0, 1.5, n)
    s = rng.random(n) < 0.02
    z[s] += rng.choice([-1, 1], s.sum()) * rng.uniform(20, 200, s.sum())
    return x, y, z


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", type=int, default=3_000_000)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--dive", type=Path, default=Path("data/raw/haidou-challenger-deep"))
    ap.add_argument("--shared", type=Path, default=Path("../shared/data"))
    a = ap.parse_args()
    clouds = {}
    if (a.dive / "dive.yaml").is_file():
        clouds["sample dive multibeam"] = sample_soundings(a.dive)
    else:
        print(f"(no sample dive at {a.dive}: run `make demo`)")
    clouds[f"synthetic trench wall, {a.points:,} soundings"] = trench_wall(a.points)
    gsf = a.shared / "bathy-real" / "0029_20160323_185603_EX1604_MB.gsf.mb121"
    if gsf.is_file():
        from hadal.grid import read_gsf

        df = read_gsf(gsf, include_flagged=True)
        fr = LocalFrame(float(df["latitude_deg"].mean()), float(df["longitude_deg"].mean()))
        gx, gy = fr.to_xy(df["longitude_deg"].to_numpy(), df["latitude_deg"].to_numpy())
        clouds["EX1604 GSF (real)"] = (gx, gy, df["depth_m"].to_numpy(np.float64))
    else:
        print(f"(no {gsf}: real cloud skipped)")
    w = trench_wall(20_000, 1)
    knn_spike_mask(*w), ckdtree_spike_mask(*w)  # compile / warm up
    print(f"{'cloud':44s} {'n':>10s} {'cKDTree wall/CPU s':>20s} {'hadal wall/CPU s':>18s} {'CPU ratio':>9s} flags")
    for name, (x, y, z) in clouds.items():
        x, y, z = (np.ascontiguousarray(v, np.float64) for v in (x, y, z))
        (pw, pc), ref = best_of(lambda x=x, y=y, z=z: ckdtree_spike_mask(x, y, z), a.repeat)
        (hw, hc), got = best_of(lambda x=x, y=y, z=z: knn_spike_mask(x, y, z), a.repeat)
        same = "identical" if np.array_equal(ref, got) else f"{int((ref != got).sum())} differ"
        print(f"{name:44s} {len(z):>10,d} {pw:9.2f} / {pc:6.2f}   {hw:7.2f} / {hc:6.2f}  {hc / pc:9.2f} {same}"
              f" ({int(got.sum())} spikes)")


if __name__ == "__main__":
    main()
