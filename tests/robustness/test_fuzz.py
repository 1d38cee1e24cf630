"""Fuzzing harness (issue 14, Method): mutate real and sample files, feed them to hadal's public readers/stages.

The property, for every reader and stage entry point: a call either returns normally or raises a
:class:`hadal.errors.HadalError` whose message is one line -- never another exception type (a traceback
for the user), never a hang (a per-example SIGALRM deadline) -- and a stage run that raises leaves the
product store exactly as it was (no new version, no ``.staging-*``).

Mutations (strategies below, composable, all printable so a failure shows what was done):

* bytes: truncation, bit flips, byte insertions (random or "special" bytes), deletions, block duplication;
* text: cell/field type swaps (a number -> ``true``/``[1.0]``/``{"a":1}``/``abc``/empty/``nan``/``1e309``),
  number scaling (ns -> ms, x1000, negation), year shifts in ISO dates (1726, 1970, 2100, 2108, 9999),
  line deletion/duplication/swap (time going backwards), encodings (UTF-16, BOM, CRLF, CR, a Latin-1 byte);
* MCAP (decoded and re-written with the ``mcap`` writer): JSON field type swaps, dropped keys, non-object
  messages, ``log_time`` ns -> ms/us, year shifts, one topic an hour off, ``stamp`` x1000, duplicate
  channels on one topic; then optionally a byte mutation of the written file.

Seeds: ``../shared/data`` (ctd-real, formats-real, bathy-real, mcap-real; skipped cleanly when absent) and
the small sample dive (``small_dive`` fixture), cut down into *mini dives* so one stage run takes well
under a second or two.

Budget: ``HADAL_FUZZ_EXAMPLES`` examples per reader test (default 20; stage tests run a third of that,
at least 3), ``derandomize=True`` and no example database, so CI is reproducible; the whole file runs in
under a minute on a 2-core machine. Long run on demand: ``HADAL_FUZZ_EXAMPLES=2000 pytest tests/robustness/test_fuzz.py``.

Every failure found becomes a file in ``tests/fuzz_corpus/<target>/`` plus a line in its README;
:func:`test_corpus_replay` replays each one (``xfail(strict=True)`` while it is a known failure, so a fix
shows up as XPASS and the entry is then moved to "fixed"), and the property tests skip exactly those
inputs (by SHA-256 of the mutated file) so they stay green.
"""

from __future__ import annotations

import bz2
import contextlib
import dataclasses
import gzip
import hashlib
import io
import json
import os
import re
import signal
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import pytest
from conftest import SHARED_DATA
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st

from hadal.errors import HadalError

HERE = Path(__file__).resolve().parents[1]
CORPUS = HERE / "fuzz_corpus"
N_EXAMPLES = max(1, int(os.environ.get("HADAL_FUZZ_EXAMPLES", "20")))
N_STAGE = max(3, N_EXAMPLES // 3)
READER_DEADLINE_S = float(os.environ.get("HADAL_FUZZ_DEADLINE_S", "20"))
STAGE_DEADLINE_S = float(os.environ.get("HADAL_FUZZ_STAGE_DEADLINE_S", "60"))

FUZZ = settings(max_examples=N_EXAMPLES, deadline=None, derandomize=True, database=None,
                suppress_health_check=list(HealthCheck), print_blob=False)
FUZZ_STAGE = settings(FUZZ, max_examples=N_STAGE)


# ============================================================================================ the property
MEM_LIMIT_GB = float(os.environ.get("HADAL_FUZZ_MEM_GB", "8"))  # address-space limit of the forked call
_LOG = os.environ.get("HADAL_FUZZ_LOG")  # a file: one line per call (outcome), to see what the budget covers
_SAVE = os.environ.get("HADAL_FUZZ_SAVE")  # a directory: every failing input is written there (to triage)


class FuzzFailure(AssertionError):
    """The property broke: a traceback (non-HadalError), a crash, a hang or a multi-line/empty message."""


def _log(line: str) -> None:
    if _LOG:
        with open(_LOG, "a", encoding="utf-8") as fh:
            fh.write(line[:400].replace("\n", "\\n") + "\n")


def _run_spec(spec: tuple) -> None:
    """What one isolated call does: ``("reader", target, path)`` or ``("stage", stage, raw_dir, store)``."""
    if spec[0] == "reader":
        _reader(spec[1])(Path(spec[2]))
    elif spec[0] == "stage":
        from hadal.pipeline import make_context, run_stage

        run_stage(spec[1], make_context(spec[2], spec[3]))
    else:
        raise AssertionError(spec)


def _child_main(spec: tuple, conn) -> None:
    """The isolated child: run ``spec`` and send its outcome (a dict) back on ``conn``."""
    import resource
    import time
    import traceback

    t0 = time.monotonic()
    out: dict[str, Any]
    if os.environ.get("HADAL_FUZZ_DEBUG"):
        import faulthandler

        faulthandler.register(signal.SIGTERM, all_threads=True, chain=True)
    try:
        if MEM_LIMIT_GB > 0:
            lim = int(MEM_LIMIT_GB * 2 ** 30)
            resource.setrlimit(resource.RLIMIT_AS, (lim, lim))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            _run_spec(spec)
        out = {"status": "ok"}
    except HadalError as exc:
        out = {"status": "hadal", "type": type(exc).__name__, "msg": str(exc)}
    except BaseException as exc:  # noqa: BLE001 - exactly what the property forbids
        tb = traceback.extract_tb(exc.__traceback__)
        where = next((f"{Path(f.filename).name}:{f.lineno} in {f.name}" for f in reversed(tb)
                      if "/hadal/" in f.filename), tb[-1].name if tb else "?")
        out = {"status": "exception", "type": type(exc).__name__, "msg": str(exc)[:500], "where": where}
    out["t_s"] = round(time.monotonic() - t0, 3)
    conn.send(out)
    conn.close()


_MP: list = []
PRELOAD = ["numpy", "pandas", "xarray", "hadal.pipeline", "hadal.formats", "hadal.inspect", "hadal.ingest.cnv",
           "hadal.ingest.seabird_hex", "hadal.ingest.mcap_reader", "hadal.grid.sonar", "hadal.grid.readers",
           "hadal.stages.ingest", "hadal.stages.grid", "test_fuzz"]


def _context():
    """A ``forkserver`` multiprocessing context: each call runs in a child forked from a clean server that
    has imported hadal but never run it -- so a segfault, hang or memory blow-up in a native library cannot
    take the test run down, and numba's GNU OpenMP layer (not fork-safe once used) is never forked used."""
    if not _MP:
        import multiprocessing as mp

        ctx = mp.get_context("forkserver")
        ctx.set_forkserver_preload(PRELOAD)
        _MP.append(ctx)
    return _MP[0]


def _parent_used_openmp() -> bool:
    try:
        import numba.np.ufunc.parallel as nbp
    except ImportError:
        return False
    return bool(getattr(nbp, "_is_initialized", True))


class _ForkCtx:
    """A plain ``os.fork`` per call (fast: everything is already imported) -- used while this test process
    has not run numba's GNU OpenMP layer, which refuses to run in a child forked after it was used."""

    @staticmethod
    def Pipe(duplex=False):  # noqa: N802 - mirrors multiprocessing.Pipe
        import multiprocessing as mp

        return mp.Pipe(duplex=duplex)

    class Process:
        def __init__(self, target, args, daemon=True):
            self.target, self.args, self.pid, self.exitcode = target, args, None, None

        def start(self):
            self.pid = os.fork()
            if self.pid == 0:  # pragma: no cover - child
                try:
                    self.target(*self.args)
                finally:
                    os._exit(0)

        def kill(self):
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, signal.SIGKILL)

        def join(self, timeout=None):
            if self.exitcode is None:
                _, status = os.waitpid(self.pid, 0)
                self.exitcode = os.waitstatus_to_exitcode(status)


def run_isolated(spec: tuple, limit_s: float) -> dict[str, Any]:
    """``spec`` run in an isolated child: its outcome, or ``{"status": "crash"|"hang"}``."""
    ctx = _context() if _parent_used_openmp() or os.environ.get("HADAL_FUZZ_FORKSERVER") else _ForkCtx
    r, w = ctx.Pipe(duplex=False)
    p = ctx.Process(target=_child_main, args=(spec, w), daemon=True)
    p.start()
    w.close()
    try:
        if not r.poll(limit_s):
            p.kill()
            p.join()
            return {"status": "hang", "msg": f"no result after {limit_s:.0f} s"}
        try:
            out = r.recv()
        except EOFError:
            out = None
    finally:
        r.close()
    p.join(30)
    if out is None:
        return {"status": "crash", "msg": f"child died (exit code {p.exitcode})"}
    return out


ISOLATE = os.environ.get("HADAL_FUZZ_ISOLATE", "native")  # "all", "native" (default) or "none"
#: readers that reach native code which has crashed the whole process (GSF: a segfault, fuzz_corpus/README.md);
#: inspect_file/detect only for GSF inputs (isolating everything costs ~0.6 s a call: JIT and lazy imports)
NATIVE = {"read_multibeam"}


def _isolated(spec: tuple) -> bool:
    if ISOLATE == "all":
        return True
    return ISOLATE == "native" and spec[0] == "reader" and (spec[1] in NATIVE or "gsf" in Path(spec[2]).name)


class _Hang(BaseException):
    pass


def run_inproc(spec: tuple, limit_s: float) -> dict[str, Any]:
    """``spec`` in this process (fast: numba's JIT and lazy imports are paid once) under a SIGALRM deadline."""
    import traceback

    def _alarm(signum, frame):
        raise _Hang

    old = signal.signal(signal.SIGALRM, _alarm)
    signal.setitimer(signal.ITIMER_REAL, limit_s)
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            _run_spec(spec)
        return {"status": "ok"}
    except _Hang:
        return {"status": "hang", "msg": f"no result after {limit_s:.0f} s"}
    except HadalError as exc:
        return {"status": "hadal", "type": type(exc).__name__, "msg": str(exc)}
    except Exception as exc:  # noqa: BLE001 - exactly what the property forbids (MemoryError included)
        tb = traceback.extract_tb(exc.__traceback__)
        where = next((f"{Path(f.filename).name}:{f.lineno} in {f.name}" for f in reversed(tb)
                      if "/hadal/" in f.filename), tb[-1].name if tb else "?")
        return {"status": "exception", "type": type(exc).__name__, "msg": str(exc)[:500], "where": where}
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


def call_checked(spec: tuple, limit_s: float = READER_DEADLINE_S, what: str = "") -> str | None:
    """Run ``spec`` (isolated, :func:`run_isolated`): returning is fine; a one-line HadalError gives its message; anything else
    (another exception type, a crash, a hang, an empty or multi-line message) raises :class:`FuzzFailure`."""
    out = run_isolated(spec, limit_s) if _isolated(spec) else run_inproc(spec, limit_s)
    st_ = out["status"]
    problem = None
    if st_ == "exception":
        problem = f"traceback: {out['type']}: {out['msg']} (at {out['where']})"
    elif st_ in ("crash", "hang"):
        problem = f"{st_}: {out['msg']}"
    elif st_ == "hadal":
        msg = out["msg"].strip()
        if not msg:
            problem = f"{out['type']} with an empty message"
        elif "\n" in msg or "\r" in msg:
            problem = f"{out['type']} message is not one line: {out['msg']!r}"
    _log(f"{what}\t{'FAIL' if problem else st_}\t{out.get('t_s')}\t{problem or out.get('msg', '')}")
    if problem:
        raise FuzzFailure(f"{what}: {problem}")
    return out["msg"] if st_ == "hadal" else None


def save_failure(target: str, name: str, data: bytes, reason: str) -> None:
    if _SAVE:
        d = Path(_SAVE) / target
        d.mkdir(parents=True, exist_ok=True)
        f = d / f"{_sha(data)[:12]}--{name}"
        f.write_bytes(data)
        with open(Path(_SAVE) / "index.tsv", "a", encoding="utf-8") as fh:
            fh.write(f"{target}/{f.name}\t{len(data)}\t{reason[:300]}\n")


# ============================================================================================ known failures
def _sha(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()


def _corpus_entries() -> list[tuple[str, Path, str, str]]:
    """``(target, file, status, reason)`` for every corpus file listed in ``fuzz_corpus/README.md``.

    README lines: ``- `<target>/<file>`: <status>: <exception and one-line description>`` with status
    ``known`` (still failing) or ``fixed``."""
    out = []
    readme = CORPUS / "README.md"
    if not readme.is_file():
        return out
    for line in readme.read_text(encoding="utf-8").splitlines():
        m = re.match(r"^- `([^/`]+)/([^`]+)`: (known|fixed): (.*)$", line.strip())
        if m:
            out.append((m[1], CORPUS / m[1] / m[2], m[3], m[4]))
    return out


KNOWN: dict[str, set[str]] = {}
for _t, _f, _s, _r in _corpus_entries():
    if _s == "known" and _f.is_file():
        KNOWN.setdefault(_t, set()).add(_sha(_f.read_bytes()))


def assume_not_known(target: str, data: bytes) -> None:
    """Exclude exactly the inputs already in the corpus as known failures (replayed by test_corpus_replay)."""
    assume(_sha(data) not in KNOWN.get(target, set()))


# ============================================================================================ mutations
SPECIAL_BYTES = [b"\x00", b"\xff", b"\xb0", b"\xe9", b"\r", b"\n", b",", b"\t", b"\"", b"{", b"\x89MCAP0\r\n",
                 b"\xef\xbb\xbf", b"*END*\n", b"# ", b"-", b"."]
SWAP_TOKENS = ["true", "false", "[1.0]", '{"a":1}', "abc", "", "nan", "inf", "-inf", "1e309", "-1e400",
               "0x1F", "NULL", "9" * 40, "-0", "1,5", "2018-10-06T23:00:00Z", "\u00b0"]
YEARS = ["1726", "1970", "1900", "2100", "2108", "9999", "0000", "2019"]


@dataclasses.dataclass(frozen=True)
class Mut:
    """One mutation: ``op`` names it, ``args`` parameterise it (fractions in [0, 1] pick positions)."""
    op: str
    args: tuple = ()

    def __call__(self, data: bytes) -> bytes:
        return _APPLY[self.op](data, *self.args)

    def __repr__(self) -> str:
        return f"{self.op}{self.args!r}"


def _pos(data: bytes | list, frac: float) -> int:
    return min(len(data), int(frac * len(data)))


# ------------------------------------------------------------------------------- byte level
def _truncate(d: bytes, f: float) -> bytes:
    return d[:_pos(d, f)]


def _bitflip(d: bytes, flips: tuple) -> bytes:
    b = bytearray(d)
    for f, bit in flips:
        if b:
            i = min(len(b) - 1, int(f * len(b)))
            b[i] ^= 1 << bit
    return bytes(b)


def _insert(d: bytes, f: float, ins: bytes) -> bytes:
    i = _pos(d, f)
    return d[:i] + ins + d[i:]


def _delete(d: bytes, f: float, n: int) -> bytes:
    i = _pos(d, f)
    return d[:i] + d[i + n:]


def _dup_block(d: bytes, f: float, n: int) -> bytes:
    i = _pos(d, f)
    return d[:i + n] + d[i:i + n] + d[i + n:]


# ------------------------------------------------------------------------------- text level (latin-1: lossless)
def _lines(d: bytes) -> list[str]:
    return d.decode("latin-1").split("\n")


def _join(lines: list[str]) -> bytes:
    return "\n".join(lines).encode("latin-1", errors="replace")


_TOKEN = re.compile(r"[^\s,;:=\[\]{}\"]+")
_NUMBER = re.compile(r"(?<![\w.])[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?(?![\w.])")


def _cell_swap(d: bytes, fl: float, ft: float, new: str) -> bytes:
    lines = _lines(d)
    if not lines:
        return d
    i = min(len(lines) - 1, int(fl * len(lines)))
    toks = list(_TOKEN.finditer(lines[i]))
    if not toks:
        return d
    m = toks[min(len(toks) - 1, int(ft * len(toks)))]
    lines[i] = lines[i][:m.start()] + new + lines[i][m.end():]
    return _join(lines)


def _column_swap(d: bytes, fl: float, ft: float, new: str) -> bytes:
    """The same token position replaced on every line from ``fl`` on (a whole column of wrong type)."""
    lines = _lines(d)
    start = min(len(lines), int(fl * len(lines)))
    for i in range(start, len(lines)):
        toks = list(_TOKEN.finditer(lines[i]))
        if toks:
            m = toks[min(len(toks) - 1, int(ft * len(toks)))]
            lines[i] = lines[i][:m.start()] + new + lines[i][m.end():]
    return _join(lines)


_KV = re.compile(r"^(\s*[#*]?\s*[\w .\-/\[\]()]+?\s*[=:]\s*)(\S.*)$")


def _header_swap(d: bytes, fl: float, new: str) -> bytes:
    """A ``key = value`` / ``key: value`` line (CNV/hex headers, YAML configs) gets a value of another type."""
    lines = _lines(d)
    kv = [i for i, ln in enumerate(lines[:2000]) if _KV.match(ln)]
    if not kv:
        return d
    i = kv[min(len(kv) - 1, int(fl * len(kv)))]
    m = _KV.match(lines[i])
    lines[i] = m[1] + new
    return _join(lines)


def _scale_numbers(d: bytes, fl: float, factor: float) -> bytes:
    """Every number from line ``fl`` on multiplied (ns -> ms is 1e-6, s -> ms 1e3, sign flip -1)."""
    lines = _lines(d)
    start = min(len(lines), int(fl * len(lines)))

    def rep(m: re.Match) -> str:
        try:
            v = float(m[0]) * factor
        except ValueError:
            return m[0]
        return repr(int(v)) if abs(v) < 1e18 and v == int(v) and "." not in m[0] else repr(v)

    for i in range(start, len(lines)):
        lines[i] = _NUMBER.sub(rep, lines[i])
    return _join(lines)


def _year_shift(d: bytes, year: str) -> bytes:
    return re.sub(rb"(?<!\d)(19|20)\d\d(?=-\d\d-\d\d)", year.encode(), d)


def _line_op(d: bytes, kind: str, fl: float, n: int) -> bytes:
    lines = _lines(d)
    if not lines:
        return d
    i = min(len(lines) - 1, int(fl * len(lines)))
    if kind == "delete":
        del lines[i:i + n]
    elif kind == "duplicate":
        lines[i:i] = lines[i:i + n]
    elif kind == "swap":  # out of order (time going backwards)
        j = min(len(lines) - 1, i + n)
        lines[i], lines[j] = lines[j], lines[i]
    elif kind == "reverse":
        lines[i:i + n] = lines[i:i + n][::-1]
    return _join(lines)


def _encoding(d: bytes, kind: str) -> bytes:
    if kind == "utf16":
        return d.decode("utf-8", errors="replace").encode("utf-16")
    if kind == "utf16be":
        return d.decode("utf-8", errors="replace").encode("utf-16-be")
    if kind == "bom":
        return b"\xef\xbb\xbf" + d
    if kind == "crlf":
        return d.replace(b"\r\n", b"\n").replace(b"\n", b"\r\n")
    if kind == "cr":
        return d.replace(b"\r\n", b"\n").replace(b"\n", b"\r")
    if kind == "latin1":  # UTF-8 text re-encoded as Latin-1 (a degree sign becomes one byte 0xB0)
        return d.decode("utf-8", errors="replace").encode("latin-1", errors="replace")
    if kind == "nul":
        return d.replace(b"\n", b"\x00\n", 1)
    raise AssertionError(kind)


# ------------------------------------------------------------------------------- compression wrappers
def _recompress(d: bytes, how: str) -> bytes:
    if how == "gzip":
        return gzip.compress(d, mtime=0)
    if how == "bz2":
        return bz2.compress(d)
    return d


_APPLY: dict[str, Callable[..., bytes]] = {
    "truncate": _truncate, "bitflip": _bitflip, "insert": _insert, "delete": _delete, "dup_block": _dup_block,
    "cell_swap": _cell_swap, "header_swap": _header_swap, "column_swap": _column_swap, "scale_numbers": _scale_numbers,
    "year_shift": _year_shift, "line_op": _line_op, "encoding": _encoding, "recompress": _recompress,
}

frac = st.floats(0.0, 1.0, allow_nan=False)

byte_mut = st.one_of(
    st.builds(lambda f: Mut("truncate", (f,)), frac),
    st.builds(lambda fl: Mut("bitflip", tuple([tuple(fl)])),
              st.lists(st.tuples(frac, st.integers(0, 7)), min_size=1, max_size=8).map(tuple)),
    st.builds(lambda f, b: Mut("insert", (f, b)), frac,
              st.one_of(st.sampled_from(SPECIAL_BYTES), st.binary(min_size=1, max_size=16))),
    st.builds(lambda f, n: Mut("delete", (f, n)), frac, st.integers(1, 256)),
    st.builds(lambda f, n: Mut("dup_block", (f, n)), frac, st.integers(1, 256)),
)

HEADER_TOKENS = [*SWAP_TOKENS, "0", "-1", "1e-9", "99999999999", "1.5", "[]", "{}", "~", "'", "yes", ".nan",
                 "seconds: 0", "0 = timeS: time [s]", "-9.990e-29", "Jan 01 1970 00:00:00", "Feb 30 2108 25:61:61"]

text_mut = st.one_of(
    st.builds(lambda a, t: Mut("header_swap", (a, t)), frac, st.sampled_from(HEADER_TOKENS)),
    st.builds(lambda a, b, t: Mut("cell_swap", (a, b, t)), frac, frac, st.sampled_from(SWAP_TOKENS)),
    st.builds(lambda a, b, t: Mut("column_swap", (a, b, t)), frac, frac, st.sampled_from(SWAP_TOKENS)),
    st.builds(lambda a, k: Mut("scale_numbers", (a, k)), frac,
              st.sampled_from([1e-6, 1e-3, 1e3, 1e6, 1e9, -1.0, 0.0, 3600.0])),
    st.builds(lambda y: Mut("year_shift", (y,)), st.sampled_from(YEARS)),
    st.builds(lambda k, a, n: Mut("line_op", (k, a, n)), st.sampled_from(["delete", "duplicate", "swap",
                                                                         "reverse"]), frac, st.integers(1, 50)),
    st.builds(lambda k: Mut("encoding", (k,)), st.sampled_from(["utf16", "utf16be", "bom", "crlf", "cr",
                                                                "latin1", "nul"])),
)

any_mut = st.one_of(byte_mut, text_mut)


def mutations(base: st.SearchStrategy = any_mut) -> st.SearchStrategy[list[Mut]]:
    return st.lists(base, min_size=1, max_size=3)


def apply_all(data: bytes, muts: list[Mut]) -> bytes:
    for m in muts:
        data = m(data)
    return data


# ------------------------------------------------------------------------------- MCAP structured mutations
@dataclasses.dataclass
class McapDoc:
    schemas: dict[int, tuple[str, str, bytes]]
    channels: dict[int, tuple[str, str, int]]  # id -> topic, message encoding, schema id
    messages: list[list]  # [channel_id, log_time, publish_time, data bytes]


def parse_mcap(data: bytes) -> McapDoc | None:
    from mcap.reader import make_reader

    try:
        r = make_reader(io.BytesIO(data))
        doc = McapDoc({}, {}, [])
        for schema, channel, msg in r.iter_messages(log_time_order=False):
            if schema is not None and schema.id not in doc.schemas:
                doc.schemas[schema.id] = (schema.name, schema.encoding, schema.data)
            if channel.id not in doc.channels:
                doc.channels[channel.id] = (channel.topic, channel.message_encoding, channel.schema_id)
            doc.messages.append([channel.id, msg.log_time, msg.publish_time, msg.data])
        return doc
    except Exception:  # noqa: BLE001 - a seed the mcap library itself cannot re-read: byte mutations only
        return None


def write_mcap(doc: McapDoc) -> bytes:
    """Re-write ``doc`` (two channel ids may share one topic: a duplicate channel)."""
    from mcap.writer import Writer

    buf = io.BytesIO()
    w = Writer(buf)
    w.start(profile="", library="hadal-fuzz")
    sid = {old: w.register_schema(*v) for old, v in doc.schemas.items()}
    cid = {}
    for old, (topic, enc, schema_id) in doc.channels.items():
        cid[old] = w.register_channel(topic, enc, sid.get(schema_id, 0))
    for seq, (ch, lt, pt, data) in enumerate(doc.messages):
        w.add_message(cid[ch], max(0, int(lt)), data, max(0, int(pt)), seq)
    w.finish()
    return buf.getvalue()


SWAP_VALUES: list[Any] = [True, False, [1.0], [[1.0, 2.0], [3.0, 4.0]], {"v": 1.0}, "12.5", "abc", None,
                          1e308, -0.0, 10 ** 30, "NaN", []]
NS_PER_YEAR = 365 * 86400 * 10 ** 9


@dataclasses.dataclass(frozen=True)
class McapMut:
    op: str
    args: tuple = ()

    def __repr__(self) -> str:
        return f"mcap.{self.op}{self.args!r}"


def _json_msgs(doc: McapDoc) -> list[int]:
    return [i for i, m in enumerate(doc.messages) if doc.channels[m[0]][1] == "json"]


def apply_mcap(doc: McapDoc, muts: list[McapMut]) -> bytes:
    doc = McapDoc(dict(doc.schemas), dict(doc.channels), [list(m) for m in doc.messages])
    for m in muts:
        js = _json_msgs(doc)
        if m.op == "field_swap" and js:
            f, fk, value, count = m.args
            start = min(len(js) - 1, int(f * len(js)))
            for i in js[start:start + count]:
                try:
                    obj = json.loads(doc.messages[i][3])
                except ValueError:
                    continue
                if isinstance(obj, dict) and obj:
                    keys = sorted(obj)
                    obj[keys[min(len(keys) - 1, int(fk * len(keys)))]] = value
                    doc.messages[i][3] = json.dumps(obj).encode()
        elif m.op == "drop_key" and js:
            f, fk = m.args
            i = js[min(len(js) - 1, int(f * len(js)))]
            with contextlib.suppress(ValueError):
                obj = json.loads(doc.messages[i][3])
                if isinstance(obj, dict) and obj:
                    del obj[sorted(obj)[min(len(obj) - 1, int(fk * len(obj)))]]
                    doc.messages[i][3] = json.dumps(obj).encode()
        elif m.op == "raw_payload" and js:
            f, payload = m.args
            doc.messages[js[min(len(js) - 1, int(f * len(js)))]][3] = payload
        elif m.op == "log_time_scale":  # ns -> ms (1e-6) / us (1e-3)
            (div,) = m.args
            for msg in doc.messages:
                msg[1] //= div
                msg[2] //= div
        elif m.op == "year_shift":
            (years,) = m.args
            for msg in doc.messages:
                msg[1] += years * NS_PER_YEAR
                msg[2] += years * NS_PER_YEAR
        elif m.op == "topic_offset":  # one topic's clock off (e.g. a gauge 1 h off the CTD)
            fc, off_s = m.args
            chans = sorted(doc.channels)
            ch = chans[min(len(chans) - 1, int(fc * len(chans)))]
            for msg in doc.messages:
                if msg[0] == ch:
                    msg[1] += off_s * 10 ** 9
        elif m.op == "stamp_scale" and js:
            (factor,) = m.args
            for i in js:
                with contextlib.suppress(ValueError):
                    obj = json.loads(doc.messages[i][3])
                    if isinstance(obj, dict) and isinstance(obj.get("stamp"), (int, float)):
                        obj["stamp"] = obj["stamp"] * factor
                        doc.messages[i][3] = json.dumps(obj).encode()
        elif m.op == "duplicate_channel":  # half of one topic's messages on a second channel with that topic
            (fc,) = m.args
            chans = sorted(doc.channels)
            ch = chans[min(len(chans) - 1, int(fc * len(chans)))]
            new = max(doc.channels) + 1
            doc.channels[new] = doc.channels[ch]
            for k, msg in enumerate(x for x in doc.messages if x[0] == ch):
                if k % 2:
                    msg[0] = new
        elif m.op == "reverse_time":
            ts = [msg[1] for msg in doc.messages][::-1]
            for msg, t in zip(doc.messages, ts, strict=True):
                msg[1] = t
    return write_mcap(doc)


mcap_mut = st.one_of(
    st.builds(lambda f, k, v, n: McapMut("field_swap", (f, k, v, n)), frac, frac, st.sampled_from(SWAP_VALUES),
              st.sampled_from([1, 10, 10 ** 6])),
    st.builds(lambda f, k: McapMut("drop_key", (f, k)), frac, frac),
    st.builds(lambda f, p: McapMut("raw_payload", (f, p)), frac,
              st.sampled_from([b"[1,2]", b"1", b'"x"', b"null", b"{", b"", b"\xff\xfe", b'{"stamp":"x"}',
                               b'{"stamp":1e400}', b"NaN"])),
    st.builds(lambda d: McapMut("log_time_scale", (d,)), st.sampled_from([10 ** 6, 10 ** 3])),
    st.builds(lambda y: McapMut("year_shift", (y,)), st.sampled_from([-48, 82, 90, 1])),
    st.builds(lambda f, o: McapMut("topic_offset", (f, o)), frac, st.sampled_from([3600, -3600, 10 ** 6])),
    st.builds(lambda k: McapMut("stamp_scale", (k,)), st.sampled_from([1000.0, 1e-3, 1e9, -1.0])),
    st.builds(lambda f: McapMut("duplicate_channel", (f,)), frac),
    st.just(McapMut("reverse_time")),
)


@dataclasses.dataclass(frozen=True)
class Recipe:
    """What to do to a seed (small, printable): MCAP-level mutations, then byte/text mutations, then
    compression (``compress``: the text is mutated and then compressed; ``pre``: mutate the compressed bytes)."""
    mcap: tuple = ()
    muts: tuple = ()
    compress: str | None = None
    pre: bool = False

    def apply(self, seed: bytes) -> bytes:
        data = seed
        if self.mcap:
            doc = parse_mcap(seed)
            if doc is not None:
                data = apply_mcap(doc, list(self.mcap))
        if self.compress and self.pre:
            return apply_all(_recompress(data, self.compress), list(self.muts))
        data = apply_all(data, list(self.muts))
        return _recompress(data, self.compress) if self.compress else data


@st.composite
def mcap_recipe(draw, seed: bytes):
    """A mutated MCAP: structured (re-written) mutations when the seed parses, then maybe byte mutations."""
    parses = parse_mcap(seed) is not None
    mc = tuple(draw(st.lists(mcap_mut, min_size=1, max_size=3))) if parses and draw(st.booleans()) else ()
    muts = tuple(draw(mutations(byte_mut))) if not mc or draw(st.booleans()) else ()
    return Recipe(mcap=mc, muts=muts)


@st.composite
def text_recipe(draw, compress: str | None = None):
    """Mutations of a text seed (optionally compressed after mutation, or mutated after compression)."""
    if compress and draw(st.booleans()):
        return Recipe(muts=tuple(draw(mutations(byte_mut))), compress=compress, pre=True)
    return Recipe(muts=tuple(draw(mutations(any_mut))), compress=compress)


# ============================================================================================ seeds
def _shared(*parts: str) -> list[Path]:
    d = SHARED_DATA.joinpath(*parts[:-1])
    return sorted(d.glob(parts[-1])) if d.is_dir() else []


def _mini_mcap(src: Path, seconds: float = 600.0) -> bytes:
    """The first ``seconds`` of an MCAP log, re-written (so one read takes milliseconds)."""
    doc = parse_mcap(src.read_bytes())
    assert doc is not None, src
    t0 = min(m[1] for m in doc.messages)
    doc.messages = [m for m in doc.messages if m[1] - t0 <= seconds * 1e9]
    return write_mcap(doc)


def _head_lines(data: bytes, n: int, step: int = 1) -> bytes:
    lines = data.split(b"\n")
    return b"\n".join(lines[:1] + lines[1:n * step:step]) + b"\n"


def _mini_ply(src: Path, n: int = 3000) -> bytes:
    raw = src.read_bytes()
    end = raw.index(b"end_header\n") + len(b"end_header\n")
    header = raw[:end].decode("ascii")
    total = int(re.search(r"element vertex (\d+)", header)[1])
    assert "property double x" in header and header.count("property") == 3
    body = raw[end:end + total * 24]
    step = max(1, total // n)
    pts = b"".join(body[i * 24:(i + 1) * 24] for i in range(0, total, step))
    header = re.sub(r"element vertex \d+", f"element vertex {len(pts) // 24}", header)
    return header.encode("ascii") + pts


@dataclasses.dataclass
class Samples:
    root: Path
    mcap: bytes
    csv: dict[str, bytes]
    xyz: bytes  # decompressed multibeam soundings (subsampled)
    ply: bytes


@pytest.fixture(scope="session")
def samples(small_dive, tmp_path_factory) -> Samples:
    root = tmp_path_factory.mktemp("fuzz-seeds")
    mc = _mini_mcap(small_dive / "logs" / "haidou.mcap")
    csv = {p.name: _head_lines(p.read_bytes(), 1200) for p in sorted((small_dive / "csv").glob("*.csv"))}
    xyz = _head_lines(gzip.decompress((small_dive / "multibeam" / "em122_line01.xyz.gz").read_bytes()), 4000, 20)
    ply = _mini_ply(small_dive / "laser" / "submap_01.ply")
    return Samples(root, mc, csv, xyz, ply)


def _write(tmp: Path, name: str, data: bytes) -> Path:
    p = tmp / name
    p.write_bytes(data)
    return p


_N = [0]


def _fresh(tmp_path: Path) -> Path:
    """A fresh directory per example (function-scoped tmp_path is shared by all examples of one test)."""
    _N[0] += 1
    d = tmp_path / f"ex{_N[0]}"
    d.mkdir()
    return d


# ============================================================================================ reader tests
CNV_SEEDS = _shared("ctd-real", "*.cnv") + _shared("formats-real", "*.cnv")
HEX_SEEDS = _shared("formats-real", "*.hex")
MB_SEEDS = (_shared("formats-real", "*.kmall") + _shared("formats-real", "*.s7k") + _shared("formats-real", "*.all")
            + _shared("bathy-real", "*.gsf*"))
GRID_SEEDS = _shared("bathy-real", "*.tif") + _shared("bathy-real", "*.nc") + _shared("formats-real", "*.nc")
MCAP_SEEDS = _shared("mcap-real", "*.mcap")
ALL_SHARED = sorted({*CNV_SEEDS, *HEX_SEEDS, *MB_SEEDS, *GRID_SEEDS, *MCAP_SEEDS,
                     *_shared("formats-real", "*.inf")})


def _reader(target: str) -> Callable[[Path], Any]:
    if target == "detect":
        from hadal.formats import detect

        return detect
    if target == "inspect_file":
        from hadal.inspect import inspect_file

        def run(p):
            out = inspect_file(p)
            err = out.get("error")
            assert err is None or ("\n" not in str(err).strip()), f"inspect_file error not one line: {err!r}"
            return out
        return run
    if target == "read_cnv":
        from hadal.ingest.cnv import read_cnv

        return read_cnv
    if target == "read_hex":
        from hadal.ingest.seabird_hex import read_hex

        return read_hex
    if target == "read_multibeam":
        from hadal.grid.sonar import read_multibeam

        return read_multibeam
    if target == "read_grid":
        from hadal.grid.readers import read_grid

        return read_grid
    if target == "read_point_cloud":
        from hadal.grid.readers import read_point_cloud

        return read_point_cloud
    if target == "read_mcap":
        from hadal.ingest.mcap_reader import read_mcap

        return read_mcap
    raise AssertionError(target)


def check_reader(target: str, tmp: Path, name: str, data: bytes) -> None:
    assume_not_known(target, data)
    p = _write(_fresh(tmp), name, data)
    try:
        call_checked(("reader", target, str(p)), what=f"{target}:{name}")
    except FuzzFailure as exc:
        save_failure(target, name, data, str(exc))
        raise


def fuzz_seeds(data, seeds: dict[str, tuple[bytes, str]]) -> tuple[str, bytes]:
    """Draw a seed by name (``seeds``: name -> (bytes, kind: mcap/text/gzip)) and a recipe; the mutated bytes."""
    if not seeds:
        pytest.skip(f"shared reference data not found at {SHARED_DATA}")
    name = data.draw(st.sampled_from(sorted(seeds)), label="seed")
    raw, kind = seeds[name]
    recipe = data.draw(mcap_recipe(raw) if kind == "mcap" else text_recipe("gzip" if kind == "gzip" else None),
                       label="recipe")
    return name, recipe.apply(raw)


def _from(paths: list[Path]) -> dict[str, tuple[bytes, str]]:
    return {p.name: (p.read_bytes(), "mcap" if p.suffix == ".mcap" else "text") for p in paths}


def _sample_seeds(samples: Samples, *which: str) -> dict[str, tuple[bytes, str]]:
    allseeds = {"haidou.mcap": (samples.mcap, "mcap"), "ctd.csv": (samples.csv["ctd.csv"], "text"),
                "keller.csv": (samples.csv["keller.csv"], "text"), "em122_line01.xyz.gz": (samples.xyz, "gzip"),
                "soundings.xyz": (samples.xyz, "text"), "submap_01.ply": (samples.ply, "text")}
    return {k: allseeds[k] for k in which}


@pytest.mark.parametrize("target", ["detect", "inspect_file"])
@FUZZ
@given(data=st.data())
def test_fuzz_detect_inspect(target, data, tmp_path):
    name, mutated = fuzz_seeds(data, _from(ALL_SHARED))
    check_reader(target, tmp_path, name, mutated)


@FUZZ
@given(data=st.data())
def test_fuzz_sample_files_detect_inspect(samples, data, tmp_path):
    name, mutated = fuzz_seeds(data, _sample_seeds(samples, "haidou.mcap", "ctd.csv", "keller.csv",
                                                   "em122_line01.xyz.gz", "submap_01.ply"))
    for target in ("detect", "inspect_file"):
        check_reader(target, tmp_path, name, mutated)


@FUZZ
@given(data=st.data())
def test_fuzz_read_cnv(data, tmp_path):
    check_reader("read_cnv", tmp_path, *fuzz_seeds(data, _from(CNV_SEEDS)))


@FUZZ
@given(data=st.data())
def test_fuzz_read_hex(data, tmp_path):
    check_reader("read_hex", tmp_path, *fuzz_seeds(data, _from(HEX_SEEDS)))


@pytest.mark.integration  # slow (> 9 s here): the integration tier (issue 20: make test <= 5 min)
@FUZZ
@given(data=st.data())
def test_fuzz_read_multibeam(samples, data, tmp_path):
    seeds = {**_from(MB_SEEDS), **_sample_seeds(samples, "em122_line01.xyz.gz")}
    check_reader("read_multibeam", tmp_path, *fuzz_seeds(data, seeds))


@FUZZ
@given(data=st.data())
def test_fuzz_read_grid(data, tmp_path):
    check_reader("read_grid", tmp_path, *fuzz_seeds(data, _from(GRID_SEEDS)))


@FUZZ
@given(data=st.data())
def test_fuzz_read_point_cloud(samples, data, tmp_path):
    check_reader("read_point_cloud", tmp_path, *fuzz_seeds(data, _sample_seeds(samples, "submap_01.ply",
                                                                                 "soundings.xyz")))


@FUZZ
@given(data=st.data())
def test_fuzz_read_mcap(samples, data, tmp_path):
    seeds = {**_from(MCAP_SEEDS), **_sample_seeds(samples, "haidou.mcap")}
    check_reader("read_mcap", tmp_path, *fuzz_seeds(data, seeds))


# ============================================================================================ stage tests
def _dive_yaml(dive_id: str, sources: dict) -> str:
    import yaml

    return yaml.safe_dump({
        "dive_id": dive_id, "platform": "Haidou", "vehicle_config": "vehicle.yaml",
        "launch": {"time_utc": "2018-10-06T23:00:00Z", "latitude_deg": 11.33711667, "longitude_deg": 142.20971667},
        "map_frame": {"origin_latitude_deg": 11.33, "origin_longitude_deg": 142.2},
        "sources": sources}, sort_keys=False)


MINI_DIVES = {
    # name: (stage, dive.yaml sources, pipeline.yaml)
    "mini-mcap": ("ingest", {"mcap": ["logs/haidou.mcap"]}, None),
    "mini-csv": ("ingest", {"csv": {"ctd": "csv/ctd.csv", "gauge": "csv/keller.csv",
                                    "altimeter": "csv/altimeter.csv", "attitude": "csv/attitude.csv",
                                    "dr": "csv/dr.csv"}}, "ingest:\n  source: csv\n"),
    # the gridding stages one by one: each is atomic (a failure leaves the store as it was); the group name
    # ``grid`` runs dtm then laser, so a bad laser file after a good DTM leaves the (valid) DTM published
    "mini-dtm": ("dtm", {"multibeam": ["multibeam/em122_line01.xyz.gz"]}, "grid:\n  dtm_resolution_m: 50.0\n"),
    "mini-laser": ("laser", {"laser": ["laser/submap_01.ply"]}, "grid:\n  laser_resolution_m: 2.0\n"),
}


def _mini_files(samples: Samples, name: str) -> dict[str, bytes]:
    if name == "mini-mcap":
        files = {"logs/haidou.mcap": samples.mcap}
    elif name == "mini-csv":
        files = {f"csv/{k}": v for k, v in samples.csv.items()}
    elif name == "mini-dtm":
        files = {"multibeam/em122_line01.xyz.gz": gzip.compress(samples.xyz, mtime=0)}
    else:
        files = {"laser/submap_01.ply": samples.ply}
    return files


class MiniDive:
    """A fixed raw directory (same path every example, so the store's dive claim accepts it) and a store
    holding one clean published run; each example writes its mutated file, runs the stage, restores."""

    def __init__(self, root: Path, name: str, samples: Samples, small_dive: Path):
        self.name, self.stage = name, MINI_DIVES[name][0]
        self.raw, self.store = root / name, root / f"{name}-store"
        self.raw.mkdir(parents=True)
        self.files = {"dive.yaml": _dive_yaml(f"fuzz-{name}", MINI_DIVES[name][1]).encode(),
                      "vehicle.yaml": (small_dive / "vehicle.yaml").read_bytes()}
        if MINI_DIVES[name][2]:
            self.files["pipeline.yaml"] = MINI_DIVES[name][2].encode()
        self.files.update(_mini_files(samples, name))
        self.restore()
        self.run()  # the clean baseline: must publish
        assert any(self.store.rglob("manifest.json")), f"{name}: the unmutated mini dive published nothing"

    def restore(self) -> None:
        for rel, data in self.files.items():
            p = self.raw / rel
            p.parent.mkdir(parents=True, exist_ok=True)
            p.write_bytes(data)

    @property
    def spec(self) -> tuple:
        return ("stage", self.stage, str(self.raw), str(self.store))

    def run(self) -> None:
        """The clean baseline run (isolated too: hadal never runs in the test process itself)."""
        out = run_isolated(self.spec, STAGE_DEADLINE_S) if _isolated(self.spec) else run_inproc(self.spec,
                                                                                                 STAGE_DEADLINE_S)
        assert out["status"] == "ok", f"{self.name}: the unmutated mini dive does not run: {out}"

    def snapshot(self) -> dict[str, tuple[int, int]]:
        return {str(p.relative_to(self.store)): (p.stat().st_size, p.stat().st_mtime_ns)
                for p in self.store.rglob("*") if p.is_file()}

    def check(self, rel: str, data: bytes, *, replay: bool = False) -> None:
        key = _corpus_name(rel).encode() + b"\0" + data
        if not replay:
            assume_not_known(f"stage-{self.name}", key)
        try:
            (self.raw / rel).write_bytes(data)
            before = self.snapshot()
            err = call_checked(self.spec, STAGE_DEADLINE_S, what=f"stage-{self.name}:{rel}")
            if err is not None:
                after = self.snapshot()
                staging = [k for k in after if "/.staging-" in f"/{k}"]
                if staging:
                    raise FuzzFailure(f"stage {self.stage} raised ({err}) and left staging files: {staging[:3]}")
                if after != before:
                    raise FuzzFailure(f"stage {self.stage} raised ({err}) yet changed the store: "
                                      f"{sorted(set(after) ^ set(before))[:5]}")
        except FuzzFailure as exc:
            save_failure(f"stage-{self.name}", "case", key, str(exc))
            raise
        finally:
            self.restore()


def _corpus_name(rel: str) -> str:
    return rel.replace("/", "__")


@pytest.fixture(scope="module")
def mini_dives(samples, small_dive, tmp_path_factory):
    root = tmp_path_factory.mktemp("fuzz-dives")
    cache: dict[str, MiniDive] = {}

    def get(name: str) -> MiniDive:
        if name not in cache:
            cache[name] = MiniDive(root, name, samples, small_dive)
        return cache[name]
    return get


def _stage_input(draw, mini: MiniDive) -> tuple[str, bytes]:
    rel = draw(st.sampled_from(sorted(mini.files)), label="file")
    raw = mini.files[rel]
    if rel.endswith(".mcap"):
        return rel, draw(mcap_recipe(raw), label="recipe").apply(raw)
    if rel.endswith(".gz"):
        raw = gzip.decompress(raw)
        return rel, draw(text_recipe("gzip"), label="recipe").apply(raw)
    return rel, draw(text_recipe(), label="recipe").apply(raw)


@pytest.mark.parametrize("name", sorted(MINI_DIVES))
@FUZZ_STAGE
@given(data=st.data())
def test_fuzz_stage(name, mini_dives, data):
    mini = mini_dives(name)
    rel, mutated = _stage_input(data.draw, mini)
    mini.check(rel, mutated)


# ============================================================================================ corpus replay
def _replay(target: str, path: Path, dives_get) -> None:
    import tempfile

    data = path.read_bytes()
    if target.startswith("stage-"):  # stage corpus files: "<file's path in the mini dive, / as __>\0<bytes>"
        rel_name, _, payload = data.partition(b"\0")
        _stage_replay(dives_get(target[len("stage-"):]), rel_name, payload)
        return
    with tempfile.TemporaryDirectory(prefix="hadal-fuzz-replay-") as d:
        f = Path(d) / path.name.split("--", 1)[-1]  # reader corpus files: "<case>--<original file name>"
        f.write_bytes(data)
        call_checked(("reader", target, str(f)))


def _stage_replay(mini: MiniDive, rel_name: bytes, payload: bytes) -> None:
    mini.check(rel_name.decode().replace("__", "/"), payload, replay=True)


def _corpus_params():
    out = []
    for target, f, status, reason in _corpus_entries():
        marks = [pytest.mark.xfail(strict=True, reason=reason)] if status == "known" else []
        out.append(pytest.param(target, f, id=f"{target}/{f.name}", marks=marks))
    return out or [pytest.param(None, None, id="empty", marks=pytest.mark.skip(reason="corpus is empty"))]


@pytest.mark.parametrize("target,path", _corpus_params())
def test_corpus_replay(target, path, request):
    assert path.is_file(), f"corpus file missing: {path}"
    _replay(target, path, lambda name: request.getfixturevalue("mini_dives")(name))
