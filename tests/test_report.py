"""Dive report: works with whichever products exist, says what is missing, fails clearly with none."""

from __future__ import annotations

import base64
import json
import re
import shutil
from html import escape as html_escape

import numpy as np
import pandas as pd
import pytest

from hadal.config import PipelineConfig
from hadal.errors import StageError
from hadal.pipeline import make_context, run_stage
from hadal.products import write_parquet
from hadal.report import FigureOptions, build_report, load_products, publish_report
from hadal.report.testing import ALL_FAKE, fake_ctd, publish_fake_products, write_fake_dive
from hadal.store import ProductStore

FAST = FigureOptions(dpi=40, width_in=6, max_points=500)


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


def test_full_report_has_every_figure_embedded(full_report):
    figs = {f.key: f for f in full_report.figures}
    assert {"fig08_ctd_profiles", "fig09_depth_time", "fig10_seafloor_depth", "fig05_06_suitability",
            "fig16_msd_surface", "fig16_matched_depth", "fig17_matched_track", "dtm_map", "landing_map"} <= set(figs)
    skipped = {k: f.skipped for k, f in figs.items() if f.png is None}
    assert not skipped, skipped
    pngs = _pngs(full_report.html)
    assert len(pngs) >= len(figs)
    assert all(p.startswith(b"\x89PNG\r\n\x1a\n") for p in pngs)
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
    assert figs["fig09_depth_time"].png is not None and figs["fig08_ctd_profiles"].png is not None
    assert figs["fig17_matched_track"].png is None and "matched track" in figs["fig17_matched_track"].skipped
    for product in ("dtm", "match", "landing", "suitability"):
        assert f"product &#x27;{product}&#x27; is missing" in rep.html
    assert "figure skipped" in rep.html
    pv = publish_report(st, rep)
    assert (pv.path / "report.html").is_file() and (pv.path / "figures" / "fig09_depth_time.png").is_file()
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
    assert figs["fig08_ctd_profiles"].png is not None
    assert "gravity_m_s2" in figs["fig08_ctd_profiles"].caption  # named as not available
    assert figs["fig10_seafloor_depth"].png is None and "seafloor_depth_m" in figs["fig10_seafloor_depth"].skipped
    assert any("fix.json is unreadable" in n for n in rep.summary["notes"])
    assert any("has no msd_surface.nc" in n for n in rep.summary["notes"])
    assert figs["dtm_map"].png is not None


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


def test_report_stage_without_products_fails_clearly(tmp_path):
    raw = write_fake_dive(tmp_path / "raw", "dive-empty")
    with pytest.raises(StageError, match="no products"):
        run_stage("report", make_context(raw, tmp_path / "store"))
    assert not (tmp_path / "store" / "dive-empty" / "report").exists()


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


def test_new_figures_are_drawn(full_report):
    figs = {f.key: f for f in full_report.figures}
    for key in ("overview_map", "ctd_ts_theta_n2", "fig16_matched_depth"):
        assert figs[key].png is not None, (key, figs[key].skipped)
    assert "residual" in figs["fig16_matched_depth"].caption


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


def test_report_html_in_headless_chromium(full_report, tmp_path):
    """Every embedded figure decodes and the page logs no error, in a real browser (skipped without one)."""
    from hadal.report.testing import browser_check, chromium

    if chromium() is None:
        pytest.skip("no chromium installed")
    res = browser_check(full_report.html, tmp_path)
    assert res["images"] >= sum(f.png is not None for f in full_report.figures)
    assert res["broken"] == [] and res["errors"] == [], res
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
