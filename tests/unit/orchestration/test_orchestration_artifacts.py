"""Stage artifacts carry the results a user looks for (issue 46), not only file sizes: QC flag counts (ingest,
derive), the fix and its error ellipses (match), the best landing sites (landing), the report link (report).

Oracles: the values written into the product files by the test itself, and pandas' own ``value_counts`` of the
QC columns.
"""

from __future__ import annotations

import json
import sys
from pathlib import Path

import numpy as np
import pandas as pd

REPO = Path(__file__).resolve().parents[3]
if str(REPO) not in sys.path:
    sys.path.insert(0, str(REPO))

from hadal.tasks.results import deg_decimals, latlon, result_lines  # noqa: E402
from hadal.tasks.stage import artifact_markdown  # noqa: E402


def _rows(md: str, first: str) -> list[list[str]]:
    return [[c.strip() for c in ln.strip("|").split("|")] for ln in md.splitlines() if ln.startswith(f"| {first}")]


def test_qc_counts_match_pandas(tmp_path):
    rng = np.random.default_rng(1)
    v = tmp_path / "ctd" / "v001"
    v.mkdir(parents=True)
    df = pd.DataFrame({"pressure_dbar": rng.normal(size=500),
                       "pressure_dbar_qc": rng.choice([1, 3, 4, 9], size=500, p=[0.7, 0.1, 0.1, 0.1]).astype("int8"),
                       "temperature_qc": np.ones(500, "int8")})
    df.to_parquet(v / "ctd.parquet")
    md = "\n".join(result_lines({"ctd": str(v)}))
    (row,) = _rows(md, "pressure_dbar")
    counts = df["pressure_dbar_qc"].value_counts()
    assert [int(x) for x in row[1:6]] == [int(counts.get(k, 0)) for k in (1, 2, 3, 4, 9)]
    flagged = 100 * (counts.get(3, 0) + counts.get(4, 0)) / (500 - counts.get(9, 0))
    assert float(row[6]) == round(flagged, 2)
    assert _rows(md, "temperature")[0][1] == "500" and "(500 samples)" in md


def test_match_artifact_gives_the_fix_and_its_ellipses(tmp_path):
    v = tmp_path / "match" / "v001"
    v.mkdir(parents=True)
    ell = {"semi_major_m": 29.98, "semi_minor_m": 12.97, "azimuth_deg": 98.9, "gaussian_content": 0.3935,
           "centre": {"lat": -11.3388713, "lon": 142.2143021}}
    (v / "fix.json").write_text(json.dumps({
        "start": {"lat": -11.33889794, "lon": 142.21430243, "time": "2018-10-07T02:32:48.500Z"},
        "uncertainty_m": {"radial": 32.67, "ellipse_1sigma": ell,
                          "ellipse_2sigma": {**ell, "semi_major_m": 59.97, "semi_minor_m": 25.93}},
        "drift_m": 537.97, "heading_error_deg": -1.694, "track_scale": 0.9679, "n_valid": 182, "n_samples": 182,
        "mismatch": True, "mismatch_reasons": ["second optimum close"]}))
    md = "\n".join(result_lines({"match": str(v)}))
    assert "- position: 11.33890 S, 142.21430 E at 2018-10-07T02:32:48.500Z" in md  # 13 m minor axis: 5 decimals
    assert "1-sigma ellipse: semi-major 30.0 m, semi-minor 13.0 m, azimuth 98.9 deg (content 39%)" in md
    assert "2-sigma ellipse: semi-major 60.0 m, semi-minor 25.9 m" in md
    assert "DRMS): 32.7 m" in md and "drift from the launch point: 538 m" in md
    assert "mismatch: YES: second optimum close" in md


def test_landing_artifact_lists_the_best_sites_lowest_cost_first(tmp_path):
    v = tmp_path / "landing" / "v001"
    v.mkdir(parents=True)
    sites = [{"submap": f"s{i}", "heading_deg": 15 * i, "lat": 11.3371166 + i * 1e-6, "lon": 142.2097166,
              "x_m": i, "y_m": -i, "radius_m": 0.32, "slope_deg": 3.0, "roughness_m": 0.01, "c_s": c}
             for i, c in enumerate([0.5, 0.1, None, 0.3, 0.9, 0.2, 0.7])]
    (v / "landing_summary.json").write_text(json.dumps({"table_v": {"number_of_sites": 7}, "final_sites": sites}))
    md = "\n".join(result_lines({"landing": str(v)}))
    rows = [r for r in _rows(md, "s") if r[0] != "submap"]
    assert [r[0] for r in rows] == ["s1", "s5", "s3", "s0", "s6"]  # 5 best by c_s; the one without a cost last
    assert rows[0][2] == "11.3371176 N, 142.2097166 E"  # a 0.32 m site: 7 decimals (1 cm), not 3 (110 m)
    assert "Best landing sites (5 of 7" in md and "Table V: number of sites 7" in md


def test_report_link_and_published_table_and_unreadable_products(tmp_path):
    rep = tmp_path / "report" / "v002"
    rep.mkdir(parents=True)
    (rep / "report.html").write_text("<html></html>")
    (rep / "manifest.json").write_text(json.dumps({"files": [{"name": "report.html", "bytes": 13}]}))
    broken = tmp_path / "match" / "v001"
    broken.mkdir(parents=True)
    md = artifact_markdown("report", "d1", {"report": str(rep), "match": str(broken)}, 1.5, [])
    assert f"[report.html]({(rep / 'report.html').resolve().as_uri()})" in md
    assert "| report | v002 | 1 | 0.0 |" in md
    assert "(results not shown: FileNotFoundError" in md  # never an exception: the artifact still says the rest


def test_coordinate_precision_follows_the_size_located():
    assert deg_decimals(30.0) == 5 and deg_decimals(0.32) == 7 and deg_decimals(float("nan")) == 6
    assert latlon(-11.5, -0.25, 2) == "11.50 S, 0.25 W" and latlon(None, 1, 2) == "-"
