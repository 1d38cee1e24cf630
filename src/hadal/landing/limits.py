"""Cell-size limits of the landing analysis (issue 15); SciPy-free so :class:`hadal.stages.landing.Params` can use
them without importing the analysis (:mod:`hadal.landing.sites` re-exports them)."""

#: the cell-size rule (issue 15): cells at most 1/10 of the vehicle width (5 cm for Table II), so the
#: footprint width spans >= 10 cells, the [Landing Eq. 8] exclusion radii (0 .. b_u/2) >= 5 cells and the 0.1 m local-slope
#: window >= 3 cells (it never gets coarser than its physical size).
CELL_FRACTION_RULE = 0.1
#: hard limit with an explicit ``max_cell_fraction`` override (e.g. the real Takuyo raster, 0.10 m = 0.2 × 0.5 m):
#: the analysis runs and adds a warning to :attr:`LandingResult.warnings`; beyond it cells are refused outright
#: (the footprint is then only ~5 cells wide and the [Landing Eq. 8] discs 1-2 cells: the exclusions are meaningless).
COARSE_CELL_LIMIT = 0.2

#: cells per row tile of the footprint-slope FFTs (:class:`hadal.landing.exclusion.HeadingCorrelator`): ~1 M cells (a
#: 1024 x 1125 float32 transform fits the caches; measured on the 100 m x 10 m strip, 12 such tiles transform ~2x faster
#: than 3 tiles of 4 M cells, overlap included)
TILE_CELLS = 1_000_000
