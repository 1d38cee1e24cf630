"""Dive description (``dive.yaml`` in a raw dive directory): what was recorded, where and with what.

Example (the sample dive written by ``hadal synth``)::

    dive_id: haidou-challenger-deep
    platform: Haidou
    vehicle_config: vehicle.yaml          # channel/column mapping, relative to the dive directory
    launch: {time_utc: 2018-10-06T23:00:00Z, latitude_deg: 11.3371167, longitude_deg: 142.2097167}
    map_frame: {origin_latitude_deg: 11.33, origin_longitude_deg: 142.20}
    sources:
      mcap: [logs/haidou.mcap]
      csv: {ctd: csv/ctd.csv, gauge: csv/keller.csv, ...}
      cnv: []
      multibeam: [multibeam/em122_line01.xyz.gz, ...]
      laser: [laser/submap_01.ply, ...]
"""

from __future__ import annotations

import datetime as _dt
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator

from hadal.errors import ConfigError, HadalError, InputError, first_validation_error
from hadal.geo import LocalFrame
from hadal.names import check_component

DIVE_FILE = "dive.yaml"


class Launch(BaseModel):
    model_config = ConfigDict(extra="forbid")
    time_utc: _dt.datetime | None = Field(None, description="launch time (ISO-8601, UTC)")
    latitude_deg: float = Field(ge=-90, le=90, description="launch latitude (decimal degrees, north positive)")
    longitude_deg: float = Field(ge=-180, le=180, description="launch longitude (decimal degrees, east positive)")


class MapFrame(BaseModel):
    """Origin of the local transverse-Mercator frame used by grids and matching."""

    model_config = ConfigDict(extra="forbid")
    origin_latitude_deg: float = Field(ge=-90, le=90, description="latitude of the frame origin (degrees)")
    origin_longitude_deg: float = Field(ge=-180, le=180, description="central meridian / origin longitude (degrees)")

    def frame(self) -> LocalFrame:
        return LocalFrame(self.origin_latitude_deg, self.origin_longitude_deg)


class LaserFrame(BaseModel):
    """Georeference of the laser survey's local frame (x, y metres): where its origin is and how it is turned."""

    model_config = ConfigDict(extra="forbid")
    origin_latitude_deg: float = Field(ge=-90, le=90, description="latitude of the laser frame's origin (degrees)")
    origin_longitude_deg: float = Field(ge=-180, le=180, description="longitude of the laser frame's origin (degrees)")
    heading_deg: float = Field(0.0, ge=-360, le=360, description="azimuth of the laser frame's +y axis, degrees "
                                                                  "clockwise from true north (0: x east, y north)")


class DiveMetadata(BaseModel):
    """Discovery metadata (ACDD-1.3, IOOS-1.2) written into every product; nothing is invented when a field is absent
    (``hadal config --check`` lists the missing required ones)."""

    model_config = ConfigDict(extra="forbid")
    creator_name: str | None = Field(None, description="person or group who collected/processed the data")
    creator_email: str | None = Field(None, description="contact e-mail of the creator")
    creator_url: str | None = Field(None, description="web page of the creator")
    creator_type: Literal["person", "group", "institution", "position"] | None = Field(
        None, description="ACDD creator_type")
    creator_country: str | None = Field(None, max_length=100,
                                        description="IOOS-1.2 creator_country: country of the creator (e.g. 'China')")
    creator_sector: Literal["academic", "gov_federal", "gov_municipal", "gov_state", "industry", "nonprofit",
                            "tribal", "other", "unknown"] | None = Field(
        None, description="IOOS-1.2 creator_sector: societal sector of the creator (https://mmisw.org/ont/ioos/sector)")
    infoUrl: str | None = Field(None, max_length=2048,  # noqa: N815 - the IOOS/ERDDAP attribute's own name
                                description="IOOS-1.2 infoUrl: URL with background information about the dataset")
    institution: str | None = Field(None, description="institution that produced the data")
    project: str | None = Field(None, description="project or cruise programme")
    program: str | None = Field(None, description="overarching programme")
    cruise: str | None = Field(None, description="cruise id")
    publisher_name: str | None = Field(None, description="publisher (data centre) name")
    publisher_email: str | None = Field(None, description="publisher contact e-mail")
    publisher_url: str | None = Field(None, description="publisher web page")
    publisher_country: str | None = Field(None, max_length=100,
                                          description="IOOS-1.2 publisher_country (default: the creator's)")
    license: str | None = Field(None, description="data licence (e.g. 'CC-BY-4.0')")
    naming_authority: str | None = Field(None, description="reverse-DNS naming authority of product ids")
    acknowledgment: str | None = Field(None, description="funding / acknowledgement text")
    references: str | None = Field(None, description="published references describing the data")
    metadata_link: str | None = Field(None, description="URL of the dataset's landing page / full metadata")
    platform_vocabulary_name: str | None = Field(
        None, description="GCMD platform keyword of the vehicle (default 'Subsurface Vehicles > AUV')")
    platform_type: str | None = Field(
        None, pattern=r"^\S+$", max_length=100,
        description="IOOS-1.2 platform: term of the IOOS platform vocabulary (https://mmisw.org/ont/ioos/platform) "
                    "for the vehicle, no blanks (default 'submersible')")
    instruments: dict[str, str] = Field(
        default_factory=dict, description="product name -> instrument description (overrides hadal's defaults, "
                                          "e.g. {ctd: 'Sea-Bird SBE 49 FastCAT', dtm: 'Kongsberg EM122'})")


class SourceFile(BaseModel):
    """One raw file with optional reading hints (every hint defaults to detection from the file's content).

    In ``dive.yaml`` an entry is either a plain path string or a mapping with ``path`` and hints.
    """

    model_config = ConfigDict(extra="forbid")
    path: str = Field(min_length=1, description="path relative to the dive directory")
    format: str | None = Field(None, description="file format, overriding detection (a hadal.formats kind, e.g. "
                                                 "'xyz', 'gsf', 'kmall', 'em_all', 'geotiff', 'netcdf_grid', 'ply')")
    # the same order as products.registry: typing caches Literal by its set of values, so the first order made wins
    z_positive: Literal["down", "up"] | None = Field(
        None, description="vertical values are depths (down) or elevations (up); default: detected")
    z_units: str | None = Field(None, max_length=40,
                                description="units of a grid's values when the file does not say (m, km, ft, "
                                            "us survey foot, fathom ...; converted to metres); default: from "
                                            "the file, metres when it gives none")
    crs: str | None = Field(None, description="CRS of x/y (e.g. 'EPSG:4326', 'EPSG:32654') or 'local' for a local "
                                              "metric frame; default: from the file, else detected")
    variable: str | None = Field(None, description="NetCDF variable holding the grid (default: the first 2-D one)")
    columns: list[str] | None = Field(
        None, description="xyz text: column names in file order, using x/lon, y/lat, z/depth/elevation")
    kind: Literal["cast", "underway"] | None = Field(
        None, description="Sea-Bird record (sources.cnv): 'cast' (a vertical profile: ctd/profile products) or "
                          "'underway' (a thermosalinograph in the ship's seawater line: per-scan positions, "
                          "constant pressure; published as the 'trajectory' product, never binned by depth). "
                          "hadal init writes the choice of hadal.ctd.underway's rule; default (absent): cast, and "
                          "derive warns when the content looks underway")

    def __str__(self) -> str:  # so a SourceFile prints (and resolves) like the plain path it names
        return self.path


def _as_source_files(v: Any) -> Any:
    if isinstance(v, (str, dict)):
        v = [v]
    if isinstance(v, list):
        return [{"path": x} if isinstance(x, str) else x for x in v]
    return v


class Sources(BaseModel):
    """Raw files of the dive, relative to the dive directory (see ``docs/dive-directory.md``)."""

    model_config = ConfigDict(extra="forbid")
    mcap: list[str] = Field(default_factory=list, description="vehicle logs in MCAP (JSON or ROS 2 CDR messages)")
    csv: dict[str, str] = Field(default_factory=dict,
                                description="vehicle logs as CSV: name -> file (the vehicle mapping says which "
                                            "sensor reads which name)")
    cnv: list[SourceFile] = Field(
        default_factory=list, description="Sea-Bird CTD casts: .cnv (also .gz/.bz2/.xz) or raw .hex")
    multibeam: list[SourceFile] = Field(
        default_factory=list, description="multibeam soundings: xyz text (also .gz/.bz2/.xz), GSF, Kongsberg "
                                          ".kmall/.all, Reson .s7k")
    prior_grid: list[SourceFile] = Field(
        default_factory=list, description="gridded prior bathymetry (GeoTIFF, NetCDF CF/COARDS, GMT .grd): the "
                                          "reference DTM when the dive has no multibeam soundings")
    laser: list[SourceFile] = Field(
        default_factory=list, description="laser bathymetry: point clouds (PLY, PCD, LAS/LAZ, xyz) or rasters "
                                          "(GeoTIFF, NetCDF)")
    vehicle_swath: list[SourceFile] = Field(
        default_factory=list, description="the vehicle's own swath (multibeam) soundings during the dive, in any "
                                          "multibeam format, positioned by its dead-reckoned navigation: the 2-D "
                                          "real-time terrain patch of MRF fine matching (match.mrf)")

    @field_validator("cnv", "multibeam", "prior_grid", "laser", "vehicle_swath", mode="before")
    @classmethod
    def _file_lists(cls, v: Any) -> Any:
        return _as_source_files(v)

    @field_validator("mcap", mode="before")
    @classmethod
    def _mcap_list(cls, v: Any) -> Any:
        return [v] if isinstance(v, str) else v

    def kinds(self) -> list[str]:
        """Source kinds with at least one file, in declaration order."""
        return [k for k in type(self).model_fields if getattr(self, k)]

    def files(self, kind: str) -> list[SourceFile]:
        """Entries of one kind as :class:`SourceFile` (``csv`` values become entries too)."""
        entries = getattr(self, kind)
        if isinstance(entries, dict):
            return [SourceFile(path=v) for v in entries.values()]
        return [e if isinstance(e, SourceFile) else SourceFile(path=e) for e in entries]


class Dive(BaseModel):
    """A raw dive directory's description (``dive.yaml``)."""

    model_config = ConfigDict(extra="forbid")
    dive_id: str = Field(description="unique id of the dive in the product store: 1-64 letters, digits, '.', '_' "
                                      "or '-', starting with a letter or digit; not a name of the store's own files "
                                      "(catalog.json, dive.json, ...) nor ending in .json, .lock or .tmp")
    platform: str = Field("unknown", description="vehicle or ship name (product metadata)")
    vehicle_config: str | None = Field(
        None, description="vehicle channel mapping (vehicle.yaml) of the MCAP/CSV logs, relative to the dive "
                          "directory; default: the packaged sample (Haidou) mapping")
    launch: Launch | None = Field(
        None, description="launch position (and time): origin of the dead-reckoned track; needed by the stages "
                          "that use it (match, and derive/suitability when no other position is known)")
    map_frame: MapFrame | None = Field(
        None, description="origin of the local transverse-Mercator map frame (default: the launch point)")
    sources: Sources = Field(default_factory=Sources, description="the dive's raw files by kind")
    metadata: DiveMetadata = Field(default_factory=DiveMetadata,
                                   description="discovery metadata (creator, institution, project, licence, "
                                               "instruments) written into the products")
    laser_frame: LaserFrame | None = Field(
        None, description="georeference of the laser survey's local frame (landing sites in lat/lon)")
    notes: str = Field("", description="free text")

    @field_validator("dive_id")
    @classmethod
    def _valid_id(cls, v: str) -> str:
        from hadal.errors import StoreError

        try:
            return check_component(v, "dive id")
        except StoreError as exc:
            raise ValueError(str(exc)) from None

    def frame(self, stage: str | None = None) -> LocalFrame:
        """The map frame; defaults to one centred on the launch point. Without either, a one-line
        :class:`ConfigError` naming ``stage`` (the stage that needs a frame)."""
        if self.map_frame is not None:
            return self.map_frame.frame()
        if self.launch is not None:
            return LocalFrame(self.launch.latitude_deg, self.launch.longitude_deg)
        who = f"stage {stage!r} needs" if stage else "this needs"
        raise ConfigError(f"dive {self.dive_id!r}: {who} a map frame, but dive.yaml has neither 'map_frame' nor "
                          "'launch' (add one, or run 'hadal init DIR --launch LAT,LON --force')")

    def require_launch(self, stage: str, why: str = "") -> Launch:
        """The launch position, or a one-line :class:`ConfigError` naming the stage that needs it."""
        if self.launch is None:
            because = f" ({why})" if why else ""
            raise ConfigError(f"dive {self.dive_id!r}: stage {stage!r} needs the launch position{because}, but "
                              "dive.yaml has no 'launch' (add launch: {latitude_deg: .., longitude_deg: ..}, or "
                              "run 'hadal init DIR --launch LAT,LON --force')")
        return self.launch


def load_dive(raw_dir: str | Path) -> tuple[Dive, Path]:
    """Read and validate ``<raw_dir>/dive.yaml``. Returns the model and the resolved directory."""
    raw = Path(raw_dir)
    f = raw / DIVE_FILE
    if not raw.is_dir():
        raise InputError(f"raw dive directory {raw} does not exist")
    if not f.exists():
        raise InputError(f"{raw} has no {DIVE_FILE}; run 'hadal init {raw}' to describe your files (or 'hadal synth "
                         f"{raw}' for a sample dive)")
    from hadal.yamlfile import load_yaml_mapping

    data = load_yaml_mapping(f, "dive description")
    try:
        dive = Dive.model_validate(data)
    except ValidationError as exc:
        loc, msg, more = first_validation_error(exc)
        raise ConfigError(f"{f}: {loc}: {msg}{more}") from None
    return dive, raw.resolve()


def _check_source_path(rel: str) -> None:
    """Each component of a ``dive.yaml`` path passes the one name rule (:func:`hadal.names.check_component`,
    ``kind="path"``: no NUL or control characters, no ``\\``, at most 255 bytes); empty, ``.`` and ``..``
    components are path structure, not names (``./x``, ``a//b``; a ``..`` that leaves the dive directory is refused
    after resolving, as "escapes the dive directory"). A one-line :class:`ConfigError`."""
    from hadal.errors import StoreError
    from hadal.names import check_component

    for part in rel.split("/")[1 if rel.startswith("/") else 0:]:
        if part in ("", ".", ".."):
            continue
        try:
            check_component(part, "source path component", kind="path")
        except StoreError as exc:
            raise ConfigError(f"source path {rel!r}: {exc}") from None


def resolve_source(raw_dir: Path, rel: str | SourceFile) -> Path:
    """Resolve a source path (or :class:`SourceFile`) relative to the dive directory, refusing paths that escape it."""
    import stat

    rel = rel.path if isinstance(rel, SourceFile) else rel
    _check_source_path(str(rel))
    try:
        p = (raw_dir / rel).resolve()
    except (RuntimeError, OSError) as exc:  # Python raises RuntimeError on a symbolic-link loop
        raise InputError(f"{raw_dir / rel}: symbolic link loop or unresolvable path ({exc})") from None
    if raw_dir.resolve() not in p.parents and p != raw_dir.resolve():
        raise ConfigError(f"source path {rel!r} escapes the dive directory {raw_dir}")
    try:
        mode = p.stat().st_mode
    except FileNotFoundError:
        return p  # the caller says the listed file does not exist
    except OSError as exc:
        raise InputError(f"{p}: cannot be opened ({exc.strerror or exc})") from None
    if stat.S_ISDIR(mode):
        raise InputError(f"{p}: listed in dive.yaml as a source file, but it is a directory")
    if not stat.S_ISREG(mode):  # reading a FIFO would block for ever
        raise InputError(f"{p}: listed in dive.yaml as a source file, but it is not a regular file "
                         "(a FIFO, socket or device)")
    return p


_FINGERPRINTS: dict[tuple, str] = {}  # (raw_dir, stat of dive.yaml and every source) -> fingerprint, per process


def _stat_key(path: Path) -> tuple:
    try:
        st = path.stat()
    except OSError:
        return (str(path), None)
    return (str(path), st.st_size, st.st_mtime_ns, st.st_ino, st.st_ctime_ns)


def dive_fingerprint(dive: Dive, raw_dir: Path) -> str:
    """Content fingerprint of a raw dive directory: SHA-256 over ``dive.yaml`` and, for every source file, its
    relative path, size and the first and last MiB (cheap on large logs, yet different for different dives).

    Computed once per process for unchanged files: memoised on the size, mtime, inode and ctime of ``dive.yaml``
    and of every source file (a run checks the dive's identity before and after each stage)."""
    key: tuple = (str(raw_dir), _stat_key(raw_dir / DIVE_FILE))
    for kind in type(dive.sources).model_fields:
        for entry in dive.sources.files(kind):
            try:
                f = resolve_source(raw_dir, entry)
            except HadalError:
                key += ((kind, str(entry.path), None),)
                continue
            key += ((kind, str(entry.path), *_stat_key(f)),)
    if key not in _FINGERPRINTS:
        _FINGERPRINTS[key] = _dive_fingerprint(dive, raw_dir)
    return _FINGERPRINTS[key]


def _dive_fingerprint(dive: Dive, raw_dir: Path) -> str:
    import hashlib

    h = hashlib.sha256()
    try:
        h.update((raw_dir / DIVE_FILE).read_bytes())
    except OSError:
        pass
    for kind in type(dive.sources).model_fields:
        for entry in dive.sources.files(kind):
            h.update(f"{kind}:{entry.path}".encode())
            try:
                f = resolve_source(raw_dir, entry)
                size = f.stat().st_size
                h.update(str(size).encode())
                with open(f, "rb") as fh:
                    h.update(fh.read(1 << 20))
                    if size > 2 << 20:
                        fh.seek(-(1 << 20), 2)
                        h.update(fh.read(1 << 20))
            except (OSError, HadalError):
                h.update(b"missing")
    return h.hexdigest()


def find_dives(*dirs: str | Path, allow_empty: bool = False) -> list[Path]:
    """Dive directories named by ``dirs``: one with ``dive.yaml`` is a dive; one without is searched one
    level down for dive subdirectories (a cruise directory). Sorted within each directory."""
    out: list[Path] = []
    for d in (Path(x) for x in dirs):
        if not d.exists():
            raise InputError(f"raw dive directory {d} does not exist")
        if not d.is_dir():
            raise InputError(f"{d} is a file, not a raw dive directory")
        if (d / DIVE_FILE).is_file():
            out.append(d)
            continue
        try:
            subs = sorted(p for p in d.iterdir() if (p / DIVE_FILE).is_file())
        except OSError as exc:
            raise InputError(f"cannot list {d}: {exc.strerror or exc}") from None
        if not subs and not allow_empty:
            raise InputError(f"{d} has no {DIVE_FILE} and no dive subdirectories")
        out.extend(subs)
    seen: set[Path] = set()  # a dive named twice (DIR and DIR/dive) is processed once
    return [p for p in out if not (p.resolve() in seen or seen.add(p.resolve()))]
