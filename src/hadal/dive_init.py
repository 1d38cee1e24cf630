"""``hadal init RAW_DIR``: describe a dive directory from its files and write a commented ``dive.yaml``.

Every file under the directory is identified by content (:func:`hadal.formats.detect`) and described
(:func:`hadal.inspect.inspect_file`); each readable one is put in the ``sources`` list of its kind:

* MCAP / CSV vehicle logs -> ``mcap`` / ``csv``, with a ``vehicle.yaml`` channel mapping suggested from the
  message types, field names and units (:func:`hadal.ingest.suggest.suggest_vehicle`); logs of which no
  channel maps to a hadal variable are listed as not used;
* Sea-Bird ``.cnv`` (also compressed) and ``.hex`` -> ``cnv``;
* multibeam (xyz text, GSF, .kmall, .all, .s7k) -> ``multibeam``; xyz text in a small metric frame is laser
  bathymetry (see :func:`xyz_role`);
* rasters (GeoTIFF, NetCDF grids) -> ``laser`` when their cells are at most :data:`LASER_MAX_CELL_M`, else
  ``prior_grid``; point clouds (PLY, PCD, LAS/LAZ) -> ``laser``.

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

VEHICLE_FILE = "vehicle.yaml"
#: hadal's own files in a dive directory (never sources)
OWN_FILES = {DIVE_FILE, VEHICLE_FILE, "pipeline.yaml"}
#: rasters with cells at most this size (m) are laser (micro-)bathymetry, coarser ones prior maps
LASER_MAX_CELL_M = 0.5
#: metric xyz point sets spanning less than this (m) are laser scans, wider ones ship soundings
LASER_MAX_EXTENT_M = 200.0


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
    #: the stages the data supports (:func:`hadal.plan.plan_stages`), filled by :func:`scan_dive_dir`
    plan: list[Any] = field(default_factory=list)

    def dive_yaml(self) -> str:
        return render_dive_yaml(self)


def sanitise_dive_id(name: str) -> str:
    """A valid dive id from a directory name (letters, digits, ``._-``; at most 64 characters)."""
    s = re.sub(r"[^A-Za-z0-9._-]+", "-", name).strip(".-_")[:64]
    if not s or not s[0].isalnum():
        raise ConfigError(f"cannot make a dive id from the directory name {name!r}; pass --dive-id")
    return s


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


def xyz_role(info: dict[str, Any]) -> str:
    """``multibeam`` or ``laser`` for an xyz text file: geographic coordinates or a wide extent are soundings;
    a metric point set narrower than :data:`LASER_MAX_EXTENT_M` is a laser scan."""
    if info.get("crs_kind") == "geographic" or "lon_range" in info or "longitude_range" in info:
        return "multibeam"
    ext = _extent_m(info)
    return "laser" if ext is not None and ext < LASER_MAX_EXTENT_M else "multibeam"


def _extent_m(info: dict[str, Any]) -> float | None:
    for key in ("x_range", "x_range_m"):
        xr_, yr_ = info.get(key), info.get(key.replace("x_", "y_"))
        if xr_ and yr_:
            return max(abs(xr_[1] - xr_[0]), abs(yr_[1] - yr_[0]))
    ext = info.get("extent")
    if isinstance(ext, dict) and {"x_min", "x_max", "y_min", "y_max"} <= set(ext):
        return max(ext["x_max"] - ext["x_min"], ext["y_max"] - ext["y_min"])
    return None


def grid_role(info: dict[str, Any]) -> str:
    """``laser`` for a metric raster with cells ≤ :data:`LASER_MAX_CELL_M`, else ``prior_grid``."""
    if info.get("crs_kind") == "geographic":
        return "prior_grid"
    res = info.get("resolution_m", info.get("resolution"))
    if isinstance(res, (list, tuple)):
        res = max(abs(float(r)) for r in res)
    try:
        return "laser" if res is not None and 0 < float(res) <= LASER_MAX_CELL_M else "prior_grid"
    except (TypeError, ValueError):
        return "prior_grid"


def _lonlat_centre(info: dict[str, Any]) -> tuple[float, float] | None:
    for lo_key, la_key in (("lon_range", "lat_range"), ("longitude_range", "latitude_range")):
        lo, la = info.get(lo_key), info.get(la_key)
        if lo and la and all(isinstance(v, (int, float)) and math.isfinite(v) for v in (*lo, *la)):
            return (lo[0] + lo[1]) / 2, (la[0] + la[1]) / 2
    ext = info.get("lonlat_extent") or info.get("geographic_extent")
    if isinstance(ext, dict) and {"lon_min", "lon_max", "lat_min", "lat_max"} <= set(ext):
        return (ext["lon_min"] + ext["lon_max"]) / 2, (ext["lat_min"] + ext["lat_max"]) / 2
    return None


def scan_dive_dir(raw_dir: str | Path, *, dive_id: str | None = None,
                  launch: tuple[float, float] | None = None) -> InitResult:
    """Identify every file of ``raw_dir`` and build the dive.yaml content (nothing is written)."""
    raw = Path(raw_dir)
    if not raw.is_dir():
        raise InputError(f"raw dive directory {raw} does not exist" if not raw.exists()
                         else f"{raw} is not a directory")
    res = InitResult(raw.resolve(), {})
    sources: dict[str, Any] = {"mcap": [], "csv": {}, "cnv": [], "multibeam": [], "prior_grid": [], "laser": []}
    centres: list[tuple[float, float]] = []
    cast_positions: list[tuple[float, float, str | None]] = []
    logs_mcap: list[Path] = []
    logs_csv: dict[str, Path] = {}
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
            logs_mcap.append(p)
        elif kind == "csv":
            logs_csv[_csv_key(p, logs_csv)] = p
        elif kind in ("cnv", "seabird_hex"):
            sources["cnv"].append(rel)
            res.mapped.append(f"{rel}: Sea-Bird cast ({kind}) -> sources.cnv")
            lat, lon = info.get("latitude_deg"), info.get("longitude_deg")
            if isinstance(lat, (int, float)) and isinstance(lon, (int, float)):
                cast_positions.append((float(lat), float(lon), info.get("start_time_utc")))
        elif kind in ("xyz", "gsf", "kmall", "em_all", "s7k"):
            role = xyz_role(info) if kind == "xyz" else "multibeam"
            sources[role].append(rel)
            res.mapped.append(f"{rel}: {kind} -> sources.{role}")
        elif kind in ("geotiff", "netcdf"):
            role = grid_role(info)
            sources[role].append(rel)
            res.mapped.append(f"{rel}: {kind} grid -> sources.{role}")
        elif kind in ("ply", "pcd", "las"):
            sources["laser"].append(rel)
            res.mapped.append(f"{rel}: {kind} point cloud -> sources.laser")
        else:
            res.not_used.append(f"{rel}: {info.get('description') or kind} (not a dive source)")
            continue
        c = _lonlat_centre(info)
        if c is not None:
            centres.append(c)
    _map_vehicle_logs(res, sources, logs_mcap, logs_csv, raw)

    did = dive_id or sanitise_dive_id(raw.resolve().name)
    dive: dict[str, Any] = {"dive_id": did, "platform": "unknown"}
    if res.vehicle_yaml is not None:
        dive["vehicle_config"] = VEHICLE_FILE
    if launch is not None:
        dive["launch"] = {"latitude_deg": launch[0], "longitude_deg": launch[1]}
    elif cast_positions:
        lat, lon, t = cast_positions[0]
        dive["launch"] = {"latitude_deg": round(lat, 6), "longitude_deg": round(lon, 6)}
        if t:
            dive["launch"]["time_utc"] = t
        res.mapped.append("launch: the position in the Sea-Bird header of " + sources["cnv"][0])
    if centres:
        lon_c = sum(c[0] for c in centres) / len(centres)
        lat_c = sum(c[1] for c in centres) / len(centres)
        dive["map_frame"] = {"origin_latitude_deg": round(lat_c, 4), "origin_longitude_deg": round(lon_c, 4)}
        res.mapped.append("map_frame: the centre of the geographic extent of the soundings/grids")
    dive["sources"] = {k: v for k, v in sources.items() if v}
    res.dive = dive
    _todo(res)
    return res


def _csv_key(p: Path, taken: dict[str, Path]) -> str:
    key = re.sub(r"[^A-Za-z0-9_]+", "_", p.name.split(".")[0]).strip("_") or "log"
    k, n = key, 2
    while k in taken:
        k, n = f"{key}_{n}", n + 1
    return k


def _map_vehicle_logs(res: InitResult, sources: dict[str, Any], mcaps: list[Path], csvs: dict[str, Path],
                      raw: Path) -> None:
    if not mcaps and not csvs:
        return
    try:
        from hadal.ingest.suggest import render_vehicle_yaml, suggest_vehicle
    except ImportError:  # pragma: no cover - the suggestion module ships with hadal
        res.not_used += [f"{p.relative_to(raw).as_posix()}: no vehicle-mapping suggester" for p in (*mcaps, *csvs.values())]
        return
    try:
        sug = suggest_vehicle(mcaps, csvs)
    except InputError as exc:
        res.not_used.append(f"vehicle logs: {exc}")
        return
    vehicle = getattr(sug, "vehicle", None)
    for line in getattr(sug, "mapped", []) or []:
        res.mapped.append(str(line))
    for line in getattr(sug, "unmapped", []) or []:
        res.not_used.append(str(line))
    for line in getattr(sug, "todo", []) or []:
        res.todo.append(str(line))
    if not vehicle or not vehicle.get("sensors"):
        for p in (*mcaps, *csvs.values()):
            res.not_used.append(f"{p.relative_to(raw).as_posix()}: no channel maps to a hadal sensor variable")
        return
    used_topics = {s["mcap"]["topic"] for s in vehicle["sensors"].values() if s.get("mcap")}
    used_csv = {s["csv"]["source"] for s in vehicle["sensors"].values() if s.get("csv")}
    used_mcap_files = set(getattr(sug, "mcap_files", None) or [str(p) for p in mcaps]) if used_topics else set()
    for p in mcaps:
        rel = p.relative_to(raw).as_posix()
        (sources["mcap"].append(rel) if str(p) in used_mcap_files
         else res.not_used.append(f"{rel}: no channel maps to a hadal sensor variable"))
    for key, p in csvs.items():
        rel = p.relative_to(raw).as_posix()
        (sources["csv"].__setitem__(key, rel) if key in used_csv
         else res.not_used.append(f"{rel}: no column maps to a hadal sensor variable"))
    res.vehicle_yaml = render_vehicle_yaml(sug)


def _todo(res: InitResult) -> None:
    """What the user must still provide, from the plan of the stages the data supports."""
    from hadal.plan import plan_stages, stage_inputs

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
        if "cnv" in dive.sources.kinds():
            res.todo.append("the casts' headers carry no position: gravity and depth will use 45° latitude unless "
                            "dive.yaml gets a launch position (--launch LAT,LON)")
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
    "sources": "raw files by kind, relative to this directory",
}


def render_dive_yaml(res: InitResult) -> str:
    """The commented dive.yaml text of ``res`` (the YAML itself round-trips to ``res.dive``)."""
    out = [_HEADER.format(date=_dt.date.today().isoformat(), dir=res.raw_dir.name)]
    for key, value in res.dive.items():
        out.append(f"# {_COMMENTS.get(key, key)}")
        out.append(yaml.safe_dump({key: value}, sort_keys=False, default_flow_style=False).rstrip())
    if res.not_used:
        out.append("# files not used:")
        out += [f"#   {line}" for line in res.not_used]
    if res.todo:
        out.append("# still to check or fill in:")
        out += [f"#   {line}" for line in res.todo]
    return "\n".join(out) + "\n"


def write_init(res: InitResult, *, force: bool = False) -> list[Path]:
    """Write ``dive.yaml`` (and ``vehicle.yaml``) into the dive directory; refuses to overwrite without ``force``."""
    targets = [(res.raw_dir / DIVE_FILE, res.dive_yaml())]
    if res.vehicle_yaml is not None:
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
