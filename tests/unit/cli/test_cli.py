"""CLI: bad input gives one clear line and exit status 2, never a traceback.

The error paths run in-process through typer's CliRunner (streams and environment isolated, ``hadal.cli._main``
called as the entry point calls it, so the one-line formatting of ``main`` is what is tested); one subprocess
smoke test goes through the installed ``hadal`` entry point."""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
from cli_runner import Res, run_cli

REPO = Path(__file__).resolve().parents[3]


def hadal(*args: str, env: dict[str, str] | None = None) -> Res:
    """``hadal ARGS`` in-process (:func:`cli_runner.run_cli`, ``HADAL_PROGRESS=0``)."""
    return run_cli(*args, env={"HADAL_PROGRESS": "0", **(env or {})})


def assert_one_line_error(res: Res, *fragments: str) -> None:
    assert res.returncode == 2, (res.stdout, res.stderr)
    assert "Traceback" not in res.stderr + res.stdout
    err_lines = [ln for ln in res.stderr.splitlines() if ln.startswith("error:")]
    assert len(err_lines) == 1, res.stderr
    for frag in fragments:
        assert frag in err_lines[0], err_lines[0]


def test_run_missing_directory(tmp_path):
    assert_one_line_error(hadal("run", str(tmp_path / "nope")), "does not exist")


def test_run_directory_without_dive_yaml(tmp_path):
    assert_one_line_error(hadal("run", str(tmp_path)), "dive.yaml")


@pytest.mark.parametrize(
    "content,fragment",
    [
        ("dive_id: [unclosed", "not valid YAML"),
        ("- a\n- b\n", "mapping"),
        ("dive_id: ../escape\nlaunch: {latitude_deg: 1, longitude_deg: 2}\n", "dive_id"),
        ("dive_id: d1\nlaunch: {latitude_deg: 100, longitude_deg: 2}\n", "latitude_deg"),
        ("dive_id: d1\n", "no source files"),
        ("dive_id: d1\nlaunch: {latitude_deg: 1, longitude_deg: 2}\nbogus: 1\n", "bogus"),
    ],
)
def test_run_bad_dive_yaml(tmp_path, content, fragment):
    (tmp_path / "dive.yaml").write_text(content)
    assert_one_line_error(hadal("run", str(tmp_path)), fragment)


def test_bad_pipeline_config(tmp_path):
    (tmp_path / "dive.yaml").write_text("dive_id: d1\nlaunch: {latitude_deg: 1, longitude_deg: 2}\n")
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("nonexistent_stage: {a: 1}\n")
    assert_one_line_error(hadal("run", str(tmp_path), "--config", str(cfg)), "nonexistent_stage")
    assert_one_line_error(hadal("run", str(tmp_path), "--config", str(tmp_path / "missing.yaml")), "does not exist")


def test_unknown_stage(tmp_path):
    (tmp_path / "dive.yaml").write_text("dive_id: d1\nlaunch: {latitude_deg: 1, longitude_deg: 2}\n")
    assert_one_line_error(hadal("stage", "teleport", str(tmp_path)), "unknown stage")


def test_products_path_traversal_and_empty(tmp_path):
    assert_one_line_error(hadal("products", "../../etc", "--store", str(tmp_path)), "invalid dive id")
    assert_one_line_error(hadal("products", "d1", "--store", str(tmp_path)), "no products for dive 'd1'")
    assert_one_line_error(hadal("products", "d1", "--store", str(tmp_path), "--json"), "no products")
    assert list(tmp_path.iterdir()) == []  # nothing created by a listing


def test_help_lists_commands():
    res = hadal("--help")
    assert res.returncode == 0
    for cmd in ("run", "stage", "products", "synth"):
        assert cmd in res.stdout


def test_version_plain_and_usage_errors_are_one_line():
    from hadal import __version__

    res = hadal("--version")
    assert res.returncode == 0 and res.stdout.strip() == f"hadal {__version__}"
    res = hadal()
    assert res.returncode == 0 and "Commands" in res.stdout and "Traceback" not in res.stderr
    for args, frag in ((["runn"], "No such command"), (["run", "--bogus", "x"], "--bogus"),
                       (["run"], "Missing argument"), (["stage", "grid"], "Missing argument")):
        assert_one_line_error(hadal(*args), frag)


def test_entry_point_smoke():
    """The one subprocess test: the installed console script answers --version and reports a usage error as one
    line with exit status 2 (no traceback from the real interpreter)."""
    from hadal import __version__

    exe = shutil.which("hadal", path=os.path.dirname(sys.executable)) or shutil.which("hadal")
    if exe is None:
        pytest.skip("no installed `hadal` console script")
    env = {**os.environ, "HADAL_PROGRESS": "0", "COLUMNS": "200"}
    res = subprocess.run([exe, "--version"], capture_output=True, text=True, env=env, timeout=120)
    assert res.returncode == 0 and res.stdout.strip() == f"hadal {__version__}", res.stderr
    res = subprocess.run([exe, "run", "--bogus", "x"], capture_output=True, text=True, env=env, timeout=120)
    assert_one_line_error(Res(res.returncode, res.stdout, res.stderr), "--bogus")


def test_config_output_is_cached_per_code_version(tmp_path):
    """`hadal config` (cached per code version) prints exactly what the generator makes; a cache file of another
    code version is never used."""
    from hadal.settings import default_yaml

    (tmp_path / "pipeline-defaults-0.0.0+stale.yaml").write_text("stale: true\n")
    oracle = default_yaml()
    first = hadal("config", env={"HADAL_CACHE_DIR": str(tmp_path)})
    assert first.returncode == 0 and first.stdout == oracle, first.stderr
    cached = [f for f in tmp_path.glob("pipeline-defaults-*.yaml") if "stale" not in f.name]
    assert len(cached) == 1 and cached[0].read_text() == oracle
    second = hadal("config", env={"HADAL_CACHE_DIR": str(tmp_path)})
    assert second.stdout == first.stdout


def test_every_command_of_the_module_doc_answers_help():
    """Every command the CLI's own docstring lists (``hadal server start`` included, a sub-command) is
    registered: ``hadal <command> --help`` exits 0 and shows that command's usage."""
    import re

    from hadal import cli

    listed = {m.group(1) for m in re.finditer(r"^\s+hadal ((?:server start)|[a-z-]+)", cli.__doc__ or "", re.M)}
    assert {"run", "stage", "server start", "cruise-dtm", "inspect", "init"} <= listed
    for command in sorted(listed):
        r = run_cli(*command.split(), "--help")
        assert r.returncode == 0, (command, r.stdout, r.stderr)
        assert f"hadal {command}" in r.stdout, command
