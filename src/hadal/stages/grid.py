"""Stage ``grid``: multibeam soundings -> reference DTM (``dtm``), laser submaps -> 10 mm grids (``laser_grids``).

Reads the raw files listed in ``dive.yaml`` (``sources.multibeam``: ``multibeam/em122_lineNN.xyz.gz``,
``sources.laser``: ``laser/submap_NN.ply``); no upstream product. Science in :mod:`hadal.grid`.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from hadal.dive import resolve_source
from hadal.errors import InputError, StageError
from hadal.grid.laser import G_RES_M, grid_laser
from hadal.grid.multibeam import add_geo, grid_multibeam
from hadal.grid.points import DEFAULT_MAX_CELLS
from hadal.grid.readers import read_point_cloud, read_soundings
from hadal.products.io import write_netcdf

if TYPE_CHECKING:
    from hadal.stages import StageContext
    from hadal.store import ProductVersion

PRODUCTS = ("dtm", "laser_grids")
UPSTREAM: tuple[str, ...] = ()


class Params(BaseModel):
    """Gridding parameters (section ``grid`` of config/pipeline.yaml)."""

    model_config = ConfigDict(extra="forbid")
    dtm_resolution_m: float = Field(20.0, gt=0, description="DTM cell size (m)")
    spike_removal: bool = Field(True, description="robust per-cell and nearest-neighbour spike tests")
    spike_k: float = Field(3.5, gt=0, description="per-cell test: reject |z - median| > k * max(1.4826 MAD, sigma_0)")
    spike_k_neighbourhood: float = Field(4.0, gt=0, description="nearest-neighbour test threshold (robust sigmas)")
    spike_neighbours: int = Field(16, ge=4, description="soundings in the nearest-neighbour test")
    spike_min_count: int = Field(5, ge=3, description="soundings a cell needs for the per-cell test")
    spike_floor_m: float = Field(0.5, ge=0, description="lower bound of the data-driven noise floor sigma_0 (m)")
    sor: bool = Field(False, description="also run open3d statistical outlier removal on the soundings")
    sor_neighbors: int = Field(16, ge=2)
    sor_std_ratio: float = Field(3.0, gt=0)
    fill_max_cells: int = Field(4, ge=0, description="fill interior holes up to this many cells (0 = never)")
    apriori_a_m: float = Field(0.5, ge=0, description="a-priori sounding sigma: constant part (m)")
    apriori_b: float = Field(0.001, ge=0, description="a-priori sounding sigma: fraction of depth (EM122 class)")
    prior_weight: float = Field(3.0, gt=0, description="pseudo-degrees of freedom of the a-priori sigma")
    laser_resolution_m: float = Field(G_RES_M, gt=0, description="laser grid cell size (m), paper g_res = 10 mm")
    laser_voxel_m: float | None = Field(None, gt=0, description="open3d voxel down-sampling before gridding (off)")
    laser_sor_neighbors: int = Field(20, ge=0, description="open3d statistical outlier removal neighbours (0 = off; ~10 s per million points on 2 cores)")
    laser_sor_std_ratio: float = Field(3.0, gt=0)
    laser_surface_tol_m: float = Field(0.02, gt=0, description="SOR candidates within this of their cell's surface stay")
    laser_frame: Literal["local", "map"] = Field(
        "local", description="'local': laser x/y are the laser survey's own frame (no geolocation, as the raw "
                             "contract says); 'map': they are the dive's map frame (grids get a CRS and lat/lon bounds)")
    max_cells: int = Field(DEFAULT_MAX_CELLS, gt=0, description="refuse grids with more cells than this")


def _frame_attrs(ctx: StageContext) -> dict:
    from hadal.products.io import dive_attributes  # launch position/time: ACDD extents of local-frame grids

    return {**dive_attributes(ctx.dive), "platform": ctx.dive.platform}


def _compress(ds) -> None:
    """gzip the (y, x) layers of large grids (a 25 m x 25 m submap at 10 mm is 6 M cells per layer)."""
    for v in ds.data_vars:
        if ds[v].dims == ("y", "x"):
            ny, nx = ds[v].shape
            ds[v].encoding.update({"compression": "gzip", "compression_opts": 4,
                                   "chunksizes": (min(ny, 512), min(nx, 512))})


def make_dtm(files: list[Path], frame, p: Params):
    """Read sounding files, project them into ``frame`` and grid them (returns the DTM Dataset)."""
    lon, lat, dep = [], [], []
    for f in files:
        df = read_soundings(f)
        lon.append(df["longitude_deg"].to_numpy())
        lat.append(df["latitude_deg"].to_numpy())
        dep.append(df["depth_m"].to_numpy())
    lon, lat, dep = np.concatenate(lon), np.concatenate(lat), np.concatenate(dep)
    x, y = frame.to_xy(lon, lat)
    ds = grid_multibeam(
        x, y, dep, p.dtm_resolution_m, remove_spikes=p.spike_removal, spike_k=p.spike_k,
        spike_k_neighbourhood=p.spike_k_neighbourhood, spike_neighbours=p.spike_neighbours, spike_min_count=p.spike_min_count,
        spike_floor_m=p.spike_floor_m, sor=p.sor,
        sor_neighbors=p.sor_neighbors, sor_std_ratio=p.sor_std_ratio, fill_max_cells=p.fill_max_cells,
        apriori_a_m=p.apriori_a_m, apriori_b=p.apriori_b, prior_weight=p.prior_weight, max_cells=p.max_cells,
    )
    ds = add_geo(ds, frame)
    _compress(ds)
    return ds


def run(ctx: StageContext) -> dict[str, ProductVersion]:
    p: Params = ctx.config.grid
    src = ctx.dive.sources
    if not src.multibeam and not src.laser:
        raise StageError(f"dive {ctx.dive_id!r} lists no multibeam or laser sources in dive.yaml; nothing to grid")
    params = ctx.params("grid")

    # compute everything first, then publish: a bad laser file must not leave a lone new dtm version
    dtm = mb_files = None
    if src.multibeam:
        mb_files = [resolve_source(ctx.raw_dir, rel) for rel in src.multibeam]
        for f in mb_files:
            if not f.is_file():
                raise InputError(f"multibeam file {f} listed in dive.yaml does not exist")
        dtm = make_dtm(list(ctx.progress.track(mb_files, "reading multibeam", total=len(mb_files))),
                       ctx.dive.frame(), p)
        ctx.log.info("dtm: %d x %d cells at %g m, %d soundings (%d spikes removed, %d cells filled)",
                     dtm.sizes["x"], dtm.sizes["y"], p.dtm_resolution_m, dtm.attrs["n_soundings_used"],
                     dtm.attrs["n_soundings_spikes"], dtm.attrs["n_cells_filled"])

    grids = []
    laser_files = [resolve_source(ctx.raw_dir, rel) for rel in src.laser]
    names = [f.stem for f in laser_files]
    if len(set(names)) != len(names):
        raise InputError(f"laser sources of dive {ctx.dive_id!r} have duplicate file names: {names}")
    for f in ctx.progress.track(laser_files, "gridding laser submaps", total=len(laser_files)):
        if not f.is_file():
            raise InputError(f"laser file {f} listed in dive.yaml does not exist")
        try:
            ds = grid_laser(read_point_cloud(f), p.laser_resolution_m, voxel_size_m=p.laser_voxel_m,
                            sor_neighbors=p.laser_sor_neighbors, sor_std_ratio=p.laser_sor_std_ratio,
                            surface_tol_m=p.laser_surface_tol_m,
                            max_cells=p.max_cells)
        except InputError as exc:
            msg = str(exc)
            raise InputError(msg if str(f) in msg else f"{f}: {msg}") from None
        ds.attrs["submap"] = f.stem
        if p.laser_frame == "map":
            ds = add_geo(ds, ctx.dive.frame(), latlon=False)
            ds["x"].attrs["long_name"] = "x (east) in the dive's map frame"
            ds["y"].attrs["long_name"] = "y (north) in the dive's map frame"
        _compress(ds)
        grids.append((f, ds))
        ctx.log.info("laser %s: %d x %d cells, %.0f%% mapped", f.stem, ds.sizes["x"], ds.sizes["y"],
                     100 * ds.attrs["mapped_fraction"])

    out: dict[str, ProductVersion] = {}
    if dtm is not None:
        with ctx.store.publish(ctx.dive_id, "dtm", parameters=params, inputs=mb_files,
                               extra={"summary": {k: dtm.attrs[k] for k in dtm.attrs if k.startswith("n_")}}) as draft:
            write_netcdf(
                dtm, draft.path / "dtm.nc",
                title=f"Reference DTM of dive {ctx.dive_id} from multibeam soundings",
                summary=("Multibeam soundings projected into the dive's transverse-Mercator map frame and gridded "
                         f"at {p.dtm_resolution_m:g} m: per-cell mean/median/count/std after robust spike removal, "
                         "standard uncertainty, small interior holes filled by harmonic interpolation (flagged)."),
                keywords="bathymetry, multibeam, digital terrain model",
                processing_level="L3 gridded", provenance_from=draft, **_frame_attrs(ctx),
            )
        out["dtm"] = draft.result
    if grids:
        with ctx.store.publish(ctx.dive_id, "laser_grids", parameters=params, inputs=laser_files) as draft:
            for f, ds in grids:
                write_netcdf(
                    ds, draft.path / f"{f.stem}.nc",
                    title=f"Laser elevation grid {f.stem} of dive {ctx.dive_id}",
                    summary=(f"Laser point cloud {f.name} filtered with open3d and resampled to a uniform "
                             f"{p.laser_resolution_m * 1000:g} mm lateral grid (Sangekar et al., SIII-A); cell mean "
                             "elevation, count and std; NaN = unmapped."),
                    keywords="bathymetry, laser, structured light, microbathymetry",
                    processing_level="L3 gridded", provenance_from=draft, **_frame_attrs(ctx),
                )
        out["laser_grids"] = draft.result
    return out
