"""Geographic helpers: the local metric map frame, geodesic distances, degree-minute formatting."""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np
from pyproj import CRS, Geod, Transformer

WGS84 = Geod(ellps="WGS84")


@dataclass(frozen=True)
class LocalFrame:
    """Local metric frame: transverse Mercator (scale 1) centred on an origin, x east / y north in metres.

    Used for every grid and for terrain matching, so that map cells are square metres and
    x/y convert to latitude/longitude exactly (pyproj) rather than with a flat-earth approximation.
    """

    origin_latitude_deg: float
    origin_longitude_deg: float

    @cached_property
    def crs(self) -> CRS:
        return CRS.from_proj4(
            f"+proj=tmerc +lat_0={self.origin_latitude_deg!r} +lon_0={self.origin_longitude_deg!r} "
            "+k=1 +x_0=0 +y_0=0 +datum=WGS84 +units=m +no_defs"
        )

    @cached_property
    def _fwd(self) -> Transformer:
        return Transformer.from_crs("EPSG:4326", self.crs, always_xy=True)

    @cached_property
    def _inv(self) -> Transformer:
        return Transformer.from_crs(self.crs, "EPSG:4326", always_xy=True)

    def to_xy(self, longitude_deg, latitude_deg):
        """(longitude, latitude) in degrees → (x_east_m, y_north_m)."""
        x, y = self._fwd.transform(np.asarray(longitude_deg, float), np.asarray(latitude_deg, float))
        return x, y

    def to_lonlat(self, x_east_m, y_north_m):
        """(x_east_m, y_north_m) → (longitude_deg, latitude_deg)."""
        lon, lat = self._inv.transform(np.asarray(x_east_m, float), np.asarray(y_north_m, float))
        return lon, lat


def geodesic_distance_m(lon1, lat1, lon2, lat2):
    """Distance on the WGS84 ellipsoid in metres (pyproj.Geod.inv)."""
    lon1, lat1, lon2, lat2 = np.broadcast_arrays(*(np.asarray(v, float) for v in (lon1, lat1, lon2, lat2)))
    _, _, d = WGS84.inv(lon1, lat1, lon2, lat2)
    return float(d) if np.ndim(d) == 0 else np.asarray(d)


def format_degmin(value_deg: float, axis: str, decimals: int = 3) -> str:
    """Format a latitude (axis='lat') or longitude (axis='lon') as the paper does: ``142°12.583'E``."""
    hemi = ("N" if value_deg >= 0 else "S") if axis == "lat" else ("E" if value_deg >= 0 else "W")
    a = abs(float(value_deg))
    deg = int(a)
    minutes = round((a - deg) * 60.0, decimals)
    if minutes >= 60.0:
        deg, minutes = deg + 1, minutes - 60.0
    return f"{deg}°{minutes:0{decimals + 3}.{decimals}f}'{hemi}"


def format_position(latitude_deg: float, longitude_deg: float, decimals: int = 3) -> str:
    """``142°12.583'E, 11°20.227'N`` (longitude first, as in the TERCOM paper)."""
    return f"{format_degmin(longitude_deg, 'lon', decimals)}, {format_degmin(latitude_deg, 'lat', decimals)}"


def parse_degmin(text: str) -> float:
    """Parse ``142°12.583'E`` / ``11 20.227 N`` into signed decimal degrees."""
    import re

    m = re.fullmatch(r"\s*(\d+)\s*[°\s]\s*(\d+(?:\.\d*)?)\s*'?\s*([NSEWnsew])\s*", text)
    if not m:
        raise ValueError(f"cannot parse degrees-minutes {text!r}")
    v = int(m.group(1)) + float(m.group(2)) / 60.0
    return -v if m.group(3).upper() in "SW" else v
