"""Prefect-free pipeline driver: build a :class:`StageContext` and run stages in order.

The Prefect flow (``flows/post_cruise.py``) and tasks (``tasks/``) call these functions; so can a
notebook or a test, without an orchestrator.
"""

from __future__ import annotations

import functools
import hashlib
import logging
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TypeVar

from hadal.errors import HadalError, InputError, StageError
from hadal.stages import (
    STAGE_GROUPS,
    NullProgress,
    Progress,
    StageContext,
)
from hadal.stages.graph import all_products, dependencies, producer_of, stage
from hadal.stages.plan import PlannedStage, check_plan, plan_stages, runtime_skip_reason
from hadal.store import ProductStore, ProductVersion

if TYPE_CHECKING:
    from hadal.settings import PipelineConfig

DIVE_CONFIG_FILE = "pipeline.yaml"
T = TypeVar("T")


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
    from hadal.dive import load_dive
    from hadal.settings import PipelineConfig, load_config

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


def claim_dive(ctx: StageContext, *, check_only: bool = False, update: bool = True) -> list[Path] | None:
    """Record (or, ``check_only``, just check) that the dive id belongs to this raw directory, atomically
    (:meth:`ProductStore.claim_dive`: ``None`` unless this call made a new claim; ``update=False``: only a new
    claim is written)."""
    from hadal.dive import dive_fingerprint

    return ctx.store.claim_dive(ctx.dive_id, ctx.raw_dir, dive_fingerprint(ctx.dive, ctx.raw_dir),
                                check_only=check_only, update=update)


def run_stage(name: str, ctx: StageContext, run_info: dict[str, Any] | None = None) -> dict[str, ProductVersion]:
    """Run one stage; it reads the latest upstream products and publishes new versions.

    Each manifest it writes records ``stage_run`` (:data:`hadal.store.STAGE_RUN`): the stage, its start time, the
    seconds from its start to that publish, and ``run_info`` (e.g. the Prefect flow/task run ids).
    A group name (:data:`hadal.stages.STAGE_GROUPS`: ``grid``) runs its stages that the dive's data supports, in
    order (an error saying why when it supports none)."""
    import datetime as _dt
    import time

    from hadal.store import STAGE_RUN

    if name in STAGE_GROUPS:
        claim_dive(ctx, check_only=True)  # refuse another directory's dive id before anything else
        out: dict[str, ProductVersion] = {}
        for ps in stage_plan(ctx, [name]):
            if ps.run:
                out.update(run_stage(ps.name, ctx, run_info))
                ctx.pins.update(out)
        return out
    rec = stage(name)
    # claim the dive id for this raw directory before any work, atomically: of two runs claiming one id for two
    # directories at once, one is refused here before it publishes; a new claim is undone if nothing is published
    created = claim_dive(ctx, update=False)
    ctx.log.info("stage %s: start", name)
    t0 = time.monotonic()
    token = STAGE_RUN.set({"stage": name, "started_utc": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
                           "t0": t0, **(run_info or {})})
    out = {}
    try:
        from hadal.products.metadata import dive_context  # the writers take ACDD metadata/paths from the dive

        with dive_context(ctx.dive, ctx.raw_dir):
            out = rec.run(ctx)
    finally:
        STAGE_RUN.reset(token)
        if created is not None and not out:
            ctx.store.release_claim(ctx.dive_id, ctx.raw_dir, created)
    if out:
        claim_dive(ctx)
    for product, pv in out.items():
        ctx.log.info("stage %s: published %s/%s/%s (%.1f s)", name, pv.dive, product, pv.label, time.monotonic() - t0)
    return out


class RunOutcome(dict):
    """``{product: version directory}`` of a run, with :attr:`stages`: one row per stage (``stage``, ``status`` -
    published / reused / skipped / failed -, ``seconds``, ``versions`` and ``reason``) for the closing table."""

    def __init__(self, published: dict[str, str] | None = None, stages: list[dict[str, Any]] | None = None):
        super().__init__(published or {})
        self.stages = list(stages or [])

    def __reduce__(self):  # results may be pickled (Dask, persisted results): keep the stage rows
        return (RunOutcome, (dict(self), self.stages))


def stage_plan(ctx: StageContext, stages: Sequence[str] | None = None) -> list[PlannedStage]:
    """The run plan (:func:`hadal.stages.plan.plan_stages`) for ``ctx``'s dive, checked (:func:`hadal.stages.plan.check_plan`).

    A stage named explicitly in ``stages`` that the data cannot support is an error (saying why); in a
    whole-dive run (``stages`` empty), and for a group name (``grid``) while another of its stages runs, such
    stages are skipped and logged.
    """
    if not ctx.dive.sources.kinds() and not stages:
        raise InputError(f"{ctx.raw_dir}/dive.yaml lists no source files: nothing to process (hadal init "
                         f"{ctx.raw_dir} lists what it finds there)")
    plan = plan_stages(ctx.dive, stages, store=ctx.store if stages else None)
    check_plan(ctx.dive, plan)
    if stages:  # a group's stage the data cannot support is skipped while another of the group runs
        runs = {ps.name for ps in plan if ps.run}
        grouped = {m for g in stages for m in STAGE_GROUPS.get(g, ()) if runs & set(STAGE_GROUPS[g])}
        refused = [ps for ps in plan if not ps.run and ps.name not in grouped]
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
    for product in stage(name).inputs.upstream:
        maker = producer_of(product)
        if maker in failed:
            return f"needs {product}, but stage {maker} failed in this run"
    return None


def graph_order(names: Sequence[str]) -> list[str]:
    """The stages of a run (``names``, in plan order) in the order the graph is walked and handed to a task runner:
    by depth in the graph (the longest chain of stages of the run above it), then plan order. Every stage comes
    after the stages it reads from, and a first-in-first-out pool of N workers starts the stages that are ready
    first (``ingest``, ``dtm`` and ``laser`` before ``derive``), as a scheduler "ready ones first, in stage order"
    would: a stage taken from the pool while its upstream still runs holds a worker, so one that is ready must
    not queue behind it."""
    deps = dependencies(list(names))
    depth: dict[str, int] = {}
    for name in names:  # plan order is a topological order
        depth[name] = 1 + max((depth[u] for u in deps[name]), default=-1)
    plan = {n: i for i, n in enumerate(names)}
    return sorted(names, key=lambda n: (depth[n], plan[n]))


def walk_stage_graph(names: Sequence[str], step: Callable[[str, dict[str, T]], T]) -> dict[str, T]:
    """The one walk of a run's stage graph (issue 44): ``step(stage, {upstream stage: its handle})`` for each stage
    of ``names`` once, in :func:`graph_order`, given the handles ``step`` returned for the stages of the run it reads
    from (:func:`hadal.stages.graph.dependencies`); returns ``{stage: handle}``.

    The flow's handle is a Prefect future (each stage task submitted once with its upstream futures:
    ``flows/post_cruise.submit_dive``); :func:`run_pipeline`'s is the stage's outcome, run in this process;
    :func:`stage_cache_status`'s is the cached result the task would reuse."""
    deps = dependencies(list(names))
    handles: dict[str, T] = {}
    for name in graph_order(names):
        handles[name] = step(name, {u: handles[u] for u in names if u in deps[name]})
    return handles


def run_pipeline(ctx: StageContext, stages: Sequence[str] | None = None) -> dict[str, ProductVersion]:
    """Run the stages the dive's data supports (of ``stages``, default all) in this process, one after the other in
    :func:`graph_order` (the walk the flow hands to Prefect: :func:`walk_stage_graph`); see :func:`stage_plan`.

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

    def step(name: str, upstream: dict[str, None]) -> None:
        if (why := blocked_by_failure(name, ctx.failed)) is not None:
            ctx.log.warning("stage %s skipped: %s", name, why)
            ctx.failed_skips[name] = why
            return
        if not should_run(name, ctx):
            return
        try:
            out = run_stage(name, ctx)
        except HadalError as exc:
            ctx.log.error("stage %s failed: %s", name, exc)
            ctx.failed[name] = str(exc)
            return
        ctx.pins.update(out)
        results.update(out)

    walk_stage_graph([ps.name for ps in plan if ps.run], step)
    raise_failures(ctx.failed)
    return results


def raise_failures(failed: dict[str, str]) -> None:
    """One :class:`StageError` naming every failed stage and its one-line error (nothing when none failed)."""
    if failed:
        raise StageError(f"{len(failed)} stage(s) failed ({'; '.join(f'{k}: {v}' for k, v in failed.items())}); "
                         "the other stages ran and the report lists the failures")


def pin_paths(ctx: StageContext, pins: dict[str, str] | None) -> None:
    """Pin the versions named by ``{product: version directory}`` (a flow passes them between its tasks)."""
    for product, path in (pins or {}).items():
        ctx.pins[product] = ctx.store.version_at(path)


# ------------------------------------------------------------------------ stage fingerprints (Prefect-free)
#: where the stage tasks' results (Prefect cache records) live: ``<store>/.prefect-results/<cache key>``
RESULTS_DIR = ".prefect-results"


def result_storage(store_root: str | os.PathLike[str] | None) -> Path:
    """Where task results (cache records) are persisted: ``<store>/.prefect-results``."""
    root = Path(store_root) if store_root is not None else default_store_root()
    return (root / RESULTS_DIR).resolve()


def raw_inputs(name: str, ctx: StageContext) -> list[Path]:
    """Raw files stage ``name`` reads: ``dive.yaml`` always; those its module's ``raw_files(ctx)`` names (derive's
    ``overlying_profile``); the files of its ``INPUTS.raw_any`` source kinds when it reads raw data
    (``Stage.inputs.reads_raw``), and the vehicle mapping for ``ingest``."""
    from hadal.confine import files_read
    from hadal.dive import resolve_source

    rec = stage(name)
    files = [ctx.raw_dir / "dive.yaml"]
    if rec.raw_files is not None:  # files a stage's settings point at (derive's overlying_profile)
        files.extend(rec.raw_files(ctx))
    inp = rec.inputs
    if not inp.reads_raw:
        return files
    if name == "ingest" and ctx.dive.vehicle_config:
        files.append(resolve_source(ctx.raw_dir, ctx.dive.vehicle_config))
    for kind in inp.raw_any:
        for e in ctx.dive.sources.files(kind):
            f = resolve_source(ctx.raw_dir, e)
            files.extend([f, *files_read(f, ctx.raw_dir)[1:]])  # and a VRT's sources (hadal.confine)
    return files


def stage_fingerprint(name: str, ctx: StageContext) -> dict[str, Any]:
    """Everything a stage's output depends on (the stage task's cache key, ``tasks/stage.py``); JSON-serialisable.

    The stage, dive and store; hadal's code (:func:`code_digest`); the stage's parameters; the SHA-256 of the raw
    files it reads (:func:`raw_inputs`, cached by size/mtime/inode/ctime: :meth:`ProductStore.file_sha256`); the
    manifests (SHA-256) of the pinned (else latest) versions of every product it reads (:attr:`Stage.reads`:
    required and optional; ``UPSTREAM`` used to leave out optional ones, e.g. the report's navigation)."""
    from hadal.store import sha256_file

    raw = {}
    for f in raw_inputs(name, ctx):  # unchanged files are not re-read: ProductStore.file_sha256
        raw[str(f)] = ctx.store.file_sha256(f) if f.is_file() else "missing"
    upstream = {}
    for product in stage(name).reads:
        pv = ctx.pins.get(product) or (ctx.store.latest(ctx.dive_id, product)
                                       if ctx.store.has(ctx.dive_id, product) else None)
        upstream[product] = f"{pv.label}:{sha256_file(pv.manifest_path)}" if pv is not None else "missing"
    return {
        "stage": name,
        "dive": ctx.dive_id,
        "store": str(Path(ctx.store.root).resolve()),
        "code": code_digest(),
        "params": ctx.params(name),
        "raw": raw,
        "upstream": upstream,
    }


def fingerprint_key(fp: dict[str, Any]) -> str:
    import json

    return hashlib.sha256(json.dumps(fp, sort_keys=True, default=str).encode()).hexdigest()


def stage_cache_key(name: str, raw_dir: str | Path, store_root: str | Path | None, config_path: str | Path | None,
                    pins: dict[str, str] | None = None, failed: dict[str, str] | None = None,
                    failed_skips: dict[str, str] | None = None) -> str:
    """The cache key of stage ``name``'s task for these task parameters: ``hadal-<stage>-<SHA-256 of its
    fingerprint>`` (the report's key also covers the failures of the run it lists)."""
    ctx = make_context(raw_dir, store_root, config_path)
    pin_paths(ctx, pins)
    fp = stage_fingerprint(name, ctx)
    if failed or failed_skips:  # the report lists this run's failures
        fp["failed"] = {"failed": failed, "skips": failed_skips}
    return f"hadal-{name}-{fingerprint_key(fp)}"


def _plain_unpickle(data: bytes) -> Any:
    """Unpickle plain data only (dict/list/str/...: a task result is ``{product: version directory}``); any class
    reference is refused."""
    import io
    import pickle

    class _Plain(pickle.Unpickler):
        def find_class(self, module: str, name: str):
            raise pickle.UnpicklingError(f"{module}.{name} is not plain data")

    return _Plain(io.BytesIO(data)).load()


def cached_result(storage: Path, key: str) -> dict[str, str] | None:
    """The result Prefect persisted for cache key ``key`` in ``storage`` (a ``ResultRecord`` JSON file:
    ``{"metadata": {"expiration", "serializer"}, "result"}``), read without importing Prefect; ``None`` if there
    is none, it expired, or it is in a form this reader does not know (then only a flow run can tell)."""
    import base64
    import datetime as _dt
    import json

    try:
        rec = json.loads((storage / key).read_bytes())
        meta = rec["metadata"]
        if meta.get("expiration") is not None:
            exp = _dt.datetime.fromisoformat(str(meta["expiration"]).replace("Z", "+00:00"))
            if exp.tzinfo is None or exp <= _dt.datetime.now(_dt.UTC):
                return None
        ser = meta.get("serializer") or {}
        if ser.get("type") == "pickle" and ser.get("picklelib") in ("cloudpickle", "pickle"):
            value = _plain_unpickle(base64.b64decode(rec["result"]))
        elif ser.get("type") == "json":
            value = json.loads(rec["result"])
        else:
            return None
    except Exception:  # noqa: BLE001 - missing, unreadable or unknown: not known to be current
        return None
    if not isinstance(value, dict) or not all(isinstance(k, str) and isinstance(v, str) for k, v in value.items()):
        return None
    return value


#: per stage of a run, in plan order: ``(name, versions it would reuse or None, seconds the check took)``
CacheStatus = list[tuple[str, dict[str, str] | None, float]]


def current_stages(raw_dir: str | Path, store_root: str | Path | None, config_path: str | Path | None,
                   names: Sequence[str], *, status: CacheStatus | None = None) -> RunOutcome | None:
    """Whether a flow run of stages ``names`` (in plan order) would be nothing but cache hits, decided without
    Prefect (:func:`stage_cache_status`, or its ``status`` already walked). Returns what that flow run would (a
    :class:`RunOutcome`: the versions reused, every stage ``reused``) when all are current, else ``None``
    (something changed, or it cannot be told: a flow run decides). Publishes nothing (it may add raw-file hashes to
    the store's hash cache, as a flow run does)."""
    if status is None:
        status = stage_cache_status(raw_dir, store_root, config_path, names)
    if not status or any(out is None for _, out, _ in status):
        return None
    published: dict[str, str] = {}
    for _, out, _ in status:
        published.update(out or {})
    return RunOutcome(published, [{"stage": name, "status": "reused", "seconds": seconds,
                                   "versions": {p: Path(v).name for p, v in (out or {}).items()}, "reason": ""}
                                  for name, out, seconds in status])


def stale_stages(raw_dir: str | Path, store_root: str | Path | None, config_path: str | Path | None,
                 names: Sequence[str], *, status: CacheStatus | None = None) -> list[str]:
    """The stages of ``names`` (in plan order) a flow run would run rather than reuse (:func:`stage_cache_status`,
    or its ``status`` already walked): those without a current cached result and every stage downstream of one.
    The CLI starts processes and figure helpers for these only; a stage it judges current that runs after all
    simply starts its own process."""
    if status is None:
        status = stage_cache_status(raw_dir, store_root, config_path, names)
    return [name for name, out, _ in status if out is None]


def current_result(storage: Path, key: str) -> dict[str, str] | None:
    """The cached result of cache key ``key`` (:func:`cached_result`) if every version directory it names still
    exists, else ``None``."""
    out = cached_result(storage, key)
    if out is None or not all(Path(p, "manifest.json").is_file() for p in out.values()):
        return None
    return out


def drop_gone_result(storage: Path, key: str) -> None:
    """Remove the cache record of ``key`` when it names a version directory that is gone (deleted by hand, or
    pruned), so the stage task runs again instead of returning versions that no longer exist; a record that is
    current, absent or unreadable here is left alone."""
    out = cached_result(storage, key)
    if out is not None and current_result(storage, key) is None:
        (storage / key).unlink(missing_ok=True)


def stage_cache_status(raw_dir: str | Path, store_root: str | Path | None, config_path: str | Path | None,
                       names: Sequence[str]) -> CacheStatus:
    """The flow's stage graph (:func:`walk_stage_graph`) walked without Prefect: for each stage of ``names`` (returned
    in plan order), its cache key (:func:`stage_cache_key`) with the run's pins and what its upstream stages would
    reuse, and its persisted result (:func:`current_result`: its versions must all still exist). None for a stage
    whose key cannot be told or has no result, and for every stage downstream of such a one (its upstream will
    publish new versions). Nothing cached yet (a first run) or Prefect told to refresh every cache: every stage
    None."""
    import time

    storage = result_storage(store_root)
    if not names or not storage.is_dir() or \
            os.environ.get("PREFECT_TASKS_REFRESH_CACHE", "").lower() in ("1", "true", "yes"):
        return [(name, None, 0.0) for name in names]
    ctx = make_context(raw_dir, store_root, config_path)
    ctx.pin_existing(all_products())
    start = {p: str(pv.path) for p, pv in ctx.pins.items()}
    seconds: dict[str, float] = {}

    def step(name: str, upstream: dict[str, dict[str, str] | None]) -> dict[str, str] | None:
        t0 = time.monotonic()
        out = None
        if all(v is not None for v in upstream.values()):
            pins = dict(start)
            for v in upstream.values():
                pins.update(v or {})
            try:
                key: str | None = stage_cache_key(name, raw_dir, store_root, config_path, pins)
            except (HadalError, OSError):
                key = None  # the task would not cache it either
            out = current_result(storage, key) if key is not None else None
        seconds[name] = round(time.monotonic() - t0, 2)
        return out

    found = walk_stage_graph(names, step)
    return [(name, found[name], seconds[name]) for name in names]


def warm_imports(names: Sequence[str], *, stop: Any = None) -> list[str]:
    """Import the modules that the stages ``names`` import when they run (their ``warm_imports``), in stage order,
    until ``stop()`` (checked before each module) says to stop; returns the modules imported.

    The CLI calls it while Prefect's temporary server boots (:func:`hadal.cli._run_flow`): the main process would
    otherwise sit idle for those seconds, and each stage thread would then pay for its imports (about 2 s for the
    sample dive's thread stages) on the run's critical path. A module that fails to import is left to its stage,
    which reports the failure in its own words. Imports run in the calling thread only: importing beside other
    threads can deadlock on circular imports."""
    from hadal.childproc import warm

    done: list[str] = []
    for name in names:
        for mod in stage(name).warm_imports:
            if stop is not None and stop():
                return done
            if warm(mod):
                done.append(mod)
    return done
