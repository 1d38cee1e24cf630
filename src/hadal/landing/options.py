"""Options of the landing analysis (:func:`hadal.landing.sites.analyse_submap`), declared once; pydantic only, so
:class:`hadal.stages.landing.Params` (which extends them) is imported without the analysis."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field

from hadal.landing.limits import CELL_FRACTION_RULE, COARSE_CELL_LIMIT, TILE_CELLS


class AnalysisOptions(BaseModel):
    """Options of :func:`analyse_submap`, declared once: the ``landing`` stage's ``Params`` extends this model
    (validated and bounded; violations -> one-line ConfigError). Defaults are Sangekar et al.'s where the paper is safe."""

    model_config = ConfigDict(extra="forbid")
    min_site_radius_m: float = Field(0.3, gt=0, le=10, description="reject sites whose inscribed circle is smaller (m)")
    min_protrusion_height_m: float = Field(0.005, ge=0, le=0.1, description="protrusions below this are noise (m)")
    exclusion_step_m: float = Field(0.005, ge=1e-4, le=0.05, description="distance step of the Fig. 15 table (m)")
    local_slope_window_m: float = Field(0.1, gt=0, le=1.0,
                                        description="window of the local slope map (m; odd cells, >= 3)")
    protrusion_method: Literal["opening", "butterworth"] = Field(
        "opening", description="protrusion heights: opening (sees every rock narrower than the vehicle diagonal) "
                               "or the paper's Butterworth low-pass (Eq. 10)")
    protrusion_coarse_m: float = Field(0.05, gt=0, le=0.2, description="cell of the ground estimate of the opening (m)")
    block_m: float = Field(2.5, ge=0.5, le=50, description="block size of the protrusion analysis (m)")
    block_margin_m: float = Field(1.0, ge=0, le=10, description="overlap margin of each Butterworth block (m)")
    filter_order: int = Field(3, ge=1, le=10, description="Butterworth low-pass order (Eq. 10)")
    edge_correction: bool = Field(False, description="normalised low-pass next to gaps (the paper zero-fills)")
    fill_holes_max_m2: float = Field(0.01, ge=0, le=1.0, description="fill interior unmapped holes up to this area (m²)")
    max_cell_fraction: float = Field(
        CELL_FRACTION_RULE, gt=0, le=COARSE_CELL_LIMIT,
        description="refuse grid cells larger than this × vehicle width (rule 0.1; up to 0.2 is an explicit override "
                    "for coarser grids, reported as a warning)")
    default_sigma_m: float = Field(0.006, ge=0, le=0.1, description="elevation 1-σ where a laser cell has < 2 points "
                                   "(m; for the per-site landability probability)")
    workers: int = Field(1, ge=1, le=64, description="headings analysed in parallel threads")
    tile_cells: int = Field(TILE_CELLS, ge=10_000, le=10**9,
                            description="cells per row tile of the footprint-slope FFTs (long strips are never "
                                        "transformed whole)")
