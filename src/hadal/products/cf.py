"""CF metadata tables shared by the product writers.

hadal names quantities with their unit as a suffix (``pressure_dbar``, ``temperature_its90_degc``,
``density_kg_m3``); :func:`units_from_name` turns the suffix into a UDUNITS string so a variable that
a stage wrote without a ``units`` attribute still gets a correct one. :data:`COLUMN_ATTRS` gives CF
standard names for the columns of the tabular products defined in ``docs/architecture.md``
(``sensors``/``ctd``/``matched_track``). Standard names are from the CF Standard Name Table v79.
"""

from __future__ import annotations

import re

STANDARD_NAME_VOCABULARY = "CF Standard Name Table v79"

#: name suffix -> UDUNITS unit string (longest suffix wins; checked in this order)
_SUFFIX_UNITS: tuple[tuple[str, str], ...] = (
    ("_kg_m3", "kg m-3"),
    ("_m_s2", "m s-2"),
    ("_m_s", "m s-1"),
    ("_s_m", "S m-1"),
    ("_ms_cm", "mS cm-1"),
    ("_degc", "degree_C"),
    ("_dbar", "dbar"),
    ("_bar", "bar"),
    ("_deg", "degree"),
    ("_rad", "rad"),
    ("_mm", "mm"),
    ("_km", "km"),
    ("_m2", "m2"),
    ("_m", "m"),
    ("_s", "s"),
    ("_ns", "ns"),
    ("_pct", "percent"),
)

_EXACT_UNITS: dict[str, str] = {
    "lat": "degrees_north",
    "latitude": "degrees_north",
    "lon": "degrees_east",
    "longitude": "degrees_east",
    "x": "m",
    "y": "m",
    "practical_salinity": "1",
    "count": "1",
    "entropy": "1",
    "msd": "m2",
}


def units_from_name(name: str) -> str | None:
    """UDUNITS units implied by hadal's naming convention (``depth_m`` → ``m``), or ``None``.

    >>> units_from_name("sound_speed_m_s"), units_from_name("gravity_m_s2"), units_from_name("phase")
    ('m s-1', 'm s-2', None)
    """
    low = name.lower()
    if low in _EXACT_UNITS:
        return _EXACT_UNITS[low]
    for suffix, units in _SUFFIX_UNITS:
        if low.endswith(suffix):
            return units
    return None


def long_name_from_name(name: str) -> str:
    """A readable long_name from a variable name (unit suffix removed): ``depth_std_m`` → ``depth std``."""
    low = name.lower()
    for suffix, _ in _SUFFIX_UNITS:
        if low.endswith(suffix) and len(low) > len(suffix):
            name = name[: -len(suffix)]
            break
    return re.sub(r"[_]+", " ", name).strip()


#: column/variable name -> CF attributes for tabular products (architecture.md). Caller attributes win.
COLUMN_ATTRS: dict[str, dict[str, str]] = {
    "time": {"standard_name": "time", "long_name": "sample time (UTC)"},
    "conductivity_s_m": {"standard_name": "sea_water_electrical_conductivity", "units": "S m-1",
                         "long_name": "CTD conductivity"},
    "temperature_its90_degc": {"standard_name": "sea_water_temperature", "units": "degree_C",
                               "long_name": "CTD temperature (ITS-90)"},
    "pressure_ctd_dbar": {"standard_name": "sea_water_pressure", "units": "dbar", "long_name": "CTD pressure"},
    "pressure_gauge_dbar": {"standard_name": "sea_water_pressure", "units": "dbar",
                            "long_name": "pressure gauge (Keller) pressure"},
    "pressure_dbar": {"standard_name": "sea_water_pressure", "units": "dbar",
                      "long_name": "fused sea water pressure"},
    "altitude_m": {"standard_name": "height_above_sea_floor", "units": "m", "long_name": "altimeter range"},
    "altitude_corrected_m": {"standard_name": "height_above_sea_floor", "units": "m",
                             "long_name": "sound-speed corrected altitude"},
    "heading_deg": {"standard_name": "platform_yaw", "units": "degree", "long_name": "heading (true)"},
    "pitch_deg": {"standard_name": "platform_pitch", "units": "degree", "long_name": "pitch"},
    "roll_deg": {"standard_name": "platform_roll", "units": "degree", "long_name": "roll"},
    "dr_east_m": {"units": "m", "long_name": "dead-reckoned east offset from launch"},
    "dr_north_m": {"units": "m", "long_name": "dead-reckoned north offset from launch"},
    "speed_m_s": {"standard_name": "platform_speed_wrt_sea_water", "units": "m s-1", "long_name": "vehicle speed"},
    "practical_salinity": {"standard_name": "sea_water_practical_salinity", "units": "1",
                           "long_name": "practical salinity (PSS-78)"},
    "density_kg_m3": {"standard_name": "sea_water_density", "units": "kg m-3",
                      "long_name": "in situ density (EOS-80)"},
    "gravity_m_s2": {"units": "m s-2", "long_name": "gravitational acceleration"},
    "depth_m": {"standard_name": "depth", "units": "m", "long_name": "vehicle depth (hydrostatic)",
                "positive": "down"},
    "depth_fofonoff_millard_m": {"standard_name": "depth", "units": "m", "positive": "down",
                                 "long_name": "vehicle depth (Fofonoff & Millard 1983)"},
    "depth_teos10_m": {"standard_name": "depth", "units": "m", "positive": "down",
                       "long_name": "vehicle depth (TEOS-10)"},
    "sound_speed_m_s": {"standard_name": "speed_of_sound_in_sea_water", "units": "m s-1",
                        "long_name": "sound speed"},
    # TEOS-10 (gsw), next to the EOS-80 columns (issue 17)
    "absolute_salinity_g_kg": {"standard_name": "sea_water_absolute_salinity", "units": "g kg-1",
                               "long_name": "Absolute Salinity (TEOS-10, gsw.SA_from_SP)"},
    "conservative_temperature_degc": {"standard_name": "sea_water_conservative_temperature", "units": "degree_C",
                                      "long_name": "Conservative Temperature (TEOS-10, gsw.CT_from_t)"},
    "potential_temperature_degc": {"standard_name": "sea_water_potential_temperature", "units": "degree_C",
                                   "long_name": "potential temperature referenced to 0 dbar (TEOS-10, gsw.pt0_from_t)"},
    "sigma0_kg_m3": {"standard_name": "sea_water_sigma_theta", "units": "kg m-3",
                     "long_name": "potential density anomaly referenced to 0 dbar (TEOS-10, gsw.sigma0 from SA "
                                  "and CT)"},
    "buoyancy_frequency_squared_s2": {"standard_name": "square_of_brunt_vaisala_frequency_in_sea_water",
                                      "units": "s-2",
                                      "long_name": "buoyancy frequency squared N2 (TEOS-10, gsw.Nsquared on the "
                                                   "binned cast)"},
    "seafloor_depth_m": {"standard_name": "sea_floor_depth_below_sea_surface", "units": "m",
                         "long_name": "seafloor depth (vehicle depth + altitude)"},
    "lat": {"standard_name": "latitude", "units": "degrees_north", "long_name": "latitude"},
    "lon": {"standard_name": "longitude", "units": "degrees_east", "long_name": "longitude"},
    "latitude_deg": {"standard_name": "latitude", "units": "degrees_north", "long_name": "latitude"},
    "longitude_deg": {"standard_name": "longitude", "units": "degrees_east", "long_name": "longitude"},
    "x_east_m": {"standard_name": "projection_x_coordinate", "units": "m", "long_name": "easting in the map frame"},
    "y_north_m": {"standard_name": "projection_y_coordinate", "units": "m",
                  "long_name": "northing in the map frame"},
}

QARTOD_FLAG_VALUES = (1, 2, 3, 4, 9)
QARTOD_FLAG_MEANINGS = "pass not_evaluated suspect fail missing"

#: Quantities of hadal products for which the CF Standard Name Table (v79..v93) has no entry. They get
#: a long_name and units but no standard_name (inventing one would make the CF §3.3 check fail); this is
#: the one documented exception to ACDD's "standard_name on every geophysical variable".
NO_CF_STANDARD_NAME = ("gravity", "entropy", "msd", "score", "suitab", "roughness", "elevation", "energy", "bias", "cost",
                       "position_uncertainty")


EDGE_RE = re.compile(r"[xy]_(min|max|edge\w*|left|right|lower|upper|start|end)(_m)?")


def is_axis_edge(name: str) -> bool:
    """Block/cell edge positions along one map axis (e.g. suitability ``x_min(x)``): auxiliary coordinates."""
    return bool(EDGE_RE.fullmatch(name.lower()))


def has_no_cf_standard_name(name: str) -> bool:
    low = name.lower()
    return any(t in low for t in NO_CF_STANDARD_NAME)


_SFD = "sea_floor_depth_below_sea_surface"


def netcdf_variable_attrs(name: str, on_grid: bool) -> dict[str, str]:
    """CF ``standard_name`` (and ``cell_methods`` for per-cell statistics) of a NetCDF product variable.

    ``on_grid``: the variable lies on a y/x map grid (seafloor surface products: DTM, suitability,
    landing maps), where depth-like quantities are seafloor depth; off-grid (profiles) they are the
    depth of the measurement. Per-cell statistics of soundings use CF cell methods (``area: median``,
    ``area: standard_deviation``) and standard-name modifiers (``number_of_observations``,
    ``standard_error``), CF-1.8 §7.3 and Appendix C.
    """
    low = name.lower()
    if has_no_cf_standard_name(low):
        return {}
    if on_grid:
        if low in ("count", "n", "n_soundings", "sounding_count") or low.startswith(("count_", "n_")):
            return {"standard_name": f"{_SFD} number_of_observations"}
        if "uncertainty" in low or "standard_error" in low:
            return {"standard_name": f"{_SFD} standard_error"}
        if low.startswith("slope") or ("slope" in low and low.endswith("_deg")):
            return {"standard_name": "ground_slope_angle"}
        if low.startswith("aspect"):
            return {"standard_name": "ground_slope_direction"}
        if "std" in low and (low.startswith("depth") or low.startswith("std") or "elev" in low):
            return {"standard_name": _SFD, "cell_methods": "area: standard_deviation"}
        if low.startswith("depth_median") or low == "median_depth_m":
            return {"standard_name": _SFD, "cell_methods": "area: median"}
        if low.startswith(("depth_min", "min_depth")):
            return {"standard_name": _SFD, "cell_methods": "area: minimum"}
        if low.startswith(("depth_max", "max_depth")):
            return {"standard_name": _SFD, "cell_methods": "area: maximum"}
        if low in ("depth_m", "depth_mean_m", "seafloor_depth_m", "depth"):
            return {"standard_name": _SFD, "cell_methods": "area: mean"}
        if low.startswith(("protrusion", "height_above")):
            return {"standard_name": "height_above_sea_floor"}
        return {}
    if low in COLUMN_ATTRS and "standard_name" in COLUMN_ATTRS[low]:
        out = {"standard_name": COLUMN_ATTRS[low]["standard_name"]}
        return out
    if low in ("count", "n_samples", "n", "sample_count") or low.startswith(("n_", "count_")):
        return {"standard_name": "sea_water_pressure number_of_observations"}
    return {}
