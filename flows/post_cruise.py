"""The post-cruise flow: raw dive → ingest ‖ dtm ‖ laser → derive ‖ suitability ‖ landing → match → report.

Stages run as soon as the stages whose products they read are done (:func:`hadal.plan.stage_dependencies`), on
Prefect's thread-pool task runner: ``dtm`` and ``laser`` do not wait for ``ingest``/``derive``, ``landing`` not
for ``match``, ``match`` not for ``laser``. At most ``resources.parallel_stages`` run at once (default the CPU
cores, at least 2: :func:`hadal.budget.parallel_stages`), the ready ones first in stage order, so on a small
machine the DTM chain (dtm → suitability → match, the longest) is not slowed by the laser clouds.
Every stage reads the upstream versions the run found at its start or published itself (pins), never a concurrent
run's newer ones. :func:`run_stage_graph` is shared with the Dask batch flow (``flows/batch.py``).
"""

from __future__ import annotations

import datetime as _dt
import importlib
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hadal.tasks.stage import configured, published_exist, route_hadal_logs
from prefect import flow
from prefect.context import TagsContext
from prefect.futures import as_completed
from prefect.task_runners import ThreadPoolTaskRunner

from hadal.budget import parallel_stages, resources_of
from hadal.errors import HadalError
from hadal.pipeline import (
    RunOutcome,
    all_products,
    blocked_by_failure,
    make_context,
    pin_paths,
    raise_failures,
    stage_plan,
)
from hadal.plan import stage_dependencies

log = logging.getLogger("hadal.flow")

#: threads of the single-dive flow's task runner (one per stage: the scheduler, not the pool, limits how many run)
STAGE_THREADS = 8


def stage_tasks(names: list[str]):
    return [getattr(importlib.import_module(f"hadal.tasks.{n}"), n) for n in names]


@dataclass
class DiveRun:
    """The bookkeeping of one dive inside :func:`run_stage_graph`."""

    raw_dir: str
    names: list[str]
    pins: dict[str, str]
    deps: dict[str, set[str]] = field(default_factory=dict)
    waiting: list[str] = field(default_factory=list)
    running: set[str] = field(default_factory=set)
    published: dict[str, str] = field(default_factory=dict)
    failed: dict[str, str] = field(default_factory=dict)
    skips: dict[str, str] = field(default_factory=dict)
    rows: list[dict[str, Any]] = field(default_factory=list)
    unexpected: BaseException | None = None
    t0: float = field(default_factory=time.monotonic)

    def __post_init__(self) -> None:
        self.deps = stage_dependencies(self.names)
        self.waiting = list(self.names)

    @property
    def done(self) -> bool:
        return not self.waiting and not self.running

    def outcome(self) -> RunOutcome:
        return RunOutcome(self.published, self.rows)


def process_stages(names: list[str]) -> set[str]:
    """The stages of ``names`` to run in their own process (:mod:`hadal.stage_process`): those whose record says
    ``process=True`` (:class:`hadal.stages.Stage`) and that may run at the same time as another stage of the run (neither upstream nor
    downstream of it: :func:`hadal.plan.downstream_stages`); a stage that always runs alone gains nothing from a
    process but pays its start (about 1.5 s of imports)."""
    from hadal.plan import downstream_stages
    from hadal.stages.graph import stage

    down = {n: set(downstream_stages(n, names)) for n in names}
    return {n for n in names if stage(n).process
            and any(o != n and o not in down[n] and n not in down[o] for o in names)}


def skipped_reason(d: DiveRun, name: str, store_root: str | None, config_path: str | None) -> str:
    """Why stage ``name`` published nothing: its content check (:func:`hadal.plan.runtime_skip_reason`, e.g.
    landing's laser cells coarser than the vehicle allows) on the products this run pinned; the table shows it,
    not just "see the log"."""
    from hadal.plan import runtime_skip_reason

    try:
        ctx = make_context(d.raw_dir, store_root, config_path)
        pin_paths(ctx, d.pins)
        why = runtime_skip_reason(name, ctx)
    except (HadalError, OSError):
        why = None
    return why or "nothing to do (see the log)"


def run_stage_graph(dives: list[DiveRun], store_root: str | None, config_path: str | None, force: bool,
                    on_dive_done: Callable[[DiveRun], None] | None = None, max_running: int | None = None,
                    isolate: bool = False) -> None:
    """Submit every dive's stages to the flow's task runner as soon as their upstream stages are done (at most
    ``max_running`` at once, None: no limit; ready stages in plan order); record each stage's outcome in its
    :class:`DiveRun`. A stage whose upstream failed in this run is skipped with the reason; the report still runs
    (and lists the failures). ``isolate``: stages in :func:`process_stages` run in their own processes."""
    tasks = {n: t for d in dives for n, t in zip(d.names, stage_tasks(d.names), strict=True)}
    running: dict[Any, tuple[DiveRun, str, float, bool]] = {}
    in_process = {id(d): process_stages(d.names) if isolate else set() for d in dives}

    def submit(d: DiveRun, name: str, forced: bool) -> None:
        notes: dict[str, Any] = {"isolate": True} if name in in_process[id(d)] else {}
        if name == "report" and d.failed:
            notes.update(failed=dict(d.failed), failed_skips=dict(d.skips))
        fut = configured(tasks[name], store_root, forced).submit(d.raw_dir, store_root, config_path, dict(d.pins),
                                                                 **notes)
        running[fut] = (d, name, time.monotonic(), forced)
        d.running.add(name)

    while True:
        for d in dives:  # submit every stage whose upstream stages are done (in plan order, while slots are free)
            for name in list(d.waiting):
                if d.deps[name] & (set(d.waiting) | d.running):
                    continue
                if max_running is not None and len(running) >= max_running \
                        and blocked_by_failure(name, d.failed) is None:
                    break
                d.waiting.remove(name)
                if (why := blocked_by_failure(name, d.failed)) is not None:
                    print(f"stage {name} skipped: {why}")
                    d.skips[name] = why
                    d.rows.append({"stage": name, "status": "skipped", "seconds": 0.0, "versions": {},
                                   "reason": why})
                    continue
                submit(d, name, force)
        if not running:
            break
        fut = next(as_completed(list(running)))
        d, name, t_submit, forced = running.pop(fut)
        d.running.discard(name)
        fut.wait()  # sets the future's final state (the done callback alone may leave it PENDING)
        state = fut.state
        seconds = time.monotonic() - t_submit
        if state.is_completed():
            out = fut.result()
            if not forced and not published_exist(out):  # a cached result whose versions were removed: re-run
                log.info("stage %s: cached versions are gone, re-running", name)
                submit(d, name, True)
                continue
            reused = state.name == "Cached"
            status = "reused" if reused else ("published" if out else "skipped")
            versions = {p: Path(v).name for p, v in out.items()}
            if reused:
                log.info("stage %s: cache hit (inputs, parameters and code unchanged): reusing %s", name,
                         ", ".join(f"{p}/{v}" for p, v in versions.items()) or "nothing")
            d.pins.update(out)
            d.published.update(out)
            d.rows.append({"stage": name, "status": status, "seconds": round(seconds, 2), "versions": versions,
                           "reason": "" if out or reused else skipped_reason(d, name, store_root, config_path)})
        else:
            exc = state.result(raise_on_failure=False)
            msg = str(exc).splitlines()[0] if isinstance(exc, BaseException) and str(exc) else state.name
            d.failed[name] = msg
            if isinstance(exc, BaseException) and not isinstance(exc, HadalError) and d.unexpected is None:
                d.unexpected = exc
            d.rows.append({"stage": name, "status": "failed", "seconds": round(seconds, 2), "versions": {},
                           "reason": msg})
        if d.done and on_dive_done is not None:
            on_dive_done(d)


def dive_tags(raw_dir: str | Path, dive_id: str, cruise: str | None = None) -> list[str]:
    """Prefect tags of a dive's runs: ``dive:<id>`` and ``cruise:<name>`` (``metadata.cruise`` of dive.yaml, else
    the name of the directory holding the dive directory)."""
    cruise = cruise or Path(raw_dir).resolve().parent.name
    return [f"dive:{dive_id}", f"cruise:{cruise}"]


def _dive_info(raw_dir: str) -> tuple[str, str | None]:
    from hadal.dive import load_dive

    dive, _ = load_dive(raw_dir)
    meta = getattr(dive, "metadata", None)
    return dive.dive_id, getattr(meta, "cruise", None)


def flow_run_name() -> str:
    """``<dive>-<UTC time>`` for a run of :func:`post_cruise` (``<raw dir name>-<time>`` if dive.yaml is bad)."""
    from prefect.runtime import flow_run

    raw = str(flow_run.parameters.get("raw_dir", "dive"))
    try:
        dive = _dive_info(raw)[0]
    except Exception:  # noqa: BLE001 - the flow itself reports a bad dive.yaml; a name is still needed
        dive = Path(raw).name or "dive"
    return f"{dive}-{_dt.datetime.now(_dt.UTC):%Y%m%dT%H%M%SZ}"


def tag_flow_run(extra: list[str]) -> None:
    """Add ``extra`` tags to the current flow run (deployments start runs with the deployment's tags only)."""
    from prefect.context import FlowRunContext

    ctx = FlowRunContext.get()
    if ctx is None or ctx.flow_run is None or set(extra) <= set(ctx.flow_run.tags or ()):
        return
    try:
        from prefect.client.orchestration import get_client

        with get_client(sync_client=True) as client:
            client.update_flow_run(ctx.flow_run.id, tags=sorted({*(ctx.flow_run.tags or ()), *extra}))
    except Exception as exc:  # noqa: BLE001 - tags are a convenience
        log.debug("could not tag the flow run: %s", exc)


@flow(name="post-cruise", log_prints=True, flow_run_name=flow_run_name,
      task_runner=ThreadPoolTaskRunner(max_workers=STAGE_THREADS))
def post_cruise(
    raw_dir: str,
    store_root: str | None = None,
    config_path: str | None = None,
    stages: list[str] | None = None,
    force: bool = False,
) -> RunOutcome:
    """Process one dive: run the selected stages (default: all the dive's data supports, :mod:`hadal.plan`), each
    as soon as the stages it reads from are done, each publishing new product versions; skipped stages are
    logged with the reason (and listed by the report).

    Unchanged stages are cache hits (their published versions are reused); ``force`` re-runs them all.
    Returns ``{product: version directory}`` for every stage that ran or was reused (a :class:`RunOutcome`,
    whose ``stages`` says per stage whether it published, reused, was skipped or failed, and its time).
    """
    route_hadal_logs()
    ctx = make_context(raw_dir, store_root, config_path)
    plan = stage_plan(ctx, stages)
    for stale in ctx.store.clean_staging():  # left by a killed run more than an hour ago
        print(f"removed abandoned staging directory {stale}")
    ctx.pin_existing(all_products())  # the run reads what it found at its start or published itself
    meta = getattr(ctx.dive, "metadata", None)
    dtags = dive_tags(ctx.raw_dir, ctx.dive_id, getattr(meta, "cruise", None))
    tag_flow_run(dtags)
    rows = []
    for ps in plan:
        if not ps.run:
            print(f"stage {ps.name} skipped: {ps.reason}")
            rows.append({"stage": ps.name, "status": "skipped", "seconds": 0.0, "versions": {}, "reason": ps.reason})
    d = DiveRun(raw_dir, [ps.name for ps in plan if ps.run], {p: str(pv.path) for p, pv in ctx.pins.items()})
    d.rows = rows
    # the dive/cruise tags are the flow run's; the stage task runs are left untagged: Prefect acquires a tag
    # concurrency slot for every tagged task run, whose service restarts took ~2 s before each stage on a busy
    # 2-core machine (the wait before derive, suitability and report: 6 s of a 67 s cold dive)
    with TagsContext(current_tags=set()):
        run_stage_graph([d], store_root, config_path, force, max_running=parallel_stages(ctx.config),
                        isolate=resources_of(ctx.config).stage_processes)
    order = {ps.name: i for i, ps in enumerate(plan)}
    d.rows.sort(key=lambda r: order.get(r["stage"], 99))
    if d.unexpected is not None:
        raise d.unexpected
    raise_failures(d.failed)
    return d.outcome()
