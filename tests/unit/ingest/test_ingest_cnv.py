"""read_cnv on every real Sea-Bird file in shared/data/ctd-real plus synthetic edge cases."""

from __future__ import annotations

import json
import math
import warnings

import numpy as np
import pytest

from hadal.errors import InputError
from hadal.ingest import parse_latlon, read_cnv

# file -> (rows, ncols, first columns, latitude, longitude, start_time_utc, first-row check values)
REAL = {
    "seabird_sta0860.cnv": (88, 12, ["scan", "prDM", "t068C", "c0S/m"], -(25 + 27.85 / 60), 44 + 15.34 / 60,
                            "2008-08-28T12:33:46+00:00", {"prDM": 3.0, "t068C": 22.5007, "c0S/m": 5.104841,
                                                          "sal00": 35.4487, "sigma-t00": 24.4187, "svCM": 1528.70}),
    "seabird_dPIRX010.cnv": (1014, 11, ["timeS", "prDM", "t090C", "t190C", "c0S/m"], None, None,
                             "2008-04-17T00:56:37+00:00", {"timeS": 0.625, "prDM": 1.0, "t090C": 27.4365,
                                                           "sal00": 35.3159, "sal11": 35.7124}),
    "sbs_19plus_V2_CTD-processing_example.cnv": (3069, 8, ["tv290C", "c0S/m", "prdM"], None, None,
                                                 "2016-12-10T06:16:51+00:00",
                                                 {"tv290C": 20.4459, "c0S/m": 0.008453, "prdM": -0.105,
                                                  "sal00": 0.0476}),
    "oceissues644_02dk.cnv": (566, 26, ["scan", "prDM", "depSM", "t090C", "t190C", "c0mS/cm"], 69 + 24.75 / 60,
                              -(59 + 49.74 / 60), "2013-07-24T13:18:00+00:00",
                              {"prDM": 1.0, "depSM": 0.990, "t090C": 3.4711, "c0mS/cm": 29.215332}),
    "pyctd_CTD_with_sigma_e00.cnv": (199, 22, ["scan", "prDM", "t068C", "c0S/m"], 39 + 16.23 / 60,
                                     -(150 + 6.34 / 60), "2013-07-12T12:59:29+00:00",
                                     {"prDM": 2.0, "t068C": 19.7225, "c0S/m": 4.575058, "sal00": 33.4538}),
}


@pytest.mark.parametrize("name", sorted(REAL))
def test_read_real_cnv(shared_data, name):
    rows, ncols, first, lat, lon, start, values = REAL[name]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        df = read_cnv(shared_data / "ctd-real" / name)
    assert df.shape == (rows, ncols)
    assert list(df.columns[: len(first)]) == first
    a = df.attrs
    if lat is None:
        assert a["latitude_deg"] is None and a["longitude_deg"] is None
    else:
        assert a["latitude_deg"] == pytest.approx(lat, abs=1e-9)
        assert a["longitude_deg"] == pytest.approx(lon, abs=1e-9)
    assert a["start_time_utc"] == start
    for col, v in values.items():
        assert df[col].iloc[0] == pytest.approx(v, abs=1e-9), col
    # every channel described, spans parse, attrs JSON-serialisable, no bad_flag left in the data
    assert [c["column"] for c in a["channels"]] == list(df.columns)
    assert a["units"]["prDM" if "prDM" in df else "prdM"] == "db"
    assert not np.isclose(df.to_numpy(), -9.99e-29, rtol=1e-6, atol=0).any()
    assert any(k.lower().startswith("datcnv_") for k, _ in a["processing"])
    json.dumps(a)
    # span lines agree with the data for the pressure channel (binned files: exact)
    p = "prDM" if "prDM" in df else "prdM"
    span = next(c["span"] for c in a["channels"] if c["column"] == p)
    if not a["truncated"]:
        assert span == pytest.approx([df[p].min(), df[p].max()], abs=1e-3)


def test_real_cnv_details(shared_data):
    d = shared_data / "ctd-real"
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        oce = read_cnv(d / "oceissues644_02dk.cnv")
    # Latin-1 'sigma-é00' kept as in the file; header nvalues 1012 but 566 rows -> warned + flagged
    assert "sigma-é00" in oce.columns
    assert oce.attrs["truncated"] and oce.attrs["nvalues_declared"] == 1012
    assert any("nvalues" in str(x.message) for x in w)
    py = read_cnv(d / "pyctd_CTD_with_sigma_e00.cnv")
    assert "scan.1" in py.columns  # duplicated channel name
    assert py.attrs["bad_values"] == 5 and py["par"].isna().sum() == 3  # bad_flag -> NaN
    assert py.attrs["start_time_note"] == "NMEA time, first data scan"
    sbs = read_cnv(d / "sbs_19plus_V2_CTD-processing_example.cnv")
    assert sbs.attrs["interval"] == {"kind": "seconds", "value": 0.25}
    t = read_cnv(d / "seabird_sta0860.cnv")
    assert t.attrs["units"]["t068C"] == "ITS-68, deg C"
    assert [k for k, _ in t.attrs["processing"]][:3] == ["datcnv_date", "datcnv_in", "datcnv_skipover"]


@pytest.mark.parametrize(
    "text,is_lat,expected",
    [
        ("69 24.75 N", True, 69.4125),
        ("25 27.85 S", True, -25.464166666666667),
        ("059 49.74 W", False, -59.829),
        ("25°27.85'S", True, -25.464166666666667),
        ("N 25 27.85", True, 25.464166666666667),
        ("25 27 51 S", True, -(25 + 27 / 60 + 51 / 3600)),
        ("-25.4642", True, -25.4642),
        ("142.2097", False, 142.2097),
        ("none", True, None),
        ("91 00.00 N", True, None),
        ("25 61.00 N", True, None),
        ("25 27.85 E", True, None),
        ("", True, None),
    ],
)
def test_parse_latlon(text, is_lat, expected):
    got = parse_latlon(text, is_latitude=is_lat)
    if expected is None:
        assert got is None
    else:
        assert got == pytest.approx(expected, abs=1e-12)


HEADER = """* Sea-Bird SBE 9 Data File:
** Latitude: 11 20.00 N
** Longitude: 142 12.00 E
# nquan = 3
# nvalues = {n}
# units = specified
# name 0 = prDM: Pressure, Digiquartz [db]
# name 1 = t090C: Temperature [ITS-90, deg C]
# name 2 = c0S/m: Conductivity [S/m]
# span 0 = 1.000, 3.000
# start_time = Oct 06 2018 23:00:00 [System UTC, header]
# bad_flag = -9.990e-29
# datcnv_date = Oct 07 2018 01:00:00, 7.26
*END*
"""


def _write(tmp_path, body, n=3, name="x.cnv"):
    p = tmp_path / name
    p.write_text(HEADER.format(n=n) + body, encoding="latin-1")
    return p


def test_synthetic_cnv(tmp_path):
    body = ("      1.000     2.0000   3.000000\n"
            "      2.000 -9.990e-29   3.100000\n"
            "      3.000     2.2000   3.200000\n")
    df = read_cnv(_write(tmp_path, body))
    assert df.shape == (3, 3) and math.isnan(df["t090C"].iloc[1])
    assert df.attrs["latitude_deg"] == pytest.approx(11 + 1 / 3)
    assert df.attrs["longitude_deg"] == pytest.approx(142.2)
    assert df.attrs["start_time_utc"] == "2018-10-06T23:00:00+00:00"
    assert df.attrs["processing"] == [["datcnv_date", "Oct 07 2018 01:00:00, 7.26"]]


def test_touching_fixed_width_columns(tmp_path):
    # SeaSoft's 11-character fields may touch when a value fills its field
    body = "      1.000-1234.56789   3.000000\n"
    df = read_cnv(_write(tmp_path, body, n=1))
    assert df["t090C"].iloc[0] == pytest.approx(-1234.56789)


def test_corrupt_rows_dropped_with_warning(tmp_path):
    body = "      1.000     2.0000   3.000000\n  garbage here\n      3.000     2.2000   3.200000\n"
    with pytest.warns(UserWarning, match="dropped 1 unreadable"):
        df = read_cnv(_write(tmp_path, body, n=3))
    assert len(df) == 2 and df.attrs["rows_dropped"] == [len(HEADER.splitlines()) + 2]


@pytest.mark.parametrize(
    "content,match",
    [
        (b"", "empty"),
        (b"* Sea-Bird\n# name 0 = prDM: Pressure [db]\n1.0\n", "no '\\*END\\*'"),
        (b"* Sea-Bird\n*END*\n1.0\n", "no '# name"),
        (b"# nquan = 1\n# name 0 = prDM: Pressure [db]\n*END*\n", "no readable data"),
        (b"# nquan = x\n# name 0 = prDM: Pressure [db]\n*END*\n1\n", "invalid '# nquan"),
    ],
)
def test_bad_cnv_raises_input_error(tmp_path, content, match):
    p = tmp_path / "bad.cnv"
    p.write_bytes(content)
    with pytest.raises(InputError, match=match):
        read_cnv(p)
    with pytest.raises(InputError, match="does not exist"):
        read_cnv(tmp_path / "missing.cnv")


# ------------------------------------------------------------------ streaming (issue 14 class 12, issue 17 §5)
def _loadtxt_oracle(text: str, end_line: int, bad_flag: float = -9.990e-29) -> np.ndarray:
    """Brute force: every body line with three numbers, through NumPy's own text parser (bad_flag -> NaN)."""
    rows = []
    for ln in text.replace("\r\n", "\n").split("\n")[end_line + 1:]:
        try:
            rows.append(np.loadtxt([ln], ndmin=1))
        except ValueError:
            continue
    a = np.array([r for r in rows if r.size == 3])
    a[np.isclose(a, bad_flag, rtol=1e-6, atol=0)] = np.nan
    return a


@pytest.mark.parametrize("piece_bytes", [37, 256, 1 << 20])
@pytest.mark.parametrize("crlf", [False, True])
def test_streamed_body_matches_loadtxt_across_pieces(tmp_path, monkeypatch, piece_bytes, crlf):
    """The body is parsed in pieces of whole lines: whatever the piece size (a line split over blocks, a label
    line, bad lines, bad_flag values, CRLF), the rows equal NumPy loadtxt's reading of the same lines."""
    from hadal.ingest import cnv

    monkeypatch.setattr(cnv, "_PIECE_BYTES", piece_bytes)
    rng = np.random.default_rng(5)
    vals = rng.normal(size=(400, 3)) * [1000, 10, 1]
    vals[17, 1] = -9.990e-29
    lines = ["".join(f"{v:11.4f}" if abs(v) > 1e-20 else f"{v:11.3e}" for v in row) for row in vals]
    lines.insert(120, "  garbage here")
    lines.insert(0, "       prDM      t090C      c0S/m")  # a label line right after *END*
    text = HEADER.format(n=400) + "\n".join(lines) + "\n"
    if crlf:
        text = text.replace("\n", "\r\n")
    p = tmp_path / "s.cnv"
    p.write_bytes(text.encode("latin-1"))
    with pytest.warns(UserWarning, match="dropped 1 unreadable"):
        df = read_cnv(p)
    end_line = HEADER.splitlines().index("*END*")
    np.testing.assert_array_equal(df.to_numpy(), _loadtxt_oracle(text, end_line))
    assert df.attrs["column_labels"] == ["prDM", "t090C", "c0S/m"] and df.attrs["bad_values"] == 1
    assert df.attrs["rows_dropped"] == [end_line + 1 + 2 + 120] and not df.attrs["truncated"]


def test_no_false_truncation_warning_on_real_casts(shared_data):
    """Only a file that really lacks rows warns: oceissues644 declares 1012 scans and its pressure span reaches
    1012 dbar, but the copy holds rows to 566 dbar (cut); every other real file reads without a warning."""
    import glob

    files = sorted(glob.glob(str(shared_data / "ctd-real" / "*.cnv")) + glob.glob(str(shared_data / "formats-real" / "*.cnv")))
    assert len(files) >= 9
    for f in files:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            df = read_cnv(f)
        msgs = [str(w.message) for w in caught if "truncated" in str(w.message)]
        if f.endswith("oceissues644_02dk.cnv"):
            span_hi = next(c["span"][1] for c in df.attrs["channels"] if c["column"] == "prDM")
            assert span_hi == 1012.0 and df["prDM"].max() == 566.0 and len(msgs) == 1
        else:
            assert msgs == [], f
            assert df.attrs["nvalues_declared"] in (None, len(df))


@pytest.mark.parametrize("gz", [False, True])
def test_overlong_line_is_one_line_error(tmp_path, gz):
    """A 'line' longer than MAX_LINE_BYTES (binary junk, a missing line end) is refused with its line number,
    whether it ends inside a block or runs past it (streamed reading holds at most one such line)."""
    import gzip

    from hadal.ingest.csv_reader import MAX_LINE_BYTES

    for n in (MAX_LINE_BYTES + 10, 3 * MAX_LINE_BYTES):
        raw = HEADER.format(n=2).encode() + b"      1.000     2.0000   3.000000\n" + b"1" * n + b"\n"
        p = tmp_path / "long.cnv"
        p.write_bytes(gzip.compress(raw) if gz else raw)
        with pytest.raises(InputError, match=rf"line {len(HEADER.splitlines()) + 2} is .* bytes long"):
            read_cnv(p)
