"""Configuration that would eat memory or time is refused up front (issue 14, class 5).

Each stage estimates the memory (and, for the terrain-matching search, the work) its configuration implies and
raises a one-line :class:`hadal.errors.ConfigError` naming the setting, the estimate and the limit before it
allocates anything; nothing is published. Every numeric field of every section refuses NaN and infinity.
"""

from __future__ import annotations

import math
import types
import typing

import numpy as np
import pandas as pd
import pytest
import yaml
from pydantic import BaseModel, ValidationError

from hadal import budget
from hadal.errors import ConfigError
from hadal.pipeline import make_context, run_stage
from hadal.products.io import write_parquet
from hadal.settings import IngestParams, PipelineConfig, load_config

# --------------------------------------------------------------------------------------------- helpers


def _one_line(exc: BaseException) -> str:
    msg = str(exc)
    assert msg and "\n" not in msg, msg
    return msg


def _write_dive(raw, sources=None, pipeline=None):
    raw.mkdir(parents=True, exist_ok=True)
    dive = {"dive_id": "B001", "platform": "test", "launch": {"latitude_deg": 11.33, "longitude_deg": 142.2},
            "map_frame": {"origin_latitude_deg": 11.33, "origin_longitude_deg": 142.2}}
    if sources:
        dive["sources"] = sources
    (raw / "dive.yaml").write_text(yaml.safe_dump(dive))
    if pipeline is not None:
        (raw / "pipeline.yaml").write_text(yaml.safe_dump(pipeline))
    return raw


def _versions(store_root, product):
    d = store_root / "B001" / product
    return sorted(p.name for p in d.glob("v*")) if d.is_dir() else []


# --------------------------------------------------------------------------------------------- the helper


def test_check_memory_message_names_setting_estimate_and_limit():
    with pytest.raises(ConfigError) as ei:
        budget.check_memory("the profile", 12.3 * budget.GIB, 11.7 * budget.GIB,
                            setting="derive.profile_bin_dbar", value=1e-4)
    msg = _one_line(ei.value)
    assert msg.startswith("derive.profile_bin_dbar = 0.0001 would need 12.3 GiB for the profile (limit 11.7 GiB)")
    budget.check_memory("the profile", 1.0, 2.0)  # within the budget: no error
    with pytest.raises(ConfigError, match="evaluations"):
        budget.check_work("the search", 1e12, 1e9, setting="match.heading_step_deg", value=1e-5)


def test_default_limit_is_a_fraction_of_machine_memory():
    import psutil

    total = psutil.virtual_memory().total
    assert budget.memory_limit_bytes(PipelineConfig()) == int(0.5 * total)
    cfg = PipelineConfig.model_validate({"resources": {"memory_fraction": 0.25}})
    assert budget.memory_limit_bytes(cfg) == int(0.25 * total)
    cfg = PipelineConfig.model_validate({"resources": {"max_memory_gb": 2}})
    assert budget.memory_limit_bytes(cfg) == 2 * budget.GIB


# --------------------------------------------------------------------------------------------- derive


def _sensors(n=2000):
    t = pd.Timestamp("2018-10-06T23:00:00Z") + pd.to_timedelta(np.arange(n) * 4.0, unit="s")
    p = np.concatenate([np.linspace(2, 10_900, n // 2), np.linspace(10_900, 2, n - n // 2)])
    df = pd.DataFrame({"time": t, "conductivity_s_m": 3.3, "temperature_its90_degc": 2.0, "pressure_ctd_dbar": p,
                       "pressure_gauge_dbar": p + 0.3, "altitude_m": np.nan, "heading_deg": 0.0, "pitch_deg": 0.0,
                       "roll_deg": 0.0, "dr_east_m": 0.0, "dr_north_m": 0.0, "speed_m_s": 0.5})
    for c in ("conductivity_s_m", "temperature_its90_degc", "pressure_ctd_dbar", "pressure_gauge_dbar", "altitude_m"):
        df[c + "_qc"] = np.where(np.isfinite(df[c]), 1, 9).astype("uint8")
    return df


def test_derive_profile_bin_too_fine_is_refused_and_publishes_nothing(tmp_path):
    raw = _write_dive(tmp_path / "raw", pipeline={"derive": {"profile_bin_dbar": 1e-4},
                                                  "resources": {"max_memory_gb": 4}})
    ctx = make_context(raw, tmp_path / "store")
    with ctx.store.publish(ctx.dive_id, "sensors", parameters={}) as draft:
        write_parquet(_sensors(), draft.path / "sensors.parquet", metadata={"dive_id": ctx.dive_id})
    with pytest.raises(ConfigError) as ei:
        run_stage("derive", ctx)
    msg = _one_line(ei.value)
    assert msg.startswith("derive.profile_bin_dbar = 0.0001 would need ")
    assert "GiB for the profile" in msg and "(limit 4 GiB)" in msg and "resources.max_memory_gb" in msg
    assert _versions(tmp_path / "store", "ctd") == [] and _versions(tmp_path / "store", "profile") == []


# --------------------------------------------------------------------------------------------- grid


def _multibeam_dive(tmp_path, grid, resources=None, laser=False):
    from hadal.geo import LocalFrame

    frame = LocalFrame(11.33, 142.2)
    rng = np.random.default_rng(0)
    raw = tmp_path / "raw"
    (raw / "mb").mkdir(parents=True)
    x, y = rng.uniform(-1000, 1000, 3000), rng.uniform(-800, 800, 3000)
    lon, lat = frame.to_lonlat(x, y)
    np.savetxt(raw / "mb" / "line.xyz", np.column_stack([lon, lat, 8000 + 0.02 * x]), fmt="%.8f %.8f %.3f")
    sources = {"multibeam": ["mb/line.xyz"]}
    if laser:
        (raw / "laser").mkdir()
        pts = np.column_stack([rng.uniform(0, 20.0, 5000), rng.uniform(0, 20.0, 5000), -1400 + rng.normal(0, 1e-3, 5000)])
        head = (f"ply\nformat binary_little_endian 1.0\nelement vertex {len(pts)}\n"
                "property double x\nproperty double y\nproperty double z\nend_header\n").encode()
        (raw / "laser" / "scan.ply").write_bytes(head + np.asarray(pts, "<f8").tobytes())
        sources = {"laser": ["laser/scan.ply"]}
    pipeline = {"grid": grid}
    if resources:
        pipeline["resources"] = resources
    return _write_dive(raw, sources, pipeline)


def test_grid_dtm_cells_beyond_memory_are_refused(tmp_path):
    # 5 cm cells over 2 km x 1.6 km with max_cells raised: 1.3e9 cells x 10 layers would be a MemoryError
    raw = _multibeam_dive(tmp_path, {"dtm_resolution_m": 0.05, "max_cells": 10_000_000_000},
                          resources={"max_memory_gb": 4})
    with pytest.raises(ConfigError) as ei:
        run_stage("grid", make_context(raw, tmp_path / "store"))
    msg = _one_line(ei.value)
    assert msg.startswith("grid.dtm_resolution_m = 0.05 would need ")
    assert "for the DTM (" in msg and "layers x 8 bytes" in msg and "(limit " in msg
    assert _versions(tmp_path / "store", "dtm") == []


def test_grid_laser_cells_beyond_memory_are_refused(tmp_path):
    raw = _multibeam_dive(tmp_path, {"laser_resolution_m": 0.001, "max_cells": 10_000_000_000,
                                     "laser_sor_neighbors": 0}, resources={"max_memory_gb": 4}, laser=True)
    with pytest.raises(ConfigError) as ei:
        run_stage("grid", make_context(raw, tmp_path / "store"))
    msg = _one_line(ei.value)
    assert msg.startswith("grid.laser_resolution_m = 0.001 would need ") and "for the laser grid" in msg
    assert "(limit 4 GiB)" in msg
    assert _versions(tmp_path / "store", "laser_grids") == []
    # a tiny budget reaches the cloud reader first (issue 45): its read is refused in one line, nothing published
    raw = _multibeam_dive(tmp_path / "b", {"laser_sor_neighbors": 0}, resources={"max_memory_gb": 1e-5}, laser=True)
    from hadal.errors import InputError

    with pytest.raises(InputError, match=r"decoding this PLY point cloud needs more than .*limit 10\.5 KiB\)"):
        run_stage("grid", make_context(raw, tmp_path / "b" / "store"))
    assert _versions(tmp_path / "b" / "store", "laser_grids") == []
    # 'auto' (>= 10 mm) with a tiny budget: the estimate is made with the automatic cell size
    from hadal.grid.readers import read_point_cloud
    from hadal.settings import GridParams
    from hadal.stages.grid import _check_laser_memory

    pts = read_point_cloud(next((raw / "laser").glob("*.ply")))
    with pytest.raises(ConfigError, match=r"^grid\.laser_resolution_m = auto \("):
        _check_laser_memory(pts, GridParams(laser_sor_neighbors=0), 1e-5 * (1 << 30))


def test_grid_over_max_cells_keeps_the_cell_count_refusal(tmp_path):
    from hadal.errors import InputError

    raw = _multibeam_dive(tmp_path, {"dtm_resolution_m": 0.001})  # 3.2e12 cells > grid.max_cells
    with pytest.raises(InputError, match="exceeds the limit of"):
        run_stage("grid", make_context(raw, tmp_path / "store"))
    assert _versions(tmp_path / "store", "dtm") == []


# --------------------------------------------------------------------------------------------- match


def _match_world(tmp_path, match, resources=None):
    import xarray as xr

    from hadal.geo import LocalFrame

    raw = _write_dive(tmp_path / "raw", pipeline={"match": match, **({"resources": resources} if resources else {})})
    ctx = make_context(raw, tmp_path / "store")
    frame = LocalFrame(11.33, 142.2)
    lx, ly = (float(v) for v in frame.to_xy(142.2, 11.33))
    x = np.round(lx / 20) * 20 + np.arange(-60, 60) * 20.0
    y = np.round(ly / 20) * 20 + np.arange(-50, 50) * 20.0
    xx, yy = np.meshgrid(x, y)
    z = 8000 + 30 * np.sin(xx / 150) * np.cos(yy / 210)
    with ctx.store.publish(ctx.dive_id, "dtm") as d:
        xr.Dataset({"depth_m": (("y", "x"), z)}, coords={"x": x, "y": y}).to_netcdf(d.path / "dtm.nc",
                                                                                    engine="h5netcdf")
    n = 400
    t = pd.Timestamp("2018-10-06T23:00:00Z") + pd.to_timedelta(np.arange(n), unit="s")
    ctd = pd.DataFrame({"time": t, "depth_m": 7990.0, "seafloor_depth_m": 8000 + np.sin(np.arange(n) / 9),
                        "dr_east_m": np.arange(n) * 1.5, "dr_north_m": np.arange(n) * 0.5, "phase": "bottom",
                        "pressure_dbar": 8150.0})
    with ctx.store.publish(ctx.dive_id, "ctd") as d:
        ctd.to_parquet(d.path / "ctd.parquet")
    return ctx


def test_match_heading_step_too_fine_is_refused_before_searching(tmp_path):
    ctx = _match_world(tmp_path, {"heading_step_deg": 1e-4})
    with pytest.raises(ConfigError) as ei:
        run_stage("match", ctx)
    msg = _one_line(ei.value)
    assert msg.startswith("match.heading_step_deg = 0.0001 would need ")
    assert "180,001 headings" in msg and "(limit " in msg
    assert _versions(tmp_path / "store", "match") == []
    # a step too fine for pydantic's bounds (the 1e-5) is a one-line configuration error too
    with pytest.raises(ConfigError, match=r"^invalid configuration at match\.heading_step_deg"):
        load_config(_write_dive(tmp_path / "raw2", pipeline={"match": {"heading_step_deg": 1e-5}}) / "pipeline.yaml")


def test_match_memory_of_the_search_is_checked(tmp_path):
    ctx = _match_world(tmp_path, {"heading_step_deg": 0.01, "heading_range_deg": 9},
                       resources={"max_memory_gb": 0.05, "max_match_evaluations": 1e15})
    with pytest.raises(ConfigError) as ei:
        run_stage("match", ctx)
    msg = _one_line(ei.value)
    assert msg.startswith("match.heading_step_deg = 0.01 would need ") and "(limit 51.2 MiB)" in msg
    assert _versions(tmp_path / "store", "match") == []


@pytest.mark.parametrize("section", [{"heading_range_deg": 2, "heading_step_deg": 5},
                                     {"scale_range": 0.01, "scale_step": 0.02}])
def test_search_step_larger_than_its_range_is_refused(tmp_path, section):
    raw = _write_dive(tmp_path / "raw", pipeline={"match": section})
    with pytest.raises(ConfigError) as ei:
        make_context(raw, tmp_path / "store")
    msg = _one_line(ei.value)
    assert "is larger than" in msg and ("only 0 deg" in msg or "only scale 1" in msg)


# --------------------------------------------------------------------------------------------- ingest


@pytest.mark.parametrize("value", [".nan", ".inf", "-1", "0"])
def test_ingest_max_gap_must_be_finite_and_positive(tmp_path, value):
    raw = tmp_path / "raw"
    raw.mkdir()
    (raw / "pipeline.yaml").write_text(f"ingest:\n  max_gap_s:\n    gauge: {value}\n")
    with pytest.raises(ConfigError) as ei:
        load_config(raw / "pipeline.yaml")
    msg = _one_line(ei.value)
    assert "ingest.max_gap_s.gauge" in msg


def test_ingest_stage_rechecks_gap_limits():
    from hadal.stages import ingest

    p = IngestParams().model_copy(update={"max_gap_s": {"gauge": float("nan")}})
    with pytest.raises(ConfigError, match=r"ingest\.max_gap_s\.gauge must be a finite number > 0"):
        ingest._gap_limits(p)


# --------------------------------------------------------------------------------------------- NaN / inf everywhere


def _leaves(model: type[BaseModel], path=()):
    for name, f in model.model_fields.items():
        yield from _walk(f.annotation, path + (name,))


def _walk(ann, path):
    origin, args = typing.get_origin(ann), typing.get_args(ann)
    if origin is typing.Annotated:
        yield from _walk(args[0], path)
    elif isinstance(ann, type) and issubclass(ann, BaseModel):
        yield from _leaves(ann, path)
    elif ann is float or ann is int:
        yield path
    elif origin in (typing.Union, types.UnionType):
        seen = set()
        for a in args:
            for p in _walk(a, path):
                if p not in seen:
                    seen.add(p)
                    yield p
    elif origin is tuple:
        for i, a in enumerate(args):
            if a is not Ellipsis:
                yield from _walk(a, path + (i,))
    elif origin is list:
        yield from _walk(args[0], path + (0,))
    elif origin is dict:
        yield from _walk(args[1], path + ("*",))


def _set(data: dict, path, value):
    """Set ``value`` at ``path`` in the default configuration (``*``: an existing key of a mapping)."""
    node = data
    for i, key in enumerate(path[:-1]):
        nxt = path[i + 1]
        if key == "*":
            key = next(iter(node)) if node else "x"
            path = path[:i] + (key,) + path[i + 1:]
        child = node.get(key) if isinstance(node, dict) else node[key]
        if child is None or (isinstance(child, (list, tuple)) and isinstance(nxt, int) and len(child) <= nxt):
            child = [0.0, 1.0] if isinstance(nxt, int) else {}
        if isinstance(child, tuple):
            child = list(child)
        node[key] = child
        node = child
    last = path[-1]
    if last == "*":
        last = next(iter(node)) if node else "x"
        path = path[:-1] + (last,)
    node[last] = value
    return tuple(path)


LEAVES = list(_leaves(PipelineConfig))


@pytest.mark.parametrize("path", [pytest.param(p, id=".".join(map(str, p))) for p in LEAVES])
def test_every_numeric_field_refuses_nan_and_inf(path):
    assert len(LEAVES) > 60
    for bad in (math.nan, math.inf, -math.inf):
        data = PipelineConfig().model_dump(mode="python")
        where = _set(data, path, bad)
        with pytest.raises(ValidationError) as ei:
            PipelineConfig.model_validate(data)
        locs = [tuple(e["loc"]) for e in ei.value.errors()]
        assert any(loc[:len(where)] == where or where[:len(loc)] == loc for loc in locs), (where, locs)


def test_nan_in_yaml_is_a_one_line_config_error(tmp_path):
    (tmp_path / "pipeline.yaml").write_text("derive:\n  profile_bin_dbar: .nan\n")
    with pytest.raises(ConfigError) as ei:
        load_config(tmp_path / "pipeline.yaml")
    assert "derive.profile_bin_dbar" in _one_line(ei.value)
