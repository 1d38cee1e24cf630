"""Same-run A/B of the cold full sample dive: ``hadal run`` of this working tree against git revision ``REV``.

    PYTHONPATH=src:. .venv/bin/python bench/bench_cold_ab.py --rev HEAD~1 [--runs 2] [--raw DIR] [--small]

Each code gets one untimed run first (a snapshot compiles its numba kernels' caches), then ``--runs`` cold full
dives each (a fresh store and a fresh PREFECT_HOME each, the temporary Prefect server as a user gets it), the two
codes alternating run by run so that a machine that slows down or speeds up meanwhile affects both alike. Measured
per run: wall time and CPU time (user + system of ``hadal`` and every process it waited for: stage processes,
forked figure processes, the temporary server; ``resource.getrusage(RUSAGE_CHILDREN)``). Printed: each run, the
means and the ratios ``REV / now`` (above 1: this tree is faster). Used for issue 44's "keep a performance device
only where it pays >= 10 % of the cold sample dive".
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_pipeline import _snapshot, make_dive  # noqa: E402


def _cpu_children_s() -> float:
    ru = resource.getrusage(resource.RUSAGE_CHILDREN)
    return ru.ru_utime + ru.ru_stime


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rev", required=True, help="git revision to compare this working tree with")
    ap.add_argument("--runs", type=int, default=2, help="timed cold full dives per code (alternating)")
    ap.add_argument("--raw", help="an existing sample dive directory (default: generate the full sample dive)")
    ap.add_argument("--small", action="store_true", help="the small sample dive (a quick check, not the A/B)")
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="hadal-bench-ab-"))
    py = sys.executable
    try:
        codes = {"now": _snapshot(work / "code-now", None), args.rev: _snapshot(work / "code-old", args.rev)}
        raw = Path(args.raw) if args.raw else make_dive(work / "raw" / "sample", args.small)[0]

        def hadal(code: str, tag: str) -> tuple[float, float]:
            env = {**os.environ, "PYTHONPATH": str(codes[code]), "HADAL_PROGRESS": "0",
                   "PREFECT_HOME": str(work / f"prefect-home-{code}-{tag}"), "PREFECT_SERVER_ANALYTICS_ENABLED": "false"}
            env.pop("PREFECT_API_URL", None)
            store = work / f"store-{code}-{tag}"
            c0, t0 = _cpu_children_s(), time.perf_counter()
            res = subprocess.run([py, "-m", "hadal.cli", "run", str(raw), "--store", str(store)], env=env,
                                 capture_output=True, text=True, timeout=3600)
            wall, cpu = time.perf_counter() - t0, _cpu_children_s() - c0
            if res.returncode != 0:
                print(f"  ({code} exit {res.returncode}: {res.stderr.strip()[-500:]})", flush=True)
            shutil.rmtree(store, ignore_errors=True)
            return wall, cpu

        print(f"dive {raw}; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores", flush=True)
        for code in codes:
            hadal(code, "warmup")
        times: dict[str, list[tuple[float, float]]] = {c: [] for c in codes}
        for i in range(args.runs):
            for code in (codes if i % 2 == 0 else list(codes)[::-1]):
                times[code].append(hadal(code, f"run{i}"))
            print(f"  run {i + 1}: " + ", ".join(f"{c} wall {times[c][-1][0]:.1f} s cpu {times[c][-1][1]:.1f} s"
                                                 for c in codes) + f" (load {os.getloadavg()[0]:.1f})", flush=True)
        mean = {c: (sum(w for w, _ in v) / len(v), sum(u for _, u in v) / len(v)) for c, v in times.items()}
        for c in codes:
            print(f"{c:>10s}: mean wall {mean[c][0]:.1f} s, mean cpu {mean[c][1]:.1f} s over {args.runs} run(s)")
        print(f"ratio {args.rev}/now: wall {mean[args.rev][0] / mean['now'][0]:.3f}, "
              f"cpu {mean[args.rev][1] / mean['now'][1]:.3f} (below 1: {args.rev} faster)", flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
