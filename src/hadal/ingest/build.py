"""Assemble the ``sensors`` table: read sources with the vehicle mapping, clean, align, QC, validate.

Pure library code (no store, no Prefect): :func:`read_sources` -> {sensor: SensorSamples};
:func:`build_sensor_table` -> (DataFrame following ``schemas/sensors.yaml``, metadata dict).
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator, Mapping, Sequence
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import yaml

from hadal.errors import InputError
from hadal.ingest.align import DEFAULT_METHODS, align_sensor, clean_times
from hadal.ingest.cnv import SEASOFT_BAD_SCAN
from hadal.ingest.csv_reader import RecordParts, SensorSamples, read_sensor_csv
from hadal.ingest.mcap_reader import mcap_info, read_mcap
from hadal.ingest.qc import VariableQC, fail_fraction, qc_table
from hadal.ingest.units import CANONICAL_UNITS
from hadal.ingest.vehicle import VehicleConfig

__all__ = ["SENSOR_VARIABLES", "sensors_schema", "read_mcap_sensors", "read_csv_sensors", "read_cnv_sensors", "read_cast", "cast_metadata",
           "is_profile", "build_profile_table", "build_sensor_table",
           "validate_sensor_table"]

#: variables a sensors table holds only when its source provides them (``optional_columns`` of
#: ``schemas/sensors.yaml``): a Sea-Bird cast's own salinity when it has no conductivity channel; GNSS fixes
#: (latitude/longitude and their variances, at the surface) and USBL/LBL fixes: the navigation smoother's fixes
OPTIONAL_SENSOR_VARIABLES: tuple[str, ...] = ("practical_salinity_vendor", "gnss_latitude_deg", "gnss_longitude_deg",
                                              "gnss_east_variance_m2", "gnss_north_variance_m2",
                                              "usbl_latitude_deg", "usbl_longitude_deg", "usbl_east_variance_m2",
                                              "usbl_north_variance_m2")
#: the variables of ``sensors.parquet`` in column order (architecture.md)
SENSOR_VARIABLES: tuple[str, ...] = tuple(v for v in CANONICAL_UNITS if v not in OPTIONAL_SENSOR_VARIABLES)


def table_variables(columns: Mapping[str, Any]) -> tuple[str, ...]:
    """The variables of a sensors table built from ``columns``: every :data:`SENSOR_VARIABLES` and the
    :data:`OPTIONAL_SENSOR_VARIABLES` present in ``columns``."""
    return SENSOR_VARIABLES + tuple(v for v in OPTIONAL_SENSOR_VARIABLES if v in columns)


@lru_cache(maxsize=1)
def _schema_path() -> Path:
    """``schemas/sensors.yaml``, shipped as package data of ``hadal.schemas`` (read with importlib.resources)."""
    from importlib.resources import files

    p = files("hadal.schemas") / "sensors.yaml"
    if not p.is_file():
        raise InputError("hadal.schemas/sensors.yaml (the sensors product contract) is missing from the installation")
    return Path(str(p))


@lru_cache(maxsize=1)
def sensors_schema() -> dict[str, Any]:
    """The ``sensors`` table contract from ``schemas/sensors.yaml`` (column set and dtypes, time rules). The
    columns' attributes are not in it: they are declared once, in the variable registry (:func:`field_metadata`)."""
    return yaml.safe_load(_schema_path().read_text(encoding="utf-8"))


def field_metadata() -> dict[str, dict[str, str]]:
    """Per-column Parquet field metadata of ``sensors`` (units, standard_name, long_name; flag attributes of the
    ``<var>_qc`` columns), QC columns included: the variable registry's (``schemas/variables.yaml``), the single
    source of the attributes (:func:`hadal.registry.column_attrs`, which :func:`write_parquet` applies too)."""
    from hadal.registry import column_attrs

    out: dict[str, dict[str, str]] = {}
    for name in sensors_schema()["columns"]:
        out[name] = column_attrs(name, where="sensors.yaml")
        if name != "time":
            out[f"{name}_qc"] = column_attrs(f"{name}_qc", where="sensors.yaml")
    return out



def qc_flag_values() -> list[int]:
    """The QARTOD flag values a ``<var>_qc`` column may hold (the registry's ``*_qc`` pattern)."""
    from hadal.registry import registry

    spec = registry().spec(f"{SENSOR_VARIABLES[0]}_qc", "sensors.yaml")
    return [int(v) for v in spec.flag_values or ()]


def check_ros2_mapping(file: str, tp: Any, mapping: Any, sensor: str) -> None:
    """Mapping validation against a ROS 2 (CDR) topic's schema: every field mapped to a numeric variable must be
    a numeric primitive (``int*``/``uint*``/``float*``, or one element ``a.0`` of a numeric array); a ``bool``,
    a ``string``, a whole array or a sub-message is a one-line :class:`InputError` naming the field, its ROS 2
    type and the variable. A ``unix_*`` time field must be numeric too (``ros_time`` takes a ``Time``)."""
    from hadal.ingest.mcap_reader import ROS2_NUMERIC, ros2_field_type

    if mapping is None or tp.message_encoding != "cdr" or tp.schema_encoding != "ros2msg" or not tp.schema_data:
        return
    text = bytes(tp.schema_data).decode("utf-8", errors="replace")
    checks = [(f, var) for var, fm in mapping.fields.items() for f in fm.inputs()]
    if mapping.time.field != "log_time" and mapping.time.format.startswith("unix_"):
        checks.append((mapping.time.field, f"time ({mapping.time.format})"))
    for f, var in checks:
        ftype = ros2_field_type(tp.schema_name, text, f)
        if ftype is None:
            continue  # not in the definition: the reader says "has no field"
        base = ftype.split("<=", 1)[0]
        if base in ROS2_NUMERIC:
            continue
        what = ("an array" if "[" in ftype else "a boolean" if base == "bool" else
                "a string" if base in ("string", "wstring") or base.startswith("string") else "a sub-message")
        hint = (f"; map one element ('{f}.0')" if "[" in ftype and ftype.split("[", 1)[0] in ROS2_NUMERIC
                else "; map one of its numeric fields ('" + f + ".<field>')" if what == "a sub-message" else "")
        raise InputError(f"{file}: vehicle config maps {sensor}'s {var} to field {f!r} of topic {tp.topic}, "
                         f"which is {what} ({ftype}) in the ROS 2 schema {tp.schema_name}: only numeric fields "
                         f"(int*, uint*, float*) can give a numeric variable{hint}")


def _mapped_sensors(vehicle: VehicleConfig, kind: str, what: str) -> Iterator[tuple[str, Any]]:
    """``(name, sensor)`` of each of the vehicle's sensors with a ``kind`` (``mcap``/``csv``) mapping, in order; a
    required sensor without one is an :class:`InputError` (``what``: the mapping in words)."""
    for name, s in vehicle.sensors.items():
        if getattr(s, kind) is None:
            if s.required:
                raise InputError(f"vehicle config gives no {what} for the required sensor {name!r}")
            continue
        yield name, s


def _missing_channel(msg: str, required: bool) -> None:
    """A mapped sensor with no data: an :class:`InputError` when it is required, else a warning (flag 9 columns)
    for the caller of the ``read_*_sensors`` function."""
    if required:
        raise InputError(msg + " - missing required channel")
    warnings.warn(msg + "; its columns will be empty (flag 9)", stacklevel=3)


def read_mcap_sensors(paths: Sequence[str | Path], vehicle: VehicleConfig, *, memory_limit_bytes: float | None = None
                      ) -> tuple[dict[str, SensorSamples], list[dict[str, Any]]]:
    """Read every sensor with an ``mcap`` mapping from the MCAP files (their messages are concatenated).

    Returns the samples and one :class:`McapReport` dict per file. A required sensor whose topic is in
    none of the files is an :class:`InputError`; an optional one is left out with a warning. Files holding
    no message on any mapped topic are a one-line :class:`InputError` ("nothing to ingest"). Each file is read
    against the memory budget ``memory_limit_bytes`` (the stage's ``resources.max_memory_gb``;
    :func:`hadal.ingest.mcap_reader.read_mcap`).
    """
    topics = {s.mcap.topic: name for name, s in vehicle.sensors.items() if s.mcap is not None}
    # each topic's messages are taken one MCAP chunk at a time into its sensor's columns (RecordParts), over
    # every file: no topic's decoded messages are ever all in memory at once
    columns = {name: RecordParts(s.mcap, "") for name, s in vehicle.sensors.items() if s.mcap is not None}

    def consumer(topic: str) -> Any:
        takers = [columns[name].add for name, s in vehicle.sensors.items() if s.mcap is not None
                  and s.mcap.topic == topic]
        return lambda t, msgs: [take(t, msgs) for take in takers]

    consume = {topic: consumer(topic) for topic in topics}
    per_topic: dict[str, list[str]] = {}
    reports = []
    for p in paths:
        data, report = read_mcap(p, topics, warn=True, memory_limit_bytes=memory_limit_bytes, consume=consume)
        reports.append(report.as_dict())
        for topic, tp in data.items():
            check_ros2_mapping(Path(p).name, tp, vehicle.sensors[topics[topic]].mcap, topics[topic])
            if tp.n_read:
                per_topic.setdefault(topic, []).append(Path(p).name)
    out: dict[str, SensorSamples] = {}
    names = ", ".join(Path(p).name for p in paths)
    if topics and paths and not per_topic:
        # the mapped topics are there but no message on them could be decoded: say so, not "check vehicle.yaml"
        undecodable = [(topic, r["path"], tr) for r in reports for topic, tr in (r.get("topics") or {}).items()
                       if topic in topics and tr.get("decode_errors") and not tr.get("read")]
        if undecodable:
            topic, path, tr = undecodable[0]
            others = sorted({x[0] for x in undecodable} - {topic})
            raise InputError(
                f"{Path(path).name}: none of the {tr['decode_errors']} message(s) on topic {topic} could be decoded "
                f"(message encoding {tr.get('message_encoding')!r}"
                f"{', schema ' + repr(tr['schema']) if tr.get('schema') else ''}); first error: "
                f"{tr.get('first_decode_error') or 'unknown'}"
                + (f"; the same on {', '.join(others[:5])}" if others else "")
                + " - the payloads are not in the declared encoding (compressed or corrupt?)")
        # no mapped channel at all (e.g. a ROS talker bag of std_msgs/String): one clear line, nothing to ingest
        have = sorted({c["topic"] for p in paths for c in mcap_info(p) if c["messages"]})
        want = sorted(topics)
        req = [n for n, s in vehicle.sensors.items() if s.required and s.mcap is not None]
        raise InputError(
            f"{names}: no messages on any of the vehicle config's MCAP topics ({', '.join(want[:6])}"
            f"{', ...' if len(want) > 6 else ''}); the file(s) hold {', '.join(have[:8]) or 'no messages'}"
            f"{', ...' if len(have) > 8 else ''} - nothing to ingest"
            f"{' (missing required channel: ' + ', '.join(req) + ')' if req else ''}; check vehicle.yaml "
            "(hadal init suggests one)")
    for name, s in _mapped_sensors(vehicle, "mcap", "MCAP topic"):
        parts = per_topic.get(s.mcap.topic)
        if not parts:
            msg = f"{names}: no messages on topic {s.mcap.topic!r} (sensor {name!r})"
            bad = [(r, r["topics"][s.mcap.topic]) for r in reports if (r.get("topics") or {}).get(
                s.mcap.topic, {}).get("decode_errors")]
            if bad:
                tr = bad[0][1]
                msg = (f"{Path(bad[0][0]['path']).name}: none of the {tr['decode_errors']} message(s) on topic "
                       f"{s.mcap.topic} (sensor {name!r}) could be decoded (message encoding "
                       f"{tr.get('message_encoding')!r}); first error: {tr.get('first_decode_error') or 'unknown'}")
            _missing_channel(msg, s.required)
            continue
        cols = columns[name]
        cols.source = "mcap:" + "+".join(parts)
        out[name] = cols.samples(name)
        if s.mcap.time.field == "log_time" and isinstance(cols.first, dict) and isinstance(out[name].stats, dict):
            out[name].stats["time_field_alternatives"] = _time_fields(cols.first)
    return out, reports


def _time_fields(msg: dict[str, Any]) -> list[str]:
    """Fields of a decoded message that look like a sample time (``stamp``, ``header.stamp``, ``time``...):
    the alternatives to ``log_time`` named when log_time turns out to be coarse."""
    import re

    from hadal.ingest.mcap_reader import field_names

    out: list[str] = []
    for f in field_names(msg):
        parts = f.split(".")
        # a ROS time is a {sec, nanosec} mapping: name the mapping (header.stamp), not its leaves
        if len(parts) > 1 and parts[-1] in ("sec", "secs", "nanosec", "nsecs") and re.search(
                r"stamp|time", parts[-2], re.I):
            f = ".".join(parts[:-1])
        elif not re.search(r"stamp|time", parts[-1], re.I):
            continue
        if f not in out:
            out.append(f)
    return out[:4]


def read_csv_sensors(files: Mapping[str, Path], vehicle: VehicleConfig, *, memory_limit_bytes: float | None = None
                     ) -> dict[str, SensorSamples]:
    """Read every sensor with a ``csv`` mapping; ``files`` maps the dive's ``sources.csv`` keys to paths; each file
    against the memory budget ``memory_limit_bytes`` (:func:`hadal.ingest.csv_reader.read_sensor_csv`)."""
    out: dict[str, SensorSamples] = {}
    for name, s in _mapped_sensors(vehicle, "csv", "CSV mapping"):
        path = files.get(s.csv.source)
        if path is None:
            _missing_channel(f"dive.yaml sources.csv has no {s.csv.source!r} file (sensor {name!r})", s.required)
            continue
        out[name] = read_sensor_csv(path, s.csv, name, memory_limit_bytes=memory_limit_bytes)
    return out


#: header metadata of a cast carried into the table metadata (``cast``) of ``sensors`` / ``casts``
CAST_ATTRS = ("source", "format", "compression", "instrument", "instrument_serial", "latitude_deg", "longitude_deg",
              "position_source", "start_time_utc", "start_time_note", "start_time_file", "start_time_correction",
              "upload_time_utc", "nmea_utc", "interval", "binned", "bad_flag",
              "bad_values", "processing", "sensors", "sensors_xml", "channel_latitude_deg", "user_header",
              "nquan", "nvalues_declared", "nvalues", "truncated", "rows_dropped", "time_channels")


def cast_metadata(attrs: Mapping[str, Any]) -> dict[str, Any]:
    """The JSON-serialisable header metadata of a read cast (:data:`CAST_ATTRS` present in ``attrs``)."""
    return {k: attrs.get(k) for k in CAST_ATTRS if k in attrs}


def read_cast(path: str | Path, name: str = "ctd", *, memory_limit_bytes: float | None = None
              ) -> tuple[SensorSamples, dict[str, Any]]:
    """One Sea-Bird cast (.cnv, compressed or not, or raw .hex: :func:`hadal.ingest.cnv.read_seabird`, against the
    memory budget ``memory_limit_bytes``) as the CTD's samples and its header metadata. A cast without a time
    channel gives NaT times (a profile)."""
    from hadal.ingest.cnv import cnv_sensor_samples, read_seabird

    df = read_seabird(path, max_bytes=memory_limit_bytes)
    try:
        s = cnv_sensor_samples(df, name, allow_no_time=True)
    except InputError as exc:
        msg = str(exc)
        raise InputError(msg if str(path) in msg else f"{path}: {msg}") from None
    return s, cast_metadata(df.attrs)


def is_profile(s: SensorSamples) -> bool:
    """True for samples without a time base (pressure-binned cast: every time NaT)."""
    return bool(len(s)) and bool(np.all(s.time_ns == np.iinfo(np.int64).min))


def read_cnv_sensors(paths: Sequence[str | Path], vehicle: VehicleConfig, *, memory_limit_bytes: float | None = None
                     ) -> dict[str, SensorSamples]:
    """CTD casts from Sea-Bird ``.cnv`` files as the time-base sensor (the other sensors stay empty, flag 9).
    Several files are concatenated (their times must not overlap; duplicates are dropped by alignment);
    casts without a time channel cannot be concatenated (ingest puts each in ``casts``)."""
    if not paths:
        raise InputError("no .cnv files to read")
    parts = [read_cast(p, vehicle.time_base, memory_limit_bytes=memory_limit_bytes)[0] for p in paths]
    if len(parts) == 1:
        return {vehicle.time_base: parts[0]}
    if any(is_profile(x) for x in parts):
        raise InputError(f"{', '.join(str(p) for p in paths)}: casts without a time channel cannot be merged "
                         "into one time series")
    first = parts[0]
    keys = list(first.values) + ([SEASOFT_BAD_SCAN] if SEASOFT_BAD_SCAN not in first.values
                                 and any(SEASOFT_BAD_SCAN in x.values for x in parts) else [])
    merged = SensorSamples(
        vehicle.time_base, np.concatenate([x.time_ns for x in parts]),
        {k: np.concatenate([x.values.get(k, np.zeros(len(x))) for x in parts]) for k in keys},
        "+".join(x.source for x in parts), {"files": [x.stats for x in parts]},
        [c for x in parts for c in x.conversions])
    return {vehicle.time_base: merged}


#: the variables a Sea-Bird cast provides, which SeaSoft's scan flags apply to
SEASOFT_FLAGGED_VARIABLES = ("pressure_ctd_dbar", "temperature_its90_degc", "conductivity_s_m")


def apply_seasoft_flags(flags: dict[str, np.ndarray], counts: dict[str, dict[str, int]], bad: np.ndarray | None,
                        meta: dict[str, Any], source: str) -> None:
    """QARTOD flag 4 (bad) on the CTD variables of the scans SeaSoft marked bad (``flag`` channel, see
    :func:`hadal.ingest.cnv.seasoft_bad_scans`): the rows stay (nothing is deleted), missing values keep flag 9.
    Updates ``flags``/``counts`` in place and records ``meta["seasoft_flags"]``."""
    if bad is None:
        return
    b = np.asarray(bad, np.float64) > 0.5
    flagged = SEASOFT_FLAGGED_VARIABLES + tuple(v for v in OPTIONAL_SENSOR_VARIABLES if f"{v}_qc" in flags)
    for var in flagged:
        f = flags[f"{var}_qc"]
        f[b & (f != 9)] = 4
        vals, n = np.unique(f, return_counts=True)
        counts[var] = {str(int(k)): int(c) for k, c in zip(vals, n, strict=True)}
    meta["seasoft_flags"] = {"scans_flagged": int(b.sum()), "scans": int(b.size), "qartod_flag": 4,
                             "variables": list(flagged), "source": source,
                             "rule": "scans whose SeaSoft 'flag' channel is non-zero or bad_flag (LoopEdit, "
                                     "WildEdit ...) are flagged 4, not deleted"}
    if b.any():
        warnings.warn(f"{source}: {int(b.sum())} of {b.size} scans marked bad by SeaSoft (flag channel): "
                      "QARTOD flag 4 on the CTD variables", stacklevel=3)


def build_profile_table(samples: SensorSamples, qc: Mapping[str, VariableQC] | None = None
                        ) -> tuple[pd.DataFrame, dict[str, Any]]:
    """The ``sensors`` table of a cast without a time base (pressure-binned): one row per bin in file (pressure)
    order, ``time`` all NaT (no time is invented), the CTD columns from the cast, every other variable NaN
    (flag 9). QC: gross range as usual; the spike test runs on the sample (bin) index; the flat-line test needs
    time and is not evaluated (it contributes flag 2, i.e. nothing, to the aggregate). Table metadata
    ``time_base`` = :data:`hadal.ingest.cnv.NO_TIME_BASE`."""
    from hadal.ingest.cnv import NO_TIME_BASE
    from hadal.ingest.qc import merge_qc

    qc = merge_qc(qc)
    n = len(samples)
    if n < 2:
        raise InputError(f"{samples.source}: only {n} sample(s) in the cast")
    columns: dict[str, np.ndarray] = {}
    meta: dict[str, Any] = {"time_base": NO_TIME_BASE, "time_base_rate_hz": None, "alignment": {}, "notes": [],
                            "unit_conversions": list(samples.conversions), "non_finite_values": {},
                            "read_stats": {samples.name: samples.stats}}
    for var in SENSOR_VARIABLES:
        v = samples.values.get(var)
        if v is None:
            columns[var] = np.full(n, np.nan)
            continue
        bad = np.isinf(v)
        if bad.any():
            meta["non_finite_values"][var] = int(bad.sum())
            v = np.where(bad, np.nan, v)
        columns[var] = channel_health(v, var, qc.get(var), meta, source=samples.source, sensor=samples.name,
                                      conversions=samples.conversions)
    meta["alignment"][samples.name] = {"source": samples.source, "samples": n, "method": "profile (no time base)"}
    no_flat = {k: v.model_copy(update={"flat_line_suspect_s": None}) for k, v in qc.items()}
    index_ns = np.arange(n, dtype=np.int64) * 1_000_000_000  # sample index (the spike test only uses order)
    for var in OPTIONAL_SENSOR_VARIABLES:
        if var in samples.values:
            columns[var] = np.where(np.isinf(samples.values[var]), np.nan, samples.values[var])
    table_vars = table_variables(columns)
    flags, counts = qc_table({v: columns[v] for v in table_vars}, index_ns, no_flat)
    apply_seasoft_flags(flags, counts, samples.values.get(SEASOFT_BAD_SCAN), meta, samples.source)
    flag_dead_channels(flags, counts, meta)
    meta["qc_counts"] = counts
    meta["qc_note"] = ("profile without time: gross range as usual, spike test on the bin index, flat-line test "
                       "not evaluated")
    df = pd.DataFrame({"time": pd.Series(pd.NaT, index=range(n), dtype="datetime64[ns, UTC]")})
    for var in table_vars:
        df[var] = columns[var].astype(np.float64)
    for var in table_vars:
        df[f"{var}_qc"] = flags[f"{var}_qc"].astype(np.uint8)
    validate_sensor_table(df, profile=True)
    return df, meta


#: a sensor whose time span covers less than this fraction of the time base's is warned about
MIN_OVERLAP = 0.5
#: data times expected within [launch - 1 day, launch + 30 days] when dive.yaml gives launch.time_utc
LAUNCH_WINDOW_S = (86_400.0, 30 * 86_400.0)
_TIME_SCALE = {"unix_ns": 1.0, "unix_ms": 1e6, "unix_s": 1e9}


def rejected_summary(sensors: Mapping[str, SensorSamples], meta: dict[str, Any]) -> None:
    """``meta["rejected_samples"]``: per sensor, the samples the readers rejected for a value that is not a
    number, with the per-field counts (``{"ctd": {"samples": 3, "fields": {"temp": {...}}}}``)."""
    out: dict[str, Any] = {}
    for name, s in sensors.items():
        st = s.stats if isinstance(s.stats, dict) else {}
        parts: list[Any] = st["files"] if isinstance(st.get("files"), list) else [st]
        n = sum(int(x.get("rejected_samples", 0) or 0) for x in parts if isinstance(x, dict))
        if n:
            fields: dict[str, Any] = {}
            for x in parts:
                for f, d in (x.get("rejected_values") or {}).items():
                    fields.setdefault(f, {"variable": d.get("variable"), "count": 0})["count"] += int(d["count"])
            out[name] = {"samples": n, "source": s.source, "fields": fields}
            meta.setdefault("notes", []).append(
                f"{name}: {n} sample(s) rejected for a value that is not a number ("
                + ", ".join(f"{f} {d['count']}" for f, d in fields.items()) + ")")
    meta["rejected_samples"] = out


class _TimeChecks:
    """Time sanity of the sensor streams (see :func:`build_sensor_table`); fills ``meta["time_checks"]``."""

    def __init__(self, meta: dict[str, Any], launch_ns: int | None, window_s: tuple[float, float]):
        from hadal.ingest.align import iso_ns, plausible_window

        self.meta, self.launch_ns = meta, launch_ns
        self.lo, self.hi = plausible_window()
        self.before_s, self.after_s = float(window_s[0]), float(window_s[1])
        self.tc: dict[str, Any] = {"plausible_range": [iso_ns(self.lo), iso_ns(self.hi)], "implausible": {},
                                   "launch_time": iso_ns(launch_ns) if launch_ns is not None else None,
                                   "launch_window_s": [-self.before_s, self.after_s] if launch_ns is not None else None,
                                   "outside_launch_window": {}, "overlap": {}}
        meta["time_checks"] = self.tc

    def _loud(self, text: str) -> None:
        warnings.warn(text, stacklevel=4)
        self.meta["notes"].append(text)

    def plausible(self, name: str, s: SensorSamples, required: bool) -> SensorSamples:
        """Drop (count, flag) sample times outside 1980 .. now + 1 day; InputError when they are >= half."""
        from hadal.ingest.align import iso_ns, out_of_range, time_unit_hint

        if len(s) == 0:
            return s
        bad = out_of_range(s.time_ns, self.lo, self.hi)
        if not bad.any():
            return s
        n, tot = int(bad.sum()), len(s)
        tb = s.time_ns[bad]
        span = f"{iso_ns(int(tb.min()))} .. {iso_ns(int(tb.max()))}"
        st = s.stats if isinstance(s.stats, dict) else {}
        fmt, fld = st.get("time_format"), st.get("time_field")
        hint = None
        if fmt in _TIME_SCALE:
            hint = time_unit_hint(tb / _TIME_SCALE[fmt], "log_time" if fld == "log_time" else fmt)
        where = f"{fld!r} ({fmt})" if fld and fld != "log_time" else ("log_time" if fld == "log_time" else "time")
        rng = f"{self.tc['plausible_range'][0][:10]} .. {self.tc['plausible_range'][1][:10]}"
        if n * 2 >= tot:
            raise InputError(f"{s.source}: {n} of {tot} {name} sample time(s) lie outside the plausible range {rng} "
                             f"({span})" + (f"; {where} {hint}" if hint else "; check the time field/format in "
                                            "the vehicle config and the logger clock"))
        self.tc["implausible"][name] = {"dropped": n, "of": tot, "span": span, **({"hint": hint} if hint else {})}
        self._loud(f"{s.source}: dropped {n} of {tot} {name} sample(s) dated outside the plausible range {rng} "
                   f"({span})" + (f"; {where} {hint}" if hint else ""))
        keep = ~bad
        return SensorSamples(s.name, s.time_ns[keep], {k: v[keep] for k, v in s.values.items()}, s.source,
                             {**st, "implausible_times": n}, s.conversions)

    def launch_window(self, name: str, source: str, t: np.ndarray, is_base: bool, strict: bool) -> None:
        from hadal.ingest.align import describe_offset, iso_ns

        if self.launch_ns is None or t.size == 0:
            return
        lo = self.launch_ns - int(self.before_s * 1e9)
        hi = self.launch_ns + int(self.after_s * 1e9)
        out = (t < lo) | (t > hi)
        if not out.any():
            return
        n = int(out.sum())
        first, last = int(t[0]), int(t[-1])
        off = describe_offset((first - self.launch_ns) / 1e9)
        text = (f"{source}: {n} of {t.size} {name} sample(s) lie outside the dive's launch window "
                f"({iso_ns(lo)} .. {iso_ns(hi)}: dive.yaml launch.time_utc {iso_ns(self.launch_ns)} "
                f"-{self.before_s / 3600:g} h / +{self.after_s / 86400:g} days); the data span "
                f"{iso_ns(first)} .. {iso_ns(last)}, starting {off} from the launch")
        self.tc["outside_launch_window"][name] = {"samples": n, "of": int(t.size), "first": iso_ns(first),
                                                  "last": iso_ns(last), "start_offset_s": (first - self.launch_ns) / 1e9}
        if is_base and strict and n == t.size:
            raise InputError(text + " - wrong launch time in dive.yaml or wrong logger clock/time format")
        self._loud(text)

    def overlap(self, name: str, source: str, base_name: str, base_t: np.ndarray, t: np.ndarray,
                min_overlap: float) -> None:
        from hadal.ingest.align import describe_offset, overlap_stats

        if t.size == 0:
            self.tc["overlap"][name] = {"overlap": 0.0, "offset_s": None, "samples": 0}
            self._loud(f"{source}: no {name} samples left to align: its columns are empty (flag 9)")
            return
        st = overlap_stats(base_t, t)
        self.tc["overlap"][name] = st
        if st["overlap"] < min_overlap:
            self._loud(f"{source}: {name} overlaps the {base_name} time base by only {st['overlap']:.0%} "
                       f"(< {min_overlap:.0%}); its data start {describe_offset(st['offset_s'])} from the time "
                       f"base's (midpoints {describe_offset(st['midpoint_offset_s'], False)} apart): base samples outside "
                       f"its span get NaN (flag 9) - check its clock, time zone or time format")


def _check_sensor_keys(vehicle: VehicleConfig, where: str, table: Mapping[str, Any] | None) -> None:
    """A mapping keyed by sensor names (``ingest.max_gap_s``) naming a sensor the vehicle does not have is a
    :class:`~hadal.errors.ConfigError` (``guage``), except the packaged defaults' names (``position``...),
    which another vehicle may lack."""
    from hadal.errors import ConfigError

    try:
        from hadal.settings import IngestParams as Params

        defaults = set(Params.model_fields["max_gap_s"].default or {})
    except Exception:  # noqa: BLE001 - the stage module is optional here (library use)
        defaults = set()
    unknown = [k for k in (table or {}) if k not in vehicle.sensors and k not in defaults]
    if unknown:
        raise ConfigError(f"{where}: unknown sensor {unknown[0]!r} (the vehicle's sensors: "
                          f"{', '.join(vehicle.sensors)})")


def _time_cleaning_notes(tc: _TimeChecks, source: str, name: str, st: Mapping[str, Any], n_rows: int,
                         alternatives: Sequence[str] = ()) -> None:
    """Warnings for what :func:`hadal.ingest.align.clean_times` did to one stream (loud ones in the notes)."""
    if st["clock_jump_rows"]:
        tc._loud(f"{source}: {st['clock_jump_rows']} {name} row(s) in {st['clock_jumps']} backward clock jump(s) "
                 f"(up to {st['clock_jump_max_s']:.3g} s back) dropped: they overlap data already logged and "
                 "their times cannot be trusted - check the logger clock")
    if st["coarse_rows"] and st["coarse_rows"] <= max(0.01 * n_rows, 4):
        warnings.warn(f"{source}: {st['coarse_rows']} {name} row(s) share a time stamp with a row holding different "
                      "values: not duplicates; spread evenly within the stamp interval", stacklevel=3)
    elif st["coarse_rows"]:
        tc._loud(f"{source}: {st['coarse_rows']} {name} row(s) share their time stamp with other rows holding "
                 f"different values (up to {st['coarse_max_per_stamp']} per stamp): the time stamps are coarse "
                 f"(effective resolution {st['coarse_resolution_s']:.3g} s); spread evenly within each stamp "
                 "interval (each stamp taken as the start of its batch) - "
                 + (f"the messages carry a time field ({', '.join(alternatives)}): map it in vehicle.yaml "
                    f"(time: {{field: {alternatives[0]}, ...}}) instead of log_time" if alternatives else
                    "map a finer time field if there is one (e.g. a message header stamp instead of log_time)"))
    if st["out_of_order"] or st["duplicates"]:
        warnings.warn(f"{source}: {st['out_of_order']} out-of-order row(s) (sorted) and {st['duplicates']} "
                      f"identical duplicated row(s) (dropped)", stacklevel=3)


def build_sensor_table(
    sensors: Mapping[str, SensorSamples],
    vehicle: VehicleConfig,
    *,
    max_gap_s: Mapping[str, float],
    default_max_gap_s: float = 2.0,
    qc: Mapping[str, VariableQC] | None = None,
    methods: Mapping[str, str] | None = None,
    launch_ns: int | None = None,
    launch_window_s: tuple[float, float] | None = None,
    strict_launch: bool = True,
    min_overlap: float = MIN_OVERLAP,
) -> tuple[pd.DataFrame, dict[str, Any]]:
    """Align all sensors on the time-base sensor's samples and add QARTOD flags.

    Steps: non-finite values (``inf``) -> NaN (counted); per sensor sort + de-duplicate times (counted);
    per channel (:func:`channel_health`) fill values -> NaN and dead channels (all fill, or more than
    ``max_fail_fraction`` outside the fail span: a failed sensor or a unit mistake, with a unit hint) flagged and
    named in ``meta["dead_channels"]``, the others processed; alignment with per-sensor ``max_gap_s``; ``ioos_qc`` flags; schema validation.

    Time sanity (:class:`_TimeChecks`, recorded in ``meta["time_checks"]``, loud ones also in ``meta["notes"]``
    for the report and as warnings): sample times outside the plausible range (1980 .. now + 1 day) are
    dropped and counted, or an :class:`InputError` with a unit guess ("log_time looks like milliseconds") when
    they are half a sensor's samples or more; with ``launch_ns`` (dive.yaml ``launch.time_utc``) times outside
    ``[launch - before, launch + after]`` (``launch_window_s``, default :data:`LAUNCH_WINDOW_S`) are flagged,
    and a time base entirely outside it is an :class:`InputError` when ``strict_launch``; a sensor whose span
    covers less than ``min_overlap`` of the time base's is a warning with the measured overlap and offset.
    Samples rejected by the readers (non-numeric values) are summed up in ``meta["rejected_samples"]``.
    """
    from hadal.ingest.qc import merge_qc

    qc = merge_qc(qc)
    _check_sensor_keys(vehicle, "ingest.max_gap_s", max_gap_s)
    base_name = vehicle.time_base
    _require_time_base(sensors, base_name)
    meta: dict[str, Any] = {"time_base": base_name, "alignment": {}, "unit_conversions": [], "non_finite_values": {},
                            "read_stats": {}, "notes": []}
    tc = _TimeChecks(meta, launch_ns, launch_window_s or LAUNCH_WINDOW_S)
    rejected_summary(sensors, meta)
    cleaned: dict[str, tuple[np.ndarray, dict[str, np.ndarray]]] = {}
    for name, s in sensors.items():
        s = tc.plausible(name, s, required=name == base_name)
        vals = _checked_values(s, qc, meta)
        empty = [var for var, v in vals.items() if var != SEASOFT_BAD_SCAN and v.size and not np.isfinite(v).any()]
        for var in empty:
            if var in meta.get("dead_channels", {}):
                continue  # named already (all fill values)
            tc._loud(f"{s.source}: {name} {var} has no valid value in any of its {len(s)} row(s) (all missing or "
                     f"non-numeric): the column is empty (flag 9) - check "
                     + ("the vehicle.yaml mapping and the file" if _declares_units_in_config(s.source) else "the file"))
        meta.setdefault("empty_variables", {})[name] = empty
        mapped = [var for var in vals if var != SEASOFT_BAD_SCAN]
        if name == base_name and empty and (len(empty) == len(mapped) or "pressure_ctd_dbar" in empty):
            raise InputError(f"{s.source}: the time-base sensor {name!r} has no valid value in "
                             f"{', '.join(empty)} ({len(s)} row(s), all missing or fill values): nothing to build "
                             "the sensor table on - check "
                             + ("the vehicle.yaml mapping and the file" if _declares_units_in_config(s.source)
                                else "the file"))
        try:
            t, vals, st = clean_times(s.time_ns, vals)
        except InputError as exc:
            raise InputError(f"{s.source}: {name}: {exc}") from None
        _time_cleaning_notes(tc, s.source, name, st, len(s), (s.stats or {}).get("time_field_alternatives", ())
                             if isinstance(s.stats, dict) else ())
        cleaned[name] = (t, vals)
        meta["alignment"][name] = {"source": s.source, **st}
        meta["unit_conversions"].extend(s.conversions)
        meta["read_stats"][name] = s.stats

    base_t, base_vals = cleaned[base_name]
    if base_t.size < 2:
        raise InputError(f"{sensors[base_name].source}: only {base_t.size} sample(s) from the time-base sensor")
    for name, (t, _) in cleaned.items():
        tc.launch_window(name, sensors[name].source, t, is_base=name == base_name, strict=strict_launch)
        if name != base_name:
            tc.overlap(name, sensors[name].source, base_name, base_t, t, min_overlap)
    dt = np.diff(base_t) / 1e9
    meta["time_base_rate_hz"] = float(1.0 / np.median(dt)) if np.median(dt) > 0 else None
    columns = _aligned_columns(sensors, cleaned, base_name, meta, max_gap_s, default_max_gap_s, methods)
    n = base_t.size
    for var in SENSOR_VARIABLES:
        if var not in columns:
            columns[var] = np.full(n, np.nan)
    table_vars = table_variables(columns)
    flags, counts = qc_table({v: columns[v] for v in table_vars}, base_t, qc)
    apply_seasoft_flags(flags, counts, base_vals.get(SEASOFT_BAD_SCAN), meta, sensors[base_name].source)
    flag_dead_channels(flags, counts, meta)
    meta["qc_counts"] = counts
    df = pd.DataFrame({"time": pd.to_datetime(base_t, unit="ns", utc=True)})
    for var in table_vars:  # each column moved into the table, not copied next to the one it came from
        df[var] = columns.pop(var).astype(np.float64, copy=False)
    for var in table_vars:
        df[f"{var}_qc"] = flags.pop(f"{var}_qc").astype(np.uint8, copy=False)
    del cleaned, base_t, base_vals, columns, flags, dt  # the table holds the samples now
    validate_sensor_table(df)
    return df, meta


def _require_time_base(sensors: Mapping[str, SensorSamples], base_name: str) -> None:
    """An :class:`InputError` (saying why, when the reader rejected samples) when the time base has no samples."""
    if base_name not in sensors or len(sensors[base_name]) == 0:
        st = sensors[base_name].stats if base_name in sensors else {}
        why = ""
        if isinstance(st, dict) and (st.get("rejected_samples") or st.get("bad_times")):
            why = (f" ({sensors[base_name].source}: {st.get('rejected_samples', 0)} sample(s) rejected for a value "
                   f"that is not a number, {st.get('bad_times', 0)} without a valid time)")
        raise InputError(f"no samples from the time-base sensor {base_name!r}{why}: cannot build the sensor table")


def _checked_values(s: SensorSamples, qc: Mapping[str, VariableQC], meta: dict[str, Any]) -> dict[str, np.ndarray]:
    """``s``'s values with ``inf`` set to NaN (counted, warned) and each variable checked by
    :func:`channel_health` (fill values -> NaN; a dead channel recorded in ``meta["dead_channels"]``, flagged by
    :func:`flag_dead_channels`). Nothing here refuses the input: a bad channel never stops the others."""
    vals = {}
    for var, v in s.values.items():
        bad = np.isinf(v)
        if bad.any():
            meta["non_finite_values"][var] = int(bad.sum())
            warnings.warn(f"{s.source}: {int(bad.sum())} infinite {var} value(s) set to NaN (flag 9)", stacklevel=3)
            v = np.where(bad, np.nan, v)
        if var in CANONICAL_UNITS:
            v = channel_health(v, var, qc.get(var), meta, source=s.source, sensor=s.name, conversions=s.conversions)
        vals[var] = v
    return vals


def _declares_units_in_config(source: str) -> bool:
    """True when a source's units come from the vehicle config (MCAP/CSV mappings), not from the file (.cnv/.hex
    headers name their own units)."""
    return source.startswith(("mcap:", "csv:"))


def _unit_hint(v: np.ndarray, var: str, unit: str | None, cfg: VariableQC, source: str) -> str | None:
    """A hint naming the unit in which most of ``v`` (canonical values, mostly outside the fail span) would lie
    inside it (``mS/cm`` logged as ``S/m``), or ``None`` when no unit of the dimension fits 90 % of them."""
    from hadal.ingest.units import unit_alternatives

    x = v[np.isfinite(v)]
    if x.size == 0 or cfg.fail_span is None:
        return None
    lo, hi = sorted(cfg.fail_span)
    slo, shi = sorted(cfg.suspect_span) if cfg.suspect_span else (lo, hi)
    best = None
    for alt, ratio in unit_alternatives(var, unit):
        y = x / ratio
        inside = float(np.count_nonzero((y >= lo) & (y <= hi)) / x.size)
        typical = float(np.count_nonzero((y >= slo) & (y <= shi)) / x.size)  # tie-break: the usual range
        score = (inside, typical, -abs(np.log10(ratio)))  # then the smallest factor
        if inside >= 0.9 and (best is None or score > best[2:]):
            best = (alt, ratio, *score)
    if best is None:
        return None
    declared = unit or CANONICAL_UNITS[var]
    where = "in the vehicle config" if _declares_units_in_config(source) else "for this channel"
    return (f"{best[2]:.0%} of them fit the range if logged in {best[0]} rather than {declared} (values x "
            f"{1 / best[1]:g}): wrong units {where}?")


def channel_health(v: np.ndarray, var: str, cfg: VariableQC | None, meta: dict[str, Any], *, source: str,
                   sensor: str, conversions: Sequence[Mapping[str, Any]] = ()) -> np.ndarray:
    """One channel's values with its fill values made NaN, and the channel judged (degrade per channel, not per
    dive: nothing here raises).

    * Fill values (:func:`hadal.ingest.qc.fill_mask` on the values as logged, recovered through the conversion
      records by :func:`hadal.ingest.units.raw_values`: 9.9e5 uS/cm, -9.99e-29, -1 "no bottom" of an altitude)
      are missing data (NaN, flag 9), counted in ``meta["fill_values"][var]`` and warned about.
    * A channel whose values are all fill values, or with more than ``cfg.max_fail_fraction`` of its remaining
      values outside ``cfg.fail_span`` (a failed sensor or a unit mistake), or whose every value is the same number
      (at least ``cfg.constant_record_min_samples`` of them: a stuck sensor), is dead: recorded in
      ``meta["dead_channels"][var]`` (reason, QARTOD flag 9 or 4, unit hint), named in a warning and in
      ``meta["notes"]`` for the report. :func:`flag_dead_channels` flags it 4 throughout after the QC tests.
    """
    from hadal.ingest.qc import fill_mask
    from hadal.ingest.units import raw_values

    raw, unit = raw_values(v, [dict(c) for c in conversions], var)
    finite = np.isfinite(v)
    fills = fill_mask(raw, v, cfg) & finite
    n_fill, n_finite = int(fills.sum()), int(finite.sum())
    if n_fill:
        shown = sorted({float(f"{x:.6g}") for x in np.unique(raw[fills])[:5]})
        meta.setdefault("fill_values", {})[var] = {"sensor": sensor, "source": source, "count": n_fill,
                                                   "of": int(v.size), "values_as_logged": shown,
                                                   "unit_as_logged": unit or CANONICAL_UNITS[var], "qartod_flag": 9}
        text = (f"{source}: {n_fill} of {v.size} {var} value(s) are fill values "
                f"({', '.join(f'{x:g}' for x in shown)} as logged): missing data (flag 9)")
        if cfg is not None and n_fill > cfg.max_fail_fraction * max(n_finite, 1):
            meta.setdefault("notes", []).append(text)  # mostly missing: for the report too
        warnings.warn(text, stacklevel=4)
        v = np.where(fills, np.nan, v)
    dead: dict[str, Any] | None = None
    if n_fill and n_fill == n_finite:
        dead = {"reason": "all fill values", "qartod_flag": 9,
                "text": f"every one of its {n_fill} value(s) is a fill value (no data)"}
    elif cfg is not None and cfg.fail_span is not None and (ff := fail_fraction(v, cfg)) > cfg.max_fail_fraction:
        lo, hi = sorted(cfg.fail_span)
        hint = _unit_hint(v, var, unit, cfg, source)
        dead = {"reason": "out of range", "qartod_flag": 4, "fraction_out_of_range": round(ff, 4),
                "range": [lo, hi], "unit": CANONICAL_UNITS[var],
                "text": f"{ff:.0%} of its values are outside the plausible range [{lo:g}, {hi:g}] "
                        f"{CANONICAL_UNITS[var]}" + (f"; {hint}" if hint else
                                                     " (a failed sensor, or wrong units)")}
        if hint:
            dead["hint"] = hint
    elif cfg is not None and cfg.constant_record_min_samples is not None \
            and (fin := v[np.isfinite(v)]).size >= cfg.constant_record_min_samples and fin.min() == fin.max():
        dead = {"reason": "constant", "qartod_flag": 4, "constant_value": float(fin[0]),
                "text": f"every one of its {fin.size} values is exactly {fin[0]:g} {CANONICAL_UNITS[var]} "
                        "(a stuck or disconnected sensor)"}
    if dead is not None:
        dead.update({"sensor": sensor, "source": source, "fill_values": n_fill, "values": int(v.size)})
        meta.setdefault("dead_channels", {})[var] = dead
        text = (f"{source}: {sensor} channel {var} is dead - {dead['text']}: flagged {dead['qartod_flag']} "
                "throughout and left out of what needs it; the other channels are processed")
        meta.setdefault("notes", []).append(text)
        warnings.warn(text, stacklevel=4)
    return v


def flag_dead_channels(flags: dict[str, np.ndarray], counts: dict[str, dict[str, int]], meta: Mapping[str, Any]
                       ) -> None:
    """QARTOD flag 4 on every present value of the channels :func:`channel_health` found dead out of range (the few
    in-range values of a failed sensor are not trusted either; missing values keep 9). In place."""
    for var, d in (meta.get("dead_channels") or {}).items():
        f = flags.get(f"{var}_qc")
        if f is None:
            continue
        f[f != 9] = 4 if d.get("qartod_flag") == 4 else 9
        vals, n = np.unique(f, return_counts=True)
        counts[var] = {str(int(k)): int(c) for k, c in zip(vals, n, strict=True)}


def _aligned_columns(sensors: Mapping[str, SensorSamples], cleaned: dict[str, tuple[np.ndarray, dict[str, np.ndarray]]],
                     base_name: str, meta: dict[str, Any], max_gap_s: Mapping[str, float], default_max_gap_s: float,
                     methods: Mapping[str, str] | None) -> dict[str, np.ndarray]:
    """Every sensor's variables on the time base's samples (:func:`build_sensor_table`); fills ``meta["alignment"]``."""
    base_t = cleaned[base_name][0]
    columns: dict[str, np.ndarray] = {}
    for name, (t, vals) in cleaned.items():
        if name == base_name:
            for var, v in vals.items():
                columns[var] = v
            meta["alignment"][name].update({"samples": int(t.size), "method": "time base"})
            continue
        gap = asked = float(max_gap_s.get(name, default_max_gap_s))
        # a limit shorter than the sensor's own sampling interval would blank almost every base sample
        # (a 1 Hz stream with jitter under a 1.0 s limit): widen it to 1.5 intervals and say so
        step = float(np.median(np.diff(t))) / 1e9 if t.size > 1 else 0.0
        held = [v for v in vals if {**DEFAULT_METHODS, **dict(methods or {})}.get(v) == "nearest"]
        # a held (nearest-sample) value is not widened with it: each reading goes to the base samples within the
        # asked limit or half the base's own interval, not to every sample up to 0.75 readings away
        base_step = float(np.median(np.diff(base_t))) / 1e9 if base_t.size > 1 else 0.0
        near_gap = max(asked, 0.5 * base_step)
        if 1.5 * step > gap:
            gap = 1.5 * step
            kept = f" ({', '.join(held)}: each reading held within {near_gap:.3g} s)" \
                if held and near_gap < gap else ""
            warnings.warn(f"{sensors[name].source}: max_gap_s for {name!r} ({asked:g} s) is shorter than 1.5 x its "
                          f"sampling interval ({step:.3g} s); using {gap:.3g} s{kept}", stacklevel=3)
        aligned, st = align_sensor(base_t, t, vals, gap, dict(methods or {}), nearest_max_gap_s=min(near_gap, gap))
        columns.update(aligned)
        meta["alignment"][name].update(st)
    return columns


def validate_sensor_table(df: pd.DataFrame, *, profile: bool = False) -> None:
    """Validate ``df`` against ``schemas/sensors.yaml`` with pandera (column set, dtypes, unique increasing
    time, QC flag values); a failure is an :class:`InputError` with the first problem.

    ``profile``: a cast without a time base — ``time`` must then be entirely NaT (same dtype), everything
    else as the contract says."""
    import pandera.pandas as pa

    sch = sensors_schema()
    cols: dict[str, Any] = {}
    flag_values = qc_flag_values()
    for name, c in sch["columns"].items():
        if name == "time" and profile:
            cols[name] = pa.Column("datetime64[ns, UTC]", nullable=True,
                                   checks=pa.Check(lambda s: bool(s.isna().all()), error="profile time not all NaT"))
        elif name == "time":
            cols[name] = pa.Column("datetime64[ns, UTC]", nullable=False, unique=True,
                                   checks=pa.Check(lambda s: s.is_monotonic_increasing, error="time not increasing"))
        else:
            cols[name] = pa.Column(c.get("dtype", "float64"), nullable=True)
            cols[f"{name}_qc"] = pa.Column("uint8", checks=pa.Check.isin(flag_values), nullable=False)
    for name, c in (sch.get("optional_columns") or {}).items():
        cols[name] = pa.Column(c.get("dtype", "float64"), nullable=True, required=False)
        cols[f"{name}_qc"] = pa.Column("uint8", checks=pa.Check.isin(flag_values), nullable=False, required=False)
    schema = pa.DataFrameSchema(cols, strict=True, ordered=False)
    try:
        schema.validate(df, lazy=False, inplace=True)  # checks only (nothing coerced): no copy of the table
    except (pa.errors.SchemaError, pa.errors.SchemaErrors) as exc:
        first = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        raise InputError(f"sensor table does not follow schemas/sensors.yaml: {first}") from None
