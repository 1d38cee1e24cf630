"""Local frame round trips, geodesic distance and the paper's degree-minute notation."""

import numpy as np
import pytest

from hadal.geo import LocalFrame, format_degmin, format_position, geodesic_distance_m, parse_degmin


def test_local_frame_round_trip_and_scale():
    f = LocalFrame(11.33, 142.2)
    x, y = f.to_xy(142.2, 11.33)
    assert abs(x) < 1e-6 and abs(y) < 1e-6
    lon, lat = f.to_lonlat(np.array([5000.0, -12000.0]), np.array([3000.0, 8000.0]))
    x2, y2 = f.to_xy(lon, lat)
    np.testing.assert_allclose(x2, [5000.0, -12000.0], atol=1e-6)
    np.testing.assert_allclose(y2, [3000.0, 8000.0], atol=1e-6)
    # metres in the frame agree with geodesic distance to < 0.01 % within ~12 km of the origin
    d = geodesic_distance_m(142.2, 11.33, lon, lat)
    np.testing.assert_allclose(d, np.hypot([5000.0, -12000.0], [3000.0, 8000.0]), rtol=1e-4)


def test_paper_launch_to_start_distance():
    """TERCOM paper §4.2: launch 142°12.583'E 11°20.227'N, start 142°12.853'E 11°20.339'N, 533 m apart."""
    lon0, lat0 = parse_degmin("142°12.583'E"), parse_degmin("11°20.227'N")
    lon1, lat1 = parse_degmin("142°12.853'E"), parse_degmin("11°20.339'N")
    assert geodesic_distance_m(lon0, lat0, lon1, lat1) == pytest.approx(533, abs=3)


@pytest.mark.parametrize(
    "value,axis,text",
    [(142.2097167, "lon", "142°12.583'E"), (11.3371167, "lat", "11°20.227'N"), (-0.5, "lat", "0°30.000'S"),
     (-70.99999999, "lon", "71°00.000'W")],
)
def test_degmin_format(value, axis, text):
    assert format_degmin(value, axis) == text
    assert parse_degmin(text) == pytest.approx(value, abs=1e-5)


def test_format_position_order():
    assert format_position(11.3371167, 142.2097167) == "142°12.583'E, 11°20.227'N"


def test_parse_degmin_rejects_garbage():
    with pytest.raises(ValueError):
        parse_degmin("north-ish")
