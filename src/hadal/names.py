"""One rule for every name a user gives hadal that becomes a path component: dive ids, product names (the
store's directories) and the components of source paths in ``dive.yaml``.

:func:`check_component` is that rule. It NFC-normalises the name (so two spellings of one name are one name),
then refuses separators, NUL and control characters, dot-names (``.``, ``..``, and for store names any leading
dot: the store's own ``.cache``, ``.lock``, ``.staging-*``, ``.prefect-results``), names longer than a bound
and, for store names, the names of the store's own files (:data:`RESERVED_STORE_NAMES`: a dive id
``catalog.json`` would otherwise turn the store's STAC catalog into a directory) and the suffixes those files
use (``.json``, ``.lock``, ``.tmp``), compared case-insensitively (case-insensitive file systems).
"""

from __future__ import annotations

import unicodedata
from pathlib import Path
from typing import Literal

from hadal.errors import StoreError

#: files and directories the store itself keeps beside dive / product directories (``<store>/catalog.json``,
#: ``<store>/<dive>/dive.json`` and ``stac-item.json``, ``<product>/vNNN/manifest.json``, the caches and locks)
RESERVED_STORE_NAMES = frozenset({
    "catalog.json", "collection.json", "dive.json", "stac-item.json", "manifest.json", "file-sha256.json",
    ".cache", ".lock", ".prefect-results", "lock", "locks", "cache",
})
#: suffixes of the store's own files: no dive id or product name may end with one (a future store file of that
#: kind can never collide with a dive)
RESERVED_STORE_SUFFIXES = (".json", ".lock", ".tmp")
#: longest store name (dive id, product name), in characters
MAX_STORE_NAME = 64
#: longest path component of a user's source path, in UTF-8 bytes (POSIX NAME_MAX)
MAX_PATH_COMPONENT_BYTES = 255
_STORE_CHARS = frozenset("abcdefghijklmnopqrstuvwxyzABCDEFGHIJKLMNOPQRSTUVWXYZ0123456789._-")


def check_component(name: object, what: str = "name", *, kind: Literal["store", "path"] = "store") -> str:
    """The NFC form of ``name`` when it is a safe single path component, else a one-line :class:`StoreError`.

    ``kind="store"`` (dive ids, product names): 1-64 ASCII letters, digits, ``.``, ``_`` or ``-``, starting with a
    letter or digit, no ``..``, not a reserved store name nor ending with a reserved suffix.
    ``kind="path"`` (one component of a source path from ``dive.yaml``): any Unicode text of at most 255 UTF-8
    bytes without ``/``, ``\\``, NUL or control characters, and not ``.`` or ``..``.
    """
    if not isinstance(name, str):
        raise StoreError(f"invalid {what} {name!r}: expected text")
    nfc = unicodedata.normalize("NFC", name)
    if kind == "path":
        return _check_path_component(nfc, what)
    if (not nfc or len(nfc) > MAX_STORE_NAME or not set(nfc) <= _STORE_CHARS or not nfc[0].isalnum()
            or ".." in nfc):
        raise StoreError(f"invalid {what} {name!r}: use 1-{MAX_STORE_NAME} letters, digits, '.', '_' or '-', "
                         "starting with a letter or digit")
    low = nfc.lower()
    if low in RESERVED_STORE_NAMES or low.endswith(RESERVED_STORE_SUFFIXES):
        raise StoreError(f"invalid {what} {name!r}: the name is reserved for the product store's own files "
                         f"({', '.join(sorted(n for n in RESERVED_STORE_NAMES if not n.startswith('.')))} and "
                         f"names ending {', '.join(RESERVED_STORE_SUFFIXES)}); choose another")
    return nfc


def _check_path_component(nfc: str, what: str) -> str:
    bad = next((c for c in nfc if c in "/\\\x00" or unicodedata.category(c) == "Cc"), None)
    if bad is not None:
        raise StoreError(f"invalid {what} {nfc!r}: contains {bad!r} (separators, NUL and control characters are "
                         "not allowed in a file name)")
    if nfc in ("", ".", ".."):
        raise StoreError(f"invalid {what} {nfc!r}: empty, '.' and '..' are not file names")
    if len(nfc.encode("utf-8", "surrogatepass")) > MAX_PATH_COMPONENT_BYTES:
        raise StoreError(f"invalid {what} {nfc[:40]!r}...: longer than {MAX_PATH_COMPONENT_BYTES} bytes")
    return nfc


def check_relative_path(path: object, what: str = "path") -> str:
    """A relative ``/``-separated path whose every component passes :func:`check_component` (``kind="path"``),
    NFC-normalised; absolute paths, ``..``/``.`` components and empty components are a one-line
    :class:`StoreError`."""
    if not isinstance(path, str):
        raise StoreError(f"invalid {what} {path!r}: expected text")
    if path.startswith("/") or "\\" in path:
        raise StoreError(f"invalid {what} {path!r}: must be relative, with '/' separators")
    return "/".join(check_component(c, what, kind="path") for c in path.split("/"))


def record_id(prefix: str, k: int, path: str | Path) -> str:
    """``<prefix><k:02d>_<stem>``: a product file id for the ``k``-th record of a dive (a cast, an underway record),
    from its file name without compression/format suffixes, reduced to ``[A-Za-z0-9_-]``."""
    import re

    stem = Path(path).name
    for ext in (".gz", ".bz2", ".xz", ".cnv", ".hex", ".txt"):
        if stem.lower().endswith(ext):
            stem = stem[: -len(ext)]
    stem = re.sub(r"[^A-Za-z0-9_-]+", "_", stem).strip("_") or prefix
    return f"{prefix}{k:02d}_{stem}"
