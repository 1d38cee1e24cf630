"""A really full disk: the small sample dive run (``make_context`` + ``run_pipeline``) into a store on a small tmpfs.

Root only (``mount -t tmpfs``); skipped otherwise. Each case fills the file system to a different level so the disk
runs out in a different stage (ingest, derive, grid, match, landing/report), with and without the free-space
pre-check (without it, ``os.write`` itself hits ENOSPC). Every case must end with one-line ``StoreError`` messages,
no traceback, no crash (the run is a subprocess: a segfault would show as its exit status), no ``.staging-*``
left behind, and only intact published versions.
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import textwrap
from pathlib import Path

import pytest

from hadal.store import ProductStore

HERE = Path(__file__).resolve().parents[1]

WORKER = textwrap.dedent("""
    import sys, warnings
    warnings.simplefilter("ignore")
    import hadal.store
    if sys.argv[3] == "nocheck":  # no pre-check: the write itself must meet ENOSPC and report it
        hadal.store.free_bytes = lambda path: None
    from hadal.errors import HadalError
    from hadal.pipeline import make_context, run_pipeline
    ctx = make_context(sys.argv[1], sys.argv[2])
    try:
        run_pipeline(ctx)
    except HadalError as exc:
        print("ERROR", exc)
        sys.exit(2)
    print("OK")
""")


def _can_mount() -> bool:
    return hasattr(os, "geteuid") and os.geteuid() == 0 and sys.platform.startswith("linux")


@pytest.fixture
def tmpfs():
    """A factory mounting a tmpfs of ``size_mb`` (unmounted again, whatever happens)."""
    if not _can_mount():
        pytest.skip("mounting a tmpfs needs root on Linux")
    mounted: list[Path] = []

    def make(size_mb: int) -> Path:
        d = Path(tempfile.mkdtemp(prefix="hadal-tmpfs-"))
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", f"size={size_mb}m", "tmpfs", str(d)],
                           capture_output=True, text=True)
        if r.returncode != 0:
            d.rmdir()
            pytest.skip(f"cannot mount a tmpfs here: {r.stderr.strip()}")
        mounted.append(d)
        return d

    try:
        yield make
    finally:
        for d in mounted:
            subprocess.run(["umount", "-l", str(d)], capture_output=True)
            try:
                d.rmdir()
            except OSError:
                pass


def _fill(root: Path, leave_mb: float) -> None:
    """Fill the file system of ``root`` until ``leave_mb`` MiB are free."""
    st = os.statvfs(root)
    free = st.f_bavail * st.f_frsize
    n = int(free - leave_mb * 2**20)
    if n > 0:
        with open(root / "filler.bin", "wb") as fh:
            chunk = b"\0" * (1 << 20)
            while n > 0:
                n -= fh.write(chunk[: min(n, len(chunk))])


# (tmpfs MiB, MiB left free before the run, pre-check on?) - the small dive's products: sensors 4 MiB, ctd 9, dtm 34,
# match 14, landing/laser/report 1-3: the disk fills in ingest, derive, grid, match and in the last stages
LEVELS = {
    "ingest": (30, 3, True),
    "derive": (30, 10, True),
    "derive-nocheck": (30, 12, False),
    "grid": (30, None, True),
    "grid-nocheck": (30, None, False),
    "match": (62, None, True),
    "late-nocheck": (65, None, False),
}


@pytest.mark.slow
@pytest.mark.integration  # 24 s a level here: the integration tier (issue 20: make test <= 5 min)
@pytest.mark.parametrize("level", list(LEVELS))
def test_full_disk_is_a_one_line_error_and_leaves_no_staging(small_dive, tmpfs, level):
    size_mb, leave_mb, check = LEVELS[level]
    root = tmpfs(size_mb)
    if leave_mb is not None:
        _fill(root, leave_mb)
    store = root / "store"
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(HERE.parent / "src"), str(HERE.parent)]),
           "HADAL_PROGRESS": "0"}
    r = subprocess.run([sys.executable, "-c", WORKER, str(small_dive), str(store), "check" if check else "nocheck"],
                       capture_output=True, text=True, env=env, timeout=600)
    out = r.stdout + r.stderr
    assert r.returncode in (0, 2), f"exit {r.returncode} (crash?):\n{out[-3000:]}"
    assert "Traceback" not in out and "Exception ignored" not in out, out[-3000:]
    assert not list(store.rglob(".staging-*")), list(store.rglob(".staging-*"))
    if r.returncode == 2:
        err = [ln for ln in r.stdout.splitlines() if ln.startswith("ERROR")]
        assert len(err) == 1 and "No space left on device" in err[0] and "nothing was published" in err[0], out
    st = ProductStore(store)
    for dive in st.dives():
        for product in st.products(dive):
            for pv in st.versions(dive, product):
                assert st.verify(pv) == [], (pv.path, st.verify(pv))
