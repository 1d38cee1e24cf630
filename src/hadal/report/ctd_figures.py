"""Water-column figures as an oceanographer reads them: T-S diagram with sigma-0 contours, potential
temperature and buoyancy frequency profiles, descent and ascent drawn apart.

TEOS-10 (gsw): absolute salinity ``SA = gsw.SA_from_SP(SP, p, lon, lat)``, conservative temperature
``CT = gsw.CT_from_t(SA, t, p)``, potential temperature (0 dbar) ``theta = gsw.pt_from_CT(SA, CT)``,
potential density anomaly ``sigma0 = gsw.sigma0(SA, CT)`` and ``N^2 = gsw.Nsquared(SA, CT, p, lat)`` between
adjacent levels of the pressure-binned profiles (``profile.nc``; without it the ``ctd`` samples are binned here
at 10 dbar). Columns written by ``derive`` into ``profile.nc`` (``absolute_salinity_g_kg``, ``conservative_temperature_degc``)
are used when present; N² is always computed here from the binned SA/CT (then averaged in log-depth bins).
"""

from __future__ import annotations

import numpy as np
import pandas as pd
from matplotlib.figure import Figure

from hadal.report.figures import CMAPS, PHASE_COLOURS, FigureOptions, FigureResult, _render
from hadal.report.load import DiveProducts

#: derive's TEOS-10 columns of profile.nc -> the names used here (used instead of recomputing when present)
TEOS_COLUMNS = {"absolute_salinity_g_kg": "SA_given", "conservative_temperature_degc": "CT_given"}

CAST_STYLE = {"descent": {"color": PHASE_COLOURS["descent"], "ls": "-", "marker": None},
              "ascent": {"color": PHASE_COLOURS["ascent"], "ls": "--", "marker": None}}


def _casts(dp: DiveProducts) -> tuple[list[tuple[str, pd.DataFrame]], float, float]:
    """[(cast name, table with pressure_dbar, depth_m, t, SP)], lat, lon: from profile.nc, else binned ctd."""
    lat = lon = np.nan
    out: list[tuple[str, pd.DataFrame]] = []
    prof = dp.profile
    ragged = _ragged_profiles(prof) if prof is not None else None
    if ragged and prof is not None:  # a CF DSG contiguous ragged array: one profile per instance
        lat = float(np.nanmean(prof["lat"].values)) if "lat" in prof.variables else np.nan
        lon = float(np.nanmean(prof["lon"].values)) if "lon" in prof.variables else np.nan
        out = ragged
    elif prof is not None and {"temperature_its90_degc", "practical_salinity"} <= set(prof.data_vars):
        lat = float(np.nanmean(prof["lat"].values)) if "lat" in prof.variables else np.nan
        lon = float(np.nanmean(prof["lon"].values)) if "lon" in prof.variables else np.nan
        zname = next((d for d in prof["temperature_its90_degc"].dims if d != "cast"), None)
        cast_dim = "cast" if "cast" in prof.dims else None
        meanings = str(prof["cast"].attrs.get("flag_meanings", "descent ascent")).split() if cast_dim else ["cast"]
        n = prof.sizes.get("cast", 1) if cast_dim else 1
        for i in range(n):
            sel = prof.isel(cast=i) if cast_dim else prof
            zp = sel["pressure_dbar"] if "pressure_dbar" in sel.data_vars else prof[zname]  # a depth-binned profile
            df = pd.DataFrame({"pressure_dbar": zp.values.astype(float),
                               "t": sel["temperature_its90_degc"].values.astype(float),
                               "SP": sel["practical_salinity"].values.astype(float)})
            if "depth_m" in sel:
                df["depth_m"] = sel["depth_m"].values.astype(float)
            for col, key in TEOS_COLUMNS.items():  # derive's TEOS-10 columns, when it wrote them
                if col in sel and sel[col].dims == (zname,):
                    df[key] = sel[col].values.astype(float)
            out.append((meanings[i] if i < len(meanings) else f"cast {i}", df))
    elif dp.ctd is not None and {"pressure_dbar", "temperature_its90_degc", "practical_salinity"} <= set(dp.ctd):
        c = dp.ctd
        if {"lat", "lon"} <= set(c.columns):
            lat, lon = float(np.nanmean(c["lat"])), float(np.nanmean(c["lon"]))
        phases = c["phase"].astype(str) if "phase" in c else pd.Series("descent", index=c.index)
        for ph in ("descent", "ascent"):
            g = c[(phases == ph).to_numpy()]
            if len(g) < 10:
                continue
            b = (g["pressure_dbar"] // 10).astype(int)
            cols = {"pressure_dbar": "pressure_dbar", "temperature_its90_degc": "t", "practical_salinity": "SP"}
            if "depth_m" in g:
                cols["depth_m"] = "depth_m"
            m = g[list(cols)].groupby(b.to_numpy()).mean().rename(columns=cols).reset_index(drop=True)
            out.append((ph, m))
    if not np.isfinite(lat):
        lat = float(dp.launch["lat"]) if dp.launch else 0.0
    if not np.isfinite(lon):
        lon = float(dp.launch["lon"]) if dp.launch else 0.0
    return out, lat, lon


def _ragged_profiles(prof) -> list[tuple[str, pd.DataFrame]] | None:
    """The profiles of a CF-1.8 contiguous ragged array (H.3.4: a count variable whose ``sample_dimension`` names the
    observation dimension) as [(name, table)], or ``None`` when ``prof`` is not laid out so. The name is the
    instance's ``cf_role = profile_id`` text (``descent``/``ascent`` when it says so)."""
    cnt = next((v for v in prof.variables if "sample_dimension" in prof[v].attrs), None)
    if cnt is None or not {"temperature_its90_degc", "practical_salinity"} <= set(prof.variables):
        return None
    obs, inst = str(prof[cnt].attrs["sample_dimension"]), prof[cnt].dims[0]
    counts = prof[cnt].values.astype(int)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    ids = next((prof[v].values for v in prof.variables
                if prof[v].attrs.get("cf_role") == "profile_id" and prof[v].dims[:1] == (inst,)), None)
    out = []
    for i, (a, n) in enumerate(zip(starts, counts, strict=True)):
        sl = prof.isel({obs: slice(int(a), int(a + n))})
        name = ids[i].decode() if ids is not None and isinstance(ids[i], bytes) else (
            "".join(ids[i].astype(str)) if ids is not None and bool(getattr(ids[i], "ndim", 0)) else
            (str(ids[i]) if ids is not None else f"cast {i}"))
        z = "pressure_dbar" if "pressure_dbar" in sl.variables else "depth"
        df = pd.DataFrame({"pressure_dbar": sl[z].values.astype(float),
                           "t": sl["temperature_its90_degc"].values.astype(float),
                           "SP": sl["practical_salinity"].values.astype(float)})
        for col in ("depth_m", "depth"):
            if col in sl.variables and sl[col].dims == (obs,):
                df["depth_m"] = sl[col].values.astype(float)
                break
        for col, key in TEOS_COLUMNS.items():
            if col in sl.variables and sl[col].dims == (obs,):
                df[key] = sl[col].values.astype(float)
        phase = next((p for p in ("descent", "ascent") if p in name.lower()), name)
        out.append((phase, df))
    return out


def teos10(df: pd.DataFrame, lat: float, lon: float) -> pd.DataFrame:
    """SA, CT, theta, sigma0 of a binned cast and N^2 at mid-levels (``N2``, ``p_mid``; NaN-padded)."""
    import gsw

    d = df[np.isfinite(df["t"]) & np.isfinite(df["SP"]) & np.isfinite(df["pressure_dbar"])].copy()
    d = d.sort_values("pressure_dbar").reset_index(drop=True)
    p = d["pressure_dbar"].to_numpy(float)
    d["SA"] = gsw.SA_from_SP(d["SP"].to_numpy(float), p, lon, lat)
    if "SA_given" in d and np.isfinite(d["SA_given"]).all():
        d["SA"] = d["SA_given"]
    d["CT"] = gsw.CT_from_t(d["SA"].to_numpy(float), d["t"].to_numpy(float), p)
    if "CT_given" in d and np.isfinite(d["CT_given"]).all():
        d["CT"] = d["CT_given"]
    d["theta"] = gsw.pt_from_CT(d["SA"].to_numpy(float), d["CT"].to_numpy(float))
    d["sigma0"] = gsw.sigma0(d["SA"].to_numpy(float), d["CT"].to_numpy(float))
    if len(d) > 1:
        n2, pmid = gsw.Nsquared(d["SA"].to_numpy(float), d["CT"].to_numpy(float), p, lat)
        d["N2"] = np.append(np.asarray(n2, float), np.nan)
        d["p_mid"] = np.append(np.asarray(pmid, float), np.nan)
    else:
        d["N2"] = d["p_mid"] = np.nan
    return d


def log_bin_mean(z: np.ndarray, v: np.ndarray, per_decade: int = 12) -> tuple[np.ndarray, np.ndarray]:
    """Means of ``v`` in depth bins equally spaced in log10(depth) (``per_decade`` per decade): N² from 10 dbar
    bins is noise-dominated in the deep, weakly stratified water; averaging over a window that grows with depth
    keeps the upper-ocean structure and shows the deep mean."""
    z, v = np.asarray(z, float), np.asarray(v, float)
    ok = np.isfinite(z) & np.isfinite(v) & (z > 0)
    if not ok.any():
        return np.array([]), np.array([])
    lz = np.log10(np.maximum(z[ok], 1.0))
    edges = np.arange(np.floor(lz.min() * per_decade), np.ceil(lz.max() * per_decade) + 1) / per_decade
    k = np.clip(np.digitize(lz, edges) - 1, 0, edges.size - 2)
    n = np.bincount(k, minlength=edges.size - 1)
    sv = np.bincount(k, weights=v[ok], minlength=edges.size - 1)
    sz = np.bincount(k, weights=z[ok], minlength=edges.size - 1)
    m = n > 0
    return sz[m] / n[m], sv[m] / n[m]


def fig_water_column(dp: DiveProducts, opt: FigureOptions) -> FigureResult:
    r = FigureResult("ctd_ts_theta_n2", "T–S diagram, conservative temperature and stratification", "Water column",
                     "(a) Conservative temperature Θ against Absolute Salinity S_A (TEOS-10, a consistent pair: "
                     "gsw.CT_from_t, gsw.SA_from_SP) with potential density anomaly σ0 = gsw.sigma0(S_A, Θ) "
                     "isopycnals (kg/m³); (b) Θ and (c) buoyancy frequency N² against depth on a "
                     "logarithmic depth axis (the upper ocean is where the water column changes), down to the "
                     "deepest level; N² from adjacent pressure bins (gsw.Nsquared), averaged in bins of 1/12 "
                     "decade of depth. Descent solid blue, ascent dashed vermillion; pressure-binned profiles.")
    casts, lat, lon = _casts(dp)
    if not casts:
        r.skipped = "no profile or ctd product with temperature and salinity"
        return r
    fig = Figure(figsize=(opt.width_in, opt.width_in * 0.55), layout="constrained")
    ax_ts, ax_th, ax_n2 = fig.subplots(1, 3, gridspec_kw={"width_ratios": [1.3, 1, 1]})
    zmax = 1.0
    all_sa, all_th = [], []
    n_nonpos = 0
    for name, df in casts:
        d = teos10(df, lat, lon)
        if d.empty:
            continue
        st = CAST_STYLE.get(name, {"color": "k", "ls": "-", "marker": None})
        z = d["depth_m"].to_numpy(float) if "depth_m" in d else d["pressure_dbar"].to_numpy(float)
        zmax = max(zmax, float(np.nanmax(z)))
        ax_ts.plot(d["SA"], d["CT"], ls=st["ls"], color=st["color"], lw=1.2, label=name)
        ax_th.plot(d["CT"], np.maximum(z, 1.0), ls=st["ls"], color=st["color"], lw=1.2, label=name)
        if d["p_mid"].notna().any():
            zmid = np.interp(d["p_mid"], d["pressure_dbar"], z)
            zb, n2b = log_bin_mean(zmid, d["N2"].to_numpy(float))
            n_nonpos += int(np.sum(n2b <= 0))
            n2b = np.where(n2b > 0, n2b, np.nan)
            ax_n2.plot(n2b, zb, ls=st["ls"], color=st["color"], lw=1.2, marker=".", ms=3, label=name)
        all_sa.append(d["SA"].to_numpy(float))
        all_th.append(d["CT"].to_numpy(float))
    if all_sa:
        import gsw

        sa = np.concatenate(all_sa)
        th = np.concatenate(all_th)
        s0, s1 = np.nanmin(sa), np.nanmax(sa)
        t0, t1 = np.nanmin(th), np.nanmax(th)
        ps, pt = 0.05 * max(s1 - s0, 0.01), 0.05 * max(t1 - t0, 0.1)
        S, T = np.meshgrid(np.linspace(s0 - ps, s1 + ps, 120), np.linspace(t0 - pt, t1 + pt, 120))
        sig = gsw.sigma0(S, T)  # T is Θ here: σ0 of the pair drawn
        cs = ax_ts.contour(S, T, sig, levels=10, colors="0.5", linewidths=0.6)
        ax_ts.clabel(cs, fontsize=8, fmt="%.2f")
        ax_ts.set_xlim(float(S.min()), float(S.max()))
        ax_ts.set_ylim(float(T.min()), float(T.max()))
    ax_ts.set_xlabel("Absolute Salinity S_A (g/kg)")
    ax_ts.set_ylabel("Conservative Temperature Θ (°C)")
    ax_ts.set_title("(a) T–S", fontsize=9)
    ax_ts.grid(alpha=0.3)
    ax_ts.legend(fontsize=8)
    for ax, lab, title in ((ax_th, "Conservative Temperature Θ (°C)", "(b) Θ"),
                           (ax_n2, "N² (s⁻²)", "(c) buoyancy frequency N²")):
        ax.set_yscale("log")
        ax.set_ylim(zmax * 1.05, 1.0)
        ax.set_xlabel(lab)
        ax.set_title(title, fontsize=9)
        ax.grid(alpha=0.3, which="both")
    ax_th.set_ylabel("depth (m, log scale)")
    ax_n2.set_xscale("log")  # bins with mean N² <= 0 (unstable or unresolved) are not drawn on a log axis
    lo, hi = ax_n2.get_xlim()
    ax_n2.set_xlim(max(lo, 1e-10), hi)
    if n_nonpos:
        r.caption += f" {n_nonpos} depth bin(s) with mean N² ≤ 0 are not drawn."
    return _render(r, fig, opt)


def fig_underway(dp: DiveProducts, opt: FigureOptions) -> FigureResult:
    """Underway (thermosalinograph) records of derive's ``trajectory``: (a) the ship's track from the records' own
    per-scan positions, coloured by practical salinity; (b) salinity and (c) temperature along time."""
    r = FigureResult("underway_tsg", "Underway thermosalinograph: track and section", "Water column",
                     "(a) Track of each underway record from its own per-scan latitude/longitude, coloured by "
                     "practical salinity (PSS-78); (b) practical salinity and (c) temperature against time. "
                     "Scans whose temperature or conductivity QC flag is not accepted have no salinity and are "
                     "not drawn. Underway records are trajectories, not casts: they have no depth profile.")
    recs = [(rec, ds) for rec, ds in dp.trajectories
            if {"lat", "lon", "time"} <= set(ds.variables) and "practical_salinity" in ds]
    if not recs:
        r.skipped = "no trajectory product with positions and salinity (no underway record)"
        return r
    fig = Figure(figsize=(opt.width_in, opt.width_in * 0.45), layout="constrained")
    ax_map, ax_s, ax_t = fig.subplots(1, 3, gridspec_kw={"width_ratios": [1.1, 1, 1]})
    sp_all = np.concatenate([ds["practical_salinity"].values.astype(float) for _, ds in recs])
    fin = sp_all[np.isfinite(sp_all)]
    vmin, vmax = (np.percentile(fin, [2, 98]) if fin.size else (0.0, 1.0))
    sc = None
    for rec, ds in recs:
        lon, lat = ds["lon"].values.astype(float), ds["lat"].values.astype(float)
        sp = ds["practical_salinity"].values.astype(float)
        t = pd.to_datetime(ds["time"].values)
        name = str(rec.get("record_id", ""))
        ax_map.plot(lon, lat, color="0.7", lw=0.8, zorder=1)
        ok = np.isfinite(sp) & np.isfinite(lon) & np.isfinite(lat)
        sc = ax_map.scatter(lon[ok], lat[ok], c=sp[ok], s=6, cmap=CMAPS["salt"], vmin=vmin, vmax=vmax, zorder=2)
        ax_map.plot(lon[np.isfinite(lon)][:1], lat[np.isfinite(lat)][:1], "k^", ms=5, zorder=3)
        ax_s.plot(t, sp, lw=0.8, marker=".", ms=2, label=name)
        if "temperature_its90_degc" in ds:
            ax_t.plot(t, ds["temperature_its90_degc"].values.astype(float), lw=0.8, marker=".", ms=2, label=name)
    if sc is not None:
        fig.colorbar(sc, ax=ax_map, label="practical salinity", shrink=0.8)
    lat_all = np.concatenate([ds["lat"].values.astype(float) for _, ds in recs])
    if np.isfinite(lat_all).any():  # metres the same both ways on the map
        ax_map.set_aspect(1.0 / max(np.cos(np.radians(float(np.nanmean(lat_all)))), 0.05), adjustable="datalim")
    ax_map.ticklabel_format(useOffset=False)
    ax_map.tick_params(axis="x", labelrotation=30, labelsize=7)
    ax_map.set_xlabel("longitude (°E)")
    ax_map.set_ylabel("latitude (°N)")
    ax_map.set_title("(a) track (▲ start)", fontsize=9)
    ax_s.set_ylabel("practical salinity (PSS-78)")
    ax_s.set_title("(b) salinity", fontsize=9)
    ax_t.set_ylabel("temperature (°C, ITS-90)")
    ax_t.set_title("(c) temperature", fontsize=9)
    for ax in (ax_map, ax_s, ax_t):
        ax.grid(alpha=0.3)
    for ax in (ax_s, ax_t):
        ax.set_xlabel("time (UTC)")
        ax.tick_params(axis="x", labelrotation=30, labelsize=7)
    if len(recs) > 1:
        ax_s.legend(fontsize=7)
    km = sum(float(rec.get("track_length_km") or 0.0) for rec, _ in recs)
    r.caption += f" {len(recs)} record(s), {km:.2f} km of track."
    return _render(r, fig, opt)
