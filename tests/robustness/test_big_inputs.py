"""Big inputs (issue 14 class 12): streamed text readers give what a whole-file read gives, and grids too big for
the memory budget are refused before they are read.

Oracles: Python's own line handling (``bytes.splitlines``/``strip``) for the line scan, and ``pandas.read_csv`` of
the whole file for the values, with blocks and chunks far smaller than the file so every boundary case is crossed.
"""

from __future__ import annotations

import gzip
import io

import numpy as np
import pandas as pd
import pytest

from hadal.errors import InputError
from hadal.formats import iter_blocks
from hadal.ingest import csv_reader
from hadal.ingest.csv_reader import read_sensor_csv
from hadal.ingest.vehicle import CsvSource
from hadal.textstream import LineScan, count_nonblank_lines


def _oracle_nonblank(raw: bytes) -> int:
    return sum(1 for line in raw.split(b"\n") if line.strip())


@pytest.mark.parametrize("seed", range(6))
@pytest.mark.parametrize("block", [1, 3, 7, 64])
def test_line_scan_counts_like_python_across_block_boundaries(seed, block):
    rng = np.random.default_rng(seed)
    pieces = [b"a,b\n", b"\n", b"  \t\n", b"1,2\n", b"\r\n", b"x", b" y \n", b"\n\n", b"3,4\r\n"]
    raw = b"".join(pieces[i] for i in rng.integers(0, len(pieces), 60))
    scan = LineScan("t", limit=10_000)
    for a in range(0, len(raw), block):
        scan.feed(raw[a:a + block])
    assert scan.finish() == _oracle_nonblank(raw)
    assert count_nonblank_lines(raw) == _oracle_nonblank(raw)


@pytest.mark.parametrize("block", [2, 5, 1000])
def test_line_scan_refuses_a_long_line_with_its_number(block):
    raw = b"h\n" + b"1,2\n" * 3 + b"9" * 50 + b"\n" + b"1,2\n"
    raw_open = b"h\n1,2\n" + b"9" * 50  # the long line unfinished at the end of a block
    scan = LineScan("f.csv", "CSV row", limit=20)
    with pytest.raises(InputError, match=r"f\.csv: line 5 is .* not a CSV row"):
        for a in range(0, len(raw), block):
            scan.feed(raw[a:a + block])
        scan.finish()
    scan = LineScan("f.csv", "CSV row", limit=20)
    with pytest.raises(InputError, match=r"f\.csv: line 3 is "):
        scan.feed(raw_open)


def test_line_scan_accepts_old_mac_line_ends():
    raw = b"h\r" + b"1,2\r" * 100
    scan = LineScan("f", limit=20)
    for a in range(0, len(raw), 7):
        scan.feed(raw[a:a + 7])


def test_iter_blocks_decompresses_and_reports_damage(tmp_path):
    p = tmp_path / "x.csv"
    body = b"t,p\n" + b"".join(b"%d,%d\n" % (i, i) for i in range(5000))
    p.write_bytes(gzip.compress(body))
    assert b"".join(iter_blocks(p, "CSV", text=True, block_bytes=1000)) == body
    p.write_bytes(gzip.compress(body)[:-200])
    with pytest.raises(InputError, match="corrupt or truncated gzip-compressed CSV file"):
        list(iter_blocks(p, "CSV", text=True, block_bytes=1000))
    (tmp_path / "e.csv").write_bytes(b"  \n\n")
    with pytest.raises(InputError, match="CSV file is empty"):
        list(iter_blocks(tmp_path / "e.csv", "CSV", text=True))


def _mapping() -> CsvSource:
    return CsvSource.model_validate({
        "source": "ctd", "time": {"field": "t", "format": "unix_s"},
        "fields": {"pressure_ctd_dbar": {"field": "p", "units": "dbar"},
                   "temperature_its90_degc": {"field": "temp", "units": "degC_its90"}}})


@pytest.mark.parametrize("chunk_rows", [1, 7, 1000])
def test_chunked_read_equals_whole_file_pandas(tmp_path, monkeypatch, chunk_rows):
    """Good rows, missing cells and rejected cells (text, booleans, a wrong field count) land in different
    chunks; the result equals a whole-file pandas read with the bad rows removed."""
    monkeypatch.setattr(csv_reader, "CSV_CHUNK_ROWS", chunk_rows)
    rng = np.random.default_rng(3)
    n = 400
    t = 1.7e9 + np.arange(n) * 0.25
    p_dbar = 1000 + rng.normal(size=n)
    temp = 2 + rng.normal(size=n) * 0.01
    rows = [f"{a:.3f},{b:.4f},{c:.5f}" for a, b, c in zip(t, p_dbar, temp, strict=True)]
    bad_rows = {17: "true", 150: "[1.5]", 151: "abc", 399: "{}"}
    for i, v in bad_rows.items():
        rows[i] = f"{t[i]:.3f},{v},{temp[i]:.5f}"
    rows[40] = f"{t[40]:.3f},{p_dbar[40]:.4f},"          # missing temperature: kept as NaN
    rows[41] = f"{t[41]:.3f},{p_dbar[41]:.4f},1,extra"   # wrong field count: dropped
    rows[300] = f"not-a-time,{p_dbar[300]:.4f},{temp[300]:.5f}"
    text = "t,p,temp\n" + "\n".join(rows) + "\n"
    path = tmp_path / "big.csv"
    path.write_text(text)
    with pytest.warns(UserWarning, match="dropped 6 corrupt row"):
        s = read_sensor_csv(path, _mapping(), "ctd")
    drop = set(bad_rows) | {41, 300}
    keep = np.array([i not in drop for i in range(n)])
    ref = pd.read_csv(io.StringIO(text), on_bad_lines="skip", dtype=str)
    assert len(ref) == n - 1  # pandas itself skips the wrong-field-count row
    np.testing.assert_array_equal(s.time_ns, np.round(t[keep] * 1e9).astype(np.int64))
    np.testing.assert_allclose(s.values["pressure_ctd_dbar"], np.round(p_dbar[keep], 4), rtol=0, atol=1e-9)
    want_temp = np.round(temp, 5)
    want_temp[40] = np.nan
    np.testing.assert_allclose(s.values["temperature_its90_degc"], want_temp[keep], rtol=0, atol=1e-12)
    assert s.stats["corrupt_rows"] == 6 and s.stats["wrong_field_count"] == 1 and s.stats["bad_times"] == 1
    assert s.stats["rejected_values"]["p"]["count"] == 4


def test_unix_ns_times_stay_exact(tmp_path):
    """Integer nanosecond times are not rounded through float64 (2^53 ns is 104 days)."""
    m = CsvSource.model_validate({"source": "ctd", "time": {"field": "t", "format": "unix_ns"},
                                  "fields": {"pressure_ctd_dbar": {"field": "p", "units": "dbar"}}})
    t0 = 1_700_000_000_123_456_789
    (tmp_path / "a.csv").write_text("t,p\n" + "".join(f"{t0 + k},{k}\n" for k in range(5)))
    s = read_sensor_csv(tmp_path / "a.csv", m, "ctd")
    np.testing.assert_array_equal(s.time_ns, t0 + np.arange(5))


@pytest.mark.parametrize("chunk_rows", [1, 13, 10_000])
@pytest.mark.parametrize("gz", [False, True])
def test_xyz_point_cloud_streamed_in_chunks(tmp_path, monkeypatch, chunk_rows, gz):
    """A text point cloud read in chunks equals numpy's whole-file ``loadtxt`` (the oracle), named columns picked
    by name; a non-numeric cell is refused with its row number counted across chunks."""
    from hadal.grid import readers

    monkeypatch.setattr(readers, "XYZ_CHUNK_ROWS", chunk_rows)
    rng = np.random.default_rng(5)
    pts = rng.normal(size=(257, 4)) * [1, 2, 0.01, 7]
    body = "# laser scan\nintensity,x,y,z\n" + "".join(f"{d:.6f},{a:.6f},{b:.6f},{c:.6f}\n" for a, b, c, d in pts)
    p = tmp_path / "cloud.xyz"
    p.write_bytes(gzip.compress(body.encode()) if gz else body.encode())
    got = readers.read_point_cloud(p)
    want = np.loadtxt(io.StringIO(body), delimiter=",", skiprows=2)[:, [1, 2, 3]]
    np.testing.assert_allclose(got[:, :3], want, rtol=0, atol=0)
    lines = body.splitlines(keepends=True)
    lines[2 + 200] = "1.0,2.0,abc,3.0\n"
    p.write_text("".join(lines))
    with pytest.raises(InputError, match="non-numeric value on data row 201"):
        readers.read_point_cloud(p)


@pytest.mark.parametrize("fmt", ["tif", "nc"])
def test_grid_too_big_for_the_budget_is_refused_before_reading(tmp_path, fmt):
    """A tiled, compressed raster (or chunked netCDF) declaring 20 000 x 30 000 cells is a few MB on disk but
    ~10 GB to read: one-line InputError naming the size and the limit, without allocating it."""
    import resource

    from hadal.grid.readers import read_grid

    ny, nx = 20_000, 30_000
    p = tmp_path / f"huge.{fmt}"
    if fmt == "tif":
        import rasterio
        from rasterio.transform import from_origin
        from rasterio.windows import Window

        with rasterio.open(p, "w", driver="GTiff", width=nx, height=ny, count=1, dtype="float32",
                           crs="EPSG:32654", transform=from_origin(300000, 1300000, 10, 10), tiled=True,
                           blockxsize=512, blockysize=512, compress="deflate", nodata=-9999) as dst:
            dst.write(np.full((512, 512), -5000, np.float32), 1, window=Window(0, 0, 512, 512))
    else:  # chunks never written are not stored: a tiny file declaring a huge variable
        import netCDF4

        with netCDF4.Dataset(p, "w") as nc:
            nc.createDimension("y", ny)
            nc.createDimension("x", nx)
            nc.createVariable("y", "f8", ("y",))[:] = np.arange(ny) * 10.0
            nc.createVariable("x", "f8", ("x",))[:] = np.arange(nx) * 10.0
            nc.createVariable("z", "f4", ("y", "x"), zlib=True, chunksizes=(1000, 1000), fill_value=np.float32(-1))
    assert p.stat().st_size < 100e6
    peak0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    with pytest.raises(InputError, match=r"the grid is 20,000 x 30,000 cells; reading it needs about \d+(\.\d+)? GiB "
                                         r"\(limit 1 GiB\)"):
        read_grid(p, max_bytes=2**30)
    assert (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - peak0) * 1024 < 2**30


def test_las_with_a_lying_point_count_is_refused_before_allocating(tmp_path):
    """A LAS header claiming 4e9 points in a 10-point file: laspy would allocate ~136 GB (a MemoryError, or the
    machine swapping); hadal compares the declared records with the file size first."""
    import struct

    laspy = pytest.importorskip("laspy")
    from hadal.grid.readers import read_point_cloud

    las = laspy.LasData(laspy.LasHeader(point_format=3, version="1.2"))
    las.x, las.y, las.z = np.arange(10.0), np.arange(10.0) * 2, -np.arange(10.0)
    p = tmp_path / "cloud.las"
    las.write(p)
    np.testing.assert_allclose(read_point_cloud(p)[:, 1], np.arange(10.0) * 2)  # the honest file reads
    b = bytearray(p.read_bytes())
    b[107:111] = struct.pack("<I", 4_000_000_000)  # LAS 1.2 legacy point count (ASPRS LAS 1.2, Table 4)
    p.write_bytes(b)
    with pytest.raises(InputError, match="declares 4,000,000,000 points but the file holds at most 10"):
        read_point_cloud(p)
