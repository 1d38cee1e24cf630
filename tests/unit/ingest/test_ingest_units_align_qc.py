"""Unit conversions, vehicle config, CSV reader, time alignment and QARTOD QC (table-driven)."""

from __future__ import annotations

import numpy as np
import pytest

from hadal.errors import ConfigError, InputError
from hadal.ingest import (
    DEFAULT_QC,
    VariableQC,
    align_linear,
    align_nearest,
    clean_times,
    convert,
    default_vehicle_config_path,
    load_vehicle_config,
    parse_time,
    qc_flags,
    read_sensor_csv,
)

# (value, unit, variable, expected canonical value)
CONVERSIONS = [
    (35.0, "mS/cm", "conductivity_s_m", 3.5),
    (3.5, "S/m", "conductivity_s_m", 3.5),
    (35000.0, "uS/cm", "conductivity_s_m", 3.5),
    (1000.0, "bar", "pressure_gauge_dbar", 10000.0),
    (100.0, "kPa", "pressure_ctd_dbar", 10.0),
    (105.0, "MPa", "pressure_ctd_dbar", 10500.0),
    (14.6959488, "psi", "pressure_ctd_dbar", 10.1325),
    (20.0048, "ITS-68", "temperature_its90_degc", 20.0),
    (275.15, "K", "temperature_its90_degc", 2.0),
    (np.pi, "rad", "heading_deg", 180.0),
    (1.0, "kn", "speed_m_s", 0.5144444444),
    (150.0, "cm", "altitude_m", 1.5),
]


@pytest.mark.parametrize("value,unit,var,expected", CONVERSIONS)
def test_convert(value, unit, var, expected):
    out, rec = convert([value], unit, var)
    assert out[0] == pytest.approx(expected, rel=1e-6)
    assert (rec is None) == (unit in ("S/m",))


def test_convert_rejects_bad_units():
    with pytest.raises(ConfigError, match="unknown unit"):
        convert([1.0], "furlongs", "altitude_m")
    with pytest.raises(ConfigError, match="cannot be converted"):
        convert([1.0], "dbar", "conductivity_s_m")


def test_packaged_vehicle_config():
    v = load_vehicle_config(default_vehicle_config_path())
    assert v.time_base == "ctd" and v.sensors["ctd"].required
    assert v.sensors["ctd"].mcap.topic == "/haidou/ctd"
    assert v.sensors["gauge"].csv.fields["pressure_gauge_dbar"].units == "bar"
    assert len(v.variables()) == 15  # 11 + the GNSS fix and its variances


@pytest.mark.parametrize(
    "text,match",
    [
        ("sensors: [unclosed", "not valid YAML"),
        ("- a\n- b\n", "expected a mapping"),
        ("sensors: {ctd: {mcap: {topic: /c, fields: {conductivity_s_m: {field: c, units: furlong}}}}}", "unknown unit"),
        ("sensors: {ctd: {mcap: {topic: /c, fields: {salinity: {field: c, units: S/m}}}}}", "unknown variable"),
        ("sensors: {ctd: {required: true}}", "needs an 'mcap' or a 'csv'"),
        ("time_base: ctd\nsensors: {gauge: {mcap: {topic: /k, fields: {pressure_gauge_dbar: {field: p, units: bar}}}}}",
         "time_base sensor 'ctd'"),
    ],
)
def test_bad_vehicle_config(tmp_path, text, match):
    p = tmp_path / "vehicle.yaml"
    p.write_text(text)
    with pytest.raises(ConfigError, match=match) as ei:
        load_vehicle_config(p)
    assert "\n" not in str(ei.value)


@pytest.mark.parametrize(
    "values,fmt,expected_ns",
    [
        (["2018-10-06T23:00:00Z"], "iso8601", 1538866800 * 10**9),
        (["2018-10-06T23:00:00.0625+00:00"], "iso8601", 1538866800 * 10**9 + 62_500_000),
        (["1538866800.5"], "unix_s", 1538866800 * 10**9 + 500_000_000),
        (["1538866800500"], "unix_ms", 1538866800 * 10**9 + 500_000_000),
        (["06/10/2018 23:00:01"], "%d/%m/%Y %H:%M:%S", 1538866801 * 10**9),
    ],
)
def test_parse_time(values, fmt, expected_ns):
    assert parse_time(values, fmt)[0] == expected_ns


def test_parse_time_bad_is_nat():
    t = parse_time(["garbage", "2018-10-06T23:00:00Z"], "iso8601")
    assert t[0] == np.iinfo(np.int64).min and t[1] > 0


def test_csv_reader_units_and_corrupt_rows(tmp_path):
    v = load_vehicle_config(default_vehicle_config_path())
    p = tmp_path / "ctd.csv"
    p.write_text("time,conductivity_mS_cm,temperature_ITS90,pressure_dbar\n"
                 "2018-10-06T23:00:00Z,32.5,2.5,100\n"
                 "2018-10-06T23:00:00.0625Z,abc,2.5,100\n"        # corrupt value
                 "not-a-time,32.5,2.5,100\n"                      # corrupt time
                 "2018-10-06T23:00:00.125Z,32.6,,100.1\n"         # empty = missing, kept
                 "2018-10-06T23:00:00.1875Z,32.6,2.5,100,extra\n"  # wrong field count
                 "2018-10-06T23:00:00.25Z,32.7,2.4,100.2\n")
    with pytest.warns(UserWarning, match="dropped 3 corrupt row"):
        s = read_sensor_csv(p, v.sensors["ctd"].csv, "ctd")
    assert len(s) == 3 and s.stats["corrupt_rows"] == 3
    np.testing.assert_allclose(s.values["conductivity_s_m"], [3.25, 3.26, 3.27])
    assert np.isnan(s.values["temperature_its90_degc"][1])
    assert s.conversions[0]["from"] == "mS/cm" and s.conversions[0]["to"] == "S/m"


def test_csv_reader_missing_column(tmp_path):
    v = load_vehicle_config(default_vehicle_config_path())
    p = tmp_path / "ctd.csv"
    p.write_text("time,temperature_ITS90,pressure_dbar\n2018-10-06T23:00:00Z,2.5,100\n")
    with pytest.raises(InputError, match="missing column.*conductivity_mS_cm"):
        read_sensor_csv(p, v.sensors["ctd"].csv, "ctd")


def test_clean_times_counts():
    t = np.array([0, 1, 2, 2, 5, 3, 4, 4], dtype=np.int64) * 10**9
    v = {"x": np.array([0, 1, 2, 2, 5, 3, 4, 4.0])}  # the repeated times hold identical rows: duplicates
    ts, vs, st = clean_times(t, v)
    assert (ts // 10**9).tolist() == [0, 1, 2, 3, 4, 5]
    assert vs["x"].tolist() == [0, 1, 2, 3, 4, 5]
    assert {k: st[k] for k in ("out_of_order", "duplicates")} == {"out_of_order": 3, "duplicates": 2}  # rows behind


def test_align_linear_gap_limit():
    t = np.array([0, 1, 2, 10, 11], dtype=np.int64) * 10**9
    v = np.array([0.0, 1.0, 2.0, 10.0, 11.0])
    base = np.array([-1, 0, 0.5, 1.5, 5, 10.5, 11, 12]) * 1e9
    out = align_linear(base.astype(np.int64), t, v, max_gap_s=2.0)
    np.testing.assert_allclose(out, [np.nan, 0.0, 0.5, 1.5, np.nan, 10.5, 11.0, np.nan])
    # a NaN sample is not bridged when the valid neighbours are too far apart
    v2 = v.copy()
    v2[1] = np.nan
    out2 = align_linear(np.array([1.0e9], dtype=np.int64), t, v2, max_gap_s=1.5)
    assert np.isnan(out2[0])
    assert align_linear(np.array([1.0e9], dtype=np.int64), t, v2, max_gap_s=2.0)[0] == pytest.approx(1.0)


def test_align_circular_heading():
    t = np.array([0, 1], dtype=np.int64) * 10**9
    out = align_linear(np.array([5 * 10**8], dtype=np.int64), t, np.array([350.0, 10.0]), 2.0, circular=True)
    assert out[0] == pytest.approx(0.0, abs=1e-9) or out[0] == pytest.approx(360.0)


def test_align_nearest_keeps_dropouts():
    t = np.array([0, 500, 1000, 1500], dtype=np.int64) * 10**6
    v = np.array([10.0, np.nan, 9.4, 9.1])
    base = np.array([100, 400, 900, 3000], dtype=np.int64) * 10**6
    out = align_nearest(base, t, v, max_gap_s=1.0)
    assert out[0] == 10.0 and np.isnan(out[1]) and out[2] == 9.4 and np.isnan(out[3])


def test_qc_saturation_and_missing():
    t = np.arange(200, dtype=np.int64) * 62_500_000
    p = np.linspace(10_480.0, 10_520.0, 200)
    p = np.minimum(p, 10_500.0)
    p[10] = np.nan
    f = qc_flags(p, t, DEFAULT_QC["pressure_ctd_dbar"])
    assert f[10] == 9
    assert np.all(f[p >= 10_500.0] == 4)
    assert np.all(f[(p < 10_499.0) & np.isfinite(p)][5:-5] == 1)


@pytest.mark.parametrize(
    "var,value,flag",
    [("conductivity_s_m", 3.2, 1), ("conductivity_s_m", 1.0, 3), ("conductivity_s_m", 32.0, 4),
     ("temperature_its90_degc", 45.0, 4), ("pitch_deg", 60.0, 3), ("heading_deg", 400.0, 4),
     ("speed_m_s", -1.0, 4)],
)
def test_qc_gross_range(var, value, flag):
    t = np.arange(20, dtype=np.int64) * 10**9
    x = np.full(20, value) + np.arange(20) * 1e-3  # not flat
    assert set(qc_flags(x, t, DEFAULT_QC[var])[2:-2]) == {flag}


def test_qc_spike_and_flat_line():
    t = np.arange(2000, dtype=np.int64) * 62_500_000
    x = 2.0 + np.sin(np.arange(2000) / 50.0) * 0.1
    x[500] += 5.0
    f = qc_flags(x, t, DEFAULT_QC["temperature_its90_degc"])
    assert f[500] == 4 and f[400] == 1
    stuck = np.full(2000, 2.0)  # 125 s constant at 16 Hz: suspect after 60 s
    g = qc_flags(stuck, t, DEFAULT_QC["temperature_its90_degc"])
    assert g[100] == 1 and g[-1] == 3
    assert qc_flags(x, t, VariableQC())[0] == 2  # no test configured: not evaluated


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_flat_line_matches_ioos_qc(seed):
    from ioos_qc import qartod

    from hadal.ingest.qc import flat_line_flags

    rng = np.random.default_rng(seed)
    x = np.round(rng.normal(0, 1, 400).cumsum(), 0) * 0.0  # mostly flat...
    x[rng.integers(0, 400, 60)] = rng.normal(0, 1, 60)     # ...with random breaks
    x[rng.integers(0, 400, 10)] = np.nan
    tinp = np.arange(x.size, dtype="int64").astype("datetime64[s]")
    for n_sus, n_fail in ((5, 12), (3, 3), (20, 40)):
        ref = np.ma.filled(qartod.flat_line_test(inp=x, tinp=tinp, suspect_threshold=n_sus,
                                                 fail_threshold=n_fail, tolerance=0.01), 9)
        np.testing.assert_array_equal(flat_line_flags(x, n_sus, n_fail, 0.01), ref)


def test_sensor_from_records_bad_values():
    from hadal.ingest import sensor_from_records

    v = load_vehicle_config(default_vehicle_config_path())
    msgs = [{"pressure": 1.0}, {"pressure": None}, {"pressure": "oops"}, {"pressure": 4}, {}]
    with pytest.warns(UserWarning, match=r"rejected 1 of 5 gauge sample\(s\).*pressure: 1 \(string 1\)"):
        s = sensor_from_records("gauge", np.arange(5, dtype=np.int64) * 10**9, msgs, v.sensors["gauge"].mcap,
                                "mcap:x")
    # the string sample is rejected (not coerced, not kept as NaN); null and a missing field are missing values
    assert s.time_ns.tolist() == [0, 10**9, 3 * 10**9, 4 * 10**9]
    np.testing.assert_array_equal(np.isnan(s.values["pressure_gauge_dbar"]), [False, True, False, True])
    assert s.stats["bad_values"] == 1 and s.stats["rejected_samples"] == 1
    assert s.stats["rejected_values"] == {"pressure": {"variable": "pressure_gauge_dbar", "count": 1,
                                                       "types": {"string": 1}}}
    with pytest.raises(InputError, match="has no field 'pressure'"):
        sensor_from_records("gauge", np.arange(2, dtype=np.int64), [{"p": 1.0}, {"p": 2.0}],
                            v.sensors["gauge"].mcap, "mcap:x")


def test_fix_streams_are_placed_at_their_nearest_base_sample_not_interpolated():
    """A USBL fix every 600 s on a 16 Hz base: each fix at exactly one base sample (the nearest, found here by
    brute force), NaN elsewhere; a fix beyond max_gap_s of every base sample is dropped."""
    from hadal.ingest.align import align_sensor

    base = (np.arange(0, 3000 * 16) * (1e9 / 16)).astype(np.int64)
    t = np.array([0.03e9, 600.01e9, 1200.5e9, 1800.97e9, 5000e9], np.int64)
    lat = np.array([11.1, 11.2, 11.3, 11.4, 11.5])
    out, _ = align_sensor(base, t, {"usbl_latitude_deg": lat, "usbl_east_variance_m2": lat * 10}, 900.0)
    a = out["usbl_latitude_deg"]
    near = [int(np.argmin(np.abs(base - ti))) for ti in t[:4]]
    assert np.flatnonzero(np.isfinite(a)).tolist() == near
    np.testing.assert_array_equal(a[near], lat[:4])
    assert np.isfinite(out["usbl_east_variance_m2"]).sum() == 4
