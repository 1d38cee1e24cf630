"""Units in the report come from the variable registry (``schemas/variables.yaml``), written for people.

The registry declares each variable's UDUNITS string (``degree_C``, ``kg m-3``); figures and tables show it as
``°C``, ``kg/m³``. Nothing here declares a unit: a variable's unit changes in the registry, and the report follows.
"""

from __future__ import annotations

from hadal.products.registry import variable_attrs

#: UDUNITS string -> how the report prints it (others are printed as declared)
_DISPLAY = {
    "1": "",
    "degree_C": "°C",
    "degree": "°",
    "kg m-3": "kg/m³",
    "S m-1": "S/m",
    "mS cm-1": "mS/cm",
    "m s-1": "m/s",
    "m s-2": "m/s²",
    "m2": "m²",
    "g kg-1": "g/kg",
    "s-2": "s⁻²",
}


def display_units(udunits: str | None) -> str:
    """``degree_C`` -> ``°C``; dimensionless (``1``) or no unit -> ``""``."""
    return _DISPLAY.get(udunits or "1", udunits or "")


def units_of(name: str) -> str:
    """The display unit of the declared variable ``name`` (its registry ``units``)."""
    return display_units(variable_attrs(name).get("units"))


def axis_label(name: str, label: str) -> str:
    """``label (unit)`` with the unit of ``name`` from the registry; the label alone for a dimensionless quantity."""
    u = units_of(name)
    return f"{label} ({u})" if u else label
