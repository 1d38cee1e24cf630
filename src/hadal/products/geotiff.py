"""Grids as Cloud-Optimized GeoTIFF (GDAL's COG driver through rasterio), in the grid's own CRS, cell for cell.

hadal's grids are computed in the dive's local map frame, a transverse Mercator projection (WGS 84, scale 1)
centred on the dive origin (:class:`hadal.geo.LocalFrame`). That is a proper projected CRS: it is written into
the GeoTIFF as such (GeoTIFF keys ``CT_TransverseMercator`` with the origin, named ``hadal map frame ...``), so
the COG's cells *are* the NetCDF's cells - no second resampling (a bilinear warp to UTM lost 11.9 m at the
deepest point of the sample DTM). A grid in another projected CRS (a laser raster or cloud kept in its own UTM,
``source_crs_wkt``) keeps that CRS; a laser grid in the laser survey's frame (``dive.yaml`` ``laser_frame``:
origin and heading) is written in the transverse Mercator frame centred on that origin with a *rotated*
geotransform (GeoTIFF ModelTransformation), which is its true footprint.

Layout (:func:`write_grid_cog`): float32 bands, ``nodata`` = :data:`NODATA` (-32768, outside every elevation,
depth, uncertainty or count on Earth: -9999 is a real elevation in a hadal trench), each band with a
description, unit and ``STATISTICS_*`` (min, max, mean, std, valid percent) that ``gdalinfo`` shows and the STAC
catalogue reuses; deflate with the floating-point predictor, 512 px tiles, internal overviews (average); layout
checked with rio-cogeo's ``cog_validate``. No vertical CRS is attached: heights are relative to the sea surface
(DTM) or to nothing the grid knows (laser grids), which no EPSG vertical datum describes.

The DTM (:func:`dtm_bands`) is published as ``elevation`` (positive up, GIS convention: GMT, QGIS and GDAL read
a single-band DEM as heights) = minus the NetCDF's ``depth_m`` (positive down), with ``uncertainty`` and
``count`` bands when the grid has them. Beside each COG a small PNG thumbnail (``<stem>_thumbnail.png``,
:func:`write_thumbnail`) for catalogues.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

#: nodata of every band: outside any elevation, depth, uncertainty or count on Earth (deepest sea floor -10 994 m)
NODATA = -32768.0
#: longest side of a thumbnail, pixels
THUMBNAIL_PX = 256
#: relative tolerance on the regularity of cell centres (a COG has one cell size)
_REGULAR_RTOL = 1e-6


@dataclass(frozen=True)
class Band:
    """One band of a COG: (y, x) values as in the dataset (rows in the order of ``y``), unit, description."""

    name: str
    values: np.ndarray
    units: str
    description: str
    tags: dict[str, str] = field(default_factory=dict)


def named_crs(wkt: str, name: str) -> str:
    """``wkt`` with ``name`` when PROJ calls it ``unknown``/``unnamed`` (a PROJ-string CRS): the name is what
    GIS tools show (GeoTIFF ``PCSCitationGeoKey``)."""
    from pyproj import CRS

    crs = CRS.from_wkt(wkt)
    if crs.name not in ("unknown", "unnamed", ""):
        return wkt
    d = crs.to_json_dict()
    d["name"] = name
    return CRS.from_json_dict(d).to_wkt()


def frame_crs_wkt(origin_latitude_deg: float, origin_longitude_deg: float, what: str = "hadal map frame") -> str:
    """WKT2 of the transverse Mercator frame (WGS 84, k = 1, no false origin) centred on the origin."""
    from hadal.geo import LocalFrame

    crs = LocalFrame(origin_latitude_deg, origin_longitude_deg).crs
    return named_crs(crs.to_wkt(), f"{what}: transverse Mercator centred on {origin_latitude_deg:.7f}, "
                                   f"{origin_longitude_deg:.7f} (WGS 84)")


def grid_crs_wkt(ds: Any, frame: Any = None) -> str:
    """The CRS of a grid's x/y, by metadata: its CF grid-mapping variable's ``crs_wkt``/``spatial_ref``, else the
    ``source_crs_wkt`` attribute (a grid kept in its input's projected CRS), else ``frame``'s."""
    for v in ds.variables.values():
        wkt = v.attrs.get("crs_wkt") or v.attrs.get("spatial_ref")
        if isinstance(wkt, str) and wkt.strip():
            return named_crs(wkt, _frame_name(ds))
    wkt = ds.attrs.get("source_crs_wkt")
    if isinstance(wkt, str) and wkt.strip():
        return wkt
    if frame is None:
        raise ValueError("grid has no grid-mapping variable, no source_crs_wkt and no frame was given")
    return frame_crs_wkt(frame.origin_latitude_deg, frame.origin_longitude_deg)


def _frame_name(ds: Any) -> str:
    lat, lon = ds.attrs.get("map_frame_origin_latitude_deg"), ds.attrs.get("map_frame_origin_longitude_deg")
    if lat is None or lon is None:
        return "hadal map frame: transverse Mercator (WGS 84)"
    return f"hadal map frame: transverse Mercator centred on {float(lat):.7f}, {float(lon):.7f} (WGS 84)"


def _regular_step(v: np.ndarray, axis: str) -> float:
    """The constant spacing of cell centres ``v``; a one-line ValueError when they are not regular."""
    if v.size < 2:
        raise ValueError(f"grid axis {axis} has {v.size} cell: no cell size")
    d = np.diff(v)
    step = float(np.median(d))
    if step == 0 or np.max(np.abs(d - step)) > _REGULAR_RTOL * max(abs(step), 1e-12) + 1e-9:
        raise ValueError(f"grid axis {axis} is not regular (steps {d.min():g}..{d.max():g}); a COG has one cell size")
    return step


def grid_transform(ds: Any, laser_frame: Any = None) -> tuple[Any, bool]:
    """(affine transform of the north-up raster, flip_rows) for a dataset with ascending or descending cell
    centres ``x``/``y``. With ``laser_frame`` the laser frame's (x, y) are turned by its heading about its origin
    (:func:`hadal.products.geo_landing.frame_to_east_north`): the rotation is in the transform."""
    from affine import Affine

    x, y = np.asarray(ds["x"].values, float), np.asarray(ds["y"].values, float)
    dx, dy = _regular_step(x, "x"), _regular_step(y, "y")
    if dx < 0:
        raise ValueError("grid x is descending; expected west -> east cell centres")
    flip = dy > 0  # rows south -> north: the raster's first row is the northernmost
    top = (y[-1] + dy / 2) if flip else (y[0] - dy / 2)
    left, dy = x[0] - dx / 2, abs(dy)
    if laser_frame is None:
        return Affine(dx, 0.0, left, 0.0, -dy, top), flip
    h = math.radians(float(laser_frame.heading_deg))
    c, s = math.cos(h), math.sin(h)  # (col, row) -> laser (x, y) -> (east, north)
    return Affine(dx * c, -dy * s, left * c + top * s, -dx * s, -dy * c, -left * s + top * c), flip


def band_statistics(values: np.ndarray) -> dict[str, float]:
    """GDAL's ``STATISTICS_*`` of a band (finite values; float64 arithmetic on the float32 values written)."""
    v = np.asarray(values, dtype="float32").astype("float64")
    ok = np.isfinite(v)
    if not ok.any():
        return {"valid_percent": 0.0}
    f = v[ok]
    return {"minimum": float(f.min()), "maximum": float(f.max()), "mean": float(f.mean()),
            "stddev": float(f.std()), "valid_percent": round(100.0 * float(ok.mean()), 4)}


def dtm_bands(ds: Any) -> list[Band]:
    """The DTM's bands: ``elevation`` (m, positive up) = -``depth_m`` when ``depth_m`` is positive down (its
    ``positive`` attribute, else its CF standard name ``sea_floor_depth_below_sea_surface``), then
    ``uncertainty`` (``uncertainty_m``) and ``count`` when present."""
    depth = ds["depth_m"]
    positive = str(depth.attrs.get("positive", "")).lower()
    if not positive and depth.attrs.get("standard_name") == "sea_floor_depth_below_sea_surface":
        positive = "down"
    if positive not in ("up", "down"):
        raise ValueError("dtm depth_m has no 'positive' attribute nor a depth standard_name: cannot tell elevation")
    z = np.asarray(depth.transpose("y", "x").values, float)
    bands = [Band("elevation", -z if positive == "down" else z, "m",
                  "elevation: sea-floor elevation relative to the sea surface, positive up (= -depth_m of dtm.nc)",
                  {"positive": "up", "source_variable": "depth_m", "source_positive": positive,
                   "relation": "elevation = -depth_m" if positive == "down" else "elevation = depth_m"})]
    if "uncertainty_m" in ds:
        u = ds["uncertainty_m"]
        bands.append(Band("uncertainty", np.asarray(u.transpose("y", "x").values, float), "m",
                          f"uncertainty: {u.attrs.get('long_name', 'standard uncertainty of the cell depth')}",
                          {"source_variable": "uncertainty_m"}))
    if "count" in ds:
        n = ds["count"]
        bands.append(Band("count", np.asarray(n.transpose("y", "x").values, float), "1",
                          f"count: {n.attrs.get('long_name', 'number of soundings in the cell')}",
                          {"source_variable": "count"}))
    return bands


def laser_bands(ds: Any) -> list[Band]:
    """A laser grid's bands: ``elevation`` (``elevation_m``, positive up, relative to no vertical datum), then
    ``count`` and ``elevation_std`` when the grid has them (point clouds; a raster has neither)."""
    el = ds["elevation_m"]
    if str(el.attrs.get("positive", "up")).lower() != "up":
        raise ValueError("laser grid elevation_m is not positive up")
    bands = [Band("elevation", np.asarray(el.transpose("y", "x").values, float), "m",
                  f"elevation: {el.attrs.get('long_name', 'laser elevation')} (positive up; no vertical datum)",
                  {"positive": "up", "source_variable": "elevation_m"})]
    for name, var, unit in (("count", "count", "1"), ("elevation_std", "elevation_std_m", "m")):
        if var in ds and ds[var].dims == el.dims:
            bands.append(Band(name, np.asarray(ds[var].transpose("y", "x").values, float), unit,
                              f"{name}: {ds[var].attrs.get('long_name', var)}", {"source_variable": var}))
    return bands


def variable_band(ds: Any, variable: str, units: str | None = None, description: str | None = None) -> Band:
    """One dataset variable as a band, as it is (its ``positive`` attribute, if any, in the band's tags)."""
    da = ds[variable]
    tags = {"source_variable": variable}
    if da.attrs.get("positive"):
        tags["positive"] = str(da.attrs["positive"])
    return Band(variable, np.asarray(da.transpose("y", "x").values, float),
                units if units is not None else str(da.attrs.get("units", "")),
                f"{variable}: {description or da.attrs.get('long_name', variable)}", tags)


def write_grid_cog(ds: Any, path: str | Path, variable: str = "depth_m", *, frame: Any = None,
                   units: str | None = None, description: str | None = None, laser_frame: Any = None,
                   bands: list[Band] | None = None, thumbnail: bool = True) -> Path:
    """Write grid bands (dims ``y``, ``x``: regular cell centres, metres in the grid's CRS) as a COG in the
    grid's own CRS, cell for cell (no resampling). Returns ``path``.

    ``bands`` default: :func:`dtm_bands` for ``variable='depth_m'`` (elevation positive up, uncertainty,
    count), :func:`laser_bands` for ``'elevation_m'`` (elevation, count, std), else the one variable as it is. With ``laser_frame`` (:class:`hadal.dive.LaserFrame`) x/y are the
    laser survey's frame: CRS = transverse Mercator centred on its origin, geotransform turned by its heading.
    With ``thumbnail`` a PNG of the first band is written beside it (:func:`write_thumbnail`)."""
    from rasterio.crs import CRS
    from rasterio.io import MemoryFile
    from rasterio.shutil import copy as rio_copy
    from rio_cogeo.cogeo import cog_validate

    path = Path(path)
    if bands is None:
        bands = (dtm_bands(ds) if variable == "depth_m" else laser_bands(ds) if variable == "elevation_m"
                 else [variable_band(ds, variable, units, description)])
    transform, flip = grid_transform(ds, laser_frame)
    if laser_frame is not None:
        wkt = frame_crs_wkt(float(laser_frame.origin_latitude_deg), float(laser_frame.origin_longitude_deg),
                            "hadal laser frame origin")
        where = (f"laser survey frame (dive.yaml laser_frame) turned by {float(laser_frame.heading_deg):g} deg "
                 "about its origin: rotated geotransform in the transverse Mercator frame centred on the origin")
    else:
        wkt = grid_crs_wkt(ds, frame)
        where = "the grid's own CRS (the NetCDF product's grid mapping): cells as computed, no resampling"
    arrays = [np.asarray(b.values[::-1] if flip else b.values, dtype="float32") for b in bands]
    h, w = arrays[0].shape
    profile = {"driver": "GTiff", "width": w, "height": h, "count": len(bands), "dtype": "float32",
               "crs": CRS.from_wkt(wkt), "transform": transform, "nodata": NODATA}
    tags = {"producer": "hadal", "resampling": "none", "georeferencing": where,
            "vertical_reference": ("none: heights relative to the sea surface (DTM) or to the survey (laser grids); "
                                   "no vertical datum is claimed")}
    with MemoryFile() as mem:
        with mem.open(**profile) as tmp:
            tmp.update_tags(**tags)
            for i, (b, a) in enumerate(zip(bands, arrays, strict=True), start=1):
                stats = band_statistics(a)
                tmp.write(np.where(np.isfinite(a), a, np.float32(NODATA)), i)
                tmp.set_band_description(i, b.description)
                tmp.update_tags(i, **{k: v for k, v in b.tags.items() if v},
                                **{f"STATISTICS_{k.upper()}": f"{v:.10g}" for k, v in stats.items()})
            tmp.units = tuple(b.units for b in bands)
        with mem.open() as tmp, MemoryFile() as cog:
            # GDAL's COG driver (through rasterio) keeps band units, descriptions and metadata, which rio-cogeo's
            # cog_translate drops; rio-cogeo validates the layout. Built in memory and written with plain
            # os.write: a full disk is then one OSError (ENOSPC), not a GDAL error about a half-written overview
            rio_copy(tmp, cog.name, driver="COG", COMPRESS="DEFLATE", PREDICTOR="YES", OVERVIEWS="AUTO",
                     RESAMPLING="AVERAGE", BLOCKSIZE=512)
            from hadal.store import write_bytes_checked

            write_bytes_checked(path, cog.read(), Path(path).name)
    ok, errors, _ = cog_validate(str(path), quiet=True)
    if not ok:  # pragma: no cover - GDAL's COG driver writes valid COGs
        raise RuntimeError(f"{path.name}: not a valid COG ({'; '.join(errors)})")
    if thumbnail:
        write_thumbnail(arrays[0], thumbnail_path(path), cmap="cividis" if bands[0].name == "elevation" else "viridis")
    return path


def thumbnail_path(cog: str | Path) -> Path:
    """``<stem>_thumbnail.png`` beside the COG."""
    p = Path(cog)
    return p.with_name(f"{p.stem}_thumbnail.png")


def write_thumbnail(values: np.ndarray, path: str | Path, *, cmap: str = "viridis", max_px: int = THUMBNAIL_PX) -> Path:
    """A small PNG of a north-up band (first row north): block-averaged to at most ``max_px`` on its longest side,
    2-98 % stretch, transparent where there is no data (matplotlib ``imsave``)."""
    import matplotlib

    a = np.asarray(values, float)
    k = max(1, math.ceil(max(a.shape) / max_px))
    hh, ww = (a.shape[0] // k) * k or a.shape[0], (a.shape[1] // k) * k or a.shape[1]
    if k > 1 and a.shape[0] >= k and a.shape[1] >= k:
        blocks = a[:hh, :ww].reshape(hh // k, k, ww // k, k)
        with np.errstate(invalid="ignore"):
            cnt = np.isfinite(blocks).sum(axis=(1, 3))
            a = np.where(cnt > 0, np.nansum(blocks, axis=(1, 3)) / np.maximum(cnt, 1), np.nan)
    ok = np.isfinite(a)
    lo, hi = (np.percentile(a[ok], [2, 98]) if ok.any() else (0.0, 1.0))
    if not hi > lo:
        hi = lo + 1.0
    rgba = matplotlib.colormaps[cmap]((np.clip(a, lo, hi) - lo) / (hi - lo))
    rgba[~ok] = 0.0
    import matplotlib.image

    path = Path(path)
    matplotlib.image.imsave(path, rgba, format="png")
    return path
