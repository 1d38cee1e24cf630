"""The Prefect API a run records itself on (issues 45, 46): a server still starting is waited for (bounded, a
progress line on stderr), an unreachable one is a one-line ``error:`` with exit 2, a server lost mid-run ends the run
within ``HADAL_API_LOST_S`` with what it published listed; a closed stdout pipe is said on stderr and changes
nothing else; ``hadal server start --port N`` gives a UI that talks to port N.

Oracles: the exit status and stderr of the ``hadal`` command in a child process, a loopback socket that refuses
(closed port) or accepts and never answers, small HTTP servers on loopback that answer ``/health`` late, a real
``prefect server start`` (integration tier) and its ``/ui-settings`` endpoint, and the product store's manifests.
"""

from __future__ import annotations

import http.server
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import pytest

from hadal.errors import ConfigError
from hadal.prefect_api import ApiSettings, ApiUnreachable, ApiWatch, api_settings, probe, wait_for_api

HERE = Path(__file__).resolve().parents[2]
HADAL = [sys.executable, "-m", "hadal.cli"]


def _env(**extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PREFECT_API", "HADAL_API"))}
    env.update({"PYTHONPATH": os.pathsep.join([str(HERE.parent / "src"), str(HERE.parent)]), "HADAL_PROGRESS": "0",
                "PREFECT_SERVER_ANALYTICS_ENABLED": "false", "COLUMNS": "200"})
    env.update(extra)
    return env


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _errors(stderr: str) -> list[str]:
    return [ln for ln in stderr.splitlines() if ln.startswith("error:")]


class _Health(http.server.BaseHTTPRequestHandler):
    """``/api/health``: 503 until the server's ``ready_at`` (monotonic), then 200 ``true``."""

    def do_GET(self) -> None:  # noqa: N802 - http.server's name
        ok = self.path.rstrip("/") == "/api/health" and time.monotonic() >= self.server.ready_at  # type: ignore[attr-defined]
        body = b"true" if ok else b"starting"
        self.send_response(200 if ok else 503)
        self.send_header("Content-Length", str(len(body)))
        self.end_headers()
        self.wfile.write(body)

    def log_message(self, *args) -> None:
        pass


def _health_server(port: int, ready_in_s: float) -> http.server.ThreadingHTTPServer:
    srv = http.server.ThreadingHTTPServer(("127.0.0.1", port), _Health)
    srv.ready_at = time.monotonic() + ready_in_s  # type: ignore[attr-defined]
    threading.Thread(target=srv.serve_forever, daemon=True).start()
    return srv


def _fast(**kw) -> ApiSettings:
    return ApiSettings(**{"probe_timeout_s": 0.5, "poll_s": 0.1, **kw})


# ---------------------------------------------------------------------------------------------------- unit level
def test_settings_are_bounded_and_named_in_the_error():
    assert api_settings({}) == ApiSettings()
    assert api_settings({"HADAL_API_WAIT_S": "5", "HADAL_API_LOST_S": "20"}).lost_s == 20.0
    for env, name in (({"HADAL_API_WAIT_S": "1e9"}, "HADAL_API_WAIT_S"), ({"HADAL_API_LOST_S": "0"}, "HADAL_API_LOST_S"),
                      ({"HADAL_API_LOST_S": "soon"}, "HADAL_API_LOST_S"), ({"HADAL_API_WAIT_S": "nan"}, "HADAL_API_WAIT_S")):
        with pytest.raises(ConfigError, match=name):
            api_settings(env)


def test_a_server_that_starts_late_is_waited_for_with_a_progress_line():
    """Port refused first (uvicorn binds after the application's startup), then 503, then 200: waited for; one
    progress line, not one per probe."""
    port = _free_port()
    url = f"http://127.0.0.1:{port}/api"
    box: dict = {}
    timer = threading.Timer(0.8, lambda: box.setdefault("srv", _health_server(port, 0.7)))
    timer.start()
    said: list[str] = []
    try:
        waited = wait_for_api(url, _fast(wait_s=20), said.append)
    finally:
        timer.join()
        box["srv"].shutdown()
    assert 1.4 <= waited < 10, waited
    assert len(said) == 1 and "waiting for the Prefect API" in said[0] and "connection refused" in said[0], said
    assert probe(url, 0.5) is not None  # shut down: refused again


@pytest.mark.parametrize("kind", ["closed", "silent", "never_ready"])
def test_a_server_that_never_answers_is_a_bounded_one_line_error(kind):
    port = _free_port()
    url = f"http://127.0.0.1:{port}/api"
    held = None
    if kind == "silent":  # accepts connections (kernel backlog) but never answers a request
        held = socket.socket()
        held.bind(("127.0.0.1", port))
        held.listen(16)
    elif kind == "never_ready":
        held = _health_server(port, 1e9)
    t0 = time.monotonic()
    try:
        with pytest.raises(ApiUnreachable) as exc:
            wait_for_api(url, _fast(wait_s=1.5), lambda _line: None)
    finally:
        if isinstance(held, socket.socket):
            held.close()
        elif held is not None:
            held.shutdown()
    assert time.monotonic() - t0 < 5
    msg = str(exc.value)
    assert "\n" not in msg and url in msg and "HADAL_API_WAIT_S" in msg
    assert {"closed": "connection refused", "silent": "no answer within", "never_ready": "HTTP 503"}[kind] in msg


def test_watch_calls_lost_once_when_the_server_stops_answering():
    port = _free_port()
    srv = _health_server(port, 0.0)
    lost: list[tuple[float, str]] = []
    watch = ApiWatch(f"http://127.0.0.1:{port}/api", _fast(lost_s=2.0), lambda s, why: lost.append((s, why)))
    watch.start()
    time.sleep(0.6)
    assert not lost and watch.answering()
    srv.shutdown()
    srv.server_close()
    t0 = time.monotonic()
    while not lost and time.monotonic() - t0 < 10:
        time.sleep(0.05)
    watch.stop()
    assert len(lost) == 1 and 2.0 <= lost[0][0] < 5 and lost[0][1] == "connection refused", lost
    assert time.monotonic() - t0 < 5


def test_server_start_sets_the_ui_api_url_unless_the_user_did(monkeypatch):
    from hadal.cli import server as cli

    for name in ("PREFECT_SERVER_UI_API_URL", "PREFECT_UI_API_URL"):
        monkeypatch.delenv(name, raising=False)
    assert cli._server_ui_environment("http://127.0.0.1:4321/api") == {
        "PREFECT_SERVER_UI_API_URL": "http://127.0.0.1:4321/api"}
    assert cli._url_host("0.0.0.0") == "127.0.0.1" and cli._url_host("::1") == "[::1]"
    monkeypatch.setenv("PREFECT_UI_API_URL", "https://proxy.example/api")
    assert cli._server_ui_environment("http://127.0.0.1:4321/api") == {}


# ---------------------------------------------------------------------------------------------- the hadal command
@pytest.mark.parametrize("kind", ["closed", "silent"])
def test_run_against_an_unreachable_api_is_one_line_exit_2(small_dive, tmp_path, kind):
    """Was a 430-line traceback and exit 1 after ~17 s of Prefect's retries."""
    port = _free_port()
    held = None
    if kind == "silent":
        held = socket.socket()
        held.bind(("127.0.0.1", port))
        held.listen(16)
    t0 = time.monotonic()
    try:
        res = subprocess.run([*HADAL, "run", str(small_dive), "--store", str(tmp_path / "store")],
                             env=_env(PREFECT_API_URL=f"http://127.0.0.1:{port}/api", HADAL_API_WAIT_S="2",
                                      PREFECT_HOME=str(tmp_path / "ph")),
                             capture_output=True, text=True, timeout=120)
    finally:
        if held is not None:
            held.close()
    assert res.returncode == 2, res.stderr[-3000:]
    assert "Traceback" not in res.stderr + res.stdout
    errs = _errors(res.stderr)
    assert len(errs) == 1 and "cannot be reached" in errs[0] and f":{port}/api" in errs[0], res.stderr
    assert any(ln.startswith("waiting for the Prefect API") for ln in res.stderr.splitlines()), res.stderr
    assert len(res.stderr.splitlines()) <= 8, res.stderr
    assert time.monotonic() - t0 < 60
    assert not any((tmp_path / "store").glob("*/*/v001"))  # nothing published without a run record


def _closed_stdout(*args: str) -> tuple[int, str]:
    """``hadal ARGS`` whose stdout reader is gone before hadal writes (``hadal ... | head -0``)."""
    proc = subprocess.Popen([*HADAL, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            env=_env(MPLCONFIGDIR=os.environ.get("MPLCONFIGDIR", "")))
    proc.stdout.close()  # before the child has even imported hadal
    err = proc.stderr.read()
    return proc.wait(timeout=300), err


def test_a_closed_stdout_pipe_is_said_on_stderr_and_changes_nothing_else(tmp_path):
    """Was exit 1 and no word (click's own EPIPE handling). ``hadal report`` publishes, then prints the path: the
    version stays published, exit 0, one note on stderr; a listing (``hadal products | head``) stops silently."""
    from factories import publish_fake_products

    from hadal.store import ProductStore

    store = tmp_path / "store"
    publish_fake_products(ProductStore(store), "dive-a", products=("ctd",))
    rc, err = _closed_stdout("report", "dive-a", "--store", str(store))
    assert rc == 0 and "Traceback" not in err, err
    assert [ln for ln in err.splitlines() if "standard output was closed" in ln], err
    assert (ProductStore(store).latest("dive-a", "report").path / "report.html").is_file()
    rc, err = _closed_stdout("products", "dive-a", "--store", str(store))
    assert (rc, err) == (0, "")


# ------------------------------------------------------------------------------------------- integration tier
def _start_prefect_server(tmp_path: Path, port: int, *args: str, env: dict[str, str] | None = None) -> subprocess.Popen:
    return subprocess.Popen(args or [sys.executable, "-m", "prefect", "server", "start", "--host", "127.0.0.1",
                                     "--port", str(port)],
                            env=env or _env(PREFECT_HOME=str(tmp_path / "prefect-home")), start_new_session=True,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def _stop_group(proc: subprocess.Popen) -> None:
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except ProcessLookupError:
        pass
    proc.wait(timeout=30)


@pytest.mark.integration
@pytest.mark.slow
def test_server_killed_mid_run_ends_the_run_in_bounded_time_listing_what_was_published(small_dive, tmp_path):
    """A real ``prefect server start`` on loopback, killed (-9, with its children) once the first version is
    published: ``hadal run`` ends within HADAL_API_LOST_S (+ probes) with one ``error:`` line naming the versions it
    published, which stay published (manifest present); it was a ~10 min hang, then a traceback. hadal is started
    while the server boots: the start is waited for too."""
    port = _free_port()
    store = tmp_path / "store"
    server = _start_prefect_server(tmp_path, port)
    hadal = None
    try:
        hadal = subprocess.Popen([*HADAL, "run", str(small_dive), "--store", str(store)], start_new_session=True,
                                 env=_env(PREFECT_API_URL=f"http://127.0.0.1:{port}/api", HADAL_API_WAIT_S="180",
                                          HADAL_API_LOST_S="5", PREFECT_HOME=str(tmp_path / "prefect-home")),
                                 stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        deadline = time.monotonic() + 400
        while not any(store.glob("*/*/v001/manifest.json")):
            assert hadal.poll() is None, hadal.stderr.read()[-3000:]
            assert time.monotonic() < deadline, "no version published"
            time.sleep(0.2)
        _stop_group(server)
        killed = time.monotonic()
        _out, err = hadal.communicate(timeout=60)
        took = time.monotonic() - killed
    finally:
        _stop_group(server)
        if hadal is not None and hadal.poll() is None:
            _stop_group(hadal)
    assert hadal.returncode == 2, err[-3000:]
    assert took < 30, took  # HADAL_API_LOST_S=5, probes every 1 s (2 s timeout), the stage processes stopped
    assert "Traceback" not in err, err[-3000:]
    errs = _errors(err)
    assert len(errs) == 1 and "stopped answering mid-run" in errs[0], err[-3000:]
    published = sorted(f"{p.parent.parent.name}/{p.parent.name}" for p in store.glob("*/*/v*/manifest.json"))
    assert published and all(v in errs[0] for v in published), (published, errs[0])


@pytest.mark.integration
@pytest.mark.slow
def test_server_start_on_a_free_port_serves_a_ui_that_talks_to_that_port(tmp_path):
    """``hadal server start --port N`` with a profile-like PREFECT_API_URL pointing at 4200 (the trap: Prefect's
    UI then asked port 4200): the UI's settings endpoint names port N."""
    port = _free_port()
    env = _env(PREFECT_HOME=str(tmp_path / "prefect-home"), PREFECT_API_URL="http://127.0.0.1:4200/api")
    server = _start_prefect_server(tmp_path, port, *HADAL, "server", "start", "--port", str(port), env=env)
    try:
        ready = wait_for_api(f"http://127.0.0.1:{port}/api", ApiSettings(wait_s=240), lambda _line: None)
        assert ready >= 0
        with urllib.request.urlopen(f"http://127.0.0.1:{port}/ui-settings", timeout=30) as resp:
            ui = json.loads(resp.read())
    finally:
        _stop_group(server)
    assert ui["api_url"] == f"http://127.0.0.1:{port}/api", ui


@pytest.mark.integration
@pytest.mark.slow
def test_run_with_stdout_closed_completes_and_says_so(small_dive, tmp_path):
    """``hadal run DIVE | head -0``: the run completes (exit 0, every product of the run published with its
    manifest, the report among them) and says on stderr that its stdout was closed."""
    store = tmp_path / "store"
    proc = subprocess.Popen([*HADAL, "run", str(small_dive), "--store", str(store)], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, env=_env(PREFECT_HOME=str(tmp_path / "ph")))
    proc.stdout.close()
    err = proc.stderr.read()
    assert proc.wait(timeout=900) == 0, err[-3000:]
    assert "Traceback" not in err and "standard output was closed" in err, err[-3000:]
    assert (next(store.glob("*/report/v001")) / "report.html").is_file()
