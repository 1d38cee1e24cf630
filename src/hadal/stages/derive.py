"""Stage ``derive``: sensors → seawater properties, depth and seafloor depth (``ctd``) and binned profiles (``profile``).

Method: Ma et al. (2023) §3.2 ([TERCOM Eqs. 6-14]) and §4.1.3. Reads the ``sensors`` product (``sensors.parquet``,
CTD time base) and computes, per sample:

* ``pressure_dbar``: CTD pressure where valid and unsaturated (saturation also detected from the data: a
  flat line or divergence from the gauge), else the high-range gauge, on one datum via a robust gain+offset
  fit on the overlap, the gauge-CTD lag removed and a cross-over below the switch (default: the gauge's
  datum, the more accurate sensor; :func:`hadal.depth.fuse_pressure`); ``pressure_source``; fit, lag,
  saturation and switch points in the metadata (``pressure_fusion``);
* PSS-78 salinity, EOS-80 density ([TERCOM Eq. 13]), Chen-Millero sound speed (:mod:`hadal.seawater`);
* ``depth_m``: hydrostatic integral ([TERCOM Eqs. 11-12]) with gravity at the current depth ([TERCOM Eq. 14]);
  ``depth_fofonoff_millard_m`` ([TERCOM Eqs. 8-10]) and ``depth_teos10_m`` (``gsw.z_from_p`` with the dynamic height
  anomaly of the descent profile) as cross-checks — their differences go into the metadata and the log;
* ``gravity_m_s2`` at the sample's depth; ``altitude_corrected_m`` (sound-speed corrected altimeter range);
  ``seafloor_depth_m`` = depth + corrected altitude (Fig. 10); ``phase`` (descent/bottom/ascent).

Publishes ``ctd`` (``ctd.parquet``) and ``profile`` (``profile.nc``, descent and ascent casts binned by pressure,
or by depth with ``profile_axis: depth``; a cast SeaSoft's BinAvg already binned keeps its own bins and only the
casts it holds: :func:`hadal.profile.prebinned_profile`, ``profile_source_bins``).

Underway records (a ``sources.cnv`` entry with ``kind: underway``: a thermosalinograph, :mod:`hadal.ctd.underway`)
are not casts: each is published in ``trajectory`` (one CF trajectory NetCDF per record, positions from the
record's own per-scan latitude/longitude channels, :func:`underway_table`), never binned by depth; when such a
record is the dive's sensor record, derive publishes ``trajectory`` instead of ``ctd``/``profile``.

A record that does not start at the surface gets the water above from :func:`hadal.depth.overlying_column`: a
user profile (``overlying_profile``, a CSV or Sea-Bird file read by :func:`hadal.depth.read_overlying_profile`),
else its own shallower samples, else the TEOS-10 standard ocean.
"""

from __future__ import annotations

import json
from typing import TYPE_CHECKING, Any

from hadal.budget import check_memory, memory_limit_bytes
from hadal.errors import InputError
from hadal.names import record_id as file_record_id
from hadal.products.underway import trajectory_dataset
from hadal.settings.derive import DeriveParams as Params
from hadal.stages import Stage, StageInputs

if TYPE_CHECKING:
    from pathlib import Path

    import numpy as np
    import pandas as pd

    from hadal.stages import StageContext
    from hadal.store import ProductVersion


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
    """Bytes :func:`hadal.profile.make_profile` allocates for ``pressure_dbar`` in ``bin_dbar`` bins: per bin the
    edges and per cast a count plus, per variable, a sum, a count, a mean and the product array (8 bytes each).
    ``n_variables``: default ``len(hadal.profile.PROFILE_VARIABLES)`` (looked up here: hadal.profile imports xarray).
    The same holds on the depth axis with depths (m) and a bin size in m (as many variables)."""
    import numpy as np

    if n_variables is None:
        from hadal.profile import PROFILE_VARIABLES

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
    df = sensors.copy()
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
        bias_window_dbar=tuple(p.gauge_bias_window_dbar), min_bias_samples=p.min_bias_samples,
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
    order (:func:`hadal.profile.prebinned_phases`); else a record without time is one profile (descent when
    pressure increases down the file, else ascent)."""
    import numpy as np
    import pandas as pd

    from hadal.depth import segment_phases

    if prebinned:
        from hadal.profile import prebinned_phases

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
    from hadal.depth import depth_teos10, dynamic_height_anomaly
    from hadal.profile import make_profile

    teos_note = "dynamic height anomaly of the binned descent profile"
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
    are the rows up to and after the deepest, :func:`hadal.profile.prebinned_phases`).

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
            return float(cast), f"cast header (NMEA/user {axis})"
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
    return frame, tuple(float(v) for v in frame.to_xy(launch.longitude_deg, launch.latitude_deg))


def derive_table(table: pd.DataFrame, sensors_meta: dict[str, Any], p: Params, dive: Any, log: Any,
                 what: str, *, external_cast: bool = False, memory_limit_bytes: float | None = None,
                 overlying_profile: Any = None) -> tuple[pd.DataFrame, dict[str, Any], Any]:
    """``derive_ctd`` + position choice + profile for one sensors-schema table (the dive's or a cast's)."""
    import numpy as np

    from hadal.ingest.cnv import NO_TIME_BASE
    from hadal.profile import N_SQUARED, make_profile, n_squared_per_sample, prebinned_profile, source_bins
    from hadal.qc_derived import load_qc_config, qc_profile

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
    df[N_SQUARED] = n_squared_per_sample(df, prof)
    if meta.get("time_base") != NO_TIME_BASE:
        _cast_times(prof, df)
    else:
        _header_cast_time(prof, sensors_meta, meta)
    return df, meta, prof


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


def _read_table(path: Path, what: str) -> tuple[pd.DataFrame, dict[str, Any], dict[str, dict[str, str]]]:
    """A sensors-schema Parquet table with its table and field metadata; an unreadable file is a one-line error."""
    import pandas as pd

    from hadal.products.io import read_parquet_metadata

    try:
        table = pd.read_parquet(path)
        meta, fields = read_parquet_metadata(path)
    except Exception as exc:  # unreadable upstream file: one-line error, not a traceback
        raise InputError(f"{path}: cannot read {what} table ({type(exc).__name__}: {exc})") from None
    return table, meta, fields


def _read_user_profile(ctx: StageContext, p: Params) -> Any:
    """``derive.overlying_profile`` read (the file's own errors name the file, not the sensors table), or None."""
    if p.overlying_profile is None:
        return None
    from hadal.depth import read_overlying_profile

    return read_overlying_profile(overlying_profile_path(p, ctx.raw_dir), surface_dbar=p.surface_start_dbar)


def _derive_external_casts(ctx: StageContext, p: Params, sensors_meta: dict[str, Any], limit: float | None,
                           underway: list[tuple[str, pd.DataFrame, dict[str, Any], Path]] | None = None
                           ) -> tuple[Any, list[tuple[str, pd.DataFrame, dict[str, Any], Any]]]:
    """External casts ingested next to the vehicle logs ('casts' of the same ingest run), derived each:
    the ``casts`` version read and (cast id, ctd table, metadata, profile) per cast. An underway record among
    them (:func:`underway_source`) is not a cast: it goes to ``underway`` as (id, table, metadata, raw path)."""
    casts_pv = None
    cast_results: list[tuple[str, pd.DataFrame, dict[str, Any], Any]] = []
    listed = [c["cast_id"] for c in sensors_meta.get("external_casts") or []]
    if listed and ctx.store.has(ctx.dive_id, "casts"):
        casts_pv = ctx.upstream("casts")
        for cid in listed:
            cpath = casts_pv.path / f"{cid}.parquet"
            ctab, cmeta, _ = _read_table(cpath, "cast")
            cmeta = {**cmeta, "cast_latitude_deg": (cmeta.get("cast") or {}).get("latitude_deg"),
                     "cast_longitude_deg": (cmeta.get("cast") or {}).get("longitude_deg")}
            raw = underway_source(ctx, cmeta, ctab, f"cast {cid}")
            if raw is not None and underway is not None:
                underway.append((cid.replace("cast", "underway", 1), ctab, cmeta, raw))
                continue
            try:
                cdf, cm, cprof = derive_table(ctab, cmeta, p, ctx.dive, ctx.log, f"cast {cid}",
                                              external_cast=True, memory_limit_bytes=limit)
            except InputError as exc:
                raise InputError(f"{cmeta.get('sources', [{}])[0].get('path', cpath)}: {exc}") from None
            cm.update({"dive_id": ctx.dive_id, "cast_id": cid, "cast": cmeta.get("cast")})
            cast_results.append((cid, cdf, cm, cprof))
    elif listed:
        ctx.log.warning("derive: sensors lists external casts %s but the dive has no 'casts' product", listed)
    return casts_pv, cast_results


def _log_dive(ctx: StageContext, df: pd.DataFrame, meta: dict[str, Any], user_profile: Any) -> None:
    """The overlying profile's use and the dive's summary line with the depth cross-check table."""
    oc = meta["overlying_column"]
    if user_profile is not None:
        ctx.log.info("derive: overlying profile %s (%d levels, %.1f to %.1f dbar, %s): %s", user_profile.source,
                     user_profile.pressure_dbar.size, user_profile.pressure_dbar[0], user_profile.pressure_dbar[-1],
                     user_profile.basis, f"used, first sample at {oc['first_depth_m']:.2f} m"
                     if oc["method"] == "user profile" else f"not needed ({oc['method']})")
    deep = meta["deepest_point"]
    ctx.log.info("derive: %d samples, gauge bias %+.3f dbar (%d samples), deepest %.2f m at %s\n%s",
                 len(df), meta["gauge_bias_dbar"], meta["gauge_bias_samples"], deep["depth_m"],
                 deep.get("time") or f"{deep.get('pressure_dbar')} dbar", comparison_table(meta))


def _ctd_fields(ctx: StageContext, p: Params, df: pd.DataFrame, table: pd.DataFrame,
                sensor_fields: dict[str, dict[str, str]]) -> dict[str, Any]:
    """Field metadata of ``ctd.parquet`` (the sensors' units/names, the derived columns', their QC flags'); with
    a launch, the per-sample dead-reckoned ``lat``/``lon`` are added to ``df`` (products.navigation)."""
    from hadal.qc_derived import load_qc_config, qc_field_attrs

    fields = {c: {k: v for k, v in sensor_fields.get(c, {}).items() if k in ("units", "standard_name", "long_name")}
              for c in sensors_columns(table)}
    fields.update(EXTRA_COLUMN_ATTRS)
    fields.update(qc_field_attrs(df.columns, load_qc_config(p.qc_thresholds)))
    if ctx.dive.launch is not None and "dr_east_m" in df:  # per-sample position (products.navigation)
        from hadal.products.navigation import CTD_POSITION_FIELDS, dead_reckoned_lonlat

        df["lat"], df["lon"] = dead_reckoned_lonlat(df, ctx.dive.frame(), ctx.dive.launch.latitude_deg,
                                                    ctx.dive.launch.longitude_deg)
        fields.update(CTD_POSITION_FIELDS)
    return fields


def _ctd_summary(meta: dict[str, Any]) -> dict[str, Any]:
    """The ``ctd`` manifest's summary: gauge bias, latitude, deepest point, depth cross-check, QC flag counts."""
    summary = {k: meta[k] for k in ("gauge_bias_dbar", "latitude_deg", "deepest_point", "depth_comparison",
                                    "overlying_column")}
    summary["latitude_source"] = meta["latitude_source"]
    summary["qc_flags"] = {v: s["counts"] for v, s in meta["qc_derived"]["summary"].items()}
    return summary


def _source_binned(meta: dict[str, Any]) -> dict[str, Any] | None:
    """The profile's axis record when the cast kept SeaSoft's own bins (``binning: source``), else ``None``."""
    ax = meta.get("profile_axis") or {}
    return ax if ax.get("binning") == "source" else None


def _bins_text(p: Params, meta: dict[str, Any]) -> str:
    """The bins of a profile in words: the configured ones, or a SeaSoft-binned cast's own."""
    ax = _source_binned(meta)
    if ax is None:
        return f"Means in {profile_axis_text(p)} bins"
    return (f"The source file's own {ax['bin_size']:g} {ax['units']} {ax['axis']} bins (binned by SeaSoft BinAvg, "
            f"not re-binned; {ax['source_bins']})")


def _title_axis(p: Params, meta: dict[str, Any]) -> str:
    ax = _source_binned(meta)
    return _axis_title(p) if ax is None else ("Depth-binned" if ax["axis"] == "depth" else "Pressure-binned")


def _is_depth_axis(p: Params, meta: dict[str, Any]) -> bool:
    ax = _source_binned(meta)
    return p.profile_axis == "depth" if ax is None else ax["axis"] == "depth"


def _profile_summary(p: Params, profile: Any, is_prof: bool, meta: dict[str, Any] | None = None) -> str:
    """The ``summary`` attribute of ``profile.nc``."""
    meta = meta or {}
    casts = " and ".join(str(c) for c in profile["cast"].values) if _source_binned(meta) else "descent and ascent"
    return (f"{_bins_text(p, meta)} of the dive's CTD samples, separately for "
            f"the {casts} casts: temperature, conductivity, PSS-78 salinity, EOS-80 density, "
            "gravity, Chen-Millero sound speed, and "
            + ("hydrostatic / Fofonoff-Millard / TEOS-10 depths." if not _is_depth_axis(p, meta) else
               "pressure and Fofonoff-Millard / TEOS-10 depths; the depth axis is the hydrostatic depth "
               "(depth_m, Eqs. 11-12).")
            + ((" The cast has no time channel (pressure-binned): its time is the header start time."
                if "time" in profile.variables else
                " The cast has no time channel (pressure-binned) and no header start time: no times.")
               if is_prof else ""))


def _publish_profile(ctx: StageContext, p: Params, params: dict, upstream: list, profile: Any,
                     meta: dict[str, Any]) -> Any:
    """Publish ``profile`` (``profile.nc``: the binned descent and ascent casts)."""
    from hadal.ingest.cnv import NO_TIME_BASE
    from hadal.products.io import write_netcdf

    is_prof = meta.get("time_base") == NO_TIME_BASE
    _profile_attrs(profile, meta)
    zdim = "depth_m" if _is_depth_axis(p, meta) else "pressure_dbar"
    psummary: dict[str, Any] = {"bin_dbar": p.profile_bin_dbar, "levels": int(profile.sizes[zdim])}
    if p.profile_axis == "depth":  # the pressure-axis summary stays as it was
        psummary = {"axis": "depth", "bin_m": p.profile_bin_m, "levels": int(profile.sizes[zdim])}
    if (ax := _source_binned(meta)) is not None:  # a SeaSoft-binned cast: its own bins
        psummary = {"axis": ax["axis"], ("bin_m" if ax["axis"] == "depth" else "bin_dbar"): ax["bin_size"],
                    "levels": int(profile.sizes[zdim]), "binning": "source", "source_bins": ax["source_bins"],
                    "casts": [str(c) for c in profile["cast"].values]}
    with ctx.store.publish(ctx.dive_id, "profile", parameters=params, upstream=upstream,
                           extra={"summary": psummary}) as draft:
        write_netcdf(
            profile, draft.path / "profile.nc",
            title=f"{_title_axis(p, meta)} CTD profiles (descent and ascent) of dive {ctx.dive_id}",
            summary=_profile_summary(p, profile, is_prof, meta),
            keywords="CTD, salinity, density, depth, pressure, profile",
            processing_level="L2 binned profile", provenance_from=draft,
            dive_id=ctx.dive_id, latitude_used_deg=meta["latitude_deg"], latitude_source=meta["latitude_source"],
            gauge_bias_dbar=meta["gauge_bias_dbar"],
        )
    return draft.result


def _publish_cast_profiles(ctx: StageContext, p: Params, params: dict, upstream: list,
                           cast_results: list[tuple[str, pd.DataFrame, dict[str, Any], Any]],
                           fields: dict[str, Any]) -> tuple[Any, list[dict[str, Any]]]:
    """Publish ``cast_profiles``: per external cast its ctd table and binned profile, and the index JSON."""
    from hadal.products.io import json_clean, write_netcdf, write_parquet

    index = []
    with ctx.store.publish(ctx.dive_id, "cast_profiles", parameters=params, upstream=upstream,
                           extra={"casts": [c[0] for c in cast_results]}) as draft:
        for cid, cdf, cm, cprof in cast_results:
            write_parquet(cdf, draft.path / f"{cid}.parquet", fields=fields, metadata=cm, provenance_from=draft)
            _profile_attrs(cprof, cm)
            write_netcdf(cprof, draft.path / f"{cid}.nc",
                         title=f"{_title_axis(p, cm)} CTD profile of cast {cid} (dive {ctx.dive_id})",
                         summary=(f"{_bins_text(p, cm)} of an external Sea-Bird "
                                  "cast of the dive: temperature, conductivity, PSS-78 salinity, EOS-80 density, "
                                  "gravity, sound speed and " + ("depths." if not _is_depth_axis(p, cm)
                                                                 else "pressure and depths.")),
                         keywords="CTD, salinity, density, depth, pressure, profile",
                         processing_level="L2 binned profile", provenance_from=draft, dive_id=ctx.dive_id,
                         cast_id=cid, latitude_used_deg=cm["latitude_deg"],
                         latitude_source=cm["latitude_source"])
            index.append({"cast_id": cid, "table": f"{cid}.parquet", "profile": f"{cid}.nc",
                          "samples": int(len(cdf)), "time_base": cm.get("time_base", "time"),
                          "latitude_deg": cm["latitude_deg"], "latitude_source": cm["latitude_source"],
                          "latitude_warning": cm.get("latitude_warning"),
                          "deepest_point": cm["deepest_point"],
                          **({"bins": cm["profile_axis"]} if _source_binned(cm) else {})})
        (draft.path / "cast_profiles.json").write_text(json.dumps(json_clean({"casts": index}), indent=2),
                                                       encoding="utf-8")
    return draft.result, index


def run(ctx: StageContext) -> dict[str, ProductVersion]:
    from hadal.products.io import write_parquet

    p: Params = ctx.config.derive
    limit = memory_limit_bytes(ctx.config)
    sensors = ctx.upstream("sensors")
    path = sensors.file("sensors.parquet")
    table, sensors_meta, sensor_fields = _read_table(path, "sensors")
    raw = underway_source(ctx, sensors_meta, table, f"dive {ctx.dive_id}")
    if raw is not None:  # an underway record (thermosalinograph): a trajectory, no ctd/profile
        return _run_underway(ctx, p, limit, sensors, table, sensors_meta, sensor_fields, raw)
    user_profile = _read_user_profile(ctx, p)
    try:
        df, meta, profile = derive_table(table, sensors_meta, p, ctx.dive, ctx.log, f"dive {ctx.dive_id}",
                                         memory_limit_bytes=limit, overlying_profile=user_profile)
    except InputError as exc:
        if user_profile is not None and str(exc).startswith(user_profile.source):
            raise
        raise InputError(f"{path}: {exc}") from None
    meta["dive_id"] = ctx.dive_id
    underway: list[tuple[str, pd.DataFrame, dict[str, Any], Path]] = []
    casts_pv, cast_results = _derive_external_casts(ctx, p, sensors_meta, limit, underway)
    _log_dive(ctx, df, meta, user_profile)

    fields = _ctd_fields(ctx, p, df, table, sensor_fields)
    params = ctx.params("derive")
    with ctx.store.publish(ctx.dive_id, "ctd", parameters=params, upstream=[sensors],
                           extra={"summary": _ctd_summary(meta)}) as draft:
        write_parquet(df, draft.path / "ctd.parquet", fields=fields, metadata=meta, provenance_from=draft)
    ctd = draft.result
    out = {"ctd": ctd, "profile": _publish_profile(ctx, p, params, [sensors, ctd], profile, meta)}
    if cast_results:
        out["cast_profiles"], index = _publish_cast_profiles(ctx, p, params, [sensors, casts_pv], cast_results,
                                                             fields)
        ctx.log.info("derive: %d external cast(s) derived into 'cast_profiles'", len(index))
    if underway:
        out["trajectory"] = _publish_trajectories(ctx, params, [sensors, casts_pv], underway)
    return out


def _axis_title(p: Params) -> str:
    return "Depth-binned" if p.profile_axis == "depth" else "Pressure-binned"


def overlying_profile_path(p: Params, raw_dir: Any) -> Path:
    """``p.overlying_profile`` as a path: absolute, or relative to the dive's raw directory (``~`` expanded)."""
    from pathlib import Path

    path = Path(str(p.overlying_profile)).expanduser()
    return path if path.is_absolute() else Path(raw_dir) / path


def raw_files(ctx: StageContext) -> list[Path]:
    """Raw files this stage reads besides its upstream products (for the cache fingerprint, tasks/stage.py):
    the overlying profile, when configured."""
    from hadal.dive import resolve_source

    p: Params = ctx.config.derive
    files = [] if p.overlying_profile is None else [overlying_profile_path(p, ctx.raw_dir)]
    # underway records: their per-scan positions are read from the raw file
    files += [resolve_source(ctx.raw_dir, e) for e in ctx.dive.sources.files("cnv") if e.kind == "underway"]
    return files


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


def sensors_columns(table: pd.DataFrame) -> list[str]:
    return [str(c) for c in table.columns]


#: long_name of each binned variable of ``profile`` (the bins' means); units, standard_name and positive are the
#: variable registry's (``schemas/variables.yaml``, :func:`_profile_var_attrs`)
_PROFILE_LONG_NAMES: dict[str, str] = {
    "temperature_its90_degc": "mean CTD temperature (ITS-90)",
    "conductivity_s_m": "mean CTD conductivity",
    "practical_salinity": "mean practical salinity (PSS-78)",
    "density_kg_m3": "mean in situ density (EOS-80, Eq. 13)",
    "gravity_m_s2": "mean gravitational acceleration (Eq. 14)",
    "sound_speed_m_s": "mean sound speed (Chen-Millero)",
    "depth_m": "mean depth, hydrostatic integral (Eqs. 11-12)",
    "depth_fofonoff_millard_m": "mean depth, Fofonoff-Millard (Eqs. 8-10)",
    "depth_teos10_m": "mean depth, TEOS-10 with dynamic height anomaly",
    "absolute_salinity_g_kg": "mean Absolute Salinity (TEOS-10, gsw.SA_from_SP)",
    "conservative_temperature_degc": "mean Conservative Temperature (TEOS-10, gsw.CT_from_t)",
    "potential_temperature_degc": "mean potential temperature, 0 dbar (TEOS-10, gsw.pt0_from_t)",
    "sigma0_kg_m3": "mean potential density anomaly, 0 dbar (TEOS-10, gsw.sigma0)",
}


def _profile_var_attrs(name: str) -> dict[str, str]:
    """Attributes of a binned ``profile`` variable: the registry's standard_name/units/positive, the bin mean's
    long_name (:data:`_PROFILE_LONG_NAMES`)."""
    from hadal.products.registry import variable_attrs

    reg = variable_attrs(name, where="profile")
    out: dict[str, str] = {k: str(reg[k]) for k in ("standard_name", "units", "positive") if k in reg}
    out["long_name"] = _PROFILE_LONG_NAMES[name]
    return out


def _profile_attrs(ds: Any, meta: dict[str, Any]) -> None:
    import numpy as np

    from hadal.profile import N_SQUARED

    axis = "depth_m" if "depth_m" in ds.dims else "pressure_dbar"
    for name in _PROFILE_LONG_NAMES:
        if name in ds and name not in ds.dims:
            ds[name].attrs.update(_profile_var_attrs(name))
            ds[name].attrs["cell_methods"] = f"{axis}: mean"
    if axis == "depth_m" and "pressure_dbar" in ds:  # the depth axis: the bins' mean pressure is a variable
        ds["pressure_dbar"].attrs.update({"standard_name": "sea_water_pressure", "units": "dbar",
                                          "long_name": "mean sea water pressure of the depth bin",
                                          "cell_methods": "depth_m: mean"})
    if N_SQUARED in ds:
        ds[N_SQUARED].attrs.update({"standard_name": "square_of_brunt_vaisala_frequency_in_sea_water",
                                    "units": "s-2", "long_name": "buoyancy frequency squared N2 of the binned cast",
                                    "comment": "gsw.Nsquared on the binned Absolute Salinity and Conservative "
                                               "Temperature, at the mid-points between levels, linearly "
                                               "interpolated to the bin centres"})
    # the profile's nominal position (the latitude used for gravity/depth, the launch longitude)
    ds.coords["lat"] = np.float64(meta["latitude_deg"])
    ds.coords["lon"] = np.float64(meta["longitude_deg"])


# ------------------------------------------------------------------------------ underway records: trajectory
def _cnv_entry(ctx: StageContext, source_path: str | None) -> tuple[Any, Path] | None:
    """The ``sources.cnv`` entry of dive.yaml (and its resolved path) that a table was ingested from."""
    from pathlib import Path

    from hadal.dive import resolve_source
    from hadal.errors import HadalError

    if not source_path:
        return None
    want = Path(source_path)
    entries = []
    for e in ctx.dive.sources.files("cnv"):
        try:
            entries.append((e, resolve_source(ctx.raw_dir, e)))
        except HadalError:
            continue
    for e, q in entries:
        if q == want or q.resolve() == want.resolve():
            return e, q
    return next(((e, q) for e, q in entries if q.name == want.name), None)  # the raw directory was moved


def _source_path(meta: dict[str, Any]) -> str | None:
    """The raw file a one-record ``sensors``/``casts`` table came from (its header's ``source``)."""
    cast = meta.get("cast") or {}
    if cast.get("source"):
        return str(cast["source"])
    srcs = meta.get("sources") or []
    return str(srcs[0].get("path")) if len(srcs) == 1 and isinstance(srcs[0], dict) else None


def underway_source(ctx: StageContext, meta: dict[str, Any], table: pd.DataFrame, what: str) -> Path | None:
    """The raw file of a ``sensors``/``casts`` table when dive.yaml says it is an underway record (``kind:
    underway`` on its ``sources.cnv`` entry), else ``None``. Without ``kind``, a record whose pressure is
    near-constant is checked against :func:`hadal.ctd.underway.underway_evidence` and, when it looks underway, a
    warning says so (it is processed as a cast: the choice is dive.yaml's, written by ``hadal init``)."""
    import numpy as np

    from hadal.ctd.underway import MAX_PRESSURE_RANGE_DBAR

    if meta.get("source_kind") not in (None, "cnv") or "cast" not in meta:
        return None
    found = _cnv_entry(ctx, _source_path(meta))
    if found is None:
        return None
    entry, path = found
    if entry.kind == "underway":
        return path
    if entry.kind is None and "pressure_ctd_dbar" in table:
        pr = table["pressure_ctd_dbar"].to_numpy(np.float64)
        pr = pr[np.isfinite(pr)]
        if pr.size and float(pr.max() - pr.min()) <= MAX_PRESSURE_RANGE_DBAR:
            ev = _evidence(path)
            if ev is not None and ev.underway:
                ctx.log.warning("derive: %s: %s looks like an underway record (%s) but dive.yaml gives it no "
                                "'kind': processed as a cast; add 'kind: underway' to its sources.cnv entry (hadal "
                                "init writes it) to publish it as a trajectory", what, entry.path, ev.reason)
    return None


def _evidence(path: Path) -> Any:
    """:func:`hadal.ctd.underway.underway_evidence` of a raw Sea-Bird file (``None`` when it cannot be read)."""
    import warnings

    from hadal.ctd.underway import underway_evidence
    from hadal.ingest.cnv import read_seabird

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the ingest stage has already warned about the file
            return underway_evidence(read_seabird(path))
    except InputError:
        return None


def underway_table(table: pd.DataFrame, raw_path: Path, p: Params) -> tuple[pd.DataFrame, dict[str, Any]]:
    """The per-scan trajectory table of an underway record: the ingested (QC'd) samples in time order with the
    file's own per-scan positions (:func:`hadal.ctd.underway.positions_at`, matched by time), temperature and
    conductivity where their QC flags are accepted (``accept_flags``), the record's pressure (missing pressure:
    0 dbar, the sea surface, counted in the metadata) and the derived columns of
    :func:`hadal.ctd.underway.underway_columns`. A record without per-scan positions or times is a one-line
    :class:`InputError`."""
    import warnings

    import numpy as np
    import pandas as pd

    from hadal.ctd.underway import (
        distance_m,
        positions_at,
        scan_positions,
        underway_columns,
        underway_evidence,
    )
    from hadal.ingest.cnv import cnv_time_ns, read_seabird

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the ingest stage has already warned about the file
        raw = read_seabird(raw_path)
    ev = underway_evidence(raw)
    try:
        lat, lon = scan_positions(raw)
        scan_t, how = cnv_time_ns(raw)
    except KeyError:
        raise InputError(f"{raw_path}: dive.yaml says 'kind: underway' but the record has no per-scan "
                         "latitude/longitude channels: a trajectory needs them (set kind: cast)") from None
    df = table.copy()
    df["time"] = pd.to_datetime(df["time"], utc=True)
    if df["time"].isna().any():
        raise InputError(f"{raw_path}: an underway record needs a time for every scan ({how})")
    df = df.sort_values("time", kind="stable").drop_duplicates("time").reset_index(drop=True)
    t_ns = df["time"].dt.tz_convert("UTC").dt.tz_localize(None).to_numpy("datetime64[ns]").astype(np.int64)
    df["lat"], df["lon"] = positions_at(t_ns, scan_t, lat, lon)
    acc = list(p.accept_flags)
    out = pd.DataFrame({"time": df["time"], "lat": df["lat"], "lon": df["lon"]})
    for c in ("temperature_its90_degc", "conductivity_s_m"):
        out[c] = np.where(_flag_ok(df, c, acc), df[c].to_numpy(np.float64), np.nan)
        if f"{c}_qc" in df:
            out[f"{c}_qc"] = df[f"{c}_qc"].to_numpy()
    pr = (np.where(_flag_ok(df, "pressure_ctd_dbar", acc), df["pressure_ctd_dbar"].to_numpy(np.float64), np.nan)
          if "pressure_ctd_dbar" in df else np.full(len(df), np.nan))
    n_surface = int((~np.isfinite(pr)).sum())
    out["pressure_dbar"] = np.where(np.isfinite(pr), pr, 0.0)
    for name, v in underway_columns(out["conductivity_s_m"].to_numpy(), out["temperature_its90_degc"].to_numpy(),
                                    out["pressure_dbar"].to_numpy(), out["lat"].to_numpy(),
                                    out["lon"].to_numpy()).items():
        out[name] = v
    ok = np.flatnonzero(np.isfinite(out["lat"].to_numpy()))
    steps = (distance_m(out["lat"].to_numpy()[ok[:-1]], out["lon"].to_numpy()[ok[:-1]],
                        out["lat"].to_numpy()[ok[1:]], out["lon"].to_numpy()[ok[1:]]) if ok.size > 1 else np.zeros(0))
    sp = out["practical_salinity"].to_numpy()
    meta = {"source": str(raw_path), "rule": ev.to_dict(), "time_base": how,
            "positions": "the record's own per-scan latitude/longitude channels "
                         f"({ev.latitude_channel}/{ev.longitude_channel}), matched to the samples by time",
            "scans": int(len(out)), "scans_without_position": int(len(out) - ok.size),
            "pressure_missing_set_to_surface": n_surface,
            "track_length_km": round(float(steps.sum()) / 1000, 3),
            "time_coverage_start": out["time"].iloc[0].isoformat() if len(out) else None,
            "time_coverage_end": out["time"].iloc[-1].isoformat() if len(out) else None,
            "latitude_range_deg": [float(np.nanmin(out["lat"])), float(np.nanmax(out["lat"]))] if ok.size else None,
            "longitude_range_deg": [float(np.nanmin(out["lon"])), float(np.nanmax(out["lon"]))] if ok.size else None,
            "practical_salinity_range": ([float(np.nanmin(sp)), float(np.nanmax(sp))]
                                         if np.isfinite(sp).any() else None),
            "salinity_method": "PSS-78 from the record's conductivity, temperature and pressure (hadal.seawater)"}
    if ok.size == 0:
        raise InputError(f"{raw_path}: no scan of the underway record has a valid per-scan position")
    return out, meta


def _publish_trajectories(ctx: StageContext, params: dict, upstream: list,
                          records: list[tuple[str, pd.DataFrame, dict[str, Any], Path]]) -> Any:
    """Publish ``trajectory``: per underway record ``<id>.nc`` (CF trajectory) and the ``trajectory.json`` index."""
    from hadal.products.io import json_clean, write_netcdf

    p: Params = ctx.config.derive
    index = []
    with ctx.store.publish(ctx.dive_id, "trajectory", parameters=params, upstream=[u for u in upstream if u],
                           extra={"records": [r[0] for r in records]}) as draft:
        for rid, table, tmeta, raw in records:
            df, meta = underway_table(table, raw, p)
            instrument = (tmeta.get("cast") or {}).get("instrument")
            write_netcdf(trajectory_dataset(df, rid), draft.path / f"{rid}.nc",
                         title=f"Underway thermosalinograph record {rid} (dive {ctx.dive_id})",
                         summary=("An underway record (thermosalinograph in the ship's seawater line) as a CF "
                                  "trajectory: for every scan its time, the record's own latitude and longitude, "
                                  "temperature, conductivity, PSS-78 salinity, EOS-80 density, sound speed and "
                                  "TEOS-10 variables; not binned by depth (its pressure is constant)."),
                         keywords="thermosalinograph, underway, trajectory, salinity, temperature",
                         featureType="trajectory", cdm_data_type="Trajectory", processing_level="L2 underway",
                         provenance_from=draft, dive_id=ctx.dive_id, record_id=rid,
                         source_file=raw.name, underway_rule=meta["rule"]["reason"],
                         source_instrument=instrument or "")
            ctx.log.info("derive: %s: underway record (%s): trajectory of %d scans, %.2f km, %s to %s", rid,
                         meta["rule"]["reason"], meta["scans"], meta["track_length_km"],
                         meta["time_coverage_start"], meta["time_coverage_end"])
            index.append({"record_id": rid, "file": f"{rid}.nc", "instrument": instrument, **meta})
        (draft.path / "trajectory.json").write_text(json.dumps(json_clean({"records": index}), indent=2),
                                                    encoding="utf-8")
    return draft.result


def _run_underway(ctx: StageContext, p: Params, limit: float | None, sensors: Any, table: pd.DataFrame,
                  sensors_meta: dict[str, Any], sensor_fields: dict[str, dict[str, str]], raw: Path
                  ) -> dict[str, ProductVersion]:
    """derive for a dive whose ``sensors`` is an underway record: ``trajectory`` (no ``ctd``/``profile``: nothing
    vertical to derive or bin), and the external casts' ``cast_profiles`` as usual."""
    rid0 = file_record_id("underway", 0, raw)
    underway: list[tuple[str, pd.DataFrame, dict[str, Any], Path]] = [(rid0, table, sensors_meta, raw)]
    casts_pv, cast_results = _derive_external_casts(ctx, p, sensors_meta, limit, underway)
    params = ctx.params("derive")
    ctx.log.info("derive: dive %s: the sensor record %s is an underway record (dive.yaml kind: underway): "
                 "published as a trajectory, no ctd/profile", ctx.dive_id, raw.name)
    out = {"trajectory": _publish_trajectories(ctx, params, [sensors, casts_pv], underway)}
    if cast_results:
        fields = _ctd_fields(ctx, p, cast_results[0][1].copy(), table, sensor_fields)
        out["cast_profiles"], index = _publish_cast_profiles(ctx, p, params, [sensors, casts_pv], cast_results,
                                                             fields)
        ctx.log.info("derive: %d external cast(s) derived into 'cast_profiles'", len(index))
    return out


def planned_products(dive: Any, made: tuple[str, ...]) -> tuple[str, ...]:
    """What derive promises for ``dive`` (:func:`hadal.plan.plan_stages`): ``trajectory`` when a ``sources.cnv``
    entry says ``kind: underway``; without ``ctd``/``profile`` when such a record is the dive's sensor record (no
    MCAP/CSV log and no Sea-Bird cast: ingest takes casts before underway records)."""
    entries = dive.sources.files("cnv")
    if not any(e.kind == "underway" for e in entries):
        return made
    out = tuple(made) + (() if "trajectory" in made else ("trajectory",))
    if not dive.sources.mcap and not dive.sources.csv and all(e.kind == "underway" for e in entries):
        out = tuple(x for x in out if x not in ("ctd", "profile"))
    return out


#: ``trajectory`` (underway records) is promised by :func:`planned_products` when dive.yaml lists one
STAGE = Stage(
    name="derive", products=("ctd", "profile", "cast_profiles", "trajectory"),
    inputs=StageInputs(upstream=("sensors",), optional_upstream=("casts",),
                       optional_products=("cast_profiles", "trajectory")),
    options=Params, run=run, raw_files=raw_files, planned_products=planned_products,
    warm_imports=("hadal.ctd.chain", "hadal.ctd.teos10", "hadal.depth", "hadal.seawater", "hadal.profile",
                  "hadal.qc_derived", "hadal.ingest.cnv", "hadal.products.io", "hadal.products.navigation",
                  "hadal.products.registry"),
)
