"""Prefect task for the `dtm` stage (science in `hadal.stages.grid`)."""

from hadal.tasks.stage import stage_task

dtm = stage_task("dtm", retries=1)
