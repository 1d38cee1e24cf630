"""Multibeam soundings of a dive's files as x, y, depth in the dive's map frame: the reading shared by the ``dtm``
stage (the ship's soundings of the reference DTM) and the ``match`` stage (the vehicle's own swath soundings, the
real-time terrain patch of MRF fine matching)."""

from __future__ import annotations

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




def read_soundings_xy(files: list, frame, hints: list | None = None, *, chunk_points: int = 1_000_000,
                      readers: dict | None = None, progress=None, memory_limit_bytes: float | None = None):
    """``(x, y, depth_m, frame, used)``: the soundings of ``files`` (any format :func:`hadal.grid.sonar.iter_multibeam`
    reads, with the reading hints ``hints[i]`` of their ``dive.yaml`` entries) in ``frame`` (None: a frame centred on
    the first positioned soundings, returned), streamed chunk by chunk (:class:`hadal.grid.sonar.ColumnAccumulator`);
    ``used`` the per-file reader texts, also put in ``readers`` ``{str(file): text}`` when given. Projected soundings
    are converted from their declared CRS; ``crs: local`` means they already are in the map frame. No positioned
    sounding at all: a one-line :class:`InputError`. ``progress`` (optional, ``.track``): lines per file read (start,
    end, and every few seconds the chunks of ``chunk_points`` soundings read) (:func:`hadal.steps.tracked`).
    ``memory_limit_bytes``: the stage's memory budget (``resources.max_memory_gb``), which every file's soundings are
    held against as they decode, with those of the files before it (:class:`hadal.grid.sonar.SoundingBudget`)."""
    from hadal.grid.sonar import ColumnAccumulator, iter_multibeam
    from hadal.steps import tracked

    hints = list(hints) if hints is not None else [None] * len(files)
    acc = ColumnAccumulator(3)
    used: list[str] = []
    for i, (f, h) in enumerate(zip(files, hints, strict=True)):
        info: dict = {}
        to_ll = None
        for chunk in tracked(progress, iter_multibeam(f, h, chunk_points=chunk_points, info=info,
                                                           held_soundings=acc.n,
                                                           memory_limit_bytes=memory_limit_bytes),
                             f"dtm: reading multibeam file {i + 1}/{len(files)} {Path(f).name} "
                             f"(chunks of {chunk_points:,} soundings; {acc.n:,} read before it)"):
            z = chunk["depth_m"].to_numpy(np.float64)
            x, y, frame, to_ll = project_chunk(f, chunk, info, frame, to_ll)
            if x is None:
                continue
            acc.add(np.asarray(x, np.float64), np.asarray(y, np.float64), z)
            del chunk, x, y, z
        desc = reader_description(info)
        used.append(f"{Path(f).name}: {desc}")
        if readers is not None:
            readers[str(f)] = desc
    if frame is None or acc.n == 0:
        raise InputError(f"no soundings with positions in {', '.join(str(f) for f in files)}")
    x, y, dep = acc.finish()
    return x, y, dep, frame, used
