"""Assemble the ``sensors`` table: read sources with the vehicle mapping, clean, align, QC, validate.

Pure library code (no store, no Prefect): :func:`read_sources` -> {sensor: SensorSamples};
:func:`build_sensor_table` -> (DataFrame following ``schemas/sensors.yaml``, metadata dict).
"""

from __future__ import annotations

import warnings
from collections.abc import Mapping, Sequence
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import yaml

from hadal.errors import InputError
from hadal.ingest.align import align_sensor, clean_times
from hadal.ingest.csv_reader import SensorSamples, read_sensor_csv, sensor_from_records
from hadal.ingest.mcap_reader import read_mcap
from hadal.ingest.qc import VariableQC, fail_fraction, qc_table
from hadal.ingest.units import CANONICAL_UNITS
from hadal.ingest.vehicle import VehicleConfig

__all__ = ["SENSOR_VARIABLES", "sensors_schema", "read_mcap_sensors", "read_csv_sensors", "read_cnv_sensors", "build_sensor_table",
           "validate_sensor_table"]

#: the variables of ``sensors.parquet`` in column order (architecture.md)
SENSOR_VARIABLES: tuple[str, ...] = tuple(CANONICAL_UNITS)


@lru_cache(maxsize=1)
def _schema_path() -> Path:
    here = Path(__file__).resolve()
    for parent in here.parents:
        p = parent / "schemas" / "sensors.yaml"
        if p.is_file():
            return p
    raise InputError("schemas/sensors.yaml (the sensors product contract) was not found next to the hadal sources")


@lru_cache(maxsize=1)
def sensors_schema() -> dict[str, Any]:
    """The ``sensors`` contract from ``schemas/sensors.yaml`` (columns with dtype/units/standard_name/long_name)."""
    return yaml.safe_load(_schema_path().read_text(encoding="utf-8"))


def field_metadata() -> dict[str, dict[str, str]]:
    """Per-column Parquet field metadata (units, standard_name, long_name) from the contract, QC columns included."""
    sch = sensors_schema()
    out: dict[str, dict[str, str]] = {}
    meanings = sch.get("qc_flag_meanings", "")
    values = " ".join(str(v) for v in sch.get("qc_flag_values", []))
    for name, col in sch["columns"].items():
        out[name] = {k: str(col[k]) for k in ("units", "standard_name", "long_name") if col.get(k)}
        if name != "time":
            out[f"{name}_qc"] = {"long_name": f"QARTOD flag of {name}", "flag_values": values,
                                 "flag_meanings": meanings, "standard_name": "quality_flag",
                                 "units": "1"}
    return out


def read_mcap_sensors(paths: Sequence[str | Path], vehicle: VehicleConfig
                      ) -> tuple[dict[str, SensorSamples], list[dict[str, Any]]]:
    """Read every sensor with an ``mcap`` mapping from the MCAP files (their messages are concatenated).

    Returns the samples and one :class:`McapReport` dict per file. A required sensor whose topic is in
    none of the files is an :class:`InputError`; an optional one is left out with a warning.
    """
    topics = {s.mcap.topic: name for name, s in vehicle.sensors.items() if s.mcap is not None}
    per_topic: dict[str, list[tuple[np.ndarray, list[dict[str, Any]], str]]] = {}
    reports = []
    for p in paths:
        data, report = read_mcap(p, topics, warn=True)
        reports.append(report.as_dict())
        for topic, tp in data.items():
            if tp.messages:
                per_topic.setdefault(topic, []).append((tp.log_time_ns, tp.messages, Path(p).name))
    out: dict[str, SensorSamples] = {}
    names = ", ".join(Path(p).name for p in paths)
    for name, s in vehicle.sensors.items():
        if s.mcap is None:
            if s.required:
                raise InputError(f"vehicle config gives no MCAP topic for the required sensor {name!r}")
            continue
        parts = per_topic.get(s.mcap.topic)
        if not parts:
            msg = f"{names}: no messages on topic {s.mcap.topic!r} (sensor {name!r})"
            if s.required:
                raise InputError(msg + " - missing required channel")
            warnings.warn(msg + "; its columns will be empty (flag 9)", stacklevel=2)
            continue
        t = np.concatenate([x[0] for x in parts])
        msgs = [m for x in parts for m in x[1]]
        out[name] = sensor_from_records(name, t, msgs, s.mcap, "mcap:" + "+".join(x[2] for x in parts))
    return out, reports


def read_csv_sensors(files: Mapping[str, Path], vehicle: VehicleConfig) -> dict[str, SensorSamples]:
    """Read every sensor with a ``csv`` mapping; ``files`` maps the dive's ``sources.csv`` keys to paths."""
    out: dict[str, SensorSamples] = {}
    for name, s in vehicle.sensors.items():
        if s.csv is None:
            if s.required:
                raise InputError(f"vehicle config gives no CSV mapping for the required sensor {name!r}")
            continue
        path = files.get(s.csv.source)
        if path is None:
            msg = f"dive.yaml sources.csv has no {s.csv.source!r} file (sensor {name!r})"
            if s.required:
                raise InputError(msg + " - missing required channel")
            warnings.warn(msg + "; its columns will be empty (flag 9)", stacklevel=2)
            continue
        out[name] = read_sensor_csv(path, s.csv, name)
    return out


def read_cnv_sensors(paths: Sequence[str | Path], vehicle: VehicleConfig) -> dict[str, SensorSamples]:
    """CTD casts from Sea-Bird ``.cnv`` files as the time-base sensor (the other sensors stay empty, flag 9).
    Several files are concatenated (their times must not overlap; duplicates are dropped by alignment)."""
    from hadal.ingest.cnv import cnv_sensor_samples, read_cnv

    if not paths:
        raise InputError("no .cnv files to read")
    parts = [cnv_sensor_samples(read_cnv(p), vehicle.time_base) for p in paths]
    if len(parts) == 1:
        return {vehicle.time_base: parts[0]}
    first = parts[0]
    merged = SensorSamples(
        vehicle.time_base, np.concatenate([x.time_ns for x in parts]),
        {k: np.concatenate([x.values[k] for x in parts]) for k in first.values},
        "+".join(x.source for x in parts), {"files": [x.stats for x in parts]},
        [c for x in parts for c in x.conversions])
    return {vehicle.time_base: merged}


def build_sensor_table(
    sensors: Mapping[str, SensorSamples],
    vehicle: VehicleConfig,
    *,
    max_gap_s: Mapping[str, float],
    default_max_gap_s: float = 2.0,
    qc: Mapping[str, VariableQC] | None = None,
    methods: Mapping[str, str] | None = None,
) -> tuple[pd.DataFrame, dict[str, Any]]:
    """Align all sensors on the time-base sensor's samples and add QARTOD flags.

    Steps: non-finite values (``inf``) -> NaN (counted); per sensor sort + de-duplicate times (counted);
    unit-mistake check (more than ``max_fail_fraction`` of a variable outside its fail span ->
    :class:`InputError`); alignment with per-sensor ``max_gap_s``; ``ioos_qc`` flags; schema validation.
    """
    from hadal.ingest.qc import DEFAULT_QC

    qc = {**DEFAULT_QC, **(qc or {})}
    base_name = vehicle.time_base
    if base_name not in sensors or len(sensors[base_name]) == 0:
        raise InputError(f"no samples from the time-base sensor {base_name!r}: cannot build the sensor table")
    meta: dict[str, Any] = {"time_base": base_name, "alignment": {}, "unit_conversions": [], "non_finite_values": {},
                            "read_stats": {}}
    cleaned: dict[str, tuple[np.ndarray, dict[str, np.ndarray]]] = {}
    for name, s in sensors.items():
        vals = {}
        for var, v in s.values.items():
            bad = np.isinf(v)
            if bad.any():
                meta["non_finite_values"][var] = int(bad.sum())
                warnings.warn(f"{s.source}: {int(bad.sum())} infinite {var} value(s) set to NaN (flag 9)", stacklevel=2)
                v = np.where(bad, np.nan, v)
            cfg = qc.get(var)
            if cfg is not None and (ff := fail_fraction(v, cfg)) > cfg.max_fail_fraction:
                lo, hi = sorted(cfg.fail_span or (np.nan, np.nan))
                raise InputError(
                    f"{s.source}: {ff:.0%} of {var} values are outside the plausible range [{lo:g}, {hi:g}] "
                    f"{CANONICAL_UNITS[var]} - wrong units in the vehicle config?")
            vals[var] = v
        t, vals, st = clean_times(s.time_ns, vals)
        if st["out_of_order"] or st["duplicates"]:
            warnings.warn(f"{s.source}: {st['out_of_order']} out-of-order and {st['duplicates']} duplicated "
                          f"time stamp(s) (sorted, duplicates dropped)", stacklevel=2)
        cleaned[name] = (t, vals)
        meta["alignment"][name] = {"source": s.source, **st}
        meta["unit_conversions"].extend(s.conversions)
        meta["read_stats"][name] = s.stats

    base_t, base_vals = cleaned[base_name]
    if base_t.size < 2:
        raise InputError(f"{sensors[base_name].source}: only {base_t.size} sample(s) from the time-base sensor")
    dt = np.diff(base_t) / 1e9
    meta["time_base_rate_hz"] = float(1.0 / np.median(dt)) if np.median(dt) > 0 else None
    columns: dict[str, np.ndarray] = {}
    for name, (t, vals) in cleaned.items():
        if name == base_name:
            for var, v in vals.items():
                columns[var] = v
            meta["alignment"][name].update({"samples": int(t.size), "method": "time base"})
            continue
        gap = float(max_gap_s.get(name, default_max_gap_s))
        # a limit shorter than the sensor's own sampling interval would blank almost every base sample
        # (a 1 Hz stream with jitter under a 1.0 s limit): widen it to 1.5 intervals and say so
        step = float(np.median(np.diff(t))) / 1e9 if t.size > 1 else 0.0
        if 1.5 * step > gap:
            warnings.warn(f"{sensors[name].source}: max_gap_s for {name!r} ({gap:g} s) is shorter than 1.5 x its "
                          f"sampling interval ({step:.3g} s); using {1.5 * step:.3g} s", stacklevel=2)
            gap = 1.5 * step
        aligned, st = align_sensor(base_t, t, vals, gap, dict(methods or {}))
        columns.update(aligned)
        meta["alignment"][name].update(st)
    n = base_t.size
    for var in SENSOR_VARIABLES:
        if var not in columns:
            columns[var] = np.full(n, np.nan)
    flags, counts = qc_table({v: columns[v] for v in SENSOR_VARIABLES}, base_t, qc)
    meta["qc_counts"] = counts
    df = pd.DataFrame({"time": pd.to_datetime(base_t, unit="ns", utc=True)})
    for var in SENSOR_VARIABLES:
        df[var] = columns[var].astype(np.float64)
    for var in SENSOR_VARIABLES:
        df[f"{var}_qc"] = flags[f"{var}_qc"].astype(np.uint8)
    validate_sensor_table(df)
    return df, meta


def validate_sensor_table(df: pd.DataFrame) -> None:
    """Validate ``df`` against ``schemas/sensors.yaml`` with pandera (column set, dtypes, unique increasing
    time, QC flag values); a failure is an :class:`InputError` with the first problem."""
    import pandera.pandas as pa

    sch = sensors_schema()
    cols: dict[str, Any] = {}
    flag_values = [int(v) for v in sch["qc_flag_values"]]
    for name, c in sch["columns"].items():
        if name == "time":
            cols[name] = pa.Column("datetime64[ns, UTC]", nullable=False, unique=True,
                                   checks=pa.Check(lambda s: s.is_monotonic_increasing, error="time not increasing"))
        else:
            cols[name] = pa.Column(c.get("dtype", "float64"), nullable=True)
            cols[f"{name}_qc"] = pa.Column("uint8", checks=pa.Check.isin(flag_values), nullable=False)
    schema = pa.DataFrameSchema(cols, strict=True, ordered=False)
    try:
        schema.validate(df, lazy=False)
    except (pa.errors.SchemaError, pa.errors.SchemaErrors) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"sensor table does not follow schemas/sensors.yaml: {first}") from None
