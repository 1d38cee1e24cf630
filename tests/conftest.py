"""Shared fixtures. Keep heavy state (Prefect, matplotlib caches) in temporary directories."""

from __future__ import annotations

import os
import sys
import tempfile
from pathlib import Path

import pytest

_TMP = Path(tempfile.mkdtemp(prefix="hadal-tests-"))
# each pytest-xdist worker (``make test`` runs ``-n``) gets its own Prefect home and matplotlib cache: the
# workers inherit the controller's environment, so ``setdefault`` alone would make them share one
_set = os.environ.__setitem__ if os.environ.get("PYTEST_XDIST_WORKER") else os.environ.setdefault
_set("MPLCONFIGDIR", str(_TMP / "mpl"))
_set("PREFECT_HOME", str(_TMP / "prefect"))
os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
os.environ.setdefault("PREFECT_LOGGING_LEVEL", "WARNING")
os.environ.setdefault("MPLBACKEND", "Agg")

REPO = Path(__file__).resolve().parents[1]
# tests mirror src/ in folders without __init__.py (unit/<package>, robustness, realdata, integration): each folder
# on sys.path (after this one), so a test module reuses another's helpers by its unique name from any folder
for _folder in sorted({str(t.parent) for t in Path(__file__).resolve().parent.glob("*/**/test_*.py")}):
    if _folder not in sys.path:
        sys.path.append(_folder)
SHARED_DATA = Path(os.environ.get("HADAL_SHARED_DATA", REPO.parent / "shared" / "data"))


@pytest.fixture(scope="session")
def shared_data() -> Path:
    """``../shared/data`` (real reference data); tests using it skip cleanly when it is absent."""
    if not SHARED_DATA.is_dir():
        pytest.skip(f"shared reference data not found at {SHARED_DATA}")
    return SHARED_DATA


@pytest.fixture(scope="session")
def shared_cnv(shared_data):
    """``read(rel)``: the Sea-Bird .cnv ``../shared/data/<rel>`` read with :func:`hadal.ingest.cnv.read_cnv` (its
    warnings silenced); the test skips cleanly when the file is absent."""
    import warnings

    from hadal.ingest.cnv import read_cnv

    def read(rel: str):
        p = shared_data / rel
        if not p.is_file():
            pytest.skip(f"{p} not present")
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return read_cnv(p)

    return read


@pytest.fixture(scope="session")
def prefect_harness():
    """ONE temporary Prefect API (sqlite in PREFECT_HOME under tmp) for every test that runs a flow (opt-in)."""
    from prefect.testing.utilities import prefect_test_harness

    with prefect_test_harness(server_startup_timeout=120):
        yield


def built_once(tmp_path_factory, name: str, build) -> Path:
    """``build(directory)`` run once per test run, shared by every pytest-xdist worker: the first worker to
    get the lock builds into ``<the run's temp root>/<name>``, the others wait for it and reuse the result
    (which the tests must only read: copy it to change it). Without xdist: a fresh directory, built once."""
    if not os.environ.get("PYTEST_XDIST_WORKER"):
        target = tmp_path_factory.mktemp(name)
        build(target)
        return target
    import fcntl
    import shutil

    root = tmp_path_factory.getbasetemp().parent  # common to the workers of this run
    target = root / name
    with open(root / f"{name}.lock", "w") as lock:
        fcntl.flock(lock, fcntl.LOCK_EX)
        if not (root / f"{name}.done").is_file():
            shutil.rmtree(target, ignore_errors=True)
            target.mkdir()
            build(target)
            (root / f"{name}.done").touch()
    return target


@pytest.fixture(scope="session")
def small_dive(tmp_path_factory) -> Path:
    """The seeded small sample dive (``hadal synth --small``), generated once per test run (~10 s), shared
    by the xdist workers: read it, or copy it to change it.

    Set ``HADAL_SAMPLE_SMALL`` to an existing one to skip generation while iterating.
    """
    pre = os.environ.get("HADAL_SAMPLE_SMALL")
    if pre and (Path(pre) / "truth.json").is_file():
        return Path(pre)
    from hadal.synth import generate_dive

    return built_once(tmp_path_factory, "sample", lambda d: generate_dive(d / "haidou-small", small=True)) \
        / "haidou-small"


@pytest.fixture(scope="session")
def small_run(small_dive, tmp_path_factory):
    """Every stage run on the small sample dive (Prefect-free), once per test run and shared by the xdist
    workers (read-only: copy the store to change it): ``(ctx, {product: the version this run published})``."""
    import warnings

    from hadal.pipeline import all_products, make_context, run_pipeline

    def build(store: Path) -> None:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            run_pipeline(make_context(small_dive, store))

    ctx = make_context(small_dive, built_once(tmp_path_factory, "store", build))
    ctx.pin_existing(all_products())  # the store holds exactly the one run's versions
    return ctx, dict(ctx.pins)


@pytest.fixture(scope="session")
def takuyo(shared_data):
    """The real Takuyo laser raster (0.10 m) as a local metric depth grid (:func:`landing_fixtures.read_takuyo`)."""
    from landing_fixtures import TAKUYO_RASTER, read_takuyo

    path = shared_data / TAKUYO_RASTER
    if not path.is_file():
        pytest.skip(f"{path} not present")
    return read_takuyo(path)

