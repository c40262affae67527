"""The "fe-kernel" deformation model: each channel's resistance R = rho integral ds / A(s) with A(s)/A0 read from
the finite-element pinch kernel (skin/kernel.py) at the horizontal distance from the probe axis to the point s.

Quasi-3D mapping (docs/skin.md, "Mechanics"): the kernel is a plane-strain solve of a strip probe at lateral
offset o from the channel axis; the point s of a channel at horizontal distance r(s) = sqrt(perp^2 + (s - s0)^2)
from the round probe's axis takes the kernel's A/A0 at offset r(s). Along the channel the integral is the midpoint
rule on `nodes` equal panels (tested against a 20x finer rule); a node with A/A0 = 0 (shut) makes the channel's
factor inf, its conductance 0, which the network solver takes on its exact path.
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
        rel_x, rel_y = x[sl, None] - start[:, 0], y[sl, None] - start[:, 1]
        s0 = rel_x * unit[:, 0] + rel_y * unit[:, 1]
        perp = rel_x * unit[:, 1] - rel_y * unit[:, 0]
        nearest = np.hypot(perp, np.maximum(np.maximum(-s0, s0 - length), 0.0))
        live = (nearest < reach) & (depth[sl, None] > 0)
        if not live.any():
            continue
        press, chan = np.nonzero(live)
        along = frac[None, :] * length[chan, None] - s0[press, chan][:, None]
        r = np.hypot(perp[press, chan][:, None], along)
        ratio = kernel.ratio(r, depth[sl][press][:, None])
        with np.errstate(divide="ignore"):
            f = np.mean(1.0 / ratio, axis=1)
        block_f, block_s = factor[sl], share[sl]
        block_f[press, chan] = f
        block_s[press, chan] = np.mean(1.0 - ratio, axis=1)
    return factor, share
