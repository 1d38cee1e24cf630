"""Options of the gridding stages ``dtm`` and ``laser`` (section ``grid`` of config/pipeline.yaml; each stage
uses its own fields, :data:`DTM_FIELDS` / :data:`LASER_FIELDS`)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

#: Largest grid (cells) built without an explicit ``max_cells``: 5e7 cells x ~5 float64 layers ~ 2 GB.
DEFAULT_MAX_CELLS = 50_000_000


class GridParams(BaseModel):
    """Gridding parameters (section ``grid`` of config/pipeline.yaml)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    dtm_resolution_m: Annotated[float, Field(gt=0, le=100_000)] | Literal["auto"] = Field(
        "auto", description="DTM cell size (m, > 0 up to 100 km; cells x layers are checked against resources.max_memory_gb), or 'auto': about twice the soundings' nearest-neighbour spacing, "
                            "on a 1-2-5 series (hadal.grid.multibeam.auto_resolution_m; 20 m for the sample dive)")
    spike_removal: bool = Field(True, description="robust per-cell and nearest-neighbour spike tests")
    spike_k: float = Field(3.5, gt=0, le=100, description="per-cell test: reject |z - median| > k * max(1.4826 MAD, sigma_0)")
    spike_k_neighbourhood: float = Field(4.0, gt=0, le=100, description="nearest-neighbour test threshold (robust sigmas)")
    spike_neighbours: int = Field(16, ge=4, le=1000, description="soundings in the nearest-neighbour test (4-1000)")
    spike_min_count: int = Field(5, ge=3, le=100_000, description="soundings a cell needs for the per-cell test")
    spike_floor_m: float = Field(0.5, ge=0, le=1000, description="lower bound of the data-driven noise floor sigma_0 (m)")
    sor: bool = Field(False, description="also run open3d statistical outlier removal on the soundings")
    sor_neighbors: int = Field(16, ge=2, le=1000, description="open3d SOR neighbours (2-1000)")
    sor_std_ratio: float = Field(3.0, gt=0, le=100, description="open3d SOR threshold (standard deviations)")
    fill_max_cells: int = Field(4, ge=0, le=1_000_000, description="fill interior holes up to this many cells (0 = never)")
    apriori_a_m: float = Field(0.5, ge=0, le=1000, description="a-priori sounding sigma: constant part (m)")
    apriori_b: float = Field(0.001, ge=0, le=1, description="a-priori sounding sigma: fraction of depth (EM122 class)")
    prior_weight: float = Field(3.0, gt=0, le=1e6, description="pseudo-degrees of freedom of the a-priori sigma")
    laser_resolution_m: Annotated[float, Field(gt=0, le=100)] | Literal["auto"] = Field(
        "auto", description="laser point-cloud grid cell size (m, > 0 up to 100 m; cells x layers are checked against resources.max_memory_gb), or 'auto': the paper's g_res = 10 mm when the "
                            "points are at least that dense, else the points' nearest-neighbour spacing (90 % "
                            "quantile; hadal.grid.laser.auto_resolution_m), recorded in the grid's "
                            "resolution_choice attribute")
    laser_voxel_m: float | None = Field(None, gt=0, le=100, description="open3d voxel down-sampling before gridding (m; off)")
    laser_sor_neighbors: int = Field(20, ge=0, le=1000, description="statistical outlier removal neighbours, open3d's rule (0 = off; about 1 s of CPU per million points)")
    laser_sor_std_ratio: float = Field(3.0, gt=0, le=100, description="laser SOR threshold (standard deviations)")
    laser_surface_tol_m: float = Field(0.02, gt=0, le=100, description="SOR candidates within this (m) of their cell's surface stay")
    laser_frame: Literal["local", "map"] = Field(
        "local", description="'local': laser x/y are the laser survey's own frame (no geolocation, as the raw "
                             "contract says); 'map': they are the dive's map frame (grids get a CRS and lat/lon bounds)")
    max_cells: int = Field(DEFAULT_MAX_CELLS, gt=0, le=10_000_000_000,
                           description="refuse grids with more cells than this (the memory budget, resources.max_memory_gb, "
                                       "is checked as well)")
    prior_resolution_m: float | None = Field(
        None, ge=0.001, le=100_000, description="cell size (m, 1 mm to 100 km) of a DTM made from a prior grid (default: the grid's native "
                                "resolution, see hadal.grid.prior)")
    prior_max_extent_km: float = Field(
        2000.0, gt=0, le=40_000, description="geographic/projected prior grids are cropped to a square this wide (km) around "
                                  "the map frame origin, where the dive's transverse-Mercator frame is accurate "
                                  "(scale error ~1e-4 at 1000 km off its meridian, ~1e-3 at 3000 km); a crop logs a "
                                  "WARNING and the dtm records the kept lon/lat bounds and the fraction of the source "
                                  "area and depth range lost (prior_grid_kept_*, prior_grid_crop_*)")
    prior_fill: bool = Field(
        False, description="with multibeam soundings: fill the DTM's empty cells from the prior grid (filled = 2); "
                           "default: the prior grid is not used (multibeam wins)")
    zarr: bool = Field(
        False, description="also write each grid (dtm.nc, the laser grids) as a Zarr store <name>.zarr beside "
                           "it: the same values and CF attributes, chunked (needs the optional zarr package: "
                           "pip install 'hadal[zarr]')")
    zarr_chunk: int = Field(512, ge=16, le=8192, description="Zarr chunk size along y and x (cells, 16-8192)")

    @field_validator("zarr")
    @classmethod
    def _zarr_installed(cls, v: bool) -> bool:
        import importlib.util

        if v and importlib.util.find_spec("zarr") is None:
            raise ValueError("grid.zarr is on but the zarr package is not installed (pip install 'hadal[zarr]')")
        return v


#: the ``grid`` fields the ``laser`` stage uses (its fingerprint and manifest); the ``dtm`` stage uses the others
LASER_FIELDS: tuple[str, ...] = ("laser_resolution_m", "laser_voxel_m", "laser_sor_neighbors", "laser_sor_std_ratio",
                                 "laser_surface_tol_m", "laser_frame", "max_cells", "zarr", "zarr_chunk")
#: the ``grid`` fields the ``dtm`` stage uses
DTM_FIELDS: tuple[str, ...] = tuple(f for f in GridParams.model_fields if not f.startswith("laser_"))
