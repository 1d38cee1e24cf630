"""The Sea-Bird processing chain as the ``derive`` stage runs it (each step enabled by a ``derive`` parameter).

Order (SBEDataProcessing's recommended one): WildEdit -> Filter -> AlignCTD -> CellTM on the raw channels
(conductivity, temperature, CTD pressure), before salinity and density are computed; LoopEdit on the depth
series after them; BinAvg (``profile_binning: seabird``) for the ``profile`` product, without the scans
LoopEdit marked bad. ``settings`` is the stage's ``Params`` (attribute names below; defaults there, all steps
off as in SeaSoft). The time-domain steps need a uniform time base: the sample interval is the median time
step; with no time channel (a pressure-binned cast) they are skipped and the summary says so.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from hadal.ctd.align import align_ctd
from hadal.ctd.filters import low_pass_filter
from hadal.ctd.loop_edit import loop_edit
from hadal.ctd.thermal_mass import cell_thermal_mass
from hadal.ctd.wild_edit import wild_edit
from hadal.errors import InputError

#: ``derive`` parameters of the chain, by step (recorded in the product metadata when the step ran)
STEP_PARAMETERS: dict[str, tuple[str, ...]] = {
    "wild_edit": ("wild_edit_std_pass_1", "wild_edit_std_pass_2", "wild_edit_scans_per_block",
                  "wild_edit_min_delta"),
    "filter": ("filter_pressure_s", "filter_temperature_s", "filter_conductivity_s"),
    "align_ctd": ("align_conductivity_s", "align_temperature_s"),
    "cell_thermal_mass": ("cell_thermal_mass_alpha", "cell_thermal_mass_beta_inverse_s"),
    "loop_edit": ("loop_edit_min_velocity_type", "loop_edit_min_velocity_m_s", "loop_edit_window_s",
                  "loop_edit_mean_speed_percent", "loop_edit_remove_surface_soak", "loop_edit_min_soak_depth_m",
                  "loop_edit_max_soak_depth_m", "loop_edit_deck_pressure_offset"),
}


def sample_interval_s(time_ns: np.ndarray) -> tuple[float | None, float]:
    """Median time step (s) of ``time_ns`` (int64 ns) and the largest relative deviation of a step from it."""
    t = np.asarray(time_ns, dtype=np.int64)
    if t.size < 2:
        return None, 0.0
    d = np.diff(t).astype(np.float64) / 1e9
    med = float(np.median(d))
    if not med > 0:
        return None, 0.0
    return med, float(np.max(np.abs(d - med)) / med)


def _params(settings: Any, step: str) -> dict[str, Any]:
    return {k: getattr(settings, k) for k in STEP_PARAMETERS[step]}


def process_channels(conductivity_s_m: np.ndarray, temperature_degc: np.ndarray, pressure_dbar: np.ndarray,
                     interval_s: float | None, settings: Any
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[dict[str, Any]]]:
    """WildEdit, Filter, AlignCTD and CellTM (those enabled in ``settings``) on the raw channels.

    Returns the processed conductivity, temperature and pressure (new arrays) and one summary entry per step
    that ran or was skipped (``step``, ``parameters``, counts or the reason it was skipped).
    """
    c = np.array(conductivity_s_m, dtype=np.float64)
    t = np.array(temperature_degc, dtype=np.float64)
    p = np.array(pressure_dbar, dtype=np.float64)
    log: list[dict[str, Any]] = []
    if settings.wild_edit:
        kw = dict(std_pass_1=settings.wild_edit_std_pass_1, std_pass_2=settings.wild_edit_std_pass_2,
                  scans_per_block=settings.wild_edit_scans_per_block, min_delta=settings.wild_edit_min_delta)
        counts = {}
        for name, arr in (("conductivity", c), ("temperature", t), ("pressure", p)):
            m = wild_edit(arr, **kw)
            arr[m] = np.nan
            counts[name] = int(m.sum())
        log.append({"step": "wild_edit", "parameters": _params(settings, "wild_edit"), "values_removed": counts})
    time_steps = [s for s in ("filter", "align_ctd", "cell_thermal_mass") if _enabled(settings, s)]
    if time_steps and interval_s is None:
        log += [{"step": s, "parameters": _params(settings, s),
                 "skipped": "no uniform time base (no time channel): the step needs a sample interval"}
                for s in time_steps]
        return c, t, p, log
    if "filter" in time_steps:
        for arr, tau in ((p, settings.filter_pressure_s), (t, settings.filter_temperature_s),
                         (c, settings.filter_conductivity_s)):
            if tau is not None:
                arr[:] = low_pass_filter(arr, tau, interval_s)
        log.append({"step": "filter", "parameters": _params(settings, "filter"), "sample_interval_s": interval_s})
    if "align_ctd" in time_steps:
        entry: dict[str, Any] = {"step": "align_ctd", "parameters": _params(settings, "align_ctd"),
                                 "sample_interval_s": interval_s}
        try:  # an advance longer than the record: the channel is left unaligned, named in the log (no-op)
            if settings.align_conductivity_s:
                c = align_ctd(c, settings.align_conductivity_s, interval_s)
        except InputError as exc:
            entry.setdefault("skipped_channels", {})["conductivity"] = str(exc)
        try:
            if settings.align_temperature_s:
                t = align_ctd(t, settings.align_temperature_s, interval_s)
        except InputError as exc:
            entry.setdefault("skipped_channels", {})["temperature"] = str(exc)
        log.append(entry)
    if "cell_thermal_mass" in time_steps:
        corrected = cell_thermal_mass(t, c, settings.cell_thermal_mass_alpha,
                                      settings.cell_thermal_mass_beta_inverse_s, interval_s)
        d = corrected - c
        c = corrected
        log.append({"step": "cell_thermal_mass", "parameters": _params(settings, "cell_thermal_mass"),
                    "sample_interval_s": interval_s,
                    "max_abs_correction_s_m": float(np.nanmax(np.abs(d))) if np.isfinite(d).any() else 0.0})
    return c, t, p, log


def _enabled(settings: Any, step: str) -> bool:
    if step == "filter":
        return any(getattr(settings, k) is not None for k in STEP_PARAMETERS["filter"])
    if step == "align_ctd":
        return bool(settings.align_conductivity_s or settings.align_temperature_s)
    return bool(getattr(settings, step))


def loop_edit_flags(depth_m: np.ndarray, interval_s: float | None, settings: Any
                    ) -> tuple[np.ndarray | None, dict[str, Any] | None]:
    """LoopEdit's bad-scan mask on the depth series (``None`` when the step is off or cannot run)."""
    if not settings.loop_edit:
        return None, None
    entry: dict[str, Any] = {"step": "loop_edit", "parameters": _params(settings, "loop_edit")}
    if interval_s is None:
        entry["skipped"] = "no uniform time base (no time channel): the step needs a sample interval"
        return None, entry
    bad = loop_edit(depth_m, interval_s, min_velocity_m_s=settings.loop_edit_min_velocity_m_s,
                    min_velocity_type=settings.loop_edit_min_velocity_type, window_s=settings.loop_edit_window_s,
                    mean_speed_percent=settings.loop_edit_mean_speed_percent,
                    remove_surface_soak=settings.loop_edit_remove_surface_soak,
                    min_soak_depth_m=settings.loop_edit_min_soak_depth_m,
                    max_soak_depth_m=settings.loop_edit_max_soak_depth_m,
                    use_deck_pressure_offset=settings.loop_edit_deck_pressure_offset,
                    bad=~np.isfinite(np.asarray(depth_m, dtype=np.float64)))
    entry.update({"sample_interval_s": interval_s, "scans_marked_bad": int(bad.sum()), "scans": int(bad.size)})
    return bad, entry


def apply_channel_steps(df: Any, settings: Any, no_time: bool) -> tuple[float | None, list[dict[str, Any]]]:
    """:func:`process_channels` on a ``sensors``-schema DataFrame, in place: ``conductivity_s_m``,
    ``temperature_its90_degc`` and ``pressure_ctd_dbar`` (when present) become the processed channels.

    Returns the sample interval used (``None`` without a uniform time base) and the step summaries (empty
    when no step is enabled; the table is then untouched)."""
    interval_s: float | None = None
    jitter = 0.0
    if not no_time:
        t = df["time"]
        if getattr(t.dt, "tz", None) is not None:
            t = t.dt.tz_convert("UTC").dt.tz_localize(None)
        interval_s, jitter = sample_interval_s(t.to_numpy(dtype="datetime64[ns]").astype(np.int64))
    steps = [s for s in ("wild_edit", "filter", "align_ctd", "cell_thermal_mass") if _enabled(settings, s)]
    if not steps:
        return interval_s, []
    n = len(df)
    pc = df["pressure_ctd_dbar"].to_numpy(np.float64) if "pressure_ctd_dbar" in df else np.full(n, np.nan)
    c, t_, p, log = process_channels(df["conductivity_s_m"].to_numpy(np.float64),
                                     df["temperature_its90_degc"].to_numpy(np.float64), pc, interval_s, settings)
    df["conductivity_s_m"] = c
    df["temperature_its90_degc"] = t_
    if "pressure_ctd_dbar" in df:
        df["pressure_ctd_dbar"] = p
    if interval_s is not None and jitter > 0.01:
        for e in log:
            if "sample_interval_s" in e:
                e["warning"] = (f"time steps differ from the median {interval_s:g} s by up to {100 * jitter:.0f} %: "
                                "the step assumes uniform sampling")
    return interval_s, log
