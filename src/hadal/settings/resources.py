"""Resource limits (section ``resources`` of config/pipeline.yaml): the memory and work every stage checks its
configuration against before allocating (:mod:`hadal.budget`), and how many stages of a dive run at once."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field

GIB = 1024 ** 3

#: default share of the memory this process can have (:func:`hadal.budget.machine_memory_bytes`) one stage may plan to allocate
DEFAULT_MEMORY_FRACTION = 0.5
#: default limit on the pose x offset evaluations of the terrain-matching search (about 10 min on 2 cores)
DEFAULT_MAX_MATCH_EVALUATIONS = 2e10


class ResourcesParams(BaseModel):
    """Memory and work limits every stage checks its configuration against before allocating."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    max_memory_gb: float | None = Field(
        None, gt=0, le=65_536,
        description="memory (GiB) one stage may plan to allocate for its largest arrays; default: memory_fraction "
                    "x the memory this process can have (physical memory, lowered to a cgroup limit or to what "
                    "ulimit -v leaves)")
    memory_fraction: float = Field(
        DEFAULT_MEMORY_FRACTION, gt=0, le=1,
        description="share (0-1] of the memory this process can have (physical, cgroup limit or ulimit -v) "
                    "used when max_memory_gb is not set")
    max_match_evaluations: float = Field(
        DEFAULT_MAX_MATCH_EVALUATIONS, ge=1, le=1e15,
        description="terrain matching: refuse searches with more (heading x scale poses) x (map offsets) "
                    "evaluations than this (2e10: about 10 minutes on 2 cores)")
    parallel_stages: int | None = Field(
        None, ge=1, le=64,
        description="stages of one dive's flow run that may run at once (those ready first in stage order go "
                    "first); default: the machine's CPU cores, at least 2. Each running stage plans its memory "
                    "against max_memory_gb on its own")
    stage_processes: bool = Field(
        True,
        description="run the gridding stages (dtm, laser) of a dive's flow run in their own "
                    "process while another stage can run beside them, so they do not share one Python GIL")
