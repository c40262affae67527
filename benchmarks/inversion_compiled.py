"""Issue 27's eighth round, measured: the default inversion's model row compiled with numba, against numpy's.

    python benchmarks/inversion_compiled.py RUN [--rows 4096] [--repeats 7] [--fastmath] [--projection] [--cache]

Needs numba, which the package does not depend on: run it from a scratch venv
(`python -m venv V && V/bin/pip install -e . numba`); without numba it exits 2. RUN: a paper dry run
(`neatskin campaign run protocols/paper.toml --dry-run --no-report -o RUN`).

One model row of `skin_inversion`'s default model (the parametric `SkinModel` of RUN's layout and probe), written
once more as plain loops and compiled (`@njit`, no cache unless --cache, so a run pays the compile, timed):
- the pinch's channel factors F and their gradient in (x, y, depth): `modelgrad.factor_and_gradient`'s integrand and
  sums on `deformation._side_panels`' panels (the standard ones, graded ones on the sides peaking above 0.9, graded
  by the call's highest peak as numpy grades a chunk, or by the row's own with `per_row`), the same Gauss-Legendre
  nodes: the same quadrature, so agreement to rounding. Two ways: node by node with libm's exp, as numpy orders the
  sums, and "flat": a side's nodes laid out first, then one loop with an exp in plain arithmetic, which LLVM
  vectorises with --fastmath (numba has no vector exp here: its llvmlite is not built with Intel's SVML);
- the network's R_eq and Jacobian (`modelgrad.pair_resistance_and_gradient`): the grounded Laplacian's Cholesky
  factor solved for the electrodes' columns, R_ab = (e_a - e_b)' Z (e_a - e_b) and Foster's
  dR_ab/dtheta = sum_c (b_c' Z (e_a - e_b))^2 g_c (dF_c/dtheta) / F_c;
- a value-only row too (the grids' rows, `pair_resistance_ohm`).
It prints the largest relative difference against numpy on random rows of the inversion's box (uniform, and with
80 % on the depth bound as the solver's rows are), and the CPU per row of each, side by side (one thread, the best
of --repeats, both in the solver's call sizes, 512 rows with the gradient and 256 without), with the compile's CPU
and wall time and `import numba`'s. --projection: `skin_inversion` and its reference on every press of RUN with
their model calls recorded, the recorded rows replayed through numpy and the compiled row, and each inversion's CPU
with its model rows compiled (the rest as measured), against the 20x target. --swap ROUNDS: the inversion itself
(`inversion._two_passes`, today's solver) run with the compiled row in place of numpy's model, and the reference too,
timed side by side, the answers compared.
"""

from __future__ import annotations

import argparse
import os
import sys
import time

import numpy as np

_started = time.process_time()
try:
    import numba
except ImportError:  # not a dependency of the package: this benchmark only measures what it would buy
    print("inversion_compiled.py needs numba: pip install numba (in a scratch venv; the package does not use it)")
    raise SystemExit(2) from None

# --fastmath: LLVM may reorder float arithmetic (and vectorise the reductions); read before the kernels compile.
# --cache: numba's on-disk cache (NUMBA_CACHE_DIR, else __pycache__): what a second run of an installed tool would pay
FASTMATH = "--fastmath" in sys.argv
CACHE = "--cache" in sys.argv
IMPORT_NUMBA_CPU_S = time.process_time() - _started
# error_model "numpy": a float division by zero gives inf or NaN as in numpy (a shut channel's F = inf), where numba's
# default ("python") tests every divisor to raise ZeroDivisionError, and that branch keeps LLVM from vectorising a loop
njit = numba.njit(cache=CACHE, fastmath=FASTMATH, error_model="numpy")

# the quadrature's constants from the skin itself (numba reads globals when it compiles): a chunk's graded panels
# follow its highest side peak; sides peaking above GRADED_FROM_P0 are graded; the standard and outer panel edges
from neatskin.skin.deformation import _CHUNK_PRESSES as CHUNK_PRESSES  # noqa: E402
from neatskin.skin.deformation import _CUTOFF_DECAYS as CUTOFF_DECAYS  # noqa: E402
from neatskin.skin.deformation import _GRADED_FROM_P0 as GRADED_FROM_P0  # noqa: E402
from neatskin.skin.deformation import _GRADED_OUTER_EDGES as OUTER_EDGES  # noqa: E402
from neatskin.skin.deformation import _PANEL_EDGES as STANDARD_EDGES  # noqa: E402

assert np.array_equal(STANDARD_EDGES, [0.0, 0.5, 2.0, np.inf]), "side_sums takes the last edge as the side's end"


@njit
def graded_edges(peak_max):
    """deformation._graded_edges of the highest peak: [0, 0.5 / 2^levels ... 0.25, 0.5, 1, 1.5, 2, 3, inf]."""
    width = np.sqrt(max(1.0 - peak_max, 1e-300) / peak_max)
    levels = int(min(max(np.ceil(np.log(0.5 / width) / np.log(2.0)), 1.0), 30.0))
    edges = np.empty(levels + 1 + OUTER_EDGES.size)
    edges[0] = 0.0
    for i in range(levels):
        edges[1 + i] = 0.5 * 2.0 ** -(levels - i)
    edges[levels + 1 :] = OUTER_EDGES
    return edges


@njit
def channel_setup(x, y, d, c, geo, consts, scale):
    """One (press, channel): p0, dp0/d(depth), decay l, perp, perp^2, footprint, and per side base, length, active."""
    gain, ratio, thickness, cdepth, a = consts[0], consts[1], consts[2], consts[3], consts[4]
    raw = gain * d / thickness * scale[c]
    rate = gain / thickness * scale[c]
    p0 = min(1.0, raw)
    if not raw < 1.0:
        rate = 0.0
    decay = ratio * (cdepth + d)
    sx, sy, ux, uy, length = geo[c, 0], geo[c, 1], geo[c, 2], geo[c, 3], geo[c, 4]
    rel_x, rel_y = x - sx, y - sy
    s0 = rel_x * ux + rel_y * uy
    perp = rel_x * uy - rel_y * ux
    perp2 = perp * perp
    half_chord = np.sqrt(max(a * a - perp2, 0.0))
    foot_lo = min(max(s0 - half_chord, 0.0), length)
    foot_hi = min(max(s0 + half_chord, 0.0), length)
    reach = max(np.sqrt(max((a + CUTOFF_DECAYS * decay) ** 2 - perp2, 0.0)) - half_chord, 0.0)
    base0, base1 = foot_hi - s0, s0 - foot_lo
    len0, len1 = length - foot_hi, foot_lo
    return p0, rate, decay, perp, perp2, foot_hi - foot_lo, base0, base1, len0, len1, min(reach, len0), min(reach, len1)


@njit
def side_peak(p0, base, perp2, a, decay):
    """The pinch at a side's start (its nearest point to the probe axis): deformation._side_panels' peak."""
    lift = max(np.sqrt(base * base + perp2) - a, 0.0) / decay
    return p0 * np.exp(-lift * lift)


@njit
def row_peak(x, y, d, geo, consts, scale):
    """The highest peak above GRADED_FROM_P0 of a press's live sides (0 if none): what grades its panels."""
    best = 0.0
    for c in range(geo.shape[0]):
        p0, _, decay, _, perp2, _, base0, base1, _, _, act0, act1 = channel_setup(x, y, d, c, geo, consts, scale)
        if p0 > GRADED_FROM_P0:
            for base, act in ((base0, act0), (base1, act1)):
                if act > 0.0:
                    peak = side_peak(p0, base, perp2, consts[4], decay)
                    if peak > GRADED_FROM_P0 and peak > best:
                        best = peak
    return best


@njit
def side_sums(edges, base, act, decay, perp2, a, p0, nodes, weights, want_grad, out):
    """A side's integrals over its panels (modelgrad._side_sums): f, f^2 P u / r, f^2 P u tau / r, f^2 P, f^2 P u^2."""
    inv_l = 1.0 / decay
    for k in range(5):
        out[k] = 0.0
    lower = 0.0  # min(edges[0] * l, active) = 0
    for i in range(1, edges.size):
        upper = act if i == edges.size - 1 else min(edges[i] * decay, act)
        width = upper - lower
        begin = base + lower
        lower = upper
        if width == 0.0:  # numpy sums these too: w f 0 = 0 exactly (f is finite below a shut channel)
            continue
        s0 = s1 = s2 = s3 = s4 = 0.0
        for j in range(nodes.size):
            tau = nodes[j] * width + begin
            r = np.sqrt(tau * tau + perp2)
            u = (r - a) * inv_l
            u2 = u * u
            big_p = np.exp(-u2) * p0
            f = 1.0 / (1.0 - big_p)
            w = weights[j]
            s0 += w * f
            if want_grad:
                fp = f * f * big_p
                a_term = fp * u / r
                s1 += w * a_term
                s2 += w * (a_term * tau)
                s3 += w * fp
                s4 += w * (fp * u2)
        out[0] += s0 * width
        if want_grad:
            out[1] += s1 * width
            out[2] += s2 * width
            out[3] += s3 * width
            out[4] += s4 * width


EXP_TAYLOR = 1.0 / np.cumprod(np.r_[1.0, np.arange(1.0, 17.0)])  # 1 / k!, k = 0..16


E0, E1, E2, E3, E4, E5, E6, E7, E8, E9, E10, E11, E12, E13, E14, E15, E16 = EXP_TAYLOR


@njit
def exp_nonpositive(x):
    """exp(x) for x in [-37.3, 0] (here -u^2, u up to the 6.1 decay lengths' cutoff) in plain arithmetic, so that a
    loop of it vectorises (numba has no vector exp without Intel's SVML, which this llvmlite is not built for):
    exp(x / 64) by its Taylor polynomial of degree 16 (|x / 64| <= 0.59: < 1e-18), squared 6 times (the squarings
    multiply its relative error by 64: ~1e-14). Written out: a loop here would have to be unrolled first."""
    r = x * (1.0 / 64.0)
    p = ((((((((E16 * r + E15) * r + E14) * r + E13) * r + E12) * r + E11) * r + E10) * r + E9) * r + E8) * r + E7
    p = (((((((p * r + E6) * r + E5) * r + E4) * r + E3) * r + E2) * r + E1) * r) + E0
    p = p * p
    p = p * p
    p = p * p
    p = p * p
    p = p * p
    return p * p


@njit
def side_sums_flat(edges, base, act, decay, perp2, a, p0, nodes, weights, want_grad, out, tau_buf, w_buf):
    """side_sums with the side's nodes laid out flat first (tau, and the weight times its panel's width), then one
    loop over them that LLVM can vectorise (fastmath lets it reorder the sums; the own exp lets it vectorise)."""
    inv_l = 1.0 / decay
    m = 0
    lower = 0.0
    for i in range(1, edges.size):
        upper = act if i == edges.size - 1 else min(edges[i] * decay, act)
        width = upper - lower
        begin = base + lower
        lower = upper
        if width == 0.0:
            continue
        for j in range(nodes.size):
            tau_buf[m] = nodes[j] * width + begin
            w_buf[m] = weights[j] * width
            m += 1
    s0 = s1 = s2 = s3 = s4 = 0.0
    if want_grad:
        for t in range(m):
            tau = tau_buf[t]
            r = np.sqrt(tau * tau + perp2)
            u = (r - a) * inv_l
            u2 = u * u
            big_p = exp_nonpositive(-u2) * p0
            f = 1.0 / (1.0 - big_p)
            w = w_buf[t]
            fp = f * f * big_p
            a_term = fp * u / r
            s0 += w * f
            s1 += w * a_term
            s2 += w * (a_term * tau)
            s3 += w * fp
            s4 += w * (fp * u2)
    else:
        for t in range(m):
            tau = tau_buf[t]
            u = (np.sqrt(tau * tau + perp2) - a) * inv_l
            s0 += w_buf[t] / (1.0 - exp_nonpositive(-u * u) * p0)
    out[0], out[1], out[2], out[3], out[4] = s0, s1, s2, s3, s4


@njit
def factor_row(x, y, d, peak_max, geo, consts, scale, nodes, weights, want_grad, flat, factor, grad, sums, buf):
    """F (C,) and dF/d(x, y, depth) (C, 3) of one press, its graded sides graded by peak_max."""
    a, ratio = consts[4], consts[1]
    standard = STANDARD_EDGES
    graded = graded_edges(peak_max) if peak_max > GRADED_FROM_P0 else STANDARD_EDGES
    for c in range(geo.shape[0]):
        p0, rate, decay, perp, perp2, foot, base0, base1, len0, len1, act0, act1 = channel_setup(
            x, y, d, c, geo, consts, scale
        )
        length, ux, uy = geo[c, 4], geo[c, 2], geo[c, 3]
        total = foot / (1.0 - p0) if foot > 0.0 else 0.0
        gx = gy = gd = 0.0
        depth_rate = rate / p0 if p0 > 0.0 else 0.0
        two_over_l = 2.0 / decay
        outer = 0.0
        for k in range(2):
            base, side_len, act = (base0, len0, act0) if k == 0 else (base1, len1, act1)
            sign = 1.0 if k == 0 else -1.0
            if act > 0.0:
                edges = standard
                if p0 > GRADED_FROM_P0 and side_peak(p0, base, perp2, a, decay) > GRADED_FROM_P0:
                    edges = graded
                if flat:
                    side_sums_flat(
                        edges, base, act, decay, perp2, a, p0, nodes, weights, want_grad, sums, buf[0], buf[1]
                    )
                else:
                    side_sums(edges, base, act, decay, perp2, a, p0, nodes, weights, want_grad, sums)
            else:
                for m in range(5):
                    sums[m] = 0.0
            outer += sums[0] + (side_len - act)
            if want_grad:
                gx += two_over_l * (sign * ux * sums[2] - perp * uy * sums[1])
                gy += two_over_l * (sign * uy * sums[2] + perp * ux * sums[1])
                gd += depth_rate * sums[3] + ratio * two_over_l * sums[4]
        factor[c] = (total + outer) / length
        if want_grad:
            inner_d = foot * rate / (1.0 - p0) ** 2 if foot > 0.0 else 0.0
            grad[c, 0] = gx / length
            grad[c, 1] = gy / length
            grad[c, 2] = (gd + inner_d) / length


@njit
def network_row(factor, grad, r0, ends, electrodes, pair_ends, want_grad, lap, cols, g, drops, weight, out_r, out_j):
    """R_eq (pairs,) and its gradient (pairs, 3) from the channel factors: the grounded Laplacian's Cholesky
    factor, its columns for the electrodes, Foster's dR/dg. ends, electrodes: indices of free nodes, the grounded
    electrode's as n_free, whose row of lap and cols is zero (so no branch); pair_ends: electrode indices."""
    n_free, n_ch, n_el = lap.shape[0] - 1, factor.size, electrodes.size
    lap[:, :] = 0.0
    for c in range(n_ch):
        gc = 1.0 / (factor[c] * r0[c])
        g[c] = gc
        i, j = ends[c, 0], ends[c, 1]
        lap[i, i] += gc
        lap[j, j] += gc
        lap[i, j] -= gc
        lap[j, i] -= gc
    for k in range(n_free):  # Cholesky, lower, in place, the ground row and column left out; 1 / diagonal kept
        s = lap[k, k]
        for m in range(k):
            s -= lap[k, m] * lap[k, m]
        diag = np.sqrt(s)
        lap[k, n_free] = 1.0 / diag  # the ground column is free storage
        for i in range(k + 1, n_free):
            s = lap[i, k]
            for m in range(k):
                s -= lap[i, m] * lap[k, m]
            lap[i, k] = s * lap[k, n_free]
    cols[:, :] = 0.0  # cols[:, e] = Z e_electrode; the grounded electrode's column, and the ground row, stay 0
    for e in range(n_el):
        node = electrodes[e]
        if node == n_free:
            continue
        for i in range(node, n_free):  # forward: L y = e_node (y is 0 above the node)
            s = 1.0 if i == node else 0.0
            for m in range(node, i):
                s -= lap[i, m] * cols[m, e]
            cols[i, e] = s * lap[i, n_free]
        for i in range(n_free - 1, -1, -1):  # back: L' z = y
            s = cols[i, e]
            for m in range(i + 1, n_free):
                s -= lap[m, i] * cols[m, e]
            cols[i, e] = s * lap[i, n_free]
    for c in range(n_ch):  # drops[e, c]: the drop across channel c for a unit current in at electrode e
        i, j = ends[c, 0], ends[c, 1]
        for e in range(n_el):
            drops[e, c] = cols[i, e] - cols[j, e]
        if want_grad:
            gf = g[c] / factor[c]
            for k in range(3):
                weight[k, c] = gf * grad[c, k]
    for q in range(pair_ends.shape[0]):
        ea, eb = pair_ends[q, 0], pair_ends[q, 1]
        na, nb = electrodes[ea], electrodes[eb]
        # potentials v = Z (e_a - e_b) = cols[:, ea] - cols[:, eb]; R = v_a - v_b
        out_r[q] = (cols[na, ea] - cols[na, eb]) - (cols[nb, ea] - cols[nb, eb])
        if want_grad:
            j0 = j1 = j2 = 0.0
            for c in range(n_ch):
                drop = drops[ea, c] - drops[eb, c]
                d2 = drop * drop
                j0 += d2 * weight[0, c]
                j1 += d2 * weight[1, c]
                j2 += d2 * weight[2, c]
            out_j[q, 0], out_j[q, 1], out_j[q, 2] = j0, j1, j2


@njit
def model_rows(
    p,
    per_row,
    want_grad,
    network,
    flat,
    geo,
    consts,
    scale,
    nodes,
    weights,
    r0,
    ends,
    electrodes,
    pair_ends,
    out_r,
    out_j,
):
    """R_eq (n, pairs) and, with want_grad, its Jacobian (n, pairs, 3) of the presses p (n, 3), every depth > 0.
    per_row False: each chunk of CHUNK_PRESSES grades its sides by its highest peak, as numpy; True: by the row's.
    network False: the channel factors only (to time the two parts; out_r, out_j untouched). flat: the sides'
    integrals by side_sums_flat (own exp, vectorisable), else side_sums (libm's exp, node by node as numpy orders)."""
    n, n_ch, n_free = p.shape[0], geo.shape[0], ends.max()  # the ground is index n_free
    factor, grad, sums = np.empty(n_ch), np.empty((n_ch, 3)), np.empty(5)
    lap, cols, g = np.empty((n_free + 1, n_free + 1)), np.empty((n_free + 1, electrodes.size)), np.empty(n_ch)
    drops, weight = np.empty((electrodes.size, n_ch)), np.empty((3, n_ch))
    buf = np.empty((2, 64 * nodes.size))  # a side's nodes, for side_sums_flat (at most 36 panels)
    for lo in range(0, n, CHUNK_PRESSES):
        hi = min(lo + CHUNK_PRESSES, n)
        chunk_peak = 0.0
        if not per_row:
            for i in range(lo, hi):
                chunk_peak = max(chunk_peak, row_peak(p[i, 0], p[i, 1], p[i, 2], geo, consts, scale))
        for i in range(lo, hi):
            peak = row_peak(p[i, 0], p[i, 1], p[i, 2], geo, consts, scale) if per_row else chunk_peak
            factor_row(
                p[i, 0],
                p[i, 1],
                p[i, 2],
                peak,
                geo,
                consts,
                scale,
                nodes,
                weights,
                want_grad,
                flat,
                factor,
                grad,
                sums,
                buf,
            )
            if network:
                network_row(
                    factor,
                    grad,
                    r0,
                    ends,
                    electrodes,
                    pair_ends,
                    want_grad,
                    lap,
                    cols,
                    g,
                    drops,
                    weight,
                    out_r[i],
                    out_j[i],
                )


class CompiledSkin:
    """The parametric `SkinModel`'s arrays as `model_rows` takes them, and its calls."""

    def __init__(self, skin) -> None:
        from neatskin.skin.channelchange import grounded_bases
        from neatskin.skin.deformation import _channel_geometry, _gauss_legendre

        self.layout = layout = skin.layout
        if not skin.has_analytic_jacobian:
            raise ValueError("only the parametric pinch with the 'deformation' fidelity is compiled here")
        start, unit, length = _channel_geometry(layout)
        self.geo = np.ascontiguousarray(np.c_[start, unit, length])
        pinch = skin.pinch
        self.consts = np.array(
            [pinch.pinch_gain, pinch.decay_ratio, layout.thickness_mm, layout.channel_depth_mm, skin.probe_radius_mm]
        )
        scale = skin._pinch_scale
        self.scale = np.ones(layout.n_channels) if scale is None else np.asarray(scale, float)
        self.nodes, self.weights = (np.ascontiguousarray(v) for v in _gauss_legendre(pinch.nodes_per_panel))
        self.r0 = np.asarray(skin.channel_baseline_ohm, float)
        ground = int(layout.electrode_junctions[0])
        n_free = layout.n_junctions - 1  # the grounded junction gets index n_free (a zero row, no branch)
        free = np.array(
            [n_free if j == ground else j - (j > ground) for j in range(layout.n_junctions)], dtype=np.int64
        )
        self.ends = free[np.asarray(layout.channel_ends)]
        self.electrodes = free[np.asarray(layout.electrode_junctions)]
        self.pair_ends = np.ascontiguousarray(np.asarray(layout.pair_electrode_index, dtype=np.int64))
        self.n_pairs = len(layout.pairs)
        # the bases numpy uses, to check the index maps against
        incidence, pairs = grounded_bases(layout)
        for c, (i, j) in enumerate(self.ends):
            assert (i == n_free or incidence[i, c] == 1.0) and (j == n_free or incidence[j, c] == -1.0)
        for q, (ea, eb) in enumerate(self.pair_ends):
            na, nb = self.electrodes[ea], self.electrodes[eb]
            assert (na == n_free or pairs[na, q] == 1.0) and (nb == n_free or pairs[nb, q] == -1.0)

    def rows(self, p, want_grad: bool = True, per_row: bool = False, network: bool = True, flat: bool = False):
        """R_eq (n, pairs) and its Jacobian (n, pairs, 3) (NaN without want_grad) at p (n, 3)."""
        p = np.ascontiguousarray(p, dtype=float)
        out_r = np.empty((len(p), self.n_pairs))
        out_j = np.full((len(p), self.n_pairs, 3), np.nan)
        model_rows(
            p, per_row, want_grad, network, flat, self.geo, self.consts, self.scale, self.nodes, self.weights, self.r0,
            self.ends, self.electrodes, self.pair_ends, out_r, out_j,
        )  # fmt: skip
        return out_r, out_j


def _box(layout):
    """The inversion's box (skin_inversion: the layout's bounds + 0.5 mm, depths 5 to 95 % of the thickness)."""
    x0, y0, x1, y1 = layout.bounds_mm
    return np.array([x0 - 0.5, y0 - 0.5, 0.05 * layout.thickness_mm]), np.array(
        [x1 + 0.5, y1 + 0.5, 0.95 * layout.thickness_mm]
    )


def random_rows(layout, n: int, on_bound: float, seed: int) -> np.ndarray:
    """n uniform rows of the box, the share on_bound of them at the depth bound (where the solver's rows sit)."""
    lo, hi = _box(layout)
    rng = np.random.default_rng(seed)
    p = lo + rng.random((n, 3)) * (hi - lo)
    p[rng.random(n) < on_bound, 2] = hi[2]
    return p


def _relative(a: np.ndarray, b: np.ndarray) -> float:
    """The largest |a - b| of a row over the row's largest |b|, the worst row."""
    axes = tuple(range(1, a.ndim))
    scale = np.maximum(np.max(np.abs(b), axis=axes), 1e-300)
    return float(np.max(np.max(np.abs(a - b), axis=axes) / scale))


def _best_cpu_us(call, n_rows: int, repeats: int) -> float:
    best = np.inf
    for _ in range(repeats):
        started = time.process_time()
        call()
        best = min(best, time.process_time() - started)
    return 1e6 * best / n_rows


def numpy_rows(skin, p, want_grad: bool):
    """numpy's model as the solver calls it: value and gradient in calls of 512 rows, values in calls of 256."""
    from neatskin.baselines.invsolve import GRADIENT_CHUNK, MODEL_CHUNK

    chunk = GRADIENT_CHUNK if want_grad else MODEL_CHUNK
    out_r = np.empty((len(p), len(skin.layout.pairs)))
    out_j = np.full((*out_r.shape, 3), np.nan)
    for s in range(0, len(p), chunk):
        q = p[s : s + chunk]
        if want_grad:
            out_r[s : s + chunk], out_j[s : s + chunk] = skin.pair_resistance_and_jacobian_ohm(
                q[:, 0], q[:, 1], q[:, 2]
            )
        else:
            out_r[s : s + chunk] = skin.pair_resistance_ohm(q[:, 0], q[:, 1], q[:, 2])
    return out_r, out_j


def compiled_rows(compiled: CompiledSkin, p, want_grad: bool, **options):
    """The compiled row in numpy's call sizes (a call is a grading chunk, so the same panels as numpy_rows)."""
    from neatskin.baselines.invsolve import GRADIENT_CHUNK, MODEL_CHUNK

    chunk = GRADIENT_CHUNK if want_grad else MODEL_CHUNK
    parts = [compiled.rows(p[s : s + chunk], want_grad, **options) for s in range(0, len(p), chunk)]
    return np.concatenate([r for r, _ in parts]), np.concatenate([j for _, j in parts])


def rows_report(skin, compiled: CompiledSkin, n_rows: int, repeats: int) -> None:
    """Agreement and CPU per row, numpy against the two compiled rows, on uniform and depth-bound-heavy rows."""
    print(f"\nmodel rows: {n_rows} random rows a set, CPU per row best of {repeats}; load {os.getloadavg()[0]:.2f}")
    print("compiled: node by node with libm's exp (as numpy orders the sums); flat: own exp, vectorisable loop")
    print(
        "| rows | kind | max rel. diff R, J: compiled | flat | compiled, per-row grading | numpy us | compiled us "
        "(factors + network) | flat us (factors + network) | numpy / compiled | numpy / flat |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|")
    for label, on_bound, seed in (("uniform in the box", 0.0, 1), ("80 % on the depth bound", 0.8, 2)):
        p = random_rows(skin.layout, n_rows, on_bound, seed)
        for want_grad in (True, False):
            ref_r, ref_j = numpy_rows(skin, p, want_grad)
            diffs = []
            for flat, per_row in ((False, False), (True, False), (False, True)):
                got_r, got_j = compiled_rows(compiled, p, want_grad, per_row=per_row, flat=flat)
                diff_j = f"{_relative(got_j, ref_j):.1e}" if want_grad else "-"
                diffs.append(f"{_relative(got_r, ref_r):.1e}, {diff_j}")
            t_np = _best_cpu_us(lambda: numpy_rows(skin, p, want_grad), n_rows, repeats)  # noqa: B023
            cells = []
            for flat in (False, True):
                whole = _best_cpu_us(lambda: compiled_rows(compiled, p, want_grad, flat=flat), n_rows, repeats)  # noqa: B023
                part = _best_cpu_us(
                    lambda: compiled_rows(compiled, p, want_grad, network=False, flat=flat),  # noqa: B023
                    n_rows,
                    repeats,
                )
                cells.append((whole, part))
            kind = "value + Jacobian" if want_grad else "value"
            times = " | ".join(f"{w:.2f} ({f:.2f} + {w - f:.2f})" for w, f in cells)
            print(
                f"| {label} | {kind} | {' | '.join(diffs)} | {t_np:.2f} | {times} | {t_np / cells[0][0]:.1f}x "
                f"| {t_np / cells[1][0]:.1f}x |"
            )


def compile_report(compiled: CompiledSkin) -> None:
    """The first call's CPU and wall time (numba's type inference and LLVM), each signature once."""
    p = random_rows(compiled.layout, 4, 0.5, 0)
    started, wall = time.process_time(), time.perf_counter()
    compiled.rows(p, True)
    compiled.rows(p, False)
    cpu_s, wall_s = time.process_time() - started, time.perf_counter() - wall
    started = time.process_time()
    compiled.rows(p, True)
    again_s = time.process_time() - started
    print(
        f"import numba {IMPORT_NUMBA_CPU_S:.2f} s CPU; compile (the first calls of model_rows, with and without the "
        f"gradient): {cpu_s:.2f} s CPU, {wall_s:.2f} s wall; a second call of 4 rows {again_s * 1e3:.2f} ms"
    )


class Recorder:
    """Wraps `SkinModel`'s two model calls and `inversion._diverse_starts` in this process: every call's rows (depth >
    0: the baseline's row is left out) and the CPU spent in each."""

    def __init__(self) -> None:
        from neatskin.baselines import inversion
        from neatskin.skin.model import SkinModel

        self.calls: list[tuple[bool, np.ndarray]] = []
        self.cpu = {"value": 0.0, "value + Jacobian": 0.0, "start search": 0.0}
        self.rows = {"value": 0, "value + Jacobian": 0}
        self._saved = [
            (SkinModel, "pair_resistance_ohm", SkinModel.pair_resistance_ohm),
            (SkinModel, "pair_resistance_and_jacobian_ohm", SkinModel.pair_resistance_and_jacobian_ohm),
            (inversion, "_diverse_starts", inversion._diverse_starts),
        ]
        for owner, name, original in self._saved:
            setattr(owner, name, self._wrap(name, original))

    def _wrap(self, name, original):
        kind = {"pair_resistance_ohm": "value", "_diverse_starts": "start search"}.get(name, "value + Jacobian")

        def call(*args, **kwargs):
            started = time.process_time()
            out = original(*args, **kwargs)
            self.cpu[kind] += time.process_time() - started
            if kind != "start search":
                p = np.column_stack([np.broadcast_to(np.asarray(v, float), np.shape(args[1])) for v in args[1:4]])
                if np.all(p[:, 2] > 0):
                    self.calls.append((kind != "value", p))
                    self.rows[kind] += len(p)
            return out

        return call

    def restore(self) -> None:
        for owner, name, original in self._saved:
            setattr(owner, name, original)


def replay_cpu_s(calls, evaluate, stride: int = 1) -> float:
    """CPU s of `evaluate(want_grad, p)` over every stride-th recorded call (in the recorded call sizes), scaled up."""
    started = time.process_time()
    for want_grad, p in calls[::stride]:
        evaluate(want_grad, p)
    return (time.process_time() - started) * len(calls) / max(len(calls[::stride]), 1)


def projection_report(run: str, compiled: CompiledSkin, repeats: int) -> None:
    """skin_inversion as the report calls it, and its reference, with their model calls recorded; the recorded rows
    replayed through numpy and the compiled row (best of `repeats`); the inversion's CPU with the compiled row."""
    from neatskin.baselines.dataset import load_baseline_data
    from neatskin.baselines.inversion import skin_inversion
    from neatskin.skin.model import SkinModel

    data = load_baseline_data(run)
    options = {"fidelity": data.skin_fidelity or "deformation", "probe_radius_mm": data.probe_radius_mm or 2.75}
    skin = SkinModel(data.layout, **options)
    n = len(data.X)
    print(f"\n{run}: every press ({n}), one process, one BLAS thread; load {os.getloadavg()[0]:.2f}")
    print(
        "| inversion | CPU s | model rows a press (value, value + Jacobian) | model CPU s in the run | start search s |"
    )
    print("|---|---|---|---|---|")
    recorded = {}
    for method in ("batched", "reference"):
        recorder = Recorder()
        started = time.process_time()
        result = skin_inversion(data.layout, data.X, method=method, **options)
        total = time.process_time() - started
        recorder.restore()
        recorded[method] = (total, recorder, result)
        model_s = recorder.cpu["value"] + recorder.cpu["value + Jacobian"]
        print(
            f"| {method} | {total:.2f} | {recorder.rows['value'] / n:.1f}, {recorder.rows['value + Jacobian'] / n:.1f} "
            f"| {model_s:.2f} | {recorder.cpu['start search']:.2f} |"
        )

    def numpy_eval(want_grad, p):
        if want_grad:
            return skin.pair_resistance_and_jacobian_ohm(p[:, 0], p[:, 1], p[:, 2])
        return skin.pair_resistance_ohm(p[:, 0], p[:, 1], p[:, 2])

    def compiled_eval(want_grad, p):  # the flat row where it vectorises (--fastmath), else node by node
        return compiled.rows(p, want_grad, flat=FASTMATH)

    total, recorder, result = recorded["batched"]
    worst = 0.0
    for want_grad, p in recorder.calls[:: max(1, len(recorder.calls) // 200)]:
        ref, got = numpy_eval(want_grad, p), compiled_eval(want_grad, p)
        worst = max(worst, _relative(got[0], ref if not want_grad else ref[0]))
        if want_grad:
            worst = max(worst, _relative(got[1], ref[1]))
    row = "flat, fastmath" if FASTMATH else "node by node"
    print(f"\nthe default's recorded rows through both ({row}; 200 calls sampled): max rel. diff {worst:.1e}")
    print("| inversion | model CPU s: numpy replay | compiled replay | CPU s as run | with the compiled row |")
    print("|---|---|---|---|---|")
    projected = {}
    for method, stride in (("batched", 1), ("reference", 10)):
        total, recorder, _ = recorded[method]
        np_s = min(replay_cpu_s(recorder.calls, numpy_eval, stride) for _ in range(repeats))
        nb_s = min(replay_cpu_s(recorder.calls, compiled_eval, stride) for _ in range(repeats))
        in_run = recorder.cpu["value"] + recorder.cpu["value + Jacobian"]
        projected[method] = total - in_run + nb_s
        print(f"| {method} | {np_s:.2f} | {nb_s:.2f} | {total:.2f} | {projected[method]:.2f} |")
    ref_s = recorded["reference"][0]
    default_s = recorded["batched"][0]
    rest = default_s - recorded["batched"][1].cpu["value"] - recorded["batched"][1].cpu["value + Jacobian"]
    print(
        f"\nreference / default: as run {ref_s / default_s:.1f}x; the default with the compiled row "
        f"{ref_s / projected['batched']:.1f}x against the numpy reference, {projected['reference'] / projected['batched']:.1f}x "
        f"with both compiled; 20x = {ref_s / 20:.2f} s. The default's CPU outside the model {rest:.2f} s (start search "
        f"{recorded['batched'][1].cpu['start search']:.2f} s); its model rows alone, compiled: "
        f"{projected['batched'] - rest:.2f} s; with the start search as measured and a solver of no cost of its own "
        f"(a bound for a compiled loop): {projected['batched'] - rest + recorded['batched'][1].cpu['start search']:.2f} s"
    )


class SwappedSkin:
    """A `SkinModel` whose two model calls are the compiled row (a call with a row at depth <= 0, the unpressed
    baseline, stays numpy's): what `invert_presses` calls, so the solver, its starts and passes are today's code."""

    has_analytic_jacobian = True

    def __init__(self, skin, compiled: CompiledSkin) -> None:
        self.skin, self.compiled = skin, compiled

    def pair_resistance_ohm(self, x_mm, y_mm, depth_mm):
        x, y, d = np.broadcast_arrays(*(np.atleast_1d(np.asarray(v, float)) for v in (x_mm, y_mm, depth_mm)))
        if not np.all(d > 0):
            return self.skin.pair_resistance_ohm(x, y, d)
        return self.compiled.rows(np.c_[x, y, d], False, flat=FASTMATH)[0]

    def pair_resistance_and_jacobian_ohm(self, x_mm, y_mm, depth_mm):
        return self.compiled.rows(np.c_[x_mm, y_mm, depth_mm], True, flat=FASTMATH)


def swapped_report(run: str, compiled: CompiledSkin, rounds: int) -> None:
    """skin_inversion's two passes (`inversion._two_passes`, as `skin_inversion` calls them) on every press of RUN,
    with numpy's model and with the compiled row swapped in, and the reference the same way: CPU (best of rounds,
    alternating) and the answers against numpy's."""
    from neatskin.baselines.dataset import load_baseline_data
    from neatskin.baselines.inversion import _two_passes
    from neatskin.skin.model import SkinModel

    data = load_baseline_data(run)
    layout = data.layout
    skin = SkinModel(layout, data.skin_fidelity or "deformation", probe_radius_mm=data.probe_radius_mm or 2.75)
    skins = {"numpy": skin, "compiled": SwappedSkin(skin, compiled)}
    x0, y0, x1, y1 = layout.bounds_mm
    bounds = (x0 - 0.5, y0 - 0.5, x1 + 0.5, y1 + 0.5)  # skin_inversion's box
    depth = (0.05 * layout.thickness_mm, 0.95 * layout.thickness_mm)
    best: dict[tuple[str, str], float] = {}
    answers = {}
    load = []
    for round_ in range(rounds):
        for method in ("batched", "reference") if round_ == 0 else ("batched",):
            order = ["numpy", "compiled"][:: -1 if round_ % 2 else 1]
            for name in order:
                started = time.process_time()
                res = _two_passes(skins[name], data.X, bounds, depth, 2.0, (6, 1.0, 0.9), method=method)
                cpu = time.process_time() - started
                load.append(os.getloadavg()[0])
                best[(name, method)] = min(best.get((name, method), np.inf), cpu)
                answers[(name, method)] = res
    row = "flat, fastmath" if FASTMATH else "node by node"
    print(
        f"\n{run}: skin_inversion's passes with the compiled row ({row}) swapped in; every press ({len(data.X)}); CPU s, "
        f"best of {rounds} (the reference: 1); load {min(load):.2f} to {max(load):.2f}"
    )
    print(
        "| inversion | numpy s | compiled s | ratio | mean error mm (numpy, compiled) | within 1e-3 mm of numpy's "
        "| moved > 0.1 mm | residual higher (> 1e-6 rel.) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for method in ("batched", "reference"):
        a, b = answers[("numpy", method)], answers[("compiled", method)]
        apart = np.max(np.abs(np.c_[a.xy_mm, a.depth_mm] - np.c_[b.xy_mm, b.depth_mm]), axis=1)
        err = [np.mean(np.hypot(*(r.xy_mm - data.y).T)) for r in (a, b)]
        higher = np.mean(b.residual_ohm > a.residual_ohm * (1 + 1e-6))
        t_np, t_nb = best[("numpy", method)], best[("compiled", method)]
        print(
            f"| {method} | {t_np:.2f} | {t_nb:.2f} | {t_np / t_nb:.2f}x | {err[0]:.4f}, {err[1]:.4f} "
            f"| {100 * np.mean(apart < 1e-3):.1f} % | {100 * np.mean(apart > 0.1):.2f} % | {100 * higher:.2f} % |"
        )
    ref = best[("numpy", "reference")]
    print(
        f"numpy reference / compiled default: {ref / best[('compiled', 'batched')]:.1f}x (numpy default "
        f"{ref / best[('numpy', 'batched')]:.1f}x); compiled reference / compiled default "
        f"{best[('compiled', 'reference')] / best[('compiled', 'batched')]:.1f}x; 20x = {ref / 20:.2f} s"
    )


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("run")
    parser.add_argument("--rows", type=int, default=4096)
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--projection", action="store_true", help="also invert every press and project (below)")
    parser.add_argument(
        "--swap", type=int, default=0, metavar="ROUNDS", help="run the inversion with the row swapped in"
    )
    parser.add_argument("--skip-rows", action="store_true", help="skip the random rows' table")
    parser.add_argument("--fastmath", action="store_true", help="compile with fastmath (read at import, above)")
    parser.add_argument("--cache", action="store_true", help="numba's on-disk cache (read at import, above)")
    args = parser.parse_args(argv)
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)  # one BLAS thread, as a report lane runs the inversion; numba's code here has one thread
    from neatskin.baselines.dataset import load_baseline_data
    from neatskin.skin.model import SkinModel

    data = load_baseline_data(args.run)
    skin = SkinModel(
        data.layout, fidelity=data.skin_fidelity or "deformation", probe_radius_mm=data.probe_radius_mm or 2.75
    )
    compiled = CompiledSkin(skin)
    print(
        f"numba {numba.__version__}, numpy {np.__version__}, python {sys.version.split()[0]}, fastmath {FASTMATH}, "
        f"cache {CACHE}; "
        f"{args.run}"
    )
    compile_report(compiled)
    if not args.skip_rows:
        rows_report(skin, compiled, args.rows, args.repeats)
    if args.projection:
        projection_report(args.run, compiled, min(args.repeats, 3))
    if args.swap:
        swapped_report(args.run, compiled, args.swap)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
