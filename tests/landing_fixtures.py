"""Real-data fixtures of the landing tests and benchmarks (one place, used by ``tests/`` and ``bench/``).

The Takuyo laser raster of ``../shared/data/bathy-real`` (0.10 m cells, depth positive down, 0 = unmapped) as the
analysis reads it, and the same area resampled to a finer grid (the only way to get finer "real" grids here).
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import xarray as xr

#: the real Takuyo raster, relative to ``../shared/data``
TAKUYO_RASTER = "bathy-real/LAD_Takuyo_B1_raster_100mm.tif"
#: its cell size (m)
TAKUYO_CELL_M = 0.1


def read_takuyo(path: str | Path) -> xr.DataArray:
    """The Takuyo raster as a local metric depth grid: ``(y, x)`` cell centres in metres from its corner,
    ``positive="down"``, unmapped cells (stored as 0) NaN."""
    from hadal.grid.readers import read_grid

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # its geographic tag is wrong for a local survey: read as local metric
        g = read_grid(path, crs="local")
    d = g.values.astype(float)
    d[d == 0] = np.nan
    ny, nx = d.shape
    return xr.DataArray(d, dims=("y", "x"), coords={"y": (np.arange(ny) + 0.5) * TAKUYO_CELL_M,
                                                     "x": (np.arange(nx) + 0.5) * TAKUYO_CELL_M},
                        attrs={"units": "m", "positive": "down"})


def resampled(t: xr.DataArray, cell_m: float, box: tuple[float, float, float, float] | None = None
              ) -> xr.DataArray:
    """The same real area on a finer grid of ``cell_m``: values bilinear (gaps filled by the nearest cell first),
    the mapped mask by the nearest original cell. ``box``: ``(y0, y1, x0, x1)`` in metres (default: all)."""
    from scipy import ndimage as ndi

    v = np.isfinite(t.values)
    idx = ndi.distance_transform_edt(~v, return_distances=False, return_indices=True)
    filled = t.copy(data=t.values[idx[0], idx[1]])
    y0, y1, x0, x1 = box or (t.y.values[0], t.y.values[-1] + 1e-9, t.x.values[0], t.x.values[-1] + 1e-9)
    y, x = np.arange(y0, y1, cell_m), np.arange(x0, x1, cell_m)
    lin = filled.interp(y=y, x=x, method="linear", kwargs={"fill_value": None})
    mask = xr.DataArray(v.astype(float), dims=t.dims, coords=t.coords).interp(
        y=y, x=x, method="nearest", kwargs={"fill_value": 0.0})
    return lin.where(mask.values > 0.5)
