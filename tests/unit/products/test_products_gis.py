"""GIS forms of the products (issue 46): GeoParquet 1.1 ``geo`` metadata and WKB points on tables with positions,
the navigation track as GeoJSON, the sample dive's COGs, GeoJSON, GeoParquet and STAC read by independent tools
(shapely's WKB, GeoPandas' GeoParquet reader, GDAL/OGR through pyogrio - what ``ogrinfo`` reports -, rasterio and
rio-cogeo, the STAC core schemas)."""

from __future__ import annotations

import json

import numpy as np
import pandas as pd
import pyarrow.parquet as pq
import pytest

from hadal.products import write_parquet
from hadal.products.geoparquet import navigation_track, wkb_points, write_navigation_track


def test_wkb_points_are_shapelys_wkb():
    shapely = pytest.importorskip("shapely")
    rng = np.random.default_rng(1)
    lon, lat = rng.uniform(-180, 180, 50), rng.uniform(-90, 90, 50)
    lon[[3, 7]] = np.nan
    lat[[7, 11]] = np.inf
    got = wkb_points(lon, lat).to_pylist()
    for i in range(50):
        if i in (3, 7, 11):
            assert got[i] is None
        else:
            assert got[i] == shapely.to_wkb(shapely.Point(lon[i], lat[i]), byte_order=1, output_dimension=2)
    assert wkb_points([], []).to_pylist() == []


def _nav(n=300):
    t = pd.date_range("2018-10-06T23:00:00", periods=n, freq="10s", tz="UTC")
    lon = 142.2 + np.linspace(0, 0.01, n)
    lat = 11.33 + 0.002 * np.sin(np.linspace(0, 3, n))
    lat[5] = np.nan
    return pd.DataFrame({"time": t, "lat": lat, "lon": lon, "depth_m": np.linspace(0, 10000, n),
                         "position_source": pd.Categorical(["dead_reckoned"] * (n - n // 3) + ["matched"] * (n // 3)),
                         "position_uncertainty_m": np.linspace(5, 50, n)})


def test_geoparquet_metadata_read_by_geopandas(tmp_path):
    gpd = pytest.importorskip("geopandas")
    nav = _nav()
    path = write_parquet(nav, tmp_path / "navigation.parquet")
    geo = json.loads(pq.read_schema(path).metadata[b"geo"])
    assert geo["version"] == "1.1.0" and geo["primary_column"] == "geometry"
    col = geo["columns"]["geometry"]
    assert col["encoding"] == "WKB" and col["geometry_types"] == ["Point"]
    assert col["bbox"] == pytest.approx([nav.lon.min(), nav.lat.min(), nav.lon.max(), nav.lat.max()])
    g = gpd.read_parquet(path)  # GeoPandas checks the geo metadata (version, encoding, PROJJSON crs)
    assert g.crs.equals("OGC:CRS84") and g.geometry.name == "geometry"
    ok = nav.lat.notna().to_numpy()
    assert g.geometry.isna().to_numpy().tolist() == (~ok).tolist()
    np.testing.assert_array_equal(g.geometry.x.to_numpy()[ok], nav.lon.to_numpy()[ok])
    np.testing.assert_array_equal(g.geometry.y.to_numpy()[ok], nav.lat.to_numpy()[ok])
    assert list(pd.read_parquet(path).columns) == [*nav.columns, "geometry"]


def test_table_without_positions_has_no_geo(tmp_path):
    path = write_parquet(pd.DataFrame({"depth_m": [1.0, 2.0]}), tmp_path / "t.parquet")
    assert b"geo" not in pq.read_schema(path).metadata
    assert pq.read_schema(path).names == ["depth_m"]


def test_navigation_track_geojson_listed_by_ogr(tmp_path):
    pyogrio = pytest.importorskip("pyogrio")
    nav = _nav()
    path = write_navigation_track(nav, tmp_path / "navigation_track.geojson", "dive-7")
    layers = pyogrio.list_layers(path)  # what `ogrinfo navigation_track.geojson` lists
    assert [str(n) for n in layers[:, 0]] == ["dive-7 track"] and layers[0, 1] == "LineString"
    info = pyogrio.read_info(path)
    assert info["features"] == 1 and info["crs"] == "EPSG:4326"
    ok = nav.lat.notna()
    assert info["total_bounds"] == pytest.approx([nav.lon[ok].min(), nav.lat[ok].min(), nav.lon[ok].max(),
                                                   nav.lat[ok].max()], abs=1e-7)
    gj = json.loads(path.read_text())
    coords = np.array(gj["features"][0]["geometry"]["coordinates"])
    np.testing.assert_allclose(coords, np.c_[nav.lon[ok], nav.lat[ok]], atol=1e-7)  # lon, lat (RFC 7946)
    p = gj["features"][0]["properties"]
    assert p["start_time"] == "2018-10-06T23:00:00Z" and p["position_sources"] == {"dead_reckoned": 200, "matched": 100}
    assert "crs" not in gj  # RFC 7946: WGS 84 lon/lat, no crs member
    # thinning keeps the ends
    thin = navigation_track(nav, "d")
    short = json.loads(json.dumps(thin))
    assert short["features"][0]["geometry"]["coordinates"][-1] == pytest.approx([nav.lon.iloc[-1], nav.lat.iloc[-1]])
    assert navigation_track(nav.iloc[:1], "d") is None


@pytest.mark.integration
def test_sample_dive_gis_products_read_by_independent_tools(small_run):
    """The small sample dive (the pipeline's own output): the DTM COG is the NetCDF's grid (elevation = -depth,
    extremes within 0.1 m; rio-cogeo validates it), the laser COG carries no vertical datum, the navigation track
    and landing footprints are listed by OGR, navigation.parquet is GeoParquet for GeoPandas, and the STAC catalog
    validates (core schemas, extension fields, checksums)."""
    rasterio = pytest.importorskip("rasterio")
    pyogrio = pytest.importorskip("pyogrio")
    gpd = pytest.importorskip("geopandas")
    import xarray as xr
    from pyproj import CRS
    from rio_cogeo.cogeo import cog_validate

    from hadal.products.stac import validate_store_catalog

    ctx, out = small_run
    dtm = out["dtm"]
    with xr.open_dataset(dtm.file("dtm.nc"), engine="h5netcdf") as ds:
        depth = ds["depth_m"].values
        nc_min, nc_max = float(np.nanmin(depth)), float(np.nanmax(depth))
        crs_wkt = ds["crs"].attrs["crs_wkt"]
    tif = dtm.file("dtm.tif")
    assert cog_validate(str(tif), quiet=True)[0]
    with rasterio.open(tif) as f:
        el = f.read(1, masked=True)
        assert f.descriptions[0].startswith("elevation") and f.tags(1)["positive"] == "up"
        assert [d.split(":")[0] for d in f.descriptions] == ["elevation", "uncertainty", "count"]
        assert CRS.from_wkt(f.crs.to_wkt()).equals(CRS.from_wkt(crs_wkt), ignore_axis_order=True)
        assert (f.height, f.width) == depth.shape
    assert abs(float(el.max()) - (-nc_min)) < 0.1 and abs(float(el.min()) - (-nc_max)) < 0.1
    for t in out["laser_grids"].path.glob("*.tif"):
        with rasterio.open(t) as f:
            assert not CRS.from_wkt(f.crs.to_wkt()).is_compound and "5829" not in f.crs.to_wkt()
    nav_pv = out["navigation"]
    layers = pyogrio.list_layers(nav_pv.file("navigation_track.geojson"))
    assert layers.shape[0] == 1 and layers[0, 1] == "LineString"
    g = gpd.read_parquet(nav_pv.file("navigation.parquet"))
    nav = pd.read_parquet(nav_pv.file("navigation.parquet"))
    np.testing.assert_array_equal(g.geometry.x.to_numpy(), nav["lon"].to_numpy())
    fp = out["landing"].path / "landing_footprints.geojson"
    if fp.is_file():
        assert pyogrio.read_info(fp)["crs"] == "EPSG:4326"
    assert validate_store_catalog(ctx.store.root, verify_checksums=True) == []
    item = json.loads((ctx.store.root / ctx.dive_id / "stac-item.json").read_text())
    assert item["assets"]["dtm/dtm.tif"]["raster:bands"][0]["statistics"]["minimum"] == pytest.approx(-nc_max, abs=0.1)
    assert item["assets"]["dtm/dtm_thumbnail.png"]["roles"] == ["thumbnail"]


def test_geometry_read_back_is_made_again_from_the_positions(tmp_path):
    """A table read from a product (with its geometry column) and written again with changed positions: the
    geometry follows the positions, not the old column."""
    shapely = pytest.importorskip("shapely")
    nav = _nav(10)
    df = pd.read_parquet(write_parquet(nav, tmp_path / "a.parquet"))
    df["lon"] = df["lon"] + 1.0
    path = write_parquet(df, tmp_path / "b.parquet")
    t = pq.read_table(path)
    assert t.column_names.count("geometry") == 1 and b"geo" in t.schema.metadata
    pts = shapely.from_wkb(t.column("geometry").to_pylist())
    ok = nav.lat.notna().to_numpy()
    np.testing.assert_array_equal(shapely.get_x(pts[ok]), df["lon"].to_numpy()[ok])
