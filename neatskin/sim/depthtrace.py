"""The probe's height along a press's moves on a sample clock, the z axis alone: the bits of
`neatskin.sim.motion.positions_mm(segments, times)[:, 2]` at a fraction of its cost.

The dry run's FSR trace needs the probe's depth at every sample of every press (8,540 samples a paper press), on
the main process, the campaign's critical path. `positions_mm` spends most of that time on per-move overheads (a
norm, three clips, a 2-D broadcast); here each move goes through motion's own cached constants and in-place
`ordered_fraction` (which `segment_fraction` uses too) on z alone, and each sample through the same IEEE operations,
in the same order, as `positions_mm` applies to it, so every bit is the same (tests/test_dry_probe_fast.py checks
it against positions_mm).
"""

from __future__ import annotations

import numpy as np

from neatskin.sim.motion import move_constants, ordered_fraction


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
        frac = ordered_fraction(move_constants(seg), tau)
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
            tau = _crossing_s(move_constants(seg), (target - z0) / (z1 - z0))
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
