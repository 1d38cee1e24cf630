"""True vehicle trajectory of the sample dive (TERCOM paper §4.1.3-4.2).

* Descent (3 h 35 min, unpowered, >= 50 m/min): the vehicle sinks from the launch point and drifts with
  the currents to the start of the bottom track (533 m away in the paper, §4.2). Nobody on board knows this
  drift: there is no horizontal velocity reference during the descent.
* Bottom survey (3 h, constant altitude, §4.1.4): a U pattern on the flat trench floor - the first leg
  passes over the deepest point recorded by the vehicle - then a long leg to the north-west up the
  rugged wall ("topographic fluctuations in the northwest direction").
* Ascent (3 h 16 min), drifting again.

The vehicle's depth during the bottom phase follows the seafloor through a depth controller (a 6 s
Gaussian smoother of seafloor - set altitude, plus a little heave); the true altitude is the difference.
All arrays are 1 Hz nodes; sensors interpolate them (:meth:`Track.at`).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from scipy.ndimage import gaussian_filter1d

from hadal.synth import scenario as sc
from hadal.synth.terrain import Terrain

PHASES = ("descent", "bottom", "ascent")


def smooth_noise(rng: np.random.Generator, n: int, corr_samples: float) -> np.ndarray:
    """Unit-variance Gaussian noise with a Gaussian autocorrelation of ``corr_samples`` samples."""
    step = max(1, int(corr_samples // 8))  # long correlations: smooth a decimated series, interpolate back
    m = n // step + 2
    c = corr_samples / step
    pad = int(4 * c) + 1
    w = rng.standard_normal(m + 2 * pad)
    s = gaussian_filter1d(w, c, mode="wrap")[pad:pad + m]
    if step > 1:
        s = np.interp(np.arange(n) / step, np.arange(m), s)
    s = s[:n]
    sd = s.std()
    return s / sd if sd > 0 else s


def trapezoid_profile(n_s: int, total: float, ramp_up_s: float, ramp_down_s: float,
                      wobble: np.ndarray | None = None) -> np.ndarray:
    """Cumulative distance (0..total) at 1 Hz over ``n_s`` seconds with a trapezoidal speed profile."""
    t = np.arange(n_s + 1, dtype=float)
    v = np.minimum(np.minimum(t / ramp_up_s, 1.0), np.minimum((n_s - t) / ramp_down_s, 1.0))
    v = np.clip(v, 0.0, 1.0)
    if wobble is not None:
        v = v * (1.0 + wobble[: n_s + 1])
    v = np.maximum(v, 0.0)
    s = np.concatenate([[0.0], np.cumsum(0.5 * (v[1:] + v[:-1]))])
    return s * (total / s[-1])


def _polyline(points: np.ndarray, step: float) -> np.ndarray:
    out = [points[0]]
    for a, b in zip(points[:-1], points[1:], strict=True):
        n = max(int(np.ceil(np.hypot(*(b - a)) / step)), 1)
        f = np.arange(1, n + 1)[:, None] / n
        out.extend(a + f * (b - a))
    return np.asarray(out)


def survey_path(start_xy: np.ndarray, deepest_xy: np.ndarray) -> np.ndarray:
    """Waypoints of the bottom survey: U pattern on the floor, then north-west up the wall (map frame, m)."""
    u1 = deepest_xy - start_xy
    u1 = u1 / np.hypot(*u1)  # first leg heads (about due south) over the deepest point
    east = np.array([-u1[1], u1[0]])  # left of a southward leg = east
    w1 = start_xy + 600.0 * u1
    w2 = w1 + 500.0 * east
    w3 = w2 - 950.0 * u1
    nw = np.array([np.sin(np.radians(315.0)), np.cos(np.radians(315.0))])
    wnw = np.array([np.sin(np.radians(300.0)), np.cos(np.radians(300.0))])
    w4 = w3 + 800.0 * nw
    w5 = w4 + 700.0 * wnw
    return np.vstack([start_xy, w1, w2, w3, w4, w5])


@dataclass
class Track:
    """1 Hz nodes of the true trajectory (time in s since launch; map frame metres; depths positive down)."""

    t: np.ndarray
    x: np.ndarray
    y: np.ndarray
    depth: np.ndarray
    seafloor: np.ndarray
    phase: np.ndarray  # int index into PHASES
    heading: np.ndarray  # deg true, unwrapped
    vx: np.ndarray  # true horizontal velocity (m/s)
    vy: np.ndarray
    i_bottom_start: int
    i_bottom_end: int
    i_deepest: int
    info: dict = field(default_factory=dict)

    @property
    def altitude(self) -> np.ndarray:
        return self.seafloor - self.depth

    def at(self, t_s: np.ndarray, terrain: Terrain) -> dict[str, np.ndarray]:
        """State at arbitrary times (linear between nodes; seafloor sampled from the terrain)."""
        t_s = np.asarray(t_s, float)
        x = np.interp(t_s, self.t, self.x)
        y = np.interp(t_s, self.t, self.y)
        depth = np.interp(t_s, self.t, self.depth)
        sf = terrain.sample(x, y)
        return {"x": x, "y": y, "depth": depth, "seafloor": sf, "altitude": sf - depth,
                "heading": np.interp(t_s, self.t, self.heading) % 360.0,
                "vx": np.interp(t_s, self.t, self.vx), "vy": np.interp(t_s, self.t, self.vy),
                "phase": self.phase[np.clip(np.searchsorted(self.t, t_s, side="right") - 1, 0, len(self.t) - 1)]}


def bottom_depth(seafloor: np.ndarray, heave: np.ndarray) -> np.ndarray:
    """Depth-controller model: smoothed (seafloor - set altitude) plus heave; linear in the seafloor."""
    return gaussian_filter1d(seafloor - sc.SURVEY_ALTITUDE_M, 6.0, mode="nearest") + heave


def build_horizontal(rng: np.random.Generator, launch_xy, start_xy, deepest_xy) -> dict:
    """Horizontal path at 1 Hz for the whole dive and the phase index."""
    launch_xy, start_xy, deepest_xy = (np.asarray(v, float) for v in (launch_xy, start_xy, deepest_xy))
    nd, nb, na = sc.DESCENT_S, sc.BOTTOM_S, sc.ASCENT_S
    n = nd + nb + na + 1
    t = np.arange(n, dtype=float)
    x = np.empty(n)
    y = np.empty(n)
    phase = np.empty(n, dtype=np.int8)
    phase[:nd] = 0
    phase[nd:nd + nb + 1] = 1
    phase[nd + nb + 1:] = 2

    # descent: most of the drift in the upper ocean (stronger currents), a lateral meander, ends at start_xy
    tau = np.arange(nd + 1) / nd
    g = (1 - np.exp(-tau / 0.35)) / (1 - np.exp(-1 / 0.35))
    d = start_xy - launch_xy
    nrm = np.array([-d[1], d[0]]) / np.hypot(*d)
    lateral = (90.0 + 30.0 * rng.random()) * np.sin(np.pi * tau) * (1 - tau) * 2.0
    wob = 12.0 * smooth_noise(rng, nd + 1, 300.0) * np.sin(np.pi * tau)
    x[:nd + 1] = launch_xy[0] + d[0] * g + nrm[0] * (lateral + wob)
    y[:nd + 1] = launch_xy[1] + d[1] * g + nrm[1] * (lateral + wob)

    # bottom: rounded-corner path, constant speed with small variations
    wps = survey_path(start_xy, deepest_xy)
    u0 = (wps[1] - wps[0]) / np.hypot(*(wps[1] - wps[0]))
    u9 = (wps[-1] - wps[-2]) / np.hypot(*(wps[-1] - wps[-2]))
    ext = np.vstack([wps[0] - 300.0 * u0, wps, wps[-1] + 300.0 * u9])
    pl = _polyline(ext, 1.0)
    sm = np.column_stack([gaussian_filter1d(pl[:, 0], 18.0, mode="nearest"),
                          gaussian_filter1d(pl[:, 1], 18.0, mode="nearest")])
    arc = np.concatenate([[0.0], np.cumsum(np.hypot(*np.diff(sm, axis=0).T))])
    # crop to the part between the first and last real waypoint (straight extensions removed)
    a0 = arc[np.argmin(np.hypot(*(sm - wps[0]).T))]
    a1 = arc[np.argmin(np.hypot(*(sm - wps[-1]).T))]
    wobble = 0.06 * smooth_noise(rng, nb + 1, 120.0)
    s = a0 + trapezoid_profile(nb, a1 - a0, 45.0, 45.0, wobble)
    x[nd:nd + nb + 1] = np.interp(s, arc, sm[:, 0])
    y[nd:nd + nb + 1] = np.interp(s, arc, sm[:, 1])
    # exact start point
    x[nd], y[nd] = start_xy

    # ascent: drift again, roughly with the descent currents
    ang = np.arctan2(d[1], d[0]) + np.radians(rng.normal(0.0, 20.0))
    mag = 420.0 + 120.0 * rng.random()
    tau = np.arange(1, na + 1) / na
    ga = 1 - (1 - tau) ** 1.6
    e = np.array([x[nd + nb], y[nd + nb]])
    x[nd + nb + 1:] = e[0] + mag * np.cos(ang) * ga + 30.0 * np.sin(np.pi * tau) * np.sin(ang)
    y[nd + nb + 1:] = e[1] + mag * np.sin(ang) * ga - 30.0 * np.sin(np.pi * tau) * np.cos(ang)

    vx = np.gradient(x)
    vy = np.gradient(y)
    i_deep = nd + int(np.argmin(np.hypot(x[nd:nd + nb + 1] - deepest_xy[0], y[nd:nd + nb + 1] - deepest_xy[1])))
    return {"t": t, "x": x, "y": y, "vx": vx, "vy": vy, "phase": phase, "i_deepest": i_deep,
            "waypoints": wps, "ascent_drift_m": float(mag)}


def build_track(rng: np.random.Generator, h: dict, terrain: Terrain, heave_bottom: np.ndarray) -> Track:
    """Depths and headings on the horizontal path ``h`` over ``terrain``."""
    nd, nb, na = sc.DESCENT_S, sc.BOTTOM_S, sc.ASCENT_S
    t, x, y = h["t"], h["x"], h["y"]
    n = len(t)
    seafloor = terrain.sample(x, y)
    depth = np.empty(n)
    b = slice(nd, nd + nb + 1)
    db = bottom_depth(seafloor[b], heave_bottom)
    db = np.minimum(db, seafloor[b] - 2.5)  # the controller never lets the vehicle closer than 2.5 m
    depth[b] = db

    # descent: start just below the surface, ramp to full speed in 90 s, slow down over the last 10 min
    z0 = 0.6
    prof = trapezoid_profile(nd, db[0] - z0, 90.0, 600.0, 0.05 * smooth_noise(rng, nd + 1, 200.0))
    depth[:nd + 1] = z0 + prof
    depth[nd] = db[0]
    # ascent: accelerate in 60 s, slow down near the surface over 3 min
    prof = trapezoid_profile(na, db[-1] - z0, 60.0, 180.0, 0.05 * smooth_noise(rng, na + 1, 200.0))
    depth[nd + nb:] = db[-1] - prof
    depth[-1] = z0

    # headings: the vehicle spins slowly while sinking / rising (random walk); along the course on the bottom
    course = np.degrees(np.arctan2(h["vx"][b], h["vy"][b]))
    course = np.degrees(np.unwrap(np.radians(course)))
    course = gaussian_filter1d(course, 3.0, mode="nearest")
    heading = np.empty(n)
    rw_d = np.cumsum(rng.normal(0.0, 0.6, nd))
    heading[:nd] = course[0] - (rw_d[-1] - rw_d)
    heading[nd:nd + nb + 1] = course
    rw_a = np.cumsum(rng.normal(0.0, 0.6, na))
    heading[nd + nb + 1:] = course[-1] + rw_a
    return Track(t=t, x=x, y=y, depth=depth, seafloor=seafloor, phase=h["phase"], heading=heading,
                 vx=h["vx"], vy=h["vy"], i_bottom_start=nd, i_bottom_end=nd + nb, i_deepest=h["i_deepest"],
                 info={"waypoints": h["waypoints"], "ascent_drift_m": h["ascent_drift_m"]})
