"""Terrain matching: TERCOM coarse search (COR/MAD/MSD), MRF fine matching, geographic fix.

* :func:`tercom` -- exhaustive FFT-based TERCOM over the whole map ([TERCOM Eqs. 15-17], §4.2);
  :func:`tercom_direct` is the per-offset reference loop; :func:`refine_tercom` the sub-cell
  (bilinear, heading, scale) refinement of an MSD fix.
* :func:`posterior_fix` -- the point-mass posterior fix (MAP, covariance, ellipses, mass outside the
  main mode, mismatch reasons) from the MSD likelihood over offsets x headings x scales.
* :func:`mrf_refine` -- MRF fine matching of a gridded real-time terrain patch ([MRF Eqs. 4-14]).
* :mod:`hadal.matching.fix` -- measured profile from ``ctd.parquet``, matched track, ``fix.json`` content.
"""

from hadal.matching.mapgrid import MapGrid
from hadal.matching.mrf import MrfResult, mrf_refine
from hadal.matching.posterior import PosteriorFix, posterior_fix
from hadal.matching.tercom import TercomResult, refine_tercom, tercom, tercom_direct

__all__ = ["MapGrid", "MrfResult", "PosteriorFix", "TercomResult", "mrf_refine", "posterior_fix", "refine_tercom", "tercom",
           "tercom_direct"]
