"""Ingest: raw vehicle logs (MCAP, CSV, Sea-Bird .cnv) -> one validated, time-aligned sensor table.

Public API
----------
* :func:`read_cnv` - Sea-Bird SeaSoft ``.cnv`` -> DataFrame (file's column names; header in ``df.attrs``).
* :func:`read_mcap` / :func:`read_mcap_tables` / :func:`mcap_info` - MCAP (JSON and ROS 2 CDR channels),
  with recovery of truncated/corrupted files (:class:`McapReport`: messages read/lost).
* :func:`read_sensor_csv` - sensor CSV with configurable columns, units, time format.
* :class:`VehicleConfig` / :func:`load_vehicle_config` - per-sensor MCAP topic / CSV column mapping.
* :func:`convert` - explicit unit conversions (recorded in the product metadata).
* :func:`clean_times`, :func:`align_sensor` - de-duplication and gap-limited alignment on the CTD time base.
* :func:`qc_flags` / :data:`DEFAULT_QC` - QARTOD flags with ``ioos_qc``.
* :func:`build_sensor_table` - all of the above -> the ``sensors`` table (``schemas/sensors.yaml``).
"""

from typing import Any

from hadal._lazy import lazy_attr

#: public name -> the submodule defining it, imported on first use (PEP 562): importing one reader (``hadal
#: inspect``, the stages) does not import them all (ioos_qc, numba, pandas: seconds)
_WHERE = {
    **dict.fromkeys(("align_linear", "align_nearest", "align_sensor", "clean_times"), "align"),
    **dict.fromkeys(("SENSOR_VARIABLES", "build_sensor_table", "field_metadata", "read_csv_sensors",
                     "read_mcap_sensors", "sensors_schema", "validate_sensor_table"), "build"),
    **dict.fromkeys(("cnv_sensor_samples", "cnv_time_ns", "parse_latlon", "read_cnv"), "cnv"),
    **dict.fromkeys(("SensorSamples", "parse_time", "read_sensor_csv", "sensor_from_records"), "csv_reader"),
    **dict.fromkeys(("McapReport", "McapTopic", "mcap_info", "read_mcap", "read_mcap_tables"), "mcap_reader"),
    **dict.fromkeys(("DEFAULT_QC", "VariableQC", "qc_flags", "qc_table"), "qc"),
    **dict.fromkeys(("CANONICAL_UNITS", "convert", "normalise_unit"), "units"),
    **dict.fromkeys(("VehicleConfig", "default_vehicle_config_path", "load_vehicle_config"), "vehicle"),
}


def __getattr__(name: str) -> Any:
    return lazy_attr(__name__, _WHERE, name)


def __dir__() -> list[str]:
    return sorted({*globals(), *_WHERE})


__all__ = [
    "CANONICAL_UNITS", "DEFAULT_QC", "SENSOR_VARIABLES", "McapReport", "McapTopic", "SensorSamples", "VariableQC",
    "VehicleConfig", "align_linear", "align_nearest", "align_sensor", "build_sensor_table", "clean_times", "cnv_sensor_samples", "cnv_time_ns",
    "convert", "default_vehicle_config_path", "field_metadata", "load_vehicle_config", "mcap_info",
    "normalise_unit", "parse_latlon", "parse_time", "qc_flags", "qc_table", "read_cnv", "read_csv_sensors",
    "read_mcap", "read_mcap_sensors", "read_mcap_tables", "read_sensor_csv", "sensor_from_records",
    "sensors_schema", "validate_sensor_table",
]
