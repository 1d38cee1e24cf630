"""``hadal init``: a commented dive.yaml (and vehicle.yaml) from the files found."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer
from rich.markup import escape

from hadal.cli._common import console


def init(
    raw_dir: Annotated[Path, typer.Argument(help="raw dive directory to describe")],
    dive_id: Annotated[str | None, typer.Option("--dive-id", help="dive id (default: the directory's name)")] = None,
    launch: Annotated[str | None, typer.Option("--launch", help="launch position LAT,LON (decimal degrees)")] = None,
    force: Annotated[bool, typer.Option("--force", help="overwrite an existing dive.yaml / vehicle.yaml")] = False,
    dry_run: Annotated[bool, typer.Option("--dry-run", help="print and validate, write nothing")] = False,
) -> None:
    """Scan RAW_DIR, write a commented dive.yaml (and vehicle.yaml) and say what is still to be filled in."""
    from hadal.dive_init import parse_latlon_pair, scan_dive_dir, write_init
    from hadal.stages.plan import format_plan
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
        console.print(f"[green]mapped[/]   {escape(line)}", highlight=False)
    for line in res.not_used:
        console.print(f"[yellow]not used[/] {escape(line)}", highlight=False)
    for line in res.todo:
        console.print(f"[red]to do[/]    {escape(line)}", highlight=False)
    if res.plan:
        console.print("plan:", highlight=False)
        console.print(format_plan(res.plan), highlight=False, markup=False)
    if dry_run:
        print(res.dive_yaml(), end="")
        if res.vehicle_yaml:
            print("# ---- vehicle.yaml\n" + res.vehicle_yaml, end="")
        return
    for p in write_init(res, force=force):
        console.print(f"wrote {escape(str(p))}", highlight=False)
