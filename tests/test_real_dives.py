"""Real dives in: every file of ../shared/data is recognised by `hadal inspect`, and a dive made of each file alone
(or with the files it needs, TOGETHER) (after `hadal init`, the generated yaml unedited) runs the stages its data supports and publishes their products.

Data is copied to a temporary directory; the tests skip cleanly when ../shared/data is absent.
"""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import pytest
import yaml

from hadal.dive_init import scan_dive_dir, write_init
from hadal.errors import InputError
from hadal.inspect import inspect_file

#: shared file (relative to ../shared/data) -> products its dive must publish (report always)
EXPECTED: dict[str, set[str]] = {
    "ctd-real/seabird_sta0860.cnv": {"sensors", "ctd", "profile"},
    "ctd-real/seabird_dPIRX010.cnv": {"sensors", "ctd", "profile"},
    "ctd-real/sbs_19plus_V2_CTD-processing_example.cnv": {"sensors", "ctd", "profile"},
    "ctd-real/oceissues644_02dk.cnv": {"sensors", "ctd", "profile"},
    "ctd-real/pyctd_CTD_with_sigma_e00.cnv": {"sensors", "ctd", "profile"},
    "formats-real/sbs_SBE19plus_01906398_2019_07_15_0033_cropped.cnv": {"sensors", "ctd", "profile"},
    "formats-real/sbs_SBE19plus_01906398_2019_07_15_0033_cropped_binavg.cnv": {"sensors", "ctd", "profile"},
    "formats-real/sbs_SBE19plus_01906398_2019_07_15_0033_cropped_loopedit.cnv": {"sensors", "ctd", "profile"},
    "formats-real/sbs_SBE19plus_01906398_2019_07_15_0033_cropped_loopedit_wildedit.cnv": {"sensors", "ctd", "profile"},
    "formats-real/sbs_19plus_V2.hex": {"sensors", "ctd", "profile"},
    "bathy-real/tut_bathy.nc": {"dtm", "suitability"},
    "formats-real/gmt_depth_pixel.nc": {"dtm", "suitability"},
    # 0.1 m cells are 1/5 of the 0.5 m vehicle: landing is skipped by the 1/10 rule (with the reason in the report)
    # unless landing.max_cell_fraction is raised (tests/test_prior_laser_inputs.py runs it with 0.2)
    "bathy-real/LAD_Takuyo_B1_raster_100mm.tif": {"laser_grids"},
    "bathy-real/0029_20160323_185603_EX1604_MB.gsf.mb121": {"dtm"},
    "formats-real/kongsberg_em_driver_MRZ_versionF.kmall": {"dtm"},
    "formats-real/mbsys_nbp1403-filtered-em120.all": {"dtm"},
    "formats-real/mbsys_TN136HS.309.snipped.s7k": set(),  # no pings: recognised, said so, nothing to grid
    "mcap-real/rosbag2_talker.mcap": set(),  # std_msgs/String only: nothing maps to a sensor
    "mcap-real/rosbag2_cdr_test_0.mcap": set(),
    "mcap-real/rosbag2_test_bag_for_seek_0.mcap": set(),
    # glider logs (content checked against the files and pyglider's L0 product in tests/test_gliders.py)
    "dives-real/pyglider_sea035.12.gli.sub.36": {"sensors", "ctd", "profile"},
    "dives-real/pyglider_sea035.12.pld1.sub.36": {"sensors", "ctd", "profile"},
    "dives-real/gutils_usf_bass_2016_252_1_14_sbd.dat": {"sensors", "ctd", "profile"},
}

#: files that make one dive only together (copied into the dive of each of them): a SeaExplorer's navigation and
#: payload logs
TOGETHER: dict[str, tuple[str, ...]] = {
    "dives-real/pyglider_sea035.12.gli.sub.36": ("dives-real/pyglider_sea035.12.pld1.sub.36",),
    "dives-real/pyglider_sea035.12.pld1.sub.36": ("dives-real/pyglider_sea035.12.gli.sub.36",),
}


def _data_files(root: Path) -> list[Path]:
    return sorted(f for f in root.rglob("*") if f.is_file() and f.suffix not in (".md", ".inf"))


def test_every_shared_file_is_inspected(shared_data):
    for f in _data_files(shared_data):
        info = inspect_file(f)
        assert info["kind"] not in ("unknown", "unreadable"), (f, info)
        assert info.get("source") is not None, (f, info)
        json.dumps(info, allow_nan=False)  # strict JSON for --json
        rel = f.relative_to(shared_data).as_posix()
        if EXPECTED.get(rel):
            assert not info.get("error"), (rel, info["error"])


def test_every_shared_file_is_listed_in_expected(shared_data):
    names = {f.relative_to(shared_data).as_posix() for f in _data_files(shared_data)}
    assert names - set(EXPECTED) == set(), "new shared files: add them to EXPECTED"


@pytest.mark.parametrize("rel", sorted(EXPECTED))
def test_init_then_run_each_real_file_alone(shared_data, tmp_path, rel):
    from hadal.pipeline import make_context, run_pipeline

    src = shared_data / rel
    if not src.is_file():
        pytest.skip(f"{rel} not in this copy of the shared data")
    raw = tmp_path / ("dive-" + src.stem.replace(".", "-")[:40])
    (raw / "raw").mkdir(parents=True)
    for f in (src, *(shared_data / r for r in TOGETHER.get(rel, ()))):
        shutil.copy(f, raw / "raw" / f.name)
    res = scan_dive_dir(raw)
    write_init(res)
    dive_yaml = yaml.safe_load((raw / "dive.yaml").read_text())
    assert dive_yaml["dive_id"] == raw.name
    with pytest.raises(Exception, match="already exist"):
        write_init(res)  # never overwrites without --force
    ctx = make_context(raw, tmp_path / "store")
    if not EXPECTED[rel]:  # nothing in it can be processed: said by init, and a one-line error from run
        assert res.not_used and not res.dive["sources"], (res.not_used, res.dive)
        with pytest.raises(InputError, match="no source files"):
            run_pipeline(ctx)
        return
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_pipeline(ctx)
    published = set(ctx.store.products(ctx.dive_id))
    assert EXPECTED[rel] | {"report"} <= published, (rel, published, res.not_used, res.todo)
    summary = json.loads(ctx.store.latest(ctx.dive_id, "report").file("summary.json").read_text())
    skipped = {s["stage"] for s in summary["skipped_stages"]}
    from hadal.stages import STAGE_ORDER

    assert {n for n in STAGE_ORDER if n != "report"} - skipped, f"{rel}: the report says every stage was skipped"
    if rel.endswith("Takuyo_B1_raster_100mm.tif"):
        why = {s["stage"]: s["reason"] for s in summary["skipped_stages"]}
        assert "landing.max_cell_fraction" in why.get("landing", ""), why


def _dive_of(tmp_path: Path, shared: Path, *rels: str) -> Path:
    raw = tmp_path / "mixed"
    raw.mkdir()
    for rel in rels:
        shutil.copy(shared / rel, raw / Path(rel).name)
    write_init(scan_dive_dir(raw))
    return raw


def test_stage_failure_does_not_stop_the_others_and_the_report_says_so(shared_data, tmp_path):
    """A cast and a corrupt sounding file: ingest/derive/report still publish; the run ends in one error."""
    from hadal.errors import StageError
    from hadal.pipeline import make_context, run_pipeline

    raw = _dive_of(tmp_path, shared_data, "ctd-real/seabird_sta0860.cnv", "bathy-real/tut_bathy.nc")
    (raw / "tut_bathy.nc").write_bytes((shared_data / "bathy-real/tut_bathy.nc").read_bytes()[:3000])
    ctx = make_context(raw, tmp_path / "store")
    with pytest.raises(StageError, match=r"1 stage\(s\) failed \(dtm: .*tut_bathy.nc"):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            run_pipeline(ctx)
    assert {"sensors", "ctd", "profile", "report"} <= set(ctx.store.products(ctx.dive_id))
    assert not ctx.store.has(ctx.dive_id, "dtm")
    summary = json.loads(ctx.store.latest(ctx.dive_id, "report").file("summary.json").read_text())
    why = {s["stage"]: s["reason"] for s in summary["skipped_stages"]}
    assert why["dtm"].startswith("failed:") and "dtm failed" in why["suitability"]


def test_cast_far_from_the_prior_grid(shared_data, tmp_path):
    """A cast off Madagascar with a grid near Bermuda: init says so; suitability centres on the grid and says so."""
    from hadal.pipeline import make_context, run_pipeline

    raw = tmp_path / "far"
    raw.mkdir()
    for rel in ("ctd-real/seabird_sta0860.cnv", "bathy-real/tut_bathy.nc"):
        shutil.copy(shared_data / rel, raw / Path(rel).name)
    res = scan_dive_dir(raw)
    assert any("lies outside tut_bathy.nc" in t for t in res.todo), res.todo
    write_init(res)
    ctx = make_context(raw, tmp_path / "store")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_pipeline(ctx)
    import xarray as xr

    with xr.open_dataset(ctx.store.latest(ctx.dive_id, "suitability").file("suitability.nc")) as s:
        assert "outside the DTM" in s.attrs["region_centre_note"]


def test_several_casts_and_a_hex_with_its_own_cnv(shared_data, tmp_path):
    raw = tmp_path / "casts"
    raw.mkdir()
    for rel in ("ctd-real/seabird_sta0860.cnv", "ctd-real/oceissues644_02dk.cnv", "formats-real/sbs_19plus_V2.hex",
                "ctd-real/sbs_19plus_V2_CTD-processing_example.cnv"):
        shutil.copy(shared_data / rel, raw / Path(rel).name)
    res = scan_dive_dir(raw)
    assert "launch" not in res.dive  # casts 25°S and 69°N: each uses its own header position
    assert sorted(res.dive["sources"]["cnv"]) == ["oceissues644_02dk.cnv", "sbs_19plus_V2_CTD-processing_example.cnv",
                                                  "seabird_sta0860.cnv"]
    assert any(n.startswith("sbs_19plus_V2.hex: the same cast as") for n in res.not_used), res.not_used


def test_report_lists_every_cast(shared_data, tmp_path):
    from hadal.pipeline import make_context, run_pipeline

    raw = _dive_of(tmp_path, shared_data, "ctd-real/seabird_sta0860.cnv", "ctd-real/oceissues644_02dk.cnv",
                   "ctd-real/seabird_dPIRX010.cnv")
    ctx = make_context(raw, tmp_path / "store")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_pipeline(ctx)
    summary = json.loads(ctx.store.latest(ctx.dive_id, "report").file("summary.json").read_text())
    casts = summary["casts"]
    assert len(casts) == 2  # the first cast makes `ctd`; the other two are listed with their own positions
    # the casts in file order: oceissues644_02dk (566 dbar) makes ctd; dPIRX010 (~1014 dbar) and sta0860 (90 dbar)
    from hadal.ingest.cnv import read_cnv

    oracle = sorted(float(read_cnv(shared_data / "ctd-real" / f)[c].max()) for f, c in
                    (("seabird_dPIRX010.cnv", "prDM"), ("seabird_sta0860.cnv", "prDM")))
    assert sorted(c["max_pressure_dbar"] for c in casts) == pytest.approx(oracle, abs=0.01)
    html = ctx.store.latest(ctx.dive_id, "report").file("report.html").read_text()
    assert "Other casts of this dive" in html
