"""The temporary-server guard costs nothing when a Prefect server is configured (issue 19: an unchanged single
stage with ``--flow`` within 2 s of Prefect's own start): Prefect's server code is loaded only when a temporary
server will start, and then the guard is installed."""

from __future__ import annotations

import os
import subprocess
import sys

import pytest

_PROBE = """
import sys
from hadal import cli
cli._prefect_environment()
srv = sys.modules.get("prefect.server.api.server")
print("loaded" if srv is not None else "not-loaded",
      bool(srv is not None and getattr(srv.SubprocessASGIServer, "_hadal_guarded", False)))
"""


def _probe(tmp_path, api_url: str | None) -> list[str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("PREFECT_API")}
    env["PREFECT_HOME"] = str(tmp_path / "prefect-home")
    if api_url:
        env["PREFECT_API_URL"] = api_url
    res = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    return res.stdout.split()


@pytest.mark.parametrize(("api_url", "expected"), [
    (None, ["loaded", "True"]),  # a temporary server will start: it is guarded
    ("http://127.0.0.1:9/api", ["not-loaded", "False"]),  # a running server: nothing to guard, nothing loaded
])
def test_guard_only_for_a_temporary_server(tmp_path, api_url, expected):
    assert _probe(tmp_path, api_url) == expected


def test_api_url_in_the_active_profile_counts(tmp_path):
    home = tmp_path / "prefect-home"
    home.mkdir()
    (home / "profiles.toml").write_text('active = "srv"\n\n[profiles.srv]\nPREFECT_API_URL = "http://127.0.0.1:9/api"\n')
    assert _probe(tmp_path, None) == ["not-loaded", "False"]
