"""CF-1.8 Discrete Sampling Geometries (chapter 9, Appendix H) as ERDDAP and the IOOS compliance-checker read them.

* Instance ids are NC_CHAR arrays (``char id(instance, id_strlen)``, CF §2.2 / H.2) with ``cf_role``: netCDF-4
  ``string`` variables are refused by the NCAS cf-checker (CF §2.2 lists no string type before CF-1.9) and by
  older netCDF readers (:func:`char_id`).
* Binned casts (``derive``'s ``profile``: descent and ascent of one vehicle; ``cast_profiles``: one external
  cast per file) are written as a **contiguous ragged array** (CF-1.8 §H.3.4 for one cast, §H.6.3 for the
  casts of one dive): dimension ``profile`` (one instance per cast) with the id ``profile_id`` (``cf_role =
  profile_id``), per-cast ``time``/``lat``/``lon`` and ``row_size`` (``sample_dimension = obs``); dimension
  ``obs`` with the binned variables and ``depth_m`` (``axis = Z``, ``positive = down``) as the vertical
  coordinate; pressure is a data variable. Empty bins are left out. The casts of one dive are a
  ``trajectoryProfile`` (IOOS-1.2 allows one trajectory per file, any number of profiles along it): a
  length-1 ``trajectory`` dimension with the dive id (``cf_role = trajectory_id``) and ``trajectory_index``
  (``instance_dimension = trajectory``) on the profiles. One cast is a ``profile`` (IOOS-1.2: one per file).
* ERDDAP's ``cdm_data_type`` and ``cdm_trajectory_variables`` / ``cdm_profile_variables`` / ``subsetVariables``
  name the instance variables (:func:`dsg_global_attributes`).

:func:`orthogonal_profile` turns such a file back into the (cast, level) layout the report's figures use.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np
import pandas as pd
import xarray as xr

#: instance dimensions of binned casts as ``hadal.ctd.profile.make_profile`` builds them
CAST_DIMS = ("cast", "profile")
#: the vertical coordinate of the ragged profiles (CF ``depth``, positive down, m)
Z_NAME = "depth_m"
#: instance variables of a profile (ERDDAP ``cdm_profile_variables``; ``profile_id`` holds ``cf_role``)
PROFILE_VARIABLES = ("profile_id", "time", "lat", "lon")


def char_id(values: Sequence[str], dim: str, attrs: dict[str, Any]) -> xr.Variable:
    """Ids ``values`` as a NC_CHAR array ``(dim, <dim>_strlen)`` (CF §2.2: a string is a char array whose last
    dimension is the maximum length). xarray writes the fixed-width bytes as ``S1`` characters."""
    encoded = [str(v).encode("utf-8") for v in values]
    width = max([1, *(len(b) for b in encoded)])
    var = xr.Variable((dim,), np.array(encoded, dtype=f"S{width}"), attrs)
    var.encoding.update({"dtype": "S1", "char_dim_name": f"{dim}_strlen"})
    return var


def id_values(var: xr.DataArray | xr.Variable) -> list[str]:
    """The ids of a char id variable as read back by xarray (bytes or str) as ``str``."""
    return [v.decode("utf-8") if isinstance(v, bytes) else str(v) for v in np.asarray(var.values).ravel()]


#: where a cast's position came from, best first (:func:`place_casts`; ``cast_position_source`` flag meanings)
POSITION_SOURCES = ("navigation", "ctd_dead_reckoning", "cast_header", "launch", "nominal")
_SOURCE_TEXT = {
    "navigation": "the navigation product (Kalman filter + RTS smoother over every position source, match stage) "
                  "interpolated to the cast's time",
    "ctd_dead_reckoning": "the vehicle's own position channels in ctd (launch + dead-reckoned offsets) at the "
                          "cast's time (no navigation product: match skipped or failed)",
    "cast_header": "the cast header position (NMEA/user; no navigation product, no dead-reckoned position)",
    "launch": "the dive.yaml launch position (no navigation product, no dead-reckoned or header position)",
    "nominal": "the latitude/longitude derive used for gravity and depth (no other position)",
}


def cast_positions(ctd: pd.DataFrame, casts: Sequence[str], phase_column: str = "phase") -> pd.DataFrame:
    """Time and reference sample of every cast in the ``ctd`` table (rows in time order): its **surface end**,
    where a CTD profile is located by convention (a ship's station at the start of the cast, an Argo float's
    profile at its surface fix): the first sample of a descent (the launch), the last of an ascent (where the
    vehicle surfaced); another cast at its shallowest sample. The time is the same instant ``derive`` gives the
    cast (:func:`hadal.ctd.derive._cast_times`). Columns: ``cast``, ``index`` (row of ``ctd``, -1 for a cast
    without samples), ``time`` (NaT without a time channel), ``lat``/``lon`` (the table's own per-sample
    position there, NaN without one or when no dead-reckoned offset is known up to that sample: then the table's
    position is only the launch's, ``dead_reckoned`` False), ``position_note``."""
    rows = []
    phase = ctd[phase_column].astype(str).to_numpy() if phase_column in ctd else np.full(len(ctd), "")
    have = {"lat", "lon"} <= set(ctd.columns)
    lat = ctd["lat"].to_numpy(float) if have else np.full(len(ctd), np.nan)
    lon = ctd["lon"].to_numpy(float) if have else np.full(len(ctd), np.nan)
    t = pd.to_datetime(ctd["time"], utc=True) if "time" in ctd else None
    p = ctd["pressure_dbar"].to_numpy(float) if "pressure_dbar" in ctd else None
    # a dead-reckoned offset known at or before each sample (without one the table's lat/lon is the launch's)
    dr = np.ones(len(ctd), bool)
    if {"dr_east_m", "dr_north_m"} <= set(ctd.columns):
        dr = np.maximum.accumulate(np.isfinite(ctd["dr_east_m"].to_numpy(float))
                                   & np.isfinite(ctd["dr_north_m"].to_numpy(float)))
    for cast in casts:
        idx = np.flatnonzero(phase == str(cast))
        if idx.size == 0:
            rows.append({"cast": str(cast), "index": -1, "time": pd.NaT, "lat": np.nan, "lon": np.nan,
                         "position_note": None})
            continue
        if str(cast) == "descent":
            k, where = idx[0], "first sample of the descent (launch)"
        elif str(cast) == "ascent":
            k, where = idx[-1], "last sample of the ascent (surfacing)"
        elif p is not None and np.isfinite(p[idx]).any():
            k, where = idx[int(np.nanargmin(p[idx]))], "shallowest sample of the cast"
        else:
            k, where = idx[0], "first sample of the cast"
        own = bool(dr[k])
        rows.append({"cast": str(cast), "index": int(k), "time": t.iloc[k] if t is not None else pd.NaT,
                     "lat": lat[k] if own else np.nan, "lon": lon[k] if own else np.nan, "position_note": where})
    return pd.DataFrame(rows)


def _interp_navigation(nav: pd.DataFrame, t: pd.Timestamp) -> tuple[float, float, float] | None:
    """(lat, lon, DRMS m) of the navigation table ``nav`` at time ``t``, linear in time between its two samples
    around ``t`` (its covariance likewise: ``position_uncertainty_m`` = sqrt(trace), the 1-sigma radial DRMS);
    ``None`` outside its time span or without positions."""
    tn = pd.to_datetime(nav["time"], utc=True).dt.tz_convert(None).to_numpy("datetime64[ns]").astype(np.int64)
    lat, lon = nav["lat"].to_numpy(float), nav["lon"].to_numpy(float)
    ok = np.isfinite(lat) & np.isfinite(lon) & (tn != np.iinfo(np.int64).min)
    if not ok.any() or pd.isna(t):
        return None
    tn, lat, lon = tn[ok], lat[ok], lon[ok]
    x = pd.Timestamp(t)
    x = (x.tz_convert("UTC").tz_localize(None) if x.tzinfo else x).as_unit("ns").value
    if x < tn[0] or x > tn[-1]:
        return None
    var = np.full(tn.size, np.nan)
    if {"position_covariance_east_m2", "position_covariance_north_m2"} <= set(nav.columns):
        var = (nav["position_covariance_east_m2"].to_numpy(float) + nav["position_covariance_north_m2"]
               .to_numpy(float))[ok]
    elif "position_uncertainty_m" in nav:
        var = nav["position_uncertainty_m"].to_numpy(float)[ok] ** 2
    xs = (tn - tn[0]).astype(float)
    at = float(x - tn[0])
    return (float(np.interp(at, xs, lat)), float(np.interp(at, xs, lon)),
            float(np.sqrt(np.interp(at, xs, var))) if np.isfinite(var).all() else float("nan"))


def place_casts(profile: xr.Dataset, ctd: pd.DataFrame, phase_column: str = "phase", *,
                navigation: pd.DataFrame | None = None, header: tuple[float, float] | None = None,
                launch: tuple[float, float] | None = None, nominal: tuple[float, float] | None = None
                ) -> xr.Dataset:
    """``profile`` (``make_profile``'s ``(cast, level)`` dataset) with per-cast ``lat``/``lon`` (and ``time`` when
    the casts have none) at each cast's surface end (:func:`cast_positions`), its ``cast_position_source`` (flag,
    :data:`POSITION_SOURCES`) and ``position_uncertainty_m``. The position is, best first and per cast:

    1. ``navigation``: the navigation product's table (``time``, ``lat``, ``lon`` and its 2x2 covariance)
       interpolated to the cast's time (:func:`_interp_navigation`); the uncertainty its DRMS there;
    2. the ``ctd`` table's own per-sample ``lat``/``lon`` (launch + dead reckoning) at the cast's sample;
    3. ``header``: the cast header's NMEA/user (lat, lon);
    4. ``launch``: the dive.yaml launch (lat, lon);
    5. ``nominal``: the (lat, lon) used for gravity and depth.

    Only the navigation carries an uncertainty (NaN otherwise: none is invented). CF-1.8 §9 gives a profile one
    horizontal position (the instance variables ``lat``/``lon``, ERDDAP's ``cdm_profile_variables``)."""
    if "cast" not in profile.dims:
        return profile
    names = [str(c) for c in profile["cast"].values]
    pos = cast_positions(ctd, names, phase_column)
    n = len(names)
    lat, lon, unc = np.full(n, np.nan), np.full(n, np.nan), np.full(n, np.nan)
    src = np.full(n, -1, dtype="i1")
    notes = []
    for i, r in enumerate(pos.itertuples()):
        got: tuple[str, float, float, float] | None = None
        if navigation is not None and len(navigation) and not pd.isna(r.time):
            at = _interp_navigation(navigation, r.time)
            if at is not None:
                got = ("navigation", *at)
        if got is None and np.isfinite(r.lat) and np.isfinite(r.lon):
            got = ("ctd_dead_reckoning", float(r.lat), float(r.lon), np.nan)
        for name, value in (("cast_header", header), ("launch", launch), ("nominal", nominal)):
            if got is None and value is not None and all(v is not None and np.isfinite(v) for v in value):
                got = (name, float(value[0]), float(value[1]), np.nan)
        if got is None:
            notes.append(f"{r.cast}: no position")
            continue
        src[i], lat[i], lon[i], unc[i] = POSITION_SOURCES.index(got[0]), got[1], got[2], got[3]
        where = f" at the {r.position_note}" if isinstance(r.position_note, str) and got[0] in (
            "navigation", "ctd_dead_reckoning") else ""
        notes.append(f"{r.cast}: {_SOURCE_TEXT[got[0]]}{where}")
    if (src < 0).all():
        return profile
    comment = ("the cast's position at its surface end (descent: its first sample, ascent: its last), from "
               + "; ".join(notes))
    coords: dict[str, Any] = {
        "lat": ("cast", lat, {"long_name": "latitude of the cast", "comment": comment}),
        "lon": ("cast", lon, {"long_name": "longitude of the cast", "comment": comment})}
    t = pd.to_datetime(pos["time"], utc=True).dt.tz_convert(None).to_numpy(dtype="datetime64[ns]")
    if "time" not in profile.variables and not np.isnat(t).any():  # binned casts have theirs: the same instant
        coords["time"] = ("cast", t, {"standard_name": "time", "long_name": "time of the cast (at its position)"})
    out = profile.drop_vars([c for c in coords if c in profile.variables])
    out = out.assign_coords(coords)
    out["cast_position_source"] = ("cast", src, {
        "long_name": "source of the cast's position", "flag_values": np.arange(len(POSITION_SOURCES), dtype="i1"),
        "flag_meanings": " ".join(POSITION_SOURCES)})
    out["position_uncertainty_m"] = ("cast", unc, {
        "units": "m", "long_name": "1-sigma radial (DRMS) horizontal uncertainty of the cast's position",
        "comment": "sqrt of the trace of the navigation product's 2x2 position covariance at the cast's time; "
                   "NaN when the position is not from the navigation product", "coordinates": "time lat lon"})
    return out


def _cast_labels(ds: xr.Dataset, dim: str) -> list[str]:
    v = ds[dim] if dim in ds.variables else None
    if v is None:
        return [f"cast{i}" for i in range(ds.sizes[dim])]
    meanings = str(v.attrs.get("flag_meanings", "")).split()
    if v.dtype.kind in "iu" and meanings:
        return [meanings[int(i)] if 0 <= int(i) < len(meanings) else f"cast{int(i)}" for i in v.values]
    return [x.decode() if isinstance(x, bytes) else str(x) for x in v.values]


def is_binned_casts(ds: xr.Dataset) -> str | None:
    """The cast dimension of a ``(cast, level)`` binned-profile dataset (a vertical dimension coordinate in dbar
    or m besides it, no y/x grid), else ``None``."""
    dim = next((d for d in CAST_DIMS if d in ds.dims), None)
    if dim is None or {"y", "x"} <= set(ds.dims):
        return None
    z = _level_dim(ds, dim)
    return dim if z is not None else None


def _level_dim(ds: xr.Dataset, cast_dim: str) -> str | None:
    for d in ds.dims:
        if d == cast_dim or d not in ds.coords:
            continue
        a = ds[d].attrs
        if a.get("units") in ("dbar", "decibar", "m") or a.get("axis") == "Z" or str(d).startswith(("pressure", "depth")):
            return str(d)
    return None


def ragged_profiles(ds: xr.Dataset, dive_id: str | None, *, latitude_deg: float | None = None) -> xr.Dataset:
    """A ``(cast, level)`` binned-profile dataset as a CF-1.8 contiguous ragged array (module docstring): one
    ``profile`` instance per cast, its non-empty bins on ``obs``; ``depth_m`` the Z coordinate (the bins' own
    depth when the data have one, else the bin centres on a depth axis, else TEOS-10 ``gsw.z_from_p`` of the
    pressure bins at ``latitude_deg``). More than one cast: a trajectoryProfile of the dive ``dive_id``."""
    cdim = is_binned_casts(ds)
    if cdim is None:
        raise ValueError("not a (cast, level) binned-profile dataset")
    zdim = _level_dim(ds, cdim)
    assert zdim is not None
    labels = _cast_labels(ds, cdim)
    n = len(labels)
    full = ds.reset_coords()
    # the depth of every (cast, level): the data's own, else the axis itself, else from pressure
    if Z_NAME in full.variables and Z_NAME != zdim:
        depth2 = np.broadcast_to(full[Z_NAME].transpose(*[d for d in (cdim, zdim) if d in full[Z_NAME].dims]).values
                                 if full[Z_NAME].ndim == 2 else full[Z_NAME].values[None, :], (n, ds.sizes[zdim]))
        z_attrs = dict(full[Z_NAME].attrs)
    elif zdim == Z_NAME:
        depth2 = np.broadcast_to(full[zdim].values[None, :], (n, ds.sizes[zdim]))
        z_attrs = dict(full[zdim].attrs)
    else:
        import gsw

        lat = latitude_deg if latitude_deg is not None else (
            float(np.nanmean(full["lat"].values)) if "lat" in full.variables else 45.0)
        depth2 = np.broadcast_to(-gsw.z_from_p(full[zdim].values.astype(float), lat)[None, :], (n, ds.sizes[zdim]))
        z_attrs = {"long_name": f"depth of the pressure bin (TEOS-10 gsw.z_from_p at {lat:.4f} deg N)"}
    depth2 = np.asarray(depth2, float)
    # an observation per non-empty bin: counted samples, else any finite measurement
    full = full.transpose(cdim, zdim, ...)
    data_names = [str(k) for k, v in full.data_vars.items() if set(v.dims) == {cdim, zdim} and str(k) != Z_NAME]
    if "count" in full and full["count"].dims == (cdim, zdim):
        keep = np.asarray(full["count"].values) > 0
    else:
        keep = np.zeros((n, ds.sizes[zdim]), bool)
        for k in data_names:
            vals = np.asarray(full[k].values)
            keep |= np.isfinite(vals) if vals.dtype.kind == "f" else True
    keep &= np.isfinite(depth2)
    rows = keep.sum(axis=1).astype("i4")
    if rows.any() and not rows.all():  # a cast without a single bin is no profile (e.g. a downcast-only file)
        held = np.flatnonzero(rows > 0)
        full, depth2, keep, rows = full.isel({cdim: held}), depth2[held], keep[held], rows[held]
        labels, n = [labels[i] for i in held], held.size
    ci, li = np.nonzero(keep)  # row-major: cast by cast, levels in order (contiguous ragged array)
    obs: dict[str, Any] = {}
    for k in data_names:
        obs[k] = ("obs", np.asarray(full[k].values)[ci, li], dict(full[k].attrs), dict(full[k].encoding))
    if zdim != Z_NAME:  # the axis of the binning becomes a data variable (e.g. the pressure bin centres)
        obs[zdim] = ("obs", np.asarray(full[zdim].values)[li], {**full[zdim].attrs}, {})
        for key in ("axis", "positive"):
            obs[zdim][2].pop(key, None)
        if obs[zdim][2].get("units") in ("dbar", "decibar"):
            obs[zdim][2].setdefault("standard_name", "sea_water_pressure")
    z_attrs = {k: v for k, v in z_attrs.items() if k not in ("cell_methods",)}
    z_attrs.update({"standard_name": "depth", "units": "m", "positive": "down", "axis": "Z"})
    out = xr.Dataset()
    for k, (dims, vals, attrs, enc) in obs.items():
        out[k] = xr.Variable(dims, vals, attrs)
        out[k].encoding.update({e: x for e, x in enc.items() if e in ("zlib", "complevel", "shuffle")})
    ids = [f"{dive_id}_{lab}" if dive_id else lab for lab in labels]
    out["profile_id"] = char_id(ids, "profile", {"cf_role": "profile_id", "long_name": "cast id (dive_cast)"})
    out["row_size"] = xr.Variable(("profile",), rows, {"sample_dimension": "obs",
                                                       "long_name": "number of levels of the cast"})
    out["cast"] = xr.Variable(("profile",), np.arange(n, dtype="i1"), {
        "long_name": "cast (dive phase)", "flag_values": np.arange(n, dtype="i1"),
        "flag_meanings": " ".join(lab.replace(" ", "_") for lab in labels)})
    coords: dict[str, Any] = {Z_NAME: ("obs", depth2[ci, li], z_attrs)}
    for name in ("time", "lat", "lon"):
        if name not in full.variables:
            continue
        v = full[name]
        if v.ndim == 0:
            note = {"lat": "the position of every cast: ", "lon": "the position of every cast: ",
                    "time": "the time of every cast: "}[name]
            attrs = dict(v.attrs)
            attrs["comment"] = note + (attrs.get("comment") or attrs.get("long_name") or
                                       "the dive's header/launch position (no per-sample navigation)")
            coords[name] = ("profile", np.repeat(v.values[None], n), attrs)
        elif v.dims == (cdim,):
            coords[name] = ("profile", v.values, dict(v.attrs))
    out = out.assign_coords(coords)
    for name in ("lat", "lon"):
        if name in out.coords:
            out[name].attrs.pop("axis", None)
    _carry_other_variables(full, out, cdim, zdim, li, set(obs) | {Z_NAME, "time", "lat", "lon", cdim, zdim})
    if n > 1:
        out["trajectory"] = char_id([dive_id or "dive"], "trajectory",
                                    {"cf_role": "trajectory_id", "long_name": "dive id"})
        out["trajectory_index"] = xr.Variable(("profile",), np.zeros(n, "i4"), {
            "instance_dimension": "trajectory", "long_name": "trajectory (dive) of the cast"})
    coord_names = " ".join(c for c in ("time", "lat", "lon", Z_NAME) if c in out.coords)
    for k in obs:
        out[k].attrs["coordinates"] = coord_names
        if out[k].attrs.get("cell_methods"):
            out[k].attrs["cell_methods"] = str(out[k].attrs["cell_methods"]).replace(f"{zdim}:", "obs:")
    out.attrs = dict(ds.attrs)
    return out


def _carry_other_variables(full: xr.Dataset, out: xr.Dataset, cdim: str, zdim: str, li: np.ndarray,
                           done: set[str]) -> None:
    """In place: the variables of ``full`` not yet in ``out`` - per cast on ``profile``, per level on ``obs``
    (each observation's level ``li``), anything else (scalars, other dimensions) as it is: nothing is dropped."""
    for name, v in full.variables.items():
        if str(name) in done or name in out.variables:
            continue
        if v.dims == (cdim,):
            out[str(name)] = xr.Variable(("profile",), v.values, dict(v.attrs))
        elif v.dims == (zdim,):
            out[str(name)] = xr.Variable(("obs",), np.asarray(v.values)[li], dict(v.attrs))
        elif cdim not in v.dims and zdim not in v.dims:
            out[str(name)] = v


def dsg_global_attributes(ds: xr.Dataset) -> dict[str, str]:
    """``featureType``, ERDDAP ``cdm_data_type``, ``cdm_*_variables`` and ``subsetVariables`` of a DSG dataset,
    from its ``cf_role`` variables (empty for a dataset without one)."""
    roles = {str(v.attrs.get("cf_role")): str(n) for n, v in ds.variables.items() if v.attrs.get("cf_role")}
    traj, prof = roles.get("trajectory_id"), roles.get("profile_id")
    if traj and prof:
        tvars = [traj]
        pvars = [prof] + [c for c in ("time", "lat", "lon") if c in ds.variables and ds[c].dims == ds[prof].dims[:1]]
        return {"featureType": "trajectoryProfile", "cdm_data_type": "TrajectoryProfile",
                "cdm_trajectory_variables": ",".join(tvars), "cdm_profile_variables": ",".join(pvars),
                "subsetVariables": ",".join(tvars + pvars)}
    if prof:
        pvars = [prof] + [c for c in ("time", "lat", "lon") if c in ds.variables and ds[c].dims == ds[prof].dims[:1]]
        return {"featureType": "profile", "cdm_data_type": "Profile", "cdm_profile_variables": ",".join(pvars),
                "subsetVariables": ",".join(pvars)}
    if traj:
        return {"featureType": "trajectory", "cdm_data_type": "Trajectory", "cdm_trajectory_variables": traj,
                "subsetVariables": traj}
    return {}


def orthogonal_profile(ds: xr.Dataset) -> xr.Dataset:
    """A ragged profile file (:func:`ragged_profiles`) back in the ``(cast, level)`` layout of
    ``hadal.ctd.profile.make_profile`` (the report's figures read that): ``cast`` labels from the ``cast`` flags,
    levels on the union of the casts' bins of the binning axis (``pressure_dbar`` when present, else
    ``depth_m``), NaN where a cast has no bin. A dataset without ``row_size`` is returned unchanged."""
    if "row_size" not in ds.variables or "obs" not in ds.dims:
        return ds
    rows = np.asarray(ds["row_size"].values, int)
    meanings = str(ds["cast"].attrs.get("flag_meanings", "")).split() if "cast" in ds.variables else []
    labels = [meanings[int(i)] if 0 <= int(i) < len(meanings) else f"cast{int(i)}" for i in ds["cast"].values] \
        if meanings else (id_values(ds["profile_id"]) if "profile_id" in ds.variables else
                          [f"cast{i}" for i in range(rows.size)])
    axis = "pressure_dbar" if (ds.attrs.get("profile_axis", "pressure") == "pressure"
                               and "pressure_dbar" in ds.variables) else Z_NAME
    zall = np.asarray(ds[axis].values, float)
    levels = np.unique(zall[np.isfinite(zall)])
    starts = np.concatenate([[0], np.cumsum(rows)[:-1]])
    out = xr.Dataset(coords={"cast": ("cast", np.array(labels, dtype=object), {"flag_meanings": " ".join(labels)}),
                             axis: (axis, levels, dict(ds[axis].attrs))})
    for name, v in ds.variables.items():
        if v.dims != ("obs",) or name == axis:
            continue
        arr = np.full((rows.size, levels.size), np.nan if v.dtype.kind == "f" else 0, dtype=v.dtype
                      if v.dtype.kind in "fiu" else float)
        for i, (s, r) in enumerate(zip(starts, rows, strict=True)):
            k = np.searchsorted(levels, zall[s:s + r])
            arr[i, k] = np.asarray(v.values)[s:s + r]
        out[str(name)] = (("cast", axis), arr, dict(v.attrs))
    for name in ("time", "lat", "lon"):
        if name in ds.variables and ds[name].dims == ("profile",):
            out = out.assign_coords({name: ("cast", ds[name].values, dict(ds[name].attrs))})
    for name in ("cast_position_source", "position_uncertainty_m"):  # where each cast is placed, and how well
        if name in ds.variables and ds[name].dims == ("profile",):
            out[name] = ("cast", ds[name].values, dict(ds[name].attrs))
    out.attrs = dict(ds.attrs)
    return out
