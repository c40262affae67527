"""One channel's resistance changed at a time: the change of every pair's R_eq by rank-one (Sherman-Morrison) updates
of one grounded inverse, the paper's sensitivity simulation (skin.maps.paper_sensitivity), exact on stiff inputs
through network.equivalent_resistance's full solve; and the grounded bases the skin's analytic Jacobian shares."""

from __future__ import annotations

import functools
import math
from collections.abc import Callable

import numpy as np

from neatskin.layout import Layout
from neatskin.skin.layoutcache import LayoutCache, per_layout
from neatskin.skin.network import (
    DENSE_MAX_JUNCTIONS,
    GROUNDED_MAX_SPREAD,
    STIFF_DENSE_MAX_JUNCTIONS,
    equivalent_resistance,
)

# ---- one channel at a time: rank-one updates of one grounded inverse ----------------------


def channel_change_delta_ohm(layout: Layout, conductance_s: np.ndarray, resistance_factor: float) -> np.ndarray:
    """dR_eq (ohm) of every pair when each channel's resistance alone is multiplied by resistance_factor,
    (channels, pairs): the paper's sensitivity simulation (each channel +50 % in turn: factor 1.5).

    Changing one channel's conductance by dg is a rank-one change of the Laplacian, so by Sherman-Morrison
        R'_ab - R_ab = -dg (b_c^T Z p_ab)^2 / (1 + dg b_c^T Z b_c)  =  (b_c^T Z p_ab)^2 / (-1/dg - b_c^T Z b_c)
    with Z the grounded inverse of the unchanged Laplacian, b_c the channel's incidence vector, p_ab = e_a - e_b and
    -1/dg = R_c f / (f - 1): one Cholesky solve and one product for every channel and pair at once, and the change
    itself, not the difference of two resistances (no cancellation). Used where the grounded path is (every
    conductance > 0 and within GROUNDED_MAX_SPREAD of the others: relative error ~1e-15, tested against exact
    rationals); anything stiffer (conductances 1e12 apart, a channel shut) takes the GTH full solve of the
    channels + 1 states, which is exact to a few ulps of each R_eq. A pair cut apart before and after gets 0 (the
    change does not connect it), never NaN.
    """
    g = np.asarray(conductance_s, dtype=float)
    rank_one = _checked_route(layout, g)
    if not (math.isfinite(resistance_factor) and resistance_factor > 0):
        raise ValueError(f"resistance_factor must be finite and > 0, got {resistance_factor!r}")
    if rank_one is None:
        return _channel_change_full_solve(layout, g, resistance_factor)
    return _rank_one_change(layout, rank_one, g, resistance_factor)


def undeformed_channel_change_delta_ohm(layout: Layout, resistance_factor: float) -> np.ndarray:
    """channel_change_delta_ohm at the layout's own channel conductances, 1 / Layout.channel_resistance_ohm (the
    paper's simulation, maps.paper_sensitivity), the same bits. Those conductances, their check and the path they
    take depend on the layout alone, so they are worked out once per layout object; the solve is done every call."""
    entry = _UNDEFORMED.get(id(layout))  # per_layout's hit path inlined: the paper map's entry point, a call saved
    g, rank_one = entry[1] if entry and entry[0]() is layout else per_layout(_UNDEFORMED, layout, _undeformed_route)
    if not (math.isfinite(resistance_factor) and resistance_factor > 0):
        raise ValueError(f"resistance_factor must be finite and > 0, got {resistance_factor!r}")
    if rank_one is None:
        return _channel_change_full_solve(layout, g, resistance_factor)
    return _rank_one_change(layout, rank_one, g, resistance_factor)


_RankOne = tuple[np.ndarray, tuple[int, int], Callable[..., tuple], np.ndarray, np.ndarray, int, slice]


def _checked_route(layout: Layout, g: np.ndarray) -> _RankOne | None:
    """Refuses g unless it holds (channels,) finite values >= 0; the rank-one structure where g may take the
    rank-one path (every conductance > 0, within GROUNDED_MAX_SPREAD, at most DENSE_MAX_JUNCTIONS junctions), else
    None: the full solve."""
    n_channels, rank_one = per_layout(_INCIDENCE, layout, _rank_one_structure)  # Layout.n_channels is a property
    # the checks on a dozen Python floats (numpy's min and max cost microseconds each, a map costs a few more):
    # one sort gives both ends, in half the time of min() and max(); a NaN leaves the order undefined, but the sum
    # is then NaN too, and refused
    values = g.tolist() if g.shape == (n_channels,) else [math.nan]
    values.sort()
    g_min, g_max, total = values[0], values[-1], sum(values)
    if not (g_min >= 0 and g_max < math.inf and total == total):
        raise ValueError(f"conductance_s must be ({n_channels},) finite values >= 0, got shape {g.shape}")
    return rank_one if g_min > 0 and g_max <= GROUNDED_MAX_SPREAD * g_min else None


def _undeformed_route(layout: Layout) -> tuple[np.ndarray, _RankOne | None]:
    g = np.reciprocal(layout.channel_resistance_ohm)
    g.flags.writeable = False
    return g, _checked_route(layout, g)


@functools.lru_cache(maxsize=16)
def _as_0d(value: float) -> np.ndarray:
    """value as a read-only 0-d array: numpy divides by an array operand on its fast path, by a Python float through
    its scalar promotion (+60 % on a dozen elements). Memoised: the factor repeats (1.5 for every paper map)."""
    array = np.array(value)
    array.flags.writeable = False
    return array


def _rank_one_change(layout: Layout, rank_one: _RankOne, g: np.ndarray, resistance_factor: float) -> np.ndarray:
    """The rank-one path of channel_change_delta_ohm, on a checked g."""
    lap_map, free_shape, posv, incidence, basis, row_length, pair_columns = rank_one
    # the grounded Laplacian sum_c g_c b_c b_c^T, symmetric: its transpose is the Fortran-ordered array LAPACK
    # factors in place (a temporary), so no copy is made. The array methods, not np.dot and @ (their dispatch
    # costs more than these small products); posv's flags positional (lower=0, overwrite_a=1): f2py parses
    # keywords slower than LAPACK factors the matrix
    _, z_b, info = posv(lap_map.dot(g).reshape(free_shape).T, incidence, 0, 1)  # Z b_c
    if info != 0:  # not positive definite: cannot happen on a connected layout within the spread, but never guess
        return _channel_change_full_solve(layout, g, resistance_factor)
    # (channels, channels + pairs): b_c^T Z b_d, then b_c^T Z p_ab, one row per channel. z_b^T times the basis
    # rather than basis^T times z_b: the same bits (every column of the basis has at most two entries, +-1, so each
    # entry is one exact difference whatever the summation order), in fewer instructions of OpenBLAS's dgemm
    gram = z_b.T.dot(basis)
    f = resistance_factor
    scale = f / (f - 1.0) if f != 1.0 else math.inf  # f = 1: an infinite denominator, a change of exactly 0
    denominator = _as_0d(scale) / g
    denominator -= gram.diagonal()  # R_c f / (f - 1) - b_c^T Z b_c: > R_c / (f - 1) > 0 when f > 1
    # squared and divided in place on the product's own array, whole and flat: numpy's fast path takes 1-D
    # operands of one length, so each channel's denominator is repeated along its row (one C call) rather than
    # broadcast down a column (numpy's general iterator, with buffering: three times the cost of the division)
    flat = gram.ravel()  # a view: the product is C-contiguous
    flat *= flat
    flat /= denominator.repeat(row_length)
    return gram[:, pair_columns]


def _channel_change_full_solve(layout: Layout, g: np.ndarray, resistance_factor: float) -> np.ndarray:
    """channel_change_delta_ohm by the GTH full solve of the channels + 1 states: exact on stiff inputs."""
    dg = g * (1.0 / resistance_factor - 1.0)
    states = np.tile(g, (layout.n_channels + 1, 1))
    states[np.arange(1, layout.n_channels + 1), np.arange(layout.n_channels)] += dg
    method = "dense" if layout.n_junctions <= STIFF_DENSE_MAX_JUNCTIONS else "auto"
    r_eq = equivalent_resistance(layout, states, method)
    with np.errstate(invalid="ignore"):
        delta = r_eq[1:] - r_eq[0]
    return np.where(np.isinf(r_eq[1:]) & np.isinf(r_eq[0]), 0.0, delta)


# per layout object (layoutcache.per_layout): its channel count, and what the rank-one path needs that depends on
# the layout alone (None above DENSE_MAX_JUNCTIONS junctions, where the full solve is used)
_INCIDENCE: LayoutCache[tuple[int, _RankOne | None]] = {}
# per layout object: its own (undeformed) channel conductances, read only, and the path they take
_UNDEFORMED: LayoutCache[tuple[np.ndarray, _RankOne | None]] = {}


def grounded_bases(layout: Layout) -> tuple[np.ndarray, np.ndarray]:
    """The channel incidence vectors b_c (junctions - 1, channels) and the pair vectors e_a - e_b (junctions - 1,
    pairs), the first electrode's row dropped (grounded): the rank-one path's and the skin's analytic Jacobian's
    (modelgrad) bases."""
    n = layout.n_junctions
    ends = layout.channel_ends
    incidence = np.zeros((n, layout.n_channels))
    incidence[ends[:, 0], np.arange(layout.n_channels)] = 1.0
    incidence[ends[:, 1], np.arange(layout.n_channels)] = -1.0
    elec = layout.electrode_junctions
    pairs = np.zeros((n, len(layout.pairs)))
    pairs[elec[layout.pair_electrode_index[:, 0]], np.arange(len(layout.pairs))] = 1.0
    pairs[elec[layout.pair_electrode_index[:, 1]], np.arange(len(layout.pairs))] = -1.0
    free = np.arange(n) != int(elec[0])
    return incidence[free], pairs[free]


def _rank_one_structure(layout: Layout) -> tuple[int, _RankOne | None]:
    """The channel count, and (up to DENSE_MAX_JUNCTIONS junctions) over the junctions with the first electrode's
    grounded (its row dropped), read only: lap_map
    (free * free, channels) with lap_map @ g the grounded Laplacian, flat, and its shape (free, free); LAPACK's
    dposv (Cholesky factor and solve in one call: a few microseconds where numpy.linalg.solve spends ten in its
    wrappers; imported here, on first use, as scipy.linalg is not otherwise loaded by the skin); the channel
    incidence vectors b_c (free, channels, Fortran-ordered for LAPACK); the basis [b_c | e_a - e_b]
    (free, channels + pairs), its column count and the slice of its pair columns."""
    from scipy.linalg.lapack import dposv

    n = layout.n_junctions
    if n > DENSE_MAX_JUNCTIONS:
        return layout.n_channels, None
    incidence, pairs = grounded_bases(layout)
    lap_map = np.einsum("ic,jc->ijc", incidence, incidence).reshape(-1, layout.n_channels).copy()
    incidence_f = np.asfortranarray(incidence)
    basis = np.hstack([incidence, pairs])
    for array in (lap_map, incidence_f, basis):
        array.flags.writeable = False
    pair_columns = slice(layout.n_channels, None)
    return layout.n_channels, (lap_map, (n - 1, n - 1), dposv, incidence_f, basis, basis.shape[1], pair_columns)
