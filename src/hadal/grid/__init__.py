"""Gridding: scattered points -> regular grids (multibeam DTM, 10 mm laser grids) and bathymetry readers.

Public API:

* :func:`grid_points` - exact NumPy sort-and-reduce cell statistics (mean, median, count, std, min, max);
* :func:`grid_tiled` - the same statistics out of core: points streamed in chunks, partitioned by tile on disk;
* :func:`grid_multibeam` / :func:`add_geo` - the reference DTM (spikes removed, uncertainty, small holes filled);
* :func:`grid_laser` - Sangekar et al. §III-A uniform 10 mm laser elevation grid (open3d cloud filtering);
* readers: :func:`read_soundings`, :func:`read_point_cloud`, :func:`read_grid`, :func:`read_gsf`.
"""

from typing import Any

from hadal._lazy import lazy_attr

#: public name -> submodule; imported on first access (PEP 562), so ``import hadal.grid.points`` (e.g. for a
#: constant in :class:`hadal.settings.grid.GridParams`) does not import SciPy, open3d and the readers
_LAZY = {
    "G_RES_M": "laser", "grid_laser": "laser",
    "add_geo": "multibeam", "apriori_sigma_m": "multibeam", "cell_uncertainty": "multibeam",
    "fill_small_holes": "multibeam", "grid_multibeam": "multibeam", "rmse_against": "multibeam",
    "GridSpec": "points", "grid_points": "points", "make_grid_spec": "points", "reduce_cells": "points",
    "robust_outlier_mask": "points", "grid_tiled": "tiles",
    "GridCRSWarning": "readers", "looks_metric": "readers", "read_grid": "readers", "read_gsf": "readers",
    "read_point_cloud": "readers", "read_soundings": "readers",
}


def __getattr__(name: str) -> Any:
    return lazy_attr(__name__, _LAZY, name)


__all__ = [
    "G_RES_M", "GridCRSWarning", "GridSpec", "add_geo", "apriori_sigma_m", "cell_uncertainty", "fill_small_holes",
    "grid_laser", "grid_multibeam", "grid_points", "grid_tiled", "looks_metric", "make_grid_spec", "read_grid", "read_gsf",
    "read_point_cloud", "read_soundings", "reduce_cells", "rmse_against", "robust_outlier_mask",
]
