"""Prefect-free pipeline driver: build a :class:`StageContext` and run stages in order.

The Prefect flow (``flows/post_cruise.py``) and tasks (``tasks/``) call these functions; so can a
notebook or a test, without an orchestrator.
"""

from __future__ import annotations

import logging
import os
from collections.abc import Sequence
from pathlib import Path

from hadal.config import PipelineConfig, load_config
from hadal.dive import load_dive
from hadal.errors import StageError
from hadal.plan import PlannedStage, check_plan, plan_stages, runtime_skip_reason
from hadal.stages import STAGE_ORDER, NullProgress, Progress, StageContext, available_stages, stage_module
from hadal.store import ProductStore, ProductVersion

DIVE_CONFIG_FILE = "pipeline.yaml"


def default_store_root() -> Path:
    """``$HADAL_STORE`` if set, else ``./data/processed``."""
    return Path(os.environ.get("HADAL_STORE", "data/processed"))


def make_context(
    raw_dir: str | Path,
    store_root: str | Path | None = None,
    config: PipelineConfig | str | Path | None = None,
    progress: Progress | None = None,
) -> StageContext:
    """Load ``dive.yaml`` and the configuration (explicit file, else ``<raw_dir>/pipeline.yaml``, else defaults)."""
    dive, raw = load_dive(raw_dir)
    if not isinstance(config, PipelineConfig):
        dive_cfg = raw / DIVE_CONFIG_FILE
        config = load_config(dive_cfg if dive_cfg.is_file() else None, config)
    return StageContext(
        dive=dive,
        raw_dir=raw,
        store=ProductStore(store_root if store_root is not None else default_store_root()),
        config=config,
        progress=progress or NullProgress(),
        log=logging.getLogger(f"hadal.{dive.dive_id}"),
    )


def claim_dive(ctx: StageContext) -> None:
    """Record (or check) that the dive id belongs to this raw directory (:meth:`ProductStore.claim_dive`)."""
    from hadal.dive import dive_fingerprint

    ctx.store.claim_dive(ctx.dive_id, ctx.raw_dir, dive_fingerprint(ctx.dive, ctx.raw_dir))


def run_stage(name: str, ctx: StageContext) -> dict[str, ProductVersion]:
    """Run one stage; it reads the latest upstream products and publishes new versions."""
    mod = stage_module(name)
    if not callable(getattr(mod, "run", None)):
        raise StageError(f"stage {name!r} is not implemented in this version of hadal")
    claim_dive(ctx)
    ctx.log.info("stage %s: start", name)
    out = mod.run(ctx)
    for product, pv in out.items():
        ctx.log.info("stage %s: published %s/%s/%s", name, pv.dive, product, pv.label)
    return out


def resolve_stages(stages: Sequence[str] | None = None) -> list[str]:
    """Validate a stage selection and return it in execution order (all implemented stages by default)."""
    avail = available_stages()
    if not stages:
        return avail
    unknown = [s for s in stages if s not in STAGE_ORDER]
    if unknown:
        raise StageError(f"unknown stage(s) {', '.join(unknown)}; stages are: {', '.join(avail)}")
    missing = [s for s in stages if s not in avail]
    if missing:
        raise StageError(f"stage(s) {', '.join(missing)} not implemented; available: {', '.join(avail)}")
    return [s for s in STAGE_ORDER if s in stages]


def stage_plan(ctx: StageContext, stages: Sequence[str] | None = None) -> list[PlannedStage]:
    """The run plan (:func:`hadal.plan.plan_stages`) for ``ctx``'s dive, checked (:func:`hadal.plan.check_plan`).

    A stage named explicitly in ``stages`` that the data cannot support is an error (saying why); in a
    whole-dive run (``stages`` empty) such stages are skipped and logged.
    """
    plan = plan_stages(ctx.dive, stages, store=ctx.store if stages else None)
    check_plan(ctx.dive, plan)
    if stages:
        refused = [ps for ps in plan if not ps.run]
        if refused:
            raise StageError("; ".join(f"stage {ps.name} cannot run on dive {ctx.dive_id!r}: {ps.reason}"
                                       for ps in refused))
    return plan


def should_run(name: str, ctx: StageContext) -> bool:
    """The content check just before a planned stage runs; a stage that cannot run is logged and skipped."""
    why = runtime_skip_reason(name, ctx)
    if why:
        ctx.log.warning("stage %s skipped: %s", name, why)
        return False
    return True


def run_pipeline(ctx: StageContext, stages: Sequence[str] | None = None) -> dict[str, ProductVersion]:
    """Run the stages the dive's data supports (of ``stages``, default all) in order; see :func:`stage_plan`."""
    results: dict[str, ProductVersion] = {}
    for ps in stage_plan(ctx, stages):
        if not ps.run:
            ctx.log.info("stage %s skipped: %s", ps.name, ps.reason)
            continue
        if should_run(ps.name, ctx):
            results.update(run_stage(ps.name, ctx))
    return results
