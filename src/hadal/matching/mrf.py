"""MRF fine terrain matching of a gridded real-time terrain patch against the prior DTM.

Method: mrf-terrain-matching.txt §2-3 (Markov-random-field underwater terrain positioning, UTPM).
The real-time terrain ``I_R`` (multibeam soundings gridded at the DTM's spacing) and the prior DTM
``I_D`` are related by a constant position deviation ``(dx, dy)`` (Assumptions 1 and 3):

* Eq. (1)  ``I_D(x, y) = I_R(x + dx, y + dy) + e(x, y)``, ``e`` Gaussian white noise (Assumption 4).
* Eq. (3)-(4) Gibbs prior of the real-time terrain,
  ``U(I_R) = sum_{(x,y) in W} sum_{|m|+|n|=1} [I_R(x+dx, y+dy) - I_R(x+m+dx, y+n+dy)]^2`` (4-neighbourhood).
* Eq. (6)-(7) first-order Taylor expansion: ``e_x(x, y) = I_D - I_R - dx dI_R/dx`` (with ``dy = 0``).
* Eq. (8)-(10) ``dx_hat = argmin_dx { sum_W e_x^2 / (2 s_n^2) + F(dx) / T }``, with
  Eq. (11) ``F(dx) = sum_W sum_{|m|+|n|=1} [I_R(x+dx, y) - I_R(x+m+dx, y+n)]^2``; likewise
  Eqs. (12)-(13) for ``dy`` with ``Y(dy)``; Eq. (14) the matched position.

Implementation notes and deviations (each needed to make the written method computable):

* **Energy and optimisation.** For each axis the energy ``E(d) + F(d)/T`` is evaluated on a grid of
  candidate shifts ``d`` in ``[-max_shift_cells, +max_shift_cells]`` (step ``step_cells``) and the
  minimum is taken (Eq. 10 / 12); ``I_R(x + d)`` at fractional ``d`` is linear interpolation along
  the axis. The data term uses the paper's linearisation (Eq. 7) at every candidate.
* **Iteration.** The Taylor expansion (Eq. 6) only holds for small shifts, and Eqs. 10/12 solve each
  axis with the other set to zero; we therefore repeat the estimate after resampling the prior DTM
  (bilinear) at the corrected patch position until the update is below ``tol_cells`` (Gauss-Newton /
  Lucas-Kanade style). The Gibbs term is always evaluated at the total deviation (accumulated +
  candidate), so the iteration minimises one fixed energy. The first iteration is exactly the
  paper's one-shot estimate.
* **Depth offset.** §3.3 (reason 4): "it is necessary to eliminate the reference depth deviation while
  normalizing" -- both windows are centred on their mean over ``W`` before the data term, and so is
  the gradient in Eq. 7 (the mean of ``I_R(x + d)`` over ``W`` moves by ``d * mean(dI_R/dx)``; without
  centring it a regional slope would be absorbed as a depth offset and the shift underestimated).
* **Units.** The paper writes ``2 s_n`` in Eq. 8; a Gaussian needs ``2 s_n^2`` (used here). ``s_n``
  defaults to the RMS of the centred residual at the current iteration. The paper sets no value for
  ``T`` (Eq. 9 silently uses ``T = 1`` and adds a dimensionless term to one in m^2); by default
  ``T = U(I_R)`` at zero shift, so the Gibbs term is O(1) against a data term O(|W|): a weak prior.
* **Missing cells.** ``W`` holds the cells where ``I_R``, its gradient along the axis and the shifted
  values are finite; the Gibbs sum uses the neighbour pairs that are finite.
* **Convergence.** Iterations stop when both axis updates are at most ``tol_cells`` (default: one
  candidate step).
* **Sign.** ``d = (dx, dy)`` is *assumed minus true* position of the patch (``I_R`` content is
  displaced by ``+d`` against the map), so the corrected patch origin is ``origin - d`` (Eq. 14).

The paper's finding (§4.3) that the method diverges for initial errors beyond a few cells is why it is
started from the TERCOM coarse fix (Simulation 3); :func:`mrf_refine` reports ``converged = False``
when the accumulated shift leaves ``max_total_shift_cells``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hadal.errors import InputError
from hadal.matching.mapgrid import MapGrid


@dataclass
class MrfResult:
    """Fine position of a patch: ``x0_m/y0_m`` = corrected map position of the patch cell ``[0, 0]``."""

    x0_m: float
    y0_m: float
    dx_m: float  # total deviation (assumed - true), Eq. (14)
    dy_m: float
    iterations: int
    converged: bool
    sigma_n_m: float
    n_window: tuple[int, int]
    energy: list[float] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)


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
    """Eq. (11)/(13) per cell: sum over the 4-neighbourhood of squared differences of (shifted) ``I_R``.

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
                   temperature: float | None, min_cells: int, offset: float = 0.0):
    """One-axis minimisation of Eq. (10) (axis=1, x) or Eq. (12) (axis=0, y). Returns (d, energy, sigma, n_W).

    ``offset`` is the deviation already accumulated along the axis (cells): the data term is linearised
    about it (``id_w`` is the DTM resampled there) while the Gibbs term is evaluated at the *total*
    deviation ``offset + d``, so the prior does not push again at every iteration.
    """
    grad = np.gradient(ir, axis=axis)  # NaN where a neighbour is missing (central differences inside)
    ir_s = _shift_axis(ir, offset + cands, axis)  # I_R(x + dx), Eq. (11)/(13)
    u = _gibbs(ir_s)
    W = np.isfinite(id_w) & np.isfinite(ir) & np.isfinite(grad) & np.isfinite(ir_s).all(axis=0)
    nw = int(W.sum())
    if nw < min_cells:
        return 0.0, float("nan"), float("nan"), nw
    a = id_w[W] - id_w[W].mean()  # depth offset removed by normalisation (§3.3, reason 4)
    b = ir[W] - ir[W].mean()
    g = grad[W] - grad[W].mean()  # the mean of I_R(x + d) over W moves by d * mean(grad): centre it too
    r0 = a - b
    s_n = sigma_n if sigma_n is not None else max(float(np.sqrt(np.mean(r0 ** 2))), 1e-3)
    e = r0[None, :] - cands[:, None] * g[None, :]  # Eq. (7)
    E = (e ** 2).sum(axis=1) / (2.0 * s_n ** 2)  # Eq. (8) exponent
    F = u[:, W].sum(axis=1)  # Eq. (11)/(13)
    if temperature is None:  # T = U(I_R) at zero total shift
        u0 = _gibbs(_shift_axis(ir, np.array([0.0]), axis))[0]
        T = max(float(np.nansum(u0[W])), 1e-12)
    else:
        T = temperature
    total = E + F / T  # Eq. (9)/(10)
    k = int(np.argmin(total))
    return float(cands[k]), float(total[k]), s_n, nw


def mrf_refine(
    patch_depth,
    patch_x0_m: float,
    patch_y0_m: float,
    dtm,
    *,
    sigma_n_m: float | None = None,
    temperature: float | None = None,
    max_shift_cells: float = 1.5,
    step_cells: float = 0.01,
    max_iter: int = 50,
    tol_cells: float | None = None,
    max_total_shift_cells: float = 3.0,
    min_cells: int = 16,
) -> MrfResult:
    """Refine the position of a real-time terrain patch on the prior DTM (MRF paper Eqs. 4-14).

    ``patch_depth[i, j]`` (depth positive down, metres; NaN = empty cell) is the real-time terrain on
    a grid with the DTM's spacing ``h`` whose cell ``[i, j]`` is *assumed* to lie at map position
    ``(patch_x0_m + j h, patch_y0_m + i h)`` -- typically the TERCOM coarse fix. Returns the corrected
    origin and the deviation (module docstring for the energy, the optimisation and the deviations).
    """
    g = MapGrid.from_any(dtm)
    ir = np.asarray(patch_depth, float)
    if ir.ndim != 2 or min(ir.shape) < 3:
        raise InputError(f"real-time terrain patch must be a 2-D grid of at least 3 x 3 cells, got shape {ir.shape}")
    ir = np.where(np.isfinite(ir), ir, np.nan)
    if np.isfinite(ir).sum() < min_cells:
        raise InputError(f"real-time terrain patch has {int(np.isfinite(ir).sum())} valid cells; need >= {min_cells}")
    if step_cells <= 0 or max_shift_cells <= 0:
        raise InputError("MRF step_cells and max_shift_cells must be > 0")
    h = g.resolution_m
    cands = np.round(np.arange(-max_shift_cells, max_shift_cells + step_cells / 2, step_cells), 10)
    ny, nx = ir.shape
    jj, ii = np.meshgrid(np.arange(nx), np.arange(ny))
    cx = cy = 0.0  # accumulated deviation in cells (assumed - true)
    energy, warnings = [], []
    converged, n_iter, s_n, nws = False, 0, float("nan"), (0, 0)
    for it in range(1, max_iter + 1):
        n_iter = it
        # prior DTM at the patch cells' current estimated positions: I_D(x') = Z(x' - c)
        id_w = g.sample_bilinear(patch_x0_m + (jj - cx) * h, patch_y0_m + (ii - cy) * h)
        dx, ex, s_x, nwx = _axis_estimate(id_w, ir, 1, cands, sigma_n_m, temperature, min_cells, cx)
        dy, ey, s_y, nwy = _axis_estimate(id_w, ir, 0, cands, sigma_n_m, temperature, min_cells, cy)
        nws = (nwx, nwy)
        if nwx < min_cells and nwy < min_cells:
            warnings.append(f"MRF window has too few usable cells ({nwx} for x, {nwy} for y); no refinement")
            break
        s_n = float(np.nanmean([s_x, s_y]))
        energy.append(float(np.nansum([ex, ey])))
        cx += dx
        cy += dy
        if np.hypot(cx, cy) > max_total_shift_cells:
            warnings.append(f"MRF diverged: accumulated shift {np.hypot(cx, cy):.2f} cells > {max_total_shift_cells}")
            break
        if max(abs(dx), abs(dy)) <= (tol_cells if tol_cells is not None else step_cells) + 1e-9:
            converged = True
            break
    else:
        warnings.append(f"MRF did not converge in {max_iter} iterations")
    for ax, n in zip("xy", nws, strict=True):
        if 0 < n < min_cells or n == 0:
            warnings.append(f"MRF: no usable gradient along {ax} in the patch; {ax} not refined")
    if not converged and any("diverged" in w for w in warnings):
        return MrfResult(patch_x0_m, patch_y0_m, 0.0, 0.0, n_iter, False, s_n, nws, energy, warnings)
    return MrfResult(patch_x0_m - cx * h, patch_y0_m - cy * h, cx * h, cy * h, n_iter, converged, s_n, nws, energy, warnings)
