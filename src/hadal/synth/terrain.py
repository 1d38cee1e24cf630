"""True reference terrain of the sample dive: an E-W trending hadal trench (Challenger Deep-like).

Model (TERCOM paper §4.1.1-4.1.2 and Figs. 3-7, qualitatively): a narrow, flat, sediment-ponded floor
along a gently curving E-W axis, deepening towards a pool south-west of the launch point (the deepest
point of the map), a steep, rugged northern (inner/forearc) wall - most rugged to the NE and NW of the
dive site, where the paper found the terrain information for matching - and a gentler southern
(Pacific-plate) wall with E-W fault scarps. Roughness is spectral (fractal, power spectrum ~ k^-beta)
noise, isotropic plus a down-slope-elongated (gully/spur) component, with an amplitude that is tiny
on the floor and large on the walls.

The surface is the bilinear interpolant of the 20 m grid (cell centres) written to truth/terrain.nc:
multibeam soundings, the altimeter and the vehicle depth all sample that same surface.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.interpolate import PchipInterpolator
from scipy.ndimage import map_coordinates

from hadal.synth import scenario as sc


@dataclass
class Terrain:
    """Depth (m, positive down) on ascending cell-centre coordinates x (east) / y (north) in the map frame."""

    x: np.ndarray
    y: np.ndarray
    depth: np.ndarray  # (ny, nx)

    @property
    def res(self) -> float:
        return float(self.x[1] - self.x[0])

    def sample(self, x_east_m, y_north_m) -> np.ndarray:
        """Bilinear depth at arbitrary map positions (edge values are held beyond the last cell centre)."""
        xi = (np.asarray(x_east_m, float) - self.x[0]) / self.res
        yi = (np.asarray(y_north_m, float) - self.y[0]) / self.res
        shape = np.shape(xi)
        out = map_coordinates(self.depth, [yi.ravel(), xi.ravel()], order=1, mode="nearest", prefilter=False)
        return out.reshape(shape)

    def bounds(self) -> tuple[float, float, float, float]:
        h = self.res / 2
        return (float(self.x[0] - h), float(self.x[-1] + h), float(self.y[0] - h), float(self.y[-1] + h))


def grid_axes(nx: int = sc.MAP_NX, ny: int = sc.MAP_NY, res: float = sc.MAP_RES_M) -> tuple[np.ndarray, np.ndarray]:
    """Cell-centre coordinates of a grid centred on the map-frame origin."""
    x = (np.arange(nx) - (nx - 1) / 2.0) * res
    y = (np.arange(ny) - (ny - 1) / 2.0) * res
    return x, y


def spectral_noise(rng: np.random.Generator, shape: tuple[int, int], res: float, beta: float,
                   stretch_y: float = 1.0, k_min: float = 1 / 20000.0) -> np.ndarray:
    """Unit-variance fractal noise: white noise filtered to a power spectrum ~ |k|^-beta (|k| >= k_min).

    ``stretch_y`` > 1 elongates features along y (the spectrum is evaluated at (kx, ky * stretch_y)).
    """
    ny, nx = shape
    white = rng.standard_normal(shape)
    f = np.fft.rfft2(white)
    ky = np.fft.fftfreq(ny, d=res)[:, None] * stretch_y
    kx = np.fft.rfftfreq(nx, d=res)[None, :]
    k = np.sqrt(kx**2 + ky**2)
    amp = np.maximum(k, k_min) ** (-beta / 2.0)
    amp[0, 0] = 0.0
    out = np.fft.irfft2(f * amp, s=shape)
    out -= out.mean()
    return out / out.std()


def _soft_ramp(u: np.ndarray, width: float) -> np.ndarray:
    """Smooth max(u, 0) (softplus with transition ``width``), for floor-to-wall transitions."""
    return width * np.logaddexp(0.0, u / width)


def trench_axis(x: np.ndarray) -> np.ndarray:
    """North coordinate (m) of the trench axis as a function of east: WSW-ENE, gently curving."""
    cx = np.array([-12500.0, -6000.0, -900.0, 1500.0, 5000.0, 12500.0])
    cy = np.array([-1900.0, -1300.0, -450.0, 850.0, 1500.0, 1200.0])
    return PchipInterpolator(cx, cy)(x)


@dataclass(frozen=True)
class TerrainLayout:
    """Named places of the terrain (map frame, metres)."""

    pool_x: float
    pool_y: float


def base_terrain(rng: np.random.Generator) -> tuple[Terrain, TerrainLayout]:
    """The trench before the calibrated deep features (flattened deepest point, pool).

    Depths shallower than 10 000 m are then bent (C1-smoothly) so that the map minimum is exactly
    8346 m; the floor is untouched.
    """
    x, y = grid_axes()
    X, Y = np.meshgrid(x, y)
    ya = trench_axis(x)[None, :]
    d = Y - ya  # signed distance north of the axis (approx.)

    # floor half-widths (north / south of the axis) vary along the axis
    w_n = 650.0 + 150.0 * np.sin(2 * np.pi * (X + 3000.0) / 9000.0)
    w_s = 750.0 + 200.0 * np.sin(2 * np.pi * (X - 1000.0) / 13000.0)
    u_n = _soft_ramp(d - w_n, 120.0)
    u_s = _soft_ramp(-d - w_s, 160.0)

    # floor: flat, deepening gently towards the pool south-west of the launch point
    pool_x, pool_y = -900.0, float(trench_axis(np.array([-900.0]))[0]) - 100.0
    r_pool2 = (X - pool_x) ** 2 + ((Y - pool_y) * 1.8) ** 2
    floor = 10905.0 + 17.0 * np.exp(-r_pool2 / (2 * 1600.0**2))

    # walls: steep lower wall (tanh) + long linear rise; the northern (forearc) wall is the steeper
    rise_n = 0.24 * u_n + 650.0 * np.tanh(u_n / 1300.0)
    rise_s = 0.12 * u_s + 380.0 * np.tanh(u_s / 1800.0)
    # E-W fault scarps (horst and graben) on the southern wall
    wander = spectral_noise(rng, (1, X.shape[1]), sc.MAP_RES_M, beta=3.0, k_min=1 / 8000.0)[0][None, :]
    for i, (off, h, wd) in enumerate(((1500.0, 90.0, 60.0), (3100.0, -60.0, 80.0), (4300.0, 120.0, 70.0),
                                      (6200.0, 80.0, 90.0))):
        offs = off + 250.0 * np.roll(wander, 211 * i, axis=1)
        hh = h * (1.0 + 0.4 * np.sin(2 * np.pi * X / (7000.0 + 1500.0 * i) + i))
        rise_s = rise_s + hh * 0.5 * (1 + np.tanh((u_s - offs) / wd))
    # a spur of the northern wall reaching towards the dive site from the NW
    spur = 180.0 * np.exp(-(((X - 300.0) * np.cos(0.6) + (Y - 2600.0) * np.sin(0.6)) / 900.0) ** 2
                          - (((X - 300.0) * -np.sin(0.6) + (Y - 2600.0) * np.cos(0.6)) / 2200.0) ** 2)
    depth = floor - rise_n - rise_s - spur * np.clip(u_n / 300.0, 0.0, 1.0)

    # roughness: isotropic fractal + down-slope gullies (elongated N-S); amplitude from ruggedness mask
    iso = spectral_noise(rng, X.shape, sc.MAP_RES_M, beta=3.3, k_min=1 / 4000.0)
    gully = spectral_noise(rng, X.shape, sc.MAP_RES_M, beta=3.2, stretch_y=3.0, k_min=1 / 3000.0)
    fine = spectral_noise(rng, X.shape, sc.MAP_RES_M, beta=2.4, k_min=1 / 2000.0)
    s_n = 1.0 - np.exp(-u_n / 400.0)
    s_s = 1.0 - np.exp(-u_s / 600.0)
    # most rugged to the NE and NW of the dive site (paper Fig. 5/6)
    ne = np.exp(-(((X - 3500.0) / 4500.0) ** 2 + ((Y - 3500.0) / 3500.0) ** 2))
    nw = np.exp(-(((X + 1500.0) / 4000.0) ** 2 + ((Y - 3000.0) / 3500.0) ** 2))
    a_n = s_n * (30.0 + 50.0 * ne + 45.0 * nw)
    a_s = s_s * 22.0
    depth = depth + (a_n + a_s) * (0.7 * iso + 0.7 * gully) + (0.6 + 0.08 * (a_n + a_s)) * fine

    # bend depths shallower than 10 000 m so that the minimum is exactly MAP_MIN_DEPTH_M (C1 at 10 000 m)
    dmin = float(depth.min())
    knee = 10000.0
    c = (dmin - sc.MAP_MIN_DEPTH_M) / (knee - dmin)
    depth = depth - c * np.maximum(0.0, knee - depth) ** 2 / (knee - dmin)
    return Terrain(x=x, y=y, depth=depth), TerrainLayout(pool_x=pool_x, pool_y=pool_y)


def flatten_disc(ter: Terrain, cx: float, cy: float, radius: float, level: float | None = None) -> np.ndarray:
    """Blend the terrain towards ``level`` (default: its local mean) inside a flat-topped disc (weights
    exp(-(r/radius)^8)); returns the weights."""
    X, Y = np.meshgrid(ter.x, ter.y)
    r = np.hypot(X - cx, Y - cy)
    w = np.exp(-((r / radius) ** 8))
    if level is None:
        level = float(ter.depth[w > 0.5].mean())
    ter.depth = ter.depth * (1 - w) + level * w
    return w


def gaussian_bump(ter: Terrain, cx: float, cy: float, sigma: float) -> np.ndarray:
    """Unit Gaussian (depth +1 m at the centre) on the grid."""
    X, Y = np.meshgrid(ter.x, ter.y)
    return np.exp(-((X - cx) ** 2 + (Y - cy) ** 2) / (2 * sigma**2))


def set_pool(ter: Terrain, layout: TerrainLayout) -> tuple[int, int]:
    """Make the map's deepest cell exactly MAP_MAX_DEPTH_M at the pool centre (a flattened, dimpled pool)."""
    ix = int(np.argmin(np.abs(ter.x - layout.pool_x)))
    iy = int(np.argmin(np.abs(ter.y - layout.pool_y)))
    cx, cy = float(ter.x[ix]), float(ter.y[iy])
    flatten_disc(ter, cx, cy, 350.0)
    g = gaussian_bump(ter, cx, cy, 180.0)
    ter.depth = ter.depth + (sc.MAP_MAX_DEPTH_M - ter.depth[iy, ix]) * g
    ter.depth[iy, ix] = sc.MAP_MAX_DEPTH_M
    return iy, ix
