"""Dive summary numbers for the report (TERCOM paper §4.2.1-§4.3 quantities, landing-site table).

Every value is taken from a product when that product has it and is ``None`` otherwise; the source of
each number is recorded next to it so the report can say where it came from.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd

from hadal.geo import format_position, geodesic_distance_m
from hadal.products.geo_landing import iso_utc
from hadal.report.load import DiveProducts


def _f(v: Any) -> float | None:
    try:
        x = float(v)
    except (TypeError, ValueError):
        return None
    return x if math.isfinite(x) else None


def _phase_durations(ctd: pd.DataFrame) -> dict[str, float]:
    """Seconds spent in each phase (descent/bottom/ascent), TERCOM paper §4.2.1 (3 h 35 min descent...)."""
    if "phase" not in ctd or "time" not in ctd:
        return {}
    t = pd.to_datetime(ctd["time"], utc=True)
    if t.isna().all():  # a cast without time channel
        return {}
    out = {}
    for ph, grp in t.groupby(ctd["phase"].astype(str)):
        if len(grp) > 1:
            out[str(ph)] = float((grp.max() - grp.min()).total_seconds())
    order = {"descent": 0, "bottom": 1, "ascent": 2}
    return dict(sorted(out.items(), key=lambda kv: order.get(kv[0], 9)))


#: QARTOD flag values and their meanings (ioos_qc, QARTOD manual)
QARTOD_FLAGS = {1: "good", 2: "not evaluated", 3: "suspect", 4: "fail", 9: "missing"}


def qc_flag_table(table: pd.DataFrame) -> list[dict[str, Any]]:
    """Per ``<variable>_qc`` column of ``table``: the count of each QARTOD flag and the share flagged 3 or 4 among
    the non-missing samples (the report's flag summary)."""
    rows = []
    for col in table.columns:
        if not str(col).endswith("_qc"):
            continue
        f = pd.to_numeric(table[col], errors="coerce").fillna(9).astype(int).to_numpy()
        row: dict[str, Any] = {"variable": str(col)[:-3]}
        for k, name in QARTOD_FLAGS.items():
            row[name] = int((f == k).sum())
        valid = len(f) - row["missing"]
        row["flagged %"] = round(100.0 * (row["suspect"] + row["fail"]) / valid, 3) if valid else 0.0
        rows.append(row)
    return rows


def dive_summary(dp: DiveProducts, launch: dict[str, float] | None = None, best_sites: int = 5) -> dict[str, Any]:
    """Headline numbers: max depth (and when), deepest point position, drift, match quality, best landing sites.

    ``launch`` (``{"lat": ..., "lon": ...}``) comes from the dive description when available, else from
    ``fix.json``. Drift is the geodesic distance from the launch point to the matched start of the bottom
    track (TERCOM paper §4.3: 533 m).
    """
    s: dict[str, Any] = {"dive": dp.dive, "products": {p: v.label for p, v in dp.versions.items()},
                         "missing_products": dp.missing, "notes": list(dp.notes)}
    fix = dp.fix or {}
    _ctd_summary(s, dp.ctd)
    _casts_summary(s, dp)
    _dtm_summary(s, dp)
    _position_summary(s, dp, fix, launch)
    _match_summary(s, dp, fix)
    _landing_summary(s, dp, best_sites)
    return s


def _ctd_summary(s: dict[str, Any], ctd: pd.DataFrame | None) -> None:
    """Depth, ranges, phases, QC flags and time span of the dive's own CTD (:func:`dive_summary`)."""
    # ---- depth
    if ctd is not None and "depth_m" in ctd and len(ctd):
        d = pd.to_numeric(ctd["depth_m"], errors="coerce")
        if d.notna().any():
            i = int(d.idxmax())
            s["max_depth_m"] = float(d.loc[i])
            s["max_depth_source"] = "ctd.depth_m (hydrostatic)"
            if "time" in ctd and pd.notna(ctd.loc[i, "time"]):
                s["max_depth_time_utc"] = iso_utc(ctd.loc[i, "time"])
            if "pressure_dbar" in ctd and pd.notna(ctd.loc[i, "pressure_dbar"]):
                s["max_depth_pressure_dbar"] = float(ctd.loc[i, "pressure_dbar"])
        if "seafloor_depth_m" in ctd:
            sf = pd.to_numeric(ctd["seafloor_depth_m"], errors="coerce")
            if sf.notna().any():
                s["max_seafloor_depth_m"] = float(sf.max())
        for col in ("pressure_dbar", "temperature_its90_degc", "practical_salinity", "density_kg_m3"):
            if col in ctd:
                v = pd.to_numeric(ctd[col], errors="coerce")
                if v.notna().any():
                    s[f"{col}_range"] = [float(v.min()), float(v.max())]
        s["phase_durations_s"] = _phase_durations(ctd)
        s["qc_flags"] = qc_flag_table(ctd)
        t = pd.to_datetime(ctd["time"], utc=True) if "time" in ctd else None
        if t is not None and t.notna().any():
            s["start_utc"], s["end_utc"] = iso_utc(t.min()), iso_utc(t.max())
            s["duration_s"] = float((t.max() - t.min()).total_seconds())
        elif t is not None:
            s["time_base"] = "none (pressure-binned cast): CTD figures against pressure/depth"
        track = [c for c in ("dr_east_m", "altitude_m") if c in ctd]
        s["cast_only"] = not any(pd.to_numeric(ctd[c], errors="coerce").notna().any() for c in track)


def _casts_summary(s: dict[str, Any], dp: DiveProducts) -> None:
    """The external Sea-Bird casts (:func:`dive_summary`)."""
    # ---- external casts (Sea-Bird casts next to the dive's own CTD)
    if dp.casts:
        s["casts"] = [{"cast": c.get("cast_id"), "start_utc": c.get("start_time_utc"),
                       "lat": _f(c.get("latitude_deg")), "lon": _f(c.get("longitude_deg")),
                       "samples": c.get("samples", c.get("rows")),
                       "max_depth_m": _f((c.get("deepest_point") or {}).get("depth_m")),
                       "max_pressure_dbar": _f((c.get("deepest_point") or {}).get("pressure_dbar")),
                       "latitude_source": c.get("latitude_source")} for c in dp.casts]
    # ---- underway records (trajectories: thermosalinographs)
    if dp.trajectories:
        s["underway"] = [{"record": r.get("record_id"), "instrument": r.get("instrument"), "scans": r.get("scans"),
                          "start_utc": r.get("time_coverage_start"), "end_utc": r.get("time_coverage_end"),
                          "track_length_km": _f(r.get("track_length_km")),
                          "latitude_range_deg": r.get("latitude_range_deg"),
                          "longitude_range_deg": r.get("longitude_range_deg"),
                          "practical_salinity_range": r.get("practical_salinity_range")} for r, _ in dp.trajectories]


def _dtm_summary(s: dict[str, Any], dp: DiveProducts) -> None:
    """The reference terrain (:func:`dive_summary`)."""
    # ---- reference terrain
    if dp.dtm is not None and "depth_m" in dp.dtm:
        z = dp.dtm["depth_m"].values
        fin = np.isfinite(z)
        if fin.any():
            s["dtm"] = {"source": str(dp.dtm.attrs.get("dtm_source", "multibeam")), "cells": [int(v) for v in z.shape],
                        "resolution_m": _f(dp.dtm.attrs.get("resolution", dp.dtm.attrs.get("resolution_m"))),
                        "depth_range_m": [float(np.nanmin(z)), float(np.nanmax(z))],
                        "mapped_fraction": float(fin.mean()),
                        "soundings": _f(dp.dtm.attrs.get("n_soundings_used"))}


def _position_summary(s: dict[str, Any], dp: DiveProducts, fix: dict[str, Any],
                      launch: dict[str, float] | None) -> None:
    """Deepest point position, launch, matched start and drift (:func:`dive_summary`)."""
    # ---- deepest point position (matched) and drift
    deep = fix.get("deepest_point") if isinstance(fix.get("deepest_point"), dict) else None
    if deep and _f(deep.get("lat")) is not None and _f(deep.get("lon")) is not None:
        s["deepest_point"] = {"lat": _f(deep["lat"]), "lon": _f(deep["lon"]),
                              "depth_m": _f(deep.get("depth_m")), "seafloor_depth_m": _f(deep.get("seafloor_depth_m")),
                              "position_degmin": deep.get("position_degmin") or format_position(deep["lat"], deep["lon"]),
                              "source": "match fix.json"}
    elif dp.track is not None and {"lat", "lon", "depth_m"} <= set(dp.track.columns) and len(dp.track):
        i = int(pd.to_numeric(dp.track["depth_m"], errors="coerce").idxmax())
        r = dp.track.loc[i]
        s["deepest_point"] = {"lat": float(r["lat"]), "lon": float(r["lon"]), "depth_m": float(r["depth_m"]),
                              "position_degmin": format_position(float(r["lat"]), float(r["lon"])),
                              "source": "match matched_track.parquet"}
    if launch is None and isinstance(fix.get("launch"), dict):
        launch = {"lat": _f(fix["launch"].get("lat")), "lon": _f(fix["launch"].get("lon"))}
    if launch and launch.get("lat") is not None and launch.get("lon") is not None:
        s["launch"] = {"lat": launch["lat"], "lon": launch["lon"],
                       "position_degmin": format_position(launch["lat"], launch["lon"])}
    from hadal.report.geo_figures import surfacing_position

    surf = surfacing_position(dp.navigation)
    if surf is not None:
        dec = 3 if surf.get("uncertainty_m") is None else None
        from hadal.report.units import coordinate_decimals

        dec = dec if dec is not None else coordinate_decimals(float(surf["uncertainty_m"]), "min")
        s["surfacing"] = {**surf, "position_degmin": format_position(surf["lat"], surf["lon"], decimals=dec),
                          "source": "navigation (last sample of the ascent)"}
    if (casts := cast_positions(dp.profile)):
        s["cast_positions"] = casts
    start = fix.get("start") if isinstance(fix.get("start"), dict) else None
    if start and _f(start.get("lat")) is not None:
        s["matched_start"] = {"lat": _f(start["lat"]), "lon": _f(start["lon"]),
                              "position_degmin": start.get("position_degmin") or format_position(start["lat"], start["lon"])}
    if _f(fix.get("drift_m")) is not None:
        s["drift_m"] = _f(fix["drift_m"])
    elif "launch" in s and "matched_start" in s:
        s["drift_m"] = float(geodesic_distance_m(s["launch"]["lon"], s["launch"]["lat"],
                                                 s["matched_start"]["lon"], s["matched_start"]["lat"]))


def _match_summary(s: dict[str, Any], dp: DiveProducts, fix: dict[str, Any]) -> None:
    """Match quality and the RMS depth residual along the matched track (:func:`dive_summary`)."""
    # ---- match quality
    if fix:
        unc = fix.get("uncertainty_m") if isinstance(fix.get("uncertainty_m"), dict) else {}
        second = fix.get("second_optimum") if isinstance(fix.get("second_optimum"), dict) else {}
        s["match"] = {
            "criterion": fix.get("criterion"), "score": _f(fix.get("score")), "bias_m": _f(fix.get("bias_m")),
            "uncertainty_radial_m": _f(unc.get("radial")), "separation_ratio": _f(second.get("separation_ratio")),
            "mismatch": bool(fix.get("mismatch")) if fix.get("mismatch") is not None else None,
            "n_samples": fix.get("n_samples"), "warnings": list(fix.get("warnings") or []),
        }
    if dp.track is not None and {"seafloor_depth_m", "map_depth_m"} <= set(dp.track.columns):
        diff = pd.to_numeric(dp.track["map_depth_m"], errors="coerce") - pd.to_numeric(dp.track["seafloor_depth_m"], errors="coerce")
        if "map_depth_minus_bias_m" in dp.track:
            diff = pd.to_numeric(dp.track["map_depth_minus_bias_m"], errors="coerce") - pd.to_numeric(dp.track["seafloor_depth_m"], errors="coerce")
        diff = diff[np.isfinite(diff)]
        if len(diff):
            s.setdefault("match", {})["rms_depth_residual_m"] = float(np.sqrt(np.mean(diff**2)))


def _landing_summary(s: dict[str, Any], dp: DiveProducts, best_sites: int) -> None:
    """The best landing sites (:func:`dive_summary`)."""
    # ---- landing
    sites = dp.landing_sites
    if sites is not None and len(sites):
        best = sites[sites["is_best"].astype(bool)] if "is_best" in sites else sites
        if "c_s" in best:
            best = best.sort_values("c_s")
        keep = [c for c in ("submap", "heading_deg", "x_m", "y_m", "lat", "lon", "heading_true_deg", "radius_m",
                            "slope_deg", "roughness_m", "c_s")
                if c in best.columns]
        s["best_landing_sites"] = [{k: (v.item() if hasattr(v, "item") else v) for k, v in row.items()}
                                   for row in best[keep].head(best_sites).to_dict(orient="records")]
        s["n_candidate_sites"] = int(len(sites))
    if dp.landing_summary and isinstance(dp.landing_summary.get("table_v"), dict):
        s["landing_table_v"] = dp.landing_summary["table_v"]


def cast_positions(profile: Any) -> list[dict[str, Any]]:
    """Per cast of ``profile.nc`` (CF ragged, ``cast_position_source`` flags of :func:`hadal.products.dsg.place_casts`):
    its name, lat/lon, position source and 1-sigma radial uncertainty, the position at the precision of that
    uncertainty (:func:`hadal.report.units.coordinate_decimals`; 3 decimal minutes without one). Empty without
    placed casts."""
    from hadal.report.units import coordinate_decimals

    if profile is None or "cast_position_source" not in profile.variables or "lat" not in profile.variables:
        return []
    dim = profile["cast_position_source"].dims[0]
    if profile["lat"].dims != (dim,):
        return []
    sources = str(profile["cast_position_source"].attrs.get("flag_meanings", "")).split()
    names = str(profile["cast"].attrs.get("flag_meanings", "")).split() if "cast" in profile.variables else []
    out = []
    for i in range(profile.sizes[dim]):
        lat, lon = _f(profile["lat"].values[i]), _f(profile["lon"].values[i])
        if lat is None or lon is None:
            continue
        k = int(profile["cast_position_source"].values[i])
        unc = _f(profile["position_uncertainty_m"].values[i]) if "position_uncertainty_m" in profile else None
        label = profile["cast"].values[i] if "cast" in profile.variables else f"cast {i}"
        if isinstance(label, (int, np.integer)):  # the ragged file's CF flags
            label = names[int(label)] if 0 <= int(label) < len(names) else f"cast {i}"
        dec = coordinate_decimals(unc, "min") if unc is not None else 3
        out.append({"cast": str(label), "lat": lat, "lon": lon,
                    "source": sources[k] if 0 <= k < len(sources) else "unknown", "uncertainty_m": unc,
                    "position_degmin": format_position(lat, lon, decimals=dec)})
    return out
