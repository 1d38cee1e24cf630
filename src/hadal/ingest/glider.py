"""Glider log conventions: ALSEAMAR SeaExplorer ``;``-delimited logs and Teledyne Slocum ``dbd2asc`` text.

What is read from the files themselves, and what is the kind's published convention:

* **Slocum dbd2asc** (``.dat``, e.g. from ``dbd2asc usf-bass-2016-252-1-14.sbd``): a block of ``key: value``
  header lines starting ``dbd_label: DBD_ASC(...)``, whose ``num_ascii_tags`` says how many there are and
  ``num_label_lines`` how many label lines follow (sensor names, units, byte sizes); then space-delimited data
  with ``NaN`` where a sensor was not updated in that cycle. Every unit is taken from the file's units line
  (``s/m``, ``degc``, ``bar``, ``rad``, ``m``, ``timestamp``; ``lat``/``lon`` mean NMEA ``[-]DDMM.mmm``). The sensor
  names are Teledyne's masterdata names; which of them hold the CTD, the altimeter, the attitude and the
  position follows GUTILS (``gutils/slocum/__init__.py`` ``SlocumReader``: time ``m_present_time`` else
  ``sci_m_present_time``; pressure ``sci_water_pressure`` (bar -> dbar x 10); ``sci_water_temp``;
  ``sci_water_cond``; NMEA positions, latitudes above 9000 / longitudes of 18000 and above being the
  masterdata's "no value" defaults). A science-bay value (``sci_*``) of exactly 0 is the science computer's
  "no data" (the all-zero row it writes when a sensor has not reported, e.g. the file's first cycle): missing
  data, as pyglider screens it (``pyglider/slocum.py`` applies ``utils._zero_screen``, ``val[val == 0] = nan``,
  to every science sensor before its conversion). A ``NaN`` is a sensor not updated in that cycle: each sensor group (CTD,
  navigation, altimeter) is its own sensor of the vehicle mapping, and a row without any of its values is no
  sample of it.
* **SeaExplorer** navigation (``*.gli.sub.*``: ``Timestamp`` ``DD/MM/YYYY HH:MM:SS``, ``Heading``/``Pitch``/``Roll`` in
  degrees, ``Lat``/``Lon`` NMEA ``DDMM.mmm``, ``Altitude`` in m with -1 for "no bottom detected") and payload
  (``*.pld1.sub.*``: ``PLD_REALTIMECLOCK`` ``DD/MM/YYYY HH:MM:SS.fff``, ``GPCTD_CONDUCTIVITY`` S/m,
  ``GPCTD_TEMPERATURE`` degC, ``GPCTD_PRESSURE`` dbar, RBR ``LEGATO_*`` with conductivity in mS/cm,
  ``NAV_LATITUDE``/``NAV_LONGITUDE`` NMEA; 9999 is the payload's fill value). Conventions as pyglider reads them
  (``pyglider/seaexplorer.py``: the two ``strptime`` formats, ``_remove_fill_values(fill_value=9999)``;
  ``utils.nmea2deg``; units from its example ``deploymentRealtime.yml`` files). The navigation board's
  ``Temperature`` and ``Pa`` are the hull's inside temperature and pressure, not the water's.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = ["DbdAscHeader", "dbd_asc_header", "nmea_to_deg", "glider_kind", "glider_fields", "unit_of_label", "SEAEXPLORER_FILL",
           "ALTITUDE_NO_BOTTOM", "SLOCUM_SCIENCE_NO_DATA"]

#: SeaExplorer payload fill value (pyglider ``seaexplorer._remove_fill_values``)
SEAEXPLORER_FILL = 9999.0
#: SeaExplorer altimeter value for "no bottom detected"
ALTITUDE_NO_BOTTOM = -1.0
#: Slocum science-bay (``sci_*``) "no data" value (pyglider ``utils._zero_screen`` on every science sensor)
SLOCUM_SCIENCE_NO_DATA = 0.0
#: Slocum masterdata "no value" defaults of NMEA positions are beyond these magnitudes (GUTILS ``standardize``)
NMEA_LAT_MAX, NMEA_LON_MAX = 9000.0, 18000.0

_DBD_LABEL = re.compile(r"^dbd_label:\s*DBD_ASC", re.IGNORECASE)


@dataclass
class DbdAscHeader:
    """The header block of a Slocum ``dbd2asc`` file: its ``key: value`` tags and the label lines."""

    tags: dict[str, str]
    #: lines before the sensor-names line (the ``key: value`` block)
    n_tag_lines: int
    #: label lines (names, units, byte sizes), ``num_label_lines``
    n_label_lines: int
    names: list[str] = field(default_factory=list)
    units: list[str] = field(default_factory=list)

    def units_of(self) -> dict[str, str]:
        return dict(zip(self.names, self.units, strict=False))


def dbd_asc_header(text: str) -> DbdAscHeader | None:
    """The :class:`DbdAscHeader` of a text that starts ``dbd_label: DBD_ASC...`` (``None`` for any other text).
    The number of tag lines is ``num_ascii_tags`` (counted when absent), of label lines ``num_label_lines``
    (3 when absent: names, units, byte sizes)."""
    lines = text.lstrip("\ufeff").splitlines()
    if not lines or not _DBD_LABEL.match(lines[0].strip()):
        return None
    tags: dict[str, str] = {}
    n = 0
    while n < len(lines) and re.match(r"^\s*[A-Za-z_][A-Za-z0-9_]*:\s", lines[n] + " "):
        k, _, v = lines[n].partition(":")
        tags[k.strip()] = v.strip()
        n += 1
    n_tags = _int(tags.get("num_ascii_tags"), n)
    n_labels = _int(tags.get("num_label_lines"), 3)
    names = lines[n_tags].split() if len(lines) > n_tags else []
    units = lines[n_tags + 1].split() if n_labels >= 2 and len(lines) > n_tags + 1 else []
    return DbdAscHeader(tags, n_tags, max(n_labels, 1), names, units)


def _int(v: Any, default: int) -> int:
    try:
        return int(str(v).strip())
    except (TypeError, ValueError):
        return default


def nmea_to_deg(values: Any) -> np.ndarray:
    """NMEA ``[-]DDDMM.mmmm`` -> decimal degrees (pyglider ``utils.nmea2deg``: ``fix(x/100) + sign(x) *
    (|x| mod 100) / 60``); magnitudes of 18000 and above (Slocum masterdata defaults) and minutes of 60 and above
    are not positions: NaN."""
    x = np.asarray(values, dtype=np.float64)
    with np.errstate(invalid="ignore"):
        minutes = np.remainder(np.abs(x), 100.0)
        deg = np.fix(x / 100.0) + np.sign(x) * minutes / 60.0
        bad = ~np.isfinite(x) | (np.abs(x) >= NMEA_LON_MAX) | (minutes >= 60.0)
    return np.where(bad, np.nan, deg)


# ------------------------------------------------------------------------------------------------ column tables

#: SeaExplorer time columns and their (day-first) formats (pyglider ``seaexplorer.raw_to_rawnc``)
SEAEXPLORER_TIME = {"Timestamp": "%d/%m/%Y %H:%M:%S", "PLD_REALTIMECLOCK": "%d/%m/%Y %H:%M:%S.%f"}

#: SeaExplorer column -> (variable, unit, fill values, score, why); positions are the (lat, lon) pairs below
_SEAEXPLORER: dict[str, tuple[str, str, tuple[float, ...], int, str]] = {
    "GPCTD_CONDUCTIVITY": ("conductivity_s_m", "S/m", (SEAEXPLORER_FILL,), 3, "Sea-Bird GPCTD conductivity (S/m)"),
    "GPCTD_TEMPERATURE": ("temperature_its90_degc", "degC_its90", (SEAEXPLORER_FILL,), 3,
                          "Sea-Bird GPCTD temperature (degC, ITS-90)"),
    "GPCTD_PRESSURE": ("pressure_ctd_dbar", "dbar", (SEAEXPLORER_FILL,), 3, "Sea-Bird GPCTD pressure (dbar)"),
    "LEGATO_CONDUCTIVITY": ("conductivity_s_m", "mS/cm", (SEAEXPLORER_FILL,), 3, "RBR Legato conductivity (mS/cm)"),
    "LEGATO_TEMPERATURE": ("temperature_its90_degc", "degC_its90", (SEAEXPLORER_FILL,), 3,
                           "RBR Legato temperature (degC, ITS-90)"),
    "LEGATO_PRESSURE": ("pressure_ctd_dbar", "dbar", (SEAEXPLORER_FILL,), 3, "RBR Legato pressure (dbar)"),
    "Heading": ("heading_deg", "deg", (), 2, "navigation board heading (degrees)"),
    "Pitch": ("pitch_deg", "deg", (), 2, "navigation board pitch (degrees)"),
    "Roll": ("roll_deg", "deg", (), 2, "navigation board roll (degrees)"),
    "Altitude": ("altitude_m", "m", (ALTITUDE_NO_BOTTOM,), 2,
                 "altimeter range to the bottom (m); -1 = no bottom detected, a fill value (missing)"),
}
_SEAEXPLORER_POS = (("Lat", "Lon", 2, "navigation board position"),
                    ("NAV_LATITUDE", "NAV_LONGITUDE", 1, "payload copy of the navigation position"))
_SEAEXPLORER_NOT = {
    "Temperature": "navigation board's internal temperature, not the water's",
    "Pa": "hull internal pressure (Pa), not the water's",
    "Depth": "depth is not read: hadal derives depth from pressure (TEOS-10)",
    "NAV_DEPTH": "depth is not read: hadal derives depth from pressure (TEOS-10)",
    "AROD_FT_TEMP": "oxygen optode temperature, not the CTD's",
}

#: Slocum: variable -> masterdata sensor names in order of preference (GUTILS ``SlocumReader``), with the score
_SLOCUM: dict[str, tuple[tuple[str, ...], int, str, str]] = {
    "conductivity_s_m": (("sci_water_cond",), 3, "science CTD conductivity", "ctd"),
    "temperature_its90_degc": (("sci_water_temp",), 3, "science CTD temperature", "ctd"),
    "pressure_ctd_dbar": (("sci_water_pressure",), 3, "science CTD pressure", "ctd"),
    "pressure_gauge_dbar": (("m_water_pressure", "m_pressure"), 2, "glider pressure sensor", "gauge"),
    "altitude_m": (("m_altitude",), 2, "altimeter range to the bottom", "altimeter"),
    "heading_deg": (("m_heading",), 2, "glider compass heading", "navigation"),
    "pitch_deg": (("m_pitch",), 2, "glider pitch", "navigation"),
    "roll_deg": (("m_roll",), 2, "glider roll", "navigation"),
}
_SLOCUM_TIME = ("m_present_time", "sci_m_present_time")
_SLOCUM_POS = (("m_lat", "m_lon", 2, "glider position (dead reckoned between GPS fixes)"),
               ("m_gps_lat", "m_gps_lon", 1, "GPS fixes"))
#: Slocum unit words that are not in hadal's unit table, and the unit they stand for
_SLOCUM_UNITS = {"lat": "nmea", "lon": "nmea", "timestamp": "unix_s", "degc": "degC_its90", "s/m": "S/m"}


def unit_of_label(label: str) -> str | None:
    """hadal's unit for a Slocum units-line word (``s/m`` -> ``S/m``, ``degc`` -> ``degC_its90``, ``bar``, ``rad``,
    ``m``; ``lat``/``lon`` -> ``nmea``, ``timestamp`` -> ``unix_s``), ``None`` when hadal has no such unit."""
    from hadal.errors import ConfigError
    from hadal.ingest.units import normalise_unit

    word = _SLOCUM_UNITS.get(label.strip().lower(), label.strip())
    if word in ("nmea", "unix_s"):
        return word
    try:
        return normalise_unit(word)
    except ConfigError:
        return None


def glider_kind(columns: list[str], dbd: DbdAscHeader | None = None) -> str | None:
    """``slocum`` (a dbd2asc header), ``seaexplorer`` (a SeaExplorer time column with its kind's columns) or
    ``None``."""
    if dbd is not None:
        return "slocum"
    cols = set(columns)
    if "Timestamp" in cols and {"NavState", "Heading"} & cols:
        return "seaexplorer"
    if "PLD_REALTIMECLOCK" in cols:
        return "seaexplorer"
    return None


@dataclass
class GliderField:
    """One suggested mapping: ``variable`` from ``field`` (or a [lat, lon] pair with a ``transform``)."""

    variable: str
    field: str | list[str]
    units: str
    score: int
    why: str
    fill_values: tuple[float, ...] = ()
    transform: str | None = None
    #: the sensor of the log this column belongs to (Slocum: ``ctd``, ``navigation``, ``altimeter``, ``gauge``; one
    #: SeaExplorer file is one sensor: ``None``)
    group: str | None = None


def glider_fields(kind: str, columns: list[str], units: dict[str, str] | None = None
                  ) -> tuple[dict[str, str] | None, list[GliderField], list[tuple[str, str]]]:
    """The time spec, the suggested fields and the (column, reason) left out of a glider log of ``kind``.

    Slocum units come from the file's units line (``units``); a unit hadal does not know leaves that column
    out with the reason."""
    if kind == "slocum":
        return _slocum_fields(columns, units or {})
    return _seaexplorer_fields(columns)


def _seaexplorer_fields(columns: list[str]) -> tuple[dict[str, str] | None, list[GliderField],
                                                     list[tuple[str, str]]]:
    cols = set(columns)
    tcol = next((c for c in SEAEXPLORER_TIME if c in cols), None)
    time = {"field": tcol, "format": SEAEXPLORER_TIME[tcol]} if tcol else None
    out: list[GliderField] = []
    skipped = [(c, r) for c, r in _SEAEXPLORER_NOT.items() if c in cols]
    for c, (var, unit, fill, score, why) in _SEAEXPLORER.items():
        if c in cols:
            out.append(GliderField(var, c, unit, score, f"SeaExplorer {why}", fill))
    for lat, lon, score, why in _SEAEXPLORER_POS:
        if lat in cols and lon in cols:
            out += _positions(lat, lon, score, f"SeaExplorer {why}")
            break
    for dcol, lat in (("Depth", "Lat"), ("NAV_DEPTH", "NAV_LATITUDE")):
        if dcol in cols and lat in cols and not _has_pressure(out):
            out.append(_depth_pressure_field(dcol, lat, f"SeaExplorer navigation depth {dcol!r} (m)"))
            skipped = [(c, r) for c, r in skipped if c != dcol]
            break
    return time, out, skipped


#: the transform that turns a glider's on-board depth into pressure (used only when its logs have no pressure)
DEPTH_PRESSURE_TRANSFORM = "depth_ddmm_lat_to_pressure_dbar"


def _has_pressure(out: list[GliderField]) -> bool:
    return any(f.variable in ("pressure_ctd_dbar", "pressure_gauge_dbar") for f in out)


def _depth_pressure_field(depth_col: str, lat_col: str, what: str) -> GliderField:
    """Gauge pressure from a glider's on-board depth (computed from its own pressure sensor) by TEOS-10
    ``gsw.p_from_z`` at its NMEA latitude: offered for a log without any pressure channel; ``hadal init`` keeps it
    only when none of the dive's logs has one (:func:`hadal.ingest.suggest`)."""
    return GliderField("pressure_gauge_dbar", [depth_col, lat_col], "dbar", 1,
                       f"{what}; no pressure channel in this log -> pressure by TEOS-10 gsw.p_from_z at the latitude "
                       f"{lat_col!r}", transform=DEPTH_PRESSURE_TRANSFORM, group="gauge")


def _slocum_fields(columns: list[str], units: dict[str, str]) -> tuple[dict[str, str] | None, list[GliderField],
                                                                     list[tuple[str, str]]]:
    from hadal.errors import ConfigError
    from hadal.ingest.units import check_unit

    cols = set(columns)
    tcol = next((c for c in _SLOCUM_TIME if c in cols), None)
    time = {"field": tcol, "format": "unix_s"} if tcol else None
    out: list[GliderField] = []
    skipped: list[tuple[str, str]] = []
    for var, (names, score, why, group) in _SLOCUM.items():
        name = next((n for n in names if n in cols), None)
        if name is None:
            continue
        raw = units.get(name, "")
        try:
            unit = check_unit(var, unit_of_label(raw) or raw)
        except ConfigError as exc:
            skipped.append((name, f"units line says {raw!r}: {exc}"))
            continue
        sci = name.startswith("sci_")
        out.append(GliderField(var, name, unit, score,
                               f"Slocum {why} {name!r}, units line {raw!r}"
                               + ("; 0 = the science bay's no-data value (missing)" if sci else ""),
                               fill_values=(SLOCUM_SCIENCE_NO_DATA,) if sci else (), group=group))
    for lat, lon, score, why in _SLOCUM_POS:
        if lat in cols and lon in cols:
            ul, uo = units.get(lat, "lat"), units.get(lon, "lon")
            if (ul, uo) != ("lat", "lon"):
                skipped.append((lat, f"units line says {ul!r}/{uo!r}, not NMEA lat/lon"))
                continue
            out += _positions(lat, lon, score, f"Slocum {why}", "navigation")
            if lat == "m_lat":  # the track is dead reckoned: its GPS fixes are measurements of their own
                out += _gps_fixes(cols, units)
            break
    if "m_depth" in cols:
        depth_field = _slocum_depth_as_pressure(cols, units, out)
        if depth_field is None:
            skipped.append(("m_depth", "depth is not read: hadal derives depth from pressure (TEOS-10)"))
        else:
            out.append(depth_field)
    return time, out, skipped


def _slocum_depth_as_pressure(cols: set[str], units: dict[str, str], out: list[GliderField]) -> GliderField | None:
    """A flight-computer log without any pressure channel (no ``sci_water_pressure``, ``m_pressure``,
    ``m_water_pressure``) but with ``m_depth`` in metres (computed on board from the glider's pressure sensor):
    the gauge pressure from it by TEOS-10 ``gsw.p_from_z`` at the log's NMEA latitude; ``None`` otherwise."""
    if _has_pressure(out):
        return None
    lat = next((la for la, _lo, _s, _w in _SLOCUM_POS if la in cols and units.get(la, "lat") == "lat"), None)
    if lat is None or units.get("m_depth", "m").strip().lower() != "m":
        return None
    return _depth_pressure_field("m_depth", lat, "Slocum glider depth 'm_depth' (units line 'm')")


#: Slocum's "no fix" value of ``m_gps_lat``/``m_gps_lon`` (masterdata default; NMEA-impossible, also NaN by
#: :func:`nmea_to_deg`)
SLOCUM_GPS_FILL = 69696969.0


def _gps_fixes(cols: set[str], units: dict[str, str]) -> list[GliderField]:
    """Slocum ``m_gps_lat``/``m_gps_lon`` (NMEA, logged at the surface) as GNSS fixes ``gnss_latitude_deg``/
    ``gnss_longitude_deg`` for the navigation smoother, beside the dead-reckoned ``m_lat``/``m_lon`` track; none
    when the log lacks them or its units line does not say lat/lon."""
    if not {"m_gps_lat", "m_gps_lon"} <= cols or (units.get("m_gps_lat", "lat"), units.get("m_gps_lon", "lon")) != (
            "lat", "lon"):
        return []
    return [GliderField(var, name, "deg", 2, f"Slocum GPS fix {name!r} (NMEA DDMM.mmm -> degrees), at the surface",
                        fill_values=(SLOCUM_GPS_FILL,), transform="nmea_to_deg", group="gnss")
            for var, name in (("gnss_latitude_deg", "m_gps_lat"), ("gnss_longitude_deg", "m_gps_lon"))]


def _positions(lat: str, lon: str, score: int, why: str, group: str | None = None) -> list[GliderField]:
    return [GliderField(var, [lat, lon], "m", score,
                        f"{why} {lat!r}/{lon!r} (NMEA DDMM.mmm -> degrees) -> metres {d} of the origin",
                        transform=f"latlon_ddmm_to_{d}_m", group=group)
            for var, d in (("dr_east_m", "east"), ("dr_north_m", "north"))]
