"""Prior bathymetry grids (GeoTIFF, NetCDF COARDS/CF, GMT .grd) -> the reference DTM in the dive's map frame.

:func:`prior_dtm` reads a grid with :func:`hadal.grid.readers.read_grid`, decides whether its values are
elevations (positive up) or depths (:func:`z_positive`) and resamples it onto the dive's transverse-Mercator
map frame (:func:`resample_to_frame`), giving the same layout as the multibeam ``dtm.nc``: ``depth_m``
(positive down) on ``x``/``y`` metres, ``lat``/``lon``, ``crs``.

**Resampling.** The target grid has square cells of (about) the source's native resolution - the smaller
of its two cell sides in metres at the grid's centre (geodesic for lon/lat grids), rounded to 3
significant digits - aligned on multiples of the resolution (as multibeam DTMs are). Every target cell
centre is transformed exactly (pyproj) from the map frame into the grid's own CRS (lon/lat of its
datum, or its projected x/y) and the value is **bilinear** in the source grid's index space. A target
cell is NaN when any source value with a non-zero bilinear weight is NaN (no value is invented next to
nodata) or when it lies outside the source's value domain: between the first and last nodes of a
gridline-registered grid, plus half a cell (nearest value) at the edges of a pixel-registered one
(GMT ``node_offset=1``, GeoTIFF ``AREA_OR_POINT=Area``). Longitudes are wrapped into the grid's range.
Grids without a CRS (``local_metric``) are taken to be in the map frame already. Large geographic grids
are cropped to ``max_extent_m`` around the map frame's origin (the transverse Mercator frame is exact
near its meridian, not across an ocean basin; ``grid.prior_max_extent_km``, default 2000 km). A crop is
never silent: the product records the kept lon/lat bounds, the fraction of the source's valid area and
of its depth range outside the crop (:func:`crop_attrs`), and the ``grid`` stage logs a WARNING.

**Units** come from the file and are converted to metres by :func:`hadal.grid.readers.read_grid`
(``prior_grid_z_units``); 0-360 longitudes are shifted to -180..180 (``prior_grid_lon_convention``).

**Sign** (:func:`z_positive`, first rule that decides): the ``z_positive`` hint of ``dive.yaml``; a CF
``positive`` attribute; a CF ``standard_name`` (``*depth*`` -> down; ``height``/``altitude``/
``*elevation*`` -> up); words of the variable's name, long_name and units (``depth``/``below`` -> down;
``elevation``/``topo*``/``height``/``above`` -> up; GMT's generic ``z`` says nothing). Only then the values,
as a guess whose reason starts with ``guessed:`` (``hadal init`` writes it into dive.yaml as a commented hint):
all <= 0 -> elevations below sea level; mixed -> elevations (GMT/ETOPO/GEBCO, land above 0); all >= 0 with
>= 1 % exactly 0, or in a GMT-written grid -> land elevations; other all >= 0 -> depths. The decision and its
reason are recorded in the product's attributes.

**Land** (:func:`depth_and_land`): a cell above sea level has no depth: ``depth_m`` NaN, flag layer ``land`` = 1.
A grid with no cell below sea level is refused in one line (:func:`no_seafloor`: "NAME is land elevation
(LO-HI m ...): no seafloor to grid").

**Several grids** (:func:`prior_mosaic`, :data:`MOSAIC_RULE`): one grid at the finest resolution over the union
of their outlines, each cell from the finest grid with a value there, then listing order; ``prior_grid_source``
names each cell's grid, ``prior_grid_sources`` each grid's resolution, sign, units and cells used.

Layers: a prior grid has no soundings, so ``count``, ``depth_median_m``, ``depth_std_m``, ``filled`` and
``uncertainty_m`` are absent (the source states no uncertainty); ``attrs['layers_absent']`` says so.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import xarray as xr

from hadal.errors import InputError
from hadal.geo import LocalFrame
from hadal.grid.points import DEFAULT_MAX_CELLS, make_grid_spec, to_dataset
from hadal.grid.readers import read_grid

#: default crop of geographic grids around the map frame origin (m, full width)
DEFAULT_MAX_EXTENT_M = 2_000_000.0

RESAMPLING = ("bilinear in the source grid's index space at the target cell centres (pyproj inverse transform "
              "from the map frame); NaN where a contributing source value is NaN or outside the source's value "
              "domain (pixel registration: nearest value within half a cell of the edge)")


# ------------------------------------------------------------------ sign
#: CF standard names of grid values that are depths (positive down) / heights (positive up)
DEPTH_STANDARD_NAMES = ("depth", "sea_floor_depth", "sea_floor_depth_below_sea_surface", "sea_floor_depth_below_geoid",
                        "sea_floor_depth_below_mean_sea_level", "sea_floor_depth_below_reference_ellipsoid",
                        "depth_below_geoid", "depth_below_sea_floor")
HEIGHT_STANDARD_NAMES = ("height", "altitude", "surface_altitude", "height_above_mean_sea_level",
                         "height_above_reference_ellipsoid", "height_above_geopotential_datum", "bedrock_altitude",
                         "height_above_geoid", "land_surface_altitude", "sea_floor_altitude")
#: words of a variable's name/long_name/units that say up (elevations) or down (depths); GMT's generic ``z``
#: and the ambiguous ``bathymetry`` say neither
UP_WORDS = ("elevation", "elev", "topo", "height", "altitude", "above", "dem", "orography")
DOWN_WORDS = ("depth", "below", "sounding")
#: all values >= 0 with at least this fraction exactly 0: a land DEM with the sea at 0 (guessed "up")
SEA_LEVEL_ZERO_FRACTION = 0.01
GUESSED = "guessed: "


def _words(text: str) -> set[str]:
    import re

    return {w for w in re.split(r"[^a-z]+", text.lower()) if w}


def _says(words: set[str], vocabulary: tuple[str, ...]) -> bool:
    """A word of ``words`` is a word of ``vocabulary`` or (for words of 4+ letters) starts with one
    (``topography`` by ``topo``, ``depths`` by ``depth``)."""
    return any(w == v or (len(v) >= 4 and w.startswith(v)) for w in words for v in vocabulary)


def z_positive(da: xr.DataArray, hint: str | None = None) -> tuple[str, str]:
    """``("up" | "down", reason)``: whether a grid's values are elevations or depths (module docstring).

    Metadata first: the ``z_positive`` hint of dive.yaml, CF ``positive``, CF ``standard_name``
    (:data:`DEPTH_STANDARD_NAMES`, :data:`HEIGHT_STANDARD_NAMES`, ``*depth*``/``*altitude*``/``*height*``), the
    words of the variable's name, ``long_name`` and units (:data:`UP_WORDS`, :data:`DOWN_WORDS`; GDAL band
    metadata land in the same attributes). Only when the file says nothing are the values used, and the reason
    then starts with ``guessed:`` (``hadal init`` writes the guess into dive.yaml): all <= 0 -> elevations below
    sea level; mixed -> elevations (GMT/ETOPO/GEBCO: land above 0); all >= 0 with >= 1 % of the cells exactly 0
    -> a land DEM with the sea at 0 (up); all >= 0 in a GMT-written grid -> elevations (GMT's convention);
    other all >= 0 -> depths (down).
    """
    if hint is not None:
        if hint not in ("up", "down"):
            raise InputError(f"z_positive must be 'up' or 'down', got {hint!r}")
        return hint, "z_positive given in dive.yaml"
    a = da.attrs
    pos = str(a.get("positive", "")).strip().lower()
    if pos in ("up", "down"):
        return pos, f"CF attribute positive={pos!r}"
    sn = str(a.get("standard_name", "")).strip().lower()
    if sn:
        if sn in DEPTH_STANDARD_NAMES or "depth" in sn:
            return "down", f"standard_name {sn!r}"
        if sn in HEIGHT_STANDARD_NAMES or any(w in sn for w in ("elevation", "altitude", "height")):
            return "up", f"standard_name {sn!r}"
    keys = ("var_name", "long_name", "description", "z_units_file" if "z_units_file" in a else "units")
    text = " ".join(str(a.get(k, "")) for k in keys)
    words = _words(text)
    down, up = _says(words, DOWN_WORDS), _says(words, UP_WORDS)
    if down and not up:
        return "down", f"name/units {' '.join(text.split())!r}"
    if up and not down:
        return "up", f"name/units {' '.join(text.split())!r}"
    return _guess_sign(np.asarray(da.values, float), gmt="GMT grid" in str(a.get("format", "")))


def _guess_sign(values: np.ndarray, gmt: bool = False) -> tuple[str, str]:
    """The values-only sign guess of :func:`z_positive` (reason starts with :data:`GUESSED`)."""
    v = values[np.isfinite(values)]
    if not v.size:
        return "up", GUESSED + "no valid values: elevation"
    lo, hi = float(v.min()), float(v.max())
    if hi <= 0:
        return "up", GUESSED + f"all values <= 0 ({lo:g}..{hi:g}): elevations below sea level"
    if lo < 0:
        return "up", GUESSED + f"mixed signs ({lo:g}..{hi:g}): elevations, land above 0 (GMT/ETOPO/GEBCO)"
    zero = float(np.mean(v == 0))
    if gmt:
        return "up", GUESSED + (f"all values >= 0 ({lo:g}..{hi:g}) in a GMT grid: elevations (GMT's z is positive "
                                "up, as in its relief grids)")
    if zero >= SEA_LEVEL_ZERO_FRACTION:
        return "up", GUESSED + (f"all values >= 0 ({lo:g}..{hi:g}) with {100 * zero:.1f} % exactly 0: land "
                                "elevations with the sea at 0")
    return "down", GUESSED + f"all values >= 0 ({lo:g}..{hi:g}), none at sea level: depths"


def is_guessed(reason: str) -> bool:
    """True when a :func:`z_positive` reason is a values-only guess (the file said nothing)."""
    return str(reason).startswith(GUESSED)


# ------------------------------------------------------------------ plausibility
#: largest plausible |depth| or |elevation| (m) of a bathymetry grid: the deepest sounding on Earth (Challenger
#: Deep, ~10 935 m) plus ~5 % margin; Everest (8 849 m) is well inside. Beyond it a value is a fill or a unit error.
MAX_ABS_DEPTH_M = 11_500.0
#: fill values of common grid writers (GMT/ArcGIS/Surfer/int16 NetCDF) taken as nodata when they stand out
COMMON_FILL_VALUES = (-32768.0, -32767.0, 32767.0, -99999.0, 99999.0, -999999.0, 999999.0, -9999.0, 9999.0)
_FEET_UNITS = ("ft", "feet", "foot", "us survey foot", "us_survey_foot", "ftus", "us-ft", "international foot")


def check_depth_plausible(da: xr.DataArray, max_abs_m: float = MAX_ABS_DEPTH_M) -> tuple[xr.DataArray, str]:
    """Refuse or mask grid values no ocean has; returns ``(da, note)`` (``note`` empty when nothing was done).

    Rules (in the source's units, before the sign is chosen):

    * units ``ft``/``feet`` (a tag or attribute): a one-line :class:`InputError` (convert to metres first);
    * cells exactly equal to a common fill value (:data:`COMMON_FILL_VALUES`: +-32767, -32768, +-99999,
      +-999999, or +-9999 when it stands >= 1 km apart from every other value) or with ``|z| >= 1e30``
      become NaN; ``note`` says how many (the grid stage logs it as a WARNING);
    * any other ``|z| > max_abs_m`` (default 11 500 m: Challenger Deep 10 935 m + 5 %): a one-line
      :class:`InputError` naming the value, with a hint - "looks like feet" when every value x 0.3048 is
      plausible and at least 10 % of the values are beyond the limit, else an unknown fill value (set the
      file's nodata).
    """
    src = da.attrs.get("source", "grid")
    units = str(da.attrs.get("units", "")).strip().lower()
    if units in _FEET_UNITS:
        raise InputError(f"{src}: grid values are in feet (units {da.attrs.get('units')!r}); hadal needs metres: "
                         "convert it first (e.g. gdal_calc.py --calc='A*0.3048')")
    a = np.asarray(da.values, float)
    fin = np.isfinite(a)
    if not fin.any():
        return da, ""
    absa = np.where(fin, np.abs(a), 0.0)
    fill = fin & (absa >= 1e30)
    for fv in COMMON_FILL_VALUES:
        hit = fin & (a == fv)
        if not hit.any():
            continue
        if abs(fv) <= max_abs_m:  # +-9999 can be a real hadal depth: only when it is an isolated plateau
            rest = fin & ~hit & ~fill
            if not rest.any() or np.min(np.abs(a[rest] - fv)) < 1000.0:
                continue
        fill |= hit
    note = ""
    if fill.any():
        vals = ", ".join(f"{v:g}" for v in np.unique(a[fill])[:4])
        note = (f"{int(fill.sum())} cell(s) holding the fill value {vals} (no nodata tag for it) taken as nodata")
        a = np.where(fill, np.nan, a)
        fin &= ~fill
        if not fin.any():
            raise InputError(f"{src}: every grid cell holds the fill value {vals}")
        da = da.copy(data=a)
    over = fin & (np.abs(np.where(fin, a, 0.0)) > max_abs_m)
    if over.any():
        v = a[over]
        worst = float(v[np.argmax(np.abs(v))])
        allv = a[fin]
        if (np.max(np.abs(allv)) * 0.3048 <= max_abs_m and np.median(np.abs(allv)) * 0.3048 > 100.0
                and over.sum() >= 0.1 * allv.size):
            hint = (f"the values look like feet (x 0.3048: {np.min(allv) * 0.3048:.0f}..{np.max(allv) * 0.3048:.0f} m)"
                    "; convert the grid to metres")
        else:
            hint = "a fill value without a nodata tag? set it (e.g. gdal_translate -a_nodata VALUE) or crop it out"
        raise InputError(f"{src}: {int(over.sum())} grid value(s) beyond +-{max_abs_m:g} m (e.g. {worst:g}), deeper "
                         f"or higher than anywhere on Earth: {hint}")
    return da, note


# ------------------------------------------------------------------ geometry
def source_crs(da: xr.DataArray):
    """The grid's pyproj CRS (``None`` for ``local_metric``); geographic grids without one are WGS84."""
    from pyproj import CRS

    kind = da.attrs.get("crs_kind")
    if kind == "local_metric":
        return None
    wkt = da.attrs.get("crs_wkt") or ""
    if wkt:
        c = CRS.from_user_input(wkt)
        if kind == "geographic" and not c.is_geographic:
            return CRS.from_epsg(4326)
        return c
    if kind == "geographic":
        return CRS.from_epsg(4326)
    raise InputError(f"{da.attrs.get('source', 'grid')}: projected grid without a CRS; give 'crs' in dive.yaml")


def _cell_sizes(da: xr.DataArray) -> tuple[float, float]:
    dx = float(da.attrs.get("cell_size_x") or abs(float(da.x[1] - da.x[0])))
    dy = float(da.attrs.get("cell_size_y") or abs(float(da.y[1] - da.y[0])))
    return dx, dy


def native_resolution_m(da: xr.DataArray) -> float:
    """Smaller cell side of the grid in metres at its centre, rounded to 3 significant digits."""
    dx, dy = _cell_sizes(da)
    crs = source_crs(da)
    if crs is not None and crs.is_geographic:
        from pyproj import Geod

        g = Geod(ellps="WGS84")
        lon_c, lat_c = float(da.x.mean()), float(da.y.mean())
        lat_c = max(-89.0, min(89.0, lat_c))
        _, _, sx = g.inv(lon_c, lat_c, lon_c + dx, lat_c)
        _, _, sy = g.inv(lon_c, lat_c, lon_c, min(90.0, lat_c + dy))
        r = min(sx, sy)
    else:
        f = 1.0
        if crs is not None and crs.axis_info:
            f = float(crs.axis_info[0].unit_conversion_factor or 1.0)
        r = min(dx, dy) * f
    if not (r > 0 and math.isfinite(r)):
        raise InputError(f"{da.attrs.get('source', 'grid')}: cannot determine the grid's cell size")
    return float(f"{r:.3g}")


def _transformers(da: xr.DataArray, frame: LocalFrame | None):
    """(map frame -> source, source -> map frame) coordinate functions."""
    crs = source_crs(da)
    if crs is None or frame is None:
        ident = lambda x, y: (np.asarray(x, float), np.asarray(y, float))  # noqa: E731
        return ident, ident
    from pyproj import Transformer

    inv = Transformer.from_crs(frame.crs, crs, always_xy=True)
    fwd = Transformer.from_crs(crs, frame.crs, always_xy=True)
    return inv.transform, fwd.transform


def bilinear(da: xr.DataArray, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    """Values of ``da`` (ascending regular x/y) at source coordinates ``xs, ys`` (module docstring rules)."""
    a = np.asarray(da.values, float)
    x, y = np.asarray(da.x.values, float), np.asarray(da.y.values, float)
    ny, nx = a.shape
    dx, dy = (x[-1] - x[0]) / (nx - 1), (y[-1] - y[0]) / (ny - 1)
    pixel = da.attrs.get("registration", "pixel") == "pixel"
    h = 0.5 if pixel else 1e-6
    xs = np.asarray(xs, float)
    if da.attrs.get("crs_kind") == "geographic":
        lo = x[0] - h * dx
        xs = lo + np.mod(xs - lo, 360.0)
    fi = (xs - x[0]) / dx
    fj = (np.asarray(ys, float) - y[0]) / dy
    inside = (fi >= -h) & (fi <= nx - 1 + h) & (fj >= -h) & (fj <= ny - 1 + h)
    fi = np.clip(np.where(inside, fi, 0.0), 0, nx - 1)
    fj = np.clip(np.where(inside, fj, 0.0), 0, ny - 1)
    i0 = np.minimum(np.floor(fi).astype(np.int64), nx - 2)
    j0 = np.minimum(np.floor(fj).astype(np.int64), ny - 2)
    wx, wy = fi - i0, fj - j0
    out = np.zeros(fi.shape)
    bad = ~inside
    for dj, di, w in ((0, 0, (1 - wx) * (1 - wy)), (0, 1, wx * (1 - wy)), (1, 0, (1 - wx) * wy), (1, 1, wx * wy)):
        v = a[j0 + dj, i0 + di]
        used = w > 1e-9
        bad |= used & ~np.isfinite(v)
        out += np.where(used & np.isfinite(v), w * v, 0.0)
    out[bad] = np.nan
    return out


def frame_bounds(da: xr.DataArray, frame: LocalFrame | None,
                 max_extent_m: float | None = DEFAULT_MAX_EXTENT_M) -> tuple[list[float], bool]:
    """The grid's outline in the map frame ``[xmin, ymin, xmax, ymax]`` (its edges projected at 257 points each),
    cropped to ``max_extent_m`` around the frame origin; and whether it was cropped."""
    _, fwd = _transformers(da, frame)
    x, y = np.asarray(da.x.values, float), np.asarray(da.y.values, float)
    dx, dy = _cell_sizes(da)
    h = 0.5 if da.attrs.get("registration", "pixel") == "pixel" else 0.0
    x0, x1, y0, y1 = x[0] - h * dx, x[-1] + h * dx, y[0] - h * dy, y[-1] + h * dy
    t = np.linspace(0.0, 1.0, 257)
    ox = np.concatenate([x0 + (x1 - x0) * t, np.full_like(t, x1), x1 - (x1 - x0) * t, np.full_like(t, x0)])
    oy = np.concatenate([np.full_like(t, y0), y0 + (y1 - y0) * t, np.full_like(t, y1), y1 - (y1 - y0) * t])
    fx, fy = fwd(ox, oy)
    fx, fy = np.asarray(fx, float), np.asarray(fy, float)
    ok = np.isfinite(fx) & np.isfinite(fy)
    if not ok.any():
        raise InputError(f"{da.attrs.get('source', 'grid')}: the grid's outline cannot be projected into the map frame")
    bounds = [fx[ok].min(), fy[ok].min(), fx[ok].max(), fy[ok].max()]
    cropped = False
    if max_extent_m and frame is not None and da.attrs.get("crs_kind") != "local_metric":
        half = max_extent_m / 2
        nb = [max(bounds[0], -half), max(bounds[1], -half), min(bounds[2], half), min(bounds[3], half)]
        cropped = nb != bounds
        bounds = nb
        if bounds[2] <= bounds[0] or bounds[3] <= bounds[1]:
            raise InputError(f"{da.attrs.get('source', 'grid')}: the grid does not cover the dive's map frame "
                             f"(origin {frame.origin_latitude_deg:g}, {frame.origin_longitude_deg:g}) within "
                             f"{half / 1000:g} km")
    return bounds, cropped


def sample_on_cells(da: xr.DataArray, frame: LocalFrame | None, xc: np.ndarray, yc: np.ndarray) -> np.ndarray:
    """``da`` (source units and sign) bilinear at the map-frame cell centres ``xc`` x ``yc`` -> ``(ny, nx)``."""
    inv, _ = _transformers(da, frame)
    z = np.empty((len(yc), len(xc)))
    step = max(1, 2_000_000 // max(1, len(xc)))
    for r0 in range(0, len(yc), step):
        yy, xx = np.meshgrid(yc[r0:r0 + step], xc, indexing="ij")
        sx, sy = inv(xx.ravel(), yy.ravel())
        z[r0:r0 + step] = bilinear(da, np.asarray(sx), np.asarray(sy)).reshape(xx.shape)
    return z


def resample_to_frame(da: xr.DataArray, frame: LocalFrame | None, resolution_m: float | None = None, *,
                      max_extent_m: float | None = DEFAULT_MAX_EXTENT_M,
                      max_cells: int = DEFAULT_MAX_CELLS) -> tuple[xr.Dataset, dict[str, Any]]:
    """Resample a :func:`read_grid` array onto square cells of ``frame`` (``None``/local grid: identity).

    Returns ``(Dataset with "z" (y, x) in the source's units and sign, info)``; ``info`` holds the
    resolution, method and crop. All-NaN border rows/columns are cropped.
    """
    res = float(resolution_m) if resolution_m else native_resolution_m(da)
    _, fwd = _transformers(da, frame)
    bounds, cropped = frame_bounds(da, frame, max_extent_m)
    try:
        spec = make_grid_spec(res, bounds, max_cells=max_cells, snap=True)
    except InputError as exc:
        raise InputError(f"{da.attrs.get('source', 'grid')}: {exc} (set grid.prior_resolution_m coarser)") from None
    z = sample_on_cells(da, frame, spec.x, spec.y)
    valid = np.isfinite(z)
    if not valid.any():
        raise InputError(f"{da.attrs.get('source', 'grid')}: no valid grid values inside the map-frame area")
    rows, cols = np.flatnonzero(valid.any(axis=1)), np.flatnonzero(valid.any(axis=0))
    r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    spec = make_grid_spec(res, (spec.x0 + c0 * res, spec.y0 + r0 * res, spec.x0 + c1 * res, spec.y0 + r1 * res),
                          max_cells=max_cells)
    z = z[r0:r1, c0:c1]
    if z.shape[0] < 2 or z.shape[1] < 2:
        raise InputError(f"{da.attrs.get('source', 'grid')}: fewer than 2 x 2 valid cells at {res:g} m in the map frame")
    ds = to_dataset(spec, {"z": z.ravel()})
    info = {"resolution_m": res, "resampling": RESAMPLING,
            "cropped_to_m": float(max_extent_m) if cropped and max_extent_m else 0.0,
            "n_cells_valid": int(np.isfinite(z).sum())}
    if cropped and frame is not None:  # a crop needs the frame (frame_bounds)
        info["crop"] = _crop_loss(da, fwd, frame, bounds)
    return ds, info


def _crop_loss(da: xr.DataArray, fwd, frame: LocalFrame, bounds) -> dict[str, Any]:
    """What a crop to ``bounds`` (map-frame x/y min, max) keeps of the source grid's valid values.

    Source value positions (at most ~1e6, strided) are projected into the frame; a value is kept when it lies
    inside the crop. Area weights: ``cos(latitude)`` per cell for geographic grids, equal otherwise. Returns the
    kept values' lon/lat bounds, the fraction of the source's valid-value area outside the crop and the source
    and kept z ranges (source units and sign).
    """
    ny, nx = da.sizes["y"], da.sizes["x"]
    sy, sx = max(1, ny // 1000), max(1, nx // 1000)
    xs, ys = np.asarray(da.x.values, float)[::sx], np.asarray(da.y.values, float)[::sy]
    zz = np.asarray(da.values, float)[::sy, ::sx]
    gx, gy = np.meshgrid(xs, ys)
    ok = np.isfinite(zz)
    fx, fy = fwd(gx[ok], gy[ok])
    fx, fy = np.asarray(fx, float), np.asarray(fy, float)
    kept = (np.isfinite(fx) & np.isfinite(fy) & (fx >= bounds[0]) & (fx <= bounds[2]) & (fy >= bounds[1])
            & (fy <= bounds[3]))
    geographic = da.attrs.get("crs_kind") == "geographic"
    w = np.cos(np.radians(np.clip(gy[ok], -90, 90))) if geographic else np.ones(int(ok.sum()))
    v = zz[ok]
    out: dict[str, Any] = {"area_fraction_lost": float(1.0 - w[kept].sum() / w.sum()) if w.sum() > 0 else 0.0,
                           "z_range_source": (float(v.min()), float(v.max()))}
    if kept.any():
        lon, lat = frame.to_lonlat(fx[kept], fy[kept])
        out["kept_lonlat"] = (float(np.min(lon)), float(np.max(lon)), float(np.min(lat)), float(np.max(lat)))
        out["z_range_kept"] = (float(v[kept].min()), float(v[kept].max()))
    return out


# ------------------------------------------------------------------ DTM
def describe_crs(da: xr.DataArray) -> str:
    c = source_crs(da) if da.attrs.get("crs_kind") != "local_metric" else None
    if c is None:
        return "local metric (no CRS)"
    epsg = c.to_epsg()
    return f"{c.name}" + (f" (EPSG:{epsg})" if epsg else "")


@dataclass
class PriorGrid:
    """One prior grid read (:func:`load_prior`): values in metres, sign decided, land-only grids refused."""

    path: Path
    da: xr.DataArray
    z_positive: str
    z_reason: str
    depth_note: str = ""
    warning: str = ""

    @property
    def name(self) -> str:
        return self.path.name


def depth_and_land(z: np.ndarray, pos: str) -> tuple[np.ndarray, np.ndarray]:
    """``(depth_m positive down with land NaN, land mask)`` of values ``z`` (metres) of sign ``pos``.
    Land: above sea level (elevation > 0, i.e. depth < 0). Sea level itself (0) is a depth of 0."""
    depth = -np.asarray(z, float) if pos == "up" else np.asarray(z, float)
    with np.errstate(invalid="ignore"):
        land = np.isfinite(depth) & (depth < 0)
    return np.where(land, np.nan, depth), land


def no_seafloor(name: str, da: xr.DataArray, pos: str, reason: str) -> str:
    """Why grid ``name`` has nothing to grid (no cell below sea level, e.g. a land DEM), else ``""``:
    "NAME is land elevation (LO-HI m, ...): no seafloor to grid"."""
    depth, _ = depth_and_land(da.values, pos)
    if np.any(np.nan_to_num(depth, nan=0.0) > 0):
        return ""
    v = da.values[np.isfinite(da.values)]
    what = "land elevation" if pos == "up" else "depths at or above sea level"
    return (f"{name} is {what} ({float(v.min()):g}-{float(v.max()):g} m, z_positive {pos}: {reason}): no seafloor "
            "to grid" + (f"; if these are depths, list {name} with z_positive: down in dive.yaml"
                         if pos == "up" and is_guessed(reason) else ""))


def load_prior(path: str | Path, *, z_positive_hint: str | None = None, crs: str | None = None,
               variable: str | None = None, format: str | None = None, z_units: str | None = None,
               max_read_bytes: float | None = None) -> PriorGrid:
    """Read a prior grid (:func:`read_grid`: metres, -180..180), mask fill values (:func:`check_depth_plausible`)
    and decide its sign (:func:`z_positive`). A grid with no cell below sea level is refused in one line:
    "NAME is land elevation (LO-HI m): no seafloor to grid" (a land DEM is never read as depths)."""
    import warnings

    from hadal.grid.readers import GridCRSWarning

    p = Path(path)
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always", GridCRSWarning)
        da = read_grid(p, variable=variable, format=format, crs=crs, max_bytes=max_read_bytes, z_units=z_units)
    da, depth_note = check_depth_plausible(da)
    pos, reason = z_positive(da, z_positive_hint)
    why = no_seafloor(p.name, da, pos, reason)
    if why:
        raise InputError(why)
    return PriorGrid(p, da, pos, reason, depth_note, str(caught[0].message) if caught else "")


def _prior_attrs(g: PriorGrid) -> dict[str, Any]:
    """The ``prior_grid_*`` attributes describing one source grid."""
    da = g.da
    dx, dy = _cell_sizes(da)
    unit = "degrees" if da.attrs["crs_kind"] == "geographic" else "m"
    out: dict[str, Any] = {
        "prior_grid_file": g.name,
        "prior_grid_format": da.attrs.get("format", ""),
        "prior_grid_reader": da.attrs.get("reader", ""),
        "prior_grid_variable": da.attrs.get("var_name", ""),
        "prior_grid_crs": describe_crs(da),
        "prior_grid_crs_kind": da.attrs["crs_kind"],
        "prior_grid_registration": da.attrs.get("registration", ""),
        "prior_grid_cell_size": f"{dx:.8g} x {dy:.8g} {unit}",
        "prior_grid_shape": f"{da.sizes['y']} x {da.sizes['x']}",
        "prior_grid_nodata_fraction": float(da.attrs.get("nodata_fraction", 0.0)),
        "prior_grid_z_units": da.attrs.get("z_units_source", ""),
        "z_positive_source": g.z_positive,
        "z_sign_detection": g.z_reason,
        "z_sign_flipped": int(g.z_positive == "up"),
    }
    for k in ("crs_override", "crs_note", "lon_convention", "scale_offset"):
        if k in da.attrs:
            out[f"prior_grid_{k}"] = da.attrs[k]
    if g.warning:
        out["prior_grid_warning"] = g.warning
    if g.depth_note:
        out["prior_grid_depth_check"] = g.depth_note
    return out


_LAYERS_ABSENT = ("count, depth_median_m, depth_std_m, filled, uncertainty_m: a prior grid has no soundings and "
                  "states no uncertainty")
_LAND_ATTRS = {"long_name": "land (above sea level in the prior grid): no depth, depth_m is NaN",
               "flag_values": np.array([0, 1], np.int8), "flag_meanings": "not_land land"}


def _depth_vars(ds: xr.Dataset, depth: np.ndarray, land: np.ndarray, long_name: str) -> None:
    ds["depth_m"] = (("y", "x"), depth, {
        "standard_name": "sea_floor_depth_below_sea_surface", "units": "m", "positive": "down",
        "long_name": long_name})
    ds["land"] = (("y", "x"), land.astype(np.int8), dict(_LAND_ATTRS))
    ds.attrs["n_cells_land"] = int(land.sum())


def prior_dtm(path: str | Path, frame: LocalFrame, *, z_positive_hint: str | None = None, crs: str | None = None,
              variable: str | None = None, format: str | None = None, resolution_m: float | None = None,
              max_extent_m: float | None = DEFAULT_MAX_EXTENT_M, max_cells: int = DEFAULT_MAX_CELLS,
              max_read_bytes: float | None = None, z_units: str | None = None) -> xr.Dataset:
    """A prior grid as a reference DTM in ``frame`` (module docstring): ``depth_m`` positive down (land NaN),
    ``land`` (1 above sea level) + metadata. ``max_read_bytes``: refuse a file whose read needs more (default:
    the memory budget)."""
    g = load_prior(path, z_positive_hint=z_positive_hint, crs=crs, variable=variable, format=format,
                   z_units=z_units, max_read_bytes=max_read_bytes)
    return _single_dtm(g, frame, resolution_m, max_extent_m, max_cells)


def _single_dtm(g: PriorGrid, frame: LocalFrame, resolution_m, max_extent_m, max_cells) -> xr.Dataset:
    from hadal.grid.multibeam import add_geo

    ds, info = resample_to_frame(g.da, frame, resolution_m, max_extent_m=max_extent_m, max_cells=max_cells)
    depth, land = depth_and_land(ds["z"].values, g.z_positive)
    if not np.any(np.nan_to_num(depth, nan=0.0) > 0):
        raise InputError(f"{g.name}: no seafloor inside the map-frame area (every valid cell there is land or at "
                         "sea level)")
    ds = ds.drop_vars("z")
    _depth_vars(ds, depth, land, f"depth from the prior grid {g.name}, resampled bilinearly onto the map frame; "
                                 "NaN on land")
    ds.attrs.update({"dtm_source": "prior_grid", **_prior_attrs(g), "resampling": info["resampling"],
                     "n_cells_valid": int(np.isfinite(depth).sum()), "layers_absent": _LAYERS_ABSENT})
    if info["cropped_to_m"]:
        ds.attrs.update(crop_attrs(info, g.z_positive))
    return add_geo(ds, frame)


MOSAIC_RULE = ("prior grids mosaicked onto one map-frame grid at the finest grid's resolution (or "
               "grid.prior_resolution_m): each cell comes from the finest grid that has a value (depth or land) "
               "there, ties in dive.yaml listing order; coarser grids only fill cells the finer ones leave empty; "
               "layer prior_grid_source names the grid of each cell")


def prior_mosaic(grids: list[PriorGrid], frame: LocalFrame, *, resolution_m: float | None = None,
                 max_extent_m: float | None = DEFAULT_MAX_EXTENT_M, max_cells: int = DEFAULT_MAX_CELLS
                 ) -> xr.Dataset:
    """Several prior grids as one DTM (:data:`MOSAIC_RULE`); one grid: :func:`prior_dtm`'s product.

    Priority: finer native resolution first (:func:`native_resolution_m`), then listing order. The target cells
    are square at the finest resolution (or ``resolution_m``), over the union of the grids' outlines; when that
    exceeds ``max_cells`` the cell is coarsened to fit (recorded in ``prior_grid_mosaic_resolution_note``).
    ``prior_grid_source`` (int8) is the index in ``prior_grid_files`` of the grid each cell came from (-1: none);
    a grid that contributes no cell is still named, with ``0`` cells, in ``prior_grid_sources``.
    """
    import json

    from hadal.grid.multibeam import add_geo

    if len(grids) == 1:
        return _single_dtm(grids[0], frame, resolution_m, max_extent_m, max_cells)
    natives = [native_resolution_m(g.da) for g in grids]
    order = sorted(range(len(grids)), key=lambda i: (natives[i], i))
    res = float(resolution_m) if resolution_m else min(natives)
    boxes = [frame_bounds(g.da, frame, max_extent_m) for g in grids]
    bounds = [min(b[0][0] for b in boxes), min(b[0][1] for b in boxes), max(b[0][2] for b in boxes),
              max(b[0][3] for b in boxes)]
    note = ""
    n = ((bounds[2] - bounds[0]) / res + 2) * ((bounds[3] - bounds[1]) / res + 2)
    if n > max_cells:
        new = float(f"{res * math.sqrt(n / max_cells) * 1.01:.3g}")
        note = (f"the union of the grids at {res:g} m would be {n:,.0f} cells (grid.max_cells {max_cells:,}): "
                f"cells coarsened to {new:g} m")
        res = new
    spec = make_grid_spec(res, bounds, max_cells=max_cells, snap=True)
    depth = np.full((spec.ny, spec.nx), np.nan)
    land = np.zeros((spec.ny, spec.nx), bool)
    source = np.full((spec.ny, spec.nx), -1, np.int8)
    used = [0] * len(grids)
    for i in order:
        d, lnd = depth_and_land(sample_on_cells(grids[i].da, frame, spec.x, spec.y), grids[i].z_positive)
        free = source < 0
        take = free & (np.isfinite(d) | lnd)
        depth[take], land[take], source[take] = d[take], lnd[take], i
        used[i] = int(take.sum())
    decided = source >= 0
    if not np.any(np.nan_to_num(depth, nan=0.0) > 0):
        raise InputError(f"{', '.join(g.name for g in grids)}: no seafloor inside the map-frame area")
    rows, cols = np.flatnonzero(decided.any(axis=1)), np.flatnonzero(decided.any(axis=0))
    r0, r1, c0, c1 = rows[0], rows[-1] + 1, cols[0], cols[-1] + 1
    spec = make_grid_spec(res, (spec.x0 + c0 * res, spec.y0 + r0 * res, spec.x0 + c1 * res, spec.y0 + r1 * res),
                          max_cells=max_cells)
    depth, land, source = depth[r0:r1, c0:c1], land[r0:r1, c0:c1], source[r0:r1, c0:c1]
    ds = to_dataset(spec, {})
    names = [g.name for g in grids]
    _depth_vars(ds, depth, land, "depth from the prior grids " + ", ".join(names) + " mosaicked onto the map frame "
                                 "(bilinear in each); NaN on land")
    ds["prior_grid_source"] = (("y", "x"), source, {
        "long_name": "index of the prior grid each cell comes from (prior_grid_files order; -1 none)",
        "flag_values": np.arange(-1, len(grids), dtype=np.int8),
        "flag_meanings": " ".join(["none"] + [f"grid_{k}" for k in range(len(grids))])})
    per = [{"file": g.name, "priority": order.index(k) + 1, "resolution_m": natives[k], "crs": describe_crs(g.da),
            "z_positive": g.z_positive, "z_sign_detection": g.z_reason,
            "z_units": g.da.attrs.get("z_units_source", ""), "n_cells_used": used[k],
            **({"lon_convention": g.da.attrs["lon_convention"]} if "lon_convention" in g.da.attrs else {})}
           for k, g in enumerate(grids)]
    first = _prior_attrs(grids[order[0]])
    ds.attrs.update({
        "dtm_source": "prior_grid", **first,
        "prior_grid_file": ", ".join(names), "prior_grid_files": ", ".join(names),
        "prior_grid_format": "; ".join(g.da.attrs.get("format", "") for g in grids),
        "prior_grid_reader": "; ".join(sorted({g.da.attrs.get("reader", "") for g in grids})),
        "prior_grid_crs": "; ".join(describe_crs(g.da) for g in grids),
        "prior_grid_registration": "; ".join(g.da.attrs.get("registration", "") for g in grids),
        "prior_grid_mosaic": MOSAIC_RULE, "prior_grid_sources": json.dumps(per),
        "z_positive_source": "; ".join(f"{g.name}: {g.z_positive}" for g in grids),
        "z_sign_detection": "; ".join(f"{g.name}: {g.z_reason}" for g in grids),
        "z_sign_flipped": int(any(g.z_positive == "up" for g in grids)),
        "resampling": RESAMPLING, "n_cells_valid": int(np.isfinite(depth).sum()), "layers_absent": _LAYERS_ABSENT,
    })
    warn = [f"{g.name}: {g.warning}" for g in grids if g.warning]
    checks = [f"{g.name}: {g.depth_note}" for g in grids if g.depth_note]
    ds.attrs.pop("prior_grid_warning", None)
    ds.attrs.pop("prior_grid_depth_check", None)
    if warn:
        ds.attrs["prior_grid_warning"] = "; ".join(warn)
    if checks:
        ds.attrs["prior_grid_depth_check"] = "; ".join(checks)
    if note:
        ds.attrs["prior_grid_mosaic_resolution_note"] = note
    cropped = [g.name for g, b in zip(grids, boxes, strict=True) if b[1]]
    if cropped and max_extent_m:
        ds.attrs["prior_grid_cropped"] = f"{', '.join(cropped)} cropped to {max_extent_m / 1000:g} km around the origin"
    return add_geo(ds, frame)


def crop_attrs(info: dict[str, Any], pos: str) -> dict[str, Any]:
    """Product attributes of a crop (:func:`resample_to_frame` ``info``; ``pos`` the source's z sign):
    the crop width, the kept bounds (lon/lat), the fraction of the source's valid area and of its depth
    range (positive down) that is outside the crop."""
    c = info.get("crop", {})
    out: dict[str, Any] = {"prior_grid_cropped_to_m": info["cropped_to_m"]}
    if "area_fraction_lost" in c:
        out["prior_grid_crop_area_fraction_lost"] = round(c["area_fraction_lost"], 4)
    if "kept_lonlat" in c:
        lo0, lo1, la0, la1 = c["kept_lonlat"]
        out.update({"prior_grid_kept_lon_min": round(lo0, 5), "prior_grid_kept_lon_max": round(lo1, 5),
                    "prior_grid_kept_lat_min": round(la0, 5), "prior_grid_kept_lat_max": round(la1, 5)})

    def depth(r):
        return tuple(sorted((-r[1], -r[0]))) if pos == "up" else tuple(r)

    if "z_range_source" in c:
        d0, d1 = depth(c["z_range_source"])
        out["prior_grid_source_depth_min_m"], out["prior_grid_source_depth_max_m"] = d0, d1
        if "z_range_kept" in c:
            k0, k1 = depth(c["z_range_kept"])
            out["prior_grid_kept_depth_min_m"], out["prior_grid_kept_depth_max_m"] = k0, k1
            out["prior_grid_crop_depth_range_lost_fraction"] = round(
                ((d1 - d0) - (k1 - k0)) / (d1 - d0), 4) if d1 > d0 else 0.0
    return out


def sample_depth(path_or_da, frame: LocalFrame, x_m, y_m, *, z_positive_hint: str | None = None,
                 **read_kw) -> np.ndarray:
    """Prior-grid depth (positive down, bilinear) at map-frame points ``x_m, y_m`` (NaN outside/nodata/land)."""
    da = path_or_da if isinstance(path_or_da, xr.DataArray) else read_grid(path_or_da, **read_kw)
    da, _ = check_depth_plausible(da)
    pos, _ = z_positive(da, z_positive_hint)
    inv, _ = _transformers(da, frame)
    xx, yy = np.broadcast_arrays(np.asarray(x_m, float), np.asarray(y_m, float))
    sx, sy = inv(xx.ravel(), yy.ravel())
    v = bilinear(da, np.asarray(sx), np.asarray(sy)).reshape(xx.shape)
    return depth_and_land(v, pos)[0]
