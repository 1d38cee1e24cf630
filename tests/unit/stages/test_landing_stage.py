"""Stage `landing`: reads `laser_grids` from the store, publishes `landing` (parquet, NetCDF maps, figures)."""

from __future__ import annotations

import json
import math

import numpy as np
import pandas as pd
import pytest
import xarray as xr
from pydantic import ValidationError

from hadal.dive import Dive
from hadal.errors import InputError, StageError
from hadal.products.io import read_parquet_metadata
from hadal.settings import LandingParams, PipelineConfig
from hadal.stages import StageContext
from hadal.stages import landing as stage
from hadal.store import ProductStore

DIVE = "test-landing"


def _submap(ny: int, nx: int, cell: float, slope_deg: float, seed: int, x0: float = 0.0, y0: float = 0.0) -> xr.Dataset:
    rng = np.random.default_rng(seed)
    Y, X = np.mgrid[0:ny, 0:nx] * cell
    z = math.tan(math.radians(slope_deg)) * Y - 1400.0 + 0.002 * rng.standard_normal((ny, nx))
    for _ in range(4):  # rocks
        cy, cx, r, h = rng.uniform(0, ny * cell), rng.uniform(0, nx * cell), rng.uniform(0.05, 0.12), rng.uniform(0.02, 0.25)
        z = np.where((Y - cy) ** 2 + (X - cx) ** 2 <= r * r, z + h, z)
    z[:, :3] = np.nan
    z[ny // 2 : ny // 2 + 10, nx // 3 : nx // 2] = np.nan
    return xr.Dataset(
        {"elevation_m": (("y", "x"), z, {"units": "m", "positive": "up"})},
        coords={"y": y0 + np.arange(ny) * cell, "x": x0 + np.arange(nx) * cell},
    )


def _ctx(tmp_path, **params) -> StageContext:
    dive = Dive.model_validate({"dive_id": DIVE, "launch": {"latitude_deg": 30.0, "longitude_deg": 140.0}})
    cfg = PipelineConfig(landing=LandingParams(**params))
    return StageContext(dive=dive, raw_dir=tmp_path, store=ProductStore(tmp_path / "store"), config=cfg)


def _publish_laser(ctx: StageContext, datasets: dict[str, xr.Dataset | bytes]) -> None:
    with ctx.store.publish(DIVE, "laser_grids") as draft:
        for name, ds in datasets.items():
            if isinstance(ds, bytes):
                (draft.path / f"{name}.nc").write_bytes(ds)
            else:
                ds.to_netcdf(draft.path / f"{name}.nc", engine="h5netcdf")


def test_stage_publishes_sites_maps_and_figures(tmp_path):
    ctx = _ctx(tmp_path, heading_step_deg=15.0)
    _publish_laser(ctx, {"submap_01": _submap(300, 130, 0.02, 8.0, 1),
                         "submap_02": _submap(300, 130, 0.02, 12.0, 2, y0=6.0)})
    out = stage.run(ctx)
    pv = out["landing"]
    assert pv.product == "landing" and ctx.store.verify(pv) == []
    df = pd.read_parquet(pv.file("landing_sites.parquet"))
    for col in ("submap", "heading_deg", "x_m", "y_m", "radius_m", "p_s", "p_f", "p_r", "c_s", "is_best"):
        assert col in df
    assert set(df["submap"]) == {"submap_01", "submap_02"}
    assert set(df["heading_deg"]) <= set(np.linspace(-90, 90, 13))
    assert df.groupby("submap")["is_best"].sum().eq(1).all()
    best1 = df[(df.submap == "submap_01") & df.is_best].iloc[0]
    assert best1["slope_deg"] == pytest.approx(8.0, abs=0.5)
    assert np.allclose(df["c_s"], (df["p_s"] + df["p_f"] + df["p_r"]) / 3)
    meta, fields = read_parquet_metadata(pv.file("landing_sites.parquet"))
    assert meta["table_v"]["number_of_sites"] == len(df)
    assert meta["critical_slope_deg"] == pytest.approx(17.7, abs=0.01)
    assert fields["c_s"]["long_name"].startswith("landing cost")
    with xr.open_dataset(pv.file("submap_01_maps.nc"), engine="h5netcdf") as ds:
        assert ds["exclusion"].shape == (13, 300, 130)
        assert ds["protrusion_height_m"].attrs["units"] == "m"
        assert int(ds["final_site"].sum()) > 0
        assert ds.attrs["Conventions"].startswith("CF")
    summary = json.loads(pv.file("landing_summary.json").read_text())
    assert len(summary["final_sites"]) == 2
    figs = sorted(p.name for p in (pv.path / "figures").glob("*.png"))
    assert "fig25_transect.png" in figs and "fig21_costs_vs_heading.png" in figs
    assert any(f.startswith("fig13_") for f in figs) and any(f.startswith("fig18_") for f in figs)
    assert sum(f.startswith("fig19_") for f in figs) == 2
    assert manifest_upstream(pv) == ["laser_grids"]


def test_figures_drawn_beside_the_analysis_are_those_drawn_in_turn(tmp_path):
    """``figure_processes: 2`` (figures in forked processes while the next submap is analysed, hadal.forkpool) gives
    the same PNG files, byte for byte, as ``figure_processes: 1`` (drawn one after the other here: the oracle)."""
    from hadal.forkpool import can_fork

    if not can_fork():
        pytest.skip("figures are drawn in forked processes on Linux only")
    pngs = {}
    for n in (1, 2):
        ctx = _ctx(tmp_path / f"p{n}", heading_step_deg=30.0, figure_processes=n)
        _publish_laser(ctx, {"submap_01": _submap(200, 90, 0.02, 8.0, 1),
                             "submap_02": _submap(200, 90, 0.02, 12.0, 2, y0=4.0),
                             "submap_03": _submap(200, 90, 0.02, 5.0, 3, y0=8.0)})
        pv = stage.run(ctx)["landing"]
        pngs[n] = {p.name: p.read_bytes() for p in (pv.path / "figures").glob("*.png")}
    assert sum(k.startswith("fig19_") for k in pngs[1]) == 3 and sorted(pngs[1]) == sorted(pngs[2])
    assert all(pngs[1][k] == pngs[2][k] for k in pngs[1])


def manifest_upstream(pv) -> list[str]:
    return [u["product"] for u in pv.manifest()["upstream"]]


def test_stage_needs_laser_grids(tmp_path):
    ctx = _ctx(tmp_path)
    with pytest.raises(StageError, match="laser_grids"):
        stage.run(ctx)


def test_stage_bad_input_publishes_nothing(tmp_path):
    ctx = _ctx(tmp_path, figures=False, heading_step_deg=45.0)
    _publish_laser(ctx, {"submap_01": _submap(120, 60, 0.02, 5.0, 3), "submap_02": b"\x89HDF\r\n truncated"})
    with pytest.raises(InputError, match="submap_02"):
        stage.run(ctx)
    assert not ctx.store.has(DIVE, "landing")
    assert not list((tmp_path / "store" / DIVE / "landing").glob(".staging-*"))
    ctx2 = _ctx(tmp_path / "b", figures=False)
    _publish_laser(ctx2, {"submap_01": xr.Dataset({"depth": (("y", "x"), np.zeros((5, 5)))})})
    with pytest.raises(InputError, match="elevation_m"):
        stage.run(ctx2)


def test_params_in_pipeline_config():
    cfg = PipelineConfig.model_validate({"landing": {"vehicle": {"length_m": 2.0}, "heading_step_deg": 10}})
    assert cfg.landing.vehicle.length_m == 2.0 and cfg.landing.vehicle.width_m == 0.5
    with pytest.raises(ValidationError):
        PipelineConfig.model_validate({"landing": {"nonsense": 1}})


def test_stage_uses_laser_uncertainty_layers(tmp_path):
    ctx = _ctx(tmp_path, figures=False, heading_step_deg=45.0)
    ds = _submap(300, 130, 0.02, 8.0, 1)
    ds["elevation_std_m"] = (("y", "x"), np.full((300, 130), 0.004))
    ds["count"] = (("y", "x"), np.full((300, 130), 16, np.int32))
    _publish_laser(ctx, {"submap_01": ds, "submap_02": _submap(300, 130, 0.02, 12.0, 2, y0=6.0)})
    df = pd.read_parquet(stage.run(ctx)["landing"].file("landing_sites.parquet"))
    p1 = df.loc[df.submap == "submap_01", "p_landable"]
    assert len(p1) and p1.between(0, 1).all()
    assert df.loc[df.submap == "submap_02", "p_landable"].isna().all()  # no uncertainty layers: not computed


def test_params_bounded():
    for bad in ({"block_m": 0}, {"filter_order": 0}, {"local_slope_window_m": 0}, {"heading_step_deg": 0.1},
                {"vehicle": {"length_m": 1e6}}, {"vehicle": {"water_density_kg_m3": 1.0}}, {"workers": -1}):
        with pytest.raises(ValidationError):
            LandingParams(**bad)


def test_a_grid_too_narrow_to_analyse_is_a_skip_reason_not_a_failure(tmp_path):
    """A laser grid one cell wide (a lon/lat LAS whose own scale rounds positions: 1 x 867 cells) is no
    landing surface: the stage is skipped with the shape named; beside a usable grid it is skipped by name
    and the usable one analysed (degrade per input, not per dive)."""
    ctx = _ctx(tmp_path, heading_step_deg=30.0, figures=False)
    strip = xr.Dataset({"elevation_m": (("y", "x"), np.full((1, 867), -1400.0), {"units": "m", "positive": "up"})},
                       coords={"y": [0.0], "x": np.arange(867) * 0.02})
    _publish_laser(ctx, {"strip": strip})
    why = stage.skip_reason(ctx)
    assert why is not None and "strip 1 x 867" in why and "fewer than 3 cells" in why


def test_a_narrow_grid_beside_a_usable_one_is_skipped_by_name(tmp_path, caplog):
    ctx = _ctx(tmp_path, heading_step_deg=30.0, figures=False)
    strip = xr.Dataset({"elevation_m": (("y", "x"), np.full((2, 300), -1400.0), {"units": "m", "positive": "up"})},
                       coords={"y": [0.0, 0.02], "x": np.arange(300) * 0.02})
    _publish_laser(ctx, {"good": _submap(200, 120, 0.02, 8.0, 3), "strip": strip})
    assert stage.skip_reason(ctx) is None
    with caplog.at_level("WARNING", logger="hadal"):
        pv = stage.run(ctx)["landing"]
    assert set(pd.read_parquet(pv.file("landing_sites.parquet"))["submap"]) == {"good"}
    assert any("strip is 2 x 300 cells, too narrow" in r.getMessage() for r in caplog.records)


def test_skip_check_reads_the_laser_grids_geometry_from_the_manifest_without_opening_them(tmp_path, monkeypatch):
    """The laser stage records each grid's cell size and shape in the manifest: landing's skip check reads them
    there and opens no grid (``run`` opens each once); the reason equals the one read from the grids themselves."""
    ctx = _ctx(tmp_path, heading_step_deg=30.0, figures=False)
    coarse = _submap(40, 30, 0.5, 5.0, 1)  # 0.5 m cells: coarser than 1/10 of the default vehicle's width
    _publish_laser(ctx, {"coarse": coarse})
    from_files = stage.skip_reason(ctx)
    assert from_files is not None and "coarser than landing.max_cell_fraction" in from_files
    with ctx.store.publish(DIVE, "laser_grids",
                           extra={"laser_grid_geometry": {"coarse.nc": {"cell_m": 0.5, "nx": 30, "ny": 40}}}) as draft:
        coarse.to_netcdf(draft.path / "coarse.nc", engine="h5netcdf")

    def no_open(*args, **kwargs):
        raise AssertionError("a laser grid was opened by the skip check")

    monkeypatch.setattr(xr, "open_dataset", no_open)
    assert stage.skip_reason(ctx) == from_files
