"""``hadal init RAW_DIR``: describe a dive directory from its files and write a commented ``dive.yaml``.

Every file under the directory is identified by content (:func:`hadal.formats.detect`) and described
(:func:`hadal.inspect.inspect_file`); each readable one is put in the ``sources`` list of its kind:

* MCAP / CSV vehicle logs -> ``mcap`` / ``csv``, with a ``vehicle.yaml`` channel mapping suggested from the
  message types, field names and units (:func:`hadal.ingest.suggest.suggest_vehicle`); logs of which no
  channel maps to a hadal variable are listed as not used;
* Sea-Bird ``.cnv`` (also compressed) and ``.hex`` -> ``cnv``;
* multibeam (xyz text, GSF, .kmall, .all, .s7k) -> ``multibeam``; xyz text in a small metric frame is laser
  bathymetry (see :func:`xyz_role`);
* rasters (GeoTIFF, NetCDF grids) -> ``laser`` when their cells are at most :data:`LASER_MAX_CELL_M` in a
  metric frame, else ``prior_grid`` (a geographic grid is always a prior grid); what the file leaves open is
  written as a commented hint (:func:`grid_hints`: ``z_positive: up  # guessed: ...``, ``z_units: m  # assumed``);
  a grid with no cell below sea level (a land DEM) is listed as not used, with why; point clouds (PLY, PCD,
  LAS/LAZ) -> ``laser``.

Positions come from the data where it has them: the map frame from the centre of the geographic extent of
the soundings/grids (or the cast position), the launch from ``--launch`` or a Sea-Bird header position.
What could not be mapped and what the user must still fill in is returned (and printed by the CLI).
"""

from __future__ import annotations

import datetime as _dt
import math
import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from hadal.dive import DIVE_FILE, Dive
from hadal.errors import ConfigError, InputError
from hadal.inspect import inspect_file
from hadal.roles import (
    all_finite,
    crs_kind,
    grid_role,
    lonlat_centre,
    xyz_role,
)

VEHICLE_FILE = "vehicle.yaml"
#: hadal's own files in a dive directory (never sources)
OWN_FILES = {DIVE_FILE, VEHICLE_FILE, "pipeline.yaml"}


@dataclass
class InitResult:
    """What :func:`scan_dive_dir` found: the dive.yaml content and the report for the user."""

    raw_dir: Path
    dive: dict[str, Any]
    vehicle_yaml: str | None = None
    files: list[dict[str, Any]] = field(default_factory=list)
    mapped: list[str] = field(default_factory=list)
    not_used: list[str] = field(default_factory=list)
    todo: list[str] = field(default_factory=list)
    #: the stages the data supports (:func:`hadal.stages.plan.plan_stages`), filled by :func:`scan_dive_dir`
    plan: list[Any] = field(default_factory=list)
    #: source path -> why its reading hints were written (a heuristic's choice): a comment above its entry
    source_notes: dict[str, str] = field(default_factory=dict)
    #: source path -> {hint: comment}: why a hint was written (a guess the file leaves open), as YAML comments
    source_comments: dict[str, dict[str, str]] = field(default_factory=dict)

    def dive_yaml(self) -> str:
        return render_dive_yaml(self)


def sanitise_dive_id(name: str) -> str:
    """A valid dive id from a directory name (letters, digits, ``._-``; at most 64 characters; the one name rule
    :func:`hadal.names.check_component`: a name the store keeps for itself, e.g. ``catalog.json``, becomes
    ``catalog-json``)."""
    from hadal.errors import StoreError
    from hadal.names import check_component

    s = re.sub(r"\.{2,}", ".", re.sub(r"[^A-Za-z0-9._-]+", "-", name)).strip(".-_")[:64]
    for candidate in (s, s.replace(".", "-")):
        try:
            return check_component(candidate, "dive id")
        except StoreError:
            continue
    raise ConfigError(f"cannot make a dive id from the directory name {name!r}; pass --dive-id")


def parse_latlon_pair(text: str) -> tuple[float, float]:
    """``"LAT,LON"`` in decimal degrees (``--launch``) -> ``(lat, lon)``, with a one-line error."""
    try:
        lat_s, lon_s = (t.strip() for t in text.split(","))
        lat, lon = float(lat_s), float(lon_s)
    except ValueError:
        raise ConfigError(f"--launch {text!r}: expected LAT,LON in decimal degrees, e.g. 11.3371,142.2097") from None
    if not (math.isfinite(lat) and -90 <= lat <= 90 and math.isfinite(lon) and -180 <= lon <= 180):
        raise ConfigError(f"--launch {text!r}: latitude must be within ±90 and longitude within ±180")
    return lat, lon


def _candidate_files(raw: Path) -> list[Path]:
    sample = (raw / "truth.json").is_file()  # a `hadal synth` sample: its ground truth is never a source
    out = []
    for p in sorted(raw.rglob("*")):
        rel = p.relative_to(raw)
        if any(part.startswith(".") for part in rel.parts):
            continue
        if sample and rel.parts[0] in ("truth", "truth.json"):
            continue
        if rel.as_posix() in OWN_FILES or not (p.is_file() or p.is_symlink()):
            continue
        out.append(p)
    return out


def xyz_hints(rel: str, info: dict[str, Any]) -> tuple[str | dict[str, Any], str]:
    """The ``dive.yaml`` entry of an xyz soundings file and why: what the reader could only guess from the values
    (lon/lat by their ranges, depth or elevation by the sign of the median; :func:`hadal.grid.sonar._iter_xyz`) is
    written as an explicit hint the user can change - ``crs: EPSG:4326`` for lon/lat, ``z_positive`` - so that the
    run does not depend on the guess. A header or a declared hint already said it: the plain path."""
    hints: dict[str, Any] = {}
    why: list[str] = []
    if info.get("crs_from") == "values" and info.get("crs_kind") == "geographic":
        lo, la = info.get("longitude_deg") or [None, None], info.get("latitude_deg") or [None, None]
        hints["crs"] = "EPSG:4326"
        span = (f" (x {lo[0]:.4g}..{lo[1]:.4g}, y {la[0]:.4g}..{la[1]:.4g})" if all_finite(*lo, *la) else "")
        why.append(f"x/y taken as longitude/latitude from their value ranges{span}: crs EPSG:4326")
    if info.get("z_positive_from") == "values" and info.get("z_positive") in ("up", "down"):
        hints["z_positive"] = info["z_positive"]
        why.append("z taken as " + ("elevation (negative median)" if info["z_positive"] == "up" else
                                    "depth (positive median)") + f": z_positive {info['z_positive']}")
    if not hints:
        return rel, ""
    return {"path": rel, **hints}, "guessed by hadal init, change if wrong: " + "; ".join(why)


#: casts whose header positions are within this distance (km) share one launch position
CASTS_TOGETHER_KM = 10.0


def _spread_km(positions: list[tuple[float, float, Any]]) -> float:
    """Largest distance (km) of a cast position from the first one (geodesic, WGS84)."""
    from pyproj import Geod

    g = Geod(ellps="WGS84")
    lat0, lon0 = positions[0][0], positions[0][1]
    return max((g.inv(lon0, lat0, lon, lat)[2] / 1000 for lat, lon, _ in positions[1:]), default=0.0)


def _lon_in(lon: float, lo: float, hi: float) -> bool:
    return any(lo <= lon + k <= hi for k in (-360.0, 0.0, 360.0))


def _lonlat_box(info: dict[str, Any]) -> tuple[float, float, float, float] | None:
    """(lon0, lon1, lat0, lat1) of a file's geographic extent, when its describer gives lon/lat ranges."""
    lo, la = info.get("longitude_deg"), info.get("latitude_deg")
    if isinstance(lo, (list, tuple)) and isinstance(la, (list, tuple)) and len(lo) == len(la) == 2 and all_finite(*lo, *la):
        return float(lo[0]), float(lo[1]), float(la[0]), float(la[1])
    ext = info.get("extent")
    if crs_kind(info) == "geographic" and isinstance(ext, dict) and {"xmin", "xmax", "ymin", "ymax"} <= set(ext):
        return float(ext["xmin"]), float(ext["xmax"]), float(ext["ymin"]), float(ext["ymax"])
    return None


#: sources farther apart than this (km, geodesic, between the nearest points of their extents) do not overlap
SOURCES_APART_KM = 20.0
#: sources whose time spans are farther apart than this (hours) do not overlap in time
SOURCES_APART_H = 24.0
#: roles whose data is gridded or matched in the local map frame (a cast or a TSG track needs none)
_FRAME_ROLES = ("multibeam", "prior_grid", "laser")


@dataclass
class _Footprint:
    """Where and when one source file's data is: its geographic box and time span (when the file says)."""

    rel: str
    role: str  # cast | track | multibeam | prior_grid | laser
    box: tuple[float, float, float, float]  # lon0, lon1, lat0, lat1 (degrees; longitudes as the file gives them)
    t0: float | None = None  # s since the epoch
    t1: float | None = None
    first: tuple[float, float] | None = None  # (lat, lon) of a vehicle track's first position

    def centre(self) -> tuple[float, float]:
        """(lon, lat) of the box centre."""
        return (self.box[0] + self.box[1]) / 2, (self.box[2] + self.box[3]) / 2


@dataclass
class _Scan:
    """What :func:`_scan_files` gathered from the raw directory for :func:`scan_dive_dir`."""

    sources: dict[str, Any]
    centres: list[tuple[float, float]] = field(default_factory=list)
    cast_positions: list[tuple[float, float, str | None]] = field(default_factory=list)
    #: casts (not underway records) whose header gives no latitude at all (no NMEA/user line, no SeaSoft note)
    casts_without_latitude: list[str] = field(default_factory=list)
    logs_mcap: list[Path] = field(default_factory=list)
    logs_csv: dict[str, Path] = field(default_factory=dict)
    casts_seen: dict[tuple[Any, Any], tuple[str, str]] = field(default_factory=dict)
    extents: list[tuple[str, float, float, float, float]] = field(default_factory=list)  # rel, lon0, lon1, lat0, lat1
    footprints: list[_Footprint] = field(default_factory=list)


def scan_dive_dir(raw_dir: str | Path, *, dive_id: str | None = None,
                  launch: tuple[float, float] | None = None) -> InitResult:
    """Identify every file of ``raw_dir`` and build the dive.yaml content (nothing is written)."""
    raw = Path(raw_dir)
    if not raw.is_dir():
        raise InputError(f"raw dive directory {raw} does not exist" if not raw.exists()
                         else f"{raw} is not a directory")
    res = InitResult(raw.resolve(), {})
    scan = _Scan({"mcap": [], "csv": {}, "cnv": [], "multibeam": [], "prior_grid": [], "laser": []})
    _scan_files(res, scan, raw)
    sources = scan.sources
    track = _track_start(scan) if launch is None else None
    _map_vehicle_logs(res, sources, scan.logs_mcap, scan.logs_csv, raw, launch or (track[:2] if track else None))

    did = dive_id or sanitise_dive_id(raw.resolve().name)
    dive: dict[str, Any] = {"dive_id": did, "platform": "unknown"}
    if (raw / VEHICLE_FILE).is_file():
        dive["vehicle_config"] = VEHICLE_FILE
        res.mapped.append(f"{VEHICLE_FILE}: the existing mapping is used and kept (--force replaces it with the "
                          "suggested one)")
    elif res.vehicle_yaml is not None:
        dive["vehicle_config"] = VEHICLE_FILE
    _set_launch(res, dive, scan, launch, track)
    _set_map_frame(res, dive, scan)
    _check_overlap(res, scan.footprints)
    dive["sources"] = {k: v for k, v in sources.items() if v}
    res.dive = dive
    _todo(res, scan.casts_without_latitude)
    return res


def _scan_files(res: InitResult, scan: _Scan, raw: Path) -> None:
    """Inspect each candidate file of ``raw`` and map it to a source (or list it as not used)."""
    sources = scan.sources
    for p in _candidate_files(raw):
        rel = p.relative_to(raw).as_posix()
        info = inspect_file(p)
        info["path"] = rel
        res.files.append(info)
        kind = info.get("kind")
        if info.get("error"):
            res.not_used.append(f"{rel}: {info['error']}")
            continue
        if kind == "mcap":
            scan.logs_mcap.append(p)
        elif kind == "csv":
            scan.logs_csv[_csv_key(p, scan.logs_csv)] = p
        elif kind in ("cnv", "seabird_hex"):
            if not _map_cast(res, scan, rel, kind, info, p):
                continue
        elif kind in ("xyz", "gsf", "kmall", "em_all", "s7k"):
            if (point := _single_position(info)) is not None:  # e.g. libgsf's 3.09 test file: 3 pings at one fix
                res.not_used.append(f"{rel}: every sounding is at one position ({point}): no extent, nothing to "
                                    "grid")
                continue
            role = xyz_role(info) if kind == "xyz" else "multibeam"
            entry, note = xyz_hints(rel, info) if kind == "xyz" and role == "multibeam" else (rel, "")
            sources[role].append(entry)
            res.mapped.append(f"{rel}: {kind} -> sources.{role}" + (f" ({note})" if note else ""))
            if note:
                res.source_notes[rel] = note
        elif kind in ("geotiff", "netcdf"):
            if not _map_grid(res, sources, rel, kind, info):
                continue
        elif kind in ("ply", "pcd", "las"):
            _map_cloud(res, sources, rel, kind, info)
        else:
            res.not_used.append(f"{rel}: {info.get('description') or kind} (not a dive source)")
            continue
        # a projected point cloud keeps its own CRS (its laser grid is not in the map frame): no say in the frame
        projected_cloud = kind in ("ply", "pcd", "las") and crs_kind(info) != "geographic"
        if not projected_cloud:
            _add_footprint(scan, rel, kind, info)
        c = None if projected_cloud else lonlat_centre(info)
        if c is not None:
            scan.centres.append(c)
            if (box := _lonlat_box(info)) is not None:
                scan.extents.append((rel, *box))


def grid_hints(info: dict[str, Any]) -> dict[str, tuple[str, str]]:
    """The reading hints ``hadal init`` writes for a grid whose file leaves a gap: ``{hint: (value, comment)}``.
    A sign guessed from the values (:func:`hadal.grid.prior.z_positive`) -> ``z_positive``; no units in the file
    -> ``z_units: m``. Each comment says it was not read from the file, so the user can change it."""
    z: dict[str, Any] = info["z"] if isinstance(info.get("z"), dict) else {}
    out: dict[str, tuple[str, str]] = {}
    if z.get("sign_guessed") and z.get("positive") in ("up", "down"):
        out["z_positive"] = (z["positive"], f"{z.get('sign_reason', 'guessed')}; the file does not say: check it")
    if z.get("units_assumed"):
        out["z_units"] = ("m", "assumed: the file gives no units for its values")
    return out


def _map_grid(res: InitResult, sources: dict[str, Any], rel: str, kind: str, info: dict[str, Any]) -> bool:
    """Map a raster grid to ``sources.prior_grid`` or ``sources.laser`` (:func:`grid_role`), with the hints of
    :func:`grid_hints`; ``False`` when it has no seafloor to grid (a land DEM: listed as not used, with why)."""
    z: dict[str, Any] = info["z"] if isinstance(info.get("z"), dict) else {}
    if z.get("no_seafloor"):
        res.not_used.append(f"{rel}: {z['no_seafloor']}")
        return False
    role = grid_role(info)
    hints = grid_hints(info)
    if hints:
        sources[role].append({"path": rel, **{k: v for k, (v, _) in hints.items()}})
        res.source_comments[rel] = {k: c for k, (_, c) in hints.items()}
    else:
        sources[role].append(rel)
    how = "; ".join(f"{k}: {v} ({c})" for k, (v, c) in hints.items())
    # no square brackets: the CLI prints these lines through rich, which takes '[...]' for markup
    res.mapped.append(f"{rel}: {kind} grid -> sources.{role}" + (f"; hints: {how}" if how else ""))
    return True


def _single_position(info: dict[str, Any]) -> str | None:
    """``"LAT, LON"`` when a sonar file's soundings all lie at one position (its describer's longitude/latitude
    ranges have no width), else ``None``."""
    lon, lat = info.get("longitude_deg"), info.get("latitude_deg")
    if not (isinstance(lon, (list, tuple)) and isinstance(lat, (list, tuple)) and len(lon) == 2 and len(lat) == 2):
        return None
    if not (all_finite(*lon, *lat) and int(info.get("soundings") or 0) > 0):
        return None
    if lon[0] != lon[1] or lat[0] != lat[1]:
        return None
    return f"{float(lat[0]):.6f}, {float(lon[0]):.6f}"


def _map_cloud(res: InitResult, sources: dict[str, Any], rel: str, kind: str, info: dict[str, Any]) -> None:
    """Map a point cloud to ``sources.laser``. A cloud whose file carries no CRS (a LAS without GeoTIFF/WKT VLRs;
    PCD and PLY never carry one) is listed with ``crs: local`` and a comment: the reader's fallback (x/y/z in
    metres in the laser survey's local frame) written down as init's choice, for the user to replace with the
    survey's CRS (whose units then scale the cloud, e.g. US survey feet)."""
    if isinstance(info.get("crs"), dict):
        sources["laser"].append(rel)
        res.mapped.append(f"{rel}: {kind} point cloud -> sources.laser")
        return
    why = ("PCD/PLY carry no CRS" if kind in ("pcd", "ply") else "the file has no CRS (no GeoTIFF or WKT VLR)")
    comment = (f"hadal init's choice: {why}, so x/y/z are read as metres in the laser survey's local frame; "
               "set the survey's CRS (e.g. EPSG:2994) if you know it: its units then scale the cloud")
    sources["laser"].append({"path": rel, "crs": "local"})
    res.source_comments[rel] = {"crs": comment}
    res.mapped.append(f"{rel}: {kind} point cloud -> sources.laser; hints: crs: local ({comment})")


def _underway(path: Path) -> Any:
    """:func:`hadal.ctd.underway.underway_evidence` of a Sea-Bird file (``None`` when it cannot be read)."""
    import warnings

    from hadal.ctd.underway import underway_evidence
    from hadal.ingest.cnv import read_seabird

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            return underway_evidence(read_seabird(path))
    except InputError:
        return None


def _map_cast(res: InitResult, scan: _Scan, rel: str, kind: str, info: dict[str, Any], path: Path) -> bool:
    """Map a Sea-Bird cast to ``sources.cnv``; ``False`` when it duplicates a cast already kept. An underway record
    (:func:`hadal.ctd.underway.underway_evidence`: per-scan positions that move, constant pressure) is listed as
    ``{path, kind: underway}`` with the evidence as a comment, and its header position is no launch candidate."""
    sources, casts_seen = scan.sources, scan.casts_seen
    key = (info.get("start_time_utc"), info.get("scans"))
    if key[0] and key[1] and key in casts_seen:  # e.g. a .hex and SeaSoft's .cnv conversion of it
        other, other_kind = casts_seen[key]
        if kind == "cnv" and other_kind == "seabird_hex":  # keep SeaSoft's conversion, drop the raw file
            sources["cnv"].remove(other)
            res.mapped = [m for m in res.mapped if not m.startswith(f"{other}:")]
            res.not_used.append(f"{other}: the same cast as {rel} (same start time and {key[1]} scans); "
                                "the .cnv is used")
            casts_seen[key] = (rel, kind)
        else:
            res.not_used.append(f"{rel}: the same cast as {other} (same start time and {key[1]} scans)")
            return False
    else:
        casts_seen[key] = (rel, kind)
    ev = _underway(path) if kind == "cnv" else None
    if ev is not None and ev.underway:
        sources["cnv"].append({"path": rel, "kind": "underway"})
        res.source_notes[rel] = (f"kind: underway, hadal init's choice by hadal.ctd.underway's rule ({ev.reason}): "
                                 "published as a trajectory; set kind: cast to process it as a CTD cast")
        res.mapped.append(f"{rel}: Sea-Bird underway record ({kind}; {ev.reason}) -> sources.cnv, kind: underway")
        return True
    sources["cnv"].append(rel)
    res.mapped.append(f"{rel}: Sea-Bird cast ({kind}) -> sources.cnv")
    lat, lon = info.get("latitude_deg"), info.get("longitude_deg")
    if isinstance(lat, (int, float)) and isinstance(lon, (int, float)):
        scan.cast_positions.append((float(lat), float(lon), info.get("start_time_utc")))
    if not isinstance(lat, (int, float)):
        scan.casts_without_latitude.append(rel)
    return True


def _set_launch(res: InitResult, dive: dict[str, Any], scan: _Scan, launch: tuple[float, float] | None,
                track: tuple[float, float, str | None, str] | None = None) -> None:
    """Set ``dive["launch"]`` (given, else the first position of the vehicle's own track, else the casts' common
    header position) and check it against the extents."""
    cast_positions = scan.cast_positions
    if launch is not None:
        dive["launch"] = {"latitude_deg": launch[0], "longitude_deg": launch[1]}
    elif track is not None:
        lat, lon, t, rel = track
        dive["launch"] = {"latitude_deg": round(lat, 6), "longitude_deg": round(lon, 6)}
        if t:
            dive["launch"]["time_utc"] = t
        res.mapped.append(f"launch: the first position of the vehicle track in {rel} (also the origin of its "
                          "positions in vehicle.yaml)")
    elif cast_positions and _spread_km(cast_positions) <= CASTS_TOGETHER_KM:
        lat, lon, t = cast_positions[0]
        dive["launch"] = {"latitude_deg": round(lat, 6), "longitude_deg": round(lon, 6)}
        if t:
            dive["launch"]["time_utc"] = t
        first = next(c for c in scan.sources["cnv"] if isinstance(c, str))
        res.mapped.append("launch: the position in the Sea-Bird header of " + first)
    elif cast_positions:
        res.mapped.append(f"launch: not set, the casts are {_spread_km(cast_positions):.0f} km apart; each cast "
                          "uses the position in its own header")
    pos = (dive["launch"]["latitude_deg"], dive["launch"]["longitude_deg"]) if "launch" in dive else None
    for rel, lon0, lon1, lat0, lat1 in scan.extents if pos is not None else ():
        assert pos is not None
        if not (lat0 <= pos[0] <= lat1 and _lon_in(pos[1], lon0, lon1)):
            res.todo.append(f"the launch/cast position ({pos[0]:.4f}, {pos[1]:.4f}) lies outside {rel} "
                            f"(lon {lon0:.4f}..{lon1:.4f}, lat {lat0:.4f}..{lat1:.4f}): check that they belong to "
                            "one dive")


def _set_map_frame(res: InitResult, dive: dict[str, Any], scan: _Scan) -> None:
    """Set ``dive["map_frame"]`` where the data that is gridded or matched in it is, never halfway between
    sources that are apart. The sources that need a frame (soundings, grids, point clouds; the vehicle track the
    match follows) are grouped by :data:`SOURCES_APART_KM`; the group is the one holding the vehicle track and a
    grid, else the one with the soundings, else the largest. The origin is the centre of the vehicle track in that
    group, else the mean centre of its soundings, else the position of the casts on its grids (the dive's site: a
    cast beside a 1' grid is where the DTM and the suitability analysis are wanted), else the centre of its grids."""
    grids = [f for f in scan.footprints if f.role in _FRAME_ROLES]
    if not grids:
        if scan.centres:  # a position without an extent (no footprint): as before, the mean centre
            _frame_at(dive, scan.centres)
            res.mapped.append("map_frame: the centre of the geographic extent of the soundings/grids")
        return
    groups = _groups(grids + [f for f in scan.footprints if f.role == "track"])
    with_grids = [g for g in groups if any(f.role in _FRAME_ROLES for f in g)]
    pick = (next((g for g in with_grids if any(f.role == "track" for f in g)), None)
            or next((g for g in with_grids if any(f.role == "multibeam" for f in g)), None)
            or max(with_grids, key=lambda g: sum(f.role in _FRAME_ROLES for f in g)))
    what, chosen = next((w, c) for w, c in (
        ("the vehicle track", [f for f in pick if f.role == "track"]),
        ("the soundings", [f for f in pick if f.role == "multibeam"]),
        ("the grids", [f for f in pick if f.role in _FRAME_ROLES])) if c)
    # prior grids only (no track, no soundings): the dive's site is its casts on them, not the grids' centre
    casts = [f for f in scan.footprints if f.role == "cast" and what == "the grids"
             and any(_box_km(f.box, g.box) <= SOURCES_APART_KM for g in chosen)]
    left = [f.rel for g in groups if g is not pick for f in g if f.role in _FRAME_ROLES]
    if casts:
        _frame_at(dive, [f.centre() for f in casts])
        res.mapped.append(f"map_frame: the position of the cast(s) ({_names(casts)}), the dive's site on the "
                          f"grids ({_names(chosen)}), not the grids' centre"
                          + (f"; not of {', '.join(left[:3])}, which lie(s) apart" if left else ""))
        return
    _frame_at(dive, [f.centre() for f in chosen])
    res.mapped.append(f"map_frame: the centre of {what} ({', '.join(f.rel for f in chosen[:3])}"
                      f"{', ...' if len(chosen) > 3 else ''})"
                      + (f"; not of {', '.join(left[:3])}, which lie(s) apart" if left else ""))


def _frame_at(dive: dict[str, Any], centres: list[tuple[float, float]]) -> None:
    """``dive["map_frame"]`` at the mean of (lon, lat) ``centres`` (longitudes unwrapped to the first's, the origin
    in -180..180)."""
    lon0 = centres[0][0]
    lons = [lon0 + ((c[0] - lon0 + 180.0) % 360.0 - 180.0) for c in centres]
    lon_c = (sum(lons) / len(lons) + 180.0) % 360.0 - 180.0
    lat_c = sum(c[1] for c in centres) / len(centres)
    dive["map_frame"] = {"origin_latitude_deg": round(lat_c, 4), "origin_longitude_deg": round(lon_c, 4)}


def _add_footprint(scan: _Scan, rel: str, kind: str, info: dict[str, Any]) -> None:
    """The :class:`_Footprint` of a mapped file, when its describer gives a position or an extent."""
    t0 = _epoch_s(info.get("start_time") or info.get("time_start") or info.get("start_time_utc"))
    t1 = _epoch_s(info.get("end_time") or info.get("time_end")) or t0
    first = None
    if kind == "csv":
        track = info.get("track")
        if not isinstance(track, dict):
            return
        lo, la = track["longitude_deg"], track["latitude_deg"]
        box: tuple[float, float, float, float] | None = (lo[0], lo[1], la[0], la[1])
        role, first = "track", (track["first_deg"][0], track["first_deg"][1])
    elif kind in ("cnv", "seabird_hex"):
        role = "cast"
        box = _lonlat_box(info)
        lat, lon = info.get("latitude_deg"), info.get("longitude_deg")
        if box is None and all_finite(lat, lon):
            box = (float(lon), float(lon), float(lat), float(lat))
    else:
        role = next((k for k, v in scan.sources.items() if isinstance(v, list) and rel in v), "multibeam")
        box = _lonlat_box(info)
        c = lonlat_centre(info) if box is None else None
        if c is not None:
            box = (c[0], c[0], c[1], c[1])
    if box is not None and all_finite(*box):
        scan.footprints.append(_Footprint(rel, role, box, t0, t1, first))


def _epoch_s(text: Any) -> float | None:
    """Seconds since the epoch of an ISO 8601 time (naive: UTC), ``None`` when absent or unreadable."""
    if not isinstance(text, str) or not text:
        return None
    try:
        t = _dt.datetime.fromisoformat(text.strip().replace("Z", "+00:00"))
    except ValueError:
        return None
    return (t if t.tzinfo else t.replace(tzinfo=_dt.UTC)).timestamp()


def _track_start(scan: _Scan) -> tuple[float, float, str | None, str] | None:
    """(lat, lon, time, file) of the earliest vehicle track's first position (glider logs), if any."""
    tracks = [f for f in scan.footprints if f.role == "track" and f.first is not None]
    if not tracks:
        return None
    f = min(tracks, key=lambda f: (f.t0 is None, f.t0 or 0.0))
    t = None if f.t0 is None else _dt.datetime.fromtimestamp(round(f.t0), _dt.UTC).isoformat().replace("+00:00", "Z")
    assert f.first is not None
    return f.first[0], f.first[1], t, f.rel


def _box_km(a: tuple[float, float, float, float], b: tuple[float, float, float, float]) -> float:
    """Geodesic distance (km, WGS84) between the nearest points of two lon/lat boxes (0 when they overlap);
    longitudes compared modulo 360."""
    from pyproj import Geod

    def near(a0: float, a1: float, b0: float, b1: float) -> tuple[float, float]:
        if a1 < b0:
            return a1, b0
        if b1 < a0:
            return a0, b1
        m = max(a0, b0)
        return m, m

    lat_a, lat_b = near(a[2], a[3], b[2], b[3])
    shift = min((-360.0, 0.0, 360.0), key=lambda k: abs((b[0] + b[1]) / 2 + k - (a[0] + a[1]) / 2))
    lon_a, lon_b = near(a[0], a[1], b[0] + shift, b[1] + shift)
    if lat_a == lat_b and lon_a == lon_b:
        return 0.0
    return float(Geod(ellps="WGS84").inv(lon_a, lat_a, lon_b, lat_b)[2]) / 1000.0


def _groups(fps: list[_Footprint]) -> list[list[_Footprint]]:
    """Footprints grouped by single linkage: within :data:`SOURCES_APART_KM` of some member of the group."""
    groups: list[list[_Footprint]] = []
    for f in fps:
        near = [g for g in groups if any(_box_km(f.box, o.box) <= SOURCES_APART_KM for o in g)]
        merged = [f] + [x for g in near for x in g]
        groups = [g for g in groups if not any(g is n for n in near)] + [merged]
    return groups


def _names(group: list[_Footprint]) -> str:
    return ", ".join(f.rel for f in group[:3]) + (f" and {len(group) - 3} more" if len(group) > 3 else "")


def _check_overlap(res: InitResult, fps: list[_Footprint]) -> None:
    """To-dos naming sources that do not overlap in space (more than :data:`SOURCES_APART_KM` apart, with the
    distance) or in time (time spans more than :data:`SOURCES_APART_H` apart; prior grids and point clouds carry
    no time of the dive)."""
    groups = _groups(fps)
    for i, a in enumerate(groups):
        for b in groups[i + 1:]:
            d = min(_box_km(x.box, y.box) for x in a for y in b)
            res.todo.append(f"sources do not overlap in space: {_names(a)} and {_names(b)} are {d:.0f} km apart "
                            "(nearest points): check that they belong to one dive")
    timed = sorted((f for f in fps if f.t0 is not None and f.role in ("cast", "track", "multibeam")),
                   key=lambda f: f.t0 or 0.0)
    spans: list[list[_Footprint]] = []
    for f in timed:
        if spans and (f.t0 or 0.0) - max(x.t1 or x.t0 or 0.0 for x in spans[-1]) <= SOURCES_APART_H * 3600:
            spans[-1].append(f)
        else:
            spans.append([f])
    for a, b in zip(spans, spans[1:], strict=False):
        end = max(x.t1 or x.t0 or 0.0 for x in a)
        gap_h = ((b[0].t0 or 0.0) - end) / 3600
        when = (f"{gap_h / 24:.0f} days" if gap_h >= 48 else f"{gap_h:.0f} h")
        res.todo.append(f"sources do not overlap in time: {_names(a)} (until {_day(end)}) and {_names(b)} (from "
                        f"{_day(b[0].t0)}) are {when} apart: check that they belong to one dive")


def _day(t: float | None) -> str:
    return "?" if t is None else _dt.datetime.fromtimestamp(t, _dt.UTC).strftime("%Y-%m-%d %H:%M")


def _csv_key(p: Path, taken: dict[str, Path]) -> str:
    key = re.sub(r"[^A-Za-z0-9_]+", "_", p.name.split(".")[0]).strip("_") or "log"
    k, n = key, 2
    while k in taken:
        k, n = f"{key}_{n}", n + 1
    return k


def _map_vehicle_logs(res: InitResult, sources: dict[str, Any], mcaps: list[Path], csvs: dict[str, Path],
                      raw: Path, launch: tuple[float, float] | None) -> None:
    """Suggest the vehicle mapping (:func:`hadal.ingest.suggest.suggest_vehicle`) and list the logs it uses."""
    if not mcaps and not csvs:
        return
    from hadal.ingest.suggest import render_vehicle_yaml, suggest_vehicle

    rel = {str(p): p.relative_to(raw).as_posix() for p in (*mcaps, *csvs.values())}
    try:
        sug = suggest_vehicle(mcaps, csvs, launch=launch)
    except InputError as exc:
        res.not_used.append(f"vehicle logs: {exc}")
        return
    for m in sug.mapped:
        unit = f" [{m.get('units')}]" if m.get("units") else ""
        how = f" via {m['transform']}" if m.get("transform") else ""
        res.mapped.append(f"{rel.get(str(m.get('file')), m.get('file'))}: {m.get('source')}.{m.get('field')}{unit}{how} "
                          f"-> {m.get('variable')} ({m.get('why', '')})".replace(" ()", ""))
    for u in sug.unmapped:
        res.not_used.append(f"{rel.get(str(u.get('file')), u.get('file'))}: {u.get('source')}"
                            f"{'.' + str(u['field']) if u.get('field') else ''}: {u.get('reason', '')}")
    res.todo += [str(c) for c in sug.checks]
    used_mcap = {str(Path(f)) for f in sug.mcap_used}
    for p in mcaps:
        if str(p) in used_mcap and sug.ok:
            sources["mcap"].append(rel[str(p)])
        else:
            res.not_used.append(f"{rel[str(p)]}: no channel maps to a hadal sensor variable")
    for key, p in csvs.items():
        if key in sug.csv_used and sug.ok:
            sources["csv"][key] = rel[str(p)]
        else:
            res.not_used.append(f"{rel[str(p)]}: no column maps to a hadal sensor variable")
    if sug.ok:
        res.vehicle_yaml = render_vehicle_yaml(sug)


def _todo(res: InitResult, casts_without_latitude: list[str]) -> None:
    """What the user must still provide, from the plan of the stages the data supports; the casts named in
    ``casts_without_latitude`` carry no latitude in their headers."""
    from hadal.stages.plan import plan_stages, stage_inputs

    try:
        dive = Dive.model_validate(res.dive)
    except Exception as exc:  # noqa: BLE001 - reported as a to-do, init still writes the file
        res.todo.append(f"dive.yaml does not validate yet: {str(exc).splitlines()[0]}")
        return
    plan = plan_stages(dive)
    if dive.launch is None:
        need = [ps.name for ps in plan if ps.run and stage_inputs(ps.name).needs_launch]
        if need:
            res.todo.append(f"launch position: stage(s) {', '.join(need)} need it (hadal init DIR --launch LAT,LON "
                            "--force, or edit dive.yaml)")
        if casts_without_latitude:
            res.todo.append(f"the header of {', '.join(casts_without_latitude)} carries no latitude: gravity and "
                            "depth will use 45° unless dive.yaml gets a launch position (--launch LAT,LON)")
    if dive.map_frame is None and dive.launch is None and ({"multibeam", "prior_grid"} & set(dive.sources.kinds())):
        res.todo.append("map_frame: no geographic position found in the data; add map_frame or --launch")
    if not dive.sources.kinds():
        res.todo.append("no file hadal can process was found")
    res.plan = plan


_HEADER = """\
# dive.yaml written by `hadal init` on {date} from the files in this directory.
# Every field is documented in docs/dive-directory.md (JSON Schema: hadal schema dive).
# Check it with `hadal config --check {dir}`; run the dive with `hadal run {dir}`.
"""

_COMMENTS = {
    "dive_id": "unique id of the dive in the product store (default: the directory's name)",
    "platform": "vehicle or ship name (used in product metadata)",
    "vehicle_config": "channel mapping of the vehicle logs (suggested by hadal init; check the units)",
    "launch": "launch position (origin of the dead-reckoned track)",
    "map_frame": "origin of the local transverse-Mercator map frame of grids and matching",
    "sources": "raw files by kind, relative to this directory (a hint with a comment is a guess: check it)",
}


#: the commented ``metadata:`` stub of a new dive.yaml: (field, example value, ACDD-1.3 / IOOS-1.2 meaning); the
#: required ones (:data:`hadal.products.metadata.REQUIRED_FIELDS`) are listed by ``hadal config --check`` while
#: missing
METADATA_STUB: tuple[tuple[str, str, str], ...] = (
    ("creator_name", "Jane Doe", "ACDD creator_name (required): person or group principally responsible for "
                                 "collecting/processing the data"),
    ("creator_email", "jane.doe@example.edu", "ACDD creator_email (required): contact address of the creator"),
    ("creator_url", "https://example.edu/~jdoe", "ACDD creator_url: web page of the creator"),
    ("creator_type", "person", "ACDD creator_type: person, group, institution or position"),
    ("creator_country", "China", "IOOS-1.2 creator_country (required): country of the creator"),
    ("creator_sector", "academic", "IOOS-1.2 creator_sector (required): academic, gov_federal, gov_municipal, "
                                   "gov_state, industry, nonprofit, tribal, other or unknown"),
    ("infoUrl", "https://example.edu/hadal-dives", "IOOS-1.2 infoUrl (required): web page with background "
                                                   "information about the data"),
    ("institution", "Example Institute of Oceanography", "ACDD/CF institution (required): where the data were "
                                                         "produced"),
    ("project", "Hadal Trench Survey 2026", "ACDD project (required): scientific project that produced the data"),
    ("program", "", "ACDD program: overarching programme of the project"),
    ("cruise", "", "cruise id (recorded in every product)"),
    ("license", "CC-BY-4.0", "ACDD license (required): terms of use of the data (SPDX id or URL)"),
    ("naming_authority", "edu.example", "ACDD naming_authority: reverse-DNS name of the organisation that makes "
                                        "the product ids unique (IOOS-1.2 asks for it)"),
    ("publisher_name", "", "ACDD publisher_name: who distributes the data (default: the creator)"),
    ("publisher_email", "", "ACDD publisher_email: contact address of the publisher"),
    ("publisher_url", "", "ACDD publisher_url: web page of the publisher (data centre)"),
    ("publisher_country", "", "IOOS-1.2 publisher_country: country of the publisher (default: the creator's)"),
    ("acknowledgment", "", "ACDD acknowledgment: funding and support"),
    ("metadata_link", "", "ACDD metadata_link: URL of the dataset's landing page / full metadata"),
    ("platform_vocabulary_name", "Subsurface Vehicles > AUV", "ACDD platform: GCMD platform keyword of the vehicle "
                                                              "(its name is the top-level 'platform:' field)"),
    ("platform_type", "submersible", "IOOS-1.2 platform: term of the IOOS platform vocabulary "
                                     "(https://mmisw.org/ont/ioos/platform; default submersible)"),
)
_INSTRUMENTS_STUB = (("ctd", "Sea-Bird SBE 49 FastCAT"), ("dtm", "Kongsberg EM 124"))


def metadata_stub() -> list[str]:
    """The commented ``metadata:`` block of a new dive.yaml: every field with its ACDD meaning and an example in
    the comment, the value empty (uncommented as is, it validates as :class:`hadal.dive.DiveMetadata` and
    ``hadal config --check`` still lists the required fields until they are filled in)."""
    out = ["# metadata: discovery metadata (ACDD-1.3, IOOS-1.2) written into every product; nothing is invented "
           "when a field",
           "# is absent (the products list it in hadal_metadata_missing). Uncomment and fill in:",
           "# metadata:"]
    for key, example, meaning in METADATA_STUB:  # values left empty: an example never reaches a product
        out.append(f"#   # {meaning}" + (f" (e.g. {example})" if example else ""))
        out.append(f"#   {key}:")
    out.append("#   # ACDD instrument per product (default: hadal's GCMD keyword; products measured by another")
    out.append("#   # product's instrument, e.g. profile by ctd, suitability by dtm, follow it), e.g.")
    out.append("#   instruments: {}")
    out += [f"#   #   {k}: {v}" for k, v in _INSTRUMENTS_STUB]
    return out


def _with_source_notes(block: str, notes: dict[str, str]) -> str:
    """The ``sources`` YAML block with each noted entry's note as a comment line above it."""
    if not notes:
        return block
    lines = []
    for ln in block.split("\n"):
        t = ln.strip()
        if t.startswith("- path: "):
            rel = yaml.safe_load(t[len("- path: "):])
            if rel in notes:
                lines.append(" " * (len(ln) - len(ln.lstrip())) + f"# {notes[rel]}")
        lines.append(ln)
    return "\n".join(lines)


def render_dive_yaml(res: InitResult) -> str:
    """The commented dive.yaml text of ``res`` (the YAML itself round-trips to ``res.dive``); without a
    ``metadata`` entry it ends with the commented stub of :func:`metadata_stub`."""
    out = [_HEADER.format(date=_dt.date.today().isoformat(), dir=res.raw_dir.name)]
    for key, value in res.dive.items():
        out.append(f"# {_COMMENTS.get(key, key)}")
        block = yaml.safe_dump({key: value}, sort_keys=False, default_flow_style=False).rstrip()
        if key == "sources":
            block = _with_source_notes(_comment_hints(block, res.source_comments), res.source_notes)
        out.append(block)
    if "metadata" not in res.dive:
        out += metadata_stub()
    if res.not_used:
        out.append("# files not used:")
        out += [f"#   {line}" for line in res.not_used]
    if res.todo:
        out.append("# still to check or fill in:")
        out += [f"#   {line}" for line in res.todo]
    return "\n".join(out) + "\n"


def _comment_hints(text: str, comments: dict[str, dict[str, str]]) -> str:
    """``text`` (the dumped ``sources:`` block) with each commented hint's line ending in ``  # why``."""
    if not comments:
        return text
    out, current = [], None
    for line in text.splitlines():
        m = re.match(r"^\s*-\s+path:\s*(.+?)\s*$", line)
        if m:
            current = yaml.safe_load(m.group(1))
        else:
            k = re.match(r"^\s+(\w+):", line)
            why = comments.get(current, {}).get(k.group(1)) if k and current is not None else None
            if why:
                line = f"{line}  # {' '.join(why.split())}"
        out.append(line)
    return "\n".join(out)


def write_init(res: InitResult, *, force: bool = False) -> list[Path]:
    """Write ``dive.yaml`` (and ``vehicle.yaml``) into the dive directory; refuses to overwrite ``dive.yaml``
    without ``force``. A ``vehicle.yaml`` the user already has is kept (and used) unless ``force``."""
    targets = [(res.raw_dir / DIVE_FILE, res.dive_yaml())]
    keep_vehicle = (res.raw_dir / VEHICLE_FILE).exists() and not force
    if res.vehicle_yaml is not None and not keep_vehicle:
        targets.append((res.raw_dir / VEHICLE_FILE, res.vehicle_yaml))
    existing = [p for p, _ in targets if p.exists()]
    if existing and not force:
        raise ConfigError(f"{', '.join(str(p) for p in existing)} already exist(s); use --force to overwrite")
    written = []
    for p, text in targets:
        tmp = p.with_name(f".{p.name}.tmp")
        try:
            tmp.write_text(text, encoding="utf-8")
            tmp.replace(p)
        except OSError as exc:
            tmp.unlink(missing_ok=True)
            raise InputError(f"cannot write {p}: {exc.strerror or exc}") from None
        written.append(p)
    return written
