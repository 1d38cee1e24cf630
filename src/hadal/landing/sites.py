"""Landing-site identification and selection (Sangekar et al. §III-C, §III-D, Eqs. 11-15) and the public
entry point :func:`analyse_submap`.

Per landing heading α (-90° .. 90°, 5° steps): combine the exclusion zones (Fig. 19a), group the cells
where C_G may land by 8-connectivity, take the centre of the largest inscribed circle (maximum of the
Euclidean distance transform) as the landing coordinate (Fig. 19c), reject groups whose circle radius is
below 0.3 m, and cost every remaining candidate:

* P_s = θ̄ / θc (Eq. 11), θ̄ the slope of the plane fitted over the footprint at the landing coordinate;
* P_f = (5 - A_r/A_f)/4 clipped to [0, 1] (Eq. 12), A_r the largest rectangle of the vehicle's aspect
  ratio, oriented along α, inscribed in the site;
* P_r = R / R_max (Eqs. 13-14), R = mean |h - h̄| of the protrusion heights under the footprint and R_max
  the same for the worst admissible terrain of Fig. 20 (heights h(d) of Eq. 8 within b_u/2 of the centre,
  h_c beyond);
* C_s = (P_s + P_f + P_r)/3 (Eq. 15); the candidate with the lowest C_s over all headings is the site.

Choices where the paper is silent or where we deviate (on purpose):

* The circle radius is the Euclidean distance from the landing cell to the nearest excluded cell centre.
  When several cells share the largest circle (a corridor), the one nearest the middle of that ridge is taken.
* θ̄ of Eq. 11 is the slope of the plane fitted over the footprint at the landing coordinate — the "mean
  slope of the ground over the footprint" that the paper thresholds in Fig. 13c.
* P_r is not clipped: terrain rougher than the Fig. 20 worst case gives P_r > 1 (the paper does not say).
* Protrusion candidates are cells whose *local* slope (3-cell plane fit, Fig. 16a) exceeds θc and whose
  height is at least 5 mm; interior holes up to 0.01 m² are filled with the nearest elevation first
  (:func:`fill_small_holes`), larger gaps stay unmapped.
* α and α ± 180° give the same footprint, so -90° and 90° are analysed once and reported twice.
"""

from __future__ import annotations

import math
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd
import xarray as xr
from scipy import ndimage as ndi

from hadal.errors import InputError
from hadal.landing.exclusion import (
    EXCLUSION_FLAGS,
    HIGH_PROTRUSION,
    SLOPE,
    SMALL_PROTRUSION,
    UNMAPPED,
    HeadingCorrelator,
    HeadingMaps,
    default_headings_deg,
    footprint_offsets,
    small_protrusion_exclusion,
)
from hadal.landing.protrusion import protrusion_height_map
from hadal.landing.slope import local_slope_deg
from hadal.landing.vehicle import Vehicle

SITE_COLUMNS = [
    "heading_deg", "site_id", "row", "col", "x_m", "y_m", "radius_m", "area_m2", "slope_deg",
    "elevation_m", "roughness_m", "rect_area_m2", "rect_area_ratio", "p_s", "p_f", "p_r", "c_s",
]

SITE_FIELDS: dict[str, dict[str, str]] = {
    "submap": {"long_name": "laser submap name"},
    "heading_deg": {"units": "degree", "long_name": "landing heading, clockwise from +y (north)"},
    "site_id": {"long_name": "8-connected group label within this heading"},
    "row": {"long_name": "grid row of the landing coordinate"},
    "col": {"long_name": "grid column of the landing coordinate"},
    "x_m": {"units": "m", "long_name": "landing coordinate x (centre of the largest inscribed circle)"},
    "y_m": {"units": "m", "long_name": "landing coordinate y (centre of the largest inscribed circle)"},
    "radius_m": {"units": "m", "long_name": "radius of the largest inscribed circle"},
    "area_m2": {"units": "m2", "long_name": "area of the site (cells where C_G may land)"},
    "slope_deg": {"units": "degree", "long_name": "slope of the plane fitted over the footprint (Eq. 11)"},
    "elevation_m": {"units": "m", "long_name": "mean elevation over the footprint (positive up)"},
    "roughness_m": {"units": "m", "long_name": "R, mean |h - mean h| over the footprint (Eq. 13)"},
    "rect_area_m2": {"units": "m2", "long_name": "A_r, largest inscribed rectangle of the vehicle aspect ratio"},
    "rect_area_ratio": {"units": "1", "long_name": "A_r / A_f (Eq. 12)"},
    "p_s": {"units": "1", "long_name": "slope cost (Eq. 11)"},
    "p_f": {"units": "1", "long_name": "safety cost (Eq. 12)"},
    "p_r": {"units": "1", "long_name": "roughness cost (Eq. 14)"},
    "c_s": {"units": "1", "long_name": "landing cost (Eq. 15)"},
    "is_best": {"long_name": "the selected (lowest-cost) site of the submap"},
}


@dataclass
class LandingResult:
    """Everything :func:`analyse_submap` computes for one submap (arrays on the input grid, y/x ascending)."""

    x_m: np.ndarray
    y_m: np.ndarray
    cell_m: float
    vehicle: Vehicle
    headings_deg: np.ndarray
    elevation_m: np.ndarray
    slope_local_deg: np.ndarray
    protrusion_height_m: np.ndarray
    protrusion_candidate: np.ndarray
    small_exclusion: np.ndarray
    high_protrusion: np.ndarray
    exclusion: np.ndarray  # uint8 (heading, y, x) bit flags, see EXCLUSION_FLAGS
    sites: pd.DataFrame
    best: dict[str, Any] | None
    footprint_slope_deg: np.ndarray  # at the best heading (or the first heading when no site)
    best_site_mask: np.ndarray
    r_max_m: float
    timings_s: dict[str, float] = field(default_factory=dict)
    filled: np.ndarray | None = None  # interior holes filled before the analysis

    @property
    def critical_slope_deg(self) -> float:
        return self.vehicle.critical_slope_deg

    def to_dataset(self) -> xr.Dataset:
        """CF-style dataset of the maps (slope, protrusion height, exclusion per heading, final site)."""
        y = xr.Variable("y", self.y_m, {"units": "m", "long_name": "y (north) in the laser frame", "axis": "Y"})
        x = xr.Variable("x", self.x_m, {"units": "m", "long_name": "x (east) in the laser frame", "axis": "X"})
        hd = xr.Variable("heading", self.headings_deg, {"units": "degree", "long_name": "landing heading, clockwise from +y"})
        enc = {"zlib": True, "complevel": 4}
        ds = xr.Dataset(
            {
                "elevation_m": (("y", "x"), self.elevation_m.astype(np.float32), {"units": "m", "positive": "up", "long_name": "elevation"}),
                "slope_local_deg": (("y", "x"), self.slope_local_deg.astype(np.float32),
                                    {"units": "degree", "long_name": "local slope (plane fit, small window; Fig. 16a)"}),
                "protrusion_height_m": (("y", "x"), self.protrusion_height_m.astype(np.float32),
                                        {"units": "m", "long_name": "height of protrusions above the low-passed surface (Eq. 10, Fig. 17)"}),
                "protrusion_candidate": (("y", "x"), self.protrusion_candidate.astype(np.int8),
                                         {"long_name": "local slope > critical slope and height >= minimum (Fig. 16b)"}),
                "small_protrusion_exclusion": (("y", "x"), self.small_exclusion.astype(np.int8),
                                               {"long_name": "C_G exclusion for protrusions h <= h_c (Fig. 18c)"}),
                "high_protrusion": (("y", "x"), self.high_protrusion.astype(np.int8),
                                    {"long_name": "protrusions higher than h_c (Fig. 18d)"}),
                "exclusion": (("heading", "y", "x"), self.exclusion,
                              {"long_name": "C_G exclusion zone per landing heading (bit flags; 0 = C_G may land)",
                               "flag_masks": np.array(list(EXCLUSION_FLAGS.values()), np.uint8),
                               "flag_meanings": " ".join(EXCLUSION_FLAGS)}),
                "footprint_slope_deg": (("y", "x"), self.footprint_slope_deg.astype(np.float32),
                                        {"units": "degree", "long_name": "slope over the vehicle footprint at the selected heading (Fig. 13c)"}),
                "final_site": (("y", "x"), self.best_site_mask.astype(np.int8), {"long_name": "cells of the selected landing site"}),
                "filled": (("y", "x"), (np.zeros(self.elevation_m.shape, bool) if self.filled is None else self.filled).astype(np.int8),
                           {"long_name": "small interior hole filled with the nearest elevation before the analysis"}),
            },
            coords={"y": y, "x": x, "heading": hd},
        )
        for name in ds.data_vars:
            ds[name].encoding.update(enc)
        best = self.best or {}
        ds.attrs.update({
            "critical_slope_deg": self.vehicle.critical_slope_deg,
            "critical_height_m": self.vehicle.critical_height_m,
            "roughness_max_m": self.r_max_m,
            "cell_size_m": self.cell_m,
            "vehicle": self.vehicle.model_dump(),
            "n_candidate_sites": int(len(self.sites)),
            "best_site": {k: (float(v) if isinstance(v, (int, float, np.floating, np.integer)) else v) for k, v in best.items()},
            "method": "Sangekar et al., Autonomous landing of underwater vehicles using high resolution bathymetry, §III-IV",
        })
        return ds


def roughness_max_m(vehicle: Vehicle, cell_m: float) -> float:
    """R_max (Eq. 14, Fig. 20): roughness (Eq. 13) of the worst terrain that still leaves the footprint
    centre outside every C_G exclusion zone: at radial distance d ≤ b_u/2 the height limit h(d) of Eq. 8,
    beyond it h_c."""
    rr, cc = footprint_offsets(vehicle.length_m, vehicle.width_m, 0.0, cell_m)
    d = np.hypot(rr, cc) * cell_m
    h = np.where(d <= 0.5 * vehicle.width_m, vehicle.protrusion_height_limit_m(np.minimum(d, 0.5 * vehicle.width_m)),
                 vehicle.critical_height_m)
    return float(np.mean(np.abs(h - h.mean())))


def largest_aspect_rectangle_m2(mask: np.ndarray, cell_m: float, heading_deg: float, length_m: float,
                                width_m: float, resolution_m: float = 0.02) -> float:
    """A_r (Eq. 12): area (m²) of the largest rectangle with the vehicle's aspect ratio, long side along
    ``heading_deg``, inscribed in boolean ``mask`` (rows = y, cols = x, cell ``cell_m``).

    The mask is resampled (nearest) onto a grid aligned with the heading whose along-heading step is
    ``length/width`` times its cross step, where such rectangles are squares; the largest square comes from
    the chessboard distance transform (odd sides, so A_r is under-estimated by at most one step)."""
    if not mask.any():
        return 0.0
    a = math.radians(heading_deg)
    dt = max(resolution_m, cell_m)
    ds = dt * length_m / width_m
    ny, nx = mask.shape
    cy = np.array([-0.5, -0.5, ny - 0.5, ny - 0.5]) * cell_m
    cx = np.array([-0.5, nx - 0.5, -0.5, nx - 0.5]) * cell_m
    s = cx * math.sin(a) + cy * math.cos(a)
    t = cx * math.cos(a) - cy * math.sin(a)
    ns = int(math.ceil((s.max() - s.min()) / ds)) + 1
    nt = int(math.ceil((t.max() - t.min()) / dt)) + 1
    S, T = np.meshgrid(s.min() + ds * (np.arange(ns) + 0.5), t.min() + dt * (np.arange(nt) + 0.5), indexing="ij")
    X = S * math.sin(a) + T * math.cos(a)
    Y = S * math.cos(a) - T * math.sin(a)
    samp = ndi.map_coordinates(mask.astype(np.uint8), [Y / cell_m, X / cell_m], order=0, cval=0, mode="constant")
    samp = np.pad(samp, 1)
    if not samp.any():
        return 0.0
    m = int(ndi.distance_transform_cdt(samp, metric="chessboard").max())
    n = 2 * m - 1
    return float((n * dt) * (n * ds))


@dataclass
class _Ctx:
    z: np.ndarray
    h: np.ndarray
    cell_m: float
    vehicle: Vehicle
    corr: HeadingCorrelator
    static_excl: np.ndarray  # uint8 SMALL_PROTRUSION bits
    min_radius_px: float
    rect_res_m: float
    r_max_m: float
    x0: float
    y0: float


def _heading_exclusion(ctx: _Ctx, hm: HeadingMaps) -> np.ndarray:
    ex = ctx.static_excl.copy()
    ex[hm.unmapped] |= UNMAPPED
    with np.errstate(invalid="ignore"):
        ex[hm.slope_deg > ctx.vehicle.critical_slope_deg] |= SLOPE
    ex[hm.high] |= HIGH_PROTRUSION
    return ex


def _analyse_heading(ctx: _Ctx, heading: float, want_labels: bool = False):
    hm = ctx.corr.compute(heading, need_slope=True if want_labels else None)
    ex = _heading_exclusion(ctx, hm)
    ok = ex == 0
    rows: list[dict[str, Any]] = []
    labels = None
    if ok.any():
        labels, n = ndi.label(ok, structure=np.ones((3, 3), bool))
        # EDT only inside the bounding box of the landable cells (plus a background border)
        sl = ndi.find_objects(ok.astype(np.int8))[0]
        r0, c0 = sl[0].start, sl[1].start
        sub = np.pad(ok[sl], 1)
        dist = ndi.distance_transform_edt(sub)[1:-1, 1:-1]
        lab = labels[sl]
        # only cells whose inscribed circle is large enough can give a candidate (r >= 0.3 m)
        core = dist >= ctx.min_radius_px
        cand: list[tuple[int, int, int, float]] = []  # (label, row, col, radius_px)
        if core.any():
            cr, ccol = np.nonzero(core)
            cl, cd = lab[cr, ccol], dist[cr, ccol]
            o = np.lexsort((-cd, cl))  # by label, then largest distance first
            starts = np.nonzero(np.r_[True, cl[o][1:] != cl[o][:-1]])[0]
            ends = np.r_[starts[1:], o.size]
            for a0, a1 in zip(starts, ends, strict=False):
                seg = o[a0:a1]
                dmax = cd[seg[0]]
                ties = seg[cd[seg] >= dmax - 1e-9]
                # several cells share the largest circle (e.g. along a corridor): take the one nearest
                # to the middle of that ridge, a deterministic and central choice
                my, mx = cr[ties].mean(), ccol[ties].mean()
                q = ties[np.argmin((cr[ties] - my) ** 2 + (ccol[ties] - mx) ** 2)]
                cand.append((int(cl[q]), int(cr[q]), int(ccol[q]), float(dmax)))
        if cand:
            areas = np.bincount(lab.ravel(), minlength=n + 1)
            objs = ndi.find_objects(lab)
            rr, cc = hm.offsets
            v = ctx.vehicle
            for lid, pr, pc, rad_px in cand:
                i, j = pr + r0, pc + c0
                hs = ctx.h[i + rr, j + cc]
                zs = ctx.z[i + rr, j + cc]
                hs = hs[np.isfinite(hs)]
                R = float(np.mean(np.abs(hs - hs.mean()))) if hs.size else float("nan")
                theta = float(hm.slope_deg[i, j])
                rect = largest_aspect_rectangle_m2(lab[objs[lid - 1]] == lid, ctx.cell_m, heading,
                                                   v.length_m, v.width_m, ctx.rect_res_m)
                ratio = rect / v.footprint_area_m2
                p_s = theta / v.critical_slope_deg  # Eq. 11
                p_f = float(np.clip(0.25 * (5.0 - ratio), 0.0, 1.0))  # Eq. 12
                p_r = R / ctx.r_max_m  # Eq. 14
                rows.append({
                    "heading_deg": float(heading), "site_id": lid, "row": int(i), "col": int(j),
                    "x_m": ctx.x0 + j * ctx.cell_m, "y_m": ctx.y0 + i * ctx.cell_m,
                    "radius_m": rad_px * ctx.cell_m, "area_m2": float(areas[lid]) * ctx.cell_m**2,
                    "slope_deg": theta, "elevation_m": float(np.nanmean(zs)), "roughness_m": R,
                    "rect_area_m2": rect, "rect_area_ratio": ratio,
                    "p_s": p_s, "p_f": p_f, "p_r": p_r, "c_s": (p_s + p_f + p_r) / 3.0,  # Eq. 15
                })
    if want_labels:
        return ex, rows, hm, labels
    return ex, rows


def fill_small_holes(z: np.ndarray, cell_m: float, max_area_m2: float) -> tuple[np.ndarray, np.ndarray]:
    """Fill interior unmapped holes of at most ``max_area_m2`` (not connected to the map's outer boundary)
    with the nearest mapped elevation. Returns (filled z, bool mask of filled cells).

    The paper's exclusion uses "the mapped area and its unmapped boundary" (Fig. 13a); a resampled laser
    grid also has isolated empty cells where the point density dips, and one such cell under the footprint
    would wrongly forbid landing. Larger holes stay unmapped (the vehicle may not land over them)."""
    mapped = np.isfinite(z)
    if max_area_m2 <= 0 or mapped.all():
        return z, np.zeros(z.shape, bool)
    holes = ndi.binary_fill_holes(mapped) & ~mapped
    if not holes.any():
        return z, holes
    lab, n = ndi.label(holes)
    size = np.bincount(lab.ravel(), minlength=n + 1)
    small = (size <= max_area_m2 / cell_m**2) & (np.arange(n + 1) > 0)
    fill = small[lab]
    if not fill.any():
        return z, fill
    idx = ndi.distance_transform_edt(~mapped, return_distances=False, return_indices=True)
    out = z.copy()
    out[fill] = z[idx[0][fill], idx[1][fill]]
    return out, fill


def _grid_arrays(grid: xr.DataArray) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    if not isinstance(grid, xr.DataArray):
        raise InputError(f"landing analysis needs an xarray.DataArray elevation grid, got {type(grid).__name__}")
    if set(grid.dims) != {"y", "x"}:
        raise InputError(f"elevation grid must have dims ('y', 'x'), got {grid.dims}")
    units = str(grid.attrs.get("units", "m")).strip().lower()
    if units not in ("m", "meter", "meters", "metre", "metres"):
        raise InputError(f"elevation grid {grid.name!r} has units {units!r}; expected metres")
    g = grid.transpose("y", "x").sortby("y").sortby("x")
    x = np.asarray(g["x"].values, float)
    y = np.asarray(g["y"].values, float)
    if x.size < 3 or y.size < 3:
        raise InputError(f"elevation grid is too small ({y.size} x {x.size} cells)")
    dx, dy = np.diff(x), np.diff(y)
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise InputError("elevation grid has non-finite x/y coordinates")
    cell = float(np.median(dx))
    if cell <= 0 or np.max(np.abs(dx - cell)) > 1e-3 * cell or np.max(np.abs(dy - cell)) > 1e-3 * cell:
        raise InputError("elevation grid must be regular with equal x and y spacing (metres)")
    z = np.asarray(g.values, float)
    if str(grid.attrs.get("positive", "up")).lower() == "down":
        z = -z
    z = np.where(np.isfinite(z), z, np.nan)  # ±inf = unmapped
    if not np.isfinite(z).any():
        raise InputError("elevation grid has no mapped (finite) cells")
    return z, x, y, cell


def analyse_submap(
    grid: xr.DataArray,
    vehicle: Vehicle | None = None,
    *,
    headings_deg: np.ndarray | list[float] | None = None,
    min_site_radius_m: float = 0.3,
    min_protrusion_height_m: float = 0.005,
    exclusion_step_m: float = 0.005,
    local_slope_window_m: float = 0.03,
    block_m: float = 2.5,
    block_margin_m: float = 1.0,
    filter_order: int = 3,
    edge_correction: bool = False,
    rectangle_resolution_m: float = 0.02,
    fill_holes_max_m2: float = 0.01,
    workers: int = 1,
    keep_heading_exclusion: bool = True,
) -> LandingResult:
    """Landing-site analysis of one bathymetry submap (Sangekar et al. §III-IV).

    ``grid``: elevation (m, positive up; ``attrs['positive'] == 'down'`` is negated) on ``y``, ``x``
    metric coordinates (regular, equal spacing, e.g. 10 mm), NaN = unmapped. ``headings_deg``: landing
    headings (default -90° .. 90° in 5° steps). ``workers``: headings analysed in parallel threads.
    Raises :class:`hadal.errors.InputError` on unusable grids.
    """
    vehicle = vehicle or Vehicle()
    t_all = time.perf_counter()
    timings: dict[str, float] = {}
    z, x, y, cell = _grid_arrays(grid)
    z, filled = fill_small_holes(z, cell, fill_holes_max_m2)
    heads = default_headings_deg() if headings_deg is None else np.asarray(headings_deg, float)
    if heads.size == 0 or not np.all(np.isfinite(heads)):
        raise InputError("landing headings must be a non-empty list of finite angles")
    theta_c = vehicle.critical_slope_deg
    h_c = vehicle.critical_height_m

    t = time.perf_counter()
    win = max(3, int(round(local_slope_window_m / cell)))
    slope_local = local_slope_deg(z, cell, win)
    timings["slope_map"] = time.perf_counter() - t

    t = time.perf_counter()
    h = protrusion_height_map(z, cell, vehicle.diagonal_m, block_m=block_m, margin_m=block_margin_m,
                              order=filter_order, edge_correction=edge_correction)
    timings["protrusion_map"] = time.perf_counter() - t

    t = time.perf_counter()
    with np.errstate(invalid="ignore"):
        candidate = (slope_local > theta_c) & (h >= min_protrusion_height_m)  # Fig. 16b, Fig. 18b
        high = candidate & (h > h_c)  # Fig. 18d
        small = candidate & ~high
    radius = np.full(z.shape, np.nan)
    radius[small] = vehicle.exclusion_distance_m(h[small], exclusion_step_m) / cell  # Fig. 15
    small_excl = small_protrusion_exclusion(radius)  # Fig. 18c
    static = np.where(small_excl, SMALL_PROTRUSION, np.uint8(0)).astype(np.uint8)
    timings["small_protrusion_exclusion"] = time.perf_counter() - t

    t = time.perf_counter()
    corr = HeadingCorrelator(z, cell, vehicle, high, static_excluded=small_excl)
    r_max = roughness_max_m(vehicle, cell)
    ctx = _Ctx(z, h, cell, vehicle, corr, static, min_site_radius_m / cell, rectangle_resolution_m, r_max,
               float(x[0]), float(y[0]))
    timings["prepare_headings"] = time.perf_counter() - t

    t = time.perf_counter()
    # α and α ± 180° give the same footprint (the paper's reason for -90..90): analyse each once
    keys = [round(float(a) % 180.0, 9) for a in heads]
    uniq = list(dict.fromkeys(keys))
    first = {k: float(heads[keys.index(k)]) for k in uniq}
    if workers > 1 and len(uniq) > 1:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            res_u = dict(zip(uniq, pool.map(lambda k: _analyse_heading(ctx, first[k]), uniq), strict=False))
    else:
        res_u = {k: _analyse_heading(ctx, first[k]) for k in uniq}
    results = []
    for a, k in zip(heads, keys, strict=False):
        ex, rows = res_u[k]
        results.append((ex, [{**r, "heading_deg": float(a)} for r in rows]))
    timings["headings"] = time.perf_counter() - t

    t = time.perf_counter()
    exclusion = np.stack([r[0] for r in results]) if keep_heading_exclusion else np.zeros((0,) + z.shape, np.uint8)
    rows = [row for r in results for row in r[1]]
    sites = pd.DataFrame(rows, columns=SITE_COLUMNS)
    best = None
    best_mask = np.zeros(z.shape, bool)
    if len(sites):
        order = np.lexsort((-sites["radius_m"].to_numpy(), sites["c_s"].to_numpy()))
        bi = int(order[0])
        sites["is_best"] = False
        sites.loc[bi, "is_best"] = True
        best = {k: (v.item() if hasattr(v, "item") else v) for k, v in sites.iloc[bi].to_dict().items()}
        _, _, hm, labels = _analyse_heading(ctx, best["heading_deg"], want_labels=True)
        best_mask = labels == int(best["site_id"])
        fp_slope = hm.slope_deg
    else:
        sites["is_best"] = pd.Series(dtype=bool)
        fp_slope = corr.compute(float(heads[0]), need_slope=True).slope_deg
    timings["selection"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - t_all
    return LandingResult(
        x_m=x, y_m=y, cell_m=cell, vehicle=vehicle, headings_deg=heads, elevation_m=z,
        slope_local_deg=slope_local, protrusion_height_m=h, protrusion_candidate=candidate,
        small_exclusion=small_excl, high_protrusion=high, exclusion=exclusion, sites=sites, best=best,
        footprint_slope_deg=fp_slope, best_site_mask=best_mask, r_max_m=r_max, timings_s=timings, filled=filled,
    )


def results_table(sites: pd.DataFrame, area_m2: float, transect_length_m: float) -> dict[str, Any]:
    """The paper's Table V for a set of submaps: transect length (m), area surveyed (m²), number of candidate
    sites (all headings), mean, range and standard deviation of their landing costs C_s, and the number of
    submaps with at least one site."""
    cs = sites["c_s"].to_numpy(float) if len(sites) else np.array([])
    n_sub = int(sites["submap"].nunique()) if "submap" in sites and len(sites) else (1 if len(sites) else 0)
    return {
        "transect_length_m": float(transect_length_m),
        "area_surveyed_m2": float(area_m2),
        "number_of_sites": int(cs.size),
        "submaps_with_sites": n_sub,
        "mean_landing_cost": float(cs.mean()) if cs.size else float("nan"),
        "landing_cost_min": float(cs.min()) if cs.size else float("nan"),
        "landing_cost_max": float(cs.max()) if cs.size else float("nan"),
        "landing_cost_std": float(cs.std(ddof=1)) if cs.size > 1 else float("nan"),
    }


def mapped_length_m(mapped: np.ndarray, cell_m: float) -> float:
    """Length (m) of the mapped area along its principal axis (the transect length of one submap)."""
    rows, cols = np.nonzero(mapped)
    if rows.size < 2:
        return float(rows.size) * cell_m
    pts = np.column_stack([cols, rows]).astype(float)
    pts -= pts.mean(axis=0)
    _, vecs = np.linalg.eigh(np.cov(pts.T))
    proj = pts @ vecs[:, -1]
    return float(np.ptp(proj) + 1.0) * cell_m
