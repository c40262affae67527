"""Synthetic press rows and tables for tests, benchmarks and examples, on the exact network solver.

A press at (x, y) raises each channel's resistance by `touch` (the paper's +50 %) times a Gaussian
of the distance from the probe to the channel's centre line (`Layout.distance_to_channels_mm`);
pair resistances come from the exact solver (`skin.network.equivalent_resistance`). This is a
stand-in campaign for exercising the dataset and baseline tools without the rig, not the
deformation model (`skin.model`). Deterministic for a given seed and press id.
"""

from __future__ import annotations

import datetime as _dt
from typing import Any

import numpy as np
import pandas as pd

from neatskin.layout import Layout
from neatskin.skin.network import equivalent_resistance


def pair_resistance_ohm(layout: Layout, channel_resistance_ohm: np.ndarray) -> np.ndarray:
    """(n, channels) channel resistances -> (n, pairs) equivalent resistances (exact solver)."""
    return equivalent_resistance(layout, 1.0 / np.atleast_2d(channel_resistance_ohm))


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


def synthetic_rows(
    layout: Layout,
    n_positions: int,
    repeats: int,
    *,
    seed: int = 0,
    campaign: str = "synthetic",
    depth_mm: float = 3.5,
    touch: float = 0.5,
    spread_mm: float = 2.0,
    noise_ohm: float = 1.0,
    start: _dt.datetime | None = None,
) -> list[dict[str, Any]]:
    """Rows for n_positions x repeats presses (press_id = position_id * repeats + repeat), ready for
    CampaignWriter.write_press; R_ohm and dR_ohm given as arrays in layout.pairs order."""
    xy = synthetic_positions_mm(layout, n_positions, seed)
    base_ch = layout.channel_resistance_ohm
    factor = 1.0 + touch * np.exp(-0.5 * (layout.distance_to_channels_mm(xy) / spread_mm) ** 2)
    baseline = pair_resistance_ohm(layout, base_ch[None])[0]
    pressed = pair_resistance_ohm(layout, base_ch[None] * factor)  # (positions, pairs)
    start = start or _dt.datetime(2026, 1, 1, tzinfo=_dt.UTC)
    rows = []
    for position_id in range(n_positions):
        for repeat in range(repeats):
            press_id = position_id * repeats + repeat
            noise = np.random.default_rng([seed, 1, press_id]).normal(0.0, noise_ohm, size=baseline.shape)
            r = pressed[position_id] + noise
            t0 = start + _dt.timedelta(seconds=2 * press_id)
            rows.append(
                {
                    "campaign": campaign,
                    "press_id": press_id,
                    "position_id": position_id,
                    "repeat": repeat,
                    "x_mm": float(xy[position_id, 0]),
                    "y_mm": float(xy[position_id, 1]),
                    "depth_mm": depth_mm,
                    "started_at": t0,
                    "finished_at": t0 + _dt.timedelta(seconds=1.5),
                    "fsr_onset_s": 0.25,
                    "fsr_offset_s": 1.25,
                    "fsr_peak_n": 4.0 + 0.01 * repeat,
                    "flags": [],
                    "R_ohm": r,
                    "dR_ohm": r - baseline,
                }
            )
    return rows


def synthetic_presses(
    layout: Layout,
    n_positions: int = 100,
    repeats: int = 28,
    *,
    noise_ohm: float = 1.0,
    seed: int = 0,
    depth_mm: float = 3.5,
) -> pd.DataFrame:
    """The same presses as a table in the dataset contract's columns (R_ohm_i_j, dR_ohm_i_j per pair)."""
    rows = synthetic_rows(layout, n_positions, repeats, seed=seed, depth_mm=depth_mm, noise_ohm=noise_ohm)
    table: dict[str, Any] = {
        key: [row[key] for row in rows]
        for key in ("press_id", "position_id", "repeat", "x_mm", "y_mm", "depth_mm", "flags")
    }
    r = np.array([row["R_ohm"] for row in rows])
    d_r = np.array([row["dR_ohm"] for row in rows])
    for p, pair in enumerate(layout.pairs):
        table[f"R_ohm_{pair.i}_{pair.j}"] = r[:, p]
        table[f"dR_ohm_{pair.i}_{pair.j}"] = d_r[:, p]
    return pd.DataFrame(table)
