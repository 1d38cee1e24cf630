"""The report's units come from the variable registry (issue 20 item 1), not from strings in the report code."""

from __future__ import annotations

import pytest

from hadal.registry import variable_attrs
from hadal.report import summary_rows
from hadal.report import units as report_units


def test_display_units_of_the_declared_variables():
    cf_units = pytest.importorskip("cf_units")
    for name, shown in (("temperature_its90_degc", "°C"), ("density_kg_m3", "kg/m³"), ("conductivity_s_m", "S/m"),
                        ("gravity_m_s2", "m/s²"), ("pressure_dbar", "dbar"), ("practical_salinity", "")):
        declared = variable_attrs(name)["units"]
        assert report_units.units_of(name) == shown
        # the displayed form is the declared unit (checked by cf_units, an independent UDUNITS parser)
        assert cf_units.Unit(declared).is_convertible(cf_units.Unit(shown.replace("³", "3").replace("²", "2")
                                                                        .replace("°C", "degC") or "1"))


def test_report_follows_a_unit_changed_in_the_registry(monkeypatch):
    real = report_units.variable_attrs

    def kelvin(name, on_grid=False, where=""):
        return {**real(name, on_grid, where), "units": "K"} if name == "temperature_its90_degc" else real(name, on_grid, where)

    monkeypatch.setattr(report_units, "variable_attrs", kelvin)
    rows = dict(summary_rows({"temperature_its90_degc_range": [274.0, 275.0], "density_kg_m3_range": [1027.0, 1075.0]}))
    assert rows["temperature"] == "274.000 – 275.000 K"
    assert rows["in situ density"] == "1027.000 – 1075.000 kg/m³"
    assert report_units.axis_label("temperature_its90_degc", "temperature ITS-90") == "temperature ITS-90 (K)"
