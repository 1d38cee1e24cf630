"""Stage `match`: TERCOM terrain matching of the bottom track on the reference DTM (+ optional MRF refinement).

Reads ``dtm`` (``dtm.nc``) and ``ctd`` (``ctd.parquet``: bottom-phase ``seafloor_depth_m`` along the
dead-reckoned ``dr_east_m``/``dr_north_m`` relative to the launch point), builds the measured profile
resampled at about the map resolution, runs the exhaustive TERCOM search (TERCOM paper §3.3, §4.2;
:func:`hadal.matching.tercom`) and publishes ``match``.

Deviations from the paper's set-up, all configurable:

* the DR track's heading error is searched (+-9 deg, 0.5 deg steps; ``heading_range_deg: 0`` gives the
  paper's translation-only search);
* the MSD fix is refined below the map resolution (``refine``, :func:`hadal.matching.refine_tercom`):
  bilinear map, continuous start, heading and DR scale (+-``refine_scale_range``). The dead reckoning
  has heading-bias, scale and random-walk errors, and a search snapped to 20 m cells lets a wrong heading
  fit the quantised samples better (on the sample dive the coarse start was 195 m off, the refined
  one 16 m). ``refine: false`` keeps the cell-resolution result;
* the DTM is low-passed by a normalised Gaussian convolution (``dtm_smooth_sigma_cells``; by default
  1 cell, 2 cells when more than 10 % of the DTM is empty) before matching: it fills small holes and
  halves the sounding noise of a multibeam DTM with a few soundings per cell;
* ``segment_m`` can restrict the match to the start of the bottom track (default: the whole track).

With ``posterior: true`` the reported fix is the point-mass posterior of
:func:`hadal.matching.posterior_fix` (MAP start/heading/scale, posterior covariance and 1-/2-sigma ellipses,
mass outside the main mode, mismatch reasons: ambiguous, short track, off the map / over holes, flat map);
the paper's cell-resolution search still provides ``msd_surface.nc`` and ``refinement.coarse``. The posterior
also estimates the dead-reckoning drift (a velocity bias piecewise constant over ``drift_segment_s``, prior
``drift_velocity_sigma_m_s``) jointly with the start, heading and scale (``1 +- refine_scale_range``); the
matched track then follows the drift. It is computed for the record in any case (``fix.json`` ``posterior``,
``msd_posterior_probability`` in ``msd_surface.nc``). ``posterior`` is on by default:
on the sample dive's 10 generator seeds its start errors equal the refined minimum's and its radial 1-sigma (the
main mode's Laplace covariance with the DTM's uncertainty layer as the noise floor and the navigation's random
walk, ``drift_random_walk_m_per_sqrt_s``: 30-51 m) covers them as a calibrated error would: 7/10 within 1-sigma,
10/10 within 2-sigma (largest 1.37 sigma; bench/sample_seeds_tercom.py, 2026-12-04), where the refined minimum's
jackknife + DR sigma (57-75 m) holds all 10 within 1-sigma. Neither places the start within one cell on every
seed: with this prior DTM (1.3 soundings a cell,
0.1 % of depth noise) the Cramér-Rao bound of the start is 14-24 m, and the same code on the true terrain is
within one cell on 10/10 (bench/sample_seeds_information.py). With ``posterior: false`` the fix uncertainty combines the MSD likelihood, a jackknife over track blocks and a dead-reckoning term
(``dr_error_fraction`` x the distance from the start to the track's terrain-information centroid; a
conservative bound: the refinement already removes part of the DR heading/scale error). The ``navigation``
product's dead-reckoning-only uncertainty (no match, or where the match does not reach) adds, in quadrature
with the launch uncertainty, ``dr_error_fraction`` x the distance dead-reckoned and a random walk
``dr_unreferenced_drift_m_per_sqrt_s`` x sqrt(seconds without a DR velocity reference): the unpowered descent
carries the vehicle hundreds of metres with the currents while the DR is held (533 m in the TERCOM paper, §4.2).
On 10 generator seeds 75 % of the DR-only errors lie within the stated 1 sigma and 100 % within 2 sigma
(bench/dr_uncertainty_tercom.py; the former 1 %-of-distance model: 0.2 % / 0.4 %). Products:

* ``msd_surface.nc`` -- the criterion on the map grid (track start at each cell), the per-offset bias, the
  posterior probability of the start per cell;
* ``matched_track.parquet`` -- the bottom samples placed on the map, lat/lon in degrees;
* ``fix.json`` -- best offset, start and deepest-point lat/lon (also degrees-minutes), drift from the
  launch point (geodesic), uncertainty, second optimum / mismatch warning, depth bias, MRF result.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING

from hadal.budget import check_memory, check_work, memory_limit_bytes, work_limit
from hadal.errors import ConfigError, InputError
from hadal.settings.match import MatchParams as Params
from hadal.settings.match import PosteriorNoiseOptions, SearchEdgeOptions
from hadal.stages import Stage, StageContext, StageInputs
from hadal.store import ProductVersion

if TYPE_CHECKING:
    from pathlib import Path

    import numpy as np
    import pandas as pd
    import xarray as xr


def _symmetric_steps(centre: float, half_range: float, step: float, keys: tuple[str, str], what: str) -> np.ndarray:
    """``centre + k * step`` for ``|k * step| <= half_range`` (just ``centre`` when the range is 0), rounded to
    1e-6; a step that is not > 0 or exceeds the range is a one-line ConfigError naming the ``match.`` keys."""
    import numpy as np

    if half_range == 0:
        return np.array([centre])
    if not step > 0 or step > half_range:
        raise ConfigError(f"match.{keys[0]} = {step:g} must be > 0 and at most match.{keys[1]} = "
                          f"{half_range:g} (else only {what} is searched)")
    n = int(round(half_range / step))
    return np.round(centre + np.arange(-n, n + 1) * step, 6)


def _headings(p: Params) -> np.ndarray:
    return _symmetric_steps(0.0, p.heading_range_deg, p.heading_step_deg,
                            ("heading_step_deg", "heading_range_deg"), "0 deg")


def _scales(p: Params) -> np.ndarray:
    return _symmetric_steps(1.0, p.scale_range, p.scale_step, ("scale_step", "scale_range"), "scale 1")


#: float64 map-sized arrays the search holds besides the per-pose surfaces (smoothed map, FFT spectra, best
#: surfaces, bias, region mask)
MATCH_MAP_LAYERS = 32


def check_search_budget(p: Params, n_cells: int, n_points: int, config=None) -> tuple[int, int]:
    """Refuse (one-line ConfigError) a search whose (heading x scale poses) x (map offsets) evaluations or
    memory (the posterior keeps a float32 score and count surface per pose) exceed the ``resources`` limits.
    Returns ``(n_headings, n_scales)``."""
    n_h, n_s = int(_search_size(p.heading_range_deg, p.heading_step_deg)), int(_search_size(p.scale_range,
                                                                                              p.scale_step))
    poses = float(n_h) * float(n_s)
    setting, value = (("match.heading_step_deg", float(p.heading_step_deg)) if n_h >= n_s
                      else ("match.scale_step", float(p.scale_step)))
    what = f"the match search ({n_h:,} headings x {n_s:,} scales x {n_cells:,} map offsets, {n_points:,} profile points)"
    check_work(what, poses * n_cells, work_limit(config), setting=setting, value=value,
               advice=f"use a larger {setting}, a smaller range or a coarser DTM, or raise "
                      "resources.max_match_evaluations")
    need = float(n_cells) * 8.0 * (MATCH_MAP_LAYERS + (poses if p.criterion == "msd" else 3))
    check_memory(what, need, memory_limit_bytes(config), setting=setting, value=value,
                 advice=f"use a larger {setting}, a smaller range or a coarser DTM, or raise resources.max_memory_gb")
    return n_h, n_s


def _search_size(rng: float, step: float) -> float:
    """Number of values of a symmetric ``+-rng`` search in ``step`` steps (1 for no search), without building it."""
    if rng == 0:
        return 1.0
    if not step > 0 or step > rng:
        raise ConfigError(f"match search step {step:g} must be > 0 and at most its range {rng:g}")
    return 2.0 * round(rng / step) + 1.0


def matching_dtm(g_raw, p: Params):
    """``(map matched on, empty fraction, smoothing sigma in cells)``: the DTM low-passed by a normalised Gaussian
    convolution of ``p.dtm_smooth_sigma_cells`` (default: 2 cells when more than 10 % of it is empty, else 1)."""
    import numpy as np

    empty = float(np.mean(~np.isfinite(g_raw.depth_m)))
    sigma = p.dtm_smooth_sigma_cells if p.dtm_smooth_sigma_cells is not None else (2.0 if empty > 0.10 else 1.0)
    return (g_raw.filled(sigma, smooth_all=True) if sigma > 0 else g_raw), empty, sigma


def posterior_options(p: Params) -> dict:
    """Keyword arguments of :func:`hadal.matching.posterior.posterior_fix` from the stage parameters (all but the
    profile, the map, ``region``, ``uncertainty`` and ``time_s``)."""
    import numpy as np

    r_s = p.refine_scale_range
    return {"headings_deg": _headings(p), "scales": _scales(p), "min_valid_fraction": min(p.min_valid_fraction, 0.5),
            "mode_radius_cells": p.mode_radius_cells, "max_mass_outside": p.max_mass_outside,
            "max_mass_outside_holes": p.max_mass_outside_holes, "min_samples": p.min_samples,
            "fine_scales": np.linspace(1 - r_s, 1 + r_s, 5) if r_s > 0 else None, "drift": p.drift,
            "drift_segment": p.drift_segment_s, "drift_sigma": p.drift_velocity_sigma_m_s,
            "drift_random_walk": p.drift_random_walk_m_per_sqrt_s,
            "noise": PosteriorNoiseOptions(**p.model_dump(include=set(PosteriorNoiseOptions.model_fields))),
            "edge": SearchEdgeOptions(**p.model_dump(include=set(SearchEdgeOptions.model_fields)))}


def read_ctd(pv: ProductVersion) -> pd.DataFrame:
    import pandas as pd

    path = pv.file("ctd.parquet")
    try:
        return pd.read_parquet(path)
    except Exception as exc:  # pyarrow raises several types on truncated/corrupt files
        raise InputError(f"{path}: cannot read the CTD table ({type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''})") from None


def surface_dataset(res, frame, criterion: str, post=None) -> xr.Dataset:
    import numpy as np
    import xarray as xr

    long = {"msd": "mean square difference (TERCOM paper Eq. 17)", "mad": "mean absolute difference (Eq. 16)",
            "cor": "cross correlation (Eq. 15)"}[criterion]
    units = {"msd": "m2", "mad": "m", "cor": "m2"}[criterion]
    data = {
        "score": (("y", "x"), res.surface.astype(np.float32), {
            "long_name": f"{long} with the track start at the cell, best heading", "units": units, "grid_mapping": "crs"}),
        "score_all_headings": (("y", "x"), res.surface_all_headings.astype(np.float32), {
            "long_name": f"best {criterion.upper()} over the searched headings", "units": units, "grid_mapping": "crs"}),
    }
    if post is not None:  # the posterior may hold a crop of the map (search region + track footprint): embed it
        pc = np.zeros(res.surface.shape, np.float32)
        h = float(res.x_m[1] - res.x_m[0])
        c0 = int(round((post.x_m[0] - res.x_m[0]) / h))
        r0 = int(round((post.y_m[0] - res.y_m[0]) / h))
        pc[r0 : r0 + post.y_m.size, c0 : c0 + post.x_m.size] = post.posterior_cells
        data["msd_posterior_probability"] = (("y", "x"), pc, {
            "long_name": "posterior probability of the track start in the cell (point-mass posterior, all poses)",
            "units": "1", "grid_mapping": "crs"})
    if res.bias_surface is not None:
        data["bias_m"] = (("y", "x"), res.bias_surface.astype(np.float32), {
            "long_name": "estimated map-minus-measured depth bias at the offset", "units": "m", "grid_mapping": "crs"})
    ds = xr.Dataset(
        data,
        coords={
            "x": ("x", res.x_m, {"standard_name": "projection_x_coordinate", "units": "m", "axis": "X",
                                 "long_name": "easting of the track start in the dive's map frame"}),
            "y": ("y", res.y_m, {"standard_name": "projection_y_coordinate", "units": "m", "axis": "Y",
                                 "long_name": "northing of the track start in the dive's map frame"}),
        },
    )
    ds["crs"] = ((), np.int32(0), {"grid_mapping_name": "transverse_mercator", "crs_wkt": frame.crs.to_wkt(),
                                   "proj4": frame.crs.srs,
                                   "latitude_of_projection_origin": frame.origin_latitude_deg,
                                   "longitude_of_central_meridian": frame.origin_longitude_deg,
                                   "scale_factor_at_central_meridian": 1.0, "false_easting": 0.0, "false_northing": 0.0})
    ds.attrs.update({"criterion": criterion, "best_x_m": res.start_x_m, "best_y_m": res.start_y_m,
                     "best_heading_error_deg": res.heading_deg, "best_score": res.score,
                     "map_frame_origin_latitude_deg": frame.origin_latitude_deg,
                     "map_frame_origin_longitude_deg": frame.origin_longitude_deg})
    return ds


#: ``ctd`` columns the bottom track is made of (seafloor depth = depth + altitude, on the dead-reckoned track)
TRACK_COLUMNS = ("seafloor_depth_m", "dr_east_m", "dr_north_m")

def skip_reason(ctx: StageContext) -> str | None:
    """Why ``match`` cannot run on this dive's ``ctd`` (no altimeter or no dead-reckoned track), or ``None``."""
    import numpy as np
    import pyarrow.parquet as pq

    pv = ctx.optional_upstream("ctd")
    if pv is None:
        return None  # run() reports the missing upstream product itself
    path = pv.file("ctd.parquet")
    try:
        names = set(pq.read_schema(path).names)
        missing = [c for c in TRACK_COLUMNS if c not in names]
        if not missing:
            tab = pq.read_table(path, columns=list(TRACK_COLUMNS))
            missing = [c for c in TRACK_COLUMNS if not np.isfinite(tab[c].to_numpy(zero_copy_only=False)).any()]
    except (OSError, ValueError):
        return None  # unreadable: run() gives the one-line error
    if missing:
        what = {"seafloor_depth_m": "altimeter ranges (seafloor depth)", "dr_east_m": "a dead-reckoned track",
                "dr_north_m": "a dead-reckoned track"}
        return "the vehicle log has no " + " and no ".join(dict.fromkeys(what[c] for c in missing))
    return None


def _search(ctx: StageContext, p: Params, prof, g, region, dtm_ds):
    """The TERCOM search of the profile (or its first ``segment_m``) on the matching map ``g``, the sub-cell
    refinement (``posterior: false``) and the point-mass posterior (MSD). Returns ``(fix, posterior or None,
    mask of the profile points used)``."""
    import numpy as np

    from hadal.matching import refine_tercom, tercom

    used = np.ones(prof.depth_m.size, bool)
    if p.segment_m is not None and prof.along_m[-1] > p.segment_m:
        used = prof.along_m <= p.segment_m
        if used.sum() < 10:  # too short to be unique: fall back to the whole track
            used[:] = True
    check_search_budget(p, int(g.depth_m.size), int(used.sum()), ctx.config)
    ctx.log.info("match: %d bottom samples -> %d profile points (%d used), %d heading(s)",
                 prof.n_raw, prof.depth_m.size, int(used.sum()), _headings(p).size)
    res = tercom(prof.depth_m[used], prof.track_xy[used], g, headings_deg=_headings(p), scales=_scales(p),
                 region=region, progress=ctx.progress, options=p)
    if p.refine and p.criterion == "msd" and not p.posterior:
        hs, sc = _headings(p), _scales(p)
        res = refine_tercom(
            prof.depth_m[used], prof.track_xy[used], g, res, region=region, options=p,
            heading_bounds_deg=(float(hs.min()) - p.heading_step_deg / 2, float(hs.max()) + p.heading_step_deg / 2)
            if hs.size > 1 else (0.0, 0.0),
            scale_bounds=(min(float(sc.min()), 1 - p.refine_scale_range), max(float(sc.max()), 1 + p.refine_scale_range)),
        )
    post = None
    if p.criterion == "msd":
        from hadal.matching.posterior import posterior_fix

        unc = dtm_ds["uncertainty_m"].transpose("y", "x").values if "uncertainty_m" in dtm_ds else None
        post = posterior_fix(prof.depth_m[used], prof.track_xy[used], g, region=region, uncertainty=unc,
                             time_s=None if prof.time_s is None else prof.time_s[used], **posterior_options(p))
        if p.posterior:
            res = post.to_tercom_result(res)
    return res, post, used


def raw_files(ctx: StageContext) -> list[Path]:
    """Raw files this stage reads besides its upstream products (for the cache fingerprint, tasks/stage.py): the
    vehicle's swath soundings, when MRF is on."""
    from hadal.dive import resolve_source

    if not ctx.config.match.mrf:
        return []
    return [resolve_source(ctx.raw_dir, e) for e in ctx.dive.sources.files("vehicle_swath")]


def _mrf_soundings(ctx: StageContext, p: Params, bottom, track, res, frame, cell_m: float):
    """The soundings MRF grids into its real-time terrain patch, on the map: the vehicle's own swath
    (``sources.vehicle_swath``, logged in its navigation = launch + dead reckoning, placed by the fix:
    :func:`hadal.matching.budget.swath_on_map`) along the first ``mrf_patch_length_m`` of the bottom track (MRF's
    one shift then corrects the reported start; ``cell_m`` the map's cell) when the dive has one, else the matched
    bottom track. Returns
    ``(map xy (K, 2), seafloor depth (K,), {"patch_source": ..., counts for fix.json})``."""
    import numpy as np

    from hadal.matching.budget import swath_on_map

    files = raw_files(ctx)
    if not files:
        return (track[["x_east_m", "y_north_m"]].to_numpy(), track["seafloor_depth_m"].to_numpy(),
                {"patch_source": "bottom_track"})
    from hadal.grid.soundings import read_soundings_xy

    hints = ctx.dive.sources.files("vehicle_swath")
    launch = ctx.dive.require_launch("match", "the vehicle's swath soundings are logged in its navigation from the launch point")
    x, y, dep, _, used = read_soundings_xy(files, frame, hints, memory_limit_bytes=memory_limit_bytes(ctx.config))
    lx, ly = (float(v) for v in frame.to_xy(launch.longitude_deg, launch.latitude_deg))
    dr = bottom[["dr_east_m", "dr_north_m"]].to_numpy(float)
    xy, placed, row = swath_on_map(np.column_stack([x - lx, y - ly]), dr, track[["x_east_m", "y_north_m"]].to_numpy(float),
                                   res, p.mrf_swath_max_offset_m)
    n_out = int((~placed).sum())
    if not placed.any():
        raise InputError(f"{', '.join(str(f) for f in files)}: none of the {placed.size} vehicle swath soundings lies "
                         f"within {p.mrf_swath_max_offset_m:g} m of the bottom track in the vehicle's dead-reckoned "
                         "navigation (launch + dead reckoning); are they positioned by the vehicle's own navigation?")
    along = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(dr, axis=0).T))])
    length = p.mrf_patch_length_m if p.mrf_patch_length_m is not None else 40 * cell_m
    near_start = along[row] <= length
    ctx.log.info("match: MRF patch from %d vehicle swath soundings of the first %g m of the bottom track (%s); %d more "
                 "placed, %d beyond %g m of the track not placed", int(near_start.sum()), length, "; ".join(used),
                 int((~near_start).sum()), n_out, p.mrf_swath_max_offset_m)
    return xy[near_start], dep[placed][near_start], {
        "patch_source": "vehicle_swath", "patch_length_m": float(length), "n_swath_soundings": int(placed.size),
        "n_swath_soundings_in_patch": int(near_start.sum()), "n_swath_soundings_not_placed": n_out,
        "swath_readers": used}


#: column attributes of ``matched_track.parquet``
TRACK_FIELDS = {
    "x_east_m": {"units": "m", "long_name": "matched easting in the dive's map frame"},
    "y_north_m": {"units": "m", "long_name": "matched northing in the dive's map frame"},
    "lon": {"units": "degrees_east", "standard_name": "longitude"},
    "lat": {"units": "degrees_north", "standard_name": "latitude"},
    "depth_m": {"units": "m", "standard_name": "depth", "long_name": "vehicle depth"},
    "seafloor_depth_m": {"units": "m", "long_name": "measured seafloor depth (vehicle depth + altitude)"},
    "map_depth_m": {"units": "m", "long_name": "reference DTM depth at the matched position (bilinear)"},
    "map_depth_minus_bias_m": {"units": "m", "long_name": "reference DTM depth minus the estimated bias"},
}


def run(ctx: StageContext) -> dict[str, ProductVersion]:
    import xarray as xr

    from hadal.matching import MapGrid
    from hadal.matching.budget import mrf_step, posterior_record, uncertainty_budget
    from hadal.matching.fix import fix_summary, matched_track, profile_from_ctd
    from hadal.products import write_netcdf, write_parquet
    from hadal.products.readers import open_dtm

    p: Params = ctx.config.match
    dtm_pv, ctd_pv = ctx.upstream("dtm"), ctx.upstream("ctd")
    upstream = [dtm_pv, ctd_pv]
    dtm_ds = open_dtm(dtm_pv)  # read once: the depth layer and, for the posterior, the per-cell uncertainty
    g_raw = MapGrid.from_any(dtm_ds, name=str(dtm_pv.path / "dtm.nc"))
    g, empty, sigma = matching_dtm(g_raw, p)
    ctd = read_ctd(ctd_pv)
    frame = ctx.dive.frame()
    prof, bottom = profile_from_ctd(ctd, p.resample_spacing_m or g.resolution_m, name=str(ctd_pv.path / "ctd.parquet"))

    region = None
    if p.region == "suitability":
        suit_pv = ctx.upstream("suitability")
        upstream.append(suit_pv)
        with xr.open_dataset(suit_pv.file("suitability.nc"), engine="h5netcdf") as s:
            reg = json.loads(s.attrs["proposed_region"])
        region = (reg["x_min_m"], reg["x_max_m"], reg["y_min_m"], reg["y_max_m"])

    res, post, used = _search(ctx, p, prof, g, region, dtm_ds)
    use_post = post is not None and p.posterior
    budget = uncertainty_budget(res, prof.track_xy[used], prof.along_m[used], g, dr_error_fraction=p.dr_error_fraction,
                                posterior_used=use_post)
    res = budget.result
    drift_xy = None
    if use_post and post.drift_model is not None:  # the matched track follows the estimated DR drift
        from hadal.matching.fix import bottom_seconds

        tb = bottom_seconds(bottom)
        drift_xy = post.drift_at(tb - tb[0])
    track = matched_track(bottom, res, frame, map_depth=g_raw.sample_bilinear, drift_xy=drift_xy)
    launch = ctx.dive.launch
    fix = fix_summary(res, track, frame, launch.latitude_deg, launch.longitude_deg)
    fix["uncertainty_m"]["components"] = budget.components
    if post is not None:
        fix.update(posterior_record(post, fix, frame, bottom, use_post))
    fix["profile"] = {"n_raw_bottom_samples": prof.n_raw, "n_profile_points": int(prof.depth_m.size),
                      "spacing_m": p.resample_spacing_m or g.resolution_m, "track_length_m": float(prof.along_m[-1]),
                      "n_points_matched": int(used.sum()), "matched_length_m": float(prof.along_m[used][-1])}
    fix["dtm"] = {"empty_fraction": empty, "smooth_sigma_cells": sigma}
    if p.mrf:
        pts, dep, source = _mrf_soundings(ctx, p, bottom, track, res, frame, g.resolution_m)
        fix["mrf"], mrf_warnings = mrf_step(
            pts, dep, g, g_raw, (fix["start"]["x_east_m"], fix["start"]["y_north_m"]), frame,
            max_shift_cells=p.mrf_max_shift_cells, max_total_shift_cells=p.mrf_max_total_shift_cells, prior=p.mrf_prior,
            patch_source=source["patch_source"], edge=SearchEdgeOptions(**p.model_dump(include=set(SearchEdgeOptions.model_fields))))
        fix["mrf"].update({k: v for k, v in source.items() if k != "patch_source"})
        fix["warnings"].extend(mrf_warnings)
    for w in fix["warnings"]:
        ctx.log.warning("match: %s", w)

    with ctx.store.publish(ctx.dive_id, "match", parameters=ctx.params("match"), upstream=upstream) as draft:
        write_netcdf(
            surface_dataset(res, frame, p.criterion, post), draft.path / "msd_surface.nc",
            title=f"TERCOM {p.criterion.upper()} surface, dive {ctx.dive_id}",
            summary="TERCOM criterion for every start position of the bottom track on the reference DTM (TERCOM paper §3.3, §4.2).",
        )
        write_parquet(track, draft.path / "matched_track.parquet", fields=TRACK_FIELDS,
                      metadata={"dive": ctx.dive_id, "criterion": p.criterion, "start_degmin": fix["start"]["position_degmin"]})
        from hadal.products.geo_landing import strict_json  # strict JSON, times without spurious microseconds

        (draft.path / "fix.json").write_text(strict_json(fix, indent=2), encoding="utf-8")
    from hadal.products.navigation import publish_navigation  # best position of every sample (products/)

    nav = publish_navigation(ctx, ctd, track, fix, [ctd_pv, draft.result], p.dr_error_fraction,
                             unreferenced_drift_m_per_sqrt_s=p.dr_unreferenced_drift_m_per_sqrt_s, smoother=p.navigation)
    return {"match": draft.result, "navigation": nav}


STAGE = Stage(
    name="match", products=("match", "navigation"),
    inputs=StageInputs(raw_any=("mcap", "csv"), upstream=("dtm", "ctd"), optional_upstream=("suitability",),
                       needs_launch=True, frame_for=("match",)),
    options=Params, run=run, skip_reason=skip_reason, raw_files=raw_files,
    warm_imports=("hadal.matching.posterior", "hadal.matching.budget", "hadal.matching.fix", "hadal.products.readers",
                  "hadal.products.navigation", "hadal.products.geo_landing"),
)
