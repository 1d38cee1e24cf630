"""Real files of the kinds in issue #43, round 2 (tests/data/real/README.md: provenance and licences).

Each test reads a real file another tool or instrument wrote and checks the content against an independent oracle
(laspy's own scaled coordinates with pyproj's transform of the file's own CRS, the file's header text, ...).
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

REAL = Path(__file__).parents[1] / "data" / "real"


def _real(name: str) -> Path:
    p = REAL / name
    if not p.is_file():
        pytest.skip(f"{name} not vendored")
    return p


def test_las_in_us_survey_feet_with_towgs84_stays_georeferenced():
    """laspy's test1_4.las: a WKT1 PROJCS with TOWGS84 (a pyproj BoundCRS) in US survey feet. The cloud is scaled
    to metres, and the CRS it is returned in must put those metres where the file's own CRS puts its feet
    (before: the metre axes were applied only to plain projected CRSs, so the grid was 400 km off)."""
    import laspy
    from pyproj import CRS, Transformer

    from hadal.grid.clouds import read_las

    p = _real("laspy_test1_4_nm_ftus.las")
    pts, meta = read_las(p)
    las = laspy.read(str(p))
    file_crs = las.header.parse_crs()
    assert meta["crs_kind"] == "projected" and meta["horizontal_units"] == "US survey foot"
    ftus = 1200 / 3937
    np.testing.assert_allclose(pts[:, 2], np.asarray(las.z) * ftus, rtol=1e-12)
    assert pts[:, 2].min() > 0  # elevation, up: not negated
    xy_crs = CRS.from_wkt(meta["xy_crs_wkt"])
    assert {ax.unit_name for ax in xy_crs.axis_info} == {"metre"}
    got = Transformer.from_crs(xy_crs, "EPSG:4326", always_xy=True).transform(pts[:, 0], pts[:, 1])
    ref = Transformer.from_crs(file_crs, "EPSG:4326", always_xy=True).transform(np.asarray(las.x), np.asarray(las.y))
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-9)  # degrees: well under a millimetre
    assert 35.99 < ref[1].min() and ref[0].max() < -106.0  # New Mexico, as the CRS says


def test_cnv_latitude_from_seasoft_channel_note_when_the_header_has_none(tmp_path):
    """castelao/seabird Hotin.cnv (SBE 19plus): no NMEA/user position, but SeaSoft wrote the latitude it used into
    the depth channel's name ('depSM: Depth [salt water, m], lat = 48.38'). That latitude is the cast's (before:
    45°). Oracle: SeaSoft's own depSM column, which UNESCO 44 reproduces at 48.38° and not at 45°."""
    import shutil

    from hadal.dive_init import scan_dive_dir
    from hadal.ingest.cnv import read_cnv
    from hadal.seawater import depth_fofonoff_millard

    p = _real("seabird_Hotin_sbe19plus.cnv")
    df = read_cnv(p)
    assert df.attrs["latitude_deg"] == pytest.approx(48.38)
    assert df.attrs["longitude_deg"] is None
    assert "depSM" in df.attrs["position_source"]["latitude"]
    pres, dep = df["prdM"].to_numpy(), df["depSM"].to_numpy()
    np.testing.assert_allclose(depth_fofonoff_millard(pres, df.attrs["latitude_deg"]), dep, rtol=0, atol=1.5e-3)
    assert np.abs(depth_fofonoff_millard(pres, 45.0) - dep).max() > 2e-3
    shutil.copy(p, tmp_path / p.name)
    res = scan_dive_dir(tmp_path)
    assert res.dive["sources"]["cnv"] == [p.name]
    assert not [t for t in res.todo if "latitude" in t]  # the cast carries its latitude: nothing to ask
    from hadal.ctd.derive import choose_position
    from hadal.dive import Dive
    from hadal.settings import DeriveParams

    meta = {"cast_latitude_deg": df.attrs["latitude_deg"], "cast": {"position_source": df.attrs["position_source"]}}
    pos = choose_position(DeriveParams(), Dive.model_validate({"dive_id": "hotin"}), meta)
    assert pos["latitude_deg"] == pytest.approx(48.38)
    assert "depSM" in pos["latitude_source"] and "NMEA" not in pos["latitude_source"]  # says where it came from



def test_map_frame_at_the_cast_on_a_prior_grid_not_at_the_grid_centre(tmp_path):
    """A cast beside a coarse grid (castelao/seabird SK287_CTD05.cnv, SBE 9 with NMEA 02 26.71 S 080 28.68 E, on
    a 15° x 15° grid of the eastern Indian Ocean): the DTM and the suitability analysis are wanted at the cast,
    not at the grid's centre 850 km away. Oracle: the cast's NMEA header lines."""
    import shutil

    import xarray as xr

    from hadal.dive_init import scan_dive_dir

    cast = _real("seabird_SK287_CTD05.cnv")
    shutil.copy(cast, tmp_path / cast.name)
    lon, lat = np.arange(75.0, 90.01, 0.25), np.arange(-10.0, 5.01, 0.25)
    z = -4000.0 - 100.0 * np.sin(lon)[None, :] * np.cos(lat)[:, None]
    xr.Dataset({"z": (("lat", "lon"), z, {"units": "m", "long_name": "elevation"})},
               coords={"lon": ("lon", lon, {"units": "degrees_east"}),
                       "lat": ("lat", lat, {"units": "degrees_north"})}).to_netcdf(tmp_path / "bay_of_bengal.nc")
    res = scan_dive_dir(tmp_path)
    grids = [g if isinstance(g, str) else g["path"] for g in res.dive["sources"]["prior_grid"]]
    assert grids == ["bay_of_bengal.nc"] and res.dive["sources"]["cnv"] == [cast.name]
    mf = res.dive["map_frame"]
    assert mf["origin_latitude_deg"] == pytest.approx(-(2 + 26.71 / 60), abs=1e-3)
    assert mf["origin_longitude_deg"] == pytest.approx(80 + 28.68 / 60, abs=1e-3)
    assert any(m.startswith("map_frame: the position of the cast(s)") for m in res.mapped)


def _sbs_16plus_digiquartz_peer(p: Path) -> dict[str, np.ndarray]:
    """seabirdscientific's own path for its 16plus_digiquartz.hex: its decoder (``read_hex_file`` with
    ``Sensors.DigiquartzPressure``, as in its test_instrument_data.py) and its conversions, with the coefficients
    typed in from the file's <CalibrationCoefficients> and Sea-Bird's AD590 defaults for the 16plus V2."""
    import seabirdscientific.cal_coefficients as sbc
    import seabirdscientific.conversion as sbconv
    import seabirdscientific.instrument_data as sbid

    raw = sbid.read_hex_file(p, sbid.InstrumentType.SBE16Plus, [sbid.Sensors.Temperature,
                             sbid.Sensors.Conductivity, sbid.Sensors.DigiquartzPressure])
    t = sbconv.convert_temperature(raw["temperature"].values, sbc.TemperatureCoefficients(
        1.271257e-03, 2.720604e-04, -9.909794e-07, 1.735758e-07), "ITS90", "C", use_mv_r=True)
    pq = sbc.PressureDigiquartzCoefficients(2.289226e02, -2.841870e-03, -2.208090e-05, 3.769400e-02, 0.0,
                                            2.776567e01, -1.796980e-04, 1.148220e-06, 1.282930e-09, 0.0)
    # SampleInterval 1800 s: the 30 s compensation average is each scan alone
    pr = sbconv.convert_pressure_digiquartz(raw["digiquartz pressure"].values,
                                            raw["temperature compensation"].values, pq, "dbar", 30.0)
    c = sbconv.convert_conductivity(raw["conductivity"].values, t, pr, sbc.ConductivityCoefficients(
        -9.952793e-01, 1.380221e-01, -1.019730e-04, 2.587865e-05, -9.570000e-08, 3.250000e-06, 0.0),
        sbid.InstrumentType.SBE16Plus, "S/m")
    return {"raw": raw, "t": t, "p": pr, "c": c}


def test_sbe16plus_digiquartz_hex_is_decoded_and_converted():
    """seabirdscientific's 16plus_digiquartz.hex (SBE 16plus V2, Digiquartz 'quartzTC-0', QUARTZ0 coefficients in
    its XML header; <OutputFormat> 'converted decimal' is the real-time setting, the 17 scans are raw hex). Before:
    refused. Oracles: the raw values seabirdscientific's own test publishes for this file (first and last scan),
    and seabirdscientific's decoder + conversions run here on the same file. No SeaSoft .cnv of it is published;
    physically the instrument is in air: conductivity at its zero-conductivity frequency (|C| < 1e-4 S/m) and the
    Digiquartz near atmospheric pressure (sea pressure 0.39-0.43 dbar, within 0.1 % of its 44 psia range)."""
    from hadal.ingest.seabird_hex import describe_hex, read_hex

    p = _real("sbs_16plus_digiquartz.hex")
    df = read_hex(p, raw=True)
    assert len(df) == 17 and df.attrs["pressure_sensor"] == "quartz" and df.attrs["model"] == "SBE 16plus V2"
    assert [c["name"] for c in df.attrs["channels"]][:4] == ["tv290C", "c0S/m", "prDM", "timeS"]
    assert [c["name"] for c in describe_hex(p)["channels"]][:3] == ["tv290C", "c0S/m", "prDM"]
    # seabirdscientific tests/test_instrument_data.py::TestReadHex16plusDigiquartz, first and last scan
    assert (df["f0"].iloc[0], df["f0"].iloc[-1]) == (407128, 468996)
    assert (df["f1"].iloc[0], df["f1"].iloc[-1]) == (687669 / 256, 687669 / 256)
    assert (df["f2"].iloc[0], df["f2"].iloc[-1]) == (8906797 / 256, 8905702 / 256)
    assert (df["f3"].iloc[0], df["f3"].iloc[-1]) == (1571, 1566)
    peer = _sbs_16plus_digiquartz_peer(p)
    np.testing.assert_array_equal(df["f3"], peer["raw"]["temperature compensation"].values)
    # SeaSoft prints tv290C to 1e-4 degC, c0S/m to 1e-6 S/m, prDM to 1e-3 dbar
    np.testing.assert_allclose(df["tv290C"], peer["t"], rtol=0, atol=5e-5)
    np.testing.assert_allclose(df["c0S/m"], peer["c"], rtol=0, atol=5e-7)
    np.testing.assert_allclose(df["prDM"], peer["p"], rtol=0, atol=5e-4)
    assert np.abs(df["c0S/m"]).max() < 1e-4
    assert 0.3 < df["prDM"].min() and df["prDM"].max() < 0.5
    assert df.attrs["interval"] == {"kind": "seconds", "value": 1800.0}  # <SamplingParameters><SampleInterval>
    assert df.attrs["start_time_utc"] == "2016-10-05T18:30:05+00:00"  # seabirdscientific's 'date time', scan 0
    np.testing.assert_array_equal(df["timeS"], np.arange(17) * 1800.0)


def test_a_dive_of_only_the_sbe16plus_digiquartz_hex_gets_its_ctd_product_and_report(tmp_path):
    """From init to the report, a dive made of the Digiquartz .hex alone: init maps it as a cast, the ctd product
    carries its temperature, conductivity and Digiquartz pressure (oracle: seabirdscientific's path, as above)
    and the report is published."""
    import shutil

    import pandas as pd

    from hadal.dive_init import scan_dive_dir, write_init
    from hadal.pipeline import make_context, run_stage

    p = _real("sbs_16plus_digiquartz.hex")
    raw = tmp_path / "dq"
    raw.mkdir()
    shutil.copy(p, raw / p.name)
    res = scan_dive_dir(raw)
    assert res.dive["sources"]["cnv"] == [p.name] and not res.not_used
    write_init(res)
    ctx = make_context(raw, tmp_path / "store")
    run_stage("ingest", ctx)
    ctd = pd.read_parquet(run_stage("derive", ctx)["ctd"].file("ctd.parquet"))
    peer = _sbs_16plus_digiquartz_peer(p)
    assert len(ctd) == 17
    np.testing.assert_allclose(ctd["temperature_its90_degc"], peer["t"], rtol=0, atol=5e-5)
    np.testing.assert_allclose(ctd["pressure_ctd_dbar"], peer["p"], rtol=0, atol=5e-4)
    np.testing.assert_allclose(ctd["conductivity_s_m"], peer["c"], rtol=0, atol=5e-7)
    assert (ctd["pressure_source"] == "ctd").all()
    assert pd.Timestamp(ctd["time"].iloc[0]) == pd.Timestamp("2016-10-05T18:30:05Z")
    run_stage("profile", ctx)
    rv = run_stage("report", ctx)["report"]
    html = rv.file("report.html").read_text()
    assert p.name in html


def test_cloud_without_crs_gets_an_explicit_commented_crs_local_from_init(tmp_path):
    """laspy's simple.laz has no VLR at all (no CRS). init lists it with ``crs: local`` and a comment saying it
    is init's choice (rule 1: a fallback is written down where the user can change it); a LAS with a CRS gets
    no hint. Reading it with that hint gives laspy's own coordinates unchanged (metres, z up)."""
    import shutil

    import laspy
    import yaml

    from hadal.dive_init import scan_dive_dir, write_init
    from hadal.grid.clouds import read_las

    p = _real("laspy_simple_nocrs.laz")
    assert laspy.read(str(p)).header.parse_crs() is None
    shutil.copy(p, tmp_path / p.name)
    shutil.copy(_real("laspy_test1_4_nm_ftus.las"), tmp_path / "with_crs.las")
    res = scan_dive_dir(tmp_path)
    write_init(res)
    text = (tmp_path / "dive.yaml").read_text()
    laser = yaml.safe_load(text)["sources"]["laser"]
    assert {"path": p.name, "crs": "local"} in laser and "with_crs.las" in laser
    line = next(ln for ln in text.splitlines() if "crs: local" in ln)
    assert "hadal init's choice" in line and "no CRS" in line
    pts, meta = read_las(tmp_path / p.name, {"crs": "local"})
    las = laspy.read(str(p))
    np.testing.assert_array_equal(pts, np.column_stack([las.x, las.y, las.z]))
    assert meta["crs_from"] == "dive.yaml" and meta["z_positive"] == "up"


@pytest.mark.parametrize("name, sep", [("pdal_utm17_tab.pcd", "\t"), ("pdal_utm17_comma.pcd", ",")])
def test_ascii_pcd_with_tab_or_comma_separators(name, sep):
    """PDAL's utm17_tab.pcd / utm17_comma.pcd (PCD v0.7 ascii, F 4): pypcd4 splits on spaces only and read no
    point (before: "not a readable PCD point cloud"). Oracles: numpy's parse of the data block with the file's
    own separator (as float32, the file's TYPE F SIZE 4), and PDAL's utm17.las of the same 10 points (laspy)."""
    import laspy

    from hadal.grid.clouds import read_pcd

    p = _real(name)
    text = p.read_text()
    body = text.split("DATA ascii", 1)[1].strip()
    ref = np.loadtxt(body.splitlines(), delimiter=sep, dtype=np.float32).astype(np.float64)
    pts, meta = read_pcd(p)
    assert meta["fields"] == "X Y Z" and meta["z_positive"] == "up"
    np.testing.assert_array_equal(pts, ref)
    las = laspy.read(str(_real("pdal_utm17.las")))
    np.testing.assert_allclose(pts, np.column_stack([las.x, las.y, las.z]), rtol=0, atol=0.5)  # float32 at 4.3e6 m


def test_sonar_file_with_every_sounding_at_one_position_is_refused_by_init(tmp_path):
    """gsfpy's GSF 3.09 test file: 3 pings, every one at the same fix. Nothing can be gridded, so init lists it
    as not used in one line, with the position (before: listed, then the dtm stage failed at run time)."""
    import shutil

    from hadal.dive_init import scan_dive_dir

    p = _real("gsfpy_GSF3_09_test_file.gsf")
    shutil.copy(p, tmp_path / p.name)
    res = scan_dive_dir(tmp_path)
    assert not res.dive["sources"]
    (line,) = [n for n in res.not_used if n.startswith(p.name)]
    assert "one position (17.847152, -64.597074)" in line and "\n" not in line


def test_a_cast_without_descent_or_ascent_says_why_its_profiles_are_empty(tmp_path):
    """castelao/seabird SK287_CTD05.cnv holds 10 scans at 0.8-4.2 dbar (a surface soak): its descent and ascent
    profiles have no binned value. They say so, with the record's phases and pressure span, instead of being
    published silently empty. Oracle: the file's own prDM column (its range)."""
    import shutil

    import xarray as xr

    from hadal.dive_init import scan_dive_dir, write_init
    from hadal.ingest.cnv import read_cnv
    from hadal.pipeline import make_context, run_stage

    src = _real("seabird_SK287_CTD05.cnv")
    raw = tmp_path / "sk287"
    raw.mkdir()
    shutil.copy(src, raw / src.name)
    write_init(scan_dive_dir(raw))
    ctx = make_context(raw, tmp_path / "store")
    for name in ("ingest", "derive"):
        run_stage(name, ctx)
    pv = run_stage("profile", ctx)["profile"]
    pres = read_cnv(src)["prDM"].to_numpy()
    with xr.open_dataset(pv.file("profile.nc"), engine="h5netcdf") as ds:
        assert int(ds["row_size"].sum()) == 0
        note = ds.attrs["profile_empty_casts"]
    assert "descent:" in note and "ascent:" in note
    assert f"{pres.min():.1f}-{pres.max():.1f} dbar" in note and "bottom 10" in note
    manifest = json.loads((pv.path / "manifest.json").read_text())
    assert set(manifest["empty_casts"]) == {"descent", "ascent"}


def _slocum_dat(shared: Path) -> tuple[Path, list[str], dict[str, np.ndarray]]:
    """GUTILS' dbd2asc file (skips when absent): its path, sensor names and columns, parsed here by its own
    14-line header and 3 label lines."""
    src = shared / "dives-real" / "gutils_usf_bass_2016_252_1_14_sbd.dat"
    if not src.is_file():
        pytest.skip("gutils_usf_bass_2016_252_1_14_sbd.dat not in this copy of the shared data")
    lines = src.read_text().splitlines()
    names = lines[14].split()
    data = np.array([[float(v) for v in ln.split()] for ln in lines[17:] if ln.strip()])
    return src, names, {n: data[:, i] for i, n in enumerate(names)}


def test_slocum_all_zero_science_row_is_missing_data_not_zero_values(shared_data, tmp_path):
    """GUTILS' usf_bass_2016_252_1_14_sbd.dat (dbd2asc): its first cycle has every science-bay value exactly 0
    (sci_water_cond, sci_water_temp, sci_water_pressure, the optics and oxygen: the science computer's "no data"
    row), which was read as a 0 degC / 0 S/m / 0 dbar sample. pyglider's convention (slocum.py applies
    utils._zero_screen, ``val[val == 0] = nan``, to every science sensor) makes them missing: init writes the 0
    as a fill value with its reason, the ingest counts them by name, and no CTD sample is 0. Oracle: the file's
    own columns parsed here, screened as pyglider does."""
    import shutil

    import pandas as pd
    import yaml

    from hadal.dive_init import scan_dive_dir, write_init
    from hadal.pipeline import make_context, run_stage

    src, names, col = _slocum_dat(shared_data)
    sci = [n for n in names if n.startswith("sci_") and n != "sci_m_present_time"]
    zero_rows = np.all(np.stack([col[n] == 0 for n in sci]), axis=0)
    assert zero_rows.sum() == 1  # the file's first data row
    ctd = ("sci_water_cond", "sci_water_temp", "sci_water_pressure")
    screened = {n: np.where(col[n] == 0, np.nan, col[n]) for n in ctd}
    ctd_rows = np.any(np.stack([np.isfinite(screened[n]) for n in ctd]), axis=0)

    raw = tmp_path / "bass"
    raw.mkdir()
    shutil.copy(src, raw / src.name)
    write_init(scan_dive_dir(raw))
    text = (raw / "vehicle.yaml").read_text()
    fields = yaml.safe_load(text)["sensors"]["ctd"]["csv"]["fields"]
    assert {f["field"]: f.get("fill_values") for f in fields.values()} == {n: [0.0] for n in ctd}
    assert all("no-data value" in ln for ln in text.splitlines() if "fill_values: [0.0]" in ln)
    ctx = make_context(raw, tmp_path / "store")
    pv = run_stage("ingest", ctx)["sensors"]
    s = pd.read_parquet(pv.file("sensors.parquet"))
    assert len(s) == ctd_rows.sum()  # the all-zero cycle is no CTD sample
    t0 = pd.Timestamp(col["m_present_time"][zero_rows][0], unit="s", tz="UTC")
    assert (s["time"] - t0).abs().min() > pd.Timedelta(seconds=1)
    for var, n, k in (("conductivity_s_m", "sci_water_cond", 1.0), ("temperature_its90_degc", "sci_water_temp", 1.0),
                      ("pressure_ctd_dbar", "sci_water_pressure", 10.0)):
        got = s[var].to_numpy()
        assert not (got == 0).any()
        np.testing.assert_allclose(got, k * screened[n][ctd_rows], rtol=0, atol=1e-9)
    conv = json.loads((pv.path / "manifest.json").read_text())["ingest"]["unit_conversions"]
    counted = {c["variable"]: c["count"] for c in conv if c["formula"] == "fill value(s) 0 -> missing"}
    assert counted == {"conductivity_s_m": 1, "temperature_its90_degc": 1, "pressure_ctd_dbar": 1}


def test_sparse_glider_altimeter_is_not_held_for_a_minute(shared_data, tmp_path):
    """The Slocum .dat logs m_altitude once every ~74 s while its CTD samples every ~3.5 s. The altimeter's
    gap limit is widened to 1.5 of its intervals (111 s), and a nearest-sample value was then held on every CTD
    sample up to 55 s from its reading: the seafloor came out 12.4 m deep where the glider's own m_water_depth
    says 25-26 m, flagged good. A held reading now stands only within half the CTD's interval of its time.
    Oracle: the file's m_depth + m_altitude at each reading (the flight computer's own depth and range)."""
    import shutil

    import pandas as pd

    from hadal.dive_init import scan_dive_dir, write_init
    from hadal.pipeline import make_context, run_stage

    src, names, col = _slocum_dat(shared_data)
    ok = np.isfinite(col["m_altitude"])
    t_read = pd.to_datetime(col["m_present_time"][ok], unit="s", utc=True)
    floor = (col["m_depth"] + col["m_altitude"])[ok]
    raw = tmp_path / "bass"
    raw.mkdir()
    shutil.copy(src, raw / src.name)
    write_init(scan_dive_dir(raw))
    ctx = make_context(raw, tmp_path / "store")
    run_stage("ingest", ctx)
    ctd = pd.read_parquet(run_stage("derive", ctx)["ctd"].file("ctd.parquet"))
    inside = (t_read >= ctd["time"].iloc[0]) & (t_read <= ctd["time"].iloc[-1])
    got = ctd[ctd["altitude_m"].notna()]
    assert inside.sum() - 1 <= len(got) <= 2 * inside.sum()  # each reading on its nearest CTD sample(s)
    step_s = float(np.median(np.diff(ctd["time"].astype("int64")))) / 1e9
    for _, r in got.iterrows():
        k = int(np.argmin(np.abs((t_read - r["time"]).total_seconds())))
        assert abs((t_read[k] - r["time"]).total_seconds()) <= 0.5 * step_s + 1e-6
        assert r["altitude_m"] == col["m_altitude"][ok][k]
        assert r["seafloor_depth_m"] == pytest.approx(floor[k], abs=0.6)
    assert got["seafloor_depth_m"].min() > 20.0  # never the 12 m of a minute-old range
