"""Protrusion height map by 2-D Fourier low-pass filtering (Sangekar et al. §III-B2, Eq. 10, Fig. 17).

Per block of bathymetry: normalise (remove the mean and align with the eigenvectors of the point
covariance, i.e. measure heights along the plane normal), zero-fill to an N×N matrix (N = next power
of two above the largest block dimension), FFT, multiply by the rotationally symmetric Butterworth
low-pass H(f) = 1/sqrt(1 + (f/f_c)^(2n)) (Eq. 10, n = 3, f_c = 2/σ with σ the vehicle diagonal in
samples), inverse FFT, and subtract the smooth surface from the normalised one.

Deviations from the paper (documented here on purpose):

* Frequencies are in cycles per sample, so f_c = 2/σ with σ in samples, i.e. a cut-off wavelength of
  half the vehicle diagonal (0.89 m for Table II) whatever the grid resolution.
* "Aligning with the eigenvectors" is done by projecting every point onto the block's principal-plane
  normal while keeping it at its grid cell (no lateral resampling of the rotated cloud; the lateral
  shift is at most (1 - cos θ) of the block size, ~6 % at 20°). Heights are therefore perpendicular
  to the local plane, which is what matters for a vehicle that settles on that plane.
* Blocks (2.5 m like the paper) are processed with an overlap margin (default 1 m each side) and only
  their core is kept, so the combined map has no seams at block edges.
* ``edge_correction=True`` (off by default, the paper zero-fills) divides the low-passed surface by the
  low-passed mapped mask (normalised convolution), which removes the pull towards zero next to gaps.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.fft as sfft


def butterworth_lowpass(shape: tuple[int, int], cutoff_cycles_per_sample: float, order: int = 3) -> np.ndarray:
    """Eq. 10 rotated around the zero frequency: H = 1/sqrt(1 + (f/f_c)^(2n)) on the ``rfft2`` grid of
    ``shape`` (f = radial frequency in cycles per sample)."""
    fy = sfft.fftfreq(shape[0])[:, None]
    fx = sfft.rfftfreq(shape[1])[None, :]
    f = np.hypot(fx, fy)
    return 1.0 / np.sqrt(1.0 + (f / cutoff_cycles_per_sample) ** (2 * order))


def cutoff_cycles_per_sample(diagonal_m: float, cell_m: float) -> float:
    """f_c = 2/σ (Sangekar et al., after Eq. 10) with σ = vehicle diagonal in samples."""
    return 2.0 / (diagonal_m / cell_m)


def _block_heights(z: np.ndarray, cell_m: float, fc: float, order: int, edge_correction: bool,
                   filters: dict[int, np.ndarray]) -> np.ndarray:
    valid = np.isfinite(z)
    out = np.full(z.shape, np.nan)
    if valid.sum() < 10:
        return out
    rows, cols = np.nonzero(valid)
    pts = np.column_stack([cols * cell_m, rows * cell_m, z[valid]])
    mean = pts.mean(axis=0)
    cov = np.cov((pts - mean).T)
    _, vecs = np.linalg.eigh(cov)
    normal = vecs[:, 0]
    if normal[2] < 0:
        normal = -normal
    if abs(normal[2]) < 0.2:  # degenerate (collinear) block: fall back to vertical heights
        normal = np.array([0.0, 0.0, 1.0])
    aligned = np.zeros(z.shape)
    aligned[valid] = (pts - mean) @ normal
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


def protrusion_height_map(
    z: np.ndarray,
    cell_m: float,
    diagonal_m: float,
    *,
    block_m: float = 2.5,
    margin_m: float = 1.0,
    order: int = 3,
    edge_correction: bool = False,
) -> np.ndarray:
    """Height of protrusions h (m, along the local plane normal; positive = above the smooth surface,
    NaN where unmapped) of elevation grid ``z`` (m, rows = y, cols = x, NaN = unmapped), Eq. 10.

    The grid is cut into ``block_m`` square blocks (the paper: 2.5 m of transect), each analysed with
    ``margin_m`` of overlap on every side; ``diagonal_m`` is the vehicle diagonal that sets f_c = 2/σ.
    """
    z = np.asarray(z, dtype=float)
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
            h = _block_heights(z[R0:R1, C0:C1], cell_m, fc, order, edge_correction, filters)
            out[r0:r1, c0:c1] = h[r0 - R0 : r1 - R0, c0 - C0 : c1 - C0]
    return out
