"""Options of the ``ingest`` stage (section ``ingest`` of config/pipeline.yaml): which raw logs, gaps, QARTOD QC."""

from __future__ import annotations

from typing import Annotated, Literal

from pydantic import BaseModel, ConfigDict, Field

from hadal.settings.qc import DEFAULT_QC, VariableQC


class IngestParams(BaseModel):
    """Raw log ingest, time alignment and QARTOD QC (section ``ingest`` of config/pipeline.yaml)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    source: Literal["auto", "mcap", "csv", "cnv"] = Field(
        "auto", description="which raw logs make 'sensors': auto = MCAP when the dive lists one, else CSV, else "
                            "the first Sea-Bird cast of sources.cnv (CTD only; the other sensors' columns stay "
                            "empty, flag 9). Casts not used for 'sensors' are each ingested into the 'casts' "
                            "product; vehicle logs not used are listed in the metadata (ignored_sources), warned")
    merge_casts: bool = Field(
        False, description="with source cnv: concatenate all casts of sources.cnv into one time series in 'sensors' "
                           "(one instrument record split into files; every cast needs a time channel)")
    vehicle_config: str | None = Field(
        None, description="vehicle channel mapping (path relative to the dive directory); default: dive.yaml's "
                          "vehicle_config, else the packaged haidou mapping")
    max_gap_s: dict[str, Annotated[float, Field(gt=0, le=86_400)]] = Field(
        {"gauge": 2.0, "altimeter": 1.5, "attitude": 2.0, "position": 5.0},
        description="per sensor: no interpolation across gaps longer than this (s) -> NaN + flag 9 "
                    "(finite, > 0 and at most 86 400 s; raised to 1.5 sampling intervals, with a warning, when "
                    "shorter than that)")
    default_max_gap_s: float = Field(2.0, gt=0, le=86_400,
                                     description="gap limit (s, > 0, at most 1 day) of sensors not listed in max_gap_s")
    qc: dict[str, VariableQC] = Field(
        default_factory=lambda: {k: v.model_copy() for k, v in DEFAULT_QC.items()},
        description="QARTOD thresholds per variable (ioos_qc gross range / spike / flat line; units of the "
                    "variable); pressure_ctd_dbar.saturation flags the SBE49 saturation (10 500 dbar) as bad")
