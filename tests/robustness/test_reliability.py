"""Malformed-input corpus across every reader + the reliability report (tried / handled / tracebacks / lost).

Cases: ``tests/malformed/make_corpus.py`` (ingest logs; also tested stage-level in test_ingest_malformed.py) and
``tests/malformed/make_corpus_readers.py`` (soundings, point clouds, rasters, dive.yaml, pipeline.yaml,
vehicle.yaml, corrupt upstream products). Each case runs the way ``hadal stage`` runs it (minus Prefect) against
a fresh store: a one-line HadalError of the expected class and message with the store byte-for-byte unchanged,
or data that flag the defect. A sample also goes through the real ``hadal`` command line. Issue 45's classes:
``security`` (``tests/malformed/security_cases.py``) and ``process`` (``tests/malformed/process_cases.py``: the
``hadal`` command and stage processes under Prefect API faults, a closed stdout, kill -9 mid-publish, concurrent
runs).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
from collections import Counter
from pathlib import Path

import pytest

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE / "malformed"))
import make_corpus  # noqa: E402
import make_corpus_readers  # noqa: E402
import process_cases  # noqa: E402
import security_cases  # noqa: E402
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
#: case classes beyond the reader families (tests/malformed/security_cases.py, tests/malformed/process_cases.py)
CLASSES = (*FAMILIES, "security", "process")
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


@pytest.mark.parametrize("name", [c.name for c in security_cases.CASES])
def test_security_case(items, work, name):
    """Issue 45's security class: a clean one-line error with the store unchanged, or a result the case's oracle
    accepts (the true SHA-256 in a manifest, no planted bytes in report.html)."""
    o = _outcome(items[name], work)
    assert o.traceback is None, o.traceback
    assert o.handled, o.detail
    assert not o.lost, o.lost


@pytest.mark.parametrize("name", [c.name for c in process_cases.CASES])
def test_process_case(items, work, name):
    """Issue 45's process class: the ``hadal`` command under Prefect API faults ends in one ``error:`` line (exit
    2, no traceback, store unchanged) or completes with the store verified by the case's oracle; kill -9 mid-publish
    and concurrent runs leave only intact versions; no process outlives its case."""
    o = _outcome(items[name], work)
    assert o.traceback is None, o.traceback
    assert o.handled, o.detail
    assert not o.lost, o.lost
    assert not o.orphans, o.orphans


def test_reliability_report(items, work, capsys):
    """Every case of both corpora: handled == tried, 0 tracebacks, 0 products lost."""
    outcomes = [_outcome(it, work) for it in items.values()]
    text, tot = table(outcomes)
    with capsys.disabled():
        print("\n" + text)
    assert {o.reader for o in outcomes} == set(CLASSES)
    assert tot["tried"] == (len(make_corpus.CASES) + len(make_corpus_readers.CASES) + len(security_cases.CASES)
                            + len(process_cases.CASES)) >= 50
    assert tot["tracebacks"] == 0, [o.detail for o in outcomes if o.traceback]
    assert tot["lost"] == 0, [(o.name, o.lost) for o in outcomes if o.lost]
    assert tot["handled"] == tot["tried"], [(o.name, o.detail) for o in outcomes if not o.handled]
    for bad in ("silent-wrong", "wrong error", "hang", "over-memory", "orphan"):
        assert tot[bad] == 0, (bad, [(o.name, o.detail) for o in outcomes if o.status not in ("clean_error",
                                                                                             "flagged")])


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


def test_report_counts_hangs_memory_orphans_and_silent_wrong(tmp_path):
    """The other bad columns are not vacuous either: a case that hangs, one that eats memory, one that leaves a
    child process behind and one that returns a wrong result are each counted in their column."""
    import time

    import numpy as np
    from reliability_report import Item

    def hang(store: Path):
        time.sleep(30)

    def hog(store: Path):
        return np.ones(int(3 * 2**30 // 8))  # 3 GiB under a 1 GiB cap

    procs = []

    def orphan(store: Path):
        procs.append(subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"]))
        from hadal.errors import InputError
        raise InputError("bad input")

    def wrong(store: Path):
        return {"result": 1}

    cases = {"hang": (hang, "InputError", None), "hog": (hog, "InputError", None),
             "orphan": (orphan, "InputError", None), "wrong": (wrong, None, lambda res: res["result"] == 2),
             "due": (wrong, "InputError", None)}
    out = {}
    for name, (fn, err, check) in cases.items():
        out[name] = run_item(Item(name, "x", tmp_path, fn, err, "bad input", check), tmp_path / name,
                             timeout_s=1.0, memory_bytes=1 << 30)
    try:
        assert out["hang"].status == "hang" and not out["hang"].handled
        assert out["hog"].status == "over_memory" and not out["hog"].handled
        assert out["orphan"].orphans == [procs[0].pid] and not out["orphan"].handled
        assert out["wrong"].status == "silent_wrong" and out["due"].status == "silent_wrong"
        text, tot = table(list(out.values()))
        assert (tot["hang"], tot["over-memory"], tot["orphan"], tot["silent-wrong"], tot["clean error"]) == \
            (1, 1, 1, 2, 1)
        assert "silent-wrong" in text and "orphan" in text
    finally:
        for pr in procs:
            pr.kill()
            pr.wait()


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


@pytest.mark.integration  # slow (> 9 s here): the integration tier (issue 20: make test <= 5 min)
@pytest.mark.slow
@pytest.mark.prefect
def test_cli_error_inside_the_flow_is_one_line_and_leaves_products_alone(items, tmp_path):
    """``hadal stage landing`` (Prefect flow) on a corrupt laser grid: the stage fails inside ``store.publish``;
    the user sees one ``error:`` line and no traceback, and every product is unchanged and none is added but the
    refreshed report that lists the failure (store-level state is not product data: Prefect's result records under
    ``.prefect-results``, the hash cache ``.cache``, the STAC ``catalog.json``/item and the dive's ``dive.json``)."""

    def products_only(tree: dict[str, str]) -> dict[str, str]:
        def product_data(k: str) -> bool:
            parts = k.split("/")
            if parts[0] in (".prefect-results", ".cache", "catalog.json"):
                return False
            return len(parts) < 2 or parts[1] not in ("dive.json", "report", "stac-item.json")
        return {k: v for k, v in tree.items() if product_data(k)}

    item = items["up_laser_truncated"]
    store = tmp_path / "store"
    item.prepare(store)
    before = products_only(snapshot(store))
    res = _hadal("stage", "landing", str(item.directory), "--store", str(store))
    line = _assert_one_line_error(res, item.match)
    assert "submap_01.nc" in line
    assert products_only(snapshot(store)) == before
    assert not list(store.glob("*/landing"))  # no landing product, not even an empty one
    shutil.rmtree(store)


def test_process_class_counts_an_orphan_that_left_the_process_tree(tmp_path):
    """A process a case started that outlives it after its parent exited (reparented away from this process, so
    not among its children) is found by the case tag, counted as an orphan, and killed."""
    import time

    from reliability_report import Item

    def run(store: Path):
        code = ("import subprocess, sys; subprocess.Popen([sys.executable, '-c', 'import time; time.sleep(60)'], "
                "start_new_session=True)")
        subprocess.run([sys.executable, "-c", code], env=process_cases.env(), check=True)
        time.sleep(0.5)  # the grandchild has started and its parent is gone
        from hadal.errors import InputError
        raise InputError("bad input")

    o = run_item(Item("stray", "process", tmp_path, run, "InputError", "bad input", None,
                      leftover=process_cases.leftover), tmp_path / "s")
    assert len(o.orphans) == 1 and not o.handled, o
    assert process_cases.leftover() == []  # killed when counted
