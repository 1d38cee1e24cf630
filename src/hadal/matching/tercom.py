"""TERCOM: batch terrain-contour matching of a measured depth profile against a reference map.

TERCOM paper (tercom-challenger-deep.md) §3.3 and §4.2. For every candidate position of the track on
the map (the whole map, at the map resolution, as in §4.2: "the whole region was searched ... the
search interval was equivalent to the map resolution") the measured seafloor depths ``d_M(i)`` are
compared with the map depths ``d_BT(x, y, i)`` under the track:

* [TERCOM Eq. 15] ``COR(x, y) = 1/N sum d_M(i) d_BT(x, y, i)``      (maximised)
* [TERCOM Eq. 16] ``MAD(x, y) = 1/N sum |d_M(i) - d_BT(x, y, i)|``  (minimised)
* [TERCOM Eq. 17] ``MSD(x, y) = 1/N sum [d_M(i) - d_BT(x, y, i)]^2`` (minimised; the paper's choice)

Implementation (FFT route). The track is given relative to its start; its samples are snapped to the
map grid relative to the start (**nearest-cell sampling**: sample ``i`` falls in cell
``start + round(track_i / h)``, an error of at most half a cell). Then, with ``V`` the map validity
mask, ``D`` the map (0 where invalid) and sparse sample masks ``C`` (count of samples per cell),
``S1`` (sum of ``d_M``), ``S2`` (sum of ``d_M^2``) built on the track's footprint, every sum over the
samples at every offset is a 2-D cross-correlation of a map layer with a mask (``*`` = correlation):

    N      = V * C          sum d_M    = V * S1       sum d_M^2 = V * S2
    sum d_BT = D * C        sum d_BT^2 = D^2 * C      sum d_M d_BT = D * S1

so ``MSD = (sum d_BT^2 - 2 sum d_M d_BT + sum d_M^2)/N`` costs a handful of FFTs for all offsets
(``scipy.fft.rfft2``; map-layer transforms are computed once and reused for every heading). Only
samples on valid map cells count (``N`` per offset); offsets where fewer than ``min_valid_fraction``
of the samples lie on valid cells (NaN cells or the track leaving the map) are infeasible (NaN). All
depths are centred on the map mean first, so the float64 FFT sums do not cancel catastrophically.

Options beyond the paper:

* ``estimate_bias``: a constant depth bias ``b`` (map minus measured; §4.2 notes the multibeam map is
  "several metres deeper than the actual depth") estimated at every offset. For MSD the optimum is
  closed form, ``b = mean(d_BT - d_M)`` and ``MSD_b = MSD - b^2``. For MAD the L1 optimum, the
  **median** residual, by a direct gather at every start cell (no correlation form; restrict with
  ``region`` on large maps). For COR (**documented deviation**) the bias-free form is the **Pearson**
  correlation ``cov(d_M, d_BT) / (sd(d_M) sd(d_BT))`` in [-1, 1] (the paper's [TERCOM Eq. 15] is dominated by
  the mean depth and its scale by the relief, so it cannot rank offsets or give a separation ratio);
  ``estimate_bias=False`` gives [TERCOM Eq. 15] as written.
* ``headings_deg``: small heading errors of the dead-reckoned track, tried by rotating the track about
  its start (e.g. ``np.arange(-9, 9.01, 0.5)``: 37 headings); the best (heading, offset) wins.
* MAD has no FFT identity (|.| is not bilinear); it is evaluated by a vectorised direct sum over the
  samples (one array slice per sample), which is O(samples x offsets): restrict it with ``region``.
"""

from __future__ import annotations

import warnings as _warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import scipy.fft as sfft
from scipy import ndimage

from hadal.errors import InputError
from hadal.matching.mapgrid import MapGrid
from hadal.matching.options import DIRECT_FIELDS, REFINE_FIELDS, TERCOM_FIELDS, TercomOptions, tercom_options

CRITERIA = ("msd", "mad", "cor")


@dataclass
class TercomResult:
    """Best match of a track on the map.

    ``start_x_m/start_y_m``: map position of the track's first sample; the matched track is
    ``R(heading) (track - track[0]) + start`` (:meth:`apply`). ``surface`` is the criterion on the map
    grid (``surface[row, col]`` = value with the track start at cell ``(row, col)``) for the best
    heading; ``surface_all_headings`` the best value over all headings at each cell.
    """

    criterion: str
    start_x_m: float
    start_y_m: float
    start_row: int
    start_col: int
    heading_deg: float
    score: float
    bias_m: float
    n_samples: int
    n_valid: int
    surface: np.ndarray
    surface_all_headings: np.ndarray
    bias_surface: np.ndarray | None
    x_m: np.ndarray
    y_m: np.ndarray
    heading_scores: dict[float, float]
    second_score: float
    second_x_m: float
    second_y_m: float
    separation_ratio: float
    mismatch: bool
    sigma_x_m: float
    sigma_y_m: float
    track_start_xy: tuple[float, float]
    warnings: list[str] = field(default_factory=list)
    scale: float = 1.0
    refinement: dict | None = None
    search_edge: dict = field(default_factory=dict)  # heading/scale at a bound of the search (issue 47)

    @property
    def sigma_m(self) -> float:
        """Radial 1-sigma position uncertainty, ``sqrt(sigma_x^2 + sigma_y^2)``."""
        return float(np.hypot(self.sigma_x_m, self.sigma_y_m))

    def apply(self, track_xy) -> np.ndarray:
        """Map positions (x_east_m, y_north_m) of track points given in the same relative frame as the input track."""
        p = np.asarray(track_xy, float).reshape(-1, 2) - np.asarray(self.track_start_xy)
        p = _rotate(p, self.heading_deg) * self.scale
        return p + np.array([self.start_x_m, self.start_y_m])


def _rotate(p: np.ndarray, heading_err_deg: float) -> np.ndarray:
    """Rotate relative east/north offsets clockwise (a heading increase) by ``heading_err_deg``."""
    if heading_err_deg == 0:
        return p
    a = np.deg2rad(heading_err_deg)
    c, s = np.cos(a), np.sin(a)
    # heading is clockwise from north: east' = e cos + n sin, north' = -e sin + n cos
    return np.column_stack([p[:, 0] * c + p[:, 1] * s, -p[:, 0] * s + p[:, 1] * c])


def _validate_inputs(profile_depth, track_xy) -> tuple[np.ndarray, np.ndarray]:
    d = np.asarray(profile_depth, float).ravel()
    t = np.asarray(track_xy, float)
    if t.ndim != 2 or t.shape[1] != 2:
        raise InputError(f"track_xy must be an (N, 2) array of x_east_m, y_north_m; got shape {t.shape}")
    if t.shape[0] != d.size:
        raise InputError(f"profile has {d.size} depths but the track has {t.shape[0]} points")
    if d.size < 3:
        raise InputError(f"measured profile has {d.size} samples; TERCOM needs at least 3")
    if not (np.isfinite(d).all() and np.isfinite(t).all()):
        raise InputError("measured profile or track contains NaN/inf; drop those samples first")
    return d, t


def _required_samples(min_valid_fraction: float, n: int) -> int:
    """Fewest samples on valid map cells for an offset to be feasible: ``max(ceil(fraction * n), 1)``."""
    return max(int(np.ceil(min_valid_fraction * n - 1e-9)), 1)


def _second_optimum_verdict(criterion: str, score: float, second: float, sx: float, sy: float, bx: float, by: float,
                            mismatch_ratio: float, estimate_bias: bool) -> tuple[float, bool, str | None]:
    """Separation ratio, mismatch flag and warning (or None) for the best ``score`` at ``(bx, by)`` and the second
    distinct optimum ``second`` at ``(sx, sy)``; COR is maximised (ratio best/second), MSD/MAD minimised."""
    if criterion == "cor":
        ratio = (score / second) if (estimate_bias and second > 0) else float("nan")
    else:
        ratio = second / score if score > 0 else float("inf")
    mismatch = bool(np.isfinite(ratio) and ratio < mismatch_ratio)
    warning = None
    if mismatch:
        warning = (f"possible mismatch: second distinct {criterion.upper()} optimum {second:.4g} at "
                   f"({sx:.0f}, {sy:.0f}) m is within a factor {mismatch_ratio} of the best {score:.4g} "
                   f"({np.hypot(sx - bx, sy - by):.0f} m away)")
    return ratio, mismatch, warning


def _snap(track_rel: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray]:
    return np.rint(track_rel[:, 1] / h).astype(np.int64), np.rint(track_rel[:, 0] / h).astype(np.int64)


class _FFTCorrelator:
    """Cross-correlations of fixed map layers with sample masks over all start cells of the map.

    Map layers are zero-padded (so circular correlation never wraps onto a feasible offset) and
    transformed once. Mask transforms are *pruned*: a mask is non-zero only in its first ``mr`` rows
    (the track's footprint), so the row transforms run on those rows only and the column transform
    zero-pads (``n=L0``). Inverse transforms run the column pass on everything and the row pass only
    on the rows of the output window. Several spectra are transformed in one batched call.
    """

    def __init__(self, layers: dict[str, np.ndarray], pad_lo: tuple[int, int], pad_hi: tuple[int, int]):
        ny, nx = next(iter(layers.values())).shape
        self.ny, self.nx = ny, nx
        self.pad_lo = pad_lo
        shape = (ny + pad_lo[0] + pad_hi[0], nx + pad_lo[1] + pad_hi[1])
        self.fshape = (sfft.next_fast_len(shape[0], real=True), sfft.next_fast_len(shape[1], real=True))
        self.F: dict[str, np.ndarray] = {}
        for k, a in layers.items():
            p = np.zeros(self.fshape)
            p[pad_lo[0] : pad_lo[0] + ny, pad_lo[1] : pad_lo[1] + nx] = a
            self.F[k] = sfft.rfft2(p, workers=-1)
        self.F32 = {k: v.astype(np.complex64) for k, v in self.F.items()}

    def masks_fft(self, rows, cols, weights: list, dtype=np.float64) -> list[np.ndarray]:
        """Conjugated FFTs of sparse masks with samples at relative (rows, cols) >= 0, one per weight vector."""
        mr = int(rows.max()) + 1
        m = np.zeros((len(weights), mr, self.fshape[1]), dtype)
        for k, w in enumerate(weights):
            np.add.at(m[k], (rows, cols), w)
        f = sfft.rfft(m, axis=-1, workers=-1)
        f = sfft.fft(f, n=self.fshape[0], axis=-2, workers=-1, overwrite_x=True)
        np.conjugate(f, out=f)
        return list(f)

    def inverse(self, specs: list[np.ndarray], rmin: int, cmin: int) -> list[np.ndarray]:
        """Back-transform spectra and cut out the start-cell grid: out[r, c] = sum_a layer[r + rmin + a] mask[a]."""
        r0, c0 = self.pad_lo[0] + rmin, self.pad_lo[1] + cmin
        x = sfft.ifft(specs, axis=-2, workers=-1, overwrite_x=True)[:, r0 : r0 + self.ny]
        out = sfft.irfft(x, n=self.fshape[1], axis=-1, workers=-1)
        return list(out[:, :, c0 : c0 + self.nx])


def _sums_all_offsets(corr: _FFTCorrelator, rows, cols, d, want_cor: bool, single: bool = False):
    """N, sum r, sum r^2 (r = d_BT - d_M) [and sum d_M d_BT, sum d_M, sum d_BT] for every start cell."""
    rmin, cmin = int(rows.min()), int(cols.min())
    rr, cc = rows - rmin, cols - cmin
    dt = np.float32 if single else np.float64
    FC, FS1, FS2 = corr.masks_fft(rr, cc, [np.ones_like(d), d, d * d], dt)
    F = corr.F32 if single else corr.F
    specs = np.empty((8 if want_cor else 3,) + FC.shape, FC.dtype)
    tmp = np.empty_like(FC)
    np.multiply(F["V"], FC, out=specs[0])
    np.multiply(F["D"], FC, out=specs[1])
    specs[1] -= np.multiply(F["V"], FS1, out=tmp)
    np.multiply(F["D2"], FC, out=specs[2])
    specs[2] -= np.multiply(F["D"], FS1, out=tmp)
    specs[2] -= tmp
    specs[2] += np.multiply(F["V"], FS2, out=tmp)
    if want_cor:
        np.multiply(F["D"], FS1, out=specs[3])
        np.multiply(F["V"], FS1, out=specs[4])
        np.multiply(F["D"], FC, out=specs[5])
        np.multiply(F["D2"], FC, out=specs[6])
        np.multiply(F["V"], FS2, out=specs[7])
    out = corr.inverse(specs, rmin, cmin)
    n = np.rint(out[0])
    extra = tuple(out[3:8]) if want_cor else None
    return n, out[1].astype(np.float64, copy=False), out[2].astype(np.float64, copy=False), extra


def _mad_direct(D: np.ndarray, V: np.ndarray, rows, cols, d, bias: np.ndarray | None, region_rc) -> np.ndarray:
    """[TERCOM Eq. 16] by direct summation over samples, vectorised over the start cells of ``region_rc``."""
    ny, nx = D.shape
    r0, r1, c0, c1 = region_rc
    out = np.zeros((r1 - r0, c1 - c0))
    for ri, ci, di in zip(rows.tolist(), cols.tolist(), d.tolist(), strict=True):
        # map cells (r + ri, c + ci) for start cells r in [r0, r1), c in [c0, c1): clip to the map
        a0, a1 = max(r0 + ri, 0), min(r1 + ri, ny)
        b0, b1 = max(c0 + ci, 0), min(c1 + ci, nx)
        if a1 <= a0 or b1 <= b0:
            continue
        sl = (slice(a0 - ri - r0, a1 - ri - r0), slice(b0 - ci - c0, b1 - ci - c0))
        res = D[a0:a1, b0:b1] - di
        if bias is not None:
            res = res - bias[r0:r1, c0:c1][sl]
        out[sl] += np.where(V[a0:a1, b0:b1], np.abs(res), 0.0)
    return out


def _mad_median_direct(D: np.ndarray, V: np.ndarray, rows, cols, d, region_rc, n_req: int, chunk: int = 8192):
    """[TERCOM Eq. 16] with the median bias: per start cell ``b = median(d_BT - d_M)``, ``MAD = mean |d_BT - d_M - b|``.

    Direct gather over the start cells of ``region_rc`` (chunked); returns ``(mad, bias)`` on the region."""
    ny, nx = D.shape
    r0, r1, c0, c1 = region_rc
    rr0, cc0 = np.mgrid[r0:r1, c0:c1]
    flat_r, flat_c = rr0.ravel(), cc0.ravel()
    mad = np.full(flat_r.size, np.nan)
    med = np.full(flat_r.size, np.nan)
    for k in range(0, flat_r.size, chunk):
        rr = flat_r[k : k + chunk, None] + rows[None, :]
        cc = flat_c[k : k + chunk, None] + cols[None, :]
        inside = (rr >= 0) & (rr < ny) & (cc >= 0) & (cc < nx)
        rr, cc = np.clip(rr, 0, ny - 1), np.clip(cc, 0, nx - 1)
        ok = inside & V[rr, cc]
        res = np.where(ok, D[rr, cc] - d[None, :], np.nan)
        feas = ok.sum(axis=1) >= n_req
        with np.errstate(invalid="ignore"), __import__("warnings").catch_warnings():
            __import__("warnings").simplefilter("ignore", RuntimeWarning)
            m = np.nanmedian(np.where(feas[:, None], res, 0.0), axis=1)
            a = np.nanmean(np.abs(res - m[:, None]), axis=1)
        med[k : k + chunk] = np.where(feas, m, np.nan)
        mad[k : k + chunk] = np.where(feas, a, np.nan)
    return mad.reshape(r1 - r0, c1 - c0), med.reshape(r1 - r0, c1 - c0)


class _Search:
    """One TERCOM search ([TERCOM Eqs. 15-17]): the map layers centred on the map mean, the track snapped for every
    (heading, scale) pose, the FFT correlator and the feasibility rules; :meth:`evaluate` gives the criterion of a
    pose at every start cell, :meth:`exact_msd` the MSD at given cells exactly (float64 direct gather)."""

    def __init__(self, d: np.ndarray, t: np.ndarray, g: MapGrid, poses: list[tuple[float, float]], o: TercomOptions,
                 region: tuple[float, float, float, float] | None):
        self.g, self.poses, self.criterion, self.estimate_bias = g, poses, o.criterion, o.estimate_bias
        self.h = g.resolution_m
        self.ny, self.nx = ny, nx = g.shape
        self.V = V = np.isfinite(g.depth_m)
        self.ref = float(np.nanmean(g.depth_m))
        self.D = D = np.where(V, g.depth_m - self.ref, 0.0)
        self.dc = d - self.ref
        rel = t - t[0]
        self.snapped = snapped = [_snap(_rotate(rel, a) * f, self.h) for a, f in poses]
        rmin = min(int(r.min()) for r, _ in snapped)
        rmax = max(int(r.max()) for r, _ in snapped)
        cmin = min(int(c.min()) for _, c in snapped)
        cmax = max(int(c.max()) for _, c in snapped)
        pad_lo = (max(0, -rmin), max(0, -cmin))
        pad_hi = (max(0, rmax), max(0, cmax))
        self.corr = _FFTCorrelator({"V": V.astype(float), "D": D, "D2": D * D}, pad_lo, pad_hi)
        self.window = r0, r1, c0, c1 = g.region_window(region)
        self.in_region = np.zeros((ny, nx), bool)
        self.in_region[r0:r1, c0:c1] = True
        self.sign = -1.0 if o.criterion == "cor" else 1.0  # internally minimise
        self.n_req = _required_samples(o.min_valid_fraction, d.size)

    def evaluate(self, k: int, single: bool):
        """``(criterion, key to minimise (inf where infeasible), bias or None, valid count)`` of pose ``k`` at
        every start cell; ``single``: float32 FFTs."""
        ny, nx, criterion, estimate_bias = self.ny, self.nx, self.criterion, self.estimate_bias
        rows, cols = self.snapped[k]
        n, s_r, s_r2, extra = _sums_all_offsets(self.corr, rows, cols, self.dc, criterion == "cor", single)
        feasible = (n >= self.n_req) & self.in_region
        r0, r1, c0, c1 = self.window
        with np.errstate(invalid="ignore", divide="ignore"):
            nn = np.where(feasible, n, np.nan)
            bias = s_r / nn if estimate_bias else None
            if criterion == "msd":
                val = s_r2 / nn
                if estimate_bias:
                    val -= bias * bias
                np.maximum(val, 0.0, out=val)  # NaN (infeasible) propagates
            elif criterion == "mad":
                val = np.full((ny, nx), np.nan)
                if estimate_bias:  # the L1-optimal bias: the median residual at every offset
                    sub, med = _mad_median_direct(self.D, self.V, rows, cols, self.dc, self.window, self.n_req)
                    bias = np.full((ny, nx), np.nan)
                    bias[r0:r1, c0:c1] = med
                    val[r0:r1, c0:c1] = np.where(feasible[r0:r1, c0:c1], sub, np.nan)
                else:
                    sub = _mad_direct(self.D, self.V, rows, cols, self.dc, None, self.window)
                    val[r0:r1, c0:c1] = sub / nn[r0:r1, c0:c1]
            else:
                val = self._cor(nn, extra)
        key = self.sign * val
        key[~np.isfinite(key)] = np.inf
        return val, key, bias, n

    def _cor(self, nn: np.ndarray, extra) -> np.ndarray:
        s_db, s_d, s_b, s_bb, s_dd = extra
        if self.estimate_bias:  # Pearson correlation of the two profiles (documented deviation)
            cov = s_db / nn - (s_d / nn) * (s_b / nn)
            vb = s_bb / nn - (s_b / nn) ** 2
            vd = s_dd / nn - (s_d / nn) ** 2
            den = np.sqrt(np.maximum(vb, 0.0) * np.maximum(vd, 0.0))
            return np.where(den > 1e-12 * max(float(np.nanmax(np.abs(vd))), 1e-300), cov / den, np.nan)
        ref = self.ref  # [TERCOM Eq. 15] with the un-centred depths: d = dc + ref, b = D + ref
        return (s_db + ref * (s_d + s_b)) / nn + ref * ref

    def exact_msd(self, k: int, flat: np.ndarray):
        """MSD, valid count and bias at cells ``flat`` for pose ``k``, exactly (float64 direct gather)."""
        ny, nx = self.ny, self.nx
        rows, cols = self.snapped[k]
        rc, cc_ = np.unravel_index(flat, (ny, nx))
        rr, cc = rc[:, None] + rows[None, :], cc_[:, None] + cols[None, :]
        inside = (rr >= 0) & (rr < ny) & (cc >= 0) & (cc < nx)
        rr, cc = np.clip(rr, 0, ny - 1), np.clip(cc, 0, nx - 1)
        ok = inside & self.V[rr, cc]
        nn = ok.sum(axis=1)
        res = np.where(ok, self.D[rr, cc] - self.dc[None, :], 0.0)
        with np.errstate(invalid="ignore", divide="ignore"):
            b = res.sum(axis=1) / nn if self.estimate_bias else np.zeros(len(flat))
            msd = np.maximum((res * res).sum(axis=1) / nn - b * b, 0.0)
        return np.where(nn >= self.n_req, msd, np.nan), nn, b

    def exact_msd_at_candidates(self, k: int, val, key, bias, n, m: int = 64) -> np.ndarray:
        """Recompute MSD exactly at the ``m`` lowest screened cells of pose ``k``; patch the surfaces in place."""
        kf = key.ravel()
        flat = np.argpartition(kf, min(m, kf.size - 1))[:m] if kf.size > m else np.arange(kf.size)
        flat = flat[np.isfinite(kf[flat])]
        msd, nn, b = self.exact_msd(k, flat)
        feas = np.isfinite(msd)
        val.flat[flat] = np.where(feas, msd, np.nan)
        key.flat[flat] = np.where(feas, msd, np.inf)
        n.flat[flat] = nn
        if bias is not None:
            bias.flat[flat] = b
        return flat


def _search_poses(s: _Search, mixed: bool, verify_headings: int, progress):
    """Evaluate every pose (float32 screening when ``mixed``, then the ``verify_headings`` best-screened poses in
    double precision). Returns ``(best, all_best, all_pose, heading_scores)``: ``best`` = ``(key, pose, flat cell,
    criterion surface, bias surface, count surface)`` or None when no offset is feasible; ``all_best`` the best key
    over the poses at each cell, ``all_pose`` its pose."""
    poses, sign, criterion = s.poses, s.sign, s.criterion
    all_best = np.full((s.ny, s.nx), np.inf)
    all_pose = np.zeros((s.ny, s.nx), np.int32)
    heading_scores: dict[float, float] = {}
    screened: list[tuple[float, int]] = []
    kept: list[tuple[float, int, tuple]] = []
    best = None
    it = range(len(poses))
    if progress is not None:
        it = progress.track(it, "TERCOM headings", total=len(poses))

    def note_score(k: int, v: float) -> None:
        a = poses[k][0]
        old = heading_scores.get(a, float("nan"))
        if not np.isfinite(old) or (np.isfinite(v) and sign * v < sign * old):
            heading_scores[a] = v

    for k in it:
        val, key, bias, n = s.evaluate(k, single=mixed)
        idx = int(np.argmin(key))
        better = key < all_best
        all_best[better] = key[better]
        all_pose[better] = k
        if not np.isfinite(key.flat[idx]):
            note_score(k, float("nan"))
            continue
        note_score(k, float(val.flat[idx]))
        screened.append((float(key.flat[idx]), k))
        if mixed and criterion == "msd":  # keep the screened surfaces of the best few headings
            kept.append((float(key.flat[idx]), k, (val, key, bias, n)))
            kept.sort(key=lambda e: e[0])
            del kept[verify_headings:]
        if not mixed and (best is None or key.flat[idx] < best[0]):
            best = (float(key.flat[idx]), k, idx, val, bias, n)
    if mixed:  # verify the best-screened headings in double precision; the best of those wins
        surfaces = {k: arrays for _, k, arrays in kept}
        for _, k in sorted(screened)[:verify_headings]:
            if criterion == "msd":
                val, key, bias, n = surfaces[k]
                flat = s.exact_msd_at_candidates(k, val, key, bias, n)
                idx = int(flat[np.argmin(key.flat[flat])])
            else:
                val, key, bias, n = s.evaluate(k, single=False)
                idx = int(np.argmin(key))
            note_score(k, float(val.flat[idx]))
            if np.isfinite(key.flat[idx]) and (best is None or key.flat[idx] < best[0]):
                best = (float(key.flat[idx]), k, idx, val, bias, n)
    return best, all_best, all_pose, heading_scores


def _second_optimum(s: _Search, all_best: np.ndarray, all_best_val: np.ndarray, all_pose: np.ndarray, r: int, c: int,
                    score: float, mixed: bool, o: TercomOptions) -> tuple[float, float, float, float, bool, list[str]]:
    """Best local optimum outside the exclusion neighbourhood of the fix (cell ``r``, ``c``) and its verdict:
    ``(second, x, y, separation ratio, mismatch, warnings)``. With float32 screening the best candidates are
    re-checked exactly (``all_best_val`` is patched in place)."""
    g, h, ny, nx = s.g, s.h, s.ny, s.nx
    excl = o.exclusion_radius_m if o.exclusion_radius_m is not None else max(5 * h, 100.0)
    key_all = np.where(np.isfinite(all_best), all_best, np.inf)
    local = key_all == ndimage.minimum_filter(key_all, size=3, mode="constant", cval=np.inf)
    rr, cc = np.mgrid[0:ny, 0:nx]
    far = np.hypot((rr - r) * h, (cc - c) * h) > excl
    cand = local & far & np.isfinite(key_all)
    warnings: list[str] = []
    if cand.any() and mixed and s.criterion == "msd":
        # float32 screening can be off by ~0.1 m^2 on high-relief maps: re-check the best candidates exactly
        cf = np.flatnonzero(cand)
        cf = cf[np.argsort(key_all.flat[cf])[:32]]
        exact = np.array([s.exact_msd(int(all_pose.flat[f]), np.array([f]))[0][0] for f in cf])
        all_best_val.flat[cf] = exact
        key_all.flat[cf] = np.where(np.isfinite(exact), exact, np.inf)
    if not cand.any():
        return float("nan"), float("nan"), float("nan"), float("inf"), False, warnings
    j = int(np.argmin(np.where(cand, key_all, np.inf)))
    r2, c2 = divmod(j, nx)
    second = float(all_best_val[r2, c2])
    sx, sy = float(g.x_m[c2]), float(g.y_m[r2])
    ratio, mismatch, warn = _second_optimum_verdict(s.criterion, score, second, sx, sy, g.x_m[c], g.y_m[r],
                                                    o.mismatch_ratio, o.estimate_bias)
    if warn is not None:
        warnings.append(warn)
    return second, sx, sy, ratio, mismatch, warnings


def tercom(
    profile_depth,
    track_xy,
    dtm,
    criterion: str | None = None,
    *,
    headings_deg: Sequence[float] | np.ndarray = (0.0,),
    scales: Sequence[float] | np.ndarray = (1.0,),
    region: tuple[float, float, float, float] | None = None,
    verify_headings: int = 3,
    progress=None,
    options: TercomOptions | None = None,
    **option_values: Any,
) -> TercomResult:
    """Exhaustive TERCOM search ([TERCOM Eqs. 15-17], §4.2) of a measured profile over the whole map.

    The options ``criterion``, ``estimate_bias``, ``precision``, ``min_valid_fraction``, ``exclusion_radius_m``
    and ``mismatch_ratio`` are :class:`hadal.matching.options.TercomOptions` (their defaults are declared there
    only): pass ``options`` or the fields as keywords (the keywords override ``options``); a value out of
    bounds raises :class:`InputError`.

    Parameters
    ----------
    profile_depth : measured seafloor depths ``d_M`` in metres, positive down (N,).
    track_xy : (N, 2) dead-reckoned positions (x_east_m, y_north_m) of the samples, any origin; the
        track is matched relative to its first sample.
    dtm : the reference map (``dtm`` Dataset with ``depth_m(y, x)``, a DataArray or a :class:`MapGrid`).
    criterion : ``"msd"`` ([TERCOM Eq. 17], minimised), ``"mad"`` ([TERCOM Eq. 16], minimised) or ``"cor"`` ([TERCOM Eq. 15], maximised).
    estimate_bias : estimate a constant map-minus-measured depth bias at every offset (module docstring).
    headings_deg : heading errors (degrees, clockwise) to try by rotating the track about its start.
    region : ``(x_min, x_max, y_min, y_max)`` in map metres restricting the *start* position; default whole map.
    min_valid_fraction : minimum fraction of samples on valid map cells for an offset to be feasible.
    exclusion_radius_m : neighbourhood of the best match outside which the second distinct local
        optimum is sought (default ``max(5 cells, 100 m)``).
    mismatch_ratio : for MSD/MAD warn of a possible mismatch when ``second / best < mismatch_ratio``
        (for COR when ``best / second < mismatch_ratio`` on centred values).
    precision : ``"double"`` (float64 FFTs throughout) or ``"mixed"``: every heading is screened with
        float32 FFTs (about 2x faster; with 2 km of relief the MSD error is up to ~0.1 m^2), then for
        the ``verify_headings`` best-screened headings the MSD is recomputed exactly (float64, direct
        sum over the samples) at the 64 lowest cells of each, and the best of those is returned: the
        reported fix, score and bias are double precision, the surfaces keep float32 accuracy
        elsewhere. For COR/MAD the verified headings are recomputed with float64 FFTs.
    scales : along-track scale factors of the dead-reckoned track to try (DVL/speed scale error),
        applied about the start together with every heading; ``heading_scores`` then holds the best
        value over the scales for each heading and ``scale`` the best factor.
    """
    if criterion is not None:
        option_values["criterion"] = criterion
    o = tercom_options(options, option_values, TERCOM_FIELDS, "tercom")
    d, t = _validate_inputs(profile_depth, track_xy)
    g = MapGrid.from_any(dtm)
    headings = [float(a) for a in headings_deg] or [0.0]
    scale_list = [float(f) for f in scales] or [1.0]
    if min(scale_list) <= 0:
        raise InputError(f"track scale factors must be > 0, got {scale_list}")
    poses = [(a, f) for a in headings for f in scale_list]
    s = _Search(d, t, g, poses, o, region)
    ny, nx = g.shape
    mixed = o.precision == "mixed" and len(poses) > verify_headings
    best, all_best, all_pose, heading_scores = _search_poses(s, mixed, verify_headings, progress)
    if best is None:
        raise InputError(
            f"no feasible TERCOM offset: the {d.size}-sample track (extent {np.ptp(t[:, 0]):.0f} x {np.ptp(t[:, 1]):.0f} m) "
            f"does not fit on valid cells of the {ny} x {nx} map with min_valid_fraction={o.min_valid_fraction}"
        )
    _, k_best, idx, surf, bias_surf, n_surf = best
    a_best, f_best = poses[k_best]
    r, c = divmod(idx, nx)
    score = float(surf[r, c])
    bias_m = float(bias_surf[r, c]) if bias_surf is not None else 0.0
    all_best_val = np.where(np.isfinite(all_best), s.sign * all_best, np.nan)
    second, sx, sy, ratio, mismatch, warnings = _second_optimum(s, all_best, all_best_val, all_pose, r, c, score,
                                                                mixed, o)
    n_valid = int(n_surf[r, c])
    if n_valid < d.size:
        warnings.append(f"{d.size - n_valid} of {d.size} samples fall on invalid map cells at the best offset")
    nb = surf[max(r - 1, 0) : r + 2, max(c - 1, 0) : c + 2]
    if r in (0, ny - 1) or c in (0, nx - 1) or not np.isfinite(nb).all():
        warnings.append("best offset lies on the edge of the feasible search region; the true position may be outside it")

    edge = pose_at_search_edge({"heading_deg": (a_best, headings), "scale": (f_best, scale_list)})
    if edge:
        mismatch = True
        warnings.append(search_edge_warning(edge, "TERCOM"))
    sig_x, sig_y = _likelihood_sigma(surf if o.criterion == "msd" else None, r, c, score, n_valid, g.resolution_m)
    return TercomResult(
        criterion=o.criterion, start_x_m=float(g.x_m[c]), start_y_m=float(g.y_m[r]), start_row=r, start_col=c,
        heading_deg=a_best, score=score, bias_m=bias_m, n_samples=int(d.size), n_valid=n_valid,
        surface=surf, surface_all_headings=all_best_val, bias_surface=bias_surf, x_m=g.x_m, y_m=g.y_m,
        heading_scores=heading_scores, second_score=second, second_x_m=sx, second_y_m=sy,
        separation_ratio=float(ratio), mismatch=mismatch, sigma_x_m=sig_x, sigma_y_m=sig_y,
        track_start_xy=(float(t[0, 0]), float(t[0, 1])), warnings=warnings, scale=f_best,
        search_edge={"at_edge": bool(edge), "retried": False, "bounds_hit": edge or None},
    )


def pose_at_search_edge(values: dict, tol_steps: float = 0.25, bounds: dict | None = None) -> dict:
    """The pose parameters at a bound of their search: ``values`` maps a name (``heading_deg``, ``scale``) to
    ``(estimate, searched grid)``; a grid of two or more values whose estimate lies within ``tol_steps`` of its step
    from its smallest or largest value is at the edge (``bounds`` may give continuous ``(lo, hi)`` bounds instead
    of the grid's). Returns ``{name: {"value", "bounds"}}``, empty when every estimate is inside."""
    out = {}
    for name, (value, grid) in values.items():
        gr = np.unique(np.asarray(grid, float))
        lo, hi = (bounds or {}).get(name, (gr[0], gr[-1]) if gr.size else (np.nan, np.nan))
        if gr.size < 2 or not hi > lo:
            continue
        tol = tol_steps * float(np.min(np.diff(gr)))
        if value <= lo + tol or value >= hi - tol:
            out[name] = {"value": float(value), "bounds": [float(lo), float(hi)]}
    return out


def search_edge_warning(edge: dict, what: str, retried: bool = False) -> str:
    """The named warning of a fix at the edge of its search (``edge`` from :func:`pose_at_search_edge`)."""
    at = " and ".join(f"{k} {v['value']:.4g} at the bound of its search [{v['bounds'][0]:.4g}, {v['bounds'][1]:.4g}]"
                      for k, v in edge.items())
    return (f"possible mismatch: search edge: the {what} {at}" + (" after widening the search once" if retried else "")
            + "; the true pose may lie outside the search: the fix and its covariance are not trusted")


def _likelihood_sigma(msd: np.ndarray | None, r: int, c: int, msd_min: float, n: int, h: float) -> tuple[float, float]:
    """1-sigma fix uncertainty (x, y) in metres from the MSD surface read as a Gaussian likelihood.

    ``L(offset) ∝ exp(-N (MSD - MSD_min) / (2 s^2))`` with the noise variance ``s^2`` estimated by
    ``MSD_min`` (floored at 1e-4 m^2); the weighted covariance of the start positions over the
    surface, plus the ``h^2/12`` quantisation of a search at map resolution. Samples along a track are
    correlated, so this is a lower bound; for COR/MAD only the quantisation term is reported.
    """
    q = h * h / 12.0
    if msd is None:
        return float(np.sqrt(q)), float(np.sqrt(q))
    s2 = max(msd_min, 1e-4)
    with np.errstate(invalid="ignore", over="ignore"):
        ll = -n * (msd - msd_min) / (2 * s2)
    ll = np.where(np.isfinite(ll), ll, -np.inf)
    w = np.exp(ll - ll.max())
    w /= w.sum()
    rr, cc = np.mgrid[0 : msd.shape[0], 0 : msd.shape[1]]
    vy = float((w * ((rr - r) * h) ** 2).sum())
    vx = float((w * ((cc - c) * h) ** 2).sum())
    return float(np.sqrt(vx + q)), float(np.sqrt(vy + q))


def tercom_direct(profile_depth, track_xy, dtm, starts_rc, criterion: str | None = None, *, heading_deg: float = 0.0,
                  scale: float = 1.0, options: TercomOptions | None = None, **option_values: Any) -> np.ndarray:
    """Reference implementation: [TERCOM Eqs. 15-17] evaluated offset by offset with a plain NumPy loop.

    Same sampling convention and options as :func:`tercom` (nearest cell relative to the start; ``criterion``,
    ``estimate_bias``, ``min_valid_fraction`` of :class:`hadal.matching.options.TercomOptions`). ``starts_rc`` is
    an (K, 2) array of start (row, col) cells. Slow - used by the tests and the benchmark as the peer.
    """
    if criterion is not None:
        option_values["criterion"] = criterion
    o = tercom_options(options, option_values, DIRECT_FIELDS, "tercom_direct")
    criterion, estimate_bias, min_valid_fraction = o.criterion, o.estimate_bias, o.min_valid_fraction
    d, t = _validate_inputs(profile_depth, track_xy)
    g = MapGrid.from_any(dtm)
    rows, cols = _snap(_rotate(t - t[0], heading_deg) * scale, g.resolution_m)
    ny, nx = g.shape
    out = np.full(len(starts_rc), np.nan)
    for k, (r, c) in enumerate(np.asarray(starts_rc, int)):
        rr, cc = rows + r, cols + c
        inside = (rr >= 0) & (rr < ny) & (cc >= 0) & (cc < nx)
        dbt = np.full(d.size, np.nan)
        dbt[inside] = g.depth_m[rr[inside], cc[inside]]
        ok = np.isfinite(dbt)
        if ok.sum() < _required_samples(min_valid_fraction, d.size):
            continue
        dm, db = d[ok], dbt[ok]
        b = np.mean(db - dm) if estimate_bias else 0.0
        if criterion == "msd":
            out[k] = np.mean((dm - (db - b)) ** 2)
        elif criterion == "mad":
            bm = np.median(db - dm) if estimate_bias else 0.0
            out[k] = np.mean(np.abs(dm - (db - bm)))
        elif estimate_bias:
            sd, sb = np.std(dm), np.std(db)
            out[k] = np.mean((dm - dm.mean()) * (db - db.mean())) / (sd * sb) if sd * sb > 0 else np.nan
        else:
            out[k] = np.mean(dm * db)
    return out


class _PoseFit:
    """The refinement's likelihood: the [TERCOM Eq. 17] MSD (closed-form bias when ``estimate_bias``) of the track
    posed at (start x, start y, heading, scale) on the bilinear map, inf outside the bounds / ``region`` or with too
    few valid samples; :meth:`fit` a bounded Nelder-Mead search from a seed pose."""

    def __init__(self, d: np.ndarray, t: np.ndarray, g: MapGrid, hb: tuple, sb: tuple, reg: tuple,
                 estimate_bias: bool, min_valid_fraction: float):
        self.d, self.g, self.hb, self.sb, self.reg = d, g, hb, sb, reg
        self.rel = t - t[0]
        self.estimate_bias, self.min_valid_fraction = estimate_bias, min_valid_fraction
        self.n_req = _required_samples(min_valid_fraction, d.size)
        h = g.resolution_m
        # free parameters: start x/y always; heading and scale only where their bounds leave room. Simplex
        # steps never exceed half the bounded range (else the simplex collapses onto the bound).
        self.free = [True, True, hb[1] > hb[0], sb[1] > sb[0]]
        self.lo = np.array([reg[0], reg[2], hb[0], sb[0]])
        self.hi = np.array([reg[1], reg[3], hb[1], sb[1]])
        self.base_step = np.array([h, h, max(0.25 * (hb[1] - hb[0]), 0.1), max(0.25 * (sb[1] - sb[0]), 0.002)])
        self.idx = [i for i in range(4) if self.free[i]]

    def residuals(self, p):
        x0, y0, a, sc = p
        q = _rotate(self.rel, a) * sc
        return self.g.sample_bilinear(q[:, 0] + x0, q[:, 1] + y0) - self.d

    def cost(self, p, keep=None):
        x0, y0, a, sc = p
        hb, sb, reg = self.hb, self.sb, self.reg
        if not (hb[0] <= a <= hb[1] and sb[0] <= sc <= sb[1] and reg[0] <= x0 <= reg[1] and reg[2] <= y0 <= reg[3]):
            return np.inf
        r = self.residuals(p)
        ok = np.isfinite(r)
        if keep is not None:
            ok &= keep
            if ok.sum() < self.min_valid_fraction * keep.sum():
                return np.inf
        elif ok.sum() < self.n_req:
            return np.inf
        r = r[ok]
        return float(np.mean((r - r.mean()) ** 2)) if self.estimate_bias else float(np.mean(r * r))

    def fit(self, s0, keep=None):
        """``(MSD, pose)`` of the Nelder-Mead search from ``s0`` (samples ``keep`` only, when given); never worse
        than the start under the same (bilinear) MSD."""
        from scipy.optimize import minimize

        idx, lo, hi, hb, sb = self.idx, self.lo, self.hi, self.hb, self.sb
        full0 = np.array([s0[0], s0[1], np.clip(s0[2], *hb), np.clip(s0[3], *sb)], float)
        x = full0[idx].copy()
        steps = []
        for j, i in enumerate(idx):
            st = self.base_step[i]
            if np.isfinite(hi[i] - lo[i]):
                narrow = (hi[i] - lo[i]) < 2 * st
                st = min(st, 0.5 * (hi[i] - lo[i]))
                if i >= 2 and narrow and (x[j] <= lo[i] or x[j] >= hi[i]):
                    x[j] = 0.5 * (lo[i] + hi[i])  # a narrow range: start inside it, not on its bound
            steps.append(st)
        simplex = [x]
        for j, i in enumerate(idx):
            v = x.copy()
            v[j] = x[j] + steps[j] if x[j] + steps[j] <= hi[i] else x[j] - steps[j]
            simplex.append(v)

        def unpack(v):
            p = full0.copy()
            p[idx] = v
            return p

        with _warnings.catch_warnings(), np.errstate(all="ignore"):  # no optimiser warning reaches the user
            _warnings.simplefilter("ignore")
            o = minimize(lambda v: self.cost(unpack(v), keep), x, method="Nelder-Mead",
                         options={"initial_simplex": np.array(simplex), "xatol": 0.05, "fatol": 1e-4, "maxiter": 800})
        f0 = self.cost(full0, keep)
        if not (np.isfinite(o.fun) and o.fun < f0):  # never worse than the start under the same (bilinear) MSD
            return float(f0), full0
        return float(o.fun), unpack(o.x)


def _refine_seeds(coarse: TercomResult, g: MapGrid, pf: _PoseFit, n_seeds: int) -> list[tuple]:
    """The coarse optimum, then the ``n_seeds`` best distinct local minima of the best-over-headings surface (each
    at the coarse heading that fits it best)."""
    hb, sb = pf.hb, pf.sb
    surf = np.where(np.isfinite(coarse.surface_all_headings), coarse.surface_all_headings, np.inf)
    local = (surf == ndimage.minimum_filter(surf, size=5, mode="constant", cval=np.inf)) & np.isfinite(surf)
    flat = np.flatnonzero(local)
    flat = flat[np.argsort(surf.flat[flat], kind="stable")[:n_seeds]]
    headings = sorted(coarse.heading_scores) or [coarse.heading_deg]
    seeds = [(coarse.start_x_m, coarse.start_y_m, coarse.heading_deg, coarse.scale)]
    for f in flat:
        r, c = divmod(int(f), g.shape[1])
        x0, y0 = float(g.x_m[c]), float(g.y_m[r])
        if (x0, y0) == seeds[0][:2]:
            continue
        a = min(headings, key=lambda a, x0=x0, y0=y0: pf.cost((x0, y0, float(np.clip(a, *hb)), float(np.clip(coarse.scale, *sb)))))
        seeds.append((x0, y0, a, coarse.scale))
    return seeds


def _refined_verdict(fits: list, coarse: TercomResult, pose, score: float, rank: int, n_seeds_tried: int,
                     n_valid: int, n: int, pf: _PoseFit, o: TercomOptions):
    """Second distinct optimum among the refined seeds and the refined fix's warnings:
    ``(second, x, y, separation ratio, mismatch, warnings)``."""
    h = pf.g.resolution_m
    x0, y0 = float(pose[0]), float(pose[1])
    excl = o.exclusion_radius_m if o.exclusion_radius_m is not None else max(5 * h, 100.0)
    others = [f for f in fits if np.hypot(f[1][0] - x0, f[1][1] - y0) > excl]
    warnings = [w for w in coarse.warnings if "fall on invalid map cells" not in w and "possible mismatch" not in w]
    if others:
        s2, p2, _ = min(others, key=lambda f: f[0])
        second, sx, sy = float(s2), float(p2[0]), float(p2[1])
        ratio, mismatch, warn = _second_optimum_verdict("msd", score, second, sx, sy, x0, y0, o.mismatch_ratio,
                                                        o.estimate_bias)
        if warn is not None:
            warnings.append(warn)
    else:
        second, sx, sy, ratio, mismatch = coarse.second_score, coarse.second_x_m, coarse.second_y_m, float("nan"), coarse.mismatch
    if n_valid < n:
        warnings.append(f"{n - n_valid} of {n} samples fall on invalid map cells at the refined fix")
    moved = float(np.hypot(x0 - coarse.start_x_m, y0 - coarse.start_y_m))
    if moved > h:
        warnings.append(f"sub-cell refinement moved the fix {moved:.0f} m from the coarse optimum"
                        + (f" (seed {rank} of {n_seeds_tried} fitted better)" if rank > 0 else ""))
    edge = _refined_edge(pf, pose)
    if edge:  # a refined pose on its bound: the optimum may lie outside (issue 47): flagged
        mismatch = True
        warnings.append(search_edge_warning(edge, "refined TERCOM")
                        + " (widen heading_range_deg / refine_scale_range)")
    return second, sx, sy, ratio, mismatch, warnings


def _refined_edge(pf: _PoseFit, pose) -> dict:
    """The refined heading / scale on a bound of the refinement (as :func:`pose_at_search_edge`)."""
    return {name: {"value": float(pose[i]), "bounds": [float(pf.lo[i]), float(pf.hi[i])]}
            for name, i in (("heading_deg", 2), ("scale", 3))
            if pf.free[i] and (np.isclose(pose[i], pf.lo[i]) or np.isclose(pose[i], pf.hi[i]))}


def _jackknife_sigma(pf: _PoseFit, pose, n: int, blocks: int) -> tuple[float, float, int]:
    """Delete-a-block jackknife of the start position (DR random walk the rigid pose cannot follow):
    ``(sigma_x, sigma_y, blocks used)``, NaN with fewer than 2 feasible refits."""
    jk = []
    if blocks >= 2 and n >= 4 * blocks:
        block = np.minimum((np.arange(n) * blocks) // n, blocks - 1)
        for k in range(blocks):
            fun, p_k = pf.fit(pose, keep=block != k)
            if np.isfinite(fun):
                jk.append(p_k[:2])
    jx = jy = float("nan")
    if len(jk) >= 2:
        a = np.array(jk)
        var_j = (len(a) - 1) / len(a) * ((a - a.mean(axis=0)) ** 2).sum(axis=0)
        jx, jy = (float(v) for v in np.sqrt(var_j))
    return jx, jy, len(jk)


def refine_tercom(
    profile_depth,
    track_xy,
    dtm,
    coarse: TercomResult,
    *,
    heading_bounds_deg: tuple[float, float] | None = None,
    scale_bounds: tuple[float, float] | None = None,
    region: tuple[float, float, float, float] | None = None,
    jackknife_blocks: int = 8,
    options: TercomOptions | None = None,
    **option_values: Any,
) -> TercomResult:
    """Continuous refinement of a coarse TERCOM (MSD) fix: sub-cell start, heading and track scale.

    Options (:class:`hadal.matching.options.TercomOptions`, defaults declared there only; ``options`` or the
    fields as keywords): ``estimate_bias``, ``min_valid_fraction``, ``exclusion_radius_m``, ``mismatch_ratio``,
    ``refine_seeds`` (the ``n_seeds`` below) and ``refine_scale_range`` (``scale_bounds`` default
    ``1 -+ refine_scale_range``). ``heading_bounds_deg`` default: the coarse heading +-1 deg.

    **Deviation from the paper, and why.** §4.2 stops at the map resolution: the track is snapped to
    whole cells and the best cell wins. On steep terrain the half-cell snapping error (up to 10 m at
    20 m cells) is worth metres of depth, and a dead-reckoned track with a heading bias and a speed
    scale error of a few per cent never fits the grid exactly, so the best *snapped* offset can lie a
    cell or two from the truth while a wrong heading fits the quantised samples better. Here the coarse
    optimum and each of the ``n_seeds`` best distinct local minima of the coarse all-heading surface
    seed a Nelder-Mead search of the [TERCOM Eq. 17] MSD (bias estimated in closed form when
    ``estimate_bias``, as in the coarse search) with the map sampled **bilinearly** at the un-snapped
    track positions, over (start x, start y, heading, scale) within the bounds (and the start inside
    ``region``); the lowest refined MSD wins. The second distinct optimum, the separation ratio and the
    mismatch flag are then recomputed from the refined seeds (best one farther than
    ``exclusion_radius_m``, default ``max(5 cells, 100 m)``, from the winner).

    The returned result is a copy of ``coarse`` with the pose, ``score``, ``bias_m``, ``n_valid``, the
    second optimum and the warnings replaced and ``refinement`` describing the step (coarse values,
    seeds, the winning seed's rank, jackknife). The surfaces stay those of the coarse search.

    Uncertainty: the MSD-likelihood sigma of the coarse search ignores the dead-reckoning error *along*
    the track (a random walk the rigid pose cannot follow), which dominates on steep terrain. A
    delete-a-block jackknife adds it: the fit is repeated ``jackknife_blocks`` times, each time without
    one contiguous block of the track, and the spread of the start positions,
    ``var_J = (J-1)/J sum (x_k - mean x)^2``, is added in quadrature to ``sigma_x_m/sigma_y_m``.
    """
    from dataclasses import replace

    o = tercom_options(options, option_values, REFINE_FIELDS, "refine_tercom")
    if scale_bounds is None:
        scale_bounds = (1.0 - o.refine_scale_range, 1.0 + o.refine_scale_range)
    if coarse.criterion != "msd":
        raise InputError(f"sub-cell refinement is implemented for MSD only, not {coarse.criterion.upper()}")
    d, t = _validate_inputs(profile_depth, track_xy)
    g = MapGrid.from_any(dtm)
    hb = tuple(heading_bounds_deg) if heading_bounds_deg is not None else (coarse.heading_deg - 1.0, coarse.heading_deg + 1.0)
    sb = tuple(scale_bounds)
    if hb[0] > hb[1] or sb[0] > sb[1] or sb[0] <= 0:
        raise InputError(f"invalid refinement bounds: heading {hb}, scale {sb}")
    reg = region if region is not None else (-np.inf, np.inf, -np.inf, np.inf)
    pf = _PoseFit(d, t, g, hb, sb, reg, o.estimate_bias, o.min_valid_fraction)
    seeds = _refine_seeds(coarse, g, pf, o.refine_seeds)
    fits = [(*pf.fit(s0), rank) for rank, s0 in enumerate(seeds)]
    fits = [f for f in fits if np.isfinite(f[0])]
    if not fits:
        return replace(coarse, warnings=[*coarse.warnings, "sub-cell refinement found no feasible pose; coarse fix kept"])
    # seeds compared under the same likelihood (bilinear MSD); a far seed must beat the coarse optimum's own
    # refinement clearly (by the noise of the MSD itself, 2/N_valid relative), else the coarse fix's basin is kept
    own = [f for f in fits if f[2] == 0]
    score, pose, rank = min(fits, key=lambda f: f[0])
    if own and rank != 0 and score > own[0][0] * (1.0 - 2.0 / max(d.size, 1)):
        score, pose, rank = own[0]
    x0, y0, a, sc = (float(v) for v in pose)
    res = pf.residuals(pose)
    ok = np.isfinite(res)
    bias = float(np.mean(res[ok])) if o.estimate_bias else 0.0
    n_valid = int(ok.sum())
    second, sx, sy, ratio, mismatch, warnings = _refined_verdict(fits, coarse, pose, score, rank, len(seeds), n_valid,
                                                                 d.size, pf, o)
    jx, jy, n_jk = _jackknife_sigma(pf, pose, d.size, jackknife_blocks)
    sig_x = float(np.hypot(coarse.sigma_x_m, jx)) if np.isfinite(jx) else coarse.sigma_x_m
    sig_y = float(np.hypot(coarse.sigma_y_m, jy)) if np.isfinite(jy) else coarse.sigma_y_m
    moved = float(np.hypot(x0 - coarse.start_x_m, y0 - coarse.start_y_m))
    return replace(
        coarse, start_x_m=x0, start_y_m=y0, heading_deg=a, scale=sc, score=score, bias_m=bias, n_valid=n_valid,
        start_row=int(np.clip(np.rint(g.row_of(y0)), 0, g.shape[0] - 1)),
        start_col=int(np.clip(np.rint(g.col_of(x0)), 0, g.shape[1] - 1)),
        second_score=second, second_x_m=sx, second_y_m=sy, separation_ratio=float(ratio), mismatch=mismatch,
        sigma_x_m=sig_x, sigma_y_m=sig_y, warnings=warnings,
        search_edge={"at_edge": bool(_refined_edge(pf, pose)), "retried": False, "bounds_hit": _refined_edge(pf, pose) or None},
        refinement={"method": "Nelder-Mead on the bilinear MSD (Eq. 17) over start x/y, heading, scale",
                    "coarse": {"x_east_m": coarse.start_x_m, "y_north_m": coarse.start_y_m,
                               "heading_deg": coarse.heading_deg, "scale": coarse.scale, "score": coarse.score,
                               "separation_ratio": coarse.separation_ratio},
                    "seeds": len(seeds), "winning_seed": rank, "moved_m": moved,
                    "heading_bounds_deg": list(hb), "scale_bounds": list(sb),
                    "jackknife_sigma_m": {"east": jx, "north": jy, "blocks": int(n_jk)}},
    )
