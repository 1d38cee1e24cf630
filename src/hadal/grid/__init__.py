"""Gridding: scattered points -> regular grids (multibeam DTM, 10 mm laser grids) and bathymetry readers.

Public API:

* :func:`grid_points` - exact NumPy sort-and-reduce cell statistics (mean, median, count, std, min, max);
* :func:`grid_multibeam` / :func:`add_geo` - the reference DTM (spikes removed, uncertainty, small holes filled);
* :func:`grid_laser` - Sangekar et al. §III-A uniform 10 mm laser elevation grid (open3d cloud filtering);
* readers: :func:`read_soundings`, :func:`read_point_cloud`, :func:`read_grid`, :func:`read_gsf`.
"""

from hadal.grid.laser import G_RES_M, grid_laser
from hadal.grid.multibeam import (
    add_geo,
    apriori_sigma_m,
    cell_uncertainty,
    fill_small_holes,
    grid_multibeam,
    rmse_against,
)
from hadal.grid.points import GridSpec, grid_points, make_grid_spec, reduce_cells, robust_outlier_mask
from hadal.grid.readers import (
    GridCRSWarning,
    looks_metric,
    read_grid,
    read_gsf,
    read_point_cloud,
    read_soundings,
)

__all__ = [
    "G_RES_M", "GridCRSWarning", "GridSpec", "add_geo", "apriori_sigma_m", "cell_uncertainty", "fill_small_holes",
    "grid_laser", "grid_multibeam", "grid_points", "looks_metric", "make_grid_spec", "read_grid", "read_gsf",
    "read_point_cloud", "read_soundings", "reduce_cells", "rmse_against", "robust_outlier_mask",
]
