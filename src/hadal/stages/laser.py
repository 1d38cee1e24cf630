"""Stage ``laser``: laser point clouds and rasters -> uniform elevation grids (``laser_grids``).

Parameters in section ``grid`` (the fields of :data:`hadal.stages.grid.LASER_FIELDS`: ``laser_*``, ``max_cells``,
``zarr``); the work is :func:`hadal.stages.grid.run_laser`. No upstream product: it starts with the run, and
``landing`` waits for it alone.
"""

from __future__ import annotations

from hadal.settings.grid import LASER_FIELDS
from hadal.settings.grid import GridParams as Params
from hadal.stages import Stage, StageInputs
from hadal.stages.grid import run_laser as run

__all__ = ["STAGE", "Params", "run"]


#: one configuration section (``grid``) shared with ``dtm``, split by field; in its own process in a flow (as dtm)
STAGE = Stage(
    name="laser", products=("laser_grids",), inputs=StageInputs(raw_any=("laser",), reads_raw=True),
    options=Params, run=run, section="grid", param_fields=LASER_FIELDS, process=True,
    warm_imports=("open3d", "hadal.grid.laser", "hadal.grid.readers", "hadal.products.io", "hadal.products.geotiff",
                  "hadal.numbawarm:first_call"),
)
