"""Prefect task for the `profile` stage (science in `hadal.stages.profile`)."""

from hadal.tasks.stage import stage_task

profile = stage_task("profile", retries=0)
