"""Real files of the kinds in issue #43, round 2 (tests/data/real/README.md: provenance and licences).

Each test reads a real file another tool or instrument wrote and checks the content against an independent oracle
(laspy's own scaled coordinates with pyproj's transform of the file's own CRS, the file's header text, ...).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

REAL = Path(__file__).parent / "data" / "real"


def _real(name: str) -> Path:
    p = REAL / name
    if not p.is_file():
        pytest.skip(f"{name} not vendored")
    return p


def test_las_in_us_survey_feet_with_towgs84_stays_georeferenced():
    """laspy's test1_4.las: a WKT1 PROJCS with TOWGS84 (a pyproj BoundCRS) in US survey feet. The cloud is scaled
    to metres, and the CRS it is returned in must put those metres where the file's own CRS puts its feet
    (before: the metre axes were applied only to plain projected CRSs, so the grid was 400 km off)."""
    import laspy
    from pyproj import CRS, Transformer

    from hadal.grid.clouds import read_las

    p = _real("laspy_test1_4_nm_ftus.las")
    pts, meta = read_las(p)
    las = laspy.read(str(p))
    file_crs = las.header.parse_crs()
    assert meta["crs_kind"] == "projected" and meta["horizontal_units"] == "US survey foot"
    ftus = 1200 / 3937
    np.testing.assert_allclose(pts[:, 2], np.asarray(las.z) * ftus, rtol=1e-12)
    assert pts[:, 2].min() > 0  # elevation, up: not negated
    xy_crs = CRS.from_wkt(meta["xy_crs_wkt"])
    assert {ax.unit_name for ax in xy_crs.axis_info} == {"metre"}
    got = Transformer.from_crs(xy_crs, "EPSG:4326", always_xy=True).transform(pts[:, 0], pts[:, 1])
    ref = Transformer.from_crs(file_crs, "EPSG:4326", always_xy=True).transform(np.asarray(las.x), np.asarray(las.y))
    np.testing.assert_allclose(got, ref, rtol=0, atol=1e-9)  # degrees: well under a millimetre
    assert 35.99 < ref[1].min() and ref[0].max() < -106.0  # New Mexico, as the CRS says


def test_cnv_latitude_from_seasoft_channel_note_when_the_header_has_none(tmp_path):
    """castelao/seabird Hotin.cnv (SBE 19plus): no NMEA/user position, but SeaSoft wrote the latitude it used into
    the depth channel's name ('depSM: Depth [salt water, m], lat = 48.38'). That latitude is the cast's (before:
    45°). Oracle: SeaSoft's own depSM column, which UNESCO 44 reproduces at 48.38° and not at 45°."""
    import shutil

    from hadal.dive_init import scan_dive_dir
    from hadal.ingest.cnv import read_cnv
    from hadal.seawater import depth_fofonoff_millard

    p = _real("seabird_Hotin_sbe19plus.cnv")
    df = read_cnv(p)
    assert df.attrs["latitude_deg"] == pytest.approx(48.38)
    assert df.attrs["longitude_deg"] is None
    assert "depSM" in df.attrs["position_source"]["latitude"]
    pres, dep = df["prdM"].to_numpy(), df["depSM"].to_numpy()
    np.testing.assert_allclose(depth_fofonoff_millard(pres, df.attrs["latitude_deg"]), dep, rtol=0, atol=1.5e-3)
    assert np.abs(depth_fofonoff_millard(pres, 45.0) - dep).max() > 2e-3
    shutil.copy(p, tmp_path / p.name)
    res = scan_dive_dir(tmp_path)
    assert res.dive["sources"]["cnv"] == [p.name]
    assert not [t for t in res.todo if "latitude" in t]  # the cast carries its latitude: nothing to ask
