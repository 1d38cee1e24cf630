"""Stage `report`: the dive report (summary, paper-style figures, self-contained HTML) from whichever
products exist. Missing upstream products are listed in the report; it always runs: a dive whose every other
stage failed or was skipped still gets a report listing its sources and why each stage did not publish.
Science-free: see :mod:`hadal.report`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from hadal.settings.report import ReportParams as Params
from hadal.stages import Stage, StageContext, StageInputs

if TYPE_CHECKING:
    from hadal.report import FigureOptions
    from hadal.store import ProductVersion


def options(p: Params) -> FigureOptions:
    from hadal.forkpool import default_workers
    from hadal.report import FigureOptions

    return FigureOptions(dpi=p.dpi, width_in=p.figure_width_in, max_points=p.max_points,
                         workers=p.figure_processes or default_workers())


def _sources(ctx: StageContext) -> dict[str, list[str]]:
    """The dive's raw files by kind (dive.yaml ``sources``), for the report's list of what was found."""
    src = ctx.dive.sources
    return {kind: [str(e.path) for e in src.files(kind)] for kind in type(src).model_fields}


def run(ctx: StageContext) -> dict[str, ProductVersion]:
    from hadal.report import build_report, publish_report

    p: Params = ctx.config.report
    lp = ctx.dive.launch
    launch = {"lat": lp.latitude_deg, "lon": lp.longitude_deg} if lp is not None else None
    from hadal.stages.plan import skipped_stages

    skipped = skipped_stages(ctx)
    for pv in ctx.pins.values():
        ctx.store.check_intact(pv)
    from hadal.stages.plan import plan_stages

    expected = {prod for ps in plan_stages(ctx.dive) if ps.run for prod in ps.products}
    rep = build_report(ctx.store, ctx.dive_id, launch=launch, options=options(p), best_sites=p.best_sites, title=p.title,
                       skipped=skipped, pins=ctx.pins, expected=expected, sources=_sources(ctx))
    for s in skipped:
        ctx.log.info("report: stage %s not run: %s", s["stage"], s["reason"])
    for note in rep.summary.get("notes", []):
        ctx.log.info("report: %s", note)
    return {"report": publish_report(ctx.store, rep, parameters=ctx.params("report"))}


#: every product the report can use, all optional (hadal.report.load.REPORT_INPUTS and REPORT_OPTIONAL): its cache
#: fingerprint covers each of them (casts, cast_profiles, navigation and trajectory were left out before)
STAGE = Stage(
    name="report", products=("report",),
    inputs=StageInputs(optional_upstream=("sensors", "ctd", "profile", "dtm", "laser_grids", "suitability", "match",
                                          "landing", "casts", "cast_profiles", "navigation", "trajectory"),
                       always=True),
    options=Params, run=run,
    warm_imports=("hadal.report", "hadal.report.figures", "hadal.report.ctd_figures", "hadal.report.geo_figures",
                  "hadal.stages.plan", "hadal.forkpool", "hadal.mplwarm:first_draw"),
)
