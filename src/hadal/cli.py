"""``hadal`` command line.

    hadal run RAW_DIR              run the whole post-cruise flow on a raw dive
    hadal run --dives DIR...       several dives in parallel on Dask (--workers N, --scheduler ADDRESS)
    hadal stage NAME RAW_DIR       re-run one stage, reusing the latest upstream products (--force, --downstream)
    hadal report DIVE              write the dive report (HTML) from the products in the store
    hadal serve RAW_DIR --cron ..  deploy the post-cruise flow on a schedule (Prefect server)
    hadal products DIVE            list product versions in the store
    hadal server start             a long-running local Prefect server (then export PREFECT_API_URL=...)
    hadal synth DEST               write the seeded sample dive (Challenger Deep, Haidou-like)
    hadal compile                  compile the numba kernels into numba's cache (once after installing)
    hadal inspect FILE...          what each file is (by content) and what is in it (--json)
    hadal init RAW_DIR             write a commented dive.yaml (+ vehicle.yaml) from the files found
    hadal schema dive|vehicle|pipeline   JSON Schema of a configuration file (for editors)

Problems with the input are reported as one line (``error: ...``) with exit status 2.
"""

from __future__ import annotations

import json
import logging
import os
import sys
import threading
from pathlib import Path
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from hadal.errors import HadalError

app = typer.Typer(add_completion=False, no_args_is_help=True, help="hadal: post-dive processing for deep-sea vehicles.")
console = Console(stderr=True)
# Imports stay inside the commands that need them (stages, Prefect, xarray, matplotlib take seconds to import):
# the listing commands (--help, --version, products, config, inspect) answer in a fraction of a second
# (bench/bench_cli.py).


def _version_callback(value: bool) -> None:
    if value:
        from hadal import __version__

        print(f"hadal {__version__}")
        raise typer.Exit(0)


@app.callback()
def _root(
    version: Annotated[bool, typer.Option("--version", help="print hadal's version and exit", is_eager=True,
                                          callback=_version_callback)] = False,
) -> None:
    """hadal: post-dive processing for deep-sea vehicles."""

StoreOpt = Annotated[
    Path | None, typer.Option("--store", help="product store root (default $HADAL_STORE or ./data/processed)")
]
ConfigOpt = Annotated[Path | None, typer.Option("--config", help="pipeline YAML overriding the defaults")]


def _store_root(store: Path | None) -> Path:
    """``--store``, else ``$HADAL_STORE``, else ``./data/processed`` (as :func:`hadal.pipeline.default_store_root`,
    without importing the pipeline)."""
    return store if store is not None else Path(os.environ.get("HADAL_STORE", "data/processed"))


class _NoHadalTracebacks(logging.Filter):
    """Prefect logs a failed flow run's exception *with its traceback*; a HadalError is a one-line report for the
    user (printed by :func:`main`), so drop the traceback from such records (other exceptions keep theirs)."""

    def filter(self, record: logging.LogRecord) -> bool:
        if record.exc_info and isinstance(record.exc_info[1], HadalError):
            record.exc_info = None
            record.exc_text = None
        return True


def _quiet_prefect_tracebacks() -> None:
    for name in ("prefect.flow_runs", "prefect.task_runs"):
        lg = logging.getLogger(name)
        if not any(isinstance(f, _NoHadalTracebacks) for f in lg.filters):
            lg.addFilter(_NoHadalTracebacks())


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


def _api_url() -> str | None:
    """The Prefect API this process's flow runs talk to (environment, else the active profile), or None."""
    url = os.environ.get("PREFECT_API_URL")
    if url:
        return url
    try:
        from prefect.settings import get_current_settings
    except ImportError:
        return None
    return get_current_settings().api.url or None


def _wait_for_api() -> None:
    """Before the first flow run: hadal's temporary server booted (:func:`_wait_for_temporary_server`), or the
    configured API answering, waited for (bounded, a progress line on stderr: :func:`hadal.prefect_api.wait_for_api`)
    or refused in one line (exit 2)."""
    from hadal.prefect_api import api_settings, wait_for_api

    if _SERVERS:
        _wait_for_temporary_server()
        return
    url = _api_url()
    if url:
        wait_for_api(url, api_settings(), lambda line: console.print(line, highlight=False, soft_wrap=True))


def _watch_api(published: Any) -> Any:
    """Start watching the API during the flow run (:class:`hadal.prefect_api.ApiWatch`): silent for
    ``HADAL_API_LOST_S``, the run ends (:func:`_api_lost`) with ``published()`` (the versions it published) listed.
    None without an API URL."""
    from hadal.prefect_api import ApiWatch, api_settings

    url = _api_url()
    if not url:
        return None
    watch: Any = None

    def lost(_silent_s: float, _why: str) -> None:
        _api_lost(_api_lost_error(watch, published()))

    watch = ApiWatch(url, api_settings(), lost)
    return watch.start()


def _api_lost_error(watch: Any, published: list[str]) -> HadalError:
    import time

    from hadal.prefect_api import ApiUnreachable

    silent = max(0.0, time.monotonic() - watch.last_ok)
    done = f"published before it stopped (they stay published): {', '.join(published)}" if published else \
        "nothing was published"
    return ApiUnreachable(f"the Prefect API at {watch.api_url} stopped answering mid-run ({watch.why or 'no answer'}, "
                          f"silent for {silent:.0f} s; HADAL_API_LOST_S={watch.settings.lost_s:g}): run stopped; "
                          f"{done}")


def _api_lost(err: HadalError) -> None:
    """From the API watch thread: the run cannot record itself any more; say so in one line (what was published
    listed), stop the stage processes and helpers, exit 2. Half-written versions stay ``.staging-*`` directories,
    which readers never see and the next run removes."""
    if not _INTERRUPT_LOCK.acquire(blocking=False):  # an interrupt is already ending the run
        return
    try:
        # on a line of its own: Prefect's log worker may have left a partial line ("All connection attempts failed")
        console.print(f"\n[red]error:[/] {err}", highlight=False, soft_wrap=True)
    except Exception:  # noqa: BLE001 - a closed stderr: the exit status still says it
        pass
    _stop_children()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:  # noqa: BLE001
            pass
    logging.disable(logging.CRITICAL)
    os._exit(2)


def _print_stage_table(out: dict[str, str], seconds: float) -> None:
    """The closing table: per stage published / reused (cache hit) / skipped / failed, with its time."""
    rows = getattr(out, "stages", None)
    if not rows:
        return
    table = Table(title=f"stages ({seconds:.1f} s in all)")
    for col in ("stage", "status", "seconds", "versions / reason"):
        table.add_column(col)
    colour = {"published": "green", "reused": "cyan", "skipped": "yellow", "failed": "red"}
    for r in rows:
        what = ", ".join(f"{p}/{v}" for p, v in r.get("versions", {}).items()) or r.get("reason", "")
        st = r.get("status", "")
        table.add_row(r.get("stage", ""), f"[{colour.get(st, 'white')}]{st}[/]", f"{r.get('seconds', 0):.1f}", what)
    Console().print(table)


def _print_report_path(published: dict[str, str]) -> None:
    """The last line of a run on stdout: ``report: <absolute path of report.html>`` of the report version the run
    published or reused (nothing when the run has no report)."""
    where = published.get("report")
    if where and (html := Path(where, "report.html")).is_file():
        print(f"report: {html.resolve()}")


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


def _print_published(published: dict[str, str]) -> None:
    if getattr(published, "stages", None):  # a flow's outcome: its stage table (_print_stage_table) says it all
        return
    table = Table(title="published products")
    table.add_column("product")
    table.add_column("version directory")
    for product, path in published.items():
        table.add_row(product, path)
    Console().print(table)


ForceOpt = Annotated[bool, typer.Option("--force", help="re-run even if the inputs, parameters and code are unchanged")]
FlowOpt = Annotated[bool, typer.Option(
    "--flow", help="always run the Prefect flow (recorded on the server), also when every stage is current")]


@app.command()
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


@app.command()
def stage(
    name: Annotated[str, typer.Argument(help="stage name (ingest, derive, dtm, laser, suitability, match, landing, "
                                             "report; grid = dtm + laser)")],
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
    from hadal.pipeline import resolve_stages
    from hadal.plan import downstream_stages

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
    from hadal.plan import plan_stages

    ctx = make_context(raw_dir, _store_root(store), config)
    ok = {ps.name for ps in plan_stages(ctx.dive, stages, store=ctx.store) if ps.run}
    return [s for i, s in enumerate(stages) if i == 0 or s in ok]


@app.command()
def report(
    dive: Annotated[str, typer.Argument(help="dive id (products are read from the store)")],
    store: StoreOpt = None,
    config: ConfigOpt = None,
    out: Annotated[Path | None, typer.Option("--out", help="also copy report.html here (file or directory)")] = None,
) -> None:
    """Write the dive report (self-contained HTML with figures) from whichever products exist."""
    import shutil

    from hadal.report import build_report, publish_report
    from hadal.settings import load_config
    from hadal.stages.report import options
    from hadal.store import ProductStore, validate_name

    validate_name(dive, "dive id")
    p = load_config(config).report
    dest = _report_destination(out) if out is not None else None  # checked before anything is published
    st = ProductStore(_store_root(store))
    rep = build_report(st, dive, options=options(p), best_sites=p.best_sites, title=p.title)
    pv = publish_report(st, rep, parameters=p.model_dump(mode="json"))
    html = pv.path / "report.html"
    for note in rep.summary.get("notes", []):
        console.print(f"note: {note}", highlight=False)
    if dest is not None:
        try:
            shutil.copyfile(html, dest)
        except OSError as exc:
            from hadal.errors import InputError

            raise InputError(f"report published as {html}, but copying it to {dest} failed "
                             f"({exc.strerror or exc})") from None
        html = dest
    print(html)


def _report_destination(out: Path) -> Path:
    """Where ``--out`` puts report.html (a directory: inside it), created and checked writable, or a one-line error."""
    import os

    from hadal.errors import InputError

    dest = out / "report.html" if out.is_dir() else out
    blocker = next((a for a in (dest.parent, *dest.parent.parents) if a.exists()), None)
    if blocker is not None and not blocker.is_dir():
        raise InputError(f"--out {out}: {blocker} is not a directory")
    try:
        dest.parent.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"--out {out}: cannot create {dest.parent} ({exc.strerror or exc})") from None
    if not os.access(dest.parent, os.W_OK):
        raise InputError(f"--out {out}: {dest.parent} is not writable")
    return dest


@app.command()
def serve(
    raw_dir: Annotated[Path, typer.Argument(help="a raw dive directory, or a cruise directory whose new dives are processed on each run")],
    cron: Annotated[str, typer.Option("--cron", help="cron schedule, e.g. '0 3 * * *' (03:00 UTC daily)")],
    name: Annotated[str, typer.Option("--name", help="deployment name")] = "hadal-post-cruise",
    store: StoreOpt = None,
    config: ConfigOpt = None,
) -> None:
    """Deploy the post-cruise flow on a cron schedule against a Prefect server (needs PREFECT_API_URL); blocks."""
    from hadal.errors import InputError
    from hadal.pipeline import make_context
    from hadal.settings import load_config

    if (raw_dir / "dive.yaml").is_file():
        make_context(raw_dir, _store_root(store), config)
    elif raw_dir.is_dir():  # a cruise directory: its dives are discovered at every run
        load_config(config)
    else:
        raise InputError(f"raw directory {raw_dir} does not exist")
    from hadal.flows.serve import check_cron, require_api_url, serve_post_cruise

    check_cron(cron)
    api = require_api_url()
    kind = "post-cruise" if (raw_dir / "dive.yaml").is_file() else "post-cruise-new-dives"
    console.print(f"[bold]hadal[/] serving deployment '{kind}/{name}' ({cron}) on {api}; Ctrl-C to stop")
    serve_post_cruise(str(raw_dir.resolve()), str(_store_root(store).resolve()),
                      str(config.resolve()) if config else None, cron=cron, name=name)


server_app = typer.Typer(add_completion=False, no_args_is_help=True,
                         help="a long-running local Prefect server (runs then skip the temporary server's start)")
app.add_typer(server_app, name="server")


@server_app.command("start")
def server_start(
    host: Annotated[str, typer.Option("--host", help="address to listen on (keep loopback: no authentication)")
                    ] = "127.0.0.1",
    port: Annotated[int, typer.Option("--port", help="port of the API and UI")] = 4200,
) -> None:
    """Run a Prefect server in the foreground (``prefect server start``); in another shell set the
    PREFECT_API_URL it prints, and every hadal run uses it (no temporary server per run, runs in its UI)."""
    import shutil

    from hadal.errors import ConfigError

    if not 1 <= port <= 65535:
        raise ConfigError(f"--port must be 1-65535 (got {port})")
    exe = shutil.which("prefect") or str(Path(sys.executable).with_name("prefect"))
    if not Path(exe).is_file():
        raise ConfigError("the 'prefect' command is not installed next to hadal (pip install prefect)")
    _check_prefect_home()
    api_url = f"http://{_url_host(host)}:{port}/api"
    console.print(f"Prefect server on {api_url[:-4]}; in the shell that runs hadal:\n"
                  f"  export PREFECT_API_URL={api_url}", highlight=False)
    os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
    os.environ.update(_server_ui_environment(api_url))
    sys.stdout.flush()
    sys.stderr.flush()
    os.execv(exe, [exe, "server", "start", "--host", host, "--port", str(port)])


def _store_dives(st: Any) -> list[str]:
    """The dives with products in store ``st`` (for an error naming what is there)."""
    out: list[str] = []
    try:
        entries = sorted(st.root.iterdir()) if st.root.is_dir() else []
    except OSError:
        return out
    for d in entries:
        try:
            if d.is_dir() and st.products(d.name):
                out.append(d.name)
        except (HadalError, OSError):  # not a dive's directory (.prefect-results, ...)
            continue
    return out


def _url_host(host: str) -> str:
    """``host`` as the UI and hadal reach it: a wildcard address (listen on every interface) as loopback, an IPv6
    address in brackets."""
    if host in ("0.0.0.0", "::", ""):
        return "127.0.0.1"
    return f"[{host}]" if ":" in host and not host.startswith("[") else host


def _server_ui_environment(api_url: str) -> dict[str, str]:
    """Settings of ``hadal server start``'s server so that its UI talks to *its* API: the UI asks the API at
    ``PREFECT_SERVER_UI_API_URL`` (Prefect 3.8; served at ``/ui-settings``), which defaults to ``PREFECT_API_URL`` if
    set (e.g. a profile's ``http://127.0.0.1:4200/api``), else ``PREFECT_SERVER_API_HOST``/``PORT`` (4200): neither
    the ``--port`` given. One set by the user (``PREFECT_SERVER_UI_API_URL`` or its alias ``PREFECT_UI_API_URL``,
    e.g. behind a proxy) is kept."""
    if os.environ.get("PREFECT_SERVER_UI_API_URL") or os.environ.get("PREFECT_UI_API_URL"):
        return {}
    return {"PREFECT_SERVER_UI_API_URL": api_url}


@app.command()
def products(
    dive: Annotated[str, typer.Argument(help="dive id")],
    store: StoreOpt = None,
    as_json: Annotated[bool, typer.Option("--json", help="machine-readable output")] = False,
) -> None:
    """List the products and versions of a dive."""
    from hadal.store import ProductStore, validate_name

    validate_name(dive, "dive id")
    st = ProductStore(_store_root(store))
    rows = []
    for product in st.products(dive):
        for pv in st.versions(dive, product):
            try:
                m = pv.manifest()
            except (OSError, ValueError):  # a damaged manifest is listed as such, not a traceback
                m = {"created_utc": None, "code_version": "(unreadable manifest.json)"}
            rows.append({"product": product, "version": pv.label, "created_utc": m.get("created_utc"),
                         "code_version": m.get("code_version"), "path": str(pv.path)})
    if not rows:
        from hadal.errors import InputError

        known = _store_dives(st)
        raise InputError(f"no products for dive {dive!r} in {st.root}" + (
            f" (dives there: {', '.join(known[:20])}{' ...' if len(known) > 20 else ''})" if known else
            " (the store holds no dive)"))
    if as_json:
        print(json.dumps(rows, indent=2))
        return
    table = Table(title=f"{dive} products in {st.root}")
    for col in ("product", "version", "created_utc", "code_version"):
        table.add_column(col)
    for r in rows:
        table.add_row(r["product"], r["version"], r["created_utc"] or "", r["code_version"] or "")
    Console().print(table)


@app.command()
def synth(
    dest: Annotated[Path, typer.Argument(help="directory to write the sample dive into")],
    seed: Annotated[int, typer.Option(help="random seed (same seed → identical files)")] = 20181006,
    small: Annotated[bool, typer.Option("--small", help="small, fast variant (tests)")] = False,
    dive_id: Annotated[str | None, typer.Option("--dive-id", help="dive id (default: the directory's name)")] = None,
) -> None:
    """Write the seeded sample dive (Haidou in the Challenger Deep) with ground truth."""
    from hadal.progress import default_progress
    from hadal.store import validate_name
    from hadal.synth import generate_dive

    if dive_id is not None:
        validate_name(dive_id, "dive id")
    out = generate_dive(dest, seed=seed, small=small, progress=default_progress(), dive_id=dive_id)
    console.print(f"sample dive written to {out}")


@app.command("compile")
def compile_cmd() -> None:
    """Compile the pipeline's numba kernels into numba's cache (once after installing; make setup runs it)."""
    import time

    from hadal.numbacompile import compile_kernels

    t0 = time.process_time()
    counts = compile_kernels()
    console.print(f"numba kernels: {counts['compiled']} compiled, {counts['loaded']} already cached "
                  f"({time.process_time() - t0:.1f} CPU-s)")


@app.command("config")
def config_cmd(
    check: Annotated[Path | None, typer.Option(
        "--check", help="validate instead of printing defaults: a pipeline YAML, or a dive directory (dive.yaml, "
                        "vehicle.yaml, pipeline.yaml and the plan of the stages its data supports)")] = None,
) -> None:
    """Print the default pipeline configuration (commented YAML), or validate a file or dive directory with --check."""
    if check is not None:
        from hadal.settings import load_config

        if check.is_dir():
            _check_dive_dir(check)
            return
        load_config(check)
        console.print(f"{check}: valid")
        return
    print(_default_yaml_cached(), end="")


def _cache_dir() -> Path:
    """``$HADAL_CACHE_DIR``, else ``$XDG_CACHE_HOME/hadal``, else ``~/.cache/hadal``."""
    if os.environ.get("HADAL_CACHE_DIR"):
        return Path(os.environ["HADAL_CACHE_DIR"]).expanduser()
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache").expanduser() / "hadal"


def _default_yaml_cached() -> str:
    """The default configuration (:func:`hadal.settings.default_yaml`), cached per code version.

    The text depends only on hadal's source (:mod:`hadal.settings`), so it is kept under :func:`_cache_dir` keyed
    by :func:`hadal.pipeline.code_digest` (any edit of any hadal source file makes a new key). Best effort: an
    unwritable cache only costs the import."""
    from hadal.pipeline import code_digest

    f = _cache_dir() / f"pipeline-defaults-{code_digest()}.yaml"
    try:
        return f.read_text(encoding="utf-8")
    except (OSError, UnicodeError):
        pass
    from hadal.settings import default_yaml

    text = default_yaml()
    code_digest.cache_clear()
    if code_digest() != f.name[len("pipeline-defaults-"):-len(".yaml")]:  # edited meanwhile: do not cache
        return text
    try:
        f.parent.mkdir(parents=True, exist_ok=True)
        tmp = f.with_name(f".{f.name}.{os.getpid()}")
        tmp.write_text(text, encoding="utf-8")
        os.replace(tmp, f)
    except OSError:
        pass
    return text


def _check_dive_dir(raw_dir: Path) -> None:
    from hadal.ingest.vehicle import load_vehicle_config
    from hadal.pipeline import make_context
    from hadal.plan import check_plan, format_plan

    ctx = make_context(raw_dir, None)
    if ctx.dive.vehicle_config:
        from hadal.dive import resolve_source

        load_vehicle_config(resolve_source(ctx.raw_dir, ctx.dive.vehicle_config))
    missing = [f"{kind}: {e.path}" for kind in ctx.dive.sources.kinds() for e in ctx.dive.sources.files(kind)
               if not _source_exists(ctx.raw_dir, e)]
    if missing:
        from hadal.errors import ConfigError

        raise ConfigError(f"{raw_dir}/dive.yaml lists missing source file(s): {', '.join(missing)}")
    from hadal.pipeline import stage_plan

    plan = stage_plan(ctx)  # also refuses a dive that lists nothing to process
    check_plan(ctx.dive, plan)
    console.print(f"{raw_dir}: valid (dive {ctx.dive_id!r}); plan:")
    print(format_plan(plan))
    from hadal.products import missing_acdd_fields  # discovery metadata the products will lack

    if missing := missing_acdd_fields(ctx.dive):
        print(f"metadata: dive.yaml 'metadata' lacks {', '.join(missing)} (ACDD/IOOS; the products leave them out and "
              "list them in hadal_metadata_missing)")


def _source_exists(raw_dir: Path, entry) -> bool:
    from hadal.dive import resolve_source

    return resolve_source(raw_dir, entry).is_file()


@app.command()
def inspect(
    files: Annotated[list[Path], typer.Argument(help="files (or directories, searched recursively) to describe")],
    as_json: Annotated[bool, typer.Option("--json", help="machine-readable output")] = False,
) -> None:
    """What each file is (detected from its content) and what is in it."""
    from hadal.inspect import inspect_file, summary_line

    paths: list[Path] = []
    for f in files:
        paths += sorted(p for p in f.rglob("*") if p.is_file()) if f.is_dir() else [f]
        if f.is_dir() and not any(p.is_file() for p in f.rglob("*")):
            console.print(f"{f}: a directory with no files in it", highlight=False)
    infos = [inspect_file(p) for p in paths]
    if as_json:
        from hadal.products.io import json_clean

        print(json.dumps(json_clean(infos), indent=2, default=str, allow_nan=False))
    else:
        table = Table(title="hadal inspect")
        for col in ("file", "kind", "dive source", "contents"):
            table.add_column(col, overflow="fold")
        for i in infos:
            kind = i.get("kind", "?") + (f" ({i['compression']})" if i.get("compression") else "")
            table.add_row(i["path"], kind, i.get("source") or "-", summary_line(i))
        Console().print(table)
    bad = [i for i in infos if i.get("kind") == "unreadable" or i.get("error")]
    if bad:  # corrupt, truncated or unreadable: a non-zero exit a script can test (the table says why per file)
        from hadal.errors import InputError

        raise InputError(f"{len(bad)} of {len(infos)} file(s) cannot be read: "
                         + ", ".join(str(i['path']) for i in bad[:10]) + (" ..." if len(bad) > 10 else ""))


@app.command()
def init(
    raw_dir: Annotated[Path, typer.Argument(help="raw dive directory to describe")],
    dive_id: Annotated[str | None, typer.Option("--dive-id", help="dive id (default: the directory's name)")] = None,
    launch: Annotated[str | None, typer.Option("--launch", help="launch position LAT,LON (decimal degrees)")] = None,
    force: Annotated[bool, typer.Option("--force", help="overwrite an existing dive.yaml / vehicle.yaml")] = False,
    dry_run: Annotated[bool, typer.Option("--dry-run", help="print and validate, write nothing")] = False,
) -> None:
    """Scan RAW_DIR, write a commented dive.yaml (and vehicle.yaml) and say what is still to be filled in."""
    from hadal.dive_init import parse_latlon_pair, scan_dive_dir, write_init
    from hadal.plan import format_plan
    from hadal.store import validate_name

    if dive_id is not None:
        validate_name(dive_id, "dive id")
    pos = parse_latlon_pair(launch) if launch else None
    existing = [raw_dir / "dive.yaml"] if (raw_dir / "dive.yaml").exists() else []
    if existing and not (force or dry_run):  # say so before scanning (which may take a while on big files)
        from hadal.errors import ConfigError

        raise ConfigError(f"{', '.join(map(str, existing))} already exist(s); use --force to overwrite "
                          "(or --dry-run to see what init would write)")
    res = scan_dive_dir(raw_dir, dive_id=dive_id, launch=pos)
    for line in res.mapped:
        console.print(f"[green]mapped[/]   {line}", highlight=False)
    for line in res.not_used:
        console.print(f"[yellow]not used[/] {line}", highlight=False)
    for line in res.todo:
        console.print(f"[red]to do[/]    {line}", highlight=False)
    if res.plan:
        console.print("plan:", highlight=False)
        console.print(format_plan(res.plan), highlight=False, markup=False)
    if dry_run:
        print(res.dive_yaml(), end="")
        if res.vehicle_yaml:
            print("# ---- vehicle.yaml\n" + res.vehicle_yaml, end="")
        return
    for p in write_init(res, force=force):
        console.print(f"wrote {p}", highlight=False)


@app.command()
def schema(
    what: Annotated[str, typer.Argument(help="dive, vehicle or pipeline")],
) -> None:
    """Print the JSON Schema of dive.yaml, vehicle.yaml or pipeline.yaml (for editors' YAML validation)."""
    from hadal.schema_docs import json_schema

    print(json.dumps(json_schema(what), indent=2))


# ---------------------------------------------------------------------------------------------- process hygiene
def _prefect_environment() -> None:
    """Environment for the flows, set up before they are imported: a writable PREFECT_HOME (checked: a one-line
    error instead of Prefect's tracebacks) and, unless a Prefect API is configured, hadal's temporary Prefect
    server started in the background (:func:`_start_temporary_server`): it boots on the other core while hadal
    imports the flows, and :func:`_wait_for_temporary_server` waits for it before the first flow run."""
    os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
    # the temporary server may need more than Prefect's default 20 s on a busy machine
    os.environ.setdefault("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "120")
    _check_prefect_home()
    _start_temporary_server()


def _check_prefect_home() -> None:
    """PREFECT_HOME (default ``~/.prefect``) must be a writable directory: the temporary server keeps its
    database there. Refuse in one line (ConfigError, exit 2) rather than let Prefect fail with tracebacks."""
    import tempfile

    from hadal.errors import ConfigError

    raw = os.environ.get("PREFECT_HOME")
    home = Path(raw).expanduser() if raw else Path("~/.prefect").expanduser()
    try:
        home.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=home):
            pass
    except OSError as exc:
        why = exc.strerror or type(exc).__name__
        raise ConfigError(
            f"Prefect's home directory {home} is not writable ({why}); the temporary Prefect server keeps its "
            "database there: set PREFECT_HOME to a writable directory (e.g. PREFECT_HOME=$(mktemp -d))") from None


#: run as the temporary Prefect server's main: the server stops by itself when the pipe from hadal reaches EOF,
#: i.e. when hadal exits in any way (kill -9 included: the kernel closes hadal's end of the pipe)
_SERVER_GUARD = """
import os, runpy, signal, sys, threading, time
fd = int(sys.argv.pop(1))
def _watch():
    try:
        while os.read(fd, 4096):
            pass
    except OSError:
        pass
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(10)
    os._exit(0)
threading.Thread(target=_watch, daemon=True).start()
sys.argv[0] = "uvicorn"
runpy.run_module("uvicorn", run_name="__main__", alter_sys=True)
"""

class _TemporaryServer:
    """hadal's temporary Prefect server process: its port, the (write) end of its guard pipe, open until the
    server is stopped, and its start time."""

    def __init__(self, proc, port: int, guard_w: int, started: float):
        self.proc, self.port, self.guard_w, self.started = proc, port, guard_w, started

    @property
    def api_url(self) -> str:
        return f"http://127.0.0.1:{self.port}/api"

    def signal_stop(self) -> None:
        """EOF for the guard and SIGTERM for the server, without waiting; never raises. The guard pipe is closed
        once (its descriptor number may be reused afterwards)."""
        if self.guard_w >= 0:
            try:
                os.close(self.guard_w)
            except OSError:
                pass
            self.guard_w = -1
        if self.proc.poll() is None:
            try:
                self.proc.terminate()
            except OSError:
                pass

    def stop(self) -> None:
        """:meth:`signal_stop`, then wait for the server to exit (killed after 5 s); never raises."""
        import subprocess

        self.signal_stop()
        if self.proc.poll() is None:
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
            except OSError:
                pass


_SERVERS: list[_TemporaryServer] = []  # this process's temporary server (at most one; stopped at exit)


def _free_port() -> int:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _start_temporary_server() -> str | None:
    """Start Prefect's server for this process's flow runs, unless a Prefect API is configured
    (``PREFECT_API_URL`` in the environment or the active profile: :func:`_prefect_api_configured`); returns its
    API URL (also set as ``PREFECT_API_URL`` for this process and its children, e.g. Dask workers) or None.

    It is the server Prefect's own temporary server runs (``uvicorn prefect.server.api.server:create_app`` with
    Prefect's ephemeral-server settings), started by hadal instead of by Prefect's first API call so that it boots
    while hadal imports the flows (a flow run started ~2.4 s sooner here), without loading Prefect's server code
    (~2 s of imports) into hadal. It is started before hadal imports Prefect itself (~0.8 s), the server's boot
    being the longer of the two: when Prefect's settings then name an API after all (a profile, ``prefect.toml``),
    that API wins and the server just started is stopped. It runs in its own process group - a Ctrl-C at the
    terminal reaches hadal only, which then stops the server instead of killing it under a running flow - and
    through :data:`_SERVER_GUARD`, so it exits when hadal dies, even by ``kill -9``; a normal exit stops it
    (atexit)."""
    import atexit
    import importlib.util
    import subprocess
    import time

    if _SERVERS:
        return _SERVERS[0].api_url
    if os.environ.get("PREFECT_API_URL"):
        return None  # configured in the environment: known without importing Prefect
    spec = importlib.util.find_spec("prefect")  # locates the package without importing it
    if spec is None or spec.origin is None or not (Path(spec.origin).parent / "server" / "api" / "server.py").is_file():
        return None  # a Prefect without the bundled server: Prefect reports it at the flow run
    port = _free_port()
    r, w = os.pipe()
    # the server reads Prefect's settings (environment, profile, prefect.toml) itself, as this process does
    env = {**os.environ, "PREFECT_UI_ENABLED": "0", "PREFECT__SERVER_EPHEMERAL": "1", "PREFECT__SERVER_FINAL": "1"}
    args = [sys.executable, "-c", _SERVER_GUARD, str(r), "--app-dir", str(Path(spec.origin).parent.parent),
            "--factory", "prefect.server.api.server:create_app", "--host", "127.0.0.1", "--port", str(port),
            "--log-level", "error", "--lifespan", "on"]
    try:
        proc = subprocess.Popen(args, env=env, pass_fds=(r,), process_group=0)
    finally:
        os.close(r)
    srv = _TemporaryServer(proc, port, w, time.monotonic())
    if _prefect_api_configured():  # an API in the active profile or prefect.toml: no temporary server after all
        srv.stop()
        return None
    from prefect.context import refresh_global_settings_context

    _SERVERS.append(srv)
    atexit.register(srv.stop)
    os.environ["PREFECT_API_URL"] = srv.api_url
    os.environ.setdefault("PREFECT_UI_URL", "")  # the temporary server serves no UI: no "View at <url>" lines
    refresh_global_settings_context()  # Prefect read its settings at import: make it see the URL
    return srv.api_url


def _server_text() -> str:
    """Where this process's flow runs are recorded, for the first line of ``hadal run``/``hadal stage``."""
    if _SERVERS:
        return f"a temporary Prefect server at {_SERVERS[0].api_url} (set PREFECT_API_URL to skip its start)"
    return os.environ.get("PREFECT_API_URL") or "the Prefect API of the active profile"


def _wait_for_temporary_server() -> None:
    """Wait until hadal's temporary server answers ``/health`` (no-op without one); a server that does not come up
    within ``PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS`` or exits is a one-line :class:`ConfigError`."""
    import time

    from hadal.errors import ConfigError

    if not _SERVERS:
        return
    srv = _SERVERS[0]
    try:
        limit = float(os.environ.get("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "120"))
    except ValueError:
        limit = 120.0
    hint = "start one with `hadal server start` (or `prefect server start`) and set PREFECT_API_URL"
    said = srv.started
    while True:
        if time.monotonic() - said >= 10.0:  # a slow first start (a new database): a progress line every 10 s
            said = time.monotonic()
            console.print(f"waiting for the temporary Prefect server to start ({said - srv.started:.0f} s so far, "
                          f"up to {limit:g} s: PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS)", highlight=False,
                          soft_wrap=True)
        if srv.proc.poll() is not None:
            raise ConfigError(f"the temporary Prefect server exited with status {srv.proc.returncode} before it "
                              f"answered (its messages are above); {hint}")
        if _server_answers(srv, 2.0):
            return
        if time.monotonic() - srv.started > limit:
            raise ConfigError(f"the temporary Prefect server did not answer within {limit:g} s "
                              f"(PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS); {hint}")
        time.sleep(0.05)


def _server_answers(srv: _TemporaryServer, timeout_s: float) -> bool:
    """Whether ``srv`` answers ``/health`` with 200 within ``timeout_s``."""
    import urllib.error
    import urllib.request

    try:
        with urllib.request.urlopen(f"{srv.api_url}/health", timeout=timeout_s) as resp:
            return bool(resp.status == 200)
    except (urllib.error.URLError, OSError):
        return False


def _temporary_server_ready() -> bool:
    """Whether hadal's temporary server answers ``/health`` now (True without one: nothing to wait for)."""
    return not _SERVERS or _server_answers(_SERVERS[0], 0.2)


def _prepare_while_server_boots(ctx: Any, names: list[str], running: list[str]) -> list[str]:
    """Use the seconds Prefect's temporary server takes to boot (a core is idle meanwhile) for the imports the
    stages ``running`` (of the run's ``names``: those that will run, not be reused) need
    (:func:`hadal.pipeline.warm_imports`, in stage order, until the server answers); returns those of them that
    will run in their own process (:func:`hadal.flows.post_cruise.process_stages`, judged on the whole run as the
    flow judges it).

    Where processes can be forked (:func:`hadal.stage_process.can_fork_ahead`) those are forked just before the flow
    starts (:func:`_fork_ahead`) and inherit these imports, so the modules are imported once; elsewhere they are
    spawned now (:func:`hadal.stage_process.prestart`), each importing its own, and only the thread stages' modules
    are imported here. Without a temporary server (a running one is configured) nothing is imported ahead."""
    from hadal.budget import resources_of
    from hadal.flows.post_cruise import process_stages
    from hadal.pipeline import warm_imports
    from hadal.stage_process import can_fork_ahead, can_isolate, prestart

    isolated = process_stages(names) if resources_of(ctx.config).stage_processes and can_isolate() else set()
    ahead = [n for n in running if n in isolated]
    forking = can_fork_ahead()
    if not forking:
        try:
            prestart(ahead)
        except OSError:  # no process to spare now (e.g. a process limit): the flow starts the stage's own when it runs
            pass
    if _SERVERS:
        warm_imports([n for n in running if forking or n not in isolated], stop=_temporary_server_ready)
    return ahead


def _fork_ahead(ctx: Any, names: list[str], isolated: list[str]) -> None:
    """Just before the flow starts, while the main thread is still the only thread: fork the processes of the stages
    that run in their own (:func:`hadal.stage_process.prestart` with ``fork``; each imports what the boot left
    undone) and the figure helpers (:func:`_start_figure_helpers`). A fork no longer possible: the stage processes
    are spawned (if not already, during the boot) and the figures are drawn in the stages' threads."""
    from hadal.stage_process import can_fork_ahead, prestart

    forking = can_fork_ahead()
    try:  # spawned now if the fork became unsafe since the boot (another thread): not left to a cold start
        prestart(isolated, fork=forking)
    except OSError:
        pass
    if forking:
        _start_figure_helpers(ctx, names)


def _start_figure_helpers(ctx: Any, names: list[str]) -> None:
    """Fork the figure helpers (:func:`hadal.forkpool.start_helpers`) for the stages of the run that draw in a pool
    (landing with figures, report): in the flow they run in task threads, where a pool cannot fork itself, so they
    drew one figure after the other at the end of the run while a core idled. As many as those stages draw with
    (their ``figure_processes``, default :func:`hadal.forkpool.default_workers`), less the stage's own thread;
    forked just before the flow starts any other thread (:func:`_fork_ahead`). Each imports the drawing stages'
    modules first (on its own core: the flow's first stages do not draw)."""
    from hadal.forkpool import default_workers, start_helpers
    from hadal.stages.graph import stage

    cfg = ctx.config
    drawing = {"landing": cfg.landing.figure_processes if cfg.landing.figures else 1,
               "report": cfg.report.figure_processes}
    drawing = {s: n for s, n in drawing.items() if s in names}
    if not drawing:
        return
    n = max((n or default_workers()) for n in drawing.values()) - 1
    start_helpers(n, tuple(m for s in drawing for m in stage(s).warm_imports))


def _prefect_api_configured() -> bool:
    """Whether Prefect will talk to a running server (``PREFECT_API_URL`` set, in the environment or the active
    profile: Prefect's settings read both) rather than start a temporary one."""
    try:
        from prefect.settings import get_current_settings
    except ImportError:
        return False
    return bool(get_current_settings().api.url)


class _Terminated(KeyboardInterrupt):
    """SIGTERM/SIGHUP, raised in the main thread like a Ctrl-C so every path that cleans up on one runs."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


_INTERRUPT_LOCK = threading.Lock()  # one _interrupted() per process
_SIGNALLED: list[int] = []  # the signal that interrupted this run (typer turns the KeyboardInterrupt into exit 130)


#: seconds the main thread gets to unwind after a signal before the watchdog ends the run itself (the flow's task
#: runner waits for its stage threads on the way out; a stage may take minutes)
_UNWIND_S = 3.0


def _raise_terminated(signum, _frame) -> None:
    if _SIGNALLED:  # a second Ctrl-C: stop now (the server's guard still stops the server)
        os._exit(130 if signum == 2 else 128 + signum)
    _SIGNALLED.append(signum)
    def _watchdog() -> None:
        import time

        time.sleep(_UNWIND_S)
        _interrupted(_Terminated(signum))

    threading.Thread(target=_watchdog, name="hadal-interrupt-watchdog", daemon=True).start()
    raise _Terminated(signum)


def _install_signal_handlers() -> None:
    import signal

    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        try:
            signal.signal(sig, _raise_terminated)
        except (ValueError, OSError):  # not the main thread / not settable
            pass


def _is_resource_tracker(proc: Any) -> bool:
    """multiprocessing's resource tracker (started with the stage processes): it ignores SIGINT/SIGTERM by design
    and exits by itself when this process does, so waiting for it would only delay the exit by the timeout."""
    try:
        return "multiprocessing.resource_tracker" in " ".join(proc.cmdline())
    except Exception:  # noqa: BLE001 - gone or unreadable: treat it as an ordinary child
        return False


def _stop_children(timeout: float = 5.0) -> None:
    """Stop Prefect's temporary server(s) and every remaining child process (Dask workers, ...); never raises."""
    import signal

    for sig in (signal.SIGINT, signal.SIGTERM):  # a second signal must not interrupt the clean-up
        try:
            signal.signal(sig, signal.SIG_IGN)
        except ValueError:  # not the main thread (the interrupt watchdog): the handler exits at once anyway
            pass
    for srv in _SERVERS:  # the wait for them is the children's, below
        srv.signal_stop()
    try:
        import psutil

        kids = [k for k in psutil.Process().children(recursive=True) if not _is_resource_tracker(k)]
        for k in kids:
            try:
                k.terminate()
            except psutil.Error:
                pass
        _gone, alive = psutil.wait_procs(kids, timeout=timeout)
        for k in alive:
            try:
                k.kill()
            except psutil.Error:
                pass
        psutil.wait_procs(alive, timeout=timeout)
    except Exception:  # psutil missing or the process table unreadable: the guards still stop the server
        pass


def _interrupted(exc: KeyboardInterrupt) -> None:
    """One line, children stopped, exit 130 (Ctrl-C) or 128+signal; ``os._exit``: threads still running a
    stage (Prefect's task runners) must not keep a killed run alive, and atexit handlers would only log
    tracebacks about the server that is already gone. A half-written version stays a ``.staging-*``
    directory, which readers never see and the next run removes."""
    import signal

    if not _INTERRUPT_LOCK.acquire(blocking=False):  # the watchdog or the main thread is already on it
        while True:
            import time

            time.sleep(60)
    signum = getattr(exc, "signum", signal.SIGINT)
    name = signal.Signals(signum).name
    try:
        console.print(f"[red]error:[/] interrupted ({name}); nothing half-written was published", highlight=False,
                      soft_wrap=True)
    except Exception:
        pass
    _stop_children()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:
            pass
    logging.disable(logging.CRITICAL)
    os._exit(130 if signum == signal.SIGINT else 128 + signum)


def entry() -> None:
    """The ``hadal`` command (and ``python -m hadal.cli``): :func:`main`, then the process ends without the
    interpreter's teardown. After a full dive the teardown (freeing every object and module of a process that held
    gigabytes) took 1.2-1.4 s after the last line was printed; what a normal exit must do is done first: the threads
    that are not daemons are joined (as the interpreter's own shutdown does), the atexit handlers run (the temporary
    Prefect server and the stage processes are stopped, logging is flushed) and the standard streams are flushed.
    An exception other than :class:`SystemExit` propagates as usual. :func:`main` itself raises ``SystemExit`` (tests
    call it in-process)."""
    sys.stdout = _StdoutGuard(sys.stdout, say=len(sys.argv) > 1 and sys.argv[1] in _WORKING_COMMANDS)
    try:
        main()
        code: Any = 0
    except SystemExit as exc:
        code = exc.code
    if code is not None and not isinstance(code, int):  # sys.exit("message"): printed, status 1 (as Python does)
        print(code, file=sys.stderr)
        code = 1
    _exit_now(code or 0)


#: commands that publish or write something: a closed stdout is said on stderr (:class:`_StdoutGuard`)
_WORKING_COMMANDS = frozenset({"run", "stage", "report", "serve", "synth", "init", "compile"})


class _StdoutGuard:
    """``sys.stdout`` of the ``hadal`` command: a closed pipe (``hadal run ... | head -1``, the reader gone: EPIPE,
    SIGPIPE being ignored by Python) must not stop the run, nor end it with an exit status and no word (click's own
    EPIPE handling: exit 1). The first failed write says so once on stderr, points the descriptor at ``/dev/null``
    and the command goes on: what it would print there is dropped, its products are published as usual and its exit
    status is the run's. ``say``: a command that does work says so (``run``, ``report``, ...); a listing piped into
    ``head`` (``hadal config | head``) stops printing silently, as Unix tools do."""

    def __init__(self, stream: Any, say: bool = True):
        self._stream = stream
        self.say = say
        self.broken = False

    def _broken_pipe(self) -> None:
        if not self.broken:
            self.broken = True
            try:
                devnull = os.open(os.devnull, os.O_WRONLY)
                os.dup2(devnull, self._stream.fileno())
                os.close(devnull)
            except (OSError, ValueError, AttributeError):
                pass
            if not self.say:
                return
            try:
                console.print("note: standard output was closed by its reader (broken pipe); hadal goes on "
                              "without it: the rest of what it prints there is dropped; its work (published products, "
                              "exit status) is not affected",
                              highlight=False, soft_wrap=True)
            except Exception:  # noqa: BLE001 - stderr closed too: the exit status still tells
                pass

    def write(self, text: str) -> int:
        if self.broken:
            return len(text)
        try:
            return self._stream.write(text)
        except BrokenPipeError:
            self._broken_pipe()
            return len(text)

    def flush(self) -> None:
        if self.broken:
            return
        try:
            self._stream.flush()
        except BrokenPipeError:
            self._broken_pipe()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


def _exit_now(code: int) -> None:
    """Exit with ``code`` as the interpreter would, in its order, but without its final teardown: threading's shutdown
    (its exit hooks stop the thread pools, then the threads that are not daemons are joined), the atexit handlers,
    the standard streams flushed, then ``os._exit``. Where that sequence is not available, the normal exit."""
    import atexit

    shutdown_threads = getattr(threading, "_shutdown", None)
    run_exit_handlers = getattr(atexit, "_run_exitfuncs", None)
    if shutdown_threads is None or run_exit_handlers is None:  # not CPython's: the normal (slower) exit
        sys.exit(code)
    shutdown_threads()
    run_exit_handlers()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:  # noqa: BLE001 - a closed or broken stream: nothing left to save
            pass
    os._exit(code)


def main() -> None:
    _install_signal_handlers()
    try:
        _main()
    except KeyboardInterrupt as exc:
        _interrupted(exc)
    except SystemExit:
        if _SIGNALLED:  # typer swallowed the interrupt (exit 130 without a word): say it, clean up
            _interrupted(_Terminated(_SIGNALLED[0]))
        raise


def _main() -> None:
    logging.basicConfig(level=os.environ.get("HADAL_LOG_LEVEL", "INFO"), format="%(levelname)s %(name)s: %(message)s")
    for noisy in ("httpx", "httpcore"):  # one line per Prefect API request otherwise
        logging.getLogger(noisy).setLevel(logging.WARNING)
    try:
        rc = app(standalone_mode=False)
    except HadalError as exc:
        console.print(f"[red]error:[/] {exc}", highlight=False, soft_wrap=True)  # one line, even at 80 columns
        sys.exit(2)
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except typer.Abort as exc:  # click turns a KeyboardInterrupt into Abort
        cause = exc.__cause__ or exc.__context__
        _interrupted(cause if isinstance(cause, KeyboardInterrupt) else KeyboardInterrupt())
    except Exception as exc:  # click usage errors
        _click_error(exc)
        raise
    sys.exit(rc if isinstance(rc, int) else 0)


def _click_exception_types() -> tuple[type[BaseException], ...]:
    """click's exception classes: typer's vendored click (``typer._click``) and, if installed, click itself."""
    types: list[type[BaseException]] = []
    for mod in ("typer._click.exceptions", "click.exceptions"):
        if mod.split(".")[0] == "click" and "click" not in sys.modules:
            continue  # not the one typer used
        try:
            m = __import__(mod, fromlist=["ClickException"])
        except ImportError:
            continue
        types.append(m.ClickException)
    return tuple(types)


def _click_error(exc: BaseException) -> None:
    """A click usage error as one line (exit 2), plain ``hadal`` as its help (exit 0); returns for other errors."""
    types = _click_exception_types()
    if not types or not isinstance(exc, types):
        return
    if type(exc).__name__ == "NoArgsIsHelpError":  # plain 'hadal' or a group without arguments: its help
        ctx = getattr(exc, "ctx", None)
        print(ctx.get_help() if ctx is not None else "", end="\n")
        sys.exit(0)
    msg = " ".join(str(exc.format_message() if hasattr(exc, "format_message") else exc).split())
    ctx = getattr(exc, "ctx", None)
    where = f" ({ctx.command_path} --help for usage)" if ctx is not None else " (hadal --help for usage)"
    code = getattr(exc, "exit_code", 2)
    console.print(f"[red]error:[/] {msg}{where}", highlight=False, soft_wrap=True, markup=True)
    sys.exit(2 if code in (1, 2) else code)


if __name__ == "__main__":
    entry()
