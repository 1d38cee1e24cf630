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


def test_a_stage_process_started_ahead_runs_the_job_and_an_unused_one_exits_with_the_parent(tmp_path):
    """``prestart`` (what the CLI does while Prefect's server boots): the dtm job goes to the process started ahead
    (it then exits, the pool no longer holds it) and publishes what the stage publishes in a thread (oracle: the
    thread run on a second store); the laser process started ahead and never used exits when its parent does,
    without delaying the parent's exit."""
    psutil = pytest.importorskip("psutil")
    raw = _dive(tmp_path / "raw")
    script = textwrap.dedent(f"""
        import os, sys
        from hadal import stage_process as sp
        assert sp.prestart(["dtm", "laser"]) == ["dtm", "laser"] and sp.prestart(["dtm"]) == []
        warm_dtm = sp._WARM["dtm"].proc
        out = sp.run_stage_in_process("dtm", raw_dir={str(raw)!r}, store_root={str(tmp_path / "a")!r}, progress=False)
        import time
        deadline = time.monotonic() + 30  # reaped by run_stage_in_process's thread (its join and ours would race)
        while warm_dtm.is_alive() and time.monotonic() < deadline:
            time.sleep(0.05)
        assert "dtm" not in sp._WARM and warm_dtm.exitcode == 0, warm_dtm.exitcode
        print(out["dtm"])
        print(sp._WARM["laser"].proc.pid, flush=True)
    """)
    t0 = time.monotonic()
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=180)
    assert r.returncode == 0, r.stderr[-2000:]
    exited_after = time.monotonic() - t0
    version_dir, laser_pid = r.stdout.split()
    ref = run_stage("dtm", make_context(raw, tmp_path / "b"))
    with xr.open_dataset(os.path.join(version_dir, "dtm.nc")) as a, xr.open_dataset(ref["dtm"].file("dtm.nc")) as b:
        np.testing.assert_array_equal(a["depth_m"].values, b["depth_m"].values)
    deadline = time.monotonic() + 10
    while psutil.pid_exists(int(laser_pid)) and time.monotonic() < deadline:
        time.sleep(0.1)
    gone = not psutil.pid_exists(int(laser_pid)) or psutil.Process(int(laser_pid)).status() == psutil.STATUS_ZOMBIE
    assert gone and exited_after < 120


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="stage processes are forked ahead on Linux only")
def test_stage_processes_forked_ahead_run_the_job_and_an_unused_one_stops_at_once(tmp_path):
    """``prestart(fork=True)`` (what the CLI does just before the flow starts, the main thread alone): the processes
    are forked (they inherit the modules imported here), the dtm job publishes what the stage publishes in a thread
    (oracle: the thread run on a second store), and the laser process never used stops as soon as it is told (EOF on
    its job pipe reaches it: the fork's copy of the parent's end is closed in the child), not after the 5 s timeout.
    Beside another thread nothing is forked (spawned instead)."""
    raw = _dive(tmp_path / "raw")
    script = textwrap.dedent(f"""
        import threading, time
        from hadal import stage_process as sp
        assert sp.prestart(["dtm", "laser"], fork=True) == ["dtm", "laser"]
        methods = {{n: w.proc._popen.method for n, w in sp._WARM.items()}}
        out = sp.run_stage_in_process("dtm", raw_dir={str(raw)!r}, store_root={str(tmp_path / "a")!r}, progress=False)
        laser = sp._WARM["laser"].proc
        t0 = time.monotonic()
        sp._stop_warm()
        stop_s = time.monotonic() - t0
        ev = threading.Event()
        t = threading.Thread(target=ev.wait)
        t.start()
        beside = sp.prestart(["laser"], fork=True)
        method_beside = sp._WARM["laser"].proc._popen.method
        ev.set()
        t.join()
        sp._stop_warm()
        print(out["dtm"], methods["dtm"], methods["laser"], laser.exitcode, round(stop_s, 2), method_beside)
    """)
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=180)
    assert r.returncode == 0, r.stderr[-2000:]
    version_dir, m_dtm, m_laser, laser_exit, stop_s, m_beside = r.stdout.split()
    assert (m_dtm, m_laser, m_beside) == ("fork", "fork", "spawn")
    assert laser_exit == "0" and float(stop_s) < 4.0
    ref = run_stage("dtm", make_context(raw, tmp_path / "b"))
    with xr.open_dataset(os.path.join(version_dir, "dtm.nc")) as a, xr.open_dataset(ref["dtm"].file("dtm.nc")) as b:
        np.testing.assert_array_equal(a["depth_m"].values, b["depth_m"].values)


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="stage processes are forked ahead on Linux only")
def test_no_fork_ahead_once_a_parallel_kernel_ran_here():
    """After a numba parallel kernel ran in this process its OpenMP pool would hang a forked child's own parallel
    kernel: the stage processes are then spawned, not forked."""
    script = textwrap.dedent("""
        from numba import njit, prange
        from hadal import stage_process as sp
        before = sp.can_fork_ahead()
        @njit(parallel=True)
        def total(n):
            s = 0
            for i in prange(n):
                s += i
            return s
        assert total(1000) == 499500
        print(before, sp.can_fork_ahead())
    """)
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=180)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.split() == ["True", "False"]


def test_warm_imports_stop_when_told_and_every_declared_module_imports():
    """``warm_imports`` imports a stage's ``WARM_IMPORTS`` in order and stops as soon as ``stop()`` says so (the CLI:
    once the server answers); every module a stage declares exists (a renamed module would silently warm nothing)."""
    import importlib

    from hadal.childproc import warm
    from hadal.pipeline import warm_imports
    from hadal.stages import STAGE_ORDER
    from hadal.stages.graph import stage

    assert warm_imports(["ingest", "derive"], stop=lambda: True) == []
    calls = []

    def stop_after_two():
        calls.append(1)
        return len(calls) > 2

    assert warm_imports(["derive"], stop=stop_after_two) == list(stage("derive").warm_imports[:2])
    for name in STAGE_ORDER:
        mods = stage(name).warm_imports
        assert mods, f"stage {name} declares no WARM_IMPORTS"
        for m in mods:
            mod, _, func = m.partition(":")
            module = importlib.import_module(mod)
            assert not func or callable(getattr(module, func, None)), f"{name}: {m} names no function"
            assert warm(m), m


def test_numba_first_call_starts_no_parallel_region():
    """The stages' ``hadal.numbawarm:first_call`` entry (run in the process that then forks the stage processes)
    initialises numba without starting its thread pool, which would forbid those forks (can_fork_ahead)."""
    import subprocess
    import sys

    code = ("import sys\nfrom hadal.childproc import warm\n"
            "assert warm('hadal.numbawarm:first_call')\n"
            "par = sys.modules.get('numba.np.ufunc.parallel')\n"
            "from hadal.stage_process import can_fork_ahead\n"
            "print('numba' in sys.modules, getattr(par, '_is_initialized', False), can_fork_ahead())\n")
    r = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert r.stdout.split() == ["True", "False", "True"]
