"""Memory and work budget: stages estimate what a configuration will cost *before* allocating it.

A parameter such as ``derive.profile_bin_dbar: 1e-4`` or ``match.heading_step_deg: 1e-5`` is valid on its
own but would need tens of GiB or hours. Each stage computes the bytes (and, for searches, the number of
evaluations) its configuration implies and calls :func:`check_memory` / :func:`check_work`, which raise a
one-line :class:`hadal.errors.ConfigError` naming the setting, the estimate and the limit::

    derive.profile_bin_dbar = 0.0001 would need 12.3 GiB for the profile (limit 11.7 GiB): use a larger
    derive.profile_bin_dbar or raise resources.max_memory_gb

The limits are the ``resources`` section of ``config/pipeline.yaml``
(:class:`hadal.settings.resources.ResourcesParams`): by default ``memory_fraction`` (0.5) of the memory this process
can have (:func:`machine_memory_bytes`: physical memory, a cgroup limit, what ``RLIMIT_AS`` leaves), or an explicit
``max_memory_gb``. Readers check the same limit on the stream as they decode (:class:`DecodeBudget`, decoded bytes
times their working copies).
"""

from __future__ import annotations

import math
import os
from typing import TYPE_CHECKING, Any

from hadal.errors import ConfigError
from hadal.settings.resources import GIB, ResourcesParams

if TYPE_CHECKING:
    from hadal.settings import PipelineConfig

def parallel_stages(config: Any) -> int:
    """How many stages of one dive may run at once: ``resources.parallel_stages``, else the CPU cores (>= 2).

    On a 2-core machine two CPU-bound stages fill it; a third only slows the DTM chain (dtm -> suitability ->
    match), the run's longest: measured on the sample dive, 49 s with two at once against 55 s unlimited."""
    n = resources_of(config).parallel_stages
    return int(n) if n is not None else max(2, os.cpu_count() or 2)


def _cgroup_limit_bytes() -> int | None:
    """The memory limit of this process's cgroup (v2 ``memory.max``, v1 ``memory.limit_in_bytes``), if any."""
    for f in ("/sys/fs/cgroup/memory.max", "/sys/fs/cgroup/memory/memory.limit_in_bytes"):
        try:
            with open(f) as fh:
                text = fh.read().strip()
        except OSError:
            continue
        if text.isdigit() and int(text) < (1 << 60):
            return int(text)
    return None


def _address_space_left_bytes() -> int | None:
    """What ``RLIMIT_AS`` (a ``ulimit -v`` cap) leaves this process: the soft limit minus its address space now."""
    try:
        import resource

        soft = resource.getrlimit(resource.RLIMIT_AS)[0]
        if soft == resource.RLIM_INFINITY:
            return None
        import psutil

        return max(int(soft) - int(psutil.Process().memory_info().vms), 0)
    except Exception:  # pragma: no cover - no resource module / psutil
        return None


def machine_memory_bytes() -> int:
    """The memory this process can have (bytes): physical memory (psutil; 8 GiB when it cannot tell), lowered to
    the cgroup's memory limit (a container started with ``--memory 4g``) and to what ``RLIMIT_AS`` leaves (a run
    under ``ulimit -v``), so a budget computed from it holds under the cap the process actually runs in."""
    try:
        import psutil

        total = int(psutil.virtual_memory().total)
    except Exception:  # pragma: no cover - psutil missing or unsupported platform
        total = 8 * GIB
    caps = [c for c in (_cgroup_limit_bytes(), _address_space_left_bytes()) if c is not None]
    return min([total, *caps])


def resources_of(config: Any) -> ResourcesParams:
    """The ``resources`` section of a :class:`hadal.settings.PipelineConfig` (defaults when absent)."""
    r = getattr(config, "resources", None)
    return r if isinstance(r, ResourcesParams) else ResourcesParams()


def memory_limit_bytes(config: PipelineConfig | ResourcesParams | None = None) -> int:
    """The memory budget (bytes) of one stage under ``config`` (a PipelineConfig or its ``resources``)."""
    r = config if isinstance(config, ResourcesParams) else resources_of(config)
    if r.max_memory_gb is not None:
        return int(r.max_memory_gb * GIB)
    return int(r.memory_fraction * machine_memory_bytes())


def work_limit(config: PipelineConfig | ResourcesParams | None = None) -> float:
    r = config if isinstance(config, ResourcesParams) else resources_of(config)
    return float(r.max_match_evaluations)


def format_bytes(n: float) -> str:
    """``12.3 GiB`` / ``512 MiB`` / ``3 KiB`` (binary units)."""
    if not math.isfinite(n):
        return "an unbounded amount of memory"
    for unit, size in (("TiB", GIB * 1024), ("GiB", GIB), ("MiB", 1024 ** 2), ("KiB", 1024)):
        if n >= size:
            return f"{n / size:.3g} {unit}" if n / size < 1000 else f"{n / size:,.0f} {unit}"
    return f"{int(n)} B"


def _setting_text(setting: str | None, value: Any) -> str:
    if setting is None:
        return "this configuration"
    return f"{setting} = {value:g}" if isinstance(value, float) else (f"{setting} = {value}" if value is not None
                                                                      else setting)


def check_memory(what: str, bytes_needed: float, limit_bytes: float, *, setting: str | None = None,
                 value: Any = None, advice: str | None = None) -> None:
    """Raise a one-line :class:`ConfigError` when ``bytes_needed`` exceeds ``limit_bytes``.

    ``what`` names the allocation ("the profile", "the DTM (3,000 x 2,000 cells x 8 layers)"), ``setting`` /
    ``value`` the configuration that caused it (``derive.profile_bin_dbar``, ``1e-4``), ``advice`` what to change
    (default: the setting, or ``resources.max_memory_gb``).
    """
    if not (bytes_needed > limit_bytes) and math.isfinite(bytes_needed):
        return
    fix = advice or (f"change {setting} or raise resources.max_memory_gb" if setting
                     else "raise resources.max_memory_gb")
    msg = (f"{_setting_text(setting, value)} would need {format_bytes(bytes_needed)} for {what} "
           f"(limit {format_bytes(limit_bytes)}): {fix}")
    raise ConfigError(" ".join(msg.split()))


def check_work(what: str, evaluations: float, limit: float, *, setting: str | None = None, value: Any = None,
               advice: str | None = None) -> None:
    """Raise a one-line :class:`ConfigError` when a search of ``evaluations`` steps exceeds ``limit``."""
    if not (evaluations > limit) and math.isfinite(evaluations):
        return
    fix = advice or (f"change {setting} or raise resources.max_match_evaluations" if setting
                     else "raise resources.max_match_evaluations")
    ev = f"{evaluations:.3g}" if math.isfinite(evaluations) else "unbounded"
    msg = (f"{_setting_text(setting, value)} would need {ev} evaluations for {what} "
           f"(limit {limit:.3g}): {fix}")
    raise ConfigError(" ".join(msg.split()))


def finite_positive(name: str, value: Any) -> float:
    """``value`` as a finite float > 0, else a one-line ConfigError naming ``name``."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{name} must be a number, got {value!r}") from None
    if not math.isfinite(v) or v <= 0:
        raise ConfigError(f"{name} must be a finite number > 0, got {value!r}")
    return v


class DecodeBudget:
    """One memory budget for a reader, checked on the stream as it decodes (compressed inputs have no trustworthy
    size, and a header's counts are claims): the reader calls :meth:`hold` with the bytes its decoded arrays hold
    (their capacity, before growing them), and the budget counts them ``copies`` times - the working copies the
    reader and its first consumer make of them (float64 conversions, masks, a DataFrame), measured per reader.
    Past ``limit_bytes`` (default :func:`memory_limit_bytes`: the machine, cgroup or ``RLIMIT_AS`` cap) it raises
    a one-line :class:`hadal.errors.InputError` naming the file, what was decoded so far and the limit::

        ctd.cnv.xz: decoding it needs more than 1.95 GiB (8.1e+07 rows of 4 values so far, counted with their
        working copies; limit 1.95 GiB): split the file or raise resources.max_memory_gb
    """

    def __init__(self, path: Any, what: str, *, copies: float = 1.0, limit_bytes: float | None = None):
        self.path, self.what, self.copies = path, what, float(copies)
        self.limit = float(memory_limit_bytes(None) if limit_bytes is None else limit_bytes)

    def hold(self, nbytes: float, so_far: str = "", *, held: float = 0.0) -> None:
        """Refuse when ``nbytes`` of decoded arrays (x ``copies``) exceed the limit; ``so_far`` says what they are.
        ``held`` is memory already held by the same read and counted elsewhere (bytes, its copies included: what a
        reader keeps across records while it decodes the next one), added to the need."""
        need = float(nbytes) * self.copies + float(held)
        if need <= self.limit and math.isfinite(need):
            return
        from hadal.errors import InputError

        detail = f"{so_far}, " if so_far else ""
        raise InputError(f"{self.path}: decoding this {self.what} needs more than {format_bytes(need)} ({detail}"
                         f"counted with its working copies; limit {format_bytes(self.limit)}): split the file, "
                         "decimate it, or raise resources.max_memory_gb")
