"""The network solver: equivalent resistance between every electrode pair for a batch of channel conductances.

Two paths, picked by size (`equivalent_resistance(..., method="auto")`):

- dense (small layouts, the paper's 9 junctions): Kron reduction of the weighted graph
  Laplacian by Gaussian elimination in the GTH form (Grassmann, Taksar, Heyman): the
  diagonal of the node being eliminated is recomputed as the sum of its remaining
  off-diagonal conductances instead of being updated by subtraction. Every operation is
  then an addition, product or quotient of non-negative numbers, so every reduced
  conductance carries a small *relative* error (a few ulps times the node count) however
  stiff the network is: conductances 1e12 apart, near-shorts, channels pinched to exactly
  zero. The effective resistance between electrodes a and b is 1 / (the conductance left
  between a and b once every other node is eliminated). All pairs share eliminations
  through a divide-and-conquer over the electrode set (within each half, then across the
  halves), vectorised over the batch of presses. A pair cut apart is left with exactly 0
  conductance and gets `inf`, never NaN.
- grounded (small batches of ordinary presses, the dry run's per-press call): the same Kron
  reduction onto the electrodes, then one batched inverse of the electrodes' Laplacian grounded
  at one electrode per connected group, R_ab = Z_aa + Z_bb - 2 Z_ab, `inf` across groups.
  A handful of numpy calls instead of the divide-and-conquer's dozens, so a press's few states
  cost a fraction of the GTH's per-call overhead. Used by "auto" when the non-zero conductances
  are within GROUNDED_MAX_SPREAD of each other; channels pinched to exactly 0 are welcome (the
  GTH reduction keeps their zeros exact, so they are simply absent; an electrode they cut off
  forms its own group). Relative error then ~1e-14, tested against the GTH path and exact
  rationals; anything stiffer stays on GTH.
- sparse (thousands of junctions): a grounded Laplacian solve per press with
  `scipy.sparse.linalg.splu`, one ground per connected component (`csgraph`: its best-connected electrode), unit
  currents injected at the electrodes; R_ab = Z_aa + Z_bb - 2 Z_ab. Accurate to the usual
  normwise backward error (fine for ordinary networks, not guaranteed relative accuracy on
  near-shorts); pairs in different components get `inf`.
"""

from __future__ import annotations

import math

import numpy as np

from neatskin.layout import Layout

DENSE_MAX_JUNCTIONS = 64
# Stiff inputs (conductances more than STIFF_SPREAD apart) stay on the exact dense path up to this size:
# the sparse LU loses about eps x spread (1.7e-3 with a 1e12 near-short on a 10 x 10 grid, against ngspice
# and a 60-digit reference), the dense GTH path keeps ~1e-15. Dense costs ~17 ms per press at 225 junctions.
STIFF_DENSE_MAX_JUNCTIONS = 256
STIFF_SPREAD = 1e6
GROUNDED_MAX_SPREAD = 1e3
GROUNDED_MAX_PRESSES = 256  # larger batches amortise the GTH's overhead and keep its relative accuracy
_DENSE_CHUNK_PRESSES = 4096
_DENSE_CHUNK_ELEMENTS = 4_000_000  # ~32 MB per (junctions, junctions, presses) work array


def equivalent_resistance(layout: Layout, conductance_s: np.ndarray, method: str = "auto") -> np.ndarray:
    """Equivalent resistance (ohm) for every pair of `layout.pairs`, per press.

    conductance_s: channel conductances in siemens, shape (presses, channels) or (channels,);
    finite and >= 0 (0 is a channel pinched shut). Returns (presses, pairs) (or (pairs,)),
    `inf` where a pair's electrodes are not connected through conducting channels.
    method: "auto" (dense up to DENSE_MAX_JUNCTIONS junctions, or up to STIFF_DENSE_MAX_JUNCTIONS when the
    conductances are more than STIFF_SPREAD apart; sparse above), "dense", "sparse", or "grounded" (one grounded
    solve per batch, fastest on small batches; "auto" takes it only for at most GROUNDED_MAX_PRESSES presses whose
    conductances lie within GROUNDED_MAX_SPREAD of each other: asked for on stiffer ones it loses accuracy, ~1e-4
    relative at 1e12 apart, where "dense" stays exact to ~1e-15).
    """
    g = np.asarray(conductance_s, dtype=float)
    single = g.ndim == 1
    g = np.atleast_2d(g)
    if g.ndim != 2 or g.shape[1] != layout.n_channels:
        raise ValueError(
            f"conductance_s must have shape (presses, {layout.n_channels}) for layout "
            f"'{layout.name}', got {np.shape(conductance_s)}"
        )
    if len(set(layout.electrode_junctions.tolist())) != layout.n_electrodes:
        raise ValueError(f"layout '{layout.name}' has two electrodes on one junction; give each its own junction")
    if not np.all(np.isfinite(g)) or np.any(g < 0):
        raise ValueError("conductance_s must be finite and >= 0 (0 = channel pinched shut)")
    if method == "auto":
        method = "dense" if layout.n_junctions <= DENSE_MAX_JUNCTIONS else "sparse"
        if method == "dense" and g.shape[0] <= GROUNDED_MAX_PRESSES and _spread(g) <= GROUNDED_MAX_SPREAD:
            method = "grounded"
        if method == "sparse" and layout.n_junctions <= STIFF_DENSE_MAX_JUNCTIONS and _spread(g) > STIFF_SPREAD:
            method = "dense"
    if method in ("dense", "grounded") and g.shape[0] == 1:
        # numpy sums a lone press's (nodes, 1) column pairwise but a batch's rows in sequence: solve the
        # lone press as a batch of two so that a press gets the same bits whatever batch it comes in
        return equivalent_resistance(layout, np.repeat(g, 2, axis=0), method)[0 if single else slice(0, 1)]
    if method == "dense":
        out = np.empty((g.shape[0], len(layout.pairs)))
        chunk = max(1, min(_DENSE_CHUNK_PRESSES, _DENSE_CHUNK_ELEMENTS // layout.n_junctions**2))
        for start in range(0, g.shape[0], chunk):
            stop = start + chunk
            out[start:stop] = _dense_chunk(layout, g[start:stop])
    elif method == "sparse":
        out = _sparse(layout, g)
    elif method == "grounded":
        out = _grounded(layout, g)
    else:
        raise ValueError(f"method must be 'auto', 'dense', 'grounded' or 'sparse', got {method!r}")
    return out[0] if single else out


def _spread(g: np.ndarray) -> float:
    """Ratio of the largest to the smallest non-zero conductance in the batch (1 when there are none)."""
    positive = g[g > 0]
    return float(positive.max() / positive.min()) if positive.size else 1.0


# ---- dense: GTH Kron reduction -----------------------------------------------------------


def _eliminate(w: np.ndarray, keep: list[int]) -> np.ndarray:
    """Schur complement of the Laplacian with off-diagonal conductances w (s, s, batch) onto `keep`.

    GTH form: the pivot is the sum of the node's remaining conductances (no subtraction).
    The diagonal of w is zero on entry and on exit. Returns (len(keep), len(keep), batch)
    in `keep` order.
    """
    order = keep + [k for k in range(w.shape[0]) if k not in keep]
    if order != list(range(w.shape[0])):
        w = w[np.ix_(order, order)]
    n_keep = len(keep)
    for s in range(w.shape[0] - 1, n_keep - 1, -1):
        row = w[s, :s]  # conductances from node s to the remaining nodes 0..s-1
        pivot = row.sum(axis=0)
        scaled = row / np.where(pivot > 0, pivot, 1.0)  # an isolated node adds nothing
        w = w[:s, :s] + row[:, None, :] * scaled[None, :, :]
        diag = np.arange(s)
        w[diag, diag] = 0.0
    return w


def _pair_conductances(w: np.ndarray, nodes: list[int], out: dict[tuple[int, int], np.ndarray]) -> None:
    """For every pair of `nodes` (w is over exactly these nodes), the conductance left between them."""
    if len(nodes) == 2:
        out[(nodes[0], nodes[1])] = w[0, 1]
        return
    half = len(nodes) // 2
    lo, hi = list(range(half)), list(range(half, len(nodes)))
    for part in (lo, hi):
        if len(part) >= 2:
            _pair_conductances(_eliminate(w, part), [nodes[k] for k in part], out)
    _cross_conductances(w, [nodes[k] for k in lo], [nodes[k] for k in hi], out)


def _cross_conductances(
    w: np.ndarray, a_nodes: list[int], b_nodes: list[int], out: dict[tuple[int, int], np.ndarray]
) -> None:
    """Pairs with one node in a_nodes and one in b_nodes; w is over a_nodes + b_nodes in that order."""
    if len(a_nodes) == 1 and len(b_nodes) == 1:
        out[(a_nodes[0], b_nodes[0])] = w[0, 1]
        return
    na = len(a_nodes)
    a_parts = _halves(list(range(na)))
    b_parts = _halves(list(range(na, na + len(b_nodes))))
    for ap in a_parts:
        for bp in b_parts:
            sub = _eliminate(w, ap + bp)
            _cross_conductances(sub, [a_nodes[k] for k in ap], [b_nodes[k - na] for k in bp], out)


def _halves(idx: list[int]) -> list[list[int]]:
    if len(idx) == 1:
        return [idx]
    half = len(idx) // 2
    return [idx[:half], idx[half:]]


def _dense_chunk(layout: Layout, g: np.ndarray) -> np.ndarray:
    n = layout.n_junctions
    ends = layout.channel_ends
    w = np.zeros((n, n, g.shape[0]))
    w[ends[:, 0], ends[:, 1]] = g.T
    w[ends[:, 1], ends[:, 0]] = g.T
    electrodes = [int(j) for j in layout.electrode_junctions]
    w = _eliminate(w, electrodes)  # Kron reduction onto the electrodes, in Layout.electrodes order
    conductance: dict[tuple[int, int], np.ndarray] = {}
    _pair_conductances(w, list(range(len(electrodes))), conductance)
    pair_g = np.stack(
        [
            conductance[(int(a), int(b))] if (int(a), int(b)) in conductance else conductance[(int(b), int(a))]
            for a, b in layout.pair_electrode_index
        ],
        axis=1,
    )
    with np.errstate(divide="ignore"):
        return 1.0 / pair_g


# ---- grounded: Kron reduction, then one batched inverse ----------------------------------


def _grounded(layout: Layout, g: np.ndarray) -> np.ndarray:
    """All pairs from the electrodes' Laplacian, grounded at the lowest electrode of each connected group."""
    n = layout.n_junctions
    electrodes = [int(j) for j in layout.electrode_junctions]
    # the junctions numbered electrodes first (in Layout.electrodes order), so the elimination needs no reordering
    order = electrodes + [j for j in range(n) if j not in electrodes]
    position = np.empty(n, dtype=np.intp)
    position[order] = np.arange(n)
    ends = position[layout.channel_ends]
    w = np.zeros((n, n, g.shape[0]))
    w[ends[:, 0], ends[:, 1]] = g.T
    w[ends[:, 1], ends[:, 0]] = g.T
    w = _eliminate(w, list(range(len(electrodes))))  # (k, k, presses), zero diagonal
    k = w.shape[0]
    # press-major and contiguous, so every press is computed the same way whatever the batch (bit for bit)
    lap = np.negative(w.transpose(2, 0, 1), out=np.empty((g.shape[0], k, k)))  # (presses, k, k)
    lap.reshape(-1, k * k)[:, :: k + 1] = -_row_sums(lap)  # the diagonal
    a, b = layout.pair_electrode_index[:, 0], layout.pair_electrode_index[:, 1]
    # Routed press by press (never by batch), so that a press gets the same bits whatever batch it comes in.
    # Every channel conducting: one group (Layout refuses a disconnected network), the plain grounding at electrode 0.
    one = np.all(g > 0, axis=1)
    if np.all(one):
        return _one_group(lap, a, b)
    root = np.zeros(lap.shape[:2], dtype=np.intp)
    root[~one] = _group_roots(lap[~one])
    one = np.all(root == 0, axis=1)  # channels shut, but every electrode still joined to electrode 0
    if np.all(one):
        return _one_group(lap, a, b)
    r = np.empty((lap.shape[0], a.size))
    if np.any(one):
        r[one] = _one_group(lap[one], a, b)
    r[~one] = _groups(lap[~one], root[~one], a, b)
    return r


def _row_sums(lap: np.ndarray) -> np.ndarray:
    """`lap.sum(axis=2)` with the same bits, in whole-column adds (numpy reduces each short contiguous row in its
    own inner-loop call, ~1,700 of them for a dry-run press). numpy's order: 0.0 plus the pairwise sum, which adds a
    row of fewer than 8 one after the other and a longer one (up to 128) in 8 interleaved partial sums, combined
    ((0+1)+(2+3))+((4+5)+(6+7)), then the rest of the 8s one after the other (tests/test_skin_network.py)."""
    k = lap.shape[2]
    if k > 128:
        return lap.sum(axis=2)
    column = lap.transpose(2, 0, 1)
    if k < 8:
        total = 0.0 + column[0]
        for j in range(1, k):
            total += column[j]
        return 0.0 + total
    partial = column[:8].copy()
    whole = k - k % 8
    for start in range(8, whole, 8):
        partial += column[start : start + 8]
    total = ((partial[0] + partial[1]) + (partial[2] + partial[3])) + (
        (partial[4] + partial[5]) + (partial[6] + partial[7])
    )
    for j in range(whole, k):
        total += column[j]
    return 0.0 + total


def _one_group(lap: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """R_ab from the electrodes' Laplacians (presses, k, k) of one connected group, grounded at electrode 0."""
    k = lap.shape[1]
    z = np.zeros_like(lap)
    z[:, 1:, 1:] = np.linalg.inv(np.ascontiguousarray(lap[:, 1:, 1:]))
    flat = z.reshape(-1, k * k)  # Z_aa + Z_bb - 2 Z_ab, gathered from the flat rows
    return (np.take(flat, a * (k + 1), axis=1) + np.take(flat, b * (k + 1), axis=1)) - 2.0 * np.take(
        flat, a * k + b, axis=1
    )


def _group_roots(lap: np.ndarray) -> np.ndarray:
    """The lowest electrode of each electrode's group, (presses, k), from the electrodes' Laplacians (presses, k, k).

    The GTH reduction leaves a reduced conductance exactly 0 where no path joins two electrodes through the other
    junctions, so the reduced graph's components are the electrodes' groups: its transitive closure by log2 k
    boolean squarings."""
    k = lap.shape[1]
    linked = (lap != 0) | np.eye(k, dtype=bool)  # every electrode reaches itself
    for _ in range(max(1, math.ceil(math.log2(max(k - 1, 1))))):
        linked = np.matmul(linked, linked)
    return np.argmax(linked, axis=2)


def _groups(lap: np.ndarray, root: np.ndarray, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """R_ab, inf across groups, for networks cut into groups (root: each electrode's group's lowest electrode).
    Each group is grounded at its lowest electrode (its row and column become the identity's), which leaves a
    non-singular matrix whatever was cut off."""
    diag = np.arange(lap.shape[1])
    keep = root != diag  # False on the grounded electrodes
    keep2 = keep[:, :, None] & keep[:, None, :]
    lap = lap * keep2
    lap[:, diag, diag] += ~keep
    z = np.linalg.inv(lap) * keep2  # a grounded electrode's potential is 0
    r = z[:, a, a] + z[:, b, b] - 2.0 * z[:, a, b]
    r[root[:, a] != root[:, b]] = np.inf
    return r


# ---- sparse: grounded solve per press ----------------------------------------------------


def _sparse(layout: Layout, g: np.ndarray) -> np.ndarray:
    import scipy.sparse as sp
    from scipy.sparse.csgraph import connected_components
    from scipy.sparse.linalg import splu

    n = layout.n_junctions
    ends = layout.channel_ends
    a_idx, b_idx = ends[:, 0], ends[:, 1]
    electrodes = layout.electrode_junctions
    pe = layout.pair_electrode_index
    out = np.full((g.shape[0], len(layout.pairs)), np.inf)
    for p in range(g.shape[0]):
        gp = g[p]
        live = gp > 0
        adjacency = sp.coo_matrix((gp[live], (a_idx[live], b_idx[live])), shape=(n, n)).tocsr()
        n_comp, label = connected_components(adjacency, directed=False)
        # Laplacian; ground one node per component by dropping its row and column
        lap = sp.coo_matrix(
            (
                np.concatenate([-gp[live], -gp[live], gp[live], gp[live]]),
                (
                    np.concatenate([a_idx[live], b_idx[live], a_idx[live], b_idx[live]]),
                    np.concatenate([b_idx[live], a_idx[live], a_idx[live], b_idx[live]]),
                ),
            ),
            shape=(n, n),
        ).tocsc()
        ground = np.zeros(n, dtype=bool)
        # ground an electrode where the component has one, so its column of Z is simply zero: the best connected
        # one (largest total conductance). Grounding an electrode that hangs on a nearly shut channel (1e-15 S) put
        # ~1e15 in every entry of Z, and R_ab = Z_aa + Z_bb - 2 Z_ab then cancelled to a few % between the others
        degree = np.bincount(a_idx[live], gp[live], minlength=n) + np.bincount(b_idx[live], gp[live], minlength=n)
        for comp in range(n_comp):
            members = np.flatnonzero(label == comp)
            on_electrode = np.intersect1d(members, electrodes)
            candidates = on_electrode if on_electrode.size else members
            ground[candidates[np.argmax(degree[candidates])]] = True
        free = np.flatnonzero(~ground)
        position = np.full(n, -1)
        position[free] = np.arange(free.size)
        z = np.zeros((len(electrodes), len(electrodes)))
        free_e = [k for k, j in enumerate(electrodes) if position[j] >= 0]
        if free.size and free_e:
            lu = splu(lap[free][:, free].tocsc())
            rhs = np.zeros((free.size, len(free_e)))
            rhs[position[electrodes[free_e]], np.arange(len(free_e))] = 1.0
            sol = lu.solve(rhs)
            z[np.ix_(free_e, free_e)] = sol[position[electrodes[free_e]]]
        za, zb = pe[:, 0], pe[:, 1]
        r = z[za, za] + z[zb, zb] - 2.0 * z[za, zb]
        same = label[electrodes[za]] == label[electrodes[zb]]
        out[p, same] = r[same]
    return out
