"""``derive.profile_axis: depth``: profile.nc binned by the hydrostatic depth (issue 17, "bin average by pressure
or depth").

No SeaSoft BinAvg-by-depth output exists in ``../shared/data`` (every ``binavg_bintype`` there is ``decibars``), so
the oracles are: a brute-force per-bin mean (a Python loop over the bins with ``numpy.mean``) for the floor bins,
and ``seabirdscientific.processing.bin_average`` with ``bin_variable="depth_m"`` (Sea-Bird's own toolkit) for the
SeaSoft bins, both on the real SBE 19plus V2 cast of ``ctd-real`` and the depths derive computed for it; the
stage-level test checks the product's coordinate, units, values and CF/ACDD compliance on both axes.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest
import xarray as xr
import yaml
from pydantic import ValidationError

from hadal.ctd import derive
from hadal.errors import ConfigError
from hadal.products.dsg import orthogonal_profile
from hadal.registry import registry
from hadal.settings import DeriveParams

gsw = pytest.importorskip("gsw")

EXAMPLE = "ctd-real/sbs_19plus_V2_CTD-processing_example.cnv"
LAT, LON = 36.6, -121.9  # Monterey Bay (the cast's header has no position; any ocean position does)
BIN_M = 2.0
MEANS = ("temperature_its90_degc", "practical_salinity", "density_kg_m3", "pressure_dbar", "sound_speed_m_s")


class _Log:
    def warning(self, *a):
        pass


@pytest.fixture(scope="module")
def sensors(shared_cnv):
    src = shared_cnv(EXAMPLE)
    t0 = pd.Timestamp("2019-07-02T15:46:41Z")
    return pd.DataFrame({"time": t0 + pd.to_timedelta(np.arange(len(src)) * 0.25, unit="s"),
                         "conductivity_s_m": src["c0S/m"].to_numpy(), "temperature_its90_degc": src["tv290C"].to_numpy(),
                         "pressure_ctd_dbar": src["prdM"].to_numpy()})


def _derive(sensors, **kw):
    p = DeriveParams(latitude_deg=LAT, longitude_deg=LON, **kw)
    return derive.derive_table(sensors, {}, p, None, _Log(), "cast")


@pytest.fixture(scope="module")
def floor_depth(sensors):
    return _derive(sensors, profile_axis="depth", profile_bin_m=BIN_M)


def test_params():
    p = DeriveParams()
    assert p.profile_axis == "pressure" and p.profile_bin_m == 10.0 and p.overlying_profile is None
    for bad in ({"profile_axis": "height"}, {"profile_bin_m": 0}, {"profile_bin_m": 1001}, {"profile_bin_m": float("nan")}):
        with pytest.raises(ValidationError):
            DeriveParams(**bad)


def test_floor_depth_bins_equal_brute_force_means(floor_depth):
    df, meta, prof = floor_depth
    assert prof["temperature_its90_degc"].dims == ("cast", "depth_m") and "pressure_dbar" not in prof.dims
    assert "depth_m" not in prof.data_vars  # the binning variable is the coordinate; its mean is not repeated
    assert meta["profile_axis"] == {"axis": "depth", "bin_size": BIN_M, "units": "m", "binning": "floor"}
    z = prof["depth_m"].values
    assert np.allclose(np.diff(z), BIN_M) and np.allclose((z / BIN_M - 0.5) % 1.0, 0.0)
    depth = df["depth_m"].to_numpy()
    phase = df["phase"].to_numpy(dtype=object)
    n_checked = 0
    for k, cast in enumerate(prof["cast"].values):
        for j, centre in enumerate(z):
            sel = (phase == cast) & (depth >= centre - BIN_M / 2) & (depth < centre + BIN_M / 2)
            assert int(prof["count"].values[k, j]) == int(sel.sum())
            for v in MEANS:
                x = df[v].to_numpy(np.float64)[sel]
                x = x[np.isfinite(x)]
                got = prof[v].values[k, j]
                if x.size == 0:
                    assert np.isnan(got), (cast, centre, v)
                else:
                    assert got == pytest.approx(float(np.mean(x)), rel=1e-12, abs=1e-12), (cast, centre, v)
                    n_checked += 1
    assert n_checked > 800 and prof["count"].values.sum() > 0.9 * (phase != "bottom").sum()
    # the deepest bin holds the deepest sample (222.9 dbar: ~221 m), and the mean pressure grows with depth
    assert z[-1] - BIN_M / 2 <= np.nanmax(depth) < z[-1] + BIN_M / 2
    pd_desc = prof["pressure_dbar"].values[0]
    assert np.all(np.diff(pd_desc[np.isfinite(pd_desc)]) > 0)
    # N² is computed on each cast's mean bin pressures and is there
    assert np.isfinite(prof["buoyancy_frequency_squared_s2"].values[0]).sum() > 50


def test_seabird_depth_bins_equal_seabirdscientific(sensors):
    sbs = pytest.importorskip("seabirdscientific.processing")
    df, _, prof = _derive(sensors, profile_axis="depth", profile_bin_m=BIN_M, profile_binning="seabird")
    assert np.array_equal(prof["depth_m"].values, np.arange(1, prof.sizes["depth_m"] + 1) * BIN_M)
    cols = ["depth_m", *MEANS]
    ds = xr.Dataset({c: ("scan", df[c].to_numpy(np.float64)) for c in cols}, coords={"scan": np.arange(len(df))})
    ds["flag"] = ("scan", np.zeros(len(df)))
    ref = sbs.bin_average(ds, "depth_m", BIN_M, cast_type=sbs.CastType.BOTH)
    # ours in SeaSoft's file order: the descent bins going down, then the ascent bins coming up
    n = prof["count"].values
    order = [(0, j) for j in np.flatnonzero(n[0] > 0)] + [(1, j) for j in np.flatnonzero(n[1] > 0)[::-1]]
    assert np.array_equal([n[k, j] for k, j in order], ref["nbin"].values.astype(int))
    for v in MEANS:
        ours = np.array([prof[v].values[k, j] for k, j in order])
        assert np.abs(ours - ref[v].values).max() <= 1e-9 * max(1.0, np.abs(ref[v].values).max()), v


def test_pressure_axis_is_still_the_default(sensors, floor_depth):
    df, meta, prof = _derive(sensors)
    assert prof["temperature_its90_degc"].dims == ("cast", "pressure_dbar") and "depth_m" in prof.data_vars
    assert prof.attrs["bin_size_dbar"] == 10.0 and "bin_size_m" not in prof.attrs
    assert meta["profile_axis"]["axis"] == "pressure"
    # the per-sample table does not depend on the profile's axis
    pd.testing.assert_frame_equal(df.drop(columns=["buoyancy_frequency_squared_s2"]),
                                  floor_depth[0].drop(columns=["buoyancy_frequency_squared_s2"]))


def test_memory_check_on_the_depth_axis(sensors, floor_depth):
    from hadal.budget import memory_limit_bytes

    sens = pd.DataFrame({"pressure_ctd_dbar": np.linspace(0.0, 11_000.0, 100)})
    with pytest.raises(ConfigError, match=r"derive\.profile_bin_m.*depth-binned profile \(up to 11440 m"):
        derive.check_profile_memory(sens, DeriveParams(profile_axis="depth", profile_bin_m=1e-4), 1e8)
    derive.check_profile_memory(sens, DeriveParams(profile_bin_m=1e-4), 1e8)  # pressure axis: bin_m unused
    # the bound covers the real cast's depth bins (the depth is not known when the check runs)
    p = DeriveParams(profile_axis="depth", profile_bin_m=BIN_M)
    z_bound = sensors["pressure_ctd_dbar"].to_numpy() * derive.DEPTH_PER_DBAR_MAX
    n_est = (np.nanmax(z_bound) - min(0.0, np.nanmin(z_bound))) / BIN_M + 2
    assert n_est >= floor_depth[2].sizes["depth_m"]
    derive.check_profile_memory(sensors, p, memory_limit_bytes())


# ------------------------------------------------------------------------------------ the stage's product
def _stage(tmp_path, sensors, axis):
    from hadal.pipeline import make_context, run_stage
    from hadal.products.io import write_parquet
    from hadal.settings import PipelineConfig

    raw = tmp_path / "raw"
    raw.mkdir()
    (raw / "dive.yaml").write_text(yaml.safe_dump({
        "dive_id": "D17", "platform": "test", "launch": {"latitude_deg": LAT, "longitude_deg": LON},
        "map_frame": {"origin_latitude_deg": LAT, "origin_longitude_deg": LON}}))
    cfg = PipelineConfig(derive=DeriveParams(profile_axis=axis, profile_bin_m=BIN_M, profile_bin_dbar=BIN_M))
    ctx = make_context(raw, tmp_path / "store", cfg)
    with ctx.store.publish(ctx.dive_id, "sensors", parameters={}) as draft:
        write_parquet(sensors, draft.path / "sensors.parquet", metadata={"dive_id": ctx.dive_id})
    return run_stage("derive", ctx) | run_stage("profile", ctx)


@pytest.mark.parametrize("axis", ["depth", "pressure"])
def test_stage_profile_product(tmp_path, sensors, floor_depth, axis):
    out = _stage(tmp_path, sensors, axis)
    path = out["profile"].file("profile.nc")
    raw = xr.open_dataset(path, engine="h5netcdf")
    # the file: a ragged array of the casts with depth as its Z axis (hadal.products.dsg), whatever the binning
    zr = raw["depth_m"]
    assert raw["temperature_its90_degc"].dims == ("obs",) and int(raw["row_size"].sum()) == raw.sizes["obs"]
    assert zr.attrs["axis"] == "Z" and zr.attrs["positive"] == "down" and zr.attrs["standard_name"] == "depth"
    assert "axis" not in raw["pressure_dbar"].attrs
    ds = orthogonal_profile(raw.load())  # back on the binning axis (the report's reader)
    zname = "depth_m" if axis == "depth" else "pressure_dbar"
    z = ds[zname]
    assert ds["temperature_its90_degc"].dims == ("cast", zname)
    if axis == "depth":
        assert z.attrs["standard_name"] == "depth" and z.attrs["units"] == "m"
        assert ds["pressure_dbar"].attrs["units"] == "dbar" and ds["pressure_dbar"].dims == ("cast", "depth_m")
        assert ds["pressure_dbar"].attrs["standard_name"] == "sea_water_pressure"
        assert ds["temperature_its90_degc"].attrs["cell_methods"] == "obs: mean"  # each obs is a bin mean
        assert "Depth-binned" in ds.attrs["title"] and f"{BIN_M:g} m depth bins" in ds.attrs["summary"]
        assert ds.attrs["profile_axis"] == "depth" and ds.attrs["bin_size_m"] == BIN_M
        assert out["profile"].manifest()["summary"] == {"axis": "depth", "bin_m": BIN_M,
                                                       "levels": ds.sizes["depth_m"]}
        # the values: those of derive_table (checked against brute force above), on the launch latitude, stored
        # as float32 within half the precision schemas/variables.yaml declares for each
        ref = floor_depth[2]
        assert np.allclose(z.values, ref["depth_m"].values, atol=5e-3)
        for v in MEANS:
            tol = registry().find(v).precision / 2
            assert np.allclose(ds[v].values, ref[v].values, equal_nan=True, rtol=0, atol=tol), v
    else:
        assert ds["depth_m"].attrs["standard_name"] == "depth" and z.attrs["units"] == "dbar"
        assert "Pressure-binned" in ds.attrs["title"] and "dbar pressure bins" in ds.attrs["summary"]
        assert out["profile"].manifest()["summary"] == {"bin_dbar": BIN_M, "levels": ds.sizes["pressure_dbar"]}
    pytest.importorskip("compliance_checker")
    from hadal.products.compliance import check_compliance

    rep = check_compliance(path)
    assert rep.ok, rep.describe()
