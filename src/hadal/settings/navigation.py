"""Options of the navigation smoother (:func:`hadal.navigation.smoother.smooth_positions`, the ``navigation``
product of the ``match`` stage; section ``match.navigation`` of config/pipeline.yaml), declared once. The science
takes the model as an argument (:mod:`hadal.navigation.smoother`'s module docstring explains every term)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field, field_validator


class SmootherOptions(BaseModel):
    """Options of :func:`hadal.navigation.smoother.smooth_positions` and its sources (:mod:`hadal.navigation.sources`),
    declared once (bounded numbers)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    current_sigma_m_s: float = Field(
        0.07, gt=0, le=5,
        description="stationary 1-sigma per axis of the depth-varying (baroclinic) part of the current the dead "
                    "reckoning does not see, m/s (also its prior at the first sample). Between two fixes only this "
                    "part widens the track's covariance (a constant drift is fixed by the two ends); the fixes see "
                    "the total drift, mostly the barotropic part. 0.07: calibrated on 200 simulated dives without "
                    "USBL (bench/bench_navigation_coverage.py, seed 2001: 0.1 covered 81 % of the samples within "
                    "1 sigma, drift paths being smoother than a 500 m-correlated random walk) and checked on held-out "
                    "dives (seeds 47, 1001, other ascent profiles) and the sample dive's seeds")
    barotropic_current_sigma_m_s: float = Field(
        0.05, gt=0, le=5,
        description="stationary 1-sigma per axis of the depth-coherent (barotropic) part of the current, m/s: "
                    "the same drift at every depth, decorrelating only with time (deep-ocean mean currents of a "
                    "few cm/s)")
    current_vertical_correlation_m: float = Field(
        500.0, gt=0, le=100000,
        description="vertical correlation length of the current (m): the drift velocity decorrelates as "
                    "exp(-|dz| / this) while the vehicle sinks or rises (the thermocline/first baroclinic mode "
                    "scale of the upper ocean, 500-1000 m)")
    current_correlation_time_s: float = Field(
        21600.0, gt=0, le=1e7,
        description="correlation time of the current at a fixed depth (s): exp(-dt / this); 6 h, half the "
                    "semidiurnal tidal period")
    position_random_walk_m_per_sqrt_s: float = Field(
        0.1, ge=0, le=100,
        description="unreferenced steps (DR held): position random walk beyond the current, 1-sigma per axis per "
                    "sqrt(s): the vehicle's own glide through the water while sinking/rising (0.1 m/sqrt(s): "
                    "about 12 m per axis over a 4 h descent)")
    dr_variance_m2_per_m: float = Field(
        0.1, ge=0, le=1000,
        description="referenced steps: dead-reckoning position variance per axis added per metre travelled "
                    "(m^2/m); 0.1: 14 m per axis after 2 km (the matched track's residual heading/scale error)")
    current_scale_range: tuple[float, float] = Field(
        (0.25, 4.0),
        description="the currents' strength is not known before the dive: their 1-sigma (current_sigma_m_s, "
                    "barotropic_current_sigma_m_s) is multiplied by a factor with a log-uniform prior over this "
                    "range, and the track is the mixture over the factor weighted by the fixes' likelihood "
                    "(currents known within a factor of 4 either way)")
    current_scale_points: int = Field(
        9, ge=1, le=33, description="grid points of that factor (1: no marginalisation, the factor is 1)")
    gate_probability: float = Field(
        0.999, gt=0.5, lt=1,
        description="chi-square gate (2 dof) of the fixes' leave-one-out residuals: a fix beyond it is rejected and named")
    max_rejections: int = Field(5, ge=0, le=100, description="at most this many fixes rejected by the gate")
    gnss_max_depth_m: float = Field(
        2.0, ge=0, le=50, description="GNSS fixes are used only where the vehicle is this shallow (at the surface)")
    gnss_uere_m: float = Field(
        4.0, gt=0, le=100,
        description="GNSS user-equivalent range error (m): a fix with an HDOP and no covariance gets a 1-sigma of "
                    "HDOP x this per axis")
    gnss_sigma_m: float = Field(5.0, gt=0, le=1000, description="1-sigma per axis (m) of a GNSS fix with neither covariance nor HDOP")
    usbl_sigma_m: float = Field(
        20.0, gt=0, le=10000,
        description="1-sigma per axis (m) of a USBL/LBL fix without a covariance (configure the system's accuracy)")
    fix_min_interval_s: float = Field(
        10.0, ge=0, le=3600,
        description="at most one fix per source in this interval (a 16 Hz table repeats a 1 Hz fix: its errors are "
                    "not independent)")
    launch_sigma_m: float = Field(
        7.0, gt=0, le=10000, description="1-sigma per axis (m) of the launch position (dive.yaml launch, a GNSS fix)")
    epoch_interval_s: float = Field(
        1.0, ge=0, le=600,
        description="the smoother's state is kept at epochs, at most one per this interval (s) of sample time "
                    "(plus every fix's sample, the first and the last sample); the steps between two epochs are "
                    "composed exactly and the samples between them interpolated (module docstring). 0: an epoch "
                    "at every sample (the full-rate smoother)")
    epoch_max_travel_m: float = Field(
        5.0, gt=0, le=10000,
        description="and at most this much dead-reckoned travel (m) between two epochs (a fast track keeps its "
                    "interpolation error small)")

    @field_validator("current_scale_range")
    @classmethod
    def _scale_range(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not (0.01 <= v[0] <= 1.0 <= v[1] <= 100.0):
            raise ValueError("current_scale_range must be (low, high) with 0.01 <= low <= 1 <= high <= 100")
        return v
