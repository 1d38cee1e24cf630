"""``hadal report``: the dive report (HTML) from the products in the store."""

from __future__ import annotations

import os
from pathlib import Path
from typing import Annotated

import typer

from hadal.cli._common import ConfigOpt, StoreOpt, _store_root, console


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
