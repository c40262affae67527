"""The "fe-kernel" deformation model: each channel's resistance R = rho integral ds / A(s) with A(s)/A0 read from
the finite-element pinch kernel (skin/kernel.py) at the horizontal distance from the probe axis to the point s.

Quasi-3D mapping (docs/skin.md, "Mechanics"): the point s of a channel at horizontal distance
r(s) = sqrt(perp^2 + (s - s0)^2) from the round probe's axis takes the kernel's A/A0 at offset r(s). Along the
channel the integral is the midpoint rule on `nodes` equal panels (tested against a 20x finer rule); a node with
A/A0 = 0 (shut) makes the channel's factor inf, its conductance 0, which the network solver takes on its exact path.

Cost: a dry-run press is one call with its few probe states, which share (x, y) and differ in depth. So the
geometry (r at every node of every channel in reach, and its place on the kernel's offset grid) is worked out once
per distinct (x, y), the kernel's depth interpolation once per state (a row over the tabulated offsets), and each
node is then one interpolation in its state's row (the same bilinear value as PinchKernel.ratio, tested to 1e-12).
"""

from __future__ import annotations

import numpy as np

from neatskin.layout import Layout
from neatskin.skin.kernel import PinchKernel

_CHUNK_PRESSES = 1024
NODES_PER_CHANNEL = 48


def kernel_factor_and_share(
    layout: Layout, kernel: PinchKernel, x_mm, y_mm, depth_mm, nodes: int = NODES_PER_CHANNEL
) -> tuple[np.ndarray, np.ndarray]:
    """(R / R0, share of the fluid volume displaced) of every channel for every press, each (presses, channels).
    R / R0 is 1 and the share 0 exactly where depth <= 0 or the channel is beyond the kernel's reach."""
    x, y, depth = np.broadcast_arrays(*(np.atleast_1d(np.asarray(v, float)) for v in (x_mm, y_mm, depth_mm)))
    x, y, depth = x.ravel(), y.ravel(), depth.ravel()
    xy = layout.xy_mm
    start = xy[layout.channel_ends[:, 0]]
    vec = xy[layout.channel_ends[:, 1]] - start
    length = np.hypot(vec[:, 0], vec[:, 1])
    unit = vec / length[:, None]
    frac = (np.arange(nodes) + 0.5) / nodes
    factor = np.ones((x.size, layout.n_channels))
    share = np.zeros((x.size, layout.n_channels))
    reach = float(kernel.offsets_mm[-1])
    for lo in range(0, x.size, _CHUNK_PRESSES):
        sl = slice(lo, lo + _CHUNK_PRESSES)
        pressed = depth[sl] > 0
        if not pressed.any():
            continue
        px, py, spot_of = _distinct_spots(x[sl], y[sl])
        rel_x, rel_y = px[:, None] - start[:, 0], py[:, None] - start[:, 1]
        s0 = rel_x * unit[:, 0] + rel_y * unit[:, 1]
        perp = rel_x * unit[:, 1] - rel_y * unit[:, 0]
        nearest = np.hypot(perp, np.maximum(np.maximum(-s0, s0 - length), 0.0))
        near = nearest < reach  # (spots, channels)
        live = near[spot_of] & pressed[:, None]
        if not live.any():
            continue
        spot, chan = np.nonzero(near)  # the (spot, channel) pairs in reach, numbered in this order
        along = frac[None, :] * length[chan, None] - s0[spot, chan][:, None]
        node_lo, node_w = kernel.offset_index(np.hypot(perp[spot, chan][:, None], along))
        rows = kernel.depth_rows(depth[sl])
        block_f, block_s = factor[sl], share[sl]
        if px.size == 1:  # one spot (a dry-run press's states): every pressed state at every near channel's nodes
            states = np.flatnonzero(pressed)
            # the means over (states, channels in reach, nodes), in place in scratch memory
            inverse, mean = kernel.lerp_rows_means(
                rows if states.size == rows.shape[0] else rows[states], node_lo, node_w
            )
            block_f[states[:, None], chan] = inverse
            block_s[states[:, None], chan] = 1.0 - mean
            continue
        pair_of = np.cumsum(near.ravel()).reshape(near.shape) - 1  # (spot, channel) -> its row in node_lo
        press, live_chan = np.nonzero(live)
        pair = pair_of[spot_of[press], live_chan]
        ratio = kernel.lerp_rows(rows, node_lo[pair], node_w[pair], press[:, None])
        with np.errstate(divide="ignore"):
            block_f[press, live_chan] = np.mean(1.0 / ratio, axis=1)
        block_s[press, live_chan] = 1.0 - np.mean(ratio, axis=1)
    return factor, share


def _distinct_spots(x: np.ndarray, y: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The distinct (x, y) of a block of presses and each press's index among them. A dry-run press's states all
    share one spot (the common case, checked first); a campaign's repeats share theirs."""
    if (x == x[0]).all() and (y == y[0]).all():
        return x[:1], y[:1], np.zeros(x.size, np.intp)
    spots, spot_of = np.unique(np.column_stack([x, y]), axis=0, return_inverse=True)
    return spots[:, 0], spots[:, 1], spot_of.ravel()
