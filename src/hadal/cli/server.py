"""``hadal server start``: a long-running local Prefect server."""

from __future__ import annotations

import os
import sys
from pathlib import Path
from typing import Annotated

import typer

from hadal.cli._common import console
from hadal.cli._process import _check_prefect_home

server_app = typer.Typer(add_completion=False, no_args_is_help=True,
                         help="a long-running local Prefect server (runs then skip the temporary server's start)")


def server_start(
    host: Annotated[str, typer.Option("--host", help="address to listen on (keep loopback: no authentication)")
                    ] = "127.0.0.1",
    port: Annotated[int, typer.Option("--port", help="port of the API and UI")] = 4200,
) -> None:
    """Run a Prefect server in the foreground (``prefect server start``); in another shell set the
    PREFECT_API_URL it prints, and every hadal run uses it (no temporary server per run, runs in its UI)."""
    import shutil

    from hadal.errors import ConfigError

    if not 1 <= port <= 65535:
        raise ConfigError(f"--port must be 1-65535 (got {port})")
    exe = shutil.which("prefect") or str(Path(sys.executable).with_name("prefect"))
    if not Path(exe).is_file():
        raise ConfigError("the 'prefect' command is not installed next to hadal (pip install prefect)")
    _check_prefect_home()
    api_url = f"http://{_url_host(host)}:{port}/api"
    console.print(f"Prefect server on {api_url[:-4]}; in the shell that runs hadal:\n"
                  f"  export PREFECT_API_URL={api_url}", highlight=False)
    os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
    os.environ.update(_server_ui_environment(api_url))
    sys.stdout.flush()
    sys.stderr.flush()
    os.execv(exe, [exe, "server", "start", "--host", host, "--port", str(port)])



def _url_host(host: str) -> str:
    """``host`` as the UI and hadal reach it: a wildcard address (listen on every interface) as loopback, an IPv6
    address in brackets."""
    if host in ("0.0.0.0", "::", ""):
        return "127.0.0.1"
    return f"[{host}]" if ":" in host and not host.startswith("[") else host


def _server_ui_environment(api_url: str) -> dict[str, str]:
    """Settings of ``hadal server start``'s server so that its UI talks to *its* API: the UI asks the API at
    ``PREFECT_SERVER_UI_API_URL`` (Prefect 3.8; served at ``/ui-settings``), which defaults to ``PREFECT_API_URL`` if
    set (e.g. a profile's ``http://127.0.0.1:4200/api``), else ``PREFECT_SERVER_API_HOST``/``PORT`` (4200): neither
    the ``--port`` given. One set by the user (``PREFECT_SERVER_UI_API_URL`` or its alias ``PREFECT_UI_API_URL``,
    e.g. behind a proxy) is kept."""
    if os.environ.get("PREFECT_SERVER_UI_API_URL") or os.environ.get("PREFECT_UI_API_URL"):
        return {}
    return {"PREFECT_SERVER_UI_API_URL": api_url}
