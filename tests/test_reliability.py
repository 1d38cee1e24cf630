"""Malformed-input corpus across every reader + the reliability report (tried / handled / tracebacks / lost).

Cases: ``tests/malformed/make_corpus.py`` (ingest logs; also tested stage-level in test_ingest_malformed.py) and
``tests/malformed/make_corpus_readers.py`` (soundings, point clouds, rasters, dive.yaml, pipeline.yaml,
vehicle.yaml, corrupt upstream products). Each case runs the way ``hadal stage`` runs it (minus Prefect) against
a fresh store: a one-line HadalError of the expected class and message with the store byte-for-byte unchanged,
or data that flag the defect. A sample also goes through the real ``hadal`` command line.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE / "malformed"))
import make_corpus  # noqa: E402
import make_corpus_readers  # noqa: E402
from reliability_report import (  # noqa: E402
    Outcome,
    all_items,
    intact_versions,
    lost_products,
    run_item,
    snapshot,
    table,
)

FAMILIES = ("mcap", "csv", "cnv", "soundings", "point_cloud", "raster", "dive_yaml", "pipeline_yaml",
            "vehicle_yaml", "upstream")
_OUTCOMES: dict[str, Outcome] = {}  # each case runs once per session; the report reuses the outcomes


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("reliability")


@pytest.fixture(scope="module")
def items(work):
    return {it.name: it for it in all_items(work / "corpus")}


def _outcome(item, work: Path) -> Outcome:
    if item.name not in _OUTCOMES:
        _OUTCOMES[item.name] = run_item(item, work / "stores" / item.name)
    return _OUTCOMES[item.name]


def test_corpus_covers_every_reader():
    names = [c.name for c in make_corpus.CASES] + [c.name for c in make_corpus_readers.CASES]
    assert len(names) == len(set(names)) and len(names) >= 50
    per = Counter(c.reader for c in make_corpus_readers.CASES)
    for fam in FAMILIES[3:]:
        assert per[fam] >= 5, (fam, per)
    assert sum(c.error is None for c in make_corpus_readers.CASES) >= 10  # flaggable, not fatal, cases too


@pytest.mark.parametrize("name", [c.name for c in make_corpus_readers.CASES])
def test_malformed_reader_input(items, work, name):
    o = _outcome(items[name], work)
    assert o.traceback is None, o.traceback
    assert o.handled, o.detail
    assert not o.lost, o.lost


def test_reliability_report(items, work, capsys):
    """Every case of both corpora: handled == tried, 0 tracebacks, 0 products lost."""
    outcomes = [_outcome(it, work) for it in items.values()]
    text, tot = table(outcomes)
    with capsys.disabled():
        print("\n" + text)
    assert {o.reader for o in outcomes} == set(FAMILIES)
    assert tot["tried"] == len(make_corpus.CASES) + len(make_corpus_readers.CASES) >= 50
    assert tot["tracebacks"] == 0, [o.detail for o in outcomes if o.traceback]
    assert tot["lost"] == 0, [(o.name, o.lost) for o in outcomes if o.lost]
    assert tot["handled"] == tot["tried"], [(o.name, o.detail) for o in outcomes if not o.handled]


def test_report_counts_tracebacks_and_lost_products(tmp_path):
    """The report's counters are not vacuous: a raw exception and a damaged version are counted."""
    from reliability_report import Item

    def boom(store: Path):
        raise KeyError("raw")

    o = run_item(Item("boom", "x", tmp_path, boom, "InputError", "", None), tmp_path / "s1")
    assert o.traceback and not o.handled

    from hadal.store import ProductStore

    def damage(store: Path):
        st = ProductStore(store)
        with st.publish("d1", "p", parameters={}) as draft:
            (draft.path / "a.txt").write_text("a")
        (draft.result.path / "a.txt").write_text("changed")
        from hadal.errors import InputError
        raise InputError("bad input after damaging a product")

    def seed(store: Path):
        st = ProductStore(store)
        with st.publish("d1", "p", parameters={}) as draft:
            (draft.path / "a.txt").write_text("a")
        st.root.joinpath("d1", "p", ".staging-123-x").mkdir()

    o = run_item(Item("damage", "x", tmp_path, damage, "InputError", "bad input", None, seed), tmp_path / "s2")
    assert not o.handled and "store changed" in o.detail
    assert any(x.startswith("d1/p/v00") for x in o.lost) and "d1/p/.staging-123-x" in o.lost
    before = intact_versions(tmp_path / "s2")
    assert lost_products(before, before, tmp_path / "s2") == ["d1/p/.staging-123-x"]


# ---------------------------------------------------------------------------------------------- real CLI
def _hadal(*args: str) -> subprocess.CompletedProcess:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(HERE.parent / "src"), str(HERE.parent)]),
           "HADAL_PROGRESS": "0", "COLUMNS": "80"}
    return subprocess.run([sys.executable, "-m", "hadal.cli", *args], capture_output=True, text=True,
                          cwd=HERE.parent, env=env, timeout=300)


def _assert_one_line_error(res: subprocess.CompletedProcess, pattern: str) -> str:
    import re

    assert res.returncode == 2, (res.stdout, res.stderr[-3000:])
    assert "Traceback" not in res.stderr, res.stderr[-3000:]
    lines = [ln for ln in res.stderr.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1, res.stderr[-3000:]
    assert re.search(pattern, lines[0]), lines[0]
    return lines[0]


@pytest.mark.parametrize("name,command", [
    ("dive_id_traversal", ("stage", "ingest")),
    ("cfg_out_of_range", ("run",)),
])
def test_cli_rejects_bad_configuration_in_one_line(items, tmp_path, name, command):
    """Cases the CLI rejects before starting Prefect: one line, exit 2, store untouched (not even created)."""
    item = items[name]
    store = tmp_path / "store"
    _assert_one_line_error(_hadal(*command, str(item.directory), "--store", str(store)), item.match)
    assert not store.exists()


@pytest.mark.slow
@pytest.mark.prefect
def test_cli_error_inside_the_flow_is_one_line_and_leaves_products_alone(items, tmp_path):
    """``hadal stage landing`` (Prefect flow) on a corrupt laser grid: the stage fails inside ``store.publish``;
    the user sees one ``error:`` line and no traceback, and the product tree is unchanged (Prefect's own result
    records under ``<store>/.prefect-results`` are orchestration state, not products)."""
    item = items["up_laser_truncated"]
    store = tmp_path / "store"
    item.prepare(store)
    before = {k: v for k, v in snapshot(store).items() if not k.startswith(".prefect-results")}
    res = _hadal("stage", "landing", str(item.directory), "--store", str(store))
    line = _assert_one_line_error(res, item.match)
    assert "submap_01.nc" in line
    after = {k: v for k, v in snapshot(store).items() if not k.startswith(".prefect-results")}
    assert after == before
    shutil.rmtree(store)
