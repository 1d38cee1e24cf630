"""Dive description (``dive.yaml`` in a raw dive directory): what was recorded, where and with what.

Example (the sample dive written by ``hadal synth``)::

    dive_id: haidou-challenger-deep
    platform: Haidou
    vehicle_config: vehicle.yaml          # channel/column mapping, relative to the dive directory
    launch: {time_utc: 2018-10-06T23:00:00Z, latitude_deg: 11.3371167, longitude_deg: 142.2097167}
    map_frame: {origin_latitude_deg: 11.33, origin_longitude_deg: 142.20}
    sources:
      mcap: [logs/haidou.mcap]
      csv: {ctd: csv/ctd.csv, gauge: csv/keller.csv, ...}
      cnv: []
      multibeam: [multibeam/em122_line01.xyz.gz, ...]
      laser: [laser/submap_01.ply, ...]
"""

from __future__ import annotations

import datetime as _dt
from pathlib import Path

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from hadal.errors import ConfigError, InputError
from hadal.geo import LocalFrame
from hadal.store import validate_name

DIVE_FILE = "dive.yaml"


class Launch(BaseModel):
    model_config = ConfigDict(extra="forbid")
    time_utc: _dt.datetime | None = None
    latitude_deg: float = Field(ge=-90, le=90)
    longitude_deg: float = Field(ge=-180, le=180)


class MapFrame(BaseModel):
    """Origin of the local transverse-Mercator frame used by grids and matching."""

    model_config = ConfigDict(extra="forbid")
    origin_latitude_deg: float = Field(ge=-90, le=90)
    origin_longitude_deg: float = Field(ge=-180, le=180)

    def frame(self) -> LocalFrame:
        return LocalFrame(self.origin_latitude_deg, self.origin_longitude_deg)


class Sources(BaseModel):
    """Raw files of the dive, relative to the dive directory."""

    model_config = ConfigDict(extra="forbid")
    mcap: list[str] = Field(default_factory=list)
    csv: dict[str, str] = Field(default_factory=dict)
    cnv: list[str] = Field(default_factory=list)
    multibeam: list[str] = Field(default_factory=list)
    laser: list[str] = Field(default_factory=list)


class Dive(BaseModel):
    """A raw dive directory's description (``dive.yaml``)."""

    model_config = ConfigDict(extra="forbid")
    dive_id: str
    platform: str = "unknown"
    vehicle_config: str | None = None
    launch: Launch
    map_frame: MapFrame | None = None
    sources: Sources = Field(default_factory=Sources)
    notes: str = ""

    @field_validator("dive_id")
    @classmethod
    def _valid_id(cls, v: str) -> str:
        from hadal.errors import StoreError

        try:
            return validate_name(v, "dive id")
        except StoreError as exc:
            raise ValueError(str(exc)) from None

    def frame(self) -> LocalFrame:
        """The map frame; defaults to one centred on the launch point."""
        if self.map_frame is not None:
            return self.map_frame.frame()
        return LocalFrame(self.launch.latitude_deg, self.launch.longitude_deg)


def load_dive(raw_dir: str | Path) -> tuple[Dive, Path]:
    """Read and validate ``<raw_dir>/dive.yaml``. Returns the model and the resolved directory."""
    raw = Path(raw_dir)
    f = raw / DIVE_FILE
    if not raw.is_dir():
        raise InputError(f"raw dive directory {raw} does not exist")
    if not f.is_file():
        raise InputError(f"{raw} has no {DIVE_FILE}; run 'hadal synth {raw}' for a sample dive or write one (see README)")
    try:
        data = yaml.safe_load(f.read_text(encoding="utf-8"))
    except yaml.YAMLError as exc:
        raise ConfigError(f"{f}: not valid YAML ({str(exc).splitlines()[0]})") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{f}: expected a mapping at the top level")
    try:
        dive = Dive.model_validate(data)
    except ValidationError as exc:
        raise ConfigError(f"{f}: {_first_error(exc)}") from None
    return dive, raw.resolve()


def resolve_source(raw_dir: Path, rel: str) -> Path:
    """Resolve a source path relative to the dive directory, refusing paths that escape it."""
    p = (raw_dir / rel).resolve()
    if raw_dir.resolve() not in p.parents and p != raw_dir.resolve():
        raise ConfigError(f"source path {rel!r} escapes the dive directory {raw_dir}")
    return p


def _first_error(exc: ValidationError) -> str:
    e = exc.errors()[0]
    loc = ".".join(str(x) for x in e.get("loc", ()))
    n = len(exc.errors())
    more = f" (+{n - 1} more)" if n > 1 else ""
    return f"{loc}: {e.get('msg')}{more}"


def find_dives(*dirs: str | Path, allow_empty: bool = False) -> list[Path]:
    """Dive directories named by ``dirs``: one with ``dive.yaml`` is a dive; one without is searched one
    level down for dive subdirectories (a cruise directory). Sorted within each directory."""
    out: list[Path] = []
    for d in (Path(x) for x in dirs):
        if not d.exists():
            raise InputError(f"raw dive directory {d} does not exist")
        if not d.is_dir():
            raise InputError(f"{d} is a file, not a raw dive directory")
        if (d / DIVE_FILE).is_file():
            out.append(d)
            continue
        try:
            subs = sorted(p for p in d.iterdir() if (p / DIVE_FILE).is_file())
        except OSError as exc:
            raise InputError(f"cannot list {d}: {exc.strerror or exc}") from None
        if not subs and not allow_empty:
            raise InputError(f"{d} has no {DIVE_FILE} and no dive subdirectories")
        out.extend(subs)
    seen: set[Path] = set()  # a dive named twice (DIR and DIR/dive) is processed once
    return [p for p in out if not (p.resolve() in seen or seen.add(p.resolve()))]
