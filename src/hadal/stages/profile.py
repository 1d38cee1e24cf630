"""Stage ``profile``: the dive's binned CTD casts (``profile.nc``), each placed at the navigation's position at its time.

It runs after ``match`` (issue 46): ``derive`` publishes the per-sample ``ctd`` table, ``match`` the ``navigation``
product (Kalman filter + RTS smoother over the launch, GNSS/USBL, terrain fix and dead reckoning, with a 2x2
covariance per sample); ``derive`` bins the descent and ascent casts once (:func:`hadal.ctd.derive.bin_casts`: bins,
QC, per-cast times, the per-sample N2 of ``ctd``) and keeps them in its ``ctd`` version
(:data:`hadal.products.binned.BINNED_CASTS`); this stage reads them and places each cast at its surface end
(descent: its first sample, the launch; ascent: its last, the surfacing), where CF-1.8 §9 profiles and ERDDAP's
``cdm_profile_variables`` carry one ``lat``/``lon`` per profile and where CTD casts are located by convention (a
ship's station at the start of the cast, an Argo float's profile at its surface fix).

The position source is recorded per cast (``cast_position_source``, :data:`hadal.products.dsg.POSITION_SOURCES`) and
falls back, per cast, from the ``navigation`` product (an optional upstream: ``match`` skipped or failed leaves
it absent, or an older version stays in use) to ``ctd``'s own per-sample position (launch + dead reckoning), the
cast header's NMEA position, the dive.yaml launch, and the latitude used for gravity and depth
(:func:`hadal.products.dsg.place_casts`). ``position_uncertainty_m`` is the navigation covariance's DRMS at the
cast's time (NaN for the other sources). A missing or unreadable navigation product is a warning and a fallback,
never a failure.

External Sea-Bird casts (``cast_profiles``) stay in ``derive``: they are the ship's casts, placed by their own
header position, which the vehicle's navigation does not know.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from hadal.products.binned import (
    cast_positions_summary,
    is_depth_axis,
    profile_attrs,
    profile_summary,
    source_binned,
    title_axis,
)
from hadal.settings.derive import DeriveParams as Params
from hadal.stages import Stage, StageInputs

if TYPE_CHECKING:
    import pandas as pd

    from hadal.stages import StageContext
    from hadal.store import ProductVersion

#: the navigation columns the placement reads
NAV_COLUMNS = ("time", "lat", "lon", "position_uncertainty_m", "position_covariance_east_m2",
               "position_covariance_north_m2")


def _navigation(ctx: StageContext) -> tuple[Any, pd.DataFrame | None]:
    """The ``navigation`` version and its table (the columns of :data:`NAV_COLUMNS` it has), or ``(None, None)``
    when the dive has none; an unreadable one is a warning (the casts fall back to the next source)."""
    import pandas as pd
    import pyarrow.parquet as pq

    from hadal.errors import HadalError

    try:
        pv = ctx.optional_upstream("navigation")
    except HadalError as exc:
        ctx.log.warning("profile: navigation product not used (%s): casts placed from the next source", exc)
        return None, None
    if pv is None:
        return None, None
    path = pv.path / "navigation.parquet"
    try:
        names = set(pq.read_schema(path).names)
        nav = pd.read_parquet(path, columns=[c for c in NAV_COLUMNS if c in names])
    except Exception as exc:  # noqa: BLE001 - degrade: an unreadable navigation is a fallback, not a failure
        ctx.log.warning("profile: %s unreadable (%s: %s): casts placed from the next source", path,
                        type(exc).__name__, exc)
        return None, None
    if not {"time", "lat", "lon"} <= set(nav.columns):
        ctx.log.warning("profile: %s has no time/lat/lon: casts placed from the next source", path)
        return None, None
    return pv, nav


def _header_position(sensors_meta: dict[str, Any]) -> tuple[float, float] | None:
    """The cast header's NMEA/user position of a Sea-Bird record (``cast`` metadata of ingest), or ``None``."""
    cast = sensors_meta.get("cast") or {}
    lat = sensors_meta.get("cast_latitude_deg", cast.get("latitude_deg"))
    lon = sensors_meta.get("cast_longitude_deg", cast.get("longitude_deg"))
    return (float(lat), float(lon)) if lat is not None and lon is not None else None


def publish_profile(ctx: StageContext, p: Params, params: dict, upstream: list, profile: Any,
                     meta: dict[str, Any]) -> Any:
    """Publish ``profile`` (``profile.nc``: the binned descent and ascent casts; the ``profile`` stage calls it);
    the casts' positions and their sources go into the manifest (``cast_positions``)."""
    from hadal.ingest.cnv import NO_TIME_BASE
    from hadal.products.io import write_netcdf

    is_prof = meta.get("time_base") == NO_TIME_BASE
    profile_attrs(profile, meta)
    zdim = "depth_m" if is_depth_axis(p, meta) else "pressure_dbar"
    psummary: dict[str, Any] = {"bin_dbar": p.profile_bin_dbar, "levels": int(profile.sizes[zdim])}
    if p.profile_axis == "depth":  # the pressure-axis summary stays as it was
        psummary = {"axis": "depth", "bin_m": p.profile_bin_m, "levels": int(profile.sizes[zdim])}
    if (ax := source_binned(meta)) is not None:  # a SeaSoft-binned cast: its own bins
        psummary = {"axis": ax["axis"], ("bin_m" if ax["axis"] == "depth" else "bin_dbar"): ax["bin_size"],
                    "levels": int(profile.sizes[zdim]), "binning": "source", "source_bins": ax["source_bins"],
                    "casts": [str(c) for c in profile["cast"].values]}
    extra: dict[str, Any] = {}  # global attributes of profile.nc
    manifest: dict[str, Any] = {"summary": psummary}
    if "cast_position_source" in profile:
        manifest["cast_positions"] = cast_positions_summary(profile)
        extra["cast_positions"] = "; ".join(f"{c['cast']}: {c['position_source']}"
                                                  for c in manifest["cast_positions"])
    if meta.get("profile_empty_casts"):  # a cast without a binned value says why (surface soak, a few scans)
        manifest["empty_casts"] = meta["profile_empty_casts"]
        extra["profile_empty_casts"] = "; ".join(f"{c}: {w}" for c, w in meta["profile_empty_casts"].items())
    with ctx.store.publish(ctx.dive_id, "profile", parameters=params, upstream=upstream,
                           extra=manifest) as draft:
        write_netcdf(
            profile, draft.path / "profile.nc",
            title=f"{title_axis(p, meta)} CTD profiles (descent and ascent) of dive {ctx.dive_id}",
            summary=profile_summary(p, profile, is_prof, meta),
            keywords="CTD, salinity, density, depth, pressure, profile",
            processing_level="L2 binned profile", provenance_from=draft,
            dive_id=ctx.dive_id, latitude_used_deg=meta["latitude_deg"], latitude_source=meta["latitude_source"],
            gauge_bias_dbar=meta["gauge_bias_dbar"], **extra,
        )
    return draft.result


#: the ``ctd`` columns the placement reads (:func:`hadal.products.dsg.cast_positions`)
CTD_COLUMNS = ("time", "phase", "lat", "lon", "pressure_dbar", "dr_east_m", "dr_north_m")


def run(ctx: StageContext) -> dict[str, ProductVersion]:
    from hadal.errors import InputError
    from hadal.products.binned import read_binned_casts
    from hadal.products.dsg import POSITION_SOURCES, place_casts
    from hadal.products.io import read_parquet_metadata, read_parquet_table
    from hadal.steps import step

    p: Params = ctx.config.derive
    ctd_pv, sensors_pv = ctx.upstream("ctd"), ctx.upstream("sensors")
    with step(ctx.progress, "profile: reading ctd and its binned casts"):
        path = ctd_pv.file("ctd.parquet")
        try:
            df, meta, _ = read_parquet_table(path, CTD_COLUMNS)
            sensors_meta, _ = read_parquet_metadata(sensors_pv.file("sensors.parquet"))
        except Exception as exc:  # unreadable upstream file: one-line error, not a traceback
            raise InputError(f"{path}: cannot read the ctd table ({type(exc).__name__}: {exc})") from None
        prof = read_binned_casts(ctd_pv)
    nav_pv, nav = _navigation(ctx)
    launch = ctx.dive.launch
    placed = place_casts(prof, df, navigation=nav, header=_header_position(sensors_meta),
                         launch=None if launch is None else (launch.latitude_deg, launch.longitude_deg),
                         nominal=(meta["latitude_deg"], meta["longitude_deg"]))
    if "cast_position_source" in placed:
        used = [POSITION_SOURCES[int(i)] if i >= 0 else "none" for i in placed["cast_position_source"].values]
        ctx.log.info("profile: casts %s placed from %s", ", ".join(map(str, placed["cast"].values)), ", ".join(used))
    upstream = [sensors_pv, ctd_pv] + ([nav_pv] if nav_pv is not None else [])
    return {"profile": publish_profile(ctx, p, ctx.params("profile"), upstream, placed, meta)}


STAGE = Stage(
    name="profile", products=("profile",),
    inputs=StageInputs(upstream=("sensors", "ctd"), optional_upstream=("navigation",)),
    options=Params, run=run, section="derive",  # derive's settings: they made the casts it places
    warm_imports=("hadal.products.io", "hadal.products.dsg", "hadal.registry"),
)
