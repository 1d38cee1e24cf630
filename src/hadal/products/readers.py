"""Readers of hadal's own products, shared by the stages that consume them (stages never import each other)."""

from __future__ import annotations

from typing import TYPE_CHECKING

from hadal.errors import InputError

if TYPE_CHECKING:
    import xarray as xr

    from hadal.store import ProductVersion


def open_dtm(pv: ProductVersion) -> xr.Dataset:
    """Load ``dtm.nc`` fully into memory with a clear error on unreadable files.

    Works for DTMs from multibeam soundings and from prior grids alike (``attrs['dtm_source']``); only
    ``depth_m(y, x)`` is required - a prior-grid DTM has no ``count``/``uncertainty_m`` layers.
    """
    import xarray as xr

    from hadal.confine import check_hdf5_self_contained

    path = pv.file("dtm.nc")
    check_hdf5_self_contained(path)
    try:
        with xr.open_dataset(path, engine="h5netcdf") as ds:
            ds = ds.load()
    except (OSError, ValueError) as exc:
        raise InputError(f"{path}: cannot read the DTM ({str(exc).splitlines()[0] if str(exc) else type(exc).__name__})") from None
    if "depth_m" not in ds or set(ds["depth_m"].dims) != {"y", "x"}:
        raise InputError(f"{path}: not a DTM (no depth_m(y, x); have {', '.join(map(str, ds.data_vars))})")
    # layers stored as float32 (their declared precision, hadal.registry.storage_dtype) are computed on
    # in float64, as they were before storage: squared depth differences of ~11 km in float32 lose the centimetres
    for name, var in ds.data_vars.items():
        if var.dtype == "float32":
            ds[name] = var.astype("float64")
    return ds
