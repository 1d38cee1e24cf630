"""Memory bombs, one per reader format (issue 45): each ends in a one-line error or a correct product, with the
peak RSS of the process that read it under a bound. Every read runs in a fresh interpreter under
``RLIMIT_AS`` = 4 GiB (the red team's cap), so the budget (:class:`hadal.budget.DecodeBudget`, from what the cap
leaves) is the one a capped run sees; the child reports its
``VmHWM`` (the oracle: the kernel's count; not ``ru_maxrss``, which Linux carries over fork + exec from the
parent, a test worker of gigabytes).

Bombs are written streaming (a compressor fed a repeated block), so the test never holds their content."""

from __future__ import annotations

import bz2
import gzip
import json
import lzma
import subprocess
import sys
import textwrap
from pathlib import Path

import numpy as np
import pytest

CAP = 4 << 30
GIB = 1 << 30
CNV_HEADER = (
    "* Sea-Bird SBE 9 Data File:\n# nquan = 4\n# nvalues = 10\n# name 0 = prDM: Pressure, Digiquartz [db]\n"
    "# name 1 = t090C: Temperature [ITS-90, deg C]\n# name 2 = c0S/m: Conductivity [S/m]\n"
    "# name 3 = timeS: Time, Elapsed [seconds]\n# start_time = Jan 01 2020 00:00:00\n# bad_flag = -9.990e-29\n"
    "*END*\n")


def _compressed(path: Path, head: bytes, block: bytes, total_bytes: int, how: str = "gzip") -> Path:
    """``head`` then ``block`` repeated up to ``total_bytes``, compressed as it is written."""
    opener = {"gzip": lambda p: gzip.open(p, "wb", compresslevel=1), "xz": lambda p: lzma.open(p, "wb", preset=1),
              "bz2": lambda p: bz2.open(p, "wb", compresslevel=1)}[how]
    big = block * max(1, (16 << 20) // len(block))
    with opener(path) as f:
        f.write(head)
        n = len(head)
        while n < total_bytes:
            f.write(big)
            n += len(big)
    return path


def _run_capped(code: str) -> dict:
    """Run ``code`` (defining ``run()``; its top level imports what it needs) in a new interpreter under RLIMIT_AS =
    4 GiB: the result or the error of ``run()``, its peak RSS and the RSS before it (after the imports), in bytes."""
    prog = textwrap.dedent("""
        import json, resource, sys, warnings
        resource.setrlimit(resource.RLIMIT_AS, (%d, %d))
        warnings.simplefilter("ignore")
        %s
        def hwm():  # this image's peak RSS: ru_maxrss would carry the forking parent's over exec
            with open("/proc/self/status") as f:
                return next(int(l.split()[1]) * 1024 for l in f if l.startswith("VmHWM:"))
        base = hwm()
        out = {}
        try:
            out["result"] = run()
        except Exception as exc:
            out["error"] = type(exc).__name__
            out["message"] = str(exc)
        out["peak"] = hwm()
        out["base"] = base
        print(json.dumps(out))
    """) % (CAP, CAP, textwrap.dedent(code).strip())
    r = subprocess.run([sys.executable, "-c", prog], capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr[-2000:]
    return json.loads(r.stdout.strip().splitlines()[-1])


def _one_line_error(out: dict, match: str) -> None:
    assert out.get("error") == "InputError", out
    assert "\n" not in out["message"] and match in out["message"], out["message"]


def test_xz_cnv_expanding_to_many_rows(tmp_path):
    """1.1 GB of scans in a small xz .cnv (25e6 scans x 4 channels, 0.75 GiB as float64, ~3 GiB with the working
    copies the ingest makes): refused as it decodes, peak far under the cap (the red team's peaked at 6 GiB)."""
    p = _compressed(tmp_path / "bomb.cnv", CNV_HEADER.encode(), b"     1.000    10.0000   3.500000      0.000\n",
                    25_000_000 * 44, "xz")
    out = _run_capped(f"""
        def run():
            from hadal.ingest.cnv import read_cnv
            return len(read_cnv({str(p)!r}))
    """)
    _one_line_error(out, "decoding this CNV file needs more than")
    assert out["peak"] < 1.5 * GIB, out


def test_cnv_under_the_budget_is_read_whole(tmp_path):
    """The budget refuses nothing ordinary: 2e6 scans (xz) are all read, values as written (the oracle)."""
    p = _compressed(tmp_path / "ok.cnv", CNV_HEADER.encode(), b"     1.000    10.0000   3.500000      0.000\n",
                    len(CNV_HEADER) + 2_000_000 * 44, "xz")
    out = _run_capped(f"""
        def run():
            from hadal.ingest.cnv import read_cnv
            df = read_cnv({str(p)!r})
            return [len(df), float(df["t090C"].mean()), float(df["c0S/m"].max())]
    """)
    assert "error" not in out, out
    n, t, c = out["result"]
    assert n >= 2_000_000 and t == 10.0 and c == 3.5


@pytest.mark.parametrize("reader", ["cnv", "csv", "hex", "xyz_cloud", "soundings", "detect"])
def test_gzip_of_nul_bytes(tmp_path, reader):
    """1 GiB of NUL bytes in a 1 MB gzip, offered to each text reader: a one-line error (binary content or a
    runaway line), peak RSS under 1 GiB (it reached the memory cap in ingest before)."""
    name = {"cnv": "nul.cnv", "csv": "nul.csv", "hex": "nul.hex", "xyz_cloud": "nul.xyz", "soundings": "nul.xyz",
            "detect": "nul.csv"}[reader]
    p = _compressed(tmp_path / name, b"", b"\x00" * (1 << 20), GIB)
    call = {
        "cnv": "from hadal.ingest.cnv import read_cnv as f",
        "csv": ("from hadal.ingest.csv_reader import read_sensor_csv\n"
                "from hadal.ingest.vehicle import CsvSource\n"
                "m = CsvSource.model_validate({'source': 'ctd', 'time': {'field': 't', 'format': 'unix_s'}, "
                "'fields': {'pressure_ctd_dbar': {'field': 'p', 'units': 'dbar'}}})\n"
                "def f(q):\n    return read_sensor_csv(q, m, 'ctd')"),
        "hex": "from hadal.ingest.seabird_hex import read_hex as f",
        "xyz_cloud": "from hadal.grid.readers import read_point_cloud as f",
        "soundings": "from hadal.grid.readers import read_soundings as f",
        "detect": "from hadal.formats import detect\ndef f(q):\n    return detect(q).kind",
    }[reader]
    out = _run_capped(call + f"""
def run():
    r = f({str(p)!r})
    return r if isinstance(r, str) else type(r).__name__
""")
    if reader == "detect":
        assert out["result"] == "unknown", out  # not a format hadal reads: refused by name at init/ingest
    else:
        assert out.get("error") == "InputError" and "\n" not in out["message"], out
    assert out["peak"] < GIB, out


def test_gzip_hex_expanding_past_the_budget(tmp_path):
    """A Sea-Bird .hex whose 3 GiB of scan lines are a 14 MB gzip: read_bytes streams it against the budget
    (it decompressed the whole file in one call before: MemoryError at the cap)."""
    head = b"* Sea-Bird SBE 9 Data File:\n*END*\n"
    p = _compressed(tmp_path / "bomb.hex", head, b"0123456789ABCDEF0123\n", 3 * GIB)
    out = _run_capped(f"""
        def run():
            from hadal.ingest.seabird_hex import read_hex
            return type(read_hex({str(p)!r})).__name__
    """)
    _one_line_error(out, "decoding this Sea-Bird .hex file needs more than")
    assert out["peak"] < 2 * GIB, out


def test_gzip_xyz_cloud_expanding_past_the_budget(tmp_path):
    """xyz points, 2.8 GiB of text (250e6 points) in a gzip: refused as the columns grow, peak under 2 GiB."""
    p = _compressed(tmp_path / "bomb.xyz", b"", b"1.0 2.0 3.0\n", 3 * GIB)
    out = _run_capped(f"""
        def run():
            from hadal.grid.readers import read_point_cloud
            return len(read_point_cloud({str(p)!r}))
    """)
    _one_line_error(out, "decoding this point cloud needs more than")
    assert out["peak"] < 2 * GIB, out


def test_gzip_csv_expanding_past_the_budget(tmp_path):
    """A sensor CSV of 3 GiB (gzip): refused as its columns grow, peak under 2 GiB."""
    p = _compressed(tmp_path / "bomb.csv", b"t,p\n", b"1.0,2.0\n", 3 * GIB)
    out = _run_capped(f"""
        def run():
            from hadal.ingest.csv_reader import read_sensor_csv
            from hadal.ingest.vehicle import CsvSource
            m = CsvSource.model_validate({{'source': 'ctd', 'time': {{'field': 't', 'format': 'unix_s'}},
                                          'fields': {{'pressure_ctd_dbar': {{'field': 'p', 'units': 'dbar'}}}}}})
            return len(read_sensor_csv({str(p)!r}, m, 'ctd'))
    """)
    _one_line_error(out, "decoding this CSV file needs more than")
    assert out["peak"] < 2 * GIB, out


def _geotiff(path: Path, n: int) -> Path:
    import rasterio
    from rasterio.transform import from_origin
    from rasterio.windows import Window

    with rasterio.open(path, "w", driver="GTiff", width=n, height=n, count=1, dtype="float32", crs="EPSG:4326",
                       transform=from_origin(142.0, 11.5, 0.2 / n, 0.2 / n), tiled=True, compress="deflate",
                       nodata=-9999) as d:
        for i in range(0, n, 512):
            h = min(512, n - i)
            d.write((-5000.0 - np.arange(h * n, dtype=np.float32).reshape(h, n) % 97), 1,
                    window=Window(0, i, n, h))
    return path


@pytest.mark.parametrize("margin", [1.02, 0.98])
def test_geotiff_just_under_and_over_the_read_budget(tmp_path, margin):
    """A GeoTIFF whose cells x GRID_READ_BYTES_PER_CELL are 2 % under (over) the read budget: the prior DTM is made
    with a peak RSS under the budget (refused in one line before reading). The budget counts the working copies
    (float64, masks, the resampled DTM): it counted the raster alone before and peaked at 3x."""
    from hadal.grid.readers import GRID_READ_BYTES_PER_CELL

    n = 2000
    p = _geotiff(tmp_path / "prior.tif", n)
    budget = n * n * GRID_READ_BYTES_PER_CELL * margin
    out = _run_capped(f"""
        from hadal.geo import LocalFrame
        from hadal.grid.prior import prior_dtm
        def run():
            ds = prior_dtm({str(p)!r}, LocalFrame(11.4, 142.1), max_read_bytes={budget!r})
            return [float(ds["depth_m"].min()), float(ds["depth_m"].max())]
    """)
    if margin > 1:
        assert "error" not in out, out
        lo, hi = out["result"]
        assert 5000 - 0.01 <= lo and hi <= 5096 + 0.01  # depths as written (-5000 - k, k < 97), positive down
        assert out["peak"] - out["base"] < budget, (out, budget)
    else:
        _one_line_error(out, "reading it needs about")
        assert out["peak"] - out["base"] < 0.1 * GIB


def _mcap_bomb(path: Path, decompressed: int, how: str) -> Path:
    """An MCAP file (spec: magic, Header, one Chunk, Footer, magic) whose chunk holds ``decompressed`` bytes of
    zeros, zstd- or lz4-compressed as written (a few MB on disk)."""
    import struct

    def string(s: bytes) -> bytes:
        return struct.pack("<I", len(s)) + s

    def record(op: int, body: bytes) -> bytes:
        return struct.pack("<BQ", op, len(body)) + body

    tmp = path.with_suffix(".z")
    block = b"\x00" * (16 << 20)
    with open(tmp, "wb") as f:
        if how == "zstd":
            import zstandard

            c = zstandard.ZstdCompressor(level=1).compressobj(size=decompressed)
        else:
            import lz4.frame

            c = lz4.frame.LZ4FrameCompressor()
            f.write(c.begin(source_size=decompressed))
        for _ in range(decompressed // len(block)):
            f.write(c.compress(block))
        f.write(c.flush())
    data = tmp.read_bytes()
    chunk = (struct.pack("<QQQI", 0, 10, decompressed, 0) + string(how.encode())
             + struct.pack("<Q", len(data)) + data)
    magic = b"\x89MCAP0\r\n"
    with open(path, "wb") as f:
        f.write(magic + record(0x01, string(b"ros2") + string(b"bomb")) + record(0x06, chunk)
                + record(0x02, struct.pack("<QQI", 0, 0, 0)) + magic)
    return path


@pytest.mark.parametrize("how", ["zstd", "lz4"])
def test_mcap_chunk_bomb(tmp_path, how):
    """One MCAP chunk of 1 GiB of zeros (a few MB on disk): its declared size with its working copies is over the
    budget left by the 4 GiB cap; refused before decompressing, in one line."""
    p = _mcap_bomb(tmp_path / "bomb.mcap", GIB, how)
    out = _run_capped(f"""
        from hadal.ingest.mcap_reader import read_mcap
        def run():
            return len(read_mcap({str(p)!r}))
    """)
    _one_line_error(out, "decoding this MCAP chunk needs more than")
    assert out["peak"] - out["base"] < 0.5 * GIB, out
