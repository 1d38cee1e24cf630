"""What a user looks for in a stage's Prefect artifact (issue 46), read back from the versions it published:

* ``sensors``/``ctd`` (ingest, derive): QARTOD flag counts per variable (the ``<variable>_qc`` columns);
* ``match``: the fix (start of the bottom track), its 1-sigma/2-sigma error ellipses, drift and mismatch;
* ``landing``: the best sites (lowest landing cost per submap) and Table V;
* ``report``: a link to ``report.html``.

Markdown lines only (Prefect-free); a product this module cannot read gives a one-line note, never an error: an
artifact must not fail a published stage. Coordinates are printed at the precision of the thing they locate
(:func:`deg_decimals`).
"""

from __future__ import annotations

import json
import math
from collections.abc import Callable
from pathlib import Path
from typing import Any

#: QARTOD flag values (QARTOD manual; ioos_qc), in the order of the artifact's columns
QARTOD = {1: "good", 2: "not evaluated", 3: "suspect", 4: "fail", 9: "missing"}
#: metres per degree of latitude (mean; enough to choose a number of decimals)
M_PER_DEG = 111_195.0
#: the best landing sites listed
BEST_SITES = 5


def deg_decimals(size_m: float) -> int:
    """Decimals of a latitude/longitude in degrees that resolve about a tenth of ``size_m`` (a 30 m ellipse: 5
    decimals, 1.1 m; a 0.3 m landing site: 7, 1 cm); between 3 and 8."""
    if not (isinstance(size_m, (int, float)) and math.isfinite(size_m) and size_m > 0):
        return 6
    return int(min(8, max(3, math.ceil(-math.log10(size_m / 10.0 / M_PER_DEG)))))


def _num(v: Any, fmt: str) -> str:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return "-"
    return format(f, fmt) if math.isfinite(f) else "-"


def latlon(lat: Any, lon: Any, decimals: int) -> str:
    """``11.33890 N, 142.21430 E`` (hemispheres by letter, not by sign); ``-`` for a missing value."""
    try:
        la, lo = float(lat), float(lon)
    except (TypeError, ValueError):
        return "-"
    if not (math.isfinite(la) and math.isfinite(lo)):
        return "-"
    return f"{abs(la):.{decimals}f} {'N' if la >= 0 else 'S'}, {abs(lo):.{decimals}f} {'E' if lo >= 0 else 'W'}"


def _cell(v: Any) -> str:
    return str(v).replace("|", "\\|").replace("\n", " ")


def qc_lines(version_dir: Path, file_name: str) -> list[str]:
    """QARTOD flag counts per ``<variable>_qc`` column of the Parquet table ``file_name`` (only those columns are
    read) and the share flagged suspect or fail among the samples that are not missing."""
    import pyarrow.compute as pc
    import pyarrow.parquet as pq

    f = version_dir / file_name
    cols = [c for c in pq.read_schema(f).names if c.endswith("_qc")]
    if not cols:
        return [f"`{file_name}`: no QC flag columns"]
    table = pq.read_table(f, columns=cols)
    lines = [f"QC flags of `{file_name}` ({table.num_rows} samples):", "",
             "| variable | " + " | ".join(QARTOD.values()) + " | flagged % |",
             "|---|" + "---|" * (len(QARTOD) + 1)]
    for c in cols:
        counts = {int(r["values"]): int(r["counts"]) for r in pc.value_counts(table[c].fill_null(9)).to_pylist()}
        row = [counts.get(k, 0) for k in QARTOD]
        valid = table.num_rows - counts.get(9, 0)
        share = 100.0 * (counts.get(3, 0) + counts.get(4, 0)) / valid if valid else 0.0
        lines.append(f"| {c[:-3]} | " + " | ".join(str(n) for n in row) + f" | {share:.2f} |")
    return lines


def match_lines(version_dir: Path) -> list[str]:
    """The fix of ``fix.json``: start position (lat/lon at the ellipse's precision), 1-sigma and 2-sigma ellipses,
    radial uncertainty, drift from the launch point, heading error, track scale, mismatch."""
    fix = json.loads((version_dir / "fix.json").read_text(encoding="utf-8"))
    unc = fix.get("uncertainty_m") or {}
    e1, e2 = unc.get("ellipse_1sigma") or {}, unc.get("ellipse_2sigma") or {}
    start = fix.get("start") or {}
    centre = e1.get("centre") or {}
    nd = deg_decimals(float(e1.get("semi_minor_m") or unc.get("radial") or float("nan")))
    lines = ["Fix (start of the bottom track, terrain matched):", ""]
    if "lat" in start and "lon" in start:
        lines.append(f"- position: {latlon(start['lat'], start['lon'], nd)}"
                     + (f" ({start['position_degmin']})" if start.get("position_degmin") else "")
                     + (f" at {start['time']}" if start.get("time") else ""))
    for name, e in (("1-sigma", e1), ("2-sigma", e2)):
        if e:
            lines.append(f"- {name} ellipse: semi-major {_num(e.get('semi_major_m'), '.1f')} m, semi-minor "
                         f"{_num(e.get('semi_minor_m'), '.1f')} m, azimuth {_num(e.get('azimuth_deg'), '.1f')} deg"
                         + (f" (content {_num(e.get('gaussian_content'), '.0%')})" if "gaussian_content" in e
                            else ""))
    if centre.get("lat") is not None:
        lines.append(f"- ellipse centre: {latlon(centre['lat'], centre.get('lon'), nd)}")
    if unc.get("radial") is not None:
        lines.append(f"- radial uncertainty (DRMS): {_num(unc['radial'], '.1f')} m")
    if fix.get("drift_m") is not None:
        lines.append(f"- drift from the launch point: {_num(fix['drift_m'], '.0f')} m")
    if fix.get("heading_error_deg") is not None:
        lines.append(f"- heading error: {_num(fix['heading_error_deg'], '+.2f')} deg, track scale "
                     f"{_num(fix.get('track_scale'), '.4f')}")
    if fix.get("n_valid") is not None:
        lines.append(f"- profile points matched: {fix['n_valid']} of {fix.get('n_samples', '?')}")
    reasons = fix.get("mismatch_reasons") or []
    lines.append(f"- mismatch: {'YES: ' + '; '.join(map(str, reasons)) if fix.get('mismatch') else 'no'}")
    return lines


def landing_lines(version_dir: Path) -> list[str]:
    """The best landing sites (``landing_summary.json``'s final sites, lowest cost ``c_s`` first; lat/lon at the
    site's precision when georeferenced) and Table V."""
    summary = json.loads((version_dir / "landing_summary.json").read_text(encoding="utf-8"))
    sites = sorted(summary.get("final_sites") or [], key=lambda s: _sort_cost(s.get("c_s")))
    tv = summary.get("table_v") or {}
    lines = [f"Best landing sites ({min(len(sites), BEST_SITES)} of {len(sites)}, lowest landing cost first):", ""]
    if sites:
        lines += ["| submap | heading (deg) | position | x (m) | y (m) | radius (m) | slope (deg) | roughness (m) "
                  "| cost c_s |", "|---|---|---|---|---|---|---|---|---|"]
        for s in sites[:BEST_SITES]:
            nd = deg_decimals(float(s.get("radius_m") or float("nan")))
            lines.append(f"| {_cell(s.get('submap', ''))} | {_num(s.get('heading_deg'), '.0f')} | "
                         f"{latlon(s.get('lat'), s.get('lon'), nd)} | "
                         f"{_num(s.get('x_m'), '.2f')} | {_num(s.get('y_m'), '.2f')} | "
                         f"{_num(s.get('radius_m'), '.2f')} | {_num(s.get('slope_deg'), '.1f')} | "
                         f"{_num(s.get('roughness_m'), '.3f')} | {_num(s.get('c_s'), '.3f')} |")
    else:
        lines.append("no landing site found")
    if tv:
        lines += ["", "Table V: " + "; ".join(f"{k.replace('_', ' ')} {_num(v, '.3g') if v is not None else '-'}"
                                              for k, v in tv.items())]
    return lines


def _sort_cost(v: Any) -> float:
    try:
        f = float(v)
    except (TypeError, ValueError):
        return math.inf
    return f if math.isfinite(f) else math.inf


def report_lines(version_dir: Path) -> list[str]:
    """A link to ``report.html`` (a ``file://`` URI: open it from the machine that ran hadal) and its path."""
    html = (version_dir / "report.html").resolve()
    return [f"Report: [{html.name}]({html.as_uri()})", "", f"`{html}`"]


#: product -> what its artifact shows
RESULTS: dict[str, Callable[[Path], list[str]]] = {
    "sensors": lambda d: qc_lines(d, "sensors.parquet"),
    "ctd": lambda d: qc_lines(d, "ctd.parquet"),
    "match": match_lines,
    "landing": landing_lines,
    "report": report_lines,
}


def result_lines(published: dict[str, str]) -> list[str]:
    """The results of every published product that has some (:data:`RESULTS`), as markdown sections; a product that
    cannot be read gives one line saying so."""
    out: list[str] = []
    for product, path in published.items():
        fn = RESULTS.get(product)
        if fn is None:
            continue
        out += ["", f"## {product}", ""]
        try:
            out += fn(Path(path))
        except Exception as exc:  # noqa: BLE001 - an artifact never fails a stage; say what is missing
            out.append(f"(results not shown: {type(exc).__name__}: {str(exc).splitlines()[0] if str(exc) else ''})")
    return out
