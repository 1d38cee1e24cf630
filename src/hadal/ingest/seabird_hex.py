"""Sea-Bird raw ``.hex`` reader: decode the scans and convert them with the calibration in the header (DatCnv).

A ``.hex`` file uploaded from an SBE 19plus V2 or SBE 16plus V2 (SeatermV2 / Seaterm232) is a ``*``-prefixed
header followed by ``*END*`` and one line of hexadecimal characters per scan. The header carries what DatCnv
needs, in one of two forms:

* **text** (``ds`` / ``dcal`` command echo): ``* mode = profile, ...``, ``* pressure sensor = strain gauge``,
  ``* Ext Volt 0 = yes, ...``, ``* SBE 38 = no, WETLABS = no, OPTODE = no, SBE63 = no, Gas Tension Device = no``,
  ``* number of scans to average = 1``, then ``* temperature:  22-Jul-16`` / ``*     TA0 = ...``,
  ``* conductivity: ...`` (G, H, I, J, CPCOR, CTCOR, CSLOPE), ``* pressure S/N = ..., range = ... psia: <date>``
  (PA0..PA2, PTCA0..2, PTCB0..2, PTEMPA0..2, POFFSET), ``* volt N: offset = ..., slope = ...`` and the ``dh``
  cast line ``* cast 1 10 Dec 2016 06:16:51 samples 1 to 3069, avg = 1, stop = ...``;
* **XML** (``GetHD`` / ``GetCD`` / ``GetCC`` echo inside ``<InstrumentState>``): ``<HardwareData>``,
  ``<ConfigurationData>`` (``<ProfileMode>``/``<MooredMode>``, ``<DataChannels>``: ``ExtVolt0..5``, ``SBE38``,
  ``WETLABS``, ``OPTODE``, ``SBE63``, ``GTD``, ``DualGTD``; ``<OutputFormat>``) and ``<CalibrationCoefficients>``
  (``<Calibration id='Main Temperature'>`` TA0..., ``'Main Conductivity'``, ``'Main Pressure'``, ``'Volt N'``).

Scan layout (SBE 19plus V2 / 16plus V2 manual, "OutputFormat=0 raw hex"; ``n`` = hex characters): temperature
A/D counts (6), conductivity frequency x 256 (6), strain-gauge pressure A/D counts (6) + pressure temperature
compensation counts (4, volts = counts / 13107) or Digiquartz frequency x 256 (6) + compensation (4, its first 3
characters the count), one 4-character word per enabled external voltage
(volts = counts / 13107), then, if enabled, SBE 38 temperature (6), WET Labs RS-232 (3 x 4), GTD pressure (8)
+ temperature (6) (twice for a dual GTD), Aanderaa optode oxygen (6), SBE 63 phase (6) + thermistor (6), and in
moored mode the time (8, seconds since 2000-01-01 UTC).

What is taken from ``seabirdscientific`` (Sea-Bird's community toolkit) and what is not:

* **Conversions** are seabirdscientific's: :func:`seabirdscientific.conversion.convert_temperature` (with
  ``use_mv_r=True``, the 19plus V2 / 16plus V2 MV-R thermistor equation), ``convert_pressure`` (strain gauge,
  to dbar), ``convert_pressure_digiquartz`` (Digiquartz, ``QUARTZ0`` coefficients PC1..PT4, PSLOPE, POFFSET;
  the pressure frequency is counts / 256 Hz and the compensation the first 3 of its 4 hex characters, turned
  into degC with Sea-Bird's 16plus V2 / 19plus V2 defaults AD590M = 0.028927, AD590B = -41.1733 unless the
  header gives them; output ``prDM`` as SeaSoft names it) and ``convert_conductivity`` (19plus: frequency / 1000 kHz), on the coefficient dataclasses of
  :mod:`seabirdscientific.cal_coefficients`, which hadal fills from the header. Two coefficients those functions
  ignore are applied here: ``TOFFSET`` (added to temperature) and ``CSLOPE`` (multiplies conductivity).
* **Byte decoding** is hadal's (a vectorised table of fields) instead of
  :func:`seabirdscientific.instrument_data.read_sbe19plus_data`, because that function (3.1.1): decodes the
  optional fields in its ``Sensors`` enum order, which puts the SBE 38 after WET Labs/GTD/optode/SBE 63 while
  the manual puts it first (wrong values when an SBE 38 is combined with any of them); converts the moored-mode
  time with ``datetime.fromtimestamp`` (local time of the computer, not UTC); on a line of the wrong length
  silently returns NaN for every value, and on a non-hex character raises a bare ``ValueError`` without a line
  number; and runs per line in Python (~20 us/scan, 20 s for 1 M scans). The test suite checks that both
  decoders give identical raw values on the real file.

SBE 37 MicroCAT (SM, SMP, SI, SIP, IM, IMP) ``.hex`` files from SeatermV2: the ``GetCC`` XML calibration
(``A0``..``A3``, ``G``..``J``, ``PCOR``, ``TCOR``, ``WBOTC``, strain-gauge ``PA0``...), scans of temperature counts
(6), conductivity frequency x 256 (6), pressure counts (6) + compensation counts (4) when ``PressureInstalled``,
and the time (8, seconds since 2000); converted with seabirdscientific (no MV-R step, ``WBOTC`` applied) and
checked against seabirdscientific's own ``read_hex_file`` decoder in the tests.

Not supported (refused with a one-line :class:`~hadal.errors.InputError` naming the model): other instruments
(SBE 9/911plus, SBE 19 / original 19plus "SeacatPlus" firmware, SBE 25plus, 39, 49 ...), SBE 37 with SBE 63
oxygen (ODO) or a Digiquartz, and non raw-hex output formats. The voltage channels are output in volts (SeaSoft's ``v0``..``vN``, numbered in
scan order as SeaSoft numbers them; the physical ``Ext Volt`` number is kept in ``attrs['channels']``); the
header's per-channel ``volt N: offset/slope`` (used by the instrument for its own engineering-unit output) are
kept as metadata and not applied, as DatCnv does not apply them either. Auxiliary sensor conversions (oxygen,
fluorescence, PAR ...) need the .xmlcon and are out of scope.
"""

from __future__ import annotations

import datetime as _dt
import math
import re
import warnings
import xml.etree.ElementTree as ET
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd

from hadal.errors import InputError
from hadal.formats import read_bytes

__all__ = ["read_hex", "describe_hex", "parse_hex_header", "HexHeader", "SUPPORTED_INSTRUMENTS"]

SUPPORTED_INSTRUMENTS = ("SBE 19plus V2 (profile or moored mode)", "SBE 16plus V2",
                         "SBE 37 (SM, SMP, SI, SIP, IM, IMP; raw hex, no SBE 63 oxygen)")
_SUPPORTED_TXT = ("supported: " + ", ".join(SUPPORTED_INSTRUMENTS)
                  + " with a strain-gauge (or, 16plus V2 / 19plus V2, Digiquartz) pressure sensor")
#: the SBE 37's calibration keys (its GetCC XML: Calibration id='Temperature' / 'Conductivity' / 'Pressure')
_SBE37_TEMP_KEYS = ("A0", "A1", "A2", "A3")
_SBE37_COND_KEYS = ("G", "H", "I", "J", "PCOR", "TCOR", "WBOTC")
COUNTS_TO_VOLTS = 13107.0  # 19plus V2 / 16plus V2 A/D: volts = counts / 13107
PROFILE_SCAN_RATE_HZ = 4.0  # 19plus V2 profiling mode samples at 4 Hz
_EPOCH_2000 = _dt.datetime(2000, 1, 1, tzinfo=_dt.UTC)
_BAD_FLAG = -9.990e-29

_TEMP_KEYS = ("TA0", "TA1", "TA2", "TA3")
_COND_KEYS = ("G", "H", "I", "J", "CPCOR", "CTCOR")
_PRES_KEYS = ("PA0", "PA1", "PA2", "PTCA0", "PTCA1", "PTCA2", "PTCB0", "PTCB1", "PTCB2",
              "PTEMPA0", "PTEMPA1", "PTEMPA2")
#: Digiquartz (``<Calibration format='QUARTZ0'>``): C1..C3, D1, D2, T1..T4 of the Paroscientific equation (PT5,
#: AD590M, AD590B are optional: the 16plus V2 / 19plus V2 GetCC lists none of them)
_QUARTZ_KEYS = ("PC1", "PC2", "PC3", "PD1", "PD2", "PT1", "PT2", "PT3", "PT4")
#: the pressure-temperature compensation of a Digiquartz on an SBE 16plus V2 / 19plus V2: temperature (degC) =
#: AD590M * N + AD590B, N = the first 3 hex characters of the 4-character word (seabirdscientific's
#: ``PressureDigiquartzCoefficients`` defaults and ``read_hex_file`` decoding for these two instruments)
_SEACAT_AD590M, _SEACAT_AD590B = 0.028927, -41.1733
#: seabirdscientific averages the compensation over this window (SBE Data Processing's 30 s, "Digiquartz")
_QUARTZ_TC_WINDOW_S = 30.0
_NUM = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eE][-+]?\d+)?"
_TIME_FORMATS = ("%d %b %Y %H:%M:%S", "%b %d %Y %H:%M:%S", "%d %b %Y %H:%M", "%Y-%m-%dT%H:%M:%S")


@dataclass
class HexHeader:
    """What the ``.hex`` header says (filled by :func:`parse_hex_header`)."""

    instrument: str | None = None  # first header line, e.g. 'Sea-Bird SBE19plus Data File:'
    model: str | None = None  # 'SBE 19plus V2' / 'SBE 16plus V2'
    firmware: str | None = None
    serial_number: str | None = None
    status_time_utc: str | None = None  # instrument clock at the 'ds' command
    upload_time_utc: str | None = None
    mode: str | None = None  # 'profile' / 'moored' (None: unknown, decided from the scan length)
    scans_to_average: int = 1
    sample_interval_s: float | None = None  # moored mode
    pressure_type: str | None = None  # 'strain gauge' / 'quartz' / 'none'
    pressure_range_psia: float | None = None
    volts: list[int] = field(default_factory=list)  # enabled external voltage channels (physical numbers)
    aux: dict[str, bool] = field(default_factory=dict)  # SBE38, WETLABS, GTD, DualGTD, OPTODE, SBE63
    output_format: str | None = None
    coefficients: dict[str, dict[str, float]] = field(default_factory=dict)  # temperature/conductivity/pressure
    calibration_dates: dict[str, str] = field(default_factory=dict)
    sensor_serials: dict[str, str] = field(default_factory=dict)
    volt_cal: dict[int, dict[str, float]] = field(default_factory=dict)
    casts: list[dict[str, Any]] = field(default_factory=list)
    latitude_deg: float | None = None
    longitude_deg: float | None = None
    position_source: dict[str, str | None] = field(default_factory=lambda: {"latitude": None, "longitude": None})
    nmea_utc: str | None = None
    header_form: str = "text"  # 'text' (ds/dcal echo) or 'xml' (GetHD/GetCD/GetCC)
    instrument_header: list[str] = field(default_factory=list)
    user_header: list[str] = field(default_factory=list)


# ------------------------------------------------------------------------------------------------ file reading
def _read_text(path: Path, max_bytes: float | None = None) -> tuple[str, str | None]:
    """File text (Latin-1) and the compression found by magic bytes (gzip / bz2 / xz / None); held against the
    memory budget ``max_bytes`` as it decompresses (:func:`hadal.formats.read_bytes`)."""
    raw, comp = read_bytes(path, "Sea-Bird .hex", text=True, max_bytes=max_bytes)
    return raw.decode("latin-1"), comp


def _split(path: Path, text: str) -> tuple[list[str], list[str], int]:
    lines = text.replace("\r\n", "\n").replace("\r", "\n").split("\n")
    end = next((i for i, ln in enumerate(lines) if ln.strip().upper() == "*END*"), None)
    if end is None:
        raise InputError(f"{path}: not a Sea-Bird .hex file (no '*END*' line after the header)")
    return lines[:end], lines[end + 1:], end + 2  # header, data lines, 1-based number of the first data line


def _parse_time(text: str, formats: tuple[str, ...] = _TIME_FORMATS) -> str | None:
    t = " ".join(text.split())
    for fmt in formats:
        try:
            return _dt.datetime.strptime(t, fmt).replace(tzinfo=_dt.UTC).isoformat()
        except ValueError:
            continue
    return None


def _float(s: str | None) -> float | None:
    try:
        v = float(str(s).strip())
    except (TypeError, ValueError):
        return None
    return v if math.isfinite(v) else None


def _major(version: str) -> int:
    m = re.match(r"\s*(\d+)", version or "")
    return int(m.group(1)) if m else 0


def _yes(s: str | None) -> bool:
    return str(s).strip().lower() in ("yes", "y", "1", "true")


# ------------------------------------------------------------------------------------------------ header parsing
def _parse_xml_blocks(h: HexHeader, header_text: str, path: Path) -> None:
    """``<HardwareData>``, ``<ConfigurationData>``, ``<StatusData>``, ``<CalibrationCoefficients>`` blocks."""
    for tag in ("HardwareData", "ConfigurationData", "StatusData", "CalibrationCoefficients"):
        m = re.search(rf"<{tag}\b.*?</{tag}>", header_text, re.S)
        if not m:
            continue
        try:
            el = ET.fromstring(m.group(0))
        except ET.ParseError as exc:
            raise InputError(f"{path}: unreadable <{tag}> XML in the .hex header ({exc})") from None
        h.header_form = "xml"
        dev = (el.get("DeviceType") or "").strip()
        sn = (el.get("SerialNumber") or "").strip()
        if sn and not h.serial_number:
            h.serial_number = sn
        if dev and not h.model:
            h.model = {"sbe19plus": "SBE 19plus", "sbe16plus": "SBE 16plus"}.get(dev.lower(), dev)
        if tag == "HardwareData":
            _xml_hardware(h, el)
        elif tag == "StatusData":
            t = el.findtext("DateTime")
            if t:
                h.status_time_utc = _parse_time(t.strip())
        elif tag == "ConfigurationData":
            _xml_configuration(h, el)
        elif tag == "CalibrationCoefficients":
            _xml_calibration(h, el)


def _xml_hardware(h: HexHeader, el: ET.Element) -> None:
    """``<HardwareData>``: firmware, pressure sensor type, sensor serial numbers."""
    fw = el.findtext("FirmwareVersion")
    if fw:
        h.firmware = fw.strip()
    for s in el.iter("Sensor"):
        sid, typ = (s.get("id") or "").strip(), (s.findtext("type") or "").strip().lower()
        if sid == "Main Pressure" and typ:
            h.pressure_type = "quartz" if "quartz" in typ else "strain gauge" if "strain" in typ else typ
        if s.findtext("SerialNumber") and sid.startswith("Main "):
            h.sensor_serials[sid[5:].lower()] = s.findtext("SerialNumber").strip()


def _xml_configuration(h: HexHeader, el: ET.Element) -> None:
    """``<ConfigurationData>``: profile/moored mode, averaging, sample interval, enabled channels, output format."""
    pm, mm = el.find("ProfileMode"), el.find("MooredMode")
    if pm is not None and mm is None:
        h.mode = "profile"
    elif mm is not None and pm is None:
        h.mode = "moored"
    for sub in (pm, mm):
        if sub is None:
            continue
        if sub.findtext("ScansToAverage") and sub is pm:
            h.scans_to_average = int(_float(sub.findtext("ScansToAverage")) or 1)
        if sub.findtext("SampleInterval") and sub is mm:
            h.sample_interval_s = _float(sub.findtext("SampleInterval"))
    sp = el.find("SamplingParameters")  # SBE 16plus V2 GetCD: <SamplingParameters><SampleInterval>
    if h.sample_interval_s is None and sp is not None and sp.findtext("SampleInterval"):
        h.sample_interval_s = _float(sp.findtext("SampleInterval"))
    mode_txt = (el.findtext("SampleMode") or el.findtext("Mode") or "").strip().lower()
    if mode_txt.startswith(("profil", "moored")):
        h.mode = "profile" if mode_txt.startswith("profil") else "moored"
    dc = el.find("DataChannels")
    if dc is not None:
        h.volts = [k for k in range(8) if _yes(dc.findtext(f"ExtVolt{k}"))]
        for key in ("SBE38", "WETLABS", "OPTODE", "SBE63", "GTD", "DualGTD"):
            if dc.find(key) is not None:
                h.aux[key] = _yes(dc.findtext(key))
    installed = el.findtext("PressureInstalled")  # SBE 37 GetCD
    if installed:
        if not _yes(installed):
            h.pressure_type = "none"
        elif h.pressure_type is None:
            h.pressure_type = "strain gauge"
    of = el.findtext("OutputFormat")
    if of:
        h.output_format = of.strip()


def _xml_calibration(h: HexHeader, el: ET.Element) -> None:
    """``<CalibrationCoefficients>``: each sensor's coefficients, calibration date and serial number."""
    for cal in el.iter("Calibration"):
        cid = (cal.get("id") or "").strip().lower()
        fmt = (cal.get("format") or "").strip().upper()
        vals = {c.tag.upper(): _float(c.text) for c in cal if _float(c.text) is not None}
        date = (cal.findtext("CalDate") or "").strip() or None
        serial = (cal.findtext("SerialNum") or "").strip() or None
        kind = None
        if "temperature" in cid and "pressure" not in cid:
            kind = "temperature"
        elif "conductivity" in cid:
            kind = "conductivity"
        elif "pressure" in cid:
            kind = "pressure"
            if fmt.startswith("QUARTZ"):
                h.pressure_type = "quartz"
            elif fmt.startswith("STRAIN") or "PA0" in vals:
                h.pressure_type = h.pressure_type or "strain gauge"
            if vals.get("PRANGE") is not None:
                h.pressure_range_psia = vals["PRANGE"]
        mv = re.match(r"volt\s*(\d+)", cid)
        if mv:
            h.volt_cal[int(mv.group(1))] = {"offset": vals.get("OFFSET"), "slope": vals.get("SLOPE")}
        if kind:
            h.coefficients[kind] = {k: v for k, v in vals.items() if k not in ("SERIALNUM",)}
            if date:
                h.calibration_dates[kind] = date
            if serial:
                h.sensor_serials[kind] = serial


_COEF_LINE = re.compile(rf"^\s*([A-Za-z][A-Za-z0-9]*)\s*=\s*({_NUM})\s*$")
_CAL_SECTION = re.compile(r"^\s*(temperature|conductivity|pressure)\b(.*?):\s*(\S.*)?$", re.I)
_VOLT_CAL = re.compile(rf"^\s*volt\s+(\d+)\s*:\s*offset\s*=\s*({_NUM})\s*,\s*slope\s*=\s*({_NUM})", re.I)
_DS_MODEL = re.compile(r"^\s*(SBE\s*(\d+)\s*plus|SeacatPlus|SBE\s*\d+\S*)\s+V\s*([\d.]+\w*)\s+SERIAL NO\.\s*(\S+)"
                       r"\s*(.*)$", re.I)
_CAST = re.compile(r"^\s*cast\s+(\d+)\s+(\d{1,2}\s+\w{3}\s+\d{4}\s+[\d:]+)\s+samples\s+(\d+)\s+to\s+(\d+)"
                   r"(?:\s*,\s*(?:avg|int)\s*=\s*(\d+))?", re.I)


def _parse_text_lines(h: HexHeader, header: list[str]) -> None:
    """The ``*`` / ``**`` text header lines of a .hex file into ``h`` (position, status, calibration, casts)."""
    from hadal.ingest.cnv import _POS_RE

    section = None
    pos_src: dict[str, str | None] = {"latitude": None, "longitude": None}
    for raw in header:
        s = raw.strip()
        if not s.startswith("*"):
            continue
        if s.startswith("**"):
            h.user_header.append(s.lstrip("*").strip())
        else:
            h.instrument_header.append(s.lstrip("*").strip())
        m = _POS_RE.match(s)
        if m:
            _position_line(h, s, m, pos_src)
            continue
        body = s.lstrip("*").strip()
        if not body or body.startswith("<"):
            continue
        section = _header_body_line(h, body, section)
    h.volts.sort()
    h.position_source = pos_src


def _position_line(h: HexHeader, s: str, m: re.Match[str], pos_src: dict[str, str | None]) -> None:
    """A ``Latitude``/``Longitude`` header line: a user (``**``) position wins over the NMEA (``*``) one."""
    from hadal.ingest.cnv import parse_latlon

    is_lat = m.group(1).lower().startswith("lat")
    val = parse_latlon(m.group(2), is_latitude=is_lat)
    src = "user" if s.startswith("**") else "nmea"
    if val is not None:
        if is_lat and (h.latitude_deg is None or (pos_src["latitude"] == "nmea" and src == "user")):
            h.latitude_deg, pos_src["latitude"] = val, src
        elif not is_lat and (h.longitude_deg is None or (pos_src["longitude"] == "nmea" and src == "user")):
            h.longitude_deg, pos_src["longitude"] = val, src


def _header_body_line(h: HexHeader, body: str, section: str | None) -> str | None:
    """One instrument header line (``*`` stripped) into ``h``; returns the calibration section now open."""
    m = re.match(r"^NMEA UTC \(Time\)\s*=\s*(.+)$", body, re.I)
    if m:
        h.nmea_utc = _parse_time(m.group(1), ("%b %d %Y %H:%M:%S",))
        return section
    m = re.match(r"^System UpLoad Time\s*=\s*(.+)$", body, re.I)
    if m:
        h.upload_time_utc = _parse_time(m.group(1), ("%b %d %Y %H:%M:%S",))
        return section
    m = re.match(r"^(Temperature|Conductivity) SN\s*=\s*(\S+)", body, re.I)
    if m:
        h.sensor_serials.setdefault(m.group(1).lower(), m.group(2))
        return section
    m = _DS_MODEL.match(body)
    if m:
        _model_line(h, m)
        return None
    m = _CAST.match(body)
    if m:
        h.casts.append({"cast": int(m.group(1)), "start_utc": _parse_time(m.group(2)),
                        "first_sample": int(m.group(3)), "last_sample": int(m.group(4)),
                        "avg": int(m.group(5)) if m.group(5) else None, "line": body})
        return section
    m = _CAL_SECTION.match(body)
    if m:
        return _calibration_section(h, m)
    m = _VOLT_CAL.match(body)
    if m:
        h.volt_cal[int(m.group(1))] = {"offset": float(m.group(2)), "slope": float(m.group(3))}
        return None
    m = _COEF_LINE.match(body)
    if m and section:
        h.coefficients[section][m.group(1).upper()] = float(m.group(2))
        return section
    # ds status lines (comma-separated key = value pairs)
    for part in body.split(","):
        kv = part.split("=", 1)
        if len(kv) == 2:
            _status_pair(h, kv[0].strip().lower(), kv[1].strip())
    return section


def _model_line(h: HexHeader, m: re.Match[str]) -> None:
    """The ``ds`` model / firmware / serial number / status time line."""
    name = m.group(1)
    if re.match(r"SBE\s*(19|16)\s*plus", name, re.I):
        num = re.search(r"\d+", name).group(0)
        ver = m.group(3)
        h.model = f"SBE {num}plus" + (" V2" if _major(ver) >= 2 else "")
    else:
        h.model = name
    h.firmware = m.group(3)
    h.serial_number = h.serial_number or m.group(4)
    t = _parse_time(m.group(5))
    if t and h.status_time_utc is None:
        h.status_time_utc = t


def _calibration_section(h: HexHeader, m: re.Match[str]) -> str:
    """A calibration section's title line (sensor kind, S/N, date, pressure range); returns the kind."""
    kind, rest, date = m.group(1).lower(), m.group(2) or "", (m.group(3) or "").strip()
    if date:
        h.calibration_dates[kind] = date
    h.coefficients.setdefault(kind, {})
    ms = re.search(r"S/N\s*=\s*([^,\s]+)", rest)
    if ms:
        h.sensor_serials[kind] = ms.group(1)
    mr = re.search(rf"range\s*=\s*({_NUM})\s*psia", rest, re.I)
    if mr:
        h.pressure_range_psia = float(mr.group(1))
    return kind


def _status_pair(h: HexHeader, key: str, val: str) -> None:
    """One ``key = value`` pair of a ``ds`` status line (mode, averaging, pressure sensor, enabled sensors)."""
    if key == "mode":
        h.mode = "profile" if val.lower().startswith("profil") else \
            "moored" if val.lower().startswith("moored") else h.mode
    elif key == "number of scans to average":
        h.scans_to_average = int(_float(val) or 1)
    elif key == "sample interval":
        h.sample_interval_s = _float(re.match(rf"^\s*({_NUM})", val).group(1)) \
            if re.match(rf"^\s*{_NUM}", val) else None
    elif key == "pressure sensor":
        v = val.lower()
        h.pressure_type = "strain gauge" if "strain" in v else "quartz" if "quartz" in v else \
            "none" if v in ("no", "none") else v
    elif key == "range" and h.pressure_type is not None and h.pressure_range_psia is None:
        h.pressure_range_psia = _float(val.split()[0]) if val.split() else None
    elif re.fullmatch(r"ext volt (\d)", key):
        k = int(key.split()[-1])
        if _yes(val) and k not in h.volts:
            h.volts.append(k)
    elif key in ("sbe 38", "sbe38"):
        h.aux["SBE38"] = _yes(val)
    elif key in ("wetlabs", "wet labs"):
        h.aux["WETLABS"] = _yes(val)
    elif key == "optode":
        h.aux["OPTODE"] = _yes(val)
    elif key in ("sbe63", "sbe 63"):
        h.aux["SBE63"] = _yes(val)
    elif key in ("gas tension device", "gtd"):
        h.aux["GTD"] = _yes(val) or val.lower().startswith("dual")
        h.aux["DualGTD"] = val.lower().startswith("dual")
    elif key in ("sbe 50", "sbe50"):
        h.aux["SBE50"] = _yes(val)
    elif key == "dual gtd":
        h.aux["DualGTD"] = _yes(val)
    elif key == "output format":
        h.output_format = val


def parse_hex_header(path: str | Path, header: list[str]) -> HexHeader:
    """Parse the ``*`` header lines of a ``.hex`` file (text ``ds``/``dcal`` echo and/or XML blocks)."""
    path = Path(path)
    h = HexHeader()
    stars = [ln for ln in header if ln.strip()]
    h.instrument = stars[0].strip().lstrip("*").strip() if stars else None
    _parse_text_lines(h, header)
    xml_text = "\n".join(re.sub(r"^\s*\*\s?", "", ln) for ln in header if ln.strip().startswith("*"))
    if "<" in xml_text:
        _parse_xml_blocks(h, xml_text, path)
    return h


def _raw_hex_lines(data_lines: list[str]) -> bool:
    """True when the first scans are raw hex (hex digits only, one length): an upload, whatever the header's
    real-time ``<OutputFormat>`` says."""
    rows = [ln.strip() for ln in data_lines[:50] if ln.strip()]
    return bool(rows) and len({len(r) for r in rows}) == 1 and all(re.fullmatch(r"[0-9A-Fa-f]+", r) for r in rows)


def _check_supported(h: HexHeader, path: Path, data_lines: list[str]) -> None:
    first = (h.instrument or "").lower()
    if not first.startswith("sea-bird") or "data file" not in first:
        raise InputError(f"{path}: not a Sea-Bird .hex file (first header line is {h.instrument!r}); "
                         f"{_SUPPORTED_TXT}")
    m = re.search(r"sbe\s*(\w+(?:-\w+)*)", h.instrument or "", re.I)  # 'SBE37SMP-ODO': the whole model
    fam = m.group(1).lower() if m else "?"
    model = h.model or ""
    if fam.startswith("37"):
        _check_sbe37(h, path, f"SBE {m.group(1)}" if m else "SBE 37")
        return
    if fam not in ("19plus", "16plus"):
        name = f"SBE {m.group(1)}" if m else h.instrument
        raise InputError(f"{path}: {name} .hex files are not supported; {_SUPPORTED_TXT}")
    if not model.endswith("V2"):
        if (h.firmware and _major(h.firmware) < 2) or "seacatplus" in model.lower():
            raise InputError(f"{path}: SBE {fam} with firmware {h.firmware} (not V2) is not supported; "
                             f"{_SUPPORTED_TXT}")
        h.model = f"SBE {fam} V2"  # XML header: DeviceType 'SBE19plus' + FirmwareVersion 2.x
    if (h.output_format and "hex" not in h.output_format.lower() and h.output_format.strip() != "0"
            and not _raw_hex_lines(data_lines)):
        # <OutputFormat> is the instrument's real-time setting; the scans of an upload are raw hex whatever it says
        # (SBE 16plus_digiquartz.hex: 'converted decimal' above 30-character hex scans), so the lines decide
        raise InputError(f"{path}: output format is {h.output_format!r}, not raw HEX; cannot convert")
    if h.pressure_type not in (None, "strain gauge", "quartz"):
        raise InputError(f"{path}: pressure sensor {h.pressure_type!r} is not supported; {_SUPPORTED_TXT}")
    missing = []
    pres_keys = _QUARTZ_KEYS if h.pressure_type == "quartz" else _PRES_KEYS
    for kind, keys in (("temperature", _TEMP_KEYS), ("conductivity", _COND_KEYS), ("pressure", pres_keys)):
        have = h.coefficients.get(kind, {})
        lack = [k for k in keys if have.get(k) is None]
        if lack:
            missing.append(f"{kind} ({', '.join(lack)})")
    if missing:
        raise InputError(f"{path}: .hex header lacks calibration coefficients for {'; '.join(missing)}; "
                         f"cannot convert (a header with the instrument's 'dcal'/'GetCC' output is needed)")
    if h.aux.get("SBE50"):
        raise InputError(f"{path}: scans with SBE 50 pressure data are not supported; {_SUPPORTED_TXT}")
    if h.pressure_type is None:
        h.pressure_type = "strain gauge"
    if h.mode is None and "16plus" in (h.model or ""):
        h.mode = "moored"  # the SBE 16plus V2 has no profiling mode


# ------------------------------------------------------------------------------------------------ scan decoding
def is_sbe37(h: HexHeader) -> bool:
    """The header is an SBE 37's (MicroCAT family: SM, SMP, SI, SIP, IM, IMP)."""
    return bool(re.search(r"sbe\s*37", h.instrument or "", re.I))


def _check_sbe37(h: HexHeader, path: Path, name: str) -> None:
    """What an SBE 37 .hex needs: no SBE 63 oxygen (ODO: its phase is not converted), raw hex output, a
    strain-gauge pressure sensor or none, and the temperature, conductivity (and pressure) coefficients of the
    header's ``GetCC`` XML. SBE 37 scans are always time-stamped (moored)."""
    if "odo" in name.lower() or "odo" in (h.model or "").lower():
        raise InputError(f"{path}: {name} .hex files (with SBE 63 oxygen) are not supported; {_SUPPORTED_TXT}")
    if h.pressure_type == "quartz":
        raise InputError(f"{path}: {name} with a Digiquartz pressure sensor is not supported; {_SUPPORTED_TXT}")
    h.mode = "moored"
    h.model = name
    missing = []
    keys = [("temperature", _SBE37_TEMP_KEYS), ("conductivity", _SBE37_COND_KEYS)]
    if h.pressure_type is not None and h.pressure_type != "none":
        keys.append(("pressure", _PRES_KEYS))
    for kind, ks in keys:
        lack = [k for k in ks if h.coefficients.get(kind, {}).get(k) is None]
        if lack:
            missing.append(f"{kind} ({', '.join(lack)})")
    if missing:
        raise InputError(f"{path}: {name} .hex header lacks calibration coefficients for {'; '.join(missing)}; "
                         "cannot convert (a header with the instrument's GetCC output is needed)")


def _layout(h: HexHeader, moored: bool) -> list[tuple[str, int]]:
    """``[(field, hex characters)]`` of one scan, in the order of the manual's OutputFormat=0 (SBE 37: temperature
    counts (6), conductivity frequency x 256 (6), with a pressure sensor its counts (6) and its temperature
    compensation counts (4), then the time (8, seconds since 2000-01-01), as seabirdscientific's
    ``read_sbe37sm_data`` decodes them)."""
    if is_sbe37(h):
        f37 = [("temperature", 6), ("conductivity", 6)]
        if h.pressure_type not in (None, "none"):
            f37 += [("pressure", 6), ("ptc", 4)]
        return f37 + [("time", 8)]
    f = [("temperature", 6), ("conductivity", 6), ("pressure", 6), ("ptc", 4)]
    f += [(f"volt{k}", 4) for k in h.volts]
    aux = h.aux
    if aux.get("SBE38"):
        f.append(("sbe38", 6))
    if aux.get("WETLABS"):
        f += [("wetlabs0", 4), ("wetlabs1", 4), ("wetlabs2", 4)]
    if aux.get("GTD") or aux.get("DualGTD"):
        f += [("gtd_p", 8), ("gtd_t", 6)]
        if aux.get("DualGTD"):
            f += [("gtd2_p", 8), ("gtd2_t", 6)]
    if aux.get("OPTODE"):
        f.append(("optode", 6))
    if aux.get("SBE63"):
        f += [("sbe63_phase", 6), ("sbe63_t", 6)]
    if moored:
        f.append(("time", 8))
    return f


_NIBBLE = np.full(256, -1, dtype=np.int64)
for _i, _c in enumerate(b"0123456789ABCDEF"):
    _NIBBLE[_c] = _i
for _i, _c in enumerate(b"abcdef"):
    _NIBBLE[_c] = 10 + _i


def _decode(path: Path, h: HexHeader, data_lines: list[str], first_line_no: int
            ) -> tuple[dict[str, np.ndarray], list[tuple[str, int]], bool]:
    """Validate every data line and decode it into integer fields (vectorised)."""
    rows = [(first_line_no + i, ln.strip()) for i, ln in enumerate(data_lines) if ln.strip()]
    if not rows:
        raise InputError(f"{path}: .hex file has no data scans after '*END*'")
    width = len(rows[0][1])
    lay_p, lay_m = _layout(h, False), _layout(h, True)
    len_p, len_m = sum(n for _, n in lay_p), sum(n for _, n in lay_m)
    if h.mode == "profile":
        moored = False if width == len_p or width != len_m else True
    elif h.mode == "moored":
        moored = not (width == len_p and width != len_m)
    else:
        moored = width == len_m
    if h.mode and moored != (h.mode == "moored"):
        warnings.warn(f"{path.name}: header says {h.mode} mode but the scans are {width} characters, as in "
                      f"{'moored' if moored else 'profile'} mode; read as such", stacklevel=3)
    layout = lay_m if moored else lay_p
    expected = len_m if moored else len_p
    desc = ", ".join(f"{name}:{n}" for name, n in layout)
    for ln_no, s in rows:
        if len(s) != expected:
            what = "truncated" if len(s) < expected else "too long"
            raise InputError(f"{path}: line {ln_no}: scan of {len(s)} characters ({what}); the header's "
                             f"configuration gives {expected} ({desc})")
    buf = np.frombuffer("".join(s for _, s in rows).encode("latin-1"), dtype=np.uint8).reshape(len(rows), expected)
    nib = _NIBBLE[buf]
    bad = np.argwhere(nib < 0)
    if bad.size:
        r, c = bad[0]
        ln_no, s = rows[r]
        raise InputError(f"{path}: line {ln_no}: non-hexadecimal character {s[c]!r} at column {c + 1}")
    out: dict[str, np.ndarray] = {}
    pos = 0
    for name, n in layout:
        v = np.zeros(len(rows), dtype=np.int64)
        for k in range(n):
            v = (v << 4) | nib[:, pos + k]
        out[name] = v
        pos += n
    return out, layout, moored


# ------------------------------------------------------------------------------------------------ conversion
def _convert(path: Path, h: HexHeader, raw: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    try:
        import seabirdscientific.cal_coefficients as sbc
        import seabirdscientific.conversion as sbconv
        import seabirdscientific.instrument_data as sbid
    except ImportError:
        raise InputError(f"{path}: converting a Sea-Bird .hex needs the 'seabirdscientific' package "
                         f"(pip install seabirdscientific)") from None

    if is_sbe37(h):
        return _convert_sbe37(h, raw, sbc, sbconv, sbid)
    ct, cc, cp = h.coefficients["temperature"], h.coefficients["conductivity"], h.coefficients["pressure"]
    tcoef = sbc.TemperatureCoefficients(ct["TA0"], ct["TA1"], ct["TA2"], ct["TA3"])
    t90 = sbconv.convert_temperature(raw["temperature"].astype(np.float64), tcoef, "ITS90", "C", use_mv_r=True)
    t90 = t90 + (ct.get("TOFFSET") or 0.0)  # seabirdscientific ignores TemperatureCoefficients.offset
    if h.pressure_type == "quartz":
        p = _convert_digiquartz(h, raw, sbc, sbconv)
    else:
        pcoef = sbc.PressureCoefficients(*(cp[k] for k in _PRES_KEYS), offset=cp.get("POFFSET") or 0.0)
        p = sbconv.convert_pressure(raw["pressure"].astype(np.float64), raw["ptc"] / COUNTS_TO_VOLTS, pcoef, "dbar")
    ccoef = sbc.ConductivityCoefficients(cc["G"], cc["H"], cc["I"], cc["J"], cc["CPCOR"], cc["CTCOR"], 0.0)
    itype = sbid.InstrumentType.SBE16Plus if "16" in (h.model or "") else sbid.InstrumentType.SBE19Plus
    c = sbconv.convert_conductivity(raw["conductivity"] / 256.0, t90, p, ccoef, itype, "S/m")
    c = c * (cc.get("CSLOPE") or 1.0)  # seabirdscientific has no slope term
    return {"tv290C": t90, "c0S/m": c, _pressure_column(h): p}


def _pressure_column(h: HexHeader) -> str:
    """SeaSoft's pressure column: ``prDM`` (Digiquartz) or ``prdM`` (strain gauge)."""
    return "prDM" if h.pressure_type == "quartz" else "prdM"


def _quartz_tc_counts(ptc: np.ndarray) -> np.ndarray:
    """The 12-bit compensation count in the first 3 of the 4 hex characters of a 16plus V2 / 19plus V2
    Digiquartz scan (seabirdscientific ``read_hex_file``)."""
    return (ptc >> 4).astype(np.float64)


def _convert_digiquartz(h: HexHeader, raw: dict[str, np.ndarray], sbc: Any, sbconv: Any) -> np.ndarray:
    """Digiquartz frequency (counts / 256 Hz) and compensation to sea pressure (dbar) with seabirdscientific's
    ``convert_pressure_digiquartz`` (the Paroscientific equation, P = C (1 - T0^2/T^2) (1 - D (1 - T0^2/T^2))
    psia, minus 14.7 psi, times PSLOPE plus POFFSET dbar), the compensation averaged over 30 s of scans."""
    cp = h.coefficients["pressure"]
    coef = sbc.PressureDigiquartzCoefficients(
        cp["PC1"], cp["PC2"], cp["PC3"], cp["PD1"], cp["PD2"], cp["PT1"], cp["PT2"], cp["PT3"], cp["PT4"],
        cp.get("PT5") or 0.0, ad590m=cp.get("AD590M", _SEACAT_AD590M), ad590b=cp.get("AD590B", _SEACAT_AD590B),
        slope=cp.get("PSLOPE") or 1.0, offset=cp.get("POFFSET") or 0.0)
    interval = h.sample_interval_s if h.mode == "moored" and h.sample_interval_s else \
        h.scans_to_average / PROFILE_SCAN_RATE_HZ
    # a window shorter than one scan (moored, interval > 30 s) is that scan alone
    interval = min(float(interval), _QUARTZ_TC_WINDOW_S)
    return np.asarray(sbconv.convert_pressure_digiquartz(raw["pressure"] / 256.0, _quartz_tc_counts(raw["ptc"]),
                                                         coef, "dbar", interval), dtype=np.float64)


def _convert_sbe37(h: HexHeader, raw: dict[str, np.ndarray], sbc: Any, sbconv: Any, sbid: Any
                   ) -> dict[str, np.ndarray]:
    """SBE 37 counts to ITS-90 degC, dbar and S/m with seabirdscientific's conversions (SBE 37 manual, "Data
    Format": T90 = 1 / (a0 + a1 ln n + a2 ln^2 n + a3 ln^3 n) - 273.15 on the raw counts, no MV-R step; the
    pressure temperature compensation in counts; conductivity from frequency = counts / 256 Hz, corrected by
    WBOTC). Without a pressure sensor the pressure is missing (NaN) and conductivity uses 0 dbar."""
    ct, cc, cp = h.coefficients["temperature"], h.coefficients["conductivity"], h.coefficients.get("pressure", {})
    tcoef = sbc.TemperatureCoefficients(ct["A0"], ct["A1"], ct["A2"], ct["A3"])
    t90 = sbconv.convert_temperature(raw["temperature"].astype(np.float64), tcoef, "ITS90", "C", use_mv_r=False)
    if "pressure" in raw:
        pcoef = sbc.PressureCoefficients(*(cp[k] for k in _PRES_KEYS), offset=cp.get("POFFSET") or 0.0)
        p = sbconv.convert_pressure(raw["pressure"].astype(np.float64), raw["ptc"].astype(np.float64), pcoef, "dbar")
    else:
        p = np.full(t90.shape, np.nan)
    ccoef = sbc.ConductivityCoefficients(cc["G"], cc["H"], cc["I"], cc["J"], cc["PCOR"], cc["TCOR"], cc["WBOTC"])
    c = sbconv.convert_conductivity(raw["conductivity"] / 256.0, t90, np.nan_to_num(p, nan=0.0), ccoef,
                                    sbid.InstrumentType.SBE37SM, "S/m")
    return {"tv290C": t90, "c0S/m": c, "prdM": p}


def _pick_cast(path: Path, h: HexHeader, n: int) -> tuple[dict[str, Any] | None, np.ndarray | None]:
    """The ``dh`` cast line that dates a profile-mode file, and an elapsed-time column when it holds several.

    The ``dh`` echo lists every cast in the instrument's memory, while an upload often holds one of them:
    the cast whose sample count equals the file's scans is the one (if unique); when the scans are all the
    listed casts together, each scan is dated from its own cast's start.
    """
    casts = [c for c in h.casts if c["start_utc"]]
    if not casts:
        return None, None
    if len(casts) == 1:
        return casts[0], None
    counts = [c["last_sample"] - c["first_sample"] + 1 for c in casts]
    same = [c for c, k in zip(casts, counts, strict=True) if k == n]
    if len(same) == 1:
        return same[0], None
    if sum(counts) == n:
        dt = h.scans_to_average / PROFILE_SCAN_RATE_HZ
        t0 = pd.Timestamp(casts[0]["start_utc"])
        parts = [(pd.Timestamp(c["start_utc"]) - t0).total_seconds() + dt * np.arange(k)
                 for c, k in zip(casts, counts, strict=True)]
        warnings.warn(f"{path.name}: holds {len(casts)} casts; timeS dates each scan from its cast's start",
                      stacklevel=3)
        return casts[0], np.concatenate(parts)
    warnings.warn(f"{path.name}: {n} scans match none of the {len(casts)} casts in the header; dated from "
                  f"the first cast's start", stacklevel=3)
    return casts[0], None


def _add_channel(cols: dict[str, np.ndarray], channels: list[dict[str, Any]], name: str, values: np.ndarray,
                 long_name: str, units: str, **extra: Any) -> None:
    """Put ``values`` in ``cols[name]`` and append its read_cnv-style channel entry to ``channels``."""
    cols[name] = values
    channels.append({"name": name, "long_name": f"{long_name} [{units}]" if units else long_name,
                     "units": units, **extra})


def _pressure_channel(h: HexHeader) -> tuple[str, str, str]:
    """(name, long name, units) of the pressure channel, as SeaSoft writes it for this sensor."""
    if h.pressure_type == "quartz":
        return "prDM", "Pressure, Digiquartz", "db"
    return "prdM", "Pressure, Strain Gauge", "db"


def _add_sensor_channels(cols: dict[str, np.ndarray], channels: list[dict[str, Any]], h: HexHeader,
                         ints: dict[str, np.ndarray]) -> None:
    """Add the CTD channels, external voltages and enabled RS-232 sensors, in SeaSoft's column order."""
    def add(name: str, values: np.ndarray, long_name: str, units: str, **extra: Any) -> None:
        _add_channel(cols, channels, name, values, long_name, units, **extra)

    for name, long_name, units in (("tv290C", "Temperature", "ITS-90, deg C"), ("c0S/m", "Conductivity", "S/m"),
                                   _pressure_channel(h)):
        add(name, cols[name], long_name, units)
    for i, k in enumerate(h.volts):
        add(f"v{i}", ints[f"volt{k}"] / COUNTS_TO_VOLTS, f"Voltage {i}", "V", physical_channel=f"Ext Volt {k}")
    if "sbe38" in ints:
        add("t3890C", ints["sbe38"] / 100000.0 - 10.0, "Temperature, SBE 38", "ITS-90, deg C")
    for k in range(3):
        if f"wetlabs{k}" in ints:
            add(f"wetlabs{k}", ints[f"wetlabs{k}"].astype(np.float64), f"WET Labs RS-232 channel {k}", "counts")
    for tag, sfx in (("gtd", ""), ("gtd2", "2")):
        if f"{tag}_p" in ints:
            add(f"gtdP{sfx}", ints[f"{tag}_p"] / 100000.0, f"GTD {sfx or '1'} pressure", "mbar")
            add(f"gtdT{sfx}", ints[f"{tag}_t"] / 100000.0 - 10.0, f"GTD {sfx or '1'} temperature", "ITS-90, deg C")
    if "optode" in ints:
        add("optodeO2", ints["optode"] / 10000.0 - 10.0, "Optode oxygen", "umol/l")
    if "sbe63_phase" in ints:
        add("sbe63phase", ints["sbe63_phase"] / 100000.0 - 10.0, "SBE 63 oxygen phase", "usec")
        add("sbe63V", ints["sbe63_t"] / 1000000.0 - 1.0, "SBE 63 thermistor voltage", "V")


def _add_time_channel(cols: dict[str, np.ndarray], channels: list[dict[str, Any]], h: HexHeader,
                      ints: dict[str, np.ndarray], moored: bool, n: int,
                      picked: tuple[dict[str, Any] | None, np.ndarray | None]
                      ) -> tuple[str | None, str | None, float | None, float | None]:
    """Add ``timeS`` where the file gives one (``picked``: :func:`_pick_cast`'s answer, profile mode); returns
    (start ISO time, its note, interval s, sample rate Hz)."""
    start_iso = start_note = None
    if moored:
        secs = ints["time"].astype(np.float64)
        _add_channel(cols, channels, "timeS", secs - secs[0], "Time, Elapsed", "seconds")
        start_iso = (_EPOCH_2000 + _dt.timedelta(seconds=float(secs[0]))).isoformat()
        start_note = "first scan's time stamp"
        interval = h.sample_interval_s
        if interval is None and n > 1:
            interval = float(np.median(np.diff(secs)))
        sample_rate = 1.0 / interval if interval else None
    else:
        interval = h.scans_to_average / PROFILE_SCAN_RATE_HZ
        sample_rate = PROFILE_SCAN_RATE_HZ / h.scans_to_average
        cast, per_cast = picked
        if cast is not None:
            start_iso, start_note = cast["start_utc"], "Instrument's time stamp, header"
        if per_cast is not None:
            _add_channel(cols, channels, "timeS", per_cast, "Time, Elapsed", "seconds")
    return start_iso, start_note, interval, sample_rate


def _channel_frame(cols: dict[str, np.ndarray], channels: list[dict[str, Any]]) -> pd.DataFrame:
    """The float64 DataFrame of ``channels`` (in order); adds ``index``, ``column`` and ``span`` to each entry."""
    data = {c["name"]: np.asarray(cols[c["name"]], dtype=np.float64) for c in channels}
    df = pd.DataFrame(data)
    for i, c in enumerate(channels):
        v = df[c["name"]].to_numpy()
        fin = v[np.isfinite(v)]
        c.update(index=i, column=c["name"], span=[float(fin.min()), float(fin.max())] if fin.size else None)
    return df


def _seabirdscientific_version() -> str:
    """The installed seabirdscientific's version (``"?"`` when it cannot be told)."""
    import seabirdscientific

    sbs_ver = getattr(seabirdscientific, "__version__", None)
    if sbs_ver is None:
        try:
            from importlib.metadata import version

            sbs_ver = version("seabirdscientific")
        except Exception:  # pragma: no cover
            sbs_ver = "?"
    return sbs_ver


def _hex_sensors(h: HexHeader) -> list[dict[str, Any]]:
    """One dict per sensor, with the keys of read_cnv's ``attrs['sensors_xml']`` entries (SeaSoft .xmlcon names)."""
    sensors: list[dict[str, Any]] = []
    quartz = h.pressure_type == "quartz"
    pdesc = "Frequency, Pressure, Digiquartz with TC" if quartz else "Count, Pressure, Strain Gauge"
    for ch, kind, typ, desc in ((1, "temperature", "TemperatureSensor", "Count, Temperature"),
                                (2, "conductivity", "ConductivitySensor", "Frequency 0, Conductivity"),
                                (3, "pressure", "PressureSensor", pdesc)):
        coefs = dict(h.coefficients.get(kind, {}))
        if quartz and kind == "pressure":  # what the conversion applied where the header has none
            coefs.setdefault("AD590M", _SEACAT_AD590M)
            coefs.setdefault("AD590B", _SEACAT_AD590B)
        sensors.append({"channel": ch, "kind": kind, "type": typ, "sensor_id": None,
                        "serial_number": h.sensor_serials.get(kind, h.serial_number),
                        "calibration_date": h.calibration_dates.get(kind), "description": desc,
                        "coefficients": coefs})
    for i, k in enumerate(h.volts):
        sensors.append({"channel": 4 + i, "kind": "voltage", "type": "VoltageChannel", "sensor_id": None,
                        "serial_number": None, "calibration_date": None,
                        "description": f"A/D voltage {i} (Ext Volt {k})",
                        "coefficients": {k2.upper(): v for k2, v in h.volt_cal.get(k, {}).items()}})
    return sensors


def _hex_attrs(path: Path, h: HexHeader, comp: str | None, df: pd.DataFrame, channels: list[dict[str, Any]],
               times: tuple[str | None, str | None, float | None, float | None], moored: bool,
               layout: list[tuple[str, int]], n: int) -> dict[str, Any]:
    """read_hex's ``df.attrs`` (read_cnv's keys plus the .hex header's instrument, calibration and casts)."""
    from hadal import __version__

    start_iso, start_note, interval, sample_rate = times
    sensors = _hex_sensors(h)
    processing = [
        ["datcnv", f"hadal {__version__} seabird_hex.read_hex (seabirdscientific {_seabirdscientific_version()} "
                   "conversions)"],
        ["datcnv_in", str(path)],
        ["datcnv_calibration", f"{h.model} S/N {h.serial_number} .hex header ({h.header_form})"],
    ]
    return {
        "source": str(path),
        "format": "Sea-Bird raw .hex",
        "conversion": "hadal DatCnv equivalent with the calibration coefficients in the .hex header",
        "compression": comp,
        "instrument": h.instrument,
        "model": h.model,
        "serial_number": h.serial_number,
        "instrument_serial": h.serial_number,
        "firmware": h.firmware,
        "channels": channels,
        "units": {c["column"]: c["units"] for c in channels},
        "latitude_deg": h.latitude_deg,
        "longitude_deg": h.longitude_deg,
        "position_source": h.position_source,
        "start_time_utc": start_iso,
        "start_time_note": start_note,
        "nmea_utc": h.nmea_utc,
        "upload_time_utc": h.upload_time_utc,
        "status_time_utc": h.status_time_utc,
        "interval": {"kind": "seconds", "value": float(interval)} if interval else None,
        "sample_rate_hz": sample_rate,
        "mode": "moored" if moored else "profile",
        "scans_to_average": h.scans_to_average,
        "pressure_sensor": h.pressure_type,
        "pressure_range_psia": h.pressure_range_psia,
        "bad_flag": _BAD_FLAG,
        "bad_values": int((~np.isfinite(df.to_numpy())).sum()),
        "processing": processing,
        "sensors": sensors,
        "sensors_xml": sensors,  # same list, under read_cnv's key for its parsed sensor block
        "binned": False,
        "calibration": {k: dict(v) for k, v in h.coefficients.items()},
        "calibration_dates": dict(h.calibration_dates),
        "volt_calibration": {str(k): v for k, v in h.volt_cal.items()},
        "casts": [{k: v for k, v in c.items() if k != "line"} for c in h.casts],
        "scan_layout": [[name, nchar] for name, nchar in layout],
        "header_form": h.header_form,
        "user_header": h.user_header,
        "instrument_header": h.instrument_header,
        "header_comments": [],
        "nquan": len(channels),
        "nvalues_declared": None,
        "nvalues": n,
        "truncated": False,
        "rows_dropped": [],
    }


def read_hex(path: str | Path, *, raw: bool = False, max_bytes: float | None = None) -> pd.DataFrame:
    """Read a Sea-Bird SBE 19plus V2 / 16plus V2 ``.hex`` file and convert it with its header calibration.

    Returns a DataFrame shaped like :func:`hadal.ingest.cnv.read_cnv`'s, with SeaSoft's column names:
    ``tv290C`` (temperature, ITS-90 degC), ``c0S/m`` (conductivity, S/m), ``prdM`` (strain-gauge pressure, dbar)
    or ``prDM`` (Digiquartz pressure, dbar),
    ``v0``..``vN`` (external voltages, V, numbered in scan order), ``t3890C`` (SBE 38 temperature) and, in moored
    mode, ``timeS`` (seconds since the first scan). Other enabled RS-232 sensors are decoded as the instrument
    writes them (``wetlabs0..2`` counts, ``gtdP`` mbar / ``gtdT`` degC, ``optodeO2`` umol/L, ``sbe63phase`` /
    ``sbe63V``). ``raw=True`` adds SeaSoft's raw channels ``f0`` (temperature A/D counts), ``f1``
    (conductivity frequency, Hz) and ``f2`` (pressure A/D counts).

    ``df.attrs`` has read_cnv's keys (``source``, ``instrument``, ``channels``, ``units``, ``latitude_deg``,
    ``longitude_deg``, ``start_time_utc``, ``interval`` = ``{'kind': 'seconds', 'value': dt}`` so that
    :func:`~hadal.ingest.cnv.cnv_time_ns` puts it on a time base, ``processing`` = ``[['datcnv', 'hadal ...'],
    ...]``, ``sensors`` (also as ``sensors_xml``, read_cnv's key for parsed sensors) = list of ``{channel,
    kind, type, serial_number, calibration_date, description, coefficients}`` ...) plus ``serial_number``
    (also ``instrument_serial``), ``firmware``, ``mode``, ``scans_to_average``, ``sample_rate_hz``, ``calibration``,
    ``casts`` and ``scan_layout``. gzip / bz2 / xz compressed files are read (detected by magic bytes).

    Raises :class:`~hadal.errors.InputError` (one line naming the file) on a missing/empty/non-.hex file, an
    unsupported instrument or pressure sensor, missing calibration coefficients, a truncated or over-long
    scan line, or a non-hexadecimal character.
    """
    path = Path(path)
    text, comp = _read_text(path, max_bytes)  # max_bytes: the memory budget (default hadal.budget's)
    header, data_lines, first_no = _split(path, text)
    h = parse_hex_header(path, header)
    _check_supported(h, path, data_lines)
    ints, layout, moored = _decode(path, h, data_lines, first_no)
    n = len(ints["temperature"])
    with np.errstate(all="ignore"):
        cols = _convert(path, h, ints)
    if not np.isfinite(cols["tv290C"]).all():
        bad = int((~np.isfinite(cols["tv290C"])).sum())
        warnings.warn(f"{path.name}: {bad} scan(s) give no finite temperature (A/D counts out of range)",
                      stacklevel=2)

    channels: list[dict[str, Any]] = []
    _add_sensor_channels(cols, channels, h, ints)
    picked = (None, None) if moored else _pick_cast(path, h, n)  # warns at read_hex's caller
    times = _add_time_channel(cols, channels, h, ints, moored, n, picked)
    if raw:
        _add_channel(cols, channels, "f0", ints["temperature"].astype(np.float64), "Temperature A/D counts", "counts")
        _add_channel(cols, channels, "f1", ints["conductivity"] / 256.0, "Conductivity frequency", "Hz")
        if h.pressure_type == "quartz":
            _add_channel(cols, channels, "f2", ints["pressure"] / 256.0, "Digiquartz pressure frequency", "Hz")
            _add_channel(cols, channels, "f3", _quartz_tc_counts(ints["ptc"]), "Digiquartz compensation",
                         "counts")
        else:
            _add_channel(cols, channels, "f2", ints["pressure"].astype(np.float64), "Pressure A/D counts",
                         "counts")
    df = _channel_frame(cols, channels)
    df.attrs.update(_hex_attrs(path, h, comp, df, channels, times, moored, layout, n))
    return df


def describe_hex(path: str | Path, *, memory_limit_bytes: float | None = None) -> dict[str, Any]:
    """What a ``.hex`` file is and holds, for ``hadal inspect`` (JSON-serialisable; no conversion done).

    Keys: ``format``, ``compression``, ``instrument``, ``model``, ``serial_number``, ``firmware``, ``mode``,
    ``scans``, ``sample_rate_hz``, ``interval_s``, ``scans_to_average``, ``pressure_sensor``, ``channels``
    (``[{name, long_name, units}]`` that :func:`read_hex` would produce), ``calibration_dates``,
    ``sensor_serials``, ``latitude_deg``, ``longitude_deg``, ``start_time_utc``, ``end_time_utc``,
    ``upload_time_utc``, ``casts``, ``scan_layout``. Raises :class:`~hadal.errors.InputError` as read_hex does
    (its text held against the memory budget ``memory_limit_bytes`` as it decompresses).
    """
    path = Path(path)
    text, comp = _read_text(path, memory_limit_bytes)
    header, data_lines, first_no = _split(path, text)
    h = parse_hex_header(path, header)
    _check_supported(h, path, data_lines)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ints, layout, moored = _decode(path, h, data_lines, first_no)
    n = len(ints["temperature"])
    chans = [("tv290C", "Temperature", "ITS-90, deg C"), ("c0S/m", "Conductivity", "S/m"), _pressure_channel(h)]
    chans += [(f"v{i}", f"Voltage {i} (Ext Volt {k})", "V") for i, k in enumerate(h.volts)]
    if h.aux.get("SBE38"):
        chans.append(("t3890C", "Temperature, SBE 38", "ITS-90, deg C"))
    extra = [name for name, _ in layout if name.startswith(("wetlabs", "gtd", "optode", "sbe63"))]
    if moored:
        chans.append(("timeS", "Time, Elapsed", "seconds"))
    start = end = None
    if moored:
        t0, t1 = float(ints["time"][0]), float(ints["time"][-1])
        start = (_EPOCH_2000 + _dt.timedelta(seconds=t0)).isoformat()
        end = (_EPOCH_2000 + _dt.timedelta(seconds=t1)).isoformat()
        interval = h.sample_interval_s or (float(np.median(np.diff(ints["time"]))) if n > 1 else None)
    else:
        interval = h.scans_to_average / PROFILE_SCAN_RATE_HZ
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            cast, per_cast = _pick_cast(path, h, n)
        if cast is not None:
            start = cast["start_utc"]
            last = float(per_cast[-1]) if per_cast is not None else (n - 1) * interval
            end = (pd.Timestamp(start) + pd.Timedelta(seconds=last)).isoformat()
            if per_cast is not None:
                chans.append(("timeS", "Time, Elapsed", "seconds"))
    return {
        "format": "Sea-Bird raw .hex",
        "compression": comp,
        "instrument": h.instrument,
        "model": h.model,
        "serial_number": h.serial_number,
        "firmware": h.firmware,
        "mode": "moored" if moored else "profile",
        "scans": n,
        "sample_rate_hz": (1.0 / interval) if interval else None,
        "interval_s": interval,
        "scans_to_average": h.scans_to_average,
        "pressure_sensor": h.pressure_type,
        "pressure_range_psia": h.pressure_range_psia,
        "channels": [{"name": a, "long_name": b, "units": c} for a, b, c in chans],
        "other_fields": extra,
        "calibration_dates": dict(h.calibration_dates),
        "sensor_serials": dict(h.sensor_serials),
        "latitude_deg": h.latitude_deg,
        "longitude_deg": h.longitude_deg,
        "start_time_utc": start,
        "end_time_utc": end,
        "upload_time_utc": h.upload_time_utc,
        "casts": [{k: v for k, v in c.items() if k != "line"} for c in h.casts],
        "scan_layout": [[name, nchar] for name, nchar in layout],
        "header_form": h.header_form,
    }
