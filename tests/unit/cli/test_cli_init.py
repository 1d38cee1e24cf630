"""`hadal inspect`, `hadal init`, `hadal config --check DIR`, `hadal schema` in-process through typer's CliRunner
(streams and environment isolated, ``hadal.cli._main`` called as the entry point calls it), and
`hadal init DIR && hadal run DIR` on a compressed real cast through the Prefect flow as a user runs it (subprocesses,
integration tier)."""

from __future__ import annotations

import gzip
import json
import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml
from cli_runner import Res, run_cli

REPO = Path(__file__).resolve().parents[3]


def hadal(*args: str) -> Res:
    """``hadal ARGS`` in-process (:func:`cli_runner.run_cli`)."""
    return run_cli(*args)


def hadal_subprocess(*args: str, env: dict[str, str] | None = None, timeout: int = 300) -> subprocess.CompletedProcess:
    """``python -m hadal.cli ARGS`` in a child process (the acceptance path only)."""
    env = {**os.environ, "HADAL_PROGRESS": "none", "PREFECT_SERVER_ANALYTICS_ENABLED": "false", **(env or {})}
    return subprocess.run([sys.executable, "-m", "hadal.cli", *args], capture_output=True, text=True, env=env,
                          timeout=timeout)


def _no_traceback(res: Res | subprocess.CompletedProcess) -> None:
    assert "Traceback" not in res.stderr + res.stdout, res.stderr[-2000:]


def test_inspect_json_and_exit_codes(tmp_path):
    good = tmp_path / "soundings.dat"
    good.write_text("142.1 11.2 8123.5\n142.2 11.3 8124.0\n142.3 11.3 8125.5\n")
    res = hadal("inspect", "--json", str(good), str(tmp_path / "missing.bin"))
    _no_traceback(res)
    assert res.returncode == 2  # one file could not be read
    info = json.loads(res.stdout)
    assert [i["kind"] for i in info] == ["xyz", "unreadable"]
    assert info[0]["source"] == "multibeam" and "does not exist" in info[1]["error"]
    res = hadal("inspect", str(good))
    assert res.returncode == 0 and "xyz" in res.stdout


def test_init_writes_validates_and_never_overwrites(tmp_path):
    raw = tmp_path / "My Dive 3"
    raw.mkdir()
    (raw / "soundings.xyz").write_text("".join(f"{142 + i * 1e-3:.4f} {11 + j * 1e-3:.4f} {8000 + i + j}\n"
                                               for i in range(20) for j in range(20)))
    res = hadal("init", str(raw), "--dry-run")
    _no_traceback(res)
    assert res.returncode == 0 and not (raw / "dive.yaml").exists()
    assert "dive_id: My-Dive-3" in res.stdout and "run   dtm" in res.stderr
    res = hadal("init", str(raw))
    assert res.returncode == 0, res.stderr
    d = yaml.safe_load((raw / "dive.yaml").read_text())
    # lon/lat and depth were guessed from the values: written as explicit, commented hints (issue 43)
    assert d["sources"] == {"multibeam": [{"path": "soundings.xyz", "crs": "EPSG:4326", "z_positive": "down"}]}
    assert "# guessed by hadal init, change if wrong: x/y taken as longitude/latitude" in (raw / "dive.yaml").read_text()
    assert d["map_frame"]["origin_latitude_deg"] == pytest.approx(11.0095, abs=1e-3)
    again = hadal("init", str(raw))
    assert again.returncode == 2 and "already exist" in again.stderr and len(again.stderr.strip().splitlines()) == 1
    assert hadal("init", str(raw), "--force", "--dive-id", "d7").returncode == 0
    assert yaml.safe_load((raw / "dive.yaml").read_text())["dive_id"] == "d7"
    chk = hadal("config", "--check", str(raw))
    assert chk.returncode == 0 and "run   dtm" in chk.stdout and "skip  landing" in chk.stdout
    assert "lacks creator_name, creator_email, institution, project, license" in chk.stdout
    bad = hadal("init", str(raw), "--force", "--launch", "95,10")
    assert bad.returncode == 2 and "--launch" in bad.stderr


def test_schema_command_and_field_reference_is_current():
    res = hadal("schema", "dive")
    s = json.loads(res.stdout)
    assert {"dive_id", "launch", "sources"} <= set(s["properties"])
    assert "SourceFile" in s["$defs"]
    assert hadal("schema", "nonsense").returncode == 2
    from hadal.schema_docs import render_doc

    doc = (REPO / "docs" / "dive-directory.md").read_text()
    assert render_doc(doc) == doc, "docs/dive-directory.md is stale: run python -m hadal.schema_docs"


@pytest.mark.integration  # slow (> 9 s here): the integration tier (issue 20: make test <= 5 min)
@pytest.mark.prefect
def test_init_then_run_a_compressed_real_cast(shared_data, tmp_path):
    """The acceptance path: `hadal init DIR && hadal run DIR`, generated yaml unedited, through Prefect."""
    raw = tmp_path / "cast-dive"
    raw.mkdir()
    src = shared_data / "ctd-real" / "oceissues644_02dk.cnv"
    (raw / "station12.dat").write_bytes(gzip.compress(src.read_bytes()))  # compressed, odd name
    env = {"PREFECT_HOME": os.environ.get("PREFECT_HOME", str(tmp_path / "prefect"))}
    assert hadal_subprocess("init", str(raw), env=env).returncode == 0
    res = hadal_subprocess("run", str(raw), "--store", str(tmp_path / "store"), env=env, timeout=600)
    _no_traceback(res)
    assert res.returncode == 0, res.stderr[-3000:]
    listing = json.loads(hadal("products", "cast-dive", "--store", str(tmp_path / "store"), "--json").stdout)
    assert {"sensors", "ctd", "profile", "report"} <= {r["product"] for r in listing}
    summary = json.loads(next((tmp_path / "store" / "cast-dive" / "report").glob("v*/summary.json")).read_text())
    assert {s["stage"] for s in summary["skipped_stages"]} == {"dtm", "laser", "suitability", "match", "landing"}


def test_init_writes_a_commented_acdd_metadata_stub(tmp_path):
    """A new dive.yaml shows every discovery field with its ACDD meaning, commented out (no placeholder reaches a
    product); uncommented as is it validates, and filling it in empties the `hadal config --check` list."""
    from hadal.dive import Dive
    from hadal.dive_init import METADATA_STUB, InitResult
    from hadal.products import missing_acdd_fields
    from hadal.products.metadata import REQUIRED_FIELDS as ACDD_REQUIRED  # ACDD-1.3 + IOOS-1.2 required

    res = InitResult(raw_dir=tmp_path, dive={"dive_id": "d1", "platform": "Haidou", "sources": {}})
    text = res.dive_yaml()
    assert yaml.safe_load(text) == res.dive  # the stub is comments only
    lines = text.splitlines()
    start = lines.index("# metadata:")
    stub = [ln[2:] for ln in lines[start:] if ln.startswith("#   ") or ln == "# metadata:"]
    for key in (*ACDD_REQUIRED, "creator_type", "naming_authority", "platform_vocabulary_name", "instruments"):
        i = next(k for k, ln in enumerate(stub) if ln.strip().startswith(f"{key}:"))
        if key != "instruments":
            assert ("ACDD" in stub[i - 1] or "IOOS" in stub[i - 1]) and stub[i - 1].strip().startswith("#"), (
                key, stub[i - 1])
    assert {k for k, _, _ in METADATA_STUB} >= set(ACDD_REQUIRED)
    uncommented = yaml.safe_load("\n".join(stub))
    dive = Dive.model_validate({**res.dive, **uncommented})
    assert missing_acdd_fields(dive) == list(ACDD_REQUIRED)  # empty values: still listed, nothing invented
    filled = {k: "x@y.org" if k.endswith("email") else "CC-BY-4.0" if k == "license" else "academic"
              if k == "creator_sector" else "A" for k in ACDD_REQUIRED}
    dive = Dive.model_validate({**res.dive, "metadata": {**uncommented["metadata"], **filled}})
    assert missing_acdd_fields(dive) == []
    res.dive["metadata"] = {"creator_name": "A"}  # a dive that has metadata gets no stub
    assert "# metadata:" not in res.dive_yaml()


def test_init_lines_keep_square_brackets(tmp_path):
    """What init prints is text, not rich markup: a file named ``cast[bold].cnv`` (and any ``[...]`` in a line,
    e.g. a guess explained as ``[elevation]``) is printed as it is."""
    import shutil

    src = Path(__file__).parents[2] / "data" / "real" / "seabird_Hotin_sbe19plus.cnv"
    raw = tmp_path / "d"
    raw.mkdir()
    shutil.copy(src, raw / "cast[bold].cnv")
    r = run_cli("init", str(raw))
    assert r.returncode == 0, r.stderr
    assert "cast[bold].cnv" in r.stdout + r.stderr
