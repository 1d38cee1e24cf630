"""``hadal inspect``: what each file is and what is in it."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Annotated

import typer
from rich.console import Console
from rich.table import Table

from hadal.cli._common import ConfigOpt, console


def inspect(
    files: Annotated[list[Path], typer.Argument(help="files (or directories, searched recursively) to describe")],
    as_json: Annotated[bool, typer.Option("--json", help="machine-readable output")] = False,
    config: ConfigOpt = None,
) -> None:
    """What each file is (detected from its content) and what is in it (read within the memory budget of
    --config's resources.max_memory_gb, else the defaults')."""
    from hadal.budget import memory_limit_bytes
    from hadal.inspect import inspect_file, summary_line
    from hadal.settings import load_config

    paths: list[Path] = []
    for f in files:
        paths += sorted(p for p in f.rglob("*") if p.is_file()) if f.is_dir() else [f]
        if f.is_dir() and not any(p.is_file() for p in f.rglob("*")):
            console.print(f"{f}: a directory with no files in it", highlight=False)
    limit = memory_limit_bytes(load_config(config) if config is not None else None)
    infos = [inspect_file(p, memory_limit_bytes=limit) for p in paths]
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
