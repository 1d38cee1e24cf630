"""The variable registry (``schemas/variables.yaml``, :mod:`hadal.registry`): every variable of every
product is declared once, the writers take their CF attributes from it and refuse an undeclared variable; the
declared units are UDUNITS and agree with the CF standard names; the MCAP JSON Schemas are declared once."""

from __future__ import annotations

import fnmatch
import json
import tomllib
import xml.etree.ElementTree as ET
from importlib.resources import files
from pathlib import Path

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest
import xarray as xr
import yaml

from hadal.errors import HadalError
from hadal.products import write_netcdf, write_parquet
from hadal.registry import REGISTRY_FILE, UndeclaredVariableError, parse_registry, registry

REPO = Path(__file__).resolve().parents[3]
REG = registry()


def _one_line(exc: BaseException) -> str:
    msg = str(exc)
    assert "\n" not in msg
    return msg


# ---------------------------------------------------------------- the writers refuse undeclared variables
def test_write_parquet_refuses_an_undeclared_column(tmp_path):
    df = pd.DataFrame({"depth_m": [1.0, 2.0], "depth_of_my_guess_m": [3.0, 4.0]})
    with pytest.raises(UndeclaredVariableError) as ei:
        write_parquet(df, tmp_path / "ctd.parquet")
    msg = _one_line(ei.value)
    assert "ctd.parquet" in msg and "'depth_of_my_guess_m'" in msg and REGISTRY_FILE in msg
    assert isinstance(ei.value, HadalError) and isinstance(ei.value, ValueError)
    assert not (tmp_path / "ctd.parquet").exists()
    # caller attributes do not make a variable declared
    with pytest.raises(UndeclaredVariableError):
        write_parquet(df, tmp_path / "ctd.parquet", fields={"depth_of_my_guess_m": {"units": "m", "long_name": "x"}})


def test_write_netcdf_refuses_an_undeclared_variable(tmp_path):
    ds = xr.Dataset({"temperature_its90_degc": ("pressure_dbar", [2.0, 1.5]),
                     "salinity_by_suffix_degc": ("pressure_dbar", [1.0, 2.0], {"units": "degree_C"})},
                    coords={"pressure_dbar": [10.0, 20.0]})
    with pytest.raises(UndeclaredVariableError, match=r"profile\.nc: variable 'salinity_by_suffix_degc'") as ei:
        write_netcdf(ds, tmp_path / "profile.nc", title="t", summary="s")
    _one_line(ei.value)
    assert not (tmp_path / "profile.nc").exists()


def test_attributes_come_from_the_registry_and_the_caller_wins(tmp_path):
    ds = xr.Dataset({"depth_m": (("y", "x"), np.full((2, 3), 10.0)), "count": (("y", "x"), np.ones((2, 3), "i4"))},
                    coords={"x": [0.0, 20.0, 40.0], "y": [0.0, 20.0]})
    ds["count"].attrs["long_name"] = "soundings per cell"
    path = write_netcdf(ds, tmp_path / "dtm.nc", title="t", summary="s")
    with xr.open_dataset(path) as out:
        d, c = out["depth_m"].attrs, out["count"].attrs
        # the grid layer's declaration: seafloor depth, cell mean
        assert d["standard_name"] == "sea_floor_depth_below_sea_surface" and d["cell_methods"] == "area: mean"
        assert d["units"] == "m" and d["positive"] == "down"
        assert c["standard_name"] == "sea_floor_depth_below_sea_surface number_of_observations"
        assert c["long_name"] == "soundings per cell" and c["units"] == "1"
        assert out["x"].attrs["standard_name"] == "projection_x_coordinate" and out["x"].attrs["axis"] == "X"
    # off the grid the same names are the vehicle's depth and the samples per pressure bin
    prof = xr.Dataset({"depth_m": ("pressure_dbar", [9.9, 19.8]), "count": ("pressure_dbar", np.array([3, 4], "i4"))},
                      coords={"pressure_dbar": [10.0, 20.0]})
    path = write_netcdf(prof, tmp_path / "profile.nc", title="t", summary="s")
    with xr.open_dataset(path) as out:
        assert out["depth_m"].attrs["standard_name"] == "depth"
        assert out["count"].attrs["standard_name"] == "sea_water_pressure number_of_observations"


def test_qc_pattern_needs_a_declared_base():
    spec = REG.find("pressure_dbar_qc")
    assert spec is not None and spec.long_name == "QARTOD flag of pressure_dbar"
    assert spec.flag_values == [1, 2, 3, 4, 9] and spec.standard_name == "aggregate_quality_flag"
    assert REG.find("not_a_variable_qc") is None
    assert REG.find("pressure_dbar_qcx") is None


def test_suffixes_are_not_guessed_any_more():
    # c_s / p_s ended in "_s" and were once given units of seconds by the suffix table
    assert REG.spec("c_s").units == "1" and REG.spec("p_s").units == "1"
    for name in ("anything_m", "foo_dbar", "bar_degc"):
        assert REG.find(name) is None


# ---------------------------------------------------------------- the registry file itself
def test_malformed_registry_is_a_one_line_error():
    data = yaml.safe_load((files("hadal.schemas") / REGISTRY_FILE).read_text(encoding="utf-8"))
    bad = json.loads(json.dumps(data))
    bad["variables"]["in_region"]["flag_meanings"] = "only_one"
    with pytest.raises(UndeclaredVariableError, match="flag_meanings must name every flag") as ei:
        parse_registry(bad)
    _one_line(ei.value)
    bad = json.loads(json.dumps(data))
    bad["variables"]["depth_m"]["unit"] = "m"  # a typo of a key is refused, not ignored
    with pytest.raises(UndeclaredVariableError, match="depth_m"):
        parse_registry(bad)
    bad = json.loads(json.dumps(data))
    bad["variables"]["entropy"]["standard_name"] = "sea_floor_depth_below_sea_surface"
    with pytest.raises(UndeclaredVariableError, match="no_cf_standard_name"):
        parse_registry(bad)


def _cf_table() -> dict[str, str]:
    cc = pytest.importorskip("compliance_checker")
    path = Path(cc.__file__).parent / "data" / "cf-standard-name-table.xml"
    if not path.is_file():
        pytest.skip("compliance-checker ships no CF standard name table")
    root = ET.parse(path).getroot()
    out = {e.get("id"): (e.findtext("canonical_units") or "").strip() for e in root.iter("entry")}
    for a in root.iter("alias"):
        target = a.findtext("entry_id")
        if target in out:
            out[a.get("id")] = out[target]
    return out


_MODIFIERS = {"number_of_observations": "1", "standard_error": None}


def _all_attrs():
    for name, spec in REG.variables.items():
        yield name, spec.attrs(False)
        if spec.grid is not None:
            yield f"{name} (grid)", spec.attrs(True)
    for p in REG.patterns:
        yield p.pattern, p.cf_attrs()


def test_units_are_udunits_and_match_the_cf_canonical_units():
    cf_units = pytest.importorskip("cf_units")
    table = _cf_table()
    checked = 0
    for name, a in _all_attrs():
        units = a.get("units")
        if units is not None:
            u = cf_units.Unit(units)  # raises ValueError on a non-UDUNITS string
            assert not u.is_unknown(), name
        sn = a.get("standard_name")
        if not sn:
            continue
        base, _, modifier = sn.partition(" ")
        assert base in table, f"{name}: standard_name {base!r} is not in the CF standard name table"
        if modifier:
            assert modifier in _MODIFIERS, (name, modifier)
        canonical = _MODIFIERS.get(modifier) or table[base]
        if units is None or canonical == "" or base == "time":
            continue
        assert cf_units.Unit(units).is_convertible(cf_units.Unit(canonical)), (name, units, canonical)
        checked += 1
    assert checked > 30
    # a few known quantities, exactly
    assert REG.spec("pressure_dbar").units == "dbar" and table["sea_water_pressure"] == "dbar"
    assert cf_units.Unit(REG.spec("density_kg_m3").units) == cf_units.Unit(table["sea_water_density"])
    assert cf_units.Unit(REG.spec("sound_speed_m_s").units) == cf_units.Unit(table["speed_of_sound_in_sea_water"])
    assert cf_units.Unit(REG.spec("lat").units).is_convertible(cf_units.Unit(table["latitude"]))


def test_no_cf_standard_name_is_declared_not_inferred():
    from hadal.products.cf import has_no_cf_standard_name

    assert has_no_cf_standard_name("entropy") and has_no_cf_standard_name("gravity_m_s2")
    assert not has_no_cf_standard_name("depth_m") and not has_no_cf_standard_name("gravity_anything")


def test_registry_ships_as_package_data():
    patterns = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["setuptools"]["package-data"]["hadal.schemas"]
    shipped = [p for p in (REPO / "schemas").rglob("*") if p.is_file() and p.suffix in (".yaml", ".json")]
    assert any(p.name == REGISTRY_FILE for p in shipped)
    for p in shipped:
        rel = p.relative_to(REPO / "schemas").as_posix()
        assert any(fnmatch.fnmatch(rel, pat) and rel.count("/") == pat.count("/") for pat in patterns), rel


# ---------------------------------------------------------------- every variable of the sample products
def _product_variables(store_dive: Path):
    """(product, file, name, dtype, values) of every column/variable of the latest version of each product."""
    for prod_dir in sorted(p for p in store_dive.iterdir() if p.is_dir() and not p.name.startswith(".")):
        versions = sorted(v for v in prod_dir.iterdir() if v.is_dir() and v.name.startswith("v"))
        if not versions:
            continue
        for f in sorted(versions[-1].rglob("*.parquet")):
            df = pd.read_parquet(f)
            for field in pq.read_schema(f):
                yield prod_dir.name, f.name, field.name, df[field.name]
        for f in sorted(versions[-1].glob("*.nc")):  # published files (internal/: a stage's hand-over)
            with xr.open_dataset(f, decode_times=False, mask_and_scale=True) as ds:
                for n, v in ds.variables.items():
                    n = str(n)
                    if n == "platform" or "grid_mapping_name" in v.attrs:  # written by the writers themselves
                        continue
                    yield prod_dir.name, f.name, n, v.load()


def test_every_variable_of_the_sample_products_is_declared(small_run):
    ctx, products = small_run
    dive_dir = Path(ctx.store.root) / ctx.dive_id
    seen: set[tuple[str, str]] = set()
    for product, fname, name, values in _product_variables(dive_dir):
        spec = REG.find(name)
        assert spec is not None, f"{product}/{fname}: {name} is not declared"
        assert product in spec.products, f"{product}/{fname}: {name} is declared for {spec.products} only"
        seen.add((product, name))
        arr = np.asarray(values)
        if spec.dtype is not None and fname.endswith(".parquet") and len(arr):
            want = spec.dtype.split("[")[0]
            got = str(values.dtype)
            assert got.startswith(want) or (want.startswith("datetime64") and "datetime64" in got), \
                (product, name, got, spec.dtype)
        if (spec.valid_min is not None or spec.valid_max is not None) and arr.dtype.kind == "f":
            finite = arr[np.isfinite(arr)]
            if finite.size:
                lo = -np.inf if spec.valid_min is None else spec.valid_min
                hi = np.inf if spec.valid_max is None else spec.valid_max
                assert lo <= finite.min() and finite.max() <= hi, (product, fname, name, finite.min(), finite.max())
    made = {p for p, _ in seen}
    assert {"sensors", "ctd", "profile", "dtm", "suitability", "match", "navigation", "laser_grids",
            "landing"} <= made


# ---------------------------------------------------------------- MCAP channel schemas: declared once
def test_synth_mcap_schemas_are_the_schema_files():
    from hadal.synth import writers

    for name, spec in writers.CHANNELS.items():
        on_disk = json.loads((REPO / "schemas" / "mcap" / f"haidou_{name}.json").read_text())
        assert spec["schema"] == on_disk
        assert spec["schema_name"] == on_disk["title"]
        assert on_disk["required"] == list(on_disk["properties"])
    src = Path(writers.__file__).read_text()
    assert '"required"' not in src and "json-schema.org" not in src  # no second copy in the generator
