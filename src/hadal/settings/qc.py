"""QARTOD thresholds, typed: of the sensor table (``ingest.qc``, :class:`VariableQC`, defaults :data:`DEFAULT_QC`;
the tests are :mod:`hadal.ingest.qc`) and of what ``derive`` computes (``derive.qc_thresholds``,
:class:`DerivedVariableQC`; defaults shipped in ``hadal/data/qc_derived.yaml``, :func:`load_qc_config`; the tests
are :mod:`hadal.qc_derived`)."""

from __future__ import annotations

import functools
import math
from collections.abc import Mapping
from importlib import resources
from typing import Any

import yaml
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from hadal.errors import ConfigError, first_validation_error


class VariableQC(BaseModel):
    """QARTOD test configuration of one variable (units: the variable's)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    fail_span: tuple[float, float] | None = Field(None, description="values outside (low, high) are flagged 4 (finite)")
    suspect_span: tuple[float, float] | None = Field(None, description="values outside (low, high) are flagged 3 "
                                                                        "(finite, inside fail_span)")
    #: values at or above this are flagged 4 (sensor saturation, e.g. SBE49 10 500 dbar)
    saturation: float | None = Field(None, description="values at or above this are flagged 4 (sensor saturation)")
    spike_suspect: float | None = Field(None, gt=0, description="spike test: suspect above this (variable's units)")
    spike_fail: float | None = Field(None, gt=0, description="spike test: fail above this (variable's units)")
    flat_line_suspect_s: float | None = Field(None, gt=0, le=31_536_000,
                                              description="flat line longer than this (s, up to a year): suspect")
    flat_line_fail_s: float | None = Field(None, gt=0, le=31_536_000,
                                           description="flat line longer than this (s, up to a year): fail")
    flat_line_tolerance: float = Field(0.0, ge=0, description="flat line: changes up to this count as flat")
    #: a channel with more than this fraction of its (non-fill) finite values outside the fail span is dead (a
    #: failed sensor or a unit mistake, mS/cm logged as S/m): flagged 4 throughout and named in a warning, the
    #: other channels are processed (degrade per channel, not per dive)
    max_fail_fraction: float = Field(0.5, ge=0, le=1)
    #: values that mean "no data" for this variable only, as logged (the source's units, before any conversion):
    #: e.g. -1 "no bottom" of an altimeter. Missing (flag 9) when they also lie outside ``fail_span`` once
    #: converted (a -1 temperature is a temperature). :data:`FILL_VALUES_ANY` apply to every variable.
    fill_values: tuple[float, ...] = Field((), max_length=32, description="per-variable fill values, as logged "
                                           "(source units): missing (flag 9) when outside fail_span")
    #: a record in which every one of at least this many finite values is the same number is a stuck or
    #: disconnected sensor (an altimeter writing 0.00 throughout, a temperature channel left at its last value):
    #: the channel is dead, flagged 4 throughout and named. This catches what the flat-line test cannot where it
    #: is not evaluated (binned casts have no time). None: not checked (pressure of an underway record is constant
    #: by design; positions of a stationary cast may be)
    constant_record_min_samples: int | None = Field(None, ge=3, le=1_000_000, description="a record whose every "
                                                    "one of at least this many values is identical is a stuck "
                                                    "sensor: dead channel, flagged 4 (null: not checked)")

    @model_validator(mode="after")
    def _spans(self) -> VariableQC:
        if self.fail_span and self.suspect_span:
            lo, hi = sorted(self.fail_span)
            slo, shi = sorted(self.suspect_span)
            if slo < lo or shi > hi:
                raise ValueError("suspect_span must lie inside fail_span")
        return self


def _q(**kw: Any) -> VariableQC:
    return VariableQC(**kw)


#: default thresholds (hadal vehicle; full-ocean-depth, 16 Hz CTD)
DEFAULT_QC: dict[str, VariableQC] = {
    "conductivity_s_m": _q(fail_span=(0.0, 7.0), suspect_span=(2.0, 6.5), spike_suspect=0.05, spike_fail=0.2,
                           flat_line_suspect_s=60, flat_line_fail_s=300, flat_line_tolerance=1e-6,
                           constant_record_min_samples=30),
    "temperature_its90_degc": _q(fail_span=(-2.5, 40.0), suspect_span=(-2.0, 35.0), spike_suspect=0.5,
                                 spike_fail=2.0, flat_line_suspect_s=60, flat_line_fail_s=300,
                                 flat_line_tolerance=1e-6, constant_record_min_samples=30),
    "pressure_ctd_dbar": _q(fail_span=(-10.0, 11_000.0), saturation=10_500.0, spike_suspect=5.0, spike_fail=20.0,
                            flat_line_suspect_s=60, flat_line_fail_s=300, flat_line_tolerance=1e-6),
    "pressure_gauge_dbar": _q(fail_span=(-10.0, 12_000.0), spike_suspect=5.0, spike_fail=20.0),
    "altitude_m": _q(fail_span=(0.0, 150.0), suspect_span=(0.0, 100.0), spike_suspect=10.0, spike_fail=50.0,
                     fill_values=(-1.0,), constant_record_min_samples=30),
    "heading_deg": _q(fail_span=(0.0, 360.0)),
    "pitch_deg": _q(fail_span=(-90.0, 90.0), suspect_span=(-45.0, 45.0), spike_suspect=10.0, spike_fail=30.0),
    "roll_deg": _q(fail_span=(-180.0, 180.0), suspect_span=(-45.0, 45.0), spike_suspect=10.0, spike_fail=30.0),
    "dr_east_m": _q(fail_span=(-100_000.0, 100_000.0)),
    "dr_north_m": _q(fail_span=(-100_000.0, 100_000.0)),
    "speed_m_s": _q(fail_span=(0.0, 10.0), suspect_span=(0.0, 3.0), spike_suspect=0.5, spike_fail=2.0),
    # optional columns (schemas/sensors.yaml optional_columns): GNSS and USBL fixes
    "gnss_latitude_deg": _q(fail_span=(-90.0, 90.0)),
    "gnss_longitude_deg": _q(fail_span=(-180.0, 360.0)),
    "gnss_east_variance_m2": _q(fail_span=(0.0, 1e8)),
    "gnss_north_variance_m2": _q(fail_span=(0.0, 1e8)),
    "usbl_latitude_deg": _q(fail_span=(-90.0, 90.0)),
    "usbl_longitude_deg": _q(fail_span=(-180.0, 360.0)),
    "usbl_east_variance_m2": _q(fail_span=(0.0, 1e8)),
    "usbl_north_variance_m2": _q(fail_span=(0.0, 1e8)),
    # optional column (schemas/sensors.yaml optional_columns): a Sea-Bird cast's own salinity (SeaSoft sal00)
    "practical_salinity_vendor": _q(fail_span=(0.0, 42.0), suspect_span=(2.0, 41.0), spike_suspect=0.3,
                                    spike_fail=1.0),
}


def _span(v: Any) -> tuple[float, float] | None:
    if v is None:
        return None
    lo, hi = (float(x) for x in v)
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise ValueError(f"a span must be [low, high] with finite low < high, not {list(v)}")
    return lo, hi


class DerivedVariableQC(BaseModel):
    """QARTOD thresholds of one variable (units: the variable's)."""

    model_config = ConfigDict(extra="forbid", allow_inf_nan=False)
    fail_span: tuple[float, float] | None = Field(None, description="outside [low, high]: flag 4 (impossible)")
    suspect_span: tuple[float, float] | None = Field(None, description="outside [low, high]: flag 3 (unusual)")
    spike_suspect: float | None = Field(None, gt=0, le=1e6, description="spike test: flag 3 above this")
    spike_fail: float | None = Field(None, gt=0, le=1e6, description="spike test: flag 4 above this")
    depends_on: list[str] = Field(default_factory=list, description="inputs whose worst flag is inherited")

    _v_spans = field_validator("fail_span", "suspect_span", mode="before")(classmethod(lambda cls, v: _span(v)))

    @model_validator(mode="after")
    def _nested(self) -> DerivedVariableQC:
        if self.fail_span and self.suspect_span:
            (lo, hi), (slo, shi) = self.fail_span, self.suspect_span
            if slo < lo or shi > hi:
                raise ValueError("suspect_span must lie inside fail_span")
        if self.spike_suspect and self.spike_fail and self.spike_fail < self.spike_suspect:
            raise ValueError("spike_fail must be >= spike_suspect")
        return self


class DerivedQCConfig(BaseModel):
    """The thresholds of ``qc_derived.yaml``: ``inputs`` (range checks on what derive reads) and ``derived``."""

    model_config = ConfigDict(extra="forbid")
    inputs: dict[str, DerivedVariableQC] = Field(default_factory=dict)
    derived: dict[str, DerivedVariableQC] = Field(default_factory=dict)

    def merged(self, overrides: Mapping[str, Any] | None) -> DerivedQCConfig:
        """A copy with ``overrides`` (``{variable: {field: value}}``, input or derived names) applied field by
        field over the defaults; a name that is neither is a :class:`ConfigError`."""
        if not overrides:
            return self
        inputs, derived = dict(self.inputs), dict(self.derived)
        for name, ov in overrides.items():
            ov = ov.model_dump(exclude_unset=True) if isinstance(ov, BaseModel) else dict(ov)
            table = derived if name in derived else inputs if name in inputs else None
            if table is None:
                raise ConfigError(f"derive.qc_thresholds: unknown variable {name!r} (known: "
                                  f"{', '.join(sorted(inputs) + sorted(derived))})")
            try:
                table[name] = DerivedVariableQC(**{**table[name].model_dump(), **ov})
            except ValidationError as exc:
                raise ConfigError(f"derive.qc_thresholds.{name}: {first_validation_error(exc)[1]}") from None
        return DerivedQCConfig(inputs=inputs, derived=derived)


@functools.lru_cache(maxsize=1)
def _default_config() -> DerivedQCConfig:
    text = resources.files("hadal").joinpath("data/qc_derived.yaml").read_text(encoding="utf-8")
    return DerivedQCConfig.model_validate(yaml.safe_load(text))


def load_qc_config(overrides: Mapping[str, Any] | None = None) -> DerivedQCConfig:
    """The shipped default thresholds (``hadal/data/qc_derived.yaml``) with ``overrides`` applied."""
    return _default_config().merged(overrides)

