"""Stage ``derive``: sensors → seawater properties, depth and seafloor depth (``ctd``).

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

Publishes ``ctd`` (``ctd.parquet``; its per-sample N2 from the binned casts). The casts are binned once, here
(:func:`hadal.ctd.derive.bin_casts`: descent and ascent binned by pressure, or by depth with ``profile_axis:
depth``; a cast SeaSoft's BinAvg already binned keeps its own bins and only the casts it holds:
:func:`hadal.ctd.profile.prebinned_profile`, ``profile_source_bins``), and kept in the ``ctd`` version
(:data:`hadal.products.binned.BINNED_CASTS`); the ``profile`` stage (:mod:`hadal.stages.profile`) places them from
the navigation product after ``match`` and publishes ``profile.nc``. External casts' binned profiles
(``cast_profiles``) stay here: they are placed by their own header position.

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

from hadal.budget import memory_limit_bytes
from hadal.ctd.derive import (
    EXTRA_COLUMN_ATTRS,
    _flag_ok,
    comparison_table,
    derive_table,
)
from hadal.errors import InputError
from hadal.names import record_id as file_record_id
from hadal.products.binned import (
    bins_text,
    is_depth_axis,
    profile_attrs,
    source_binned,
    title_axis,
    write_binned_casts,
)
from hadal.products.underway import trajectory_dataset
from hadal.settings.derive import DeriveParams as Params
from hadal.stages import Stage, StageInputs

if TYPE_CHECKING:
    from pathlib import Path

    import pandas as pd

    from hadal.stages import StageContext
    from hadal.store import ProductVersion



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

    return read_overlying_profile(overlying_profile_path(p, ctx.raw_dir), surface_dbar=p.surface_start_dbar,
                                  max_bytes=memory_limit_bytes(ctx.config))


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
            profile_attrs(cprof, cm)
            write_netcdf(cprof, draft.path / f"{cid}.nc",
                         title=f"{title_axis(p, cm)} CTD profile of cast {cid} (dive {ctx.dive_id})",
                         summary=(f"{bins_text(p, cm)} of an external Sea-Bird "
                                  "cast of the dive: temperature, conductivity, PSS-78 salinity, EOS-80 density, "
                                  "gravity, sound speed and " + ("depths." if not is_depth_axis(p, cm)
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
                          **({"bins": cm["profile_axis"]} if source_binned(cm) else {})})
        (draft.path / "cast_profiles.json").write_text(json.dumps(json_clean({"casts": index}), indent=2),
                                                       encoding="utf-8")
    return draft.result, index


def run(ctx: StageContext) -> dict[str, ProductVersion]:
    from hadal.products.io import write_parquet

    p: Params = ctx.config.derive
    limit = memory_limit_bytes(ctx.config)
    sensors = ctx.upstream("sensors")
    path = sensors.file("sensors.parquet")
    from hadal.steps import step  # progress lines (issue 46)

    with step(ctx.progress, f"derive: reading {path.name}"):
        table, sensors_meta, sensor_fields = _read_table(path, "sensors")
    raw = underway_source(ctx, sensors_meta, table, f"dive {ctx.dive_id}")
    if raw is not None:  # an underway record (thermosalinograph): a trajectory, no ctd/profile
        return _run_underway(ctx, p, limit, sensors, table, sensors_meta, sensor_fields, raw)
    user_profile = _read_user_profile(ctx, p)
    try:
        with step(ctx.progress, f"derive: {len(table):,} samples -> depth, TEOS-10, QC, profiles"):
            df, meta, binned = derive_table(table, sensors_meta, p, ctx.dive, ctx.log, f"dive {ctx.dive_id}",
                                            memory_limit_bytes=limit, overlying_profile=user_profile)
    except InputError as exc:
        if user_profile is not None and str(exc).startswith(user_profile.source):
            raise
        raise InputError(f"{path}: {exc}") from None
    meta["dive_id"] = ctx.dive_id
    underway: list[tuple[str, pd.DataFrame, dict[str, Any], Path]] = []
    casts_pv, cast_results = _derive_external_casts(ctx, p, sensors_meta, limit, underway)
    _log_dive(ctx, df, meta, user_profile)
    table = table.iloc[:0]  # only its columns are needed from here: the samples are not held while writing

    fields = _ctd_fields(ctx, p, df, table, sensor_fields)
    params = ctx.params("derive")
    with step(ctx.progress, "derive: writing ctd"), ctx.store.publish(
            ctx.dive_id, "ctd", parameters=params, upstream=[sensors], extra={"summary": _ctd_summary(meta)}) as draft:
        write_parquet(df, draft.path / "ctd.parquet", fields=fields, metadata=meta, provenance_from=draft)
        # the casts binned once (ctd's per-sample N2 is theirs): the profile stage places them after match
        write_binned_casts(binned, draft.path)
    out: dict[str, Any] = {"ctd": draft.result}
    if cast_results:
        out["cast_profiles"], index = _publish_cast_profiles(ctx, p, params, [sensors, casts_pv], cast_results,
                                                             fields)
        ctx.log.info("derive: %d external cast(s) derived into 'cast_profiles'", len(index))
    if underway:
        out["trajectory"] = _publish_trajectories(ctx, params, [sensors, casts_pv], underway)
    return out


def overlying_profile_path(p: Params, raw_dir: Any) -> Path:
    """``p.overlying_profile`` as a path, relative to the dive's raw directory (or absolute, ``~`` expanded) and,
    like every source, inside it: a path that resolves outside the dive (``..``, a symbolic link) is a one-line
    :class:`~hadal.errors.ConfigError` (:func:`hadal.dive.resolve_source`)."""
    from pathlib import Path

    from hadal.dive import resolve_source

    return resolve_source(Path(raw_dir), str(Path(str(p.overlying_profile)).expanduser()))


def raw_files(ctx: StageContext) -> list[Path]:
    """Raw files this stage reads besides its upstream products (for the cache fingerprint, tasks/stage.py):
    the overlying profile, when configured."""
    from hadal.dive import resolve_source

    p: Params = ctx.config.derive
    files = [] if p.overlying_profile is None else [overlying_profile_path(p, ctx.raw_dir)]
    # underway records: their per-scan positions are read from the raw file
    files += [resolve_source(ctx.raw_dir, e) for e in ctx.dive.sources.files("cnv") if e.kind == "underway"]
    return files


def sensors_columns(table: pd.DataFrame) -> list[str]:
    return [str(c) for c in table.columns]


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
            ev = _evidence(path, memory_limit_bytes(ctx.config))
            if ev is not None and ev.underway:
                ctx.log.warning("derive: %s: %s looks like an underway record (%s) but dive.yaml gives it no "
                                "'kind': processed as a cast; add 'kind: underway' to its sources.cnv entry (hadal "
                                "init writes it) to publish it as a trajectory", what, entry.path, ev.reason)
    return None


def _evidence(path: Path, max_bytes: float | None) -> Any:
    """:func:`hadal.ctd.underway.underway_evidence` of a raw Sea-Bird file (``None`` when it cannot be read, or its
    read would pass the memory budget ``max_bytes``: the stage's ``resources.max_memory_gb``)."""
    import warnings

    from hadal.ctd.underway import underway_evidence
    from hadal.ingest.cnv import read_seabird

    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the ingest stage has already warned about the file
            return underway_evidence(read_seabird(path, max_bytes=max_bytes))
    except InputError:
        return None


def underway_table(table: pd.DataFrame, raw_path: Path, p: Params, *, max_bytes: float | None = None
                   ) -> tuple[pd.DataFrame, dict[str, Any]]:
    """The per-scan trajectory table of an underway record: the ingested (QC'd) samples in time order with the
    file's own per-scan positions (:func:`hadal.ctd.underway.positions_at`, matched by time), temperature and
    conductivity where their QC flags are accepted (``accept_flags``), the record's pressure (missing pressure:
    0 dbar, the sea surface, counted in the metadata) and the derived columns of
    :func:`hadal.ctd.underway.underway_columns`. A record without per-scan positions or times is a one-line
    :class:`InputError`. The raw file is re-read against the memory budget ``max_bytes`` (the stage's
    ``resources.max_memory_gb``; :func:`hadal.ingest.cnv.read_seabird`)."""
    import warnings

    import numpy as np
    import pandas as pd

    from hadal.ctd.underway import (
        distance_m,
        positions_at,
        record_positions,
        underway_columns,
        underway_evidence,
    )
    from hadal.ingest.cnv import cnv_time_ns, read_seabird

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the ingest stage has already warned about the file
        raw = read_seabird(raw_path, max_bytes=max_bytes)
    ev = underway_evidence(raw)
    try:
        lat, lon, where = record_positions(raw)
        scan_t, how = cnv_time_ns(raw)
    except KeyError:
        raise InputError(f"{raw_path}: dive.yaml says 'kind: underway' but the record has no per-scan "
                         "latitude/longitude channels and no header position: a trajectory needs them (set kind: cast)"
                         ) from None
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
            "positions": where,
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
            df, meta = underway_table(table, raw, p, max_bytes=memory_limit_bytes(ctx.config))
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
            from hadal.products.geoparquet import write_record_track  # its track for GIS: <id>_track.geojson

            write_record_track(df, draft.path / f"{rid}_track.geojson", rid)
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
    """What derive promises for ``dive`` (:func:`hadal.stages.plan.plan_stages`): ``trajectory`` when a ``sources.cnv``
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
    name="derive", products=("ctd", "cast_profiles", "trajectory"),
    inputs=StageInputs(upstream=("sensors",), optional_upstream=("casts",),
                       optional_products=("cast_profiles", "trajectory")),
    options=Params, run=run, raw_files=raw_files, planned_products=planned_products,
    warm_imports=("hadal.ctd.chain", "hadal.ctd.teos10", "hadal.depth", "hadal.seawater", "hadal.ctd.profile",
                  "hadal.qc_derived", "hadal.ingest.cnv", "hadal.products.io", "hadal.products.navigation",
                  "hadal.registry"),
)
