"""Issue 43: degrade per channel, not per dive; the report always runs and draws every product it has.

Real files from ../shared/data (skipped when absent), damaged copies made here. Oracles: the untouched file's own
run, the file's own columns, gsw (TEOS-10 standard-ocean depth), rasterio's reading of the GeoTIFF.
"""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from hadal.dive_init import scan_dive_dir, write_init
from hadal.ingest.qc import DEFAULT_QC, fill_mask

CAST = "ctd-real/seabird_sta0860.cnv"
LASER = "bathy-real/LAD_Takuyo_B1_raster_100mm.tif"
COND = slice(33, 44)  # the c0S/m column of seabird_sta0860.cnv (11-character SeaSoft columns)


def _damaged_cast(src: Path, dst: Path, fraction: float, value=None) -> int:
    """``src`` with the conductivity of its first ``fraction`` of scans replaced (9.9e5 by default, or
    ``value(old)``); returns how many scans were changed."""
    head, body = src.read_bytes().decode("latin-1").split("*END*", 1)
    lines = body.split("\n")
    n = sum(1 for ln in lines if ln.strip())
    n_bad = round(fraction * n)
    out, i = [], 0
    for ln in lines:
        if ln.strip():
            if i < n_bad:
                new = f"{9.9e5:11.6g}" if value is None else f"{value(float(ln[COND])):11.5f}"
                ln = ln[:COND.start] + new + ln[COND.stop:]
            i += 1
        out.append(ln)
    dst.write_bytes((head + "*END*" + "\n".join(out)).encode("latin-1"))
    return n_bad


def _run(tmp_path: Path, name: str, files: list[Path]):
    from hadal.errors import StageError
    from hadal.pipeline import make_context, run_pipeline

    raw = tmp_path / name
    (raw / "raw").mkdir(parents=True)
    for f in files:
        shutil.copy(f, raw / "raw" / f.name)
    write_init(scan_dive_dir(raw))
    ctx = make_context(raw, tmp_path / f"store-{name}")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        try:
            run_pipeline(ctx)
        except StageError:
            pass  # a failed stage: the test looks at what was published and at the report
    return ctx


def _table(ctx, product: str) -> pd.DataFrame:
    return pd.read_parquet(ctx.store.latest(ctx.dive_id, product).file(f"{product}.parquet"))


def _meta(ctx, product: str) -> dict:
    from hadal.products.io import read_parquet_metadata

    return read_parquet_metadata(ctx.store.latest(ctx.dive_id, product).file(f"{product}.parquet"))[0]


def _summary(ctx) -> dict:
    return json.loads(ctx.store.latest(ctx.dive_id, "report").file("summary.json").read_text())


def test_fill_rule_is_per_variable():
    """-1 is "no bottom" for an altitude, a temperature for a thermometer; 9.9e5 uS/cm is a dead conductivity cell
    but 990000 Pa is a real 99 dbar; Sea-Bird's bad_flag is missing whatever the variable."""
    minus1 = np.array([-1.0])
    assert fill_mask(minus1, minus1, DEFAULT_QC["altitude_m"]).all()
    assert not fill_mask(minus1, minus1, DEFAULT_QC["temperature_its90_degc"]).any()
    assert fill_mask(np.array([9.9e5]), np.array([99.0]), DEFAULT_QC["conductivity_s_m"]).all()
    assert not fill_mask(np.array([9.9e5]), np.array([99.0]), DEFAULT_QC["pressure_ctd_dbar"]).any()
    assert fill_mask(np.array([-9.99e-29]), np.array([-9.99e-29]), DEFAULT_QC["temperature_its90_degc"]).all()


@pytest.fixture(scope="module")
def untouched(shared_data, tmp_path_factory):
    return _run(tmp_path_factory.mktemp("ok"), "ok", [shared_data / CAST])


def test_failed_conductivity_cell_keeps_temperature_pressure_and_depth(shared_data, untouched, tmp_path):
    """92 % of the scans' conductivity 9.9e5 (a failed cell): the cast is processed, those scans' conductivity and
    salinity are missing (flag 9), and temperature, pressure and depth equal the untouched file's run."""
    bad = tmp_path / "sta0860_deadcond.cnv"
    n_bad = _damaged_cast(shared_data / CAST, bad, 0.92)
    ctx = _run(tmp_path, "dead", [bad])
    assert {"sensors", "ctd", "profile", "report"} <= set(ctx.store.products(ctx.dive_id))
    a, b = _table(untouched, "ctd"), _table(ctx, "ctd")
    assert len(a) == len(b)
    for c in ("pressure_dbar", "temperature_its90_degc"):
        np.testing.assert_array_equal(b[c].to_numpy(), a[c].to_numpy())
    # depth: the density of the scans without salinity is interpolated from the valid ones (hydrostatic_depth's
    # rule); the whole 84 m column differs from the untouched run's by centimetres
    np.testing.assert_allclose(b["depth_m"].to_numpy(), a["depth_m"].to_numpy(), atol=0.05)
    assert (b["conductivity_s_m_qc"].iloc[:n_bad] == 9).all() and b["conductivity_s_m"].iloc[:n_bad].isna().all()
    assert (b["practical_salinity_qc"].iloc[:n_bad].isin([4, 9])).all()
    np.testing.assert_array_equal(b["practical_salinity"].iloc[n_bad:].to_numpy(),
                                  a["practical_salinity"].iloc[n_bad:].to_numpy())
    fills = _meta(ctx, "sensors")["fill_values"]["conductivity_s_m"]
    assert fills["count"] == n_bad and fills["values_as_logged"] == [990000.0]
    assert "vehicle config" not in json.dumps(_meta(ctx, "sensors")["notes"])


def test_dead_conductivity_channel_gives_standard_ocean_depth(shared_data, untouched, tmp_path):
    """Every conductivity scan 9.9e5: the channel is dead (named in the report), salinity/density missing, depth
    from the TEOS-10 standard ocean (gsw.z_from_p of the file's own pressures), temperature/pressure unchanged."""
    import gsw

    bad = tmp_path / "sta0860_allcond.cnv"
    _damaged_cast(shared_data / CAST, bad, 1.0)
    ctx = _run(tmp_path, "alldead", [bad])
    a, b = _table(untouched, "ctd"), _table(ctx, "ctd")
    np.testing.assert_array_equal(b["temperature_its90_degc"].to_numpy(), a["temperature_its90_degc"].to_numpy())
    np.testing.assert_array_equal(b["pressure_dbar"].to_numpy(), a["pressure_dbar"].to_numpy())
    z = -gsw.z_from_p(b["pressure_dbar"].to_numpy(), float(_meta(ctx, "ctd")["latitude_deg"]))
    np.testing.assert_allclose(b["depth_m"].to_numpy(), z, rtol=1e-12)
    assert np.abs(b["depth_m"].to_numpy() - a["depth_m"].to_numpy()).max() < 0.5  # standard ocean vs the real water
    assert b["practical_salinity"].isna().all() and (b["conductivity_s_m_qc"] == 9).all()
    notes = " ".join(_summary(ctx)["notes"])
    assert "conductivity_s_m is dead" in notes and "vehicle config" not in notes
    assert _summary(ctx)["dead_channels"]["conductivity_s_m"]["reason"] == "all fill values"
    assert "Dead sensor channels" in ctx.store.latest(ctx.dive_id, "report").file("report.html").read_text()


def test_conductivity_in_the_wrong_units_is_a_dead_channel_with_a_hint(shared_data, tmp_path):
    """Conductivity x10 (mS/cm written under a S/m name): flagged 4, the warning names the unit, no vehicle config."""
    bad = tmp_path / "sta0860_x10.cnv"
    _damaged_cast(shared_data / CAST, bad, 1.0, value=lambda c: c * 10)
    ctx = _run(tmp_path, "x10", [bad])
    s = _table(ctx, "sensors")
    assert (s["conductivity_s_m_qc"] == 4).all() and (s["temperature_its90_degc_qc"] != 4).mean() > 0.9
    notes = " ".join(_summary(ctx)["notes"])
    assert "logged in mS/cm rather than S/m" in notes and "vehicle config" not in notes


def test_report_runs_when_the_only_stage_fails(shared_data, tmp_path):
    """A cast of one scan: ingest fails, nothing upstream is published, the report still publishes the failure
    and what was found."""
    src = (shared_data / CAST).read_bytes().decode("latin-1")
    head, body = src.split("*END*", 1)
    one = tmp_path / "one_scan.cnv"
    one.write_bytes((head + "*END*\n" + next(ln for ln in body.split("\n") if ln.strip()) + "\n").encode("latin-1"))
    ctx = _run(tmp_path, "onescan", [one])
    assert set(ctx.store.products(ctx.dive_id)) == {"report"}
    summ = _summary(ctx)
    why = {s["stage"]: s["reason"] for s in summ["skipped_stages"]}
    assert why["ingest"].startswith("failed:") and "only 1 sample" in why["ingest"], why
    assert summ["sources"] == {"cnv": ["raw/one_scan.cnv"]}
    html = ctx.store.latest(ctx.dive_id, "report").file("report.html").read_text()
    assert "only 1 sample" in html and "one_scan.cnv" in html


def test_laser_only_dive_has_its_laser_figure(shared_data, tmp_path):
    """The Takuyo laser raster alone: report.html embeds a map of the laser grid; the summary gives the grid's
    extent and elevation range, equal to rasterio's reading of the GeoTIFF (its depths, positive down)."""
    import rasterio

    ctx = _run(tmp_path, "laser", [shared_data / LASER])
    rep = ctx.store.latest(ctx.dive_id, "report")
    summ = _summary(ctx)
    assert summ["figures"]["laser_grids"] == "ok"
    assert (rep.path / "figures" / "laser_grids.png").stat().st_size > 10_000
    assert "id='laser_grids'" in rep.file("report.html").read_text()
    (g,) = summ["laser_grids"]
    with rasterio.open(shared_data / LASER) as r:
        b = r.bounds
        z = r.read(1, masked=True)
    np.testing.assert_allclose(g["x_range_m"], [b.left, b.right], atol=1e-6)
    np.testing.assert_allclose(g["y_range_m"], [b.bottom, b.top], atol=1e-6)
    np.testing.assert_allclose(g["elevation_range_m"], [-float(z.max()), -float(z.min())], atol=1e-4)


def test_a_channel_constant_through_the_record_is_a_stuck_sensor():
    """An altimeter writing 0.00 throughout a binned cast (no time: the flat-line test is not evaluated there) is
    dead by name, flagged 4; a channel that varies, or a constant one too short to judge, is not."""
    from hadal.ingest.build import channel_health

    meta: dict = {}
    with warnings.catch_warnings(record=True) as w:
        warnings.simplefilter("always")
        channel_health(np.zeros(200), "altitude_m", DEFAULT_QC["altitude_m"], meta, source="aer205.cnv",
                       sensor="ctd")
    dead = meta["dead_channels"]["altitude_m"]
    assert dead["reason"] == "constant" and dead["qartod_flag"] == 4 and dead["constant_value"] == 0.0
    assert any("altitude_m is dead" in str(x.message) and "exactly 0 m" in str(x.message) for x in w)
    for v in (np.linspace(10.0, 5.0, 200), np.zeros(10)):
        meta = {}
        channel_health(v, "altitude_m", DEFAULT_QC["altitude_m"], meta, source="x.cnv", sensor="ctd")
        assert "dead_channels" not in meta


@pytest.mark.parametrize("name", ["ctd-real/seabird_sta0860.cnv", "ctd-real/seabird_dPIRX010.cnv",
                                  "ctd-real/oceissues644_02dk.cnv", "ctd-real/pyctd_CTD_with_sigma_e00.cnv",
                                  "ctd-real/sbs_19plus_V2_CTD-processing_example.cnv",
                                  "dives-real/oce_SBE25_ctd.cnv", "dives-real/seabird_SBE21_TSG_PIR_010.cnv"])
def test_no_real_channel_is_taken_for_a_stuck_sensor(shared_data, name):
    """False-positive guard on other people's real casts (binned, raw, an underway TSG with constant pressure):
    the constant-record rule names none of their channels."""
    from hadal.ingest.build import read_cast

    path = shared_data / name
    if not path.exists():
        pytest.skip(f"{name} not in ../shared/data")
    samples, _ = read_cast(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        meta = _health_only(samples)
    assert not [v for v, d in (meta.get("dead_channels") or {}).items() if d["reason"] == "constant"]


def _health_only(samples) -> dict:
    from hadal.ingest.build import channel_health

    meta: dict = {}
    for var, v in samples.values.items():
        if var in DEFAULT_QC:
            channel_health(np.asarray(v, float), var, DEFAULT_QC[var], meta, source="x", sensor=samples.name)
    return meta
