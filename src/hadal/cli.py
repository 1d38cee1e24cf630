"""``hadal`` command line.

    hadal run RAW_DIR              run the whole post-cruise flow on a raw dive
    hadal stage NAME RAW_DIR       re-run one stage, reusing the latest upstream products
    hadal products DIVE            list product versions in the store
    hadal synth DEST               write the seeded sample dive (Challenger Deep, Haidou-like)

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


def _run_flow(raw_dir: Path, store: Path | None, config: Path | None, stages: list[str] | None) -> dict[str, str]:
    from hadal.dive import load_dive
    from hadal.pipeline import make_context, resolve_stages

    # validate everything cheap before starting Prefect, so bad input fails fast and in one line
    load_dive(raw_dir)
    make_context(raw_dir, _store_root(store), config)
    names = resolve_stages(stages)
    os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
    from flows.post_cruise import post_cruise

    console.print(f"[bold]hadal[/] {raw_dir} → stages: {', '.join(names)}")
    return post_cruise(
        str(raw_dir), str(_store_root(store)), str(config) if config else None, names
    )


def _print_published(published: dict[str, str]) -> None:
    table = Table(title="published products")
    table.add_column("product")
    table.add_column("version directory")
    for product, path in published.items():
        table.add_row(product, path)
    Console().print(table)


@app.command()
def run(
    raw_dir: Annotated[Path, typer.Argument(help="raw dive directory containing dive.yaml")],
    store: StoreOpt = None,
    config: ConfigOpt = None,
) -> None:
    """Run the full post-cruise flow on one dive."""
    _print_published(_run_flow(raw_dir, store, config, None))


@app.command()
def stage(
    name: Annotated[str, typer.Argument(help="stage name (ingest, derive, grid, suitability, match, landing, report)")],
    raw_dir: Annotated[Path, typer.Argument(help="raw dive directory containing dive.yaml")],
    store: StoreOpt = None,
    config: ConfigOpt = None,
) -> None:
    """Re-run one stage, reusing the latest upstream products."""
    _print_published(_run_flow(raw_dir, store, config, [name]))


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
) -> None:
    """Write the seeded sample dive (Haidou in the Challenger Deep) with ground truth."""
    from hadal.progress import default_progress
    from hadal.synth import generate_dive

    out = generate_dive(dest, seed=seed, small=small, progress=default_progress())
    console.print(f"sample dive written to {out}")


def main() -> None:
    logging.basicConfig(level=os.environ.get("HADAL_LOG_LEVEL", "INFO"), format="%(levelname)s %(name)s: %(message)s")
    try:
        rc = app(standalone_mode=False)
    except HadalError as exc:
        console.print(f"[red]error:[/] {exc}", highlight=False)
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
