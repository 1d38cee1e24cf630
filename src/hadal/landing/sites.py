"""Landing-site identification and selection (Sangekar et al. §III-C, §III-D, [Landing Eqs. 11-15]) and the public
entry point :func:`analyse_submap`.

Per landing heading α (-90° .. 90°, 5° steps): combine the exclusion zones (Fig. 19a), group the cells
where C_G may land by 8-connectivity, take the centre of the largest inscribed circle (maximum of the
Euclidean distance transform) as the landing coordinate (Fig. 19c), reject groups whose circle radius is
below 0.3 m, and cost every remaining candidate:

* P_s = θ̄ / θc ([Landing Eq. 11]), θ̄ the slope of the plane fitted over the footprint at the landing coordinate;
* P_f = (5 - A_r/A_f)/4 clipped to [0, 1] ``[Landing Eq. 12]``, A_r the largest rectangle of the vehicle's aspect
  ratio, oriented along α, inscribed in the site;
* P_r = R / R_max ([Landing Eqs. 13-14]), R = mean |h - h̄| of the protrusion heights under the footprint and R_max
  the same for the worst admissible terrain of Fig. 20 (heights h(d) of [Landing Eq. 8] within b_u/2 of the centre,
  h_c beyond);
* C_s = (P_s + P_f + P_r)/3 ([Landing Eq. 15]); the candidate with the lowest C_s over all headings is the site.

Choices where the paper is silent or where we deviate (on purpose):

* The circle radius is the Euclidean distance from the landing cell to the nearest excluded cell centre.
  When several cells share the largest circle (a corridor), the one nearest the middle of that ridge is taken.
* θ̄ of [Landing Eq. 11] is the slope of the plane fitted over the footprint at the landing coordinate — the "mean
  slope of the ground over the footprint" that the paper thresholds in Fig. 13c.
* P_r is not clipped: terrain rougher than the Fig. 20 worst case gives P_r > 1 (the paper does not say).
* Protrusions higher than h_c ``[Landing Eq. 9]`` are *every* mapped cell whose height (above the ground of
  :mod:`hadal.landing.protrusion`, which keeps the full height of any rock narrower than the vehicle
  diagonal) exceeds h_c — not only steep cells, so flat rock tops count. The ``[Landing Eq. 8]`` discs
  for lower protrusions use the paper's candidates: cells whose local slope (plane fit over a fixed
  *physical* window, ``local_slope_window_m`` = 0.1 m by default, Fig. 16a) exceeds θc and whose height is at
  least 5 mm. A window of a few cells (the old 3 cm) turns sub-resolution sensor noise into steep cells; 0.1 m
  keeps the slope error under 6 mm noise at ~1°. Interior holes up to 0.01 m² are filled with the nearest
  elevation first (:func:`fill_small_holes`), larger gaps stay unmapped.
* A_r of [Landing Eq. 12] is exact on the grid (:func:`largest_aspect_rectangle_m2`), independent of the crop origin.
* Inputs are checked for plausibility (units, cell size ≤ 1/10 × vehicle width — up to 0.2 × only with an
  explicit ``max_cell_fraction`` override, reported as a warning — depth sign, elevations beyond
  any ocean depth, implausible median slope) and options are bounded (:class:`AnalysisOptions`); candidates
  with a non-finite cost are dropped, so the best site is never NaN.
* α and α ± 180° give the same footprint, so -90° and 90° are analysed once and reported twice.
"""

from __future__ import annotations

import dataclasses
import math
import queue
import threading
import time
import warnings
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd
import xarray as xr
from pydantic import ValidationError
from scipy import ndimage as ndi

from hadal.errors import ConfigError, InputError, first_validation_error
from hadal.landing._kernels import (
    combine_exclusion,
    outer_border,
    outer_border_of,
    site_cells_at_least,
    site_stats,
    squared_edt,
    squared_edt_into,
)
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
from hadal.landing.limits import CELL_FRACTION_RULE, COARSE_CELL_LIMIT
from hadal.landing.options import AnalysisOptions
from hadal.landing.protrusion import protrusion_height_map
from hadal.landing.slope import local_slope_deg
from hadal.landing.vehicle import Vehicle

#: fewest cells along each axis of a grid the analysis accepts (the slope/curvature windows need neighbours)
MIN_GRID_CELLS = 3
#: the cell-size rule CELL_FRACTION_RULE and the hard limit COARSE_CELL_LIMIT (issue 15): see hadal.landing.limits
ROUGHNESS_WINDOW_M = 0.3  # heights are averaged over this before R ([Landing Eq. 13]): 3 cells of the coarsest allowed grid

SITE_COLUMNS = [
    "heading_deg", "site_id", "row", "col", "x_m", "y_m", "radius_m", "area_m2", "slope_deg",
    "elevation_m", "roughness_m", "rect_area_m2", "rect_area_ratio", "p_s", "p_f", "p_r", "c_s",
]

SITE_FIELDS: dict[str, dict[str, str]] = {
    "p_landable": {"units": "1", "long_name": "probability that slope and protrusion tests hold under the per-cell "
                                              "elevation uncertainty (NaN without uncertainty layers)"},
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
    "roughness_m": {"units": "m", "long_name": "R, mean |h - mean h| over the footprint of h averaged over the local-slope window (Eq. 13)"},
    "rect_area_m2": {"units": "m2", "long_name": "A_r, largest inscribed rectangle of the vehicle aspect ratio "
                     "(exact below 5 A_f; at or above it a lower bound >= 5 A_f, where P_f = 0 anyway)"},
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
    # along-track frame: the arrays (x_m = across-track, y_m = along-track) are rotated by this compass angle;
    # world (x, y) = (y_f sin φ + x_f cos φ, y_f cos φ - x_f sin φ). Sites and headings are in world terms.
    frame_rotation_deg: float = 0.0
    # input grid (x, y) and, per input cell, the frame cell it falls in (rows, cols, inside) when rotated
    world_grid: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None
    warnings: list[str] = field(default_factory=list)  # e.g. cells coarser than the 1/10-width rule

    def to_world(self, xf: np.ndarray | float, yf: np.ndarray | float) -> tuple[np.ndarray, np.ndarray]:
        """World (x, y) (m) of frame coordinates (``x_m``/``y_m`` of the arrays)."""
        return _to_world(np.asarray(xf, float), np.asarray(yf, float), self.frame_rotation_deg)

    @property
    def critical_slope_deg(self) -> float:
        return self.vehicle.critical_slope_deg

    def to_dataset(self) -> xr.Dataset:
        """CF-style dataset of the maps (slope, protrusion height, exclusion per heading, final site), on the
        input grid (maps of an along-track frame are sampled back onto it, nearest frame cell)."""
        ds = self._frame_dataset()
        if self.world_grid is None:
            return ds
        xw, yw, fr, fc, inside = self.world_grid
        out = xr.Dataset(coords={"y": ("y", yw, ds["y"].attrs | {"long_name": "y (north) in the laser frame"}),
                                 "x": ("x", xw, ds["x"].attrs | {"long_name": "x (east) in the laser frame"}),
                                 "heading": ds["heading"]}, attrs=ds.attrs)
        out.attrs["frame_comment"] = (f"analysed in an along-track frame rotated by {self.frame_rotation_deg:.3f}° "
                                      "(compass); maps sampled back onto the input grid; site row/col index the frame")
        for name, da in ds.data_vars.items():
            a = da.values
            fill = np.nan if a.dtype.kind == "f" else 0
            b = np.full(a.shape[:-2] + inside.shape, fill, dtype=a.dtype)
            b[..., inside] = a[..., fr[inside], fc[inside]]
            out[name] = (da.dims, b, da.attrs)
        return out

    def _frame_dataset(self) -> xr.Dataset:
        y = xr.Variable("y", self.y_m, {"units": "m", "long_name": "y (north) in the laser frame", "axis": "Y"})
        x = xr.Variable("x", self.x_m, {"units": "m", "long_name": "x (east) in the laser frame", "axis": "X"})
        hd = xr.Variable("heading", self.headings_deg, {"units": "degree", "long_name": "landing heading, clockwise from +y"})
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
        best = self.best or {}
        ds.attrs.update({
            "critical_slope_deg": self.vehicle.critical_slope_deg,
            "critical_height_m": self.vehicle.critical_height_m,
            "roughness_max_m": self.r_max_m,
            "cell_size_m": self.cell_m,
            "vehicle": self.vehicle.model_dump(),
            "n_candidate_sites": int(len(self.sites)),
            "best_site": {k: (float(v) if isinstance(v, (int, float, np.floating, np.integer)) else v) for k, v in best.items()},
            "frame_rotation_deg": self.frame_rotation_deg,
            "frame_comment": ("x/y are across/along-track in a frame rotated by frame_rotation_deg (compass); world "
                              "x = y sin(φ) + x cos(φ), y = y cos(φ) - x sin(φ); sites are in world coordinates"
                              if self.frame_rotation_deg else "x/y are the input grid's coordinates"),
            "method": "Sangekar et al., Autonomous landing of underwater vehicles using high resolution bathymetry, §III-IV",
        })
        return ds


def roughness_max_m(vehicle: Vehicle, cell_m: float) -> float:
    """R_max ([Landing Eq. 14], Fig. 20): roughness ([Landing Eq. 13]) of the worst terrain that still leaves the footprint
    centre outside every C_G exclusion zone: at radial distance d ≤ b_u/2 the height limit h(d) of [Landing Eq. 8],
    beyond it h_c."""
    rr, cc = footprint_offsets(vehicle.length_m, vehicle.width_m, 0.0, cell_m)
    d = np.hypot(rr, cc) * cell_m
    h = np.where(d <= 0.5 * vehicle.width_m, vehicle.protrusion_height_limit_m(np.minimum(d, 0.5 * vehicle.width_m)),
                 vehicle.critical_height_m)
    return float(np.mean(np.abs(h - h.mean())))


def largest_aspect_rectangle_m2(mask: np.ndarray, cell_m: float, heading_deg: float, length_m: float,
                                width_m: float, resolution_m: float | None = None,
                                max_scale: float | None = None, clearance2: np.ndarray | None = None,
                                label: int | None = None) -> float:
    """A_r ``[Landing Eq. 12]``: area (m²) of the largest rectangle with the vehicle's aspect ratio, long side
    along ``heading_deg``, inscribed in boolean ``mask`` (rows = y, cols = x, cell ``cell_m``), exact on the grid.

    The rectangle is centred on a cell of the site, like the vehicle's C_G, and may not contain the centre of
    any cell outside the site (the convention of the footprint erosion, Fig. 13b). For a centre p the largest
    scale is s(p) = min over outside cells q of the rectangle norm max(|Δs|/(l/2), |Δt|/(w/2)) of q - p
    (Δs along the heading, Δt across), i.e. the Chebyshev (L∞) distance in the rotated frame scaled by the
    half sides, found for every p at once with a k-d tree; only the outside cells 8-adjacent to the site can
    be nearest (the cell centres inside a convex rectangle wider than a cell are 8-connected). A_r =
    max_p s(p)² l w. The result depends only on the site's cells, not on the crop or the grid origin; tests
    check it against a brute-force erosion with the rotated footprint. ``max_scale``: stop as soon as a
    rectangle of that scale (side / vehicle side) is found and return its area, a lower bound (the site uses
    √5: P_f of [Landing Eq. 12] is 0 for every A_r ≥ 5 A_f). ``resolution_m`` is ignored (kept for old callers).

    ``clearance2`` (optional, same shape as ``mask``): for every site cell, the squared distance (cells²) to
    some cell outside the site (e.g. the squared EDT of the landable cells). Then s(p) ≤ √clearance2 / (w/2)
    (the rectangle norm is at most the Euclidean length over the shorter half side), and the k-d tree is only
    queried where that bound can still reach the best value found: the same maxima, hence the same result
    (tests compare), without querying every lattice point of a large site.

    ``label``: ``mask`` is a label array and the site is ``mask == label`` (with ``clearance2``, no mask of the
    site is built: two passes over the site's bounding box fewer)."""
    from scipy.spatial import cKDTree

    if label is not None and clearance2 is None:
        mask, label = np.asarray(mask) == label, None
    if label is None:
        m = np.ascontiguousarray(mask, dtype=bool)
        br, bc, n_site = outer_border(m)  # compiled: the outside cells 8-adjacent to the site, one pass
    else:
        m = np.asarray(mask)  # a view of the labels (no copy: the kernels take strided arrays)
        br, bc, n_site = outer_border_of(m, m.dtype.type(label))
    if n_site == 0:
        return 0.0
    a = math.radians(heading_deg)
    sa, ca = math.sin(a), math.cos(a)
    hl, hw = 0.5 * length_m / cell_m, 0.5 * width_m / cell_m

    def frame(rows: np.ndarray, cols: np.ndarray) -> np.ndarray:
        r, c = rows.astype(float), cols.astype(float)
        return np.column_stack([(c * sa + r * ca) / hl, (c * ca - r * sa) / hw])

    # unbalanced, uncompacted: ~2x faster to build and query here; the nearest distance does not depend on it
    tree = cKDTree(frame(br, bc), balanced_tree=False, compact_nodes=False)
    if clearance2 is not None:
        return _rect_scale_pruned(m, label, np.asarray(clearance2), n_site, tree, frame, min(hl, hw), max_scale,
                                  length_m * width_m)
    pr = pc = None  # the site's cells, only listed when the coarse lattice does not settle A_r
    best0 = 0.0
    for k in (16, 4):  # coarse lattices first: a lower bound, and an early exit for very large sites
        if n_site <= 4 * k * k:
            continue
        # s is 1-Lipschitz in the rectangle norm, so s at the lattice point (r - r % k, c - c % k) plus the
        # largest norm of an offset inside a k x k block bounds s(p) from above; exact s only where that bound
        # reaches the best lattice value (lattice points inside the site are candidates themselves)
        lr, lc = np.mgrid[0 : m.shape[0] : k, 0 : m.shape[1] : k]
        d_lat, _ = tree.query(frame(lr.ravel(), lc.ravel()), k=1, p=np.inf)
        d_lat = d_lat.reshape(lr.shape)
        best0 = max(best0, float(np.max(d_lat[m[::k, ::k]], initial=0.0)))
        if max_scale is not None and best0 >= max_scale:
            return float(best0 * best0 * length_m * width_m)
        oy, ox = np.mgrid[0:k, 0:k]
        slack = float(np.max(np.maximum(np.abs(ox * sa + oy * ca) / hl, np.abs(ox * ca - oy * sa) / hw)))
        if pr is None:
            pr, pc = np.nonzero(m)
        sel = d_lat[pr // k, pc // k] + slack >= best0 - 1e-12
        pr, pc = pr[sel], pc[sel]
    if pr is None:
        pr, pc = np.nonzero(m)
    d, _ = tree.query(frame(pr, pc), k=1, p=np.inf) if pr.size else (np.zeros(1), None)
    best = max(best0, float(np.max(d)))
    return float(best * best * length_m * width_m)


def _rect_scale_pruned(m: np.ndarray, label: int | None, c2: np.ndarray, n_site: int, tree, frame, h_min: float,
                       max_scale: float | None, area: float) -> float:
    """:func:`largest_aspect_rectangle_m2` with the clearance bound: the maximum of s over the same point sets
    (the k = 16 and k = 4 lattices inside the site for the early exits, then every site cell), each found by
    querying the points in decreasing order of their bound until the bound falls below the best value.
    ``m``: the site's bool mask, or (``label`` given) a label array holding the site as ``m == label``."""

    def max_s(rows: np.ndarray, cols: np.ndarray, best: float) -> float:
        ub = np.sqrt(c2[rows, cols].astype(float)) / h_min * (1.0 + 1e-9) + 1e-9
        keep = ub >= best
        rows, cols, ub = rows[keep], cols[keep], ub[keep]
        order = np.argsort(-ub, kind="stable")
        i, chunk = 0, 256
        while i < order.size and ub[order[i]] >= best:
            sel = order[i : i + chunk]
            d, _ = tree.query(frame(rows[sel], cols[sel]), k=1, p=np.inf)
            best = max(best, float(np.max(d)))
            i += sel.size
            chunk *= 2
        return best

    best0 = 0.0
    for k in (16, 4):
        if n_site <= 4 * k * k:
            continue
        sub = m[::k, ::k]
        lr, lc = np.nonzero(sub if label is None else sub == label)
        best0 = max_s(lr * k, lc * k, best0)
        if max_scale is not None and best0 >= max_scale:
            return float(best0 * best0 * area)
    thr = (max(best0 - 2e-9, 0.0) * h_min) ** 2 * (1.0 - 1e-9)  # cells whose bound can reach best0
    if label is None:
        pr, pc = np.nonzero(m & (c2 >= thr))
    else:
        pr, pc = site_cells_at_least(m, m.dtype.type(label), c2, c2.dtype.type(thr) if thr < 3e38 else np.inf)
    best = max_s(pr, pc, best0) if pr.size else best0
    if best == 0.0 and not pr.size:  # pragma: no cover - an empty site returned 0 above
        return 0.0
    return float(best * best * area)


@dataclass
class _Ctx:
    z: np.ndarray
    h: np.ndarray  # heights used for the roughness R (averaged over the local-slope window)
    cell_m: float
    vehicle: Vehicle
    corr: HeadingCorrelator
    static_excl: np.ndarray  # uint8 SMALL_PROTRUSION bits
    min_radius_px: float
    rect_res_m: float
    r_max_m: float
    x0: float
    y0: float


def _heading_exclusion(ctx: _Ctx, hm: HeadingMaps, ok: np.ndarray | None = None
                       ) -> tuple[np.ndarray, np.ndarray, tuple[int, int, int, int]]:
    """Bit flags of one heading, the bool map of the cells where C_G may land (into ``ok`` when given) and their
    bounding box (r0, r1, c0, c1; r0 = -1 when none), one compiled pass."""
    tan_c = np.float32(math.tan(math.radians(ctx.vehicle.critical_slope_deg)))
    ok = np.empty(hm.unmapped.shape, bool) if ok is None else ok
    ex, r0, r1, c0, c1 = combine_exclusion(ctx.static_excl, hm.unmapped, hm.high, hm.tan_slope, tan_c,
                                           UNMAPPED, SLOPE, HIGH_PROTRUSION, ok)
    return ex, ok, (r0, r1, c0, c1)


class _Workspace:
    """Buffers of one thread's heading loop, reused from heading to heading: the slope tangents, the labels
    and the squared EDT of a 10 M-cell strip are 40 MB each, and a fresh array of that size is mapped and
    page-faulted anew every time (~1.5 s of the strip's 37 headings). Results that outlive the heading
    (the kept best heading) are copied by the caller."""

    def __init__(self, shape: tuple[int, int]):
        self.shape = shape
        self._buf: dict[str, np.ndarray] = {}

    def get(self, name: str, shape: tuple[int, int], dtype) -> np.ndarray:
        n = int(shape[0]) * int(shape[1])
        buf = self._buf.get(name)
        if buf is None or buf.dtype != np.dtype(dtype) or buf.size < n:
            buf = self._buf[name] = np.empty(int(self.shape[0]) * int(self.shape[1]), dtype)
        return buf[:n].reshape(shape)


def _analyse_heading(ctx: _Ctx, heading: float, want_labels: bool = False, keep: bool = False,
                     ws: _Workspace | None = None):
    """Exclusion flags and site rows of one heading; ``want_labels``: also the heading maps and the full-grid
    labels; ``keep``: also (heading maps, labels of the landable box, box) so the caller can keep the
    heading that holds the best site instead of recomputing it (with ``ws`` they share its buffers: copy
    what is kept). ``ws``: reused buffers (one workspace per thread)."""
    hm = ctx.corr.compute(heading, need_slope=True if want_labels else None,
                          out=None if ws is None else ws.get("tan", ctx.z.shape, np.float32))
    ex, ok_all, (r0, r1, c0, c1) = _heading_exclusion(
        ctx, hm, None if ws is None else ws.get("ok", ctx.z.shape, np.bool_))
    rows: list[dict[str, Any]] = []
    labels = None
    kept = None
    if r0 >= 0:
        ok = ok_all[r0:r1, c0:c1]  # labels, EDT and site statistics only inside the landable bounding box
        eight = np.ones((3, 3), bool)
        if ws is None:
            lab, n = ndi.label(ok, structure=eight)
        else:
            lab = ws.get("lab", ok.shape, np.int32)
            n = ndi.label(ok, structure=eight, output=lab)
        if want_labels:
            labels = np.zeros(ex.shape, lab.dtype)
            labels[r0:r1, c0:c1] = lab
        if keep:
            kept = (hm, lab, (r0, r1, c0, c1))
        # exact squared EDT (numba, F&H; = scipy's distance_transform_edt of the padded box, tests compare);
        # squared distances are exact integers, so the cells sharing the largest circle are found exactly
        if ws is None:
            d2 = squared_edt(ok)
        else:
            d2 = ws.get("d2", ok.shape, np.float32)
            squared_edt_into(ok, d2)
        # per label: area, bounding box, the largest inscribed circle (only if >= the minimum radius), and among
        # the cells sharing it (e.g. along a corridor) the one nearest to their mean position — a deterministic
        # and central choice (ties: smallest row, then column)
        areas, bb_r0, bb_r1, bb_c0, bb_c1, dmax2, best_r, best_c = site_stats(
            lab, d2, n, ctx.min_radius_px ** 2 - 1e-9)
        cand = [(lid, int(best_r[lid]), int(best_c[lid]), math.sqrt(dmax2[lid]))
                for lid in np.nonzero(dmax2 >= 0)[0] if lid > 0]
        if cand:
            rr, cc = hm.offsets
            v = ctx.vehicle
            for lid, pr, pc, rad_px in cand:
                i, j = pr + r0, pc + c0
                hs = ctx.h[i + rr, j + cc]
                zs = ctx.z[i + rr, j + cc]
                hs = hs[np.isfinite(hs)]
                R = float(np.mean(np.abs(hs - hs.mean()))) if hs.size else float("nan")
                theta = hm.slope_at(i, j)
                box = lab[bb_r0[lid] : bb_r1[lid], bb_c0[lid] : bb_c1[lid]]
                rect = largest_aspect_rectangle_m2(
                    box, ctx.cell_m, heading, v.length_m, v.width_m, max_scale=math.sqrt(5.0),
                    clearance2=d2[bb_r0[lid] : bb_r1[lid], bb_c0[lid] : bb_c1[lid]], label=lid)
                ratio = rect / v.footprint_area_m2
                p_s = theta / v.critical_slope_deg  # [Landing Eq. 11]
                p_f = float(np.clip(0.25 * (5.0 - ratio), 0.0, 1.0))  # [Landing Eq. 12]
                p_r = R / ctx.r_max_m  # [Landing Eq. 14]
                rows.append({
                    "heading_deg": float(heading), "site_id": lid, "row": int(i), "col": int(j),
                    "x_m": ctx.x0 + j * ctx.cell_m, "y_m": ctx.y0 + i * ctx.cell_m,  # frame; world later
                    "radius_m": rad_px * ctx.cell_m, "area_m2": float(areas[lid]) * ctx.cell_m**2,
                    "slope_deg": theta, "elevation_m": float(np.nanmean(zs)), "roughness_m": R,
                    "rect_area_m2": rect, "rect_area_ratio": ratio,
                    "p_s": p_s, "p_f": p_f, "p_r": p_r, "c_s": (p_s + p_f + p_r) / 3.0,  # [Landing Eq. 15]
                })
    if want_labels:
        return ex, rows, hm, labels
    if keep:
        return ex, rows, kept
    return ex, rows


def _best_score(rows: list[dict[str, Any]]) -> tuple[float, float] | None:
    """The best-site order of :func:`analyse_submap` (smallest C_s, then largest radius) over the rows with
    finite costs: the key of a heading's best row, None when it has none."""
    keys = [(r["c_s"], -r["radius_m"]) for r in rows
            if all(math.isfinite(r[c]) for c in ("p_s", "p_f", "p_r", "c_s"))]
    return min(keys) if keys else None


def fill_small_holes(z: np.ndarray, cell_m: float, max_area_m2: float) -> tuple[np.ndarray, np.ndarray]:
    """Fill interior unmapped holes of at most ``max_area_m2`` (not connected to the map's outer boundary)
    with the nearest mapped elevation. Returns (filled z, bool mask of filled cells).

    The paper's exclusion uses "the mapped area and its unmapped boundary" (Fig. 13a); a resampled laser
    grid also has isolated empty cells where the point density dips, and one such cell under the footprint
    would wrongly forbid landing. Larger holes stay unmapped (the vehicle may not land over them)."""
    mapped = np.isfinite(z)
    if max_area_m2 <= 0 or mapped.all():
        return z, np.zeros(z.shape, bool)
    # holes = 4-connected unmapped components not touching the grid edge (what binary_fill_holes finds), by one
    # labelling pass instead of binary_fill_holes' iterative propagation (slow on large oblique bounding grids)
    lab, n = ndi.label(~mapped)
    edge = np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]]))
    size = np.bincount(lab.ravel(), minlength=n + 1)
    small = (size <= max_area_m2 / cell_m**2) & (np.arange(n + 1) > 0)
    small[edge] = False
    if not small.any():
        return z, np.zeros(z.shape, bool)
    fill = small[lab]
    if not fill.any():
        return z, fill
    idx = ndi.distance_transform_edt(~mapped, return_distances=False, return_indices=True)
    out = z.copy()
    out[fill] = z[idx[0][fill], idx[1][fill]]
    return out, fill


_DEPTH_NAMES = ("depth", "sea_floor_depth", "sea_floor_depth_below_sea_surface", "depth_m", "bathymetry_depth")


def _grid_arrays(grid: xr.DataArray, vehicle: Vehicle, max_cell_fraction: float
                 ) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Elevation (m, positive up), x, y (ascending) and the cell size, with plausibility checks: units,
    regular square cells no larger than ``max_cell_fraction`` of the vehicle width, the sign of depth grids."""
    if not isinstance(grid, xr.DataArray):
        raise InputError(f"landing analysis needs an xarray.DataArray elevation grid, got {type(grid).__name__}")
    if set(grid.dims) != {"y", "x"}:
        raise InputError(f"elevation grid must have dims ('y', 'x'), got {grid.dims}")
    units = str(grid.attrs.get("units", "m")).strip().lower()
    if units not in ("m", "meter", "meters", "metre", "metres"):
        raise InputError(f"elevation grid {grid.name!r} has units {units!r}; expected metres")
    g = grid.transpose("y", "x")
    for ax in ("y", "x"):  # sortby copies the grid (0.4 s on a 10 M-cell strip): only when not already ascending
        c = np.asarray(g[ax].values)
        if c.size > 1 and not (c.dtype.kind in "fiu" and np.all(c[1:] > c[:-1])):
            g = g.sortby(ax)
    x = np.asarray(g["x"].values, float)
    y = np.asarray(g["y"].values, float)
    if x.size < MIN_GRID_CELLS or y.size < MIN_GRID_CELLS:
        raise InputError(f"elevation grid is too small ({y.size} x {x.size} cells; at least {MIN_GRID_CELLS} along "
                         "each axis)")
    if not (np.all(np.isfinite(x)) and np.all(np.isfinite(y))):
        raise InputError("elevation grid has non-finite x/y coordinates")
    for ax in ("x", "y"):
        u = str(g[ax].attrs.get("units", "m")).strip().lower()
        if u not in ("m", "meter", "meters", "metre", "metres"):
            raise InputError(f"elevation grid coordinate {ax!r} has units {u!r}; the landing analysis needs metres")
    dx, dy = np.diff(x), np.diff(y)
    cell = float(np.median(dx))
    if cell <= 0 or np.max(np.abs(dx - cell)) > 1e-3 * cell or np.max(np.abs(dy - cell)) > 1e-3 * cell:
        raise InputError("elevation grid must be regular with equal x and y spacing (metres)")
    max_cell = max_cell_fraction * vehicle.width_m
    if cell > max_cell * (1 + 1e-6):
        hint = ("; x/y in mm labelled m?" if cell > COARSE_CELL_LIMIT * vehicle.width_m else
                f" (a coarser grid up to {COARSE_CELL_LIMIT:g} × width runs only with max_cell_fraction raised, "
                "reported as a warning)")
        raise InputError(f"grid cells of {cell:g} m are too coarse for a {vehicle.width_m:g} m wide vehicle "
                         f"(at most {max_cell:g} m = {max_cell_fraction:g} × width){hint}")
    z = np.array(g.values, dtype=float)  # the analysis' own copy
    np.copyto(z, np.nan, where=np.isinf(z))  # ±inf = unmapped
    with warnings.catch_warnings():  # all-NaN: reported below
        warnings.simplefilter("ignore", RuntimeWarning)
        lo, hi = float(np.nanmin(z)), float(np.nanmax(z))  # one pass each (fmin/fmax reductions, no copy)
    if not math.isfinite(lo):
        raise InputError("elevation grid has no mapped (finite) cells")
    positive = str(grid.attrs.get("positive", "")).strip().lower()
    names = {str(grid.name or "").lower(), str(grid.attrs.get("standard_name", "")).lower()}
    if positive not in ("", "up", "down"):
        raise InputError(f"elevation grid has positive={positive!r}; expected 'up' or 'down'")
    if not positive:
        if names & set(_DEPTH_NAMES) or "depth" in str(grid.attrs.get("long_name", "")).lower():
            positive = "down"  # a depth variable without the attribute: depths are positive down
        elif lo > 50.0:
            raise InputError(f"elevation grid {grid.name!r} is all > 50 m (min {lo:.1f}) and has no "
                             "'positive' attribute: depths? set positive='down' (or 'up')")
    if positive == "down":
        np.negative(z, out=z)
    if max(abs(lo), abs(hi)) > 12_000.0:
        raise InputError(f"elevation grid {grid.name!r} reaches {max(abs(lo), abs(hi)):.0f} m: deeper than any "
                         "ocean (values in mm labelled m?)")
    return z, x, y, cell


def _options(**kw) -> AnalysisOptions:
    try:
        return AnalysisOptions(**kw)
    except ValidationError as exc:
        loc, msg, _ = first_validation_error(exc)
        raise ConfigError(f"landing option {loc}={exc.errors()[0].get('input')!r}: {msg}") from None


def _workers(workers: Any) -> int:
    """The heading-thread count, 1-64 (a one-line ConfigError otherwise)."""
    if isinstance(workers, bool) or not isinstance(workers, int) or not 1 <= workers <= 64:
        raise ConfigError(f"landing option workers={workers!r}: headings analysed in parallel threads must be an "
                          "integer from 1 to 64")
    return workers


def _to_world(xf: np.ndarray, yf: np.ndarray, phi_deg: float) -> tuple[np.ndarray, np.ndarray]:
    a = math.radians(phi_deg)
    return yf * math.sin(a) + xf * math.cos(a), yf * math.cos(a) - xf * math.sin(a)


def along_track_frame(z: np.ndarray, x: np.ndarray, y: np.ndarray, cell: float, min_gain: float = 1.3,
                      min_cells: int = 250_000):
    """Re-grid an oblique strip in its along-track frame: rows along the principal axis of the mapped cells
    (compass angle φ), columns across, same cell size, each frame cell taking the nearest input cell (values
    are never interpolated, so rock tops keep their height). Returns (z_f, x_f, y_f, φ) or None when the
    frame would not shrink the grid by ``min_gain`` (an axis-aligned strip) or the grid has fewer than
    ``min_cells`` cells (then the cost is negligible and the input cells are kept as they are)."""
    if z.size < min_cells:
        return None
    mapped = np.isfinite(z)
    # quick decision on a regular sub-lattice of the cells (~250 k): an axis-aligned strip (the common case)
    # is recognised without listing every mapped cell; otherwise the axis is taken from all of them as before
    k = max(1, int(math.sqrt(z.size / 250_000)))
    if k > 1:
        rs, cs = np.nonzero(mapped[::k, ::k])
        if rs.size >= 10:
            ps = np.column_stack([x[cs * k], y[rs * k]])
            _, vs = np.linalg.eigh(np.cov((ps - ps.mean(axis=0)).T))
            phs = (math.degrees(math.atan2(vs[0, 1], vs[1, 1])) + 90.0) % 180.0 - 90.0
            if abs(phs) < 0.5 or abs(abs(phs) - 90.0) < 0.5:
                return None
    rows, cols = np.nonzero(mapped)
    if rows.size < 10:
        return None
    px, py = x[cols], y[rows]
    pts = np.column_stack([px - px.mean(), py - py.mean()])
    _, vecs = np.linalg.eigh(np.cov(pts.T))
    ax_ = vecs[:, 1]
    phi = math.degrees(math.atan2(ax_[0], ax_[1]))
    phi = (phi + 90.0) % 180.0 - 90.0
    if abs(phi) < 1.0 or abs(abs(phi) - 90.0) < 1.0:
        return None
    a = math.radians(phi)
    along = px * math.sin(a) + py * math.cos(a)
    across = px * math.cos(a) - py * math.sin(a)
    na = int(math.floor((along.max() - along.min()) / cell)) + 3
    nc = int(math.floor((across.max() - across.min()) / cell)) + 3
    if z.size < min_gain * na * nc:
        return None
    yf = along.min() - cell + cell * np.arange(na)
    xf = across.min() - cell + cell * np.arange(nc)
    xw, yw = _to_world(xf[None, :], yf[:, None], phi)
    ci = np.rint((xw - x[0]) / cell).astype(np.int64)
    ri = np.rint((yw - y[0]) / cell).astype(np.int64)
    ok = (ci >= 0) & (ci < x.size) & (ri >= 0) & (ri < y.size)
    zf = np.full((na, nc), np.nan)
    zf[ok] = z[ri[ok], ci[ok]]
    # inverse map: the frame cell of every input cell (for writing the maps back on the input grid)
    Xw, Yw = np.meshgrid(x, y)
    fa = np.rint((Xw * math.sin(a) + Yw * math.cos(a) - yf[0]) / cell).astype(np.int64)
    fcn = np.rint((Xw * math.cos(a) - Yw * math.sin(a) - xf[0]) / cell).astype(np.int64)
    inside = (fa >= 0) & (fa < na) & (fcn >= 0) & (fcn < nc)
    return zf, xf, yf, phi, (ri, ci, ok), (x, y, np.clip(fa, 0, na - 1), np.clip(fcn, 0, nc - 1), inside)


def _sigma_array(sig, grid: xr.DataArray, shape: tuple[int, int], default: float) -> np.ndarray | None:
    if sig is None:
        return None
    if not isinstance(sig, xr.DataArray) or set(sig.dims) != {"y", "x"}:
        raise InputError("elevation_sigma_m must be an xarray.DataArray on (y, x)")
    s = np.asarray(sig.transpose("y", "x").sortby("y").sortby("x").values, float)
    if s.shape != shape:
        raise InputError(f"elevation_sigma_m has shape {s.shape}, the grid {shape}")
    if np.any(s[np.isfinite(s)] < 0):
        raise InputError("elevation_sigma_m has negative values")
    return np.where(np.isfinite(s), s, default)


def landability_probability(z: np.ndarray, h: np.ndarray, sigma: np.ndarray, row: int, col: int,
                            heading_frame_deg: float, cell_m: float, vehicle: Vehicle) -> float:
    """Probability that a site passes the slope test ``[Landing Eq. 2]`` and the protrusion test
    ``[Landing Eq. 9]`` given independent Gaussian elevation errors of 1-σ ``sigma`` (m) per cell (analytic
    propagation): P = Φ((tan θc - g)/σ_g) · Π_k Φ((h_c - h_k)/σ_k) over the footprint cells, g the gradient of the
    least-squares plane over the footprint and σ_g its standard error (delta method through the weighted
    normal equations); the ground under h is a vehicle-scale average, so σ_h ≈ σ of the cell."""
    from scipy.special import log_ndtr

    rr, cc = footprint_offsets(vehicle.length_m, vehicle.width_m, heading_frame_deg, cell_m)
    i, j = row + rr, col + cc
    zz, hh, ss = z[i, j], h[i, j], sigma[i, j]
    ok = np.isfinite(zz) & np.isfinite(ss)
    if ok.sum() < 3:
        return float("nan")
    u, v = cc[ok] * cell_m, rr[ok] * cell_m
    u, v = u - u.mean(), v - v.mean()
    A = np.column_stack([u, v])
    M = A.T @ A
    coef = np.linalg.lstsq(np.column_stack([np.ones(u.size), u, v]), zz[ok], rcond=None)[0]
    g = np.array(coef[1:])
    Minv = np.linalg.inv(M)
    C = Minv @ ((A * (ss[ok] ** 2)[:, None]).T @ A) @ Minv
    gn = float(np.hypot(*g))
    var_g = float(g @ C @ g) / gn**2 if gn > 1e-9 else 0.5 * float(np.trace(C))
    sg = math.sqrt(max(var_g, 1e-30))
    logp = float(log_ndtr((math.tan(math.radians(vehicle.critical_slope_deg)) - gn) / sg))
    hv = ok & np.isfinite(hh)
    logp += float(np.sum(log_ndtr((vehicle.critical_height_m - hh[hv]) / np.maximum(ss[hv], 1e-9))))
    return float(math.exp(logp))


#: peak bytes per grid cell of :func:`analyse_submap` beyond the input (float64 maps: elevation, local slope,
#: protrusion height, roughness heights, small-protrusion radii; per heading the bool exclusion maps, the float32
#: footprint slope, the squared EDT, the labels; the tile spectra). Measured with ``bench/bench_landing.py --only
#: strip`` (10 M cells) and rounded up.
BYTES_PER_CELL = 120
#: bytes per entry of the Fig. 15 exclusion table (distance and height, float64)
TABLE_ENTRY_BYTES = 16
#: bytes per cell of each heading thread beyond the first (its workspace: float32 slope tangents, int32
#: labels, float32 squared EDT; the bool exclusion maps of the heading in flight), rounded up
THREAD_BYTES_PER_CELL = 24


def estimate_resources(shape: tuple[int, int], n_headings: int, *, keep_heading_exclusion: bool = True,
                       exclusion_step_m: float = 0.005, vehicle: Vehicle | None = None,
                       workers: int = 1) -> dict[str, float]:
    """Memory (bytes) and work (cell x heading evaluations) :func:`analyse_submap` will need for a grid of
    ``shape`` and ``n_headings`` headings, estimated before anything is allocated: ``BYTES_PER_CELL`` per cell,
    one byte per cell and heading for the kept exclusion maps, the Fig. 15 table of ``exclusion_step_m``,
    ``THREAD_BYTES_PER_CELL`` per cell for each heading thread beyond the first (``workers``)."""
    vehicle = vehicle or Vehicle()
    cells = float(shape[0]) * float(shape[1])
    n_table = math.floor(0.5 * vehicle.width_m / exclusion_step_m) + 2 if exclusion_step_m > 0 else math.inf
    parts = {
        "maps": cells * BYTES_PER_CELL,
        "heading_exclusion": cells * n_headings if keep_heading_exclusion else 0.0,
        "exclusion_table": n_table * TABLE_ENTRY_BYTES,
        "heading_threads": cells * THREAD_BYTES_PER_CELL * max(0, min(int(workers), n_headings) - 1),
    }
    return {"bytes": float(sum(parts.values())), "work": cells * n_headings, **parts}


def check_resources(shape: tuple[int, int], n_headings: int, *, memory_limit_bytes: float | None,
                    work_limit: float | None, keep_heading_exclusion: bool = True, exclusion_step_m: float = 0.005,
                    vehicle: Vehicle | None = None, what: str = "the landing analysis",
                    heading_setting: tuple[str, Any] | None = None,
                    step_setting: tuple[str, Any] | None = None, workers: int = 1) -> dict[str, float]:
    """Refuse (one-line :class:`ConfigError` with the estimate and the limit, :mod:`hadal.budget`) a grid /
    heading / table / thread configuration whose :func:`estimate_resources` exceeds the memory or work budget."""
    from hadal.budget import check_memory, check_work

    est = estimate_resources(shape, n_headings, keep_heading_exclusion=keep_heading_exclusion,
                             exclusion_step_m=exclusion_step_m, vehicle=vehicle, workers=workers)
    cells = f"{shape[0]:,} x {shape[1]:,} cells"
    hs, hv = heading_setting or ("headings_deg", f"{n_headings} headings")
    if memory_limit_bytes is not None:
        if est["exclusion_table"] >= max(est["maps"], est["heading_exclusion"]):
            ss, sv = step_setting or ("exclusion_step_m", exclusion_step_m)
            check_memory(f"the Fig. 15 exclusion table of {what}", est["bytes"], memory_limit_bytes, setting=ss,
                         value=sv)
        else:
            check_memory(f"{what} ({cells}, {n_headings} headings)", est["bytes"], memory_limit_bytes, setting=hs,
                         value=hv, advice=f"use a larger {hs}, a coarser or smaller grid, or raise "
                                          "resources.max_memory_gb")
    if work_limit is not None:
        check_work(f"{what} ({cells} x {n_headings} headings)", est["work"], work_limit, setting=hs, value=hv,
                   advice=f"use a larger {hs}, a coarser or smaller grid, or raise the work limit")
    return est


def slope_window_px(window_m: float, cell_m: float) -> int:
    """Odd window (cells) of the local slope plane fit closest to ``window_m``, at least 3 cells."""
    return max(3, 2 * int(math.floor(0.5 * window_m / cell_m + 1e-9)) + 1)


def analyse_submap(
    grid: xr.DataArray,
    vehicle: Vehicle | None = None,
    *,
    headings_deg: np.ndarray | list[float] | None = None,
    frame: str = "auto",
    elevation_sigma_m: xr.DataArray | None = None,
    keep_heading_exclusion: bool = True,
    memory_limit_bytes: float | None = None,
    work_limit: float | None = None,
    options: AnalysisOptions | None = None,
    workers: int = 1,
    **option_values: Any,
) -> LandingResult:
    """Landing-site analysis of one bathymetry submap (Sangekar et al. §III-IV).

    ``grid``: elevation (m, positive up; ``attrs['positive'] == 'down'`` is negated; a depth-named variable
    without the attribute is read as depth, an all-positive one refused) on ``y``, ``x`` metric coordinates
    (regular, equal spacing no larger than ``max_cell_fraction`` × vehicle width, NaN = unmapped). The rule is
    1/10 of the width (:data:`CELL_FRACTION_RULE`); ``max_cell_fraction`` up to 0.2 is an explicit override for
    coarser grids (the 0.10 m Takuyo raster) and adds a warning to ``LandingResult.warnings``.
    The analysis options are :class:`AnalysisOptions` (their defaults are declared there only): pass ``options``
    or its fields as keywords (``option_values``; both together: the keywords override ``options``).
    ``headings_deg``: landing headings (default -90° .. 90° in 5° steps). ``local_slope_window_m``: physical
    size of the local-slope plane fit (rounded to an odd number of cells, at least 3). ``protrusion_method``:
    ``"opening"`` (heights that see every rock narrower than the vehicle diagonal, see
    :mod:`hadal.landing.protrusion`) or the paper's ``"butterworth"`` ``[Landing Eq. 10]``.
    ``frame``: ``"auto"`` grids an oblique strip in its own along-track frame (:func:`along_track_frame`, nearest
    cell, same cell size) so the cost follows the mapped area; ``"grid"`` keeps the input grid.
    ``elevation_sigma_m``: per-cell 1-σ uncertainty of the elevation (m) on the grid's coordinates (e.g. the
    laser grid's ``elevation_std_m / sqrt(count)``; NaN -> ``default_sigma_m``): each site then gets
    ``p_landable``, the probability that its slope and protrusion tests hold (:func:`landability_probability`).
    ``workers``: headings analysed in parallel threads (1-64).
    ``memory_limit_bytes`` / ``work_limit``: refuse before allocating when :func:`estimate_resources` exceeds
    them (one-line ConfigError with the estimate and the limit). ``tile_cells``: size of the row tiles of the
    footprint-slope FFTs (:class:`HeadingCorrelator`; long strips are never transformed whole).
    Raises :class:`hadal.errors.InputError` on unusable grids, :class:`hadal.errors.ConfigError` on options
    out of bounds.
    """
    vehicle = vehicle if isinstance(vehicle, Vehicle) else Vehicle(**vehicle.model_dump()) if vehicle else Vehicle()
    opt = _options(**{**(options.model_dump() if options is not None else {}), **option_values})
    workers = _workers(workers)
    t_all = time.perf_counter()
    timings: dict[str, float] = {}
    inp = _prepare_input(grid, vehicle, opt, headings_deg, frame, elevation_sigma_m, keep_heading_exclusion,
                         memory_limit_bytes, work_limit, workers)
    maps = _terrain_maps(inp.z, inp.cell, vehicle, opt, timings)

    t = time.perf_counter()
    ctx = _heading_context(inp, vehicle, opt, maps)
    timings["prepare_headings"] = time.perf_counter() - t

    t = time.perf_counter()
    results, first, cached = _run_headings(ctx, inp.heads, inp.phi, workers, keep_heading_exclusion)
    timings["headings"] = time.perf_counter() - t

    t = time.perf_counter()
    exclusion = (np.stack([r[0] for r in results]) if keep_heading_exclusion
                 else np.zeros((0,) + inp.z.shape, np.uint8))
    sites = _site_table(results, inp.phi)
    del results
    if len(sites) and inp.sigma is not None:
        sites["p_landable"] = [
            landability_probability(inp.z, maps.h, inp.sigma, int(r.row), int(r.col), float(r.heading_deg) - inp.phi,
                                    inp.cell, vehicle)
            for r in sites.itertuples()]
    best, best_mask, fp_slope = _select_best(ctx, sites, inp.heads, inp.phi, first, cached)
    timings["selection"] = time.perf_counter() - t
    timings["total"] = time.perf_counter() - t_all
    return LandingResult(
        x_m=inp.x, y_m=inp.y, cell_m=inp.cell, vehicle=vehicle, headings_deg=inp.heads, elevation_m=inp.z,
        slope_local_deg=maps.slope_local, protrusion_height_m=maps.h, protrusion_candidate=maps.candidate,
        small_exclusion=maps.small_excl, high_protrusion=maps.high, exclusion=exclusion, sites=sites, best=best,
        footprint_slope_deg=fp_slope, best_site_mask=best_mask, r_max_m=ctx.r_max_m, timings_s=timings,
        filled=inp.filled, frame_rotation_deg=inp.phi, world_grid=inp.world, warnings=inp.warnings,
    )


@dataclass
class _Input:
    """The analysed grid of :func:`analyse_submap`: elevation (m, up; in the along-track frame when rotated by
    ``phi``), its coordinates, cell, per-cell σ, filled holes, the world grid, the headings and the warnings."""

    z: np.ndarray
    x: np.ndarray
    y: np.ndarray
    cell: float
    sigma: np.ndarray | None
    filled: np.ndarray | None
    phi: float
    world: Any
    heads: np.ndarray
    warnings: list[str]


def _prepare_input(grid: xr.DataArray, vehicle: Vehicle, opt: AnalysisOptions, headings_deg, frame: str,
                   elevation_sigma_m: xr.DataArray | None, keep_heading_exclusion: bool,
                   memory_limit_bytes: float | None, work_limit: float | None, workers: int) -> _Input:
    """Checked grid arrays, resource limits, σ, filled holes and the along-track frame of :func:`analyse_submap`
    (in that order, so the first problem found is the one reported)."""
    z, x, y, cell = _grid_arrays(grid, vehicle, opt.max_cell_fraction)
    warn: list[str] = []
    if cell > CELL_FRACTION_RULE * vehicle.width_m * (1 + 1e-6):
        warn.append(f"grid cells of {cell:g} m are coarser than the rule of 1/10 of the vehicle width "
                    f"({CELL_FRACTION_RULE * vehicle.width_m:g} m), analysed only because max_cell_fraction = "
                    f"{opt.max_cell_fraction:g}: exclusion discs and the footprint edge are resolved by few cells")
    n_heads = 37 if headings_deg is None else int(np.size(headings_deg))
    if memory_limit_bytes is not None or work_limit is not None:
        check_resources(z.shape, n_heads, memory_limit_bytes=memory_limit_bytes, work_limit=work_limit,
                        keep_heading_exclusion=keep_heading_exclusion, exclusion_step_m=opt.exclusion_step_m,
                        vehicle=vehicle, workers=workers)
    sigma = _sigma_array(elevation_sigma_m, grid, z.shape, opt.default_sigma_m)
    z, filled = fill_small_holes(z, cell, opt.fill_holes_max_m2)
    phi = 0.0
    world = None
    if frame == "auto":
        fr = along_track_frame(z, x, y, cell)
        if fr is not None:
            z, x, y, phi, filled = fr[0], fr[1], fr[2], fr[3], None
            world = fr[5]
            if sigma is not None:
                ri, ci, okf = fr[4]
                sf = np.full(z.shape, np.nan)
                sf[okf] = sigma[ri[okf], ci[okf]]
                sigma = sf
    elif frame != "grid":
        raise ConfigError(f"landing option frame={frame!r}: expected 'auto' or 'grid'")
    heads = default_headings_deg() if headings_deg is None else np.asarray(headings_deg, float)
    if heads.ndim != 1 or heads.size == 0 or not np.all(np.isfinite(heads)):
        raise InputError("landing headings must be a non-empty list of finite angles")
    if opt.min_protrusion_height_m >= vehicle.critical_height_m:
        raise ConfigError(f"min_protrusion_height_m {opt.min_protrusion_height_m} m must be below h_c "
                          f"{vehicle.critical_height_m:.3f} m")
    return _Input(z, x, y, cell, sigma, filled, phi, world, heads, warn)


@dataclass
class _TerrainMaps:
    """The heading-independent maps of :func:`analyse_submap` (Figs. 16-18)."""

    slope_local: np.ndarray
    h: np.ndarray
    high: np.ndarray
    candidate: np.ndarray
    small_excl: np.ndarray
    static: np.ndarray  # uint8 SMALL_PROTRUSION bits


def _terrain_maps(z: np.ndarray, cell: float, vehicle: Vehicle, opt: AnalysisOptions,
                  timings: dict[str, float]) -> _TerrainMaps:
    """Local slope (checked for plausibility), protrusion heights, high protrusions and the small-protrusion
    exclusion; their times into ``timings``."""
    t = time.perf_counter()
    win = slope_window_px(opt.local_slope_window_m, cell)
    slope_local = local_slope_deg(z, cell, win)
    med = float(np.nanmedian(slope_local)) if np.isfinite(slope_local).any() else 0.0
    if med > 60.0:
        raise InputError(f"median local slope {med:.0f}° is implausible for a seafloor: elevations in mm "
                         "labelled m (or x/y in a larger unit)?")
    timings["slope_map"] = time.perf_counter() - t

    t = time.perf_counter()
    h = protrusion_height_map(z, cell, vehicle.diagonal_m, method=opt.protrusion_method, block_m=opt.block_m,
                              margin_m=opt.block_margin_m, order=opt.filter_order, edge_correction=opt.edge_correction,
                              coarse_m=opt.protrusion_coarse_m)
    timings["protrusion_map"] = time.perf_counter() - t

    t = time.perf_counter()
    with np.errstate(invalid="ignore"):
        # [Landing Eq. 9]: nothing higher than h_c may touch the vehicle — every mapped cell counts (flat rock tops too)
        high = np.isfinite(h) & (h > vehicle.critical_height_m)  # Fig. 18d
        # [Landing Eq. 8] discs for the lower protrusion points: steep cells (Fig. 16b) at least min height high
        small = (slope_local > vehicle.critical_slope_deg) & (h >= opt.min_protrusion_height_m) & ~high
        candidate = small | high
    radius = np.full(z.shape, np.nan, np.float32)  # (float32: 4 bytes per cell on long strips)
    radius[small] = vehicle.exclusion_distance_m(h[small], opt.exclusion_step_m) / cell  # Fig. 15
    small_excl = small_protrusion_exclusion(radius)  # Fig. 18c
    static = np.where(small_excl, SMALL_PROTRUSION, np.uint8(0)).astype(np.uint8)
    timings["small_protrusion_exclusion"] = time.perf_counter() - t
    return _TerrainMaps(slope_local, h, high, candidate, small_excl, static)


def _heading_context(inp: _Input, vehicle: Vehicle, opt: AnalysisOptions, maps: _TerrainMaps) -> _Ctx:
    """The footprint correlator, R_max and the roughness heights shared by every heading."""
    z, cell, h = inp.z, inp.cell, maps.h
    corr = HeadingCorrelator(z, cell, vehicle, maps.high, static_excluded=maps.small_excl, tile_cells=opt.tile_cells)
    r_max = roughness_max_m(vehicle, cell)
    # R [Landing Eq. 13] from heights averaged over the local-slope window: white sensor noise below that
    # scale is not roughness the vehicle feels (it raised C_s by ~30 % at 6 mm on the Takuyo raster)
    hv = np.isfinite(h)
    with np.errstate(invalid="ignore", divide="ignore"):
        rw = slope_window_px(ROUGHNESS_WINDOW_M, cell)
        # float32, in place (a 10 M-cell strip would otherwise hold six float64 temporaries here)
        h_rough = ndi.uniform_filter(np.where(hv, h, 0.0).astype(np.float32), rw, mode="constant")
        h_rough /= ndi.uniform_filter(hv.astype(np.float32), rw, mode="constant")
        h_rough[~hv] = np.nan
    return _Ctx(z, h_rough, cell, vehicle, corr, maps.static, opt.min_site_radius_m / cell, 0.0, r_max,
                float(inp.x[0]), float(inp.y[0]))


def _heading_key(heading_deg: float, phi: float) -> float:
    """The frame heading modulo 180° (α and α ± 180° give the same footprint), rounded: one analysis per key."""
    return round((float(heading_deg) - phi) % 180.0, 9)


def _run_headings(ctx: _Ctx, heads: np.ndarray, phi: float, workers: int, keep_heading_exclusion: bool):
    """Analyse every distinct heading once (``workers`` threads, one :class:`_Workspace` each). Returns the
    per-heading (flags or None, site rows with world headings) in ``heads`` order, the frame heading of each key
    and the cache [(key, rank, kept maps)] of the heading holding the best site."""
    # α and α ± 180° give the same footprint (the paper's reason for -90..90): analyse each once
    keys = [_heading_key(a, phi) for a in heads]
    uniq = list(dict.fromkeys(keys))
    first = {k: float(heads[keys.index(k)]) - phi for k in uniq}  # frame headings
    order_of = {k: n for n, k in enumerate(uniq)}
    # the maps of the heading holding the best site so far are kept (copied out of the thread's workspace),
    # so the best site's footprint slope and mask need no recomputation; (best-site order, heading order)
    # decides, ties to the earlier heading, as the final selection
    best_lock = threading.Lock()
    cached: list[Any] = []  # [(key, (score, order), kept maps)] of the heading holding the best site
    spaces: queue.SimpleQueue[_Workspace] = queue.SimpleQueue()
    n_threads = max(1, min(workers, len(uniq)))
    for _ in range(n_threads):
        spaces.put(_Workspace(ctx.z.shape))

    def one(k: float):
        ws = spaces.get()
        try:
            ex_k, rows_k, kept = _analyse_heading(ctx, first[k], keep=True, ws=ws)
            score = _best_score(rows_k)
            if score is not None:
                rank = (score, order_of[k])
                with best_lock:
                    if not cached or rank < cached[0][1]:
                        hm_k, lab_k, box_k = kept  # they share the workspace's buffers: copy what is kept
                        cached[:] = [(k, rank, (dataclasses.replace(hm_k, tan_slope=hm_k.tan_slope.copy()),
                                                lab_k.copy(), box_k))]
            # the per-heading flags are only kept when asked for (10 MB per heading on a 10 M-cell strip)
            return (ex_k if keep_heading_exclusion else None), rows_k
        finally:
            spaces.put(ws)

    if n_threads > 1:
        with ThreadPoolExecutor(max_workers=n_threads) as pool:
            res_u = dict(zip(uniq, pool.map(one, uniq), strict=True))
    else:
        res_u = {k: one(k) for k in uniq}
    while not spaces.empty():  # free the workspaces' buffers before the selection
        spaces.get()
    results = []
    for a, k in zip(heads, keys, strict=False):
        ex, rows = res_u[k]
        results.append((ex, [{**r, "heading_deg": float(a)} for r in rows]))
    return results, first, cached


def _site_table(results: list, phi: float) -> pd.DataFrame:
    """The candidate sites of all headings (x/y in world terms), without those of a non-finite cost."""
    rows = [row for r in results for row in r[1]]
    sites = pd.DataFrame(rows, columns=SITE_COLUMNS)
    if phi and len(sites):
        xw, yw = _to_world(sites["x_m"].to_numpy(float), sites["y_m"].to_numpy(float), phi)
        sites["x_m"], sites["y_m"] = xw, yw
    finite = np.isfinite(sites[["p_s", "p_f", "p_r", "c_s"]].to_numpy(float)).all(axis=1) if len(sites) else []
    if len(sites) and not np.all(finite):  # never a NaN cost or a NaN "best"
        sites = sites[finite].reset_index(drop=True)
    return sites


def _select_best(ctx: _Ctx, sites: pd.DataFrame, heads: np.ndarray, phi: float, first: dict[float, float],
                 cached: list[Any]) -> tuple[dict[str, Any] | None, np.ndarray, np.ndarray]:
    """Mark the lowest-cost site (ties: the larger circle) in ``sites`` (``is_best``, in place) and return it, its
    cell mask and the footprint slope of its heading (the first heading when there is no site); the maps come from
    ``cached`` when it holds that heading, else the heading is analysed again."""
    best = None
    best_mask = np.zeros(ctx.z.shape, bool)
    if len(sites):
        order = np.lexsort((-sites["radius_m"].to_numpy(), sites["c_s"].to_numpy()))
        bi = int(order[0])
        sites["is_best"] = False
        sites.loc[bi, "is_best"] = True
        best = {k: (v.item() if hasattr(v, "item") else v) for k, v in sites.iloc[bi].to_dict().items()}
        kb = _heading_key(best["heading_deg"], phi)
        if cached and cached[0][0] == kb and first[kb] == float(best["heading_deg"]) - phi:
            hm, lab, (b0, b1, b2, b3) = cached[0][2]
            best_mask = np.zeros(ctx.z.shape, bool)
            best_mask[b0:b1, b2:b3] = lab == int(best["site_id"])
        else:
            _, _, hm, labels = _analyse_heading(ctx, best["heading_deg"] - phi, want_labels=True)
            best_mask = labels == int(best["site_id"])
        cached.clear()
        fp_slope = hm.slope_deg
    else:
        sites["is_best"] = pd.Series(dtype=bool)
        fp_slope = ctx.corr.compute(float(heads[0]) - phi, need_slope=True).slope_deg
    return best, best_mask, fp_slope


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
