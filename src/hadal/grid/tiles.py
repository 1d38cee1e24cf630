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


class TilePartition:
    """Points partitioned by tile into raw files in a scratch directory (module doc, step 2).

    ``add(x, y, z)`` a chunk at a time, then :meth:`reduce` the tiles one by one. A context manager: the scratch
    directory (a fresh ``hadal-tiles-*`` directory under ``scratch_dir``, default the system temp dir) is
    removed on exit. ``check_inside``: drop (and count) points outside the grid, as ``grid_points`` with
    explicit bounds; otherwise points are clamped into the edge cells (the grid was built from their extent).
    """

    def __init__(self, scheme: TileScheme, *, scratch_dir: str | os.PathLike | None = None,
                 check_inside: bool = True) -> None:
        base = Path(scratch_dir) if scratch_dir is not None else Path(tempfile.gettempdir())
        if not base.is_dir():
            raise InputError(f"scratch directory {base} does not exist (or is not a directory)")
        try:
            self.dir = Path(tempfile.mkdtemp(prefix="hadal-tiles-", dir=base))
        except OSError as e:
            raise InputError(f"cannot create a scratch directory in {base}: {e.strerror or e}") from None
        self.scheme = scheme
        self.check_inside = bool(check_inside)
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

    def _paths(self, t: int) -> tuple[Path, Path]:
        return self.dir / f"t{t}.cell.i4", self.dir / f"t{t}.z.f8"

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
        need = BYTES_PER_POINT * len(x) + _DISK_RESERVE_BYTES
        free = _free_bytes(self.dir)
        if free < need:
            raise InputError(f"scratch directory {self.dir.parent} has {free / 2**30:.2f} GiB free; the tiles need "
                             f"{need / 2**30:.2f} GiB more for the next {len(x):,} points (12 bytes a point): "
                             "free disk or give another scratch_dir")
        starts, local, zs, nb, no = self._partition(x, y, z)
        self.n_input += len(x)
        self.n_nonfinite += int(nb)
        self.n_outside += int(no)
        for t in np.flatnonzero(np.diff(starts)):
            a, b = int(starts[t]), int(starts[t + 1])
            pc, pz = self._paths(int(t))
            try:
                with open(pc, "ab") as fh:
                    local[a:b].tofile(fh)
                with open(pz, "ab") as fh:
                    zs[a:b].tofile(fh)
            except OSError as e:
                raise InputError(f"cannot write tile files in {self.dir}: {e.strerror or e}") from None
            self.tile_points[int(t)] += b - a

    def _partition(self, x, y, z):
        """``(starts, local, zs, n_nonfinite, n_outside)`` of one chunk: compiled, or the NumPy reference."""
        import numpy as np

        sc, s = self.scheme, self.scheme.spec
        kern = _partition_kernels()
        if kern is not None:
            return kern.tile_partition_chunk(x, y, z, float(s.x0), float(s.y0), 1.0 / s.resolution, int(s.nx),
                                             int(s.ny), self.check_inside, int(sc.tile_cells), int(sc.ntx),
                                             int(sc.n_tiles))
        ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(z)
        idx, inside = s.cell_index(x, y, check_inside=self.check_inside)
        nb = len(x) - int(ok.sum())
        no = 0
        if inside is not None:
            no = int((ok & ~inside).sum())
            ok &= inside
        idx, zz = idx[ok], z[ok]
        r, c = np.divmod(idx, s.nx)
        tc = sc.tile_cells
        ty, tx = r // tc, c // tc
        tw = np.minimum(tc, s.nx - tx * tc)
        tile = ty * sc.ntx + tx
        local = ((r - ty * tc) * tw + (c - tx * tc)).astype(np.int32)
        order = np.argsort(tile, kind="stable")
        starts = np.zeros(sc.n_tiles + 1, np.int64)
        np.cumsum(np.bincount(tile, minlength=sc.n_tiles), out=starts[1:])
        return starts, local[order], zz[order], nb, no

    def tile_points_of(self, t: int) -> tuple[np.ndarray, np.ndarray]:
        """Tile ``t``'s points: ``(cell within the tile int32, value)``, in input order."""
        import numpy as np

        if self.tile_points[t] == 0:
            return np.empty(0, np.int32), np.empty(0)
        pc, pz = self._paths(t)
        return np.fromfile(pc, dtype=np.int32), np.fromfile(pz, dtype=np.float64)

    def reduce(self, fn: Callable[[np.ndarray, np.ndarray, int], dict[str, np.ndarray]],
               empty: dict[str, tuple[object, object]]) -> dict[str, np.ndarray]:
        """Assemble the full flat layers ``{name: array}`` from ``fn(cells, values, tile_n_cells)`` of every
        non-empty tile (each a dict of flat per-cell arrays over the tile); ``empty`` gives each layer's
        ``(dtype, fill value)`` (the value of the cells of empty tiles). One tile's points in memory at a time."""
        import numpy as np

        sc, s = self.scheme, self.scheme.spec
        out = {k: np.full(s.n_cells, fill, dtype=dt) for k, (dt, fill) in empty.items()}
        grids = {k: v.reshape(s.ny, s.nx) for k, v in out.items()}
        for t in range(sc.n_tiles):
            if self.tile_points[t] == 0:
                continue
            r0, r1, c0, c1 = sc.window(t)
            cells, values = self.tile_points_of(t)
            layers = fn(cells, values, (r1 - r0) * (c1 - c0))
            del cells, values
            for k, v in layers.items():
                grids[k][r0:r1, c0:c1] = v.reshape(r1 - r0, c1 - c0)
        return out


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

    compiled = part.n_points >= _COMPILED_MIN_POINTS  # reduce_cells' choice on all kept soundings
    flat = part.reduce(lambda c, v, m: dtm_cell_layers(c, v, m, apriori_a_m=apriori_a_m, apriori_b=apriori_b,
                                                       prior_weight=prior_weight, compiled=compiled),
                       _empty_layers(DTM_CELL_LAYERS))
    return fill_dtm_holes(part.scheme.spec, flat, fill_max_cells, apriori_a_m, apriori_b)


def scratch_need_bytes(n_points: int) -> int:
    """Disk the tiles of ``n_points`` points take (12 bytes a point)."""
    return BYTES_PER_POINT * int(n_points)


__all__ = ["DEFAULT_TILE_CELLS", "TilePartition", "TileScheme", "choose_tile_cells", "dtm_layers_tiled",
           "grid_tiled", "iter_array_chunks", "partition_chunks", "scratch_need_bytes"]
