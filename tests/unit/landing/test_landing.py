"""Landing-site analysis (Sangekar et al.) on synthetic grids with known answers."""

from __future__ import annotations

import math

import numpy as np
import pytest
import xarray as xr
from landing_reference import footprint_slope_reference_deg, small_protrusion_exclusion_reference
from scipy import ndimage as ndi

from hadal.errors import ConfigError, InputError
from hadal.landing import Vehicle, analyse_submap
from hadal.landing.exclusion import (
    HIGH_PROTRUSION,
    SLOPE,
    UNMAPPED,
    HeadingCorrelator,
    default_headings_deg,
    footprint_mask,
    footprint_offsets,
    small_protrusion_exclusion,
)
from hadal.landing.protrusion import butterworth_lowpass, protrusion_height_map
from hadal.landing.sites import largest_aspect_rectangle_m2, roughness_max_m
from hadal.landing.slope import local_slope_deg

V = Vehicle()


def plane(ny: int, nx: int, cell: float, slope_deg: float = 0.0, aspect_deg: float = 0.0) -> np.ndarray:
    """Elevation (m) of a plane rising at ``slope_deg`` towards compass direction ``aspect_deg``."""
    Y, X = np.mgrid[0:ny, 0:nx] * cell
    a = math.radians(aspect_deg)
    return math.tan(math.radians(slope_deg)) * (X * math.sin(a) + Y * math.cos(a))


def grid(z: np.ndarray, cell: float, **attrs) -> xr.DataArray:
    ny, nx = z.shape
    return xr.DataArray(z, dims=("y", "x"), coords={"y": np.arange(ny) * cell, "x": np.arange(nx) * cell},
                        attrs={"units": "m", **attrs})


# ----------------------------------------------------------------------------- vehicle (Eqs. 1-9)
def test_vehicle_table_ii_values():
    assert V.net_force_n == pytest.approx(3 * 9.81)
    assert V.critical_slope_deg == pytest.approx(17.70, abs=0.01)  # paper: 17.7°
    assert V.critical_height_m == pytest.approx(0.152, abs=0.001)  # paper: h_c = 0.15 m


def _tilt_moment_nm(v: Vehicle, tilt_rad: float, contact_m: float) -> float:
    """Net moment (N m) about the contact point P of gravity at C_G and buoyancy at C_B, the vehicle tilted by
    ``tilt_rad`` about P: statics with explicit rotated positions, no use of Eq. 1's closed form.
    Body frame: P at the skid plane, ``contact_m`` across from the C_G-C_B centre line; C_G ``d_g`` above the skid,
    C_B ``d_m`` above C_G. Positive: the vehicle keeps tilting; zero: the righting moment balances it."""
    c, s = math.cos(tilt_rad), math.sin(tilt_rad)
    moment = 0.0
    for height, force_up in ((v.cg_height_m, -v.force_gravity_n), (v.cg_height_m + v.cg_cb_distance_m, v.force_buoyancy_n)):
        u, w = -contact_m, height
        lever_x = c * u - s * w  # horizontal arm after the rotation
        moment += lever_x * force_up  # z-component of r x F for a vertical force
    return moment


@pytest.mark.parametrize("vehicle", [V, Vehicle(width_m=0.9, cg_cb_distance_m=0.08, cg_height_m=0.3, mass_kg=70.0)],
                         ids=["table-ii", "other"])
def test_critical_slope_is_the_moment_balance_on_the_long_edge(vehicle):
    """Eq. 2 against an independent oracle: the tilt at which the righting moment balances the net weight for
    contact on the long edge (d_psi = b_u/2), found numerically from the statics above."""
    from scipy.optimize import brentq

    d = 0.5 * vehicle.width_m
    assert _tilt_moment_nm(vehicle, 0.0, d) == pytest.approx(vehicle.net_force_n * d)  # upright: tips towards P
    root = brentq(lambda t: _tilt_moment_nm(vehicle, t, d), 0.0, math.pi / 2 - 1e-6, xtol=1e-14)
    assert vehicle.critical_slope_deg == pytest.approx(math.degrees(root), abs=1e-9)
    # just below θc the vehicle still tilts on to the slope; just above, the righting moment holds it off
    th = math.radians(vehicle.critical_slope_deg)
    assert _tilt_moment_nm(vehicle, th - 1e-3, d) > 0 > _tilt_moment_nm(vehicle, th + 1e-3, d)
    # Eq. 1 / Eq. 7 at other contact distances: the same balance, and the allowed tilt grows with d
    for frac in (0.1, 0.5, 0.9):
        r = brentq(lambda t, dd=frac * d: _tilt_moment_nm(vehicle, t, dd), 0.0, math.pi / 2 - 1e-6, xtol=1e-14)
        assert float(vehicle.tilt_angle_rad(frac * d)) == pytest.approx(r, abs=1e-9) and r < root


def test_vehicle_current_and_friction():
    # Eqs. 5-6 at θ = 0, μ = 0.5: F_C = 14.715 N, v_c = sqrt(2 F_C / (1.2 * 1025 * 1.7 * 0.4))
    assert V.admissible_current_m_s(0.0, 0.5) == pytest.approx(math.sqrt(2 * 14.715 / (1.2 * 1025 * 0.68)), rel=1e-6)
    # friction equal to tan θ: no current admissible; lower friction also 0 (slides)
    assert V.admissible_current_m_s(17.7, math.tan(math.radians(17.7))) == pytest.approx(0.0, abs=1e-6)
    assert V.admissible_current_m_s(30.0, 0.3) == 0.0
    v = V.admissible_current_m_s(np.array([0.0, 10.0, 17.7]), 0.6)
    assert np.all(np.diff(v) < 0)  # steeper -> less current allowed (Fig. 10)


def test_vehicle_protrusion_table():
    d, h = V.exclusion_table(0.005)
    assert d[0] == 0 and h[0] == 0
    assert d[-1] == pytest.approx(0.25) and h[-1] == pytest.approx(V.critical_height_m)  # Eq. 8 -> Eq. 9
    assert np.all(np.diff(h) > 0)
    dist = V.exclusion_distance_m(np.array([0.004, 0.05, 0.15, 0.16]))
    assert dist[0] == pytest.approx(0.015)  # rounded up to the 5 mm table
    assert 0.0 < dist[1] < dist[2] <= 0.25
    assert np.isnan(dist[3])  # h > h_c: handled by the footprint dilation
    # conservative: the tabulated distance always allows at least the height asked for
    assert np.all(V.protrusion_height_limit_m(dist[:3]) >= np.array([0.004, 0.05, 0.15]) - 1e-12)


def test_vehicle_rejects_positive_buoyancy(tmp_path):
    with pytest.raises(ValueError, match="negative buoyancy"):  # pydantic's ValidationError is a ValueError
        Vehicle(mass_kg=60.0, buoyancy_mass_kg=62.0)
    with pytest.raises(ValueError, match="no righting moment"):
        Vehicle(cg_height_m=2.0)
    from hadal.settings import load_config

    cfg = tmp_path / "pipeline.yaml"  # from YAML: one clean line naming the setting
    cfg.write_text("landing:\n  vehicle:\n    mass_kg: 60\n    buoyancy_mass_kg: 62\n")
    with pytest.raises(ConfigError, match=r"^invalid configuration at landing.vehicle: vehicle mass 60.0 kg must exceed"):
        load_config(cfg)


def test_headings_and_footprint():
    h = default_headings_deg()
    assert h.size == 37 and h[0] == -90 and h[-1] == 90
    rr, cc = footprint_offsets(1.7, 0.5, 0.0, 0.01)
    assert rr.size == 171 * 51  # cells with centres inside the rectangle, heading 0 = along +y (rows)
    assert np.ptp(rr) == 170 and np.ptp(cc) == 50
    m = footprint_mask(1.7, 0.5, 90.0, 0.01)
    assert m.sum() == 171 * 51 and np.array_equal(m, m[::-1, ::-1])
    m = footprint_mask(1.7, 0.5, 35.0, 0.01)
    assert np.array_equal(m, m[::-1, ::-1])  # point-symmetric
    assert m.sum() * 1e-4 == pytest.approx(0.85, rel=0.02)


# ----------------------------------------------------------------------------- slope maps
def test_local_slope_of_plane_with_gaps():
    z = plane(60, 80, 0.01, 12.0, 70.0)
    z[20:25, 30:40] = np.nan
    s = local_slope_deg(z, 0.01, 3)
    assert np.nanmax(np.abs(s - 12.0)) < 1e-6
    assert np.isnan(s[22, 35])
    assert np.isfinite(s[0, 1]) and np.isnan(s[0, 0])  # edge window: 6 of 9 cells; corner: 4 < half


def test_footprint_slope_matches_lstsq_reference():
    rng = np.random.default_rng(3)
    cell = 0.05
    z = plane(90, 70, cell, 14.0, -30.0) + 0.02 * rng.standard_normal((90, 70))
    z = ndi.gaussian_filter(z, 1.0)
    hc = HeadingCorrelator(z, cell, V, np.zeros(z.shape, bool))
    for heading in (0.0, 35.0, -70.0):
        hm = hc.compute(heading, need_slope=True)
        ok = np.argwhere(~hm.unmapped)
        assert len(ok) > 50
        pick = ok[rng.choice(len(ok), 15, replace=False)]
        ref = footprint_slope_reference_deg(z, cell, footprint_mask(V.length_m, V.width_m, heading, cell), pick)
        got = hm.slope_deg[pick[:, 0], pick[:, 1]]
        assert np.max(np.abs(got - ref)) < 0.05
        assert abs(np.nanmedian(hm.slope_deg) - 14.0) < 0.5


def test_erosion_and_dilation_match_scipy_morphology():
    rng = np.random.default_rng(5)
    cell = 0.05
    z = plane(80, 60, cell, 5.0)
    z[rng.random(z.shape) < 0.003] = np.nan
    z[:6, :] = np.nan
    high = rng.random(z.shape) < 0.002
    hc = HeadingCorrelator(z, cell, V, high)
    for heading in (0.0, 25.0, 90.0, -55.0):
        se = footprint_mask(V.length_m, V.width_m, heading, cell)
        hm = hc.compute(heading)
        can_enter = ndi.binary_erosion(np.isfinite(z), se, border_value=0)
        assert np.array_equal(~hm.unmapped, can_enter)
        assert np.array_equal(hm.high, ndi.binary_dilation(high, se))


def test_small_protrusion_exclusion_exact():
    rng = np.random.default_rng(7)
    r = np.full((50, 60), np.nan)
    idx = rng.choice(r.size, 12, replace=False)
    r.flat[idx] = rng.uniform(0.0, 9.0, 12)
    assert np.array_equal(small_protrusion_exclusion(r), small_protrusion_exclusion_reference(r))
    assert not small_protrusion_exclusion(np.full((5, 5), np.nan)).any()


# ----------------------------------------------------------------------------- protrusions (Eq. 10)
def test_butterworth_minus_3db_at_cutoff():
    H = butterworth_lowpass((256, 256), 16 / 256, 3)
    assert H[0, 0] == 1.0
    assert H[0, 16] == pytest.approx(1 / math.sqrt(2), abs=1e-12)  # f = f_c: -3 dB
    assert H[16, 0] == pytest.approx(1 / math.sqrt(2), abs=1e-12)  # rotationally symmetric
    assert H[0, 32] == pytest.approx(1 / math.sqrt(1 + 2**6), abs=1e-12)  # 3rd order: (f/f_c)^6
    assert H[128, 128] < 1e-3


@pytest.mark.parametrize("height", [0.05, 0.12])
def test_rock_height_detected(height):
    cell = 0.01
    z = plane(300, 300, cell, 10.0, 40.0)
    Y, X = np.mgrid[0:300, 0:300] * cell
    rock = (X - 1.5) ** 2 + (Y - 1.4) ** 2 <= 0.08**2
    n = np.array([-math.sin(math.radians(10)) * math.sin(math.radians(40)),
                  -math.sin(math.radians(10)) * math.cos(math.radians(40)), math.cos(math.radians(10))])
    z = z + np.where(rock, height / n[2], 0.0)  # a cylinder of `height` along the plane normal
    h = protrusion_height_map(z, cell, V.diagonal_m)
    assert np.nanmax(h[rock]) == pytest.approx(height, rel=0.15)
    far = (X - 1.5) ** 2 + (Y - 1.4) ** 2 > 0.6**2
    assert np.nanmax(np.abs(h[far])) < 0.01 * height / 0.05


def test_protrusion_map_keeps_gaps_and_blocks_seamless():
    cell = 0.01
    z = plane(600, 120, cell, 8.0, 10.0)
    z[300:320, 40:60] = np.nan
    h = protrusion_height_map(z, cell, V.diagonal_m, block_m=1.0, margin_m=0.5)
    assert np.isnan(h[310, 50]) and np.isfinite(h[100, 50])
    assert np.nanmax(np.abs(h)) < 0.01  # a plane has no protrusions, no seams at block edges


# ----------------------------------------------------------------------------- sites and costs
def test_flat_area_site_at_centre_and_heading_dependence():
    cell = 0.01
    z = np.full((300, 160), np.nan)
    z[30:270, 20:140] = 0.0  # mapped: 2.4 m (y) x 1.2 m (x), flat
    res = analyse_submap(grid(z, cell), headings_deg=[0.0, 45.0, 90.0])
    s = res.sites
    assert set(s["heading_deg"]) == {0.0}  # the 1.7 m vehicle does not fit across 1.2 m
    assert len(s) == 1
    site = s.iloc[0]
    assert site["x_m"] == pytest.approx(0.795, abs=0.011)  # centre of the mapped rectangle
    assert site["y_m"] == pytest.approx(1.495, abs=0.011)
    # C_G region (0.7 m x 0.7 m square) -> inscribed circle radius ~0.35 m
    assert site["radius_m"] == pytest.approx(0.35, abs=0.015)
    assert site["p_s"] == pytest.approx(0.0, abs=1e-3) and site["p_r"] == pytest.approx(0.0, abs=1e-6)
    assert site["p_f"] == 1.0  # A_r << A_f
    assert site["c_s"] == pytest.approx(1 / 3, abs=1e-3)
    assert res.best["heading_deg"] == 0.0
    assert res.best_site_mask[150, 80] and not res.best_site_mask[35, 80]
    k90 = list(res.headings_deg).index(90.0)
    assert ((res.exclusion[k90] & UNMAPPED) != 0).all()


def test_slope_threshold_and_cost():
    cell = 0.02
    for slope, expect_site in ((10.0, True), (25.0, False)):
        z = plane(150, 100, cell, slope, 0.0)
        res = analyse_submap(grid(z, cell), headings_deg=[0.0, 90.0])
        assert (len(res.sites) > 0) is expect_site
        if expect_site:
            assert res.sites["slope_deg"].to_numpy() == pytest.approx(slope, abs=0.05)
            assert res.sites["p_s"].to_numpy() == pytest.approx(slope / V.critical_slope_deg, abs=0.005)
        else:
            inner = ~((res.exclusion[0] & UNMAPPED) != 0)
            assert ((res.exclusion[0][inner] & SLOPE) != 0).all()


def test_high_rock_shifts_landing_point():
    cell = 0.01
    z = np.zeros((400, 120))
    base = analyse_submap(grid(z, cell), headings_deg=[0.0])
    assert len(base.sites) == 1 and base.best["y_m"] == pytest.approx(1.995, abs=0.02)
    Y, X = np.mgrid[0:400, 0:120] * cell
    rock = (np.abs(X - 0.6) <= 0.05) & (np.abs(Y - 3.5) <= 0.05)
    z2 = np.where(rock, 0.25, 0.0)  # 25 cm > h_c: no part of the vehicle may touch it
    res = analyse_submap(grid(z2, cell), headings_deg=[0.0, 90.0])
    assert res.high_protrusion[rock].any()
    assert np.nanmax(res.protrusion_height_m[rock]) == pytest.approx(0.25, rel=0.15)
    ex0 = res.exclusion[0]
    # C_G may not come within half a vehicle length (+ rock half size) of the rock along the heading
    assert ((ex0[int(2.65 / cell) :, 60] & HIGH_PROTRUSION) != 0).all()
    assert len(res.sites) == 1 and res.best["heading_deg"] == 0.0
    assert res.best["y_m"] < 1.9  # pushed away from the rock
    assert res.best["y_m"] + 0.85 < 3.45  # the footprint stays clear of it


def test_small_protrusion_makes_disc_exclusion():
    cell = 0.01
    z = np.zeros((400, 120))
    Y, X = np.mgrid[0:400, 0:120] * cell
    bump = (X - 0.6) ** 2 + (Y - 2.0) ** 2 <= 0.03**2
    z = np.where(bump, 0.06, z)  # 6 cm < h_c
    res = analyse_submap(grid(z, cell), headings_deg=[0.0])
    assert not res.high_protrusion.any()
    assert res.small_exclusion[200, 60]
    r_expect = float(V.exclusion_distance_m(np.nanmax(res.protrusion_height_m[bump])))
    # the exclusion reaches ~d(h) beyond the rock's steep rim, and no further than d(h_c) = b/2
    assert res.small_exclusion[200, 60 + int((0.03 + r_expect) / cell) - 2]
    assert not res.small_exclusion[200, 60 + int((0.03 + 0.25) / cell) + 3]
    assert len(res.sites) >= 1


def test_rectangle_and_rmax():
    cell = 0.01
    m = np.zeros((300, 300), bool)
    m[50:250, 100:160] = True  # 2.0 m (y) x 0.6 m (x)
    a0 = largest_aspect_rectangle_m2(m, cell, 0.0, 1.7, 0.5, 0.01)
    assert a0 == pytest.approx(0.6 * 0.6 * 3.4, rel=0.08)  # width-limited: 0.6 x 2.04 m
    a90 = largest_aspect_rectangle_m2(m, cell, 90.0, 1.7, 0.5, 0.01)
    assert a90 == pytest.approx(0.6 * 0.6 / 3.4, rel=0.12)  # length-limited across the strip
    rm = roughness_max_m(V, 0.01)
    assert 0.01 < rm < 0.06


def test_input_errors():
    with pytest.raises(InputError):
        analyse_submap(grid(np.full((20, 20), np.nan), 0.01))
    with pytest.raises(InputError):
        analyse_submap(xr.DataArray(np.zeros((20, 20)), dims=("a", "b")))
    with pytest.raises(InputError):
        analyse_submap(grid(np.zeros((20, 20)), 0.01, units="mm"))
    with pytest.raises(InputError):
        analyse_submap(np.zeros((20, 20)))  # type: ignore[arg-type]
    g = grid(np.zeros((20, 30)), 0.01)
    g = g.assign_coords(x=np.arange(30) * 0.02)
    with pytest.raises(InputError):
        analyse_submap(g)


def test_depth_positive_down_and_descending_y():
    cell = 0.02
    z = plane(120, 80, cell, 6.0, 0.0)
    g = grid(-z, cell, positive="down").isel(y=slice(None, None, -1))
    res = analyse_submap(g, headings_deg=[0.0])
    assert res.y_m[0] < res.y_m[-1]
    assert len(res.sites) == 1
    assert res.sites["slope_deg"].iloc[0] == pytest.approx(6.0, abs=0.05)
    ds = res.to_dataset()
    assert set(ds.data_vars) >= {"slope_local_deg", "protrusion_height_m", "exclusion", "final_site"}
    assert ds["exclusion"].shape == (1, 120, 80)


def test_parallel_headings_same_result():
    rng = np.random.default_rng(11)
    cell = 0.02
    z = plane(200, 80, cell, 8.0, 20.0) + ndi.gaussian_filter(rng.standard_normal((200, 80)), 3) * 0.05
    hs = [-20.0, -10.0, 0.0, 10.0, 20.0]
    a = analyse_submap(grid(z, cell), headings_deg=hs, workers=1)
    b = analyse_submap(grid(z, cell), headings_deg=hs, workers=2)
    assert np.array_equal(a.exclusion, b.exclusion)
    assert a.sites.equals(b.sites)
    # the best heading's maps kept by whichever thread found it: the same best site, mask and footprint slope
    assert a.best == b.best and a.best is not None
    assert np.array_equal(a.best_site_mask, b.best_site_mask) and a.best_site_mask.any()
    assert np.array_equal(a.footprint_slope_deg, b.footprint_slope_deg, equal_nan=True)
    c = analyse_submap(grid(z, cell), headings_deg=[-90.0, 90.0])
    assert np.array_equal(c.exclusion[0], c.exclusion[1])  # α and α+180° are the same footprint


def test_isolated_empty_cells_are_filled_but_large_gaps_are_not():
    cell = 0.02
    z = plane(250, 60, cell, 5.0)
    rng = np.random.default_rng(2)
    holes = rng.random(z.shape) < 0.01  # scattered empty cells of a resampled point cloud
    holes[:, :2] = holes[:, -2:] = False
    z[holes] = np.nan
    z[60:75, 25:40] = np.nan  # a 0.3 m x 0.3 m gap stays unmapped
    res = analyse_submap(grid(z, cell), headings_deg=[0.0])
    assert res.filled[holes & ~np.isnan(res.elevation_m)].all()
    assert not res.filled[60:75, 25:40].any() and np.isnan(res.elevation_m[67, 32])
    assert len(res.sites) >= 1
    strict = analyse_submap(grid(z, cell), headings_deg=[0.0], fill_holes_max_m2=0.0)
    assert len(strict.sites) == 0  # every footprint would cover an empty cell
