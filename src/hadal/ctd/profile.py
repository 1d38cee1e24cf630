"""Pressure- or depth-binned vertical profiles of a dive (descent and ascent casts) — the ``profile`` product.

Sort-and-reduce binning (as NOAA bathygrid grids soundings): each sample's bin index is
``floor(z / bin_size)``, and per-bin sums/counts come from ``np.bincount`` — O(n), NaN-aware per variable.
``z`` is the pressure (``axis="pressure"``, dbar, coordinate ``pressure_dbar``) or the hydrostatic depth
(``axis="depth"``, m, coordinate ``depth_m``; SeaSoft BinAvg's "bin type: depth"); the other one is then a
binned mean like every other variable (``depth_m`` on the pressure axis, ``pressure_dbar`` on the depth axis).
The paper's Fig. 8 (conductivity, temperature, salinity, density and gravity of the whole water column) is
this product plotted against pressure.

``binning="seabird"`` bins as SBEDataProcessing's BinAvg does instead (:func:`hadal.ctd.bin_average`): bins
centred on multiples of the bin size, the record split at its deepest scan (not by ``phase``), the
turn-around bin in the descent cast. With ``latitude_deg`` the profile also gets N² per cast
(:func:`hadal.ctd.teos10.n_squared_profile`, ``gsw.Nsquared`` on the binned SA and CT).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Literal

import numpy as np
import pandas as pd
import xarray as xr
from numpy.typing import ArrayLike

from hadal.errors import InputError

#: Variables of ``ctd.parquet`` averaged into the profile (those present are used).
PROFILE_VARIABLES: tuple[str, ...] = (
    "temperature_its90_degc", "conductivity_s_m", "practical_salinity", "density_kg_m3", "gravity_m_s2",
    "sound_speed_m_s", "depth_m", "depth_fofonoff_millard_m", "depth_teos10_m",
    "absolute_salinity_g_kg", "conservative_temperature_degc", "potential_temperature_degc", "sigma0_kg_m3",
)
#: N² of each binned cast (computed from the binned SA and CT when a latitude is given)
N_SQUARED = "buoyancy_frequency_squared_s2"
CASTS: tuple[str, ...] = ("descent", "ascent")

Axis = Literal["pressure", "depth"]
#: the binning column (and coordinate name) of each axis, its unit, and the column averaged instead of it
AXES: dict[str, tuple[str, str, str]] = {"pressure": ("pressure_dbar", "dbar", "depth_m"),
                                         "depth": ("depth_m", "m", "pressure_dbar")}
#: CF attributes of the vertical coordinate (bin centres) of each axis
AXIS_ATTRS: dict[str, dict[str, str]] = {
    "pressure": {"standard_name": "sea_water_pressure", "units": "dbar", "positive": "down", "axis": "Z",
                 "long_name": "sea water pressure (bin centre)"},
    "depth": {"standard_name": "depth", "units": "m", "positive": "down", "axis": "Z",
              "long_name": "depth below the sea surface (bin centre; hydrostatic depth, Eqs. 11-12)"},
}


def profile_variables(axis: Axis = "pressure") -> tuple[str, ...]:
    """The columns averaged into a profile on ``axis``: :data:`PROFILE_VARIABLES`, on the depth axis with the
    mean pressure in place of the mean (hydrostatic) depth, which is the coordinate there."""
    if axis == "pressure":
        return PROFILE_VARIABLES
    return tuple("pressure_dbar" if v == "depth_m" else v for v in PROFILE_VARIABLES)


def _axis(axis: str) -> tuple[str, str, str]:
    if axis not in AXES:
        raise InputError(f"profile: axis must be pressure or depth, got {axis!r}")
    return AXES[axis]


def bin_edges(pressure_dbar: ArrayLike, bin_dbar: float, *, unit: str = "dbar") -> np.ndarray:
    """Bin edges, multiples of ``bin_dbar``, covering 0 (or the lowest value, if negative) to the highest finite
    value (pressure in dbar, or depth in m with ``unit="m"``: only the messages differ)."""
    if not bin_dbar > 0:
        raise InputError(f"profile bin size must be > 0 {unit}, got {bin_dbar}")
    p = np.asarray(pressure_dbar, dtype=np.float64)
    p = p[np.isfinite(p)]
    if p.size == 0:
        raise InputError(f"profile: no finite {'pressure' if unit == 'dbar' else 'depth'} to bin")
    k0 = min(0, int(np.floor(p.min() / bin_dbar)))
    k1 = int(np.floor(p.max() / bin_dbar)) + 1
    return np.arange(k0, k1 + 1) * float(bin_dbar)


def bin_by_pressure(pressure_dbar: ArrayLike, values: Mapping[str, ArrayLike], edges: np.ndarray
                    ) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Mean of each variable in pressure bins ``[edges[k], edges[k+1])`` ignoring NaNs per variable.

    Returns ``(means, count)``: ``means[name]`` has ``len(edges) - 1`` entries (NaN in empty bins), ``count``
    the number of samples with a finite pressure in each bin. Datetime variables are averaged as time.
    """
    p = np.asarray(pressure_dbar, dtype=np.float64)
    nb = len(edges) - 1
    ok = np.isfinite(p)
    k = np.searchsorted(edges, p[ok], side="right") - 1
    inside = (k >= 0) & (k < nb)
    k = k[inside]
    count = np.bincount(k, minlength=nb)
    means: dict[str, np.ndarray] = {}
    for name, v in values.items():
        arr = np.asarray(v)
        is_time = np.issubdtype(arr.dtype, np.datetime64)
        x = arr.astype("datetime64[ns]").astype(np.int64).astype(np.float64) if is_time else arr.astype(np.float64)
        if is_time:
            x[np.asarray(pd.isna(arr))] = np.nan
        x = x[ok][inside]
        fin = np.isfinite(x)
        s = np.bincount(k[fin], weights=x[fin], minlength=nb)
        n = np.bincount(k[fin], minlength=nb)
        with np.errstate(invalid="ignore", divide="ignore"):
            m = np.where(n > 0, s / np.maximum(n, 1), np.nan)
        if is_time:
            m = pd.to_datetime(np.where(np.isfinite(m), m, np.nan), utc=True).tz_localize(None).to_numpy()
        means[name] = m
    return means, count


def _numpy(s: pd.Series) -> np.ndarray:
    """A column as a NumPy array; timezone-aware times become naive UTC datetime64[ns]."""
    if isinstance(s.dtype, pd.DatetimeTZDtype):
        return s.dt.tz_convert("UTC").dt.tz_localize(None).to_numpy("datetime64[ns]")
    return s.to_numpy()


def make_profile(df: pd.DataFrame, bin_dbar: float = 10.0, *, casts: Sequence[str] = CASTS,
                 phase_column: str = "phase", pressure_column: str = "pressure_dbar",
                 binning: Literal["floor", "seabird"] = "floor", latitude_deg: float | None = None,
                 axis: Axis = "pressure") -> xr.Dataset:
    """Bin a ``ctd`` table by pressure (or depth) separately for each cast (``phase`` = descent / ascent).

    Returns a Dataset with dims ``(cast, pressure_dbar)``: ``pressure_dbar`` = bin centres (bin ``k`` covers
    ``[k, k+1) * bin_dbar``), the mean of every :data:`PROFILE_VARIABLES` column present and ``count``
    (samples per bin). Bins that no sample of either cast reaches are dropped from the bottom. (The
    dimension is not called ``pressure``: CF checkers take a ``pressure`` axis to be ``air_pressure``.)
    ``binning="seabird"``: SeaSoft BinAvg bins (centre ``k * bin_dbar``, ``k >= 1``), see the module docstring.

    ``axis="depth"``: the same on the ``depth_m`` column (the hydrostatic depth), ``bin_dbar`` then being the bin
    size in metres; dims ``(cast, depth_m)``, ``depth_m`` the bin centres (CF ``depth``, positive down, axis Z)
    and ``pressure_dbar(cast, depth_m)`` the mean pressure of each bin (N² is computed on it).
    """
    zcol, unit, _ = _axis(axis)
    if axis == "pressure":
        zcol = pressure_column
    if binning == "seabird":
        return _seabird_profile(df, bin_dbar, casts, zcol, latitude_deg, axis)
    if zcol not in df or phase_column not in df:
        raise InputError(f"profile: table lacks {zcol!r} or {phase_column!r}")
    z = df[zcol].to_numpy(np.float64)
    edges = bin_edges(z, bin_dbar, unit=unit)
    names = [c for c in profile_variables(axis) if c in df.columns]
    cols = {n: _numpy(df[n]) for n in names}
    per_cast = []
    for cast in casts:
        sel = (df[phase_column] == cast).to_numpy()
        means, count = bin_by_pressure(z[sel], {n: v[sel] for n, v in cols.items()}, edges)
        per_cast.append((means, count))
    counts = np.stack([c for _, c in per_cast])
    used = np.flatnonzero(counts.sum(axis=0) > 0)
    last = used[-1] + 1 if used.size else 1
    centres = 0.5 * (edges[:-1] + edges[1:])[:last]
    coord = AXES[axis][0]
    dims = ("cast", coord)
    ds = xr.Dataset(coords={"cast": np.array(list(casts), dtype=object), coord: centres})
    for n in names:
        ds[n] = (dims, np.stack([m[n][:last] for m, _ in per_cast]))
    ds["count"] = (dims, counts[:, :last].astype(np.int32))
    ds[coord].attrs.update({**AXIS_ATTRS[axis], "comment": f"bin k covers [k, k+1) x {float(bin_dbar):g} {unit}"})
    ds["cast"].attrs.update({"long_name": "cast (dive phase)", "comment": "descent or ascent"})
    _finish(ds, axis, bin_dbar, latitude_deg)
    return ds


def _finish(ds: xr.Dataset, axis: str, bin_size: float, latitude_deg: float | None) -> None:
    """Attributes common to both binnings (count, bin size, axis) and N²."""
    what = "pressure" if axis == "pressure" else "depth"
    ds["count"].attrs.update({"long_name": f"number of CTD samples in the {what} bin", "units": "1"})
    if axis == "pressure":
        ds.attrs["bin_size_dbar"] = float(bin_size)
    else:
        ds.attrs["bin_size_m"] = float(bin_size)
        ds["count"].attrs["standard_name"] = "depth number_of_observations"
        if "pressure_dbar" in ds:
            ds["pressure_dbar"].attrs.update({"standard_name": "sea_water_pressure", "units": "dbar",
                                              "long_name": "mean sea water pressure of the depth bin"})
    ds.attrs["profile_axis"] = axis
    _add_n_squared(ds, latitude_deg)


def _add_n_squared(ds: xr.Dataset, latitude_deg: float | None) -> None:
    """N² per cast from the binned SA and CT (when both and a latitude are there)."""
    if latitude_deg is None or "absolute_salinity_g_kg" not in ds or "conservative_temperature_degc" not in ds:
        return
    from hadal.ctd.teos10 import n_squared_profile

    if "pressure_dbar" not in ds:
        return
    sa = ds["absolute_salinity_g_kg"]
    # the pressure of each level: the bin centres (pressure axis) or each cast's mean bin pressure (depth axis)
    pr = np.broadcast_to(ds["pressure_dbar"].values, sa.shape)
    n2 = np.stack([n_squared_profile(pr[k], sa.values[k], ds["conservative_temperature_degc"].values[k],
                                     latitude_deg) for k in range(ds.sizes["cast"])])
    ds[N_SQUARED] = (sa.dims, n2)


def _seabird_profile(df: pd.DataFrame, bin_dbar: float, casts: Sequence[str], pressure_column: str,
                     latitude_deg: float | None, axis: Axis = "pressure") -> xr.Dataset:
    """SeaSoft BinAvg binning of every :func:`profile_variables` column onto a (cast, pressure_dbar) grid (or
    (cast, depth_m): BinAvg's depth bin type, on the column ``pressure_column``, then the depth)."""
    from hadal.ctd.bin_average import bin_average

    unit = AXES[axis][1]
    if pressure_column not in df:
        raise InputError(f"profile: table lacks {pressure_column!r}")
    if not bin_dbar > 0:
        raise InputError(f"profile bin size must be > 0 {unit}, got {bin_dbar}")
    names = [c for c in profile_variables(axis) if c in df.columns]
    cols = {}
    for n in names:
        v = _numpy(df[n])
        if np.issubdtype(v.dtype, np.datetime64):
            x = v.astype("datetime64[ns]").astype(np.int64).astype(np.float64)
            x[np.asarray(pd.isna(v))] = np.nan
            cols[n] = x
        else:
            cols[n] = v.astype(np.float64)
    r = bin_average(df[pressure_column].to_numpy(np.float64), cols, bin_dbar)
    k = np.rint(r.centre / bin_dbar).astype(np.int64)
    kmax = int(k.max())
    centres = np.arange(1, kmax + 1) * float(bin_dbar)
    ci = {c: i for i, c in enumerate(casts)}
    counts = np.zeros((len(casts), kmax), dtype=np.int32)
    data = {n: np.full((len(casts), kmax), np.nan) for n in names}
    for j in range(len(k)):
        row = ci.get(r.cast[j])
        if row is None:
            continue
        counts[row, k[j] - 1] = r.nbin[j]
        for n in names:
            data[n][row, k[j] - 1] = r.means[n][j]
    coord = AXES[axis][0]
    dims = ("cast", coord)
    ds = xr.Dataset(coords={"cast": np.array(list(casts), dtype=object), coord: centres})
    for n in names:
        vals = data[n]
        if np.issubdtype(_numpy(df[n]).dtype, np.datetime64):
            vals = pd.to_datetime(vals.ravel(), utc=True).tz_localize(None).to_numpy().reshape(vals.shape)
        ds[n] = (dims, vals)
    ds["count"] = (dims, counts)
    ds[coord].attrs.update({**AXIS_ATTRS[axis],
                            "comment": f"SeaSoft BinAvg bins: bin k covers [k - 1/2, k + 1/2) x "
                                       f"{float(bin_dbar):g} {unit} (descent; ascent (k - 1/2, k + 1/2]); "
                                       "the turn-around bin is in the descent cast"})
    ds["cast"].attrs.update({"long_name": "cast (split at the deepest scan)", "comment": "descent or ascent"})
    ds.attrs["binning"] = "seabird BinAvg"
    _finish(ds, axis, bin_dbar, latitude_deg)
    return ds


def n_squared_per_sample(df: pd.DataFrame, ds: xr.Dataset, *, phase_column: str = "phase",
                         pressure_column: str = "pressure_dbar") -> np.ndarray:
    """Each sample's N²: that of its binned cast in ``ds`` at its pressure (bottom samples: the descent's), NaN
    where the profile has none (no latitude given, or outside the cast's levels)."""
    from hadal.ctd.teos10 import n_squared_at

    out = np.full(len(df), np.nan)
    if N_SQUARED not in ds or phase_column not in df or pressure_column not in df or "pressure_dbar" not in ds:
        return out
    pr = df[pressure_column].to_numpy(np.float64)
    phase = df[phase_column].to_numpy(dtype=object)
    # the levels' pressures: the bin centres, or on the depth axis each cast's mean bin pressures
    levels = np.broadcast_to(ds["pressure_dbar"].values, ds[N_SQUARED].shape)
    for k, cast in enumerate(ds["cast"].values):
        sel = (phase == cast) | ((phase == "bottom") & (cast == "descent"))
        if sel.any():
            out[sel] = n_squared_at(pr[sel], levels[k], ds[N_SQUARED].values[k])
    return out


# ------------------------------------------------------------------------------ casts SeaSoft has already binned
#: SeaSoft BinAvg bin types that bin by a vertical coordinate -> the profile axis (``scans``/``seconds`` bins are
#: time averages of a time series: such a record is binned like any other)
SEASOFT_VERTICAL_BINS: dict[str, Axis] = {"decibars": "pressure", "meters": "depth"}


def source_bins(cast_meta: Mapping | None) -> dict | None:
    """The vertical bins of a cast that SeaSoft's BinAvg already averaged, from its header (the ``cast`` metadata of
    :func:`hadal.ingest.build.cast_metadata`): the ``# binavg_bintype`` and ``# binavg_binsize`` processing lines,
    else the ``# interval = decibars: 1`` (or ``meters``) line. Returns ``{"axis", "bin_size", "units",
    "bintype", "source"}`` or ``None`` (not binned, or binned by scans/time, or an unreadable bin size)."""
    if not cast_meta:
        return None
    proc = {str(k): str(v).strip() for k, v in (cast_meta.get("processing") or []) if k is not None}
    bintype, size, source = proc.get("binavg_bintype", "").split(",")[0].strip().lower(), proc.get("binavg_binsize"), \
        "binavg_bintype / binavg_binsize"
    if not bintype or size is None:
        iv = cast_meta.get("interval") or {}
        bintype, size, source = str(iv.get("kind") or "").lower(), iv.get("value"), "interval"
    try:
        bin_size = float(str(size).split()[0]) if size is not None else float("nan")
    except ValueError:
        return None
    axis = SEASOFT_VERTICAL_BINS.get(bintype)
    if axis is None or not (np.isfinite(bin_size) and bin_size > 0):
        return None
    return {"axis": axis, "bin_size": bin_size, "units": AXES[axis][1], "bintype": bintype,
            "source": f"Sea-Bird header ({source}): {bintype}, {bin_size:g} {AXES[axis][1]}"}


def prebinned_phases(pressure_dbar: ArrayLike) -> np.ndarray:
    """Casts of a SeaSoft-binned record in file order, as BinAvg wrote them: the rows up to and including the
    deepest are the descent, those after it the ascent (BinAvg puts the turn-around bin in the downcast); a record
    whose first row is its deepest is one ascent. Only the casts the file holds appear."""
    p = np.asarray(pressure_dbar, dtype=np.float64)
    out = np.full(p.size, "descent", dtype=object)
    fin = np.flatnonzero(np.isfinite(p))
    if fin.size < 2:
        return out
    deep = int(fin[np.argmax(p[fin])])
    if deep == fin[0]:
        out[:] = "ascent"
    else:
        out[deep + 1:] = "ascent"
    return out


def prebinned_profile(df: pd.DataFrame, bins: Mapping, *, phase_column: str = "phase",
                      latitude_deg: float | None = None, bin_column: str | None = None) -> xr.Dataset:
    """The ``profile`` of a cast SeaSoft's BinAvg already binned (``bins`` from :func:`source_bins`): its own bins
    kept, not re-binned. Each row of the file is one bin: the coordinate is the bin centre ``k x bin_size`` with
    ``k = round(z / bin_size)`` (``z``: the row's pressure, or hydrostatic depth for ``meters`` bins; BinAvg writes
    the bin's mean, within half a bin of the centre), each variable is the row's value (the derived ones computed
    on it), ``count`` the rows in the bin (1; two only if the file repeats a bin). Only the casts the file holds
    (descent, ascent: ``phase``) appear, never an empty one; dims ``(cast, pressure_dbar)`` or ``(cast, depth_m)``
    like :func:`make_profile`. ``bin_column``: the column whose value gives each row's bin (default the axis
    column; for ``meters`` bins the depth SeaSoft binned by, e.g. the Fofonoff-Millard depth of ``depSM``).
    """
    axis: Axis = bins["axis"]
    size = float(bins["bin_size"])
    coord, unit, _ = _axis(axis)
    zcol = bin_column or coord
    if coord not in df or zcol not in df or phase_column not in df:
        raise InputError(f"profile: table lacks {zcol!r} or {phase_column!r}")
    z = df[zcol].to_numpy(np.float64)
    fin = np.isfinite(z)
    if not fin.any():
        raise InputError(f"profile: no finite {'pressure' if axis == 'pressure' else 'depth'} to bin")
    k = np.rint(z[fin] / size).astype(np.int64)
    used = np.unique(k)
    edges = np.arange(int(used.min()) - 0.5, int(used.max()) + 1.0) * size
    names = [c for c in profile_variables(axis) if c in df.columns]
    cols = {n: _numpy(df[n]) for n in names}
    phase = df[phase_column].astype(str).to_numpy()
    casts = [c for c in CASTS if (phase == c).any()]
    per_cast = []
    for cast in casts:
        sel = phase == cast
        per_cast.append(bin_by_pressure(z[sel], {n: v[sel] for n, v in cols.items()}, edges))
    keep = used - int(used.min())
    ds = xr.Dataset(coords={"cast": np.array(casts, dtype=object), coord: used.astype(np.float64) * size})
    dims = ("cast", coord)
    for n in names:
        ds[n] = (dims, np.stack([m[n][keep] for m, _ in per_cast]))
    ds["count"] = (dims, np.stack([c[keep] for _, c in per_cast]).astype(np.int32))
    ds[coord].attrs.update({**AXIS_ATTRS[axis], "comment": (
        f"the source file's own bins ({bins['source']}): bin k centred on k x {size:g} {unit}; the cast was "
        "binned by SeaSoft BinAvg and is not re-binned: each value is the file's row of that bin")})
    ds["cast"].attrs.update({"long_name": "cast (file order: up to the deepest bin, then after it)",
                             "comment": "descent or ascent; only the casts the file holds"})
    ds.attrs["binning"] = "source file (SeaSoft BinAvg)"
    ds.attrs["seasoft_binavg_bintype"] = str(bins["bintype"])
    ds.attrs["seasoft_binavg_binsize"] = size
    ds.attrs["seasoft_bins_source"] = str(bins["source"])
    _finish(ds, axis, size, latitude_deg)
    ds["count"].attrs["long_name"] = "number of rows of the SeaSoft-binned file in the bin"
    return ds
