"""Run one pipeline stage in this process, optionally pausing at a chosen point of the publish (fault injection).

Usage: ``PYTHONPATH=src python tests/malformed/stage_worker.py STAGE RAW_DIR STORE [--pause POINT] [--marker F]
[--go F]``. ``POINT``:

* ``write``:  right after the stage wrote its first product file into the staging directory (no manifest yet);
* ``commit``: after the manifest is written, before the version lock is taken;
* ``rename``: inside the lock, just before the staging directory is renamed to ``vNNN``.

At the pause the worker creates ``--marker`` and waits until ``--go`` exists (without ``--go``: forever, to be
killed). Used by ``tests/robustness/test_fault_injection.py`` (kill -9 mid-publish, concurrent runs).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
import warnings
from pathlib import Path


def _pause(marker: Path | None, go: Path | None) -> None:
    if marker is not None:
        marker.write_text(str(os.getpid()))
    deadline = time.monotonic() + 300
    while time.monotonic() < deadline:
        if go is not None and go.exists():
            return
        time.sleep(0.01)
    sys.exit(3)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("stage")
    ap.add_argument("raw_dir", type=Path)
    ap.add_argument("store", type=Path)
    ap.add_argument("--pause", choices=("write", "commit", "rename"))
    ap.add_argument("--marker", type=Path)
    ap.add_argument("--go", type=Path)
    a = ap.parse_args()

    import hadal.products
    import hadal.products.io
    from hadal.pipeline import make_context, run_stage
    from hadal.store import ProductStore

    hold = lambda: _pause(a.marker, a.go)  # noqa: E731
    if a.pause == "write":
        for mod in (hadal.products, hadal.products.io):
            for fn in ("write_parquet", "write_netcdf"):
                orig = getattr(mod, fn)

                def wrapped(*args, _orig=orig, **kw):
                    out = _orig(*args, **kw)
                    hold()
                    return out
                setattr(mod, fn, wrapped)
    elif a.pause == "commit":
        orig_commit = ProductStore._commit

        def commit(self, *args, **kw):
            hold()
            return orig_commit(self, *args, **kw)
        ProductStore._commit = commit
    elif a.pause == "rename":
        orig_rename = os.rename

        def rename(src, dst, *args, **kw):
            if Path(src).name.startswith(".staging-"):
                hold()
            return orig_rename(src, dst, *args, **kw)
        os.rename = rename

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        out = run_stage(a.stage, make_context(a.raw_dir, a.store))
    for product, pv in out.items():
        print(product, pv.label)


if __name__ == "__main__":
    main()
