"""Position sources as sensors for :func:`hadal.navigation.smoother.smooth_positions` (issue 47).

* the launch position (``dive.yaml`` ``launch``: the GNSS fix taken as the vehicle dives), 1-sigma
  ``launch_sigma_m`` per axis;
* GNSS fixes logged by the vehicle (``gnss_latitude_deg``/``gnss_longitude_deg`` of the sensor table; a ROS 2
  ``sensor_msgs/NavSatFix`` is mapped to them by ``hadal init``), with their covariance
  (``gnss_east_variance_m2``/``gnss_north_variance_m2``: NavSatFix ``position_covariance[0]``/``[4]``, ENU),
  else ``gnss_hdop`` x ``gnss_uere_m``, else ``gnss_sigma_m``; used only where the vehicle is at the surface
  (``depth_m`` <= ``gnss_max_depth_m``): a submerged vehicle has no GNSS;
* USBL/LBL fixes (``usbl_latitude_deg``/``usbl_longitude_deg``, ``usbl_east_variance_m2``/
  ``usbl_north_variance_m2`` else ``usbl_sigma_m``), at any depth;
* the terrain fix (``match``'s ``fix.json``: the matched position of the first bottom sample with the
  posterior's full 2x2 covariance ``uncertainty_m.covariance_m2``, else the east/north 1-sigma); refused, with a
  note, when ``fix.json`` flags a possible mismatch (ambiguous, over holes, at the search edge: its covariance is
  not a confident fix's);
* dead reckoning (``dr_east_m``/``dr_north_m``) and, on the bottom, the terrain-matched track (the DR with the
  match's heading, scale and drift corrections) as the process increments.

Each source keeps at most one fix per ``fix_min_interval_s`` (the sensor table repeats a 1 Hz fix at the
CTD's rate; the copies are not independent measurements).
"""

from __future__ import annotations

from typing import Any

import numpy as np
import pandas as pd

from hadal.geo import LocalFrame
from hadal.navigation.smoother import Fix
from hadal.settings.navigation import SmootherOptions

#: sensor-table columns of the fix sources: (latitude, longitude, east variance, north variance, hdop)
FIX_COLUMNS = {
    "gnss": ("gnss_latitude_deg", "gnss_longitude_deg", "gnss_east_variance_m2", "gnss_north_variance_m2", "gnss_hdop"),
    "usbl": ("usbl_latitude_deg", "usbl_longitude_deg", "usbl_east_variance_m2", "usbl_north_variance_m2", None),
}


def thin_times(t_s: np.ndarray, min_interval_s: float) -> np.ndarray:
    """Indices into ``t_s`` (sorted) keeping the first sample and then one at least ``min_interval_s`` later."""
    keep, last = [], -np.inf
    for i, t in enumerate(np.asarray(t_s, float)):
        if t - last >= min_interval_s:
            keep.append(i)
            last = t
    return np.asarray(keep, np.int64)


def _col(df: pd.DataFrame, name: str | None) -> np.ndarray | None:
    return df[name].to_numpy(float) if name and name in df else None


def table_fixes(ctd: pd.DataFrame, frame: LocalFrame, t_s: np.ndarray, options: SmootherOptions,
                times: Any = None) -> tuple[list[Fix], dict[str, str]]:
    """GNSS and USBL fixes of the sensor/CTD table ``ctd`` (module docstring); ``t_s`` its sample times (s).
    Returns the fixes and, per source present, what was used or refused and why."""
    fixes: list[Fix] = []
    notes: dict[str, str] = {}
    depth = ctd["depth_m"].to_numpy(float) if "depth_m" in ctd else np.full(len(ctd), np.nan)
    for src, (clat, clon, cve, cvn, chdop) in FIX_COLUMNS.items():
        lat, lon = _col(ctd, clat), _col(ctd, clon)
        if lat is None or lon is None:
            continue
        ok = np.isfinite(lat) & np.isfinite(lon)
        n_all = int(ok.sum())
        if src == "gnss":
            ok &= np.isfinite(depth) & (depth <= options.gnss_max_depth_m)
        idx = np.flatnonzero(ok)
        idx = idx[thin_times(t_s[idx], options.fix_min_interval_s)] if idx.size else idx
        ve, vn, hdop = _col(ctd, cve), _col(ctd, cvn), _col(ctd, chdop)
        x, y = frame.to_xy(lon[idx], lat[idx])
        x, y = np.atleast_1d(np.asarray(x, float)), np.atleast_1d(np.asarray(y, float))
        for j, i in enumerate(idx):
            if ve is not None and vn is not None and np.isfinite(ve[i]) and np.isfinite(vn[i]) \
                    and ve[i] > 0 and vn[i] > 0:
                cov = np.diag([ve[i], vn[i]])
            elif hdop is not None and np.isfinite(hdop[i]) and hdop[i] > 0:
                cov = np.eye(2) * (hdop[i] * options.gnss_uere_m) ** 2
            else:
                cov = np.eye(2) * (options.gnss_sigma_m if src == "gnss" else options.usbl_sigma_m) ** 2
            fixes.append(Fix(int(i), float(x[j]), float(y[j]), cov, src,
                             None if times is None else times[int(i)]))
        notes[src] = (f"{idx.size} fixes used (one per {options.fix_min_interval_s:g} s) of {n_all} samples"
                      + (f"; fixes deeper than {options.gnss_max_depth_m:g} m refused (no GNSS under water)"
                         if src == "gnss" and n_all > int(ok.sum()) else ""))
    return fixes, notes


def terrain_fix(fix: dict[str, Any] | None, index: int, time: Any = None) -> Fix | None:
    """The terrain fix of ``match``'s ``fix.json`` at sample ``index`` (the first matched bottom sample): the
    matched start with the posterior covariance (``uncertainty_m.covariance_m2``), else the east/north 1-sigma
    (``posterior: false``); None without a usable uncertainty."""
    if not fix or "start" not in fix:
        return None
    u = fix.get("uncertainty_m") or {}
    cov = u.get("covariance_m2")
    if cov is not None:
        c = np.asarray(cov, float)
    else:
        e, n = u.get("east"), u.get("north")
        if e is None or n is None:
            r = u.get("radial")
            if r is None:
                return None
            e = n = float(r) / np.sqrt(2.0)
        c = np.diag([float(e) ** 2, float(n) ** 2])
    if c.shape != (2, 2) or not np.isfinite(c).all() or np.linalg.eigvalsh(c)[0] <= 0:
        return None
    return Fix(int(index), float(fix["start"]["x_east_m"]), float(fix["start"]["y_north_m"]), c, "terrain", time)


def increments(e: np.ndarray, n: np.ndarray, matched_xy: np.ndarray | None, is_matched: np.ndarray | None,
               referenced_dr: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Process increments (n, 2) and the per-step ``referenced`` flag: the DR offsets' steps (``e``, ``n``,
    forward-filled, m), replaced by the matched track's steps where both ends are matched samples (the DR with
    the terrain match's heading/scale/drift corrections); such steps are referenced, as are DR steps with a
    velocity reference (``referenced_dr``)."""
    d = np.column_stack([np.diff(e, prepend=e[:1]), np.diff(n, prepend=n[:1])])
    ref = np.asarray(referenced_dr, bool).copy()
    if matched_xy is not None and is_matched is not None:
        both = is_matched & np.concatenate([[False], is_matched[:-1]])
        dm = np.diff(matched_xy, axis=0, prepend=matched_xy[:1])
        d[both] = dm[both]
        ref |= both
    d[~np.isfinite(d)] = 0.0
    return d, ref


def body_to_enu(forward_m_s: np.ndarray, left_m_s: np.ndarray, heading_deg: np.ndarray,
                cov_body_m2_s2: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray | None]:
    """Horizontal velocities of the vehicle frame (ROS REP 103 body axes: x forward, y left; e.g. a DVL's
    ``TwistWithCovarianceStamped`` in ``base_link``) to east/north with the heading (deg clockwise from true
    north): ``v_e = f sin h - l cos h``, ``v_n = f cos h + l sin h``; the 2x2 covariance (n, 2, 2) rotated as
    ``R C R'``. Returns ((n, 2) east/north m/s, covariance or None). Pitch and roll are neglected (the horizontal
    projection of a level vehicle's velocity)."""
    h = np.radians(np.asarray(heading_deg, float))
    sh, ch = np.sin(h), np.cos(h)
    f, left = np.asarray(forward_m_s, float), np.asarray(left_m_s, float)
    v = np.column_stack([f * sh - left * ch, f * ch + left * sh])
    if cov_body_m2_s2 is None:
        return v, None
    R = np.stack([np.stack([sh, -ch], -1), np.stack([ch, sh], -1)], -2)  # (n, 2, 2)
    C = np.asarray(cov_body_m2_s2, float).reshape(-1, 2, 2)
    return v, R @ C @ np.swapaxes(R, -1, -2)


def velocity_increments(t_s: np.ndarray, v_enu_m_s: np.ndarray, cov_m2_s2: np.ndarray | None,
                        over_ground: np.ndarray | bool, sigma_m_s: float
                        ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Process increments of :func:`~hadal.navigation.smoother.smooth_positions` from measured east/north
    velocities ``v_enu_m_s`` (n, 2; DVL bottom- or water-track): the step to sample ``k`` is
    ``v_{k-1} dt_k`` (the velocity at the step's start: with white velocity noise the steps' errors are then
    independent, as the smoother's process model assumes) with covariance ``C_{k-1} dt_k^2`` (``cov_m2_s2``
    (n, 2, 2), a ``TwistWithCovarianceStamped``'s linear x/y block rotated to east/north; NaN or missing:
    ``sigma_m_s`` per axis).

    ``over_ground`` (bool or (n,) bool): bottom track, the velocity over ground, a referenced step (the current
    is not added); water track (False), the velocity through the water, an unreferenced step (the smoother adds
    the current state, so the same drift model as the DR-held descent applies). Returns ``(d (n, 2),
    referenced (n,), cov (n, 2, 2), valid (n,))``; ``valid`` False where the step has no finite velocity (the
    caller keeps its DR increment there)."""
    t_s = np.asarray(t_s, float)
    n = t_s.size
    v = np.asarray(v_enu_m_s, float).reshape(n, 2)
    dt = np.clip(np.diff(t_s, prepend=t_s[:1]), 0.0, None)
    v0 = np.vstack([np.full((1, 2), np.nan), v[:-1]]) if n else v
    valid = np.isfinite(v0).all(axis=1)
    d = np.where(valid[:, None], np.nan_to_num(v0) * dt[:, None], 0.0)
    if cov_m2_s2 is None:
        C = np.full((n, 2, 2), np.nan)
    else:
        C = np.asarray(cov_m2_s2, float).reshape(n, 2, 2)
    C0 = np.concatenate([np.full((1, 2, 2), np.nan), C[:-1]]) if n else C
    bad = ~np.isfinite(C0).all(axis=(1, 2)) | (C0[:, 0, 0] <= 0) | (C0[:, 1, 1] <= 0)
    C0 = np.where(bad[:, None, None], np.eye(2) * sigma_m_s ** 2, C0)
    cov = np.where(valid[:, None, None], C0 * (dt ** 2)[:, None, None], 0.0)
    og = np.broadcast_to(np.asarray(over_ground, bool), (n,))
    og0 = np.concatenate([[True], og[:-1]]) if n else og
    return d, valid & og0, cov, valid


def pose_fixes(t_s: np.ndarray, x_east_m: np.ndarray, y_north_m: np.ndarray, cov_m2: np.ndarray | None,
               sigma_m: float, min_interval_s: float, source: str = "pose", times: Any = None) -> list[Fix]:
    """Absolute positions in the map frame (a ``PoseWithCovarianceStamped`` of an INS/LBL/acoustic positioning
    solution, its position x/y east/north of the map-frame origin, REP 103) as fixes with their 2x2 covariance
    (``cov_m2`` (n, 2, 2): the pose covariance's x/y block; non-finite or not positive definite: ``sigma_m`` per
    axis), at most one per ``min_interval_s`` (a fix repeated at a higher rate is not a new measurement)."""
    t_s = np.asarray(t_s, float)
    x, y = np.asarray(x_east_m, float), np.asarray(y_north_m, float)
    idx = np.flatnonzero(np.isfinite(x) & np.isfinite(y))
    idx = idx[thin_times(t_s[idx], min_interval_s)] if idx.size else idx
    out = []
    for i in idx:
        c = np.eye(2) * sigma_m ** 2
        if cov_m2 is not None:
            ci = np.asarray(cov_m2[i], float).reshape(2, 2)
            if np.isfinite(ci).all() and np.linalg.eigvalsh(0.5 * (ci + ci.T))[0] > 0:
                c = 0.5 * (ci + ci.T)
        out.append(Fix(int(i), float(x[i]), float(y[i]), c, source, None if times is None else times[int(i)]))
    return out
