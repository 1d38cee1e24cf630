"""Explicit unit conversions for ingest; every conversion applied is returned as a record for the metadata.

Each hadal variable has one canonical unit (its name suffix). A vehicle config declares the unit each
source field is logged in; :func:`convert` maps it to the canonical unit with a factor/offset from the
tables below or raises :class:`~hadal.errors.ConfigError` for an unknown or incompatible unit.

Temperature scales: IPTS-68 -> ITS-90 uses T90 = T68 / 1.00024 (Saunders 1990, "The International
Temperature Scale of 1990, ITS-90", WOCE Newsletter 10; the same factor SeaSoft uses, see
``shared/data/README.md``). Pressure: 1 dbar = 10 kPa = 0.1 bar = 0.01 MPa; 1 psi = 0.689475729 dbar.
Conductivity: 1 S/m = 10 mS/cm = 10 000 uS/cm.
"""

from __future__ import annotations

import re
from typing import Any

import numpy as np

from hadal.errors import ConfigError

__all__ = ["CANONICAL_UNITS", "convert", "normalise_unit"]

#: variable -> canonical unit token
CANONICAL_UNITS: dict[str, str] = {
    "conductivity_s_m": "S/m",
    "temperature_its90_degc": "degC_its90",
    "pressure_ctd_dbar": "dbar",
    "pressure_gauge_dbar": "dbar",
    "altitude_m": "m",
    "heading_deg": "deg",
    "pitch_deg": "deg",
    "roll_deg": "deg",
    "dr_east_m": "m",
    "dr_north_m": "m",
    "speed_m_s": "m/s",
}

# unit token -> (dimension, factor to the dimension's canonical unit)  [value_canonical = value * factor]
_LINEAR: dict[str, tuple[str, float]] = {
    "S/m": ("conductivity", 1.0),
    "mS/cm": ("conductivity", 0.1),
    "uS/cm": ("conductivity", 1e-4),
    "mS/m": ("conductivity", 1e-3),
    "dbar": ("pressure", 1.0),
    "bar": ("pressure", 10.0),
    "mbar": ("pressure", 0.01),
    "kPa": ("pressure", 0.1),
    "MPa": ("pressure", 100.0),
    "Pa": ("pressure", 1e-4),
    "psi": ("pressure", 0.689475729),
    "m": ("length", 1.0),
    "cm": ("length", 0.01),
    "mm": ("length", 0.001),
    "km": ("length", 1000.0),
    "ft": ("length", 0.3048),
    "deg": ("angle", 1.0),
    "rad": ("angle", 180.0 / np.pi),
    "m/s": ("speed", 1.0),
    "cm/s": ("speed", 0.01),
    "kn": ("speed", 1852.0 / 3600.0),
}
_TEMPERATURE = {"degC_its90", "degC_its68", "K"}

_ALIASES: dict[str, str] = {
    "s m-1": "S/m", "s/m": "S/m", "siemens/m": "S/m",
    "ms/cm": "mS/cm", "ms cm-1": "mS/cm", "mmho/cm": "mS/cm",
    "us/cm": "uS/cm", "µs/cm": "uS/cm", "us cm-1": "uS/cm",
    "ms/m": "mS/m",
    "dbar": "dbar", "db": "dbar", "decibar": "dbar",
    "bar": "bar", "mbar": "mbar", "hpa": "mbar", "kpa": "kPa", "mpa": "MPa", "pa": "Pa", "psi": "psi", "psia": "psi",
    "m": "m", "metre": "m", "meter": "m", "cm": "cm", "mm": "mm", "km": "km", "ft": "ft",
    "deg": "deg", "degree": "deg", "degrees": "deg", "°": "deg", "rad": "rad", "radian": "rad",
    "m/s": "m/s", "m s-1": "m/s", "cm/s": "cm/s", "kn": "kn", "knot": "kn", "knots": "kn", "kt": "kn",
    "degc": "degC_its90", "°c": "degC_its90", "degree_c": "degC_its90", "degc_its90": "degC_its90",
    "its-90": "degC_its90", "its90": "degC_its90", "degc_its-90": "degC_its90", "its-90, deg c": "degC_its90",
    "degc_its68": "degC_its68", "its-68": "degC_its68", "ipts-68": "degC_its68", "its68": "degC_its68",
    "degc_ipts68": "degC_its68", "its-68, deg c": "degC_its68",
    "k": "K", "kelvin": "K",
}

_DIM_OF_VAR = {v: ("temperature" if u.startswith("degC") else _LINEAR[u][0]) for v, u in CANONICAL_UNITS.items()}


def normalise_unit(unit: str) -> str:
    """Canonical token of a unit string (``"mS cm-1"`` -> ``"mS/cm"``, ``"ITS-68"`` -> ``"degC_its68"``)."""
    key = re.sub(r"\s+", " ", str(unit).strip()).lower()
    if key in _ALIASES:
        return _ALIASES[key]
    if unit in _LINEAR or unit in _TEMPERATURE:
        return unit
    raise ConfigError(f"unknown unit {unit!r}; known: {', '.join(sorted(set(_ALIASES.values())))}")


def check_unit(variable: str, unit: str) -> str:
    """Normalised ``unit`` if it can be converted to ``variable``'s canonical unit, else :class:`ConfigError`."""
    if variable not in CANONICAL_UNITS:
        raise ConfigError(f"unknown variable {variable!r}; known: {', '.join(CANONICAL_UNITS)}")
    u = normalise_unit(unit)
    dim = "temperature" if u in _TEMPERATURE else _LINEAR[u][0]
    if dim != _DIM_OF_VAR[variable]:
        raise ConfigError(f"unit {unit!r} ({dim}) cannot be converted to {variable} ({CANONICAL_UNITS[variable]})")
    return u


def convert(values: Any, unit: str, variable: str) -> tuple[np.ndarray, dict[str, Any] | None]:
    """Convert ``values`` given in ``unit`` to ``variable``'s canonical unit.

    Returns ``(float64 array, record)``; ``record`` is ``None`` when no conversion was needed, else
    ``{"variable", "from", "to", "formula"}`` for the product metadata.
    """
    u = check_unit(variable, unit)
    target = CANONICAL_UNITS[variable]
    x = np.asarray(values, dtype=np.float64)
    if u == target:
        return x, None
    if variable == "temperature_its90_degc":
        if u == "degC_its68":
            # Saunders (1990): T90 = T68 / 1.00024 (valid to a few mK over the oceanographic range)
            return x / 1.00024, {"variable": variable, "from": "degC (IPTS-68)", "to": "degC (ITS-90)",
                                 "formula": "T90 = T68 / 1.00024"}
        if u == "K":
            return x - 273.15, {"variable": variable, "from": "K", "to": "degC (ITS-90)", "formula": "T - 273.15"}
    factor = _LINEAR[u][1] / _LINEAR[target][1]
    return x * factor, {"variable": variable, "from": u, "to": target, "formula": f"x * {factor:.10g}"}
