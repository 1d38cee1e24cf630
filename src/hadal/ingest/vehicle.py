"""Vehicle channel/column mapping (``vehicle.yaml``): which MCAP topic / CSV column holds which variable, in
which unit and time format. Nothing about a particular vehicle is hard-coded in the readers.

Example (abridged from ``hadal/data/vehicles/haidou.yaml``)::

    vehicle: haidou
    time_base: ctd
    sensors:
      ctd:
        required: true
        mcap:
          topic: /haidou/ctd
          time: {field: log_time, format: unix_ns}
          fields:
            conductivity_s_m: {field: cond, units: S/m}
            temperature_its90_degc: {field: temp, units: degC_its90}
            pressure_ctd_dbar: {field: pres, units: dbar}
        csv:
          source: ctd                       # key of dive.yaml sources.csv
          time: {field: time, format: iso8601}
          fields:
            conductivity_s_m: {field: conductivity_mS_cm, units: mS/cm}
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from hadal.errors import ConfigError, first_validation_error
from hadal.ingest.units import CANONICAL_UNITS, TRANSFORMS, check_unit, normalise_unit

__all__ = ["TIME_FORMATS", "FieldMap", "TimeSpec", "McapSource", "CsvSource", "SensorConfig", "VehicleConfig",
           "load_vehicle_config", "default_vehicle_config_path"]

#: time formats understood by :func:`hadal.ingest.csv_reader.parse_time` (or any strftime pattern with '%')
TIME_FORMATS = ("unix_ns", "unix_ms", "unix_s", "iso8601", "ros_time")


class FieldMap(BaseModel):
    """One source field/column and the unit it is logged in; optionally a ``transform`` of several fields
    (``field`` is then the list of its inputs) and an ``offset`` added after the unit conversion."""

    model_config = ConfigDict(extra="forbid")
    field: str | list[str] = Field(description="message field (dotted for nested ROS 2 fields: pose.position.x) or "
                                               "CSV column; a list of them as the inputs of a 'transform'")
    units: str = Field(description="unit the value is logged in (of the transform's result when there is one), "
                                   "converted to the variable's unit")
    transform: str | None = Field(None, description="computation from several fields: " + ", ".join(TRANSFORMS),
                                  json_schema_extra={"examples": list(TRANSFORMS)})
    #: added to the value after the conversion to the variable's unit (e.g. -10.1325 dbar: absolute -> sea pressure)
    offset: float | None = Field(None, description="added after the unit conversion, in the variable's unit "
                                                   "(-10.1325: absolute -> sea pressure in dbar)")
    #: [latitude, longitude] of the origin of a ``latlon_to_*`` transform (default: the first valid fix)
    origin: tuple[float, float] | None = Field(None, description="[latitude, longitude] origin of the latlon_to_* "
                                                                 "transforms (default: the first valid fix)")

    #: values that mean "no measurement" in the source (an altimeter's -1 "no bottom", a logger's 9999): missing
    fill_values: list[float] | None = Field(None, max_length=16,
                                            description="source values that mean 'no measurement' (e.g. -1 for an "
                                                        "altimeter's 'no bottom', 9999): read as missing values, "
                                                        "before any transform or unit conversion")

    @model_validator(mode="after")
    def _check_transform(self) -> FieldMap:
        names = [self.field] if isinstance(self.field, str) else list(self.field)
        if not names or any(not n for n in names):
            raise ValueError("field names must not be empty")
        if self.transform is None:
            if not isinstance(self.field, str):
                raise ValueError("a list of fields needs a 'transform' that combines them")
            if self.origin is not None:
                raise ValueError("'origin' only applies to the latlon_to_* transforms")
            return self
        if self.transform not in TRANSFORMS:
            raise ValueError(f"unknown transform {self.transform!r}; known: {', '.join(TRANSFORMS)}")
        t = TRANSFORMS[self.transform][0]
        if t.n_inputs is not None and len(names) != t.n_inputs:
            raise ValueError(f"transform {t.name} takes {t.n_inputs} fields ({t.doc}), got {len(names)}")
        try:
            unit = normalise_unit(self.units)
        except ConfigError as exc:
            raise ValueError(str(exc)) from None
        if t.unit is not None and unit != t.unit:
            raise ValueError(f"transform {t.name} gives {t.unit}; set units: {t.unit}")
        if self.origin is not None and not t.name.startswith("latlon_"):
            raise ValueError("'origin' only applies to the latlon_to_* transforms")
        return self

    def inputs(self) -> list[str]:
        """The source field names (one, or a transform's inputs)."""
        return [self.field] if isinstance(self.field, str) else list(self.field)

    def label(self) -> str:
        """``field`` or ``transform(a, b, ...)`` for messages and metadata."""
        return self.field if isinstance(self.field, str) else f"{self.transform}({', '.join(self.field)})"


class TimeSpec(BaseModel):
    """Where the sample time is: an MCAP ``log_time`` (ns) or a field/column, and its format."""

    model_config = ConfigDict(extra="forbid")
    field: str = "log_time"
    #: unix_ns | unix_ms | unix_s | iso8601 | ros_time (a {sec, nanosec} sub-message, MCAP only) | strftime pattern
    format: str = "unix_ns"

    @field_validator("format")
    @classmethod
    def _fmt(cls, v: str) -> str:
        if v not in TIME_FORMATS and "%" not in v:
            raise ValueError(f"time format {v!r} is not one of {', '.join(TIME_FORMATS)} or a strftime pattern")
        return v


class _Source(BaseModel):
    model_config = ConfigDict(extra="forbid")
    time: TimeSpec = Field(default_factory=TimeSpec)
    fields: dict[str, FieldMap]
    #: optional boolean field/column: samples where it is false become NaN (e.g. altimeter ``valid``)
    valid_field: str | None = None

    @field_validator("fields")
    @classmethod
    def _vars(cls, v: dict[str, FieldMap]) -> dict[str, FieldMap]:
        if not v:
            raise ValueError("at least one field mapping is required")
        for var, fm in v.items():
            try:
                check_unit(var, fm.units)
            except ConfigError as exc:
                raise ValueError(str(exc)) from None
        return v


class McapSource(_Source):
    topic: str = Field(min_length=1)


class CsvSource(_Source):
    #: key of the dive's ``sources.csv`` mapping
    source: str = Field(min_length=1)
    delimiter: str = ","
    time: TimeSpec = Field(default_factory=lambda: TimeSpec(field="time", format="iso8601"))

    @field_validator("time")
    @classmethod
    def _csv_time(cls, v: TimeSpec) -> TimeSpec:
        if v.format == "ros_time":
            raise ValueError("time format 'ros_time' (a ROS sub-message) applies to MCAP sources only")
        return v


class SensorConfig(BaseModel):
    model_config = ConfigDict(extra="forbid")
    required: bool = False
    mcap: McapSource | None = None
    csv: CsvSource | None = None

    @model_validator(mode="after")
    def _some_source(self) -> SensorConfig:
        if self.mcap is None and self.csv is None:
            raise ValueError("a sensor needs an 'mcap' or a 'csv' mapping")
        if self.mcap and self.csv and set(self.mcap.fields) != set(self.csv.fields):
            raise ValueError("the 'mcap' and 'csv' mappings must give the same variables")
        return self

    def variables(self) -> list[str]:
        src = self.mcap or self.csv
        assert src is not None
        return list(src.fields)


class VehicleConfig(BaseModel):
    """A vehicle's sensors; ``time_base`` names the sensor whose sample times define the table (the CTD)."""

    model_config = ConfigDict(extra="forbid")
    vehicle: str = "unknown"
    time_base: str = "ctd"
    sensors: dict[str, SensorConfig]

    @model_validator(mode="after")
    def _check(self) -> VehicleConfig:
        if self.time_base not in self.sensors:
            raise ValueError(f"time_base sensor {self.time_base!r} is not among the sensors")
        seen: dict[str, str] = {}
        for name, s in self.sensors.items():
            for var in s.variables():
                if var in seen:
                    raise ValueError(f"variable {var!r} mapped by both {seen[var]!r} and {name!r}")
                seen[var] = name
        return self

    def variables(self) -> list[str]:
        """Mapped variables in the canonical column order."""
        mapped = {v for s in self.sensors.values() for v in s.variables()}
        return [v for v in CANONICAL_UNITS if v in mapped]

    def sensor_of(self, variable: str) -> str:
        for name, s in self.sensors.items():
            if variable in s.variables():
                return name
        raise KeyError(variable)


def default_vehicle_config_path() -> Path:
    """The packaged sample vehicle mapping (``hadal/data/vehicles/haidou.yaml``)."""
    return Path(__file__).resolve().parents[1] / "data" / "vehicles" / "haidou.yaml"


def load_vehicle_config(path: str | Path) -> VehicleConfig:
    """Read and validate a vehicle YAML; any problem is a one-line :class:`ConfigError` naming the file."""
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"vehicle config {p} does not exist")
    from hadal.yamlfile import parse_yaml_text, read_config_text

    data = parse_yaml_text(read_config_text(p, "vehicle config"), p)  # bounded: size, depth, aliases, scalars
    if not isinstance(data, dict):
        raise ConfigError(f"{p}: expected a mapping with 'sensors' at the top level")
    try:
        return VehicleConfig.model_validate(data)
    except ValidationError as exc:
        loc, msg, more = first_validation_error(exc)
        raise ConfigError(f"{p}: invalid vehicle config at {loc or '<top>'}: {msg}{more}") from None


SourceKind = Literal["mcap", "csv"]
