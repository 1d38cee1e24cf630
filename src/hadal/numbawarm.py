"""numba's one-time start in a process, done ahead of the stages that run compiled kernels.

The first call of any compiled (numba) kernel in a process initialises numba's CPU target (its LLVM context and
registries): about 0.35 s of CPU (measured, 2-core machine), paid again by every stage process that calls a kernel
first. :func:`first_call` pays it once in the process that forks the stage processes (a stage's ``warm_imports``
entry ``"hadal.numbawarm:first_call"``, run while Prefect's server boots: :func:`hadal.childproc.warm`), so the forked
ones inherit an initialised numba. Its kernel is serial: no parallel region starts, which would forbid the later
forks (:func:`hadal.stage_process.can_fork_ahead`).
"""

from __future__ import annotations

import numpy as np
from numba import njit


@njit(cache=True, nogil=True)
def _total(a):  # pragma: no cover - compiled
    s = 0.0
    for v in a:
        s += v
    return s


def first_call() -> None:
    """Initialise numba in this process by one call of a small cached serial kernel (module doc)."""
    _total(np.ones(2))
