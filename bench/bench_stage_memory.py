"""Peak RSS and CPU of every stage, each in its own process, on the sample dive scaled ×1 and ×N (issue 48).

The ×N sample dive is the seeded sample (:func:`hadal.synth.generate_dive`) with every sensor rate ×N and the
multibeam ping spacing ÷N (the scaling the issue's measurements used). Each stage then runs in a fresh interpreter
(``run_pipeline(ctx, [stage])`` on one store, in the stage graph's order, so each reads its upstream products;
after one untimed run of every stage, which compiles the numba caches) and
reports its own ``getrusage`` peak RSS (the larger of itself and any child it waited for) and its CPU seconds
(user + system, itself and its children). The flow as a user runs it (``hadal run`` in a fresh process, every stage)
is measured the same way when ``--flow`` is given. The ×1 row is the peer of the ×N row in the same run: the ratio
column is the ×N stage's CPU over its ×1 CPU.

    PYTHONPATH=src .venv/bin/python bench/bench_stage_memory.py [--scales 1,10] [--stages ingest,derive] [--flow]
    PYTHONPATH=src .venv/bin/python bench/bench_stage_memory.py --keep DIR   # dives and stores kept in DIR (reused)
    PYTHONPATH=src .venv/bin/python bench/bench_stage_memory.py --sensors-only --stages ingest,derive
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]

GENERATE = textwrap.dedent("""
    import dataclasses, sys
    from hadal.synth import generate as g, sensors as s
    k, k_mb = float(sys.argv[2]), float(sys.argv[3])
    s.FULL_RATES_HZ = {name: hz * k for name, hz in s.FULL_RATES_HZ.items()}
    g.FULL_MB = dataclasses.replace(g.FULL_MB, ping_spacing_m=g.FULL_MB.ping_spacing_m / k_mb)
    g.generate_dive(sys.argv[1])
""")

RUN_STAGE = textwrap.dedent("""
    import json, logging, os, resource, sys, warnings
    warnings.simplefilter("ignore")
    logging.disable(logging.WARNING)
    from hadal.pipeline import make_context, run_pipeline
    raw, store, stage = sys.argv[1:4]
    run_pipeline(make_context(raw, store), [stage])
    me, ch = resource.getrusage(resource.RUSAGE_SELF), resource.getrusage(resource.RUSAGE_CHILDREN)
    print(json.dumps({"peak": max(me.ru_maxrss, ch.ru_maxrss) * 1024,
                      "cpu": me.ru_utime + me.ru_stime + ch.ru_utime + ch.ru_stime}))
""")

RUN_FLOW = textwrap.dedent("""
    import json, resource, subprocess, sys
    subprocess.run([sys.executable, "-m", "hadal.cli", "run", sys.argv[1], "--store", sys.argv[2]], check=True,
                   stdout=subprocess.DEVNULL)
    ch = resource.getrusage(resource.RUSAGE_CHILDREN)
    print(json.dumps({"peak": ch.ru_maxrss * 1024, "cpu": ch.ru_utime + ch.ru_stime}))
""")


def _child(code: str, *args: str, src: Path = REPO / "src") -> dict:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(src), os.environ.get("PYTHONPATH", "")]),
           "HADAL_PROGRESS": "0", "PREFECT_LOGGING_LEVEL": "WARNING"}
    out = subprocess.run([sys.executable, "-c", code, *args], env=env, check=True, capture_output=True, text=True)
    lines = [ln for ln in out.stdout.splitlines() if ln.startswith("{")]
    return json.loads(lines[-1]) if lines else {}


def sample_dive(work: Path, scale: float, multibeam: bool = True) -> Path:
    """The sample dive with every sensor rate x ``scale`` and, with ``multibeam``, the ping spacing / ``scale``."""
    raw = work / (f"sample-x{scale:g}" + ("" if multibeam else "-mbx1"))
    if not (raw / "dive.yaml").is_file():
        _child(GENERATE, str(raw), str(scale), str(scale if multibeam else 1.0))
    return raw


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--scales", default="1,10", help="comma-separated scale factors (first one is the peer)")
    ap.add_argument("--stages", default="", help="comma-separated stages (default: every stage the dive supports)")
    ap.add_argument("--flow", action="store_true", help="also the whole flow (hadal run) in one fresh process")
    ap.add_argument("--sensors-only", action="store_true",
                    help="scale only the sensor rates (multibeam as in the x1 sample: for ingest/derive, quicker)")
    ap.add_argument("--peer", type=Path, help="another source tree (its src/ directory, e.g. a `git archive` of "
                    "main) run on its own store, each stage alternating with this tree's: the before/after ratios")
    ap.add_argument("--no-warmup", action="store_true", help="skip the untimed first run of each stage and tree "
                    "(at the first scale: it compiles each tree's numba caches)")
    ap.add_argument("--raw", type=Path, help="measure this raw dive directory as the (one) scale given by --scales "
                    "(e.g. a scaled sample made earlier, or its MCAP log alone for ingest/derive)")
    ap.add_argument("--keep", type=Path, help="directory for the dives and stores (kept; dives reused)")
    args = ap.parse_args()
    sys.path.insert(0, str(REPO / "src"))
    from hadal.stages.plan import resolve_stages

    stages = [s for s in args.stages.split(",") if s] or resolve_stages(None)
    scales = [float(s) for s in args.scales.split(",")]
    work = args.keep or Path(tempfile.mkdtemp(prefix="hadal-stage-mem-"))
    work.mkdir(parents=True, exist_ok=True)
    rows: dict[str, dict[float, dict]] = {}
    try:
        for k in scales:
            raw = args.raw if args.raw else sample_dive(work, k, multibeam=not args.sensors_only)
            mcap = raw / "logs" / "haidou.mcap"
            print(f"x{k:g}: {raw} (MCAP {mcap.stat().st_size / 2**20:.0f} MiB)", flush=True)
            trees = [("", REPO / "src")] + ([(" (peer)", args.peer)] if args.peer else [])
            for tag, _src in trees:
                shutil.rmtree(work / f"store-x{k:g}{tag.strip(' ()')}", ignore_errors=True)
            if k == scales[0] and not args.no_warmup:
                for tag, src in trees:
                    warm = work / f"store-warmup{tag.strip(' ()')}"
                    shutil.rmtree(warm, ignore_errors=True)
                    for s in stages:
                        _child(RUN_STAGE, str(raw), str(warm), s, src=src)
                    shutil.rmtree(warm, ignore_errors=True)
            for s in stages:
                for tag, src in trees:
                    store = work / f"store-x{k:g}{tag.strip(' ()')}"
                    rows.setdefault(s + tag, {})[k] = r = _child(RUN_STAGE, str(raw), str(store), s, src=src)
                    print(f"  {s + tag:18} peak {r['peak'] / 2**30:6.2f} GiB  cpu {r['cpu']:7.1f} s", flush=True)
                if args.peer:
                    a, b = rows[s][k], rows[s + " (peer)"][k]
                    print(f"  {s:18} this/peer: peak {a['peak'] / b['peak']:.2f}x, cpu {a['cpu'] / b['cpu']:.2f}x",
                          flush=True)
            if args.flow:
                fstore = work / f"store-flow-x{k:g}"
                shutil.rmtree(fstore, ignore_errors=True)
                rows.setdefault("flow (hadal run)", {})[k] = r = _child(RUN_FLOW, str(raw), str(fstore))
                print(f"  {'flow':12} peak {r['peak'] / 2**30:6.2f} GiB  cpu {r['cpu']:7.1f} s", flush=True)
        head = "".join(f"{'peak GiB x' + format(k, 'g'):>15}{'CPU s x' + format(k, 'g'):>12}" for k in scales)
        print(f"\n{'stage':25}{head}{'CPU ratio':>11}")
        for s, by in rows.items():
            cells = "".join(f"{by[k]['peak'] / 2**30:15.2f}{by[k]['cpu']:12.1f}" for k in scales if k in by)
            ratio = by[scales[-1]]["cpu"] / by[scales[0]]["cpu"] if len(by) > 1 and by[scales[0]]["cpu"] else float("nan")
            print(f"{s:25}{cells}{ratio:11.2f}")
    finally:
        if args.keep is None:
            shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
