"""Synthetic press tables for tests and benchmarks: a smooth nonlinear map from (x, y) to pair features.

Not a skin model (that is rig.skin's job): each electrode pair's resistance change is a
Gaussian ridge along the straight segment between its two electrodes, plus Gaussian noise,
so position is recoverable but not linearly. Rows follow the dataset contract's columns
(press_id, position_id, repeat, x_mm, y_mm, depth_mm, flags, R_ohm_i_j, dR_ohm_i_j).
"""

from __future__ import annotations

import itertools

import numpy as np
import pandas as pd

# The paper skin's electrodes (SPEC): number -> (x_mm, y_mm)
PAPER_ELECTRODES_MM = {
    1: (15.0, 0.0), 2: (30.0, 0.0), 3: (30.0, 15.0), 4: (30.0, 30.0),
    5: (15.0, 30.0), 6: (0.0, 30.0), 7: (0.0, 15.0), 8: (0.0, 0.0),
}
PAPER_PAIRS = tuple(itertools.combinations(sorted(PAPER_ELECTRODES_MM), 2))


def _segment_distance_mm(xy: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Distance (n, pairs) from points xy (n, 2) to segments a->b (pairs, 2)."""
    ab = b - a
    t = np.einsum("npk,pk->np", xy[:, None, :] - a[None], ab) / np.einsum("pk,pk->p", ab, ab)
    closest = a[None] + np.clip(t, 0.0, 1.0)[..., None] * ab[None]
    return np.linalg.norm(xy[:, None, :] - closest, axis=-1)


def synthetic_features(xy_mm: np.ndarray, width_mm: float = 6.0, scale_ohm: float = 50.0) -> np.ndarray:
    """Noise-free features (n, 28): a Gaussian ridge along each pair's electrode segment."""
    a = np.array([PAPER_ELECTRODES_MM[i] for i, _ in PAPER_PAIRS])
    b = np.array([PAPER_ELECTRODES_MM[j] for _, j in PAPER_PAIRS])
    d = _segment_distance_mm(np.asarray(xy_mm, float), a, b)
    return scale_ohm * np.exp(-0.5 * (d / width_mm) ** 2)


def synthetic_presses(
    n_positions: int = 100,
    repeats: int = 28,
    noise_ohm: float = 1.0,
    seed: int = 0,
    depth_mm: float = 3.5,
) -> pd.DataFrame:
    """A press table in the dataset contract's columns: n_positions x repeats rows, positions in [0, 30]^2."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(0.0, 30.0, (n_positions, 2))
    position = np.repeat(np.arange(n_positions), repeats)
    clean = synthetic_features(xy)[position]
    d_r = clean + rng.normal(0.0, noise_ohm, clean.shape)
    table = {
        "press_id": np.arange(len(position)),
        "position_id": position,
        "repeat": np.tile(np.arange(repeats), n_positions),
        "x_mm": xy[position, 0],
        "y_mm": xy[position, 1],
        "depth_mm": np.full(len(position), depth_mm),
        "flags": [[] for _ in range(len(position))],
    }
    for p, (i, j) in enumerate(PAPER_PAIRS):
        table[f"R_ohm_{i}_{j}"] = 1000.0 + d_r[:, p]
        table[f"dR_ohm_{i}_{j}"] = d_r[:, p]
    return pd.DataFrame(table)
