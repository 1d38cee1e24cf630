"""Grids as Cloud-Optimized GeoTIFF (rio-cogeo) in a standard CRS, for GIS users (QGIS, GMT, GDAL).

hadal's grids live in the dive's local transverse-Mercator map frame (:class:`hadal.geo.LocalFrame`), which is
exact but not a registered CRS. :func:`write_grid_cog` resamples one layer (bilinear, ``rasterio.warp``) onto a
north-up grid in the UTM zone of the grid's centre (WGS 84, EPSG:326zz north / 327zz south; the Norway/Svalbard
zone exceptions are not applied; beyond 84°N/80°S, where UTM is undefined, geographic EPSG:4326 is used) at the
grid's own cell size, and writes it as a COG (GDAL's COG driver: deflate, internal overviews; layout checked with rio-cogeo's
``cog_validate``), with ``nodata`` = -9999, the band's
units and description, and the source grid named in the tags. The NetCDF product keeps its CF grid mapping.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

NODATA = -9999.0


def utm_epsg(lon_deg: float, lat_deg: float) -> int:
    """EPSG code of the WGS 84 UTM zone containing (lon, lat); 4326 outside UTM's latitude range."""
    if not -80.0 <= lat_deg <= 84.0:
        return 4326
    zone = int(math.floor(((lon_deg + 180.0) % 360.0) / 6.0)) + 1
    return (32600 if lat_deg >= 0 else 32700) + min(zone, 60)


def _grid_crs_wkt(ds: Any, frame: Any = None) -> str:
    for v in ds.variables.values():
        wkt = v.attrs.get("crs_wkt") or v.attrs.get("spatial_ref")
        if isinstance(wkt, str) and wkt.strip():
            return wkt
    if frame is None:
        raise ValueError("grid has no grid-mapping variable and no frame was given")
    return frame.crs.to_wkt()


def write_grid_cog(ds: Any, path: str | Path, variable: str = "depth_m", *, frame: Any = None,
                   units: str | None = None, description: str | None = None, epsg: int | None = None,
                   laser_frame: Any = None) -> Path:
    """Write ``ds[variable]`` (dims ``y``, ``x``: ascending cell centres, metres in the map frame) as a COG in
    the UTM zone of its centre (or ``epsg``). Returns ``path``.

    With ``laser_frame`` (:class:`hadal.dive.LaserFrame`) the grid's x/y are the laser survey's local frame:
    turned by its heading (:func:`hadal.products.geo_landing.frame_to_east_north`) about its origin, which is
    the centre of a transverse Mercator (:class:`hadal.geo.LocalFrame`) - the rotation goes into the source
    affine transform, so the resampling is the same single bilinear warp."""
    from pyproj import CRS as PCRS
    from pyproj import Transformer
    from rasterio.crs import CRS
    from rasterio.io import MemoryFile
    from rasterio.shutil import copy as rio_copy
    from rasterio.transform import from_origin
    from rasterio.warp import Resampling, calculate_default_transform, reproject
    from rio_cogeo.cogeo import cog_validate

    path = Path(path)
    da = ds[variable].transpose("y", "x")
    x, y = ds["x"].values.astype(float), ds["y"].values.astype(float)
    dx, dy = float(np.median(np.diff(x))), float(np.median(np.diff(y)))
    src = np.asarray(da.values, dtype="float64")
    if dy > 0:  # rows south -> north: flip to north-up
        src, top = src[::-1], y[-1] + dy / 2
    else:
        top = y[0] - dy / 2
    dy = abs(dy)
    left, right, bottom = x[0] - dx / 2, x[-1] + dx / 2, top - dy * src.shape[0]
    if laser_frame is not None:
        from affine import Affine

        from hadal.geo import LocalFrame
        from hadal.products.geo_landing import frame_to_east_north

        src_wkt = LocalFrame(laser_frame.origin_latitude_deg, laser_frame.origin_longitude_deg).crs.to_wkt()
        h = math.radians(float(laser_frame.heading_deg))
        c, s_ = math.cos(h), math.sin(h)  # (col, row) -> laser (x, y) -> (east, north)
        src_transform = Affine(dx * c, -dy * s_, left * c + top * s_, -dx * s_, -dy * c, -left * s_ + top * c)
        ce, cn = frame_to_east_north(np.array([left, right, right, left]), np.array([top, top, bottom, bottom]),
                                     float(laser_frame.heading_deg))
        left, right, bottom, top = float(ce.min()), float(ce.max()), float(cn.min()), float(cn.max())
    else:
        src_wkt = _grid_crs_wkt(ds, frame)
        src_transform = from_origin(left, top, dx, dy)
    src_crs = CRS.from_wkt(src_wkt)
    if epsg is None:
        to_ll = Transformer.from_crs(PCRS.from_wkt(src_wkt), PCRS.from_epsg(4326), always_xy=True)
        lon, lat = to_ll.transform(0.5 * (left + right), 0.5 * (bottom + top))
        epsg = utm_epsg(lon, lat)
    dst_crs = CRS.from_epsg(epsg)
    # the finer of the two cell sizes: a coarser output would make GDAL widen the bilinear kernel (smoothing)
    res = min(dx, dy) if epsg != 4326 else min(dx, dy) / 111_320.0
    transform, w, h = calculate_default_transform(src_crs, dst_crs, src.shape[1], src.shape[0],
                                                  left=left, bottom=bottom, right=right, top=top,
                                                  resolution=res)
    dst = np.full((h, w), np.nan, dtype="float64")
    reproject(src, dst, src_transform=src_transform, src_crs=src_crs, dst_transform=transform, dst_crs=dst_crs,
              resampling=Resampling.bilinear, src_nodata=np.nan, dst_nodata=np.nan)
    out = np.where(np.isfinite(dst), dst, NODATA).astype("float32")
    units = units or str(da.attrs.get("units", ""))
    desc = description or str(da.attrs.get("long_name", variable))
    profile = {"driver": "GTiff", "width": w, "height": h, "count": 1, "dtype": "float32", "crs": dst_crs,
               "transform": transform, "nodata": NODATA}
    tags = {"variable": variable, "units": units, "positive": str(da.attrs.get("positive", "")),
            "source_crs": ("laser survey frame (dive.yaml laser_frame) turned by "
                           f"{float(laser_frame.heading_deg):g} deg about its origin" if laser_frame is not None
                           else "hadal map frame (transverse Mercator), see the NetCDF product's grid mapping"),
            "resampling": "bilinear", "producer": "hadal"}
    with MemoryFile() as mem:
        with mem.open(**profile) as tmp:
            tmp.write(out, 1)
            tmp.update_tags(**{k: v for k, v in tags.items() if v})
            tmp.set_band_description(1, f"{variable}: {desc}")
            if units:
                tmp.units = (units,)
        with mem.open() as tmp:
            # GDAL's COG driver (through rasterio) keeps the band's unit type, which rio-cogeo's cog_translate
            # drops; rio-cogeo validates the layout
            rio_copy(tmp, str(path), driver="COG", COMPRESS="DEFLATE", PREDICTOR="YES", OVERVIEWS="AUTO",
                     RESAMPLING="BILINEAR", BLOCKSIZE=512)
    ok, errors, _ = cog_validate(str(path), quiet=True)
    if not ok:  # pragma: no cover - GDAL's COG driver writes valid COGs
        raise RuntimeError(f"{path.name}: not a valid COG ({'; '.join(errors)})")
    return path
