"""MRF fine terrain matching of a gridded real-time terrain patch against the prior DTM.

Method: mrf-terrain-matching.txt §2-3 (Markov-random-field underwater terrain positioning, UTPM).
The real-time terrain ``I_R`` (multibeam soundings gridded at the DTM's spacing) and the prior DTM
``I_D`` are related by a constant position deviation ``(dx, dy)`` (Assumptions 1 and 3):

* [MRF Eqs. 1/5] ``I_D(x, y) = I_R(x + dx, y + dy) + e(x, y)``, ``e`` Gaussian white noise (Assumption 4).
* [MRF Eqs. 2-4] MAP estimate with the Gibbs prior of the real-time terrain
  ``P(I_R) = Z^-1 exp(-U(I_R) / T)``, ``U(I_R) = sum_W sum_{|m|+|n|=1} [I_R(x, y) - I_R(x+m, y+n)]^2``.
* [MRF Eqs. 6-7] first-order Taylor expansion: ``e_x(x, y) = I_D - I_R - dx dI_R/dx`` (with ``dy = 0``).
* [MRF Eqs. 8-13] ``dx_hat = argmin_dx sum_W e_x^2 / (2 s_n^2) (+ F(dx) / T)``, likewise ``dy``;
  [MRF Eq. 14] the matched position.

What this module does (``mrf_refine``, defaults) and where it deviates from the paper, with the reason:

1. **Coarse stage: the exact data term, no linearisation.** The paper's Taylor step ([MRF Eq. 6]) only holds
   within about a cell; yet it reports positioning results from initial errors (IPE) of 20 and 25 grid
   cells (§4.3 Simulation 1: 40 x 30 patch, 1 m grid, IPE 20 m and 25 m; "when the IPE reached 30 m the
   positioning results were divergent"). We therefore first evaluate the data term of [MRF Eq. 5] exactly,
   ``E(d) = mean_W [I_D(x) - I_R(x + d)]^2`` with the depth offset removed (§3.3 reason 4: both windows
   centred over their overlap ``W``), at every integer shift ``d`` within ``max_total_shift_cells``
   (default 25: the largest IPE the paper reports results for). Shifts whose overlap holds fewer than
   ``min_overlap`` of the patch's cells are not candidates. The mean (not the sum) over ``W`` keeps shifts
   with different overlaps comparable.
2. **Fine stage: the paper's [MRF Eqs. 7-13].** From the best integer shift, the linearised per-axis
   estimate (candidate grid ``+-max_shift_cells``, step ``step_cells``) is iterated, the prior DTM being
   resampled (bilinear) at the corrected position each time (Gauss-Newton / Lucas-Kanade); the first
   iteration is the paper's one-shot estimate. The fine stage may move at most ``max_fine_cells`` from the
   coarse shift, and the total at most ``max_total_shift_cells + max_fine_cells``; otherwise the result is
   flagged (``converged = False``) and the input position returned.
3. **The Gibbs prior, made to matter.** Taken literally (the previous implementation, ``prior="window"``),
   ``U(I_R(. + d))`` of the *measured* patch depends on ``d`` only through which cells enter ``W`` and the
   interpolation at fractional shifts; with ``T = U(I_R)`` it changed no fix by more than 0.08 cell
   (issue 16). In [MRF Eq. 2] ``I_R`` is the unknown real-time terrain and the soundings ``M`` its noisy
   measurement (Assumption 4), so the MAP of [MRF Eqs. 2-4] over the terrain given the soundings is
   ``I_R = argmin sum (I_R - M)^2 / (2 s^2) + U(I_R) / T`` (``s``: the soundings' noise), i.e. the linear
   system ``(1 + 4 s^2 / T · L) I_R = M`` (``L`` the 4-neighbourhood graph Laplacian over the valid cells;
   :class:`GibbsFilter`). ``prior="gibbs"`` (default) matches this restored terrain: the coarse search is
   repeated and the fine stage ([MRF Eqs. 7-13]) run with the DTM window passed through the *same* operator
   (deviation: otherwise the two sides of [MRF Eq. 5] have different smoothness and the Taylor step over-shoots
   by ``sum dI . K dI / sum (K dI)^2``, measured as non-convergence). Where it matters (bench/mrf_convergence.py,
   paired trials on real GMT windows): when both the soundings and the DTM are noisy on low-texture terrain
   -- [MRF Eq. 7]'s gradient of the *measured* terrain is then mostly noise -- the restored terrain lowers the
   RMS error from 0.40 to 0.31 cell (soundings 10 %, DTM 20 % of the patch range) and from 0.67 to 0.47
   cell, fixes > 1 cell off from 15 % to 5 % (both 20 %); fixes move by 0.2-0.3 cell on average. On
   textured terrain it is negligible (0.013 vs 0.015 cell). Against an exact DTM with noisy soundings
   the unfiltered least squares is already the maximum-likelihood estimate: the prior costs a little at
   10 % sounding noise (0.19 vs 0.14 cell RMS) and helps slightly at 20 % (0.39 vs 0.44); real prior DTMs
   are not exact, hence the default. **Temperature.** ``P(I_R)`` is then a
   Gaussian MRF in which each neighbour difference has variance ``T/4`` (every pair appears twice in
   [MRF Eq. 4]), so ``T`` is set from the data as the Gibbs distribution requires:
   ``T = 4 max(var(dM) - 2 s^2, 0.1 var(dM))``, ``dM`` the measured neighbour differences (white noise
   adds ``2 s^2``), ``s`` the soundings' own white-noise level (:func:`sounding_noise_m`, Immerkær's
   estimator, at most ``s_n``; ``sigma_n_m`` when given) -- not ``s_n``, which holds the map error too and
   over-smooths a clean patch against a noisy DTM (measured: 1.3 vs 0.4 cell RMS). The prior thus weighs
   ``s^2 / var(dI_R)``: strong where the data are ambiguous (low texture, noise), negligible on rough
   terrain. ``temperature`` overrides ``T``; ``prior="none"`` uses the soundings as measured; ``gibbs_coarse=False`` keeps the coarse search on the raw soundings.
4. **Noise.** The paper writes ``2 s_n`` in [MRF Eq. 8]; a Gaussian needs ``2 s_n^2`` (used here). ``s_n``
   (``sigma_n_m``) defaults to the RMS of the centred residual at the coarse fix (the paper's ``e`` of
   [MRF Eq. 1] lumps sounding and map error).
5. **Texture check (refusal).** The Cramér-Rao bound of the linearised data term ([MRF Eq. 7]) gives the
   shift's 1 sigma per axis, ``s_n / sqrt(sum_W (dI_R/dx)^2)`` (cells); above ``max_sigma_cells`` (default
   0.5) the patch has too little texture for the fix and the result is flagged (``converged = False``,
   input position returned), as is a coarse minimum beyond ``max_total_shift_cells`` + 0.5 (the search disc
   has a one-cell guard ring; such a minimum says the initial error may exceed the range). A second
   coarse minimum more than ``ambiguity_radius_cells`` from the best whose energy is within
   ``min_energy_gap`` (default 3) of it is flagged as ambiguous; the energy is the Gaussian log-likelihood of
   [MRF Eq. 8] with the best MSD as the variance and the window's *effective* number of independent cells
   (``n (1 - rho_x)(1 - rho_y) / ((1 + rho_x)(1 + rho_y))``, ``rho`` the residual's lag-1 autocorrelation:
   a wrong match leaves correlated terrain in the residual, a right one mostly white noise).
6. **Missing cells.** ``W`` holds the cells where ``I_R``, its gradient along the axis and the shifted
   values are finite; the Gibbs sums use the neighbour pairs that are finite.
8. **Search edge (issue 47).** A coarse minimum within ``SearchEdgeOptions.mrf_edge_cells`` (1) of the search
   radius ``max_total_shift_cells`` says the true deviation may lie beyond it (the paper's method diverges beyond
   its range; on real terrain such minima gave confident fixes 11-14 cells wrong): the coarse search is repeated
   once within ``edge_widen_factor`` x the radius (at most ``mrf_edge_max_radius_cells``); a minimum still at the
   edge of the wider search is refused (``converged = False``, a warning naming the search edge, no fix).
   (Deviation: the paper has no search-range check; its Taylor step has no range at all.)
9. **Sign.** ``d = (dx, dy)`` is *assumed minus true* position of the patch (``I_R`` content is displaced
   by ``+d`` against the map), so the corrected patch origin is ``origin - d`` ([MRF Eq. 14]).

The previous implementation (linearised estimate only, the Gibbs term of the measured window, a 3-cell
cap) is ``mrf_refine(..., coarse=False, prior="window", max_total_shift_cells=3)``; bench/mrf_convergence.py
compares both on real grids. MRF needs a 2-D real-time terrain patch (swath/multibeam soundings); the
``match`` stage does not run it on a single-beam track.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hadal.errors import InputError
from hadal.matching.mapgrid import MapGrid
from hadal.matching.options import SearchEdgeOptions


@dataclass
class MrfResult:
    """Fine position of a patch: ``x0_m/y0_m`` = corrected map position of the patch cell ``[0, 0]``."""

    x0_m: float
    y0_m: float
    dx_m: float  # total deviation (assumed - true), [MRF Eq. 14]
    dy_m: float
    iterations: int
    converged: bool
    sigma_n_m: float
    n_window: tuple[int, int]
    energy: list[float] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    coarse_d_cells: tuple[float, float] = (0.0, 0.0)  # integer shift of the coarse stage (dx, dy)
    sigma_cells: tuple[float, float] = (float("nan"), float("nan"))  # Cramér-Rao 1 sigma of (dx, dy)
    temperature: float = float("nan")  # Gibbs temperature T used (NaN: no prior)
    energy_gap: float = float("nan")  # coarse: second minimum minus best, log-likelihood units
    search_edge: dict = field(default_factory=dict)  # coarse minimum at the search radius: retry and flag (docstring, 8)


def _shift_axis(a: np.ndarray, d: np.ndarray, axis: int) -> np.ndarray:
    """``a`` sampled at ``index + d`` along ``axis`` for each candidate ``d`` (linear interpolation) -> (K, ny, nx).

    NaN where ``index + d`` falls outside the grid or on a missing neighbour.
    """
    n = a.shape[axis]
    pos = np.arange(n)[None, :] + np.asarray(d, float)[:, None]  # (K, n)
    inside = (pos >= -1e-9) & (pos <= n - 1 + 1e-9)
    i0 = np.clip(np.floor(pos + 1e-9).astype(int), 0, n - 2)
    w = np.clip(pos - i0, 0.0, 1.0)
    at = a if axis == 1 else a.T  # work along the last axis
    a0, a1 = at[:, i0], at[:, i0 + 1]  # (m, K, n)
    with np.errstate(invalid="ignore"):
        v = np.where(w == 0, a0, np.where(w == 1, a1, a0 * (1 - w) + a1 * w))
    v = np.where(inside[None], v, np.nan).transpose(1, 0, 2)  # (K, m, n)
    return v if axis == 1 else v.transpose(0, 2, 1)


def _gibbs(ir_s: np.ndarray) -> np.ndarray:
    """[MRF Eqs. 11/13] per cell: sum over the 4-neighbourhood of squared differences of (shifted) ``I_R``.

    ``ir_s`` is (K, ny, nx); returns (K, ny, nx) with NaN where the cell itself is missing. Missing
    neighbours contribute nothing.
    """
    out = np.zeros_like(ir_s)
    for sl_a, sl_b in (((slice(None), slice(None, -1), slice(None)), (slice(None), slice(1, None), slice(None))),
                       ((slice(None), slice(None), slice(None, -1)), (slice(None), slice(None), slice(1, None)))):
        diff2 = (ir_s[sl_a] - ir_s[sl_b]) ** 2
        diff2 = np.where(np.isfinite(diff2), diff2, 0.0)
        out[sl_a] += diff2  # neighbour (m, n) = +1
        out[sl_b] += diff2  # neighbour (m, n) = -1
    return np.where(np.isfinite(ir_s), out, np.nan)


def _axis_estimate(id_w: np.ndarray, ir: np.ndarray, axis: int, cands: np.ndarray, sigma_n: float | None,
                   temperature: float | None, min_cells: int, offset: float = 0.0, window_gibbs: bool = True):
    """One-axis minimisation of [MRF Eq. 10] (axis=1, x) or [MRF Eq. 12] (axis=0, y). Returns (d, energy, sigma, n_W).

    ``offset`` is the deviation already accumulated along the axis (cells): the data term is linearised
    about it (``id_w`` is the DTM resampled there) while the Gibbs term is evaluated at the *total*
    deviation ``offset + d``, so the prior does not push again at every iteration.
    """
    grad = np.gradient(ir, axis=axis)  # NaN where a neighbour is missing (central differences inside)
    W = np.isfinite(id_w) & np.isfinite(ir) & np.isfinite(grad)
    if window_gibbs:
        ir_s = _shift_axis(ir, offset + cands, axis)  # I_R(x + dx), [MRF Eqs. 11/13]
        u = _gibbs(ir_s)
        W &= np.isfinite(ir_s).all(axis=0)
    nw = int(W.sum())
    if nw < min_cells:
        return 0.0, float("nan"), float("nan"), nw
    a = id_w[W] - id_w[W].mean()  # depth offset removed by normalisation (§3.3, reason 4)
    b = ir[W] - ir[W].mean()
    g = grad[W] - grad[W].mean()  # the mean of I_R(x + d) over W moves by d * mean(grad): centre it too
    r0 = a - b
    s_n = sigma_n if sigma_n is not None else max(float(np.sqrt(np.mean(r0 ** 2))), 1e-3)
    e = r0[None, :] - cands[:, None] * g[None, :]  # [MRF Eq. 7]
    E = (e ** 2).sum(axis=1) / (2.0 * s_n ** 2)  # [MRF Eq. 8] exponent
    if not window_gibbs:  # the Gibbs prior acts on the restored patch instead (module docstring)
        k = int(np.argmin(E))
        return float(cands[k]), float(E[k]), s_n, nw
    F = u[:, W].sum(axis=1)  # [MRF Eqs. 11/13]
    if temperature is None:  # T = U(I_R) at zero total shift
        u0 = _gibbs(_shift_axis(ir, np.array([0.0]), axis))[0]
        T = max(float(np.nansum(u0[W])), 1e-12)
    else:
        T = temperature
    total = E + F / T  # [MRF Eqs. 9/10]
    k = int(np.argmin(total))
    return float(cands[k]), float(total[k]), s_n, nw


def _neighbour_pairs(valid: np.ndarray):
    """Flat index pairs (a, b) of 4-neighbour cells that are both valid (each unordered pair once)."""
    idx = np.arange(valid.size).reshape(valid.shape)
    pa, pb = [], []
    for sa, sb in (((slice(None, -1), slice(None)), (slice(1, None), slice(None))),
                   ((slice(None), slice(None, -1)), (slice(None), slice(1, None)))):
        both = valid[sa] & valid[sb]
        pa.append(idx[sa][both])
        pb.append(idx[sb][both])
    return np.concatenate(pa), np.concatenate(pb)


def sounding_noise_m(patch: np.ndarray) -> float:
    """White-noise standard deviation of a gridded patch from its own cells (Immerkær 1996, CVIU 64(2) 300-302).

    ``sqrt(pi/2) / 6 * mean |N * I|`` with ``N = [[1,-2,1],[-2,4,-2],[1,-2,1]]`` over the cells whose 3 x 3
    neighbourhood is valid (terrain curvature leaks in, so it is an upper bound on rough terrain).
    """
    z = np.asarray(patch, float)
    k = np.array([[1.0, -2.0, 1.0], [-2.0, 4.0, -2.0], [1.0, -2.0, 1.0]])
    acc = np.zeros((z.shape[0] - 2, z.shape[1] - 2))
    for i in range(3):
        for j in range(3):
            acc = acc + k[i, j] * z[i : i + acc.shape[0], j : j + acc.shape[1]]
    acc = acc[np.isfinite(acc)]
    return float(np.sqrt(np.pi / 2) / 6.0 * np.mean(np.abs(acc))) if acc.size else float("nan")


def gibbs_temperature(patch: np.ndarray, sigma_n_m: float) -> float:
    """``T`` of the Gaussian MRF of [MRF Eqs. 3-4] from the measured neighbour differences (module docstring, 3)."""
    a, b = _neighbour_pairs(np.isfinite(patch))
    if a.size == 0:
        return float("nan")
    flat = patch.ravel()
    v = float(np.mean((flat[a] - flat[b]) ** 2))
    return 4.0 * max(v - 2.0 * sigma_n_m ** 2, 0.1 * v, 1e-12)


class GibbsFilter:
    """MAP terrain under the Gibbs prior: ``argmin_I sum (I - M)^2/(2 s_n^2) + U(I)/T`` ([MRF Eqs. 2-4] with [MRF Eq. 8]).

    ``filter(M)`` solves ``(1 + 4 s_n^2/T L) I = M`` on the cells where ``M`` is finite (``L``: the
    4-neighbourhood graph Laplacian of those cells); NaN cells stay NaN. The factorisation is cached per
    cell mask, so the DTM window can be passed through the same operator at every iteration.
    """

    def __init__(self, sigma_n_m: float, temperature: float):
        self.lam = 4.0 * sigma_n_m ** 2 / temperature if np.isfinite(temperature) and temperature > 0 else 0.0
        self._cache: dict[bytes, tuple] = {}

    def _factor(self, valid: np.ndarray):
        key = valid.tobytes() + bytes(valid.shape)
        if key not in self._cache:
            from scipy.sparse import coo_matrix, diags, identity
            from scipy.sparse.linalg import splu

            a, b = _neighbour_pairs(valid)
            n = valid.size
            w = np.ones(a.size)
            adj = coo_matrix((np.r_[w, w], (np.r_[a, b], np.r_[b, a])), shape=(n, n)).tocsr()
            lap = (diags(np.asarray(adj.sum(axis=1)).ravel()) - adj).tocsr()
            keep = np.flatnonzero(valid.ravel())
            lap = lap[keep][:, keep]
            self._cache = {key: (keep, splu((identity(keep.size, format="csr") + self.lam * lap).tocsc()))}
        return self._cache[key]

    def __call__(self, z: np.ndarray) -> np.ndarray:
        valid = np.isfinite(z)
        if self.lam == 0 or valid.sum() == 0:
            return np.where(valid, z, np.nan)
        keep, lu = self._factor(valid)
        out = np.full(z.shape, np.nan)
        out.ravel()[keep] = lu.solve(z.ravel()[keep])
        return out


def _n_effective(resid: np.ndarray) -> float:
    """Independent cells in a residual window: ``n prod_axes (1 - rho) / (1 + rho)`` (lag-1 autocorrelation, AR(1))."""
    r = resid - np.nanmean(resid)
    n = float(np.isfinite(r).sum())
    var = np.nanmean(r ** 2)
    if not var > 0:
        return n
    f = 1.0
    for ax in (0, 1):
        a = np.take(r, np.arange(r.shape[ax] - 1), axis=ax)
        b = np.take(r, np.arange(1, r.shape[ax]), axis=ax)
        rho = float(np.clip(np.nanmean(a * b) / var, 0.0, 0.99)) if np.isfinite(a * b).any() else 0.0
        f *= (1.0 - rho) / (1.0 + rho)
    return n * f


def _coarse_search(ext: np.ndarray, ir: np.ndarray, radius: int, min_n: int):
    """Exact centred mean-square data term ([MRF Eq. 5]) at integer shifts ``|d| <= radius``. Returns (msd, n) (2R+1, 2R+1).

    ``ext`` is the DTM sampled on the patch lattice extended by ``radius`` cells on each side; the DTM under
    patch cell ``(i, j)`` at deviation ``(cx, cy)`` is ``ext[i - cy + R, j - cx + R]``. Index ``[cy + R, cx + R]``.
    """
    from numpy.lib.stride_tricks import sliding_window_view

    ny, nx = ir.shape
    R = radius
    vr = np.isfinite(ir)
    irz = np.where(vr, ir, 0.0)
    msd = np.full((2 * R + 1, 2 * R + 1), np.inf)
    nn = np.zeros((2 * R + 1, 2 * R + 1), int)
    for k, cy in enumerate(range(-R, R + 1)):
        rows = ext[R - cy : R - cy + ny]  # (ny, nx + 2R)
        win = sliding_window_view(rows, nx, axis=1)  # (ny, 2R+1, nx); win[:, q] is column offset q = R - cx
        win = np.moveaxis(win, 1, 0)[::-1]  # index by cx + R
        v = np.isfinite(win) & vr[None]
        dz = np.where(v, win - irz[None], 0.0)
        n = v.sum(axis=(1, 2))
        s1 = dz.sum(axis=(1, 2))
        s2 = (dz ** 2).sum(axis=(1, 2))
        with np.errstate(invalid="ignore", divide="ignore"):
            m = (s2 - s1 ** 2 / np.maximum(n, 1)) / np.maximum(n, 1)
        cx = np.arange(-R, R + 1)
        ok = (n >= min_n) & (np.hypot(cx, cy) <= R + 1e-9)
        msd[k] = np.where(ok, m, np.inf)
        nn[k] = n
    return msd, nn


def _validated_patch(patch_depth, min_cells: int, step_cells: float, max_shift_cells: float,
                     max_total_shift_cells: float, prior: str) -> np.ndarray:
    """The real-time terrain patch as a float grid (NaN = empty cell), or an :class:`InputError` for a bad patch
    or bad :func:`mrf_refine` parameters."""
    ir = np.asarray(patch_depth, float)
    if ir.ndim != 2 or min(ir.shape) < 3:
        raise InputError(f"real-time terrain patch must be a 2-D grid of at least 3 x 3 cells, got shape {ir.shape}")
    ir = np.where(np.isfinite(ir), ir, np.nan)
    if np.isfinite(ir).sum() < min_cells:
        raise InputError(f"real-time terrain patch has {int(np.isfinite(ir).sum())} valid cells; need >= {min_cells}")
    if step_cells <= 0 or max_shift_cells <= 0 or max_total_shift_cells <= 0:
        raise InputError("MRF step_cells, max_shift_cells and max_total_shift_cells must be > 0")
    if prior not in ("gibbs", "window", "none"):
        raise InputError(f"MRF prior must be 'gibbs', 'window' or 'none', got {prior!r}")
    return ir


@dataclass
class _Search:
    """Outcome of the coarse stage and the prior of :func:`mrf_refine`: the accumulated deviation ``(cx, cy)``
    (cells, assumed - true), the noise ``s_n``, the ambiguity energy gap, the Gibbs temperature and operator and
    the terrain the fine stage matches (``ir_fine``)."""

    cx: float
    cy: float
    s_n: float
    gap: float
    T: float
    ir_fine: np.ndarray
    filt: GibbsFilter | None


def _coarse_minimum(msd: np.ndarray, R: int):
    """Index of the smallest coarse MSD and its shift ``(cy, cx)`` in cells."""
    k = np.unravel_index(int(np.argmin(msd)), msd.shape)
    return k, float(k[0] - R), float(k[1] - R)


def _search_and_prior(g, ir, patch_x0_m, patch_y0_m, *, sigma_n_m, temperature, prior, coarse, gibbs_coarse,
                      R, min_n, min_cells, ambiguity_radius_cells):
    """Coarse stage (exact centred data term of [MRF Eq. 5] at integer shifts, repeated through the Gibbs operator
    of [MRF Eqs. 2-4] for ``prior="gibbs"``) and the ambiguity energy gap ([MRF Eq. 8] log-likelihood with the best
    MSD as the variance). Returns a :class:`_Search`, or ``None`` when the patch overlaps the map at no shift."""
    h = g.resolution_m
    ny, nx = ir.shape
    cx = cy = 0.0  # accumulated deviation in cells (assumed - true)
    gap = float("nan")
    s_n = sigma_n_m
    ext = None
    if coarse:
        ey, ex = np.mgrid[-R : ny + R, -R : nx + R]
        ext = g.sample_bilinear(patch_x0_m + ex * h, patch_y0_m + ey * h)
        msd, nn = _coarse_search(ext, ir, R, min_n)
        if not np.isfinite(msd).any():
            return None
        k, cy, cx = _coarse_minimum(msd, R)
        if s_n is None:
            s_n = max(float(np.sqrt(msd[k])), 1e-3)
    if s_n is None:  # no coarse stage: residual at the input position
        jj, ii = np.meshgrid(np.arange(nx), np.arange(ny))
        d0 = g.sample_bilinear(patch_x0_m + jj * h, patch_y0_m + ii * h) - ir
        s_n = max(float(np.nanstd(d0)), 1e-3) if np.isfinite(d0).sum() >= min_cells else 1e-3
    T = float("nan")
    ir_fine = ir
    filt = None
    if prior == "gibbs":
        s_m = sounding_noise_m(ir) if sigma_n_m is None else sigma_n_m  # the soundings' own noise, not the map's
        s_m = min(s_m, s_n) if np.isfinite(s_m) else s_n
        T = temperature if temperature is not None else gibbs_temperature(ir, s_m)
        filt = GibbsFilter(s_m, T)
        ir_fine = filt(ir)
        if coarse and gibbs_coarse:  # the exact data term again, on both sides through the Gibbs operator
            msd, nn = _coarse_search(GibbsFilter(s_m, T)(ext), ir_fine, R, min_n)
            k, cy, cx = _coarse_minimum(msd, R)
    if coarse:
        qy, qx = np.mgrid[-R : R + 1, -R : R + 1]
        far = np.hypot(qx - cx, qy - cy) > ambiguity_radius_cells
        if np.isfinite(msd[far]).any():  # log-likelihood units, the best MSD as the residual variance ([MRF Eq. 8])
            r = ext[R - int(cy) : R - int(cy) + ny, R - int(cx) : R - int(cx) + nx] - ir
            gap = float(_n_effective(r) * (np.min(msd[far]) / max(msd[k], 1e-12) - 1.0) / 2.0)
    return _Search(cx, cy, s_n, gap, T, ir_fine, filt)


def _at_search_edge(search: _Search, radius_cells: float, edge_cells: float) -> bool:
    """The coarse minimum within ``edge_cells`` of the search radius (module docstring, 8)."""
    return bool(np.hypot(search.cx, search.cy) >= radius_cells - edge_cells - 1e-9)


def _texture_sigma(ir_fine: np.ndarray, s_n: float, min_cells: int) -> tuple[float, float]:
    """Cramér-Rao 1 sigma (cells) of ``(dx, dy)`` from the linearised data term ([MRF Eq. 7]):
    ``s_n / sqrt(sum_W (dI_R/dx)^2)`` on the terrain the fine stage uses (``inf`` without a gradient)."""
    sig = []
    for ax in (1, 0):
        gr = np.gradient(ir_fine, axis=ax)
        gg = np.nansum((gr - np.nanmean(gr)) ** 2) if np.isfinite(gr).sum() >= min_cells else 0.0
        sig.append(float(s_n / np.sqrt(gg)) if gg > 0 else float("inf"))
    return (sig[0], sig[1])


def _refusal(sig_t, cx, cy, gap, *, max_sigma_cells, max_total_shift_cells, min_energy_gap,
             ambiguity_radius_cells) -> str | None:
    """The warning of a coarse fix that is refused (too little texture, minimum at the edge of the search range,
    ambiguous), or ``None``."""
    if max(sig_t) > max_sigma_cells:
        return (f"MRF: too little terrain texture for a fix (Cramér-Rao 1 sigma {max(sig_t):.2f} cells "
                f"> {max_sigma_cells}); no fix")
    if np.hypot(cx, cy) > max_total_shift_cells + 0.5:
        return (f"MRF: the coarse minimum ({np.hypot(cx, cy):.0f} cells) is at the edge of the search range "
                f"(max_total_shift_cells = {max_total_shift_cells:g}); the initial error may be larger; no fix")
    if np.isfinite(gap) and gap < min_energy_gap:
        return (f"MRF: ambiguous coarse match (a second minimum more than {ambiguity_radius_cells:g} cells away "
                f"is within {gap:.2f} log-likelihood units of the best); no fix")
    return None


@dataclass
class _Fine:
    """Outcome of the fine stage of :func:`mrf_refine`: the total deviation (cells), the energy per iteration,
    whether it converged, the iterations, the window sizes and the per-axis noise of the last iteration."""

    cx: float
    cy: float
    energy: list[float]
    converged: bool
    n_iter: int
    nws: tuple[int, int]
    s_x: float
    s_y: float


def _fine_stage(g, ir, search, patch_x0_m, patch_y0_m, warnings, *, sig_fix, temperature, win, coarse,
                max_shift_cells, step_cells, max_iter, tol_cells, min_cells, max_total_shift_cells, max_fine_cells):
    """The paper's linearised per-axis estimate ([MRF Eqs. 7-13]) iterated from the coarse shift, the prior DTM
    resampled (bilinear) at the corrected position each time; appends its warnings to ``warnings``."""
    h = g.resolution_m
    ny, nx = ir.shape
    jj, ii = np.meshgrid(np.arange(nx), np.arange(ny))
    cx, cy, ir_fine, filt = search.cx, search.cy, search.ir_fine, search.filt
    cands = np.round(np.arange(-max_shift_cells, max_shift_cells + step_cells / 2, step_cells), 10)
    c0x, c0y = cx, cy
    energy = []
    converged, n_iter, nws = False, 0, (0, 0)
    for it in range(1, max_iter + 1):
        n_iter = it
        # prior DTM at the patch cells' current estimated positions: I_D(x') = Z(x' - c)
        id_w = g.sample_bilinear(patch_x0_m + (jj - cx) * h, patch_y0_m + (ii - cy) * h)
        if filt is not None:  # the DTM window through the same Gibbs operator (docstring, 3)
            id_w = filt(np.where(np.isfinite(ir), id_w, np.nan))
        dx, ex, s_x, nwx = _axis_estimate(id_w, ir_fine, 1, cands, sig_fix, temperature, min_cells, cx, win)
        dy, ey, s_y, nwy = _axis_estimate(id_w, ir_fine, 0, cands, sig_fix, temperature, min_cells, cy, win)
        nws = (nwx, nwy)
        if nwx < min_cells and nwy < min_cells:
            warnings.append(f"MRF window has too few usable cells ({nwx} for x, {nwy} for y); no refinement")
            break
        energy.append(float(np.nansum([ex, ey])))
        cx += dx
        cy += dy
        if np.hypot(cx, cy) > max_total_shift_cells + (max_fine_cells if coarse else 0.0):
            warnings.append(f"MRF diverged: accumulated shift {np.hypot(cx, cy):.2f} cells > {max_total_shift_cells}")
            break
        if coarse and np.hypot(cx - c0x, cy - c0y) > max_fine_cells:
            warnings.append(f"MRF diverged: the fine stage moved {np.hypot(cx - c0x, cy - c0y):.2f} cells "
                            f"from the coarse shift (> {max_fine_cells})")
            break
        if max(abs(dx), abs(dy)) <= (tol_cells if tol_cells is not None else step_cells) + 1e-9:
            converged = True
            break
    else:
        warnings.append(f"MRF did not converge in {max_iter} iterations")
    return _Fine(cx, cy, energy, converged, n_iter, nws, s_x, s_y)


def mrf_refine(
    patch_depth,
    patch_x0_m: float,
    patch_y0_m: float,
    dtm,
    *,
    sigma_n_m: float | None = None,
    temperature: float | None = None,
    prior: str = "gibbs",
    coarse: bool = True,
    max_total_shift_cells: float = 25.0,
    min_overlap: float = 0.5,
    max_shift_cells: float = 1.5,
    max_fine_cells: float = 2.0,
    step_cells: float = 0.01,
    max_iter: int = 50,
    tol_cells: float | None = None,
    min_cells: int = 16,
    max_sigma_cells: float = 0.5,
    ambiguity_radius_cells: float = 3.0,
    min_energy_gap: float = 3.0,
    gibbs_coarse: bool = True,
    edge: SearchEdgeOptions | None = None,
) -> MrfResult:
    """Refine the position of a real-time terrain patch on the prior DTM ([MRF Eqs. 1-14]).

    ``patch_depth[i, j]`` (depth positive down, metres; NaN = empty cell) is the real-time terrain on
    a grid with the DTM's spacing ``h`` whose cell ``[i, j]`` is *assumed* to lie at map position
    ``(patch_x0_m + j h, patch_y0_m + i h)`` -- e.g. the dead-reckoned or TERCOM position. Returns the
    corrected origin and the deviation. Stages, prior, temperature and flags: module docstring.
    ``coarse=False, prior="window", max_total_shift_cells=3`` reproduces the previous implementation.
    """
    g = MapGrid.from_any(dtm)
    ir = _validated_patch(patch_depth, min_cells, step_cells, max_shift_cells, max_total_shift_cells, prior)
    h = g.resolution_m
    warnings: list[str] = []

    def flagged(msg, s_n=float("nan"), **kw):
        warnings.append(msg)
        return MrfResult(patch_x0_m, patch_y0_m, 0.0, 0.0, 0, False, s_n, (0, 0), [], warnings, **kw)

    if not np.nanstd(ir) > 0:
        return flagged("MRF: the real-time terrain patch has no relief (no texture); no fix")
    min_n = max(min_cells, int(np.ceil(min_overlap * int(np.isfinite(ir).sum()))))
    edge = edge if edge is not None else SearchEdgeOptions()

    def search_within(radius_cells: float):
        return _search_and_prior(g, ir, patch_x0_m, patch_y0_m, sigma_n_m=sigma_n_m, temperature=temperature,
                                 prior=prior, coarse=coarse, gibbs_coarse=gibbs_coarse,
                                 R=int(np.floor(radius_cells)) + 1, min_n=min_n, min_cells=min_cells,
                                 ambiguity_radius_cells=ambiguity_radius_cells)

    search = search_within(max_total_shift_cells)
    if search is None:
        return flagged("MRF: the patch does not overlap the map enough at any shift; no fix")
    at_edge = coarse and _at_search_edge(search, max_total_shift_cells, edge.mrf_edge_cells)
    edge_record: dict = {"at_edge": False, "retried": False, "radius_cells": float(max_total_shift_cells)}
    if at_edge and edge.edge_retry:  # widen once (module docstring, 8)
        wider = min(edge.edge_widen_factor * max_total_shift_cells, edge.mrf_edge_max_radius_cells)
        if wider > max_total_shift_cells + edge.mrf_edge_cells:
            retry = search_within(wider)
            if retry is not None:
                edge_record.update({"retried": True, "first_radius_cells": float(max_total_shift_cells),
                                    "first_minimum_cells": [search.cx, search.cy], "radius_cells": float(wider)})
                search, max_total_shift_cells = retry, wider
                at_edge = _at_search_edge(search, max_total_shift_cells, edge.mrf_edge_cells)
    edge_record["at_edge"] = bool(at_edge)
    if at_edge:
        return flagged(f"possible mismatch: search edge: the MRF coarse minimum ({np.hypot(search.cx, search.cy):.1f} "
                       f"cells) is within {edge.mrf_edge_cells:g} cell of the {max_total_shift_cells:g}-cell search "
                       "radius; the initial error may be larger: no fix", s_n=search.s_n,
                       coarse_d_cells=(search.cx, search.cy), temperature=search.T, energy_gap=search.gap,
                       search_edge=edge_record)
    s_n = search.s_n
    # texture (Cramér-Rao of [MRF Eq. 7]) on the terrain the fine stage uses
    sig_t = _texture_sigma(search.ir_fine, s_n, min_cells)
    common = {"coarse_d_cells": (search.cx, search.cy), "sigma_cells": sig_t, "temperature": search.T,
              "energy_gap": search.gap, "search_edge": edge_record}
    if coarse:
        refused = _refusal(sig_t, search.cx, search.cy, search.gap, max_sigma_cells=max_sigma_cells,
                           max_total_shift_cells=max_total_shift_cells, min_energy_gap=min_energy_gap,
                           ambiguity_radius_cells=ambiguity_radius_cells)
        if refused is not None:
            return flagged(refused, s_n=s_n, **common)

    fine = _fine_stage(g, ir, search, patch_x0_m, patch_y0_m, warnings, sig_fix=sigma_n_m if not coarse else s_n,
                       temperature=temperature, win=prior == "window", coarse=coarse,
                       max_shift_cells=max_shift_cells, step_cells=step_cells, max_iter=max_iter, tol_cells=tol_cells,
                       min_cells=min_cells, max_total_shift_cells=max_total_shift_cells,
                       max_fine_cells=max_fine_cells)
    cx, cy, nws = fine.cx, fine.cy, fine.nws
    for ax, n in zip("xy", nws, strict=True):
        if n < min_cells:
            warnings.append(f"MRF: no usable gradient along {ax} in the patch; {ax} not refined")
    if not coarse:
        s_n = float(np.nanmean([fine.s_x, fine.s_y]))
    if not fine.converged and any("diverged" in w for w in warnings):
        return MrfResult(patch_x0_m, patch_y0_m, 0.0, 0.0, fine.n_iter, False, s_n, nws, fine.energy, warnings,
                         **common)
    return MrfResult(patch_x0_m - cx * h, patch_y0_m - cy * h, cx * h, cy * h, fine.n_iter, fine.converged, s_n, nws,
                     fine.energy, warnings, **common)
