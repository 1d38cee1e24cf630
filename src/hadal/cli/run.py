"""``hadal run``: the post-cruise flow on one dive, or on several in parallel (``--dives``)."""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from hadal.cli._common import (
    ConfigOpt,
    FlowOpt,
    ForceOpt,
    StoreOpt,
    _print_published,
    _print_report_path,
    _print_stage_table,
    _quiet_prefect_tracebacks,
    _store_root,
    console,
)
from hadal.cli._process import (
    _api_lost_error,
    _fork_ahead,
    _prefect_environment,
    _prepare_while_server_boots,
    _server_text,
    _wait_for_api,
    _watch_api,
)
from hadal.errors import HadalError


def _run_flow(raw_dir: Path, store: Path | None, config: Path | None, stages: list[str] | None,
              force: bool = False, flow_run: bool = False) -> dict[str, str]:
    """Run the post-cruise flow on ``stages`` of one dive (default all); when every stage would be a cache hit
    (:func:`hadal.pipeline.current_stages`), and neither ``force`` nor ``flow_run`` is given, say so in one line and
    return without starting Prefect: the products, manifests and lineage are those an unchanged flow run leaves."""
    import time

    from hadal.dive import load_dive
    from hadal.pipeline import (
        claim_dive,
        current_stages,
        make_context,
        stage_cache_status,
        stage_plan,
        stale_stages,
    )

    t0 = time.monotonic()
    # validate everything cheap before starting Prefect, so bad input fails fast and in one line
    load_dive(raw_dir)
    ctx = make_context(raw_dir, _store_root(store), config)
    plan = stage_plan(ctx, stages)  # the stages the dive's data supports (explicit ones that cannot run: error)
    claim_dive(ctx, check_only=True)
    names = [ps.name for ps in plan if ps.run]
    for ps in plan:
        if not ps.run:
            console.print(f"[yellow]skip[/] {ps.name}: {ps.reason}", highlight=False)
    cfg_path = str(config) if config else None
    # one walk of the cache (no Prefect): whether all is current, and else what will run rather than be reused
    status = [] if force else stage_cache_status(raw_dir, _store_root(store), cfg_path, names)
    if not force and not flow_run and (
            cur := current_stages(raw_dir, _store_root(store), cfg_path, names, status=status)) is not None:
        for stale in ctx.store.clean_staging():  # as the flow does at its start
            console.print(f"removed abandoned staging directory {stale}", highlight=False)
        console.print(f"[bold]hadal[/] {raw_dir}: all {len(names)} stage(s) current (raw files, parameters and code "
                      "unchanged): nothing to run (--flow records a Prefect run anyway, --force re-runs)",
                      highlight=False, soft_wrap=True)
        return cur
    _prefect_environment()
    from prefect import tags

    from hadal.flows.post_cruise import dive_tags, post_cruise

    _quiet_prefect_tracebacks()
    console.print(f"[bold]hadal[/] {raw_dir} → stages: {', '.join(names)} (on {_server_text()})", highlight=False)
    # cache hits need no process, helper or imports ahead
    running = names if force else stale_stages(raw_dir, _store_root(store), cfg_path, names, status=status)
    isolated = _prepare_while_server_boots(ctx, names, running)
    _wait_for_api()
    from hadal.forkpool import stop_helpers

    _fork_ahead(ctx, running, isolated)
    meta = getattr(ctx.dive, "metadata", None)
    before = _store_versions(ctx.store, ctx.dive_id)
    watch = _watch_api(lambda: _published_since(ctx.store, ctx.dive_id, before))
    try:
        with tags(*dive_tags(ctx.raw_dir, ctx.dive_id, getattr(meta, "cruise", None))):
            out = post_cruise(str(raw_dir), str(_store_root(store)), cfg_path, stages, force)
    except HadalError:
        raise
    except Exception:
        if watch is not None and not watch.answering():  # Prefect's client gave up on a server lost mid-run
            raise _api_lost_error(watch, _published_since(ctx.store, ctx.dive_id, before)) from None
        raise
    finally:
        if watch is not None:
            watch.stop()
        stop_helpers()
    _print_stage_table(out, time.monotonic() - t0)
    return out


def _store_versions(store: Any, dive: str) -> set[str]:
    """``product/version`` of every version of ``dive`` in the store now (what a run found at its start)."""
    try:
        return {f"{p}/{pv.label}" for p in store.products(dive) for pv in store.versions(dive, p)}
    except (HadalError, OSError):
        return set()


def _published_since(store: Any, dive: str, before: set[str]) -> list[str]:
    """The versions of ``dive`` published since ``before`` (:func:`_store_versions`), sorted."""
    return sorted(_store_versions(store, dive) - before)



def _expand_dives(dirs: list[Path]) -> list[Path]:
    """Batch inputs: a directory with dive.yaml is one dive; one without is searched for dive subdirectories."""
    from hadal.dive import find_dives

    return find_dives(*dirs)


def _run_batch(raw_dirs: list[Path], store: Path | None, config: Path | None, workers: int,
               scheduler: str | None, force: bool) -> dict:
    from hadal.errors import ConfigError
    from hadal.pipeline import claim_dive, make_context, stage_plan

    if workers < 1:
        raise ConfigError(f"--workers must be at least 1 (got {workers})")
    dives = _expand_dives(raw_dirs)
    owner: dict[str, Path] = {}
    for d in dives:  # fail fast, in one line, before starting Prefect and Dask
        ctx = make_context(d, _store_root(store), config)
        if ctx.dive_id in owner:
            raise ConfigError(f"dive id {ctx.dive_id!r} is used by both {owner[ctx.dive_id]} and {d}; give each dive "
                              "its own dive_id in its dive.yaml")
        owner[ctx.dive_id] = d
        stage_plan(ctx)
        claim_dive(ctx, check_only=True)
    if "HADAL_LOG_LEVEL" not in os.environ:  # quiet by default: one progress line per dive, warnings, errors
        for h in logging.getLogger().handlers:
            h.setLevel(logging.WARNING)
        os.environ.setdefault("PREFECT_LOGGING_LEVEL", "WARNING")  # also in the Dask workers (inherited)
        os.environ.setdefault("DASK_LOGGING__DISTRIBUTED", "warning")
        logging.getLogger("distributed").setLevel(logging.WARNING)
    _prefect_environment()
    from hadal.flows.batch import run_batch

    _quiet_prefect_tracebacks()
    _wait_for_api()

    where = f"scheduler {scheduler}" if scheduler else f"LocalCluster, {workers} worker(s)"
    console.print(f"[bold]hadal[/] batch of {len(dives)} dive(s) on {where} → the stages each dive's data supports")
    from hadal.store import ProductStore

    st = ProductStore(_store_root(store))
    before = {dive: _store_versions(st, dive) for dive in owner}

    def published() -> list[str]:
        return [f"{dive}/{v}" for dive in owner for v in _published_since(st, dive, before[dive])]

    watch = _watch_api(published)  # a server lost mid-batch: the same bounded end as a single dive's run
    try:
        return run_batch([str(d) for d in dives], str(_store_root(store)), str(config) if config else None, None,
                         workers=workers, scheduler=scheduler, force=force)
    except HadalError:
        raise
    except Exception:
        if watch is not None and not watch.answering():
            raise _api_lost_error(watch, published()) from None
        raise
    finally:
        if watch is not None:
            watch.stop()



def run(
    raw_dirs: Annotated[list[Path], typer.Argument(help="raw dive directory containing dive.yaml (several with --dives)")],
    store: StoreOpt = None,
    config: ConfigOpt = None,
    dives: Annotated[bool, typer.Option("--dives", help="batch: process every DIR (or every dive directory inside it) in parallel on Dask")] = False,
    workers: Annotated[int, typer.Option("--workers", help="batch: LocalCluster worker processes")] = 2,
    scheduler: Annotated[str | None, typer.Option("--scheduler", help="batch: address of an existing dask scheduler (tcp://host:8786)")] = None,
    force: ForceOpt = False,
    flow_run: FlowOpt = False,
) -> None:
    """Run the full post-cruise flow on one dive, or on several in parallel (--dives DIR...).

    A dive whose stages are all current (raw files, parameters, code and upstream versions unchanged since their
    products were published) is told in one line without starting Prefect; --flow runs (and records) the flow."""
    if not dives and len(raw_dirs) == 1:
        out = _run_flow(raw_dirs[0], store, config, None, force, flow_run)
        _print_published(out)
        _print_report_path(out)
        return
    results = _run_batch(raw_dirs, store, config, workers, scheduler, force)
    table = Table(title="batch")
    for col in ("dive directory", "status", "products"):
        table.add_column(col)
    for raw, r in results.items():
        table.add_row(raw, "ok" if r["ok"] else f"failed: {r.get('error', '')}", ", ".join(r.get("published", {})))
    Console().print(table)
    for r in results.values():
        _print_report_path(r.get("published") or {})
    failed = [raw for raw, r in results.items() if not r["ok"]]
    if failed:
        console.print(f"[red]error:[/] {len(failed)} of {len(results)} dive(s) failed", highlight=False)
        raise typer.Exit(1)
