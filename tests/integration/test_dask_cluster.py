"""A cruise on a real Dask cluster (issue 48), integration tier: a ``dask scheduler`` and ``dask worker`` processes
started on 127.0.0.1 (free ports); the Dask batch of dives and the cruise-DTM flow run against it, and a worker
killed (SIGKILL) mid-run: the run completes on the remaining worker, every product complete and verified.
Oracle for the cruise DTM: the in-memory grid of all the soundings (tests/unit/grid/test_cruise_dtm.py)."""

from __future__ import annotations

import os
import signal
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from test_cruise_dtm import assert_same_dtm, make_cruise, oracle_dtm

REPO = Path(__file__).resolve().parents[2]
if str(REPO) not in sys.path:  # flows/ lives at the repository root
    sys.path.insert(0, str(REPO))

pytestmark = pytest.mark.integration


def _cruise_flow():
    try:
        from hadal.flows.cruise import cruise_dtm
    except ImportError:  # a checkout whose installed hadal.flows is another tree's (worktrees)
        from flows.cruise import cruise_dtm
    return cruise_dtm


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _env() -> dict[str, str]:
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO / "src"), str(REPO), env.get("PYTHONPATH", "")])
    env["DASK_DISTRIBUTED__WORKER__DAEMON"] = "False"
    return env


class LoopbackCluster:
    """``dask scheduler`` + ``n`` ``dask worker --no-nanny`` processes on 127.0.0.1 (no nanny: a killed worker stays
    dead, as a lost machine)."""

    def __init__(self, tmp: Path, n_workers: int) -> None:
        dask = str(Path(sys.executable).parent / "dask")
        port = _free_port()
        self.address = f"tcp://127.0.0.1:{port}"
        self.logs = tmp / "dask-logs"
        self.logs.mkdir(exist_ok=True)
        env = _env()
        self.scheduler = subprocess.Popen(
            [dask, "scheduler", "--host", "127.0.0.1", "--port", str(port), "--dashboard-address", ":0",
             "--no-show"], stdout=subprocess.DEVNULL, stderr=open(self.logs / "scheduler.log", "w"), env=env)
        self.workers = []
        for k in range(n_workers):
            self.workers.append(subprocess.Popen(
                [dask, "worker", self.address, "--nthreads", "1", "--no-nanny", "--host", "127.0.0.1",
                 "--dashboard-address", ":0", "--name", f"w{k}", "--local-directory", str(tmp / f"w{k}")],
                stdout=subprocess.DEVNULL, stderr=open(self.logs / f"worker{k}.log", "w"), env=env))
        from distributed import Client

        with Client(self.address, timeout=60) as c:
            c.wait_for_workers(n_workers, timeout=90)

    def close(self) -> None:
        for p in [*self.workers, self.scheduler]:
            if p.poll() is None:
                p.terminate()
        for p in [*self.workers, self.scheduler]:
            try:
                p.wait(timeout=5)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


@pytest.fixture
def loopback(tmp_path):
    clusters: list[LoopbackCluster] = []

    def start(n: int) -> LoopbackCluster:
        clusters.append(LoopbackCluster(tmp_path, n))
        return clusters[-1]

    yield start
    for c in clusters:
        c.close()


def _read_nc(path: Path):
    import xarray as xr

    with xr.open_dataset(path) as ds:
        return ds.load()


def _check_product(store: Path, cruise_id: str, raws: list[Path], res: float) -> None:
    from hadal.store import ProductStore

    st = ProductStore(store)
    pv = st.latest(cruise_id, "cruise_dtm")
    assert st.verify(pv) == []
    ds = _read_nc(pv.file("cruise_dtm.nc"))
    ref, _ = oracle_dtm(raws, res)
    for v in ("depth_m", "depth_median_m", "depth_std_m", "uncertainty_m"):  # the product's storage type (float32)
        assert ds[v].dtype == np.float32
        ref[v] = ref[v].astype(np.float32)
    assert_same_dtm(ds, ref)
    prov = pv.manifest()["provenance"]
    assert sorted(prov["dives"]) == [f"D{k:03d}" for k in range(len(raws))]


def test_batch_and_cruise_on_loopback_scheduler(tmp_path, prefect_harness, loopback):
    """The Dask batch of dives (``run_batch``, stage dtm) and the cruise flow on a ``dask scheduler`` + 2
    ``dask worker`` processes."""
    from hadal.flows.batch import run_batch

    from hadal.store import ProductStore

    cl = loopback(2)
    raws = make_cruise(tmp_path / "raw", n=4000)
    store = tmp_path / "store"
    out = run_batch([str(r) for r in raws], str(store), None, ["dtm"], scheduler=cl.address)
    st = ProductStore(store)
    for k, r in enumerate(raws):
        assert out[str(r)]["ok"], out[str(r)]
        pv = st.latest(f"D{k:03d}", "dtm")
        assert st.verify(pv) == []
    res = _cruise_flow()([str(r) for r in raws], str(store), "CRUISE-1", 20.0, scheduler=cl.address, tile_cells=16)
    assert Path(res["path"]).parent == store / "CRUISE-1" / "cruise_dtm"
    _check_product(store, "CRUISE-1", raws, 20.0)


def test_killed_worker_mid_run_completes_on_the_rest(tmp_path, prefect_harness, loopback):
    """SIGKILL one of two workers as soon as the first dive has been read: its tasks are re-run on the other
    worker, the cruise DTM is published complete (store.verify) and equal to the in-memory grid."""
    cl = loopback(2)
    raws = make_cruise(tmp_path / "raw", n=40_000)
    store = tmp_path / "store"
    scratch = tmp_path / "scratch"
    scratch.mkdir()
    killed: list[int] = []

    def killer() -> None:
        t_end = time.monotonic() + 120
        while time.monotonic() < t_end:
            if any((scratch / "read").glob("[!.]*/f*/z.f8")):  # a dive read and renamed into place
                victim = cl.workers[0]
                os.kill(victim.pid, signal.SIGKILL)
                killed.append(victim.pid)
                return
            time.sleep(0.05)

    th = threading.Thread(target=killer, daemon=True)
    th.start()
    res = _cruise_flow()([str(r) for r in raws], str(store), "CRUISE-K", 20.0, scheduler=cl.address,
                         tile_cells=16, scratch_dir=str(scratch))
    th.join(timeout=5)
    assert killed, "the worker was not killed during the run"
    assert cl.workers[0].wait(timeout=10) == -signal.SIGKILL and cl.workers[1].poll() is None
    assert all(d["used"] for d in res["dives"].values())
    # the scheduler lost the worker during the run (its held results or running tasks recomputed elsewhere)
    assert "name: w0" in (cl.logs / "scheduler.log").read_text()
    _check_product(store, "CRUISE-K", raws, 20.0)
    assert np.isfinite(_read_nc(Path(res["path"]) / "cruise_dtm.nc")["depth_m"].values).any()


def test_cruise_on_default_local_cluster(tmp_path, prefect_harness):
    """No scheduler given: the flow starts its own LocalCluster of ``workers`` processes; a bad raw directory is
    refused by name, the product made of the rest."""
    raws = make_cruise(tmp_path / "raw", n=2000)
    (tmp_path / "raw" / "junk").mkdir()
    store = tmp_path / "store"
    res = _cruise_flow()([*map(str, raws), str(tmp_path / "raw" / "junk")], str(store), "CRUISE-L", 20.0,
                         workers=2, tile_cells=16)
    assert str(tmp_path / "raw" / "junk") in res["refused_raw_dirs"]
    _check_product(store, "CRUISE-L", raws, 20.0)
    assert not (store / ".scratch").exists() or not any((store / ".scratch").iterdir())  # scratch removed
