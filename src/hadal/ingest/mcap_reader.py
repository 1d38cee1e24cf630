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
"""

from __future__ import annotations

import io
import json
import struct
import warnings
import zlib
from collections.abc import Iterable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from hadal.errors import InputError

__all__ = ["McapReport", "McapTopic", "mcap_info", "read_mcap", "read_mcap_tables", "to_dict"]

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


def _chunk_bytes(chunk: Any) -> bytes:
    """Decompressed, CRC-checked payload of a Chunk record (ValueError when damaged)."""
    if chunk.compression == "zstd":
        import zstandard

        data = zstandard.decompress(chunk.data, max_output_size=chunk.uncompressed_size)
    elif chunk.compression == "lz4":
        import lz4.frame

        data = lz4.frame.decompress(chunk.data)
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
            append((_OP_MESSAGE, (cid, lt, data[pos + 22:end])))
        elif op == _OP_SCHEMA:
            append((op, Schema.read(ReadDataStream(io.BytesIO(data[pos:end])))))
        elif op == _OP_CHANNEL:
            append((op, Channel.read(ReadDataStream(io.BytesIO(data[pos:end])))))
        pos = end
    return out


def _stream_reader(fh: Any) -> Any:
    """``mcap.stream_reader.StreamReader`` (chunks emitted whole) that skips index/attachment/metadata records
    without parsing them: parsing every chunk's MessageIndex (one Python call per message) cost more than
    the messages themselves. Chunk CRCs are checked in :func:`_chunk_bytes`, so the reader's own CRC
    bookkeeping over the whole data section (one ``crc32`` call per field read) is switched off."""
    from mcap.opcode import Opcode
    from mcap.stream_reader import StreamReader

    skip = {Opcode.MESSAGE_INDEX, Opcode.CHUNK_INDEX, Opcode.ATTACHMENT, Opcode.ATTACHMENT_INDEX,
            Opcode.METADATA, Opcode.METADATA_INDEX, Opcode.SUMMARY_OFFSET}

    class _Reader(StreamReader):
        def _read_record(self, opcode: int, length: int) -> Any:  # mcap 1.x hook
            if opcode in skip:
                self._stream.read(length)
                return None
            return super()._read_record(opcode, length)

    return _Reader(fh, emit_chunks=True, validate_crcs=False, record_size_limit=_RECORD_LIMIT)


def _scan(path: Path, topics: set[str] | None) -> tuple[dict, dict, dict[int, list], dict[int, list], McapReport, Any]:
    """One sequential pass: schemas, channels, raw messages per channel id, and the damage report."""
    from mcap.records import Channel, Chunk, Message, Schema, Statistics

    report = McapReport(path=str(path))
    schemas: dict[int, Any] = {}
    channels: dict[int, Any] = {}
    times: dict[int, list[int]] = {}
    datas: dict[int, list[bytes]] = {}
    stats = None
    wanted: dict[int, bool] = {}

    def want(cid: int) -> bool:
        ok = wanted.get(cid)
        if ok is None:
            ch = channels.get(cid)
            if ch is None:
                return False
            ok = wanted[cid] = topics is None or ch.topic in topics
            if ok:
                times.setdefault(cid, [])
                datas.setdefault(cid, [])
        return ok

    def add_message(cid: int, log_time: int, data: bytes) -> None:
        if want(cid):
            times[cid].append(log_time)
            datas[cid].append(data)
        elif cid not in channels:
            report.decode_errors += 1  # message of an unknown channel

    with open(path, "rb") as fh:
        it = _stream_reader(fh).records
        while True:
            try:
                rec = next(it)
            except StopIteration:
                break
            except Exception as exc:  # noqa: BLE001 - truncated/corrupted framing: keep what we have
                report.truncated = True
                report.problem = f"reading stopped at byte {fh.tell()}: {type(exc).__name__} {exc}".strip()
                break
            if isinstance(rec, Chunk):
                try:
                    inner = _parse_chunk(_chunk_bytes(rec))
                except Exception:  # noqa: BLE001 - bad compression / CRC / framing: skip this chunk only
                    report.corrupt_chunks += 1
                    continue
                for op, r in inner:
                    if op == _OP_MESSAGE:
                        cid, lt, d = r
                        if wanted.get(cid):  # fast path
                            times[cid].append(lt)
                            datas[cid].append(d)
                        else:
                            add_message(cid, lt, d)
                    elif op == _OP_SCHEMA:
                        schemas[r.id] = r
                    else:
                        channels[r.id] = r
                        wanted.pop(r.id, None)
            elif isinstance(rec, Message):
                add_message(rec.channel_id, rec.log_time, rec.data)
            elif isinstance(rec, Schema):
                schemas[rec.id] = rec
            elif isinstance(rec, Channel):
                channels[rec.id] = rec
                wanted.pop(rec.id, None)
            elif isinstance(rec, Statistics):
                stats = rec
    return schemas, channels, times, datas, report, stats


def _decode_json(datas: list[bytes]) -> tuple[list[Any], int]:
    """Decode JSON messages in one ``json.loads`` call; fall back per message when some are corrupt."""
    try:
        out = json.loads(b"[" + b",".join(datas) + b"]")
        if len(out) == len(datas):
            return out, 0
    except (ValueError, UnicodeDecodeError):
        pass
    out, bad = [], 0
    for d in datas:
        try:
            out.append(json.loads(d))
        except (ValueError, UnicodeDecodeError):
            out.append(None)
            bad += 1
    return out, bad


def read_mcap(path: str | Path, topics: Iterable[str] | None = None, *, warn: bool = True
              ) -> tuple[dict[str, McapTopic], McapReport]:
    """Read (and decode) the messages of ``topics`` (all when ``None``) from an MCAP file.

    JSON channels are decoded with :mod:`json`; ``ros2msg``/CDR channels with mcap-ros2-support's
    ``DecoderFactory`` and converted to plain dicts. Messages that cannot be decoded are dropped and
    counted (``report.decode_errors``). Damaged files are read as far as possible (module docstring);
    a :class:`UserWarning` reports lost messages. Raises :class:`InputError` when the file is missing,
    empty or not MCAP, or a requested topic uses an encoding hadal cannot decode.
    """
    path = Path(path)
    _open_check(path)
    tset = set(topics) if topics is not None else None
    schemas, channels, times, datas, report, stats = _scan(path, tset)
    if stats is not None:
        per_chan, total = dict(stats.channel_message_counts), int(stats.message_count)
    else:
        per_chan, total = _summary_counts(path) if (report.truncated or report.corrupt_chunks) else (None, None)

    out: dict[str, McapTopic] = {}
    ros2_factory = None
    for cid, ch in sorted(channels.items()):
        if tset is not None and ch.topic not in tset:
            continue
        sch = schemas.get(ch.schema_id)
        raw = datas.pop(cid, [])  # released once decoded (peak memory: one topic's payloads + all decoded)
        t = np.asarray(times.get(cid, []), dtype=np.int64)
        enc = ch.message_encoding
        if enc == "json":
            msgs, bad = _decode_json(raw)
        elif enc == "cdr" and sch is not None and sch.encoding in ("ros2msg", "ros2idl"):
            if ros2_factory is None:
                from mcap_ros2.decoder import DecoderFactory

                ros2_factory = DecoderFactory()
            try:
                dec = ros2_factory.decoder_for(enc, sch)
            except Exception as exc:  # noqa: BLE001 - broken message definition in the schema record
                raise InputError(f"{path}: cannot build a ROS 2 decoder for {ch.topic} ({sch.name}): {exc}") from None
            msgs, bad = [], 0
            for d in raw:
                try:
                    msgs.append(to_dict(dec(d)))
                except Exception:  # noqa: BLE001 - corrupt CDR payload: drop and count
                    msgs.append(None)
                    bad += 1
        else:
            raise InputError(
                f"{path}: topic {ch.topic} uses message encoding {enc!r} "
                f"(schema {getattr(sch, 'encoding', None)!r}); hadal reads 'json' and ROS 2 'cdr'"
            )
        keep = [i for i, m in enumerate(msgs) if isinstance(m, dict)]
        bad = len(msgs) - len(keep)  # undecodable or not an object
        if len(keep) != len(msgs):
            msgs = [msgs[i] for i in keep]
            t = t[np.asarray(keep, dtype=np.int64)] if keep else t[:0]
        report.decode_errors += bad
        expected = per_chan.get(cid, 0) if per_chan is not None else None
        report.topics[ch.topic] = {
            "channel_id": cid, "schema": getattr(sch, "name", None), "schema_encoding": getattr(sch, "encoding", None),
            "message_encoding": enc, "read": len(msgs), "expected": expected,
            "lost": (expected - len(raw)) if expected is not None else None, "decode_errors": bad,
        }
        out[ch.topic] = McapTopic(ch.topic, getattr(sch, "name", None), getattr(sch, "encoding", None), enc, t, msgs)

    report.messages_read = sum(len(v.messages) for v in out.values())
    if total is not None and tset is None:
        report.messages_expected = total
    elif per_chan is not None:
        report.messages_expected = sum(n for cid, n in per_chan.items()
                                       if cid in channels and (tset is None or channels[cid].topic in tset))
    if report.messages_expected is not None:
        report.messages_lost = max(report.messages_expected - report.messages_read, 0)
    elif report.truncated or report.corrupt_chunks:
        report.messages_lost = None  # unknown: no summary survived
    else:
        report.messages_lost = report.decode_errors
    if warn and report.damaged:
        lost = "an unknown number of" if report.messages_lost is None else str(report.messages_lost)
        what = []
        if report.truncated:
            what.append("truncated/corrupted after the last intact record")
        if report.corrupt_chunks:
            what.append(f"{report.corrupt_chunks} corrupt chunk(s) skipped")
        if report.decode_errors:
            what.append(f"{report.decode_errors} undecodable message(s)")
        warnings.warn(f"{path.name}: {lost} message(s) lost ({'; '.join(what)}); "
                      f"recovered {report.messages_read}", stacklevel=2)
    return out, report


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
    schemas, channels, times, _, _, _ = _scan(path, None)
    return [{"topic": c.topic, "schema": getattr(schemas.get(c.schema_id), "name", None),
             "schema_encoding": getattr(schemas.get(c.schema_id), "encoding", None),
             "message_encoding": c.message_encoding, "messages": len(times.get(c.id, []))}
            for c in sorted(channels.values(), key=lambda c: c.id)]
