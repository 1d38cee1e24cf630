"""Discovery metadata (ACDD-1.3) of the products, from the dive's ``dive.yaml`` - never invented.

* Who made the data (``creator_*``, ``institution``, ``project``, ``license``, ...) comes from ``dive.yaml``
  ``metadata`` (:class:`hadal.dive.DiveMetadata`), else from ``HADAL_<ATTRIBUTE>`` environment variables (a
  deployment's operator). Nothing else: a field given nowhere is left out of the product and listed in its
  ``hadal_metadata_missing`` attribute; :func:`missing_acdd_fields` lists the required ones for ``hadal config
  --check``.
* What hadal knows for certain (``source``, ``processing_level``, ``references`` of the method papers, the
  GCMD vocabularies) is written always. ``instrument`` is per product (:data:`PRODUCT_INSTRUMENTS`, overridden
  per product by ``metadata.instruments``): the DTM names the multibeam echosounder, the CTD products the CTD.
* IOOS-1.2 (:data:`IOOS_REQUIRED`, asked of the dive like the ACDD required ones): ``creator_country``,
  ``creator_sector``, ``infoUrl`` (``publisher_country`` follows the creator's); the global ``platform`` is a term
  of the IOOS platform vocabulary (``metadata.platform_type``, default ``submersible``; IOOS disallows GCMD
  keywords there), ``platform_id`` the vehicle name's letters and digits, and the GCMD platform keyword goes to
  the products' ``platform`` container variable (:func:`hadal.products.io.prepare_dataset`).
* :func:`dive_context` makes a stage's dive (and raw directory) known to the writers while it runs
  (``hadal.pipeline.run_stage``); provenance then records input paths relative to the raw directory.
"""

from __future__ import annotations

import contextlib
import contextvars
import json
import os
import re
from collections.abc import Iterator, Mapping
from pathlib import Path
from typing import Any

#: ACDD attributes a dive must give (``hadal config --check`` lists the missing ones)
ACDD_REQUIRED: tuple[str, ...] = ("creator_name", "creator_email", "institution", "project", "license")
#: IOOS-1.2 attributes (required there: high priority in the IOOS compliance-checker) only the operator can give,
#: beyond the ACDD ones; ``hadal config --check`` lists them too. The other IOOS-required operator attributes follow
#: from these: ``creator_institution`` = ``institution``, ``publisher_*`` = the creator's unless given.
IOOS_REQUIRED: tuple[str, ...] = ("creator_country", "creator_sector", "infoUrl", "creator_url", "naming_authority")
#: every attribute ``hadal config --check`` asks dive.yaml ``metadata`` for
REQUIRED_FIELDS: tuple[str, ...] = (*ACDD_REQUIRED, *IOOS_REQUIRED)
#: IOOS-1.2 required attributes checked in a product's final attributes (``hadal_metadata_missing``)
IOOS_PRODUCT_REQUIRED: tuple[str, ...] = (*IOOS_REQUIRED, "creator_institution", "publisher_country",
                                          "publisher_institution", "platform_name")
#: the IOOS platform vocabulary (IOOS-1.2: ``platform`` is one of its terms, no GCMD keyword) and hadal's default
IOOS_PLATFORM_VOCABULARY = "https://mmisw.org/ont/ioos/platform"
IOOS_PLATFORM_DEFAULT = "submersible"
#: NERC G04 (ISO 19115 CI_RoleCode): the vocabulary of ``contributor_role`` (IOOS-1.2 default)
CONTRIBUTOR_ROLE_VOCABULARY = "https://vocab.nerc.ac.uk/collection/G04/current/"
#: ACDD "recommended" attributes taken from the dive when given (the compliance checker asks for them)
ACDD_RECOMMENDED: tuple[str, ...] = ("creator_url", "naming_authority", "publisher_name", "publisher_email",
                                     "publisher_url")
#: ACDD "suggested" attributes (compliance-checker: low priority) listed as missing when nobody gives them
ACDD_SUGGESTED: tuple[str, ...] = ("creator_type", "creator_institution", "publisher_type", "publisher_institution",
                                   "program", "metadata_link", "platform", "platform_vocabulary", "instrument",
                                   "instrument_vocabulary")
#: every operator attribute read from dive.yaml ``metadata`` / ``HADAL_<NAME>``
OPERATOR_FIELDS: tuple[str, ...] = tuple(dict.fromkeys((
    *ACDD_REQUIRED, *ACDD_RECOMMENDED, *IOOS_REQUIRED, "creator_type", "creator_institution", "publisher_type",
    "publisher_institution", "publisher_country", "program", "acknowledgment", "contributor_name", "contributor_role",
    "cruise", "metadata_link")))

#: facts about every hadal product (not about its operator): always written
HADAL_FACTS: dict[str, str] = {
    "keywords": (
        "EARTH SCIENCE > OCEANS > BATHYMETRY/SEAFLOOR TOPOGRAPHY > BATHYMETRY, "
        "EARTH SCIENCE > OCEANS > OCEAN PRESSURE > WATER PRESSURE, "
        "EARTH SCIENCE > OCEANS > OCEAN TEMPERATURE > WATER TEMPERATURE, "
        "EARTH SCIENCE > OCEANS > SALINITY/DENSITY > SALINITY, hadal, deep-sea vehicle"
    ),
    "keywords_vocabulary": "GCMD:GCMD Keywords",
    "acknowledgment": "Processed with the hadal post-dive pipeline.",
    "contributor_name": "hadal post-dive pipeline",
    "contributor_role": "processor",
    "contributor_role_vocabulary": CONTRIBUTOR_ROLE_VOCABULARY,
    "processing_level": "L2: geophysical variables derived from vehicle sensors",
    "references": ("Zhang et al., TERCOM terrain matching at the Challenger Deep; MRF terrain matching; "
                   "Sangekar et al., AUV landing-site detection in laser bathymetry"),
    "comment": "Product of the hadal pipeline; provenance in hadal_provenance and the version's manifest.json.",
}

_CTD = "In Situ/Laboratory Instruments > Profilers/Sounders > CTD"
_MULTIBEAM = "Active Remote Sensing > Profilers/Sounders > Acoustic Sounders > MULTIBEAM ECHO SOUNDERS"
_LASER = "Active Remote Sensing > Profilers/Sounders > Lidar/Laser Sounders > LIDAR"
_ALTIMETER = "Active Remote Sensing > Profilers/Sounders > Acoustic Sounders > ALTIMETERS"
_DVL = "In Situ/Laboratory Instruments > Current/Wind Meters > ADCP"
_TSG = "In Situ/Laboratory Instruments > Conductivity Sensors > THERMOSALINOGRAPHS"
#: GCMD instrument keywords of each product (its measuring instruments); ``metadata.instruments`` overrides
PRODUCT_INSTRUMENTS: dict[str, str] = {
    "sensors": f"{_CTD}, {_ALTIMETER}, {_DVL}",
    "ctd": _CTD, "profile": _CTD, "casts": _CTD, "cast_profiles": _CTD,
    "trajectory": _TSG,
    "dtm": _MULTIBEAM, "suitability": _MULTIBEAM,
    "laser_grids": _LASER, "landing": _LASER,
    "match": f"{_MULTIBEAM}, {_ALTIMETER}, {_CTD}",
    "navigation": f"{_DVL}, {_ALTIMETER}, {_CTD}, {_MULTIBEAM}",
}
#: products measured by another product's instrument (``metadata.instruments`` names the instrument once)
INSTRUMENT_OF: dict[str, str] = {"sensors": "ctd", "profile": "ctd", "casts": "ctd", "cast_profiles": "ctd",
                                 "suitability": "dtm", "landing": "laser_grids"}
_GCMD_AUV = "Subsurface Vehicles > AUV"

_DIVE: contextvars.ContextVar[tuple[Any, Path | None] | None] = contextvars.ContextVar("hadal_dive", default=None)


@contextlib.contextmanager
def dive_context(dive: Any, raw_dir: str | os.PathLike[str] | None = None) -> Iterator[None]:
    """Make ``dive`` (a :class:`hadal.dive.Dive`) and its raw directory known to the product writers."""
    token = _DIVE.set((dive, Path(raw_dir).resolve() if raw_dir is not None else None))
    try:
        yield
    finally:
        _DIVE.reset(token)


def current_dive(path: Path | None = None) -> tuple[Any, Path | None]:
    """(dive, raw_dir) of the running stage, else of the store the file ``path`` is written into (its
    ``<dive>/dive.json`` record), else ``(None, None)``."""
    cur = _DIVE.get()
    if cur is not None:
        return cur
    if path is None:
        return None, None
    parent = Path(path).parent
    if not (parent.name.startswith(".staging-") or re.fullmatch(r"v\d{3,}", parent.name)):
        return None, None
    rec = parent.parent.parent / "dive.json"
    try:
        raw = Path(json.loads(rec.read_text(encoding="utf-8"))["raw_dir"])
        from hadal.dive import load_dive

        dive, raw = load_dive(raw)
    except Exception:  # noqa: BLE001 - no record / moved raw directory: the product says what it lacks
        return None, None
    return dive, raw


def operator_attributes(dive: Any = None) -> dict[str, str]:
    """Operator attributes: ``dive.yaml`` ``metadata``, else ``HADAL_<NAME>`` environment variables."""
    out: dict[str, str] = {}
    for key in OPERATOR_FIELDS:
        env = os.environ.get(f"HADAL_{key.upper()}")
        if env:
            out[key] = env
    md = getattr(dive, "metadata", None)
    if md is not None:
        out.update({k: str(v) for k, v in md.model_dump(
            exclude={"instruments", "platform_vocabulary_name", "platform_type"}).items() if v not in (None, "")})
    if "creator_institution" not in out and "institution" in out:
        out["creator_institution"] = out["institution"]
    return out


def missing_acdd_fields(dive: Any, recommended: bool = False) -> list[str]:
    """The required ACDD-1.3 and IOOS-1.2 attributes (:data:`REQUIRED_FIELDS`; with ``recommended``: also the
    recommended ACDD ones) that neither ``dive.yaml`` ``metadata`` nor a ``HADAL_<NAME>`` environment variable
    gives; ``platform`` when dive.yaml names no platform (the vehicle; IOOS-1.2 requires ``platform_name``)."""
    have = operator_attributes(dive)
    want = dict.fromkeys(REQUIRED_FIELDS + (ACDD_RECOMMENDED if recommended else ()))
    out = [k for k in want if k not in have]
    if dive is not None and getattr(dive, "platform", None) in (None, "", "unknown"):
        out.append("platform")  # dive.yaml's top-level platform (the vehicle): IOOS-1.2 platform/platform_name
    return out


def product_attributes(dive: Any, product: str | None, given: Mapping[str, Any] | None = None) -> dict[str, Any]:
    """Discovery attributes of one product of ``dive``: hadal's facts, the operator's attributes, platform and
    the product's instrument; ``hadal_metadata_missing`` names the ACDD fields nobody gave."""
    given = dict(given or {})
    out: dict[str, Any] = dict(HADAL_FACTS)
    out.update(operator_attributes(dive))
    md = getattr(dive, "metadata", None)
    platform = getattr(dive, "platform", None) or given.get("platform_name")
    if platform and platform != "unknown":
        out["platform_name"] = platform
    if platform and platform != "unknown":
        # IOOS-1.2: `platform` is a term of the IOOS platform vocabulary (a URL; GCMD keywords, which have blanks,
        # are not allowed there); ACDD-1.3 accepts any vocabulary. The GCMD keyword goes to the platform variable.
        out["platform"] = getattr(md, "platform_type", None) or IOOS_PLATFORM_DEFAULT
        out["platform_vocabulary"] = IOOS_PLATFORM_VOCABULARY
        out["platform_id"] = re.sub(r"[^A-Za-z0-9]", "", str(platform)) or None
        out["hadal_platform_gcmd"] = getattr(md, "platform_vocabulary_name", None) or _GCMD_AUV
    instruments = dict(getattr(md, "instruments", None) or {})
    inst = instruments.get(product or "") or instruments.get(INSTRUMENT_OF.get(product or "", "")) or \
        PRODUCT_INSTRUMENTS.get(product or "")
    if given.get("dtm_source") == "prior_grid" and product in ("dtm", "suitability") and product not in instruments:
        inst = None  # a compiled prior grid: no instrument of this dive measured it
    if inst:
        out["instrument"] = inst
        out["instrument_vocabulary"] = ("GCMD:GCMD Instruments" if all(
            part.strip() in _gcmd_parts() for part in inst.split(",")) else "none (free text of dive.yaml "
                                                                               "metadata.instruments)")
    if "publisher_name" not in out and "creator_name" in out:
        # the creator publishes unless the dive names a publisher (ACDD: publisher = who distributes the data)
        for a, b in (("publisher_name", "creator_name"), ("publisher_email", "creator_email"),
                     ("publisher_url", "creator_url"), ("publisher_type", "creator_type"),
                     ("publisher_institution", "creator_institution"), ("publisher_country", "creator_country")):
            if b in out:
                out[a] = out[b]
    return out


def metadata_missing(attrs: Mapping[str, Any]) -> str | None:
    """The ACDD attributes absent from a product's final global ``attrs`` (space-separated), or ``None``."""
    missing = [k for k in dict.fromkeys((*ACDD_REQUIRED, *ACDD_RECOMMENDED, *ACDD_SUGGESTED, *IOOS_PRODUCT_REQUIRED))
               if attrs.get(k) in (None, "")]
    return " ".join(missing) or None


def _gcmd_parts() -> set[str]:
    return {p.strip() for v in PRODUCT_INSTRUMENTS.values() for p in v.split(",")}


def relative_to_raw(path: str | os.PathLike[str], raw_dir: Path | None) -> str:
    """``path`` relative to the dive's raw directory when inside it (else its file name: no machine paths)."""
    p = Path(path)
    if raw_dir is not None:
        try:
            return p.resolve().relative_to(raw_dir).as_posix()
        except (ValueError, OSError):
            pass
    return p.as_posix() if not p.is_absolute() else p.name


def store_relative(path: str | os.PathLike[str]) -> str:
    """A store path as ``<dive>/<product>/<version>`` (the store root is machine-specific)."""
    parts = Path(path).parts
    return "/".join(parts[-3:]) if len(parts) >= 3 else Path(path).as_posix()


