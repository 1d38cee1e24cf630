"""Prefect-free pipeline driver: build a :class:`StageContext` and run stages in order.

The Prefect flow (``flows/post_cruise.py``) and tasks (``tasks/``) call these functions; so can a
notebook or a test, without an orchestrator.
"""

from __future__ import annotations

import functools
import hashlib
import logging
import os
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hadal.errors import HadalError, InputError, StageError
from hadal.plan import PlannedStage, check_plan, plan_stages, runtime_skip_reason
from hadal.stages import (
    STAGE_ORDER,
    NullProgress,
    Progress,
    StageContext,
    available_stages,
    producer_of,
    stage_module,
)
from hadal.store import ProductStore, ProductVersion

if TYPE_CHECKING:  # hadal.config imports every stage (and their science): only where a run needs it
    from hadal.config import PipelineConfig

DIVE_CONFIG_FILE = "pipeline.yaml"


def default_store_root() -> Path:
    """``$HADAL_STORE`` if set, else ``./data/processed``."""
    return Path(os.environ.get("HADAL_STORE", "data/processed"))


@functools.lru_cache(maxsize=1)
def code_digest() -> str:
    """hadal's version + SHA-256 over its source files (catches uncommitted edits, unlike git HEAD); part of
    every stage's cache key and the key of the CLI's cached ``hadal config`` output."""
    import hadal

    root = Path(hadal.__file__).resolve().parent
    h = hashlib.sha256(hadal.__version__.encode())
    for p in sorted(root.rglob("*.py")):
        h.update(str(p.relative_to(root)).encode())
        h.update(p.read_bytes())
    return f"{hadal.__version__}+{h.hexdigest()[:16]}"


def make_context(
    raw_dir: str | Path,
    store_root: str | Path | None = None,
    config: PipelineConfig | str | Path | None = None,
    progress: Progress | None = None,
) -> StageContext:
    """Load ``dive.yaml`` and the configuration (explicit file, else ``<raw_dir>/pipeline.yaml``, else defaults)."""
    from hadal.config import PipelineConfig, load_config
    from hadal.dive import load_dive

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


def claim_dive(ctx: StageContext, *, check_only: bool = False) -> None:
    """Record (or, ``check_only``, just check) that the dive id belongs to this raw directory
    (:meth:`ProductStore.claim_dive`)."""
    from hadal.dive import dive_fingerprint

    ctx.store.claim_dive(ctx.dive_id, ctx.raw_dir, dive_fingerprint(ctx.dive, ctx.raw_dir), check_only=check_only)


def run_stage(name: str, ctx: StageContext, run_info: dict[str, Any] | None = None) -> dict[str, ProductVersion]:
    """Run one stage; it reads the latest upstream products and publishes new versions.

    Each manifest it writes records ``stage_run`` (:data:`hadal.store.STAGE_RUN`): the stage, its start time, the
    seconds from its start to that publish, and ``run_info`` (e.g. the Prefect flow/task run ids)."""
    import datetime as _dt
    import time

    from hadal.store import STAGE_RUN

    mod = stage_module(name)
    if not callable(getattr(mod, "run", None)):
        raise StageError(f"stage {name!r} is not implemented in this version of hadal")
    claim_dive(ctx, check_only=True)  # refuse another directory's dive id before any work
    ctx.log.info("stage %s: start", name)
    t0 = time.monotonic()
    token = STAGE_RUN.set({"stage": name, "started_utc": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
                           "t0": t0, **(run_info or {})})
    try:
        from hadal.products.metadata import dive_context  # the writers take ACDD metadata/paths from the dive

        with dive_context(ctx.dive, ctx.raw_dir):
            out = mod.run(ctx)
    finally:
        STAGE_RUN.reset(token)
    if out:
        claim_dive(ctx)
    for product, pv in out.items():
        ctx.log.info("stage %s: published %s/%s/%s (%.1f s)", name, pv.dive, product, pv.label, time.monotonic() - t0)
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
    if not ctx.dive.sources.kinds() and not stages:
        raise InputError(f"{ctx.raw_dir}/dive.yaml lists no source files: nothing to process (hadal init "
                         f"{ctx.raw_dir} lists what it finds there)")
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


def blocked_by_failure(name: str, failed: dict[str, str]) -> str | None:
    """Why stage ``name`` cannot run after the stages in ``failed`` (``{stage: error}``) failed in this run:
    one of its upstream products comes from a failed stage (its older versions would mix runs). ``None``: run."""
    from hadal.plan import stage_inputs

    for product in stage_inputs(name).upstream:
        maker = producer_of(product)
        if maker in failed:
            return f"needs {product}, but stage {maker} failed in this run"
    return None


def run_pipeline(ctx: StageContext, stages: Sequence[str] | None = None) -> dict[str, ProductVersion]:
    """Run the stages the dive's data supports (of ``stages``, default all) in order; see :func:`stage_plan`.

    A stage that fails with a :class:`HadalError` does not stop the stages that do not depend on it; the report
    still runs and lists the failure (:attr:`StageContext.failed`), and the run then raises one
    :class:`StageError` naming every failed stage."""
    results: dict[str, ProductVersion] = {}
    plan = stage_plan(ctx, stages)
    for stale in ctx.store.clean_staging():  # left by a killed run more than an hour ago
        ctx.log.info("removed abandoned staging directory %s", stale)
    ctx.pin_existing(all_products())  # this run reads what it found at its start or published itself
    for ps in plan:
        if not ps.run:
            ctx.log.info("stage %s skipped: %s", ps.name, ps.reason)
            continue
        if (why := blocked_by_failure(ps.name, ctx.failed)) is not None:
            ctx.log.warning("stage %s skipped: %s", ps.name, why)
            ctx.failed_skips[ps.name] = why
            continue
        if not should_run(ps.name, ctx):
            continue
        try:
            out = run_stage(ps.name, ctx)
        except HadalError as exc:
            ctx.log.error("stage %s failed: %s", ps.name, exc)
            ctx.failed[ps.name] = str(exc)
            continue
        ctx.pins.update(out)
        results.update(out)
    raise_failures(ctx.failed)
    return results


def raise_failures(failed: dict[str, str]) -> None:
    """One :class:`StageError` naming every failed stage and its one-line error (nothing when none failed)."""
    if failed:
        raise StageError(f"{len(failed)} stage(s) failed ({'; '.join(f'{k}: {v}' for k, v in failed.items())}); "
                         "the other stages ran and the report lists the failures")


def all_products() -> list[str]:
    """Every product any stage publishes, in stage order."""
    return [p for n in STAGE_ORDER for p in getattr(stage_module(n), "PRODUCTS", ())]


def pin_paths(ctx: StageContext, pins: dict[str, str] | None) -> None:
    """Pin the versions named by ``{product: version directory}`` (a flow passes them between its tasks)."""
    for product, path in (pins or {}).items():
        ctx.pins[product] = ctx.store.version_at(path)
