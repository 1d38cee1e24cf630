"""Laser (light-sectioning) bathymetry submaps for the landing analysis.

Modelled on the data of Sangekar et al., *Autonomous landing of underwater vehicles using high resolution
bathymetry*: §III (Table I: mapping altitude 2 m, camera-laser baseline 1.03 m, 4 mm along-track and 3 mm
cross-track resolution, 6 mm vertical resolution) and §IV (a transect on a rocky seamount slope at
~1380-1430 m, split into 25 m submaps with a ~1.5 m swath, manganese crusts, rocks, narrow swath).

Each submap is a strip along +x (the transect heads east in the survey's local frame) on a 15-25° slope
whose dip direction is within +-35° of the track, with

* benches: a smooth staircase along the dip direction - gently sloping treads (3-8°, below the 17.7°
  maximum landing slope of the paper's vehicle) separated by steeper risers, so the mean slope stays 15-25°;
* rocks and boulders: rounded elliptical protrusions 0.05-0.6 m high (power-law sizes), sparser on benches;
* crust texture: fractal roughness of a few millimetres; 1.5 mm range noise on every point;
* unmapped gaps: dropped scan lines, short full-swath gaps, low-reflectance holes and the camera's
  occlusion shadows behind tall boulders; ragged swath edges.

Points are x, y (m, local survey frame: x east, y north) and z = elevation (m, up; ~-1400 m).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.ndimage import map_coordinates

from hadal.synth.terrain import spectral_noise

MAPPING_ALTITUDE_M = 2.0
BASELINE_M = 1.03


@dataclass(frozen=True)
class SubmapSpec:
    index: int
    x0: float  # along-track start (m, survey frame)
    length_m: float
    swath_m: float
    slope_deg: float
    dip_offset_deg: float  # dip direction relative to the track direction (+x)
    z_start: float  # elevation at the start of the strip's centre line (m)
    bench_period_m: float
    spacing_along_m: float = 0.004
    spacing_across_m: float = 0.004
    raster_m: float = 0.005


def submap_specs(rng: np.random.Generator, small: bool) -> list[SubmapSpec]:
    """Consecutive submaps along the transect, 4 m apart (3 x 25 m; small: one 5 m strip)."""
    n, length = (1, 5.0) if small else (3, 25.0)
    specs, x0, z = [], 0.0, -1392.0
    for i in range(n):
        slope = float(rng.uniform(15.0, 25.0)) if i else float(rng.uniform(15.0, 18.0))
        dip = float(rng.uniform(-35.0, 35.0))
        specs.append(SubmapSpec(index=i + 1, x0=x0, length_m=length, swath_m=float(rng.uniform(1.4, 1.6)),
                                slope_deg=round(slope, 2), dip_offset_deg=round(dip, 2), z_start=round(z, 3),
                                bench_period_m=float(rng.uniform(2.6, 3.6))))
        drop = np.tan(np.radians(slope)) * np.cos(np.radians(dip)) * (length + 4.0)
        x0 += length + 4.0
        z -= drop
    return specs


def _staircase(s: np.ndarray, slope_deg: float, period: float, phase: float) -> tuple[np.ndarray, dict]:
    """Elevation change along the dip coordinate ``s`` (m): treads of 3-8° and risers, mean slope ``slope_deg``."""
    tread = np.tan(np.radians(5.0))
    mean = np.tan(np.radians(slope_deg))
    fs = np.linspace(s.min() - period, s.max() + period, int((s.max() - s.min() + 2 * period) / 0.002) + 2)
    riser = 0.5 * (1 + np.tanh((np.cos(2 * np.pi * (fs - phase) / period) - 0.1) / 0.12))
    rmean = riser.mean()
    steep = tread + (mean - tread) / rmean
    grad = tread + (steep - tread) * riser
    z = -np.concatenate([[0.0], np.cumsum(0.5 * (grad[1:] + grad[:-1]) * np.diff(fs))])
    z -= np.interp(0.0, fs, z)
    info = {"tread_slope_deg": 5.0, "riser_slope_deg": round(float(np.degrees(np.arctan(steep))), 2),
            "fs": fs, "riser": riser}
    return np.interp(s, fs, z), info


def _raster_axes(sp: SubmapSpec, meander_amp_m: float) -> tuple[np.ndarray, np.ndarray, tuple[float, float, float, float]]:
    """Raster cell-centre axes ``gx``, ``gy`` (m) over the strip's bounding box and the box
    ``(x0, x1, y0, y1)`` (m): the strip plus 0.1 m along-track and the meander plus 0.2 m across."""
    L, W, res = sp.length_m, sp.swath_m, sp.raster_m
    xr0, xr1 = sp.x0 - 0.1, sp.x0 + L + 0.1
    yr0, yr1 = -W / 2 - meander_amp_m - 0.2, W / 2 + meander_amp_m + 0.2
    gx = np.arange(xr0, xr1 + res, res)
    gy = np.arange(yr0, yr1 + res, res)
    return gx, gy, (xr0, xr1, yr0, yr1)


def _dip_coordinate(x_m, y_m, sp: SubmapSpec, dip_rad: float):
    """Coordinate along the dip direction (m, downslope) of points ``x_m``, ``y_m`` (m) from the strip start."""
    return (x_m - sp.x0) * np.cos(dip_rad) + y_m * np.sin(dip_rad)


def _draw_rocks(rng: np.random.Generator, sp: SubmapSpec, box: tuple[float, float, float, float], dip_rad: float,
                sinfo: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rock centres ``rx``, ``ry`` (m) and heights (m): power-law heights 0.05-0.6 m, at least two big
    boulders on a full (>= 20 m) submap, most of those falling on a tread rejected."""
    xr0, xr1, yr0, yr1 = box
    area = (xr1 - xr0) * (yr1 - yr0)
    n_rocks = rng.poisson(1.6 * area)
    u = rng.random(n_rocks)
    hmin, hmax, k = 0.05, 0.6, 2.2
    heights = (hmin ** (1 - k) - u * (hmin ** (1 - k) - hmax ** (1 - k))) ** (1 / (1 - k))
    if sp.length_m >= 20.0:  # at least one big boulder per full submap
        m = min(2, n_rocks)
        heights[:m] = rng.uniform(0.4, 0.6, m)
    rx = rng.uniform(xr0, xr1, n_rocks)
    ry = rng.uniform(yr0, yr1, n_rocks)
    # fewer rocks on the treads: reject most that fall on a tread
    on_tread = np.interp(_dip_coordinate(rx, ry, sp, dip_rad), sinfo["fs"], 1.0 - sinfo["riser"]) > 0.5
    keep = ~on_tread | (rng.random(n_rocks) < 0.15) | (heights >= 0.4)
    return rx[keep], ry[keep], heights[keep]


def _rock_relief(rng: np.random.Generator, gx: np.ndarray, gy: np.ndarray, X: np.ndarray, Y: np.ndarray,
                 rx: np.ndarray, ry: np.ndarray, heights: np.ndarray) -> tuple[np.ndarray, list[tuple]]:
    """Rock protrusion raster ``H`` (m above the base surface) of rounded elliptical rocks, and the camera
    occlusion shadows ``(x_a, x_b, y_c, half_width)`` (m) down-track of the rocks taller than 0.15 m."""
    H = np.zeros_like(X)
    shadows = []
    for x_c, y_c, h in zip(rx, ry, heights, strict=True):
        a = h * rng.uniform(1.2, 2.2)  # semi-axes ~ 1.2-2.2 x height
        b = a * rng.uniform(0.6, 1.0)
        rot = rng.uniform(0, np.pi)
        i0, i1 = np.searchsorted(gx, [x_c - a, x_c + a])
        j0, j1 = np.searchsorted(gy, [y_c - a, y_c + a])
        if i1 <= i0 or j1 <= j0:
            continue
        dx = X[j0:j1, i0:i1] - x_c
        dy = Y[j0:j1, i0:i1] - y_c
        p = (dx * np.cos(rot) + dy * np.sin(rot)) / a
        q = (-dx * np.sin(rot) + dy * np.cos(rot)) / b
        r2 = p * p + q * q
        shape = np.clip(1 - r2, 0, None) ** 0.55
        np.maximum(H[j0:j1, i0:i1], h * shape, out=H[j0:j1, i0:i1])
        if h > 0.15:  # camera occlusion shadow down-track of tall rocks
            shadows.append((x_c + 0.6 * a, x_c + 0.6 * a + h * BASELINE_M / MAPPING_ALTITUDE_M, y_c, 0.7 * b))
    return H, shadows


def _scan_lines(rng: np.random.Generator, sp: SubmapSpec) -> tuple[np.ndarray, list[list[float]]]:
    """Along-track positions (m) of the kept scan lines, every ``spacing_along_m`` with jitter, less the
    dropped lines and the short full-swath gaps; and those gaps ``[x_start, x_end]`` (m)."""
    L = sp.length_m
    nl = int(L / sp.spacing_along_m)
    ul = sp.x0 + (np.arange(nl) + 0.5) * sp.spacing_along_m + rng.normal(0, 0.0003, nl)
    keep_line = rng.random(nl) > 0.01  # dropped scan lines
    gaps = []
    for _ in range(max(1, int(L / 10.0))):  # short full-swath gaps (turbidity, vehicle pitch)
        g0 = float(rng.uniform(sp.x0 + 0.5, sp.x0 + L - 1.0))
        g1 = g0 + float(rng.uniform(0.15, 0.5))
        gaps.append([round(g0, 3), round(g1, 3)])
        keep_line &= ~((ul >= g0) & (ul <= g1))
    return ul[keep_line], gaps


def _scan_points(rng: np.random.Generator, sp: SubmapSpec, ul: np.ndarray,
                 y_centre: Callable[[np.ndarray], np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """Horizontal positions ``px``, ``py`` (m) of the laser points: every ``spacing_across_m`` along each
    scan line at along-track ``ul`` (m), yawed, inside a ragged swath around the meandering centre line."""
    W = sp.swath_m
    yaw = np.radians(rng.normal(0, 0.8)) + np.radians(0.5) * np.sin(ul / 3.1)
    half = W / 2 + 0.06 * np.sin(ul / 1.7 + 1.0) + rng.normal(0, 0.01, len(ul))  # ragged edges
    nv = int(np.ceil((W / 2 + 0.1) / sp.spacing_across_m))
    v = np.arange(-nv, nv + 1) * sp.spacing_across_m
    V = v[None, :] + rng.uniform(-0.3, 0.3, (len(ul), len(v))) * sp.spacing_across_m
    inside = np.abs(V) <= half[:, None]
    px = ul[:, None] + V * np.sin(yaw)[:, None]
    py = y_centre(ul)[:, None] + V * np.cos(yaw)[:, None]
    return px[inside], py[inside]


def _unmapped_mask(rng: np.random.Generator, sp: SubmapSpec, px: np.ndarray, py: np.ndarray,
                   y_centre: Callable[[Any], Any],
                   shadows: list[tuple]) -> tuple[np.ndarray, list[list[float]]]:
    """Mask of the points at ``px``, ``py`` (m) lost in low-reflectance holes or occlusion ``shadows``, and
    the holes ``[x, y, radius]`` (m)."""
    L, W = sp.length_m, sp.swath_m
    drop = np.zeros(len(px), dtype=bool)
    holes = []
    for _ in range(rng.poisson(0.3 * L) + 1):
        hr = float(rng.uniform(0.06, 0.2))
        hx = float(rng.uniform(sp.x0 + hr, sp.x0 + L - hr))
        hy = float(y_centre(hx) + rng.uniform(-W / 2 + hr + 0.1, W / 2 - hr - 0.1))
        holes.append([round(hx, 3), round(hy, 3), round(hr, 3)])
        drop |= (px - hx) ** 2 + (py - hy) ** 2 < hr * hr
    for x_a, x_b, y_c, half_w in shadows:
        drop |= (px >= x_a) & (px <= x_b) & (np.abs(py - y_c) <= half_w)
    return drop, holes


def _flat_patches(sp: SubmapSpec, dip_rad: float, sinfo: dict,
                  y_centre: Callable[[np.ndarray], np.ndarray]) -> list[dict]:
    """Flat-ish patches (treads, 5°) at least 0.6 m long crossed by the strip centre line, as
    ``{x_min, x_max, slope_deg}`` (m, degrees), for the landing tests."""
    fs, riser = sinfo["fs"], sinfo["riser"]
    xs_line = np.arange(sp.x0, sp.x0 + sp.length_m, 0.01)
    s_line = _dip_coordinate(xs_line, y_centre(xs_line), sp, dip_rad)
    on = np.interp(s_line, fs, 1.0 - riser) > 0.8
    patches = []
    if on.any():
        edges = np.flatnonzero(np.diff(np.concatenate([[0], on.astype(int), [0]])))
        for a0, a1 in zip(edges[::2], edges[1::2], strict=True):
            if (a1 - a0) * 0.01 >= 0.6:
                patches.append({"x_min": round(float(xs_line[a0]), 3), "x_max": round(float(xs_line[a1 - 1]), 3),
                                "slope_deg": 5.0})
    return patches


def _submap_info(sp: SubmapSpec, pts: np.ndarray, sinfo: dict, heights: np.ndarray, patches: list[dict],
                 gaps: list, holes: list) -> dict:
    """Truth record of one submap from its points ``(N, 3)`` (m) and drawn features."""
    px, py, pz = pts[:, 0], pts[:, 1], pts[:, 2]
    return {
        "x_min": float(px.min()), "x_max": float(px.max()), "y_min": float(py.min()), "y_max": float(py.max()),
        "z_min": float(pz.min()), "z_max": float(pz.max()), "n_points": int(len(pts)),
        "length_m": sp.length_m, "swath_m": sp.swath_m, "mean_slope_deg": sp.slope_deg,
        "dip_direction_deg_from_track": sp.dip_offset_deg,
        "dip_azimuth_deg": round((90.0 + sp.dip_offset_deg) % 360.0, 2),
        "tread_slope_deg": sinfo["tread_slope_deg"], "riser_slope_deg": sinfo["riser_slope_deg"],
        "bench_period_m": round(sp.bench_period_m, 3),
        "n_rocks": int(len(heights)), "max_protrusion_m": round(float(heights.max()) if len(heights) else 0.0, 3),
        "n_rocks_taller_than_0_15_m": int((heights > 0.15).sum()),
        "flat_patches": patches, "swath_gaps_x_m": gaps, "holes_xyr_m": holes,
        "point_spacing_m": [sp.spacing_along_m, sp.spacing_across_m], "range_noise_m": 0.0015,
    }


def make_submap(rng: np.random.Generator, sp: SubmapSpec) -> tuple[np.ndarray, dict]:
    """Point cloud ``(N, 3)`` (x, y, z) of one submap and its truth record."""
    res = sp.raster_m
    # vehicle lateral meander and raster over the strip's bounding box
    phase_m = float(rng.uniform(0, 2 * np.pi))
    yc_amp = float(rng.uniform(0.05, 0.2))

    def y_centre(x):
        """Lateral offset (m) of the vehicle's centre line at along-track ``x`` (m)."""
        return yc_amp * np.sin(2 * np.pi * (x - sp.x0) / 30.0 + phase_m)

    gx, gy, box = _raster_axes(sp, yc_amp)
    X, Y = np.meshgrid(gx, gy)

    th = np.radians(sp.dip_offset_deg)
    s = _dip_coordinate(X, Y, sp, th)  # coordinate along the dip (downslope)
    bench_phase = float(rng.uniform(0, sp.bench_period_m))
    zs, sinfo = _staircase(s, sp.slope_deg, sp.bench_period_m, bench_phase)
    base = sp.z_start + zs
    # crust texture: fractal roughness, ~3 mm rms, mostly at decimetre scales
    base = base + 0.003 * spectral_noise(rng, X.shape, res, beta=3.4, k_min=1 / 1.5)

    rx, ry, heights = _draw_rocks(rng, sp, box, th, sinfo)
    H, shadows = _rock_relief(rng, gx, gy, X, Y, rx, ry, heights)
    surf = base + H

    # scan geometry: lines every spacing_along, points every spacing_across along the projected laser line
    ul, gaps = _scan_lines(rng, sp)
    px, py = _scan_points(rng, sp, ul, y_centre)

    # low-reflectance holes and occlusion shadows
    drop, holes = _unmapped_mask(rng, sp, px, py, y_centre, shadows)
    px, py = px[~drop], py[~drop]

    fi = (px - gx[0]) / res
    fj = (py - gy[0]) / res
    pz = map_coordinates(surf, [fj, fi], order=1, mode="nearest", prefilter=False)
    pz = pz + rng.normal(0, 0.0015, len(pz))
    pts = np.column_stack([px, py, pz])

    # flat-ish patches (treads) crossed by the strip centre line, for the landing tests
    patches = _flat_patches(sp, th, sinfo, y_centre)
    return pts, _submap_info(sp, pts, sinfo, heights, patches, gaps, holes)
