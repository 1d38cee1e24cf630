"""``hadal compile`` (:mod:`hadal.numbacompile`): the kernels' signatures compiled into numba's cache, loaded by
the next process. (That the table covers what the small sample dive's first run calls is measured by
bench/bench_first_run.py: no kernel compiled in the first run.)"""

from __future__ import annotations

import importlib
import json
import os
import re
import subprocess
import sys
from pathlib import Path

from hadal.numbacompile import SIGNATURES

SRC = Path(__file__).resolve().parents[3] / "src"


def test_every_cached_kernel_module_is_listed_and_every_listed_kernel_is_cached():
    cached = set()
    for f in (SRC / "hadal").rglob("*.py"):
        if re.search(r"^@njit\(.*cache=True", f.read_text(), re.M):
            cached.add(".".join(f.relative_to(SRC).with_suffix("").parts))
    assert cached == set(SIGNATURES)
    for name, kernels in SIGNATURES.items():
        mod = importlib.import_module(name)
        for kernel, sigs in kernels.items():
            disp = getattr(mod, kernel)
            assert type(disp._cache).__name__ == "FunctionCache", kernel  # @njit(cache=True)
            assert sigs and all(isinstance(s, tuple) for s in sigs)


_CHILD = """
import json, sys
from hadal.numbacompile import compile_kernels
print(json.dumps(compile_kernels(sys.argv[1:])))
"""


def test_compile_fills_the_cache_and_the_next_process_loads_it(tmp_path):
    env = {**os.environ, "NUMBA_CACHE_DIR": str(tmp_path), "PYTHONPATH": str(SRC)}
    mods = ["hadal.numbawarm", "hadal.ingest._mcap_kernels"]
    n = sum(len(s) for m in mods for s in SIGNATURES[m].values())

    def run() -> dict[str, int]:
        r = subprocess.run([sys.executable, "-c", _CHILD, *mods], env=env, capture_output=True, text=True,
                           check=True)
        return json.loads(r.stdout.strip().splitlines()[-1])

    assert run() == {"compiled": n, "loaded": 0}
    for m in mods:
        for kernel in SIGNATURES[m]:
            assert list(tmp_path.rglob(f"{m.rsplit('.', 1)[1]}.{kernel}-*.nbi")), kernel
    assert run() == {"compiled": 0, "loaded": n}
