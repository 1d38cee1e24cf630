"""``hadal stage``: re-run one stage, reusing the latest upstream products."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from hadal.cli._common import (
    ConfigOpt,
    FlowOpt,
    ForceOpt,
    StoreOpt,
    _print_published,
    _print_report_path,
    _store_root,
    console,
)
from hadal.cli.run import _run_flow


def stage(
    name: Annotated[str, typer.Argument(help="stage name (ingest, derive, dtm, laser, suitability, match, profile, "
                                             "landing, report; grid = dtm + laser)")],
    raw_dir: Annotated[Path, typer.Argument(help="raw dive directory containing dive.yaml")],
    store: StoreOpt = None,
    config: ConfigOpt = None,
    force: ForceOpt = False,
    downstream: Annotated[bool, typer.Option(
        "--downstream", help="also re-run every stage that depends on it (directly or through other stages)")] = False,
    flow_run: FlowOpt = False,
) -> None:
    """Re-run one stage, reusing the latest upstream products (a cache hit if nothing changed; --force re-runs).

    ``grid`` re-runs both gridding stages (dtm and laser) that the dive's data supports. The report is refreshed
    after it (a cache hit when nothing changed). Without --downstream, the stages that depend on NAME keep their
    products made from its previous version: the command says which ones are stale."""
    from hadal.stages.plan import downstream_stages, resolve_stages

    names = resolve_stages([name])  # unknown or unimplemented: one line; a group (grid): its stages
    dependents = downstream_stages(name)
    stages = [name, *dependents] if downstream else [name, *(["report"] if name != "report" else [])]
    stages = _runnable_with(stages, raw_dir, store, config)
    out = _run_flow(raw_dir, store, config, stages, force, flow_run)
    _print_published(out)
    _print_report_path(out)
    rows = {r["stage"]: r for r in getattr(out, "stages", [])}
    fresh = [n for n in names if rows.get(n, {}).get("status") == "published"]  # of a group: those that published
    stale_set = {s for n in fresh for s in downstream_stages(n)} - {"report"}
    stale = [s for s in dependents if s in stale_set]
    if not downstream and stale:
        console.print(f"note: {', '.join(stale)} still use(s) the previous {'/'.join(fresh)} products; "
                      f"'hadal stage {name} {raw_dir} --downstream' re-runs them", highlight=False)


def _runnable_with(stages: list[str], raw_dir: Path, store: Path | None, config: Path | None) -> list[str]:
    """``stages`` less a trailing ``report`` the dive's plan would refuse (never the stage the user named)."""
    from hadal.pipeline import make_context
    from hadal.stages.plan import plan_stages

    ctx = make_context(raw_dir, _store_root(store), config)
    ok = {ps.name for ps in plan_stages(ctx.dive, stages, store=ctx.store) if ps.run}
    return [s for i, s in enumerate(stages) if i == 0 or s in ok]
