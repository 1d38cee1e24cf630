"""What a raw file is, from its content (magic bytes and the first lines), not from its name.

:func:`detect` returns a :class:`FileKind`: the ``kind`` (one of :data:`KINDS`), the compression wrapper
(``gzip``/``bz2``/``xz`` or ``None``) and the dive source kind it belongs to (:data:`SOURCE_OF`:
``mcap``, ``csv``, ``cnv``, ``multibeam``, ``prior_grid``, ``laser`` or ``None``), plus two finer facts the
readers dispatch on: ``text`` (the decompressed content is text) and ``points`` (numeric text rows of at least
three columns, readable as x y z whatever the kind). The extension is only a tie-breaker where the content is
ambiguous (a NetCDF grid may be a prior map or a laser raster; an ``x y z`` text file may be soundings or a
laser point cloud).

This module is the one place that sniffs content and undoes gzip/bz2/xz: every reader asks :func:`detect`
what a file is (mapping the kind to its own vocabulary; a ``SourceFile.format`` hint overrides it there), and
reads through :func:`open_binary` / :func:`read_bytes` under :func:`decompress_errors`, so a damaged stream is
the same one-line :class:`InputError` everywhere.

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
* Teledyne Slocum ``dbd2asc`` text: first line ``dbd_label: DBD_ASC...`` (a ``csv`` table after its header block);
* GMT native binary grid (``.grd`` "bf"/"bs" etc.) is not sniffed; GMT's default netCDF grids are netCDF.
"""

from __future__ import annotations

import bz2
import codecs
import contextlib
import gzip
import io
import lzma
import re
import struct
import zlib
from collections.abc import Callable
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
    "empty": "empty (0 bytes)",
    "unknown": "not a format hadal reads",
}

#: which ``dive.yaml`` source list a kind goes to by default (``None``: not a dive source)
SOURCE_OF: dict[str, str | None] = {
    "mcap": "mcap", "csv": "csv", "cnv": "cnv", "seabird_hex": "cnv", "xyz": "multibeam", "gsf": "multibeam",
    "kmall": "multibeam", "em_all": "multibeam", "s7k": "multibeam", "geotiff": "prior_grid",
    "netcdf": "prior_grid", "ply": "laser", "pcd": "laser", "las": "laser", "yaml": None, "empty": None,
    "unknown": None,
}

_HEAD_BYTES = 65536
_COMPRESSION = ((b"\x1f\x8b", "gzip"), (b"BZh", "bz2"), (b"\xfd7zXZ\x00", "xz"))
_OPENERS: dict[str, Callable[..., Any]] = {"gzip": gzip.open, "bz2": bz2.open, "xz": lzma.open}
#: what a damaged gzip/bz2/xz stream raises (``gzip.BadGzipFile`` is an ``OSError``)
DECOMPRESS_ERRORS = (OSError, EOFError, lzma.LZMAError, zlib.error, ValueError)
#: the multibeam kinds :func:`detect` recognises in binary content (xyz soundings are text)
SWATH_KINDS = ("gsf", "kmall", "em_all", "s7k")
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
    #: the (decompressed) content is text
    text: bool = False
    #: numeric text rows of >= 3 columns (x y z ...), at least two of them: readable as points or soundings
    points: bool = False

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def compression_of(head: bytes) -> str | None:
    """``gzip``/``bz2``/``xz`` from a file's first bytes, else ``None``."""
    for magic, name in _COMPRESSION:
        if head.startswith(magic):
            return name
    return None


def utf16_of(head: bytes) -> str | None:
    """``"utf-16"`` when ``head`` is UTF-16 text with a byte-order mark (Windows "Unicode" exports of loggers and
    spreadsheets): the BOM, and its first 2 KiB decode to printable text. Binary formats that happen to start
    with ``FF FE`` fail the text test."""
    if not head.startswith((b"\xff\xfe", b"\xfe\xff")) or len(head) < 4:
        return None
    sample = head[:2048]
    sample = sample[:len(sample) - len(sample) % 2]
    try:
        text = sample.decode("utf-16")
    except UnicodeDecodeError:
        return None
    ok = sum(c.isprintable() or c in "\t\r\n" for c in text)
    return "utf-16" if text and ok >= 0.98 * len(text) else None


def text_encoding_of(head: bytes) -> str:
    """``"utf-8"`` when ``head`` (the first bytes of a text file, as :func:`read_head` gives them) is valid UTF-8
    (a character cut at the end allowed), else ``"cp1252"`` (Windows Latin-1: ``°`` ``µ`` in column names of
    older loggers), which decodes any byte."""
    try:
        head.decode("utf-8")
        return "utf-8"
    except UnicodeDecodeError as exc:
        return "utf-8" if exc.start >= len(head) - 3 and exc.reason.startswith("unexpected end") else "cp1252"


class _Utf8FromUtf16(io.RawIOBase):
    """A binary stream of the UTF-8 encoding of a UTF-16 stream (decoded incrementally, BOM dropped), so the
    text readers see UTF-8 whatever the file's encoding."""

    def __init__(self, fh: Any):
        self._fh = fh
        self._dec = codecs.getincrementaldecoder("utf-16")(errors="replace")
        self._buf = b""
        self._eof = False

    def readable(self) -> bool:
        return True

    def readinto(self, b: Any) -> int:
        while not self._buf and not self._eof:
            raw = self._fh.read(1 << 16)
            self._eof = not raw
            self._buf = self._dec.decode(raw, final=self._eof).encode("utf-8")
        n = min(len(b), len(self._buf))
        b[:n] = self._buf[:n]
        self._buf = self._buf[n:]
        return n

    def close(self) -> None:
        self._fh.close()
        super().close()


def open_binary(path: str | Path):
    """Open a file for binary reading, transparently decompressing gzip/bz2/xz (detected by magic bytes) and
    transcoding UTF-16 text (:func:`utf16_of`) to UTF-8."""
    p = Path(path)
    with open(p, "rb") as fh:
        comp = compression_of(fh.read(8))
    fh = _OPENERS[comp](p, "rb") if comp else open(p, "rb")
    try:
        head = fh.peek(4096)[:4096] if hasattr(fh, "peek") else b""
    except DECOMPRESS_ERRORS:
        head = b""
    if utf16_of(head):
        return io.BufferedReader(_Utf8FromUtf16(fh))
    return fh


def _first_line(exc: BaseException) -> str:
    return str(exc).splitlines()[0] if str(exc) else type(exc).__name__


@contextlib.contextmanager
def decompress_errors(path: str | Path, compression: str | None, what: str = ""):
    """Turn a failure while reading (through :func:`open_binary`) into a one-line :class:`InputError` naming the
    file: ``corrupt or truncated gzip file (...)`` for a damaged gzip/bz2/xz stream (``what``, e.g. ``"CNV"``,
    makes it ``gzip-compressed CNV file``), ``cannot read (...)`` for a plain file. InputErrors pass through."""
    try:
        yield
    except InputError:
        raise
    except DECOMPRESS_ERRORS as exc:
        if compression is None:
            msg = str(exc).splitlines()[0] if str(exc) else ""
            raise InputError(f"{path}: cannot read ({type(exc).__name__}: {msg})") from None
        kind = f"{compression}-compressed {what}" if what else compression
        raise InputError(f"{path}: corrupt or truncated {kind} file ({_first_line(exc)})") from None


def _require_file(p: Path, label: str) -> None:
    if not p.is_file():
        raise InputError(f"{p}: {label} does not exist")


def _check_text(p: Path, label: str, content: bytes) -> None:
    """``content`` (a file's decompressed text, or its head) must be text: not blank, no NUL in its first 4 KiB."""
    if not content.strip():
        raise InputError(f"{p}: {label} is empty")
    if b"\x00" in content[:4096]:
        raise InputError(f"{p}: not a {label} (binary content)")


def read_text_head(path: str | Path, what: str, n: int) -> tuple[bytes, str | None]:
    """The first ``n`` decompressed bytes of a text file and its compression, with the one-line errors of
    :func:`read_bytes` (``text=True``): missing, unreadable, empty, binary."""
    p = Path(path)
    label = f"{what} file" if what else "file"
    _require_file(p, label)
    try:
        head, comp = read_head(p, n)
    except OSError as exc:
        raise InputError(f"{p}: cannot read {label} ({exc.strerror or exc})") from None
    _check_text(p, label, head)
    return head, comp


def _decompress_bounded(p: Path, comp: str, what: str, label: str, text: bool, budget: Any) -> bytes:
    """A compressed file's content decoded block by block, each block counted by ``budget`` (a
    :class:`hadal.budget.DecodeBudget`) before the next is read; with ``text``, binary content (a NUL in the first
    4 KiB: a gzip of NUL bytes) is refused after the first block, never decompressed whole."""
    out = bytearray()
    with decompress_errors(p, comp, what), _OPENERS[comp](p, "rb") as fh:
        while True:
            b = fh.read(STREAM_BLOCK_BYTES)
            if not b:
                break
            if text and not out and b"\x00" in b[:4096]:
                raise InputError(f"{p}: not a {label} (binary content)")
            out += b
            budget.hold(len(out), f"{len(out):,} bytes decompressed so far")
    return bytes(out)


def read_bytes(path: str | Path, what: str = "", *, text: bool = False, copies: float = 3.0,
               max_bytes: float | None = None) -> tuple[bytes, str | None]:
    """A file's whole content, decompressed when its first bytes are a gzip/bz2/xz magic (whatever the
    name), and the compression found. Every failure is a one-line :class:`InputError` naming the file and
    ``what`` it should be (e.g. ``"CNV"``): ``CNV file does not exist``, ``cannot read CNV file (...)``, or
    :func:`decompress_errors`' ``corrupt or truncated gzip-compressed CNV file (...)``. ``text``: the content
    must be text, so blank content is ``CNV file is empty`` and a NUL byte in the first 4 KiB is
    ``not a CNV file (binary content)``.

    Memory: the content (decompressed as it streams, never trusting a size) times ``copies`` (the working copies
    the caller makes: its text, its parsed values) is held against ``max_bytes`` (default: the memory budget),
    one :class:`hadal.budget.DecodeBudget`; a compression bomb is a one-line error at the limit."""
    from hadal.budget import DecodeBudget

    p = Path(path)
    label = f"{what} file" if what else "file"
    _require_file(p, label)
    budget = DecodeBudget(p, label, copies=copies, limit_bytes=max_bytes)
    try:
        with open(p, "rb") as fh:
            comp = compression_of(fh.read(8))
        if comp is None:
            budget.hold(p.stat().st_size, f"{p.stat().st_size:,} bytes")
            raw = p.read_bytes()
    except OSError as exc:
        raise InputError(f"{p}: cannot read {label} ({exc.strerror or exc})") from None
    if comp is not None:
        raw = _decompress_bounded(p, comp, what, label, text, budget)
    if utf16_of(raw[:4096]):
        raw = raw.decode("utf-16", errors="replace").encode("utf-8")
    if text:
        _check_text(p, label, raw)
    return raw, comp


#: block size of :func:`iter_blocks` (decompressed bytes per block)
STREAM_BLOCK_BYTES = 4 << 20


def iter_blocks(path: str | Path, what: str = "", *, text: bool = False, block_bytes: int = STREAM_BLOCK_BYTES):
    """A file's (decompressed) content in blocks of ``block_bytes``: what :func:`read_bytes` returns, without
    holding the whole file. Same one-line one-line errors (missing, unreadable, damaged stream, and with
    ``text`` empty or binary content); a damaged stream is reported when the block holding the damage is read."""
    p = Path(path)
    label = f"{what} file" if what else "file"
    _require_file(p, label)
    try:
        fh = open_binary(p)
    except OSError as exc:
        raise InputError(f"{p}: cannot read {label} ({exc.strerror or exc})") from None
    with open(p, "rb") as raw_fh:
        comp = compression_of(raw_fh.read(8))
    blank = True
    with fh, decompress_errors(p, comp, what):
        first = True
        while True:
            b = fh.read(block_bytes)
            if not b:
                break
            if text and first and b"\x00" in b[:4096]:
                raise InputError(f"{p}: not a {label} (binary content)")
            first = False
            blank = blank and not b.strip()
            yield b
    if text and blank:
        raise InputError(f"{p}: {label} is empty")


def read_head(path: str | Path, n: int = _HEAD_BYTES, *, strict: bool = True) -> tuple[bytes, str | None]:
    """The first ``n`` decompressed bytes of a file and its compression. A stream that breaks off (truncated)
    gives what came before it; a corrupt one is an :class:`InputError` unless ``strict`` is false, where it
    too ends the head (a reader then reports the damage when it reads the whole file)."""
    p = Path(path)
    with open(p, "rb") as fh:
        raw = fh.read(n)
    comp = compression_of(raw)
    if comp is not None:
        try:
            with _OPENERS[comp](p, "rb") as fh:
                raw = _read_up_to(fh, n, strict)
        except DECOMPRESS_ERRORS as exc:
            if not strict:
                return b"", comp
            raise InputError(f"{p}: corrupt {comp} stream ({exc})") from None
    if utf16_of(raw):  # UTF-16 text: its first n bytes as UTF-8, as open_binary gives them
        try:
            with open_binary(p) as fh:
                raw = _read_up_to(fh, n, strict)
        except DECOMPRESS_ERRORS as exc:
            if not strict:
                return b"", comp
            raise InputError(f"{p}: corrupt {comp} stream ({exc})") from None
    return raw, comp


def _read_up_to(fh: Any, n: int, strict: bool = True) -> bytes:
    """Up to ``n`` bytes in small pieces: a stream that breaks off loses only the piece it broke in."""
    out = bytearray()
    while len(out) < n:
        try:
            b = fh.read(min(1024, n - len(out)))
        except EOFError:  # truncated stream: what came before is still the file's head
            break
        except DECOMPRESS_ERRORS:
            if strict:
                raise
            break
        if not b:
            break
        out += b
    return bytes(out)


def detect(path: str | Path, *, strict: bool = True) -> FileKind:
    """Detect what a file is from its content. Missing/unreadable files are a one-line :class:`InputError`;
    an unrecognised file is kind ``unknown`` (not an error). ``strict=False`` (readers): a corrupt compressed
    stream is sniffed from what decompressed before the damage instead of raising (see :func:`read_head`)."""
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
        if p.stat().st_size == 0:  # nothing to sniff: say so rather than "not a format hadal reads"
            return FileKind(str(p), "empty", None, None, KINDS["empty"], False, False)
        head, comp = read_head(p, strict=strict)
    except PermissionError:
        raise InputError(f"{p}: permission denied") from None
    except OSError as exc:
        raise InputError(f"{p}: cannot read ({exc.strerror or exc})") from None
    return sniff(head, p.name, p, comp)


def sniff(head: bytes, name: str = "", path: str | Path = "", compression: str | None = None) -> FileKind:
    """:func:`detect` on a file's (decompressed) first bytes already in hand; ``name`` is the tie-breaker."""
    text = _as_text(head) if head else None
    kind = _sniff(head, text, name.lower())
    points = (text is not None and kind in ("xyz", "csv", "unknown") and not _DBD_ASC.match(text.lstrip()[:64])
              and _points(_data_rows(_lines(text))))
    return FileKind(str(path), kind, compression, SOURCE_OF.get(kind), KINDS[kind], text is not None, points)


def is_text(head: bytes) -> bool:
    """The first bytes look like text: no NUL in the first 4 KiB, >= 95 % printable (Latin-1/UTF-8 allowed)."""
    return _as_text(head) is not None


def _sniff(head: bytes, text: str | None, name: str) -> str:
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
    if text is None:  # a binary PCD still has a text header
        return "pcd" if _is_pcd(_lines(head[:1024].decode("latin-1"))[:15]) else "unknown"
    return _text_kind(text, name)


def _binary_kind(head: bytes) -> str | None:
    if len(head) >= 8 and head[4:5] == b"#" and head[5:8].isalpha() and head[5:8].isupper():
        (size,) = struct.unpack("<I", head[:4])  # KMALL: u32 numBytesDgm, then "#" + 3 capital letters
        if 8 <= size < 2**26:
            return "kmall"
    if len(head) >= 8 and head[4:8] == b"\xff\xff\x00\x00":  # s7k DRF: u16 version, u16 offset, u32 0x0000FFFF
        return "s7k"
    if len(head) >= 16 and b"GSF-v" in head[8:16]:  # big-endian size, record id 1 (header), "GSF-v03.xx"
        return "gsf"
    if len(head) >= 8 and head[4] == 0x02 and _em_all_first_datagram(head):
        return "em_all"
    return None


def _em_all_first_datagram(head: bytes) -> bool:
    """A Kongsberg .all file's first datagram in either byte order: u32 length, STX 0x02, type, u16 model ...
    ETX 0x03, u16 checksum (the sum of the bytes between STX and ETX). A datagram whose end is in ``head`` is
    recognised by its ETX and checksum whatever its type (any EM model writes its own first datagram); one longer
    than ``head`` by a datagram type seen first in files."""
    for order in "<>":
        n = struct.unpack(order + "I", head[:4])[0]
        if not 16 <= n < 2**24:
            continue
        if len(head) < n + 4:
            if head[5] in _EM_ALL_TYPES:
                return True
            continue
        body = head[4:n + 4]
        if body[-3] == 0x03 and struct.unpack(order + "H", body[-2:])[0] == (sum(body[1:-3]) & 0xFFFF):
            return True
        if body[-3] == 0x03 and head[5] in _EM_ALL_TYPES:  # a writer that leaves the checksum 0 or wrong
            return True
    return False


def _as_text(head: bytes) -> str | None:
    if b"\x00" in head[:4096]:
        return None
    sample = head[:8192]
    printable = sum(32 <= b < 127 or b in (9, 10, 13) or b >= 128 for b in sample)
    if printable < 0.95 * len(sample):
        return None
    return head.decode("latin-1")


_DOCUMENT_SUFFIXES = (".md", ".rst", ".html", ".htm", ".json", ".inf", ".xml", ".py", ".sh")


def _lines(text: str) -> list[str]:
    """Stripped lines, whatever the line ends."""
    return [ln.strip() for ln in text.replace("\r\n", "\n").replace("\r", "\n").split("\n")]


def _is_pcd(stripped: list[str]) -> bool:
    first = stripped[0] if stripped else ""
    return first.startswith(("# .PCD", "VERSION")) or (
        any(s.startswith("VERSION") for s in stripped[:12]) and any(s.startswith("FIELDS") for s in stripped[:15]))


#: first line of a Teledyne Slocum ``dbd2asc`` text file (``dbd_label: DBD_ASC(dinkum_binary_data)file``)
_DBD_ASC = re.compile(r"^dbd_label:\s*DBD_ASC", re.IGNORECASE)
_CNV_HEADER = re.compile(r"^#\s*(?:name\s+\d+\s*=|nquan\b)")


def _text_kind(text: str, name: str) -> str:
    stripped = _lines(text)
    if "*END*" in (s.upper() for s in stripped):
        end = next(i for i, s in enumerate(stripped) if s.upper() == "*END*")
        header = stripped[:end]
        if any(_CNV_HEADER.match(s) for s in header):
            return "cnv"
        after = [s for s in stripped[end + 1:end + 20] if s]
        if after and all(_HEX_LINE.match(s) for s in after):
            return "seabird_hex"
        if any(s.startswith("* Sea-Bird") or s.startswith("*Sea-Bird") for s in header):
            return "seabird_hex" if not after else "cnv"
    first = stripped[0] if stripped else ""
    if _DBD_ASC.match(first):  # Teledyne Slocum dbd2asc: a header block, then a space-delimited table
        return "csv"
    if _is_pcd(stripped):
        return "pcd"
    if first.startswith("%YAML") or first == "---" or (":" in first and not _numeric_row(first)
                                                       and name.endswith((".yaml", ".yml"))):
        return "yaml"
    data = _data_rows(stripped)
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


def _data_rows(stripped: list[str]) -> list[str]:
    """The non-empty, non-comment lines among the first 200."""
    return [s for s in stripped[:200] if s and not s.startswith(("#", "%", "//"))]


def _points(data: list[str]) -> bool:
    """Numeric rows of >= 3 columns, at least two, are >= 80 % of the rows after the first (maybe a header)."""
    wide = [s for s in data if _numeric_row(s) and len(_split(s)) >= 3]
    return len(wide) >= 2 and len(wide) >= 0.8 * len(data[1:])


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
