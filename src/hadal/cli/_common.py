"""What the commands share: the stderr console, the common options, the store root and the closing tables."""

from __future__ import annotations

import logging
import os
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from hadal.errors import HadalError

console = Console(stderr=True)

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
