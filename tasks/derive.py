"""Prefect task for the `derive` stage (science in `hadal.stages.derive`)."""

from hadal.tasks.stage import stage_task

derive = stage_task("derive", retries=0)
