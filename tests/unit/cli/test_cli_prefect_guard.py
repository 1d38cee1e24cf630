"""hadal's temporary Prefect server (issue 19): started only when no Prefect API is configured, without loading
Prefect's server code into hadal; it answers at the URL hadal gives Prefect, and stops when hadal exits (normally
here; kill -9, Ctrl-C and SIGTERM in tests/unit/orchestration/test_process_hygiene.py)."""

from __future__ import annotations

import json
import os
import subprocess
import sys

import pytest

_PROBE = """
import json, sys, urllib.request
from hadal.cli import _process as cli
cli._prefect_environment()
from prefect.settings import get_current_settings
out = {"server_code_loaded": "prefect.server.api.server" in sys.modules, "started": bool(cli._SERVERS),
       "api_url": get_current_settings().api.url, "ui_url": get_current_settings().ui_url}
if cli._SERVERS:
    cli._wait_for_temporary_server()
    with urllib.request.urlopen(out["api_url"] + "/health", timeout=10) as r:
        out["health"] = r.status
    out["pid"] = cli._SERVERS[0].proc.pid
print(json.dumps(out))
"""


def _probe(tmp_path, api_url: str | None) -> dict:
    env = {k: v for k, v in os.environ.items() if not k.startswith("PREFECT_API")}
    env["PREFECT_HOME"] = str(tmp_path / "prefect-home")
    if api_url:
        env["PREFECT_API_URL"] = api_url
    res = subprocess.run([sys.executable, "-c", _PROBE], env=env, capture_output=True, text=True, timeout=300)
    assert res.returncode == 0, res.stderr[-2000:]
    return json.loads(res.stdout.strip().splitlines()[-1])


def _gone(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    try:  # a zombie not yet reaped by init counts as gone
        with open(f"/proc/{pid}/stat") as f:
            return f.read().split(")")[-1].split()[0] == "Z"
    except OSError:
        return True


def test_temporary_server_starts_answers_and_stops(tmp_path):
    out = _probe(tmp_path, None)
    assert out["started"] and not out["server_code_loaded"], out
    assert out["api_url"].startswith("http://127.0.0.1:") and out["health"] == 200, out
    assert not out["ui_url"], out  # no UI on the temporary server: no "View at" link to nowhere
    assert _gone(out["pid"]), "the temporary server outlived hadal"


@pytest.mark.parametrize("api_url", ["http://127.0.0.1:9/api"])
def test_no_server_when_an_api_is_configured(tmp_path, api_url):
    out = _probe(tmp_path, api_url)
    assert out == {"server_code_loaded": False, "started": False, "api_url": api_url, "ui_url": "http://127.0.0.1:9"}


def test_api_url_in_the_active_profile_counts(tmp_path):
    home = tmp_path / "prefect-home"
    home.mkdir()
    (home / "profiles.toml").write_text('active = "srv"\n\n[profiles.srv]\nPREFECT_API_URL = "http://127.0.0.1:9/api"\n')
    out = _probe(tmp_path, None)
    assert out == {"server_code_loaded": False, "started": False, "api_url": "http://127.0.0.1:9/api",
                   "ui_url": "http://127.0.0.1:9"}


@pytest.mark.parametrize(("code", "timeout", "message"), [
    ("raise SystemExit(3)", "120", "exited with status 3 before it answered"),
    ("import time; time.sleep(30)", "0.3", "did not answer within 0.3 s"),
])
def test_a_server_that_does_not_come_up_is_one_line(monkeypatch, code, timeout, message):
    """A temporary server that dies or never answers /health: a one-line ConfigError naming the way out."""
    import time

    from hadal.cli import _process as cli
    from hadal.errors import ConfigError

    proc = subprocess.Popen([sys.executable, "-c", code])
    r, w = os.pipe()
    os.close(r)
    srv = cli._TemporaryServer(proc, cli._free_port(), w, time.monotonic())
    monkeypatch.setattr(cli, "_SERVERS", [srv])
    monkeypatch.setenv("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", timeout)
    try:
        with pytest.raises(ConfigError, match=message) as exc:
            cli._wait_for_temporary_server()
        assert "\n" not in str(exc.value) and "PREFECT_API_URL" in str(exc.value)
    finally:
        srv.stop()
    assert proc.poll() is not None


def test_a_slow_temporary_server_start_says_so(monkeypatch, capsys):
    """A start longer than 10 s (a new database on a busy machine) gets a progress line, then the bounded error."""
    import time

    from hadal.cli import _process as cli
    from hadal.errors import ConfigError

    proc = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    r, w = os.pipe()
    os.close(r)
    srv = cli._TemporaryServer(proc, cli._free_port(), w, time.monotonic() - 10.0)  # booting for 10 s already
    monkeypatch.setattr(cli, "_SERVERS", [srv])
    monkeypatch.setenv("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "11")
    try:
        with pytest.raises(ConfigError, match="did not answer within 11 s"):
            cli._wait_for_temporary_server()
    finally:
        srv.stop()
    err = capsys.readouterr().err
    assert "waiting for the temporary Prefect server to start (10 s so far, up to 11 s" in err, err
