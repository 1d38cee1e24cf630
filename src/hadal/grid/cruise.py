"""A cruise-level DTM: every dive's multibeam soundings gridded together, dives and tiles as the units of work
(issue 48, "a cruise on an existing distributed engine").

Prefect-free science: each phase is a pure function of files on a scratch directory that every worker sees,
and the phases are fanned out by a ``map`` callable (``map(fn, [args, ...]) -> [result, ...]`` in order), the
builtin-like :func:`serial_map` in tests and Prefect's Dask task runner in :mod:`hadal.flows.cruise`. Every
task writes its files atomically (a temporary name, then ``os.replace``), so a task re-run after a worker died
(Dask reschedules it) gives the same files, and a half-written file is never read.

1. **cruise frame** (:func:`cruise_frame`): one transverse Mercator :class:`hadal.geo.LocalFrame` (scale 1)
   centred on the centre of the longitude/latitude bounding box of the dives' own map-frame origins (``map_frame``
   or ``launch`` of each ``dive.yaml``). Chosen over a UTM zone because a cruise may straddle a zone boundary (zones
   54 and 55 meet at 144 E, in the Mariana Trench) and the dives' products already use the same projection (one code path, exact conversion to lon/lat with pyproj). The frame is known before any
   sounding is read (no second read). Over a cruise's extent of tens of km the transverse Mercator scale error
   stays below ~1e-5 (k = 1 + x^2 / 2R^2: 3e-5 at 50 km from the centre; Snyder, *Map Projections - A Working
   Manual*, USGS PP 1395, 1987, formula 8-7), well below a DTM cell.
2. **read** (:func:`read_dive`, one task a dive): the dive's ``sources.multibeam`` files read with their
   ``dive.yaml`` reading hints (:func:`hadal.grid.soundings.read_soundings`, one file at a time so a bad file is
   refused by name and the others kept) into the cruise frame, each chunk written to the scratch directory as it
   is read (x, y, depth; never the dive whole in memory); soundings beyond any ocean depth dropped (as the
   ``dtm`` stage); returns the extent and count. A dive that cannot
   be read is named and left out (:class:`DiveRead` ``error``), the others kept.
3. **grid spec**: the union of the dives' extents, snapped to the resolution (:func:`hadal.grid.points.
   make_grid_spec` ``snap=True``, as :func:`hadal.grid.multibeam.grid_multibeam` makes it from all the soundings).
4. **partition** (:func:`partition_dive`, one task a dive): the dive's soundings cut by tile
   (:class:`hadal.grid.tiles.TilePartition`: the in-memory kernels' cell rule) into per-tile files of its own.
5. **spike test** (``grid.spike_removal``; the dive ``dtm``'s own, :func:`hadal.grid.tiles.spike_flags_of_tile`):
   the dives' partitions read as one (:func:`dive_union`: a tile's points of every dive in dive order, input
   indices offset by the dives before), the noise floor ``sigma_0`` from every tile's cell MADs
   (:func:`hadal.grid.tiles.tile_cell_mads`, one task a group of tiles; their median in the driver), then
   :func:`spike_tiles` per group: the per-cell test and the neighbour test whose halo reaches into the tiles
   around, whichever dive their soundings come from; flags written per tile.
6. **reduce** (:func:`reduce_tile`; one task a group of consecutive tiles holding >= :data:`MIN_TASK_POINTS`
   soundings, :func:`group_tiles`): the tile's points of every dive, in dive order, less the spikes, reduced by
   :func:`hadal.grid.multibeam.dtm_cell_layers`, the per-tile function of the in-memory DTM.
7. **assemble** (:func:`assemble`): the tiles' layers in their windows, small holes filled
   (:func:`hadal.grid.multibeam.fill_dtm_holes`), georeferenced (:func:`hadal.grid.multibeam.add_geo`).

A cell's statistics depend only on its soundings in input order, which the partition keeps (dives in the given
order, each dive's files and soundings in order), and the spike test is exact across tile seams and dives
(:mod:`hadal.grid.tiles`), so the cruise DTM equals :func:`hadal.grid.multibeam.grid_multibeam` of all the
soundings concatenated in the cruise frame, spikes and counts included.
"""

from __future__ import annotations

import os
import shutil
import uuid
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hadal.errors import HadalError, InputError

if TYPE_CHECKING:
    import numpy as np
    import xarray as xr

    from hadal.geo import LocalFrame
    from hadal.grid.points import GridSpec
    from hadal.grid.tiles import PartitionUnion, TileScheme
    from hadal.settings.grid import GridParams

#: soundings a reduce task holds at least (small tiles grouped): a Prefect task costs ~0.15 CPU-s of its own
#: (API calls, states) in a worker, about the reduction of 1e6 soundings (bench/bench_cruise_dtm.py)
MIN_TASK_POINTS = 1_000_000

#: the ``map`` callable: ``map(fn, [args tuple, ...])`` -> results in the same order
MapFn = Callable[[Callable[..., Any], Sequence[tuple]], list]


def serial_map(fn: Callable[..., Any], items: Sequence[tuple]) -> list:
    """The ``map`` of one process: ``[fn(*args) for args in items]``."""
    return [fn(*args) for args in items]


@dataclass(frozen=True)
class DiveSource:
    """One dive of the cruise: its id, raw directory, the multibeam files found (with their ``dive.yaml`` entries,
    the reading hints) and the files listed but refused (missing), ``{path: reason}``."""

    dive_id: str
    raw_dir: str
    files: tuple[str, ...]
    hints: tuple[Any, ...]
    origin_lat_lon: tuple[float, float]
    refused: dict[str, str] = field(default_factory=dict)


@dataclass(frozen=True)
class DiveRead:
    """A dive's soundings read into the cruise frame (:func:`read_dive`): their files on the scratch directory,
    extent ``(xmin, ymin, xmax, ymax)`` of the finite ones, count, the files used (reader texts) and refused."""

    dive_id: str
    directory: str | None
    n_soundings: int = 0
    n_implausible: int = 0
    extent: tuple[float, float, float, float] | None = None
    used: dict[str, str] = field(default_factory=dict)
    refused: dict[str, str] = field(default_factory=dict)
    error: str | None = None
    n_files: int = 0  # files read: their soundings in ``directory``/f0, f1, ...


@dataclass(frozen=True)
class DivePartition:
    """A dive's soundings cut by tile (:func:`partition_dive`): the directory of its per-tile files and the points
    per tile (``error``: the dive could not be partitioned, left out)."""

    dive_id: str
    directory: str | None
    tile_points: tuple[int, ...] = ()
    n_input: int = 0
    n_nonfinite: int = 0
    error: str | None = None


def _atomic_write(path: Path, arr) -> None:
    tmp = path.with_name(f".{path.name}.{uuid.uuid4().hex[:8]}.tmp")
    arr.tofile(tmp)
    os.replace(tmp, path)


def dive_sources(raw_dirs: Sequence[str | os.PathLike]) -> tuple[list[DiveSource], dict[str, str]]:
    """The cruise's dives from their raw directories: ``(dives, refused)``, ``refused`` = ``{raw_dir: reason}`` for a
    directory with no readable ``dive.yaml``, no map frame/launch or no multibeam file (a one-line reason each).
    Listed files that do not exist are refused by name in the dive's ``refused``."""
    from hadal.dive import load_dive, resolve_source

    dives: list[DiveSource] = []
    refused: dict[str, str] = {}
    seen: set[str] = set()
    for raw in raw_dirs:
        try:
            dive, rdir = load_dive(Path(raw))
            frame = dive.frame("cruise_dtm")
        except (HadalError, OSError, ValueError) as exc:
            refused[str(raw)] = str(exc).splitlines()[0]
            continue
        if dive.dive_id in seen:
            refused[str(raw)] = f"dive id {dive.dive_id!r} is already in the cruise (listed twice?)"
            continue
        files, hints, missing = [], [], {}
        for sf in dive.sources.multibeam:
            f = resolve_source(rdir, sf)
            if f.is_file():
                files.append(str(f))
                hints.append(sf)
            else:
                missing[str(f)] = "listed in dive.yaml but does not exist"
        if not files:
            refused[str(raw)] = (f"dive {dive.dive_id!r} lists no existing multibeam file"
                                 + (f" ({', '.join(missing)} missing)" if missing else ""))
            continue
        seen.add(dive.dive_id)
        dives.append(DiveSource(dive.dive_id, str(rdir), tuple(files), tuple(hints),
                                (float(frame.origin_latitude_deg), float(frame.origin_longitude_deg)), missing))
    return dives, refused


def cruise_frame(dives: Sequence[DiveSource]) -> LocalFrame:
    """The cruise map frame (module doc, step 1): transverse Mercator centred on the centre of the bounding box of
    the dives' map-frame origins (longitudes unwrapped around the first dive's, so a cruise across 180 E works)."""
    from hadal.geo import LocalFrame

    if not dives:
        raise InputError("no dive with multibeam soundings in the cruise")
    lat = [d.origin_lat_lon[0] for d in dives]
    lon0 = dives[0].origin_lat_lon[1]
    lon = [lon0 + ((d.origin_lat_lon[1] - lon0 + 180.0) % 360.0 - 180.0) for d in dives]
    c_lon = (min(lon) + max(lon)) / 2.0
    c_lon = (c_lon + 180.0) % 360.0 - 180.0
    return LocalFrame(round((min(lat) + max(lat)) / 2.0, 9), round(c_lon, 9))


def read_dive(dive: DiveSource, frame: LocalFrame, scratch_dir: str) -> DiveRead:
    """Step 2 of the module doc for one dive: its files read into ``frame`` chunk by chunk, each chunk written to
    disk as it arrives (:func:`hadal.grid.soundings.read_soundings` spilling from the first sounding: the dive's
    soundings never sit whole in memory), one directory a file, ``<scratch_dir>/read/<dive_id>/f<k>/`` (x, y,
    depth); a file that fails is refused by name, the others kept. Soundings deeper/higher than anywhere on Earth
    are counted here and dropped as they are read back. The dive's directory is written under a fresh name, then
    renamed into place (a re-run replaces it whole). Never raises for bad input: a dive with nothing readable comes
    back with ``error`` (named, left out of the cruise)."""
    from hadal.grid.soundings import SpilledSoundings, read_soundings

    base = Path(scratch_dir) / "read"
    base.mkdir(parents=True, exist_ok=True)
    tmp = base / f".{dive.dive_id}-{uuid.uuid4().hex[:8]}"
    tmp.mkdir()
    used: dict[str, str] = {}
    refused = dict(dive.refused)
    n = n_implausible = 0
    exts = []
    try:
        for f, h in zip(dive.files, dive.hints, strict=True):
            readers: dict[str, str] = {}
            try:
                sp, _, _ = read_soundings([Path(f)], frame, [h], readers=readers, spill_above_points=0,
                                          scratch_dir=tmp)
            except (HadalError, OSError, ValueError, RuntimeError, KeyError, TypeError) as exc:
                refused[f] = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
                continue
            assert isinstance(sp, SpilledSoundings)
            os.replace(sp.dir, tmp / f"f{len(used)}")
            used[f] = readers.get(f, "?")
            n += sp.n - sp.n_implausible
            n_implausible += sp.n_implausible
            if sp.extent is not None:
                exts.append(sp.extent)
        if not used:
            return DiveRead(dive.dive_id, None, refused=refused,
                            error=f"dive {dive.dive_id!r}: no multibeam file could be read ("
                                  + "; ".join(f"{Path(k).name}: {v}" for k, v in refused.items()) + ")")
        if not exts:
            return DiveRead(dive.dive_id, None, used=used, refused=refused,
                            error=f"dive {dive.dive_id!r}: all {n} soundings have NaN/inf coordinates or depths")
        ext = (min(e[0] for e in exts), min(e[1] for e in exts), max(e[2] for e in exts), max(e[3] for e in exts))
        out = base / dive.dive_id
        old = base / f".old-{dive.dive_id}-{uuid.uuid4().hex[:8]}"
        if out.exists():
            os.replace(out, old)
        os.replace(tmp, out)
        shutil.rmtree(old, ignore_errors=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return DiveRead(dive.dive_id, str(out), n, n_implausible, ext, used, refused, n_files=len(used))


def cruise_grid_spec(reads: Sequence[DiveRead], resolution_m: float, *, max_cells: int | None = None) -> GridSpec:
    """Step 3: the grid over the union of the dives' extents, snapped as ``grid_multibeam`` snaps all soundings'."""
    from hadal.grid.points import DEFAULT_MAX_CELLS, make_grid_spec

    ext = [r.extent for r in reads if r.extent is not None and r.error is None]
    if not ext:
        raise InputError("no dive of the cruise has positioned soundings")
    union = (min(e[0] for e in ext), min(e[1] for e in ext), max(e[2] for e in ext), max(e[3] for e in ext))
    return make_grid_spec(float(resolution_m), union, max_cells=max_cells or DEFAULT_MAX_CELLS, snap=True)


def partition_dive(read: DiveRead, scheme: TileScheme, scratch_dir: str) -> DivePartition:
    """Step 4 for one dive: its soundings (from :func:`read_dive`) cut by tile into
    ``<scratch_dir>/tiles/<dive_id>/t<k>.*`` with their positions (:class:`hadal.grid.tiles.TilePartition`
    ``with_xy``, for the spike test; points
    clamped into the edge cells as the grid covers them all). Written in a fresh directory, then renamed into
    place: a re-run (the worker died) replaces the directory whole."""
    from hadal.grid.soundings import SpilledSoundings
    from hadal.grid.tiles import PARTITION_CHUNK_POINTS, TilePartition

    base = Path(scratch_dir) / "tiles"
    base.mkdir(parents=True, exist_ok=True)
    try:
        d = Path(read.directory or "")
        part = TilePartition(scheme, scratch_dir=base, check_inside=False, with_xy=True)
        try:
            for k in range(read.n_files):
                for x, y, z in SpilledSoundings.open(d / f"f{k}").chunks(PARTITION_CHUNK_POINTS):
                    part.add(x, y, z)
        except BaseException:
            part.close()
            raise
    except (HadalError, OSError) as exc:
        return DivePartition(read.dive_id, None, error=f"dive {read.dive_id!r}: {str(exc).splitlines()[0]}")
    target = base / read.dive_id
    old = base / f".old-{read.dive_id}-{uuid.uuid4().hex[:8]}"
    if target.exists():
        os.replace(target, old)
    os.replace(part.dir, target)
    shutil.rmtree(old, ignore_errors=True)
    return DivePartition(read.dive_id, str(target), tuple(part.tile_points), part.n_input, part.n_nonfinite)


def dive_union(scheme: TileScheme, parts: Sequence[DivePartition]) -> PartitionUnion:
    """The dives' partitions as one (:class:`hadal.grid.tiles.PartitionUnion`): a tile's points of every dive in
    the dives' order, a sounding's input index offset by the soundings of the dives before it (so the union is
    the partition of all the soundings concatenated in dive order)."""
    from hadal.grid.tiles import PartitionUnion

    good = [p for p in parts if p.error is None]
    offsets, n = [], 0
    for p in good:
        offsets.append(n)
        n += p.n_input
    return PartitionUnion(scheme, tuple(p.directory or "" for p in good), tuple(p.tile_points for p in good),
                          tuple(offsets))


def spike_tiles(ts: Sequence[int], union: PartitionUnion, sigma0: float, spikes_dir: str, k: float,
                k_neighbourhood: float, neighbours: int, min_count: int) -> int:
    """Step 5a for the tiles ``ts``: each tile's spike flags (:func:`hadal.grid.tiles.spike_flags_of_tile`: the
    per-cell test and the neighbour test with a halo reaching into the tiles around it, of every dive) written to
    ``<spikes_dir>/t<k>.spike.u1`` atomically; returns the spikes found."""
    import numpy as np

    from hadal.grid.tiles import spike_flags_of_tile

    n = 0
    for t in ts:
        if union.tile_points[t]:
            bad = spike_flags_of_tile(union, t, sigma0, k=k, k_neighbourhood=k_neighbourhood, neighbours=neighbours,
                                      min_count=min_count)
            _atomic_write(Path(spikes_dir) / f"t{t}.spike.u1", bad.astype(np.uint8))
            n += int(bad.sum())
    return n


def reduce_tile(t: int, union: PartitionUnion, compiled: bool, apriori_a_m: float, apriori_b: float,
                prior_weight: float, spikes_dir: str | None = None) -> dict[str, np.ndarray] | None:
    """Step 5b for tile ``t``: the tile's points of every dive, in the dives' order, less the spikes flagged in
    ``spikes_dir`` (:func:`spike_tiles`; None: no spike test), reduced by
    :func:`hadal.grid.multibeam.dtm_cell_layers` (flat layers over the tile's cells; None: no point)."""
    import numpy as np

    from hadal.grid.multibeam import dtm_cell_layers

    if not union.tile_points[t]:
        return None
    cells, values = union.tile_points_of(t)
    if spikes_dir is not None:
        keep = np.fromfile(Path(spikes_dir) / f"t{t}.spike.u1", dtype=np.uint8) == 0
        cells, values = cells[keep], values[keep]
    r0, r1, c0, c1 = union.scheme.window(t)
    return dtm_cell_layers(cells, values, (r1 - r0) * (c1 - c0), apriori_a_m=apriori_a_m, apriori_b=apriori_b,
                           prior_weight=prior_weight, compiled=compiled)


def reduce_tiles(ts: Sequence[int], union: PartitionUnion, compiled: bool, apriori_a_m: float, apriori_b: float,
                 prior_weight: float, spikes_dir: str | None = None) -> list[dict[str, np.ndarray] | None]:
    """:func:`reduce_tile` of each tile of ``ts`` (a group of small tiles as one task: the orchestrator's fixed
    cost per task is paid once for the group)."""
    return [reduce_tile(t, union, compiled, apriori_a_m, apriori_b, prior_weight, spikes_dir) for t in ts]


def group_tiles(tiles: Sequence[int], points: Sequence[int], min_points: int) -> list[list[int]]:
    """Consecutive tiles grouped until a group holds at least ``min_points`` points (the last group may hold
    fewer); ``min_points`` <= 1: one tile a group."""
    groups: list[list[int]] = []
    cur: list[int] = []
    n = 0
    for t, k in zip(tiles, points, strict=True):
        cur.append(t)
        n += k
        if n >= min_points:
            groups.append(cur)
            cur, n = [], 0
    if cur:
        groups.append(cur)
    return groups


def assemble(scheme: TileScheme, tiles: Sequence[dict[str, np.ndarray] | None], frame: LocalFrame, *,
             fill_max_cells: int, apriori_a_m: float, apriori_b: float, prior_weight: float,
             attrs: dict[str, Any], method: dict[str, Any]) -> xr.Dataset:
    """Step 6: the tiles' layers written into their windows, small holes filled, the DTM Dataset georeferenced in
    the cruise frame (``method``: the arguments of :func:`hadal.grid.multibeam._method_attrs`)."""
    import numpy as np

    from hadal.grid.multibeam import DTM_CELL_LAYERS, _dtm_attrs, _method_attrs, add_geo, fill_dtm_holes
    from hadal.grid.points import to_dataset

    s = scheme.spec
    flat = {k: np.full(s.n_cells, 0 if k == "count" else np.nan, dtype=np.int64 if k == "count" else np.float64)
            for k in DTM_CELL_LAYERS}
    grids = {k: v.reshape(s.ny, s.nx) for k, v in flat.items()}
    for t, layers in enumerate(tiles):
        if layers is None:
            continue
        r0, r1, c0, c1 = scheme.window(t)
        for k, v in layers.items():
            grids[k][r0:r1, c0:c1] = v.reshape(r1 - r0, c1 - c0)
    flat, filled = fill_dtm_holes(s, flat, fill_max_cells, apriori_a_m, apriori_b)
    attrs = {**attrs, "n_cells_filled": int(filled.sum()), **_method_attrs(**method),
             "tile_cells": scheme.tile_cells, "n_tiles": scheme.n_tiles}
    names = {"mean": "depth_m", "median": "depth_median_m", "std": "depth_std_m", "uncertainty": "uncertainty_m"}
    ds = to_dataset(s, flat, names=names, attrs=attrs)
    _dtm_attrs(ds)
    return add_geo(ds, frame)


def cruise_dtm_dataset(raw_dirs: Sequence[str | os.PathLike], resolution_m: float, scratch_dir: str | os.PathLike,
                       *, map: MapFn = serial_map, tile_cells: int | None = None,
                       params: GridParams | None = None,
                       min_task_points: int = MIN_TASK_POINTS) -> tuple[xr.Dataset, dict[str, Any]]:
    """The cruise DTM of the dives in ``raw_dirs`` (module doc), its phases fanned out by ``map`` on
    ``scratch_dir`` (a directory every worker sees); hole filling, a-priori uncertainty and the cell-count limit
    from ``params`` (the ``grid`` settings, :class:`hadal.settings.grid.GridParams`; default its defaults).
    Tiles are reduced in groups of at least ``min_task_points`` soundings (:func:`group_tiles`; 1: a task a tile).
    Returns ``(Dataset, provenance)``: provenance names every dive and file used (with its reader) or refused
    (with the reason). No dive usable: one-line InputError."""
    from hadal.grid.points import _COMPILED_MIN_POINTS
    from hadal.grid.tiles import TileScheme, choose_tile_cells, sigma_of_mads, spike_floor, tile_cell_mads
    from hadal.settings.grid import GridParams

    p = params if params is not None else GridParams()
    fill_max_cells, apriori_a_m, apriori_b, prior_weight = (p.fill_max_cells, p.apriori_a_m, p.apriori_b,
                                                            p.prior_weight)
    max_cells = p.max_cells

    scratch = str(scratch_dir)
    if not Path(scratch).is_dir():
        raise InputError(f"scratch directory {scratch} does not exist (or is not a directory)")
    dives, refused_dirs = dive_sources(raw_dirs)
    frame = cruise_frame(dives)
    reads: list[DiveRead] = map(read_dive, [(d, frame, scratch) for d in dives])
    ok_reads = [r for r in reads if r.error is None]
    spec = cruise_grid_spec(ok_reads, resolution_m, max_cells=max_cells)
    n_total = sum(r.n_soundings for r in ok_reads)
    scheme = TileScheme(spec, choose_tile_cells(spec, n_total, tile_cells=tile_cells))
    parts: list[DivePartition] = map(partition_dive, [(r, scheme, scratch) for r in ok_reads])
    good = [p for p in parts if p.error is None]
    if not good:
        raise InputError("no dive of the cruise could be partitioned: "
                         + "; ".join(p.error or "" for p in parts))
    union = dive_union(scheme, good)
    n_points = union.n_points
    tile_points = union.tile_points
    nonempty = [t for t in range(scheme.n_tiles) if tile_points[t]]
    groups = group_tiles(nonempty, [tile_points[t] for t in nonempty], min_task_points)
    n_spikes, sigma0, spikes_dir = 0, float("nan"), None
    if p.spike_removal:  # the dive dtm's spike test, cruise-wide: one noise floor, halos across tiles and dives
        mads = map(tile_cell_mads, [(union, g, p.spike_min_count) for g in groups])
        sigma0 = spike_floor(sigma_of_mads(mads), p.spike_floor_m)
        spikes_dir = str(Path(scratch) / "spikes")
        Path(spikes_dir).mkdir(parents=True, exist_ok=True)
        n_spikes = sum(map(spike_tiles, [(g, union, sigma0, spikes_dir, p.spike_k, p.spike_k_neighbourhood,
                                          p.spike_neighbours, p.spike_min_count) for g in groups]))
    # reduce_cells' choice on all the kept soundings (the in-memory rule)
    compiled = n_points - n_spikes >= _COMPILED_MIN_POINTS
    reduced = map(reduce_tiles, [(g, union, compiled, apriori_a_m, apriori_b, prior_weight, spikes_dir)
                                 for g in groups])
    tiles: list[dict | None] = [None] * scheme.n_tiles
    for g, layers_of in zip(groups, reduced, strict=True):
        for t, layers in zip(g, layers_of, strict=True):
            tiles[t] = layers
    part_err = {p.dive_id: p.error for p in parts if p.error is not None}
    prov: dict[str, Any] = {
        "cruise_frame": {"origin_latitude_deg": frame.origin_latitude_deg,
                         "origin_longitude_deg": frame.origin_longitude_deg,
                         "projection": "transverse Mercator, k=1, WGS84 (centre of the dives' map-frame origins)"},
        "dives": {r.dive_id: {"used": r.error is None and r.dive_id not in part_err,
                              "error": r.error or part_err.get(r.dive_id), "n_soundings": r.n_soundings,
                              "n_soundings_implausible": r.n_implausible, "files_used": r.used,
                              "files_refused": r.refused} for r in reads},
        "refused_raw_dirs": refused_dirs,
        "raw_dirs": {d.dive_id: d.raw_dir for d in dives},
    }
    used_ids = [p.dive_id for p in good]
    attrs = {
        "n_soundings_input": int(sum(p.n_input for p in good)),
        "n_soundings_nonfinite": int(sum(p.n_nonfinite for p in good)), "n_soundings_outside": 0,
        "n_soundings_spikes": int(n_spikes), "n_soundings_sor": 0, "n_soundings_used": int(n_points - n_spikes),
        "spike_noise_floor_m": sigma0,
        "n_soundings_implausible": int(sum(r.n_implausible for r in ok_reads)),
        "resolution_m": float(resolution_m), "cruise_dives": ", ".join(used_ids),
        "cruise_dives_refused": "; ".join([f"{k}: {v}" for k, v in refused_dirs.items()]
                                          + [r.error or "" for r in reads if r.error]
                                          + [v for v in part_err.values()]),
        "multibeam_readers": "; ".join(f"{r.dive_id}/{Path(f).name}: {t}" for r in ok_reads
                                       for f, t in r.used.items()),
    }
    method = {"spike_k": p.spike_k, "spike_k_neighbourhood": p.spike_k_neighbourhood,
              "spike_neighbours": p.spike_neighbours, "spike_min_count": p.spike_min_count,
              "spike_floor_m": p.spike_floor_m, "remove_spikes": p.spike_removal, "sor": False, "sor_neighbors": 16,
              "sor_std_ratio": 3.0, "fill_max_cells": fill_max_cells, "apriori_a_m": apriori_a_m,
              "apriori_b": apriori_b, "prior_weight": prior_weight}
    ds = assemble(scheme, tiles, frame, fill_max_cells=fill_max_cells, apriori_a_m=apriori_a_m,
                  apriori_b=apriori_b, prior_weight=prior_weight, attrs=attrs, method=method)
    return ds, prov


__all__ = ["DivePartition", "DiveRead", "DiveSource", "assemble", "cruise_dtm_dataset", "cruise_frame",
           "cruise_grid_spec", "dive_sources", "partition_dive", "read_dive", "reduce_tile",
           "reduce_tiles", "group_tiles", "serial_map"]
