"""Options of the ``landing`` stage (section ``landing`` of config/pipeline.yaml): the analysis options of
:func:`hadal.landing.sites.analyse_submap` (:class:`AnalysisOptions`), the vehicle (:class:`Vehicle`, Table II of
Sangekar et al.) and the stage's own (:class:`LandingParams`)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

#: the cell-size rule (issue 15): cells at most 1/10 of the vehicle width (5 cm for Table II), so the
#: footprint width spans >= 10 cells, the [Landing Eq. 8] exclusion radii (0 .. b_u/2) >= 5 cells and the 0.1 m local-slope
#: window >= 3 cells (it never gets coarser than its physical size).
CELL_FRACTION_RULE = 0.1
#: hard limit with an explicit ``max_cell_fraction`` override (e.g. the real Takuyo raster, 0.10 m = 0.2 × 0.5 m):
#: the analysis runs and adds a warning to :attr:`LandingResult.warnings`; beyond it cells are refused outright
#: (the footprint is then only ~5 cells wide and the [Landing Eq. 8] discs 1-2 cells: the exclusions are meaningless).
COARSE_CELL_LIMIT = 0.2

#: cells per row tile of the footprint-slope FFTs (:class:`hadal.landing.exclusion.HeadingCorrelator`): ~1 M cells (a
#: 1024 x 1125 float32 transform fits the caches; measured on the 100 m x 10 m strip, 12 such tiles transform ~2x faster
#: than 3 tiles of 4 M cells, overlap included)
TILE_CELLS = 1_000_000

#: default work budget of one landing submap (cells x headings; about 10 minutes single-threaded)
DEFAULT_MAX_CELL_HEADINGS = 1e10


class Vehicle(BaseModel):  # the equations that use it: hadal.landing.vehicle.Vehicle (a subclass)
    """Physical properties of the landing vehicle (Table II of Sangekar et al.).

    The forces are derived from the masses with ``gravity_m_s2`` (65 kg and 62 kg give the paper's
    F_G = 637 N, F_B = 608 N, F_R = 29 N; with g = 9.81 m/s² [Landing Eq. 2] gives the paper's θc = 17.7°).
    """

    model_config = ConfigDict(extra="forbid", frozen=True)

    length_m: float = Field(1.7, gt=0, le=20, description="l_u, length of the landing vehicle (m)")
    width_m: float = Field(0.5, gt=0, le=10, description="b_u, width of the landing vehicle (m)")
    height_m: float = Field(0.40, gt=0, le=10, description="h_u, height of the landing vehicle (m)")
    mass_kg: float = Field(65.0, gt=0, le=1e5, description="mass; F_G = mass_kg * g (kg)")
    buoyancy_mass_kg: float = Field(62.0, gt=0, le=1e5, description="displaced water mass; F_B = buoyancy_mass_kg * g (kg)")
    cg_height_m: float = Field(0.25, ge=0, le=10, description="d_g, vertical distance from the skid to C_G (m)")
    cg_cb_distance_m: float = Field(0.05, gt=0, le=10, description="d_m, vertical distance between C_G and C_B (m)")
    gravity_m_s2: float = Field(9.81, ge=1.0, le=30.0, description="gravitational acceleration (m/s²)")
    drag_coefficient: float = Field(1.2, gt=0, le=5.0, description="C_d for a rectangular shape (Eq. 6)")
    water_density_kg_m3: float = Field(1025.0, ge=900.0, le=1300.0, description="ρ, sea-water density (Eq. 6)")

    @model_validator(mode="after")
    def _check(self) -> Vehicle:
        # ValueError, as pydantic expects: construction raises a ValidationError (a ValueError); the configuration
        # loaders turn it into a one-line ConfigError
        if self.mass_kg <= self.buoyancy_mass_kg:
            raise ValueError(
                f"vehicle mass {self.mass_kg} kg must exceed its buoyancy mass {self.buoyancy_mass_kg} kg "
                "(the landing concept needs negative buoyancy, F_R > 0)"
            )
        if self.righting_denominator_nm <= 0:
            raise ValueError(
                "vehicle has no righting moment: d_m*F_B - d_g*F_R must be > 0 "
                f"(got {self.righting_denominator_nm:.3f} N m); check cg_height_m / cg_cb_distance_m"
            )
        if self.width_m > self.length_m:
            raise ValueError(f"vehicle width {self.width_m} m exceeds its length {self.length_m} m")
        return self

    # ------------------------------------------------------------------ forces
    @property
    def force_gravity_n(self) -> float:
        """F_G (N)."""
        return self.mass_kg * self.gravity_m_s2

    @property
    def force_buoyancy_n(self) -> float:
        """F_B (N)."""
        return self.buoyancy_mass_kg * self.gravity_m_s2

    @property
    def net_force_n(self) -> float:
        """F_R = F_G - F_B, the net downward force (N)."""
        return self.force_gravity_n - self.force_buoyancy_n

    @property
    def righting_denominator_nm(self) -> float:
        """d_m F_B - d_g F_R (N m), the denominator of [Landing Eqs. 1, 2 and 7]."""
        return self.cg_cb_distance_m * self.force_buoyancy_n - self.cg_height_m * self.net_force_n


class AnalysisOptions(BaseModel):
    """Options of :func:`analyse_submap`, declared once: the ``landing`` stage's :class:`LandingParams` extends this model
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
    tile_cells: int = Field(TILE_CELLS, ge=10_000, le=10**9,
                            description="cells per row tile of the footprint-slope FFTs (long strips are never "
                                        "transformed whole)")


class LandingParams(AnalysisOptions):
    """Landing-site analysis parameters (defaults = Sangekar et al. where the paper is safe; every number bounded).

    The analysis options are :class:`AnalysisOptions` (declared there, once); this model
    adds the stage's own (vehicle, headings, work budget, thread count with 'auto', figures)."""

    model_config = ConfigDict(extra="forbid")
    vehicle: Vehicle = Field(default_factory=Vehicle, description="vehicle geometry and forces (Table II)")
    heading_step_deg: float = Field(5.0, ge=1.0, le=90, description="landing headings -90..90° in these steps")
    max_cell_headings: float = Field(
        DEFAULT_MAX_CELL_HEADINGS, ge=1e3, le=1e13,
        description="refuse a submap whose cells x headings exceed this (work budget, checked before allocating; "
                    "1e10 is about 10 minutes single-threaded)")
    workers: int = Field(0, ge=0, le=64, description="headings analysed in parallel threads (0 = auto: "
                         "min(4, CPU cores); each thread beyond the first needs ~24 bytes per cell)")
    figures: bool = Field(True, description="write PNG figures into the product")
    figure_processes: int | None = Field(
        None, ge=1, le=64,
        description="processes drawing the figures while the next submap is analysed (forked children beside the "
                    "stage's own, or in a flow the helpers hadal forks before it starts; null: 2 on a machine with 2 "
                    "or more cores where processes can be forked (Linux), else 1)")
