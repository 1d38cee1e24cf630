"""The post-cruise flow: raw dive → ingest → derive → grid → suitability → match → landing → report."""

from __future__ import annotations

import importlib

from prefect import flow

from hadal.pipeline import make_context, stage_plan
from hadal.tasks.stage import configured, published_exist


def stage_tasks(names: list[str]):
    return [getattr(importlib.import_module(f"hadal.tasks.{n}"), n) for n in names]


def run_stage_task(t, raw_dir: str, store_root: str | None, config_path: str | None, force: bool = False) -> dict[str, str]:
    """Run one stage task with caching in the store; a cached result whose versions were removed re-runs."""
    out = configured(t, store_root, force)(raw_dir, store_root, config_path)
    if not force and not published_exist(out):
        out = configured(t, store_root, True)(raw_dir, store_root, config_path)
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
    plan = stage_plan(make_context(raw_dir, store_root, config_path), stages)
    published: dict[str, str] = {}
    for ps in plan:
        if not ps.run:
            print(f"stage {ps.name} skipped: {ps.reason}")
            continue
        (t,) = stage_tasks([ps.name])
        published.update(run_stage_task(t, raw_dir, store_root, config_path, force))
    return published
