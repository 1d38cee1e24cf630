"""Options of the ``report`` stage (section ``report`` of config/pipeline.yaml)."""

from __future__ import annotations

from pydantic import BaseModel, ConfigDict, Field


class ReportParams(BaseModel):
    """Dive report (HTML with embedded figures, also published as Prefect artifacts inside a flow)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    dpi: int = Field(110, ge=50, le=400, description="figure resolution (dots per inch)")
    figure_width_in: float = Field(10.0, gt=2, le=30, description="figure width in inches")
    max_points: int = Field(20000, ge=100, le=10_000_000, description="time series are thinned to at most this many points per figure")
    best_sites: int = Field(5, ge=1, le=100, description="number of best landing sites listed")
    figure_processes: int | None = Field(
        None, ge=1, le=64,
        description="processes drawing the figures (forked children beside the stage's own, or in a flow the helpers "
                    "hadal forks before it starts; null: 2 on a machine with 2 or more cores where processes can be "
                    "forked (Linux), else 1)")
    title: str | None = Field(None, description="report title (default: 'Dive report — <dive id>')")
