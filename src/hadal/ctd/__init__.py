"""Sea-Bird processing steps as pure functions on NumPy arrays (SBEDataProcessing's documented algorithms).

One small module per SBEDataProcessing module, in the order Sea-Bird recommends running them:

* :mod:`hadal.ctd.wild_edit` — WildEdit: two-pass, block-wise standard-deviation rejection;
* :mod:`hadal.ctd.filters` — Filter: Sea-Bird's time-constant low-pass, run forward and backward;
* :mod:`hadal.ctd.align` — AlignCTD: advance a channel in time relative to pressure;
* :mod:`hadal.ctd.thermal_mass` — CellTM: conductivity cell thermal-mass correction (alpha, 1/beta);
* :mod:`hadal.ctd.loop_edit` — LoopEdit: minimum velocity / percent of mean speed, pressure reversals, soak;
* :mod:`hadal.ctd.casts` — split a record at its deepest good scan into descent and ascent casts;
* :mod:`hadal.ctd.bin_average` — BinAvg: bins centred on multiples of the bin size, by pressure or depth.

:mod:`hadal.ctd.chain` runs the enabled steps on a ``sensors`` table; :mod:`hadal.ctd.derive` is the ``derive``
stage's science (pressure fusion, seawater, depth, phases: :func:`hadal.ctd.derive.derive_table`).
Reference: Sea-Bird Scientific, *SBE Data Processing* manual (SeaSoft V2, 7.26.8), sections
"Data Processing Modules" (AlignCTD, BinAvg, CellTM, Filter, LoopEdit, WildEdit). Bad scans are boolean
masks here (``True`` = bad) rather than SeaSoft's ``-9.990e-29`` flag value; bad values are NaN.
"""

from hadal.ctd.align import align_ctd
from hadal.ctd.bin_average import BinAverage, bin_average
from hadal.ctd.casts import cast_labels, find_downcast, find_upcast
from hadal.ctd.filters import low_pass_filter
from hadal.ctd.loop_edit import loop_edit
from hadal.ctd.thermal_mass import cell_thermal_mass
from hadal.ctd.wild_edit import wild_edit

__all__ = ["BinAverage", "align_ctd", "bin_average", "cast_labels", "cell_thermal_mass", "find_downcast",
           "find_upcast", "loop_edit", "low_pass_filter", "wild_edit"]
