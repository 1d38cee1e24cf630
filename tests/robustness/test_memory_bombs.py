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
    4 GiB: the result or the error of ``run()``, its peak RSS and the RSS before it (after the imports), and the
    peak of its child processes, in bytes."""
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
        # child processes' peak (the GSF reader's libgsf child): an upper bound, Linux starts a child's count at
        # its parent's at the fork (this small interpreter's)
        out["children_peak"] = resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss * 1024
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


def _mcap_many_chunks(path: Path, n_chunks: int, per_chunk: int, *, same: bool = True) -> Path:
    """An MCAP file (spec: magic, Header, a JSON Schema and Channel ``/ctd``, ``n_chunks`` zstd Chunks of
    ``per_chunk`` Message records each, Footer, magic): every chunk small and within the budget on its own.
    ``same``: one chunk written ``n_chunks`` times (a few MB for millions of messages); else consecutive log times
    (``k`` ms for message ``k``) with ``p`` = 1.5, ``t`` = 10.25, ``c`` = 3.5 in every message."""
    import struct
    import zlib

    import zstandard

    def string(s: bytes) -> bytes:
        return struct.pack("<I", len(s)) + s

    def record(op: int, body: bytes) -> bytes:
        return struct.pack("<BQ", op, len(body)) + body

    schema = record(0x03, struct.pack("<H", 1) + string(b"ctd") + string(b"jsonschema") + string(b'{"type":"object"}'))
    channel = record(0x04, struct.pack("<HH", 1, 1) + string(b"/ctd") + string(b"json") + struct.pack("<I", 0))
    magic = b"\x89MCAP0\r\n"
    cctx = zstandard.ZstdCompressor(level=3)
    body = b""
    with open(path, "wb") as f:
        f.write(magic + record(0x01, string(b"") + string(b"bomb")) + schema + channel)
        for k in range(n_chunks):
            if not body or not same:
                t0 = 0 if same else k * per_chunk
                msgs = b"".join(record(0x05, struct.pack("<HIQQ", 1, i, (t0 + i) * 1_000_000, (t0 + i) * 1_000_000)
                                       + b'{"p": 1.5, "t": 10.25, "c": 3.5}') for i in range(per_chunk))
                data = cctx.compress(msgs)
                body = (struct.pack("<QQQI", t0 * 1_000_000, (t0 + per_chunk) * 1_000_000, len(msgs),
                                    zlib.crc32(msgs)) + string(b"zstd") + struct.pack("<Q", len(data)) + data)
            f.write(record(0x06, body))
        f.write(record(0x02, struct.pack("<QQI", 0, 0, 0)) + magic)
    return path


def test_mcap_many_small_chunks_past_the_budget(tmp_path):
    """2,000 chunks of 10,000 JSON messages each (0.6 MB decoded a chunk, 1.2 GB and 2e7 messages in all, 5 GB
    as decoded objects; a few MB on disk): each chunk passes on its own, their sum is counted against one budget
    for the file and refused in one line naming the file and the limit, peak far under the cap."""
    p = _mcap_many_chunks(tmp_path / "chunks.mcap", 2000, 10_000)
    out = _run_capped(f"""
        from hadal.ingest.mcap_reader import read_mcap
        def run():
            return len(read_mcap({str(p)!r})[0]["/ctd"].messages)
    """)
    _one_line_error(out, "decoding this MCAP file needs more than")
    assert str(p) in out["message"] and "limit" in out["message"], out
    assert out["peak"] - out["base"] < 0.75 * GIB, out


def test_mcap_many_small_chunks_under_the_budget_are_read_whole(tmp_path):
    """The file budget refuses nothing ordinary: 1e6 messages in 100 chunks are all read through the sensors
    reader under the cap, values and times as written (the oracle)."""
    p = _mcap_many_chunks(tmp_path / "ok.mcap", 100, 10_000, same=False)
    out = _run_capped(f"""
        import warnings
        from hadal.ingest.build import read_mcap_sensors
        from hadal.ingest.vehicle import VehicleConfig
        def run():
            v = VehicleConfig.model_validate({{"time_base": "ctd", "sensors": {{"ctd": {{"mcap": {{"topic": "/ctd",
                "fields": {{"pressure_ctd_dbar": {{"field": "p", "units": "dbar"}},
                           "temperature_its90_degc": {{"field": "t", "units": "degC"}}}}}}}}}}}})
            s = read_mcap_sensors([{str(p)!r}], v)[0]["ctd"]
            steps = set((s.time_ns[1:] - s.time_ns[:-1]).tolist())
            return [len(s), sorted(steps), float(s.values["pressure_ctd_dbar"].mean()),
                    float(s.values["temperature_its90_degc"].max())]
    """)
    assert "error" not in out, out
    n, steps, pm, tmax = out["result"]
    assert n == 1_000_000 and steps == [1_000_000] and pm == 1.5 and tmax == 10.25


# ---------------------------------------------------------------------------------------------- swath formats
def _real(name: str) -> bytes:
    """A real file of a swath format (``$HADAL_SHARED_DATA/formats-real`` or ``bathy-real``, provenance in their
    PROVENANCE.md), the seed of the bombs below: a header field of a copy is changed, or its records repeated."""
    import os

    root = Path(os.environ.get("HADAL_SHARED_DATA", "/work/shared/data"))
    for sub in ("formats-real", "bathy-real"):
        if (root / sub / name).is_file():
            return (root / sub / name).read_bytes()
    pytest.skip(f"real file {name} not here (HADAL_SHARED_DATA)")


EM_ALL = "mbsys_nbp1403-filtered-em120.all"
KMALL = "kongsberg_em_driver_MRZ_versionF.kmall"
S7K = "mbsys_TN136HS.309.snipped.s7k"
GSF = "0029_20160323_185603_EX1604_MB.gsf.mb121"


def _em_datagrams(data: bytes) -> list[tuple[str, int, int]]:
    """(type, offset, length) of each datagram of a little-endian .all file (u32 length excluding itself)."""
    import struct

    out, off = [], 0
    while off < len(data):
        n = struct.unpack_from("<I", data, off)[0]
        out.append((chr(data[off + 5]), off, n))
        off += 4 + n
    return out


def _em_depths(data: bytes) -> bytes:
    """The real file's Depth (D) datagrams, one after the other: 3 pings, 572 valid soundings."""
    return b"".join(data[o:o + 4 + n] for t, o, n in _em_datagrams(data) if t == "D")


def _read_swath(p: Path) -> str:
    """The DTM stage's read of a multibeam file (hadal.grid.soundings.read_soundings_xy): soundings, depth range."""
    return f"""
        from hadal.grid.soundings import read_soundings_xy
        def run():
            x, y, dep, frame, used = read_soundings_xy([{str(p)!r}], None)
            return [int(dep.size), float(dep.min()), float(dep.max())]
    """


def test_em_all_of_many_depth_datagrams_past_the_budget(tmp_path):
    """The real EM 120 .all with its 3 Depth datagrams repeated 260,000 times (1.5e8 soundings, 2.4 GB, a gzip of a
    few MB): each ping is valid, their sum is refused in one line as they decode, peak under 2 GiB (0.5 GiB measured;
    before, the reader kept every ping until the navigation was read: MemoryError at 2.8 GiB)."""
    data = _real(EM_ALL)
    p = _compressed(tmp_path / "bomb.all", data, _em_depths(data), 2_400_000_000)
    out = _run_capped(_read_swath(p))
    _one_line_error(out, "decoding this em_all multibeam file needs more than")
    assert "limit" in out["message"], out
    assert out["peak"] < 2 * GIB, out


def test_em_all_of_many_depth_datagrams_under_the_budget_is_read_whole(tmp_path):
    """1,000 repeats (5.7e5 soundings): all read, the soundings and depths those of the real file (the oracle:
    572 valid beams, 2581.32-3051.72 m as mbinfo reports), 1,001 times."""
    import gzip

    data = _real(EM_ALL)
    p = tmp_path / "ok.all"
    with gzip.open(p, "wb", compresslevel=1) as f:
        f.write(data + _em_depths(data) * 1000)
    out = _run_capped(_read_swath(p))
    assert "error" not in out, out
    n, lo, hi = out["result"]
    assert n == 572 * 1001 and abs(lo - 2581.32) < 0.01 and abs(hi - 3051.72) < 0.01, out


def _kmall_mrz(data: bytes, *, time_s: int | None = None, parts: tuple[int, int] | None = None,
               size: int | None = None) -> bytes:
    """The real #MRZ datagram with its time (u32 s at byte 12), partition (u16 numOfDgms, dgmNum at byte 20) or
    length (u32 at 0 and at the end, zeros before the trailing length) changed."""
    import struct

    d = bytearray(data)
    if time_s is not None:
        struct.pack_into("<I", d, 12, time_s)
    if parts is not None:
        struct.pack_into("<HH", d, 20, *parts)
    if size is not None:
        d = d[:-4] + bytes(size - len(d)) + d[-4:]
        struct.pack_into("<I", d, 0, size)
        struct.pack_into("<I", d, size - 4, size)
    return bytes(d)


def test_kmall_partitions_that_never_complete(tmp_path):
    """400 #MRZ partitions (1 of 2, each of another ping, 8 MiB: 3.2 GiB, a gzip of 4 MB) wait for their second
    parts: held against the budget, refused in one line, peak under 2 GiB (1.1 GiB measured; they were held without
    bound before: 3.4 GiB, then "no #MRZ datagrams")."""
    import gzip

    data = _real(KMALL)
    p = tmp_path / "parts.kmall"
    with gzip.open(p, "wb", compresslevel=1) as f:
        for k in range(400):
            f.write(_kmall_mrz(data, time_s=1_557_607_590 + k, parts=(2, 1), size=8 << 20))
    out = _run_capped(_read_swath(p))
    _one_line_error(out, "decoding this kmall multibeam file needs more than")
    assert "pending" in out["message"], out
    assert out["peak"] < 2 * GIB, out


def test_kmall_of_many_pings_is_read_whole(tmp_path):
    """The real #MRZ ping 200 times (one ping a second): all read under the cap, 200 x its 393 valid soundings,
    depths as the single ping's (the oracle: the real file read alone)."""
    data = _real(KMALL)
    one = tmp_path / "one.kmall"
    one.write_bytes(data)
    p = tmp_path / "many.kmall"
    p.write_bytes(b"".join(_kmall_mrz(data, time_s=1_557_607_590 + k) for k in range(200)))
    ref = _run_capped(_read_swath(one))["result"]
    out = _run_capped(_read_swath(p))
    assert "error" not in out, out
    assert ref[0] == 393 and out["result"] == [200 * 393, ref[1], ref[2]], (ref, out)
    assert out["peak"] < GIB, out


@pytest.mark.parametrize("fmt", ["em_all_length", "em_all_beams", "kmall_length", "s7k_size", "gsf_beams"])
def test_swath_header_claiming_a_huge_count(tmp_path, fmt):
    """A header field of a real file claiming far more than the file holds (a datagram/record length of 16 MiB -
    256 MiB, a Depth datagram of 255 beams in 191 beams' bytes, a GSF ping of 65,535 beams): a one-line error,
    nothing allocated for the claim (peak under 0.5 GiB above the start)."""
    import struct

    if fmt.startswith("em_all"):
        d = bytearray(_real(EM_ALL))
        t, o, n = next(x for x in _em_datagrams(bytes(d)) if x[0] == "D")
        if fmt == "em_all_length":
            struct.pack_into("<I", d, o, (1 << 24) - 4)
            match = "truncated .all file"
        else:
            d[o + 4 + 23] = 255  # N beams (u8 after the 16-byte header, heading, sound speed, transducer depth, max)
            struct.pack_into("<H", d, o + 4 + n - 2, sum(d[o + 5:o + 4 + n - 3]) & 0xFFFF)  # checksum kept right
            match = "too short for its beam count"
        name = "claim.all"
    elif fmt == "kmall_length":
        d = bytearray(_real(KMALL))
        struct.pack_into("<I", d, 0, (1 << 26) - 4)
        match, name = "truncated .kmall file", "claim.kmall"
    elif fmt == "s7k_size":
        d = bytearray(_real(S7K))
        struct.pack_into("<I", d, 8, (1 << 28) - 64)  # DRF: u16 version, u16 offset, u32 sync, u32 size
        match, name = "truncated .s7k file", "claim.s7k"
    else:
        d = bytearray(_real(GSF))
        struct.pack_into(">H", d, 7340 + 8 + 16, 65535)  # number_beams of the first ping (after time, lat, lon)
        match, name = "invalid number of beams", "claim.gsf"
    p = tmp_path / name
    p.write_bytes(bytes(d))
    out = _run_capped(_read_swath(p))
    _one_line_error(out, match)
    assert out["peak"] - out["base"] < 0.5 * GIB, out


def test_s7k_records_of_a_declared_huge_size_in_a_gzip(tmp_path):
    """The real .s7k's file-header record declaring 255 MiB, zeros to fill it, then its 17 records repeated for
    1 GiB (a gzip of a few MB): read record by record and refused in one line (no bathymetry records), peak
    about one record."""
    import struct

    d = bytearray(_real(S7K))
    first = struct.unpack_from("<I", d, 8)[0]
    head = bytes(d[:first])
    big = bytearray(head)
    struct.pack_into("<I", big, 8, 255 << 20)
    p = _compressed(tmp_path / "big.s7k", bytes(big) + bytes((255 << 20) - len(big)), bytes(d[first:]), GIB)
    out = _run_capped(_read_swath(p))
    _one_line_error(out, "contains no bathymetry pings")
    assert out["peak"] - out["base"] < GIB, out


def _gsf_records(data: bytes) -> list[tuple[int, int, int]]:
    """(record id, offset, record bytes with the 8-byte header and padding) of a GSF file (big-endian)."""
    import struct

    out, off = [], 0
    while off < len(data):
        n, rid = struct.unpack_from(">II", data, off)
        size = 8 + n + (-n % 4)
        out.append((rid & 0x7FFFFFFF, off, size))
        off += size
    return out


def test_gsf_of_many_pings_past_the_budget(tmp_path):
    """The real EX1604 GSF's first ping record repeated 200,000 times (6e7 soundings, 1.2 GB, a gzip of a few MB):
    the child process that reads it with libgsf refuses as it decodes, in one line (its limits are this
    process's, RLIMIT_AS included), peak of either process under 2 GiB (the child's 0.8 GiB measured; it reached
    the cap before, a numpy MemoryError at 2.5 GiB)."""
    data = _real(GSF)
    recs = _gsf_records(data)
    first = next(o for r, o, s in recs if r == 2)
    ping = next(data[o:o + s] for r, o, s in recs if r == 2)
    p = _compressed(tmp_path / "bomb.gsf", data[:first], ping, first + 200_000 * len(ping))
    out = _run_capped(_read_swath(p))
    _one_line_error(out, "decoding this gsf multibeam file needs more than")
    assert out["peak"] < 2 * GIB and out["children_peak"] < 2 * GIB, out


@pytest.mark.parametrize("reader", ["dtm", "read_soundings"])
def test_gzip_xyz_soundings_expanding_past_the_budget(tmp_path, reader):
    """xyz soundings, 2 GiB of text (1.1e8 soundings) in a gzip, read by the DTM stage's reader or the public
    ``read_soundings``: refused in one line as the soundings decode, peak under 2 GiB."""
    p = _compressed(tmp_path / "bomb.xyz", b"", b"142.1 11.3 5000.0\n", 2 * GIB)
    code = _read_swath(p) if reader == "dtm" else f"""
        from hadal.grid.readers import read_soundings
        def run():
            return len(read_soundings({str(p)!r}))
    """
    out = _run_capped(code)
    _one_line_error(out, "decoding this multibeam file needs more than")
    assert out["peak"] < 2 * GIB, out


def test_compressed_gsf_decompressed_past_the_free_disk_space(tmp_path):
    """A gzip GSF (the real file's pings repeated, 200 MB) is decompressed to a temporary file for libgsf: the copy
    stops in one line once it would leave less than the reserve free (the reserve set here so that 64 MiB are left:
    a disk-filling bomb without writing one), and the temporary file is gone."""
    import tempfile

    data = _real(GSF)
    recs = _gsf_records(data)
    first = next(o for r, o, s in recs if r == 2)
    ping = next(data[o:o + s] for r, o, s in recs if r == 2)
    p = _compressed(tmp_path / "big.gsf", data[:first], ping, 200_000_000)
    tmp = tmp_path / "tmp"
    tmp.mkdir()
    out = _run_capped(f"""
        import shutil, tempfile
        import hadal.grid.sonar as sonar
        def run():
            tempfile.tempdir = {str(tmp)!r}
            sonar._GSF_TMP_RESERVE = shutil.disk_usage({str(tmp)!r}).free - (64 << 20)
            return len(sonar.read_multibeam({str(p)!r}))
    """)
    _one_line_error(out, "decompressing this gzip GSF file needs more than")
    assert not any(tmp.iterdir()) and tempfile.gettempdir() != str(tmp)


# ----------------------------------------------------------------- measured cost per reader, the stage's budget
def _s7k_record(rtype: int, data: bytes, opt: bytes = b"") -> bytes:
    """One 7k record [Teledyne RESON DFD, DRF v5]: 64-byte frame, ``data``, optional data, u32 checksum (flag 1)."""
    import struct

    size = 64 + len(data) + len(opt) + 4
    t7k = struct.pack("<HHfBB", 2019, 131, 30.5, 20, 46)
    drf = struct.pack("<HHIIII10sHIIHHIHHIII", 5, 60, 0x0000FFFF, size, 64 + len(data) if opt else 0, 0, t7k, 1,
                      rtype, 7125, 0, 0, 0, 1, 0, 0, 0, 0)
    body = drf + data + opt
    return body + struct.pack("<I", sum(body) & 0xFFFFFFFF)


def _s7k_ping(nb: int = 400) -> bytes:
    """A 7027 raw-detection record of ``nb`` detections with the optional bathymetry block (DFD layout: f32
    frequency, f64 latitude, f64 longitude, f32 heading (rad), u8, 5 x f32; per detection f32 depth, along, across,
    pointing, azimuth): depths 5000 + (i % 97) m, across-track -4 .. 4 km, at 11.3 N 142.2 E heading north."""
    import math
    import struct

    rth = struct.pack("<QIHIIBIfff60x", 1, 42, 0, nb, 34, 2, 0, 34000.0, 0.0, 0.0)
    dets = b"".join(struct.pack("<HffIIffff", i, 100.0 + i, 0.1 * i, 1, 3, 0, 0, 0, 0) for i in range(nb))
    opt = struct.pack("<fddfBfffff", 400e3, math.radians(11.3), math.radians(142.2), 0.0, 0, 0, 0, 0, 0, 0)
    opt += b"".join(struct.pack("<fffff", 5000.0 + (i % 97), 0.0, -4000.0 + 8000.0 * i / (nb - 1), 0, 0)
                    for i in range(nb))
    return _s7k_record(7027, rth + dets, opt)


@pytest.mark.integration  # ~2 min: the 1.6e8 soundings are decoded up to the budget
def test_s7k_soundings_past_the_budget(tmp_path):
    """The real TN136 .s7k's records, then a 7027 ping of 4,000 georeferenced soundings repeated 40,000 times (1.6e8
    soundings, 3.2 GB, a gzip of a few MB): each ping valid, their sum refused in one line as they decode, peak under
    2 GiB (the 4 GiB cap of the red team)."""
    ping = _s7k_ping(4000)
    p = _compressed(tmp_path / "bomb.s7k", _real(S7K), ping, 40_000 * len(ping))
    out = _run_capped(_read_swath(p))
    _one_line_error(out, "decoding this s7k multibeam file needs more than")
    assert "limit" in out["message"], out
    print(f"s7k bomb: peak {out['peak'] / 2**20:.0f} MiB; {out['message'].split(': ', 1)[1]}")
    assert out["peak"] < 2 * GIB, out


def _swath_file(tmp_path: Path, fmt: str, soundings: int) -> tuple[Path, Path, int]:
    """A file of ``fmt`` with about ``soundings`` soundings made by repeating a real file's ping (the .s7k: the
    ping of :func:`_s7k_ping` after the real file's records), gzip-compressed; the file of one unit (the oracle's);
    the soundings it holds."""
    import gzip

    if fmt == "em_all":
        data = _real(EM_ALL)
        k = soundings // 572
        one, body, total = data, data + _em_depths(data) * k, 572 * (k + 1)
    elif fmt == "kmall":
        data = _real(KMALL)
        k = soundings // 393
        one, body, total = data, b"".join(_kmall_mrz(data, time_s=1_557_607_590 + i) for i in range(k)), 393 * k
    elif fmt == "s7k":
        k = soundings // 400
        one, body, total = _real(S7K) + _s7k_ping(), _real(S7K) + _s7k_ping() * k, 400 * k
    elif fmt == "gsf":  # the real EX1604 file's first ping repeated: its soundings are counted by the oracle's read
        data = _real(GSF)
        recs = _gsf_records(data)
        first = next(o for r, o, sz in recs if r == 2)
        ping = next(data[o:o + sz] for r, o, sz in recs if r == 2)
        k = soundings // 400
        one, body, total = data[:first] + ping, data[:first] + ping * k, -k
    else:  # xyz text
        lines = "".join(f"{142.2 + 1e-5 * (i % 1000):.5f} {11.3 + 1e-5 * (i // 1000 % 1000):.5f} {5000 + i % 97}\n"
                        for i in range(10_000)).encode()
        k = soundings // 10_000
        one, body, total = lines, lines * k, 10_000 * k
    ref = tmp_path / f"one.{fmt}"
    ref.write_bytes(one)
    p = tmp_path / f"many.{fmt}"
    with gzip.open(p, "wb", compresslevel=1) as f:
        f.write(body)
    return p, ref, total


@pytest.mark.parametrize("margin", [1.03, 0.97])
@pytest.mark.parametrize("fmt", ["em_all", "kmall", "s7k", "xyz", "gsf"])
def test_swath_file_just_under_and_over_the_sounding_budget(tmp_path, fmt, margin):
    """A file whose measured read cost (SOUNDING_READ_COST: fixed + soundings x bytes per sounding of its reader) is
    3 % under (over) the stage's budget (``memory_limit_bytes`` of the DTM stage's read): read whole, every sounding
    and the depths of the one-ping file (the oracle), with a peak RSS above the start under the budget; else refused
    in one line as it decodes. The budget counted 84 B a sounding for every reader before (30-90 B measured)."""
    from hadal.grid.sonar import SOUNDING_READ_COST

    n = {"em_all": 1_500_000, "kmall": 400_000, "s7k": 1_500_000, "xyz": 1_500_000, "gsf": 1_500_000}[fmt]
    p, one, total = _swath_file(tmp_path, fmt, n)
    fixed, per = SOUNDING_READ_COST[fmt]
    code = """
        import numpy, pandas  # before the baseline, as in the bench that measured SOUNDING_READ_COST
        import hadal.grid.sonar
        from hadal.grid.soundings import read_soundings_xy
        def run():
            x, y, dep, frame, used = read_soundings_xy([%r], None, memory_limit_bytes=%r)
            return [int(dep.size), float(dep.min()), float(dep.max())]
    """
    ref = _run_capped(code % (str(one), None))["result"]
    if total < 0:  # -k: k copies of the one-ping file's soundings
        total = -total * ref[0]
    limit = (fixed + total * per) * margin
    out = _run_capped(code % (str(p), limit))
    if margin > 1:
        assert "error" not in out, out
        assert out["result"] == [total, ref[1], ref[2]], (ref, out)
    else:
        _one_line_error(out, "multibeam file needs more than")
        assert "limit" in out["message"], out
    print(fmt, margin, f"peak - base {(out['peak'] - out['base']) / 2**20:.0f} MiB, limit {limit / 2**20:.0f} MiB")
    assert out["peak"] - out["base"] < limit, (out, limit)


def test_stage_budgets_honour_resources_max_memory_gb(tmp_path):
    """``resources.max_memory_gb`` is the budget of the readers a stage calls (it was the machine's before): a tiny
    dive's ingest (from its MCAP, its CSV logs, or a real .cnv cast) and an xyz dive's DTM stage, fine under the
    default budget, are refused in one line naming the configured limit when it is set below what their reads need
    (the MCAP budget: the chunks and the kept messages; CSV/.cnv: the decoded columns; the soundings': the xyz
    reader's measured cost)."""
    import os
    import shutil
    import sys
    import warnings

    import yaml

    from hadal.dive import load_dive
    from hadal.errors import InputError
    from hadal.geo import LocalFrame
    from hadal.pipeline import make_context, run_stage
    from hadal.settings import PipelineConfig
    from hadal.stages import StageContext, ingest
    from hadal.store import ProductStore

    sys.path.insert(0, str(Path(__file__).parents[1] / "malformed"))
    from tiny_dive import write_dive

    raw = write_dive(tmp_path / "raw", 30.0)
    cnv = tmp_path / "cnv" / "raw"
    write_dive(cnv, 5.0)
    shutil.copy(Path(os.environ.get("HADAL_SHARED_DATA", "/work/shared/data")) / "formats-real"
                / "sbs_SBE19plus_01906398_2019_07_15_0033_cropped.cnv", cnv / "cast.cnv")
    y = yaml.safe_load((cnv / "dive.yaml").read_text())
    y["sources"] = {"cnv": ["cast.cnv"]}
    (cnv / "dive.yaml").write_text(yaml.safe_dump(y))
    for source, d, what in (("mcap", raw, "MCAP"), ("csv", raw, "CSV file"), ("cnv", cnv, "CNV file")):
        dive, rdir = load_dive(d)
        for limit_gb in (None, 1e-6):
            res = {} if limit_gb is None else {"resources": {"max_memory_gb": limit_gb}}
            ctx = StageContext(dive=dive, raw_dir=rdir, store=ProductStore(tmp_path / f"store-{source}{limit_gb}"),
                               config=PipelineConfig.model_validate({"ingest": {"source": source}, **res}))
            if limit_gb is None:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    assert len(ingest.run(ctx)["sensors"].file("sensors.parquet").read_bytes()) > 0
            else:
                with pytest.raises(InputError) as ei:
                    ingest.run(ctx)
                msg = str(ei.value)
                assert "\n" not in msg and f"decoding this {what}" in msg and "limit 1.05 KiB)" in msg, msg

    frame = LocalFrame(11.33, 142.2)
    rng = np.random.default_rng(0)
    mb = tmp_path / "mb" / "raw"
    (mb / "mb").mkdir(parents=True)
    x, y = rng.uniform(-1000, 1000, 3000), rng.uniform(-800, 800, 3000)
    lon, lat = frame.to_lonlat(x, y)
    np.savetxt(mb / "mb" / "line.xyz", np.column_stack([lon, lat, 8000 + 0.02 * x]), fmt="%.8f %.8f %.3f")
    dive_yaml = {"dive_id": "B001", "platform": "test", "launch": {"latitude_deg": 11.33, "longitude_deg": 142.2},
                 "map_frame": {"origin_latitude_deg": 11.33, "origin_longitude_deg": 142.2},
                 "sources": {"multibeam": ["mb/line.xyz"]}}
    (mb / "dive.yaml").write_text(yaml.safe_dump(dive_yaml))
    (mb / "pipeline.yaml").write_text(yaml.safe_dump({"grid": {"dtm_resolution_m": 50.0},
                                                      "resources": {"max_memory_gb": 0.01}}))
    with pytest.raises(InputError) as ei:
        run_stage("grid", make_context(mb, tmp_path / "mb" / "store"))
    msg = str(ei.value)
    assert "\n" not in msg and "decoding this multibeam file needs more than" in msg and "limit 10.2 MiB)" in msg, msg


# ----------------------------------------------------------------- point clouds (LAS/LAZ, PCD, PLY, xyz)
def _cloud(tmp_path: Path, fmt: str, n: int) -> Path:
    """A cloud of ``n`` points (a 1 km square, z -5000 .. -4900 m) in ``fmt``, written by the format's own library
    (laspy/lazrs, pypcd4, open3d) or as text, in chunks for LAS/LAZ."""
    rng = np.random.default_rng(45)
    if fmt in ("las", "laz"):
        import laspy

        header = laspy.LasHeader(point_format=0, version="1.2")
        header.scales, header.offsets = [0.01, 0.01, 0.01], [0.0, 0.0, -5000.0]
        p = tmp_path / f"cloud.{fmt}"
        with laspy.open(str(p), mode="w", header=header,
                        laz_backend=laspy.LazBackend.Lazrs if fmt == "laz" else None) as w:
            for k in range(0, n, 1_000_000):
                m = min(1_000_000, n - k)
                rec = laspy.ScaleAwarePointRecord.zeros(m, header=header)
                rec.x, rec.y, rec.z = rng.uniform(0, 1000, m), rng.uniform(0, 1000, m), rng.uniform(-5000, -4900, m)
                w.write_points(rec)
        return p
    xyz = np.column_stack([rng.uniform(0, 1000, n), rng.uniform(0, 1000, n), rng.uniform(-5000, -4900, n)])
    p = tmp_path / f"cloud.{fmt}"
    if fmt == "pcd":
        from pypcd4 import PointCloud

        PointCloud.from_xyz_points(xyz.astype(np.float32)).save(str(p))
    elif fmt == "ply":
        import open3d as o3d

        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(xyz))
        o3d.io.write_point_cloud(str(p), pc, write_ascii=False)
    else:
        np.savetxt(p, xyz, fmt="%.3f")
    return p


#: what each cloud reader holds per point against its budget (counted here from the formats, the oracle of the
#: readers' own counting): the (n, 3) float64 points and their 3 working copies; PCD its record too (3 float32),
#: PLY open3d's own float64 triple; xyz text 3 growable float64 columns x 3 copies (their capacity: up to twice)
_CLOUD_BYTES = {"las": 24 * 3, "laz": 24 * 3, "pcd": 12 + 24 * 3, "ply": 24 * 4, "xyz": 24 * 3}


@pytest.mark.parametrize("fmt", ["las", "laz", "pcd", "ply", "xyz"])
def test_point_cloud_under_and_over_its_budget(tmp_path, fmt):
    """A cloud of 2e6 points of each format: read whole under a budget 1.5x what its reader counts (every point as
    the format's library reads it, the oracle: laspy, pypcd4, open3d, numpy.loadtxt), with a peak RSS above the
    start under that budget; refused in one line naming the file and the limit under half of it (the readers were
    held against the machine's memory, not ``resources.max_memory_gb``, and LAZ not at all as it decoded)."""
    n = 2_000_000
    p = _cloud(tmp_path, fmt, n)
    need = n * _CLOUD_BYTES[fmt] * (2 if fmt == "xyz" else 1)
    code = """
        import numpy
        from hadal.grid.readers import read_point_cloud_meta
        def run():
            pts, meta = read_point_cloud_meta(%r, memory_limit_bytes=%r)
            return [len(pts), float(pts[:, 2].sum()), float(pts[:, 0].max())]
    """
    out = _run_capped(code % (str(p), 1.5 * need))
    assert "error" not in out, out
    if fmt in ("las", "laz"):
        import laspy

        las = laspy.read(str(p))
        ref = [len(las.points), float(np.asarray(las.z).sum()), float(np.asarray(las.x).max())]
    elif fmt == "pcd":
        from pypcd4 import PointCloud

        a = PointCloud.from_path(p).numpy(("x", "y", "z")).astype(np.float64)
        ref = [len(a), float(a[:, 2].sum()), float(a[:, 0].max())]
    elif fmt == "ply":
        import open3d as o3d

        a = np.asarray(o3d.io.read_point_cloud(str(p)).points)
        ref = [len(a), float(a[:, 2].sum()), float(a[:, 0].max())]
    else:
        a = np.loadtxt(p)
        ref = [len(a), float(a[:, 2].sum()), float(a[:, 0].max())]
    assert out["result"][0] == ref[0] == n and out["result"][2] == ref[2], (out, ref)
    assert out["result"][1] == pytest.approx(ref[1], rel=1e-12), (out, ref)
    print(fmt, f"peak - base {(out['peak'] - out['base']) / 2**20:.0f} MiB, budget {1.5 * need / 2**20:.0f} MiB")
    assert out["peak"] - out["base"] < 1.5 * need, out
    out = _run_capped(code % (str(p), 0.5 * need))
    _one_line_error(out, "point cloud needs more than")
    assert str(p) in out["message"] and "limit" in out["message"], out


def test_laz_whose_header_claims_many_points(tmp_path):
    """A LAZ of 1,000 points whose header claims 2e9 (laspy would allocate for the claim; a LAZ's size says nothing
    of its count): refused in one line before anything is allocated, peak under 0.25 GiB above the start; and a
    LAZ holding 3e7 points (a few MB of compressed repeats) past a 0.5 GiB budget is refused as it decodes, its
    peak under the budget."""
    import struct

    p = _cloud(tmp_path, "laz", 1000)
    data = bytearray(p.read_bytes())
    assert struct.unpack_from("<I", data, 107)[0] == 1000  # LAS 1.2 header: legacy point count at byte 107
    struct.pack_into("<I", data, 107, 2_000_000_000)
    lie = tmp_path / "lie.laz"
    lie.write_bytes(bytes(data))
    code = """
        from hadal.grid.readers import read_point_cloud_meta
        def run():
            return len(read_point_cloud_meta(%r, memory_limit_bytes=%r)[0])
    """
    out = _run_capped(code % (str(lie), None))
    _one_line_error(out, "its header declares 2,000,000,000 points")
    assert out["peak"] - out["base"] < GIB / 4, out
    import laspy

    header = laspy.LasHeader(point_format=0, version="1.2")
    big = tmp_path / "many.laz"
    rec = laspy.ScaleAwarePointRecord.zeros(1_000_000, header=header)
    with laspy.open(str(big), mode="w", header=header, laz_backend=laspy.LazBackend.Lazrs) as w:
        for _ in range(30):
            w.write_points(rec)
    assert big.stat().st_size < 64 << 20
    out = _run_capped(code % (str(big), GIB / 2))
    _one_line_error(out, "decoding this LAS/LAZ point cloud needs more than")
    assert out["peak"] - out["base"] < GIB / 2, out


def test_ply_whose_header_claims_many_vertices(tmp_path):
    """A binary PLY of 10 vertices whose header claims 2e9 (open3d sizes its arrays by the claim, 48 GB):
    refused in one line before open3d reads it, peak under 0.25 GiB above the start."""
    p = tmp_path / "lie.ply"
    p.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 2000000000\nproperty double x\n"
                  b"property double y\nproperty double z\nend_header\n" + np.zeros(30).tobytes())
    out = _run_capped(f"""
        from hadal.grid.readers import read_point_cloud_meta
        def run():
            return len(read_point_cloud_meta({str(p)!r})[0])
    """)
    _one_line_error(out, "its header declares 2,000,000,000 vertices")
    assert out["peak"] - out["base"] < GIB / 4, out


# ----------------------------------------------------------------- derive's re-reads of raw Sea-Bird files
def test_derive_rereads_of_an_xz_cnv_are_held_against_the_budget(tmp_path):
    """derive re-reads raw Sea-Bird files after the ingest (the overlying profile ``derive.overlying_profile``, an
    underway record's per-scan positions): an xz .cnv of 0.26 GB of scans (6e6) is refused in one line as it
    decodes by either re-read given a 256 MiB budget, peak under 0.5 GiB above the start; and the derive stage gives them
    ``resources.max_memory_gb`` (the machine's budget before): a .cnv overlying profile of 2e6 scans, which the
    default budget reads, is refused naming the configured 64 MiB."""
    import sys
    import warnings

    from hadal.dive import load_dive
    from hadal.errors import InputError
    from hadal.settings import PipelineConfig
    from hadal.stages import StageContext, derive, ingest
    from hadal.store import ProductStore

    row = b"     1.000    10.0000   3.500000      0.000\n"
    bomb = _compressed(tmp_path / "bomb.cnv", CNV_HEADER.encode(), row, 6_000_000 * 44, "xz")
    for call in ("from hadal.depth import read_overlying_profile\n"
                 "def run():\n    return str(read_overlying_profile(%r, max_bytes=1 << 28))",
                 "import pandas\nfrom hadal.settings import PipelineConfig\n"
                 "from hadal.stages.derive import underway_table\n"
                 "def run():\n    return len(underway_table(pandas.DataFrame(), %r, PipelineConfig().derive,\n"
                 "                              max_bytes=1 << 28)[0])"):
        out = _run_capped(call % str(bomb))
        _one_line_error(out, "decoding this CNV file needs more than")
        assert "limit 256 MiB)" in out["message"] and out["peak"] - out["base"] < GIB / 2, out

    sys.path.insert(0, str(Path(__file__).parents[1] / "malformed"))
    from tiny_dive import write_dive

    raw = write_dive(tmp_path / "raw", 5.0)
    prof = _compressed(raw / "top.cnv", CNV_HEADER.encode(), row, len(CNV_HEADER) + 2_000_000 * 44, "xz")
    dive, rdir = load_dive(raw)
    store = ProductStore(tmp_path / "store")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ingest.run(StageContext(dive=dive, raw_dir=rdir, store=store, config=PipelineConfig()))
    cfg = PipelineConfig.model_validate({"derive": {"overlying_profile": "top.cnv"},
                                         "resources": {"max_memory_gb": 1 / 16}})
    with pytest.raises(InputError) as ei:
        derive.run(StageContext(dive=dive, raw_dir=rdir, store=store, config=cfg))
    msg = str(ei.value)
    assert "\n" not in msg and msg.startswith(str(prof)) and "limit 64 MiB)" in msg, msg


# ----------------------------------------------------------------- hadal inspect
@pytest.mark.parametrize("kind", ["cnv", "xyz", "mcap", "ply"])
def test_inspect_refuses_a_bomb_in_one_line(tmp_path, kind):
    """``hadal inspect --config`` reads within the configuration's ``resources.max_memory_gb`` (256 MiB here; it
    read against the machine's memory before): a bomb of each kind (an xz .cnv of 6e6 scans, a gzip of 0.5 GiB of
    xyz soundings, an MCAP chunk of 0.5 GiB of zeros, a PLY claiming 2e8 vertices) is one line in the table naming
    the file and the configured limit, a one-line ``error:`` and exit status 2, peak RSS under 0.5 GiB above the
    start; the readers' error text is the oracle of the same limit."""
    if kind == "cnv":
        p = _compressed(tmp_path / "bomb.cnv", CNV_HEADER.encode(), b"     1.000    10.0000   3.500000      0.000\n",
                        6_000_000 * 44, "xz")
    elif kind == "xyz":
        p = _compressed(tmp_path / "bomb.xyz", b"", b"142.1 11.3 5000.0\n", GIB // 2)
    elif kind == "mcap":
        p = _mcap_bomb(tmp_path / "bomb.mcap", GIB // 2, "zstd")
    else:
        p = tmp_path / "bomb.ply"
        p.write_bytes(b"ply\nformat ascii 1.0\nelement vertex 200000000\nproperty float x\nproperty float y\n"
                      b"property float z\nend_header\n1 2 3\n")
    cfg = tmp_path / "pipeline.yaml"
    cfg.write_text("resources:\n  max_memory_gb: 0.25\n")
    out = _run_capped(f"""
        import sys
        sys.path.insert(0, {str(Path(__file__).resolve().parents[1])!r})
        from cli_runner import run_cli
        def run():
            res = run_cli("inspect", "--json", "--config", {str(cfg)!r}, {str(p)!r})
            return [res.returncode, res.stdout, res.stderr]
    """)
    code, stdout, stderr = out["result"]
    assert code == 2 and "Traceback" not in stdout + stderr, out
    errs = [ln for ln in stderr.splitlines() if ln.startswith("error:")]
    assert len(errs) == 1 and "1 of 1 file(s) cannot be read" in errs[0], stderr
    msg = json.loads(stdout)[0]["error"]
    assert "\n" not in msg and msg.startswith(str(p)) and "needs more than" in msg and "limit 256 MiB)" in msg, msg
    assert out["peak"] - out["base"] < GIB / 2, out
