"""Press order: repeats grouped by position or shuffled across positions, and travel ordering of positions.

Travel ordering visits the positions along a short open route: nearest neighbour from the start
point, then 2-opt moves (vectorised over candidate pairs) until none shortens the route.
"""

from __future__ import annotations

import numpy as np

ORDERS = ("position", "shuffled")


def press_order(
    n_positions: int, repeats: int, order: str, seed: int, position_sequence: np.ndarray | None = None
) -> np.ndarray:
    """(presses, 2) array of (position_id, repeat) in execution order."""
    seq = np.arange(n_positions) if position_sequence is None else np.asarray(position_sequence)
    grid = np.column_stack([np.repeat(seq, repeats), np.tile(np.arange(repeats), len(seq))])
    if order == "position":
        return grid
    if order == "shuffled":
        # a stream separate from the positions' (which use default_rng(seed) directly)
        rng = np.random.default_rng([seed, 0x5EED])
        return grid[rng.permutation(len(grid))]
    raise ValueError(f"unknown order {order!r}; use one of {ORDERS}")


def route_length_mm(xy_mm: np.ndarray, sequence: np.ndarray, start_xy_mm: np.ndarray | None = None) -> float:
    pts = xy_mm[np.asarray(sequence)]
    if start_xy_mm is not None:
        pts = np.vstack([np.asarray(start_xy_mm, float)[None], pts])
    return float(np.sum(np.linalg.norm(np.diff(pts, axis=0), axis=1)))


def shorten_route(xy_mm: np.ndarray, start_xy_mm: np.ndarray | None = None, max_moves: int | None = None) -> np.ndarray:
    """A visiting order of the points: nearest neighbour from `start_xy_mm` (or point 0), then best-improvement 2-opt; the start never moves."""
    xy = np.asarray(xy_mm, float)
    n = len(xy)
    if n <= 2:
        return np.arange(n)
    current = np.asarray(start_xy_mm, float) if start_xy_mm is not None else xy[0]
    left = np.ones(n, dtype=bool)
    visits: list[int] = []
    for _ in range(n):
        d = np.where(left, np.linalg.norm(xy - current, axis=1), np.inf)
        k = int(np.argmin(d))
        visits.append(k)
        left[k] = False
        current = xy[k]
    route = np.array(visits)
    pts_all = xy if start_xy_mm is None else np.vstack([xy, np.asarray(start_xy_mm, float)[None]])
    head = [] if start_xy_mm is None else [n]  # the fixed start as an extra point at the front
    for _ in range(max_moves if max_moves is not None else 20 * n):
        path = np.array(head + route.tolist())
        p = pts_all[path]
        m = len(p)
        # reversing path[i+1 .. j] replaces edges (i, i+1) and (j, j+1) by (i, j) and (i+1, j+1);
        # j may be the last point (open route: no edge after it)
        i, j = np.triu_indices(m, k=2)
        a, b, c = p[i], p[i + 1], p[j]
        last = j == m - 1
        d = p[np.minimum(j + 1, m - 1)]
        old = np.linalg.norm(a - b, axis=1) + np.where(last, 0.0, np.linalg.norm(c - d, axis=1))
        new = np.linalg.norm(a - c, axis=1) + np.where(last, 0.0, np.linalg.norm(b - d, axis=1))
        gain = old - new
        best = int(np.argmax(gain)) if len(gain) else -1
        if best < 0 or gain[best] <= 1e-9:
            break
        bi, bj = int(i[best]), int(j[best])
        path[bi + 1 : bj + 1] = path[bi + 1 : bj + 1][::-1].copy()
        route = path[len(head) :]
    return route
