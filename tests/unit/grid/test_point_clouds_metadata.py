"""LAS/LAZ and PCD point clouds read by their metadata (hadal.grid.clouds): CRS, feet -> metres, z up, PCD fields
in any case and any encoding. Oracles: laspy's own scaled coordinates, pyproj's transforms of the file's own CRS,
the arrays the test files were written from, and (real data) PDAL's autzen LAS/PCD pair of the same 1065 points.
"""

from __future__ import annotations

import numpy as np
import pytest
import xarray as xr
import yaml

from hadal.errors import InputError

AUTZEN_LAS = "dives-real/pdal_autzen-utm.las"
AUTZEN_PCD = "dives-real/pdal_autzen-utm.pcd"


def _shared(shared_data, rel):
    p = shared_data / rel
    if not p.is_file():
        pytest.skip(f"{rel} not present")
    return p


def _laspy_xyz(path):
    import laspy

    las = laspy.read(str(path))
    return np.column_stack([np.asarray(las.x), np.asarray(las.y), np.asarray(las.z)])


def test_real_las_in_its_own_crs_and_metres_z_up(shared_data):
    from hadal.grid.clouds import read_las

    p = _shared(shared_data, AUTZEN_LAS)
    pts, meta = read_las(p)
    ref = _laspy_xyz(p)
    np.testing.assert_array_equal(pts, ref)  # no sign flip, no scaling: the file is in metres
    assert len(pts) == 1065 and 123.9 <= pts[:, 2].min() < pts[:, 2].max() <= 178.8
    assert meta["crs_epsg"] == 26910 and meta["crs_kind"] == "projected" and meta["crs_from"] == "file"
    assert meta["horizontal_units"] == "metre" and meta["z_to_m"] == 1.0 and meta["z_positive"] == "up"


def test_real_pcd_upper_case_fields_binary(shared_data):
    """PDAL's writers.pcd: FIELDS X Y Z (F 8) + 13 LAS dimensions, binary: the LAS file's own points (laspy)."""
    from hadal.grid.clouds import read_pcd
    from hadal.grid.readers import read_point_cloud

    pcd = _shared(shared_data, AUTZEN_PCD)
    ref = _laspy_xyz(_shared(shared_data, AUTZEN_LAS))
    pts, meta = read_pcd(pcd)
    np.testing.assert_allclose(pts, ref, rtol=0, atol=1e-9)
    assert meta["pcd_data"] == "binary" and meta["fields"].startswith("X Y Z ") and meta["z_positive"] == "up"
    np.testing.assert_allclose(read_point_cloud(pcd), ref, rtol=0, atol=1e-9)  # by content, no format hint


def _pcd_header(fields, size, typ, n, data):
    return (f"# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS {' '.join(fields)}\n"
            f"SIZE {' '.join(map(str, size))}\nTYPE {' '.join(typ)}\nCOUNT {' '.join('1' * len(fields))}\n"
            f"WIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\nDATA {data}\n").encode()


@pytest.mark.parametrize("case", ["ascii", "binary_f4_extra", "binary_compressed"])
def test_pcd_encodings_and_field_cases(tmp_path, case):
    from hadal.grid.clouds import read_pcd

    rng = np.random.default_rng(4)
    xyz = np.column_stack([rng.uniform(0, 3, 200), rng.uniform(0, 2, 200), -1400 + rng.normal(0, 0.01, 200)])
    f = tmp_path / "c.pcd"
    if case == "ascii":  # written by hand: intensity first, then Z X Y in mixed case
        rows = "\n".join(f"{i} {z:.6f} {x:.6f} {y:.6f}" for i, (x, y, z) in enumerate(xyz))
        f.write_bytes(_pcd_header(["intensity", "Z", "x", "Y"], [4, 8, 8, 8], "UFFF", 200, "ascii") + rows.encode())
        want = np.round(xyz, 6)
    elif case == "binary_f4_extra":  # written by hand: float32 X Y Z and a uint8 label
        rec = np.zeros(200, dtype=[("X", "<f4"), ("Y", "<f4"), ("Z", "<f4"), ("label", "u1")])
        rec["X"], rec["Y"], rec["Z"], rec["label"] = xyz[:, 0], xyz[:, 1], xyz[:, 2], 7
        f.write_bytes(_pcd_header(["X", "Y", "Z", "label"], [4, 4, 4, 1], "FFFU", 200, "binary") + rec.tobytes())
        want = np.column_stack([rec["X"], rec["Y"], rec["Z"]]).astype(np.float64)
    else:  # LZF-compressed, by pypcd4's writer (the array is the oracle)
        from pypcd4 import Encoding, PointCloud

        PointCloud.from_xyz_points(xyz.astype(np.float32)).save(f, encoding=Encoding.BINARY_COMPRESSED)
        want = xyz.astype(np.float32).astype(np.float64)
    pts, meta = read_pcd(f)
    np.testing.assert_allclose(pts, want, rtol=0, atol=1e-6)
    assert meta["pcd_data"] == case.split("_f4")[0]


def test_pcd_without_xyz_or_truncated_is_one_line(tmp_path):
    from hadal.grid.clouds import read_pcd

    f = tmp_path / "a.pcd"
    f.write_bytes(_pcd_header(["u", "v", "w"], [4, 4, 4], "FFF", 2, "ascii") + b"1 2 3\n4 5 6\n")
    with pytest.raises(InputError, match="no x/y/z fields"):
        read_pcd(f)
    f.write_bytes(_pcd_header(["x", "y", "z"], [8, 8, 8], "FFF", 100, "binary") + b"\0" * 240)
    with pytest.raises(InputError, match="a.pcd") as ei:
        read_pcd(f)
    assert "\n" not in str(ei.value)


def _write_las(path, crs, xyz, *, version="1.2", point_format=3):
    import laspy
    from pyproj import CRS

    h = laspy.LasHeader(point_format=point_format, version=version)
    if crs:
        h.add_crs(CRS(crs))
    h.scales, h.offsets = [0.001] * 3, [float(np.floor(xyz[:, i].min())) for i in range(3)]
    las = laspy.LasData(h)
    las.x, las.y, las.z = xyz[:, 0], xyz[:, 1], xyz[:, 2]
    las.write(path)
    return _laspy_xyz(path)


@pytest.mark.parametrize("crs,version,pf,zf", [
    ("EPSG:2992", "1.2", 3, 0.3048),                      # NAD83 / Oregon Lambert (ft), GeoKeys: z in the same feet
    ("EPSG:6557+6360", "1.4", 6, 1200 / 3937),            # (ft) + NAVD88 height (ftUS), WKT VLR: z in US survey feet
    ("EPSG:32610", "1.4", 6, 1.0),                        # UTM 10N metres
])
def test_las_feet_become_metres_in_the_same_place(tmp_path, crs, version, pf, zf):
    from pyproj import CRS, Transformer

    from hadal.grid.clouds import read_las

    rng = np.random.default_rng(5)
    xyz = np.column_stack([1.2e6 + rng.uniform(0, 500, 400), 4.0e5 + rng.uniform(0, 500, 400),
                           100 + rng.uniform(0, 60, 400)])
    ref = _write_las(tmp_path / "ft.las", crs, xyz, version=version, point_format=pf)
    pts, meta = read_las(tmp_path / "ft.las")
    c = CRS(crs)
    horiz = c.sub_crs_list[0] if c.is_compound else c
    fxy = horiz.axis_info[0].unit_conversion_factor
    np.testing.assert_allclose(pts[:, :2], ref[:, :2] * fxy, rtol=1e-15)
    np.testing.assert_allclose(pts[:, 2], ref[:, 2] * zf, rtol=1e-12)
    # the grid's x/y CRS (source_crs_wkt) puts the metres where the file's feet are
    lon0, lat0 = Transformer.from_crs(horiz, 4326, always_xy=True).transform(ref[:, 0], ref[:, 1])
    lon1, lat1 = Transformer.from_crs(CRS.from_wkt(meta["xy_crs_wkt"]), 4326, always_xy=True).transform(
        pts[:, 0], pts[:, 1])
    assert np.abs(lon1 - lon0).max() < 1e-9 and np.abs(lat1 - lat0).max() < 1e-9
    assert meta["z_positive"] == "up"


def test_las_without_crs_is_metres_and_says_so(tmp_path):
    from hadal.grid.clouds import read_las

    xyz = np.column_stack([np.linspace(0, 2, 50), np.linspace(0, 1, 50), np.full(50, 12.5)])
    ref = _write_las(tmp_path / "n.las", None, xyz)
    pts, meta = read_las(tmp_path / "n.las")
    np.testing.assert_array_equal(pts, ref)
    assert meta["crs_kind"] == "none" and "assumed" in meta["horizontal_units"]


def _run_laser(tmp_path, files, sources, pipeline="grid: {laser_resolution_m: auto}\n"):
    import shutil

    from hadal.pipeline import make_context, run_stage

    raw = tmp_path / "raw"
    raw.mkdir(exist_ok=True)
    for f in files:
        shutil.copy(f, raw / f.name)
    (raw / "dive.yaml").write_text(yaml.safe_dump({"dive_id": "P001", "platform": "t", "sources": {"laser": sources}}))
    (raw / "pipeline.yaml").write_text(pipeline)
    lg = run_stage("laser", make_context(raw, tmp_path / "store"))["laser_grids"]
    return lg


def _open(lg, name):
    with xr.open_dataset(lg.file(name), engine="h5netcdf") as ds:
        return ds.load()


def _cell_means(pts, ds):
    """Per-cell mean of the points on the grid's own cells (numpy; the gridder is not used)."""
    r = float(ds.attrs["resolution"])
    x0, y0 = float(ds.attrs["grid_x0_edge"]), float(ds.attrs["grid_y0_edge"])
    ix = np.clip(np.floor((pts[:, 0] - x0) / r).astype(int), 0, ds.sizes["x"] - 1)
    iy = np.clip(np.floor((pts[:, 1] - y0) / r).astype(int), 0, ds.sizes["y"] - 1)
    k = iy * ds.sizes["x"] + ix
    n = np.bincount(k, minlength=ds.sizes["x"] * ds.sizes["y"])
    s = np.bincount(k, weights=pts[:, 2], minlength=n.size)
    with np.errstate(invalid="ignore"):
        return (s / n).reshape(ds.sizes["y"], ds.sizes["x"])


@pytest.mark.parametrize("rel", [AUTZEN_LAS, AUTZEN_PCD])
def test_real_cloud_laser_grid_is_elevation_in_its_crs(shared_data, tmp_path, rel):
    src = _shared(shared_data, rel)
    ref = _laspy_xyz(_shared(shared_data, AUTZEN_LAS))
    lg = _run_laser(tmp_path, [src], [src.name], "grid: {laser_resolution_m: auto, laser_sor_neighbors: 0}\n")
    ds = _open(lg, src.stem + ".nc")
    assert ds.attrs["z_sign_flipped"] == 0 and ds.attrs["z_positive_source"] == "up"
    e = ds["elevation_m"].values
    assert ref[:, 2].min() - 1e-9 <= np.nanmin(e) < np.nanmax(e) <= ref[:, 2].max() + 1e-9
    assert int(ds["count"].sum()) == 1065
    # stored as float32: within half the 1 mm precision schemas/variables.yaml declares (the LAS holds z in cm)
    np.testing.assert_allclose(e, _cell_means(ref, ds), rtol=0, atol=5e-4, equal_nan=True)
    x = ds["x"].values
    assert ref[:, 0].min() - ds.attrs["resolution"] <= x[0] and x[-1] <= ref[:, 0].max() + ds.attrs["resolution"]
    if rel == AUTZEN_LAS:
        assert ds.attrs["source_crs_epsg"] == 26910 and "UTM zone 10N" in ds.attrs["source_crs_wkt"]
        assert ds.attrs["source_horizontal_units"] == "metre"
    else:
        assert ds.attrs["source_pcd_data"] == "binary" and "source_crs_wkt" not in ds.attrs


def test_las_in_feet_through_the_laser_stage(tmp_path):
    rng = np.random.default_rng(6)
    n = 4000
    xyz = np.column_stack([1.2e6 + rng.uniform(0, 60, n), 4.0e5 + rng.uniform(0, 60, n),
                           300 + rng.normal(0, 0.05, n)])
    f = tmp_path / "feet.las"
    ref = _write_las(f, "EPSG:2992", xyz)
    lg = _run_laser(tmp_path, [f], ["feet.las"], "grid: {laser_resolution_m: 2.0, laser_sor_neighbors: 0}\n")
    ds = _open(lg, "feet.nc")
    assert ds.attrs["source_horizontal_units"] == "foot" and ds.attrs["source_z_scaled_by"] == 0.3048
    np.testing.assert_allclose(float(np.nanmean(ds["elevation_m"].where(ds["count"] > 0))),
                               np.mean(ref[:, 2]) * 0.3048, atol=0.05)
    assert abs(float(ds["x"].values[-1] - ds["x"].values[0]) - 60 * 0.3048) < 2 * 2.0
    assert "(axes in metres)" in ds.attrs["source_crs_wkt"]


def test_pcd_declaring_more_points_than_memory_or_file_is_refused(tmp_path):
    from hadal.grid.clouds import read_pcd

    f = tmp_path / "big.pcd"
    f.write_bytes(_pcd_header(["x", "y", "z"], [8, 8, 8], "FFF", 10**12, "binary_compressed") + b"\0" * 64)
    with pytest.raises(InputError, match="declares 1,000,000,000,000 points"):
        read_pcd(f)
    f.write_bytes(_pcd_header(["x", "y", "z"], [8, 8, 8], "FFF", 1000, "binary") + b"\0" * 240)
    with pytest.raises(InputError, match="holds at most 10 "):
        read_pcd(f)


def test_lonlat_las_is_gridded_in_the_dive_map_frame(tmp_path):
    """A LAS in EPSG:4326 (x = lon, y = lat): `hadal init` centres the map frame on it and the laser grid is in that
    transverse-Mercator frame (metres), its extent pyproj's projection of the file's lon/lat."""
    import laspy
    from pyproj import CRS, Transformer

    from hadal.dive_init import scan_dive_dir, write_init
    from hadal.pipeline import make_context, run_stage

    rng = np.random.default_rng(8)
    n = 3000
    lon, lat = 142.2 + rng.uniform(0, 4e-4, n), 11.33 + rng.uniform(0, 4e-4, n)
    h = laspy.LasHeader(point_format=6, version="1.4")
    h.add_crs(CRS("EPSG:4326"))
    h.scales, h.offsets = [1e-8, 1e-8, 0.001], [142.0, 11.0, 0.0]
    las = laspy.LasData(h)
    las.x, las.y, las.z = lon, lat, -10900 + rng.normal(0, 0.02, n)
    raw = tmp_path / "raw"
    raw.mkdir()
    las.write(raw / "geo.las")
    write_init(scan_dive_dir(raw))
    d = yaml.safe_load((raw / "dive.yaml").read_text())
    assert d["sources"]["laser"] == ["geo.las"] and abs(d["map_frame"]["origin_latitude_deg"] - 11.3302) < 1e-3
    (raw / "pipeline.yaml").write_text("grid: {laser_resolution_m: 2.0, laser_sor_neighbors: 0}\n")
    lg = run_stage("laser", make_context(raw, tmp_path / "store"))["laser_grids"]
    ds = _open(lg, "geo.nc")
    mf = d["map_frame"]
    tm = CRS.from_proj4(f"+proj=tmerc +lat_0={mf['origin_latitude_deg']} +lon_0={mf['origin_longitude_deg']} +k=1 "
                        "+x_0=0 +y_0=0 +datum=WGS84 +units=m +no_defs")
    x, y = Transformer.from_crs(4326, tm, always_xy=True).transform(np.asarray(las.x), np.asarray(las.y))
    r = ds.attrs["resolution"]
    assert abs(ds["x"].values[0] - x.min()) < r and abs(ds["x"].values[-1] - x.max()) < r
    assert abs(ds["y"].values[0] - y.min()) < r and abs(ds["y"].values[-1] - y.max()) < r
    assert ds.attrs["source_crs_kind"] == "geographic" and "map frame" in ds["x"].attrs["long_name"]
    assert -10901 < float(np.nanmean(ds["elevation_m"])) < -10899
    # georeferenced by that frame: a grid mapping and the ACDD extent of the cloud's own lon/lat (not the launch point)
    assert ds["elevation_m"].attrs.get("grid_mapping") == "crs" and ds["crs"].attrs["grid_mapping_name"] == \
        "transverse_mercator"
    assert "hadal_georeference" not in ds.attrs
    tol = 2 * r / 111_000  # two cells, in degrees
    assert abs(ds.attrs["geospatial_lon_min"] - lon.min()) < tol and abs(ds.attrs["geospatial_lon_max"] - lon.max()) < tol
    assert abs(ds.attrs["geospatial_lat_min"] - lat.min()) < tol and abs(ds.attrs["geospatial_lat_max"] - lat.max()) < tol
    import rasterio

    with rasterio.open(lg.file("geo.tif")) as cog:  # the COG in the same frame, cell for cell
        assert cog.crs is not None and cog.width == ds.sizes["x"] and cog.height == ds.sizes["y"]
        assert abs(cog.bounds.left - (float(ds["x"][0]) - r / 2)) < 1e-6


def test_laz_in_us_survey_feet(tmp_path):
    """LAZ (lazrs) with a compound CRS in US survey feet (NAD83(2011) / Oregon GIC Lambert (ft) + NAVD88 (ftUS)):
    metres by the CRS's own factors, not labelled metres as read."""
    pytest.importorskip("lazrs")
    from hadal.formats import detect
    from hadal.grid.readers import read_point_cloud_meta

    rng = np.random.default_rng(9)
    xyz = np.column_stack([1.2e6 + rng.uniform(0, 100, 300), 4.0e5 + rng.uniform(0, 100, 300), rng.uniform(50, 90, 300)])
    ref = _write_las(tmp_path / "c.laz", "EPSG:6557+6360", xyz, version="1.4", point_format=6)
    assert detect(tmp_path / "c.laz").kind == "las"
    pts, meta = read_point_cloud_meta(tmp_path / "c.laz")
    np.testing.assert_allclose(pts[:, :2], ref[:, :2] * 0.3048, rtol=1e-15)
    np.testing.assert_allclose(pts[:, 2], ref[:, 2] * 1200 / 3937, rtol=1e-12)
    assert meta["vertical_units"] == "US survey foot" and meta["z_positive"] == "up"
