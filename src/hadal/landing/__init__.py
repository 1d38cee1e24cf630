"""Landing-site analysis on mm-resolution laser bathymetry (Sangekar et al., §III-IV).

Public API: :class:`Vehicle` (Table II, [Landing Eqs. 1-9]), :func:`analyse_submap` -> :class:`LandingResult`.
"""

from typing import Any

from hadal._lazy import lazy_attr

#: public name -> submodule, imported on first access (PEP 562): ``hadal.landing.vehicle``/``limits`` (used by
#: :class:`hadal.settings.landing.LandingParams`) load without the SciPy/numba analysis in ``sites``
_LAZY = {"LandingResult": "sites", "analyse_submap": "sites", "Vehicle": "vehicle"}


def __getattr__(name: str) -> Any:
    return lazy_attr(__name__, _LAZY, name)


__all__ = ["LandingResult", "Vehicle", "analyse_submap"]
