"""Stage ``grid`` end to end on a tiny synthetic raw dive: products, contract, CF/ACDD, bad input."""

from __future__ import annotations

import gzip

import numpy as np
import pytest
import xarray as xr
import yaml
from pydantic import ValidationError

from hadal.errors import InputError, StageError
from hadal.geo import LocalFrame
from hadal.pipeline import make_context, run_stage
from hadal.settings import GridParams

FRAME = LocalFrame(11.33, 142.2)


def _write_ply(path, pts):
    head = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(pts)}\n"
            "property double x\nproperty double y\nproperty double z\nend_header\n").encode()
    path.write_bytes(head + np.asarray(pts, "<f8").tobytes())


@pytest.fixture
def raw_dive(tmp_path):
    rng = np.random.default_rng(0)
    raw = tmp_path / "raw"
    (raw / "multibeam").mkdir(parents=True)
    (raw / "laser").mkdir()
    for line in (1, 2):
        n = 4000
        x, y = rng.uniform(-1000, 1000, n), rng.uniform(-500 + 400 * line, -100 + 400 * line, n)
        z = 8000 + 0.02 * x + rng.normal(0, 1.0, n)
        lon, lat = FRAME.to_lonlat(x, y)
        with gzip.open(raw / "multibeam" / f"em122_line{line:02d}.xyz.gz", "wt") as fh:
            np.savetxt(fh, np.column_stack([lon, lat, z]), fmt="%.8f %.8f %.3f")
    for k in (1, 2):
        m = 20_000
        pts = np.column_stack([rng.uniform(0, 1.0, m), rng.uniform(0, 0.4, m), -1400 + 0.001 * rng.normal(size=m)])
        _write_ply(raw / "laser" / f"submap_{k:02d}.ply", pts)
    dive = {
        "dive_id": "T001", "platform": "test",
        "launch": {"latitude_deg": 11.33, "longitude_deg": 142.2},
        "map_frame": {"origin_latitude_deg": 11.33, "origin_longitude_deg": 142.2},
        "sources": {"multibeam": ["multibeam/em122_line01.xyz.gz", "multibeam/em122_line02.xyz.gz"],
                    "laser": ["laser/submap_01.ply", "laser/submap_02.ply"]},
    }
    (raw / "dive.yaml").write_text(yaml.safe_dump(dive))
    return raw


def _set_sources(raw, **sources):
    d = yaml.safe_load((raw / "dive.yaml").read_text())
    d["sources"] = sources
    (raw / "dive.yaml").write_text(yaml.safe_dump(d))


def test_stage_contract():
    from hadal.stages import STAGE_GROUPS, dtm, laser

    assert STAGE_GROUPS["grid"] == ("dtm", "laser")
    d, la = dtm.STAGE, laser.STAGE
    assert d.products == ("dtm",) and la.products == ("laser_grids",) and d.reads == la.reads == ()
    assert d.config_section == la.config_section == "grid"  # one configuration section, split by field
    assert set(d.param_fields) | set(la.param_fields) == set(GridParams.model_fields)
    assert not set(d.param_fields) & {"laser_resolution_m", "laser_sor_neighbors"}
    p = GridParams()
    assert p.dtm_resolution_m == "auto" and p.laser_resolution_m == "auto"
    for bad in (0, -5, float("nan"), "fine"):
        with pytest.raises(ValidationError):
            GridParams(dtm_resolution_m=bad)


@pytest.mark.parametrize("spacing_m, expected_m", [(10.0, 20.0), (3.0, 5.0), (0.05, 0.1), (40.0, 100.0), (230.0, 500.0)])
def test_auto_resolution_is_twice_the_sounding_spacing(spacing_m, expected_m):
    """Oracle: soundings on a regular lattice have nearest-neighbour distance = the lattice spacing; the cell is
    the 1-2-5 value nearest (in log) to twice that, whatever the survey's position and orientation."""
    from hadal.grid.multibeam import auto_resolution_m

    i, j = np.meshgrid(np.arange(60), np.arange(40))
    a = np.radians(30.0)
    x, y = i.ravel() * spacing_m, j.ravel() * spacing_m
    xr_, yr_ = 5e5 + x * np.cos(a) - y * np.sin(a), -3e5 + x * np.sin(a) + y * np.cos(a)
    res, info = auto_resolution_m(xr_, yr_)
    assert res == expected_m and info["nn_quantile_m"] == pytest.approx(spacing_m, rel=1e-6)


def test_grid_stage_publishes_dtm_and_laser_grids(raw_dive, tmp_path):
    ctx = make_context(raw_dive, tmp_path / "store")
    out = run_stage("grid", ctx)
    assert set(out) == {"dtm", "laser_grids"}
    dtm = xr.open_dataset(out["dtm"].file("dtm.nc"), engine="h5netcdf")
    for v in ("depth_m", "depth_median_m", "count", "depth_std_m", "uncertainty_m", "filled", "lat", "lon", "crs"):
        assert v in dtm.variables, v
    assert dtm["depth_m"].dims == ("y", "x") and dtm["lat"].dims == ("y", "x")
    assert np.all(np.diff(dtm.x) > 0) and np.all(np.diff(dtm.y) > 0)
    assert dtm.attrs["map_frame_origin_latitude_deg"] == 11.33 and dtm.attrs["resolution"] == 20.0
    assert dtm.attrs["Conventions"].startswith("CF-1.8")
    assert int(dtm["count"].sum()) == dtm.attrs["n_soundings_used"] <= 8000
    xx = np.broadcast_to(dtm.x.values, dtm["depth_m"].shape)
    err = (dtm["depth_m"] - (8000 + 0.02 * xx)).where(dtm["count"] > 0)
    assert float(np.sqrt((err**2).mean())) < 1.0
    man = out["dtm"].manifest()
    assert len(man["inputs"]) == 2 and man["parameters"]["dtm_resolution_m"] == "auto"
    names = sorted(f["name"] for f in out["laser_grids"].manifest()["files"])
    assert names == ["submap_01.nc", "submap_02.nc"]
    lg = xr.open_dataset(out["laser_grids"].file("submap_01.nc"), engine="h5netcdf")
    assert {"elevation_m", "count", "elevation_std_m"} <= set(lg.data_vars)
    assert lg.attrs["resolution"] == 0.01 and lg.sizes["x"] == 100
    # default: the laser survey's own frame - no projection; the position attributes are the dive's
    assert "crs" not in lg.variables and "local frame" in lg["x"].attrs["long_name"]
    assert lg.attrs["dive_id"] == "T001"
    # each grid's geometry in the manifest (landing's skip check reads it there): as the written file has it
    geometry = out["laser_grids"].manifest()["laser_grid_geometry"]
    for name in names:
        with xr.open_dataset(out["laser_grids"].file(name), engine="h5netcdf") as g:
            assert geometry[name] == {"cell_m": pytest.approx(float(g.attrs["resolution"])), "nx": g.sizes["x"],
                                      "ny": g.sizes["y"]}


def test_products_pass_cf_acdd_compliance(raw_dive, tmp_path):
    pytest.importorskip("compliance_checker")
    from hadal.products.compliance import check_compliance

    _set_sources(raw_dive, multibeam=["multibeam/em122_line01.xyz.gz"], laser=["laser/submap_01.ply"])
    paths = []
    for frame in ("local", "map"):  # laser grids in their own frame, and geolocated in the map frame
        (raw_dive / "pipeline.yaml").write_text(f"grid: {{laser_frame: {frame}}}\n")
        out = run_stage("grid", make_context(raw_dive, tmp_path / "store"))
        paths.append(out["laser_grids"].file("submap_01.nc"))
    assert "crs" in xr.open_dataset(paths[1], engine="h5netcdf").variables
    for path in (out["dtm"].file("dtm.nc"), *paths):
        rep = check_compliance(path)
        assert rep.ok, rep.describe()


def test_missing_and_bad_inputs_publish_nothing(raw_dive, tmp_path):
    store = tmp_path / "store"
    (raw_dive / "laser" / "submap_02.ply").write_bytes(b"ply\nformat binary_little_endian 1.0\n")
    with pytest.raises(InputError, match="submap_02"):
        run_stage("laser", make_context(raw_dive, store))
    assert not (store / "T001").exists() or not any((store / "T001").glob("*/v*"))
    with pytest.raises(InputError, match="submap_02"):  # the group: the DTM (good input) is published, laser not
        run_stage("grid", make_context(raw_dive, store))
    assert [p.name for p in (store / "T001").glob("*/v*")] == ["v001"] and (store / "T001" / "dtm").is_dir()
    _set_sources(raw_dive, multibeam=["multibeam/nope.xyz.gz"])
    with pytest.raises(InputError, match="does not exist"):
        run_stage("grid", make_context(raw_dive, store))
    _set_sources(raw_dive)
    with pytest.raises(StageError, match="lists no multibeam soundings or prior bathymetry grid"):
        run_stage("grid", make_context(raw_dive, store))
    with pytest.raises(StageError, match="lists no laser"):
        run_stage("laser", make_context(raw_dive, store))


def test_multibeam_only_dive(raw_dive, tmp_path):
    _set_sources(raw_dive, multibeam=["multibeam/em122_line01.xyz.gz"])
    out = run_stage("grid", make_context(raw_dive, tmp_path / "store"))
    assert set(out) == {"dtm"}


def test_dtm_and_laser_fingerprints_cover_only_their_own_parameters_and_files(raw_dive, tmp_path):
    """The split's point for re-runs: a changed laser parameter or laser file re-runs `laser` (and landing), not the
    DTM; a changed DTM parameter or multibeam file re-runs `dtm`, not the laser grids. Oracle: which fields of the
    `grid:` section and which raw files each stage reads (docs/architecture.md)."""
    from hadal.pipeline import stage_fingerprint

    def prints(pipeline: str | None = None):
        if pipeline is not None:
            (raw_dive / "pipeline.yaml").write_text(pipeline)
        ctx = make_context(raw_dive, tmp_path / "store")
        return {n: stage_fingerprint(n, ctx) for n in ("dtm", "laser")}

    base = prints()
    laser_param = prints("grid: {laser_sor_neighbors: 7}\n")
    assert laser_param["dtm"] == base["dtm"] and laser_param["laser"] != base["laser"]
    dtm_param = prints("grid: {dtm_resolution_m: 50.0}\n")
    assert dtm_param["laser"] == base["laser"] and dtm_param["dtm"] != base["dtm"]
    (raw_dive / "pipeline.yaml").unlink()
    assert prints() == base
    with open(raw_dive / "laser" / "submap_02.ply", "ab") as fh:  # a changed laser file
        fh.write(b"\0" * 24)
    laser_file = prints()
    assert laser_file["dtm"] == base["dtm"] and laser_file["laser"] != base["laser"]
