"""Readers for bathymetry inputs; every failure is a one-line :class:`hadal.errors.InputError`.

* :func:`read_soundings` - XYZ/CSV text soundings ``longitude_deg latitude_deg depth_m`` (whitespace or
  comma separated, optional header, ``#`` comments, ``.gz``/``.bz2``/``.xz`` transparently);
* :func:`read_point_cloud` - PLY (open3d), PCD (pypcd4) and LAS/LAZ (laspy; LAZ needs a laspy LAZ backend),
  LAS/PCD read by their metadata (:mod:`hadal.grid.clouds`);
* :func:`read_grid` - GeoTIFF (rasterio) and NetCDF/GMT grids (xarray) as an ``(y, x)`` DataArray with
  ascending coordinates, detecting rasters whose geographic CRS tag is wrong (:func:`looks_metric`);
* :func:`read_gsf` - GSF swath bathymetry via the maintained ``gsfpy`` bindings of libgsf.
"""

from __future__ import annotations

import io
import math
import re
import warnings
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import xarray as xr

from hadal.errors import InputError
from hadal.formats import decompress_errors, detect, open_binary, read_head

SOUNDING_COLUMNS = ("longitude_deg", "latitude_deg", "depth_m")


class GridCRSWarning(UserWarning):
    """A grid's CRS tag was overridden (e.g. a metric raster mislabelled as EPSG:4326)."""


def _require_file(path: str | Path, what: str) -> Path:
    p = Path(path)
    if not p.is_file():
        raise InputError(f"{what} file {p} does not exist")
    if p.stat().st_size == 0:
        raise InputError(f"{what} file {p} is empty")
    return p


def read_soundings(path: str | Path, *, columns=SOUNDING_COLUMNS, check_ranges: bool = True,
                   hints=None, memory_limit_bytes: float | None = None) -> pd.DataFrame:
    """Read an xyz text soundings file into a DataFrame (default columns lon, lat, depth positive down).

    A thin wrapper of the streaming xyz reader :func:`hadal.grid.sonar.iter_multibeam` (whitespace-, comma- or
    semicolon-separated, optional header naming the columns, ``#`` comments, plain/gzip/bz2/xz by content):
    elevations (header name, declared ``hints.z_positive='up'``, or a negative median) are converted to depth
    positive down; projected x/y come back as ``x_m, y_m, depth_m``. ``columns`` renames the three output
    columns. Truncated or corrupt files, non-numeric values and longitudes/latitudes out of range raise
    :class:`InputError`; NaN values are kept (the gridder drops and counts them), and so is a file whose soundings
    pass the memory budget as they decode (:class:`hadal.grid.sonar.SoundingBudget`, limit ``memory_limit_bytes``
    or the default of :func:`hadal.budget.memory_limit_bytes`). ``attrs`` records the reader.
    For binary swath formats use :func:`hadal.grid.sonar.read_multibeam`.
    """
    from hadal.grid.sonar import SoundingBudget, _iter_xyz, _require, sniff_multibeam

    p = _require(path)
    sn = sniff_multibeam(p)
    if sn["format"] not in ("xyz", "unknown"):
        raise InputError(f"{p}: is a {sn['format']} file, not xyz text (read it with hadal.grid.sonar.read_multibeam)")
    info: dict = {"path": str(p), "compression": sn["compression"]}
    # counted as they decode (a compressed file's size says nothing)
    budget = SoundingBudget(p, "multibeam file", limit_bytes=memory_limit_bytes)
    parts = []
    for c in _iter_xyz(p, sn["compression"], hints, 1_000_000, info, check_ranges=check_ranges):
        budget.add(len(c))
        parts.append(c)
    df = parts[0] if len(parts) == 1 else pd.concat(parts, ignore_index=True)
    del parts
    if columns != SOUNDING_COLUMNS and df.columns[0] == SOUNDING_COLUMNS[0]:
        df.columns = list(columns)
    df.attrs.update(info)
    return df


# ------------------------------------------------------------------ content sniffing (grids, point clouds)
#: ``SourceFile.format`` hints accepted by :func:`read_grid` / :func:`read_point_cloud`, and what they mean
FORMAT_ALIASES = {
    "geotiff": "geotiff", "tif": "geotiff", "tiff": "geotiff", "gtiff": "geotiff", "gdal": "gdal",
    "netcdf": "netcdf", "netcdf_grid": "netcdf", "nc": "netcdf", "cdf": "netcdf", "coards": "netcdf",
    "gmt": "netcdf", "gmt_grd": "netcdf", "grd": "netcdf",
    "ply": "ply", "pcd": "pcd", "las": "las", "laz": "las", "xyz": "xyz", "pts": "xyz", "txt": "xyz",
}
_GRID_KINDS = ("geotiff", "netcdf", "gdal")
_CLOUD_KINDS = ("ply", "pcd", "las", "xyz")


def sniff_kind(path: str | Path) -> str:
    """What a grid or point-cloud file is, from its content (:func:`hadal.formats.detect`), not its name.

    ``geotiff``, ``netcdf``, ``ply``, ``las`` (also LAZ), ``pcd``, ``xyz`` (numeric text rows of >= 3
    columns, also gzip/bz2/xz-compressed), ``text`` (other text) or ``unknown`` (other binary: left to GDAL,
    which identifies its own formats by content). The library readers read plain files only, so compressed
    content is ``xyz``, ``text`` or ``unknown``.
    """
    fk = detect(path)  # a corrupt compressed stream: "corrupt gzip stream" InputError
    if fk.kind in _GRID_KINDS + _CLOUD_KINDS and fk.kind != "xyz" and fk.compression is None:
        return fk.kind
    return "xyz" if fk.points else "text" if fk.text else "unknown"


def _kind_of(p: Path, fmt: str | None) -> str:
    if fmt is None:
        return sniff_kind(p)
    k = FORMAT_ALIASES.get(str(fmt).lower())
    if k is None:
        raise InputError(f"{p}: unknown format hint {fmt!r} (use one of {', '.join(sorted(set(FORMAT_ALIASES)))})")
    return k


def reader_of(kind: str) -> str:
    """The library (and version) that reads a file of ``kind`` (for manifests and ``hadal inspect``)."""
    from importlib.metadata import PackageNotFoundError, version

    def v(*names: str) -> str:
        for n in names:
            try:
                return version(n)
            except PackageNotFoundError:
                continue
        return "?"

    if kind in ("geotiff", "gdal"):
        import rasterio

        return f"rasterio {rasterio.__version__} (GDAL {rasterio.__gdal_version__})"
    if kind == "netcdf":
        return f"xarray {v('xarray')} (netCDF4 {v('netCDF4', 'netcdf4')})"
    if kind == "ply":
        return f"open3d {v('open3d', 'open3d-cpu')}"
    if kind == "pcd":
        return f"pypcd4 {v('pypcd4')}"
    if kind == "las":
        return f"laspy {v('laspy')}"
    if kind == "xyz":
        return f"pandas {v('pandas')} (text columns)"
    return "?"


def read_point_cloud(path: str | Path, *, format: str | None = None, columns: list[str] | None = None,
                     ) -> np.ndarray:
    """Read a point cloud as an ``(N, 3)`` float64 array of x, y, z (:func:`read_point_cloud_meta` without its
    metadata: LAS/LAZ coordinates in metres, z as stored for PLY and xyz text)."""
    return read_point_cloud_meta(path, format=format, columns=columns)[0]


def read_point_cloud_meta(path: str | Path, *, format: str | None = None, columns: list[str] | None = None,
                          hints=None, memory_limit_bytes: float | None = None) -> tuple[np.ndarray, dict]:
    """Read a point cloud as an ``(N, 3)`` float64 array of x, y, z and what its metadata says.

    The format is detected from the content (:func:`sniff_kind`), not the name; ``format`` overrides
    (``ply``, ``pcd``, ``las``/``laz``, ``xyz``). LAS/LAZ (laspy) and PCD (pypcd4) are read by their metadata
    (:mod:`hadal.grid.clouds`: CRS and linear units from the file, x/y/z in metres, z elevation positive up;
    ``hints`` - a dive.yaml :class:`hadal.dive.SourceFile` - may set ``crs``/``z_positive``); PLY with open3d,
    xyz text (whitespace/comma separated, optional header, ``#`` comments, gzip/bz2/xz) with pandas;
    ``columns`` names the text columns (``x``/``lon``/``easting``, ``y``/``lat``/``northing``,
    ``z``/``depth``/``elevation``; default: the first three). PLY and xyz carry no vertical metadata: their z is
    returned as stored and the metadata has no ``z_positive`` (the caller decides).

    Memory: every reader holds its points, counted with :data:`CLOUD_WORKING_COPIES`, against one
    :class:`hadal.budget.DecodeBudget` of ``memory_limit_bytes`` (the stage's ``resources.max_memory_gb``; default
    :func:`hadal.budget.memory_limit_bytes`): LAS/LAZ and xyz text as they decode (a LAZ or a gzip has no
    trustworthy size), PLY and PCD before the library allocates what their header declares; past it, a one-line
    :class:`InputError` naming the file and the limit.
    """
    p = _require_file(path, "point cloud")
    kind = _kind_of(p, format)
    if kind == "ply":
        import open3d as o3d

        _check_ply_budget(p, memory_limit_bytes)
        with _quiet_open3d(o3d):
            pc = o3d.io.read_point_cloud(str(p), format=kind)
        pts = np.asarray(pc.points, dtype=np.float64)
        if len(pts) == 0:
            raise InputError(f"{p}: no points read (truncated or not a {kind.upper()} point cloud)")
        _check_ply_count(p, len(pts))
        return pts, {"format": kind}
    if kind == "pcd":
        from hadal.grid.clouds import read_pcd

        return read_pcd(p, hints, memory_limit_bytes=memory_limit_bytes)
    if kind == "las":
        from hadal.grid.clouds import read_las

        return read_las(p, hints, memory_limit_bytes=memory_limit_bytes)
    if kind == "xyz":
        return _read_xyz_cloud(p, columns, memory_limit_bytes), {"format": kind}
    if kind in _GRID_KINDS:
        raise InputError(f"{p}: is a {kind} raster, not a point cloud")
    raise InputError(f"{p}: unsupported point cloud format (content is not PLY, PCD, LAS/LAZ or xyz text; "
                     f"extension {p.suffix or 'none'!r})")


_X_NAMES = ("x", "lon", "longitude", "longitude_deg", "easting", "east", "e")
_Y_NAMES = ("y", "lat", "latitude", "latitude_deg", "northing", "north", "n")
_Z_NAMES = ("z", "depth", "depth_m", "elevation", "elevation_m", "height", "h", "altitude")


#: rows parsed per chunk of an xyz text point cloud
XYZ_CHUNK_ROWS = 500_000


#: working copies of an xyz point cloud's coordinates counted by its memory budget (:class:`hadal.budget.DecodeBudget`):
#: the growable columns, their trimmed values and the stacked (n, 3) array
XYZ_WORKING_COPIES = 3.0
#: working copies of a LAS/LAZ, PCD or PLY cloud's (n, 3) float64 points counted by its memory budget: the points,
#: the finite points their first consumer keeps (:func:`hadal.grid.describe.describe_point_cloud`, the laser grid's
#: ``pts[ok]``) and that consumer's projected or cell-sorted copy
CLOUD_WORKING_COPIES = 3.0
#: bytes of one point's x, y, z as float64
POINT_BYTES = 24


def _read_xyz_cloud(p: Path, columns: list[str] | None, memory_limit_bytes: float | None = None) -> np.ndarray:
    """x y z (and more) numeric text columns, streamed: the (decompressed) file passes once through a
    :class:`~hadal.textstream.LineScan` (line-length bound) into pandas in chunks of :data:`XYZ_CHUNK_ROWS`,
    and only the three coordinate columns are kept, as float64. Peak memory: the points plus one chunk."""
    from hadal.budget import DecodeBudget
    from hadal.grid.sonar import _not_number
    from hadal.textstream import MAX_LINE_BYTES, GrowableColumn, LineScan, ScannedStream

    head, compression = read_head(p, MAX_LINE_BYTES + 1, strict=False)
    LineScan(p, "point cloud line").feed(head)
    text = head.decode("utf-8", errors="replace")
    first = next((t for ln in io.StringIO(text) if (t := ln.strip()) and not t.startswith(("#", "//"))), None)
    if first is None:
        raise InputError(f"{p}: no points (file has no data lines)")
    sep = "," if "," in first else ";" if ";" in first else r"\s+"
    header = 0 if any(_not_number(t) for t in first.replace(",", " ").replace(";", " ").split()) else None
    out = [GrowableColumn(max(p.stat().st_size // 24, 1024), np.float64) for _ in range(3)]
    budget = DecodeBudget(p, "point cloud", copies=XYZ_WORKING_COPIES, limit_bytes=memory_limit_bytes)
    idx: list[int] | None = None
    n_rows = 0
    with open_binary(p) as fh, decompress_errors(p, compression, "point cloud"):
        try:
            reader = pd.read_csv(ScannedStream(fh, LineScan(p, "point cloud line")), sep=sep, header=header,
                                 comment="#", skipinitialspace=True, engine="c", chunksize=XYZ_CHUNK_ROWS,
                                 encoding="utf-8", encoding_errors="replace")
            with reader:
                for df in reader:
                    if idx is None:
                        idx = _xyz_columns(p, df, columns, header)
                    raw = df.iloc[:, idx]
                    sub = raw.apply(pd.to_numeric, errors="coerce")
                    bad = sub.isna().any(axis=1) & raw.notna().all(axis=1)
                    if bad.any():
                        i = int(np.flatnonzero(bad.to_numpy())[0])
                        raise InputError(f"{p}: non-numeric value on data row {n_rows + i + 1} "
                                         f"({raw.iloc[i].tolist()})")
                    for k in range(3):
                        out[k].extend(sub.iloc[:, k].to_numpy(np.float64))
                    n_rows += len(df)
                    budget.hold(sum(c.a.nbytes for c in out), f"{n_rows:,} points so far")
        except InputError:
            raise
        except (pd.errors.ParserError, pd.errors.EmptyDataError, ValueError) as exc:
            raise InputError(f"{p}: cannot parse xyz text ({str(exc).splitlines()[0]})") from None
    if n_rows == 0:
        raise InputError(f"{p}: no points (header only)")
    return np.column_stack([c.values() for c in out])


def _xyz_columns(p: Path, df: pd.DataFrame, columns: list[str] | None, header: int | None) -> list[int]:
    """Which columns of an xyz table are x, y, z: by name (``columns`` given, or the header), else 0 1 2."""
    names = [str(c).strip().lower() for c in (columns or (df.columns if header == 0 else []))]
    if columns is not None and len(columns) > df.shape[1]:
        raise InputError(f"{p}: {len(columns)} column names given but the file has {df.shape[1]} columns")

    def pick(cands, default):
        for c in cands:
            if c in names:
                return names.index(c)
        return default

    idx = [pick(_X_NAMES, 0), pick(_Y_NAMES, 1), pick(_Z_NAMES, 2)] if names else [0, 1, 2]
    if df.shape[1] < 3 or max(idx) >= df.shape[1]:
        raise InputError(f"{p}: expected at least 3 columns (x y z), found {df.shape[1]}")
    return idx


def _check_las_count(p: Path, h: Any, budget: Any) -> int:
    """The point count of a LAS/LAZ header ``h``, refused when it declares more point records than the file holds
    (a truncated file or a lying header; LAS only, a LAZ has no size to check it against) or, with the working
    copies, more than ``budget`` (a :class:`hadal.budget.DecodeBudget`) allows: laspy decodes at most the declared
    count, and the points are allocated for it."""
    n, size = int(h.point_count), int(h.point_format.size)
    offset = int(h.offset_to_point_data)
    compressed = bool(getattr(h, "are_points_compressed", False))
    if not compressed and offset + n * size > p.stat().st_size:
        have = max(p.stat().st_size - offset, 0) // max(size, 1)
        raise InputError(f"{p}: LAS header declares {n:,} points but the file holds at most {have:,} "
                         "(truncated, or a wrong point count in the header)")
    budget.hold(n * POINT_BYTES, f"its header declares {n:,} points")
    return n


def _check_ply_budget(p: Path, limit_bytes: float | None) -> None:
    """Refuse a PLY whose header declares more vertices than the memory budget allows, before open3d allocates
    them (it sizes its arrays by the declared count: x/y/z, normals and colours as float64 triples) and the
    points' working copies (:data:`CLOUD_WORKING_COPIES`)."""
    from hadal.budget import DecodeBudget

    with open(p, "rb") as fh:
        head = fh.read(65536)
    n, props = 0, set()
    in_vertex = False
    for line in head.split(b"end_header", 1)[0].decode("ascii", errors="replace").splitlines():
        tok = line.split()
        if len(tok) >= 3 and tok[0] == "element":
            in_vertex = tok[1] == "vertex"
            if in_vertex and tok[2].isdigit():
                n = int(tok[2])
        elif in_vertex and len(tok) >= 3 and tok[0] == "property":
            props.add(tok[-1])
    triples = 1 + bool(props & {"nx", "ny", "nz"}) + bool(props & {"red", "green", "blue"})
    budget = DecodeBudget(p, "PLY point cloud", limit_bytes=limit_bytes)
    budget.hold(n * POINT_BYTES * (triples + CLOUD_WORKING_COPIES), f"its header declares {n:,} vertices")


def _quiet_open3d(o3d):
    """Silence open3d's console warnings while reading (we raise our own one-line errors)."""
    return o3d.utility.VerbosityContextManager(o3d.utility.VerbosityLevel.Error)


_PLY_SIZES = {"char": 1, "uchar": 1, "int8": 1, "uint8": 1, "short": 2, "ushort": 2, "int16": 2, "uint16": 2,
              "int": 4, "uint": 4, "int32": 4, "uint32": 4, "float": 4, "float32": 4, "double": 8, "float64": 8}


def _check_ply_count(p: Path, n_read: int) -> None:
    """Detect truncated PLY files, which open3d reads partially (zero-filling or dropping vertices).

    Compares the vertex count declared in the header with what was read and, for binary files whose
    elements have only scalar properties, the file size with the size the header implies.
    """
    with open(p, "rb") as fh:
        head = fh.read(65536)
    end = head.find(b"end_header")
    if end < 0:
        raise InputError(f"{p}: PLY header has no end_header (not a PLY file or truncated)")
    header_len = head.index(b"\n", end) + 1
    n_decl, binary, expected, sized = None, False, header_len, True
    cur = None
    for line in head[:header_len].decode("ascii", errors="replace").splitlines():
        tok = line.split()
        if not tok:
            continue
        if tok[0] == "format":
            binary = tok[1] != "ascii"
        elif tok[0] == "element" and len(tok) >= 3:
            cur = int(tok[2]) if tok[2].isdigit() else 0
            if tok[1] == "vertex":
                n_decl = cur
        elif tok[0] == "property" and cur is not None:
            if tok[1] == "list" or tok[1] not in _PLY_SIZES:
                sized = False
            else:
                expected += cur * _PLY_SIZES[tok[1]]
    if n_decl is not None and n_decl != n_read:
        raise InputError(f"{p}: PLY header declares {n_decl} vertices but {n_read} were read (truncated file?)")
    size = p.stat().st_size
    if binary and sized and size < expected:
        raise InputError(f"{p}: truncated PLY file ({size} bytes, header implies {expected})")


# ------------------------------------------------------------------ truncation (grids)
_NC_TYPE_SIZES = {1: 1, 2: 1, 3: 2, 4: 4, 5: 4, 6: 8, 7: 1, 8: 2, 9: 4, 10: 8, 11: 8}
_NC_STREAMING = 0xFFFFFFFF


def netcdf_classic_min_size(head: bytes) -> tuple[int, int]:
    """``(header_bytes, min_file_bytes)`` of a netCDF classic / 64-bit offset / CDF-5 file from its header.

    These formats store variables uncompressed at the ``begin`` offsets the header gives, so a complete file
    is at least ``max(begin + size)`` over the variables (record variables: ``numrecs`` records of the
    record size). Raises ``ValueError`` when ``head`` ends inside the header (itself truncated) or is not one.
    """
    import struct

    if head[:3] != b"CDF" or head[3:4] not in (b"\x01", b"\x02", b"\x05"):
        raise ValueError("not a netCDF classic file")
    ver = head[3]
    pos = 4
    n_fmt = ">Q" if ver == 5 else ">I"
    n_len = 8 if ver == 5 else 4

    def take(n: int) -> bytes:
        nonlocal pos
        if pos + n > len(head):
            raise ValueError("header ends early")
        b = head[pos:pos + n]
        pos += n
        return b

    def count() -> int:
        return struct.unpack(n_fmt, take(n_len))[0]

    def u32() -> int:
        return struct.unpack(">I", take(4))[0]

    def name() -> str:
        n = count()
        s = take(n)
        take((-n) % 4)
        return s.decode("utf-8", "replace")

    def att_list() -> None:
        tag, n = u32(), count()
        if tag not in (0, 0x0C):
            raise ValueError("bad attribute list tag")
        for _ in range(n):
            name()
            t = u32()
            m = count()
            sz = m * _NC_TYPE_SIZES.get(t, 1)
            take(sz + (-sz) % 4)

    numrecs = count()
    tag, ndims = u32(), count()
    if tag not in (0, 0x0A):
        raise ValueError("bad dimension list tag")
    dims = []
    for _ in range(ndims):
        name()
        dims.append(count())
    att_list()
    tag, nvars = u32(), count()
    if tag not in (0, 0x0B):
        raise ValueError("bad variable list tag")
    off_fmt, off_len = (">I", 4) if ver == 1 else (">Q", 8)
    vars_ = []
    for _ in range(nvars):
        name()
        nd = count()
        ids = [count() for _ in range(nd)]
        att_list()
        t = u32()
        vsize = count()
        begin = struct.unpack(off_fmt, take(off_len))[0]
        shape = [dims[i] if i < len(dims) else 0 for i in ids]
        is_rec = bool(ids) and shape[0] == 0
        n = 1
        for s in (shape[1:] if is_rec else shape):
            n *= s
        vars_.append((begin, n * _NC_TYPE_SIZES.get(t, 1), vsize, is_rec))
    header = pos
    rec_vars = [v for v in vars_ if v[3]]
    recsize = sum(v[2] for v in rec_vars) if len(rec_vars) != 1 else rec_vars[0][1]
    need = header
    for begin, raw, _vsize, is_rec in vars_:
        if is_rec:
            if numrecs in (0, _NC_STREAMING if ver != 5 else 2**64 - 1):
                continue
            need = max(need, begin + (numrecs - 1) * recsize + raw)
        else:
            need = max(need, begin + raw)
    return header, need


def _hdf5_eof_address(p: Path) -> int | None:
    """The end-of-file address an HDF5 superblock records (at 0, 512, 1024, ...), or None."""
    size = p.stat().st_size
    with open(p, "rb") as fh:
        off = 0
        while off + 64 <= size:
            fh.seek(off)
            sb = fh.read(96)
            if sb[:8] == b"\x89HDF\r\n\x1a\n":
                ver = sb[8]
                if ver in (0, 1):
                    so = sb[13]
                    start = 24 + (4 if ver == 1 else 0)
                    i = start + 2 * so  # base address, free-space address, then end-of-file address
                else:
                    so = sb[9]
                    i = 12 + 2 * so  # base address, superblock extension address, then end-of-file address
                if so not in (2, 4, 8) or i + so > len(sb):
                    return None
                base = int.from_bytes(sb[(start if ver in (0, 1) else 12):][:so], "little")
                eof = int.from_bytes(sb[i:i + so], "little")
                if eof == (1 << (8 * so)) - 1:  # undefined address
                    return None
                return (base or off) + eof  # relative to the base address (the superblock's, normally)
            off = 512 if off == 0 else off * 2
    return None


def check_grid_truncation(p: Path) -> None:
    """A one-line :class:`InputError` when a NetCDF grid is shorter than its own header says.

    netCDF classic/64-bit offset/CDF-5: the header's variable offsets and sizes (data uncompressed); netCDF-4
    (HDF5): the superblock's end-of-file address. Other files are not checked here.
    """
    size = p.stat().st_size
    with open(p, "rb") as fh:
        magic = fh.read(8)
    if magic[:3] == b"CDF":
        with open(p, "rb") as fh:
            head = fh.read(1 << 20)
        try:
            header, need = netcdf_classic_min_size(head)
        except ValueError as exc:
            if str(exc) == "header ends early":
                if len(head) < size:  # a huge header: read the whole file
                    try:
                        header, need = netcdf_classic_min_size(p.read_bytes())
                    except ValueError:
                        raise InputError(f"{p}: truncated: {size} bytes, the netCDF header itself is incomplete"
                                         ) from None
                else:
                    raise InputError(f"{p}: truncated: {size} bytes, the netCDF header itself is incomplete"
                                     ) from None
            else:
                return
        if size < need:
            raise InputError(f"{p}: truncated: {size} bytes, the header implies at least {need}")
        return
    eof = _hdf5_eof_address(p) if magic == b"\x89HDF\r\n\x1a\n" or size > 512 else None
    if eof is not None and size < eof:
        raise InputError(f"{p}: truncated: {size} bytes, the header implies at least {eof}")


_TIFF_TYPES = {1: ("B", 1), 3: ("H", 2), 4: ("I", 4), 16: ("Q", 8), 13: ("I", 4)}


def tiff_min_size(p: Path) -> int | None:
    """The bytes a (Big)TIFF needs for its first image: ``max(offset + byte count)`` over its strips/tiles
    (and the IFD itself), from the header; None when it is not a TIFF or the tags are not plain."""
    import struct

    size = p.stat().st_size
    with open(p, "rb") as fh:
        hdr = fh.read(16)
        if hdr[:2] not in (b"II", b"MM"):
            return None
        e = "<" if hdr[:2] == b"II" else ">"
        magic = struct.unpack(e + "H", hdr[2:4])[0]
        if magic == 42:
            ifd, big = struct.unpack(e + "I", hdr[4:8])[0], False
        elif magic == 43:
            ifd, big = struct.unpack(e + "Q", hdr[8:16])[0], True
        else:
            return None
        cnt_fmt, cnt_len, ent_len = ("Q", 8, 20) if big else ("H", 2, 12)
        if ifd + cnt_len > size:
            return ifd + cnt_len
        fh.seek(ifd)
        n = struct.unpack(e + cnt_fmt, fh.read(cnt_len))[0]
        need = ifd + cnt_len + n * ent_len
        if need > size:
            return need
        raw = fh.read(n * ent_len)
        tags: dict[int, list[int]] = {}
        for k in range(n):
            ent = raw[k * ent_len:(k + 1) * ent_len]
            tag, typ = struct.unpack(e + "HH", ent[:4])
            if tag not in (273, 279, 324, 325):
                continue
            if typ not in _TIFF_TYPES:
                return None
            c, sz = _TIFF_TYPES[typ]
            count = struct.unpack(e + ("Q" if big else "I"), ent[4:12] if big else ent[4:8])[0]
            field = ent[12:20] if big else ent[8:12]
            if count * sz <= len(field):
                data = field[:count * sz]
            else:
                off = struct.unpack(e + ("Q" if big else "I"), field)[0]
                if off + count * sz > size:
                    return off + count * sz
                fh.seek(off)
                data = fh.read(count * sz)
            tags[tag] = list(struct.unpack(e + c * count, data))
    for o_tag, c_tag in ((273, 279), (324, 325)):
        if o_tag in tags and c_tag in tags and len(tags[o_tag]) == len(tags[c_tag]):
            ends = [o + c for o, c in zip(tags[o_tag], tags[c_tag], strict=True) if c > 0]
            if ends:
                need = max(need, max(ends))
    return need


# ------------------------------------------------------------------ grids
def looks_metric(x_extent: float, y_extent: float, relief_m: float) -> bool:
    """True when a grid tagged geographic is really in metres.

    Either the extent is impossible in degrees, or the data relief (m) is implausibly small for the
    extent *read as degrees* (mean slope < 1e-5: 2 m of relief over 2000 km) yet plausible for the
    extent read as metres (slope 1e-3..10). Real ETOPO-like grids have slopes ~1e-3..1e-2 in degrees
    and are absurd (> 10) read as metres; a metric laser grid (metres of relief over tens of metres)
    is the reverse.
    """
    if x_extent > 360 or y_extent > 180:
        return True
    diag = math.hypot(x_extent, y_extent)
    if diag <= 0 or not math.isfinite(relief_m):
        return False
    slope_deg_reading = relief_m / (diag * 111_320.0)
    slope_m_reading = relief_m / diag
    return slope_deg_reading < 1e-5 and 1e-3 <= slope_m_reading <= 10


#: bytes a grid read needs per cell at its peak, working copies included: the stored values, the mask, the float64
#: copy, the finite mask, a unit conversion, and the prior-grid DTM made from it (sign, land mask, resampling onto
#: the map frame at about the grid's cell count). Measured (issue 45, GDAL block cache 64 MB): load_prior of a
#: 2,000 x 2,000 float32 GeoTIFF 41 B/cell (tracemalloc), prior_dtm 105 B/cell (tracemalloc), 120 B/cell RSS; the
#: 17 B/cell counted before let a GeoTIFF "just under the budget" peak at several times the budget
GRID_READ_BYTES_PER_CELL = 128


def check_grid_read_size(p: Path, ny: int, nx: int, max_bytes: float | None) -> None:
    """One-line :class:`InputError` when reading a ``ny`` x ``nx`` grid would need more than ``max_bytes``
    (default: the memory budget of :mod:`hadal.budget`), before anything is read: a prior map of a whole ocean
    basin, or a header that declares absurd dimensions."""
    from hadal.budget import format_bytes, memory_limit_bytes

    limit = memory_limit_bytes(None) if max_bytes is None else max_bytes
    need = float(ny) * float(nx) * GRID_READ_BYTES_PER_CELL
    if need > limit:
        raise InputError(f"{p}: the grid is {ny:,} x {nx:,} cells; reading it needs about {format_bytes(need)} "
                         f"(limit {format_bytes(limit)}): crop it to the dive area first (e.g. gdal_translate "
                         "-projwin or gmt grdcut) or raise resources.max_memory_gb")


def read_grid(path: str | Path, *, crs_kind: str | None = None, variable: str | None = None,
              format: str | None = None, crs: str | None = None, max_bytes: float | None = None,
              z_units: str | None = None) -> xr.DataArray:
    """Read a gridded surface as a 2-D DataArray ``z(y, x)`` in metres (the sign as stored: it is the caller's).

    The format is detected from the content (:func:`sniff_kind`; ``format`` overrides): GeoTIFF and any
    other GDAL raster (ESRI ASCII, Surfer, BAG ...) via rasterio; NetCDF COARDS/CF and GMT netCDF ``.grd``
    (also GMT's old 1-D ``x_range``/``dimension``/``z`` layout) via xarray, falling back to GDAL. GMT's
    native binary ``.grd`` formats are not readable by GDAL: a clear error says how to convert them.

    Coordinates are the positions of the values, ascending: cell centres of pixel-registered grids
    (GeoTIFF ``AREA_OR_POINT=Area``, GMT ``node_offset=1``), nodes of gridline-registered ones
    (``attrs["registration"]``). Nodata/``_FillValue``/±inf become NaN. ``attrs``: ``crs_kind``
    (``geographic`` x/y degrees, ``projected`` x/y in a CRS, ``local_metric`` metres with no usable CRS),
    ``crs_wkt``, ``cell_size_x``/``cell_size_y``, ``units``, ``format``, ``reader``, ``registration``,
    ``nodata``, ``nodata_fraction``, and the value's ``var_name``/``long_name``/``standard_name``/
    ``positive`` when the file has them (for the sign detection of :mod:`hadal.grid.prior`).

    GDAL band scale/offset are applied (``attrs["scale_offset"]``). A NetCDF variable with dimensions beyond
    its two x/y ones is squeezed when they have length 1 and refused when longer (``z(time, lat, lon)`` with
    several times: no slice is picked silently); a CF lat/lon netCDF is never handed to GDAL's band 1.
    Longitudes in -180..180 that jump at the antimeridian are unwrapped (> 180 after the jump).

    **Units** (:func:`apply_z_units`): the values' units come from the file (NetCDF ``units``, GDAL band unit or
    ``UNITS`` tag, the linear unit of a GeoTIFF's vertical CRS) or the ``z_units`` hint of ``dive.yaml``, and are
    converted to metres (``km`` x 1000, ``ft`` x 0.3048, ...); ``attrs["units"]`` is then ``m`` and
    ``attrs["z_units_source"]`` says what was done. Units hadal cannot convert are refused in one line; no units
    at all: metres assumed (``attrs["z_units_assumed"] = 1``; ``hadal init`` writes ``z_units: m`` into dive.yaml).

    **Longitudes** of a geographic grid wholly east of 180° (0-360 convention, e.g. 195..210) are shifted by -360
    to -180..180 (``attrs["lon_convention"]`` records it); a grid across 180° keeps continuous longitudes (> 180
    after the antimeridian), which every lookup wraps mod 360.

    ``crs_kind`` or ``crs`` (``'EPSG:32654'``, WKT, PROJ, or ``'local'``) override the file. Without them a
    raster whose only geographic evidence is a CRS tag (GeoTIFF/GDAL; not a NetCDF with ``degrees_east``/
    ``degrees_north`` coordinates, which say so themselves) and whose extent/relief make no sense in degrees
    (:func:`looks_metric`) is returned as ``local_metric`` with a :class:`GridCRSWarning`. Every failure is a one-line :class:`InputError`; a grid
    whose read would need more than ``max_bytes`` (default: the memory budget) is refused before it is read
    (:func:`check_grid_read_size`).
    """
    p = _require_file(path, "grid")
    if crs_kind not in (None, "geographic", "projected", "local_metric"):
        raise InputError(f"crs_kind must be geographic, projected or local_metric, got {crs_kind!r}")
    kind = _kind_of(p, format)
    if kind in _CLOUD_KINDS:
        raise InputError(f"{p}: is a {kind} point cloud, not a grid")
    if kind == "geotiff":
        _check_tiff_truncation(p)
        da = _read_geotiff(p, max_bytes)
    elif kind == "netcdf":
        da = _read_netcdf_or_gdal(p, variable, max_bytes)
    else:
        da = _read_gdal_raster(p, max_bytes)
    if da.sizes["x"] < 2 or da.sizes["y"] < 2:
        raise InputError(f"{p}: grid must be at least 2 x 2 cells, got {da.sizes['y']} x {da.sizes['x']}")
    finite = np.isfinite(da.values)
    if not finite.any():
        raise InputError(f"{p}: grid has no valid (non-nodata) cells")
    da.attrs["nodata_fraction"] = float(1.0 - finite.mean())
    da = apply_z_units(p, da, z_units)
    _apply_crs(p, da, crs, crs_kind)
    return _lon_convention(da)


#: linear units of grid values -> metres (CF/UDUNITS spellings, GDAL band units, PROJ unit names)
Z_UNIT_FACTORS: dict[str, float] = {
    **dict.fromkeys(("m", "meter", "meters", "metre", "metres", "metre(s)", "meter(s)"), 1.0),
    **dict.fromkeys(("km", "kilometer", "kilometers", "kilometre", "kilometres"), 1000.0),
    **dict.fromkeys(("cm", "centimeter", "centimeters", "centimetre", "centimetres"), 0.01),
    **dict.fromkeys(("mm", "millimeter", "millimeters", "millimetre", "millimetres"), 0.001),
    **dict.fromkeys(("dm", "decimeter", "decimetre", "decimeters", "decimetres"), 0.1),
    **dict.fromkeys(("ft", "feet", "foot", "international foot", "international_foot", "international feet"),
                    0.3048),
    **dict.fromkeys(("us survey foot", "us_survey_foot", "us survey feet", "ftus", "us-ft", "us_ft", "survey foot",
                     "foot_us", "us-foot"), 1200.0 / 3937.0),
    **dict.fromkeys(("fathom", "fathoms", "fm", "ftm"), 1.8288),
}
#: ``units`` values that say nothing (treated as absent)
_NO_UNITS = ("", "none", "unknown", "n/a", "na", "-", "?", "1", "unitless")


def z_unit_factor(units: str) -> float | None:
    """Metres per unit of ``units`` (``m``, ``km``, ``ft``, ``feet``, ``metres above sea level`` ...), else ``None``.
    A compound name (``metres above mean sea level``, ``m (positive up)``) is read by its first word."""
    u = str(units).strip().lower()
    if u in Z_UNIT_FACTORS:
        return Z_UNIT_FACTORS[u]
    first = re.split(r"[\s(,;]+", u, maxsplit=1)[0] if u else ""
    return Z_UNIT_FACTORS.get(first)


def apply_z_units(p: Path, da: xr.DataArray, hint: str | None = None) -> xr.DataArray:
    """``da`` converted to metres from its units (module :func:`read_grid` rules); a one-line :class:`InputError`
    for units that are not a length hadal knows. Records ``units`` (now ``m``), ``z_units_file`` (as the file
    says), ``z_units_source`` (what was done) and ``z_units_assumed`` (1 when nothing said)."""
    given = str(da.attrs.get("units", "") or "").strip()
    if hint is not None:
        f = z_unit_factor(hint)
        if f is None:
            raise InputError(f"{p}: z_units {hint!r} in dive.yaml is not a length unit hadal converts "
                             f"(use one of m, km, cm, mm, ft, us survey foot, fathom)")
        how, assumed = f"z_units {hint!r} given in dive.yaml", 0
    elif given.lower() in _NO_UNITS:
        f, how, assumed = 1.0, "no units in the file: metres assumed", 1
    else:
        f = z_unit_factor(given)
        if f is None:
            raise InputError(f"{p}: grid values are in {given!r}, not a length unit hadal converts to metres "
                             "(m, km, cm, mm, ft, us survey foot, fathom): give z_units in dive.yaml if it is one")
        how, assumed = f"units {given!r} in the file", 0
    if f != 1.0:
        attrs = dict(da.attrs)
        da = da * f
        da.attrs = attrs
        how += f": x {f:g} to metres"
    da.attrs.update(units="m", z_units_file=given, z_units_source=how, z_units_assumed=assumed)
    return da


def _lon_convention(da: xr.DataArray) -> xr.DataArray:
    """Shift the longitudes of a geographic grid wholly east of 180° (0-360 convention) to -180..180."""
    if da.attrs.get("crs_kind") != "geographic":
        return da
    x = np.asarray(da.x.values, float)
    h = 0.5 * abs(float(da.attrs.get("cell_size_x") or 0.0)) if da.attrs.get("registration") == "pixel" else 0.0
    if x.size and x[0] - h >= 180.0 and x[-1] + h <= 360.0 + 1e-9:
        xattrs = dict(da["x"].attrs)
        da = da.assign_coords(x=("x", x - 360.0, xattrs))
        da.attrs["lon_convention"] = (f"0-360 in the file ({x[0] - h:g}..{x[-1] + h:g}); shifted by -360 to "
                                      f"{x[0] - h - 360:g}..{x[-1] + h - 360:g}")
    elif x.size and x[-1] > 180.0:
        da.attrs["lon_convention"] = (f"{x[0] - h:g}..{x[-1] + h:g}: across 180°, kept continuous (lookups wrap "
                                      "longitudes mod 360)")
    return da


def _read_netcdf_or_gdal(p: Path, variable: str | None, max_bytes: float | None) -> xr.DataArray:
    """A NetCDF grid via xarray, falling back to GDAL for HDF5/layouts xarray cannot map (see :func:`read_grid`)."""
    from hadal.confine import check_hdf5_self_contained

    check_grid_truncation(p)  # classic netCDF is read zero-filled past a cut, as a valid-looking grid
    check_hdf5_self_contained(p)  # no value read from an external raw file or a virtual dataset's sources
    try:
        return _read_netcdf_grid(p, variable, max_bytes)
    except InputError as first:
        # HDF5 that is not netCDF (e.g. BAG), or a layout xarray cannot map: GDAL's turn. A readable netCDF
        # that lacks the asked-for variable or its coordinates stays an error (GDAL would silently give
        # pixel indices as coordinates).
        if variable is not None or not any(t in str(first) for t in ("cannot read NetCDF", "no 2-D variable")):
            raise
        # A netCDF with CF lat/lon coordinate variables is geographic: GDAL's band 1 of it (e.g. of a
        # z(time, lat, lon) cube) would come back as 'local metric' with degree-sized metre cells - a
        # silently wrong DTM. Refuse instead of falling back.
        ll = _netcdf_latlon_names(p)
        if ll:
            raise InputError(f"{str(first).rstrip('.')}; the file has CF lat/lon coordinates "
                             f"({', '.join(ll)}) but no readable 2-D lat/lon grid variable: give the "
                             "variable in dive.yaml or make a 2-D file (e.g. 'ncks -d time,0 IN.nc OUT.nc')"
                             ) from None
        try:
            return _read_geotiff(p, max_bytes)
        except InputError:
            raise first from None


def _read_gdal_raster(p: Path, max_bytes: float | None) -> xr.DataArray:
    """Any other GDAL raster; a one-line error (with a GMT hint for ``.grd``) when GDAL cannot read it."""
    from hadal.confine import ConfinementError

    try:
        return _read_geotiff(p, max_bytes)
    except InputError as exc:
        if "reading it needs about" in str(exc) or isinstance(exc, ConfinementError):
            raise
        hint = (" (a GMT native binary grid? GDAL cannot read those: convert it with "
                "'gmt grdconvert IN.grd OUT.nc')" if p.suffix.lower() == ".grd" else "")
        raise InputError(f"{p}: not a grid format hadal reads (GeoTIFF, NetCDF/GMT netCDF or another GDAL "
                         f"raster){hint}") from None


def _apply_crs(p: Path, da: xr.DataArray, crs: str | None, crs_kind: str | None) -> None:
    """Apply the ``crs``/``crs_kind`` overrides, the local-metric detection and the x/y units (in place)."""
    detected = da.attrs["crs_kind"]
    if crs is not None:
        if str(crs).lower() in ("local", "local_metric", "none"):
            da.attrs.update(crs_kind="local_metric", crs_wkt="", crs_override=f"crs {crs!r} given in dive.yaml")
        else:
            from pyproj import CRS
            from pyproj.exceptions import CRSError

            try:
                c = CRS.from_user_input(crs)
            except CRSError as exc:
                raise InputError(f"{p}: cannot use crs {crs!r} ({str(exc).splitlines()[0]})") from None
            da.attrs.update(crs_kind="geographic" if c.is_geographic else "projected", crs_wkt=c.to_wkt(),
                            crs_override=f"crs {crs!r} given in dive.yaml")
    if crs_kind is not None:
        da.attrs["crs_kind"] = crs_kind
    elif crs is None and detected == "geographic" and not da.attrs.get("coords_in_degrees"):
        xe = float(da.x[-1] - da.x[0]) + abs(float(da.attrs.get("cell_size_x", 0)))
        ye = float(da.y[-1] - da.y[0]) + abs(float(da.attrs.get("cell_size_y", 0)))
        relief = float(np.nanmax(da.values) - np.nanmin(da.values))
        if looks_metric(xe, ye, relief):
            warnings.warn(
                f"{p.name}: CRS says geographic but a {xe:g} x {ye:g} extent with {relief:.3g} m of relief only "
                "makes sense in metres; treating it as a local metric grid",
                GridCRSWarning, stacklevel=3,
            )
            da.attrs["crs_kind"] = "local_metric"
            da.attrs["crs_override"] = "geographic tag ignored: local metric frame"
    if da.attrs["crs_kind"] != "geographic":
        da["x"].attrs.update({"units": "m"})
        da["y"].attrs.update({"units": "m"})
    else:
        da["x"].attrs.update({"units": "degrees_east", "standard_name": "longitude"})
        da["y"].attrs.update({"units": "degrees_north", "standard_name": "latitude"})


def _check_tiff_truncation(p: Path) -> None:
    need = tiff_min_size(p)
    if need is not None and p.stat().st_size < need:
        raise InputError(f"{p}: truncated: {p.stat().st_size} bytes, the header implies at least {need}")


def _read_geotiff(p: Path, max_bytes: float | None = None) -> xr.DataArray:
    """Band 1 of a GDAL raster (GeoTIFF or any format GDAL identifies) via rasterio."""
    import rasterio
    from rasterio.errors import RasterioError

    from hadal.confine import check_gdal_file, check_opened_files, gdal_env

    check_gdal_file(p)  # a VRT naming a file outside the dive, a URL or /vsicurl/: refused before GDAL opens it
    try:
        with warnings.catch_warnings(), gdal_env():
            warnings.simplefilter("ignore", rasterio.errors.NotGeoreferencedWarning)
            with rasterio.open(p) as src:
                check_opened_files(p, list(src.files))
                if src.count < 1:
                    raise InputError(f"{p}: raster has no bands")
                check_grid_read_size(p, src.height, src.width, max_bytes)
                a = src.read(1, masked=True).astype(np.float64).filled(np.nan)
                # GDAL band scale/offset (packed int16 grids): value = raw * scale + offset, as GDAL's
                # 'unscale' and netCDF's scale_factor/add_offset; nodata applies to the raw values (masked above)
                scale = float(src.scales[0]) if src.scales and src.scales[0] is not None else 1.0
                offset = float(src.offsets[0]) if src.offsets and src.offsets[0] is not None else 0.0
                if scale != 1.0 or offset != 0.0:
                    a = a * scale + offset
                nodata = src.nodata
                t = src.transform
                crs = src.crs
                driver = src.driver
                units = (src.units[0] if src.units and src.units[0] else None) or _vertical_unit(crs)
                tags = {**src.tags(), **src.tags(1)}
                desc = src.descriptions[0] if src.descriptions else None
                georef = not t.is_identity
    except InputError:
        raise
    except RasterioError as exc:
        raise InputError(f"{p}: cannot read raster ({str(exc).splitlines()[0]})") from None
    except (OSError, ValueError, MemoryError) as exc:
        raise InputError(f"{p}: cannot read raster ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})"
                         ) from None
    if t.b != 0 or t.d != 0:
        raise InputError(f"{p}: rotated rasters are not supported")
    if not georef:  # pixel indices as coordinates would be a silently wrong cell size and position
        raise InputError(f"{p}: raster has no georeferencing (no geotransform: cell size and origin unknown); give "
                         "it one, e.g. a world file beside it or 'gdal_translate -a_ullr ULX ULY LRX LRY'")
    a[~np.isfinite(a)] = np.nan
    ny, nx = a.shape
    x = t.c + (np.arange(nx) + 0.5) * t.a
    y = t.f + (np.arange(ny) + 0.5) * t.e
    if t.a < 0:
        x, a = x[::-1], a[:, ::-1]
    if t.e < 0:
        y, a = y[::-1], a[::-1, :]
    kind = "local_metric" if crs is None else ("geographic" if crs.is_geographic else "projected")
    # GDAL shifts AREA_OR_POINT=Point rasters' transform by half a cell, so (i + 0.5) is the value's position
    reg = "gridline" if str(tags.get("AREA_OR_POINT", "Area")).lower() == "point" else "pixel"
    low = {k.lower(): v for k, v in tags.items()}
    attrs = {"crs_kind": kind, "crs_wkt": crs.to_wkt() if crs else "", "nodata": nodata if nodata is not None else "",
             "cell_size_x": abs(t.a), "cell_size_y": abs(t.e), "units": units or low.get("units", ""),
             "source": str(p), "format": "GeoTIFF" if driver == "GTiff" else f"GDAL {driver}",
             "reader": reader_of("geotiff"), "registration": reg, "var_name": "band 1"}
    if scale != 1.0 or offset != 0.0:
        attrs["scale_offset"] = f"band scale {scale:g}, offset {offset:g} applied"
    for k in ("positive", "standard_name", "long_name"):
        if k in low:
            attrs[k] = str(low[k])
    if desc:
        attrs.setdefault("long_name", str(desc))
    return xr.DataArray(np.ascontiguousarray(a), dims=("y", "x"), coords={"x": x, "y": y}, name="z", attrs=attrs)


def _vertical_unit(crs) -> str | None:
    """The linear unit name of a raster CRS's vertical component (a compound CRS), else ``None``."""
    if crs is None:
        return None
    try:
        from pyproj import CRS

        c = CRS.from_wkt(crs.to_wkt())
        for sub in c.sub_crs_list or []:
            if sub.is_vertical and sub.axis_info:
                return str(sub.axis_info[0].unit_name)
    except Exception:  # noqa: BLE001 - an unusual CRS: no vertical unit read from it
        return None
    return None


_X_DIM_NAMES = ("lon", "longitude", "x", "easting", "nav_lon", "long")
_Y_DIM_NAMES = ("lat", "latitude", "y", "northing", "nav_lat")
_PREFERRED_VARS = ("z", "elevation", "depth", "topo", "topography", "bathymetry", "bathy", "height", "band1",
                   "altitude", "elev", "dem")
_NOT_GRID_VARS = ("crs", "spatial_ref", "lat", "lon", "latitude", "longitude", "x", "y", "mask", "count",
                  "uncertainty", "std", "tid", "source", "flags")


def _axis_of(name: str, var: xr.DataArray | None) -> str | None:
    a = var.attrs if var is not None else {}
    sn = str(a.get("standard_name", "")).lower()
    un = str(a.get("units", "")).lower()
    ax = str(a.get("axis", "")).upper()
    n = name.lower()
    if ax == "X" or sn in ("longitude", "projection_x_coordinate", "grid_longitude") or un.startswith(
            ("degree_e", "degrees_e")) or n in _X_DIM_NAMES:
        return "x"
    if ax == "Y" or sn in ("latitude", "projection_y_coordinate", "grid_latitude") or un.startswith(
            ("degree_n", "degrees_n")) or n in _Y_DIM_NAMES:
        return "y"
    return None


def _read_netcdf_grid(p: Path, variable: str | None, max_bytes: float | None = None) -> xr.DataArray:
    """A 2-D variable of a NetCDF (COARDS/CF, GMT netCDF) file via xarray."""
    try:
        ds = xr.open_dataset(p, decode_times=False)
    except Exception as exc:  # noqa: BLE001 - xarray raises many kinds for non-netCDF/corrupt files
        raise InputError(f"{p}: cannot read NetCDF ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})"
                         ) from None
    with ds:
        if variable is None and "z" in ds and ds["z"].ndim == 1 and "dimension" in ds and "x_range" in ds:
            return _read_old_gmt(p, ds)
        da = _netcdf_variable(p, ds, variable)
        big = [n for n in da.shape if n > 1]
        if len(big) == 2:
            check_grid_read_size(p, big[0], big[1], max_bytes)
        try:
            da = da.squeeze(drop=True).load()
        except InputError:
            raise
        except Exception as exc:  # noqa: BLE001 - truncated data blocks
            raise InputError(f"{p}: cannot read variable {da.name!r} ({str(exc).splitlines()[0]})") from None
        gm_attrs = _netcdf_grid_mapping(ds, da)
        gattrs = dict(ds.attrs)
        fmt = _netcdf_format(p, ds)
    if da.ndim != 2:
        raise InputError(f"{p}: variable {da.name!r} is not 2-D after dropping length-1 dimensions ({da.dims})")
    var_name = str(da.name)
    d0, d1 = (str(d) for d in da.dims)
    ax0, ax1 = _axis_of(d0, da[d0] if d0 in da.coords else None), _axis_of(d1, da[d1] if d1 in da.coords else None)
    if ax0 == "x" or ax1 == "y":
        da = da.transpose(d1, d0)
        d0, d1 = d1, d0
    for d in (d0, d1):
        if d not in da.coords:
            raise InputError(f"{p}: grid dimension {d!r} has no coordinate values")
    xv, yv = da[d1], da[d0]
    xu, yu = str(xv.attrs.get("units", "")).lower(), str(yv.attrs.get("units", "")).lower()
    xs, ys = str(xv.attrs.get("standard_name", "")).lower(), str(yv.attrs.get("standard_name", "")).lower()
    #: the coordinates themselves say degrees (COARDS/CF units or standard names): never re-read as metres
    in_degrees = xu.startswith("degree") or yu.startswith("degree") or (xs, ys) == ("longitude", "latitude")
    geographic = in_degrees or (d1.lower() in ("lon", "longitude") and d0.lower() in ("lat", "latitude"))
    vattrs = dict(da.attrs)
    da = da.rename({d0: "y", d1: "x"}).astype(np.float64)
    da = da.where(np.isfinite(da))  # inf cells are nodata, as in GeoTIFFs (_FillValue: masked by xarray)
    if geographic and da.sizes["x"] > 1:
        # a regular grid across the antimeridian in -180..180 longitudes (179.98 .. 180, -179.999 ..): unwrap
        # the jump of ~360 deg so the longitudes are continuous (> 180 after it; lookups wrap them mod 360)
        lon = np.asarray(da.x.values, float)
        if np.all(np.isfinite(lon)) and np.any(np.abs(np.diff(lon)) > 180.0):
            da = da.assign_coords(x=np.unwrap(lon, period=360.0))
    if da.sizes["x"] > 1 and float(da.x[1] - da.x[0]) < 0:
        da = da.isel(x=slice(None, None, -1))
    if da.sizes["y"] > 1 and float(da.y[1] - da.y[0]) < 0:
        da = da.isel(y=slice(None, None, -1))
    cells = _regular_cells(p, da)
    crs_wkt, crs_note, geographic = _netcdf_crs(gm_attrs, geographic)
    kind = "geographic" if geographic else ("projected" if crs_wkt else "local_metric")
    reg, reg_src = _registration(vattrs, gattrs)
    da = da.reset_coords(drop=True)
    attrs = {"crs_kind": kind, "crs_wkt": crs_wkt, "cell_size_x": cells[0], "cell_size_y": cells[1],
             "units": str(vattrs.get("units", "")), "source": str(p), "format": fmt, "reader": reader_of("netcdf"),
             "registration": reg, "registration_source": reg_src, "var_name": var_name, "nodata": ""}
    if in_degrees and kind == "geographic":
        attrs["coords_in_degrees"] = 1
    if crs_note:
        attrs["crs_note"] = crs_note
    for k in ("positive", "standard_name", "long_name"):
        if k in vattrs:
            attrs[k] = str(vattrs[k])
    da.attrs = attrs
    da.name = "z"
    return da


def _netcdf_variable(p: Path, ds: xr.Dataset, variable: str | None) -> xr.DataArray:
    """The (not yet loaded) grid variable of ``ds``: ``variable``, else the preferred/first 2-D data variable."""
    if variable is not None:
        if variable not in ds:
            raise InputError(f"{p}: no variable {variable!r} (have {', '.join(map(str, ds.data_vars))})")
        da = ds[variable]
        _refuse_stacked(p, ds, [variable])
        return da
    else:
        def squeezed_ndim(v):
            return sum(s > 1 for s in ds[v].shape)

        cands = [v for v in ds.data_vars if ds[v].ndim >= 2 and squeezed_ndim(v) == 2
                 and str(v).lower() not in _NOT_GRID_VARS]
        if not cands:
            _refuse_stacked(p, ds, [v for v in ds.data_vars if str(v).lower() not in _NOT_GRID_VARS])
            raise InputError(f"{p}: no 2-D variable to read as a grid (have {', '.join(map(str, ds.data_vars))})")
        pref = [v for v in cands if str(v).lower() in _PREFERRED_VARS]
        return ds[(pref or cands)[0]]


def _netcdf_grid_mapping(ds: xr.Dataset, da: xr.DataArray) -> dict:
    """The attrs of ``da``'s CF grid-mapping variable, else of a conventional CRS variable holding a WKT."""
    gm = str(da.attrs.get("grid_mapping", "") or da.encoding.get("grid_mapping", ""))
    gm_attrs = dict(ds[gm].attrs) if gm and gm in ds else {}
    if not gm_attrs:
        for cand in ("crs", "spatial_ref", "transverse_mercator", "mercator"):
            if cand in ds.variables and ("crs_wkt" in ds[cand].attrs or "spatial_ref" in ds[cand].attrs):
                gm_attrs = dict(ds[cand].attrs)
                break
    return gm_attrs


def _netcdf_format(p: Path, ds: xr.Dataset) -> str:
    """The ``format`` attr: the netCDF flavour from the magic bytes, GMT version and Conventions."""
    with open(p, "rb") as fh:
        magic = fh.read(4)
    fmt = {b"CDF\x01": "netCDF classic", b"CDF\x02": "netCDF 64-bit offset", b"CDF\x05": "netCDF CDF-5",
           b"\x89HDF": "netCDF-4 (HDF5)"}.get(magic, "netCDF")
    if "GMT_version" in ds.attrs or "node_offset" in ds.attrs:
        fmt += f", GMT grid ({ds.attrs.get('GMT_version', 'GMT')})"
    conv = ds.attrs.get("Conventions")
    if conv:
        fmt += f", {conv}"
    return fmt


def _regular_cells(p: Path, da: xr.DataArray) -> list[float]:
    """The x and y cell sizes of a grid with ascending coordinates; irregular spacing is refused."""
    cells = []
    for d in ("x", "y"):
        c = np.asarray(da[d].values, float)
        if c.size > 1:
            dc = np.diff(c)
            step = (c[-1] - c[0]) / (c.size - 1)
            if not np.all(np.isfinite(c)) or step <= 0 or np.max(np.abs(dc - step)) > 0.01 * step:
                raise InputError(f"{p}: {d} coordinates are not regularly spaced (irregular grids are not supported)")
            cells.append(float(step))
        else:
            cells.append(0.0)
    return cells


def _netcdf_crs(gm_attrs: dict, geographic: bool) -> tuple[str, str, bool]:
    """``(crs_wkt, crs_note, geographic)`` from the grid-mapping attrs and the coordinates' geographic guess."""
    crs_wkt, crs_note = "", ""
    wkt = gm_attrs.get("crs_wkt") or gm_attrs.get("spatial_ref")
    if wkt:
        crs_wkt = str(wkt)
    elif gm_attrs.get("grid_mapping_name"):
        try:
            from pyproj import CRS

            crs_wkt = CRS.from_cf(gm_attrs).to_wkt()
        except Exception:  # noqa: BLE001 - incomplete CF grid mapping
            crs_wkt = ""
    if crs_wkt:
        from pyproj import CRS

        try:
            geographic = CRS.from_user_input(crs_wkt).is_geographic
        except Exception:  # noqa: BLE001
            crs_wkt = ""
    if not crs_wkt and geographic:
        crs_note = "no CRS in the file: geographic coordinates taken as WGS84 (EPSG:4326)"
    return crs_wkt, crs_note, geographic


def _registration(vattrs: dict, gattrs: dict) -> tuple[str, str]:
    """``(registration, registration_source)`` from GMT's ``node_offset`` (variable or global attr)."""
    node_offset = vattrs.get("node_offset", gattrs.get("node_offset"))
    if node_offset is not None:
        try:
            reg = "pixel" if int(np.asarray(node_offset).ravel()[0]) == 1 else "gridline"
        except (TypeError, ValueError):
            reg = "gridline"
        reg_src = "node_offset attribute (GMT)"
    else:
        reg, reg_src = "gridline", "COARDS/CF coordinates are the values' positions"
    return reg, reg_src


def _netcdf_latlon_names(p: Path) -> list[str]:
    """Names of the CF latitude/longitude coordinate variables of a netCDF file (units ``degrees_north``/
    ``degrees_east``, ``standard_name`` latitude/longitude, or named lat/lon); ``[]`` when none or unreadable."""
    try:
        ds = xr.open_dataset(p, decode_times=False, decode_cf=False)
    except Exception:  # noqa: BLE001 - not openable by xarray: let GDAL try
        try:
            import h5py

            with h5py.File(p, "r") as h:
                names = [k for k in h.keys() if isinstance(h[k], h5py.Dataset)]
                meta = {k: {a: (v.decode() if isinstance(v, bytes) else str(v)) for a, v in h[k].attrs.items()
                            if a in ("units", "standard_name")} for k in names}
        except Exception:  # noqa: BLE001
            return []
    else:
        with ds:
            meta = {str(k): {a: str(v) for a, v in ds.variables[k].attrs.items() if a in ("units", "standard_name")}
                    for k in ds.variables}
    out = []
    for k, a in meta.items():
        un, sn = str(a.get("units", "")).lower(), str(a.get("standard_name", "")).lower()
        if (un.startswith(("degrees_north", "degree_north", "degrees_east", "degree_east"))
                or sn in ("latitude", "longitude") or k.lower() in ("lat", "lon", "latitude", "longitude")):
            out.append(k)
    return out


def _refuse_stacked(p: Path, ds: xr.Dataset, names: list) -> None:
    """One-line :class:`InputError` when a grid-like variable has two x/y dimensions plus further dimensions
    longer than 1 (``z(time, lat, lon)`` with several times): hadal never picks a slice silently.
    Length-1 extra dimensions are fine (they are squeezed)."""
    for v in names:
        if v not in ds.data_vars:
            continue
        da = ds[v]
        axes = {str(d): _axis_of(str(d), ds[d] if d in ds.variables else None) for d in da.dims}
        if sorted(a for a in axes.values() if a) != ["x", "y"]:
            continue
        extra = [(str(d), n) for d, n in zip(da.dims, da.shape, strict=True) if axes[str(d)] is None and n > 1]
        if extra:
            what = ", ".join(f"{n} {d} values" for d, n in extra)
            d0 = extra[0][0]
            raise InputError(f"{p}: {v} has dims ({', '.join(map(str, da.dims))}) with {what}: hadal reads one 2-D "
                             f"grid and will not pick a slice; pick one with e.g. 'ncks -d {d0},0 IN.nc OUT.nc' "
                             f"or 'cdo seltimestep,1' (or xarray ds.isel({d0}=0).to_netcdf(...))")


def _read_old_gmt(p: Path, ds: xr.Dataset) -> xr.DataArray:
    """GMT's pre-COARDS netCDF grid: 1-D ``z`` (rows from the north) with ``x_range``, ``y_range``,
    ``spacing``, ``dimension`` and ``z`` attribute ``node_offset``."""
    try:
        nx, ny = (int(v) for v in np.asarray(ds["dimension"].values).ravel()[:2])
        x0, x1 = (float(v) for v in np.asarray(ds["x_range"].values).ravel()[:2])
        y0, y1 = (float(v) for v in np.asarray(ds["y_range"].values).ravel()[:2])
        z = np.asarray(ds["z"].values, np.float64)
        off = int(ds["z"].attrs.get("node_offset", 0))
        zattrs = dict(ds["z"].attrs)
    except Exception as exc:  # noqa: BLE001
        raise InputError(f"{p}: malformed GMT netCDF grid ({exc})") from None
    if z.size != nx * ny or nx < 2 or ny < 2:
        raise InputError(f"{p}: GMT grid z has {z.size} values, dimension says {nx} x {ny}")
    dx = (x1 - x0) / (nx - off if off else nx - 1)
    dy = (y1 - y0) / (ny - off if off else ny - 1)
    h = 0.5 if off else 0.0
    x = x0 + (np.arange(nx) + h) * dx
    y = y0 + (np.arange(ny) + h) * dy
    a = z.reshape(ny, nx)[::-1, :]
    a = np.where(np.isfinite(a), a, np.nan)
    xu = str(ds["x_range"].attrs.get("units", "")).lower()
    geographic = xu.startswith("degree") or (-360 <= x0 < x1 <= 360 and -90 <= y0 < y1 <= 90)
    attrs = {"crs_kind": "geographic" if geographic else "local_metric", "crs_wkt": "", "cell_size_x": dx,
             "cell_size_y": dy, "units": str(zattrs.get("units", "")), "source": str(p),
             "format": "GMT netCDF (old 1-D layout)", "reader": reader_of("netcdf"),
             "registration": "pixel" if off else "gridline", "registration_source": "node_offset attribute (GMT)",
             "var_name": "z", "nodata": ""}
    for k in ("positive", "standard_name", "long_name"):
        if k in zattrs:
            attrs[k] = str(zattrs[k])
    return xr.DataArray(np.ascontiguousarray(a), dims=("y", "x"), coords={"x": x, "y": y}, name="z", attrs=attrs)


# ------------------------------------------------------------------ GSF
def read_gsf(path: str | Path, *, include_flagged: bool = False, isolate: bool = True,
             budget: Any = None) -> pd.DataFrame:
    """Soundings of a GSF file as ``longitude_deg, latitude_deg, depth_m, ping`` (one row per beam).

    libgsf is C code that can crash the process on a corrupt file (a fuzzed EX1604 file segfaults inside
    ``gsfRead``), so by default it runs in a child interpreter (``python -m hadal.grid._gsf_child``, a plain
    subprocess, so it also works inside daemonic Dask workers) and a crash becomes a one-line
    :class:`InputError`; ``isolate=False`` reads in this process (:func:`_read_gsf_here`).

    Memory: the reading process holds the soundings against its budget as it decodes them
    (:class:`hadal.grid.sonar.SoundingBudget`; the child inherits this process's limits, ``RLIMIT_AS`` included, and
    is given the limit of ``budget``); this process counts the child's soundings against ``budget`` (a
    ``SoundingBudget``, default a new one) before it reads them, row group by row group (:func:`iter_gsf`), into
    the columns of the returned frame (no second copy of the table).
    """
    from hadal.grid.sonar import SoundingBudget

    if budget is None:
        budget = SoundingBudget(Path(str(path)), "gsf multibeam file")
    if not isolate:
        return _read_gsf_here(path, include_flagged=include_flagged, budget=budget)
    cols: dict[str, np.ndarray] = {}
    k = 0
    attrs: dict = {}
    for chunk in iter_gsf(path, include_flagged=include_flagged, budget=budget):
        if not cols:
            attrs = dict(chunk.attrs)
            n = int(attrs.get("soundings") or 0)
            cols = {c: np.empty(n, chunk[c].dtype) for c in chunk.columns}
        for c, a in cols.items():
            a[k:k + len(chunk)] = chunk[c].to_numpy()
        k += len(chunk)
    df = pd.DataFrame(cols, copy=False)
    df.attrs.update(attrs)
    return df


def iter_gsf(path: str | Path, *, include_flagged: bool = False, budget: Any = None,
             chunk_points: int = 250_000) -> Iterator[pd.DataFrame]:
    """The soundings of a GSF file read by libgsf in a child process (:func:`read_gsf`), as DataFrames of the
    child's Parquet row groups (``chunk_points`` soundings each; ``attrs``: the reader's): this process never
    holds the whole table (it held pyarrow's table and its pandas copy before, 99 B a sounding with its
    consumer's columns). ``budget`` (a :class:`hadal.grid.sonar.SoundingBudget`) counts the child's soundings
    before the first row group is read; the child holds its own as it decodes (same limit)."""
    import json
    import subprocess
    import sys
    import tempfile

    import pyarrow.parquet as pq

    from hadal.grid.sonar import SoundingBudget

    p = _require_file(path, "GSF")
    budget = budget if budget is not None else SoundingBudget(p, "gsf multibeam file")
    try:
        with tempfile.TemporaryDirectory(prefix="hadal-gsf-") as td:
            out = Path(td) / "soundings.parquet"
            proc = subprocess.run([sys.executable, "-m", "hadal.grid._gsf_child", str(p), str(out),
                                   "1" if include_flagged else "0", repr(float(budget.limit)),
                                   str(int(chunk_points))], capture_output=True, text=True)
            if proc.returncode == 0:
                attrs = json.loads(out.with_suffix(".json").read_text(encoding="utf-8"))
                budget.add(int(attrs.get("soundings") or 0))
                with pq.ParquetFile(out) as f:
                    for i in range(f.num_row_groups):
                        chunk = f.read_row_group(i).to_pandas()
                        chunk.attrs.update(attrs)
                        yield chunk
                return
    except OSError as exc:
        raise InputError(f"{p}: cannot run the GSF reader ({exc.strerror or exc})") from None
    last = (proc.stderr.strip().splitlines() or [""])[-1]
    if proc.returncode == 2 and last:
        raise InputError(last)
    if proc.returncode < 0:
        raise InputError(f"{p}: the GSF library (libgsf) crashed reading this file (signal {-proc.returncode}): "
                         "corrupt or truncated GSF")
    raise InputError(f"{p}: the GSF reader failed ({last or f'exit status {proc.returncode}'})")


def gsf_file_version(path: str | Path) -> str:
    """The GSF version of a file (``"03.06"``) from its header record, the first record of every GSF file
    (u32 size, u32 id 1, ``GSF-vNN.NN``); ``""`` when it is not there."""
    import re

    with open(path, "rb") as fh:
        head = fh.read(32)
    m = re.search(rb"GSF-v(\d{1,2}\.\d{1,2})", head)
    return m.group(1).decode() if m else ""


def _libgsf_version() -> str:
    """The libgsf that gsfpy uses (its ``DEFAULT_GSF_VERSION``: ``3.08`` unless set)."""
    try:
        from gsfpy import get_default_gsf_version
    except ImportError:  # pragma: no cover - older gsfpy
        return "?"
    return get_default_gsf_version().replace("_", ".")


def _gsf_ping_position(ping) -> tuple[float, float]:
    """``(latitude, longitude)`` of a gsfpy swath ping: libgsf's ``gsfSwathBathyPing`` holds the latitude in the
    first double after ``ping_time`` and the longitude in the second, whatever names the ctypes binding gives
    them (gsfpy 2.0.0 calls them longitude, latitude)."""
    names = [f[0] for f in type(ping)._fields_]
    i = names.index("ping_time")
    first, second = names[i + 1], names[i + 2]
    return float(getattr(ping, first)), float(getattr(ping, second))


def _read_gsf_here(path: str | Path, *, include_flagged: bool = False, budget: Any = None) -> pd.DataFrame:
    """Soundings of a GSF file as ``longitude_deg, latitude_deg, depth_m, ping`` (one row per beam).

    Uses UKHO's ``gsfpy`` (ctypes bindings of libgsf). Beam positions: the ping's position plus the
    along-/across-track offsets rotated by the ping heading (along = forward, across = starboard),
    converted to degrees on the WGS84 ellipsoid with pyproj ``Geod.fwd``. Beams whose GSF beam flag
    has the *ignore* bit (0x01) set, and null depths, are dropped unless ``include_flagged``.

    Note: gsfpy 2.0.0's ctypes ``c_gsfSwathBathyPing`` (both its libgsf 3.08 and 3.09 bindings) declares
    ``longitude`` before ``latitude``, whereas libgsf's ``gsfSwathBathyPing`` stores latitude first, so the
    Python field named ``longitude`` holds the latitude; :func:`_gsf_ping_position` reads the first double after
    ``ping_time`` as the latitude whatever the binding calls it (checked on the Okeanos Explorer EX1604 file:
    8.71 N 167.48 E, Kwajalein), so a gsfpy that fixes the names keeps working.

    GSF versions: libgsf reads every 3.x file version (its record layouts are decoded by the version in the file's
    header record; newer sensor-specific subrecords are skipped by their size); the EX1604 file (GSF-v03.06) gives
    the same soundings through gsfpy's libgsf 3.08 and 3.09 (``DEFAULT_GSF_VERSION``), also relabelled v03.01 ..
    v03.11 (tests/unit/grid/test_gsf_versions.py). ``attrs`` record the file's ``gsf_version`` and the ``libgsf`` used.

    ``attrs``: ``reader`` ("gsfpy <version>"), ``format``, ``pings``, ``beams_per_ping``, ``soundings``,
    ``dropped`` (flagged or null beams), ``time_start``/``time_end`` (ISO 8601 UTC). A file with no swath
    bathymetry ping, or one libgsf cannot read (truncated, corrupt), is a one-line :class:`InputError`; so is one
    whose soundings pass the memory budget as they decode (``budget``, a :class:`hadal.grid.sonar.SoundingBudget`).
    """
    attrs: dict[str, Any] = {}
    blocks = list(gsf_blocks(path, include_flagged=include_flagged, budget=budget, attrs=attrs))
    df = pd.DataFrame(blocks[0], copy=False)
    df.attrs.update(attrs)
    return df


#: the columns of a GSF read (:func:`read_gsf`) and their dtypes
GSF_COLUMNS = {"longitude_deg": np.float64, "latitude_deg": np.float64, "depth_m": np.float64, "ping": np.int32}


def gsf_blocks(path: str | Path, *, include_flagged: bool = False, budget: Any = None,
               block_points: int | None = None, attrs: dict | None = None) -> Iterator[dict[str, np.ndarray]]:
    """The soundings of a GSF file read with libgsf in this process (:func:`_read_gsf_here` says how), as blocks of
    :data:`GSF_COLUMNS` arrays of at least ``block_points`` soundings (the last one fewer; ``None``: one block of
    them all); ``attrs`` (a dict) receives the read's attributes once the file is read. ``budget`` (a
    :class:`hadal.grid.sonar.SoundingBudget`) counts every sounding decoded, so a reader that writes the blocks
    out (the child process of :func:`read_gsf`) holds one block at a time."""
    from hadal.grid.sonar import SoundingBudget

    p = _require_file(path, "GSF")
    budget = budget if budget is not None else SoundingBudget(p, "gsf multibeam file", reader="gsf")
    try:
        from gsfpy import GsfException, open_gsf
        from gsfpy.enums import RecordType
    except ImportError:
        raise InputError(f"{p}: reading GSF needs the gsfpy package (pip install gsfpy)") from None
    from pyproj import Geod

    geod = Geod(ellps="WGS84")
    lons: list[np.ndarray] = []
    lats: list[np.ndarray] = []
    deps: list[np.ndarray] = []
    pings: list[np.ndarray] = []
    held = total = 0

    def block() -> dict[str, np.ndarray]:
        out = {c: np.concatenate(a) for c, a in zip(GSF_COLUMNS, (lons, lats, deps, pings), strict=True)}
        for a in (lons, lats, deps, pings):
            a.clear()
        return out

    try:
        f = open_gsf(p)
    except GsfException as exc:
        raise InputError(f"{p}: cannot open GSF ({exc.error_message})") from None
    beams_max = dropped = 0
    times: list[float] = []
    with f:
        k = 0
        while True:
            try:
                _, rec = f.read(RecordType.GSF_RECORD_SWATH_BATHYMETRY_PING)
            except GsfException as exc:
                if exc.error_code == -23:  # GSF_READ_TO_END_OF_FILE
                    break
                raise InputError(f"{p}: GSF read error after {k} pings ({exc.error_message})") from None
            ping = rec.mb_ping
            n = int(ping.number_beams)
            if n <= 0 or not ping.depth:
                continue
            beams_max = max(beams_max, n)
            times.append(ping.ping_time.tv_sec + 1e-9 * ping.ping_time.tv_nsec)
            lat0, lon0 = _gsf_ping_position(ping)
            depth = np.ctypeslib.as_array(ping.depth, shape=(n,)).astype(np.float64)
            across = np.ctypeslib.as_array(ping.across_track, shape=(n,)).astype(np.float64) \
                if ping.across_track else np.zeros(n)
            along = np.ctypeslib.as_array(ping.along_track, shape=(n,)).astype(np.float64) \
                if ping.along_track else np.zeros(n)
            keep = np.isfinite(depth) & (depth != 0)
            if ping.beam_flags and not include_flagged:
                flags = np.ctypeslib.as_array(ping.beam_flags, shape=(n,))
                keep &= (flags & 0x01) == 0
            h = math.radians(float(ping.heading))
            east = along * math.sin(h) + across * math.cos(h)
            north = along * math.cos(h) - across * math.sin(h)
            az = np.degrees(np.arctan2(east, north))
            dist = np.hypot(east, north)
            lo, la, _ = geod.fwd(np.full(n, lon0), np.full(n, lat0), az, dist)
            m = int(keep.sum())
            lons.append(lo[keep])
            lats.append(la[keep])
            deps.append(depth[keep])
            pings.append(np.full(m, k, dtype=np.int32))
            budget.add(m)
            held, total = held + m, total + m
            dropped += n - m
            k += 1
            if block_points is not None and held >= block_points:
                yield block()
                held = 0
    if k == 0:
        raise InputError(f"{p}: GSF file contains no bathymetry pings")
    if total == 0:
        raise InputError(f"{p}: no valid soundings in the GSF file")
    import importlib.metadata as md

    from hadal.grid.sonar import _iso

    if attrs is not None:
        attrs.update({"reader": f"gsfpy {md.version('gsfpy')}", "format": "gsf", "pings": k,
                      "gsf_version": gsf_file_version(p), "libgsf": _libgsf_version(),
                      "beams_per_ping": beams_max, "soundings": total, "dropped": dropped,
                      "crs_kind": "geographic", "z_positive": "down",
                      "time_start": _iso(min(times)), "time_end": _iso(max(times))})
    if held or block_points is None:
        yield block()
