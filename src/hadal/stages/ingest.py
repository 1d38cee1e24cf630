"""Stage ``ingest``: raw vehicle logs (MCAP or CSV) -> ``sensors`` (``sensors.parquet``).

Reads the dive's sources with its vehicle channel mapping (``vehicle.yaml``; the packaged Haidou mapping
when the dive names none), converts units explicitly, aligns every sensor onto the CTD time base with
per-sensor gap limits, adds QARTOD flags (``ioos_qc``) and publishes one validated table following
``schemas/sensors.yaml``. Table metadata: dive id, vehicle, sources with SHA-256, unit conversions,
alignment and QC statistics, MCAP damage reports (messages lost) and the warnings raised while reading.

Sources: vehicle logs (MCAP, else CSV) make ``sensors`` when the dive has them; otherwise the first Sea-Bird
cast of ``sources.cnv`` (``.cnv`` plain or gzip/bz2/xz-compressed, or raw ``.hex``, detected by content) does.
``ingest.source`` overrides the choice; sources not used are listed in ``ignored_sources`` with a warning.
Every cast not used for ``sensors`` is ingested on its own into ``casts``. A cast without a time channel
(pressure-binned) is a *profile*: ``time`` is all NaT (no time is invented), table metadata ``time_base`` =
``'none (pressure-binned cast)'``, rows in file (pressure) order, QC gross range as usual, spike test on
the bin index, flat-line not evaluated. The cast header (position, processing, XML sensors) is carried in
the metadata (``cast``, ``cast_latitude_deg``/``cast_longitude_deg``) for derive.
"""

from __future__ import annotations

import json
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from hadal.budget import memory_limit_bytes
from hadal.errors import InputError
from hadal.names import record_id as file_record_id
from hadal.settings.ingest import IngestParams as Params
from hadal.stages import Stage, StageInputs
from hadal.store import sha256_file

if TYPE_CHECKING:
    import pandas as pd

    from hadal.ingest.csv_reader import SensorSamples
    from hadal.ingest.vehicle import VehicleConfig
    from hadal.stages import StageContext
    from hadal.store import ProductVersion


def _gap_limits(p: Params) -> dict[str, float]:
    """``ingest.max_gap_s`` checked again where it is used (a constructed Params skips validation): finite, > 0."""
    from hadal.budget import finite_positive

    finite_positive("ingest.default_max_gap_s", p.default_max_gap_s)
    return {k: finite_positive(f"ingest.max_gap_s.{k}", v) for k, v in p.max_gap_s.items()}


def _vehicle_path(ctx: StageContext, p: Params) -> Path:
    from hadal.dive import resolve_source
    from hadal.ingest.vehicle import default_vehicle_config_path

    rel = p.vehicle_config or ctx.dive.vehicle_config
    if rel:
        path = resolve_source(ctx.raw_dir, rel)
        if not path.is_file():
            raise InputError(f"vehicle config {rel!r} named by the dive/pipeline config does not exist in {ctx.raw_dir}")
        return path
    if ctx.dive.sources.mcap or ctx.dive.sources.csv:  # a cast-only dive needs no vehicle channel mapping
        ctx.log.warning("dive %s names no vehicle_config; using the packaged haidou mapping", ctx.dive_id)
    return default_vehicle_config_path()


def _cast_table(samples: SensorSamples, vehicle: VehicleConfig, p: Params, launch_ns: int | None = None
                ) -> tuple[pd.DataFrame, dict[str, Any]]:
    """A cast's own sensors-schema table: a profile (no time base) or a CTD-only time series."""
    from hadal.ingest.build import build_profile_table, build_sensor_table, is_profile

    if is_profile(samples):
        return build_profile_table(samples, p.qc)
    return build_sensor_table({vehicle.time_base: samples}, vehicle, max_gap_s=_gap_limits(p),
                              default_max_gap_s=p.default_max_gap_s, qc=p.qc, launch_ns=launch_ns,
                              strict_launch=False)


def _launch_ns(ctx: StageContext) -> int | None:
    """dive.yaml ``launch.time_utc`` as ns since the epoch (a naive time is UTC); ``None`` when not given."""
    import pandas as pd

    launch = ctx.dive.launch
    if launch is None or launch.time_utc is None:
        return None
    ts = pd.Timestamp(launch.time_utc)
    ts = ts.tz_localize("UTC") if ts.tzinfo is None else ts.tz_convert("UTC")
    return int(ts.value)


def _coverage(df: pd.DataFrame) -> tuple[str | None, str | None]:
    t = df["time"].dropna()
    return (t.iloc[0].isoformat(), t.iloc[-1].isoformat()) if len(t) else (None, None)


def _version(dist: str) -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(dist)
    except PackageNotFoundError:
        return "?"


def reader_of(path: Path) -> str:
    """Which reader (library and version) reads a raw ingest file, for the manifest."""
    from hadal import __version__
    from hadal.errors import HadalError
    from hadal.formats import detect

    try:
        fk = detect(path)
    except HadalError:
        return "?"
    comp = f", {fk.compression}" if fk.compression else ""
    if fk.kind == "mcap":
        return f"mcap {_version('mcap')} + mcap-ros2-support {_version('mcap-ros2-support')} (ROS 2 CDR) / json"
    if fk.kind == "cnv":
        return f"hadal {__version__} SeaSoft .cnv reader{comp}"
    if fk.kind == "seabird_hex":
        return f"hadal {__version__} .hex decoder + seabirdscientific {_version('seabirdscientific')} conversions{comp}"
    if fk.kind == "csv":
        return f"pandas {_version('pandas')} read_csv{comp}"
    if fk.kind == "yaml":
        return f"PyYAML {_version('PyYAML')} (vehicle mapping)"
    return fk.kind


@dataclass
class _Read:
    """What the reading of the chosen sources gives: samples per sensor and the bookkeeping for the metadata."""

    sensors: dict[str, SensorSamples]
    used: list[Path]
    mcap_reports: list[dict[str, Any]] = field(default_factory=list)
    ignored: list[dict[str, str]] = field(default_factory=list)
    cast_meta: dict[str, Any] | None = None


def _source_kind(p: Params, src) -> str:
    """``ingest.source``, with ``auto`` resolved: MCAP when the dive lists one, else CSV, else the casts."""
    if p.source == "auto":
        return "mcap" if src.mcap else ("csv" if src.csv else "cnv")
    return p.source


def _read_mcap(ctx: StageContext, p: Params, vehicle: VehicleConfig) -> _Read:
    from hadal.dive import resolve_source
    from hadal.ingest.build import read_mcap_sensors

    src = ctx.dive.sources
    if not src.mcap:
        raise InputError(f"dive {ctx.dive_id}: ingest.source is 'mcap' but dive.yaml lists no MCAP file")
    paths = [resolve_source(ctx.raw_dir, r) for r in src.mcap]
    for q in paths:
        if not q.is_file():
            raise InputError(f"{q}: MCAP file listed in dive.yaml does not exist")
    ignored = []
    if src.csv:
        ignored.append({"kind": "csv", "files": ", ".join(sorted(src.csv.values())),
                        "why": f"ingest.source is {p.source!r}: the MCAP logs make sensors "
                               "(set ingest.source: csv to use the CSV logs instead)"})
    sensors, mcap_reports = read_mcap_sensors(paths, vehicle, memory_limit_bytes=memory_limit_bytes(ctx.config))
    return _Read(sensors, paths, mcap_reports, ignored)


def _read_record(ctx: StageContext, path: Path, name: str) -> tuple[Any, dict[str, Any]]:
    """One Sea-Bird record (:func:`hadal.ingest.build.read_cast`). An underway record (dive.yaml ``kind:
    underway``: a thermosalinograph in the seawater line) may have no pressure channel: its pressure is then
    0 dbar, the sea surface where the ship's seawater intake is (the metadata and a warning say so)."""
    from hadal.dive import resolve_source
    from hadal.ingest.build import cast_metadata, read_cast
    from hadal.ingest.cnv import CNV_PRESSURE, cnv_sensor_samples, read_seabird

    limit = memory_limit_bytes(ctx.config)
    underway = any(e.kind == "underway" and resolve_source(ctx.raw_dir, e) == path for e in ctx.dive.sources.cnv)
    if not underway:
        return read_cast(path, name, memory_limit_bytes=limit)
    df = read_seabird(path, max_bytes=limit)
    if any(c in df.columns for c, _ in CNV_PRESSURE):
        return read_cast(path, name, memory_limit_bytes=limit)
    df["prM"] = 0.0  # the seawater line is at the sea surface
    s = cnv_sensor_samples(df, name, allow_no_time=True)
    note = "underway record without a pressure channel: 0 dbar (the sea surface) assumed for every scan"
    s.stats["pressure"] = note
    s.stats["channels"]["pressure_ctd_dbar"] = "none (0 dbar assumed)"
    warnings.warn(f"{path.name}: {note}", stacklevel=2)
    meta = cast_metadata(df.attrs)
    meta["pressure_assumed"] = note
    return s, meta


def _read_cnv(ctx: StageContext, p: Params, vehicle: VehicleConfig, cast_paths: list[Path]) -> _Read:
    from hadal.ingest.build import read_cnv_sensors

    src = ctx.dive.sources
    if not cast_paths:
        raise InputError(f"dive {ctx.dive_id}: ingest.source is 'cnv' but dive.yaml lists no .cnv file"
                         if p.source == "cnv" else
                         f"dive {ctx.dive_id}: dive.yaml lists neither MCAP, CSV nor .cnv sensor logs")
    ignored = []
    for k_, files in (("mcap", list(src.mcap)), ("csv", list(src.csv.values()))):
        if files:
            ignored.append({"kind": k_, "files": ", ".join(files),
                            "why": "ingest.source is 'cnv': the Sea-Bird cast makes sensors"})
    if p.merge_casts and len(cast_paths) > 1:
        return _Read(read_cnv_sensors(cast_paths, vehicle, memory_limit_bytes=memory_limit_bytes(ctx.config)),
                     cast_paths, ignored=ignored)
    s0, cast_meta = _read_record(ctx, cast_paths[0], vehicle.time_base)
    return _Read({vehicle.time_base: s0}, cast_paths[:1], ignored=ignored, cast_meta=cast_meta)


def _read_csv(ctx: StageContext, vehicle: VehicleConfig) -> _Read:
    from hadal.dive import resolve_source
    from hadal.ingest.build import read_csv_sensors

    src = ctx.dive.sources
    if not src.csv:
        raise InputError(f"dive {ctx.dive_id}: ingest.source is 'csv' but dive.yaml lists no CSV file")
    files = {k: resolve_source(ctx.raw_dir, r) for k, r in src.csv.items()}
    used_names = {s.csv.source for s in vehicle.sensors.values() if s.csv is not None}
    unused = sorted(k for k in files if k not in used_names)
    ignored = []
    if unused:
        ignored.append({"kind": "csv", "files": ", ".join(unused),
                        "why": "no sensor of the vehicle mapping reads these sources.csv names"})
    files = {k: v for k, v in files.items() if k in used_names}
    if src.mcap:
        ignored.append({"kind": "mcap", "files": ", ".join(src.mcap),
                        "why": "ingest.source is 'csv': the CSV logs make sensors"})
    return _Read(read_csv_sensors(files, vehicle, memory_limit_bytes=memory_limit_bytes(ctx.config)),
                 list(files.values()), ignored=ignored)


def _sensor_table(ctx: StageContext, p: Params, vehicle: VehicleConfig, kind: str, read: _Read
                  ) -> tuple[pd.DataFrame, dict[str, Any]]:
    """The ``sensors`` table: a profile for a cast without time base, else the aligned, QC'd time series."""
    from hadal.ingest.build import build_profile_table, build_sensor_table, is_profile

    base = read.sensors.get(vehicle.time_base)
    if kind == "cnv" and base is not None and is_profile(base):
        return build_profile_table(base, p.qc)
    return build_sensor_table(read.sensors, vehicle, max_gap_s=_gap_limits(p),
                              default_max_gap_s=p.default_max_gap_s, qc=p.qc,
                              launch_ns=_launch_ns(ctx), strict_launch=kind != "cnv")


def _external_casts(ctx: StageContext, p: Params, vehicle: VehicleConfig, cast_paths: list[Path],
                    in_sensors: set[Path]) -> list[tuple[str, Path, pd.DataFrame, dict[str, Any]]]:
    """Every cast not used for sensors, ingested on its own (never silently ignored): (cast id, path, table, meta)."""

    external = []
    for k, q in enumerate(cast_paths):
        if q in in_sensors:
            continue
        s_k, m_k = _read_record(ctx, q, vehicle.time_base)
        t_k, tm_k = _cast_table(s_k, vehicle, p, _launch_ns(ctx))
        tm_k["cast"] = m_k
        _add_cast_notes(tm_k)
        external.append((file_record_id("cast", k, q), q, t_k, tm_k))
    return external


def _add_cast_notes(meta: dict[str, Any]) -> None:
    """What was read from a cast's metadata instead of taken as written, in the table's ``notes`` (the report
    lists them): a ``start_time`` corrected from the header's clocks, the vendor's salinity used for want of a
    conductivity channel, altimeter readings that are its no-bottom output."""
    cast = meta.get("cast") or {}
    notes = meta.setdefault("notes", [])
    src = Path(str(cast.get("source", "cast"))).name
    if cast.get("start_time_correction"):
        notes.append(f"{src}: {cast['start_time_correction']}")
    for st in (meta.get("read_stats") or {}).values():
        if not isinstance(st, dict):
            continue
        if st.get("salinity_method"):
            notes.append(f"{src}: practical salinity is {st['salinity_method']}; conductivity is missing (flag 9)")
        alt = st.get("altimeter") or {}
        if alt.get("no_echo_readings"):
            notes.append(f"{src}: altimeter '{alt['channel']}': {alt['no_echo_readings']} reading(s) at or above "
                         f"{alt['no_echo_threshold_m']:.4g} m are its no-bottom output (missing, flag 9); full scale "
                         f"from the {alt['full_scale_source']}")


def _source_entry(q: Path) -> dict[str, Any]:
    return {"path": str(q), "sha256": sha256_file(q), "bytes": q.stat().st_size}


def _sensors_metadata(ctx: StageContext, meta: dict[str, Any], df: pd.DataFrame, *, vehicle: VehicleConfig,
                      vpath: Path, kind: str, inputs: list[Path], read: _Read, messages: list[str],
                      external: list) -> None:
    """Complete the ``sensors`` table metadata (dive, sources with SHA-256, MCAP damage, warnings, cast header)."""
    lost = [r.get("messages_lost") for r in read.mcap_reports]
    start, end = _coverage(df)
    meta.update({
        "dive_id": ctx.dive_id,
        "vehicle": vehicle.vehicle,
        "vehicle_config": str(vpath),
        "source_kind": kind,
        "sources": [_source_entry(q) for q in inputs],
        "mcap": read.mcap_reports,
        "messages_lost": (None if any(x is None for x in lost) else sum(lost)) if read.mcap_reports else 0,
        "warnings": messages,
        "ignored_sources": read.ignored,
        "external_casts": [{"cast_id": c, "path": str(q)} for c, q, _, _ in external],
        "rows": int(len(df)),
        "time_coverage_start": start,
        "time_coverage_end": end,
    })
    if read.cast_meta is not None:
        meta["cast"] = read.cast_meta
        meta["cast_latitude_deg"] = read.cast_meta.get("latitude_deg")
        meta["cast_longitude_deg"] = read.cast_meta.get("longitude_deg")
        _add_cast_notes(meta)
    meta["readers"] = {q.name: reader_of(q) for q in inputs}


def _publish_casts(ctx: StageContext, vpath: Path, external: list
                   ) -> tuple[ProductVersion | None, list[dict[str, Any]]]:
    """Publish ``casts``: one ``<cast id>.parquet`` per external cast and the ``casts.json`` index."""
    from hadal.ingest.build import field_metadata
    from hadal.products import write_parquet
    from hadal.products.io import json_clean

    index = []
    for cid, q, t_k, tm_k in external:
        s0, e0 = _coverage(t_k)
        tm_k.update({"dive_id": ctx.dive_id, "cast_id": cid, "source_kind": "cnv", "rows": int(len(t_k)),
                     "sources": [_source_entry(q)],
                     "time_coverage_start": s0, "time_coverage_end": e0})
        index.append({"cast_id": cid, "file": f"{cid}.parquet", "source": str(q), "rows": int(len(t_k)),
                      "time_base": tm_k["time_base"], "latitude_deg": tm_k["cast"].get("latitude_deg"),
                      "longitude_deg": tm_k["cast"].get("longitude_deg"),
                      "start_time_utc": tm_k["cast"].get("start_time_utc"),
                      "instrument": tm_k["cast"].get("instrument")})
    with ctx.store.publish(ctx.dive_id, "casts", parameters=ctx.params("ingest"),
                           inputs=[vpath] + [q for _, q, _, _ in external],
                           extra={"casts": [c["cast_id"] for c in index]}) as draft:
        for cid, _, t_k, tm_k in external:
            write_parquet(t_k, draft.path / f"{cid}.parquet", fields=field_metadata(), metadata=tm_k,
                          provenance_from=draft)
        (draft.path / "casts.json").write_text(json.dumps(json_clean({"casts": index}), indent=2),
                                               encoding="utf-8")
    return draft.result, index


def run(ctx: StageContext) -> dict[str, ProductVersion]:
    """Read, align, QC and publish ``sensors`` (and ``casts``); see the module docstring."""
    from hadal.dive import resolve_source
    from hadal.ingest.build import field_metadata
    from hadal.ingest.vehicle import load_vehicle_config
    from hadal.products import write_parquet

    p: Params = ctx.config.ingest
    vpath = _vehicle_path(ctx, p)
    vehicle = load_vehicle_config(vpath)
    kind = _source_kind(p, ctx.dive.sources)
    # an underway record (kind: underway, a thermosalinograph) makes sensors only when the dive has no cast
    cnv_entries = sorted(ctx.dive.sources.cnv, key=lambda e: e.kind == "underway")
    cast_paths = [resolve_source(ctx.raw_dir, r) for r in cnv_entries]
    for q in cast_paths:
        if not q.is_file():
            raise InputError(f"{q}: Sea-Bird cast listed in dive.yaml sources.cnv does not exist")
    from hadal.steps import step  # progress lines (issue 46)

    with warnings.catch_warnings(record=True) as caught, step(ctx.progress, f"ingest: reading the {kind} logs"):
        warnings.simplefilter("always")
        if kind == "mcap":
            read = _read_mcap(ctx, p, vehicle)
        elif kind == "cnv":
            read = _read_cnv(ctx, p, vehicle, cast_paths)
        else:
            read = _read_csv(ctx, vehicle)
        inputs: list[Path] = [vpath, *read.used]
        with step(ctx.progress, "ingest: aligning, converting and QC of the sensors table"):
            df, meta = _sensor_table(ctx, p, vehicle, kind, read)
        read.sensors = {}  # in the table now: the samples as read are not held while writing
        external = _external_casts(ctx, p, vehicle, cast_paths, set(inputs))
    messages = [str(w.message) for w in caught]
    for m in messages:
        ctx.log.warning("ingest: %s", m)
    for ig in read.ignored:
        ctx.log.warning("ingest: %s logs not used (%s): %s", ig["kind"], ig["files"], ig["why"])
    _sensors_metadata(ctx, meta, df, vehicle=vehicle, vpath=vpath, kind=kind, inputs=inputs, read=read,
                      messages=messages, external=external)
    with step(ctx.progress, f"ingest: writing sensors ({len(df):,} rows)"), ctx.store.publish(
            ctx.dive_id, "sensors", parameters=ctx.params("ingest"), inputs=inputs,
            extra={"ingest": {k: meta[k] for k in ("source_kind", "rows", "messages_lost", "unit_conversions",
                                                   "time_base", "readers")}}) as draft:
        write_parquet(df, draft.path / "sensors.parquet", fields=field_metadata(), metadata=meta,
                      provenance_from=draft)
    out = {"sensors": draft.result}
    ctx.log.info("ingest: %d rows from %s (%s), %d warning(s)", len(df), kind, vehicle.vehicle, len(messages))
    if external:
        out["casts"], index = _publish_casts(ctx, vpath, external)
        ctx.log.info("ingest: %d external cast(s) in 'casts': %s", len(index),
                     ", ".join(c["source"] for c in index))
    return out


STAGE = Stage(
    name="ingest", products=("sensors", "casts"),
    inputs=StageInputs(raw_any=("mcap", "csv", "cnv"), product_sources={"casts": ("cnv",)}, reads_raw=True,
                       optional_products=("casts",)),
    options=Params, run=run,
    warm_imports=("hadal.ingest.build", "hadal.ingest.vehicle", "hadal.products.io", "hadal.numbawarm:first_call"),
)
