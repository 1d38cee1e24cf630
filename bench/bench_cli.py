"""CLI start-up benchmark: wall time of the listing commands, as a user runs them (a fresh process each).

    .venv/bin/python bench/bench_cli.py [--repeat 5] [--baseline REV]

For each command it prints the median wall time (subprocess start to exit) of ``--repeat`` runs, its ratio to
``python -c pass`` (the interpreter's own start, measured in the same run) and, with ``--baseline REV``
(default ``HEAD``: the last commit), the same command run from that revision's sources (exported with
``git archive`` into a temporary directory; nothing in the working tree changes), so the speed-up of the lazy
imports is a ratio measured on the same machine at the same time. Goal (issue 19): every listing command
<= 0.5 s. ``hadal config`` is timed warm (its output is cached per code version; the first call after an edit
pays the import of every stage once) and cold (empty cache).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import tarfile
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
GOAL_S = 0.5


def _env(src: Path, cache: Path) -> dict[str, str]:
    return {**os.environ, "PYTHONPATH": os.pathsep.join([str(src / "src"), str(src)]), "HADAL_PROGRESS": "0",
            "HADAL_CACHE_DIR": str(cache), "COLUMNS": "120"}


def _time(cmd: list[str], env: dict[str, str], repeat: int, before=None) -> float:
    out = []
    for _ in range(repeat):
        if before is not None:
            before()
        t0 = time.perf_counter()
        subprocess.run(cmd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=300)
        out.append(time.perf_counter() - t0)
    return statistics.median(out)


def _export(rev: str, dest: Path) -> Path | None:
    """``git archive REV src flows tasks`` unpacked into ``dest`` (read-only for the repository)."""
    tar = dest / "src.tar"
    try:
        with open(tar, "wb") as fh:
            subprocess.run(["git", "-C", str(REPO), "archive", rev, "src", "flows", "tasks", "schemas"], stdout=fh,
                           check=True, stderr=subprocess.DEVNULL)
    except (OSError, subprocess.CalledProcessError):
        return None
    with tarfile.open(tar) as tf:
        tf.extractall(dest / "tree", filter="data")
    # the installed package maps flows/ tasks/ to hadal.flows / hadal.tasks: do the same for the export
    for sub in ("flows", "tasks"):
        link = dest / "tree" / "src" / "hadal" / sub
        if not link.exists() and (dest / "tree" / sub).is_dir():
            link.symlink_to(dest / "tree" / sub)
    return dest / "tree"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeat", type=int, default=5)
    ap.add_argument("--baseline", default="HEAD", help="git revision to compare with ('' to skip)")
    args = ap.parse_args()
    py = sys.executable
    with tempfile.TemporaryDirectory() as tmp_s:
        tmp = Path(tmp_s)
        store = tmp / "store"
        small = tmp / "small.csv"
        small.write_text("time,pressure_dbar\n2018-10-06T23:00:00Z,1.0\n")
        cache = tmp / "cache"
        commands = {
            "--help": ["--help"],
            "--version": ["--version"],
            "(no arguments)": [],
            "products DIVE": ["products", "nodive", "--store", str(store)],
            "config": ["config"],
            "inspect small.csv": ["inspect", str(small)],
            "mistyped option": ["run", "--bogus"],
        }
        base = _export(args.baseline, tmp) if args.baseline else None
        peer = _time([py, "-c", "pass"], os.environ.copy(), args.repeat)
        print(f"python -c pass: {peer:.3f} s (machine load {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores)")
        head = f"{'command':<20s} {'now s':>7s} {'x pass':>7s}" + (f" {args.baseline + ' s':>10s} {'speed-up':>8s}"
                                                                   if base else "") + "  goal <= 0.5 s"
        print(head)
        for label, argv in commands.items():
            env = _env(REPO, cache)
            _time([py, "-m", "hadal.cli", *argv], env, 1)  # warm the page cache (and the config cache)
            now = _time([py, "-m", "hadal.cli", *argv], env, args.repeat)
            line = f"{label:<20s} {now:7.3f} {now / peer:7.1f}"
            if base is not None:
                old = _time([py, "-m", "hadal.cli", *argv], _env(base, tmp / "cache-old"), args.repeat)
                line += f" {old:10.3f} {old / now:8.1f}"
            print(line + ("  ok" if now <= GOAL_S else "  SLOW"))

        # what every run and cache-hit stage pays before Prefect's own start (issue 19): every stage's Params
        # (hadal.settings) and the flow/tasks; the science (pandas, xarray, numba, ioos_qc, ...) must stay unimported
        imports = {
            "import all stages": "import hadal.settings, hadal.pipeline; hadal.pipeline.all_products()",
            "import flow+tasks": "import hadal.flows.post_cruise, hadal.tasks.ingest, hadal.tasks.report",
        }
        probe = ("; import sys; bad = [m for m in ('pandas', 'xarray', 'numba', 'ioos_qc', 'scipy', 'open3d', "
                 "'matplotlib', 'gsw', 'pyarrow') if m in sys.modules]; sys.exit(f'science imported: {bad}' if bad "
                 "else 0)")
        for label, code in imports.items():
            env = _env(REPO, cache)
            check = subprocess.run([py, "-c", code + probe], env=env, capture_output=True, text=True)
            now = _time([py, "-c", code], env, args.repeat)
            line = f"{label:<20s} {now:7.3f} {now / peer:7.1f}"
            if base is not None:
                old = _time([py, "-c", code], _env(base, tmp / "cache-old"), args.repeat)
                line += f" {old:10.3f} {old / now:8.1f}"
            print(line + ("  no science imported" if check.returncode == 0 else f"  {check.stderr.strip()[-120:]}"))

        def _clear() -> None:
            for f in cache.glob("*"):
                f.unlink()

        cold = _time([py, "-m", "hadal.cli", "config"], _env(REPO, cache), max(1, args.repeat // 2), before=_clear)
        print(f"{'config (cold cache)':<20s} {cold:7.3f} {cold / peer:7.1f}   (first call after an edit of hadal)")


if __name__ == "__main__":
    main()
