"""Prefect task for the `match` stage (science in `hadal.stages.match`)."""

from hadal.tasks.stage import stage_task

match = stage_task("match", retries=0)
