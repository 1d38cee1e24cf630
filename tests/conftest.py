"""Shared fixtures. Keep heavy state (Prefect, matplotlib caches) in temporary directories."""

from __future__ import annotations

import os
import tempfile
from pathlib import Path

import pytest

_TMP = Path(tempfile.mkdtemp(prefix="hadal-tests-"))
os.environ.setdefault("MPLCONFIGDIR", str(_TMP / "mpl"))
os.environ.setdefault("PREFECT_HOME", str(_TMP / "prefect"))
os.environ.setdefault("PREFECT_SERVER_ANALYTICS_ENABLED", "false")
os.environ.setdefault("PREFECT_LOGGING_LEVEL", "WARNING")
os.environ.setdefault("MPLBACKEND", "Agg")

REPO = Path(__file__).resolve().parents[1]
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


@pytest.fixture(scope="session")
def small_dive(tmp_path_factory) -> Path:
    """The seeded small sample dive (``hadal synth --small``), generated once per test session (~10 s).

    Set ``HADAL_SAMPLE_SMALL`` to an existing one to skip generation while iterating.
    """
    pre = os.environ.get("HADAL_SAMPLE_SMALL")
    if pre and (Path(pre) / "truth.json").is_file():
        return Path(pre)
    from hadal.synth import generate_dive

    return generate_dive(tmp_path_factory.mktemp("sample") / "haidou-small", small=True)


@pytest.fixture(scope="session")
def small_run(small_dive, tmp_path_factory):
    """Every stage run on the small sample dive (Prefect-free), once per session: ``(ctx, products)``."""
    import warnings

    from hadal.pipeline import make_context, run_pipeline

    ctx = make_context(small_dive, tmp_path_factory.mktemp("store"))
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        products = run_pipeline(ctx)
    return ctx, products


@pytest.fixture(scope="session")
def takuyo(shared_data):
    """The real Takuyo laser raster (0.10 m) as a local metric depth grid (:func:`hadal.landing.testing.read_takuyo`)."""
    from hadal.landing.testing import TAKUYO_RASTER, read_takuyo

    path = shared_data / TAKUYO_RASTER
    if not path.is_file():
        pytest.skip(f"{path} not present")
    return read_takuyo(path)
