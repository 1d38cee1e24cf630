"""Reliability report: run every malformed-input case through the code path a user hits and count the outcomes.

Usage::

    PYTHONPATH=src python tests/reliability_report.py [WORKDIR]

builds both corpora (``tests/malformed/make_corpus.py``: ingest logs; ``tests/malformed/make_corpus_readers.py``:
soundings, point clouds, rasters, dive.yaml, pipeline.yaml, vehicle.yaml, corrupt upstream products), runs each
case as ``hadal stage <stage> DIR --store S`` does (dive + config validation, then the stage; Prefect left out)
against a fresh store, adds the ``security`` class (``tests/malformed/security_cases.py``) and the ``process``
class (``tests/malformed/process_cases.py``: the ``hadal`` command and stage processes under a Prefect API that
refuses, never answers or never becomes ready, a closed stdout pipe, ``kill -9`` mid-publish, two concurrent runs;
real child processes, their orphans found by an environment tag), and prints per reader family or class:

* ``tried``        cases run;
* ``clean error``  a one-line :class:`hadal.errors.HadalError` of the expected class and message with the store
                   byte-for-byte unchanged;
* ``flagged``      published/returned data that flag the defect (the case's check, an oracle on the content);
* ``traceback``    any other exception (goal 0);
* ``silent-wrong`` a result where an error was due, or whose content fails the case's check (goal 0);
* ``wrong error``  a HadalError of the wrong class or message, or one that changed the store (goal 0);
* ``hang``         still running after :data:`CASE_TIMEOUT_S` (a watchdog alarm), or a case's child process
                   still running after its own timeout (``subprocess.TimeoutExpired``; goal 0);
* ``over-memory``  a ``MemoryError`` under an address-space cap of :data:`CASE_MEMORY_BYTES` above the
                   process's size at the start of the case (goal 0);
* ``orphan``       child processes the case left running, and processes it started (tagged) that outlive it
                   (goal 0);
* ``lost``         product versions that no longer verify (:meth:`ProductStore.verify`) or vanished, new versions
                   that do not verify, and leftover staging directories (goal 0).

Exit status 1 when there is a traceback, a lost product or an unhandled case. ``tests/robustness/test_reliability.py``
runs it.
"""

from __future__ import annotations

import contextlib
import hashlib
import logging
import re
import shutil
import subprocess
import sys
import tempfile
import threading
import traceback
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE / "malformed"))

import make_corpus  # noqa: E402
import make_corpus_readers  # noqa: E402
import process_cases  # noqa: E402
import security_cases  # noqa: E402


# ---------------------------------------------------------------------------------------------- store state
def snapshot(root: Path) -> dict[str, str]:
    """Every path under ``root`` (hidden ones too) -> ``"dir"`` or the file's SHA-256."""
    out: dict[str, str] = {}
    if not root.exists():
        return out
    for p in sorted(root.rglob("*")):
        rel = p.relative_to(root).as_posix()
        out[rel] = "dir" if p.is_dir() else hashlib.sha256(p.read_bytes()).hexdigest()
    return out


def intact_versions(root: Path) -> dict[str, bool]:
    """``dive/product/vNNN`` -> whether the version verifies against its manifest."""
    from hadal.store import ProductStore

    st = ProductStore(root)
    out = {}
    for dive in st.dives():
        for product in st.products(dive):
            for pv in st.versions(dive, product):
                try:
                    ok = not st.verify(pv)
                except Exception:  # unreadable manifest
                    ok = False
                out[f"{dive}/{product}/{pv.label}"] = ok
    return out


def lost_products(before: dict[str, bool], after: dict[str, bool], root: Path) -> list[str]:
    """Versions intact before and now broken or gone, new versions that are broken, staging leftovers."""
    lost = [k for k, ok in before.items() if ok and not after.get(k, False)]
    lost += [k for k, ok in after.items() if k not in before and not ok]
    lost += [p.relative_to(root).as_posix() for p in root.glob("*/*/.staging-*")] if root.exists() else []
    return lost


# ---------------------------------------------------------------------------------------------- cases
@dataclass
class Item:
    """One corpus case, whatever generator it comes from."""

    name: str
    reader: str
    directory: Path
    run: Callable[[Path], Any]          # store root -> result (raises on a detected problem)
    error: str | None
    match: str
    check: Callable[[Any], bool] | None
    prepare: Callable[[Path], None] = lambda store: None
    #: processes the case started that are still running after it (pids), beyond this process's children
    leftover: Callable[[], list[int]] = lambda: []


def ingest_items(dest: Path) -> list[Item]:
    from hadal.pipeline import make_context, run_stage
    from hadal.settings import PipelineConfig

    def runner(case: make_corpus.Case, d: Path) -> Callable[[Path], Any]:
        def run(store: Path) -> Any:
            cfg = PipelineConfig.model_validate({"ingest": {"source": case.source}})
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                return run_stage("ingest", make_context(d, store, cfg))
        return run

    def checker(case: make_corpus.Case) -> Callable[[Any], bool] | None:
        if case.check is None:
            return None

        def check(res: Any) -> bool:
            import pandas as pd

            from hadal.products import read_parquet_metadata

            path = res["sensors"].file("sensors.parquet")
            return bool(case.check(pd.read_parquet(path), read_parquet_metadata(path)[0]))
        return check

    reader = {"mcap": "mcap", "csv": "csv", "cnv": "cnv", "vehicle": "vehicle_yaml", "dive": "dive_yaml"}
    return [Item(c.name, reader[c.name.split("_")[0]], d, runner(c, d), c.error, c.match, checker(c))
            for c, d in make_corpus.build_corpus(dest)]


def reader_items(dest: Path) -> list[Item]:
    return [Item(c.name, c.reader, d, (lambda store, c=c, d=d: make_corpus_readers.run_user_path(c, d, store)),
                 c.error, c.match, c.check, (lambda store, d=d: make_corpus_readers.publish_upstream(d, store)))
            for c, d in make_corpus_readers.build_corpus(dest)]


def security_items(dest: Path) -> list[Item]:
    """The ``security`` class (``tests/malformed/security_cases.py``): forged provenance, hand-edited stores,
    hostile names and YAML, a symlinked file offered to the report, AlignCTD's edge."""
    out = []
    for c in security_cases.CASES:
        d = Path(dest) / c.name
        d.mkdir(parents=True, exist_ok=True)
        out.append(Item(c.name, "security", d, (lambda store, c=c, d=d: c.run(d, store)), c.error, c.match,
                        (lambda res, c=c, d=d: c.check(d, res)) if c.check else None,
                        (lambda store, c=c, d=d: c.prepare(d, store))))
    return out


def process_items(dest: Path) -> list[Item]:
    """The ``process`` class (``tests/malformed/process_cases.py``): the ``hadal`` command and stage processes
    under Prefect API faults, a closed stdout, kill -9 mid-publish and concurrent runs."""
    out = []
    for c in process_cases.CASES:
        d = Path(dest) / c.name
        d.mkdir(parents=True, exist_ok=True)
        out.append(Item(c.name, "process", d, (lambda store, c=c, d=d: c.run(d, store)), c.error, c.match,
                        (lambda res, c=c, d=d: c.check(d, res)) if c.check else None,
                        (lambda store, c=c, d=d: c.prepare(d, store)), process_cases.leftover))
    return out


def all_items(dest: Path) -> list[Item]:
    return (ingest_items(Path(dest) / "ingest") + reader_items(Path(dest) / "readers")
            + security_items(Path(dest) / "security") + process_items(Path(dest) / "process"))


# ---------------------------------------------------------------------------------------------- running
#: outcome classes of one case; the first two are good, every other one is a defect (goal 0)
STATUSES = ("clean_error", "flagged", "traceback", "silent_wrong", "wrong_error", "hang", "over_memory")
#: a case that runs longer than this (seconds) is a hang
CASE_TIMEOUT_S = 120.0
#: a case may grow the process's address space by at most this much (bytes) before it is over-memory
CASE_MEMORY_BYTES = 4 << 30


@dataclass
class Outcome:
    name: str
    reader: str
    handled: bool
    traceback: str | None = None
    lost: list[str] = field(default_factory=list)
    detail: str = ""
    #: one of :data:`STATUSES`
    status: str = "traceback"
    #: child processes the case left running (pids)
    orphans: list[int] = field(default_factory=list)


class _Hang(BaseException):
    """Raised by the watchdog alarm in the case's thread (a BaseException: no ``except Exception`` eats it)."""


@contextlib.contextmanager
def _limits(timeout_s: float, memory_bytes: int):
    """A wall-clock alarm (:class:`_Hang`) and an address-space cap (``MemoryError``) around one case, where the
    platform allows (main thread, POSIX); the previous limits are restored after."""
    import resource
    import signal

    main = threading.current_thread() is threading.main_thread() and hasattr(signal, "setitimer")
    old_handler = None
    if main:
        def on_alarm(signum, frame):
            raise _Hang()
        old_handler = signal.signal(signal.SIGALRM, on_alarm)
        signal.setitimer(signal.ITIMER_REAL, timeout_s)
    old_as = resource.getrlimit(resource.RLIMIT_AS)
    try:
        vm = _vm_size_bytes()
        if vm:
            cap = vm + memory_bytes
            hard = old_as[1]
            resource.setrlimit(resource.RLIMIT_AS, (cap if hard == resource.RLIM_INFINITY else min(cap, hard), hard))
    except (ValueError, OSError):
        pass
    try:
        yield
    finally:
        if main:
            signal.setitimer(signal.ITIMER_REAL, 0)
            signal.signal(signal.SIGALRM, old_handler)
        try:
            resource.setrlimit(resource.RLIMIT_AS, old_as)
        except (ValueError, OSError):
            pass


def _vm_size_bytes() -> int | None:
    try:
        for line in Path("/proc/self/status").read_text().splitlines():
            if line.startswith("VmSize:"):
                return int(line.split()[1]) * 1024
    except OSError:
        return None
    return None


def _children() -> set[int]:
    try:
        import psutil
    except ImportError:
        return set()
    return {c.pid for c in psutil.Process().children(recursive=True) if c.is_running()
            and c.status() != psutil.STATUS_ZOMBIE}


def run_item(item: Item, store: Path, *, timeout_s: float = CASE_TIMEOUT_S,
             memory_bytes: int = CASE_MEMORY_BYTES) -> Outcome:
    """Run one case against a fresh ``store``; never raises. Counts the outcome class (:data:`STATUSES`), lost
    products and orphaned child processes."""
    from hadal.errors import HadalError

    if store.exists():
        shutil.rmtree(store)
    item.prepare(store)
    before_tree, before = snapshot(store), intact_versions(store)
    children_before = _children()
    out = Outcome(item.name, item.reader, handled=False)
    try:
        with _limits(timeout_s, memory_bytes):
            res = item.run(store)
    except _Hang:
        out.status = "hang"
        out.detail = f"HANG: still running after {timeout_s:g} s"
    except subprocess.TimeoutExpired as exc:  # a case's child process, killed by the case at its own timeout
        out.status = "hang"
        out.detail = f"HANG: {exc}"
    except MemoryError:
        out.status = "over_memory"
        out.detail = f"OVER MEMORY: needed more than {memory_bytes / 2**30:g} GiB"
    except HadalError as exc:
        msg = str(exc)
        problems = []
        if item.error is None:
            problems.append(f"unexpected {type(exc).__name__}")
        elif type(exc).__name__ != item.error:
            problems.append(f"{type(exc).__name__} instead of {item.error}")
        if "\n" in msg or not msg:
            problems.append("message is not one line")
        if not re.search(item.match, msg):
            problems.append(f"message does not match {item.match!r}")
        if snapshot(store) != before_tree:
            problems.append("store changed")
        out.handled = not problems
        out.status = "clean_error" if not problems else "wrong_error"
        out.detail = f"{type(exc).__name__}: {msg}" + (f"  [{'; '.join(problems)}]" if problems else "")
    except Exception as exc:  # noqa: BLE001 - counting them is the point
        out.traceback = "".join(traceback.format_exception(exc))
        out.status = "traceback"
        out.detail = f"TRACEBACK {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''}"
    else:
        try:
            ok = item.error is None and item.check is not None and bool(item.check(res))
        except Exception as exc:  # noqa: BLE001
            ok = False
            out.detail = f"check raised {type(exc).__name__}: {exc}"
        out.handled = ok
        # a result where an error was due, or one whose content fails the case's oracle check: silently wrong
        out.status = "flagged" if ok else "silent_wrong"
        out.detail = out.detail or ("published, flagged" if ok else f"expected {item.error}, got a result")
    out.lost = lost_products(before, intact_versions(store), store)
    out.orphans = sorted((_children() - children_before) | set(item.leftover()))
    if out.orphans:
        out.handled = False
    return out


def run_all(items: list[Item], work: Path) -> list[Outcome]:
    return [run_item(it, Path(work) / "stores" / it.name) for it in items]


#: the report's columns: (header, counter of one reader's outcomes)
COLUMNS: tuple[tuple[str, Callable[[list[Outcome]], int]], ...] = (
    ("tried", len),
    ("clean error", lambda sel: sum(o.status == "clean_error" for o in sel)),
    ("flagged", lambda sel: sum(o.status == "flagged" for o in sel)),
    ("traceback", lambda sel: sum(o.status == "traceback" for o in sel)),
    ("silent-wrong", lambda sel: sum(o.status == "silent_wrong" for o in sel)),
    ("wrong error", lambda sel: sum(o.status == "wrong_error" for o in sel)),
    ("hang", lambda sel: sum(o.status == "hang" for o in sel)),
    ("over-memory", lambda sel: sum(o.status == "over_memory" for o in sel)),
    ("orphan", lambda sel: sum(len(o.orphans) for o in sel)),
    ("lost", lambda sel: sum(len(o.lost) for o in sel)),
)


def table(outcomes: list[Outcome]) -> tuple[str, dict[str, int]]:
    """The per-reader table and the totals (keys: the column headers, plus ``handled``/``tracebacks``)."""
    readers = sorted({o.reader for o in outcomes})
    rows = []
    tot: dict[str, int] = {}
    for r in readers + ["TOTAL"]:
        sel = [o for o in outcomes if r == "TOTAL" or o.reader == r]
        row = {name: int(f(sel)) for name, f in COLUMNS}
        row["handled"] = sum(o.handled for o in sel)
        row["tracebacks"] = row["traceback"]
        if r == "TOTAL":
            tot = row
        rows.append((r, row))
    w = max(len(r) for r, _ in rows)
    head = f"{'reader':<{w}}  " + " ".join(f"{name:>{max(len(name), 5)}}" for name, _ in COLUMNS)
    lines = [head]
    for r, row in rows:
        if r == "TOTAL":
            lines.append("-" * len(head))
        lines.append(f"{r:<{w}}  " + " ".join(f"{row[name]:>{max(len(name), 5)}}" for name, _ in COLUMNS))
    return "\n".join(lines), tot


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    logging.getLogger("hadal").setLevel(logging.ERROR)  # the stages' warnings are expected here
    work = Path(argv[0]) if argv else Path(tempfile.mkdtemp(prefix="hadal-reliability-"))
    outcomes = run_all(all_items(work / "corpus"), work)
    text, tot = table(outcomes)
    bad = [o for o in outcomes if not o.handled or o.traceback or o.lost or o.orphans]
    for o in bad:
        print(f"! {o.name}: {o.detail}{'  lost: ' + ', '.join(o.lost) if o.lost else ''}")
        if o.traceback:
            print(o.traceback)
    print(text)
    print(f"inputs tried {tot['tried']}, handled {tot['handled']} (clean error {tot['clean error']}, flagged "
          f"{tot['flagged']}); goal 0 in each of: tracebacks {tot['traceback']}, silent-wrong {tot['silent-wrong']}, "
          f"wrong error {tot['wrong error']}, hangs {tot['hang']}, over-memory {tot['over-memory']}, "
          f"orphan processes {tot['orphan']}, products lost {tot['lost']}")
    if not argv:
        shutil.rmtree(work, ignore_errors=True)
    return 0 if not bad else 1


if __name__ == "__main__":
    sys.exit(main())
