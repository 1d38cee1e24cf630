"""hadal.ctd (Sea-Bird processing steps) against two independent oracles.

(a) SBEDataProcessing's own step outputs (``formats-real/sbs_SBE19plus_01906398_2019_07_15_0033_cropped*.cnv``,
    one SBE 19plus cast: DatCnv -> LoopEdit -> WildEdit, and DatCnv -> BinAvg; the settings below are those
    printed in each file's header), read with hadal's .cnv reader. LoopEdit and WildEdit flags are reproduced
    exactly; BinAvg means to the file's printed precision (half a unit of the last printed digit).
(b) Sea-Bird's ``seabirdscientific.processing`` functions, one by one, on real casts of ``ctd-real/``.
"""

from __future__ import annotations

import numpy as np
import pytest

from hadal import ctd
from hadal.seawater import depth_fofonoff_millard

CROPPED = "formats-real/sbs_SBE19plus_01906398_2019_07_15_0033_cropped"
EXAMPLE = "ctd-real/sbs_19plus_V2_CTD-processing_example.cnv"  # 3069 scans at 4 Hz, DatCnv only
BINNED = ("ctd-real/oceissues644_02dk.cnv", "ctd-real/seabird_dPIRX010.cnv", "ctd-real/pyctd_CTD_with_sigma_e00.cnv")
FLAG = -9.99e-29  # SeaSoft's bad flag (seabirdscientific.constants.FLAG_VALUE)
# BinAvg output columns -> half a unit of the printed last digit
PRINTED = {"timeS": 5e-4, "c0mS/cm": 5e-7, "prdM": 5e-4, "tv290C": 5e-5}


@pytest.fixture(scope="module")
def sbe(shared_cnv):
    return {k: shared_cnv(f"{CROPPED}{k}.cnv") for k in ("", "_loopedit", "_loopedit_wildedit", "_binavg")}


@pytest.fixture(scope="module")
def example(shared_cnv):
    return shared_cnv(EXAMPLE)


def _setting(df, key):
    return next(v for k, v in df.attrs["processing"] if k == key)


# ----------------------------------------------------------------------------- (a) SBEDataProcessing outputs
def test_loop_edit_reproduces_sbe(sbe):
    src, out = sbe[""], sbe["_loopedit"]
    assert float(_setting(out, "loopedit_minVelocity")) == 0.25
    assert src.attrs["interval"] == {"kind": "seconds", "value": 0.25}
    z = depth_fofonoff_millard(src["prdM"].to_numpy(), 0.0)  # no latitude in the header
    bad = ctd.loop_edit(z, 0.25, min_velocity_m_s=0.25, remove_surface_soak=False)
    expected = out["flag"].isna().to_numpy()  # read_cnv turns the bad flag into NaN
    assert expected.sum() == 76
    assert np.array_equal(bad, expected)
    # the latitude (depth vs pressure scale, 0.3 %) does not change a single flag here
    assert np.array_equal(ctd.loop_edit(depth_fofonoff_millard(src["prdM"].to_numpy(), 80.0), 0.25), expected)


def test_wild_edit_reproduces_sbe_after_our_loop_edit(sbe):
    src, le, we = sbe[""], sbe["_loopedit"], sbe["_loopedit_wildedit"]
    settings = dict(we.attrs["processing"])
    assert settings["wildedit_vars"].split() == ["c0mS/cm", "prdM", "tv290C"]
    bad = ctd.loop_edit(depth_fofonoff_millard(src["prdM"].to_numpy(), 0.0), 0.25)
    for var in ("c0mS/cm", "prdM", "tv290C"):
        assert np.array_equal(src[var].to_numpy(), le[var].to_numpy())  # LoopEdit changes flags only
        wild = ctd.wild_edit(src[var].to_numpy(), std_pass_1=float(settings["wildedit_pass1_nstd"]),
                             std_pass_2=float(settings["wildedit_pass2_nstd"]),
                             scans_per_block=int(settings["wildedit_npoint"]),
                             min_delta=float(settings["wildedit_pass2_mindelta"]), bad=bad,
                             exclude_bad=settings["wildedit_excl_bad_scans"] == "yes")
        expected = we[var].isna().to_numpy()
        assert expected.sum() > 30, var
        assert np.array_equal(wild, expected), (var, int((wild != expected).sum()))
        kept = ~expected
        assert np.array_equal(src[var].to_numpy()[kept], we[var].to_numpy()[kept])


def test_bin_average_reproduces_sbe(sbe):
    src, out = sbe[""], sbe["_binavg"]
    s = dict(out.attrs["processing"])
    assert s["binavg_bintype"] == "decibars" and float(s["binavg_binsize"]) == 2.0
    assert s["binavg_surface_bin"].startswith("no") and int(s["binavg_min_scans_bin"]) == 1
    cols = list(PRINTED)
    r = ctd.bin_average(src["prdM"].to_numpy(), {c: src[c].to_numpy() for c in cols}, 2.0,
                        bad=src["flag"].isna().to_numpy())
    assert len(r.nbin) == len(out) == 21
    assert np.array_equal(r.nbin, out["nbin"].to_numpy().astype(int))
    assert list(r.cast).count("descent") == 11  # 2..22 dbar down (22: the turn-around bin), 20..2 up
    assert np.array_equal(r.centre, np.r_[np.arange(2, 23, 2), np.arange(20, 1, -2)])
    for c, tol in PRINTED.items():
        d = np.abs(r.means[c] - out[c].to_numpy())
        assert d.max() <= tol * (1 + 1e-6), (c, d.max())


def test_chain_on_sbe_cast_is_step_by_step(sbe):
    """DatCnv -> LoopEdit -> WildEdit -> BinAvg with our steps: the scans left are SeaSoft's."""
    src, we = sbe[""], sbe["_loopedit_wildedit"]
    bad = ctd.loop_edit(depth_fofonoff_millard(src["prdM"].to_numpy(), 0.0), 0.25)
    wild = {v: ctd.wild_edit(src[v].to_numpy(), std_pass_1=1.0, std_pass_2=2.5, min_delta=0.1, bad=bad)
            for v in ("c0mS/cm", "prdM", "tv290C")}
    any_bad = bad | np.logical_or.reduce(list(wild.values()))
    expected = we["flag"].isna().to_numpy() | we[["c0mS/cm", "prdM", "tv290C"]].isna().any(axis=1).to_numpy()
    assert np.array_equal(any_bad, expected)
    r = ctd.bin_average(src["prdM"].to_numpy(), {"tv290C": src["tv290C"].to_numpy()}, 2.0, bad=any_bad)
    assert r.nbin.sum() == (~expected & (src["prdM"].to_numpy() >= 1.0)).sum()


# ----------------------------------------------------------------------------- (b) seabirdscientific, per function
sbs = pytest.importorskip("seabirdscientific.processing")


@pytest.mark.parametrize("advance_s", [0.5, 0.25, 1.073, -0.4, 0.0])
def test_align_matches_seabirdscientific(example, advance_s):
    for col in ("tv290C", "c0S/m"):
        x = example[col].to_numpy()
        ours = ctd.align_ctd(x, advance_s, 0.25)
        ref = sbs.align_ctd(x, advance_s, 0.25)
        ref = np.where(ref == FLAG, np.nan, ref)
        assert np.array_equal(np.isnan(ours), np.isnan(ref)), (col, advance_s)
        ok = np.isfinite(ref)
        assert np.abs(ours[ok] - ref[ok]).max() <= 1e-12 * np.abs(ref[ok]).max()


@pytest.mark.parametrize(("alpha", "beta_inv"), [(0.04, 8.0), (0.03, 7.0), (0.1, 2.0)])
def test_cell_thermal_mass_matches_seabirdscientific(example, alpha, beta_inv):
    t, c = example["tv290C"].to_numpy(), example["c0S/m"].to_numpy()
    ours = ctd.cell_thermal_mass(t, c, alpha, beta_inv, 0.25)
    ref = sbs.cell_thermal_mass(t, c, alpha, beta_inv, 0.25)
    assert np.abs(ours - ref).max() <= 1e-12
    assert np.abs(ours - c).max() > 1e-5  # the correction is not nothing on this cast


@pytest.mark.parametrize("tau_s", [0.5, 1.0, 0.03])
def test_low_pass_matches_seabirdscientific(example, tau_s):
    for col in ("prdM", "tv290C"):
        x = example[col].to_numpy()
        ours = ctd.low_pass_filter(x, tau_s, 0.25)
        ref = sbs.low_pass_filter(x, tau_s, 0.25)
        assert np.abs(ours - ref).max() <= 1e-9 * max(1.0, np.abs(x).max())


def test_low_pass_step_response_is_the_time_constant():
    """One forward pass of Sea-Bird's filter on a step reaches 1 - 1/e after one time constant (RC filter)."""
    from scipy.signal import lfilter

    dt, tau = 0.01, 1.0
    r = 2 * tau / dt
    a = 1 / (1 + r)
    y = lfilter([a, a], [1, a * (1 - r)], np.ones(1000))
    assert y[int(tau / dt)] == pytest.approx(1 - np.exp(-1), abs=2e-3)
    # and the forward-backward filter keeps a constant series constant, bridging NaNs
    x = np.full(200, 3.5)
    x[50] = np.nan
    f = ctd.low_pass_filter(x, 1.0, 0.25)
    assert np.isnan(f[50]) and np.allclose(np.delete(f, 50), 3.5, atol=1e-12)


LOOP_CASES = [
    dict(min_velocity_type="fixed", min_velocity_m_s=0.25, remove_surface_soak=False),
    dict(min_velocity_type="fixed", min_velocity_m_s=0.1, remove_surface_soak=True, min_soak_depth_m=2.0,
         max_soak_depth_m=10.0),
    dict(min_velocity_type="fixed", min_velocity_m_s=0.4, remove_surface_soak=True, use_deck_pressure_offset=False),
    dict(min_velocity_type="percent", min_velocity_m_s=0.1, mean_speed_percent=20.0, window_s=3.0),
    dict(min_velocity_type="percent", min_velocity_m_s=0.25, mean_speed_percent=50.0, window_s=10.0,
         remove_surface_soak=True, min_soak_depth_m=1.0, max_soak_depth_m=5.0),
]


@pytest.mark.parametrize("case", LOOP_CASES)
def test_loop_edit_matches_seabirdscientific(example, sbe, case):
    for df, dt in ((example, 0.25), (sbe[""], 0.25)):
        p = df["prdM"].to_numpy()
        z = depth_fofonoff_millard(p, 0.0)
        ours = ctd.loop_edit(z, dt, **case)
        ref = sbs.loop_edit(z, np.zeros(p.size), dt, case["min_velocity_type"], case["min_velocity_m_s"],
                            case.get("window_s", 300.0), case.get("mean_speed_percent", 20.0),
                            case.get("remove_surface_soak", False), case.get("min_soak_depth_m", 5.0),
                            case.get("max_soak_depth_m", 20.0), case.get("use_deck_pressure_offset", True), True)
        assert np.array_equal(ours, ref == FLAG), (case, int((ours != (ref == FLAG)).sum()))
        assert 0 < ours.sum() < p.size


def test_loop_edit_keeps_earlier_flags(example):
    z = depth_fofonoff_millard(example["prdM"].to_numpy(), 0.0)
    prior = np.zeros(z.size, dtype=bool)
    prior[1500:1510] = True
    ours = ctd.loop_edit(z, 0.25, bad=prior)
    ref = sbs.loop_edit(z, np.where(prior, FLAG, 0.0), 0.25, "fixed", 0.25, 300, 20, False, 5, 20, True, True)
    assert ours[prior].all() and np.array_equal(ours, ref == FLAG)


@pytest.mark.parametrize(("s1", "s2", "block", "delta", "exclude"),
                         [(2.0, 20.0, 100, 0.0, False), (1.0, 2.5, 100, 0.1, True), (1.5, 3.0, 37, 0.0, False)])
def test_wild_edit_matches_seabirdscientific(example, s1, s2, block, delta, exclude, shared_cnv):
    z = depth_fofonoff_millard(example["prdM"].to_numpy(), 0.0)
    loop = ctd.loop_edit(z, 0.25)
    series = [(example[c].to_numpy(), loop) for c in ("tv290C", "c0S/m", "prdM")]
    for rel in BINNED:  # SeaSoft-binned casts: other water, other instruments
        df = shared_cnv(rel)
        col = next(c for c in df.columns if c.startswith(("t090C", "t068C")))
        series.append((df[col].to_numpy(), np.zeros(len(df), dtype=bool)))
    n_flagged = 0
    for x, bad in series:
        ours = ctd.wild_edit(x, std_pass_1=s1, std_pass_2=s2, scans_per_block=block, min_delta=delta, bad=bad,
                             exclude_bad=exclude)
        ref = sbs.wild_edit(x, np.where(bad, FLAG, 0.0), s1, s2, block, delta, exclude)
        assert np.array_equal(ours, ref == FLAG)
        n_flagged += int(ours.sum())
    assert n_flagged > 0


def _sbs_bin(df, cols, control, size, bad, cast):
    import xarray as xr

    d = df[cols].copy()
    d["flag"] = np.where(bad, FLAG, 0.0)
    ds = xr.Dataset({c: ("scan", d[c].to_numpy()) for c in d.columns}, coords={"scan": np.arange(len(d))})
    return sbs.bin_average(ds, control, size, cast_type=cast)


@pytest.mark.parametrize(("size", "cast"), [(2.0, "both"), (1.0, "both"), (5.0, "both"), (1.0, "descent"),
                                            (3.0, "ascent")])
def test_bin_average_matches_seabirdscientific(example, size, cast):
    cols = ["prdM", "tv290C", "c0S/m", "sal00"]
    bad = ctd.loop_edit(depth_fofonoff_millard(example["prdM"].to_numpy(), 0.0), 0.25)
    ours = ctd.bin_average(example["prdM"].to_numpy(), {c: example[c].to_numpy() for c in cols}, size, bad=bad,
                           cast=cast)
    kind = {"both": sbs.CastType.BOTH, "descent": sbs.CastType.DOWNCAST, "ascent": sbs.CastType.UPCAST}[cast]
    ref = _sbs_bin(example, cols, "prdM", size, bad, kind)
    assert np.array_equal(ours.nbin, ref["nbin"].values.astype(int))
    for c in cols:
        assert np.abs(ours.means[c] - ref[c].values).max() <= 1e-9 * max(1.0, np.abs(ref[c].values).max()), c


def test_split_matches_seabirdscientific(example):
    p = example["prdM"].to_numpy()
    bad = ctd.loop_edit(depth_fofonoff_millard(p, 0.0), 0.25)
    flag = np.where(bad, FLAG, 0.0)
    for min_depth in (-np.inf, 0.0, 5.0):
        assert ctd.find_downcast(p, bad, min_depth) == sbs.find_downcast(p, flag, min_depth)
        assert ctd.find_upcast(p, bad, min_depth) == sbs.find_upcast(p, flag, min_depth)
    lab = ctd.cast_labels(p, bad)
    assert lab[int(np.nanargmax(np.where(bad, np.nan, p)))] == "descent"
    assert set(lab) <= {"descent", "ascent", ""} and (lab == "ascent").sum() > 100


def test_bad_arguments_are_one_line_errors():
    from hadal.errors import InputError

    with pytest.raises(ValueError):
        ctd.align_ctd([1.0, 2.0], 1.0, 0.0)
    with pytest.raises(ValueError):
        ctd.cell_thermal_mass([1.0], [1.0], 0.0, 7.0, 1.0)
    with pytest.raises(InputError):
        ctd.bin_average([np.nan, np.nan], {}, 1.0)
    with pytest.raises(InputError):
        ctd.find_downcast([1.0, 2.0], [True, True])


def test_cell_thermal_mass_holds_missing_temperature(example):
    """A NaN temperature is held at the last valid one: equal to seabirdscientific on the held series."""
    t, c = example["tv290C"].to_numpy().copy(), example["c0S/m"].to_numpy()
    t[[0, 1, 700, 701, 702, 2000]] = np.nan
    held = t.copy()
    for i in range(held.size):
        if np.isnan(held[i]):
            held[i] = held[i - 1] if i and np.isfinite(held[i - 1]) else np.nan
    held[:2] = held[2]
    ours = ctd.cell_thermal_mass(t, c, 0.04, 8.0, 0.25)
    assert np.isfinite(ours).all()
    assert np.abs(ours - sbs.cell_thermal_mass(held, c, 0.04, 8.0, 0.25)).max() <= 1e-12


def test_raw_hex_through_the_chain_equals_seasoft_datcnv_through_it(shared_data, example):
    """From the instrument's own .hex (hadal's DatCnv): LoopEdit flags and 1 dbar BinAvg means equal those of
    SeaSoft's DatCnv output of the same cast, to the .cnv's printed precision."""
    from hadal.ingest.seabird_hex import read_hex

    p = shared_data / "formats-real/sbs_19plus_V2.hex"
    if not p.is_file():
        pytest.skip(f"{p} not present")
    raw = read_hex(p, raw=True)
    bads = []
    means = []
    for df in (raw, example):
        bad = ctd.loop_edit(depth_fofonoff_millard(df["prdM"].to_numpy(), 0.0), 0.25)
        bads.append(bad)
        means.append(ctd.bin_average(df["prdM"].to_numpy(), {"t": df["tv290C"].to_numpy(),
                                                             "c": df["c0S/m"].to_numpy()}, 1.0, bad=bad))
    # the pressure differs by <= 6e-4 dbar (printed 3 decimals): a handful of velocity decisions can flip
    assert (bads[0] != bads[1]).sum() <= 5
    assert abs(len(means[0].nbin) - len(means[1].nbin)) <= 1
    n = min(len(means[0].nbin), len(means[1].nbin))
    same = means[0].nbin[:n] == means[1].nbin[:n]
    assert same.mean() > 0.95
    assert np.nanmax(np.abs(means[0].means["t"][:n] - means[1].means["t"][:n])[same]) < 1e-4
    assert np.nanmax(np.abs(means[0].means["c"][:n] - means[1].means["c"][:n])[same]) < 1e-5
