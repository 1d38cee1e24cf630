"""Serve the post-cruise flow on a cron schedule (``hadal serve RAW_DIR --cron "..."``).

``RAW_DIR`` is one dive (it holds ``dive.yaml``: the deployment re-runs ``post-cruise`` on it) or a cruise
directory of dives (``<cruise>/<dive>/dive.yaml``: the deployment runs ``post-cruise-new-dives``, which
discovers the dives present at each run, so every new dive is processed on the next tick while dives
whose raw files, parameters and code are unchanged are task-cache hits and publish nothing new).

``flow.serve`` registers a deployment with a cron schedule on the Prefect server named by
``PREFECT_API_URL`` and then polls it, executing scheduled runs in this process's machine. Schedules
need a real server (``prefect server start``): the temporary server a plain flow run starts cannot
schedule. See docs/operations.md.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

from prefect import flow

from hadal.dive import DIVE_FILE, find_dives
from hadal.errors import ConfigError, StageError

DEFAULT_NAME = "hadal-post-cruise"


@flow(name="post-cruise-new-dives", log_prints=True)
def post_cruise_new_dives(
    cruise_dir: str,
    store_root: str | None = None,
    config_path: str | None = None,
    stages: list[str] | None = None,
) -> dict[str, dict[str, Any]]:
    """Run ``post-cruise`` on every dive directory in ``cruise_dir`` (new dives are processed, unchanged
    ones are cache hits). A failing dive does not stop the others, but the run then ends Failed (so a
    scheduled run shows red) with the failed dives and their errors in the message.

    Returns ``{dive_dir: {"ok": True, "published": {...}}}`` when every dive succeeded.
    """
    from hadal.flows.post_cruise import post_cruise

    results: dict[str, dict[str, Any]] = {}
    dives = find_dives(cruise_dir, allow_empty=True)
    print(f"{cruise_dir}: {len(dives)} dive(s)")
    for d in dives:
        try:
            results[str(d)] = {"ok": True, "published": post_cruise(str(d), store_root, config_path, stages)}
        except Exception as exc:  # noqa: BLE001 - one bad dive must not stop the cruise
            results[str(d)] = {"ok": False, "error": str(exc).splitlines()[0] if str(exc) else type(exc).__name__}
        print(f"{d.name}: {'ok' if results[str(d)]['ok'] else results[str(d)]['error']}")
    failed = {k: v["error"] for k, v in results.items() if not v["ok"]}
    if failed:
        raise StageError(f"{len(failed)} of {len(results)} dive(s) failed: "
                         + "; ".join(f"{Path(k).name}: {e}" for k, e in failed.items()))
    return results


def require_api_url() -> str:
    """``PREFECT_API_URL`` from the environment or the active Prefect profile, else a clear ConfigError."""
    url = os.environ.get("PREFECT_API_URL")
    if not url:
        try:
            from prefect.settings import PREFECT_API_URL

            url = PREFECT_API_URL.value()
        except Exception:  # noqa: BLE001 - settings unreadable: treat as unset
            url = None
    if not url:
        raise ConfigError(
            "hadal serve needs a Prefect server: run 'prefect server start' and set "
            "PREFECT_API_URL=http://127.0.0.1:4200/api (see docs/operations.md)"
        )
    return url


def check_cron(cron: str) -> str:
    """Validate a cron expression with Prefect's own validator; one-line ConfigError if invalid."""
    from prefect._internal.schemas.validators import validate_cron_string

    try:
        return validate_cron_string(cron)
    except ValueError as exc:
        raise ConfigError(f"invalid cron schedule {cron!r}: {exc} (expected 5 fields, e.g. '0 3 * * *')") from None


def serve_post_cruise(raw_dir: str, store_root: str | None, config_path: str | None, *, cron: str,
                      name: str = DEFAULT_NAME, stages: list[str] | None = None) -> None:
    """Create/update the deployment ``<flow>/<name>`` on ``cron`` and serve it (blocks until stopped).

    A dive directory deploys ``post-cruise``; a cruise directory deploys ``post-cruise-new-dives``.
    """
    fl, params = deployment_target(raw_dir, store_root, config_path, stages)
    fl.serve(
        name=name,
        cron=cron,
        parameters=params,
        description=f"hadal post-cruise processing of {raw_dir}",
        tags=["hadal"],
        pause_on_shutdown=False,
    )


def deployment_target(raw_dir: str, store_root: str | None, config_path: str | None,
                      stages: list[str] | None = None):
    """``(flow, parameters)`` to deploy for ``raw_dir``: one dive, or a cruise directory of dives."""
    from pathlib import Path

    from hadal.flows.post_cruise import post_cruise

    common = {"store_root": store_root, "config_path": config_path, "stages": stages}
    if (Path(raw_dir) / DIVE_FILE).is_file():
        return post_cruise, {"raw_dir": raw_dir, **common}
    return post_cruise_new_dives, {"cruise_dir": raw_dir, **common}


if __name__ == "__main__":  # python -m hadal.flows.serve RAW_DIR CRON
    import sys

    serve_post_cruise(sys.argv[1], os.environ.get("HADAL_STORE"), None, cron=sys.argv[2])
