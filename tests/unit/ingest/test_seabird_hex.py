"""read_hex / describe_hex: raw Sea-Bird .hex converted with its header calibration, checked against SeaSoft.

Oracle: ``ctd-real/sbs_19plus_V2_CTD-processing_example.cnv`` is SeaSoft DatCnv 7.26.7 output of the same cast
as ``formats-real/sbs_19plus_V2.hex`` (3069 scans; DatCnv only, no further processing step in its header). It
was converted with an .xmlcon whose coefficients have 9 significant digits, while the .hex header (``dcal``)
prints 7; the tolerances below are the .cnv's printed precision (tv290C 4 decimals, c0S/m 6, prdM 3), which the
7-digit coefficients still reach (measured: 5.2e-5 degC, 1.1e-6 S/m, 5.3e-4 dbar; with the .xmlcon's 9-digit
values the differences are pure rounding: 5.0e-5, 5.0e-7, 5.0e-4).
"""

from __future__ import annotations

import bz2
import gzip
import json
import lzma
import re
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from hadal.errors import InputError
from hadal.ingest.cnv import cnv_time_ns
from hadal.ingest.seabird_hex import describe_hex, read_hex

HEX = "formats-real/sbs_19plus_V2.hex"
CNV = "ctd-real/sbs_19plus_V2_CTD-processing_example.cnv"

# channel -> (max |hex - SeaSoft| allowed, the .cnv's printed resolution)
TOL = {"tv290C": 1e-4, "c0S/m": 1e-5, "prdM": 1e-3}
MEASURED_BOUND = {"tv290C": 6e-5, "c0S/m": 2e-6, "prdM": 6e-4}  # regression guard on what is reached today


@pytest.fixture(scope="module")
def hex_path(shared_data) -> Path:
    p = shared_data / HEX
    if not p.is_file():
        pytest.skip(f"{p} not present")
    return p


@pytest.fixture(scope="module")
def seasoft(shared_cnv):
    return shared_cnv(CNV)


@pytest.fixture(scope="module")
def converted(hex_path):
    return read_hex(hex_path, raw=True)


def _header_and_data(path: Path) -> tuple[list[str], list[str]]:
    lines = path.read_text(encoding="latin-1").splitlines()
    end = lines.index("*END*")
    return lines[:end], [ln for ln in lines[end + 1:] if ln.strip()]


def _write(path: Path, header: list[str], data: list[str]) -> Path:
    path.write_text("\r\n".join(header + ["*END*"] + data) + "\r\n", encoding="latin-1")
    return path


# ------------------------------------------------------------------------------------------ SeaSoft oracle
def test_real_hex_matches_seasoft_datcnv(converted, seasoft, shared_data):
    df = converted
    assert len(df) == len(seasoft) == 3069
    assert seasoft.attrs["nvalues"] == 3069
    # the oracle is DatCnv output only: no Filter/AlignCTD/CellTM/LoopEdit/WildEdit/BinAvg... line in its header
    text = (shared_data / CNV).read_text(encoding="latin-1")
    steps = set(re.findall(r"^# ([A-Za-z]+)_(?:date|in|vars)\b", text, re.M))
    assert steps == {"datcnv"}, steps
    for col, tol in TOL.items():
        d = np.abs(df[col].to_numpy() - seasoft[col].to_numpy())
        assert np.isfinite(d).all()
        assert d.max() <= tol, (col, d.max())
        assert d.max() <= MEASURED_BOUND[col], (col, d.max())
    # raw decoding is exact: SeaSoft's f0 (temperature A/D counts), f1 (conductivity Hz, 3 decimals), f2 (pressure)
    assert np.array_equal(df["f0"].to_numpy(), seasoft["f0"].to_numpy())
    assert np.array_equal(df["f2"].to_numpy(), seasoft["f2"].to_numpy())
    assert np.abs(df["f1"].to_numpy() - seasoft["f1"].to_numpy()).max() <= 5e-4 + 1e-9


def test_real_hex_attrs(converted, seasoft):
    a = converted.attrs
    json.dumps(a)  # JSON-serialisable, like read_cnv's
    assert a["model"] == "SBE 19plus V2" and a["serial_number"] == "6130" and a["firmware"] == "2.5.2"
    assert a["mode"] == "profile" and a["sample_rate_hz"] == 4.0
    assert a["interval"] == {"kind": "seconds", "value": 0.25}  # SeaSoft: '# interval = seconds: 0.25'
    assert a["start_time_utc"] == "2016-12-10T06:16:51+00:00"  # SeaSoft: 'Dec 10 2016 06:16:51 [Instrument's..]'
    assert a["processing"][0][0] == "datcnv" and a["processing"][0][1].startswith("hadal ")
    assert [c["name"] for c in a["channels"]][:7] == ["tv290C", "c0S/m", "prdM", "v0", "v1", "v2", "v3"]
    # Ext Volt 3 is off in the header, so SeaSoft's 4th voltage word (v3) is the physical Ext Volt 4
    assert a["channels"][6]["physical_channel"] == "Ext Volt 4"
    assert a["scan_layout"] == [["temperature", 6], ["conductivity", 6], ["pressure", 6], ["ptc", 4],
                                ["volt0", 4], ["volt1", 4], ["volt2", 4], ["volt4", 4]]
    sens = {s["kind"]: s for s in a["sensors"]}
    assert sens["temperature"]["calibration_date"] == "22-Jul-16"
    assert sens["pressure"]["serial_number"] == "2711888"
    assert sens["pressure"]["calibration_date"] == "21-Jul-16"
    assert a["calibration"]["temperature"]["TA0"] == pytest.approx(1.280156e-03)
    assert a["latitude_deg"] is None and a["longitude_deg"] is None  # no NMEA lines in this header
    # SeaSoft's span lines (printed precision) agree with ours
    for ch in a["channels"][:3]:
        lo, hi = next(c["span"] for c in seasoft.attrs["channels"] if c["name"] == ch["name"])
        assert ch["span"][0] == pytest.approx(lo, abs=TOL[ch["name"]])
        assert ch["span"][1] == pytest.approx(hi, abs=TOL[ch["name"]])
    # voltages are volts (counts / 13107), within the 0..5 V A/D range
    v = converted[["v0", "v1", "v2", "v3"]].to_numpy()
    assert (v >= 0).all() and (v <= 5.0).all()


def test_time_base(converted):
    t, how = cnv_time_ns(converted)
    assert len(t) == 3069 and "0.25" in how
    assert t[0] == pd.Timestamp("2016-12-10T06:16:51Z").value
    assert np.all(np.diff(t) == 250_000_000)


def test_decoder_matches_seabirdscientific(hex_path, converted):
    """hadal's vectorised decoder gives the same raw values as seabirdscientific's per-line reader."""
    from seabirdscientific import instrument_data as sid

    _, data = _header_and_data(hex_path)
    S = sid.Sensors
    enabled = [S.Temperature, S.Conductivity, S.Pressure, S.ExtVolt0, S.ExtVolt1, S.ExtVolt2, S.ExtVolt4]
    rows = [sid.read_hex(sid.InstrumentType.SBE19Plus, ln, enabled) for ln in data]
    ref = {k: np.array([r[k] for r in rows], dtype=float) for k in rows[0]}
    assert np.array_equal(ref["temperature"], converted["f0"].to_numpy())
    assert np.array_equal(ref["conductivity"], converted["f1"].to_numpy())
    assert np.array_equal(ref["pressure"], converted["f2"].to_numpy())
    for i, k in enumerate((0, 1, 2, 4)):
        assert np.allclose(ref[f"volt {k}"], converted[f"v{i}"].to_numpy(), rtol=0, atol=1e-12)


def test_describe_hex(hex_path):
    d = describe_hex(hex_path)
    json.dumps(d)
    assert d["scans"] == 3069 and d["sample_rate_hz"] == 4.0 and d["serial_number"] == "6130"
    assert d["model"] == "SBE 19plus V2" and d["mode"] == "profile"
    assert [c["name"] for c in d["channels"]] == ["tv290C", "c0S/m", "prdM", "v0", "v1", "v2", "v3"]
    assert d["calibration_dates"] == {"temperature": "22-Jul-16", "conductivity": "22-Jul-16",
                                      "pressure": "21-Jul-16"}
    assert d["start_time_utc"] == "2016-12-10T06:16:51+00:00"
    assert d["end_time_utc"] == "2016-12-10T06:29:38+00:00"  # 3068 scans * 0.25 s later


# ------------------------------------------------------------------------------------------ compressed input
@pytest.mark.parametrize("kind,opener,suffix", [("gzip", gzip.compress, ".hex.gz"), ("bz2", bz2.compress, ".hex.bz2"),
                                                ("xz", lzma.compress, ".hex.xz"), ("gzip", gzip.compress, ".hex")])
def test_compressed_copies_read_identically(hex_path, converted, tmp_path, kind, opener, suffix):
    p = tmp_path / f"cast{suffix}"  # the last case: gzip content under a plain .hex name (magic bytes decide)
    p.write_bytes(opener(hex_path.read_bytes()))
    df = read_hex(p, raw=True)
    pd.testing.assert_frame_equal(df, converted)
    assert df.attrs["compression"] == kind
    assert describe_hex(p)["scans"] == 3069


def test_truncated_compressed_file(hex_path, tmp_path):
    blob = gzip.compress(hex_path.read_bytes())
    p = tmp_path / "cut.hex.gz"
    p.write_bytes(blob[: len(blob) // 2])
    with pytest.raises(InputError, match="cut.hex.gz.*corrupt or truncated gzip"):
        read_hex(p)


# ------------------------------------------------------------------------------------------ bad input
def _one_line(exc: pytest.ExceptionInfo, path: Path) -> str:
    msg = str(exc.value)
    assert "\n" not in msg and str(path) in msg
    return msg


def test_truncated_last_line(hex_path, tmp_path):
    header, data = _header_and_data(hex_path)
    p = _write(tmp_path / "trunc.hex", header, data[:-1] + [data[-1][:20]])
    with pytest.raises(InputError) as e:
        read_hex(p)
    msg = _one_line(e, p)
    assert f"line {len(header) + 1 + len(data)}" in msg and "20 characters (truncated)" in msg and "38" in msg


def test_non_hex_character(hex_path, tmp_path):
    header, data = _header_and_data(hex_path)
    bad = list(data)
    bad[100] = bad[100][:7] + "G" + bad[100][8:]
    p = _write(tmp_path / "nonhex.hex", header, bad)
    with pytest.raises(InputError) as e:
        read_hex(p)
    msg = _one_line(e, p)
    assert "non-hexadecimal character 'G' at column 8" in msg and f"line {len(header) + 2 + 100}" in msg


@pytest.mark.parametrize("drop,what", [("TA1", "temperature (TA1)"), ("CPCOR", "conductivity (CPCOR)"),
                                       ("PTEMPA2", "pressure (PTEMPA2)")])
def test_missing_calibration(hex_path, tmp_path, drop, what):
    header, data = _header_and_data(hex_path)
    hdr = [ln for ln in header if not ln.strip().lstrip("*").strip().startswith(f"{drop} =")]
    assert len(hdr) == len(header) - 1
    p = _write(tmp_path / "nocal.hex", hdr, data)
    with pytest.raises(InputError) as e:
        read_hex(p)
    msg = _one_line(e, p)
    assert "lacks calibration coefficients" in msg and what in msg


def test_no_calibration_at_all(hex_path, tmp_path):
    header, data = _header_and_data(hex_path)
    hdr = header[:26]  # ds status only, no dcal block
    p = _write(tmp_path / "nodcal.hex", hdr, data)
    with pytest.raises(InputError, match="lacks calibration coefficients for temperature"):
        describe_hex(p)


@pytest.mark.parametrize("first,expect", [
    ("* Sea-Bird SBE 9 Data File:", "SBE 9 .hex files are not supported; supported: SBE 19plus V2"),
    # SBE 37 .hex files are decoded (issue 43): with a 19plus calibration block the SBE 37 coefficients are missing
    ("* Sea-Bird SBE37SM Data File:", "SBE 37SM .hex header lacks calibration coefficients for temperature (A0"),
    ("* Sea-Bird SBE 25plus Data File:", "SBE 25plus .hex files are not supported"),
])
def test_unsupported_instrument(hex_path, tmp_path, first, expect):
    header, data = _header_and_data(hex_path)
    p = _write(tmp_path / "other.hex", [first] + header[1:], data)
    with pytest.raises(InputError) as e:
        read_hex(p)
    assert expect in _one_line(e, p)


def test_original_19plus_firmware_refused(hex_path, tmp_path):
    header, data = _header_and_data(hex_path)
    hdr = [ln.replace("SBE 19plus V 2.5.2", "SeacatPlus V 1.4D") for ln in header]
    p = _write(tmp_path / "v1.hex", hdr, data)
    with pytest.raises(InputError, match="not V2.*supported: SBE 19plus V2"):
        read_hex(p)


def test_quartz_pressure_without_its_coefficients_refused(hex_path, tmp_path):
    header, data = _header_and_data(hex_path)
    hdr = [ln.replace("pressure sensor = strain gauge", "pressure sensor = quartz") for ln in header]
    p = _write(tmp_path / "quartz.hex", hdr, data)
    with pytest.raises(InputError, match=r"lacks calibration coefficients for pressure \(PC1, "):
        read_hex(p)


def test_wrong_channel_configuration(hex_path, tmp_path):
    header, data = _header_and_data(hex_path)
    hdr = [ln.replace("Ext Volt 3 = no", "Ext Volt 3 = yes") for ln in header]
    p = _write(tmp_path / "cfg.hex", hdr, data)
    with pytest.raises(InputError, match=r"line \d+: scan of 38 characters \(truncated\); the header's "
                                         r"configuration gives 42"):
        read_hex(p)


@pytest.mark.parametrize("content,expect", [
    (b"", "is empty"), (b"* Sea-Bird SBE19plus Data File:\n04FAD718466B\n", r"no '\*END\*' line"),
    (b"\x89PNG\r\n\x1a\n\x00\x00\x00", "binary content"),
])
def test_not_a_hex_file(tmp_path, content, expect):
    p = tmp_path / "x.hex"
    p.write_bytes(content)
    with pytest.raises(InputError, match=expect):
        read_hex(p)


def test_missing_file(tmp_path):
    with pytest.raises(InputError, match="does not exist"):
        read_hex(tmp_path / "nope.hex")


def test_no_scans(hex_path, tmp_path):
    header, _ = _header_and_data(hex_path)
    p = _write(tmp_path / "empty.hex", header, [])
    with pytest.raises(InputError, match="no data scans"):
        read_hex(p)


# ------------------------------------------------------------------------------------------ other header forms
def _xml_header(serial="01906130") -> list[str]:
    """The real file's configuration and calibration written as a SeatermV2 XML (GetHD/GetCD/GetCC) header."""
    x = f"""<InstrumentState>
<HardwareData DeviceType = 'SBE19plus' SerialNumber = '{serial}'>
   <FirmwareVersion>2.5.2</FirmwareVersion>
   <InternalSensors>
      <Sensor id = 'Main Pressure'>
         <type>strain-0</type>
         <SerialNumber>2711888</SerialNumber>
      </Sensor>
   </InternalSensors>
</HardwareData>
<ConfigurationData DeviceType = 'SBE19plus' SerialNumber = '{serial}'>
   <ProfileMode>
      <ScansToAverage>1</ScansToAverage>
   </ProfileMode>
   <DataChannels>
      <ExtVolt0>yes</ExtVolt0>
      <ExtVolt1>yes</ExtVolt1>
      <ExtVolt2>yes</ExtVolt2>
      <ExtVolt3>no</ExtVolt3>
      <ExtVolt4>yes</ExtVolt4>
      <ExtVolt5>no</ExtVolt5>
      <SBE38>no</SBE38>
      <WETLABS>no</WETLABS>
      <OPTODE>no</OPTODE>
      <SBE63>no</SBE63>
      <GTD>no</GTD>
   </DataChannels>
   <OutputFormat>raw HEX</OutputFormat>
</ConfigurationData>
<CalibrationCoefficients DeviceType = 'SBE19plus' SerialNumber = '{serial}'>
   <Calibration format = 'TEMP1' id = 'Main Temperature'>
      <SerialNum>{serial}</SerialNum>
      <CalDate>22-Jul-16</CalDate>
      <TA0>1.280156e-03</TA0>
      <TA1>2.583678e-04</TA1>
      <TA2>-1.395276e-08</TA2>
      <TA3>1.390246e-07</TA3>
      <TOFFSET>0.000000e+00</TOFFSET>
   </Calibration>
   <Calibration format = 'WBCOND0' id = 'Main Conductivity'>
      <SerialNum>{serial}</SerialNum>
      <CalDate>22-Jul-16</CalDate>
      <G>-1.023657e+00</G>
      <H>1.493062e-01</H>
      <I>-5.632062e-04</I>
      <J>6.518213e-05</J>
      <CPCOR>-9.570000e-08</CPCOR>
      <CTCOR>3.250000e-06</CTCOR>
      <CSLOPE>1.000000e+00</CSLOPE>
   </Calibration>
   <Calibration format = 'STRAIN0' id = 'Main Pressure'>
      <SerialNum>2711888</SerialNum>
      <CalDate>21-Jul-16</CalDate>
      <PA0>6.515467e-02</PA0>
      <PA1>1.544241e-03</PA1>
      <PA2>6.136531e-12</PA2>
      <PTCA0>5.241084e+05</PTCA0>
      <PTCA1>5.473716e+00</PTCA1>
      <PTCA2>-1.533652e-01</PTCA2>
      <PTCB0>2.590087e+01</PTCB0>
      <PTCB1>7.750000e-04</PTCB1>
      <PTCB2>0.000000e+00</PTCB2>
      <PTEMPA0>-6.286242e+01</PTEMPA0>
      <PTEMPA1>5.416207e+01</PTEMPA1>
      <PTEMPA2>-2.960267e-01</PTEMPA2>
      <POFFSET>0.000000e+00</POFFSET>
      <PRANGE>5.080000e+02</PRANGE>
   </Calibration>
   <Calibration format = 'VOLT0' id = 'Volt 0'>
      <OFFSET>-4.602000e-02</OFFSET>
      <SLOPE>1.252711e+00</SLOPE>
   </Calibration>
</CalibrationCoefficients>
</InstrumentState>"""
    return ["* Sea-Bird SBE19plus Data File:", "* FileName = C:\\data\\cast.hex", "* Software Version 2.8.0",
            "* System UpLoad Time = Dec 12 2016 13:25:15"] + [f"* {ln}" for ln in x.splitlines()] + \
        ["* cast   1 10 Dec 2016 06:16:51 samples 1 to 3069, avg = 1, stop = mag switch",
         "* NMEA Latitude = 36 48.12 N", "* NMEA Longitude = 121 47.50 W"]


def test_xml_header_form(hex_path, converted, tmp_path):
    _, data = _header_and_data(hex_path)
    p = _write(tmp_path / "xml.hex", _xml_header(), data)
    df = read_hex(p, raw=True)
    a = df.attrs
    assert a["header_form"] == "xml" and a["model"] == "SBE 19plus V2" and a["serial_number"] == "01906130"
    pd.testing.assert_frame_equal(df, converted)  # same coefficients -> same values
    assert a["calibration_dates"]["pressure"] == "21-Jul-16"
    assert a["latitude_deg"] == pytest.approx(36 + 48.12 / 60) and a["longitude_deg"] == pytest.approx(-121 - 47.5 / 60)
    assert a["start_time_utc"] == "2016-12-10T06:16:51+00:00"
    assert a["pressure_range_psia"] == 508.0


def test_xml_header_missing_coefficient(hex_path, tmp_path):
    _, data = _header_and_data(hex_path)
    hdr = [ln for ln in _xml_header() if "<PTCB1>" not in ln]
    p = _write(tmp_path / "xmlnocal.hex", hdr, data)
    with pytest.raises(InputError, match=r"pressure \(PTCB1\)"):
        read_hex(p)


def test_moored_mode_with_sbe38(hex_path, converted, tmp_path):
    """Moored mode: SBE 38 word after the voltages, then seconds since 2000-01-01 (UTC) at the end of a scan."""
    header, data = _header_and_data(hex_path)
    n = 50
    hdr = [ln.replace("mode = profile", "mode = moored, sample interval = 10 seconds")
           .replace("SBE 38 = no", "SBE 38 = yes") for ln in header]
    t0 = int((pd.Timestamp("2021-03-04T05:06:07Z") - pd.Timestamp("2000-01-01T00:00:00Z")).total_seconds())
    sbe38 = [f"{int(round((12.3456 + 0.001 * i + 10) * 100000)):06X}" for i in range(n)]
    lines = [data[i] + sbe38[i] + f"{t0 + 10 * i:08X}" for i in range(n)]
    p = _write(tmp_path / "moored.hex", hdr, lines)
    df = read_hex(p)
    a = df.attrs
    assert a["mode"] == "moored" and a["interval"] == {"kind": "seconds", "value": 10.0}
    assert a["start_time_utc"] == "2021-03-04T05:06:07+00:00"
    assert np.array_equal(df["timeS"].to_numpy(), 10.0 * np.arange(n))
    assert np.allclose(df["t3890C"].to_numpy(), 12.3456 + 0.001 * np.arange(n), atol=1e-9)
    for col in TOL:  # the CTD words are unchanged by the extra fields
        assert np.array_equal(df[col].to_numpy(), converted[col].to_numpy()[:n])
    t, how = cnv_time_ns(df)
    assert "timeS" in how and t[1] - t[0] == 10_000_000_000
    d = describe_hex(p)
    assert d["end_time_utc"] == "2021-03-04T05:14:17+00:00" and d["sample_rate_hz"] == pytest.approx(0.1)


def test_mode_inferred_from_scan_length(hex_path, tmp_path):
    """A header whose mode disagrees with the scans: read as the scans say, with a warning."""
    header, data = _header_and_data(hex_path)
    lines = [ln + f"{600000000 + i:08X}" for i, ln in enumerate(data[:10])]
    p = _write(tmp_path / "mode.hex", header, lines)
    with pytest.warns(UserWarning, match="header says profile mode"):
        df = read_hex(p)
    assert df.attrs["mode"] == "moored" and "timeS" in df


def test_cast_chosen_from_dh_listing(hex_path, converted, tmp_path):
    """The dh echo lists every cast in memory; the one with the file's scan count dates the file."""
    header, data = _header_and_data(hex_path)
    i = next(k for k, ln in enumerate(header) if ln.startswith("* cast   1"))
    casts = ["* cast   1 09 Dec 2016 22:00:00 samples 1 to 500, avg = 1, stop = mag switch",
             "* cast   2 10 Dec 2016 06:16:51 samples 501 to 3569, avg = 1, stop = mag switch",
             "* cast   3 11 Dec 2016 08:00:00 samples 3570 to 3600, avg = 1, stop = mag switch"]
    p = _write(tmp_path / "dh.hex", header[:i] + casts + header[i + 1:], data)
    df = read_hex(p)
    assert df.attrs["start_time_utc"] == "2016-12-10T06:16:51+00:00" and "timeS" not in df
    assert len(df.attrs["casts"]) == 3


def test_several_casts_in_one_file(hex_path, tmp_path):
    header, data = _header_and_data(hex_path)
    i = next(k for k, ln in enumerate(header) if ln.startswith("* cast   1"))
    casts = ["* cast   1 10 Dec 2016 06:16:51 samples 1 to 1000, avg = 1, stop = mag switch",
             "* cast   2 10 Dec 2016 07:00:00 samples 1001 to 3069, avg = 1, stop = mag switch"]
    p = _write(tmp_path / "two.hex", header[:i] + casts + header[i + 1:], data)
    with pytest.warns(UserWarning, match="holds 2 casts"):
        df = read_hex(p)
    t, how = cnv_time_ns(df)
    assert "timeS" in how
    assert t[999] - t[0] == 999 * 250_000_000
    assert t[1000] == pd.Timestamp("2016-12-10T07:00:00Z").value
    assert describe_hex(p)["end_time_utc"] == (pd.Timestamp("2016-12-10T07:00:00Z")
                                               + pd.Timedelta(seconds=2068 * 0.25)).isoformat()


def test_sbe16plus_v2(hex_path, converted, tmp_path):
    """An SBE 16plus V2 (moored only, no 'mode' line) with the same scan words plus the time."""
    header, data = _header_and_data(hex_path)
    hdr = [ln.replace("SBE19plus", "SBE16plus").replace("SBE 19plus V 2.5.2", "SBE 16plus V 2.5.2")
           for ln in header if "mode = profile" not in ln and not ln.startswith("* cast")]
    hdr.append("* sample interval = 900 seconds, number of measurements per sample = 1")
    t0 = 700000000
    p = _write(tmp_path / "sbe16.hex", hdr, [ln + f"{t0 + 900 * i:08X}" for i, ln in enumerate(data[:20])])
    df = read_hex(p)
    assert df.attrs["model"] == "SBE 16plus V2" and df.attrs["mode"] == "moored"
    assert df.attrs["interval"]["value"] == 900.0
    assert df.attrs["start_time_utc"] == (pd.Timestamp("2000-01-01T00:00:00Z")
                                          + pd.Timedelta(seconds=t0)).isoformat()
    assert np.array_equal(df["tv290C"].to_numpy(), converted["tv290C"].to_numpy()[:20])


def test_random_corruption_never_tracebacks(hex_path, tmp_path):
    """Flipped bytes, dropped or cut header lines, a file cut anywhere: a result or one-line InputError."""
    import random

    src = hex_path.read_bytes()
    lines = src.split(b"\n")
    p = tmp_path / "fuzz.hex"
    outcomes = {"ok": 0, "error": 0}
    for seed in range(80):
        r = random.Random(seed)
        op = seed % 4
        if op == 0:
            b = bytearray(src)
            for _ in range(r.randint(1, 5)):
                b[r.randrange(0, 4000)] = r.randrange(256)
            blob = bytes(b)
        elif op == 1:
            drop = r.randrange(0, 66)
            blob = b"\n".join(ln for i, ln in enumerate(lines) if i != drop)
        elif op == 2:
            cut = list(lines)
            i = r.randrange(0, 66)
            cut[i] = cut[i][: r.randrange(0, len(cut[i]) + 1)]
            blob = b"\n".join(cut)
        else:
            blob = src[: r.randrange(0, len(src))]
        p.write_bytes(blob)
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                read_hex(p)
            outcomes["ok"] += 1
        except InputError as exc:
            assert "\n" not in str(exc) and str(p) in str(exc)
            outcomes["error"] += 1
    assert outcomes["ok"] and outcomes["error"]


# ------------------------------------------------------------------------------------------------ SBE 37
#: an SBE 37-SM header as SeatermV2 writes it (GetHD / GetCD / GetCC echo); coefficients of a real cal sheet
_SBE37_HEADER = """* Sea-Bird SBE37SM-RS232  Data File:
* FileName = C:\\\\x\\\\SBE37SM-RS232_03716125.hex
* Software version SeatermV2 2.6.3.104
* Temperature SN = 16125
* Conductivity SN = 16125
* System UpLoad Time = Nov 16 2017 20:32:55
* <InstrumentState>
* <HardwareData DeviceType='SBE37SM-RS232' SerialNumber='03716125'>
*    <FirmwareVersion>4.1</FirmwareVersion>
*    <InternalSensors>
*       <Sensor id='Temperature'><type>temperature-1</type><SerialNumber>03716125</SerialNumber></Sensor>
*       <Sensor id='Conductivity'><type>conductivity-1</type><SerialNumber>03716125</SerialNumber></Sensor>
*       <Sensor id='Pressure'><type>strain-0</type><SerialNumber>10685588</SerialNumber></Sensor>
*    </InternalSensors>
* </HardwareData>
* <ConfigurationData DeviceType='SBE37SM-RS232' SerialNumber='03716125'>
*    <PressureInstalled>{pressure}</PressureInstalled>
*    <SampleInterval>90</SampleInterval>
* </ConfigurationData>
* <CalibrationCoefficients DeviceType='SBE37SM-RS232' SerialNumber='03716125'>
*    <Calibration format='TEMP1' id='Temperature'><SerialNum>03716125</SerialNum><CalDate>17-Aug-17</CalDate>
*       <A0>-1.898409e-04</A0><A1>3.136087e-04</A1><A2>-4.461848e-06</A2><A3>2.019781e-07</A3>
*    </Calibration>
*    <Calibration format='WBCOND0' id='Conductivity'><SerialNum>03716125</SerialNum><CalDate>17-Aug-17</CalDate>
*       <G>-1.001932e+00</G><H>1.284250e-01</H><I>-9.960452e-05</I><J>2.347041e-05</J>
*       <PCOR>-9.570000e-08</PCOR><TCOR>3.250000e-06</TCOR><WBOTC>-1.491050e-07</WBOTC>
*    </Calibration>
{pressure_cal}* </CalibrationCoefficients>
* </InstrumentState>
*END*
"""
_SBE37_PRESSURE_CAL = """*    <Calibration format='STRAIN0' id='Pressure'><SerialNum>10685588</SerialNum><CalDate>15-Aug-17</CalDate>
*       <PA0>1.054949e-03</PA0><PA1>4.853700e-04</PA1><PA2>-2.070713e-12</PA2>
*       <PTCA0>5.236075e+05</PTCA0><PTCA1>4.346490e+00</PTCA1><PTCA2>-1.758472e-01</PTCA2>
*       <PTCB0>2.526225e+01</PTCB0><PTCB1>6.500000e-04</PTCB1><PTCB2>0.000000e+00</PTCB2>
*       <PTEMPA0>-6.152156e+01</PTEMPA0><PTEMPA1>5.181662e-02</PTEMPA1><PTEMPA2>-2.894098e-07</PTEMPA2>
*       <POFFSET>0.000000e+00</POFFSET><PRANGE>1.600000e+02</PRANGE>
*    </Calibration>
"""


def _sbe37_file(tmp_path, pressure: bool = True):
    """An SBE 37-SM .hex built from the documented scan format (T counts 6, C frequency x 256 6, P counts 6,
    P temperature compensation counts 4, seconds since 2000 8 hex characters)."""
    rng = np.random.default_rng(37)
    n = 50
    t_counts = rng.integers(600_000, 700_000, n)
    c_x256 = rng.integers(int(4800 * 256), int(5600 * 256), n)
    p_counts = rng.integers(600_000, 640_000, n)
    ptc = rng.integers(1100, 1200, n)
    secs = 564_100_000 + 90 * np.arange(n)  # 2017-11-16, every 90 s
    lines = []
    for k in range(n):
        s = f"{t_counts[k]:06X}{c_x256[k]:06X}"
        if pressure:
            s += f"{p_counts[k]:06X}{ptc[k]:04X}"
        lines.append(s + f"{secs[k]:08X}")
    p = tmp_path / ("sbe37.hex" if pressure else "sbe37_nop.hex")
    header = _SBE37_HEADER.replace("{pressure}", "yes" if pressure else "no").replace(
        "{pressure_cal}", _SBE37_PRESSURE_CAL if pressure else "")
    p.write_text(header + "\n".join(lines) + "\n", encoding="latin-1")
    return p, secs


def test_sbe37_hex_against_seabirdscientific(tmp_path):
    """Oracle: seabirdscientific's own decoder (read_hex_file, SBE37SM) and conversions with the header's
    coefficients, and the SBE 37 manual's temperature / pressure equations written out here."""
    import seabirdscientific.cal_coefficients as sbc
    import seabirdscientific.conversion as sbconv
    import seabirdscientific.instrument_data as sbid

    from hadal.ingest.seabird_hex import read_hex

    path, secs = _sbe37_file(tmp_path)
    df = read_hex(path)
    ref = sbid.read_hex_file(path, sbid.InstrumentType.SBE37SM,
                             [sbid.Sensors.Temperature, sbid.Sensors.Conductivity, sbid.Sensors.Pressure])
    t_counts = ref["temperature"].values.astype(float)
    a0, a1, a2, a3 = -1.898409e-04, 3.136087e-04, -4.461848e-06, 2.019781e-07
    ln = np.log(t_counts)
    t90 = 1 / (a0 + a1 * ln + a2 * ln**2 + a3 * ln**3) - 273.15  # SBE 37 manual, no MV-R step
    np.testing.assert_allclose(df["tv290C"], t90, atol=1e-9)
    assert -5 < t90.min() and t90.max() < 35
    pc = sbc.PressureCoefficients(1.054949e-03, 4.853700e-04, -2.070713e-12, 5.236075e+05, 4.346490e+00,
                                  -1.758472e-01, 2.526225e+01, 6.500000e-04, 0.0, -6.152156e+01, 5.181662e-02,
                                  -2.894098e-07, offset=0.0)
    p_ref = sbconv.convert_pressure(ref["pressure"].values.astype(float),
                                    ref["temperature compensation"].values.astype(float), pc, "dbar")
    np.testing.assert_allclose(df["prdM"], p_ref, atol=1e-9)
    cc = sbc.ConductivityCoefficients(-1.001932e+00, 1.284250e-01, -9.960452e-05, 2.347041e-05, -9.57e-08,
                                      3.25e-06, -1.491050e-07)
    c_ref = sbconv.convert_conductivity(ref["conductivity"].values.astype(float), t90, p_ref, cc,
                                        sbid.InstrumentType.SBE37SM, "S/m")
    np.testing.assert_allclose(df["c0S/m"], c_ref, atol=1e-12)
    # time: seconds since 2000-01-01 UTC (seabirdscientific's naive datetimes are UTC)
    t0 = pd.Timestamp(ref["date time"].values[0]).tz_localize("UTC")
    assert pd.Timestamp(df.attrs["start_time_utc"]) == t0 == pd.Timestamp("2000-01-01", tz="UTC") + pd.Timedelta(
        seconds=int(secs[0]))
    np.testing.assert_allclose(df["timeS"], secs - secs[0])
    assert df.attrs["model"] == "SBE 37SM-RS232" and df.attrs["mode"] == "moored"


def test_sbe37_hex_without_pressure_and_odo_refused(tmp_path):
    from hadal.errors import InputError
    from hadal.ingest.seabird_hex import read_hex

    path, _ = _sbe37_file(tmp_path, pressure=False)
    df = read_hex(path)
    assert df["prdM"].isna().all() and np.isfinite(df["c0S/m"]).all()
    odo = tmp_path / "odo.hex"
    odo.write_text(path.read_text().replace("SBE37SM-RS232  Data File", "SBE37SMP-ODO-RS232 Data File"))
    with pytest.raises(InputError, match="SBE 37SMP-ODO-RS232 .hex files .*not supported"):
        read_hex(odo)
