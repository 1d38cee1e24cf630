"""Describe vehicle logs and suggest their channel mapping (``vehicle.yaml``) - used by ``hadal init``/``inspect``.

* :func:`describe_mcap` / :func:`describe_csv` (from the readers): what a file holds, JSON-serialisable.
* :func:`suggest_vehicle`: MCAP channels and CSV columns -> a :class:`Suggestion`: the ``vehicle.yaml`` content
  (a dict that validates as :class:`~hadal.ingest.vehicle.VehicleConfig`), what was mapped and why, what could
  not be mapped, and what the user must still check. :func:`render_vehicle_yaml` writes it as commented YAML.

How channels are recognised
---------------------------
1. ROS 2 standard message types, by type (decoded from the schema stored in the file): ``sensor_msgs/msg/
   FluidPressure`` (absolute pressure in Pa -> ``pressure_gauge_dbar`` with ``offset: -10.1325``),
   ``Temperature``, ``Range`` (altimeter), ``NavSatFix`` (``latlon_to_east_m``/``_north_m``), ``Imu``
   (orientation quaternion -> heading/pitch/roll), ``nav_msgs/msg/Odometry``, ``geometry_msgs/msg/PoseStamped``
   / ``PoseWithCovarianceStamped`` (position x/y -> ``dr_east_m``/``dr_north_m``, orientation) and
   ``TwistStamped`` / ``TwistWithCovarianceStamped`` (``vector_norm`` of the linear velocity -> speed).
   ROS messages are timed by ``header.stamp`` when it agrees with the recorder's ``log_time`` (within 60 s),
   else by ``log_time``.
2. Any other JSON or ROS channel, and CSV columns, by field names (``cond``, ``temp``, ``pres``/``pressure``,
   ``range``/``altitude``, ``heading``, ``pitch``, ``roll``, ``east``/``north``, ``speed``, ``lat``/``lon`` ...),
   with the unit taken from the schema (JSON Schema ``units``/``description``, ``.msg`` comments), else from a
   unit suffix of the name (``pressure_bar``, ``conductivity_mS_cm``, ``temperature_ITS90``), else assumed
   (the variable's own unit, corrected by the magnitude of the first value: 56 -> mS/cm) and listed as a check.
   A channel with conductivity, temperature and pressure is a CTD (``pressure_ctd_dbar``); other pressures are
   a gauge (``pressure_gauge_dbar``). A boolean ``valid`` field becomes ``valid_field``.

3. Glider logs (ALSEAMAR SeaExplorer navigation/payload, Teledyne Slocum dbd2asc; :mod:`hadal.ingest.glider`), by
   their kind's column conventions: day-first SeaExplorer times, NMEA ``DDMM.mmm`` positions
   (``latlon_ddmm_to_*``), fill values (``fill_values``: the altimeter's -1, the payload's 9999) and, for Slocum,
   every unit from the file's own units line; a Slocum file gives one sensor per group (CTD, navigation,
   altimeter) reading the same ``sources.csv`` key.

When several channels give one variable, the most specific wins (a CTD's temperature over a thermometer's, an
IMU's attitude over an odometry's, a dead-reckoning over GNSS fixes; then the higher message count); the others
are listed as not mapped. CSV files giving the same variables as an MCAP topic become that sensor's ``csv``
alternative; others become CSV-only sensors. ``time_base`` is the CTD if there is one, else the pressure
sensor, else the mapped sensor with the highest rate.

Decoder choice (issue 13): on ``../shared/data/mcap-real`` (32 messages in 3 files) mcap-ros2-support decodes
32/32 from the schemas in the files; rosbags' ``AnyReader`` decodes 27/32 (it refuses the 5 messages of
``rosbag2_test_bag_for_seek_0.mcap``, whose schema is named ``test_msgs/BasicTypes`` without ``/msg/``; 32/32
once the name is normalised by hand). hadal therefore decodes with mcap-ros2-support (also a dependency
already); rosbags is used in the tests as an independent writer and decoder.
"""

from __future__ import annotations

import math
import re
from collections.abc import Iterable, Mapping
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import yaml

from hadal.errors import ConfigError, InputError
from hadal.ingest.csv_reader import describe_csv
from hadal.ingest.mcap_reader import describe_mcap, ros2_type_name
from hadal.ingest.units import CANONICAL_UNITS, check_unit, normalise_unit, unit_dimension
from hadal.ingest.vehicle import VehicleConfig

__all__ = ["Suggestion", "describe_csv", "describe_log", "describe_mcap", "is_mcap", "render_vehicle_yaml",
           "suggest_vehicle"]

#: one standard atmosphere in dbar (sensor_msgs/FluidPressure is absolute pressure)
ATMOSPHERE_DBAR = 10.1325

_STOP = {"min", "max", "std", "stdev", "sigma", "var", "variance", "cov", "covariance", "err", "error", "offset",
         "bias", "rate", "status", "quality", "flag", "qc", "count", "id", "valid", "setpoint", "target", "cmd",
         "command", "desired", "ref", "reference", "sound", "wind", "air", "internal", "board", "cpu", "battery",
         "motor", "stamp", "sec", "nanosec", "time", "frame", "seq", "accuracy", "resolution", "gain", "limit",
         "threshold", "dt", "age", "sensor_temp", "noise", "cal", "calibration", "setting"}
_KINDS: dict[str, set[str]] = {
    "cond": {"cond", "conductivity", "c0", "c1", "c0s", "c1s", "condo"},
    "temp": {"temp", "temperature", "t090", "t090c", "t068", "t068c", "t190c", "wtemp", "watertemp", "sst"},
    "pres": {"pres", "pressure", "press", "prdm", "prsm", "prm", "pr"},
    "alt": {"altitude", "altimeter", "alt", "range", "hab"},
    "heading": {"heading", "hdg", "yaw", "compass"},
    "pitch": {"pitch"},
    "roll": {"roll"},
    "east": {"east", "dreast"},
    "north": {"north", "drnorth"},
    "speed": {"speed", "sog", "spd"},
    "lat": {"lat", "latitude"},
    "lon": {"lon", "long", "longitude", "lng"},
}
_KIND_VAR = {"cond": "conductivity_s_m", "temp": "temperature_its90_degc", "alt": "altitude_m",
             "heading": "heading_deg", "pitch": "pitch_deg", "roll": "roll_deg", "east": "dr_east_m",
             "north": "dr_north_m", "speed": "speed_m_s"}
_KIND_WORD = {"cond": "conductivity", "alt": "altitude (range to the bottom)", "east": "east", "north": "north",
              "heading": "heading", "pitch": "pitch", "roll": "roll", "speed": "speed"}
_TIME_TOKENS = {"stamp", "time", "sec", "secs", "nanosec", "nsecs", "timestamp", "utc", "epoch", "seq", "t"}
_VALID_NAMES = {"valid", "is_valid", "ok", "good", "valid_flag", "isvalid"}
_ROLE_ORDER = ("ctd", "gauge", "altimeter", "attitude", "position", "navigation", "gnss", "usbl", "thermometer",
               "conductivity", "sensor")


# ------------------------------------------------------------------------------------------------ result types


@dataclass
class Suggestion:
    """What :func:`suggest_vehicle` found.

    ``vehicle``: the ``vehicle.yaml`` content (validates as VehicleConfig) or ``None`` when nothing could be
    mapped (then there is nothing to ingest from these logs). ``mapped``: one dict per mapped variable
    (``variable``, ``sensor``, ``kind`` mcap|csv, ``source`` (topic or CSV key), ``file``, ``field``,
    ``units``, ``transform``, ``offset``, ``why``, ``assumed``). ``unmapped``: ``source``/``file``/``field``/
    ``reason`` of each channel or field left out. ``checks``: what the user must still verify.
    ``files``: the :func:`describe_mcap` / :func:`describe_csv` result of each file, by path.
    """

    vehicle: dict[str, Any] | None
    mapped: list[dict[str, Any]] = field(default_factory=list)
    unmapped: list[dict[str, Any]] = field(default_factory=list)
    checks: list[str] = field(default_factory=list)
    files: dict[str, dict[str, Any]] = field(default_factory=dict)
    #: MCAP files with at least one mapped channel / CSV keys with a mapping
    mcap_used: list[str] = field(default_factory=list)
    csv_used: dict[str, str] = field(default_factory=dict)

    @property
    def ok(self) -> bool:
        """Whether anything was mapped (a vehicle config to ingest with)."""
        return self.vehicle is not None

    @property
    def time_base(self) -> str | None:
        return self.vehicle["time_base"] if self.vehicle else None

    def config(self) -> VehicleConfig | None:
        """The suggestion validated as :class:`VehicleConfig` (``None`` when nothing was mapped)."""
        return VehicleConfig.model_validate(self.vehicle) if self.vehicle is not None else None

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass
class _Cand:
    kind: str  # mcap | csv
    source: str  # topic or CSV key
    file: str
    variable: str
    fm: dict[str, Any]
    score: int
    why: str
    assumed: bool = False
    count: int = 0
    checks: list[str] = field(default_factory=list)


@dataclass
class _Src:
    """One MCAP topic or CSV file and what it offers."""

    kind: str
    source: str
    file: str
    time: dict[str, str]
    rate_hz: float | None
    count: int
    valid_field: str | None = None
    delimiter: str = ","
    cands: list[_Cand] = field(default_factory=list)
    label: str = ""
    #: the dive.yaml ``sources.csv`` key when ``source`` names one sensor of a file holding several (glider logs)
    csv_key: str | None = None


# ------------------------------------------------------------------------------------------------ name / unit parsing


def _tokens(name: str) -> list[str]:
    return [t for t in re.split(r"[_\-\s.\[\]()/]+", name) if t]


def _split_unit(name: str) -> tuple[list[str], str | None]:
    """Base tokens (lower case, camelCase split) and the unit of a unit suffix: ``conductivity_mS_cm`` ->
    (['conductivity'], 'mS/cm'); ``temperature_ITS90`` -> (['temperature'], 'degC_its90')."""
    toks = _tokens(name)
    unit = None
    for k in (3, 2, 1):
        if len(toks) <= k:
            continue
        tail = toks[-k:]
        for cand in ("/".join(tail), "_".join(tail), " ".join(tail)):
            try:
                unit = normalise_unit(cand)
            except ConfigError:
                continue
            toks = toks[:-k]
            break
        if unit:
            break
    base: list[str] = []
    for t in toks:
        base.extend(p.lower() for p in re.split(r"(?<=[a-z])(?=[A-Z])", t) if p)
    return base, unit


def _kind_of(name: str) -> tuple[str | None, str | None]:
    """(kind, unit from the name) of a field/column name, or (None, None)."""
    if name in CANONICAL_UNITS:
        return "canonical:" + name, CANONICAL_UNITS[name]
    base, unit = _split_unit(name)
    if not base or any(t in _STOP for t in base):
        return None, None
    joined = "".join(base)
    kinds = {k for k, words in _KINDS.items() if any(t in words for t in base) or joined in words}
    if len(kinds) != 1:
        return None, None
    return kinds.pop(), unit


def _var_dim(var: str) -> str:
    return unit_dimension(CANONICAL_UNITS[var])


def _unit_from_text(text: str | None, var: str) -> str | None:
    """A unit of ``var``'s dimension named in a schema description / comment, if any."""
    if not text:
        return None
    dim = _var_dim(var)
    if dim == "temperature" and re.search(r"\b(i?pts|its)[- ]?68\b", text, re.IGNORECASE):
        return "degC_its68"
    m = re.match(r"units:\s*([^;]+)", text)
    segs = ([m.group(1)] if m else []) + [s for s in re.split(r"[,;()\[\]{}]", text) if s.strip()]
    for seg in segs:
        words = [seg.strip()] + seg.split()
        for w in words:
            w = w.strip(" .:'\"[]{}")
            if not w:
                continue
            try:
                u = normalise_unit(w)
            except ConfigError:
                continue
            if unit_dimension(u) == dim:
                return u
    return None


def _num(v: Any) -> float | None:
    if isinstance(v, bool) or v is None:
        return None
    try:
        x = float(v)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def _by_magnitude(var: str, unit: str, v: float | None) -> tuple[str, str | None]:
    """Correct an assumed unit from the first value's magnitude; returns (unit, note)."""
    if v is None:
        return unit, None
    a = abs(v)
    if var == "conductivity_s_m" and unit == "S/m":
        if a > 1000:
            return "uS/cm", f"first value {v:g} suggests uS/cm"
        if a > 10:
            return "mS/cm", f"first value {v:g} suggests mS/cm (sea water is 0-7 S/m)"
    if var == "temperature_its90_degc" and unit == "degC_its90" and a > 150:
        return "K", f"first value {v:g} suggests kelvin"
    if var.startswith("pressure") and unit == "dbar" and a > 15000:
        return "Pa", f"first value {v:g} suggests Pa"
    return unit, None


def _get(msg: Any, path: str) -> Any:
    if not isinstance(msg, dict):
        return None
    if path in msg:
        return msg[path]
    for p in path.split("."):
        if isinstance(msg, dict):
            msg = msg.get(p)
        else:
            return None
    return msg


def _fm(fieldname: Any, units: str, transform: str | None = None, offset: float | None = None,
        origin: tuple[float, float] | None = None) -> dict[str, Any]:
    out: dict[str, Any] = {"field": fieldname, "units": units}
    if transform:
        out["transform"] = transform
    if offset:
        out["offset"] = offset
    if origin is not None:
        out["origin"] = [float(origin[0]), float(origin[1])]
    return out


# ------------------------------------------------------------------------------------------------ ROS 2 types

_Q = ("x", "y", "z", "w")


def _quat(prefix: str, score: int, what: str) -> list[tuple[str, dict[str, Any], int, str]]:
    f = [f"{prefix}.{c}" for c in _Q]
    return [(var, _fm(f, "deg", f"quaternion_to_{var}"), score,
             f"{what} orientation quaternion ({prefix}), ROS REP 103 ENU/FLU")
            for var in ("heading_deg", "pitch_deg", "roll_deg")]


def _xy(prefix: str, score: int, what: str) -> list[tuple[str, dict[str, Any], int, str]]:
    return [("dr_east_m", _fm(f"{prefix}.x", "m"), score, f"{what} position x (east, REP 103 ENU)"),
            ("dr_north_m", _fm(f"{prefix}.y", "m"), score, f"{what} position y (north, REP 103 ENU)")]


def _twist(prefix: str, score: int, what: str) -> list[tuple[str, dict[str, Any], int, str]]:
    return [("speed_m_s", _fm([f"{prefix}.x", f"{prefix}.y"], "m/s", "vector_norm"), score,
             f"{what} horizontal speed |({prefix}.x, {prefix}.y)|")]


def _ros_standard(mtype: str, msg: dict[str, Any] | None, origin: tuple[float, float] | None
                  ) -> tuple[list[tuple[str, dict[str, Any], int, str]], list[tuple[str, str]], list[str]] | None:
    """(candidates, unmapped (field, reason), checks) for a recognised standard ROS 2 type, else None."""
    t = mtype
    checks: list[str] = []
    if t == "sensor_msgs/msg/FluidPressure":
        return ([("pressure_gauge_dbar", _fm("fluid_pressure", "Pa", offset=-ATMOSPHERE_DBAR), 3,
                  "sensor_msgs/FluidPressure.fluid_pressure: absolute pressure in Pa -> dbar, minus one standard "
                  "atmosphere (10.1325 dbar) for sea pressure")], [],
                ["{src}: FluidPressure is absolute pressure by definition; offset -10.1325 dbar assumes the gauge "
                 "reads one standard atmosphere at the surface - check against the surface readings (drop the "
                 "offset if the driver already publishes sea/gauge pressure)"])
    if t == "sensor_msgs/msg/Temperature":
        return ([("temperature_its90_degc", _fm("temperature", "degC_its90"), 2,
                  "sensor_msgs/Temperature.temperature (degC)")], [],
                ["{src}: sensor_msgs/Temperature gives degC without a scale; ITS-90 assumed, and check that it "
                 "measures the water (not a housing)"])
    if t == "sensor_msgs/msg/Range":
        return ([("altitude_m", _fm("range", "m"), 3, "sensor_msgs/Range.range (m)")], [],
                ["{src}: +/-inf ranges (REP 117: no detection) become missing values; check that this range "
                 "finder looks down"])
    if t == "sensor_msgs/msg/NavSatFix":
        # a GNSS fix, not a dead-reckoned offset: the navigation smoother uses it where the vehicle is at the
        # surface, weighted by its position_covariance (ENU: [0] east, [4] north variance, m^2)
        cands = [("gnss_latitude_deg", _fm("latitude", "deg"), 3, "sensor_msgs/NavSatFix.latitude (GNSS fix)"),
                 ("gnss_longitude_deg", _fm("longitude", "deg"), 3, "sensor_msgs/NavSatFix.longitude (GNSS fix)")]
        cov = _get(msg, "position_covariance") if msg else None
        ctype = _get(msg, "position_covariance_type") if msg else None
        if isinstance(cov, list) and len(cov) == 9 and ctype not in (None, 0):
            cands += [("gnss_east_variance_m2", _fm("position_covariance.0", "m2"), 3,
                       "sensor_msgs/NavSatFix.position_covariance[0] (east variance, ENU)"),
                      ("gnss_north_variance_m2", _fm("position_covariance.4", "m2"), 3,
                       "sensor_msgs/NavSatFix.position_covariance[4] (north variance, ENU)")]
        return (cands, [("altitude", "GNSS altitude is not a hadal variable")]
                + ([] if isinstance(cov, list) and ctype not in (None, 0) else
                   [("position_covariance", "position_covariance_type 0 (unknown): the smoother's configured "
                                            "GNSS accuracy is used")]),
                ["{src}: NavSatFix fixes are used only where the vehicle is at the surface (depth <= "
                 "navigation gnss_max_depth_m); fixes with status -1 (no fix) are not filtered"])
    if t == "sensor_msgs/msg/Imu":
        cov = _get(msg, "orientation_covariance") if msg else None
        if isinstance(cov, list) and cov and cov[0] == -1:
            return [], [("orientation", "orientation_covariance[0] = -1: the IMU gives no orientation")], []
        return (_quat("orientation", 3, "sensor_msgs/Imu"), [],
                ["{src}: Imu orientation taken as ROS REP 103 (ENU world, FLU body); for a NED driver use the "
                 "ned_quaternion_to_* transforms, and check the heading reference (true/magnetic)"])
    if t == "nav_msgs/msg/Odometry":
        return (_xy("pose.pose.position", 2, "nav_msgs/Odometry") + _twist("twist.twist.linear", 2, "nav_msgs/"
                "Odometry (child frame)") + _quat("pose.pose.orientation", 1, "nav_msgs/Odometry"), [],
                ["{src}: Odometry x/y taken as east/north of the odom frame origin (REP 103); hadal expects "
                 "metres from the launch point - check the frame and its origin"])
    if t in ("geometry_msgs/msg/PoseStamped", "geometry_msgs/msg/PoseWithCovarianceStamped"):
        pre = "pose" if t.endswith("PoseStamped") else "pose.pose"
        what = t.replace("/msg/", "/")
        return (_xy(f"{pre}.position", 2, what) + _quat(f"{pre}.orientation", 1, what), [],
                ["{src}: pose x/y taken as east/north of the frame origin (REP 103); check the frame and that its "
                 "origin is the launch point"])
    if t in ("geometry_msgs/msg/TwistStamped", "geometry_msgs/msg/TwistWithCovarianceStamped"):
        pre = "twist.linear" if t.endswith("TwistStamped") else "twist.twist.linear"
        return _twist(pre, 2, t.replace("/msg/", "/")), [], checks
    if t == "geometry_msgs/msg/QuaternionStamped":
        return _quat("quaternion", 2, "geometry_msgs/QuaternionStamped"), [], []
    return None


def _ros_time_spec(msg: dict[str, Any] | None, first_log_ns: int | None) -> tuple[dict[str, str], str | None]:
    stamp = _get(msg, "header.stamp") if msg else None
    if isinstance(stamp, dict) and "sec" in stamp and first_log_ns is not None:
        ns = int(stamp.get("sec") or 0) * 1_000_000_000 + int(stamp.get("nanosec") or 0)
        if ns > 0 and abs(ns - first_log_ns) < 60e9:
            return {"field": "header.stamp", "format": "ros_time"}, None
        return {"field": "log_time", "format": "unix_ns"}, (
            f"header.stamp differs from log_time by {abs(ns - first_log_ns) / 1e9:.3g} s (simulated time or unset "
            "stamps?); log_time used")
    return {"field": "log_time", "format": "unix_ns"}, None


# ------------------------------------------------------------------------------------------------ by field names


def _by_names(src: _Src, leaves: Mapping[str, Any], docs: Mapping[str, str], what: str
              ) -> tuple[list[_Cand], list[tuple[str, str]]]:
    """Candidates from field/column names; ``leaves``: name -> first value (None when unknown)."""
    found: dict[str, list[tuple[str, str | None]]] = {}
    unmapped: list[tuple[str, str]] = []
    fix_kind = _fix_kind(src.source, leaves)  # "usbl" / "gnss": the channel's lat/lon are absolute fixes
    gnss = fix_kind is not None
    variances: dict[str, str] = {}
    for name, value in leaves.items():
        if isinstance(value, (bool, str, list, tuple, dict)):
            continue  # text, arrays and flags are not measurements (valid flags: see _valid_field)
        axis = _variance_axis(name) if gnss else None
        if axis is not None:
            variances.setdefault(axis, name)
            continue
        kind, unit = _kind_of(name)
        if kind is None:
            base = _split_unit(name)[0]
            if "depth" in base:
                unmapped.append((name, "depth is not read: hadal derives depth from pressure (TEOS-10)"))
            elif base and not any(t in _TIME_TOKENS for t in base):
                unmapped.append((name, "not recognised as a hadal variable"))
            continue
        found.setdefault(kind, []).append((name, unit))
    cands: list[_Cand] = []

    def add(var: str, name: str, name_unit: str | None, score: int, why: str) -> None:
        doc = docs.get(name)
        unit = _unit_from_text(doc, var)
        how = f"unit from the schema ({doc!r})" if unit else None
        notes = []
        if unit is None and name_unit is not None:
            try:
                unit = check_unit(var, name_unit)
                how = "unit from the name"
            except ConfigError:
                unit = None
        assumed = unit is None
        if assumed:
            unit = CANONICAL_UNITS[var]
            unit, note = _by_magnitude(var, unit, _num(leaves.get(name)))
            how = note or f"unit not stated, {unit} assumed"
            notes.append(f"{src.label}: {name} -> {var}: {how}; check the unit")
        cands.append(_Cand(src.kind, src.source, src.file, var, _fm(name, unit), score,
                           f"{what} {name!r}: {why}; {how}", assumed, src.count, notes))

    for kind, items in found.items():
        for name, _ in items[1:]:
            unmapped.append((name, f"another {kind} field ({items[0][0]!r}) of the same channel was used"))
    first = {k: v[0] for k, v in found.items()}
    is_ctd = {"cond", "temp", "pres"} <= set(first)
    for kind, (name, unit) in first.items():
        if kind.startswith("canonical:"):
            var = kind.split(":", 1)[1]
            add(var, name, unit, 3, "hadal variable name")
        elif kind == "pres":
            if is_ctd:
                add("pressure_ctd_dbar", name, unit, 3, "pressure of a CTD (with conductivity and temperature)")
            else:
                add("pressure_gauge_dbar", name, unit, 2, "pressure")
        elif kind == "temp":
            score = 3 if is_ctd else (1 if "pres" in first else 2)
            add(_KIND_VAR[kind], name, unit, score, "temperature" + (" of a CTD" if is_ctd else ""))
        elif kind in ("lat", "lon"):
            continue
        else:
            add(_KIND_VAR[kind], name, unit, 3 if is_ctd and kind == "cond" else 2, _KIND_WORD.get(kind, kind))
    if "lat" in first and "lon" in first and fix_kind is not None:
        # a channel named as GNSS (topic/file/field says gnss, gps, fix) or as USBL/LBL acoustic positioning:
        # fixes for the navigation smoother, with their logged variances when the channel has them
        lat, lon = first["lat"][0], first["lon"][0]
        label = fix_kind.upper()
        for var, name in ((f"{fix_kind}_latitude_deg", lat), (f"{fix_kind}_longitude_deg", lon)):
            cands.append(_Cand(src.kind, src.source, src.file, var, _fm(name, "deg"), 2,
                               f"{what} {name!r}: {label} fix (the channel is named as {label}), degrees", False,
                               src.count))
        for axis, name in variances.items():
            var = f"{fix_kind}_{axis}_variance_m2"
            cands.append(_Cand(src.kind, src.source, src.file, var, _fm(name, "m2"), 2,
                               f"{what} {name!r}: {axis} variance of the {label} fix (m^2)", False, src.count))
    elif "lat" in first and "lon" in first:
        lat, lon = first["lat"][0], first["lon"][0]
        for var, tr in (("dr_east_m", "latlon_to_east_m"), ("dr_north_m", "latlon_to_north_m")):
            cands.append(_Cand(src.kind, src.source, src.file, var, _fm([lat, lon], "m", tr), 1,
                               f"{what} {lat!r}/{lon!r} (latitude/longitude, degrees) -> metres from the first fix",
                               False, src.count,
                               [f"{src.label}: positions from {lat}/{lon} are relative to the first valid fix; set "
                                "'origin: [lat, lon]' to the launch point if needed"]))
    return cands, unmapped


_GNSS_WORDS = {"gnss", "gps", "fix", "navsat", "navsatfix", "gpsfix"}
#: acoustic positioning from the ship or a seafloor array: USBL/SBL/LBL fixes (valid at any depth)
_USBL_WORDS = {"usbl", "sbl", "lbl", "hipap", "gaps", "posidonia"}


def _fix_kind(source: str, leaves: Mapping[str, Any]) -> str | None:
    """``usbl`` for a channel named as acoustic positioning (the topic / CSV key or a field says usbl, lbl, ...:
    fixes at any depth), ``gnss`` for one named as a GNSS receiver (gnss, gps or fix, e.g. ``m_gps_lat``), else
    None: other latitude/longitude channels (a vehicle's own navigation estimate) stay dead reckoning."""
    words = {t.lower() for t in _tokens(source)}
    for name in leaves:
        words |= {t.lower() for t in _tokens(name)}
    if words & _USBL_WORDS:
        return "usbl"
    return "gnss" if words & _GNSS_WORDS else None


def _variance_axis(name: str) -> str | None:
    """``east``/``north`` for a field named as that axis's position variance (``east_variance``,
    ``north_variance_m2``, ``var_north``), else None."""
    base = {t.lower() for t in _split_unit(name)[0]}
    if not base & {"variance", "var"}:
        return None
    axes = base & {"east", "north"}
    return axes.pop() if len(axes) == 1 else None


def _valid_field(leaves: Mapping[str, Any]) -> str | None:
    for name, v in leaves.items():
        if isinstance(v, bool) and name.lower() in _VALID_NAMES:
            return name
    return None


def _leaves(msg: Any, prefix: str = "") -> dict[str, Any]:
    out: dict[str, Any] = {}
    if isinstance(msg, dict):
        for k, v in msg.items():
            key = f"{prefix}{k}"
            if isinstance(v, dict) and v:
                out.update(_leaves(v, key + "."))
            else:
                out[key] = v
    return out


# ------------------------------------------------------------------------------------------------ per source


def is_mcap(path: str | Path) -> bool:
    """Whether a file is an MCAP log by content, whatever its name (:func:`hadal.formats.detect`)."""
    from hadal.formats import detect

    try:
        return detect(path, strict=False).kind == "mcap"
    except InputError:
        return False


def describe_log(path: str | Path) -> dict[str, Any]:
    """:func:`describe_mcap` for an MCAP file (recognised by its magic bytes), else :func:`describe_csv`."""
    return describe_mcap(path) if is_mcap(path) else describe_csv(path)


def _mcap_sources(paths: Iterable[str | Path], origin: tuple[float, float] | None, files: dict[str, Any],
                  unmapped: list[dict[str, Any]], checks: list[str]) -> tuple[list[_Src], str | None]:
    srcs: dict[str, _Src] = {}
    vehicle_name = None
    for p in paths:
        d = describe_mcap(p)
        files[str(p)] = d
        name = Path(p).name
        if d["truncated"] or d["chunks"]["corrupt"]:
            lost = d["messages_lost"]
            checks.append(f"{name} is damaged ({d['problem'] or str(d['chunks']['corrupt']) + ' corrupt chunk(s)'});"
                          f" {'an unknown number of' if lost is None else lost} message(s) lost")
        if not d["channels"]:
            unmapped.append({"source": name, "file": str(p), "field": None,
                             "reason": "no channels" + (" (the file is damaged before its first channel)"
                                                         if d["truncated"] else "")})
        for ch in d["channels"]:
            topic = ch["topic"]
            vehicle_name = vehicle_name or ch["metadata"].get("vehicle")
            if topic in srcs:  # the same topic in another file: ingest concatenates them
                srcs[topic].count += ch["message_count"]
                for c in srcs[topic].cands:
                    c.count = srcs[topic].count
                continue
            label = f"{name}:{topic}"
            if ch["message_count"] == 0:
                unmapped.append({"source": topic, "file": str(p), "field": None, "reason": "no messages"})
                continue
            msg = ch["first_message"]
            if not isinstance(msg, dict):
                unmapped.append({"source": topic, "file": str(p), "field": None,
                                 "reason": ch["decode_error"] or "messages are not objects"})
                continue
            mtype = ch["message_type"] or ""
            is_ros = ch["message_encoding"] == "cdr"
            time, note = (_ros_time_spec(msg, ch["first_log_time_ns"]) if is_ros
                          else ({"field": "log_time", "format": "unix_ns"}, None))
            if note:
                checks.append(f"{label}: {note}")
            src = _Src("mcap", topic, str(p), time, ch["rate_hz"], ch["message_count"], label=label)
            std = _ros_standard(ros2_type_name(mtype) or "", msg, origin) if is_ros else None
            leaves = _leaves(msg)
            if std is not None:
                cands, skipped, chk = std
                src.cands = [_Cand("mcap", topic, str(p), var, fm, score, why, False, ch["message_count"])
                             for var, fm, score, why in cands]
                for c in src.cands:
                    c.checks = [x.format(src=label) for x in chk]
                for f, reason in skipped:
                    unmapped.append({"source": topic, "file": str(p), "field": f, "reason": reason})
            else:
                names = dict(leaves)
                if list(names) == ["data"]:  # std_msgs/Float64 & co: the topic names the quantity
                    names = {topic.rstrip("/").rsplit("/", 1)[-1]: leaves["data"]}
                cands, skipped = _by_names(src, names, ch["field_docs"], f"{mtype or 'JSON'} field")
                if list(leaves) == ["data"]:
                    for c in cands:
                        c.fm["field"] = "data"
                        c.why += f" (std_msgs value named by its topic {topic})"
                src.cands = cands
                src.valid_field = _valid_field(leaves) if cands else None
                for f, reason in skipped if cands else ():  # nothing mapped: one line for the channel
                    unmapped.append({"source": topic, "file": str(p), "field": f, "reason": reason})
            if not src.cands:
                unmapped.append({"source": topic, "file": str(p), "field": None,
                                 "reason": f"{mtype or ch['message_encoding']}: no field recognised as a hadal "
                                           f"variable (fields: {', '.join(ch['fields'][:8]) or 'none'})"})
                continue
            srcs[topic] = src
    return list(srcs.values()), vehicle_name


def _csv_sources(csv_files: Mapping[str, str | Path], origin: tuple[float, float] | None,
                 files: dict[str, Any], unmapped: list[dict[str, Any]]) -> list[_Src]:
    out = []
    for key, p in csv_files.items():
        d = describe_csv(p)
        files[str(p)] = d
        label = f"{Path(p).name}"
        if d["time_column"] is None:
            unmapped.append({"source": key, "file": str(p), "field": None,
                             "reason": "no time column recognised (name it 'time' with ISO 8601 or Unix times)"})
            continue
        src = _Src("csv", key, str(p), {"field": d["time_column"], "format": d["time_format"]}, d["rate_hz"],
                   d["rows"], delimiter=d["delimiter"], label=label)
        if d.get("glider"):
            out += _glider_sources(src, d, origin, unmapped)
            continue
        leaves: dict[str, Any] = {}
        for c in d["columns"]:
            if c == d["time_column"]:
                continue
            v = d["first_values"].get(c)
            if c.lower() in _VALID_NAMES and str(v).strip().lower() in ("true", "false", "0", "1", "yes", "no"):
                src.valid_field = c
            elif c in d["numeric_columns"]:
                leaves[c] = _num(v)
            elif v is None:
                leaves[c] = None  # empty column: may still be a variable (all missing)
        cands, skipped = _by_names(src, leaves, {}, "CSV column")
        if origin is not None:
            for c in cands:
                if c.fm.get("transform", "").startswith("latlon_"):
                    c.fm["origin"] = [float(origin[0]), float(origin[1])]
        src.cands = cands
        for f, reason in skipped if cands else ():
            unmapped.append({"source": key, "file": str(p), "field": f, "reason": reason})
        if not cands:
            unmapped.append({"source": key, "file": str(p), "field": None,
                             "reason": f"no column recognised as a hadal variable (columns: "
                                       f"{', '.join(d['columns'][:10])})"})
            continue
        out.append(src)
    return out


_GLIDER_NAME = {"seaexplorer": "ALSEAMAR SeaExplorer", "slocum": "Teledyne Slocum dbd2asc"}


def _glider_sources(src: _Src, d: Mapping[str, Any], origin: tuple[float, float] | None,
                    unmapped: list[dict[str, Any]]) -> list[_Src]:
    """A glider log's sources, by its kind's column conventions (:mod:`hadal.ingest.glider`; Slocum units from the
    file's units line): one per sensor group of the log (Slocum CTD, navigation, altimeter), all reading the same
    ``sources.csv`` key; none when no column is a hadal variable."""
    from hadal.ingest.glider import glider_fields

    kind = d["glider"]
    _, fields, skipped = glider_fields(kind, d["columns"], d.get("units") or {})
    groups = list(dict.fromkeys(f.group for f in fields))
    srcs = []
    for g in groups:
        part = _Src("csv", src.source if len(groups) == 1 else f"{src.source}@{g}", src.file, dict(src.time),
                    src.rate_hz, src.count, delimiter=src.delimiter, label=src.label, csv_key=src.source)
        _glider_cands(part, kind, [f for f in fields if f.group == g], origin)
        srcs.append(part)
    for name, reason in skipped:
        unmapped.append({"source": src.source, "file": src.file, "field": name, "reason": reason})
    if not fields:
        unmapped.append({"source": src.source, "file": src.file, "field": None,
                         "reason": f"{_GLIDER_NAME[kind]} log: no column recognised as a hadal variable (columns: "
                                   f"{', '.join(d['columns'][:10])})"})
    return srcs


def _glider_cands(src: _Src, kind: str, fields: list[Any], origin: tuple[float, float] | None) -> None:
    what = f"{_GLIDER_NAME[kind]} column"
    for f in fields:
        fm = _fm(f.field, f.units, f.transform)
        if f.fill_values:
            fm["fill_values"] = [float(v) for v in f.fill_values]
        if f.transform and f.transform.startswith("latlon_") and origin is not None:
            fm["origin"] = [float(origin[0]), float(origin[1])]
        src.cands.append(_Cand("csv", src.source, src.file, f.variable, fm, f.score,
                               f"{what} {f.field if isinstance(f.field, str) else '/'.join(f.field)!r}: "
                               f"{f.why.split(' ', 1)[1]}",
                               False, src.count))
    if src.cands and src.time["format"].startswith("%d"):
        src.cands[0].checks.append(f"{src.label}: times read day first ({src.time['format']}), the {_GLIDER_NAME[kind]}"
                                   " convention")
    if src.cands and any(c.fm.get("transform", "").startswith("latlon_") for c in src.cands) and origin is None:
        src.cands[0].checks.append(f"{src.label}: glider positions are metres from its first valid position; set "
                                   "'origin: [lat, lon]' (or hadal init --launch) for another origin")


def _resolve(srcs: list[_Src], unmapped: list[dict[str, Any]]) -> dict[str, dict[str, _Cand]]:
    """Best candidate per variable -> {source: {variable: cand}}; the losers go to ``unmapped``."""
    best: dict[str, _Cand] = {}
    allc = _without_depth_pressure([c for s in srcs for c in s.cands], unmapped)
    for c in allc:
        b = best.get(c.variable)
        if b is None or (c.score, c.count) > (b.score, b.count):
            best[c.variable] = c
    for c in allc:
        w = best[c.variable]
        if w is not c:
            unmapped.append({"source": _key_of(c), "file": c.file, "field": _label(c.fm),
                             "reason": f"{c.variable} is taken from {_key_of(w)} ({_label(w.fm)}) instead"})
    out: dict[str, dict[str, _Cand]] = {}
    for var in CANONICAL_UNITS:
        if var in best:
            out.setdefault(best[var].source, {})[var] = best[var]
    return out


def _without_depth_pressure(allc: list[_Cand], unmapped: list[dict[str, Any]]) -> list[_Cand]:
    """A glider's on-board depth offered as pressure (:data:`hadal.ingest.glider.DEPTH_PRESSURE_TRANSFORM`) is kept
    only when no log of the dive has a pressure channel (hadal derives depth from pressure); else it is unmapped."""
    from hadal.ingest.glider import DEPTH_PRESSURE_TRANSFORM

    depth = [c for c in allc if c.fm.get("transform") == DEPTH_PRESSURE_TRANSFORM]
    if not depth or not any(c.variable in ("pressure_ctd_dbar", "pressure_gauge_dbar") and c not in depth
                            for c in allc):
        return allc
    for c in depth:
        unmapped.append({"source": _key_of(c), "file": c.file, "field": c.fm["field"][0],
                         "reason": "depth is not read: hadal derives depth from pressure (TEOS-10), which another "
                                   "log of the dive has"})
    return [c for c in allc if c not in depth]


def _key_of(c: _Cand) -> str:
    """The topic or ``sources.csv`` key of a candidate (a glider log's sensor groups read one key: ``key@ctd``;
    the keys hadal init writes hold no ``@``)."""
    return c.source.split("@", 1)[0] if c.kind == "csv" else c.source


def _label(fm: Mapping[str, Any]) -> str:
    f = fm["field"]
    return f if isinstance(f, str) else f"{fm.get('transform')}({', '.join(f)})"


def _role(variables: set[str]) -> str:
    if variables & {"conductivity_s_m", "pressure_ctd_dbar"}:
        return "ctd"
    if "pressure_gauge_dbar" in variables:
        return "gauge"
    att = bool(variables & {"heading_deg", "pitch_deg", "roll_deg"})
    pos = bool(variables & {"dr_east_m", "dr_north_m", "speed_m_s"})
    if "altitude_m" in variables and not (att and pos):  # else a navigation board that logs the altimeter too
        return "altimeter"
    if att and pos:
        return "navigation"
    if att:
        return "attitude"
    if pos:
        return "position"
    if any(v.startswith("gnss_") for v in variables):
        return "gnss"
    if any(v.startswith("usbl_") for v in variables):
        return "usbl"
    if "temperature_its90_degc" in variables:
        return "thermometer"
    return "sensor"


def _source_block(src: _Src, cands: Mapping[str, _Cand]) -> dict[str, Any]:
    block: dict[str, Any] = {}
    if src.kind == "mcap":
        block["topic"] = src.source
    else:
        block["source"] = src.csv_key or src.source
        if src.delimiter != ",":
            block["delimiter"] = src.delimiter
    block["time"] = dict(src.time)
    if src.valid_field:
        block["valid_field"] = src.valid_field
    block["fields"] = {var: dict(c.fm) for var, c in cands.items()}
    return block


def suggest_vehicle(mcap_paths: Iterable[str | Path] = (), csv_files: Mapping[str, str | Path] | None = None, *,
                    launch: tuple[float, float] | None = None, vehicle_name: str | None = None) -> Suggestion:
    """Suggest the vehicle mapping for a dive's MCAP logs and sensor CSV files (see the module docstring).

    ``csv_files`` maps the dive.yaml ``sources.csv`` keys to paths (the keys become ``csv.source``).
    ``launch`` ``(latitude, longitude)`` is the origin of positions computed from GNSS fixes. Describing the
    files raises :class:`~hadal.errors.InputError` for a file that is missing or not MCAP/CSV.
    """
    files: dict[str, Any] = {}
    unmapped: list[dict[str, Any]] = []
    checks: list[str] = []
    mcap_paths = list(mcap_paths)
    msrcs, vname = _mcap_sources(mcap_paths, launch, files, unmapped, checks)
    csrcs = _csv_sources(dict(csv_files or {}), launch, files, unmapped)
    mwin = _resolve(msrcs, unmapped)
    cwin = _resolve(csrcs, unmapped)
    by_src = {("mcap", s.source): s for s in msrcs} | {("csv", s.source): s for s in csrcs}

    sensors: dict[str, dict[str, Any]] = {}
    info: dict[str, dict[str, Any]] = {}  # sensor -> {rate, sources}
    taken: set[str] = set()

    def new_name(role: str) -> str:
        name, i = role, 2
        while name in sensors:
            name, i = f"{role}_{i}", i + 1
        return name

    msens: dict[frozenset[str], str] = {}
    for topic, cands in mwin.items():
        src = by_src[("mcap", topic)]
        name = new_name(_role(set(cands)))
        sensors[name] = {"mcap": _source_block(src, cands)}
        info[name] = {"rate": src.rate_hz or 0.0, "cands": list(cands.values()), "csv_only": False}
        msens[frozenset(cands)] = name
        taken |= set(cands)
    for key, cands in cwin.items():
        src = by_src[("csv", key)]
        vars_ = frozenset(cands)
        if vars_ in msens:
            sname = msens[vars_]
            sensors[sname]["csv"] = _source_block(src, cands)
            info[sname]["cands"].extend(cands.values())
        elif not (vars_ & taken):
            name = new_name(_role(set(cands)))
            sensors[name] = {"csv": _source_block(src, cands)}
            info[name] = {"rate": src.rate_hz or 0.0, "cands": list(cands.values()), "csv_only": bool(mwin)}
            taken |= vars_
            if mcap_paths and mwin:
                checks.append(f"sensor {name!r} is only in CSV {Path(src.file).name}: ingest reads the MCAP logs "
                              "when dive.yaml lists any (set ingest.source: csv to use the CSV files)")
        else:
            for c in cands.values():
                unmapped.append({"source": key, "file": c.file, "field": _label(c.fm),
                                 "reason": f"CSV gives {', '.join(sorted(vars_))}, not the same set of variables as "
                                           "one MCAP sensor (a sensor's csv and mcap mappings must match)"})

    mapped: list[dict[str, Any]] = []
    for name, i in info.items():
        for c in i["cands"]:
            mapped.append({"variable": c.variable, "sensor": name, "kind": c.kind, "source": _key_of(c),
                           "file": c.file, "field": c.fm["field"], "units": c.fm["units"],
                           "transform": c.fm.get("transform"), "offset": c.fm.get("offset"), "why": c.why,
                           "assumed": c.assumed})
            checks.extend(x for x in c.checks if x not in checks)
    mapped.sort(key=lambda m: (list(CANONICAL_UNITS).index(m["variable"]), m["kind"]))
    if not sensors:
        return Suggestion(None, [], unmapped, checks, files)
    if mcap_paths and not mwin:
        checks.append("no MCAP channel could be mapped: ingest must read the CSV files (ingest.source: csv)")

    readable = [n for n in sensors if not info[n]["csv_only"]]
    ctd = [n for n in readable if {"conductivity_s_m", "pressure_ctd_dbar"} & _vars(sensors[n])]
    gauge = [n for n in readable if "pressure_gauge_dbar" in _vars(sensors[n])]
    if ctd:
        base, why = ctd[0], "the CTD"
    elif gauge:
        base, why = gauge[0], "the pressure sensor (no CTD found)"
    else:
        base = max(readable, key=lambda n: info[n]["rate"])
        why = f"the mapped sensor with the highest rate ({info[base]['rate']:.3g} Hz; no CTD or pressure sensor)"
        checks.append(f"no CTD or pressure sensor was found: without pressure there is no depth (derive/match need "
                      f"it); time base {base!r}")
    for n, s in sensors.items():
        s_vars = _vars(s)
        req = n == base or bool(s_vars & {"pressure_ctd_dbar", "pressure_gauge_dbar"})
        s["required"] = bool(req and not info[n]["csv_only"])
        sensors[n] = {"required": s["required"], **{k: v for k, v in s.items() if k != "required"}}
    order = sorted(sensors, key=lambda n: (_ROLE_ORDER.index(n.rsplit("_", 1)[0]) if n.rsplit("_", 1)[0]
                                           in _ROLE_ORDER else len(_ROLE_ORDER), n))
    vehicle = {"vehicle": vehicle_name or vname or "unknown", "time_base": base,
               "sensors": {n: sensors[n] for n in order}}
    VehicleConfig.model_validate(vehicle)  # a bug here, not a user error: let it raise
    from hadal.ingest.build import (
        SENSOR_VARIABLES,  # the optional columns (GNSS, USBL, vendor salinity) may be absent
    )

    missing = [v for v in SENSOR_VARIABLES if v not in _all_vars(vehicle)]
    if missing:
        checks.append(f"not found in the logs (columns stay empty, flag 9): {', '.join(missing)}")
    checks.insert(0, f"time base: {base!r}, {why}")
    return Suggestion(vehicle, mapped, unmapped, checks, files,
                      mcap_used=sorted({c["file"] for c in mapped if c["kind"] == "mcap"}),
                      csv_used={c["source"]: c["file"] for c in mapped if c["kind"] == "csv"})


def _vars(sensor: Mapping[str, Any]) -> set[str]:
    src = sensor.get("mcap") or sensor.get("csv") or {}
    return set(src.get("fields", {}))


def _all_vars(vehicle: Mapping[str, Any]) -> set[str]:
    return {v for s in vehicle["sensors"].values() for v in _vars(s)}


# ------------------------------------------------------------------------------------------------ YAML


def _flow(v: Any) -> str:
    return yaml.safe_dump(v, default_flow_style=True, width=10_000, sort_keys=False).strip().removesuffix("...").strip()


def render_vehicle_yaml(suggestion: Suggestion, *, title: str | None = None) -> str:
    """The suggestion as a commented ``vehicle.yaml`` (loads back to ``suggestion.vehicle``).

    Each mapped field carries a comment saying why it was mapped; what was not mapped and what to check follow
    as comments at the end. When nothing was mapped the text is comments only (loads as ``None``)."""
    lines = [f"# {title or 'Vehicle channel mapping suggested by hadal init'} (hadal.ingest.VehicleConfig).",
             "# Per sensor: the MCAP topic (or CSV file: key of dive.yaml sources.csv) and field -> variable, with",
             "# the unit each field is logged in; units, offsets and transforms are applied explicitly and recorded",
             "# in the sensors product metadata. Time formats: unix_ns | unix_ms | unix_s | iso8601 | ros_time |",
             "# a strftime pattern; MCAP `log_time` is the recorder's time (ns since the epoch)."]
    v = suggestion.vehicle
    why = {(m["sensor"], m["kind"], m["variable"]): m for m in suggestion.mapped}
    if v is None:
        lines.append("# Nothing in these logs could be mapped to a hadal variable: there is nothing to ingest.")
    else:
        checks = [c for c in suggestion.checks if c.startswith("time base")]
        lines += [f"vehicle: {_flow(v['vehicle'])}",
                  f"time_base: {_flow(v['time_base'])}" + (f"  # {checks[0]}" if checks else ""),
                  "sensors:"]
        for name, s in v["sensors"].items():
            lines.append(f"  {_flow(name)}:")
            lines.append(f"    required: {_flow(s['required'])}")
            for kind in ("mcap", "csv"):
                if kind not in s:
                    continue
                src = s[kind]
                lines.append(f"    {kind}:")
                for k, val in src.items():
                    if k == "fields":
                        continue
                    lines.append(f"      {k}: {_flow(val)}")
                lines.append("      fields:")
                for var, fm in src["fields"].items():
                    m = why.get((name, kind, var))
                    note = f"  # {m['why']}" if m else ""
                    if m and m["assumed"]:
                        note += " - CHECK THE UNIT"
                    lines.append(f"        {var}: {_flow(fm)}{note}")
    if suggestion.unmapped:
        lines += ["", "# Not mapped:"]
        lines += [f"#   {u['source']}" + (f" {u['field']}" if u.get("field") else "") + f": {u['reason']}"
                  for u in suggestion.unmapped]
    rest = [c for c in suggestion.checks if not c.startswith("time base")]
    if rest:
        lines += ["", "# Check before processing:"]
        lines += [f"#   - {c}" for c in rest]
    return "\n".join(lines) + "\n"
