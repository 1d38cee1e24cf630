"""Landing sites in geographic coordinates and vehicle footprints as GeoJSON.

The laser survey's local frame (x, y in metres) is tied to the Earth by ``dive.yaml`` ``laser_frame``
(:class:`hadal.dive.LaserFrame`): its origin (latitude, longitude) and the azimuth ``heading_deg`` of its +y axis,
clockwise from true north. A frame point (x, y) is east/north offset

    east  =  x cos(h) + y sin(h)
    north = -x sin(h) + y cos(h)

from the origin (a rotation by h; h = 0: x east, y north), projected to longitude/latitude with a transverse
Mercator frame centred on the origin (:class:`hadal.geo.LocalFrame`; survey extents of metres to a few km, where
its scale error is below 1e-7). A landing heading (clockwise from the frame's +y) becomes the geographic
heading ``heading + h``.
"""

from __future__ import annotations

import datetime as _dt
import json
import math
import re
from typing import Any

import numpy as np
import pandas as pd

from hadal.geo import LocalFrame


def frame_to_east_north(x_m: Any, y_m: Any, heading_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Laser-frame (x, y) -> (east, north) offsets from the frame origin (m), rotation by ``heading_deg``."""
    h = math.radians(heading_deg)
    x, y = np.asarray(x_m, float), np.asarray(y_m, float)
    return x * math.cos(h) + y * math.sin(h), -x * math.sin(h) + y * math.cos(h)


def frame_to_lonlat(x_m: Any, y_m: Any, laser_frame: Any) -> tuple[np.ndarray, np.ndarray]:
    """Laser-frame (x, y) -> (longitude, latitude) in degrees (WGS 84)."""
    e, n = frame_to_east_north(x_m, y_m, float(laser_frame.heading_deg))
    lon, lat = LocalFrame(laser_frame.origin_latitude_deg, laser_frame.origin_longitude_deg).to_lonlat(e, n)
    return np.asarray(lon, float), np.asarray(lat, float)


def georeference_sites(sites: pd.DataFrame, laser_frame: Any) -> pd.DataFrame:
    """``sites`` (``x_m``/``y_m``/``heading_deg`` in the laser frame) with ``lat``, ``lon`` and
    ``heading_true_deg`` (clockwise from true north) added; unchanged without a ``laser_frame``."""
    if laser_frame is None or not {"x_m", "y_m"} <= set(sites.columns):
        return sites
    out = sites.copy()
    lon, lat = frame_to_lonlat(out["x_m"].to_numpy(float), out["y_m"].to_numpy(float), laser_frame)
    out["lat"], out["lon"] = lat, lon
    if "heading_deg" in out.columns:
        out["heading_true_deg"] = np.mod(out["heading_deg"].to_numpy(float) + float(laser_frame.heading_deg), 360.0)
    return out


SITE_GEO_FIELDS: dict[str, dict[str, str]] = {
    "lat": {"units": "degrees_north", "standard_name": "latitude", "long_name": "latitude of the landing coordinate"},
    "lon": {"units": "degrees_east", "standard_name": "longitude", "long_name": "longitude of the landing coordinate"},
    "heading_true_deg": {"units": "degree", "long_name": "landing heading, clockwise from true north"},
}


def footprint_corners(x_m: float, y_m: float, heading_deg: float, length_m: float, width_m: float) -> np.ndarray:
    """Corners (4, 2) of the vehicle footprint (length along ``heading_deg``, clockwise from +y) centred on
    (x, y), in the same frame, counter-clockwise."""
    h = math.radians(heading_deg)
    ux, uy = math.sin(h), math.cos(h)  # along the heading
    vx, vy = math.cos(h), -math.sin(h)  # to the right of it
    a, b = 0.5 * length_m, 0.5 * width_m
    c = [(x_m - a * ux - b * vx, y_m - a * uy - b * vy), (x_m - a * ux + b * vx, y_m - a * uy + b * vy),
         (x_m + a * ux + b * vx, y_m + a * uy + b * vy), (x_m + a * ux - b * vx, y_m + a * uy - b * vy)]
    pts = np.array(c, float)
    # counter-clockwise (RFC 7946 exterior rings): positive shoelace area in x-east/y-north
    area = 0.5 * np.sum(pts[:, 0] * np.roll(pts[:, 1], -1) - np.roll(pts[:, 0], -1) * pts[:, 1])
    return pts if area > 0 else pts[::-1]


def footprints_geojson(sites: pd.DataFrame, laser_frame: Any, length_m: float, width_m: float,
                       properties: tuple[str, ...] = ("submap", "heading_deg", "heading_true_deg", "c_s", "radius_m",
                                                      "slope_deg", "is_best")) -> dict[str, Any] | None:
    """A GeoJSON FeatureCollection (RFC 7946: lon/lat WGS 84) of the vehicle footprint of every site at its
    landing heading, or ``None`` without a ``laser_frame``."""
    if laser_frame is None:
        return None
    feats = []
    for _, s in sites.iterrows():
        poly = footprint_corners(float(s["x_m"]), float(s["y_m"]), float(s["heading_deg"]), length_m, width_m)
        lon, lat = frame_to_lonlat(poly[:, 0], poly[:, 1], laser_frame)
        ring = [[float(a), float(b)] for a, b in zip(lon, lat, strict=True)]
        ring.append(ring[0])
        props = {k: _plain(s[k]) for k in properties if k in s.index}
        feats.append({"type": "Feature", "geometry": {"type": "Polygon", "coordinates": [ring]},
                      "properties": props})
    return {"type": "FeatureCollection", "features": feats,
            "properties": {"laser_frame": {"origin_latitude_deg": laser_frame.origin_latitude_deg,
                                           "origin_longitude_deg": laser_frame.origin_longitude_deg,
                                           "heading_deg": laser_frame.heading_deg},
                           "vehicle_length_m": length_m, "vehicle_width_m": width_m}}


def _plain(v: Any) -> Any:
    if isinstance(v, (np.bool_, bool)):
        return bool(v)
    if isinstance(v, (np.integer,)):
        return int(v)
    if isinstance(v, (float, np.floating)):
        return float(v) if np.isfinite(v) else None
    return v if isinstance(v, (str, int)) or v is None else str(v)


def strict_json(obj: Any, **kw: Any) -> str:
    """``json.dumps`` that never writes NaN/Infinity (they become ``null``) and turns numpy/pandas values
    into plain ones (timestamps ISO-8601 without spurious microseconds)."""
    from hadal.products.io import json_clean

    return json.dumps(json_clean(_timestamps(obj)), allow_nan=False, default=_default, **kw)


_ISO_RE = re.compile(r"\d{4}-\d{2}-\d{2}[T ]\d{2}:\d{2}:\d{2}(\.\d+)?(Z|[+-]\d{2}:?\d{2})")


def _timestamps(obj: Any) -> Any:
    """Timestamps (objects, and ISO-8601 strings with an offset) as :func:`iso_utc` strings."""
    if isinstance(obj, dict):
        return {k: _timestamps(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [_timestamps(v) for v in obj]
    if isinstance(obj, (pd.Timestamp, _dt.datetime)):
        return iso_utc(obj)
    if isinstance(obj, str) and _ISO_RE.fullmatch(obj):
        return iso_utc(obj)
    return obj


def iso_utc(t: Any) -> str | None:
    """ISO-8601 UTC (``Z``); fractional seconds only when there are any (milliseconds, or microseconds when the
    time has sub-millisecond digits)."""
    if t is None or (isinstance(t, float) and not np.isfinite(t)):
        return None
    ts = pd.Timestamp(t)
    if ts is pd.NaT:
        return None
    ts = ts.tz_localize("UTC") if ts.tzinfo is None else ts.tz_convert("UTC")
    if ts.microsecond == 0 and ts.nanosecond == 0:
        return ts.strftime("%Y-%m-%dT%H:%M:%SZ")
    if ts.microsecond % 1000 == 0:
        return ts.strftime("%Y-%m-%dT%H:%M:%S.") + f"{ts.microsecond // 1000:03d}Z"
    return ts.strftime("%Y-%m-%dT%H:%M:%S.%fZ")  # real sub-millisecond digits are kept


def _default(obj: Any) -> Any:
    if isinstance(obj, (np.integer, np.floating, np.bool_)):
        return obj.item()
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, pd.Timestamp):
        return iso_utc(obj)
    return str(obj)
