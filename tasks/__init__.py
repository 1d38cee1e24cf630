"""Prefect tasks: thin wrappers, one per pipeline stage, around ``hadal.stages.<stage>.run``."""
