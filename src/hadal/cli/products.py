"""``hadal products``: the product versions of a dive in the store."""

from __future__ import annotations

import json
from typing import Annotated, Any

import typer
from rich.console import Console
from rich.table import Table

from hadal.cli._common import StoreOpt, _store_root
from hadal.errors import HadalError


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
