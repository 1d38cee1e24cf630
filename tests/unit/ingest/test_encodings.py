"""Text in other encodings (issue 14 class 6): UTF-16 exports (Windows "Unicode text" from loggers and
spreadsheets) read like their UTF-8 original; binary files starting with the same bytes are not mistaken."""

from __future__ import annotations

import gzip

import numpy as np
import pytest

from hadal.formats import detect, open_binary, read_bytes, read_head, utf16_of
from hadal.ingest.csv_reader import describe_csv, read_sensor_csv
from hadal.ingest.vehicle import CsvSource

TEXT = "time,p_dbar,temp_degC\n" + "".join(f"2019-07-15T00:{k // 60:02d}:{k % 60:02d}Z,{100 + k * 0.5:.2f},"
                                              f"{2.5 - k * 1e-3:.4f}\n" for k in range(300))


@pytest.mark.parametrize("encoding", ["utf-16", "utf-16-le", "utf-16-be"])
@pytest.mark.parametrize("gz", [False, True])
def test_utf16_csv_reads_like_utf8(tmp_path, encoding, gz):
    raw = TEXT.encode(encoding)
    if encoding != "utf-16":  # explicit-endian codecs write no BOM; exporters do
        raw = ("\ufeff" + TEXT).encode(encoding)
    p16, p8 = tmp_path / "a16.csv", tmp_path / "a8.csv"
    p16.write_bytes(gzip.compress(raw) if gz else raw)
    p8.write_text(TEXT)
    assert detect(p16).kind == detect(p8).kind == "csv"
    assert read_head(p16, 100)[0] == TEXT.encode()[:100]
    assert read_bytes(p16)[0] == TEXT.encode()
    with open_binary(p16) as fh:
        assert fh.read() == TEXT.encode()
    m = CsvSource.model_validate({"source": "ctd", "time": {"field": "time", "format": "iso8601"},
                                  "fields": {"pressure_ctd_dbar": {"field": "p_dbar", "units": "dbar"}}})
    a, b = read_sensor_csv(p16, m, "ctd"), read_sensor_csv(p8, m, "ctd")
    np.testing.assert_array_equal(a.time_ns, b.time_ns)
    np.testing.assert_array_equal(a.values["pressure_ctd_dbar"], b.values["pressure_ctd_dbar"])
    assert describe_csv(p16)["rows"] == 300


def test_binary_starting_like_a_bom_is_not_text():
    rng = np.random.default_rng(0)
    blob = b"\xff\xfe" + rng.integers(0, 256, 4000, dtype=np.uint8).tobytes()
    assert utf16_of(blob) is None
    assert utf16_of(b"\xff\xfe" + "depth,lat\n".encode("utf-16-le")) == "utf-16"


def test_latin1_column_names_match_the_mapping(tmp_path):
    """A Windows Latin-1 header (``temp_°C``) matches a vehicle.yaml mapping written in UTF-8."""
    p = tmp_path / "l1.csv"
    p.write_bytes(TEXT.replace("temp_degC", "temp_°C").encode("cp1252"))
    m = CsvSource.model_validate({"source": "ctd", "time": {"field": "time", "format": "iso8601"},
                                  "fields": {"temperature_its90_degc": {"field": "temp_°C", "units": "degC_its90"}}})
    s = read_sensor_csv(p, m, "ctd")
    np.testing.assert_allclose(s.values["temperature_its90_degc"][:2], [2.5, 2.499])
    assert "temp_°C" in describe_csv(p)["columns"]
