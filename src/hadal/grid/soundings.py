"""Multibeam soundings of a dive's files as x, y, depth in the dive's map frame: the reading shared by the ``dtm``
stage (the ship's soundings of the reference DTM) and the ``match`` stage (the vehicle's own swath soundings, the
real-time terrain patch of MRF fine matching)."""

from __future__ import annotations

import contextlib
from pathlib import Path

import numpy as np

from hadal.errors import InputError


def project_chunk(f: Path, chunk, info: dict, frame, to_ll):
    """One chunk of soundings -> (x, y) in the map frame, with the frame (made from the first positioned
    soundings when None) and the CRS transformer carried to the next chunk; x is None when the chunk cannot be
    placed yet (geographic soundings with no finite position and no frame)."""
    from hadal.geo import LocalFrame

    if "longitude_deg" in chunk:
        lon, lat = chunk["longitude_deg"].to_numpy(), chunk["latitude_deg"].to_numpy()
        if frame is None:
            ok = np.isfinite(lon) & np.isfinite(lat)
            if ok.any():
                frame = LocalFrame(float(np.median(lat[ok])), float(np.median(lon[ok])))
        if frame is None:
            return None, None, frame, to_ll
        x, y = frame.to_xy(lon, lat)
        return x, y, frame, to_ll
    crs = info.get("crs")
    xm, ym = chunk["x_m"].to_numpy(np.float64), chunk["y_m"].to_numpy(np.float64)
    if crs is not None and str(crs).strip().lower() in ("local", "local_metric"):
        if frame is None:
            raise InputError(f"{f}: soundings are in the dive's local map frame (crs: local) but the "
                             "dive has no map_frame or launch")
        return xm, ym, frame, to_ll
    if crs is None:
        raise InputError(f"{f}: soundings are projected x/y metres with no CRS; declare it in dive.yaml "
                         "(crs: 'EPSG:32654', or 'local' when they are in the dive's map frame)")
    if to_ll is None:
        from pyproj import Transformer

        to_ll = Transformer.from_crs(crs, "EPSG:4326", always_xy=True)
    lon, lat = to_ll.transform(xm, ym)
    if frame is None:
        ok = np.isfinite(lon) & np.isfinite(lat)
        frame = LocalFrame(float(np.median(lat[ok])), float(np.median(lon[ok])))
    x, y = frame.to_xy(lon, lat)
    return x, y, frame, to_ll


def reader_description(info: dict) -> str:
    """The manifest's text for how one multibeam file was read: ``reader (format, compression, ...)``."""
    desc = f"{info.get('reader', '?')} ({info.get('format')}"
    if info.get("compression"):
        desc += f", {info['compression']}"
    if info.get("crs_kind") == "projected":
        desc += f", projected {info.get('crs') or ''}".rstrip()
    if info.get("format") == "xyz" and info.get("z_positive") == "up":
        desc += f", elevations negated ({info.get('z_positive_from')})"
    if info.get("pings") is not None:
        desc += f", {info['pings']} pings, {info.get('dropped', 0)} beams dropped"
    return desc + ")"




class SpilledSoundings(contextlib.AbstractContextManager):
    """x, y, depth soundings appended chunk by chunk to three raw float64 files in a fresh scratch directory
    (``hadal-soundings-*`` under ``scratch_dir``, default the system temp dir), so a dive's soundings never sit
    whole in memory (issue 48); a context manager that removes the directory. While they are written, the
    statistics the ``dtm`` stage needs before it grids are kept: soundings beyond any ocean depth
    (``n_implausible``: finite depth, ``|depth| > MAX_ABS_DEPTH_M``), and of the others the extent of the finite
    x, y (``extent_xy``, the grid-size check) and of the finite x, y, depth (``extent``, the grid), and the count
    of finite x, y (``n_xy``, the automatic resolution's subsample)."""

    def __init__(self, scratch_dir=None) -> None:
        import tempfile

        base = Path(scratch_dir) if scratch_dir is not None else Path(tempfile.gettempdir())
        try:
            self.dir = Path(tempfile.mkdtemp(prefix="hadal-soundings-", dir=base))
        except OSError as e:
            raise InputError(f"cannot create a scratch directory in {base}: {e.strerror or e}") from None
        self.n = 0
        self.n_implausible = 0
        self.n_xy = 0
        self._ext_xy = [np.inf, np.inf, -np.inf, -np.inf]
        self._ext = [np.inf, np.inf, -np.inf, -np.inf]

    @classmethod
    def open(cls, directory) -> SpilledSoundings:
        """Soundings spilled before into ``directory`` (e.g. by another process), to read back
        (:meth:`chunks`); the statistics are not kept."""
        sp = cls.__new__(cls)
        sp.dir = Path(directory)
        sp.n = (sp.dir / "z.f8").stat().st_size // 8 if (sp.dir / "z.f8").exists() else 0
        sp.n_implausible = sp.n_xy = 0
        sp._ext_xy = [np.inf, np.inf, -np.inf, -np.inf]
        sp._ext = [np.inf, np.inf, -np.inf, -np.inf]
        return sp

    def __exit__(self, *exc) -> None:
        """Remove the scratch directory (:meth:`close`)."""
        self.close()

    def close(self) -> None:
        """Remove the scratch directory and the soundings in it."""
        import shutil

        shutil.rmtree(self.dir, ignore_errors=True)

    def _path(self, k: int) -> Path:
        return self.dir / ("x.f8", "y.f8", "z.f8")[k]

    @staticmethod
    def _grow(ext: list, x: np.ndarray, y: np.ndarray) -> None:
        if x.size:
            ext[0], ext[1] = min(ext[0], float(x.min())), min(ext[1], float(y.min()))
            ext[2], ext[3] = max(ext[2], float(x.max())), max(ext[3], float(y.max()))

    def add(self, x, y, z) -> None:
        """Append one chunk (arrays of one length) and update the statistics."""
        from hadal.grid.prior import MAX_ABS_DEPTH_M

        cols = [np.ascontiguousarray(a, dtype=np.float64).ravel() for a in (x, y, z)]
        try:
            for k, a in enumerate(cols):
                with open(self._path(k), "ab") as fh:
                    a.tofile(fh)
        except OSError as e:
            raise InputError(f"cannot write soundings to the scratch directory {self.dir}: {e.strerror or e}") from None
        x, y, z = cols
        keep = ~(np.isfinite(z) & (np.abs(z) > MAX_ABS_DEPTH_M))
        self.n += len(z)
        self.n_implausible += len(z) - int(keep.sum())
        keep &= np.isfinite(x) & np.isfinite(y)
        self.n_xy += int(keep.sum())
        self._grow(self._ext_xy, x[keep], y[keep])
        keep &= np.isfinite(z)
        self._grow(self._ext, x[keep], y[keep])

    @property
    def extent(self) -> tuple[float, float, float, float] | None:
        """``(xmin, ymin, xmax, ymax)`` of the plausible soundings with finite x, y and depth (None: none)."""
        return tuple(self._ext) if np.isfinite(self._ext[0]) else None  # type: ignore[return-value]

    @property
    def extent_xy(self) -> tuple[float, float, float, float] | None:
        """``(xmin, ymin, xmax, ymax)`` of the plausible soundings with finite x, y (None: none)."""
        return tuple(self._ext_xy) if np.isfinite(self._ext_xy[0]) else None  # type: ignore[return-value]

    def chunks(self, chunk_points: int = 1 << 21, *, drop_implausible: bool = True):
        """Yield ``(x, y, depth)`` in the order written, ``chunk_points`` read at a time (fresh arrays, not
        memory maps: a mapping's resident pages would count in the process's memory), the implausible soundings
        dropped (``drop_implausible``)."""
        from hadal.grid.prior import MAX_ABS_DEPTH_M

        if self.n == 0:
            return
        with open(self._path(0), "rb") as fx, open(self._path(1), "rb") as fy, open(self._path(2), "rb") as fz:
            for a in range(0, self.n, chunk_points):
                m = min(chunk_points, self.n - a)
                x, y, z = (np.fromfile(fh, dtype=np.float64, count=m) for fh in (fx, fy, fz))
                if drop_implausible:
                    keep = ~(np.isfinite(z) & (np.abs(z) > MAX_ABS_DEPTH_M))
                    if not keep.all():
                        x, y, z = x[keep], y[keep], z[keep]
                yield x, y, z

    def xy_subsample(self, step: int, chunk_points: int = 1 << 21) -> tuple[np.ndarray, np.ndarray]:
        """Every ``step``-th of the plausible soundings with finite x, y (``x[ok][::step]`` of the in-memory
        arrays, the same points)."""
        xs, ys, seen = [], [], 0
        for x, y, _ in self.chunks(chunk_points):
            ok = np.isfinite(x) & np.isfinite(y)
            x, y = x[ok], y[ok]
            first = (-seen) % step
            xs.append(x[first::step])
            ys.append(y[first::step])
            seen += len(x)
        return (np.concatenate(xs), np.concatenate(ys)) if xs else (np.empty(0), np.empty(0))

    def abs_depth_median(self) -> float:
        """Median of ``|depth|`` over all soundings (the one-line error's hint when most are implausible)."""
        z = np.fromfile(self._path(2), dtype=np.float64) if self.n else np.empty(0)
        return float(np.median(np.abs(z)))


def read_soundings_xy(files: list, frame, hints: list | None = None, *, chunk_points: int = 1_000_000,
                      readers: dict | None = None, progress=None, memory_limit_bytes: float | None = None):
    """``(x, y, depth_m, frame, used)``: the soundings of ``files`` in memory (:func:`read_soundings`, whose
    documentation this follows, with no spill)."""
    cols, frame, used = read_soundings(files, frame, hints, chunk_points=chunk_points, readers=readers,
                                       progress=progress, memory_limit_bytes=memory_limit_bytes)
    x, y, dep = cols  # type: ignore[misc]  # no spill without spill_above_points
    return x, y, dep, frame, used


def read_soundings(files: list, frame, hints: list | None = None, *, chunk_points: int = 1_000_000,
                  readers: dict | None = None, progress=None, memory_limit_bytes: float | None = None,
                  spill_above_points: int | None = None, scratch_dir=None):
    """``(cols, frame, used)``: the soundings of ``files`` (any format :func:`hadal.grid.sonar.iter_multibeam`
    reads, with the reading hints ``hints[i]`` of their ``dive.yaml`` entries) in ``frame`` (None: a frame centred on
    the first positioned soundings, returned), streamed chunk by chunk (:class:`hadal.grid.sonar.ColumnAccumulator`);
    ``used`` the per-file reader texts, also put in ``readers`` ``{str(file): text}`` when given. Projected soundings
    are converted from their declared CRS; ``crs: local`` means they already are in the map frame. No positioned
    sounding at all: a one-line :class:`InputError`. ``progress`` (optional, ``.track``): lines per file read (start,
    end, and every few seconds the chunks of ``chunk_points`` soundings read) (:func:`hadal.steps.tracked`).
    ``memory_limit_bytes``: the stage's memory budget (``resources.max_memory_gb``), which every file's soundings are
    held against as they decode, with those of the files before it (:class:`hadal.grid.sonar.SoundingBudget`).
    ``cols`` is ``(x, y, depth_m)`` in memory or, once more than ``spill_above_points`` soundings are read (0: from
    the first), a :class:`SpilledSoundings` (on disk under ``scratch_dir``; the caller closes it) to which every
    further chunk is appended as it is projected, so the soundings never sit whole in memory."""
    from hadal.grid.sonar import ColumnAccumulator

    hints = list(hints) if hints is not None else [None] * len(files)
    acc = ColumnAccumulator(3)
    used: list[str] = []
    spill_box: list[SpilledSoundings | None] = [None]
    try:
        frame = _read_into(files, frame, hints, acc, chunk_points, readers, progress, memory_limit_bytes,
                           spill_above_points, scratch_dir, used, spill_box)
        spill = spill_box[0]
        if frame is None or (acc.n == 0 and (spill is None or spill.n == 0)):
            raise InputError(f"no soundings with positions in {', '.join(str(f) for f in files)}")
    except BaseException:
        if spill_box[0] is not None:
            spill_box[0].close()
        raise
    if spill is not None:
        return spill, frame, used
    x, y, dep = acc.finish()
    return (x, y, dep), frame, used


def _read_into(files, frame, hints, acc, chunk_points, readers, progress, memory_limit_bytes, spill_above_points,
               scratch_dir, used, spill_box):
    """The reading loop of :func:`read_soundings` (``spill_box[0]``: the spill once made); returns the frame."""
    from hadal.grid.sonar import iter_multibeam
    from hadal.steps import tracked

    for i, (f, h) in enumerate(zip(files, hints, strict=True)):
        info: dict = {}
        to_ll = None
        for chunk in tracked(progress, iter_multibeam(f, h, chunk_points=chunk_points, info=info,
                                                           held_soundings=acc.n,
                                                           memory_limit_bytes=memory_limit_bytes,
                                                           streamed=spill_box[0] is not None
                                                           or spill_above_points == 0),
                             f"dtm: reading multibeam file {i + 1}/{len(files)} {Path(f).name} "
                             f"(chunks of {chunk_points:,} soundings; {acc.n:,} read before it)"):
            z = chunk["depth_m"].to_numpy(np.float64)
            x, y, frame, to_ll = project_chunk(f, chunk, info, frame, to_ll)
            if x is None:
                continue
            if (spill_box[0] is None and spill_above_points is not None
                    and acc.n + len(z) > spill_above_points):
                spill_box[0] = SpilledSoundings(scratch_dir)
                if acc.n:
                    spill_box[0].add(*acc.finish())
                acc.n = acc.fill = 0
            if spill_box[0] is not None:
                spill_box[0].add(x, y, z)
            else:
                acc.add(np.asarray(x, np.float64), np.asarray(y, np.float64), z)
            del chunk, x, y, z
        desc = reader_description(info)
        used.append(f"{Path(f).name}: {desc}")
        if readers is not None:
            readers[str(f)] = desc
    return frame
