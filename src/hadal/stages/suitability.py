"""Stage `suitability`: per-block terrain standard deviation and entropy of the reference DTM, proposed matching region.

Reads the ``dtm`` product, computes [TERCOM Eqs. 1-5] on an ``n_blocks_y x n_blocks_x`` block
grid (44 x 60 in the paper, §4.1.2; see :mod:`hadal.suitability`) and proposes a matching region
around the launch point (Fig. 7). Publishes ``suitability`` (``suitability.nc``).
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

from hadal.settings.suitability import SuitabilityParams as Params
from hadal.stages import Stage, StageContext, StageInputs
from hadal.store import ProductVersion

if TYPE_CHECKING:
    import xarray as xr


def skip_reason(ctx) -> str | None:
    """Why no block of the DTM can be evaluated (sparse ship soundings: mostly empty cells), naming the
    coverage (:func:`hadal.suitability.sparse_skip_reason`); ``None`` = run."""
    from hadal.products.readers import open_dtm
    from hadal.suitability import sparse_skip_reason

    pv = ctx.optional_upstream("dtm")
    if pv is None:
        return None
    p: Params = ctx.config.suitability
    return sparse_skip_reason(open_dtm(pv), p.n_blocks_y, p.n_blocks_x, p.min_valid_fraction)


def region_centre(dive, dtm: xr.Dataset, frame) -> tuple[float, float, str]:
    """Centre (lat, lon) of the proposed matching region: the launch point (TERCOM paper §4.1.2), else the
    map-frame origin; when that lies outside the DTM (a cast taken far from the prior map), the DTM's centre,
    with a note saying so."""
    import numpy as np

    launch = dive.launch
    lat, lon = ((launch.latitude_deg, launch.longitude_deg) if launch is not None
                else (frame.origin_latitude_deg, frame.origin_longitude_deg))
    x, y = (float(v) for v in frame.to_xy(lon, lat))
    xs, ys = dtm["x"].values, dtm["y"].values
    if xs.min() <= x <= xs.max() and ys.min() <= y <= ys.max():
        return lat, lon, ""
    cx, cy = float(xs.min() + xs.max()) / 2, float(ys.min() + ys.max()) / 2
    clon, clat = (float(v) for v in frame.to_lonlat(cx, cy))
    what = "launch point" if launch is not None else "map-frame origin"
    dist_km = float(np.hypot(x - cx, y - cy)) / 1000
    return clat, clon, (f"the {what} ({lat:.4f}, {lon:.4f}) is {dist_km:.0f} km from the DTM's centre, outside "
                        "the DTM: the matching region is centred on the DTM instead")


def _min_window(suit: xr.Dataset, dim: str, size_m: float) -> float:
    """``size_m``, or two block widths along ``dim`` when the blocks are wider than half the window."""
    import numpy as np

    c = suit[dim].values
    block = float(np.median(np.diff(c))) if c.size > 1 else float(suit[f"{dim}_max"].values.max()
                                                                   - suit[f"{dim}_min"].values.min())
    return max(float(size_m), 2.0 * abs(block))


def build_suitability(dtm: xr.Dataset, frame, launch_lat_deg: float, launch_lon_deg: float, p: Params) -> xr.Dataset:
    """Block statistics + lat/lon + proposed region, ready to write."""
    import numpy as np

    from hadal.matching.mapgrid import MapGrid
    from hadal.suitability import block_counts, coverage_text, propose_region_near, suitability_map

    g = MapGrid.from_any(dtm, name="dtm.nc")
    ny, nx = g.shape
    nby, nbx = block_counts(ny, nx, p.n_blocks_y, p.n_blocks_x)
    suit = suitability_map(g, nby, nbx, min_valid_fraction=p.min_valid_fraction)
    lx, ly = (float(v) for v in frame.to_xy(launch_lon_deg, launch_lat_deg))
    # a map coarser than the paper's 5.8 x 3.7 km window (a km-scale prior grid) gets a window of at least
    # two blocks each way, so a region exists on any map that has blocks at all (recorded below)
    sx, sy = _min_window(suit, "x", p.region_size_x_m), _min_window(suit, "y", p.region_size_y_m)
    region, far_note = propose_region_near(suit, lx, ly, sx, sy, p.region_search_radius_m)
    if far_note:  # sparse ship-track DTM: the launch point lies between tracks
        suit.attrs["region_coverage_note"] = f"{far_note} ({coverage_text(suit, g.depth_m, p.min_valid_fraction)})"
    xx, yy = np.meshgrid(suit["x"].values, suit["y"].values)
    lon, lat = frame.to_lonlat(xx, yy)
    suit["lat"] = (("y", "x"), np.asarray(lat), {"standard_name": "latitude", "units": "degrees_north"})
    suit["lon"] = (("y", "x"), np.asarray(lon), {"standard_name": "longitude", "units": "degrees_east"})
    suit["in_region"] = (("y", "x"), region.contains(xx, yy).astype(np.int8),
                         {"long_name": "block centre inside the proposed matching region", "flag_values": np.array([0, 1], np.int8),
                          "flag_meanings": "outside inside"})
    suit["crs"] = ((), np.int32(0), {"grid_mapping_name": "transverse_mercator", "crs_wkt": frame.crs.to_wkt(),
                                     "proj4": frame.crs.srs,
                                     "latitude_of_projection_origin": frame.origin_latitude_deg,
                                     "longitude_of_central_meridian": frame.origin_longitude_deg,
                                     "scale_factor_at_central_meridian": 1.0, "false_easting": 0.0, "false_northing": 0.0})
    for v in ("std_m", "entropy", "entropy_deficit", "n_valid", "in_region"):
        suit[v].attrs["grid_mapping"] = "crs"
        suit[v].attrs["coordinates"] = "lat lon"
    suit.attrs.update({
        "proposed_region": json.dumps(region.as_dict()),
        "launch_x_east_m": lx, "launch_y_north_m": ly,
        "map_frame_origin_latitude_deg": frame.origin_latitude_deg,
        "map_frame_origin_longitude_deg": frame.origin_longitude_deg,
        "method": "TERCOM paper (Challenger Deep) Eqs. 1-5, §4.1.2; variance normaliser m(n-1) as written; p_ij from depth positive down",
    })
    if (sx, sy) != (p.region_size_x_m, p.region_size_y_m):
        suit.attrs["region_size_note"] = (f"region window enlarged from {p.region_size_x_m:g} x {p.region_size_y_m:g} m "
                                          f"to {sx:g} x {sy:g} m (two blocks of this map)")
    if (nby, nbx) != (p.n_blocks_y, p.n_blocks_x):
        suit.attrs["comment"] = f"block grid reduced from {p.n_blocks_y} x {p.n_blocks_x} to {nby} x {nbx}: DTM has only {ny} x {nx} cells"
    return suit


def run(ctx: StageContext) -> dict[str, ProductVersion]:
    from hadal.products import write_netcdf  # lazy: the listing commands import this module's Params
    from hadal.products.readers import open_dtm

    p: Params = ctx.config.suitability
    dtm_pv = ctx.upstream("dtm")
    dtm = open_dtm(dtm_pv)
    frame = ctx.dive.frame("suitability")
    lat, lon, note = region_centre(ctx.dive, dtm, frame)
    if note:
        ctx.log.warning("suitability: %s", note)
    suit = build_suitability(dtm, frame, lat, lon, p)
    if note:
        suit.attrs["region_centre_note"] = note
    if "region_coverage_note" in suit.attrs:
        ctx.log.warning("suitability: %s", suit.attrs["region_coverage_note"])
    ctx.log.info("suitability: %d x %d blocks, region %s", suit.sizes["y"], suit.sizes["x"], suit.attrs["proposed_region"])
    with ctx.store.publish(ctx.dive_id, "suitability", parameters=ctx.params("suitability"), upstream=[dtm_pv]) as draft:
        write_netcdf(
            suit, draft.path / "suitability.nc",
            title=f"Terrain suitability for matching, dive {ctx.dive_id}",
            summary="Per-block terrain elevation standard deviation and topographic entropy of the reference DTM, "
                    "with the proposed terrain-matching region (TERCOM paper §3.1, §4.1.2).",
        )
        from hadal.products.geotiff import write_grid_cog  # block statistics as COGs in the map frame

        for v in COG_VARIABLES:
            write_grid_cog(suit, draft.path / f"suitability_{v}.tif", v)
    return {"suitability": draft.result}


#: suitability layers also written as Cloud-Optimized GeoTIFF (``suitability_<name>.tif``)
COG_VARIABLES = ("std_m", "entropy")


STAGE = Stage(
    name="suitability", products=("suitability",), inputs=StageInputs(upstream=("dtm",), frame_for=("suitability",)),
    options=Params, run=run, skip_reason=skip_reason,
    warm_imports=("hadal.suitability", "hadal.matching.mapgrid", "hadal.products.readers", "hadal.products.geotiff"),
)
