"""``hadal cruise-dtm``: one DTM of every listed dive's multibeam soundings, on Dask (:mod:`hadal.flows.cruise`)."""

from __future__ import annotations

from pathlib import Path
from typing import Annotated

import typer

from hadal.cli._common import ConfigOpt, StoreOpt, _quiet_prefect_tracebacks, _store_root, console
from hadal.cli._process import _prefect_environment, _wait_for_api


def cruise_dtm(
    dives: Annotated[list[Path], typer.Argument(help="dive directories (with dive.yaml), or folders holding them")],
    cruise: Annotated[str, typer.Option("--cruise", help="cruise id: the store's <cruise>/cruise_dtm/vNNN/")],
    resolution_m: Annotated[float, typer.Option("--resolution-m", help="cell size of the cruise DTM (m)",
                                                min=0.01, max=100_000.0)],
    store: StoreOpt = None,
    config: ConfigOpt = None,
    workers: Annotated[int, typer.Option("--workers", help="Dask LocalCluster worker processes", min=1,
                                         max=256)] = 2,
    scheduler: Annotated[str | None, typer.Option("--scheduler", help="address of an existing Dask scheduler "
                                                  "(tcp://host:8786); every worker must see the raw "
                                                  "directories and the store")] = None,
) -> None:
    """Grid every listed dive's multibeam soundings into one cruise DTM (dives and tiles are Dask tasks); a dive
    that cannot be read is named and left out, the rest gridded."""
    from hadal.dive import find_dives
    from hadal.settings import load_config
    from hadal.store import validate_name

    validate_name(cruise, "cruise id")
    raw_dirs = find_dives(*dives)
    params = load_config(config).grid
    _prefect_environment()
    from hadal.flows.cruise import cruise_dtm as run_cruise_dtm

    _quiet_prefect_tracebacks()
    _wait_for_api()
    where = f"scheduler {scheduler}" if scheduler else f"LocalCluster, {workers} worker(s)"
    console.print(f"[bold]hadal[/] cruise DTM of {len(raw_dirs)} dive(s) at {resolution_m:g} m on {where}",
                  highlight=False)
    out = run_cruise_dtm([str(d) for d in raw_dirs], str(_store_root(store)), cruise, resolution_m, workers,
                         scheduler, params=params)
    for raw, why in (out.get("refused_raw_dirs") or {}).items():
        console.print(f"[yellow]left out[/] {raw}: {why}", highlight=False, soft_wrap=True)
    print(f"cruise DTM: {Path(out['path']) / 'cruise_dtm.nc'} ({len(out['dives'])} dive(s))")
