"""A stage run in its own process (hadal.stage_process): same products as in the caller's thread, log records and
errors come back to the caller's thread, a killed child is a one-line StageError, an orphaned child stops itself."""

from __future__ import annotations

import gzip
import logging
import os
import subprocess
import sys
import textwrap
import threading
import time

import numpy as np
import pytest
import xarray as xr
import yaml

from hadal.errors import InputError, StageError
from hadal.geo import LocalFrame
from hadal.pipeline import make_context, run_stage
from hadal.stage_process import run_stage_in_process

FRAME = LocalFrame(11.33, 142.2)


def _dive(raw, lines: int = 2, n: int = 3000):
    rng = np.random.default_rng(1)
    (raw / "multibeam").mkdir(parents=True)
    for line in range(1, lines + 1):
        x, y = rng.uniform(-1000, 1000, n), rng.uniform(-500 + 400 * line, -100 + 400 * line, n)
        z = 8000 + 0.02 * x + rng.normal(0, 1.0, n)
        lon, lat = FRAME.to_lonlat(x, y)
        with gzip.open(raw / "multibeam" / f"em122_line{line:02d}.xyz.gz", "wt") as fh:
            np.savetxt(fh, np.column_stack([lon, lat, z]), fmt="%.8f %.8f %.3f")
    dive = {"dive_id": "P001", "platform": "test", "launch": {"latitude_deg": 11.33, "longitude_deg": 142.2},
            "map_frame": {"origin_latitude_deg": 11.33, "origin_longitude_deg": 142.2},
            "sources": {"multibeam": [f"multibeam/em122_line{k:02d}.xyz.gz" for k in range(1, lines + 1)]}}
    (raw / "dive.yaml").write_text(yaml.safe_dump(dive))
    return raw


class _Collect(logging.Handler):
    def __init__(self):
        super().__init__(logging.DEBUG)
        self.records: list[logging.LogRecord] = []

    def emit(self, record):
        self.records.append(record)


def test_dtm_in_a_process_publishes_what_the_thread_publishes_and_its_logs_come_back(tmp_path):
    """Oracle: the same stage run in the caller's thread on a second store (the products must be identical), and
    the caller's own thread id/pid on the child's re-emitted records (so Prefect's run logger and the per-thread
    warnings collector of tasks/stage.py see them as the task's)."""
    raw = _dive(tmp_path / "raw")
    collect = _Collect()
    hlog = logging.getLogger("hadal")
    hlog.addHandler(collect)
    old = hlog.level
    hlog.setLevel(logging.INFO)
    try:
        out = run_stage_in_process("dtm", raw_dir=str(raw), store_root=str(tmp_path / "a"),
                                   run_info={"flow_run": "f-1", "task_run": "t-1"}, progress=False)
    finally:
        hlog.removeHandler(collect)
        hlog.setLevel(old)
    ref = run_stage("dtm", make_context(raw, tmp_path / "b"))
    assert set(out) == {"dtm"} and out["dtm"].endswith("dtm/v001")
    with xr.open_dataset(os.path.join(out["dtm"], "dtm.nc")) as a, xr.open_dataset(ref["dtm"].file("dtm.nc")) as b:
        np.testing.assert_array_equal(a["depth_m"].values, b["depth_m"].values)
    import json

    manifest = json.loads(open(os.path.join(out["dtm"], "manifest.json")).read())
    assert manifest["stage_run"]["stage"] == "dtm" and manifest["stage_run"]["task_run"] == "t-1"
    msgs = [r.getMessage() for r in collect.records]
    assert any(m.startswith("stage dtm: start") for m in msgs) and any("published P001/dtm/v001" in m for m in msgs)
    assert all(r.thread == threading.get_ident() and r.process == os.getpid() for r in collect.records)


def test_a_bad_input_in_the_child_is_raised_here_as_the_same_one_line_error(tmp_path):
    """A corrupt multibeam file: InputError in the caller (same class as in a thread, so the flow neither retries
    it nor prints a traceback), its message naming the file."""
    raw = _dive(tmp_path / "raw", lines=1)
    (raw / "multibeam" / "em122_line01.xyz.gz").write_bytes(b"\x1f\x8b\x08\x00garbage")
    with pytest.raises(InputError) as ei:
        run_stage("dtm", make_context(raw, tmp_path / "t"))
    with pytest.raises(InputError) as ep:
        run_stage_in_process("dtm", raw_dir=str(raw), store_root=str(tmp_path / "p"), progress=False)
    assert str(ep.value) == str(ei.value) and "em122_line01" in str(ep.value)
    assert not (tmp_path / "p" / "P001" / "dtm").exists()  # nothing published


def test_a_killed_child_is_a_one_line_stage_error_and_publishes_nothing(tmp_path):
    """SIGKILL (what the kernel's OOM killer sends) while the child imports: StageError naming the signal."""
    psutil = pytest.importorskip("psutil")
    raw = _dive(tmp_path / "raw", lines=1)
    me = psutil.Process()
    killed: list[int] = []
    # an earlier test's stage process may still be exiting (answered children are reaped by a thread): not this one
    before = {k.pid for k in me.children()}

    def killer():
        deadline = time.monotonic() + 30
        while time.monotonic() < deadline and not killed:
            for k in me.children():
                if k.pid not in before and "spawn_main" in " ".join(k.cmdline()):
                    k.kill()
                    killed.append(k.pid)
            time.sleep(0.05)

    t = threading.Thread(target=killer, daemon=True)
    t.start()
    with pytest.raises(StageError, match=r"stage dtm: its process ended without an answer \(killed by signal 9"):
        run_stage_in_process("dtm", raw_dir=str(raw), store_root=str(tmp_path / "s"), progress=False)
    t.join()
    assert killed and not (tmp_path / "s" / "P001" / "dtm").exists()


def test_an_orphaned_child_stops_by_itself(tmp_path):
    """The parent process dies (kill -9 leaves no time to stop children): the child's watchdog sees its parent gone
    and exits within a few seconds instead of computing (and publishing) for nobody."""
    psutil = pytest.importorskip("psutil")
    raw = _dive(tmp_path / "raw", lines=2, n=200_000)  # a DTM of 400 k soundings: longer than the watchdog's tick
    script = textwrap.dedent(f"""
        import os, sys, threading, time, psutil
        from hadal.stage_process import run_stage_in_process
        threading.Thread(target=run_stage_in_process, args=("dtm",),
                         kwargs=dict(raw_dir={str(raw)!r}, store_root={str(tmp_path / "s")!r}, progress=False),
                         daemon=True).start()
        for _ in range(600):
            kids = [k for k in psutil.Process().children() if "spawn_main" in " ".join(k.cmdline())]
            if kids:
                time.sleep(1.5)  # the child is importing/working
                print(kids[0].pid, flush=True)
                os._exit(0)
            time.sleep(0.05)
        os._exit(1)
    """)
    res = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=120)
    assert res.returncode == 0, res.stderr
    pid = int(res.stdout.split()[0])
    deadline = time.monotonic() + 15
    while time.monotonic() < deadline:
        try:
            if psutil.Process(pid).status() in (psutil.STATUS_ZOMBIE, psutil.STATUS_DEAD):
                break
        except psutil.NoSuchProcess:
            break
        time.sleep(0.2)
    else:
        psutil.Process(pid).kill()
        pytest.fail("the orphaned stage process kept running")
    assert not list((tmp_path / "s").glob("P001/dtm/v*/manifest.json"))  # it stopped before publishing


def test_the_child_ignores_a_terminal_ctrl_c_the_parent_decides(tmp_path):
    """Ctrl-C in a terminal sends SIGINT to the whole process group: the child keeps going (the CLI's handler
    stops children with SIGTERM itself), so a library caller that catches it still gets the stage's result.
    The SIGINT is sent once the child logged "stage dtm: start" (inside the stage, past its start-up)."""
    import signal

    psutil = pytest.importorskip("psutil")
    raw = _dive(tmp_path / "raw", lines=2, n=100_000)
    started = threading.Event()

    class _Started(logging.Handler):
        def emit(self, record):
            if record.getMessage().startswith("stage dtm: start"):
                started.set()

    sent: list[int] = []

    def interrupt():
        if started.wait(60):
            for k in psutil.Process().children():
                if "spawn_main" in " ".join(k.cmdline()):
                    os.kill(k.pid, signal.SIGINT)
                    sent.append(k.pid)

    hlog = logging.getLogger("hadal")
    handler, old = _Started(logging.INFO), hlog.level
    hlog.addHandler(handler)
    hlog.setLevel(logging.INFO)
    t = threading.Thread(target=interrupt, daemon=True)
    t.start()
    try:
        out = run_stage_in_process("dtm", raw_dir=str(raw), store_root=str(tmp_path / "s"), progress=False)
    finally:
        hlog.removeHandler(handler)
        hlog.setLevel(old)
    t.join()
    assert sent and out["dtm"].endswith("dtm/v001")
