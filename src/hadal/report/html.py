"""Self-contained HTML dive report: summary tables, figures embedded as base64 PNG, provenance."""

from __future__ import annotations

import base64
import datetime as _dt
import html
import re
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import Any

from hadal import __version__
from hadal.figtext import MIN_FONT_PT  # the landing stage's figures: 110 dpi (hadal.landing.figures._save)
from hadal.report.figures import FigureResult
from hadal.report.load import DiveProducts
from hadal.report.units import coordinate_decimals, human_label, units_of

#: horizontal size (m) a ship's GPS position locates (casts, launch): the decimals of its lat/lon
#: (:func:`hadal.report.units.coordinate_decimals`: 5 decimals of a degree)
SHIP_POSITION_M = 10.0

CSS = """
body{font-family:-apple-system,Segoe UI,Helvetica,Arial,sans-serif;margin:2em auto;max-width:1100px;color:#222;padding:0 1em}
h1{border-bottom:3px solid #08306b;padding-bottom:.2em}h2{color:#08306b;margin-top:1.6em;border-bottom:1px solid #ccc}
table{border-collapse:collapse;margin:.6em 0;font-size:.92em}td,th{border:1px solid #ccc;padding:.25em .6em;text-align:left}
th{background:#eef3fa}figure{margin:1.2em 0}figure img{max-width:100%;border:1px solid #ddd}
figcaption{font-size:.9em;color:#444;margin-top:.3em}.note{background:#fff7e0;border-left:4px solid #f0b400;padding:.4em .8em;margin:.3em 0}
.warn{background:#fdecea;border-left:4px solid #d93025;padding:.4em .8em;margin:.3em 0}.muted{color:#777;font-size:.85em}
"""


def _e(v: Any) -> str:
    return html.escape(str(v))


def _fmt(v: Any, nd: int = 1) -> str:
    if v is None:
        return "—"
    if isinstance(v, float):
        return f"{v:,.{nd}f}"
    return str(v)


def _hms(seconds: float | None) -> str:
    if seconds is None:
        return "—"
    s = int(round(seconds))
    return f"{s // 3600} h {s % 3600 // 60:02d} min"


def _table(rows: Iterable[tuple[str, Any]]) -> str:
    body = "".join(f"<tr><th>{_e(k)}</th><td>{_e(v)}</td></tr>" for k, v in rows)
    return f"<table>{body}</table>"


def _records_table(records: Sequence[Mapping[str, Any]], nd: int = 3, position_m: float = SHIP_POSITION_M) -> str:
    """Rows of ``records`` under people's column labels (:func:`hadal.report.units.human_label`); ``lat``/``lon``
    with the decimals of a ``position_m`` thing (:func:`coordinate_decimals`), other floats with ``nd``."""
    if not records:
        return "<p class='muted'>none</p>"
    cols = list(records[0].keys())
    head = "".join(f"<th>{_e(human_label(str(c)))}</th>" for c in cols)
    dec = coordinate_decimals(position_m)

    def cell(c: str, v: Any) -> str:
        return _fmt(v, dec if c in ("lat", "lon") else nd)

    rows = "".join("<tr>" + "".join(f"<td>{_e(cell(c, r.get(c)))}</td>" for c in cols) + "</tr>" for r in records)
    return f"<table><tr>{head}</tr>{rows}</table>"


def landing_site_records(sites: list[Mapping[str, Any]]) -> list[dict[str, str]]:
    """The best landing sites for the table: every value as text, the latitude/longitude of each site with the
    decimals of its size (its largest inscribed circle's radius, :func:`coordinate_decimals`; 6 decimals of a degree
    for a 0.32 m site), plus its degrees-minutes ``position`` at the same precision."""
    from hadal.geo import format_position

    out = []
    for r in sites:
        size = r.get("radius_m")
        size = float(size) if isinstance(size, (int, float)) else 0.5  # no radius: a vehicle-sized site
        deg, mins = coordinate_decimals(size, "deg"), coordinate_decimals(size, "min")
        row: dict[str, str] = {}
        for k, v in r.items():
            row[k] = (f"{float(v):.{deg}f}" if k in ("lat", "lon") and isinstance(v, (int, float))
                      else _fmt(v, 3))
        if isinstance(r.get("lat"), (int, float)) and isinstance(r.get("lon"), (int, float)):
            row["position"] = format_position(float(r["lat"]), float(r["lon"]), decimals=mins)
        out.append(row)
    return out


def summary_rows(s: Mapping[str, Any]) -> list[tuple[str, str]]:
    """The headline numbers as (label, text) rows (also used for the Prefect markdown artifact)."""
    rows: list[tuple[str, str]] = [("dive", s.get("dive", "?"))]
    if "start_utc" in s:
        rows.append(("recording", f"{s['start_utc']} → {s['end_utc']} ({_hms(s.get('duration_s'))})"))
    ph = s.get("phase_durations_s") or {}
    if ph:
        rows.append(("phases", ", ".join(f"{k} {_hms(v)}" for k, v in ph.items())))
    if "max_depth_m" in s:
        rows.append(("maximum depth (CTD cast)" if s.get("cast_only") else "maximum vehicle depth", f"{s['max_depth_m']:,.1f} m" + (f" at {s['max_depth_time_utc']}" if s.get("max_depth_time_utc") else "")))
    if "max_seafloor_depth_m" in s:
        rows.append(("maximum seafloor depth (depth + altitude)", f"{s['max_seafloor_depth_m']:,.1f} m"))
    dpnt = s.get("deepest_point")
    if dpnt:
        rows.append(("deepest point (matched)", f"{dpnt['position_degmin']} ({dpnt['lat']:.5f}°, {dpnt['lon']:.5f}°)"))
    if "launch" in s:
        rows.append(("position (cast)" if s.get("cast_only") else "launch point", s["launch"]["position_degmin"]))
    if s.get("dtm"):
        t = s["dtm"]
        res = f"{t['resolution_m']:g} m cells, " if t.get("resolution_m") else ""
        snd = f", {t['soundings']:,.0f} soundings" if t.get("soundings") else ""
        rows.append((f"reference DTM ({'prior grid' if t['source'] == 'prior_grid' else 'multibeam'})",
                     f"{t['cells'][1]} x {t['cells'][0]} {res}depth {t['depth_range_m'][0]:,.1f} – "
                     f"{t['depth_range_m'][1]:,.1f} m, {100 * t['mapped_fraction']:.0f} % mapped{snd}"))
    if s.get("surfacing"):
        sf = s["surfacing"]
        unc = f" ±{sf['uncertainty_m']:,.0f} m (1σ)" if sf.get("uncertainty_m") else ""
        rows.append(("surfacing position (end of the ascent)", f"{sf['position_degmin']}{unc}"
                     + (f" at {sf['time_utc']}" if sf.get("time_utc") else "")))
    for c in s.get("cast_positions") or []:  # where profile.nc places each cast, and from what
        unc = f" ±{c['uncertainty_m']:,.0f} m (1σ)" if c.get("uncertainty_m") else ""
        rows.append((f"{c['cast']} cast position (profile.nc)", f"{c['position_degmin']}{unc}, from "
                     f"{c['source'].replace('_', ' ')}"))
    if "matched_start" in s:
        rows.append(("matched start of the bottom track", s["matched_start"]["position_degmin"]))
    if s.get("drift_m") is not None:
        rows.append(("horizontal drift launch → bottom", f"{s['drift_m']:,.0f} m"))
    m = s.get("match") or {}
    if m:
        q = []
        if m.get("score") is not None:
            q.append(f"{(m.get('criterion') or 'msd').upper()} {m['score']:.3g}")
        if m.get("uncertainty_radial_m") is not None:
            q.append(f"±{m['uncertainty_radial_m']:.0f} m (radial)")
        if m.get("separation_ratio") is not None:
            q.append(f"2nd/best {m['separation_ratio']:.2f}")
        if m.get("rms_depth_residual_m") is not None:
            q.append(f"RMS depth residual {m['rms_depth_residual_m']:.1f} m")
        if m.get("bias_m") is not None:
            q.append(f"bias {m['bias_m']:.1f} m")
        if m.get("mismatch"):
            q.append("POSSIBLE MISMATCH")
        rows.append(("match quality", ", ".join(q) or "—"))
    if s.get("best_landing_sites"):
        b = s["best_landing_sites"][0]
        txt = f"{b.get('submap', '?')}: cost {_fmt(b.get('c_s'), 3)}"
        if b.get("slope_deg") is not None:
            txt += f", slope {_fmt(b.get('slope_deg'), 1)}°"
        if b.get("heading_deg") is not None:
            txt += f", heading {_fmt(b.get('heading_deg'), 0)}°"
        if b.get("lat") is not None and b.get("lon") is not None:
            txt += f", at {landing_site_records([b])[0]['position']}"
        rows.append(("best landing site", txt))
    for name, label in (("temperature_its90_degc", "temperature"), ("practical_salinity", "practical salinity"),
                        ("density_kg_m3", "in situ density")):
        if f"{name}_range" in s:
            lo, hi = s[f"{name}_range"]
            rows.append((label, f"{lo:.3f} – {hi:.3f} {units_of(name)}".strip()))  # unit: the variable registry
    return [(k, str(v)) for k, v in rows]


def summary_markdown(s: Mapping[str, Any]) -> str:
    lines = [f"# Dive report: {s.get('dive', '?')}", "", "| quantity | value |", "|---|---|"]
    lines += [f"| {k} | {v} |" for k, v in summary_rows(s)]
    if s.get("missing_products"):
        lines += ["", "Missing products: " + ", ".join(s["missing_products"])]
    return "\n".join(lines) + "\n"


#: match messages that describe normal processing (the sub-cell refinement moving the fix within the search
#: it was given): shown as notes, not red warnings
INFORMATIONAL = (re.compile(r"sub-cell refinement moved the fix [\d.]+ m from the coarse optimum$"),)


def is_real_warning(text: str) -> bool:
    """Whether a stage message is a problem for the reader (red box) rather than a note."""
    return not any(p.search(text) for p in INFORMATIONAL)


#: captions of the landing stage's figures (file name prefix -> what it shows, landing paper figure numbers)
LANDING_CAPTIONS: dict[str, str] = {
    "fig13_slope": "Exclusion for slope (landing paper Fig. 13): mapped area, where the centre of gravity can "
                   "enter, the slope under the vehicle footprint and the cells excluded because it exceeds the "
                   "critical slope, at the best site's heading",
    "fig18_protrusions": "Exclusion for protrusions (landing paper Fig. 18): protrusion heights and the cells "
                         "where a protrusion under the footprint exceeds the height limit",
    "fig19_sites": "Landing sites (landing paper Fig. 19): full exclusion of the centre of gravity, candidate sites "
                   "and the landing points on the elevation",
    "fig21_costs_vs_heading": "Landing costs against heading (landing paper Fig. 21): slope, safety, roughness "
                              "and total cost of every candidate site",
    "fig25_transect": "Best sites along the surveyed transect (landing paper Fig. 25)",
}


def landing_caption(name: str) -> str:
    stem = name.removesuffix(".png")
    for prefix, cap in LANDING_CAPTIONS.items():
        if stem.startswith(prefix):
            sub = stem[len(prefix):].strip("_")
            return cap + (f" - {sub.replace('_', ' ')}" if sub else "")
    return stem.replace("_", " ")


def _span(r: Any) -> str:
    """``[lo, hi]`` as ``lo .. hi`` (3 significant decimals), ``-`` when absent."""
    return "-" if not r else f"{r[0]:.3f} .. {r[1]:.3f}"


def render_html(dp: DiveProducts, summary: Mapping[str, Any], figures: list[FigureResult],
                provenance: list[dict[str, Any]], title: str | None = None) -> str:
    """The complete report as one HTML string (no external resources)."""
    now = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
    title = title or f"Dive report — {dp.dive}"
    parts = [f"<!DOCTYPE html><html lang='en'><head><meta charset='utf-8'><title>{_e(title)}</title>",
             f"<style>{CSS}</style></head><body>", f"<h1>{_e(title)}</h1>",
             f"<p class='muted'>generated {now} by hadal {__version__}</p>", "<h2>Summary</h2>",
             _table(summary_rows(summary))]
    warns = list((summary.get("match") or {}).get("warnings") or [])
    for w in warns:
        cls = "warn" if is_real_warning(str(w)) else "note"
        parts.append(f"<div class='{cls}'>match: {_e(w)}</div>")
    if summary.get("casts"):
        parts.append("<h2>Other casts of this dive</h2>")
        parts.append(_records_table(summary["casts"]))
    if summary.get("underway"):
        parts.append("<h2>Underway records (thermosalinograph trajectories)</h2>")
        parts.append("<p class='muted'>published as derive's trajectory product (CF trajectory, the records' own "
                     "per-scan positions), not as casts</p>")
        parts.append(_records_table(summary["underway"]))
    if summary.get("qc_flags"):
        parts.append("<h2>Quality flags (QARTOD) of the CTD product</h2>")
        parts.append("<p class='muted'>1 good, 2 not evaluated, 3 suspect, 4 fail, 9 missing; derived variables "
                     "inherit the worst range flag of their inputs (hadal.qc_derived)</p>")
        parts.append(_records_table(summary["qc_flags"]))
    if summary.get("sources"):
        parts.append("<h2>Sources found (dive.yaml)</h2>")
        parts.append(_table([(k, ", ".join(v)) for k, v in summary["sources"].items()]))
    if summary.get("laser_grids"):
        parts.append("<h2>Laser grids</h2>")
        parts.append(_records_table([{"grid": g["name"], "cells (rows x cols)": "x".join(map(str, g["cells"])),
                                      "resolution (m)": g["resolution_m"],
                                      "x range (m)": _span(g["x_range_m"]), "y range (m)": _span(g["y_range_m"]),
                                      "elevation range (m)": _span(g["elevation_range_m"])}
                                     for g in summary["laser_grids"]]))
    if summary.get("dead_channels"):
        parts.append("<h2>Dead sensor channels (flagged, left out; the other channels processed)</h2>")
        parts.append(_records_table([{"channel": k, **v} for k, v in summary["dead_channels"].items()]))
    skipped = summary.get("skipped_stages") or []
    if skipped:
        parts.append("<h2>Stages not run on this dive</h2>")
        parts.append(_table([(s["stage"], s["reason"]) for s in skipped]))
    if dp.notes:
        parts.append("<h2>Missing or unreadable inputs</h2>")
        parts += [f"<div class='note'>{_e(n)}</div>" for n in dp.notes]
    sections: dict[str, list[FigureResult]] = {}
    for f in figures:
        sections.setdefault(f.section, []).append(f)
    for section, figs in sections.items():
        parts.append(f"<h2>{_e(section)}</h2>")
        for f in figs:
            if f.png is None:
                parts.append(f"<div class='note'><b>{_e(f.title)}</b>: figure skipped — {_e(f.skipped)}</div>")
                continue
            b64 = base64.b64encode(f.png).decode("ascii")
            size = (f" data-dpi='{f.dpi:g}' data-min-font-pt='{f.min_font_pt:g}'"
                    if f.dpi is not None and f.min_font_pt is not None else "")
            parts.append(f"<figure id='{_e(f.key)}'><img alt='{_e(f.title)}'{size} src='data:image/png;base64,{b64}'>"
                         f"<figcaption><b>{_e(f.title)}.</b> {_e(f.caption)}</figcaption></figure>")
        if section == "Landing sites" and any(f.png is not None for f in figs):
            parts.append("<h3>Best landing sites (lowest cost per submap)</h3>")
            parts.append(_records_table(landing_site_records(summary.get("best_landing_sites") or [])))
    if (summary.get("best_landing_sites") or dp.landing_figures) and "Landing sites" not in sections:
        parts.append("<h2>Landing sites</h2>"
                     + _records_table(landing_site_records(summary.get("best_landing_sites") or [])))
    if dp.landing_figures:
        parts.append("<h3>Figures of the landing stage</h3>")
        for p in dp.landing_figures:
            b64 = base64.b64encode(Path(p).read_bytes()).decode("ascii")
            cap = landing_caption(Path(p).name)
            parts.append(f"<figure><img alt='{_e(cap)}' data-dpi='110' data-min-font-pt='{MIN_FONT_PT:g}' "
                         f"src='data:image/png;base64,{b64}'>"
                         f"<figcaption><b>{_e(cap)}</b> <span class='muted'>({_e(Path(p).name)}, landing product; "
                         "laser frame: local x/y of the laser survey, m)</span></figcaption></figure>")
    if summary.get("landing_table_v"):
        tv = summary["landing_table_v"]
        parts.append("<h3>Landing analysis summary (landing paper Table V)</h3>")
        parts.append(_table((human_label(str(k)), _fmt(v, 2)) for k, v in tv.items()) if isinstance(tv, Mapping)
                     else f"<pre>{_e(tv)}</pre>")
    parts.append("<h2>Provenance</h2>")
    parts.append(_records_table(provenance))
    parts.append("</body></html>")
    return "\n".join(parts)
