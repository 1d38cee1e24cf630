"""The variable registry: every variable of every product declared once in ``schemas/variables.yaml``.

The product writers (:func:`hadal.products.io.write_parquet`, :func:`hadal.products.io.write_netcdf`) take each
variable's CF attributes (``units``, ``standard_name``, ``long_name``, ``positive``, ``cell_methods``, flags,
``coverage_content_type``) from here; a variable the registry does not declare is refused with a one-line
:class:`UndeclaredVariableError` instead of being given attributes guessed from its name.

A variable may have a ``grid`` block: its attributes as a layer of a y/x map grid (seafloor products, where
``depth_m`` is the seafloor depth and ``count`` counts soundings). ``patterns`` declare names made from another
variable's name (``*_qc``: the QARTOD flag of ``{base}``); the base must itself be declared.
"""

from __future__ import annotations

import fnmatch
import functools
from collections.abc import Mapping
from importlib.resources import files
from typing import Annotated, Any, Literal

import yaml
from pydantic import BaseModel, ConfigDict, Field, StringConstraints, ValidationError, model_validator

from hadal.errors import HadalError, first_validation_error

#: where the registry lives (package data of ``hadal.schemas``)
REGISTRY_FILE = "variables.yaml"

_Name = Annotated[str, StringConstraints(pattern=r"^[A-Za-z][A-Za-z0-9_]{0,63}$")]
_Text = Annotated[str, StringConstraints(min_length=1, max_length=300)]
_Short = Annotated[str, StringConstraints(min_length=1, max_length=120)]
_Flags = Annotated[list[int], Field(min_length=1, max_length=32)]
_Coverage = Literal["image", "thematicClassification", "physicalMeasurement", "auxiliaryInformation",
                    "qualityInformation", "referenceInformation", "modelResult", "coordinate"]


class UndeclaredVariableError(HadalError, ValueError):
    """A product writer was given a variable that ``schemas/variables.yaml`` does not declare (a contract error of
    the code that made the product: declare the variable, with its units and standard name, in the registry)."""


#: the attributes a registry entry may give a variable (written into the product files)
CF_KEYS = ("units", "standard_name", "long_name", "positive", "axis", "cell_methods", "coverage_content_type",
           "flag_values", "flag_masks", "flag_meanings", "comment")


class VariableAttrs(BaseModel):
    """CF attributes of a variable (all optional: a ``grid`` block overrides only what it names)."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    units: Annotated[str, StringConstraints(max_length=40)] | None = None
    standard_name: _Short | None = None
    long_name: _Text | None = None
    positive: Literal["down", "up"] | None = None
    axis: Literal["X", "Y", "Z", "T"] | None = None
    cell_methods: _Short | None = None
    coverage_content_type: _Coverage | None = None
    flag_values: _Flags | None = None
    flag_masks: _Flags | None = None
    flag_meanings: _Text | None = None
    comment: _Text | None = None

    @model_validator(mode="after")
    def _flags(self) -> VariableAttrs:
        n = len(self.flag_values or self.flag_masks or [])
        if n and (self.flag_meanings is None or len(self.flag_meanings.split()) != n):
            raise ValueError("flag_meanings must name every flag value/mask (one word each)")
        return self

    def cf_attrs(self) -> dict[str, Any]:
        return {k: getattr(self, k) for k in CF_KEYS if getattr(self, k) is not None}


class VariableSpec(VariableAttrs):
    """One declared variable: its CF attributes plus the contract fields (products, dtype, valid range)."""

    long_name: _Text
    products: Annotated[list[_Name], Field(max_length=20)]
    dtype: _Short | None = None
    valid_min: float | None = None
    valid_max: float | None = None
    #: the data's precision in ``units``: NetCDF products store the variable as float32 when float32's rounding
    #: (half a unit in the last place at the largest value) stays within half of it (:func:`storage_dtype`)
    precision: float | None = Field(None, gt=0, le=1e6)
    no_cf_standard_name: bool = False
    grid: VariableAttrs | None = None

    @model_validator(mode="after")
    def _consistent(self) -> VariableSpec:
        if self.no_cf_standard_name and (self.standard_name or (self.grid and self.grid.standard_name)):
            raise ValueError("no_cf_standard_name is set but a standard_name is given")
        if self.valid_min is not None and self.valid_max is not None and self.valid_min > self.valid_max:
            raise ValueError("valid_min > valid_max")
        return self

    def attrs(self, on_grid: bool = False) -> dict[str, Any]:
        """CF attributes of the variable (as a y/x map-grid layer with ``on_grid``)."""
        out = self.cf_attrs()
        if on_grid and self.grid is not None:
            out.update(self.grid.cf_attrs())
        return out


class PatternSpec(VariableAttrs):
    """Names made from a declared variable's name (``pattern`` with one ``*``; ``{base}`` in the long_name)."""

    pattern: Annotated[str, StringConstraints(pattern=r"^[A-Za-z0-9_]*\*[A-Za-z0-9_]*$")]
    long_name: _Text
    products: Annotated[list[_Name], Field(max_length=20)]


class Registry(BaseModel):
    """``schemas/variables.yaml``."""

    model_config = ConfigDict(extra="forbid", frozen=True)
    version: Literal[1]
    standard_name_vocabulary: _Short
    variables: Annotated[dict[_Name, VariableSpec], Field(min_length=1, max_length=2000)]
    patterns: Annotated[list[PatternSpec], Field(max_length=50)] = []

    def find(self, name: str) -> VariableSpec | None:
        """The declaration of ``name`` (a pattern's is instantiated for the name), or ``None``."""
        spec = self.variables.get(name)
        if spec is not None:
            return spec
        for p in self.patterns:
            if fnmatch.fnmatchcase(name, p.pattern):
                pre, post = p.pattern.split("*")
                base = name[len(pre): len(name) - len(post)]
                if base not in self.variables:
                    continue
                data = p.model_dump(exclude={"pattern"}, exclude_none=True)
                data["long_name"] = p.long_name.format(base=base)
                return VariableSpec.model_validate(data)
        return None

    def spec(self, name: str, where: str = "") -> VariableSpec:
        """The declaration of ``name``; :class:`UndeclaredVariableError` when there is none."""
        spec = self.find(name)
        if spec is None:
            at = f"{where}: " if where else ""
            raise UndeclaredVariableError(
                f"{at}variable {name!r} is not declared in hadal.schemas/{REGISTRY_FILE} (declare its units, "
                "standard_name and long_name there; the writers do not guess attributes from names)")
        return spec

    def attrs(self, name: str, on_grid: bool = False, where: str = "") -> dict[str, Any]:
        """CF attributes of ``name`` (raises :class:`UndeclaredVariableError` for an undeclared one)."""
        return self.spec(name, where).attrs(on_grid)


def parse_registry(data: Any, source: str = REGISTRY_FILE) -> Registry:
    """Validate a loaded registry mapping (one-line :class:`UndeclaredVariableError` on a malformed one)."""
    try:
        return Registry.model_validate(data)
    except ValidationError as exc:
        loc, msg, more = first_validation_error(exc)
        raise UndeclaredVariableError(f"{source}: {loc}: {msg}{more}") from None


@functools.lru_cache(maxsize=1)
def registry() -> Registry:
    """The installed registry (``hadal.schemas/variables.yaml``), loaded and validated once per process."""
    p = files("hadal.schemas") / REGISTRY_FILE
    if not p.is_file():
        raise UndeclaredVariableError(f"hadal.schemas/{REGISTRY_FILE} (the variable registry) is missing from the "
                                      "installation")
    return parse_registry(yaml.safe_load(p.read_text(encoding="utf-8")), f"hadal.schemas/{REGISTRY_FILE}")


def variable_attrs(name: str, on_grid: bool = False, where: str = "") -> dict[str, Any]:
    """CF attributes of the declared variable ``name`` (see :meth:`Registry.attrs`)."""
    return registry().attrs(name, on_grid, where)


#: float32 keeps 24 significant bits: rounding a value v to float32 moves it by at most |v| * 2**-24
FLOAT32_RELATIVE_ROUNDING = 2.0 ** -24


def storage_dtype(name: str, values: Any) -> str | None:
    """``"float32"`` when ``schemas/variables.yaml`` declares a ``precision`` for ``name`` and rounding the finite
    ``values`` (float64) to float32 moves none of them by more than half that precision, else ``None`` (keep the
    dtype). E.g. depths to 11 000 m at 1 cm: float32 moves them by at most 0.66 mm."""
    import numpy as np

    spec = registry().find(name)
    if spec is None or spec.precision is None:
        return None
    v = np.asarray(values)
    if v.dtype != np.float64:
        return None
    finite = np.abs(v[np.isfinite(v)])
    top = float(finite.max()) if finite.size else 0.0
    if top > float(np.finfo(np.float32).max) or top * FLOAT32_RELATIVE_ROUNDING > spec.precision / 2:
        return None
    return "float32"


def has_no_cf_standard_name(name: str) -> bool:
    """The registry declares ``name`` with ``no_cf_standard_name: true`` (the CF table has no entry for it)."""
    spec = registry().find(name)
    return bool(spec is not None and spec.no_cf_standard_name)


#: registry attributes that describe NetCDF variables only (not written into Parquet field metadata)
_NETCDF_ONLY = ("coverage_content_type", "axis")


def _field_text(v: Any) -> str:
    return " ".join(map(str, v)) if isinstance(v, (list, tuple)) else str(v)


def column_attrs(name: str, given: Mapping[str, Any] | None = None, *, where: str = "") -> dict[str, str]:
    """CF attributes of a column: the ones ``schemas/variables.yaml`` declares, the caller's winning. A column
    the registry does not declare raises :class:`hadal.registry.UndeclaredVariableError`."""
    out = {k: _field_text(v) for k, v in variable_attrs(name, where=where).items() if k not in _NETCDF_ONLY}
    out.update({k: str(v) for k, v in (given or {}).items() if v is not None})
    return out
