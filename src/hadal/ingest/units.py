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

__all__ = ["CANONICAL_UNITS", "TRANSFORMS", "Transform", "apply_transform", "convert", "normalise_unit",
           "quaternion_to_euler_deg", "unit_dimension", "unit_alternatives", "raw_values"]

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
    # GNSS fixes (optional columns: hadal.ingest.build.OPTIONAL_SENSOR_VARIABLES), e.g. a ROS 2 NavSatFix
    "gnss_latitude_deg": "deg",
    "gnss_longitude_deg": "deg",
    "gnss_east_variance_m2": "m2",
    "gnss_north_variance_m2": "m2",
    # USBL/LBL fixes (optional columns, as the GNSS ones)
    "usbl_latitude_deg": "deg",
    "usbl_longitude_deg": "deg",
    "usbl_east_variance_m2": "m2",
    "usbl_north_variance_m2": "m2",
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
    "m2": ("area", 1.0),
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
    "m2": "m2", "m^2": "m2", "m**2": "m2",
    "m": "m", "metre": "m", "meter": "m", "cm": "cm", "mm": "mm", "km": "km", "ft": "ft",
    "deg": "deg", "degree": "deg", "degrees": "deg", "°": "deg", "rad": "rad", "radian": "rad",
    "m/s": "m/s", "m s-1": "m/s", "cm/s": "cm/s", "kn": "kn", "knot": "kn", "knots": "kn", "kt": "kn",
    "degc": "degC_its90", "°c": "degC_its90", "degree_c": "degC_its90", "degc_its90": "degC_its90",
    "its-90": "degC_its90", "its90": "degC_its90", "degc_its-90": "degC_its90", "its-90, deg c": "degC_its90",
    "degc_its68": "degC_its68", "its-68": "degC_its68", "ipts-68": "degC_its68", "its68": "degC_its68",
    "degc_ipts68": "degC_its68", "its-68, deg c": "degC_its68",
    "k": "K", "kelvin": "K",
    "pascal": "Pa", "pascals": "Pa", "decibars": "dbar", "bars": "bar", "millibar": "mbar", "hectopascal": "mbar",
    "degrees_c": "degC_its90", "deg_c": "degC_its90", "celsius": "degC_its90", "degrees celsius": "degC_its90",
    "degree_celsius": "degC_its90", "metres": "m", "meters": "m", "m_s": "m/s", "ms_cm": "mS/cm", "s_m": "S/m",
    "us_cm": "uS/cm", "ms_m": "mS/m", "cm_s": "cm/s", "m/sec": "m/s", "radians": "rad", "deg_true": "deg",
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


def unit_dimension(unit: str) -> str:
    """Physical dimension of a unit (``conductivity``, ``temperature``, ``pressure``, ``length``, ``angle``,
    ``speed``); :class:`ConfigError` for an unknown unit."""
    u = normalise_unit(unit)
    return "temperature" if u in _TEMPERATURE else _LINEAR[u][0]


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


def unit_alternatives(variable: str, declared: str | None = None) -> list[tuple[str, float]]:
    """The other units of ``variable``'s dimension as ``(unit, ratio)``: a value converted from ``declared`` (default:
    the canonical unit) is ``ratio`` times what it would be had it been logged in ``unit`` (mS/cm read as S/m:
    ``("mS/cm", 0.1)``). Temperature scales are not linear and have none. For the unit-mistake hint of a channel
    that is mostly out of range (:func:`hadal.ingest.build.channel_health`)."""
    target = CANONICAL_UNITS.get(variable)
    if target is None or target.startswith("degC"):
        return []
    try:
        decl = normalise_unit(declared) if declared else target
    except ConfigError:
        return []
    if decl not in _LINEAR:
        return []
    dim, f_decl = _LINEAR[decl]
    return [(u, f_decl / f) for u, (d, f) in _LINEAR.items() if d == dim and u != decl]


def raw_values(values: np.ndarray, records: list[dict[str, Any]], variable: str) -> tuple[np.ndarray, str | None]:
    """``values`` (canonical units) taken back through the conversion records of ``variable`` (as written by
    :func:`convert` and the readers: ``x * f``, ``x + o``, IPTS-68, kelvin) to the values as logged, and the unit
    they were logged in (``None``: canonical). A transform (several fields) stops the way back: its output is
    returned. Used to recognise fill values, which are written in the logger's units (9.9e5 uS/cm)."""
    x = np.asarray(values, dtype=np.float64)
    unit = None
    for rec in reversed([r for r in records if r.get("variable") == variable]):
        formula = str(rec.get("formula", ""))
        m = re.fullmatch(r"x ([*+]) (\S+)", formula)
        if m:
            try:
                k = float(m.group(2))
            except ValueError:
                break
            x = x / k if m.group(1) == "*" and k != 0 else (x - k if m.group(1) == "+" else x)
            if m.group(1) == "*":
                unit = str(rec.get("from"))
        elif formula == "T90 = T68 / 1.00024":
            x, unit = x * 1.00024, "degC_its68"
        elif formula == "T - 273.15":
            x, unit = x + 273.15, "K"
        else:  # a transform of several fields: its output is what there is
            break
    return x, unit


# --------------------------------------------------------------------------------------------------------------
# Transforms: values computed from several source fields before the unit conversion (vehicle.yaml ``transform``)
# --------------------------------------------------------------------------------------------------------------


class Transform:
    """A named, documented computation of one value from ``n_inputs`` source fields (``None``: any number >= 1).

    ``unit``: the unit of the result (``None``: the unit of the inputs, given as the mapping's ``units``);
    ``dimension``: the result's dimension (checked against the variable's)."""

    def __init__(self, name: str, n_inputs: int | None, unit: str | None, dimension: str, doc: str):
        self.name, self.n_inputs, self.unit, self.dimension, self.doc = name, n_inputs, unit, dimension, doc


def quaternion_to_euler_deg(x, y, z, w, frame: str = "enu") -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Unit quaternion(s) -> marine (heading, pitch, roll) in degrees.

    ``frame="enu"``: ROS REP 103 orientation of a FLU body (x forward, y left, z up) in an ENU world (x east,
    y north, z up), as in ``sensor_msgs/Imu`` and ``nav_msgs/Odometry``. ``frame="ned"``: FRD body in a NED
    world (many marine INS drivers). Results follow the hadal/CF conventions: heading clockwise from north in
    [0, 360), pitch positive bow up, roll positive starboard down. The intrinsic Z-Y'-X'' (yaw, pitch, roll)
    Tait-Bryan angles are taken from the normalised quaternion; a zero (unset) quaternion gives NaN.
    """
    q = [np.asarray(v, dtype=np.float64) for v in (x, y, z, w)]
    n = np.sqrt(q[0] ** 2 + q[1] ** 2 + q[2] ** 2 + q[3] ** 2)
    with np.errstate(invalid="ignore", divide="ignore"):
        qx, qy, qz, qw = (np.where(n > 1e-9, v / n, np.nan) for v in q)
    roll = np.degrees(np.arctan2(2 * (qw * qx + qy * qz), 1 - 2 * (qx * qx + qy * qy)))
    pitch = np.degrees(np.arcsin(np.clip(2 * (qw * qy - qz * qx), -1.0, 1.0)))
    yaw = np.degrees(np.arctan2(2 * (qw * qz + qx * qy), 1 - 2 * (qy * qy + qz * qz)))
    if frame == "enu":  # yaw counter-clockwise from east; FLU pitch positive nose down
        return np.mod(90.0 - yaw, 360.0), -pitch, roll
    if frame == "ned":
        return np.mod(yaw, 360.0), pitch, roll
    raise ValueError(f"unknown frame {frame!r}")


def _quat(which: int, frame: str):
    def f(inputs, **_):
        return quaternion_to_euler_deg(*inputs, frame=frame)[which]
    return f


def _latlon(which: int, nmea: bool = False):
    def f(inputs, origin=None, **_):
        from hadal.geo import LocalFrame

        lat, lon = (np.asarray(v, dtype=np.float64) for v in inputs)
        if nmea:  # [-]DDMM.mmm (glider logs) -> decimal degrees
            from hadal.ingest.glider import nmea_to_deg

            lat, lon = nmea_to_deg(lat), nmea_to_deg(lon)
        ok = np.isfinite(lat) & np.isfinite(lon) & (np.abs(lat) <= 90) & (np.abs(lon) <= 360)
        out = np.full(lat.shape, np.nan)
        if not ok.any():
            return out
        if origin is None:
            i = int(np.argmax(ok))
            origin = (float(lat[i]), float(lon[i]))
        frame = LocalFrame(float(origin[0]), float(origin[1]))
        xy = frame.to_xy(lon[ok], lat[ok])
        out[ok] = xy[which]
        return out
    return f


def _nmea_deg(inputs, **_):
    from hadal.ingest.glider import nmea_to_deg

    return nmea_to_deg(inputs[0])


def _depth_to_pressure(inputs, **_):
    """TEOS-10 sea pressure (dbar) of a depth (m, positive down) at a latitude logged as NMEA [-]DDMM.mmm:
    ``gsw.p_from_z(-depth, lat)`` (IOC et al. 2010, TEOS-10 manual; hydrostatic, standard ocean). A row without
    a latitude uses the median of the log's valid latitudes (p depends on latitude by < 0.6 %)."""
    import gsw

    from hadal.ingest.glider import nmea_to_deg

    depth, lat = (np.asarray(v, dtype=np.float64) for v in inputs)
    lat = nmea_to_deg(lat)
    lat = np.where(np.isfinite(lat) & (np.abs(lat) <= 90), lat, np.nan)
    fill = float(np.nanmedian(lat)) if np.isfinite(lat).any() else 45.0
    return np.asarray(gsw.p_from_z(-depth, np.where(np.isfinite(lat), lat, fill)), dtype=np.float64)


def _norm(inputs, **_):
    arr = [np.asarray(v, dtype=np.float64) for v in inputs]
    return np.sqrt(sum(a * a for a in arr))


#: name -> (Transform, implementation(inputs: list[array], origin=...) -> array)
TRANSFORMS: dict[str, tuple[Transform, Any]] = {
    t.name: (t, f) for t, f in [
        (Transform("quaternion_to_heading_deg", 4, "deg", "angle",
                   "heading (deg clockwise from north) from an ENU/FLU quaternion [x, y, z, w] (ROS REP 103)"),
         _quat(0, "enu")),
        (Transform("quaternion_to_pitch_deg", 4, "deg", "angle",
                   "pitch (deg, bow up positive) from an ENU/FLU quaternion [x, y, z, w] (ROS REP 103)"),
         _quat(1, "enu")),
        (Transform("quaternion_to_roll_deg", 4, "deg", "angle",
                   "roll (deg, starboard down positive) from an ENU/FLU quaternion [x, y, z, w] (ROS REP 103)"),
         _quat(2, "enu")),
        (Transform("ned_quaternion_to_heading_deg", 4, "deg", "angle",
                   "heading (deg clockwise from north) from a NED/FRD quaternion [x, y, z, w]"), _quat(0, "ned")),
        (Transform("ned_quaternion_to_pitch_deg", 4, "deg", "angle",
                   "pitch (deg, bow up positive) from a NED/FRD quaternion [x, y, z, w]"), _quat(1, "ned")),
        (Transform("ned_quaternion_to_roll_deg", 4, "deg", "angle",
                   "roll (deg, starboard down positive) from a NED/FRD quaternion [x, y, z, w]"), _quat(2, "ned")),
        (Transform("latlon_to_east_m", 2, "m", "length",
                   "metres east of `origin` [lat, lon] (default: the first valid fix) from [latitude, longitude] "
                   "in degrees (transverse Mercator centred on the origin, as hadal.geo.LocalFrame)"), _latlon(0)),
        (Transform("latlon_to_north_m", 2, "m", "length",
                   "metres north of `origin` [lat, lon] (default: the first valid fix) from [latitude, longitude] "
                   "in degrees (transverse Mercator centred on the origin, as hadal.geo.LocalFrame)"), _latlon(1)),
        (Transform("latlon_ddmm_to_east_m", 2, "m", "length",
                   "latlon_to_east_m of [latitude, longitude] logged as NMEA [-]DDMM.mmm (glider logs; "
                   "origin in decimal degrees)"), _latlon(0, nmea=True)),
        (Transform("latlon_ddmm_to_north_m", 2, "m", "length",
                   "latlon_to_north_m of [latitude, longitude] logged as NMEA [-]DDMM.mmm (glider logs; "
                   "origin in decimal degrees)"), _latlon(1, nmea=True)),
        (Transform("nmea_to_deg", 1, "deg", "angle",
                   "decimal degrees of a latitude or longitude logged as NMEA [-]DDMM.mmm (glider GPS fixes); "
                   "impossible values (minutes >= 60, masterdata defaults) missing"), _nmea_deg),
        (Transform("depth_ddmm_lat_to_pressure_dbar", 2, "dbar", "pressure",
                   "TEOS-10 sea pressure gsw.p_from_z(-depth, lat) of [depth (m, positive down), latitude logged as "
                   "NMEA [-]DDMM.mmm] (a glider's on-board depth when its log has no pressure channel)"),
         _depth_to_pressure),
        (Transform("vector_norm", None, None, "any",
                   "Euclidean norm of the input components (e.g. speed from twist.linear.x and .y), "
                   "in the mapping's `units`"), _norm),
    ]
}


def apply_transform(name: str, inputs: list[Any], origin: tuple[float, float] | None = None) -> np.ndarray:
    """Apply the transform ``name`` (:data:`TRANSFORMS`) to the input arrays."""
    if name not in TRANSFORMS:
        raise ConfigError(f"unknown transform {name!r}; known: {', '.join(TRANSFORMS)}")
    t, f = TRANSFORMS[name]
    if t.n_inputs is not None and len(inputs) != t.n_inputs:
        raise ConfigError(f"transform {name} takes {t.n_inputs} fields, got {len(inputs)}")
    return np.asarray(f(inputs, origin=origin), dtype=np.float64)
