"""Fault injection on real stage runs: kill -9 mid-publish, concurrent runs on one dive, disk full while writing.

The store-level versions of these tests are in ``tests/unit/core/test_store.py``; here a real stage (``ingest`` of the small
sample dive, in a subprocess: ``tests/malformed/stage_worker.py``) is interrupted at chosen points of the publish.
"""

from __future__ import annotations

import errno
import fcntl
import os
import shutil
import signal
import subprocess
import sys
import time
import warnings
from pathlib import Path

import pytest

from hadal.errors import StoreError
from hadal.pipeline import make_context, run_stage
from hadal.store import ProductStore

HERE = Path(__file__).resolve().parents[1]
WORKER = HERE / "malformed" / "stage_worker.py"
sys.path.insert(0, str(HERE))
sys.path.insert(0, str(HERE / "malformed"))
from reliability_report import snapshot  # noqa: E402
from tiny_dive import write_dive  # noqa: E402


def _env() -> dict[str, str]:
    src = str(HERE.parent / "src")
    return {**os.environ, "PYTHONPATH": os.pathsep.join([src, str(HERE.parent)]), "HADAL_PROGRESS": "0"}


def _worker(raw: Path, store: Path, *extra: str, stage: str = "ingest") -> subprocess.Popen:
    return subprocess.Popen([sys.executable, str(WORKER), stage, str(raw), str(store), *extra],
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=_env())


def _wait_for(path: Path, proc: subprocess.Popen, timeout: float = 120.0) -> None:
    deadline = time.monotonic() + timeout
    while not path.exists():
        if proc.poll() is not None:
            raise AssertionError(f"worker exited ({proc.returncode}) before the pause: {proc.stderr.read()[-2000:]}")
        if time.monotonic() > deadline:
            proc.kill()
            raise AssertionError(f"worker never reached the pause point ({path.name})")
        time.sleep(0.01)


def _run(raw: Path, store: Path, stage: str = "ingest"):
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return run_stage(stage, make_context(raw, store))


def _all_intact(st: ProductStore, dive: str, product: str) -> list[str]:
    labels = []
    for pv in st.versions(dive, product):
        assert st.verify(pv) == [], (pv.label, st.verify(pv))
        assert pv.manifest()["version"] == pv.label
        labels.append(pv.label)
    return labels


@pytest.fixture(scope="module")
def seeded_store(small_dive, tmp_path_factory) -> Path:
    """A store holding one intact ``sensors`` version (v001) of the small dive."""
    store = tmp_path_factory.mktemp("seeded") / "store"
    _run(small_dive, store)
    return store


@pytest.fixture
def store(seeded_store, tmp_path) -> Path:
    dst = tmp_path / "store"
    shutil.copytree(seeded_store, dst)
    return dst


@pytest.mark.integration  # 9-17 s each here (a worker process per case): the integration tier (signals)
@pytest.mark.parametrize("point", ["write", "rename"])
def test_kill9_mid_publish_leaves_no_partial_version(small_dive, store, tmp_path, point):
    """SIGKILL while a real stage publishes (files half-way / inside the version lock): readers see only v001,
    the staging leftover is cleaned, the lock is free, and the next run publishes an intact v002."""
    dive_id = make_context(small_dive, store).dive_id
    st = ProductStore(store)
    marker = tmp_path / "paused"
    proc = _worker(small_dive, store, "--pause", point, "--marker", str(marker))
    try:
        _wait_for(marker, proc)
        staging = list((store / dive_id / "sensors").glob(".staging-*"))
        assert len(staging) == 1 and any(staging[0].iterdir())  # really mid-publish: files in staging
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(timeout=30)
    assert proc.returncode == -signal.SIGKILL

    assert [pv.label for pv in st.versions(dive_id, "sensors")] == ["v001"]  # no partial version visible
    assert _all_intact(st, dive_id, "sensors") == ["v001"]
    with open(store / dive_id / "sensors" / ".lock", "a+") as fh:  # the killed holder released the lock
        fcntl.flock(fh, fcntl.LOCK_EX | fcntl.LOCK_NB)
        fcntl.flock(fh, fcntl.LOCK_UN)
    assert len(st.clean_staging(older_than_s=0)) == 1
    assert not list(store.rglob(".staging-*"))

    out = _run(small_dive, store)
    assert out["sensors"].label == "v002"
    assert _all_intact(st, dive_id, "sensors") == ["v001", "v002"]


@pytest.mark.integration
def test_two_concurrent_stage_runs_get_two_intact_versions(small_dive, store, tmp_path):
    """Two ``ingest`` runs of the same dive, released together at the commit: v002 and v003, both intact."""
    dive_id = make_context(small_dive, store).dive_id
    go = tmp_path / "go"
    markers = [tmp_path / "ready1", tmp_path / "ready2"]
    procs = [_worker(small_dive, store, "--pause", "commit", "--marker", str(m), "--go", str(go)) for m in markers]
    try:
        for m, p in zip(markers, procs, strict=True):
            _wait_for(m, p)
        assert len(list((store / dive_id / "sensors").glob(".staging-*"))) == 2
        go.write_text("go")
        outs = [p.communicate(timeout=120) for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
    assert [p.returncode for p in procs] == [0, 0], [o[1][-2000:] for o in outs]
    assert sorted(o[0].split()[-1] for o in outs) == ["v002", "v003"]
    st = ProductStore(store)
    assert _all_intact(st, dive_id, "sensors") == ["v001", "v002", "v003"]
    assert not list(store.rglob(".staging-*"))


# ---------------------------------------------------------------------------------------------- disk full
@pytest.fixture(scope="module")
def tiny_dive(tmp_path_factory) -> Path:
    return write_dive(tmp_path_factory.mktemp("tiny") / "dive", 20.0)


def _enospc(*_a, **_k):
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))


def _half_then_enospc(path, *_a, **_k):
    Path(path).write_bytes(b"PAR1" + b"\0" * 4096)  # a partial file, then the disk is full
    raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC), str(path))


def _pyarrow_style_enospc(*_a, **_k):  # pyarrow/HDF5 put the OS message in the text, errno unset
    raise OSError("IOError: [Errno 28] No space left on device. Detail: [errno 28] No space left on device")


@pytest.mark.parametrize("where", ["product_file", "library_message", "manifest_fsync", "staging_mkdir", "new_store"])
def test_disk_full_gives_one_line_store_error_and_changes_nothing(tiny_dive, tmp_path, monkeypatch, where):
    store = tmp_path / "store"
    if where != "new_store":
        _run(tiny_dive, store)  # one intact version already there
    before = snapshot(store)
    import hadal.products

    if where == "product_file":
        monkeypatch.setattr(hadal.products, "write_parquet", lambda df, path, **kw: _half_then_enospc(path))
    elif where == "library_message":
        monkeypatch.setattr(hadal.products, "write_parquet", _pyarrow_style_enospc)
    elif where == "manifest_fsync":
        monkeypatch.setattr(os, "fsync", _enospc)
    else:  # no room for the staging directory (or, new_store, for the store itself)
        monkeypatch.setattr(os, "mkdir", _enospc)
    with pytest.raises(StoreError) as ei:
        _run(tiny_dive, store)
    monkeypatch.undo()
    msg = str(ei.value)
    assert "No space left on device" in msg and "nothing was published" in msg, msg
    assert "\n" not in msg and len(msg) < 400
    assert snapshot(store) == before  # no partial version, no staging leftover, no new directories
    out = _run(tiny_dive, store)  # space is back: the next run works
    assert ProductStore(store).verify(out["sensors"]) == []
