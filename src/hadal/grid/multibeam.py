"""Multibeam soundings -> reference DTM (``dtm.nc``).

Pipeline (:func:`grid_multibeam`):

1. drop soundings with NaN/inf coordinates (counted);
2. **spike removal**, two robust tests (both documented in :func:`spike_mask`):
   a. per cell: ``|z - median| > k * max(1.4826 * MAD, sigma_0)`` for cells with >= ``min_count``
      soundings (the bathygrid/CUBE-style per-node median test); ``sigma_0`` is the typical cell
      sigma of the whole survey (data-driven noise floor);
   b. per sounding: ``|z - ref| > k_nb * max(sigma_nb, sigma_0)``, ``ref`` the median depth of its 16
      nearest soundings (scipy cKDTree) and ``sigma_nb`` their scaled MAD (noise plus local relief).
      This catches spikes in sparse surveys (0-2 soundings per cell) that test (a) cannot judge.
   Optionally (``sor=True``) open3d's statistical outlier removal on the (x, y, z) cloud as well.
3. per-cell mean (``depth_m``), median, count and sample std with :func:`hadal.grid.points.reduce_cells`;
4. **uncertainty** (:func:`cell_uncertainty`);
5. **gap filling** of small interior holes only (:func:`fill_small_holes`), flagged in ``filled``.

Depth is positive down throughout (the contract's ``depth_m``).
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import xarray as xr
from scipy import ndimage

from hadal.errors import InputError
from hadal.geo import LocalFrame
from hadal.grid.points import (
    DEFAULT_MAX_CELLS,
    cell_robust_stats,
    distinct_xy,
    make_grid_spec,
    point_extent,
    reduce_cells,
    robust_outlier_mask,
    to_dataset,
    typical_cell_sigma,
)

MAD_TO_SIGMA = 1.4826


#: candidate DTM cell sizes (m) of :func:`auto_resolution_m`: the 1-2-5 series from 0.1 m to 5 km
RESOLUTION_SERIES_M: tuple[float, ...] = tuple(m * 10.0 ** e for e in range(-1, 4) for m in (1.0, 2.0, 5.0)) + (
    10000.0,)


def auto_resolution_m(x_m: np.ndarray, y_m: np.ndarray, *, quantile: float = 0.9, factor: float = 2.0,
                      max_points: int = 1_000_000) -> tuple[float, dict[str, float]]:
    """A DTM cell size from the sounding spacing: ``factor`` x the ``quantile`` of the nearest-neighbour
    distances between soundings, snapped (in log) to the nearest value of :data:`RESOLUTION_SERIES_M`.

    With the defaults a cell is about twice the spacing that 90 % of the soundings have to their nearest
    neighbour, so most cells hold soundings (beam spacing across track, ping spacing along it). Not from the
    TERCOM paper, which fixes 20 m for its EM122 survey at 11 km depth: the default must suit a 4-m deep single
    ping as well as a hadal survey (the sample dive pins 20 m in its pipeline.yaml). Above ``max_points`` a
    regular subsample is used and the distances scaled by sqrt(step) (2-D density scaling).
    Returns ``(size_m, {"nn_quantile_m": ..., "soundings": ...})``.
    """
    x, y = np.asarray(x_m, np.float64), np.asarray(y_m, np.float64)
    ok = np.isfinite(x) & np.isfinite(y)
    x, y = x[ok], y[ok]
    step = auto_resolution_step(x.size, max_points)
    return auto_resolution_of_sample(x[::step], y[::step], step, x.size, quantile=quantile, factor=factor)


def auto_resolution_step(n_xy: int, max_points: int = 1_000_000) -> int:
    """The subsample step of :func:`auto_resolution_m` for ``n_xy`` soundings with finite x, y."""
    return 1 if n_xy <= max_points else int(np.ceil(n_xy / max_points))


def auto_resolution_of_sample(xs: np.ndarray, ys: np.ndarray, step: int, n_xy: int, *, quantile: float = 0.9,
                              factor: float = 2.0) -> tuple[float, dict[str, float]]:
    """:func:`auto_resolution_m` from its subsample ``xs, ys`` (every ``step``-th of the ``n_xy`` soundings with
    finite x, y; :func:`auto_resolution_step`), e.g. read from soundings kept on disk."""
    from scipy.spatial import cKDTree

    xy = distinct_xy(xs, ys)
    if len(xy) < 3:
        raise InputError("too few soundings with distinct positions to choose a DTM resolution")
    d, _ = cKDTree(xy).query(xy, k=2)
    q = float(np.quantile(d[:, 1], quantile)) / np.sqrt(step)
    target = max(factor * q, RESOLUTION_SERIES_M[0])
    series = np.asarray(RESOLUTION_SERIES_M)
    res = float(series[np.argmin(np.abs(np.log(series / target)))])
    return res, {"nn_quantile_m": float(q), "soundings": float(n_xy)}


def apriori_sigma_m(depth_m, a_m: float = 0.5, b: float = 0.001):
    """A-priori 1-sigma vertical uncertainty of one sounding: ``sqrt(a**2 + (b * depth)**2)`` metres.

    The form is IHO S-44 (6th ed., Table 1) total vertical uncertainty; the defaults are not S-44's
    95 % survey-order limits but a 1-sigma deep-water multibeam performance of 0.1 % of depth (EM122
    class: ~0.2 % of depth at 2 sigma), so a 10 000 m sounding has sigma ~ 10 m.
    """
    d = np.abs(np.asarray(depth_m, dtype=np.float64))
    return np.sqrt(a_m * a_m + (b * d) ** 2)


def cell_uncertainty(count, std, median_depth_m, *, a_m: float = 0.5, b: float = 0.001,
                     prior_weight: float = 3.0) -> np.ndarray:
    """Standard uncertainty of a cell's mean depth (m).

    The sounding sigma is a Bayesian/pooled combination of the cell's sample variance ``s**2``
    (``n - 1`` degrees of freedom) and the a-priori variance ``sigma_a**2`` (:func:`apriori_sigma_m`)
    weighted as ``prior_weight`` pseudo-degrees of freedom::

        sigma**2 = ((n - 1) * s**2 + nu0 * sigma_a**2) / (n - 1 + nu0),   u = sigma / sqrt(n)

    so a cell with one sounding gets ``sigma_a`` and a well-sampled cell converges to the standard
    error of its mean ``s / sqrt(n)`` (which also absorbs the terrain relief inside the cell).
    Empty cells are NaN.
    """
    n = np.asarray(count, dtype=np.float64)
    s2 = np.nan_to_num(np.asarray(std, dtype=np.float64) ** 2)
    sa = apriori_sigma_m(median_depth_m, a_m, b)
    dof = np.maximum(n - 1.0, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        sigma2 = (dof * s2 + prior_weight * sa * sa) / (dof + prior_weight)
        u = np.sqrt(sigma2 / n)
    return np.where(n > 0, u, np.nan)


def _plane_fit(dx, dy, nb, w):
    """Weighted least-squares plane ``z = c0 + c1 dx + c2 dy`` per row (batched 3 x 3 normal equations,
    with a tiny ridge on the slope terms so collinear neighbours do not make it singular)."""
    s1, sx, sy = w.sum(1), (w * dx).sum(1), (w * dy).sum(1)
    sxx, syy, sxy = (w * dx * dx).sum(1), (w * dy * dy).sum(1), (w * dx * dy).sum(1)
    ridge = 1e-6 * (sxx + syy) / np.maximum(s1, 1) + 1e-12
    m = np.stack([np.stack([s1, sx, sy], -1), np.stack([sx, sxx + ridge, sxy], -1),
                  np.stack([sy, sxy, syy + ridge], -1)], -2)
    rhs = np.stack([(w * nb).sum(1), (w * nb * dx).sum(1), (w * nb * dy).sum(1)], -1)
    return np.linalg.solve(m, rhs[..., None])[..., 0]


def _neighbour_chunks(x, y, neighbours: int, chunk: int):
    """``(s0, s1, j)`` per chunk of ``chunk`` soundings: ``j[i]`` the indices of the ``neighbours`` nearest
    soundings (horizontal distance, scipy cKDTree) of sounding ``s0 + i``, itself excluded."""
    from scipy.spatial import cKDTree

    xy = np.column_stack([x, y])
    tree = cKDTree(xy)
    for s0 in range(0, len(xy), chunk):
        s1 = min(len(xy), s0 + chunk)
        _, j = tree.query(xy[s0:s1], k=neighbours + 1, workers=2)
        yield s0, s1, j[:, 1:]  # column 0 is the sounding itself


def knn_spike_mask(x, y, z, *, k: float = 4.0, neighbours: int = 16, floor: float = 0.5,
                   chunk: int = 100_000) -> np.ndarray:
    """True where a sounding deviates from the local surface of its ``neighbours`` nearest soundings.

    For each sounding a plane is fitted to its neighbours (horizontal distance), robustly:
    least squares, then again without the neighbours whose residual exceeds ``3 * max(1.4826 MAD,
    floor)`` (spikes among the neighbours). The sounding is a spike if its own residual exceeds
    ``k * max(1.4826 MAD of the kept residuals, floor)``. The plane removes the terrain slope, which on a
    trench wall is tens of metres across the neighbourhood and would otherwise hide 100 m spikes; the
    test does not depend on the sounding density, so it works for sparse surveys where most 20 m cells
    hold 0-1 soundings and a per-cell test cannot judge anything.

    The neighbour search and the per-sounding fit and test run in one compiled loop
    (:func:`hadal.grid._spike_kernels.knn_spike_flags_cells`): an exact search of a uniform cell grid
    (:mod:`hadal.grid.knn_cells`), ties between equally distant neighbours broken by the lower index, a
    sounding never its own neighbour. It flags exactly what the NumPy reference
    :func:`knn_spike_mask_reference` (scipy cKDTree neighbours) flags where no two neighbour distances tie
    (tests/unit/grid/test_grid_multibeam.py, also on real EX1604 soundings), at 0.55x its CPU time on the sample dive's
    3.45 M soundings (bench/bench_spike_test.py). Soundings the grid does not suit (no extent, a dense blob) use the
    cKDTree neighbours (``chunk`` soundings at a time). The inputs must be finite (the gridder drops
    non-finite soundings first).
    """
    from hadal.grid._spike_kernels import knn_spike_flags, knn_spike_flags_cells
    from hadal.grid.knn_cells import lateral_cell_order

    x = np.ascontiguousarray(x, dtype=np.float64)
    y = np.ascontiguousarray(y, dtype=np.float64)
    z = np.ascontiguousarray(z, dtype=np.float64)
    out = np.zeros(len(z), dtype=bool)
    if len(z) <= neighbours:
        return out
    co = lateral_cell_order(x, y, neighbours)
    if co is not None:
        flags = np.empty(len(z), dtype=bool)
        knn_spike_flags_cells(x[co.order], y[co.order], z[co.order], co.order, co.starts, co.ncu, co.ncv, co.u0,
                              co.v0, co.cs, int(neighbours), float(k), float(floor), MAD_TO_SIGMA, flags, 1024)
        out[co.order] = flags
        return out
    for s0, _, j in _neighbour_chunks(x, y, neighbours, chunk):
        knn_spike_flags(x, y, z, s0, np.ascontiguousarray(j, dtype=np.int64), float(k), float(floor),
                        MAD_TO_SIGMA, out)
    return out


def knn_spike_mask_reference(x, y, z, *, k: float = 4.0, neighbours: int = 16, floor: float = 0.5,
                             chunk: int = 100_000, neighbour_index: np.ndarray | None = None) -> np.ndarray:
    """The NumPy reference of :func:`knn_spike_mask` (the method is described there), the oracle of its
    compiled kernel in the tests: ``(chunk, neighbours)`` arrays instead of one sounding at a time. The neighbours
    are scipy cKDTree's (:func:`_neighbour_chunks`) unless ``neighbour_index`` gives them, ``(n, neighbours)``
    indices nearest first (e.g. a brute-force search with its own tie rule)."""
    n = len(z)
    out = np.zeros(n, dtype=bool)
    if n <= neighbours:
        return out
    chunks = (_neighbour_chunks(x, y, neighbours, chunk) if neighbour_index is None else
              ((s0, min(n, s0 + chunk), neighbour_index[s0:s0 + chunk]) for s0 in range(0, n, chunk)))
    for s0, s1, j in chunks:
        dx, dy, nb = x[j] - x[s0:s1, None], y[j] - y[s0:s1, None], z[j]
        w = np.ones_like(nb)
        for _ in range(2):
            c = _plane_fit(dx, dy, nb, w)
            res = nb - (c[:, :1] + c[:, 1:2] * dx + c[:, 2:3] * dy)
            mad = MAD_TO_SIGMA * np.median(np.abs(res), axis=1)
            w = (np.abs(res) <= 3.0 * np.maximum(mad, floor)[:, None]).astype(np.float64)
        kept = np.where(w > 0, np.abs(res), np.nan)
        with np.errstate(all="ignore"):
            import warnings

            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                scale = MAD_TO_SIGMA * np.nanmedian(kept, axis=1)
        scale = np.maximum(np.nan_to_num(scale, nan=floor), floor)
        out[s0:s1] = np.abs(z[s0:s1] - c[:, 0]) > k * scale
    return out


def spike_mask(
    idx: np.ndarray,
    x: np.ndarray,
    y: np.ndarray,
    depth_m: np.ndarray,
    *,
    k: float = 3.5,
    k_neighbourhood: float = 4.0,
    neighbours: int = 16,
    min_count: int = 5,
    floor_m: float = 0.5,
) -> tuple[np.ndarray, float]:
    """Spike flags from the per-cell and the nearest-neighbour robust tests (module doc), and the noise floor.

    The per-cell scale is floored at the *typical cell sigma* ``sigma_0`` (the median over
    well-sampled cells of 1.4826 MAD, :func:`hadal.grid.points.typical_cell_sigma`, at least
    ``floor_m``): a cell whose few soundings happen to agree closely would otherwise reject ordinary
    noise. The floor is data-driven rather than the a-priori depth-proportional sigma because real
    and simulated sonars are often better than their a-priori model, which would let spikes of a few
    a-priori sigmas through. The neighbour test (:func:`knn_spike_mask`) uses the same floor.
    """
    stats = cell_robust_stats(idx, depth_m)  # the cell medians and MADs both tests below need
    sigma0 = typical_cell_sigma(idx, depth_m, min_count, stats=stats)
    sigma0 = max(sigma0, floor_m) if np.isfinite(sigma0) else floor_m
    bad = robust_outlier_mask(idx, depth_m, k, floor=sigma0, min_count=min_count, stats=stats)
    bad |= knn_spike_mask(x, y, depth_m, k=k_neighbourhood, neighbours=neighbours, floor=sigma0)
    return bad, sigma0


def sor_mask(x, y, z, nb_neighbors: int = 16, std_ratio: float = 3.0) -> np.ndarray:
    """True for points open3d's statistical outlier removal rejects (mean distance to the
    ``nb_neighbors`` nearest neighbours above ``mean + std_ratio * std`` over the cloud): the laser stage's
    :func:`hadal.grid.laser.sor_outlier_mask`, which flags exactly what open3d flags (real EX1604 soundings
    included, tests/unit/grid/test_laser_sor.py); none of at most ``nb_neighbors`` soundings."""
    from hadal.grid.laser import sor_outlier_mask

    n = len(x)
    if n <= nb_neighbors:
        return np.zeros(n, dtype=bool)
    return sor_outlier_mask(np.column_stack([x, y, z]), nb_neighbors, std_ratio)


def fill_small_holes(values: np.ndarray, max_cells: int, *, max_iter: int = 500, tol: float = 1e-6
                     ) -> tuple[np.ndarray, np.ndarray]:
    """Fill interior holes of at most ``max_cells`` empty (NaN) cells by harmonic interpolation.

    A hole is a 4-connected component of NaN cells that does not touch the grid border (a region
    open to the border is outside the survey, not a hole). Its cells are solved for the discrete
    Laplace equation with the surrounding measured cells as boundary values (Jacobi iterations,
    started from the mean of the hole's rim), i.e. a smooth membrane interpolated from the
    neighbours. Returns ``(filled_values, filled_mask)``; larger holes stay NaN.
    """
    v = np.array(values, dtype=np.float64, copy=True)
    empty = ~np.isfinite(v)
    if max_cells <= 0 or not empty.any() or empty.all():
        return v, np.zeros(v.shape, dtype=bool)
    lab, nlab = ndimage.label(empty)  # 4-connectivity
    if nlab == 0:
        return v, np.zeros(v.shape, dtype=bool)
    sizes = np.bincount(lab.ravel(), minlength=nlab + 1)
    border = np.unique(np.concatenate([lab[0], lab[-1], lab[:, 0], lab[:, -1]]))
    ok = sizes <= max_cells
    ok[0] = False
    ok[border] = False
    hole = ok[lab]
    if not hole.any():
        return v, hole
    # initial guess: mean of each hole's rim
    rim_lab = ndimage.grey_dilation(np.where(hole, lab, 0), size=(3, 3)) * (~empty)
    with np.errstate(invalid="ignore", divide="ignore"):
        rim_mean = ndimage.mean(np.nan_to_num(v), labels=rim_lab, index=np.arange(nlab + 1))
    v[hole] = np.asarray(rim_mean)[lab[hole]]
    ys, xs = np.nonzero(hole)
    # interior holes: all four neighbours exist (holes never touch the border)
    for _ in range(max_iter):
        new = 0.25 * (v[ys - 1, xs] + v[ys + 1, xs] + v[ys, xs - 1] + v[ys, xs + 1])
        change = np.max(np.abs(new - v[ys, xs]))
        v[ys, xs] = new
        if change <= tol * max(1.0, float(np.max(np.abs(new)))):
            break
    return v, hole


def grid_multibeam(
    x,
    y,
    depth_m,
    resolution: float = 20.0,
    *,
    bounds: Sequence[float] | None = None,
    spike_k: float = 3.5,
    spike_k_neighbourhood: float = 4.0,
    spike_neighbours: int = 16,
    spike_min_count: int = 5,
    spike_floor_m: float = 0.5,
    remove_spikes: bool = True,
    sor: bool = False,
    sor_neighbors: int = 16,
    sor_std_ratio: float = 3.0,
    fill_max_cells: int = 4,
    apriori_a_m: float = 0.5,
    apriori_b: float = 0.001,
    prior_weight: float = 3.0,
    max_cells: int = DEFAULT_MAX_CELLS,
    progress=None,
) -> xr.Dataset:
    """Grid soundings ``(x, y, depth_m)`` (metres, depth positive down) into a DTM.

    ``progress`` (optional, ``.track``): a start and an end line for the spike test and the gridding
    (:func:`hadal.steps.step`).

    Returns a Dataset on cell centres with ``depth_m`` (mean of the kept soundings),
    ``depth_median_m``, ``count``, ``depth_std_m``, ``uncertainty_m`` and ``filled`` (1 where
    :func:`fill_small_holes` interpolated the depth); attrs count the soundings used, dropped as
    non-finite and rejected as spikes. See the module docstring for the method.
    """
    x = np.asarray(x, dtype=np.float64).ravel()
    y = np.asarray(y, dtype=np.float64).ravel()
    z = np.asarray(depth_m, dtype=np.float64).ravel()
    if not (len(x) == len(y) == len(z)):
        raise InputError(f"x, y and depth must have the same length (got {len(x)}, {len(y)}, {len(z)})")
    if len(z) == 0:
        raise InputError("no soundings to grid (empty input)")
    if bounds is None:
        ext, _ = point_extent(x, y, z)
        spec = make_grid_spec(resolution, ext, max_cells=max_cells, snap=True)
    else:
        spec = make_grid_spec(resolution, bounds, max_cells=max_cells)
    from hadal.steps import step

    x, y, z, idx, n_bad, n_out = _soundings_in_grid(spec, x, y, z, bounds)
    n_in = len(z)
    spikes = np.zeros(n_in, dtype=bool)
    sigma0 = float("nan")
    if remove_spikes:
        with step(progress, f"dtm: spike test of {n_in:,} soundings (per cell and {spike_neighbours} nearest)"):
            sp, sigma0 = spike_mask(idx, x, y, z, k=spike_k, k_neighbourhood=spike_k_neighbourhood,
                                    neighbours=spike_neighbours, min_count=spike_min_count, floor_m=spike_floor_m)
        spikes |= sp
    n_sor = 0
    if sor:
        with step(progress, f"dtm: statistical outlier removal of {n_in:,} soundings"):
            s = sor_mask(x, y, z, sor_neighbors, sor_std_ratio)
        n_sor = int((s & ~spikes).sum())
        spikes |= s
    keep = ~spikes
    with step(progress, f"dtm: gridding {int(keep.sum()):,} soundings into {spec.nx} x {spec.ny} cells"):
        flat, filled = _dtm_layers(spec, idx[keep], z[keep], fill_max_cells, apriori_a_m, apriori_b, prior_weight)
    names = {"mean": "depth_m", "median": "depth_median_m", "std": "depth_std_m", "uncertainty": "uncertainty_m"}
    attrs = {
        "n_soundings_input": int(n_in + n_bad + n_out),
        "n_soundings_nonfinite": n_bad,
        "n_soundings_outside": n_out,
        "n_soundings_spikes": int(spikes.sum()),
        "n_soundings_sor": n_sor,
        "n_soundings_used": int(keep.sum()),
        "n_cells_filled": int(filled.sum()),
        "spike_noise_floor_m": sigma0,
        **_method_attrs(spike_k=spike_k, spike_k_neighbourhood=spike_k_neighbourhood,
                        spike_neighbours=spike_neighbours, spike_min_count=spike_min_count,
                        spike_floor_m=spike_floor_m, remove_spikes=remove_spikes, sor=sor,
                        sor_neighbors=sor_neighbors, sor_std_ratio=sor_std_ratio, fill_max_cells=fill_max_cells,
                        apriori_a_m=apriori_a_m, apriori_b=apriori_b, prior_weight=prior_weight),
    }
    ds = to_dataset(spec, flat, names=names, attrs=attrs)
    _dtm_attrs(ds)
    return ds


def _soundings_in_grid(spec, x: np.ndarray, y: np.ndarray, z: np.ndarray, bounds: Sequence[float] | None):
    """Drop non-finite soundings (and, with explicit ``bounds``, those outside the grid).

    Returns ``(x, y, z, idx, n_bad, n_out)``: the kept soundings, their flat cell index, the number
    dropped as non-finite and the number outside the bounds.
    """
    # keep x/y aligned with z when dropping non-finite points
    ok = np.isfinite(x) & np.isfinite(y) & np.isfinite(z)
    n_bad = int(len(x) - ok.sum())
    if bounds is None:
        x, y, z = x[ok], y[ok], z[ok]
        idx, _ = spec.cell_index(x, y, check_inside=False, finite=True)
        return x, y, z, idx, n_bad, 0
    if not ok.any():
        raise InputError(f"all {len(x)} soundings have NaN/inf coordinates; nothing to grid")
    x, y, z = x[ok], y[ok], z[ok]
    idx, inside = spec.cell_index(x, y, check_inside=True, finite=True)
    n_out = int(len(x) - inside.sum())
    x, y, z, idx = x[inside], y[inside], z[inside], idx[inside]
    if len(z) == 0:
        raise InputError(f"none of the soundings fall inside the grid bounds {tuple(bounds)}")
    return x, y, z, idx, n_bad, n_out


#: the per-cell DTM layers of :func:`dtm_cell_layers`
DTM_CELL_LAYERS = ("mean", "median", "count", "std", "uncertainty")


def dtm_cell_layers(idx: np.ndarray, z: np.ndarray, n_cells: int, *, apriori_a_m: float = 0.5, apriori_b: float = 0.001,
                    prior_weight: float = 3.0, compiled: bool | None = None) -> dict[str, np.ndarray]:
    """Per-cell mean/median/count/std (:func:`hadal.grid.points.reduce_cells`) and uncertainty
    (:func:`cell_uncertainty`) of the soundings ``z`` in cells ``idx`` of ``n_cells``: the whole grid in memory
    (:func:`grid_multibeam`) or one tile of it (:func:`hadal.grid.tiles.dtm_layers_tiled`; ``compiled``: the
    kernel choice of all the soundings, so both give the same bits)."""
    flat = reduce_cells(idx, z, n_cells, ("mean", "median", "count", "std"), compiled=compiled)
    flat["uncertainty"] = cell_uncertainty(flat["count"], flat["std"], flat["median"], a_m=apriori_a_m, b=apriori_b,
                                           prior_weight=prior_weight)
    return flat


def fill_dtm_holes(spec, flat: dict, fill_max_cells: int, apriori_a_m: float, apriori_b: float
                   ) -> tuple[dict, np.ndarray]:
    """The DTM layers from the assembled per-cell layers of :func:`dtm_cell_layers`: small holes of the mean and
    the median filled (:func:`fill_small_holes`), their uncertainty the a-priori sigma of the filled depth, and the
    ``filled`` flag. Returns the flat layers for :func:`to_dataset` and the 2-D mask of filled cells."""
    shape = (spec.ny, spec.nx)
    mean_f, filled = fill_small_holes(flat["mean"].reshape(shape), fill_max_cells)
    med_f, _ = fill_small_holes(flat["median"].reshape(shape), fill_max_cells)
    unc = flat["uncertainty"].reshape(shape)
    unc[filled] = apriori_sigma_m(mean_f[filled], apriori_a_m, apriori_b)
    layers = {
        "mean": mean_f.ravel(), "median": med_f.ravel(), "count": flat["count"].astype(np.int32),
        "std": flat["std"], "uncertainty": unc.ravel(), "filled": filled.ravel().astype(np.int8),
    }
    return layers, filled


def _dtm_layers(spec, idx: np.ndarray, z: np.ndarray, fill_max_cells: int, apriori_a_m: float, apriori_b: float,
                prior_weight: float) -> tuple[dict, np.ndarray]:
    """Per-cell mean/median/count/std/uncertainty of the kept soundings, small holes filled: the grid as one
    tile (:func:`dtm_cell_layers`, then :func:`fill_dtm_holes`; :mod:`hadal.grid.tiles` runs the same two
    functions tile by tile). Returns the flat layers for :func:`to_dataset` and the 2-D mask of filled cells.
    """
    flat = dtm_cell_layers(idx, z, spec.n_cells, apriori_a_m=apriori_a_m, apriori_b=apriori_b,
                           prior_weight=prior_weight)
    return fill_dtm_holes(spec, flat, fill_max_cells, apriori_a_m, apriori_b)


def _method_attrs(*, spike_k, spike_k_neighbourhood, spike_neighbours, spike_min_count, spike_floor_m,
                  remove_spikes, sor, sor_neighbors, sor_std_ratio, fill_max_cells, apriori_a_m, apriori_b,
                  prior_weight) -> dict:
    """The DTM's ``spike_filter``, ``uncertainty_model`` and ``gap_filling`` attrs (method descriptions)."""
    return {
        "spike_filter": (f"per-cell median +- {spike_k} x max(1.4826 MAD, sigma_0) (cells with >= "
                         f"{spike_min_count} soundings); median of the {spike_neighbours} nearest soundings +- "
                         f"{spike_k_neighbourhood} x max(their 1.4826 MAD, sigma_0); sigma_0 = median cell 1.4826 MAD "
                         f"(>= {spike_floor_m} m)" if remove_spikes else "none")
                        + (f"; open3d statistical outlier removal (nb={sor_neighbors}, std_ratio={sor_std_ratio})"
                           if sor else ""),
        "uncertainty_model": (f"sigma_a = sqrt({apriori_a_m}^2 + ({apriori_b} * depth)^2); sigma^2 = ((n-1) s^2 + "
                              f"{prior_weight} sigma_a^2) / (n - 1 + {prior_weight}); u = sigma / sqrt(n); "
                              "filled cells: u = sigma_a"),
        "gap_filling": f"harmonic interpolation of interior holes of <= {fill_max_cells} cells",
    }


def _dtm_attrs(ds: xr.Dataset) -> None:
    depth = {"units": "m", "positive": "down"}
    ds["depth_m"].attrs = {"standard_name": "sea_floor_depth_below_sea_surface",
                           "long_name": "mean depth of the soundings in the cell (filled cells interpolated)",
                           "cell_methods": "area: mean", **depth}
    ds["depth_median_m"].attrs = {"long_name": "median depth of the soundings in the cell",
                                  "cell_methods": "area: median", **depth}
    ds["depth_std_m"].attrs = {"long_name": "sample standard deviation (ddof=1) of the soundings in the cell",
                               "units": "m"}
    ds["uncertainty_m"].attrs = {"long_name": "standard uncertainty of the cell depth", "units": "m",
                                 "comment": ds.attrs["uncertainty_model"]}
    ds["count"].attrs = {"long_name": "number of soundings in the cell (after spike removal)", "units": "1"}
    ds["filled"].attrs = {"long_name": "depth interpolated into a small hole", "flag_values": np.array([0, 1], np.int8),
                          "flag_meanings": "measured interpolated"}


def add_geo(ds: xr.Dataset, frame: LocalFrame, *, latlon: bool = True) -> xr.Dataset:
    """Add ``lat(y, x)``, ``lon(y, x)`` (pyproj, exact) and a CF ``crs`` grid-mapping variable for ``frame``.

    Also sets CF axis attributes on x/y, ``grid_mapping`` on every (y, x) variable and ACDD
    ``geospatial_*`` bounds plus the ``map_frame_origin_*`` attributes of the contract. With
    ``latlon=False`` (10 mm laser grids: 2-D lat/lon would double the file for no information) only
    the grid's outline is transformed for the bounds.
    """
    ds = ds.copy()
    if latlon:
        xx, yy = np.meshgrid(ds["x"].values, ds["y"].values)
    else:
        xs, ys = ds["x"].values, ds["y"].values
        xx = np.concatenate([xs, xs, np.full(len(ys), xs[0]), np.full(len(ys), xs[-1])])
        yy = np.concatenate([np.full(len(xs), ys[0]), np.full(len(xs), ys[-1]), ys, ys])
    lon, lat = frame.to_lonlat(xx, yy)
    ds["x"].attrs.update({"standard_name": "projection_x_coordinate", "long_name": "x (east) in the map frame",
                          "units": "m", "axis": "X"})
    ds["y"].attrs.update({"standard_name": "projection_y_coordinate", "long_name": "y (north) in the map frame",
                          "units": "m", "axis": "Y"})
    grid_vars = [v for v in ds.data_vars if ds[v].dims == ("y", "x")]
    if latlon:
        ds = ds.assign_coords(
            lat=(("y", "x"), lat, {"standard_name": "latitude", "long_name": "latitude", "units": "degrees_north"}),
            lon=(("y", "x"), lon, {"standard_name": "longitude", "long_name": "longitude", "units": "degrees_east"}),
        )
    crs = frame.crs
    ds["crs"] = xr.DataArray(np.int32(0), attrs={
        "grid_mapping_name": "transverse_mercator",
        "latitude_of_projection_origin": frame.origin_latitude_deg,
        "longitude_of_central_meridian": frame.origin_longitude_deg,
        "scale_factor_at_central_meridian": 1.0,
        "false_easting": 0.0,
        "false_northing": 0.0,
        "semi_major_axis": 6378137.0,
        "inverse_flattening": 298.257223563,
        "crs_wkt": crs.to_wkt(),
        "spatial_ref": crs.to_wkt(),
        "proj4": (f"+proj=tmerc +lat_0={frame.origin_latitude_deg!r} +lon_0={frame.origin_longitude_deg!r} "
                  "+k=1 +x_0=0 +y_0=0 +datum=WGS84 +units=m +no_defs"),
    })
    for v in grid_vars:
        ds[v].attrs["grid_mapping"] = "crs"
    res = float(ds.attrs.get("resolution", np.nan))
    ds.attrs.update({
        "map_frame_origin_latitude_deg": frame.origin_latitude_deg,
        "map_frame_origin_longitude_deg": frame.origin_longitude_deg,
        "resolution_m": res,
        "geospatial_lat_min": float(np.min(lat)), "geospatial_lat_max": float(np.max(lat)),
        "geospatial_lon_min": float(np.min(lon)), "geospatial_lon_max": float(np.max(lon)),
        "geospatial_lat_units": "degrees_north", "geospatial_lon_units": "degrees_east",
        "geospatial_bounds_crs": "EPSG:4326",
    })
    return ds


def rmse_against(dtm: xr.Dataset, truth: xr.DataArray, *, bias_m: float = 0.0, measured_only: bool = True) -> dict:
    """Compare a DTM's ``depth_m`` with a true depth grid (interpolated linearly to the DTM cell centres).

    Returns ``{"rmse_m", "mean_error_m", "rmse_debiased_m", "n_cells"}``; ``bias_m`` is subtracted
    from the error before ``rmse_debiased_m``. Used for the sample-dive round trip (tests, accuracy
    reports); the pipeline never reads truth.
    """
    t = truth.interp(x=dtm["x"], y=dtm["y"], method="linear")
    err = dtm["depth_m"] - t
    if measured_only:
        err = err.where(dtm["count"] > 0)
    e = err.values[np.isfinite(err.values)]
    if e.size == 0:
        raise InputError("DTM and truth grid do not overlap")
    return {
        "rmse_m": float(np.sqrt(np.mean(e**2))),
        "mean_error_m": float(np.mean(e)),
        "rmse_debiased_m": float(np.sqrt(np.mean((e - bias_m) ** 2))),
        "n_cells": int(e.size),
    }
