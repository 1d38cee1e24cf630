"""The post-cruise flow: raw dive → ingest ‖ dtm ‖ laser → derive ‖ suitability ‖ landing → match → profile → report.

The flow hands the stage graph to Prefect (issue 44): :func:`submit_dive` walks it once
(:func:`hadal.pipeline.walk_stage_graph`, the walk the in-process runner :func:`hadal.pipeline.run_pipeline` and the
Prefect-free cache check :func:`hadal.pipeline.stage_cache_status` share) and submits each stage task once, with its
upstream stages' futures as a parameter wrapped in ``allow_failure``: Prefect starts a stage when the stages whose
products it reads (:func:`hadal.stages.plan.stage_dependencies`) are done, ``dtm`` and ``laser`` do not wait for
``ingest``/``derive``, ``landing`` not for ``match``, ``match`` not for ``laser``. The upstream results carry the
pins: every stage reads the upstream versions the run found at its start or its upstream stages published, never
a concurrent run's newer ones. A stage whose upstream failed skips itself with the reason, and the report still
runs and lists the failures. At most ``resources.parallel_stages`` stages run at once: the max_workers of the
Prefect thread-pool task runner (default the CPU cores, at least 2: :func:`hadal.budget.parallel_stages`), filled
ready ones first (:func:`hadal.pipeline.graph_order`), so on a small machine the DTM chain (dtm → suitability →
match, the longest) is not slowed by the laser clouds. The Dask batch flow (``flows/batch.py``) uses the same
:func:`submit_dive` and :func:`collect_dives`.
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
from prefect.utilities.annotations import allow_failure

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
    walk_stage_graph,
)
from hadal.stages.plan import stage_dependencies

log = logging.getLogger("hadal.flow")


def stage_tasks(names: list[str]):
    return [getattr(importlib.import_module(f"hadal.tasks.{n}"), n) for n in names]


@dataclass
class DiveRun:
    """One dive of a flow run: the stages to run (plan order), the versions found at the start (pins), the stage
    tasks' futures (:func:`submit_dive`) and, once they are done (:func:`collect_dives`), the run table's rows."""

    raw_dir: str
    names: list[str]
    pins: dict[str, str]
    isolate: set[str] = field(default_factory=set)
    futures: dict[str, Any] = field(default_factory=dict)
    done_at: dict[str, float] = field(default_factory=dict)
    published: dict[str, str] = field(default_factory=dict)
    failed: dict[str, str] = field(default_factory=dict)
    skips: dict[str, str] = field(default_factory=dict)
    rows: list[dict[str, Any]] = field(default_factory=list)
    unexpected: BaseException | None = None
    t0: float = field(default_factory=time.monotonic)

    def outcome(self) -> RunOutcome:
        return RunOutcome(self.published, self.rows)


def process_stages(names: list[str]) -> set[str]:
    """The stages of ``names`` to run in their own process (:mod:`hadal.stage_process`): those whose record says
    ``process=True`` (:class:`hadal.stages.Stage`) and that may run at the same time as another stage of the run (neither upstream nor
    downstream of it: :func:`hadal.stages.plan.downstream_stages`); a stage that always runs alone gains nothing from a
    process but pays its start (about 1.5 s of imports)."""
    from hadal.stages.graph import stage
    from hadal.stages.plan import downstream_stages

    down = {n: set(downstream_stages(n, names)) for n in names}
    return {n for n in names if stage(n).process
            and any(o != n and o not in down[n] and n not in down[o] for o in names)}


def skipped_reason(raw_dir: str, pins: dict[str, str], name: str, store_root: str | None,
                   config_path: str | None) -> str:
    """Why stage ``name`` published nothing: its content check (:func:`hadal.stages.plan.runtime_skip_reason`, e.g.
    landing's laser cells coarser than the vehicle allows) on the products this run pinned (``pins``); the table
    shows it, not just "see the log"."""
    from hadal.stages.plan import runtime_skip_reason

    try:
        ctx = make_context(raw_dir, store_root, config_path)
        pin_paths(ctx, pins)
        why = runtime_skip_reason(name, ctx)
    except (HadalError, OSError):
        why = None
    return why or "nothing to do (see the log)"


def submit_dive(runner: Any, d: DiveRun, store_root: str | None, config_path: str | None, force: bool) -> None:
    """Hand dive ``d``'s stage graph to the Prefect task ``runner`` (the flow's thread pool, or the batch's Dask
    runner): each stage task submitted once (:func:`hadal.pipeline.walk_stage_graph`), its upstream stages' futures
    passed as its ``upstream`` parameter and in ``wait_for``, both through ``allow_failure`` so a stage whose
    upstream failed still starts, skips itself with the reason (and the report lists the failure). ``force``: every
    task bypasses its cache."""
    tasks = dict(zip(d.names, stage_tasks(d.names), strict=True))

    def step(name: str, upstream: dict[str, Any]) -> Any:
        params = {"raw_dir": d.raw_dir, "store_root": store_root, "config_path": config_path, "pins": dict(d.pins),
                  "upstream": {u: allow_failure(f) for u, f in upstream.items()}, "isolate": name in d.isolate}
        return runner.submit(configured(tasks[name], store_root, force), params,
                             wait_for=[allow_failure(f) for f in upstream.values()])

    d.t0 = time.monotonic()
    d.futures = walk_stage_graph(d.names, step)


def collect_dives(dives: list[DiveRun], store_root: str | None, config_path: str | None,
                  on_dive_done: Callable[[DiveRun], None] | None = None) -> None:
    """Wait for the stage tasks of every dive (:func:`submit_dive`) and record, when a dive's are all done, its run
    table (:func:`record_dive`); then ``on_dive_done(dive)`` (the batch's progress line)."""
    def finish(d: DiveRun) -> None:
        record_dive(d, store_root, config_path)
        if on_dive_done is not None:
            on_dive_done(d)

    owner = {f: (d, n) for d in dives for n, f in d.futures.items()}
    left = {id(d): len(d.futures) for d in dives}
    for d in dives:
        if not d.futures:
            finish(d)
    for fut in as_completed(list(owner)):
        d, name = owner[fut]
        d.done_at[name] = time.monotonic()
        left[id(d)] -= 1
        if left[id(d)] == 0:
            finish(d)


def record_dive(d: DiveRun, store_root: str | None, config_path: str | None) -> None:
    """Dive ``d``'s rows (published / reused / skipped / failed, with the reason) from its stage tasks' final states.
    A stage's seconds run from when its last upstream stage finished (or the submission) to its own end."""
    deps = stage_dependencies(d.names)
    states = {}
    for name, fut in d.futures.items():
        fut.wait()  # sets the future's final state (the done callback alone may leave it PENDING)
        states[name] = fut.state
    for name in d.names:
        state = states[name]
        if state.is_completed():
            continue
        exc = state.result(raise_on_failure=False) if state.is_failed() else None
        msg = str(exc).splitlines()[0] if isinstance(exc, BaseException) and str(exc) else state.name
        d.failed[name] = msg
        if isinstance(exc, BaseException) and not isinstance(exc, HadalError) and d.unexpected is None:
            d.unexpected = exc
    for name in d.names:
        state = states[name]
        ready = max([d.t0, *(d.done_at.get(u, d.t0) for u in deps[name])])
        seconds = round(max(0.0, d.done_at.get(name, ready) - ready), 2)
        if name in d.failed:
            d.rows.append({"stage": name, "status": "failed", "seconds": seconds, "versions": {},
                           "reason": d.failed[name]})
            continue
        if (why := blocked_by_failure(name, d.failed)) is not None:
            print(f"stage {name} skipped: {why}")
            d.skips[name] = why
            d.rows.append({"stage": name, "status": "skipped", "seconds": 0.0, "versions": {}, "reason": why})
            continue
        out = state.result()
        if not published_exist(out):  # a cache record the task could not check (:func:`hadal.pipeline.drop_gone_result`)
            d.failed[name] = "its cached versions are gone; run it again with --force"
            d.rows.append({"stage": name, "status": "failed", "seconds": seconds, "versions": {},
                           "reason": d.failed[name]})
            continue
        reused = state.name == "Cached"
        versions = {p: Path(v).name for p, v in out.items()}
        if reused:
            log.info("stage %s: cache hit (inputs, parameters and code unchanged): reusing %s", name,
                     ", ".join(f"{p}/{v}" for p, v in versions.items()) or "nothing")
        d.published.update(out)
        d.rows.append({"stage": name, "status": "reused" if reused else ("published" if out else "skipped"),
                       "seconds": seconds, "versions": versions,
                       "reason": "" if out or reused else skipped_reason(d.raw_dir, {**d.pins, **d.published}, name,
                                                                          store_root, config_path)})


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


@flow(name="post-cruise", log_prints=True, flow_run_name=flow_run_name)
def post_cruise(
    raw_dir: str,
    store_root: str | None = None,
    config_path: str | None = None,
    stages: list[str] | None = None,
    force: bool = False,
) -> RunOutcome:
    """Process one dive: run the selected stages (default: all the dive's data supports, :mod:`hadal.stages.plan`), each
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
    names = [ps.name for ps in plan if ps.run]
    isolate = process_stages(names) if resources_of(ctx.config).stage_processes else set()
    d = DiveRun(raw_dir, names, {p: str(pv.path) for p, pv in ctx.pins.items()}, isolate)
    # the dive/cruise tags are the flow run's; the stage task runs are left untagged: Prefect acquires a tag
    # concurrency slot for every tagged task run, whose service restarts took ~2 s before each stage on a busy
    # 2-core machine (the wait before derive, suitability and report: 6 s of a 67 s cold dive)
    runner: ThreadPoolTaskRunner[Any] = ThreadPoolTaskRunner(max_workers=parallel_stages(ctx.config))
    with TagsContext(current_tags=set()), runner:
        submit_dive(runner, d, store_root, config_path, force)
        collect_dives([d], store_root, config_path)
    d.rows = rows + d.rows
    order = {ps.name: i for i, ps in enumerate(plan)}
    d.rows.sort(key=lambda r: order.get(r["stage"], 99))
    if d.unexpected is not None:
        raise d.unexpected
    raise_failures(d.failed)
    return d.outcome()
