"""Process hygiene of ``hadal run``: kill -9, Ctrl-C and SIGTERM mid-run leave no process behind (the temporary
Prefect server included); an interrupt is one line and exit 130 (143 for SIGTERM); a read-only HOME is one line and
exit 2, no traceback.

``hadal run`` runs in its own session; after the signal every process of that session, and every descendant seen
while it ran (the Prefect server runs in its own process group, still in the session), must be gone.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import psutil
import pytest

HERE = Path(__file__).resolve().parents[2]
HADAL = [sys.executable, "-m", "hadal.cli"]  # the `hadal` command's own entry (hadal.cli.entry)


def _env(**extra: str) -> dict[str, str]:
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(HERE.parent / "src"), str(HERE.parent)]),
           "HADAL_PROGRESS": "0"}
    env.update(extra)
    return env


def _session_procs(sid: int, seen: set[int]) -> list[psutil.Process]:
    out = []
    for p in psutil.process_iter():
        try:
            if (p.pid in seen or os.getsid(p.pid) == sid) and p.status() != psutil.STATUS_ZOMBIE:
                out.append(p)
        except (OSError, psutil.Error):
            continue
    return out


def _start(raw: Path, store: Path, env: dict[str, str]) -> subprocess.Popen:
    return subprocess.Popen([*HADAL, "run", str(raw), "--store", str(store)], start_new_session=True,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)


def _wait_mid_run(proc: subprocess.Popen, store: Path, timeout: float = 240.0) -> set[int]:
    """Wait until a stage is writing into the store (a staging directory or a version exists); the descendants
    of ``proc`` seen meanwhile (the Prefect server among them)."""
    seen: set[int] = set()
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise AssertionError(f"hadal run ended ({proc.returncode}) before mid-run: {proc.stdout.read()[-3000:]}")
        try:
            seen |= {c.pid for c in psutil.Process(proc.pid).children(recursive=True)}
        except psutil.Error:
            pass
        if seen and store.is_dir() and (any(store.glob("*/*/.staging-*")) or any(store.glob("*/*/v001"))):
            return seen
        time.sleep(0.1)
    proc.kill()
    raise AssertionError("hadal run never reached a stage")


def _assert_none_left(sid: int, seen: set[int], timeout: float = 20.0) -> None:
    deadline = time.monotonic() + timeout
    while (left := _session_procs(sid, seen)) and time.monotonic() < deadline:
        time.sleep(0.2)
    names = []
    for p in left:
        try:
            names.append(f"{p.pid}: {' '.join(p.cmdline())[:120]}")
        except psutil.Error:
            continue
    for p in left:  # do not leak them into the rest of the test session
        try:
            p.kill()
        except psutil.Error:
            pass
    assert not names, f"processes left behind: {names}"


@pytest.mark.slow
@pytest.mark.integration  # 27 s a signal here: the integration tier (issue 20: make test <= 5 min)
@pytest.mark.parametrize("how", ["kill9", "ctrl_c", "sigterm"])
def test_signal_mid_run_leaves_no_process(small_dive, tmp_path, how):
    store = tmp_path / "store"
    proc = _start(small_dive, store, _env(PREFECT_HOME=str(tmp_path / "prefect")))
    sid = proc.pid  # start_new_session: hadal leads its session
    try:
        seen = _wait_mid_run(proc, store)
        if how == "kill9":
            proc.send_signal(signal.SIGKILL)
        elif how == "ctrl_c":  # what a terminal does: SIGINT to the whole foreground process group
            os.killpg(sid, signal.SIGINT)
        else:
            proc.send_signal(signal.SIGTERM)
        out, _ = proc.communicate(timeout=60)  # no hang
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    _assert_none_left(sid, seen)
    if how == "kill9":
        assert proc.returncode == -signal.SIGKILL
        return
    assert proc.returncode == (130 if how == "ctrl_c" else 143), out[-3000:]
    assert "Traceback" not in out, out[-3000:]
    lines = [ln for ln in out.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1 and "interrupted" in lines[0], out[-3000:]


def _read_only_dir(tmp_path: Path):
    """A directory nobody (root included) can write: a read-only tmpfs as root, else a mode-0500 directory."""
    d = Path(tempfile.mkdtemp(prefix="hadal-rohome-", dir=tmp_path))
    if os.geteuid() == 0:
        r = subprocess.run(["mount", "-t", "tmpfs", "-o", "ro,size=1m", "tmpfs", str(d)], capture_output=True)
        if r.returncode != 0:
            pytest.skip("root, but cannot mount a read-only tmpfs")
        return d, lambda: subprocess.run(["umount", "-l", str(d)], capture_output=True)
    d.chmod(0o500)
    return d, lambda: d.chmod(0o700)


def test_read_only_home_is_one_line_exit_2(small_dive, tmp_path):
    home, undo = _read_only_dir(tmp_path)
    try:
        env = _env(HOME=str(home))
        env.pop("PREFECT_HOME", None)
        r = subprocess.run([*HADAL, "run", str(small_dive), "--store", str(tmp_path / "store")],
                           capture_output=True, text=True, env=env, timeout=120, start_new_session=True)
    finally:
        undo()
    out = r.stdout + r.stderr
    assert r.returncode == 2, out[-3000:]
    assert "Traceback" not in out, out[-3000:]
    errs = [ln for ln in out.splitlines() if ln.startswith("error:")]
    assert len(errs) == 1 and "PREFECT_HOME" in errs[0] and "not writable" in errs[0], out


def test_unwritable_prefect_home_is_one_line_exit_2(small_dive, tmp_path):
    """PREFECT_HOME set explicitly to a place that cannot be created (under a regular file)."""
    blocker = tmp_path / "file"
    blocker.write_text("x")
    r = subprocess.run([*HADAL, "run", str(small_dive), "--store", str(tmp_path / "store")], capture_output=True,
                       text=True, env=_env(PREFECT_HOME=str(blocker / "prefect")), timeout=120)
    out = r.stdout + r.stderr
    assert r.returncode == 2 and "Traceback" not in out, out[-3000:]
    assert sum(ln.startswith("error:") for ln in out.splitlines()) == 1, out


def test_a_finished_run_exits_at_once_and_leaves_no_process(small_dive, tmp_path):
    """``hadal run`` ends without the interpreter's teardown (:func:`hadal.cli.entry`) but as a normal exit would:
    the flow's thread pool stopped (joining its threads without threading's exit hooks hung here), the temporary
    server and the stage processes stopped, status 0, the closing table printed, nothing left in its session."""
    store = tmp_path / "store"
    proc = subprocess.Popen([*HADAL, "run", str(small_dive), "--store", str(store)], start_new_session=True,
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
                            env=_env(PREFECT_HOME=str(tmp_path / "prefect")))
    try:
        out, _ = proc.communicate(timeout=600)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    assert proc.returncode == 0, out[-3000:]
    assert "report" in out and "published" in out and "Traceback" not in out, out[-3000:]
    assert (store / small_dive.name / "report").is_dir() or any(store.glob("*/report/v001"))
    _assert_none_left(proc.pid, set(), timeout=5.0)
