"""The Sea-Bird chain and the TEOS-10 columns inside ``derive`` on real casts.

Oracles: SeaSoft's own outputs (BinAvg file; sal00, potemp090C, sigma-theta columns), ``gsw`` called directly,
and ``seabirdscientific.processing`` for the chained channel steps.
"""

from __future__ import annotations

import numpy as np
import pandas as pd
import pytest

from hadal import ctd
from hadal.ctd import derive
from hadal.settings import DeriveParams

gsw = pytest.importorskip("gsw")

CROPPED = "formats-real/sbs_SBE19plus_01906398_2019_07_15_0033_cropped"
EXAMPLE = "ctd-real/sbs_19plus_V2_CTD-processing_example.cnv"
LAT, LON = 36.6, -121.9  # Monterey Bay (the casts' headers carry no position; any ocean position does)
FLAG = -9.99e-29


def _sensors(df, c_col, t_col, p_col, c_scale=1.0, dt=0.25):
    t0 = pd.Timestamp("2019-07-02T15:46:41Z")
    return pd.DataFrame({"time": t0 + pd.to_timedelta(np.arange(len(df)) * dt, unit="s"),
                         "conductivity_s_m": df[c_col].to_numpy() * c_scale,
                         "temperature_its90_degc": df[t_col].to_numpy(), "pressure_ctd_dbar": df[p_col].to_numpy()})


@pytest.fixture(scope="module")
def example(shared_cnv):
    return shared_cnv(EXAMPLE)


@pytest.fixture(scope="module")
def example_derived(example):
    return derive.derive_ctd(_sensors(example, "c0S/m", "tv290C", "prdM"), LAT, LON, DeriveParams())


def test_teos10_columns_against_gsw_and_seasoft_salinity(example, example_derived):
    out, _ = example_derived
    p = example["prdM"].to_numpy()
    sa_ref = gsw.SA_from_SP(example["sal00"].to_numpy(), p, LON, LAT)  # from SeaSoft's salinity
    ct_ref = gsw.CT_from_t(sa_ref, example["tv290C"].to_numpy(), p)
    good = p > 1.0  # SeaSoft's sal00 is only printed to 4 decimals; near-surface conductivity ~0
    sa, ct = out["absolute_salinity_g_kg"].to_numpy(), out["conservative_temperature_degc"].to_numpy()
    assert np.nanmax(np.abs(sa - sa_ref)[good]) < 2e-4  # sal00 printed precision x dSA/dSP
    assert np.nanmax(np.abs(ct - ct_ref)[good]) < 1e-5
    assert np.nanmax(np.abs(out["sigma0_kg_m3"].to_numpy() - gsw.sigma0(sa_ref, ct_ref))[good]) < 2e-4
    pt = gsw.pt0_from_t(sa_ref, example["tv290C"].to_numpy(), p)
    assert np.nanmax(np.abs(out["potential_temperature_degc"].to_numpy() - pt)[good]) < 1e-5


@pytest.mark.parametrize(("rel", "t_col", "c_col", "c_scale", "pt_col", "sig_col"), [
    ("ctd-real/pyctd_CTD_with_sigma_e00.cnv", "t068C", "c0S/m", 1.0, "potemp090C", "sigma-\xe900"),
    ("ctd-real/seabird_dPIRX010.cnv", "t090C", "c0S/m", 1.0, "potemp090C", None),
])
def test_teos10_theta_and_sigma0_close_to_seasoft_eos80(rel, t_col, c_col, c_scale, pt_col, sig_col, shared_cnv):
    """TEOS-10 potential temperature / sigma0 against SeaSoft's EOS-80 theta / sigma-theta of the same cast:
    different equations of state, so agreement to a few mK / 0.01 kg m-3 (McDougall & Barker 2011, Fig. 1)."""
    df = shared_cnv(rel)
    t = df[t_col].to_numpy()
    if t_col.startswith("t068"):
        t = t / 1.00024  # IPTS-68 -> ITS-90
    sens = pd.DataFrame({"time": pd.NaT, "conductivity_s_m": df[c_col].to_numpy() * c_scale,
                         "temperature_its90_degc": t, "pressure_ctd_dbar": df["prDM"].to_numpy()})
    out, _ = derive.derive_ctd(sens, LAT, LON, DeriveParams())
    pr = df["prDM"].to_numpy()
    # derive puts a binned cast in pressure order when it is not monotonic
    order = np.arange(pr.size) if (np.all(np.diff(pr) >= 0) or np.all(np.diff(pr) <= 0)) else np.argsort(
        pr, kind="stable")
    theta = df[pt_col].to_numpy()[order]
    # plausible water only: dPIRX010 ends in scans with T = 98 degC and S = 78 (a primary-sensor failure that
    # SeaSoft kept; its secondary sensor reads 4.7 degC): keep scans where both sensors agree
    sal = df["sal00"].to_numpy()
    sane = (t > -2) & (t < 40) & (sal > 20) & (sal < 42)
    if "t190C" in df:
        sane &= np.abs(df["t090C"].to_numpy() - df["t190C"].to_numpy()) < 0.1
    sane = sane[order]
    assert sane.sum() > 150
    d = np.abs(out["potential_temperature_degc"].to_numpy() - theta)[sane]
    assert np.nanmax(d) < 5e-3, np.nanmax(d)
    if sig_col:
        sig = df[sig_col].to_numpy()[order]
        d = np.abs(out["sigma0_kg_m3"].to_numpy() - sig)[sane]
        assert np.nanmax(d) < 0.02, np.nanmax(d)


def test_profile_n_squared_against_gsw(example, example_derived):
    out, meta = example_derived
    out = out.assign(phase=ctd.cast_labels(out["pressure_dbar"].to_numpy()))
    from hadal.ctd.profile import N_SQUARED, make_profile, n_squared_per_sample

    prof = make_profile(out, 1.0, latitude_deg=LAT)
    k = 0  # descent
    pr = prof["pressure_dbar"].values
    sa, ct = prof["absolute_salinity_g_kg"].values[k], prof["conservative_temperature_degc"].values[k]
    ok = np.isfinite(sa) & np.isfinite(ct)
    n2, pm = gsw.Nsquared(sa[ok], ct[ok], pr[ok], lat=np.full(ok.sum(), LAT))
    ours = prof[N_SQUARED].values[k]
    # at each level: gsw's N² of the binned cast, linear between its mid-points
    inside = ok & (pr >= pm[0]) & (pr <= pm[-1])
    assert inside.sum() > 10
    assert np.allclose(ours[inside], np.interp(pr[inside], pm, n2), rtol=0, atol=1e-15)
    assert np.isnan(ours[~ok]).all()
    assert np.nanmax(ours) > 1e-4  # a real thermocline (~1e-3 s-2 in the top 20 m)
    per_sample = n_squared_per_sample(out, prof)
    assert np.isfinite(per_sample).mean() > 0.75  # the rest: out of the water or above the first mid-point


def test_chain_channels_match_seabirdscientific(example):
    """Wild edit -> filter -> align -> cell thermal mass inside derive = seabirdscientific's functions chained."""
    p = DeriveParams(wild_edit=True, filter_pressure_s=1.0, filter_temperature_s=0.5, filter_conductivity_s=0.5,
                      align_conductivity_s=0.5, align_temperature_s=-0.25, cell_thermal_mass=True,
                      cell_thermal_mass_alpha=0.04, cell_thermal_mass_beta_inverse_s=8.0, loop_edit=True,
                      loop_edit_remove_surface_soak=False)
    sens = _sensors(example, "c0S/m", "tv290C", "prdM")
    out, meta = derive.derive_ctd(sens, LAT, LON, p)
    steps = [s["step"] for s in meta["ctd_processing"]]
    assert steps == ["wild_edit", "filter", "align_ctd", "cell_thermal_mass", "loop_edit"]
    assert meta["ctd_processing"][0]["parameters"]["wild_edit_std_pass_2"] == 20.0

    from seabirdscientific import processing as sbs

    def ref_chain(x, tau, adv):
        w = sbs.wild_edit(x, np.zeros(x.size), 2.0, 20.0, 100, 0.0, False) == FLAG
        x = np.where(w, np.nan, x)
        x = np.interp(np.arange(x.size), np.flatnonzero(~w), x[~w])  # the filter bridges wild values
        x = sbs.low_pass_filter(x, tau, 0.25)
        x[w] = np.nan
        if adv:
            x = sbs.align_ctd(x, adv, 0.25)
            x = np.where(x == FLAG, np.nan, x)
        return x

    c_ref = ref_chain(example["c0S/m"].to_numpy(), 0.5, 0.5)
    t_ref = ref_chain(example["tv290C"].to_numpy(), 0.5, -0.25)
    t_held = pd.Series(t_ref).ffill().bfill().to_numpy()  # CellTM holds a missing temperature
    c_ref = sbs.cell_thermal_mass(t_held, c_ref, 0.04, 8.0, 0.25)
    ok = np.isfinite(c_ref) & np.isfinite(t_ref)
    assert ok.sum() > 3000
    assert np.abs(out["temperature_its90_degc"].to_numpy()[ok] - t_ref[ok]).max() < 1e-9
    assert np.abs(out["conductivity_s_m"].to_numpy()[ok] - c_ref[ok]).max() < 1e-9
    le = sbs.loop_edit(out["depth_m"].to_numpy(), np.zeros(len(out)), 0.25, "fixed", 0.25, 300, 20, False, 5, 20,
                       True, True)
    assert np.array_equal(out["loop_edit_bad"].to_numpy(), le == FLAG)
    assert out["loop_edit_bad"].sum() > 100


def test_seabird_binning_reproduces_sbe_binavg(shared_cnv):
    """derive with profile_binning=seabird on SeaSoft's DatCnv output = SeaSoft's BinAvg output (2 dbar)."""
    src, sbe = shared_cnv(f"{CROPPED}.cnv"), shared_cnv(f"{CROPPED}_binavg.cnv")
    sens = _sensors(src, "c0mS/cm", "tv290C", "prdM", c_scale=0.1)
    p = DeriveParams(profile_binning="seabird", profile_bin_dbar=2.0, latitude_deg=LAT, longitude_deg=LON)

    class _Log:
        def warning(self, *a):
            pass

    df, meta, prof = derive.derive_table(sens, {}, p, None, _Log(), "cast")
    down = sbe.iloc[:11]
    up = sbe.iloc[11:]
    lev = prof["pressure_dbar"].values
    assert np.array_equal(lev, np.arange(2.0, 23.0, 2.0))
    t = prof["temperature_its90_degc"].values
    c = prof["conductivity_s_m"].values
    n = prof["count"].values
    assert np.abs(t[0] - down["tv290C"].to_numpy()).max() <= 5e-5 * 1.001
    assert np.abs(c[0] * 10 - down["c0mS/cm"].to_numpy()).max() <= 5e-7 * 1.001
    assert np.array_equal(n[0], down["nbin"].to_numpy().astype(int))
    # the ascent cast: 20 .. 2 dbar in SeaSoft's file order, the 22 dbar turn-around bin in the descent
    assert np.isnan(t[1][-1]) and n[1][-1] == 0
    assert np.abs(t[1][:-1][::-1] - up["tv290C"].to_numpy()).max() <= 5e-5 * 1.001
    assert np.array_equal(n[1][:-1][::-1], up["nbin"].to_numpy().astype(int))
    assert "buoyancy_frequency_squared_s2" in prof and "sigma0_kg_m3" in prof


def test_chain_skipped_without_time(shared_cnv):
    df = shared_cnv("ctd-real/seabird_dPIRX010.cnv")
    sens = pd.DataFrame({"time": pd.NaT, "conductivity_s_m": df["c0S/m"].to_numpy(),
                         "temperature_its90_degc": df["t090C"].to_numpy(), "pressure_ctd_dbar": df["prDM"].to_numpy()})
    out, meta = derive.derive_ctd(sens, LAT, LON, DeriveParams(filter_temperature_s=0.5, loop_edit=True))
    assert all("skipped" in s for s in meta["ctd_processing"])
    assert "loop_edit_bad" not in out
    assert np.array_equal(out["temperature_its90_degc"].to_numpy(), df["t090C"].to_numpy())


def test_params_bounds():
    from pydantic import ValidationError

    assert DeriveParams().loop_edit is False and DeriveParams().filter_pressure_s is None
    for bad in ({"wild_edit_std_pass_1": 0}, {"filter_pressure_s": 0}, {"align_conductivity_s": 100},
                {"cell_thermal_mass_alpha": 2}, {"loop_edit_min_velocity_type": "x"}, {"profile_binning": "y"}):
        with pytest.raises(ValidationError):
            DeriveParams(**bad)
