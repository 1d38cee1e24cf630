"""Sensors -> seawater properties, depth, seafloor depth and phases of one record: the science of the ``derive``
stage, moved here unchanged from ``hadal.stages.derive`` (issue 44). Method: Ma et al. (2023) §3.2 ([TERCOM
Eqs. 6-14]) and §4.1.3; see :func:`derive_ctd` (one record) and :func:`derive_table` (a record with its position
chosen and its metadata). The options are :class:`hadal.settings.DeriveParams`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from hadal.budget import check_memory, memory_limit_bytes
from hadal.errors import InputError
from hadal.settings.derive import DeriveParams as Params

if TYPE_CHECKING:
    import numpy as np
    import pandas as pd


REQUIRED_COLUMNS = ("time", "conductivity_s_m", "temperature_its90_degc")

#: attributes of the columns this stage adds that the shared CF table does not define
EXTRA_COLUMN_ATTRS: dict[str, dict[str, str]] = {
    "pressure_source": {"long_name": "source of pressure_dbar",
                        "comment": "ctd: SBE49 CTD pressure (gain+offset fitted onto the gauge on the gauge datum); "
                                   "gauge: Keller gauge (lag removed; mapped onto the CTD on the CTD datum); blend: "
                                   "linear cross-over of the two below the switch pressure (derive.pressure_blend_dbar); "
                                   "empty: no valid pressure"},
    "phase": {"long_name": "dive phase", "comment": "descent, bottom or ascent (from the depth series)"},
    "gravity_m_s2": {"units": "m s-2", "long_name": "gravitational acceleration at the sample depth (Eq. 14)"},
    "loop_edit_bad": {"long_name": "scan marked bad by LoopEdit (slow-down, reversal or surface soak)",
                      "comment": "derive.loop_edit; such scans are left out of profile.nc"},
    "buoyancy_frequency_squared_s2": {"standard_name": "square_of_brunt_vaisala_frequency_in_sea_water",
                                      "units": "s-2", "long_name": "N2 of the sample's binned cast (descent for "
                                      "descent and bottom samples) at its pressure (gsw.Nsquared)"},
}


def _flag_ok(df: pd.DataFrame, column: str, accept: list[int]) -> np.ndarray:
    """True where ``column`` is finite and its ``<column>_qc`` flag (if present) is accepted."""
    import numpy as np

    v = df[column].to_numpy(dtype=np.float64)
    ok = np.isfinite(v)
    qc = f"{column}_qc"
    if qc in df.columns:
        ok &= np.isin(df[qc].to_numpy(), accept)
    return ok


#: most metres per dbar of a water column (density >= 990 kg/m3, g >= 9.78 m/s2: 1e4 / (990 x 9.78) = 1.033): an
#: upper bound of the depth from the pressure, for the memory check of a depth-binned profile before derive
DEPTH_PER_DBAR_MAX = 1.04


def profile_memory_bytes(pressure_dbar: Any, bin_dbar: float, n_variables: int | None = None,
                         n_casts: int = 2) -> float:
    """Bytes :func:`hadal.ctd.profile.make_profile` allocates for ``pressure_dbar`` in ``bin_dbar`` bins: per bin the
    edges and per cast a count plus, per variable, a sum, a count, a mean and the product array (8 bytes each).
    ``n_variables``: default ``len(hadal.ctd.profile.PROFILE_VARIABLES)`` (looked up here: hadal.ctd.profile imports xarray).
    The same holds on the depth axis with depths (m) and a bin size in m (as many variables)."""
    import numpy as np

    if n_variables is None:
        from hadal.ctd.profile import PROFILE_VARIABLES

        n_variables = len(PROFILE_VARIABLES)

    pr = np.asarray(pressure_dbar, dtype=np.float64)
    pr = pr[np.isfinite(pr)]
    if pr.size == 0:
        return 0.0
    n_bins = (float(pr.max()) - min(0.0, float(pr.min()))) / float(bin_dbar) + 2
    return n_bins * 8.0 * (1 + n_casts * (1 + 4 * n_variables))


def check_profile_memory(sensors: pd.DataFrame, p: Params, limit_bytes: float | None = None) -> None:
    """Refuse (one-line ConfigError) a ``profile_bin_dbar`` (or, on the depth axis, ``profile_bin_m``) whose bins
    would not fit the memory budget. On the depth axis the depth is not known yet: it is bounded by
    :data:`DEPTH_PER_DBAR_MAX` x the pressure, and the descent profile derive bins by pressure for the TEOS-10
    cross-check (one cast, four variables, ``profile_bin_dbar``) is counted too."""
    import numpy as np
    import pandas as pd

    cols = [c for c in ("pressure_ctd_dbar", "pressure_gauge_dbar") if c in sensors.columns]
    if not cols:
        return
    pr = np.concatenate([pd.to_numeric(sensors[c], errors="coerce").to_numpy(np.float64) for c in cols])
    fin = pr[np.isfinite(pr)]
    limit = memory_limit_bytes() if limit_bytes is None else limit_bytes
    if p.profile_axis == "depth":
        z = pr * DEPTH_PER_DBAR_MAX
        need = profile_memory_bytes(z, p.profile_bin_m) + profile_memory_bytes(pr, p.profile_bin_dbar, 4, 1)
        zf = z[np.isfinite(z)]
        span = (f"up to {float(zf.max()) - min(0.0, float(zf.min())):.0f} m ({DEPTH_PER_DBAR_MAX:g} m/dbar x the "
                "pressure)" if zf.size else "no pressure")
        check_memory(f"the depth-binned profile ({span} in {p.profile_bin_m:g} m bins)", need, limit,
                     setting="derive.profile_bin_m", value=float(p.profile_bin_m),
                     advice="use a larger derive.profile_bin_m (and profile_bin_dbar) or raise "
                            "resources.max_memory_gb")
        return
    need = profile_memory_bytes(pr, p.profile_bin_dbar)
    span = f"{float(fin.max()) - min(0.0, float(fin.min())):.0f} dbar" if fin.size else "no pressure"
    check_memory(f"the profile ({span} in {p.profile_bin_dbar:g} dbar bins)", need, limit,
                 setting="derive.profile_bin_dbar", value=float(p.profile_bin_dbar),
                 advice="use a larger derive.profile_bin_dbar or raise resources.max_memory_gb")


def profile_bin_size(p: Params) -> float:
    """The bin size of profile.nc in its axis' unit (dbar or m)."""
    return p.profile_bin_m if p.profile_axis == "depth" else p.profile_bin_dbar


def profile_axis_text(p: Params) -> str:
    """``'10 dbar pressure'`` or ``'5 m depth'``: the bins of profile.nc, for titles and summaries."""
    return f"{p.profile_bin_m:g} m depth" if p.profile_axis == "depth" else f"{p.profile_bin_dbar:g} dbar pressure"


def _checked_samples(sensors: pd.DataFrame, p: Params, memory_limit_bytes: float | None,
                     keep_file_order: bool = False) -> tuple[pd.DataFrame, bool, np.ndarray]:
    """The sensors table checked (required columns, memory of the profile), in time order (a pressure-binned
    cast without times: in pressure order, unless ``keep_file_order``: a SeaSoft-binned cast's rows are its
    descent then its ascent) with repeated times dropped; returns it, whether it has no time base and the
    dropped rows' mask."""
    import numpy as np
    import pandas as pd

    missing = [c for c in REQUIRED_COLUMNS if c not in sensors.columns]
    if missing:
        raise InputError(f"sensors table lacks required column(s) {', '.join(missing)}")
    if "pressure_ctd_dbar" not in sensors.columns and "pressure_gauge_dbar" not in sensors.columns:
        raise InputError("sensors table has neither pressure_ctd_dbar nor pressure_gauge_dbar")
    if len(sensors) == 0:
        raise InputError("sensors table is empty")
    check_profile_memory(sensors, p, memory_limit_bytes)
    # pandas >= 3 copies on write: a shallow copy is already independent of ``sensors``, without a second copy of
    # every sample while the table is derived (issue 48)
    df = sensors.copy(deep=int(pd.__version__.split(".")[0]) < 3)
    df["time"] = pd.to_datetime(df["time"], utc=True)
    no_time = bool(df["time"].isna().all())  # a pressure-binned cast: rows in pressure order, no times
    if no_time:
        pr = pd.to_numeric(df.get("pressure_ctd_dbar", df.get("pressure_gauge_dbar")), errors="coerce")
        if not (keep_file_order or pr.dropna().is_monotonic_increasing or pr.dropna().is_monotonic_decreasing):
            df = df.iloc[np.argsort(pr.to_numpy(), kind="stable")].reset_index(drop=True)
        dup = np.zeros(len(df), dtype=bool)
    else:
        if df["time"].isna().any():
            raise InputError(f"sensors table has {int(df['time'].isna().sum())} missing time(s) among valid ones")
        if not df["time"].is_monotonic_increasing:
            df = df.sort_values("time", kind="stable").reset_index(drop=True)
        dup = df["time"].duplicated(keep="first").to_numpy()
    if dup.any():  # repeated samples (the ingest contract says unique times): keep the first, count the rest
        df = df.loc[~dup].reset_index(drop=True)
    return df, no_time, dup


def _fused_pressure(df: pd.DataFrame, p: Params, acc: list[int], no_time: bool) -> Any:
    """Fuse CTD and gauge pressure (:func:`hadal.depth.fuse_pressure`) into ``pressure_dbar``/``pressure_source``."""
    import numpy as np
    import pandas as pd

    from hadal.depth import fuse_pressure

    nan = np.full(len(df), np.nan)
    pc = df["pressure_ctd_dbar"].to_numpy(np.float64) if "pressure_ctd_dbar" in df else nan
    pg = df["pressure_gauge_dbar"].to_numpy(np.float64) if "pressure_gauge_dbar" in df else nan
    fusion = fuse_pressure(
        pc, pg,
        ctd_ok=_flag_ok(df, "pressure_ctd_dbar", acc) if "pressure_ctd_dbar" in df else None,
        gauge_ok=_flag_ok(df, "pressure_gauge_dbar", acc) if "pressure_gauge_dbar" in df else None,
        ctd_saturation_dbar=p.ctd_saturation_dbar, saturation_margin_dbar=p.saturation_margin_dbar,
        bias_window_dbar=(p.gauge_bias_window_dbar[0], p.gauge_bias_window_dbar[1]), min_bias_samples=p.min_bias_samples,
        datum=p.pressure_datum, fit=p.pressure_fit, blend_dbar=p.pressure_blend_dbar,
        estimate_lag=p.estimate_pressure_lag, max_lag_s=p.max_pressure_lag_s,
        time_s=None if no_time else (df["time"] - df["time"].iloc[0]).dt.total_seconds().to_numpy(),
    )
    if not np.isfinite(fusion.pressure_dbar).any():
        raise InputError("sensors table has no valid pressure (CTD and gauge both missing or flagged bad)")
    df["pressure_dbar"] = fusion.pressure_dbar
    df["pressure_source"] = pd.array(fusion.source, dtype="string")
    return fusion


#: how ``practical_salinity`` is computed (``salinity_method`` of the ``ctd`` metadata)
SALINITY_FROM_CONDUCTIVITY = "PSS-78 from conductivity, temperature and pressure (hadal.seawater.practical_salinity)"


def _salinity(df: pd.DataFrame, acc: list[int], pres: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Practical salinity and the temperature that goes with it (NaN where not accepted): PSS-78 from the
    accepted conductivity/temperature pairs; for a table without any accepted conductivity that carries the
    vendor's salinity (``practical_salinity_vendor``: a Sea-Bird cast without a conductivity channel, SeaSoft's
    ``sal00``), that salinity where it and the temperature are accepted. The vendor column is dropped from
    ``df`` (``practical_salinity`` holds it) and ``df.attrs["salinity_method"]`` says which was used."""
    import numpy as np

    from hadal.ingest.build import OPTIONAL_SENSOR_VARIABLES
    from hadal.seawater import practical_salinity

    vendor = OPTIONAL_SENSOR_VARIABLES[0]
    t_ok = _flag_ok(df, "temperature_its90_degc", acc)
    tc_ok = _flag_ok(df, "conductivity_s_m", acc) & t_ok
    if not tc_ok.any() and vendor in df.columns and (ts_ok := _flag_ok(df, vendor, acc) & t_ok).any():
        sp = np.where(ts_ok, df[vendor].to_numpy(np.float64), np.nan)
        temp = np.where(ts_ok, df["temperature_its90_degc"].to_numpy(np.float64), np.nan)
        df.attrs["salinity_method"] = (f"the vendor's practical salinity ({vendor}, from the instrument's own "
                                       "salinity channel); no conductivity")
    else:
        cond = np.where(tc_ok, df["conductivity_s_m"].to_numpy(np.float64), np.nan)
        temp = np.where(tc_ok, df["temperature_its90_degc"].to_numpy(np.float64), np.nan)
        sp = practical_salinity(cond, temp, pres)
        df.attrs["salinity_method"] = SALINITY_FROM_CONDUCTIVITY
    for c in (vendor, f"{vendor}_qc"):
        if c in df.columns:
            del df[c]
    return sp, temp


def _seawater(df: pd.DataFrame, p: Params, acc: list[int], pres: np.ndarray, latitude_deg: float,
              longitude_deg: float, overlying_profile: Any) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, Any]:
    """Salinity, density, gravity, the depths, sound speed and the TEOS-10 columns of accepted C/T samples;
    returns salinity, temperature, density, depth and the overlying water column."""
    import numpy as np

    from hadal.ctd.teos10 import teos10_columns
    from hadal.depth import hydrostatic_depth, overlying_column
    from hadal.seawater import (
        density_eos80,
        depth_fofonoff_millard,
        gravity,
        sound_speed_chen_millero,
    )

    sp, temp = _salinity(df, acc, pres)
    rho = density_eos80(sp, temp, pres)
    if not np.isfinite(rho).any():
        t_ok = _flag_ok(df, "temperature_its90_degc", acc)
        if not t_ok.any():
            raise InputError("sensors table has no valid temperature: cannot compute salinity, density or depth")
        # degrade per channel: no valid conductivity (a dead channel) -> no salinity/density/sound speed, but the
        # depth of the valid pressures from the TEOS-10 standard ocean (pressure only)
        temp = np.where(t_ok, df["temperature_its90_degc"].to_numpy(np.float64), np.nan)
        depth, column = _standard_ocean_depth(pres, latitude_deg)
    else:
        # the overlying column starts at the record's first valid pressure, as the integral does: a density gap
        # there (a conductivity dropout at the start) is filled as hydrostatic_depth fills it
        rho_start = rho
        valid_p = np.isfinite(pres)
        if valid_p.any() and not np.isfinite(rho[int(np.argmax(valid_p))]):
            from hadal.depth import _fill_density_gaps

            rho_start = _fill_density_gaps(np.array(rho, dtype=np.float64), True, valid_p)
        column = overlying_column(pres, sp, temp, latitude_deg, density_kg_m3=rho_start,
                                  surface_dbar=p.surface_start_dbar, bin_dbar=p.profile_bin_dbar,
                                  profile=overlying_profile)
        depth = hydrostatic_depth(pres, sp, temp, latitude_deg, integration=p.depth_integration, density_kg_m3=rho,
                                  start_depth_m=column.start_depth_m)
    df["practical_salinity"] = sp
    df["density_kg_m3"] = rho
    df["gravity_m_s2"] = np.where(np.isfinite(depth), gravity(latitude_deg, depth), np.nan)
    df["depth_m"] = depth
    df["depth_fofonoff_millard_m"] = depth_fofonoff_millard(pres, latitude_deg)
    sv = sound_speed_chen_millero(sp, temp, pres)
    df["sound_speed_m_s"] = sv
    # TEOS-10 next to EOS-80 (gsw; N² comes from the binned casts, in derive_table)
    for name, values in teos10_columns(sp, temp, pres, longitude_deg, latitude_deg).items():
        df[name] = values
    return sp, temp, rho, depth, column


def _standard_ocean_depth(pres: np.ndarray, latitude_deg: float) -> tuple[np.ndarray, Any]:
    """Depth (m) of the valid pressures in the TEOS-10 standard ocean (``gsw.z_from_p``, no salinity needed) and the
    :class:`hadal.depth.OverlyingColumn` saying so: the depth of a record without any valid salinity (its
    conductivity channel dead); NaN where the pressure is."""
    import gsw
    import numpy as np

    from hadal.depth import OverlyingColumn, _warm_column_psi

    depth = np.where(np.isfinite(pres), -gsw.z_from_p(pres, latitude_deg), np.nan)
    i0 = int(np.argmax(np.isfinite(pres)))
    p_max = float(np.nanmax(pres))
    err = abs(_warm_column_psi(p_max, latitude_deg)) / float(gsw.grav(latitude_deg, p_max))
    note = ("no valid salinity (conductivity missing or flagged bad throughout): depth from the TEOS-10 standard "
            "ocean (gsw.z_from_p, pressure only); salinity, density and sound speed are missing")
    return depth, OverlyingColumn(float(pres[i0]), float(depth[i0]), "standard ocean (TEOS-10)", err, note)


def _phases(df: pd.DataFrame, p: Params, pres: np.ndarray, depth: np.ndarray, no_time: bool,
            prebinned: bool = False) -> None:
    """``phase``: descent/bottom/ascent from the depth record; a cast SeaSoft already binned: its casts in file
    order (:func:`hadal.ctd.profile.prebinned_phases`); else a record without time is one profile (descent when
    pressure increases down the file, else ascent)."""
    import numpy as np
    import pandas as pd

    from hadal.depth import segment_phases

    if prebinned:
        from hadal.ctd.profile import prebinned_phases

        phase = prebinned_phases(pres)
    elif no_time:
        fin = pres[np.isfinite(pres)]
        phase = np.full(len(df), "descent" if fin.size < 2 or fin[-1] >= fin[0] else "ascent", dtype=object)
    else:
        phase = segment_phases(df["time"], depth, smoothing_s=p.phase_smoothing_s,
                               vertical_speed_threshold_m_s=p.phase_speed_threshold_m_s,
                               deep_fraction=p.phase_deep_fraction)
    df["phase"] = pd.array(phase, dtype="string")


def _teos10_depth(df: pd.DataFrame, p: Params, pres: np.ndarray, temp: np.ndarray, latitude_deg: float,
                  longitude_deg: float) -> str:
    """``depth_teos10_m`` with the dynamic height anomaly of the binned descent profile; returns how it was made."""
    from hadal.ctd.profile import make_profile
    from hadal.depth import depth_teos10, dynamic_height_anomaly

    teos_note = "dynamic height anomaly of the binned descent profile"
    p_psi: np.ndarray | None
    psi: np.ndarray | None
    try:
        prof = make_profile(df[["pressure_dbar", "phase", "practical_salinity", "temperature_its90_degc"]]
                            .assign(temperature_its90_degc=temp), p.profile_bin_dbar, casts=("descent",))
        pp = prof["pressure_dbar"].values
        sp_b = prof["practical_salinity"].values[0]
        t_b = prof["temperature_its90_degc"].values[0]
        p_psi, psi = dynamic_height_anomaly(pp, sp_b, t_b, longitude_deg, latitude_deg)
    except InputError:
        p_psi = psi = None
        teos_note = "no usable descent profile: standard ocean (dynamic height anomaly 0)"
    df["depth_teos10_m"] = depth_teos10(pres, latitude_deg, p_psi, psi)
    return teos_note


def _altitude_seafloor(df: pd.DataFrame, p: Params, acc: list[int], pres: np.ndarray, sp: np.ndarray,
                       temp: np.ndarray, rho: np.ndarray, depth: np.ndarray, latitude_deg: float) -> None:
    """``altitude_corrected_m`` (sound speed of the water at the vehicle) and ``seafloor_depth_m``."""
    import numpy as np
    import pandas as pd

    from hadal.depth import correct_altitude, seafloor_depth

    if "altitude_m" in df.columns:
        alt_ok = _flag_ok(df, "altitude_m", acc) & (df["altitude_m"].to_numpy(np.float64) > 0)
        alt = np.where(alt_ok, df["altitude_m"].to_numpy(np.float64), np.nan)
        # water properties at the vehicle: hold the last valid T/S over short conductivity dropouts
        sp_h = pd.Series(sp).ffill().bfill().to_numpy()
        t_h = pd.Series(temp).ffill().bfill().to_numpy()
        rho_h = pd.Series(rho).ffill().bfill().to_numpy()
        df["altitude_corrected_m"] = correct_altitude(alt, sp_h, t_h, pres, density_kg_m3=rho_h,
                                                      nominal_sound_speed_m_s=p.nominal_sound_speed_m_s,
                                                      latitude_deg=latitude_deg)
    else:
        df["altitude_corrected_m"] = np.full(len(df), np.nan)
    df["seafloor_depth_m"] = seafloor_depth(depth, df["altitude_corrected_m"].to_numpy())


#: a cast's altimeter reading whose seafloor (depth + altitude) is more than this above the deepest point the CTD
#: reached is a false echo (m; at least, or this fraction of that depth: SEAFLOOR_ABOVE_CAST_FRACTION)
SEAFLOOR_ABOVE_CAST_M = 2.0
SEAFLOOR_ABOVE_CAST_FRACTION = 0.01


def flag_false_echoes(df: pd.DataFrame, depth_m: np.ndarray, acc: list[int]) -> dict[str, Any] | None:
    """Altimeter readings of a vertical cast that put the seafloor above the deepest point the CTD reached
    (depth + altitude < deepest depth - max(:data:`SEAFLOOR_ABOVE_CAST_M`, :data:`SEAFLOOR_ABOVE_CAST_FRACTION` x
    that depth)): the instrument went deeper at the same place, so the echo is not the bottom (scattering layer,
    the wire, the ship). ``altitude_m_qc`` becomes 4 there (the value is kept); returns the count and the rule,
    ``None`` without an accepted altimeter reading. Only for a cast: a vehicle moving over the seafloor can be
    above ground it was deeper than elsewhere."""
    import numpy as np

    if "altitude_m" not in df.columns:
        return None
    alt = df["altitude_m"].to_numpy(np.float64)
    ok = _flag_ok(df, "altitude_m", acc) & (alt > 0) & np.isfinite(depth_m)
    if not ok.any() or not np.isfinite(depth_m).any():
        return None
    deepest = float(np.nanmax(depth_m))
    tol = max(SEAFLOOR_ABOVE_CAST_M, SEAFLOOR_ABOVE_CAST_FRACTION * deepest)
    bad = ok & (depth_m + alt < deepest - tol)
    n = int(bad.sum())
    if n:
        qc = df["altitude_m_qc"].to_numpy().copy() if "altitude_m_qc" in df else np.ones(len(df), np.uint8)
        qc[bad] = 4
        df["altitude_m_qc"] = qc.astype(np.uint8)
    return {"readings_flagged": n, "accepted_readings": int(ok.sum()), "deepest_depth_m": round(deepest, 3),
            "tolerance_m": round(tol, 3), "qartod_flag": 4,
            "rule": "a vertical cast's altimeter reading whose seafloor (depth + altitude) lies above the deepest "
                    "depth the cast reached, less the tolerance, is a false echo"}


def derive_ctd(sensors: pd.DataFrame, latitude_deg: float, longitude_deg: float, p: Params,
               frame: Any = None, launch_xy: tuple[float, float] = (0.0, 0.0), *,
               memory_limit_bytes: float | None = None, overlying_profile: Any = None,
               vertical_cast: bool = False, prebinned: bool = False) -> tuple[pd.DataFrame, dict]:
    """Pure science of the stage: the ``ctd`` table and its metadata from a ``sensors`` table.

    ``prebinned``: the table is a cast SeaSoft's BinAvg already binned (one row per bin; its descent and ascent
    are the rows up to and after the deepest, :func:`hadal.ctd.profile.prebinned_phases`).

    ``frame`` (a :class:`hadal.geo.LocalFrame`) and ``launch_xy`` (the launch point in it) turn the
    dead-reckoned offsets of the deepest point into longitude/latitude when given. ``overlying_profile`` (a
    :class:`hadal.depth.UserProfile`, from ``p.overlying_profile``) is the water above a record that does not
    start at the surface (:func:`hadal.depth.overlying_column`). ``vertical_cast`` (a Sea-Bird cast): altimeter
    readings above the cast's deepest point are flagged as false echoes (:func:`flag_false_echoes`).
    """
    import numpy as np

    from hadal.ctd.chain import apply_channel_steps, loop_edit_flags
    from hadal.ingest.cnv import NO_TIME_BASE
    from hadal.qc_derived import apply_to_table as apply_derived_qc
    from hadal.qc_derived import load_qc_config

    df, no_time, dup = _checked_samples(sensors, p, memory_limit_bytes, keep_file_order=prebinned)
    acc = list(p.accept_flags)
    # --- Sea-Bird processing chain on the raw channels (hadal.ctd.chain; every step off unless enabled)
    interval_s, ctd_steps = apply_channel_steps(df, p, no_time)
    fusion = _fused_pressure(df, p, acc, no_time)
    pres = fusion.pressure_dbar
    sp, temp, rho, depth, column = _seawater(df, p, acc, pres, latitude_deg, longitude_deg, overlying_profile)
    loop_bad, loop_step = loop_edit_flags(depth, interval_s, p)
    if loop_bad is not None:
        df["loop_edit_bad"] = loop_bad
    if loop_step is not None:
        ctd_steps.append(loop_step)
    _phases(df, p, pres, depth, no_time, prebinned)  # needed for the descent profile of the TEOS-10 cross-check
    teos_note = _teos10_depth(df, p, pres, temp, latitude_deg, longitude_deg)
    echoes = flag_false_echoes(df, depth, acc) if vertical_cast else None
    _altitude_seafloor(df, p, acc, pres, sp, temp, rho, depth, latitude_deg)
    # QARTOD flags on the derived variables and range checks on the inputs (hadal.qc_derived)
    qc_meta = apply_derived_qc(df, load_qc_config(p.qc_thresholds), latitude_deg=latitude_deg,
                               longitude_deg=longitude_deg)

    meta = _metadata(df, fusion, latitude_deg, longitude_deg, p, teos_note, frame, launch_xy)
    meta["salinity_method"] = df.attrs.pop("salinity_method", SALINITY_FROM_CONDUCTIVITY)
    if echoes is not None:
        meta["altimeter_false_echoes"] = echoes
    meta["qc_derived"] = qc_meta
    meta["pressure_fusion"] = fusion.to_dict()
    meta["overlying_column"] = column.to_dict()
    if not np.isfinite(sp).any():
        meta["depth_method"] = column.warning
    if overlying_profile is not None:
        meta["overlying_column"]["user_profile"] = overlying_profile.to_dict()
    meta["duplicate_times_dropped"] = int(dup.sum())
    if ctd_steps:
        meta["ctd_processing"] = ctd_steps
    if no_time:
        meta["time_base"] = NO_TIME_BASE
        meta["profile_note"] = ("no time channel: salinity, density, gravity and depth integrated in pressure "
                                "order; phase from the pressure trend; no times, no phase durations")
    return df, meta


def _point(df: pd.DataFrame, i: int, frame: Any, launch_xy: tuple[float, float]) -> dict[str, Any]:
    import numpy as np
    import pandas as pd

    row = df.iloc[i]
    t = pd.Timestamp(row["time"])
    out: dict[str, Any] = {"time": None if pd.isna(t) else t.isoformat(), "index": int(i)}
    for c in ("depth_m", "pressure_dbar", "seafloor_depth_m", "altitude_corrected_m", "depth_fofonoff_millard_m",
              "depth_teos10_m", "dr_east_m", "dr_north_m"):
        if c in df.columns and np.isfinite(row[c]):
            out[c] = round(float(row[c]), 3)
    if frame is not None and "dr_east_m" in out and "dr_north_m" in out:
        lon, lat = frame.to_lonlat(launch_xy[0] + out["dr_east_m"], launch_xy[1] + out["dr_north_m"])
        out["longitude_deg"] = round(float(lon), 7)
        out["latitude_deg"] = round(float(lat), 7)
    return out


def _stats(diff: np.ndarray) -> dict[str, float]:
    import numpy as np

    d = diff[np.isfinite(diff)]
    if d.size == 0:
        return {}
    return {"mean_m": round(float(d.mean()), 4), "min_m": round(float(d.min()), 4),
            "max_m": round(float(d.max()), 4), "max_abs_m": round(float(np.abs(d).max()), 4)}


def _metadata(df: pd.DataFrame, fusion: Any, lat: float, lon: float, p: Params, teos_note: str,
              frame: Any, launch_xy: tuple[float, float]) -> dict[str, Any]:
    import numpy as np

    depth = df["depth_m"].to_numpy()
    i_deep = int(np.nanargmax(depth))
    meta: dict[str, Any] = {
        "latitude_deg": lat, "longitude_deg": lon,
        "depth_method": f"hydrostatic integral, Eqs. 11-12 ({p.depth_integration}), EOS-80 density, "
                        "gravity at the current depth (Eq. 14, McDougall & Barker 2011 sign)",
        "teos10_depth": teos_note,
        "gauge_bias_dbar": round(fusion.gauge_bias_dbar, 4),
        "gauge_bias_samples": fusion.bias_samples,
        "gauge_bias_mad_dbar": None if not np.isfinite(fusion.bias_mad_dbar) else round(fusion.bias_mad_dbar, 4),
        "gauge_bias_window_dbar": list(p.gauge_bias_window_dbar),
        "pressure_datum": p.pressure_datum,
        "pressure_source_counts": {"ctd": fusion.n_ctd, "gauge": fusion.n_gauge, "blend": fusion.n_blend,
                                   "none": int(len(df) - fusion.n_ctd - fusion.n_gauge - fusion.n_blend)},
        "nominal_sound_speed_m_s": p.nominal_sound_speed_m_s,
        "deepest_point": _point(df, i_deep, frame, launch_xy),
    }
    sf = df["seafloor_depth_m"].to_numpy()
    if np.isfinite(sf).any():
        meta["deepest_seafloor"] = _point(df, int(np.nanargmax(sf)), frame, launch_xy)
    phases = {}
    for ph in ("descent", "bottom", "ascent"):
        sel = (df["phase"] == ph).to_numpy()
        if sel.any():
            t = df["time"][sel].dropna()
            phases[ph] = {"start": t.iloc[0].isoformat() if len(t) else None,
                          "end": t.iloc[-1].isoformat() if len(t) else None, "samples": int(sel.sum())}
    meta["phases"] = phases
    fm = df["depth_fofonoff_millard_m"].to_numpy()
    te = df["depth_teos10_m"].to_numpy()
    meta["depth_comparison"] = {
        "hydrostatic_minus_fofonoff_millard": _stats(depth - fm),
        "hydrostatic_minus_teos10": _stats(depth - te),
        "teos10_minus_fofonoff_millard": _stats(te - fm),
        "at_deepest_point": {"hydrostatic_m": round(float(depth[i_deep]), 3),
                             "fofonoff_millard_m": round(float(fm[i_deep]), 3),
                             "teos10_m": round(float(te[i_deep]), 3)},
    }
    return meta


def comparison_table(meta: dict[str, Any]) -> str:
    """The depth cross-check as a small text table (logged by the stage)."""
    c = meta["depth_comparison"]
    d = c["at_deepest_point"]
    rows = [("hydrostatic (depth_m)", d["hydrostatic_m"], 0.0),
            ("Fofonoff-Millard", d["fofonoff_millard_m"], d["hydrostatic_m"] - d["fofonoff_millard_m"]),
            ("TEOS-10 + dyn. height", d["teos10_m"], d["hydrostatic_m"] - d["teos10_m"])]
    lines = ["depth at the deepest point      depth (m)   hydrostatic - this (m)"]
    lines += [f"  {n:<28s} {v:11.3f}   {dv:+10.3f}" for n, v, dv in rows]
    for k, label in (("hydrostatic_minus_fofonoff_millard", "hydrostatic - F-M"),
                     ("hydrostatic_minus_teos10", "hydrostatic - TEOS-10")):
        s = c[k]
        if s:
            lines.append(f"  whole dive {label:<22s} mean {s['mean_m']:+.3f}  range [{s['min_m']:+.3f}, {s['max_m']:+.3f}]")
    return "\n".join(lines)


#: latitude used when neither the parameter, the launch nor the cast header gives one
FALLBACK_LATITUDE_DEG = 45.0


def _latitude_error_m(pressure_dbar: float) -> float:
    """Largest depth error at ``pressure_dbar`` from using 45° for a cast anywhere between equator and pole."""
    import numpy as np

    from hadal.seawater import depth_fofonoff_millard

    p = np.array([pressure_dbar])
    d45 = float(depth_fofonoff_millard(p, FALLBACK_LATITUDE_DEG)[0])
    return max(abs(float(depth_fofonoff_millard(p, lat)[0]) - d45) for lat in (0.0, 90.0))


def choose_position(p: Params, dive: Any, sensors_meta: dict[str, Any], *, header_first: bool = False
                    ) -> dict[str, Any]:
    """Latitude/longitude for gravity and depth, in order: ``derive.latitude_deg`` parameter, dive.yaml
    launch, the cast header's NMEA/user position (``cast_latitude_deg`` in the sensors metadata), else 45°
    with a warning (and the largest depth error that can cause at the deepest sample). ``header_first``
    (an external cast, which need not be at the vehicle's launch point): the header before the launch."""
    launch = getattr(dive, "launch", None)

    def pick(axis: str, fallback: tuple[float, str]) -> tuple[float, str]:
        key = f"{axis}_deg"
        cast = sensors_meta.get(f"cast_{key}")
        if getattr(p, key) is not None:
            return getattr(p, key), f"derive.{key} parameter"
        if cast is not None and (header_first or launch is None):
            # the cast reader's own account of where the header position came from (NMEA, user line, or SeaSoft's
            # depSM 'lat =' note), when it gives one
            said = ((sensors_meta.get("cast") or {}).get("position_source") or {}).get(axis)
            return float(cast), f"cast header ({said})" if said else f"cast header (NMEA/user {axis})"
        if launch is not None:
            return getattr(launch, key), "dive launch"
        return fallback

    lat, lat_src = pick("latitude", (FALLBACK_LATITUDE_DEG,
                                     "fallback 45 deg (no parameter, launch or cast header latitude)"))
    lon, lon_src = pick("longitude", (0.0, "fallback 0 deg (only the TEOS-10 cross-check uses it)"))
    return {"latitude_deg": float(lat), "longitude_deg": float(lon), "latitude_source": lat_src,
            "longitude_source": lon_src, "fallback": lat_src.startswith("fallback")}


def _frame(dive: Any) -> tuple[Any, tuple[float, float]]:
    """The map frame and the launch point in it, or ``(None, (0, 0))`` without launch (DR positions omitted)."""
    launch = getattr(dive, "launch", None)
    if launch is None:
        return None, (0.0, 0.0)
    frame = dive.frame("derive")
    x, y = frame.to_xy(launch.longitude_deg, launch.latitude_deg)
    return frame, (float(x), float(y))


def derive_table(table: pd.DataFrame, sensors_meta: dict[str, Any], p: Params, dive: Any, log: Any,
                 what: str, *, external_cast: bool = False, memory_limit_bytes: float | None = None,
                 overlying_profile: Any = None) -> tuple[pd.DataFrame, dict[str, Any], Any]:
    """``derive_ctd`` + position choice + profile (:func:`bin_casts`) for one sensors-schema table (the dive's or a
    cast's)."""
    import numpy as np

    from hadal.ctd.profile import source_bins
    from hadal.ingest.cnv import NO_TIME_BASE

    pos = choose_position(p, dive, sensors_meta, header_first=external_cast)
    frame, launch_xy = (None, (0.0, 0.0)) if external_cast else _frame(dive)
    # a cast SeaSoft already binned keeps its own bins (derive.profile_source_bins)
    bins = source_bins(sensors_meta.get("cast")) if p.profile_source_bins == "keep" else None
    df, meta = derive_ctd(table, pos["latitude_deg"], pos["longitude_deg"], p, frame=frame, launch_xy=launch_xy,
                          memory_limit_bytes=memory_limit_bytes, overlying_profile=overlying_profile,
                          vertical_cast=external_cast or sensors_meta.get("source_kind") == "cnv",
                          prebinned=bins is not None)
    meta.update({k: pos[k] for k in ("latitude_source", "longitude_source")})
    if (meta.get("altimeter_false_echoes") or {}).get("readings_flagged"):
        fe = meta["altimeter_false_echoes"]
        log.warning("derive: %s: %d of %d altimeter readings put the seafloor above the cast's deepest point "
                    "(%.1f m): false echoes, flagged 4", what, fe["readings_flagged"], fe["accepted_readings"],
                    fe["deepest_depth_m"])
    vendor_method = next((st.get("salinity_method") for st in (sensors_meta.get("read_stats") or {}).values()
                          if isinstance(st, dict) and st.get("salinity_method")), None)
    if vendor_method and meta["salinity_method"] != SALINITY_FROM_CONDUCTIVITY:
        meta["salinity_method"] = vendor_method
        log.warning("derive: %s: practical salinity is %s", what, vendor_method)
    if pos["fallback"]:
        pmax = float(np.nanmax(df["pressure_dbar"].to_numpy()))
        err = _latitude_error_m(pmax)
        msg = (f"{what}: no latitude (no derive.latitude_deg, no dive.yaml launch, none in the cast header): "
               f"using {FALLBACK_LATITUDE_DEG:g} deg; gravity and depth may be off by up to {err:.2f} m at "
               f"{pmax:.0f} dbar ({100 * err / max(meta['deepest_point'].get('depth_m', 1.0), 1e-9):.2f} % of depth)")
        meta["latitude_warning"] = msg
        meta["latitude_depth_error_max_m"] = round(err, 3)
        log.warning("derive: %s", msg)
    if (meta.get("overlying_column") or {}).get("warning"):
        log.warning("derive: %s: %s", what, meta["overlying_column"]["warning"])
    if sensors_meta.get("time_base") == NO_TIME_BASE:
        meta["time_base"] = NO_TIME_BASE
    prof = bin_casts(df, meta, sensors_meta, p, log, what, bins=bins)
    return df, meta, prof


def empty_cast_reasons(prof: Any, df: pd.DataFrame) -> dict[str, str]:
    """``{cast: why}`` for every cast of the binned ``prof`` without a single binned value: which phases the
    record's samples are in and the pressure they span (a surface soak, a record of a few scans at one depth), so an
    empty profile says why instead of being published silently empty."""
    import numpy as np

    binned_vars = [v for v in prof.data_vars if prof[v].dims[:1] == ("cast",) and prof[v].ndim == 2
                   and not v.endswith("_qc") and v != "count"]
    out: dict[str, str] = {}
    pres = df["pressure_dbar"].to_numpy(np.float64) if "pressure_dbar" in df else np.empty(0)
    phases = df["phase"].astype(str).value_counts().to_dict() if "phase" in df else {}
    for i, cast in enumerate(prof["cast"].values):
        if any(np.isfinite(prof[v].values[i]).any() for v in binned_vars):
            continue
        n = int(phases.get(str(cast), 0))
        where = ", ".join(f"{k} {c}" for k, c in phases.items()) or "no phase"
        span = (f"{np.nanmin(pres):.1f}-{np.nanmax(pres):.1f} dbar" if np.isfinite(pres).any() else "no pressure")
        out[str(cast)] = (f"{n} of the record's {len(df)} accepted samples are in its {cast} (samples by phase: "
                          f"{where}; pressure {span})")
    return out


def bin_casts(df: pd.DataFrame, meta: dict[str, Any], sensors_meta: dict[str, Any], p: Params, log: Any, what: str,
              *, bins: dict[str, Any] | None = None) -> Any:
    """The binned casts (``(cast, level)`` dataset of :func:`hadal.ctd.profile.make_profile`, or a SeaSoft-binned cast's
    own bins ``bins``: :func:`hadal.ctd.profile.prebinned_profile`) of a derived table ``df`` (:func:`derive_ctd` with
    ``meta``), with per-cast times; sets ``df``'s per-sample N2 and the profile's entries of ``meta``
    (``profile_axis``, ``qc_derived.profile``, ``profile_values_excluded_by_flag``, the cast time's source).
    Only accepted samples are binned (``accept_flags``; LoopEdit's bad scans left out, as SeaSoft's BinAvg).
    Pure: called once per record, by the ``derive`` stage (:func:`derive_table`), which publishes the per-sample N2
    in ``ctd`` and keeps the binned casts in the ``ctd`` version for the ``profile`` stage to place."""
    import numpy as np

    from hadal.ctd.profile import N_SQUARED, make_profile, n_squared_per_sample, prebinned_profile
    from hadal.ingest.cnv import NO_TIME_BASE
    from hadal.qc_derived import load_qc_config, qc_profile

    # the binned profile uses only accepted samples: a flag-4 value (QARTOD fail, SeaSoft-flagged scan) is no mean's
    masked = {c: np.where(_flag_ok(df, c, list(p.accept_flags)), df[c].to_numpy(np.float64), np.nan)
              for c in ("temperature_its90_degc", "conductivity_s_m") if c in df}
    excluded = {c: int((np.isfinite(df[c].to_numpy(np.float64)) & ~np.isfinite(v)).sum()) for c, v in masked.items()}
    if any(excluded.values()):
        meta["profile_values_excluded_by_flag"] = excluded
    binned = df.assign(**masked)
    if "loop_edit_bad" in binned:  # LoopEdit's bad scans take no part in the bins (as in SeaSoft's BinAvg)
        binned = binned.loc[~binned["loop_edit_bad"].to_numpy(bool)]
    if bins is not None:
        bin_column = None
        if bins["axis"] == "depth":  # SeaSoft's depth bins are of its depSM: Fofonoff-Millard at its latitude
            from hadal.seawater import depth_fofonoff_millard

            chan_lat = [v for v in ((sensors_meta.get("cast") or {}).get("channel_latitude_deg") or {}).values()
                        if v is not None]
            lat_bins = float(chan_lat[0]) if chan_lat else meta["latitude_deg"]
            binned = binned.assign(_seasoft_depth_m=depth_fofonoff_millard(
                binned["pressure_dbar"].to_numpy(np.float64), lat_bins))
            bin_column = "_seasoft_depth_m"
            bins = {**bins, "source": f"{bins['source']}; rows placed by their Fofonoff-Millard depth at "
                                      f"{lat_bins:g} deg (SeaSoft's depSM)"}
        prof = prebinned_profile(binned, bins, latitude_deg=meta["latitude_deg"], bin_column=bin_column)
        meta["profile_axis"] = {"axis": bins["axis"], "bin_size": bins["bin_size"], "units": bins["units"],
                                "binning": "source", "source_bins": bins["source"]}
        log.info("derive: %s: binned by SeaSoft BinAvg (%s): its own %d bins kept, casts %s", what,
                 bins["source"], int(prof.sizes["depth_m" if bins["axis"] == "depth" else "pressure_dbar"]),
                 ", ".join(map(str, prof["cast"].values)))
    else:
        prof = make_profile(binned, profile_bin_size(p), binning=p.profile_binning,
                            latitude_deg=meta["latitude_deg"], axis=p.profile_axis)
        meta["profile_axis"] = {"axis": p.profile_axis, "bin_size": profile_bin_size(p),
                                "units": "m" if p.profile_axis == "depth" else "dbar", "binning": p.profile_binning}
    if "qc_derived" in meta:
        meta["qc_derived"]["profile"] = qc_profile(prof, load_qc_config(p.qc_thresholds))
        if "depth_m_qc" in prof and "depth_m" in prof.dims:  # the depth axis: bin centres are not checked
            prof = prof.drop_vars("depth_m_qc")
            prof["depth_m"].attrs.pop("ancillary_variables", None)
            meta["qc_derived"]["profile"].pop("depth_m", None)
    if empty := empty_cast_reasons(prof, binned):
        meta["profile_empty_casts"] = empty
        for cast, why in empty.items():
            log.warning("derive: %s: the %s profile has no binned values: %s", what, cast, why)
    df[N_SQUARED] = n_squared_per_sample(df, prof)
    if meta.get("time_base") != NO_TIME_BASE:
        _cast_times(prof, df)
    else:
        _header_cast_time(prof, sensors_meta, meta)
    return prof


def _header_cast_time(ds: Any, sensors_meta: dict[str, Any], meta: dict[str, Any]) -> None:
    """``time(cast)`` of a cast without a time channel: the Sea-Bird header's ``start_time`` (``cast`` metadata
    ``start_time_utc``) for every cast, recorded in ``meta["cast_time_source"]``. Without one the profile has no
    time at all (none is invented: not the processing time)."""
    import numpy as np
    import pandas as pd

    start = (sensors_meta.get("cast") or {}).get("start_time_utc")
    t = pd.Timestamp(start) if start else None
    if t is None or pd.isna(t):
        meta["cast_time_source"] = "none: no time channel and no start_time in the cast header (time omitted)"
        ds.attrs["time_omitted"] = "no time channel and no start_time in the cast header: the cast has no time"
        return
    t = (t.tz_convert("UTC") if t.tzinfo else t).tz_localize(None)
    meta["cast_start_time_utc"] = t.isoformat() + "Z"
    meta["cast_time_source"] = "cast header start_time (no time channel)"
    ds["time"] = ("cast", np.full(ds.sizes["cast"], np.datetime64(t, "ns")), {
        "standard_name": "time", "long_name": "start time of the cast from the Sea-Bird header (# start_time); "
                                              "the cast has no time channel, so the samples have no times"})


def _cast_times(ds: Any, df: pd.DataFrame) -> None:
    """``time(cast)``: when the cast was at the sea surface (descent: its first sample, ascent: its last); the
    casts' first and last sample times go into its ``comment`` (a CF ``time_bounds`` variable would need
    attributes the product writer adds to every variable)."""
    import numpy as np
    import pandas as pd

    t = df["time"].dt.tz_convert("UTC").dt.tz_localize(None)
    bounds = np.full((ds.sizes["cast"], 2), np.datetime64("NaT"), dtype="datetime64[ns]")
    for k, cast in enumerate(ds["cast"].values):
        sel = t[(df["phase"] == cast).to_numpy()]
        if len(sel):
            bounds[k] = [sel.min().to_datetime64(), sel.max().to_datetime64()]
    surface = np.array([b[1] if c == "ascent" else b[0] for c, b in zip(ds["cast"].values, bounds, strict=True)],
                       dtype="datetime64[ns]")
    spans = "; ".join(f"{c}: {pd.Timestamp(b[0]).isoformat()} to {pd.Timestamp(b[1]).isoformat()}"
                      for c, b in zip(ds["cast"].values, bounds, strict=True))
    ds["time"] = ("cast", surface, {"standard_name": "time",
                                    "long_name": "time of the cast at the sea surface (descent: first sample, "
                                                 "ascent: last sample)", "comment": f"cast spans (UTC) {spans}"})
