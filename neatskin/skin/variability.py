"""The skin's press-to-press variability: fabrication spread, slow drift and viscoelastic memory, as pure functions.

Each source is a pure function of its knobs, the seed and the press ids, so a dry run that is
killed and resumed draws exactly what an uninterrupted one would have (no state is kept in
process memory). Physical basis and the values used are in docs/skin.md:

- fabrication spread: moulded channels differ in height from channel to channel (a cast
  silicone skin's channel height varies by several percent); each channel's height is
  lognormal around the layout's, drawn once per skin from the seed.
- drift: the fluid's resistivity follows its temperature, rho (1 + alpha dT), and water
  evaporating through the silicone concentrates the salt, lowering rho by the share of water
  lost; both linear in time over a campaign.
- viscoelastic memory: after the probe lifts, silicone keeps a dent of `hysteresis_fraction`
  times the press depth that relaxes as exp(-t / relaxation_time_s); later presses feel the
  dents of the presses before them, in press order.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

STREAM_FABRICATION = 11
RESIDUAL_FLOOR_MM = 1e-4  # a dent shallower than this changes no channel by more than ~1e-9
MAX_REMEMBERED_PRESSES = 64


def fabrication_heights(n_channels: int, spread_fraction: float, seed: int) -> tuple[float, ...] | None:
    """Per-channel height over the nominal, lognormal with std `spread_fraction` in log; None when 0."""
    if spread_fraction == 0:
        return None
    rng = np.random.default_rng([seed, STREAM_FABRICATION])
    return tuple(float(h) for h in np.exp(rng.normal(0.0, spread_fraction, n_channels)))


def drift_resistivity_factor(
    time_s,
    temperature_drift_k_per_h: float,
    evaporation_fraction_per_h: float,
    resistivity_tempco_per_k: float = -0.02,
) -> np.ndarray:
    """rho(t) / rho(0): (1 + alpha dT/dt t) (1 - e t), t in seconds since the campaign's first press."""
    hours = np.asarray(time_s, float) / 3600.0
    return (1.0 + resistivity_tempco_per_k * temperature_drift_k_per_h * hours) * (
        1.0 - evaporation_fraction_per_h * hours
    )


@dataclass(frozen=True)
class Relaxation:
    """Viscoelastic memory of the silicone: residual dent h * depth, relaxing with time constant tau."""

    hysteresis_fraction: float
    relaxation_time_s: float
    press_interval_s: float

    def residual_dents(self, press_id: int, commanded_mm: np.ndarray) -> np.ndarray:
        """(k, 3) x, y and residual depth of the dents the presses before `press_id` left at its start.

        commanded_mm: (presses, 3) commanded x, y, depth of every press, by press id (press order).
        Only dents deeper than RESIDUAL_FLOOR_MM count, at most MAX_REMEMBERED_PRESSES of them."""
        if self.hysteresis_fraction == 0 or press_id == 0:
            return np.empty((0, 3))
        first = max(0, press_id - MAX_REMEMBERED_PRESSES)
        earlier = np.asarray(commanded_mm[first:press_id], float)
        age_s = (press_id - np.arange(first, press_id)) * self.press_interval_s
        depth = self.hysteresis_fraction * earlier[:, 2] * np.exp(-age_s / self.relaxation_time_s)
        keep = depth > RESIDUAL_FLOOR_MM
        return np.column_stack([earlier[keep, 0], earlier[keep, 1], depth[keep]])

    def memory_presses(self, depth_mm: float) -> int:
        """How many earlier presses can still leave a dent above the floor (for the docs and benchmarks)."""
        if self.hysteresis_fraction == 0:
            return 0
        ratio = self.hysteresis_fraction * depth_mm / RESIDUAL_FLOOR_MM
        return min(MAX_REMEMBERED_PRESSES, math.floor(self.relaxation_time_s * math.log(ratio) / self.press_interval_s))
