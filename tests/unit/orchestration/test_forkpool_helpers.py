"""hadal.forkpool helpers: processes forked ahead that draw for a flow's task threads. Calls a helper runs give what
a plain loop gives, in order; failures (an exception, an unpicklable call, a helper killed) behave as a plain loop.

Each case runs in a fresh interpreter (the helpers are forked only while the main thread is the process's only
thread, which a pytest session with other fixtures' threads cannot promise)."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap

import pytest

from hadal.forkpool import can_fork

pytestmark = pytest.mark.skipif(not can_fork(), reason="helpers are forked on Linux only")

PRELUDE = textwrap.dedent("""
    import json, os, signal, threading, time
    import numpy as np
    from hadal import forkpool

    def pid_and_square(x):
        return os.getpid(), x * x

    def pid_and_sum(a, k):
        return os.getpid(), float(a.sum()) * k

    def slow(x):
        time.sleep(0.2)
        return os.getpid(), x

    def boom(x):
        raise ValueError(f"bad item {x}")

    def die_in_helper(parent):
        if os.getpid() != parent:
            os.kill(os.getpid(), signal.SIGKILL)
        return os.getpid()

    def in_thread(fn):
        out = {}
        def run():
            try:
                out["value"] = fn()
            except BaseException as exc:
                out["error"] = f"{type(exc).__name__}: {exc}"
        t = threading.Thread(target=run)
        t.start()
        t.join()
        return out
""")


def _run(body: str) -> dict:
    res = subprocess.run([sys.executable, "-c", PRELUDE + textwrap.dedent(body)], capture_output=True, text=True,
                         timeout=120)
    assert res.returncode == 0, res.stderr[-3000:]
    return json.loads(res.stdout.strip().splitlines()[-1])


def test_calls_from_a_task_thread_run_in_a_helper_and_equal_a_plain_loop():
    out = _run("""
        started = forkpool.start_helpers(1)
        def work():
            with forkpool.ForkPool(2) as pool:
                for x in range(12):
                    pool.submit(slow, x)
                return pool.results()
        res = in_thread(work)["value"]
        forkpool.stop_helpers()
        print(json.dumps({"started": started, "values": [v for _, v in res],
                          "pids": sorted({p for p, _ in res}), "me": os.getpid()}))
    """)
    assert out["started"] is True
    assert out["values"] == list(range(12))  # the plain loop's results, in submission order
    assert len(out["pids"]) == 2 and out["me"] in out["pids"]  # the thread and the helper both drew


def test_without_helpers_a_task_thread_runs_every_call_itself():
    out = _run("""
        def work():
            with forkpool.ForkPool(2) as pool:
                for x in range(4):
                    pool.submit(pid_and_square, x)
                return pool.results(), forkpool.default_workers()
        res, workers = in_thread(work)["value"]
        print(json.dumps({"pids": sorted({p for p, _ in res}), "values": [v for _, v in res], "me": os.getpid(),
                          "workers": workers}))
    """)
    assert out["pids"] == [out["me"]] and out["values"] == [0, 1, 4, 9] and out["workers"] == 1


def test_a_shared_argument_travels_once_and_gives_the_plain_result():
    out = _run("""
        import pickle
        forkpool.start_helpers(1)
        a = np.arange(2_000_000, dtype=np.float64)
        def work():
            with forkpool.ForkPool(2) as pool:
                sh = pool.share(a)
                call_bytes = len(pickle.dumps((pid_and_sum, (sh, 3))))
                for k in range(6):
                    pool.submit(pid_and_sum, sh, k)
                return pool.results(), call_bytes
        res, call_bytes = in_thread(work)["value"]
        forkpool.stop_helpers()
        print(json.dumps({"values": [v for _, v in res], "call_bytes": call_bytes, "array_bytes": a.nbytes,
                          "pids": sorted({p for p, _ in res}), "me": os.getpid()}))
    """)
    total = float(sum(range(2_000_000)))
    assert out["values"] == [total * k for k in range(6)]
    assert out["call_bytes"] < 1000 < out["array_bytes"]  # a call carries the token, not the 16 MB array
    assert len(out["pids"]) == 2


def test_an_error_in_a_helper_is_raised_here_with_its_type():
    out = _run("""
        forkpool.start_helpers(1)
        def work():
            with forkpool.ForkPool(2) as pool:
                pool.submit(boom, 1)
                pool.submit(pid_and_square, 2)
                return pool.results()
        res = in_thread(work)
        forkpool.stop_helpers()
        print(json.dumps(res))
    """)
    assert out == {"error": "ValueError: bad item 1"}


def test_a_helper_killed_during_a_call_has_the_call_rerun_here_and_the_pool_goes_on():
    out = _run("""
        forkpool.start_helpers(1)
        me = os.getpid()
        def work():
            with forkpool.ForkPool(2) as pool:
                pool.submit(die_in_helper, me)
                for x in range(3):
                    pool.submit(pid_and_square, x)
                return pool.results()
        res = in_thread(work)["value"]
        running = forkpool.helpers_running()
        forkpool.stop_helpers()
        print(json.dumps({"first": res[0], "rest": [v for _, v in res[1:]], "me": me}))
    """)
    assert out["first"] == out["me"]  # re-run here after the helper died without an answer
    assert out["rest"] == [0, 1, 4]


def test_an_unpicklable_call_runs_here():
    out = _run("""
        forkpool.start_helpers(1)
        def work():
            with forkpool.ForkPool(2) as pool:
                pool.submit(lambda: os.getpid())
                return pool.results()
        res = in_thread(work)["value"]
        forkpool.stop_helpers()
        print(json.dumps({"pid": res[0], "me": os.getpid()}))
    """)
    assert out["pid"] == out["me"]


def test_helpers_are_not_forked_beside_other_threads_and_stop_promptly():
    out = _run("""
        ev = threading.Event()
        t = threading.Thread(target=ev.wait)
        t.start()
        refused = forkpool.start_helpers(1)  # another thread runs: a fork could copy a lock it holds
        ev.set()
        t.join()
        started = forkpool.start_helpers(1)
        procs = [h.proc for h in forkpool._HELPERS[0].all]
        t0 = time.monotonic()
        forkpool.stop_helpers()
        print(json.dumps({"refused": refused, "started": started, "alive": any(p.is_alive() for p in procs),
                          "stop_s": time.monotonic() - t0, "running": forkpool.helpers_running()}))
    """)
    assert out["refused"] is False and out["started"] is True
    assert not out["alive"] and not out["running"]
    assert out["stop_s"] < 4.0  # EOF reaches the helper at once (not the 5 s kill)


def test_calls_do_not_pile_up_behind_a_helper_busy_with_another_pool():
    """A pool whose helper is busy (another thread's pool holds it) runs its calls here at once, as a plain loop
    would, instead of queueing them (and their arguments) behind the helper."""
    out = _run("""
        forkpool.start_helpers(1)
        started = threading.Event()
        def long_pool():
            with forkpool.ForkPool(2) as pool:
                pool.submit(time.sleep, 2.0)  # the helper's only call: it holds the helper for 2 s
                started.set()
                return pool.results()
        def quick_pool():
            started.wait()
            t0 = time.monotonic()
            with forkpool.ForkPool(2) as pool:
                for x in range(3):
                    pool.submit(pid_and_square, x)
                res = pool.results()
            return res, time.monotonic() - t0
        box = {}
        t = threading.Thread(target=lambda: box.update(long=long_pool()))
        t.start()
        res, quick_s = in_thread(quick_pool)["value"]
        t.join()
        forkpool.stop_helpers()
        print(json.dumps({"pids": sorted({p for p, _ in res}), "values": [v for _, v in res], "me": os.getpid(),
                          "quick_s": quick_s}))
    """)
    assert out["pids"] == [out["me"]] and out["values"] == [0, 1, 4]
    assert out["quick_s"] < 1.5  # not held up behind the helper's 2 s call


def test_a_stage_process_started_ahead_still_gets_eof_when_helpers_were_forked_after_it():
    """The stage processes' job pipe ends reach the helpers through hadal.childproc (the helpers import no
    orchestration): a helper forked after them closes its copies, so the parent closing a job pipe is EOF for the
    stage process, which then exits by itself (exit code 0) instead of waiting for a job forever."""
    out = _run("""
        from hadal import childproc, stage_process as sp
        assert sp.prestart(["dtm"], fork=True) == ["dtm"]
        job_end = sp._WARM["dtm"].conn.fileno()
        registered = job_end in childproc.inherited_ends()
        started = forkpool.start_helpers(1)
        w = sp._WARM.pop("dtm")
        w.conn.close()  # EOF, unless a helper still holds a copy of this end
        w.proc.join(timeout=90)  # its warm imports first (seconds on a loaded machine), then the EOF
        exitcode = w.proc.exitcode
        if exitcode is None:
            w.proc.kill()
        forkpool.stop_helpers()
        print(json.dumps({"registered": registered, "started": started, "exitcode": exitcode}))
    """)
    assert out["registered"] and out["started"]
    assert out["exitcode"] == 0  # it returned on EOF by itself (None: it never saw EOF and was killed)
