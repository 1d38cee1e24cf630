"""Real dives in: every file of ../shared/data is recognised by `hadal inspect`, and a dive made of each file alone
(or with the files it needs, TOGETHER) (after `hadal init`, the generated yaml unedited) runs the stages its data supports and publishes their products.

Data is copied to a temporary directory; the tests skip cleanly when ../shared/data is absent.
"""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import pytest
import yaml
from dive_runs import init_dive, run_quiet  # noqa: E402

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
    # unless landing.max_cell_fraction is raised (tests/unit/grid/test_prior_laser_inputs.py runs it with 0.2)
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
    # glider logs (content checked against the files and pyglider's L0 product in tests/unit/ingest/test_gliders.py)
    "dives-real/pyglider_sea035.12.gli.sub.36": {"sensors", "ctd", "profile"},
    "dives-real/pyglider_sea035.12.pld1.sub.36": {"sensors", "ctd", "profile"},
    "dives-real/gutils_usf_bass_2016_252_1_14_sbd.dat": {"sensors", "ctd", "profile"},
    # an underway thermosalinograph (per-scan lat/lon, prM = 0): a trajectory, never a 0 m cast or a profile
    "dives-real/seabird_SBE21_TSG_PIR_010.cnv": {"sensors", "trajectory"},
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


def _run_alone(shared: Path, tmp_path: Path, rel: str):
    """The dive made of ``rel`` alone (init + every stage); returns the run context."""
    raw, _ = init_dive(shared, tmp_path, rel)
    return run_quiet(raw, tmp_path / "store")


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
        # its COG: the grid's cells in the cloud's own CRS (laspy's reading of the LAS header), no resampling,
        # no vertical datum claimed for the elevations (issue 46)
        import rasterio
        from pyproj import CRS

        with rasterio.open(lg.file(src.stem + ".tif")) as f:
            crs = CRS.from_wkt(f.crs.to_wkt())
            el = f.read(1, masked=True)
        assert crs.equals(las.header.parse_crs(), ignore_axis_order=True) and not crs.is_compound
        assert abs(float(el.min()) - np.nanmin(e)) < 0.1 and abs(float(el.max()) - np.nanmax(e)) < 0.1
        assert int((~el.mask).sum()) == int(np.isfinite(e).sum())


# ---------------------------------------------------------------- underway records and SeaSoft-binned casts
TSG = "dives-real/seabird_SBE21_TSG_PIR_010.cnv"


def _seasoft_columns(path: Path) -> tuple[dict[str, Any], str]:
    """The oracle: a .cnv's own columns parsed here with NumPy (not hadal's reader), by its ``# name i = x:`` lines,
    and its header text."""
    import re

    import numpy as np

    text = path.read_bytes().decode("latin-1")
    head, body = re.split(r"^\*END\*\s*$", text, maxsplit=1, flags=re.M)
    names = {int(i): n.strip() for i, n in re.findall(r"^# name (\d+) = ([^:]+):", head, flags=re.M)}
    rows = np.array([[float(v) for v in ln.split()] for ln in body.splitlines() if ln.strip()])
    return {names[i]: rows[:, i] for i in sorted(names)}, head


def _run_dive(tmp_path: Path, shared: Path, *rels: str):
    raw, res = init_dive(shared, tmp_path, *rels)
    return raw, res, run_quiet(raw, tmp_path / "store")


def test_underway_tsg_is_a_trajectory_with_its_own_positions(shared_data, tmp_path):
    """Oracle: the file's own per-scan latitude/longitude/timeJ/T/C/P columns (parsed here), gsw.SP_from_C and
    gsw's TEOS-10 at each scan's own position."""
    import gsw
    import numpy as np
    import pandas as pd
    import xarray as xr

    if not (shared_data / TSG).is_file():
        pytest.skip(f"{TSG} not in this copy of the shared data")
    raw, res, ctx = _run_dive(tmp_path, shared_data, TSG)
    # init: the choice is explicit in dive.yaml, with its evidence in a comment the user can read and change
    text = (raw / "dive.yaml").read_text()
    assert yaml.safe_load(text)["sources"]["cnv"] == [{"path": "raw/seabird_SBE21_TSG_PIR_010.cnv", "kind": "underway"}]
    assert "# kind: underway, hadal init's choice" in text and "13.79 km" in text and "prM spans 0.000 dbar" in text
    assert "launch" not in res.dive  # the header position is not a cast position
    published = set(ctx.store.products(ctx.dive_id))
    assert {"sensors", "trajectory", "report"} <= published and not {"ctd", "profile"} & published, published
    col, _ = _seasoft_columns(shared_data / TSG)
    pv = ctx.store.latest(ctx.dive_id, "trajectory")
    index = json.loads(pv.file("trajectory.json").read_text())["records"]
    assert len(index) == 1 and index[0]["scans"] == len(col["latitude"]) == 602
    with xr.open_dataset(pv.path / index[0]["file"]) as ds:
        assert ds.attrs["featureType"] == "trajectory" and ds.attrs["cdm_data_type"] == "Trajectory"
        assert ds["trajectory"].attrs["cf_role"] == "trajectory_id" and int(ds["row_size"][0]) == 602
        assert "pressure_dbar" not in ds.dims and "cast" not in ds.dims  # not binned, not a profile
        # the file's own per-scan positions (not the header's 0 51.788 S 38 0.000 W)
        np.testing.assert_allclose(ds["lat"].values, col["latitude"], rtol=0, atol=1e-9)
        np.testing.assert_allclose(ds["lon"].values, col["longitude"], rtol=0, atol=1e-9)
        assert np.ptp(ds["lat"].values) > 0.12  # moves ~14 km
        # times: start year 2011 + timeJ (day of year, 1 = Jan 1 00:00)
        t_file = pd.Timestamp("2011-01-01") + pd.to_timedelta(col["timeJ"] - 1.0, unit="D")
        dt = np.abs((pd.to_datetime(ds["time"].values) - t_file).total_seconds())
        assert dt.max() < 1e-3
        np.testing.assert_allclose(ds["temperature_its90_degc"].values[np.isfinite(ds["temperature_its90_degc"])],
                                   col["t090C"][np.isfinite(ds["temperature_its90_degc"].values)], atol=1e-9)
        # PSS-78 salinity vs gsw on the file's own T/C/P; NaN only where ingest's QC flagged T or C bad
        sp_oracle = gsw.SP_from_C(col["c0S/m"] * 10.0, col["t090C"], col["prM"])
        sp = ds["practical_salinity"].values
        ok = np.isfinite(sp)
        np.testing.assert_allclose(sp[ok], sp_oracle[ok], rtol=0, atol=2e-4)
        flagged = ~np.isin(ds["conductivity_s_m_qc"].values, [1, 2, 3]) | \
            ~np.isin(ds["temperature_its90_degc_qc"].values, [1, 2, 3])
        assert np.array_equal(~ok, flagged)
        assert ok.sum() > 400
        # TEOS-10 at each scan's own position (a wrong position changes SA)
        sa = gsw.SA_from_SP(sp_oracle, col["prM"], col["longitude"], col["latitude"])
        np.testing.assert_allclose(ds["absolute_salinity_g_kg"].values[ok], sa[ok], rtol=0, atol=2e-4)
        ct = gsw.CT_from_t(sa, col["t090C"], col["prM"])
        np.testing.assert_allclose(ds["sigma0_kg_m3"].values[ok], gsw.sigma0(sa, ct)[ok], rtol=0, atol=2e-4)
    # its track for GIS beside the NetCDF: GDAL/OGR (pyogrio, what ogrinfo reads) finds one LineString in lon/lat
    pyogrio = pytest.importorskip("pyogrio")
    track = pv.path / index[0]["file"].replace(".nc", "_track.geojson")
    info = pyogrio.read_info(track)
    assert info["features"] == 1 and info["geometry_type"] == "LineString" and info["crs"] == "EPSG:4326"
    ok_pos = np.isfinite(col["latitude"]) & np.isfinite(col["longitude"])
    assert info["total_bounds"] == pytest.approx([col["longitude"][ok_pos].min(), col["latitude"][ok_pos].min(),
                                                   col["longitude"][ok_pos].max(), col["latitude"][ok_pos].max()],
                                                  abs=1e-7)
    # the report draws the track/section figure instead of cast figures, and lists the record
    summary = json.loads(ctx.store.latest(ctx.dive_id, "report").file("summary.json").read_text())
    assert summary["figures"].get("underway_tsg") == "ok", summary["figures"]
    assert not {"fig08_ctd_profiles", "fig09_depth_time", "ctd_ts_theta_n2"} & set(summary["figures"])
    assert summary["underway"][0]["scans"] == 602
    assert summary["underway"][0]["latitude_range_deg"] == pytest.approx([col["latitude"].min(), col["latitude"].max()])
    assert not [n for n in summary["notes"] if "missing" in n], summary["notes"]
    html = ctx.store.latest(ctx.dive_id, "report").file("report.html").read_text()
    assert "Underway records (thermosalinograph trajectories)" in html and "underway00_seabird_SBE21" in html


def test_underway_tsg_beside_a_cast(shared_data, tmp_path):
    """A cast and a TSG in one dive: the cast makes ctd/profile (whatever the file order), the TSG a trajectory."""
    import numpy as np
    import xarray as xr

    if not (shared_data / TSG).is_file():
        pytest.skip(f"{TSG} not in this copy of the shared data")
    _, res, ctx = _run_dive(tmp_path, shared_data, "ctd-real/seabird_sta0860.cnv", TSG)
    published = set(ctx.store.products(ctx.dive_id))
    assert {"sensors", "ctd", "profile", "trajectory"} <= published and "cast_profiles" not in published, published
    assert res.dive["launch"]["latitude_deg"] == pytest.approx(-(25 + 27.85 / 60), abs=1e-4)  # the cast's header
    col, _ = _seasoft_columns(shared_data / "ctd-real/seabird_sta0860.cnv")
    with xr.open_dataset(ctx.store.latest(ctx.dive_id, "profile").file("profile.nc")) as prof:
        assert prof["pressure_dbar"].values.max() == pytest.approx(col["prDM"].max())
    pv = ctx.store.latest(ctx.dive_id, "trajectory")
    rec = json.loads(pv.file("trajectory.json").read_text())["records"][0]
    with xr.open_dataset(pv.path / rec["file"]) as ds:
        tsg, _ = _seasoft_columns(shared_data / TSG)
        np.testing.assert_allclose(ds["lat"].values, tsg["latitude"], atol=1e-9)


#: SeaSoft-binned casts: (file, pressure column, temperature column, ITS-68?)
BINNED = [("ctd-real/pyctd_CTD_with_sigma_e00.cnv", "prDM", "t068C", True),
          ("formats-real/sbs_SBE19plus_01906398_2019_07_15_0033_cropped_binavg.cnv", "prdM", "tv290C", False),
          ("ctd-real/seabird_sta0860.cnv", "prDM", "t068C", True)]


@pytest.mark.parametrize("rel,pcol,tcol,t68", BINNED)
def test_seasoft_binned_cast_keeps_its_own_bins(shared_data, tmp_path, rel, pcol, tcol, t68):
    """Oracle: the file's own rows (bin pressure and temperature per row) and its header's binavg_binsize. Before:
    re-binned to 10 dbar (the 2 dbar SBE 19plus cast became one bin) with an all-NaN ascent."""
    import re

    import numpy as np
    import xarray as xr

    if not (shared_data / rel).is_file():
        pytest.skip(f"{rel} not in this copy of the shared data")
    _, _, ctx = _run_dive(tmp_path, shared_data, rel)
    col, head = _seasoft_columns(shared_data / rel)
    size = float(re.search(r"^# binavg_binsize = ([0-9.]+)", head, flags=re.M).group(1))
    p = col[pcol]
    t = col[tcol] / 1.00024 if t68 else col[tcol]  # ITS-68 -> ITS-90
    deepest = int(np.argmax(p))
    first_is_deepest = deepest == 0
    phase = np.where(np.arange(p.size) <= deepest, "descent", "ascent") if not first_is_deepest else \
        np.full(p.size, "ascent")
    pv = ctx.store.latest(ctx.dive_id, "profile")
    assert pv.manifest()["summary"]["binning"] == "source"
    assert pv.manifest()["summary"]["bin_dbar"] == size
    from hadal.products.dsg import orthogonal_profile  # the ragged casts on their bins (the report's reader)

    with xr.open_dataset(pv.path / "profile.nc") as ragged:
        prof = orthogonal_profile(ragged.load())
        assert prof.attrs["bin_size_dbar"] == size == prof.attrs["seasoft_binavg_binsize"]
        assert prof.attrs["seasoft_binavg_bintype"] == "decibars"
        casts = str(prof["cast"].attrs["flag_meanings"]).split()
        assert casts == [c for c in ("descent", "ascent") if (phase == c).any()]  # no empty cast
        centres = prof["pressure_dbar"].values
        np.testing.assert_allclose(centres, np.unique(np.rint(p / size)) * size)
        for k, cast in enumerate(casts):
            sel = phase == cast
            levels = np.searchsorted(centres, np.rint(p[sel] / size) * size)
            # float32 in the file: within half the registry's 0.0001 degC precision (the file gives 4 decimals)
            np.testing.assert_allclose(prof["temperature_its90_degc"].values[k, levels], t[sel], atol=5e-5)
            assert (prof["count"].values[k, levels] == 1).all()
            assert int(prof["count"].values[k].sum()) == int(sel.sum())
            assert np.isfinite(prof["temperature_its90_degc"].values[k]).any()


def test_underway_record_without_a_pressure_channel(shared_data, tmp_path):
    """The real TSG with its pressure channel renamed away (an SBE 45 has none): still a trajectory, salinity at
    0 dbar (oracle: gsw.SP_from_C on the file's own T/C at p = 0), the assumption said in a warning."""
    import gsw
    import numpy as np
    import xarray as xr

    from hadal.pipeline import make_context, run_pipeline

    if not (shared_data / TSG).is_file():
        pytest.skip(f"{TSG} not in this copy of the shared data")
    raw = tmp_path / "dive"
    (raw / "raw").mkdir(parents=True)
    text = (shared_data / TSG).read_bytes().replace(b"# name 5 = prM: Pressure [db]", b"# name 5 = v0: Voltage 0")
    (raw / "raw" / "tsg.cnv").write_bytes(text)
    write_init(scan_dive_dir(raw))
    assert yaml.safe_load((raw / "dive.yaml").read_text())["sources"]["cnv"][0]["kind"] == "underway"
    ctx = make_context(raw, tmp_path / "store")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_pipeline(ctx)
    pv = ctx.store.latest(ctx.dive_id, "trajectory")
    rec = json.loads(pv.file("trajectory.json").read_text())["records"][0]
    col, _ = _seasoft_columns(shared_data / TSG)
    with xr.open_dataset(pv.path / rec["file"]) as ds:
        assert (ds["pressure_dbar"].values == 0).all()
        sp = ds["practical_salinity"].values
        ok = np.isfinite(sp)
        np.testing.assert_allclose(sp[ok], gsw.SP_from_C(col["c0S/m"] * 10.0, col["t090C"], 0.0)[ok], atol=2e-4)
    from hadal.products.io import read_parquet_metadata

    meta, _ = read_parquet_metadata(ctx.store.latest(ctx.dive_id, "sensors").path / "sensors.parquet")
    assert any("without a pressure channel" in w for w in meta["warnings"]), meta["warnings"]


def test_seasoft_depth_binned_cast_keeps_its_own_depth_bins(shared_data, tmp_path):
    """A depth-binned cast (the 1 dbar oceissues644 cast relabelled as SeaSoft 'meters' bins; no real BinAvg-by-depth
    file is in ../shared/data): the profile is on depth_m with one level per row at rint(depSM) (oracle: the file's
    own depSM column), bin type and size recorded."""
    import numpy as np
    import xarray as xr

    from hadal.pipeline import make_context, run_pipeline

    rel = "ctd-real/oceissues644_02dk.cnv"
    if not (shared_data / rel).is_file():
        pytest.skip(f"{rel} not in this copy of the shared data")
    raw = tmp_path / "dive"
    (raw / "raw").mkdir(parents=True)
    text = (shared_data / rel).read_bytes().replace(b"binavg_bintype = decibars", b"binavg_bintype = meters")
    (raw / "raw" / "m.cnv").write_bytes(text.replace(b"# interval = decibars: 1", b"# interval = meters: 1"))
    write_init(scan_dive_dir(raw))
    ctx = make_context(raw, tmp_path / "store")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_pipeline(ctx)
    col, _ = _seasoft_columns(shared_data / rel)
    from hadal.products.dsg import orthogonal_profile  # the ragged casts on their bins (the report's reader)

    with xr.open_dataset(ctx.store.latest(ctx.dive_id, "profile").file("profile.nc")) as ragged:
        prof = orthogonal_profile(ragged.load())
        assert prof.attrs["seasoft_binavg_bintype"] == "meters" and prof.attrs["bin_size_m"] == 1.0
        np.testing.assert_array_equal(prof["depth_m"].values, np.unique(np.rint(col["depSM"])))
        assert int(prof["count"].values.sum()) == len(col["depSM"])


def test_underway_record_listed_without_kind_is_a_cast_with_a_warning(shared_data, tmp_path, caplog):
    """A hand-written dive.yaml listing the TSG without 'kind': the pipeline follows dive.yaml (a cast, as before)
    and derive says in a warning that the content looks underway and how to change it."""
    import logging

    from hadal.pipeline import make_context, run_pipeline

    if not (shared_data / TSG).is_file():
        pytest.skip(f"{TSG} not in this copy of the shared data")
    raw = tmp_path / "dive"
    raw.mkdir()
    shutil.copy(shared_data / TSG, raw / "tsg.cnv")
    (raw / "dive.yaml").write_text("dive_id: tsg\nsources:\n  cnv: [tsg.cnv]\n")
    ctx = make_context(raw, tmp_path / "store")
    with warnings.catch_warnings(), caplog.at_level(logging.WARNING, logger="hadal"):
        warnings.simplefilter("ignore")
        run_pipeline(ctx)
    assert {"ctd", "profile"} <= set(ctx.store.products(ctx.dive_id))
    assert not ctx.store.has(ctx.dive_id, "trajectory")
    assert any("looks like an underway record" in r.getMessage() and "kind: underway" in r.getMessage()
               for r in caplog.records), [r.getMessage() for r in caplog.records]


def test_real_cast_profile_is_a_ragged_dsg_at_the_header_position(shared_data, tmp_path):
    """dives-real/oce_SBE25_ctd.cnv: profile.nc is a CF ragged array read back with netCDF4 (row sizes sum to the
    obs dimension, NC_CHAR ids, depth as the Z axis) at the header's position (oracle: the file's `** Latitude:` /
    `** Longitude:` lines), said to be the header/launch position (no per-sample navigation in a ship cast)."""
    import re

    import netCDF4

    rel = "dives-real/oce_SBE25_ctd.cnv"
    if not (shared_data / rel).is_file():
        pytest.skip(f"{rel} not in this copy of the shared data")
    head = (shared_data / rel).read_text(encoding="latin-1")
    la = re.search(r"\*\* Latitude:\s+([NS])(\d+) ([\d.]+)", head)
    lo = re.search(r"\*\* Longitude:\s+([EWew])(\d+) ([\d.]+)", head)
    lat = (1 if la.group(1) == "N" else -1) * (int(la.group(2)) + float(la.group(3)) / 60)
    lon = (1 if lo.group(1).upper() == "E" else -1) * (int(lo.group(2)) + float(lo.group(3)) / 60)
    _, _, ctx = _run_dive(tmp_path, shared_data, rel)
    with netCDF4.Dataset(ctx.store.latest(ctx.dive_id, "profile").file("profile.nc")) as nc:
        assert int(nc["row_size"][:].sum()) == len(nc.dimensions["obs"])
        assert nc["profile_id"].dtype == np.dtype("S1") and nc["profile_id"].cf_role == "profile_id"
        z = nc["depth_m"]
        assert (z.axis, z.positive, z.standard_name) == ("Z", "down", "depth")
        assert nc.featureType in ("profile", "trajectoryProfile")
        assert nc.cdm_profile_variables.split(",")[0] == "profile_id"
        np.testing.assert_allclose(nc["lat"][:], lat, atol=1e-6)
        np.testing.assert_allclose(nc["lon"][:], lon, atol=1e-6)
        assert "header position" in nc["lat"].comment and "dead-reckoned" in nc["lat"].comment


def test_report_draws_a_real_prior_grid_on_a_geographic_map(shared_data, tmp_path):
    """A real COARDS grid (0-360 longitudes, z in km) as the dive's DTM: the report's DTM map spans the dtm product's
    own lon/lat (read here with xarray, the oracle) on equal ground distances, and the coverage/uncertainty figure is
    skipped with the reason (a prior grid has no soundings), in summary.json and the page."""
    import math

    import numpy as np
    import xarray as xr

    from hadal.report import FigureOptions, load_products
    from hadal.report.geo_figures import fig_dtm_geo

    _, _, ctx = _run_dive(tmp_path, shared_data, "dives-real/gmt_HI_topo_04.nc")
    with xr.open_dataset(ctx.store.latest(ctx.dive_id, "dtm").file("dtm.nc")) as ds:
        lon, lat = ds["lon"].values, ds["lat"].values
    summary = json.loads(ctx.store.latest(ctx.dive_id, "report").file("summary.json").read_text())
    assert summary["figures"]["dtm_map"] == "ok"
    assert "prior grid" in summary["figures"]["dtm_quality"]
    fr = fig_dtm_geo(load_products(ctx.store, ctx.dive_id), FigureOptions(dpi=40, keep_figure=True))
    ax = fr.figure.axes[0]
    assert ax.get_xlim() == pytest.approx((np.nanmin(lon), np.nanmax(lon)), abs=1e-12)
    assert ax.get_ylim() == pytest.approx((np.nanmin(lat), np.nanmax(lat)), abs=1e-12)
    assert ax.get_aspect() == pytest.approx(1 / math.cos(math.radians(0.5 * (np.nanmin(lat) + np.nanmax(lat)))))
