"""Synthetic press rows for tests, benchmarks and examples: a small resistor-network stand-in for a
campaign, so the dataset tools can be exercised without the rig (the real physics lives in rig.skin).

A press at (x, y) raises each channel's resistance by `touch` (the paper's +50 %) times a Gaussian of the
distance from the probe to the channel's centre line; pair resistances follow from the network's
Laplacian. Deterministic for a given seed and press id.
"""

from __future__ import annotations

import datetime as _dt
from typing import Any

import numpy as np

from neatskin.layout import Layout


def pair_resistance_ohm(layout: Layout, channel_resistance_ohm: np.ndarray) -> np.ndarray:
    """(n, channels) channel resistances -> (n, pairs) equivalent resistances, via the Laplacian's
    pseudo-inverse (R_ij = L+_ii + L+_jj - 2 L+_ij)."""
    g = 1.0 / np.atleast_2d(channel_resistance_ohm)
    n_j = layout.n_junctions
    a, b = layout.channel_ends[:, 0], layout.channel_ends[:, 1]
    lap = np.zeros((g.shape[0], n_j, n_j))
    rows = np.arange(g.shape[0])[:, None]
    np.add.at(lap, (rows, a, a), g)
    np.add.at(lap, (rows, b, b), g)
    np.add.at(lap, (rows, a, b), -g)
    np.add.at(lap, (rows, b, a), -g)
    pinv = np.linalg.pinv(lap)
    jn = layout.electrode_junctions[layout.pair_electrode_index]  # (pairs, 2) junction indices
    i, j = jn[:, 0], jn[:, 1]
    return pinv[:, i, i] + pinv[:, j, j] - 2.0 * pinv[:, i, j]


def distance_to_channels_mm(layout: Layout, xy_mm: np.ndarray) -> np.ndarray:
    """(n, 2) points -> (n, channels) distance to each channel's centre line segment."""
    p0 = layout.xy_mm[layout.channel_ends[:, 0]]
    p1 = layout.xy_mm[layout.channel_ends[:, 1]]
    seg = p1 - p0
    rel = xy_mm[:, None, :] - p0[None]
    t = np.clip(np.sum(rel * seg, axis=2) / np.sum(seg * seg, axis=1), 0.0, 1.0)
    nearest = p0[None] + t[..., None] * seg[None]
    return np.linalg.norm(xy_mm[:, None, :] - nearest, axis=2)


def synthetic_positions_mm(layout: Layout, n_positions: int, seed: int) -> np.ndarray:
    """n random positions inside the layout's bounds, half of them snapped onto a channel."""
    rng = np.random.default_rng([seed, 0])
    x0, y0, x1, y1 = layout.bounds_mm
    xy = rng.uniform((x0, y0), (x1, y1), size=(n_positions, 2))
    on_channel = rng.random(n_positions) < 0.5
    ch = rng.integers(0, layout.n_channels, size=n_positions)
    t = rng.random(n_positions)
    p0 = layout.xy_mm[layout.channel_ends[ch, 0]]
    p1 = layout.xy_mm[layout.channel_ends[ch, 1]]
    xy[on_channel] = (p0 + t[:, None] * (p1 - p0))[on_channel]
    return xy


def synthetic_rows(layout: Layout, n_positions: int, repeats: int, *, seed: int = 0, campaign: str = "synthetic",
                   depth_mm: float = 3.5, touch: float = 0.5, spread_mm: float = 2.0, noise_ohm: float = 1.0,
                   start: _dt.datetime | None = None) -> list[dict[str, Any]]:
    """Rows for n_positions x repeats presses (press_id = position_id * repeats + repeat), ready for
    CampaignWriter.write_press; R_ohm and dR_ohm given as arrays in layout.pairs order."""
    xy = synthetic_positions_mm(layout, n_positions, seed)
    base_ch = layout.channel_resistance_ohm
    factor = 1.0 + touch * np.exp(-0.5 * (distance_to_channels_mm(layout, xy) / spread_mm) ** 2)
    baseline = pair_resistance_ohm(layout, base_ch[None])[0]
    pressed = pair_resistance_ohm(layout, base_ch[None] * factor)  # (positions, pairs)
    start = start or _dt.datetime(2026, 1, 1, tzinfo=_dt.timezone.utc)
    rows = []
    for position_id in range(n_positions):
        for repeat in range(repeats):
            press_id = position_id * repeats + repeat
            noise = np.random.default_rng([seed, 1, press_id]).normal(0.0, noise_ohm, size=baseline.shape)
            r = pressed[position_id] + noise
            t0 = start + _dt.timedelta(seconds=2 * press_id)
            rows.append({
                "campaign": campaign, "press_id": press_id, "position_id": position_id, "repeat": repeat,
                "x_mm": float(xy[position_id, 0]), "y_mm": float(xy[position_id, 1]), "depth_mm": depth_mm,
                "started_at": t0, "finished_at": t0 + _dt.timedelta(seconds=1.5),
                "fsr_onset_s": 0.25, "fsr_offset_s": 1.25, "fsr_peak_n": 4.0 + 0.01 * repeat,
                "flags": [], "R_ohm": r, "dR_ohm": r - baseline,
            })
    return rows
