"""The ``sensors`` columns' attributes are declared once, in the variable registry (``schemas/variables.yaml``):
``schemas/sensors.yaml`` keeps only the table contract (column set, dtypes, time rules)."""

from __future__ import annotations

from hadal.ingest.build import SENSOR_VARIABLES, field_metadata, qc_flag_values, sensors_schema
from hadal.registry import column_attrs, registry


def test_sensors_yaml_declares_no_attributes():
    cols = sensors_schema()["columns"]
    assert list(cols) == ["time", *SENSOR_VARIABLES]
    for name, col in cols.items():
        assert not {"units", "standard_name", "long_name"} & set(col), name
    assert not {"qc_flag_values", "qc_flag_meanings"} & set(sensors_schema())


def test_field_metadata_is_the_registry():
    fm = field_metadata()
    assert set(fm) == {"time", *SENSOR_VARIABLES, *(f"{v}_qc" for v in SENSOR_VARIABLES)}
    for name, attrs in fm.items():
        spec = registry().spec(name)
        assert "sensors" in spec.products, name
        assert attrs == column_attrs(name), name
    assert fm["conductivity_s_m"]["units"] == "S m-1"
    assert fm["pressure_ctd_dbar"]["standard_name"] == "sea_water_pressure"
    assert fm["pressure_ctd_dbar_qc"]["flag_values"] == "1 2 3 4 9"
    assert qc_flag_values() == [1, 2, 3, 4, 9]
