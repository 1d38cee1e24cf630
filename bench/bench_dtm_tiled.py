"""Benchmark (issue 48): the ``dtm`` stage's gridding in memory against out of core, on a dive's multibeam files.

Each variant runs :func:`hadal.stages.grid.make_dtm` (read, project, spike test, grid, fill) in its own fresh child
process, A B B A (so a drifting machine load hits both alike); CPU is the child's user+system time over all its
threads around ``make_dtm`` (imports and numba's start-up, one warm-up call on a few soundings, not counted), peak
RSS its ``VmHWM``. The products' arrays are compared bit for bit (every data variable of the DTM).

    PYTHONPATH=src .venv/bin/python bench/bench_dtm_tiled.py DIVE_DIR   # e.g. `hadal synth /tmp/sample`
    PYTHONPATH=src .venv/bin/python bench/bench_dtm_tiled.py DIVE_DIR --times 4   # a dive 4x denser

Out of core the soundings go to disk chunk by chunk as they are read (:class:`hadal.grid.soundings.
SpilledSoundings`), so the peak RSS of the two variants is the in-memory DTM's against the streamed one's.
``--times K`` lists the dive's multibeam files K times over (a survey K times as dense: the same lines run again).

Decides whether the stage grids out of core always (identical and no dearer) or only above the memory budget.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np


def vm_hwm_bytes() -> int:
    for line in Path("/proc/self/status").read_text().splitlines():
        if line.startswith("VmHWM:"):
            return int(line.split()[1]) * 1024
    return -1


def child(dive_dir: Path, variant: str, out: Path, times: int = 1) -> None:
    from hadal.dive import load_dive, resolve_source
    from hadal.settings.pipeline import load_config
    from hadal.stages.grid import make_dtm

    dive, raw = load_dive(dive_dir)
    cfg = load_config(raw / "pipeline.yaml" if (raw / "pipeline.yaml").exists() else None)
    files = [resolve_source(raw, sf) for sf in dive.sources.multibeam] * times
    hints = list(dive.sources.multibeam) * times
    frame = dive.frame("grid")
    tiled = variant == "tiled"
    make_dtm(files[:1], frame, cfg.grid, hints[:1], out_of_core=tiled)  # warm-up: kernels loaded
    c0, t0 = time.process_time(), time.perf_counter()
    ds = make_dtm(files, frame, cfg.grid, hints, out_of_core=tiled)
    cpu, wall = time.process_time() - c0, time.perf_counter() - t0
    np.savez(out, **{v: ds[v].values for v in ds.data_vars if ds[v].ndim == 2})
    print(json.dumps({"variant": variant, "cpu_s": cpu, "wall_s": wall, "peak_rss": vm_hwm_bytes(),
                      "soundings": int(ds.attrs["n_soundings_input"]), "spikes": int(ds.attrs["n_soundings_spikes"]),
                      "cells": int(ds.sizes["x"] * ds.sizes["y"]), "tiles": ds.attrs.get("n_tiles")}))


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("dive")
    ap.add_argument("--repeats", type=int, default=1, help="A B B A rounds")
    ap.add_argument("--times", type=int, default=1, help="list the dive's multibeam files this many times over")
    ap.add_argument("--child", default=None, help=argparse.SUPPRESS)
    ap.add_argument("--out", default=None, help=argparse.SUPPRESS)
    a = ap.parse_args(argv)
    if a.child:
        child(Path(a.dive), a.child, Path(a.out), a.times)
        return 0
    rows: dict[str, list[dict]] = {"memory": [], "tiled": []}
    with tempfile.TemporaryDirectory(prefix="hadal-bench-dtm-") as td:
        for _ in range(a.repeats):
            for v in ("memory", "tiled", "tiled", "memory"):
                out = Path(td) / f"{v}.npz"
                r = subprocess.run([sys.executable, __file__, a.dive, "--child", v, "--out", str(out),
                                    "--times", str(a.times)],
                                   capture_output=True, text=True)
                if r.returncode:
                    raise SystemExit(f"{v} failed:\n{r.stderr[-3000:]}")
                rows[v].append(json.loads(r.stdout.strip().splitlines()[-1]))
        m, t = np.load(Path(td) / "memory.npz"), np.load(Path(td) / "tiled.npz")
        same = {k: bool(np.array_equal(m[k], t[k], equal_nan=True)) for k in m.files}
    r0 = rows["memory"][0]
    print(f"dtm of {a.dive}: {r0['soundings']:,} soundings, {r0['spikes']:,} spikes, {r0['cells']:,} cells; "
          f"tiled in {rows['tiled'][0]['tiles']} tiles")
    for v, rs in rows.items():
        cpu = [r["cpu_s"] for r in rs]
        print(f"  {v:7s} CPU {np.median(cpu):6.2f} s (runs {', '.join(f'{c:.2f}' for c in cpu)}), "
              f"peak RSS {max(r['peak_rss'] for r in rs) / 2**20:.0f} MiB")
    ratio = np.median([r["cpu_s"] for r in rows["tiled"]]) / np.median([r["cpu_s"] for r in rows["memory"]])
    rss = max(r["peak_rss"] for r in rows["tiled"]) / max(r["peak_rss"] for r in rows["memory"])
    print(f"  tiled / in memory: CPU {ratio:.2f}x, peak RSS {rss:.2f}x")
    print("  arrays: " + ("all identical" if all(same.values()) else
                          ", ".join(f"{k} {'identical' if s else 'DIFFER'}" for k, s in same.items())))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
