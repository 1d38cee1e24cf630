"""Stage ``ingest``: raw vehicle logs (MCAP or CSV) -> ``sensors`` (``sensors.parquet``).

Reads the dive's sources with its vehicle channel mapping (``vehicle.yaml``; the packaged Haidou mapping
when the dive names none), converts units explicitly, aligns every sensor onto the CTD time base with
per-sensor gap limits, adds QARTOD flags (``ioos_qc``) and publishes one validated table following
``schemas/sensors.yaml``. Table metadata: dive id, vehicle, sources with SHA-256, unit conversions,
alignment and QC statistics, MCAP damage reports (messages lost) and the warnings raised while reading.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from typing import TYPE_CHECKING, Any, Literal

from pydantic import BaseModel, ConfigDict, Field

from hadal.dive import resolve_source
from hadal.errors import InputError
from hadal.ingest.build import (
    build_sensor_table,
    field_metadata,
    read_cnv_sensors,
    read_csv_sensors,
    read_mcap_sensors,
)
from hadal.ingest.qc import DEFAULT_QC, VariableQC
from hadal.ingest.vehicle import default_vehicle_config_path, load_vehicle_config
from hadal.store import sha256_file

if TYPE_CHECKING:
    from hadal.stages import StageContext
    from hadal.store import ProductVersion

PRODUCTS = ("sensors",)
UPSTREAM: tuple[str, ...] = ()


class Params(BaseModel):
    """Raw log ingest, time alignment and QARTOD QC (section ``ingest`` of config/pipeline.yaml)."""

    model_config = ConfigDict(extra="forbid")
    source: Literal["auto", "mcap", "csv", "cnv"] = Field(
        "auto", description="which raw logs to read: auto = MCAP when the dive lists one, else CSV, else "
                            "Sea-Bird .cnv (CTD only; the other sensors' columns stay empty, flag 9)")
    vehicle_config: str | None = Field(
        None, description="vehicle channel mapping (path relative to the dive directory); default: dive.yaml's "
                          "vehicle_config, else the packaged haidou mapping")
    max_gap_s: dict[str, float] = Field(
        {"gauge": 2.0, "altimeter": 1.5, "attitude": 2.0, "position": 5.0},
        description="per sensor: no interpolation across gaps longer than this (s) -> NaN + flag 9 "
                    "(raised to 1.5 sampling intervals, with a warning, when shorter than that)")
    default_max_gap_s: float = Field(2.0, gt=0, description="gap limit of sensors not listed in max_gap_s")
    qc: dict[str, VariableQC] = Field(
        default_factory=lambda: {k: v.model_copy() for k, v in DEFAULT_QC.items()},
        description="QARTOD thresholds per variable (ioos_qc gross range / spike / flat line; units of the "
                    "variable); pressure_ctd_dbar.saturation flags the SBE49 saturation (10 500 dbar) as bad")


def _vehicle_path(ctx: StageContext, p: Params) -> Path:
    rel = p.vehicle_config or ctx.dive.vehicle_config
    if rel:
        path = resolve_source(ctx.raw_dir, rel)
        if not path.is_file():
            raise InputError(f"vehicle config {rel!r} named by the dive/pipeline config does not exist in {ctx.raw_dir}")
        return path
    ctx.log.warning("dive %s names no vehicle_config; using the packaged haidou mapping", ctx.dive_id)
    return default_vehicle_config_path()


def run(ctx: StageContext) -> dict[str, ProductVersion]:
    """Read, align, QC and publish ``sensors``; see the module docstring."""
    from hadal.products import write_parquet

    p: Params = ctx.config.ingest
    vpath = _vehicle_path(ctx, p)
    vehicle = load_vehicle_config(vpath)
    src = ctx.dive.sources
    kind = p.source
    if kind == "auto":
        kind = "mcap" if src.mcap else ("csv" if src.csv or not src.cnv else "cnv")
    inputs: list[Path] = [vpath]
    mcap_reports: list[dict[str, Any]] = []
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        if kind == "mcap":
            if not src.mcap:
                raise InputError(f"dive {ctx.dive_id}: ingest.source is 'mcap' but dive.yaml lists no MCAP file")
            paths = [resolve_source(ctx.raw_dir, r) for r in src.mcap]
            for q in paths:
                if not q.is_file():
                    raise InputError(f"{q}: MCAP file listed in dive.yaml does not exist")
            sensors, mcap_reports = read_mcap_sensors(paths, vehicle)
            inputs += paths
        elif kind == "cnv":
            if not src.cnv:
                raise InputError(f"dive {ctx.dive_id}: ingest.source is 'cnv' but dive.yaml lists no .cnv file")
            paths = [resolve_source(ctx.raw_dir, r) for r in src.cnv]
            sensors = read_cnv_sensors(paths, vehicle)
            inputs += paths
        else:
            if not src.csv:
                raise InputError(f"dive {ctx.dive_id}: dive.yaml lists neither MCAP, CSV nor .cnv sensor logs")
            files = {k: resolve_source(ctx.raw_dir, r) for k, r in src.csv.items()}
            used = {s.csv.source for s in vehicle.sensors.values() if s.csv is not None}
            files = {k: v for k, v in files.items() if k in used}
            sensors = read_csv_sensors(files, vehicle)
            inputs += list(files.values())
        df, meta = build_sensor_table(sensors, vehicle, max_gap_s=p.max_gap_s,
                                      default_max_gap_s=p.default_max_gap_s, qc=p.qc)
    messages = [str(w.message) for w in caught]
    for m in messages:
        ctx.log.warning("ingest: %s", m)
    lost = [r.get("messages_lost") for r in mcap_reports]
    meta.update({
        "dive_id": ctx.dive_id,
        "vehicle": vehicle.vehicle,
        "vehicle_config": str(vpath),
        "source_kind": kind,
        "sources": [{"path": str(q), "sha256": sha256_file(q), "bytes": q.stat().st_size} for q in inputs],
        "mcap": mcap_reports,
        "messages_lost": (None if any(x is None for x in lost) else sum(lost)) if mcap_reports else 0,
        "warnings": messages,
        "rows": int(len(df)),
        "time_coverage_start": df["time"].iloc[0].isoformat(),
        "time_coverage_end": df["time"].iloc[-1].isoformat(),
    })
    with ctx.store.publish(ctx.dive_id, "sensors", parameters=ctx.params("ingest"), inputs=inputs,
                           extra={"ingest": {k: meta[k] for k in ("source_kind", "rows", "messages_lost",
                                                                  "unit_conversions")}}) as draft:
        write_parquet(df, draft.path / "sensors.parquet", fields=field_metadata(), metadata=meta,
                      provenance_from=draft)
    ctx.log.info("ingest: %d rows from %s (%s), %d warning(s)", len(df), kind, vehicle.vehicle, len(messages))
    return {"sensors": draft.result}
