"""The deformation model: how a flat probe pressed into the skin pinches each channel, and the
resulting channel resistance as the integral of rho / A(s) along the channel.

Model (documented with its parameters in docs/skin.md):

- The probe is a flat circular punch of radius a at (x, y), pressed to depth d into a skin of
  thickness T (layout.thickness_mm). A channel's centre line is the straight segment between its
  junctions; r(s) is the horizontal distance from the probe axis to the point s of that line.
- The channel keeps its width and loses the fraction p(r) of its height (A = w h (1 - p)):
      p(r) = p0                                  r <= a   (under the flat probe)
      p(r) = p0 * exp(-((r - a) / l)^2)          r >  a   (decay outside the probe edge)
      p0   = min(1, pinch_gain * d / T)          (uniform compression d / T of the layer, times a
                                                  gain for the void's extra compliance; 1 = shut)
      l    = decay_ratio * (c + d)               (c = layout.channel_depth_mm: the deformation
                                                  field spreads as it goes down, and with depth)
  p is C1 at the probe edge; a press to depth T / pinch_gain shuts the channels under the probe.
- Channel resistance R = rho / (w h) * integral ds / (1 - p(r(s))) = R0 * F with the factor
      F = (1 / L) * integral_0^L ds / (1 - p(r(s))).
  Under the probe the integrand is the constant 1 / (1 - p0): that part is exact. Outside it the
  integrand is analytic on each side of the probe footprint (split where the probe edge crosses
  the channel, or at its nearest point), so each side is cut into panels at 0.5 l and 2 l from
  the edge, up to where r - a = 6.1 l (beyond it p < 1e-16 and the stretch counts exactly its
  length); each panel gets Gauss-Legendre with `nodes_per_panel` nodes, and the error falls
  exponentially with the node count (table in docs/skin.md; held against QUADPACK in
  tests/test_skin_deformation.py, against a 64-node reference in benchmarks/bench_skin.py).
  A side whose pinch peaks above 0.9 (near full depth, under or right by the probe) gets graded
  panels instead (`_side_panels`).
  A channel pinched shut over any length has F = inf (conductance 0).

Everything is vectorised over presses x channels x nodes; presses are processed in chunks, and
only channel sides within reach of the pinch are integrated.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np

from neatskin.layout import Layout
from neatskin.skin.scratch import arrays

_CHUNK_PRESSES = 768
_NODE_BUFFER_MAX = 1 << 20  # float64 elements (8 MB): the integrand's batch, from the reused scratch block, at most
_CUTOFF_DECAYS = 6.1  # exp(-6.1^2) < 1e-16
_PANEL_EDGES = np.array([0.0, 0.5, 2.0, np.inf])  # side panels in decay lengths from the probe edge
# Near a full-depth press (p0 -> 1) the integrand 1 / (1 - p0 exp(-u^2)) is a peak of half-width
# w = sqrt((1 - p0) / p0) decay lengths at the footprint's edge: the first panel is then cut
# geometrically (ratio 1/3) towards the edge until its innermost panel is about w wide.
_GRADED_FROM_P0 = 0.9
_GRADING_RATIO = 2.0
_MAX_GRADING_LEVELS = 30
# where the channel only grazes the probe, r - a grows as s^2 / 2a and the peak spreads over the
# outer panels: near full depth they are halved too
_GRADED_OUTER_EDGES = np.array([0.5, 1.0, 1.5, 2.0, 3.0, np.inf])


@dataclass(frozen=True)
class PinchParams:
    """Parameters of the pinch profile p(r) and of its quadrature."""

    pinch_gain: float = 1.0
    decay_ratio: float = 0.5
    nodes_per_panel: int = 6

    def __post_init__(self) -> None:
        if not (np.isfinite(self.pinch_gain) and self.pinch_gain > 0):
            raise ValueError(f"pinch_gain must be a positive number, got {self.pinch_gain!r}")
        if not (np.isfinite(self.decay_ratio) and self.decay_ratio > 0):
            raise ValueError(f"decay_ratio must be a positive number, got {self.decay_ratio!r}")
        if not (isinstance(self.nodes_per_panel, int) and 1 <= self.nodes_per_panel <= 200):
            raise ValueError(f"nodes_per_panel must be an integer in 1..200, got {self.nodes_per_panel!r}")


def pinch_fraction(
    r_mm,
    depth_mm,
    probe_radius_mm: float | np.ndarray,
    thickness_mm: float,
    channel_depth_mm: float,
    params: PinchParams = PinchParams(),
) -> np.ndarray:
    """Fraction of the channel height lost at horizontal distance r_mm from the probe axis (broadcasts)."""
    r_mm, depth_mm = np.asarray(r_mm, float), np.asarray(depth_mm, float)
    depth = np.maximum(depth_mm, 0.0)
    p0 = np.minimum(1.0, params.pinch_gain * depth / thickness_mm)
    decay_mm = params.decay_ratio * (channel_depth_mm + depth)
    outside = np.maximum(r_mm - probe_radius_mm, 0.0) / decay_mm
    return p0 * np.exp(-outside * outside)


def _channel_geometry(layout: Layout) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Start point (C, 2), unit direction (C, 2) and straight length (C,) of each channel's centre line."""
    xy = layout.xy_mm
    start = xy[layout.channel_ends[:, 0]]
    vec = xy[layout.channel_ends[:, 1]] - start
    length = np.hypot(vec[:, 0], vec[:, 1])
    return start, vec / length[:, None], length


@lru_cache(maxsize=64)
def _gauss_legendre(q: int) -> tuple[np.ndarray, np.ndarray]:
    x, w = np.polynomial.legendre.leggauss(q)
    return (x + 1.0) / 2.0, w / 2.0  # on [0, 1]


def resistance_factor(
    layout: Layout,
    x_mm,
    y_mm,
    depth_mm,
    probe_radius_mm,
    params: PinchParams = PinchParams(),
    pinch_scale: np.ndarray | None = None,
) -> np.ndarray:
    """R / R0 of every channel for every press, shape (presses, channels); 1 exactly where depth <= 0,
    inf where a channel is pinched shut. Inputs are arrays of shape (presses,) or scalars.

    pinch_scale (channels,): multiplies each channel's pinch fraction (capped at shut). A channel of
    relative height h loses the same absolute height as a nominal one, so its scale is 1 / h;
    None = every channel at the layout's height."""
    return _integrate(layout, x_mm, y_mm, depth_mm, probe_radius_mm, params, pinch_scale, volume=False)


def pinched_length_fraction(
    layout: Layout,
    x_mm,
    y_mm,
    depth_mm,
    probe_radius_mm,
    params: PinchParams = PinchParams(),
    pinch_scale: np.ndarray | None = None,
) -> np.ndarray:
    """(1 / L) integral of p(r(s)) ds along every channel, (presses, channels): the share of each
    channel's fluid volume the press displaces (same quadrature as `resistance_factor`)."""
    return _integrate(layout, x_mm, y_mm, depth_mm, probe_radius_mm, params, pinch_scale, volume=True)


def factor_and_length_fraction(
    layout: Layout,
    x_mm,
    y_mm,
    depth_mm,
    probe_radius_mm,
    params: PinchParams = PinchParams(),
    pinch_scale: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """`resistance_factor` and `pinched_length_fraction` of the same presses from one pass of the quadrature
    (the same nodes and operations up to the integrand's last step, so the same bits as the two calls)."""
    both = _integrate(layout, x_mm, y_mm, depth_mm, probe_radius_mm, params, pinch_scale, volume=None)
    return both[0], both[1]


def _integrate(layout, x_mm, y_mm, depth_mm, probe_radius_mm, params, pinch_scale, *, volume):
    """(presses, channels) of the factor (volume False), the length fraction (True), or both stacked (None)."""
    x, y, depth, radius = np.broadcast_arrays(
        *(np.atleast_1d(np.asarray(v, float)) for v in (x_mm, y_mm, depth_mm, probe_radius_mm))
    )
    scale = None if pinch_scale is None else np.asarray(pinch_scale, float).reshape(1, layout.n_channels)
    out = np.empty((x.shape[0], layout.n_channels) if volume is not None else (2, x.shape[0], layout.n_channels))
    untouched = ~(depth > 0)  # exactly 1 (no volume) without the quadrature (NaN too): `_factor_chunk` sets the same
    if volume is None:
        out[0, untouched], out[1, untouched] = 1.0, 0.0
    else:
        out[untouched] = 0.0 if volume else 1.0
    # the chunks are modelgrad.factor_and_gradient's (the graded panels depend on a chunk's highest side peak)
    for sl in _press_chunks(~untouched):
        out[..., sl, :] = _factor_chunk(layout, x[sl], y[sl], depth[sl], radius[sl], params, scale, volume)
    return out


def _graded_edges(peak: np.ndarray) -> np.ndarray:
    """Panel edges (in decay lengths) for the sides whose pinch peaks above _GRADED_FROM_P0: the standard ones, with
    the first panel cut geometrically towards the side's start down to the highest peak's half-width."""
    if peak.size == 0:
        return _PANEL_EDGES
    width = np.sqrt(max(1.0 - float(peak.max()), 1e-300) / float(peak.max()))
    levels = int(np.clip(np.ceil(np.log(_PANEL_EDGES[1] / width) / np.log(_GRADING_RATIO)), 1, _MAX_GRADING_LEVELS))
    graded = _PANEL_EDGES[1] * _GRADING_RATIO ** -np.arange(levels, 0, -1.0)
    return np.concatenate([[0.0], graded, _GRADED_OUTER_EDGES])


def _press_chunks(touching: np.ndarray) -> list[np.ndarray]:
    """The touching presses' indices in chunks of _CHUNK_PRESSES: one chunking for the value (here) and the
    gradient (modelgrad), as a chunk's graded panels depend on its highest side peak."""
    idx = np.flatnonzero(touching)
    return [idx[lo : lo + _CHUNK_PRESSES] for lo in range(0, idx.size, _CHUNK_PRESSES)]


def _footprint_sides(x, y, a, decay, start, unit, length):
    """Per (press, channel), (n, C): the probe axis' offset across the channel's centre line (perp) and its square,
    the footprint's length on the line (foot), and (n, C, 2) per side outside the footprint: the distance from the
    axis' foot s0 to the footprint's edge (base), the side's length (side_len) and the stretch beyond the edge still
    to integrate (active).

    The two sides outside the footprint are integrated as panels from the edge (`_side_panels`); only (s - s0)^2
    enters, and on side k, s - s0 = sign_k * (base_k + offset). Beyond r = a + CUTOFF * l the pinch is below 1e-16:
    that stretch is exactly its length, so `active` stops there. Shared by the resistance integral and its analytic
    gradient (modelgrad), so both integrate the same panels."""
    rel_x, rel_y = x[:, None] - start[:, 0], y[:, None] - start[:, 1]  # (n, C)
    s0 = rel_x * unit[:, 0] + rel_y * unit[:, 1]
    perp = rel_x * unit[:, 1] - rel_y * unit[:, 0]
    perp2 = perp * perp
    half_chord = np.sqrt(np.maximum(a * a - perp2, 0.0))
    foot_lo = np.clip(s0 - half_chord, 0.0, length)
    foot_hi = np.clip(s0 + half_chord, 0.0, length)
    base = np.stack([foot_hi - s0, s0 - foot_lo], axis=-1)  # (n, C, 2): footprint edge to s0 distance
    side_len = np.stack([length - foot_hi, foot_lo], axis=-1)
    reach = np.sqrt(np.maximum((a + _CUTOFF_DECAYS * decay) ** 2 - perp2, 0.0)) - half_chord
    active = np.minimum(np.maximum(reach, 0.0)[..., None], side_len)  # (n, C, 2)
    return perp, perp2, foot_hi - foot_lo, base, side_len, active


def _side_panels(perp2, base, active, a, decay, p0, max_nodes):
    """The live sides (active > 0) of a chunk and their panels, in batches of at most `max_nodes` panels x sides:
    tuples (live, side_of, press_of, width, begin) of the flat side indices, their (press, channel) and press
    indices, and the panels' widths and starts (panels, m) along the side from s0.

    A side's integrand 1 / (1 - P) peaks where it starts (tau = base, the point nearest the probe axis) at
    P_max = p0 exp(-((r_min - a)^+ / l)^2). In u = (r - a) / l its nearest singularity (p0 exp(-u^2) = 1) lies
    sqrt(u_min^2 - ln p0) = sqrt(-ln P_max) from u_min: a side with P_max <= _GRADED_FROM_P0 is no sharper than a
    press of the standard panels' range (p0 <= 0.9) and gets them; the others get `_graded_edges`, graded by the
    chunk's highest peak. Only the 2-4 sides under or right by a deep probe are graded, not all 20-odd live ones."""
    live = np.flatnonzero(active > 0)
    side_of = live >> 1  # flat (press, channel) index of each live side
    press_of = side_of // active.shape[1]
    per_side = lambda v: _per_side(v, press_of, side_of)  # noqa: E731
    side_base = base.reshape(-1)[live]
    side_decay = per_side(decay)
    graded = np.zeros(live.size, dtype=bool)
    peak = np.zeros(0)
    if np.max(p0, initial=0.0) > _GRADED_FROM_P0:  # P_max <= p0: only a deep chunk has sides to grade
        deep = np.flatnonzero(per_side(p0) > _GRADED_FROM_P0)
        lift = np.sqrt(side_base[deep] * side_base[deep] + perp2.reshape(-1)[side_of[deep]])  # r_min
        lift -= per_side(a)[deep] if np.ndim(a) else a
        np.maximum(lift, 0.0, out=lift)
        lift /= side_decay[deep]
        peak = per_side(p0)[deep] * np.exp(-lift * lift)
        graded[deep] = peak > _GRADED_FROM_P0
        peak = peak[peak > _GRADED_FROM_P0]
    batches = []
    groups: list[tuple[np.ndarray | None, np.ndarray]] = [(None, _PANEL_EDGES)]  # None: every live side
    if graded.any():
        groups = [(np.flatnonzero(~graded), _PANEL_EDGES), (np.flatnonzero(graded), _graded_edges(peak))]
    for sides, panel_edges in groups:
        count = live.size if sides is None else sides.size
        step = max(1, max_nodes // (panel_edges.size - 1))
        for lo in range(0, count, step):
            k = slice(lo, lo + step) if sides is None else sides[lo : lo + step]  # a slice: views, no gathering
            side_active = active.reshape(-1)[live[k]]
            edges = np.minimum(panel_edges[:, None] * side_decay[k], side_active)
            edges[-1] = side_active  # (panels + 1, m)
            width = edges[1:] - edges[:-1]
            batches.append((live[k], side_of[k], press_of[k], width, side_base[k] + edges[:-1]))
    return batches


def _factor_chunk(layout, x, y, depth, radius, params, scale=None, volume=False):
    """(n, C) of the factor (volume False), the length share (True) or both stacked (None) of one chunk: the
    standard panels, graded ones on the sides peaking above _GRADED_FROM_P0 (`_side_panels`)."""
    start, unit, length = _channel_geometry(layout)
    thickness, cdepth = layout.thickness_mm, layout.channel_depth_mm
    touching = depth > 0
    d = np.where(touching, depth, 0.0)[:, None]
    a = radius[:, None]
    p0 = params.pinch_gain * d / thickness  # (n, 1), or (n, C) with a per-channel height
    p0 = np.minimum(1.0, p0 if scale is None else p0 * scale)
    decay = params.decay_ratio * (cdepth + d)
    _, perp2, foot, base, side_len, active = _footprint_sides(x, y, a, decay, start, unit, length)
    nodes, weights = _gauss_legendre(params.nodes_per_panel)
    sums = np.zeros((2, active.size))  # per side: the factor's integral, the length share's
    # only the sides with something left to integrate (far channels have none), laid out as (q, panels, sides) so
    # every broadcast operand is a contiguous block; each live side's press and channel quantities are gathered by
    # index (the values a broadcast to (n, C, 2) would hold)
    max_nodes = _NODE_BUFFER_MAX // nodes.size
    for live, side_of, press_of, width, begin in _side_panels(perp2, base, active, a, decay, p0, max_nodes):
        r = _minus_pinch(nodes, width, begin, perp2, a, decay, p0, side_of, press_of)
        if volume is not False:
            sums[1, live] = _node_sums(True, r, weights, width)  # leaves p in r
            np.negative(r, out=r)  # -p again, exactly
        if volume is not True:
            sums[0, live] = _node_sums(False, r, weights, width)
    parts = (foot, p0, active, side_len, length, touching)
    if volume is not None:
        return _finish_chunk(bool(volume), sums[int(volume)], *parts)
    return np.stack([_finish_chunk(False, sums[0], *parts), _finish_chunk(True, sums[1], *parts)])


def _per_side(v, press_of, side_of):
    """A press's (n, 1) or a (press, channel)'s (n, C) quantity at each live side (a scalar as it is): the value a
    broadcast to (n, C, 2) would hold there."""
    return v if np.ndim(v) == 0 else v.reshape(-1)[press_of if v.shape[-1] == 1 else side_of]


def _minus_pinch(nodes, width, begin, perp2, a, decay, p0, side_of, press_of):
    """-p at every node, (q, panels, m), in the thread's scratch block (skin/scratch.py: a fresh array's page faults
    cost as much as the arithmetic over a dry-run press's few hundred states, 0.53 -> 0.38 ms for 204 states)."""
    (r,) = arrays((nodes.size, *width.shape))
    np.multiply(nodes[:, None, None], width, out=r)
    # in place from here: one pass per operation
    r += begin
    np.multiply(r, r, out=r)
    r += perp2.reshape(-1)[side_of]
    np.sqrt(r, out=r)
    r -= _per_side(a, press_of, side_of)
    np.multiply(r, r, out=r)  # outside the footprint r >= a, so this is (r - a)^2
    r *= _per_side(-1.0 / (decay * decay), press_of, side_of)
    np.exp(r, out=r)
    r *= _per_side(-p0, press_of, side_of)  # -p
    return r


def _node_sums(volume, r, weights, width):
    """Each side's integral of p (volume) or of 1 / (1 - p), from r: (q, panels, m) of -p (used in place)."""
    if volume:
        np.negative(r, out=r)
    else:
        r += 1.0
        with np.errstate(divide="ignore"):
            np.reciprocal(r, out=r)
    # np.tensordot(weights, r, axes=(0, 0)) is this one dot of (1, q) by (q, panels * m), without its reshaping
    nodes_sum = np.dot(weights[None, :], r.reshape(r.shape[0], -1)).reshape(width.shape)
    return np.sum(nodes_sum * width, axis=0)


def _finish_chunk(volume, side_integral, foot, p0, active, side_len, length, touching):
    """R / R0 (volume False) or the length share (True) of each (press, channel) from its sides' integrals."""
    if volume:
        inner = foot * p0  # exact: p = p0 under the probe
    else:
        with np.errstate(divide="ignore", invalid="ignore"):
            inner = np.where(foot > 0, foot / (1.0 - p0), 0.0)
    beyond = 0.0 if volume else side_len - active  # past the reach p < 1e-16: exactly its length (or no volume)
    outer = np.sum(side_integral.reshape(active.shape) + beyond, axis=-1)
    factor = (inner + outer) / length
    factor[~touching] = 0.0 if volume else 1.0
    return factor


def nearest_point_factor(
    layout: Layout,
    x_mm,
    y_mm,
    depth_mm,
    probe_radius_mm,
    params: PinchParams = PinchParams(),
    pinch_scale: np.ndarray | None = None,
) -> np.ndarray:
    """Closed-form stand-in for resistance_factor (the "network" fidelity): the pinch at the channel
    point nearest the probe axis, applied over the probe's footprint (one diameter, at most the
    channel length): F = 1 + (min(2a, L) / L) * (1 / (1 - p(r_min)) - 1). Shape (presses, channels)."""
    x, y, depth, radius = np.broadcast_arrays(
        *(np.atleast_1d(np.asarray(v, float)) for v in (x_mm, y_mm, depth_mm, probe_radius_mm))
    )
    start, unit, length = _channel_geometry(layout)
    rel_x, rel_y = x[:, None] - start[:, 0], y[:, None] - start[:, 1]
    s0 = np.clip(rel_x * unit[:, 0] + rel_y * unit[:, 1], 0.0, length)
    r_min = np.hypot(rel_x - s0 * unit[:, 0], rel_y - s0 * unit[:, 1])
    p = pinch_fraction(r_min, depth[:, None], radius[:, None], layout.thickness_mm, layout.channel_depth_mm, params)
    if pinch_scale is not None:  # same absolute height lost: p / h, capped at shut (p0 = 1)
        p0 = np.minimum(1.0, params.pinch_gain * np.maximum(depth, 0.0) / layout.thickness_mm)[:, None]
        with np.errstate(invalid="ignore", divide="ignore"):
            shape = np.where(p0 > 0, p / np.where(p0 > 0, p0, 1.0), 0.0)
        p = np.minimum(1.0, p0 * np.asarray(pinch_scale, float)[None, :]) * shape
    share = np.minimum(2.0 * radius[:, None], length) / length
    with np.errstate(divide="ignore"):
        factor = 1.0 + share * (1.0 / (1.0 - p) - 1.0)
    factor[depth <= 0] = 1.0
    return factor
