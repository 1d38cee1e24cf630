"""First run after installing vs the second: CPU of ``hadal run`` on the small sample dive (issue 48).

    .venv/bin/python bench/bench_first_run.py [--repeat 2] [--baseline REV]

A "fresh install" is a copy of ``src/`` (this working tree, and ``--baseline REV``'s exported with ``git archive``,
default ``HEAD``) with its bytecode compiled and an empty numba cache (``NUMBA_CACHE_DIR``, a new temporary folder):
then ``hadal compile`` where the code has it (what ``make setup`` runs; its CPU printed apart), the first
``hadal run`` (cold) and a second one on a new store (warm: every stage runs again, numba loads its cache). The
ratio first/second is the issue's acceptance (<= 1.2); both codes are measured alternately in the same run, so
the ratios are comparable on a shared machine. CPU is every descendant process's user+system time (this process
is a child subreaper: processes orphaned by the run, such as Prefect's server, are reaped here and counted).
``compiled in the 1st run`` counts the kernels numba compiled and saved during the first run (``NUMBA_DEBUG_CACHE``).
Prefect's and matplotlib's home folders are the user's (not fresh).
"""

from __future__ import annotations

import argparse
import ctypes
import os
import resource
import shutil
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PR_SET_CHILD_SUBREAPER = 36


def _children_cpu() -> float:
    u = resource.getrusage(resource.RUSAGE_CHILDREN)
    return u.ru_utime + u.ru_stime


def _reap(timeout_s: float = 30.0) -> None:
    """Wait for the orphans of a run (reparented to this subreaper) so that their CPU is counted."""
    end = time.monotonic() + timeout_s
    while time.monotonic() < end:
        try:
            pid, _ = os.waitpid(-1, os.WNOHANG)
        except ChildProcessError:
            return
        if pid == 0:
            time.sleep(0.1)


def _measure(cmd: list[str], env: dict[str, str]) -> tuple[float, str]:
    """(CPU seconds of the command and all its descendants, stderr+stdout)."""
    before = _children_cpu()
    r = subprocess.run(cmd, env=env, capture_output=True, text=True)
    _reap()
    if r.returncode:
        sys.exit(f"failed ({r.returncode}): {' '.join(cmd)}\n{r.stdout[-2000:]}\n{r.stderr[-4000:]}")
    return _children_cpu() - before, r.stdout + r.stderr


def _export(rev: str, dest: Path) -> Path:
    """``rev``'s src/ exported into ``dest``."""
    tar = dest / "src.tar"
    with open(tar, "wb") as f:
        subprocess.run(["git", "-C", str(REPO), "archive", rev, "src"], stdout=f, check=True)
    with tarfile.open(tar) as t:
        t.extractall(dest, filter="data")
    return dest / "src"


def _install(src: Path, dest: Path) -> Path:
    """A copy of ``src`` without any numba cache, bytecode compiled (as an installer does)."""
    shutil.copytree(src, dest, ignore=shutil.ignore_patterns("*.nbi", "*.nbc", "__pycache__"))
    subprocess.run([sys.executable, "-m", "compileall", "-q", str(dest)], check=True, stdout=subprocess.DEVNULL)
    return dest


def _has_compile(src: Path) -> bool:
    return (src / "hadal" / "numbacompile.py").exists()


def one(label: str, src_orig: Path, dive: Path, work: Path, i: int) -> dict[str, float]:
    base = work / f"{label}-{i}"
    src = _install(src_orig, base / "src")
    cache = base / "numba-cache"
    cache.mkdir()
    env = {**os.environ, "PYTHONPATH": str(src), "NUMBA_CACHE_DIR": str(cache), "HADAL_PROGRESS": "0",
           "PREFECT_SERVER_ANALYTICS_ENABLED": "false"}
    hadal = [sys.executable, "-m", "hadal.cli"]
    out: dict[str, float] = {"compile": 0.0}
    if _has_compile(src):
        out["compile"], _ = _measure([*hadal, "compile"], env)
    out["first"], log = _measure([*hadal, "run", str(dive), "--store", str(base / "store1")],
                                 {**env, "NUMBA_DEBUG_CACHE": "1"})
    out["compiled_first"] = float(log.count("data saved to"))
    out["second"], log = _measure([*hadal, "run", str(dive), "--store", str(base / "store2")],
                                  {**env, "NUMBA_DEBUG_CACHE": "1"})
    out["compiled_second"] = float(log.count("data saved to"))
    shutil.rmtree(base, ignore_errors=True)
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--repeat", type=int, default=2)
    ap.add_argument("--baseline", default="HEAD", help="git revision to compare with ('' : none)")
    a = ap.parse_args()
    ctypes.CDLL(None, use_errno=True).prctl(PR_SET_CHILD_SUBREAPER, 1, 0, 0, 0)
    with tempfile.TemporaryDirectory(prefix="hadal-first-run-") as tmp:
        work = Path(tmp)
        codes = {"this tree": REPO / "src"}
        if a.baseline:
            (work / "baseline").mkdir()
            codes[f"baseline {a.baseline}"] = _export(a.baseline, work / "baseline")
        env = {**os.environ, "PYTHONPATH": str(REPO / "src"), "HADAL_PROGRESS": "0"}
        subprocess.run([sys.executable, "-m", "hadal.cli", "synth", str(work / "dive"), "--small"], env=env,
                       check=True, capture_output=True)
        print(f"small sample dive; {os.cpu_count()} cores, load average {os.getloadavg()[0]:.1f}")
        results: dict[str, list[dict[str, float]]] = {k: [] for k in codes}
        for i in range(a.repeat):
            for label, src in codes.items():  # alternating: both codes see the same machine load
                r = one(label, src, work / "dive", work, i)
                results[label].append(r)
                print(f"  {label:<16} #{i + 1}: compile step {r['compile']:5.1f} CPU-s, first run {r['first']:5.1f}, "
                      f"second {r['second']:5.1f} -> first/second {r['first'] / r['second']:.2f}x "
                      f"(kernels compiled in the 1st run {r['compiled_first']:.0f}, in the 2nd "
                      f"{r['compiled_second']:.0f})", flush=True)
        for label, rs in results.items():
            ratios = sorted(r["first"] / r["second"] for r in rs)
            print(f"{label}: first/second run CPU {', '.join(f'{x:.2f}' for x in ratios)}x "
                  f"(goal <= 1.2; compile step {sum(r['compile'] for r in rs) / len(rs):.1f} CPU-s)")


if __name__ == "__main__":
    main()
