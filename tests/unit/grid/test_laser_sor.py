"""Statistical outlier removal of laser clouds (:func:`hadal.grid.laser.sor_outlier_mask`, issue 19: the laser stage's
SOR was its largest cost) against the oracle it replaces: open3d's ``PointCloud.remove_statistical_outlier``.

The compiled grid search must flag exactly the points open3d removes, on real clouds written by others (the Takuyo
laser raster's cell centres with particle returns added; the EX1604 multibeam soundings in metres) and on the
awkward kinds: coincident points (open3d removes a point whose k neighbours are all at distance 0), a vertical wall,
a line, coordinates far from the origin, clustered density, a cloud of k + 1 points."""

from __future__ import annotations

import numpy as np
import pytest

from hadal.grid.laser import _open3d_sor_mask, filter_cloud, sor_outlier_mask


def _with_particles(p: np.ndarray, rng, frac: float = 0.01, height: float = 0.5) -> np.ndarray:
    """``p`` plus isolated returns up to ``height`` m above random points (particles in the water column)."""
    idx = rng.choice(len(p), max(int(frac * len(p)), 1), replace=False)
    q = p[idx] + np.column_stack([rng.normal(0, 0.05, idx.size), rng.normal(0, 0.05, idx.size),
                                  rng.uniform(0.05, height, idx.size)])
    return np.concatenate([p, q])


def _check(p: np.ndarray, k: int = 20, std_ratio: float = 3.0) -> np.ndarray:
    ref = _open3d_sor_mask(p, k, std_ratio)
    got = sor_outlier_mask(p, k, std_ratio)
    assert got.shape == ref.shape
    np.testing.assert_array_equal(got, ref)
    return got


def test_real_takuyo_laser_cloud_with_particles(takuyo):
    z = np.asarray(takuyo.values, float)
    yy, xx = np.meshgrid(np.asarray(takuyo[takuyo.dims[0]].values, float),
                         np.asarray(takuyo[takuyo.dims[1]].values, float), indexing="ij")
    ok = np.isfinite(z)
    p = np.column_stack([xx[ok], yy[ok], -z[ok]])  # elevation up
    rng = np.random.default_rng(19)
    p = p + rng.normal(0, 0.003, p.shape)  # a raster's lattice is a degenerate cloud: jitter as real returns are
    flagged = _check(_with_particles(p, rng))
    assert 0 < flagged.sum() < 0.1 * len(flagged)
    for k, r in ((8, 2.0), (30, 1.0)):
        _check(p, k, r)


def test_real_multibeam_soundings(shared_data):
    from hadal.geo import LocalFrame
    from hadal.grid.readers import read_gsf

    df = read_gsf(shared_data / "bathy-real" / "0029_20160323_185603_EX1604_MB.gsf.mb121")
    frame = LocalFrame(float(df["latitude_deg"].mean()), float(df["longitude_deg"].mean()))
    x, y = frame.to_xy(df["longitude_deg"].to_numpy(), df["latitude_deg"].to_numpy())
    _check(np.column_stack([x, y, -df["depth_m"].to_numpy()]), 16, 2.0)


@pytest.mark.parametrize("kind", ["duplicates", "wall", "line", "far", "clustered", "tiny", "surface"])
def test_awkward_clouds(kind):
    rng = np.random.default_rng(7)
    n = 20_000
    xy = rng.uniform(0, 2.0, (n, 2))
    p = np.column_stack([xy, 0.05 * np.sin(3 * xy[:, 0]) + rng.normal(0, 0.002, n)])
    if kind == "duplicates":  # 30 copies of some points: their 20 neighbours sit at distance 0
        p = np.concatenate([p, np.repeat(p[:50], 30, axis=0), p[50:60]])
    elif kind == "wall":  # a vertical wall in x-z
        p = np.column_stack([xy[:, 0], rng.normal(0, 0.002, n), xy[:, 1]])
    elif kind == "line":
        t = rng.uniform(0, 5.0, n)
        p = np.column_stack([t, 2 * t, 0.1 * t])
    elif kind == "far":  # UTM-sized coordinates
        p = p + np.array([512_345.0, 4_123_456.0, -3000.0])
    elif kind == "clustered":  # a dense blob: the grid falls back to open3d
        p = np.concatenate([p, rng.normal(1.0, 1e-4, (3000, 3))])
    elif kind == "tiny":
        p = p[:21]
    _check(_with_particles(p, rng))


def test_filter_cloud_uses_it():
    rng = np.random.default_rng(3)
    p = _with_particles(np.column_stack([rng.uniform(0, 1, (5000, 2)), rng.normal(0, 0.001, 5000)]), rng)
    pts, cand, info = filter_cloud(p, sor_neighbors=20, sor_std_ratio=3.0)
    np.testing.assert_array_equal(cand, _open3d_sor_mask(p, 20, 3.0))
    assert info["n_sor_candidates"] == int(cand.sum()) > 0


@pytest.mark.parametrize("kind", ["random", "lattice", "clustered", "line", "three"])
def test_nearest_neighbour_equals_scipy(kind):
    """:func:`hadal.grid.laser.nearest_neighbour_m` (the ``laser_resolution_m: auto`` spacing) against scipy's k-d tree."""
    from scipy.spatial import cKDTree

    from hadal.grid.laser import nearest_neighbour_m

    rng = np.random.default_rng(11)
    xy = rng.uniform(0, 3.0, (30_000, 2))
    if kind == "lattice":  # a raster's points, jittered
        g = np.arange(0, 2.0, 0.01)
        xy = np.column_stack([a.ravel() for a in np.meshgrid(g, g)]) + rng.normal(0, 1e-4, (g.size**2, 2))
    elif kind == "clustered":  # a dense blob: scipy fallback
        xy = np.concatenate([xy, rng.normal(1.0, 1e-5, (5000, 2))])
    elif kind == "line":
        t = rng.uniform(0, 5, 10_000)
        xy = np.column_stack([t, 0.5 * t])
    elif kind == "three":
        xy = xy[:3]
    d, _ = cKDTree(xy).query(xy, k=2)
    np.testing.assert_array_equal(nearest_neighbour_m(xy), d[:, 1])


def test_nearest_neighbour_on_the_real_laser_raster(takuyo):
    from scipy.spatial import cKDTree

    from hadal.grid.laser import nearest_neighbour_m

    z = np.asarray(takuyo.values, float)
    yy, xx = np.meshgrid(np.asarray(takuyo[takuyo.dims[0]].values, float),
                         np.asarray(takuyo[takuyo.dims[1]].values, float), indexing="ij")
    ok = np.isfinite(z)
    xy = np.column_stack([xx[ok], yy[ok]]) + np.random.default_rng(2).normal(0, 0.01, (int(ok.sum()), 2))
    d, _ = cKDTree(xy).query(xy, k=2)
    np.testing.assert_array_equal(nearest_neighbour_m(xy), d[:, 1])


def test_no_numba_threading_warning_next_to_open3d(tmp_path):
    """open3d loads an older TBB; numba's parallel kernels (the laser outlier filter run first, as in the laser stage's
    own process, then gridding and the spike test) must not warn about it."""
    import subprocess
    import sys

    code = ("import numpy as np, open3d\n"
            "from hadal.grid.multibeam import knn_spike_mask\n"
            "from hadal.grid.laser import grid_laser\n"
            "rng = np.random.default_rng(0)\n"
            "x, y = rng.uniform(0, 100, 3000), rng.uniform(0, 100, 3000)\n"
            "grid_laser(np.column_stack([x / 100, y / 100, rng.normal(0, 1e-3, 3000)]), 0.05)\n"
            "knn_spike_mask(x, y, rng.normal(size=3000))\n")
    env = {k: v for k, v in __import__("os").environ.items() if not k.startswith("NUMBA_THREADING")}
    out = subprocess.run([sys.executable, "-W", "error::Warning", "-c", code], capture_output=True, text=True,
                         env=env, cwd=tmp_path, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
