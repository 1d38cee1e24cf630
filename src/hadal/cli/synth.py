"""``hadal synth``: the seeded sample dive."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from hadal.cli._common import console


def synth(
    dest: Annotated[Path, typer.Argument(help="directory to write the sample dive into")],
    seed: Annotated[int, typer.Option(help="random seed (same seed → identical files)")] = 20181006,
    small: Annotated[bool, typer.Option("--small", help="small, fast variant (tests)")] = False,
    dive_id: Annotated[str | None, typer.Option("--dive-id", help="dive id (default: the directory's name)")] = None,
    usbl_interval_s: Annotated[float | None, typer.Option(
        "--usbl-interval-s", min=1.0, max=86400.0,
        help="also log USBL fixes from the ship every this many seconds (1 % of slant range, with known truth)")] = None,
) -> None:
    """Write the seeded sample dive (Haidou in the Challenger Deep) with ground truth."""
    from hadal.progress import default_progress
    from hadal.store import validate_name
    from hadal.synth import generate_dive

    if dive_id is not None:
        validate_name(dive_id, "dive id")
    out = generate_dive(dest, seed=seed, small=small, progress=default_progress(), dive_id=dive_id,
                        usbl_interval_s=usbl_interval_s)
    console.print(f"sample dive written to {out}")
