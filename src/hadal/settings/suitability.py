"""Options of the ``suitability`` stage (section ``suitability`` of config/pipeline.yaml)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class SuitabilityParams(BaseModel):
    """Terrain suitability (TERCOM paper §3.1, §4.1.2): block std/entropy and the matching region."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    n_blocks_y: int = Field(44, ge=1, le=10_000, description="blocks south-north (paper: 44); reduced if the DTM is too small")
    n_blocks_x: int = Field(60, ge=1, le=10_000, description="blocks west-east (paper: 60); reduced if the DTM is too small")
    min_valid_fraction: float = Field(0.5, gt=0, le=1, description="minimum fraction of valid cells for a block to be evaluated")
    region_size_x_m: float = Field(5800.0, gt=0, le=10_000_000, description="matching-region width west-east in metres (paper: 5.8 km)")
    region_size_y_m: float = Field(3700.0, gt=0, le=10_000_000, description="matching-region height south-north in metres (paper: 3.7 km)")
    region_search_radius_m: float = Field(
        0.0, ge=0, le=10_000_000, description="(m) 0: region centred on the launch point; >0: best-scoring window centred within this radius"
    )
