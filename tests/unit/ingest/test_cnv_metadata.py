"""Sea-Bird casts read by their metadata (issue 43): the header's clocks check ``start_time``, the altimeter's
calibration says which readings are its no-bottom output, SeaSoft's ``sal00`` stands in for a missing
conductivity channel, and a cast's false echoes are flagged.

Oracles: the header text itself (times written in it), Sea-Bird application note AN95 (altimeter height =
300 V / ScaleFactor + Offset; no echo = 4.98 V of 5 V), the values written in the synthetic files.
"""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest

from hadal.ingest.cnv import (
    ALTIMETER_NO_ECHO_FRACTION,
    VENDOR_SALINITY,
    altimeter_full_scale_m,
    checked_start_time,
    cnv_sensor_samples,
    read_cnv,
)


def _clock(**kw: str) -> dict[str, tuple[str | None, str]]:
    return {k: (pd.Timestamp(v, tz="UTC").isoformat(), v) for k, v in kw.items()}


def test_two_digit_year_gets_the_upload_century():
    used, note = checked_start_time("1903-10-15T11:38:38+00:00", "Oct 15 1903 11:38:38", None,
                                    _clock(upload_time="2003-10-15 11:38:38"))
    assert used == "2003-10-15T11:38:38+00:00"
    assert "disagrees with System UpLoad Time" in note and "100 years" in note


def test_start_after_upload_uses_the_upload_time():
    used, note = checked_start_time("2015-06-01T00:00:00+00:00", "Jun 01 2015 00:00:00", None,
                                    _clock(upload_time="2012-03-04 05:06:07"))
    assert used == "2012-03-04T05:06:07+00:00" and "after it" in note


def test_nmea_utc_is_preferred_and_agreement_is_left_alone():
    used, note = checked_start_time("1999-01-01T00:00:00+00:00", "Jan 01 1999 00:00:00",
                                    "2011-04-01T07:26:31+00:00", _clock(upload_time="1999-01-01 00:00:00"))
    assert used == "2011-04-01T07:26:31+00:00" and "NMEA UTC (Time)" in note
    # a moored record uploaded months later, a cast a few seconds after its NMEA time: unchanged
    assert checked_start_time("2011-04-01T07:26:35+00:00", "", "2011-04-01T07:26:31+00:00", {}) == (
        "2011-04-01T07:26:35+00:00", None)
    assert checked_start_time("2010-01-01T00:00:00+00:00", "", None,
                              _clock(upload_time="2011-06-01 00:00:00"))[1] is None


def _cnv(tmp_path, names: list[str], rows: np.ndarray, xml: str = "", extra: str = "") -> pd.DataFrame:
    head = ["* Sea-Bird SBE 9 Data File:", extra, f"# nquan = {len(names)}", f"# nvalues = {len(rows)}"]
    head += [f"# name {i} = {n}" for i, n in enumerate(names)]
    head += ["# interval = seconds: 1", "# start_time = Apr 01 2011 07:26:35", "# bad_flag = -9.990e-29"]
    head += [f"# {ln}" for ln in xml.splitlines()]
    body = "\n".join("".join(f"{v:11.4f}" for v in r) for r in rows)
    p = tmp_path / "c.cnv"
    p.write_text("\n".join(h for h in head if h) + "\n*END*\n" + body + "\n", encoding="latin-1")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_cnv(p)


ALT_XML = """<Sensors count="1" >
  <sensor Channel="1" >
    <!-- A/D voltage 4, Altimeter -->
    <AltimeterSensor SensorID="0" >
      <SerialNumber>1</SerialNumber>
      <CalibrationDate>1 March 2010</CalibrationDate>
      <ScaleFactor>{sf}</ScaleFactor>
      <Offset>{off}</Offset>
    </AltimeterSensor>
  </sensor>
</Sensors>"""


@pytest.mark.parametrize(("channel", "to_m"), [("altM: Altimeter [m]", 1.0), ("altF: Altimeter [ft]", 0.3048)])
def test_altimeter_no_echo_from_the_calibration(tmp_path, channel, to_m):
    sf, off = 30.0, 0.5  # AN95: full scale = 300 x 5 V / 30 + 0.5 = 50.5 m
    volts = np.array([1.0, 2.0, 4.98, 4.94, 5.0, 0.5])
    alt_m = 300 * volts / sf + off
    n = len(volts)
    rows = np.column_stack([np.arange(n), np.arange(n, dtype=float), np.full(n, 10.0), np.full(n, 5.0),
                            np.full(n, 3.5), alt_m / to_m])
    df = _cnv(tmp_path, ["scan: Scan", "timeS: t [s]", "prDM: p [db]", "t090C: T [ITS-90, deg C]",
                         "c0S/m: C [S/m]", channel], rows, ALT_XML.format(sf=sf, off=off))
    fs, how = altimeter_full_scale_m(df.attrs)
    assert fs == pytest.approx(300 * 5 / sf + off) and "AltimeterSensor" in how
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        s = cnv_sensor_samples(df)
    got = s.values["altitude_m"]
    no_echo = volts * 300 / sf + off >= ALTIMETER_NO_ECHO_FRACTION * fs
    assert no_echo.tolist() == [False, False, True, True, True, False]
    np.testing.assert_allclose(got[~no_echo], alt_m[~no_echo], atol=2e-4)
    assert np.isnan(got[no_echo]).all()
    assert s.stats["altimeter"]["no_echo_readings"] == 3
    assert any("no-bottom output" in str(x.message) for x in w)


def test_altimeter_without_calibration_uses_a_saturated_plateau_only(tmp_path):
    n = 40
    base = np.column_stack([np.arange(n), np.arange(n, dtype=float), np.full(n, 10.0), np.full(n, 5.0),
                            np.full(n, 3.5)])
    names = ["scan: Scan", "timeS: t [s]", "prDM: p [db]", "t090C: T", "c0S/m: C [S/m]", "altM: Altimeter [m]"]
    plateau = np.r_[np.full(30, 99.6), np.linspace(20, 5, 10)]
    s = cnv_sensor_samples(_cnv(tmp_path, names, np.column_stack([base, plateau])))
    assert np.isnan(s.values["altitude_m"][:30]).all() and np.isfinite(s.values["altitude_m"][30:]).all()
    ramp = np.linspace(40, 2, n)  # a bottom approach, no saturation: every reading is a range
    s = cnv_sensor_samples(_cnv(tmp_path, names, np.column_stack([base, ramp])))
    np.testing.assert_allclose(s.values["altitude_m"], ramp, atol=1e-4)


def test_sal00_without_conductivity(tmp_path):
    rows = np.array([[1, 0, 2.0, 14.2, 29.9], [2, 1, 3.0, 14.1, 30.0], [3, 2, 4.0, 13.0, 30.5]])
    df = _cnv(tmp_path, ["scan: scan number", "timeS: time [s]", "pr: pressure [db]",
                         "t068: temperature, IPTS-68 [deg C]", "sal00: salinity, PSS-78 [PSU]"], rows)
    with pytest.warns(UserWarning, match="no conductivity channel"):
        s = cnv_sensor_samples(df)
    np.testing.assert_allclose(s.values[VENDOR_SALINITY], rows[:, 4])
    np.testing.assert_allclose(s.values["temperature_its90_degc"], rows[:, 3] / 1.00024)  # Saunders 1990
    assert "conductivity_s_m" not in s.values  # never back-computed from the salinity
    assert s.stats["salinity_method"] == "SeaSoft sal00 (vendor), no conductivity channel"


def test_no_conductivity_and_no_salinity_is_refused_in_one_line(tmp_path):
    from hadal.errors import InputError

    rows = np.array([[1, 0, 2.0, 14.2], [2, 1, 3.0, 14.1]])
    df = _cnv(tmp_path, ["scan: s", "timeS: t [s]", "pr: p [db]", "t068: T"], rows)
    with pytest.raises(InputError, match="no conductivity channel .*sal00"):
        cnv_sensor_samples(df)


def test_false_echoes_of_a_cast_are_flagged():
    from hadal.ctd.derive import flag_false_echoes

    depth = np.array([10.0, 100.0, 500.0, 1000.0, 990.0, 995.0])
    alt = np.array([np.nan, 50.0, 20.0, np.nan, 12.0, 4.0])  # 150 m and 520 m: above the 1000 m reached
    df = pd.DataFrame({"altitude_m": alt, "altitude_m_qc": np.where(np.isfinite(alt), 1, 9).astype(np.uint8)})
    out = flag_false_echoes(df, depth, [1, 2, 3])
    assert df["altitude_m_qc"].tolist() == [9, 4, 4, 9, 1, 1]
    assert out["readings_flagged"] == 2 and out["deepest_depth_m"] == 1000.0


def test_sbe37_hex_is_refused_in_one_line_naming_the_model(tmp_path):
    """An SBE 37 kind that is not decoded (ODO: SBE 63 oxygen): one line naming the model; hadal init lists it
    as not used."""
    from hadal.dive_init import scan_dive_dir
    from hadal.errors import InputError
    from hadal.ingest.cnv import read_seabird

    raw = tmp_path / "d"
    raw.mkdir()
    p = raw / "sbe37.hex"
    p.write_text("* Sea-Bird SBE37SMP-ODO Data File:\n* FileName = C:\\x.hex\n* Temperature SN = 12345\n"
                 "*END*\n0A1B2C3D4E5F60718293A4B5C6D7E8F9\n0A1B2C3D4E5F60718293A4B5C6D7E8F9\n")
    with pytest.raises(InputError, match=r"SBE 37SMP-ODO \.hex files .*not supported") as ei:
        read_seabird(p)
    assert "\n" not in str(ei.value)
    res = scan_dive_dir(raw)
    assert not res.dive.get("sources") and any("SBE 37SMP-ODO" in n for n in res.not_used)
