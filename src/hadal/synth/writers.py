"""Byte-deterministic writers for the raw dive directory (docs/architecture.md "Raw dive directory").

No wall-clock time goes into any file: gzip members have mtime 0 and no file name, the MCAP writer gets
no metadata records, NetCDF/Parquet carry only data-derived attributes.
"""

from __future__ import annotations

import gzip
import json
from collections.abc import Callable
from importlib.resources import files
from pathlib import Path

import numpy as np
import pandas as pd
import xarray as xr
from mcap.writer import CompressionType, Writer

from hadal.synth.sensors import KELLER_MAX_DBAR, SBE49_MAX_DBAR

#: MCAP topic and JSON Schema file (``schemas/mcap/<file>``, package data of ``hadal.schemas``) of each of the
#: six channels (architecture.md "MCAP channels"). The schemas are declared once, in those files; the MCAP
#: schema name is the schema's ``title``.
_CHANNEL_FILES: dict[str, tuple[str, str]] = {
    "ctd": ("/haidou/ctd", "haidou_ctd.json"),
    "keller": ("/haidou/keller", "haidou_keller.json"),
    "altimeter": ("/haidou/altimeter", "haidou_altimeter.json"),
    "attitude": ("/haidou/attitude", "haidou_attitude.json"),
    "dr": ("/haidou/dr", "haidou_dr.json"),
    "gnss": ("/haidou/gnss", "haidou_gnss.json"),
    "usbl": ("/haidou/usbl", "haidou_usbl.json"),
}


def load_channel_schema(file_name: str) -> dict:
    """The JSON Schema ``schemas/mcap/<file_name>`` (installed as ``hadal.schemas``)."""
    return json.loads((files("hadal.schemas") / "mcap" / file_name).read_text(encoding="utf-8"))


def _channels() -> dict[str, dict]:
    out: dict[str, dict] = {}
    for name, (topic, file_name) in _CHANNEL_FILES.items():
        schema = load_channel_schema(file_name)
        out[name] = {"topic": topic, "schema_name": schema["title"], "schema": schema}
    # the sensor limits the generator simulates are the ones the schemas state
    for name, field, limit in (("ctd", "pres", SBE49_MAX_DBAR), ("keller", "pressure", KELLER_MAX_DBAR)):
        if out[name]["schema"]["properties"][field].get("maximum") != limit:
            raise ValueError(f"schemas/mcap/{_CHANNEL_FILES[name][1]}: {field} maximum differs from the simulated "
                             f"sensor range {limit:g} dbar")
    return out


#: MCAP topics, schema names and JSON Schemas of the channels, read from ``schemas/mcap/*.json``
CHANNELS: dict[str, dict] = _channels()
#: the channels in file order; ``usbl`` only when the sample has USBL fixes (``hadal synth --usbl-interval-s``)
CHANNEL_ORDER = ("ctd", "keller", "altimeter", "attitude", "dr", "gnss", "usbl")


def _stamps(t_unix_ms: np.ndarray) -> list[str]:
    s, ms = np.divmod(t_unix_ms, 1000)
    return [f"{a}.{b:03d}" for a, b in zip(s.tolist(), ms.tolist(), strict=True)]


def payloads(name: str, ch: dict[str, np.ndarray], t0_unix_ms: int) -> list[bytes]:
    """JSON message bodies (compact, fixed decimals) of one channel."""
    st = _stamps(ch["t_ms"] + t0_unix_ms)
    if name == "ctd":
        rows = zip(st, ch["cond"].tolist(), ch["temp"].tolist(), ch["pres"].tolist(), strict=True)
        return [f'{{"stamp":{s},"cond":{c:.5f},"temp":{t:.4f},"pres":{p:.3f}}}'.encode() for s, c, t, p in rows]
    if name == "keller":
        return [f'{{"stamp":{s},"pressure":{p:.2f}}}'.encode() for s, p in zip(st, ch["pressure"].tolist(), strict=True)]
    if name == "altimeter":
        out = []
        for s, r, v in zip(st, ch["range"].tolist(), ch["valid"].tolist(), strict=True):
            out.append((f'{{"stamp":{s},"range":{r:.1f},"valid":true}}' if v
                        else f'{{"stamp":{s},"range":null,"valid":false}}').encode())
        return out
    if name == "attitude":
        rows = zip(st, ch["heading"].tolist(), ch["pitch"].tolist(), ch["roll"].tolist(), strict=True)
        return [f'{{"stamp":{s},"heading":{h:.2f},"pitch":{p:.2f},"roll":{r:.2f}}}'.encode() for s, h, p, r in rows]
    if name == "dr":
        rows = zip(st, ch["east"].tolist(), ch["north"].tolist(), ch["speed"].tolist(), strict=True)
        return [f'{{"stamp":{s},"east":{e:.3f},"north":{n:.3f},"speed":{v:.3f}}}'.encode() for s, e, n, v in rows]
    if name in ("gnss", "usbl"):
        fixes = zip(st, ch["latitude"].tolist(), ch["longitude"].tolist(), ch["east_variance"].tolist(),
                    ch["north_variance"].tolist(), strict=True)
        return [f'{{"stamp":{s},"latitude":{a:.8f},"longitude":{o:.8f},"east_variance":{e:.2f},"north_variance":{n:.2f}}}'
                .encode() for s, a, o, e, n in fixes]
    raise KeyError(name)


def write_mcap(path: Path, channels: dict[str, dict[str, np.ndarray]], t0_unix_ms: int, progress=None) -> dict:
    """One MCAP file, JSON messages with jsonschema schemas, zstd chunks, messages in log_time order (the
    channels of :data:`CHANNEL_ORDER` present in ``channels``)."""
    order_names = [n for n in CHANNEL_ORDER if n in channels]
    times, chans, bodies = [], [], []
    for k, name in enumerate(order_names):
        ch = channels[name]
        times.append((ch["t_ms"] + t0_unix_ms) * 1_000_000)
        chans.append(np.full(len(ch["t_ms"]), k, dtype=np.int64))
        bodies.extend(payloads(name, ch, t0_unix_ms))
    t_ns = np.concatenate(times)
    c = np.concatenate(chans)
    seq = np.concatenate([np.arange(len(ch["t_ms"])) for ch in (channels[n] for n in order_names)])
    order = np.lexsort((seq, c, t_ns))
    counts = {}
    with open(path, "wb") as fh:
        w = Writer(fh, chunk_size=4 * 1024 * 1024, compression=CompressionType.ZSTD)
        w.start(profile="", library="hadal.synth")
        ids = []
        for name in order_names:
            spec = CHANNELS[name]
            sid = w.register_schema(name=spec["schema_name"], encoding="jsonschema",
                                    data=json.dumps(spec["schema"], indent=None, sort_keys=False).encode())
            ids.append(w.register_channel(topic=spec["topic"], message_encoding="json", schema_id=sid,
                                          metadata={"vehicle": "Haidou"}))
        add = w.add_message
        t_l = t_ns[order].tolist()
        c_l = c[order].tolist()
        s_l = seq[order].tolist()
        o_l = order.tolist()
        it = range(len(o_l))
        if progress is not None:
            it = progress.track(it, "writing MCAP", total=len(o_l))
        for i in it:
            add(channel_id=ids[c_l[i]], log_time=t_l[i], publish_time=t_l[i], sequence=s_l[i], data=bodies[o_l[i]])
        w.finish()
    for name in order_names:
        counts[CHANNELS[name]["topic"]] = int(len(channels[name]["t_ms"]))
    return counts


def _iso_ms(t_unix_ms: np.ndarray) -> np.ndarray:
    return np.char.add(np.datetime_as_string(t_unix_ms.astype("datetime64[ms]"), unit="ms"), "Z")


def write_csvs(csv_dir: Path, channels: dict[str, dict[str, np.ndarray]], t0_unix_ms: int) -> dict[str, str]:
    """The CSV variants (other units and time format, architecture.md "CSV variants"). Returns {key: relpath}."""
    csv_dir.mkdir(parents=True, exist_ok=True)
    files = {}

    def emit(key: str, channel: str, fname: str, header: str, row: Callable[..., str], *cols: str) -> None:
        ch = channels[channel]
        t = _iso_ms(ch["t_ms"] + t0_unix_ms).tolist()
        lines = (row(a, *vals) for a, *vals in zip(t, *(ch[c].tolist() for c in cols), strict=True))
        with open(csv_dir / fname, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(header + "\n")
            fh.write("\n".join(lines))
            fh.write("\n")
        files[key] = f"csv/{fname}"

    emit("ctd", "ctd", "ctd.csv", "time,conductivity_mS_cm,temperature_ITS90,pressure_dbar",
         lambda a, c, b, p: f"{a},{c * 10:.4f},{b:.4f},{p:.3f}", "cond", "temp", "pres")
    emit("gauge", "keller", "keller.csv", "time,pressure_bar", lambda a, p: f"{a},{p / 10:.3f}", "pressure")
    emit("altimeter", "altimeter", "altimeter.csv", "time,altitude_m",
         lambda a, r, v: f"{a},{r:.1f}" if v else f"{a},", "range", "valid")
    emit("attitude", "attitude", "attitude.csv", "time,heading_deg,pitch_deg,roll_deg",
         lambda a, h, p, r: f"{a},{h:.2f},{p:.2f},{r:.2f}", "heading", "pitch", "roll")
    emit("dr", "dr", "dr.csv", "time,east_m,north_m,speed_m_s",
         lambda a, e, n, v: f"{a},{e:.3f},{n:.3f},{v:.3f}", "east", "north", "speed")
    emit("gnss", "gnss", "gnss.csv", "time,latitude_deg,longitude_deg,east_variance_m2,north_variance_m2",
         lambda a, la, lo, e, n: f"{a},{la:.8f},{lo:.8f},{e:.2f},{n:.2f}", "latitude", "longitude", "east_variance",
         "north_variance")
    if "usbl" in channels:
        emit("usbl", "usbl", "usbl.csv", "time,latitude_deg,longitude_deg,east_variance_m2,north_variance_m2",
             lambda a, la, lo, e, n: f"{a},{la:.8f},{lo:.8f},{e:.2f},{n:.2f}", "latitude", "longitude",
             "east_variance", "north_variance")
    return files


def write_gzip_text(path: Path, text: str, level: int = 6) -> None:
    """gzip with no file name and mtime 0 (byte-deterministic)."""
    with open(path, "wb") as raw, gzip.GzipFile(filename="", mode="wb", fileobj=raw, mtime=0,
                                                compresslevel=level) as gz:
        gz.write(text.encode("ascii"))


def soundings_text(lon: np.ndarray, lat: np.ndarray, depth: np.ndarray) -> str:
    """``longitude_deg latitude_deg depth_m`` lines (7 decimals ~1 cm, depth to cm)."""
    cols = [(np.asarray(lon, float), 7), (np.asarray(lat, float), 7), (np.asarray(depth, float), 2)]
    if len(cols[0][0]) and all(np.isfinite(v).all() and v.min() >= 1.0 and v.max() < 1e6 for v, _ in cols):
        return _fixed_point_lines(cols)
    fmt = "{:.7f} {:.7f} {:.2f}\n".format
    return "".join(map(fmt, np.asarray(lon, float).tolist(), np.asarray(lat, float).tolist(),
                       np.asarray(depth, float).tolist()))


def _fixed_point_lines(cols: list[tuple[np.ndarray, int]]) -> str:
    """Vectorised ``%.Nf`` formatting of positive columns (space separated, one row per line).

    Same text as Python's formatting (round half to even on the scaled value may differ from the
    decimal rounding of ``format`` in the last digit for exact ties; values here are noisy floats).
    """
    n = len(cols[0][0])
    parts: list[np.ndarray] = []  # (n, w) uint8 blocks
    masks: list[np.ndarray] = []
    for k, (v, dec) in enumerate(cols):
        iv = np.round(v * 10**dec).astype(np.int64)
        n_int = max(int(np.floor(np.log10(max(int(iv.max()) // 10**dec, 1)))) + 1, 1)
        width = n_int + 1 + dec
        block = np.empty((n, width), np.uint8)
        rest = iv.copy()
        for j in range(width - 1, -1, -1):
            if j == n_int:
                block[:, j] = ord(".")
                continue
            rest, d = np.divmod(rest, 10)
            block[:, j] = d + ord("0")
        # leading zeros of the integer part are dropped (but keep one digit before the point)
        ipart = iv // 10**dec
        ndig = np.maximum(np.floor(np.log10(np.maximum(ipart, 1))).astype(int) + 1, 1)
        keep = np.arange(width)[None, :] >= (n_int - ndig)[:, None]
        parts.append(block)
        masks.append(keep)
        sep = np.full((n, 1), ord("\n" if k == len(cols) - 1 else " "), np.uint8)
        parts.append(sep)
        masks.append(np.ones((n, 1), bool))
    mat = np.concatenate(parts, axis=1)
    msk = np.concatenate(masks, axis=1)
    return mat[msk].tobytes().decode("ascii")


def write_ply(path: Path, xyz: np.ndarray, comment: str) -> None:
    """Binary little-endian PLY, float64 x y z."""
    xyz = np.ascontiguousarray(xyz, dtype="<f8")
    header = ("ply\nformat binary_little_endian 1.0\n"
              f"comment {comment}\n"
              f"element vertex {len(xyz)}\n"
              "property double x\nproperty double y\nproperty double z\nend_header\n")
    with open(path, "wb") as fh:
        fh.write(header.encode("ascii"))
        fh.write(xyz.tobytes())


def write_terrain(path: Path, x: np.ndarray, y: np.ndarray, depth: np.ndarray, attrs: dict) -> None:
    """truth/terrain.nc: depth_m (y, x) positive down, ascending cell-centre coordinates (map frame, m)."""
    ds = xr.Dataset(
        {"depth_m": (("y", "x"), depth.astype(np.float32),
                     {"units": "m", "standard_name": "sea_floor_depth_below_sea_surface",
                      "long_name": "true seafloor depth (positive down)", "positive": "down"})},
        coords={"x": ("x", x, {"units": "m", "long_name": "x (east) in the dive's map frame", "axis": "X"}),
                "y": ("y", y, {"units": "m", "long_name": "y (north) in the dive's map frame", "axis": "Y"})},
        attrs=attrs,
    )
    ds.to_netcdf(path, engine="h5netcdf",
                 encoding={"depth_m": {"zlib": True, "complevel": 4, "shuffle": True, "chunksizes": (295, 397)}})


def write_track(path: Path, df: pd.DataFrame) -> None:
    df.to_parquet(path, index=False, engine="pyarrow", compression="zstd")
