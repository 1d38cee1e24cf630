"""Terrain matching: TERCOM coarse search (COR/MAD/MSD), MRF fine matching, geographic fix.

* :func:`tercom` -- exhaustive FFT-based TERCOM over the whole map ([TERCOM Eqs. 15-17], §4.2);
  :func:`tercom_direct` is the per-offset reference loop; :func:`refine_tercom` the sub-cell
  (bilinear, heading, scale) refinement of an MSD fix. Their options: :mod:`hadal.matching.options`.
* :func:`posterior_fix` -- the point-mass posterior fix (MAP, covariance, ellipses, mass outside the
  main mode, mismatch reasons) from the MSD likelihood over offsets x headings x scales.
* :func:`mrf_refine` -- MRF fine matching of a gridded real-time terrain patch ([MRF Eqs. 4-14]).
* :mod:`hadal.matching.budget` -- the fix's uncertainty budget and the MRF step of the ``match`` stage.
* :mod:`hadal.matching.fix` -- measured profile from ``ctd.parquet``, matched track, ``fix.json`` content.
"""

import sys
import types
from typing import TYPE_CHECKING, Any

from hadal._lazy import lazy_attr

if TYPE_CHECKING:  # the names the type checker sees (at run time they are imported on first access)
    from hadal.matching.mapgrid import MapGrid
    from hadal.matching.mrf import MrfResult, mrf_refine
    from hadal.matching.posterior import PosteriorFix, posterior_fix
    from hadal.matching.tercom import TercomResult, refine_tercom, tercom, tercom_direct

#: public name -> submodule, imported on first access (PEP 562): ``hadal.matching.options`` (used by
#: :class:`hadal.settings.match.MatchParams` and the navigation product) loads without NumPy/SciPy
_LAZY = {"MapGrid": "mapgrid", "MrfResult": "mrf", "mrf_refine": "mrf", "PosteriorFix": "posterior",
         "posterior_fix": "posterior", "TercomResult": "tercom", "refine_tercom": "tercom", "tercom": "tercom",
         "tercom_direct": "tercom"}


def __getattr__(name: str) -> Any:
    return lazy_attr(__name__, _LAZY, name)


class _Package(types.ModuleType):
    """The package's ``tercom`` is the function: the import system sets the attribute of a submodule's name on its
    package once the submodule ``hadal.matching.tercom`` is imported (by any path); keep the function there."""

    def __setattr__(self, name: str, value: Any) -> None:
        if name == "tercom" and isinstance(value, types.ModuleType):
            value = value.tercom
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package

__all__ = ["MapGrid", "MrfResult", "PosteriorFix", "TercomResult", "mrf_refine", "posterior_fix", "refine_tercom", "tercom",
           "tercom_direct"]
