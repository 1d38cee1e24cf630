"""Which code made a product: hadal's version and git commit, the command line and the versions of the libraries
that computed its numbers. The one place this is computed (the store's manifests and the NetCDF attributes read
it); the code a process runs is the code it imported, so each value is computed once per process."""

from __future__ import annotations

import functools
import subprocess
import sys
from pathlib import Path
from typing import Any

from hadal import __version__

#: libraries whose versions computed the numbers of a product (manifest ``software.libraries``)
PROVENANCE_LIBRARIES: tuple[str, ...] = ("numpy", "scipy", "pandas", "xarray", "gsw", "open3d", "prefect", "pyproj",
                                         "numba")


def _git(*args: str) -> str | None:
    """``git <args>`` in hadal's source directory (stdout stripped), ``None`` outside a checkout or without git."""
    src = Path(__file__).resolve().parent
    try:
        return subprocess.run(["git", "-C", str(src), *args], capture_output=True, text=True, timeout=5,
                              check=True).stdout.strip()
    except (OSError, subprocess.SubprocessError):
        return None


@functools.lru_cache(maxsize=1)
def git_commit() -> str | None:
    """The full git commit of hadal's source tree when it is a checkout, else ``None``."""
    return _git("rev-parse", "HEAD") or None


@functools.lru_cache(maxsize=1)
def code_version() -> str:
    """hadal's version plus the git commit of the source tree when it is a checkout (``+g<sha>[.dirty]``)."""
    sha = _git("rev-parse", "--short=12", "HEAD")
    dirty = _git("status", "--porcelain", "--untracked-files=no", "--", ".")
    if not sha or dirty is None:
        return __version__
    return f"{__version__}+g{sha}{'.dirty' if dirty else ''}"


def software_provenance() -> dict[str, Any]:
    """What computed a product: the command line, hadal's version and git commit, and library versions
    (distribution metadata, so open3d/prefect are not imported; ``null`` when not installed)."""
    from importlib import metadata as _md

    libs: dict[str, str | None] = {}
    for name in PROVENANCE_LIBRARIES:
        libs[name] = None
        for dist in (name, f"{name}-cpu"):  # open3d is also distributed as open3d-cpu
            try:
                libs[name] = _md.version(dist)
                break
            except _md.PackageNotFoundError:
                continue
    return {"command": [Path(sys.argv[0]).name, *sys.argv[1:]] if sys.argv and sys.argv[0] else [],
            "hadal_version": __version__, "git_commit": git_commit(), "python": sys.version.split()[0],
            "libraries": libs}
