"""LAS/LAZ and PCD point clouds read by their metadata: CRS, linear units and the direction of z.

* LAS/LAZ [ASPRS LAS 1.0-1.4 R15] through laspy: the scaled ``x, y, z`` (``X * scale + offset``); the CRS from the
  file's own VLRs (laspy's ``header.parse_crs()``: the OGC WKT VLR of LAS 1.4, else the GeoTIFF GeoKey VLRs),
  its horizontal linear unit from the CRS axes (``axis_info[i].unit_conversion_factor``: foot 0.3048, US survey
  foot 1200/3937), the vertical unit from the vertical CRS of a compound CRS, else the GeoTIFF
  ``VerticalUnitsGeoKey`` (4099), else the horizontal unit (the convention of lidar producers: a state-plane-feet
  cloud has its heights in feet; recorded as such). ``z`` is elevation, positive up: the LAS spec's Z is a height
  ("elevation") in the vertical datum of the file, never a depth.
* PCD [PCL "The PCD (Point Cloud Data) file format", v0.5-0.7] through pypcd4: ``ascii``, ``binary`` and
  ``binary_compressed`` (LZF) data, any SIZE/TYPE, extra fields; the coordinate fields are found by name without
  regard to case (PDAL's writers.pcd writes ``X Y Z``). PCD carries no CRS or units: metres (PCL's convention),
  z the third axis of the cloud's frame, taken as elevation (positive up).

Every coordinate is returned in metres: a cloud in feet is scaled, and the CRS its x/y are then in is the file's
CRS with metre axes (:func:`metric_crs`, same projection and datum), so the grid's x/y stay georeferenced.
A ``crs`` / ``z_positive`` given in dive.yaml wins over the file. Failures are one-line :class:`InputError`.
"""

from __future__ import annotations

import io
import re
from pathlib import Path
from typing import Any

import numpy as np

from hadal.errors import InputError
from hadal.grid.sonar import _hint

#: GeoTIFF ProjLinearUnitsGeoKey / VerticalUnitsGeoKey codes (EPSG units) -> metres per unit
_EPSG_LINEAR_UNITS = {9001: 1.0, 9002: 0.3048, 9003: 1200.0 / 3937.0, 9036: 1000.0, 9030: 1852.0,
                      9096: 0.9144, 9014: 1.8288}
_GEOKEY_VERTICAL_UNITS = 4099
_GEOKEY_PROJ_LINEAR_UNITS = 3076


def _first_line(exc: BaseException) -> str:
    s = str(exc)
    return s.splitlines()[0] if s else type(exc).__name__



def metric_crs(crs):
    """The projected ``crs`` with its x/y axes in metres (same projection, datum and parameters; the parameters
    carry their own units in PROJ JSON, so only the coordinates' unit changes). ``crs`` in metres is returned."""
    from pyproj import CRS

    d = crs.to_json_dict()
    # a BoundCRS (a WKT1 PROJCS with TOWGS84, as LAS writers emit) keeps its datum shift: its source CRS changes
    proj = d["source_crs"] if d.get("type") == "BoundCRS" else d
    cs = proj.get("coordinate_system", {})
    for ax in cs.get("axis", []):
        ax["unit"] = "metre"
    proj.pop("id", None)  # no longer the registry's CRS
    proj["name"] = f"{proj.get('name', 'CRS')} (axes in metres)"
    return CRS.from_json_dict(d)


def _unit(axis) -> tuple[float, str]:
    f = float(getattr(axis, "unit_conversion_factor", 1.0) or 1.0)
    return f, str(getattr(axis, "unit_name", "") or "metre")


def _geokeys(header) -> dict[int, int]:
    """The GeoTIFF keys of a LAS header's GeoKeyDirectory VLR that hold their value inline (``{key id: value}``)."""
    for v in header.vlrs:
        keys = getattr(v, "geo_keys", None)
        if keys:
            return {int(k.id): int(k.value_offset) for k in keys if int(getattr(k, "tiff_tag_location", 0)) == 0}
    return {}


def _crs_from_hint(p: Path, crs: str):
    from pyproj import CRS

    if str(crs).strip().lower() in ("local", "local_metric"):
        return None
    try:
        return CRS.from_user_input(str(crs))
    except Exception as exc:  # noqa: BLE001 - pyproj's CRSError and others
        raise InputError(f"{p}: crs {crs!r} is not a CRS pyproj understands ({_first_line(exc)})") from None


def describe_crs(crs, geokeys: dict[int, int] | None = None) -> dict[str, Any]:
    """``{crs_kind, crs_name, crs_epsg, horizontal_units, xy_to_m, vertical_units, z_to_m, z_units_from}`` of a
    point cloud's CRS (None: no CRS, metres assumed). ``geokeys``: the LAS GeoTIFF keys (VerticalUnitsGeoKey)."""
    geokeys = geokeys or {}
    out: dict[str, Any] = {"crs_kind": "none", "crs_name": "", "crs_epsg": 0, "horizontal_units": "metre (assumed)",
                           "xy_to_m": 1.0, "vertical_units": "metre (assumed)", "z_to_m": 1.0,
                           "z_units_from": "no CRS in the file: metres assumed"}
    if crs is None:
        if _GEOKEY_VERTICAL_UNITS in geokeys and geokeys[_GEOKEY_VERTICAL_UNITS] in _EPSG_LINEAR_UNITS:
            out["z_to_m"] = _EPSG_LINEAR_UNITS[geokeys[_GEOKEY_VERTICAL_UNITS]]
            out["vertical_units"] = f"EPSG unit {geokeys[_GEOKEY_VERTICAL_UNITS]}"
            out["z_units_from"] = "GeoTIFF VerticalUnitsGeoKey"
        return out
    horiz, vert = crs, None
    if crs.is_compound:
        subs = crs.sub_crs_list
        horiz = subs[0]
        vert = next((s for s in subs[1:] if s.is_vertical), None)
    out["crs_name"] = str(crs.name)
    out["crs_epsg"] = int(crs.to_epsg() or 0)
    if horiz.is_geographic:
        out["crs_kind"] = "geographic"
        out["horizontal_units"] = "degree"
        out["xy_to_m"] = float("nan")
        h_factor, h_name = 1.0, "metre"
    elif horiz.is_projected:
        out["crs_kind"] = "projected"
        h_factor, h_name = _unit(horiz.axis_info[0])
        out["horizontal_units"], out["xy_to_m"] = h_name, h_factor
    else:
        raise InputError(f"CRS {crs.name!r} is neither projected nor geographic (geocentric clouds are not supported)")
    if vert is not None and vert.axis_info:
        f, name = _unit(vert.axis_info[0])
        out.update(vertical_units=name, z_to_m=f, z_units_from=f"vertical CRS {vert.name!r}")
    elif _GEOKEY_VERTICAL_UNITS in geokeys and geokeys[_GEOKEY_VERTICAL_UNITS] in _EPSG_LINEAR_UNITS:
        code = geokeys[_GEOKEY_VERTICAL_UNITS]
        out.update(vertical_units=f"EPSG unit {code}", z_to_m=_EPSG_LINEAR_UNITS[code],
                   z_units_from="GeoTIFF VerticalUnitsGeoKey")
    else:
        out.update(vertical_units=h_name, z_to_m=h_factor,
                   z_units_from="no vertical CRS or units in the file: the horizontal CRS's unit")
    return out


#: points laspy decodes per chunk of a LAS/LAZ file
LAS_CHUNK_POINTS = 1_000_000


def _las_errors(p: Path, laspy, exc: BaseException) -> InputError:
    """A laspy failure as a one-line error naming the file."""
    if isinstance(exc, MemoryError):
        return InputError(f"{p}: cannot read LAS/LAZ (its point count does not fit in memory)")
    msg = _first_line(exc)
    if isinstance(exc, laspy.errors.LaspyException) and ("backend" in msg.lower() or "laz" in msg.lower()):
        msg += " (LAZ needs a backend: pip install lazrs)"
    return InputError(f"{p}: cannot read LAS/LAZ ({msg})")


def _las_points(p: Path, limit_bytes: float | None = None) -> tuple[Any, np.ndarray]:
    """The header and scaled x, y, z (``(N, 3)`` float64) of a LAS/LAZ file, decoded by laspy in chunks of
    :data:`LAS_CHUNK_POINTS` straight into the points array. Memory (:class:`hadal.budget.DecodeBudget`, limit
    ``limit_bytes``): the header's count (laspy decodes no more) with the points' working copies
    (:data:`hadal.grid.readers.CLOUD_WORKING_COPIES`) before anything is allocated, then the points decoded so far
    and the chunk's records as each chunk decodes (a LAZ has no size to check its count against)."""
    import laspy

    from hadal.budget import DecodeBudget
    from hadal.grid.readers import CLOUD_WORKING_COPIES, POINT_BYTES, _check_las_count

    budget = DecodeBudget(p, "LAS/LAZ point cloud", copies=CLOUD_WORKING_COPIES, limit_bytes=limit_bytes)
    try:
        with laspy.open(str(p)) as f:
            h = f.header
            n = _check_las_count(p, h, budget)
            chunk_bytes = min(n, LAS_CHUNK_POINTS) * (int(h.point_format.size) + 2 * POINT_BYTES)
            pts = np.empty((n, 3), np.float64)
            k = 0
            for chunk in f.chunk_iterator(LAS_CHUNK_POINTS):
                m = min(len(chunk), n - k)
                budget.hold((k + m) * POINT_BYTES, f"{k + m:,} points decoded", held=chunk_bytes)
                pts[k:k + m, 0], pts[k:k + m, 1], pts[k:k + m, 2] = chunk.x[:m], chunk.y[:m], chunk.z[:m]
                k += m
    except InputError:
        raise
    except (MemoryError, laspy.errors.LaspyException, OSError, ValueError, EOFError) as exc:
        raise _las_errors(p, laspy, exc) from None
    if k < n:
        raise InputError(f"{p}: LAS header declares {n:,} points but {k:,} were read (truncated?)")
    return h, pts


def read_las(path: str | Path, hints=None, *, memory_limit_bytes: float | None = None
             ) -> tuple[np.ndarray, dict[str, Any]]:
    """A LAS/LAZ cloud as ``(N, 3)`` float64 x, y, z **in metres** and its metadata (module docstring).

    Metadata: :func:`describe_crs`'s keys plus ``crs_from`` (``file``/``dive.yaml``/``none``), ``crs_wkt`` (the
    file's CRS), ``xy_crs_wkt`` (the CRS of the returned x/y: the file's with metre axes), ``z_positive`` and
    ``z_positive_from``, ``las_version``, ``point_format``, ``scales``/``offsets``. Read against the memory budget
    ``memory_limit_bytes`` as it decodes (:func:`_las_points`).
    """
    p = Path(path)
    h, pts = _las_points(p, memory_limit_bytes)
    if len(pts) == 0:
        raise InputError(f"{p}: LAS file has no points")
    geokeys = _geokeys(h)
    hint = _hint(hints, "crs")
    crs, crs_from, note = None, "none", ""
    if hint is not None:
        crs, crs_from = _crs_from_hint(p, hint), "dive.yaml"
    else:
        try:
            crs = h.parse_crs()
        except Exception as exc:  # noqa: BLE001 - laspy/pyproj raise many kinds on a broken VLR
            note = f"the file's CRS VLR could not be parsed ({_first_line(exc)}): no CRS used"
        crs_from = "file" if crs is not None else "none"
    try:
        meta = describe_crs(crs, geokeys)
    except InputError as exc:
        raise InputError(f"{p}: {exc}") from None
    if crs is None and _GEOKEY_PROJ_LINEAR_UNITS in geokeys and geokeys[_GEOKEY_PROJ_LINEAR_UNITS] != 9001:
        code = geokeys[_GEOKEY_PROJ_LINEAR_UNITS]
        if code in _EPSG_LINEAR_UNITS:  # a user-defined projection in feet: the unit key still says so
            meta.update(horizontal_units=f"EPSG unit {code}", xy_to_m=_EPSG_LINEAR_UNITS[code])
    meta.update(_scale_to_metres(pts, meta))
    meta.update({
        "format": "las", "crs_from": crs_from, "crs_note": note,
        "crs_wkt": crs.to_wkt() if crs is not None else "",
        "xy_crs_wkt": _xy_crs_wkt(crs, meta),
        "las_version": f"{h.version.major}.{h.version.minor}", "point_format": int(h.point_format.id),
        "scales": [float(s) for s in h.scales], "offsets": [float(o) for o in h.offsets],
    })
    zpos = _hint(hints, "z_positive")
    meta["z_positive"] = zpos or "up"
    meta["z_positive_from"] = ("z_positive given in dive.yaml" if zpos else
                               "ASPRS LAS specification: Z is elevation (positive up)")
    return pts, meta


def _scale_to_metres(pts: np.ndarray, meta: dict[str, Any]) -> dict[str, Any]:
    """Scale x/y (projected) and z to metres in place; the factors applied."""
    fxy = meta["xy_to_m"] if meta["crs_kind"] != "geographic" else 1.0
    fz = meta["z_to_m"]
    if fxy != 1.0:
        pts[:, :2] *= fxy
    if fz != 1.0:
        pts[:, 2] *= fz
    return {"xy_scaled_by": float(fxy), "z_scaled_by": float(fz)}


def _xy_crs_wkt(crs, meta: dict[str, Any]) -> str:
    """WKT of the CRS the returned x/y are in (projected clouds only)."""
    if crs is None or meta["crs_kind"] != "projected":
        return ""
    horiz = crs.sub_crs_list[0] if crs.is_compound else crs
    return (metric_crs(horiz) if meta["xy_to_m"] != 1.0 else horiz).to_wkt()


# ------------------------------------------------------------------ PCD
_PCD_TYPES = {("F", 4), ("F", 8), ("I", 1), ("I", 2), ("I", 4), ("I", 8), ("U", 1), ("U", 2), ("U", 4), ("U", 8)}


def _pcd_field(fields: tuple[str, ...], name: str) -> str | None:
    """The field called ``name`` (exact first, then without regard to case)."""
    if name in fields:
        return name
    return next((f for f in fields if f.lower() == name), None)


def _pcd_error(exc: BaseException) -> str:
    """pypcd4's error in one line: a header pydantic refuses is named by its missing/invalid entries."""
    errors = getattr(exc, "errors", None)
    if callable(errors):
        try:
            bad = sorted({str(e["loc"][0]).upper() for e in errors() if e.get("loc")})
        except Exception:  # noqa: BLE001 - not a pydantic error after all
            bad = []
        if bad:
            return f"header entries missing or invalid: {', '.join(bad)}"
    return _first_line(exc)


def _check_pcd_size(p: Path, limit_bytes: float | None = None) -> None:
    """Refuse a PCD whose header declares more points than its binary data holds (truncated) or whose read needs
    more than the memory budget (:class:`hadal.budget.DecodeBudget`, limit ``limit_bytes``), before the data is
    read: pypcd4 allocates what the header declares (``binary``: points x record; ``binary_compressed``: the
    LZF block's declared size, then a points x record table), and an ``ascii`` body as many records as it has
    lines (at most one per two bytes a value); with the points as float64 and their working copies
    (:data:`hadal.grid.readers.CLOUD_WORKING_COPIES`)."""
    import struct

    from hadal.budget import DecodeBudget
    from hadal.grid.readers import CLOUD_WORKING_COPIES, POINT_BYTES

    with open(p, "rb") as fh:
        head = fh.read(1 << 16)
    fields: dict[str, list[str]] = {}
    end = -1
    for m in re.finditer(rb"[^\n]*\n", head):
        tok = m.group().decode("ascii", errors="replace").split()
        if tok and not tok[0].startswith("#"):
            fields[tok[0].upper()] = tok[1:]
        if tok and tok[0].upper() == "DATA":
            end = m.end()
            break
    try:
        n = int(fields["POINTS"][0])
        counts = fields.get("COUNT", ["1"] * len(fields["SIZE"]))
        record = sum(int(s) * int(c) for s, c in zip(fields["SIZE"], counts, strict=False))
        n_values = sum(int(c) for c in counts)
    except (KeyError, IndexError, ValueError):
        return  # not a header this check understands: pypcd4 says what is wrong
    data = fields.get("DATA", [""])[0].lower()
    size = p.stat().st_size
    rows, block = n, 0
    if data == "ascii":
        rows = max(n, (size - max(end, 0)) // max(2 * n_values, 1))
    elif data == "binary_compressed" and end > 0 and len(head) >= end + 8:
        block = struct.unpack_from("<II", head, end)[1]  # compressed size, uncompressed size
    budget = DecodeBudget(p, "PCD point cloud", limit_bytes=limit_bytes)
    budget.hold(rows * (record + POINT_BYTES * CLOUD_WORKING_COPIES) + block,
                f"its header declares {n:,} points, {data or 'unknown'} data")
    if end > 0 and data == "binary" and end + n * record > size:
        have = max(size - end, 0) // max(record, 1)
        raise InputError(f"{p}: PCD header declares {n:,} points but the file holds at most {have:,} (truncated?)")


def read_pcd(path: str | Path, hints=None, *, memory_limit_bytes: float | None = None
             ) -> tuple[np.ndarray, dict[str, Any]]:
    """A PCD cloud (ascii, binary or binary_compressed; any field sizes/types; ``x y z`` in any case) as
    ``(N, 3)`` float64 x, y, z and its metadata (``format``, ``pcd_version``, ``pcd_data``, ``fields``,
    ``viewpoint``, ``crs_*``/units as :func:`describe_crs` (none: metres), ``z_positive``/``z_positive_from``).
    NaN points (PCL's "no return") are kept (the gridder drops and counts them). Held against the memory budget
    ``memory_limit_bytes`` before pypcd4 allocates (:func:`_check_pcd_size`)."""
    p = Path(path)
    try:
        from pypcd4 import PointCloud
    except ImportError:  # pragma: no cover - a declared dependency
        raise InputError(f"{p}: reading PCD needs pypcd4 (pip install pypcd4)") from None
    _check_pcd_size(p, memory_limit_bytes)
    try:
        pc, version = _pcd_open(p, PointCloud)
    except InputError:
        raise
    except MemoryError:
        raise InputError(f"{p}: cannot read PCD (its point count does not fit in memory)") from None
    except Exception as exc:  # noqa: BLE001 - pypcd4 raises ValueError, KeyError, struct and LZF errors
        raise InputError(f"{p}: no points read (not a readable PCD point cloud: {_pcd_error(exc)})") from None
    md = pc.metadata
    fields = tuple(md.fields)
    names = [_pcd_field(fields, n) for n in ("x", "y", "z")]
    if None in names:
        raise InputError(f"{p}: PCD has no x/y/z fields (FIELDS {' '.join(fields)})")
    for n in names:
        i = fields.index(n)
        if md.count[i] != 1:
            raise InputError(f"{p}: PCD field {n} has COUNT {md.count[i]} (one value per point expected)")
    pts = np.ascontiguousarray(pc.numpy(tuple(str(n) for n in names)), dtype=np.float64)
    if pts.ndim != 2 or len(pts) == 0:
        raise InputError(f"{p}: PCD has no points")
    if len(pts) != int(md.points):
        raise InputError(f"{p}: PCD header declares {md.points} points but {len(pts)} were read (truncated?)")
    meta = describe_crs(None)
    crs_hint = _hint(hints, "crs")
    crs = _crs_from_hint(p, crs_hint) if crs_hint is not None else None
    if crs is not None:
        meta = describe_crs(crs)
        meta.update(_scale_to_metres(pts, meta))
    meta.update({
        "format": "pcd", "crs_from": "dive.yaml" if crs is not None else "none (PCD has no CRS)",
        "crs_wkt": crs.to_wkt() if crs is not None else "", "xy_crs_wkt": _xy_crs_wkt(crs, meta) if crs else "",
        "pcd_version": version or str(md.version), "pcd_data": str(getattr(md.data, "value", md.data)),
        "fields": " ".join(fields), "viewpoint": " ".join(f"{v:g}" for v in md.viewpoint),
    })
    zpos = _hint(hints, "z_positive")
    meta["z_positive"] = zpos or "up"
    meta["z_positive_from"] = ("z_positive given in dive.yaml" if zpos else
                               "PCD: z is the third axis of the cloud's frame, elevation (positive up)")
    return pts, meta


#: PCD header versions older than pypcd4's ``.7`` with the same layout (PCL's ``pcd_io``: v0.6 has no VIEWPOINT
#: line, whose default is the identity; v0.5 has no VIEWPOINT and no WIDTH/HEIGHT split beyond POINTS)
_PCD_OLD_VERSIONS = (b".6", b"0.6", b".5", b"0.5")


def _pcd_open(p: Path, PointCloud) -> tuple[Any, str | None]:
    """pypcd4's reader and the file's own VERSION when it was not ``.7``; a v0.5/v0.6 header (which pypcd4 refuses
    by its VERSION only) is read with the VERSION line set to ``.7`` and the PCL default VIEWPOINT. An ascii data
    block whose values are separated by tabs or commas (PDAL's readers.pcd accepts both; its test data has
    ``utm17_tab.pcd``/``utm17_comma.pcd``) is read with those separators as spaces, pypcd4's only separator."""
    with open(p, "rb") as fh:
        head = fh.read(4096)
    m = re.search(rb"^VERSION\s+(\S+)[ \t]*\r?$", head, re.M)
    old = m is not None and m.group(1) in _PCD_OLD_VERSIONS
    d = re.search(rb"^DATA[ \t]+ascii[ \t]*\r?\n", head, re.M)
    first = head[d.end():].split(b"\n", 1)[0] if d is not None else b""  # the separator of the first scan
    odd_sep = re.search(rb"[\t,]", first) is not None
    if not (old or odd_sep):
        return PointCloud.from_path(p), None
    raw = p.read_bytes()
    fixed = raw
    if odd_sep and d is not None:
        fixed = raw[:d.end()] + re.sub(rb"[ \t]*[\t,][ \t]*", b" ", raw[d.end():])
    if old and m is not None:
        fixed = fixed[:m.start()] + b"VERSION .7" + fixed[m.end():]
        if not re.search(rb"^VIEWPOINT", fixed[:4096], re.M):
            dd = re.search(rb"^DATA\s", fixed[:4096], re.M)
            if dd is not None:
                fixed = fixed[:dd.start()] + b"VIEWPOINT 0 0 0 1 0 0 0\n" + fixed[dd.start():]
    return PointCloud.from_fileobj(io.BytesIO(fixed)), (m.group(1).decode() if old and m is not None else None)


# ------------------------------------------------------------------ into the laser grid
def cloud_to_frame(path: Path, pts: np.ndarray, frame) -> np.ndarray:
    """A lon/lat cloud's x/y projected into the dive's transverse-Mercator map frame (metres); z kept."""
    lon, lat = pts[:, 0], pts[:, 1]
    with np.errstate(invalid="ignore"):
        if np.nanmax(np.abs(lat)) > 90 or np.nanmin(lon) < -180 or np.nanmax(lon) > 360:
            raise InputError(f"{path}: the cloud's CRS is geographic but its x/y are not longitudes/latitudes "
                             f"(x {np.nanmin(lon):g}..{np.nanmax(lon):g}, y {np.nanmin(lat):g}..{np.nanmax(lat):g})")
    x, y = frame.to_xy(lon, lat)
    return np.column_stack([x, y, pts[:, 2]])


#: the metadata of :func:`read_las`/:func:`read_pcd` recorded in a laser grid's attributes (``source_`` prefix)
_RECORDED = ("crs_kind", "crs_name", "crs_epsg", "crs_from", "horizontal_units", "vertical_units", "z_units_from",
             "xy_scaled_by", "z_scaled_by", "las_version", "point_format", "pcd_version", "pcd_data", "fields",
             "viewpoint")


def cloud_metadata(ds, meta: dict[str, Any]) -> None:
    """Record a cloud's metadata (CRS, units, scaling to metres) in its laser grid ``ds`` (in place): attributes
    ``source_<key>``, the file's CRS as ``source_crs_file_wkt`` and, for a projected cloud, the CRS of the grid's
    x/y (the file's, with metre axes when the file is in feet) as ``source_crs_wkt``."""
    for k in _RECORDED:
        if k in meta and meta[k] not in (None, ""):
            v = meta[k]
            ds.attrs[f"source_{k}"] = v if isinstance(v, (int, float, str)) else str(v)
    if meta.get("crs_wkt"):
        ds.attrs["source_crs_file_wkt"] = meta["crs_wkt"]
    if meta.get("xy_crs_wkt"):
        ds.attrs["source_crs_wkt"] = meta["xy_crs_wkt"]
        ds["x"].attrs["long_name"] = "x (easting) in the cloud's projected CRS (source_crs_wkt), metres"
        ds["y"].attrs["long_name"] = "y (northing) in the cloud's projected CRS (source_crs_wkt), metres"
    elif meta.get("crs_kind") == "geographic":
        ds["x"].attrs["long_name"] = "x (east) in the dive's map frame"
        ds["y"].attrs["long_name"] = "y (north) in the dive's map frame"
