"""Serve the post-cruise flow on a cron schedule (``hadal serve RAW_DIR --cron "..."``).

``flow.serve`` registers a deployment with a cron schedule on the Prefect server named by
``PREFECT_API_URL`` and then polls it, executing scheduled runs in this process's machine. Schedules
need a real server (``prefect server start``): the temporary server a plain flow run starts cannot
schedule. See docs/operations.md.
"""

from __future__ import annotations

import os

from hadal.errors import ConfigError

DEFAULT_NAME = "hadal-post-cruise"


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
    """Create/update the deployment ``post-cruise/<name>`` on ``cron`` and serve it (blocks until stopped)."""
    from flows.post_cruise import post_cruise

    post_cruise.serve(
        name=name,
        cron=cron,
        parameters={"raw_dir": raw_dir, "store_root": store_root, "config_path": config_path, "stages": stages},
        description=f"hadal post-cruise processing of {raw_dir}",
        tags=["hadal"],
        pause_on_shutdown=False,
    )


if __name__ == "__main__":  # python -m flows.serve RAW_DIR CRON
    import sys

    serve_post_cruise(sys.argv[1], os.environ.get("HADAL_STORE"), None, cron=sys.argv[2])
