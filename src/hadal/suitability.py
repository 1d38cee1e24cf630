"""Terrain suitability for matching: elevation standard deviation and terrain entropy per block.

TERCOM paper (tercom-challenger-deep.md) §3.1 and §4.1.2: the reference map is divided into an
``m x n`` grid of blocks (44 x 60 for the Challenger Deep map) and for each block, with ``z(i, j)`` its
``m x n`` cell values,

* [TERCOM Eq. 1]  ``zbar = 1/(mn) * sum z(i, j)``
* [TERCOM Eq. 2]  ``D(z) = 1/(m(n-1)) * sum (z(i, j) - zbar)^2``  -- **implemented as written**: the paper's
  normaliser is ``m(n-1)``, not the usual ``mn - 1``; for a 20 x 20 block it differs from the
  ``mn - 1`` sample variance by a factor ``(mn-1)/(m(n-1)) = 1.047``.
* [TERCOM Eq. 3]  ``sigma = sqrt(D(z))``
* [TERCOM Eq. 4]  ``H_f = - sum p_ij log p_ij`` (natural logarithm, nats)
* [TERCOM Eq. 5]  ``p_ij = z(i, j) / sum z(i, j)``

``p_ij`` must be a probability, so ``z`` must be positive: we use **depth positive down** (``depth_m``
of the DTM, ~10 000 m at the Challenger Deep), never elevation (negative below sea level). Blocks that
contain a non-positive depth (land, bad cells) get NaN entropy.

With these definitions ``H_f`` is largest (``log(mn)``) for a perfectly flat block and *decreases*
as the relative relief grows, so a **low entropy** marks an information-rich block (the paper's text:
"if the elevation value of a region changes rapidly ... the calculated local topographic entropy is
small"; its Fig. 6 caption reads the other way round). Suitable = high ``sigma`` and low ``H_f``. We
also store ``entropy_deficit = log(K) - H_f`` (K valid cells; 0 for flat terrain, grows with relief).

Missing (NaN) cells: a block is evaluated from its ``K`` valid cells when at least
``min_valid_fraction`` of it is valid; [TERCOM Eq. 2]'s normaliser then becomes ``K (n-1)/n`` (equal to
``m(n-1)`` when the block is complete) -- a deviation needed to handle holes, documented here.
"""

from __future__ import annotations

from dataclasses import dataclass, replace

import numpy as np
import xarray as xr

from hadal.errors import InputError
from hadal.matching.mapgrid import MapGrid


def block_std_entropy(z: np.ndarray, min_valid_fraction: float = 0.5) -> tuple[float, float, int]:
    """[TERCOM Eqs. 1-5] for one ``m x n`` block ``z`` (depth positive down, metres).

    Returns ``(sigma_m, entropy_nats, n_valid)``; NaN when fewer than ``min_valid_fraction`` cells are valid.
    """
    z = np.asarray(z, float)
    sig, ent, cnt = _blocks(z[None, None, :, :], min_valid_fraction)
    return float(sig[0, 0]), float(ent[0, 0]), int(cnt[0, 0])


def _blocks(b: np.ndarray, min_valid_fraction: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Vectorised [TERCOM Eqs. 1-5] over blocks ``b[by, bx, m, n]``."""
    m, n = b.shape[2], b.shape[3]
    valid = np.isfinite(b)
    k = valid.sum(axis=(2, 3))
    bz = np.where(valid, b, 0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        zbar = bz.sum(axis=(2, 3)) / k  # [TERCOM Eq. 1] over the valid cells
        dev2 = np.where(valid, (b - zbar[..., None, None]) ** 2, 0.0).sum(axis=(2, 3))
        norm = k * (n - 1) / n if n > 1 else k.astype(float)  # = m(n-1) for a complete block ([TERCOM Eq. 2])
        sigma = np.sqrt(dev2 / norm)  # [TERCOM Eqs. 2-3]
        total = bz.sum(axis=(2, 3))
        p = np.where(valid, b, 1.0) / total[..., None, None]  # [TERCOM Eq. 5]
        plogp = np.where(valid & (p > 0), p * np.log(np.where(p > 0, p, 1.0)), 0.0)
        entropy = -plogp.sum(axis=(2, 3))  # [TERCOM Eq. 4]
    ok = k >= max(1, int(np.ceil(min_valid_fraction * m * n)))
    nonpos = (np.where(valid, b, 1.0) <= 0).any(axis=(2, 3))
    sigma = np.where(ok, sigma, np.nan)
    entropy = np.where(ok & ~nonpos, entropy, np.nan)
    return sigma, entropy, k


def suitability_map(
    dtm,
    n_blocks_y: int = 44,
    n_blocks_x: int = 60,
    *,
    min_valid_fraction: float = 0.5,
) -> xr.Dataset:
    """Per-block ``std_m`` ([TERCOM Eqs. 1-3]) and ``entropy`` ([TERCOM Eqs. 4-5]) of the reference DTM on an ``n_blocks_y x n_blocks_x`` grid.

    The map is cut into equal blocks of ``floor(ny/n_blocks_y) x floor(nx/n_blocks_x)`` cells; the
    remainder rows/columns (fewer than one block) on the north/east edge are left out. Returns a
    Dataset on dims ``(by, bx)`` with block-centre coordinates ``x``/``y`` (metres, map frame), block
    bounds, ``std_m``, ``entropy``, ``entropy_deficit``, ``n_valid`` (CF attributes set).
    """
    g = MapGrid.from_any(dtm, name="dtm")
    ny, nx = g.shape
    if n_blocks_y < 1 or n_blocks_x < 1:
        raise InputError(f"number of blocks must be >= 1, got {n_blocks_y} x {n_blocks_x}")
    m, n = ny // n_blocks_y, nx // n_blocks_x
    if m < 2 or n < 2:
        raise InputError(
            f"dtm of {ny} x {nx} cells is too small for {n_blocks_y} x {n_blocks_x} blocks (need >= 2 x 2 cells per block)"
        )
    z = g.depth_m[: m * n_blocks_y, : n * n_blocks_x]
    b = z.reshape(n_blocks_y, m, n_blocks_x, n).transpose(0, 2, 1, 3)
    sigma, entropy, k = _blocks(b, min_valid_fraction)
    h = g.resolution_m
    x_edge0 = g.x_m[0] - h / 2 + np.arange(n_blocks_x) * n * h
    y_edge0 = g.y_m[0] - h / 2 + np.arange(n_blocks_y) * m * h
    xc = x_edge0 + n * h / 2
    yc = y_edge0 + m * h / 2
    with np.errstate(invalid="ignore"):
        deficit = np.log(np.maximum(k, 1)) - entropy
    ds = xr.Dataset(
        {
            "std_m": (("y", "x"), sigma, {
                "long_name": "terrain elevation standard deviation of the block (TERCOM paper Eqs. 1-3, normaliser m(n-1))",
                "units": "m", "coverage_content_type": "physicalMeasurement"}),
            "entropy": (("y", "x"), entropy, {
                "long_name": "topographic information entropy of the block (TERCOM paper Eqs. 4-5, p_ij from depth positive down)",
                "units": "1", "comment": "natural logarithm (nats); low entropy = rich terrain information"}),
            "entropy_deficit": (("y", "x"), deficit, {
                "long_name": "log(number of valid cells) minus entropy: 0 for flat terrain, larger for rougher terrain",
                "units": "1"}),
            "n_valid": (("y", "x"), k.astype(np.int32), {"long_name": "number of valid map cells in the block", "units": "1"}),
            "x_min": (("x",), x_edge0, {"long_name": "western edge of the block", "units": "m"}),
            "x_max": (("x",), x_edge0 + n * h, {"long_name": "eastern edge of the block", "units": "m"}),
            "y_min": (("y",), y_edge0, {"long_name": "southern edge of the block", "units": "m"}),
            "y_max": (("y",), y_edge0 + m * h, {"long_name": "northern edge of the block", "units": "m"}),
        },
        coords={
            "x": ("x", xc, {"long_name": "block centre easting in the dive's map frame", "units": "m",
                            "standard_name": "projection_x_coordinate", "axis": "X"}),
            "y": ("y", yc, {"long_name": "block centre northing in the dive's map frame", "units": "m",
                            "standard_name": "projection_y_coordinate", "axis": "Y"}),
        },
        attrs={"block_rows_cells": m, "block_cols_cells": n, "n_blocks_y": n_blocks_y, "n_blocks_x": n_blocks_x,
               "map_resolution_m": h, "variance_normaliser": "m(n-1) as in TERCOM paper Eq. 2"},
    )
    return ds


@dataclass(frozen=True)
class Region:
    """A rectangular matching region in the map frame (metres)."""

    x_min_m: float
    x_max_m: float
    y_min_m: float
    y_max_m: float
    mean_std_m: float
    mean_entropy: float
    score: float
    method: str

    def as_dict(self) -> dict:
        return {k: (float(v) if isinstance(v, (float, np.floating)) else v) for k, v in self.__dict__.items()}

    def contains(self, x_m, y_m) -> np.ndarray:
        x_m, y_m = np.asarray(x_m), np.asarray(y_m)
        return (x_m >= self.x_min_m) & (x_m <= self.x_max_m) & (y_m >= self.y_min_m) & (y_m <= self.y_max_m)


def propose_region(
    suit: xr.Dataset,
    center_x_m: float,
    center_y_m: float,
    size_x_m: float = 5800.0,
    size_y_m: float = 3700.0,
    search_radius_m: float = 0.0,
) -> Region:
    """Propose a terrain-matching region (TERCOM paper §4.1.2, Fig. 7: a 5.8 km x 3.7 km window near the launch point).

    Candidate windows of ``size_x_m x size_y_m`` are centred on block centres within ``search_radius_m``
    of ``(center_x_m, center_y_m)`` (radius 0: the window centred on the given point, usually the
    launch point). Each candidate is scored by the mean block ``std_m`` (maximised) with the mean
    ``entropy`` as a tie-breaker (minimised): ``score = mean_std_m - 1e-3 * mean_entropy``. The window
    is clipped to the map.
    """
    x, y = suit["x"].values, suit["y"].values
    std, ent = suit["std_m"].values, suit["entropy"].values
    xmin, xmax = float(suit["x_min"].values.min()), float(suit["x_max"].values.max())
    ymin, ymax = float(suit["y_min"].values.min()), float(suit["y_max"].values.max())
    if not (np.isfinite(center_x_m) and np.isfinite(center_y_m)):
        raise InputError("matching-region centre must be finite")
    cands = [(float(center_x_m), float(center_y_m))]
    if search_radius_m > 0:
        xx, yy = np.meshgrid(x, y)
        near = np.hypot(xx - center_x_m, yy - center_y_m) <= search_radius_m
        cands += list(zip(xx[near].tolist(), yy[near].tolist(), strict=True))
    best = None
    for cx, cy in cands:
        x0, x1 = max(cx - size_x_m / 2, xmin), min(cx + size_x_m / 2, xmax)
        y0, y1 = max(cy - size_y_m / 2, ymin), min(cy + size_y_m / 2, ymax)
        if x1 <= x0 or y1 <= y0:
            continue
        sel = ((x >= x0) & (x <= x1))[None, :] & ((y >= y0) & (y <= y1))[:, None]
        s, e = std[sel], ent[sel]
        if not np.isfinite(s).any():
            continue
        ms, me = float(np.nanmean(s)), float(np.nanmean(e)) if np.isfinite(e).any() else float("nan")
        score = ms - 1e-3 * (me if np.isfinite(me) else 0.0)
        if best is None or score > best.score:
            best = Region(x0, x1, y0, y1, ms, me, score, "window" if search_radius_m <= 0 else "max-std search")
    if best is None:
        raise InputError(
            f"no matching region of {size_x_m:.0f} x {size_y_m:.0f} m with valid blocks near ({center_x_m:.0f}, {center_y_m:.0f}) m"
        )
    return best


def block_counts(ny: int, nx: int, n_blocks_y: int, n_blocks_x: int) -> tuple[int, int]:
    """The block grid used on a ``ny x nx`` DTM: the requested one, reduced to at most ``ny // 2 x nx // 2`` blocks
    (every block needs >= 2 x 2 cells)."""
    return min(n_blocks_y, ny // 2), min(n_blocks_x, nx // 2)


def _coverage(depth_m: np.ndarray, n_evaluated: int, n_blocks: int, min_valid_fraction: float) -> str:
    return (f"{100 * float(np.isfinite(depth_m).mean()):.1f} % of the DTM's {depth_m.shape[0]} x {depth_m.shape[1]} "
            f"cells have a depth; {n_evaluated} of {n_blocks} blocks have >= {100 * min_valid_fraction:g} % valid cells")


def coverage_text(suit: xr.Dataset, depth_m: np.ndarray, min_valid_fraction: float) -> str:
    """One line naming a DTM's coverage: the share of cells with a depth and of blocks evaluated."""
    ok = np.isfinite(suit["std_m"].values)
    return _coverage(depth_m, int(ok.sum()), int(ok.size), min_valid_fraction)


def sparse_skip_reason(dtm, n_blocks_y: int, n_blocks_x: int, min_valid_fraction: float) -> str | None:
    """Why no block of the DTM can be evaluated (a DTM gridded from sparse ship soundings is mostly empty cells:
    no block reaches ``min_valid_fraction`` valid cells, the rule of :func:`suitability_map`), naming the coverage;
    ``None`` when at least one block can. Counts valid cells only (cheap: run before the stage and by the report)."""
    g = MapGrid.from_any(dtm, name="dtm")
    ny, nx = g.shape
    nby, nbx = block_counts(ny, nx, n_blocks_y, n_blocks_x)
    if nby < 1 or nbx < 1:
        return f"the DTM has only {ny} x {nx} cells (a block needs >= 2 x 2)"
    m, n = ny // nby, nx // nbx
    valid = np.isfinite(g.depth_m[: m * nby, : n * nbx]).reshape(nby, m, nbx, n).sum(axis=(1, 3))
    ok = valid >= max(1, int(np.ceil(min_valid_fraction * m * n)))
    if ok.any():
        return None
    return (f"no block of the DTM can be evaluated ({_coverage(g.depth_m, 0, int(ok.size), min_valid_fraction)}); "
            "lower suitability.min_valid_fraction or grid the soundings coarser (dtm resolution)")


def propose_region_near(
    suit: xr.Dataset,
    center_x_m: float,
    center_y_m: float,
    size_x_m: float,
    size_y_m: float,
    search_radius_m: float = 0.0,
) -> tuple[Region, str]:
    """:func:`propose_region`; when no window there holds an evaluated block (a DTM of sparse ship tracks: the
    launch point between two tracks), the window centred on the evaluated block nearest to the centre, with a
    one-line note naming the distance (``""`` otherwise). No evaluated block at all is an InputError."""
    try:
        return propose_region(suit, center_x_m, center_y_m, size_x_m, size_y_m, search_radius_m), ""
    except InputError:
        pass
    ok = np.isfinite(suit["std_m"].values)
    if not ok.any():
        raise InputError(f"no block of the DTM could be evaluated ({int(ok.size)} blocks, none with enough valid cells)")
    xx, yy = np.meshgrid(suit["x"].values, suit["y"].values)
    dist = np.hypot(xx[ok] - center_x_m, yy[ok] - center_y_m)
    i = int(np.argmin(dist))
    reg = propose_region(suit, float(xx[ok][i]), float(yy[ok][i]), size_x_m, size_y_m, 0.0)
    note = (f"no evaluated block within the {size_x_m:g} x {size_y_m:g} m window at ({center_x_m:.0f}, {center_y_m:.0f}) m; "
            f"the region is centred on the nearest evaluated block, {dist[i] / 1000:.2f} km away")
    return replace(reg, method="nearest evaluated blocks"), note
