"""Glider logs through `hadal init` and the pipeline (issue 43): ALSEAMAR SeaExplorer `;`-delimited navigation +
payload logs and a Teledyne Slocum dbd2asc `.dat`, from ../shared/data/dives-real.

Oracles: the files' own columns (parsed here with the standard library, independently of hadal's readers), the
NMEA conversion as pyglider documents it, and pyglider's own L0 product of the SeaExplorer files (published
check values below).
"""

from __future__ import annotations

import csv
import datetime as dt
import math
import shutil
from pathlib import Path

import numpy as np
import pandas as pd
import pytest
import yaml
from dive_runs import run_quiet  # noqa: E402

from hadal.dive_init import scan_dive_dir, write_init

GLI = "dives-real/pyglider_sea035.12.gli.sub.36"
PLD = "dives-real/pyglider_sea035.12.pld1.sub.36"
SBD = "dives-real/gutils_usf_bass_2016_252_1_14_sbd.dat"
EM3000 = "dives-real/pdal_mbf_em300raw.all"

#: pyglider's L0 product of these two files (c-proof/pyglider @ 9e7bd9ab8e4c3d9f2c3fe5dd12dfdeaa618277b6 :
#: tests/data/l0-timeseries/dfo-eva035-20190718.nc, pyglider 0.0.7, created 2024-08-31T16:48:10Z), its first 26
#: records (time 2019-07-21T23:25:02.736 .. 23:37:32.822: the 26 rows of pld1.sub.36), read with xarray and copied
#: to 6 significant digits: salinity (gsw SP_from_C of GPCTD C, T, P) and heading/pitch/roll (navigation board,
#: interpolated by pyglider onto the payload times).
L0_SALINITY = [2.93561, 32.2003, 32.2141, 32.316, 32.3237, 32.3201, 32.3227, 32.324, 32.3251, 32.3199, 32.3248,
               32.3189, 32.321, 32.3294, 32.3426, 32.4083, 32.4339, 32.4024, 32.3621, 32.3424, 32.2992, 32.3303,
               32.3333, 32.3377, 32.3219, 32.3256]
L0_HEADING = [108.862, 87.0899, 88.1075, 95.2187, 86.2702, 87.2963, 89.6096, 89.7818, 92.0654, 92.373, 86.1956,
              95.5518, 91.8114, 64.5639, 61.6711, 61.7886, 62.3101, 59.1985, 52.536, 41.1403, 25.542, 337.335,
              306.542, 308.191, 294.234, 262.041]
L0_PITCH = [40.6892, -27.9792, -16.0048, -10.9833, -33.6051, -25.1579, -11.8295, -35.3846, -16.9945, -14.3829,
            -23.026, -15.3029, -36.0429, -57.6911, -33.1564, -26.6411, -9.43445, 8.23064, 12.3888, 10.3686, 7.81469,
            4.21044, 1.82178, 5.2364, 4.08914, 5.43665]
L0_ROLL = [0.318625, 6.43498, 2.29846, -3.74928, -5.85553, -4.44929, 3.73461, 2.15525, 2.06572, 2.19249, 5.33661,
           5.17507, 2.84623, -1.84809, 3.06953, 4.079, 3.4809, 3.32452, 3.43961, -8.67684, -18.9432, -9.5058,
           -2.85837, -3.046, -6.71797, 0.258315]


def _nmea(x: float) -> float:
    """pyglider ``utils.nmea2deg`` as documented: ``-12640.3232 -> -126.6721``."""
    deg, minutes = divmod(abs(x), 100.0)
    return math.copysign(deg + minutes / 60.0, x)


def _semicolon_table(path: Path) -> list[dict[str, str]]:
    with open(path, newline="") as fh:
        return [{k: v for k, v in r.items() if k} for r in csv.DictReader(fh, delimiter=";")]


def _dbd_table(path: Path) -> tuple[dict[str, str], list[str], list[str], np.ndarray]:
    """A dbd2asc file by its own header: tags, names, units and the data as floats (NaN kept)."""
    lines = path.read_text().splitlines()
    tags = dict(ln.split(":", 1) for ln in lines[:14])
    n = int(tags["num_ascii_tags"])
    k = int(tags["num_label_lines"])
    names, units = lines[n].split(), lines[n + 1].split()
    data = np.array([[float(v) for v in ln.split()] for ln in lines[n + k:] if ln.strip()])
    return tags, names, units, data


def _table(ctx, product: str) -> pd.DataFrame:
    return pd.read_parquet(ctx.store.latest(ctx.dive_id, product).file(f"{product}.parquet"))


# ------------------------------------------------------------------------------------------------ conventions


def test_nmea_conversion_and_masterdata_defaults():
    from hadal.ingest.glider import nmea_to_deg

    got = nmea_to_deg([-12640.3232, 4854.554, -13036.442, 2822.2511, 69696969.0, 4899.0, np.nan])
    assert got[0] == pytest.approx(-126.6721, abs=5e-5)  # pyglider's docstring example
    assert got[1:4] == pytest.approx([_nmea(4854.554), _nmea(-13036.442), _nmea(2822.2511)], abs=1e-12)
    assert np.isnan(got[4:]).all()  # Slocum masterdata default, minutes >= 60, missing


def test_kinds_are_recognised_by_content(shared_data, tmp_path):
    from hadal.formats import detect
    from hadal.ingest.csv_reader import describe_csv

    sbd = shared_data / SBD
    fk = detect(sbd)
    assert (fk.kind, fk.source, fk.points) == ("csv", "csv", False)  # not multibeam xyz
    tags, names, units, data = _dbd_table(sbd)
    d = describe_csv(sbd)
    assert d["glider"] == "slocum" and d["columns"] == names and d["rows"] == len(data)
    assert d["units"] == dict(zip(names, units, strict=True))
    assert d["header_tags"]["num_ascii_tags"] == tags["num_ascii_tags"].strip()
    t = data[:, names.index("m_present_time")]
    assert (d["time_column"], d["time_format"]) == ("m_present_time", "unix_s")
    assert pd.Timestamp(d["start_time"]) == pd.Timestamp(np.nanmin(t), unit="s", tz="UTC").floor("ms")
    lat = [_nmea(v) for v in data[:, names.index("m_lat")] if np.isfinite(v)]
    assert d["track"]["first_deg"][0] == pytest.approx(lat[0], abs=1e-9)

    for rel, tcol, fmt in ((GLI, "Timestamp", "%d/%m/%Y %H:%M:%S"), (PLD, "PLD_REALTIMECLOCK", "%d/%m/%Y %H:%M:%S.%f")):
        rows = _semicolon_table(shared_data / rel)
        d = describe_csv(shared_data / rel)
        assert (d["glider"], d["delimiter"], d["rows"], d["time_column"]) == ("seaexplorer", ";", len(rows), tcol)
        first = dt.datetime.strptime(rows[0][tcol], fmt).replace(tzinfo=dt.UTC)
        assert pd.Timestamp(d["start_time"]) == pd.Timestamp(first)
    # a renamed copy is recognised the same (by its columns, not its name)
    shutil.copy(shared_data / GLI, tmp_path / "nav.csv")
    assert describe_csv(tmp_path / "nav.csv")["glider"] == "seaexplorer"


# ------------------------------------------------------------------------------------------------ SeaExplorer


@pytest.fixture(scope="module")
def seaexplorer(shared_data, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("seaexplorer")
    raw = tmp / "sea035"
    raw.mkdir()
    for rel in (GLI, PLD):
        shutil.copy(shared_data / rel, raw / Path(rel).name)
    res = scan_dive_dir(raw)
    write_init(res)
    return res, raw, run_quiet(raw, tmp / "store")


def test_seaexplorer_mapping_written_by_init(seaexplorer, shared_data):
    res, raw, _ = seaexplorer
    text = (raw / "vehicle.yaml").read_text()
    v = yaml.safe_load(text)
    ctd, nav = v["sensors"]["ctd"]["csv"], v["sensors"]["navigation"]["csv"]
    assert v["time_base"] == "ctd"
    assert ctd["time"] == {"field": "PLD_REALTIMECLOCK", "format": "%d/%m/%Y %H:%M:%S.%f"}
    assert nav["time"] == {"field": "Timestamp", "format": "%d/%m/%Y %H:%M:%S"}
    assert (ctd["delimiter"], nav["delimiter"]) == (";", ";")
    assert {k: (f["field"], f["units"]) for k, f in ctd["fields"].items()} == {
        "conductivity_s_m": ("GPCTD_CONDUCTIVITY", "S/m"), "temperature_its90_degc": ("GPCTD_TEMPERATURE", "degC_its90"),
        "pressure_ctd_dbar": ("GPCTD_PRESSURE", "dbar")}
    assert nav["fields"]["altitude_m"] == {"field": "Altitude", "units": "m", "fill_values": [-1.0]}
    assert nav["fields"]["dr_east_m"]["transform"] == "latlon_ddmm_to_east_m"
    assert "-1 = no bottom detected" in text and "Temperature: navigation board's internal temperature" in text
    rows = _semicolon_table(shared_data / GLI)
    launch = res.dive["launch"]  # the glider's own first position, also the origin of its positions
    assert launch["latitude_deg"] == pytest.approx(_nmea(float(rows[0]["Lat"])), abs=1e-6)
    assert launch["longitude_deg"] == pytest.approx(_nmea(float(rows[0]["Lon"])), abs=1e-6)
    assert nav["fields"]["dr_east_m"]["origin"] == pytest.approx([launch["latitude_deg"], launch["longitude_deg"]],
                                                                 abs=1e-6)
    assert not any("overlap" in t for t in res.todo), res.todo  # one glider, one place, one time


def test_seaexplorer_sensors_match_the_files_and_pyglider_l0(seaexplorer, shared_data):
    _, _, ctx = seaexplorer
    assert {"sensors", "ctd", "profile", "report"} <= set(ctx.store.products(ctx.dive_id))
    s = _table(ctx, "sensors")
    pld = _semicolon_table(shared_data / PLD)
    t = [dt.datetime.strptime(r["PLD_REALTIMECLOCK"], "%d/%m/%Y %H:%M:%S.%f").replace(tzinfo=dt.UTC) for r in pld]
    assert list(s["time"]) == [pd.Timestamp(x) for x in t]
    for var, col in (("conductivity_s_m", "GPCTD_CONDUCTIVITY"), ("temperature_its90_degc", "GPCTD_TEMPERATURE"),
                     ("pressure_ctd_dbar", "GPCTD_PRESSURE")):
        assert s[var].to_numpy() == pytest.approx([float(r[col]) for r in pld], abs=1e-9), var
    # the altimeter's -1 ("no bottom") is missing data, never a value: ingest goes on
    gli = _semicolon_table(shared_data / GLI)
    assert any(float(r["Altitude"]) == -1 for r in gli)
    assert not (s["altitude_m"] == -1).any() and s["altitude_m"].isna().sum() >= 20
    # attitude on the payload times: pyglider's L0 interpolation, where hadal's gap rule keeps a value
    # (pyglider interpolates heading linearly, also across north; there the oracle is the file's two headings
    # interpolated the short way round)
    tg = np.array([dt.datetime.strptime(r["Timestamp"], "%d/%m/%Y %H:%M:%S").replace(tzinfo=dt.UTC).timestamp()
                   for r in gli])
    hg = np.array([float(r["Heading"]) for r in gli])
    tp = np.array([x.timestamp() for x in t])
    j = np.searchsorted(tg, tp)
    wraps = np.abs(hg[np.clip(j, 1, len(hg) - 1)] - hg[np.clip(j - 1, 0, len(hg) - 2)]) > 180
    short = np.degrees(np.unwrap(np.radians(hg)))
    heading = np.where(wraps, np.mod(np.interp(tp, tg, short), 360.0), L0_HEADING)
    assert wraps.sum() >= 1
    for var, l0 in (("heading_deg", heading), ("pitch_deg", L0_PITCH), ("roll_deg", L0_ROLL)):
        got = s[var].to_numpy()
        ok = np.isfinite(got)
        assert ok.sum() >= 20, var
        assert got[ok] == pytest.approx(np.asarray(l0)[ok], abs=2e-3, rel=1e-5), var


def test_seaexplorer_salinity_and_track(seaexplorer, shared_data):
    _, _, ctx = seaexplorer
    c = _table(ctx, "ctd")
    good = (c["practical_salinity_qc"] == 1).to_numpy()
    assert good.sum() >= 20
    assert c["practical_salinity"].to_numpy()[good] == pytest.approx(np.asarray(L0_SALINITY)[good], abs=2e-4)
    # positions: the navigation board's NMEA Lat/Lon, converted here, at the payload times
    gli = _semicolon_table(shared_data / GLI)
    tg = np.array([dt.datetime.strptime(r["Timestamp"], "%d/%m/%Y %H:%M:%S").replace(tzinfo=dt.UTC).timestamp()
                   for r in gli])
    lat = np.array([_nmea(float(r["Lat"])) for r in gli])
    lon = np.array([_nmea(float(r["Lon"])) for r in gli])
    tc = c["time"].map(lambda x: x.timestamp()).to_numpy()
    ok = np.isfinite(c["lat"].to_numpy()) & (c["dr_east_m_qc"] == 1).to_numpy()
    assert ok.sum() >= 20
    assert c["lat"].to_numpy()[ok] == pytest.approx(np.interp(tc, tg, lat)[ok], abs=2e-6)
    assert c["lon"].to_numpy()[ok] == pytest.approx(np.interp(tc, tg, lon)[ok], abs=2e-6)


# ------------------------------------------------------------------------------------------------ Slocum


@pytest.fixture(scope="module")
def slocum(shared_data, tmp_path_factory):
    tmp = tmp_path_factory.mktemp("slocum")
    raw = tmp / "bass"
    raw.mkdir()
    shutil.copy(shared_data / SBD, raw / Path(SBD).name)
    res = scan_dive_dir(raw)
    write_init(res)
    return res, raw, run_quiet(raw, tmp / "store")


def test_slocum_mapping_uses_the_units_line(slocum, shared_data):
    _, raw, _ = slocum
    _, names, units, _ = _dbd_table(shared_data / SBD)
    unit = dict(zip(names, units, strict=True))
    v = yaml.safe_load((raw / "vehicle.yaml").read_text())
    fields = {f["field"] if isinstance(f["field"], str) else tuple(f["field"]): f["units"]
              for s in v["sensors"].values() for f in s["csv"]["fields"].values()}
    assert unit["sci_water_pressure"] == "bar" and fields["sci_water_pressure"] == "bar"
    assert unit["m_heading"] == "rad" and fields["m_heading"] == "rad"
    assert unit["sci_water_cond"] == "s/m" and fields["sci_water_cond"] == "S/m"
    assert fields[("m_lat", "m_lon")] == "m"
    assert {s["csv"]["source"] for s in v["sensors"].values()} == {"gutils_usf_bass_2016_252_1_14_sbd"}
    assert v["sensors"]["ctd"]["csv"]["time"] == {"field": "m_present_time", "format": "unix_s"}


def test_slocum_sensors_match_the_file(slocum, shared_data):
    _, _, ctx = slocum
    _, names, _, data = _dbd_table(shared_data / SBD)
    col = {n: data[:, i] for i, n in enumerate(names)}
    for n in ("sci_water_cond", "sci_water_temp", "sci_water_pressure"):  # pyglider utils._zero_screen: 0 = no data
        col[n] = np.where(col[n] == 0, np.nan, col[n])
    ctd_rows = np.isfinite(col["sci_water_cond"]) | np.isfinite(col["sci_water_temp"]) | \
        np.isfinite(col["sci_water_pressure"])
    s = _table(ctx, "sensors")
    assert len(s) == ctd_rows.sum()  # a cycle without a CTD value is no CTD sample
    t_ns = np.round(col["m_present_time"][ctd_rows] * 1e9).astype(np.int64)
    assert np.abs(s["time"].astype("int64").to_numpy() - t_ns).max() < 2_000_000  # within 2 ms (spread duplicates)
    assert s["pressure_ctd_dbar"].to_numpy() == pytest.approx(10 * col["sci_water_pressure"][ctd_rows], abs=1e-9)
    assert s["conductivity_s_m"].to_numpy() == pytest.approx(col["sci_water_cond"][ctd_rows], abs=1e-12)
    assert s["temperature_its90_degc"].to_numpy() == pytest.approx(col["sci_water_temp"][ctd_rows], abs=1e-12)
    assert {"ctd", "profile", "report"} <= set(ctx.store.products(ctx.dive_id))


def test_slocum_gps_fixes_are_gnss_fixes(slocum, shared_data):
    """The log's own GPS fixes (m_gps_lat/m_gps_lon, NMEA, at the surface) become gnss_latitude/longitude_deg
    beside the dead-reckoned m_lat/m_lon track; oracle: the file's values parsed here (pyglider's nmea2deg): each
    fix in the sensor table is one of the logged fixes exactly (placed at its nearest CTD sample, never
    interpolated: hadal.ingest.align.align_fix), on distinct samples, and the fixes there are several."""
    _, raw, ctx = slocum
    v = yaml.safe_load((raw / "vehicle.yaml").read_text())
    g = v["sensors"]["gnss"]["csv"]["fields"]
    assert g["gnss_latitude_deg"] == {"field": "m_gps_lat", "units": "deg", "transform": "nmea_to_deg",
                                      "fill_values": [69696969.0]}
    assert g["gnss_longitude_deg"]["field"] == "m_gps_lon"
    _, names, _, data = _dbd_table(shared_data / SBD)
    col = {n: data[:, i] for i, n in enumerate(names)}
    ok = np.isfinite(col["m_gps_lat"]) & (np.abs(col["m_gps_lat"]) < 9000)
    lat = np.array([_nmea(x) for x in col["m_gps_lat"][ok]])
    lon = np.array([_nmea(x) for x in col["m_gps_lon"][ok]])
    s = _table(ctx, "sensors")
    got = s[["gnss_latitude_deg", "gnss_longitude_deg"]].dropna()
    assert 3 <= len(got) <= ok.sum()
    for a, o in zip(got["gnss_latitude_deg"], got["gnss_longitude_deg"], strict=True):
        assert np.any((np.abs(lat - a) < 1e-9) & (np.abs(lon - o) < 1e-9)), (a, o)


def test_slocum_units_come_from_the_file(shared_data, tmp_path):
    """The same file with its units line saying dbar for sci_water_pressure (and the heading in degrees written
    as such): init maps what the file says, and the values are read unscaled."""
    from hadal.ingest.csv_reader import read_sensor_csv
    from hadal.ingest.suggest import suggest_vehicle

    lines = (shared_data / SBD).read_text().splitlines(keepends=True)
    _, names, units, data = _dbd_table(shared_data / SBD)
    units[names.index("sci_water_pressure")] = "dbar"
    lines[15] = " ".join(units) + " \n"
    f = tmp_path / "edited.dat"
    f.write_text("".join(lines))
    v = suggest_vehicle([], {"g": f}).config()
    assert v is not None and v.sensors["ctd"].csv.fields["pressure_ctd_dbar"].units == "dbar"
    ctd = read_sensor_csv(f, v.sensors["ctd"].csv, "ctd")
    p = data[:, names.index("sci_water_pressure")]
    p = p[np.isfinite(p) & (p != 0)]  # 0 = the science bay's no data (pyglider utils._zero_screen)
    assert ctd.values["pressure_ctd_dbar"] == pytest.approx(p, abs=1e-12)
    nav = read_sensor_csv(f, v.sensors["navigation"].csv, "navigation")
    h = data[:, names.index("m_heading")]
    assert np.sort(nav.values["heading_deg"][np.isfinite(nav.values["heading_deg"])]) == \
        pytest.approx(np.sort(np.degrees(h[np.isfinite(h)])), abs=1e-9)
    # a mapping that contradicts the units line is named
    fm = v.sensors["ctd"].csv.fields["pressure_ctd_dbar"].model_copy(update={"units": "bar"})
    wrong = v.sensors["ctd"].csv.model_copy(update={"fields": {**v.sensors["ctd"].csv.fields, "pressure_ctd_dbar": fm}})
    with pytest.warns(UserWarning, match="sci_water_pressure.*'dbar' by the file's units line"):
        read_sensor_csv(f, wrong, "ctd")


# ------------------------------------------------------------------------------------------------ cross-source checks


def test_init_warns_when_sources_are_apart_and_frames_the_soundings(shared_data, tmp_path):
    """A Slocum glider off Cape Canaveral (2016) with EM3000 soundings of Tampa Bay (1999): init names both, the
    distance and the years between them, and puts the map frame on the soundings, not between them."""
    from pyproj import Geod

    raw = tmp_path / "apart"
    raw.mkdir()
    for rel in (SBD, EM3000):
        shutil.copy(shared_data / rel, raw / Path(rel).name)
    res = scan_dive_dir(raw)
    space = [t for t in res.todo if "do not overlap in space" in t]
    assert len(space) == 1 and "gutils_usf_bass_2016_252_1_14_sbd.dat" in space[0] and \
        "pdal_mbf_em300raw.all" in space[0], res.todo
    km = float(space[0].split(" km apart")[0].rsplit(" ", 1)[1])
    _, names, _, data = _dbd_table(shared_data / SBD)
    la, lo = data[:, names.index("m_lat")], data[:, names.index("m_lon")]
    i = int(np.argmax(np.isfinite(la)))
    # EM3000 position from dives-real/PROVENANCE.md (27.7594N 82.6328W); the glider track spans < 1 km
    oracle = Geod(ellps="WGS84").inv(-82.6328, 27.7594, _nmea(lo[i]), _nmea(la[i]))[2] / 1000
    assert km == pytest.approx(oracle, abs=2.0)
    assert any("do not overlap in time" in t and "1999-02-17" in t and "2016-09-09" in t for t in res.todo), res.todo
    frame = res.dive["map_frame"]
    assert frame["origin_latitude_deg"] == pytest.approx(27.7594, abs=1e-3)
    assert frame["origin_longitude_deg"] == pytest.approx(-82.6328, abs=1e-3)


def test_seaexplorer_payload_rows_of_other_instruments_are_no_ctd_samples(shared_data, tmp_path):
    """A raw payload log interleaves instruments row by row (pyglider drops the rows without CTD values); a
    gzip-compressed, renamed copy with an empty-CTD row after each real one reads as the 26 CTD samples."""
    import gzip

    from hadal.ingest.csv_reader import read_sensor_csv
    from hadal.ingest.suggest import suggest_vehicle

    lines = (shared_data / PLD).read_text().splitlines()
    n = len(lines[0].split(";"))
    out = [lines[0]]
    for ln in lines[1:]:
        out += [ln, ";".join([ln.split(";")[0], "117"] + [""] * (n - 2))]
    f = tmp_path / "payload.log.gz"
    f.write_bytes(gzip.compress(("\n".join(out) + "\n").encode()))
    v = suggest_vehicle([], {"p": f}).config()
    assert v is not None and v.sensors["ctd"].csv.fields["pressure_ctd_dbar"].field == "GPCTD_PRESSURE"
    ctd = read_sensor_csv(f, v.sensors["ctd"].csv, "ctd")
    rows = _semicolon_table(shared_data / PLD)
    assert len(ctd) == len(rows) and ctd.stats["rows_not_updated"] == len(rows)
    assert ctd.values["pressure_ctd_dbar"] == pytest.approx([float(r["GPCTD_PRESSURE"]) for r in rows], abs=1e-9)


def test_map_frame_on_the_glider_track_not_between_it_and_a_far_grid(shared_data, tmp_path):
    """The SeaExplorer pair beside lon/lat soundings (a 0.4° survey box around it) and a grid near Bermuda: the
    frame is at the glider's track (the data the match follows), the far grid is named, never the midpoint."""
    raw = tmp_path / "framed"
    raw.mkdir()
    for rel in (GLI, PLD, "bathy-real/tut_bathy.nc"):
        shutil.copy(shared_data / rel, raw / Path(rel).name)
    gli = _semicolon_table(shared_data / GLI)
    lat = [_nmea(float(r["Lat"])) for r in gli]
    lon = [_nmea(float(r["Lon"])) for r in gli]
    (raw / "survey.xyz").write_text("".join(f"{min(lon) - 0.1 + i * 0.02:.5f} {min(lat) - 0.2 + j * 0.02:.5f} "
                                            f"{2500 + i + j}\n" for i in range(21) for j in range(21)))
    res = scan_dive_dir(raw)
    assert sorted(res.dive["sources"]) == ["csv", "multibeam", "prior_grid"], res.dive["sources"]
    frame = res.dive["map_frame"]
    assert frame["origin_latitude_deg"] == pytest.approx((min(lat) + max(lat)) / 2, abs=1e-4)
    assert frame["origin_longitude_deg"] == pytest.approx((min(lon) + max(lon)) / 2, abs=1e-4)
    note = next(m for m in res.mapped if m.startswith("map_frame"))
    assert "vehicle track" in note and "not of tut_bathy.nc" in note, note
    space = [t for t in res.todo if "do not overlap in space" in t]
    assert len(space) == 1 and "tut_bathy.nc" in space[0] and "survey.xyz" in space[0], res.todo  # 2 groups
