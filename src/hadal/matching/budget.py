"""The ``match`` stage's science after the search, pure (arrays and models in, results out; no I/O):

* :func:`uncertainty_budget` -- the fix's 1-sigma budget: the match term (MSD likelihood, + jackknife when refined,
  or the posterior main mode's covariance) and, for the refined score minimum (``match.posterior: false``), a
  dead-reckoning term ``dr_error_fraction`` x :func:`information_distance_m` (radial; per axis / sqrt 2), in
  quadrature;
* :func:`posterior_record` -- the ``fix.json`` entries of the point-mass posterior (summary, ellipses about the
  profile start, the dead-reckoning-only track);
* :func:`mrf_step` -- MRF fine matching of soundings placed on the map by the fix and gridded on its cells
  (:func:`grid_track_patch`): the vehicle's own swath (:func:`swath_on_map`) when the dive has one, else the matched
  track; or the reason it is not run (a single-beam track is no 2-D real-time terrain patch, MRF paper §2).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import numpy as np
import pandas as pd

from hadal.errors import InputError
from hadal.geo import LocalFrame
from hadal.matching.mapgrid import MapGrid
from hadal.matching.tercom import TercomResult

#: MRF runs only on a 2-D real-time terrain patch: at least this fraction of the patch's cells must hold soundings
MRF_MIN_COVERAGE = 0.5


@dataclass(frozen=True)
class UncertaintyBudget:
    """The fix with its budgeted 1-sigma (``result.sigma_x_m``/``sigma_y_m``) and the ``fix.json``
    ``uncertainty_m.components`` entry describing it."""

    result: TercomResult
    components: dict[str, Any]
    dead_reckoning_sigma_m: float  # per axis
    information_distance_m: float


def information_distance_m(res: TercomResult, track_xy: np.ndarray, along_m: np.ndarray, g: MapGrid) -> float:
    """Along-track distance from the start to where the terrain fixes the match: the centroid of the
    profile points weighted by the squared map gradient at their matched positions (flat stretches carry no
    position information, so the start is carried there by dead reckoning)."""
    xy = res.apply(track_xy)
    gy, gx = np.gradient(g.depth_m, g.resolution_m)  # NaN next to holes: those points carry no weight
    w = (MapGrid(gx, g.x_m, g.y_m, g.resolution_m).sample_bilinear(xy[:, 0], xy[:, 1]) ** 2
         + MapGrid(gy, g.x_m, g.y_m, g.resolution_m).sample_bilinear(xy[:, 0], xy[:, 1]) ** 2)
    w = np.where(np.isfinite(w), w, 0.0)
    return float(np.sum(w * along_m) / np.sum(w)) if np.sum(w) > 0 else float(along_m[-1] / 2)


def uncertainty_budget(res: TercomResult, track_xy: np.ndarray, along_m: np.ndarray, g: MapGrid, *,
                       dr_error_fraction: float, posterior_used: bool) -> UncertaintyBudget:
    """The fix's 1-sigma budget. ``res``: the reported fix (its ``sigma_x_m``/``sigma_y_m`` are the match term);
    ``track_xy``/``along_m``: the matched profile points (relative track, along-track distance); ``g``: the map
    matched on. With ``posterior_used`` the posterior main mode's covariance is the whole budget (no separate DR term);
    else the DR term ``dr_error_fraction x information_distance_m / sqrt(2)`` per axis is added in quadrature."""
    sigma_match = (res.sigma_x_m, res.sigma_y_m)
    d_info = information_distance_m(res, track_xy, along_m, g)
    sigma_dr = 0.0 if posterior_used else dr_error_fraction * d_info / np.sqrt(2.0)  # per axis
    out = replace(res, sigma_x_m=float(np.hypot(res.sigma_x_m, sigma_dr)),
                  sigma_y_m=float(np.hypot(res.sigma_y_m, sigma_dr)))
    components = {
        "match_radial": float(np.hypot(*sigma_match)), "dead_reckoning_radial": float(sigma_dr * np.sqrt(2.0)),
        "information_distance_m": d_info, "dr_error_fraction": dr_error_fraction,
        "comment": ("posterior main mode's covariance at the MAP fix (Laplace over position, heading, scale, drift and "
                    "bias, with the dead reckoning's random walk; the mass elsewhere is posterior.mass_outside_main_mode; noise "
                    "and effective sample size estimated from the residuals); no separate dead-reckoning term")
        if posterior_used else
        ("match: MSD likelihood (+ jackknife when refined); dead reckoning: dr_error_fraction x the along-track "
         "distance from the start to the terrain-information centroid (gradient^2-weighted) of the track"),
    }
    return UncertaintyBudget(out, components, float(sigma_dr), d_info)


def posterior_record(post: Any, fix: dict[str, Any], frame: LocalFrame, bottom: pd.DataFrame,
                     used_for_fix: bool) -> dict[str, Any]:
    """``fix.json`` entries of the point-mass posterior ``post`` (:class:`hadal.matching.posterior.PosteriorFix`):
    ``posterior`` and, when it is the reported fix, ``mismatch_reasons`` and the ``uncertainty_m`` ellipses /
    covariance (about the MAP profile start); ``dead_reckoning_track`` (launch ``fix['launch']`` + the DR offsets
    of ``bottom``, every 10th sample and the last). Returns the entries to update ``fix`` with (``uncertainty_m``
    is ``fix``'s, updated)."""
    out: dict[str, Any] = {"posterior": post.summary()}
    out["posterior"]["used_for_fix"] = used_for_fix
    if used_for_fix:
        out["mismatch_reasons"] = list(post.reasons)
        # the report draws the ellipse about the matched start and the dead-reckoning-only track
        e1, e2 = post.ellipse(1.0), post.ellipse(2.0)
        clon, clat = (float(v) for v in frame.to_lonlat(post.start_x_m, post.start_y_m))
        centre = {"x_east_m": post.start_x_m, "y_north_m": post.start_y_m, "lat": clat, "lon": clon,
                  "comment": "ellipse centre: the MAP position of the first profile point (profile_start)"}
        e1, e2 = {**e1, "centre": centre}, {**e2, "centre": centre}
        out["uncertainty_m"] = {**fix["uncertainty_m"], "ellipse_1sigma": e1, "ellipse_2sigma": e2,
                                "covariance_m2": out["posterior"]["covariance_m2"]}
        out["posterior"]["ellipse_1sigma"], out["posterior"]["ellipse_2sigma"] = e1, e2
    else:
        out["posterior"]["comment"] = ("computed for the record; the reported fix is the refined score minimum "
                                       "(match.posterior: false)")
    out["posterior"]["surface"] = {
        "file": "msd_surface.nc", "variable": "msd_posterior_probability",
        "comment": "marginal posterior probability of the track start per map cell (sums to 1 over the searched cells)"}
    dr_only = bottom[["dr_east_m", "dr_north_m"]].to_numpy(float)
    lx, ly = fix["launch"]["x_east_m"], fix["launch"]["y_north_m"]
    drt: dict[str, Any] = {
        "comment": "bottom track by dead reckoning only (launch point + DR offsets), map frame metres; "
                   "every 10th sample and the last",
        "x_east_m": [float(v) for v in (dr_only[::10, 0] + lx)] + [float(dr_only[-1, 0] + lx)],
        "y_north_m": [float(v) for v in (dr_only[::10, 1] + ly)] + [float(dr_only[-1, 1] + ly)],
    }
    dlon, dlat = frame.to_lonlat(np.asarray(drt["x_east_m"]), np.asarray(drt["y_north_m"]))
    drt["lon"] = [float(v) for v in np.atleast_1d(dlon)]
    drt["lat"] = [float(v) for v in np.atleast_1d(dlat)]
    out["dead_reckoning_track"] = drt
    return out


def grid_track_patch(xy: np.ndarray, depth: np.ndarray, g: MapGrid, margin_cells: int = 3):
    """Grid matched track soundings onto the DTM cells (cell means): the 'real-time terrain' patch for MRF.

    Returns ``(patch, x0_m, y0_m)`` with NaN for empty cells and the map position of cell ``[0, 0]``.
    """
    col = np.rint(g.col_of(xy[:, 0])).astype(int)
    row = np.rint(g.row_of(xy[:, 1])).astype(int)
    c0, r0 = col.min() - margin_cells, row.min() - margin_cells
    nx_p, ny_p = col.max() - c0 + 1 + margin_cells, row.max() - r0 + 1 + margin_cells
    flat = (row - r0) * nx_p + (col - c0)
    s = np.bincount(flat, weights=depth, minlength=nx_p * ny_p)
    n = np.bincount(flat, minlength=nx_p * ny_p)
    with np.errstate(invalid="ignore"):
        patch = (s / n).reshape(ny_p, nx_p)
    h = g.resolution_m
    return patch, float(g.x_m[0] + c0 * h), float(g.y_m[0] + r0 * h)


def swath_interior_fraction(patch: np.ndarray) -> float:
    """Share of the sounded (finite) cells of ``patch`` whose four neighbours are sounded too (0 when none is)."""
    v = np.isfinite(np.asarray(patch, float))
    if v.sum() == 0:
        return 0.0
    inner = np.zeros_like(v)
    inner[1:-1, 1:-1] = v[1:-1, 1:-1] & v[:-2, 1:-1] & v[2:, 1:-1] & v[1:-1, :-2] & v[1:-1, 2:]
    return float(inner.sum() / v.sum())


def swath_on_map(swath_dr_xy: np.ndarray, bottom_dr_xy: np.ndarray, track_map_xy: np.ndarray, res: TercomResult,
                 max_offset_m: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Map positions of the vehicle's own swath soundings, placed by the match like the bottom track.

    ``swath_dr_xy`` (M, 2): the soundings in the dead-reckoning frame of the bottom track (their logged position minus
    the launch point: the vehicle's own navigation, launch + dead reckoning); ``bottom_dr_xy`` / ``track_map_xy``
    (N, 2): the bottom-track samples in that frame and on the map (:func:`hadal.matching.fix.matched_track`, the
    estimated dead-reckoning drift included). A sounding gets the rigid pose of the fix (``res.apply``: start,
    heading, scale, so a beam's offset from nadir turns with the heading correction) plus the drift of the nearest
    bottom-track sample (nearest in the dead-reckoning frame: the swath files carry no time per sounding). Soundings
    more than ``max_offset_m`` from every bottom-track sample (logged before or after the bottom phase, or not
    positioned by the vehicle's navigation) are not placed. Returns ``(map xy (K, 2), mask (M,) of those placed,
    index (K,) of each placed sounding's bottom-track sample)``."""
    from scipy.spatial import cKDTree

    q = np.asarray(swath_dr_xy, float).reshape(-1, 2)
    b = np.asarray(bottom_dr_xy, float).reshape(-1, 2)
    m = np.asarray(track_map_xy, float).reshape(-1, 2)
    ok_b = np.isfinite(b).all(axis=1) & np.isfinite(m).all(axis=1)
    rows = np.flatnonzero(ok_b)
    b, m = b[ok_b], m[ok_b]
    if len(b) == 0 or len(q) == 0:
        return np.empty((0, 2)), np.zeros(len(q), bool), np.empty(0, int)
    dist, i = cKDTree(b).query(np.nan_to_num(q, nan=np.inf), k=1, distance_upper_bound=float(max_offset_m))
    placed = np.isfinite(dist) & np.isfinite(q).all(axis=1)
    drift = m - res.apply(b)  # what the match added to each sample beyond the rigid pose (the drift estimate)
    return res.apply(q[placed]) + drift[i[placed]], placed, rows[i[placed]]


def mrf_step(track_xy: np.ndarray, seafloor_depth_m: np.ndarray, g: MapGrid, g_raw: MapGrid,
             start_xy: tuple[float, float], frame: LocalFrame, *, max_shift_cells: float,
             max_total_shift_cells: float, prior: str, patch_source: str = "bottom_track", edge: Any = None
             ) -> tuple[dict[str, Any], list[str]]:
    """MRF fine matching ([MRF Eqs. 4-14], :func:`hadal.matching.mrf.mrf_refine` on ``g_raw``) of soundings placed
    on the map by the fix (map positions ``track_xy``, measured ``seafloor_depth_m``: the matched bottom track, or
    with ``patch_source="vehicle_swath"`` the vehicle's own swath soundings, :func:`swath_on_map`) gridded on the
    cells of ``g``; ``start_xy``: the reported start, moved by the MRF shift; ``edge``: the search-edge options
    (:class:`hadal.matching.options.SearchEdgeOptions`, default when None). Returns ``(fix.json 'mrf' entry,
    warnings for fix.json)``."""
    from hadal.matching.mrf import mrf_refine

    patch, x0, y0 = grid_track_patch(track_xy, seafloor_depth_m, g)
    if patch_source == "vehicle_swath":
        # a swath along a long, turning track fills little of its bounding box by geometry: it is judged by its own
        # footprint, the share of its sounded cells whose four neighbours are sounded too (the Gibbs neighbourhood
        # and the 2-D Taylor step need them; a swath under ~3 cells wide has almost none)
        cover = swath_interior_fraction(patch)
        reason = (f"{100 * cover:.0f} % of the map cells the vehicle's swath sounds have all four neighbours sounded "
                  f"(< {100 * MRF_MIN_COVERAGE:.0f} %): too narrow or sparse a swath at the map's cell size for a 2-D "
                  "real-time terrain patch, so MRF is not run")
        warning = "match.mrf: the vehicle's swath is too narrow or sparse for a 2-D terrain patch at the map's cell " \
                  "size: MRF not run"
    else:
        # MRF paper §2: the real-time terrain is a 2-D multibeam patch; a single-beam (altimeter) track gridded on
        # the map leaves most cells empty, and the Gibbs neighbourhood prior and the 2-D Taylor step are undefined
        cover = float(np.isfinite(patch[3:-3, 3:-3]).mean()) if min(patch.shape) > 6 else 0.0
        reason = (f"MRF fine matching needs a 2-D real-time terrain patch (the vehicle's own swath/multibeam "
                  f"soundings); this dive's bottom track is a single-beam altimeter profile covering "
                  f"{100 * cover:.0f} % of the cells under it (< {100 * MRF_MIN_COVERAGE:.0f} %), so MRF is not run")
        warning = "match.mrf is on but the bottom track is single-beam (no 2-D terrain patch): MRF not run"
    if cover < MRF_MIN_COVERAGE:
        return {"applied": False, "coverage": cover, "patch_source": patch_source, "reason": reason}, [warning]
    try:
        m = mrf_refine(patch, x0, y0, g_raw, max_shift_cells=max_shift_cells,
                       max_total_shift_cells=max_total_shift_cells, prior=prior, edge=edge)
    except InputError as exc:
        return {"applied": False, "reason": str(exc)}, []
    sx, sy = start_xy[0] - m.dx_m, start_xy[1] - m.dy_m
    slon, slat = (float(v) for v in frame.to_lonlat(sx, sy))
    entry = {"applied": m.converged, "patch_source": patch_source, "coverage": cover, "dx_m": m.dx_m, "dy_m": m.dy_m,
             "iterations": m.iterations,
             "sigma_n_m": m.sigma_n_m, "window_cells": list(m.n_window), "warnings": m.warnings,
             "coarse_shift_cells": list(m.coarse_d_cells),
             "sigma_cells": [v if np.isfinite(v) else None for v in m.sigma_cells],
             "gibbs_temperature_m2": m.temperature if np.isfinite(m.temperature) else None,
             "search_edge": m.search_edge,
             "start": {"x_east_m": sx, "y_north_m": sy, "lat": slat, "lon": slon}}
    return entry, list(m.warnings)
