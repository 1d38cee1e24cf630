"""Prefect task for the `laser` stage (science in `hadal.stages.grid`)."""

from hadal.tasks.stage import stage_task

laser = stage_task("laser", retries=1)
