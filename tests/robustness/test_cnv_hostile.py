"""Hostile/edited Sea-Bird .cnv files (issue 14 hunt findings 01, 02, 03, 14c, 17): the reader must not trust
header counts for memory, must not blank SeaSoft's flag channel with ``bad_flag = 0``, must date ``timeJ``
across New Year, must name a column-count mismatch and must warn about a CTD channel with no valid value.

Every expectation is independent of the reader's own output on the mutated file: the unmutated real file's
values (../shared/data/ctd-real), or times computed with :mod:`datetime` from the synthetic cast's definition."""

from __future__ import annotations

import datetime as dt
import gzip
import re
import tracemalloc
import warnings

import numpy as np
import pytest

from hadal.errors import InputError
from hadal.ingest.cnv import cnv_sensor_samples, cnv_time_ns, read_cnv, seasoft_bad_scans

SBS19 = "sbs_19plus_V2_CTD-processing_example.cnv"


def _read(path):
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        df = read_cnv(path)
    return df, [str(x.message) for x in w]


def _same(a: np.ndarray, b: np.ndarray) -> None:
    np.testing.assert_array_equal(np.asarray(a, dtype=np.float64), np.asarray(b, dtype=np.float64))


# ------------------------------------------------------------------------------------------- 01: huge nvalues
def test_gzip_cnv_huge_nvalues_is_not_preallocated(shared_data, tmp_path):
    """A gzip .cnv declaring 3e8 scans (x 8 channels = 17.9 GiB): the hint is capped, memory stays small, the
    rows equal the unmutated file's and the mismatch is a one-line warning."""
    src = (shared_data / "ctd-real" / SBS19).read_bytes()
    ref, _ = _read(shared_data / "ctd-real" / SBS19)
    body = re.sub(rb"(?m)^# nvalues = \d+", b"# nvalues = 300000000", src, count=1)
    assert body != src
    p = tmp_path / "cast.cnv.gz"
    p.write_bytes(gzip.compress(body))
    tracemalloc.start()
    try:
        df, msgs = _read(p)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 256 << 20, f"peak {peak / 2**20:.0f} MiB for a {len(src) / 2**20:.1f} MiB cast"
    assert df.shape == ref.shape
    for c in ref.columns:
        _same(df[c], ref[c])
    assert any("nvalues = 300000000" in m and "3069" in m for m in msgs)


# --------------------------------------------------------------------------------------------- 02: bad_flag 0
def test_bad_flag_zero_spares_flag_channel(shared_data, tmp_path):
    """``# bad_flag = 0`` on an intact cast: SeaSoft's flag channel (0 = good) stays 0, so no scan is bad; every
    channel equals the unmutated file (it has no other zero), and the ambiguity is warned about."""
    src = (shared_data / "ctd-real" / SBS19).read_bytes()
    ref, _ = _read(shared_data / "ctd-real" / SBS19)
    p = tmp_path / "cast.cnv"
    p.write_bytes(re.sub(rb"(?m)^# bad_flag = .*$", b"# bad_flag = 0.000e+00", src, count=1))
    df, msgs = _read(p)
    assert df.attrs["bad_flag"] == 0
    for c in ref.columns:
        _same(df[c], ref[c])
    assert not seasoft_bad_scans(df).any() and not seasoft_bad_scans(ref).any()
    assert any("bad_flag = 0" in m and "collides" in m for m in msgs)


def test_bad_flag_zero_blanks_only_plausible_zeros(shared_data, tmp_path):
    """With bad_flag 0, a 0 written into the pressure of three scans becomes NaN; the all-zero user polynomial
    channel ``upoly0`` and the scan counter keep their real values; everything else equals the original."""
    path = shared_data / "ctd-real" / "oceissues644_02dk.cnv"
    ref, _ = _read(path)
    text = path.read_bytes().decode("latin-1")
    head, body = text.split("*END*", 1)
    head = re.sub(r"(?m)^# bad_flag = .*$", "# bad_flag = 0.000e+00", head, count=1)
    lines = body.split("\n")
    rows = [i for i, ln in enumerate(lines) if ln.strip()]
    zeroed = [10, 200, 400]  # data rows whose pressure (column 1) is set to 0
    for r in zeroed:
        toks = lines[rows[r]].split()
        toks[1] = "0.000"
        lines[rows[r]] = " ".join(toks)
    p = tmp_path / "cast.cnv"
    p.write_bytes((head + "*END*" + "\n".join(lines)).encode("latin-1"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the file's own nvalues mismatch
        df, msgs = _read(p)
    expect_p = ref["prDM"].to_numpy().copy()
    expect_p[zeroed] = np.nan
    _same(df["prDM"], expect_p)
    assert (df["upoly0"] == 0).all() and (ref["upoly0"] == 0).all()
    _same(df["scan"], ref["scan"])
    for c in ref.columns:
        if c == "prDM":
            continue
        fin = np.isfinite(ref[c].to_numpy())  # original bad_flag values are plain numbers now
        _same(df[c].to_numpy()[fin], ref[c].to_numpy()[fin])
    assert any("prDM (3)" in m for m in msgs)


# --------------------------------------------------------------------------------- 17: timeJ across New Year
def _timej_cast(start: dt.datetime, first: dt.datetime, n: int = 480, hz: float = 4.0) -> tuple[str, list]:
    """A 4-channel timeJ cast whose scans run from ``first`` at ``hz``; returns the text and the true times."""
    true = [first + dt.timedelta(seconds=i / hz) for i in range(n)]
    jd = [(t - dt.datetime(t.year, 1, 1, tzinfo=dt.UTC)).total_seconds() / 86400 + 1 for t in true]
    rows = "".join(f"{j:14.9f} {1000 + 0.5 * i:9.3f} {2.5:8.4f} {3.25:9.6f}\n" for i, j in enumerate(jd))
    hdr = (f"* Sea-Bird SBE 9 Data File:\n# nquan = 4\n# nvalues = {n}\n# name 0 = timeJ: Julian Days\n"
           "# name 1 = prDM: Pressure, Digiquartz [db]\n# name 2 = t090C: Temperature [ITS-90, deg C]\n"
           f"# name 3 = c0S/m: Conductivity [S/m]\n# start_time = {start:%b %d %Y %H:%M:%S}\n"
           "# bad_flag = -9.990e-29\n*END*\n")
    return hdr + rows, true


@pytest.mark.parametrize("start, first", [
    (dt.datetime(2018, 12, 31, 23, 59, tzinfo=dt.UTC), dt.datetime(2018, 12, 31, 23, 59, tzinfo=dt.UTC)),
    (dt.datetime(2020, 12, 31, 23, 59, tzinfo=dt.UTC), dt.datetime(2020, 12, 31, 23, 59, tzinfo=dt.UTC)),  # leap
    # start_time just after midnight while the first scans are still on Dec 31
    (dt.datetime(2021, 1, 1, 0, 0, 30, tzinfo=dt.UTC), dt.datetime(2020, 12, 31, 23, 59, 50, tzinfo=dt.UTC)),
])
def test_timej_across_new_year(tmp_path, start, first):
    text, true = _timej_cast(start, first)
    p = tmp_path / "cast.cnv"
    p.write_text(text)
    df, _ = _read(p)
    t, how = cnv_time_ns(df)
    expect = np.array([int(x.timestamp() * 1e6) * 1000 for x in true], dtype=np.int64)
    assert how == "start year + timeJ"
    assert np.max(np.abs(t - expect)) < 1_000_000  # 1 ms (timeJ written to 1e-9 day = 86 us)


# -------------------------------------------------------------------------------- 14c: column-count mismatch
def test_rows_with_extra_value_name_the_column_count(shared_data, tmp_path):
    src = (shared_data / "ctd-real" / SBS19).read_bytes()
    head, body = src.split(b"*END*", 1)
    p = tmp_path / "cast.cnv"
    p.write_bytes(head + b"*END*" + re.sub(rb"(?m)^(\s+-?\d.*\S)[ \t]*\r?$", rb"\1      1.000", body))
    with pytest.raises(InputError, match=r"rows have 9 values, the header declares 8 columns \('# nquan = 8', "
                                         r"8 '# name' lines\)"):
        read_cnv(p)


# ------------------------------------------------------------------------------- 03: channel with no valid value
def test_ctd_channel_all_bad_flag_is_warned(shared_data, tmp_path):
    """Temperature bad_flag on every scan: a loud warning naming the channel; the other channels equal the
    unmutated file's."""
    src = (shared_data / "ctd-real" / SBS19).read_bytes()
    head, body = src.split(b"*END*", 1)
    p = tmp_path / "cast.cnv"
    p.write_bytes(head + b"*END*" + re.sub(rb"(?m)^(\s*)(\S+)", rb"\1-9.990e-29", body))
    ref, _ = _read(shared_data / "ctd-real" / SBS19)
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        s = cnv_sensor_samples(read_cnv(p))
    msgs = [str(x.message) for x in w]
    assert any("temperature" in m and "'tv290C'" in m and "no valid value" in m for m in msgs)
    assert np.isnan(s.values["temperature_its90_degc"]).all()
    _same(s.values["pressure_ctd_dbar"], ref["prdM"])
    # the oracle's own reading of the unmutated file raises no such warning
    with warnings.catch_warnings(record=True) as w2:
        warnings.simplefilter("always")
        cnv_sensor_samples(ref)
    assert not any("no valid value" in str(x.message) for x in w2)
