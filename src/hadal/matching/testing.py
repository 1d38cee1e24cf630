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


# ------------------------------------------------------------------ real terrain (projected) and simulated tracks
def real_terrain(path, frame=None):
    """A real bathymetry grid (``read_grid``) projected onto a transverse-Mercator frame at its native resolution.

    Returns ``(MapGrid, truth)``: the map (depth positive down, NaN on land and nodata) and a bicubic
    interpolant of the same nodes, ``truth(x_m, y_m)`` (NaN where the map is NaN) - the seafloor the
    simulated vehicle "measures", which differs from the bilinear map between the nodes as real
    terrain differs from a gridded DTM.
    """
    from scipy.interpolate import RectBivariateSpline

    from hadal.geo import LocalFrame
    from hadal.grid.prior import resample_to_frame, z_positive
    from hadal.grid.readers import read_grid
    from hadal.matching.mapgrid import MapGrid

    da = read_grid(path)
    if frame is None:
        frame = LocalFrame(float(da.y.mean()), float(da.x.mean()))
    ds, _ = resample_to_frame(da, frame)
    z = np.asarray(ds["z"].values, float)
    pos, _ = z_positive(da)
    depth = -z if pos == "up" else z
    depth = np.where(np.isfinite(depth) & (depth > 0), depth, np.nan)
    g = MapGrid.from_any(depth, np.asarray(ds["x"].values, float), np.asarray(ds["y"].values, float))
    filled = np.where(np.isfinite(g.depth_m), g.depth_m, np.nanmean(g.depth_m))
    spl = RectBivariateSpline(g.y_m, g.x_m, filled, kx=3, ky=3)

    def truth(x_m, y_m):
        x = np.asarray(x_m, float)
        y = np.asarray(y_m, float)
        out = spl.ev(y, x)
        return np.where(np.isfinite(g.sample_bilinear(x, y)), out, np.nan)

    return g, truth


def crop(g, r0: int, c0: int, size: int):
    """A ``size`` x ``size`` cell window of a MapGrid (for fast trials on a large real grid)."""
    from hadal.matching.mapgrid import MapGrid

    return MapGrid(np.ascontiguousarray(g.depth_m[r0 : r0 + size, c0 : c0 + size]), g.x_m[c0 : c0 + size],
                   g.y_m[r0 : r0 + size], g.resolution_m)


def meander_track(n: int, step_m: float, rng, turn_sd_rad: float = 0.35) -> np.ndarray:
    """(n, 2) track of ``n`` samples ``step_m`` apart with a random-walk heading (sd ``turn_sd_rad`` per step)."""
    heading = rng.uniform(0, 2 * np.pi) + np.cumsum(rng.normal(0, turn_sd_rad, n))
    xy = np.column_stack([np.sin(heading), np.cos(heading)]) * step_m
    xy[0] = 0
    return np.cumsum(xy, axis=0)


KINDS = ("clean", "drift", "holes", "off_map", "flat", "short")


def simulate_case(g, truth, rng, kind: str = "clean", n: int | None = None, noise_frac: float | None = None):
    """One simulated dive segment with known truth on a (real) map ``g`` whose seafloor is ``truth``.

    The vehicle's dead-reckoned track ``dr`` (one sample per map cell of travel) is related to the true
    track by ``true_i = start + f R(a) (dr_i - dr_0) + w_i`` (heading error ``a`` in +-4 deg, scale ``f``
    in 1 +- 3 %, ``w`` a random walk plus a velocity bias, zero at the start); the profile is the true
    seafloor minus a bias (+-50 m) plus noise (``noise_frac`` x the map relief, 0-2 %). ``kind``:
    ``clean``; ``drift`` (velocity bias up to 2 % of the distance); ``holes`` (NaN blobs under 40-50 %
    of the samples); ``off_map`` (25-35 % of the true track off the map); ``flat`` (a zero-relief map);
    ``short`` (3-8 samples). Returns a dict with ``profile``, ``dr``, ``map`` (possibly modified),
    ``start`` (truth), ``h``, and the drawn parameters.
    """
    from hadal.matching.mapgrid import MapGrid
    from hadal.matching.tercom import _rotate

    h = g.resolution_m
    ny, nx = g.shape
    if n is None:
        n = int(rng.integers(3, 9)) if kind == "short" else int(rng.integers(20, 101))
    if noise_frac is None:
        noise_frac = float(rng.uniform(0.0, 0.02))
    z = g.depth_m
    relief = float(np.nanpercentile(z, 99) - np.nanpercentile(z, 1)) if np.isfinite(z).any() else 0.0
    a = float(rng.uniform(-4, 4))
    f = float(rng.uniform(0.97, 1.03))
    bias = float(rng.uniform(-50, 50))
    vb = float(rng.uniform(0, 0.02 if kind == "drift" else 0.005))
    for _ in range(400):
        dr = meander_track(n, h, rng)
        rel = dr - dr[0]
        q = _rotate(rel, a) * f
        s = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(rel, axis=0).T))])
        ang = rng.uniform(0, 2 * np.pi)
        w = np.cumsum(rng.normal(0, 0.03 * h, (n, 2)), axis=0)
        w -= w[0]
        w += vb * s[:, None] * np.array([np.cos(ang), np.sin(ang)])
        q = q + w
        lo, hi = q.min(axis=0), q.max(axis=0)
        if kind == "off_map":
            start = np.array([rng.uniform(g.x_m[0] - hi[0], g.x_m[-1] - lo[0]), rng.uniform(g.y_m[0] - hi[1], g.y_m[-1] - lo[1])])
            p = q + start
            inside = ((p[:, 0] >= g.x_m[0]) & (p[:, 0] <= g.x_m[-1]) & (p[:, 1] >= g.y_m[0]) & (p[:, 1] <= g.y_m[-1]))
            if inside[0] and 0.25 <= 1 - inside.mean() <= 0.35:
                break
            continue
        span = np.array([g.x_m[-1] - g.x_m[0], g.y_m[-1] - g.y_m[0]]) - (hi - lo) - 4 * h
        if (span <= 0).any():
            continue
        start = np.array([g.x_m[0], g.y_m[0]]) - lo + 2 * h + rng.uniform(0, 1, 2) * span
        p = q + start
        if np.isfinite(g.sample_bilinear(p[:, 0], p[:, 1])).mean() >= (0.95 if kind != "holes" else 0.0):
            break
    else:
        raise RuntimeError(f"cannot place a {n}-sample track on the {ny} x {nx} map")
    if kind == "flat":
        zf = np.full_like(z, float(np.nanmean(z)))
        zf[~np.isfinite(z)] = np.nan
        g = MapGrid(zf, g.x_m, g.y_m, h)
        true_depth = np.full(n, float(np.nanmean(z)))
        noise_m = 1.0
    else:
        true_depth = truth(p[:, 0], p[:, 1])
        noise_m = noise_frac * relief
        if kind == "off_map":
            true_depth = np.where(np.isfinite(true_depth), true_depth, float(np.nanmean(z)) + rng.normal(0, 0.3 * relief, n))
        if kind == "holes":
            zh = z.copy()
            yy, xx = np.mgrid[0:ny, 0:nx]
            target = rng.uniform(0.40, 0.50)
            for _ in range(50):
                i = int(rng.integers(n))
                rr, cc = g.row_of(p[i, 1]), g.col_of(p[i, 0])
                zh[(yy - rr) ** 2 + (xx - cc) ** 2 <= rng.uniform(2, 4) ** 2] = np.nan
                gh = MapGrid(zh, g.x_m, g.y_m, h)
                if (~np.isfinite(gh.sample_bilinear(p[:, 0], p[:, 1]))).mean() >= target:
                    break
            g = gh
    prof = true_depth - bias + rng.normal(0, 1.0, n) * noise_m
    if not np.isfinite(prof).all():
        prof = np.where(np.isfinite(prof), prof, float(np.nanmean(prof)))
    return {"profile": prof, "dr": dr + rng.uniform(-5e4, 5e4, 2), "map": g, "start": start, "h": h, "n": n,
            "noise_m": noise_m, "noise_frac": noise_frac, "heading_deg": a, "scale": f, "bias_m": bias,
            "velocity_bias": vb, "kind": kind, "relief_m": relief}


def cut_patch(g, truth, rng: np.random.Generator, noise_frac: float, r0: float | None = None,
              c0: float | None = None, ny: int = 30, nx: int = 40) -> tuple[np.ndarray, float, float]:
    """(patch, true x0, true y0): an ``ny`` x ``nx`` patch of the true seafloor ``truth(x, y)`` (e.g. the bicubic
    interpolant of a real grid: off-node) at a random sub-cell position inside the map ``g`` (a
    :class:`hadal.matching.MapGrid`; at row/column ``r0``/``c0`` + U(0, 1) when given), with a depth bias
    U(-50, 50) m and white noise ``noise_frac`` x the patch's depth range (the MRF tests and benchmark)."""
    h = g.resolution_m
    for _ in range(200):
        r = rng.uniform(1, g.shape[0] - ny - 2) if r0 is None else r0 + rng.uniform(0, 1)
        c = rng.uniform(1, g.shape[1] - nx - 2) if c0 is None else c0 + rng.uniform(0, 1)
        x0, y0 = g.x_m[0] + c * h, g.y_m[0] + r * h
        jj, ii = np.meshgrid(np.arange(nx), np.arange(ny))
        z = truth(x0 + jj * h, y0 + ii * h)
        if np.isfinite(z).all():
            return z + rng.uniform(-50, 50) + rng.normal(0, noise_frac * float(np.ptp(z)), z.shape), x0, y0
    raise RuntimeError("no valid patch position")
