"""Compiled (numba) inner loops of :mod:`hadal.ingest.mcap_reader`: the record walk over a decompressed
MCAP chunk and the gathering of one channel's payloads into one buffer.

MCAP spec (https://mcap.dev/spec): a record is ``opcode u8, length u64 LE, body``; a Message body is
``channel_id u16, sequence u32, log_time u64, publish_time u64, data``. Compiled on first use and cached
next to this file; :func:`hadal.ingest.mcap_reader._parse_chunk` is the pure-Python reference.
"""

from __future__ import annotations

import numpy as np
from numba import njit

#: a log time above int64 (a valid MCAP u64, e.g. 2**63) is clamped to this: one implausible time stamp,
#: rejected and counted downstream like any out-of-range time, rather than an overflow that drops the chunk
INT64_MAX = np.iinfo(np.int64).max

#: walk status: 0 ok, 1 record header past the chunk end, 2 record past the chunk end, 3 message too short
OK, HEADER_PAST_END, RECORD_PAST_END, MESSAGE_TOO_SHORT = 0, 1, 2, 3


@njit(cache=True, nogil=True)
def _u64(b, p):  # pragma: no cover - compiled
    v = np.uint64(0)
    for i in range(7, -1, -1):
        v = (v << np.uint64(8)) | np.uint64(b[p + i])
    return v


@njit(cache=True, nogil=True)
def walk_chunk(b):  # pragma: no cover - compiled
    """Records of a decompressed chunk ``b`` (uint8). Returns ``(status, cid, log_time, data_start,
    data_len, other_op, other_start, other_end)``: per Message record its channel id, log time (int64 ns)
    (clamped to ``INT64_MAX``) and payload span; per other record (Schema, Channel, ...) its opcode and body span, in file order.
    ``status`` != 0 (see the module constants) means damaged framing: the caller drops the chunk."""
    n = b.size
    cap = n // 31 + 1  # the shortest message record is 9 + 22 bytes
    cid = np.empty(cap, np.int64)
    lt = np.empty(cap, np.int64)
    ds = np.empty(cap, np.int64)
    dl = np.empty(cap, np.int64)
    ocap = n // 9 + 1
    oop = np.empty(ocap, np.int64)
    os_ = np.empty(ocap, np.int64)
    oe = np.empty(ocap, np.int64)
    k = 0
    ko = 0
    status = OK
    pos = 0
    while pos < n:
        if pos + 9 > n:
            status = HEADER_PAST_END
            break
        op = b[pos]
        ln = _u64(b, pos + 1)
        pos += 9
        if ln > np.uint64(n - pos):
            status = RECORD_PAST_END
            break
        end = pos + np.int64(ln)
        if op == 5:
            if end - pos < 22:
                status = MESSAGE_TOO_SHORT
                break
            cid[k] = np.int64(b[pos]) | (np.int64(b[pos + 1]) << 8)
            t = _u64(b, pos + 6)
            lt[k] = np.int64(t) if t <= np.uint64(INT64_MAX) else INT64_MAX
            ds[k] = pos + 22
            dl[k] = end - pos - 22
            k += 1
        else:
            oop[ko] = op
            os_[ko] = pos
            oe[ko] = end
            ko += 1
        pos = end
    return status, cid[:k].copy(), lt[:k].copy(), ds[:k].copy(), dl[:k].copy(), oop[:ko].copy(), \
        os_[:ko].copy(), oe[:ko].copy()


@njit(cache=True, nogil=True)
def gather(b, starts, lens):  # pragma: no cover - compiled
    """The spans ``b[s:s+l]`` as one JSON array text: ``[`` span ``,`` span ... ``]`` (uint8 array)."""
    m = starts.size
    total = 0
    for i in range(m):
        total += lens[i]
    out = np.empty(total + max(m - 1, 0) + 2, np.uint8)
    out[0] = 91  # [
    p = 1
    for i in range(m):
        if i:
            out[p] = 44  # ,
            p += 1
        s = starts[i]
        ln = lens[i]
        out[p:p + ln] = b[s:s + ln]
        p += ln
    out[p] = 93  # ]
    return out
