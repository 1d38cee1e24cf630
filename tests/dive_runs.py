"""Running whole dives in tests: a dive directory made of real files (``hadal init`` as a user runs it) and a quiet
run of every stage. Shared by the real-data suites."""

from __future__ import annotations

import shutil
import warnings
from pathlib import Path
from typing import Any

import pytest


def run_quiet(raw: Path, store: Path) -> Any:
    """Every stage of the dive in ``raw`` into ``store`` (warnings silenced); returns the run context."""
    from hadal.pipeline import make_context, run_pipeline

    ctx = make_context(raw, store)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        run_pipeline(ctx)
    return ctx


def init_dive(shared: Path, tmp_path: Path, *rels: str) -> tuple[Path, Any]:
    """``<tmp_path>/dive`` with the files ``rels`` (relative to ``shared``) in ``raw/``, initialised by ``hadal
    init``'s scan + write; skips the test when a file is not in this copy of the shared data. Returns (dive
    directory, scan result)."""
    from hadal.dive_init import scan_dive_dir, write_init

    raw = tmp_path / "dive"
    (raw / "raw").mkdir(parents=True)
    for rel in rels:
        src = shared / rel
        if not src.is_file():
            pytest.skip(f"{rel} not in this copy of the shared data")
        shutil.copy(src, raw / "raw" / src.name)
    res = scan_dive_dir(raw)
    write_init(res)
    return raw, res
