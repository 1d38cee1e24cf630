"""Report figures, modelled on the method papers, drawn with matplotlib's Agg canvas and cmocean maps.

Each ``fig_*`` function takes the loaded :class:`~hadal.report.load.DiveProducts` and returns a
:class:`FigureResult`: a PNG (bytes) and caption, or ``png=None`` with the reason it was skipped (missing
product or column). Figures are built on ``matplotlib.figure.Figure`` objects directly (no pyplot global
state), so they are safe in threads (Dask/Prefect workers).

=====================  =====================================================================
function               paper figure
=====================  =====================================================================
fig_ctd_profiles       TERCOM Fig. 8: conductivity, temperature, salinity, density, gravity vs depth
fig_depth_time         TERCOM Fig. 9: calibrated vehicle depth during the whole dive
fig_seafloor_depth     TERCOM Fig. 10: vehicle depth + altitude → seafloor depth
fig_dtm                reference DTM (multibeam) with the matched track
fig_suitability        TERCOM Figs. 5-6: block elevation standard deviation and information entropy
fig_msd_surface        TERCOM Fig. 16: MSD over the candidate positions, minimum marked
fig_matched_depth      TERCOM Fig. 16: measured vs reference depth along the matched track
fig_matched_track      TERCOM Fig. 17: matched track on the reference map, launch (x), deepest point (*)
fig_landing_map        landing paper Figs. 19/25: elevation of the best submap and the selected site
=====================  =====================================================================

In the report (:func:`all_figures`) every map is drawn on geographic axes instead (:mod:`hadal.report.geo_figures`:
``fig_dtm_geo`` hillshaded with the track, ``fig_dtm_quality`` coverage, sounding density and uncertainty,
``fig_suitability_geo``, ``fig_msd_geo``, ``fig_matched_track_geo``; the map-frame figures here remain for a
product without a map frame), beside the overview and the position uncertainty along the dive
(``fig_nav_uncertainty``). Text is at least :attr:`FigureOptions.min_font_pt` (9 pt) and categorical colours are
Okabe-Ito's (:data:`OKABE_ITO`).
"""

from __future__ import annotations

import io
import json
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import pandas as pd
import xarray as xr
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure
from matplotlib.patches import Rectangle
from matplotlib.ticker import MaxNLocator

from hadal.report.load import DiveProducts
from hadal.report.units import axis_label

try:  # cmocean is a dependency; fall back to matplotlib maps if it is broken
    import cmocean.cm as cmo

    CMAPS = {"depth": cmo.deep, "temp": cmo.thermal, "salt": cmo.haline, "dens": cmo.dense, "cond": cmo.tempo,
             "grav": cmo.amp, "std": cmo.matter, "entropy": cmo.tempo, "msd": cmo.rain, "elev": cmo.deep_r}
except Exception:  # pragma: no cover
    CMAPS = {k: "viridis" for k in ("depth", "temp", "salt", "dens", "cond", "grav", "std", "entropy", "msd", "elev")}

#: Okabe & Ito's colour-blind-safe categorical palette (Color Universal Design, 2008)
OKABE_ITO = {"black": "#000000", "orange": "#E69F00", "sky_blue": "#56B4E9", "bluish_green": "#009E73",
             "yellow": "#F0E442", "blue": "#0072B2", "vermillion": "#D55E00", "reddish_purple": "#CC79A7"}
#: dive phases in Okabe-Ito colours (descent blue, bottom bluish green, ascent vermillion: told apart with any
#: common colour-vision deficiency; red/green was not)
PHASE_COLOURS = {"descent": OKABE_ITO["blue"], "bottom": OKABE_ITO["bluish_green"], "ascent": OKABE_ITO["vermillion"]}


@dataclass
class FigureResult:
    key: str
    title: str
    section: str
    caption: str
    png: bytes | None = None
    skipped: str | None = None
    #: the drawn matplotlib Figure, kept only with ``FigureOptions(keep_figure=True)`` (tests inspect its artists)
    figure: Figure | None = field(default=None, repr=False, compare=False)
    #: resolution (dots per inch) of :attr:`png` and its smallest text (points): the page tells the browser test
    #: (``data-dpi``, ``data-min-font-pt``) so it can check the text's size as displayed
    dpi: float | None = None
    min_font_pt: float | None = None


@dataclass
class FigureOptions:
    dpi: int = 110
    width_in: float = 10.0
    max_points: int = 20000
    keep_figure: bool = False  # keep the Figure on the result (FigureResult.figure); off: freed after rendering
    #: smallest text (points) on a figure: every smaller label, tick label and legend entry is raised to it. At the
    #: default dpi and width the PNG is shown at ~97 % of its size in the page (1100 px wide at most), so 9 pt stays
    #: >= 9 pt (12 CSS px) on screen (checked in headless Chromium, tests/unit/report/test_report.py)
    min_font_pt: float = 9.0
    #: processes drawing the figures (:class:`hadal.forkpool.ForkPool`; 1 with ``keep_figure``: a Figure stays here)
    workers: int = 1


def _png(fig: Figure, dpi: int, tight: bool = True) -> bytes:
    """PNG of ``fig``; ``tight``: cropped to the drawn content (``bbox_inches="tight"``), else the whole canvas."""
    FigureCanvasAgg(fig)
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=dpi, bbox_inches="tight" if tight else None)
    return buf.getvalue()


def _render(r: FigureResult, fig: Figure, opt: FigureOptions, tight: bool = True) -> FigureResult:
    """``r`` with the PNG of ``fig`` (and ``fig`` itself when ``opt.keep_figure``); ``tight``: see :func:`_png`.
    Text smaller than ``opt.min_font_pt`` is raised to it first (:func:`hadal.figtext.min_fonts`)."""
    from hadal.figtext import min_fonts

    min_fonts(fig, opt.min_font_pt)
    r.png = _png(fig, opt.dpi, tight)
    r.dpi, r.min_font_pt = float(opt.dpi), float(opt.min_font_pt)
    if opt.keep_figure:
        r.figure = fig
    return r


def _thin(df: pd.DataFrame, n: int) -> pd.DataFrame:
    step = max(1, int(np.ceil(len(df) / max(1, n))))
    return df.iloc[::step]


def _phases(df: pd.DataFrame) -> list[tuple[str, pd.DataFrame]]:
    if "phase" not in df:
        return [("all", df)]
    out = [(str(ph), g) for ph, g in df.groupby(df["phase"].astype(str), sort=False)]
    order = {"descent": 0, "bottom": 1, "ascent": 2}
    return sorted(out, key=lambda t: order.get(t[0], 9))


def _time(df: pd.DataFrame) -> pd.Series:
    return pd.to_datetime(df["time"], utc=True).dt.tz_localize(None)


def _has_time(df: pd.DataFrame | None) -> bool:
    """Whether the table has sample times (a pressure-binned cast has an all-NaT ``time``)."""
    return df is not None and "time" in df and bool(pd.to_datetime(df["time"], utc=True).notna().any())


def _need(df: pd.DataFrame | None, cols: tuple[str, ...], what: str) -> str | None:
    if df is None:
        return f"no {what}"
    miss = [c for c in cols if c not in df.columns]
    return f"{what} has no column(s) {', '.join(miss)}" if miss else None


def _lacks(r: FigureResult, df: pd.DataFrame | None, cols: tuple[str, ...], what: str) -> bool:
    """Whether the table ``df`` (``what``) is missing or lacks any of ``cols``: then ``r`` is skipped with the reason."""
    r.skipped = _need(df, cols, what)
    return r.skipped is not None


# ------------------------------------------------------------------------------------------ CTD / depth
#: (variable, axis label without its unit, panel title); the unit comes from the variable registry
CTD_PANELS = (
    ("conductivity_s_m", "conductivity", "(a) conductivity"),
    ("temperature_its90_degc", "temperature ITS-90", "(b) temperature"),
    ("practical_salinity", "practical salinity", "(c) salinity"),
    ("density_kg_m3", "in situ density", "(d) density"),
    ("gravity_m_s2", "gravity", "(e) gravity"),
)


def fig_ctd_profiles(dp: DiveProducts, opt: FigureOptions) -> FigureResult:
    r = FigureResult("fig08_ctd_profiles", "Water-column profiles", "Water column",
                     "Measured conductivity and temperature, and the salinity, density and gravity derived from them, "
                     "against depth: descent wide pale blue, bottom bluish green, ascent thin dashed vermillion (cf. TERCOM paper "
                     "Fig. 8).")
    df = dp.ctd
    zcol = "depth_m" if df is not None and "depth_m" in df else "pressure_dbar"
    if _lacks(r, df, (zcol,), "ctd product"):
        return r
    assert df is not None  # _lacks said so
    panels = [p for p in CTD_PANELS if p[0] in df.columns]
    if not panels:
        r.skipped = "ctd product has none of " + ", ".join(p[0] for p in CTD_PANELS)
        return r
    missing = [p[0] for p in CTD_PANELS if p[0] not in df.columns]
    d = _thin(df, opt.max_points)
    fig = Figure(figsize=(opt.width_in, opt.width_in * 0.55))
    axes = fig.subplots(1, len(panels), sharey=True, squeeze=False)[0]
    for ax, (col, label, title) in zip(axes, panels, strict=True):
        for ph, g in _phases(d):
            if len(d) < 2000:  # a binned cast: few levels, draw them as a line with markers
                ax.plot(g[col], g[zcol], ".-", ms=3, lw=0.8, color=PHASE_COLOURS.get(ph, "k"), label=ph)
            else:  # descent wide and pale under a thin dashed ascent: both stay visible where they overlap
                sty = {"descent": {"lw": 3.2, "alpha": 0.55, "ls": "-"}, "ascent": {"lw": 1.0, "alpha": 1.0, "ls": "--"},
                       }.get(ph, {"lw": 1.5, "alpha": 0.9, "ls": "-"})
                ax.plot(g[col], g[zcol], color=PHASE_COLOURS.get(ph, "k"), label=ph, rasterized=True, **sty)
        ax.set_xlabel(axis_label(col, label))
        ax.set_title(title, fontsize=9)
        ax.grid(alpha=0.3)
        ax.tick_params(labelsize=8)
        ax.ticklabel_format(axis="x", useOffset=False)  # an offset label would overlap the axis label
        ax.xaxis.set_major_locator(MaxNLocator(3))
        # a narrow range (gravity over a shallow cast: 9.809758-9.809775) has long labels: slanted, they do not
        # run into each other in a narrow panel
        ax.tick_params(axis="x", labelrotation=30)
        for lbl in ax.get_xticklabels():
            lbl.set_horizontalalignment("right")
    axes[0].set_ylabel(axis_label(zcol, "depth" if zcol == "depth_m" else "pressure"))
    zmax = float(np.nanmax(pd.to_numeric(d[zcol], errors="coerce")))
    if np.isfinite(zmax) and zmax > 0:
        axes[0].set_ylim(zmax * 1.01, min(0.0, float(np.nanmin(pd.to_numeric(d[zcol], errors="coerce")))))
        axes[0].yaxis.set_major_locator(MaxNLocator(8))  # ticks down to the floor
    else:
        axes[0].invert_yaxis()
    axes[-1].legend(fontsize=7, loc="lower left")
    if missing:
        r.caption += f" Not available: {', '.join(missing)}."
    return _render(r, fig, opt)


def fig_depth_time(dp: DiveProducts, opt: FigureOptions) -> FigureResult:
    r = FigureResult("fig09_depth_time", "Vehicle depth during the dive", "Dive",
                     "Calibrated vehicle depth (hydrostatic integral of the fused pressure) during the whole dive, "
                     "coloured by phase; the deepest sample is marked (cf. TERCOM paper Fig. 9).")
    df = dp.ctd
    if _lacks(r, df, ("time", "depth_m"), "ctd product"):
        return r
    if not _has_time(df):
        return _depth_pressure(df, r, opt)
    d = _thin(df, opt.max_points)
    fig = Figure(figsize=(opt.width_in, opt.width_in * 0.4))
    ax = fig.subplots()
    for ph, g in _phases(d):
        ax.plot(_time(g), g["depth_m"], lw=1.2, color=PHASE_COLOURS.get(ph, "k"), label=ph)
    _mark_deepest(ax, df, _time, "time (UTC)", ms=14)
    fig.autofmt_xdate()
    return _render(r, fig, opt)


def _depth_pressure(df: pd.DataFrame, r: FigureResult, opt: FigureOptions) -> FigureResult:
    """A cast without times (pressure-binned): depth against pressure instead of time, with the
    Fofonoff-Millard cross-check."""
    if "pressure_dbar" not in df:
        r.skipped = "ctd product has no times and no pressure_dbar"
        return r
    r.title = "Depth against pressure (cast without time channel)"
    r.caption = ("The cast has no time channel (pressure-binned): depth from the hydrostatic integral (and "
                 "Fofonoff-Millard, when present) against pressure; the deepest level is marked.")
    fig = Figure(figsize=(opt.width_in * 0.6, opt.width_in * 0.45))
    ax = fig.subplots()
    ax.plot(df["pressure_dbar"], df["depth_m"], ".-", ms=3, lw=0.8, label="hydrostatic (depth_m)")
    if "depth_fofonoff_millard_m" in df:
        ax.plot(df["pressure_dbar"], df["depth_fofonoff_millard_m"], "--", lw=0.8, label="Fofonoff-Millard")
    _mark_deepest(ax, df, lambda rows: rows["pressure_dbar"], "pressure (dbar)", ms=12)
    return _render(r, fig, opt)


def _mark_deepest(ax, df: pd.DataFrame, x_of: Callable[[pd.DataFrame], object], xlabel: str, *, ms: float) -> None:
    """Star the deepest sample (at ``x_of(rows)``), depth increasing downwards, labels, grid and legend."""
    i = int(pd.to_numeric(df["depth_m"], errors="coerce").idxmax())
    ax.plot(x_of(df.loc[[i]]), [df.loc[i, "depth_m"]], "*", color="gold", mec="k", ms=ms,
            label=f"max {df.loc[i, 'depth_m']:.1f} m")
    ax.invert_yaxis()
    ax.set_xlabel(xlabel)
    ax.set_ylabel("depth (m)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)


def fig_seafloor_depth(dp: DiveProducts, opt: FigureOptions) -> FigureResult:
    r = FigureResult("fig10_seafloor_depth", "Seafloor depth from depth and altitude", "Dive",
                     "(a) vehicle depth, (b) altitude above the seafloor (single-beam altimeter, sound-speed corrected) "
                     "and (c) seafloor depth = depth + altitude, near the bottom (cf. TERCOM paper Fig. 10).")
    df = dp.ctd
    alt = "altitude_corrected_m" if df is not None and "altitude_corrected_m" in df else "altitude_m"
    if _lacks(r, df, ("time", "depth_m", alt, "seafloor_depth_m"), "ctd product"):
        return r
    if not _has_time(df):
        r.skipped = "cast without time channel (pressure-binned): no altimeter time series"
        return r
    d = df[np.isfinite(pd.to_numeric(df["seafloor_depth_m"], errors="coerce"))]
    if "phase" in d and (d["phase"].astype(str) == "bottom").any():
        d = d[d["phase"].astype(str) == "bottom"]
    if d.empty:
        r.skipped = ("no valid seafloor depth samples (no accepted altimeter reading: no bottom in range, missing "
                     "or flagged bad for the whole dive)")
        return r
    d = _thin(d, opt.max_points)
    t = _time(d)
    fig = Figure(figsize=(opt.width_in, opt.width_in * 0.6))
    axes = fig.subplots(3, 1, sharex=True)
    for ax, col, lab, c in ((axes[0], "depth_m", "(a) depth (m)", OKABE_ITO["blue"]),
                            (axes[1], alt, "(b) altitude (m)", OKABE_ITO["orange"]),
                            (axes[2], "seafloor_depth_m", "(c) seafloor depth (m)", OKABE_ITO["bluish_green"])):
        ax.plot(t, d[col], ".", ms=1.5, color=c, rasterized=True)
        ax.set_ylabel(lab, fontsize=8)
        ax.grid(alpha=0.3)
    axes[0].invert_yaxis()
    axes[2].invert_yaxis()
    axes[2].set_xlabel("time (UTC)")
    fig.autofmt_xdate()
    return _render(r, fig, opt)


# ------------------------------------------------------------------------------------------ maps
def _xy_extent(ds: xr.Dataset) -> list[float]:
    x, y = ds["x"].values, ds["y"].values
    dx = float(np.median(np.diff(x))) if x.size > 1 else 1.0
    dy = float(np.median(np.diff(y))) if y.size > 1 else 1.0
    return [x[0] - dx / 2, x[-1] + dx / 2, y[0] - dy / 2, y[-1] + dy / 2]


def _map(ax, ds: xr.Dataset, var: str, cmap, label: str, fig: Figure, km: bool = True, frame: str = "map frame"):
    s = 1e-3 if km else 1.0
    ext = [e * s for e in _xy_extent(ds)]
    im = ax.imshow(ds[var].values, origin="lower", extent=ext, cmap=cmap, aspect="equal", interpolation="nearest")
    fig.colorbar(im, ax=ax, label=label, shrink=0.85)
    unit = "km" if km else "m"
    ax.set_xlabel(f"x east ({unit}, {frame})")
    ax.set_ylabel(f"y north ({unit}, {frame})")
    return im


def _launch_xy(dp: DiveProducts) -> tuple[float, float] | None:
    """Launch point in the map frame: from fix.json, else the dive's launch projected with the map-frame
    origin recorded in the DTM/suitability attributes."""
    la = (dp.fix or {}).get("launch")
    if isinstance(la, dict) and la.get("x_east_m") is not None and la.get("y_north_m") is not None:
        return float(la["x_east_m"]), float(la["y_north_m"])
    if dp.launch and dp.launch.get("lat") is not None:
        for ds in (dp.dtm, dp.suitability, dp.msd):
            if ds is not None and "map_frame_origin_latitude_deg" in ds.attrs:
                from hadal.geo import LocalFrame

                fr = LocalFrame(float(ds.attrs["map_frame_origin_latitude_deg"]),
                                float(ds.attrs["map_frame_origin_longitude_deg"]))
                x, y = fr.to_xy(dp.launch["lon"], dp.launch["lat"])
                return float(x), float(y)
    return None


def _deep_xy(dp: DiveProducts) -> tuple[float, float] | None:
    dpnt = (dp.fix or {}).get("deepest_point")
    if isinstance(dpnt, dict) and dpnt.get("x_east_m") is not None:
        return float(dpnt["x_east_m"]), float(dpnt["y_north_m"])
    return None


def _grid_ok(ds: xr.Dataset | None, var: str, what: str) -> str | None:
    if ds is None:
        return f"no {what}"
    if var not in ds or not {"x", "y"} <= set(ds[var].dims):
        return f"{what} has no {var}(y, x)"
    return None


def fig_dtm(dp: DiveProducts, opt: FigureOptions) -> FigureResult:
    r = FigureResult("dtm_map", "Reference terrain (multibeam DTM)", "Terrain",
                     "Reference DTM gridded from the ship's multibeam soundings (depth positive down) with the matched "
                     "bottom track, when available.")
    if (why := _grid_ok(dp.dtm, "depth_m", "dtm product")) is not None:
        r.skipped = why
        return r
    if dp.dtm.attrs.get("dtm_source") == "prior_grid":
        r.title = "Reference terrain (prior bathymetry grid)"
        r.caption = ("Reference DTM resampled from the prior bathymetry grid onto the dive's map frame (depth "
                     "positive down), with the matched bottom track when available.")
    fig = Figure(figsize=(opt.width_in * 0.75, opt.width_in * 0.6))
    ax = fig.subplots()
    _map(ax, dp.dtm, "depth_m", CMAPS["depth"], "depth (m)", fig)
    handles = _draw_land(ax, dp.dtm)
    if handles:
        r.caption += " Land (above sea level in the source grid) is drawn as land: it has no depth."
    if dp.track is not None and {"x_east_m", "y_north_m"} <= set(dp.track.columns):
        tr = _thin(dp.track, opt.max_points)
        ax.plot(tr["x_east_m"] * 1e-3, tr["y_north_m"] * 1e-3, "-", color="w", lw=1.5, label="matched track")
    if handles or (dp.track is not None and {"x_east_m", "y_north_m"} <= set(dp.track.columns)):
        ax.legend(handles=[*ax.get_legend_handles_labels()[0], *handles], fontsize=8, loc="upper right")
    return _render(r, fig, opt)


#: colour of land cells on DTM maps
LAND_COLOUR = "#c9b27c"


def _draw_land(ax, ds: xr.Dataset) -> list:
    """Land cells of a DTM (``land`` = 1: above sea level in the prior grid, no depth) drawn in
    :data:`LAND_COLOUR` over the depth map (km axes); returns the legend handle (empty without land)."""
    if "land" not in ds or not {"x", "y"} <= set(ds["land"].dims):
        return []
    land = np.asarray(ds["land"].transpose("y", "x").values) == 1
    if not land.any():
        return []
    from matplotlib.colors import ListedColormap
    from matplotlib.patches import Patch

    ext = [e * 1e-3 for e in _xy_extent(ds)]
    ax.imshow(np.ma.masked_where(~land, np.ones(land.shape)), origin="lower", extent=ext,
              cmap=ListedColormap([LAND_COLOUR]), aspect="equal", interpolation="nearest", vmin=0, vmax=1)
    return [Patch(facecolor=LAND_COLOUR, edgecolor="none", label="land")]


def _region(ds: xr.Dataset) -> dict | None:
    reg = ds.attrs.get("proposed_region")
    if isinstance(reg, str):
        try:
            reg = json.loads(reg)
        except ValueError:
            return None
    return reg if isinstance(reg, dict) and {"x_min_m", "x_max_m", "y_min_m", "y_max_m"} <= set(reg) else None


def fig_suitability(dp: DiveProducts, opt: FigureOptions) -> FigureResult:
    r = FigureResult("fig05_06_suitability", "Terrain suitability for matching", "Terrain",
                     "(left) terrain elevation standard deviation and (right) topographic information entropy per block "
                     "(cf. TERCOM paper Figs. 5-6); dashed: proposed matching region, x: launch point.")
    ds = dp.suitability
    if ds is None:
        r.skipped = "no suitability product"
        return r
    if _launch_xy(dp) is None:
        r.caption = r.caption.replace(", x: launch point.", ".")
    panels = [(v, lab, cm) for v, lab, cm in (("std_m", "elevation std (m)", CMAPS["std"]),
                                              ("entropy", "information entropy", CMAPS["entropy"]))
              if _grid_ok(ds, v, "suitability") is None]
    if not panels:
        r.skipped = "suitability product has neither std_m(y, x) nor entropy(y, x)"
        return r
    fig = Figure(figsize=(opt.width_in, opt.width_in * 0.4))
    axes = fig.subplots(1, len(panels), squeeze=False)[0]
    reg = _region(ds)
    launch = _launch_xy(dp)
    for ax, (v, lab, cm) in zip(axes, panels, strict=True):
        _map(ax, ds, v, cm, lab, fig)
        if reg:
            xs = np.array([reg["x_min_m"], reg["x_max_m"], reg["x_max_m"], reg["x_min_m"], reg["x_min_m"]]) * 1e-3
            ys = np.array([reg["y_min_m"], reg["y_min_m"], reg["y_max_m"], reg["y_max_m"], reg["y_min_m"]]) * 1e-3
            ax.plot(xs, ys, "--", color="k", lw=1.2)
        if launch:
            ax.plot(launch[0] * 1e-3, launch[1] * 1e-3, "x", color="r", ms=9, mew=2)
    return _render(r, fig, opt)


def _score_var(ds: xr.Dataset) -> str | None:
    for v in ("score", "msd", "msd_m2"):
        if v in ds and {"x", "y"} <= set(ds[v].dims):
            return v
    cands = [v for v in ds.data_vars if {"x", "y"} <= set(ds[v].dims) and v not in ("lat", "lon")]
    return str(cands[0]) if cands else None


def fig_msd_surface(dp: DiveProducts, opt: FigureOptions) -> FigureResult:
    r = FigureResult("fig16_msd_surface", "TERCOM criterion surface", "Terrain matching",
                     "Matching criterion (MSD) of the measured seafloor-depth profile for every start position of the "
                     "track on the reference map; the minimum (white circle) is the TERCOM fix (cf. TERCOM paper §4.2, Fig. 16).")
    ds = dp.msd
    if ds is None:
        r.skipped = "no match product (msd_surface.nc)"
        return r
    v = _score_var(ds)
    if v is None:
        r.skipped = "msd_surface.nc has no (y, x) criterion variable"
        return r
    crit = str(ds.attrs.get("criterion", "msd")).upper()
    vals = ds[v].values.astype(float)
    fig = Figure(figsize=(opt.width_in * 0.75, opt.width_in * 0.6))
    ax = fig.subplots()
    show = ds.copy()
    finite = vals[np.isfinite(vals)]
    if finite.size and crit != "COR" and finite.min() > 0:
        show[v] = (ds[v].dims, np.log10(vals))
        label = f"log10 {crit} ({ds[v].attrs.get('units', '')})"
    else:
        label = f"{crit} ({ds[v].attrs.get('units', '')})"
    _map(ax, show, v, CMAPS["msd"], label, fig)
    bx, by = ds.attrs.get("best_x_m"), ds.attrs.get("best_y_m")
    if bx is None and finite.size:
        iy, ix = np.unravel_index(np.nanargmin(vals) if crit != "COR" else np.nanargmax(vals), vals.shape)
        bx, by = float(ds["x"][ix]), float(ds["y"][iy])
    if bx is not None:
        ax.plot(float(bx) * 1e-3, float(by) * 1e-3, "o", mfc="none", mec="w", ms=14, mew=2, label="best match")
    sm = ((dp.fix or {}).get("posterior") or {}).get("second_mode")
    if isinstance(sm, dict) and sm.get("x") is not None and float(sm.get("mass") or 0) > 0.01:
        ax.plot(float(sm["x"]) * 1e-3, float(sm["y"]) * 1e-3, "D", mfc="none", mec="c", ms=11, mew=2,
                label=f"second mode ({100 * float(sm['mass']):.0f} % of the posterior mass)")
        r.caption += " Cyan diamond: the posterior's second mode."
    if bx is not None or ax.get_legend_handles_labels()[0]:  # dark legend: the markers are white/cyan
        ax.legend(fontsize=8, loc="upper right", facecolor="0.3", labelcolor="w", framealpha=0.85)
    return _render(r, fig, opt)


def _track_depths(tr: pd.DataFrame, max_points: int) -> tuple[pd.DataFrame, Any, str]:
    """The matched track thinned to ``max_points``, its x axis (sample times, else sample numbers) and its
    reference-depth column (the map depth minus the bias when the match estimated one)."""
    tr = _thin(tr, max_points)
    xaxis = _time(tr) if "time" in tr else np.arange(len(tr))
    ref = "map_depth_minus_bias_m" if "map_depth_minus_bias_m" in tr else "map_depth_m"
    return tr, xaxis, ref


def _plot_track_depths(ax, tr: pd.DataFrame, xaxis, ref: str, rasterized: bool = False) -> None:
    """Measured seafloor depth (dots) and the reference map's (line) along the matched track, depth down."""
    ax.plot(xaxis, tr["seafloor_depth_m"], ".", ms=2, label="measured (depth + altitude)", color=OKABE_ITO["blue"],
            rasterized=rasterized)
    ax.plot(xaxis, tr[ref], "-", lw=1.5, label="reference map" + (" − bias" if ref != "map_depth_m" else ""),
            color=OKABE_ITO["vermillion"])
    ax.invert_yaxis()
    ax.set_ylabel("seafloor depth (m)")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)


def fig_matched_depth(dp: DiveProducts, opt: FigureOptions) -> FigureResult:
    r = FigureResult("fig16_matched_depth", "Measured vs reference depth along the matched track", "Terrain matching",
                     "Seafloor depth measured by the vehicle and the reference-map depth at the matched positions "
                     "(bias-corrected when the match estimated a bias), cf. TERCOM paper Fig. 16.")
    tr = dp.track
    if _lacks(r, tr, ("seafloor_depth_m", "map_depth_m"), "matched track"):
        return r
    tr, xaxis, ref = _track_depths(tr, opt.max_points)
    fig = Figure(figsize=(opt.width_in, opt.width_in * 0.4))
    ax = fig.subplots()
    _plot_track_depths(ax, tr, xaxis, ref)
    ax.set_xlabel("time (UTC)" if "time" in tr else "sample")
    if "time" in tr:
        fig.autofmt_xdate()
    return _render(r, fig, opt)


def fig_matched_track(dp: DiveProducts, opt: FigureOptions) -> FigureResult:
    r = FigureResult("fig17_matched_track", "Matched track on the reference map", "Terrain matching",
                     "Bottom track placed on the reference terrain by the match; x: launch point, *: deepest point "
                     "(cf. TERCOM paper Fig. 17).")
    tr = dp.track
    if _lacks(r, tr, ("x_east_m", "y_north_m"), "matched track"):
        return r
    fig = Figure(figsize=(opt.width_in * 0.75, opt.width_in * 0.6))
    ax = fig.subplots()
    pts = [tr["x_east_m"].to_numpy(float), tr["y_north_m"].to_numpy(float)]
    launch, deep = _launch_xy(dp), _deep_xy(dp)
    for p in (launch, deep):
        if p:
            pts[0] = np.append(pts[0], p[0])
            pts[1] = np.append(pts[1], p[1])
    if dp.dtm is not None and _grid_ok(dp.dtm, "depth_m", "dtm") is None:
        pad = 600.0
        sub = dp.dtm.sel(x=slice(np.nanmin(pts[0]) - pad, np.nanmax(pts[0]) + pad),
                         y=slice(np.nanmin(pts[1]) - pad, np.nanmax(pts[1]) + pad))
        if sub.sizes.get("x", 0) > 1 and sub.sizes.get("y", 0) > 1:
            _map(ax, sub, "depth_m", CMAPS["depth"], "reference depth (m)", fig, km=False)
            cs = ax.contour(sub["x"].values, sub["y"].values, sub["depth_m"].values, levels=8, colors="k",
                            linewidths=0.5, alpha=0.6)
            ax.clabel(cs, fontsize=6, fmt="%.0f")
    t = _thin(tr, opt.max_points)
    ax.plot(t["x_east_m"], t["y_north_m"], "-", color="w", lw=2.2)
    ax.plot(t["x_east_m"], t["y_north_m"], "-", color="m", lw=1.2, label="matched track")
    if launch:
        ax.plot(*launch, "x", color="r", ms=11, mew=2.5, label="launch")
    if deep:
        ax.plot(*deep, "*", color="gold", mec="k", ms=16, label="deepest point")
    ax.set_xlabel("x east (m, map frame)")
    ax.set_ylabel("y north (m, map frame)")
    ax.set_aspect("equal")
    ax.legend(fontsize=8, loc="best")
    return _render(r, fig, opt)


# ------------------------------------------------------------------------------------------ laser grids
def fig_laser_grids(dp: DiveProducts, opt: FigureOptions) -> FigureResult:
    """The ``laser_grids`` product: one map per grid (at most :data:`hadal.report.load.MAX_LASER_FIGURES`, the rest
    listed in the summary) of ``elevation_m`` in the grid's own metric frame (x/y of its cell centres, m, as
    published), each with its colour bar, its extent and its elevation range in the panel title."""
    r = FigureResult("laser_grids", "Laser elevation grids", "Terrain",
                     "Elevation (m, positive up) of each laser grid in its own metric frame (x/y in m as published; "
                     "local laser frame unless the source had a projected CRS); NaN cells (no points) are blank.")
    if not dp.laser_grids:
        r.skipped = "no laser_grids product"
        return r
    n = len(dp.laser_grids)
    ncols = 1 if n == 1 else 2
    nrows = (n + ncols - 1) // ncols
    w = opt.width_in * (0.7 if n == 1 else 1.0)
    fig = Figure(figsize=(w, w / ncols * 0.85 * nrows), layout="constrained")
    axes = np.atleast_1d(fig.subplots(nrows, ncols)).ravel()
    thinned = []
    for ax, (name, ds) in zip(axes, dp.laser_grids, strict=False):
        z = ds["elevation_m"].values
        ext = _xy_extent(ds)
        im = ax.imshow(z, origin="lower" if ds["y"].values[0] < ds["y"].values[-1] else "upper",
                       extent=[ext[0], ext[1], min(ext[2], ext[3]), max(ext[2], ext[3])], cmap=CMAPS["elev"],
                       aspect="equal", interpolation="nearest")
        _inset_colorbar(fig, im, ax, "elevation (m)", fontsize=8)
        fin = z[np.isfinite(z)]
        rng = f"{fin.min():.2f} .. {fin.max():.2f} m" if fin.size else "no data"
        res = ds.attrs.get("resolution_m")
        ax.set_title(f"{name}\n{'cell ' + format(float(res), 'g') + ' m, ' if res else ''}elevation {rng}", fontsize=9)
        frame = ("local frame" if ds.attrs.get("source_crs_kind") in (None, "local_metric")
                 else str(ds.attrs.get("source_crs_name") or "grid CRS"))  # the grid's own CRS, by name
        ax.set_xlabel(f"x (m, {frame})", fontsize=8)
        ax.set_ylabel(f"y (m, {frame})", fontsize=8)
        ax.tick_params(labelsize=7)
        ax.ticklabel_format(useOffset=False, style="plain")  # projected coordinates in full (494 200, not 1e6 +)
        if int(ds.attrs.get("thinned_by", 1)) > 1:
            thinned.append(f"{name} every {int(ds.attrs['thinned_by'])}th cell")
    for ax in axes[n:]:
        ax.set_visible(False)
    if thinned:
        r.caption += f" Drawn thinned: {', '.join(thinned)}."
    if len(dp.laser_info) > n:
        r.caption += f" {len(dp.laser_info)} grids: the first {n} are drawn; all are listed in the Laser grids table."
    return _render(r, fig, opt, tight=True)


# ------------------------------------------------------------------------------------------ landing
def _inset_colorbar(fig: Figure, im, ax, label: str, fontsize: float | None = None):
    """A vertical colour bar just right of ``ax``'s drawn (aspect-adjusted) box, as tall as it: it moves with
    the axes, and constrained layout reserves its room from the axes' tight box."""
    cb = fig.colorbar(im, cax=ax.inset_axes((1.02, 0.0, 0.03, 1.0)), orientation="vertical")
    cb.set_label(label, fontsize=fontsize)
    if fontsize:
        cb.ax.tick_params(labelsize=fontsize)
    return cb


def fig_landing_map(dp: DiveProducts, opt: FigureOptions) -> FigureResult:
    r = FigureResult("landing_map", "Best landing site", "Landing sites",
                     "Laser elevation of the submap holding the dive's lowest-cost landing site (top: the whole strip; "
                     "bottom: zoom on the site, with its own colour range); hatched (top) / greyed (zoom): cells where "
                     "the vehicle's centre of gravity may not land at the site's heading (for every heading when "
                     "there is no site); red: the selected site and its largest inscribed circle; yellow: the "
                     "vehicle footprint at the chosen heading (arrow: bow) (cf. landing paper Figs. 19 and 25).")
    if not dp.landing_maps:
        r.skipped = "no landing product maps (submap_NN_maps.nc)"
        return r
    best, best_name, path = _best_landing_site(dp)
    try:
        with xr.open_dataset(path, engine="h5netcdf") as ds:
            ds = ds.load()
    except Exception as exc:
        r.skipped = f"{path.name} is unreadable ({type(exc).__name__})"
        return r
    if _grid_ok(ds, "elevation_m", path.name) is not None:
        r.skipped = f"{path.name} has no elevation_m(y, x)"
        return r
    x, y = ds["x"].values, ds["y"].values
    heading = float(best["heading_deg"]) if best is not None and "heading_deg" in best else None
    ex, site = _landing_masks(ds, heading)
    has_best = best is not None and {"x_m", "y_m"} <= set(best.index)
    # a submap is a long strip (25 m x 1.5 m): the whole strip on top, a zoom on the site below
    fig = Figure(figsize=(opt.width_in, opt.width_in * 0.62), layout="constrained")
    ax_all, ax = fig.subplots(2, 1, height_ratios=[1, 3])
    ext = _xy_extent(ds)
    elev = np.asarray(ds["elevation_m"].transpose("y", "x").values, float)
    zoom_lim = None
    if has_best:  # colour range of the zoom: the elevations around the site (the strip's range hides its relief)
        bx0 = float(best["x_m"])
        win = elev[:, (x > bx0 - 1.5) & (x < bx0 + 1.5)]
        if np.isfinite(win).any():
            zoom_lim = (float(np.nanpercentile(win, 1)), float(np.nanpercentile(win, 99)))
    ims = {}
    for a_ in (ax_all, ax):
        lim = zoom_lim if a_ is ax and zoom_lim else (None, None)
        ims[a_] = a_.imshow(elev, origin="lower", extent=ext, cmap=CMAPS["elev"], aspect="equal",
                            interpolation="nearest", vmin=lim[0], vmax=lim[1])
        if ex is not None:
            if a_ is ax_all:
                a_.contourf(x, y, ex, levels=[0.5, 1.5], colors="none", hatches=["///"])
            else:  # the zoom: a light grey veil keeps the relief readable under the excluded cells
                a_.contourf(x, y, ex, levels=[0.5, 1.5], colors=["0.85"], alpha=0.55)
        if site is not None:
            a_.contourf(x, y, site, levels=[0.5, 1.5], colors=["red"], alpha=0.45)
        if has_best:
            a_.plot(float(best["x_m"]), float(best["y_m"]), "*", color="red", mec="k", ms=14 if a_ is ax else 8)
    im = ims[ax_all]
    ax_all.tick_params(labelsize=7)
    ax_all.set_ylabel("y (m)", fontsize=7)
    rot = float(ds.attrs.get("frame_rotation_deg", 0.0) or 0.0)
    if has_best:
        _draw_best_site(ax, ax_all, best, heading, rot, ext, x, y, (dp.landing_meta or {}).get("vehicle") or {})
    xl, yl = _landing_frame_caption(r, dp, rot)
    ax.set_xlabel(xl)
    ax.set_ylabel(yl)
    # colour bars in insets of their own axes: ``fig.colorbar(ax=...)`` anchors an equal-aspect axes to the east of
    # its layout box (the colour bar's ``panchor``), so constrained layout left the canvas' left half empty and the
    # tall label of the short strip's bar poked out of the top (a 596 x 714 PNG of an 1100 x 682 figure)
    _inset_colorbar(fig, im, ax_all, "elevation (m)\nwhole strip", fontsize=7)
    if zoom_lim:
        _inset_colorbar(fig, ims[ax], ax, "elevation (m, up), around the site")
    title = path.name.replace("_maps.nc", "")
    if has_best:
        title += f": best site, cost {float(best['c_s']):.3f}" + (f", heading {heading:.0f}°" if heading is not None else "")
    else:
        title += ": no landing site found" if best_name is None else f" (maps of the best submap {best_name} missing)"
    ax_all.set_title(title, fontsize=9)
    # the whole canvas: constrained layout keeps everything on it, and cropping to the content would make the
    # PNG's shape follow the map's aspect instead of the figure's
    return _render(r, fig, opt, tight=False)


def _best_landing_site(dp: DiveProducts) -> tuple[Any, str | None, Any]:
    """The lowest-cost best site (or ``None``), its submap's name and the maps file :func:`fig_landing_map` draws."""
    best = None
    s = dp.landing_sites
    if s is not None and {"submap", "c_s"} <= set(s.columns) and len(s):
        if "is_best" in s:
            s = s[s["is_best"].astype(bool)]
        if len(s):
            best = s.sort_values("c_s").iloc[0]
    best_name = str(best["submap"]) if best is not None else None
    path = next((p for p in dp.landing_maps if best_name and p.name == f"{best_name}_maps.nc"), None)
    if path is None:  # the best site's submap has no maps file: show the first submap without a site
        path, best = dp.landing_maps[0], None
    return best, best_name, path


def _landing_masks(ds: xr.Dataset, heading: float | None) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The (y, x) exclusion mask at ``heading`` (every heading when ``None``) and the final site's mask."""
    ex = None
    if "exclusion" in ds:
        ex = ds["exclusion"]
        if "heading" in ex.dims:
            ex = ex.sel(heading=heading, method="nearest") if heading is not None else (ex > 0).min(dim="heading")
        extra = [d for d in ex.dims if d not in ("y", "x")]
        ex = (ex > 0).max(dim=extra) if extra else ex > 0
        ex = np.asarray(ex.transpose("y", "x").values, float)
    site = None
    if "final_site" in ds and {"y", "x"} <= set(ds["final_site"].dims) and float(ds["final_site"].max()) > 0:
        site = np.asarray(ds["final_site"].transpose("y", "x").values, float)
    return ex, site


def _draw_best_site(ax: Any, ax_all: Any, best: Any, heading: float | None, rot: float, ext: Any,
                    x: np.ndarray, y: np.ndarray, veh: dict[str, Any]) -> None:
    """The best site on the landing map: vehicle footprint and bow arrow, zoom range, inscribed circle."""
    bx, by = float(best["x_m"]), float(best["y_m"])
    if {"row", "col"} <= set(best.index) and 0 <= int(best["col"]) < x.size and 0 <= int(best["row"]) < y.size:
        bx, by = float(x[int(best["col"])]), float(y[int(best["row"])])  # the maps' own (analysis) frame
    rad = float(best["radius_m"]) if "radius_m" in best.index else 0.3
    if heading is not None and veh.get("length_m") and veh.get("width_m"):
        from matplotlib.patches import Polygon

        from hadal.products.geo_landing import footprint_corners

        poly = footprint_corners(bx, by, heading - rot, float(veh["length_m"]), float(veh["width_m"]))
        ax.add_patch(Polygon(poly, closed=True, fill=False, ec="yellow", lw=2,
                             label=f"vehicle footprint {float(veh['length_m']):g} m x {float(veh['width_m']):g} m "
                                   f"at heading {heading:.0f}°"))
        ax.annotate("", xy=(bx + 0.6 * float(veh["length_m"]) * np.sin(np.radians(heading - rot)),
                            by + 0.6 * float(veh["length_m"]) * np.cos(np.radians(heading - rot))),
                    xytext=(bx, by), arrowprops={"arrowstyle": "->", "color": "yellow", "lw": 1.5})
    half = max(1.5, 4 * rad)
    z0, z1 = max(ext[0], bx - half), min(ext[1], bx + half)  # the zoom's x range, within the map
    ax.set_xlim(z0, z1)
    ax_all.add_patch(Rectangle((z0, ext[2]), z1 - z0, ext[3] - ext[2], fill=False, ec="red", lw=1))
    t = np.linspace(0, 2 * np.pi, 100)
    ax.plot(bx + rad * np.cos(t), by + rad * np.sin(t), "-", color="red", lw=1.5, label="largest inscribed circle")
    ax.legend(fontsize=7, loc="upper right")


def _landing_frame_caption(r: FigureResult, dp: DiveProducts, rot: float) -> tuple[str, str]:
    """Add the laser frame (and analysis-frame rotation) to ``r``'s caption; returns the x/y axis labels."""
    lf = (dp.landing_summary or {}).get("laser_frame")
    if isinstance(lf, dict):
        r.caption += (f" Laser frame: local x/y (m) of the laser survey, georeferenced by dive.yaml laser_frame "
                      f"(origin {lf.get('origin_latitude_deg')}°N {lf.get('origin_longitude_deg')}°E, +y axis at "
                      f"{lf.get('heading_deg')}° from true north); the sites' lat/lon are in landing_sites.parquet "
                      "and the footprints in landing_footprints.geojson.")
        xl, yl = "x (m, laser frame)", "y (m, laser frame)"
    else:
        r.caption += " Laser frame: local x/y (m) of the laser survey (not georeferenced: dive.yaml has no laser_frame)."
        xl, yl = "x (m, laser frame)", "y (m, laser frame)"
    if rot:
        r.caption += f" The maps are in the along-track analysis frame, rotated by {rot:.1f}° from the laser frame."
    return xl, yl


FIGURES: tuple[Callable[[DiveProducts, FigureOptions], FigureResult], ...] = (
    fig_depth_time, fig_ctd_profiles, fig_seafloor_depth, fig_dtm, fig_laser_grids, fig_suitability,
    fig_msd_surface, fig_matched_depth, fig_matched_track, fig_landing_map,
)


def all_figures(dp: DiveProducts | None = None) -> tuple[Callable[[DiveProducts, FigureOptions], FigureResult], ...]:
    """The report's figures in order: :data:`FIGURES` with the geographic overview first, the T-S/θ/N² figure
    after the CTD profiles (then, when ``dp`` has underway records or is not given, their track/section figure)
    and the residual panel in place of the plain matched-depth figure."""
    from hadal.report.ctd_figures import fig_underway, fig_water_column
    from hadal.report.geo_figures import (
        fig_dtm_geo,
        fig_dtm_quality,
        fig_matched_track_geo,
        fig_msd_geo,
        fig_nav_uncertainty,
        fig_overview,
        fig_residuals,
        fig_suitability_geo,
    )

    geographic: dict[Callable[[DiveProducts, FigureOptions], FigureResult],
                     Callable[[DiveProducts, FigureOptions], FigureResult]] = {fig_suitability: fig_suitability_geo, fig_msd_surface: fig_msd_geo,
                  fig_matched_track: fig_matched_track_geo, fig_matched_depth: fig_residuals}

    out: list[Callable[[DiveProducts, FigureOptions], FigureResult]] = [fig_overview]
    # a dive whose only CTD record is underway has a trajectory instead of ctd/profile: no cast figures for it
    underway_only = dp is not None and bool(dp.trajectories) and "ctd" not in dp.versions
    cast_figures = (fig_depth_time, fig_ctd_profiles, fig_seafloor_depth)
    for fn in FIGURES:
        if underway_only and fn in cast_figures:
            if fn is fig_ctd_profiles:
                out.append(fig_underway)
            continue
        if fn is fig_dtm:  # the DTM on a geographic map, with its coverage, density and uncertainty
            out += [fig_dtm_geo, fig_dtm_quality]
            continue
        out.append(geographic.get(fn, fn))
        if fn is fig_depth_time:
            out.append(fig_nav_uncertainty)
        if fn is fig_ctd_profiles:
            out.append(fig_water_column)
            if dp is None or dp.trajectories:
                out.append(fig_underway)
    return tuple(out)


def _figure_or_skip(fn: Callable[[DiveProducts, FigureOptions], FigureResult], dp: DiveProducts,
                    opt: FigureOptions) -> FigureResult:
    try:
        return fn(dp, opt)
    except Exception as exc:  # defensive: unexpected product content must not sink the whole report
        name = fn.__name__.removeprefix("fig_")
        return FigureResult(name, name.replace("_", " "), "Other", "", skipped=f"could not draw ({type(exc).__name__}: {exc})")


def make_figures(dp: DiveProducts, opt: FigureOptions | None = None) -> list[FigureResult]:
    """All report figures; a figure that fails to draw is skipped with the reason (never fails the report). With
    ``opt.workers`` > 1 they are drawn in that many processes (:class:`hadal.forkpool.ForkPool`), in the same order."""
    from hadal.forkpool import ForkPool

    opt = opt or FigureOptions()
    with ForkPool(1 if opt.keep_figure else opt.workers) as pool:
        products = pool.share(dp)  # every figure reads them: sent to a helper process once
        for fn in all_figures(dp):
            pool.submit(_figure_or_skip, fn, products, opt)
        return pool.results()
