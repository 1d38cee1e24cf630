"""What a raw file is, from its content (magic bytes and the first lines), not from its name.

:func:`detect` returns a :class:`FileKind`: the ``kind`` (one of :data:`KINDS`), the compression wrapper
(``gzip``/``bz2``/``xz`` or ``None``) and the dive source kind it belongs to (:data:`SOURCE_OF`:
``mcap``, ``csv``, ``cnv``, ``multibeam``, ``prior_grid``, ``laser`` or ``None``). The extension is only a
tie-breaker where the content is ambiguous (a NetCDF grid may be a prior map or a laser raster; an
``x y z`` text file may be soundings or a laser point cloud).

Signatures (public format documentation):

* MCAP: ``\\x89MCAP0\\r\\n`` (MCAP spec, "Magic");
* HDF5/netCDF-4: ``\\x89HDF\\r\\n\\x1a\\n``; netCDF classic/64-bit: ``CDF\\x01``/``CDF\\x02``/``CDF\\x05``;
* GeoTIFF: ``II*\\0``/``MM\\0*`` (TIFF), ``II+\\0``/``MM\\0+`` (BigTIFF);
* PLY: ``ply`` line; LAS/LAZ: ``LASF``; PCD: ``# .PCD`` or a ``VERSION`` header line;
* Kongsberg .kmall: datagram header (u32 length, ``#`` + 3-letter type such as ``#IIP``/``#MRZ``);
* Kongsberg .all (EM series): u32 length, STX ``0x02``, a datagram type byte, u16 model (little- or big-endian);
* Reson .s7k: data record frame with sync pattern ``0x0000FFFF`` at byte 4;
* GSF: first record is ``GSF_RECORD_HEADER`` whose text starts ``GSF-v`` at byte 8;
* Sea-Bird .cnv: ``*END*`` after ``# name 0 = ...`` lines; Sea-Bird .hex: ``*END*`` followed by hex scans;
* GMT native binary grid (``.grd`` "bf"/"bs" etc.) is not sniffed; GMT's default netCDF grids are netCDF.
"""

from __future__ import annotations

import bz2
import gzip
import lzma
import re
import struct
import zlib
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Any

from hadal.errors import InputError

#: every kind :func:`detect` can return, with a one-line description
KINDS: dict[str, str] = {
    "mcap": "MCAP log (robotics container; JSON or ROS 2 CDR messages)",
    "csv": "delimited text table with a header row",
    "cnv": "Sea-Bird SeaSoft converted CTD cast (.cnv)",
    "seabird_hex": "Sea-Bird raw instrument data (.hex) with calibration in its header",
    "xyz": "numeric text columns (x/lon y/lat z/depth)",
    "gsf": "Generic Sensor Format (GSF) multibeam",
    "kmall": "Kongsberg .kmall multibeam",
    "em_all": "Kongsberg EM .all multibeam",
    "s7k": "Reson/Teledyne .s7k multibeam",
    "geotiff": "GeoTIFF raster",
    "netcdf": "netCDF / HDF5 file",
    "ply": "PLY point cloud",
    "pcd": "PCD point cloud",
    "las": "LAS/LAZ point cloud",
    "yaml": "YAML document",
    "unknown": "not a format hadal reads",
}

#: which ``dive.yaml`` source list a kind goes to by default (``None``: not a dive source)
SOURCE_OF: dict[str, str | None] = {
    "mcap": "mcap", "csv": "csv", "cnv": "cnv", "seabird_hex": "cnv", "xyz": "multibeam", "gsf": "multibeam",
    "kmall": "multibeam", "em_all": "multibeam", "s7k": "multibeam", "geotiff": "prior_grid",
    "netcdf": "prior_grid", "ply": "laser", "pcd": "laser", "las": "laser", "yaml": None, "unknown": None,
}

_HEAD_BYTES = 65536
_COMPRESSION = ((b"\x1f\x8b", "gzip"), (b"BZh", "bz2"), (b"\xfd7zXZ\x00", "xz"))
_OPENERS = {"gzip": gzip.open, "bz2": bz2.open, "xz": lzma.open}
#: Kongsberg EM .all datagram types seen first in files (installation, runtime, position, clock, XYZ 88 ...)
_EM_ALL_TYPES = set(b"IiRPCAXDhUNfkFHnGSJ01") | {0x30, 0x31, 0x33, 0x41, 0x42, 0x43, 0x44, 0x45, 0x47, 0x48,
                                                  0x49, 0x4E, 0x50, 0x52, 0x53, 0x55, 0x57, 0x58, 0x59, 0x66,
                                                  0x68, 0x69, 0x6B, 0x6E, 0x70, 0x72}
_HEX_LINE = re.compile(r"^[0-9A-Fa-f]{6,}$")


@dataclass(frozen=True)
class FileKind:
    """Result of :func:`detect`."""

    path: str
    kind: str
    compression: str | None = None
    source: str | None = None
    description: str = ""

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def compression_of(head: bytes) -> str | None:
    """``gzip``/``bz2``/``xz`` from a file's first bytes, else ``None``."""
    for magic, name in _COMPRESSION:
        if head.startswith(magic):
            return name
    return None


def open_binary(path: str | Path):
    """Open a file for binary reading, transparently decompressing gzip/bz2/xz (detected by magic bytes)."""
    p = Path(path)
    with open(p, "rb") as fh:
        comp = compression_of(fh.read(8))
    return _OPENERS[comp](p, "rb") if comp else open(p, "rb")


def read_head(path: str | Path, n: int = _HEAD_BYTES) -> tuple[bytes, str | None]:
    """The first ``n`` decompressed bytes of a file and its compression. A corrupt compressed stream
    is an :class:`InputError`."""
    p = Path(path)
    with open(p, "rb") as fh:
        raw = fh.read(n)
    comp = compression_of(raw)
    if comp is None:
        return raw, None
    try:
        with _OPENERS[comp](p, "rb") as fh:
            return _read_up_to(fh, n), comp
    except (OSError, EOFError, lzma.LZMAError, zlib.error, ValueError) as exc:
        raise InputError(f"{p}: corrupt {comp} stream ({exc})") from None


def _read_up_to(fh: Any, n: int) -> bytes:
    out = bytearray()
    while len(out) < n:
        try:
            b = fh.read(n - len(out))
        except EOFError:  # truncated stream: what came before is still the file's head
            break
        if not b:
            break
        out += b
    return bytes(out)


def detect(path: str | Path) -> FileKind:
    """Detect what a file is from its content. Missing/unreadable files are a one-line :class:`InputError`;
    an unrecognised file is kind ``unknown`` (not an error)."""
    p = Path(path)
    if p.is_symlink() and not p.exists():
        raise InputError(f"{p}: broken symbolic link")
    if p.is_dir():
        raise InputError(f"{p}: is a directory, not a file")
    if not p.exists():
        raise InputError(f"{p}: file does not exist")
    if not p.is_file():
        raise InputError(f"{p}: not a regular file (a FIFO, socket or device)")
    try:
        head, comp = read_head(p)
    except PermissionError:
        raise InputError(f"{p}: permission denied") from None
    except OSError as exc:
        raise InputError(f"{p}: cannot read ({exc.strerror or exc})") from None
    kind = _sniff(head, p.name.lower())
    return FileKind(str(p), kind, comp, SOURCE_OF.get(kind), KINDS[kind])


def _sniff(head: bytes, name: str) -> str:
    if not head:
        return "unknown"
    if head.startswith(b"\x89MCAP"):
        return "mcap"
    if head.startswith(b"\x89HDF\r\n\x1a\n") or head[:4] in (b"CDF\x01", b"CDF\x02", b"CDF\x05"):
        return "netcdf"
    if head[:4] in (b"II*\x00", b"MM\x00*", b"II+\x00", b"MM\x00+"):
        return "geotiff"
    if head.startswith(b"LASF"):
        return "las"
    if head.startswith(b"ply\n") or head.startswith(b"ply\r\n"):
        return "ply"
    binary = _binary_kind(head)
    if binary:
        return binary
    text = _as_text(head)
    if text is None:
        return "unknown"
    return _text_kind(text, name)


def _binary_kind(head: bytes) -> str | None:
    if len(head) >= 8 and head[4:5] == b"#" and head[5:8].isalpha() and head[5:8].isupper():
        (size,) = struct.unpack("<I", head[:4])
        if 8 <= size < 2**26:
            return "kmall"
    if len(head) >= 8 and head[4:8] == b"\xff\xff\x00\x00":  # s7k DRF: u16 version, u16 offset, u32 0x0000FFFF
        return "s7k"
    if len(head) >= 16 and head[8:13] == b"GSF-v":
        return "gsf"
    if len(head) >= 8 and head[4] == 0x02 and head[5] in _EM_ALL_TYPES:
        le, be = struct.unpack("<I", head[:4])[0], struct.unpack(">I", head[:4])[0]
        if 8 <= le < 2**24 or 8 <= be < 2**24:
            return "em_all"
    return None


def _as_text(head: bytes) -> str | None:
    if b"\x00" in head[:4096]:
        return None
    sample = head[:8192]
    printable = sum(32 <= b < 127 or b in (9, 10, 13) or b >= 128 for b in sample)
    if printable < 0.95 * len(sample):
        return None
    return head.decode("latin-1")


_DOCUMENT_SUFFIXES = (".md", ".rst", ".html", ".htm", ".json", ".inf", ".xml", ".py", ".sh")


def _text_kind(text: str, name: str) -> str:
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    stripped = [ln.strip() for ln in lines]
    if "*END*" in (s.upper() for s in stripped):
        end = next(i for i, s in enumerate(stripped) if s.upper() == "*END*")
        header = stripped[:end]
        if any(s.startswith("# name ") for s in header) or any(s.startswith("# nquan") for s in header):
            return "cnv"
        after = [s for s in stripped[end + 1:end + 20] if s]
        if after and all(_HEX_LINE.match(s) for s in after):
            return "seabird_hex"
        if any(s.startswith("* Sea-Bird") or s.startswith("*Sea-Bird") for s in header):
            return "seabird_hex" if not after else "cnv"
    first = stripped[0] if stripped else ""
    if first.startswith("# .PCD") or first.startswith("VERSION") or (
            first.startswith("#") and any(s.startswith("VERSION") for s in stripped[:5])
            and any(s.startswith("FIELDS") for s in stripped[:15])):
        return "pcd"
    if first.startswith("%YAML") or first == "---" or (":" in first and not _numeric_row(first)
                                                       and name.endswith((".yaml", ".yml"))):
        return "yaml"
    data = [s for s in stripped[:200] if s and not s.startswith(("#", "%", "//"))]
    if not data or (name.endswith(_DOCUMENT_SUFFIXES) and not _numeric_row(data[-1])):
        return "unknown"
    numeric = [s for s in data if _numeric_row(s)]
    if len(numeric) >= max(1, int(0.8 * len(data[1:] or data))) and numeric:
        ncol = len(_split(numeric[0]))
        header_is_text = not _numeric_row(data[0])
        if header_is_text and ("," in data[0] or ";" in data[0] or "\t" in data[0]) and ncol > 3:
            return "csv"
        if ncol >= 3:
            return "xyz"
        return "csv" if header_is_text else "unknown"
    if ("," in data[0] or ";" in data[0] or "\t" in data[0]) and len(data) >= 2:
        return "csv"
    return "unknown"


def _split(row: str) -> list[str]:
    for sep in (",", ";", "\t"):
        if sep in row:
            return [t.strip() for t in row.split(sep)]
    return row.split()


def _numeric_row(row: str) -> bool:
    toks = [t for t in _split(row) if t != ""]
    if not toks:
        return False
    try:
        for t in toks:
            float(t)
    except ValueError:
        return False
    return True
