"""``hadal serve``: the post-cruise flow deployed on a cron schedule."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from hadal.cli._common import ConfigOpt, StoreOpt, _store_root, console


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
