"""Options of the landing analysis (:func:`hadal.landing.sites.analyse_submap`), declared once in
:mod:`hadal.settings.landing`."""

from hadal.settings.landing import AnalysisOptions

__all__ = ["AnalysisOptions"]
