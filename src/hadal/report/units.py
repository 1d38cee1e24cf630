"""Units in the report come from the variable registry (``schemas/variables.yaml``), written for people.

The registry declares each variable's UDUNITS string (``degree_C``, ``kg m-3``); figures and tables show it as
``°C``, ``kg/m³``. Nothing here declares a unit: a variable's unit changes in the registry, and the report follows.
"""

from __future__ import annotations

from hadal.registry import variable_attrs

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


#: metres per degree of latitude (WGS 84 meridian arc at the equator, 110 574 m, to the poles, 111 694 m: the
#: upper bound is used so a degree's digit is never coarser than claimed anywhere on Earth)
M_PER_DEG_LAT_MAX = 111_694.0
#: metres per arc-minute of latitude at most (:data:`M_PER_DEG_LAT_MAX` / 60)
M_PER_MIN_LAT_MAX = M_PER_DEG_LAT_MAX / 60.0


def coordinate_decimals(size_m: float, unit: str = "deg", *, lo: int = 0, hi: int = 9) -> int:
    """Decimals of a latitude/longitude in ``unit`` (``"deg"``: decimal degrees, ``"min"``: the minutes of a
    degrees-minutes position) whose last digit is at most ``size_m`` on the ground: the precision of the thing
    located (a 0.32 m landing site: 6 decimals of a degree, 0.11 m; 4 of a minute, 0.19 m), never the 3 decimals
    of a degree (~110 m) a ship's position gets. The last digit of a latitude is the coarser one (a degree of
    longitude shrinks with cos(latitude)), so the bound uses a degree of latitude (:data:`M_PER_DEG_LAT_MAX`):
    ``ceil(log10(m_per_unit / size_m))``, clipped to ``[lo, hi]``; ``size_m`` <= 0 or not finite: ``hi``."""
    import math

    per = {"deg": M_PER_DEG_LAT_MAX, "min": M_PER_MIN_LAT_MAX}[unit]
    if not (isinstance(size_m, (int, float)) and math.isfinite(size_m) and size_m > 0):
        return hi
    return int(min(hi, max(lo, math.ceil(math.log10(per / float(size_m)) - 1e-12))))


#: report labels of table keys (landing sites, landing Table V, summary tables): words and units for people
LABELS: dict[str, str] = {
    "submap": "submap",
    "heading_deg": "heading (°, laser frame)",
    "heading_true_deg": "heading (° true)",
    "x_m": "x (m, laser frame)",
    "y_m": "y (m, laser frame)",
    "lat": "latitude (°N)",
    "lon": "longitude (°E)",
    "position": "position",
    "radius_m": "largest inscribed circle radius (m)",
    "slope_deg": "slope (°)",
    "roughness_m": "roughness (m)",
    "c_s": "landing cost C_s",
    "transect_length_m": "transect length (m)",
    "area_surveyed_m2": "area surveyed (m²)",
    "number_of_sites": "candidate sites (all headings)",
    "submaps_with_sites": "submaps with at least one site",
    "mean_landing_cost": "mean landing cost C_s",
    "landing_cost_min": "lowest landing cost C_s",
    "landing_cost_max": "highest landing cost C_s",
    "landing_cost_std": "standard deviation of landing cost C_s",
    "cast": "cast",
    "start_utc": "start (UTC)",
    "end_utc": "end (UTC)",
    "samples": "samples",
    "max_depth_m": "maximum depth (m)",
    "max_pressure_dbar": "maximum pressure (dbar)",
    "latitude_source": "latitude from",
}

#: unit suffixes of snake_case keys -> the unit shown (longest first)
_SUFFIX_UNITS = (("_m2", "m²"), ("_m_s", "m/s"), ("_deg", "°"), ("_dbar", "dbar"), ("_degc", "°C"), ("_km", "km"),
                 ("_m", "m"), ("_s", "s"))


def human_label(key: str) -> str:
    """A table key for people: :data:`LABELS`, else the words of the snake_case key with its unit suffix as
    ``(unit)`` (``track_length_km`` -> ``track length (km)``)."""
    if key in LABELS:
        return LABELS[key]
    for suf, unit in _SUFFIX_UNITS:
        if key.endswith(suf) and len(key) > len(suf):
            return f"{key[: -len(suf)].replace('_', ' ')} ({unit})"
    return key.replace("_", " ")
