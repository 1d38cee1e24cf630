"""Cruise flow (issue 48): one DTM over every dive's multibeam soundings on a Dask cluster, through Prefect's Dask
task runner (prefect-dask ``DaskTaskRunner``).

The science is :func:`hadal.grid.cruise.cruise_dtm_dataset`; this flow only gives it a ``map`` that submits one
Prefect task per dive (read, then partition) and per group of tiles (spike-test noise floor, spike flags, reduce;
small tiles grouped to about a million soundings) to the task runner: a new
``dask.distributed.LocalCluster`` of ``workers`` single-threaded worker processes, or an existing cluster at
``scheduler`` (``tcp://host:8786``; every worker must see the raw directories, the store and the scratch
directory, and have hadal installed). Each task writes its scratch files atomically and is a pure function of
them, so when a worker dies mid-run Dask runs its tasks again on the others and the run completes; the product
is published only at the end, atomically (:meth:`hadal.store.ProductStore.publish`), so a killed worker never
leaves a partial product. The DTM is published as product ``cruise_dtm`` under the cruise id (in place of a dive
id), with the dives and files used or refused in its manifest (``extra.provenance``).
"""

from __future__ import annotations

import shutil
import uuid
from pathlib import Path
from typing import Any

from prefect import flow, task
from prefect.cache_policies import NO_CACHE

from hadal.grid.cruise import cruise_dtm_dataset, partition_dive, read_dive, reduce_tiles, spike_tiles
from hadal.grid.tiles import tile_cell_mads
from hadal.settings.grid import GridParams

# one Prefect task per unit of work; no Prefect cache (the scratch files are the state, and the inputs are
# arrays/frames Prefect would hash); Dask re-runs a task whose worker died
_TASKS: dict[str, Any] = {
    read_dive.__name__: task(name="cruise-read-dive", cache_policy=NO_CACHE)(read_dive),
    partition_dive.__name__: task(name="cruise-partition-dive", cache_policy=NO_CACHE)(partition_dive),
    tile_cell_mads.__name__: task(name="cruise-tile-noise", cache_policy=NO_CACHE)(tile_cell_mads),
    spike_tiles.__name__: task(name="cruise-spike-tiles", cache_policy=NO_CACHE)(spike_tiles),
    reduce_tiles.__name__: task(name="cruise-reduce-tiles", cache_policy=NO_CACHE)(reduce_tiles),
}


def _task_map(fn, items) -> list:
    """The ``map`` of :func:`cruise_dtm_dataset` on the flow's task runner: every item submitted, then gathered in
    order (Prefect futures)."""
    t = _TASKS[fn.__name__]
    futures = [t.submit(*args) for args in items]
    return [f.result() for f in futures]


def publish_cruise_dtm(store_root: str, cruise_id: str, ds, provenance: dict[str, Any],
                       parameters: dict[str, Any]) -> str:
    """Write the cruise DTM as ``cruise_dtm.nc`` in a new version of ``<cruise_id>/cruise_dtm`` (atomic publish);
    returns the version directory."""
    from hadal.products.io import write_netcdf
    from hadal.store import ProductStore

    inputs = [f for d in provenance["dives"].values() if d["used"] for f in d["files_used"]]
    store = ProductStore(store_root)
    with store.publish(cruise_id, "cruise_dtm", parameters=parameters, inputs=inputs,
                       extra={"provenance": provenance}) as draft:
        write_netcdf(ds, draft.path / "cruise_dtm.nc", title=f"Cruise {cruise_id} DTM",
                     summary=f"Multibeam DTM of the dives {ds.attrs.get('cruise_dives', '')} gridded together "
                             "in one transverse Mercator frame (hadal.grid.cruise)", provenance_from=draft)
    assert draft.result is not None
    return str(draft.result.path)


@flow(name="cruise-dtm")
def cruise_dtm_flow(raw_dirs: list[str], store_root: str, cruise_id: str, resolution_m: float,
                    tile_cells: int | None = None, scratch_dir: str | None = None,
                    params: GridParams | None = None) -> dict[str, Any]:
    """The cruise DTM on the flow's task runner, published; returns ``{"path": version dir, "dives": {...},
    "refused_raw_dirs": {...}}``. ``scratch_dir`` (default a fresh ``.scratch/cruise-*`` directory in the store,
    which every worker sees) is removed at the end; ``params``: the ``grid`` settings (hole filling, a-priori
    uncertainty, cell-count limit; default their defaults)."""
    from hadal.store import validate_name

    validate_name(cruise_id, "cruise id")
    own = scratch_dir is None
    scratch = Path(scratch_dir) if scratch_dir else Path(store_root) / ".scratch" / f"cruise-{uuid.uuid4().hex[:12]}"
    scratch.mkdir(parents=True, exist_ok=True)
    try:
        ds, prov = cruise_dtm_dataset(raw_dirs, resolution_m, scratch, map=_task_map, tile_cells=tile_cells,
                                      params=params)
        path = publish_cruise_dtm(store_root, cruise_id, ds, prov,
                                  {"resolution_m": float(resolution_m), "tile_cells": ds.attrs["tile_cells"],
                                   "raw_dirs": [str(r) for r in raw_dirs]})
    finally:
        if own:
            shutil.rmtree(scratch, ignore_errors=True)
    return {"path": path, "dives": prov["dives"], "refused_raw_dirs": prov["refused_raw_dirs"]}


def dask_runner(workers: int = 2, scheduler: str | None = None):
    """A DaskTaskRunner on ``scheduler`` (an existing cluster) or on a new LocalCluster of ``workers``
    single-threaded worker processes (as the batch of dives, :mod:`hadal.flows.batch`)."""
    from prefect_dask import DaskTaskRunner

    if scheduler:
        return DaskTaskRunner(address=scheduler)
    if not (isinstance(workers, int) and 1 <= workers <= 256):
        from hadal.errors import ConfigError

        raise ConfigError(f"workers must be a whole number in 1..256, got {workers!r}")
    return DaskTaskRunner(cluster_kwargs={"n_workers": workers, "threads_per_worker": 1, "processes": True,
                                          "dashboard_address": ":0"})


def cruise_dtm(raw_dirs: list[str], store_root: str, cruise_id: str, resolution_m: float, workers: int = 2,
               scheduler: str | None = None, *, tile_cells: int | None = None,
               scratch_dir: str | None = None, params: GridParams | None = None) -> dict[str, Any]:
    """Run :func:`cruise_dtm_flow` on Dask: a LocalCluster of ``workers`` processes, or the cluster at
    ``scheduler``. The entry point of ``hadal cruise-dtm``."""
    return cruise_dtm_flow.with_options(task_runner=dask_runner(workers, scheduler))(
        [str(r) for r in raw_dirs], str(store_root), cruise_id, float(resolution_m), tile_cells, scratch_dir,
        params)
