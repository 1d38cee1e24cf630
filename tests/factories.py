"""Test and benchmark fixture factories, in one place: synthetic terrains and tracks for terrain matching, and
small synthetic products for the report and the orchestration. Not used by the pipeline.

Terrain matching (the matching tests, the accuracy study and the benchmarks in ``bench/``): the terrain
:class:`AnalyticTerrain` is an analytic function (sum of random plane waves plus Gaussian seamounts), so it can be
sampled exactly at any sub-cell position - the "truth" for the real-time measurements - while the reference map
is its cell-centre samples plus map noise; :func:`real_terrain`, :func:`simulate_case` and :func:`cut_patch` place
simulated dives on a real bathymetry grid.

Products (the report, orchestration and work-pool tests, ``bench/bench_pipeline.py``): :func:`publish_fake_products`
publishes a tiny but physically plausible dive (a 3-phase hadal dive sampled at 1 Hz, a 20 m DTM, a suitability
block grid, a TERCOM-like match and landing sites) that follows the contract in docs/architecture.md into a
store, so the report and the orchestration can be exercised without the science stages. Values are synthetic:
do not use them to validate science. :func:`browser_check` loads a report page in headless Chromium.

The sample-dive generator (:mod:`hadal.synth`, the independent ground truth of the science tests) stays apart:
these fixtures use the code under test (``MapGrid``, the product writers), which the generator must not.
Everything but numpy is imported where it is used, so importing this module stays cheap (the memory benchmark
measures its child process's peak RSS).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    import pandas as pd

    from hadal.store import ProductStore, ProductVersion

# ============================================================================== terrain matching

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


def simulate_case(g, truth, rng, kind: str = "clean", n: int | None = None, noise_frac: float | None = None,
                  walk_cells: float = 0.03):
    """One simulated dive segment with known truth on a (real) map ``g`` whose seafloor is ``truth``.

    The vehicle's dead-reckoned track ``dr`` (one sample per map cell of travel) is related to the true
    track by ``true_i = start + f R(a) (dr_i - dr_0) + w_i`` (heading error ``a`` in +-4 deg, scale ``f``
    in 1 +- 3 %, ``w`` a random walk of ``walk_cells`` cells per sample and axis (1 sigma; 0: none) plus a
    velocity bias, zero at the start); the profile is the true
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
        w = np.cumsum(rng.normal(0, 1.0, (n, 2)) * (walk_cells * h), axis=0)  # same draws for any walk_cells
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


# ============================================================================== fake products (report, orchestration)

ALL_FAKE = ("sensors", "ctd", "profile", "dtm", "suitability", "match", "landing")
LAUNCH = (11.3371167, 142.2097167)  # TERCOM paper §4.3 launch point (lat, lon)
ORIGIN = (11.33, 142.20)


def write_fake_dive(raw_dir: str | Path, dive_id: str = "fake-dive") -> Path:
    """A minimal raw dive directory (only ``dive.yaml``) for stages that read nothing raw (report)."""
    raw = Path(raw_dir)
    raw.mkdir(parents=True, exist_ok=True)
    (raw / "dive.yaml").write_text(
        f"dive_id: {dive_id}\nplatform: Haidou\n"
        f"launch: {{time_utc: 2018-10-06T23:00:00Z, latitude_deg: {LAUNCH[0]}, longitude_deg: {LAUNCH[1]}}}\n"
        f"map_frame: {{origin_latitude_deg: {ORIGIN[0]}, origin_longitude_deg: {ORIGIN[1]}}}\n",
        encoding="utf-8")
    return raw


def _terrain(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    X, Y = np.meshgrid(x, y)
    return 10905 - 0.03 * X + 0.02 * Y + 25 * np.sin(X / 300) * np.cos(Y / 250) + 8 * np.sin((X + 2 * Y) / 90)


def fake_ctd(n_descent: int = 600, n_bottom: int = 400, n_ascent: int = 500, rng: np.random.Generator | None = None) -> pd.DataFrame:
    import pandas as pd

    rng = rng or np.random.default_rng(0)
    n = n_descent + n_bottom + n_ascent
    t = pd.date_range("2018-10-06T23:00:00Z", periods=n, freq="20s")
    depth = np.concatenate([np.linspace(0, 10880, n_descent), 10880 + 10 * np.sin(np.linspace(0, 6, n_bottom)),
                            np.linspace(10880, 0, n_ascent)])
    p = depth * 1.0485
    temp = 1.45 + 20 * np.exp(-depth / 300) + 0.0001 * depth
    sal = 34.7 - 0.5 * np.exp(-depth / 400)
    alt = np.where(np.arange(n) >= n_descent, 5 + 2 * np.sin(np.arange(n) / 15), np.nan)
    alt[(np.arange(n) >= n_descent + n_bottom)] = np.nan
    seafloor = depth + alt
    phase = np.array(["descent"] * n_descent + ["bottom"] * n_bottom + ["ascent"] * n_ascent)
    return pd.DataFrame({
        "time": t, "conductivity_s_m": 3.2 + 0.1 * temp / 10 + rng.normal(0, 1e-3, n),
        "temperature_its90_degc": temp, "pressure_ctd_dbar": np.minimum(p, 10500.0), "pressure_gauge_dbar": p + 1.2,
        "altitude_m": alt, "heading_deg": np.full(n, 45.0), "pitch_deg": np.zeros(n), "roll_deg": np.zeros(n),
        "dr_east_m": np.linspace(0, 300, n), "dr_north_m": np.linspace(0, 200, n), "speed_m_s": np.full(n, 0.5),
        "pressure_dbar": p, "pressure_source": np.where(p > 10500, "gauge", "ctd"), "practical_salinity": sal,
        "density_kg_m3": 1027 + 0.0047 * depth, "gravity_m_s2": 9.7817 + 2.2e-6 * depth, "depth_m": depth,
        "sound_speed_m_s": 1500 + 0.017 * depth, "altitude_corrected_m": alt, "seafloor_depth_m": seafloor,
        "phase": phase,
    })


def _published(draft: Any) -> ProductVersion:
    """The version a finished ``store.publish`` draft made."""
    assert draft.result is not None
    return draft.result


def _publish_fake(store: ProductStore, dive: str, product: str, write) -> ProductVersion:
    """Publish one fake ``product`` of ``dive``: ``write(path)`` fills the draft directory ``path``."""
    with store.publish(dive, product, parameters={"fake": True}) as d:
        write(d.path)
    return _published(d)


def _publish_fake_sensors(store: ProductStore, dive: str, ctd: pd.DataFrame) -> ProductVersion:
    """The raw-sensor columns of the fake ``ctd`` table as the ``sensors`` product."""
    from hadal.products import write_parquet

    cols = [c for c in ctd.columns if c in ("time", "conductivity_s_m", "temperature_its90_degc", "pressure_ctd_dbar",
                                            "pressure_gauge_dbar", "altitude_m", "heading_deg", "pitch_deg",
                                            "roll_deg", "dr_east_m", "dr_north_m", "speed_m_s")]
    return _publish_fake(store, dive, "sensors",
                         lambda p: write_parquet(ctd[cols], p / "sensors.parquet", metadata={"dive": dive}))


def _publish_fake_ctd(store: ProductStore, dive: str, ctd: pd.DataFrame) -> ProductVersion:
    """The fake ``ctd`` table as the ``ctd`` product."""
    from hadal.products import write_parquet

    return _publish_fake(store, dive, "ctd", lambda p: write_parquet(ctd, p / "ctd.parquet", metadata={"dive": dive}))


def _publish_fake_profile(store: ProductStore, dive: str) -> ProductVersion:
    """A descent and an ascent temperature profile (°C) every 50 dbar as the ``profile`` product."""
    import xarray as xr

    from hadal.products import write_netcdf

    p = np.arange(5.0, 11400.0, 50.0)
    ds = xr.Dataset({"temperature_its90_degc": (("phase", "pressure_dbar"), np.vstack([1.45 + 20 * np.exp(-p / 310)] * 2))},
                    coords={"pressure_dbar": p, "phase": ["descent", "ascent"]},
                    attrs={"launch_latitude_deg": LAUNCH[0], "launch_longitude_deg": LAUNCH[1]})
    return _publish_fake(store, dive, "profile",
                         lambda path: write_netcdf(ds, path / "profile.nc", title="fake profile", summary="fake"))


def _publish_fake_dtm(store: ProductStore, dive: str, frame, x: np.ndarray, y: np.ndarray,
                      depth: np.ndarray) -> ProductVersion:
    """The terrain ``depth`` (m) on the cell centres ``x``, ``y`` (m, map frame) as the ``dtm`` product."""
    import xarray as xr

    from hadal.products import write_netcdf

    X, Y = np.meshgrid(x, y)
    lon, lat = frame.to_lonlat(X, Y)
    ds = xr.Dataset({"depth_m": (("y", "x"), depth), "count": (("y", "x"), np.full(depth.shape, 4, "i4")),
                     "lat": (("y", "x"), lat), "lon": (("y", "x"), lon),
                     "crs": ((), 0, {"crs_wkt": frame.crs.to_wkt()})}, coords={"x": x, "y": y},
                    attrs={"map_frame_origin_latitude_deg": ORIGIN[0], "map_frame_origin_longitude_deg": ORIGIN[1]})
    return _publish_fake(store, dive, "dtm", lambda p: write_netcdf(ds, p / "dtm.nc", title="fake dtm", summary="fake"))


def _publish_fake_suitability(store: ProductStore, dive: str, x: np.ndarray, y: np.ndarray,
                              depth: np.ndarray) -> ProductVersion:
    """Depth std (m) and entropy of 5 x 5 cell blocks of the terrain as the ``suitability`` product."""
    import xarray as xr

    from hadal.products import write_netcdf

    b = 5
    blk = depth[: depth.shape[0] // b * b, : depth.shape[1] // b * b].reshape(depth.shape[0] // b, b, depth.shape[1] // b, b)
    std = blk.std(axis=(1, 3))
    ent = np.log(1 + std)
    bx, by = x[: blk.shape[2] * b : b] + b * 10, y[: blk.shape[0] * b : b] + b * 10
    ds = xr.Dataset({"std_m": (("y", "x"), std), "entropy": (("y", "x"), ent)}, coords={"x": bx, "y": by},
                    attrs={"proposed_region": json.dumps({"x_min_m": 300.0, "x_max_m": 1500.0,
                                                          "y_min_m": 200.0, "y_max_m": 1200.0})})
    return _publish_fake(store, dive, "suitability",
                         lambda p: write_netcdf(ds, p / "suitability.nc", title="fake suitability", summary="fake"))


def _fake_matched_track(rng: np.random.Generator, frame, bottom: pd.DataFrame, x: np.ndarray, y: np.ndarray,
                        depth: np.ndarray, sx_m: float, sy_m: float) -> pd.DataFrame:
    """The bottom phase's DR track moved to start at ``sx_m``, ``sy_m`` (m, map frame), with the map depth
    under it (m) and a measured seafloor depth (map + N(0, 1 m))."""
    import pandas as pd

    tx = sx_m + bottom["dr_east_m"].to_numpy() - bottom["dr_east_m"].iloc[0]
    ty = sy_m + bottom["dr_north_m"].to_numpy() - bottom["dr_north_m"].iloc[0]
    tlon, tlat = frame.to_lonlat(tx, ty)
    ix = np.clip(np.searchsorted(x, tx), 0, x.size - 1)
    iy = np.clip(np.searchsorted(y, ty), 0, y.size - 1)
    return pd.DataFrame({"time": bottom["time"], "x_east_m": tx, "y_north_m": ty, "lon": tlon, "lat": tlat,
                         "depth_m": bottom["depth_m"], "seafloor_depth_m": depth[iy, ix] + rng.normal(0, 1, len(bottom)),
                         "map_depth_m": depth[iy, ix]})


def _fake_msd_surface(rng: np.random.Generator, sx_m: float, sy_m: float):
    """A TERCOM-like MSD surface (m²) on 20 m cells, a bowl with its minimum near ``sx_m``, ``sy_m`` (m)."""
    import xarray as xr

    cx, cy = np.arange(0.0, 1400.0, 20.0), np.arange(0.0, 1000.0, 20.0)
    CX, CY = np.meshgrid(cx, cy)
    msd = 1 + ((CX - sx_m) ** 2 + (CY - sy_m) ** 2) / 5e3 + rng.random(CX.shape)
    return xr.Dataset({"score": (("y", "x"), msd, {"units": "m2"})}, coords={"x": cx, "y": cy},
                      attrs={"criterion": "msd", "best_x_m": sx_m, "best_y_m": sy_m})


def _fake_fix(frame, bottom: pd.DataFrame, track: pd.DataFrame, best_score: float, sx_m: float,
              sy_m: float) -> dict[str, Any]:
    """The ``fix.json`` record of the fake match: start at ``sx_m``, ``sy_m`` (m), launch, drift (m),
    uncertainty (m) and the deepest point of the ``bottom`` phase on the matched ``track``."""
    from hadal.geo import format_position, geodesic_distance_m

    tx, ty = track["x_east_m"].to_numpy(), track["y_north_m"].to_numpy()
    tlon, tlat = track["lon"].to_numpy(), track["lat"].to_numpy()
    lx, ly = (float(v) for v in frame.to_xy(LAUNCH[1], LAUNCH[0]))
    slon, slat = (float(v) for v in frame.to_lonlat(sx_m, sy_m))
    k = int(bottom["depth_m"].idxmax())
    return {"criterion": "msd", "score": best_score, "bias_m": 3.2,
            "start": {"x_east_m": sx_m, "y_north_m": sy_m, "lat": slat, "lon": slon,
                      "position_degmin": format_position(slat, slon)},
            "launch": {"lat": LAUNCH[0], "lon": LAUNCH[1], "x_east_m": lx, "y_north_m": ly,
                       "position_degmin": format_position(*LAUNCH)},
            "drift_m": float(geodesic_distance_m(LAUNCH[1], LAUNCH[0], slon, slat)),
            "uncertainty_m": {"east": 15.0, "north": 12.0, "radial": 19.2},
            "second_optimum": {"score": best_score * 1.8, "separation_ratio": 1.8}, "mismatch": False,
            "n_samples": len(bottom), "warnings": [],
            "deepest_point": {"time": str(bottom.loc[k, "time"]), "depth_m": float(bottom.loc[k, "depth_m"]),
                              "seafloor_depth_m": float(track.loc[k, "seafloor_depth_m"]),
                              "x_east_m": float(tx[k]), "y_north_m": float(ty[k]), "lat": float(tlat[k]),
                              "lon": float(tlon[k]),
                              "position_degmin": format_position(float(tlat[k]), float(tlon[k]))}}


def _publish_fake_match(store: ProductStore, dive: str, rng: np.random.Generator, frame, ctd: pd.DataFrame,
                        x: np.ndarray, y: np.ndarray, depth: np.ndarray) -> ProductVersion:
    """A TERCOM-like ``match`` product (MSD surface, matched track, fix) starting at (700, 500) m."""
    from hadal.products import write_netcdf, write_parquet

    bottom = ctd[ctd["phase"] == "bottom"].reset_index(drop=True)
    sx, sy = 700.0, 500.0
    track = _fake_matched_track(rng, frame, bottom, x, y, depth, sx, sy)
    mds = _fake_msd_surface(rng, sx, sy)
    fix = _fake_fix(frame, bottom, track, float(mds["score"].values.min()), sx, sy)

    def write(p: Path) -> None:
        write_netcdf(mds, p / "msd_surface.nc", title="fake msd", summary="fake",
                     map_frame_origin_latitude_deg=ORIGIN[0], map_frame_origin_longitude_deg=ORIGIN[1])
        write_parquet(track, p / "matched_track.parquet")
        (p / "fix.json").write_text(json.dumps(fix, indent=2), encoding="utf-8")

    return _publish_fake(store, dive, "match", write)


def _fake_landing_sites(rng: np.random.Generator) -> pd.DataFrame:
    """One random landing site per submap and heading (-45, 0, 45°; positions and radius in m, slope in
    degrees, roughness in m), the lowest ``c_s`` of each submap marked best."""
    import pandas as pd

    rows = []
    for sm in ("submap_01", "submap_02"):
        for h in (-45.0, 0.0, 45.0):
            rows.append({"submap": sm, "heading_deg": h, "site_id": 1, "x_m": rng.uniform(0, 3), "y_m": rng.uniform(0, 3),
                         "radius_m": rng.uniform(0.3, 0.8), "slope_deg": rng.uniform(0, 10),
                         "roughness_m": rng.uniform(0, 0.02), "c_s": rng.uniform(0, 1), "is_best": False})
    sites = pd.DataFrame(rows)
    for _, g in sites.groupby("submap"):
        sites.loc[g["c_s"].idxmin(), "is_best"] = True
    return sites


def _fake_landing_maps():
    """A 3 m x 3 m elevation map (m) on 1 cm cells with a 0.5 m radius final-site flag."""
    import xarray as xr

    gx = np.arange(0.0, 3.0, 0.01)
    GX, GY = np.meshgrid(gx, gx)
    elev = 0.05 * np.sin(GX * 3) + 0.03 * np.cos(GY * 4)
    return xr.Dataset({"elevation_m": (("y", "x"), elev),
                       "final_site": (("y", "x"), ((GX - 1.5) ** 2 + (GY - 1.5) ** 2 < 0.25).astype("i1"),
                                      {"flag_values": np.array([0, 1], "i1"), "flag_meanings": "no yes"})},
                      coords={"x": gx, "y": gx},
                      attrs={"launch_latitude_deg": LAUNCH[0], "launch_longitude_deg": LAUNCH[1]})


def _publish_fake_landing(store: ProductStore, dive: str, rng: np.random.Generator) -> ProductVersion:
    """A ``landing`` product: the landing sites and the same fake maps for two submaps."""
    from hadal.products import write_netcdf, write_parquet

    sites = _fake_landing_sites(rng)
    maps = _fake_landing_maps()

    def write(p: Path) -> None:
        write_parquet(sites, p / "landing_sites.parquet")
        for sm in ("submap_01", "submap_02"):
            write_netcdf(maps, p / f"{sm}_maps.nc", title="fake landing maps", summary="fake")

    return _publish_fake(store, dive, "landing", write)


def publish_fake_products(store: ProductStore, dive: str = "fake-dive", products: Sequence[str] = ALL_FAKE,
                          seed: int = 0) -> dict[str, ProductVersion]:
    """Publish the selected fake products of ``dive``; returns ``{product: version}``."""
    from hadal.geo import LocalFrame

    rng = np.random.default_rng(seed)
    frame = LocalFrame(*ORIGIN)
    out: dict[str, ProductVersion] = {}
    ctd = fake_ctd(rng=rng)
    x = np.arange(0.0, 2000.0, 20.0)
    y = np.arange(0.0, 1600.0, 20.0)
    depth = _terrain(x, y)
    if "sensors" in products:
        out["sensors"] = _publish_fake_sensors(store, dive, ctd)
    if "ctd" in products:
        out["ctd"] = _publish_fake_ctd(store, dive, ctd)
    if "profile" in products:
        out["profile"] = _publish_fake_profile(store, dive)
    if "dtm" in products:
        out["dtm"] = _publish_fake_dtm(store, dive, frame, x, y, depth)
    if "suitability" in products:
        out["suitability"] = _publish_fake_suitability(store, dive, x, y, depth)
    if "match" in products:
        out["match"] = _publish_fake_match(store, dive, rng, frame, ctd, x, y, depth)
    if "landing" in products:
        out["landing"] = _publish_fake_landing(store, dive, rng)
    return out


_PROBE = """<script>
window.__hadalErrs = [];
window.addEventListener('error', e => window.__hadalErrs.push(String(e.message || (e.target && e.target.src
  ? 'failed to load ' + e.target.src.slice(0, 60) : e))), true);
(() => { const oe = console.error; console.error = (...a) => { window.__hadalErrs.push(a.join(' ')); oe(...a); }; })();
window.addEventListener('load', () => {
  const imgs = [...document.images];
  const d = document.createElement('pre'); d.id = 'hadal-probe';
  d.textContent = JSON.stringify({images: imgs.length,
    broken: imgs.filter(i => !(i.complete && i.naturalWidth > 0)).map(i => i.alt || i.src.slice(0, 40)),
    errors: window.__hadalErrs,
    figures: imgs.map(i => { const r = i.getBoundingClientRect(); return {alt: i.alt, natural_w: i.naturalWidth,
      natural_h: i.naturalHeight, shown_w: r.width, shown_h: r.height, dpi: parseFloat(i.dataset.dpi || 'NaN'),
      min_font_pt: parseFloat(i.dataset.minFontPt || 'NaN')}; })});
  document.body.appendChild(d);
});
</script>"""


def chromium() -> str | None:
    """Path of a headless-capable Chromium, or ``None``."""
    import shutil

    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        if p := shutil.which(name):
            return p
    return None


def browser_screenshot(html: str, png: str | Path, width: int = 1200, height: int = 3000,
                       timeout_s: float = 120.0) -> Path | None:
    """A PNG screenshot (``width`` x ``height`` CSS px window) of ``html`` rendered by headless Chromium, or ``None``
    without one."""
    import subprocess

    exe = chromium()
    if exe is None:
        return None
    png = Path(png)
    page = png.with_suffix(".html")
    page.write_text(html, encoding="utf-8")
    subprocess.run([exe, "--headless=new", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                    "--disable-dev-shm-usage", f"--user-data-dir={png.parent / 'chromium-shot-profile'}",
                    "--hide-scrollbars", f"--window-size={width},{height}", f"--screenshot={png.resolve()}",
                    page.resolve().as_uri()], capture_output=True, text=True, timeout=timeout_s, check=False)
    return png if png.is_file() else None


def browser_check(html: str, workdir: str | Path, timeout_s: float = 120.0, width: int = 1280
                  ) -> dict[str, Any] | None:
    """Load ``html`` in headless Chromium and return ``{images, broken: [...], errors: [...], figures: [...]}``
    (images that did not decode, script errors and console.error messages; per image its natural and displayed
    size and its ``data-dpi``/``data-min-font-pt``, in a ``width`` CSS px wide window), or ``None`` when no Chromium
    is installed."""
    import re
    import subprocess

    exe = chromium()
    if exe is None:
        return None
    page = Path(workdir) / "report_probe.html"
    probed = html.replace("<head>", "<head>" + _PROBE, 1) if "<head>" in html else _PROBE + html
    page.write_text(probed, encoding="utf-8")
    out = subprocess.run([exe, "--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                          f"--user-data-dir={Path(workdir) / 'chromium-profile'}", "--virtual-time-budget=10000", f"--window-size={int(width)},2000",
                          "--dump-dom", page.resolve().as_uri()], capture_output=True, text=True,
                         timeout=timeout_s, check=False)
    m = re.search(r'<pre id="hadal-probe">(.*?)</pre>', out.stdout, re.S)
    if not m:
        raise RuntimeError(f"chromium gave no probe result (rc {out.returncode}): {out.stderr[-500:]}")
    import html as _html

    return json.loads(_html.unescape(m.group(1)))
