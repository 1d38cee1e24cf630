"""Readers for bathymetry inputs; every failure is a one-line :class:`hadal.errors.InputError`.

* :func:`read_soundings` - XYZ/CSV text soundings ``longitude_deg latitude_deg depth_m`` (whitespace or
  comma separated, optional header, ``#`` comments, ``.gz``/``.bz2``/``.xz`` transparently);
* :func:`read_point_cloud` - PLY/PCD (open3d) and LAS/LAZ (laspy; LAZ needs a laspy LAZ backend);
* :func:`read_grid` - GeoTIFF (rasterio) and NetCDF/GMT grids (xarray) as an ``(y, x)`` DataArray with
  ascending coordinates, detecting rasters whose geographic CRS tag is wrong (:func:`looks_metric`);
* :func:`read_gsf` - GSF swath bathymetry via the maintained ``gsfpy`` bindings of libgsf.
"""

from __future__ import annotations

import gzip
import io
import math
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from hadal.errors import InputError

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


def _open_text(p: Path):
    """Text handle; gzip is decompressed fully up front so truncation is reported as such."""
    if p.suffix == ".gz":
        try:
            with gzip.open(p, "rb") as fh:
                data = fh.read()
        except (EOFError, OSError, gzip.BadGzipFile) as exc:
            raise InputError(f"{p}: corrupt or truncated gzip file ({exc})") from None
        return io.StringIO(data.decode("utf-8", errors="replace"))
    return open(p, encoding="utf-8", errors="replace")


def read_soundings(path: str | Path, *, columns=SOUNDING_COLUMNS, check_ranges: bool = True) -> pd.DataFrame:
    """Read a sounding text file into a DataFrame with ``columns`` (default lon, lat, depth positive down).

    Accepts whitespace- or comma-separated values, an optional header line (non-numeric first row)
    and ``#`` comments. Rows with too few fields or non-numeric values, an empty file, longitudes or
    latitudes out of range, or depths that are all negative (elevations?) raise :class:`InputError`.
    NaN values are kept (the gridder drops and counts them).
    """
    p = _require_file(path, "soundings")
    with _open_text(p) as fh:
        text = fh.read()
    first = next((t for ln in io.StringIO(text) if (t := ln.strip()) and not t.startswith("#")), None)
    last = None
    end = len(text)
    while first is not None and end > 0:  # last data line, scanning back from the end
        start = text.rfind("\n", 0, end - 1) + 1
        t = text[start:end].strip()
        if t and not t.startswith("#"):
            last = t
            break
        end = start
    if first is None:
        raise InputError(f"{p}: no soundings (file has no data lines)")
    sep = "," if "," in first else r"\s+"
    toks = lambda line: [t for t in (line.split(",") if sep == "," else line.split()) if t.strip() != ""]  # noqa: E731
    header = 0 if any(_not_number(t) for t in toks(first)) else None
    ncols = len(columns)
    if len(toks(first)) < ncols:
        raise InputError(f"{p}: expected {ncols} columns ({', '.join(columns)}), found {len(toks(first))}")
    if len(toks(last)) < ncols and last is not first:
        raise InputError(f"{p}: last line {last[:60]!r} has fewer than {ncols} values (truncated file?)")
    try:
        df = pd.read_csv(io.StringIO(text), sep=sep, header=header, comment="#", skipinitialspace=True,
                         engine="c")
    except (pd.errors.ParserError, pd.errors.EmptyDataError, ValueError) as exc:
        raise InputError(f"{p}: cannot parse soundings ({str(exc).splitlines()[0]})") from None
    if df.shape[1] < ncols:
        raise InputError(f"{p}: expected {ncols} columns ({', '.join(columns)}), found {df.shape[1]}")
    if len(df) == 0:
        raise InputError(f"{p}: no soundings (header only)")
    df = df.iloc[:, :ncols].copy()
    df.columns = list(columns)
    for c in columns:
        if df[c].dtype.kind not in "fi":
            conv = pd.to_numeric(df[c], errors="coerce")
            bad = conv.isna() & df[c].notna()
            if bad.any():
                i = int(np.flatnonzero(bad.to_numpy())[0])
                raise InputError(f"{p}: non-numeric {c} {df[c].iloc[i]!r} on data row {i + 1}")
            df[c] = conv
    df = df.astype(np.float64)
    if check_ranges and columns == SOUNDING_COLUMNS:
        lon, lat, dep = (df[c].to_numpy() for c in columns)
        with np.errstate(invalid="ignore"):
            if np.any(np.abs(lat) > 90):
                raise InputError(f"{p}: latitude out of [-90, 90] (max |lat| {np.nanmax(np.abs(lat)):g}); "
                                 "columns must be longitude latitude depth")
            if np.any((lon < -180) | (lon > 360)):
                raise InputError(f"{p}: longitude out of [-180, 360] ({np.nanmin(lon):g}..{np.nanmax(lon):g})")
            if np.nanmedian(dep) < 0 if np.isfinite(dep).any() else False:
                raise InputError(f"{p}: depths are negative (median {np.nanmedian(dep):g} m); depth_m must be "
                                 "positive down - convert elevations first")
    return df


def _not_number(tok: str) -> bool:
    try:
        float(tok)
    except ValueError:
        return True
    return False


def read_point_cloud(path: str | Path) -> np.ndarray:
    """Read a point cloud as an ``(N, 3)`` float64 array of x, y, z (PLY/PCD via open3d, LAS/LAZ via laspy)."""
    p = _require_file(path, "point cloud")
    suf = p.suffix.lower()
    if suf in (".ply", ".pcd", ".xyz", ".pts"):
        import open3d as o3d

        with _quiet_open3d(o3d):
            pc = o3d.io.read_point_cloud(str(p), format="auto")
        pts = np.asarray(pc.points, dtype=np.float64)
        if len(pts) == 0:
            raise InputError(f"{p}: no points read (truncated or not a {suf[1:].upper()} point cloud)")
        if suf == ".ply":
            _check_ply_count(p, len(pts))
        return pts
    if suf in (".las", ".laz"):
        import laspy

        try:
            las = laspy.read(str(p))
        except laspy.errors.LaspyException as exc:
            msg = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            if suf == ".laz" and "backend" in msg.lower():
                msg += " (install a LAZ backend: pip install lazrs)"
            raise InputError(f"{p}: cannot read {suf[1:].upper()} ({msg})") from None
        except (OSError, ValueError) as exc:
            raise InputError(f"{p}: cannot read {suf[1:].upper()} ({exc})") from None
        pts = np.column_stack([np.asarray(las.x, np.float64), np.asarray(las.y, np.float64),
                               np.asarray(las.z, np.float64)])
        if len(pts) == 0:
            raise InputError(f"{p}: LAS file has no points")
        return pts
    raise InputError(f"{p}: unsupported point cloud format {suf!r} (use .ply, .pcd, .las or .laz)")


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


def read_grid(path: str | Path, *, crs_kind: str | None = None, variable: str | None = None) -> xr.DataArray:
    """Read a gridded surface (GeoTIFF via rasterio, NetCDF/GRD via xarray) as a 2-D DataArray ``z(y, x)``.

    Coordinates are cell centres, ascending; nodata becomes NaN. ``attrs["crs_kind"]`` is
    ``"geographic"`` (x/y degrees), ``"projected"`` or ``"local_metric"`` (x/y metres, no usable CRS),
    ``attrs["crs_wkt"]`` the source CRS if any, ``attrs["units"]`` the value units when known.
    ``crs_kind`` overrides the detection. A raster tagged geographic whose extent/relief make no sense
    in degrees (:func:`looks_metric`) is returned as ``local_metric`` with a :class:`GridCRSWarning`.
    """
    p = _require_file(path, "grid")
    if crs_kind not in (None, "geographic", "projected", "local_metric"):
        raise InputError(f"crs_kind must be geographic, projected or local_metric, got {crs_kind!r}")
    suf = p.suffix.lower()
    if suf in (".tif", ".tiff", ".gtiff"):
        da = _read_geotiff(p)
    elif suf in (".nc", ".grd", ".nc4", ".cdf"):
        da = _read_netcdf_grid(p, variable)
    else:
        raise InputError(f"{p}: unsupported grid format {suf!r} (use GeoTIFF or NetCDF)")
    if not np.isfinite(da.values).any():
        raise InputError(f"{p}: grid has no valid (non-nodata) cells")
    detected = da.attrs["crs_kind"]
    if crs_kind is not None:
        da.attrs["crs_kind"] = crs_kind
    elif detected == "geographic":
        xe = float(da.x[-1] - da.x[0]) + abs(float(da.attrs.get("cell_size_x", 0)))
        ye = float(da.y[-1] - da.y[0]) + abs(float(da.attrs.get("cell_size_y", 0)))
        relief = float(np.nanmax(da.values) - np.nanmin(da.values))
        if looks_metric(xe, ye, relief):
            warnings.warn(
                f"{p.name}: CRS says geographic but a {xe:g} x {ye:g} extent with {relief:.3g} m of relief only "
                "makes sense in metres; treating it as a local metric grid",
                GridCRSWarning, stacklevel=2,
            )
            da.attrs["crs_kind"] = "local_metric"
            da.attrs["crs_override"] = "geographic tag ignored: local metric frame"
    if da.attrs["crs_kind"] != "geographic":
        da["x"].attrs.update({"units": "m"})
        da["y"].attrs.update({"units": "m"})
    else:
        da["x"].attrs.update({"units": "degrees_east", "standard_name": "longitude"})
        da["y"].attrs.update({"units": "degrees_north", "standard_name": "latitude"})
    return da


def _read_geotiff(p: Path) -> xr.DataArray:
    import rasterio
    from rasterio.errors import RasterioError

    try:
        with rasterio.open(p) as src:
            if src.count < 1:
                raise InputError(f"{p}: raster has no bands")
            a = src.read(1).astype(np.float64)
            nodata = src.nodata
            t = src.transform
            crs = src.crs
            units = (src.units[0] if src.units and src.units[0] else None)
    except RasterioError as exc:
        raise InputError(f"{p}: cannot read GeoTIFF ({str(exc).splitlines()[0]})") from None
    if t.b != 0 or t.d != 0:
        raise InputError(f"{p}: rotated rasters are not supported")
    if nodata is not None:
        a[a == nodata] = np.nan
    a[~np.isfinite(a)] = np.nan
    ny, nx = a.shape
    x = t.c + (np.arange(nx) + 0.5) * t.a
    y = t.f + (np.arange(ny) + 0.5) * t.e
    if t.a < 0:
        x, a = x[::-1], a[:, ::-1]
    if t.e < 0:
        y, a = y[::-1], a[::-1, :]
    kind = "local_metric" if crs is None else ("geographic" if crs.is_geographic else "projected")
    return xr.DataArray(
        np.ascontiguousarray(a), dims=("y", "x"), coords={"x": x, "y": y}, name="z",
        attrs={"crs_kind": kind, "crs_wkt": crs.to_wkt() if crs else "", "nodata": nodata if nodata is not None else "",
               "cell_size_x": abs(t.a), "cell_size_y": abs(t.e), "units": units or "", "source": str(p)},
    )


_LON_NAMES = ("lon", "longitude", "x")
_LAT_NAMES = ("lat", "latitude", "y")


def _read_netcdf_grid(p: Path, variable: str | None) -> xr.DataArray:
    try:
        ds = xr.open_dataset(p)
    except (OSError, ValueError) as exc:
        raise InputError(f"{p}: cannot read NetCDF ({str(exc).splitlines()[0]})") from None
    with ds:
        if variable is not None:
            if variable not in ds:
                raise InputError(f"{p}: no variable {variable!r} (have {', '.join(map(str, ds.data_vars))})")
            da = ds[variable]
        else:
            cands = [v for v in ds.data_vars if ds[v].ndim == 2]
            if not cands:
                raise InputError(f"{p}: no 2-D variable to read as a grid")
            da = ds[cands[0]]
        da = da.load()
    ydim, xdim = da.dims
    da = da.rename({ydim: "y", xdim: "x"}).astype(np.float64)
    for d in ("x", "y"):
        if d not in da.coords:
            raise InputError(f"{p}: grid dimension {d} has no coordinate values")
    xu = str(da["x"].attrs.get("units", "")).lower()
    yu = str(da["y"].attrs.get("units", "")).lower()
    geographic = xu.startswith("degree") or yu.startswith("degree") or (
        str(xdim).lower() in ("lon", "longitude") and str(ydim).lower() in ("lat", "latitude"))
    fill = da.attrs.get("_FillValue")
    if fill is not None:
        da = da.where(da != fill)
    da = da.where(np.isfinite(da))  # inf cells are nodata, as in GeoTIFFs
    if da.sizes["x"] > 1 and float(da.x[1] - da.x[0]) < 0:
        da = da.isel(x=slice(None, None, -1))
    if da.sizes["y"] > 1 and float(da.y[1] - da.y[0]) < 0:
        da = da.isel(y=slice(None, None, -1))
    dx = float(abs(da.x[1] - da.x[0])) if da.sizes["x"] > 1 else 0.0
    dy = float(abs(da.y[1] - da.y[0])) if da.sizes["y"] > 1 else 0.0
    units = str(da.attrs.get("units", ""))
    da = da.reset_coords(drop=True)
    da.attrs = {"crs_kind": "geographic" if geographic else "projected", "crs_wkt": "", "cell_size_x": dx,
                "cell_size_y": dy, "units": units, "source": str(p)}
    da.name = "z"
    return da


# ------------------------------------------------------------------ GSF
def read_gsf(path: str | Path, *, include_flagged: bool = False) -> pd.DataFrame:
    """Soundings of a GSF file as ``longitude_deg, latitude_deg, depth_m, ping`` (one row per beam).

    Uses UKHO's ``gsfpy`` (ctypes bindings of libgsf). Beam positions: the ping's position plus the
    along-/across-track offsets rotated by the ping heading (along = forward, across = starboard),
    converted to degrees on the WGS84 ellipsoid with pyproj ``Geod.fwd``. Beams whose GSF beam flag
    has the *ignore* bit (0x01) set, and null depths, are dropped unless ``include_flagged``.

    Note: gsfpy 2.0.0's ctypes ``c_gsfSwathBathyPing`` declares ``longitude`` before ``latitude``,
    whereas libgsf's ``gsfSwathBathyPing`` stores latitude first, so the Python field named
    ``longitude`` holds the latitude; we read them swapped (checked on the Okeanos Explorer EX1604
    file: 8.71 N 167.48 E, Kwajalein).
    """
    p = _require_file(path, "GSF")
    try:
        from gsfpy import GsfException, open_gsf
        from gsfpy.enums import RecordType
    except ImportError:
        raise InputError(f"{p}: reading GSF needs the gsfpy package (pip install gsfpy)") from None
    from pyproj import Geod

    geod = Geod(ellps="WGS84")
    lons, lats, deps, pings = [], [], [], []
    try:
        f = open_gsf(p)
    except GsfException as exc:
        raise InputError(f"{p}: cannot open GSF ({exc.error_message})") from None
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
            lat0, lon0 = float(ping.longitude), float(ping.latitude)  # swapped, see docstring
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
            lons.append(lo[keep])
            lats.append(la[keep])
            deps.append(depth[keep])
            pings.append(np.full(int(keep.sum()), k, dtype=np.int32))
            k += 1
    if not deps or sum(len(d) for d in deps) == 0:
        raise InputError(f"{p}: no valid soundings in the GSF file")
    return pd.DataFrame({"longitude_deg": np.concatenate(lons), "latitude_deg": np.concatenate(lats),
                         "depth_m": np.concatenate(deps), "ping": np.concatenate(pings)})
