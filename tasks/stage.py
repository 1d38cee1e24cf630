"""Factory for the per-stage Prefect tasks (each ``tasks/<stage>.py`` is one line using it).

Caching: a stage task's cache key is the SHA-256 of its *fingerprint* (:func:`hadal.pipeline.stage_fingerprint`,
Prefect-free, so ``hadal run`` can tell an unchanged dive without starting Prefect:
:func:`hadal.pipeline.current_stages`):

* the stage name, dive id and store root;
* hadal's code version (package version + SHA-256 of every ``hadal/**/*.py`` source file);
* the stage's configuration section (``ctx.params(stage)``, canonical JSON);
* for stages that read raw files (``Stage.inputs.reads_raw``: ``ingest``, ``dtm``, ``laser``), the SHA-256 of those files
  and of ``dive.yaml`` (cached with each file's size, mtime, inode and ctime in the store:
  :meth:`hadal.store.ProductStore.file_sha256`, so an unchanged re-run does not re-read ~280 MB of raw data);
  for every stage, the manifests (SHA-256) of the pinned (else latest) versions of every product it reads (``Stage.reads``).

Inside a flow, hadal's log records go to the Prefect run (:func:`route_hadal_logs`), task runs are named after
their stage, and each fresh run leaves a markdown artifact ``<dive>-stage-<stage>`` (:func:`stage_artifact`).

The task's result (``{product: version directory}``) is persisted under ``<store>/.prefect-results``
(:func:`result_storage`), so re-running an unchanged stage returns the already-published versions
instead of publishing duplicates, while a changed parameter, input file, upstream version or code
re-runs it. Because ingest's output version then stays the same, an unchanged pipeline is a chain of
cache hits. ``force=True`` (``hadal stage --force``) bypasses the cache (``refresh_cache``).

Retries: I/O-bound stages (ingest, dtm, laser) retry on ``OSError`` only (:func:`retry_on_io_error`); a
:class:`~hadal.errors.HadalError` (bad input, configuration) is never retried.
"""

from __future__ import annotations

import json
import logging
import re
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from prefect import task

from hadal.errors import HadalError
from hadal.pipeline import (  # noqa: F401 - the fingerprint functions are re-exported (Prefect-free in pipeline)
    RESULTS_DIR,
    blocked_by_failure,
    code_digest,
    drop_gone_result,
    fingerprint_key,
    make_context,
    pin_paths,
    raw_inputs,
    result_storage,
    run_stage,
    should_run,
    stage_cache_key,
    stage_fingerprint,
)
from hadal.progress import default_progress
from hadal.stage_process import can_isolate, run_stage_in_process
from hadal.stages import NullProgress, StageContext

__all__ = ["code_digest", "stage_fingerprint", "stage_task", "configured", "published_exist", "route_hadal_logs"]

# ---------------------------------------------------------------------------------------- logs into Prefect
class PrefectRunLogHandler(logging.Handler):
    """Sends hadal's log records (logger ``hadal`` and below) to the Prefect run they are logged in (its UI and
    API), through Prefect's own :class:`~prefect.logging.handlers.APILogHandler`; records outside a flow or task
    run are left to the other handlers."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        from prefect.logging.handlers import APILogHandler

        self._api = APILogHandler()

    def emit(self, record: logging.LogRecord) -> None:
        from prefect.context import FlowRunContext, TaskRunContext

        if TaskRunContext.get() is None and FlowRunContext.get() is None:
            return
        self._api.emit(record)


_ROUTE_LOCK = threading.Lock()


def route_hadal_logs() -> None:
    """Attach :class:`PrefectRunLogHandler` to the ``hadal`` logger once per process (flow and Dask workers)."""
    lg = logging.getLogger("hadal")
    with _ROUTE_LOCK:
        if not any(isinstance(h, PrefectRunLogHandler) for h in lg.handlers):
            lg.addHandler(PrefectRunLogHandler())
        if lg.getEffectiveLevel() > logging.INFO:  # e.g. a Dask worker: INFO still reaches the Prefect run
            lg.setLevel(logging.INFO)


class _ThreadWarnings(logging.Handler):
    """Collects the WARNING+ records of hadal logged by one thread (one stage task) for its artifact."""

    def __init__(self) -> None:
        super().__init__(logging.WARNING)
        self.thread = threading.get_ident()
        self.records: list[logging.LogRecord] = []

    def emit(self, record: logging.LogRecord) -> None:
        if record.thread == self.thread:
            self.records.append(record)


def _artifact_key(dive: str, what: str) -> str:
    return re.sub(r"[^a-z0-9-]+", "-", f"{dive}-{what}".lower()).strip("-")[:100]


def stage_artifact(name: str, ctx: StageContext, published: dict[str, str], seconds: float,
                   warnings: list[logging.LogRecord]) -> None:
    """A markdown artifact ``<dive>-stage-<stage>`` for a fresh stage run: no-op outside a Prefect task run."""
    from prefect.artifacts import create_markdown_artifact
    from prefect.context import TaskRunContext

    if TaskRunContext.get() is None:
        return
    create_markdown_artifact(artifact_markdown(name, ctx.dive_id, published, seconds, warnings),
                             key=_artifact_key(ctx.dive_id, f"stage-{name}"),
                             description=f"hadal stage {name} on dive {ctx.dive_id}")


def artifact_markdown(name: str, dive: str, published: dict[str, str], seconds: float,
                      warnings: list[logging.LogRecord]) -> str:
    """The stage artifact's markdown: the results a user looks for first (:func:`hadal.tasks.results.result_lines`:
    QC counts, the fix and its ellipse, the best landing sites, the report link), then the versions published (with
    sizes) and the time, and a table of the warnings the stage logged."""
    from hadal.tasks.results import result_lines

    lines = [f"# {dive}: stage `{name}`", *result_lines(published), "", "## Published", "",
             f"{seconds:.1f} s; published:", "", "| product | version | files | MiB |", "|---|---|---|---|"]
    for product, path in published.items():
        try:
            files = json.loads(Path(path, "manifest.json").read_text(encoding="utf-8")).get("files", [])
        except (OSError, ValueError):
            files = []
        mib = sum(f.get("bytes", 0) for f in files) / 2**20
        lines.append(f"| {product} | {Path(path).name} | {len(files)} | {mib:.1f} |")
    if not published:
        lines.append("| (nothing) | | | |")
    lines += ["", f"## Warnings ({len(warnings)})", ""]
    if warnings:
        lines += ["| level | logger | message |", "|---|---|---|"]
        for r in warnings[:200]:
            msg = r.getMessage().replace("|", "\\|").replace("\n", " ")
            lines.append(f"| {r.levelname} | {r.name} | {msg[:500]} |")
    else:
        lines.append("none")
    return "\n".join(lines)


def _run_ids() -> dict[str, str]:
    from prefect.context import TaskRunContext

    trc = TaskRunContext.get()
    if trc is None:
        return {}
    return {"flow_run": str(trc.task_run.flow_run_id), "task_run": str(trc.task_run.id)}


def upstream_state(name: str, pins: dict[str, str] | None, upstream: dict[str, Any] | None
                   ) -> tuple[dict[str, str], dict[str, str], dict[str, str]]:
    """What stage ``name``'s task knows from the stages it reads from (``upstream``: ``{stage: its result, or the
    exception it failed with}``, as Prefect hands them over through ``allow_failure``): the pins (the run's ``pins``
    updated with what the upstream stages published or reused), the upstream stages that failed (``{stage: the
    first line of the error}``) and those skipped because of such a failure (:func:`hadal.pipeline.
    blocked_by_failure`); the report lists both."""
    merged = dict(pins or {})
    failed: dict[str, str] = {}
    for up, value in (upstream or {}).items():
        if isinstance(value, BaseException):
            failed[up] = str(value).splitlines()[0] if str(value) else type(value).__name__
        elif isinstance(value, dict):
            merged.update(value)
    skips = {up: why for up in (upstream or {}) if up not in failed
             and (why := blocked_by_failure(up, failed)) is not None}
    return merged, failed, skips


def cache_key(name: str) -> Callable[[Any, dict[str, Any]], str | None]:
    """A Prefect ``cache_key_fn`` for stage ``name`` (task parameters: raw_dir, store_root, config_path, pins,
    upstream). A stage that an upstream failure blocks is not cached; a record whose versions are gone is removed
    first (:func:`hadal.pipeline.drop_gone_result`), so the stage runs again."""

    def _key(context: Any, parameters: dict[str, Any]) -> str | None:
        pins, failed, skips = upstream_state(name, parameters.get("pins"), parameters.get("upstream"))
        if blocked_by_failure(name, failed) is not None:
            return None
        try:
            key = stage_cache_key(name, parameters["raw_dir"], parameters.get("store_root"),
                                  parameters.get("config_path"), pins, failed, skips)
        except (HadalError, OSError):
            return None  # the task itself will report the problem; never cache it
        drop_gone_result(result_storage(parameters.get("store_root")), key)
        return key

    _key.__name__ = f"{name}_cache_key"
    return _key


def retry_on_io_error(task_: Any, task_run: Any, state: Any) -> bool:
    """Retry only transient I/O failures (``OSError`` that is not a hadal input/config error)."""
    exc = getattr(state, "data", None)
    if not isinstance(exc, BaseException):
        try:
            exc = state.result(raise_on_failure=False)
        except Exception:  # noqa: BLE001 - an unreadable state is not worth a retry
            return False
    return isinstance(exc, OSError) and not isinstance(exc, HadalError)


def stage_task(name: str, *, retries: int = 0, after: Callable[[str, dict[str, str]], None] | None = None):
    """A Prefect task running stage ``name`` on a raw dive; returns ``{product: version directory}``.

    ``pins`` (``{product: version directory}``) are the versions the flow run found at its start; ``upstream``
    (``{stage: result}``, Prefect futures wrapped in ``allow_failure`` when submitted: ``flows/post_cruise.py``) adds
    what the stages it reads from published or reused in this run: the task reads those, never a concurrent run's
    newer ones. An upstream stage that failed makes the task skip (returning nothing) when it needs that stage's
    product (:func:`hadal.pipeline.blocked_by_failure`); the failures and those skips reach the report, which
    lists them (:func:`upstream_state`). ``isolate``:
    run the stage in its own process (:mod:`hadal.stage_process`; not part of the cache key).

    ``after(name, published)`` runs inside the task after a fresh (non-cached) run, e.g. to publish
    Prefect artifacts.
    """

    def _run(raw_dir: str, store_root: str | None = None, config_path: str | None = None,
             pins: dict[str, str] | None = None, upstream: dict[str, Any] | None = None,
             isolate: bool = False) -> dict[str, str]:
        route_hadal_logs()
        ctx = make_context(raw_dir, store_root, config_path, progress=default_progress())
        pins, failed, failed_skips = upstream_state(name, pins, upstream)
        if (why := blocked_by_failure(name, failed)) is not None:
            ctx.log.warning("stage %s skipped: %s", name, why)
            return {}
        pin_paths(ctx, pins)
        ctx.failed, ctx.failed_skips = failed, failed_skips
        if not should_run(name, ctx):  # the upstream content cannot support it (logged with the reason)
            return {}
        collect = _ThreadWarnings()
        hlog = logging.getLogger("hadal")
        hlog.addHandler(collect)
        t0 = time.monotonic()
        try:
            if isolate and can_isolate():
                published = run_stage_in_process(
                    name, raw_dir=raw_dir, store_root=store_root, config_path=config_path, pins=pins, failed=failed,
                    failed_skips=failed_skips, run_info=_run_ids(), progress=not isinstance(ctx.progress, NullProgress))
            else:
                published = {product: str(pv.path) for product, pv in run_stage(name, ctx, _run_ids()).items()}
        finally:
            hlog.removeHandler(collect)
        try:
            stage_artifact(name, ctx, published, time.monotonic() - t0, collect.records)
        except Exception as exc:  # noqa: BLE001 - an artifact must never fail a published stage
            ctx.log.warning("stage %s: artifact not created (%s)", name, exc)
        if after is not None:
            after(name, published)
        return published

    _run.__name__ = _run.__qualname__ = name
    _run.__doc__ = f"Run the hadal stage {name!r} and publish its products."
    return task(
        name=name, task_run_name=name, retries=retries, retry_delay_seconds=2,
        retry_condition_fn=retry_on_io_error if retries else None,
        cache_key_fn=cache_key(name), persist_result=True,
    )(_run)


def configured(t: Any, store_root: str | None, force: bool = False) -> Any:
    """``t`` with its result storage in the dive's store and, if ``force``, the cache bypassed."""
    return t.with_options(result_storage=result_storage(store_root), refresh_cache=True if force else None)


def published_exist(published: dict[str, str]) -> bool:
    """True if every version directory of a (possibly cached) result still exists."""
    return all(Path(p, "manifest.json").is_file() for p in published.values())
