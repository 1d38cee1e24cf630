"""Options of the terrain matching, declared once in :mod:`hadal.settings.match` (:class:`TercomOptions`,
:class:`DeadReckoningOptions`, :class:`PosteriorNoiseOptions`, :class:`SearchEdgeOptions`); :func:`tercom_options` merges
keyword values into them for the search functions."""

from __future__ import annotations

from hadal.settings.match import (
    DIRECT_FIELDS,
    MRF_EDGE_FIELDS,
    REFINE_FIELDS,
    TERCOM_FIELDS,
    DeadReckoningOptions,
    PosteriorNoiseOptions,
    SearchEdgeOptions,
    TercomOptions,
)

__all__ = ["DIRECT_FIELDS", "MRF_EDGE_FIELDS", "REFINE_FIELDS", "TERCOM_FIELDS", "DeadReckoningOptions",
           "PosteriorNoiseOptions", "SearchEdgeOptions", "TercomOptions", "tercom_options"]


def tercom_options(options: TercomOptions | None, values: dict, allowed: tuple[str, ...], what: str) -> TercomOptions:
    """``options`` (default :class:`TercomOptions`) with the keyword ``values`` (fields in ``allowed``) applied;
    an unknown keyword is a ``TypeError``, a value out of bounds a one-line :class:`hadal.errors.InputError`."""
    from pydantic import ValidationError

    from hadal.errors import InputError, first_validation_error

    unknown = sorted(set(values) - set(allowed))
    if unknown:
        raise TypeError(f"{what}() got unexpected keyword argument(s) {', '.join(map(repr, unknown))}")
    if isinstance(values.get("criterion"), str):
        values = {**values, "criterion": values["criterion"].lower()}
    base = options.model_dump(include=set(TercomOptions.model_fields)) if options is not None else {}
    try:
        return TercomOptions(**{**base, **values})
    except ValidationError as exc:
        loc, msg, _ = first_validation_error(exc)
        raise InputError(f"TERCOM option {loc}={exc.errors()[0].get('input')!r}: {msg}") from None
