"""The reference map as used by the matchers: a regular grid of depth (positive down) on ascending x/y.

``MapGrid.from_any`` accepts the ``dtm`` product layout (an ``xarray.Dataset`` with ``depth_m(y, x)``
on cell-centre coordinates in metres of the dive's map frame), a ``DataArray`` or a plain
``(depth, x, y)`` triple, and validates it once (square cells, ascending axes, finite coordinates), so
the matching code can work in integer cell indices.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import xarray as xr

from hadal.errors import InputError


@dataclass(frozen=True)
class MapGrid:
    """``depth_m[row, col]`` at ``x_m[col]`` (east) / ``y_m[row]`` (north), cell size ``resolution_m``."""

    depth_m: np.ndarray
    x_m: np.ndarray
    y_m: np.ndarray
    resolution_m: float

    @property
    def shape(self) -> tuple[int, int]:
        return self.depth_m.shape  # type: ignore[return-value]

    @classmethod
    def from_any(cls, dtm, x=None, y=None, *, name: str = "reference map") -> MapGrid:
        if isinstance(dtm, MapGrid):
            return dtm
        if isinstance(dtm, xr.Dataset):
            if "depth_m" not in dtm:
                raise InputError(f"{name} has no 'depth_m' variable (have: {', '.join(map(str, dtm.data_vars))})")
            dtm = dtm["depth_m"]
        if isinstance(dtm, xr.DataArray):
            if set(dtm.dims) != {"y", "x"}:
                raise InputError(f"{name}: depth_m must have dims (y, x), got {dtm.dims}")
            dtm = dtm.transpose("y", "x")
            x = np.asarray(dtm["x"].values, float)
            y = np.asarray(dtm["y"].values, float)
            z = np.asarray(dtm.values, float)
        else:
            if x is None or y is None:
                raise InputError(f"{name}: give x and y coordinates with a plain depth array")
            z = np.asarray(dtm, float)
            x = np.asarray(x, float)
            y = np.asarray(y, float)
        if z.ndim != 2 or z.shape != (y.size, x.size):
            raise InputError(f"{name}: depth grid shape {z.shape} does not match y ({y.size}) x x ({x.size})")
        if x.size < 2 or y.size < 2:
            raise InputError(f"{name}: grid must be at least 2 x 2 cells, got {z.shape}")
        if not (np.isfinite(x).all() and np.isfinite(y).all()):
            raise InputError(f"{name}: x/y coordinates must be finite")
        if x[1] < x[0]:
            x, z = x[::-1], z[:, ::-1]
        if y[1] < y[0]:
            y, z = y[::-1], z[::-1, :]
        dx, dy = np.diff(x), np.diff(y)
        res = float(dx[0])
        if res <= 0 or not (np.allclose(dx, res, rtol=1e-6, atol=1e-6 * res) and np.allclose(dy, res, rtol=1e-6, atol=1e-6 * res)):
            raise InputError(f"{name}: cells must be square and regular with ascending x and y")
        z = np.where(np.isfinite(z), z, np.nan)
        if not np.isfinite(z).any():
            raise InputError(f"{name}: depth_m has no finite cells")
        return cls(np.ascontiguousarray(z), x, y, res)

    def filled(self, sigma_cells: float, min_weight: float = 0.05, smooth_all: bool = False) -> MapGrid:
        """Fill empty (NaN) cells by normalised Gaussian convolution of the valid ones (valid cells unchanged).

        ``fill(c) = sum_k w_k z_k / sum_k w_k`` over valid cells ``k`` with Gaussian weights of standard
        deviation ``sigma_cells``; cells whose weight sum (relative to a full neighbourhood) is below
        ``min_weight`` stay empty. For sparse multibeam DTMs (a few soundings per cell or fewer), where
        a track would otherwise rarely lie on valid cells only. ``smooth_all`` replaces every cell by
        the normalised convolution (a uniform low-pass map: filled and measured cells then have the same
        noise level, so the MSD does not favour the smoother filled areas).
        """
        from scipy.ndimage import gaussian_filter

        v = np.isfinite(self.depth_m)
        if sigma_cells <= 0 or (v.all() and not smooth_all):
            return self
        ref = float(np.nanmean(self.depth_m))
        num = gaussian_filter(np.where(v, self.depth_m - ref, 0.0), sigma_cells, mode="constant", truncate=3.0)
        den = gaussian_filter(v.astype(float), sigma_cells, mode="constant", truncate=3.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            fill = np.where(den >= min_weight, num / den + ref, np.nan)
        out = fill if smooth_all else np.where(v, self.depth_m, fill)
        return MapGrid(out, self.x_m, self.y_m, self.resolution_m)

    # ---------------------------------------------------------------- coordinates
    def region_window(self, region: tuple[float, float, float, float] | None) -> tuple[int, int, int, int]:
        """Row/column bounds ``(r0, r1, c0, c1)`` (half-open) of the cells whose centres lie in ``region``
        ``(x_min, x_max, y_min, y_max)`` (m); the whole map for ``None``. A region off the map is an
        :class:`~hadal.errors.InputError`."""
        ny, nx = self.shape
        if region is None:
            return 0, ny, 0, nx
        x0, x1, y0, y1 = region
        c0 = int(np.clip(np.ceil(self.col_of(x0) - 1e-9), 0, nx))
        c1 = int(np.clip(np.floor(self.col_of(x1) + 1e-9) + 1, 0, nx))
        r0 = int(np.clip(np.ceil(self.row_of(y0) - 1e-9), 0, ny))
        r1 = int(np.clip(np.floor(self.row_of(y1) + 1e-9) + 1, 0, ny))
        if r1 <= r0 or c1 <= c0:
            from hadal.errors import InputError

            raise InputError(f"matching region {region} does not overlap the map")
        return r0, r1, c0, c1

    def col_of(self, x_m) -> np.ndarray:
        """Fractional column index of map x (cell centre = integer)."""
        return (np.asarray(x_m, float) - self.x_m[0]) / self.resolution_m

    def row_of(self, y_m) -> np.ndarray:
        return (np.asarray(y_m, float) - self.y_m[0]) / self.resolution_m

    def sample_bilinear(self, x_m, y_m) -> np.ndarray:
        """Depth at map points by bilinear interpolation of the cell centres; NaN outside or next to NaN cells."""
        c, r = self.col_of(x_m), self.row_of(y_m)
        ny, nx = self.shape
        out = np.full(np.broadcast(c, r).shape, np.nan)
        c, r = np.broadcast_arrays(c, r)
        ok = (c >= 0) & (c <= nx - 1) & (r >= 0) & (r <= ny - 1)
        c0 = np.clip(np.floor(c[ok]).astype(int), 0, nx - 2)
        r0 = np.clip(np.floor(r[ok]).astype(int), 0, ny - 2)
        fc, fr = c[ok] - c0, r[ok] - r0
        z = self.depth_m
        out[ok] = (z[r0, c0] * (1 - fc) * (1 - fr) + z[r0, c0 + 1] * fc * (1 - fr)
                   + z[r0 + 1, c0] * (1 - fc) * fr + z[r0 + 1, c0 + 1] * fc * fr)
        return out
