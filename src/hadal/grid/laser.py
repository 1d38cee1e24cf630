"""Laser point clouds -> uniform 10 mm elevation grids (``laser_grids`` product).

Sangekar et al., *Autonomous landing of underwater vehicles using high resolution bathymetry*,
§III-A "Surface mapping": the unstructured light-sectioning point cloud (north, east, depth) is
"resampled to a uniform lateral grid resolution of g_res = 10 mm", fine enough to resolve any
protrusion that matters for landing. The paper does not say how points are combined per cell;
we use the cell **mean** elevation of the points (after outlier removal) and also publish the
point count and the within-cell standard deviation, so a consumer can judge each cell. Cells
with no point stay NaN ("unmapped" for the landing stage) - we deliberately do not interpolate
them, because an invented surface could hide an obstacle.

Cloud handling: open3d's optional voxel down-sampling (thins over-dense overlapping scan
lines before the statistics; off by default so ``count`` is the true number of laser returns)
and open3d's statistical outlier removal rule (mean distance to the k nearest neighbours more than
``std_ratio`` standard deviations above the cloud's mean: isolated returns from particles in the
water column or multipath), confirmed by a vertical test against the cell's other points so that
good points on swath and hole edges (which SOR also flags) stay. The SOR neighbour search runs in
a compiled cell-grid search (:func:`sor_outlier_mask`) instead of open3d's k-d tree: the same flags
(tests/unit/grid/test_laser_sor.py, open3d as the oracle) at about half of open3d's CPU time on the sample's
2.2 M-point submaps (bench/bench_laser_sor.py); open3d itself where a cloud does not suit the grid.
Cell statistics use the exact chunked sort-and-reduce of :mod:`hadal.grid.points`.
"""

from __future__ import annotations

import warnings
from collections.abc import Sequence

import numpy as np
import xarray as xr

from hadal.errors import InputError
from hadal.grid.points import (
    DEFAULT_MAX_CELLS,
    cell_moments,
    distinct_xy,
    make_grid_spec,
    point_extent,
    to_dataset,
)

#: Paper's lateral grid resolution g_res (m), §III-A.
G_RES_M = 0.010

#: cell = AUTO_FACTOR x the 90 % quantile of the points' nearest-neighbour distances (when coarser than g_res).
#: 1.0 with the grid's cell centres on the first point (below): a regular lattice of spacing s then puts one
#: point in every cell (100 % mapped); a cell of 0.95 s would already leave ~10 % empty (0.95**2 = 0.90).
AUTO_FACTOR = 1.0


def auto_resolution_m(points, *, quantile: float = 0.9, max_points: int = 1_000_000) -> tuple[float, dict]:
    """The ``laser_resolution_m: auto`` cell size of a cloud: the paper's g_res (10 mm) when the points are
    at least that dense, else :data:`AUTO_FACTOR` x the ``quantile`` of the lateral nearest-neighbour
    distances (as :func:`hadal.grid.multibeam.auto_resolution_m`, not snapped to its 1-2-5 series, which
    starts at 0.1 m), rounded to 3 significant digits and floored at 10 mm.

    Returns ``(size_m, {"nn_quantile_m", "rule"})``; above ``max_points`` a regular subsample is used and the
    distance scaled by sqrt(step) (2-D density scaling).
    """
    p, _ = clean_cloud(points)
    step = max(1, int(np.ceil(len(p) / max_points)))
    xy = distinct_xy(p[::step, 0], p[::step, 1])
    if len(xy) < 3:
        return G_RES_M, {"nn_quantile_m": float("nan"), "rule": "fewer than 3 distinct x/y positions: g_res"}
    q = float(np.quantile(nearest_neighbour_m(xy), quantile)) / np.sqrt(step)
    target = AUTO_FACTOR * q
    if target <= G_RES_M * 1.0005:
        return G_RES_M, {"nn_quantile_m": q, "rule": f"points at least as dense as g_res (nearest-neighbour "
                                                       f"{100 * quantile:g} % quantile {q:.3g} m): paper's 10 mm"}
    res = max(G_RES_M, float(f"{target:.3g}"))
    return res, {"nn_quantile_m": q, "rule": f"{AUTO_FACTOR:g} x the nearest-neighbour {100 * quantile:g} % "
                                             f"quantile {q:.4g} m (coarser than the paper's 10 mm g_res)"}


def nearest_neighbour_m(xy: np.ndarray) -> np.ndarray:
    """(M,) distance of every x/y point (distinct) to its nearest other: scipy ``cKDTree(xy).query(xy, k=2)``'s second
    column, by the grid search of :func:`knn_mean_distance_m` on the points at z = 0 (twice the mean of 0 and that
    distance, exact in binary) where the points suit it, else by scipy."""
    pts = np.column_stack([np.asarray(xy, np.float64), np.zeros(len(xy))])
    avg = knn_mean_distance_m(pts, 2) if len(pts) > 2 else None
    if avg is None:
        from scipy.spatial import cKDTree

        d, _ = cKDTree(pts[:, :2]).query(pts[:, :2], k=2)
        return d[:, 1]
    return 2.0 * avg


def coordinate_quantum_m(v, *, max_points: int = 5_000_000) -> float:
    """The step every coordinate value of ``v`` sits on (m), or 0.0 when the values are not quantised.

    The smallest positive difference ``q`` between the sorted distinct values is the quantum when (nearly)
    every difference is an integer multiple of it: float32 coordinates far from the origin (UTM x ~5e5 m
    resolves only 2**-5 m, y ~1.25e6 m 2**-3 m), or text printed with few decimals. Above ``max_points`` a
    regular subsample is used.
    """
    a = np.asarray(v, np.float64)
    a = a[np.isfinite(a)]
    if a.size > max_points:
        a = a[:: int(np.ceil(a.size / max_points))]
    u = np.unique(a)
    if u.size < 3:
        return 0.0
    d = np.diff(u)
    q = float(d.min())
    if not q > 0:
        return 0.0
    r = d / q
    if np.mean(np.abs(r - np.rint(r)) < 0.01) < 0.99:
        return 0.0
    return q


def check_quantisation(p: np.ndarray, resolution: float, pinned: bool) -> tuple[float, str]:
    """Compare the cloud's x/y coordinate quantum (:func:`coordinate_quantum_m`) with the cell size.

    A quantum more than 5 % coarser than the cell leaves empty stripes (points only every q/res columns).
    Returns ``(resolution, note)``. ``pinned`` (the user gave the cell size): a one-line :class:`InputError`
    when the quantum is the float32 spacing at the coordinates' magnitude (precision lost in the file), else
    the cell is kept and ``note`` warns (a lattice-like cloud, e.g. a raster's points, gridded finer than its
    spacing). Otherwise (auto) the cell is raised to the coarser quantum and ``note`` says why.
    """
    qs = {ax: coordinate_quantum_m(p[:, i]) for i, ax in enumerate("xy")}
    q = max(qs.values())
    if not q > resolution * 1.05:
        return resolution, ""
    ax = max(qs, key=qs.get)
    mag = float(np.max(np.abs(p[:, "xy".index(ax)])))
    f32 = float(np.spacing(np.float32(mag)))
    is_f32 = 0.5 * f32 <= q <= 2.0 * f32
    why = (f"float32 coordinates at {mag:.3g} m resolve only {f32:g} m: shift the cloud to a local origin before "
           "saving it (e.g. CloudCompare/PDAL global shift) or store it as float64"
           if is_f32 else "a lattice, or coordinates stored with few decimals")
    msg = f"the laser cloud's {ax} coordinates are quantised to {q:g} m, coarser than the {resolution:g} m cell ({why})"
    if pinned:
        if is_f32:
            raise InputError(f"{msg}; use grid.laser_resolution_m >= {q:g} or 'auto'")
        return resolution, f"{msg}; expect empty stripes between the coordinate steps"
    new = float(f"{q:.3g}")
    new = new if new >= q else float(f"{q * 1.001:.3g}")
    return new, f"{msg}; cell raised to {new:g} m"


def clean_cloud(points) -> tuple[np.ndarray, int]:
    """``(N, 3)`` float64 array without rows containing NaN/inf, and the number dropped.

    Raises :class:`InputError` for a wrongly shaped, empty or all-non-finite cloud.
    """
    try:
        p = np.asarray(points, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise InputError(f"a point cloud must hold numbers (x, y, z metres): {exc}") from None
    if p.ndim != 2 or p.shape[1] != 3:
        raise InputError(f"a point cloud must be an (N, 3) array of x, y, z metres, got shape {p.shape}")
    if len(p) == 0:
        raise InputError("empty point cloud: no points to grid")
    ok = np.isfinite(p).all(axis=1)
    n_bad = int(len(p) - ok.sum())
    if n_bad == len(p):
        raise InputError(f"all {len(p)} points of the cloud have NaN/inf coordinates")
    return (p[ok] if n_bad else p), n_bad


def sor_outlier_mask(points: np.ndarray, nb_neighbors: int, std_ratio: float) -> np.ndarray:
    """True for the points open3d's ``remove_statistical_outlier(nb_neighbors, std_ratio)`` removes: mean distance to
    the ``nb_neighbors`` nearest points (the point itself included) not below ``mean + std_ratio * std`` of the
    cloud's mean distances, or zero (a point with ``nb_neighbors`` coincident copies).

    Same arithmetic as open3d (:mod:`hadal.grid._sor_kernels`), with the neighbour search of
    :func:`knn_mean_distance_m` instead of a k-d tree: on a laser submap of even density it takes about half open3d's
    CPU time, its searches in parallel blocks (bench/bench_laser_sor.py; ``tests/unit/grid/test_laser_sor.py`` checks the
    flags against open3d). A cloud the grid does not suit goes to open3d itself."""
    from hadal.grid._sor_kernels import sor_keep

    pts = np.ascontiguousarray(points, dtype=np.float64)
    avg = knn_mean_distance_m(pts, int(nb_neighbors))
    if avg is None:
        return _open3d_sor_mask(pts, int(nb_neighbors), std_ratio)
    return ~sor_keep(avg, float(std_ratio))


def knn_mean_distance_m(points: np.ndarray, k: int) -> np.ndarray | None:
    """(N,) mean distance of every point to its ``k`` nearest points (itself included, at 0), by an exact search of
    a uniform cell grid over two axes (the pair with the least search work: the lateral plane of a 2.5-D surface;
    :func:`hadal.grid._sor_kernels.knn_mean_distance`); None when the cloud does not suit the grid (no extent in
    any plane, or a cell holding more than ``max(64 k, 1 %)`` of the points)."""
    from hadal.grid._sor_kernels import knn_mean_distance
    from hadal.grid.knn_cells import sorted_by_cell, too_dense, uniform_cells

    pts = np.ascontiguousarray(points, dtype=np.float64)
    n = len(pts)
    lo = pts.min(axis=0)
    # the lateral plane: the pair of axes with the least search work, judged on a regular subsample
    step = max(1, n // 200_000)
    sub = pts[::step]
    trials = {ax: uniform_cells(sub, lo, ax[0], ax[1], k) for ax in ((0, 1), (0, 2), (1, 2))}
    work = {ax: t[0] for ax, t in trials.items() if t is not None}
    if not work:
        return None
    a0, a1 = min(work, key=lambda ax: work[ax])
    binned = trials[(a0, a1)] if step == 1 else uniform_cells(pts, lo, a0, a1, k)  # the subsample is the cloud
    if binned is None:
        return None
    if too_dense(binned[5], n, k):
        return None
    co = sorted_by_cell(binned, float(lo[a0]), float(lo[a1]))
    del binned, trials
    cols = [pts[co.order, i] for i in range(3)]  # x, y, z in cell order (contiguous copies)
    avg_sorted = np.empty(n)
    knn_mean_distance(cols[0], cols[1], cols[2], cols[a0], cols[a1], co.starts, co.ncu, co.ncv, co.u0, co.v0, co.cs,
                      k, avg_sorted, 4096)
    del cols
    avg = np.empty(n)
    avg[co.order] = avg_sorted
    return avg


def _open3d_sor_mask(pts: np.ndarray, k: int, std_ratio: float) -> np.ndarray:
    import open3d as o3d

    pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(pts))
    _, ind = pc.remove_statistical_outlier(nb_neighbors=int(k), std_ratio=float(std_ratio))
    cand = np.ones(len(pts), dtype=bool)
    cand[np.asarray(ind, dtype=np.int64)] = False
    return cand


def filter_cloud(points: np.ndarray, *, voxel_size_m: float | None = None, sor_neighbors: int = 20,
                 sor_std_ratio: float = 3.0) -> tuple[np.ndarray, np.ndarray, dict]:
    """open3d voxel down-sampling (if ``voxel_size_m``), then statistical outlier removal (if ``sor_neighbors``;
    :func:`sor_outlier_mask`, open3d's ``remove_statistical_outlier``).

    Returns ``(points, candidate_mask, info)``: the (down-sampled) points, True for the points SOR
    flags, and ``{"n_after_voxel", "n_sor_candidates"}``. The caller decides which candidates go
    (:func:`grid_laser`): SOR alone also flags good points on swath and hole edges, whose neighbours
    lie on one side only.
    """
    pts = points
    if voxel_size_m:
        import open3d as o3d

        if voxel_size_m <= 0:
            raise InputError(f"voxel size must be positive, got {voxel_size_m}")
        pc = o3d.geometry.PointCloud(o3d.utility.Vector3dVector(points))
        pts = np.asarray(pc.voxel_down_sample(float(voxel_size_m)).points)
    cand = np.zeros(len(pts), dtype=bool)
    if sor_neighbors and len(pts) > sor_neighbors:
        cand = sor_outlier_mask(pts, int(sor_neighbors), float(sor_std_ratio))
    return pts, cand, {"n_after_voxel": len(pts), "n_sor_candidates": int(cand.sum())}


def grid_laser(
    points,
    resolution: float | str = G_RES_M,
    *,
    bounds: Sequence[float] | None = None,
    voxel_size_m: float | None = None,
    sor_neighbors: int = 20,
    sor_std_ratio: float = 3.0,
    surface_tol_m: float = 0.02,
    max_cells: int = DEFAULT_MAX_CELLS,
) -> xr.Dataset:
    """Grid a laser cloud ``(N, 3)`` (x, y, z metres, z up = elevation) at ``resolution`` (default 10 mm).

    Outliers: statistical outlier removal (open3d's rule, :func:`sor_outlier_mask`) proposes candidates; a
    candidate is removed only if it is also off the surface - its cell has no other point, or it lies more than
    ``max(surface_tol_m, 4 * cell std)`` from the mean of the cell's other points. ``surface_tol_m``
    (20 mm) is ~3x the paper's 6 mm vertical resolution (Table I). This keeps the good edge points
    SOR flags along swath edges, gaps and holes, and removes returns from particles above the floor.

    Returns a Dataset with ``elevation_m`` (cell mean, NaN where unmapped), ``elevation_std_m``
    (sample std, NaN for < 2 points) and ``count`` on cell-centre ``x``/``y`` (ascending).

    ``resolution="auto"``: :func:`auto_resolution_m` (10 mm for dense clouds, else from the point spacing);
    a cell coarser than 10 mm is laid out with a cell centre on the lowest x/y of the points (not snapped to
    multiples of the cell), so lattice-like clouds (a raster's points) fall one per cell.
    ``attrs``: ``resolution_choice`` and ``nn_quantile_m`` record the choice.
    """
    p, n_bad = clean_cloud(points)
    n_in = len(p)
    resolution, choice, nn_q, qnote, centred = _choose_resolution(p, resolution, bounds)
    pts, cand, info = filter_cloud(p, voxel_size_m=voxel_size_m, sor_neighbors=sor_neighbors,
                                   sor_std_ratio=sor_std_ratio)
    x, y, z = (np.ascontiguousarray(pts[:, i]) for i in range(3))
    good = ~cand
    if not good.any():
        raise InputError(f"statistical outlier removal rejected all {len(pts)} points; check the cloud")
    if centred:  # the extent of all points: SOR candidates kept below must fall inside the grid too
        ext, _ = point_extent(x, y, z)
        h = resolution / 2
        spec = make_grid_spec(resolution, (ext[0] - h, ext[1] - h, ext[2] + h, ext[3] + h), max_cells=max_cells)
    elif bounds is None:
        ext, _ = point_extent(x[good], y[good], z[good])
        spec = make_grid_spec(resolution, ext, max_cells=max_cells, snap=True)
    else:
        spec = make_grid_spec(resolution, bounds, max_cells=max_cells)
    n_removed = 0
    if cand.any() and centred:
        n_removed = _keep_surface_candidates_nn(x, y, z, good, cand, resolution, surface_tol_m)
        x, y, z = x[good], y[good], z[good]
    elif cand.any():
        n_removed = _keep_surface_candidates_cell(x, y, z, good, cand, spec, surface_tol_m)
        x, y, z = x[good], y[good], z[good]
    info["n_outliers"] = n_removed
    cnt, mean, m2, _, n_out = cell_moments(x, y, z, spec, check_inside=bounds is not None, all_finite=True)
    std = np.full(spec.n_cells, np.nan)
    ok = cnt > 1
    std[ok] = np.sqrt(m2[ok] / (cnt[ok] - 1))
    ds = to_dataset(
        spec, {"mean": mean, "std": std, "count": cnt.astype(np.int32)},
        names={"mean": "elevation_m", "std": "elevation_std_m"},
        attrs={
            "n_points_input": int(n_in + n_bad),
            "n_points_nonfinite": n_bad,
            "n_points_after_voxel": int(info["n_after_voxel"]),
            "n_points_sor_candidates": int(info["n_sor_candidates"]),
            "n_points_outliers": int(info["n_outliers"]),
            "n_points_outside": int(n_out),
            "n_points_used": int(cnt.sum()),
            "mapped_fraction": float(np.count_nonzero(cnt) / spec.n_cells),
            "resolution_m": spec.resolution,
            "resolution_choice": choice,
            "coordinate_quantisation": qnote,
            "nn_quantile_m": nn_q,
            "voxel_size_m": float(voxel_size_m) if voxel_size_m else 0.0,
            "outlier_filter": (f"statistical outlier removal as open3d remove_statistical_outlier(nb_neighbors="
                               f"{sor_neighbors}, std_ratio={sor_std_ratio}): candidates removed when off the surface "
                               f"(> max({surface_tol_m} m, 4 cell std) from their cell's other points)"
                               if sor_neighbors else "none"),
            "method": "Sangekar et al. SIII-A: resampled to a uniform lateral grid; cell mean of the points",
        },
    )
    _laser_var_attrs(ds)
    return ds


def _choose_resolution(p: np.ndarray, resolution: float | str, bounds: Sequence[float] | None
                       ) -> tuple[float, str, float, str, bool]:
    """Resolve ``resolution`` (a number or ``"auto"``) for :func:`grid_laser`; warn on coordinate quantisation.

    Returns ``(resolution, choice, nn_q, qnote, centred)``.
    """
    choice, nn_q = f"{resolution!r} given", float("nan")
    centred = False
    if isinstance(resolution, str):
        if resolution != "auto":
            raise InputError(f"laser resolution must be a number of metres or 'auto', got {resolution!r}")
        resolution, ainfo = auto_resolution_m(p)
        choice, nn_q = f"auto: {ainfo['rule']}", ainfo["nn_quantile_m"]
        resolution, qnote = check_quantisation(p, resolution, pinned=False)
        if qnote:
            choice = f"auto: {qnote}"
            warnings.warn(qnote, UserWarning, stacklevel=3)
        centred = resolution > G_RES_M and bounds is None
    else:
        resolution = float(resolution)
        _, qnote = check_quantisation(p, resolution, pinned=True)
        if qnote:
            warnings.warn(qnote, UserWarning, stacklevel=3)
    return float(resolution), choice, nn_q, qnote, centred


def _keep_surface_candidates_nn(x, y, z, good: np.ndarray, cand: np.ndarray, resolution: float,
                                surface_tol_m: float) -> int:
    """Mark SOR candidates on the surface of their nearest neighbours as ``good`` (in place); return the removed."""
    # a spacing-derived cell holds about one point: the surface test uses the candidate's 8 nearest
    # non-candidate neighbours within 2.5 cells instead of its cell's other points
    from scipy.spatial import cKDTree

    gi = np.flatnonzero(good)
    ci = np.flatnonzero(cand)
    d, nb = cKDTree(np.column_stack([x[gi], y[gi]])).query(np.column_stack([x[ci], y[ci]]), k=8,
                                                           distance_upper_bound=2.5 * resolution)
    has = np.isfinite(d)
    zn = np.where(has, z[gi][np.minimum(nb, len(gi) - 1)], np.nan)
    cnt_n = has.sum(axis=1)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        mu = np.nanmean(zn, axis=1)
        sd = np.where(cnt_n > 1, np.nanstd(zn, axis=1, ddof=1), 0.0)
        on_surface = (cnt_n > 0) & (np.abs(z[ci] - mu) <= np.maximum(surface_tol_m, 4.0 * sd))
    good[ci[on_surface]] = True
    n_removed = int(ci.size - on_surface.sum())
    return n_removed


def _keep_surface_candidates_cell(x, y, z, good: np.ndarray, cand: np.ndarray, spec, surface_tol_m: float) -> int:
    """Mark SOR candidates on the surface of their cell's other points as ``good`` (in place); return the removed."""
    c0, mean0, m20, _, _ = cell_moments(x[good], y[good], z[good], spec, check_inside=True, all_finite=True)
    ci, inside = spec.cell_index(x[cand], y[cand], check_inside=True, finite=True)
    cc = np.where(inside, c0[ci], 0)
    sd = np.zeros(len(ci))
    multi = cc > 1
    sd[multi] = np.sqrt(m20[ci[multi]] / (cc[multi] - 1))
    with np.errstate(invalid="ignore"):
        on_surface = (cc > 0) & (np.abs(z[cand] - mean0[ci]) <= np.maximum(surface_tol_m, 4.0 * sd))
    keep_c = np.flatnonzero(cand)[on_surface]
    good[keep_c] = True
    n_removed = int(cand.sum() - on_surface.sum())
    return n_removed


def _laser_var_attrs(ds: xr.Dataset) -> None:
    """Set the CF attrs of the laser grid's variables and coordinates."""
    ds["elevation_m"].attrs = {"standard_name": "height", "long_name": "mean elevation of the laser points in the cell",
                               "units": "m", "positive": "up", "cell_methods": "area: mean",
                               "comment": "NaN = unmapped cell"}
    ds["elevation_std_m"].attrs = {"long_name": "sample standard deviation of the point elevations in the cell",
                                   "units": "m"}
    ds["count"].attrs = {"long_name": "number of laser points in the cell", "units": "1"}
    ds["x"].attrs.update({"long_name": "x in the laser survey's local frame", "units": "m", "axis": "X"})
    ds["y"].attrs.update({"long_name": "y in the laser survey's local frame", "units": "m", "axis": "Y"})


def laser_grid_from_raster(da: xr.DataArray, *, z_positive: str, z_reason: str = "", frame=None) -> xr.Dataset:
    """A laser bathymetry raster (a :func:`hadal.grid.readers.read_grid` array) as a ``laser_grids`` Dataset.

    The raster is used **at its own resolution** (no resampling to ``G_RES_M``: a raster already has one
    value per cell, and refining it would only interpolate) whether finer or coarser than 10 mm; the
    resolution is recorded in ``resolution``/``resolution_m``. Local metric and projected rasters keep
    their x/y metres; a geographic (lon/lat) raster, or one with non-square cells, is resampled bilinearly
    (:func:`hadal.grid.prior.resample_to_frame`) onto ``frame`` (the dive's map frame) at its native
    resolution. Values become ``elevation_m`` (positive up): depths (``z_positive='down'``) are negated.
    Nodata is NaN (unmapped). A raster has no per-cell point statistics, so ``count``/``elevation_std_m``
    are absent.
    """
    from hadal.grid.prior import RESAMPLING, resample_to_frame

    src = str(da.attrs.get("source", "raster"))
    dx, dy = float(da.attrs.get("cell_size_x", 0)), float(da.attrs.get("cell_size_y", 0))
    kind = da.attrs.get("crs_kind")
    square = dx > 0 and abs(dx - dy) <= 1e-3 * dx
    if kind == "geographic" or not square:
        if kind == "geographic" and frame is None:
            raise InputError(f"{src}: a lon/lat laser raster needs the dive's map frame to be gridded in metres")
        ds, info = resample_to_frame(da, frame if kind == "geographic" else None, None, max_extent_m=None)
        z, x, y, res, method = ds["z"].values, ds["x"].values, ds["y"].values, info["resolution_m"], RESAMPLING
    else:
        z, x, y, res = np.asarray(da.values, float), da["x"].values, da["y"].values, dx
        method = "raster loaded at its own resolution (no resampling)"
    elev = -z if z_positive == "down" else z
    mapped = np.isfinite(elev)
    ds = xr.Dataset(
        {"elevation_m": (("y", "x"), elev, {
            "standard_name": "height", "long_name": "elevation of the laser raster cell", "units": "m",
            "positive": "up", "comment": "NaN = unmapped (nodata) cell"})},
        coords={"x": ("x", np.asarray(x, float), {"long_name": "x in the laser survey's local frame", "units": "m",
                                                  "axis": "X"}),
                "y": ("y", np.asarray(y, float), {"long_name": "y in the laser survey's local frame", "units": "m",
                                                  "axis": "Y"})},
    )
    ds.attrs.update({
        "resolution": float(res), "resolution_m": float(res),
        "grid_x0_edge": float(x[0]) - res / 2, "grid_y0_edge": float(y[0]) - res / 2,
        "mapped_fraction": float(mapped.mean()), "n_cells_mapped": int(mapped.sum()),
        "laser_input": "raster", "method": method,
        "source_format": str(da.attrs.get("format", "")), "source_reader": str(da.attrs.get("reader", "")),
        "source_crs_kind": str(kind), "source_cell_size": f"{dx:.8g} x {dy:.8g}",
        "z_positive_source": z_positive, "z_sign_detection": z_reason, "z_sign_flipped": int(z_positive == "down"),
        "layers_absent": "count, elevation_std_m: a raster has no per-cell point statistics",
    })
    if da.attrs.get("crs_wkt") and kind == "projected":
        ds.attrs["source_crs_wkt"] = str(da.attrs["crs_wkt"])
        ds["x"].attrs["long_name"] = "x (easting) in the raster's projected CRS (source_crs_wkt)"
        ds["y"].attrs["long_name"] = "y (northing) in the raster's projected CRS (source_crs_wkt)"
    if kind == "geographic":
        ds["x"].attrs["long_name"] = "x (east) in the dive's map frame"
        ds["y"].attrs["long_name"] = "y (north) in the dive's map frame"
    if "crs_override" in da.attrs:
        ds.attrs["source_crs_override"] = str(da.attrs["crs_override"])
    return ds
