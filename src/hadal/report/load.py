"""Read whichever products of a dive exist, defensively, for the report.

Every product is optional: a missing product, an unreadable file or a missing column becomes a *note*
(shown in the report) instead of an exception. :func:`load_products` raises only when the dive has no
product at all and no run plan says why (the report stage passes the plan: it always publishes).

Only files of the product versions read are opened, and only after the store's checks: a version outside its
place in the store, holding a symbolic link or a file its manifest does not list is left out with a note
(:meth:`ProductStore.check_layout`); every file read or embedded is first verified against the SHA-256 its
manifest recorded (:meth:`ProductStore.verified_file`), so a symlinked or edited file never reaches report.html.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd
import xarray as xr

from hadal.errors import StageError, StoreError
from hadal.store import ProductStore, ProductVersion

#: (product, stage that makes it) in pipeline order; the report reads all of them when present.
REPORT_INPUTS: tuple[tuple[str, str], ...] = (
    ("sensors", "ingest"), ("ctd", "derive"), ("profile", "profile"), ("dtm", "dtm"),
    ("laser_grids", "laser"), ("suitability", "suitability"), ("match", "match"), ("landing", "landing"),
)
#: products made only when the data calls for them (external Sea-Bird casts): read when present, never "missing"
REPORT_OPTIONAL: tuple[tuple[str, str], ...] = (("casts", "ingest"), ("cast_profiles", "derive"),
                                                ("navigation", "match"), ("trajectory", "derive"))


@dataclass
class DiveProducts:
    """The products of one dive that the report could read (``None`` where absent)."""

    dive: str
    versions: dict[str, ProductVersion] = field(default_factory=dict)
    notes: list[str] = field(default_factory=list)
    ctd: pd.DataFrame | None = None
    profile: xr.Dataset | None = None
    dtm: xr.Dataset | None = None
    suitability: xr.Dataset | None = None
    msd: xr.Dataset | None = None
    track: pd.DataFrame | None = None
    fix: dict[str, Any] | None = None
    landing_sites: pd.DataFrame | None = None
    landing_summary: dict[str, Any] | None = None
    landing_figures: list[Path] = field(default_factory=list)
    landing_maps: list[Path] = field(default_factory=list)
    launch: dict[str, float] | None = None  # {"lat", "lon"} of the dive's launch point, when known
    casts: list[dict[str, Any]] = field(default_factory=list)  # external casts: casts.json + cast_profiles.json
    navigation: pd.DataFrame | None = None  # best position of every sample (match's navigation product)
    landing_meta: dict[str, Any] = field(default_factory=dict)  # landing manifest parameters (vehicle geometry)
    store: ProductStore | None = field(default=None, repr=False)  # where the versions are verified before reads
    #: the laser grids drawn (at most :data:`MAX_LASER_FIGURES`, thinned to :data:`LASER_FIGURE_CELLS` a side)
    laser_grids: list[tuple[str, xr.Dataset]] = field(default_factory=list)
    #: per laser grid (all of them): name, extent (m, its own frame), elevation range, cells, resolution
    laser_info: list[dict[str, Any]] = field(default_factory=list)
    #: the sensor channels ingest found dead (all fill values / out of range): variable -> reason, flag, source
    dead_channels: dict[str, Any] = field(default_factory=dict)
    #: underway records (derive's ``trajectory``): (trajectory.json entry, its CF trajectory dataset)
    trajectories: list[tuple[dict[str, Any], xr.Dataset]] = field(default_factory=list)

    @property
    def missing(self) -> list[str]:
        return [p for p, _ in REPORT_INPUTS if p not in self.versions]

    def note(self, text: str) -> None:
        if text not in self.notes:
            self.notes.append(text)


def _table_meta(path: Path) -> dict[str, Any]:
    """A Parquet product's table metadata (its ``notes``: loud data problems such as times out of the dive's window,
    rejected samples, dead channels); empty when the file or its metadata cannot be read."""
    try:
        from hadal.products.io import read_parquet_metadata

        meta, _ = read_parquet_metadata(path)
    except Exception:  # noqa: BLE001 - the table itself is read (and its problems noted) separately
        return {}
    return meta if isinstance(meta, dict) else {}


def _read(pv: ProductVersion, name: str, dp: DiveProducts, reader: Callable[[Path], Any],
          errors: tuple[type[BaseException], ...] = (Exception,)) -> Any:
    """``reader(path)`` of the file ``name`` of ``pv``, or None with a note in ``dp`` when the file is missing or
    ``reader`` raises one of ``errors`` (a corrupt/truncated file: reported, never failing the report)."""
    path = _verified(pv, name, dp)
    if path is None:
        return None
    try:
        return reader(path)
    except errors as exc:
        dp.note(f"{pv.product}/{pv.label}/{name} is unreadable ({type(exc).__name__})")
        return None


def _verified(pv: ProductVersion, name: str, dp: DiveProducts) -> Path | None:
    """The file ``name`` of ``pv`` once the store verified it (listed, confined, SHA-256 as published), else None
    with a note: ``has no`` when it is not there, ``is unreadable (why)`` when it fails a check."""
    store = dp.store if dp.store is not None else ProductStore(pv.path.parent.parent.parent)
    try:
        return store.verified_file(pv, name)
    except StoreError as exc:
        if "has no file" in str(exc) or "is missing" in str(exc):
            dp.note(f"{pv.product}/{pv.label} has no {name}")
        else:
            dp.note(f"{pv.product}/{pv.label}/{name} is unreadable ({exc})")
        return None


def _listed(pv: ProductVersion, dp: DiveProducts, keep: Callable[[str], bool]) -> list[Path]:
    """Verified files of ``pv`` whose manifest name satisfies ``keep``, in name order."""
    try:
        names = sorted(str(f.get("name")) for f in pv.manifest().get("files", []) if isinstance(f, dict))
    except (OSError, ValueError):
        return []
    return [p for n in names if keep(n) and (p := _verified(pv, n, dp)) is not None]


def _read_parquet(pv: ProductVersion, name: str, dp: DiveProducts) -> pd.DataFrame | None:
    return _read(pv, name, dp, pd.read_parquet)


def _check_parquet(pv: ProductVersion, name: str, dp: DiveProducts) -> None:
    """Note a Parquet file of ``pv`` that is missing or whose footer (schema, row groups) does not read, without
    loading its table: for products the report lists but draws nothing from (``sensors``: the figures read the
    calibrated ``ctd`` table)."""
    import pyarrow.parquet as pq

    _read(pv, name, dp, pq.read_metadata)


def _load_netcdf(path: Path) -> xr.Dataset:
    with xr.open_dataset(path, engine="h5netcdf") as ds:
        return ds.load()


def _read_netcdf(pv: ProductVersion, name: str, dp: DiveProducts) -> xr.Dataset | None:
    return _read(pv, name, dp, _load_netcdf)


def _read_json(pv: ProductVersion, name: str, dp: DiveProducts) -> dict[str, Any] | None:
    data = _read(pv, name, dp, lambda path: json.loads(path.read_text(encoding="utf-8")), (OSError, ValueError))
    return data if isinstance(data, dict) else None


#: laser grids drawn in the report (one map each); the others are listed in the summary with a note
MAX_LASER_FIGURES = 6
#: a laser grid is thinned (every k-th cell) to at most this many cells a side for its map
LASER_FIGURE_CELLS = 800


def _laser_grid_info(name: str, ds: xr.Dataset) -> dict[str, Any]:
    """Name, extent (cell edges, m, in the grid's own frame), elevation range, size and resolution of one grid."""
    import numpy as np

    x, y = ds["x"].values, ds["y"].values
    dx = float(np.median(np.diff(x))) if x.size > 1 else float(ds.attrs.get("resolution_m", 0.0) or 0.0)
    dy = float(np.median(np.diff(y))) if y.size > 1 else dx
    z = ds["elevation_m"].values
    fin = np.isfinite(z)
    return {"name": name, "x_range_m": [float(x.min() - abs(dx) / 2), float(x.max() + abs(dx) / 2)],
            "y_range_m": [float(y.min() - abs(dy) / 2), float(y.max() + abs(dy) / 2)],
            "elevation_range_m": [float(z[fin].min()), float(z[fin].max())] if fin.any() else None,
            "cells": [int(y.size), int(x.size)], "mapped_cells": int(fin.sum()),
            "resolution_m": float(ds.attrs.get("resolution_m", abs(dx)) or abs(dx)),
            "source_file": ds.attrs.get("source_file"), "crs_kind": ds.attrs.get("source_crs_kind")}


def _read_laser_grids(pv: ProductVersion, dp: DiveProducts) -> None:
    """The ``laser_grids`` product's grids (``*.nc``, ``*.zarr``): :attr:`DiveProducts.laser_info` for every one,
    the first :data:`MAX_LASER_FIGURES` thinned into :attr:`DiveProducts.laser_grids` for their maps."""
    import numpy as np

    files = sorted([*pv.path.glob("*.nc"), *pv.path.glob("*.zarr")])
    for path in files:
        name = path.name.removesuffix(".nc").removesuffix(".zarr")
        try:
            with (xr.open_zarr(path) if path.suffix == ".zarr" else xr.open_dataset(path)) as ds:
                if "elevation_m" not in ds or not {"x", "y"} <= set(ds["elevation_m"].dims):
                    dp.note(f"laser grid {path.name} has no elevation_m(y, x): not drawn")
                    continue
                k = max(1, int(np.ceil(max(ds.sizes["x"], ds.sizes["y"]) / LASER_FIGURE_CELLS)))
                small = ds[["elevation_m"]].isel(x=slice(None, None, k), y=slice(None, None, k)).load()
                small.attrs = {a: ds.attrs[a] for a in ("resolution_m", "source_file", "source_crs_kind",
                                                        "source_crs_name", "submap") if a in ds.attrs}
                small.attrs["thinned_by"] = k
                info = _laser_grid_info(name, ds)  # the full grid's extent and range, not the thinned copy's
                if k > 1:
                    info["drawn_every_nth_cell"] = k
        except (OSError, ValueError, KeyError, RuntimeError) as exc:
            dp.note(f"laser grid {path.name} could not be read ({type(exc).__name__}: {exc})")
            continue
        dp.laser_info.append(info)
        if len(dp.laser_grids) < MAX_LASER_FIGURES:
            dp.laser_grids.append((name, small))
    if len(dp.laser_info) > MAX_LASER_FIGURES:
        dp.note(f"{len(dp.laser_info)} laser grids: the first {MAX_LASER_FIGURES} are drawn, all are listed in "
                "summary.json (laser_grids)")


def latest_versions(store: ProductStore, dive: str, pins: dict[str, ProductVersion] | None = None
                    ) -> dict[str, ProductVersion]:
    """The version of every report input product that exists: the run's pinned one, else the latest."""
    pins = pins or {}
    return {p: pins.get(p) or store.latest(dive, p) for p, _ in (*REPORT_INPUTS, *REPORT_OPTIONAL)
            if p in pins or store.has(dive, p)}


def load_products(store: ProductStore, dive: str, skipped_stages: set[str] | None = None,
                  pins: dict[str, ProductVersion] | None = None, expected: set[str] | None = None) -> DiveProducts:
    """Load every available product of ``dive``.

    ``skipped_stages``: stages the dive's data does not support (the report lists them with the reason, so
    their missing products get no note here; ``expected``: the products the run's plan makes, the only ones
    whose absence is noted). Without any product: when called with the run's plan (``skipped_stages`` given, as the
    report stage does) an empty :class:`DiveProducts` with a note - the report still says what was found, read,
    skipped and failed; without it (``hadal report DIVE`` on a store the pipeline never wrote) a
    :class:`StageError`.
    """
    versions = latest_versions(store, dive, pins)
    if not versions and skipped_stages is None:
        raise StageError(
            f"dive {dive!r} has no products in {store.root}; run the pipeline first (hadal run RAW_DIR --store {store.root})"
        )
    dp = DiveProducts(dive=dive, store=store)
    left_out = set()
    for product, pv in versions.items():  # only versions laid out as published are read (no link, no added file)
        try:
            store.check_layout(pv)
        except StoreError as exc:
            dp.note(f"product {product!r} is left out: {exc}")
            left_out.add(product)
            continue
        dp.versions[product] = pv
    versions = dp.versions
    if not versions:
        dp.note("no product was published upstream: the stages below failed or were skipped, with the reasons")
    for product, stage in REPORT_INPUTS:
        if (product not in versions and product not in left_out and stage not in (skipped_stages or set())
                and (expected is None or product in expected)):
            dp.note(f"product {product!r} is missing (stage {stage} has not run): its figures are skipped")
    if "sensors" in versions:
        _check_parquet(versions["sensors"], "sensors.parquet", dp)  # its notes below; its table is not drawn
        sensors = _verified(versions["sensors"], "sensors.parquet", DiveProducts(dive=dive, store=store))
        smeta = _table_meta(sensors) if sensors is not None else {}
        for n in smeta.get("notes") or []:
            dp.note(f"ingest: {n}")
        if isinstance(smeta.get("dead_channels"), dict):
            dp.dead_channels = {k: {f: v.get(f) for f in ("reason", "qartod_flag", "source", "hint")
                                    if isinstance(v, dict) and v.get(f) is not None}
                                for k, v in smeta["dead_channels"].items()}
    if "ctd" in versions:
        dp.ctd = _read_parquet(versions["ctd"], "ctd.parquet", dp)
    if "profile" in versions:
        dp.profile = _read_netcdf(versions["profile"], "profile.nc", dp)
        if dp.profile is not None:  # a ragged-array profile file: back to the (cast, level) layout the figures use
            from hadal.products.dsg import orthogonal_profile

            dp.profile = orthogonal_profile(dp.profile)
    if "dtm" in versions:
        dp.dtm = _read_netcdf(versions["dtm"], "dtm.nc", dp)
    if "laser_grids" in versions:
        _read_laser_grids(versions["laser_grids"], dp)
    if "suitability" in versions:
        dp.suitability = _read_netcdf(versions["suitability"], "suitability.nc", dp)
    if "match" in versions:
        pv = versions["match"]
        dp.fix = _read_json(pv, "fix.json", dp)
        dp.msd = _read_netcdf(pv, "msd_surface.nc", dp)
        dp.track = _read_parquet(pv, "matched_track.parquet", dp)
    if "navigation" in versions:
        dp.navigation = _read_parquet(versions["navigation"], "navigation.parquet", dp)
    if "cast_profiles" in versions:
        derived = _read_json(versions["cast_profiles"], "cast_profiles.json", dp) or {}
        listed = (_read_json(versions["casts"], "casts.json", dp) or {}) if "casts" in versions else {}
        info = {c.get("cast_id"): c for c in listed.get("casts", []) if isinstance(c, dict)}
        dp.casts = [{**info.get(c.get("cast_id"), {}), **c} for c in derived.get("casts", []) if isinstance(c, dict)]
    if "trajectory" in versions:
        index = _read_json(versions["trajectory"], "trajectory.json", dp) or {}
        for rec in index.get("records", []):
            if isinstance(rec, dict) and isinstance(rec.get("file"), str):
                ds = _read_netcdf(versions["trajectory"], rec["file"], dp)
                if ds is not None:
                    dp.trajectories.append((rec, ds))
    if "landing" in versions:
        pv = versions["landing"]
        dp.landing_sites = _read_parquet(pv, "landing_sites.parquet", dp)
        if (pv.path / "landing_summary.json").is_file():
            dp.landing_summary = _read_json(pv, "landing_summary.json", dp)
        dp.landing_figures = _listed(pv, dp, lambda n: n.startswith("figures/") and n.endswith(".png")
                                     and n.count("/") == 1)
        dp.landing_maps = _listed(pv, dp, lambda n: "/" not in n and n.endswith("_maps.nc"))
        try:
            dp.landing_meta = dict(pv.manifest().get("parameters") or {})
        except (OSError, ValueError):
            dp.landing_meta = {}
    return dp
