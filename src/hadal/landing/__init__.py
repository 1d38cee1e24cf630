"""Landing-site analysis on mm-resolution laser bathymetry (Sangekar et al., §III-IV).

Public API: :class:`Vehicle` (Table II, [Landing Eqs. 1-9]), :func:`analyse_submap` -> :class:`LandingResult`.
"""

import importlib
from typing import Any

#: public name -> submodule, imported on first access (PEP 562): ``hadal.landing.vehicle``/``limits`` (used by
#: :class:`hadal.stages.landing.Params`) load without the SciPy/numba analysis in ``sites``
_LAZY = {"LandingResult": "sites", "analyse_submap": "sites", "Vehicle": "vehicle"}


def __getattr__(name: str) -> Any:
    if name in _LAZY:
        value = getattr(importlib.import_module(f"{__name__}.{_LAZY[name]}"), name)
        globals()[name] = value
        return value
    raise AttributeError(f"module {__name__!r} has no attribute {name!r}")


__all__ = ["LandingResult", "Vehicle", "analyse_submap"]
