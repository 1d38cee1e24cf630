"""Small synthetic products that follow the contract in docs/architecture.md (tests, benchmarks, demos).

:func:`publish_fake_products` publishes a tiny but physically plausible dive (a 3-phase hadal dive
sampled at 1 Hz, a 20 m DTM, a suitability block grid, a TERCOM-like match and landing sites) into a
store, so the report and the orchestration can be exercised without the science stages. Values are
synthetic: do not use them to validate science.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np
import pandas as pd
import xarray as xr

from hadal.geo import LocalFrame, format_position, geodesic_distance_m
from hadal.products import write_netcdf, write_parquet
from hadal.store import ProductStore, ProductVersion

ALL_FAKE = ("sensors", "ctd", "profile", "dtm", "suitability", "match", "landing")
LAUNCH = (11.3371167, 142.2097167)  # TERCOM paper §4.3 launch point (lat, lon)
ORIGIN = (11.33, 142.20)


def write_fake_dive(raw_dir: str | Path, dive_id: str = "fake-dive") -> Path:
    """A minimal raw dive directory (only ``dive.yaml``) for stages that read nothing raw (report)."""
    raw = Path(raw_dir)
    raw.mkdir(parents=True, exist_ok=True)
    (raw / "dive.yaml").write_text(
        f"dive_id: {dive_id}\nplatform: Haidou\n"
        f"launch: {{time_utc: 2018-10-06T23:00:00Z, latitude_deg: {LAUNCH[0]}, longitude_deg: {LAUNCH[1]}}}\n"
        f"map_frame: {{origin_latitude_deg: {ORIGIN[0]}, origin_longitude_deg: {ORIGIN[1]}}}\n",
        encoding="utf-8")
    return raw


def _terrain(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    X, Y = np.meshgrid(x, y)
    return 10905 - 0.03 * X + 0.02 * Y + 25 * np.sin(X / 300) * np.cos(Y / 250) + 8 * np.sin((X + 2 * Y) / 90)


def fake_ctd(n_descent: int = 600, n_bottom: int = 400, n_ascent: int = 500, rng: np.random.Generator | None = None) -> pd.DataFrame:
    rng = rng or np.random.default_rng(0)
    n = n_descent + n_bottom + n_ascent
    t = pd.date_range("2018-10-06T23:00:00Z", periods=n, freq="20s")
    depth = np.concatenate([np.linspace(0, 10880, n_descent), 10880 + 10 * np.sin(np.linspace(0, 6, n_bottom)),
                            np.linspace(10880, 0, n_ascent)])
    p = depth * 1.0485
    temp = 1.45 + 20 * np.exp(-depth / 300) + 0.0001 * depth
    sal = 34.7 - 0.5 * np.exp(-depth / 400)
    alt = np.where(np.arange(n) >= n_descent, 5 + 2 * np.sin(np.arange(n) / 15), np.nan)
    alt[(np.arange(n) >= n_descent + n_bottom)] = np.nan
    seafloor = depth + alt
    phase = np.array(["descent"] * n_descent + ["bottom"] * n_bottom + ["ascent"] * n_ascent)
    return pd.DataFrame({
        "time": t, "conductivity_s_m": 3.2 + 0.1 * temp / 10 + rng.normal(0, 1e-3, n),
        "temperature_its90_degc": temp, "pressure_ctd_dbar": np.minimum(p, 10500.0), "pressure_gauge_dbar": p + 1.2,
        "altitude_m": alt, "heading_deg": np.full(n, 45.0), "pitch_deg": np.zeros(n), "roll_deg": np.zeros(n),
        "dr_east_m": np.linspace(0, 300, n), "dr_north_m": np.linspace(0, 200, n), "speed_m_s": np.full(n, 0.5),
        "pressure_dbar": p, "pressure_source": np.where(p > 10500, "gauge", "ctd"), "practical_salinity": sal,
        "density_kg_m3": 1027 + 0.0047 * depth, "gravity_m_s2": 9.7817 + 2.2e-6 * depth, "depth_m": depth,
        "sound_speed_m_s": 1500 + 0.017 * depth, "altitude_corrected_m": alt, "seafloor_depth_m": seafloor,
        "phase": phase,
    })


def publish_fake_products(store: ProductStore, dive: str = "fake-dive", products: Sequence[str] = ALL_FAKE,
                          seed: int = 0) -> dict[str, ProductVersion]:
    """Publish the selected fake products of ``dive``; returns ``{product: version}``."""
    rng = np.random.default_rng(seed)
    frame = LocalFrame(*ORIGIN)
    out: dict[str, ProductVersion] = {}
    ctd = fake_ctd(rng=rng)
    x = np.arange(0.0, 2000.0, 20.0)
    y = np.arange(0.0, 1600.0, 20.0)
    depth = _terrain(x, y)
    if "sensors" in products:
        cols = [c for c in ctd.columns if c in ("time", "conductivity_s_m", "temperature_its90_degc", "pressure_ctd_dbar",
                                                "pressure_gauge_dbar", "altitude_m", "heading_deg", "pitch_deg",
                                                "roll_deg", "dr_east_m", "dr_north_m", "speed_m_s")]
        with store.publish(dive, "sensors", parameters={"fake": True}) as d:
            write_parquet(ctd[cols], d.path / "sensors.parquet", metadata={"dive": dive})
        out["sensors"] = d.result
    if "ctd" in products:
        with store.publish(dive, "ctd", parameters={"fake": True}) as d:
            write_parquet(ctd, d.path / "ctd.parquet", metadata={"dive": dive})
        out["ctd"] = d.result
    if "profile" in products:
        p = np.arange(5.0, 11400.0, 50.0)
        ds = xr.Dataset({"temperature_its90_degc": (("phase", "pressure_dbar"), np.vstack([1.45 + 20 * np.exp(-p / 310)] * 2))},
                        coords={"pressure_dbar": p, "phase": ["descent", "ascent"]},
                        attrs={"launch_latitude_deg": LAUNCH[0], "launch_longitude_deg": LAUNCH[1]})
        with store.publish(dive, "profile", parameters={"fake": True}) as d:
            write_netcdf(ds, d.path / "profile.nc", title="fake profile", summary="fake")
        out["profile"] = d.result
    X, Y = np.meshgrid(x, y)
    lon, lat = frame.to_lonlat(X, Y)
    if "dtm" in products:
        ds = xr.Dataset({"depth_m": (("y", "x"), depth), "count": (("y", "x"), np.full(depth.shape, 4, "i4")),
                         "lat": (("y", "x"), lat), "lon": (("y", "x"), lon),
                         "crs": ((), 0, {"crs_wkt": frame.crs.to_wkt()})}, coords={"x": x, "y": y},
                        attrs={"map_frame_origin_latitude_deg": ORIGIN[0], "map_frame_origin_longitude_deg": ORIGIN[1]})
        with store.publish(dive, "dtm", parameters={"fake": True}) as d:
            write_netcdf(ds, d.path / "dtm.nc", title="fake dtm", summary="fake")
        out["dtm"] = d.result
    if "suitability" in products:
        b = 5
        blk = depth[: depth.shape[0] // b * b, : depth.shape[1] // b * b].reshape(depth.shape[0] // b, b, depth.shape[1] // b, b)
        std = blk.std(axis=(1, 3))
        ent = np.log(1 + std)
        bx, by = x[: blk.shape[2] * b : b] + b * 10, y[: blk.shape[0] * b : b] + b * 10
        ds = xr.Dataset({"std_m": (("y", "x"), std), "entropy": (("y", "x"), ent)}, coords={"x": bx, "y": by},
                        attrs={"proposed_region": json.dumps({"x_min_m": 300.0, "x_max_m": 1500.0,
                                                              "y_min_m": 200.0, "y_max_m": 1200.0})})
        with store.publish(dive, "suitability", parameters={"fake": True}) as d:
            write_netcdf(ds, d.path / "suitability.nc", title="fake suitability", summary="fake")
        out["suitability"] = d.result
    if "match" in products:
        bottom = ctd[ctd["phase"] == "bottom"].reset_index(drop=True)
        sx, sy = 700.0, 500.0
        tx = sx + bottom["dr_east_m"].to_numpy() - bottom["dr_east_m"].iloc[0]
        ty = sy + bottom["dr_north_m"].to_numpy() - bottom["dr_north_m"].iloc[0]
        tlon, tlat = frame.to_lonlat(tx, ty)
        ix = np.clip(np.searchsorted(x, tx), 0, x.size - 1)
        iy = np.clip(np.searchsorted(y, ty), 0, y.size - 1)
        track = pd.DataFrame({"time": bottom["time"], "x_east_m": tx, "y_north_m": ty, "lon": tlon, "lat": tlat,
                              "depth_m": bottom["depth_m"], "seafloor_depth_m": depth[iy, ix] + rng.normal(0, 1, len(bottom)),
                              "map_depth_m": depth[iy, ix]})
        cx, cy = np.arange(0.0, 1400.0, 20.0), np.arange(0.0, 1000.0, 20.0)
        CX, CY = np.meshgrid(cx, cy)
        msd = 1 + ((CX - sx) ** 2 + (CY - sy) ** 2) / 5e3 + rng.random(CX.shape)
        mds = xr.Dataset({"score": (("y", "x"), msd, {"units": "m2"})}, coords={"x": cx, "y": cy},
                         attrs={"criterion": "msd", "best_x_m": sx, "best_y_m": sy})
        lx, ly = (float(v) for v in frame.to_xy(LAUNCH[1], LAUNCH[0]))
        slon, slat = (float(v) for v in frame.to_lonlat(sx, sy))
        k = int(bottom["depth_m"].idxmax())
        fix = {"criterion": "msd", "score": float(msd.min()), "bias_m": 3.2,
               "start": {"x_east_m": sx, "y_north_m": sy, "lat": slat, "lon": slon, "position_degmin": format_position(slat, slon)},
               "launch": {"lat": LAUNCH[0], "lon": LAUNCH[1], "x_east_m": lx, "y_north_m": ly,
                          "position_degmin": format_position(*LAUNCH)},
               "drift_m": float(geodesic_distance_m(LAUNCH[1], LAUNCH[0], slon, slat)),
               "uncertainty_m": {"east": 15.0, "north": 12.0, "radial": 19.2},
               "second_optimum": {"score": float(msd.min()) * 1.8, "separation_ratio": 1.8}, "mismatch": False,
               "n_samples": len(bottom), "warnings": [],
               "deepest_point": {"time": str(bottom.loc[k, "time"]), "depth_m": float(bottom.loc[k, "depth_m"]),
                                 "seafloor_depth_m": float(track.loc[k, "seafloor_depth_m"]),
                                 "x_east_m": float(tx[k]), "y_north_m": float(ty[k]), "lat": float(tlat[k]), "lon": float(tlon[k]),
                                 "position_degmin": format_position(float(tlat[k]), float(tlon[k]))}}
        with store.publish(dive, "match", parameters={"fake": True}) as d:
            write_netcdf(mds, d.path / "msd_surface.nc", title="fake msd", summary="fake",
                         map_frame_origin_latitude_deg=ORIGIN[0], map_frame_origin_longitude_deg=ORIGIN[1])
            write_parquet(track, d.path / "matched_track.parquet")
            (d.path / "fix.json").write_text(json.dumps(fix, indent=2), encoding="utf-8")
        out["match"] = d.result
    if "landing" in products:
        rows = []
        for sm in ("submap_01", "submap_02"):
            for h in (-45.0, 0.0, 45.0):
                rows.append({"submap": sm, "heading_deg": h, "site_id": 1, "x_m": rng.uniform(0, 3), "y_m": rng.uniform(0, 3),
                             "radius_m": rng.uniform(0.3, 0.8), "slope_deg": rng.uniform(0, 10),
                             "roughness_m": rng.uniform(0, 0.02), "c_s": rng.uniform(0, 1), "is_best": False})
        sites = pd.DataFrame(rows)
        for _, g in sites.groupby("submap"):
            sites.loc[g["c_s"].idxmin(), "is_best"] = True
        gx = np.arange(0.0, 3.0, 0.01)
        GX, GY = np.meshgrid(gx, gx)
        elev = 0.05 * np.sin(GX * 3) + 0.03 * np.cos(GY * 4)
        maps = xr.Dataset({"elevation_m": (("y", "x"), elev),
                           "final_site": (("y", "x"), ((GX - 1.5) ** 2 + (GY - 1.5) ** 2 < 0.25).astype("i1"),
                                          {"flag_values": np.array([0, 1], "i1"), "flag_meanings": "no yes"})},
                          coords={"x": gx, "y": gx},
                          attrs={"launch_latitude_deg": LAUNCH[0], "launch_longitude_deg": LAUNCH[1]})
        with store.publish(dive, "landing", parameters={"fake": True}) as d:
            write_parquet(sites, d.path / "landing_sites.parquet")
            for sm in ("submap_01", "submap_02"):
                write_netcdf(maps, d.path / f"{sm}_maps.nc", title="fake landing maps", summary="fake")
        out["landing"] = d.result
    return out


_PROBE = """<script>
window.__hadalErrs = [];
window.addEventListener('error', e => window.__hadalErrs.push(String(e.message || (e.target && e.target.src
  ? 'failed to load ' + e.target.src.slice(0, 60) : e))), true);
(() => { const oe = console.error; console.error = (...a) => { window.__hadalErrs.push(a.join(' ')); oe(...a); }; })();
window.addEventListener('load', () => {
  const imgs = [...document.images];
  const d = document.createElement('pre'); d.id = 'hadal-probe';
  d.textContent = JSON.stringify({images: imgs.length,
    broken: imgs.filter(i => !(i.complete && i.naturalWidth > 0)).map(i => i.alt || i.src.slice(0, 40)),
    errors: window.__hadalErrs});
  document.body.appendChild(d);
});
</script>"""


def chromium() -> str | None:
    """Path of a headless-capable Chromium, or ``None``."""
    import shutil

    for name in ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable"):
        if p := shutil.which(name):
            return p
    return None


def browser_check(html: str, workdir: str | Path, timeout_s: float = 120.0) -> dict[str, Any] | None:
    """Load ``html`` in headless Chromium and return ``{images, broken: [...], errors: [...]}`` (images that did
    not decode, script errors and console.error messages), or ``None`` when no Chromium is installed."""
    import json
    import re
    import subprocess

    exe = chromium()
    if exe is None:
        return None
    page = Path(workdir) / "report_probe.html"
    probed = html.replace("<head>", "<head>" + _PROBE, 1) if "<head>" in html else _PROBE + html
    page.write_text(probed, encoding="utf-8")
    out = subprocess.run([exe, "--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                          f"--user-data-dir={Path(workdir) / 'chromium-profile'}", "--virtual-time-budget=10000",
                          "--dump-dom", page.resolve().as_uri()], capture_output=True, text=True,
                         timeout=timeout_s, check=False)
    m = re.search(r'<pre id="hadal-probe">(.*?)</pre>', out.stdout, re.S)
    if not m:
        raise RuntimeError(f"chromium gave no probe result (rc {out.returncode}): {out.stderr[-500:]}")
    import html as _html

    return json.loads(_html.unescape(m.group(1)))
