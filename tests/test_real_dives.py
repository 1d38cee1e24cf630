"""Real dives in: every file of ../shared/data is recognised by `hadal inspect`, and a dive made of each file alone
(after `hadal init`, the generated yaml unedited) runs the stages its data supports and publishes their products.

Data is copied to a temporary directory; the tests skip cleanly when ../shared/data is absent.
"""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import numpy as np
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
    # COARDS lon 195-210 (0-360), z in km: a prior grid (never laser), depths = -1000 x z, land masked
    "dives-real/gmt_HI_topo_04.nc": {"dtm", "suitability"},
    # a land DEM (0-1505 m, 0 = sea): no seafloor to grid; init lists it as not used with why, nothing published
    "dives-real/gmt_Kilauea.utm.nc": set(),
    # 0.1 m cells are 1/5 of the 0.5 m vehicle: landing is skipped by the 1/10 rule (with the reason in the report)
    # unless landing.max_cell_fraction is raised (tests/test_prior_laser_inputs.py runs it with 0.2)
    "bathy-real/LAD_Takuyo_B1_raster_100mm.tif": {"laser_grids"},
    # no conductivity channel: salinity is SeaSoft's sal00 (method in the metadata); start_time 1903 -> 2003
    "dives-real/oce_SBE25_ctd.cnv": {"sensors", "ctd", "profile"},
    # 24 Hz raw SBE 9 with altM: no-bottom readings missing, false echoes flagged, not refused
    "dives-real/pyctd_CTD-spiked-unfiltered.cnv.bz2": {"sensors", "ctd", "profile"},
    "bathy-real/0029_20160323_185603_EX1604_MB.gsf.mb121": {"dtm"},
    "formats-real/kongsberg_em_driver_MRZ_versionF.kmall": {"dtm"},
    "formats-real/mbsys_nbp1403-filtered-em120.all": {"dtm"},
    "formats-real/mbsys_TN136HS.309.snipped.s7k": set(),  # no pings: recognised, said so, nothing to grid
    # point clouds read by their metadata (CRS, units, z up) and a big-endian EM3000 .all (content: below)
    "dives-real/pdal_autzen-utm.las": {"laser_grids"},
    "dives-real/pdal_autzen-utm.pcd": {"laser_grids"},
    "dives-real/pdal_mbf_em300raw.all": {"dtm", "suitability"},
    "mcap-real/rosbag2_talker.mcap": set(),  # std_msgs/String only: nothing maps to a sensor
    "mcap-real/rosbag2_cdr_test_0.mcap": set(),
    "mcap-real/rosbag2_test_bag_for_seek_0.mcap": set(),
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
    shutil.copy(src, raw / "raw" / src.name)
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


def _run_alone(shared: Path, tmp_path: Path, rel: str):
    """The dive made of ``rel`` alone (init + every stage); returns the run context."""
    from hadal.pipeline import make_context, run_pipeline

    src = shared / rel
    if not src.is_file():
        pytest.skip(f"{rel} not in this copy of the shared data")
    raw = tmp_path / "dive"
    (raw / "raw").mkdir(parents=True)
    shutil.copy(src, raw / "raw" / src.name)
    write_init(scan_dive_dir(raw))
    ctx = make_context(raw, tmp_path / "store")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_pipeline(ctx)
    return ctx


def _cnv_body(path: Path, opener=open) -> np.ndarray:
    """The data rows after ``*END*`` read with NumPy alone (the oracle, not hadal's reader)."""
    with opener(path, "rt", encoding="latin-1") as fh:
        text = fh.read()
    return np.loadtxt(text.split("*END*", 1)[1].strip().splitlines(), ndmin=2)


def test_cast_without_conductivity_uses_sal00(shared_data, tmp_path):
    """oce_SBE25_ctd.cnv (SBE 25, SeaSoft 4): scan, timeS, pr, depS, t068, sal00, flag; start_time 1903."""
    import gsw
    import pandas as pd

    rel = "dives-real/oce_SBE25_ctd.cnv"
    ctx = _run_alone(shared_data, tmp_path, rel)
    a = _cnv_body(shared_data / rel)
    pr, dep_s, t68, sal = a[:, 2], a[:, 3], a[:, 4], a[:, 5]
    ctd = pd.read_parquet(ctx.store.latest(ctx.dive_id, "ctd").file("ctd.parquet"))
    meta = ctd.attrs["hadal"]
    assert meta["salinity_method"] == "SeaSoft sal00 (vendor), no conductivity channel"
    assert len(ctd) == len(a)
    np.testing.assert_allclose(ctd["practical_salinity"], sal)  # passes through
    np.testing.assert_allclose(ctd["temperature_its90_degc"], t68 / 1.00024)  # T90 = T68 / 1.00024
    assert ctd["conductivity_s_m"].isna().all() and (ctd["conductivity_s_m_qc"] == 9).all()  # not invented
    lat = 44 + 41.056 / 60  # ** Latitude: N44 41.056
    assert meta["latitude_deg"] == pytest.approx(lat, abs=1e-6)
    # SeaSoft's depS is the UNESCO (Fofonoff-Millard) depth: within its printed precision (+ rounding of lat)
    np.testing.assert_allclose(ctd["depth_fofonoff_millard_m"], dep_s, atol=0.0025)
    # density: EOS-80 of sal00 against gsw (TEOS-10) in situ density, which differs by a few 0.001 kg/m3
    sa = gsw.SA_from_SP(sal, pr, -(63 + 38.633 / 60), lat)
    rho = gsw.rho(sa, gsw.CT_from_t(sa, t68 / 1.00024, pr), pr)
    np.testing.assert_allclose(ctd["density_kg_m3"], rho, atol=0.01)
    # hydrostatic depth: the integral of dp / (rho g) with gsw's density and gravity (from the surface)
    dz = 1e4 / (rho * gsw.grav(lat, pr))
    z = pr[0] * dz[0] + np.r_[0, np.cumsum(np.diff(pr) * (dz[1:] + dz[:-1]) / 2)]
    np.testing.assert_allclose(ctd["depth_m"], z, atol=0.01)
    # the year: 2003 from the System UpLoad Time, not the header's 1903 start_time, and said so
    t = pd.to_datetime(ctd["time"], utc=True)
    assert t.iloc[0] == pd.Timestamp("2003-10-15 11:38:38", tz="UTC") + pd.Timedelta(seconds=a[0, 1])
    sensors = ctx.store.latest(ctx.dive_id, "sensors").file("sensors.parquet")
    smeta = pd.read_parquet(sensors).attrs["hadal"]
    assert "disagrees with System UpLoad Time" in smeta["cast"]["start_time_correction"]
    assert smeta["cast"]["start_time_file"].startswith("1903-10-15")
    assert any("1903" in n for n in smeta["notes"]) and any("sal00" in n for n in smeta["notes"])


def test_cast_altimeter_read_and_its_no_bottom_missing(shared_data, tmp_path):
    """pyctd_CTD-spiked-unfiltered.cnv.bz2 (SBE 9, 24 Hz, altM, AltimeterSensor ScaleFactor 15 = 100 m full
    scale). Measured: 70 253 of 71 325 altM readings are the altimeter's no-echo output (98.6-100 m); the other
    1 072 (8-97 m) come between 150 and 310 dbar, while the cast went to 1 036 dbar at the same place: depth +
    altM there is 180-400 m, above the cast's own deepest point, so they are false echoes, not the bottom (no
    echo at all was received within 100 m of the bottom). Oracle: altM and gsw depth from the file."""
    import bz2

    import gsw
    import pandas as pd

    rel = "dives-real/pyctd_CTD-spiked-unfiltered.cnv.bz2"
    ctx = _run_alone(shared_data, tmp_path, rel)
    a = _cnv_body(shared_data / rel, bz2.open)
    alt_m, pr = a[:, 11], a[:, 2]
    sensors = pd.read_parquet(ctx.store.latest(ctx.dive_id, "sensors").file("sensors.parquet"))
    assert len(sensors) == len(a)  # 24 Hz raw cast: not refused, every scan kept
    no_echo = alt_m >= 0.97 * 100.0  # AN95: 300 x 5 V / 15 = 100 m; no echo at ~4.94-5 V
    assert no_echo.sum() == 70253
    got = sensors["altitude_m"].to_numpy()
    np.testing.assert_allclose(got[~no_echo], alt_m[~no_echo])
    assert np.isnan(got[no_echo]).all() and (sensors["altitude_m_qc"].to_numpy()[no_echo] == 9).all()
    # the QARTOD spike test flags the altimeter's jumps (suspect); the CTD channels pass it
    assert (sensors["altitude_m_qc"] == 3).sum() > 0
    ctd = pd.read_parquet(ctx.store.latest(ctx.dive_id, "ctd").file("ctd.parquet"))
    lat = float(np.mean(a[:, 20]))
    depth = -gsw.z_from_p(pr, lat)
    seafloor = depth + alt_m
    false_echo = ~no_echo & (seafloor < depth.max() - 0.01 * depth.max())
    assert false_echo.sum() == (~no_echo).sum() == 1072
    assert (ctd["altitude_m_qc"].to_numpy()[false_echo] == 4).all()
    assert ctd["seafloor_depth_m"].isna().all()  # no echo from the seafloor anywhere in this cast
    assert ctd.attrs["hadal"]["altimeter_false_echoes"]["readings_flagged"] == 1072
    # gsw.z_from_p is the standard ocean; this warm, salty water column is 0.15 % lighter: 1.6 m at 1 030 m
    assert float(ctd["depth_m"].max()) == pytest.approx(depth.max(), rel=3e-3)
    summary = json.loads(ctx.store.latest(ctx.dive_id, "report").file("summary.json").read_text())
    assert "altimeter out of range" not in summary["figures"]["fig10_seafloor_depth"]
    assert any("no-bottom output" in n for n in summary["notes"])
    # the casts in file order: oceissues644_02dk (566 dbar) makes ctd; dPIRX010 (~1014 dbar) and sta0860 (90 dbar)
    from hadal.ingest.cnv import read_cnv

    oracle = sorted(float(read_cnv(shared_data / "ctd-real" / f)[c].max()) for f, c in
                    (("seabird_dPIRX010.cnv", "prDM"), ("seabird_sta0860.cnv", "prDM")))
    assert sorted(c["max_pressure_dbar"] for c in casts) == pytest.approx(oracle, abs=0.01)
    html = ctx.store.latest(ctx.dive_id, "report").file("report.html").read_text()
    assert "Other casts of this dive" in html


@pytest.mark.parametrize("rel", ["dives-real/pdal_autzen-utm.las", "dives-real/pdal_autzen-utm.pcd",
                                 "dives-real/pdal_mbf_em300raw.all"])
def test_real_point_clouds_and_em3000_content(shared_data, tmp_path, rel):
    """The dive of each file alone, after `hadal init`: the laser grid of PDAL's autzen LAS/PCD holds laspy's own
    elevations (123.93..178.73 m, positive up, all 1065 points, NAD83 / UTM 10N for the LAS); the EM3000 DTM holds
    depths of 4.0-4.85 m (2.42-3.23 m below the transducer + its 1.59-1.62 m) around 27.7594 N 82.6328 W."""
    import laspy
    import numpy as np
    import xarray as xr

    from hadal.pipeline import make_context, run_pipeline

    src = shared_data / rel
    if not src.is_file():
        pytest.skip(f"{rel} not present")
    raw = tmp_path / "dive"
    raw.mkdir()
    shutil.copy(src, raw / src.name)
    write_init(scan_dive_dir(raw))
    ctx = make_context(raw, tmp_path / "store")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_pipeline(ctx)
    if rel.endswith(".all"):
        with xr.open_dataset(ctx.store.latest(ctx.dive_id, "dtm").file("dtm.nc"), engine="h5netcdf") as ds:
            dep, lat, lon = ds["depth_m"].values, ds["lat"].values, ds["lon"].values
        ok = np.isfinite(dep)
        assert ok.sum() > 10 and 4.0 <= np.nanmin(dep) < np.nanmax(dep) <= 4.85
        assert np.all(np.abs(lat[ok] - 27.7594) < 2e-4) and np.all(np.abs(lon[ok] + 82.6328) < 2e-4)
        assert ctx.store.has(ctx.dive_id, "suitability")
        return
    las = laspy.read(str(shared_data / "dives-real/pdal_autzen-utm.las"))
    lg = ctx.store.latest(ctx.dive_id, "laser_grids")
    with xr.open_dataset(lg.file(src.stem + ".nc"), engine="h5netcdf") as ds:
        e, n, attrs = ds["elevation_m"].values, int(ds["count"].sum()), dict(ds.attrs)
    z = np.asarray(las.z)
    assert attrs["z_sign_flipped"] == 0 and ds["elevation_m"].attrs["positive"] == "up"
    assert z.min() - 1e-9 <= np.nanmin(e) < np.nanmax(e) <= z.max() + 1e-9 and n + attrs["n_points_outliers"] == 1065
    if src.suffix == ".las":
        assert attrs["source_crs_epsg"] == 26910 and attrs["source_horizontal_units"] == "metre"
