"""hadal.seawater against published check values (UNESCO 44, GSW) and SeaSoft's own columns in real .cnv casts.

Table-driven like GSW-Python's check-value tests: each row is (inputs, expected, tolerance = half a unit in
the last printed digit unless stated). Sources: /work/shared/data/check_values.md.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np
import pytest

from hadal import seawater as sw

# ------------------------------------------------------------------------------------- UNESCO 44 tables
# PSS-78, UNESCO 44 p. 9: (R, t68, p) -> (Rp, rt, Rt, S)
PSS78 = [
    (1.0, 15, 0, 1.0000000, 1.0000000, 1.0000000, 35.000000),
    (1.2, 20, 2000, 1.0169429, 1.1164927, 1.0568875, 37.245628),
    (0.65, 5, 1500, 1.0204864, 0.77956585, 0.81705885, 27.995347),
]


@pytest.mark.parametrize("r, t68, p, rp, rt, big_rt, s", PSS78)
def test_pss78_unesco44(r, t68, p, rp, rt, big_rt, s):
    got = sw.pss78_ratios(r, t68, p)
    np.testing.assert_allclose(got, (rp, rt, big_rt), atol=5e-8, rtol=0)
    assert sw.salinity_from_ratio(r, t68, p) == pytest.approx(s, abs=5e-7)


def test_pss78_fortran_sal78_and_c3515():
    # R printed to 1e-6 and dS/dR ~ 21 at S=40: S known to ~2e-5
    assert sw.salinity_from_ratio(1.888091, 40.0, 10000.0) == pytest.approx(40.0, abs=2e-5)
    # C(35, 15 degC IPTS-68, 0) gives S = 35 through the ITS-90 interface, as it does in the peer library (gsw,
    # mS/cm), across a range of conductivities and pressures
    assert sw.practical_salinity(sw.C3515_S_M, 15.0 / 1.00024, 0.0) == pytest.approx(35.0, abs=5e-7)
    gsw = pytest.importorskip("gsw")
    assert float(gsw.SP_from_C(10 * sw.C3515_S_M, 15.0 / 1.00024, 0.0)) == pytest.approx(35.0, abs=5e-7)
    c, t, p = np.meshgrid([2.5, 3.3, 4.2914, 5.5], [-1.5, 2.0, 15.0, 28.0], [0.0, 1000.0, 6000.0], indexing="ij")
    np.testing.assert_allclose(sw.practical_salinity(c, t, p), gsw.SP_from_C(10 * c, t, p), atol=2e-6, rtol=0)


# Row 1 is printed 0.498088 in UNESCO 44, a misprint: the CSIRO SEAWATER test report lists the same mismatch
# (it computes 0.49800825, as python-seawater and we do), and R = 0.498088 would give S = 25.0044, not 25.
CNDR = [(0, 0, 25, 0.498008), (10, 0, 25, 0.654990), (0, 1000, 25, 0.506244), (10, 1000, 25, 0.662975),
        (10, 0, 40, 1.000073), (30, 0, 40, 1.529967)]


@pytest.mark.parametrize("t68, p, s, r", CNDR)
def test_conductivity_ratio_inverse_unesco44(t68, p, s, r):
    assert sw.conductivity_ratio(s, t68, p) == pytest.approx(r, abs=5e-7)


def test_cndr_misprint_is_inconsistent_with_pss78():
    assert abs(sw.salinity_from_ratio(0.498088, 0.0, 0.0) - 25.0) > 1e-3
    assert sw.salinity_from_ratio(0.498008, 0.0, 0.0) == pytest.approx(25.0, abs=2e-5)


# EOS-80, UNESCO 44 p. 19: S, t68, p -> rho (kg m-3), V (1e-3 m3 kg-1)
EOS80 = [
    (0, 5, 0, 999.96675, 1.000033251), (0, 5, 10000, 1044.12802, 0.957736964),
    (0, 25, 0, 997.04796, 1.00296078), (0, 25, 10000, 1037.90204, 0.963482064),
    (35, 5, 0, 1027.67547, 0.973069835), (35, 5, 10000, 1069.48914, 0.935025857),
    (35, 25, 0, 1023.34306, 0.977189409), (35, 25, 10000, 1062.53817, 0.941142660),
]


@pytest.mark.parametrize("s, t68, p, rho, v", EOS80)
def test_eos80_unesco44(s, t68, p, rho, v):
    got = sw.density_eos80_t68(s, t68, p)
    assert got == pytest.approx(rho, abs=5e-6)
    assert 1000.0 / got == pytest.approx(v, abs=5e-9 if v < 1 else 5e-8)
    # the ITS-90 interface is the same formula after T68 = 1.00024 T90
    assert sw.density_eos80(s, t68 / 1.00024, p) == pytest.approx(got, abs=1e-10)


SVAN = [(0, 0, 0, 2749.54), (0, 0, 10000, 2288.61), (0, 30, 0, 3170.58), (0, 30, 10000, 3147.85),
        (35, 0, 0, 0.00), (35, 0, 10000, 0.00), (35, 30, 0, 607.14), (35, 30, 10000, 916.34)]


@pytest.mark.parametrize("s, t68, p, svan", SVAN)
def test_specific_volume_anomaly_unesco44(s, t68, p, svan):
    got = sw.specific_volume_anomaly(s, t68 / 1.00024, p) * 1e8
    assert got == pytest.approx(svan, abs=5e-3)


def test_svan_sigma_40_40_10000():
    rho = sw.density_eos80_t68(40, 40, 10000)
    assert rho - 1000 == pytest.approx(59.82037, abs=2e-5)  # 59.82037 (UNESCO), 59.82038 (CSIRO)
    svan = sw.specific_volume_anomaly(40, 40 / 1.00024, 10000) * 1e8
    assert svan == pytest.approx(981.30210, abs=3e-4)  # UNESCO's 981.30210 is 32-bit: CSIRO gets 981.30190


def test_other_unesco44_checks():
    assert sw.potential_temperature_t68(40, 40, 10000, 0) == pytest.approx(36.89073, abs=5e-6)
    assert sw.sound_speed_chen_millero_t68(40, 40, 10000) == pytest.approx(1731.995, abs=5e-4)


DEPTH = {500: (496.65, 496.00, 495.34, 494.69, 494.03), 5000: (4915.04, 4908.56, 4902.08, 4895.60, 4889.13),
         10000: (9725.47, 9712.65, 9699.84, 9687.03, 9674.23)}


@pytest.mark.parametrize("p", sorted(DEPTH))
def test_depth_fofonoff_millard_unesco44(p):
    got = sw.depth_fofonoff_millard(p, [0, 30, 45, 60, 90])
    np.testing.assert_allclose(got, DEPTH[p], atol=5e-3, rtol=0)


def test_depth_fofonoff_millard_check_value():
    assert sw.depth_fofonoff_millard(10000, 30) == pytest.approx(9712.653, abs=5e-4)
    # the polynomial of Eq. (9) alone (integral term) is 95224.4 at 10 000 dbar... divided by g(30, p)
    assert sw.depth_fofonoff_millard(10000, 30) * sw.gravity_unesco(30, 10000) == pytest.approx(95224.4, abs=0.05)


@pytest.mark.parametrize("lat, g0", [(0, 9.780318), (30, 9.793240), (45, 9.806190), (60, 9.819169), (90, 9.832177)])
def test_gravity_unesco_form(lat, g0):
    assert sw.gravity_unesco(lat, 0.0) == pytest.approx(g0, abs=5e-7)


# ----------------------------------------------------------------------------------------- GSW checks
def _gsw_cv():
    gsw = pytest.importorskip("gsw")
    f = Path(gsw.__file__).parent / "tests" / "gsw_cv_v3_0.npz"
    if not f.is_file():
        pytest.skip("gsw check-value file gsw_cv_v3_0.npz not installed")
    return gsw, np.load(f)


def test_gravity_matches_gsw_check_cast():
    """Eq. (14) with the McDougall & Barker sign: g(lat, depth = -z_from_p) == gsw_grav check values."""
    _, cv = _gsw_cv()
    lat = cv["lat_chck_cast"].astype(float)
    depth = -cv["z_from_p"]
    got = sw.gravity(lat[np.newaxis, :], depth)
    ok = np.isfinite(cv["grav"])
    np.testing.assert_allclose(got[ok], cv["grav"][ok], atol=max(float(cv["grav_ca"]), 1e-12), rtol=0)
    np.testing.assert_allclose(sw.gravity(lat, 0.0), [9.78220713, 9.78173367, 9.81838559], atol=5e-9)
    # row 44 cast 0 (6131 dbar): grav = 9.7954958
    assert got[44, 0] == pytest.approx(9.7954958, abs=5e-8)


def test_gravity_increases_with_depth_like_gsw_grav():
    gsw = pytest.importorskip("gsw")
    p = np.linspace(0, 11000, 23)
    for lat in (0.0, 11.33, 45.0, 89.0):
        np.testing.assert_allclose(sw.gravity(lat, -gsw.z_from_p(p, lat)), gsw.grav(lat, p), atol=1e-12, rtol=0)
    g = sw.gravity(11.33, [0.0, 5000.0, 10900.0])
    assert np.all(np.diff(g) > 0)
    assert g[-1] - g[0] == pytest.approx(9.782 * 2.26e-7 * 10900, rel=1e-3)


# ------------------------------------------------------------------------- python-seawater cross-check
def test_agrees_with_python_seawater_over_the_ocean_range():
    psw = pytest.importorskip("seawater")
    rng = np.random.default_rng(1)
    n = 2000
    s = rng.uniform(2, 42, n)
    t = rng.uniform(-2, 35, n)
    p = rng.uniform(0, 10000, n)
    lat = rng.uniform(-90, 90, n)
    c = sw.conductivity_from_salinity(s, t, p)
    np.testing.assert_allclose(sw.practical_salinity(c, t, p), s, atol=1e-10)
    np.testing.assert_allclose(sw.practical_salinity(c, t, p), psw.salt(c / sw.C3515_S_M, t, p), atol=1e-9)
    np.testing.assert_allclose(sw.density_eos80(s, t, p), psw.dens(s, t, p), atol=1e-9)
    np.testing.assert_allclose(sw.sound_speed_chen_millero(s, t, p), psw.svel(s, t, p), atol=1e-8)
    np.testing.assert_allclose(sw.potential_temperature(s, t, p), psw.ptmp(s, t, p), atol=1e-8, rtol=0)
    np.testing.assert_allclose(sw.depth_fofonoff_millard(p, lat), psw.dpth(p, lat), atol=1e-3)


def test_nan_propagates_and_broadcasts():
    out = sw.practical_salinity([4.0, np.nan], 10.0, [100.0, 100.0])
    assert np.isfinite(out[0]) and np.isnan(out[1])
    assert sw.density_eos80(35.0, [0.0, 10.0], [[0.0], [1000.0]]).shape == (2, 2)
    assert sw.practical_salinity(0.0, 20.0, 0.0) == 0.0  # sensor in air: SeaSoft gives 0


# ------------------------------------------------------------------------------- SeaSoft .cnv columns
CNV_FILES = ["seabird_sta0860.cnv", "seabird_dPIRX010.cnv", "sbs_19plus_V2_CTD-processing_example.cnv",
             "oceissues644_02dk.cnv", "pyctd_CTD_with_sigma_e00.cnv"]


def _read(path: Path):
    """The cast as ``hadal.ingest.read_cnv`` reads it (a DataFrame named by SeaSoft short names, header in attrs)."""
    ingest = pytest.importorskip("hadal.ingest", reason="hadal.ingest.read_cnv not available")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # e.g. oceissues644: header nvalues larger than the rows kept
        return ingest.read_cnv(path)


def _header_latitude(path: Path) -> float | None:
    """Latitude of the ``* NMEA Latitude = 69 24.75 N`` header line (None when the cast has none)."""
    return _read(path).attrs.get("latitude_deg")


def _columns(path: Path) -> dict[str, np.ndarray]:
    """The cast's columns by SeaSoft short name (``prDM``, ``t090C``, ``sal00``, ``sigma-é00`` ...)."""
    df = _read(path)
    return {str(k): np.asarray(df[k], dtype=np.float64) for k in df.columns}


def _pick(cols: dict[str, np.ndarray], *prefixes: str) -> tuple[str, np.ndarray] | tuple[None, None]:
    for pre in prefixes:
        for k in cols:
            if k == pre or (k.startswith(pre) and pre.endswith("-")):
                return k, cols[k]
    return None, None


def _cast(path: Path):
    cols = _columns(path)
    _, p = _pick(cols, "prDM", "prdM", "prSM")
    if "t090C" in cols:
        t90 = cols["t090C"]
    elif "tv290C" in cols:
        t90 = cols["tv290C"]
    else:
        t90 = sw.t90_from_t68(cols["t068C"])
    c = cols["c0S/m"] if "c0S/m" in cols else cols["c0mS/cm"] / 10.0
    return cols, p, t90, c


@pytest.mark.parametrize("name", CNV_FILES)
def test_seasoft_columns(shared_data, name):
    path = shared_data / "ctd-real" / name
    if not path.is_file():
        pytest.skip(f"{path} not present")
    cols, p, t90, c = _cast(path)
    sp = sw.practical_salinity(c, t90, p)
    # PSS-78 validity range; where the cast has a second temperature sensor, scans where the two disagree by
    # more than 0.05 degC are sensor faults (the bottom of dPIRX010: primary T jumping between -20 and 30 degC)
    valid = (t90 > -2.5) & (t90 < 35) & (sp > 2) & (sp < 42)
    if "t190C" in cols:
        valid &= np.abs(cols["t190C"] - t90) < 0.05
    assert valid.sum() > 0.9 * valid.size
    checked = []
    binned = name.startswith("pyctd")
    if binned:
        # bin-averaged file: SeaSoft averaged salinity of the scans, we compute it from averaged C and T;
        # documented agreement ~2e-3 (README), the median is at the print precision
        err = np.abs(sp - cols["sal00"])[valid]
        assert np.median(err) < 1e-4 and np.quantile(err, 0.95) < 2e-3
        return
    np.testing.assert_allclose(sp[valid], cols["sal00"][valid], atol=1e-4, rtol=0)
    checked.append("sal00")
    k, sig = _pick(cols, "sigma-t00")
    if k:
        np.testing.assert_allclose(sw.sigma_t(sp, t90)[valid], sig[valid], atol=1e-4, rtol=0)
        checked.append(k)
    k = next((k for k in cols if k.startswith("sigma-") and k.endswith("00") and k != "sigma-t00"), None)
    if k:
        np.testing.assert_allclose(sw.sigma_theta(sp, t90, p)[valid], cols[k][valid], atol=1e-4, rtol=0)
        checked.append(k)
    if "svCM" in cols:
        np.testing.assert_allclose(sw.sound_speed_chen_millero(sp, t90, p)[valid], cols["svCM"][valid],
                                   atol=5e-3, rtol=0)
        checked.append("svCM")
    if "potemp090C" in cols:
        np.testing.assert_allclose(sw.potential_temperature(sp, t90, p)[valid], cols["potemp090C"][valid],
                                   atol=1e-4, rtol=0)
        checked.append("potemp090C")
    assert checked


@pytest.mark.parametrize("name", CNV_FILES)
def test_seasoft_depth(shared_data, name):
    """SeaSoft depSM (Fofonoff-Millard, "salt water") with the latitude of the cast's header."""
    path = shared_data / "ctd-real" / name
    if not path.is_file():
        pytest.skip(f"{path} not present")
    lat = _header_latitude(path)
    if lat is None:
        pytest.skip(f"{name}: no NMEA latitude in the header, so depth cannot be computed (SeaSoft needs it too)")
    cols, p, _, _ = _cast(path)
    if "depSM" not in cols:
        pytest.skip(f"{name}: SeaSoft did not derive depSM for this cast")
    np.testing.assert_allclose(sw.depth_fofonoff_millard(p, lat), cols["depSM"], atol=1e-3, rtol=0)
