"""Geographic report figures: the dive on the reference terrain in longitude/latitude.

* :func:`fig_overview` - hillshaded DTM with depth contours on lon/lat axes (equal ground distances: the aspect is
  1/cos(latitude)), a scale bar, the best track of the whole dive (``navigation``), the dead-reckoning-only track,
  the launch point, the matched start of the bottom track with its 1-sigma and 2-sigma uncertainty ellipses
  (``fix.json`` ``uncertainty_m.ellipse_*``, about ``profile_start``), the posterior's second mode when it holds
  more than 1 % of the mass, and the deepest point.
* :func:`fig_residuals` - measured and reference seafloor depth along the matched track, with the residual
  (measured - (map - bias)) in a panel under it.
* :func:`fig_dtm_geo`, :func:`fig_dtm_quality`, :func:`fig_suitability_geo`, :func:`fig_msd_geo` (TERCOM's criterion
  surface) and :func:`fig_matched_track_geo` (TERCOM Fig. 17) - every map of the report on lon/lat axes from the
  product's map frame (``map_frame_origin_*``), with the dive's track, a scale bar clear of insets and the
  degrees-and-minutes graticule.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
import pandas as pd
from matplotlib.colors import LightSource
from matplotlib.figure import Figure

from hadal.report.figures import (
    CMAPS,
    FigureOptions,
    FigureResult,
    _plot_track_depths,
    _render,
    _thin,
    _track_depths,
)
from hadal.report.load import DiveProducts


def _frame(dp: DiveProducts) -> Any:
    from hadal.geo import LocalFrame

    for ds in (dp.dtm, dp.suitability, dp.msd):
        if ds is not None and "map_frame_origin_latitude_deg" in ds.attrs:
            return LocalFrame(float(ds.attrs["map_frame_origin_latitude_deg"]),
                              float(ds.attrs["map_frame_origin_longitude_deg"]))
    return None


def _second_mode(fix: dict[str, Any]) -> dict[str, Any] | None:
    sm = ((fix or {}).get("posterior") or {}).get("second_mode")
    if isinstance(sm, dict) and sm.get("x") is not None and float(sm.get("mass") or 0) > 0.01:
        return sm
    return None


def _nice_length(m: float) -> float:
    """A 1-2-5 length close to ``m`` (scale bars)."""
    e = 10 ** math.floor(math.log10(m))
    return max(v * e for v in (1, 2, 5) if v * e <= m) if m > 0 else 1.0


def _scale_bar(ax, lat0: float, avoid: list[float] | None = None) -> Any:
    """A 1-2-5 scale bar in the lower left corner of a lon/lat map, or the lower right one when ``avoid`` (an inset's
    box, axes fraction x0, y0, w, h) covers the lower left; returns its label (a Text)."""
    x0, x1 = ax.get_xlim()
    y0, y1 = ax.get_ylim()
    m_per_deg_lon = 111_320.0 * math.cos(math.radians(lat0))
    width_m = (x1 - x0) * m_per_deg_lon
    L = _nice_length(width_m / 5)
    dlon = L / m_per_deg_lon
    fx = 0.05
    if avoid is not None and avoid[0] < 0.3 and avoid[1] < 0.2:  # the inset sits in the lower left corner
        fx = 0.95 - dlon / (x1 - x0)
    bx, by = x0 + fx * (x1 - x0), y0 + 0.06 * (y1 - y0)
    ax.plot([bx, bx + dlon], [by, by], "-", color="k", lw=4, solid_capstyle="butt")
    ax.plot([bx, bx + dlon], [by, by], "-", color="w", lw=2, solid_capstyle="butt")
    return ax.text(bx + dlon / 2, by + 0.02 * (y1 - y0), f"{L / 1000:g} km" if L >= 1000 else f"{L:g} m",
                   ha="center", va="bottom", fontsize=9, bbox={"fc": "w", "ec": "none", "alpha": 0.7, "pad": 1},
                   gid="scale_bar")


#: inset corners (axes fraction: x0, y0, width, height), tried in this order
_INSET_CORNERS = ((0.64, 0.03), (0.02, 0.03), (0.64, 0.67), (0.02, 0.67))
_INSET_SIZE = (0.34, 0.30)


def _emptiest_corner(lines, lon_lim: tuple[float, float], lat_lim: tuple[float, float]) -> list[float]:
    """The inset box (axes fraction) over the fewest points of the plotted tracks and markers, so the zoom on the
    fix does not hide them (ties: the first of :data:`_INSET_CORNERS`, lower right)."""
    pts = [np.column_stack([np.asarray(ln.get_xdata(), float), np.asarray(ln.get_ydata(), float)]) for ln in lines]
    xy = np.concatenate(pts) if pts else np.empty((0, 2))
    xy = xy[np.isfinite(xy).all(axis=1)]
    u = (xy[:, 0] - lon_lim[0]) / max(lon_lim[1] - lon_lim[0], 1e-12)
    v = (xy[:, 1] - lat_lim[0]) / max(lat_lim[1] - lat_lim[0], 1e-12)
    w, h = _INSET_SIZE
    counts = [int(((u >= x0) & (u <= x0 + w) & (v >= y0) & (v <= y0 + h)).sum()) for x0, y0 in _INSET_CORNERS]
    x0, y0 = _INSET_CORNERS[int(np.argmin(counts))]
    return [x0, y0, w, h]


def _ellipse_lonlat(frame, x: float, y: float, e: dict[str, Any]) -> tuple[np.ndarray, np.ndarray] | None:
    """Outline (lon, lat) of an uncertainty ellipse about map-frame (x, y): semi-axes in metres, azimuth of
    the major axis clockwise from north; built on the ground and projected point by point (exact)."""
    try:
        a, b, az = float(e["semi_major_m"]), float(e["semi_minor_m"]), math.radians(float(e["azimuth_deg"]))
    except (KeyError, TypeError, ValueError):
        return None
    t = np.linspace(0, 2 * np.pi, 121)
    u, v = a * np.cos(t), b * np.sin(t)  # along / across the major axis
    ex = x + u * math.sin(az) + v * math.cos(az)
    ny = y + u * math.cos(az) - v * math.sin(az)
    lon, lat = frame.to_lonlat(ex, ny)
    return np.asarray(lon, float), np.asarray(lat, float)


def fig_overview(dp: DiveProducts, opt: FigureOptions) -> FigureResult:
    r = FigureResult("overview_map", "Geographic overview of the dive", "Dive",
                     "The dive on the hillshaded reference DTM (depth contours) in longitude/latitude "
                     "(WGS 84; equal ground distances on both axes; washed-out cells: no soundings): best track of the whole dive (navigation: "
                     "terrain-matched on the bottom, dead reckoning adjusted to the launch and the match elsewhere), "
                     "the dead-reckoning-only track, the launch point, the matched start of the bottom track with "
                     "its 1-sigma and 2-sigma uncertainty ellipses (inset: zoom on the fix; the radial 1-sigma circle "
                     "when the match has no posterior ellipse), the posterior's second mode when it holds more "
                     "than 1 % of the mass, the selected landing sites when the laser survey is georeferenced, "
                     "and the deepest point.")
    frame = _frame(dp)
    if dp.dtm is None or frame is None or "depth_m" not in dp.dtm:
        r.skipped = "no dtm product (reference terrain)"
        return r
    ds = dp.dtm
    fix = dp.fix or {}
    x, y = ds["x"].values.astype(float), ds["y"].values.astype(float)
    z = ds["depth_m"].transpose("y", "x").values.astype(float)
    x, y, z, dr = _overview_area(dp, fix, x, y, z)
    X, Y = np.meshgrid(x, y)
    LON, LAT = (np.asarray(v, float) for v in frame.to_lonlat(X, Y))
    lat0 = float(np.nanmean(LAT))
    fig = Figure(figsize=(opt.width_in * 0.8, opt.width_in * 0.72), layout="constrained")
    ax = fig.subplots()
    _shaded_dtm(fig, ax, LON, LAT, x, z)
    handles = _overview_tracks(ax, dp, fix, dr, frame, opt)
    st = fix.get("start")
    _surfacing(ax, dp, handles)
    inset_box = None
    if isinstance(st, dict) and st.get("lon") is not None:
        inset_box = _overview_fix(ax, dp, fix, st, frame, handles, LON, LAT, lat0)
    sm2 = _second_mode(fix)
    if sm2 is not None:
        slon, slat = frame.to_lonlat(float(sm2["x"]), float(sm2["y"]))
        handles += ax.plot(slon, slat, "D", mfc="none", mec="c", mew=1.8, ms=9, ls="none",
                           label=f"posterior second mode ({100 * float(sm2['mass']):.0f} % of the mass)")
    ls_ = dp.landing_sites
    if ls_ is not None and {"lat", "lon"} <= set(ls_.columns) and len(ls_):
        best = ls_[ls_["is_best"].astype(bool)] if "is_best" in ls_ else ls_
        handles += ax.plot(best["lon"], best["lat"], "^", color="#39ff14", mec="k", ms=9, ls="none",
                           label="selected landing site(s) (laser survey)")
    deep = fix.get("deepest_point")
    if isinstance(deep, dict) and deep.get("lon") is not None:
        handles += ax.plot(deep["lon"], deep["lat"], "*", color="gold", mec="k", ms=15, ls="none",
                           label="deepest point")
    _geo_axes(ax, LON, LAT)  # the same graticule as the DTM map: degrees and minutes, 4-5 ticks
    ax.tick_params(labelsize=8)
    _scale_bar(ax, lat0, inset_box)
    if handles:
        ax.legend(handles=handles, fontsize=7, loc="upper right", framealpha=0.85)
    reasons = fix.get("mismatch_reasons") or []
    if reasons:
        ax.set_title("fix flagged: " + ", ".join(map(str, reasons)), fontsize=9, color="#b00020")
    return _render(r, fig, opt)


def _overview_area(dp: DiveProducts, fix: dict[str, Any], x: np.ndarray, y: np.ndarray, z: np.ndarray
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
    """The DTM cropped to the area around the dive (:func:`fig_overview`) and the dead-reckoning track of fix.json."""
    # the area around the dive: track, launch and start with a margin; the whole grid without a track
    px, py = [], []
    if dp.navigation is not None and {"x_east_m", "y_north_m"} <= set(dp.navigation.columns):
        px += list(dp.navigation["x_east_m"].to_numpy(float)[::50])
        py += list(dp.navigation["y_north_m"].to_numpy(float)[::50])
    elif dp.track is not None and {"x_east_m", "y_north_m"} <= set(dp.track.columns):
        px += list(dp.track["x_east_m"].to_numpy(float)[::50])
        py += list(dp.track["y_north_m"].to_numpy(float)[::50])
    dr = fix.get("dead_reckoning_track") or {}
    px += list(dr.get("x_east_m") or [])
    py += list(dr.get("y_north_m") or [])
    for k in ("launch", "start"):
        if isinstance(fix.get(k), dict) and fix[k].get("x_east_m") is not None:
            px.append(float(fix[k]["x_east_m"]))
            py.append(float(fix[k]["y_north_m"]))
    if px:
        pad = max(800.0, 0.25 * max(np.nanmax(px) - np.nanmin(px), np.nanmax(py) - np.nanmin(py)))
        kx = (x >= np.nanmin(px) - pad) & (x <= np.nanmax(px) + pad)
        ky = (y >= np.nanmin(py) - pad) & (y <= np.nanmax(py) + pad)
        if kx.sum() > 2 and ky.sum() > 2:
            x, y, z = x[kx], y[ky], z[np.ix_(ky, kx)]
    return x, y, z, dr


def _shaded_dtm(fig: Figure, ax: Any, LON: np.ndarray, LAT: np.ndarray, x: np.ndarray, z: np.ndarray) -> None:
    """The hillshaded DTM (empty cells washed out), its colour bar and depth contours (:func:`fig_overview`)."""
    # empty cells: nearest valid depth for the shading (no false cliffs at their edges), drawn greyed below
    bad = ~np.isfinite(z)
    if bad.any() and (~bad).any():
        from scipy.ndimage import distance_transform_edt

        idx = distance_transform_edt(bad, return_distances=False, return_indices=True)
        zf = z[tuple(idx)]
    else:
        zf = np.where(bad, 0.0, z)
    ls = LightSource(azdeg=315, altdeg=45)
    dx = float(np.median(np.diff(x))) if x.size > 1 else 1.0
    cmap = CMAPS["depth"]
    norm_z = (zf - np.nanmin(zf)) / max(np.nanmax(zf) - np.nanmin(zf), 1e-9)
    rgb = ls.shade_rgb(cmap(norm_z), -zf, vert_exag=1.0, dx=dx, dy=dx, blend_mode="soft")[..., :3]
    rgb = np.where(bad[..., None], 0.6 * rgb + 0.4, rgb)  # empty cells of the DTM: washed out
    ax.pcolormesh(LON, LAT, rgb, shading="nearest", rasterized=True)
    from matplotlib.cm import ScalarMappable
    from matplotlib.colors import Normalize

    sm = ScalarMappable(norm=Normalize(np.nanmin(z), np.nanmax(z)), cmap=cmap)
    cb = fig.colorbar(sm, ax=ax, shrink=0.8, label="reference depth (m, positive down)")
    cb.ax.invert_yaxis()
    step = _nice_length(max(float(np.nanmax(z) - np.nanmin(z)) / 10.0, 1.0))  # about 10 contours, 1-2-5 m
    levels = np.arange(math.ceil(np.nanmin(z) / step) * step, np.nanmax(z), step)
    if levels.size:
        cs = ax.contour(LON, LAT, z, levels=levels, colors="k", linewidths=0.4, alpha=0.6)
        ax.clabel(cs, levels=levels[::2], fontsize=9, fmt="%.0f")


def _overview_tracks(ax: Any, dp: DiveProducts, fix: dict[str, Any], dr: dict[str, Any], frame: Any,
                     opt: FigureOptions) -> list[Any]:
    """The best, matched and dead-reckoning tracks and the launch point (:func:`fig_overview`); their handles."""
    handles = []
    if dp.navigation is not None and {"lon", "lat"} <= set(dp.navigation.columns):
        nav = _thin(dp.navigation, opt.max_points)
        src = nav["position_source"].astype(str) if "position_source" in nav else pd.Series("", index=nav.index)
        m = (src == "matched").to_numpy()
        handles += ax.plot(nav["lon"].where(~m), nav["lat"].where(~m), "-", color="#ff9900", lw=1.2,
                           label="best track (dead reckoning adjusted)")
        handles += ax.plot(nav["lon"].where(m), nav["lat"].where(m), "-", color="m", lw=1.8,
                           label="best track (terrain-matched)")
    elif dp.track is not None and {"lon", "lat"} <= set(dp.track.columns):
        t = _thin(dp.track, opt.max_points)
        handles += ax.plot(t["lon"], t["lat"], "-", color="m", lw=1.8, label="matched bottom track")
    if dr.get("x_east_m"):
        dlon, dlat = frame.to_lonlat(np.asarray(dr["x_east_m"], float), np.asarray(dr["y_north_m"], float))
        handles += ax.plot(dlon, dlat, "--", color="#00e5ff", lw=1.4, label="dead reckoning only (bottom)")
    elif dp.ctd is not None and {"lon", "lat"} <= set(dp.ctd.columns):
        c = _thin(dp.ctd, opt.max_points)
        handles += ax.plot(c["lon"], c["lat"], "--", color="#00e5ff", lw=1.4, label="dead reckoning only")
    la = fix.get("launch") or ({"lat": dp.launch["lat"], "lon": dp.launch["lon"]} if dp.launch else None)
    if la and la.get("lon") is not None:
        handles += ax.plot(la["lon"], la["lat"], "X", color="r", mec="k", ms=11, ls="none", label="launch")
    return handles


def _overview_fix(ax: Any, dp: DiveProducts, fix: dict[str, Any], st: dict[str, Any], frame: Any,
                  handles: list[Any], LON: np.ndarray, LAT: np.ndarray, lat0: float) -> list[float] | None:
    """The matched start, its uncertainty ellipses and an inset zoom on them (:func:`fig_overview`); returns the
    inset's box (axes fraction) or ``None`` without one."""
    handles += ax.plot(st["lon"], st["lat"], "o", mfc="none", mec="yellow", mew=2, ms=9, ls="none",
                       label="matched start of the bottom track")
    unc = fix.get("uncertainty_m") or {}
    centre = fix.get("profile_start") if isinstance(fix.get("profile_start"), dict) else st
    cx, cy = centre.get("x_east_m", st.get("x_east_m")), centre.get("y_north_m", st.get("y_north_m"))
    ells = [(key, ls_, lab) for key, ls_, lab in (("ellipse_1sigma", "-", "1σ ellipse"),
                                                  ("ellipse_2sigma", ":", "2σ ellipse"))
            if isinstance(unc.get(key), dict)]
    if not ells and unc.get("radial"):  # no posterior ellipse: the radial (DRMS) uncertainty as a circle
        rr = float(unc["radial"])
        unc = {**unc, "_circle": {"semi_major_m": rr, "semi_minor_m": rr, "azimuth_deg": 0.0}}
        ells = [("_circle", "-", f"radial 1σ uncertainty ({rr:.0f} m)")]
    outlines = []
    for key, ls_, lab in ells:
        pts = _ellipse_lonlat(frame, float(cx), float(cy), unc[key]) if cx is not None else None
        if pts is not None:
            handles += ax.plot(pts[0], pts[1], ls_, color="yellow", lw=1.4, label=lab)
            outlines.append((pts, ls_))
    if not outlines:
        return None
    if outlines:  # always here: the ellipses are tens of metres on a map of kilometres, an inset zooms on the fix
        box = _emptiest_corner(handles, (float(np.nanmin(LON)), float(np.nanmax(LON))),
                               (float(np.nanmin(LAT)), float(np.nanmax(LAT))))
        ins = ax.inset_axes(box)
        ins.set_facecolor("0.15")
        for pts, ls_ in outlines:
            ins.plot(pts[0], pts[1], ls_, color="yellow", lw=1.4)
        ins.plot(st["lon"], st["lat"], "o", mfc="none", mec="yellow", mew=1.5, ms=6)
        if dp.track is not None and {"lon", "lat"} <= set(dp.track.columns):
            tt = _thin(dp.track, 2000)
            ins.plot(tt["lon"], tt["lat"], "-", color="m", lw=1.2)
        big = outlines[-1][0]
        w = max(float(np.ptp(big[0])), float(np.ptp(big[1])) * math.cos(math.radians(lat0)))
        ins.set_xlim(st["lon"] - w, st["lon"] + w)
        ins.set_ylim(st["lat"] - w / math.cos(math.radians(lat0)), st["lat"] + w / math.cos(math.radians(lat0)))
        ins.set_aspect(1.0 / math.cos(math.radians(lat0)))
        ins.set_xticks([])
        ins.set_yticks([])
        wm = w * 111_320.0 * math.cos(math.radians(lat0))
        ins.set_title(f"zoom on the fix ({2 * wm:.0f} m wide)", fontsize=9, color="k", pad=2,
                      bbox={"fc": "w", "ec": "none", "alpha": 0.8, "pad": 1})
    return box


def fig_residuals(dp: DiveProducts, opt: FigureOptions) -> FigureResult:
    r = FigureResult("fig16_matched_depth", "Measured vs reference depth along the matched track", "Terrain matching",
                     "(top) Seafloor depth measured by the vehicle (depth + altitude) and the reference-map depth at "
                     "the matched positions (minus the estimated bias when the match estimated one); (bottom) the "
                     "residual measured - reference, with its RMS (cf. TERCOM paper Fig. 16).")
    tr = dp.track
    if tr is None or not {"seafloor_depth_m", "map_depth_m"} <= set(tr.columns):
        r.skipped = "no matched track" if tr is None else "matched track has no seafloor_depth_m/map_depth_m"
        return r
    tr, xaxis, ref = _track_depths(tr, opt.max_points)
    res = tr["seafloor_depth_m"].to_numpy(float) - tr[ref].to_numpy(float)
    fig = Figure(figsize=(opt.width_in, opt.width_in * 0.55), layout="constrained")
    ax, ax2 = fig.subplots(2, 1, sharex=True, height_ratios=[2.2, 1])
    _plot_track_depths(ax, tr, xaxis, ref, rasterized=True)
    ok = np.isfinite(res)
    rms = float(np.sqrt(np.mean(res[ok] ** 2))) if ok.any() else float("nan")
    ax2.plot(xaxis, res, ".", ms=1.5, color="k", rasterized=True)
    ax2.axhline(0, color="#D55E00", lw=1)
    ax2.set_ylabel("residual (m)")
    ax2.set_xlabel("time (UTC)" if "time" in tr else "sample")
    ax2.grid(alpha=0.3)
    ax2.text(0.01, 0.92, f"RMS {rms:.1f} m, mean {np.nanmean(res):+.1f} m", transform=ax2.transAxes, fontsize=8,
             va="top", bbox={"fc": "w", "ec": "none", "alpha": 0.8})
    if "time" in tr:
        fig.autofmt_xdate()
    return _render(r, fig, opt)


# ------------------------------------------------------------------------------------------ geographic DTM maps
#: a DTM drawn on a geographic map is thinned (every k-th cell) to at most this many cells a side
DTM_FIGURE_CELLS = 700


def degmin_formatter(axis: str, span_deg: float):
    """A tick formatter writing a longitude (``axis="lon"``) or latitude as degrees and decimal minutes
    (``142°12.5'E``), with as many decimals of a minute as the tick spacing (about ``span_deg`` / 5) needs."""
    from matplotlib.ticker import FuncFormatter

    from hadal.geo import format_degmin

    step_min = max(abs(span_deg) * 60.0 / 5.0, 1e-9)
    dec = int(min(4, max(1, math.ceil(-math.log10(step_min) + 0.3))))
    return FuncFormatter(lambda v, _pos: format_degmin(v, axis, dec))


def dtm_lonlat(ds, k: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """Longitude/latitude (degrees) of every ``k``-th cell centre of a DTM: its own ``lon``/``lat`` (y, x)
    coordinates when it has them, else its map frame (``map_frame_origin_*`` attributes) projected."""
    if {"lon", "lat"} <= set(ds.variables) and ds["lon"].ndim == 2:
        return (np.asarray(ds["lon"].transpose("y", "x").values[::k, ::k], float),
                np.asarray(ds["lat"].transpose("y", "x").values[::k, ::k], float))
    from hadal.geo import LocalFrame

    fr = LocalFrame(float(ds.attrs["map_frame_origin_latitude_deg"]), float(ds.attrs["map_frame_origin_longitude_deg"]))
    X, Y = np.meshgrid(ds["x"].values[::k].astype(float), ds["y"].values[::k].astype(float))
    lon, lat = fr.to_lonlat(X, Y)
    return np.asarray(lon, float), np.asarray(lat, float)


def _geo_axes(ax, lon: np.ndarray, lat: np.ndarray, *, narrow: bool = False) -> float:
    """Limits at the cells' lon/lat bounds, equal ground distances (aspect 1/cos(latitude)), graticule labels in
    degrees and minutes; returns the mean latitude. ``narrow``: a panel of a multi-panel figure, whose longitude
    labels (up to 12 characters at a small survey's 4 decimals of a minute) get fewer ticks, slanted."""
    lo0, lo1, la0, la1 = (float(np.nanmin(lon)), float(np.nanmax(lon)), float(np.nanmin(lat)), float(np.nanmax(lat)))
    lat0 = 0.5 * (la0 + la1)
    ax.set_xlim(lo0, lo1)
    ax.set_ylim(la0, la1)
    ax.set_aspect(1.0 / math.cos(math.radians(lat0)))
    ax.xaxis.set_major_formatter(degmin_formatter("lon", lo1 - lo0))
    ax.yaxis.set_major_formatter(degmin_formatter("lat", la1 - la0))
    from matplotlib.ticker import MaxNLocator

    ax.xaxis.set_major_locator(MaxNLocator(3 if narrow else 4))
    ax.yaxis.set_major_locator(MaxNLocator(5))
    if narrow:
        ax.tick_params(axis="x", labelrotation=20)
        for lbl in ax.get_xticklabels():
            lbl.set_horizontalalignment("right")
    ax.set_xlabel("longitude (WGS 84)")
    ax.set_ylabel("latitude (WGS 84)")
    ax.grid(color="w", alpha=0.35, lw=0.6)
    return lat0


def _thin_k(ds) -> int:
    return max(1, int(math.ceil(max(ds.sizes["x"], ds.sizes["y"]) / DTM_FIGURE_CELLS)))


def fig_dtm_geo(dp: DiveProducts, opt: FigureOptions) -> FigureResult:
    """The reference DTM on a geographic map (what ``mbm_grdplot`` draws): depth coloured and hillshaded
    (:class:`matplotlib.colors.LightSource`, sun from the north-west), depth contours, the dive's best track and
    launch point, a scale bar, graticule in degrees and minutes; axes at the product's lon/lat bounds."""
    r = FigureResult("dtm_map", "Reference terrain (multibeam DTM)", "Terrain",
                     "Reference DTM gridded from the ship's multibeam soundings (depth positive down), hillshaded "
                     "(sun from the north-west, 45° high) in longitude/latitude (WGS 84, equal ground distances on "
                     "both axes) with depth contours, the dive's track and the launch point; washed-out cells have "
                     "no sounding (the coverage figure below shows them).")
    ds = dp.dtm
    if ds is None or "depth_m" not in ds or not {"x", "y"} <= set(ds["depth_m"].dims):
        r.skipped = "no dtm product (reference terrain)" if ds is None else "dtm product has no depth_m(y, x)"
        return r
    if not ({"lon", "lat"} <= set(ds.variables) or "map_frame_origin_latitude_deg" in ds.attrs):
        r.skipped = "dtm product has neither lon/lat nor its map frame's origin: it cannot be placed on a map"
        return r
    if ds.attrs.get("dtm_source") == "prior_grid":
        r.title = "Reference terrain (prior bathymetry grid)"
        r.caption = r.caption.replace("gridded from the ship's multibeam soundings",
                                      "resampled from the prior bathymetry grid")
    k = _thin_k(ds)
    lon, lat = dtm_lonlat(ds, k)
    z = np.asarray(ds["depth_m"].transpose("y", "x").values[::k, ::k], float)
    x = ds["x"].values[::k].astype(float)
    fig = Figure(figsize=(opt.width_in, opt.width_in * 0.72), layout="constrained")
    ax = fig.subplots()
    _shaded_dtm(fig, ax, lon, lat, x, z)
    handles = _overview_tracks(ax, dp, dp.fix or {}, (dp.fix or {}).get("dead_reckoning_track") or {},
                               _frame(dp), opt) if _frame(dp) is not None else []
    if "land" in ds and ds["land"].dims == ("y", "x"):  # above sea level in the source grid: no depth, drawn as land
        from matplotlib.colors import ListedColormap
        from matplotlib.patches import Patch

        from hadal.report.figures import LAND_COLOUR

        land = np.asarray(ds["land"].values[::k, ::k]) == 1
        if land.any():
            ax.pcolormesh(lon, lat, np.ma.masked_where(~land, np.ones(land.shape)), shading="nearest",
                          cmap=ListedColormap([LAND_COLOUR]), vmin=0, vmax=1, rasterized=True)
            handles.append(Patch(facecolor=LAND_COLOUR, edgecolor="none", label="land"))
            r.caption += " Land (above sea level in the source grid) is drawn as land: it has no depth."
    _surfacing(ax, dp, handles)
    lat0 = _geo_axes(ax, *dtm_lonlat(ds))
    _scale_bar(ax, lat0)
    if handles:
        ax.legend(handles=handles, loc="upper right", framealpha=0.85)
    if k > 1:
        r.caption += f" Drawn every {k}th cell ({ds.sizes['x']} x {ds.sizes['y']} cells)."
    return _render(r, fig, opt)


def fig_dtm_quality(dp: DiveProducts, opt: FigureOptions) -> FigureResult:
    """Coverage/sounding density (``count``, soundings per cell, log scale; empty cells shown) and the standard
    uncertainty (``uncertainty_m``) of the multibeam DTM on geographic axes (Kluster's and ``mbgrid``'s density and
    uncertainty layers)."""
    r = FigureResult("dtm_quality", "Reference terrain: coverage, sounding density and uncertainty", "Terrain",
                     "(a) Soundings per DTM cell (log scale; grey: no sounding, i.e. no coverage) and (b) standard "
                     "uncertainty of each cell's depth (m; a-priori sonar error and the soundings' spread over "
                     "sqrt(count), the DTM's uncertainty_m), in longitude/latitude (WGS 84).")
    ds = dp.dtm
    if ds is None:
        r.skipped = "no dtm product (reference terrain)"
        return r
    panels = [v for v in ("count", "uncertainty_m") if v in ds and ds[v].dims == ("y", "x")]
    if not panels or not ({"lon", "lat"} <= set(ds.variables) or "map_frame_origin_latitude_deg" in ds.attrs):
        r.skipped = ("dtm product has no count/uncertainty_m layers (a prior grid has no soundings)" if not panels
                     else "dtm product cannot be placed on a map (no lon/lat)")
        return r
    from matplotlib.colors import LogNorm

    k = _thin_k(ds)
    full_lon, full_lat = dtm_lonlat(ds)
    fig = Figure(figsize=(opt.width_in, opt.width_in * 0.52), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, len(panels)))
    cov, tracked = None, []
    for ax, v in zip(axes, panels, strict=True):
        # block means of k x k cells (a density map must not skip cells): soundings per cell, uncertainty
        a = np.asarray(ds[v].transpose("y", "x").values, float)
        lon, lat, a = (_block_mean(b, k) for b in (full_lon, full_lat, a))
        ax.set_facecolor("0.75")
        if v == "count":
            cnt = np.where(a > 0, a, np.nan)
            fin = cnt[np.isfinite(cnt)]
            cov = float(np.mean(np.asarray(ds[v].values) > 0))
            im = ax.pcolormesh(lon, lat, cnt, shading="nearest", cmap="viridis", rasterized=True,
                               norm=LogNorm(max(0.1, float(fin.min())) if fin.size else 1.0,
                                            max(2.0, float(fin.max())) if fin.size else 2.0))
            cb = fig.colorbar(im, ax=ax, orientation="horizontal", shrink=0.8, label="soundings per cell")
            from matplotlib.ticker import LogLocator, NullFormatter, ScalarFormatter

            cb.ax.xaxis.set_major_locator(LogLocator(subs=(1.0, 2.0, 5.0)))
            cb.ax.xaxis.set_major_formatter(ScalarFormatter())
            cb.ax.xaxis.set_minor_formatter(NullFormatter())
            ax.set_title("(a) sounding density (grey: no sounding)")
        else:
            fin = a[np.isfinite(a)]
            vmax = float(np.nanpercentile(fin, 99)) if fin.size else 1.0
            im = ax.pcolormesh(lon, lat, a, shading="nearest", cmap="cividis", vmin=0.0, vmax=vmax, rasterized=True)
            fig.colorbar(im, ax=ax, orientation="horizontal", shrink=0.8, label="standard uncertainty of depth (m)",
                         extend="max")
            ax.set_title("(b) depth uncertainty" + (f" (median {np.nanmedian(fin):.2f} m)" if fin.size else ""))
        tracked = _track_on_map(ax, dp, opt)
        _scale_bar(ax, _geo_axes(ax, full_lon, full_lat, narrow=True))
    if tracked:
        r.caption += f" Line: the dive's {tracked[0].get_label()}."
    if cov is not None:
        r.caption += f" {100 * cov:.1f} % of the {ds.sizes['x'] * ds.sizes['y']:,} cells hold at least one sounding."
    if k > 1:
        r.caption += f" Drawn as means of {k} x {k} cells."
    return _render(r, fig, opt)


def _block_mean(a: np.ndarray, k: int) -> np.ndarray:
    """Means of the ``k`` x ``k`` blocks of a 2-D array (NaN ignored; a partial last block trimmed); ``a`` for k = 1."""
    if k <= 1:
        return a
    ny, nx = (a.shape[0] // k) * k, (a.shape[1] // k) * k
    b = a[:ny, :nx].reshape(ny // k, k, nx // k, k)
    with np.errstate(invalid="ignore"):
        import warnings

        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            return np.nanmean(b, axis=(1, 3))


def surfacing_position(nav: pd.DataFrame | None) -> dict[str, Any] | None:
    """The vehicle's surfacing position: the last sample of the navigation product (end of the ascent) with a
    position, its time, 1-sigma radial uncertainty (``position_uncertainty_m``) and source; ``None`` without one."""
    if nav is None or not {"lat", "lon"} <= set(nav.columns) or not len(nav):
        return None
    ok = np.isfinite(nav["lat"].to_numpy(float)) & np.isfinite(nav["lon"].to_numpy(float))
    if "phase" in nav and (nav["phase"].astype(str) == "ascent").any():
        ok &= (nav["phase"].astype(str) == "ascent").to_numpy()
    if not ok.any():
        return None
    row = nav[ok].iloc[-1]
    out: dict[str, Any] = {"lat": float(row["lat"]), "lon": float(row["lon"])}
    if "time" in nav and pd.notna(row["time"]):
        out["time_utc"] = pd.Timestamp(row["time"]).isoformat()
    if "position_uncertainty_m" in nav and np.isfinite(float(row["position_uncertainty_m"])):
        out["uncertainty_m"] = float(row["position_uncertainty_m"])
    if "position_source" in nav:
        out["source"] = str(row["position_source"])
    return out


def _surfacing(ax, dp: DiveProducts, handles: list[Any]) -> None:
    """The surfacing position (and its 1-sigma circle) on a lon/lat map."""
    s = surfacing_position(dp.navigation)
    if s is None:
        return
    lab = "surfacing position" + (f" (±{s['uncertainty_m']:.0f} m, 1σ)" if s.get("uncertainty_m") else "")
    handles += ax.plot(s["lon"], s["lat"], "s", color="#E69F00", mec="k", ms=9, ls="none", label=lab)
    if s.get("uncertainty_m"):
        t = np.linspace(0, 2 * np.pi, 91)
        rr = float(s["uncertainty_m"])
        ax.plot(s["lon"] + rr * np.sin(t) / (111_320.0 * math.cos(math.radians(s["lat"]))),
                s["lat"] + rr * np.cos(t) / 111_320.0, "-", color="#E69F00", lw=1.4)


#: columns of the navigation product read as per-sample position uncertainty (besides ``position_uncertainty_m``)
SIGMA_HINTS = ("sigma", "_std_")


def _cov_role(name: str) -> str | None:
    """Which element of a horizontal position covariance a column holds, from its name: ``ee`` (east variance),
    ``nn`` (north) or ``en`` (east-north covariance); ``position_covariance_east_m2`` -> ``ee``,
    ``..._east_north_m2`` -> ``en``, ``cov_xx`` -> ``ee``; ``None`` for anything else."""
    import re

    words = set(re.split(r"[^a-z]+", name.lower()))
    east, north = bool(words & {"east", "e", "x", "easting"}), bool(words & {"north", "n", "y", "northing"})
    pair = next((w for w in words if w in ("ee", "nn", "en", "ne", "xx", "yy", "xy", "yx")), None)
    if pair:
        return {"ee": "ee", "xx": "ee", "nn": "nn", "yy": "nn"}.get(pair, "en")
    if east and north:
        return "en"
    return "ee" if east else "nn" if north else None


def nav_uncertainty_series(nav: pd.DataFrame) -> dict[str, np.ndarray]:
    """Per-sample horizontal position uncertainty (m, 1 sigma) of the navigation product by what it is:
    ``position_uncertainty_m`` (radial DRMS), every ``*sigma*`` column in metres, and, from a covariance
    (``*_cov_*``: east/north variances and covariance, m²), the semi-major axis of the 1-sigma ellipse
    sqrt(largest eigenvalue). Columns it cannot read are left out."""
    out: dict[str, np.ndarray] = {}
    if "position_uncertainty_m" in nav:
        out["radial 1σ (DRMS)"] = nav["position_uncertainty_m"].to_numpy(float)
    for c in nav.columns:
        lc = str(c).lower()
        if c != "position_uncertainty_m" and any(h in lc for h in SIGMA_HINTS) and lc.endswith("_m"):
            v = pd.to_numeric(nav[c], errors="coerce").to_numpy(float)
            if np.isfinite(v).any():
                out[str(c).replace("_", " ")] = v
    roles = {_cov_role(str(c)): c for c in nav.columns if "cov" in str(c).lower()}
    ee, nn, en = roles.get("ee"), roles.get("nn"), roles.get("en")
    if ee and nn:
        a = pd.to_numeric(nav[ee], errors="coerce").to_numpy(float)
        b = pd.to_numeric(nav[nn], errors="coerce").to_numpy(float)
        c = pd.to_numeric(nav[en], errors="coerce").to_numpy(float) if en else np.zeros_like(a)
        lam = 0.5 * (a + b) + np.sqrt(0.25 * (a - b) ** 2 + c ** 2)
        out["ellipse semi-major 1σ (covariance)"] = np.sqrt(np.clip(lam, 0, None))
    return out


def fig_nav_uncertainty(dp: DiveProducts, opt: FigureOptions) -> FigureResult:
    """Horizontal position uncertainty along the dive (navigation product), phases shaded, the surfacing
    position's uncertainty marked."""
    r = FigureResult("nav_uncertainty", "Position uncertainty along the dive", "Dive",
                     "Horizontal position uncertainty (1 sigma, m) of the best track (navigation product) against "
                     "time: small on the bottom where the track is terrain-matched, growing while the vehicle is "
                     "dead-reckoned (descent, ascent); the square marks the surfacing position's uncertainty.")
    nav = dp.navigation
    if nav is None or "time" not in nav:
        r.skipped = "no navigation product" if nav is None else "navigation product has no time"
        return r
    series = nav_uncertainty_series(nav)
    if not series:
        r.skipped = "navigation product has no position uncertainty column"
        return r
    n = _thin(nav, opt.max_points)
    idx = nav.index.get_indexer(n.index)
    t = pd.to_datetime(n["time"], utc=True).dt.tz_localize(None)
    fig = Figure(figsize=(opt.width_in, opt.width_in * 0.4), layout="constrained")
    ax = fig.subplots()
    okabe = ("#0072B2", "#D55E00", "#009E73", "#CC79A7", "#56B4E9")
    for (lab, v), col in zip(series.items(), okabe * 3, strict=False):
        ax.plot(t, v[idx], "-", lw=1.5, color=col, label=lab)
    if "phase" in n:
        ph = n["phase"].astype(str).to_numpy()
        for name, shade in (("descent", "#56B4E9"), ("bottom", "#009E73"), ("ascent", "#E69F00")):
            m = ph == name
            if m.any():
                ax.axvspan(t[m].min(), t[m].max(), color=shade, alpha=0.12, lw=0)
                ax.text(t[m].min() + (t[m].max() - t[m].min()) / 2, 1.0, name, transform=ax.get_xaxis_transform(),
                        ha="center", va="bottom")
    s = surfacing_position(nav)
    if s and s.get("uncertainty_m") and s.get("time_utc"):
        ax.plot(pd.Timestamp(s["time_utc"]).tz_localize(None) if pd.Timestamp(s["time_utc"]).tzinfo is None else
                pd.Timestamp(s["time_utc"]).tz_convert(None), s["uncertainty_m"], "s", color="#E69F00", mec="k",
                ms=9, label=f"surfacing: ±{s['uncertainty_m']:.0f} m")
    ax.set_ylabel("horizontal position uncertainty, 1σ (m)")
    ax.set_xlabel("time (UTC)")
    ax.set_ylim(bottom=0)
    ax.grid(alpha=0.3)
    ax.legend(loc="upper left")
    fig.autofmt_xdate()
    return _render(r, fig, opt)


def fig_suitability_geo(dp: DiveProducts, opt: FigureOptions) -> FigureResult:
    """TERCOM Figs. 5-6 (block elevation standard deviation and information entropy) on geographic axes: the
    suitability product's blocks placed by its map frame (``map_frame_origin_*``), the proposed matching region's
    outline and the launch point in longitude/latitude; the map-frame figure when the product has no frame origin."""
    from hadal.report.figures import _grid_ok, _region, fig_suitability

    ds = dp.suitability
    if ds is None or "map_frame_origin_latitude_deg" not in ds.attrs:
        return fig_suitability(dp, opt)
    r = FigureResult("fig05_06_suitability", "Terrain suitability for matching", "Terrain",
                     "(left) terrain elevation standard deviation and (right) topographic information entropy per "
                     "block (cf. TERCOM paper Figs. 5-6) in longitude/latitude (WGS 84, equal ground distances; "
                     "scale bar in each panel); "
                     "dashed: proposed matching region, x: launch point.")
    panels = [(v, lab, cm) for v, lab, cm in (("std_m", "elevation std (m)", CMAPS["std"]),
                                              ("entropy", "information entropy", "viridis"))
              if _grid_ok(ds, v, "suitability") is None]
    if not panels:
        r.skipped = "suitability product has neither std_m(y, x) nor entropy(y, x)"
        return r
    from hadal.geo import LocalFrame

    fr = LocalFrame(float(ds.attrs["map_frame_origin_latitude_deg"]), float(ds.attrs["map_frame_origin_longitude_deg"]))
    X, Y = np.meshgrid(ds["x"].values.astype(float), ds["y"].values.astype(float))
    lon, lat = (np.asarray(v, float) for v in fr.to_lonlat(X, Y))
    fig = Figure(figsize=(opt.width_in, opt.width_in * 0.45), layout="constrained")
    axes = np.atleast_1d(fig.subplots(1, len(panels)))
    reg = _region(ds)
    launch = dp.launch or ((dp.fix or {}).get("launch") if isinstance((dp.fix or {}).get("launch"), dict) else None)
    for ax, (v, lab, cm) in zip(axes, panels, strict=True):
        im = ax.pcolormesh(lon, lat, ds[v].transpose("y", "x").values.astype(float), shading="nearest", cmap=cm,
                           rasterized=True)
        fig.colorbar(im, ax=ax, orientation="horizontal", shrink=0.8, label=lab)
        if reg:
            t = np.linspace(0.0, 1.0, 50)
            x0, x1, y0, y1 = reg["x_min_m"], reg["x_max_m"], reg["y_min_m"], reg["y_max_m"]
            xs = np.concatenate([x0 + (x1 - x0) * t, np.full(50, x1), x1 - (x1 - x0) * t, np.full(50, x0)])
            ys = np.concatenate([np.full(50, y0), y0 + (y1 - y0) * t, np.full(50, y1), y1 - (y1 - y0) * t])
            rlon, rlat = fr.to_lonlat(xs, ys)
            ax.plot(rlon, rlat, "--", color="k", lw=1.2)
        tracked = _track_on_map(ax, dp, opt)
        if launch and launch.get("lon") is not None:
            ax.plot(float(launch["lon"]), float(launch["lat"]), "x", color="#D55E00", ms=10, mew=2.5)
        _scale_bar(ax, _geo_axes(ax, lon, lat, narrow=len(panels) > 1))
    if not (launch and launch.get("lon") is not None):
        r.caption = r.caption.replace(", x: launch point.", ".")
    if tracked:
        r.caption += f" Line: the dive's {tracked[0].get_label()}."
    return _render(r, fig, opt)


# ------------------------------------------------------------------------------------------ terrain matching maps
def _track_on_map(ax: Any, dp: DiveProducts, opt: FigureOptions) -> list[Any]:
    """The dive's track on a lon/lat map (a black-edged line, seen on light and dark maps): the best track of the
    whole dive (``navigation``), else the matched bottom track; its legend handle (none without either)."""
    for df, label in ((dp.navigation, "best track (navigation)"), (dp.track, "matched bottom track")):
        if df is not None and {"lon", "lat"} <= set(df.columns) and len(df):
            t = _thin(df, opt.max_points)
            ax.plot(t["lon"], t["lat"], "-", color="k", lw=2.8)
            return ax.plot(t["lon"], t["lat"], "-", color="#CC79A7", lw=1.4, label=label)
    return []


def _frame_of(ds: Any, dp: DiveProducts) -> Any:
    """The map frame of a local-frame product: its own ``map_frame_origin_*`` attributes, else the dive's
    (:func:`_frame`); ``None`` without one."""
    from hadal.geo import LocalFrame

    if ds is not None and "map_frame_origin_latitude_deg" in ds.attrs:
        return LocalFrame(float(ds.attrs["map_frame_origin_latitude_deg"]),
                          float(ds.attrs["map_frame_origin_longitude_deg"]))
    return _frame(dp)


def fig_msd_geo(dp: DiveProducts, opt: FigureOptions) -> FigureResult:
    """TERCOM's criterion surface ([TERCOM Eq. 17] over every start position of the track, the paper's Fig. 16) on a
    geographic map: the ``msd_surface.nc`` cells (map-frame x/y of the track's start) placed in longitude/latitude
    by the map frame, the best match and the posterior's second mode, the dive's track, the launch point, a scale
    bar and the degrees-and-minutes graticule; the map-frame figure when the product cannot be placed."""
    from hadal.report.figures import _score_var, fig_msd_surface

    ds = dp.msd
    frame = _frame_of(ds, dp)
    v = _score_var(ds) if ds is not None else None
    if ds is None or v is None or frame is None:
        return fig_msd_surface(dp, opt)
    r = FigureResult("fig16_msd_surface", "TERCOM criterion surface", "Terrain matching",
                     "Matching criterion of the measured seafloor-depth profile for every start position of the "
                     "track on the reference map (cf. TERCOM paper §4.2, Fig. 16), in longitude/latitude (WGS 84, "
                     "equal ground distances on both axes): the minimum (white circle) is the TERCOM fix; the dive's "
                     "track and the launch point (x) drawn over it.")
    crit = str(ds.attrs.get("criterion", "msd")).upper()
    vals = np.asarray(ds[v].transpose("y", "x").values, float)
    finite = vals[np.isfinite(vals)]
    label = f"{crit} ({ds[v].attrs.get('units', '')})"
    if finite.size and crit != "COR" and finite.min() > 0:
        vals, label = np.log10(vals), f"log10 {label}"
    X, Y = np.meshgrid(ds["x"].values.astype(float), ds["y"].values.astype(float))
    lon, lat = (np.asarray(a, float) for a in frame.to_lonlat(X, Y))
    fig = Figure(figsize=(opt.width_in * 0.8, opt.width_in * 0.66), layout="constrained")
    ax = fig.subplots()
    im = ax.pcolormesh(lon, lat, vals, shading="nearest", cmap=CMAPS["msd"], rasterized=True)
    fig.colorbar(im, ax=ax, shrink=0.85, label=label)
    handles = _track_on_map(ax, dp, opt)
    best: tuple[float, float] | None = None
    if ds.attrs.get("best_x_m") is not None and ds.attrs.get("best_y_m") is not None:
        best = (float(ds.attrs["best_x_m"]), float(ds.attrs["best_y_m"]))
    elif finite.size:
        raw = np.asarray(ds[v].transpose("y", "x").values, float)
        iy, ix = np.unravel_index(np.nanargmin(raw) if crit != "COR" else np.nanargmax(raw), raw.shape)
        best = (float(ds["x"][ix]), float(ds["y"][iy]))
    if best is not None:
        blon, blat = frame.to_lonlat(*best)
        handles += ax.plot(blon, blat, "o", mfc="none", mec="w", ms=14, mew=2, ls="none", label="best match")
    sm = _second_mode(dp.fix or {})
    if sm is not None:
        slon, slat = frame.to_lonlat(float(sm["x"]), float(sm["y"]))
        handles += ax.plot(slon, slat, "D", mfc="none", mec="c", ms=11, mew=2, ls="none",
                           label=f"second mode ({100 * float(sm['mass']):.0f} % of the posterior mass)")
        r.caption += " Cyan diamond: the posterior's second mode."
    handles += _launch_on_map(ax, dp)
    lat0 = _geo_axes(ax, lon, lat)
    _scale_bar(ax, lat0)
    if handles:  # dark legend: the markers are white/cyan
        ax.legend(handles=handles, loc="upper right", facecolor="0.3", labelcolor="w", framealpha=0.85)
    return _render(r, fig, opt)


def _launch_on_map(ax: Any, dp: DiveProducts) -> list[Any]:
    """The launch point (fix.json's, else dive.yaml's) as an x on a lon/lat map; its handle."""
    la = (dp.fix or {}).get("launch")
    la = la if isinstance(la, dict) and la.get("lon") is not None else dp.launch
    if not la or la.get("lon") is None:
        return []
    return ax.plot(float(la["lon"]), float(la["lat"]), "x", color="#D55E00", ms=11, mew=2.5, ls="none",
                   label="launch")


def fig_matched_track_geo(dp: DiveProducts, opt: FigureOptions) -> FigureResult:
    """TERCOM Fig. 17 on a geographic map: the matched bottom track on the hillshaded reference DTM around it (depth
    contours), the launch point and the deepest point, in longitude/latitude with a scale bar and the graticule;
    the map-frame figure when the track has no lon/lat or the DTM cannot be placed."""
    from hadal.report.figures import _deep_xy, _launch_xy, fig_matched_track

    tr, ds = dp.track, dp.dtm
    frame = _frame_of(ds, dp)
    if (tr is None or not {"lon", "lat", "x_east_m", "y_north_m"} <= set(tr.columns) or frame is None
            or ds is None or "depth_m" not in ds or not {"x", "y"} <= set(ds["depth_m"].dims)):
        return fig_matched_track(dp, opt)
    r = FigureResult("fig17_matched_track", "Matched track on the reference map", "Terrain matching",
                     "Bottom track placed on the hillshaded reference terrain (depth contours) by the match, in "
                     "longitude/latitude (WGS 84, equal ground distances on both axes); x: launch point, *: deepest "
                     "point (cf. TERCOM paper Fig. 17).")
    px = list(tr["x_east_m"].to_numpy(float))
    py = list(tr["y_north_m"].to_numpy(float))
    deep = (dp.fix or {}).get("deepest_point")
    for p in (_launch_xy(dp), _deep_xy(dp)):  # the map holds the track, the launch and the deepest point
        if p is not None:
            px.append(p[0])
            py.append(p[1])
    x, y = ds["x"].values.astype(float), ds["y"].values.astype(float)
    pad = 600.0
    kx = (x >= np.nanmin(px) - pad) & (x <= np.nanmax(px) + pad)
    ky = (y >= np.nanmin(py) - pad) & (y <= np.nanmax(py) + pad)
    if kx.sum() < 2 or ky.sum() < 2:
        return fig_matched_track(dp, opt)
    z = np.asarray(ds["depth_m"].transpose("y", "x").values, float)[np.ix_(ky, kx)]
    X, Y = np.meshgrid(x[kx], y[ky])
    lon, lat = (np.asarray(a, float) for a in frame.to_lonlat(X, Y))
    fig = Figure(figsize=(opt.width_in * 0.8, opt.width_in * 0.66), layout="constrained")
    ax = fig.subplots()
    _shaded_dtm(fig, ax, lon, lat, x[kx], z)
    t = _thin(tr, opt.max_points)
    ax.plot(t["lon"], t["lat"], "-", color="w", lw=2.6)
    handles = ax.plot(t["lon"], t["lat"], "-", color="#CC79A7", lw=1.4, label="matched track")
    handles += _launch_on_map(ax, dp)
    if isinstance(deep, dict) and deep.get("lon") is not None:
        handles += ax.plot(float(deep["lon"]), float(deep["lat"]), "*", color="gold", mec="k", ms=16, ls="none",
                           label="deepest point")
    lat0 = _geo_axes(ax, lon, lat)
    _scale_bar(ax, lat0)
    ax.legend(handles=handles, loc="upper right", framealpha=0.85)
    return _render(r, fig, opt)
