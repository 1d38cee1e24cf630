"""Exceptions with one-line, user-facing messages.

Every error hadal raises on bad input derives from :class:`HadalError`; the CLI prints ``str(exc)``
as a single line and exits with status 2 instead of showing a traceback.
"""

from __future__ import annotations


class HadalError(Exception):
    """Base class: a clear, one-line problem report meant for the person running the pipeline."""


class InputError(HadalError, ValueError):
    """A raw input file is missing, unreadable, truncated or inconsistent (also a :class:`ValueError`, so library
    callers catch it as they would a bad value from numpy or xarray)."""


class ConfigError(HadalError, ValueError):
    """A YAML configuration (pipeline, dive or vehicle) or a parameter is invalid (also a :class:`ValueError`)."""


class StoreError(HadalError):
    """The product store was asked for something it cannot do (bad name, missing product, ...)."""


class StageError(HadalError):
    """A pipeline stage cannot run (e.g. its upstream product is missing)."""


def first_validation_error(exc) -> tuple[str, str, str]:
    """``(location, message, more)`` of a pydantic ``ValidationError``'s first error, for one-line reports:
    the dotted location (``""`` at the top level), the message without pydantic's ``"Value error, "`` prefix
    (a validator's own ``ValueError`` text) and ``" (+N more)"`` when there are further errors (else ``""``)."""
    errors = exc.errors()
    e = errors[0]
    loc = ".".join(str(x) for x in e.get("loc", ()))
    msg = str(e.get("msg", "")).removeprefix("Value error, ")
    return loc, msg, f" (+{len(errors) - 1} more)" if len(errors) > 1 else ""
