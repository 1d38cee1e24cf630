"""An underway record (thermosalinograph) as a CF-1.8 trajectory product file: the dataset derive's ``trajectory``
product writes, one file per record (its variables from :func:`hadal.stages.derive.underway_table`)."""

from __future__ import annotations

from typing import Any

import pandas as pd

#: long_name of the trajectory's variables (units and standard_name: the variable registry)
_TRAJECTORY_LONG_NAMES: dict[str, str] = {
    "temperature_its90_degc": "sea water temperature in the ship's seawater line (thermosalinograph, ITS-90)",
    "conductivity_s_m": "sea water conductivity (thermosalinograph)",
    "pressure_dbar": "sea water pressure of the record (its own channel; 0 dbar where it has none)",
    "practical_salinity": "practical salinity (PSS-78)",
    "density_kg_m3": "in situ density (EOS-80)",
    "sound_speed_m_s": "sound speed (Chen-Millero)",
    "absolute_salinity_g_kg": "Absolute Salinity (TEOS-10, gsw.SA_from_SP at the scan's position)",
    "conservative_temperature_degc": "Conservative Temperature (TEOS-10, gsw.CT_from_t)",
    "potential_temperature_degc": "potential temperature, 0 dbar (TEOS-10, gsw.pt0_from_t)",
    "sigma0_kg_m3": "potential density anomaly, 0 dbar (TEOS-10, gsw.sigma0)",
}


def trajectory_dataset(df: pd.DataFrame, record_id: str) -> Any:
    """An underway record as a CF-1.8 Discrete Sampling Geometry trajectory (contiguous ragged array, one
    trajectory, as :func:`hadal.products.navigation.trajectory_dataset`): dimension ``obs`` with ``time``/``lat``/
    ``lon`` coordinates (the file's own per-scan positions), ``trajectory(traj=1)`` with ``cf_role =
    trajectory_id`` and ``row_size``, and per scan the measured and derived variables of :func:`hadal.stages.derive.underway_table`."""
    import numpy as np
    import pandas as pd
    import xarray as xr

    from hadal.products.dsg import char_id
    from hadal.registry import variable_attrs

    obs = np.arange(len(df), dtype="i4")
    t = pd.to_datetime(df["time"], utc=True).dt.tz_convert(None).to_numpy(dtype="datetime64[ns]")
    coords = {
        "time": ("obs", t, {"standard_name": "time", "long_name": "scan time (UTC)", "axis": "T"}),
        "lat": ("obs", df["lat"].to_numpy(float), {"standard_name": "latitude", "units": "degrees_north",
                                                   "axis": "Y", "long_name": "latitude of the scan (NMEA, the "
                                                   "record's own per-scan channel)"}),
        "lon": ("obs", df["lon"].to_numpy(float), {"standard_name": "longitude", "units": "degrees_east",
                                                   "axis": "X", "long_name": "longitude of the scan (NMEA, the "
                                                   "record's own per-scan channel)"}),
        "obs": obs,
    }
    data: dict[str, Any] = {
        "trajectory": char_id([record_id], "traj", {"cf_role": "trajectory_id", "long_name": "underway record id"}),
        "row_size": (("traj",), np.array([len(obs)], dtype="i4"),
                     {"sample_dimension": "obs", "long_name": "number of observations of the trajectory"}),
    }
    for c, long_name in _TRAJECTORY_LONG_NAMES.items():
        if c in df:
            attrs = {k: v for k, v in variable_attrs(c, where="trajectory").items()
                     if k in ("standard_name", "units")}
            data[c] = ("obs", df[c].to_numpy(float), {**attrs, "long_name": long_name})
            if f"{c}_qc" in df:
                data[f"{c}_qc"] = ("obs", df[f"{c}_qc"].to_numpy().astype("i1"), {})
                data[c][2]["ancillary_variables"] = f"{c}_qc"
    ds = xr.Dataset(data, coords=coords)
    for n in ds.data_vars:
        if ds[n].dims == ("obs",):
            ds[n].attrs["coordinates"] = "time lat lon"
    return ds
