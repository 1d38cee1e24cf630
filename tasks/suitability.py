"""Prefect task for the `suitability` stage (science in `hadal.stages.suitability`)."""

from hadal.tasks.stage import stage_task

suitability = stage_task("suitability", retries=0)
