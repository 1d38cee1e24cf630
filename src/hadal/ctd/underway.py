"""Underway records (thermosalinographs): recognised by their metadata and content, published as a trajectory.

A Sea-Bird thermosalinograph (SBE 21, SBE 45, ...) logged by Seasave with ``Store Lat/Lon Data = Append to Every
Scan`` writes a ``.cnv`` whose rows carry the ship's NMEA position (SeaSoft channels ``latitude: Latitude [deg]``,
``longitude: Longitude [deg]``) next to temperature and conductivity; its pressure channel, when there is one, is
a constant (``prM = 0``: the instrument sits in the ship's seawater line). Binned by pressure it would become a
0 m "cast" at the header position; it is a *trajectory* (CF-1.8 ``featureType = trajectory``): per scan time,
latitude, longitude, temperature, conductivity, PSS-78 salinity and density.

Rule (:func:`underway_evidence`; ``hadal init`` writes its outcome into ``dive.yaml`` as the source entry's
``kind: underway`` or ``kind: cast``, with the evidence in a comment, and the pipeline follows ``kind``):

* the record has per-scan position channels (SeaSoft ``latitude``/``longitude``, units ``deg``), and
* those positions move: the largest great-circle distance of a scan's position from the first scan's is at least
  :data:`MIN_TRACK_M` (a ship on station drifts less during a cast; a cast has pressure range anyway), and
* its pressure is near-constant: no pressure channel, or the span of its finite values between their 1st and 99th
  percentiles (a few spikes do not count) is at most :data:`MAX_PRESSURE_RANGE_DBAR` (a cast profiles, a seawater
  line does not).

The instrument model (``* Sea-Bird SBE 21 Data File:``: a thermosalinograph model, :data:`TSG_MODELS`) is recorded
in the evidence but neither needed nor sufficient: per-scan moving positions at constant pressure are what make a
trajectory. Everything here is pure (NumPy/pandas; gsw via :mod:`hadal.ctd.teos10`).
"""

from __future__ import annotations

import re
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
import pandas as pd

#: positions of an underway record move at least this far from the first scan's (m)
MIN_TRACK_M = 100.0
#: an underway record's pressure range (max - min of the finite values) is at most this (dbar)
MAX_PRESSURE_RANGE_DBAR = 2.0
#: SeaSoft short names of the per-scan NMEA position channels (Seasave "Append to Every Scan")
LATITUDE_CHANNELS = ("latitude", "lat")
LONGITUDE_CHANNELS = ("longitude", "lon")
#: Sea-Bird thermosalinograph models (recorded in the evidence; not needed for the rule)
TSG_MODELS = ("SBE 21", "SBE 45", "SBE 38")
#: SeaSoft pressure channels, in order of preference (as :data:`hadal.ingest.cnv.CNV_PRESSURE`)
_PRESSURE_CHANNELS = ("prDM", "prdM", "prSM", "prM", "pr")
_EARTH_RADIUS_M = 6_371_008.8


@dataclass
class UnderwayEvidence:
    """What :func:`underway_evidence` found, and its outcome (``underway``) with the reason in words."""

    underway: bool
    reason: str
    latitude_channel: str | None = None
    longitude_channel: str | None = None
    positions: int = 0
    max_distance_m: float | None = None
    pressure_channel: str | None = None
    pressure_range_dbar: float | None = None
    instrument_model: str | None = None

    def to_dict(self) -> dict[str, Any]:
        return asdict(self)


def _channel(df: pd.DataFrame, names: tuple[str, ...]) -> str | None:
    by_lower = {str(c).strip().lower(): str(c) for c in df.columns}
    return next((by_lower[n] for n in names if n in by_lower), None)


def position_channels(df: pd.DataFrame) -> tuple[str, str] | None:
    """The per-scan latitude and longitude columns of a :func:`hadal.ingest.cnv.read_cnv` frame, or ``None``."""
    lat, lon = _channel(df, LATITUDE_CHANNELS), _channel(df, LONGITUDE_CHANNELS)
    return (lat, lon) if lat is not None and lon is not None else None


def scan_positions(df: pd.DataFrame) -> tuple[np.ndarray, np.ndarray]:
    """Per-scan latitude and longitude (degrees north/east) of a read ``.cnv``; NaN where missing (bad_flag) or
    outside ±90/±180 (the -180..180 convention of the file is kept). ``KeyError`` without position channels."""
    cols = position_channels(df)
    if cols is None:
        raise KeyError("no per-scan latitude/longitude channels")
    lat = pd.to_numeric(df[cols[0]], errors="coerce").to_numpy(np.float64)
    lon = pd.to_numeric(df[cols[1]], errors="coerce").to_numpy(np.float64)
    bad = ~(np.isfinite(lat) & np.isfinite(lon)) | (np.abs(lat) > 90) | (np.abs(lon) > 360)
    lat, lon = lat.copy(), lon.copy()
    lat[bad] = np.nan
    lon[bad] = np.nan
    return lat, lon


def distance_m(lat0: float, lon0: float, lat: np.ndarray, lon: np.ndarray) -> np.ndarray:
    """Great-circle (haversine, mean Earth radius) distance in m from ``(lat0, lon0)`` to each position."""
    p0, p = np.radians(lat0), np.radians(lat)
    dphi = p - p0
    dlmb = np.radians(lon - lon0)
    a = np.sin(dphi / 2) ** 2 + np.cos(p0) * np.cos(p) * np.sin(dlmb / 2) ** 2
    return 2 * _EARTH_RADIUS_M * np.arcsin(np.sqrt(np.clip(a, 0.0, 1.0)))


def _instrument_model(attrs: dict[str, Any]) -> str | None:
    m = re.search(r"SBE\s*(\d+\w*)", str(attrs.get("instrument") or ""), re.I)
    return f"SBE {m.group(1)}" if m else None


def underway_evidence(df: pd.DataFrame) -> UnderwayEvidence:
    """Apply the module's rule to a read Sea-Bird record (:func:`hadal.ingest.cnv.read_seabird`)."""
    model = _instrument_model(dict(df.attrs))
    tsg = f" ({model}, a thermosalinograph model)" if model in TSG_MODELS else (f" ({model})" if model else "")
    pcol = next((c for c in _PRESSURE_CHANNELS if c in df.columns), None)
    prange = None
    if pcol is not None:
        pr = pd.to_numeric(df[pcol], errors="coerce").to_numpy(np.float64)
        pr = pr[np.isfinite(pr)]
        prange = float(np.diff(np.percentile(pr, [1, 99]))[0]) if pr.size else None
    ev = UnderwayEvidence(False, "", pressure_channel=pcol, pressure_range_dbar=prange, instrument_model=model)
    cols = position_channels(df)
    if cols is None:
        return _header_position_evidence(ev, df, model, tsg)
    ev.latitude_channel, ev.longitude_channel = cols
    lat, lon = scan_positions(df)
    ok = np.flatnonzero(np.isfinite(lat))
    ev.positions = int(ok.size)
    if ok.size < 2:
        ev.reason = f"cast: per-scan position channels {cols[0]}/{cols[1]} hold {ok.size} valid position(s){tsg}"
        return ev
    d = distance_m(lat[ok[0]], lon[ok[0]], lat[ok], lon[ok])
    ev.max_distance_m = round(float(d.max()), 1)
    ptxt = ("no pressure channel" if pcol is None else
            f"{pcol} spans {prange:.3f} dbar (1st-99th percentile)" if prange is not None else f"{pcol} has no valid value")
    if ev.max_distance_m < MIN_TRACK_M:
        ev.reason = (f"cast: per-scan positions ({cols[0]}/{cols[1]}) stay within {ev.max_distance_m:.0f} m of the "
                     f"first (< {MIN_TRACK_M:g} m){tsg}")
        return ev
    if prange is not None and prange > MAX_PRESSURE_RANGE_DBAR:
        ev.reason = (f"cast: {ptxt} (> {MAX_PRESSURE_RANGE_DBAR:g} dbar), although its per-scan positions move "
                     f"{ev.max_distance_m:.0f} m{tsg}")
        return ev
    ev.underway = True
    ev.reason = (f"underway: per-scan positions ({cols[0]}/{cols[1]}, {ok.size} fixes) move up to "
                 f"{ev.max_distance_m / 1000:.2f} km from the first, {ptxt} (<= {MAX_PRESSURE_RANGE_DBAR:g} dbar)"
                 f"{tsg}")
    return ev


def header_position(df: pd.DataFrame) -> tuple[float, float] | None:
    """The record's header position (``* NMEA Latitude/Longitude`` or ``** Latitude/Longitude``, as read by
    :func:`hadal.ingest.cnv.read_seabird` into ``attrs``), or ``None``."""
    lat, lon = df.attrs.get("latitude_deg"), df.attrs.get("longitude_deg")
    if lat is None or lon is None or not (np.isfinite(lat) and np.isfinite(lon)):
        return None
    return float(lat), float(lon)


def _header_position_evidence(ev: UnderwayEvidence, df: pd.DataFrame, model: str | None, tsg: str) -> UnderwayEvidence:
    """No per-scan position channels: a thermosalinograph model (the header's ``* Sea-Bird SBE 21 Data File:``)
    at near-constant (or no) pressure is an underway record whose every scan is at the header position (Seasave
    without "Append to Every Scan"); anything else is a cast."""
    pos = header_position(df)
    flat = ev.pressure_range_dbar is None or ev.pressure_range_dbar <= MAX_PRESSURE_RANGE_DBAR
    if model not in TSG_MODELS or pos is None or not flat:
        ev.reason = f"cast: no per-scan latitude/longitude channels{tsg}"
        return ev
    ptxt = ("no pressure channel" if ev.pressure_channel is None else
            f"{ev.pressure_channel} spans {ev.pressure_range_dbar:.3f} dbar (1st-99th percentile)")
    ev.underway, ev.positions = True, 1
    ev.reason = (f"underway: {model}, a thermosalinograph model, {ptxt} (<= {MAX_PRESSURE_RANGE_DBAR:g} dbar); no "
                 f"per-scan position channels: every scan at the header position ({pos[0]:.5f}, {pos[1]:.5f})")
    return ev


def record_positions(df: pd.DataFrame) -> tuple[np.ndarray, np.ndarray, str]:
    """Per-scan positions of an underway record and where they come from: its own per-scan channels
    (:func:`scan_positions`), else its header position for every scan (a thermosalinograph logged without
    per-scan positions). ``KeyError`` when it has neither."""
    cols = position_channels(df)
    if cols is not None:
        lat, lon = scan_positions(df)
        return lat, lon, (f"the record's own per-scan latitude/longitude channels ({cols[0]}/{cols[1]}), matched "
                          "to the samples by time")
    pos = header_position(df)
    if pos is None:
        raise KeyError("no per-scan latitude/longitude channels and no header position")
    n = len(df)
    return (np.full(n, pos[0]), np.full(n, pos[1]),
            "the record's header position (no per-scan position channels): every scan at the same place")


def positions_at(times_ns: np.ndarray, scan_times_ns: np.ndarray, lat: np.ndarray, lon: np.ndarray
                 ) -> tuple[np.ndarray, np.ndarray]:
    """The file's own per-scan positions at ``times_ns`` (the samples of the ingested table): the scan with the
    same time (exact match; the ingest keeps the scans' times), NaN where no scan has that time."""
    order = np.argsort(scan_times_ns, kind="stable")
    st = np.asarray(scan_times_ns)[order]
    t = np.asarray(times_ns)
    i = np.clip(np.searchsorted(st, t), 0, max(st.size - 1, 0))
    hit = st.size > 0
    found = (st[i] == t) if hit else np.zeros(t.shape, bool)
    out_lat = np.where(found, np.asarray(lat)[order][i], np.nan) if hit else np.full(t.shape, np.nan)
    out_lon = np.where(found, np.asarray(lon)[order][i], np.nan) if hit else np.full(t.shape, np.nan)
    return out_lat, out_lon


def underway_columns(conductivity_s_m: np.ndarray, temperature_its90_degc: np.ndarray, pressure_dbar: np.ndarray,
                     latitude_deg: np.ndarray, longitude_deg: np.ndarray) -> dict[str, np.ndarray]:
    """Per-scan seawater properties of an underway record: PSS-78 practical salinity and EOS-80 in situ density
    (:mod:`hadal.seawater`, as for a cast), Chen-Millero sound speed and the TEOS-10 columns (gsw, each scan at its
    own position; :func:`hadal.ctd.teos10.teos10_columns`). NaN where an input is NaN."""
    from hadal.ctd.teos10 import teos10_columns
    from hadal.seawater import density_eos80, practical_salinity, sound_speed_chen_millero

    c = np.asarray(conductivity_s_m, np.float64)
    t = np.asarray(temperature_its90_degc, np.float64)
    p = np.asarray(pressure_dbar, np.float64)
    sp = practical_salinity(c, t, p)
    out = {"practical_salinity": sp, "density_kg_m3": density_eos80(sp, t, p),
           "sound_speed_m_s": sound_speed_chen_millero(sp, t, p)}
    lat = np.asarray(latitude_deg, np.float64)
    lon = np.asarray(longitude_deg, np.float64)
    out.update(teos10_columns(sp, t, p, lon, lat))  # type: ignore[arg-type]  # gsw takes per-scan positions
    return out
