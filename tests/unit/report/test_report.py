"""Dive report: works with whichever products exist, says what is missing, fails clearly with none."""

from __future__ import annotations

import base64
import io
import json
import math
import re
import shutil
from html import escape as html_escape

import numpy as np
import pandas as pd
import pytest
from factories import ALL_FAKE, fake_ctd, publish_fake_products, write_fake_dive

from hadal.errors import StageError
from hadal.pipeline import make_context, run_stage
from hadal.products import write_parquet
from hadal.report import FigureOptions, build_report, load_products, publish_report
from hadal.settings import PipelineConfig
from hadal.store import ProductStore

FAST = FigureOptions(dpi=40, width_in=6, max_points=500, keep_figure=True)  # keep_figure: the artists are tested


@pytest.fixture(scope="module")
def full_store(tmp_path_factory):
    root = tmp_path_factory.mktemp("report") / "store"
    publish_fake_products(ProductStore(root), "dive-a", ALL_FAKE)
    return root


@pytest.fixture(scope="module")
def full_report(full_store):
    return build_report(ProductStore(full_store), "dive-a", options=FAST)


def _pngs(html: str) -> list[bytes]:
    return [base64.b64decode(b) for b in re.findall(r"data:image/png;base64,([A-Za-z0-9+/=]+)", html)]


def _image(png: bytes) -> np.ndarray:
    """Decoded RGB(A) pixels (floats in [0, 1]) of a PNG."""
    from matplotlib.image import imread

    return imread(io.BytesIO(png), format="png")


def assert_drawn(fr, opt: FigureOptions = FAST) -> np.ndarray:
    """The figure's PNG decodes to a non-blank image of about the figure's size at ``opt.dpi`` (``bbox_inches=
    "tight"`` crops to the drawn content, or grows where a label or colour bar pokes out); returns the pixels."""
    assert fr.png is not None and fr.png.startswith(b"\x89PNG\r\n\x1a\n"), (fr.key, fr.skipped)
    img = _image(fr.png)
    h, w = img.shape[:2]
    assert img[..., :3].std() > 0.05, f"{fr.key}: blank image"  # a plain canvas has std 0
    assert len(np.unique(img[..., :3].reshape(-1, 3), axis=0)) > 16, f"{fr.key}: hardly anything drawn"
    if fr.figure is not None:
        fw, fh = fr.figure.get_size_inches() * opt.dpi
        assert 0.4 * fw <= w <= 1.3 * fw and 0.4 * fh <= h <= 1.3 * fh, (fr.key, (w, h), (fw, fh))
    return img


def _line(ax, label: str):
    found = [ln for ln in ax.get_lines() if ln.get_label() == label]
    assert len(found) == 1, (label, [ln.get_label() for ln in ax.get_lines()])
    return found[0]


def assert_points_of(xs, ys, df: pd.DataFrame, xcol: str, ycol: str, max_points: int) -> None:
    """The plotted points are rows of ``df`` (exact coordinates, in order), start at its first row and
    cover it to within one thinning step, at most ``max_points`` of them."""
    xs, ys = np.asarray(xs, float), np.asarray(ys, float)
    src = list(zip(df[xcol].to_numpy(float), df[ycol].to_numpy(float), strict=True))
    idx = [src.index(pt) for pt in zip(xs, ys, strict=True)]  # ValueError: a point that is not in the input
    assert idx[0] == 0 and idx == sorted(idx) and len(idx) <= max_points
    assert len(src) - 1 - idx[-1] < math.ceil(len(src) / max_points)


def test_full_report_has_every_figure_embedded(full_report):
    figs = {f.key: f for f in full_report.figures}
    assert {"fig08_ctd_profiles", "fig09_depth_time", "fig10_seafloor_depth", "fig05_06_suitability",
            "fig16_msd_surface", "fig16_matched_depth", "fig17_matched_track", "dtm_map", "landing_map"} <= set(figs)
    skipped = {k: f.skipped for k, f in figs.items() if f.png is None}
    assert not skipped, skipped
    pngs = _pngs(full_report.html)
    assert len(pngs) >= len(figs)
    assert {f.png for f in figs.values()} <= set(pngs)  # the page embeds exactly the drawn figures
    for f in figs.values():
        assert_drawn(f)
    assert "<script" not in full_report.html and "http://" not in full_report.html.replace("http://www.w3", "")


def test_summary_numbers_come_from_the_products(full_store, full_report):
    st = ProductStore(full_store)
    ctd = pd.read_parquet(st.latest("dive-a", "ctd").file("ctd.parquet"))
    fix = json.loads(st.latest("dive-a", "match").file("fix.json").read_text())
    sites = pd.read_parquet(st.latest("dive-a", "landing").file("landing_sites.parquet"))
    s = full_report.summary
    assert s["max_depth_m"] == pytest.approx(ctd["depth_m"].max())
    assert s["drift_m"] == pytest.approx(fix["drift_m"])
    assert s["deepest_point"]["lat"] == pytest.approx(fix["deepest_point"]["lat"])
    best = sites[sites["is_best"]].sort_values("c_s")
    assert [b["c_s"] for b in s["best_landing_sites"]] == pytest.approx(best["c_s"].tolist())
    assert s["match"]["uncertainty_radial_m"] == pytest.approx(19.2)
    assert s["phase_durations_s"]["descent"] > 0
    assert s["missing_products"] == ["laser_grids"]
    html = full_report.html
    assert f"{s['max_depth_m']:,.1f} m" in html
    assert html_escape(fix["deepest_point"]["position_degmin"]) in html


def test_partial_products_are_reported_missing_not_fatal(tmp_path):
    st = ProductStore(tmp_path)
    publish_fake_products(st, "dive-b", products=("ctd",))
    rep = build_report(st, "dive-b", options=FAST)
    figs = {f.key: f for f in rep.figures}
    assert_drawn(figs["fig09_depth_time"])
    assert_drawn(figs["fig08_ctd_profiles"])
    # the depth-time figure draws the ctd product's depth, one line per phase, and stars the deepest sample
    ctd = pd.read_parquet(st.latest("dive-b", "ctd").file("ctd.parquet"))
    ax = figs["fig09_depth_time"].figure.axes[0]
    for phase in ("descent", "bottom", "ascent"):
        line = _line(ax, phase)
        g = ctd[ctd["phase"] == phase]
        assert np.isin(line.get_ydata(), g["depth_m"].to_numpy()).all() and len(line.get_ydata()) > 10
    deepest = _line(ax, f"max {ctd['depth_m'].max():.1f} m")
    assert deepest.get_ydata()[0] == ctd["depth_m"].max()
    assert ax.get_ylabel() == "depth (m)" and ax.get_ylim()[0] > ax.get_ylim()[1]  # depth increases downwards
    assert [a.get_xlabel() for a in figs["fig08_ctd_profiles"].figure.axes] == [
        "conductivity (S/m)", "temperature ITS-90 (°C)", "practical salinity", "in situ density (kg/m³)",
        "gravity (m/s²)"]
    assert figs["fig17_matched_track"].png is None and "matched track" in figs["fig17_matched_track"].skipped
    for product in ("dtm", "match", "landing", "suitability"):
        assert f"product &#x27;{product}&#x27; is missing" in rep.html
    assert "figure skipped" in rep.html
    pv = publish_report(st, rep)
    assert (pv.path / "report.html").read_text(encoding="utf-8") == rep.html
    assert (pv.path / "figures" / "fig09_depth_time.png").read_bytes() == figs["fig09_depth_time"].png
    assert sorted(p.stem for p in (pv.path / "figures").glob("*.png")) == sorted(
        f.key for f in rep.figures if f.png is not None)  # one file per drawn figure, none for skipped ones
    assert {u["product"] for u in pv.manifest()["upstream"]} == {"ctd"}


def test_missing_columns_and_unreadable_files_skip_figures(tmp_path):
    st = ProductStore(tmp_path)
    publish_fake_products(st, "dive-c", products=("dtm",))
    df = fake_ctd().drop(columns=["gravity_m_s2", "seafloor_depth_m"])

    with st.publish("dive-c", "ctd") as d:
        write_parquet(df, d.path / "ctd.parquet")
    with st.publish("dive-c", "match") as d:
        (d.path / "fix.json").write_text("{not json")
    rep = build_report(st, "dive-c", options=FAST)
    figs = {f.key: f for f in rep.figures}
    assert_drawn(figs["fig08_ctd_profiles"])
    assert "gravity_m_s2" in figs["fig08_ctd_profiles"].caption  # named as not available
    assert "gravity (m/s²)" not in [a.get_xlabel() for a in figs["fig08_ctd_profiles"].figure.axes]
    assert len(figs["fig08_ctd_profiles"].figure.axes) == 4
    assert figs["fig10_seafloor_depth"].png is None and "seafloor_depth_m" in figs["fig10_seafloor_depth"].skipped
    assert any("fix.json is unreadable" in n for n in rep.summary["notes"])
    assert any("has no msd_surface.nc" in n for n in rep.summary["notes"])
    assert figs["dtm_map"].png is not None


def test_unreadable_sensors_table_is_a_note(tmp_path):
    """The report draws nothing from ``sensors`` (the figures read ``ctd``) and does not load its table, but a
    truncated sensors.parquet is still named in the notes, as every other unreadable product file."""
    st = ProductStore(tmp_path)
    pvs = publish_fake_products(st, "dive-s", products=("sensors", "ctd"))
    path = pvs["sensors"].path / "sensors.parquet"
    data = path.read_bytes()
    path.write_bytes(data[: len(data) // 2])
    rep = build_report(st, "dive-s", options=FAST)
    assert any("sensors/v001/sensors.parquet is unreadable" in n for n in rep.summary["notes"]), rep.summary["notes"]
    assert {f.key: f for f in rep.figures}["fig09_depth_time"].png is not None


def test_nan_only_seafloor_depth_is_a_skipped_figure(tmp_path):
    st = ProductStore(tmp_path)
    df = fake_ctd()
    df["seafloor_depth_m"] = np.nan
    with st.publish("dive-d", "ctd") as d:
        write_parquet(df, d.path / "ctd.parquet")
    rep = build_report(st, "dive-d", options=FAST)
    fig = {f.key: f for f in rep.figures}["fig10_seafloor_depth"]
    assert fig.png is None and "no valid seafloor depth" in fig.skipped


def test_no_products_is_a_clear_error(tmp_path):
    with pytest.raises(StageError, match="has no products"):
        load_products(ProductStore(tmp_path), "dive-x")


def test_report_stage_run_publishes_with_parameters(tmp_path, full_store):
    store = tmp_path / "store"
    shutil.copytree(full_store, store)
    raw = write_fake_dive(tmp_path / "raw", "dive-a")
    cfg = PipelineConfig.model_validate({"report": {"dpi": 50, "figure_width_in": 5, "max_points": 300,
                                                    "best_sites": 1, "title": "Haidou test dive"}})
    ctx = make_context(raw, store, cfg)
    out = run_stage("report", ctx)
    pv = out["report"]
    assert pv.manifest()["parameters"]["dpi"] == 50
    html = (pv.path / "report.html").read_text()
    assert "<title>Haidou test dive</title>" in html
    summary = json.loads((pv.path / "summary.json").read_text())
    assert len(summary["best_landing_sites"]) == 1
    assert summary["launch"]["lat"] == pytest.approx(ctx.dive.launch.latitude_deg)


def test_report_stage_without_products_still_publishes(tmp_path):
    """Issue 43: the report always runs (was: a StageError "no products"): with nothing upstream it lists the
    dive's sources (dive.yaml), the stages not run with the reasons, and says that nothing was published."""
    raw = write_fake_dive(tmp_path / "raw", "dive-empty")
    ctx = make_context(raw, tmp_path / "store")
    run_stage("report", ctx)
    rep = ctx.store.latest("dive-empty", "report")
    summary = json.loads(rep.file("summary.json").read_text())
    assert summary["products"] == {}
    assert any("no product was published upstream" in n for n in summary["notes"])
    assert summary["sources"] == {}  # its dive.yaml lists none (tests/unit/ingest/test_degrade_channels.py: a real cast)
    html = rep.file("report.html").read_text()
    for s in summary["skipped_stages"]:
        assert s["reason"] and s["stage"] in html


def test_cli_report_writes_html(tmp_path, full_store, monkeypatch, capsys):
    import sys

    from hadal import cli

    out = tmp_path / "out"
    out.mkdir()
    monkeypatch.setattr(sys, "argv", ["hadal", "report", "dive-a", "--store", str(full_store), "--out", str(out)])
    with pytest.raises(SystemExit) as exc:
        cli.main()
    assert exc.value.code == 0
    html = (out / "report.html").read_text()
    assert "Dive report" in html and len(_pngs(html)) >= 9
    monkeypatch.setattr(sys, "argv", ["hadal", "report", "nope", "--store", str(full_store)])
    with pytest.raises(SystemExit) as exc:
        cli.main()
    assert exc.value.code == 2
    err = capsys.readouterr().err
    assert "error:" in err and "no products" in " ".join(err.split()) and "Traceback" not in err


def test_new_figures_are_drawn(full_store, full_report):
    figs = {f.key: f for f in full_report.figures}
    for key in ("overview_map", "ctd_ts_theta_n2", "fig16_matched_depth"):
        assert_drawn(figs[key])
    assert "residual" in figs["fig16_matched_depth"].caption
    dp = load_products(ProductStore(full_store), "dive-a")
    track = dp.track
    # overview: the matched track in lon/lat, the launch, and (no posterior ellipse) the radial 1σ circle
    ax = figs["overview_map"].figure.axes[0]
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("longitude (WGS 84)", "latitude (WGS 84)")
    tr = _line(ax, "matched bottom track")
    assert_points_of(tr.get_xdata(), tr.get_ydata(), track, "lon", "lat", FAST.max_points)
    la = _line(ax, "launch")
    assert (la.get_xdata()[0], la.get_ydata()[0]) == (dp.fix["launch"]["lon"], dp.fix["launch"]["lat"])
    circle = _line(ax, "radial 1σ uncertainty (19 m)")
    from factories import ORIGIN

    from hadal.geo import LocalFrame

    cx, cy = LocalFrame(*ORIGIN).to_xy(np.asarray(circle.get_xdata()), np.asarray(circle.get_ydata()))
    r = np.hypot(cx - dp.fix["start"]["x_east_m"], cy - dp.fix["start"]["y_north_m"])
    assert r == pytest.approx(np.full(r.size, dp.fix["uncertainty_m"]["radial"]), abs=1e-3)  # 19.2 m on the ground
    # residual panel: measured - (map - bias) of the matched track, in metres
    top, bottom = figs["fig16_matched_depth"].figure.axes[:2]
    assert top.get_ylabel() == "seafloor depth (m)" and bottom.get_ylabel() == "residual (m)"
    meas = _line(top, "measured (depth + altitude)").get_ydata()
    ref = _line(top, "reference map").get_ydata()
    res = bottom.get_lines()[0].get_ydata()
    assert_points_of(meas, ref, track, "seafloor_depth_m", "map_depth_m", FAST.max_points)
    assert np.allclose(res, np.asarray(meas) - np.asarray(ref))
    # T-S / θ / N²: every axis says its quantity and unit
    labels = [(a.get_xlabel(), a.get_ylabel()) for a in figs["ctd_ts_theta_n2"].figure.axes]
    # a consistent pair (issue 46): Conservative Temperature with Absolute Salinity, not θ with S_A
    assert labels[0] == ("Absolute Salinity S_A (g/kg)", "Conservative Temperature Θ (°C)")
    assert labels[1] == ("Conservative Temperature Θ (°C)", "depth (m, log scale)")
    assert labels[2][0] == "N² (s⁻²)"


def test_ts_diagram_axes_are_gsw_values_of_the_profile():
    """The T-S panel draws (S_A, Θ) of each cast computed here with gsw from the profile's own in-situ temperature,
    practical salinity and pressure (the oracle), its axes span exactly those values (plus a 5 % margin), and its
    isopycnals are gsw.sigma0(S_A, Θ) at the points they pass through."""
    import gsw
    import xarray as xr

    from hadal.report.ctd_figures import fig_water_column
    from hadal.report.load import DiveProducts

    p = np.arange(5.0, 10_900.0, 50.0)
    t = np.stack([1.5 + 26.0 * np.exp(-p / 400.0), 1.6 + 25.0 * np.exp(-p / 420.0)])
    sp = np.stack([34.6 + 0.4 * np.exp(-((p - 150) / 120) ** 2), 34.62 + 0.3 * np.exp(-((p - 170) / 100) ** 2)])
    lat, lon = 11.34, 142.21
    prof = xr.Dataset({"temperature_its90_degc": (("cast", "pressure_dbar"), t),
                       "practical_salinity": (("cast", "pressure_dbar"), sp)},
                      coords={"cast": ("cast", [0, 1], {"flag_meanings": "descent ascent"}), "pressure_dbar": p,
                              "lat": lat, "lon": lon})
    fr = fig_water_column(DiveProducts(dive="x", profile=prof), FAST)
    ax = fr.figure.axes[0]
    sa_all, ct_all = [], []
    for i, cast in enumerate(("descent", "ascent")):
        sa = gsw.SA_from_SP(sp[i], p, lon, lat)
        ct = gsw.CT_from_t(sa, t[i], p)
        ln = _line(ax, cast)
        assert np.allclose(ln.get_xdata(), sa, atol=1e-9) and np.allclose(ln.get_ydata(), ct, atol=1e-9), cast
        sa_all.append(sa)
        ct_all.append(ct)
    sa, ct = np.concatenate(sa_all), np.concatenate(ct_all)
    ps, pt = 0.05 * max(np.ptp(sa), 0.01), 0.05 * max(np.ptp(ct), 0.1)
    assert ax.get_xlim() == pytest.approx((sa.min() - ps, sa.max() + ps), abs=1e-9)
    assert ax.get_ylim() == pytest.approx((ct.min() - pt, ct.max() + pt), abs=1e-9)
    cs = next(c for c in ax.collections if hasattr(c, "levels") and len(getattr(c, "levels", [])) > 1)
    for level, path in zip(cs.levels, cs.get_paths(), strict=False):
        if len(path.vertices):
            x, y = path.vertices[len(path.vertices) // 2]
            assert gsw.sigma0(x, y) == pytest.approx(level, abs=2e-3)


def test_coordinate_decimals_hand_computed():
    """Decimals of a lat/lon at the precision of the thing located: a 0.32 m landing site needs 6 decimals of a
    degree (111 694 m / 0.32 m = 349 044 -> 10^5.54 -> 6; the last digit 0.11 m) and 4 of a minute (1 861.6 m /
    0.32 m = 5 817 -> 10^3.76 -> 4; 0.19 m); a 10 m ship position 5 and 3; a 2 km search area 2 and 0."""
    from hadal.report.units import coordinate_decimals

    assert coordinate_decimals(0.32) == 6 and coordinate_decimals(0.32, "min") == 4
    assert coordinate_decimals(10.0) == 5 and coordinate_decimals(10.0, "min") == 3
    assert coordinate_decimals(2000.0) == 2 and coordinate_decimals(2000.0, "min") == 0
    assert coordinate_decimals(0.0) == 9 and coordinate_decimals(float("nan")) == 9
    for size in (0.05, 0.32, 3.0, 40.0, 700.0):  # the last digit is never coarser than the size, and not 10x finer
        d = coordinate_decimals(size)
        assert 111_694.0 * 10.0 ** -d <= size < 111_694.0 * 10.0 ** -(d - 1)


def test_landing_table_labels_and_site_precision():
    """The best-sites table: people's column labels with units (no snake_case key), each site's lat/lon with the
    decimals of its inscribed circle (0.32 m: 6 decimals) and a degrees-minutes position to 4 decimals of a minute
    that parses back to within the site's radius."""
    from hadal.geo import parse_degmin
    from hadal.report.html import _records_table, landing_site_records

    site = {"submap": "submap_01", "heading_deg": 30.0, "x_m": 12.5, "y_m": 0.4, "lat": 11.3371234567,
            "lon": 142.2097123456, "radius_m": 0.32, "slope_deg": 4.2, "roughness_m": 0.012, "c_s": 0.2}
    rec = landing_site_records([site])[0]
    assert rec["lat"] == "11.337123" and rec["lon"] == "142.209712"
    lon_txt, lat_txt = rec["position"].split(", ")
    assert lat_txt == "11°20.2274'N"  # 0.3371234567 * 60 = 20.227407'
    assert abs(parse_degmin(lat_txt) - site["lat"]) * 111_694 < 0.32
    assert abs(parse_degmin(lon_txt) - site["lon"]) * 111_694 < 0.32
    html = _records_table([rec])
    heads = re.findall(r"<th>(.*?)</th>", html)
    assert not [h for h in heads if "_" in h.replace("C_s", "")], heads
    assert "slope (°)" in heads and "largest inscribed circle radius (m)" in heads


@pytest.mark.parametrize("opt", [FAST, FigureOptions(dpi=110, width_in=10, keep_figure=True)], ids=["fast", "default"])
def test_landing_map_png_is_the_figure_canvas_with_everything_on_it(full_store, opt):
    """The landing map's PNG has the figure's size (it came out as a 596 x 714 portrait of an 1100 x 682 figure:
    colour bars anchored the equal-aspect maps to the right and a colour-bar label poked out of the top), and every
    axes, colour bar and label lies inside the canvas."""
    from hadal.report.figures import fig_landing_map

    fr = fig_landing_map(load_products(ProductStore(full_store), "dive-a"), opt)
    img = assert_drawn(fr, opt)
    fw, fh = fr.figure.get_size_inches() * opt.dpi
    assert abs(img.shape[1] - fw) <= 2 and abs(img.shape[0] - fh) <= 2, ((img.shape[1], img.shape[0]), (fw, fh))
    fig = fr.figure
    renderer = fig.canvas.get_renderer()
    canvas = fig.bbox
    axes = [a for ax in fig.axes for a in (ax, *ax.child_axes)]
    assert len(axes) >= 4  # the strip, the zoom and their colour bars
    for a in axes:
        bb = a.get_tightbbox(renderer)
        assert (bb.x0 >= canvas.x0 - 1 and bb.y0 >= canvas.y0 - 1 and bb.x1 <= canvas.x1 + 1
                and bb.y1 <= canvas.y1 + 1), (a.get_label() or a.get_ylabel(), bb.bounds, canvas.bounds)
    strip, zoom = fig.axes[:2]
    assert strip.get_title().startswith("submap_") and zoom.get_xlabel() == "x (m, laser frame)"


def test_overview_draws_the_fix_ellipses_from_the_summary(full_store):
    """The 1σ/2σ outlines on the overview map have the semi-axes and azimuth of fix.json's ellipses (metres on
    the ground, about profile_start), and the zoom inset shows the same outlines."""
    from factories import ORIGIN

    from hadal.geo import LocalFrame
    from hadal.report.geo_figures import fig_overview

    dp = load_products(ProductStore(full_store), "dive-a")
    centre = {"x_east_m": dp.fix["start"]["x_east_m"] + 40.0, "y_north_m": dp.fix["start"]["y_north_m"] - 25.0}
    ell = {"ellipse_1sigma": {"semi_major_m": 30.0, "semi_minor_m": 12.0, "azimuth_deg": 60.0},
           "ellipse_2sigma": {"semi_major_m": 73.4, "semi_minor_m": 29.4, "azimuth_deg": 60.0}}
    dp.fix = {**dp.fix, "profile_start": centre, "uncertainty_m": {**dp.fix["uncertainty_m"], **ell}}
    fr = fig_overview(dp, FAST)
    assert_drawn(fr)
    ax = fr.figure.axes[0]
    frame = LocalFrame(*ORIGIN)
    for key, label in (("ellipse_1sigma", "1σ ellipse"), ("ellipse_2sigma", "2σ ellipse")):
        line = _line(ax, label)
        x, y = frame.to_xy(np.asarray(line.get_xdata()), np.asarray(line.get_ydata()))
        dx, dy = np.asarray(x) - centre["x_east_m"], np.asarray(y) - centre["y_north_m"]
        r = np.hypot(dx, dy)
        e = ell[key]
        assert r.max() == pytest.approx(e["semi_major_m"], abs=0.01)
        assert r.min() == pytest.approx(e["semi_minor_m"], abs=0.01)
        k = int(np.argmax(r))
        assert math.degrees(math.atan2(dx[k], dy[k])) % 180 == pytest.approx(e["azimuth_deg"], abs=0.05)
    assert "radial 1σ uncertainty (19 m)" not in [ln.get_label() for ln in ax.get_lines()]
    inset = next(a for a in ax.child_axes)
    assert inset.get_title().startswith("zoom on the fix")
    two_sigma = _line(ax, "2σ ellipse")
    assert any(np.array_equal(ln.get_xdata(), two_sigma.get_xdata()) for ln in inset.get_lines())


def test_overview_zoom_inset_does_not_hide_the_track(full_store):
    """The zoom inset sits in the map corner over the fewest plotted track points: with a dead-reckoning track
    running from the start to the map's south-east (through the lower-right corner, the inset's first choice) the
    inset moves to a corner that covers fewer of the tracks' points than any other."""
    from hadal.report.geo_figures import _INSET_CORNERS, _INSET_SIZE, fig_overview

    dp = load_products(ProductStore(full_store), "dive-a")
    st = dp.fix["start"]
    xs, ys = dp.dtm["x"].values, dp.dtm["y"].values
    end = (xs.max() - 0.1 * np.ptp(xs), ys.min() + 0.1 * np.ptp(ys))  # towards the map's south-east corner
    t = np.linspace(0.0, 1.0, 200)
    dr = {"x_east_m": list(st["x_east_m"] + (end[0] - st["x_east_m"]) * t),
          "y_north_m": list(st["y_north_m"] + (end[1] - st["y_north_m"]) * t)}
    dp.fix = {**dp.fix, "dead_reckoning_track": dr}
    w, h = _INSET_SIZE
    fig = fig_overview(dp, FAST).figure
    ax = fig.axes[0]
    inset = next(a for a in ax.child_axes)
    to_axes = ax.transData + ax.transAxes.inverted()
    uv = np.concatenate([to_axes.transform(np.column_stack([ln.get_xdata(), ln.get_ydata()]).astype(float))
                         for ln in ax.get_lines() if "track" in ln.get_label() or "dead reckoning" in ln.get_label()])
    uv = uv[np.isfinite(uv).all(axis=1)]

    def covered(x0, y0):
        return int(((uv[:, 0] >= x0) & (uv[:, 0] <= x0 + w) & (uv[:, 1] >= y0) & (uv[:, 1] <= y0 + h)).sum())

    assert covered(*_INSET_CORNERS[0]) > 0  # the DR track does run through the lower-right corner
    fig.canvas.draw()
    pi, pa = inset.get_window_extent(), ax.get_window_extent()  # pixels, as drawn (the inset keeps its aspect)
    cu, cv = ((pi.x0 + pi.x1) / 2 - pa.x0) / pa.width, ((pi.y0 + pi.y1) / 2 - pa.y0) / pa.height
    (x0, y0), = [c for c in _INSET_CORNERS if c[0] < cu < c[0] + w and c[1] < cv < c[1] + h]
    assert (x0, y0) != _INSET_CORNERS[0]
    assert covered(x0, y0) == min(covered(*c) for c in _INSET_CORNERS)


def test_matched_track_figure_is_geographic_on_the_dtms_own_lon_lat(full_report, full_store):
    """TERCOM Fig. 17 on lon/lat axes: the track's points are the matched track's lon/lat rows, the deepest point
    fix.json's, the hillshaded DTM cells sit at dtm.nc's own lon/lat (read with xarray: the oracle of the map
    frame's projection), equal ground distances (aspect 1/cos(latitude)), a scale bar and a degrees-minutes
    graticule."""
    import xarray as xr

    fr = {f.key: f for f in full_report.figures}["fig17_matched_track"]
    assert_drawn(fr)
    st = ProductStore(full_store)
    dp = load_products(st, "dive-a")
    ax = fr.figure.axes[0]
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("longitude (WGS 84)", "latitude (WGS 84)")
    line = _line(ax, "matched track")
    assert_points_of(line.get_xdata(), line.get_ydata(), dp.track, "lon", "lat", FAST.max_points)
    deep = _line(ax, "deepest point")
    assert (deep.get_xdata()[0], deep.get_ydata()[0]) == (dp.fix["deepest_point"]["lon"],
                                                          dp.fix["deepest_point"]["lat"])
    lat0 = 0.5 * sum(ax.get_ylim())
    assert ax.get_aspect() == pytest.approx(1 / math.cos(math.radians(lat0)))
    assert any(t.get_gid() == "scale_bar" for t in ax.texts)
    assert "°" in ax.xaxis.get_major_formatter()(float(np.mean(ax.get_xlim())), 0)
    mesh = next(c for c in ax.collections if c.__class__.__name__ == "QuadMesh")
    corners = mesh.get_coordinates()  # (ny, nx, 2) cell centres (shading "nearest": given as centres)
    with xr.open_dataset(st.latest("dive-a", "dtm").file("dtm.nc")) as ds:
        lon, lat = ds["lon"].values, ds["lat"].values
        if lon.ndim == 1:
            lon, lat = np.meshgrid(lon, lat)
    # the drawn cell centres (mean of each cell's corners) are a block of dtm.nc's cells, at their lon/lat
    got = 0.25 * (corners[:-1, :-1] + corners[1:, 1:] + corners[:-1, 1:] + corners[1:, :-1])
    iy, ix = np.unravel_index(np.argmin((lon - got[0, 0, 0]) ** 2 + (lat - got[0, 0, 1]) ** 2), lon.shape)
    ny, nx = got.shape[:2]
    want_lon, want_lat = lon[iy:iy + ny, ix:ix + nx], lat[iy:iy + ny, ix:ix + nx]
    assert np.abs(got[..., 0] - want_lon).max() < 1e-7 and np.abs(got[..., 1] - want_lat).max() < 1e-7


def test_normal_refinement_is_a_note_and_real_problems_stay_warnings(full_store):
    from hadal.report.html import is_real_warning

    assert not is_real_warning("sub-cell refinement moved the fix 27 m from the coarse optimum")
    assert is_real_warning("refined fix hit the search bound")
    dp = load_products(ProductStore(full_store), "dive-a")
    from hadal.report.html import render_html

    html = render_html(dp, {"match": {"warnings": ["sub-cell refinement moved the fix 70 m from the coarse optimum",
                                                   "posterior is ambiguous"]}}, [], [])
    assert "<div class='note'>match: sub-cell refinement" in html
    assert "<div class='warn'>match: posterior is ambiguous" in html


def test_log_bin_mean_against_brute_force():
    from hadal.report.ctd_figures import log_bin_mean

    rng = np.random.default_rng(1)
    z = rng.uniform(1, 10000, 3000)
    v = rng.normal(size=z.size)
    zb, vb = log_bin_mean(z, v, per_decade=4)
    edges = 10 ** (np.arange(0, 17) / 4)
    want = [(z[(z >= a) & (z < b)].mean(), v[(z >= a) & (z < b)].mean()) for a, b in zip(edges[:-1], edges[1:],
                                                                                         strict=True)
            if ((z >= a) & (z < b)).any()]
    assert np.allclose(zb, [w[0] for w in want]) and np.allclose(vb, [w[1] for w in want])


def full_store_path(report) -> str:
    """The store a report was built from (its upstream versions' store root)."""
    return str(report.upstream[0].path.parent.parent.parent)


def test_report_html_in_headless_chromium(full_report, tmp_path):
    """Every embedded figure decodes and the page logs no error, in a real browser (skipped without one)."""
    from factories import browser_check, chromium

    if chromium() is None:
        pytest.skip("no chromium installed")
    res = browser_check(full_report.html, tmp_path)
    assert res["images"] >= sum(f.png is not None for f in full_report.figures)
    assert res["broken"] == [] and res["errors"] == [], res
    # at the report's own resolution, in a 1280 px wide window: every figure's smallest text is at least 9 pt on
    # screen (12 CSS px: its points x dpi / 72 x the displayed / natural width the browser laid out), no figure is a
    # strip (the landing transect was 2475 x 440 px, shown 1068 x 190) and each is shown at least 250 px tall
    default = build_report(ProductStore(full_store_path(full_report)), "dive-a", options=FigureOptions())
    res = browser_check(default.html, tmp_path, width=1280)
    assert res["broken"] == [] and res["errors"] == [], res
    figs = res["figures"]
    assert len(figs) == sum(f.png is not None for f in default.figures) + len(
        load_products(ProductStore(full_store_path(full_report)), "dive-a").landing_figures)
    for f in figs:
        scale = f["shown_w"] / f["natural_w"]
        assert f["min_font_pt"] * f["dpi"] / 72 * scale >= 12.0 - 0.3, f  # 0.3 px: the img's 1 px border
        assert f["shown_w"] / f["shown_h"] <= 4.0 and f["shown_h"] >= 250, f
    from factories import browser_screenshot

    shot = browser_screenshot(default.html, tmp_path / "report.png", 1280, 2400)
    assert shot is not None and _image(shot.read_bytes())[..., :3].std() > 0.05  # the page drew something
    # the probe sees a broken image and a console error (it can fail)
    bad = browser_check("<html><head></head><body><img alt='x' src='data:image/png;base64,AAAA'>"
                        "<script>console.error('boom')</script></body></html>", tmp_path)
    assert bad["broken"] == ["x"] and "boom" in bad["errors"]


def test_teos10_profile_quantities_against_eos80_peer():
    """θ and N² of the report's water-column figure against python-seawater (EOS-80), an independent peer."""
    sw = pytest.importorskip("seawater")
    from hadal.report.ctd_figures import teos10

    p = np.arange(5.0, 6000.0, 10.0)
    t = 2.0 + 26.0 * np.exp(-p / 400.0)
    sp = 34.6 + 0.4 * np.exp(-((p - 150) / 120) ** 2) - 0.3 * np.exp(-((p - 700) / 300) ** 2)
    d = teos10(pd.DataFrame({"pressure_dbar": p, "t": t, "SP": sp}), 11.3, 142.2)
    theta_eos80 = sw.ptmp(sp, t * 1.00024, p, 0) / 1.00024  # ITS-90 <-> IPTS-68
    assert np.max(np.abs(d["theta"] - theta_eos80)) < 5e-3
    n2_eos80, _, _ = sw.bfrq(sp, t * 1.00024, p, 11.3)
    n2 = d["N2"].to_numpy()[:-1]
    strong = n2 > 1e-6
    assert strong.sum() > 20
    assert np.allclose(n2[strong], np.ravel(n2_eos80)[strong], rtol=0.05)


def test_qc_flag_summary_counts_and_renders():
    """The per-variable QARTOD summary: known flags in, known counts out (flagged share among non-missing)."""
    import pandas as pd

    from hadal.report.summary import qc_flag_table

    ctd = pd.DataFrame({"practical_salinity_qc": [1, 1, 1, 4, 9, 9], "depth_m_qc": [1, 2, 3, 3, 1, 1],
                        "depth_m": [1.0] * 6})
    rows = {r["variable"]: r for r in qc_flag_table(ctd)}
    assert set(rows) == {"practical_salinity", "depth_m"}
    assert rows["practical_salinity"] == {"variable": "practical_salinity", "good": 3, "not evaluated": 0,
                                          "suspect": 0, "fail": 1, "missing": 2, "flagged %": 25.0}
    assert rows["depth_m"]["suspect"] == 2 and rows["depth_m"]["flagged %"] == pytest.approx(100 * 2 / 6, abs=1e-3)


def test_figures_drawn_in_two_processes_are_those_drawn_here(full_store):
    """``FigureOptions(workers=2)`` (forked children, :mod:`hadal.forkpool`) gives the same figures, byte for byte and
    in the same order, as drawing them one after the other in this process (the oracle)."""
    from hadal.forkpool import can_fork
    from hadal.report import make_figures

    if not can_fork():
        pytest.skip("figures are drawn in forked processes on Linux only")
    dp = load_products(ProductStore(full_store), "dive-a")
    here = make_figures(dp, FigureOptions(workers=1))
    forked = make_figures(dp, FigureOptions(workers=2))
    assert [f.key for f in forked] == [f.key for f in here]
    assert sum(f.png is not None for f in here) >= 9
    for a, b in zip(here, forked, strict=True):
        assert (a.png, a.skipped, a.caption) == (b.png, b.skipped, b.caption), a.key


def test_dtm_map_is_geographic_at_the_products_lon_lat_bounds(full_store):
    """The DTM map's axes span the product's own lon/lat (read here with xarray from dtm.nc, the oracle), with
    equal ground distances (aspect 1/cos(latitude)) and a hillshaded image; the quality figure draws the count and
    uncertainty layers at the same bounds, and its coverage share is the file's share of cells with count > 0."""
    import xarray as xr

    from hadal.report.geo_figures import fig_dtm_geo, fig_dtm_quality

    st = ProductStore(full_store)
    with xr.open_dataset(st.latest("dive-a", "dtm").file("dtm.nc")) as ds:
        lon, lat = ds["lon"].values, ds["lat"].values
        count = ds["count"].values if "count" in ds else None
    dp = load_products(st, "dive-a")
    fr = fig_dtm_geo(dp, FAST)
    ax = fr.figure.axes[0]
    assert ax.get_xlim() == pytest.approx((np.nanmin(lon), np.nanmax(lon)), abs=1e-12)
    assert ax.get_ylim() == pytest.approx((np.nanmin(lat), np.nanmax(lat)), abs=1e-12)
    assert ax.get_aspect() == pytest.approx(1 / math.cos(math.radians(0.5 * (np.nanmin(lat) + np.nanmax(lat)))))
    assert "°" in ax.xaxis.get_major_formatter()(float(np.nanmean(lon)), 0)  # degrees and minutes graticule
    assert_drawn(fr)
    q = fig_dtm_quality(dp, FAST)
    if count is None:
        assert q.png is None and "count" in q.skipped
        return
    for a in q.figure.axes[::2][:2]:
        if a.get_title():
            assert a.get_xlim() == pytest.approx((np.nanmin(lon), np.nanmax(lon)), abs=1e-12)
    assert f"{100 * float(np.mean(count > 0)):.1f} % of the" in q.caption


def test_overview_scale_bar_is_not_under_the_inset(full_store):
    """The overview's scale bar (its label) does not overlap the zoom inset on the fix, wherever the inset goes."""
    from hadal.report.geo_figures import fig_overview

    dp = load_products(ProductStore(full_store), "dive-a")
    fr = fig_overview(dp, FAST)
    fig = fr.figure
    ax = fig.axes[0]
    r = fig.canvas.get_renderer()
    label = next(t for t in ax.texts if t.get_gid() == "scale_bar")
    insets = [a for a in ax.child_axes]
    assert insets, "no inset drawn"
    for ins in insets:
        assert not label.get_window_extent(r).overlaps(ins.get_window_extent(r))


def test_surfacing_and_along_track_uncertainty_from_navigation():
    """The surfacing position is the navigation product's last ascent sample and its 1-sigma radius; the uncertainty
    figure draws position_uncertainty_m and, from an east/north covariance, the 1-sigma ellipse's semi-major axis
    sqrt(largest eigenvalue) (oracle: numpy.linalg.eigvalsh on each 2x2 matrix)."""
    from hadal.report.geo_figures import fig_nav_uncertainty, nav_uncertainty_series, surfacing_position
    from hadal.report.load import DiveProducts

    n = 300
    t = pd.date_range("2018-10-06T23:00:00Z", periods=n, freq="60s")
    phase = np.array(["descent"] * 100 + ["bottom"] * 100 + ["ascent"] * 100)
    rng = np.random.default_rng(3)
    ee, nn = rng.uniform(10, 400, n), rng.uniform(10, 400, n)
    en = rng.uniform(-1, 1, n) * np.sqrt(ee * nn) * 0.9
    nav = pd.DataFrame({"time": t, "lat": 11.3 + np.arange(n) * 1e-5, "lon": 142.2 + np.arange(n) * 1e-5,
                        "position_uncertainty_m": np.linspace(10, 600, n), "phase": phase,
                        # the smoother's names (issue 47, hadal.navigation): east/north variances and covariance
                        "position_covariance_east_m2": ee, "position_covariance_north_m2": nn,
                        "position_covariance_east_north_m2": en})
    nav.loc[n - 1, ["lat", "lon"]] = np.nan  # a last sample without position: the one before it surfaced
    s = surfacing_position(nav)
    assert (s["lat"], s["lon"], s["uncertainty_m"]) == (nav["lat"][n - 2], nav["lon"][n - 2],
                                                        nav["position_uncertainty_m"][n - 2])
    series = nav_uncertainty_series(nav)
    want = np.sqrt([np.linalg.eigvalsh([[a, c], [c, b]]).max() for a, b, c in zip(ee, nn, en, strict=True)])
    assert np.allclose(series["ellipse semi-major 1σ (covariance)"], want)
    opt = FigureOptions(dpi=40, width_in=10, max_points=500, keep_figure=True)  # the report's width, few pixels
    fr = fig_nav_uncertainty(DiveProducts(dive="x", navigation=nav), opt)
    labels = [ln.get_label() for ln in fr.figure.axes[0].get_lines()]
    assert "radial 1σ (DRMS)" in labels and "ellipse semi-major 1σ (covariance)" in labels
    assert_drawn(fr, opt)
    assert surfacing_position(nav.drop(columns=["lat"])) is None
    from hadal.report.geo_figures import _cov_role

    assert [_cov_role(c) for c in ("cov_xx", "cov_yy", "cov_xy", "pos_cov_ee_m2", "position_covariance_type")] == [
        "ee", "nn", "en", "ee", None]


def test_progress_lines_of_a_step_and_a_tracked_loop(caplog):
    """:func:`hadal.steps.step` through :class:`hadal.progress.LogProgress`: a start and an end line (with the
    duration) on the hadal.progress logger; a loop's lines give its count and percentage; nothing without progress."""
    import logging

    from hadal.progress import LogProgress
    from hadal.steps import step, tracked

    prog = LogProgress(interval_s=0.0, echo=False)
    with caplog.at_level(logging.INFO, logger="hadal.progress"):
        with step(prog, "dtm: gridding 5 soundings"):
            pass
        assert list(tracked(prog, range(4), "dtm: reading", total=4)) == [0, 1, 2, 3]
        with step(None, "silent"):
            pass
    msgs = [r.getMessage() for r in caplog.records if r.name == "hadal.progress"]
    assert msgs[0] == "dtm: gridding 5 soundings: started" and msgs[1].startswith("dtm: gridding 5 soundings: done")
    assert "dtm: reading: 2/4 (50 %)" in " ".join(msgs) and msgs[-1].startswith("dtm: reading: done, 4 step(s)")
    assert not [m for m in msgs if "silent" in m]


def test_progress_lines_echo_on_a_terminal(capsys):
    """A stage in its own process has no bar: with ``echo`` (its stderr is a terminal) the same lines are printed
    there, so dtm's phases show on the terminal as well as in the Prefect logs."""
    from hadal.progress import LogProgress
    from hadal.steps import step

    with step(LogProgress(interval_s=60.0, echo=True), "dtm: spike test of 3 soundings"):
        pass
    err = capsys.readouterr().err.splitlines()
    assert err[0] == "  dtm: spike test of 3 soundings: started" and "done, 1 step(s) in" in err[1]


def test_long_landing_transect_is_split_into_legible_panels(tmp_path):
    """An 83 m x 1.5 m transect (3 submaps of 25 m, the sample dive's; drawn on one axis it was a 2475 x 440 px
    strip) becomes stacked panels at one scale, each within the panel aspect, the PNG at most ~1000 px wide (shown
    1:1 in the page) and not a strip; every site is drawn once, in the panel holding its x, coloured by its C_s."""
    from matplotlib.image import imread

    import hadal.landing.figures as lf

    rng = np.random.default_rng(2)
    outlines = {f"submap_{i:02d}": np.column_stack([np.linspace(29 * i, 29 * i + 25, 300),
                                                    rng.uniform(-0.75, 0.75, 300)]) for i in range(3)}
    best = pd.DataFrame({"submap": ["submap_00", "submap_01", "submap_02"], "x_m": [5.0, 40.0, 70.0],
                         "y_m": [0.1, -0.2, 0.3], "c_s": [0.2, 0.35, 0.5]})
    seen = {}
    real_save = lf._save

    def keep(fig, path):
        seen["axes"] = [a for a in fig.axes if a.get_label() != "<colorbar>"]
        return real_save(fig, path)

    lf._save = keep
    try:
        path = lf.figure_transect(best, outlines, tmp_path / "fig25_transect.png")
    finally:
        lf._save = real_save
    h, w = imread(path).shape[:2]
    assert w <= 1000 and w / h <= 2.5, (w, h)
    panels = [a for a in seen["axes"] if a.get_xlabel() or a.get_ylabel() == "y (m)"]
    assert len(panels) >= 3
    drawn = []
    for a in panels:
        x0, x1 = a.get_xlim()
        y0, y1 = a.get_ylim()
        assert (x1 - x0) / (y1 - y0) <= lf.TRANSECT_PANEL_ASPECT + 1e-9
        for c in a.collections:
            for (x, _), v in zip(c.get_offsets(), c.get_array(), strict=True):
                assert x0 <= x <= x1
                drawn.append((float(x), float(v)))
    assert sorted(drawn) == sorted(zip(best["x_m"], best["c_s"], strict=True))


def test_msd_surface_figure_is_geographic_at_the_files_lon_lat(small_run):
    """The TERCOM criterion surface drawn in lon/lat: its cells where msd_surface.nc's own CF grid mapping puts them
    (the file's ``crs`` variable read by pyproj's ``CRS.from_cf``, x/y transformed to WGS 84: the oracle), the best
    match among them, the dive's track, equal ground distances, a scale bar, a degrees-minutes graticule."""
    import xarray as xr
    from pyproj import CRS, Transformer

    from hadal.report.geo_figures import fig_msd_geo

    ctx, versions = small_run  # the sample dive's match product: its grid mapping as the match stage wrote it
    with xr.open_dataset(versions["match"].file("msd_surface.nc"), decode_coords=False) as ds:
        gm = ds[ds["score"].attrs["grid_mapping"]].attrs
        X, Y = np.meshgrid(ds["x"].values.astype(float), ds["y"].values.astype(float))
    lon, lat = Transformer.from_crs(CRS.from_cf(gm), CRS.from_epsg(4326), always_xy=True).transform(X, Y)
    dp = load_products(ctx.store, ctx.dive_id)
    fr = fig_msd_geo(dp, FAST)
    assert_drawn(fr)
    ax = fr.figure.axes[0]
    assert (ax.get_xlabel(), ax.get_ylabel()) == ("longitude (WGS 84)", "latitude (WGS 84)")
    mesh = next(c for c in ax.collections if c.__class__.__name__ == "QuadMesh")
    c = mesh.get_coordinates()
    got = 0.25 * (c[:-1, :-1] + c[1:, 1:] + c[:-1, 1:] + c[1:, :-1])
    assert got.shape[:2] == lon.shape
    assert np.abs(got[..., 0] - lon).max() < 1e-7 and np.abs(got[..., 1] - lat).max() < 1e-7
    best = _line(ax, "best match")
    assert lon.min() <= best.get_xdata()[0] <= lon.max() and lat.min() <= best.get_ydata()[0] <= lat.max()
    track = [ln for ln in ax.get_lines() if "track" in ln.get_label()]
    assert track and np.isfinite(np.asarray(track[0].get_xdata(), float)).any()
    assert ax.get_aspect() == pytest.approx(1 / math.cos(math.radians(0.5 * sum(ax.get_ylim()))))
    assert any(t.get_gid() == "scale_bar" for t in ax.texts)
    assert "°" in ax.yaxis.get_major_formatter()(float(np.mean(ax.get_ylim())), 0)
