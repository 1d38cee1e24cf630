"""CF conventions shared by the product writers.

The CF attributes of every product variable (units, standard name, long name, flags, ...) are declared once in
``schemas/variables.yaml`` (:mod:`hadal.registry`); nothing here derives them from a variable's name.
What remains are CF constants (the QARTOD flag convention, the standard-name vocabulary) and two lookups the
writers and the compliance report share. Standard names are from the CF Standard Name Table v79.
"""

from __future__ import annotations

import re

from hadal.registry import has_no_cf_standard_name, registry

__all__ = ["EDGE_RE", "QARTOD_FLAG_MEANINGS", "QARTOD_FLAG_VALUES", "STANDARD_NAME_VOCABULARY",
           "has_no_cf_standard_name", "is_axis_edge", "units_from_name"]

STANDARD_NAME_VOCABULARY = "CF Standard Name Table v79"

QARTOD_FLAG_VALUES = (1, 2, 3, 4, 9)
QARTOD_FLAG_MEANINGS = "pass not_evaluated suspect fail missing"


def units_from_name(name: str) -> str | None:
    """The UDUNITS units ``schemas/variables.yaml`` declares for ``name``, or ``None`` (undeclared, or a
    variable without units such as a flag or label). A registry lookup, not a guess from the name's suffix.

    >>> units_from_name("sound_speed_m_s"), units_from_name("gravity_m_s2"), units_from_name("phase")
    ('m s-1', 'm s-2', None)
    """
    spec = registry().find(name)
    return spec.units if spec is not None else None


#: block/cell edge positions along one map axis (suitability ``x_min(x)``), made auxiliary coordinates. The
#: names are declared in the registry like every other variable; this only says which of them are edges.
EDGE_RE = re.compile(r"[xy]_(min|max|edge\w*|left|right|lower|upper|start|end)(_m)?")


def is_axis_edge(name: str) -> bool:
    """Block/cell edge positions along one map axis (e.g. suitability ``x_min(x)``): auxiliary coordinates."""
    return bool(EDGE_RE.fullmatch(name.lower()))
