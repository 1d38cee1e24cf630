"""Writers used by every stage so products are uniformly self-describing.

* :func:`write_parquet` stores per-column ``units``/``standard_name``/``long_name`` as Arrow field
  metadata and table-level metadata (JSON) under the ``hadal`` key, readable by pandas, polars and duckdb.
* :func:`write_netcdf` writes an ``xarray.Dataset`` with CF-1.8 / ACDD-1.3 global attributes.
"""

from __future__ import annotations

import datetime as _dt
import json
from collections.abc import Mapping
from pathlib import Path
from typing import Any

import pandas as pd
import pyarrow as pa
import pyarrow.parquet as pq
import xarray as xr

from hadal import __version__


def write_parquet(
    df: pd.DataFrame,
    path: str | Path,
    fields: Mapping[str, Mapping[str, str]] | None = None,
    metadata: Mapping[str, Any] | None = None,
) -> Path:
    """Write ``df`` to Parquet with column attributes (``fields[col] = {units, standard_name, long_name}``)
    as Arrow field metadata and ``metadata`` as JSON under the table key ``hadal``."""
    path = Path(path)
    table = pa.Table.from_pandas(df, preserve_index=False)
    fields = fields or {}
    new_fields = []
    for f in table.schema:
        meta = {k: str(v) for k, v in (fields.get(f.name) or {}).items()}
        new_fields.append(f.with_metadata(meta) if meta else f)
    schema_meta = dict(table.schema.metadata or {})
    schema_meta[b"hadal"] = json.dumps(dict(metadata or {}), default=str).encode()
    table = table.cast(pa.schema(new_fields, metadata=schema_meta))
    pq.write_table(table, path, compression="zstd")
    return path


def read_parquet_metadata(path: str | Path) -> tuple[dict[str, Any], dict[str, dict[str, str]]]:
    """Return (table metadata, per-column field metadata) written by :func:`write_parquet`."""
    schema = pq.read_schema(path)
    table_meta = json.loads((schema.metadata or {}).get(b"hadal", b"{}"))
    cols = {f.name: {k.decode(): v.decode() for k, v in (f.metadata or {}).items()} for f in schema}
    return table_meta, cols


def write_netcdf(ds: xr.Dataset, path: str | Path, *, title: str, summary: str, **attrs: Any) -> Path:
    """Write ``ds`` to NetCDF-4 with CF/ACDD global attributes filled in (caller's ``attrs`` win)."""
    path = Path(path)
    now = _dt.datetime.now(_dt.UTC).isoformat(timespec="seconds")
    glob = {
        "Conventions": "CF-1.8, ACDD-1.3",
        "title": title,
        "summary": summary,
        "source": f"hadal {__version__}",
        "date_created": now,
        "history": f"{now} created by hadal {__version__}",
        **{k: v for k, v in ds.attrs.items()},
        **attrs,
    }
    out = ds.copy()
    out.attrs = {k: (json.dumps(v) if isinstance(v, (dict, list)) else v) for k, v in glob.items() if v is not None}
    out.to_netcdf(path, engine="h5netcdf")
    return path
