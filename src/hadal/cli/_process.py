"""Process hygiene of the commands that run flows: Prefect's environment and temporary server, the wait for
and watch of the API, signals, and stopping the children on the way out."""

from __future__ import annotations

import logging
import os
import sys
import threading
from pathlib import Path
from typing import Any

from hadal.cli._common import console
from hadal.errors import HadalError


def _api_url() -> str | None:
    """The Prefect API this process's flow runs talk to (environment, else the active profile), or None."""
    url = os.environ.get("PREFECT_API_URL")
    if url:
        return url
    try:
        from prefect.settings import get_current_settings
    except ImportError:
        return None
    return get_current_settings().api.url or None


def _wait_for_api() -> None:
    """Before the first flow run: hadal's temporary server booted (:func:`_wait_for_temporary_server`), or the
    configured API answering, waited for (bounded, a progress line on stderr: :func:`hadal.prefect_api.wait_for_api`)
    or refused in one line (exit 2)."""
    from hadal.prefect_api import api_settings, wait_for_api

    if _SERVERS:
        _wait_for_temporary_server()
        return
    url = _api_url()
    if url:
        wait_for_api(url, api_settings(), lambda line: console.print(line, highlight=False, soft_wrap=True))


def _watch_api(published: Any) -> Any:
    """Start watching the API during the flow run (:class:`hadal.prefect_api.ApiWatch`): silent for
    ``HADAL_API_LOST_S``, the run ends (:func:`_api_lost`) with ``published()`` (the versions it published) listed.
    None without an API URL."""
    from hadal.prefect_api import ApiWatch, api_settings

    url = _api_url()
    if not url:
        return None
    watch: Any = None

    def lost(_silent_s: float, _why: str) -> None:
        _api_lost(_api_lost_error(watch, published()))

    watch = ApiWatch(url, api_settings(), lost)
    return watch.start()


def _api_lost_error(watch: Any, published: list[str]) -> HadalError:
    import time

    from hadal.prefect_api import ApiUnreachable

    silent = max(0.0, time.monotonic() - watch.last_ok)
    done = f"published before it stopped (they stay published): {', '.join(published)}" if published else \
        "nothing was published"
    return ApiUnreachable(f"the Prefect API at {watch.api_url} stopped answering mid-run ({watch.why or 'no answer'}, "
                          f"silent for {silent:.0f} s; HADAL_API_LOST_S={watch.settings.lost_s:g}): run stopped; "
                          f"{done}")


def _api_lost(err: HadalError) -> None:
    """From the API watch thread: the run cannot record itself any more; say so in one line (what was published
    listed), stop the stage processes and helpers, exit 2. Half-written versions stay ``.staging-*`` directories,
    which readers never see and the next run removes."""
    if not _INTERRUPT_LOCK.acquire(blocking=False):  # an interrupt is already ending the run
        return
    try:
        # on a line of its own: Prefect's log worker may have left a partial line ("All connection attempts failed")
        console.print(f"\n[red]error:[/] {err}", highlight=False, soft_wrap=True)
    except Exception:  # noqa: BLE001 - a closed stderr: the exit status still says it
        pass
    _stop_children()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:  # noqa: BLE001
            pass
    logging.disable(logging.CRITICAL)
    os._exit(2)



# ---------------------------------------------------------------------------------------------- process hygiene
def _prefect_environment() -> None:
    """Environment for the flows, set up before they are imported: a writable PREFECT_HOME (checked: a one-line
    error instead of Prefect's tracebacks) and, unless a Prefect API is configured, hadal's temporary Prefect
    server started in the background (:func:`_start_temporary_server`): it boots on the other core while hadal
    imports the flows, and :func:`_wait_for_temporary_server` waits for it before the first flow run."""
    os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
    # the temporary server may need more than Prefect's default 20 s on a busy machine
    os.environ.setdefault("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "120")
    _check_prefect_home()
    _start_temporary_server()


def _check_prefect_home() -> None:
    """PREFECT_HOME (default ``~/.prefect``) must be a writable directory: the temporary server keeps its
    database there. Refuse in one line (ConfigError, exit 2) rather than let Prefect fail with tracebacks."""
    import tempfile

    from hadal.errors import ConfigError

    raw = os.environ.get("PREFECT_HOME")
    home = Path(raw).expanduser() if raw else Path("~/.prefect").expanduser()
    try:
        home.mkdir(parents=True, exist_ok=True)
        with tempfile.TemporaryFile(dir=home):
            pass
    except OSError as exc:
        why = exc.strerror or type(exc).__name__
        raise ConfigError(
            f"Prefect's home directory {home} is not writable ({why}); the temporary Prefect server keeps its "
            "database there: set PREFECT_HOME to a writable directory (e.g. PREFECT_HOME=$(mktemp -d))") from None


#: run as the temporary Prefect server's main: the server stops by itself when the pipe from hadal reaches EOF,
#: i.e. when hadal exits in any way (kill -9 included: the kernel closes hadal's end of the pipe)
_SERVER_GUARD = """
import os, runpy, signal, sys, threading, time
fd = int(sys.argv.pop(1))
def _watch():
    try:
        while os.read(fd, 4096):
            pass
    except OSError:
        pass
    os.kill(os.getpid(), signal.SIGTERM)
    time.sleep(10)
    os._exit(0)
threading.Thread(target=_watch, daemon=True).start()
sys.argv[0] = "uvicorn"
runpy.run_module("uvicorn", run_name="__main__", alter_sys=True)
"""

class _TemporaryServer:
    """hadal's temporary Prefect server process: its port, the (write) end of its guard pipe, open until the
    server is stopped, and its start time."""

    def __init__(self, proc, port: int, guard_w: int, started: float):
        self.proc, self.port, self.guard_w, self.started = proc, port, guard_w, started

    @property
    def api_url(self) -> str:
        return f"http://127.0.0.1:{self.port}/api"

    def signal_stop(self) -> None:
        """EOF for the guard and SIGTERM for the server, without waiting; never raises. The guard pipe is closed
        once (its descriptor number may be reused afterwards)."""
        if self.guard_w >= 0:
            try:
                os.close(self.guard_w)
            except OSError:
                pass
            self.guard_w = -1
        if self.proc.poll() is None:
            try:
                self.proc.terminate()
            except OSError:
                pass

    def stop(self) -> None:
        """:meth:`signal_stop`, then wait for the server to exit (killed after 5 s); never raises."""
        import subprocess

        self.signal_stop()
        if self.proc.poll() is None:
            try:
                self.proc.wait(timeout=5)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
            except OSError:
                pass


_SERVERS: list[_TemporaryServer] = []  # this process's temporary server (at most one; stopped at exit)


def _free_port() -> int:
    import socket

    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
        sock.bind(("127.0.0.1", 0))
        return int(sock.getsockname()[1])


def _start_temporary_server() -> str | None:
    """Start Prefect's server for this process's flow runs, unless a Prefect API is configured
    (``PREFECT_API_URL`` in the environment or the active profile: :func:`_prefect_api_configured`); returns its
    API URL (also set as ``PREFECT_API_URL`` for this process and its children, e.g. Dask workers) or None.

    It is the server Prefect's own temporary server runs (``uvicorn prefect.server.api.server:create_app`` with
    Prefect's ephemeral-server settings), started by hadal instead of by Prefect's first API call so that it boots
    while hadal imports the flows (a flow run started ~2.4 s sooner here), without loading Prefect's server code
    (~2 s of imports) into hadal. It is started before hadal imports Prefect itself (~0.8 s), the server's boot
    being the longer of the two: when Prefect's settings then name an API after all (a profile, ``prefect.toml``),
    that API wins and the server just started is stopped. It runs in its own process group - a Ctrl-C at the
    terminal reaches hadal only, which then stops the server instead of killing it under a running flow - and
    through :data:`_SERVER_GUARD`, so it exits when hadal dies, even by ``kill -9``; a normal exit stops it
    (atexit)."""
    import atexit
    import importlib.util
    import subprocess
    import time

    if _SERVERS:
        return _SERVERS[0].api_url
    if os.environ.get("PREFECT_API_URL"):
        return None  # configured in the environment: known without importing Prefect
    spec = importlib.util.find_spec("prefect")  # locates the package without importing it
    if spec is None or spec.origin is None or not (Path(spec.origin).parent / "server" / "api" / "server.py").is_file():
        return None  # a Prefect without the bundled server: Prefect reports it at the flow run
    port = _free_port()
    r, w = os.pipe()
    # the server reads Prefect's settings (environment, profile, prefect.toml) itself, as this process does
    env = {**os.environ, "PREFECT_UI_ENABLED": "0", "PREFECT__SERVER_EPHEMERAL": "1", "PREFECT__SERVER_FINAL": "1"}
    args = [sys.executable, "-c", _SERVER_GUARD, str(r), "--app-dir", str(Path(spec.origin).parent.parent),
            "--factory", "prefect.server.api.server:create_app", "--host", "127.0.0.1", "--port", str(port),
            "--log-level", "error", "--lifespan", "on"]
    try:
        proc = subprocess.Popen(args, env=env, pass_fds=(r,), process_group=0)
    finally:
        os.close(r)
    srv = _TemporaryServer(proc, port, w, time.monotonic())
    if _prefect_api_configured():  # an API in the active profile or prefect.toml: no temporary server after all
        srv.stop()
        return None
    from prefect.context import refresh_global_settings_context

    _SERVERS.append(srv)
    atexit.register(srv.stop)
    os.environ["PREFECT_API_URL"] = srv.api_url
    os.environ.setdefault("PREFECT_UI_URL", "")  # the temporary server serves no UI: no "View at <url>" lines
    refresh_global_settings_context()  # Prefect read its settings at import: make it see the URL
    return srv.api_url


def _server_text() -> str:
    """Where this process's flow runs are recorded, for the first line of ``hadal run``/``hadal stage``."""
    if _SERVERS:
        return f"a temporary Prefect server at {_SERVERS[0].api_url} (set PREFECT_API_URL to skip its start)"
    return os.environ.get("PREFECT_API_URL") or "the Prefect API of the active profile"


def _wait_for_temporary_server() -> None:
    """Wait until hadal's temporary server answers ``/health`` (no-op without one); a server that does not come up
    within ``PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS`` or exits is a one-line :class:`ConfigError`."""
    import time

    from hadal.errors import ConfigError

    if not _SERVERS:
        return
    srv = _SERVERS[0]
    try:
        limit = float(os.environ.get("PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS", "120"))
    except ValueError:
        limit = 120.0
    hint = "start one with `hadal server start` (or `prefect server start`) and set PREFECT_API_URL"
    said = srv.started
    while True:
        if time.monotonic() - said >= 10.0:  # a slow first start (a new database): a progress line every 10 s
            said = time.monotonic()
            console.print(f"waiting for the temporary Prefect server to start ({said - srv.started:.0f} s so far, "
                          f"up to {limit:g} s: PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS)", highlight=False,
                          soft_wrap=True)
        if srv.proc.poll() is not None:
            raise ConfigError(f"the temporary Prefect server exited with status {srv.proc.returncode} before it "
                              f"answered (its messages are above); {hint}")
        if _server_answers(srv, 2.0):
            return
        if time.monotonic() - srv.started > limit:
            raise ConfigError(f"the temporary Prefect server did not answer within {limit:g} s "
                              f"(PREFECT_SERVER_EPHEMERAL_STARTUP_TIMEOUT_SECONDS); {hint}")
        time.sleep(0.05)


def _server_answers(srv: _TemporaryServer, timeout_s: float) -> bool:
    """Whether ``srv`` answers ``/health`` with 200 within ``timeout_s``."""
    import urllib.error
    import urllib.request

    try:
        with urllib.request.urlopen(f"{srv.api_url}/health", timeout=timeout_s) as resp:
            return bool(resp.status == 200)
    except (urllib.error.URLError, OSError):
        return False


def _temporary_server_ready() -> bool:
    """Whether hadal's temporary server answers ``/health`` now (True without one: nothing to wait for)."""
    return not _SERVERS or _server_answers(_SERVERS[0], 0.2)


def _prepare_while_server_boots(ctx: Any, names: list[str], running: list[str]) -> list[str]:
    """Use the seconds Prefect's temporary server takes to boot (a core is idle meanwhile) for the imports the
    stages ``running`` (of the run's ``names``: those that will run, not be reused) need
    (:func:`hadal.pipeline.warm_imports`, in stage order, until the server answers); returns those of them that
    will run in their own process (:func:`hadal.flows.post_cruise.process_stages`, judged on the whole run as the
    flow judges it).

    Where processes can be forked (:func:`hadal.stage_process.can_fork_ahead`) those are forked just before the flow
    starts (:func:`_fork_ahead`) and inherit these imports, so the modules are imported once; elsewhere they are
    spawned now (:func:`hadal.stage_process.prestart`), each importing its own, and only the thread stages' modules
    are imported here. Without a temporary server (a running one is configured) nothing is imported ahead."""
    from hadal.budget import resources_of
    from hadal.flows.post_cruise import process_stages
    from hadal.pipeline import warm_imports
    from hadal.stage_process import can_fork_ahead, can_isolate, prestart

    isolated = process_stages(names) if resources_of(ctx.config).stage_processes and can_isolate() else set()
    ahead = [n for n in running if n in isolated]
    forking = can_fork_ahead()
    if not forking:
        try:
            prestart(ahead)
        except OSError:  # no process to spare now (e.g. a process limit): the flow starts the stage's own when it runs
            pass
    if _SERVERS:
        warm_imports([n for n in running if forking or n not in isolated], stop=_temporary_server_ready)
    return ahead


def _fork_ahead(ctx: Any, names: list[str], isolated: list[str]) -> None:
    """Just before the flow starts, while the main thread is still the only thread: fork the processes of the stages
    that run in their own (:func:`hadal.stage_process.prestart` with ``fork``; each imports what the boot left
    undone) and the figure helpers (:func:`_start_figure_helpers`). A fork no longer possible: the stage processes
    are spawned (if not already, during the boot) and the figures are drawn in the stages' threads."""
    from hadal.stage_process import can_fork_ahead, prestart

    forking = can_fork_ahead()
    try:  # spawned now if the fork became unsafe since the boot (another thread): not left to a cold start
        prestart(isolated, fork=forking)
    except OSError:
        pass
    if forking:
        _start_figure_helpers(ctx, names)


def _start_figure_helpers(ctx: Any, names: list[str]) -> None:
    """Fork the figure helpers (:func:`hadal.forkpool.start_helpers`) for the stages of the run that draw in a pool
    (landing with figures, report): in the flow they run in task threads, where a pool cannot fork itself, so they
    drew one figure after the other at the end of the run while a core idled. As many as those stages draw with
    (their ``figure_processes``, default :func:`hadal.forkpool.default_workers`), less the stage's own thread;
    forked just before the flow starts any other thread (:func:`_fork_ahead`). Each imports the drawing stages'
    modules first (on its own core: the flow's first stages do not draw)."""
    from hadal.forkpool import default_workers, start_helpers
    from hadal.stages.graph import stage

    cfg = ctx.config
    drawing = {"landing": cfg.landing.figure_processes if cfg.landing.figures else 1,
               "report": cfg.report.figure_processes}
    drawing = {s: n for s, n in drawing.items() if s in names}
    if not drawing:
        return
    n = max((n or default_workers()) for n in drawing.values()) - 1
    start_helpers(n, tuple(m for s in drawing for m in stage(s).warm_imports))


def _prefect_api_configured() -> bool:
    """Whether Prefect will talk to a running server (``PREFECT_API_URL`` set, in the environment or the active
    profile: Prefect's settings read both) rather than start a temporary one."""
    try:
        from prefect.settings import get_current_settings
    except ImportError:
        return False
    return bool(get_current_settings().api.url)


class _Terminated(KeyboardInterrupt):
    """SIGTERM/SIGHUP, raised in the main thread like a Ctrl-C so every path that cleans up on one runs."""

    def __init__(self, signum: int):
        super().__init__(signum)
        self.signum = signum


_INTERRUPT_LOCK = threading.Lock()  # one _interrupted() per process
_SIGNALLED: list[int] = []  # the signal that interrupted this run (typer turns the KeyboardInterrupt into exit 130)


#: seconds the main thread gets to unwind after a signal before the watchdog ends the run itself (the flow's task
#: runner waits for its stage threads on the way out; a stage may take minutes)
_UNWIND_S = 3.0


def _raise_terminated(signum, _frame) -> None:
    if _SIGNALLED:  # a second Ctrl-C: stop now (the server's guard still stops the server)
        os._exit(130 if signum == 2 else 128 + signum)
    _SIGNALLED.append(signum)
    def _watchdog() -> None:
        import time

        time.sleep(_UNWIND_S)
        _interrupted(_Terminated(signum))

    threading.Thread(target=_watchdog, name="hadal-interrupt-watchdog", daemon=True).start()
    raise _Terminated(signum)


def _install_signal_handlers() -> None:
    import signal

    for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        try:
            signal.signal(sig, _raise_terminated)
        except (ValueError, OSError):  # not the main thread / not settable
            pass


def _is_resource_tracker(proc: Any) -> bool:
    """multiprocessing's resource tracker (started with the stage processes): it ignores SIGINT/SIGTERM by design
    and exits by itself when this process does, so waiting for it would only delay the exit by the timeout."""
    try:
        return "multiprocessing.resource_tracker" in " ".join(proc.cmdline())
    except Exception:  # noqa: BLE001 - gone or unreadable: treat it as an ordinary child
        return False


def _stop_children(timeout: float = 5.0) -> None:
    """Stop Prefect's temporary server(s) and every remaining child process (Dask workers, ...); never raises."""
    import signal

    for sig in (signal.SIGINT, signal.SIGTERM):  # a second signal must not interrupt the clean-up
        try:
            signal.signal(sig, signal.SIG_IGN)
        except ValueError:  # not the main thread (the interrupt watchdog): the handler exits at once anyway
            pass
    for srv in _SERVERS:  # the wait for them is the children's, below
        srv.signal_stop()
    try:
        import psutil

        kids = [k for k in psutil.Process().children(recursive=True) if not _is_resource_tracker(k)]
        for k in kids:
            try:
                k.terminate()
            except psutil.Error:
                pass
        _gone, alive = psutil.wait_procs(kids, timeout=timeout)
        for k in alive:
            try:
                k.kill()
            except psutil.Error:
                pass
        psutil.wait_procs(alive, timeout=timeout)
    except Exception:  # psutil missing or the process table unreadable: the guards still stop the server
        pass


def _interrupted(exc: KeyboardInterrupt) -> None:
    """One line, children stopped, exit 130 (Ctrl-C) or 128+signal; ``os._exit``: threads still running a
    stage (Prefect's task runners) must not keep a killed run alive, and atexit handlers would only log
    tracebacks about the server that is already gone. A half-written version stays a ``.staging-*``
    directory, which readers never see and the next run removes."""
    import signal

    if not _INTERRUPT_LOCK.acquire(blocking=False):  # the watchdog or the main thread is already on it
        while True:
            import time

            time.sleep(60)
    signum = getattr(exc, "signum", signal.SIGINT)
    name = signal.Signals(signum).name
    try:
        console.print(f"[red]error:[/] interrupted ({name}); nothing half-written was published", highlight=False,
                      soft_wrap=True)
    except Exception:
        pass
    _stop_children()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:
            pass
    logging.disable(logging.CRITICAL)
    os._exit(130 if signum == signal.SIGINT else 128 + signum)
