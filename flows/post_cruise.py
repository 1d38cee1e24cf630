"""The post-cruise flow: raw dive → ingest → derive → grid → suitability → match → landing → report."""

from __future__ import annotations

import importlib

from prefect import flow

from hadal.pipeline import resolve_stages


def stage_tasks(names: list[str]):
    return [getattr(importlib.import_module(f"tasks.{n}"), n) for n in names]


@flow(name="post-cruise", log_prints=True)
def post_cruise(
    raw_dir: str,
    store_root: str | None = None,
    config_path: str | None = None,
    stages: list[str] | None = None,
) -> dict[str, str]:
    """Process one dive: run the selected stages (default all) in order, each publishing new product versions.

    Returns ``{product: version directory}`` for everything published in this run.
    """
    names = resolve_stages(stages)
    published: dict[str, str] = {}
    for t in stage_tasks(names):
        published.update(t(raw_dir, store_root, config_path))
    return published
