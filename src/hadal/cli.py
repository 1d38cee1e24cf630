"""``hadal`` command line.

    hadal run RAW_DIR              run the whole post-cruise flow on a raw dive
    hadal run --dives DIR...       several dives in parallel on Dask (--workers N, --scheduler ADDRESS)
    hadal stage NAME RAW_DIR       re-run one stage, reusing the latest upstream products (--force)
    hadal report DIVE              write the dive report (HTML) from the products in the store
    hadal serve RAW_DIR --cron ..  deploy the post-cruise flow on a schedule (Prefect server)
    hadal products DIVE            list product versions in the store
    hadal synth DEST               write the seeded sample dive (Challenger Deep, Haidou-like)
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
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from hadal.errors import HadalError

app = typer.Typer(add_completion=False, no_args_is_help=True, help="hadal: post-dive processing for deep-sea vehicles.")
console = Console(stderr=True)

StoreOpt = Annotated[
    Path | None, typer.Option("--store", help="product store root (default $HADAL_STORE or ./data/processed)")
]
ConfigOpt = Annotated[Path | None, typer.Option("--config", help="pipeline YAML overriding the defaults")]


def _store_root(store: Path | None) -> Path:
    from hadal.pipeline import default_store_root

    return store if store is not None else default_store_root()


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
              force: bool = False) -> dict[str, str]:
    from hadal.dive import load_dive
    from hadal.pipeline import make_context, resolve_stages

    # validate everything cheap before starting Prefect, so bad input fails fast and in one line
    load_dive(raw_dir)
    make_context(raw_dir, _store_root(store), config)
    names = resolve_stages(stages)
    os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
    # the temporary server may need more than Prefect's default 20 s on a busy machine
    os.environ.setdefault("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "120")
    from hadal.flows.post_cruise import post_cruise

    _quiet_prefect_tracebacks()

    console.print(f"[bold]hadal[/] {raw_dir} → stages: {', '.join(names)}")
    return post_cruise(
        str(raw_dir), str(_store_root(store)), str(config) if config else None, names, force
    )


def _expand_dives(dirs: list[Path]) -> list[Path]:
    """Batch inputs: a directory with dive.yaml is one dive; one without is searched for dive subdirectories."""
    from hadal.dive import find_dives

    return find_dives(*dirs)


def _run_batch(raw_dirs: list[Path], store: Path | None, config: Path | None, workers: int,
               scheduler: str | None, force: bool) -> dict:
    from hadal.pipeline import make_context, resolve_stages

    dives = _expand_dives(raw_dirs)
    for d in dives:  # fail fast, in one line, before starting Prefect and Dask
        make_context(d, _store_root(store), config)
    names = resolve_stages(None)
    if workers < 1:
        from hadal.errors import ConfigError

        raise ConfigError(f"--workers must be at least 1 (got {workers})")
    os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
    # the temporary server may need more than Prefect's default 20 s on a busy machine
    os.environ.setdefault("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "120")
    from hadal.flows.batch import run_batch

    _quiet_prefect_tracebacks()

    where = f"scheduler {scheduler}" if scheduler else f"LocalCluster, {workers} worker(s)"
    console.print(f"[bold]hadal[/] batch of {len(dives)} dive(s) on {where} → stages: {', '.join(names)}")
    return run_batch([str(d) for d in dives], str(_store_root(store)), str(config) if config else None, names,
                     workers=workers, scheduler=scheduler, force=force)


def _print_published(published: dict[str, str]) -> None:
    table = Table(title="published products")
    table.add_column("product")
    table.add_column("version directory")
    for product, path in published.items():
        table.add_row(product, path)
    Console().print(table)


ForceOpt = Annotated[bool, typer.Option("--force", help="re-run even if the inputs, parameters and code are unchanged")]


@app.command()
def run(
    raw_dirs: Annotated[list[Path], typer.Argument(help="raw dive directory containing dive.yaml (several with --dives)")],
    store: StoreOpt = None,
    config: ConfigOpt = None,
    dives: Annotated[bool, typer.Option("--dives", help="batch: process every DIR (or every dive directory inside it) in parallel on Dask")] = False,
    workers: Annotated[int, typer.Option("--workers", help="batch: LocalCluster worker processes")] = 2,
    scheduler: Annotated[str | None, typer.Option("--scheduler", help="batch: address of an existing dask scheduler (tcp://host:8786)")] = None,
    force: ForceOpt = False,
) -> None:
    """Run the full post-cruise flow on one dive, or on several in parallel (--dives DIR...)."""
    if not dives and len(raw_dirs) == 1:
        _print_published(_run_flow(raw_dirs[0], store, config, None, force))
        return
    results = _run_batch(raw_dirs, store, config, workers, scheduler, force)
    table = Table(title="batch")
    for col in ("dive directory", "status", "products"):
        table.add_column(col)
    for raw, r in results.items():
        table.add_row(raw, "ok" if r["ok"] else f"failed: {r.get('error', '')}", ", ".join(r.get("published", {})))
    Console().print(table)
    failed = [raw for raw, r in results.items() if not r["ok"]]
    if failed:
        console.print(f"[red]error:[/] {len(failed)} of {len(results)} dive(s) failed", highlight=False)
        raise typer.Exit(1)


@app.command()
def stage(
    name: Annotated[str, typer.Argument(help="stage name (ingest, derive, grid, suitability, match, landing, report)")],
    raw_dir: Annotated[Path, typer.Argument(help="raw dive directory containing dive.yaml")],
    store: StoreOpt = None,
    config: ConfigOpt = None,
    force: ForceOpt = False,
) -> None:
    """Re-run one stage, reusing the latest upstream products (a cache hit if nothing changed; --force re-runs)."""
    _print_published(_run_flow(raw_dir, store, config, [name], force))


@app.command()
def report(
    dive: Annotated[str, typer.Argument(help="dive id (products are read from the store)")],
    store: StoreOpt = None,
    config: ConfigOpt = None,
    out: Annotated[Path | None, typer.Option("--out", help="also copy report.html here (file or directory)")] = None,
) -> None:
    """Write the dive report (self-contained HTML with figures) from whichever products exist."""
    import shutil

    from hadal.config import load_config
    from hadal.report import build_report, publish_report
    from hadal.stages.report import options
    from hadal.store import ProductStore, validate_name

    validate_name(dive, "dive id")
    p = load_config(config).report
    st = ProductStore(_store_root(store))
    rep = build_report(st, dive, options=options(p), best_sites=p.best_sites, title=p.title)
    pv = publish_report(st, rep, parameters=p.model_dump(mode="json"))
    html = pv.path / "report.html"
    for note in rep.summary.get("notes", []):
        console.print(f"note: {note}", highlight=False)
    if out is not None:
        dest = out / "report.html" if out.is_dir() else out
        dest.parent.mkdir(parents=True, exist_ok=True)
        shutil.copyfile(html, dest)
        html = dest
    print(html)


@app.command()
def serve(
    raw_dir: Annotated[Path, typer.Argument(help="a raw dive directory, or a cruise directory whose new dives are processed on each run")],
    cron: Annotated[str, typer.Option("--cron", help="cron schedule, e.g. '0 3 * * *' (03:00 UTC daily)")],
    name: Annotated[str, typer.Option("--name", help="deployment name")] = "hadal-post-cruise",
    store: StoreOpt = None,
    config: ConfigOpt = None,
) -> None:
    """Deploy the post-cruise flow on a cron schedule against a Prefect server (needs PREFECT_API_URL); blocks."""
    from hadal.config import load_config
    from hadal.errors import InputError
    from hadal.pipeline import make_context

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
            m = pv.manifest()
            rows.append({"product": product, "version": pv.label, "created_utc": m.get("created_utc"),
                         "code_version": m.get("code_version"), "path": str(pv.path)})
    if as_json:
        print(json.dumps(rows, indent=2))
        return
    if not rows:
        console.print(f"no products for dive {dive!r} in {st.root}")
        raise typer.Exit(1)
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


@app.command("config")
def config_cmd(
    check: Annotated[Path | None, typer.Option(
        "--check", help="validate instead of printing defaults: a pipeline YAML, or a dive directory (dive.yaml, "
                        "vehicle.yaml, pipeline.yaml and the plan of the stages its data supports)")] = None,
) -> None:
    """Print the default pipeline configuration (commented YAML), or validate a file or dive directory with --check."""
    from hadal.config import default_yaml, load_config

    if check is not None:
        if check.is_dir():
            _check_dive_dir(check)
            return
        load_config(check)
        console.print(f"{check}: valid")
        return
    print(default_yaml(), end="")


def _check_dive_dir(raw_dir: Path) -> None:
    from hadal.ingest.vehicle import load_vehicle_config
    from hadal.pipeline import make_context
    from hadal.plan import check_plan, format_plan, plan_stages

    ctx = make_context(raw_dir, None)
    if ctx.dive.vehicle_config:
        from hadal.dive import resolve_source

        load_vehicle_config(resolve_source(ctx.raw_dir, ctx.dive.vehicle_config))
    missing = [f"{kind}: {e.path}" for kind in ctx.dive.sources.kinds() for e in ctx.dive.sources.files(kind)
               if not _source_exists(ctx.raw_dir, e)]
    if missing:
        from hadal.errors import ConfigError

        raise ConfigError(f"{raw_dir}/dive.yaml lists missing source file(s): {', '.join(missing)}")
    plan = plan_stages(ctx.dive)
    check_plan(ctx.dive, plan)
    console.print(f"{raw_dir}: valid (dive {ctx.dive_id!r}); plan:")
    print(format_plan(plan))


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
    if any(i.get("kind") == "unreadable" for i in infos):
        raise typer.Exit(2)


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
    res = scan_dive_dir(raw_dir, dive_id=dive_id, launch=parse_latlon_pair(launch) if launch else None)
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


def main() -> None:
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
    except typer.Abort:
        console.print("aborted")
        sys.exit(130)
    except Exception as exc:  # click usage errors
        import click

        if isinstance(exc, click.ClickException):
            exc.show()
            sys.exit(exc.exit_code)
        raise
    sys.exit(rc if isinstance(rc, int) else 0)


if __name__ == "__main__":
    main()
