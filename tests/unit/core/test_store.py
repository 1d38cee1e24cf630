"""Product store: immutable versions, atomic publish, provenance, name validation, concurrency."""

from __future__ import annotations

import json
import multiprocessing as mp
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from hadal.errors import StoreError
from hadal.store import ProductStore, sha256_file, validate_name


def _publish(store: ProductStore, text: str, product: str = "ctd", **kw):
    with store.publish("dive-1", product, **kw) as draft:
        (draft.path / "data.txt").write_text(text)
    return draft.result


def test_versions_are_numbered_and_immutable(tmp_path):
    store = ProductStore(tmp_path)
    v1 = _publish(store, "one", parameters={"bin_dbar": 10})
    v2 = _publish(store, "two", parameters={"bin_dbar": 5})
    assert (v1.label, v2.label) == ("v001", "v002")
    assert [v.label for v in store.versions("dive-1", "ctd")] == ["v001", "v002"]
    assert store.latest("dive-1", "ctd") == v2
    assert store.get("dive-1", "ctd", "v001") == v1 == store.get("dive-1", "ctd", 1)
    assert (v1.path / "data.txt").read_text() == "one"  # older version untouched
    m = v2.manifest()
    assert m["version"] == "v002" and m["parameters"] == {"bin_dbar": 5}
    assert m["files"] == [{"name": "data.txt", "bytes": 3, "mtime_ns": (v2.path / "data.txt").stat().st_mtime_ns,
                           "sha256": sha256_file(v2.path / "data.txt")}]
    assert m["code_version"].startswith("0.")
    assert store.verify(v2) == []


def test_manifest_records_inputs_and_upstream(tmp_path):
    store = ProductStore(tmp_path / "store")
    raw = tmp_path / "raw.csv"
    raw.write_text("a,b\n1,2\n")
    up = _publish(store, "sensors", product="sensors", inputs=[raw])
    down = _publish(store, "ctd", upstream=[up])
    m_up, m_down = up.manifest(), down.manifest()
    assert m_up["inputs"][0]["sha256"] == sha256_file(raw)
    assert m_up["inputs"][0]["path"] == str(raw.resolve())
    assert m_down["upstream"] == [{"product": "sensors", "version": "v001", "manifest_sha256": sha256_file(up.manifest_path)}]


def test_failed_publish_leaves_nothing(tmp_path):
    store = ProductStore(tmp_path)
    _publish(store, "good")
    with pytest.raises(RuntimeError):
        with store.publish("dive-1", "ctd") as draft:
            (draft.path / "half.txt").write_text("half written")
            raise RuntimeError("boom")
    assert [v.label for v in store.versions("dive-1", "ctd")] == ["v001"]
    assert not list((tmp_path / "dive-1" / "ctd").glob(".staging-*"))


def test_empty_version_refused(tmp_path):
    store = ProductStore(tmp_path)
    with pytest.raises(StoreError, match="empty"):
        with store.publish("dive-1", "ctd"):
            pass
    assert store.versions("dive-1", "ctd") == []


def test_missing_input_refused(tmp_path):
    store = ProductStore(tmp_path)
    with pytest.raises(StoreError, match="does not exist"):
        _publish(store, "x", inputs=[tmp_path / "nope.bin"])
    assert store.versions("dive-1", "ctd") == []


@pytest.mark.parametrize("bad", ["../etc", "..", "a/b", "", ".hidden", "-x", "a" * 65, "dive 1", "x\x00y", "a..b",
                                 "catalog.json", "Dive.JSON", "stac-item.json", ".cache", "d.lock"])
def test_names_are_validated(tmp_path, bad):
    with pytest.raises(StoreError):
        validate_name(bad)
    store = ProductStore(tmp_path)
    with pytest.raises(StoreError):
        with store.publish(bad, "ctd"):
            pass
    with pytest.raises(StoreError):
        store.versions("dive-1", bad)
    assert list(tmp_path.iterdir()) == []


def test_get_errors_are_clear(tmp_path):
    store = ProductStore(tmp_path)
    with pytest.raises(StoreError, match="no published version"):
        store.latest("dive-1", "ctd")
    _publish(store, "x")
    with pytest.raises(StoreError, match="no version"):
        store.get("dive-1", "ctd", "v009")
    with pytest.raises(StoreError, match="invalid version"):
        store.get("dive-1", "ctd", "newest")


def test_staging_dirs_are_invisible_and_cleaned(tmp_path):
    store = ProductStore(tmp_path)
    _publish(store, "x")
    stale = tmp_path / "dive-1" / "ctd" / ".staging-999-deadbeef"
    stale.mkdir()
    (stale / "partial.bin").write_bytes(b"\0" * 10)
    (tmp_path / "dive-1" / "ctd" / "v007").mkdir()  # a version dir without manifest is not a version
    assert [v.label for v in store.versions("dive-1", "ctd")] == ["v001"]
    old = time.time() - 7200
    os.utime(stale, (old, old))
    assert store.clean_staging(older_than_s=3600) == [stale]
    assert not stale.exists()


def _worker(root: str, n: int, q) -> None:
    store = ProductStore(root)
    labels = []
    for i in range(n):
        with store.publish("dive-1", "ctd", parameters={"pid": os.getpid(), "i": i}) as d:
            (d.path / "data.txt").write_text(f"{os.getpid()}-{i}")
        labels.append(d.result.label)
    q.put(labels)


def test_concurrent_publishers_get_distinct_intact_versions(tmp_path):
    ctx = mp.get_context("fork")
    q = ctx.Queue()
    procs = [ctx.Process(target=_worker, args=(str(tmp_path), 8, q)) for _ in range(3)]
    for p in procs:
        p.start()
    labels = [label for _ in procs for label in q.get(timeout=60)]
    for p in procs:
        p.join(timeout=60)
    assert len(labels) == len(set(labels)) == 24
    versions = ProductStore(tmp_path).versions("dive-1", "ctd")
    assert [v.version for v in versions] == list(range(1, 25))
    for v in versions:
        m = v.manifest()
        assert m["version"] == v.label
        assert (v.path / "data.txt").read_text() == f"{m['parameters']['pid']}-{m['parameters']['i']}"
        assert ProductStore(tmp_path).verify(v) == []


def test_kill_during_publish_leaves_no_partial_version(tmp_path):
    """kill -9 while a large version is being written: no partial version is visible; the next publish works."""
    script = textwrap.dedent(
        f"""
        import sys, time
        from hadal.store import ProductStore
        store = ProductStore({str(tmp_path)!r})
        with store.publish("dive-1", "ctd") as d:
            with open(d.path / "big.bin", "wb") as fh:
                for _ in range(10_000):
                    fh.write(b"x" * 65536)
                    fh.flush()
                    print("writing", flush=True)
                    time.sleep(0.001)
        """
    )
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(__file__).resolve().parents[3] / "src"), *sys.path])}
    proc = subprocess.Popen([sys.executable, "-c", script], stdout=subprocess.PIPE, env=env)
    assert proc.stdout is not None
    proc.stdout.readline()  # it has started writing
    time.sleep(0.2)
    proc.send_signal(signal.SIGKILL)
    proc.wait(timeout=30)
    store = ProductStore(tmp_path)
    assert store.versions("dive-1", "ctd") == []
    assert list((tmp_path / "dive-1" / "ctd").glob(".staging-*"))  # debris stays hidden
    v = _publish(store, "after")
    assert v.label == "v001" and store.verify(v) == []


def test_manifest_is_valid_json_with_created_time(tmp_path):
    v = _publish(ProductStore(tmp_path), "x")
    m = json.loads(v.manifest_path.read_text())
    assert m["created_utc"].endswith("+00:00")
    assert m["dive"] == "dive-1" and m["product"] == "ctd"


def test_tampered_upstream_is_refused(tmp_path):
    """A product file changed after publishing (same size, new content or new mtime) is never used as is."""
    import os

    from hadal.stages import StageContext

    store = ProductStore(tmp_path)
    with store.publish("d1", "sensors") as draft:
        (draft.path / "sensors.parquet").write_bytes(b"abcdef")
    pv = draft.result
    store.check_intact(pv)  # fast path: size + mtime as recorded
    f = pv.path / "sensors.parquet"
    st = f.stat()
    f.write_bytes(b"abcdeX")  # same size, other content
    os.utime(f, ns=(st.st_atime_ns, st.st_mtime_ns + 10**9))
    with pytest.raises(StoreError, match="modified after it was published"):
        ProductStore(tmp_path).check_intact(pv)
    f.write_bytes(b"abcdef")  # restored content, new mtime: re-hashed and accepted
    ProductStore(tmp_path).check_intact(pv)
    (pv.path / "sensors.parquet").unlink()
    ctx = StageContext(dive=None, raw_dir=tmp_path, store=ProductStore(tmp_path), config=None)  # type: ignore[arg-type]
    ctx.pins["sensors"] = pv
    with pytest.raises(StoreError, match="missing"):
        ctx.upstream("sensors")


def test_a_run_reads_the_versions_it_pinned(tmp_path):
    """Two runs of one dive: the second run's newer upstream version does not leak into the first run."""
    from hadal.stages import StageContext

    store = ProductStore(tmp_path)
    with store.publish("d1", "dtm") as draft:
        (draft.path / "dtm.nc").write_bytes(b"run A")
    mine = draft.result
    ctx = StageContext(dive=None, raw_dir=tmp_path, store=store, config=None)  # type: ignore[arg-type]
    ctx.pins["dtm"] = mine
    with store.publish("d1", "dtm") as draft:  # a concurrent run publishes v002
        (draft.path / "dtm.nc").write_bytes(b"run B")
    assert store.latest("d1", "dtm").label == "v002"
    assert ctx.upstream("dtm") == mine and ctx.upstream("dtm").label == "v001"


def test_file_hash_cache_is_the_sha256_and_sees_every_change(tmp_path, monkeypatch):
    """ProductStore.file_sha256 equals hashlib's SHA-256 (oracle); an unchanged file is not re-read, by this
    process nor by a new one (persisted in the store); a same-size rewrite with its old mtime restored is seen
    (inode/ctime)."""
    import hashlib

    import hadal.store as hs

    store = tmp_path / "store"
    store.mkdir()
    raw = tmp_path / "log.bin"
    raw.write_bytes(b"abc" * 1000)
    st = ProductStore(store)
    assert st.file_sha256(raw) == hashlib.sha256(b"abc" * 1000).hexdigest()
    reads = []
    real = hs.sha256_file
    monkeypatch.setattr(hs, "sha256_file", lambda p: reads.append(p) or real(p))
    hs._PROCESS_HASHES.clear()  # a fresh process: only the store's cache file remains
    assert ProductStore(store).file_sha256(raw) == hashlib.sha256(b"abc" * 1000).hexdigest()
    assert reads == []  # served from <store>/.cache/file-sha256.json
    old = raw.stat()
    time.sleep(0.01)
    raw.write_bytes(b"abd" * 1000)  # same size...
    os.utime(raw, ns=(old.st_atime_ns, old.st_mtime_ns))  # ...and the old mtime
    assert ProductStore(store).file_sha256(raw) == hashlib.sha256(b"abd" * 1000).hexdigest()
    assert reads  # re-hashed


def test_file_hashes_of_a_cold_run_reach_the_store_cache(tmp_path, monkeypatch):
    """A cold run hashes its raw inputs before the first product creates the store: once the store exists, the
    next lookup in the same process writes them to its cache, so the first re-run (a new process) reads nothing."""
    import hashlib

    import hadal.store as hs

    hs._PROCESS_HASHES.clear()
    raw = tmp_path / "log.bin"
    raw.write_bytes(b"xyz" * 500)
    st = ProductStore(tmp_path / "store")  # not created yet
    assert st.file_sha256(raw) == hashlib.sha256(b"xyz" * 500).hexdigest()
    assert not (tmp_path / "store").exists()  # a store is never created just for its cache
    with st.publish("d1", "sensors") as draft:
        (draft.path / "a.txt").write_text("x")
    ProductStore(tmp_path / "store").file_sha256(raw)  # later in the same run (another stage's context)
    reads = []
    real = hs.sha256_file
    monkeypatch.setattr(hs, "sha256_file", lambda p: reads.append(p) or real(p))
    hs._PROCESS_HASHES.clear()  # the re-run: a new process
    assert ProductStore(tmp_path / "store").file_sha256(raw) == hashlib.sha256(b"xyz" * 500).hexdigest()
    assert reads == []


def test_manifest_records_the_stage_run_time(tmp_path):
    from hadal.store import STAGE_RUN

    st = ProductStore(tmp_path / "s")
    token = STAGE_RUN.set({"stage": "grid", "started_utc": "2026-01-01T00:00:00+00:00", "t0": time.monotonic() - 2})
    try:
        with st.publish("d1", "dtm") as draft:
            (draft.path / "a.txt").write_text("x")
    finally:
        STAGE_RUN.reset(token)
    run = draft.result.manifest()["stage_run"]
    assert run["stage"] == "grid" and 2.0 <= run["seconds"] < 60 and "t0" not in run
    with st.publish("d1", "dtm") as draft:  # outside a stage run: no record
        (draft.path / "a.txt").write_text("y")
    assert "stage_run" not in draft.result.manifest()


def test_manifest_input_hash_is_read_not_taken_from_the_cache(tmp_path, monkeypatch):
    """A hash-cache record with the input's identity but a wrong SHA-256 never reaches a manifest (oracle:
    hashlib over the file's bytes); the record is corrected. More cases: tests/robustness/test_security.py."""
    import hashlib
    import json

    import hadal.store as hs

    raw = tmp_path / "in.bin"
    raw.write_bytes(b"provenance" * 1000)
    store = ProductStore(tmp_path / "s")
    _publish(store, "x", inputs=[raw])
    cache = store.root / hs.HASH_CACHE
    data = json.loads(cache.read_text())
    data[str(raw.resolve())]["sha256"] = "1" * 64
    cache.write_text(json.dumps(data))
    monkeypatch.setattr(hs, "_PROCESS_HASHES", {})
    v = _publish(ProductStore(store.root), "x", inputs=[raw])
    truth = hashlib.sha256(raw.read_bytes()).hexdigest()
    assert v.manifest()["inputs"][0]["sha256"] == truth
    assert json.loads(cache.read_text())[str(raw.resolve())]["sha256"] == truth


def test_read_refuses_a_manifest_name_outside_the_version(tmp_path):
    import json

    store = ProductStore(tmp_path)
    v = _publish(store, "x")
    m = v.manifest()
    m["files"][0]["name"] = "../../../../etc/hostname"
    v.manifest_path.write_text(json.dumps(m))
    with pytest.raises(StoreError, match="outside the version"):
        store.check_intact(v)
