"""Press sensitivities of a channel network by the adjoint formula: d R_ab / d(x, y, depth) for every press and
every pair of candidate electrode junctions, without finite differences of full network solves.

For a unit current driven from junction a to junction b, the current through channel c is I_c^ab, and
d R_ab / d R_c = (I_c^ab)^2 (Tellegen / the adjoint of the grounded Laplacian solve). A press changes only
the channels within reach of the probe (K, a handful per press), so the pressed network's potentials follow
from the unpressed one's by a rank-|K| Woodbury update:

    dV_K' = (I + M_KK diag(dg_K))^-1 dV_K,      M = B^T Z B,  dV = B^T Z (e_a - e_b)

with Z the grounded inverse of the unpressed Laplacian (dense, computed once per layout), B the channel
incidence, dg the press's conductance change. Then I_c' = g_c' dV_c' and
d R_ab / d theta = sum_{c in K} (I_c'^ab)^2 d R_c / d theta, theta = (x_mm, y_mm, depth_mm). The channel
resistances and their derivatives come from `neatskin.skin.deformation` (the deformation model or its
closed-form "network" stand-in), by central differences of that per-channel factor only.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from neatskin.layout import Layout
from neatskin.skin.deformation import PinchParams, nearest_point_factor, resistance_factor

FIDELITIES = ("network", "deformation")
DENSE_MAX_JUNCTIONS = 3000  # Z is junctions^2 floats: 72 MB at 3000
_STEP_MM = 1e-3


@dataclass(frozen=True)
class PressJacobian:
    """Everything the bound needs about one batch of presses, for a set of candidate electrode junctions.

    weights: (presses, K, J) unit-current potential drops over the touched channels K, pressed state,
        for unit current into each candidate junction (J) against the grounded reference; a pair's drop is
        the difference of two columns.
    conductance_s: (presses, K) pressed conductance of each touched channel (0 for a padding slot).
    d_resistance: (presses, K, 3) d R_c / d(x_mm, y_mm, depth_mm) in ohm per mm (0 for padding).
    baseline_pair_ohm: (J, J) unpressed equivalent resistance between candidate junctions.
    pressed_drop: (presses, K, J) unpressed-state drops dV_K (for the pressed R_eq by Woodbury).
    delta_g: (presses, K) conductance change of each touched channel.
    """

    junctions: np.ndarray
    weights: np.ndarray
    conductance_s: np.ndarray
    d_resistance: np.ndarray
    baseline_pair_ohm: np.ndarray
    unpressed_drop: np.ndarray
    delta_g: np.ndarray

    @property
    def n_presses(self) -> int:
        return int(self.weights.shape[0])

    def pair_jacobian(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """d R_ab / d(x, y, depth) for index arrays a, b into `junctions` (broadcast together): (presses, *ab, 3)."""
        a, b = np.broadcast_arrays(np.asarray(a), np.asarray(b))
        drop = self.weights[:, :, a] - self.weights[:, :, b]  # (n, K, *ab)
        extra = (None,) * a.ndim
        current2 = (drop * self.conductance_s[(..., *extra)]) ** 2
        return np.einsum("nk...,nkt->n...t", current2, self.d_resistance)

    def pressed_pair_ohm(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Pressed R_ab (presses, *ab): R0 - sum_K dg_k dV_k dV_k' (exact Woodbury); inf where a press cuts a pair."""
        a, b = np.broadcast_arrays(np.asarray(a), np.asarray(b))
        extra = (None,) * a.ndim
        before = self.unpressed_drop[:, :, a] - self.unpressed_drop[:, :, b]
        after = self.weights[:, :, a] - self.weights[:, :, b]
        change = np.einsum("nk...,nk...->n...", self.delta_g[(..., *extra)] * before, after)
        pressed = self.baseline_pair_ohm[a, b][None] - change
        return np.where(np.isfinite(pressed) & (pressed > 0), pressed, np.inf)


def grounded_inverse(layout: Layout, conductance_s: np.ndarray | None = None) -> np.ndarray:
    """Z: the inverse of the Laplacian grounded at junction 0 (row and column 0 are zero), (junctions, junctions)."""
    n = layout.n_junctions
    if n > DENSE_MAX_JUNCTIONS:
        raise ValueError(
            f"layout '{layout.name}' has {n} junctions; the design study's dense solve stops at "
            f"{DENSE_MAX_JUNCTIONS} (use a coarser grid)"
        )
    g = 1.0 / layout.channel_resistance_ohm if conductance_s is None else np.asarray(conductance_s, float)
    a, b = layout.channel_ends[:, 0], layout.channel_ends[:, 1]
    lap = np.zeros((n, n))
    np.add.at(lap, (a, b), -g)
    np.add.at(lap, (b, a), -g)
    np.add.at(lap, (a, a), g)
    np.add.at(lap, (b, b), g)
    z = np.zeros((n, n))
    z[1:, 1:] = np.linalg.inv(lap[1:, 1:])
    return z


@dataclass(frozen=True)
class ChannelSubset:
    """The part of a layout the deformation model reads (geometry of some channels, skin thickness and channel
    depth): the channels within reach of one tile of presses, so a big grid costs presses x nearby channels."""

    xy_mm: np.ndarray
    channel_ends: np.ndarray
    thickness_mm: float
    channel_depth_mm: float

    @property
    def n_channels(self) -> int:
        return int(self.channel_ends.shape[0])


def channel_factors(
    layout: Layout | ChannelSubset,
    x_mm: np.ndarray,
    y_mm: np.ndarray,
    depth_mm: np.ndarray,
    probe_radius_mm: float,
    fidelity: str = "network",
    pinch: PinchParams = PinchParams(),
) -> np.ndarray:
    """R_c / R0_c at the press and at +-step in x, y and depth: (7, presses, channels), stencil order
    (centre, +x, -x, +y, -y, +depth, -depth)."""
    if fidelity not in FIDELITIES:
        raise ValueError(f"fidelity must be one of {FIDELITIES}, got {fidelity!r}")
    factor = nearest_point_factor if fidelity == "network" else resistance_factor
    h = _STEP_MM
    dx = np.array([0.0, h, -h, 0.0, 0.0, 0.0, 0.0])
    dy = np.array([0.0, 0.0, 0.0, h, -h, 0.0, 0.0])
    dd = np.array([0.0, 0.0, 0.0, 0.0, 0.0, h, -h])
    n = x_mm.shape[0]
    xs = (x_mm[None] + dx[:, None]).ravel()
    ys = (y_mm[None] + dy[:, None]).ravel()
    ds = (depth_mm[None] + dd[:, None]).ravel()
    out = factor(layout, xs, ys, ds, probe_radius_mm, pinch)  # type: ignore[arg-type]  # duck-typed subset
    return out.reshape(7, n, layout.n_channels)


def reach_mm(layout: Layout, probe_radius_mm: float, depth_mm: float, pinch: PinchParams = PinchParams()) -> float:
    """Beyond this horizontal distance from the probe axis a channel's factor is exactly 1 (pinch < 1e-16)."""
    decay = pinch.decay_ratio * (layout.channel_depth_mm + depth_mm + _STEP_MM)
    return probe_radius_mm + 6.2 * decay + 1.0


def press_jacobian(
    layout: Layout,
    junctions: np.ndarray,
    x_mm: np.ndarray,
    y_mm: np.ndarray,
    depth_mm: float | np.ndarray,
    probe_radius_mm: float,
    fidelity: str = "network",
    z: np.ndarray | None = None,
    on_presses: Callable[[int], None] | None = None,
) -> PressJacobian:
    """The adjoint sensitivities of every press (x_mm, y_mm at depth_mm) for the candidate `junctions` (indices).

    Presses are processed in square tiles of about TILE_PRESSES presses, each against only the channels within
    reach of the tile, so the cost grows with presses x nearby channels, not presses x all channels."""
    x = np.asarray(x_mm, float).ravel()
    y = np.asarray(y_mm, float).ravel()
    depth = np.broadcast_to(np.asarray(depth_mm, float), x.shape).copy()
    junctions = np.asarray(junctions, dtype=np.intp)
    z = grounded_inverse(layout) if z is None else z
    ends = layout.channel_ends
    t_cand = z[ends[:, 0]][:, junctions] - z[ends[:, 1]][:, junctions]  # (C, J): B^T Z for the candidates
    z_jj = z[np.ix_(junctions, junctions)]
    diag = np.diag(z_jj)
    baseline = diag[:, None] + diag[None, :] - 2.0 * z_jj
    reach = reach_mm(layout, probe_radius_mm, float(depth.max(initial=0.0)))
    parts = []
    order = _tile_order(x, y)
    for tile in order:
        parts.append(_press_chunk(layout, z, t_cand, x[tile], y[tile], depth[tile], probe_radius_mm, fidelity, reach))
        if on_presses is not None:
            on_presses(int(tile.size))
    k_max = max(p[0].shape[1] for p in parts)
    padded = [tuple(_pad(arr, k_max) for arr in p) for p in parts]
    stacked = [np.concatenate(list(col)) for col in zip(*padded)]
    back = np.argsort(np.concatenate(order), kind="stable")
    weights, conductance, d_res, unpressed, delta_g = (arr[back] for arr in stacked)
    return PressJacobian(junctions, weights, conductance, d_res, baseline, unpressed, delta_g)


TILE_PRESSES = 64


def _tile_order(x: np.ndarray, y: np.ndarray) -> list[np.ndarray]:
    """Press indices grouped into square tiles of about TILE_PRESSES presses."""
    span_x, span_y = float(np.ptp(x)) + 1e-9, float(np.ptp(y)) + 1e-9
    side = max(np.sqrt(span_x * span_y * TILE_PRESSES / max(x.size, 1)), 1e-6)
    tx = np.floor((x - x.min()) / side).astype(np.int64)
    ty = np.floor((y - y.min()) / side).astype(np.int64)
    key = ty * (int(tx.max()) + 1) + tx
    order = np.argsort(key, kind="stable")
    cuts = np.flatnonzero(np.diff(key[order])) + 1
    return np.split(order, cuts)


def _pad(arr: np.ndarray, k: int) -> np.ndarray:
    if arr.shape[1] == k:
        return arr
    width = [(0, 0)] * arr.ndim
    width[1] = (0, k - arr.shape[1])
    return np.pad(arr, width)


def _nearby_channels(layout: Layout, x: np.ndarray, y: np.ndarray, reach: float) -> np.ndarray:
    """Channels whose bounding box comes within `reach` of the presses' bounding box."""
    xy = layout.xy_mm
    a, b = xy[layout.channel_ends[:, 0]], xy[layout.channel_ends[:, 1]]
    lo, hi = np.minimum(a, b), np.maximum(a, b)
    near = (lo[:, 0] <= x.max() + reach) & (hi[:, 0] >= x.min() - reach)
    near &= (lo[:, 1] <= y.max() + reach) & (hi[:, 1] >= y.min() - reach)
    return np.flatnonzero(near)


def _press_chunk(layout, z, t_cand, x, y, depth, probe_radius_mm, fidelity, reach):
    near = _nearby_channels(layout, x, y, reach)
    subset = ChannelSubset(layout.xy_mm, layout.channel_ends[near], layout.thickness_mm, layout.channel_depth_mm)
    f = channel_factors(subset, x, y, depth, probe_radius_mm, fidelity)
    touched = np.any(f != 1.0, axis=0)  # (n, near)
    k = max(1, int(touched.sum(axis=1).max()))
    local = np.argsort(~touched, axis=1, kind="stable")[:, :k]  # touched channels first
    live = np.take_along_axis(touched, local, axis=1)
    rows = np.arange(x.shape[0])[:, None]
    fk = f[:, rows, local]  # (7, n, k)
    order = near[local]  # global channel indices
    r0k = layout.channel_resistance_ohm[order]
    h = 2.0 * _STEP_MM
    with np.errstate(invalid="ignore"):
        d_res = np.stack([fk[1] - fk[2], fk[3] - fk[4], fk[5] - fk[6]], axis=-1) * (r0k / h)[..., None]
    d_res = np.where(live[..., None] & np.isfinite(d_res), d_res, 0.0)
    with np.errstate(divide="ignore"):
        g_pressed = np.where(live, 1.0 / (fk[0] * r0k), 1.0 / r0k)
    delta_g = np.where(live, g_pressed - 1.0 / r0k, 0.0)
    ends = layout.channel_ends
    u, v = ends[order, 0], ends[order, 1]  # (n, k)
    # M_kl = (e_u - e_v)^T Z (e_u' - e_v') for the touched channels of each press
    m = z[u[:, :, None], u[:, None, :]] - z[u[:, :, None], v[:, None, :]]
    m -= z[v[:, :, None], u[:, None, :]] - z[v[:, :, None], v[:, None, :]]
    system = np.eye(k)[None] + m * delta_g[:, None, :]
    unpressed = t_cand[order]  # (n, k, J)
    with np.errstate(all="ignore"):
        try:
            weights = np.linalg.solve(system, unpressed)
        except np.linalg.LinAlgError:
            weights = np.stack([_solve_or_nan(s, q) for s, q in zip(system, unpressed)])
    weights = np.where(np.isfinite(weights), weights, 0.0)  # a press that cuts the network: no information
    return weights, g_pressed * live, d_res, unpressed, delta_g


def _solve_or_nan(system: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    try:
        return np.linalg.solve(system, rhs)
    except np.linalg.LinAlgError:
        return np.full(rhs.shape, np.nan)
