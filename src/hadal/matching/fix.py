"""From the derived CTD table to a geographic fix: measured profile, matched track, drift, deepest point.

TERCOM paper §4.1.3-§4.2: the measured profile is the seafloor depth (vehicle depth + altitude) along
the bottom track; the matched start of the track is reported in latitude/longitude (degrees-minutes),
with the horizontal drift between the launch point and the start of the matched track (533 m in the
paper, a geodesic distance here) and the position of the deepest point recorded by the vehicle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pandas as pd

from hadal.errors import InputError
from hadal.geo import LocalFrame, format_position, geodesic_distance_m
from hadal.matching.tercom import TercomResult

REQUIRED_CTD_COLUMNS = ("time", "seafloor_depth_m", "dr_east_m", "dr_north_m", "phase", "depth_m")


@dataclass(frozen=True)
class Profile:
    """Measured profile resampled along the track: relative positions, seafloor depth, along-track distance."""

    track_xy: np.ndarray  # (N, 2) dead-reckoned x_east_m, y_north_m (relative to launch)
    depth_m: np.ndarray  # (N,) seafloor depth, positive down
    along_m: np.ndarray  # (N,) along-track distance of the bin centre
    n_raw: int
    time_s: np.ndarray | None = None  # (N,) mean time of the bin, seconds since the first sample (when given)


def bottom_samples(ctd: pd.DataFrame, name: str = "ctd.parquet") -> pd.DataFrame:
    """Bottom-phase rows with finite seafloor depth and dead-reckoned position, in time order."""
    missing = [c for c in REQUIRED_CTD_COLUMNS if c not in ctd.columns]
    if missing:
        raise InputError(f"{name} lacks column(s) {', '.join(missing)} needed for terrain matching")
    b = ctd[ctd["phase"].astype(str) == "bottom"]
    if b.empty:
        raise InputError(f"{name} has no rows with phase == 'bottom'; cannot build a seafloor profile")
    cols = ["seafloor_depth_m", "dr_east_m", "dr_north_m"]
    vals = b[cols].to_numpy(float)
    ok = np.isfinite(vals).all(axis=1)
    b = b[ok].sort_values("time")
    if len(b) < 3:
        raise InputError(f"{name}: only {len(b)} bottom samples with finite seafloor depth and position")
    if (b["seafloor_depth_m"] <= 0).any() or (b["seafloor_depth_m"] > 12000).any():
        raise InputError(f"{name}: seafloor_depth_m outside (0, 12000] m; expected depth positive down in metres")
    return b


def bottom_seconds(bottom: pd.DataFrame) -> np.ndarray:
    """Time of the bottom samples in seconds (UNIX epoch; any tz-aware or naive timestamps)."""
    t = pd.to_datetime(bottom["time"], utc=True)
    return (t - pd.Timestamp(0, tz="UTC")).dt.total_seconds().to_numpy(float)


def resample_along_track(x_m, y_m, depth_m, spacing_m: float, time_s=None) -> Profile:
    """Average consecutive samples into bins of ``spacing_m`` of along-track distance (~ the map resolution).

    Stationary periods (hovering) collapse into one bin, so each map cell along the track weighs about
    the same in the MSD, and the 1 Hz DR noise is averaged.
    """
    x, y, z = (np.asarray(a, float) for a in (x_m, y_m, depth_m))
    if spacing_m <= 0:
        raise InputError(f"resampling spacing must be > 0 m, got {spacing_m}")
    s = np.concatenate([[0.0], np.cumsum(np.hypot(np.diff(x), np.diff(y)))])
    k = np.floor(s / spacing_m).astype(np.int64)
    uk, inv, cnt = np.unique(k, return_inverse=True, return_counts=True)
    def mean(v):
        return np.bincount(inv, weights=v) / cnt
    tb = None if time_s is None else mean(np.asarray(time_s, float) - float(np.asarray(time_s, float)[0]))
    return Profile(np.column_stack([mean(x), mean(y)]), mean(z), mean(s), x.size, tb)


def profile_from_ctd(ctd: pd.DataFrame, spacing_m: float, name: str = "ctd.parquet") -> tuple[Profile, pd.DataFrame]:
    """Measured profile of the bottom phase (seafloor depth vs dead-reckoned track), resampled at ``spacing_m``."""
    b = bottom_samples(ctd, name)
    prof = resample_along_track(b["dr_east_m"], b["dr_north_m"], b["seafloor_depth_m"], spacing_m,
                                time_s=bottom_seconds(b))
    if prof.depth_m.size < 3:
        raise InputError(f"{name}: the bottom track is shorter than 3 x {spacing_m} m; too short to match")
    return prof, b


def matched_track(bottom: pd.DataFrame, res: TercomResult, frame: LocalFrame, map_depth=None,
                  drift_xy=None) -> pd.DataFrame:
    """The bottom-phase samples placed on the map by the TERCOM result, with lat/lon (degrees); ``drift_xy``
    (N, 2), the estimated dead-reckoning drift at the samples (posterior fix), is added when given."""
    xy = res.apply(bottom[["dr_east_m", "dr_north_m"]].to_numpy(float))
    if drift_xy is not None:
        xy = xy + np.asarray(drift_xy, float).reshape(-1, 2)
    lon, lat = frame.to_lonlat(xy[:, 0], xy[:, 1])
    out = pd.DataFrame({
        "time": bottom["time"].array,  # its own dtype: to_numpy() of tz-aware times is an object array (0.3 s)
        "x_east_m": xy[:, 0],
        "y_north_m": xy[:, 1],
        "lon": np.asarray(lon, float),
        "lat": np.asarray(lat, float),
        "depth_m": bottom["depth_m"].to_numpy(float),
        "seafloor_depth_m": bottom["seafloor_depth_m"].to_numpy(float),
    })
    if map_depth is not None:
        out["map_depth_m"] = map_depth(xy[:, 0], xy[:, 1])
        out["map_depth_minus_bias_m"] = out["map_depth_m"] - res.bias_m
    return out


def fix_summary(res: TercomResult, track: pd.DataFrame, frame: LocalFrame, launch_lat_deg: float, launch_lon_deg: float) -> dict:
    """fix.json content: start and deepest point in lat/lon and degrees-minutes, drift, uncertainty, warnings."""
    first = track.iloc[0]  # the first bottom sample, placed on the map by the match
    sx, sy = float(first["x_east_m"]), float(first["y_north_m"])
    slon, slat = float(first["lon"]), float(first["lat"])
    drift = geodesic_distance_m(launch_lon_deg, launch_lat_deg, slon, slat)
    lx, ly = (float(v) for v in frame.to_xy(launch_lon_deg, launch_lat_deg))
    i = int(np.nanargmax(track["depth_m"].to_numpy(float)))
    deep = track.iloc[i]
    return {
        "criterion": res.criterion,
        "start": {
            "time": pd.Timestamp(first["time"]).isoformat(),
            "x_east_m": sx, "y_north_m": sy, "lat": slat, "lon": slon,
            "position_degmin": format_position(slat, slon),
            "comment": "matched position of the first bottom-phase sample",
        },
        "profile_start": {"x_east_m": res.start_x_m, "y_north_m": res.start_y_m,
                          "comment": "map position of the first along-track profile point (TERCOM cell, or refined)"},
        "refinement": res.refinement,
        "best_offset_m": {"east": res.start_x_m - res.track_start_xy[0] - lx,
                          "north": res.start_y_m - res.track_start_xy[1] - ly,
                          "comment": "map position of the track start minus launch point plus dead-reckoned start"},
        "launch": {"lat": launch_lat_deg, "lon": launch_lon_deg, "x_east_m": lx, "y_north_m": ly,
                   "position_degmin": format_position(launch_lat_deg, launch_lon_deg)},
        "drift_m": float(drift),
        "heading_error_deg": res.heading_deg,
        "track_scale": res.scale,
        "score": res.score,
        "bias_m": res.bias_m,
        "bias_comment": "map depth minus measured depth (positive: multibeam map deeper than measured)",
        "uncertainty_m": {"east": res.sigma_x_m, "north": res.sigma_y_m, "radial": res.sigma_m},
        "second_optimum": {"score": res.second_score, "x_east_m": res.second_x_m, "y_north_m": res.second_y_m,
                           "separation_ratio": res.separation_ratio},
        "mismatch": res.mismatch,
        "search_edge": res.search_edge,
        "n_samples": res.n_samples,
        "n_valid": res.n_valid,
        "deepest_point": {
            "time": pd.Timestamp(deep["time"]).isoformat(), "depth_m": float(deep["depth_m"]),
            "seafloor_depth_m": float(deep["seafloor_depth_m"]),
            "x_east_m": float(deep["x_east_m"]), "y_north_m": float(deep["y_north_m"]),
            "lat": float(deep["lat"]), "lon": float(deep["lon"]),
            "position_degmin": format_position(float(deep["lat"]), float(deep["lon"])),
        },
        "warnings": list(res.warnings),
    }
