"""End-to-end benchmark: sample dive through the pipeline, Prefect overhead, Dask batch scaling.

    PYTHONPATH=src:. .venv/bin/python bench/bench_pipeline.py [--small] [--dives 4] [--skip-batch]
    .venv/bin/python bench/bench_pipeline.py --cli HEAD [--raw DIR] [--small]

``--cli REV``: ``hadal run``/``hadal stage`` as a user runs them (fresh processes), this working tree against git
revision ``REV`` in the same run: ``--cold-runs`` cold full dives per code, alternating, with a temporary Prefect
server and with a long-running one (``prefect server start``, started by the benchmark), after one untimed run each
(a snapshot compiles its numba kernels' caches first); then an unchanged re-run with either server and an unchanged
single stage; each unchanged case also with ``--flow`` (a recorded Prefect run of cache hits, what ``REV`` always
does when it predates the Prefect-free currency check).

Measured in the same run (so the ratios are meaningful on a shared machine):

1. ``run_pipeline`` called directly (no Prefect) on the sample dive (``hadal.synth.generate_dive``);
2. the ``post-cruise`` flow on a fresh store, first call (includes starting Prefect's temporary server)
   and a forced re-run with the server up (Prefect overhead per run = flow - direct);
3. an unchanged re-run of the flow (every stage a cache hit);
4. a batch of N copies of the (small) sample dive with ``DaskTaskRunner`` on a LocalCluster of 1 and
   of 2 worker processes, started and warmed up before the timing (speed-up = t1 / t2; bounded by the
   idle cores you actually have: see the load average printed with it).

Without the sample generator (``hadal.synth``) it falls back to a fake dive whose products are
published by :mod:`factories` (tests/) and times only the stages that can run on it (report).
"""

from __future__ import annotations

import argparse
import os
import shutil
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
for p in (REPO / "src", REPO):
    if str(p) not in sys.path:
        sys.path.insert(0, str(p))
os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
os.environ.setdefault("PREFECT_LOGGING_LEVEL", "WARNING")
os.environ.setdefault("HADAL_PROGRESS", "0")
import logging  # noqa: E402

logging.getLogger("distributed").setLevel(logging.WARNING)
os.environ["PYTHONPATH"] = os.pathsep.join([str(REPO / "src"), str(REPO), os.environ.get("PYTHONPATH", "")])

import yaml  # noqa: E402


def make_dive(dest: Path, small: bool, dive_id: str | None = None) -> tuple[Path, list[str] | None, bool]:
    """(raw_dir, stages, is_synthetic_sample). Falls back to a fake dive when hadal.synth is missing."""
    try:
        from hadal.synth import generate_dive
    except ImportError:
        import _tests_path  # noqa: F401  (tests/ on sys.path)
        from factories import write_fake_dive

        raw = write_fake_dive(dest, dive_id or "fake-dive")
        return raw, ["report"], False
    raw = Path(generate_dive(dest, small=small))
    if dive_id:
        f = raw / "dive.yaml"
        data = yaml.safe_load(f.read_text())
        data["dive_id"] = dive_id
        f.write_text(yaml.safe_dump(data, sort_keys=False))
    return raw, None, True


def prepare_store(store: Path, raw: Path, real: bool) -> None:
    if not real:
        import _tests_path  # noqa: F401  (tests/ on sys.path)
        from factories import publish_fake_products

        from hadal.dive import load_dive
        from hadal.store import ProductStore

        publish_fake_products(ProductStore(store), load_dive(raw)[0].dive_id)


def _warm_worker() -> bool:
    import hadal.tasks.stage  # noqa: F401
    import matplotlib  # noqa: F401

    import hadal.pipeline  # noqa: F401
    import hadal.report  # noqa: F401

    return True


def timed(fn, *a, **k):
    t = time.perf_counter()
    out = fn(*a, **k)
    return time.perf_counter() - t, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--small", action="store_true", help="use the small sample dive for the single-dive timings")
    ap.add_argument("--dives", type=int, default=4, help="dives in the batch (small sample dives)")
    ap.add_argument("--skip-batch", action="store_true")
    ap.add_argument("--batch-skip", default="", help="comma-separated stages not run on small dives (batch, and --small)")
    ap.add_argument("--repeat", type=int, default=2, help="repeats of the warm direct and forced flow runs (best of)")
    args = ap.parse_args()

    from hadal.flows.batch import run_batch
    from hadal.flows.post_cruise import post_cruise
    from prefect.testing.utilities import prefect_test_harness

    from hadal.pipeline import make_context, run_pipeline

    work = Path(tempfile.mkdtemp(prefix="hadal-bench-"))
    os.environ.setdefault("PREFECT_HOME", str(work / "prefect-home"))
    try:
        raw, stages, real = make_dive(work / "raw" / "sample", args.small)
        if real and args.small:
            from hadal.stages.plan import resolve_stages

            stages = [s for s in resolve_stages(None) if s not in args.batch_skip.split(",")]
            print(f"stages (small dive): {', '.join(stages)}")
        print(f"dive: {raw} ({'sample dive' + (' (small)' if args.small else '') if real else 'FAKE products, report stage only: hadal.synth missing'})")
        s_cold, s_flow = work / "store-cold", work / "store-flow"
        for st in (s_cold, s_flow):
            prepare_store(st, raw, real)
        t_cold, _ = timed(run_pipeline, make_context(raw, s_cold), stages)  # pays the first-import costs
        t_direct = float("inf")
        for i in range(args.repeat):  # best of N on a fresh store: the machine may be shared
            st = work / f"store-direct-{i}"
            prepare_store(st, raw, real)
            t_direct = min(t_direct, timed(run_pipeline, make_context(raw, st), stages)[0])
        print(f"run_pipeline (no Prefect), cold process:   {t_cold:8.2f} s")
        print(f"run_pipeline (no Prefect), warm, best of {args.repeat}: {t_direct:6.2f} s")
        with prefect_test_harness(server_startup_timeout=180):
            t_first, _ = timed(post_cruise, str(raw), str(s_flow), None, stages)
            t_forced = min(timed(post_cruise, str(raw), str(s_flow), None, stages, True)[0] for _ in range(args.repeat))
            t_cached, _ = timed(post_cruise, str(raw), str(s_flow), None, stages)
            print(f"flow, first run (incl. Prefect start-up):  {t_first:8.2f} s")
            print(f"flow, forced re-run (server up), best of {args.repeat}: {t_forced:5.2f} s")
            print(f"flow, unchanged re-run (all cache hits):   {t_cached:8.2f} s")
            over = t_forced - t_direct
            print(f"Prefect overhead per run: {over:+.2f} s = {over / t_forced:.1%} of the flow run "
                  f"(flow/direct = {t_forced / t_direct:.2f}x); first run/direct = {t_first / t_direct:.2f}x; "
                  f"cached/forced = {t_cached / t_forced:.3f}")
            if args.skip_batch:
                return
            raws = []
            for i in range(args.dives):
                r, bstages, breal = make_dive(work / "raw" / f"batch-{i}", True, f"batch-dive-{i}")
                raws.append(str(r))
            if breal:
                from hadal.stages.plan import resolve_stages

                # the small sample's bottom track does not fit its thinned multibeam map: TERCOM has no
                # feasible offset there, so the batch runs every other stage (the report notes the gap)
                bstages = [s for s in resolve_stages(None) if s not in args.batch_skip.split(",")]
            print(f"batch stages: {', '.join(bstages)}")
            from distributed import Client, LocalCluster

            times = {}
            for n in (1, 2):
                store = work / f"store-batch-{n}"
                for r in raws:
                    prepare_store(store, Path(r), breal)
                t0 = time.perf_counter()
                with LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=":0") as cl, \
                        Client(cl) as client:
                    client.run(_warm_worker)  # imports on every worker, so start-up is not in the batch time
                    t_up = time.perf_counter() - t0
                    times[n], res = timed(run_batch, raws, str(store), None, bstages, scheduler=cl.scheduler_address)
                bad = [k for k, v in res.items() if not v["ok"]]
                print(f"batch of {len(raws)} dives on {n} Dask worker(s): {times[n]:8.2f} s "
                      f"(+{t_up:.1f} s cluster start-up and imports)" + (f"  FAILED: {bad}" if bad else ""))
            print(f"batch speed-up 2 vs 1 workers: {times[1] / times[2]:.2f}x (cores: {os.cpu_count()}, "
                  f"load average {os.getloadavg()[0]:.1f})")
    finally:
        shutil.rmtree(work, ignore_errors=True)


# ------------------------------------------------------------------------------------ the CLI, before/after
def _snapshot(dest: Path, rev: str | None) -> Path:
    """hadal's code (the working tree, or git ``rev`` via ``git archive``: nothing in the tree changes) under
    ``dest``, with flows/ tasks/ schemas/ linked in as hadal.flows / hadal.tasks / hadal.schemas."""
    import subprocess
    import tarfile

    dest.mkdir(parents=True)
    parts = ["src", "flows", "tasks", "schemas"]
    if rev:
        tar = dest / "code.tar"
        with open(tar, "wb") as fh:
            subprocess.run(["git", "-C", str(REPO), "archive", rev, *parts], stdout=fh, check=True)
        with tarfile.open(tar) as tf:
            tf.extractall(dest, filter="data")
    else:
        for part in parts:
            if (REPO / part).is_dir():
                shutil.copytree(REPO / part, dest / part, ignore=shutil.ignore_patterns("__pycache__"))
    for part in parts[1:]:
        if (dest / part).is_dir():
            (dest / "src" / "hadal" / part).symlink_to(dest / part)
    return dest / "src"


def cli_compare(args) -> None:
    """``hadal run``/``hadal stage`` as a user runs them (a fresh process each), this tree vs git ``args.cli``."""
    import subprocess

    work = Path(tempfile.mkdtemp(prefix="hadal-bench-cli-"))
    py = sys.executable
    try:
        codes = {"now": _snapshot(work / "code-now", None), args.cli: _snapshot(work / "code-old", args.cli)}
        has_flow = {c: '"--flow"' in (src / "hadal" / "cli.py").read_text(encoding="utf-8") for c, src in codes.items()}
        raw = Path(args.raw) if args.raw else make_dive(work / "raw" / "sample", args.small)[0]
        srv_home = work / "prefect-server"
        srv_home.mkdir()
        port = 4000 + os.getpid() % 1000
        server = subprocess.Popen([str(Path(py).with_name("prefect")), "server", "start", "--host", "127.0.0.1",
                                   "--port", str(port)], env={**os.environ, "PREFECT_HOME": str(srv_home)},
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
        api = f"http://127.0.0.1:{port}/api"

        def hadal(code: str, *argv: str, server_up: bool = False) -> float:
            if code != "now" and not has_flow[code]:  # code before --flow always ran the Prefect flow anyway
                argv = tuple(a for a in argv if a != "--flow")
            env = {**os.environ, "PYTHONPATH": str(codes[code]), "HADAL_PROGRESS": "0",
                   "PREFECT_HOME": str(work / f"prefect-home-{code}-{'srv' if server_up else 'tmp'}")}
            env.pop("PREFECT_API_URL", None)
            if server_up:
                env["PREFECT_API_URL"] = api
            t0 = time.perf_counter()
            res = subprocess.run([py, "-m", "hadal.cli", *argv], env=env, capture_output=True, text=True,
                                 timeout=3600)
            dt = time.perf_counter() - t0
            if res.returncode != 0:
                print(f"  ({code} hadal {' '.join(argv[:2])} exit {res.returncode}: {res.stderr.strip()[-300:]})")
            return dt

        rows: list[tuple[str, dict[str, float]]] = []

        def both(label: str, fn) -> None:
            vals = {code: fn(code) for code in codes}
            rows.append((label, vals))
            a, b = vals["now"], vals[args.cli]
            print(f"{label:<46s} now {a:7.2f} s   {args.cli} {b:7.2f} s   speed-up {b / a:5.2f}x", flush=True)

        def store(code: str) -> str:
            return str(work / f"store-{code}")

        print(f"dive {raw}; load average {os.getloadavg()[0]:.1f} on {os.cpu_count()} cores (shared machine?)")
        for code in codes:  # a snapshot has no compiled-kernel caches yet: one run each compiles them (not timed)
            hadal(code, "run", str(raw), "--store", str(work / f"store-warmup-{code}"))
        cold_full_dives(args.cold_runs, list(codes), args.cli, hadal, work, raw)
        both("cold full dive, hadal run (temporary server)", lambda c: hadal(c, "run", str(raw), "--store", store(c)))
        both("unchanged re-run, hadal run (temporary server)",
             lambda c: hadal(c, "run", str(raw), "--store", store(c)))
        both("unchanged re-run, hadal run (server up)",
             lambda c: hadal(c, "run", str(raw), "--store", store(c), server_up=True))
        both("unchanged re-run, hadal run --flow (server up)",
             lambda c: hadal(c, "run", str(raw), "--store", store(c), "--flow", server_up=True))
        both("unchanged stage, hadal stage landing (server up)",
             lambda c: hadal(c, "stage", "landing", str(raw), "--store", store(c), server_up=True))
        both("unchanged stage, hadal stage landing --flow (server up)",
             lambda c: hadal(c, "stage", "landing", str(raw), "--store", store(c), "--flow", server_up=True))
        t_prefect = min(_timed_proc([py, "-c", "from prefect import flow; flow(lambda: 1)()"],
                                    {**os.environ, "PREFECT_API_URL": api}) for _ in range(2))
        t_import = min(_timed_proc([py, "-c", "import hadal.settings"], {**os.environ, "PYTHONPATH": str(codes["now"])})
                       for _ in range(2))
        print(f"reference: a trivial Prefect flow run against the server, fresh process: {t_prefect:.2f} s; "
              f"importing every stage (hadal.settings): {t_import:.2f} s")
        server.terminate()
        server.wait(30)
    finally:
        shutil.rmtree(work, ignore_errors=True)


def cold_full_dives(n: int, codes: list[str], old: str, hadal, work: Path, raw: Path) -> None:
    """``n`` cold full dives (a fresh store each) per code and Prefect setting, the codes alternating run by run (so a
    machine that slows down or speeds up meanwhile affects both alike); each run, then per code the mean and range,
    and the ratio of the means."""
    for server_up, what in ((False, "temporary server"), (True, "long-running server")):
        times: dict[str, list[float]] = {c: [] for c in codes}
        for i in range(n):
            for code in codes:
                st = work / f"store-cold-{code}-{int(server_up)}-{i}"
                times[code].append(hadal(code, "run", str(raw), "--store", str(st), server_up=server_up))
                shutil.rmtree(st, ignore_errors=True)
            print(f"  cold full dive ({what}) run {i + 1}: " + ", ".join(f"{c} {times[c][-1]:.1f} s" for c in codes),
                  flush=True)
        mean = {c: sum(v) / len(v) for c, v in times.items()}
        print(f"cold full dive, {what}, {n} alternating runs: " + "; ".join(
            f"{c} mean {mean[c]:.1f} s (range {min(times[c]):.1f}-{max(times[c]):.1f})" for c in codes)
            + f"; speed-up {mean[old] / mean['now']:.2f}x", flush=True)


def _timed_proc(cmd: list[str], env: dict[str, str]) -> float:
    import subprocess

    t0 = time.perf_counter()
    subprocess.run(cmd, env=env, capture_output=True, timeout=600)
    return time.perf_counter() - t0


if __name__ == "__main__":
    if "--cli" in sys.argv:
        ap = argparse.ArgumentParser(description="hadal run/stage through the CLI, this tree vs a git revision")
        ap.add_argument("--cli", default="HEAD", help="git revision to compare with")
        ap.add_argument("--raw", help="an existing sample dive directory (default: generate one)")
        ap.add_argument("--small", action="store_true")
        ap.add_argument("--cold-runs", type=int, default=3,
                        help="alternating cold full dives per code, with a temporary and with a long-running server")
        cli_compare(ap.parse_args())
    else:
        main()
