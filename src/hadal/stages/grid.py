"""Gridding: the ``dtm`` and ``laser`` stages (:mod:`hadal.stages.dtm`, :mod:`hadal.stages.laser`), which share the
configuration section ``grid`` (:class:`Params`); ``hadal stage grid`` runs both.

Both read the raw files listed in ``dive.yaml``; no upstream product. Science in :mod:`hadal.grid`.

* ``dtm`` (:func:`run_dtm`): ``sources.multibeam`` soundings gridded at ``dtm_resolution_m`` (:func:`make_dtm`);
  without soundings, the first ``sources.prior_grid`` (GeoTIFF, NetCDF COARDS/CF, GMT netCDF .grd, other GDAL
  rasters) resampled onto the map frame at about its native resolution (:mod:`hadal.grid.prior`: CRS,
  registration and elevation/depth sign handled and recorded in the attributes). With both, multibeam
  wins: the prior grid is not used, or (``prior_fill``) fills the DTM's empty cells (``filled`` = 2).
* ``laser_grids`` (:func:`run_laser`): one ``<stem>.nc`` per ``sources.laser`` entry whatever its name (stems made
  unique), the kind detected from the content: point clouds (PLY, PCD, LAS/LAZ, xyz text) gridded at
  ``laser_resolution_m`` (:func:`hadal.grid.laser.grid_laser`), rasters (GeoTIFF, NetCDF) loaded at their
  own resolution (:func:`hadal.grid.laser.laser_grid_from_raster`). ``elevation_m`` is positive up.

The two were one stage; split, the DTM chain (dtm -> suitability -> match) no longer waits for the laser clouds,
and a laser setting re-runs only the laser grids (each stage's fingerprint holds only the fields it uses:
:data:`DTM_FIELDS`, :data:`LASER_FIELDS`). Every bad input is a one-line :class:`InputError` naming the file, and
the stage publishes nothing: all of a stage's inputs are gridded before its product is published.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Any, NamedTuple

from hadal.budget import check_memory, memory_limit_bytes
from hadal.confine import files_read
from hadal.errors import ConfigError, InputError, StageError
from hadal.settings.grid import GridParams as Params

if TYPE_CHECKING:
    import numpy as np

    from hadal.stages import StageContext
    from hadal.store import ProductVersion


#: float64 (y, x) layers a multibeam DTM holds at its peak (mean, median, count, std, uncertainty, filled and the
#: gridding/hole-filling intermediates)
DTM_LAYERS = 10
#: bytes a sounding takes at the in-memory DTM's peak, its x, y, depth included (reading, cell index, the per-cell
#: sort and deviations, the neighbour search's sorted copies, flags): the sample dive's 3.45 M soundings peak at
#: 776 MiB of which 210 MiB imports (bench/bench_dtm_tiled.py). Above the memory budget the soundings go to disk as
#: they are read and the DTM is made out of core (:func:`hadal.grid.tiles.grid_multibeam_tiled`: the same arrays;
#: one chunk, one tile with its halo and the layers held), below it in memory (out of core costs 1.15x the CPU
#: there, same bench)
DTM_BYTES_PER_SOUNDING = 170
#: float64 (y, x) layers of a laser grid at its peak (mean, std, count, second moment, the SOR pass's moments)
LASER_LAYERS = 8


def _xy_extent(x: np.ndarray, y: np.ndarray) -> tuple[float, float, float, float] | None:
    """``(xmin, ymin, xmax, ymax)`` of the finite ``x``, ``y`` (None: none)."""
    import numpy as np

    ok = np.isfinite(x) & np.isfinite(y)
    if not ok.any():
        return None
    return float(np.min(x[ok])), float(np.min(y[ok])), float(np.max(x[ok])), float(np.max(y[ok]))


def grid_memory_bytes(x: np.ndarray, y: np.ndarray, resolution_m: float, layers: int) -> tuple[float, int, int]:
    """``(bytes, nx, ny)`` of a grid at ``resolution_m`` covering the finite points ``x``, ``y``."""
    return _extent_memory_bytes(_xy_extent(x, y), resolution_m, layers)


def _extent_memory_bytes(ext, resolution_m: float, layers: int) -> tuple[float, int, int]:
    if ext is None:
        return 0.0, 0, 0
    nx, ny = int((ext[2] - ext[0]) // resolution_m) + 2, int((ext[3] - ext[1]) // resolution_m) + 2
    return float(nx) * float(ny) * layers * 8.0, nx, ny


def check_grid_memory(what: str, x: np.ndarray, y: np.ndarray, resolution_m: float, layers: int,
                      limit_bytes: float | None, setting: str, value, max_cells: int | None = None, *,
                      extent: tuple[float, float, float, float] | None = None) -> None:
    """Refuse (one-line ConfigError) a grid whose cells x layers x 8 bytes exceed the memory budget (the grid over
    the finite ``x``, ``y``, or over ``extent`` when given; ``x``, ``y`` are then not used).

    A grid over ``max_cells`` is left to the gridder's own cell-count refusal (an InputError, before it allocates).
    """
    need, nx, ny = _extent_memory_bytes(extent if extent is not None else _xy_extent(x, y), resolution_m, layers)
    if max_cells is not None and float(nx) * float(ny) > max_cells * 1.01:
        return
    check_memory(f"{what} ({nx:,} x {ny:,} cells x {layers} layers x 8 bytes)", need,
                 memory_limit_bytes() if limit_bytes is None else limit_bytes, setting=setting, value=value,
                 advice=f"use a coarser {setting} or raise resources.max_memory_gb")


def _frame_attrs(ctx: StageContext) -> dict:
    from hadal.products.io import dive_attributes  # launch position/time: ACDD extents of local-frame grids

    return {**dive_attributes(ctx.dive), "platform": ctx.dive.platform}


def _compress(ds) -> None:
    """gzip the (y, x) layers of large grids (a 25 m x 25 m submap at 10 mm is 6 M cells per layer) in 512 x 512
    chunks (:func:`hadal.products.compression.gzip_encoding`)."""
    from hadal.products.compression import gzip_encoding

    for v in ds.data_vars:
        if ds[v].dims == ("y", "x"):
            ny, nx = ds[v].shape
            ds[v].encoding.update(gzip_encoding((min(ny, 512), min(nx, 512))))


def _check_implausible(files: list[Path], n_implausible: int, n: int, abs_median) -> None:
    """An error when most soundings are deeper/higher than anywhere on Earth (``abs_median()``: the median
    ``|depth|`` of all, for the hint)."""
    from hadal.grid.prior import MAX_ABS_DEPTH_M

    if n_implausible > 0.5 * n:
        med = float(abs_median())
        hint = (f" (feet? x 0.3048 = {med * 0.3048:.0f} m)" if med * 0.3048 <= MAX_ABS_DEPTH_M else "")
        raise InputError(f"{', '.join(str(f) for f in files)}: {n_implausible} of {n} soundings are beyond "
                         f"+-{MAX_ABS_DEPTH_M:g} m (median |depth| {med:.0f}){hint}: check the depth units/column")


def _drop_implausible(files: list[Path], x: np.ndarray, y: np.ndarray, dep: np.ndarray):
    """Drop soundings deeper/higher than anywhere on Earth (fill values or a unit error; NaN/inf are the gridder's
    'nonfinite'); an error when they are most of them. Returns x, y, depth and the number dropped."""
    import numpy as np

    from hadal.grid.prior import MAX_ABS_DEPTH_M

    bad = np.isfinite(dep) & (np.abs(dep) > MAX_ABS_DEPTH_M)
    n_implausible = int(bad.sum())
    if n_implausible:
        _check_implausible(files, n_implausible, dep.size, lambda: np.median(np.abs(dep)))
        x, y, dep = x[~bad], y[~bad], dep[~bad]
    return x, y, dep, n_implausible


def _dtm_resolution(p: Params, auto) -> tuple[float | str, str]:
    """The DTM cell size (``grid.dtm_resolution_m``, or the automatic one ``auto()`` = ``(size, stats)`` of
    :func:`hadal.grid.multibeam.auto_resolution_m`) and how it was chosen."""
    res_m, how = p.dtm_resolution_m, "grid.dtm_resolution_m"
    if res_m == "auto":
        res_m, stats = auto()
        how = (f"auto: 2 x the 90th percentile ({stats['nn_quantile_m']:.3g} m) of the soundings' nearest-neighbour "
               "distances, on the 1-2-5 series")
    return res_m, how


def _spill_above_points(p: Params, limit_bytes: float | None, out_of_core: bool | None) -> int | None:
    """Soundings read above which they go to disk and the DTM is made out of core: those whose in-memory DTM
    (:data:`DTM_BYTES_PER_SOUNDING`) would exceed the memory budget (``out_of_core`` forces the choice: 0 or None);
    never with ``grid.sor`` (a whole-cloud statistic)."""
    if p.sor or out_of_core is False:
        return None
    if out_of_core:
        return 0
    limit = memory_limit_bytes() if limit_bytes is None else limit_bytes
    return int(limit // DTM_BYTES_PER_SOUNDING)


def _grid_dtm_spilled(files: list[Path], sp, p: Params, limit_bytes: float | None, progress):
    """The DTM of soundings kept on disk (:class:`hadal.grid.soundings.SpilledSoundings`) out of core
    (:func:`hadal.grid.tiles.grid_multibeam_tiled`, the same Dataset as :func:`hadal.grid.multibeam.grid_multibeam`
    of them in memory): the implausible ones counted and dropped, the resolution from a subsample read back, the
    grid from their extent, the soundings streamed from disk into the tiles. Returns ``(ds, res_m, how,
    n_implausible)``."""
    import numpy as np

    from hadal.grid.multibeam import auto_resolution_of_sample, auto_resolution_step
    from hadal.grid.points import make_grid_spec
    from hadal.grid.tiles import grid_multibeam_tiled

    _check_implausible(files, sp.n_implausible, sp.n, sp.abs_depth_median)

    def auto():
        step = auto_resolution_step(sp.n_xy)
        return auto_resolution_of_sample(*sp.xy_subsample(step), step, sp.n_xy)

    res_m, how = _dtm_resolution(p, auto)
    check_grid_memory("the DTM", np.empty(0), np.empty(0), float(res_m), DTM_LAYERS + (2 if p.prior_fill else 0), limit_bytes,
                      "grid.dtm_resolution_m",
                      f"auto ({float(res_m):g} m)" if p.dtm_resolution_m == "auto" else float(res_m), p.max_cells,
                      extent=sp.extent_xy or (0.0, 0.0, 0.0, 0.0))
    n = sp.n - sp.n_implausible
    if sp.extent is None:
        raise InputError(f"all {n} soundings have NaN/inf coordinates; nothing to grid")
    spec = make_grid_spec(float(res_m), sp.extent, max_cells=p.max_cells, snap=True)
    ds = grid_multibeam_tiled(
        sp.chunks(), spec, check_inside=False, spike_k=p.spike_k, spike_k_neighbourhood=p.spike_k_neighbourhood,
        spike_neighbours=p.spike_neighbours, spike_min_count=p.spike_min_count, spike_floor_m=p.spike_floor_m,
        remove_spikes=p.spike_removal, fill_max_cells=p.fill_max_cells, apriori_a_m=p.apriori_a_m,
        apriori_b=p.apriori_b, prior_weight=p.prior_weight, expected_points=n, progress=progress)
    return ds, res_m, how, sp.n_implausible


def make_dtm(files: list[Path], frame, p: Params, hints: list | None = None, readers: dict | None = None,
             chunk_points: int = 1_000_000, *, memory_limit_bytes: float | None = None, progress=None,
             out_of_core: bool | None = None, scratch_dir=None):
    """Read multibeam sounding files, project them into ``frame`` and grid them (returns the DTM Dataset).

    Each file is streamed through :func:`hadal.grid.sonar.iter_multibeam` (xyz text in any compression,
    GSF, Kongsberg .kmall/.all, Reson .s7k; format detected from the content) with the reading hints of
    its ``dive.yaml`` entry (``hints[i]``, a :class:`hadal.dive.SourceFile` or None; :func:`hadal.grid.soundings.
    read_soundings`). Chunks are projected
    as they arrive and only x, y, depth are kept (:class:`hadal.grid.sonar.ColumnAccumulator`: ~1x). Projected soundings are
    converted from their declared CRS (``crs:``) to the map frame; ``crs: local`` means they already are
    in the dive's map frame. ``frame`` None: a frame centred on the first file's first soundings.
    ``readers``, when given, receives ``{str(file): "reader (format ...)"}`` for the manifest; the same text
    is in ``ds.attrs["multibeam_readers"]``. Once the soundings read are more than the in-memory gridding fits in
    the memory budget (or from the first with ``out_of_core``), every chunk goes to disk as it is read (under
    ``scratch_dir``, default the system temp dir) and they are gridded tile by tile (:func:`_grid_dtm_spilled`; the
    same DTM).
    """

    from hadal.grid.multibeam import add_geo, auto_resolution_m, grid_multibeam
    from hadal.grid.soundings import SpilledSoundings, read_soundings

    if hints is not None and len(hints) != len(files):
        raise ValueError("make_dtm: hints must have one entry per file")
    cols, frame, used = read_soundings(files, frame, hints, chunk_points=chunk_points, readers=readers,
                                       progress=progress, memory_limit_bytes=memory_limit_bytes,
                                       spill_above_points=_spill_above_points(p, memory_limit_bytes, out_of_core),
                                       scratch_dir=scratch_dir)
    if isinstance(cols, SpilledSoundings):
        with cols:
            ds, res_m, how, n_implausible = _grid_dtm_spilled(files, cols, p, memory_limit_bytes, progress)
    else:
        x, y, dep = cols
        del cols
        x, y, dep, n_implausible = _drop_implausible(files, x, y, dep)
        res_m, how = _dtm_resolution(p, lambda: auto_resolution_m(x, y))
        check_grid_memory("the DTM", x, y, float(res_m), DTM_LAYERS + (2 if p.prior_fill else 0),
                          memory_limit_bytes, "grid.dtm_resolution_m",
                          f"auto ({float(res_m):g} m)" if p.dtm_resolution_m == "auto" else float(res_m), p.max_cells)
        ds = grid_multibeam(
            x, y, dep, float(res_m), remove_spikes=p.spike_removal, spike_k=p.spike_k,
            spike_k_neighbourhood=p.spike_k_neighbourhood, spike_neighbours=p.spike_neighbours, spike_min_count=p.spike_min_count,
            spike_floor_m=p.spike_floor_m, sor=p.sor,
            sor_neighbors=p.sor_neighbors, sor_std_ratio=p.sor_std_ratio, fill_max_cells=p.fill_max_cells,
            apriori_a_m=p.apriori_a_m, apriori_b=p.apriori_b, prior_weight=p.prior_weight, max_cells=p.max_cells,
            progress=progress,
        )
    ds = add_geo(ds, frame)
    ds.attrs["multibeam_readers"] = "; ".join(used)
    ds.attrs["n_soundings_implausible"] = n_implausible
    ds.attrs["resolution_m"] = float(res_m)
    ds.attrs["resolution_choice"] = how
    _compress(ds)
    return ds


def _as_input_error(f: Path, exc: Exception) -> InputError | ConfigError:
    """One line naming the file, whatever a reader library raised (an ``InputError`` included); a budget or
    setting refusal (``ConfigError``, also a ``ValueError``) is returned as it is."""
    if isinstance(exc, ConfigError):
        return exc
    msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return InputError(msg if str(f) in msg or f.name in msg else f"{f}: {msg}")


def _existing(ctx: StageContext, entries, what: str) -> list[tuple[Path, object]]:
    from hadal.dive import resolve_source

    out = []
    for sf in entries:
        f = resolve_source(ctx.raw_dir, sf)
        if not f.is_file():
            raise InputError(f"{what} file {f} listed in dive.yaml does not exist")
        out.append((f, sf))
    return out


def _drop_duplicates(entries: list[tuple[Path, object]], what: str, log) -> list[tuple[Path, object]]:
    """Drop sources listed twice (same resolved path) or with identical content (SHA-256; only files of equal
    size are hashed), keeping the first, with a WARNING: gridding the same soundings twice doubles ``count`` and
    shrinks ``uncertainty_m`` by ~sqrt(2)."""
    import hashlib

    by_size: dict[int, list[int]] = {}
    for i, (f, _) in enumerate(entries):
        by_size.setdefault(f.stat().st_size, []).append(i)
    drop: dict[int, str] = {}
    for idx in by_size.values():
        if len(idx) < 2:
            continue
        seen: dict[object, int] = {}
        for i in idx:
            f = entries[i][0]
            real = f.resolve()
            if real in seen:
                drop[i] = f"listed twice (same file as entry {seen[real] + 1})"
                continue
            h = hashlib.sha256()
            with open(f, "rb") as fh:
                for block in iter(lambda fh=fh: fh.read(1 << 20), b""):
                    h.update(block)
            key = h.hexdigest()
            if key in seen:
                drop[i] = f"identical content (SHA-256 {key[:12]}...) to {entries[seen[key]][0].name}"
                continue
            seen[real] = seen[key] = i
    for i, why in sorted(drop.items()):
        log.warning("%s: %s %s: %s; dropped (its soundings would be counted twice)", what, entries[i][0].name,
                    f"(entry {i + 1})", why)
    return [e for i, e in enumerate(entries) if i not in drop]


def _hint(sf, name: str):
    return getattr(sf, name, None)


def _unique_stems(files: list[Path]) -> list[str]:
    """Product file stems for the laser inputs: the file's stem, made unique (``scan``, ``scan_tif``,
    ``scan_2`` ...) when two inputs share one, restricted to safe characters."""
    import re

    out: list[str] = []
    for f in files:
        stem = re.sub(r"[^A-Za-z0-9._-]+", "_", f.name.split(".")[0] or f.stem) or "laser"
        name = stem
        if name in out:
            ext = re.sub(r"[^A-Za-z0-9]+", "", "".join(f.suffixes))
            name = f"{stem}_{ext}" if ext else stem
        k = 2
        while name in out:
            name = f"{stem}_{k}"
            k += 1
        out.append(name)
    return out


def _fill_from_prior(dtm, f: Path, sf, frame) -> int:
    """Fill the multibeam DTM's empty cells from a prior grid (``filled`` = 2); returns the cells filled."""
    import numpy as np

    from hadal.grid.prior import sample_depth

    try:
        empty = ~np.isfinite(dtm["depth_m"].values)
        xx, yy = np.meshgrid(dtm["x"].values, dtm["y"].values)
        v = sample_depth(f, frame, xx[empty], yy[empty], z_positive_hint=_hint(sf, "z_positive"),
                         crs=_hint(sf, "crs"), variable=_hint(sf, "variable"), format=_hint(sf, "format"),
                         z_units=_hint(sf, "z_units"))
    except (OSError, ValueError, RuntimeError, KeyError, TypeError) as exc:
        raise _as_input_error(f, exc) from None
    ok = np.isfinite(v)
    idx = tuple(a[ok] for a in np.nonzero(empty))
    for var in ("depth_m", "depth_median_m"):
        if var in dtm:
            a = dtm[var].values.copy()
            a[idx] = v[ok]
            dtm[var].values = a
    if "filled" in dtm:
        fl = dtm["filled"].values.copy()
        fl[idx] = 2
        dtm["filled"].values = fl
        dtm["filled"].attrs.update({"flag_values": np.array([0, 1, 2], np.int8),
                                    "flag_meanings": "measured interpolated prior_grid"})
    return int(ok.sum())


def _check_laser_memory(pts: np.ndarray, p: Params, limit_bytes: float | None) -> None:
    """The laser grid's cells x layers against the budget; 'auto' is at least the paper's 10 mm, so the
    (costly) automatic cell size is only computed when 10 mm cells would not fit."""
    from hadal.grid.laser import G_RES_M
    from hadal.grid.laser import auto_resolution_m as laser_auto_resolution_m

    x, y = pts[:, 0], pts[:, 1]
    if p.laser_resolution_m != "auto":
        check_grid_memory("the laser grid", x, y, float(p.laser_resolution_m), LASER_LAYERS, limit_bytes,
                          "grid.laser_resolution_m", float(p.laser_resolution_m), p.max_cells)
        return
    limit = memory_limit_bytes() if limit_bytes is None else limit_bytes
    if grid_memory_bytes(x, y, G_RES_M, LASER_LAYERS)[0] <= limit:
        return
    res, _ = laser_auto_resolution_m(pts)
    check_grid_memory("the laser grid", x, y, float(res), LASER_LAYERS, limit, "grid.laser_resolution_m",
                      f"auto ({float(res):g} m)", p.max_cells)


def _laser_grid(ctx: StageContext, f: Path, sf, p: Params, limit_bytes: float | None = None):
    """One laser input (point cloud or raster, detected by content) -> a laser grid Dataset."""
    import warnings

    import xarray as xr

    from hadal.grid.clouds import cloud_metadata, cloud_to_frame
    from hadal.grid.laser import grid_laser, laser_grid_from_raster
    from hadal.grid.prior import z_positive
    from hadal.grid.readers import _CLOUD_KINDS, _kind_of, read_grid, read_point_cloud_meta, reader_of

    try:
        kind = _kind_of(f, _hint(sf, "format"))
        if kind not in _CLOUD_KINDS and kind != "text":  # rasters (and other binaries: GDAL may know them)
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # a mislabelled CRS is expected for laser rasters; recorded
                da = read_grid(f, variable=_hint(sf, "variable"), format=_hint(sf, "format"), crs=_hint(sf, "crs"),
                               max_bytes=memory_limit_bytes(ctx.config), z_units=_hint(sf, "z_units"))
            pos, reason = z_positive(da, _hint(sf, "z_positive"))
            frame = ctx.dive.frame("grid") if da.attrs["crs_kind"] == "geographic" else None
            ds = laser_grid_from_raster(da, z_positive=pos, z_reason=reason, frame=frame)
            return ds, da.attrs.get("reader", reader_of(kind)), "raster"
        pts, meta = read_point_cloud_meta(f, format=_hint(sf, "format"), columns=_hint(sf, "columns"), hints=sf,
                                          memory_limit_bytes=memory_limit_bytes(ctx.config))
        if meta.get("z_positive"):  # LAS/PCD: from the file's format (or dive.yaml), never from the values' sign
            pos, reason = meta["z_positive"], meta["z_positive_from"]
        else:
            pos, reason = z_positive(xr.DataArray(pts[:, 2]), _hint(sf, "z_positive"))
        if pos == "down":
            pts = pts.copy()
            pts[:, 2] = -pts[:, 2]
        if meta.get("crs_kind") == "geographic":  # lon/lat cloud: into the dive's map frame
            pts = cloud_to_frame(f, pts, ctx.dive.frame("grid"))
        _check_laser_memory(pts, p, limit_bytes)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", UserWarning)  # the quantisation note is logged below
            ds = grid_laser(pts, p.laser_resolution_m, voxel_size_m=p.laser_voxel_m,
                            sor_neighbors=p.laser_sor_neighbors, sor_std_ratio=p.laser_sor_std_ratio,
                            surface_tol_m=p.laser_surface_tol_m, max_cells=p.max_cells)
        if ds.attrs.get("coordinate_quantisation"):
            ctx.log.warning("laser %s: %s", f.name, ds.attrs["coordinate_quantisation"])
        ds.attrs.update({"laser_input": "point cloud", "source_format": kind, "source_reader": reader_of(kind),
                         "z_positive_source": pos, "z_sign_detection": reason, "z_sign_flipped": int(pos == "down")})
        cloud_metadata(ds, meta)
        if meta.get("crs_kind") == "geographic":  # gridded in the dive's map frame: georeferenced by it
            from hadal.grid.multibeam import add_geo

            long_names = (ds["x"].attrs.get("long_name"), ds["y"].attrs.get("long_name"))
            ds = add_geo(ds, ctx.dive.frame("grid"), latlon=False)
            ds["x"].attrs["long_name"], ds["y"].attrs["long_name"] = long_names
        if meta.get("crs_note"):
            ctx.log.warning("laser %s: %s", f.name, meta["crs_note"])
        return ds, reader_of(kind), "point cloud"
    except (OSError, ValueError, RuntimeError, KeyError, TypeError, MemoryError) as exc:
        raise _as_input_error(f, exc) from None


class _Dtm(NamedTuple):
    """The DTM made in memory before anything is published, with its inputs and its NetCDF texts."""

    ds: Any
    inputs: list[Path]
    title: str
    summary: str
    keywords: str


def _fill_dtm_from_priors(ctx: StageContext, p: Params, dtm, priors: list[tuple[Path, object]], frame,
                          readers: dict[str, str], inputs: list[Path]) -> None:
    """Multibeam wins over prior grids: fill its empty cells from them (``grid.prior_fill``) or record them unused."""
    names = ", ".join(f.name for f, _ in priors)
    if p.prior_fill:
        n = 0
        for f, sf in priors:
            n += _fill_from_prior(dtm, f, sf, frame)
            readers[str(f)] = "prior grid fill"
        inputs += [q for f, _ in priors for q in files_read(f)]  # a VRT's sources too (hadal.confine)
        dtm.attrs["prior_grid_use"] = f"multibeam wins; empty cells filled from {names} (filled = 2)"
        dtm.attrs["n_cells_prior_filled"] = n
        ctx.log.info("dtm: multibeam wins over the prior grid(s) %s; %d empty cells filled from them", names, n)
    else:
        dtm.attrs["prior_grid_use"] = f"ignored: multibeam soundings win ({names} not used; grid.prior_fill)"
        ctx.log.info("dtm: multibeam soundings win; prior grid(s) %s not used (set grid.prior_fill to fill "
                     "empty cells from them)", names)


def _multibeam_dtm(ctx: StageContext, p: Params, priors: list[tuple[Path, object]], readers: dict[str, str],
                   limit: float | None) -> _Dtm:
    """The DTM from the dive's multibeam soundings (duplicates dropped), prior grids filling its empty cells."""
    from hadal.grid.prior import MAX_ABS_DEPTH_M

    mb = _drop_duplicates(_existing(ctx, ctx.dive.sources.multibeam, "multibeam"), "multibeam", ctx.log)
    mb_files = [f for f, _ in mb]
    frame = ctx.dive.frame("grid")
    dtm = make_dtm(mb_files, frame, p, hints=[sf for _, sf in mb], readers=readers, memory_limit_bytes=limit,
                   progress=ctx.progress)
    inputs = list(mb_files)
    ctx.log.info("dtm: %d x %d cells at %g m, %d soundings (%d spikes removed, %d cells filled)",
                 dtm.sizes["x"], dtm.sizes["y"], dtm.attrs["resolution_m"], dtm.attrs["n_soundings_used"],
                 dtm.attrs["n_soundings_spikes"], dtm.attrs["n_cells_filled"])
    dtm.attrs["dtm_source"] = "multibeam"
    if dtm.attrs["n_soundings_implausible"]:
        ctx.log.warning("dtm: %d sounding(s) deeper/higher than %g m (fill values?) dropped",
                        dtm.attrs["n_soundings_implausible"], MAX_ABS_DEPTH_M)
    if priors:
        _fill_dtm_from_priors(ctx, p, dtm, priors, frame, readers, inputs)
    summary = ("Multibeam soundings projected into the dive's transverse-Mercator map frame and gridded "
               f"at {dtm.attrs['resolution_m']:g} m ({dtm.attrs['resolution_choice']}): per-cell mean/median/count/std after robust spike removal, "
               "standard uncertainty, small interior holes filled by harmonic interpolation (flagged).")
    return _Dtm(dtm, inputs, f"Reference DTM of dive {ctx.dive_id} from multibeam soundings", summary,
                "bathymetry, multibeam, digital terrain model")


def _log_prior_dtm(ctx: StageContext, f: Path, dtm) -> None:
    """The prior-grid DTM's log lines: how it was read and resampled, its depth check, warning and crop."""
    ctx.log.info("dtm: prior grid %s (%s, %s, %s registration) resampled to %d x %d cells at %g m; z %s (%s)",
                 f.name, dtm.attrs["prior_grid_format"], dtm.attrs["prior_grid_crs"],
                 dtm.attrs["prior_grid_registration"], dtm.sizes["x"], dtm.sizes["y"], dtm.attrs["resolution"],
                 "elevation, negated" if dtm.attrs["z_sign_flipped"] else "depth", dtm.attrs["z_sign_detection"])
    for k in ("prior_grid_depth_check", "prior_grid_warning"):
        if dtm.attrs.get(k):
            ctx.log.warning("dtm: prior grid %s: %s", f.name, dtm.attrs[k])
    if dtm.attrs.get("prior_grid_cropped_to_m"):
        a = dtm.attrs
        ctx.log.warning(
            "dtm: prior grid %s cropped to %g km around the map frame origin (grid.prior_max_extent_km): kept "
            "lon %.4g..%.4g, lat %.4g..%.4g; %.1f%% of its area and %.1f%% of its depth range (%.0f..%.0f m, "
            "kept %.0f..%.0f m) lost", f.name, a["prior_grid_cropped_to_m"] / 1000,
            a.get("prior_grid_kept_lon_min", float("nan")), a.get("prior_grid_kept_lon_max", float("nan")),
            a.get("prior_grid_kept_lat_min", float("nan")), a.get("prior_grid_kept_lat_max", float("nan")),
            100 * a.get("prior_grid_crop_area_fraction_lost", float("nan")),
            100 * a.get("prior_grid_crop_depth_range_lost_fraction", float("nan")),
            a.get("prior_grid_source_depth_min_m", float("nan")), a.get("prior_grid_source_depth_max_m", float("nan")),
            a.get("prior_grid_kept_depth_min_m", float("nan")), a.get("prior_grid_kept_depth_max_m", float("nan")))


def _load_priors(ctx: StageContext, p: Params, priors: list[tuple[Path, object]], frame):
    """Every listed prior grid read (:func:`hadal.grid.prior.load_prior`) and checked against the map frame:
    ``(usable, refused)``; a refused grid is named with its one-line reason (logged as a WARNING)."""
    from hadal.grid.prior import frame_bounds, load_prior

    usable, refused = [], []
    for f, sf in priors:
        try:
            g = load_prior(f, z_positive_hint=_hint(sf, "z_positive"), crs=_hint(sf, "crs"),
                           variable=_hint(sf, "variable"), format=_hint(sf, "format"), z_units=_hint(sf, "z_units"),
                           max_read_bytes=memory_limit_bytes(ctx.config))
            frame_bounds(g.da, frame, p.prior_max_extent_km * 1000.0)
        except InputError as exc:
            refused.append((f, str(exc)))
            continue
        except (OSError, ValueError, RuntimeError, KeyError, TypeError) as exc:
            refused.append((f, str(_as_input_error(f, exc))))
            continue
        usable.append(g)
    return usable, refused


def _prior_grid_dtm(ctx: StageContext, p: Params, priors: list[tuple[Path, object]], readers: dict[str, str]) -> _Dtm:
    """The DTM from every listed prior grid (no multibeam): one grid resampled onto the map frame, several
    mosaicked (:func:`hadal.grid.prior.prior_mosaic`); a grid that cannot be used is refused by name."""
    from hadal.grid.prior import prior_mosaic

    frame = ctx.dive.frame("grid")
    usable, refused = _load_priors(ctx, p, priors, frame)
    if not usable:
        if len(refused) == 1:
            raise InputError(refused[0][1])
        raise InputError("no prior grid can be used: " + "; ".join(why for _, why in refused))
    try:
        dtm = prior_mosaic(usable, frame, resolution_m=p.prior_resolution_m,
                           max_extent_m=p.prior_max_extent_km * 1000.0, max_cells=p.max_cells)
    except (OSError, ValueError, RuntimeError, KeyError, TypeError) as exc:
        raise _as_input_error(usable[0].path, exc) from None
    for g in usable:
        readers[str(g.path)] = g.da.attrs.get("reader", "")
    if refused:
        dtm.attrs["prior_grid_refused"] = "; ".join(why for _, why in refused)
        for f, why in refused:
            ctx.log.warning("dtm: prior grid %s refused: %s", f.name, why)
    names = ", ".join(g.name for g in usable)
    if len(usable) > 1:
        ctx.log.info("dtm: %d prior grids mosaicked (%s) at %g m: %s", len(usable), names,
                     dtm.attrs["resolution"], dtm.attrs["prior_grid_sources"])
        for k in ("prior_grid_depth_check", "prior_grid_warning", "prior_grid_mosaic_resolution_note",
                  "prior_grid_cropped"):
            if dtm.attrs.get(k):
                ctx.log.warning("dtm: prior grids: %s", dtm.attrs[k])
    else:
        _log_prior_dtm(ctx, usable[0].path, dtm)
    if dtm.attrs.get("n_cells_land"):
        ctx.log.info("dtm: %d cell(s) are land in the prior grid(s): masked (depth_m NaN, land = 1)",
                     dtm.attrs["n_cells_land"])
    what = (f"Prior bathymetry grid {names} ({dtm.attrs['prior_grid_crs']}) resampled bilinearly onto"
            if len(usable) == 1 else f"Prior bathymetry grids {names} mosaicked (finer grid wins, then listing "
                                     "order; layer prior_grid_source) and resampled bilinearly onto")
    summary = (f"{what} the dive's transverse-Mercator map frame at {dtm.attrs['resolution']:g} m; depth positive "
               "down, land (above sea level) masked (layer 'land'). No soundings: count, uncertainty and fill "
               "layers are absent.")
    return _Dtm(dtm, [q for g in usable for q in files_read(g.path)],
                f"Reference DTM of dive {ctx.dive_id} from the prior grid{'s' if len(usable) > 1 else ''} {names}",
                summary, "bathymetry, prior grid, digital terrain model")


def _grid_laser_inputs(ctx: StageContext, p: Params, laser: list[tuple[Path, object]], readers: dict[str, str],
                       limit: float | None) -> list[tuple[Path, str, Any, str]]:
    """Every laser input gridded (in the map frame with ``grid.laser_frame: map``): (file, stem, Dataset, kind)."""
    from hadal.grid.multibeam import add_geo

    grids = []
    stems = _unique_stems([f for f, _ in laser])
    for (f, sf), stem in zip(ctx.progress.track(laser, "gridding laser inputs", total=len(laser)), stems, strict=True):
        ds, reader, what = _laser_grid(ctx, f, sf, p, limit)
        readers[str(f)] = reader
        ds.attrs["submap"] = stem
        ds.attrs["source_file"] = f.name
        if p.laser_frame == "map" and "source_crs_wkt" not in ds.attrs and "map frame" not in ds["x"].attrs.get(
                "long_name", ""):
            ds = add_geo(ds, ctx.dive.frame("grid"), latlon=False)
            ds["x"].attrs["long_name"] = "x (east) in the dive's map frame"
            ds["y"].attrs["long_name"] = "y (north) in the dive's map frame"
        _compress(ds)
        grids.append((f, stem, ds, what))
        ctx.log.info("laser %s (%s %s): %d x %d cells at %g m, %.0f%% mapped", stem, what, f.name, ds.sizes["x"],
                     ds.sizes["y"], ds.attrs["resolution"], 100 * ds.attrs["mapped_fraction"])
    return grids


def _dtm_manifest_extra(dtm: _Dtm, readers: dict[str, str]) -> dict[str, Any]:
    """The ``dtm`` manifest's ``extra``: the ``n_*`` counts, source, prior-grid crop and the readers of its inputs."""
    attrs = dtm.ds.attrs
    summary = {k: attrs[k] for k in attrs if k.startswith("n_")}
    summary["dtm_source"] = attrs["dtm_source"]
    summary.update({k: attrs[k] for k in attrs if k.startswith(("prior_grid_crop", "prior_grid_kept_",
                                                                 "prior_grid_source_depth"))})
    extra = {"summary": summary, "readers": {Path(k).name: v for k, v in readers.items() if Path(k) in dtm.inputs}}
    if "prior_grid_use" in attrs:
        extra["prior_grid_use"] = attrs["prior_grid_use"]
    return extra


def _publish_dtm(ctx: StageContext, p: Params, params: dict, dtm: _Dtm, readers: dict[str, str]):
    """Publish ``dtm``: ``dtm.nc``, the same DTM as a COG (``dtm.tif``) and, with ``grid.zarr``, a Zarr store."""
    from hadal.products.io import write_netcdf

    with ctx.store.publish(ctx.dive_id, "dtm", parameters=params, inputs=dtm.inputs,
                           extra=_dtm_manifest_extra(dtm, readers)) as draft:
        write_netcdf(dtm.ds, draft.path / "dtm.nc", title=dtm.title, summary=dtm.summary, keywords=dtm.keywords,
                     processing_level="L3 gridded", provenance_from=draft, **_frame_attrs(ctx))
        from hadal.products.geotiff import write_grid_cog  # the DTM as a COG in its own frame, cell for cell

        write_grid_cog(dtm.ds, draft.path / "dtm.tif", "depth_m")
        if p.zarr:  # the same DTM as a chunked Zarr store (hadal.products.io.write_zarr)
            from hadal.products.io import write_zarr

            write_zarr(draft.path / "dtm.nc", draft.path / "dtm.zarr", chunk=p.zarr_chunk)
    return draft.result


def _laser_summary(f: Path, ds, what: str) -> str:
    """The ``summary`` attribute of one laser grid's NetCDF."""
    if what == "raster":
        return (f"Laser bathymetry raster {f.name} ({ds.attrs['source_format']}) loaded at its own "
                f"{ds.attrs['resolution']:g} m resolution as elevation (positive up); NaN = unmapped; "
                "no per-cell point statistics.")
    return (f"Laser point cloud {f.name} filtered with open3d and resampled to a uniform "
            f"{ds.attrs['resolution'] * 1000:g} mm lateral grid (Sangekar et al., SIII-A; "
            f"{ds.attrs.get('resolution_choice', 'grid.laser_resolution_m')}); cell mean "
            "elevation, count and std; NaN = unmapped.")


def _grid_geometry(ds: Any) -> dict[str, Any]:
    """A laser grid's cell size (median x step, m; None for one column) and cells along x and y, for the manifest:
    landing's skip check reads them there instead of opening every grid before it reads them."""
    import numpy as np

    x = np.asarray(ds["x"].values, dtype=np.float64)
    return {"cell_m": float(np.median(np.abs(np.diff(x)))) if x.size > 1 else None, "nx": int(x.size),
            "ny": int(ds.sizes.get("y", 0))}


def _publish_laser_grids(ctx: StageContext, p: Params, params: dict, laser: list[tuple[Path, object]],
                         grids: list[tuple[Path, str, Any, str]], readers: dict[str, str]):
    """Publish ``laser_grids``: ``<stem>.nc`` per input, a Zarr store with ``grid.zarr``, a COG when georeferenced."""
    from hadal.products.io import write_netcdf

    extra = {"readers": {f.name: readers[str(f)] for f, *_ in grids},
             "laser_grid_files": {f.name: f"{stem}.nc" for f, stem, *_ in grids},
             "laser_grid_geometry": {f"{stem}.nc": _grid_geometry(ds) for _, stem, ds, _ in grids}}
    with ctx.store.publish(ctx.dive_id, "laser_grids", parameters=params, inputs=[f for f, _ in laser],
                           extra=extra) as draft:
        for f, stem, ds, what in grids:
            write_netcdf(
                ds, draft.path / f"{stem}.nc",
                title=f"Laser elevation grid {stem} of dive {ctx.dive_id}", summary=_laser_summary(f, ds, what),
                keywords="bathymetry, laser, structured light, microbathymetry",
                processing_level="L3 gridded", provenance_from=draft, **_frame_attrs(ctx),
            )
            if p.zarr:
                from hadal.products.io import write_zarr

                write_zarr(draft.path / f"{stem}.nc", draft.path / f"{stem}.zarr", chunk=p.zarr_chunk)
            lf = None if p.laser_frame == "map" else getattr(ctx.dive, "laser_frame", None)
            if p.laser_frame == "map" or lf is not None or ds.attrs.get("source_crs_wkt") \
                    or ds.attrs.get("source_crs_kind") == "geographic":  # georeferenced: a COG
                from hadal.products.geotiff import write_grid_cog

                write_grid_cog(ds, draft.path / f"{stem}.tif", "elevation_m", laser_frame=lf)
    return draft.result


def run_dtm(ctx: StageContext) -> dict[str, ProductVersion]:
    """Stage ``dtm``: the reference DTM from the dive's multibeam soundings, else from its first prior grid."""
    p: Params = ctx.config.grid
    src = ctx.dive.sources
    if not src.multibeam and not src.prior_grid:
        raise StageError(f"dive {ctx.dive_id!r} lists no multibeam or prior_grid sources in dive.yaml; no DTM to "
                         "make")
    readers: dict[str, str] = {}
    priors = _existing(ctx, src.prior_grid, "prior grid")
    if src.multibeam:
        dtm = _multibeam_dtm(ctx, p, priors, readers, memory_limit_bytes(ctx.config))
    else:
        dtm = _prior_grid_dtm(ctx, p, priors, readers)
    _compress(dtm.ds)
    return {"dtm": _publish_dtm(ctx, p, ctx.params("dtm"), dtm, readers)}


def run_laser(ctx: StageContext) -> dict[str, ProductVersion]:
    """Stage ``laser``: every laser input gridded (all of them before anything is published)."""
    p: Params = ctx.config.grid
    if not ctx.dive.sources.laser:
        raise StageError(f"dive {ctx.dive_id!r} lists no laser sources in dive.yaml; no laser grids to make")
    readers: dict[str, str] = {}
    laser = _existing(ctx, ctx.dive.sources.laser, "laser")
    grids = _grid_laser_inputs(ctx, p, laser, readers, memory_limit_bytes(ctx.config))
    return {"laser_grids": _publish_laser_grids(ctx, p, ctx.params("laser"), laser, grids, readers)}
