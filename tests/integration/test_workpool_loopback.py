"""The work-pool deployment of docs/operations.md, end to end on loopback: a real ``prefect server start``, a
process work pool (``prefect work-pool create``), the cruise flow deployed on an interval schedule
(``prefect deploy flows/serve.py:post_cruise_new_dives``) and ``prefect worker start``: the worker picks up the
scheduled runs, the first processes the dive present, and a dive dropped into the cruise directory afterwards is
processed by a later scheduled run while the first dive is a cache hit (no new version).

Integration tier (``-m integration``, also ``slow``): ~1-3 min on a busy 2-core machine. Every child process (server,
worker, the worker's flow-run processes) is stopped at the end, whatever happens.
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from factories import publish_fake_products, write_fake_dive

from hadal.pipeline import code_digest
from hadal.store import ProductStore

REPO = Path(__file__).resolve().parents[2]
PREFECT = str(Path(sys.executable).with_name("prefect"))
POOL = "hadal-loopback"

pytestmark = [pytest.mark.integration, pytest.mark.slow]


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _stop(procs: list[subprocess.Popen]) -> None:
    """Terminate every process in ``procs`` and all their descendants (the worker's flow-run processes, the
    server's uvicorn), then kill what is left after 15 s."""
    import psutil

    tree: list[psutil.Process] = []
    for p in procs:
        try:
            root = psutil.Process(p.pid)
            tree += [*root.children(recursive=True), root]
        except psutil.Error:
            pass
    for p in tree:
        try:
            p.terminate()
        except psutil.Error:
            pass
    _gone, alive = psutil.wait_procs(tree, timeout=15)
    for p in alive:
        try:
            p.kill()
        except psutil.Error:
            pass
    psutil.wait_procs(alive, timeout=5)
    for p in procs:  # reap (no zombies), close the pipes
        try:
            p.wait(timeout=5)
        except subprocess.TimeoutExpired:
            pass


def _versions(store: Path, dive: str) -> list[str]:
    st = ProductStore(store)
    return [v.label for v in st.versions(dive, "report")] if st.has(dive, "report") else []


def test_worker_runs_scheduled_deployment_and_picks_up_a_new_dive(tmp_path):
    import httpx

    port = _free_port()
    api = f"http://127.0.0.1:{port}/api"
    env = {**os.environ, "PREFECT_HOME": str(tmp_path / "prefect-home"), "PREFECT_API_URL": api,
           "PREFECT_SERVER_ANALYTICS_ENABLED": "false", "PREFECT_SERVER_UI_ENABLED": "false",
           "PREFECT_SERVER_SERVICES_SCHEDULER_LOOP_SECONDS": "2", "PREFECT_WORKER_QUERY_SECONDS": "2",
           "PREFECT_LOGGING_LEVEL": "WARNING", "HADAL_PROGRESS": "0", "MPLBACKEND": "Agg",
           "PYTHONPATH": os.pathsep.join([str(REPO / "src"), str(REPO)])}
    server_env = {k: v for k, v in env.items() if k != "PREFECT_API_URL"}
    procs: list[subprocess.Popen] = []
    handles: list = []
    logs = tmp_path / "logs"
    logs.mkdir()

    def start(name: str, argv: list[str], **kw) -> subprocess.Popen:
        out = open(logs / f"{name}.log", "wb")  # noqa: SIM115 - closed after the process, at the end
        handles.append(out)
        p = subprocess.Popen(argv, stdout=out, stderr=subprocess.STDOUT, **kw)
        procs.append(p)
        return p

    def tail(name: str) -> str:
        return (logs / f"{name}.log").read_text(errors="replace")[-2000:]

    def prefect_cli(*argv: str) -> None:
        res = subprocess.run([PREFECT, "--no-prompt", *argv], env=env, cwd=REPO, capture_output=True, text=True,
                             timeout=180)
        assert res.returncode == 0, f"prefect {' '.join(argv[:2])}: {res.stdout[-1500:]}{res.stderr[-1500:]}"

    def runs(dep_id: str, state: str) -> list[dict]:
        r = httpx.post(f"{api}/flow_runs/filter", json={"deployments": {"id": {"any_": [dep_id]}},
                                                       "flow_runs": {"state": {"type": {"any_": [state]}}}},
                       timeout=10)
        r.raise_for_status()
        return r.json()

    code0 = code_digest.__wrapped__()  # part of every cache key
    cruise, store = tmp_path / "cruise", tmp_path / "store"
    st = ProductStore(store)
    publish_fake_products(st, "dive-a", products=("ctd",))
    write_fake_dive(cruise / "dive-a", "dive-a")
    try:
        server = start("server", [PREFECT, "server", "start", "--host", "127.0.0.1", "--port", str(port), "--no-ui"],
                       env=server_env, cwd=tmp_path)
        deadline = time.monotonic() + 120
        while True:
            try:
                if httpx.get(f"{api}/health", timeout=2).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            assert server.poll() is None, tail("server")
            assert time.monotonic() < deadline, "prefect server did not start: " + tail("server")
            time.sleep(0.5)

        # the documented commands (docs/operations.md), an interval instead of a cron so that the test need not
        # wait for a minute boundary
        written = [f for f in ("prefect.yaml", ".prefectignore") if not (REPO / f).exists()]
        prefect_cli("work-pool", "create", POOL, "--type", "process")
        params = {"cruise_dir": str(cruise), "store_root": str(store), "stages": ["report"]}
        prefect_cli("deploy", "flows/serve.py:post_cruise_new_dives", "--name", "cruise", "--pool", POOL,
                    "--interval", "5", "--params", json.dumps(params))
        for f in written:  # `prefect deploy` without a terminal writes nothing into the checkout
            if (REPO / f).exists():
                (REPO / f).unlink()
                pytest.fail(f"prefect deploy wrote {REPO / f}")
        r = httpx.post(f"{api}/deployments/filter", json={"deployments": {"name": {"any_": ["cruise"]}}}, timeout=10)
        r.raise_for_status()
        (dep,) = r.json()
        assert dep["work_pool_name"] == POOL and dep["schedules"][0]["schedule"]["interval"] == 5.0
        worker = start("worker", [PREFECT, "worker", "start", "--pool", POOL, "--limit", "1"], env=env, cwd=REPO)

        deadline = time.monotonic() + 240
        while not _versions(store, "dive-a"):  # the first scheduled run processes the dive present
            assert worker.poll() is None, tail("worker")
            assert not runs(dep["id"], "FAILED"), tail("worker")
            assert time.monotonic() < deadline, "no scheduled run processed dive-a: " + tail("worker")
            time.sleep(1)
        t_drop = time.monotonic()
        publish_fake_products(st, "dive-b", products=("ctd",))  # a new dive dropped into the cruise directory
        write_fake_dive(cruise / "dive-b", "dive-b")
        deadline = time.monotonic() + 240
        while not _versions(store, "dive-b"):
            assert worker.poll() is None, tail("worker")
            assert not runs(dep["id"], "FAILED"), tail("worker")
            assert time.monotonic() < deadline, "no scheduled run processed the new dive: " + tail("worker")
            time.sleep(1)
        assert time.monotonic() > t_drop
        done = runs(dep["id"], "COMPLETED")
        deadline = time.monotonic() + 120
        while len(done) < 2:  # the run that processed dive-b is a second, completed scheduled run
            assert time.monotonic() < deadline, "the runs did not complete: " + tail("worker")
            time.sleep(1)
            done = runs(dep["id"], "COMPLETED")
        assert all(r["deployment_id"] == dep["id"] and r["work_pool_name"] == POOL for r in done)
        assert _versions(store, "dive-b") == ["v001"]
        if code_digest.__wrapped__() == code0:  # (hadal's code edited meanwhile: every stage re-runs, rightly)
            assert _versions(store, "dive-a") == ["v001"]  # unchanged: a cache hit in the later runs
    finally:
        _stop(procs)
        for h in handles:
            h.close()
