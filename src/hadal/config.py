"""Pipeline configuration: one typed section per stage, loaded from YAML.

``config/pipeline.yaml`` in the repository holds the defaults with comments; a dive directory may
carry its own ``pipeline.yaml`` that overrides them, and the CLI accepts ``--config FILE``.
Every section is a pydantic model owned by its stage module (``hadal.stages.<stage>.Params``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError

from hadal.errors import ConfigError
from hadal.stages.derive import Params as DeriveParams
from hadal.stages.grid import Params as GridParams
from hadal.stages.ingest import Params as IngestParams
from hadal.stages.landing import Params as LandingParams
from hadal.stages.match import Params as MatchParams
from hadal.stages.suitability import Params as SuitabilityParams


class PipelineConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    ingest: IngestParams = Field(default_factory=IngestParams)
    derive: DeriveParams = Field(default_factory=DeriveParams)
    grid: GridParams = Field(default_factory=GridParams)
    suitability: SuitabilityParams = Field(default_factory=SuitabilityParams)
    match: MatchParams = Field(default_factory=MatchParams)
    landing: LandingParams = Field(default_factory=LandingParams)

    def section(self, stage: str) -> BaseModel | None:
        return getattr(self, stage, None)


def _deep_merge(base: dict[str, Any], over: dict[str, Any]) -> dict[str, Any]:
    out = dict(base)
    for k, v in over.items():
        out[k] = _deep_merge(out[k], v) if isinstance(v, dict) and isinstance(out.get(k), dict) else v
    return out


def load_config(*paths: str | Path | None) -> PipelineConfig:
    """Load and merge YAML files (later ones override earlier ones); missing ``None`` entries are skipped."""
    merged: dict[str, Any] = {}
    for p in paths:
        if p is None:
            continue
        p = Path(p)
        if not p.is_file():
            raise ConfigError(f"configuration file {p} does not exist")
        try:
            data = yaml.safe_load(p.read_text(encoding="utf-8")) or {}
        except yaml.YAMLError as exc:
            raise ConfigError(f"{p}: not valid YAML ({str(exc).splitlines()[0]})") from None
        if not isinstance(data, dict):
            raise ConfigError(f"{p}: expected a mapping of stage sections at the top level")
        merged = _deep_merge(merged, data)
    try:
        return PipelineConfig.model_validate(merged)
    except ValidationError as exc:
        e = exc.errors()[0]
        loc = ".".join(str(x) for x in e.get("loc", ()))
        raise ConfigError(f"invalid configuration at {loc}: {e.get('msg')}") from None
