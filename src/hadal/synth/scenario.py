"""The scenario of the sample dive: the Haidou dive in the Challenger Deep (Zhang et al., TERCOM paper §2, §4).

All numbers the generator takes from the paper live here, with the section they come from.

Positions (§4.2): launch 142°12.583'E 11°20.227'N; matched start of the bottom track 142°12.853'E
11°20.339'N (533 m from the launch point); deepest point recorded by the vehicle 142°12.852'E 11°20.282'N
at 10 905 m. Timing (§4.1.3): descent ~3 h 35 min, ~3 h near the seafloor, ascent ~3 h 16 min; unpowered
descent and ascent no slower than 50 m/min (Table 1). Reference map (§4.1.1): 23.8 km E-W x 17.7 km N-S at
20 m, depths 8346-10 928 m; the deepest point of the map lies south-west of the launch point (§4.1.2).
"""

from __future__ import annotations

import datetime as _dt

from hadal.geo import parse_degmin

#: Launch point (§4.2).
LAUNCH_LON_DEG = parse_degmin("142°12.583'E")
LAUNCH_LAT_DEG = parse_degmin("11°20.227'N")
#: Initial position of the matched trajectory = start of the bottom track (§4.2).
BOTTOM_START_LON_DEG = parse_degmin("142°12.853'E")
BOTTOM_START_LAT_DEG = parse_degmin("11°20.339'N")
#: Deepest point recorded by Haidou and its vehicle depth (§4.2).
DEEPEST_LON_DEG = parse_degmin("142°12.852'E")
DEEPEST_LAT_DEG = parse_degmin("11°20.282'N")
DEEPEST_VEHICLE_DEPTH_M = 10905.0

#: Launch time (the sea trials were in September/October 2018; 09:00 local time in Guam).
LAUNCH_TIME_UTC = _dt.datetime(2018, 10, 6, 23, 0, 0, tzinfo=_dt.UTC)

#: Phase durations (§4.1.3): 3 h 35 min descent, 3 h bottom survey, 3 h 16 min ascent.
DESCENT_S = 3 * 3600 + 35 * 60
BOTTOM_S = 3 * 3600
ASCENT_S = 3 * 3600 + 16 * 60

#: Map frame origin = centre of the reference map (dive.yaml ``map_frame``).
MAP_ORIGIN_LAT_DEG = 11.33
MAP_ORIGIN_LON_DEG = 142.20
#: Reference map (§4.1.1): 1190 x 885 cells of 20 m (23.8 km x 17.7 km), 8346-10 928 m.
MAP_RES_M = 20.0
MAP_NX = 1190
MAP_NY = 885
MAP_MIN_DEPTH_M = 8346.0
MAP_MAX_DEPTH_M = 10928.0

#: Constant-altitude mode of the bottom survey (§4.1.4); the set altitude is our choice.
SURVEY_ALTITUDE_M = 10.0

DIVE_ID = "haidou-challenger-deep"
PLATFORM = "Haidou"
