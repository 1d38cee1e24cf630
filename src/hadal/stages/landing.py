"""Stage `landing`: landing-site analysis of the 10 mm laser grids (Sangekar et al. §III-IV).

Reads ``laser_grids`` (one ``<name>.nc`` per laser input, whatever its name - e.g. ``submap_NN.nc`` - with
``elevation_m`` on (y, x) metres, NaN unmapped, at any regular square resolution) and publishes ``landing``:

* ``landing_sites.parquet`` — every candidate site for every heading with its costs, landing coordinate
  and ``is_best`` (the lowest-cost site of each submap);
* ``<name>_maps.nc`` — slope, protrusion height, exclusion per heading and the final site;
* ``landing_summary.json`` — the paper's Table V for the dive, plus the per-submap final sites;
* ``figures/`` — Figs. 13, 18, 19 and 21 of the dive's best submap, Fig. 19 of every submap, Fig. 25.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING

from hadal.budget import memory_limit_bytes
from hadal.errors import InputError, StageError
from hadal.forkpool import ForkPool, default_workers
from hadal.settings.landing import COARSE_CELL_LIMIT, AnalysisOptions
from hadal.settings.landing import LandingParams as Params
from hadal.stages import Stage, StageInputs

if TYPE_CHECKING:
    import numpy as np
    import pandas as pd
    import xarray as xr


def _read_submap(path: Path) -> tuple[xr.DataArray, xr.DataArray | None]:
    """Elevation and, where the laser grid has ``elevation_std_m`` and ``count``, the 1-σ uncertainty of the
    cell mean std/sqrt(count) (NaN where fewer than 2 points: the analysis uses its default sensor σ there)."""
    import numpy as np
    import xarray as xr

    sigma = None
    try:
        with xr.open_dataset(path, engine="h5netcdf") as ds:
            if "elevation_m" not in ds:
                raise InputError(f"{path.name}: no variable 'elevation_m' (have {', '.join(map(str, ds.data_vars))})")
            da = ds["elevation_m"].load()
            if "elevation_std_m" in ds and "count" in ds and set(ds["elevation_std_m"].dims) == {"y", "x"}:
                n = ds["count"].load().astype(float)
                sigma = (ds["elevation_std_m"].load() / np.sqrt(n.where(n >= 2))).transpose(*da.dims)
    except InputError:
        raise
    except Exception as exc:  # truncated / not NetCDF
        raise InputError(f"{path.name}: cannot read laser grid ({type(exc).__name__}: {exc})") from None
    if set(da.dims) != {"y", "x"}:
        raise InputError(f"{path.name}: elevation_m must be on (y, x), got {da.dims}")
    return da, sigma


def _grid_geometry(pv, files: list[Path]) -> list[tuple[float | None, int, int] | None]:
    """(cell size in m or None, cells along x, cells along y) of each laser grid ``files`` of ``pv``, as the laser
    stage recorded it in the manifest (``laser_grid_geometry``), so that no grid is opened here and again by
    :func:`run`; a version published without it: from the grid's coordinates (None if unreadable)."""
    import numpy as np
    import xarray as xr

    try:
        recorded = pv.manifest().get("laser_grid_geometry") or {}
    except (OSError, ValueError):
        recorded = {}
    out: list[tuple[float | None, int, int] | None] = []
    for f in files:
        g = recorded.get(f.name)
        if isinstance(g, dict):
            out.append((g.get("cell_m"), int(g.get("nx", 0)), int(g.get("ny", 0))))
            continue
        try:
            with xr.open_dataset(f, engine="h5netcdf") as ds:
                x = np.asarray(ds["x"].values, dtype=np.float64)
                ny = int(ds.sizes.get("y", 0))
        except Exception:  # noqa: BLE001 - unreadable grids are run()'s one-line error
            out.append(None)
            continue
        out.append(((float(np.median(np.abs(np.diff(x)))) if x.size > 1 else None), int(x.size), ny))
    return out


def _too_small(nx: int, ny: int) -> bool:
    from hadal.landing.sites import MIN_GRID_CELLS

    return nx < MIN_GRID_CELLS or ny < MIN_GRID_CELLS


def _laser_files(pv) -> list[Path]:
    """Every grid of a ``laser_grids`` version, whatever its name (laser inputs keep their file stems); only
    landing's own ``*_maps.nc`` outputs are skipped should they ever sit next to them."""
    return sorted(f for f in pv.path.glob("*.nc") if f.is_file() and not f.name.endswith("_maps.nc"))


def skip_reason(ctx) -> str | None:
    """Why ``landing`` cannot analyse this dive's laser grids, or ``None``: every grid's cells are coarser than
    ``landing.max_cell_fraction`` x the vehicle width (the [Landing Eq. 9] footprint tests need several cells across the
    vehicle). A laser-only dive with a coarse raster then publishes its grids and says why no sites were sought,
    instead of failing; ``hadal stage landing`` names the reason as an error."""
    p: Params = ctx.config.landing
    pv = ctx.optional_upstream("laser_grids")
    if pv is None:
        return None
    files = _laser_files(pv)
    geo = _grid_geometry(pv, files)
    if geo and all(g is not None and _too_small(g[1], g[2]) for g in geo):
        from hadal.landing.sites import MIN_GRID_CELLS

        shapes = ", ".join(f"{f.stem} {g[2]} x {g[1]}" for f, g in zip(files, geo, strict=True) if g is not None)
        return (f"every laser grid has fewer than {MIN_GRID_CELLS} cells along an axis ({shapes} cells): too "
                "narrow to seek a landing site")
    cells = [g[0] if g is not None else None for g in geo]
    limit = p.max_cell_fraction * p.vehicle.width_m
    if not cells or any(c is None or c <= limit * (1 + 1e-6) for c in cells):
        return None
    return (f"the laser grids' cells ({', '.join(f'{c:g}' for c in sorted(set(cells)))} m) are coarser than "
            f"landing.max_cell_fraction ({p.max_cell_fraction:g}) x the vehicle width ({p.vehicle.width_m:g} m) = "
            f"{limit:g} m; raise landing.max_cell_fraction (at most {COARSE_CELL_LIMIT:g}) to analyse them anyway")


@dataclass
class _DiveSites:
    """What the loop over the submaps gathers for the dive-wide products (pure bookkeeping, no I/O)."""

    warnings: list[str] = field(default_factory=list)
    sites: list[pd.DataFrame] = field(default_factory=list)
    finals: list[dict] = field(default_factory=list)
    mapped_area: float = 0.0
    transect: float = 0.0
    outlines: dict[str, np.ndarray] = field(default_factory=dict)
    best_overall: tuple[float, str] | None = None

    def add(self, name: str, res) -> None:
        """Add one analysed submap: its warnings, mapped area and transect length, outline, sites and final site."""
        import numpy as np

        from hadal.landing.sites import mapped_length_m

        self.warnings.extend(f"{name}: {w}" for w in res.warnings)
        mapped = np.isfinite(res.elevation_m)
        self.mapped_area += float(mapped.sum()) * res.cell_m**2
        rows_, cols_ = np.nonzero(mapped)
        self.transect += mapped_length_m(mapped, res.cell_m)
        step = max(1, int(len(rows_) // 4000))
        self.outlines[name] = np.column_stack(res.to_world(res.x_m[cols_[::step]], res.y_m[rows_[::step]]))
        sites = res.sites.copy()
        sites.insert(0, "submap", name)
        self.sites.append(sites)
        if res.best is not None:
            self.finals.append({"submap": name, **res.best})
            if self.best_overall is None or res.best["c_s"] < self.best_overall[0]:
                self.best_overall = (float(res.best["c_s"]), name)


def vehicle(p: Params):
    """The vehicle of ``landing.vehicle`` with the equations of :class:`hadal.landing.vehicle.Vehicle`."""
    from hadal.landing.vehicle import Vehicle

    return p.vehicle if isinstance(p.vehicle, Vehicle) else Vehicle(**p.vehicle.model_dump())


def _analyse_file(ctx, p: Params, f: Path, headings: np.ndarray, mem_limit, threads: int):
    """Read one laser grid, check its memory and work budget, analyse it; None (logged) when it has no mapped cells."""
    import numpy as np

    from hadal.landing.sites import analyse_submap, check_resources

    name = f.stem
    grid, sigma = _read_submap(f)
    if not np.isfinite(grid.values).any():
        ctx.log.warning("landing: %s has no mapped cells; skipped", name)
        return None
    if _too_small(grid.sizes["x"], grid.sizes["y"]):
        ctx.log.warning("landing: %s is %d x %d cells, too narrow to seek a landing site; skipped", name,
                        grid.sizes["y"], grid.sizes["x"])
        return None
    # memory and work before allocating anything of the analysis (issue 14): one-line ConfigError
    check_resources(tuple(grid.shape), len(headings), memory_limit_bytes=mem_limit,
                    work_limit=p.max_cell_headings, keep_heading_exclusion=True,
                    exclusion_step_m=p.exclusion_step_m, vehicle=vehicle(p), what=f"landing submap {name}",
                    heading_setting=("landing.heading_step_deg", p.heading_step_deg),
                    step_setting=("landing.exclusion_step_m", p.exclusion_step_m), workers=threads)
    opts = AnalysisOptions(**p.model_dump(include=set(AnalysisOptions.model_fields)))
    res = analyse_submap(grid, vehicle(p), headings_deg=headings, elevation_sigma_m=sigma, options=opts, workers=threads)
    ctx.log.info("landing: %s %d candidate sites in %.1f s", name, len(res.sites), res.timings_s["total"])
    for w in res.warnings:
        ctx.log.warning("landing: %s: %s", name, w)
    return res


def _write_submap_maps(ctx, res, path: Path, name: str) -> None:
    """``<name>_maps.nc``: slope, protrusion height, exclusion per heading and the selected site of one submap."""
    from hadal.products import dive_attributes, write_netcdf
    from hadal.products.compression import gzip_encoding

    ds = res.to_dataset()
    for v in ds.data_vars:
        ds[v].encoding.update(gzip_encoding())
    write_netcdf(ds, path, title=f"Landing-site maps, {ctx.dive_id} {name}",
                 summary="Slope, protrusion height, C_G exclusion per landing heading and the selected landing "
                         "site (Sangekar et al.).", submap=name, **dive_attributes(ctx.dive))


def _write_dive_products(ctx, p: Params, acc: _DiveSites, out: Path) -> tuple[pd.DataFrame, pd.DataFrame]:
    """``landing_sites.parquet`` (Table V in its metadata), ``landing_summary.json`` and the footprint GeoJSON;
    returns the georeferenced final sites (for the transect figure)."""
    import pandas as pd

    from hadal.landing.sites import SITE_FIELDS, results_table
    from hadal.products import write_parquet

    sites_df = pd.concat(acc.sites, ignore_index=True) if acc.sites else pd.DataFrame(columns=list(SITE_FIELDS))
    table = results_table(sites_df, acc.mapped_area, acc.transect)
    v = vehicle(p)
    meta = {"dive_id": ctx.dive_id, "critical_slope_deg": v.critical_slope_deg,
            "critical_height_m": v.critical_height_m, "table_v": table,
            "method": "Sangekar et al., Autonomous landing of underwater vehicles using high resolution bathymetry"}
    if acc.warnings:
        meta["warnings"] = acc.warnings  # e.g. grids coarser than the 1/10-width cell rule (explicit override)
    from hadal.products.geo_landing import (
        SITE_GEO_FIELDS,
        footprints_geojson,
        georeference_sites,
        strict_json,
    )

    lf = ctx.dive.laser_frame  # dive.yaml georeference of the laser frame: sites in lat/lon, footprints GeoJSON
    sites_df, finals_df = georeference_sites(sites_df, lf), georeference_sites(pd.DataFrame(acc.finals), lf)
    meta["laser_frame"] = lf.model_dump() if lf is not None else "local (not georeferenced: no laser_frame)"
    write_parquet(sites_df, out / "landing_sites.parquet", fields={**SITE_FIELDS, **SITE_GEO_FIELDS},
                  metadata=meta)
    (out / "landing_summary.json").write_text(
        strict_json({"table_v": table, "laser_frame": meta["laser_frame"],
                     "final_sites": finals_df.to_dict(orient="records")}, indent=2), encoding="utf-8")
    if (gj := footprints_geojson(sites_df, lf, p.vehicle.length_m, p.vehicle.width_m)) is not None:
        (out / "landing_footprints.geojson").write_text(strict_json(gj), encoding="utf-8")
    return sites_df, finals_df


def _write_dive_figures(ctx, acc: _DiveSites, sites_df: pd.DataFrame, finals_df: pd.DataFrame, best_res,
                        figdir: Path, pool: ForkPool) -> None:
    """Figs. 25 and 21 of the dive, Figs. 13 and 18 of its best submap (drawn by ``pool``)."""
    from hadal.landing import figures as fg

    pool.submit(fg.figure_transect, finals_df, acc.outlines, figdir / "fig25_transect.png")
    pool.submit(fg.figure_costs_vs_heading, sites_df, figdir / "fig21_costs_vs_heading.png", f"{ctx.dive_id}: all submaps")
    if best_res is not None and acc.best_overall is not None:
        best = pool.share(best_res)  # two figures of it: sent to a helper process once
        pool.submit(fg.figure_slope_exclusion, best, figdir / f"fig13_slope_{acc.best_overall[1]}.png")
        pool.submit(fg.figure_protrusion_exclusion, best, figdir / f"fig18_protrusions_{acc.best_overall[1]}.png")


def run(ctx) -> dict:
    """Analyse every laser submap and publish the ``landing`` product."""
    import numpy as np

    p: Params = ctx.config.landing
    laser = ctx.upstream("laser_grids")
    files = _laser_files(laser)
    if not files:
        raise StageError(f"{ctx.dive_id}/laser_grids/{laser.label} has no laser grids (*.nc)")
    headings = np.linspace(-90.0, 90.0, int(round(180.0 / p.heading_step_deg)) + 1)
    mem_limit = memory_limit_bytes(ctx.config)
    threads = p.workers or min(4, os.cpu_count() or 1)
    acc = _DiveSites()
    with ctx.store.publish(ctx.dive_id, "landing", parameters=ctx.params("landing"), upstream=[laser]) as draft, \
            ForkPool((p.figure_processes or default_workers()) if p.figures else 1) as pool:
        figdir = draft.path / "figures"
        if p.figures:
            figdir.mkdir()
        best_res = None
        for f in ctx.progress.track(files, "landing sites", total=len(files)):
            name = f.stem
            res = _analyse_file(ctx, p, f, headings, mem_limit, threads)
            if res is None:
                continue
            acc.add(name, res)
            if p.figures:  # drawn beside the next submap's analysis when a process is free
                from hadal.landing import figures as fg

                pool.submit(fg.figure_sites, res, figdir / f"fig19_sites_{name}.png")
                if acc.best_overall is not None and acc.best_overall[1] == name:
                    best_res = res  # only the dive's best submap is kept for the detailed figures
            _write_submap_maps(ctx, res, draft.path / f"{name}_maps.nc", name)
        sites_df, finals_df = _write_dive_products(ctx, p, acc, draft.path)
        if p.figures:
            _write_dive_figures(ctx, acc, sites_df, finals_df, best_res, figdir, pool)
        pool.results()
    return {"landing": draft.result}


STAGE = Stage(
    name="landing", products=("landing",), inputs=StageInputs(upstream=("laser_grids",)),
    options=Params, run=run, skip_reason=skip_reason,
    warm_imports=("hadal.landing.sites", "hadal.landing.figures", "hadal.products.geo_landing", "hadal.products.io",
                  "hadal.mplwarm:first_draw", "hadal.numbawarm:first_call"),
)
