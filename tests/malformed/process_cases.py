"""Process cases of the reliability report (issue 45): the ``hadal`` command and stage processes under the faults of
the process around them - a Prefect API that refuses, accepts and never answers, or never becomes ready; a closed
stdout pipe; ``kill -9`` in the middle of a publish; two runs of one stage at once.

Each case runs real processes (``python -m hadal.cli`` or ``tests/malformed/stage_worker.py``) in the shape of
``tests/reliability_report.py``'s ``Item``:

* the command ends with exit 2, exactly one ``error:`` line on stderr and no traceback: :class:`CliError` (a
  :class:`hadal.errors.HadalError`) carrying that line, which the report checks against ``match`` with the store
  byte-for-byte unchanged (clean error);
* a traceback on stderr, or another exit status where an error was due: a ``RuntimeError`` (counted as a
  traceback);
* a run that completes: its ``CliRun`` (exit status, stdout, stderr, store) for ``check``, an oracle on the store
  (the versions verify against their manifests, the expected versions are there) and on what stderr says;
* a command still running after :data:`CASE_TIMEOUT_S` is killed with its process group and raises
  ``subprocess.TimeoutExpired`` (counted as a hang);
* every process a case starts carries ``HADAL_CASE_TAG`` in its environment: :func:`leftover` finds those still
  running after the case (orphans; they are then killed).
"""

from __future__ import annotations

import http.server
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import uuid
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hadal.errors import HadalError

HERE = Path(__file__).resolve().parent
REPO = HERE.parent.parent
WORKER = HERE / "stage_worker.py"
#: a command of a case still running after this is a hang (below the report's watchdog, so the case can kill it)
CASE_TIMEOUT_S = 100.0


class CliError(HadalError):
    """The one ``error:`` line of a command that ended with exit 2 and no traceback."""


@dataclass
class CliRun:
    returncode: int
    stdout: str
    stderr: str
    store: Path


@dataclass
class ProcessCase:
    name: str
    prepare: Callable[[Path, Path], None]
    run: Callable[[Path, Path], Any]
    error: str | None
    match: str
    check: Callable[[Path, Any], bool] | None = None


_TAG = f"hadal-case-{uuid.uuid4().hex}"


def env(**extra: str) -> dict[str, str]:
    """The environment of a case's processes: this repository's ``src``, no Prefect API of the caller, no progress
    lines, and the tag :func:`leftover` looks for."""
    e = {k: v for k, v in os.environ.items() if not k.startswith(("PREFECT_API", "HADAL_API"))}
    e.update({"PYTHONPATH": os.pathsep.join([str(REPO / "src"), str(REPO)]), "HADAL_PROGRESS": "0",
              "PREFECT_SERVER_ANALYTICS_ENABLED": "false", "COLUMNS": "200", "HADAL_CASE_TAG": _TAG})
    e.update(extra)
    return e


def leftover() -> list[int]:
    """Processes started by a case (``HADAL_CASE_TAG`` in their environment) still running: their pids (they are
    killed, so that one case's orphans do not count again in the next)."""
    try:
        import psutil
    except ImportError:  # pragma: no cover
        return []
    found = []
    for proc in psutil.process_iter(["pid"]):
        try:
            if proc.pid != os.getpid() and proc.environ().get("HADAL_CASE_TAG") == _TAG \
                    and proc.status() != psutil.STATUS_ZOMBIE:
                found.append(proc)
        except (psutil.Error, OSError):
            continue
    for proc in found:
        try:
            proc.kill()
        except psutil.Error:
            pass
    psutil.wait_procs(found, timeout=10)  # gone (or a zombie its parent reaps) before the next case looks
    return sorted(p.pid for p in found)


def _kill_group(proc: subprocess.Popen) -> None:
    try:
        os.killpg(proc.pid, signal.SIGKILL)
    except (ProcessLookupError, PermissionError):
        pass
    proc.wait(timeout=30)


def _finish(proc: subprocess.Popen, store: Path, error_due: bool, stdout_closed: bool = False) -> CliRun:
    """Wait for ``proc`` (at most :data:`CASE_TIMEOUT_S`) and classify its end (module docstring)."""
    try:
        if stdout_closed:
            err = proc.stderr.read() if proc.stderr else ""
            proc.wait(timeout=CASE_TIMEOUT_S)
            out = ""
        else:
            out, err = proc.communicate(timeout=CASE_TIMEOUT_S)
    except subprocess.TimeoutExpired:
        _kill_group(proc)
        raise
    rc = proc.returncode
    if "Traceback" in (out or "") + (err or ""):
        raise RuntimeError(f"exit {rc} with a traceback: {err.strip().splitlines()[-1] if err.strip() else ''}")
    errors = [ln for ln in err.splitlines() if ln.startswith("error:")]
    if rc == 2 and len(errors) == 1:
        raise CliError(errors[0][len("error:"):].strip())
    if rc != 0 or error_due:
        raise RuntimeError(f"exit {rc}, {len(errors)} error line(s): {err.strip()[-500:]}")
    return CliRun(rc, out, err, store)


def hadal(args: list[str], store: Path, *, error_due: bool, stdout_closed: bool = False, **extra: str) -> CliRun:
    """``python -m hadal.cli ARGS`` in its own session (its process group killed on a hang)."""
    proc = subprocess.Popen([sys.executable, "-m", "hadal.cli", *args], stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True, cwd=REPO, env=env(**extra), start_new_session=True)
    if stdout_closed:
        proc.stdout.close()  # before the child has even imported hadal (``hadal ... | head -0``)
    return _finish(proc, store, error_due, stdout_closed)


# ------------------------------------------------------------------------------------ Prefect API faults
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class _Starting(http.server.BaseHTTPRequestHandler):
    """``/api/health`` answering 503 ("starting") for ever: a server that never becomes ready."""

    def do_GET(self) -> None:  # noqa: N802 - http.server's name
        self.send_response(503)
        self.send_header("Content-Length", "8")
        self.end_headers()
        self.wfile.write(b"starting")

    def log_message(self, *args: Any) -> None:
        pass


@contextmanager
def _api(kind: str) -> Iterator[str]:
    """A Prefect API URL on loopback that refuses (``closed``), accepts and never answers (``silent``) or answers
    503 for ever (``never_ready``)."""
    port = _free_port()
    held: Any = None
    if kind == "silent":
        held = socket.socket()
        held.bind(("127.0.0.1", port))
        held.listen(16)
    elif kind == "never_ready":
        held = http.server.ThreadingHTTPServer(("127.0.0.1", port), _Starting)
        threading.Thread(target=held.serve_forever, daemon=True).start()
    try:
        yield f"http://127.0.0.1:{port}/api"
    finally:
        if isinstance(held, socket.socket):
            held.close()
        elif held is not None:
            held.shutdown()
            held.server_close()


def _dive(d: Path) -> Path:
    from tiny_dive import write_dive

    raw = d / "dive"
    if not (raw / "dive.yaml").is_file():
        write_dive(raw, 30.0, csv=False, dive_id="proc-dive")
    return raw


def _run_unreachable(kind: str) -> Callable[[Path, Path], Any]:
    def run(d: Path, store: Path) -> Any:
        with _api(kind) as url:
            return hadal(["run", str(_dive(d)), "--store", str(store)], store, error_due=True,
                         PREFECT_API_URL=url, HADAL_API_WAIT_S="2", PREFECT_HOME=str(d / "prefect-home"))
    return run


# ------------------------------------------------------------------------------------ a closed stdout pipe
def _prep_fake_products(d: Path, store: Path) -> None:
    from factories import publish_fake_products

    from hadal.store import ProductStore

    publish_fake_products(ProductStore(store), "dive-a", products=("ctd",))


def _check_report_published(d: Path, res: CliRun) -> bool:
    """The report version is published and verifies; stderr says that stdout was closed (one line)."""
    from hadal.store import ProductStore

    st = ProductStore(res.store)
    pv = st.latest("dive-a", "report")
    return (pv is not None and not st.verify(pv) and (pv.path / "report.html").is_file()
            and len([ln for ln in res.stderr.splitlines() if "standard output was closed" in ln]) == 1)


# ------------------------------------------------------------------------------------ stage processes
def _worker(raw: Path, store: Path, *extra: str) -> subprocess.Popen:
    return subprocess.Popen([sys.executable, str(WORKER), "ingest", str(raw), str(store), *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env(),
                            start_new_session=True)


def _wait_for(path: Path, proc: subprocess.Popen) -> None:
    deadline = time.monotonic() + CASE_TIMEOUT_S
    while not path.exists():
        if proc.poll() is not None:
            raise RuntimeError(f"stage worker exited ({proc.returncode}) before its pause: "
                               f"{(proc.stderr.read() if proc.stderr else '')[-500:]}")
        if time.monotonic() > deadline:
            _kill_group(proc)
            raise subprocess.TimeoutExpired(WORKER.name, CASE_TIMEOUT_S)
        time.sleep(0.01)


def _versions(store: Path) -> dict[str, bool]:
    """``product/vNNN`` -> verifies against its manifest, for the dive of the process cases."""
    from hadal.store import ProductStore

    st = ProductStore(store)
    return {f"{product}/{pv.label}": not st.verify(pv)
            for product in st.products("proc-dive") for pv in st.versions("proc-dive", product)}


def _prep_one_version(d: Path, store: Path) -> None:
    proc = _worker(_dive(d), store)
    _finish(proc, store, error_due=False)


def _run_kill9(d: Path, store: Path) -> Any:
    """SIGKILL while ingest has written its first product file into staging (no manifest yet); then the user runs
    it again. What hadal does at the start of a run after an hour (``clean_staging``) is done at once here."""
    from hadal.store import ProductStore

    marker = d / "paused"
    marker.unlink(missing_ok=True)
    proc = _worker(_dive(d), store, "--pause", "write", "--marker", str(marker))
    try:
        _wait_for(marker, proc)
    finally:
        _kill_group(proc)
    seen = _versions(store)  # what readers see right after the kill
    again = _finish(_worker(_dive(d), store), store, error_due=False)
    cleaned = ProductStore(store).clean_staging(older_than_s=0)
    return {"after_kill": seen, "after_rerun": _versions(store), "cleaned": len(cleaned), "rerun": again}


def _check_kill9(d: Path, res: dict) -> bool:
    """Right after the kill only the intact v001; after the rerun v001 and v002, both intact; one staging leftover
    (the killed run's) removed."""
    return (res["after_kill"] == {"sensors/v001": True}
            and res["after_rerun"] == {"sensors/v001": True, "sensors/v002": True} and res["cleaned"] == 1)


def _run_concurrent(d: Path, store: Path) -> Any:
    """Two ingest runs of one dive, held at the commit until both are there, then released together."""
    go, marks = d / "go", [d / "m1", d / "m2"]
    for f in (go, *marks):
        f.unlink(missing_ok=True)
    procs = [_worker(_dive(d), store, "--pause", "commit", "--marker", str(m), "--go", str(go)) for m in marks]
    try:
        for m, p in zip(marks, procs, strict=True):
            _wait_for(m, p)
        go.write_text("go")
        runs = [_finish(p, store, error_due=False) for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                _kill_group(p)
    return {"versions": _versions(store), "labels": sorted(r.stdout.split()[-1] for r in runs)}


def _check_concurrent(d: Path, res: dict) -> bool:
    """v001 (the seed) and the two runs' v002 and v003, every one intact."""
    return (res["versions"] == {"sensors/v001": True, "sensors/v002": True, "sensors/v003": True}
            and res["labels"] == ["v002", "v003"])


CASES: list[ProcessCase] = [
    ProcessCase("proc_prefect_api_refused", lambda d, s: None, _run_unreachable("closed"), "CliError",
                r"cannot be reached.*connection refused"),
    ProcessCase("proc_prefect_api_accepts_never_answers", lambda d, s: None, _run_unreachable("silent"), "CliError",
                r"cannot be reached.*no answer within"),
    ProcessCase("proc_prefect_server_never_ready", lambda d, s: None, _run_unreachable("never_ready"), "CliError",
                r"cannot be reached.*HTTP 503"),
    ProcessCase("proc_stdout_closed_report", _prep_fake_products,
                lambda d, s: hadal(["report", "dive-a", "--store", str(s)], s, error_due=False, stdout_closed=True),
                None, "", _check_report_published),
    ProcessCase("proc_stdout_closed_listing", _prep_fake_products,
                lambda d, s: hadal(["products", "dive-a", "--store", str(s)], s, error_due=False,
                                   stdout_closed=True),
                None, "", lambda d, res: res.returncode == 0 and res.stderr == ""),
    ProcessCase("proc_kill9_mid_publish", _prep_one_version, _run_kill9, None, "", _check_kill9),
    ProcessCase("proc_two_concurrent_stage_runs", _prep_one_version, _run_concurrent, None, "", _check_concurrent),
]
