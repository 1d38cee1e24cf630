"""Cell-size limits of the landing analysis (issue 15), declared with the options in :mod:`hadal.settings.landing`
(:mod:`hadal.landing.sites` re-exports them)."""

from hadal.settings.landing import CELL_FRACTION_RULE, COARSE_CELL_LIMIT, TILE_CELLS

__all__ = ["CELL_FRACTION_RULE", "COARSE_CELL_LIMIT", "TILE_CELLS"]
