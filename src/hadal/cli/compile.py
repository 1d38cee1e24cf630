"""``hadal compile``: the numba kernels compiled into numba's cache."""

from __future__ import annotations

from hadal.cli._common import console


def compile_cmd() -> None:
    """Compile the pipeline's numba kernels into numba's cache (once after installing; make setup runs it)."""
    import time

    from hadal.numbacompile import compile_kernels

    t0 = time.process_time()
    counts = compile_kernels()
    console.print(f"numba kernels: {counts['compiled']} compiled, {counts['loaded']} already cached "
                  f"({time.process_time() - t0:.1f} CPU-s)")
