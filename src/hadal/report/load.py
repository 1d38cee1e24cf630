"""Read whichever products of a dive exist, defensively, for the report.

Every product is optional: a missing product, an unreadable file or a missing column becomes a *note*
(shown in the report) instead of an exception. :func:`load_products` raises only when the dive has no
product at all.
"""

from __future__ import annotations

import json
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import pandas as pd
import xarray as xr

from hadal.errors import StageError
from hadal.store import ProductStore, ProductVersion

#: (product, stage that makes it) in pipeline order; the report reads all of them when present.
REPORT_INPUTS: tuple[tuple[str, str], ...] = (
    ("sensors", "ingest"), ("ctd", "derive"), ("profile", "derive"), ("dtm", "dtm"),
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
    #: underway records (derive's ``trajectory``): (trajectory.json entry, its CF trajectory dataset)
    trajectories: list[tuple[dict[str, Any], xr.Dataset]] = field(default_factory=list)

    @property
    def missing(self) -> list[str]:
        return [p for p, _ in REPORT_INPUTS if p not in self.versions]

    def note(self, text: str) -> None:
        if text not in self.notes:
            self.notes.append(text)


def _table_notes(path: Path) -> list[str]:
    """The ``notes`` a stage recorded in a Parquet product's table metadata (loud data problems: times out of
    the dive's window, rejected samples, ...); none when the file or its metadata cannot be read."""
    try:
        from hadal.products.io import read_parquet_metadata

        meta, _ = read_parquet_metadata(path)
    except Exception:  # noqa: BLE001 - the table itself is read (and its problems noted) separately
        return []
    notes = meta.get("notes") if isinstance(meta, dict) else None
    return [str(n) for n in notes] if isinstance(notes, list) else []


def _read(pv: ProductVersion, name: str, dp: DiveProducts, reader: Callable[[Path], Any],
          errors: tuple[type[BaseException], ...] = (Exception,)) -> Any:
    """``reader(path)`` of the file ``name`` of ``pv``, or None with a note in ``dp`` when the file is missing or
    ``reader`` raises one of ``errors`` (a corrupt/truncated file: reported, never failing the report)."""
    path = pv.path / name
    if not path.is_file():
        dp.note(f"{pv.product}/{pv.label} has no {name}")
        return None
    try:
        return reader(path)
    except errors as exc:
        dp.note(f"{pv.product}/{pv.label}/{name} is unreadable ({type(exc).__name__})")
        return None


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
    whose absence is noted). A dive with no product at all is a :class:`StageError` (any
    source file makes ingest, dtm or laser run, so that means the pipeline has not run).
    """
    versions = latest_versions(store, dive, pins)
    if not versions:
        raise StageError(
            f"dive {dive!r} has no products in {store.root}; run the pipeline first (hadal run RAW_DIR --store {store.root})"
        )
    dp = DiveProducts(dive=dive, versions=versions)
    for product, stage in REPORT_INPUTS:
        if product not in versions and stage not in (skipped_stages or set()) and (expected is None
                                                                                   or product in expected):
            dp.note(f"product {product!r} is missing (stage {stage} has not run): its figures are skipped")
    if "sensors" in versions:
        _check_parquet(versions["sensors"], "sensors.parquet", dp)  # its notes below; its table is not drawn
        for n in _table_notes(versions["sensors"].path / "sensors.parquet"):
            dp.note(f"ingest: {n}")
    if "ctd" in versions:
        dp.ctd = _read_parquet(versions["ctd"], "ctd.parquet", dp)
    if "profile" in versions:
        dp.profile = _read_netcdf(versions["profile"], "profile.nc", dp)
    if "dtm" in versions:
        dp.dtm = _read_netcdf(versions["dtm"], "dtm.nc", dp)
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
        dp.landing_figures = sorted((pv.path / "figures").glob("*.png")) if (pv.path / "figures").is_dir() else []
        dp.landing_maps = sorted(pv.path.glob("*_maps.nc"))
        try:
            dp.landing_meta = dict(pv.manifest().get("parameters") or {})
        except (OSError, ValueError):
            dp.landing_meta = {}
    return dp
