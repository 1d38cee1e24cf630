"""Run the IOOS compliance-checker (CF-1.8 and ACDD-1.3; IOOS-1.2 on request) on a product file.

``compliance-checker`` is an optional (test) dependency; it is imported only when you call
:func:`check_compliance`. Usage::

    from hadal.products.compliance import check_compliance
    rep = check_compliance("data/processed/<dive>/dtm/v001/dtm.nc")
    assert rep.ok, rep.describe()

Two findings are *documented exceptions* (``Finding.allowed``), not defects of the writer:

* ACDD "variable missing standard_name" for quantities the CF Standard Name Table has no entry for
  (declared with ``no_cf_standard_name: true`` in the variable registry, ``schemas/variables.yaml``, see
  :func:`hadal.registry.has_no_cf_standard_name`: gravity, topographic entropy, MSD, scores, ...).
  Inventing a standard name would instead fail CF §3.3.
* ACDD "<attribute> not present" for operator metadata (creator, institution, licence, ...) that the dive's
  ``dive.yaml`` does not give: hadal never invents it, and the file lists exactly those attributes in its
  ``hadal_metadata_missing`` attribute (``hadal config --check`` lists the required ones).
* ACDD "geospatial_vertical_extents_match: Could not find vertical variable" for 2-D seafloor grids
  (DTM, suitability, landing maps): their vertical extent is the range of the seafloor depth
  *field*, which CF does not model as a vertical coordinate.
* ACDD "geospatial_vertical_* not present" for products with no vertical information at all (e.g. the
  MSD surface over candidate horizontal positions); :func:`hadal.products.io.write_netcdf` writes the
  vertical attributes whenever the data have a vertical coordinate or a depth field.

IOOS-1.2 (``checkers=IOOS_CHECKERS``; high-priority checks, see ``tests/unit/products/test_products_ioos.py``). Every product
carries the IOOS attribution attributes, a ``platform`` container variable and ``Conventions`` with IOOS-1.2;
these high-priority findings are documented exceptions (not applicable, or not the writer's to fix):

* "NDBC/GTS Ingest Requirements": the checker fails it always, to list the variables that qualify for GTS
  ingest (compliance-checker#759); no hadal product is meant for the GTS.
* "<attribute>: <attribute> not present" for IOOS operator attributes (``creator_country``, ``creator_sector``,
  ``infoUrl``, ...) that ``dive.yaml`` does not give: listed in ``hadal_metadata_missing`` like the ACDD ones;
  likewise "platform ... it is None" when dive.yaml names no platform (vehicle).
* "featureType not present" and "CF DSG: Invalid featureType" on grids (DTM, laser grids, suitability, landing
  maps, MSD surface): a grid is not a CF Discrete Sampling Geometry, and CF allows ``featureType`` only on DSGs.

Binned casts are CF ragged arrays with depth as their Z axis (:mod:`hadal.products.dsg`: one profile per instance,
the descent and ascent of a dive a trajectoryProfile), so IOOS-1.2's one-profile-per-file and length-only vertical
coordinate checks pass and are no exceptions.

The NCAS cf-checker (``cfchecker``, :func:`run_cfchecks`) is run on the same files in the integration tests; it
needs the UDUNITS-2 C library (Debian ``libudunits2-0``) and the CF tables, which it downloads unless given: the
standard-name table bundled with compliance-checker is passed, and empty area-type / region tables (no hadal
product uses either).
"""

from __future__ import annotations

import re
import warnings
from dataclasses import dataclass, field
from pathlib import Path

from hadal.errors import InputError
from hadal.products.cf import has_no_cf_standard_name

DEFAULT_CHECKERS = ("cf:1.8", "acdd:1.3")
IOOS_CHECKERS = ("cf:1.8", "acdd:1.3", "ioos:1.2")
PRIORITY = {3: "high", 2: "medium", 1: "low"}


@dataclass(frozen=True)
class Finding:
    checker: str
    priority: str
    name: str
    messages: tuple[str, ...]
    allowed: bool = False

    def __str__(self) -> str:
        tag = " (documented exception)" if self.allowed else ""
        return f"[{self.checker} {self.priority}] {self.name}: {'; '.join(self.messages)}{tag}"


@dataclass
class ComplianceReport:
    path: Path
    findings: list[Finding] = field(default_factory=list)
    errors: dict[str, str] = field(default_factory=dict)  # check that raised -> exception text

    @property
    def failures(self) -> list[Finding]:
        """Findings that are not documented exceptions (any priority)."""
        return [f for f in self.findings if not f.allowed]

    @property
    def ok(self) -> bool:
        """No checker errors and no failed check other than the documented exceptions."""
        return not self.errors and not self.failures

    def describe(self) -> str:
        lines = [f"{self.path}:"]
        lines += [f"  ERROR in {k}: {v}" for k, v in self.errors.items()]
        lines += [f"  {f}" for f in self.findings]
        return "\n".join(lines)


def _allowed(checker: str, name: str, msgs: list[str], missing: frozenset[str] = frozenset(),
             grid: bool = False) -> bool:
    if checker.startswith("ioos"):
        return _allowed_ioos(name, msgs, missing, grid)
    if checker.startswith("acdd") and name.startswith("variable ") and msgs == ["standard_name"]:
        m = re.match(r'variable "([^"]+)"', name)
        return bool(m and has_no_cf_standard_name(m.group(1)))
    if checker.startswith("acdd") and name == "Global Attributes":
        # no vertical information at all; or operator metadata the dive did not give (listed in the file's
        # hadal_metadata_missing)
        return all(re.fullmatch(r"geospatial_(bounds_)?vertical_\w+ not present", m)
                   or ((g := re.fullmatch(r"(\w+) not present", m)) is not None and g.group(1) in missing)
                   for m in msgs)
    if checker.startswith("acdd") and name == "geospatial_vertical_extents_match":
        return all(m.startswith("Could not find vertical variable") for m in msgs)
    return False


def _allowed_ioos(name: str, msgs: list[str], missing: frozenset[str], grid: bool) -> bool:
    """The documented IOOS-1.2 exceptions (module docstring)."""
    if name == "NDBC/GTS Ingest Requirements":
        return all(m.startswith("The following variables qualified for NDBC/GTS Ingest") for m in msgs)
    if name in missing and msgs == [f"{name} not present"]:
        return True
    if name == "platform" and "platform" in missing:  # dive.yaml names no platform: listed, not invented
        return all(m.endswith("it is None") for m in msgs)
    if grid and name in ("featureType", "CF DSG: Invalid featureType"):
        return True
    return False


def check_compliance(path: str | Path, checkers: tuple[str, ...] = DEFAULT_CHECKERS) -> ComplianceReport:
    """Run the compliance-checker suites ``checkers`` on ``path`` and collect every failed check."""
    path = Path(path)
    if not path.is_file():
        raise InputError(f"{path} does not exist")
    try:
        from compliance_checker.runner import CheckSuite
    except ImportError:  # pragma: no cover - optional dependency
        raise InputError("compliance-checker is not installed (pip install compliance-checker)") from None
    suite = CheckSuite()
    suite.load_all_available_checkers()
    report = ComplianceReport(path)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        ds = suite.load_dataset(str(path))
        missing = frozenset(str(getattr(ds, "hadal_metadata_missing", "") or "").split())
        grid = str(getattr(ds, "cdm_data_type", "")) == "Grid" and not getattr(ds, "featureType", None)
        try:
            groups = suite.run_all(ds, list(checkers), skip_checks=[])
        finally:
            close = getattr(ds, "close", None)
            if close:
                close()
    for checker, (results, errors) in groups.items():
        for check, (exc, _tb) in (errors or {}).items():
            report.errors[f"{checker}:{check}"] = f"{type(exc).__name__}: {exc}"
        for r in results:
            value = r.value
            failed = (value[0] != value[1]) if isinstance(value, tuple) else not value
            if failed:
                msgs = [str(m) for m in r.msgs]
                report.findings.append(Finding(checker, PRIORITY.get(r.weight, str(r.weight)), str(r.name),
                                               tuple(msgs), _allowed(checker, str(r.name), msgs, missing, grid)))
    return report


_EMPTY_TABLE = '<?xml version="1.0"?>\n<{tag}><version_number>0</version_number><date>none</date></{tag}>\n'


def run_cfchecks(path: str | Path, workdir: str | Path) -> tuple[list[str], list[str]]:
    """(errors, warnings) of the NCAS cf-checker (``cfchecks``, CF version from the file's ``Conventions``) on
    ``path``, offline: compliance-checker's bundled standard-name table, empty area-type and region tables
    written into ``workdir``. :class:`InputError` when cfchecker (or its UDUNITS-2 library) is not installed."""
    import importlib.resources
    import io
    from contextlib import redirect_stdout

    try:
        from cfchecker.cfchecks import CFChecker, CFVersion
    except (ImportError, OSError, FileNotFoundError) as exc:  # cfunits raises when libudunits2 is missing
        raise InputError(f"cfchecker is not usable here ({type(exc).__name__}: {exc})") from None
    workdir = Path(workdir)
    area, region = workdir / "cf-area-types.xml", workdir / "cf-regions.xml"
    area.write_text(_EMPTY_TABLE.format(tag="area_type_table"), encoding="utf-8")
    region.write_text(_EMPTY_TABLE.format(tag="standardized_region_list"), encoding="utf-8")
    names = importlib.resources.files("compliance_checker") / "data" / "cf-standard-name-table.xml"
    checker = CFChecker(cfStandardNamesXML=str(names), cfAreaTypesXML=str(area), cfRegionNamesXML=str(region),
                        version=CFVersion(), silent=True)  # CFVersion(): the file's Conventions
    with redirect_stdout(io.StringIO()):
        res = checker.checker(str(path))
    errors = [f"{res_key}: {m}" for res_key, r in _cf_results(res) for m in r.get("ERROR", []) + r.get("FATAL", [])]
    warns = [f"{res_key}: {m}" for res_key, r in _cf_results(res) for m in r.get("WARN", [])]
    return errors, warns


def _cf_results(res: dict) -> list[tuple[str, dict]]:
    """The global and per-variable result blocks of a ``CFChecker.checker`` result."""
    out = [("global", res.get("global") or {})]
    out += [(str(k), v) for k, v in (res.get("variables") or {}).items()]
    return out
