"""Security of the store and of what users supply (issue 45): provenance that a poisoned hash cache cannot forge,
manifests checked on read (no path outside its version, no symbolic link, no in-place edit), one rule for names,
an atomic dive-id claim, bounded YAML/JSON parsing, the report embedding only verified files, AlignCTD's edge.

Oracles: :mod:`hashlib` for content hashes, the bytes written by the test for what a file holds, the caps
declared in :mod:`hadal.yamlfile` for what must be refused, plain NumPy slicing for AlignCTD.
"""

from __future__ import annotations

import base64
import hashlib
import json
import multiprocessing
import os
import sys
import threading
import time
import warnings
from pathlib import Path

import numpy as np
import pytest

import hadal.store as hs
from hadal.errors import ConfigError, InputError, StoreError
from hadal.names import check_component, check_relative_path
from hadal.store import ProductStore

HERE = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(HERE / "malformed"))
from tiny_dive import write_dive  # noqa: E402


def _one_line(exc: BaseException) -> str:
    msg = str(exc)
    assert msg and "\n" not in msg, msg
    return msg


def _publish(store: ProductStore, dive: str = "d1", product: str = "sensors", files: dict | None = None, **kw):
    with store.publish(dive, product, **kw) as draft:
        for name, data in (files or {"data.bin": b"0123456789"}).items():
            p = draft.path / name
            p.parent.mkdir(parents=True, exist_ok=True)
            p.write_bytes(data)
    return draft.result


# ------------------------------------------------------------------------------------ 1. provenance
def test_poisoned_hash_cache_never_reaches_a_manifest(tmp_path, monkeypatch):
    """A cache record with the input's exact identity (device, inode, size, mtime, ctime) but a wrong SHA-256:
    the manifest records hashlib's SHA-256 of the file, and the lying record is replaced by the truth."""
    raw = tmp_path / "raw.bin"
    raw.write_bytes(os.urandom(300_000))
    truth = hashlib.sha256(raw.read_bytes()).hexdigest()
    store = ProductStore(tmp_path / "store")
    _publish(store, inputs=[raw])  # cold: hashes the file, writes the cache
    cache = store.root / hs.HASH_CACHE
    data = json.loads(cache.read_text())
    key = str(raw.resolve())
    assert data[key]["sha256"] == truth
    data[key]["sha256"] = "0" * 64  # poison: same identity, wrong hash
    cache.write_text(json.dumps(data))
    monkeypatch.setattr(hs, "_PROCESS_HASHES", {})  # a new process: nothing hashed yet
    fresh = ProductStore(store.root)
    # the skip decision may use the cache (documented): it is an optimisation, not provenance
    assert fresh.file_sha256(raw) == "0" * 64
    pv = _publish(fresh, inputs=[raw])
    assert pv.manifest()["inputs"][0]["sha256"] == truth
    assert json.loads(cache.read_text())[key]["sha256"] == truth  # the lie is corrected
    monkeypatch.setattr(hs, "_PROCESS_HASHES", {})
    assert ProductStore(store.root).file_sha256(raw) == truth


def test_poisoned_cache_on_a_real_stage_run(tmp_path, monkeypatch):
    """``ingest`` of a tiny dive after its inputs' cache records were poisoned: every input SHA-256 in the
    sensors manifest is hashlib's."""
    from hadal.pipeline import make_context, run_stage

    raw = write_dive(tmp_path / "raw", 20.0, csv=False)
    store = tmp_path / "store"
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_stage("ingest", make_context(raw, store))
    cache = store / hs.HASH_CACHE
    data = json.loads(cache.read_text())
    assert data, "the cold run wrote no hash cache"
    for rec in data.values():
        rec["sha256"] = "f" * 64
    cache.write_text(json.dumps(data))
    monkeypatch.setattr(hs, "_PROCESS_HASHES", {})
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = run_stage("ingest", make_context(raw, store))
    inputs = out["sensors"].manifest()["inputs"]
    assert inputs
    for rec in inputs:
        assert rec["sha256"] == hashlib.sha256(Path(rec["path"]).read_bytes()).hexdigest(), rec["path"]


# ------------------------------------------------------------------------------------ 2. manifests on read
@pytest.mark.parametrize("name", ["../../../etc/passwd", "/etc/passwd", "a/../../x", "", "x\x00y"])
def test_manifest_naming_a_path_outside_its_version_is_refused(tmp_path, name):
    store = ProductStore(tmp_path)
    pv = _publish(store)
    m = pv.manifest()
    m["files"].append({"name": name, "bytes": 1, "sha256": "0" * 64})
    pv.manifest_path.write_text(json.dumps(m))
    with pytest.raises(StoreError) as e:
        store.check_intact(pv)
    _one_line(e.value)
    assert store.verify(pv)  # reported as a problem, never followed
    with pytest.raises(StoreError):
        pv.file(name)


def test_symlinked_product_file_is_refused(tmp_path):
    """A product file replaced by a symbolic link to a file outside the store (with the same content, so only
    the link gives it away): refused on read, by ``file()`` and by the integrity check."""
    store = ProductStore(tmp_path / "store")
    pv = _publish(store)
    outside = tmp_path / "secret.bin"
    outside.write_bytes(b"0123456789")
    f = pv.path / "data.bin"
    f.unlink()
    f.symlink_to(outside)
    for call in (lambda: store.check_intact(pv), lambda: pv.file("data.bin"),
                 lambda: ProductStore(store.root).verified_file(pv, "data.bin")):
        with pytest.raises(StoreError, match="symbolic link"):
            call()
    (pv.path / "extra.bin").symlink_to(outside)  # an unlisted link beside the real files
    f.unlink()
    f.write_bytes(b"0123456789")
    with pytest.raises(StoreError, match="not in its manifest"):
        ProductStore(store.root).check_intact(pv)


def test_in_place_edit_with_size_and_mtime_kept_is_detected(tmp_path):
    """Same size, mtime restored, even in the store object that already verified it once (its memory is keyed
    by ctime too): the stage reading it gets a one-line StoreError."""
    from hadal.stages import StageContext

    store = ProductStore(tmp_path)
    pv = _publish(store, files={"sensors.parquet": b"A" * 4096})
    ctx = StageContext(dive=None, raw_dir=tmp_path, store=store, config=None)  # type: ignore[arg-type]
    ctx.pins["sensors"] = pv
    assert ctx.upstream("sensors") == pv
    f = pv.path / "sensors.parquet"
    st = f.stat()
    time.sleep(0.01)
    with open(f, "r+b") as fh:
        fh.seek(100)
        fh.write(b"B")
    os.utime(f, ns=(st.st_atime_ns, st.st_mtime_ns))
    assert f.stat().st_size == st.st_size and f.stat().st_mtime_ns == st.st_mtime_ns
    with pytest.raises(StoreError, match="modified after it was published") as e:
        ctx.upstream("sensors")
    _one_line(e.value)
    assert store.verify(pv) == ["checksum mismatch sensors.parquet"]


def test_symlinked_product_directory_outside_the_store(tmp_path):
    """Publishing through ``<store>/<dive>/<product>`` linked to a directory outside the store is refused (and
    writes nothing there); a version read through such a link is refused."""
    store = ProductStore(tmp_path / "store")
    _publish(store, product="ctd")
    outside = tmp_path / "outside"
    outside.mkdir()
    (store.root / "d1" / "sensors").symlink_to(outside)
    with pytest.raises(StoreError, match="symbolic link") as e:
        _publish(store, product="sensors")
    _one_line(e.value)
    assert list(outside.iterdir()) == []
    # a version that only exists through the link (made elsewhere, then linked in)
    other = ProductStore(tmp_path / "other")
    pv_other = _publish(other, product="sensors")
    os.rmdir(outside)
    outside.symlink_to(pv_other.path.parent)
    pv = store.latest("d1", "sensors")
    with pytest.raises(StoreError, match="outside the store"):
        store.check_intact(pv)


def test_hostile_manifest_json_is_a_one_line_error(tmp_path):
    store = ProductStore(tmp_path)
    pv = _publish(store)
    pv.manifest_path.write_text("[" * 100_000 + "]" * 100_000)  # RecursionError in plain json
    with pytest.raises(StoreError, match="unreadable manifest") as e:
        store.check_intact(pv)
    _one_line(e.value)


# ------------------------------------------------------------------------------------ 3. names and claims
@pytest.mark.parametrize("bad", ["catalog.json", "CATALOG.JSON", "dive.json", "stac-item.json", "manifest.json",
                                 ".cache", ".lock", ".prefect-results", "x.json", "x.lock", "a/b", "a\\b", "..",
                                 ".", "", "a" * 65, "e\u0301t\u00e9", "dive 1", "x\x00y", "-x"])
def test_one_rule_refuses_unsafe_store_names(bad):
    with pytest.raises(StoreError) as e:
        check_component(bad, "dive id")
    _one_line(e.value)


def test_names_are_nfc_and_path_components_follow_the_same_rule():
    assert check_component("dive-1.a") == "dive-1.a"
    decomposed = "cafe\u0301.cnv"
    assert check_component(decomposed, kind="path") == "caf\u00e9.cnv"  # one name, one spelling
    assert check_relative_path("ctd/caf\u00e9.cnv") == "ctd/caf\u00e9.cnv"
    for bad in ("../x", "/etc/passwd", "a//b", "a/./b", "a\x01b", "x" * 256):
        with pytest.raises(StoreError):
            check_relative_path(bad)


def test_dive_id_catalog_json_is_refused_by_dive_yaml(tmp_path):
    """The red team's case: a dive id ``catalog.json`` would turn the store's STAC catalog into a directory."""
    from hadal.dive import load_dive

    raw = write_dive(tmp_path / "raw", 5.0, csv=False, dive_id="catalog.json")
    with pytest.raises(ConfigError, match="reserved") as e:
        load_dive(raw)
    _one_line(e.value)
    with pytest.raises(StoreError):
        ProductStore(tmp_path / "s").product_dir("catalog.json", "ctd")


def _claim(args):
    root, dive, raw = args
    try:
        ProductStore(root).claim_dive(dive, raw, f"fp-{Path(raw).name}")
        return "ok"
    except StoreError as exc:
        return "refused: " + str(exc)


def test_dive_id_claim_is_atomic_threads_and_processes(tmp_path):
    """Eight threads, then eight processes, each claiming one dive id for its own raw directory at once: exactly
    one wins, every other is refused, and the record names the winner."""
    raws = []
    for i in range(8):
        (tmp_path / f"raw{i}").mkdir()
        raws.append(tmp_path / f"raw{i}")
    for kind, root in (("threads", tmp_path / "s1"), ("processes", tmp_path / "s2")):
        args = [(root, "same", r) for r in raws]
        if kind == "threads":
            results: list[str] = [""] * len(raws)
            barrier = threading.Barrier(len(raws))

            def go(i, barrier=barrier, results=results, args=args):
                barrier.wait()
                results[i] = _claim(args[i])
            ts = [threading.Thread(target=go, args=(i,)) for i in range(len(raws))]
            for t in ts:
                t.start()
            for t in ts:
                t.join()
        else:
            with multiprocessing.get_context("fork").Pool(len(raws)) as pool:
                results = pool.map(_claim, args)
        assert results.count("ok") == 1, (kind, results)
        winner = raws[results.index("ok")]
        assert ProductStore(root).dive_identity("same")["raw_dir"] == str(winner.resolve())
        assert all("belongs to raw directory" in r for r in results if r != "ok")


def test_two_raw_directories_one_dive_id_concurrent_runs(tmp_path):
    """Two different raw directories with the same dive id, ``ingest`` run at the same time in two processes:
    one publishes, the other is refused before publishing anything (no version of it stays)."""
    import subprocess

    a = write_dive(tmp_path / "a", 20.0, csv=False, dive_id="twin")
    b = write_dive(tmp_path / "b", 25.0, csv=False, dive_id="twin")
    store = tmp_path / "store"
    env = {**os.environ, "PYTHONPATH": str(HERE.parent / "src"), "HADAL_PROGRESS": "0"}
    worker = HERE / "malformed" / "stage_worker.py"
    procs = [subprocess.Popen([sys.executable, str(worker), "ingest", str(d), str(store)], env=env,
                              stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) for d in (a, b)]
    outs = [p.communicate(timeout=300) for p in procs]
    codes = [p.returncode for p in procs]
    assert sorted(c == 0 for c in codes) == [False, True], (codes, [o[1][-800:] for o in outs])
    i_loser = next(i for i, c in enumerate(codes) if c != 0)
    assert "belongs to raw directory" in outs[i_loser][0] + outs[i_loser][1], outs[i_loser][1][-800:]
    loser = (a, b)[i_loser]
    winner = a if loser == b else b
    st = ProductStore(store)
    versions = st.versions("twin", "sensors")
    assert len(versions) == 1
    paths = {Path(i["path"]).parent.parent for i in versions[0].manifest()["inputs"]}
    assert str(winner.resolve()) in {str(p) for p in paths} | {str(p.parent) for p in paths}
    assert all(str(loser.resolve()) not in i["path"] for i in versions[0].manifest()["inputs"])
    assert st.dive_identity("twin")["raw_dir"] == str(winner.resolve())


def test_failed_first_stage_leaves_no_claim(tmp_path):
    """A new claim whose stage publishes nothing is undone: the store is as it was (nothing at all)."""
    from hadal.pipeline import make_context, run_stage

    raw = write_dive(tmp_path / "raw", 5.0, csv=False)
    (raw / "logs" / "haidou.mcap").write_bytes(b"not an mcap file")
    store = tmp_path / "store"
    with pytest.raises(Exception):  # noqa: B017 - the reader's own error; only the store matters here
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            run_stage("ingest", make_context(raw, store))
    assert not store.exists() or not any(store.rglob("*")), sorted(store.rglob("*"))


# ------------------------------------------------------------------------------------ 4. bounded parsing
def _yaml_cases() -> dict[str, str]:
    laughs = "a: &a [x, x, x, x, x, x, x, x, x, x]\n" + "".join(
        f"{c}: &{c} [{', '.join(['*' + p] * 10)}]\n" for p, c in zip("abcdefgh", "bcdefghi", strict=True))
    return {
        "billion laughs": "dive_id: x\n" + laughs,
        "deep nesting": "dive_id: x\nnotes: " + "[" * 5000 + "]" * 5000 + "\n",
        "deep block nesting": "dive_id: x\n" + "".join("  " * i + f"k{i}:\n" for i in range(200)) + "  " * 200 + "v\n",
        "huge scalar": "dive_id: x\nnotes: " + "a" * 3_000_000 + "\n",
        "huge integer": "dive_id: x\nlaunch: " + "9" * 100_000 + "\n",
        "huge file": "dive_id: x\n" + "# pad\n" * 1_000_000,
    }


@pytest.mark.parametrize("case", list(_yaml_cases()))
@pytest.mark.parametrize("kind", ["dive", "pipeline", "vehicle"])
def test_hostile_yaml_is_a_quick_one_line_config_error(tmp_path, case, kind):
    from hadal.dive import load_dive
    from hadal.ingest.vehicle import load_vehicle_config
    from hadal.settings import load_config

    text = _yaml_cases()[case]
    f = tmp_path / {"dive": "dive.yaml", "pipeline": "pipeline.yaml", "vehicle": "vehicle.yaml"}[kind]
    f.write_text(text)
    load = {"dive": lambda: load_dive(tmp_path), "pipeline": lambda: load_config(f),
            "vehicle": lambda: load_vehicle_config(f)}[kind]
    t0 = time.monotonic()
    with pytest.raises(ConfigError) as e:
        load()
    assert time.monotonic() - t0 < 5.0
    msg = _one_line(e.value)
    assert str(f) in msg or f.name in msg
    if case in ("billion laughs", "deep nesting", "deep block nesting", "huge scalar", "huge file"):
        assert any(w in msg for w in ("alias", "nested", "characters", "MiB")), msg


def test_yaml_bounds_keep_ordinary_files(tmp_path):
    """The packaged vehicle mapping and a dive.yaml listing 5000 files with anchors still load (no false alarm)."""
    from hadal.ingest.vehicle import default_vehicle_config_path, load_vehicle_config
    from hadal.yamlfile import safe_load_unique

    assert load_vehicle_config(default_vehicle_config_path()).sensors
    text = "base: &b {a: 1, b: [1, 2, 3]}\nuse: *b\nsources:\n  cnv:\n" + "".join(
        f"    - ctd/cast_{i:05d}.cnv\n" for i in range(5000))
    data = safe_load_unique(text)
    assert len(data["sources"]["cnv"]) == 5000 and data["use"] == {"a": 1, "b": [1, 2, 3]}


# ------------------------------------------------------------------------------------ 5. report
def test_report_embeds_no_symlinked_store_file(tmp_path):
    """A landing figure replaced by a symbolic link to a file outside the store: its bytes never reach
    report.html (the landing version is left out with a note naming the link)."""
    from factories import publish_fake_products

    from hadal.report import FigureOptions, build_report

    st = ProductStore(tmp_path / "store")
    pvs = publish_fake_products(st, "dive-r", products=("ctd", "landing"))
    figs = sorted((pvs["landing"].path / "figures").glob("*.png")) if (pvs["landing"].path / "figures").is_dir() \
        else []
    secret = tmp_path / "secret.png"
    secret.write_bytes(b"\x89PNG\r\n\x1a\n" + b"TOP-SECRET-BYTES" * 64)
    target = figs[0] if figs else pvs["landing"].path / "figures" / "injected.png"
    target.parent.mkdir(exist_ok=True)
    if target.exists():
        target.unlink()
    target.symlink_to(secret)
    rep = build_report(st, "dive-r", options=FigureOptions(dpi=50, width_in=4, max_points=500, workers=1))
    b64 = base64.b64encode(secret.read_bytes()).decode("ascii")
    assert b64[:40] not in rep.html
    assert any("symbolic link" in n for n in rep.summary["notes"]), rep.summary["notes"]


# ------------------------------------------------------------------------------------ 6. AlignCTD
@pytest.mark.parametrize("advance_s", [5.0, -5.0, 7.0, 4.5, -6.25])
def test_align_ctd_advance_longer_than_the_record(advance_s):
    from hadal.ctd.align import align_ctd

    with pytest.raises(InputError, match="not shorter than the record") as e:
        align_ctd(np.arange(5.0), advance_s, 1.0)
    _one_line(e.value)


def test_align_ctd_longest_valid_advance_matches_slicing():
    from hadal.ctd.align import align_ctd

    x = np.arange(5.0) * 2
    out = align_ctd(x, 4.0, 1.0)  # one scan keeps a value: x[4] at scan 0
    assert out[0] == x[4] and np.isnan(out[1:]).all()
    out = align_ctd(x, -4.0, 1.0)
    assert out[4] == x[0] and np.isnan(out[:4]).all()


def test_ctd_chain_leaves_a_too_long_advance_as_a_flagged_no_op():
    from types import SimpleNamespace

    from hadal.ctd.chain import process_channels

    settings = SimpleNamespace(
        wild_edit=False, filter_pressure_s=None, filter_temperature_s=None, filter_conductivity_s=None,
        align_conductivity_s=10.0, align_temperature_s=0.0, cell_thermal_mass=False, loop_edit=False)
    c = np.linspace(3.0, 3.1, 5)
    c_out, _t, _p, log = process_channels(c, np.full(5, 2.0), np.full(5, 100.0), 1.0, settings)
    np.testing.assert_array_equal(c_out, c)  # unaligned, not blanked
    entry = next(e for e in log if e["step"] == "align_ctd")
    assert "not shorter than the record" in entry["skipped_channels"]["conductivity"]


@pytest.mark.parametrize("path", ["logs/ha\x00idou.mcap", "logs/\x1b[31m.mcap", "logs\\haidou.mcap",
                                  "logs/" + "x" * 300 + ".mcap"])
def test_source_path_components_follow_the_name_rule(tmp_path, path):
    """A dive.yaml source path with a NUL, a control character, a backslash or an over-long name: a one-line
    ConfigError naming it (a NUL used to reach ``os.stat`` as a ValueError)."""
    from hadal.dive import load_dive, resolve_source

    raw = write_dive(tmp_path / "raw", 5.0, csv=False)
    dive, rd = load_dive(raw)
    with pytest.raises(ConfigError, match="source path") as e:
        resolve_source(rd, path)
    _one_line(e.value)
    assert resolve_source(rd, "./logs/haidou.mcap") == (raw / "logs" / "haidou.mcap").resolve()


def test_stac_catalog_leaves_out_a_version_with_a_symlink(tmp_path):
    """The STAC writer opens product files (NetCDF attributes): a version holding a symbolic link is left out of
    the catalogue instead of being read through the link."""
    from hadal.products.stac import write_store_catalog

    store = ProductStore(tmp_path / "store")
    _publish(store, product="ctd")
    pv = _publish(store, product="dtm", files={"dtm.nc": b"x"})
    (tmp_path / "outside.nc").write_bytes(b"CDF\x01")
    (pv.path / "evil.nc").symlink_to(tmp_path / "outside.nc")
    cat = write_store_catalog(store)
    assert cat.is_file()
    item = json.loads((store.root / "d1" / "stac-item.json").read_text())
    assert not any("dtm" in str(a.get("href", "")) for a in item.get("assets", {}).values())
    assert any("ctd" in str(a.get("href", "")) for a in item.get("assets", {}).values())


def test_init_and_synth_never_propose_a_reserved_dive_id():
    """``hadal init`` derives the dive id from the directory's name: a directory ``catalog.json`` gets a valid id
    (accepted by the one rule), never the store's own file name."""
    from hadal.dive_init import sanitise_dive_id
    from hadal.synth.generate import default_dive_id

    for name in ("catalog.json", "dive.json", "a..b", "x.lock"):
        did = sanitise_dive_id(name)
        assert check_component(did) == did and did.lower() not in ("catalog.json", "dive.json", "x.lock")
    assert check_component(default_dive_id("/tmp/catalog.json"))


def test_source_symlinked_out_of_the_dive_is_refused(tmp_path):
    """A dive.yaml source that is a symbolic link inside the dive to a file outside it (resolved before it is
    checked, as ``..`` is): a one-line ConfigError naming it, nothing opened; a link that stays inside is read."""
    from hadal.dive import load_dive, resolve_source

    raw = write_dive(tmp_path / "raw", 5.0, csv=False)
    outside = tmp_path / "secret.mcap"
    outside.write_bytes((raw / "logs" / "haidou.mcap").read_bytes())
    (raw / "logs" / "out.mcap").symlink_to(outside)
    (raw / "logs" / "in.mcap").symlink_to(raw / "logs" / "haidou.mcap")
    dive, rd = load_dive(raw)
    with pytest.raises(ConfigError, match="escapes the dive directory") as e:
        resolve_source(rd, "logs/out.mcap")
    _one_line(e.value)
    assert resolve_source(rd, "logs/in.mcap") == (raw / "logs" / "haidou.mcap").resolve()
