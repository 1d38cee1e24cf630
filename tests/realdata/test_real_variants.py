"""Held-back kinds (issue 43): variants of every dives-real kind as other users' files have them, generated here from
the real files by independent libraries (tests/real_variants.py: laspy, pypcd4, netCDF4, rasterio; SeaSoft and
dbd2asc text rewritten), read by their metadata. Oracles: the original file's own values through laspy/pypcd4/
netCDF4 (x, y, z; grid values and their units/positive), the .cnv's own columns (SeaSoft's channels), TEOS-10
(gsw) for the Slocum pressure, the header position for the thermosalinograph.
"""

from __future__ import annotations

import re
import shutil
import sys
import warnings
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

sys.path.insert(0, str(Path(__file__).parents[1]))
import real_variants as rv  # noqa: E402


@pytest.fixture(scope="module")
def shared(shared_data):
    if not (shared_data / "dives-real").is_dir():
        pytest.skip("dives-real not present")
    return shared_data


def _run(tmp_path: Path, files: list[Path], stages=None):
    from hadal.dive_init import scan_dive_dir, write_init
    from hadal.errors import StageError
    from hadal.pipeline import make_context, run_pipeline, run_stage

    raw = tmp_path / "dive"
    (raw / "raw").mkdir(parents=True)
    for f in files:
        shutil.copy(f, raw / "raw" / f.name)
    write_init(scan_dive_dir(raw))
    ctx = make_context(raw, tmp_path / "store")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        if stages:
            for st in stages:
                run_stage(st, ctx)
        else:
            try:
                run_pipeline(ctx)
            except StageError:
                pass
    return ctx


def _cnv_table(path: Path) -> pd.DataFrame:
    """The data block of a .cnv by its '# name i = short:' lines (independent of hadal's reader)."""
    text = path.read_bytes().decode("latin-1")
    head, _, body = text.partition("*END*")
    names = [m.group(1).strip() for m in re.finditer(r"# name \d+ = ([^:]+):", head)]
    rows = [ln.split() for ln in body.splitlines() if ln.strip()]
    return pd.DataFrame(np.array(rows, dtype=float), columns=names)


# ------------------------------------------------------------------ Sea-Bird casts
def test_cast_with_strain_gauge_names_reordered_no_nmea(shared, tmp_path):
    """prdM / tv290C / c0S/m (S/m) first, no NMEA position: the values are the original's prDM / t090C / c0mS/cm/10,
    and PSS-78 from them equals SeaSoft's own sal00 of the file."""
    p = rv.cnv_02dk_renamed(shared, tmp_path)
    orig = _cnv_table(shared / "ctd-real/oceissues644_02dk.cnv")
    ctx = _run(tmp_path, [p], ("ingest", "derive"))
    ctd = pd.read_parquet(ctx.store.latest(ctx.dive_id, "ctd").file("ctd.parquet"))
    np.testing.assert_allclose(ctd["pressure_ctd_dbar"], orig["prDM"], atol=1e-4)
    np.testing.assert_allclose(ctd["temperature_its90_degc"], orig["t090C"], atol=1e-4)
    np.testing.assert_allclose(ctd["conductivity_s_m"], orig["c0mS/cm"] / 10, rtol=1e-6)
    np.testing.assert_allclose(ctd["practical_salinity"], orig["sal00"], atol=2e-3)


def test_cast_conductivity_in_microsiemens(shared, tmp_path):
    p = rv.cnv_02dk_microsiemens(shared, tmp_path)
    orig = _cnv_table(shared / "ctd-real/oceissues644_02dk.cnv")
    ctx = _run(tmp_path, [p], ("ingest",))
    s = pd.read_parquet(ctx.store.latest(ctx.dive_id, "sensors").file("sensors.parquet"))
    np.testing.assert_allclose(s["conductivity_s_m"], orig["c0mS/cm"] / 10, rtol=1e-6)


def test_unbinned_sbe19_with_nmea_position(shared, tmp_path):
    """An unbinned 4 Hz cast, c0S/m, with an NMEA header position: the position is the cast's (latitude used)."""
    p = rv.cnv_sbe19_unbinned_nmea(shared, tmp_path)
    orig = _cnv_table(shared / "formats-real/sbs_SBE19plus_01906398_2019_07_15_0033_cropped.cnv")
    ctx = _run(tmp_path, [p], ("ingest", "derive"))
    s = pd.read_parquet(ctx.store.latest(ctx.dive_id, "sensors").file("sensors.parquet"))
    np.testing.assert_allclose(np.sort(s["pressure_ctd_dbar"].dropna()), np.sort(orig["prdM"]), atol=1e-4)
    np.testing.assert_allclose(np.sort(s["conductivity_s_m"].dropna()), np.sort(orig["c0mS/cm"] / 10), rtol=1e-6)
    from hadal.products.io import read_parquet_metadata

    meta = read_parquet_metadata(ctx.store.latest(ctx.dive_id, "ctd").file("ctd.parquet"))[0]
    assert "49.083" in str(meta)  # 49 05.00 N


def test_cast_with_eco_fluorometer_and_its68(shared, tmp_path):
    p = rv.cnv_sta0860_oxygen_fluor(shared, tmp_path)
    orig = _cnv_table(shared / "ctd-real/seabird_sta0860.cnv")
    ctx = _run(tmp_path, [p], ("ingest", "derive"))
    ctd = pd.read_parquet(ctx.store.latest(ctx.dive_id, "ctd").file("ctd.parquet"))
    np.testing.assert_allclose(ctd["temperature_its90_degc"], orig["t068C"] / 1.00024, atol=1e-4)  # T90 = T68/1.00024
    np.testing.assert_allclose(ctd["practical_salinity"], orig["sal00"], atol=2e-3)


def test_thermosalinograph_with_header_position_only_is_a_trajectory(shared, tmp_path):
    """The SBE 21 record without its latitude/longitude columns: underway (a TSG model at constant pressure), every
    scan at the header's NMEA position (00 51.788 S, 038 0.000 W); no cast, no profile."""
    p = rv.tsg_header_position_only(shared, tmp_path)
    ctx = _run(tmp_path, [p])
    prods = set(ctx.store.products(ctx.dive_id))
    assert "trajectory" in prods and "profile" not in prods
    import xarray as xr

    f = next(ctx.store.latest(ctx.dive_id, "trajectory").path.glob("*.nc"))
    ds = xr.open_dataset(f, engine="h5netcdf")
    assert ds.sizes["obs"] == 602
    np.testing.assert_allclose(ds["lat"].values, -(51.788 / 60), atol=1e-9)
    np.testing.assert_allclose(ds["lon"].values, -38.0, atol=1e-9)


# ------------------------------------------------------------------ Slocum
def test_slocum_without_pressure_channels_uses_m_depth(shared, tmp_path):
    """No sci_water_pressure / m_pressure / m_altitude, columns reversed: the gauge pressure is gsw.p_from_z of
    -m_depth at the log's latitude; derive runs."""
    import gsw

    p = rv.slocum_other_sensors(shared, tmp_path)
    ctx = _run(tmp_path, [p], ("ingest", "derive"))
    s = pd.read_parquet(ctx.store.latest(ctx.dive_id, "sensors").file("sensors.parquet"))
    lines = p.read_text().splitlines()
    names = lines[14].split()
    data = np.array([ln.split() for ln in lines[17:]], dtype=float)
    d = data[:, names.index("m_depth")]
    t = data[:, names.index("m_present_time")]
    lat = data[:, names.index("m_lat")]
    latd = np.sign(lat) * (np.floor(np.abs(lat) / 100) + (np.abs(lat) % 100) / 60)
    ok = np.isfinite(d)
    want = gsw.p_from_z(-d[ok], np.where(np.isfinite(latd[ok]), latd[ok], np.nanmedian(latd)))
    ts = pd.to_datetime(s["time"]).astype("int64").to_numpy() / 1e9
    got = s["pressure_gauge_dbar"].to_numpy()
    o = np.argsort(t[ok])
    exp = np.interp(ts, t[ok][o], want[o], left=np.nan, right=np.nan)  # the sensors table is on the CTD's times
    fin = np.isfinite(got) & np.isfinite(exp)
    assert fin.sum() > 10 and np.nanmax(got) > 5
    np.testing.assert_allclose(got[fin], exp[fin], atol=0.05)
    assert "ctd" in set(ctx.store.products(ctx.dive_id))


# ------------------------------------------------------------------ point clouds
@pytest.mark.parametrize("kw", [
    dict(version="1.4", point_format=6, scale=0.001, offset_shift=1000.0),
    dict(version="1.2", point_format=1, scale=0.01, offset_shift=-500.0),
    dict(version="1.4", point_format=7, scale=0.01, offset_shift=0.0, laz=True, feet=True),
    dict(version="1.2", point_format=3, scale=0.01, offset_shift=0.0, laz=True, feet=True),
])
def test_las_laz_variants_read_in_metres_in_their_crs(shared, tmp_path, kw):
    """Heights are elevations in metres whatever the version/format/scale/offset; a LAZ in international feet
    (EPSG:2994) gives the original metres (z * 0.3048) and its x/y in that CRS with metre axes."""
    import laspy
    from pyproj import CRS, Transformer

    from hadal.grid.clouds import read_las

    p = rv.las_variant(shared, tmp_path, **kw)
    ref = laspy.read(shared / "dives-real/pdal_autzen-utm.las")
    pts, meta = read_las(p)
    np.testing.assert_allclose(pts[:, 2], np.asarray(ref.z), atol=0.01 if kw.get("feet") else kw["scale"])
    if kw.get("feet"):
        src = laspy.read(p)
        to_m = Transformer.from_crs(CRS.from_epsg(2994), CRS.from_wkt(meta["xy_crs_wkt"]), always_xy=True)
        xm, ym = to_m.transform(np.asarray(src.x), np.asarray(src.y))
        np.testing.assert_allclose(pts[:, 0], xm, atol=0.01)
        np.testing.assert_allclose(pts[:, 1], ym, atol=0.01)
    else:
        np.testing.assert_allclose(pts[:, 0], np.asarray(ref.x), atol=kw["scale"])


@pytest.mark.parametrize("encoding,upper", [("ascii", False), ("binary", False), ("binary_compressed", True)])
def test_pcd_variants(shared, tmp_path, encoding, upper):
    from pypcd4 import PointCloud

    from hadal.grid.clouds import read_pcd

    p = rv.pcd_variant(shared, tmp_path, encoding=encoding, upper=upper)
    ref = PointCloud.from_path(shared / "dives-real/pdal_autzen-utm.pcd").numpy(("X", "Y", "Z"))
    pts, _meta = read_pcd(p)
    np.testing.assert_allclose(pts, ref, atol=1e-6 if encoding == "ascii" else 0)


# ------------------------------------------------------------------ grids
@pytest.mark.parametrize("positive,units,lon0", [("down", "m", 175.0), ("up", "km", 175.0), ("down", "km", 195.0)])
def test_netcdf_grid_positive_units_and_0_360(shared, tmp_path, positive, units, lon0):
    """The grid's own `positive` and `units` decide the depths (never the sign); longitudes in 0-360 crossing 180
    stay continuous; land (elevation > 0) has no depth."""
    import netCDF4

    from hadal.grid.prior import load_prior

    p = rv.nc_grid_variant(shared, tmp_path, positive=positive, units=units, lon0_360=lon0)
    with netCDF4.Dataset(shared / "dives-real/gmt_HI_topo_04.nc") as src:
        zname = next(v for v in src.variables if src.variables[v].ndim == 2)
        elev_m = np.asarray(src.variables[zname][:], float) * 1000.0
    g = load_prior(p)
    da = g.da
    lon = da["x"].values
    assert np.all(np.diff(lon) > 0) and lon.max() - lon.min() == pytest.approx(15.0, abs=1e-6)
    from hadal.grid.prior import depth_and_land

    depth, land = depth_and_land(da.values, g.z_positive)
    want = np.where(elev_m < 0, -elev_m, np.nan)
    flip = da["y"].values[0] > da["y"].values[-1]
    want = want[::-1] if flip else want
    ok = np.isfinite(want) & np.isfinite(depth)
    assert ok.sum() > 0.5 * np.isfinite(want).sum()
    np.testing.assert_allclose(depth[ok], want[ok], rtol=1e-5, atol=0.5)
    assert land.sum() == (elev_m > 0).sum()


def test_geotiff_in_a_projected_crs(shared, tmp_path):
    """A seafloor GeoTIFF in UTM 5N (rasterio): read in its CRS, depths = 2000 m - the Kilauea elevations."""
    import netCDF4

    from hadal.grid.prior import depth_and_land, load_prior

    p = rv.geotiff_projected(shared, tmp_path)
    with netCDF4.Dataset(shared / "dives-real/gmt_Kilauea.utm.nc") as src:
        z = np.ma.filled(np.ma.asarray(src.variables["z"][:], dtype=float), np.nan)
    g = load_prior(p)
    assert "32605" in str(g.da.attrs.get("crs_wkt", "")) + str(g.da.attrs.get("crs", "")) or g.da.attrs["crs_kind"] == "projected"
    depth, _land = depth_and_land(g.da.values, g.z_positive)
    want = 2000.0 - z
    if g.da["y"].values[0] > g.da["y"].values[-1]:
        want = want[::-1]
    ok = np.isfinite(want)
    np.testing.assert_allclose(np.sort(depth[np.isfinite(depth)]), np.sort(want[ok]), atol=1e-3)


def test_cast_with_depth_and_no_pressure_channel(shared, tmp_path):
    """SeaSoft depSM but no pressure channel: the pressure is depSM's Fofonoff-Millard formula inverted at the
    header latitude; it equals the original file's prDM (SeaSoft computed depSM from it)."""
    p = rv.cnv_rewrite(shared / "ctd-real/oceissues644_02dk.cnv", tmp_path / "depth_only.cnv", drop=("prDM",))
    orig = _cnv_table(shared / "ctd-real/oceissues644_02dk.cnv")
    ctx = _run(tmp_path, [p], ("ingest",))
    s = pd.read_parquet(ctx.store.latest(ctx.dive_id, "sensors").file("sensors.parquet"))
    np.testing.assert_allclose(s["pressure_ctd_dbar"], orig["prDM"], atol=0.01)


def test_cast_with_the_secondary_sensor_pair_only(shared, tmp_path):
    """A dual-CTD cast exported with its secondary pair only (t190C, c1S/m): read, and PSS-78 from them equals
    SeaSoft's own sal11."""
    src = shared / "ctd-real/seabird_dPIRX010.cnv"
    p = rv.cnv_rewrite(src, tmp_path / "t1_only.cnv", drop=("t090C", "c0S/m"))
    orig = _cnv_table(src)
    ctx = _run(tmp_path, [p], ("ingest", "derive"))
    ctd = pd.read_parquet(ctx.store.latest(ctx.dive_id, "ctd").file("ctd.parquet"))
    np.testing.assert_allclose(ctd["temperature_its90_degc"], orig["t190C"], atol=1e-4)
    np.testing.assert_allclose(ctd["conductivity_s_m"], orig["c1S/m"], rtol=1e-6)
    np.testing.assert_allclose(ctd["practical_salinity"], orig["sal11"], atol=2e-3)


def test_seaexplorer_with_a_legato_payload(shared, tmp_path):
    """An RBR Legato payload (conductivity in mS/cm): the conductivities are the original GPCTD_CONDUCTIVITY
    values in S/m (the file's own column, fill 9999 left out)."""
    nav, pld = rv.seaexplorer_legato(shared, tmp_path)
    ctx = _run(tmp_path, [nav, pld], ("ingest",))
    s = pd.read_parquet(ctx.store.latest(ctx.dive_id, "sensors").file("sensors.parquet"))
    orig = pd.read_csv(shared / "dives-real/pyglider_sea035.12.pld1.sub.36", sep=";")
    c = orig["GPCTD_CONDUCTIVITY"].to_numpy(float)
    c = c[np.isfinite(c) & (c != 9999.0)]
    got = s["conductivity_s_m"].to_numpy(float)
    got = got[np.isfinite(got)]
    assert got.size == c.size
    np.testing.assert_allclose(np.sort(got), np.sort(c), atol=1e-5)


@pytest.mark.parametrize("encoding", ["ascii", "binary"])
def test_pcd_version_06_without_viewpoint(shared, tmp_path, encoding):
    """A PCD v0.6 header (no VIEWPOINT line; PCL's older writer) around the same data: the same points, its own
    version recorded (pypcd4 alone refuses the VERSION)."""
    from pypcd4 import PointCloud

    from hadal.grid.clouds import read_pcd

    p = rv.pcd_variant(shared, tmp_path, encoding=encoding, upper=False)
    raw = p.read_bytes()
    i = raw.index(b"DATA")
    head = b"\n".join(ln for ln in raw[:i].split(b"\n") if not ln.startswith(b"VIEWPOINT"))
    head = head.replace(b"VERSION 0.7", b"VERSION .6").replace(b"VERSION .7", b"VERSION .6")
    p.write_bytes(head + raw[i:])
    assert b"VERSION .6" in p.read_bytes()[:200]
    ref = PointCloud.from_path(shared / "dives-real/pdal_autzen-utm.pcd").numpy(("X", "Y", "Z"))
    pts, meta = read_pcd(p)
    assert meta["pcd_version"] == ".6"
    np.testing.assert_allclose(pts, ref, atol=1e-6 if encoding == "ascii" else 0)


def test_las_feet_horizontal_metre_vertical_compound_crs(shared, tmp_path):
    """NAD83(HARN) / Oregon GIC Lambert (ft) + NAVD88 height (m), EPSG:2994+5703, written by laspy: x/y in feet,
    z in metres by the vertical CRS (not scaled by the horizontal foot)."""
    import laspy
    from pyproj import CRS, Transformer

    from hadal.grid.clouds import read_las

    src = laspy.read(shared / "dives-real/pdal_autzen-utm.las")
    x, y = Transformer.from_crs(src.header.parse_crs(), CRS.from_epsg(2994), always_xy=True).transform(
        np.asarray(src.x), np.asarray(src.y))
    hdr = laspy.LasHeader(version="1.4", point_format=6)
    hdr.scales = np.array([0.01, 0.01, 0.01])
    hdr.offsets = np.array([np.floor(x.min()), np.floor(y.min()), 0.0])
    hdr.add_crs(CRS.from_user_input("EPSG:2994+5703"))
    las = laspy.LasData(hdr)
    las.x, las.y, las.z = x, y, np.asarray(src.z)
    las.write(tmp_path / "ft_vm.las")
    pts, meta = read_las(tmp_path / "ft_vm.las")
    assert meta["horizontal_units"] == "foot" and meta["vertical_units"] == "metre"
    np.testing.assert_allclose(pts[:, 2], np.asarray(src.z), atol=0.006)


def test_glider_depth_is_pressure_only_when_no_log_has_pressure(shared, tmp_path):
    """The Slocum flight log without pressure beside its science log (sci_water_pressure): init maps the CTD
    pressure and leaves m_depth unread with the reason; alone, m_depth gives the gauge pressure."""
    from hadal.dive_init import scan_dive_dir

    flight = rv.slocum_other_sensors(shared, tmp_path)
    lines = (shared / "dives-real/gutils_usf_bass_2016_252_1_14_sbd.dat").read_text("latin-1").splitlines()
    names = lines[14].split()
    keep = [i for i, n in enumerate(names) if n.startswith("sci_")]
    head = [f"sensors_per_cycle: {len(keep)}" if ln.startswith("sensors_per_cycle") else ln for ln in lines[:14]]
    rows = [ln.split() for ln in lines[17:] if ln.strip()]
    rows = [r for r in rows if any(r[i] != "NaN" for i in keep)]
    sci = tmp_path / "usf_bass_tbd.dat"
    sci.write_text("\n".join(head + [" ".join(x.split()[i] for i in keep) for x in lines[14:17]]
                             + [" ".join(r[i] for i in keep) for r in rows]) + "\n")
    for files, want_depth in (([flight], True), ([flight, sci], False)):
        raw = tmp_path / f"d{len(files)}"
        (raw / "raw").mkdir(parents=True)
        for f in files:
            shutil.copy(f, raw / "raw" / f.name)
        res = scan_dive_dir(raw)
        text = str(res.vehicle) if hasattr(res, "vehicle") else str(res.__dict__)
        assert ("depth_ddmm_lat_to_pressure_dbar" in text) == want_depth
        if not want_depth:
            assert any("m_depth" in u and "another log" in u for u in res.not_used)
