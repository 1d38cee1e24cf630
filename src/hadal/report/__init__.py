"""Dive report: summary numbers, paper-style figures (matplotlib Agg + cmocean) and a self-contained HTML page.

Prefect-free. :func:`build_report` reads whichever products of a dive exist (missing ones are listed in the
report, not fatal); :func:`publish_report` writes ``report.html``, ``summary.json`` and ``figures/*.png`` as a
new version of the ``report`` product. The stage ``hadal.stages.report`` and ``hadal report DIVE`` call it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from hadal.products.geo_landing import strict_json
from hadal.report.figures import FigureOptions, FigureResult, make_figures
from hadal.report.html import render_html, summary_markdown, summary_rows
from hadal.report.load import REPORT_INPUTS, DiveProducts, load_products
from hadal.report.summary import dive_summary
from hadal.store import ProductStore, ProductVersion

__all__ = ["REPORT_INPUTS", "DiveProducts", "FigureOptions", "Report", "build_report", "dive_summary",
           "load_products", "make_figures", "publish_report", "render_html", "summary_markdown", "summary_rows"]


@dataclass
class Report:
    dive: str
    html: str
    summary: dict[str, Any]
    figures: list[FigureResult] = field(default_factory=list)
    upstream: list[ProductVersion] = field(default_factory=list)


def _provenance(dp: DiveProducts) -> list[dict[str, Any]]:
    rows = []
    for product, pv in dp.versions.items():
        try:
            m = pv.manifest()
        except (OSError, ValueError):
            m = {}
        rows.append({"product": product, "version": pv.label, "created_utc": m.get("created_utc"),
                     "code_version": m.get("code_version"), "path": str(pv.path)})
    return rows


def build_report(store: ProductStore, dive: str, *, launch: dict[str, float] | None = None,
                 options: FigureOptions | None = None, best_sites: int = 5, title: str | None = None,
                 skipped: list[dict[str, str]] | None = None, pins: dict[str, ProductVersion] | None = None,
                 expected: set[str] | None = None, sources: dict[str, list[str]] | None = None) -> Report:
    """Load the dive's products, compute the summary and figures, render the HTML (nothing is written).

    ``skipped``: stages the dive's data does not support, ``[{"stage", "reason"}]`` (:func:`hadal.stages.plan.skipped_stages`),
    listed in the summary and the HTML (a failed stage with its one-line error). ``pins``: the versions a pipeline run
    used (default: the latest). ``sources``: the dive's raw files by kind (dive.yaml ``sources``), listed as what was
    found. With no product at all (every stage failed or skipped) the report still renders: sources, stages and
    reasons."""
    dp = load_products(store, dive, None if skipped is None else {s["stage"] for s in skipped}, pins, expected)
    dp.launch = launch
    summary = dive_summary(dp, launch=launch, best_sites=best_sites)
    summary["skipped_stages"] = list(skipped or [])
    if sources is not None:
        summary["sources"] = {k: list(v) for k, v in sources.items() if v}
    if dp.laser_info:
        summary["laser_grids"] = dp.laser_info
    if dp.dead_channels:
        summary["dead_channels"] = dp.dead_channels
    figures = _drop_skipped(make_figures(dp, options), skipped or [])
    for product, key in (("laser_grids", "laser_grids"), ("navigation", "nav_uncertainty")):
        if product not in dp.versions:  # optional data (most dives have no laser survey): no placeholder
            figures = [f for f in figures if f.key != key or f.png is not None]
    summary["figures"] = {f.key: ("ok" if f.png is not None else f"skipped: {f.skipped}") for f in figures}
    html = render_html(dp, summary, figures, _provenance(dp), title=title)
    return Report(dive=dive, html=html, summary=summary, figures=figures, upstream=list(dp.versions.values()))


#: what a figure's "skipped" reason names when it lacks a stage's products (report figures' own wording)
_STAGE_TOKENS = {"dtm": ("dtm", "reference terrain"), "laser": ("laser_grids",), "suitability": ("suitability",),
                 "match": ("match", "matched track", "navigation"), "landing": ("landing",), "derive": ("ctd",),
                 "profile": ("profile",),
                 "ingest": ("sensors",)}


def _drop_skipped(figures: list[FigureResult], skipped: list[dict[str, str]]) -> list[FigureResult]:
    """Leave out the placeholders of figures whose stage does not run on this dive (the report lists those
    stages with the reason once, instead of one "figure skipped" note per figure)."""
    tokens = tuple(f"no {t}" for s in skipped for t in _STAGE_TOKENS.get(s["stage"], ()))
    return [f for f in figures if f.png is not None or not (f.skipped or "").startswith(tokens) or not tokens]


def publish_report(store: ProductStore, report: Report, parameters: dict[str, Any] | None = None) -> ProductVersion:
    """Publish ``report`` as a new version of ``<dive>/report`` (report.html, summary.json, figures/*.png)."""
    with store.publish(report.dive, "report", parameters=parameters or {}, upstream=report.upstream) as draft:
        (draft.path / "report.html").write_text(report.html, encoding="utf-8")
        (draft.path / "summary.json").write_text(strict_json(report.summary, indent=2), encoding="utf-8")
        figdir = draft.path / "figures"
        figdir.mkdir()
        for f in report.figures:
            if f.png is not None:
                (figdir / f"{f.key}.png").write_bytes(f.png)
    assert draft.result is not None
    from hadal.products.stac import write_store_catalog  # the store's STAC catalog, now with this report

    try:
        write_store_catalog(store)
    except (OSError, ValueError) as exc:  # the catalog is an index: a failure to write it never loses a report
        import logging

        logging.getLogger("hadal.report").warning("report: STAC catalog of %s not written (%s)", store.root, exc)
    return draft.result
