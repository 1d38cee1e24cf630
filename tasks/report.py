"""Prefect task for the `report` stage (science-free; in `hadal.stages.report` / `hadal.report`).

After a fresh run it publishes the dive summary as Prefect artifacts (a markdown summary and a table of
the best landing sites and product versions) so the report is visible in the Prefect UI.
"""

from __future__ import annotations

import json
import logging
import re
from pathlib import Path

from hadal.tasks.stage import stage_task

log = logging.getLogger("hadal.report")


def _artifact_key(dive: str, what: str) -> str:
    return re.sub(r"[^a-z0-9-]+", "-", f"{dive}-{what}".lower()).strip("-")[:100]


def publish_artifacts(name: str, published: dict[str, str]) -> None:
    """Markdown + table artifacts for the report just published (no-op outside a Prefect run)."""
    from prefect.artifacts import create_markdown_artifact, create_table_artifact
    from prefect.context import TaskRunContext

    from hadal.report import summary_markdown

    if TaskRunContext.get() is None or "report" not in published:
        return
    path = Path(published["report"])
    try:
        summary = json.loads((path / "summary.json").read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        log.warning("report artifacts skipped: %s", exc)
        return
    dive = str(summary.get("dive", "dive"))
    md = summary_markdown(summary) + f"\nReport: `{path / 'report.html'}`\n"
    create_markdown_artifact(md, key=_artifact_key(dive, "report"), description=f"hadal dive report {dive}")
    versions = [{"product": p, "version": v} for p, v in (summary.get("products") or {}).items()]
    create_table_artifact(versions, key=_artifact_key(dive, "products"), description=f"product versions used, {dive}")
    if summary.get("best_landing_sites"):
        create_table_artifact(summary["best_landing_sites"], key=_artifact_key(dive, "landing-sites"),
                              description=f"best landing sites, {dive}")


report = stage_task("report", retries=0, after=publish_artifacts)
