"""Options of the ``derive`` stage (section ``derive`` of config/pipeline.yaml): pressure fusion, seawater, depth,
phases, the Sea-Bird processing chain and the binned profile (:mod:`hadal.ctd`, :mod:`hadal.depth`, :mod:`hadal.ctd.profile`)."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from hadal.errors import ConfigError
from hadal.settings.qc import DerivedVariableQC, load_qc_config


class DeriveParams(BaseModel):
    """Seawater and depth parameters (section ``derive`` of config/pipeline.yaml)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    latitude_deg: float | None = Field(None, ge=-90, le=90,
                                       description="latitude for gravity/depth; default: the dive's launch latitude, "
                                                   "else the cast header's NMEA/user latitude, else 45 (warned, "
                                                   "with the depth error it can cause, in the product metadata)")
    longitude_deg: float | None = Field(None, ge=-180, le=360,
                                        description="longitude for TEOS-10 absolute salinity; default: launch, else "
                                                    "the cast header, else 0")
    depth_integration: Literal["trapezoid", "rectangle"] = Field(
        "trapezoid", description="hydrostatic sum: trapezoid (1/(rho g) averaged over each interval) or "
                                 "rectangle (Eq. 12 as printed, rho and g of the interval's end sample)")
    accept_flags: list[Annotated[int, Field(ge=1, le=9)]] = Field(
        [1, 2, 3], description="QARTOD flags (1-9) of sensor values that are used")
    ctd_saturation_dbar: float = Field(10_500.0, ge=100, le=20_000,
                                       description="SBE49 pressure range (dbar, 100-20 000; saturates here)")
    saturation_margin_dbar: float = Field(5.0, ge=0, le=1000,
                                          description="use the gauge from saturation - margin up (dbar, 0-1000)")
    gauge_bias_window_dbar: tuple[Annotated[float, Field(ge=-100, le=20_000)], Annotated[float, Field(ge=-100, le=20_000)]] = Field(
        (6000.0, 10_400.0), description="CTD pressure range (dbar, -100 to 20 000) where the gauge-CTD gain and offset are fitted")
    min_bias_samples: int = Field(20, ge=1, le=100_000_000, description="fewer samples in the window: use the whole overlap")
    pressure_datum: Literal["gauge", "ctd"] = Field(
        "gauge", description="datum of pressure_dbar: gauge (CTD + bias where the CTD is used; the gauge is the "
                             "more accurate sensor) or ctd (gauge - bias where the CTD saturates)")
    pressure_fit: Literal["gain_offset", "offset"] = Field(
        "gain_offset", description="gauge vs CTD on the overlap: gain_offset (robust Huber fit gauge = a + b ctd) "
                                   "or offset (median difference only)")
    pressure_blend_dbar: float = Field(20.0, ge=0, le=1000, description="cross-over from CTD to gauge over this "
                                       "many dbar below the switch pressure (0-1000; 0: a hard switch)")
    estimate_pressure_lag: bool = Field(True, description="estimate the gauge-CTD time lag (regression on the "
                                                          "vertical speed) and shift the gauge by it")
    max_pressure_lag_s: float = Field(30.0, gt=0, le=600, description="largest gauge-CTD lag accepted (s, up to 600)")
    surface_start_dbar: float = Field(20.0, ge=0, le=1000, description="a record whose first pressure is deeper "
                                      "than this (dbar) gets the water above from a model: its own shallower "
                                      "samples, else the TEOS-10 standard ocean (warned, with the error estimate)")
    qc_thresholds: dict[str, DerivedVariableQC] = Field(
        default_factory=dict, description="QARTOD thresholds of derived variables and inputs overriding the shipped "
                                          "defaults (hadal/data/qc_derived.yaml; same keys, e.g. {depth_m: "
                                          "{fail_span: [-10, 11100]}})")
    nominal_sound_speed_m_s: float = Field(1500.0, ge=1300, le=1800,
                                           description="sound speed the altimeter assumes (m/s, 1300-1800)")
    profile_bin_dbar: float = Field(
        10.0, ge=1e-4, le=1000, description="pressure bin size of profile.nc (dbar, 1e-4 to 1000; the bins' memory is "
                                            "checked against resources.max_memory_gb)")
    profile_axis: Literal["pressure", "depth"] = Field(
        "pressure", description="vertical axis of profile.nc: pressure (profile_bin_dbar bins, coordinate "
                                "pressure_dbar) or depth (profile_bin_m bins of the hydrostatic depth depth_m, "
                                "with the bins' mean pressure as a variable)")
    profile_bin_m: float = Field(
        10.0, ge=1e-4, le=1000, description="depth bin size of profile.nc with profile_axis: depth (m, 1e-4 to "
                                            "1000; memory checked against resources.max_memory_gb)")
    overlying_profile: str | None = Field(
        None, min_length=1, max_length=4096,
        description="profile of the water above a record that does not start at the surface: a CSV (columns "
                    "pressure_dbar and temperature_its90_degc + practical_salinity, or density_kg_m3; other "
                    "units as 'name [unit]') or Sea-Bird .cnv file, path relative to the dive's raw directory "
                    "(or absolute), inside the dive like every source; monotonic pressure from within surface_start_dbar of the surface down to the "
                    "record's first sample (null: the record's own shallower samples, else the standard ocean)")
    phase_smoothing_s: float = Field(60.0, gt=0, le=86_400,
                                     description="depth smoothing before the phase segmentation (s, up to 1 day)")
    phase_speed_threshold_m_s: float = Field(0.2, gt=0, le=10,
                                             description="vertical speed separating transit/bottom (m/s, up to 10)")
    phase_deep_fraction: float = Field(0.5, gt=0, lt=1, description="bottom phase only below this x max depth")
    # --- Sea-Bird processing chain (hadal.ctd, SBEDataProcessing's steps); every step off, as in SeaSoft
    wild_edit: bool = Field(False, description="WildEdit conductivity, temperature and CTD pressure first "
                                               "(values beyond the pass-2 limit become missing)")
    wild_edit_std_pass_1: float = Field(2.0, gt=0, le=100, description="WildEdit pass-1 limit (std, 0-100)")
    wild_edit_std_pass_2: float = Field(20.0, gt=0, le=1000, description="WildEdit pass-2 limit (std, 0-1000)")
    wild_edit_scans_per_block: int = Field(100, ge=2, le=10_000_000, description="WildEdit scans per block (2-1e7)")
    wild_edit_min_delta: float = Field(0.0, ge=0, le=1e6, description="WildEdit keeps values within this distance "
                                                                      "of the block mean (channel units, 0-1e6)")
    filter_pressure_s: float | None = Field(None, gt=0, le=3600, description="Filter: low-pass time constant of "
                                            "CTD pressure (s, up to 3600; null: not filtered)")
    filter_temperature_s: float | None = Field(None, gt=0, le=3600, description="Filter: low-pass time constant "
                                               "of temperature (s, up to 3600; null: not filtered)")
    filter_conductivity_s: float | None = Field(None, gt=0, le=3600, description="Filter: low-pass time constant "
                                                "of conductivity (s, up to 3600; null: not filtered)")
    align_conductivity_s: float = Field(0.0, ge=-60, le=60, description="AlignCTD: advance of conductivity "
                                        "relative to pressure (s, -60 to 60; 0: none)")
    align_temperature_s: float = Field(0.0, ge=-60, le=60, description="AlignCTD: advance of temperature "
                                       "relative to pressure (s, -60 to 60; 0: none)")
    cell_thermal_mass: bool = Field(False, description="CellTM: correct conductivity for the cell's thermal mass")
    cell_thermal_mass_alpha: float = Field(0.03, gt=0, le=1, description="CellTM thermal anomaly amplitude alpha "
                                           "(0-1; SBE 9plus 0.03, SBE 19plus 0.04)")
    cell_thermal_mass_beta_inverse_s: float = Field(7.0, gt=0, le=1000, description="CellTM time constant 1/beta "
                                                    "(s, up to 1000; SBE 9plus 7, SBE 19plus 8)")
    loop_edit: bool = Field(False, description="LoopEdit: exclude slow-down and reversal scans from profile.nc "
                                               "(column loop_edit_bad)")
    loop_edit_min_velocity_type: Literal["fixed", "percent"] = Field(
        "fixed", description="LoopEdit criterion: fixed minimum velocity or percent of the mean speed")
    loop_edit_min_velocity_m_s: float = Field(0.25, ge=0, le=10, description="LoopEdit minimum velocity (m/s, 0-10)")
    loop_edit_window_s: float = Field(300.0, gt=0, le=86_400, description="LoopEdit mean-speed window (s, up to 1 day)")
    loop_edit_mean_speed_percent: float = Field(20.0, ge=0, le=100,
                                                description="LoopEdit percent of the mean speed (0-100)")
    loop_edit_remove_surface_soak: bool = Field(True, description="LoopEdit removes the surface soak")
    loop_edit_min_soak_depth_m: float = Field(5.0, ge=0, le=1000, description="LoopEdit minimum soak depth (m, 0-1000)")
    loop_edit_max_soak_depth_m: float = Field(20.0, ge=0, le=1000, description="LoopEdit maximum soak depth (m, 0-1000)")
    loop_edit_deck_pressure_offset: bool = Field(True, description="LoopEdit soak depths relative to the first scan")
    profile_source_bins: Literal["keep", "rebin"] = Field(
        "keep", description="a cast SeaSoft's BinAvg already binned by pressure or depth (header binavg_bintype/"
                            "binavg_binsize or '# interval = decibars: N'): keep its own bins in profile.nc (one "
                            "level per row, casts split at the deepest row) or rebin it like any record")
    profile_binning: Literal["floor", "seabird"] = Field(
        "floor", description="profile.nc bins: floor ([k, k+1) x bin, by phase) or seabird (BinAvg: centred on "
                             "k x bin, split at the deepest scan)")

    @field_validator("qc_thresholds")
    @classmethod
    def _qc(cls, v: dict[str, DerivedVariableQC]) -> dict[str, DerivedVariableQC]:
        try:
            load_qc_config(v)
        except ConfigError as exc:
            raise ValueError(str(exc)) from None
        return v

    @field_validator("overlying_profile")
    @classmethod
    def _overlying(cls, v: str | None) -> str | None:
        if v is not None and (not v.strip() or "\x00" in v):
            raise ValueError("overlying_profile must be a file path (not blank, no NUL character)")
        return v

    @field_validator("gauge_bias_window_dbar")
    @classmethod
    def _window(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not v[0] < v[1]:
            raise ValueError("gauge_bias_window_dbar must be (low, high) with low < high")
        return v
