"""Compile the pipeline's numba kernels into numba's on-disk cache ahead of the first run (``hadal compile``).

Every compiled kernel is ``@njit(cache=True)``: compiled on its first call with a new argument type signature and
saved to numba's cache, loaded from it by later processes. :func:`compile_kernels` compiles each kernel for the type
signatures the pipeline's stages call it with (:data:`SIGNATURES`), so that a first run loads them like any later
run. ``make setup`` runs it; a pip install runs ``hadal compile`` once (as the user who runs the pipeline).

Where numba keeps the cache: ``NUMBA_CACHE_DIR`` when set; else the ``__pycache__`` folder next to the kernel's
module when the user can write there (a venv, an editable install); else the user's cache folder
(``~/.cache/numba``, a read-only site-packages). A cache entry is valid for the kernel's source (content hash) and
this machine's CPU: editing a kernel or moving the install to another CPU type recompiles it on first use.

A kernel missing from the table, or called with a signature it does not list, is still compiled on its first call
(and cached): the table only moves that cost to the install.
"""

from __future__ import annotations

import importlib
import time
from collections.abc import Callable, Iterable
from typing import Any

from numba.core import types as nt


def _a(dtype: Any, ndim: int = 1, layout: str = "C", readonly: bool = False) -> Any:
    return nt.Array(dtype, ndim, layout, readonly=readonly)  # type: ignore[call-overload]


_f4, _f8, _i4, _i8, _u1, _u2, _b1, _c8 = (nt.float32, nt.float64, nt.int32, nt.int64, nt.uint8, nt.uint16,
                                          nt.boolean, nt.complex64)
_F8, _I8, _B1 = _a(_f8), _a(_i8), _a(_b1)
_B1_2, _F4_2 = _a(_b1, 2), _a(_f4, 2)
_RO_U1 = _a(_u1, readonly=True)  # an MCAP chunk's bytes (np.frombuffer of bytes: read-only)

#: module -> kernel -> the argument type signatures the pipeline's stages call it with
SIGNATURES: dict[str, dict[str, tuple[tuple[Any, ...], ...]]] = {
    "hadal.numbawarm": {"_total": ((_F8,),)},
    "hadal.ingest._mcap_kernels": {
        "_u64": ((_RO_U1, _i8),),
        "walk_chunk": ((_RO_U1,),),
        "gather": ((_RO_U1, _I8, _I8),),
    },
    "hadal.grid._kernels": {
        "shifted_cell_sums": ((_F8, _F8, _F8, _f8, _f8, _f8, _i8, _i8, _f8, _b1, _i8),),
        "partition_kernel": ((_I8, _F8, _i8, _i8, _i8, _i8),),
        "_sort_small": ((_F8,),),
        "block_stats_kernel": ((_a(_u2), _F8, _a(_i8, 2), _i8, _i8, _b1, _b1, _i8),),
        "cell_counting_order": ((_I8, _i8),),
        "segment_median_mad": ((_I8, _F8, _I8, _I8, _F8, _F8, _F8, _i8),),
    },
    "hadal.grid._sor_kernels": {
        "knn_mean_distance": ((_F8, _F8, _F8, _F8, _F8, _I8, _i8, _i8, _f8, _f8, _f8, _i8, _F8, _i8),),
        "sor_keep": ((_F8, _f8),),
    },
    "hadal.grid._spike_kernels": {
        "knn_spike_flags_cells": ((_F8, _F8, _F8, _I8, _I8, _i8, _i8, _f8, _f8, _f8, _i8, _f8, _f8, _f8, _B1, _i8),),
    },
    "hadal.navigation.smoother": {
        "_transition": ((_f8, _b1, _f8, _f8),),
        "_rts": ((_F8, _a(_f8, 2), _B1, _F8, _f8, _F8, _a(_f8, 2), _I8, _a(_f8, 2), _a(_f8, 3)),),
    },
    "hadal.landing._kernels": {
        "row_runs": ((_B1_2,),),
        "dilate_rows": ((_I8, _I8, _I8, _i8, _i8, _I8, _I8, _I8, _b1, _i8, _i8),),
        "disc_union": ((_I8, _I8, _F8, _i8, _i8),),
        "any_free": ((_B1_2, _B1_2, _B1_2),),
        "plane_tangent": ((_a(_f4, 2, "A"), _a(_f4, 2, "A"), _f4, _f4, _f4, _f4, _f4, _f4, _B1_2, _F4_2),),
        "times_conj_imaginary": ((_a(_c8, 2), _F4_2, _F4_2, _a(_c8, 2), _a(_c8, 2)),),
        "combine_exclusion": ((_a(_u1, 2), _B1_2, _B1_2, _F4_2, _f4, _u1, _u1, _u1, _B1_2),),
        "squared_edt_into": ((_a(_b1, 2, "A"), _F4_2), (_B1_2, _F4_2)),
        "site_stats": ((_a(_i4, 2), _F4_2, _i8, _f8),),
        "outer_border_of": ((_a(_i4, 2, "A"), _i4),),
        "site_cells_at_least": ((_a(_i4, 2, "A"), _i4, _a(_f4, 2, "A"), _f4),),
    },
}


def compile_kernels(modules: Iterable[str] | None = None,
                    report: Callable[[str, str, float, bool], None] | None = None) -> dict[str, int]:
    """Compile (or load from numba's cache) every kernel of ``modules`` (default: all of :data:`SIGNATURES`) for
    its listed signatures; numba saves what it compiles to its cache. ``report(module, kernel, cpu_s, loaded)``
    after each kernel (``loaded``: every signature came from the cache). Returns ``{"compiled": n, "loaded": m}``
    counted in signatures."""
    counts = {"compiled": 0, "loaded": 0}
    for name in SIGNATURES if modules is None else modules:
        mod = importlib.import_module(name)
        for kernel, sigs in SIGNATURES[name].items():
            disp = getattr(mod, kernel)
            t0 = time.process_time()
            hits = disp.stats.cache_hits.copy()
            for sig in sigs:
                disp.compile(sig)
            loaded = sum((disp.stats.cache_hits - hits).values())
            counts["loaded"] += loaded
            counts["compiled"] += len(sigs) - loaded
            if report is not None:
                report(name, kernel, time.process_time() - t0, loaded == len(sigs))
    return counts


if __name__ == "__main__":  # pragma: no cover - python -m hadal.numbacompile
    print(compile_kernels())
