"""Run plan (stages the data supports), dive identity in the store, file detection by content, packaging."""

from __future__ import annotations

import bz2
import gzip
import lzma
import struct
from pathlib import Path

import numpy as np
import pytest
import yaml

from hadal.dive import Dive, dive_fingerprint
from hadal.errors import ConfigError, StageError, StoreError
from hadal.formats import detect
from hadal.stages.plan import check_plan, plan_stages
from hadal.store import ProductStore, validate_name


def _dive(**sources) -> Dive:
    return Dive.model_validate({"dive_id": "d1", "sources": sources})


def _runs(plan) -> list[str]:
    return [p.name for p in plan if p.run]


# ---------------------------------------------------------------- plan
@pytest.mark.parametrize("sources, expected", [
    ({"cnv": ["a.cnv"]}, ["ingest", "derive", "profile", "report"]),
    ({"multibeam": ["a.xyz"]}, ["dtm", "suitability", "report"]),
    ({"laser": ["a.ply"]}, ["laser", "landing", "report"]),
    ({"prior_grid": ["g.nc"], "mcap": ["log.mcap"]},
     ["ingest", "derive", "dtm", "suitability", "match", "profile", "report"]),
    ({"prior_grid": ["g.nc"], "cnv": ["a.cnv"]}, ["ingest", "derive", "dtm", "suitability", "profile", "report"]),
    ({"mcap": ["a.mcap"], "multibeam": ["m.xyz"], "laser": ["l.ply"]},
     ["ingest", "derive", "dtm", "laser", "suitability", "match", "profile", "landing", "report"]),
    ({}, ["report"]),
])
def test_plan_runs_the_stages_the_data_supports(sources, expected):
    plan = plan_stages(_dive(**sources))
    assert _runs(plan) == expected
    for p in plan:
        assert p.run or p.reason, f"{p.name} skipped without a reason"


def test_plan_reasons_name_the_missing_data():
    plan = {p.name: p for p in plan_stages(_dive(cnv=["a.cnv"]))}
    assert "multibeam" in plan["dtm"].reason and "laser" in plan["laser"].reason
    assert "dtm" in plan["suitability"].reason
    assert "laser_grids" in plan["landing"].reason
    only_laser = {p.name: p for p in plan_stages(_dive(laser=["a.ply"]))}
    assert not only_laser["dtm"].run and only_laser["laser"].products == ("laser_grids",)  # no dtm from laser


def test_launch_is_required_only_by_the_stages_that_need_it():
    check_plan(_dive(cnv=["a.cnv"]), plan_stages(_dive(cnv=["a.cnv"])))  # CTD only: no launch needed
    d = _dive(prior_grid=["g.nc"], mcap=["log.mcap"])
    with pytest.raises(ConfigError, match="match"):
        check_plan(d, plan_stages(d))


def test_frame_error_names_the_stage():
    with pytest.raises(ConfigError, match="'grid'"):
        _dive().frame("grid")


def test_explicit_stage_that_cannot_run_says_why(tmp_path):
    from hadal.pipeline import make_context, stage_plan

    (tmp_path / "a.cnv").write_text("x")
    (tmp_path / "dive.yaml").write_text(yaml.safe_dump({"dive_id": "d1", "sources": {"cnv": ["a.cnv"]}}))
    ctx = make_context(tmp_path, tmp_path / "store")
    with pytest.raises(StageError, match="stage landing cannot run.*laser_grids"):
        stage_plan(ctx, ["landing"])
    assert [p.name for p in stage_plan(ctx) if p.run] == ["ingest", "derive", "profile", "report"]


# ---------------------------------------------------------------- dive identity
def _write_raw(d: Path, dive_id: str, payload: bytes) -> Path:
    d.mkdir(parents=True)
    (d / "a.xyz").write_bytes(payload)
    (d / "dive.yaml").write_text(yaml.safe_dump({"dive_id": dive_id, "sources": {"multibeam": ["a.xyz"]}}))
    return d


def test_second_raw_directory_with_the_same_dive_id_is_refused(tmp_path):
    store = ProductStore(tmp_path / "store")
    a = _write_raw(tmp_path / "a", "same", b"1 2 3\n")
    b = _write_raw(tmp_path / "b", "same", b"4 5 6\n")
    da, db = Dive.model_validate(yaml.safe_load((a / "dive.yaml").read_text())), \
        Dive.model_validate(yaml.safe_load((b / "dive.yaml").read_text()))
    store.claim_dive("same", a, dive_fingerprint(da, a))
    store.claim_dive("same", a, dive_fingerprint(da, a))  # same directory again: fine
    with pytest.raises(StoreError, match="belongs to raw directory"):
        store.claim_dive("same", b, dive_fingerprint(db, b))
    # a moved copy of the same dive (same content) is accepted and the record follows it
    c = tmp_path / "moved"
    c.mkdir()
    for f in a.iterdir():
        (c / f.name).write_bytes(f.read_bytes())
    store.claim_dive("same", c, dive_fingerprint(da, c))
    assert store.dive_identity("same")["raw_dir"] == str(c.resolve())


def test_two_synth_dives_with_one_id_do_not_mix(tmp_path):
    """`run --dives` with two sample dives of one id used to mix their products; the second is now refused."""
    from hadal.pipeline import make_context, run_stage

    a = _write_raw(tmp_path / "x" / "dive", "dup", b"142.2 11.3 8000\n142.21 11.31 8001\n142.2 11.31 8002\n")
    b = _write_raw(tmp_path / "y" / "dive", "dup", b"142.2 11.3 9000\n142.21 11.31 9001\n142.2 11.31 9002\n")
    ctx_a, ctx_b = make_context(a, tmp_path / "store"), make_context(b, tmp_path / "store")
    from hadal.pipeline import claim_dive

    claim_dive(ctx_a)
    with pytest.raises(StoreError, match="different dive with the same id"):
        run_stage("grid", ctx_b)


def test_synth_default_dive_id_is_the_directory_name(tmp_path):
    from hadal.synth.generate import default_dive_id

    assert default_dive_id(tmp_path / "My Dive 07") == "My-Dive-07"
    assert default_dive_id(tmp_path / "dive-a") == "dive-a"


def test_dive_ids_with_newlines_are_refused():
    for bad in ("tiny\n", "a/b", "..", ".hidden", ""):
        with pytest.raises(StoreError):
            validate_name(bad, "dive id")


# ---------------------------------------------------------------- detection by content
def _write_kinds(d: Path) -> dict[str, Path]:
    d.mkdir(exist_ok=True)
    files = {
        "xyz": ("soundings.dat", b"142.1 11.2 8123.5\n142.2 11.3 8124.0\n142.3 11.3 8125.5\n"),
        "csv": ("log.txt", b"time,pressure_dbar,temperature_degC,cond\n2018-10-06T00:00:00Z,1.0,20.1,5.0\n"),
        "ply": ("scan.bin", b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nend_header\n1\n"),
        "las": ("pts.data", b"LASF" + b"\x00" * 300),
        "mcap": ("log.bin", b"\x89MCAP0\r\n" + b"\x00" * 32),
        "netcdf": ("grid.data", b"\x89HDF\r\n\x1a\n" + b"\x00" * 64),
        "geotiff": ("raster.img", b"II*\x00" + b"\x00" * 64),
        "kmall": ("ping.bin", struct.pack("<I", 100) + b"#IIP" + b"\x00" * 92),
        "em_all": ("ping.raw", struct.pack("<I", 100) + b"\x02\x49" + struct.pack("<H", 120) + b"\x00" * 92),
        "cnv": ("cast.txt", b"* Sea-Bird SBE 9 Data File:\n# nquan = 2\n# name 0 = prDM: Pressure [db]\n*END*\n 1.0 2.0\n"),
        "seabird_hex": ("raw.txt", b"* Sea-Bird SBE19plus  Data File:\n*END*\n0A1B2C3D4E5F6071\n0A1B2C3D4E5F6072\n"),
    }
    out = {}
    for kind, (name, data) in files.items():
        (d / name).write_bytes(data)
        out[kind] = d / name
    return out


def test_detect_uses_content_not_extension(tmp_path):
    for kind, path in _write_kinds(tmp_path).items():
        assert detect(path).kind == kind, path.name


@pytest.mark.parametrize("comp, opener", [("gzip", gzip.compress), ("bz2", bz2.compress), ("xz", lzma.compress)])
def test_detect_sees_through_compression(tmp_path, comp, opener):
    f = tmp_path / "cast.bin"
    f.write_bytes(opener(b"* Sea-Bird SBE 9 Data File:\n# name 0 = prDM: Pressure [db]\n*END*\n 1.0\n"))
    k = detect(f)
    assert (k.kind, k.compression, k.source) == ("cnv", comp, "cnv")


def test_detect_errors_are_one_line(tmp_path):
    from hadal.errors import InputError

    with pytest.raises(InputError, match="does not exist"):
        detect(tmp_path / "nope")
    with pytest.raises(InputError, match="directory"):
        detect(tmp_path)
    (tmp_path / "loop").symlink_to(tmp_path / "loop")
    with pytest.raises(InputError):
        detect(tmp_path / "loop")
    bad = tmp_path / "bad.gz"
    bad.write_bytes(b"\x1f\x8b\x08\x00garbage-not-deflate")
    with pytest.raises(InputError, match="corrupt gzip"):
        detect(bad)


def test_every_shared_file_is_recognised(shared_data):
    """Every data file in ../shared/data is identified as a kind hadal reads (documents are not data)."""
    expected_source = {"ctd-real": "cnv", "mcap-real": "mcap"}
    for f in sorted(shared_data.rglob("*")):
        if not f.is_file() or f.suffix in (".md", ".inf"):
            continue
        k = detect(f)
        assert k.kind != "unknown", f
        top = f.relative_to(shared_data).parts[0]
        if top in expected_source:
            assert k.source == expected_source[top], f


def test_fingerprint_changes_with_content(tmp_path):
    a = _write_raw(tmp_path / "a", "d", b"1 2 3\n")
    d = Dive.model_validate(yaml.safe_load((a / "dive.yaml").read_text()))
    f1 = dive_fingerprint(d, a)
    (a / "a.xyz").write_bytes(b"1 2 4\n")
    assert dive_fingerprint(d, a) != f1
    assert np.isscalar(len(f1)) and len(f1) == 64


@pytest.mark.parametrize("make, match", [
    (lambda d: (d / "a").symlink_to(d / "b") or (d / "b").symlink_to(d / "a"), "symbolic link loop"),
    (lambda d: __import__("os").mkfifo(d / "a"), "not a regular file"),
    (lambda d: (d / "a").mkdir(), "is a directory"),
])
def test_odd_source_files_are_one_line_errors_not_hangs(tmp_path, make, match):
    """A source that is a symlink loop, a FIFO (reading it would block) or a directory: said as it is."""
    from hadal.errors import InputError
    from hadal.pipeline import make_context, run_stage

    make(tmp_path)
    (tmp_path / "dive.yaml").write_text(yaml.safe_dump({
        "dive_id": "odd", "sources": {"multibeam": ["a"]},
        "map_frame": {"origin_latitude_deg": 1.0, "origin_longitude_deg": 2.0}}))
    with pytest.raises(InputError, match=match):
        run_stage("grid", make_context(tmp_path, tmp_path / "store"))
    assert not (tmp_path / "store").exists()


def test_stage_dependencies_follow_the_products_each_stage_reads():
    """Oracle: the data flow of docs/architecture.md (derive reads sensors; suitability, match and landing read
    the grid's products; match also ctd and suitability; report everything)."""
    from hadal.stages.plan import downstream_stages, stage_dependencies

    deps = stage_dependencies(["ingest", "derive", "dtm", "laser", "suitability", "match", "profile", "landing",
                               "report"])
    assert deps["ingest"] == deps["dtm"] == deps["laser"] == set()  # the three raw readers run side by side
    assert deps["derive"] == {"ingest"}
    assert deps["suitability"] == {"dtm"}
    assert deps["landing"] == {"laser"}  # landing waits neither for match nor for the DTM
    assert deps["match"] == {"derive", "dtm", "suitability"}  # nor match for the laser grids
    # the binned casts wait for the navigation product (issue 46): placed at its position at the cast's time
    assert deps["profile"] == {"ingest", "derive", "match"}
    assert deps["report"] == {"ingest", "derive", "dtm", "laser", "suitability", "match", "profile", "landing"}
    assert stage_dependencies(["derive", "landing"]) == {"derive": set(), "landing": set()}  # only the run's stages
    assert downstream_stages("grid") == ["suitability", "match", "profile", "landing", "report"]  # dtm + laser
    assert downstream_stages("dtm") == ["suitability", "match", "profile", "report"]
    assert downstream_stages("laser") == ["landing", "report"]
    assert downstream_stages("derive") == ["match", "profile", "report"]
    assert downstream_stages("report") == []
