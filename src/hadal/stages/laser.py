"""Stage ``laser``: laser point clouds and rasters -> uniform elevation grids (``laser_grids``).

Parameters in section ``grid`` (the fields of :data:`hadal.stages.grid.LASER_FIELDS`: ``laser_*``, ``max_cells``,
``zarr``); the work is :func:`hadal.stages.grid.run_laser`. No upstream product: it starts with the run, and
``landing`` waits for it alone.
"""

from __future__ import annotations

from hadal.settings.grid import LASER_FIELDS
from hadal.settings.grid import GridParams as Params
from hadal.stages import StageInputs
from hadal.stages.grid import run_laser as run

__all__ = ["Params", "run"]

SECTION = "grid"
PARAM_FIELDS = LASER_FIELDS
#: CPU-bound for seconds: a flow runs it in its own process when another stage can run beside it
#: (:func:`flows.post_cruise.process_stages`; measured faster than in the flow's threads, docs/operations.md)
PROCESS = True
#: modules its run imports (lazily), imported ahead while Prefect's server boots (:func:`hadal.pipeline.warm_imports`)
WARM_IMPORTS = ("open3d", "hadal.grid.laser", "hadal.grid.readers", "hadal.products.io", "hadal.products.geotiff",
                "hadal.numbawarm:first_call")
PRODUCTS = ("laser_grids",)
UPSTREAM: tuple[str, ...] = ()
INPUTS = StageInputs(raw_any=("laser",), reads_raw=True)
