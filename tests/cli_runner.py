"""``hadal ARGS`` in-process through typer's CliRunner, shared by the CLI tests (``test_cli``, ``test_cli_init``):
streams and environment isolated, ``hadal.cli._main`` called as the entry point calls it, so the one-line error
formatting of ``main`` is what is tested."""

from __future__ import annotations

import sys
import traceback
from collections.abc import Mapping
from dataclasses import dataclass

from typer.testing import CliRunner

from hadal import cli


@dataclass
class Res:
    returncode: int
    stdout: str
    stderr: str


def run_cli(*args: str, env: Mapping[str, str] | None = None) -> Res:
    """``hadal ARGS`` in-process: exit status, stdout, stderr; an escaping exception is printed as a traceback
    on stderr, as the interpreter would print it. ``env`` is added to ``COLUMNS=200`` (no progress bars unless
    it sets ``HADAL_PROGRESS``)."""
    runner = CliRunner()
    code = 0
    with runner.isolation(env={"HADAL_PROGRESS": "none", "COLUMNS": "200", **(env or {})}) as (out, err, _):
        argv, sys.argv = sys.argv, ["hadal", *args]
        try:
            cli._main()
        except SystemExit as exc:
            code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
        except Exception:  # would be a traceback for the user
            traceback.print_exc(file=sys.stderr)
            code = 1
        finally:
            sys.argv = argv
            sys.stdout.flush()
            sys.stderr.flush()
        return Res(code, out.getvalue().decode(), err.getvalue().decode())
