"""Options of the ``match`` stage (section ``match`` of config/pipeline.yaml): the TERCOM search
(:class:`TercomOptions`; :func:`hadal.matching.tercom`, :func:`hadal.matching.refine_tercom`), the dead-reckoning
error model (:class:`DeadReckoningOptions`; :func:`hadal.matching.budget.uncertainty_budget`, the ``navigation``
product) and the stage's own (:class:`MatchParams`). The posterior fix's defaults are declared here once
(:func:`hadal.matching.posterior.posterior_fix` takes them as its keyword defaults)."""

from __future__ import annotations

from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from hadal.settings.navigation import SmootherOptions

#: posterior fix (:func:`hadal.matching.posterior.posterior_fix`): flag a mismatch when more posterior mass than this
#: lies outside the main mode (ambiguous), or would with the map's holes filled (over_holes)
MAX_MASS_OUTSIDE = 0.2
MAX_MASS_OUTSIDE_HOLES = 0.05
#: posterior fix: radius of the main mode (map cells) and the fewest profile samples it accepts
MODE_RADIUS_CELLS = 3.0
MIN_SAMPLES = 10
#: posterior drift with sample times: constant-velocity-bias segment (s) and the bias's prior sigma (m/s)
DRIFT_SEGMENT_S = 900.0
DRIFT_VELOCITY_SIGMA_M_S = 0.003


class TercomOptions(BaseModel):
    """Options of :func:`tercom` and :func:`refine_tercom`, declared once: the ``match`` stage's ``Params``
    extends this model; the functions take it (``options=``) or its fields as keywords."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    criterion: Literal["msd", "mad", "cor"] = Field("msd", description="TERCOM criterion (paper Eqs. 15-17); the paper uses MSD")
    estimate_bias: bool = Field(True, description="estimate a constant map-minus-measured depth bias at every offset")
    precision: Literal["double", "mixed"] = Field(
        "mixed", description="heading search: float32 screening of every heading + exact float64 check of the best 3 (mixed), or float64 throughout"
    )
    min_valid_fraction: float = Field(0.8, gt=0, le=1, description="minimum fraction of profile samples on valid map cells")
    exclusion_radius_m: float | None = Field(None, gt=0, le=10_000_000, description="neighbourhood (m) excluded when looking for the second optimum (default max(5 cells, 100 m))")
    mismatch_ratio: float = Field(1.2, ge=1, le=1000, description="warn when second-best / best MSD is below this ratio")
    refine_scale_range: float = Field(0.05, ge=0, lt=0.5, description="refinement: DR track scale searched within 1 +- this")
    refine_seeds: int = Field(12, ge=1, le=100, description="refinement: number of distinct coarse minima refined")


#: the :class:`TercomOptions` fields :func:`tercom`, :func:`tercom_direct` and :func:`refine_tercom` take
TERCOM_FIELDS = ("criterion", "estimate_bias", "precision", "min_valid_fraction", "exclusion_radius_m", "mismatch_ratio")
DIRECT_FIELDS = ("criterion", "estimate_bias", "min_valid_fraction")
REFINE_FIELDS = ("estimate_bias", "min_valid_fraction", "exclusion_radius_m", "mismatch_ratio", "refine_scale_range",
                 "refine_seeds")


class DeadReckoningOptions(BaseModel):
    """The dead-reckoning error model, declared once (the ``match`` stage's ``Params`` extends this model; the
    ``navigation`` product reads its defaults here)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    dr_error_fraction: float = Field(
        0.02, ge=0, lt=1,
        description="dead-reckoning error per distance dead-reckoned (1 sigma radial), for the fix uncertainty (the start is carried from where the terrain fixes the track) and the navigation product; "
                    "0.02: the DR-only error grown along the sample dive's bottom track is 1.2-2.3 % (median 1.6 %) of the distance on 10 generator seeds (bench/dr_uncertainty_tercom.py; compass bias 1-2.5 deg, speed scale 1-3 %)",
    )
    drift_random_walk_m_per_sqrt_s: float = Field(
        0.07, ge=0, le=100,
        description="posterior: the dead reckoning's random walk beyond the drift segments, 1-sigma per axis per sqrt(s) (from the navigation's specification: a velocity noise sigma_v correlated over tau_c gives sqrt(2 sigma_v^2 tau_c)); "
                    "it widens the main mode's covariance by the error carried from the terrain that fixes the track to the start. 0.07: 3 mm/s correlated over 5 min, the sample dive's DVL; 0: none",
    )
    dr_unreferenced_drift_m_per_sqrt_s: float = Field(
        5.6, ge=0, le=1000,
        description="navigation product without a match: while the dead reckoning has no velocity reference (unpowered descent and ascent, DR held) the vehicle drifts with the currents; "
                    "1-sigma radial error = this x sqrt(unreferenced seconds), a random walk (currents change with depth). 5.6: the TERCOM paper's 533 m descent drift in 3 h 35 min taken as the median "
                    "of a Rayleigh distribution (533 / sqrt(ln 2 x 12 900 s))",
    )


class PosteriorNoiseOptions(BaseModel):
    """The posterior fix's model of the residuals' along-track correlation
    (:func:`hadal.matching.posterior.posterior_fix`, module docstring *Correlated residuals*), declared once."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    correlation_model: Literal["hac", "acf", "ar1"] = Field(
        "hac",
        description="residual correlation along the track: 'hac' = the main mode's covariance is the HAC sandwich with the "
                    "residuals' autocorrelation (Geyer's initial positive sequence), the likelihood tempered as before; "
                    "'acf' = the same and the likelihood tempered by the effective sample size n / (1 + 2 sum rho_k); "
                    "'ar1' = the previous model (lag-1 AR(1) equivalent n (1 - rho) / (1 + rho), tempered Laplace covariance)",
    )
    correlation_max_lag: int = Field(
        50, ge=1, le=10_000, description="largest lag (samples) of the residual autocorrelation sum (also at most n / 4)")


class SearchEdgeOptions(BaseModel):
    """What happens when a terrain fix sits at the edge of its search (issue 47), declared once: the TERCOM/posterior
    heading or scale at a bound of its search, the MRF coarse optimum within ``mrf_edge_cells`` of its search radius.
    The search is widened once (``edge_widen_factor``, capped) and, if still at the edge, the fix is flagged
    (mismatch ``at_search_edge``, a named warning): its covariance is not a confident fix's."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    edge_retry: bool = Field(True, description="widen a search whose optimum sits at its edge once and search again")
    edge_widen_factor: float = Field(2.0, gt=1, le=5, description="the retry's search half-range = this x the first one (capped below)")
    edge_max_heading_range_deg: float = Field(30.0, gt=0, le=45, description="largest heading half-range of the retry, degrees")
    edge_max_scale_range: float = Field(0.2, gt=0, lt=0.5, description="largest scale half-range of the retry (1 +- this)")
    mrf_edge_cells: float = Field(1.0, ge=0, le=10, description="MRF: a coarse optimum within this many cells of the search radius is at the edge")
    mrf_edge_max_radius_cells: float = Field(60.0, gt=0, le=200, description="MRF: largest search radius of the retry, cells")


#: the :class:`SearchEdgeOptions` fields :func:`hadal.matching.mrf.mrf_refine` takes
MRF_EDGE_FIELDS = ("edge_retry", "edge_widen_factor", "mrf_edge_cells", "mrf_edge_max_radius_cells")


class MatchParams(TercomOptions, DeadReckoningOptions, PosteriorNoiseOptions, SearchEdgeOptions):
    """Terrain matching (TERCOM MSD search over the map, optional MRF fine matching).

    The search options are :class:`TercomOptions`, the dead-reckoning error model :class:`DeadReckoningOptions`,
    the posterior's residual correlation :class:`PosteriorNoiseOptions` and the search-edge handling
    :class:`SearchEdgeOptions` (declared once); this model adds the stage's own
    (search ranges, map smoothing, region, posterior, drift, MRF)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    resample_spacing_m: float | None = Field(None, ge=0.001, le=100_000, description="along-track profile spacing in metres (1 mm to 100 km; default: map resolution)")
    segment_m: float | None = Field(
        None, gt=0, le=10_000_000,
        description="match only the first segment_m metres of the bottom track (DR error grows along the track); null = the whole track, as in the paper",
    )
    heading_range_deg: float = Field(
        9.0, ge=0, le=45, description="search DR heading errors in +-this range (0: translation only, as in the paper)"
    )
    heading_step_deg: float = Field(
        0.5, ge=1e-4, le=45, description="heading search step in degrees (1e-4 to 45, at most heading_range_deg; the "
                                         "search's work and memory are checked against the resources section)")
    region: Literal["map", "suitability"] = Field("map", description="search the whole map or the suitability product's proposed region")
    dtm_smooth_sigma_cells: float | None = Field(
        None, ge=0, le=100,
        description="normalised Gaussian convolution of the DTM before matching (fills holes, suppresses sounding noise); null = 2 cells when > 10 % of the DTM is empty, else 1; 0 = never",
    )
    refine: bool = Field(
        True,
        description="refine the MSD fix below the map resolution (bilinear map, continuous start/heading/scale; a deviation from the paper, see hadal.matching.refine_tercom)",
    )
    mrf: bool = Field(False, description="refine the fix with MRF fine matching of a 2-D real-time terrain patch (MRF paper): the vehicle's own swath soundings (dive.yaml sources.vehicle_swath) placed by the fix, else the bottom track; a single-beam bottom track (< 50 % of the cells under it sounded) or a swath too narrow for the map's cells (< 50 % of its cells with four sounded neighbours) is recorded as not matchable by MRF and MRF is not run")
    mrf_patch_length_m: float | None = Field(
        None, gt=0, le=1_000_000,
        description="MRF on the vehicle's swath: the real-time terrain patch is the swath of the first this many metres of the bottom track (MRF moves the fix by one constant shift, which holds over a local patch, not over a track whose dead-reckoning error changes along it); null = 40 map cells, the MRF paper's patch (§4.3: 40 x 30 cells)",
    )
    mrf_swath_max_offset_m: float = Field(
        1000.0, gt=0, le=50_000,
        description="MRF on the vehicle's swath: soundings farther than this from every bottom-track sample (in the vehicle's dead-reckoned navigation) are not placed on the map (logged outside the bottom phase, or not positioned by the vehicle's navigation)",
    )
    scale_range: float = Field(0.0, ge=0, lt=0.5, description="search DR scale errors 1 +- this range (0: none)")
    scale_step: float = Field(0.01, ge=1e-5, le=0.5, description="scale search step (1e-5 to 0.5, at most scale_range)")
    mrf_max_shift_cells: float = Field(1.5, gt=0, le=100, description="MRF fine stage (linearised MRF paper Eqs. 7-13): shift search range per iteration, in map cells")
    mrf_max_total_shift_cells: float = Field(
        25.0, gt=0, le=100,
        description="MRF coarse stage: the exact data term is searched over shifts up to this many map cells from the TERCOM fix (25: the largest initial error the MRF paper reports results from, §4.3 Simulation 1; divergent at 30); a minimum beyond it is flagged",
    )
    mrf_prior: Literal["gibbs", "none"] = Field(
        "gibbs",
        description="MRF Gibbs neighbourhood prior (paper Eqs. 3-4): 'gibbs' matches the MAP real-time terrain with T from the soundings' noise (hadal.matching.mrf, deviation 3); 'none' the soundings as measured",
    )
    posterior: bool = Field(
        True,
        description="report the point-mass posterior fix (MAP, covariance, ellipses, mass outside the main mode; hadal.matching.posterior); false: the refined score minimum with the jackknife + dead-reckoning uncertainty",
    )
    max_mass_outside: float = Field(MAX_MASS_OUTSIDE, gt=0, lt=1, description="posterior: flag a mismatch (ambiguous) when more than this posterior mass lies outside the main mode (0.2: chosen on the real-terrain calibration bench, see hadal.matching.posterior)")
    max_mass_outside_holes: float = Field(MAX_MASS_OUTSIDE_HOLES, gt=0, lt=1, description="posterior: flag a mismatch (over_holes) when, were the map under its interior holes to fit the track as well as its valid part does, more than this posterior mass would lie outside the main mode")
    mode_radius_cells: float = Field(MODE_RADIUS_CELLS, gt=0, le=1000, description="posterior: radius of the main mode in map cells")
    min_samples: int = Field(MIN_SAMPLES, ge=3, le=10_000_000, description="posterior: flag profiles with fewer samples as too short")
    drift: bool = Field(True, description="posterior: estimate the dead-reckoning drift (a velocity bias, piecewise constant in time) jointly with the start, heading and scale")
    drift_segment_s: float = Field(DRIFT_SEGMENT_S, ge=10, le=1_000_000, description="posterior: duration of each constant-velocity-bias segment of the drift, seconds")
    drift_velocity_sigma_m_s: float = Field(DRIFT_VELOCITY_SIGMA_M_S, gt=0, le=10, description="posterior: prior standard deviation of the DR velocity bias in each segment, m/s")
    navigation: SmootherOptions = Field(
        default_factory=SmootherOptions,
        description="the navigation product's smoother over every position source (hadal.navigation.smoother)")

    @model_validator(mode="after")
    def _steps(self) -> MatchParams:
        if self.heading_range_deg > 0 and self.heading_step_deg > self.heading_range_deg:
            raise ValueError(f"heading_step_deg ({self.heading_step_deg:g}) is larger than heading_range_deg "
                             f"({self.heading_range_deg:g}): the search would try only 0 deg; use a smaller step "
                             "or heading_range_deg: 0")
        if self.scale_range > 0 and self.scale_step > self.scale_range:
            raise ValueError(f"scale_step ({self.scale_step:g}) is larger than scale_range ({self.scale_range:g}): "
                             "the search would try only scale 1; use a smaller step or scale_range: 0")
        return self
