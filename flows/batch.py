"""Batch flow: process several dives in parallel on a Dask cluster (prefect-dask ``DaskTaskRunner``).

Each dive's stages are chained (a stage waits for the previous one of the same dive); different dives
run concurrently on the cluster's workers. By default a ``dask.distributed.LocalCluster`` with
``workers`` single-threaded worker processes is started for the run; pass ``scheduler="tcp://host:8786"``
to use an existing cluster (every worker must see the same raw directories and store, e.g. on a
shared filesystem, and have hadal installed). A failing dive does not stop the others: its error is
returned in the result.
"""

from __future__ import annotations

from typing import Any

from hadal.flows.post_cruise import stage_tasks
from hadal.tasks.stage import configured
from prefect import flow
from prefect.futures import PrefectFuture

from hadal.errors import HadalError
from hadal.pipeline import make_context, stage_plan


def dask_runner(workers: int = 2, scheduler: str | None = None, threads_per_worker: int = 1, processes: bool = True):
    """A DaskTaskRunner on ``scheduler`` (an existing cluster) or on a new LocalCluster of ``workers``
    worker processes (``processes=False``: threads in this process, cheaper to start, GIL-bound)."""
    from prefect_dask import DaskTaskRunner

    if scheduler:
        return DaskTaskRunner(address=scheduler)
    return DaskTaskRunner(cluster_kwargs={"n_workers": int(workers), "threads_per_worker": int(threads_per_worker),
                                          "processes": bool(processes), "dashboard_address": ":0"})


@flow(name="post-cruise-batch", log_prints=True)
def post_cruise_batch(
    raw_dirs: list[str],
    store_root: str | None = None,
    config_path: str | None = None,
    stages: list[str] | None = None,
    force: bool = False,
) -> dict[str, dict[str, Any]]:
    """Run the selected stages on every dive; returns ``{raw_dir: {"ok": bool, "published"|"error": ...}}``."""
    chains: dict[str, list[PrefectFuture]] = {}
    planned: dict[str, list[str]] = {}
    unplanned: dict[str, str] = {}
    for raw in raw_dirs:
        try:
            names = [ps.name for ps in stage_plan(make_context(raw, store_root, config_path), stages) if ps.run]
        except HadalError as exc:  # this dive cannot be planned; the others still run
            unplanned[raw] = str(exc)
            continue
        planned[raw] = names
        prev: PrefectFuture | None = None
        futs = []
        for t in (configured(t, store_root, force) for t in stage_tasks(names)):
            fut = t.submit(raw, store_root, config_path, wait_for=[prev] if prev is not None else None)
            futs.append(fut)
            prev = fut
        chains[raw] = futs
    results: dict[str, dict[str, Any]] = {raw: {"ok": False, "published": {}, "error": err}
                                          for raw, err in unplanned.items()}
    for raw, err in unplanned.items():
        print(f"{raw}: {err}")
    for raw, futs in chains.items():
        published: dict[str, str] = {}
        error = None
        for name, fut in zip(planned[raw], futs, strict=True):
            fut.wait()
            state = fut.state
            if state.is_completed():
                published.update(fut.result())
            else:
                exc = state.result(raise_on_failure=False)
                error = f"stage {name}: {exc}" if isinstance(exc, BaseException) else f"stage {name}: {state.name}"
                break
        results[raw] = {"ok": error is None, "published": published} if error is None else \
            {"ok": False, "published": published, "error": error}
        print(f"{raw}: {'ok' if error is None else error}")
    return results


def run_batch(raw_dirs: list[str], store_root: str | None = None, config_path: str | None = None,
              stages: list[str] | None = None, workers: int = 2, scheduler: str | None = None,
              force: bool = False, processes: bool = True) -> dict[str, dict[str, Any]]:
    """Run :func:`post_cruise_batch` with a Dask task runner (LocalCluster or ``scheduler`` address)."""
    runner = dask_runner(workers, scheduler, processes=processes)
    return post_cruise_batch.with_options(task_runner=runner)(
        [str(r) for r in raw_dirs], store_root, config_path, stages, force)
