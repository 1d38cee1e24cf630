"""Integration tier (issue 46 acceptance): every NetCDF product of the sample dive and of real dives checked with the
field's own tools - the IOOS compliance-checker (cf:1.8, acdd:1.3, ioos:1.2) with no high-priority failure but the
documented exceptions of :mod:`hadal.products.compliance` (none about metadata when dive.yaml gives it all), and
the NCAS cf-checker (``cfchecks``) with no error. Slow (full pipeline runs): ``make test-integration``.
"""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest
import yaml

pytest.importorskip("compliance_checker")

from dive_runs import init_dive, run_quiet  # noqa: E402

from hadal.errors import InputError  # noqa: E402
from hadal.products.compliance import IOOS_CHECKERS, check_compliance, run_cfchecks  # noqa: E402

pytestmark = pytest.mark.integration

#: IOOS-1.2 attributes the sample dive's metadata lacks (hadal config --check names them)
COMPLETE = {"creator_country": "Germany", "creator_sector": "other", "infoUrl": "https://example.org/hadal-sample"}
GTS = "NDBC/GTS Ingest Requirements"
GRID_ONLY = {"featureType"}  # IOOS asks every file for a featureType; CF allows it only on DSGs (not on grids)

#: real dives (files of ../shared/data, alone) and the NetCDF files their products must include
REAL = {"dives-real/oce_SBE25_ctd.cnv": {"profile.nc"},
        "dives-real/seabird_SBE21_TSG_PIR_010.cnv": set(),  # an underway record: <record id>.nc trajectory
        "dives-real/gmt_HI_topo_04.nc": {"dtm.nc", "suitability.nc"},
        "dives-real/pdal_autzen-utm.las": set(),  # a grid on the file's own UTM CRS: footprint, grid mapping
        "dives-real/gutils_usf_bass_2016_252_1_14_sbd.dat": {"profile.nc"}}  # a glider's casts


def _cfchecks(path: Path, tmp_path: Path) -> list[str]:
    try:
        errors, _ = run_cfchecks(path, tmp_path)
    except InputError as exc:  # cfchecker or the UDUNITS-2 library missing here
        pytest.skip(str(exc))
    return errors


def _check_files(files: list[Path], tmp_path: Path, complete: bool) -> list[str]:
    bad = []
    for f in files:
        rep = check_compliance(f, IOOS_CHECKERS)
        with_grid = {x.name for x in rep.findings if x.priority == "high" and x.allowed and x.checker == "ioos:1.2"}
        failing = [str(x) for x in rep.findings if x.priority == "high" and not x.allowed]
        if rep.errors or failing:
            bad.append(rep.describe())
        if complete and not with_grid <= {GTS} | GRID_ONLY:
            bad.append(f"{f.name}: IOOS exceptions beyond GTS/grid with complete metadata: {sorted(with_grid)}")
        if errs := _cfchecks(f, tmp_path):
            bad.append(f"{f.name}: cfchecks errors: {errs}")
    return bad


def test_sample_dive_with_complete_metadata_passes_cf_acdd_ioos_and_cfchecks(small_dive, tmp_path):
    raw = tmp_path / "haidou-small"
    shutil.copytree(small_dive, raw)
    spec = yaml.safe_load((raw / "dive.yaml").read_text())
    spec["metadata"].update(COMPLETE)
    (raw / "dive.yaml").write_text(yaml.safe_dump(spec, sort_keys=False))
    from hadal.products import missing_acdd_fields

    ctx = run_quiet(raw, tmp_path / "store")
    assert missing_acdd_fields(ctx.dive) == []  # hadal config --check: nothing missing
    files = sorted((tmp_path / "store").rglob("v*/*.nc"))
    assert {f.name for f in files} >= {"dtm.nc", "profile.nc", "navigation.nc", "suitability.nc", "msd_surface.nc"}
    bad = _check_files(files, tmp_path, complete=True)
    assert not bad, "\n".join(bad)


@pytest.mark.parametrize("rel", sorted(REAL))
def test_real_dive_products_pass_cf_acdd_ioos_and_cfchecks(shared_data, tmp_path, rel):
    raw, _ = init_dive(shared_data, tmp_path, rel)
    run_quiet(raw, tmp_path / "store")
    files = sorted((tmp_path / "store").rglob("v*/*.nc"))
    assert files and REAL[rel] <= {f.name for f in files}, (rel, files)
    bad = _check_files(files, tmp_path, complete=False)  # dive.yaml from init: operator metadata missing (listed)
    assert not bad, "\n".join(bad)
