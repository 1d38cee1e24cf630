"""Versioned, immutable product store.

Layout::

    <root>/<dive>/<product>/v001/          one immutable version
                               manifest.json
                               <product files>
    <root>/<dive>/<product>/.staging-*/    a version being written (never visible to readers)
    <root>/<dive>/<product>/.lock          advisory lock taken while a version number is chosen

A version is *published* by writing everything into a staging directory beside the versions,
hashing the files, writing ``manifest.json`` last and then renaming the staging directory to the
next free ``vNNN`` under an exclusive lock. ``rename(2)`` of a directory is atomic on POSIX, so a
reader either sees a complete version or none; a process killed mid-publish leaves only a
``.staging-*`` directory, which readers ignore and :meth:`ProductStore.clean_staging` removes.

The manifest records the input files with their SHA-256, the parameters, the code version, the
creation time and the upstream product versions (provenance). Input hashes in a manifest are always computed by
reading the file (never taken from the hash cache, which only serves skip decisions: :meth:`ProductStore.file_sha256`).

Reading is checked (issue 45): a version is used only when its directory is its own place in the store, its
manifest names only regular files inside it, it holds nothing else, and every file's SHA-256 is the one recorded at
publish time (:meth:`ProductStore.check_intact`). Names follow :func:`hadal.names.check_component`; a dive id is
claimed atomically in ``<dive>/dive.json`` before a stage runs (:meth:`ProductStore.claim_dive`).
"""

from __future__ import annotations

import contextlib
import contextvars
import datetime as _dt
import errno
import fcntl
import hashlib
import json
import os
import re
import shutil
import stat
import threading
import time
import uuid
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hadal.errors import StoreError
from hadal.names import check_component, check_relative_path
from hadal.provenance import code_version, software_provenance
from hadal.yamlfile import load_json_bounded

VERSION_RE = re.compile(r"^v(\d{3,})$")
MANIFEST = "manifest.json"
#: per-dive record of the raw directory a dive id belongs to (``<root>/<dive>/dive.json``)
DIVE_IDENTITY = "dive.json"
_HASH_CHUNK = 1 << 20


def validate_name(name: str, what: str = "name") -> str:
    """``name`` (NFC) if it is a safe dive/product name, else a one-line :class:`StoreError`: the one rule of
    :func:`hadal.names.check_component` (1-64 letters, digits, ``.``, ``_``, ``-``; no separators, no dot-names,
    no ``..``, none of the store's own file names such as ``catalog.json`` or ``dive.json``)."""
    return check_component(name, what)


def _is_name(name: str) -> bool:
    """Whether a directory name found in the store is a dive/product name (not a store file, not a staging)."""
    try:
        return check_component(name) == name
    except StoreError:
        return False


def sha256_file(path: str | os.PathLike[str]) -> str:
    """SHA-256 hex digest of a file, read in 1 MiB chunks."""
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        while chunk := fh.read(_HASH_CHUNK):
            h.update(chunk)
    return h.hexdigest()


#: per-store cache of raw-file hashes (``<root>/.cache/file-sha256.json``), see :meth:`ProductStore.file_sha256`
HASH_CACHE = ".cache/file-sha256.json"
#: (resolved path, device, inode, size, mtime_ns, ctime_ns) -> SHA-256 that this process computed by reading the
#: file (never a value taken from the store's cache file: see :meth:`ProductStore.file_sha256`)
_PROCESS_HASHES: dict[tuple, str] = {}
_HASH_LOCK = threading.Lock()
#: the stage run publishing in this context (set by :func:`hadal.pipeline.run_stage`: ``stage``, ``started_utc``,
#: ``t0`` = its ``time.monotonic()`` start, and e.g. the Prefect ``flow_run``/``task_run`` ids); every manifest
#: written in it records ``stage_run`` with ``seconds`` = the stage's time from its start to this publish
STAGE_RUN: contextvars.ContextVar[dict[str, Any] | None] = contextvars.ContextVar("hadal_stage_run", default=None)


def _file_key(path: Path) -> tuple:
    """The identity the hash cache trusts: (path, device, inode, size, mtime_ns, ctime_ns); ctime cannot be set
    from user space, so an in-place edit with the old size and mtime restored still changes the key."""
    st = path.stat()
    return (str(path), st.st_dev, st.st_ino, st.st_size, st.st_mtime_ns, st.st_ctime_ns)


@dataclass(frozen=True)
class ProductVersion:
    """One published, immutable version of a product."""

    dive: str
    product: str
    version: int
    path: Path

    @property
    def label(self) -> str:
        return f"v{self.version:03d}"

    @property
    def manifest_path(self) -> Path:
        return self.path / MANIFEST

    def manifest(self) -> dict[str, Any]:
        """The parsed ``manifest.json`` (bounded: :data:`MANIFEST_MAX_BYTES`, nesting depth); ``OSError`` when it
        cannot be read, ``ValueError`` when it is not a bounded JSON object."""
        if self.manifest_path.is_symlink():
            raise ValueError("manifest.json is a symbolic link")
        data = load_json_bounded(self.manifest_path.read_bytes(), max_bytes=MANIFEST_MAX_BYTES)
        if not isinstance(data, dict):
            raise ValueError("not a JSON object")
        return data

    def file(self, name: str) -> Path:
        """Path of a file of this version; a one-line :class:`StoreError` when it is not there, is not listed in
        the version's manifest, or is not a regular file inside the version directory (a ``..`` name, an absolute
        name or a symbolic link leading anywhere are refused: :func:`confined_file`)."""
        label = f"{self.dive}/{self.product}/{self.label}"
        try:
            listed = {str(f.get("name")) for f in self.manifest().get("files", []) if isinstance(f, dict)}
        except (OSError, ValueError) as exc:
            raise StoreError(f"{label}: unreadable manifest ({exc}); re-run the stage that makes it") from None
        if name not in listed:
            raise StoreError(f"{label} has no file {name!r}")
        return confined_file(self.path, name, label)

    def ref(self) -> dict[str, Any]:
        """Provenance reference recorded in downstream manifests."""
        return {
            "product": self.product,
            "version": self.label,
            "manifest_sha256": sha256_file(self.manifest_path),
        }


@dataclass
class Draft:
    """A version being written. Write files under :attr:`path`; the store publishes on success."""

    path: Path
    dive: str
    product: str
    parameters: dict[str, Any] = field(default_factory=dict)
    inputs: list[Path] = field(default_factory=list)
    upstream: list[ProductVersion] = field(default_factory=list)
    extra: dict[str, Any] = field(default_factory=dict)
    result: ProductVersion | None = None


def _json_default(obj: Any) -> Any:
    if isinstance(obj, Path):
        return str(obj)
    if isinstance(obj, (_dt.datetime, _dt.date)):
        return obj.isoformat()
    if hasattr(obj, "item"):  # numpy scalars
        return obj.item()
    if hasattr(obj, "tolist"):
        return obj.tolist()
    if hasattr(obj, "model_dump"):
        return obj.model_dump(mode="json")
    raise TypeError(f"not JSON serialisable: {type(obj).__name__}")


class ProductStore:
    """Immutable, versioned products under ``root`` (see module docstring)."""

    def __init__(self, root: str | os.PathLike[str]):
        self.root = Path(root)
        self._intact: set[tuple] = set()  # identities (_file_key) of files check_intact hashed and found intact
        self._hashes: dict[str, dict[str, Any]] | None = None  # HASH_CACHE, loaded on first use

    # ---------------------------------------------------------------- raw-file hashes
    def file_sha256(self, path: str | os.PathLike[str], *, verified: bool = False) -> str:
        """SHA-256 of a (raw input) file without re-reading it when it is unchanged.

        The hash is remembered with the file's identity (device, inode, size, mtime, ctime: :func:`_file_key`), in
        this process and in the store (``<root>/.cache/file-sha256.json``), so an unchanged re-run of a dive stats
        its ~280 MB of raw files instead of hashing them for its stage cache keys (the skip decision). A file whose
        identity differs - edited, replaced, touched, copied - is hashed again.

        The store's cache file is an optimisation anyone who can write the store can edit, so it is never proof
        of content: with ``verified=True`` (a manifest being written: :meth:`_write_manifest`) the answer is a
        hash this process computed by reading the file under the same identity, else the file is read now; a
        cache record that disagrees is replaced by the true hash. A poisoned cache entry can therefore change at
        most a skip decision (the stage re-runs or is skipped), never what a manifest records. The cache is best
        effort: an unreadable or unwritable one only costs the hashing."""
        p = Path(path).resolve()
        key = _file_key(p)
        with _HASH_LOCK:
            known = _PROCESS_HASHES.get(key)
            rec: Any = self._hash_records().get(key[0])
        stored = isinstance(rec, dict) and rec.get("stat") == list(key[1:]) and isinstance(rec.get("sha256"), str)
        if known is not None:
            # hashed earlier in this process, perhaps before the store existed (a cold run hashes its inputs
            # before the first product creates the store): remember it in the store now that it can be written
            if (not stored or rec["sha256"] != known) and self.root.is_dir():
                self._remember_hash(key, known)
            return known
        if stored and not verified:
            return rec["sha256"]
        digest = sha256_file(p)
        if _file_key(p) != key:  # changed while it was read: do not remember either state
            return digest
        if not (stored and rec["sha256"] == digest):  # new, or a cache record that lied: write the truth
            self._remember_hash(key, digest)
        with _HASH_LOCK:
            _PROCESS_HASHES[key] = digest
        return digest

    def _hash_records(self) -> dict[str, dict[str, Any]]:
        if self._hashes is None:
            try:
                data = json.loads((self.root / HASH_CACHE).read_text(encoding="utf-8"))
            except (OSError, ValueError):
                data = {}
            self._hashes = data if isinstance(data, dict) else {}
        return self._hashes

    def _remember_hash(self, key: tuple, digest: str) -> None:
        """Add one record to the store's hash cache (merged with what other processes wrote; atomic replace)."""
        f = self.root / HASH_CACHE
        if not self.root.is_dir():  # never create a store just for its cache
            return
        with _HASH_LOCK:
            try:
                f.parent.mkdir(exist_ok=True)
                with open(f.parent / ".lock", "a+") as lock:
                    fcntl.flock(lock, fcntl.LOCK_EX)
                    try:
                        data = json.loads(f.read_text(encoding="utf-8"))
                    except (OSError, ValueError):
                        data = {}
                    if not isinstance(data, dict):
                        data = {}
                    data = {k: v for k, v in data.items() if k == key[0] or Path(k).exists()}  # forget gone files
                    data[key[0]] = {"stat": list(key[1:]), "sha256": digest}
                    tmp = f.with_name(f".{f.name}.{os.getpid()}.{uuid.uuid4().hex[:8]}")
                    tmp.write_text(json.dumps(data, indent=0), encoding="utf-8")
                    os.replace(tmp, f)
                    self._hashes = data
            except OSError:
                pass

    # ---------------------------------------------------------------- reading
    def product_dir(self, dive: str, product: str) -> Path:
        return self.root / validate_name(dive, "dive id") / validate_name(product, "product name")

    def dives(self) -> list[str]:
        if not self.root.is_dir():
            return []
        return sorted(p.name for p in self.root.iterdir() if p.is_dir() and _is_name(p.name))

    def products(self, dive: str) -> list[str]:
        d = self.root / validate_name(dive, "dive id")
        if not d.is_dir():
            return []
        return sorted(p.name for p in d.iterdir() if p.is_dir() and _is_name(p.name) and self.versions(dive, p.name))

    def versions(self, dive: str, product: str) -> list[ProductVersion]:
        """All published versions, oldest first. Staging directories are never listed."""
        d = self.product_dir(dive, product)
        if not d.is_dir():
            return []
        out = []
        for p in d.iterdir():
            m = VERSION_RE.match(p.name)
            if m and p.is_dir() and (p / MANIFEST).is_file():
                out.append(ProductVersion(dive, product, int(m.group(1)), p))
        return sorted(out, key=lambda v: v.version)

    def get(self, dive: str, product: str, version: int | str = "latest") -> ProductVersion:
        """Resolve ``version`` (``"latest"``, ``"v003"``, ``"3"`` or ``3``) to a published version."""
        versions = self.versions(dive, product)
        if not versions:
            raise StoreError(f"no published version of product {product!r} for dive {dive!r} in {self.root}")
        if version in ("latest", None):
            return versions[-1]
        num = version
        if isinstance(version, str):
            m = re.fullmatch(r"v?(\d+)", version)
            if not m:
                raise StoreError(f"invalid version {version!r}: use 'latest', 'vNNN' or a number")
            num = int(m.group(1))
        for v in versions:
            if v.version == num:
                return v
        raise StoreError(f"{dive}/{product} has no version {version!r} (have {', '.join(v.label for v in versions)})")

    def latest(self, dive: str, product: str) -> ProductVersion:
        return self.get(dive, product, "latest")

    def has(self, dive: str, product: str) -> bool:
        return bool(self.versions(dive, product))

    # ---------------------------------------------------------------- dive identity
    def dive_identity(self, dive: str) -> dict[str, Any] | None:
        """The recorded raw directory (``raw_dir``, ``fingerprint``) of ``dive``, or ``None``."""
        f = self.root / validate_name(dive, "dive id") / DIVE_IDENTITY
        try:
            if f.is_symlink():
                raise OSError("a symbolic link")
            rec = load_json_bounded(f.read_bytes(), max_bytes=1 << 20)
        except FileNotFoundError:
            return None
        except (OSError, ValueError) as exc:
            raise StoreError(f"{f}: unreadable dive identity record ({exc}); remove it to re-claim the dive") from None
        return rec if isinstance(rec, dict) else None

    def claim_dive(self, dive: str, raw_dir: str | os.PathLike[str], fingerprint: str, *, check_only: bool = False,
                   update: bool = True) -> list[Path] | None:
        """Record that dive id ``dive`` belongs to ``raw_dir`` (content ``fingerprint``), or refuse.

        A dive id already recorded for another directory is accepted only when the content fingerprint is the
        same (the directory was moved or copied); otherwise a second raw directory with the same dive id would
        mix its products with the first one's, so it is a one-line :class:`StoreError`.

        The check and the write are one atomic step under an exclusive lock on the dive's directory, so of two
        runs claiming one dive id for two raw directories at the same time exactly one wins and the other is
        refused before it publishes anything (:func:`hadal.pipeline.run_stage` claims before a stage runs).
        ``check_only``: refuse a conflicting directory but write nothing. ``update=False`` (before a stage runs):
        write only a new claim; a record this directory may keep (same directory with new content, or the same
        content moved) is rewritten only by the call after a publish, so a failed stage changes nothing.
        Returns ``None`` when nothing was
        written (already ours, or ``check_only``), else the directories this claim created (``[]`` when none):
        :meth:`release_claim` undoes a claim whose stage then published nothing.
        """
        raw = str(Path(raw_dir).resolve())
        if check_only:
            self._check_claim(dive, self.dive_identity(dive), raw, fingerprint)
            return None
        d = self.root / validate_name(dive, "dive id")
        created = [x for x in (d, self.root) if not x.exists()]
        try:
            d.mkdir(parents=True, exist_ok=True)
            if d.resolve() != self.root.resolve() / dive:  # the dive directory must not be a symbolic link
                raise StoreError(f"cannot claim dive id {dive!r}: {d} resolves to {d.resolve()}, outside the store "
                                 "(a symbolic link); remove the link")
            with _dir_lock(d):
                rec = self.dive_identity(dive)
                self._check_claim(dive, rec, raw, fingerprint)
                if rec is not None and (not update or (rec.get("raw_dir") == raw
                                                       and rec.get("fingerprint") == fingerprint)):
                    return None
                new = {"dive": dive, "raw_dir": raw, "fingerprint": fingerprint,
                       "claimed_utc": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
                       "previous": ([*rec.get("previous", []), {"raw_dir": rec.get("raw_dir"),
                                                                 "fingerprint": rec.get("fingerprint")}][-5:]
                                    if rec else [])}
                tmp = d / f".{DIVE_IDENTITY}.{os.getpid()}.{uuid.uuid4().hex[:8]}"
                tmp.write_text(json.dumps(new, indent=2), encoding="utf-8")
                os.replace(tmp, d / DIVE_IDENTITY)
                return created if rec is None else None
        except OSError as exc:
            _remove_empty(created)
            raise _store_error(exc, dive, DIVE_IDENTITY) from None
        except StoreError:
            _remove_empty(created)
            raise

    def _check_claim(self, dive: str, rec: dict[str, Any] | None, raw: str, fingerprint: str) -> None:
        if rec is not None and rec.get("raw_dir") != raw and rec.get("fingerprint") != fingerprint:
            raise StoreError(
                f"dive id {dive!r} in store {self.root} belongs to raw directory {rec.get('raw_dir')}; {raw} is a "
                "different dive with the same id (give it another dive_id in its dive.yaml, or use another --store)")

    def release_claim(self, dive: str, raw_dir: str | os.PathLike[str], created: Sequence[Path]) -> None:
        """Undo a new claim (:meth:`claim_dive` returned ``created``) whose stage published nothing: the record
        is removed when it is still this directory's, then the directories the claim created when empty; a
        failed first stage leaves the store as it was (a stage of the same directory that publishes meanwhile
        records the claim again after its publish). Never raises."""
        d = self.root / dive
        with contextlib.suppress(OSError, StoreError):
            with _dir_lock(d):
                rec = self.dive_identity(dive)
                if rec is not None and rec.get("raw_dir") == str(Path(raw_dir).resolve()):
                    (d / DIVE_IDENTITY).unlink()
        _remove_empty(created)

    # ---------------------------------------------------------------- writing
    @contextlib.contextmanager
    def publish(
        self,
        dive: str,
        product: str,
        *,
        parameters: Mapping[str, Any] | None = None,
        inputs: Sequence[str | os.PathLike[str]] = (),
        upstream: Sequence[ProductVersion] = (),
        extra: Mapping[str, Any] | None = None,
    ) -> Iterator[Draft]:
        """Context manager that publishes a new version atomically.

        Usage::

            with store.publish(dive, "ctd", parameters=p, upstream=[sensors]) as draft:
                df.to_parquet(draft.path / "ctd.parquet")
            draft.result  # -> ProductVersion

        If the body raises, the staging directory is deleted and nothing is published.
        """
        pdir = self.product_dir(dive, product)
        # directories this publish creates are removed again if it fails: a failed run leaves the store as it was
        created = [d for d in (pdir, pdir.parent, self.root) if not d.exists()]
        staging = pdir / f".staging-{os.getpid()}-{uuid.uuid4().hex[:12]}"
        try:
            pdir.mkdir(parents=True, exist_ok=True)
            self._check_product_dir(pdir, dive, product)
            staging.mkdir(parents=True)  # parents: a concurrent failed publish may have just removed pdir
        except OSError as exc:
            _remove_empty(created)
            raise _store_error(exc, dive, product) from exc
        except StoreError:
            _remove_empty(created)
            raise
        draft = Draft(
            path=staging, dive=dive, product=product,
            parameters=dict(parameters or {}), inputs=[Path(p) for p in inputs],
            upstream=list(upstream), extra=dict(extra or {}),
        )
        try:
            yield draft
            self._write_manifest(draft)
            draft.result = self._commit(pdir, staging, dive, product)
        except BaseException as exc:
            shutil.rmtree(staging, ignore_errors=True)
            _remove_empty(created)
            if _is_storage_error(exc):
                raise _store_error(exc, dive, product) from exc
            raise

    def _check_product_dir(self, pdir: Path, dive: str, product: str) -> None:
        """Refuse (one-line :class:`StoreError`) to publish through a dive or product directory that is a symbolic
        link: the version would be written wherever the link points, outside the store."""
        want = self.root.resolve() / dive / product
        real = pdir.resolve()
        if real != want:
            raise StoreError(f"cannot publish {dive}/{product}: {pdir} resolves to {real}, outside its place in the "
                             "store (a symbolic link); remove the link; nothing was published")

    def _write_manifest(self, draft: Draft) -> None:
        files = []
        for p in sorted(draft.path.rglob("*")):
            if p.is_file() and p.name != MANIFEST:
                st = p.stat()
                files.append({"name": str(p.relative_to(draft.path)), "bytes": st.st_size, "mtime_ns": st.st_mtime_ns,
                              "sha256": sha256_file(p)})
        if not files:
            raise StoreError(f"refusing to publish an empty version of {draft.dive}/{draft.product}")
        inputs = []
        for p in draft.inputs:
            if not p.is_file():
                raise StoreError(f"input file {p} recorded for {draft.product} does not exist")
            # verified: hashed by reading the file (in this process, same identity), never the cache file's word
            inputs.append({"path": str(p.resolve()), "bytes": p.stat().st_size,
                           "sha256": self.file_sha256(p, verified=True)})
        manifest = {
            "dive": draft.dive,
            "product": draft.product,
            "version": None,  # filled in on commit
            "created_utc": _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds"),
            "code_version": code_version(),
            "parameters": draft.parameters,
            "inputs": inputs,
            "upstream": [u.ref() for u in draft.upstream],
            "files": files,
            **draft.extra,
        }
        manifest.setdefault("software", software_provenance())
        run = STAGE_RUN.get()
        if run:
            manifest["stage_run"] = {**{k: v for k, v in run.items() if k != "t0"},
                                     "seconds": round(time.monotonic() - run.get("t0", time.monotonic()), 3)}
        tmp = draft.path / (MANIFEST + ".tmp")
        with open(tmp, "w", encoding="utf-8") as fh:
            json.dump(manifest, fh, indent=2, default=_json_default)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, draft.path / MANIFEST)

    def _commit(self, pdir: Path, staging: Path, dive: str, product: str) -> ProductVersion:
        _fsync_tree(staging)
        try:  # O_NOFOLLOW: a .lock planted as a symbolic link never creates a file elsewhere
            lock_fh = os.fdopen(os.open(pdir / ".lock", os.O_RDWR | os.O_CREAT | os.O_APPEND | os.O_NOFOLLOW, 0o644),
                                "a+")
        except OSError as exc:  # e.g. .lock is a directory, or the store is read-only
            raise StoreError(f"cannot lock {pdir / '.lock'} to publish {dive}/{product} "
                             f"({exc.strerror or exc}); nothing was published") from None
        with lock_fh as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)
            try:
                existing = [int(m.group(1)) for p in pdir.iterdir() if (m := VERSION_RE.match(p.name))]
                number = max(existing, default=0) + 1
                # record the final version inside the manifest before it becomes visible
                mpath = staging / MANIFEST
                manifest = json.loads(mpath.read_text(encoding="utf-8"))
                manifest["version"] = f"v{number:03d}"
                tmp = staging / (MANIFEST + ".tmp")
                tmp.write_text(json.dumps(manifest, indent=2), encoding="utf-8")
                os.replace(tmp, mpath)
                target = pdir / f"v{number:03d}"
                os.rename(staging, target)  # atomic; fails if target exists
                _fsync_dir(pdir)
            finally:
                fcntl.flock(lock, fcntl.LOCK_UN)
        return ProductVersion(dive, product, number, target)

    def clean_staging(self, older_than_s: float = 3600.0) -> list[Path]:
        """Remove abandoned ``.staging-*`` directories (e.g. from a killed run) older than ``older_than_s``."""
        removed = []
        if not self.root.is_dir():
            return removed
        now = time.time()
        for p in self.root.glob("*/*/.staging-*"):
            try:
                stale = p.is_dir() and now - p.stat().st_mtime > older_than_s
            except OSError:  # removed meanwhile by its own (finishing or failing) publish
                continue
            if stale:
                shutil.rmtree(p, ignore_errors=True)
                removed.append(p)
        return removed

    def confined_version(self, pv: ProductVersion) -> Path:
        """The real directory of ``pv``, when it is ``<root>/<dive>/<product>/vNNN`` itself (no directory on the
        way is a symbolic link, so nothing read through it can lie outside the store); else a one-line
        :class:`StoreError`."""
        label = f"{pv.dive}/{pv.product}/{pv.label}"
        root = self.root.resolve()
        want = root / validate_name(pv.dive, "dive id") / validate_name(pv.product, "product name") / pv.label
        try:
            real = pv.path.resolve(strict=True)
        except (OSError, RuntimeError):
            raise StoreError(f"{label}: version directory {pv.path} is missing or unresolvable") from None
        if real != want:
            raise StoreError(f"{label}: {pv.path} resolves to {real}, not to its place in the store {want} (a "
                             "symbolic link); refusing to read products from outside the store")
        return real

    def check_intact(self, pv: ProductVersion) -> None:
        """Refuse (one-line :class:`StoreError`) a version that is not exactly what was published: its directory
        must be its own place in the store and hold only the files its manifest lists, as regular files
        (:meth:`check_layout`), each with the SHA-256 recorded at publish time (:meth:`verified_file`)."""
        for name, _ in self.check_layout(pv):
            self.verified_file(pv, name)

    def check_layout(self, pv: ProductVersion) -> list[tuple[str, dict[str, Any]]]:
        """The manifest's ``(name, entry)`` records once the version's layout is what was published: its directory
        is ``<root>/<dive>/<product>/vNNN`` itself (:meth:`confined_version`), every listed name is a regular
        file inside it (:func:`confined_file`: no ``..``, no absolute name, no symbolic link) and it holds
        nothing else (no symbolic link, no file added after publishing); else a one-line :class:`StoreError`.
        Contents are not hashed here (:meth:`verified_file`)."""
        label = f"{pv.dive}/{pv.product}/{pv.label}"
        real = self.confined_version(pv)
        entries = self._manifest_files(pv, label)
        listed = {MANIFEST}
        for name, _ in entries:
            confined_file(real, name, label)
            listed.add(name)
        for extra in _tree_entries(real):
            if extra not in listed:
                raise StoreError(f"{label}: {extra!r} is not in its manifest (added after publishing, or a "
                                 "symbolic link); remove it or re-run the stage that makes it")
        return entries

    def verified_file(self, pv: ProductVersion, name: str) -> Path:
        """Path of file ``name`` of ``pv`` once its content is verified: listed in the manifest, a regular file
        inside the version (:func:`confined_file`), with the size and SHA-256 recorded at publish time; else a
        one-line :class:`StoreError`.

        The file is hashed: size and mtime are never proof (an in-place edit can keep both). The one shortcut is
        this store object's memory of a hash it computed itself for the same file identity (device, inode, size,
        mtime and ctime - ctime changes on any write), so one run hashes a product file once. Cost on the sample
        dive's largest product (ctd.parquet, 72.5 MB): 37 ms (docs/operations.md, "Integrity of products")."""
        label = f"{pv.dive}/{pv.product}/{pv.label}"
        real = self.confined_version(pv)
        entry = next((e for n, e in self._manifest_files(pv, label) if n == name), None)
        if entry is None:
            raise StoreError(f"{label} has no file {name!r}")
        p = confined_file(real, name, label)
        key = _file_key(p)
        if key in self._intact:
            return p
        if key[3] != entry.get("bytes") or sha256_file(p) != entry.get("sha256") or _file_key(p) != key:
            raise StoreError(f"{label}: file {name!r} was modified after it was published (size or SHA-256 "
                             "differs from its manifest); re-run the stage that makes it")
        self._intact.add(key)
        return p

    def _manifest_files(self, pv: ProductVersion, label: str) -> list[tuple[str, dict[str, Any]]]:
        """``(name, entry)`` of each file the manifest lists, or a one-line :class:`StoreError`."""
        if (pv.path / MANIFEST).is_symlink():
            raise StoreError(f"{label}: manifest.json is a symbolic link; refusing it")
        try:
            entries = pv.manifest().get("files", [])
        except (OSError, ValueError) as exc:
            raise StoreError(f"{label}: unreadable manifest ({exc}); re-run the stage that makes it") from None
        if not isinstance(entries, list) or not all(isinstance(f, dict) for f in entries):
            raise StoreError(f"{label}: its manifest's 'files' is not a list of records; re-run the stage that "
                             "makes it")
        return [(str(f.get("name", "")), f) for f in entries]

    def version_at(self, path: str | os.PathLike[str]) -> ProductVersion:
        """The published version whose directory is ``path`` (``<root>/<dive>/<product>/vNNN``)."""
        p = Path(path)
        m = VERSION_RE.match(p.name)
        if not m or not (p / MANIFEST).is_file():
            raise StoreError(f"{p} is not a published product version")
        return ProductVersion(p.parent.parent.name, p.parent.name, int(m.group(1)), p)

    def verify(self, pv: ProductVersion) -> list[str]:
        """Re-hash a version's files against its manifest; returns a list of problems (empty = intact), including
        a version outside its place in the store, a manifest naming a file outside the version, symbolic links
        and files the manifest does not list."""
        label = f"{pv.dive}/{pv.product}/{pv.label}"
        try:
            real = self.confined_version(pv)
            entries = self._manifest_files(pv, label)
        except StoreError as exc:
            return [str(exc)]
        problems = []
        listed = {MANIFEST}
        for name, entry in entries:
            listed.add(name)
            try:
                p = confined_file(real, name, label)
            except StoreError as exc:
                problems.append(f"missing {name}" if "is missing" in str(exc) else str(exc))
                continue
            if sha256_file(p) != entry.get("sha256"):
                problems.append(f"checksum mismatch {name}")
        problems += [f"not in manifest {x}" for x in _tree_entries(real) if x not in listed]
        return problems


def _tree_entries(top: Path) -> list[str]:
    """Every file, symbolic link or special file under ``top`` (relative ``/`` paths; symbolic links to
    directories are listed, not followed)."""
    out = []
    for dirpath, dirnames, filenames in os.walk(top, followlinks=False):
        rel = Path(dirpath).relative_to(top)
        out += [(rel / n).as_posix() for n in filenames]
        out += [(rel / n).as_posix() for n in dirnames if (Path(dirpath) / n).is_symlink()]
    return out


#: largest ``manifest.json`` read (a casts product lists one file per cast: a few hundred kB)
MANIFEST_MAX_BYTES = 64 << 20


def confined_file(version_dir: Path, name: object, label: str) -> Path:
    """``version_dir / name`` when ``name`` is a relative path of plain components (no ``..``, not absolute:
    :func:`hadal.names.check_relative_path`) naming a regular file that is not reached through any symbolic
    link; else a one-line :class:`StoreError` (a manifest naming ``../../etc/passwd`` or a symlinked product
    file is refused before anything opens it)."""
    try:
        rel = check_relative_path(name, "file name")
    except StoreError as exc:
        raise StoreError(f"{label}: its manifest names a file outside the version ({exc}); the store was edited "
                         "by hand - re-run the stage that makes it") from None
    p = version_dir / rel
    here = version_dir
    for part in rel.split("/"):
        here = here / part
        try:
            st = here.lstat()
        except OSError:
            raise StoreError(f"{label}: file {rel!r} of its manifest is missing; re-run the stage that makes "
                             "it") from None
        if stat.S_ISLNK(st.st_mode):
            raise StoreError(f"{label}: {rel!r} is a symbolic link (to {os.readlink(here)!r}); a product file "
                             "must be a regular file inside its version - re-run the stage that makes it")
    if not stat.S_ISREG(st.st_mode):
        raise StoreError(f"{label}: {rel!r} is not a regular file; re-run the stage that makes it")
    return p


#: write failures that are about the store's storage (not the inputs): reported as a one-line StoreError
_STORAGE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS})


def _is_storage_error(exc: BaseException) -> bool:
    """ENOSPC & co., also from libraries (pyarrow, HDF5) that only put the OS message in the text."""
    if not isinstance(exc, OSError):
        return False
    return exc.errno in _STORAGE_ERRNOS or any(os.strerror(e) in str(exc) for e in _STORAGE_ERRNOS)


def _store_error(exc: OSError, dive: str, product: str) -> StoreError:
    where = f" ({exc.filename})" if getattr(exc, "filename", None) else ""
    text = str(exc)
    reason = (exc.strerror or next((os.strerror(e) for e in _STORAGE_ERRNOS if os.strerror(e) in text), None)
              or (text.splitlines()[0] if text else type(exc).__name__))
    return StoreError(f"cannot write {dive}/{product}: {reason}{where}; nothing was published")


#: space kept free on the store's file system beyond a write's own size (manifest, lock, other writers)
FREE_SPACE_RESERVE = 4 << 20


def free_bytes(path: str | os.PathLike[str]) -> int | None:
    """Bytes an unprivileged writer may still use on the file system holding ``path`` (its nearest existing
    parent); ``None`` when it cannot be told (then no check is made)."""
    p = Path(path)
    while not p.exists() and p != p.parent:
        p = p.parent
    try:
        st = os.statvfs(p)
    except OSError:
        return None
    return st.f_bavail * st.f_frsize


def ensure_free_space(path: str | os.PathLike[str], nbytes: int, what: str = "") -> None:
    """Raise ``OSError(ENOSPC)`` (reported by :meth:`ProductStore.publish` as a one-line :class:`StoreError`)
    when writing ``nbytes`` more at ``path`` would leave less than :data:`FREE_SPACE_RESERVE` on its file
    system, before a byte is written."""
    free = free_bytes(path)
    need = int(nbytes) + FREE_SPACE_RESERVE
    if free is not None and free < need:
        raise OSError(errno.ENOSPC, f"{os.strerror(errno.ENOSPC)}: {what or Path(path).name} needs "
                                    f"{_mib(need)} (with reserve), {_mib(free)} free", str(path))


def _mib(n: float) -> str:
    return f"{n / 2**20:.1f} MiB"


def write_bytes_checked(path: str | os.PathLike[str], data: bytes | memoryview, what: str = "") -> None:
    """Write ``data`` to a new file ``path`` after checking the free space; on any failure the partial file
    is removed and the ``OSError`` (ENOSPC, ...) re-raised - plain ``os.write``, so a full disk is an error,
    never a crash."""
    ensure_free_space(path, len(data), what)
    mv = memoryview(data).cast("B")
    fd = os.open(path, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o644)
    try:
        try:
            pos = 0
            while pos < len(mv):
                pos += os.write(fd, mv[pos:pos + (8 << 20)])
        finally:
            os.close(fd)
    except BaseException:
        with contextlib.suppress(OSError):
            os.unlink(path)
        raise


@contextlib.contextmanager
def _dir_lock(d: Path) -> Iterator[None]:
    """Exclusive ``flock`` on directory ``d`` itself (no lock file that could collide with a name)."""
    fd = os.open(d, os.O_RDONLY | os.O_DIRECTORY | os.O_NOFOLLOW)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX)
        yield
    finally:
        os.close(fd)  # releases the lock


def _remove_empty(dirs: Sequence[Path]) -> None:
    """rmdir the given directories (innermost first) where they are empty; never raises."""
    for d in dirs:
        try:
            d.rmdir()
        except OSError:
            pass


def _fsync_dir(path: Path) -> None:
    try:
        fd = os.open(path, os.O_RDONLY)
    except OSError:
        return
    try:
        os.fsync(fd)
    except OSError:
        pass
    finally:
        os.close(fd)


def _fsync_tree(path: Path) -> None:
    for p in path.rglob("*"):
        if p.is_file():
            with open(p, "rb") as fh:
                os.fsync(fh.fileno())
    _fsync_dir(path)
