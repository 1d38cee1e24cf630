"""Titles, summaries and variable attributes of the binned-cast NetCDF products: ``profile`` (the dive's descent
and ascent, :mod:`hadal.stages.profile`) and ``cast_profiles`` (external Sea-Bird casts, :mod:`hadal.stages.derive`).

Shared by both stages (stages never import each other). The binning itself is :func:`hadal.ctd.derive.bin_casts`,
run once, by ``derive``, which keeps the dive's binned casts in its ``ctd`` version (:data:`BINNED_CASTS`,
:func:`write_binned_casts`) for the ``profile`` stage to place (:func:`read_binned_casts`); the CF-1.8 ragged layout
:mod:`hadal.products.dsg`.
"""

from __future__ import annotations

from typing import Any

from hadal.ctd.derive import profile_axis_text
from hadal.settings.derive import DeriveParams as Params


def source_binned(meta: dict[str, Any]) -> dict[str, Any] | None:
    """The profile's axis record when the cast kept SeaSoft's own bins (``binning: source``), else ``None``."""
    ax = meta.get("profile_axis") or {}
    return ax if ax.get("binning") == "source" else None


def bins_text(p: Params, meta: dict[str, Any]) -> str:
    """The bins of a profile in words: the configured ones, or a SeaSoft-binned cast's own."""
    ax = source_binned(meta)
    if ax is None:
        return f"Means in {profile_axis_text(p)} bins"
    return (f"The source file's own {ax['bin_size']:g} {ax['units']} {ax['axis']} bins (binned by SeaSoft BinAvg, "
            f"not re-binned; {ax['source_bins']})")


def title_axis(p: Params, meta: dict[str, Any]) -> str:
    ax = source_binned(meta)
    return axis_title(p) if ax is None else ("Depth-binned" if ax["axis"] == "depth" else "Pressure-binned")


def is_depth_axis(p: Params, meta: dict[str, Any]) -> bool:
    ax = source_binned(meta)
    return p.profile_axis == "depth" if ax is None else ax["axis"] == "depth"


def profile_summary(p: Params, profile: Any, is_prof: bool, meta: dict[str, Any] | None = None) -> str:
    """The ``summary`` attribute of ``profile.nc``."""
    meta = meta or {}
    casts = " and ".join(str(c) for c in profile["cast"].values) if source_binned(meta) else "descent and ascent"
    return (f"{bins_text(p, meta)} of the dive's CTD samples, separately for "
            f"the {casts} casts: temperature, conductivity, PSS-78 salinity, EOS-80 density, "
            "gravity, Chen-Millero sound speed, and "
            + ("hydrostatic / Fofonoff-Millard / TEOS-10 depths." if not is_depth_axis(p, meta) else
               "pressure and Fofonoff-Millard / TEOS-10 depths; the depth axis is the hydrostatic depth "
               "(depth_m, Eqs. 11-12).")
            + ((" The cast has no time channel (pressure-binned): its time is the header start time."
                if "time" in profile.variables else
                " The cast has no time channel (pressure-binned) and no header start time: no times.")
               if is_prof else ""))


def cast_positions_summary(profile: Any) -> list[dict[str, Any]]:
    """Per cast: its time, position, position source and 1-sigma radial uncertainty (``profile`` manifest)."""
    import numpy as np
    import pandas as pd

    from hadal.products.dsg import POSITION_SOURCES

    out = []
    for i, cast in enumerate(profile["cast"].values):
        src = int(profile["cast_position_source"].values[i])
        unc = float(profile["position_uncertainty_m"].values[i])
        t = profile["time"].values[i] if "time" in profile.variables else None
        out.append({"cast": str(cast), "time": None if t is None or pd.isna(t) else pd.Timestamp(t).isoformat() + "Z",
                    "latitude_deg": round(float(profile["lat"].values[i]), 7),
                    "longitude_deg": round(float(profile["lon"].values[i]), 7),
                    "position_source": POSITION_SOURCES[src] if src >= 0 else None,
                    "position_uncertainty_m": round(unc, 2) if np.isfinite(unc) else None})
    return out


def axis_title(p: Params) -> str:
    return "Depth-binned" if p.profile_axis == "depth" else "Pressure-binned"


#: long_name of each binned variable of ``profile`` (the bins' means); units, standard_name and positive are the
#: variable registry's (``schemas/variables.yaml``, :func:`profile_var_attrs`)
PROFILE_LONG_NAMES: dict[str, str] = {
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


def profile_var_attrs(name: str) -> dict[str, str]:
    """Attributes of a binned ``profile`` variable: the registry's standard_name/units/positive, the bin mean's
    long_name (:data:`PROFILE_LONG_NAMES`)."""
    from hadal.registry import variable_attrs

    reg = variable_attrs(name, where="profile")
    out: dict[str, str] = {k: str(reg[k]) for k in ("standard_name", "units", "positive") if k in reg}
    out["long_name"] = PROFILE_LONG_NAMES[name]
    return out


def profile_attrs(ds: Any, meta: dict[str, Any]) -> None:
    import numpy as np

    from hadal.ctd.profile import N_SQUARED

    axis = "depth_m" if "depth_m" in ds.dims else "pressure_dbar"
    for name in PROFILE_LONG_NAMES:
        if name in ds and name not in ds.dims:
            ds[name].attrs.update(profile_var_attrs(name))
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
    # the profile's nominal position (the latitude used for gravity/depth, the launch longitude) unless placed
    if "lat" not in ds.variables:
        ds.coords["lat"] = np.float64(meta["latitude_deg"])
        ds.coords["lon"] = np.float64(meta["longitude_deg"])


#: the dive's binned casts inside its ``ctd`` version (derive's one binning, before placement): the ``profile``
#: stage's input. xarray's own NetCDF encoding, read back exactly; an internal hand-over, not a user product (in a
#: sub-directory: the product files, checked for CF/ACDD/IOOS, are the version's top-level ones)
BINNED_CASTS = "internal/binned_casts.nc"


def write_binned_casts(profile: Any, version_dir: Any) -> Any:
    """Write the binned casts (:func:`hadal.ctd.derive.bin_casts`) into a ``ctd`` version being published."""
    from pathlib import Path

    from hadal.products.io import write_dataset_exact

    return write_dataset_exact(profile, Path(version_dir) / BINNED_CASTS)


def read_binned_casts(ctd_version: Any) -> Any:
    """The binned casts ``derive`` kept in a ``ctd`` version (a ``ProductVersion``), exactly as it binned them; a
    version without them (published before they were kept) is a one-line :class:`hadal.errors.InputError`."""
    from hadal.errors import InputError
    from hadal.products.io import read_dataset_exact

    path = ctd_version.path / BINNED_CASTS
    if not path.is_file():
        raise InputError(f"{ctd_version.path}: this ctd version has no binned casts ({BINNED_CASTS}; published by "
                         "an older hadal): re-run derive (hadal stage derive DIR --downstream)")
    try:
        return read_dataset_exact(path)
    except Exception as exc:  # unreadable upstream file: one-line error, not a traceback
        raise InputError(f"{path}: cannot read the binned casts ({type(exc).__name__}: {exc})") from None
