"""Confinement of what the grid readers open (issue 45): no file outside the dive, no network, no external storage.

GDAL and HDF5 follow references a file makes to other files: a GDAL VRT names its source rasters (any path, a
``/vsicurl/`` URL, ``/vsis3/`` bucket, ``http://`` address or a driver connection string such as ``NETCDF:...``);
an HDF5/netCDF-4 dataset may keep its values in *external* raw files (``H5Pset_external``) or be a *virtual*
dataset mapping other HDF5 files. Left alone, a prior grid listed in ``dive.yaml`` could make hadal read a file
outside the dive (and publish it as the dive's DTM, with a manifest naming only the VRT), or make HTTP requests
from the processing host (server-side request forgery).

* :func:`check_gdal_file` reads a VRT's XML *before* GDAL opens it (bounded size, no DTD/entities) and refuses, in
  one line naming the file and the reference, any source that is not a plain path resolving (``..`` and symlinks
  resolved) inside the confinement root: the dive directory (the nearest directory above the file holding
  ``dive.yaml``, :func:`dive_root_of`), else the file's own directory. Nested VRTs are checked the same way.
* :func:`gdal_env` opens GDAL with network access off (GDAL configuration options, `GDAL configuration options
  <https://gdal.org/user/configoptions.html>`_): ``/vsicurl/`` and every network file system derived from it
  consider no file to exist (``CPL_VSIL_CURL_ALLOWED_EXTENSIONS``), HTTP requests of the HTTP/WMS drivers go to a
  closed loopback proxy with no retry, VRT Python pixel functions are off and no directory is listed on open.
  It is the second line: a reference the XML check let through still reaches no server.
* after opening, :func:`check_opened_files` checks every file GDAL says the dataset uses (``GetFileList``:
  the VRT's sources, sidecar ``.aux.xml``/``.ovr``/world files) against the same root.
* :func:`check_hdf5_self_contained` refuses an HDF5/netCDF-4 file with a dataset stored in external files or a
  virtual dataset before any value is read (h5py, ``Dataset.external`` / ``Dataset.is_virtual``): hadal reads only
  what is inside the file the dive lists, so its manifest's SHA-256 covers every byte read.
* :func:`files_read` is the list of files a grid read touches (the file and, for a VRT, its sources): the stages
  put all of them in the manifest.
"""

from __future__ import annotations

import contextlib
import os
import re
from pathlib import Path
from typing import Any

from hadal.errors import InputError

__all__ = ["GDAL_SAFE_OPTIONS", "ConfinementError", "check_gdal_file", "check_hdf5_self_contained", "check_opened_files",
           "dive_root_of", "files_read", "gdal_env", "is_vrt"]

#: GDAL configuration options of every hadal GDAL open: no network, no Python, no directory listing, a 64 MB
#: block cache. The proxy is
#: a closed loopback port (discard, 9): an HTTP request of a driver that does not honour the vsicurl option fails
#: at once on the processing host and reaches no other server.
GDAL_SAFE_OPTIONS: dict[str, str | int] = {
    "CPL_VSIL_CURL_ALLOWED_EXTENSIONS": ".hadal-network-off",
    "GDAL_HTTP_PROXY": "http://127.0.0.1:9",
    "GDAL_HTTPS_PROXY": "http://127.0.0.1:9",
    "GDAL_HTTP_MAX_RETRY": "0",
    "GDAL_HTTP_TIMEOUT": "1",
    "GDAL_HTTP_CONNECTTIMEOUT": "1",
    "GDAL_VRT_ENABLE_PYTHON": "NO",
    "GDAL_DISABLE_READDIR_ON_OPEN": "EMPTY_DIR",
    "CPL_VSIL_CURL_USE_HEAD": "NO",
    # GDAL's block cache (default 5 % of the machine's memory) is a working copy no read budget would see
    "GDAL_CACHEMAX": 64,
}

#: largest VRT read (a VRT mosaicking thousands of tiles is a few MB)
MAX_VRT_BYTES = 16 << 20
#: deepest chain of VRTs naming VRTs
MAX_VRT_DEPTH = 8
#: VRT elements that name a file GDAL opens
_FILE_TAGS = ("SourceFilename", "SourceDataset", "Filename")
#: a GDAL virtual file system, URL or driver connection string (``/vsicurl/``, ``http://``, ``NETCDF:"f":z``)
_NOT_A_PATH = re.compile(r"^\s*(/vsi|\\vsi|[A-Za-z][A-Za-z0-9_+.-]*:(?![\\/]))|://|^\s*[A-Za-z0-9_]+:", re.I)
_REMOTE = re.compile(r"/vsi[a-z0-9_]+|[a-z][a-z0-9+.-]*://", re.I)


class ConfinementError(InputError):
    """A file refers to data outside the dive directory, to the network or to external storage (one line)."""


def dive_root_of(path: str | Path) -> Path:
    """The confinement root of a raw file: the nearest directory above it holding ``dive.yaml`` (the dive
    directory), else the file's own directory (resolved)."""
    p = Path(path).resolve()
    for d in list(p.parents)[:64]:
        if (d / "dive.yaml").is_file():
            return d
    return p.parent


def _inside(q: Path, root: Path) -> bool:
    try:
        q.relative_to(root)
    except ValueError:
        return False
    return True


def is_vrt(path: str | Path) -> bool:
    """The file is a GDAL VRT, by GDAL's own test (``<VRTDataset`` in its first bytes; VRTDataset::Identify)."""
    try:
        with open(path, "rb") as fh:
            head = fh.read(8192)
    except OSError:
        return False
    return b"<VRTDataset" in head


def _parse_vrt(p: Path) -> Any:
    import xml.etree.ElementTree as ET

    if p.stat().st_size > MAX_VRT_BYTES:
        raise ConfinementError(f"{p}: GDAL VRT is {p.stat().st_size:,} bytes (limit {MAX_VRT_BYTES:,})")
    data = p.read_bytes()
    if b"<!DOCTYPE" in data or b"<!ENTITY" in data:
        raise ConfinementError(f"{p}: GDAL VRT declares a DTD or entities: refused (a VRT needs neither)")
    try:
        return ET.fromstring(data)
    except ET.ParseError as exc:
        raise ConfinementError(f"{p}: not a readable GDAL VRT ({exc})") from None


def _vrt_sources(p: Path, root: Path) -> list[Path]:
    """The files VRT ``p`` names, each checked (module docstring); one-line InputError for the first refused."""
    tree = _parse_vrt(p)
    out: list[Path] = []
    for el in tree.iter():
        if str(el.tag).lower() == "pixelfunctionlanguage" and (el.text or "").strip().lower() == "python":
            raise ConfinementError(f"{p}: GDAL VRT runs Python pixel-function code: refused")
        for value in [el.text or "", *el.attrib.values()]:
            if _REMOTE.search(value) and el.tag not in _FILE_TAGS:
                raise ConfinementError(f"{p}: GDAL VRT refers to {value.strip()[:200]!r}, a network or virtual file "
                                 "system: hadal reads only files inside the dive directory")
        if el.tag not in _FILE_TAGS:
            continue
        name = (el.text or "").strip()
        if not name:
            continue
        if _NOT_A_PATH.search(name):
            raise ConfinementError(f"{p}: GDAL VRT source {name[:200]!r} is a URL, virtual file system or driver "
                             "connection string, not a file: hadal reads only files inside the dive directory "
                             "(no network access)")
        rel = el.attrib.get("relativeToVRT", "0").strip() == "1"
        q = Path(name)
        if not q.is_absolute():
            q = (p.parent if rel else Path.cwd()) / q
        q = q.resolve()
        if not _inside(q, root):
            raise ConfinementError(f"{p}: GDAL VRT source {name[:200]!r} resolves to {q}, outside the dive directory "
                             f"{root}: refused (copy the raster into the dive and list it there)")
        out.append(q)
    return out


def check_gdal_file(path: str | Path, root: str | Path | None = None) -> list[Path]:
    """Check a raster GDAL is about to open (module docstring) and return every file the read will touch: the
    file itself, then the sources of a VRT (recursively, each once). ``root``: the confinement root (default
    :func:`dive_root_of`)."""
    p = Path(path).resolve()
    r = Path(root).resolve() if root is not None else dive_root_of(p)
    if not _inside(p, r):
        raise ConfinementError(f"{path}: resolves to {p}, outside the dive directory {r}")
    seen: list[Path] = [p]
    todo = [(p, 0)]
    while todo:
        f, depth = todo.pop()
        if not f.is_file() or not is_vrt(f):
            continue
        if depth >= MAX_VRT_DEPTH:
            raise ConfinementError(f"{path}: GDAL VRTs nested more than {MAX_VRT_DEPTH} deep")
        for q in _vrt_sources(f, r):
            if q not in seen:
                seen.append(q)
                todo.append((q, depth + 1))
    return seen


def check_opened_files(path: str | Path, files: list[str], root: str | Path | None = None) -> None:
    """Every file GDAL reports for an opened dataset (``dataset.files``) resolves inside the root."""
    r = Path(root).resolve() if root is not None else dive_root_of(path)
    for f in files:
        if _REMOTE.search(str(f)):
            raise ConfinementError(f"{path}: GDAL would read {str(f)[:200]!r} (network or virtual file system): refused")
        q = Path(f).resolve()
        if not _inside(q, r):
            raise ConfinementError(f"{path}: GDAL would read {q}, outside the dive directory {r}: refused")


def files_read(path: str | Path, root: str | Path | None = None) -> list[Path]:
    """The files a grid read of ``path`` touches (the file and a VRT's sources), for the manifest; never raises
    (a file that fails :func:`check_gdal_file` is refused by the reader, and only ``path`` is listed)."""
    try:
        return check_gdal_file(path, root)
    except (InputError, OSError):
        return [Path(path)]


@contextlib.contextmanager
def gdal_env():
    """``rasterio.Env`` with :data:`GDAL_SAFE_OPTIONS` (network off, no Python, no directory listing)."""
    import rasterio

    with rasterio.Env(**GDAL_SAFE_OPTIONS) as env:
        yield env


def check_hdf5_self_contained(path: str | Path) -> None:
    """One-line :class:`InputError` when an HDF5/netCDF-4 file keeps a dataset's values outside itself (external
    raw files, ``H5Pset_external``, or a virtual dataset), checked with h5py before any value is read. Other
    files (netCDF classic, not HDF5) pass."""
    p = Path(path)
    try:
        with open(p, "rb") as fh:
            if fh.read(8) != b"\x89HDF\r\n\x1a\n":
                return
    except OSError:
        return
    import h5py

    found: list[str] = []

    def visit(name: str, obj: Any) -> None:
        if found or not isinstance(obj, h5py.Dataset):
            return
        ext = obj.external
        if ext:
            found.append(f"variable {name!r} keeps its values in external file(s) "
                         f"{', '.join(repr(os.fsdecode(e[0])) for e in ext[:3])} (HDF5 external storage)")
        elif obj.is_virtual:
            srcs = sorted({s.file_name for s in obj.virtual_sources()})
            found.append(f"variable {name!r} is an HDF5 virtual dataset of {', '.join(map(repr, srcs[:3]))}")

    try:
        with h5py.File(p, "r") as h:
            h.visititems(visit)
    except (OSError, ValueError, RuntimeError, KeyError):
        return  # not readable by h5py: the reader reports it
    if found:
        raise ConfinementError(f"{p}: {found[0]}: refused, hadal reads only values stored in the file the dive lists "
                         "(make it self-contained, e.g. 'h5repack' or 'nccopy')")
