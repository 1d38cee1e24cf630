"""Prefect task for the `ingest` stage (science in `hadal.stages.ingest`)."""

from hadal.tasks.stage import stage_task

ingest = stage_task("ingest", retries=2)
