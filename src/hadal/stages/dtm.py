"""Stage ``dtm``: multibeam soundings (else a prior grid) -> the reference DTM (``dtm``).

Parameters in section ``grid`` (the fields of :data:`hadal.stages.grid.DTM_FIELDS`); the work is
:func:`hadal.stages.grid.run_dtm`. No upstream product: it starts with the run, beside ``ingest`` and ``laser``.
"""

from __future__ import annotations

from hadal.settings.grid import DTM_FIELDS
from hadal.settings.grid import GridParams as Params
from hadal.stages import Stage, StageInputs
from hadal.stages.grid import run_dtm as run

__all__ = ["STAGE", "Params", "run"]


#: one configuration section (``grid``) shared with ``laser``, split by field; CPU-bound for seconds, so a flow runs
#: it in its own process when another stage can run beside it (:func:`flows.post_cruise.process_stages`; measured
#: faster than in the flow's threads, docs/operations.md)
STAGE = Stage(
    name="dtm", products=("dtm",),
    inputs=StageInputs(raw_any=("multibeam", "prior_grid"), reads_raw=True, frame_for=("dtm",)),
    options=Params, run=run, section="grid", param_fields=DTM_FIELDS, process=True,
    warm_imports=("hadal.grid.multibeam", "hadal.grid.sonar", "hadal.grid.readers", "hadal.products.io",
                  "hadal.products.geotiff", "hadal.numbawarm:first_call"),
)
