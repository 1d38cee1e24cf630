"""Prefect task for the `landing` stage (science in `hadal.stages.landing`)."""

from hadal.tasks.stage import stage_task

landing = stage_task("landing", retries=0)
