"""Navigation science (Prefect-free): :mod:`hadal.navigation.smoother`, one linear-Gaussian RTS smoother of the
vehicle's position over the whole dive from dead reckoning, GNSS, USBL and terrain fixes (issue 47)."""

from hadal.navigation.smoother import Fix, SmoothedTrack, ellipse, smooth_positions
from hadal.settings.navigation import SmootherOptions

__all__ = ["Fix", "SmoothedTrack", "SmootherOptions", "ellipse", "smooth_positions"]
