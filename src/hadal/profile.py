"""Pressure-binned vertical profiles of a dive (descent and ascent casts) — the ``profile`` product.

Sort-and-reduce binning (as NOAA bathygrid grids soundings): each sample's bin index is
``floor(p / bin_dbar)``, and per-bin sums/counts come from ``np.bincount`` — O(n), NaN-aware per variable.
The paper's Fig. 8 (conductivity, temperature, salinity, density and gravity of the whole water column) is
this product plotted against pressure.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence

import numpy as np
import pandas as pd
import xarray as xr
from numpy.typing import ArrayLike

from hadal.errors import InputError

#: Variables of ``ctd.parquet`` averaged into the profile (those present are used).
PROFILE_VARIABLES: tuple[str, ...] = (
    "temperature_its90_degc", "conductivity_s_m", "practical_salinity", "density_kg_m3", "gravity_m_s2",
    "sound_speed_m_s", "depth_m", "depth_fofonoff_millard_m", "depth_teos10_m",
)
CASTS: tuple[str, ...] = ("descent", "ascent")


def bin_edges(pressure_dbar: ArrayLike, bin_dbar: float) -> np.ndarray:
    """Bin edges (dbar) multiples of ``bin_dbar`` covering 0 (or the lowest pressure, if negative) to the
    highest finite pressure."""
    if not bin_dbar > 0:
        raise InputError(f"profile bin size must be > 0 dbar, got {bin_dbar}")
    p = np.asarray(pressure_dbar, dtype=np.float64)
    p = p[np.isfinite(p)]
    if p.size == 0:
        raise InputError("profile: no finite pressure to bin")
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
                 phase_column: str = "phase", pressure_column: str = "pressure_dbar") -> xr.Dataset:
    """Bin a ``ctd`` table by pressure separately for each cast (``phase`` = descent / ascent).

    Returns a Dataset with dims ``(cast, pressure_dbar)``: ``pressure_dbar`` = bin centres (bin ``k`` covers
    ``[k, k+1) * bin_dbar``), the mean of every :data:`PROFILE_VARIABLES` column present and ``count``
    (samples per bin). Bins that no sample of either cast reaches are dropped from the bottom. (The
    dimension is not called ``pressure``: CF checkers take a ``pressure`` axis to be ``air_pressure``.)
    """
    if pressure_column not in df or phase_column not in df:
        raise InputError(f"profile: table lacks {pressure_column!r} or {phase_column!r}")
    edges = bin_edges(df[pressure_column].to_numpy(), bin_dbar)
    names = [c for c in PROFILE_VARIABLES if c in df.columns]
    cols = {n: _numpy(df[n]) for n in names}
    per_cast = []
    for cast in casts:
        sel = (df[phase_column] == cast).to_numpy()
        means, count = bin_by_pressure(df[pressure_column].to_numpy(np.float64)[sel],
                                       {n: v[sel] for n, v in cols.items()}, edges)
        per_cast.append((means, count))
    counts = np.stack([c for _, c in per_cast])
    used = np.flatnonzero(counts.sum(axis=0) > 0)
    last = used[-1] + 1 if used.size else 1
    centres = 0.5 * (edges[:-1] + edges[1:])[:last]
    dims = ("cast", "pressure_dbar")
    ds = xr.Dataset(coords={"cast": np.array(list(casts), dtype=object), "pressure_dbar": centres})
    for n in names:
        ds[n] = (dims, np.stack([m[n][:last] for m, _ in per_cast]))
    ds["count"] = (dims, counts[:, :last].astype(np.int32))
    ds["pressure_dbar"].attrs.update({"standard_name": "sea_water_pressure", "units": "dbar", "positive": "down",
                                      "axis": "Z", "long_name": "sea water pressure (bin centre)",
                                      "comment": f"bin k covers [k, k+1) x {float(bin_dbar):g} dbar"})
    ds["cast"].attrs.update({"long_name": "cast (dive phase)", "comment": "descent or ascent"})
    ds["count"].attrs.update({"long_name": "number of CTD samples in the pressure bin", "units": "1"})
    ds.attrs["bin_size_dbar"] = float(bin_dbar)
    return ds
