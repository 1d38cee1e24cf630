"""Ship soundings in lon/lat xyz text (x = longitude in degrees, y = latitude, z depth or negative elevation), made
from the real EX1604 GSF soundings (NOAA Okeanos Explorer EM302) read by gsfpy/libgsf: `hadal init` detects lon/lat
and the z sign from the values and writes them into dive.yaml as explicit, commented hints; the DTM equals the one
made from the GSF itself (the oracle: the same soundings through libgsf), in -180..180 or 0..360 longitudes.
"""

from __future__ import annotations

import shutil

import numpy as np
import pytest
import xarray as xr
import yaml

GSF = "bathy-real/0029_20160323_185603_EX1604_MB.gsf.mb121"


@pytest.fixture(scope="module")
def gsf_soundings(shared_data):
    from hadal.grid.readers import read_gsf

    p = shared_data / GSF
    if not p.is_file():
        pytest.skip(f"{GSF} not present")
    df = read_gsf(p)
    return p, df[["longitude_deg", "latitude_deg", "depth_m"]].to_numpy(np.float64)


def _dtm(tmp_path, name, write, pipeline="grid: {dtm_resolution_m: 100}\n"):
    from hadal.dive_init import scan_dive_dir, write_init
    from hadal.pipeline import make_context, run_stage

    raw = tmp_path / name
    raw.mkdir()
    write(raw)
    res = scan_dive_dir(raw)
    write_init(res)
    (raw / "pipeline.yaml").write_text(pipeline)
    out = run_stage("dtm", make_context(raw, tmp_path / f"store-{name}"))["dtm"]
    with xr.open_dataset(out.file("dtm.nc"), engine="h5netcdf") as ds:
        return ds.load(), res, (raw / "dive.yaml").read_text()


@pytest.mark.parametrize("variant", ["depth", "elevation_0_360"])
def test_lonlat_xyz_soundings_grid_as_the_gsf_does(gsf_soundings, tmp_path, variant):
    gsf, s = gsf_soundings
    ref, _, _ = _dtm(tmp_path, "gsf", lambda raw: shutil.copy(gsf, raw / gsf.name))
    # 0..360: the survey moved 60 degrees east (227.5 E = -132.5): a transverse Mercator frame centred on the data
    # gives the same metres wherever the survey is, so the GSF's DTM stays the oracle
    lon = s[:, 0] + (60.0 if variant.endswith("0_360") else 0.0)
    assert variant == "depth" or lon.min() > 180
    z = -s[:, 2] if variant.startswith("elevation") else s[:, 2]
    sep = "," if variant.startswith("elevation") else " "

    def write(raw):
        np.savetxt(raw / "ship.xyz", np.column_stack([lon, s[:, 1], z]), fmt="%.9f", delimiter=sep)

    got, res, text = _dtm(tmp_path, "xyz", write)
    entry = yaml.safe_load(text)["sources"]["multibeam"][0]
    assert entry == {"path": "ship.xyz", "crs": "EPSG:4326",
                     "z_positive": "up" if variant.startswith("elevation") else "down"}
    assert "# guessed by hadal init, change if wrong: x/y taken as longitude/latitude" in text
    assert -180 <= yaml.safe_load(text)["map_frame"]["origin_longitude_deg"] < 180
    assert got.sizes == ref.sizes
    np.testing.assert_allclose(got["x"].values, ref["x"].values, atol=1e-6)
    np.testing.assert_allclose(got["y"].values, ref["y"].values, atol=1e-6)
    np.testing.assert_array_equal(got["count"].values, ref["count"].values)
    np.testing.assert_allclose(got["depth_m"].values, ref["depth_m"].values, atol=1e-6, equal_nan=True)
    dep = got["depth_m"].values
    assert s[:, 2].min() - 1 <= np.nanmin(dep) and np.nanmax(dep) <= s[:, 2].max() + 1  # depths, positive down


def test_declared_hints_are_kept_as_plain_paths(tmp_path):
    """A header naming the columns already says lon/lat and depth: nothing is guessed, the entry stays a path."""
    from hadal.dive_init import scan_dive_dir

    raw = tmp_path / "named"
    raw.mkdir()
    rows = "".join(f"{142 + i * 1e-3:.4f},{11 + j * 1e-3:.4f},{8000 + i + j}\n" for i in range(20) for j in range(20))
    (raw / "s.csv").write_text("lon,lat,depth\n" + rows)
    res = scan_dive_dir(raw)
    assert res.dive["sources"]["multibeam"] == ["s.csv"] and not res.source_notes
