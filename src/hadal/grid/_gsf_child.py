"""Child process of :func:`hadal.grid.readers.read_gsf`: reads one GSF file with libgsf in this process and
writes the soundings to a Parquet file (attrs as JSON beside it), so a crash of the C library on a corrupt file
cannot take the caller down. Usage: ``python -m hadal.grid._gsf_child GSF OUT.parquet INCLUDE_FLAGGED(0|1) [LIMIT_BYTES]``
(``LIMIT_BYTES``: the caller's memory budget, held by :class:`hadal.grid.sonar.SoundingBudget` as it decodes).
Exit 0: written; 2: a one-line :class:`~hadal.errors.HadalError` on stderr (last line)."""

from __future__ import annotations

import json
import sys
from pathlib import Path


def main(argv: list[str]) -> int:
    from hadal.errors import HadalError
    from hadal.grid.readers import read_gsf
    from hadal.grid.sonar import SoundingBudget

    src, out, flagged = argv[0], Path(argv[1]), argv[2] == "1"
    limit = float(argv[3]) if len(argv) > 3 else None
    try:
        budget = SoundingBudget(Path(src), "gsf multibeam file", reader="gsf_child", limit_bytes=limit)
        df = read_gsf(src, include_flagged=flagged, isolate=False, budget=budget)
    except HadalError as exc:
        print(str(exc), file=sys.stderr)
        return 2
    attrs = dict(df.attrs)
    df.attrs = {}
    df.to_parquet(out)
    out.with_suffix(".json").write_text(json.dumps(attrs, default=str), encoding="utf-8")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
