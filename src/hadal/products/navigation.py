"""The ``navigation`` product: the vehicle's best position for every sample of the dive.

Published positions (issue 47): :func:`smoothed_navigation`, one Kalman filter + Rauch-Tung-Striebel smoother
over the whole dive (:mod:`hadal.navigation.smoother`): the launch position, GNSS fixes at the surface, USBL
fixes and the terrain fix (with its posterior 2x2 covariance) as measurements, the dead reckoning and the
terrain-matched bottom track as the process; every sample gets its 2x2 covariance
(``position_covariance_east_m2``/``_north_m2``/``_east_north_m2``; ``position_uncertainty_m`` is the square root
of its trace, the DRMS) and the manifest summary ``smoother`` the per-fix residuals and chi-square status and the
surfacing / deepest-point ellipses (:func:`smoother_summary`). On the sample dive's 10 generator seeds its RMS
error is about half of the rule below (bench/bench_navigation_coverage.py).

:func:`navigation_table` (the rule of thumb below; still ``derive``'s dead-reckoned positions and the
``position_source`` column) -- sources, per sample (column ``position_source``):

* ``matched`` - bottom-phase samples positioned by terrain matching (``match``'s ``matched_track``);
* ``dead_reckoned`` - the dead-reckoned track (launch point + DR offsets ``dr_east_m``/``dr_north_m``). With a
  match, the descent is corrected by the offset between the matched and the dead-reckoned position at the first
  bottom sample, distributed linearly in time from the launch (known position, correction 0) to that sample:
  the standard adjustment of a dead-reckoned leg between two fixes, which assumes the DR error grows
  uniformly. The ascent has no later fix: it keeps the correction of the last matched sample;
* ``launch`` - samples without a DR offset (before the first DR message, dropouts), at the launch point (descent)
  or the last known position.

Uncertainty (``position_uncertainty_m``, 1-sigma radial, DRMS): matched samples take the fix's radial uncertainty
(``fix.json`` ``uncertainty_m.radial``). Without a match, three terms in quadrature: ``launch_uncertainty_m``;
the drift with the currents while the dead reckoning has no velocity reference (the unpowered descent and
ascent: DR offsets held), a random walk ``unreferenced_drift_m_per_sqrt_s`` x sqrt(unreferenced time) (see
``match.dr_unreferenced_drift_m_per_sqrt_s``); and ``dr_error_fraction`` x the horizontal distance dead-reckoned
(``match.dr_error_fraction``). With a match, the match reveals the DR error over the descent (c0 = |matched - DR| at the
first bottom sample): on the descent the adjusted track's error is taken as c0 x min(w, 1 - w) (w: fraction of the
descent time; zero at both fixes, c0/2 half-way), and after the last match it grows as the larger of the
dead-reckoning-only model restarted at the fix (random walk over the unreferenced time plus the distance term) and
the revealed drift rate c0 / descent time extrapolated linearly, each in quadrature with the nearer fix's
uncertainty.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from hadal.geo import LocalFrame

SOURCES = ("matched", "dead_reckoned", "launch")

NAV_FIELDS: dict[str, dict[str, str]] = {
    "time": {"standard_name": "time", "long_name": "sample time (UTC)"},
    "lat": {"standard_name": "latitude", "units": "degrees_north", "long_name": "best latitude of the vehicle"},
    "lon": {"standard_name": "longitude", "units": "degrees_east", "long_name": "best longitude of the vehicle"},
    "x_east_m": {"standard_name": "projection_x_coordinate", "units": "m",
                 "long_name": "best easting in the dive's map frame"},
    "y_north_m": {"standard_name": "projection_y_coordinate", "units": "m",
                  "long_name": "best northing in the dive's map frame"},
    "depth_m": {"standard_name": "depth", "units": "m", "positive": "down", "long_name": "vehicle depth (hydrostatic)"},
    "position_source": {"long_name": "source of the position: matched, dead_reckoned or launch"},
    "position_uncertainty_m": {"units": "m", "long_name": "1-sigma radial (DRMS) horizontal position uncertainty"},
    "phase": {"long_name": "dive phase (descent, bottom, ascent)"},
}


def _travelled(e: np.ndarray, n: np.ndarray) -> np.ndarray:
    """Cumulative horizontal distance along (e, n) (m), NaN steps counted as 0."""
    d = np.hypot(np.diff(e, prepend=e[:1]), np.diff(n, prepend=n[:1]))
    return np.cumsum(np.where(np.isfinite(d), d, 0.0))


def unreferenced_seconds(ts: np.ndarray, e: np.ndarray, n: np.ndarray, window_s: float = 60.0,
                         min_move_m: float = 0.5) -> np.ndarray:
    """Cumulative time (s) since the first sample during which the dead reckoning had no velocity reference:
    the DR offsets (``e``, ``n``, m) moved less than ``min_move_m`` within +-``window_s``/2 (unpowered descent
    and ascent: DR held while the vehicle drifts with the currents; a vehicle hovering with a bottom lock is
    counted too, which only overstates the uncertainty)."""
    if ts.size == 0:
        return np.zeros(0)
    dt = np.clip(np.diff(ts, prepend=ts[0]), 0.0, None)
    return np.cumsum(np.where(dr_referenced(ts, e, n, window_s, min_move_m), 0.0, dt))


def dr_referenced(ts: np.ndarray, e: np.ndarray, n: np.ndarray, window_s: float = 60.0,
                  min_move_m: float = 0.5) -> np.ndarray:
    """Per sample: the dead reckoning had a velocity reference (its offsets moved at least ``min_move_m``
    within +-``window_s``/2; see :func:`unreferenced_seconds`)."""
    if ts.size == 0:
        return np.zeros(0, bool)
    h = window_s / 2
    move = np.hypot(np.interp(ts + h, ts, e) - np.interp(ts - h, ts, e),
                    np.interp(ts + h, ts, n) - np.interp(ts - h, ts, n))
    return ~(move < min_move_m)  # NaN moves count as referenced, as before


def navigation_table(ctd: pd.DataFrame, frame: LocalFrame, launch_lat: float, launch_lon: float, *,
                     matched: pd.DataFrame | None = None, fix: dict[str, Any] | None = None,
                     dr_error_fraction: float | None = None, launch_uncertainty_m: float = 10.0,
                     unreferenced_drift_m_per_sqrt_s: float | None = None) -> pd.DataFrame:
    """Best position of every ``ctd`` sample (see module docstring). ``matched``: match's ``matched_track``
    (``time``, ``x_east_m``, ``y_north_m``); ``fix``: its ``fix.json`` (for the radial uncertainty).
    ``dr_error_fraction``, ``unreferenced_drift_m_per_sqrt_s``: default :class:`DeadReckoningOptions`' (the ``match``
    stage's ``Params`` extends it)."""
    if dr_error_fraction is None or unreferenced_drift_m_per_sqrt_s is None:
        from hadal.settings.match import DeadReckoningOptions  # the defaults are declared once, there

        f = DeadReckoningOptions.model_fields
        dr_error_fraction = f["dr_error_fraction"].default if dr_error_fraction is None else dr_error_fraction
        unreferenced_drift_m_per_sqrt_s = (f["dr_unreferenced_drift_m_per_sqrt_s"].default
                                           if unreferenced_drift_m_per_sqrt_s is None
                                           else unreferenced_drift_m_per_sqrt_s)
    n = len(ctd)
    has_t = "time" in ctd
    t = pd.to_datetime(ctd["time"], utc=True).reset_index(drop=True) if has_t else None
    # ns whatever the column's resolution (pandas 3 keeps us/ms/s; tz-aware to_numpy is slow)
    tns = t.dt.as_unit("ns").astype("int64").to_numpy() if has_t else np.zeros(n, np.int64)
    ts = (tns - tns[0]) / 1e9 if n else np.zeros(0)
    lx, ly = (float(v) for v in frame.to_xy(launch_lon, launch_lat))
    e = ctd["dr_east_m"].to_numpy(float) if "dr_east_m" in ctd else np.full(n, np.nan)
    nn = ctd["dr_north_m"].to_numpy(float) if "dr_north_m" in ctd else np.full(n, np.nan)
    have_dr = np.isfinite(e) & np.isfinite(nn)
    # carry the last known DR offset over dropouts (0 = launch point before the first one)
    ef = pd.Series(np.where(have_dr, e, np.nan)).ffill().fillna(0.0).to_numpy()
    nf = pd.Series(np.where(have_dr, nn, np.nan)).ffill().fillna(0.0).to_numpy()
    x, y = lx + ef, ly + nf
    seen = np.cumsum(have_dr) > 0  # a DR offset has been received (held over later dropouts)
    source = np.where(seen, "dead_reckoned", "launch").astype(object)
    dist = _travelled(ef, nf)
    t_unref = unreferenced_seconds(ts, ef, nf)
    unc = np.sqrt(launch_uncertainty_m ** 2 + unreferenced_drift_m_per_sqrt_s ** 2 * t_unref
                  + (dr_error_fraction * dist) ** 2)
    if matched is not None and len(matched) and has_t and n:
        mt = pd.to_datetime(matched["time"], utc=True).dt.as_unit("ns").astype("int64").to_numpy()
        mx, my = matched["x_east_m"].to_numpy(float), matched["y_north_m"].to_numpy(float)
        order = np.argsort(mt, kind="stable")
        mt, mx, my = mt[order], mx[order], my[order]
        k = np.clip(np.searchsorted(mt, tns), 0, mt.size - 1)
        is_m = (mt[k] == tns) & np.isfinite(mx[k]) & np.isfinite(my[k])
        if is_m.any():
            first, last = int(np.argmax(is_m)), int(n - 1 - np.argmax(is_m[::-1]))
            u_fix = float(((fix or {}).get("uncertainty_m") or {}).get("radial") or 0.0)
            cx0, cy0 = mx[k[first]] - x[first], my[k[first]] - y[first]
            cx1, cy1 = mx[k[last]] - x[last], my[k[last]] - y[last]
            c0 = float(np.hypot(cx0, cy0))  # the DR error the match revealed over the descent
            span = ts[first] - ts[0]
            # descent: correction grows linearly in time from 0 at the launch to (cx0, cy0) at the first match;
            # its error is bounded by the revealed DR error times the distance in time to the nearer fix
            w = np.clip((ts[:first] - ts[0]) / span, 0.0, 1.0) if span > 0 else np.ones(first)
            x[:first] += w * cx0
            y[:first] += w * cy0
            unc[:first] = np.hypot((1 - w) * launch_uncertainty_m + w * u_fix, c0 * np.minimum(w, 1 - w))
            x[is_m], y[is_m] = mx[k[is_m]], my[k[is_m]]
            source[is_m] = "matched"
            unc[is_m] = u_fix
            # unmatched bottom samples (altimeter dropouts) and the ascent keep the correction of the last match;
            # their error grows at the DR drift rate the descent revealed (c0 / descent time)
            rest = (np.arange(n) > first) & ~is_m
            x[rest] += cx1
            y[rest] += cy1
            # the larger of the dead-reckoning-only growth restarted at the last fix (random walk over the time
            # without a velocity reference, plus the distance term) and the revealed rate extrapolated linearly
            # (the ascent's drift need not be uniform: the linear rate alone covered 21-23 % of the generated
            # dives' ascent errors within 1 sigma, bench/dr_uncertainty_tercom.py --match)
            rate = c0 / span if span > 0 else 0.0
            grow2 = np.maximum(unreferenced_drift_m_per_sqrt_s ** 2 * np.abs(t_unref[rest] - t_unref[last])
                               + (dr_error_fraction * np.abs(dist[rest] - dist[last])) ** 2,
                               (rate * np.abs(ts[rest] - ts[last])) ** 2)
            unc[rest] = np.sqrt(u_fix ** 2 + grow2)
    lon, lat = frame.to_lonlat(x, y)
    out = pd.DataFrame({"lat": np.asarray(lat, float), "lon": np.asarray(lon, float),
                        "x_east_m": x, "y_north_m": y,
                        "depth_m": ctd["depth_m"].to_numpy(float) if "depth_m" in ctd else np.full(n, np.nan),
                        "position_source": pd.Categorical(source, categories=list(SOURCES)),
                        "position_uncertainty_m": unc})
    if has_t:
        out.insert(0, "time", t)
    if "phase" in ctd:
        out["phase"] = ctd["phase"].astype(str).to_numpy()
    return out


SMOOTHED_FIELDS: dict[str, dict[str, str]] = {
    "position_covariance_east_m2": {"units": "m2", "long_name": "variance of the easting (smoothed position)"},
    "position_covariance_north_m2": {"units": "m2", "long_name": "variance of the northing (smoothed position)"},
    "position_covariance_east_north_m2": {"units": "m2",
                                          "long_name": "covariance of the easting and northing (smoothed position)"},
    "drift_velocity_east_m_s": {"units": "m s-1", "long_name": "smoothed drift velocity (current) the dead reckoning "
                                                               "does not see, east"},
    "drift_velocity_north_m_s": {"units": "m s-1", "long_name": "smoothed drift velocity (current) the dead "
                                                                "reckoning does not see, north"},
}


def _times_ns(ctd: pd.DataFrame) -> np.ndarray:
    return pd.to_datetime(ctd["time"], utc=True).reset_index(drop=True).dt.as_unit("ns").astype("int64").to_numpy()


def smoothed_navigation(ctd: pd.DataFrame, frame: LocalFrame, launch_lat: float, launch_lon: float, *,
                        matched: pd.DataFrame | None = None, fix: dict[str, Any] | None = None,
                        extra_fixes: list | None = None, launch_time: Any = None, options: Any = None,
                        ) -> tuple[pd.DataFrame, Any, dict[str, str]]:
    """The ``navigation`` table by :func:`hadal.navigation.smoother.smooth_positions` (issue 47): every sample's
    smoothed position (``x_east_m``/``y_north_m``/``lat``/``lon``), its 2x2 covariance
    (``position_covariance_*_m2``; ``position_uncertainty_m`` = sqrt(trace), the DRMS) and drift velocity, from
    the launch position, the GNSS/USBL fixes of ``ctd`` (:func:`hadal.navigation.sources.table_fixes`), the
    terrain fix (``fix``) and ``extra_fixes`` (:class:`~hadal.navigation.smoother.Fix`), with the DR offsets and
    the matched track as the process. ``position_source`` and the other columns as :func:`navigation_table`
    (today's adjusted dead reckoning, kept for comparison). Returns (table, :class:`SmoothedTrack`, notes per
    source)."""
    from hadal.navigation.smoother import Fix, smooth_positions
    from hadal.navigation.sources import increments, table_fixes, terrain_fix
    from hadal.settings.navigation import SmootherOptions

    opt = options or SmootherOptions()
    base = navigation_table(ctd, frame, launch_lat, launch_lon, matched=matched, fix=fix)
    n = len(ctd)
    tns = _times_ns(ctd) if "time" in ctd else np.arange(n, dtype=np.int64) * 10**9
    ts = (tns - tns[0]) / 1e9 if n else np.zeros(0)
    e = ctd["dr_east_m"].to_numpy(float) if "dr_east_m" in ctd else np.full(n, np.nan)
    nn = ctd["dr_north_m"].to_numpy(float) if "dr_north_m" in ctd else np.full(n, np.nan)
    have = np.isfinite(e) & np.isfinite(nn)
    ef = pd.Series(np.where(have, e, np.nan)).ffill().fillna(0.0).to_numpy()
    nf = pd.Series(np.where(have, nn, np.nan)).ffill().fillna(0.0).to_numpy()
    is_m = (base["position_source"].astype(str) == "matched").to_numpy()
    mxy = base[["x_east_m", "y_north_m"]].to_numpy(float) if is_m.any() else None
    d, ref = increments(ef, nf, mxy, is_m if is_m.any() else None, dr_referenced(ts, ef, nf))
    times = base["time"] if "time" in base else None
    lx, ly = (float(v) for v in frame.to_xy(launch_lon, launch_lat))
    i0 = 0  # the launch fix at the first sample at or after the launch time (default: the first sample)
    if launch_time is not None and n and "time" in ctd:
        lt = pd.Timestamp(launch_time)
        lt = lt.tz_localize("UTC") if lt.tzinfo is None else lt.tz_convert("UTC")
        i0 = int(min(np.searchsorted(tns, lt.as_unit("ns").value), n - 1))
    fixes = [Fix(i0, lx, ly, np.eye(2) * opt.launch_sigma_m ** 2, "launch", None if times is None else times[i0])]
    flagged = bool(fix and fix.get("mismatch"))  # ambiguous, over holes, at the search edge: not a confident fix
    tf = terrain_fix(fix, int(np.argmax(is_m)), times[int(np.argmax(is_m))] if times is not None else None) \
        if is_m.any() and not flagged else None
    notes = {"launch": f"dive.yaml launch position, 1-sigma {opt.launch_sigma_m:g} m per axis"}
    if tf is not None:
        fixes.append(tf)
        notes["terrain"] = "match fix.json start with its posterior covariance"
    elif flagged:
        notes["terrain"] = ("refused: the terrain fix is flagged as a possible mismatch (its covariance is not a "
                            "confident fix's); the smoother uses the other sources")
    elif is_m.any():
        notes["terrain"] = "refused: fix.json has no usable uncertainty"
    tab, tnotes = table_fixes(ctd, frame, ts, opt, times)
    fixes += tab
    notes.update(tnotes)
    for f in extra_fixes or []:
        fixes.append(f)
    sm = smooth_positions(ts, d, ref, fixes, opt,
                          depth_m=ctd["depth_m"].to_numpy(float) if "depth_m" in ctd else None)
    lon, lat = frame.to_lonlat(sm.x_m, sm.y_m)
    out = base.copy()
    out["lat"], out["lon"] = np.asarray(lat, float), np.asarray(lon, float)
    out["x_east_m"], out["y_north_m"] = sm.x_m, sm.y_m
    out["position_uncertainty_m"] = np.sqrt(sm.cov_m2[:, 0, 0] + sm.cov_m2[:, 1, 1])
    out["position_covariance_east_m2"] = sm.cov_m2[:, 0, 0]
    out["position_covariance_north_m2"] = sm.cov_m2[:, 1, 1]
    out["position_covariance_east_north_m2"] = sm.cov_m2[:, 0, 1]
    out["drift_velocity_east_m_s"] = sm.current_m_s[:, 0]
    out["drift_velocity_north_m_s"] = sm.current_m_s[:, 1]
    return out, sm, notes


def _point(nav: pd.DataFrame, i: int) -> dict[str, Any]:
    """Position, covariance and 1-/2-sigma ellipses (2-D contents 68.3 / 95.4 %) of sample ``i``."""
    from hadal.geo import format_position
    from hadal.navigation.smoother import CHI2_2DOF_1SIGMA, CHI2_2DOF_2SIGMA, ellipse

    r = nav.iloc[i]
    c = np.array([[r["position_covariance_east_m2"], r["position_covariance_east_north_m2"]],
                  [r["position_covariance_east_north_m2"], r["position_covariance_north_m2"]]], float)
    out = {"lat": float(r["lat"]), "lon": float(r["lon"]), "x_east_m": float(r["x_east_m"]),
           "y_north_m": float(r["y_north_m"]), "position_degmin": format_position(float(r["lat"]), float(r["lon"])),
           "covariance_m2": c.tolist(), "drms_m": float(np.sqrt(np.trace(c))),
           "ellipse_1sigma": ellipse(c, CHI2_2DOF_1SIGMA), "ellipse_2sigma": ellipse(c, CHI2_2DOF_2SIGMA)}
    if "time" in nav:
        out["time"] = pd.Timestamp(r["time"]).isoformat()
    if "depth_m" in nav:
        out["depth_m"] = float(r["depth_m"])
    return out


def smoother_summary(nav: pd.DataFrame, sm: Any, notes: dict[str, str]) -> dict[str, Any]:
    """The smoother's record (navigation metadata and manifest summary): the surfacing (last sample) and
    deepest-point positions with their ellipses, every fix's residual and chi-square status, the sources used."""
    fx = sm.fixes
    recs = [{"source": str(r.source), "sample": int(r.index),
             "time": None if r.time is None or pd.isna(r.time) else pd.Timestamp(r.time).isoformat(),
             "residual_east_m": float(r.residual_east_m), "residual_north_m": float(r.residual_north_m),
             "chi2_2dof": None if not np.isfinite(r.d2) else float(r.d2), "status": str(r.status)}
            for r in fx.itertuples()]
    depth = nav["depth_m"].to_numpy(float) if "depth_m" in nav else np.full(len(nav), np.nan)
    out: dict[str, Any] = {
        "method": "Kalman filter + Rauch-Tung-Striebel smoother of position and drift velocity "
                  "(hadal.navigation.smoother)",
        "sources": notes, "gate_chi2_2dof": sm.gate_d2, "fixes": recs, "rejected_fixes": sm.rejected,
        "surfacing": _point(nav, len(nav) - 1) if len(nav) else None,
        "deepest_point": _point(nav, int(np.nanargmax(depth))) if np.isfinite(depth).any() else None,
        "ellipse_comment": "ellipses x' C^-1 x = d2 with d2 = 2.30 (1 sigma, 68.3 % in 2-D) and 6.18 (2 sigma, 95.4 %)",
    }
    return out


def dead_reckoned_lonlat(ctd: pd.DataFrame, frame: LocalFrame, launch_lat: float, launch_lon: float
                         ) -> tuple[np.ndarray, np.ndarray]:
    """(lat, lon) of every ``ctd`` sample by dead reckoning alone (launch + DR offsets; launch where no DR yet):
    the positions ``derive`` can know (``ctd``'s ``lat``/``lon``); ``navigation`` has the matched ones."""
    nav = navigation_table(ctd, frame, launch_lat, launch_lon)
    return nav["lat"].to_numpy(), nav["lon"].to_numpy()


def navigation_summary(nav: pd.DataFrame) -> dict[str, Any]:
    """Counts per source, the uncertainty range and the best position of the surfacing (manifest summary)."""
    src = nav["position_source"].astype(str)
    u = nav["position_uncertainty_m"].to_numpy(float)
    return {"samples": int(len(nav)), "sources": {s: int((src == s).sum()) for s in SOURCES},
            "uncertainty_m": {"min": float(np.nanmin(u)) if len(u) else None,
                              "median": float(np.nanmedian(u)) if len(u) else None,
                              "max": float(np.nanmax(u)) if len(u) else None},
            "surfacing": surfacing_position(nav)}


def surfacing_position(nav: pd.DataFrame) -> dict[str, Any] | None:
    """The best position of the last sample (where the ascent cast ends, the vehicle surfacing): time, lat, lon
    (8 decimals, ~1 mm), its 1-sigma radial uncertainty and source; ``None`` for an empty table."""
    if not len(nav):
        return None
    last = nav.iloc[-1]
    t = last["time"] if "time" in nav else None
    return {"time_utc": pd.Timestamp(t).isoformat() if t is not None and not pd.isna(t) else None,
            "latitude_deg": round(float(last["lat"]), 8), "longitude_deg": round(float(last["lon"]), 8),
            "uncertainty_m": float(last["position_uncertainty_m"]), "source": str(last["position_source"])}


def trajectory_dataset(nav: pd.DataFrame, ctd: pd.DataFrame | None, dive_id: str,
                       columns: tuple[str, ...] = ("pressure_dbar", "temperature_its90_degc", "practical_salinity",
                                                   "conductivity_s_m", "altitude_corrected_m", "seafloor_depth_m",
                                                   "sound_speed_m_s")) -> Any:
    """The dive time series as a CF-1.8 Discrete Sampling Geometry: one trajectory in the contiguous ragged
    array representation (CF §H.4.3): dimension ``obs`` with ``time``/``lat``/``lon``/``depth_m`` coordinates,
    dimension ``traj`` of length 1 with the id variable ``trajectory`` (``cf_role = trajectory_id``, the dive
    id as a NC_CHAR array, :func:`hadal.products.dsg.char_id`) and ``row_size`` (``sample_dimension = obs``:
    every sample), the best positions and, from ``ctd``,
    the listed measurement columns. (A length-1 instance dimension rather than CF §H.4.1's scalar id: IOOS-1.2
    asks the trajectory_id variable for a dimension of length 1, one platform per dataset.)"""
    import xarray as xr

    from hadal.products.compression import gzip_encoding
    from hadal.products.dsg import char_id
    from hadal.registry import variable_attrs

    obs = np.arange(len(nav), dtype="i4")
    t = pd.to_datetime(nav["time"], utc=True).dt.tz_convert(None).to_numpy(dtype="datetime64[ns]")
    coords = {
        "time": ("obs", t, {"standard_name": "time", "long_name": "sample time (UTC)", "axis": "T"}),
        "lat": ("obs", nav["lat"].to_numpy(float), dict(NAV_FIELDS["lat"], axis="Y")),
        "lon": ("obs", nav["lon"].to_numpy(float), dict(NAV_FIELDS["lon"], axis="X")),
        "depth_m": ("obs", nav["depth_m"].to_numpy(float), dict(NAV_FIELDS["depth_m"], axis="Z")),
    }
    src = nav["position_source"].astype(str).to_numpy()
    data = {
        "trajectory": char_id([dive_id], "traj", {"cf_role": "trajectory_id", "long_name": "dive id"}),
        "row_size": (("traj",), np.array([len(obs)], dtype="i4"),
                     {"sample_dimension": "obs", "long_name": "number of observations of the trajectory"}),
        "x_east_m": ("obs", nav["x_east_m"].to_numpy(float), dict(NAV_FIELDS["x_east_m"])),
        "y_north_m": ("obs", nav["y_north_m"].to_numpy(float), dict(NAV_FIELDS["y_north_m"])),
        "position_uncertainty_m": ("obs", nav["position_uncertainty_m"].to_numpy(float),
                                   {"units": "m", "long_name": NAV_FIELDS["position_uncertainty_m"]["long_name"]}),
        **{c: ("obs", nav[c].to_numpy(float), dict(SMOOTHED_FIELDS[c])) for c in SMOOTHED_FIELDS if c in nav},
        "position_source": ("obs", pd.Categorical(src, categories=list(SOURCES)).codes.astype("i1"),
                            {"long_name": "source of the position", "flag_values": np.arange(len(SOURCES), dtype="i1"),
                             "flag_meanings": " ".join(SOURCES)}),
    }
    for c in columns:
        if ctd is not None and c in ctd and len(ctd) == len(nav):
            attrs = {k: v for k, v in variable_attrs(c, where="navigation.nc").items()
                     if k in ("standard_name", "units", "long_name")}
            data[c] = ("obs", ctd[c].to_numpy(float), attrs)
    ds = xr.Dataset(data, coords={**coords, "obs": obs})
    for n in ds.data_vars:
        if ds[n].dims == ("obs",):
            ds[n].attrs["coordinates"] = "time lat lon depth_m"
            ds[n].encoding.update(gzip_encoding((min(len(obs), 1 << 16),) if len(obs) else None))
    for n in ("time", "lat", "lon", "depth_m"):
        ds[n].encoding.update(gzip_encoding())
    return ds


def publish_navigation(ctx: Any, ctd: pd.DataFrame, track: pd.DataFrame | None, fix: dict[str, Any] | None,
                       upstream: list[Any], dr_error_fraction: float,
                       unreferenced_drift_m_per_sqrt_s: float | None = None, smoother: Any = None) -> Any:
    """Publish the ``navigation`` product (``navigation.parquet`` + CF trajectory ``navigation.nc`` + the track as
    GeoJSON, ``navigation_track.geojson``) of a stage context ``ctx`` (``match`` calls it after publishing
    ``match``): the smoothed positions and their covariances (:func:`smoothed_navigation`; ``smoother``: its
    :class:`~hadal.settings.navigation.SmootherOptions`). Returns the ProductVersion."""
    from hadal.products.io import write_netcdf, write_parquet

    launch = ctx.dive.require_launch("navigation")
    frame = ctx.dive.frame()
    from hadal.settings.navigation import SmootherOptions

    opt = smoother or SmootherOptions()
    nav, sm, notes = smoothed_navigation(ctd, frame, launch.latitude_deg, launch.longitude_deg, matched=track,
                                         fix=fix, launch_time=launch.time_utc, options=opt)
    for w in sm.rejected:
        ctx.log.warning("navigation: fix %s rejected: inconsistent with the other sources (chi-square gate %.1f)",
                        w, sm.gate_d2)
    summary = navigation_summary(nav)
    summary["smoother"] = smoother_summary(nav, sm, notes)
    meta = {"dive_id": ctx.dive_id, "summary": summary, "method": "Kalman filter + RTS smoother over every "
            "position source (hadal.navigation.smoother)",
            "map_frame": {"origin_latitude_deg": frame.origin_latitude_deg,
                          "origin_longitude_deg": frame.origin_longitude_deg, "crs_wkt": frame.crs.to_wkt()}}
    with ctx.store.publish(ctx.dive_id, "navigation", parameters={"dr_error_fraction": dr_error_fraction,
                                                         "unreferenced_drift_m_per_sqrt_s": unreferenced_drift_m_per_sqrt_s,
                                                         "smoother": opt.model_dump()},
                           upstream=upstream, extra={"summary": summary}) as draft:
        write_parquet(nav, draft.path / "navigation.parquet", fields={**NAV_FIELDS, **SMOOTHED_FIELDS},
                      metadata=meta, provenance_from=draft)
        write_netcdf(trajectory_dataset(nav, ctd, ctx.dive_id), draft.path / "navigation.nc",
                     title=f"Best vehicle position and CTD time series of dive {ctx.dive_id}",
                     summary=("The dive's time series as a CF trajectory: for every sample the best position "
                              "(Kalman filter + RTS smoother over the launch position, GNSS/USBL fixes, the terrain "
                              "fix and the dead-reckoned / terrain-matched track), its 2x2 covariance, 1-sigma "
                              "radial uncertainty and source, and the CTD measurements."),
                     keywords="navigation, trajectory, terrain-aided navigation, CTD, deep-sea vehicle",
                     featureType="trajectory", cdm_data_type="Trajectory", processing_level="L2 navigation",
                     provenance_from=draft, dive_id=ctx.dive_id)
        from hadal.products import geoparquet  # the track for GIS (GeoJSON)

        geoparquet.write_navigation_track(nav, draft.path / geoparquet.TRACK_FILE, ctx.dive_id)
    return draft.result


#: ``ctd``'s per-sample position columns (derive runs before match: dead reckoning only)
CTD_POSITION_FIELDS: dict[str, dict[str, str]] = {
    "lat": {"standard_name": "latitude", "units": "degrees_north",
            "long_name": "dead-reckoned latitude (launch + DR offsets; terrain-matched positions: navigation product)"},
    "lon": {"standard_name": "longitude", "units": "degrees_east",
            "long_name": "dead-reckoned longitude (launch + DR offsets; terrain-matched positions: navigation product)"},
}
