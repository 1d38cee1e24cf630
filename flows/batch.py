"""Batch flow: process several dives in parallel on a Dask cluster (prefect-dask ``DaskTaskRunner``).

Each dive's stages start when the stages they read from are done (``grid`` beside ``ingest``/``derive``) and read
the upstream versions pinned for that dive; different dives run concurrently on the cluster's workers. By
default a ``dask.distributed.LocalCluster`` with ``workers`` single-threaded worker processes is started for the
run; pass ``scheduler="tcp://host:8786"`` to use an existing cluster (every worker must see the same raw directories and store, e.g. on a
shared filesystem, and have hadal installed). A failing dive does not stop the others: its error is
returned in the result.
"""

from __future__ import annotations

import logging
import time
from typing import Any

from hadal.flows.post_cruise import DiveRun, collect_dives, submit_dive
from hadal.tasks.stage import route_hadal_logs
from prefect import flow
from prefect.context import FlowRunContext

from hadal.errors import HadalError
from hadal.pipeline import all_products, make_context, stage_plan

log = logging.getLogger("hadal.batch")


def dask_runner(workers: int = 2, scheduler: str | None = None, threads_per_worker: int = 1, processes: bool = True):
    """A DaskTaskRunner on ``scheduler`` (an existing cluster) or on a new LocalCluster of ``workers``
    worker processes (``processes=False``: threads in this process, cheaper to start, GIL-bound)."""
    from prefect_dask import DaskTaskRunner

    if scheduler:
        return DaskTaskRunner(address=scheduler)
    return DaskTaskRunner(cluster_kwargs={"n_workers": int(workers), "threads_per_worker": int(threads_per_worker),
                                          "processes": bool(processes), "dashboard_address": ":0"})


@flow(name="post-cruise-batch")
def post_cruise_batch(
    raw_dirs: list[str],
    store_root: str | None = None,
    config_path: str | None = None,
    stages: list[str] | None = None,
    force: bool = False,
) -> dict[str, dict[str, Any]]:
    """Run the selected stages on every dive; returns ``{raw_dir: {"ok": bool, "published"|"error": ...,
    "stages": [...]}}``.

    Every dive's stage graph is handed to the flow's (Dask) task runner as the single-dive flow does
    (:func:`hadal.flows.post_cruise.submit_dive`, shared): a stage starts when the stages it reads from are done, and every stage of a dive reads the upstream versions the batch found at its
    start or published itself for that dive (pins), never a concurrent run's newer ones (issue 14, class 9).
    One line per finished dive (progress); a failing dive does not stop the others."""
    route_hadal_logs()
    runs: list[DiveRun] = []
    results: dict[str, dict[str, Any]] = {}
    for raw in raw_dirs:
        try:
            ctx = make_context(raw, store_root, config_path)
            names = [ps.name for ps in stage_plan(ctx, stages) if ps.run]
        except HadalError as exc:  # this dive cannot be planned; the others still run
            results[raw] = {"ok": False, "published": {}, "error": str(exc), "stages": []}
            _progress(f"{raw}: {exc}")
            continue
        ctx.pin_existing(all_products())
        runs.append(DiveRun(raw, names, {p: str(pv.path) for p, pv in ctx.pins.items()}))
    total = len(runs)
    finished: list[str] = []

    def done(d: DiveRun) -> None:
        finished.append(d.raw_dir)
        n = len(finished)
        error = "; ".join(f"stage {k}: {v}" for k, v in d.failed.items()) or None
        results[d.raw_dir] = ({"ok": True, "published": dict(d.published), "stages": d.rows} if error is None else
                              {"ok": False, "published": dict(d.published), "error": error, "stages": d.rows})
        counts = {s: sum(1 for r in d.rows if r["status"] == s) for s in ("published", "reused", "failed")}
        _progress(f"[{n}/{total}] {d.raw_dir}: {'ok' if error is None else 'FAILED ' + error} "
              f"({counts['published']} published, {counts['reused']} reused, {counts['failed']} failed; "
              f"{time.monotonic() - d.t0:.0f} s)")

    run_ctx = FlowRunContext.get()
    runner = run_ctx.task_runner if run_ctx is not None else None
    for d in runs:
        submit_dive(runner, d, store_root, config_path, force)
    collect_dives(runs, store_root, config_path, on_dive_done=done)
    return {raw: results[raw] for raw in raw_dirs if raw in results}


def _progress(line: str) -> None:
    """One progress line: on stdout (also when Prefect's console logging is quiet) and in the flow run's log."""
    print(line, flush=True)
    log.info("%s", line)


def run_batch(raw_dirs: list[str], store_root: str | None = None, config_path: str | None = None,
              stages: list[str] | None = None, workers: int = 2, scheduler: str | None = None,
              force: bool = False, processes: bool = True) -> dict[str, dict[str, Any]]:
    """Run :func:`post_cruise_batch` with a Dask task runner (LocalCluster or ``scheduler`` address)."""
    runner = dask_runner(workers, scheduler, processes=processes)
    return post_cruise_batch.with_options(task_runner=runner)(
        [str(r) for r in raw_dirs], store_root, config_path, stages, force)
