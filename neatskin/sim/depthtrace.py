"""The probe's height along a press's moves on a sample clock, the z axis alone: the bits of
`neatskin.sim.motion.positions_mm(segments, times)[:, 2]` at a fraction of its cost.

The dry run's FSR trace needs the probe's depth at every sample of every press (8,540 samples a paper press), on
the main process, the campaign's critical path. `positions_mm` spends most of that time on per-move overheads (a
norm, three clips, a 2-D broadcast); here each move's constants are computed once per distinct move (the 28
repeats of a position share theirs) and each sample goes through the same IEEE operations, in the same order, as
`neatskin.sim.motion.segment_fraction` (ordered branch) and `positions_mm` apply to it, so every bit is the same
(tests/test_dry_probe_fast.py checks it against positions_mm).
"""

from __future__ import annotations

import functools

import numpy as np


@functools.lru_cache(maxsize=64)
def _move_constants(seg) -> tuple:
    """What segment_fraction computes of a move before it looks at the times: ("still",) for a move of no length
    or time, ("linear", duration), or ("trapezoid", length, a, v, t_a, d_a, t_c)."""
    length = float(np.linalg.norm(np.asarray(seg.p1_mm, float) - np.asarray(seg.p0_mm, float)))
    duration = seg.own_duration_s
    if length == 0 or duration <= 0:
        return ("still",)
    if seg.linear:
        return ("linear", duration)
    a = seg.accel_mm_s2
    v = min(seg.feed_mm_s, float(np.sqrt(a * length)))
    t_a, d_a = v / a, v * v / (2 * a)
    t_c = max(0.0, (length - 2 * d_a) / v)
    return ("trapezoid", length, a, v, t_a, d_a, t_c)


def _fraction(constants: tuple, tau: np.ndarray) -> np.ndarray:
    """segment_fraction(seg, tau, ordered=True) for tau >= 0, increasing, finite; `tau` is overwritten."""
    kind = constants[0]
    if kind == "still":
        return np.ones_like(tau)
    if kind == "linear":
        np.divide(tau, constants[1], out=tau)
        return np.minimum(tau, 1.0, out=tau)
    _, length, a, v, t_a, d_a, t_c = constants
    dist = np.empty_like(tau)
    i_c, i_b = int(tau.searchsorted(t_a)), int(tau.searchsorted(t_a + t_c))  # the first cruising, braking
    i_b = max(i_b, i_c)
    half_a = 0.5 * a
    # each phase only where it has times: a sample clock cut to the skin (below_runs) often starts braking
    if i_c:
        head = dist[:i_c]
        np.multiply(tau[:i_c], half_a, out=head)  # 0.5 * a * tau * tau, left to right
        np.multiply(head, tau[:i_c], out=head)
    if i_b > i_c:
        cruise = dist[i_c:i_b]
        np.subtract(tau[i_c:i_b], t_a, out=cruise)  # d_a + v * (tau - t_a)
        np.multiply(cruise, v, out=cruise)
        np.add(cruise, d_a, out=cruise)
    if i_b < tau.shape[0]:
        td = tau[i_b:]
        np.subtract(td, t_a, out=td)  # clip(tau - t_a - t_c, 0, t_a)
        np.subtract(td, t_c, out=td)
        np.maximum(td, 0.0, out=td)
        np.minimum(td, t_a, out=td)
        brake = dist[i_b:]
        np.multiply(td, v, out=brake)  # d_a + v * t_c + v * td - 0.5 * a * td * td, left to right
        np.add(brake, d_a + v * t_c, out=brake)
        square = np.multiply(td, half_a)
        np.multiply(square, td, out=square)
        np.subtract(brake, square, out=brake)
    np.minimum(dist, length, out=dist)  # min(dist, length) / length
    return np.divide(dist, length, out=dist)


def z_mm(segments: list, times_s: np.ndarray) -> np.ndarray:
    """`positions_mm(segments, times_s)[:, 2]` for a 1-D, increasing, finite sample clock (the caller checks)."""
    n = times_s.shape[0]
    out = np.empty(n)
    t0s = [seg.t0_s for seg in segments]
    bounds = np.searchsorted(times_s, t0s, side="left").tolist()  # times before move k's start end at bounds[k]
    out[: bounds[0]] = float(segments[0].p0_mm[2])
    for seg, lo, hi in zip(segments, bounds, [*bounds[1:], n]):
        if hi <= lo:
            continue
        tau = np.subtract(times_s[lo:hi], seg.t0_s)
        np.maximum(tau, 0.0, out=tau)  # clip(times - t0, 0, None)
        frac = _fraction(_move_constants(seg), tau)
        z0 = float(seg.p0_mm[2])
        np.multiply(frac, float(seg.p1_mm[2]) - z0, out=out[lo:hi])  # p0 + frac * (p1 - p0)
        np.add(out[lo:hi], z0, out=out[lo:hi])
    return out


TRIM_MARGIN_SAMPLES = 2  # kept beyond the analytic crossing time on each side, far more than its rounding error
Z_TOLERANCE_MM = 1e-9  # the height left out is contact + this: z's own rounding (~1e-14 mm) stays below it


def below_runs(segments: list, times_s: np.ndarray, contact_z_mm: float) -> list[tuple[int, int]]:
    """[lo, hi) runs of an increasing sample clock outside which the probe is surely at or above contact_z_mm.

    Per move (and the rest after it, until the next move starts): a move that stays above is left out; a move
    that crosses the height (z is monotonic along a move) keeps only its times from TRIM_MARGIN_SAMPLES before
    the analytic crossing time on; everything else is kept whole. The caller evaluates only the runs."""
    n = times_s.shape[0]
    if not segments:
        return [(0, n)]
    t0s = [seg.t0_s for seg in segments]
    bounds = np.searchsorted(times_s, t0s, side="left").tolist()
    runs: list[tuple[int, int]] = []
    target = contact_z_mm + Z_TOLERANCE_MM  # a move that ends at the height may round a hair below it
    if bounds[0] > 0 and segments[0].p0_mm[2] < target:  # before the first move, at its start
        runs.append((0, bounds[0]))
    for seg, lo, hi in zip(segments, bounds, [*bounds[1:], n]):
        if hi <= lo:
            continue
        z0, z1 = float(seg.p0_mm[2]), float(seg.p1_mm[2])
        if min(z0, z1) >= target:
            continue
        if max(z0, z1) > target:  # crosses it inside the move: keep the part below (and the rest after a descent)
            tau = _crossing_s(_move_constants(seg), (target - z0) / (z1 - z0))
            if tau is not None:
                cut = int(np.searchsorted(times_s[lo:hi], seg.t0_s + tau)) + lo
                if z1 < z0:  # descending: below from the crossing on
                    lo = max(lo, cut - TRIM_MARGIN_SAMPLES)
                else:  # rising: below until the crossing
                    hi = min(hi, cut + TRIM_MARGIN_SAMPLES)
        if runs and runs[-1][1] == lo:
            runs[-1] = (runs[-1][0], hi)
        elif hi > lo:
            runs.append((lo, hi))
    return runs


def _crossing_s(constants: tuple, fraction: float) -> float | None:
    """The time after its start at which a move has covered `fraction` of its length (None: no motion)."""
    kind = constants[0]
    if kind == "still":
        return None
    if kind == "linear":
        return fraction * constants[1]
    _, length, a, v, t_a, d_a, t_c = constants
    distance = fraction * length
    if distance <= d_a:
        return float(np.sqrt(2.0 * distance / a))
    if distance <= d_a + v * t_c:
        return t_a + (distance - d_a) / v
    braked = max(0.0, distance - d_a - v * t_c)
    return t_a + t_c + (v - float(np.sqrt(max(0.0, v * v - 2.0 * a * braked)))) / a
