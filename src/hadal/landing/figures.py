"""Figures in the style of Sangekar et al.: Fig. 13 (slope exclusion), Fig. 18 (protrusion exclusion),
Fig. 19 (sites and landing point), Fig. 21 (site costs vs heading) and Fig. 25 (final sites along the
transect). Matplotlib with the Agg backend and cmocean colour maps; every function writes one PNG."""

from __future__ import annotations

import math
from collections.abc import Mapping
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import warnings  # noqa: E402

with warnings.catch_warnings():  # cmocean < 4 passes N= to ListedColormap (deprecated in matplotlib 3.11)
    warnings.simplefilter("ignore")
    import cmocean  # noqa: E402
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import pandas as pd  # noqa: E402
from matplotlib.colors import ListedColormap  # noqa: E402
from matplotlib.patches import Circle, Polygon  # noqa: E402
from scipy import ndimage as ndi  # noqa: E402

from hadal.landing.exclusion import HIGH_PROTRUSION, SLOPE, UNMAPPED  # noqa: E402
from hadal.landing.sites import LandingResult  # noqa: E402

_BIN = ListedColormap(["#f2f2f2", "#1f4e79"])
#: allowed / excluded in Okabe-Ito colours (sky blue / vermillion: told apart with any common colour-vision deficiency)
_EXCL = ListedColormap(["#56B4E9", "#D55E00"])


def _panels(res: LandingResult, n: int, title: str):
    ny, nx = res.elevation_m.shape
    h_m, w_m = ny * res.cell_m, nx * res.cell_m
    ratio = h_m / w_m
    if ratio > 2.0:  # tall strip: panels side by side
        fig_h = 9.0
        pw = max(2.3, fig_h / ratio + 1.2)
        fig, axes = plt.subplots(1, n, figsize=(min(22.0, pw * n + 0.5), fig_h), squeeze=False, layout="compressed")
    elif ratio < 0.5:  # wide strip: panels stacked
        fig_w = 9.0
        ph = max(1.4, fig_w * ratio + 0.6)
        fig, axes = plt.subplots(n, 1, figsize=(fig_w, min(22.0, ph * n + 0.5)), squeeze=False, layout="compressed")
    else:
        ncol = int(math.ceil(math.sqrt(n)))
        nrow = int(math.ceil(n / ncol))
        fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 4.2 * ratio * nrow + 0.6), squeeze=False,
                                 layout="compressed")
        for ax in axes.ravel()[n:]:
            ax.set_axis_off()
    fig.suptitle(title, fontsize=10)
    return fig, list(axes.ravel())


def _show(ax, res: LandingResult, img, cmap, label: str, vmin=None, vmax=None, cbar: bool = True):
    c = res.cell_m
    ext = (res.x_m[0] - c / 2, res.x_m[-1] + c / 2, res.y_m[0] - c / 2, res.y_m[-1] + c / 2)
    im = ax.imshow(img, origin="lower", extent=ext, cmap=cmap, vmin=vmin, vmax=vmax, interpolation="nearest")
    ax.set_title(label, fontsize=8)
    ax.set_aspect("equal")
    ax.tick_params(labelsize=6)
    ax.set_xlabel("x (m)", fontsize=7)
    ax.set_ylabel("y (m)", fontsize=7)
    if cbar:  # a labelled colorbar as tall as the panel (strips are flat: a short bar is unreadable)
        flat = (ext[3] - ext[2]) < 0.5 * (ext[1] - ext[0])
        cb = plt.colorbar(im, ax=ax, shrink=1.0, aspect=5 if flat else 20, pad=0.01)
        cb.ax.tick_params(labelsize=6)
        cb.set_label(label.split(") ", 1)[-1], fontsize=6)
    return im


def _heading_index(res: LandingResult, heading: float | None) -> tuple[int, float]:
    if heading is None:
        heading = float(res.best["heading_deg"]) if res.best else float(res.headings_deg[0])
    k = int(np.argmin(np.abs(res.headings_deg - heading)))
    return k, float(res.headings_deg[k])


def _footprint_polygon(x: float, y: float, heading_deg: float, length: float, width: float) -> np.ndarray:
    a = math.radians(heading_deg)
    es = np.array([math.sin(a), math.cos(a)])
    et = np.array([math.cos(a), -math.sin(a)])
    return np.array([[x, y] + sl * length / 2 * es + st * width / 2 * et for sl, st in ((1, 1), (1, -1), (-1, -1), (-1, 1))])


def figure_slope_exclusion(res: LandingResult, path: str | Path, heading_deg: float | None = None) -> Path:
    """Fig. 13: a) mapped area, b) where C_G can enter, c) footprint slope, d) slope exclusion θ > θc."""
    k, hd = _heading_index(res, heading_deg)
    ex = res.exclusion[k]
    fig, ax = _panels(res, 4, f"Exclusion for slope, landing heading {hd:.0f}° (θc = {res.critical_slope_deg:.1f}°)")
    _show(ax[0], res, np.isfinite(res.elevation_m).astype(int), _BIN, "a) mapped area", 0, 1, cbar=False)
    _show(ax[1], res, ((ex & UNMAPPED) == 0).astype(int), _BIN, "b) C_G can enter", 0, 1, cbar=False)
    # LandingResult keeps the footprint slope of the selected heading (of the first heading without a site)
    fp_heading = float(res.best["heading_deg"]) if res.best else float(res.headings_deg[0])
    fp = res.footprint_slope_deg if abs(fp_heading - hd) < 1e-6 else None
    if fp is not None:
        _show(ax[2], res, fp, cmocean.cm.amp, "c) footprint slope (°)", 0, max(30.0, res.critical_slope_deg * 1.5))
    else:
        ax[2].set_axis_off()
    sl = np.where((ex & UNMAPPED) != 0, np.nan, ((ex & SLOPE) != 0).astype(float))
    _show(ax[3], res, sl, _EXCL, "d) C_G exclusion θ > θc", 0, 1, cbar=False)
    return _save(fig, path)


def figure_protrusion_exclusion(res: LandingResult, path: str | Path, heading_deg: float | None = None) -> Path:
    """Fig. 18: a) slope map, b) protrusion heights, c) exclusion h ≤ h_c, d) protrusions h > h_c,
    e) exclusion for h > h_c at the landing heading."""
    k, hd = _heading_index(res, heading_deg)
    ex = res.exclusion[k]
    mapped = np.isfinite(res.elevation_m)
    fig, ax = _panels(res, 5, f"Exclusion for protrusions (h_c = {res.vehicle.critical_height_m * 100:.1f} cm), heading {hd:.0f}°")
    _show(ax[0], res, res.slope_local_deg, cmocean.cm.amp, "a) slope (°)", 0, 45)
    hp = np.where(res.protrusion_candidate, res.protrusion_height_m * 100, np.nan)
    _show(ax[1], res, np.where(mapped, 0, np.nan), ListedColormap(["#dddddd"]), "", cbar=False)
    hmax = float(np.nanpercentile(hp, 99)) if np.isfinite(hp).any() else 1.0
    _show(ax[1], res, hp, cmocean.cm.thermal, "b) protrusion height h (cm)", 0, max(1.0, hmax))
    _show(ax[2], res, np.where(mapped, res.small_exclusion.astype(float), np.nan), _EXCL, "c) C_G exclusion h ≤ h_c", 0, 1, cbar=False)
    _show(ax[3], res, np.where(mapped, res.high_protrusion.astype(float), np.nan), _BIN, "d) protrusions h > h_c", 0, 1, cbar=False)
    hi = np.where(mapped, ((ex & HIGH_PROTRUSION) != 0).astype(float), np.nan)
    _show(ax[4], res, hi, _EXCL, f"e) C_G exclusion h > h_c at {hd:.0f}°", 0, 1, cbar=False)
    return _save(fig, path)


def figure_sites(res: LandingResult, path: str | Path, heading_deg: float | None = None) -> Path:
    """Fig. 19: a) full C_G exclusion, b) candidate sites, c) landing point (inscribed circle, footprint)."""
    k, hd = _heading_index(res, heading_deg)
    ex = res.exclusion[k]
    mapped = np.isfinite(res.elevation_m)
    fig, ax = _panels(res, 3, f"Landing sites, heading {hd:.0f}°")
    _show(ax[0], res, np.where(mapped, (ex != 0).astype(float), np.nan), _EXCL, "a) full C_G exclusion", 0, 1, cbar=False)
    lab, _ = ndi.label(ex == 0, structure=np.ones((3, 3), bool))
    sites = res.sites[np.isclose(res.sites["heading_deg"], hd)] if len(res.sites) else res.sites
    show = np.where(np.isin(lab, sites["site_id"].to_numpy()) if len(sites) else False, lab, 0).astype(float)
    show[show == 0] = np.nan
    _show(ax[1], res, np.where(mapped, 0, np.nan), ListedColormap(["#dddddd"]), "", cbar=False)
    _show(ax[1], res, show, "tab20", f"b) candidate sites ({len(sites)})", cbar=False)
    _show(ax[2], res, res.elevation_m, cmocean.cm.deep_r, "c) landing point on elevation (m)")
    for _, s in sites.iterrows():
        best = bool(s.get("is_best", False))
        col = "#ffdd00" if best else "white"
        # the maps are in the analysis frame (rotated by res.frame_rotation_deg): draw at the site's cell
        fx, fy = float(res.x_m[int(s["col"])]), float(res.y_m[int(s["row"])])
        ax[2].add_patch(Circle((fx, fy), s["radius_m"], fill=False, ec=col, lw=0.8))
        poly = _footprint_polygon(fx, fy, hd - res.frame_rotation_deg, res.vehicle.length_m, res.vehicle.width_m)
        ax[2].add_patch(Polygon(poly, closed=True, fill=False, ec=col, lw=1.2 if best else 0.6))
        ax[2].annotate(f"{s['c_s']:.2f}", (fx, fy), fontsize=6, color=col, ha="center", va="center")
    return _save(fig, path)


def figure_costs_vs_heading(sites: pd.DataFrame, path: str | Path, title: str = "") -> Path:
    """Fig. 21: P_s, P_f, P_r and C_s of every candidate site against landing heading."""
    fig, axes = plt.subplots(4, 1, figsize=(7, 7), sharex=True, layout="compressed")
    for ax, col, lab in zip(axes, ["p_s", "p_f", "p_r", "c_s"], ["P_s (slope)", "P_f (safety)", "P_r (roughness)", "C_s (cost)"], strict=False):
        if len(sites):
            ax.scatter(sites["heading_deg"], sites[col], s=8, c=sites["c_s"], cmap=cmocean.cm.matter, vmin=0, vmax=1)
            if "is_best" in sites:
                b = sites[sites["is_best"].astype(bool)]
                ax.scatter(b["heading_deg"], b[col], s=60, facecolors="none", edgecolors="k")
        ax.set_ylabel(lab, fontsize=8)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("landing heading (°)")
    axes[-1].set_xlim(-95, 95)
    fig.suptitle(title or "Landing-site properties vs heading", fontsize=10)
    return _save(fig, path)


#: widest panel of the transect figure (width / height, axes at equal scale): a longer transect is split
TRANSECT_PANEL_ASPECT = 8.0
#: at most this many panels; the transect figure's width (inches, at 110 dpi: shown 1:1 in the report's page)
TRANSECT_MAX_PANELS = 4
TRANSECT_WIDTH_IN = 9.0


def transect_segments(x_min: float, x_max: float, height_m: float, *, aspect: float = TRANSECT_PANEL_ASPECT,
                      max_panels: int = TRANSECT_MAX_PANELS) -> list[tuple[float, float]]:
    """Consecutive, equal x ranges covering ``[x_min, x_max]``, as few as keep each panel within ``aspect``
    (width / ``height_m``), at most ``max_panels``."""
    w = max(float(x_max - x_min), 1e-9)
    k = int(min(max_panels, max(1, math.ceil(w / (aspect * max(height_m, 1e-9))))))
    edges = np.linspace(x_min, x_max, k + 1)
    return [(float(a), float(b)) for a, b in zip(edges[:-1], edges[1:], strict=True)]


def figure_transect(best_sites: pd.DataFrame, outlines: Mapping[str, np.ndarray], path: str | Path) -> Path:
    """Fig. 25: the selected site of each submap coloured by its landing cost C_s, over the mapped
    outlines (``outlines[name]`` = N×2 array of x, y of mapped cells, decimated). A long transect is split into
    stacked panels (:func:`transect_segments`) so the figure keeps a legible shape (a 3 x 25 m transect on one
    axis was a 2475 x 440 px strip, shrunk to illegibility in the report); viridis (colour-blind safe) for C_s."""
    allxy = np.concatenate([xy for xy in outlines.values() if len(xy)] or [np.zeros((1, 2))])
    if len(best_sites):
        allxy = np.concatenate([allxy, best_sites[["x_m", "y_m"]].to_numpy(float)])
    x0, x1 = float(allxy[:, 0].min()) - 0.5, float(allxy[:, 0].max()) + 0.5
    y0, y1 = float(allxy[:, 1].min()) - 0.5, float(allxy[:, 1].max()) + 0.5
    segs = transect_segments(x0, x1, y1 - y0)
    seg_w = segs[0][1] - segs[0][0]
    panel_h_m = max(y1 - y0, seg_w / TRANSECT_PANEL_ASPECT)  # every panel at one scale and one height
    panel_in = TRANSECT_WIDTH_IN * 0.9 * panel_h_m / seg_w
    fig, axes = plt.subplots(len(segs), 1, figsize=(TRANSECT_WIDTH_IN, max(3.2, len(segs) * (panel_in + 0.55) + 1.6)),
                             squeeze=False, layout="constrained")
    axes = axes[:, 0]
    vmax = max(0.7, float(best_sites["c_s"].max())) if len(best_sites) else 1.0
    sc = None
    for ax, (a, b) in zip(axes, segs, strict=True):
        for _name, xy in outlines.items():
            if len(xy):
                m = (xy[:, 0] >= a - 1) & (xy[:, 0] <= b + 1)
                ax.plot(xy[m, 0], xy[m, 1], ".", ms=1, color="#bbbbbb", alpha=0.6)
        if len(best_sites):
            sel = best_sites[(best_sites["x_m"] >= a) & (best_sites["x_m"] <= b)]
            sc = ax.scatter(sel["x_m"], sel["y_m"], c=sel["c_s"], cmap="viridis", vmin=0, vmax=vmax, s=70,
                            edgecolors="k", zorder=3)
            for _, s in sel.iterrows():
                ax.annotate(str(s.get("submap", "")).replace("submap_", ""), (s["x_m"], s["y_m"]), fontsize=9,
                            xytext=(5, 5), textcoords="offset points")
        ym = 0.5 * (y0 + y1)
        ax.set_xlim(a, b)
        ax.set_ylim(ym - panel_h_m / 2, ym + panel_h_m / 2)
        ax.set_aspect("equal")
        ax.set_ylabel("y (m)")
        ax.tick_params(labelsize=9)
        ax.grid(alpha=0.3)
    axes[-1].set_xlabel("x (m, laser frame)")
    if sc is not None:
        fig.colorbar(sc, ax=list(axes), label="landing cost C_s", orientation="horizontal", shrink=0.6, aspect=40)
    part = f" ({len(segs)} consecutive panels along x)" if len(segs) > 1 else ""
    axes[0].set_title(f"Final landing site per submap and its landing cost{part}", fontsize=10)
    return _save(fig, path)


def _save(fig, path: str | Path) -> Path:
    """Write ``fig`` as a 110 dpi PNG, every text at least :data:`hadal.figtext.MIN_FONT_PT` (legible in the report)."""
    from hadal.figtext import min_fonts

    path = Path(path)
    min_fonts(fig)
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path
