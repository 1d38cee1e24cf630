"""GSF of every libgsf version: the EX1604 file (GSF-v03.06, NOAA Okeanos Explorer EM302 off Kwajalein) through both
libgsf builds gsfpy ships (3.08 and 3.09, ``DEFAULT_GSF_VERSION``) and relabelled as every 3.x version. Oracles: the
other libgsf build, the depth range the shared data's README publishes (3849-4309 m with flagged beams) and the
survey's published position (8.71 N 167.48 E).
"""

from __future__ import annotations

import pytest

GSF = "bathy-real/0029_20160323_185603_EX1604_MB.gsf.mb121"


@pytest.fixture(scope="module")
def gsf(shared_data):
    p = shared_data / GSF
    if not p.is_file():
        pytest.skip(f"{GSF} not present")
    return p


def _read(path, monkeypatch, lib, **kw):
    from hadal.grid.readers import read_gsf

    monkeypatch.setenv("DEFAULT_GSF_VERSION", lib)  # the child process that runs libgsf inherits it
    return read_gsf(path, **kw)


def test_both_libgsf_builds_read_the_same_soundings(gsf, monkeypatch):
    import pandas as pd

    from hadal.grid.readers import gsf_file_version

    assert gsf_file_version(gsf) == "03.06"
    a = _read(gsf, monkeypatch, "3.08")
    b = _read(gsf, monkeypatch, "3.09")
    assert a.attrs["libgsf"] == "3.08" and b.attrs["libgsf"] == "3.09" and a.attrs["gsf_version"] == "03.06"
    pd.testing.assert_frame_equal(a, b, check_exact=True)
    assert abs(a["latitude_deg"].mean() - 8.71) < 0.01 and abs(a["longitude_deg"].mean() - 167.48) < 0.01
    f = _read(gsf, monkeypatch, "3.08", include_flagged=True)
    assert 3849.0 < f["depth_m"].min() < 3850.0 and 4308.0 < f["depth_m"].max() < 4309.0


@pytest.mark.parametrize("version", ["03.01", "03.04", "03.08", "03.09", "03.10"])
def test_every_3x_header_version_reads_alike(gsf, tmp_path, monkeypatch, version):
    """libgsf decodes records by the version in the header record; the 3.x record layouts of swath pings are one:
    the same file labelled as another 3.x version gives the same soundings with either build."""
    import pandas as pd

    from hadal.grid.readers import gsf_file_version

    b = bytearray(gsf.read_bytes())
    assert b[8:18] == b"GSF-v03.06"
    b[8:18] = f"GSF-v{version}".encode()
    f = tmp_path / f"v{version}.gsf"
    f.write_bytes(bytes(b))
    assert gsf_file_version(f) == version
    ref = _read(gsf, monkeypatch, "3.08")
    for lib in ("3.08", "3.09"):
        got = _read(f, monkeypatch, lib)
        pd.testing.assert_frame_equal(got, ref, check_exact=True)
