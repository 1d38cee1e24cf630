"""The post-cruise flow: raw dive → ingest → derive → grid → suitability → match → landing → report."""

from __future__ import annotations

import importlib

from hadal.tasks.stage import configured, published_exist
from prefect import flow

from hadal.errors import HadalError
from hadal.pipeline import all_products, blocked_by_failure, make_context, raise_failures, stage_plan


def stage_tasks(names: list[str]):
    return [getattr(importlib.import_module(f"hadal.tasks.{n}"), n) for n in names]


def run_stage_task(t, raw_dir: str, store_root: str | None, config_path: str | None, force: bool = False,
                   pins: dict[str, str] | None = None, **notes: dict[str, str] | None) -> dict[str, str]:
    """Run one stage task with caching in the store; a cached result whose versions were removed re-runs.
    ``notes``: ``failed``/``failed_skips`` of the run so far (for the report)."""
    out = configured(t, store_root, force)(raw_dir, store_root, config_path, pins, **notes)
    if not force and not published_exist(out):
        out = configured(t, store_root, True)(raw_dir, store_root, config_path, pins, **notes)
    return out


@flow(name="post-cruise", log_prints=True)
def post_cruise(
    raw_dir: str,
    store_root: str | None = None,
    config_path: str | None = None,
    stages: list[str] | None = None,
    force: bool = False,
) -> dict[str, str]:
    """Process one dive: run the selected stages (default: all the dive's data supports, :mod:`hadal.plan`) in
    order, each publishing new product versions; skipped stages are logged with the reason (and listed by the
    report).

    Unchanged stages are cache hits (their published versions are reused); ``force`` re-runs them all.
    Returns ``{product: version directory}`` for every stage that ran or was reused.
    """
    ctx = make_context(raw_dir, store_root, config_path)
    plan = stage_plan(ctx, stages)
    for stale in ctx.store.clean_staging():  # left by a killed run more than an hour ago
        print(f"removed abandoned staging directory {stale}")
    ctx.pin_existing(all_products())  # the run reads what it found at its start or published itself
    pins = {product: str(pv.path) for product, pv in ctx.pins.items()}
    published: dict[str, str] = {}
    failed: dict[str, str] = {}
    skips: dict[str, str] = {}
    unexpected: BaseException | None = None
    for ps in plan:
        if not ps.run:
            print(f"stage {ps.name} skipped: {ps.reason}")
            continue
        if (why := blocked_by_failure(ps.name, failed)) is not None:
            print(f"stage {ps.name} skipped: {why}")
            skips[ps.name] = why
            continue
        (t,) = stage_tasks([ps.name])
        notes = {"failed": dict(failed), "failed_skips": dict(skips)} if ps.name == "report" and failed else {}
        try:
            out = run_stage_task(t, raw_dir, store_root, config_path, force, pins=dict(pins), **notes)
        except Exception as exc:  # noqa: BLE001 - the stages that do not depend on it and the report still run
            failed[ps.name] = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            if not isinstance(exc, HadalError) and unexpected is None:
                unexpected = exc
            continue
        pins.update(out)
        published.update(out)
    if unexpected is not None:
        raise unexpected
    raise_failures(failed)
    return published
