"""Product writers: CF/ACDD NetCDF and self-describing Parquet (``check_compliance`` in ``.compliance``)."""

from hadal.products.io import (
    dive_attributes,
    prepare_dataset,
    read_parquet_metadata,
    write_netcdf,
    write_parquet,
)
from hadal.products.metadata import dive_context, missing_acdd_fields

__all__ = ["dive_attributes", "dive_context", "missing_acdd_fields", "prepare_dataset", "read_parquet_metadata",
           "write_netcdf", "write_parquet"]
