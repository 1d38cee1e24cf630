"""``generate_dive``: assemble the sample dive and write it (see :mod:`hadal.synth`)."""

from __future__ import annotations

import datetime as _dt
import importlib.resources
import json
import shutil
import tempfile
from collections.abc import Callable, Iterable
from pathlib import Path

import numpy as np
import pandas as pd
import yaml

import hadal
from hadal.errors import InputError
from hadal.geo import LocalFrame, format_position, geodesic_distance_m
from hadal.synth import laser as _laser
from hadal.synth import multibeam as _mb
from hadal.synth import scenario as sc
from hadal.synth import sensors as _sensors
from hadal.synth import writers as _w
from hadal.synth.terrain import Terrain, base_terrain, flatten_disc, set_pool
from hadal.synth.track import PHASES, Track, build_horizontal, build_track, smooth_noise
from hadal.synth.water import WaterColumn

GENERATOR = "hadal.synth"
FORMAT_VERSION = 1

#: Multibeam survey designs: full ~3 soundings per 20 m cell, small ~1.3 (sparser maps leave too many
#: empty cells for a fix within one cell; see hadal.stages.match).
FULL_MB = _mb.MultibeamModel(n_lines=9, ping_spacing_m=30.0, beams_per_ping=600, swath_half_width_m=6000.0)
SMALL_MB = _mb.MultibeamModel(n_lines=5, ping_spacing_m=20.0, beams_per_ping=300, swath_half_width_m=6000.0)


class _NullProgress:
    def track(self, it: Iterable, description: str, total: int | None = None):
        yield from it


def default_dive_id(dest: str | Path) -> str:
    """The dive id of a sample written to ``dest``: the directory's name made a valid id (letters, digits,
    ``._-``), else the scenario's own id."""
    import re

    from hadal.errors import StoreError
    from hadal.names import check_component

    name = re.sub(r"[^A-Za-z0-9._-]+", "-", Path(dest).resolve().name).strip(".-_")[:64]
    try:
        return check_component(name, "dive id")  # the one name rule (no '..', no store file name)
    except StoreError:
        return sc.DIVE_ID


def generate_dive(dest: str | Path, *, seed: int = 20181006, small: bool = False, progress=None,
                  dive_id: str | None = None, usbl_interval_s: float | None = None) -> Path:
    """Write the seeded sample dive into ``dest`` (created; a previous sample there is replaced) and return it.

    ``dive_id`` defaults to the destination directory's name (:func:`default_dive_id`), so two samples in two
    directories are two dives in one store.

    Same ``seed`` and ``small`` -> byte-identical files. ``small=True`` keeps the physics and the layout but
    decimates the sensors (CTD 2 Hz, others 1 Hz), thins the multibeam and writes one short laser submap.
    ``progress``: an object with ``.track(iterable, description, total)`` (hadal.stages.Progress).
    ``usbl_interval_s``: also log USBL fixes from the ship every this many seconds (:func:`hadal.synth.sensors.
    simulate_usbl`; channel ``/haidou/usbl``, ``csv/usbl.csv``, mapped in the dive's vehicle.yaml; truth in
    truth.json ``sensors.usbl``); None (default): none, and the other files are unchanged.
    """
    if usbl_interval_s is not None and not (1.0 <= float(usbl_interval_s) <= 86400.0):
        raise InputError(f"USBL interval {usbl_interval_s} s: give 1 to 86400 s")
    dest = Path(dest)
    if dest.exists():
        if not dest.is_dir():
            raise InputError(f"{dest} exists and is not a directory")
        if any(dest.iterdir()) and not _is_sample(dest):
            raise InputError(f"{dest} is not empty and does not hold a sample dive; choose an empty or new directory")
    dest.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{dest.name}.synth-", dir=dest.parent))
    try:
        _generate(staging, int(seed), bool(small), progress or _NullProgress(), dive_id or default_dive_id(dest),
                  usbl_interval_s)
        if dest.exists():
            shutil.rmtree(dest)
        staging.rename(dest)
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return dest


def _is_sample(d: Path) -> bool:
    try:
        return json.loads((d / "truth.json").read_text()).get("generator") == GENERATOR
    except (OSError, ValueError, AttributeError):
        return False


def _steps(progress) -> Callable:
    def step(desc: str, fn: Callable, *a, **k):
        out = None
        for _ in progress.track([0], desc, total=1):
            out = fn(*a, **k)
        return out
    return step


def _generate(out: Path, seed: int, small: bool, progress, dive_id: str, usbl_interval_s: float | None = None) -> None:
    step = _steps(progress)
    r = _rngs(seed)
    r_terrain, r_track, r_track2, r_err, r_sens, r_mb, r_laser = (r[k] for k in RNG_STREAMS[:7])

    frame = LocalFrame(sc.MAP_ORIGIN_LAT_DEG, sc.MAP_ORIGIN_LON_DEG)
    launch_xy = np.array(frame.to_xy(sc.LAUNCH_LON_DEG, sc.LAUNCH_LAT_DEG), float)
    start_xy = np.array(frame.to_xy(sc.BOTTOM_START_LON_DEG, sc.BOTTOM_START_LAT_DEG), float)
    deep_xy = np.array(frame.to_xy(sc.DEEPEST_LON_DEG, sc.DEEPEST_LAT_DEG), float)

    ter, layout = step("terrain", base_terrain, r_terrain)
    track, terrain_info = step("trajectory", _trajectory, ter, layout, r_track, r_track2, launch_xy, start_xy, deep_xy)
    water = WaterColumn(sc.LAUNCH_LAT_DEG, sc.LAUNCH_LON_DEG)
    err = _sensors.SensorErrors.draw(r_err)
    rates = _sensors.SMALL_RATES_HZ if small else _sensors.FULL_RATES_HZ
    channels = step("sensors", _sensors.simulate, track, ter, water, err, rates, r_sens)
    channels["gnss"] = _sensors.simulate_gnss(track, frame, r["gnss"])  # launch and recovery fixes
    if usbl_interval_s is not None:  # the ship over the launch point
        channels["usbl"] = _sensors.simulate_usbl(track, frame, r["usbl"], float(usbl_interval_s),
                                                  (float(launch_xy[0]), float(launch_xy[1])))

    t0_ms = int(sc.LAUNCH_TIME_UTC.timestamp() * 1000)
    (out / "logs").mkdir()
    counts = step("MCAP log", _w.write_mcap, out / "logs" / "haidou.mcap", channels, t0_ms)
    csv_files = step("CSV files", _w.write_csvs, out / "csv", channels, t0_ms)

    # multibeam
    mb = SMALL_MB if small else FULL_MB
    mb = _mb.MultibeamModel(**{**mb.__dict__, "bias_m": round(float(r_mb.uniform(3.0, 6.0)), 2)})
    (out / "multibeam").mkdir()
    mb_files, n_sound = [], 0
    lines = _mb.line_positions(ter, mb.n_lines)
    for i in progress.track(range(mb.n_lines), "multibeam lines", total=mb.n_lines):
        sx, sy, _true, meas = _mb.survey_line(r_mb, ter, mb, float(lines[i]), westward=bool(i % 2))
        lon, lat = _mb.to_lonlat(frame, sx, sy)
        rel = f"multibeam/em122_line{i + 1:02d}.xyz.gz"
        _w.write_gzip_text(out / rel, _w.soundings_text(lon, lat, meas), level=4)
        mb_files.append(rel)
        n_sound += len(sx)

    # laser submaps
    (out / "laser").mkdir()
    specs = _laser.submap_specs(r_laser, small)
    laser_files, laser_truth = [], []
    for sp in progress.track(specs, "laser submaps", total=len(specs)):
        pts, info = _laser.make_submap(r_laser, sp)
        rel = f"laser/submap_{sp.index:02d}.ply"
        _w.write_ply(out / rel, pts, f"hadal.synth laser submap {sp.index:02d}: x east, y north, z elevation (m), "
                                     "local frame of the laser survey")
        laser_files.append(rel)
        laser_truth.append({"file": rel, **{k: (round(v, 4) if isinstance(v, float) else v) for k, v in info.items()}})

    # truth
    (out / "truth").mkdir()
    ter_attrs = {
        "title": "hadal.synth true reference terrain (sample dive)",
        "map_frame_origin_latitude_deg": sc.MAP_ORIGIN_LAT_DEG,
        "map_frame_origin_longitude_deg": sc.MAP_ORIGIN_LON_DEG,
        "crs_proj4": frame.crs.srs,
        "resolution_m": sc.MAP_RES_M,
        "seed": seed,
    }
    step("terrain file", _w.write_terrain, out / "truth" / "terrain.nc", ter.x, ter.y, ter.depth, ter_attrs)
    tdf = _track_frame(track, frame, water)
    _w.write_track(out / "truth" / "track.parquet", tdf)

    vehicle_rel = _copy_vehicle(out, with_usbl="usbl" in channels)
    _write_dive_yaml(out, seed, small, vehicle_rel, csv_files, mb_files, laser_files, dive_id)
    _write_pipeline_yaml(out, rates, small)
    truth = _truth(seed, small, frame, ter, track, water, err, rates, counts, mb, n_sound, laser_truth,
                   terrain_info, launch_xy, start_xy, deep_xy)
    if usbl_interval_s is not None:
        u = channels["usbl"]
        truth["sensors"]["usbl"] = {
            "interval_s": float(usbl_interval_s), "ship_x_east_m": _r(launch_xy[0], 3),
            "ship_y_north_m": _r(launch_xy[1], 3), "range_fraction": _sensors.USBL_RANGE_FRACTION,
            "min_sigma_m": _sensors.USBL_MIN_SIGMA_M, "n_fixes": int(u["t_ms"].size),
            "comment": "fixes = true position + white noise of sigma per axis = max(min_sigma_m, range_fraction x "
                       "slant range from the ship over the launch point); that variance logged with each fix"}
    (out / "truth.json").write_text(json.dumps(truth, indent=2) + "\n", encoding="utf-8")


#: the generator's random streams (a new stream goes last: the earlier ones, spawned by index, stay unchanged)
RNG_STREAMS = ("terrain", "track", "track2", "errors", "sensors", "multibeam", "laser", "gnss", "usbl")


def _rngs(seed: int) -> dict[str, np.random.Generator]:
    """Independent random streams of the generator's components, all derived from ``seed``."""
    ss = np.random.SeedSequence([int(seed), 0x5E11])
    return {k: np.random.default_rng(s) for k, s in zip(RNG_STREAMS, ss.spawn(len(RNG_STREAMS)), strict=True)}


def _trajectory(ter: Terrain, layout, r_track, r_track2, launch_xy, start_xy, deep_xy) -> tuple[Track, dict]:
    """Horizontal path, then terrain/controller calibration so that the vehicle's deepest depth is exactly
    10 905 m at the node nearest the paper's deepest point, and the map's deepest cell is exactly 10 928 m.

    The bilinear 20 m surface can only peak at cell centres, so the deepest point is not made by a terrain
    dimple: the floor around it is flattened into a shallow flat-bottomed pan (radius ~250 m) a little
    deeper than the surrounding floor, and the vehicle's depth controller makes a 1.5 m excursion there
    (a Gaussian in time, 20 s), whose peak is the recorded deepest point.
    """
    h = build_horizontal(r_track, launch_xy, start_xy, deep_xy)
    nd, nb = sc.DESCENT_S, sc.BOTTOM_S
    k = h["i_deepest"] - nd
    px, py = float(h["x"][h["i_deepest"]]), float(h["y"][h["i_deepest"]])
    heave = 0.12 * smooth_noise(r_track, nb + 1, 30.0)
    # remove the heave's local trend at the deepest node so the maximum is not dragged along the track
    tt = np.arange(nb + 1, dtype=float) - k
    slope = (heave[min(k + 5, nb)] - heave[max(k - 5, 0)]) / (min(k + 5, nb) - max(k - 5, 0))
    heave = heave - slope * tt * np.exp(-0.5 * (tt / 60.0) ** 2)
    dip_m = 1.5
    heave = heave + dip_m * np.exp(-0.5 * (tt / 20.0) ** 2)
    level = sc.DEEPEST_VEHICLE_DEPTH_M + sc.SURVEY_ALTITUDE_M - float(heave[k])
    flatten_disc(ter, px, py, 250.0, level=level)
    pool_iy, pool_ix = set_pool(ter, layout)
    ter.depth = ter.depth.astype(np.float32).astype(np.float64)
    track = build_track(r_track2, h, ter, heave)
    i = int(np.argmax(track.depth))
    dmax = float(track.depth[i])
    far = np.abs(np.arange(len(track.depth)) - h["i_deepest"]) > 60
    if abs(dmax - sc.DEEPEST_VEHICLE_DEPTH_M) > 0.01 or i != h["i_deepest"] or \
            track.depth[far].max() > sc.DEEPEST_VEHICLE_DEPTH_M - 0.2:
        raise RuntimeError(f"synth: deepest point calibration failed (max {dmax:.3f} m at node {i}, "
                           f"wanted node {h['i_deepest']}; elsewhere {track.depth[far].max():.3f} m)")
    if float(ter.depth.min()) != sc.MAP_MIN_DEPTH_M or float(ter.depth.max()) != sc.MAP_MAX_DEPTH_M:
        raise RuntimeError(f"synth: terrain range {ter.depth.min()}..{ter.depth.max()} m off design")
    return track, {"deepest_pan_level_m": round(level, 3), "deepest_pan_radius_m": 250.0,
                   "controller_dip_at_deepest_m": dip_m, "pool_cell_yx": [pool_iy, pool_ix]}


def _track_frame(track: Track, frame: LocalFrame, water: WaterColumn) -> pd.DataFrame:
    lon, lat = frame.to_lonlat(track.x, track.y)
    time = pd.to_datetime(sc.LAUNCH_TIME_UTC) + pd.to_timedelta(track.t, unit="s")
    return pd.DataFrame({
        "time": time.astype("datetime64[ns, UTC]"),
        "lon": np.asarray(lon), "lat": np.asarray(lat),
        "x_east_m": track.x, "y_north_m": track.y,
        "depth_m": track.depth, "altitude_m": track.altitude, "seafloor_depth_m": track.seafloor,
        "pressure_dbar": water.pressure_from_depth(track.depth),
        "phase": pd.Categorical.from_codes(track.phase.astype(np.int8), categories=list(PHASES)).astype(str),
    })


#: the vehicle.yaml block of the optional USBL channel (appended to the dive's copy when the sample has USBL)
_USBL_VEHICLE_BLOCK = """  usbl:                     # USBL fixes from the support ship (hadal synth --usbl-interval-s); the navigation smoother's fixes
    mcap:
      topic: /haidou/usbl
      time: {field: log_time, format: unix_ns}
      fields:
        usbl_latitude_deg: {field: latitude, units: deg}
        usbl_longitude_deg: {field: longitude, units: deg}
        usbl_east_variance_m2: {field: east_variance, units: m2}
        usbl_north_variance_m2: {field: north_variance, units: m2}
    csv:
      source: usbl
      time: {field: time, format: iso8601}
      fields:
        usbl_latitude_deg: {field: latitude_deg, units: deg}
        usbl_longitude_deg: {field: longitude_deg, units: deg}
        usbl_east_variance_m2: {field: east_variance_m2, units: m2}
        usbl_north_variance_m2: {field: north_variance_m2, units: m2}
"""


def _copy_vehicle(out: Path, with_usbl: bool = False) -> str | None:
    """Copy the Haidou vehicle mapping (ingest's VehicleConfig) if the package or repo provides it (with the USBL
    channel's mapping appended when ``with_usbl``)."""
    cands = []
    try:
        cands.append(importlib.resources.files("hadal") / "data" / "vehicles" / "haidou.yaml")
    except (ModuleNotFoundError, TypeError):
        pass
    cands.append(Path(hadal.__file__).resolve().parents[2] / "config" / "vehicles" / "haidou.yaml")
    for c in cands:
        try:
            if c.is_file():
                text = c.read_bytes()
                if with_usbl:
                    text = text.rstrip(b"\n") + b"\n" + _USBL_VEHICLE_BLOCK.encode()
                (out / "vehicle.yaml").write_bytes(text)
                return "vehicle.yaml"
        except OSError:
            continue
    return None


def _write_dive_yaml(out: Path, seed: int, small: bool, vehicle_rel, csv_files, mb_files, laser_files,
                     dive_id: str) -> None:
    d = {
        "dive_id": dive_id,
        "platform": sc.PLATFORM,
    }
    if vehicle_rel:
        d["vehicle_config"] = vehicle_rel
    d["launch"] = {"time_utc": sc.LAUNCH_TIME_UTC.strftime("%Y-%m-%dT%H:%M:%SZ"),
                   "latitude_deg": round(sc.LAUNCH_LAT_DEG, 8), "longitude_deg": round(sc.LAUNCH_LON_DEG, 8)}
    d["map_frame"] = {"origin_latitude_deg": sc.MAP_ORIGIN_LAT_DEG, "origin_longitude_deg": sc.MAP_ORIGIN_LON_DEG}
    d["sources"] = {"mcap": ["logs/haidou.mcap"], "csv": dict(csv_files), "cnv": [],
                    "multibeam": list(mb_files), "laser": list(laser_files)}
    # discovery metadata of the sample (synthetic: the addresses are RFC 2606 example domains on purpose)
    d["metadata"] = {"creator_name": "hadal.synth sample generator", "creator_type": "group",
                     "creator_email": "sample-dive@example.org", "creator_url": "https://example.org/hadal-sample",
                     "institution": "synthetic sample dive (no institution)", "project": "hadal sample dive",
                     "license": "CC0-1.0", "naming_authority": "org.example.hadal-sample",
                     "instruments": {"ctd": "Sea-Bird SBE 49 FastCAT CTD (simulated)",
                                     "dtm": "Kongsberg EM122 multibeam echosounder (simulated)",
                                     "laser_grids": "structured-light laser scanner (simulated)"}}
    # the laser survey's local frame: origin at the launch point, +y axis 15 degrees east of north
    d["laser_frame"] = {"origin_latitude_deg": round(sc.LAUNCH_LAT_DEG, 8),
                        "origin_longitude_deg": round(sc.LAUNCH_LON_DEG, 8), "heading_deg": 15.0}
    d["notes"] = (f"Synthetic sample dive written by hadal.synth (seed {seed}{', small' if small else ''}): "
                  "Haidou in the Challenger Deep after Zhang et al. (TERCOM) sections 2 and 4. "
                  "Ground truth in truth.json and truth/ (never read by the pipeline).")
    with open(out / "dive.yaml", "w", encoding="utf-8") as fh:
        yaml.safe_dump(d, fh, sort_keys=False, allow_unicode=True, width=100)


def _write_pipeline_yaml(out: Path, rates: dict[str, float], small: bool) -> None:
    """Dive-level configuration of the sample: the DTM cell size of the paper's EM122 survey (20 m) pinned, so
    the sample's results do not depend on the automatic choice; the small sample's sensors are logged at
    reduced rates, so its ingest interpolation gap limits are 1.5 sampling intervals (the defaults suit the
    full rates)."""
    cfg: dict = {"grid": {"dtm_resolution_m": 20.0}}
    text = "# sample dive: the TERCOM paper's 20 m DTM cells\n"
    if small:
        sensor_of = {"gauge": "keller", "altimeter": "altimeter", "attitude": "attitude", "position": "dr"}
        cfg["ingest"] = {"max_gap_s": {k: max(2.0, 1.5 / rates[v]) for k, v in sensor_of.items()}}
        text += "# small sample dive: sensors logged at reduced rates -> gap limits of 1.5 sampling intervals\n"
    (out / "pipeline.yaml").write_text(text + yaml.safe_dump(cfg, sort_keys=False), encoding="utf-8")


def _iso(t_s: float) -> str:
    t = sc.LAUNCH_TIME_UTC + _dt.timedelta(seconds=float(t_s))
    return t.strftime("%Y-%m-%dT%H:%M:%S.") + f"{t.microsecond // 1000:03d}Z"


def _r(v, n=6):
    return round(float(v), n)


def _truth_positions(frame, track, water) -> dict:
    """Truth of the track's key points: ``bottom_track_start``/``_end``, ``surfacing``, ``deepest_point``
    (times, degrees, m east/north in the map frame, depths in m, pressure in dbar) and ``drift_m`` (m,
    launch point to bottom-track start)."""
    ib, ie, idp = track.i_bottom_start, track.i_bottom_end, track.i_deepest
    lon_b, lat_b = (float(v) for v in frame.to_lonlat(track.x[ib], track.y[ib]))
    lon_d, lat_d = (float(v) for v in frame.to_lonlat(track.x[idp], track.y[idp]))
    drift = geodesic_distance_m(sc.LAUNCH_LON_DEG, sc.LAUNCH_LAT_DEG, lon_b, lat_b)
    lon_s, lat_s = (float(v) for v in frame.to_lonlat(track.x[-1], track.y[-1]))
    return {
        "bottom_track_start": {"time": _iso(track.t[ib]), "t_since_launch_s": _r(track.t[ib], 3),
                               "latitude_deg": _r(lat_b, 8), "longitude_deg": _r(lon_b, 8),
                               "x_east_m": _r(track.x[ib], 3), "y_north_m": _r(track.y[ib], 3),
                               "depth_m": _r(track.depth[ib], 3), "seafloor_depth_m": _r(track.seafloor[ib], 3),
                               "position": format_position(lat_b, lon_b)},
        "bottom_track_end": {"time": _iso(track.t[ie]), "t_since_launch_s": _r(track.t[ie], 3),
                             "x_east_m": _r(track.x[ie], 3), "y_north_m": _r(track.y[ie], 3)},
        "surfacing": {"time": _iso(track.t[-1]), "latitude_deg": _r(lat_s, 8), "longitude_deg": _r(lon_s, 8)},
        "deepest_point": {"time": _iso(track.t[idp]), "t_since_launch_s": _r(track.t[idp], 3),
                          "latitude_deg": _r(lat_d, 8), "longitude_deg": _r(lon_d, 8),
                          "x_east_m": _r(track.x[idp], 3), "y_north_m": _r(track.y[idp], 3),
                          "depth_m": _r(track.depth[idp], 4), "seafloor_depth_m": _r(track.seafloor[idp], 4),
                          "altitude_m": _r(track.altitude[idp], 4),
                          "pressure_dbar": _r(water.pressure_from_depth(track.depth[idp]), 3),
                          "position": format_position(lat_d, lon_d),
                          "paper_position": format_position(sc.DEEPEST_LAT_DEG, sc.DEEPEST_LON_DEG),
                          "offset_from_paper_position_m": _r(geodesic_distance_m(
                              sc.DEEPEST_LON_DEG, sc.DEEPEST_LAT_DEG, lon_d, lat_d), 3)},
        "drift_m": _r(drift, 3),
    }


def _truth_bottom_survey(track) -> dict:
    """Truth of the bottom survey: set altitude, altitude and seafloor-depth ranges (m), track length (m) and
    waypoints (m, map frame)."""
    b = slice(track.i_bottom_start, track.i_bottom_end + 1)
    return {"set_altitude_m": sc.SURVEY_ALTITUDE_M,
            "altitude_range_m": [_r(track.altitude[b].min(), 3), _r(track.altitude[b].max(), 3)],
            "seafloor_range_m": [_r(track.seafloor[b].min(), 3), _r(track.seafloor[b].max(), 3)],
            "length_m": _r(np.hypot(np.diff(track.x[b]), np.diff(track.y[b])).sum(), 1),
            "waypoints_xy_m": np.round(track.info["waypoints"], 2).tolist()}


def _truth_map(ter, terrain_info) -> dict:
    """Truth of the reference terrain map: frame, shape, 20 m resolution, x/y ranges and depth range (m)."""
    return {"frame": "transverse Mercator (hadal.geo.LocalFrame)",
            "origin_latitude_deg": sc.MAP_ORIGIN_LAT_DEG, "origin_longitude_deg": sc.MAP_ORIGIN_LON_DEG,
            "shape_yx": [int(ter.depth.shape[0]), int(ter.depth.shape[1])], "resolution_m": sc.MAP_RES_M,
            "x_range_m": [_r(ter.x[0], 3), _r(ter.x[-1], 3)], "y_range_m": [_r(ter.y[0], 3), _r(ter.y[-1], 3)],
            "min_depth_m": float(ter.depth.min()), "max_depth_m": float(ter.depth.max()),
            "surface": "bilinear interpolation of truth/terrain.nc cell centres",
            **terrain_info}


def _truth_water_column(water) -> dict:
    """Truth of the water column: position (degrees), depth-pressure conversion, heave (dbar rms), profile."""
    return {"latitude_deg": _r(water.latitude_deg, 8), "longitude_deg": _r(water.longitude_deg, 8),
            "depth_pressure": "TEOS-10 gsw.z_from_p/p_from_z with geo_strf_dyn_height (p_ref 0) of "
                              "this profile on a 1 dbar grid",
            "internal_wave_heave_dbar_rms": 4.0,
            "profile": water.summary()}


def _truth_sensors(err, rates, counts) -> dict:
    """Truth of the simulated sensors: rates (Hz), message counts and each sensor's errors (in the units
    their keys name)."""
    return {
        "rates_hz": rates, "message_counts": counts,
        "ctd": {"pressure_offset_dbar": err.ctd_pressure_offset_dbar,
                "pressure_noise_dbar": err.ctd_pressure_noise_dbar,
                "pressure_saturation_dbar": _sensors.SBE49_MAX_DBAR,
                "temperature_noise_degc": err.ctd_temperature_noise_degc,
                "conductivity_noise_s_m": err.ctd_conductivity_noise_s_m},
        "keller": {"offset_dbar": err.keller_offset_dbar, "noise_dbar": err.keller_noise_dbar,
                   "resolution_dbar": _sensors.KELLER_RESOLUTION_DBAR, "range_dbar": _sensors.KELLER_MAX_DBAR,
                   "gauge_minus_ctd_dbar": _r(err.keller_offset_dbar - err.ctd_pressure_offset_dbar, 4)},
        "altimeter": {"nominal_sound_speed_m_s": _sensors.ALTIMETER_NOMINAL_SOUND_SPEED_M_S,
                      "range_reported": "true_range * nominal_sound_speed / local_sound_speed, quantised",
                      "resolution_m": _sensors.ALTIMETER_RESOLUTION_M,
                      "max_range_m": _sensors.ALTIMETER_MAX_RANGE_M,
                      "noise_m": err.altimeter_noise_m, "dropout_fraction": err.altimeter_dropout_fraction},
        "attitude": {"compass_bias_deg": err.compass_bias_deg, "heading_noise_deg": err.heading_noise_deg},
        "gnss": {"sigma_m_per_axis": _sensors.GNSS_SIGMA_M, "surface_seconds": _sensors.GNSS_SURFACE_S,
                 "comment": "1 Hz fixes the first and last surface_seconds of the dive (launch, recovery): true "
                            "position + white noise"},
    }


def _truth(seed, small, frame, ter, track, water, err, rates, counts, mb, n_sound, laser_truth, terrain_info,
           launch_xy, start_xy, deep_xy) -> dict:
    """The ``truth.json`` record of the sample dive (units in the key names)."""
    positions = _truth_positions(frame, track, water)
    return {
        "generator": GENERATOR, "format_version": FORMAT_VERSION, "hadal_version": getattr(hadal, "__version__", ""),
        "seed": seed, "small": small,
        "sources": {"paper": "Zhang et al., Terrain matching localization for hybrid underwater vehicle in the "
                             "Challenger Deep of the Mariana Trench, sections 2 and 4",
                    "laser": "Sangekar et al., Autonomous landing of underwater vehicles using high resolution "
                             "bathymetry, sections III-IV"},
        "launch": {"time": _iso(0.0), "latitude_deg": _r(sc.LAUNCH_LAT_DEG, 8),
                   "longitude_deg": _r(sc.LAUNCH_LON_DEG, 8),
                   "x_east_m": _r(launch_xy[0], 3), "y_north_m": _r(launch_xy[1], 3),
                   "position": format_position(sc.LAUNCH_LAT_DEG, sc.LAUNCH_LON_DEG)},
        **positions,
        "phases_s": {"descent": sc.DESCENT_S, "bottom": sc.BOTTOM_S, "ascent": sc.ASCENT_S},
        "bottom_survey": _truth_bottom_survey(track),
        "map": _truth_map(ter, terrain_info),
        "water_column": _truth_water_column(water),
        "sensors": _truth_sensors(err, rates, counts),
        "dr_error": {"heading_bias_deg": err.compass_bias_deg, "scale_error": err.dr_scale_error,
                     "velocity_noise_m_s": err.dr_velocity_noise_m_s, "velocity_noise_correlation_s": 300.0,
                     "model": "v_dr = (1 + scale_error) * R(heading_bias) * v_true + noise; DR = 0 until the "
                              "bottom-track start (no velocity reference during the descent), held during the "
                              "ascent; true map position = launch_xy + true displacement"},
        "multibeam": {**mb.truth(), "n_soundings": int(n_sound),
                      "soundings_per_cell": _r(n_sound / ter.depth.size, 3)},
        "laser": {"frame": "local frame of the laser survey: x east, y north, z elevation (up), metres; "
                           "a rocky seamount slope near 1400 m (Takuyo-Daigo-like), not in the trench map",
                  "submaps": laser_truth},
    }
