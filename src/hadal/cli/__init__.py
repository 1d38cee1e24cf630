"""``hadal`` command line.

    hadal run RAW_DIR              run the whole post-cruise flow on a raw dive
    hadal run --dives DIR...       several dives in parallel on Dask (--workers N, --scheduler ADDRESS)
    hadal cruise-dtm DIR... --cruise ID --resolution-m R   one DTM of every dive's soundings, on Dask
    hadal stage NAME RAW_DIR       re-run one stage, reusing the latest upstream products (--force, --downstream)
    hadal report DIVE              write the dive report (HTML) from the products in the store
    hadal serve RAW_DIR --cron ..  deploy the post-cruise flow on a schedule (Prefect server)
    hadal products DIVE            list product versions in the store
    hadal server start             a long-running local Prefect server (then export PREFECT_API_URL=...)
    hadal synth DEST               write the seeded sample dive (Challenger Deep, Haidou-like)
    hadal compile                  compile the numba kernels into numba's cache (once after installing)
    hadal inspect FILE...          what each file is (by content) and what is in it (--json)
    hadal init RAW_DIR             write a commented dive.yaml (+ vehicle.yaml) from the files found
    hadal schema dive|vehicle|pipeline   JSON Schema of a configuration file (for editors)

Problems with the input are reported as one line (``error: ...``) with exit status 2.
"""

from __future__ import annotations

import logging
import os
import sys
import threading
from typing import Annotated, Any

import typer

from hadal.errors import HadalError

app = typer.Typer(add_completion=False, no_args_is_help=True, help="hadal: post-dive processing for deep-sea vehicles.")
# Imports stay inside the commands that need them (stages, Prefect, xarray, matplotlib take seconds to import):
# the listing commands (--help, --version, products, config, inspect) answer in a fraction of a second
# (bench/bench_cli.py).


def _version_callback(value: bool) -> None:
    if value:
        from hadal import __version__

        print(f"hadal {__version__}")
        raise typer.Exit(0)


@app.callback()
def _root(
    version: Annotated[bool, typer.Option("--version", help="print hadal's version and exit", is_eager=True,
                                          callback=_version_callback)] = False,
) -> None:
    """hadal: post-dive processing for deep-sea vehicles."""


from hadal.cli import compile as _compile  # noqa: E402 - the commands, registered below (each imports lazily)
from hadal.cli import config as _config  # noqa: E402
from hadal.cli import cruise as _cruise  # noqa: E402
from hadal.cli import init as _init  # noqa: E402
from hadal.cli import inspect as _inspect  # noqa: E402
from hadal.cli import products as _products  # noqa: E402
from hadal.cli import report as _report  # noqa: E402
from hadal.cli import run as _run  # noqa: E402
from hadal.cli import schema as _schema  # noqa: E402
from hadal.cli import serve as _serve  # noqa: E402
from hadal.cli import server as _server  # noqa: E402
from hadal.cli import stage as _stage  # noqa: E402
from hadal.cli import synth as _synth  # noqa: E402
from hadal.cli._common import console  # noqa: E402
from hadal.cli._process import _SIGNALLED, _install_signal_handlers, _interrupted, _Terminated  # noqa: E402

app.command("run")(_run.run)
app.command("stage")(_stage.stage)
app.command("cruise-dtm")(_cruise.cruise_dtm)
app.command("report")(_report.report)
app.command("serve")(_serve.serve)
_server.server_app.command("start")(_server.server_start)
app.add_typer(_server.server_app, name="server")
app.command("products")(_products.products)
app.command("synth")(_synth.synth)
app.command("compile")(_compile.compile_cmd)
app.command("config")(_config.config_cmd)
app.command("inspect")(_inspect.inspect)
app.command("init")(_init.init)
app.command("schema")(_schema.schema)

def entry() -> None:
    """The ``hadal`` command (and ``python -m hadal.cli``): :func:`main`, then the process ends without the
    interpreter's teardown. After a full dive the teardown (freeing every object and module of a process that held
    gigabytes) took 1.2-1.4 s after the last line was printed; what a normal exit must do is done first: the threads
    that are not daemons are joined (as the interpreter's own shutdown does), the atexit handlers run (the temporary
    Prefect server and the stage processes are stopped, logging is flushed) and the standard streams are flushed.
    An exception other than :class:`SystemExit` propagates as usual. :func:`main` itself raises ``SystemExit`` (tests
    call it in-process)."""
    sys.stdout = _StdoutGuard(sys.stdout, say=len(sys.argv) > 1 and sys.argv[1] in _WORKING_COMMANDS)
    try:
        main()
        code: Any = 0
    except SystemExit as exc:
        code = exc.code
    if code is not None and not isinstance(code, int):  # sys.exit("message"): printed, status 1 (as Python does)
        print(code, file=sys.stderr)
        code = 1
    _exit_now(code or 0)


#: commands that publish or write something: a closed stdout is said on stderr (:class:`_StdoutGuard`)
_WORKING_COMMANDS = frozenset({"run", "stage", "report", "serve", "synth", "init", "compile"})


class _StdoutGuard:
    """``sys.stdout`` of the ``hadal`` command: a closed pipe (``hadal run ... | head -1``, the reader gone: EPIPE,
    SIGPIPE being ignored by Python) must not stop the run, nor end it with an exit status and no word (click's own
    EPIPE handling: exit 1). The first failed write says so once on stderr, points the descriptor at ``/dev/null``
    and the command goes on: what it would print there is dropped, its products are published as usual and its exit
    status is the run's. ``say``: a command that does work says so (``run``, ``report``, ...); a listing piped into
    ``head`` (``hadal config | head``) stops printing silently, as Unix tools do."""

    def __init__(self, stream: Any, say: bool = True):
        self._stream = stream
        self.say = say
        self.broken = False

    def _broken_pipe(self) -> None:
        if not self.broken:
            self.broken = True
            try:
                devnull = os.open(os.devnull, os.O_WRONLY)
                os.dup2(devnull, self._stream.fileno())
                os.close(devnull)
            except (OSError, ValueError, AttributeError):
                pass
            if not self.say:
                return
            try:
                console.print("note: standard output was closed by its reader (broken pipe); hadal goes on "
                              "without it: the rest of what it prints there is dropped; its work (published products, "
                              "exit status) is not affected",
                              highlight=False, soft_wrap=True)
            except Exception:  # noqa: BLE001 - stderr closed too: the exit status still tells
                pass

    def write(self, text: str) -> int:
        if self.broken:
            return len(text)
        try:
            return self._stream.write(text)
        except BrokenPipeError:
            self._broken_pipe()
            return len(text)

    def flush(self) -> None:
        if self.broken:
            return
        try:
            self._stream.flush()
        except BrokenPipeError:
            self._broken_pipe()

    def __getattr__(self, name: str) -> Any:
        return getattr(self._stream, name)


def _exit_now(code: int) -> None:
    """Exit with ``code`` as the interpreter would, in its order, but without its final teardown: threading's shutdown
    (its exit hooks stop the thread pools, then the threads that are not daemons are joined), the atexit handlers,
    the standard streams flushed, then ``os._exit``. Where that sequence is not available, the normal exit."""
    import atexit

    shutdown_threads = getattr(threading, "_shutdown", None)
    run_exit_handlers = getattr(atexit, "_run_exitfuncs", None)
    if shutdown_threads is None or run_exit_handlers is None:  # not CPython's: the normal (slower) exit
        sys.exit(code)
    shutdown_threads()
    run_exit_handlers()
    for stream in (sys.stdout, sys.stderr):
        try:
            stream.flush()
        except Exception:  # noqa: BLE001 - a closed or broken stream: nothing left to save
            pass
    os._exit(code)


def main() -> None:
    _install_signal_handlers()
    try:
        _main()
    except KeyboardInterrupt as exc:
        _interrupted(exc)
    except SystemExit:
        if _SIGNALLED:  # typer swallowed the interrupt (exit 130 without a word): say it, clean up
            _interrupted(_Terminated(_SIGNALLED[0]))
        raise


def _main() -> None:
    logging.basicConfig(level=os.environ.get("HADAL_LOG_LEVEL", "INFO"), format="%(levelname)s %(name)s: %(message)s")
    for noisy in ("httpx", "httpcore"):  # one line per Prefect API request otherwise
        logging.getLogger(noisy).setLevel(logging.WARNING)
    try:
        rc = app(standalone_mode=False)
    except HadalError as exc:
        console.print(f"[red]error:[/] {exc}", highlight=False, soft_wrap=True)  # one line, even at 80 columns
        sys.exit(2)
    except typer.Exit as exc:
        sys.exit(exc.exit_code)
    except typer.Abort as exc:  # click turns a KeyboardInterrupt into Abort
        cause = exc.__cause__ or exc.__context__
        _interrupted(cause if isinstance(cause, KeyboardInterrupt) else KeyboardInterrupt())
    except Exception as exc:  # click usage errors
        _click_error(exc)
        raise
    sys.exit(rc if isinstance(rc, int) else 0)


def _click_exception_types() -> tuple[type[BaseException], ...]:
    """click's exception classes: typer's vendored click (``typer._click``) and, if installed, click itself."""
    types: list[type[BaseException]] = []
    for mod in ("typer._click.exceptions", "click.exceptions"):
        if mod.split(".")[0] == "click" and "click" not in sys.modules:
            continue  # not the one typer used
        try:
            m = __import__(mod, fromlist=["ClickException"])
        except ImportError:
            continue
        types.append(m.ClickException)
    return tuple(types)


def _click_error(exc: BaseException) -> None:
    """A click usage error as one line (exit 2), plain ``hadal`` as its help (exit 0); returns for other errors."""
    types = _click_exception_types()
    if not types or not isinstance(exc, types):
        return
    if type(exc).__name__ == "NoArgsIsHelpError":  # plain 'hadal' or a group without arguments: its help
        ctx = getattr(exc, "ctx", None)
        print(ctx.get_help() if ctx is not None else "", end="\n")
        sys.exit(0)
    msg = " ".join(str(exc.format_message() if hasattr(exc, "format_message") else exc).split())
    ctx = getattr(exc, "ctx", None)
    where = f" ({ctx.command_path} --help for usage)" if ctx is not None else " (hadal --help for usage)"
    code = getattr(exc, "exit_code", 2)
    console.print(f"[red]error:[/] {msg}{where}", highlight=False, soft_wrap=True, markup=True)
    sys.exit(2 if code in (1, 2) else code)

