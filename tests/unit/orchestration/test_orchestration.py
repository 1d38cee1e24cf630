"""Orchestration: cache keys, retries, cached flow re-runs, Dask batch of dives, cron deployment on a real server."""

from __future__ import annotations

import json
import os
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from factories import publish_fake_products, write_fake_dive

from hadal.errors import InputError
from hadal.pipeline import make_context
from hadal.store import ProductStore

REPO = Path(__file__).resolve().parents[3]
if str(REPO) not in sys.path:  # flows/ and tasks/ live at the repository root
    sys.path.insert(0, str(REPO))

from hadal.tasks.stage import fingerprint_key, retry_on_io_error, stage_fingerprint  # noqa: E402


@pytest.fixture
def fake(tmp_path):
    store = tmp_path / "store"
    publish_fake_products(ProductStore(store), "dive-a", products=("ctd",))
    raw = write_fake_dive(tmp_path / "raw" / "dive-a", "dive-a")
    return raw, store


def _key(stage, raw, store, config=None):
    return fingerprint_key(stage_fingerprint(stage, make_context(raw, store, config)))


def test_cache_key_tracks_parameters_upstream_and_raw_files(fake, tmp_path):
    raw, store = fake
    k0 = _key("report", raw, store)
    assert _key("report", raw, store) == k0  # deterministic
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("report: {dpi: 72}\n")
    assert _key("report", raw, store, cfg) != k0  # a parameter changed
    cfg.write_text("report: {}\n")
    assert _key("report", raw, store, cfg) == k0  # defaults spelled out = same parameters
    publish_fake_products(ProductStore(store), "dive-a", products=("dtm",))
    k1 = _key("report", raw, store)
    assert k1 != k0  # a new upstream product version
    assert _key("report", raw, tmp_path / "other-store") != k1  # another store
    # raw files: ingest hashes the files it reads
    (raw / "csv").mkdir()
    (raw / "csv" / "ctd.csv").write_text("time,pressure_dbar\n2018-10-06T23:00:00Z,1.0\n")
    (raw / "dive.yaml").write_text((raw / "dive.yaml").read_text() + "sources: {csv: {ctd: csv/ctd.csv}}\n")
    fp = stage_fingerprint("ingest", make_context(raw, store))
    assert str(raw.resolve() / "csv" / "ctd.csv") in fp["raw"]
    ki = fingerprint_key(fp)
    (raw / "csv" / "ctd.csv").write_text("time,pressure_dbar\n2018-10-06T23:00:00Z,2.0\n")
    assert _key("ingest", raw, store) != ki
    assert _key("report", raw, store) != k1  # dive.yaml is an input of every stage


def test_retry_condition_only_for_io_errors():
    class S:
        def __init__(self, exc):
            self.data = exc

    assert retry_on_io_error(None, None, S(OSError("NFS hiccup")))
    assert not retry_on_io_error(None, None, S(InputError("truncated file")))
    assert not retry_on_io_error(None, None, S(ValueError("bug")))


@pytest.mark.integration  # slow (> 9 s here): the integration tier (issue 20: make test <= 5 min)
@pytest.mark.prefect
def test_flow_reuses_unchanged_stage_and_reruns_changed(fake, tmp_path, prefect_harness):
    from hadal.flows.post_cruise import post_cruise

    raw, store = fake
    st = ProductStore(store)
    out1 = post_cruise(str(raw), str(store), None, ["report"])
    out2 = post_cruise(str(raw), str(store), None, ["report"])
    assert out1 == out2 and [v.label for v in st.versions("dive-a", "report")] == ["v001"]  # cache hit
    assert (store / ".prefect-results").is_dir()
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("report: {dpi: 60}\n")
    out3 = post_cruise(str(raw), str(store), str(cfg), ["report"])
    assert out3["report"].endswith("v002")  # parameter changed -> re-run
    out4 = post_cruise(str(raw), str(store), str(cfg), ["report"], force=True)
    assert out4["report"].endswith("v003")  # --force bypasses the cache
    shutil.rmtree(out4["report"])  # a cached result whose version disappeared is re-run, not returned
    out5 = post_cruise(str(raw), str(store), str(cfg), ["report"])
    assert Path(out5["report"], "report.html").is_file()
    # the report was published as Prefect artifacts
    from prefect.client.orchestration import get_client
    from prefect.client.schemas.filters import ArtifactFilter, ArtifactFilterKey

    with get_client(sync_client=True) as client:
        arts = client.read_artifacts(artifact_filter=ArtifactFilter(key=ArtifactFilterKey(any_=["dive-a-report"])))
    assert arts and "dive-a" in arts[0].data
    with get_client(sync_client=True) as client:  # the stage artifact links the report (issue 46)
        arts = client.read_artifacts(
            artifact_filter=ArtifactFilter(key=ArtifactFilterKey(any_=["dive-a-stage-report"])))
    link = f"({Path(out5['report'], 'report.html').resolve().as_uri()})"
    assert any(link in a.data for a in arts), [a.data for a in arts]


@pytest.mark.integration  # slow (> 9 s here): the integration tier (issue 20: make test <= 5 min)
@pytest.mark.prefect
def test_cruise_directory_flow_processes_new_dives_and_reuses_unchanged(tmp_path, prefect_harness):
    """`hadal serve CRUISE_DIR` deploys post-cruise-new-dives: each run discovers the dives present,
    processes the new ones and reuses (cache hit) the unchanged ones; a broken dive does not stop the others."""
    from hadal.flows.serve import deployment_target, post_cruise_new_dives

    store = tmp_path / "store"
    cruise = tmp_path / "cruise"
    st = ProductStore(store)
    for d in ("dive-a", "dive-b"):
        publish_fake_products(st, d, products=("ctd",))
        write_fake_dive(cruise / d, d)
    fl, params = deployment_target(str(cruise), str(store), None, ["report"])
    assert fl is post_cruise_new_dives and params["cruise_dir"] == str(cruise)
    assert deployment_target(str(cruise / "dive-a"), str(store), None)[1]["raw_dir"] == str(cruise / "dive-a")
    first = post_cruise_new_dives(str(cruise), str(store), None, ["report"])
    assert all(r["ok"] for r in first.values()) and len(first) == 2
    publish_fake_products(st, "dive-c", products=("ctd",))
    write_fake_dive(cruise / "dive-c", "dive-c")
    (cruise / "broken").mkdir()
    (cruise / "broken" / "dive.yaml").write_text("dive_id: [unclosed\n")
    state = post_cruise_new_dives(str(cruise), str(store), None, ["report"], return_state=True)
    assert state.is_failed() and "1 of 4 dive(s) failed: broken:" in state.message and "YAML" in state.message
    for d in ("dive-a", "dive-b"):  # unchanged: cache hits, nothing new published
        assert [v.label for v in st.versions(d, "report")] == ["v001"], d
    assert [v.label for v in st.versions("dive-c", "report")] == ["v001"]  # the new dive was processed


@pytest.mark.prefect
@pytest.mark.parametrize("processes", [False, pytest.param(True, marks=[pytest.mark.slow, pytest.mark.integration])], ids=["threads", "processes"])
def test_batch_two_dives_on_two_dask_workers(tmp_path, prefect_harness, processes):
    """Two dives fanned out on a 2-worker LocalCluster (worker processes: slow, ~40 s on a busy 2-core box)."""
    from hadal.flows.batch import run_batch

    store = tmp_path / "store"
    st = ProductStore(store)
    raws = []
    for d in ("dive-a", "dive-b"):
        publish_fake_products(st, d, products=("ctd",))
        raws.append(str(write_fake_dive(tmp_path / "raw" / d, d)))
    bad = tmp_path / "raw" / "not-a-dive"
    bad.mkdir()
    out = run_batch([*raws, str(bad)], str(store), None, ["report"], workers=2, processes=processes)
    for raw, d in zip(raws, ("dive-a", "dive-b"), strict=True):
        assert out[raw]["ok"], out[raw]
        assert Path(out[raw]["published"]["report"]).parent == store / d / "report"
        assert st.versions(d, "report")
    assert not out[str(bad)]["ok"] and "dive.yaml" in out[str(bad)]["error"]


# ------------------------------------------------------------------------------------------ CLI
def cli(monkeypatch, capsys, *args: str) -> tuple[int, str, str]:
    """Run ``hadal ARGS`` in-process (a subprocess would pay hadal's import time per call)."""
    from hadal import cli as hcli

    monkeypatch.setattr(sys, "argv", ["hadal", *args])
    with pytest.raises(SystemExit) as exc:
        hcli.main()
    out = capsys.readouterr()
    return int(exc.value.code or 0), out.out, out.err


def one_line_error(res: tuple[int, str, str], fragment: str) -> None:
    rc, _, err = res
    assert rc == 2, err
    assert "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln.startswith("error:")]
    assert len(lines) == 1 and fragment in " ".join(err.split()), err


def test_cli_serve_and_batch_errors(tmp_path, monkeypatch, capsys):
    from prefect.settings import PREFECT_API_URL, temporary_settings

    raw = write_fake_dive(tmp_path / "raw", "dive-a")
    monkeypatch.setenv("COLUMNS", "250")
    monkeypatch.delenv("PREFECT_API_URL", raising=False)
    with temporary_settings(restore_defaults={PREFECT_API_URL}):
        one_line_error(cli(monkeypatch, capsys, "serve", str(raw), "--cron", "0 3 * * *", "--store", str(tmp_path)),
                       "needs a Prefect server")
    one_line_error(cli(monkeypatch, capsys, "serve", str(raw), "--cron", "every day"), "invalid cron")
    one_line_error(cli(monkeypatch, capsys, "run", "--dives", str(tmp_path / "nothing")), "does not exist")
    (tmp_path / "empty").mkdir()
    one_line_error(cli(monkeypatch, capsys, "run", "--dives", str(tmp_path / "empty")), "no dive.yaml")
    one_line_error(cli(monkeypatch, capsys, "run", "--dives", str(raw), "--workers", "0", "--store",
                       str(tmp_path / "s")), "--workers")


# ------------------------------------------------------------------------------------------ serve
def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def _post(url: str, body: dict) -> list:
    import httpx

    r = httpx.post(url, json=body, timeout=10)
    r.raise_for_status()
    return r.json()


@pytest.mark.slow
@pytest.mark.integration
def test_serve_creates_scheduled_runs_on_a_real_server(tmp_path):
    """`hadal serve` registers a cron deployment; the server's scheduler creates Scheduled runs for it."""
    import httpx

    port = _free_port()
    api = f"http://127.0.0.1:{port}/api"
    home = tmp_path / "prefect-home"
    env = {**os.environ, "PREFECT_HOME": str(home), "PREFECT_API_URL": api, "PREFECT_SERVER_ANALYTICS_ENABLED": "false",
           "PREFECT_SERVER_SERVICES_SCHEDULER_LOOP_SECONDS": "2", "PREFECT_SERVER_UI_ENABLED": "false",
           "PREFECT_LOGGING_LEVEL": "WARNING",
           "PYTHONPATH": os.pathsep.join([str(REPO / "src"), str(REPO)]), "HADAL_PROGRESS": "0"}
    server_env = {k: v for k, v in env.items() if k != "PREFECT_API_URL"}
    prefect = str(Path(sys.executable).with_name("prefect"))
    server = subprocess.Popen([prefect, "server", "start", "--host", "127.0.0.1", "--port", str(port), "--no-ui"],
                              env=server_env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, cwd=tmp_path)
    procs = [server]
    try:
        deadline = time.monotonic() + 180  # a loaded 2-core machine took over 75 s
        while time.monotonic() < deadline:
            try:
                if httpx.get(f"{api}/health", timeout=2).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            assert server.poll() is None, server.stderr.read().decode()[-2000:]
            time.sleep(0.5)
        else:
            pytest.fail("prefect server did not start")
        store = tmp_path / "store"
        raw = write_fake_dive(tmp_path / "raw", "dive-a")
        serve = subprocess.Popen([sys.executable, "-m", "hadal.cli", "serve", str(raw), "--cron", "0 3 * * *",
                                  "--name", "nightly", "--store", str(store)], env=env, cwd=REPO,
                                 stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        procs.append(serve)
        runs: list = []
        while time.monotonic() < deadline + 45 and not runs:
            assert serve.poll() is None, serve.stderr.read().decode()[-2000:]
            deps = _post(f"{api}/deployments/filter", {"deployments": {"name": {"any_": ["nightly"]}}})
            if deps:
                runs = _post(f"{api}/flow_runs/filter", {
                    "deployments": {"id": {"any_": [deps[0]["id"]]}},
                    "flow_runs": {"state": {"type": {"any_": ["SCHEDULED"]}}}})
            time.sleep(1)
        assert runs, "no scheduled flow run appeared for the deployment"
        assert deps[0]["schedules"][0]["schedule"]["cron"] == "0 3 * * *"
        assert json.loads(json.dumps(deps[0]["parameters"]))["raw_dir"] == str(raw.resolve())
        assert all(r["state"]["type"] == "SCHEDULED" for r in runs)
    finally:
        for p in reversed(procs):
            p.terminate()
        for p in reversed(procs):
            try:
                p.wait(timeout=15)
            except subprocess.TimeoutExpired:
                p.kill()


_FAKE_MAKES = {"ingest": "sensors", "derive": "ctd", "dtm": "dtm", "laser": "laser_grids", "landing": "landing",
               "report": "report"}


def _fake_stage(name: str, log: dict, lock, seconds: float, fail: bool = False):
    """A Prefect task standing in for stage ``name``: sleeps, logs its start/end/pins/isolate flag, then publishes
    an empty version of the product it makes (or raises InputError if ``fail``)."""
    from hadal.tasks.stage import upstream_state
    from prefect import task
    from prefect.cache_policies import NO_CACHE

    from hadal.errors import InputError

    def run(raw_dir, store_root=None, config_path=None, pins=None, upstream=None, isolate=False):
        t0 = time.monotonic()
        pins, failed, _ = upstream_state(name, pins, upstream)  # what the real stage task reads from upstream
        time.sleep(seconds)
        with lock:
            log[name] = {"t0": t0, "t1": time.monotonic(), "pins": pins, "failed": failed, "isolate": isolate}
        if fail:
            raise InputError(f"{name} broke")
        v = Path(store_root, "d", _FAKE_MAKES[name], "v001")
        v.mkdir(parents=True)
        (v / "manifest.json").write_text("{}")
        return {_FAKE_MAKES[name]: str(v)}

    # never a cache hit: these tests look at scheduling (an earlier test's fake stage of the same name and source
    # could otherwise be taken for this one's result)
    return task(name=name, cache_policy=NO_CACHE)(run)


@pytest.mark.prefect
def test_stage_graph_runs_independent_stages_concurrently_with_pins(tmp_path, prefect_harness, monkeypatch):
    """The stage graph handed to Prefect (submit_dive: each task submitted once with its upstream futures) starts a
    stage as soon as the stages it reads from are done: ingest and laser overlap, derive waits for ingest, landing for laser (not for match); each stage gets the pins of
    what its upstream published; a failed stage skips its dependents, the others and the report still run.
    Oracle: the dependency table of the stage docs (derive reads sensors, landing reads laser_grids)."""
    import threading

    from hadal.flows import post_cruise as pc
    from prefect import flow
    from prefect.task_runners import ThreadPoolTaskRunner

    log: dict[str, dict] = {}
    lock = threading.Lock()

    names = ["ingest", "derive", "laser", "landing", "report"]
    monkeypatch.setattr(pc, "stage_tasks", lambda ns: [_fake_stage(n, log, lock, 1.0, fail=(n == "derive"))
                                                       for n in ns])

    @flow(task_runner=ThreadPoolTaskRunner(max_workers=4))
    def graph():
        from prefect.context import FlowRunContext

        d = pc.DiveRun("raw", names, {"dtm": "old-dtm"})
        pc.submit_dive(FlowRunContext.get().task_runner, d, str(tmp_path), None, False)
        pc.collect_dives([d], str(tmp_path), None)
        return d

    d = graph()
    assert log["laser"]["t0"] < log["ingest"]["t1"]  # concurrent: laser does not wait for ingest
    assert log["derive"]["t0"] >= log["ingest"]["t1"]  # derive reads sensors
    assert log["landing"]["t0"] >= log["laser"]["t1"] and log["landing"]["t0"] < log["derive"]["t1"] + 0.9
    assert log["derive"]["pins"]["sensors"].endswith("sensors/v001") and log["derive"]["pins"]["dtm"] == "old-dtm"
    assert log["report"]["t0"] >= max(log[n]["t1"] for n in ("ingest", "derive", "laser", "landing"))
    assert log["report"]["failed"] == {"derive": "derive broke"}  # the report lists the failure
    status = {r["stage"]: r["status"] for r in d.rows}
    assert status == {"ingest": "published", "derive": "failed", "laser": "published", "landing": "published",
                      "report": "published"}
    assert d.failed == {"derive": "derive broke"}
    assert [r["stage"] for r in d.rows] == names  # the run table in plan order


@pytest.mark.prefect
def test_stage_graph_runs_at_most_max_running_stages_ready_ones_in_plan_order(tmp_path, prefect_harness,
                                                                              monkeypatch):
    """With a task runner of two workers no more than two stages overlap although ingest, dtm and laser are ready
    together; the first two in stage order (ingest, dtm) start first, laser takes the first free slot (derive, not
    ready, does not hold a worker before them); stages the graph marks for a process get ``isolate=True`` (dtm and
    laser overlap ingest/derive), the others not.
    Oracle: the start/end times each fake stage logged."""
    import threading

    from hadal.flows import post_cruise as pc
    from prefect import flow
    from prefect.task_runners import ThreadPoolTaskRunner

    log: dict[str, dict] = {}
    lock = threading.Lock()

    names = ["ingest", "derive", "dtm", "laser", "report"]
    monkeypatch.setattr(pc, "stage_tasks", lambda ns: [_fake_stage(n, log, lock, 2.0) for n in ns])

    @flow
    def graph():
        d = pc.DiveRun("raw", names, {}, pc.process_stages(names))
        with ThreadPoolTaskRunner(max_workers=2) as runner:
            pc.submit_dive(runner, d, str(tmp_path), None, False)
            pc.collect_dives([d], str(tmp_path), None)
        return d

    d = graph()
    assert {r["stage"]: r["status"] for r in d.rows} == dict.fromkeys(names, "published")
    spans = sorted((v["t0"], v["t1"]) for v in log.values())
    for t, _ in spans:  # at any stage start, at most two stages are running (itself included)
        assert sum(a <= t < b for a, b in spans) <= 2
    assert log["dtm"]["t0"] < log["ingest"]["t1"] and log["laser"]["t0"] >= min(log["ingest"]["t1"],
                                                                                log["dtm"]["t1"]) - 0.05
    assert {n for n, v in log.items() if v["isolate"]} == {"dtm", "laser"}


def test_process_stages_are_the_cpu_bound_ones_that_can_overlap_another_stage():
    """Oracle: the dependency diagram of docs/operations.md: in a full run dtm and laser each have a stage beside
    them; in a chain (dtm -> suitability -> match) nothing can overlap, so nothing pays a process; match and
    landing (no PROCESS flag) stay in threads."""
    from hadal.flows.post_cruise import process_stages

    full = ["ingest", "derive", "dtm", "laser", "suitability", "match", "landing", "report"]
    assert process_stages(full) == {"dtm", "laser"}
    assert process_stages(["dtm", "suitability", "match", "report"]) == set()
    assert process_stages(["ingest", "derive", "dtm", "suitability", "match", "report"]) == {"dtm"}
    assert process_stages(["laser", "landing", "report"]) == set()


@pytest.mark.prefect
def test_flow_run_is_named_and_tagged_for_the_dive_and_task_runs_after_stages(fake, prefect_harness, monkeypatch,
                                                                           capsys):
    """`hadal stage report --flow` records a flow run named ``<dive>-<UTC time>`` with the tags ``dive:<id>`` and
    ``cruise:<dir>`` (read back from the Prefect API), and one task run per stage named after the stage, untagged
    (a tagged task run makes Prefect acquire a tag concurrency slot before it starts)."""
    import re

    from prefect.client.orchestration import get_client
    from prefect.client.schemas.filters import FlowRunFilter, FlowRunFilterId

    raw, store = fake
    rc, _, err = cli(monkeypatch, capsys, "stage", "report", str(raw), "--store", str(store), "--flow", "--force")
    assert rc == 0, err
    with get_client(sync_client=True) as client:
        fr = max(client.read_flow_runs(), key=lambda r: r.created)
        trs = client.read_task_runs(flow_run_filter=FlowRunFilter(id=FlowRunFilterId(any_=[fr.id])))
    assert re.fullmatch(r"dive-a-\d{8}T\d{6}Z", fr.name), fr.name
    assert {"dive:dive-a", f"cruise:{raw.parent.name}"} <= set(fr.tags), fr.tags
    assert [(t.name, list(t.tags)) for t in trs] == [("report", [])]


# ------------------------------------------------------------------------------ unchanged dive without Prefect
def _tree(root: Path) -> dict[str, tuple[int, int]]:
    """Every file under ``root`` (products, manifests, cache records) with its size and mtime."""
    return {str(p.relative_to(root)): (p.stat().st_size, p.stat().st_mtime_ns) for p in root.rglob("*") if p.is_file()}


@pytest.mark.prefect
def test_unchanged_dive_is_told_without_a_flow_run_and_changes_still_rerun(fake, tmp_path, prefect_harness,
                                                                           monkeypatch, capsys):
    """`hadal stage`/`hadal run` on a dive whose stages would all be cache hits answer without starting Prefect,
    returning what Prefect's own cache returns (oracle: the flow's re-run, and Prefect's ResultRecord reader for
    the records); a changed parameter (re-run through the CLI), raw file (dive.yaml) or removed version is not
    current, and --flow still runs the flow."""
    from hadal.flows.post_cruise import post_cruise
    from prefect.client.orchestration import get_client
    from prefect.results import ResultRecord

    from hadal.cli import run as hcli_run
    from hadal.pipeline import cached_result, current_stages, result_storage, stale_stages

    raw, store = fake
    st = ProductStore(store)
    assert current_stages(str(raw), str(store), None, ["report"]) is None  # never run: not current
    out1 = post_cruise(str(raw), str(store), None, ["report"])
    cur = current_stages(str(raw), str(store), None, ["report"])
    again = post_cruise(str(raw), str(store), None, ["report"])  # Prefect's own cache decision
    assert cur is not None and dict(cur) == dict(again) == dict(out1)
    assert [r["status"] for r in cur.stages] == [r["status"] for r in again.stages] == ["reused"]
    assert stale_stages(str(raw), str(store), None, ["report"]) == []  # what the CLI starts processes for
    storage = result_storage(store)
    for rec in storage.iterdir():  # the Prefect-free reader agrees with Prefect's
        assert cached_result(storage, rec.name) == ResultRecord.deserialize(rec.read_bytes()).result

    monkeypatch.setenv("COLUMNS", "250")

    def no_prefect():
        raise AssertionError("Prefect was started for an unchanged dive")

    def flow_runs() -> int:
        with get_client(sync_client=True) as client:
            return len(client.read_flow_runs())

    before, n_runs = _tree(store), flow_runs()
    monkeypatch.setattr(hcli_run, "_prefect_environment", no_prefect)
    rc, _, err = cli(monkeypatch, capsys, "stage", "report", str(raw), "--store", str(store))
    assert rc == 0 and "1 stage(s) current" in err and "Traceback" not in err, err
    assert _tree(store) == before and flow_runs() == n_runs  # nothing written, no flow run
    monkeypatch.undo()
    monkeypatch.setenv("COLUMNS", "250")

    rc, _, err = cli(monkeypatch, capsys, "stage", "report", str(raw), "--store", str(store), "--flow")
    assert rc == 0 and flow_runs() == n_runs + 1, err  # --flow: a recorded (all cache hits) run
    assert [v.label for v in st.versions("dive-a", "report")] == ["v001"]
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("report: {dpi: 60}\n")
    assert current_stages(str(raw), str(store), str(cfg), ["report"]) is None  # a parameter changed
    assert stale_stages(str(raw), str(store), str(cfg), ["report"]) == ["report"]
    rc, _, err = cli(monkeypatch, capsys, "stage", "report", str(raw), "--store", str(store), "--config", str(cfg))
    assert rc == 0 and [v.label for v in st.versions("dive-a", "report")] == ["v001", "v002"], err
    assert current_stages(str(raw), str(store), str(cfg), ["report"]) is not None
    shutil.rmtree(st.latest("dive-a", "report").path)  # the cached version is gone: not current
    assert current_stages(str(raw), str(store), str(cfg), ["report"]) is None
    (raw / "dive.yaml").write_text((raw / "dive.yaml").read_text() + "# edited\n")  # a raw input changed
    assert current_stages(str(raw), str(store), None, ["report"]) is None  # (the flow then re-runs: cache key test)


@pytest.mark.parametrize("changed", ["ingest", "dtm", "laser", "match", "report"])
def test_stale_stages_are_the_changed_stage_and_everything_downstream(changed, tmp_path, monkeypatch):
    """A stage without a current cached result runs, and so does every stage that reads what it publishes (oracle:
    :func:`hadal.stages.plan.downstream_stages`, what ``hadal stage NAME --downstream`` re-runs); the others are reused.
    Nothing cached yet: every stage runs."""
    from hadal import pipeline
    from hadal.stages import STAGE_ORDER
    from hadal.stages.plan import downstream_stages

    names = list(STAGE_ORDER)
    raw = write_fake_dive(tmp_path / "raw", "dive-a")
    store = tmp_path / "store"
    assert pipeline.stale_stages(str(raw), str(store), None, names) == names  # a first run
    pipeline.result_storage(store).mkdir(parents=True)
    version = tmp_path / "v"
    version.mkdir()
    (version / "manifest.json").write_text("{}")
    monkeypatch.setattr(pipeline, "stage_cache_key", lambda name, *a, **k: name)
    monkeypatch.setattr(pipeline, "cached_result",
                        lambda storage, key: None if key == changed else {f"{key}-product": str(version)})
    expected = [n for n in names if n == changed or n in downstream_stages(changed, names)]
    assert pipeline.stale_stages(str(raw), str(store), None, names) == expected
    assert pipeline.current_stages(str(raw), str(store), None, names) is None


def test_cached_result_reads_prefect_records_and_refuses_what_it_cannot_trust(tmp_path):
    """Records written by Prefect's own ResultRecord (pickle and JSON serializers) are read back as the task result;
    an expired record, a result that is not plain data (a pickled class) and a garbled file are "not known"."""
    import datetime as dt

    from prefect._internal.result_records import ResultRecord, ResultRecordMetadata
    from prefect.serializers import JSONSerializer, PickleSerializer

    from hadal.pipeline import cached_result

    value = {"report": str(tmp_path / "d" / "report" / "v001")}

    def write(key, result, **meta):
        rec = ResultRecord(metadata=ResultRecordMetadata(storage_key=str(tmp_path / key), **meta), result=result)
        (tmp_path / key).write_bytes(rec.serialize())

    write("pickle", value)
    write("json", value, serializer=JSONSerializer())
    write("future", value, expiration=dt.datetime.now(dt.UTC) + dt.timedelta(days=1))
    write("expired", value, expiration=dt.datetime.now(dt.UTC) - dt.timedelta(seconds=1))
    write("object", {"report": tmp_path}, serializer=PickleSerializer())  # a PosixPath: a class reference
    (tmp_path / "garbled").write_text("{not json")
    assert cached_result(tmp_path, "pickle") == cached_result(tmp_path, "json") == value
    assert cached_result(tmp_path, "future") == value
    for key in ("expired", "object", "garbled", "absent"):
        assert cached_result(tmp_path, key) is None, key


@pytest.mark.prefect
def test_stage_grid_runs_the_group_and_names_only_what_its_fresh_members_made_stale(tmp_path, prefect_harness,
                                                                                   monkeypatch, capsys):
    """`hadal stage grid` (the group dtm + laser) on a dive with multibeam and laser: after a changed laser
    parameter only `laser` publishes (dtm is a cache hit), so the stale note names landing, not suitability;
    `--downstream` then re-runs landing and leaves suitability's version. Oracle: the stage dependencies of
    docs/operations.md and the versions in the store."""
    import gzip

    import numpy as np
    import yaml

    from hadal.geo import LocalFrame

    rng = np.random.default_rng(3)
    raw = tmp_path / "raw" / "g1"
    (raw / "multibeam").mkdir(parents=True)
    (raw / "laser").mkdir()
    frame = LocalFrame(11.33, 142.2)
    x, y = rng.uniform(-800, 800, 4000), rng.uniform(-800, 800, 4000)
    lon, lat = frame.to_lonlat(x, y)
    with gzip.open(raw / "multibeam" / "line.xyz.gz", "wt") as fh:
        np.savetxt(fh, np.column_stack([lon, lat, 8000 + 0.01 * x + rng.normal(0, 1, 4000)]), fmt="%.8f %.8f %.3f")
    pts = np.column_stack([rng.uniform(0, 1.0, 20000), rng.uniform(0, 1.0, 20000), -1400 + 0.001 * rng.normal(size=20000)])
    head = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(pts)}\n"
            "property double x\nproperty double y\nproperty double z\nend_header\n").encode()
    (raw / "laser" / "s1.ply").write_bytes(head + pts.astype("<f8").tobytes())
    (raw / "dive.yaml").write_text(yaml.safe_dump({
        "dive_id": "g1", "platform": "test", "map_frame": {"origin_latitude_deg": 11.33, "origin_longitude_deg": 142.2},
        "sources": {"multibeam": ["multibeam/line.xyz.gz"], "laser": ["laser/s1.ply"]}}))
    store = tmp_path / "store"
    rc, out, err = cli(monkeypatch, capsys, "run", str(raw), "--store", str(store))
    assert rc == 0, err
    st = ProductStore(store)
    assert st.has("g1", "dtm") and st.has("g1", "laser_grids") and st.has("g1", "suitability")
    # the run ends by printing where its report is (issue 46)
    assert out.strip().splitlines()[-1] == f"report: {(st.latest('g1', 'report').path / 'report.html').resolve()}"
    cfg = tmp_path / "laser.yaml"
    cfg.write_text("grid: {laser_sor_std_ratio: 2.5}\n")
    rc, out, err = cli(monkeypatch, capsys, "stage", "grid", str(raw), "--store", str(store), "--config", str(cfg))
    assert rc == 0, err
    text = " ".join(err.split())  # notes go to stderr, the table to stdout
    assert st.latest("g1", "dtm").label == "v001" and st.latest("g1", "laser_grids").label == "v002"
    assert "note: landing still use(s) the previous laser products" in text, err
    rc, out, err = cli(monkeypatch, capsys, "stage", "grid", str(raw), "--store", str(store), "--config", str(cfg),
                       "--downstream")
    assert rc == 0, err
    assert st.latest("g1", "landing").label == "v002" and st.latest("g1", "suitability").label == "v001"
    assert "still use" not in err


def test_a_stage_skipped_by_its_content_check_names_the_reason_in_the_run_table(shared_data, tmp_path):
    """A laser-only dive of a coarse airborne lidar cloud (dives-real LAS, 31.6 m cells): landing publishes nothing;
    the flow's table row says why (landing's own content check), not just "see the log"."""
    from dive_runs import init_dive, run_quiet
    from hadal.flows.post_cruise import skipped_reason

    raw, _ = init_dive(shared_data, tmp_path, "dives-real/pdal_autzen-utm.las")
    run_quiet(raw, tmp_path / "store")
    why = skipped_reason(str(raw), {}, "landing", str(tmp_path / "store"), None)
    assert "coarser than landing.max_cell_fraction" in why and "\n" not in why
    assert skipped_reason(str(raw), {}, "report", str(tmp_path / "store"), None) == "nothing to do (see the log)"


def test_a_stage_task_whose_upstream_failed_skips_itself_uncached_and_the_report_lists_both(fake):
    """What Prefect hands a stage task through ``allow_failure`` when an upstream stage failed is that stage's
    exception: suitability (which needs dtm, docs/operations.md) then publishes nothing and is not cached (its cache
    key is None, so a later run retries it); the report sees the failure and the skip it caused, with the reasons.
    Oracle: the stage dependency table (suitability needs dtm; the report needs nothing, reads everything)."""
    from hadal.tasks.report import report
    from hadal.tasks.stage import upstream_state
    from hadal.tasks.suitability import suitability

    raw, store = fake
    broke = InputError("dtm.tif: not a grid\nsecond line")
    params = {"raw_dir": str(raw), "store_root": str(store), "config_path": None, "pins": {},
              "upstream": {"dtm": broke}, "isolate": False}
    assert suitability.fn(**params) == {}
    assert suitability.cache_key_fn(None, params) is None
    assert not (store / "dive-a" / "suitability").exists()
    pins, failed, skips = upstream_state("report", {"ctd": "old"}, {"dtm": broke, "suitability": {}, "ingest":
                                                                    {"sensors": "new"}})
    assert pins == {"ctd": "old", "sensors": "new"}
    assert failed == {"dtm": "dtm.tif: not a grid"}
    assert skips == {"suitability": "needs dtm, but stage dtm failed in this run"}
    key = report.cache_key_fn(None, {**params, "upstream": {"dtm": broke, "suitability": {}}})
    assert key is not None and key.startswith("hadal-report-")
