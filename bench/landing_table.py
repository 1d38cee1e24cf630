"""Results table like Table V of Sangekar et al. ("Results of analysis on mapped bathymetry").

Sources (any combination):
* ``--product DIR``  a published ``landing`` product version (reads landing_sites.parquet metadata/rows);
* ``--raster TIF``   a laser-bathymetry GeoTIFF (depth positive down, nodata = NaN), analysed here;
  default: the real Takuyo-Daigo raster in ../shared/data (0.10 m cells; its EPSG:4326 tag is ignored);
* ``--grids DIR``    a directory of submap_NN.nc (variable elevation_m), e.g. a laser_grids product.

Prints a Markdown table next to the paper's values, and per-submap final sites.
Usage: PYTHONPATH=src .venv/bin/python bench/landing_table.py [--product DIR] [--raster TIF] [--grids DIR]
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr

from hadal.landing import analyse_submap
from hadal.landing.sites import mapped_length_m, results_table

PAPER = {"transect_length_m": 521, "area_surveyed_m2": 794.4, "number_of_sites": 754, "mean_landing_cost": 0.28,
         "landing_cost_min": 0.15, "landing_cost_max": 0.63, "landing_cost_std": 0.13, "submaps_with_sites": 20}
DEFAULT_RASTER = Path(__file__).resolve().parents[2] / "shared" / "data" / "bathy-real" / "LAD_Takuyo_B1_raster_100mm.tif"


def read_raster(path: Path, cell_m: float = 0.1) -> xr.DataArray:
    """A laser-bathymetry raster via :func:`hadal.grid.readers.read_grid` (depth positive down, nodata 0 ->
    NaN). The Takuyo raster's EPSG:4326 tag is wrong: its cells are ``cell_m`` in a local metric frame."""
    import warnings

    from hadal.grid.readers import read_grid

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        g = read_grid(path, crs="local")
    d = np.asarray(g.values, float)
    d[d == 0.0] = np.nan
    ny, nx = d.shape
    return xr.DataArray(d, dims=("y", "x"), coords={"y": (np.arange(ny) + 0.5) * cell_m, "x": (np.arange(nx) + 0.5) * cell_m},
                        attrs={"units": "m", "positive": "down"})


def analyse(grids: dict[str, xr.DataArray]) -> tuple[pd.DataFrame, float, float]:
    frames, area, length = [], 0.0, 0.0
    for name, g in grids.items():
        r = analyse_submap(g, max_cell_fraction=0.2)  # the 0.10 m raster: explicit override of the 1/10 rule
        m = np.isfinite(r.elevation_m)
        area += float(m.sum()) * r.cell_m**2
        length += mapped_length_m(m, r.cell_m)
        s = r.sites.copy()
        s.insert(0, "submap", name)
        frames.append(s)
        print(f"{name}: {len(s)} sites in {r.timings_s['total']:.1f} s")
    return pd.concat(frames, ignore_index=True), area, length


def markdown(table: dict, title: str) -> str:
    rows = [
        ("Transect length", f"{table['transect_length_m']:.1f} m", f"{PAPER['transect_length_m']} m"),
        ("Area surveyed", f"{table['area_surveyed_m2']:.1f} sq.m.", f"{PAPER['area_surveyed_m2']} sq.m."),
        ("Submaps with a site", str(table["submaps_with_sites"]), str(PAPER["submaps_with_sites"])),
        ("Number of sites", str(table["number_of_sites"]), str(PAPER["number_of_sites"])),
        ("Mean landing cost", f"{table['mean_landing_cost']:.2f}", f"{PAPER['mean_landing_cost']:.2f}"),
        ("Landing cost range", f"{table['landing_cost_min']:.2f} - {table['landing_cost_max']:.2f}",
         f"{PAPER['landing_cost_min']:.2f} - {PAPER['landing_cost_max']:.2f}"),
        ("Landing cost Std. Dev.", f"{table['landing_cost_std']:.2f}", f"{PAPER['landing_cost_std']:.2f}"),
    ]
    out = [f"### {title}", "", "| Property | This run | Sangekar et al. Table V |", "|---|---|---|"]
    out += [f"| {a} | {b} | {c} |" for a, b, c in rows]
    return "\n".join(out)


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--product", type=Path)
    ap.add_argument("--raster", type=Path)
    ap.add_argument("--grids", type=Path)
    a = ap.parse_args()
    if a.product:
        meta = json.loads((a.product / "landing_summary.json").read_text())
        sites = pd.read_parquet(a.product / "landing_sites.parquet")
        print(markdown(meta["table_v"], f"landing product {a.product}"))
    else:
        grids: dict[str, xr.DataArray] = {}
        if a.grids:
            for f in sorted(a.grids.glob("submap_*.nc")):
                with xr.open_dataset(f) as ds:
                    grids[f.stem] = ds["elevation_m"].load()
        raster = a.raster or (DEFAULT_RASTER if not a.grids else None)
        if raster is not None:
            grids[raster.stem] = read_raster(raster)
        if not grids:
            raise SystemExit("nothing to analyse")
        sites, area, length = analyse(grids)
        print(markdown(results_table(sites, area, length), ", ".join(grids)))
    best = sites[sites["is_best"].astype(bool)]
    print("\nFinal site per submap:")
    print(best[["submap", "heading_deg", "x_m", "y_m", "radius_m", "slope_deg", "p_s", "p_f", "p_r", "c_s"]]
          .to_string(index=False, float_format=lambda v: f"{v:.2f}"))


if __name__ == "__main__":
    main()
