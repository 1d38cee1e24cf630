"""Prefect flows of the hadal pipeline (orchestration only; the science is in ``hadal``)."""
