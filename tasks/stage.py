"""Factory for the per-stage Prefect tasks (each ``tasks/<stage>.py`` is one line using it)."""

from __future__ import annotations

from prefect import task

from hadal.pipeline import make_context, run_stage
from hadal.progress import default_progress


def stage_task(name: str, *, retries: int = 0):
    """A Prefect task running stage ``name`` on a raw dive; returns ``{product: version directory}``."""

    def _run(raw_dir: str, store_root: str | None = None, config_path: str | None = None) -> dict[str, str]:
        ctx = make_context(raw_dir, store_root, config_path, progress=default_progress())
        return {product: str(pv.path) for product, pv in run_stage(name, ctx).items()}

    _run.__name__ = _run.__qualname__ = name
    _run.__doc__ = f"Run the hadal stage {name!r} and publish its products."
    return task(name=name, retries=retries, retry_delay_seconds=2)(_run)
