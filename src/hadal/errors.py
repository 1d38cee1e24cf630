"""Exceptions with one-line, user-facing messages.

Every error hadal raises on bad input derives from :class:`HadalError`; the CLI prints ``str(exc)``
as a single line and exits with status 2 instead of showing a traceback.
"""

from __future__ import annotations


class HadalError(Exception):
    """Base class: a clear, one-line problem report meant for the person running the pipeline."""


class InputError(HadalError):
    """A raw input file is missing, unreadable, truncated or inconsistent."""


class ConfigError(HadalError):
    """A YAML configuration (pipeline, dive or vehicle) is invalid."""


class StoreError(HadalError):
    """The product store was asked for something it cannot do (bad name, missing product, ...)."""


class StageError(HadalError):
    """A pipeline stage cannot run (e.g. its upstream product is missing)."""
