"""Benchmark (issue 48): the cruise DTM on Dask, 1 worker against 2 (the peer: the same flow on one worker, in the
same run), and the serial in-process science (:func:`hadal.grid.cruise.cruise_dtm_dataset` with ``serial_map``)
as the floor of the cost.

``--dives`` synthetic dives (tests/unit/grid/test_cruise_dtm.py ``write_cruise_dive``: two gzip xyz lines of ``--soundings``
lon/lat/depth soundings each) are written once; then, alternated ``--repeat`` times: the cruise flow
(:func:`hadal.flows.cruise.cruise_dtm`) on a ``LocalCluster`` of 1 and of 2 single-threaded worker processes
started by the bench (its address passed as ``scheduler``, so cluster start-up is not timed; one temporary Prefect
API for the whole bench), and the serial
science. Wall time of the call; CPU = this process's user+system time plus the worker processes' (psutil, read
before the cluster is closed; reaped children included), the workers warmed up untimed (imports, kernels: a
long-lived cluster's state), each as a delta over the call (the Prefect API server's own CPU is not counted).
Prints one JSON line per measure and the ratios (wall 1 worker / 2 workers: the speed-up;
CPU 2 workers / serial: the distribution's overhead).

Run::

    PYTHONPATH=src:. .venv/bin/python bench/bench_cruise_dtm.py [--dives 4] [--soundings 400000] [--repeat 2]

Goal (issue 48): 2 workers >= 1.7x faster than 1 on an idle machine (the machine may be shared: report the load).
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import tempfile
import time
from pathlib import Path

import _tests_path  # noqa: F401

REPO = Path(__file__).resolve().parents[1]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))


def _cruise_flow():
    try:
        from hadal.flows.cruise import cruise_dtm
    except ImportError:  # a worktree whose installed hadal.flows is another tree's
        from flows.cruise import cruise_dtm
    return cruise_dtm


def _cpu_self() -> float:
    """This process's CPU seconds, its reaped children's included (readers may work in forked children)."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def _workers_cpu(client) -> float:
    def cpu() -> float:
        import psutil

        c = psutil.Process().cpu_times()
        return c.user + c.system + c.children_user + c.children_system

    return float(sum(client.run(cpu).values()))


def _warm(raw: str, scratch: str, resolution_m: float) -> None:
    """The serial science on one dive in a worker (imports, numba kernels), in its own scratch directory."""
    import uuid

    from hadal.grid.cruise import cruise_dtm_dataset

    d = Path(scratch) / uuid.uuid4().hex[:8]
    d.mkdir(parents=True)
    cruise_dtm_dataset([raw], resolution_m, d)


def run_flow(raws: list[str], root: Path, workers: int, resolution_m: float, k: int, tile_cells: int) -> dict:
    from distributed import Client, LocalCluster

    with LocalCluster(n_workers=workers, threads_per_worker=1, processes=True, dashboard_address=":0") as cl, \
            Client(cl) as client:
        # a long-lived cluster's workers have imported hadal and compiled its kernels: warm them up untimed
        client.run(_warm, raws[0], str(root / f"warm-{workers}-{k}"), resolution_m)
        w0, c0, t0 = _workers_cpu(client), _cpu_self(), time.perf_counter()
        _cruise_flow()(raws, str(root / f"store-{workers}-{k}"), "BENCH", resolution_m, scheduler=cl.scheduler_address,
                       tile_cells=tile_cells)
        wall = time.perf_counter() - t0
        main_cpu, workers_cpu = _cpu_self() - c0, _workers_cpu(client) - w0
    return {"measure": f"flow_{workers}_workers", "wall_s": round(wall, 3), "cpu_s": round(main_cpu + workers_cpu, 3),
            "cpu_main_s": round(main_cpu, 3), "cpu_workers_s": round(workers_cpu, 3)}


def run_serial(raws: list[str], root: Path, resolution_m: float, k: int, tile_cells: int) -> dict:
    from hadal.grid.cruise import cruise_dtm_dataset

    scratch = root / f"scratch-serial-{k}"
    scratch.mkdir()
    c0, t0 = _cpu_self(), time.perf_counter()
    cruise_dtm_dataset(raws, resolution_m, scratch, tile_cells=tile_cells)
    return {"measure": "serial_science", "wall_s": round(time.perf_counter() - t0, 3),
            "cpu_s": round(_cpu_self() - c0, 3)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dives", type=int, default=4)
    ap.add_argument("--soundings", type=int, default=400_000, help="soundings per line (2 lines a dive)")
    ap.add_argument("--resolution", type=float, default=5.0)
    ap.add_argument("--tile-cells", type=int, default=128, help="tile side (cells): the units of work of the reduce")
    ap.add_argument("--repeat", type=int, default=2)
    a = ap.parse_args()
    os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
    from prefect.testing.utilities import prefect_test_harness
    from test_cruise_dtm import write_cruise_dive

    # one temporary Prefect API for the whole bench (else every flow call starts its own, timed)
    with tempfile.TemporaryDirectory(prefix="hadal-bench-cruise-") as tmp, \
            prefect_test_harness(server_startup_timeout=120):
        root = Path(tmp)
        raws = [str(write_cruise_dive(root / f"dive-{k}", f"D{k:03d}", (11.33 + 0.012 * (k % 2), 142.2 + 0.015 * k),
                                      seed=k, n=a.soundings)) for k in range(a.dives)]
        print(json.dumps({"dives": a.dives, "soundings": 2 * a.soundings * a.dives, "cpus": os.cpu_count(),
                          "loadavg": os.getloadavg()}), flush=True)
        # warm-up: numba compilation and imports in this process, out of the timed runs
        run_serial(raws[:1], root, a.resolution, -1, a.tile_cells)
        rows: dict[str, list[dict]] = {}
        for k in range(a.repeat):
            for r in (run_flow(raws, root, 1, a.resolution, k, a.tile_cells),
                      run_flow(raws, root, 2, a.resolution, k, a.tile_cells),
                      run_serial(raws, root, a.resolution, k, a.tile_cells)):
                rows.setdefault(r["measure"], []).append(r)
                print(json.dumps(r), flush=True)
        best = {m: {q: min(r[q] for r in rs) for q in ("wall_s", "cpu_s")} for m, rs in rows.items()}
        print(json.dumps({
            "speedup_wall_2_vs_1_workers": round(best["flow_1_workers"]["wall_s"] / best["flow_2_workers"]["wall_s"], 3),
            "cpu_ratio_2_vs_1_workers": round(best["flow_2_workers"]["cpu_s"] / best["flow_1_workers"]["cpu_s"], 3),
            "cpu_ratio_2_workers_vs_serial": round(best["flow_2_workers"]["cpu_s"] / best["serial_science"]["cpu_s"], 3),
            "loadavg_end": os.getloadavg(), "goal": "speed-up >= 1.7 on an idle machine"}), flush=True)


if __name__ == "__main__":
    main()
