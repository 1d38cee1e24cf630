"""Peak memory per decoded sounding of every multibeam reader (xyz text, EM .all, KMALL, GSF, s7k), and of a large
xyz.gz through the streaming reader vs plain ``pandas.read_csv`` (the peer).

Run on demand (not part of the tests)::

    .venv/bin/python bench/bench_soundings_memory.py [--points 1250000,5000000] [--formats xyz,em_all,kmall,gsf,s7k]
    .venv/bin/python bench/bench_soundings_memory.py --pandas [--points 10000000]

**Per reader** (the numbers behind :data:`hadal.grid.sonar.SOUNDING_READ_COST`): a file of each format with
about ``points`` soundings is written by repeating a real file's pings (``$HADAL_SHARED_DATA/formats-real`` and
``bathy-real``; .s7k: 7027 records with the DFD's optional bathymetry block, built here, the real .s7k having none),
gzip-compressed as it is written. Each is read in a fresh interpreter (so each peak is its own) by:

* ``dtm``  - :func:`hadal.grid.soundings.read_soundings_xy`, the DTM stage's read (x, y, depth kept);
* ``read`` - :func:`hadal.grid.sonar.read_multibeam` (one DataFrame, lon/lat/depth + ping);
* ``gsf child`` (GSF only) - what the libgsf child process of :func:`hadal.grid.readers.read_gsf` does, in-process.

The peak is the child's ``VmHWM`` (the kernel's count; ``ru_maxrss`` carries the parent's over fork + exec) minus
its ``VmHWM`` after the imports, divided by the soundings read: bytes per sounding with every working copy. The
decoded float64 lon, lat, depth (24 B/sounding) is printed beside it as the reference ratio.
"""

from __future__ import annotations

import argparse
import gzip
import json
import math
import os
import struct
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

CHILD = r"""
import json, sys, time, warnings
warnings.simplefilter("ignore")
import numpy as np, pandas as pd
from hadal.grid.sonar import iter_multibeam, read_multibeam
from hadal.grid.soundings import read_soundings_xy
def hwm():
    with open("/proc/self/status") as f:
        return next(int(l.split()[1]) * 1024 for l in f if l.startswith("VmHWM:"))
mode, path = sys.argv[1], sys.argv[2]
if mode == "gsf_child":  # libgsf reads a plain file: decompressed before the baseline, as _iter_gsf does
    import gzip, shutil, tempfile
    from pathlib import Path
    td = tempfile.mkdtemp()
    with gzip.open(path, "rb") as src, open(Path(td) / "s.gsf", "wb") as dst:
        shutil.copyfileobj(src, dst)
    path = str(Path(td) / "s.gsf")
base = hwm()
t = time.perf_counter()
if mode == "dtm":
    n = int(read_soundings_xy([path], None)[2].size)
elif mode == "read":
    n = len(read_multibeam(path))
elif mode == "gsf_child":
    from hadal.grid._gsf_child import main
    assert main([path, str(Path(td) / "s.parquet"), "0"]) == 0
    n = len(pd.read_parquet(Path(td) / "s.parquet", columns=["ping"]))
    shutil.rmtree(td)
elif mode == "iter_multibeam":
    n = sum(len(c) for c in iter_multibeam(path))
else:
    n = len(pd.read_csv(path, sep=r"\s+", header=None))
dt = time.perf_counter() - t
print(json.dumps({"mode": mode, "n": n, "baseline": base, "peak": hwm(), "seconds": dt}))
"""


# ----------------------------------------------------------------------------------- writers of each format
def _real(name: str) -> bytes:
    root = Path(os.environ.get("HADAL_SHARED_DATA", "/work/shared/data"))
    for sub in ("formats-real", "bathy-real"):
        if (root / sub / name).is_file():
            return (root / sub / name).read_bytes()
    raise SystemExit(f"real file {name} not found under {root} (set HADAL_SHARED_DATA)")


def _repeat(path: Path, head: bytes, unit: bytes, per_unit: int, points: int, edit=None) -> int:
    """``head`` then ``unit`` (``per_unit`` soundings) repeated for about ``points`` soundings, gzip level 1.
    ``edit(k)`` (optional) gives the k-th unit instead. Returns the soundings written (beyond the head's)."""
    n = max(1, math.ceil(points / per_unit))
    with gzip.open(path, "wb", compresslevel=1) as f:
        f.write(head)
        if edit is None:
            batch = max(1, (8 << 20) // len(unit))
            for s in range(0, n, batch):
                f.write(unit * min(batch, n - s))
        else:
            for k in range(n):
                f.write(edit(k))
    return n * per_unit


def write_xyz(path: Path, points: int, seed: int = 0, chunk: int = 1_000_000) -> int:
    rng = np.random.default_rng(seed)
    with gzip.open(path, "wb", compresslevel=1) as fh:
        for s in range(0, points, chunk):
            m = min(chunk, points - s)
            a = np.column_stack([142.2 + rng.uniform(0, 0.5, m), 11.3 + rng.uniform(0, 0.5, m),
                                 8000 + rng.uniform(-500, 500, m)])
            np.savetxt(fh, a, fmt="%.7f %.7f %.2f")
    return points


def write_em_all(path: Path, points: int) -> int:
    """The real EM 120 .all (3 Depth datagrams, 572 valid soundings) with its Depth datagrams repeated."""
    data = _real("mbsys_nbp1403-filtered-em120.all")
    off, depth = 0, []
    while off < len(data):
        n = struct.unpack_from("<I", data, off)[0]
        if data[off + 5] == ord("D"):
            depth.append(data[off:off + 4 + n])
        off += 4 + n
    return 572 + _repeat(path, data, b"".join(depth), 572, points)


def write_kmall(path: Path, points: int) -> int:
    """The real #MRZ ping (393 valid soundings) repeated, one ping a second (time: u32 s at byte 12)."""
    data = _real("kongsberg_em_driver_MRZ_versionF.kmall")

    def ping(k: int) -> bytes:
        d = bytearray(data)
        struct.pack_into("<I", d, 12, 1_557_607_590 + k)
        return bytes(d)

    return _repeat(path, b"", data, 393, points, edit=ping)


def write_gsf(path: Path, points: int) -> int:
    """The real EX1604 GSF's first swath ping (record id 2) repeated after the file's leading records."""
    data = _real("0029_20160323_185603_EX1604_MB.gsf.mb121")
    off, recs = 0, []
    while off < len(data):
        n, rid = struct.unpack_from(">II", data, off)
        size = 8 + n + (-n % 4)
        recs.append((rid & 0x7FFFFFFF, off, size))
        off += size
    first = next(o for r, o, s in recs if r == 2)
    ping = next(data[o:o + s] for r, o, s in recs if r == 2)
    probe = path.with_suffix(".one.gsf")  # soundings of one ping: read it (the reader drops flagged beams)
    probe.write_bytes(data[:first] + ping)
    sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
    from hadal.grid.readers import read_gsf

    per = len(read_gsf(probe))
    probe.unlink()
    return _repeat(path, data[:first], ping, per, points)


def s7k_record(rtype: int, data: bytes, opt: bytes = b"", t_s: float = 30.5) -> bytes:
    """One 7k record (DRF v5, 64 bytes; checksum flag set, u32 byte sum at the end)."""
    size = 64 + len(data) + len(opt) + 4
    t7k = struct.pack("<HHfBB", 2019, 131, t_s, 20, 46)
    drf = struct.pack("<HHIIII10sHIIHHIHHIII", 5, 60, 0x0000FFFF, size, 64 + len(data) if opt else 0, 0, t7k, 1,
                      rtype, 7125, 0, 0, 0, 1, 0, 0, 0, 0)
    body = drf + data + opt
    return body + struct.pack("<I", sum(body) & 0xFFFFFFFF)


def s7k_ping(nb: int = 512) -> bytes:
    """A 7027 raw-detection record of ``nb`` detections with the optional bathymetry block (DFD layout): a
    swath of depths 5000-5100 m, across-track -5 km .. 5 km, at 11.3 N 142.2 E heading north."""
    rth = struct.pack("<QIHIIBIfff60x", 1, 42, 0, nb, 34, 2, 0, 34000.0, 0.0, 0.0)
    dets = b"".join(struct.pack("<HffIIffff", i, 100.0 + i, 0.1 * i, 1, 3, 0, 0, 0, 0) for i in range(nb))
    opt = struct.pack("<fddfBfffff", 400e3, math.radians(11.3), math.radians(142.2), 0.0, 0, 0, 0, 0, 0, 0)
    across = np.linspace(-5000.0, 5000.0, nb)
    opt += b"".join(struct.pack("<fffff", 5000.0 + (i % 101), 0.0, a, 0, 0) for i, a in enumerate(across))
    return s7k_record(7027, rth + dets, opt)


def write_s7k(path: Path, points: int) -> int:
    """The real TN136 .s7k's records, then a 7027 ping of 512 soundings repeated."""
    return _repeat(path, _real("mbsys_TN136HS.309.snipped.s7k"), s7k_ping(512), 512, points)


WRITERS = {"xyz": write_xyz, "em_all": write_em_all, "kmall": write_kmall, "gsf": write_gsf, "s7k": write_s7k}


def _run(mode: str, path: Path) -> dict:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(Path(__file__).resolve().parents[1] / "src"),
                                                        os.environ.get("PYTHONPATH", "")])}
    r = subprocess.run([sys.executable, "-c", CHILD, mode, str(path)], capture_output=True, text=True, env=env)
    if r.returncode:
        return {"mode": mode, "failed": (r.stderr.strip().splitlines() or [f"exit {r.returncode}"])[-1]}
    return json.loads(r.stdout.strip().splitlines()[-1])


def per_reader(sizes: list[int], formats: list[str], tmp: Path) -> None:
    """Each format at each size in ``sizes``; with two sizes or more, the slope (bytes per sounding) between the
    smallest and the largest and the intercept (fixed bytes) at the largest: the model the budget counts."""
    print(f"{'format':7} {'mode':10} {'soundings':>11} {'file MiB':>9} {'peak-base MiB':>14} {'B/sounding':>11} "
          f"{'x float64 xyz':>14} {'s':>6}")
    fits = []
    for fmt in formats:
        modes = ("dtm", "read", "gsf_child") if fmt == "gsf" else ("dtm", "read")
        got: dict[str, list[tuple[int, int]]] = {m: [] for m in modes}
        for points in sizes:
            path = tmp / f"s.{fmt}.gz"
            WRITERS[fmt](path, points)
            for mode in modes:
                d = _run(mode, path)
                if "failed" in d:
                    print(f"{fmt:7} {mode:10} failed: {d['failed']}")
                    continue
                extra = d["peak"] - d["baseline"]
                got[mode].append((d["n"], extra))
                print(f"{fmt:7} {mode:10} {d['n']:11,} {path.stat().st_size / 2**20:9.1f} {extra / 2**20:14.0f} "
                      f"{extra / d['n']:11.1f} {extra / d['n'] / 24:14.2f} {d['seconds']:6.1f}", flush=True)
            path.unlink()
        for mode, pts in got.items():
            if len(pts) >= 2:
                (n0, e0), (n1, e1) = min(pts), max(pts)
                slope = (e1 - e0) / (n1 - n0)
                fits.append((fmt, mode, slope, e1 - slope * n1))
    if fits:
        sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "src"))
        from hadal.grid.sonar import SOUNDING_READ_COST

        print(f"\n{'format':7} {'mode':10} {'B/sounding (slope)':>19} {'fixed MiB':>10} {'slope / 24 B':>13}  "
              "counted by the budget (B/sounding, fixed MiB)")
        for fmt, mode, slope, fixed in fits:
            c_fixed, c_per = SOUNDING_READ_COST["gsf_child" if mode == "gsf_child" else fmt]
            print(f"{fmt:7} {mode:10} {slope:19.1f} {fixed / 2**20:10.1f} {slope / 24:13.2f}  "
                  f"{c_per:.0f}, {c_fixed / 2**20:.0f}")


def vs_pandas(points: int, tmp: Path, keep: Path | None) -> None:
    path = keep or tmp / "soundings.xyz.gz"
    if not path.exists():
        write_xyz(path, points)
    decoded = points * 3 * 8
    print(f"decoded float64 points: {decoded / 2**20:.0f} MiB")
    for mode in ("read", "iter_multibeam", "pandas.read_csv"):
        d = _run(mode, path)
        if "failed" in d:
            print(f"{mode}: failed: {d['failed']}")
            continue
        extra = d["peak"] - d["baseline"]
        print(f"{mode:16s} n={d['n']:,}  baseline {d['baseline'] / 2**20:6.0f} MiB  peak {d['peak'] / 2**20:6.0f} "
              f"MiB  (peak-baseline)/decoded {extra / decoded:5.2f}x  {d['seconds']:.1f} s")


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--points", default="1250000,5000000",
                    help="soundings per file, comma-separated sizes (two or more: slope and intercept)")
    ap.add_argument("--formats", default=",".join(WRITERS))
    ap.add_argument("--pandas", action="store_true", help="the xyz.gz reader against pandas.read_csv instead")
    ap.add_argument("--keep", type=Path, default=None, help="(--pandas) write (or reuse) the xyz.gz here")
    a = ap.parse_args(argv)
    t = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="hadal-bench-sound-") as td:
        if a.pandas:
            vs_pandas(int(a.points.split(",")[-1]), Path(td), a.keep)
        else:
            per_reader([int(x) for x in a.points.split(",")], [f for f in a.formats.split(",") if f], Path(td))
    print(f"({time.perf_counter() - t:.0f} s)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
