"""MCAP reader: JSON (``jsonschema``) and ROS 2 CDR (``ros2msg``) channels to per-topic tables, with recovery
of damaged files.

The file is read once, sequentially, with :class:`mcap.stream_reader.StreamReader` (``emit_chunks=True``) so
that a damaged record does not cost the rest of the file:

* each chunk is decompressed and CRC-checked on its own (:func:`mcap.stream_reader.breakup_chunk`); a chunk
  that fails (bit flip, bad compression) is skipped and counted, reading continues with the next record;
* a truncated file (or a corrupted record header) ends the scan; every message of the intact chunks before
  it is kept;
* the number of messages lost is ``expected - read`` where the expected count comes from the summary's
  Statistics record (read at the end of the scan, or with a seeking reader from the footer when the scan
  stopped early); when no summary survives the count is reported as unknown (``None``).

The result is a :class:`McapReport` (JSON-able via :meth:`McapReport.as_dict`) recorded in the product
metadata; a warning is issued whenever messages were lost.

Speed (issue 19): files of 4 MiB or more walk their chunks with compiled kernels
(:mod:`hadal.ingest._mcap_kernels`: record framing and per-channel payload gathering, no Python object
per message until decoding), each chunk's payloads of a channel become one JSON array text decoded by
msgspec in one call (json.loads where msgspec refuses what json accepts, message by message where a
payload is corrupt), and ROS 2 CDR types of fixed size are decoded column-wise with NumPy
(:func:`_decode_cdr_fixed_part`); :func:`_parse_chunk` and mcap-ros2-support's decoder remain the reference
and the general path.
"""

from __future__ import annotations

import io
import json
import re
import struct
import warnings
import zlib
from collections.abc import Callable, Iterable, Iterator
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from hadal.errors import InputError

__all__ = ["McapReport", "McapTopic", "describe_mcap", "mcap_info", "read_mcap", "read_mcap_tables", "ros2_type_name",
           "to_dict"]

#: MCAP log times are u64; one above int64 (2**63 ...) is clamped here, an implausible time that the time
#: checks reject as one sample (the kernels do the same, :data:`hadal.ingest._mcap_kernels.INT64_MAX`)
_INT64_MAX = 2**63 - 1
_RECORD_LIMIT = 256 * 2**20  # a record header claiming more than 256 MiB is treated as corruption


@dataclass
class McapTopic:
    """Messages of one topic: log times (ns since epoch) and decoded messages (dicts), in file order."""

    topic: str
    schema_name: str | None
    schema_encoding: str | None
    message_encoding: str
    log_time_ns: np.ndarray
    messages: list[dict[str, Any]]
    #: the schema record's data (ros2msg text / JSON Schema), for mapping validation
    schema_data: bytes | None = None
    #: the channel(s) read: several channels on one topic with one schema are merged (time order)
    channel_ids: list[int] = field(default_factory=list)
    #: exact duplicates (same log time and payload on two channels of the topic) dropped by the merge
    duplicates_dropped: int = 0
    #: messages read (decoded to an object): ``len(messages)``, or all the parts' when a consumer took them
    n_read: int = 0
    #: what the consumer given to :func:`read_mcap` returned for each part (``messages`` is then empty)
    parts: list[Any] = field(default_factory=list)


@dataclass
class McapReport:
    """What was read from an MCAP file and what was lost."""

    path: str
    topics: dict[str, dict[str, Any]] = field(default_factory=dict)
    messages_read: int = 0
    messages_expected: int | None = None
    messages_lost: int | None = 0
    corrupt_chunks: int = 0
    decode_errors: int = 0
    truncated: bool = False
    problem: str | None = None
    duplicates_dropped: int = 0

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    @property
    def damaged(self) -> bool:
        return bool(self.truncated or self.corrupt_chunks or self.decode_errors or self.messages_lost)


def to_dict(obj: Any) -> Any:
    """Decoded ROS 2 message (``SimpleNamespace`` subclasses from mcap-ros2-support) -> plain dicts/lists."""
    slots = getattr(type(obj), "__slots__", None)
    if slots is not None and not isinstance(obj, (str, bytes, int, float)):
        return {k: to_dict(getattr(obj, k)) for k in slots if hasattr(obj, k)}
    if hasattr(obj, "__dict__") and not isinstance(obj, type):
        return {k: to_dict(v) for k, v in vars(obj).items()}
    if isinstance(obj, dict):
        return {k: to_dict(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_dict(v) for v in obj]
    if isinstance(obj, (bytes, bytearray)):
        return list(obj)
    return obj


def _open_check(path: Path) -> None:
    if not path.is_file():
        raise InputError(f"{path}: MCAP file does not exist")
    if path.stat().st_size == 0:
        raise InputError(f"{path}: MCAP file is empty")
    with open(path, "rb") as fh:
        magic = fh.read(8)
    if magic != b"\x89MCAP0\r\n":
        raise InputError(f"{path}: not an MCAP file (bad magic bytes {magic[:8]!r})")


def _summary_counts(path: Path) -> tuple[dict[int, int] | None, int | None]:
    """Per-channel and total message counts from the footer's summary (``None`` when unreadable)."""
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as fh:
            s = make_reader(fh).get_summary()
    except Exception:  # noqa: BLE001 - any failure here just means "no summary"
        return None, None
    if s is None or s.statistics is None:
        return None, None
    return dict(s.statistics.channel_message_counts), int(s.statistics.message_count)


_HDR = struct.Struct("<BQ")
_MSG = struct.Struct("<HIQQ")
_OP_SCHEMA, _OP_CHANNEL, _OP_MESSAGE = 0x03, 0x04, 0x05


#: working copies of a decompressed MCAP chunk its memory budget counts (the payload, its parsed records, the
#: channel buffers they are copied into)
MCAP_CHUNK_COPIES = 4.0
#: bytes of bookkeeping per kept message (its log time and length in the channel buffer, the list slots and object
#: headers of its decoded form) added to its payload in the file's cumulative count
MCAP_MESSAGE_OVERHEAD = 32
#: working copies of the messages kept across the whole file (payload + :data:`MCAP_MESSAGE_OVERHEAD`), per message
#: encoding: the raw buffers, the decoded objects (a dict per message), the per-topic tables. Measured with
#: ``bench/bench_reader_memory.py --mcap`` (1e6 messages of ~36 B through :func:`hadal.ingest.build.read_mcap_sensors`,
#: fresh interpreter, VmHWM above the after-imports VmHWM, over payload + overhead): JSON 7.95, ROS 2 CDR of a
#: fixed-size type (hadal's vectorised decoder) 11.97, ROS 2 CDR with a string (``sensor_msgs/FluidPressure``,
#: mcap-ros2-support's decoder) 14.70; each x 1.25, rounded. The x10 of every encoding before was measured on JSON only
MCAP_KEPT_COPIES_BY_ENCODING: dict[str, float] = {"json": 10.0, "cdr_fixed": 15.0, "cdr": 18.0}
#: the factor of an encoding not in :data:`MCAP_KEPT_COPIES_BY_ENCODING` (its topics are refused when decoded; until
#: then their payloads are held as the largest known encoding's)
MCAP_KEPT_COPIES = max(MCAP_KEPT_COPIES_BY_ENCODING.values())


def kept_copies(channel: Any, schema: Any) -> float:
    """The decode factor (:data:`MCAP_KEPT_COPIES_BY_ENCODING`) of the messages of ``channel`` (an MCAP Channel
    record; ``schema`` its Schema record or None): ``cdr_fixed`` for ROS 2 CDR of a fixed-size type (hadal's
    vectorised decoder, :func:`_fixed_cdr_layout`), ``cdr`` for other ROS 2 CDR, ``json``."""
    enc = getattr(channel, "message_encoding", None)
    if enc == "cdr" and schema is not None and schema.encoding == "ros2msg":
        try:
            if _fixed_cdr_layout(schema.name or "", bytes(schema.data).decode("utf-8")) is not None:
                return MCAP_KEPT_COPIES_BY_ENCODING["cdr_fixed"]
        except (UnicodeDecodeError, ValueError):
            pass
    return MCAP_KEPT_COPIES_BY_ENCODING.get(str(enc), MCAP_KEPT_COPIES)


def _chunk_bytes(chunk: Any, budget: Any = None) -> bytes:
    """Decompressed, CRC-checked payload of a Chunk record (ValueError when damaged). ``budget`` (a
    :class:`hadal.budget.DecodeBudget`) is held against the declared decompressed size before anything is
    decompressed, and neither decompressor may give more than that size (a compression bomb declaring little)."""
    if budget is not None:
        budget.hold(float(chunk.uncompressed_size), f"one chunk declaring {chunk.uncompressed_size:,} bytes")
    if chunk.compression == "zstd":
        import zstandard

        data = zstandard.decompress(chunk.data, max_output_size=chunk.uncompressed_size)
    elif chunk.compression == "lz4":
        import lz4.frame

        dec = lz4.frame.LZ4FrameDecompressor()
        data = dec.decompress(chunk.data, max_length=int(chunk.uncompressed_size) + 1)
    elif chunk.compression == "":
        data = chunk.data
    else:
        raise ValueError(f"unsupported chunk compression {chunk.compression!r}")
    if len(data) != chunk.uncompressed_size:
        raise ValueError("chunk size mismatch")
    if chunk.uncompressed_crc != 0 and zlib.crc32(data) != chunk.uncompressed_crc:
        raise ValueError("chunk CRC mismatch")
    return data


def _parse_chunk(data: bytes) -> list[tuple[int, Any]]:
    """Records of a decompressed chunk as ``(opcode, record)``; messages as ``(channel_id, log_time, payload)``.

    A direct ``struct`` walk over the chunk (MCAP spec: opcode u8, length u64, body): about 5x fewer Python
    calls per message than ``mcap.stream_reader.breakup_chunk``. Schema/Channel bodies are parsed by mcap's
    own record classes. Raises ValueError on a record running past the chunk end.
    """
    from mcap.data_stream import ReadDataStream
    from mcap.records import Channel, Schema

    out: list[tuple[int, Any]] = []
    append = out.append
    hdr, msg = _HDR.unpack_from, _MSG.unpack_from
    pos, n = 0, len(data)
    while pos < n:
        if pos + 9 > n:
            raise ValueError("record header past the end of the chunk")
        op, ln = hdr(data, pos)
        pos += 9
        end = pos + ln
        if end > n:
            raise ValueError("record past the end of the chunk")
        if op == _OP_MESSAGE:
            if ln < 22:
                raise ValueError("message record too short")
            cid, _seq, lt, _pt = msg(data, pos)
            append((_OP_MESSAGE, (cid, min(lt, _INT64_MAX), data[pos + 22:end])))
        elif op == _OP_SCHEMA:
            append((op, Schema.read(ReadDataStream(io.BytesIO(data[pos:end])))))
        elif op == _OP_CHANNEL:
            append((op, Channel.read(ReadDataStream(io.BytesIO(data[pos:end])))))
        pos = end
    return out


def _stream_reader(fh: Any, keep: frozenset[int] = frozenset()) -> Any:
    """``mcap.stream_reader.StreamReader`` (chunks emitted whole) that skips index/attachment/metadata records
    without parsing them: parsing every chunk's MessageIndex (one Python call per message) cost more than
    the messages themselves. Chunk CRCs are checked in :func:`_chunk_bytes`, so the reader's own CRC
    bookkeeping over the whole data section (one ``crc32`` call per field read) is switched off."""
    from mcap.opcode import Opcode
    from mcap.stream_reader import StreamReader

    skip = {Opcode.MESSAGE_INDEX, Opcode.CHUNK_INDEX, Opcode.ATTACHMENT, Opcode.ATTACHMENT_INDEX,
            Opcode.METADATA, Opcode.METADATA_INDEX, Opcode.SUMMARY_OFFSET} - set(keep)

    class _Reader(StreamReader):
        def _read_record(self, opcode: int, length: int) -> Any:  # mcap 1.x hook
            if opcode in skip:
                self._stream.read(length)
                return None
            return super()._read_record(opcode, length)

    return _Reader(fh, emit_chunks=True, validate_crcs=False, record_size_limit=_RECORD_LIMIT)


class _Walk:
    """One sequential pass over an MCAP stream: its records in file order (chunks whole, see
    :func:`_stream_reader`) until damaged framing ends the pass (``problem`` says where: what came before is
    kept); :meth:`chunk` unpacks a chunk's records, or gives ``None`` for a damaged chunk (counted in
    ``corrupt``) so that only that chunk is skipped.

    Memory (issue 45) is held against one budget for the whole file: each chunk by its declared size x
    :data:`MCAP_CHUNK_COPIES` before it is decompressed, on top of what the read keeps; the messages the caller
    keeps (:meth:`keep`) are counted cumulatively x their encoding's factor (:func:`kept_copies`), so that a file of
    many small chunks, each within the budget, is refused once their sum is not (a one-line :class:`InputError`
    naming the file and the limit). ``limit_bytes``: the stage's budget (``resources.max_memory_gb``); default
    :func:`hadal.budget.memory_limit_bytes` of the defaults (the machine's, cgroup's or ``RLIMIT_AS``'s)."""

    def __init__(self, fh: Any, keep: frozenset[int] = frozenset(), *, limit_bytes: float | None = None):
        self._fh, self._records = fh, _stream_reader(fh, keep).records
        self.problem: str | None = None
        self.corrupt = 0
        from hadal.budget import DecodeBudget

        name = getattr(fh, "name", "MCAP file")
        self.budget = DecodeBudget(name, "MCAP chunk", copies=MCAP_CHUNK_COPIES, limit_bytes=limit_bytes)
        self.file_budget = DecodeBudget(name, "MCAP file", limit_bytes=self.budget.limit)
        self.chunks = 0
        self.kept_messages = 0
        self.kept_bytes = 0.0

    def _admit(self, rec: Any) -> None:
        """Hold the next chunk against the budget before it is decompressed: on its own (its declared size x
        :data:`MCAP_CHUNK_COPIES`: "this MCAP chunk" in the refusal), then on top of the messages kept so far
        ("this MCAP file")."""
        size = float(rec.uncompressed_size)
        self.budget.hold(size, f"one chunk declaring {rec.uncompressed_size:,} bytes")
        self.file_budget.hold(self.kept_bytes, f"{self.kept_messages:,} messages kept from {self.chunks:,} chunks "
                                               f"so far and the next chunk", held=size * MCAP_CHUNK_COPIES)
        self.chunks += 1

    def keep(self, payload_bytes: int, messages: int, copies: float = MCAP_KEPT_COPIES) -> None:
        """Count ``messages`` kept (``payload_bytes`` of payload, decoded at ``copies`` times: :func:`kept_copies`)
        against the file's budget; refuses past it."""
        self.kept_messages += int(messages)
        self.kept_bytes += (float(payload_bytes) + MCAP_MESSAGE_OVERHEAD * int(messages)) * float(copies)
        self.file_budget.hold(self.kept_bytes, f"{self.kept_messages:,} messages kept from {self.chunks:,} "
                                               "chunks so far")

    def __iter__(self) -> Iterator[Any]:
        while True:
            try:
                rec = next(self._records)
            except StopIteration:
                return
            except Exception as exc:  # noqa: BLE001 - truncated/corrupted framing: keep what we have
                self.problem = f"reading stopped at byte {self._fh.tell()}: {type(exc).__name__} {exc}".strip()
                return
            yield rec

    def chunk(self, rec: Any) -> list[tuple[int, Any]] | None:
        try:
            self._admit(rec)
            return _parse_chunk(_chunk_bytes(rec, self.budget))
        except InputError:
            raise
        except Exception:  # noqa: BLE001 - bad compression / CRC / framing: skip this chunk only
            self.corrupt += 1
            return None

    def chunk_channels(self, rec: Any, kern: Any) -> Any:
        """:func:`_chunk_channels` of a chunk, or ``None`` for a damaged chunk (counted)."""
        try:
            self._admit(rec)
            return _chunk_channels(_chunk_bytes(rec, self.budget), kern)
        except InputError:
            raise
        except Exception:  # noqa: BLE001 - bad compression / CRC / framing: skip this chunk only
            self.corrupt += 1
            return None


class _ChanBuf:
    """The raw messages of one channel as read: per chunk, the log times (int64 ns), the payloads written
    as one JSON array text (``[p1,p2,...]``: the payloads one after the other, a comma between two,
    whatever their encoding) and their lengths; no Python object per message."""

    __slots__ = ("times", "blobs", "lens", "n")

    def __init__(self) -> None:
        self.times: list[np.ndarray] = []
        self.blobs: list[Any] = []
        self.lens: list[np.ndarray] = []
        self.n = 0

    def add(self, times: np.ndarray, blob: Any, lens: np.ndarray) -> None:
        self.times.append(times)
        self.blobs.append(blob)
        self.lens.append(lens)
        self.n += len(lens)

    def add_one(self, log_time: int, data: bytes) -> None:
        self.add(np.array([min(log_time, _INT64_MAX)], dtype=np.int64), b"[" + bytes(data) + b"]",
                 np.array([len(data)], dtype=np.int64))

    def log_times(self) -> np.ndarray:
        return np.concatenate(self.times) if self.times else np.zeros(0, dtype=np.int64)

    def decode_json(self) -> tuple[list[Any], int]:
        """Every message decoded (:func:`_decode_json_text` per chunk; a chunk's part holding a corrupt
        message is decoded message by message, the corrupt ones as ``None``) and the number undecodable."""
        out: list[Any] = []
        bad = 0
        for blob, lens in zip(self.blobs, self.lens, strict=True):
            part = _decode_json_text(blob, len(lens))
            if part is None:
                part, b = _decode_json(_split(blob, lens))
                bad += b
            out.extend(part)
        return out, bad

    def payload(self, i: int) -> bytes:
        """Message ``i``'s payload (only its chunk's part is split)."""
        for blob, lens in zip(self.blobs, self.lens, strict=True):
            if i < len(lens):
                return _split(blob, lens)[i]
            i -= len(lens)
        raise IndexError(i)

    def payloads(self) -> list[bytes]:
        """One bytes object per message (CDR decoding, channel merges)."""
        out: list[bytes] = []
        for blob, lens in zip(self.blobs, self.lens, strict=True):
            out.extend(_split(blob, lens))
        return out


def _split(blob: Any, lens: np.ndarray) -> list[bytes]:
    """The payloads of one ``[p1,p2,...]`` blob of :class:`_ChanBuf`."""
    mv = memoryview(blob)
    ends = np.cumsum(lens + 1)  # one past each payload, counting the opening bracket
    starts = (ends - lens).tolist()
    return [bytes(mv[a:b]) for a, b in zip(starts, ends.tolist(), strict=True)]


#: files at least this large walk their chunks with the compiled kernels (numba's start-up, ~1 s, is not
#: worth it for small files)
_COMPILED_MIN_BYTES = 4 * 2**20


def _chunk_kernels() -> Any:
    """:mod:`hadal.ingest._mcap_kernels`, or None without numba (or with ``HADAL_NO_NUMBA`` set)."""
    import os

    if os.environ.get("HADAL_NO_NUMBA"):
        return None
    try:
        from hadal.ingest import _mcap_kernels
    except ImportError:
        return None
    return _mcap_kernels


def _chunk_channels(data: bytes, kern: Any) -> tuple[list[tuple[int, Any]], dict[int, tuple[np.ndarray, bytes, np.ndarray]]]:
    """The records of a decompressed chunk: its Schema/Channel records ``(opcode, record)`` in file order,
    and per channel id its messages as ``(log times, comma-separated payloads, payload lengths)``.
    Compiled walk with ``kern`` (:func:`hadal.ingest._mcap_kernels.walk_chunk`), else :func:`_parse_chunk`.
    Raises ValueError on damaged framing (the caller skips the chunk)."""
    from mcap.data_stream import ReadDataStream
    from mcap.records import Channel, Schema

    per: dict[int, tuple[np.ndarray, bytes, np.ndarray]] = {}
    if kern is None:
        others, msgs = [], {}
        for op, r in _parse_chunk(data):
            if op == _OP_MESSAGE:
                msgs.setdefault(r[0], []).append(r)
            else:
                others.append((op, r))
        for cid, rs in msgs.items():
            per[cid] = (np.array([r[1] for r in rs], dtype=np.int64), b"[" + b",".join(r[2] for r in rs) + b"]",
                        np.array([len(r[2]) for r in rs], dtype=np.int64))
        return others, per
    b = np.frombuffer(data, dtype=np.uint8)
    status, cid, lt, ds, dl, oop, ost, oen = kern.walk_chunk(b)
    if status != kern.OK:
        raise ValueError({kern.HEADER_PAST_END: "record header past the end of the chunk",
                          kern.RECORD_PAST_END: "record past the end of the chunk",
                          kern.MESSAGE_TOO_SHORT: "message record too short"}.get(int(status), "bad chunk"))
    others = []
    for op, a, e in zip(oop.tolist(), ost.tolist(), oen.tolist(), strict=True):
        if op == _OP_SCHEMA:
            others.append((op, Schema.read(ReadDataStream(io.BytesIO(data[a:e])))))
        elif op == _OP_CHANNEL:
            others.append((op, Channel.read(ReadDataStream(io.BytesIO(data[a:e])))))
    if len(cid) == 0:
        return others, per
    first = int(cid[0])
    if (cid == first).all():
        groups = [(first, None)]
    else:
        groups = [(int(c), cid == c) for c in np.unique(cid)]
    for c, sel in groups:
        s_, l_, t_ = (ds, dl, lt) if sel is None else (ds[sel], dl[sel], lt[sel])
        per[c] = (t_, kern.gather(b, s_, l_), l_)
    return others, per


def _scan(path: Path, topics: set[str] | None, limit_bytes: float | None = None
          ) -> tuple[dict, dict, dict[int, _ChanBuf], McapReport, Any]:
    """One sequential pass: schemas, channels, raw messages per channel id, and the damage report. The messages
    kept are held against the memory budget ``limit_bytes`` (:class:`_Walk`) by their channel's decode factor."""
    from mcap.records import Channel, Chunk, Message, Schema, Statistics

    report = McapReport(path=str(path))
    schemas: dict[int, Any] = {}
    channels: dict[int, Any] = {}
    bufs: dict[int, _ChanBuf] = {}
    stats = None
    wanted: dict[int, bool] = {}
    copies: dict[int, float] = {}
    kern = _chunk_kernels() if path.stat().st_size >= _COMPILED_MIN_BYTES else None

    def want(cid: int) -> bool:
        ok = wanted.get(cid)
        if ok is None:
            ch = channels.get(cid)
            if ch is None:
                return False
            ok = wanted[cid] = topics is None or ch.topic in topics
            if ok:
                bufs.setdefault(cid, _ChanBuf())
                copies[cid] = kept_copies(ch, schemas.get(ch.schema_id))
        return ok

    def add_record(op: int, r: Any) -> None:
        if op == _OP_SCHEMA:
            schemas[r.id] = r
        else:
            channels[r.id] = r
            wanted.pop(r.id, None)

    with open(path, "rb") as fh:
        walk = _Walk(fh, limit_bytes=limit_bytes)
        for rec in walk:
            if isinstance(rec, Chunk):
                inner = walk.chunk_channels(rec, kern)
                if inner is None:
                    continue
                others, per = inner
                for op, r in others:
                    add_record(op, r)
                for cid, (t, blob, lens) in per.items():
                    if want(cid):
                        bufs[cid].add(t, blob, lens)
                        walk.keep(len(blob), len(lens), copies[cid])
                    elif cid not in channels:
                        report.decode_errors += len(lens)  # messages of an unknown channel
            elif isinstance(rec, Message):
                if want(rec.channel_id):
                    bufs[rec.channel_id].add_one(rec.log_time, rec.data)
                    walk.keep(len(rec.data), 1, copies[rec.channel_id])
                elif rec.channel_id not in channels:
                    report.decode_errors += 1
            elif isinstance(rec, Schema):
                add_record(_OP_SCHEMA, rec)
            elif isinstance(rec, Channel):
                add_record(_OP_CHANNEL, rec)
            elif isinstance(rec, Statistics):
                stats = rec
    report.truncated, report.problem, report.corrupt_chunks = walk.problem is not None, walk.problem, walk.corrupt
    return schemas, channels, bufs, report, stats


def _decode_json_text(text: Any, n: int) -> list[Any] | None:
    """``n`` messages from one JSON array, with msgspec (2-3x the standard library) and, where msgspec
    refuses what :mod:`json` accepts (``NaN``/``Infinity``, integers beyond 64 bits, lone surrogates),
    with :func:`json.loads`; None when the array is not ``n`` valid JSON values (a corrupt message)."""
    import msgspec

    try:
        out = msgspec.json.decode(text)
    except (msgspec.DecodeError, UnicodeDecodeError):
        try:
            out = json.loads(bytes(text))
        except (ValueError, UnicodeDecodeError, RecursionError):
            return None
    return out if isinstance(out, list) and len(out) == n else None


def _decode_json(datas: list[bytes]) -> tuple[list[Any], int]:
    """Decode JSON messages in one call; fall back per message (:func:`json.loads`) when some are corrupt."""
    out = _decode_json_text(b"[" + b",".join(datas) + b"]", len(datas))
    if out is not None:
        return out, 0
    out, bad = [], 0
    for d in datas:
        try:
            out.append(json.loads(d))
        except (ValueError, UnicodeDecodeError, RecursionError):
            out.append(None)
            bad += 1
    return out, bad


#: CDR primitive -> NumPy little-endian type (ROS 2 ``char`` and ``byte`` are uint8, decoded as ints)
_CDR_PRIMITIVES = {"bool": "?", "byte": "u1", "char": "u1", "octet": "u1", "int8": "i1", "uint8": "u1",
                   "int16": "<i2", "uint16": "<u2", "int32": "<i4", "uint32": "<u4", "int64": "<i8",
                   "uint64": "<u8", "float32": "<f4", "float64": "<f8", "float": "<f4", "double": "<f8"}


def _fixed_cdr_layout(schema_name: str, text: str) -> tuple[list[tuple[tuple[str, ...], str, int, int]], int] | None:
    """The byte layout of a ROS 2 message type whose serialised size is fixed (primitives, fixed-size
    arrays of primitives, nested such messages; no string, no sequence): ``[(field path, NumPy type,
    offset, count or 0 for a scalar)], size``, or None. Offsets are those of plain CDR (XCDR1, what
    rosbag2 writes): each primitive aligned to its size, relative to the end of the 4-byte encapsulation
    header."""
    sections = _ros2msg_sections(schema_name, text)
    if schema_name not in sections:
        return None
    fields: list[tuple[tuple[str, ...], str, int, int]] = []
    pos = 0

    def walk(tname: str, prefix: tuple[str, ...], depth: int) -> bool:
        nonlocal pos
        if depth > 8 or not sections.get(tname):
            return False
        for ftype, fname in sections[tname]:
            base, count = ftype, 0
            if "[" in ftype:
                base, rest = ftype.split("[", 1)
                if not rest[:-1].isdigit():  # unbounded or bounded sequence: variable size
                    return False
                count = int(rest[:-1])
            if "<=" in base:
                return False
            if base in _CDR_PRIMITIVES:
                dt = np.dtype(_CDR_PRIMITIVES[base])
                pos = -(-pos // dt.itemsize) * dt.itemsize  # align
                fields.append((prefix + (fname,), dt.str, pos, count))
                pos += dt.itemsize * max(count, 1)
            elif count == 0:
                sub = _ros2msg_resolve(sections, ftype, tname.split("/", 1)[0])
                if sub is None or sub == tname or not walk(sub, prefix + (fname,), depth + 1):
                    return False
            else:
                return False  # array of messages: left to the general decoder
        return True

    if not walk(schema_name, (), 0) or not fields:
        return None
    return fields, pos


def _cdr_fixed_layout_of(buf: _ChanBuf, sch: Any) -> Any:
    """The fixed layout (:func:`_fixed_cdr_layout`) when every payload of ``buf`` fits it (size, little-endian
    CDR encapsulation), else None (use the general decoder: a type that is not fixed-size, a payload whose size
    differs from the layout's beyond up to 3 bytes of end padding, an encapsulation header that is not
    little-endian CDR); checked over the whole channel before any part is decoded."""
    try:
        layout = _fixed_cdr_layout(sch.name or "", bytes(sch.data).decode("utf-8"))
    except (UnicodeDecodeError, ValueError):
        return None
    if layout is None or buf.n == 0:
        return None
    size = layout[1]
    for blob, lens in zip(buf.blobs, buf.lens, strict=True):
        width = int(lens[0])
        if not (4 + size <= width <= 4 + size + 3) or (lens != width).any():
            return None
        rows = np.frombuffer(blob, dtype=np.uint8)[1:].reshape(len(lens), width + 1)
        if (rows[:, 0] != 0).any() or (rows[:, 1] != 1).any():  # CDR_LE encapsulation
            return None
    return layout


def _decode_cdr_fixed_part(blobs: list[Any], lens_: list[np.ndarray], layout: Any) -> list[dict[str, Any]]:
    """Vectorised decoding of a fixed-layout ROS 2 message type (:func:`_fixed_cdr_layout`) of ``blobs`` (checked
    by :func:`_cdr_fixed_layout_of`): every payload of a chunk viewed as a row of one ``(messages, bytes)`` array,
    each field one strided NumPy column."""
    fields, _size = layout
    cols: list[list[Any]] = [[] for _ in fields]
    for blob, lens in zip(blobs, lens_, strict=True):
        width = int(lens[0])
        rows = np.frombuffer(blob, dtype=np.uint8)[1:].reshape(len(lens), width + 1)
        for col, (_path, dt, off, count) in zip(cols, fields, strict=True):
            itemsize = np.dtype(dt).itemsize
            raw = np.ascontiguousarray(rows[:, 4 + off:4 + off + itemsize * max(count, 1)])
            v = raw.view(dt)
            col.extend(v.ravel().tolist() if count == 0 else v.tolist())
    # nested dicts in field order, as mcap-ros2-support's decoder + to_dict give them
    tree: dict[str, Any] = {}
    for i, (path, *_rest) in enumerate(fields):
        node = tree
        for part in path[:-1]:
            node = node.setdefault(part, {})
        node[path[-1]] = i

    def build(node: dict[str, Any]) -> Any:
        keys = list(node)
        parts = [cols[v] if isinstance(v, int) else build(v) for v in node.values()]
        return [dict(zip(keys, vals, strict=True)) for vals in zip(*parts, strict=True)]

    return build(tree)


def _schema_label(ch: Any, sch: Any) -> str:
    if sch is None:
        return f"channel {ch.id}: no schema ({ch.message_encoding})"
    return f"channel {ch.id}: {sch.name or '(unnamed)'} [{sch.encoding}/{ch.message_encoding}]"


def _check_same_schema(path: Path, topic: str, chans: list[tuple[int, Any, Any]]) -> None:
    """Several channels on one topic are merged only when they carry the same schema (name, encoding,
    definition) and message encoding; otherwise a one-line :class:`InputError` naming the two schemas."""
    def key(ch: Any, sch: Any) -> tuple:
        return (ch.message_encoding, getattr(sch, "name", None), getattr(sch, "encoding", None),
                bytes(getattr(sch, "data", b"") or b""))

    _, ch0, s0 = chans[0]
    for _, ch, sc in chans[1:]:
        if key(ch, sc) != key(ch0, s0):
            same_name = (getattr(sc, "name", None) == getattr(s0, "name", None)
                         and getattr(sc, "encoding", None) == getattr(s0, "encoding", None)
                         and ch.message_encoding == ch0.message_encoding)
            raise InputError(
                f"{path}: topic {topic} is recorded on {len(chans)} channels with different schemas "
                f"({_schema_label(ch0, s0)}; {_schema_label(ch, sc)}"
                f"{' - same name, different definitions' if same_name else ''}): hadal cannot merge them; "
                "re-record or split the topic (mcap filter) so that one topic has one schema")


def _merge_channels(parts: list[tuple[list[int], list[bytes]]]) -> tuple[list[bytes], np.ndarray, int, int]:
    """Messages of several channels of one topic as one stream: time-sorted (stable: file order within a
    time), a message equal in log time and payload to one of an earlier channel dropped as an exact
    duplicate. Returns (payloads, log times, messages before dropping, duplicates dropped)."""
    seen: set[tuple[int, bytes]] = set()
    t_all: list[int] = []
    d_all: list[bytes] = []
    n_raw = dups = 0
    for times_c, datas_c in parts:
        n_raw += len(datas_c)
        mine: list[tuple[int, bytes]] = []
        for lt, d in zip(times_c, datas_c, strict=True):
            k = (lt, bytes(d))
            if k in seen:
                dups += 1
                continue
            mine.append(k)
            t_all.append(lt)
            d_all.append(d)
        seen.update(mine)
    t = np.asarray(t_all, dtype=np.int64)
    order = np.argsort(t, kind="stable")
    return [d_all[i] for i in order], t[order], n_raw, dups


#: one part of a topic (:func:`_topic_parts`)
_Part = tuple[np.ndarray, "list[bytes] | None", "list[Any] | None", Any, "dict[int, bytes] | None"]


def _topic_parts(path: Path, topic: str, cids: list[int], channels: dict[int, Any], schemas: dict[int, Any],
                 bufs: dict[int, _ChanBuf]) -> tuple[int, int, Iterator[_Part]]:
    """Take one topic's buffered messages out of ``bufs`` (released once taken). Returns (messages before dropping
    duplicates, duplicates dropped, its parts): each part is (log times, payloads still to decode, JSON already
    decoded, fixed-layout CDR already decoded, the first unusable JSON payload by index) of one MCAP chunk's
    messages, decoded only when the part is
    taken, so that a reader that keeps only columns of each part never holds a whole topic's messages as
    objects. Several channels of the topic are merged (:func:`_merge_channels`) into one part."""
    cid, ch = cids[0], channels[cids[0]]
    sch = schemas.get(ch.schema_id)
    enc = ch.message_encoding
    if len(cids) > 1:
        _check_same_schema(path, topic, [(c, channels[c], schemas.get(channels[c].schema_id)) for c in cids])
        parts = [(b.log_times().tolist(), b.payloads()) for b in (bufs.pop(c, None) or _ChanBuf() for c in cids)]
        raw, t, n_raw, dups = _merge_channels(parts)
        return n_raw, dups, iter([(t, raw, None, None, None)])
    buf = bufs.pop(cid, None) or _ChanBuf()
    layout = _cdr_fixed_layout_of(buf, sch) if enc == "cdr" and sch is not None and sch.encoding == "ros2msg" \
        else None

    def parts_of(buf: _ChanBuf) -> Iterator[_Part]:
        if not buf.blobs:  # no message: still one (empty) part, so that an unreadable encoding is said
            yield np.zeros(0, dtype=np.int64), [], None, None, None
        for lst in (buf.times, buf.blobs, buf.lens):
            lst.reverse()
        while buf.blobs:  # each chunk's part released as it is handed over
            t, blob, lens = buf.times.pop(), buf.blobs.pop(), buf.lens.pop()
            if enc == "json":
                msgs = _decode_json_text(blob, len(lens))
                if msgs is None:
                    msgs = _decode_json(_split(blob, lens))[0]
                raw_json = None
                if not set(map(type, msgs)) <= {dict}:  # keep the first unusable payload (for the error text)
                    i0 = next(i for i, m in enumerate(msgs) if not isinstance(m, dict))
                    raw_json = {i0: _split(blob, lens)[i0]}
                yield t, None, msgs, None, raw_json
            elif layout is not None:
                yield t, None, None, _decode_cdr_fixed_part([blob], [lens], layout), None
            else:
                yield t, _split(blob, lens), None, None, None

    return buf.n, 0, parts_of(buf)


def _decode_topic(path: Path, ch: Any, sch: Any, raw: list[bytes] | None, msgs: list[Any] | None, fixed: Any,
                  factory: list[Any]) -> tuple[list[Any], Any]:
    """Decode what :func:`_topic_payloads` left to decode; returns (messages, the ROS 2 decoder or None).
    ``factory`` holds the one ROS 2 ``DecoderFactory`` of a read, made on first use."""
    enc = ch.message_encoding
    dec = None
    if enc == "json":
        if raw is not None:
            msgs, _bad = _decode_json(raw)
    elif fixed is not None:
        msgs = fixed
    elif enc == "cdr" and sch is not None and sch.encoding in ("ros2msg", "ros2idl"):
        if not factory:
            from mcap_ros2.decoder import DecoderFactory

            factory.append(DecoderFactory())
        try:
            dec = factory[0].decoder_for(enc, sch)
        except Exception as exc:  # noqa: BLE001 - broken message definition in the schema record
            raise InputError(f"{path}: cannot build a ROS 2 decoder for {ch.topic} ({sch.name}): {exc}") from None
        msgs = []
        for d in raw:
            try:
                msgs.append(to_dict(dec(d)))
            except Exception:  # noqa: BLE001 - corrupt CDR payload: drop and count
                msgs.append(None)
    else:
        raise InputError(
            f"{path}: topic {ch.topic} uses message encoding {enc!r} "
            f"(schema {getattr(sch, 'encoding', None)!r}); hadal reads 'json' and ROS 2 'cdr'"
        )
    return msgs, dec


def _keep_objects(msgs: list[Any], t: np.ndarray, raw: list[bytes] | None, raw_json: dict[int, bytes] | None,
                  enc: str, dec: Any) -> tuple[list[Any], np.ndarray, int, str | None]:
    """Drop the messages that did not decode to an object; returns (messages, their log times, number dropped,
    why the first one was unusable)."""
    if set(map(type, msgs)) <= {dict}:  # at C speed: every message decoded to an object
        keep = msgs
    else:
        keep = [i for i, m in enumerate(msgs) if isinstance(m, dict)]
    bad = len(msgs) - len(keep)  # undecodable or not an object
    first_error = None
    if bad:
        i0 = next(i for i, m in enumerate(msgs) if not isinstance(m, dict))
        payload = raw[i0] if raw is not None and i0 < len(raw) else (raw_json or {}).get(i0)
        if payload is not None:
            first_error = _decode_error_text(payload, enc, dec, msgs[i0])
    if len(keep) != len(msgs):
        msgs = [msgs[i] for i in keep]
        t = t[np.asarray(keep, dtype=np.int64)] if keep else t[:0]
    return msgs, t, bad, first_error


def _read_topic(path: Path, topic: str, cids: list[int], channels: dict[int, Any], schemas: dict[int, Any],
                bufs: dict[int, _ChanBuf], per_chan: dict[int, int] | None, report: McapReport, warn: bool,
                factory: list[Any], consume: Callable[[np.ndarray, list[Any]], Any] | None = None) -> McapTopic:
    """Decode one topic (all its channels) into a :class:`McapTopic`; records it in ``report.topics``.

    ``consume``: called with each part's log times and messages (one MCAP chunk's, in file order); its results
    are the topic's ``parts`` and its ``messages`` stay empty (the decoded objects of one part at a time)."""
    cid, ch = cids[0], channels[cids[0]]
    sch = schemas.get(ch.schema_id)
    enc = ch.message_encoding
    n_raw, dups, parts = _topic_parts(path, topic, cids, channels, schemas, bufs)
    times: list[np.ndarray] = []
    kept: list[Any] = []
    bad = n_read = 0
    first_error = None
    for t, raw, msgs, fixed, raw_json in parts:
        msgs, dec = _decode_topic(path, ch, sch, raw, msgs, fixed, factory)
        msgs, t, b, err = _keep_objects(msgs, t, raw, raw_json, enc, dec)
        bad += b
        first_error = first_error or err
        n_read += len(msgs)
        if consume is None:
            times.append(t)
            kept.extend(msgs)
        else:
            kept.append(consume(t, msgs))
        del msgs, raw, raw_json
    report.decode_errors += bad
    expected = sum(per_chan.get(c, 0) for c in cids) if per_chan is not None else None
    report.topics[topic] = {
        "channel_id": cid, "schema": getattr(sch, "name", None), "schema_encoding": getattr(sch, "encoding", None),
        "message_encoding": enc, "read": n_read, "expected": expected,
        "lost": (expected - n_raw) if expected is not None else None, "decode_errors": bad,
        "first_decode_error": first_error,
    }
    if len(cids) > 1:
        report.topics[topic].update(channel_ids=list(cids), duplicates_dropped=dups)
        report.duplicates_dropped += dups
        if warn:
            warnings.warn(f"{path.name}: topic {topic} is recorded on {len(cids)} channels "
                          f"({', '.join(str(c) for c in cids)}) with the same schema "
                          f"{getattr(sch, 'name', None)!r}: merged in time order, {dups} exact duplicate "
                          "message(s) dropped", stacklevel=3)  # the caller of read_mcap
    log_t = np.concatenate(times) if times else np.zeros(0, dtype=np.int64)
    return McapTopic(topic, getattr(sch, "name", None), getattr(sch, "encoding", None), enc, log_t,
                     kept if consume is None else [], getattr(sch, "data", None), list(cids), dups, n_read,
                     kept if consume is not None else [])


def _count_lost(report: McapReport, out: dict[str, McapTopic], total: int | None, per_chan: dict[int, int] | None,
                channels: dict[int, Any], tset: set[str] | None) -> None:
    """Fill ``report.messages_read`` / ``messages_expected`` / ``messages_lost`` from what was read."""
    report.messages_read = sum(v.n_read for v in out.values())
    if total is not None and tset is None:
        report.messages_expected = total
    elif per_chan is not None:
        report.messages_expected = sum(n for cid, n in per_chan.items()
                                       if cid in channels and (tset is None or channels[cid].topic in tset))
    if report.messages_expected is not None:
        report.messages_lost = max(report.messages_expected - report.messages_read - report.duplicates_dropped, 0)
    elif report.truncated or report.corrupt_chunks:
        report.messages_lost = None  # unknown: no summary survived
    else:
        report.messages_lost = report.decode_errors


def _warn_lost(path: Path, report: McapReport) -> None:
    """The one :class:`UserWarning` of a damaged read (what was lost and why), raised at read_mcap's caller."""
    lost = "an unknown number of" if report.messages_lost is None else str(report.messages_lost)
    what = []
    if report.truncated:
        what.append("truncated/corrupted after the last intact record")
    if report.corrupt_chunks:
        what.append(f"{report.corrupt_chunks} corrupt chunk(s) skipped")
    if report.decode_errors:
        what.append(f"{report.decode_errors} undecodable message(s)")
    if not what:
        what.append(f"the summary counts {report.messages_expected} message(s) on these topics, "
                    f"{report.messages_read} were found")
    warnings.warn(f"{path.name}: {lost} message(s) lost ({'; '.join(what)}); "
                  f"recovered {report.messages_read}", stacklevel=3)


def read_mcap(path: str | Path, topics: Iterable[str] | None = None, *, warn: bool = True,
              memory_limit_bytes: float | None = None,
              consume: dict[str, Callable[[np.ndarray, list[Any]], Any]] | None = None
              ) -> tuple[dict[str, McapTopic], McapReport]:
    """Read (and decode) the messages of ``topics`` (all when ``None``) from an MCAP file.

    JSON channels are decoded with :mod:`json`; ``ros2msg``/CDR channels with mcap-ros2-support's
    ``DecoderFactory`` and converted to plain dicts. Messages that cannot be decoded are dropped and
    counted (``report.decode_errors``). Damaged files are read as far as possible (module docstring);
    a :class:`UserWarning` reports lost messages. Raises :class:`InputError` when the file is missing,
    empty or not MCAP, or a requested topic uses an encoding hadal cannot decode, or when its chunks and kept
    messages need more than ``memory_limit_bytes`` (the stage's ``resources.max_memory_gb``; default
    :func:`hadal.budget.memory_limit_bytes` of the defaults; :class:`_Walk`).

    ``consume`` (topic -> function): a topic named there is decoded part by part (one MCAP chunk's messages:
    their log times and decoded objects, in file order) and each part handed to its function as it is decoded;
    the results are the topic's ``parts``, its ``messages`` stay empty: a topic's decoded messages are never
    all held at once (:func:`hadal.ingest.build.read_mcap_sensors`, issue 48).
    """
    path = Path(path)
    _open_check(path)
    tset = set(topics) if topics is not None else None
    schemas, channels, bufs, report, stats = _scan(path, tset, memory_limit_bytes)
    if stats is not None:
        per_chan, total = dict(stats.channel_message_counts), int(stats.message_count)
    else:
        per_chan, total = _summary_counts(path) if (report.truncated or report.corrupt_chunks) else (None, None)

    out: dict[str, McapTopic] = {}
    ros2_factory: list[Any] = []
    by_topic: dict[str, list[int]] = {}
    for cid, ch in sorted(channels.items()):
        if tset is None or ch.topic in tset:
            by_topic.setdefault(ch.topic, []).append(cid)
    for topic, cids in by_topic.items():
        out[topic] = _read_topic(path, topic, cids, channels, schemas, bufs, per_chan, report, warn, ros2_factory,
                                 (consume or {}).get(topic))
    _count_lost(report, out, total, per_chan, channels, tset)
    if warn and report.damaged:
        _warn_lost(path, report)
    return out, report


def _decode_error_text(payload: bytes, enc: str, dec: Any, decoded: Any) -> str:
    """Why one message could not be used: the decoder's error (or the type it decoded to) and its first bytes."""
    why = f"decoded to a {type(decoded).__name__}, not an object" if decoded is not None else None
    if why is None:
        try:
            if enc == "json":
                json.loads(payload)
            elif dec is not None:
                dec(payload)
            why = "undecodable"
        except Exception as exc:  # noqa: BLE001 - the decoder's own message is what the user needs
            why = f"{type(exc).__name__}: {str(exc).splitlines()[0][:120] if str(exc) else ''}".rstrip(": ")
    head = bytes(payload[:8]).hex(" ")
    return f"{why} (payload of {len(payload)} bytes starting {head or '(empty)'})"


def _flatten(d: dict[str, Any], prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    for k, v in d.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict):
            out.update(_flatten(v, key + "."))
        else:
            out[key] = v
    return out


def read_mcap_tables(path: str | Path, topics: Iterable[str] | None = None, *, warn: bool = True
                     ) -> tuple[dict[str, pd.DataFrame], McapReport]:
    """:func:`read_mcap` as one DataFrame per topic: ``log_time_ns`` plus the message fields (nested
    messages flattened with ``.``: ``stamp.sec``)."""
    data, report = read_mcap(path, topics, warn=warn)
    tables = {}
    for topic, tp in data.items():
        flat = tp.messages
        if any(isinstance(v, dict) for m in flat[:1] for v in m.values()):
            flat = [_flatten(m) for m in flat]
        df = pd.DataFrame.from_records(flat) if flat else pd.DataFrame()
        df.insert(0, "log_time_ns", tp.log_time_ns)
        tables[topic] = df
    return tables, report


def mcap_info(path: str | Path) -> list[dict[str, Any]]:
    """Channels of an MCAP file: topic, schema name/encoding, message encoding and message count
    (from the summary when present, else counted by a scan)."""
    path = Path(path)
    _open_check(path)
    from mcap.reader import make_reader

    try:
        with open(path, "rb") as fh:
            s = make_reader(fh).get_summary()
    except Exception:  # noqa: BLE001 - damaged footer: fall back to a scan
        s = None
    if s is not None and s.statistics is not None:
        counts = s.statistics.channel_message_counts
        return [{"topic": c.topic, "schema": s.schemas[c.schema_id].name if c.schema_id in s.schemas else None,
                 "schema_encoding": s.schemas[c.schema_id].encoding if c.schema_id in s.schemas else None,
                 "message_encoding": c.message_encoding, "messages": int(counts.get(c.id, 0))}
                for c in sorted(s.channels.values(), key=lambda c: c.id)]
    schemas, channels, bufs, _, _ = _scan(path, None)
    return [{"topic": c.topic, "schema": getattr(schemas.get(c.schema_id), "name", None),
             "schema_encoding": getattr(schemas.get(c.schema_id), "encoding", None),
             "message_encoding": c.message_encoding, "messages": bufs[c.id].n if c.id in bufs else 0}
            for c in sorted(channels.values(), key=lambda c: c.id)]


# --------------------------------------------------------------------------------------------------------------
# describe: what is in an MCAP file (``hadal inspect``, ``hadal init``)
# --------------------------------------------------------------------------------------------------------------


def ros2_type_name(schema_name: str | None) -> str | None:
    """``pkg/msg/Type`` for a ROS 2 schema name (``test_msgs/BasicTypes`` -> ``test_msgs/msg/BasicTypes``)."""
    if not schema_name:
        return None
    parts = schema_name.split("/")
    if len(parts) == 2:
        return f"{parts[0]}/msg/{parts[1]}"
    return schema_name


def _iso(ns: int | None) -> str | None:
    if ns is None:
        return None
    return str(np.datetime64(int(ns), "ns").astype("datetime64[ms]")) + "Z"


def _preview(v: Any, depth: int = 0) -> Any:
    """JSON-safe, abridged copy of a decoded message (lists cut to 8 items, long strings to 200 characters)."""
    if isinstance(v, dict):
        return {str(k): _preview(x, depth + 1) for k, x in v.items()} if depth < 8 else "{...}"
    if isinstance(v, (list, tuple)):
        out = [_preview(x, depth + 1) for x in list(v)[:8]]
        return out + [f"... ({len(v)} items)"] if len(v) > 8 else out
    if isinstance(v, float) and not np.isfinite(v):
        return str(v)
    if isinstance(v, (np.integer, np.floating)):
        return _preview(v.item())
    if isinstance(v, str) and len(v) > 200:
        return v[:200] + "..."
    if isinstance(v, (bytes, bytearray)):
        return _preview(list(v), depth)
    return v


def field_names(msg: dict[str, Any], prefix: str = "") -> list[str]:
    """Dotted names of the leaf fields of a decoded message (lists are leaves)."""
    out: list[str] = []
    for k, v in msg.items():
        key = f"{prefix}{k}"
        if isinstance(v, dict) and v:
            out.extend(field_names(v, key + "."))
        else:
            out.append(key)
    return out


_ROS_FIELD = re.compile(r"^\s*([A-Za-z0-9_/]+(?:\[[^\]]*\])?(?:<=\d+)?)\s+([A-Za-z_][A-Za-z0-9_]*)"
                                      r"(?:\s+[^#]*)?(?:#\s*(.*))?$")


def _ros2msg_resolve(sections: dict[str, Any], t: str, pkg: str) -> str | None:
    """The section name a field type ``t`` (of package ``pkg``) refers to: ``Foo``, ``pkg/Foo``, ``pkg/msg/Foo``."""
    base = t.split("[", 1)[0].split("<=", 1)[0]
    for cand in (base, base.replace("/", "/msg/", 1), f"{pkg}/{base}", f"{pkg}/msg/{base}"):
        if cand in sections:
            return cand
    short = base.rsplit("/", 1)[-1]
    for k in sections:
        if k.rsplit("/", 1)[-1] == short and ("/" not in base or k.split("/")[0] == base.split("/")[0]):
            return k
    return None


def _ros2msg_docs(schema_name: str, text: str) -> dict[str, str]:
    """Comments of the fields of a ``ros2msg`` definition (with its dependencies), by dotted field path:
    ``float64 pressure  # dbar`` -> ``{"pressure": "dbar"}``. Constants (``uint8 A=1``) are skipped."""
    sections = _ros2msg_blocks(schema_name, text)

    def resolve(t: str, pkg: str) -> str | None:
        return _ros2msg_resolve(sections, t, pkg)

    out: dict[str, str] = {}

    def walk(tname: str, prefix: str, depth: int) -> None:
        pkg = tname.split("/", 1)[0]
        for ftype, fname, comment in sections.get(tname, []):
            path = f"{prefix}{fname}"
            sub = resolve(ftype, pkg) if "[" not in ftype else None
            if sub is not None and sub != tname and depth < 8:
                walk(sub, path + ".", depth + 1)
            elif comment:
                out[path] = comment
    root = schema_name if schema_name in sections else next(iter(sections), "")
    walk(root, "", 0)
    return out


#: ROS 2 primitive types that decode to one number
ROS2_NUMERIC = frozenset({"int8", "uint8", "int16", "uint16", "int32", "uint32", "int64", "uint64", "float32",
                          "float64", "float", "double", "byte", "char", "octet"})


def _ros2msg_sections(schema_name: str, text: str) -> dict[str, list[tuple[str, str]]]:
    """``{type name: [(field type, field name), ...]}`` of a ``ros2msg`` definition and its dependencies."""
    return {k: [(t, n) for t, n, _ in v] for k, v in _ros2msg_blocks(schema_name, text).items()}


def _ros2msg_blocks(schema_name: str, text: str) -> dict[str, list[tuple[str, str, str]]]:
    """``{type name: [(field type, field name, comment), ...]}`` of a ``ros2msg`` definition and the
    ``MSG: <type>`` blocks of its dependencies (separated by a line of 80 ``=``); constants are skipped."""
    sections: dict[str, list[tuple[str, str, str]]] = {}
    name = schema_name
    for block in text.split("\n" + "=" * 80 + "\n"):
        lines = block.strip("\n").splitlines()
        if lines and lines[0].startswith("MSG: "):
            name, lines = lines[0][5:].strip(), lines[1:]
        fields = []
        for ln in lines:
            if not ln.strip() or ln.lstrip().startswith("#"):
                continue
            m = _ROS_FIELD.match(ln)
            if not m or _is_constant(ln) or _CONSTANT.match(ln):
                continue
            fields.append((m.group(1), m.group(2), (m.group(3) or "").strip()))
        sections[name] = fields
        name = ""
    return sections


#: ``TYPE NAME = value`` (a constant written with spaces around '=')
_CONSTANT = re.compile(r"^\s*\S+\s+[A-Za-z_][A-Za-z0-9_]*\s*=")


def _is_constant(line: str) -> bool:
    parts = line.split("#", 1)[0].split(None, 1)
    return len(parts) == 2 and "=" in parts[1].split(None, 1)[0]


def ros2_field_type(schema_name: str | None, text: str, path: str) -> str | None:
    """The ROS 2 type of the (dotted) field ``path`` of a ``ros2msg`` schema: a primitive (``float64``,
    ``bool``, ``string``), an array (``float64[9]``, ``float64[]``; ``a.0`` gives the element type) or a
    message type (``builtin_interfaces/Time``); ``None`` when the field is not in the definition."""
    sections = _ros2msg_sections(schema_name or "", text)
    if not sections:
        return None

    def resolve(t: str, pkg: str) -> str | None:
        return _ros2msg_resolve(sections, t, pkg)

    cur: str | None = schema_name if schema_name in sections else next(iter(sections))
    ftype: str | None = None
    for part in path.split("."):
        if ftype is not None and "[" in ftype and part.isdigit():
            ftype = ftype.split("[", 1)[0]  # element of an array
            if ftype in ROS2_NUMERIC or ftype in ("bool", "string", "wstring"):
                cur = None
            else:
                cur = resolve(ftype, (cur or "").split("/", 1)[0])
            continue
        if cur is None:
            return None
        hit = next((ft for ft, fn in sections.get(cur, []) if fn == part), None)
        if hit is None:
            return None
        ftype = hit
        base = hit.split("[", 1)[0].split("<=", 1)[0]
        cur = None if ("[" in hit or base in ROS2_NUMERIC or base in ("bool", "string", "wstring")) \
            else resolve(hit, cur.split("/", 1)[0])
    return ftype


def _jsonschema_docs(schema: Any, prefix: str = "", depth: int = 0) -> dict[str, str]:
    """``units``/``unit`` or ``description`` of each property of a JSON Schema, by dotted field path."""
    out: dict[str, str] = {}
    if not isinstance(schema, dict) or depth > 8:
        return out
    for k, prop in (schema.get("properties") or {}).items():
        if not isinstance(prop, dict):
            continue
        path = f"{prefix}{k}"
        unit = prop.get("units", prop.get("unit"))
        desc = prop.get("description")
        text = "; ".join(str(x) for x in ((f"units: {unit}" if unit else None), desc) if x)
        if text:
            out[path] = text
        out.update(_jsonschema_docs(prop, path + ".", depth + 1))
    return out


def _decode_first(enc: str, sch: Any, data: bytes, factory: list[Any]) -> tuple[Any, str | None]:
    if enc == "json":
        try:
            return json.loads(data), None
        except (ValueError, UnicodeDecodeError) as exc:
            return None, f"invalid JSON: {exc}"
    if enc == "cdr" and sch is not None and sch.encoding in ("ros2msg", "ros2idl"):
        try:
            if not factory:
                from mcap_ros2.decoder import DecoderFactory

                factory.append(DecoderFactory())
            return to_dict(factory[0].decoder_for(enc, sch)(data)), None
        except Exception as exc:  # noqa: BLE001 - broken definition or payload: describe, don't fail
            return None, f"cannot decode ({type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''})"
    return None, (f"message encoding {enc!r} (schema {getattr(sch, 'encoding', None)!r}) is not decoded by hadal "
                  "(it reads 'json' and ROS 2 'cdr')")


class _McapTally:
    """What :func:`describe_mcap`'s one pass collects: schemas, channels and per-channel counts / time spans."""

    def __init__(self) -> None:
        self.schemas: dict[int, Any] = {}
        self.channels: dict[int, Any] = {}
        self.count: dict[int, int] = {}
        self.tmin: dict[int, int] = {}
        self.tmax: dict[int, int] = {}
        self.first: dict[int, bytes] = {}
        self.header: Any = None
        self.stats: Any = None
        self.chunk_indexes = 0
        self.chunks_read = 0
        self.attachments = 0
        self.compression: set[str] = set()
        self.metadata: list[str] = []

    def add(self, cid: int, lt: int, data: bytes) -> None:
        n = self.count.get(cid)
        if n is None:
            self.count[cid] = 1
            self.tmin[cid] = self.tmax[cid] = lt
            self.first[cid] = bytes(data)
            return
        self.count[cid] = n + 1
        if lt < self.tmin[cid]:
            self.tmin[cid] = lt
        elif lt > self.tmax[cid]:
            self.tmax[cid] = lt


def _tally_mcap(path: Path, limit_bytes: float | None = None) -> tuple[_McapTally, _Walk]:
    """One sequential, damage-tolerant pass over ``path`` (chunks held against ``limit_bytes``); the walk keeps
    its ``problem`` / ``corrupt``."""
    from mcap.opcode import Opcode
    from mcap.records import (
        Attachment,
        Channel,
        Chunk,
        ChunkIndex,
        Header,
        Message,
        Metadata,
        Schema,
        Statistics,
    )

    t = _McapTally()
    keep = frozenset({Opcode.CHUNK_INDEX, Opcode.ATTACHMENT, Opcode.METADATA})
    with open(path, "rb") as fh:
        walk = _Walk(fh, keep, limit_bytes=limit_bytes)
        for rec in walk:
            if isinstance(rec, Chunk):
                t.compression.add(rec.compression or "none")
                inner = walk.chunk(rec)
                if inner is None:
                    continue
                t.chunks_read += 1
                for op, r in inner:
                    if op == _OP_MESSAGE:
                        t.add(*r)
                    elif op == _OP_SCHEMA:
                        t.schemas[r.id] = r
                    else:
                        t.channels[r.id] = r
            elif isinstance(rec, Message):
                t.add(rec.channel_id, rec.log_time, rec.data)
            elif isinstance(rec, Schema):
                t.schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                t.channels[rec.id] = rec
            elif isinstance(rec, Header):
                t.header = rec
            elif isinstance(rec, Statistics):
                t.stats = rec
            elif isinstance(rec, ChunkIndex):
                t.chunk_indexes += 1
            elif isinstance(rec, Metadata):
                t.metadata.append(rec.name)
            elif isinstance(rec, Attachment):
                t.attachments += 1
    return t, walk


def _recover_summary(path: Path, t: _McapTally) -> bool:
    """A seeking reader finds the footer's summary when only the middle of the file is damaged; True if read."""
    from mcap.reader import make_reader

    summary_read = False
    try:
        with open(path, "rb") as fh:
            s = make_reader(fh).get_summary()
        if s is not None:
            t.stats = s.statistics
            t.chunk_indexes = len(s.chunk_indexes)
            summary_read = True
            for sid, sc in s.schemas.items():
                t.schemas.setdefault(sid, sc)
            for cid, c in s.channels.items():
                t.channels.setdefault(cid, c)
    except Exception:  # noqa: BLE001 - no summary either
        pass
    return summary_read


def _schema_docs(sch: Any, sname: str | None, senc: str | None) -> tuple[dict[str, str], str | None]:
    """Field docs (units/comments) from a channel's schema, and its name (a JSON schema's title if unnamed)."""
    docs: dict[str, str] = {}
    try:
        if senc == "jsonschema" and sch is not None and sch.data:
            js = json.loads(sch.data)
            docs = _jsonschema_docs(js)
            if not sname:
                sname = js.get("title")
        elif senc == "ros2msg" and sch is not None:
            docs = _ros2msg_docs(sname or "", sch.data.decode("utf-8", errors="replace"))
    except (ValueError, UnicodeDecodeError, AttributeError):
        docs = {}
    return docs, sname


def _describe_channel(cid: int, ch: Any, t: _McapTally, per_chan: dict[int, int] | None,
                      factory: list[Any]) -> dict[str, Any]:
    """:func:`describe_mcap`'s entry for one channel."""
    sch = t.schemas.get(ch.schema_id)
    enc = ch.message_encoding
    senc = getattr(sch, "encoding", None)
    is_ros = enc == "cdr" or (senc or "").startswith("ros")
    msg, err = (None, None)
    if cid in t.first:
        msg, err = _decode_first(enc, sch, t.first[cid], factory)
    docs, sname = _schema_docs(sch, getattr(sch, "name", None), senc)
    n = t.count.get(cid, 0)
    span = (t.tmax[cid] - t.tmin[cid]) / 1e9 if n > 1 else None
    return {
        "id": cid, "topic": ch.topic, "message_encoding": enc, "schema_name": sname, "schema_encoding": senc,
        "message_type": ros2_type_name(sname) if is_ros else sname,
        "metadata": dict(ch.metadata or {}), "message_count": n,
        "messages_expected": int(per_chan.get(cid, 0)) if per_chan is not None else None,
        "first_log_time": _iso(t.tmin.get(cid)), "last_log_time": _iso(t.tmax.get(cid)),
        "first_log_time_ns": t.tmin.get(cid), "last_log_time_ns": t.tmax.get(cid),
        "rate_hz": (n - 1) / span if span else None,
        "fields": field_names(msg) if isinstance(msg, dict) else [],
        "first_message": _preview(msg) if msg is not None else None,
        "field_docs": docs, "decode_error": err,
    }


def describe_mcap(path: str | Path, *, memory_limit_bytes: float | None = None) -> dict[str, Any]:
    """What is in an MCAP file, as a JSON-serialisable dict (``hadal inspect``, ``hadal init``).

    One sequential pass with the same damage recovery as :func:`read_mcap` (intact chunks of a truncated or
    corrupted file are kept). Keys: ``path``, ``format`` (``"mcap"``), ``size_bytes``, ``profile``, ``library``,
    ``message_count``, ``start_time``/``end_time`` (ISO 8601 UTC) and ``duration_s``, ``chunks`` (``read``,
    ``corrupt``, ``expected``/``lost`` when the summary survived, ``compression``), ``truncated``, ``problem``,
    ``messages_expected``/``messages_lost`` (``None`` when unknown), ``summary`` (whether a summary section
    was read), ``metadata`` (record names), ``attachments`` and ``channels``: one dict per channel with
    ``id``, ``topic``, ``message_encoding``, ``schema_name``, ``schema_encoding``, ``message_type`` (ROS 2
    ``pkg/msg/Type`` or the schema name), ``metadata``, ``message_count`` (read), ``messages_expected``,
    ``first_log_time``/``last_log_time``, ``rate_hz``, ``fields`` (dotted names of the first decoded
    message), ``first_message`` (abridged), ``field_docs`` (units/comments from the schema) and
    ``decode_error``. Raises :class:`InputError` only when the file is missing, empty or not MCAP, or when its
    chunks pass the memory budget ``memory_limit_bytes`` as they decompress (:class:`_Walk`).
    """
    path = Path(path)
    _open_check(path)
    t, walk = _tally_mcap(path, memory_limit_bytes)
    truncated, problem, corrupt = walk.problem is not None, walk.problem, walk.corrupt
    summary_read = t.stats is not None
    if t.stats is None and (truncated or corrupt):
        summary_read = _recover_summary(path, t)
    stats = t.stats
    per_chan = dict(stats.channel_message_counts) if stats is not None else None
    factory: list[Any] = []
    out_channels = [_describe_channel(cid, ch, t, per_chan, factory) for cid, ch in sorted(t.channels.items())]
    total = sum(t.count.values())
    expected = int(stats.message_count) if stats is not None else None
    t0 = min(t.tmin.values()) if t.tmin else None
    t1 = max(t.tmax.values()) if t.tmax else None
    lost = max(expected - total, 0) if expected is not None else (0 if not (truncated or corrupt) else None)
    return {
        "path": str(path), "format": "mcap", "size_bytes": path.stat().st_size,
        "profile": getattr(t.header, "profile", None), "library": getattr(t.header, "library", None),
        "message_count": total, "start_time": _iso(t0), "end_time": _iso(t1),
        "duration_s": (t1 - t0) / 1e9 if t0 is not None and t1 is not None else None,
        "chunks": {"read": t.chunks_read, "corrupt": corrupt,
                   "expected": t.chunk_indexes if summary_read else None,
                   "lost": max(t.chunk_indexes - t.chunks_read, 0) if summary_read else None,
                   "compression": sorted(t.compression)},
        "truncated": truncated, "problem": problem, "summary": summary_read,
        "messages_expected": expected, "messages_lost": lost,
        "metadata": t.metadata, "attachments": t.attachments, "channels": out_channels,
    }
