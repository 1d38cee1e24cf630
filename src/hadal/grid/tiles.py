"""Out-of-core gridding (issue 48): soundings partitioned by tile on disk, each tile reduced with the in-memory
kernels, the tiles assembled into the grid.

Method (the external-memory "distribution sweep": one partitioning pass, then each partition in memory;
Vitter, *Algorithms and Data Structures for External Memory*, 2008, §5):

1. a **tile scheme** (:class:`TileScheme`) cuts the grid of a :class:`~hadal.grid.points.GridSpec` into tiles
   of ``tile_cells x tile_cells`` *whole cells* (the last column/row of tiles narrower), so every cell, and so
   every cell's points, belongs to exactly one tile: seams need no overlap and no merging;
2. **partition** (:class:`TilePartition`): points arrive in chunks ``(x, y, z)`` of any size (a reader's chunks,
   a file's slices); each chunk's cell indices are computed by the in-memory kernels' own rule
   (:func:`hadal.grid._kernels.tile_partition_chunk`: the cell of :meth:`GridSpec.cell_index`, NaN/inf and
   outside points skipped and counted), the tile and the index inside the tile follow by integer arithmetic
   (so a point on a seam or a cell edge lands where the in-memory grid puts it), and the chunk's points are
   appended per tile, in input order, to two raw files of the tile in a scratch directory (int32 cell within
   the tile, float64 value: 12 bytes a point); free disk is checked before every chunk;
3. **reduce** each tile in turn with :func:`hadal.grid.points.reduce_cells` on its points alone; a cell's
   statistics there depend only on that cell's values in input order, which the partition keeps, so count,
   mean, std, median, min and max come out bit-identical to the in-memory :func:`reduce_cells` /
   :func:`~hadal.grid.points.cell_stats` of all the points (the tile takes the path - compiled or NumPy - the
   whole point set would take);
4. **assemble**: each tile's layers are written into their window of the full flat layers, the only
   O(grid) memory. Peak memory: one chunk (~44 bytes a point while it is partitioned), one tile's points
   (~30 bytes a point while reduced) and the output layers.

The DTM's per-cell layers (mean, median, count, std, uncertainty) are one function of a tile's points,
:func:`hadal.grid.multibeam.dtm_cell_layers`, used unchanged for the in-memory DTM (the whole grid as one tile,
no disk) and for tiles (:func:`dtm_layers_tiled`); small holes are filled on the assembled grid.

The count/mean/std-only path of :func:`hadal.grid.points.grid_points` (:func:`~hadal.grid.points.cell_moments`:
sums shifted by one global sample median, two threads' partial sums added) is a different summation order:
there the tiled count is identical and mean/std agree to rounding (a few ulp), as the in-memory paths agree
with one another.
"""

from __future__ import annotations

import os
import shutil
import tempfile
from collections.abc import Callable, Iterable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

from hadal.errors import InputError
from hadal.grid.points import (
    _COMPILED_MIN_POINTS,
    GridSpec,
    _check_stats,
    _partition_kernels,
    reduce_cells,
    to_dataset,
)

if TYPE_CHECKING:
    import numpy as np
    import xarray as xr

#: largest default tile side (cells): 1024 x 1024 cells, 8 MiB a float64 layer of a tile
DEFAULT_TILE_CELLS = 1024
#: tiles are sized (:func:`choose_tile_cells`) so an evenly covered tile holds at most this many points: its
#: arrays (16 MiB of values) then stay below glibc's largest mmap threshold (32 MiB), so successive tiles reuse
#: the same heap pages instead of faulting fresh ones in (a page fault costs ~0.5 ms a MB on the reference VM,
#: ~15 ns a point of a tile: as much as the reduction of count/mean/std itself; measured)
DEFAULT_MAX_TILE_POINTS = 1 << 21
#: points a chunk is cut into before partitioning (same reason: its arrays stay below 32 MiB)
PARTITION_CHUNK_POINTS = 1 << 21
#: bytes a partitioned point takes on disk (int32 cell in the tile, float64 value)
BYTES_PER_POINT = 12
#: bytes a partitioned point takes besides with ``with_xy`` (x, y float64, int64 input index)
BYTES_PER_POINT_XY = 24
#: free disk kept in reserve beyond a chunk's own bytes before it is written
_DISK_RESERVE_BYTES = 256 << 20


@dataclass(frozen=True)
class TileScheme:
    """Tiles of ``tile_cells x tile_cells`` whole cells over ``spec`` (row-major, ``ntx`` tiles a row; the last
    column/row of tiles holds the remaining cells)."""

    spec: GridSpec
    tile_cells: int

    def __post_init__(self) -> None:
        if not (isinstance(self.tile_cells, int) and 1 <= self.tile_cells <= 46340):  # a tile < 2**31 cells
            raise InputError(f"tile_cells must be a whole number of cells in 1..46340, got {self.tile_cells!r}")

    @property
    def ntx(self) -> int:
        return -(-self.spec.nx // self.tile_cells)

    @property
    def nty(self) -> int:
        return -(-self.spec.ny // self.tile_cells)

    @property
    def n_tiles(self) -> int:
        return self.ntx * self.nty

    def window(self, t: int) -> tuple[int, int, int, int]:
        """``(row0, row1, col0, col1)``: the cells of tile ``t`` in the full grid (half-open)."""
        ty, tx = divmod(int(t), self.ntx)
        tc = self.tile_cells
        return ty * tc, min(self.spec.ny, (ty + 1) * tc), tx * tc, min(self.spec.nx, (tx + 1) * tc)

    def tile_spec(self, t: int) -> GridSpec:
        """Tile ``t`` as a grid of its own (its cell centres); points are never re-indexed on it (the partition
        indexes them on the full grid), so floating-point offsets cannot move a point across a seam."""
        r0, r1, c0, c1 = self.window(t)
        s = self.spec
        return GridSpec(s.x0 + c0 * s.resolution, s.y0 + r0 * s.resolution, s.resolution, c1 - c0, r1 - r0)


def choose_tile_cells(spec: GridSpec, expected_points: int | None = None, *,
                      max_tile_points: int = DEFAULT_MAX_TILE_POINTS, tile_cells: int | None = None) -> int:
    """Tile side (cells): ``tile_cells`` when given, else the largest side up to :data:`DEFAULT_TILE_CELLS`
    (at least 16) at which an evenly covered tile holds at most ``max_tile_points`` of ``expected_points``; a
    grid smaller than one tile is one tile. (Uneven coverage makes some tiles fuller: their points are held one
    tile at a time.)"""
    if tile_cells is not None:
        return int(tile_cells)
    t = DEFAULT_TILE_CELLS
    if expected_points:
        per_cell = expected_points / max(1, spec.n_cells)
        t = int(min(t, max(16.0, (max_tile_points / max(per_cell, 1e-12)) ** 0.5)))
    return max(1, min(t, max(spec.nx, spec.ny)))


def _free_bytes(path: Path) -> int:
    return shutil.disk_usage(path).free


def tile_paths(d: Path, t: int) -> tuple[Path, Path]:
    """The files of tile ``t``'s points in a partition directory ``d``: cell within the tile (int32), value."""
    return d / f"t{t}.cell.i4", d / f"t{t}.z.f8"


def tile_xy_paths(d: Path, t: int) -> tuple[Path, Path, Path]:
    """The files of tile ``t``'s positions in a partition ``with_xy``: x, y (float64), input index (int64)."""
    return d / f"t{t}.x.f8", d / f"t{t}.y.f8", d / f"t{t}.i.i8"


class TilePartition:
    """Points partitioned by tile into raw files in a scratch directory (module doc, step 2).

    ``add(x, y, z)`` a chunk at a time, then :meth:`reduce` the tiles one by one. A context manager: the scratch
    directory (a fresh ``hadal-tiles-*`` directory under ``scratch_dir``, default the system temp dir) is
    removed on exit. ``check_inside``: drop (and count) points outside the grid, as ``grid_points`` with
    explicit bounds; otherwise points are clamped into the edge cells (the grid was built from their extent).
    """

    def __init__(self, scheme: TileScheme, *, scratch_dir: str | os.PathLike | None = None,
                 check_inside: bool = True, with_xy: bool = False) -> None:
        base = Path(scratch_dir) if scratch_dir is not None else Path(tempfile.gettempdir())
        if not base.is_dir():
            raise InputError(f"scratch directory {base} does not exist (or is not a directory)")
        try:
            self.dir = Path(tempfile.mkdtemp(prefix="hadal-tiles-", dir=base))
        except OSError as e:
            raise InputError(f"cannot create a scratch directory in {base}: {e.strerror or e}") from None
        self.scheme = scheme
        self.check_inside = bool(check_inside)
        self.with_xy = bool(with_xy)
        self.has_spikes = False  # spike flags written beside the tiles (spike_flags_tiled)
        self.tile_points = [0] * scheme.n_tiles
        self.n_input = 0
        self.n_nonfinite = 0
        self.n_outside = 0

    def __enter__(self) -> TilePartition:
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def close(self) -> None:
        """Remove the scratch directory and its tile files."""
        shutil.rmtree(self.dir, ignore_errors=True)

    @property
    def n_points(self) -> int:
        """Points written to the tiles (finite, inside)."""
        return sum(self.tile_points)

    @property
    def bytes_per_point(self) -> int:
        """Disk a partitioned point takes: 12 bytes, 36 with ``with_xy`` (x, y float64 and the input index)."""
        return BYTES_PER_POINT + (BYTES_PER_POINT_XY if self.with_xy else 0)

    def _paths(self, t: int) -> tuple[Path, Path]:
        return tile_paths(self.dir, t)

    def _xy_paths(self, t: int) -> tuple[Path, Path, Path]:
        return tile_xy_paths(self.dir, t)

    def add(self, x, y, z) -> None:
        """Append one chunk's points to their tiles (in input order; arrays of one length)."""
        import numpy as np

        x = np.ascontiguousarray(x, dtype=np.float64).ravel()
        y = np.ascontiguousarray(y, dtype=np.float64).ravel()
        z = np.ascontiguousarray(z, dtype=np.float64).ravel()
        if not (len(x) == len(y) == len(z)):
            raise InputError(f"x, y and z must have the same length (got {len(x)}, {len(y)}, {len(z)})")
        if len(x) == 0:
            return
        if len(x) > PARTITION_CHUNK_POINTS:  # cache- and heap-friendly pieces (module constants)
            for a in range(0, len(x), PARTITION_CHUNK_POINTS):
                sl = slice(a, a + PARTITION_CHUNK_POINTS)
                self.add(x[sl], y[sl], z[sl])
            return
        bpp = self.bytes_per_point
        need = bpp * len(x) + _DISK_RESERVE_BYTES
        free = _free_bytes(self.dir)
        if free < need:
            raise InputError(f"scratch directory {self.dir.parent} has {free / 2**30:.2f} GiB free; the tiles need "
                             f"{need / 2**30:.2f} GiB more for the next {len(x):,} points ({bpp} bytes a point): "
                             "free disk or give another scratch_dir")
        if self.with_xy:
            starts, local, src, nb, no = self._partition(x, y, z, order=True)
            cols = [(self._paths, (local, z[src])), (self._xy_paths, (x[src], y[src], src + self.n_input))]
        else:
            starts, local, zs, nb, no = self._partition(x, y, z)
            cols = [(self._paths, (local, zs))]
        self.n_input += len(x)
        self.n_nonfinite += int(nb)
        self.n_outside += int(no)
        for t in np.flatnonzero(np.diff(starts)):
            a, b = int(starts[t]), int(starts[t + 1])
            try:
                for paths, arrays in cols:
                    for path, arr in zip(paths(int(t)), arrays, strict=True):
                        with open(path, "ab") as fh:
                            arr[a:b].tofile(fh)
            except OSError as e:
                raise InputError(f"cannot write tile files in {self.dir}: {e.strerror or e}") from None
            self.tile_points[int(t)] += b - a

    def _partition(self, x, y, z, order: bool = False):
        """``(starts, local, zs, n_nonfinite, n_outside)`` of one chunk (``order``: the chunk positions ``src``
        in place of ``zs``): compiled, or the NumPy reference."""
        import numpy as np

        sc, s = self.scheme, self.scheme.spec
        kern = _partition_kernels()
        if kern is not None:
            fn = kern.tile_partition_order if order else kern.tile_partition_chunk
            return fn(x, y, z, float(s.x0), float(s.y0), 1.0 / s.resolution, int(s.nx),
                                             int(s.ny), self.check_inside, int(sc.tile_cells), int(sc.ntx),
                                             int(sc.n_tiles))
        ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(z)
        idx, inside = s.cell_index(x, y, check_inside=self.check_inside)
        nb = len(x) - int(ok.sum())
        no = 0
        if inside is not None:
            no = int((ok & ~inside).sum())
            ok &= inside
        keep = np.flatnonzero(ok)
        idx, zz = idx[ok], z[ok]
        r, c = np.divmod(idx, s.nx)
        tc = sc.tile_cells
        ty, tx = r // tc, c // tc
        tw = np.minimum(tc, s.nx - tx * tc)
        tile = ty * sc.ntx + tx
        local = ((r - ty * tc) * tw + (c - tx * tc)).astype(np.int32)
        by_tile = np.argsort(tile, kind="stable")
        starts = np.zeros(sc.n_tiles + 1, np.int64)
        np.cumsum(np.bincount(tile, minlength=sc.n_tiles), out=starts[1:])
        return starts, local[by_tile], (keep[by_tile] if order else zz[by_tile]), nb, no

    def tile_points_of(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        """Tile ``t``'s points: ``(cell within the tile int32, value)``, in input order."""
        import numpy as np

        if self.tile_points[t] == 0:
            return np.empty(0, np.int32), np.empty(0)
        pc, pz = self._paths(t)
        return np.fromfile(pc, dtype=np.int32), np.fromfile(pz, dtype=np.float64)

    def kept_of(self, t: int) -> np.ndarray:
        """Tile ``t``'s points not flagged as spikes (:func:`spike_flags_tiled`), a boolean mask."""
        import numpy as np

        return np.fromfile(self.dir / f"t{t}.spike.u1", dtype=np.uint8) == 0

    def n_spikes(self) -> int:
        """Points flagged as spikes over all tiles (:func:`spike_flags_tiled`)."""
        return sum(self.tile_points[t] - int(self.kept_of(t).sum()) for t in range(self.scheme.n_tiles)
                   if self.tile_points[t])

    def tile_xy_of(self, t: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Tile ``t``'s ``(x, y, input index int64)`` in input order (a partition ``with_xy``)."""
        import numpy as np

        if not self.with_xy:
            raise ValueError("tile_xy_of needs a partition made with_xy")
        if self.tile_points[t] == 0:
            return np.empty(0), np.empty(0), np.empty(0, np.int64)
        px, py, pi = self._xy_paths(t)
        return np.fromfile(px), np.fromfile(py), np.fromfile(pi, dtype=np.int64)

    def reduce(self, fn: Callable[[np.ndarray, np.ndarray, int], dict[str, np.ndarray]],
               empty: dict[str, tuple[object, object]],
               select: Callable[[int], np.ndarray] | None = None) -> dict[str, np.ndarray]:
        """Assemble the full flat layers ``{name: array}`` from ``fn(cells, values, tile_n_cells)`` of every
        non-empty tile (each a dict of flat per-cell arrays over the tile); ``empty`` gives each layer's
        ``(dtype, fill value)`` (the value of the cells of empty tiles). ``select(t)``: a boolean mask of the
        tile's points to reduce (e.g. those not flagged as spikes). One tile's points in memory at a time."""
        import numpy as np

        sc, s = self.scheme, self.scheme.spec
        out = {k: np.full(s.n_cells, fill, dtype=dt) for k, (dt, fill) in empty.items()}
        grids = {k: v.reshape(s.ny, s.nx) for k, v in out.items()}
        for t in range(sc.n_tiles):
            if self.tile_points[t] == 0:
                continue
            r0, r1, c0, c1 = sc.window(t)
            cells, values = self.tile_points_of(t)
            if select is not None:
                keep = select(t)
                cells, values = cells[keep], values[keep]
            layers = fn(cells, values, (r1 - r0) * (c1 - c0))
            del cells, values
            for k, v in layers.items():
                grids[k][r0:r1, c0:c1] = v.reshape(r1 - r0, c1 - c0)
        return out


@dataclass(frozen=True)
class PartitionUnion:
    """Several partitions of one :class:`TileScheme` (their directories, e.g. a cruise's dives, each made
    ``with_xy``) read as one: tile ``t``'s points are every partition's, in the given order, and a point's input
    index is its partition's plus ``offsets[k]`` (the points of the partitions before it), so the union is the
    partition of all the points concatenated. Read-only and picklable (a unit of work on another machine)."""

    scheme: TileScheme
    dirs: tuple[str, ...]
    points: tuple[tuple[int, ...], ...]  # per partition, its points per tile
    offsets: tuple[int, ...]

    @property
    def tile_points(self) -> list[int]:
        return [sum(p[t] for p in self.points) for t in range(self.scheme.n_tiles)]

    @property
    def n_points(self) -> int:
        return sum(sum(p) for p in self.points)

    def _read(self, t: int, paths, dtypes, offset_col: int | None = None) -> list[np.ndarray]:
        import numpy as np

        cols: list[list[np.ndarray]] = [[] for _ in dtypes]
        for d, pts, off in zip(self.dirs, self.points, self.offsets, strict=True):
            if pts[t]:
                for k, (path, dt) in enumerate(zip(paths(Path(d), t), dtypes, strict=True)):
                    a = np.fromfile(path, dtype=dt)
                    cols[k].append(a + off if k == offset_col else a)
        return [np.concatenate(c) if c else np.empty(0, dt) for c, dt in zip(cols, dtypes, strict=True)]

    def tile_points_of(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        """Tile ``t``'s ``(cell within the tile int32, value)`` of every partition, in order."""
        import numpy as np

        c, z = self._read(t, tile_paths, (np.int32, np.float64))
        return c, z

    def tile_xy_of(self, t: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Tile ``t``'s ``(x, y, input index int64)`` of every partition, in order, indices offset."""
        import numpy as np

        x, y, i = self._read(t, tile_xy_paths, (np.float64, np.float64, np.int64), offset_col=2)
        return x, y, i


def iter_array_chunks(x, y, z, chunk_points: int = 1 << 22) -> Iterator[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """``(x, y, z)`` slices of ``chunk_points`` points (in-memory or memory-mapped arrays)."""
    n = len(x)
    for a in range(0, n, chunk_points):
        yield x[a:a + chunk_points], y[a:a + chunk_points], z[a:a + chunk_points]


def partition_chunks(chunks: Iterable[tuple[object, object, object]], spec: GridSpec, *,
                     tile_cells: int | None = None, expected_points: int | None = None,
                     scratch_dir: str | os.PathLike | None = None, check_inside: bool = True) -> TilePartition:
    """A :class:`TilePartition` of ``spec`` filled from ``chunks`` (the caller closes it, or uses it in a
    ``with``); the tile side from :func:`choose_tile_cells`."""
    tc = choose_tile_cells(spec, expected_points, tile_cells=tile_cells)
    part = TilePartition(TileScheme(spec, tc), scratch_dir=scratch_dir, check_inside=check_inside)
    try:
        for x, y, z in chunks:
            part.add(x, y, z)
    except BaseException:
        part.close()
        raise
    return part


def _empty_layers(stats: Sequence[str]) -> dict[str, tuple[object, object]]:
    import numpy as np

    return {s: ((np.int64, 0) if s == "count" else (np.float64, np.nan)) for s in stats}


def grid_tiled(chunks: Iterable[tuple[object, object, object]], spec: GridSpec,
               statistics: Sequence[str] = ("mean", "median", "count", "std"), *, ddof: int = 1,
               check_inside: bool = True, tile_cells: int | None = None, expected_points: int | None = None,
               scratch_dir: str | os.PathLike | None = None, z_attrs: dict | None = None) -> xr.Dataset:
    """Grid points streamed as ``(x, y, z)`` chunks onto ``spec`` out of core (module doc): the Dataset
    :func:`hadal.grid.points.grid_points` gives for the same points, spec and ``check_inside`` (its explicit
    ``bounds``), with memory bounded by a chunk, a tile and the output. With median/min/max in ``statistics``
    every layer is bit-identical to ``grid_points``'; count/mean/std alone: count identical, mean/std to
    rounding (module doc). All points NaN/inf: :class:`InputError`, as ``grid_points``."""
    stats = _check_stats(statistics)
    with partition_chunks(chunks, spec, tile_cells=tile_cells, expected_points=expected_points,
                          scratch_dir=scratch_dir, check_inside=check_inside) as part:
        if part.n_input == 0:
            raise InputError("no points to grid (empty point set)")
        if part.n_nonfinite == part.n_input:
            raise InputError(f"all {part.n_input} points have NaN/inf coordinates; nothing to grid")
        # grid_points' compiled/NumPy choice is made on all its input points (cell_stats)
        compiled = part.n_input >= _COMPILED_MIN_POINTS
        flat = part.reduce(lambda c, v, m: reduce_cells(c, v, m, stats, ddof=ddof, compiled=compiled),
                           _empty_layers(stats))
        n_used = part.n_points
        attrs = {"n_points_used": n_used, "n_points_nonfinite": part.n_nonfinite,
                 "n_points_outside": part.n_outside, "tile_cells": part.scheme.tile_cells,
                 "n_tiles": part.scheme.n_tiles}
    return to_dataset(spec, flat, z_attrs=z_attrs, attrs=attrs)


def dtm_layers_tiled(part: TilePartition, *, fill_max_cells: int = 4, apriori_a_m: float = 0.5,
                     apriori_b: float = 0.001, prior_weight: float = 3.0) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """The DTM layers (mean, median, count, std, uncertainty, filled) of a partition of kept soundings (depth
    positive down): :func:`hadal.grid.multibeam.dtm_cell_layers` per tile, then small holes filled on the
    assembled grid, as :func:`hadal.grid.multibeam.grid_multibeam` does for the whole grid in memory (the same
    two functions, so the layers are identical). Returns ``(flat layers, 2-D filled mask)``."""
    from hadal.grid.multibeam import DTM_CELL_LAYERS, dtm_cell_layers, fill_dtm_holes

    select = part.kept_of if part.has_spikes else None
    n_kept = part.n_points - (part.n_spikes() if part.has_spikes else 0)
    compiled = n_kept >= _COMPILED_MIN_POINTS  # reduce_cells' choice on all kept soundings
    flat = part.reduce(lambda c, v, m: dtm_cell_layers(c, v, m, apriori_a_m=apriori_a_m, apriori_b=apriori_b,
                                                       prior_weight=prior_weight, compiled=compiled),
                       _empty_layers(DTM_CELL_LAYERS), select=select)
    return fill_dtm_holes(part.scheme.spec, flat, fill_max_cells, apriori_a_m, apriori_b)


def tile_cell_mads(part: TilePartition | PartitionUnion, ts: Sequence[int], min_count: int) -> np.ndarray:
    """The MADs of the cells with >= ``min_count`` points of the tiles ``ts`` (each cell's own points,
    :func:`hadal.grid.points.cell_robust_stats` per tile), concatenated."""
    import numpy as np

    from hadal.grid.points import cell_robust_stats

    mads = []
    for t in ts:
        if part.tile_points[t]:
            cells, z = part.tile_points_of(t)
            st = cell_robust_stats(cells, z)
            mads.append(st.mad[st.counts >= min_count])
    return np.concatenate(mads) if mads else np.empty(0)


def sigma_of_mads(mads: Sequence[np.ndarray]) -> float:
    """``1.4826 x`` the median of all the cells' MADs (:func:`hadal.grid.points.typical_cell_sigma`; NaN: none)."""
    import numpy as np

    allm = np.concatenate(list(mads)) if len(mads) else np.empty(0)
    return float(1.4826 * np.median(allm)) if allm.size else float("nan")


def typical_cell_sigma_tiled(part: TilePartition | PartitionUnion, min_count: int) -> float:
    """:func:`hadal.grid.points.typical_cell_sigma` of all the partition's points: every cell's MAD is its own
    points' (:func:`tile_cell_mads`), and the median of the same multiset of MADs is the same number, so the
    result is identical to the in-memory one."""
    return sigma_of_mads([tile_cell_mads(part, range(part.scheme.n_tiles), min_count)])


def _halo_window(sc: TileScheme, t: int, h: int) -> tuple[int, int, int, int]:
    r0, r1, c0, c1 = sc.window(t)
    return max(0, r0 - h), min(sc.spec.ny, r1 + h), max(0, c0 - h), min(sc.spec.nx, c1 + h)


def _halo_points(part: TilePartition | PartitionUnion, t: int, win: tuple[int, int, int, int]):
    """``(x, y, z, input index)`` of the points of the cells in ``win`` (rows/cols, half-open), tile ``t``'s own
    points first, then the other tiles' points in those cells; and the number of tile ``t``'s points."""
    import numpy as np

    sc = part.scheme
    wr0, wr1, wc0, wc1 = win
    tiles = [t] + [ty * sc.ntx + tx for ty in range(wr0 // sc.tile_cells, (wr1 - 1) // sc.tile_cells + 1)
                   for tx in range(wc0 // sc.tile_cells, (wc1 - 1) // sc.tile_cells + 1)
                   if ty * sc.ntx + tx != t]
    cols: list[list[np.ndarray]] = [[], [], [], []]
    n_core = part.tile_points[t]
    for u in tiles:
        if not part.tile_points[u]:
            continue
        cells, z = part.tile_points_of(u)
        x, y, gi = part.tile_xy_of(u)
        if u != t:
            r0, _, c0, c1 = sc.window(u)
            rr, cc = np.divmod(cells, c1 - c0)
            rr += r0
            cc += c0
            sel = (rr >= wr0) & (rr < wr1) & (cc >= wc0) & (cc < wc1)
            x, y, z, gi = x[sel], y[sel], z[sel], gi[sel]
        for c, a in zip(cols, (x, y, z, gi), strict=True):
            c.append(a)
    return (*(np.concatenate(c) for c in cols), n_core)


def _knn_flags_local(x, y, z, gi, targets, neighbours: int, k: float, floor: float):
    """Flags and ``nb``-th neighbour squared distances of the soundings ``targets`` (indices into ``x``...)
    among all of ``x``, ``y``, ``z`` by the exact ``(distance, input index)`` search of
    :func:`hadal.grid._spike_kernels.knn_spike_flags_targets` (the in-memory search's neighbours and tie rule);
    a set with no lateral extent (collinear) uses scipy's k-d tree."""
    import numpy as np

    from hadal.grid._spike_kernels import knn_spike_flags, knn_spike_flags_targets
    from hadal.grid.knn_cells import sorted_by_cell, uniform_cells
    from hadal.grid.multibeam import MAD_TO_SIGMA

    pts = np.column_stack([x, y])
    lo = pts.min(axis=0)
    binned = uniform_cells(pts, lo, 0, 1, neighbours)
    out = np.empty(len(targets), bool)
    kd2 = np.empty(len(targets))
    if binned is None:  # the targets first, then scipy's neighbours in that order
        from scipy.spatial import cKDTree

        m = len(targets)
        rest = np.ones(len(x), bool)
        rest[targets] = False
        perm = np.concatenate([targets, np.flatnonzero(rest)])
        xp, yp, zp = x[perm], y[perm], z[perm]
        d, j = cKDTree(pts[perm]).query(pts[targets], k=neighbours + 1)
        flags = np.zeros(len(x), bool)
        knn_spike_flags(xp, yp, zp, 0, np.ascontiguousarray(j[:, 1:], np.int64), float(k), float(floor),
                        MAD_TO_SIGMA, flags)
        out[:] = flags[:m]
        kd2[:] = d[:, -1] ** 2
        return out, kd2
    co = sorted_by_cell(binned, float(lo[0]), float(lo[1]))
    inv = np.empty(len(x), np.int64)
    inv[co.order] = np.arange(len(x))
    knn_spike_flags_targets(x[co.order], y[co.order], z[co.order], np.ascontiguousarray(gi[co.order]), co.starts,
                            co.ncu, co.ncv, co.u0, co.v0, co.cs, int(neighbours), float(k), float(floor),
                            MAD_TO_SIGMA, np.ascontiguousarray(inv[targets]), out, kd2, 1024)
    return out, kd2


def _seam_bound(sc: TileScheme, win: tuple[int, int, int, int], x, y):
    """Per point a lower bound of its distance to any point of a cell outside ``win`` (the halo window): the
    distance to the window's inner sides (a side on the grid's edge has no cell beyond it), less a rounding
    margin (a point within rounding of a cell edge may have been binned on either side)."""
    import numpy as np

    s = sc.spec
    wr0, wr1, wc0, wc1 = win
    b = np.full(len(x), np.inf)
    if wc0 > 0:
        np.minimum(b, x - (s.x0 + wc0 * s.resolution), out=b)
    if wc1 < s.nx:
        np.minimum(b, (s.x0 + wc1 * s.resolution) - x, out=b)
    if wr0 > 0:
        np.minimum(b, y - (s.y0 + wr0 * s.resolution), out=b)
    if wr1 < s.ny:
        np.minimum(b, (s.y0 + wr1 * s.resolution) - y, out=b)
    margin = 1e-6 * s.resolution + 1e-12 * (abs(s.x0) + abs(s.y0) + (s.nx + s.ny) * s.resolution)
    return b - margin


def knn_spike_flags_tile(part: TilePartition | PartitionUnion, t: int, *, neighbours: int, k: float, floor: float,
                         halo_cells: int | None = None) -> np.ndarray:
    """The neighbour spike test (:func:`hadal.grid.multibeam.knn_spike_mask`) of tile ``t``'s soundings, in the
    tile's order, among the soundings of the tile and a **halo** of ``h`` cells around it: each sounding's
    ``neighbours`` nearest are searched in that set with the in-memory tie rule (input index), and kept only when
    the ``neighbours``-th is nearer than the halo's inner edge (no sounding beyond the halo can be nearer, nor
    tie); the others are searched again with the halo doubled, until the window covers the grid. ``h`` starts at
    ``halo_cells``, else at twice the radius holding ``neighbours`` soundings at the tile's mean density.
    So the flags equal those of the whole point set, seams included (where the in-memory search is the exact
    cell search, i.e. not the k-d tree fallback of a dense blob)."""
    import numpy as np

    sc = part.scheme
    n_core = part.tile_points[t]
    flags = np.zeros(n_core, bool)
    if n_core == 0:
        return flags
    r0, r1, c0, c1 = sc.window(t)
    if halo_cells is None:
        per_cell = n_core / ((r1 - r0) * (c1 - c0))
        h = max(1, int(np.ceil(2.0 * np.sqrt(neighbours / (np.pi * per_cell)))))
    else:
        h = max(1, int(halo_cells))
    pending = np.arange(n_core)
    while True:
        win = _halo_window(sc, t, h)
        whole = win == (0, sc.spec.ny, 0, sc.spec.nx)
        x, y, z, gi, _ = _halo_points(part, t, win)
        if len(x) > neighbours:
            out, kd2 = _knn_flags_local(x, y, z, gi, pending, neighbours, k, floor)
            if whole:
                flags[pending] = out
                return flags
            b = _seam_bound(sc, win, x[pending], y[pending])
            ok = kd2 < np.where(b > 0, b, 0.0) ** 2
            flags[pending[ok]] = out[ok]
            pending = pending[~ok]
            if pending.size == 0:
                return flags
        elif whole:  # the whole grid holds no more than `neighbours` soundings: none is tested (in-memory rule)
            return flags
        h *= 2


def spike_floor(sigma0: float, floor_m: float) -> float:
    """The spike tests' noise floor: ``sigma_0`` at least ``floor_m`` (``floor_m`` when NaN), as
    :func:`hadal.grid.multibeam.spike_mask`."""
    import math

    return max(sigma0, floor_m) if math.isfinite(sigma0) else floor_m


def spike_flags_of_tile(part: TilePartition | PartitionUnion, t: int, sigma0: float, *, k: float = 3.5,
                        k_neighbourhood: float = 4.0, neighbours: int = 16, min_count: int = 5,
                        halo_cells: int | None = None) -> np.ndarray:
    """Spike flags of tile ``t``'s points (in the tile's order) with the noise floor ``sigma0``
    (:func:`spike_floor`): the per-cell test (a cell lies in one tile) and, when the partition holds more than
    ``neighbours`` points (the in-memory rule), the neighbour test with a halo (:func:`knn_spike_flags_tile`)."""
    from hadal.grid.points import cell_robust_stats, robust_outlier_mask

    cells, z = part.tile_points_of(t)
    bad = robust_outlier_mask(cells, z, k, floor=sigma0, min_count=min_count, stats=cell_robust_stats(cells, z))
    del cells, z
    if part.n_points > neighbours:
        bad |= knn_spike_flags_tile(part, t, neighbours=neighbours, k=k_neighbourhood, floor=sigma0,
                                    halo_cells=halo_cells)
    return bad


def spike_flags_tiled(part: TilePartition, *, k: float = 3.5, k_neighbourhood: float = 4.0, neighbours: int = 16,
                      min_count: int = 5, floor_m: float = 0.5, halo_cells: int | None = None,
                      progress=None) -> tuple[int, float]:
    """:func:`hadal.grid.multibeam.spike_mask` of all the points of a partition ``with_xy``, tile by tile: the
    noise floor ``sigma_0`` over all tiles (:func:`typical_cell_sigma_tiled`), then per tile
    :func:`spike_flags_of_tile`; the flags are written beside the tile's points (:meth:`TilePartition.kept_of`).
    Returns ``(spikes, sigma_0)``."""
    import numpy as np

    sigma0 = spike_floor(typical_cell_sigma_tiled(part, min_count), floor_m)
    n_spikes = 0
    for t in range(part.scheme.n_tiles):
        if not part.tile_points[t]:
            continue
        bad = spike_flags_of_tile(part, t, sigma0, k=k, k_neighbourhood=k_neighbourhood, neighbours=neighbours,
                                  min_count=min_count, halo_cells=halo_cells)
        bad.astype(np.uint8).tofile(part.dir / f"t{t}.spike.u1")
        n_spikes += int(bad.sum())
    part.has_spikes = True
    return n_spikes, sigma0


def grid_multibeam_tiled(chunks: Iterable[tuple[object, object, object]], spec: GridSpec, *,
                         check_inside: bool = False, spike_k: float = 3.5, spike_k_neighbourhood: float = 4.0,
                         spike_neighbours: int = 16, spike_min_count: int = 5, spike_floor_m: float = 0.5,
                         remove_spikes: bool = True, fill_max_cells: int = 4, apriori_a_m: float = 0.5,
                         apriori_b: float = 0.001, prior_weight: float = 3.0, tile_cells: int | None = None,
                         expected_points: int | None = None, halo_cells: int | None = None,
                         scratch_dir: str | os.PathLike | None = None, progress=None) -> xr.Dataset:
    """:func:`hadal.grid.multibeam.grid_multibeam` out of core: soundings streamed as ``(x, y, depth)`` chunks
    onto ``spec`` (``check_inside`` False: the grid was made from their extent, as ``grid_multibeam`` without
    ``bounds``; True: its explicit ``bounds``), partitioned by tile with their positions, spike-tested tile by
    tile with a halo (:func:`spike_flags_tiled`), reduced tile by tile (:func:`dtm_layers_tiled`). The same
    Dataset as the in-memory DTM, layers and counts (module doc); no SOR (a whole-cloud statistic)."""
    from hadal.grid.multibeam import _dtm_attrs, _method_attrs
    from hadal.steps import step

    tc = choose_tile_cells(spec, expected_points, tile_cells=tile_cells)
    with TilePartition(TileScheme(spec, tc), scratch_dir=scratch_dir, check_inside=check_inside,
                       with_xy=True) as part:
        with step(progress, "dtm: partitioning soundings into tiles"):
            for x, y, z in chunks:
                part.add(x, y, z)
        if part.n_input == 0:
            raise InputError("no soundings to grid (empty input)")
        if part.n_points == 0:
            if part.n_nonfinite == part.n_input:
                raise InputError(f"all {part.n_input} soundings have NaN/inf coordinates; nothing to grid")
            raise InputError(f"none of the soundings fall inside the grid bounds {spec.bounds}")
        n_in = part.n_points
        n_spikes, sigma0 = 0, float("nan")
        if remove_spikes:
            with step(progress, f"dtm: spike test of {n_in:,} soundings in {part.scheme.n_tiles} tiles"):
                n_spikes, sigma0 = spike_flags_tiled(
                    part, k=spike_k, k_neighbourhood=spike_k_neighbourhood, neighbours=spike_neighbours,
                    min_count=spike_min_count, floor_m=spike_floor_m, halo_cells=halo_cells)
        with step(progress, f"dtm: gridding {n_in - n_spikes:,} soundings into {spec.nx} x {spec.ny} cells"):
            flat, filled = dtm_layers_tiled(part, fill_max_cells=fill_max_cells, apriori_a_m=apriori_a_m,
                                            apriori_b=apriori_b, prior_weight=prior_weight)
        attrs = {
            "n_soundings_input": int(part.n_input), "n_soundings_nonfinite": int(part.n_nonfinite),
            "n_soundings_outside": int(part.n_outside), "n_soundings_spikes": int(n_spikes),
            "n_soundings_sor": 0, "n_soundings_used": int(n_in - n_spikes), "n_cells_filled": int(filled.sum()),
            "spike_noise_floor_m": sigma0,
            **_method_attrs(spike_k=spike_k, spike_k_neighbourhood=spike_k_neighbourhood,
                            spike_neighbours=spike_neighbours, spike_min_count=spike_min_count,
                            spike_floor_m=spike_floor_m, remove_spikes=remove_spikes, sor=False, sor_neighbors=16,
                            sor_std_ratio=3.0, fill_max_cells=fill_max_cells, apriori_a_m=apriori_a_m,
                            apriori_b=apriori_b, prior_weight=prior_weight),
            "tile_cells": part.scheme.tile_cells, "n_tiles": part.scheme.n_tiles,
        }
    names = {"mean": "depth_m", "median": "depth_median_m", "std": "depth_std_m", "uncertainty": "uncertainty_m"}
    ds = to_dataset(spec, flat, names=names, attrs=attrs)
    _dtm_attrs(ds)
    return ds


def scratch_need_bytes(n_points: int) -> int:
    """Disk the tiles of ``n_points`` points take (12 bytes a point)."""
    return BYTES_PER_POINT * int(n_points)


__all__ = ["DEFAULT_TILE_CELLS", "PartitionUnion", "TilePartition", "TileScheme", "choose_tile_cells",
           "dtm_layers_tiled", "grid_multibeam_tiled", "grid_tiled", "knn_spike_flags_tile", "sigma_of_mads",
           "spike_flags_of_tile", "spike_flags_tiled", "spike_floor", "tile_cell_mads", "tile_paths", "tile_xy_paths",
           "typical_cell_sigma_tiled", "iter_array_chunks", "partition_chunks", "scratch_need_bytes"]
