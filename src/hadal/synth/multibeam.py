"""EM122-like multibeam soundings of the reference terrain (TERCOM paper §4.1.1).

Parallel E-W survey lines; each ping is a dual swath of equidistant beams across-track (the outer beams
beyond the usable deep-water swath dropped), with ship yaw, ping-to-ping jitter and a little position
noise. Each sounding samples the true (bilinear) surface at its footprint centre and adds

* depth-proportional noise, sigma = ``noise_fraction`` x depth (0.1 % of depth, EM122 class),
* spikes: a fraction ``spike_fraction`` of soundings off by +-100..300 m (bottom-detection blunders),
* a constant deep bias ``bias_m`` (the paper: "due to the uncertain sound velocity ... the multibeam
  bathymetric data was several meters deeper than the actual depth", §4.2).

Soundings are cropped to the reference-map rectangle (the paper's map is a crop of the cruise data).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hadal.geo import LocalFrame
from hadal.synth.terrain import Terrain


@dataclass(frozen=True)
class MultibeamModel:
    n_lines: int
    ping_spacing_m: float  # along-track spacing of (dual-swath) pings
    beams_per_ping: int
    swath_half_width_m: float
    noise_fraction: float = 0.001
    spike_fraction: float = 0.003
    spike_min_m: float = 100.0
    spike_max_m: float = 300.0
    bias_m: float = 4.0

    def truth(self) -> dict:
        return {"noise_sigma_fraction_of_depth": self.noise_fraction, "spike_fraction": self.spike_fraction,
                "spike_magnitude_m": [self.spike_min_m, self.spike_max_m], "bias_m": self.bias_m,
                "bias_sense": "soundings are deeper than the truth by bias_m",
                "n_lines": self.n_lines, "ping_spacing_m": self.ping_spacing_m,
                "beams_per_ping": self.beams_per_ping, "swath_half_width_m": self.swath_half_width_m}


def survey_line(rng: np.random.Generator, terrain: Terrain, model: MultibeamModel, y_line: float,
                westward: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """(x, y, true depth, measured depth) of one line's soundings inside the map rectangle."""
    x0, x1, y0, y1 = terrain.bounds()
    margin = 600.0
    n_ping = int((x1 - x0 + 2 * margin) / model.ping_spacing_m)
    s = np.arange(n_ping) * model.ping_spacing_m + rng.uniform(0, model.ping_spacing_m)
    xs = (x0 - margin + s) if not westward else (x1 + margin - s)
    # ship track wanders a little; yaw rotates the swath
    wander = np.cumsum(rng.normal(0.0, 3.0, n_ping))
    wander -= np.linspace(wander[0], wander[-1], n_ping)
    ys = y_line + wander
    yaw = np.radians(rng.normal(0.0, 1.5, n_ping))
    across = np.linspace(-model.swath_half_width_m, model.swath_half_width_m, model.beams_per_ping)
    a = across[None, :] + rng.uniform(-0.4, 0.4, (n_ping, model.beams_per_ping)) * (across[1] - across[0])
    sx = xs[:, None] + a * np.sin(yaw)[:, None] + rng.normal(0.0, 2.0, a.shape)
    sy = ys[:, None] + a * np.cos(yaw)[:, None] + rng.normal(0.0, 2.0, a.shape)
    sx, sy = sx.ravel(), sy.ravel()
    inside = (sx >= x0) & (sx <= x1) & (sy >= y0) & (sy <= y1)
    sx, sy = sx[inside], sy[inside]
    true = terrain.sample(sx, sy)
    n = len(sx)
    meas = true + model.bias_m + rng.normal(0.0, 1.0, n) * model.noise_fraction * true
    spikes = rng.random(n) < model.spike_fraction
    k = int(spikes.sum())
    meas[spikes] += rng.choice([-1.0, 1.0], k) * rng.uniform(model.spike_min_m, model.spike_max_m, k)
    return sx, sy, true, meas


def line_positions(terrain: Terrain, n_lines: int) -> np.ndarray:
    _, _, y0, y1 = terrain.bounds()
    return np.linspace(y0 + 400.0, y1 - 400.0, n_lines)


def to_lonlat(frame: LocalFrame, x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    lon, lat = frame.to_lonlat(x, y)
    return np.asarray(lon), np.asarray(lat)
