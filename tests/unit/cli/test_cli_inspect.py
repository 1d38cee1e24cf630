"""``hadal inspect`` says what ``mbinfo`` says first (issue 46): time span, bounds at the data's precision (not 17
digits), depth range and counts; a corrupt or truncated file is a non-zero exit.

Oracle: MB-System's own ``mbinfo`` summary of the EM120 ``.all`` file (``formats-real/*.mb56.inf``, written by
``mbinfo``, not by hadal): records (pings), beams, good beams, depth limits, start/end time, lon/lat limits.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import pytest
from cli_runner import run_cli

EM120 = "formats-real/mbsys_nbp1403-filtered-em120.all"
EM120_INF = "formats-real/mbsys_nbp1403-filtered-em120.mb56.inf"


def _inf(text: str) -> dict[str, float | str]:
    """The numbers of an mbinfo ``.inf`` summary that inspect must match."""
    def num(pattern: str) -> float:
        m = re.search(pattern, text)
        assert m, pattern
        return float(m.group(1))

    times = re.findall(r"Time:.*\((\d{4}-\d\d-\d\dT[\d:.]+)\)", text)
    return {
        "records": num(r"Number of Records:\s+(\d+)"),
        "beams": num(r"Bathymetry Data.*\n\s+Number of Beams:\s+(\d+)"),
        "good": num(r"Bathymetry Data.*\n.*\n\s+Number of Good Beams:\s+(\d+)"),
        "min_depth": num(r"Minimum Depth:\s+([-\d.]+)"), "max_depth": num(r"Maximum Depth:\s+([-\d.]+)"),
        "min_lon": num(r"Minimum Longitude:\s+([-\d.]+)"), "max_lon": num(r"Maximum Longitude:\s+([-\d.]+)"),
        "min_lat": num(r"Minimum Latitude:\s+([-\d.]+)"), "max_lat": num(r"Maximum Latitude:\s+([-\d.]+)"),
        "start": times[0], "end": times[1],
    }


def _floats(text: str) -> list[float]:
    return [float(x) for x in re.findall(r"-?\d+\.\d+", text)]


def test_inspect_em120_says_what_mbinfo_says(shared_data):
    f = shared_data / EM120
    if not f.is_file():
        pytest.skip(f"{EM120} not in this copy of the shared data")
    ref = _inf((shared_data / EM120_INF).read_text())
    res = run_cli("inspect", "--json", str(f))
    assert res.returncode == 0, res.stderr
    ov = json.loads(res.stdout)[0]["overview"]
    # counts: mbinfo's records x beams, good beams
    pings, per, total, good = map(int, re.match(r"(\d+) ping\(s\) x (\d+) beams = (\d+) beams, (\d+) good",
                                                ov["counts"]).groups())
    assert (pings, total, good) == (ref["records"], ref["beams"], ref["good"]) and pings * per == total
    # depth limits to the centimetre (mbinfo prints 4 decimals of the same float32 depths)
    assert _floats(ov["depth"]) == pytest.approx([ref["min_depth"], ref["max_depth"]], abs=0.006)
    # time span: mbinfo's start and end, to the millisecond
    assert ov["time"].startswith(ref["start"][:23]) and ref["end"][:23] in ov["time"], (ov["time"], ref)
    assert "(17.487 s)" in ov["time"]
    # bounds: 6 decimals of a degree (about 0.1 m), not the float's 17 digits; within 0.001 deg of mbinfo's (the two
    # place the outer beams from the same datagrams with different beam geometry: up to ~70 m on a 7 km swath)
    lon0, lon1, lat0, lat1 = _floats(ov["bounds"])
    assert all(len(x.split(".")[1]) == 6 for x in re.findall(r"-?\d+\.\d+", ov["bounds"])), ov["bounds"]
    assert [lon0, lon1, lat0, lat1] == pytest.approx(
        [ref["min_lon"], ref["max_lon"], ref["min_lat"], ref["max_lat"]], abs=1e-3)
    table = run_cli("inspect", str(f))  # the terminal table shows the same overview, no long floats
    assert table.returncode == 0 and "2581.32 to 3051.72 m" in table.stdout, table.stdout
    assert not re.search(r"\d\.\d{10,}", table.stdout), table.stdout


def test_inspect_grid_bounds_at_the_cell_precision(shared_data):
    f = shared_data / "formats-real/gmt_depth_pixel.nc"
    if not f.is_file():
        pytest.skip("gmt_depth_pixel.nc not in this copy of the shared data")
    res = run_cli("inspect", "--json", str(f))
    assert res.returncode == 0, res.stderr
    ov = json.loads(res.stdout)[0]["overview"]
    # PROVENANCE.md (GMT's grid): 1050 x 750, pixel registration, lon -30..5, lat -30..-5, z -6585..716 m
    assert ov["bounds"] == "lon -30.000 to 5.000, lat -30.000 to -5.000 (degrees)"  # 2 arc-min cells: 3 decimals
    assert ov["counts"].startswith("1050 x 750 cells") and _floats(ov["z"]) == [-6585.0, 716.0]


@pytest.mark.parametrize("cut", [0.5, 0.95])
def test_inspect_a_truncated_multibeam_file_exits_non_zero(shared_data, tmp_path, cut):
    f = shared_data / EM120
    if not f.is_file():
        pytest.skip(f"{EM120} not in this copy of the shared data")
    data = f.read_bytes()
    bad = tmp_path / "cut.all"
    bad.write_bytes(data[: int(len(data) * cut)])
    res = run_cli("inspect", str(bad), str(f))
    assert res.returncode == 2, (res.stdout, res.stderr)
    assert "Traceback" not in res.stderr + res.stdout
    errs = [ln for ln in res.stderr.splitlines() if ln.startswith("error:")]
    assert len(errs) == 1 and "1 of 2 file(s) cannot be read" in errs[0] and str(bad) in errs[0], res.stderr
    assert "truncated" in res.stdout  # the table says why, per file


def test_overview_of_soundings_without_pings(tmp_path):
    from hadal.inspect import inspect_file

    f = tmp_path / "soundings.xyz"
    f.write_text("142.123456789 11.2 8123.456\n142.2 11.312345678 8124.0\n142.3 11.3 8125.5\n")
    ov = inspect_file(Path(f))["overview"]
    assert ov["bounds"] == "lon 142.123457 to 142.300000, lat 11.200000 to 11.312346 (degrees)"
    assert ov["depth"] == "8123.46 to 8125.50 m" and ov["counts"] == "3 beams, 3 good (100.00 %)"
