"""Sample-dive generator (``hadal synth DEST``): a seeded, byte-deterministic Haidou dive in the Challenger Deep.

Writes a raw dive directory exactly as docs/architecture.md ("Raw dive directory", "MCAP channels",
"CSV variants") describes, plus the ground truth (truth.json, truth/terrain.nc, truth/track.parquet).
The scenario follows Zhang et al., *Terrain matching localization for hybrid underwater vehicle in the
Challenger Deep of the Mariana Trench* §2 and §4 (see :mod:`hadal.synth.scenario`); the laser submaps follow
Sangekar et al., *Autonomous landing of underwater vehicles using high resolution bathymetry* §III-IV.

This package is the ground truth the science modules are tested against: it must not import
hadal.seawater, hadal.depth, hadal.ingest, hadal.grid, hadal.matching or hadal.landing. It uses gsw
(TEOS-10) for the water column, pyproj through :mod:`hadal.geo` for the map frame, and mcap for the log.

    >>> from hadal.synth import generate_dive
    >>> generate_dive("/tmp/sample", small=True)   # doctest: +SKIP
"""

from __future__ import annotations

from hadal.synth.generate import generate_dive

__all__ = ["generate_dive"]
