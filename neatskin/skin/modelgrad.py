"""The skin model's gradient in (x, y, depth): channel factors R / R0 and pair resistances with their derivatives.

For the physics inversion's Jacobian (issue 27): one pass gives the value and its gradient, where forward differences
take a model call per coordinate. The pinch's factor F = (1 / L) integral ds / (1 - p(r(s))) (`deformation.py`) is
differentiated under the integral sign: the points where the integral is split (the footprint's edges, the channel's
ends, the point nearest the probe) contribute nothing, as the integrand is continuous there (1 / (1 - p0) on both
sides of a footprint edge) or the point is fixed, so

    dF/dtheta = (1 / L) [foot dp0/dtheta / (1 - p0)^2 + integral over the sides of df/dtheta ds],
    df/dtheta = f^2 dP/dtheta,  P = p0 exp(-u^2),  u = (r - a) / l,  r^2 = (s - s0)^2 + perp^2,

on the value's own panels and nodes (`deformation._factor_chunk`'s). x and y move s0 and perp, depth moves p0 and the
decay length l. The network's part is Foster's: with Z the inverse of the Laplacian grounded at the first electrode,
dR_ab/dg_c = -(b_c' Z (e_a - e_b))^2 (the squared potential drop across channel c for a unit current from a to b),
and g_c = 1 / (R0_c F_c). Exact derivatives of the exact integral, computed by the value's quadrature: they agree
with central differences of the model to the quadrature's accuracy (tests/test_skin_modelgrad.py).

Supported: the parametric pinch with the "deformation" fidelity, any channel heights; rows with a channel shut
(p0 = 1, F = inf) get NaN gradients (the caller differences those).
"""

from __future__ import annotations

import numpy as np

from neatskin.layout import Layout
from neatskin.skin.channelchange import grounded_bases
from neatskin.skin.deformation import (
    PinchParams,
    _channel_geometry,
    _footprint_sides,
    _gauss_legendre,
    _per_side,
    _press_chunks,
    _side_panels,
)
from neatskin.skin.scratch import BLOCK_MAX as _BUFFER_MAX  # `_side_panels` batches a chunk's sides to fit
from neatskin.skin.scratch import arrays as _arrays
from neatskin.skin.scratch import buffers as _buffers  # temporaries reused per thread (scratch.py's reason)


def factor_and_gradient(
    layout: Layout,
    x_mm: np.ndarray,
    y_mm: np.ndarray,
    depth_mm: np.ndarray,
    probe_radius_mm: float,
    params: PinchParams = PinchParams(),
    pinch_scale: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """R / R0 of every channel (presses, channels) and its derivatives in (x, y, depth) (presses, channels, 3).

    The same chunks and panels as `deformation.resistance_factor` (the sides peaking above 0.9 graded by their chunk's
    highest peak), so the factor agrees with it to rounding. A press not touching (depth <= 0): 1 and 0."""
    # broadcast as deformation._integrate does: a scalar depth (or x, y) holds for every press
    x, y, depth = np.broadcast_arrays(*(np.atleast_1d(np.asarray(v, float)) for v in (x_mm, y_mm, depth_mm)))
    scale = None if pinch_scale is None else np.asarray(pinch_scale, float).reshape(1, layout.n_channels)
    factor = np.ones((x.size, layout.n_channels))
    grad = np.zeros((x.size, layout.n_channels, 3))
    for sl in _press_chunks(depth > 0):
        factor[sl], grad[sl] = _chunk(layout, x[sl], y[sl], depth[sl], probe_radius_mm, params, scale)
    return factor, grad


def _chunk(layout, x, y, depth, radius, params, scale):
    start, unit, length = _channel_geometry(layout)
    d = depth[:, None]
    raw = params.pinch_gain * d / layout.thickness_mm
    rate = np.full_like(raw, params.pinch_gain / layout.thickness_mm)  # dp0/d(depth)
    if scale is not None:
        raw, rate = raw * scale, rate * scale
    p0 = np.minimum(1.0, raw)  # (n, 1) or (n, C)
    rate = np.where(raw < 1.0, rate, 0.0)
    decay = params.decay_ratio * (layout.channel_depth_mm + d)  # (n, 1)
    perp, perp2, foot, base, side_len, active = _footprint_sides(x, y, radius, decay, start, unit, length)
    nodes, weights = _gauss_legendre(params.nodes_per_panel)
    side = np.zeros((5, active.size))
    for live, side_of, press_of, width, begin in _side_panels(
        perp2, base, active, radius, decay, p0, _BUFFER_MAX // (6 * nodes.size)
    ):
        side[:, live] = _side_sums(nodes, weights, width, begin, perp2, radius, decay, p0, side_of, press_of)
    side = side.reshape(5, *active.shape)  # (5, n, C, 2)
    with np.errstate(divide="ignore", invalid="ignore"):
        inner = np.where(foot > 0, foot / (1.0 - p0), 0.0)
        inner_d = np.where(foot > 0, foot * rate / (1.0 - p0) ** 2, 0.0)
        depth_rate = np.where(p0 > 0, rate / p0, 0.0)
    factor = (inner + np.sum(side[0] + (side_len - active), axis=-1)) / length
    two_over_l = (2.0 / decay)[..., None]  # (n, 1, 1)
    sign = np.array([1.0, -1.0])  # s - s0 = +tau on the far side, -tau on the near one
    ux, uy = unit[:, 0][None, :, None], unit[:, 1][None, :, None]
    pp = perp[..., None]
    with np.errstate(invalid="ignore"):  # a shut channel's sums are inf x 0: NaN, as its gradient is set below
        gx = two_over_l * (sign * ux * side[2] - pp * uy * side[1])
        gy = two_over_l * (sign * uy * side[2] + pp * ux * side[1])
        gd = depth_rate[..., None] * side[3] + params.decay_ratio * two_over_l * side[4]
        grad = np.stack([gx.sum(-1), gy.sum(-1), gd.sum(-1) + inner_d], axis=-1) / length[None, :, None]
    grad[~np.isfinite(factor)] = np.nan
    return factor, grad


def _side_sums(nodes, weights, width, begin, perp2, radius, decay, p0, side_of, press_of):
    """(5, m) per live side: the integrals of f, f^2 P u / r, f^2 P u tau / r, f^2 P and f^2 P u^2 over its panels."""
    shape = (nodes.size, *width.shape)
    # tau: distance from s0 along the channel; r: from the probe axis; u: (r - a) / l; then P, f and the sums
    tau, r, u, u2, big_p, f = _buffers(6, shape)
    np.multiply(nodes[:, None, None], width, out=tau)
    tau += begin
    np.multiply(tau, tau, out=r)
    r += perp2.reshape(-1)[side_of]
    np.sqrt(r, out=r)
    np.subtract(r, radius, out=u)
    u *= (1.0 / decay).reshape(-1)[press_of]
    np.multiply(u, u, out=u2)
    np.negative(u2, out=big_p)
    np.exp(big_p, out=big_p)
    big_p *= _per_side(p0, press_of, side_of)
    np.subtract(1.0, big_p, out=f)
    with np.errstate(divide="ignore"):
        np.reciprocal(f, out=f)
    sums = np.empty((5, width.shape[1]))
    flat = (nodes.size, -1)
    sums[0] = np.sum(np.dot(weights[None, :], f.reshape(flat)).reshape(width.shape) * width, axis=0)
    fp = np.multiply(f, f, out=f)  # f^2 P from here
    fp *= big_p
    a_term = np.multiply(fp, u, out=u)  # f^2 P u / r
    a_term /= r
    for k, values in enumerate((a_term, np.multiply(a_term, tau, out=tau), fp, np.multiply(fp, u2, out=u2))):
        sums[k + 1] = np.sum(np.dot(weights[None, :], values.reshape(flat)).reshape(shape[1:]) * width, axis=0)
    return sums


def pair_resistance_and_gradient(
    layout: Layout, factor: np.ndarray, factor_grad: np.ndarray, channel_baseline_ohm: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """R_eq of every pair (presses, pairs) and its gradient (presses, pairs, 3), from the channel factors and theirs.

    Z = the Laplacian's inverse, grounded at the first electrode; R_ab = (e_a - e_b)' Z (e_a - e_b) and
    dR_ab/dtheta = sum_c (b_c' Z (e_a - e_b))^2 g_c (dF_c/dtheta) / F_c. Rows with a channel shut (F inf) or a
    singular Laplacian: NaN."""
    incidence, pairs = grounded_bases(layout)
    with np.errstate(divide="ignore"):
        g = 1.0 / (factor * channel_baseline_ohm)  # (n, C)
    ok = np.all(np.isfinite(factor) & (g > 0), axis=1)
    r_eq = np.full((factor.shape[0], pairs.shape[1]), np.nan)
    jac = np.full((*r_eq.shape, 3), np.nan)
    for rows in _press_chunks(ok):  # chunks whose temporaries fit the reused block
        r_eq[rows], jac[rows] = _network_chunk(incidence, pairs, g[rows], factor[rows], factor_grad[rows])
    return r_eq, jac


def _network_chunk(incidence, pairs, g, factor, factor_grad):
    """R_eq (m, pairs) and its gradient (m, pairs, 3) of presses with every channel conducting. The temporaries are
    views of the reused block: fresh, their page faults cost as much as the arithmetic (measured 5.4 -> 2.5 us a
    row for 256 presses, the same bits)."""
    m, (free, n_pairs), n_channels = g.shape[0], pairs.shape, incidence.shape[1]
    scaled, lap, potentials, product, drop = _arrays(
        (m, free, n_channels), (m, free, free), (m, free, n_pairs), (m, free, n_pairs), (m, n_channels, n_pairs)
    )
    np.multiply(incidence, g[:, None, :], out=scaled)
    np.matmul(scaled, incidence.T, out=lap)  # (m, free, free)
    np.matmul(np.linalg.inv(lap), pairs, out=potentials)  # Z (e_a - e_b), (m, free, pairs)
    r_eq = np.sum(np.multiply(potentials, pairs, out=product), axis=1)
    np.matmul(incidence.T, potentials, out=drop)  # (m, C, pairs): the potential drop across each channel
    drop *= drop
    weight = g[:, :, None] * factor_grad / factor[:, :, None]  # (m, C, 3)
    return r_eq, np.matmul(drop.transpose(0, 2, 1), weight)
