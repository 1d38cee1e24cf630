"""Child process of :func:`hadal.grid.readers.read_gsf`: reads one GSF file with libgsf in this process and
writes the soundings to a Parquet file (attrs as JSON beside it), so a crash of the C library on a corrupt file
cannot take the caller down. Usage: ``python -m hadal.grid._gsf_child GSF OUT.parquet INCLUDE_FLAGGED(0|1) [LIMIT_BYTES
[ROW_GROUP]]`` (``LIMIT_BYTES``: the caller's memory budget, held by :class:`hadal.grid.sonar.SoundingBudget` as it
decodes; ``ROW_GROUP``: soundings per Parquet row group, what the caller reads at a time, default 250,000).
Exit 0: written; 2: a one-line :class:`~hadal.errors.HadalError` on stderr (last line)."""

from __future__ import annotations

import json
import sys
from pathlib import Path


def main(argv: list[str]) -> int:
    import pyarrow as pa
    import pyarrow.parquet as pq

    from hadal.errors import HadalError
    from hadal.grid.readers import GSF_COLUMNS, gsf_blocks
    from hadal.grid.sonar import SoundingBudget

    src, out, flagged = argv[0], Path(argv[1]), argv[2] == "1"
    limit = float(argv[3]) if len(argv) > 3 else None
    row_group = max(int(argv[4]) if len(argv) > 4 else 250_000, 1)
    schema = pa.schema([(c, pa.from_numpy_dtype(t)) for c, t in GSF_COLUMNS.items()])
    attrs: dict = {}
    try:
        # counted at the parent's cost (SOUNDING_READ_COST["gsf"], above the child's own "gsf_child"): the caller
        # will hold every sounding written here, so a file it must refuse is refused before it is written out
        budget = SoundingBudget(Path(src), "gsf multibeam file", reader="gsf", limit_bytes=limit)
        # one row group at a time: the child holds a block of soundings, not the file's
        with pq.ParquetWriter(out, schema) as w:
            for block in gsf_blocks(src, include_flagged=flagged, budget=budget, block_points=row_group,
                                    attrs=attrs):
                w.write_table(pa.table(block, schema=schema), row_group_size=max(len(block["ping"]), 1))
    except HadalError as exc:
        print(str(exc), file=sys.stderr)
        return 2
    out.with_suffix(".json").write_text(json.dumps(attrs, default=str), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
