"""Product writers: CF/ACDD NetCDF and self-describing Parquet."""

from hadal.products.io import write_netcdf, write_parquet

__all__ = ["write_netcdf", "write_parquet"]
