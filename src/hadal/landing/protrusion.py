"""Protrusion height maps (Sangekar et al. §III-B2, [Landing Eq. 10], Fig. 17).

Two methods:

* :func:`protrusion_height_map` with ``method="opening"`` (the default) — height above a *ground surface*
  obtained by a morphological opening whose structuring element is tied to the vehicle footprint:
  a flat octagon (≈ disc) of minimum width = the vehicle diagonal σ, applied after removing a robust local
  plane per block. Every rock narrower than σ — i.e. every rock the whole vehicle cannot stand on —
  is removed from the ground entirely, so its height comes out in full, flat tops included, on any slope.
* ``method="butterworth"`` — the paper's literal [Landing Eq. 10]: Fourier low-pass
  H(f) = 1/sqrt(1 + (f/f_c)^(2n)) with f_c = 2/σ (σ in samples) per zero-filled block
  ``[Landing Eq. 10]``; kept for comparison (``bench/bench_landing.py --rocks`` prints both).

Why the default deviates from the literal f_c = 2/σ ``[Landing Eq. 10]``
-------------------------------------------------------------------------
f_c = 2/σ cycles per sample is a cut-off *wavelength* of σ/2 = 0.89 m for Table II. Any rock whose size is
comparable to that wavelength is partly kept in the "smooth" surface and its height is lost: a 30 cm dome keeps
83 % of its height at 0.2 m diameter, 51 % at 0.4 m, 23 % at 0.6 m, 13 % at 1 m — so a 30 cm × 0.6 m rock
under the footprint reads as 7 cm and the site is called safe, breaking the [Landing Eq. 9] rule (nothing higher than
h_c may touch the vehicle). A mean over a disc of the vehicle diagonal (the reference C++ implementation,
ocean-perception/landing_area_detector) keeps ~92 % of a 0.6 m rock but only ~30 % of a 1.5 m one.
Any *linear* low-pass keeps a fraction of a wide rock; a morphological opening does not: the ground at a point
is the highest flat σ-wide plate that fits under the seafloor there, so a rock the plate cannot fit on
contributes nothing to the ground and 100 % to the height, whatever its shape. Slopes (up to θc) are handled
by removing a robust per-block plane first (the paper's eigenvector alignment: heights are measured along the
block's plane normal); a plane is reproduced exactly by an opening, so plain slopes give zero height.
Features wider than σ are terrain, not protrusions: the vehicle can stand on them and the footprint slope
(Fig. 13c) judges their edges. Convex terrain of curvature radius ρ_c reads at most (σ/2)²/(2 ρ_c) high at
its crest (the linear filters have the same order of error).

Noise: the ground is computed on block means of ``coarse_m`` cells (≈ 5 cm) smoothed over ``smooth_m``
(0.2 m, at least 3 coarse cells), so white sensor noise averages out of it; the height itself keeps the full
resolution (z - ground). A rock grows by one coarse cell plus half the smoothing window on each side in that
surface, so rocks up to ≈ σ - 0.3 m wide (1.5 m for Table II) are removed from the ground entirely.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.fft as sfft
from scipy import ndimage as ndi

# ----------------------------------------------------------------------------- paper's [Landing Eq. 10] (for comparison)


def butterworth_lowpass(shape: tuple[int, int], cutoff_cycles_per_sample: float, order: int = 3) -> np.ndarray:
    """``[Landing Eq. 10]`` rotated around the zero frequency: H = 1/sqrt(1 + (f/f_c)^(2n)) on the ``rfft2``
    grid of ``shape`` (f = radial frequency in cycles per sample)."""
    fy = sfft.fftfreq(shape[0])[:, None]
    fx = sfft.rfftfreq(shape[1])[None, :]
    f = np.hypot(fx, fy)
    return 1.0 / np.sqrt(1.0 + (f / cutoff_cycles_per_sample) ** (2 * order))


def cutoff_cycles_per_sample(diagonal_m: float, cell_m: float) -> float:
    """f_c = 2/σ (after ``[Landing Eq. 10]``) with σ = vehicle diagonal in samples."""
    return 2.0 / (diagonal_m / cell_m)


def _plane_normal(pts: np.ndarray) -> np.ndarray:
    mean = pts.mean(axis=0)
    _, vecs = np.linalg.eigh(np.cov((pts - mean).T))
    normal = vecs[:, 0]
    if normal[2] < 0:
        normal = -normal
    if abs(normal[2]) < 0.2:  # degenerate (collinear) block: fall back to vertical heights
        normal = np.array([0.0, 0.0, 1.0])
    return normal


def _block_heights_fft(z: np.ndarray, cell_m: float, fc: float, order: int, edge_correction: bool,
                       filters: dict[int, np.ndarray]) -> np.ndarray:
    valid = np.isfinite(z)
    out = np.full(z.shape, np.nan)
    if valid.sum() < 10:
        return out
    rows, cols = np.nonzero(valid)
    pts = np.column_stack([cols * cell_m, rows * cell_m, z[valid]])
    normal = _plane_normal(pts)
    aligned = np.zeros(z.shape)
    aligned[valid] = (pts - pts.mean(axis=0)) @ normal
    n = 1 << int(math.ceil(math.log2(max(z.shape))))
    filt = filters.get(n)
    if filt is None:
        filt = filters[n] = butterworth_lowpass((n, n), fc, order)
    low = sfft.irfft2(sfft.rfft2(aligned, s=(n, n), workers=1) * filt, s=(n, n), workers=1)[: z.shape[0], : z.shape[1]]
    if edge_correction:
        wlow = sfft.irfft2(sfft.rfft2(valid.astype(float), s=(n, n), workers=1) * filt, s=(n, n), workers=1)
        wlow = wlow[: z.shape[0], : z.shape[1]]
        low = np.where(wlow > 0.05, low / np.maximum(wlow, 0.05), low)
    out[valid] = aligned[valid] - low[valid]
    return out


# ----------------------------------------------------------------------------- morphology helpers
def _diag_filter(a: np.ndarray, size: int, anti: bool, fn) -> np.ndarray:
    """1-D ``fn`` (minimum/maximum_filter1d) of ``size`` along the diagonals (anti=False: (1, 1) direction)
    by shearing the diagonals into rows; cells outside ``a`` are ignored (±inf padding)."""
    ny, nx = a.shape
    fill = np.inf if fn is ndi.minimum_filter1d else -np.inf
    j = np.arange(nx)
    off = (nx - 1 - j) if not anti else j  # row shift per column
    b = np.full((ny + nx - 1, nx), fill)
    rows = np.arange(ny)[:, None] + off[None, :]
    b[rows, j[None, :]] = a
    b = fn(b, size, axis=1, mode="constant", cval=fill)  # a diagonal of ``a`` is a row of ``b``
    return b[rows, j[None, :]]


def _octagon_sizes(half_px: int) -> tuple[int, int]:
    """Square half-side s and diagonal half-length t (diagonal steps) of a near-regular octagon of inradius
    ``half_px``: axis support s + 2t = r, diagonal support (s + t)√2 = r -> t = r/(2 + √2), s = r - 2t."""
    t = max(0, int(round(half_px / (2.0 + math.sqrt(2.0)))))
    return max(1, half_px - 2 * t), t


def _octagon_filter(a: np.ndarray, half_px: int, erode: bool) -> np.ndarray:
    """Grey erosion (``erode``) or dilation of ``a`` (±inf = ignored) by a flat octagon of inradius
    ``half_px`` cells: square ⊕ two diagonal segments (each O(N), van Herk / Gil-Werman in scipy)."""
    fn = ndi.minimum_filter1d if erode else ndi.maximum_filter1d
    fill = np.inf if erode else -np.inf
    s, t = _octagon_sizes(half_px)
    out = fn(a, 2 * s + 1, axis=0, mode="constant", cval=fill)
    out = fn(out, 2 * s + 1, axis=1, mode="constant", cval=fill)
    if t > 0:
        out = _diag_filter(out, 2 * t + 1, False, fn)
        out = _diag_filter(out, 2 * t + 1, True, fn)
    return out


def octagon_offsets(half_px: int) -> np.ndarray:
    """Offsets (row, col) of the structuring element used by :func:`_octagon_filter` (for tests)."""
    s, t = _octagon_sizes(half_px)
    sq = np.array([(i, j) for i in range(-s, s + 1) for j in range(-s, s + 1)])
    d1 = np.array([(k, k) for k in range(-t, t + 1)])
    d2 = np.array([(k, -k) for k in range(-t, t + 1)])
    pts = (sq[:, None, None, :] + d1[None, :, None, :] + d2[None, None, :, :]).reshape(-1, 2)
    return np.unique(pts, axis=0)


def _block_mean(z: np.ndarray, k: int) -> np.ndarray:
    """NaN-aware mean over k × k blocks (the last partial blocks included)."""
    ny, nx = z.shape
    py, px = (-ny) % k, (-nx) % k
    zz = np.pad(z, ((0, py), (0, px)), constant_values=np.nan)
    v = np.isfinite(zz)
    s = np.where(v, zz, 0.0).reshape(zz.shape[0] // k, k, zz.shape[1] // k, k).sum(axis=(1, 3))
    n = v.reshape(zz.shape[0] // k, k, zz.shape[1] // k, k).sum(axis=(1, 3))
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(n >= max(1, (k * k) // 4), s / np.maximum(n, 1), np.nan)


def _robust_plane(x: np.ndarray, y: np.ndarray, z: np.ndarray, iterations: int = 4) -> np.ndarray:
    """Plane z = c + a x + b y by least squares with outliers (rocks, pits) dropped iteratively
    (|residual - median| > 3 × 1.4826 MAD + 5 mm). Returns (c, a, b)."""
    keep = np.ones(z.size, bool)
    A = np.column_stack([np.ones(z.size), x, y])
    coef = np.zeros(3)
    for _ in range(iterations):
        if keep.sum() < 3:
            break
        coef = np.linalg.lstsq(A[keep], z[keep], rcond=None)[0]
        r = z - A @ coef
        med = np.median(r[keep])
        mad = 1.4826 * np.median(np.abs(r[keep] - med))
        new = np.abs(r - med) <= 3.0 * mad + 0.005
        if np.array_equal(new, keep):
            break
        keep = new
    return coef


def ground_surface_m(z: np.ndarray, cell_m: float, plate_m: float, *, block_m: float = 2.5,
                     coarse_m: float = 0.05, smooth_m: float = 0.2, rows: slice | str | None = None,
                     _coarse: tuple | None = None):
    """Ground under the protrusions: per ``block_m`` block (analysed with a margin of ``plate_m`` on every
    side), a robust plane is removed from the ``coarse_m`` block means of ``z`` and a grey opening by a flat
    octagon of minimum width ``plate_m`` is applied; the plane is added back and the result interpolated
    bilinearly onto the input grid. Returns (ground elevation (m), cos of the block slope) on ``z``'s grid
    (``rows``: a slice of rows only; ``rows="coarse"``: the coarse ground and cosines, which ``_coarse`` then
    upsamples row chunk by row chunk without full-size temporaries)."""
    z = np.asarray(z, float)
    ny, nx = z.shape
    k = max(1, int(round(coarse_m / cell_m)))
    if _coarse is not None:  # upsample rows ``rows`` of an already computed coarse ground
        return _upsample_ground(*_coarse, k, ny, nx, rows)
    cc = cell_m * k
    zc = _block_mean(z, k)
    nyc, nxc = zc.shape
    half = max(1, int(round(0.5 * plate_m / cc)))
    sm = max(3, 2 * int(math.floor(0.5 * smooth_m / cc + 1e-9)) + 1)  # odd smoothing window (coarse cells)
    bs = max(1, int(round(block_m / cc)))
    mg = 2 * half + 1
    ground = np.full(zc.shape, np.nan)
    cosm = np.ones(zc.shape)
    Yc, Xc = np.mgrid[0:nyc, 0:nxc].astype(float)
    # near-equal blocks of about ``block_m`` (no thin remainder block at the far edges)
    ry = np.linspace(0, nyc, max(1, int(round(nyc / bs))) + 1).astype(int)
    rx = np.linspace(0, nxc, max(1, int(round(nxc / bs))) + 1).astype(int)
    for r0, r1 in zip(ry[:-1], ry[1:], strict=True):
        for c0, c1 in zip(rx[:-1], rx[1:], strict=True):
            if not np.isfinite(zc[r0:r1, c0:c1]).any():
                continue
            R0, R1, C0, C1 = max(0, r0 - mg), min(nyc, r1 + mg), max(0, c0 - mg), min(nxc, c1 + mg)
            w = zc[R0:R1, C0:C1]
            v = np.isfinite(w)
            if v.sum() < 3:
                continue
            X, Y = Xc[R0:R1, C0:C1] * cc, Yc[R0:R1, C0:C1] * cc
            c, a, b = _robust_plane(X[v], Y[v], w[v])
            trend = c + a * X + b * Y
            # 3 x 3 mean (NaN-aware) of the detrended coarse cells: white sensor noise must not shape the lower
            # envelope; done after the plane removal so the grid edges of a slope are not biased
            d0 = np.where(v, w - trend, 0.0)
            with np.errstate(invalid="ignore", divide="ignore"):
                d = ndi.uniform_filter(d0, sm, mode="constant") / ndi.uniform_filter(v.astype(float), sm, mode="constant")
            d = np.where(v, d, np.inf)
            op = _octagon_filter(_octagon_filter(d, half, True), half, False)
            g = op + trend
            g = np.where(np.isfinite(op), g, np.nan)
            ground[r0:r1, c0:c1] = g[r0 - R0 : r1 - R0, c0 - C0 : c1 - C0]
            cosm[r0:r1, c0:c1] = 1.0 / math.sqrt(1.0 + a * a + b * b)
    # fill coarse cells without a ground value from their nearest neighbour (edges), then upsample
    bad = ~np.isfinite(ground)
    if bad.all():
        ground = None
    elif bad.any():
        idx = ndi.distance_transform_edt(bad, return_distances=False, return_indices=True)
        ground = ground[idx[0], idx[1]]
    if rows == "coarse":  # the coarse ground and slope cosines, for a row-chunked upsampling
        return ground, cosm
    return _upsample_ground(ground, cosm, k, ny, nx, rows)


def _upsample_ground(ground, cosm, k: int, ny: int, nx: int, rows: slice | None):
    """Bilinear ground and block cosines on the fine grid (rows ``rows`` only, or all)."""
    r = np.arange(ny)[rows] if rows is not None else np.arange(ny)
    if ground is None:
        return np.full((r.size, nx), np.nan), np.ones((r.size, nx))
    nyc, nxc = ground.shape
    # coarse cell (i, j) has its centre at fine index (i k + (k-1)/2, j k + (k-1)/2)
    fy = (r - 0.5 * (k - 1)) / k
    fx = (np.arange(nx) - 0.5 * (k - 1)) / k
    g_fine = _bilinear(ground, fy, fx)
    cos_fine = cosm[np.minimum(r // k, nyc - 1)][:, np.minimum(np.arange(nx) // k, nxc - 1)]
    return g_fine, cos_fine


def _bilinear(a: np.ndarray, fy: np.ndarray, fx: np.ndarray) -> np.ndarray:
    """Separable bilinear interpolation of ``a`` at fractional rows ``fy`` × columns ``fx`` (extrapolated linearly at the edges)."""
    def weights(f, n):  # linear extrapolation over the last half coarse cell at the edges
        if n == 1:
            return np.zeros(f.size, int), np.zeros(f.size, int), np.zeros(f.size)
        i0 = np.clip(np.floor(f).astype(int), 0, n - 2)
        return i0, i0 + 1, f - i0

    y0, y1, wy = weights(fy, a.shape[0])
    rows = a[y0] * (1.0 - wy)[:, None] + a[y1] * wy[:, None]
    x0, x1, wx = weights(fx, a.shape[1])
    return rows[:, x0] * (1.0 - wx)[None, :] + rows[:, x1] * wx[None, :]


def protrusion_height_map(
    z: np.ndarray,
    cell_m: float,
    diagonal_m: float,
    *,
    method: str = "opening",
    block_m: float = 2.5,
    margin_m: float = 1.0,
    order: int = 3,
    edge_correction: bool = False,
    coarse_m: float = 0.05,
) -> np.ndarray:
    """Height of protrusions h (m, along the local plane normal; positive = above the ground, NaN where
    unmapped) of elevation grid ``z`` (m, rows = y, cols = x, NaN = unmapped).

    ``method="opening"`` (default): h = (z - ground) cos θ_block, the ground from :func:`ground_surface_m`
    with a plate as wide as the vehicle diagonal ``diagonal_m`` (deviation from the literal
    ``[Landing Eq. 10]`` cut-off, see the module docstring: every rock narrower than the diagonal keeps
    its full height). ``method="butterworth"``: the paper's Fourier low-pass ``[Landing Eq. 10]``,
    f_c = 2/σ, order ``order``, blocks of ``block_m`` with ``margin_m`` overlap.
    """
    z = np.asarray(z, dtype=float)
    if method == "opening":
        cm = max(coarse_m, cell_m)
        coarse = ground_surface_m(z, cell_m, diagonal_m, block_m=block_m, coarse_m=cm, rows="coarse")
        out = np.empty(z.shape)
        step = max(1, 1_000_000 // max(1, z.shape[1]))  # upsampled in row chunks: no full-size temporaries
        for r0 in range(0, z.shape[0], step):
            sl = slice(r0, min(z.shape[0], r0 + step))
            ground, cos_t = ground_surface_m(z, cell_m, diagonal_m, coarse_m=cm, rows=sl, _coarse=coarse)
            zz = z[sl]
            with np.errstate(invalid="ignore"):
                out[sl] = np.where(np.isfinite(zz), (zz - ground) * cos_t, np.nan)
        return out
    if method != "butterworth":
        raise ValueError(f"unknown protrusion method {method!r}")
    ny, nx = z.shape
    fc = cutoff_cycles_per_sample(diagonal_m, cell_m)
    bs = max(1, int(round(block_m / cell_m)))
    mg = max(0, int(math.ceil(margin_m / cell_m)))
    out = np.full(z.shape, np.nan)
    filters: dict[int, np.ndarray] = {}
    for r0 in range(0, ny, bs):
        r1 = min(ny, r0 + bs)
        for c0 in range(0, nx, bs):
            c1 = min(nx, c0 + bs)
            core = z[r0:r1, c0:c1]
            if not np.isfinite(core).any():
                continue
            R0, R1 = max(0, r0 - mg), min(ny, r1 + mg)
            C0, C1 = max(0, c0 - mg), min(nx, c1 + mg)
            h = _block_heights_fft(z[R0:R1, C0:C1], cell_m, fc, order, edge_correction, filters)
            out[r0:r1, c0:c1] = h[r0 - R0 : r1 - R0, c0 - C0 : c1 - C0]
    return out
