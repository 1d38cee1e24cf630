"""Synthetic terrains and tracks for the matching tests, the accuracy study and the benchmark.

Not used by the pipeline. The terrain is an analytic function (sum of random plane waves plus
Gaussian seamounts), so it can be sampled exactly at any sub-cell position - the "truth" for the
real-time measurements - while the reference map is its cell-centre samples plus map noise.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class AnalyticTerrain:
    """``depth(x, y) = base + sum_k a_k sin(k . (x, y) + phi_k) + seamounts`` (metres, positive down)."""

    base_m: float
    amp: np.ndarray
    kx: np.ndarray
    ky: np.ndarray
    phase: np.ndarray
    bump_xy: np.ndarray
    bump_height: np.ndarray
    bump_sigma: np.ndarray

    @classmethod
    def random(cls, seed: int = 0, relief_m: float = 100.0, wavelength_m: tuple[float, float] = (300.0, 2000.0),
               n_waves: int = 12, n_bumps: int = 6, extent_m: float = 4000.0, base_m: float = 10_000.0) -> AnalyticTerrain:
        rng = np.random.default_rng(seed)
        lam = rng.uniform(*wavelength_m, n_waves)
        ang = rng.uniform(0, np.pi, n_waves)
        k = 2 * np.pi / lam
        amp = relief_m * rng.uniform(0.3, 1.0, n_waves) * (lam / wavelength_m[1]) ** 0.5 / np.sqrt(n_waves)
        return cls(base_m, amp, k * np.cos(ang), k * np.sin(ang), rng.uniform(0, 2 * np.pi, n_waves),
                   rng.uniform(0, extent_m, (n_bumps, 2)), relief_m * rng.uniform(-1, 1, n_bumps),
                   rng.uniform(100, 400, n_bumps))

    def __call__(self, x_m, y_m) -> np.ndarray:
        x = np.asarray(x_m, float)[..., None]
        y = np.asarray(y_m, float)[..., None]
        z = (self.amp * np.sin(self.kx * x + self.ky * y + self.phase)).sum(-1)
        dx = x - self.bump_xy[:, 0]
        dy = y - self.bump_xy[:, 1]
        z = z + (self.bump_height * np.exp(-(dx * dx + dy * dy) / (2 * self.bump_sigma ** 2))).sum(-1)
        return self.base_m + z

    def grid(self, nx: int, ny: int, h: float = 20.0, noise_m: float = 0.0, seed: int = 0):
        """Reference map: (depth[ny, nx], x, y) at cell centres ``0, h, 2h, ...`` plus Gaussian map noise."""
        x = np.arange(nx) * h
        y = np.arange(ny) * h
        z = self(*np.meshgrid(x, y))
        if noise_m:
            z = z + np.random.default_rng(seed).normal(0, noise_m, z.shape)
        return z, x, y


def lawnmower(n: int, width_m: float, height_m: float, legs: int = 4) -> np.ndarray:
    """(n, 2) points evenly spaced along a U/lawnmower pattern starting at (0, 0): ``legs`` legs north-south."""
    legs = max(1, legs)
    dxl = width_m / max(legs - 1, 1)
    pts = [(0.0, 0.0)]
    for i in range(legs):
        x = i * dxl
        y0, y1 = (0.0, height_m) if i % 2 == 0 else (height_m, 0.0)
        if i > 0:
            pts.append((x, y0))
        pts.append((x, y1))
    p = np.array(pts)
    seg = np.hypot(*np.diff(p, axis=0).T)
    s = np.concatenate([[0], np.cumsum(seg)])
    t = np.linspace(0, s[-1], n)
    return np.column_stack([np.interp(t, s, p[:, 0]), np.interp(t, s, p[:, 1])])


def wiggly_track(n: int, length_m: float, seed: int = 0) -> np.ndarray:
    """(n, 2) smooth random track of about ``length_m`` starting at (0, 0), heading changes of tens of degrees."""
    rng = np.random.default_rng(seed)
    heading = np.cumsum(rng.normal(0, 0.08, n)) + rng.uniform(0, 2 * np.pi)
    step = length_m / max(n - 1, 1)
    xy = np.column_stack([np.sin(heading), np.cos(heading)]) * step
    xy[0] = 0
    return np.cumsum(xy, axis=0)
