"""``derive.overlying_profile``: a user-supplied profile of the water above a record that does not start at the
surface (issue 17 §4).

Oracle: the same real cast uncut. A SeaSoft-binned cast of ``ctd-real`` (``oceissues644_02dk``: 1-566 dbar, with
SeaSoft's ``depSM``; ``seabird_dPIRX010``: 1-1014 dbar) is cut to start at depth; the removed top, written as the
user's profile file (CSV with units in the header, CSV of ``gsw.rho`` TEOS-10 densities, or the .cnv itself), must
give the depth the full cast gives at the same pressures. Bad files are one-line errors naming the file.
"""

from __future__ import annotations

import warnings

import numpy as np
import pandas as pd
import pytest
import yaml
from pydantic import ValidationError

from hadal.ctd.derive import derive_ctd
from hadal.depth import read_overlying_profile
from hadal.errors import ConfigError, InputError
from hadal.settings import DeriveParams
from hadal.stages import derive

gsw = pytest.importorskip("gsw")

ARCTIC = "ctd-real/oceissues644_02dk.cnv"  # header latitude 69.41 N; c0mS/cm; depSM
PIRATA = "ctd-real/seabird_dPIRX010.cnv"  # no position in the header: any tropical latitude does
TIME_SERIES = "ctd-real/sbs_19plus_V2_CTD-processing_example.cnv"  # 0.25 s scans with loops (not one binned cast)
CASTS = {ARCTIC: ("c0mS/cm", 0.1, 69.4125), PIRATA: ("c0S/m", 1.0, 10.0)}
#: the cut record's depth against the full cast's, with the top as the user profile (measured: < 1e-5 m with the
#: cast's own T/S, 0.8 mm with TEOS-10 gsw.rho densities; the standard ocean instead is 0.15-0.88 m off)
TOL_M = 0.005


def _sensors(src, c_col, c_scale):
    return pd.DataFrame({"time": pd.NaT, "conductivity_s_m": src[c_col].to_numpy() * c_scale,
                         "temperature_its90_degc": src["t090C"].to_numpy(), "pressure_ctd_dbar": src["prDM"].to_numpy()})


def _top_csv(path, top):
    pd.DataFrame({"pressure [dbar]": top["prDM"].to_numpy(), "temperature [ITS-90, deg C]": top["t090C"].to_numpy(),
                  "salinity [PSU]": top["sal00"].to_numpy()}).to_csv(path, index=False)
    return path


@pytest.mark.parametrize("rel", [ARCTIC, PIRATA])
@pytest.mark.parametrize("cut_dbar", [100.0, 500.0])
def test_cut_cast_with_its_top_as_user_profile_gives_the_full_depth(tmp_path, rel, cut_dbar, shared_cnv):
    src = shared_cnv(rel)
    c_col, c_scale, lat = CASTS[rel]
    sens = _sensors(src, c_col, c_scale)
    full, _ = derive_ctd(sens, lat, 0.0, DeriveParams())
    sel = src["prDM"].to_numpy() >= cut_dbar
    cut = sens.loc[sel].reset_index(drop=True)
    ref = full["depth_m"].to_numpy()[sel]
    prof = read_overlying_profile(_top_csv(tmp_path / "top.csv", src.loc[~sel]))
    out, meta = derive_ctd(cut, lat, 0.0, DeriveParams(), overlying_profile=prof)
    oc = meta["overlying_column"]
    assert oc["method"] == "user profile" and oc["first_pressure_dbar"] == cut_dbar
    assert oc["user_profile"]["file"] == str(tmp_path / "top.csv") and len(oc["user_profile"]["sha256"]) == 64
    assert oc["user_profile"]["pressure_range_dbar"] == [1.0, cut_dbar - 1.0]
    assert np.nanmax(np.abs(out["depth_m"].to_numpy() - ref)) < TOL_M
    # without it: the standard ocean, decimetres off (and said so, within its stated error)
    std, m2 = derive_ctd(cut, lat, 0.0, DeriveParams())
    err_std = np.nanmax(np.abs(std["depth_m"].to_numpy() - ref))
    assert m2["overlying_column"]["method"].startswith("standard ocean") and 0.1 < err_std
    assert err_std <= m2["overlying_column"]["estimated_error_m"]
    if "depSM" in src:  # SeaSoft's depth: the cut record is as far from it as the full cast (standard ocean formula)
        sm = src["depSM"].to_numpy()[sel]
        assert np.nanmax(np.abs(np.abs(out["depth_m"].to_numpy() - sm) - np.abs(ref - sm))) < TOL_M
        assert np.nanmax(np.abs(out["depth_m"].to_numpy() - sm)) < 0.5


def test_density_csv_and_cnv_file_as_user_profile(shared_data, tmp_path, shared_cnv):
    src = shared_cnv(ARCTIC)
    c_col, c_scale, lat = CASTS[ARCTIC]
    sens = _sensors(src, c_col, c_scale)
    full, _ = derive_ctd(sens, lat, 0.0, DeriveParams())
    sel = src["prDM"].to_numpy() >= 300.0
    top = src.loc[~sel]
    p = top["prDM"].to_numpy()
    sa = gsw.SA_from_SP(top["sal00"].to_numpy(), p, 0.0, lat)
    rho = gsw.rho(sa, gsw.CT_from_t(sa, top["t090C"].to_numpy(), p), p)  # TEOS-10 density: an independent model
    (tmp_path / "rho.csv").write_text("# TEOS-10 density of the cast's top\n" + pd.DataFrame(
        {"pressure_dbar": p, "density_kg_m3": rho}).to_csv(index=False))
    for f, basis in ((tmp_path / "rho.csv", "density column"), (shared_data / ARCTIC, "EOS-80")):
        with warnings.catch_warnings():  # the .cnv's header says nvalues = 1012 for its 566 rows
            warnings.simplefilter("ignore")
            prof = read_overlying_profile(f)
        assert prof.basis.startswith(basis)
        out, meta = derive_ctd(sens.loc[sel].reset_index(drop=True), lat, 0.0, DeriveParams(),
                                      overlying_profile=prof)
        assert meta["overlying_column"]["method"] == "user profile"
        assert np.nanmax(np.abs(out["depth_m"].to_numpy() - full["depth_m"].to_numpy()[sel])) < TOL_M


def test_stage_uses_records_and_fingerprints_the_profile(tmp_path, shared_cnv):
    from hadal.pipeline import make_context, run_stage
    from hadal.products.io import read_parquet_metadata, write_parquet
    from hadal.settings import PipelineConfig

    src = shared_cnv(ARCTIC)
    c_col, c_scale, lat = CASTS[ARCTIC]
    sel = src["prDM"].to_numpy() >= 300.0
    raw = tmp_path / "raw"
    raw.mkdir()
    (raw / "dive.yaml").write_text(yaml.safe_dump({
        "dive_id": "D17", "platform": "test", "launch": {"latitude_deg": lat, "longitude_deg": 0.0},
        "map_frame": {"origin_latitude_deg": lat, "origin_longitude_deg": 0.0}}))
    (raw / "site").mkdir()
    _top_csv(raw / "site" / "top.csv", src.loc[~sel])
    cfg = PipelineConfig(derive=DeriveParams(overlying_profile="site/top.csv"))
    ctx = make_context(raw, tmp_path / "store", cfg)
    with ctx.store.publish(ctx.dive_id, "sensors", parameters={}) as draft:
        write_parquet(_sensors(src, c_col, c_scale).loc[sel].reset_index(drop=True), draft.path / "sensors.parquet",
                      metadata={"dive_id": ctx.dive_id})
    out = run_stage("derive", ctx)
    meta, _ = read_parquet_metadata(out["ctd"].file("ctd.parquet"))
    oc = meta["overlying_column"]
    assert oc["method"] == "user profile" and oc["user_profile"]["file"] == str(raw / "site" / "top.csv")
    man = out["ctd"].manifest()
    assert man["summary"]["overlying_column"]["method"] == "user profile"
    assert man["parameters"]["overlying_profile"] == "site/top.csv"
    assert derive.raw_files(ctx) == [raw / "site" / "top.csv"]
    pytest.importorskip("prefect")
    from tasks.stage import raw_inputs  # the cache fingerprint: an edited profile file re-runs derive

    assert raw / "site" / "top.csv" in raw_inputs("derive", ctx)
    ctd = pd.read_parquet(out["ctd"].file("ctd.parquet"))
    assert abs(ctd["depth_m"].iloc[0] - oc["first_depth_m"]) < 1e-3
    # a missing file is a one-line ConfigError naming the setting, before anything is published
    ctx.config = PipelineConfig(derive=DeriveParams(overlying_profile="site/none.csv"))
    with pytest.raises(ConfigError, match=r"none\.csv: derive\.overlying_profile does not exist") as exc:
        run_stage("derive", ctx)
    assert "\n" not in str(exc.value)


def _write(tmp_path, name, text):
    (tmp_path / name).write_text(text)
    return tmp_path / name


GOOD_ROWS = "1,10.0,35.0\n100,5.0,35.0\n600,3.0,35.0\n"


@pytest.mark.parametrize(("text", "match"), [
    ("depth [m],temperature [degC],salinity\n" + GOOD_ROWS, r"no pressure column"),
    ("pressure [dbar],temperature [degC]\n1,10\n600,3\n", r"needs temperature and practical salinity, or density"),
    ("pressure,temperature [degC],salinity\n" + GOOD_ROWS, r"column 'pressure' has no unit"),
    ("pressure [m],temperature [degC],salinity\n" + GOOD_ROWS, r"'pressure \[m\]': wrong unit for pressure"),
    ("pressure [kPa],temperature [degC],salinity\n10,10,35\n1000,5,35\n200000,3,35\n",
     r"pressure from .* is outside -5 to 12000 dbar: wrong unit\?"),
    ("pressure [dbar],temperature [degC],salinity [g/kg]\n" + GOOD_ROWS, r"not practical salinity"),
    ("pressure_dbar,density [kg/m3]\n1,27.1\n600,27.9\n", r"density from 27.1 to 27.9 kg m-3 is outside"),
    ("pressure_dbar,sigma [kg/m3],density [sigma-theta]\n1,27.1,27\n600,27.9,28\n", r"is not a density"),
    ("pressure_dbar,temperature_its90_degc,practical_salinity\n1,10,35\n100,5,35\n50,4,35\n600,3,35\n",
     r"not strictly monotonic \(50.00 dbar after 100.00 dbar"),
    ("pressure_dbar,temperature_its90_degc,practical_salinity\n100,10,35\n600,3,35\n", r"starts at 100.0 dbar"),
    ("pressure_dbar,temperature_its90_degc,practical_salinity\n1,10,35\n100,abc,35\n", r"row 2 is not a number"),
    ("", r"empty"),
])
def test_bad_profile_files_are_one_line_errors(tmp_path, text, match):
    path = _write(tmp_path, "p.csv", text)
    with pytest.raises(InputError, match=match) as exc:
        read_overlying_profile(path)
    assert "\n" not in str(exc.value) and str(path) in str(exc.value)


def test_real_bad_files(shared_data, tmp_path, shared_cnv):
    # a time series with loops (not one binned cast): non-monotonic pressure
    src = shared_data / TIME_SERIES
    if not src.is_file():
        pytest.skip(f"{src} not present")
    with pytest.raises(InputError, match="not strictly monotonic") as exc, warnings.catch_warnings():
        warnings.simplefilter("ignore")
        read_overlying_profile(src)
    assert "\n" not in str(exc.value)
    # a profile that does not reach the record's start
    arc = shared_cnv(ARCTIC)
    c_col, c_scale, lat = CASTS[ARCTIC]
    prof = read_overlying_profile(_top_csv(tmp_path / "top.csv", arc.loc[arc["prDM"] < 200]))
    rec = _sensors(arc, c_col, c_scale).loc[arc["prDM"].to_numpy() >= 400].reset_index(drop=True)
    with pytest.raises(InputError, match=r"top\.csv: overlying profile covers 1.0 to 199.0 dbar but the record "
                                         r"starts at 400.0 dbar") as exc:
        derive_ctd(rec, lat, 0.0, DeriveParams(), overlying_profile=prof)
    assert "\n" not in str(exc.value)
    # a binary file, a missing one
    (tmp_path / "x.bin").write_bytes(b"\x00\x01" * 100)
    with pytest.raises(InputError, match="not a CSV or Sea-Bird"):
        read_overlying_profile(tmp_path / "x.bin")
    with pytest.raises(ConfigError, match="does not exist"):
        read_overlying_profile(tmp_path / "none.cnv")


def test_params_validation():
    for bad in ("", "   ", "a\x00b"):
        with pytest.raises(ValidationError):
            DeriveParams(overlying_profile=bad)
    assert DeriveParams(overlying_profile="/abs/top.csv").overlying_profile == "/abs/top.csv"


def test_overlying_profile_outside_the_dive_is_refused_in_one_line(tmp_path):
    """Like every source, the overlying profile resolves inside the dive directory (issue 45: confinement):
    a ``..`` path, an absolute path elsewhere and a symbolic link out of the dive are one-line config errors;
    a file inside the dive (relative or absolute) is accepted."""
    raw = tmp_path / "dive"
    raw.mkdir()
    outside = tmp_path / "top.csv"
    outside.write_text("pressure_dbar,density_kg_m3\n0,1025\n")
    (raw / "link.csv").symlink_to(outside)
    (raw / "inside.csv").write_text("pressure_dbar,density_kg_m3\n0,1025\n")
    for rel in ("../top.csv", str(outside), "link.csv"):
        with pytest.raises(ConfigError, match="escapes the dive directory") as exc:
            derive.overlying_profile_path(DeriveParams(overlying_profile=rel), raw)
        assert "\n" not in str(exc.value)
    assert derive.overlying_profile_path(DeriveParams(overlying_profile="inside.csv"), raw) == (raw / "inside.csv").resolve()
    assert derive.overlying_profile_path(DeriveParams(overlying_profile=str(raw / "inside.csv")), raw) \
        == (raw / "inside.csv").resolve()
