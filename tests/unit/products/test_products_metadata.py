"""ACDD metadata from dive.yaml without placeholders, NC_CHAR attributes, relative provenance paths, strict JSON,
software provenance in manifests (issue 18)."""

from __future__ import annotations

import json
from importlib import metadata as importlib_metadata
from pathlib import Path

import h5py
import netCDF4
import numpy as np
import pandas as pd
import pytest
import xarray as xr

from hadal.dive import Dive
from hadal.products import dive_attributes, dive_context, missing_acdd_fields, write_netcdf
from hadal.products.geo_landing import iso_utc, strict_json
from hadal.products.io import provenance
from hadal.products.metadata import ACDD_REQUIRED, REQUIRED_FIELDS
from hadal.provenance import software_provenance
from hadal.store import ProductStore

FULL_METADATA = {
    "creator_name": "A. Scientist", "creator_email": "a.scientist@ocean.example.net", "creator_type": "person",
    "creator_url": "https://ocean.example.net/people/a", "institution": "Example Ocean Institute",
    "project": "Hadal Trench Survey 2026", "program": "Deep Ocean Programme", "license": "CC-BY-4.0",
    "naming_authority": "net.example.ocean", "metadata_link": "https://ocean.example.net/data/dive-7",
    "instruments": {"dtm": "Kongsberg EM124 multibeam echosounder"},
    "creator_country": "China", "creator_sector": "academic", "infoUrl": "https://ocean.example.net/data/dive-7",
}


def _dive(metadata=None, **kw) -> Dive:
    return Dive(dive_id="dive-7", platform="Haidou", metadata=metadata or {},
                launch={"latitude_deg": 11.3371, "longitude_deg": 142.2097, "time_utc": "2018-10-06T23:00:00Z"},
                **kw)


def _grid() -> xr.Dataset:
    from hadal.geo import LocalFrame

    fr = LocalFrame(11.33, 142.2)
    x, y = np.arange(0.0, 200.0, 20.0), np.arange(0.0, 100.0, 20.0)
    X, Y = np.meshgrid(x, y)
    lon, lat = fr.to_lonlat(X, Y)
    return xr.Dataset({"depth_m": (("y", "x"), 10900 + X / 100), "lat": (("y", "x"), lat),
                       "lon": (("y", "x"), lon), "crs": ((), 0, {"crs_wkt": fr.crs.to_wkt()})},
                      coords={"x": x, "y": y})


def _store_path(tmp_path: Path, product: str, name: str) -> Path:
    d = tmp_path / "store" / "dive-7" / product / "v001"
    d.mkdir(parents=True)
    return d / name


def test_missing_acdd_fields_lists_exactly_what_dive_yaml_lacks(monkeypatch):
    for k in REQUIRED_FIELDS:
        monkeypatch.delenv(f"HADAL_{k.upper()}", raising=False)
    assert missing_acdd_fields(_dive()) == list(REQUIRED_FIELDS)
    assert missing_acdd_fields(_dive(FULL_METADATA)) == []
    assert missing_acdd_fields(_dive({"creator_name": "x", "license": "CC0-1.0"})) == [
        "creator_email", "institution", "project", "creator_country", "creator_sector", "infoUrl", "creator_url",
        "naming_authority"]  # IOOS-1.2 requires creator_url and naming_authority too (compliance-checker ioos:1.2)
    monkeypatch.setenv("HADAL_INSTITUTION", "Operator Institute")  # a deployment's operator counts
    assert "institution" not in missing_acdd_fields(_dive())


def test_no_placeholder_metadata_without_dive_metadata(tmp_path, monkeypatch):
    for k in ACDD_REQUIRED:
        monkeypatch.delenv(f"HADAL_{k.upper()}", raising=False)
    path = write_netcdf(_grid(), _store_path(tmp_path, "dtm", "dtm.nc"), title="t", summary="s",
                        **dive_attributes(_dive()))
    with netCDF4.Dataset(path) as n:
        attrs = {k: str(n.getncattr(k)) for k in n.ncattrs()}
    text = json.dumps(attrs)
    for fake in ("example.org", "github.com/hadal", "org.hadal", "hadal post-dive processing", "hadal deep-sea vehicle post"):
        assert fake not in text, fake
    for k in ACDD_REQUIRED:
        assert k not in attrs
    assert set(ACDD_REQUIRED) <= set(attrs["hadal_metadata_missing"].split())
    assert "CTD" not in attrs["instrument"] and "MULTIBEAM" in attrs["instrument"]


def test_full_dive_metadata_passes_acdd_with_no_exception(tmp_path):
    pytest.importorskip("compliance_checker")
    from hadal.products.compliance import check_compliance

    dive = _dive(FULL_METADATA)
    path = write_netcdf(_grid(), _store_path(tmp_path, "dtm", "dtm.nc"), title="t", summary="s",
                        **dive_attributes(dive))
    rep = check_compliance(path)
    assert rep.ok, rep.describe()
    # only the documented 2-D-grid vertical-extent exception may remain: no metadata exception at all
    assert all(f.name == "geospatial_vertical_extents_match" for f in rep.findings), rep.describe()
    with netCDF4.Dataset(path) as n:
        assert n.creator_email == FULL_METADATA["creator_email"]
        assert n.instrument == "Kongsberg EM124 multibeam echosounder"  # per product, from dive.yaml
        assert n.project == FULL_METADATA["project"]
        assert "hadal_metadata_missing" not in n.ncattrs()


def test_dive_context_gives_metadata_to_writers_without_dive_attributes(tmp_path):
    with dive_context(_dive(FULL_METADATA), tmp_path):
        path = write_netcdf(_grid(), _store_path(tmp_path, "profile", "x.nc"), title="t", summary="s")
    with netCDF4.Dataset(path) as n:
        assert n.institution == "Example Ocean Institute"
        assert "CTD" in n.instrument  # the profile product: the CTD


def test_string_attributes_are_nc_char(tmp_path):
    path = write_netcdf(_grid(), tmp_path / "g.nc", title="Tïtle with ° sign", summary="s")
    with h5py.File(path, "r") as f:
        for key in ("title", "Conventions", "summary"):
            t = f.attrs.get_id(key).get_type()
            assert isinstance(t, h5py.h5t.TypeStringID) and not t.is_variable_str(), key
        t = f["depth_m"].attrs.get_id("units").get_type()
        assert not t.is_variable_str()
    with netCDF4.Dataset(path) as n:  # netCDF-C reads them as text, UTF-8 intact
        assert n.title == "Tïtle with ° sign"
        assert n["depth_m"].units == "m"


def test_provenance_paths_are_relative_to_the_raw_directory(tmp_path):
    raw = tmp_path / "raw"
    (raw / "logs").mkdir(parents=True)
    f = raw / "logs" / "a.mcap"
    f.write_bytes(b"x")
    store = ProductStore(tmp_path / "store")
    with dive_context(_dive(), raw), store.publish("dive-7", "sensors", inputs=[f]) as draft:
        prov = provenance(draft)
        (draft.path / "x.txt").write_text("x")
    assert prov["inputs"] == ["logs/a.mcap"]
    assert str(tmp_path) not in json.dumps(prov)
    m = json.loads((draft.result.path / "manifest.json").read_text())
    sw = m["software"]
    assert sw["hadal_version"] and sw["command"]
    assert sw["libraries"]["numpy"] == np.__version__  # the imported library's own version
    assert sw["libraries"]["pandas"] == pd.__version__
    assert sw["libraries"]["scipy"] == importlib_metadata.version("scipy")


def test_software_provenance_names_the_libraries():
    sw = software_provenance()
    assert {"numpy", "gsw", "scipy", "open3d", "prefect"} <= set(sw["libraries"])
    import gsw

    assert sw["libraries"]["gsw"] == gsw.__version__
    assert sw["git_commit"] is None or len(sw["git_commit"]) == 40


def test_strict_json_and_timestamps():
    text = strict_json({"a": float("nan"), "b": [np.float64(np.inf), np.int64(3)],
                        "t": pd.Timestamp("2018-10-07T02:32:46", tz="UTC"),
                        "t2": pd.Timestamp("2018-10-07T02:32:46.375000", tz="UTC")})
    data = json.loads(text, parse_constant=lambda c: pytest.fail(f"non-strict JSON constant {c}"))
    assert data == {"a": None, "b": [None, 3], "t": "2018-10-07T02:32:46Z", "t2": "2018-10-07T02:32:46.375Z"}
    assert iso_utc("2026-12-01T19:00:00.000000+00:00") == "2026-12-01T19:00:00Z"
    assert iso_utc("2026-12-01T19:00:00.000250+00:00") == "2026-12-01T19:00:00.000250Z"
    assert json.loads(strict_json({"s": "2018-10-07T02:32:46.375000+00:00"})) == {"s": "2018-10-07T02:32:46.375Z"}
