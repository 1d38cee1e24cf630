"""Prefect task for the `grid` stage (science in `hadal.stages.grid`)."""

from hadal.tasks.stage import stage_task

grid = stage_task("grid", retries=1)
