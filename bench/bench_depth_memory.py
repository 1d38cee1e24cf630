"""Peak memory of ``hydrostatic_depth``, ``sigma_theta`` and ``sigma_t`` on a long series, as a ratio to the output.

Issue 17 §4 goal: each <= 3x the output array (8 bytes a sample). Peak = ``tracemalloc`` peak of the call (NumPy
reports its array allocations to ``tracemalloc``), inputs allocated before tracing. The TEOS-10 peers
(``gsw.z_from_p``, ``gsw.sigma0`` from SA/CT) are measured in the same run on the same samples, for comparison.

    PYTHONPATH=src .venv/bin/python bench/bench_depth_memory.py [n_samples, default 10_000_000]
"""

from __future__ import annotations

import sys
import time
import tracemalloc

import numpy as np

from hadal import seawater as sw
from hadal.depth import hydrostatic_depth

LAT = 11.33


def series(n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A full-ocean-depth dive's pressure (dbar), practical salinity and ITS-90 temperature."""
    rng = np.random.default_rng(0)
    p = np.abs(11_000.0 * np.sin(np.linspace(0.0, np.pi, n))) + rng.normal(0, 0.05, n)
    t = 1.5 + 27.5 * np.exp(-p / 400.0)
    sp = 34.7 - 0.5 * np.exp(-p / 300.0)
    return p, sp, t


def measure(fn, *args, **kw) -> tuple[float, float, np.ndarray]:
    tracemalloc.start()
    tracemalloc.reset_peak()
    t0 = time.perf_counter()
    out = fn(*args, **kw)
    dt = time.perf_counter() - t0
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak, dt, out


def main() -> None:
    n = int(float(sys.argv[1])) if len(sys.argv) > 1 else 10_000_000
    p, sp, t = series(n)
    out_bytes = n * 8
    rho = sw.density_eos80(sp, t, p)
    cases = [
        ("hydrostatic_depth (density computed)", lambda: hydrostatic_depth(p, sp, t, LAT)),
        ("hydrostatic_depth (density passed)", lambda: hydrostatic_depth(p, sp, t, LAT, density_kg_m3=rho)),
        ("sigma_theta", lambda: sw.sigma_theta(sp, t, p)),
        ("sigma_t", lambda: sw.sigma_t(sp, t)),
    ]
    try:
        import gsw

        sa = gsw.SA_from_SP(sp, p, 142.2, LAT)
        ct = gsw.CT_from_t(sa, t, p)
        cases += [("peer gsw.z_from_p", lambda: gsw.z_from_p(p, LAT)), ("peer gsw.sigma0", lambda: gsw.sigma0(sa, ct))]
    except ImportError:
        pass
    print(f"{n:,} samples, output {out_bytes / 2**20:.0f} MiB; goal: hadal peak <= 3x output (machine may be shared)")
    print(f"{'function':40} {'peak MiB':>9} {'x output':>9} {'s':>6}")
    for name, fn in cases:
        peak, dt, _ = measure(fn)
        print(f"{name:40} {peak / 2**20:9.0f} {peak / out_bytes:9.2f} {dt:6.2f}")


if __name__ == "__main__":
    main()
