"""Landing-site analysis on mm-resolution laser bathymetry (Sangekar et al., §III-IV).

Public API: :class:`Vehicle` (Table II, Eqs. 1-9), :func:`analyse_submap` -> :class:`LandingResult`.
"""

from hadal.landing.sites import LandingResult, analyse_submap
from hadal.landing.vehicle import Vehicle

__all__ = ["LandingResult", "Vehicle", "analyse_submap"]
