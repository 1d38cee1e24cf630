"""The stage graph, derived once from the stages' records (:class:`hadal.stages.Stage`, each module's ``STAGE``).

:data:`STAGES` (in :data:`hadal.stages.STAGE_ORDER`, the flow's priority among ready stages) is the one list; the
plan (:mod:`hadal.stages.plan`), the cache fingerprint (:func:`hadal.pipeline.stage_fingerprint`), the in-process runner
(:func:`hadal.pipeline.run_pipeline`) and the flow (``flows/post_cruise.py``) all read it through the functions
here: :func:`stage`, :func:`producer_of`, :func:`all_products` and :func:`dependencies`.
"""

from __future__ import annotations

from collections.abc import Sequence

from hadal.errors import StageError
from hadal.stages import (
    STAGE_GROUPS,
    STAGE_ORDER,
    Stage,
    derive,
    dtm,
    ingest,
    landing,
    laser,
    match,
    profile,
    report,
    suitability,
)

#: every stage, in execution order
STAGES: tuple[Stage, ...] = (ingest.STAGE, derive.STAGE, dtm.STAGE, laser.STAGE, suitability.STAGE, match.STAGE,
                             profile.STAGE, landing.STAGE, report.STAGE)
assert tuple(s.name for s in STAGES) == STAGE_ORDER, "STAGES must follow STAGE_ORDER"

_BY_NAME: dict[str, Stage] = {s.name: s for s in STAGES}
#: product -> the stage that publishes it
PRODUCER: dict[str, str] = {p: s.name for s in STAGES for p in s.products}


def stage(name: str) -> Stage:
    """The record of stage ``name`` (an unknown name, or a group such as ``grid``: a one-line StageError)."""
    rec = _BY_NAME.get(name)
    if rec is None:
        group = f" ({name} stands for {', '.join(STAGE_GROUPS[name])})" if name in STAGE_GROUPS else ""
        raise StageError(f"unknown stage {name!r}{group}; stages are: {', '.join(STAGE_ORDER)}")
    return rec


def producer_of(product: str) -> str:
    """The stage that publishes ``product``; ``?`` for none."""
    return PRODUCER.get(product, "?")


def all_products() -> list[str]:
    """Every product any stage publishes, in stage order."""
    return [p for s in STAGES for p in s.products]


def dependencies(names: Sequence[str]) -> dict[str, set[str]]:
    """For each stage of a run (``names``), the stages *of that run* it must wait for: those that publish a product
    it reads (:attr:`Stage.reads`). Stages with no path between them run concurrently in the flow."""
    made = {n: set(stage(n).products) for n in names}
    return {n: {m for m in names if m != n and made[m] & set(stage(n).reads)} for n in names}
